"""The robustness matrix: train on one sensor, evaluate on every sensor.

    sensor-envs robustness --domain highway --preset quick --out runs/quick
    sensor-envs robustness --domain neato --preset short --out runs/robust_neato
    sensor-envs robustness --domain highway --preset full --out runs/robust_hw --backend ray [--address auto]
        [--real-data ../shared/data/real] [--workers 2]

Rows are the sensor trained on, columns the sensor evaluated on. Cells, per metric (episode return and
collision rate on highway; success, collision and return on Neato), rliable-style
(:mod:`sensor_envs.training.stats`): the interquartile mean (IQM) and the mean of the seeds x episodes scores,
each with a 95 % percentile bootstrap interval, stratified by cell (seeds resampled whole with their episodes;
with a single seed, the episodes are resampled, and the report says so); rates' intervals stay inside [0, 1]. The tables
show the IQM of returns and the mean of rates (a rate's IQM drops its rare events). Between the rows, per
column and metric: the probability of improvement P(row a better than row b) with its interval.

Jobs: one per (training sensor, seed); a job trains (:func:`sensor_envs.training.train.train`), then evaluates its
final policy (``--policy final``), EvalCallback's best checkpoint (``--policy best``: chosen on episodes with other
seeds than the matrix's; the highway ``full`` preset's default) or the checkpoint chosen on validation episodes
(``--policy selected``: :mod:`sensor_envs.training.selection`, ``--reevaluate`` redoes a done job's choice and
evaluation, without training) on every column with the same evaluation seeds (common random numbers). Each job is the
command ``python -m sensor_envs.training.robustness job ...`` so the local process pool (default) and a Ray cluster
(``--backend ray``) run the same code; outputs land in ``--out`` whichever backend ran them (on a cluster ``--out``
must sit on a shared filesystem at the same path, and sensor_envs be installed). A job writes its ``eval.json`` and
then, atomically, its ``done`` marker; a rerun skips jobs that have one. ``--real-data`` adds a column with a model
fitted on real data (KDE radar on Astyx; learned lidar on ``neato_mar27_train.npz``), fitted once and cached in
``<out>/real_models/`` (never in the repository). Writes ``matrix.md``, ``.json`` and ``.png`` (heat maps) in ``--out``.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing as mp
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError, parse_json, read_text, real_path
from sensor_envs.training import selection, stats
from sensor_envs.training.matrix_report import HIGHER_IS_BETTER, _write_atomic, write_reports
from sensor_envs.training.matrix_report import headline as headline
from sensor_envs.training.robustness_inputs import (
    REAL_COLUMNS,
    UsageError,
    check_address,
    check_jobs,
    check_out,
    connect_ray,
    fit_real_models,
    real_model_paths,
    real_source,
)

__all__ = [
    "DOMAINS",
    "PRESETS",
    "DEFAULT_CONFIG",
    "UsageError",
    "column_kwargs",
    "sensor_names",
    "run_job",
    "run_jobs",
    "build_matrix",
    "write_reports",
    "add_arguments",
    "run",
    "main",
]

DEFAULT_CONFIG = Path(__file__).with_name("configs") / "default.yaml"

DOMAINS: dict[str, dict[str, Any]] = {
    "neato": {
        "env_id": "sensor_envs/Neato-v0",
        "sensors": ["ideal", "gaussian", "learned"],
        "real": REAL_COLUMNS["neato"],
        "model_files": ["neato_lidar.npz", "neato_rig.json"],
        "metrics": ["success", "collision", "return"],
    },
    "highway": {
        "env_id": "sensor_envs/HighwayFast-v0",
        "sensors": ["ideal", "gaussian", "kde"],
        "real": REAL_COLUMNS["highway"],
        "model_files": ["radar_gaussian.npz", "radar_kde.npz", "radar_object_clutter.json", "radar_rig.json"],
        "metrics": ["return", "collision", "speed"],
    },
}

# per domain: training budget and evaluation size; `set` entries override the env's training config, `algo` (optional)
# picks the config's block for that algorithm (`--algo` overrides it), `sensors` / `columns` (optional) the rows and
# columns when `--sensors` / `--columns` are not given
PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    # the README's quick start: one seed per row, the two rows trained side by side (one job per core), a few minutes
    # on 2 cores; shows that the pipeline runs and what a policy does after a short run, not which sensor is better
    "quick": {
        "neato": {
            "seeds": 1,
            "eval_episodes": 10,
            "max_episode_steps": 200,
            "sensors": ["ideal", "learned"],
            "columns": ["ideal", "learned"],
            "set": {"n_timesteps": 8192, "n_envs": 4, "eval_freq": 10**9, "eval_episodes": 1},
            "hyperparams": None,
        },
        "highway": {
            "algo": "dqn",
            "seeds": 1,
            "eval_episodes": 10,
            "max_episode_steps": None,
            "sensors": ["ideal", "kde_tracks"],
            "columns": ["ideal", "kde_tracks"],
            "set": {"n_timesteps": 3000, "n_envs": 1, "eval_freq": 10**9, "eval_episodes": 1},
            "hyperparams": None,
        },
    },
    "short": {
        "neato": {
            "seeds": 2,
            "eval_episodes": 2,
            "max_episode_steps": 40,
            "set": {"n_timesteps": 64, "n_envs": 1, "eval_freq": 10**9, "eval_episodes": 1},
            "hyperparams": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
        },
        "highway": {
            "seeds": 2,
            "eval_episodes": 2,
            "max_episode_steps": None,
            "set": {"n_timesteps": 128, "n_envs": 1, "eval_freq": 10**9, "eval_episodes": 1},
            "hyperparams": {"n_steps": 64, "batch_size": 32, "n_epochs": 1},
        },
    },
    "medium": {
        "neato": {
            "seeds": 3,
            "eval_episodes": 5,
            "max_episode_steps": 200,
            "set": {"n_timesteps": 8192, "n_envs": 4, "eval_freq": 10**9, "eval_episodes": 1},
            "hyperparams": None,
        },
        "highway": {
            "seeds": 3,
            "eval_episodes": 10,
            "max_episode_steps": None,
            "set": {"n_timesteps": 2048, "n_envs": 2, "eval_freq": 10**9, "eval_episodes": 1},
            "hyperparams": None,
        },
    },
    # "full" is sized for the shared 2-core machine without a GPU (README: budgets, wall time, how much the
    # policies learned): Neato 8 seeds (~25 min with 2 workers). Highway-fast: issue 41's recipe, 5 seeds, DQN with
    # highway-env's documented settings (the config's `algos: dqn` block) and highway-env's documented 20,000 steps,
    # a checkpoint every 2,000 steps, and the matrix evaluates the one with the fewest collisions on 50 validation
    # episodes (`--policy selected`; the final model regresses, EvalCallback's 20-episode pick is noisy:
    # docs/results/highway_matrix_surround_selected.md) on 30 episodes per cell; highway-env sets the pace.
    "full": {
        "neato": {
            "seeds": 8,
            "eval_episodes": 10,
            "max_episode_steps": 300,
            "set": {"n_timesteps": 150000, "n_envs": 4, "eval_freq": 10**9, "eval_episodes": 1},
            "hyperparams": None,
        },
        "highway": {
            "algo": "dqn",
            "seeds": 5,
            "eval_episodes": 30,
            "max_episode_steps": None,
            "policy": "selected",
            "set": {"n_timesteps": 20000, "n_envs": 1, "eval_freq": 2000, "eval_episodes": 20},
            "hyperparams": None,
        },
    },
}
MODEL_KWARGS = ("radar_model", "model")
"""Env keywords that name a sensor model file (hashed with the shipped ones when a config sets them)."""
EVAL_SEED = 1_000_000  # evaluation episode e of every cell resets with seed EVAL_SEED + e


# ---------------------------------------------------------------------------------------------- a job
def column_kwargs(
    domain: str, column: str, real_models: dict[str, str], config: str | Path = DEFAULT_CONFIG
) -> dict[str, Any]:
    """Env keyword arguments for evaluation column ``column``.

    A name of the config's ``sensors`` table gets that entry (over the block's ``env_kwargs``, as for
    training: :func:`sensor_envs.training.train.sensor_kwargs`); the real-data column the fitted model.
    """
    from sensor_envs.training import train as train_mod

    env_id = DOMAINS[domain]["env_id"]
    if column == DOMAINS[domain]["real"]:
        if domain == "neato":
            return {"lidar": "learned", "model": real_models[column]}
        return {"radar": "kde", "radar_model": real_models[column]}
    return dict(train_mod.load_config(Path(config), env_id, [], sensor=column)["env_kwargs"])


def sensor_names(domain: str, config: str | Path) -> list[str]:
    """The rows and columns a matrix may use: the domain's defaults, then the config's ``sensors`` table."""
    from sensor_envs.training import train as train_mod

    cfg = train_mod.load_config(Path(config), DOMAINS[domain]["env_id"], [])
    names = list(DOMAINS[domain]["sensors"])
    return names + [n for n in train_mod.sensor_table(cfg) if n not in names]


def evaluate(
    model: Any, env_id: str, kwargs: dict[str, Any], episodes: int, max_steps: int | None, seed0: int = EVAL_SEED
) -> dict[str, list]:
    """Per-episode return, collision and success of ``model`` (deterministic actions) on ``env_id(**kwargs)``.

    Episode ``e`` resets with seed ``seed0 + e``. When ``info`` reports the ego's ``speed`` (highway-env, m/s), also
    each episode's mean speed (``"speed"``): a policy avoiding collisions by crawling shows.
    """
    import gymnasium as gym

    extra: dict[str, Any] = {"max_episode_steps": max_steps} if max_steps else {}
    env = gym.make(env_id, **kwargs, **extra)
    out: dict[str, list] = {"return": [], "collision": [], "success": []}
    speeds: list[float] = []
    for e in range(episodes):
        obs, info = env.reset(seed=seed0 + e)
        total, done, episode_speeds = 0.0, False, []
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, term, trunc, info = env.step(action)
            total += float(reward)
            if "speed" in info:
                episode_speeds.append(float(info["speed"]))
            done = term or trunc
        if episode_speeds:
            speeds.append(float(np.mean(episode_speeds)))
        out["return"].append(total)
        out["collision"].append(float(bool(info.get("collision", info.get("crashed", False)))))
        out["success"].append(float(bool(info.get("is_success", False))))
    env.close()
    if len(speeds) == episodes:
        out["speed"] = speeds
    return out


def run_job(spec: dict[str, Any]) -> dict[str, Any]:
    """Train one (sensor, seed) run and evaluate it on every column; writes ``eval.json`` then ``done``."""
    import torch

    from sensor_envs.training import train as train_mod

    torch.set_num_threads(1)  # one core per job; also keeps the numbers reproducible
    run_dir = Path(spec["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    domain, env_id = spec["domain"], DOMAINS[spec["domain"]]["env_id"]
    if spec.get("reevaluate"):  # --reevaluate: a done job, trained with the config it recorded
        cfg, train_s = selection.trained(run_dir)
        t0 = time.perf_counter() - train_s
    else:
        overrides = [f"{k}={json.dumps(v)}" for k, v in spec["set"].items()]
        if spec["hyperparams"]:
            overrides.append(f"hyperparams={json.dumps(spec['hyperparams'])}")
        cfg = train_mod.load_config(Path(spec["config"]), env_id, overrides, algo=spec["algo"], sensor=spec["sensor"])
        cfg["device"] = spec["device"]
        resolved = {"env_id": env_id, "seed": spec["seed"], "sensor": spec["sensor"], "config": cfg}
        _write_atomic(run_dir / "config.json", json.dumps(resolved, indent=1))
        t0 = time.perf_counter()
        train_mod.train(env_id, cfg, run_dir, spec["seed"], progress_bar=False)
        train_s = time.perf_counter() - t0
    import stable_baselines3 as sb3

    policy = spec.get("policy", "final")  # "best": EvalCallback's pick on held-out seeds (seed + 10000)
    chosen = selection.choose(spec, evaluate)  # "selected": writes selected_model.zip
    model = getattr(sb3, cfg["algo"].upper()).load(run_dir / f"{policy}_model", device=spec["device"])
    cells = {
        col: evaluate(
            model,
            env_id,
            column_kwargs(domain, col, spec["real_models"], spec["config"]),
            spec["eval_episodes"],
            spec["max_episode_steps"],
        )
        for col in spec["columns"]
    }
    result = {"spec": spec, "train_seconds": train_s, "eval_seconds": time.perf_counter() - t0 - train_s}
    kwargs = [cfg.get("env_kwargs") or {}] + [
        column_kwargs(domain, col, spec["real_models"], spec["config"]) for col in spec["columns"]
    ]
    given = {str(k[key]) for k in kwargs for key in MODEL_KWARGS if isinstance(k.get(key), str)}
    result["sensor_models_sha256"] = sensor_model_hashes(domain, {**spec["real_models"], **{p: p for p in given}})
    result["cells"] = cells
    selection.write_eval(run_dir, {**result, "policy": policy, "selection": chosen}, bool(spec.get("reevaluate")))
    _write_atomic(run_dir / "done", "done\n")
    return result


def _job_command(spec: dict[str, Any]) -> list[str]:
    return [sys.executable, "-m", "sensor_envs.training.robustness", "job", json.dumps(spec)]


def _check(proc: subprocess.CompletedProcess[str], cmd: list[str]) -> None:
    """Raise with the tail of a failed job's stderr."""
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-3:]
        raise RuntimeError(f"job {json.loads(cmd[-1])['run_dir']} failed ({proc.returncode}): {tail}")


