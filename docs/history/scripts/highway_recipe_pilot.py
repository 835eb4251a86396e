"""Pilot a highway-fast training recipe: train one policy, evaluate its best and final checkpoints.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: a DQN pilot on the ideal radar (6,000 steps,
eval every 1,000 on 10 episodes, seed 0, 30 held-out episodes): best checkpoint (4,000 steps) collision 0.10 at 22.2
m/s vs the final model 0.40 at 23.2 m/s, 65 ms per training step under load (`725fcb4`); it set the highway matrix's
6,000-step budget (docs/results/highway_matrix.md).

    python docs/history/scripts/highway_recipe_pilot.py --out runs/pilot_a --sensor ideal --steps 6000 \
        [--algo dqn] [--set eval_freq=1000] [--set eval_episodes=10] [--train-config '{collision_reward: -3}'] \
        [--episodes 30] [--seed 0]

Trains with :func:`sensor_envs.training.train.train` (the shipped config's block for ``--algo``, the
``--sensor`` variant, ``--set`` overrides; ``--train-config`` adds highway-env config overrides to the
TRAINING env only, e.g. a reward setting), then plays ``--episodes`` deterministic episodes of
``best_model.zip`` (EvalCallback's pick on other seeds) and of ``final_model.zip`` on the UNCHANGED
evaluation env of the same sensor with the robustness matrix's evaluation seeds (``EVAL_SEED + e``), and
prints per model: collision rate, mean return, mean ego speed [m/s] over all steps, mean episode length,
and the training cost (seconds, ms per step). Writes ``pilot.json`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml


def play(model: Any, env_id: str, kwargs: dict[str, Any], episodes: int) -> dict[str, float]:
    """Collision rate, mean return, mean speed and mean length of ``episodes`` evaluation episodes."""
    import gymnasium as gym

    from sensor_envs.training.robustness import EVAL_SEED

    env = gym.make(env_id, **kwargs)
    coll, rets, speeds, lengths = [], [], [], []
    for e in range(episodes):
        obs, info = env.reset(seed=EVAL_SEED + e)
        total, n, done = 0.0, 0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, term, trunc, info = env.step(action)
            total += float(reward)
            speeds.append(float(info.get("speed", np.nan)))
            n += 1
            done = term or trunc
        coll.append(float(bool(info.get("crashed", False))))
        rets.append(total)
        lengths.append(n)
    env.close()
    return {
        "collision": float(np.mean(coll)),
        "return": float(np.mean(rets)),
        "speed": float(np.nanmean(speeds)),
        "length": float(np.mean(lengths)),
    }


def main(argv: list[str] | None = None) -> None:
    import stable_baselines3 as sb3
    import torch

    import sensor_envs  # noqa: F401
    from sensor_envs.training import train as train_mod

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--sensor", default="ideal")
    parser.add_argument("--algo", default="dqn")
    parser.add_argument("--steps", type=int, default=6000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--train-config", default=None, help="YAML mapping of highway-env config (training only)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    env_id = "sensor_envs/HighwayFast-v0"
    path = train_mod.DEFAULT_CONFIG
    eval_cfg = train_mod.load_config(path, env_id, [], sensor=args.sensor)
    cfg = train_mod.load_config(
        path, env_id, [f"n_timesteps={args.steps}", *args.set], algo=args.algo, sensor=args.sensor
    )
    cfg["device"] = "cpu"
    if args.train_config:
        cfg["env_kwargs"] = {**cfg["env_kwargs"], "config": yaml.safe_load(args.train_config)}
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    train_mod.train(env_id, cfg, args.out, args.seed, progress_bar=False, tensorboard=False)
    train_s = time.perf_counter() - t0
    algo = getattr(sb3, cfg["algo"].upper())
    result: dict[str, Any] = {
        "sensor": args.sensor,
        "algo": cfg["algo"],
        "steps": args.steps,
        "seed": args.seed,
        "set": args.set,
        "train_config": args.train_config,
        "train_seconds": train_s,
        "ms_per_step": 1000 * train_s / args.steps,
    }
    curve = np.load(args.out / "evaluations.npz")
    result["curve"] = {
        "timesteps": curve["timesteps"].tolist(),
        "return": curve["results"].mean(axis=1).round(2).tolist(),
        "length": curve["ep_lengths"].mean(axis=1).round(1).tolist(),
    }
    for which in ("best_model", "final_model"):
        model = algo.load(args.out / which, device="cpu")
        result[which] = play(model, env_id, dict(eval_cfg["env_kwargs"]), args.episodes)
    (args.out / "pilot.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
