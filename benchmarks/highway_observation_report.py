"""What the highway agent's observation shows of the cars that matter, per radar and observation option.

    python benchmarks/highway_observation_report.py --episodes 30 --policy random \
        --json /tmp/highway_observation.json --md docs/results/highway_observation.md \
        --plot docs/results/highway_observation.png --force

On ``sensor_envs/HighwayFast-v0`` (highway-env's highway-fast defaults: 3 lanes, 1 Hz policy, 30 s
episodes), the same seeds and the same action sequence (a scripted policy whose actions do not depend
on the observation, so every configuration drives through the same traffic until its episode ends), per
policy step and configuration, from the wrapper's ground truth (``info["radar"]`` and
``RadarObservation.last_rows``):

* **cars that matter**: the nearest car ahead in the ego lane, in the left lane and in the right lane
  (within highway-env's perception distance, centre ahead of the ego's front bumper). A car is
  *shown* when an observation row is that car (a detection of it, or a track it last updated);
  *miss rate* = share of steps it is not shown (whatever the reason: out of view, occluded, missed,
  or pushed out of the ``vehicles_count - 1`` rows by clutter); *position error* = distance [m] of the
  row to the car's closest corner (the point the radar measures); *speed error* = |row velocity -
  true velocity| [m/s];
* **disappearances**: for every car while it is a car that matters, the lengths ``k`` of its runs of
  consecutive steps not shown between two shown steps (per 100 such car-steps);
* **rows**: how many of the agent's ``vehicles_count - 1`` rows hold a car, clutter, or nothing;
* **before collisions**: for episodes that end in a crash, the last two observations (the last second
  the agent acted on and the one before): was the car the ego crashed into shown, how many rows held
  clutter.

Policies (``--policy``, one or more; the tables are given per policy): ``random`` (uniform over the 5
meta-actions, its own seeded generator: many early crashes, so many collision records), ``idle``
(keeps lane and speed: longer episodes, the steady state of trackers), ``lane`` (changes lane every 5
steps). Progress: one line per configuration on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.geometry import from_frame
from sensor_envs.outputs import atomic_write

CONFIGS: dict[str, dict[str, Any]] = {
    "ideal": {"radar": "ideal"},
    "gaussian": {"radar": "gaussian"},
    "kde, point-level clutter (before)": {"radar": "kde", "clutter": "model"},
    "kde": {"radar": "kde"},
    "kde, stationary dropped": {"radar": "kde", "stationary": "drop"},
    "kde, tracks": {"radar": "kde", "tracks": True},
    "kde, tracks 3 of 3": {"radar": "kde", "tracks": True, "tracker": {"confirm_hits": 3, "confirm_window": 3}},
    "kde, tracks, stationary dropped": {"radar": "kde", "tracks": True, "stationary": "drop"},
    "ideal, tracks": {"radar": "ideal", "tracks": True},
}
ROLES = ("ego lane", "left lane", "right lane")
GAP_BINS = (1, 2, 3, 4)  # the last bin counts >= 4


@dataclass
class Tally:
    """Running counts of one configuration."""

    steps: int = 0
    role_steps: dict[str, int] = field(default_factory=lambda: dict.fromkeys(ROLES, 0))
    role_shown: dict[str, int] = field(default_factory=lambda: dict.fromkeys(ROLES, 0))
    pos_err: dict[str, list[float]] = field(default_factory=lambda: {r: [] for r in ROLES})
    speed_err: dict[str, list[float]] = field(default_factory=lambda: {r: [] for r in ROLES})
    rows: list[tuple[int, int, int]] = field(default_factory=list)
    gaps: list[int] = field(default_factory=list)
    matter_steps: int = 0
    crashes: list[dict[str, Any]] = field(default_factory=list)
    episodes: int = 0


def _policy(name: str, rng: np.random.Generator, t: int) -> int:
    if name == "random":
        return int(rng.integers(5))
    if name == "lane":
        return (0 if (t // 5) % 2 else 2) if t % 5 == 0 else 1
    return 1  # IDLE


def _cars_that_matter(base: Any) -> dict[str, Any]:
    """The nearest car ahead in the ego lane and each adjacent lane (``None`` where there is none)."""
    ego, road = base.vehicle, base.road
    lane = ego.lane_index
    s0 = ego.lane.local_coordinates(ego.position)[0] + ego.LENGTH / 2
    out: dict[str, Any] = dict.fromkeys(ROLES)
    best = dict.fromkeys(ROLES, np.inf)
    for v in road.vehicles:
        if v is ego or np.linalg.norm(v.position - ego.position) >= base.PERCEPTION_DISTANCE:
            continue
        li = v.lane_index
        if li[:2] != lane[:2]:
            continue
        role = {0: "ego lane", -1: "left lane", 1: "right lane"}.get(li[2] - lane[2])
        ds = ego.lane.local_coordinates(v.position)[0] - s0
        if role is not None and ds > 0 and ds < best[role]:
            best[role], out[role] = ds, v
    return out


def _corner_world(info: Any, obj_index: int) -> np.ndarray:
    return np.asarray(from_frame(info.truth_reference[obj_index], info.sensor_pose), dtype=np.float64).reshape(2)


def _shown_objects(wrapper: Any) -> list[Any]:
    return list(wrapper.last_rows.objects)


def run_config(name: str, kwargs: dict[str, Any], episodes: int, seed: int, policy: str) -> Tally:
    """Roll ``episodes`` episodes of one configuration and tally what the observation showed."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make("sensor_envs/HighwayFast-v0", disable_env_checker=True, **kwargs)
    wrapper = _find_radar(env)
    base: Any = env.unwrapped
    tally = Tally()
    n_rows = wrapper.layout.vehicles_count - 1
    for ep in range(episodes):
        _, info = env.reset(seed=seed + ep)
        act_rng = np.random.default_rng([seed, ep, 7])
        last_seen: dict[int, int] = {}  # id(car) -> last step it was shown while it mattered
        history: list[dict[str, Any]] = []
        t, done = 0, False
        while not done:
            snapshot = _tally_step(base, wrapper, info["radar"], tally, n_rows, last_seen, t)
            history.append(snapshot)
            _, _, term, trunc, info = env.step(_policy(policy, act_rng, t))
            t += 1
            done = term or trunc
        tally.episodes += 1
        if base.vehicle.crashed:
            tally.crashes.append(_crash_record(base, history))
    env.close()
    return tally


