"""Speed of the Neato world: steps/s of Neato-v0 per lidar, and microseconds per 360-ray raycast.

Run: python benchmarks/bench_neato.py [--lidars ideal gaussian learned] [--steps 2000]
Medians of 5 repeats (the machine drifts, so compare figures from one run).
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import sensor_envs  # noqa: F401
from sensor_envs.geometry import as_segments, raycast_pose
from sensor_envs.lidar.sensors import LIDAR_NAMES


def steps_per_second(lidar: str, steps: int, map_name: str) -> float:
    env = gym.make("sensor_envs/Neato-v0", lidar=lidar, map=map_name)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(steps)]
    rates = []
    for _ in range(5):
        env.reset(seed=0)
        t0 = time.perf_counter()
        for a in actions:
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
        rates.append(steps / (time.perf_counter() - t0))
    return float(np.median(rates))


def raycast_us(n_segments: int, repeats: int = 200) -> float:
    rng = np.random.default_rng(0)
    centres = rng.uniform(-4, 4, size=(n_segments, 2))
    ang = rng.uniform(0, np.pi, size=n_segments)
    half = rng.uniform(0.1, 0.6, size=n_segments)[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    segs = as_segments(np.stack([centres - half, centres + half], axis=1))
    bearings = np.deg2rad(np.arange(360.0))
    pose = np.array([0.1, 0.2, 0.3])
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(repeats):
            raycast_pose(pose, bearings, segs, 5.0)
        times.append((time.perf_counter() - t0) / repeats * 1e6)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lidars", nargs="+", default=list(LIDAR_NAMES))
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--map", default="seed_room")
    args = parser.parse_args()
    print(f"Neato-v0 on map {args.map!r}, {args.steps} random-action steps, median of 5:")
    for lidar in args.lidars:
        print(f"  lidar={lidar:<9s} {steps_per_second(lidar, args.steps, args.map):9.0f} steps/s")
    print("360-ray raycast (range + incidence), median of 5 x 200:")
    for m in (5, 50, 500):
        print(f"  {m:4d} segments: {raycast_us(m):9.1f} us per scan")


if __name__ == "__main__":
    main()
