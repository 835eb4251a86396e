"""Train a stable-baselines3 agent on a sensor_envs env from a YAML config keyed by env id.

    sensor-envs train --env sensor_envs/Neato-v0 --out runs/neato [--seed 1] [--algo sac] [--force]
        [--sensor gaussian] [--device auto] [--config my.yaml] [--set n_timesteps=5000]
        [--set vec_env=subproc|vector]

The default config is ``configs/default.yaml`` beside this module (package data). An existing ``--out`` is
refused unless ``--force``; the run is built in a claimed temporary folder beside ``--out`` that replaces it
as a whole when the run ends (two runs never mix their files). Writes into ``--out``: ``config.json`` (the
resolved config, the seed and the command line), SB3 checkpoints (``checkpoints/``), TensorBoard logs
(``tb/``; ``tensorboard --logdir runs``), ``best_model.zip``
and ``evaluations.npz`` from ``EvalCallback``, ``final_model.zip`` and ``result.json`` (mean and std of the
final evaluation return). A seed is drawn and logged when absent. ``--algo`` picks another algorithm's
block (``algos:``) of the env's config; ``--sensor`` sets the env's ``radar`` (highway ids) or ``lidar``
(Neato) keyword. A bad config or argument exits with status 2 and one line naming the key.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import warnings
from pathlib import Path
from typing import Any, NoReturn

import gymnasium as gym
import numpy as np
from tqdm import TqdmExperimentalWarning

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.inputs import InputError, bad_name, parse_yaml, read_text

__all__ = [
    "ALGOS",
    "VEC_ENVS",
    "DEFAULT_CONFIG",
    "ConfigError",
    "load_config",
    "config_inputs",
    "sensor_table",
    "sensor_kwargs",
    "make_env",
    "train",
    "add_arguments",
    "run",
    "main",
]

ALGOS = ("ppo", "sac", "a2c", "dqn")
VEC_ENVS = ("dummy", "subproc", "vector")
KEYS = {
    "algo",
    "policy",
    "n_timesteps",
    "n_envs",
    "env_kwargs",
    "hyperparams",
    "eval_freq",
    "eval_episodes",
    "vec_env",
    "device",
    "algos",
    "sensors",
}
ALGO_KEYS = {"policy", "hyperparams", "n_timesteps", "n_envs", "eval_freq", "eval_episodes"}
DEFAULT_CONFIG = Path(__file__).with_name("configs") / "default.yaml"
"""The shipped config (package data ``sensor_envs/training/configs/default.yaml``)."""


class ConfigError(InputError):
    """A bad config file, config entry or argument (the message names the file and the key)."""


class EnvRefused(ConfigError):
    """The env refused the config's keyword arguments (``env_kwargs``, with the sensor chosen)."""


class UsageExit(SystemExit):
    """Exit status 2 after a usage or config error; ``str()`` is the one-line message."""

    def __init__(self, message: str) -> None:
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


def sensor_key(env_id: str) -> str:
    """The env keyword that selects the sensor: ``lidar`` for Neato ids, ``radar`` for the highway ids."""
    return "lidar" if "Neato" in env_id else "radar"


def sensor_table(cfg: dict[str, Any], where: str = "config") -> dict[str, dict[str, Any]]:
    """The named sensors of an env's config block (``sensors:``): name -> env keyword arguments.

    Raises :class:`ConfigError` naming ``where`` when the table or an entry is not a mapping.
    """
    table = cfg.get("sensors") or {}
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: sensors must be a mapping of name -> env keyword arguments, got {table!r}")
    for name, kwargs in table.items():
        if not isinstance(kwargs, dict) or not kwargs:
            raise ConfigError(f"{where}: sensors.{name} must be a non-empty mapping of env keyword arguments")
    return table


