"""``sensor-envs record|fit|validate lidar``: record a rig log, fit the learned lidar, validate it.

    sensor-envs record lidar --out LOG.npz [--map NAME] [--poses N] [--repeats R] [--seed S] [--unit-seed U]
    sensor-envs fit lidar LOG --out MODEL [--variant seed|extended] [--folds 10] [--seed S] [LOG OPTIONS]
        [--max-range M] [--spur-above M] [--table-range-step M] [--max-readings N] [--cv-block-scans N]
    sensor-envs validate lidar MODEL LOG --out DIR [--card] [LOG OPTIONS]

LOG OPTIONS: ``--map FILE`` (any map ``sensor_envs.maps.load_map`` reads, ROS map_server YAML included;
replaces the log's map), ``--align`` (scan-match the log's odometry poses onto the ``--map`` grid),
``--part all|train|test`` with ``--block-scans N --test-every K`` (blocks of N consecutive scans, every
K-th held out). A log without a map and without ``--map`` (CARMEN) gets a nominal map built from its
TRAINING blocks only, in ``fit`` and in ``validate`` alike. Logs with one reading per pose and bearing
are fitted per reading and validated per reading (held-out NLL, null-rate calibration, PIT, lag-1 ACF).

``fit`` also writes the model card ``MODEL.md``; ``validate --card`` rewrites it with the validation.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np


def register(verbs: dict[str, argparse._SubParsersAction[argparse.ArgumentParser]]) -> None:
    """Add the ``lidar`` sub-commands under each verb parser in ``verbs``."""
    rec = verbs["record"].add_parser("lidar", help="record a static-pose log from the reference Neato rig")
    rec.add_argument("--out", required=True, help="output log (.npz)")
    rec.add_argument("--map", default="seed_room", help="map name or file (default: seed_room)")
    rec.add_argument("--poses", type=int, default=30, help="number of static poses (default: 30)")
    rec.add_argument("--repeats", type=int, default=200, help="readings per pose and bearing (default: 200)")
    rec.add_argument("--seed", type=int, default=0, help="seed of poses, map error and noise (default: 0)")
    rec.add_argument("--unit-seed", type=int, default=0, help="seed of the rig unit's bias (default: 0)")
    rec.set_defaults(func=_record)
    fit = verbs["fit"].add_parser("lidar", help="fit the per-bearing LWLR lidar model to a log")
    fit.add_argument("log", help="lidar log (.npz, CARMEN log or ROS bag)")
    fit.add_argument("--out", required=True, help="output model file (.npz); the card goes to MODEL.md")
    fit.add_argument("--variant", choices=("seed", "extended"), default="extended")
    fit.add_argument("--folds", type=int, default=10, help="cross-validation folds (default: 10)")
    fit.add_argument("--seed", type=int, default=0, help="seed of the fold assignment (default: 0)")
    fit.add_argument("--note", action="append", default=[], help="a line for the model card (e.g. how LOG was made)")
    fit.add_argument("--max-range", type=float, default=5.0, help="sensor's maximum range [m] (default: 5)")
    fit.add_argument("--spur-above", type=float, default=6.0, help="spurious far returns beyond this [m] (default: 6)")
    fit.add_argument("--table-range-step", type=float, default=0.125, help="range step of the tables [m]")
    fit.add_argument("--max-readings", type=int, default=300, help="per-reading fit: scans used (default: 300)")
    fit.add_argument(
        "--cv-block-scans", type=int, default=None, help="per-reading fit: CV block length (default: auto)"
    )
    _log_options(fit)
    fit.set_defaults(func=_fit)
    val = verbs["validate"].add_parser("lidar", help="compare a lidar model and its baselines with a log")
    val.add_argument("model", help="model file (.npz)")
    val.add_argument("log", help="lidar log")
    val.add_argument("--out", required=True, help="output folder (report.json, report.md, plots)")
    val.add_argument("--card", action="store_true", help="rewrite MODEL.md with this validation")
    _log_options(val)
    val.set_defaults(func=_validate)


def _log_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", default=None, help="map file (segments, JSON/YAML, ROS map_server YAML) for the log")
    p.add_argument("--align", action="store_true", help="scan-match the odometry poses onto the --map grid")
    p.add_argument("--part", choices=("all", "train", "test"), default="all", help="scans used (default: all)")
    p.add_argument("--block-scans", type=int, default=40, help="scans per block of the train/test split (default: 40)")
    p.add_argument("--test-every", type=int, default=4, help="every K-th block is the test part (default: 4)")


def _prepared_log(args: argparse.Namespace, max_range: float):  # noqa: ANN202
    from sensor_envs.lidar.log import load_log  # noqa: PLC0415
    from sensor_envs.lidar.mapping import prepare_log  # noqa: PLC0415

    return prepare_log(
        load_log(args.log),
        map=args.map,
        part=args.part,
        block_scans=args.block_scans,
        test_every=args.test_every,
        max_range=max_range,
        align=args.align,
    )


def _command() -> str:
    return "sensor-envs " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def _record(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.log import save_log  # noqa: PLC0415
    from sensor_envs.lidar.rig import NeatoRig  # noqa: PLC0415
    from sensor_envs.maps import load_map  # noqa: PLC0415

    log, _ = NeatoRig(unit_seed=args.unit_seed).record(
        load_map(args.map).segments, np.random.default_rng(args.seed), n_poses=args.poses, repeats=args.repeats
    )
    path = save_log(log, args.out)
    print(f"wrote {path}: {log.n_poses} poses x {log.n_bearings} bearings x {log.ranges.shape[2]} repeats")
    return 0


def _fit(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.lwlr import LidarLWLR  # noqa: PLC0415
    from sensor_envs.lidar.validate import fit_gaussian_lidar, model_card_markdown  # noqa: PLC0415

    log, prep = _prepared_log(args, args.max_range)
    t0 = time.perf_counter()
    model = LidarLWLR(
        variant=args.variant,
        n_folds=args.folds,
        random_state=args.seed,
        max_range=args.max_range,
        spur_above=args.spur_above,
        table_range_step=args.table_range_step,
    )
    if log.ranges.shape[2] == 1:
        from sensor_envs.lidar.mapping import map_features  # noqa: PLC0415
        from sensor_envs.lidar.validate_readings import fit_gaussian_readings  # noqa: PLC0415

        model.fit(log, max_readings=args.max_readings, block_scans=args.cv_block_scans)
        r, a = map_features(log.poses, log.bearings, log.require_map(), model.max_range)
        g = fit_gaussian_readings(log, r, a, model.spur_above)
    else:
        model.fit(log)
        g = fit_gaussian_lidar(log, model.spur_above, model.max_range)
    model.card_extra_ = {
        "log_preparation": prep,
        "gaussian_baseline": {k: float(v) for k, v in vars(g).items()},
        "fit_seconds": time.perf_counter() - t0,
        "commands": [*args.note, _command()],
    }
    path = model.save(args.out)
    path.with_suffix(".md").write_text(model_card_markdown(model, model.card_extra_["commands"]))
    print(f"wrote {path} and {path.with_suffix('.md')} in {time.perf_counter() - t0:.1f} s; kernel widths {model.h_}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.lwlr import LidarLWLR  # noqa: PLC0415
    from sensor_envs.lidar.validate import metrics_markdown, model_card_markdown, validate  # noqa: PLC0415
    from sensor_envs.lidar.validate_readings import readings_markdown  # noqa: PLC0415

    model = LidarLWLR.load(args.model)
    log, prep = _prepared_log(args, model.max_range)
    report = validate(model, log, args.out)
    if "calibration" in next(iter(report["metrics"].values())):  # per-reading report (scans at moving poses)
        print(readings_markdown(report["metrics"]))
        report["log_preparation"] = prep
        (Path(args.out) / "report.json").write_text(json.dumps(report, indent=2, default=float))
        if args.card:
            raise ValueError(f"{args.model}: --card needs a repeated log (Table I); not written")
    else:
        print(metrics_markdown(report["metrics"]))
    if args.card:
        card = Path(args.model).with_suffix(".md")
        cmds = [*model.card_extra_.get("commands", ["sensor-envs fit lidar ..."]), _command()]
        card.write_text(model_card_markdown(model, cmds, report))
        print(f"rewrote {card}")
    print(f"wrote {Path(args.out) / 'report.json'}")
    return 0
