"""Steps/s of highway-fast-v0 with highway-env's ideal Kinematics vs each radar, in one run.

    python benchmarks/bench_highway.py [--steps 150] [--repeats 5] [--seed 0] [--model KDE.npz ...]

Prints, per configuration, the median over repeats (configurations interleaved within each repeat,
so machine drift hits all alike) of: steps/s, ms per step, ms per step spent computing the
observation (highway-env's ``KinematicObservation.observe`` for the baseline; the radar wrapper's
whole sensing + observation building for the radars), the part of it spent inside the radar model
(``sample_cycle`` + ``sample_clutter``; the rest is the wrapper: truth, field of view, occlusion,
tracks, layout), and the step-time ratio to the baseline.
The radar wrapper replaces highway-env's observation (it is not computed twice), so a ratio near
or below 1 is expected; the sensor-only time against the baseline step is the figure to gate on.

Radar rate rows (``--no-rate`` skips them): the same world at ``simulation_frequency`` 15 Hz
(highway-v0's, 66.7 ms sub-steps; highway-fast-v0 itself simulates at 5 Hz), with its own
Kinematics baseline, the shipped 1 s KDE at ``radar_rate="policy"`` and the shipped
``radar_kde_fast.npz`` (cycle time 1/15 s) at ``radar_rate="simulation"``: 15 radar cycles per
policy step. Their ratios are to the 15 Hz baseline; "obs" then includes every cycle's sensing.

Observation option rows: ``tracks=True`` (the multi-target tracker, its own time per policy step in the
"tracker ms" column, goal < 2 ms, and the mean number of live tracks, tentative included),
``tracks=True, stationary="drop"`` and ``history=4``. The last line times filterpy's ``predict`` +
``update`` on one 4-state filter and multiplies by the live-track count: what a per-track filterpy
loop would cost instead of the batched numpy filter.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np

import sensor_envs  # noqa: F401
from sensor_envs.envs.highway import RadarObservation
from sensor_envs.modelio import ModelFileError, default_model_path
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.sensors import RADAR_NAMES as RADARS


def _timed(fn: Callable, sink: list[float]) -> Callable:
    def run(*args, **kwargs):
        t = time.perf_counter()
        out = fn(*args, **kwargs)
        sink.append(time.perf_counter() - t)
        return out

    return run


class _TimedModel:
    """Delegates to a radar model, adding the time spent in its sampling methods to ``sink``."""

    def __init__(self, model, sink: list[float]) -> None:
        self.model = model
        self.sample_cycle = _timed(model.sample_cycle, sink)
        self.sample_clutter = _timed(model.sample_clutter, sink)


def _find_radar(env: gym.Env) -> RadarObservation | None:
    while isinstance(env, gym.Wrapper):
        if isinstance(env, RadarObservation):
            return env
        env = env.env
    return None


def run_once(make: Callable[[], gym.Env], steps: int, seed: int) -> tuple[float, float, float, float, float]:
    """Seconds per step, of observation, of radar model and of tracker per step; mean live tracks."""
    env = make()
    obs_times: list[float] = []
    model_times: list[float] = []
    tracker_times: list[float] = []
    live: list[int] = []
    radar = _find_radar(env)
    if radar is not None:  # the hooks installed at reset call these (per policy step / per sub-step)
        radar._on_observe = _timed(radar._on_observe, obs_times)
        radar._cycle = _timed(radar._cycle, obs_times)
        radar.radar = _TimedModel(radar.radar, model_times)  # this instance only (models are shared)
        if radar.tracker is not None:
            radar.tracker.step = _timed(radar.tracker.step, tracker_times)

    def reset(s=None):
        env.reset(seed=s)
        if radar is None:
            ot = env.unwrapped.observation_type
            ot.observe = _timed(ot.observe, obs_times)

    reset(seed)
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, env.action_space.n, steps)
    obs_times.clear()
    model_times.clear()
    t0 = time.perf_counter()
    for a in actions:
        _, _, term, trunc, _ = env.step(int(a))
        if radar is not None and radar.tracker is not None:
            live.append(len(radar.tracker))
        if term or trunc:
            reset()
    total = time.perf_counter() - t0
    env.close()
    per = (float(np.sum(x)) / steps for x in (obs_times, model_times, tracker_times))
    return (total / steps, *per, float(np.mean(live)) if live else 0.0)  # type: ignore[return-value]


def filterpy_seconds_per_track() -> float:
    """Median seconds of filterpy's ``predict`` + ``update`` on one constant-velocity 4-state filter."""
    from filterpy.kalman import predict, update

    x, P, F, Q = np.zeros(4), np.eye(4), np.eye(4), 0.1 * np.eye(4)
    F[0, 2] = F[1, 3] = 1.0
    H, R, z = np.eye(2, 4), 0.5 * np.eye(2), np.ones(2)
    times = []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(400):
            xp, Pp = predict(x, P, F, Q)
            update(xp, Pp, z, R, H)
        times.append((time.perf_counter() - t) / 400)
    return float(np.median(times))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-rate", action="store_true", help="skip the radar-rate rows (15 Hz world)")
    parser.add_argument(
        "--model",
        nargs="+",
        default=[],
        help="also time these KDE model files at highway-fast-v0 (radar='kde', radar_model=PATH), e.g. one "
        "with extra state variables",
    )
    args = parser.parse_args(argv)
    for path in args.model:  # bad input: one line naming the file, exit 2, before any timing
        try:
            KDERadarModel.load(path)
        except ModelFileError as exc:
            print(exc, file=sys.stderr)
            raise SystemExit(2) from None
    base_name, base15 = "kinematics (highway-env)", "kinematics, sim 15 Hz"
    configs: dict[str, Callable[[], gym.Env]] = {base_name: lambda: gym.make("highway-fast-v0")}
    for r in RADARS:
        configs[f"radar={r}"] = lambda r=r: gym.make("sensor_envs/HighwayFast-v0", radar=r)
    for path in args.model:
        configs[f"kde {Path(path).name}"[:25]] = lambda p=path: gym.make("sensor_envs/HighwayFast-v0", radar="kde",
                                                                        radar_model=p)  # fmt: skip
    if not args.no_rate:
        sim15 = {"simulation_frequency": 15}
        configs[base15] = lambda: gym.make("highway-fast-v0", config=sim15)
        configs["kde, 15 Hz, rate=policy"] = lambda: gym.make("sensor_envs/HighwayFast-v0", radar="kde", config=sim15)
        configs["kde_fast, rate=simulation"] = lambda: gym.make(
            "sensor_envs/HighwayFast-v0",
            radar="kde",
            radar_model=str(default_model_path("radar_kde_fast.npz")),
            radar_rate="simulation",
            config=sim15,
        )
    fast = "sensor_envs/HighwayFast-v0"
    configs["kde, tracks"] = lambda: gym.make(fast, radar="kde", tracks=True)
    configs["kde, tracks, drop"] = lambda: gym.make(fast, radar="kde", tracks=True, stationary="drop")
    configs["kde, clutter=model, tracks"] = lambda: gym.make(fast, radar="kde", tracks=True, clutter="model")
    configs["kde, history=4"] = lambda: gym.make(fast, radar="kde", history=4)
    rate_rows = {base15, "kde, 15 Hz, rate=policy", "kde_fast, rate=simulation"}  # their baseline: 15 Hz
    results: dict[str, list[tuple[float, float, float, float, float]]] = {k: [] for k in configs}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for make in configs.values():  # warm-up: imports, model loading (cached per process)
            run_once(make, 5, args.seed)
        for rep in range(args.repeats):
            for k, make in configs.items():
                results[k].append(run_once(make, args.steps, args.seed + rep))
    base_steps = {k: float(np.median([r[0] for r in results[k]])) for k in (base_name, base15) if k in results}
    print(f"highway-fast-v0, {args.steps} steps x {args.repeats} repeats (medians), seed {args.seed}")
    print(
        f"{'configuration':<26}{'steps/s':>9}{'ms/step':>9}{'obs ms/step':>13}{'model ms':>10}{'step ratio':>12}"
        f"{'obs % of base step':>20}{'wrapper %':>11}{'tracker ms':>12}{'live tracks':>13}"
    )
    most_live = 0.0
    for k, res in results.items():
        step, obs, model, trk, live = (float(np.median([r[i] for r in res])) for i in range(5))
        most_live = max(most_live, live)
        radar = not k.startswith("kinematics")
        base_step = base_steps[base15 if k in rate_rows else base_name]
        model_col = f"{model * 1e3:>10.3f}" if radar else f"{'-':>10}"
        wrapper_col = f"{100 * (obs - model) / base_step:>10.1f}%" if radar else f"{'-':>11}"
        print(
            f"{k:<26}{1 / step:>9.1f}{step * 1e3:>9.2f}{obs * 1e3:>13.3f}{model_col}"
            f"{step / base_step:>12.3f}{100 * obs / base_step:>19.1f}%{wrapper_col}"
            + (f"{trk * 1e3:>12.3f}{live:>13.1f}" if live else "")
        )
    per_track = filterpy_seconds_per_track()
    print(
        f"filterpy predict+update: {per_track * 1e6:.1f} us per filter and cycle; a per-track loop at "
        f"{most_live:.0f} live tracks would take {per_track * most_live * 1e3:.2f} ms per policy step"
    )


if __name__ == "__main__":
    main()
