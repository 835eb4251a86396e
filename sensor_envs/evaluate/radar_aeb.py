"""A forward-collision warning (FCW/AEB trigger) and a multi-object tracker driven by each highway radar.

Seeded episodes of ``sensor_envs/HighwayFast-v0`` are driven by an open-loop random policy that does
not look at the radar (``FASTER`` half of the time, so that the ego closes on traffic and crashes
happen), hence every radar sees the same traffic; only the radar's output differs.

* **Tracker**: nearest-neighbour association (greedy, gate ``gate`` [m]; ``gate_init`` for tracks with
  one hit, whose velocity is then set from the two points) of the radar's world-frame detections
  (targets and clutter) to tracks with an alpha-beta filter (position, velocity); a track is
  confirmed after 2 hits and dropped after 2 misses. Scored per step by GOSPA (``c = 5 m``,
  ``p = 2``, ``alpha = 2``) between confirmed tracks and the true reference points of the visible
  targets; lower is better.
* **Warning** (FCW): a confirmed track ahead in the ego's lane (``0 < x``, ``|y| <= lane_half``, sensor
  frame) whose time to collision ``x / closing speed`` (closing speed from the track and the ego's
  velocity) is below ``ttc`` [s]. **Truth**: the same rule on the true targets (reference points and
  velocities). Per step: warning & truth = hit, warning only = false alarm, truth only = missed.
* **Lead time** of an episode with a truth event: first truth step minus first warning step within
  ``lead_window`` steps before it (policy steps of 1 s; positive = early); missing when no warning.

P/R come with Wilson 95 % intervals. There is no real reference in highway-env: the report compares the
radars with each other (the ideal radar is the reference of what a perfect sensor would give).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from tqdm.auto import tqdm

from sensor_envs.evaluate.metrics import precision_recall, wilson_interval
from sensor_envs.outputs import write_json
from sensor_envs.radar.sensors import RADAR_NAMES

__all__ = ["NNTracker", "gospa", "aeb_experiment", "write_aeb_report"]


def gospa(x: NDArray[np.float64], y: NDArray[np.float64], c: float = 5.0, p: float = 2.0) -> float:
    """GOSPA distance (``alpha = 2``) between point sets ``x (n, 2)`` and ``y (m, 2)`` [m].

    ``(sum of assigned d^p (d capped at c) + c^p / 2 * unassigned)^(1/p)``.
    """
    n, m = len(x), len(y)
    if n == 0 or m == 0:
        return float((c**p / 2 * (n + m)) ** (1 / p))
    d = np.minimum(np.linalg.norm(x[:, None] - y[None], axis=2), c) ** p
    r, k = linear_sum_assignment(d)
    cost = d[r, k]
    real = cost < c**p  # pairs at the cut-off count as one miss + one false track
    total = cost[real].sum() + c**p / 2 * (n + m - 2 * int(real.sum()))
    return float(total ** (1 / p))


class NNTracker:
    """Nearest-neighbour alpha-beta tracker in the world frame (see the module docstring)."""

    def __init__(
        self, dt: float = 1.0, gate: float = 4.0, gate_init: float = 12.0, alpha: float = 0.6, beta: float = 0.3
    ) -> None:
        self.dt, self.gate, self.gate_init, self.alpha, self.beta = dt, gate, gate_init, alpha, beta
        self.x = np.zeros((0, 2))
        self.v = np.zeros((0, 2))
        self.hits = np.zeros(0, dtype=int)
        self.misses = np.zeros(0, dtype=int)

    def step(self, z: NDArray[np.float64], v0: NDArray[np.float64]) -> None:
        """Predict, associate detections ``z (k, 2)`` [m], update; new tracks start at velocity ``v0`` [m/s]."""
        pred = self.x + self.v * self.dt
        used = np.zeros(len(z), dtype=bool)
        hit = np.zeros(len(pred), dtype=bool)
        if len(pred) and len(z):
            d = np.linalg.norm(pred[:, None] - z[None], axis=2)
            tentative = self.hits < 2
            gate = np.where(tentative, self.gate_init, self.gate)
            for flat in np.argsort(d, axis=None):  # greedy nearest pairs first
                i, j = divmod(int(flat), len(z))
                if d[i, j] > self.gate_init:
                    break
                if hit[i] or used[j] or d[i, j] > gate[i]:
                    continue
                hit[i], used[j] = True, True
                if tentative[i]:  # two-point initialisation of the velocity
                    self.v[i] = (z[j] - self.x[i]) / self.dt
                    pred[i] = z[j]
                else:
                    r = z[j] - pred[i]
                    pred[i] = pred[i] + self.alpha * r
                    self.v[i] = self.v[i] + self.beta * r / self.dt
        self.x = pred
        self.hits = np.where(hit, self.hits + 1, self.hits)
        self.misses = np.where(hit, 0, self.misses + 1)
        keep = self.misses < 2
        new = z[~used]
        self.x = np.concatenate([self.x[keep], new])
        self.v = np.concatenate([self.v[keep], np.tile(v0, (len(new), 1))])
        self.hits = np.concatenate([self.hits[keep], np.ones(len(new), dtype=int)])
        self.misses = np.concatenate([self.misses[keep], np.zeros(len(new), dtype=int)])

    @property
    def confirmed(self) -> NDArray[np.bool_]:
        """``(n_tracks,)`` tracks with at least 2 hits."""
        return self.hits >= 2


def _to_sensor(xy: NDArray[np.float64], pose: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = xy - pose[:2]
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def _critical(pos_s: NDArray, vel_w: NDArray, ego_v: NDArray, yaw: float, lane_half: float, ttc: float) -> bool:
    """Whether any object (sensor-frame position, world velocity) is ahead in lane with time to collision < ``ttc``."""
    if not len(pos_s):
        return False
    fwd = np.array([np.cos(yaw), np.sin(yaw)])
    closing = (ego_v - vel_w) @ fwd
    ahead = (pos_s[:, 0] > 0) & (np.abs(pos_s[:, 1]) <= lane_half) & (closing > 0.1)
    return bool(np.any(ahead & (pos_s[:, 0] / np.maximum(closing, 1e-6) < ttc)))


def run_episodes(
    radar: str, episodes: int, max_steps: int, seed: int, ttc: float = 3.0, lane_half: float = 1.5
) -> list[dict[str, Any]]:
    """Per episode: lists of per-step ``warn``, ``truth``, ``gospa`` and whether it crashed."""
    import gymnasium as gym

    import sensor_envs  # noqa: F401  (registers the ids)

    env = gym.make("sensor_envs/HighwayFast-v0", radar=radar)
    out = []
    for ep in range(episodes):  # one seeded episode per iteration
        env.reset(seed=seed + ep)
        policy = np.random.default_rng([seed, ep])
        trk = NNTracker()
        rec: dict[str, Any] = {"warn": [], "truth": [], "gospa": [], "crashed": False}
        for _ in range(max_steps):
            u = policy.random()
            action = 3 if u < 0.5 else 1 if u < 0.8 else (0 if u < 0.9 else 2)
            _, _, term, trunc, info = env.step(action)
            ri = info["radar"]
            base: Any = env.unwrapped
            ego = base.vehicle
            ego_v = np.asarray(ego.velocity, dtype=float)
            pose = ri.sensor_pose
            trk.step(ri.detections_world, ego_v)
            conf = trk.confirmed
            tr_s = _to_sensor(trk.x[conf], pose)
            rec["warn"].append(_critical(tr_s, trk.v[conf], ego_v, pose[2], lane_half, ttc))
            rec["truth"].append(_critical(ri.truth_reference, ri.truth_velocity, ego_v, pose[2], lane_half, ttc))
            vis = ri.visible
            truth_w = ri.truth_reference[vis]
            c, s = np.cos(pose[2]), np.sin(pose[2])
            truth_w = truth_w @ np.array([[c, s], [-s, c]]) + pose[:2]
            rec["gospa"].append(gospa(trk.x[conf], truth_w))
            if term or trunc:
                rec["crashed"] = bool(info.get("crashed", False))
                break
        out.append(rec)
    env.close()
    return out


def summarise_radar(eps: list[dict[str, Any]], lead_window: int = 5) -> dict[str, Any]:
    """Hits, false alarms, missed warnings, P/R with Wilson intervals, lead times, GOSPA of one radar."""
    w = np.concatenate([np.asarray(e["warn"], bool) for e in eps])
    t = np.concatenate([np.asarray(e["truth"], bool) for e in eps])
    tp, fp, fn = int((w & t).sum()), int((w & ~t).sum()), int((~w & t).sum())
    p, r = precision_recall(tp, fp, fn)
    leads, events, missed_events = [], 0, 0
    for e in eps:
        tt, ww = np.asarray(e["truth"], bool), np.asarray(e["warn"], bool)
        if not tt.any():
            continue
        events += 1
        k = int(np.argmax(tt))
        early = np.flatnonzero(ww[max(0, k - lead_window) : k + 1])
        if early.size:
            leads.append(float(k - (max(0, k - lead_window) + early[0])))
        else:
            missed_events += 1
    g = np.concatenate([np.asarray(e["gospa"], float) for e in eps])
    return {
        "steps": int(len(w)),
        "truth_steps": int(t.sum()),
        "warnings": int(w.sum()),
        "hits": tp,
        "false_alarms": fp,
        "missed_warnings": fn,
        "precision": round(p, 4),
        "precision_ci95": [round(v, 4) for v in wilson_interval(tp, tp + fp)],
        "recall": round(r, 4),
        "recall_ci95": [round(v, 4) for v in wilson_interval(tp, tp + fn)],
        "episodes_with_event": events,
        "events_without_warning": missed_events,
        "mean_lead_time_s": round(float(np.mean(leads)), 3) if leads else None,
        "crashes": int(sum(e["crashed"] for e in eps)),
        "mean_gospa_m": round(float(g.mean()), 3),
    }


def aeb_experiment(
    episodes: int = 30, max_steps: int = 40, seed: int = 0, radars: tuple[str, ...] = RADAR_NAMES, ttc: float = 3.0
) -> dict[str, Any]:
    """FCW and tracker metrics per radar over the same seeded episodes (see the module docstring)."""
    per = {}
    for radar in tqdm(radars, desc="radars (AEB episodes)"):
        per[radar] = summarise_radar(run_episodes(radar, episodes, max_steps, seed, ttc=ttc))
    ref = per.get("ideal")
    dist = {}
    if ref is not None:
        for k, v in per.items():
            if k != "ideal":
                dist[k] = round(float(np.hypot(v["precision"] - ref["precision"], v["recall"] - ref["recall"])), 4)
    return {
        "experiment": "forward-collision warning and NN tracker on highway-fast, per radar",
        "episodes": episodes,
        "max_steps": max_steps,
        "seed": seed,
        "ttc_s": ttc,
        "radars": per,
        "distance_to_ideal": dist,
        "note": "no real reference in highway-env: distances are to the ideal radar's (P, R), not to reality",
    }


def write_aeb_report(report: dict[str, Any], folder: Path) -> None:
    """``report.json``, ``report.md`` and ``aeb.png`` (P/R with Wilson intervals per radar) into ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    write_json(folder / "report.json", report)
    rows = [
        "| radar | warnings | hits | false alarms | missed | precision [95 % CI] | recall [95 % CI] "
        "| lead time [s] | GOSPA [m] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for k, v in report["radars"].items():
        rows.append(
            f"| {k} | {v['warnings']} | {v['hits']} | {v['false_alarms']} | {v['missed_warnings']} | "
            f"{v['precision']:.3f} [{v['precision_ci95'][0]:.3f}, {v['precision_ci95'][1]:.3f}] | "
            f"{v['recall']:.3f} [{v['recall_ci95'][0]:.3f}, {v['recall_ci95'][1]:.3f}] | "
            f"{v['mean_lead_time_s']} | {v['mean_gospa_m']} |"
        )
    md = [
        f"# {report['experiment']}",
        "",
        f"Command: `{report.get('command', '')}`",
        "",
        *rows,
        "",
        f"Distance of (P, R) to the ideal radar's: {report['distance_to_ideal']}",
        "",
        report["note"],
        "",
    ]
    (folder / "report.md").write_text("\n".join(md))
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    for k, v in report["radars"].items():
        ax.errorbar(
            v["recall"],
            v["precision"],
            xerr=[[v["recall"] - v["recall_ci95"][0]], [v["recall_ci95"][1] - v["recall"]]],
            yerr=[[v["precision"] - v["precision_ci95"][0]], [v["precision_ci95"][1] - v["precision"]]],
            marker="o",
            capsize=3,
            label=k,
        )
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall (warning when needed)")
    ax.set_ylabel("precision (warning was needed)")
    ax.set_title("FCW on highway-fast per radar (95 % Wilson intervals)", fontsize=9)
    ax.legend()
    fig.savefig(folder / "aeb.png", dpi=120, bbox_inches="tight")
    plt.close(fig)
