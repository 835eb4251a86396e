"""Steps/s of N Neato robots: gymnasium's SyncVectorEnv over N single envs vs the vector entry point.

Run: python benchmarks/bench_neato_vector.py [--lidars ideal gaussian learned] [--sizes 1 8 64] [--steps 20000]

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lidars", nargs="+", default=["ideal", "gaussian", "learned"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[1, 8, 64])
    parser.add_argument("--steps", type=int, default=20000, help="robot-steps per timed run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
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