def sensor_kwargs(cfg: dict[str, Any], env_id: str, sensor: str, where: str = "config") -> dict[str, Any]:
    """``cfg``'s ``env_kwargs`` with the sensor ``sensor`` selected.

    A name of the block's ``sensors`` table replaces every keyword any entry of the table sets (so
    ``kde_tracks`` after a config default of ``radar: ideal`` carries no stale option, and ``ideal`` after a
    default with ``tracks: true`` carries no tracker); any other name sets the env's ``radar`` (highway
    ids) or ``lidar`` (Neato) keyword, as before the table existed.
    """
    table = sensor_table(cfg, where)
    kwargs = dict(cfg.get("env_kwargs") or {})
    if sensor not in table:
        return {**kwargs, sensor_key(env_id): sensor}
    owned = {key for entry in table.values() for key in entry}
    return {**{k: v for k, v in kwargs.items() if k not in owned}, **table[sensor]}


COUNT_LIMITS = {"n_timesteps": 10**9, "n_envs": 256, "eval_freq": 10**9, "eval_episodes": 10_000}
"""Declared range of every count of a config: an integer in ``[1, limit]`` (``n_timesteps: 1e12`` is refused)."""
_DEVICE = re.compile(r"auto|cpu|mps|cuda(?::[0-9]{1,3})?")


def check_device(value: Any, where: str = "--device") -> str:
    """``value`` if it names a torch device of this machine: ``auto``, ``cpu``, ``mps`` or an existing ``cuda[:N]``.

    stable-baselines3 would fall back to the CPU silently for a CUDA device that is not there, and torch
    raises a ``RuntimeError`` deep inside training for a name that is no device.

    Raises:
        ConfigError: ``"<where>: ..."``.
    """
    if not isinstance(value, str) or not _DEVICE.fullmatch(value):
        raise ConfigError(f"{where}: expected auto, cpu, mps, cuda or cuda:N, got {value!r:.60}")
    if value.startswith("cuda"):
        import torch

        n, k = torch.cuda.device_count(), int(value.partition(":")[2] or 0)
        if k >= n:
            raise ConfigError(f"{where}: {value} is not a device of this machine ({n} CUDA devices)")
    return value


def set_value(item: str, option: str = "--set") -> Any:
    """The value of a ``key=value`` override (YAML, through the input layer: no aliases, tags or huge nesting).

    Raises:
        ConfigError: ``"--set <key>: ..."`` for an item without ``=``, an empty or unprintable key, or a value
            that is no plain YAML value.
    """
    key, sep, value = item.partition("=")
    if not sep or bad_name(key):
        raise ConfigError(f"{option} {item!r:.80}: expected key=value with a key of printable text")
    try:
        return parse_yaml(value, f"{option} {key}")
    except InputError as err:
        raise ConfigError(str(err)) from None