def _find_radar(env: Any) -> Any:
    e = env
    while not hasattr(e, "last_rows"):
        e = e.env
    return e


def _tally_step(
    base: Any, wrapper: Any, info: Any, tally: Tally, n_rows: int, last_seen: dict[int, int], t: int
) -> dict[str, Any]:
    """Count one observation; returns what the collision record needs."""
    tally.steps += 1
    rows = wrapper.last_rows
    shown = rows.objects
    n_car = sum(o is not None for o in shown)
    tally.rows.append((n_car, len(shown) - n_car, n_rows - len(shown)))
    cars = _cars_that_matter(base)
    objs = wrapper.last_frame.truth.objects
    for role, car in cars.items():
        if car is None:
            continue
        tally.role_steps[role] += 1
        tally.matter_steps += 1
        hit = [k for k, o in enumerate(shown) if o is car]
        key = id(car)
        if hit:
            tally.role_shown[role] += 1
            k = hit[0]
            corner = _corner_world(info, objs.index(car))
            tally.pos_err[role].append(float(np.linalg.norm(rows.position[k] - corner)))
            tally.speed_err[role].append(float(np.linalg.norm(rows.velocity[k] - car.velocity)))
            if key in last_seen and t - last_seen[key] > 1:
                tally.gaps.append(t - last_seen[key] - 1)
            last_seen[key] = t
    return {
        "shown": [o for o in shown if o is not None],
        "clutter_rows": len(shown) - n_car,
        "rows": len(shown),
    }


def _crash_record(base: Any, history: list[dict[str, Any]]) -> dict[str, Any]:
    """What the last two observations before the crash showed of the car the ego hit."""
    ego = base.vehicle
    others = [v for v in base.road.vehicles if v is not ego and v.crashed]
    hit = min(others, key=lambda v: np.linalg.norm(v.position - ego.position)) if others else None
    last = history[-2:]  # the observation the last action was taken on, and the one before
    return {
        "other_found": hit is not None,
        "shown": [hit is not None and any(o is hit for o in h["shown"]) for h in last],
        "clutter_rows": [h["clutter_rows"] for h in last],
    }


