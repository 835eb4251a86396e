"""Checkpoint selection on validation episodes, and re-evaluating finished jobs (``sensor-envs robustness``).

    sensor-envs robustness ... --policy selected [--select-episodes 50]
    sensor-envs robustness ... --policy selected --reevaluate [--force]     # a finished run, no training

``--policy best`` evaluates EvalCallback's pick, chosen on the config's ``eval_episodes`` episodes (20 in the
highway ``full`` preset): a noisy choice among ten checkpoints
(docs/results/highway_matrix_surround_selected.md). :func:`select` plays every checkpoint a job saved
(``checkpoints/model_<N>_steps.zip``, and ``final_model.zip`` unless a checkpoint has its step count) on
``--select-episodes`` validation episodes of the job's own training sensor (the ``env_kwargs`` of its
``config.json``), episode ``e`` reset with seed ``SELECT_SEED + e`` (2,000,000 + e: apart from the matrix's
``EVAL_SEED + e`` episodes and EvalCallback's ``seed + 10000``), deterministic actions, with the matrix's own
episode loop (:func:`sensor_envs.training.robustness.evaluate`, passed in: this module imports nothing of
``robustness``). It copies the chosen checkpoint to ``selected_model.zip`` and writes ``selection.json``.

The criterion is the lowest collision rate, ties broken by the highest mean return (then the later checkpoint):
the collision rate is the matrix's safety metric, and highway-env's discrete actions cannot slow the ego below
20 m/s, so a policy cannot buy a low collision rate by crawling (the mean speed is recorded all the same). A
Neato job without collisions is chosen by its return.

``--reevaluate`` runs, for the jobs that are already ``done``, only the policy choice and the evaluation; the
previous ``eval.json`` is kept as ``eval_<policy>.json`` (:func:`write_eval`). Cost: one checkpoint's
validation is ``--select-episodes`` episodes, so a job's selection costs ``checkpoints x select_episodes``
episodes on top of its ``columns x eval_episodes`` evaluation episodes.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.inputs import parse_json, read_text
from sensor_envs.outputs import atomic_write, write_json
from sensor_envs.training.robustness_inputs import UsageError

__all__ = [
    "SELECT_SEED",
    "SELECT_EPISODES",
    "POLICIES",
    "checkpoints",
    "select",
    "choose",
    "trained",
    "write_eval",
    "reevaluations",
    "settings",
    "add_arguments",
]

SELECT_SEED = 2_000_000
"""Validation episode ``e`` of a checkpoint resets with seed ``SELECT_SEED + e``."""
SELECT_EPISODES = 50
"""Default ``--select-episodes``."""
POLICIES = ("final", "best", "selected")
"""``--policy``: the model each job evaluates (``<policy>_model.zip``)."""
CHECKPOINT = re.compile(r"model_([0-9]+)_steps\.zip")
# the job's evaluation: a done job whose eval.json has these spec entries is not evaluated again
EVALUATION_KEYS = (
    "policy",
    "select_episodes",
    "eval_episodes",
    "columns",
    "max_episode_steps",
    "real_models",
    "config",
)
# what a job was trained with: --reevaluate refuses a done job trained otherwise (its models are not these)
TRAINING_KEYS = ("domain", "algo", "set", "hyperparams", "sensor", "seed")

Evaluate = Callable[..., dict[str, list]]


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _read(path: Path, what: str) -> Any:
    """A JSON file of a job's folder (written by robustness; read bounded, as any input)."""
    data = parse_json(read_text(path, what), str(path))
    if not isinstance(data, dict):
        raise UsageError(f"{path}: expected a JSON object")
    return data


def checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """``(steps, path)`` of the job's ``checkpoints/model_<steps>_steps.zip``, by steps."""
    folder = Path(run_dir) / "checkpoints"
    found = [(m, p) for p in folder.glob("model_*_steps.zip") if (m := CHECKPOINT.fullmatch(p.name))]
    return sorted((int(m.group(1)), p) for m, p in found)


def _require_checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """:func:`checkpoints` of a job that ``--policy selected`` chooses among (none: an input error naming it)."""
    found = checkpoints(run_dir)
    if not found:
        raise UsageError(f"--policy selected: {run_dir} has no checkpoints (checkpoints/model_<N>_steps.zip)")
    return found


def _load(algo: str, path: Path, device: str) -> Any:
    """The SB3 model saved at ``path`` (a seam for the tests)."""
    import stable_baselines3 as sb3

    return getattr(sb3, algo.upper()).load(path, device=device)