# ---------------------------------------------------------------------------------------------- backends
def run_jobs(specs: list[dict[str, Any]], backend: str, workers: int, address: str | None) -> None:
    """Run the job commands with a local process pool (spawn) or on a Ray cluster; progress via tqdm."""
    from tqdm import tqdm

    cmds = [_job_command(s) for s in specs]
    if not cmds:
        return
    bar = tqdm(total=len(cmds), desc=f"jobs ({backend})", unit="job")
    run: dict[str, Any] = {"capture_output": True, "text": True, "check": False}
    t0 = time.perf_counter()
    done: list[str] = []  # a disabled bar (stderr not a terminal) does not count

    def finished(cmd: list[str]) -> None:
        """Advance the bar; when stderr is not a terminal (a log file: the CLI disables the bar), print a line."""
        bar.update()
        done.append(cmd[-1])
        if not sys.stderr.isatty():
            spec = json.loads(cmd[-1])
            print(
                f"job {spec['sensor']} seed {spec['seed']} done ({len(done)} of {len(cmds)}; "
                f"{time.perf_counter() - t0:.0f} s since start)",
                file=sys.stderr,
                flush=True,
            )

    # The task is the job's command line (subprocess.run pickles by reference on both backends): the job
    # process imports the installed sensor_envs, so workers need no package state of the driver.
    if backend == "process":
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
            futures = {pool.submit(subprocess.run, c, **run): c for c in cmds}  # type: ignore[arg-type]
            for fut in cf.as_completed(futures):
                _check(fut.result(), futures[fut])
                finished(futures[fut])
    else:
        import ray

        started = not ray.is_initialized()
        if started:
            ray.init(address=address, num_cpus=None if address else workers, include_dashboard=False)
        remote = ray.remote(num_cpus=1)(subprocess.run)
        pending = {remote.remote(c, **run): c for c in cmds}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            cmd = pending.pop(ready[0])
            _check(ray.get(ready[0]), cmd)
            finished(cmd)
        if started:
            ray.shutdown()
    bar.close()


