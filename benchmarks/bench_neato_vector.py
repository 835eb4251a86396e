"""Steps/s of N Neato robots: gymnasium's SyncVectorEnv over N single envs vs the vector entry point.

Run: python benchmarks/bench_neato_vector.py [--lidars ideal gaussian learned] [--sizes 1 8 64] [--steps 20000]

A "step" is one robot-step (a vector step of N robots counts N). Random actions (seeded), autoreset on;
median of ``--repeats`` timed runs per cell, both modes measured in one process, one after the other.
Goal of issue 14: the vector entry point >= 10x SyncVectorEnv at N = 64.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import sensor_envs  # noqa: F401


def robot_steps_per_second(mode: str, lidar: str, n: int, robot_steps: int, repeats: int) -> float:
    env = gym.make_vec("sensor_envs/Neato-v0", num_envs=n, vectorization_mode=mode, lidar=lidar)
    n_steps = max(1, robot_steps // n)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(n_steps, n, 2)).astype(np.float32)
    rates = []
    for _ in range(repeats):
        env.reset(seed=0)
        t0 = time.perf_counter()
        for a in actions:
            env.step(a)
        rates.append(n_steps * n / (time.perf_counter() - t0))
    env.close()
    return float(np.median(rates))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lidars", nargs="+", default=["ideal", "gaussian", "learned"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[1, 8, 64])
    parser.add_argument("--steps", type=int, default=20000, help="robot-steps per timed run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"Neato-v0 robot-steps/s, {args.steps} robot-steps per run, median of {args.repeats}")
    print("| lidar | N | SyncVectorEnv | vector_entry_point | speed-up |")
    print("|---|---:|---:|---:|---:|")
    for lidar in args.lidars:
        for n in args.sizes:
            sync = robot_steps_per_second("sync", lidar, n, args.steps, args.repeats)
            vec = robot_steps_per_second("vector_entry_point", lidar, n, args.steps, args.repeats)
            print(f"| {lidar} | {n} | {sync:,.0f} | {vec:,.0f} | {vec / sync:.1f}x |", flush=True)


if __name__ == "__main__":
    main()