def select(
    run_dir: Path,
    episodes: int,
    max_steps: int | None,
    device: str,
    evaluate: Evaluate,
    log: Callable[[str], None] = _stderr,
) -> dict[str, Any]:
    """Choose the job's checkpoint with the fewest collisions on ``episodes`` validation episodes.

    Each candidate is played with ``evaluate(model, env_id, env_kwargs, episodes, max_steps, seed0=SELECT_SEED)``
    on the job's training env (its ``config.json``); a line per candidate goes to ``log`` (stderr). Writes
    ``selected_model.zip`` (a copy of the chosen file: temporary file, then a rename) and ``selection.json``
    (returned): per candidate its file, steps, collision rate, mean return, mean speed (``None`` when the
    env reports none), episodes and seeds; the chosen one.

    Raises:
        UsageError: the job saved no checkpoints (one line naming ``run_dir``).
    """
    run_dir = Path(run_dir)
    found = _require_checkpoints(run_dir)
    job = _read(run_dir / "config.json", "job config")
    env_id, cfg = job["env_id"], job["config"]
    kwargs = dict(cfg.get("env_kwargs") or {})
    final = _load(cfg["algo"], run_dir / "final_model.zip", device)
    candidates: list[tuple[int, Path, Any]] = [(steps, path, None) for steps, path in found]
    if int(final.num_timesteps) not in {steps for steps, _ in found}:  # else the same weights as that checkpoint
        candidates.append((int(final.num_timesteps), run_dir / "final_model.zip", final))
    seeds = [SELECT_SEED, SELECT_SEED + episodes - 1]
    rows: list[dict[str, Any]] = []
    for i, (steps, path, model) in enumerate(candidates):
        t0 = time.perf_counter()
        model = model if model is not None else _load(cfg["algo"], path, device)
        got = evaluate(model, env_id, kwargs, episodes, max_steps, seed0=SELECT_SEED)
        speed = float(np.mean(got["speed"])) if "speed" in got else None
        rows.append(
            {
                "checkpoint": str(path.relative_to(run_dir)),
                "steps": steps,
                "collision_rate": float(np.mean(got["collision"])),
                "mean_return": float(np.mean(got["return"])),
                "mean_speed": speed,
                "episodes": episodes,
                "seeds": seeds,
                "seconds": time.perf_counter() - t0,
            }
        )
        r = rows[-1]
        log(
            f"select {run_dir}: {r['checkpoint']} ({i + 1} of {len(candidates)}): collision {r['collision_rate']:.2f}, "
            f"return {r['mean_return']:.2f}" + (f", speed {speed:.1f}" if speed is not None else "")
            + f" ({r['seconds']:.0f} s)"
        )  # fmt: skip
    chosen = min(rows, key=lambda r: (r["collision_rate"], -r["mean_return"], -r["steps"]))
    from sensor_envs.modelio import file_sha256

    source = run_dir / chosen["checkpoint"]
    atomic_write(run_dir / "selected_model.zip", lambda tmp: shutil.copyfile(source, tmp))
    result = {
        "criterion": "lowest collision rate, then highest mean return, then most steps",
        "env_id": env_id,
        "env_kwargs": kwargs,
        "episodes": episodes,
        "seeds": seeds,
        "deterministic": True,
        "chosen": {**chosen, "sha256": file_sha256(source)},
        "candidates": rows,
    }
    atomic_write(run_dir / "selection.json", lambda tmp: write_json(tmp, result))
    log(f"select {run_dir}: chose {chosen['checkpoint']} ({chosen['steps']} steps)")
    return result


def choose(spec: dict[str, Any], evaluate: Evaluate) -> dict[str, Any] | None:
    """A job's ``--policy selected`` choice (:func:`select`; ``None`` for the other policies)."""
    if spec.get("policy") != "selected":
        return None
    return select(Path(spec["run_dir"]), spec["select_episodes"], spec["max_episode_steps"], spec["device"], evaluate)


def trained(run_dir: Path) -> tuple[dict[str, Any], float]:
    """A done job's resolved training config (its ``config.json``) and training time (its ``eval.json``)."""
    run_dir = Path(run_dir)
    cfg = _read(run_dir / "config.json", "job config")["config"]
    return cfg, float(_read(run_dir / "eval.json", "job result").get("train_seconds") or 0.0)


def _policy(result: dict[str, Any]) -> str:
    """The policy an ``eval.json`` evaluated (jobs before ``policy`` was recorded: their spec's; else final)."""
    policy = result.get("policy") or (result.get("spec") or {}).get("policy") or "final"
    return policy if policy in POLICIES else "unknown"