# ---------------------------------------------------------------------------------------------- the matrix
BOOTSTRAP_REPS = 2000


def score_matrix(evals: list[dict[str, Any]], column: str, metric: str) -> NDArray[np.float64]:
    """(seeds, episodes) scores of one cell: row ``i`` the evaluation episodes of seed ``i``'s policy."""
    return np.array([e["cells"][column][metric] for e in evals], dtype=np.float64)


def cell_statistics(scores: NDArray[np.float64]) -> dict[str, Any]:
    """IQM and mean with 95 % bootstrap intervals, seeds resampled whole (seeded: same scores, same numbers)."""
    return {
        "iqm": stats.iqm(scores),
        "iqm_ci95": list(stats.bootstrap_ci(scores, stats.iqm, reps=BOOTSTRAP_REPS)),
        "mean": stats.mean(scores),
        "mean_ci95": list(stats.bootstrap_ci(scores, stats.mean, reps=BOOTSTRAP_REPS)),
        "per_seed": [float(v) for v in scores.mean(axis=1)],
    }


def improvement(a: NDArray[np.float64], b: NDArray[np.float64], metric: str) -> dict[str, Any]:
    """P(a policy of row ``a`` does better than one of row ``b``) on one cell's episodes, with its interval."""
    sign = 1.0 if HIGHER_IS_BETTER[metric] else -1.0
    if a.shape[0] == 1:  # one seed: the episodes are the runs, one stratum
        a, b = a.T, b.T
    p = stats.probability_of_improvement(sign * a, sign * b)
    lo, hi = stats.probability_of_improvement_ci(sign * a, sign * b, reps=BOOTSTRAP_REPS)
    return {"p": p, "ci95": [lo, hi]}


