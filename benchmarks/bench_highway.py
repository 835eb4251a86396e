"""Steps/s of highway-fast-v0 with highway-env's ideal Kinematics vs each radar, in one run.

    python benchmarks/bench_highway.py [--steps 150] [--repeats 5] [--seed 0]

Prints, per configuration, the median over repeats (configurations interleaved within each repeat,
so machine drift hits all alike) of: steps/s, ms per step, ms per step spent computing the
observation (highway-env's ``KinematicObservation.observe`` for the baseline; the radar wrapper's
whole sensing + observation building for the radars), the part of it spent inside the radar model
(``sample_cycle`` + ``sample_clutter``; the rest is the wrapper: truth, field of view, occlusion,
tracks, layout), and the step-time ratio to the baseline.
The radar wrapper replaces highway-env's observation (it is not computed twice), so a ratio near
or below 1 is expected; the sensor-only time against the baseline step is the figure to gate on.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np

import sensor_envs  # noqa: F401
from sensor_envs.envs.highway import RadarObservation
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


def run_once(make: Callable[[], gym.Env], steps: int, seed: int) -> tuple[float, float, float]:
    """Return seconds per step, of observation per step and of radar model per step over ``steps`` steps."""
    env = make()
    obs_times: list[float] = []
    model_times: list[float] = []
    radar = _find_radar(env)
    if radar is not None:
        radar._observe = _timed(radar._observe, obs_times)  # the hook installed at reset calls this
        radar.radar = _TimedModel(radar.radar, model_times)  # this instance only (models are shared)

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
        if term or trunc:
            reset()
    total = time.perf_counter() - t0
    env.close()
    return total / steps, float(np.sum(obs_times)) / steps, float(np.sum(model_times)) / steps


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    configs: dict[str, Callable[[], gym.Env]] = {"kinematics (highway-env)": lambda: gym.make("highway-fast-v0")}
    for r in RADARS:
        configs[f"radar={r}"] = lambda r=r: gym.make("sensor_envs/HighwayFast-v0", radar=r)
    results: dict[str, list[tuple[float, float, float]]] = {k: [] for k in configs}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for make in configs.values():  # warm-up: imports, model loading (cached per process)
            run_once(make, 5, args.seed)
        for rep in range(args.repeats):
            for k, make in configs.items():
                results[k].append(run_once(make, args.steps, args.seed + rep))
    base_step = np.median([r[0] for r in results["kinematics (highway-env)"]])
    print(f"highway-fast-v0, {args.steps} steps x {args.repeats} repeats (medians), seed {args.seed}")
    print(
        f"{'configuration':<26}{'steps/s':>9}{'ms/step':>9}{'obs ms/step':>13}{'model ms':>10}{'step ratio':>12}"
        f"{'obs % of base step':>20}{'wrapper %':>11}"
    )
    for k, res in results.items():
        step, obs, model = (float(np.median([r[i] for r in res])) for i in range(3))
        radar = k.startswith("radar=")
        model_col = f"{model * 1e3:>10.3f}" if radar else f"{'-':>10}"
        wrapper_col = f"{100 * (obs - model) / base_step:>10.1f}%" if radar else f"{'-':>11}"
        print(
            f"{k:<26}{1 / step:>9.1f}{step * 1e3:>9.2f}{obs * 1e3:>13.3f}{model_col}"
            f"{step / base_step:>12.3f}{100 * obs / base_step:>19.1f}%{wrapper_col}"
        )


if __name__ == "__main__":
    main()