def summarise(tally: Tally) -> dict[str, Any]:
    """Plain-JSON figures of one configuration."""
    rows = np.asarray(tally.rows, dtype=np.float64).reshape(-1, 3)
    gaps = np.asarray(tally.gaps, dtype=np.int64)
    per100 = 100.0 / max(tally.matter_steps, 1)
    gap_counts = {f"{k}": float(((gaps == k) if k < GAP_BINS[-1] else (gaps >= k)).sum() * per100) for k in GAP_BINS}
    roles = {}
    for r in ROLES:
        e, v = np.asarray(tally.pos_err[r]), np.asarray(tally.speed_err[r])
        roles[r] = {
            "steps": tally.role_steps[r],
            "miss_rate": 1.0 - tally.role_shown[r] / max(tally.role_steps[r], 1),
            "position_error_median": float(np.median(e)) if e.size else float("nan"),
            "position_error_p90": float(np.quantile(e, 0.9)) if e.size else float("nan"),
            "speed_error_median": float(np.median(v)) if v.size else float("nan"),
            "speed_error_p90": float(np.quantile(v, 0.9)) if v.size else float("nan"),
        }
    crashes = tally.crashes
    last_shown = [c["shown"][-1] for c in crashes if c["other_found"] and c["shown"]]
    prev_shown = [c["shown"][0] for c in crashes if c["other_found"] and len(c["shown"]) == 2]
    return {
        "episodes": tally.episodes,
        "steps": tally.steps,
        "cars_that_matter": roles,
        "gaps_per_100_car_steps": gap_counts,
        "rows_mean": {
            "car": float(rows[:, 0].mean()),
            "clutter": float(rows[:, 1].mean()),
            "empty": float(rows[:, 2].mean()),
        },
        "crashes": len(crashes),
        "crash_share": len(crashes) / max(tally.episodes, 1),
        "crashed_into_shown_last_obs": float(np.mean(last_shown)) if last_shown else float("nan"),
        "crashed_into_shown_obs_before": float(np.mean(prev_shown)) if prev_shown else float("nan"),
        "clutter_rows_last_obs_before_crash": float(np.mean([c["clutter_rows"][-1] for c in crashes]))
        if crashes
        else float("nan"),
    }


def markdown(by_policy: dict[str, dict[str, dict[str, Any]]], command: str, seconds: float, plots: dict) -> str:
    """The results page: one section per policy."""
    first = next(iter(next(iter(by_policy.values())).values()))
    lines = [
        "# What the highway agent sees: the cars that matter, per radar and observation option",
        "",
        f"Generated on {time.strftime('%Y-%m-%d', time.gmtime())} (UTC) by `{command}` "
        f"({first['episodes']} episodes per configuration and policy, {seconds:.0f} s). "
        "Script: `benchmarks/highway_observation_report.py` (its docstring defines every figure). "
        "World: `sensor_envs/HighwayFast-v0` defaults (3 lanes, 1 Hz policy, 30 s episodes, 5 observation rows: "
        "ego + 4). The same seeds and action sequence for every configuration.",
        "",
    ]
    for policy, results in by_policy.items():
        steps = next(iter(results.values()))["steps"]
        lines += [f"# Policy `{policy}` ({steps} steps per configuration)", ""]
        lines += _policy_tables(results, plots.get(policy))
    return "\n".join(lines)