def _read_json(path: Path) -> Any:
    """A job's JSON output in ``--out`` (written by this tool; read bounded, as any input)."""
    return parse_json(read_text(path, "job result"), str(path))


def build_matrix(out: Path, domain: str, rows: list[str], columns: list[str], seeds: list[int]) -> dict[str, Any]:
    """The jobs' ``eval.json`` as cells (IQM, mean, intervals) and the rows' probabilities of improvement."""
    evals = {r: [_read_json(out / "runs" / r / f"seed{s}" / "eval.json") for s in seeds] for r in rows}
    # a metric the jobs did not record (e.g. speed in jobs run before it was recorded) is left out
    metrics = [
        m
        for m in DOMAINS[domain]["metrics"]
        if all(m in e["cells"][c] for es in evals.values() for e in es for c in columns)
    ]
    over = "seeds resampled whole, with their episodes" if len(seeds) > 1 else "episodes resampled (single seed)"
    cells = {
        f"{r}->{c}": {m: cell_statistics(score_matrix(evals[r], c, m)) for m in metrics} for r in rows for c in columns
    }
    better = {
        m: {
            f"{a} vs {b} @ {c}": improvement(score_matrix(evals[a], c, m), score_matrix(evals[b], c, m), m)
            for i, a in enumerate(rows)
            for b in rows[i + 1 :]
            for c in columns
        }
        for m in metrics
        if m in HIGHER_IS_BETTER
    }
    return {
        "domain": domain,
        "env_id": DOMAINS[domain]["env_id"],
        "rows_trained_on": rows,
        "columns_evaluated_on": columns,
        "seeds": seeds,
        "metrics": metrics,
        "interval": f"95 % bootstrap per cell ({over}; {BOOTSTRAP_REPS} replicates, percentile)",
        "cells": cells,
        "probability_of_improvement": better,
    }