def write_eval(run_dir: Path, result: dict[str, Any], keep: bool) -> Path | None:
    """Write the job's ``eval.json`` atomically; with ``keep``, first keep the previous one (returned).

    The previous one is kept as ``eval_<its policy>.json`` (``eval_<policy>.<k>.json`` when that name holds
    another evaluation already), so a re-evaluation loses nothing.
    """
    path, kept = Path(run_dir) / "eval.json", None
    if keep and path.is_file():
        text = read_text(path, "job result")
        policy, k = _policy(_read(path, "job result")), 0
        while kept is None:
            name = path.with_name(f"eval_{policy}.json" if k == 0 else f"eval_{policy}.{k}.json")
            if not name.exists():
                atomic_write(name, lambda tmp: tmp.write_text(text, encoding="utf-8"))
            if name.read_text(encoding="utf-8") == text:  # written now, or by an interrupted re-evaluation
                kept = name
            k += 1
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(result, indent=1), encoding="utf-8"))
    return kept


def reevaluations(specs: list[dict[str, Any]], log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """``--reevaluate``: the done jobs of ``specs`` to choose and evaluate again (``"reevaluate": True``).

    A done job whose ``eval.json`` records this evaluation (its spec's :data:`EVALUATION_KEYS`) is left
    alone (an interrupted re-evaluation resumes). Checked before anything is written.

    Raises:
        UsageError: a done job trained with other settings than ``specs``, or without the file its policy
            needs (``--policy selected``: no checkpoints), naming its folder.
    """
    redo, done = [], 0
    for spec in specs:
        run_dir = Path(spec["run_dir"])
        if not (run_dir / "done").is_file():
            continue
        done += 1
        old = _read(run_dir / "eval.json", "job result").get("spec") or {}
        other = [k for k in TRAINING_KEYS if old.get(k) != spec.get(k)]
        if other:
            raise UsageError(f"--reevaluate: {run_dir} was trained with other settings ({', '.join(other)})")
        if spec["policy"] == "selected":
            _require_checkpoints(run_dir)
        if spec["policy"] != "selected" and not (run_dir / f"{spec['policy']}_model.zip").is_file():
            raise UsageError(f"--policy {spec['policy']}: {run_dir} has no {spec['policy']}_model.zip")
        if any(old.get(k) != spec.get(k) for k in EVALUATION_KEYS):
            redo.append({**spec, "reevaluate": True})
    log(f"--reevaluate: {len(redo)} of {done} done jobs to evaluate again ({done - len(redo)} already evaluated so)")
    return redo


def settings(args: argparse.Namespace, policy: str, train_set: dict[str, Any]) -> dict[str, Any]:
    """The settings entries of ``--policy`` / ``--select-episodes`` (``select_episodes`` with ``selected`` only).

    Raises:
        UsageError: ``best`` or ``selected`` when no checkpoint is saved, a ``--select-episodes`` below 1 or
            without ``--policy selected``.
    """
    n = getattr(args, "select_episodes", None)
    if policy in ("best", "selected") and int(train_set.get("eval_freq", 10**9)) > int(train_set["n_timesteps"]):
        what = "EvalCallback never runs" if policy == "best" else "no checkpoint is saved"
        raise UsageError(f"--policy {policy}: {what} (eval_freq > n_timesteps); set eval_freq")
    if policy != "selected":
        if n is not None:
            raise UsageError(f"--select-episodes applies to --policy selected only (the policy is {policy})")
        return {}
    if n is not None and n < 1:
        raise UsageError(f"--select-episodes: must be >= 1, got {n}")
    return {"select_episodes": SELECT_EPISODES if n is None else n}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--policy``, ``--select-episodes`` and ``--reevaluate`` of ``sensor-envs robustness``."""
    parser.add_argument(
        "--policy",
        choices=POLICIES,
        default=None,
        help="the model each job evaluates: final, best (EvalCallback's pick on held-out seeds) or selected (the "
        "checkpoint with the fewest collisions on --select-episodes validation episodes of its training sensor); "
        "default: preset's",
    )
    parser.add_argument(
        "--select-episodes",
        type=int,
        default=None,
        metavar="N",
        help=f"--policy selected: validation episodes per checkpoint (default {SELECT_EPISODES})",
    )
    parser.add_argument(
        "--reevaluate",
        action="store_true",
        help="jobs already done: choose the policy and evaluate it again, without training (the previous eval.json "
        "is kept as eval_<policy>.json)",
    )
