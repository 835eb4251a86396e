"""The robustness matrix's inputs, checked before ``--out`` is made (``sensor-envs robustness``).

Every option is resolved as the jobs will resolve it (:func:`check_jobs`: each row's training config, each
column's env), ``--address`` is answered (:func:`check_address`, :func:`connect_ray`), ``--real-data`` holds
what the domain fits its real-data model on (:func:`real_source`), and ``--out`` is no place where an input
would be written over (:func:`check_out`). A refusal is a :class:`UsageError` naming the option.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

from sensor_envs.inputs import InputError

__all__ = [
    "UsageError",
    "REAL_COLUMNS",
    "REAL_SOURCES",
    "WRITTEN",
    "real_source",
    "real_model_paths",
    "fit_real_models",
    "check_jobs",
    "check_address",
    "check_out",
    "connect_ray",
]


class UsageError(InputError):
    """A bad argument or an output folder made with other settings (one line naming the key)."""


REAL_COLUMNS = {"neato": "learned-real", "highway": "kde-astyx"}
"""The real-data column of each domain's matrix."""
REAL_SOURCES = {"neato": "neato_mar27_train.npz", "highway": "astyx_hires2019"}
"""What ``--real-data`` must hold per domain: the real log the real-data column's model is fitted on."""


def real_source(domain: str, data: Path) -> Path:
    """The real log in ``data`` the domain's real-data model is fitted on (checked before anything is written).

    Raises:
        UsageError: ``"--real-data ...: ... not found"``.
    """
    src = Path(data) / REAL_SOURCES[domain]
    if not (src.is_file() if domain == "neato" else src.is_dir()):
        raise UsageError(f"--real-data {data}: {src} not found (expected {REAL_SOURCES[domain]} there)")
    return src


def real_model_paths(domain: str, out: Path) -> dict[str, str]:
    """Column -> path of the real-data model cached in ``<out>/real_models/`` (fitted by :func:`fit_real_models`)."""
    name = "neato_lidar_real.npz" if domain == "neato" else "radar_kde_astyx.npz"
    return {REAL_COLUMNS[domain]: str(Path(out) / "real_models" / name)}


def fit_real_models(domain: str, data: Path, out: Path) -> dict[str, str]:
    """Fit the real-data sensor model once and cache it in ``<out>/real_models/``; returns column -> path."""
    src = real_source(domain, data)
    ((column, name),) = real_model_paths(domain, out).items()
    path = Path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file():
        tmp = path.parent / f".tmp_{path.name}"
        if domain == "neato":
            from sensor_envs.lidar.log import load_log
            from sensor_envs.lidar.lwlr import LidarLWLR

            LidarLWLR().fit(load_log(src)).save(tmp)
        else:
            from sensor_envs.radar.astyx import load_astyx
            from sensor_envs.radar.kde import KDERadarModel

            KDERadarModel(use_prev=False, cv_group="sequence", random_state=0).fit(load_astyx(src)).save(tmp)
        saved = tmp if tmp.is_file() else tmp.with_suffix(".npz")
        os.replace(saved, path)
    return {column: str(path)}


def check_jobs(args: argparse.Namespace, settings: dict[str, Any], real_models: dict[str, str], env_id: str) -> None:
    """Resolve every job's training config and every column's env as the jobs will, before anything is written.

    A job that would fail (an ``--algo`` without a block in the config, a ``--set`` the config refuses, a
    sensor whose env keywords the env refuses) is refused here, naming the option, instead of failing
    inside a job process after ``--out`` was made.

    Raises:
        UsageError: naming the option (and the config file and key).
    """
    from sensor_envs.training import train as train_mod

    overrides = [f"{k}={json.dumps(v)}" for k, v in settings["set"].items()]
    if settings["hyperparams"] and settings["algo"] in (None, "ppo"):
        overrides.append(f"hyperparams={json.dumps(settings['hyperparams'])}")
    algo_option = "--algo" if args.algo else f"--preset {args.preset} (algo)"
    config = Path(settings["config"])
    try:
        for row in settings["rows"]:
            train_mod.load_config(
                config, env_id, overrides, algo=settings["algo"], sensor=row, algo_option=algo_option,
                sensor_option="--sensors", set_keys=[item.partition("=")[0] for item in args.set],
            )  # fmt: skip
        for col in settings["columns"]:
            if col not in real_models:
                train_mod.load_config(config, env_id, [], sensor=col, sensor_option="--columns")
    except train_mod.ConfigError as err:
        raise UsageError(str(err)) from None


def check_address(address: str | None, timeout: float = 10.0) -> None:
    """``--address``: ``auto``, ``local``, ``HOST:PORT`` or ``ray://HOST:PORT``, and something answers there.

    ``ray.init`` waits for minutes on an address where no cluster runs; a TCP connection that fails within
    ``timeout`` seconds is refused here first.

    Raises:
        UsageError: ``"--address ...: ..."``.
    """
    import re
    import socket

    if address is None or address in ("auto", "local"):
        return
    m = re.fullmatch(r"(?:ray://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):([0-9]{1,5})", address)
    if not m or not 1 <= int(m.group(2)) <= 65535:
        raise UsageError(f"--address {address!r:.80}: expected auto, local, HOST:PORT or ray://HOST:PORT")
    host = m.group(1).strip("[]")
    try:
        socket.create_connection((host, int(m.group(2))), timeout=timeout).close()
    except OSError as exc:
        raise UsageError(f"--address {address}: no Ray cluster answers there ({exc.strerror or exc})") from None


WRITTEN = ("settings.json", "matrix.md", "matrix.json", "matrix.png", "runs", "real_models")
"""What a run writes into ``--out`` (files, and folders it fills)."""


def check_out(args: argparse.Namespace) -> None:
    """``--out`` (written into, kept across reruns) is a folder in which no input would be written over.

    Refused: ``--out`` inside the ``--real-data`` folder or holding it (never write beside real data), and
    a ``--config`` at a place the run writes (``settings.json``, ``matrix.*``, ``runs/``, ``real_models/``).

    Raises:
        UsageError: naming ``--out`` and the input.
    """
    from sensor_envs.outputs import _inside

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: exists and is not a folder")
    if args.real_data and (_inside(out, Path(args.real_data)) or _inside(Path(args.real_data), out)):
        raise UsageError(f"--out {out}: lies in, or holds, the --real-data folder {args.real_data}")
    if any(_inside(Path(args.config), out / name) for name in WRITTEN):
        raise UsageError(f"--out {out}: the run would write over the --config file {args.config}")


def connect_ray(args: argparse.Namespace) -> bool:
    """With ``--backend ray``, start or join the Ray instance before ``--out`` is made; whether it was started.

    Raises:
        UsageError: ``"--address ...: ..."`` when no cluster is found there.
    """
    if args.backend != "ray":
        return False
    import ray

    if ray.is_initialized():
        return False
    try:
        ray.init(address=args.address, num_cpus=None if args.address else args.workers, include_dashboard=False)
    except ConnectionError as exc:
        raise UsageError(f"--address {args.address}: {' '.join(str(exc).split())}") from None
    return True