def sha256(path: Path) -> str | None:
    """SHA-256 of a file (:func:`sensor_envs.modelio.file_sha256`; ``None`` when it is absent)."""
    from sensor_envs.modelio import file_sha256

    return file_sha256(path) if path.is_file() else None


def sensor_model_hashes(domain: str, real_models: dict[str, str]) -> dict[str, str | None]:
    """SHA-256 of the sensor model files a job uses.

    The shipped models the domain's envs load are keyed by file name, every file of ``real_models`` (any
    model file a job used besides the shipped ones) by its path.
    """
    from sensor_envs.modelio import default_model_path

    hashes = {name: sha256(default_model_path(name)) for name in DOMAINS[domain]["model_files"]}
    hashes.update({str(path): sha256(Path(path)) for path in real_models.values()})
    return hashes


def model_hashes(
    domain: str, out: Path, rows: list[str], seeds: list[int], real_models: dict[str, str], policy: str = "final"
) -> dict[str, Any]:
    """SHA-256 of the sensor models the jobs used and of every evaluated policy (``<policy>_model.zip``).

    The sensor models' hashes are the ones the jobs recorded when they ran (``hashed_at: "jobs"``; a
    ``sensor_models_by_job`` entry when jobs disagree, e.g. a resumed run after a model changed); jobs
    written before jobs recorded them are hashed now (``hashed_at: "report"``).
    """
    jobs = {f"{r}/seed{s}": out / "runs" / r / f"seed{s}" for r in rows for s in seeds}
    recorded = {k: _read_json(d / "eval.json").get("sensor_models_sha256") for k, d in jobs.items()}
    policies = {f"{k}/{policy}_model.zip": sha256(d / f"{policy}_model.zip") for k, d in jobs.items()}
    if any(v is None for v in recorded.values()):
        return {"hashed_at": "report", "sensor_models": sensor_model_hashes(domain, real_models), "policies": policies}
    distinct = {json.dumps(v, sort_keys=True) for v in recorded.values()}
    result: dict[str, Any] = {"hashed_at": "jobs", "sensor_models": next(iter(recorded.values())), "policies": policies}
    if len(distinct) > 1:
        result["sensor_models_by_job"] = recorded
    return result