def load_config(
    path: Path,
    env_id: str,
    overrides: list[str],
    algo: str | None = None,
    sensor: str | None = None,
    *,
    algo_option: str = "--algo",
    sensor_option: str = "--sensor",
    set_keys: list[str] | None = None,
) -> dict[str, Any]:
    """The config block of ``env_id`` in ``path`` with ``key=value`` overrides applied; unknown keys are errors.

    ``algo`` merges that algorithm's entry of the block's ``algos`` over the block; ``sensor`` sets the
    env's sensor: a name of the block's ``sensors`` table selects that entry's env keyword arguments,
    any other name sets the ``radar`` / ``lidar`` keyword (:func:`sensor_kwargs`).
    Raises :class:`ConfigError` naming the file and the key, and the option a refused value came from:
    ``algo_option`` for ``algo``, ``sensor_option`` for ``sensor``, ``--set KEY`` for the overrides (only
    ``set_keys`` when given: the keys a user set, the others being a preset's).
    """
    try:  # bounded: a regular file of sane size, no aliases, tags or duplicate keys (sensor_envs.inputs)
        doc = parse_yaml(read_text(path, "config"), str(path)) or {}
    except InputError as err:
        raise ConfigError(str(err)) from None
    if not isinstance(doc, dict) or env_id not in doc or not isinstance(doc[env_id], dict):
        known = sorted(doc) if isinstance(doc, dict) else []
        raise ConfigError(f"{path}: no config for env id {env_id!r}; known: {known}")
    cfg = dict(doc[env_id])
    keys = [item.partition("=")[0] for item in overrides] if set_keys is None else list(set_keys)
    where = f"{path} [{env_id}]" + (f" with --set {', '.join(keys)}" if keys else "")  # the value may be a --set
    if algo is not None and algo != cfg.get("algo"):
        alt = (cfg.get("algos") or {}).get(algo)
        if not isinstance(alt, dict):
            blocks = sorted(cfg.get("algos") or {}) if isinstance(cfg.get("algos"), dict) else []
            raise ConfigError(
                f"{algo_option} {algo}: {where}: no algos.{algo} block for this env (the config's blocks: "
                f"{[cfg.get('algo'), *blocks]})"
            )
        bad = set(alt) - ALGO_KEYS
        if bad:
            expected = sorted(ALGO_KEYS)
            raise ConfigError(f"{where}: algos.{algo}: unknown keys {sorted(bad)}; expected {expected}")
        cfg.update(alt, algo=algo)
    given: set[str] = set()
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--set {item!r}: expected key=value")
        if key in given:  # the last would win silently
            raise ConfigError(f"--set {key}: the key is given twice")
        given.add(key)
        cfg[key] = set_value(item)
    unknown = set(cfg) - KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)}; expected {sorted(KEYS)}")
    if cfg.get("algo") not in ALGOS:
        raise ConfigError(f"{where}: algo must be one of {ALGOS}, got {cfg.get('algo')!r}")
    if cfg.setdefault("vec_env", "dummy") not in VEC_ENVS:
        raise ConfigError(f"{where}: vec_env must be one of {VEC_ENVS}, got {cfg['vec_env']!r}")
    spec = gym.registry.get(env_id)
    if cfg["vec_env"] == "vector" and (spec is None or spec.vector_entry_point is None):
        raise ConfigError(f"{where}: vec_env: 'vector' needs a vector entry point, which this id has not")
    check_device(cfg.setdefault("device", "auto"), f"{where}: device")
    for key, high in COUNT_LIMITS.items():
        value = cfg.get(key, 1)
        if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= high:
            raise ConfigError(f"{where}: {key} must be an integer in [1, {high}], got {value!r:.40}")
    for key in ("env_kwargs", "hyperparams"):
        if not isinstance(cfg.get(key) or {}, dict):
            raise ConfigError(f"{where}: {key} must be a mapping, got {cfg[key]!r}")
    table = sensor_table(cfg, where=where)
    base = dict(cfg.get("env_kwargs") or {})
    if sensor is not None:
        cfg["env_kwargs"] = sensor_kwargs(cfg, env_id, sensor, where=where)
    try:
        check_arguments(cfg, env_id, where)
    except EnvRefused as err:
        # a sensor the env refuses while the config's own keywords build: the option is at fault, not the file
        if sensor is None or cfg["env_kwargs"] == base or not _builds(env_id, base):
            raise
        named = f" (or a name of the config's sensors: {sorted(table)})" if table else ""
        raise ConfigError(f"{sensor_option} {sensor}: {err}{named}") from None
    return cfg


