"""Train a stable-baselines3 agent on a sensor_envs env from a YAML config keyed by env id.

    python training/train.py --env sensor_envs/Neato-v0 --out runs/neato [--seed 1] [--set n_timesteps=5000]

Writes into ``--out``: ``config.json`` (the resolved config, the seed and the command line), SB3
checkpoints, ``best_model.zip`` and ``evaluations.npz`` from ``EvalCallback``, ``final_model.zip`` and
``result.json`` (mean and std of the final evaluation return). A seed is drawn and logged when absent.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml
from tqdm import TqdmExperimentalWarning

import sensor_envs  # noqa: F401  (registers the ids)

ALGOS = ("ppo", "sac", "a2c")
KEYS = {"algo", "policy", "n_timesteps", "n_envs", "env_kwargs", "hyperparams", "eval_freq", "eval_episodes"}
DEFAULT_CONFIG = Path(__file__).with_name("configs") / "default.yaml"


def load_config(path: Path, env_id: str, overrides: list[str]) -> dict[str, Any]:
    """The config block of ``env_id`` in ``path`` with ``key=value`` overrides applied; unknown keys are errors."""
    doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    if env_id not in doc:
        raise SystemExit(f"{path}: no config for env id {env_id!r}; known: {sorted(doc)}")
    cfg = dict(doc[env_id])
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: expected key=value")
        cfg[key] = yaml.safe_load(value)
    unknown = set(cfg) - KEYS
    if unknown:
        raise SystemExit(f"{path} [{env_id}]: unknown keys {sorted(unknown)}; expected {sorted(KEYS)}")
    if cfg.get("algo") not in ALGOS:
        raise SystemExit(f"{path} [{env_id}]: algo must be one of {ALGOS}, got {cfg.get('algo')!r}")
    return cfg


def train(env_id: str, cfg: dict[str, Any], out: Path, seed: int) -> dict[str, Any]:
    """Train with ``cfg`` into ``out``; returns the final evaluation summary."""
    import stable_baselines3 as sb3
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy

    env_kwargs = dict(cfg.get("env_kwargs") or {})
    n_envs = int(cfg.get("n_envs", 1))
    venv = make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs)
    eval_env = make_vec_env(env_id, n_envs=1, seed=seed + 10_000, env_kwargs=env_kwargs)
    algo = getattr(sb3, cfg["algo"].upper())
    model = algo(cfg["policy"], venv, seed=seed, verbose=0, device="cpu", **(cfg.get("hyperparams") or {}))
    every = max(1, int(cfg.get("eval_freq", 10_000)) // n_envs)
    callbacks = [
        CheckpointCallback(save_freq=every, save_path=str(out / "checkpoints"), name_prefix="model"),
        EvalCallback(
            eval_env,
            best_model_save_path=str(out),
            log_path=str(out),
            eval_freq=every,
            n_eval_episodes=int(cfg.get("eval_episodes", 5)),
            deterministic=True,
        ),
    ]
    warnings.filterwarnings("ignore", category=TqdmExperimentalWarning)  # SB3's rich progress bar
    model.learn(total_timesteps=int(cfg["n_timesteps"]), callback=callbacks, progress_bar=True)
    model.save(out / "final_model")
    mean, std = evaluate_policy(model, eval_env, n_eval_episodes=int(cfg.get("eval_episodes", 5)))
    venv.close()
    eval_env.close()
    return {
        "env_id": env_id,
        "seed": seed,
        "mean_return": float(mean),
        "std_return": float(std),
        "n_timesteps": int(cfg["n_timesteps"]),
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Parse arguments, resolve the config, log it, train, and write ``result.json``."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", required=True, help="registered env id, e.g. sensor_envs/Neato-v0")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=None, help="drawn and logged when absent")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config entry")
    args = parser.parse_args(argv)
    if args.env not in gym.registry:
        raise SystemExit(f"--env: {args.env!r} is not a registered env id")
    cfg = load_config(args.config, args.env, args.set)
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 2**31)
    args.out.mkdir(parents=True, exist_ok=True)
    resolved = {"env_id": args.env, "seed": seed, "config": cfg, "command": [sys.executable, *sys.argv]}
    (args.out / "config.json").write_text(json.dumps(resolved, indent=2))
    result = train(args.env, cfg, args.out, seed)
    (args.out / "result.json").write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main()