# ---------------------------------------------------------------------------------------------- driver
def plan(args: argparse.Namespace, real_models: dict[str, str]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The job specs of the matrix and the settings that define the output folder."""
    preset = PRESETS[args.preset][args.domain]
    try:
        known = sensor_names(args.domain, args.config)
    except InputError as err:  # ConfigError
        raise UsageError(f"--config: {err}") from None
    rows = list(args.sensors or preset.get("sensors") or DOMAINS[args.domain]["sensors"])
    for flag, names in (("--sensors", rows), ("--columns", args.columns or [])):
        bad = sorted(set(names) - set(known))
        if bad:
            raise UsageError(f"{flag}: unknown {bad} for domain {args.domain!r}; choose from {known}")
    # every default sensor and every trained row is evaluated unless --columns names the columns
    defaults = preset.get("columns") or DOMAINS[args.domain]["sensors"]
    columns = list(args.columns or defaults + [r for r in rows if r not in defaults])
    columns += list(real_models)
    seeds = list(range(args.seed0, args.seed0 + (args.seeds or preset["seeds"])))
    if seeds[-1] >= 2**32:  # numpy and SB3 seed with 32 bits
        raise UsageError(f"--seed0: the seeds {args.seed0}.. must stay below 2**32, got {args.seed0}")
    train_set = dict(preset["set"])
    from sensor_envs.training.train import check_device, set_value

    try:
        check_device(args.device)
    except ValueError as err:  # ConfigError
        raise UsageError(str(err)) from None
    for k, item in enumerate(args.set):
        key = item.partition("=")[0]
        if key in {i.partition("=")[0] for i in args.set[:k]}:  # the last would win silently
            raise UsageError(f"--set {key}: the key is given twice")
        try:
            train_set[key] = set_value(item)
        except ValueError as err:  # ConfigError
            raise UsageError(str(err)) from None
    eval_episodes = preset["eval_episodes"] if args.eval_episodes is None else args.eval_episodes
    if eval_episodes < 1:
        raise UsageError(f"--eval-episodes: must be >= 1, got {eval_episodes}")
    algo = args.algo or preset.get("algo")  # the preset's algorithm unless --algo names one
    policy = args.policy or preset.get("policy", "final")
    settings = {
        "domain": args.domain,
        "preset": args.preset,
        "algo": algo,
        "policy": policy,
        **selection.settings(args, policy, train_set),
        "seeds": seeds,
        "rows": rows,
        "columns": columns,
        "eval_episodes": eval_episodes,
        "max_episode_steps": preset["max_episode_steps"],
        "set": train_set,
        "hyperparams": preset["hyperparams"],
        "config": str(real_path(args.config)),
    }
    check_jobs(args, settings, real_models, DOMAINS[args.domain]["env_id"])
    specs = [
        {
            **{
                k: settings[k]
                for k in ("domain", "algo", "policy", "columns", "eval_episodes", "max_episode_steps", "set")
            },
            "hyperparams": preset["hyperparams"] if algo in (None, "ppo") else None,
            "config": settings["config"],
            "select_episodes": settings.get("select_episodes"),
            "sensor": r,
            "seed": s,
            "device": args.device,
            "real_models": real_models,
            "run_dir": str(real_path(args.out / "runs" / r / f"seed{s}")),
        }
        for s in seeds  # seed-major: the first seeds' rows finish first (a stopped run leaves whole seeds)
        for r in rows
    ]
    return specs, settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``sensor-envs robustness``."""
    parser.add_argument("--domain", choices=sorted(DOMAINS), default="neato", help="world (default neato)")
    parser.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        default="short",
        help="training budget, evaluation size and default rows: quick (the README's: 1 seed, minutes), short (a "
        "smoke test), medium, full (default short)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder (a rerun with its settings resumes)")
    parser.add_argument(
        "--backend", choices=("process", "ray"), default="process", help="local process pool or Ray (default process)"
    )
    parser.add_argument("--address", default=None, help="Ray cluster address (default: start a local instance)")
    parser.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2)), help="parallel jobs (local)")
    from sensor_envs.training.train import ALGOS

    parser.add_argument(
        "--algo", choices=ALGOS, default=None, help="algorithm block of the config (default: the env's algo)"
    )
    parser.add_argument(
        "--sensors",
        nargs="+",
        default=None,
        help="training sensors (rows): the domain's or the config's `sensors` names (default: the preset's, else "
        "the domain's)",
    )
    parser.add_argument(
        "--columns",
        nargs="+",
        default=None,
        help="evaluation sensors (columns); default: the preset's or domain's, and the rows",
    )
    parser.add_argument(
        "--eval-episodes", type=int, default=None, help="episodes per seed and cell (default: preset's)"
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a training config entry of the preset"
    )
    selection.add_arguments(parser)  # --policy, --select-episodes, --reevaluate
    parser.add_argument("--seeds", type=int, default=None, help="number of seeds (default: the preset's)")
    parser.add_argument("--seed0", type=int, default=0, help="first training seed (default 0)")
    parser.add_argument("--device", default="auto", help="torch device: auto (default), cpu, cuda, ...")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="YAML config (default: the shipped one)")
    parser.add_argument(
        "--real-data", type=Path, default=None, help="e.g. ../shared/data/real: adds a real-data column"
    )
    parser.add_argument("--force", action="store_true", help="reuse an --out folder made with other settings")


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Run (or resume) the matrix of ``args`` (from :func:`add_arguments`) and write its reports.

    Raises:
        UsageError: a bad argument or an ``--out`` made with other settings (one line naming the key).
    """
    argv = list(getattr(args, "argv", None) or sys.argv[1:])
    return _run(args, argv[1:] if argv[:1] == ["robustness"] else argv)


def main(argv: list[str] | None = None) -> dict[str, Any] | None:
    """Run (or resume) the matrix and write its reports; ``job SPEC`` runs one job (used by the backends)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["job"]:
        run_job(json.loads(argv[1]))
        return None
    parser = argparse.ArgumentParser(
        prog="sensor-envs robustness", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return _run(args, argv)
    except UsageError as err:
        print(f"sensor-envs robustness: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None


def _run(args: argparse.Namespace, argv: list[str]) -> dict[str, Any]:
    if args.backend == "process" and args.address:
        raise UsageError("--address applies to --backend ray only")
    if args.workers < 1:
        raise UsageError(f"--workers: must be >= 1, got {args.workers}")
    if args.backend == "ray":
        try:
            import ray
        except ImportError:
            raise UsageError("--backend ray: ray is not installed (pip install ray, or the ray extra)") from None
        check_address(args.address)
    real: dict[str, str] = {}
    if args.real_data:
        real_source(args.domain, args.real_data)
        real = real_model_paths(args.domain, args.out)  # fitted once --out is made, cached there
    specs, settings = plan(args, real)  # a bad config or option is refused before --out is made
    check_out(args)
    started = connect_ray(args)
    try:
        return _run_matrix(args, argv, specs, settings, real)
    finally:
        if started:
            import ray

            ray.shutdown()


def _run_matrix(
    args: argparse.Namespace,
    argv: list[str],
    specs: list[dict[str, Any]],
    settings: dict[str, Any],
    real: dict[str, str],
) -> dict[str, Any]:
    """Make ``--out``, fit the real-data models, run the jobs not yet done, and write the reports."""
    stamp = args.out / "settings.json"
    if stamp.is_file() and not args.force:
        old = parse_json(read_text(stamp, "settings"), f"{stamp}: settings")
        old = old if isinstance(old, dict) else {}
        changed = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
        if changed:
            raise UsageError(f"--out {args.out}: made with other settings ({', '.join(changed)}); use --force")
    redo = selection.reevaluations(specs) if getattr(args, "reevaluate", False) else []  # before writing
    args.out.mkdir(parents=True, exist_ok=True)
    if args.real_data:
        fit_real_models(args.domain, args.real_data, args.out)
    _write_atomic(stamp, json.dumps(settings, indent=1))
    todo = [s for s in specs if not (Path(s["run_dir"]) / "done").is_file()]
    print(f"{len(specs) - len(todo)} of {len(specs)} jobs already done; running {len(todo)} on {args.backend}")
    t0 = time.perf_counter()
    run_jobs(todo + redo, args.backend, args.workers, args.address)
    matrix = build_matrix(args.out, args.domain, settings["rows"], settings["columns"], settings["seeds"])
    meta = {
        "preset": args.preset,
        "algo": settings["algo"] or "config default",
        "eval_episodes": settings["eval_episodes"],
        "backend": args.backend,
        "jobs_run": len(todo) + len(redo),
        "wall_seconds": time.perf_counter() - t0,
        "command": " ".join(["sensor-envs", "robustness", *argv]),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "policy": settings["policy"],
        "sha256": model_hashes(args.domain, args.out, settings["rows"], settings["seeds"], real, settings["policy"]),
    }
    write_reports(args.out, matrix, meta)
    print((args.out / "matrix.md").read_text())
    return matrix


if __name__ == "__main__":
    main()