def _builds(env_id: str, kwargs: dict[str, Any]) -> bool:
    """Whether ``env_id`` builds with ``kwargs`` (refusals of bad input only; any other error propagates)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            gym.make(env_id, **kwargs).close()
        except (InputError, TypeError):
            return False
    return True


MODEL_KWARGS = ("radar_model", "model")
"""Env keywords that name a sensor model file."""


def config_inputs(path: Path, cfg: dict[str, Any]) -> list[Path]:
    """The files a run of ``cfg`` reads: the config file and every sensor model file its env keywords name."""
    kwargs = cfg.get("env_kwargs") or {}
    return [Path(path), *[Path(kwargs[k]) for k in MODEL_KWARGS if isinstance(kwargs.get(k), str)]]


def _bad_number(x: Any) -> Any:
    """The first number nested in ``x`` that is not finite or beyond 1e12 in size (``None`` if there is none)."""
    stack = [x]
    while stack:
        v = stack.pop()
        if isinstance(v, dict):
            stack.extend(v.values())
        elif isinstance(v, (list, tuple)):
            stack.extend(v)
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and not abs(v) <= 1e12:
            return v
    return None


def check_arguments(cfg: dict[str, Any], env_id: str, where: str) -> None:
    """Check ``hyperparams`` and ``env_kwargs`` before any output is made: finite numbers, known names, an env.

    Else SB3 or the env would fail deep inside training (a ``ValueError`` for a NaN learning rate, a
    ``TypeError`` for an unknown keyword argument).

    Raises:
        ConfigError: naming ``where`` and the key.
    """
    import inspect

    import stable_baselines3 as sb3

    hp = cfg.get("hyperparams") or {}
    for key in ("hyperparams", "env_kwargs"):
        bad = _bad_number(cfg.get(key) or {})
        if bad is not None:
            raise ConfigError(f"{where}: {key}: {bad!r} is not a finite number within 1e12")
    for key in ("gamma", "gae_lambda", "tau", "learning_rate"):  # SB3 takes them unchecked (gamma 2 diverges)
        v = hp.get(key, 1.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= 1:
            raise ConfigError(f"{where}: hyperparams: {key} must be a number in (0, 1], got {v!r:.40}")
    unknown = sorted(set(hp) - set(inspect.signature(getattr(sb3, cfg["algo"].upper())).parameters))
    if unknown:
        raise ConfigError(f"{where}: hyperparams: {unknown[0]!r} is no {cfg['algo']} argument")
    _check_builds(cfg, env_id, where)


def _check_builds(cfg: dict[str, Any], env_id: str, where: str) -> None:
    """Build the env from ``env_kwargs`` and the SB3 model on it (CPU), turning their refusals into ConfigErrors."""
    import stable_baselines3 as sb3

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            env = gym.make(env_id, **dict(cfg.get("env_kwargs") or {}))
        except (InputError, TypeError) as exc:  # an unknown keyword argument is a TypeError of the constructor
            raise EnvRefused(f"{where}: env_kwargs: {' '.join(str(exc).split())}") from None
        try:  # the policy name, the algorithm's action spaces and the hyperparameters' values, as SB3 checks them
            getattr(sb3, cfg["algo"].upper())(cfg["policy"], env, device="cpu", **(cfg.get("hyperparams") or {}))
        except (ValueError, TypeError, AssertionError, KeyError) as exc:
            raise ConfigError(f"{where}: algo/policy/hyperparams: {' '.join(str(exc).split())[:200]}") from None
        finally:
            env.close()


def make_env(env_id: str, cfg: dict[str, Any], n_envs: int, seed: int) -> Any:
    """SB3 vector env of ``n_envs`` copies; ``vec_env: subproc`` runs them in worker processes.

    The workers import ``sensor_envs`` through the ``"sensor_envs:<id>"`` form of the id, so spawn and
    forkserver start methods find the registered ids. ``vec_env: vector`` steps all copies with the id's
    gymnasium vector entry point (Neato-v0: one batched raycast) through
    :func:`sensor_envs.envs.sb3_vec.make_sb3_vector_env`.
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if cfg.get("vec_env") == "vector":
        from sensor_envs.envs.sb3_vec import make_sb3_vector_env

        return make_sb3_vector_env(env_id, n_envs, seed=seed, env_kwargs=dict(cfg.get("env_kwargs") or {}))
    subproc = cfg.get("vec_env") == "subproc" and n_envs > 1
    return make_vec_env(
        f"sensor_envs:{env_id}",
        n_envs=n_envs,
        seed=seed,
        env_kwargs=dict(cfg.get("env_kwargs") or {}),
        vec_env_cls=SubprocVecEnv if subproc else DummyVecEnv,
    )