def _policy_tables(results: dict[str, dict[str, Any]], plot_name: str | None) -> list[str]:
    """The tables of one policy."""
    lines = [
        "## Nearest car ahead: share of steps not shown in the observation, and the shown row's errors",
        "",
        "| configuration | miss: ego lane | miss: left | miss: right | pos. err. ego lane median / p90 [m] "
        "| speed err. ego lane median / p90 [m/s] |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        c = r["cars_that_matter"]
        e = c["ego lane"]
        lines.append(
            f"| {name} | {e['miss_rate']:.2f} | {c['left lane']['miss_rate']:.2f} | {c['right lane']['miss_rate']:.2f} "
            f"| {e['position_error_median']:.2f} / {e['position_error_p90']:.2f} "
            f"| {e['speed_error_median']:.2f} / {e['speed_error_p90']:.2f} |"
        )
    lines += [
        "",
        "## Rows and disappearances",
        "",
        "Rows: mean number of the agent's 4 non-ego rows holding a car / clutter / nothing. Gaps: runs of k "
        "consecutive steps a car that matters was not shown between two steps it was, per 100 car-steps.",
        "",
        "| configuration | rows car | rows clutter | rows empty | gap k=1 | k=2 | k=3 | k>=4 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        m, g = r["rows_mean"], r["gaps_per_100_car_steps"]
        lines.append(
            f"| {name} | {m['car']:.2f} | {m['clutter']:.2f} | {m['empty']:.2f} | {g['1']:.2f} | {g['2']:.2f} "
            f"| {g['3']:.2f} | {g['4']:.2f} |"
        )
    lines += [
        "",
        "## Before collisions",
        "",
        "Of the episodes that ended in a crash: share in which the car the ego crashed into was shown in the "
        "last observation the agent acted on, and in the one before; mean clutter rows in that last observation.",
        "",
        "| configuration | crashes / episodes | shown, last obs | shown, obs before | clutter rows, last obs |",
        "|---|---|---|---|---|",
    ]
    for name, r in results.items():
        lines.append(
            f"| {name} | {r['crashes']} / {r['episodes']} | {r['crashed_into_shown_last_obs']:.2f} "
            f"| {r['crashed_into_shown_obs_before']:.2f} | {r['clutter_rows_last_obs_before_crash']:.2f} |"
        )
    if plot_name:
        lines += ["", f"![what the observation shows]({plot_name})"]
    lines += [""]
    lines += _reading(results)
    return lines


def _reading(results: dict[str, dict[str, Any]]) -> list[str]:
    """A few sentences stating what the tables show, from the figures themselves."""

    def miss(name: str) -> str:
        return f"{results[name]['cars_that_matter']['ego lane']['miss_rate']:.2f}"

    def rows(name: str, key: str) -> str:
        return f"{results[name]['rows_mean'][key]:.1f}"

    out = ["## Reading", ""]
    if {"ideal", "kde", "kde, point-level clutter (before)"} <= set(results):
        out.append(
            f"* With raw detections the nearest car ahead in the ego lane is not in the observation in "
            f"{miss('kde, point-level clutter (before)')} of the steps with the point-level clutter and {miss('kde')} "
            f"with object-level clutter (ideal radar: {miss('ideal')}): of the 4 rows, "
            f"{rows('kde', 'clutter')} hold clutter on average, {rows('kde', 'car')} a car."
        )
    if {"kde", "kde, stationary dropped"} <= set(results):
        out.append(
            f"* The Doppler stationary filter brings it to {miss('kde, stationary dropped')} "
            f"({rows('kde, stationary dropped', 'car')} rows hold a car)."
        )
    if {"kde, tracks", "kde, tracks, stationary dropped"} <= set(results):
        out.append(
            f"* Tracks on all detections: {miss('kde, tracks')} ({rows('kde, tracks', 'clutter')} rows hold "
            f"confirmed clutter tracks); tracks after the stationary filter: {miss('kde, tracks, stationary dropped')}."
        )
    out.append("")
    return out


def plot(results: dict[str, dict[str, Any]], path: Path) -> None:
    """Miss rates per lane and the rows' composition, per configuration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    y = np.arange(len(names))
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.5 * len(names) + 1.5), sharey=True)
    for j, role in enumerate(ROLES):
        axes[0].barh(
            y + (j - 1) * 0.27, [results[n]["cars_that_matter"][role]["miss_rate"] for n in names], 0.27, label=role
        )
    axes[0].set_xlabel("miss rate of the nearest car ahead")
    axes[0].set_xlim(0, 1)
    axes[0].legend(fontsize=8)
    left = np.zeros(len(names))
    for key, colour in (("car", "tab:green"), ("clutter", "tab:orange"), ("empty", "lightgrey")):
        v = np.array([results[n]["rows_mean"][key] for n in names])
        axes[1].barh(y, v, left=left, color=colour, label=key)
        left += v
    axes[1].set_xlabel("agent's non-ego rows (mean)")
    axes[1].legend(fontsize=8)
    axes[0].set_yticks(y, names, fontsize=8)
    axes[0].invert_yaxis()
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))


def _write(path: Path, text: str, force: bool) -> None:
    if path.exists() and not force:
        sys.exit(f"{path}: exists (use --force)")
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--policy", nargs="+", choices=("random", "idle", "lane"), default=["random", "idle"])
    ap.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=list(CONFIGS))
    ap.add_argument("--json", type=Path)
    ap.add_argument("--md", type=Path)
    ap.add_argument("--plot", type=Path)
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args()
    for p in (a.json, a.md, a.plot):
        if p is not None and p.exists() and not a.force:
            sys.exit(f"{p}: exists (use --force)")
    t0 = time.perf_counter()
    by_policy: dict[str, dict[str, dict[str, Any]]] = {}
    for policy in a.policy:
        results = by_policy.setdefault(policy, {})
        for name in a.configs:
            t1 = time.perf_counter()
            results[name] = summarise(run_config(name, CONFIGS[name], a.episodes, a.seed, policy))
            print(f"stage: {policy}, {name}: {time.perf_counter() - t1:.0f} s", file=sys.stderr, flush=True)
    seconds = time.perf_counter() - t0
    command = "python benchmarks/highway_observation_report.py " + " ".join(sys.argv[1:])
    print(json.dumps(by_policy, indent=1))
    if a.json:
        doc = {"command": command, "seconds": seconds, "results": by_policy}
        _write(a.json, json.dumps(doc, indent=1), a.force)
    plots = {}
    if a.plot:
        for policy, results in by_policy.items():
            path = a.plot if policy == a.policy[0] else a.plot.with_name(f"{a.plot.stem}_{policy}{a.plot.suffix}")
            plot(results, path)
            plots[policy] = path.name
    if a.md:
        _write(a.md, markdown(by_policy, command, seconds, plots), a.force)


if __name__ == "__main__":
    main()
