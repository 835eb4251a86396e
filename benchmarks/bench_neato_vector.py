"""Steps/s of N Neato robots: gymnasium's SyncVectorEnv over N single envs vs the vector entry point.

Run: python benchmarks/bench_neato_vector.py [--lidars ideal gaussian learned] [--sizes 1 8 64] [--steps 20000]
     python benchmarks/bench_neato_vector.py --breakdown [--lidars learned]   # us per part of one N = 64 step

A "step" is one robot-step (a vector step of N robots counts N). Random actions (seeded), autoreset on;
both modes in one process, alternating run by run; rates by wall clock and by CPU time (steadier when other
jobs share the cores), the median of ``--repeats`` timed runs per mode. The speed-up is the median over the
repeats of each pair's ratio (a sync run and the vector run right after it see the same machine; this
machine's speed drifts by tens of percent over minutes), with the lowest and highest pair ratio beside it.
Goal of issue 14: the vector entry point >= 10x SyncVectorEnv at N = 64.
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np

import sensor_envs  # noqa: F401
from sensor_envs.heap import keep_freed_heap


def robot_steps_per_second(lidar: str, n: int, robot_steps: int, repeats: int) -> dict[str, dict[str, list[float]]]:
    """Robot-steps/s of each mode in each repeat, by wall clock and by this process's CPU time.

    The two modes alternate run by run (sync, vector, sync, ...), so both see the same machine load; the CPU-time
    rate is the steadier one on a shared machine (both modes are single-threaded).
    """
    modes = ("sync", "vector_entry_point")
    envs = {m: gym.make_vec("sensor_envs/Neato-v0", num_envs=n, vectorization_mode=m, lidar=lidar) for m in modes}
    n_steps = max(1, robot_steps // n)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(n_steps, n, 2)).astype(np.float32)
    rates: dict[str, dict[str, list[float]]] = {m: {"wall": [], "cpu": []} for m in modes}
    for m in modes:  # warm-up (first calls, compiled kernels)
        envs[m].reset(seed=0)
        envs[m].step(actions[0])
    for _ in range(repeats):
        for m in modes:
            env = envs[m]
            env.reset(seed=0)
            w0, c0 = time.perf_counter(), time.process_time()
            for a in actions:
                env.step(a)
            rates[m]["wall"].append(n_steps * n / (time.perf_counter() - w0))
            rates[m]["cpu"].append(n_steps * n / (time.process_time() - c0))
    for env in envs.values():
        env.close()
    return rates


def step_breakdown(lidar: str, n: int = 64, calls: int = 1000) -> dict[str, float]:
    """Microseconds per call of each part of one vector step of ``n`` robots (median of 5 blocks of ``calls``).

    The parts are called on the robots' poses after a seeded reset, as :func:`~sensor_envs.envs.neato.observe_batch`
    calls them: the raycast (and, alone, the arccos of its incidences), the lidar's readings (for the learned
    lidar also its uniform and normal draws and, alone, the three compiled passes and numpy's exp of
    :meth:`~sensor_envs.lidar.lwlr.LidarLWLR.sample_scan`), the observation pass, the whole ``observe_batch`` and
    the whole ``step``.
    """
    from sensor_envs.envs.neato import finish_observation, measure_rows, observe_batch
    from sensor_envs.geometry import raycast_pose, to_frame, wrap_angle
    from sensor_envs.rng import compiled
    from sensor_envs.trig import acos_unit

    venv = gym.make_vec("sensor_envs/Neato-v0", num_envs=n, vectorization_mode="vector_entry_point", lidar=lidar)
    u = venv.unwrapped
    u.reset(seed=0)
    env, pose, goal, rngs = u.envs[0], u._pose.copy(), u._goal.copy(), u._rngs
    segs, box = env.world_map.segments, env.observation_space
    hit = np.zeros(n, dtype=bool)
    nom, inc, _ = raycast_pose(pose, env.bearings, segs, env.max_range)
    raw = measure_rows(env.lidar, nom, inc, rngs)
    goal_rel, dth = to_frame(goal[:, :2], pose.T), wrap_angle(goal[:, 2] - pose[:, 2])
    cosines = np.cos(np.nan_to_num(inc))  # values in [0, 1], as the raycast's arguments of acos
    parts = {
        "raycast": lambda: raycast_pose(pose, env.bearings, segs, env.max_range),
        "  of it: arccos of the incidences (trig.acos_unit)": lambda: acos_unit(cosines),
        "lidar readings": lambda: measure_rows(env.lidar, nom, inc, rngs),
        "observation pass": lambda: finish_observation(
            raw, inc, goal_rel, dth, box.low, box.high, env.max_range, env.null_value
        ),
        "observe_batch (all of the above)": lambda: observe_batch(env, pose, goal, rngs, hit),
        "step": lambda: u.step(np.zeros((n, 2), dtype=np.float32)),
    }
    model = getattr(env.lidar, "model", None)
    if model is not None:
        from sensor_envs.lidar import scan_sampler

        passes = (
            compiled(scan_sampler.scan_nodes),
            compiled(scan_sampler.scan_gather),
            compiled(scan_sampler.scan_readings),
        )
        uu, zz = rngs.random(nom.shape), rngs.standard_normal(nom.shape)
        parts["  of it: uniform draws"] = lambda: rngs.random(nom.shape)
        parts["  of it: normal draws"] = lambda: rngs.standard_normal(nom.shape)
        if None not in passes:
            nodes, gather, readings = passes
            cells, grid, draw, _ = scan_sampler.scan_constants(model)
            node = np.empty(nom.shape, dtype=np.int64)
            wr, wa, rq, v0, v1, v2, v3 = (np.empty(nom.shape) for _ in range(7))
            parts["  of it: pass 1, nodes and weights (compiled)"] = lambda: nodes(*grid, nom, inc, node, wr, wa, rq)
            parts["  of it: pass 2, table reads (compiled)"] = lambda: gather(
                cells.ravel(), 4 * grid[1], node, wr, wa, v0, v1, v2, v3
            )
            parts["  of it: exp of the log-scales (numpy)"] = lambda: np.exp(v2)
            parts["  of it: pass 3, the draw (compiled)"] = lambda: readings(
                v0, v1, v2, v3, rq, grid[4], uu, zz, *draw, np.nan, np.empty_like(rq)
            )
    out = {}
    for name, f in parts.items():
        f()
        blocks = []
        for _ in range(5):
            t = time.perf_counter()
            for _ in range(calls):
                f()
            blocks.append((time.perf_counter() - t) / calls * 1e6)
        out[name] = float(np.median(blocks))
    venv.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lidars", nargs="+", default=["ideal", "gaussian", "learned"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[1, 8, 64])
    parser.add_argument("--steps", type=int, default=20000, help="robot-steps per timed run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--breakdown", action="store_true", help="us per part of one N = 64 vector step instead")
    args = parser.parse_args()
    keep_freed_heap()  # opt-in since issue 40; the published figures were measured with it (both modes)
    if args.breakdown:
        for lidar in args.lidars:
            parts = step_breakdown(lidar)
            print(f"\n{lidar} lidar, one vector step of 64 robots (23,040 rays), us per call, median of 5 x 1000:")
            print("| part | us |\n|---|---:|")
            for name, us in parts.items():
                print(f"| {name} | {us:,.0f} |")
        return
    print(f"Neato-v0 robot-steps/s, {args.steps} robot-steps per run, median of {args.repeats}")
    print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    print(
        "| lidar | N | SyncVectorEnv (wall) | vector_entry_point (wall) | speed-up (wall, pair ratios: median "
        "[min, max]) | speed-up (CPU time, median pair ratio) |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for lidar in args.lidars:
        for n in args.sizes:
            r = robot_steps_per_second(lidar, n, args.steps, args.repeats)
            sync, vec = r["sync"], r["vector_entry_point"]
            wall = np.array(vec["wall"]) / np.array(sync["wall"])
            cpu = np.array(vec["cpu"]) / np.array(sync["cpu"])
            print(
                f"| {lidar} | {n} | {np.median(sync['wall']):,.0f} | {np.median(vec['wall']):,.0f} "
                f"| {np.median(wall):.1f}x [{wall.min():.1f}, {wall.max():.1f}] | {np.median(cpu):.1f}x |",
                flush=True,
            )
    print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