def train(
    env_id: str, cfg: dict[str, Any], out: Path, seed: int, progress_bar: bool = True, tensorboard: bool = True
) -> dict[str, Any]:
    """Train with ``cfg`` into ``out``; returns the final evaluation summary."""
    import stable_baselines3 as sb3
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
    from stable_baselines3.common.evaluation import evaluate_policy

    n_envs = int(cfg.get("n_envs", 1))
    venv = make_env(env_id, cfg, n_envs, seed)
    eval_env = make_env(env_id, {**cfg, "vec_env": "dummy"}, 1, seed + 10_000)
    algo = getattr(sb3, cfg["algo"].upper())
    tb_log = str(out / "tb") if tensorboard and _has_tensorboard() else None
    model = algo(
        cfg["policy"],
        venv,
        seed=seed,
        verbose=0,
        device=cfg.get("device", "auto"),
        tensorboard_log=tb_log,
        **(cfg.get("hyperparams") or {}),
    )
    if tb_log is None:  # else SB3 makes an empty folder in the system's temp dir per run
        from stable_baselines3.common.logger import configure

        model.set_logger(configure(str(out / "log"), ["csv"]))
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
    warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")  # subproc, vector
    model.learn(total_timesteps=int(cfg["n_timesteps"]), callback=callbacks, progress_bar=progress_bar)
    model.save(out / "final_model")
    mean, std = evaluate_policy(model, eval_env, n_eval_episodes=int(cfg.get("eval_episodes", 5)))
    venv.close()
    eval_env.close()
    return {
        "env_id": env_id,
        "seed": seed,
        "mean_return": float(np.asarray(mean)),
        "std_return": float(np.asarray(std)),
        "n_timesteps": int(cfg["n_timesteps"]),
        "algo": cfg["algo"],
        "device": str(model.device),
    }


def _has_tensorboard() -> bool:
    """Whether TensorBoard logging is available (the ``train`` extra installs it)."""
    import importlib.util

    return importlib.util.find_spec("tensorboard") is not None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``sensor-envs train``."""
    parser.add_argument("--env", required=True, help="registered env id, e.g. sensor_envs/Neato-v0")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="YAML config (default: the shipped one)")
    parser.add_argument("--out", type=Path, required=True, help="run folder (refused if it exists, unless --force)")
    parser.add_argument("--seed", type=int, default=None, help="drawn and logged when absent (at most 2**32 - 1)")
    parser.add_argument("--algo", choices=ALGOS, default=None, help="use the config's block for this algorithm")
    parser.add_argument("--sensor", default=None, help="the env's radar (highway ids) or lidar (Neato) name")
    parser.add_argument("--device", default=None, help="torch device: auto (default), cpu, cuda, cuda:1, ...")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config entry")
    parser.add_argument("--force", action="store_true", help="replace an existing --out (whole, when the run ends)")


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Resolve the config, log it, train, and write ``result.json`` (``args`` from :func:`add_arguments`).

    Raises:
        InputError: a bad config or argument (``ConfigError``) or an unsafe ``--out`` (``OutputError``), before
            anything is written; the command line shows it as one line with exit status 2.
    """
    from sensor_envs.outputs import OutputTransaction, check_output

    if args.env not in gym.registry:
        raise ConfigError(f"--env: {args.env!r} is not a registered env id")
    cfg = load_config(args.config, args.env, args.set, algo=args.algo, sensor=args.sensor)
    # --out is replaced as a whole: it must not be, or hold, a file the run reads
    check_output(args.out, inputs=config_inputs(args.config, cfg), force=args.force, folder=True)
    if args.seed is not None and not 0 <= args.seed < 2**32:  # numpy and SB3 seed with 32 bits
        raise ConfigError(f"--seed: expected an integer in [0, 2**32 - 1], got {args.seed}")
    if args.device is not None:
        cfg["device"] = check_device(args.device)
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy) % 2**31  # type: ignore[arg-type]
    resolved = {"env_id": args.env, "seed": seed, "config": cfg, "command": [sys.executable, *sys.argv]}
    # Built in the claimed temporary folder, replacing --out as a whole when it ends: with --force an old
    # run's checkpoints and logs never mix with this one's; an interrupted run leaves --out as it was.
    with OutputTransaction() as tx:
        folder = tx.folder(args.out)
        (folder / "config.json").write_text(json.dumps(resolved, indent=2))
        result = train(args.env, cfg, folder, seed)
        (folder / "result.json").write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))
    return result


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """``sensor-envs train`` with ``argv`` (default: ``sys.argv[1:]``); returns the final evaluation summary."""
    parser = argparse.ArgumentParser(
        prog="sensor-envs train", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_arguments(parser)
    try:
        return run(parser.parse_args(argv))
    except InputError as err:
        _fail(" ".join(str(err).split()))


def _fail(message: str) -> NoReturn:
    """Print one line to stderr and exit with status 2."""
    print(f"sensor-envs train: error: {message}", file=sys.stderr)
    raise UsageExit(message)


if __name__ == "__main__":
    main()
