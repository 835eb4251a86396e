"""PPO training throughput on Neato-v0: SB3 DummyVecEnv of single envs vs the vector entry point (vec_env: vector).

Run: python benchmarks/bench_train_vector.py [--sizes 4 16] [--lidar learned] [--timesteps 16384] [--repeats 2]

Each run builds the training env exactly as ``sensor-envs train`` does (``make_env`` with ``vec_env: dummy`` or
``vector``) with the default config's Neato PPO hyperparameters (n_steps 512, batch 256, 10 epochs), on the CPU
with ``torch.set_num_threads(1)``, and times ``model.learn(total_timesteps)`` (no callbacks): env steps/s by
wall clock and by this process's CPU time (``time.process_time``, steadier on a shared machine), and the share
of the learn time spent collecting rollouts (env steps + policy forward passes; the rest is the PPO update).
Median of ``--repeats`` runs per cell; the two modes alternate run by run, so both see the same load.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from sensor_envs.heap import keep_freed_heap

ID = "sensor_envs/Neato-v0"


class RolloutTimer(BaseCallback):
    """Wall time spent collecting rollouts (between SB3's rollout start and end hooks)."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds, self._t0 = 0.0, 0.0

    def _on_rollout_start(self) -> None:
        self._t0 = time.perf_counter()

    def _on_rollout_end(self) -> None:
        self.seconds += time.perf_counter() - self._t0

    def _on_step(self) -> bool:
        return True


def one_run(train: Any, mode: str, n_envs: int, lidar: str, timesteps: int, seed: int) -> dict[str, float]:
    """Train PPO for ``timesteps`` env steps; steps/s by wall and CPU time, and the rollout share of the wall time."""
    cfg = train.load_config(
        train.DEFAULT_CONFIG, ID, [f"vec_env={mode}", f"n_envs={n_envs}"], sensor=lidar
    )  # default config: map seed_room, PPO hyperparameters
    venv = train.make_env(ID, cfg, n_envs, seed)
    model = PPO(cfg["policy"], venv, seed=seed, device="cpu", verbose=0, **cfg["hyperparams"])
    timer = RolloutTimer()
    w0, c0 = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=timesteps, callback=timer)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    steps = model.num_timesteps
    venv.close()
    return {"wall": steps / wall, "cpu": steps / cpu, "rollout": timer.seconds / wall, "steps": steps}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=int, default=[4, 16], help="n_envs")
    parser.add_argument("--lidar", default="learned")
    parser.add_argument("--timesteps", type=int, default=16384, help="env steps per run (PPO rounds up to rollouts)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    keep_freed_heap()  # opt-in since issue 40; the published figures were measured with it (both modes)
    torch.set_num_threads(1)
    from sensor_envs.training import train

    modes = ("dummy", "vector")
    print(
        f"PPO on {ID} (lidar={args.lidar}), {args.timesteps} env steps per run, median of {args.repeats}, CPU, 1 thread"
    )
    print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores\n")
    rows = []
    for n in args.sizes:
        runs: dict[str, list[dict[str, float]]] = {m: [] for m in modes}
        for _ in range(args.repeats):
            for m in modes:
                runs[m].append(one_run(train, m, n, args.lidar, args.timesteps, args.seed))
        med = {m: {k: float(np.median([r[k] for r in runs[m]])) for k in ("wall", "cpu", "rollout")} for m in modes}
        rows.append((n, med))
    print(
        "| n_envs | vec_env | env steps/s (wall) | env steps/s (CPU time) | rollout share | vector/dummy (wall, CPU) |"
    )
    print("|---:|---|---:|---:|---:|---:|")
    for n, med in rows:
        for m in modes:
            ratio = ""
            if m == "vector":
                wall, cpu = (med["vector"][k] / med["dummy"][k] for k in ("wall", "cpu"))
                ratio = f"{wall:.2f}x, {cpu:.2f}x"
            print(f"| {n} | {m} | {med[m]['wall']:,.0f} | {med[m]['cpu']:,.0f} | {med[m]['rollout']:.0%} | {ratio} |")
    print(f"\nload average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
