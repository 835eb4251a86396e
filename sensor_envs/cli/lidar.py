"""``sensor-envs record|fit|validate lidar``: record a rig log, fit the learned lidar, validate it.

    sensor-envs record lidar --out LOG.npz [--rig RIG.json] [--map NAME] [--poses N] [--repeats R] [--seed S]
        [--unit-seed U]
    sensor-envs calibrate lidar REAL_DATA --out RIG.json [--seed S] [--max-evals N] [--spurious-only RIG]
    sensor-envs fit lidar LOG --out MODEL [--variant seed|extended] [--folds 10] [--seed S]
        [--bias-model pooled|per_bearing] [LOG OPTIONS]
        [--max-range M] [--spur-above M] [--table-range-step M] [--max-readings N] [--cv-block-scans N]
    sensor-envs validate lidar MODEL LOG --out DIR [--card] [LOG OPTIONS]

LOG OPTIONS: ``--map FILE`` (any map ``sensor_envs.maps.load_map`` reads, ROS map_server YAML included;
replaces the log's map), ``--align`` (scan-match the log's odometry poses onto the ``--map`` grid),
``--part all|train|test`` with ``--block-scans N --test-every K`` (blocks of N consecutive scans, every
K-th held out), ``--bearings N`` (resample to N evenly spaced bearings from 0 deg, nearest logged beam: a
361-beam ROS scan onto the Neato world's 360). A log without a map and without ``--map`` (CARMEN) gets a
nominal map built from its TRAINING blocks only, in ``fit`` and in ``validate`` alike. Logs with one reading
per pose and bearing are fitted per reading and validated per reading (held-out NLL, null-rate calibration,
PIT, lag-1 ACF).

``fit`` also writes the model card ``MODEL.md``; ``validate --card`` rewrites it with the validation.
``record`` records from a rig file (default: the shipped calibrated ``models/neato_rig.json``);
``calibrate`` fits a rig file to a real static-pose log (the ``.npz`` or its folder) by simulation.
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.cli.args import OneLineParser, about, add_force, nonneg_int, positive_float, positive_int, printable
from sensor_envs.inputs import InputError
from sensor_envs.modelio import read_model
from sensor_envs.outputs import OutputTransaction, check_inputs, check_output, write_json

_REAL_NAME = "neato_mar27_train.npz"


def register(verbs: dict[str, argparse._SubParsersAction[OneLineParser]]) -> None:
    """Add the ``lidar`` sub-commands under each verb parser in ``verbs``."""
    rec = verbs["record"].add_parser("lidar", help="record a static-pose log from the reference Neato rig")
    rec.add_argument("--out", required=True, help="output log (.npz)")
    rec.add_argument(
        "--rig", default=None, help="rig file (.json) to record from (default: the shipped models/neato_rig.json)"
    )
    rec.add_argument("--map", default="seed_room", help="map name or file (default: seed_room)")
    rec.add_argument("--poses", type=positive_int, default=30, help="number of static poses (default: 30)")
    rec.add_argument("--repeats", type=positive_int, default=200, help="readings per pose and bearing (default: 200)")
    rec.add_argument("--seed", type=nonneg_int, default=0, help="seed of poses, map error and noise (default: 0)")
    rec.add_argument(
        "--unit-seed", type=nonneg_int, default=None, help="seed of the rig unit's bias (default: the rig file's)"
    )
    add_force(rec)
    rec.set_defaults(func=_record)
    cal = verbs["calibrate"].add_parser("lidar", help="fit the Neato rig's parameters to a real static-pose log")
    cal.add_argument("real_data", metavar="REAL_DATA", help=f"real log (.npz) or the folder holding {_REAL_NAME}")
    cal.add_argument("--out", required=True, help="output rig file (.json)")
    cal.add_argument("--seed", type=nonneg_int, default=0, help="seed of the common random numbers (default: 0)")
    cal.add_argument(
        "--max-evals", type=positive_int, default=None, help="most simulations of the search (default: 200)"
    )
    cal.add_argument(
        "--spurious-only",
        metavar="RIG",
        default=None,
        help="no search: RIG (a rig file) with only its spurious-prone law re-derived from REAL_DATA "
        "(the near-cell law, cut and shrinkage by leave-poses-out CV); its other parameters are kept",
    )
    add_force(cal)
    cal.set_defaults(func=_calibrate)
    fit = verbs["fit"].add_parser("lidar", help="fit the per-bearing LWLR lidar model to a log")
    fit.add_argument("log", help="lidar log (.npz, CARMEN log or ROS bag)")
    fit.add_argument("--out", required=True, help="output model file (.npz); the card goes to MODEL.md")
    fit.add_argument(
        "--variant",
        choices=("seed", "extended"),
        default="extended",
        help="seed: the paper's model; extended: + spurious returns, pooling, persistence (default)",
    )
    fit.add_argument("--folds", type=positive_int, default=10, help="cross-validation folds (default: 10)")
    fit.add_argument("--seed", type=nonneg_int, default=0, help="seed of the fold assignment (default: 0)")
    fit.add_argument(
        "--bias-model",
        choices=("pooled", "per_bearing"),
        default="pooled",
        help="pooled: a trend over all bearings + a per-bearing part weighted by CV (default, format 6); "
        "per_bearing: the per-bearing bias alone (the fit before format 6)",
    )
    add_force(fit)
    fit.add_argument("--note", action="append", default=[], help="a line for the model card (e.g. how LOG was made)")
    fit.add_argument(
        "--max-range",
        type=positive_float,
        default=None,
        help="sensor's maximum range [m] (default: the Neato's 5 for a .npz log; required for CARMEN logs, ROS bags)",
    )
    fit.add_argument(
        "--spur-above",
        type=positive_float,
        default=None,
        help="spurious far returns beyond this [m] (default: max range + 1)",
    )
    fit.add_argument("--table-range-step", type=positive_float, default=0.125, help="range step of the tables [m]")
    fit.add_argument(
        "--max-readings", type=positive_int, default=300, help="per-reading fit: scans used (default: 300)"
    )
    fit.add_argument(
        "--cv-block-scans", type=positive_int, default=None, help="per-reading fit: CV block length (default: auto)"
    )
    _log_options(fit)
    fit.set_defaults(func=_fit)
    val = verbs["validate"].add_parser("lidar", help="compare a lidar model and its baselines with a log")
    val.add_argument("model", help="model file (.npz)")
    val.add_argument("log", help="lidar log")
    val.add_argument("--out", required=True, help="output folder (report.json, report.md, plots)")
    val.add_argument("--card", action="store_true", help="rewrite MODEL.md with this validation")
    add_force(val)
    _log_options(val)
    val.set_defaults(func=_validate)


def _log_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", default=None, help="map file (segments, JSON/YAML, ROS map_server YAML) for the log")
    p.add_argument("--align", action="store_true", help="scan-match the odometry poses onto the --map grid")
    p.add_argument("--part", choices=("all", "train", "test"), default="all", help="scans used (default: all)")
    p.add_argument(
        "--block-scans", type=positive_int, default=40, help="scans per block of the train/test split (default: 40)"
    )
    p.add_argument("--test-every", type=positive_int, default=4, help="every K-th block is the test part (default: 4)")
    p.add_argument(
        "--bearings",
        type=positive_int,
        default=None,
        metavar="N",
        help="resample the log to N bearings evenly spaced from 0 deg counter-clockwise, each taking the nearest "
        "logged beam (360: a 361-beam ROS LaserScan over -180..180 deg on the Neato world's bearings); default: "
        "the logged beams as they are",
    )


BEYOND_RANGE_SHARE = 0.01
"""Largest share of a log's returns just beyond a maximum range that is a default, not the user's."""
NEAR_BEYOND = 1.5
"""Returns within ``(max_range, 1.5 max_range]`` count as "just beyond" (the sensor sees that far)."""


def check_range_fits(log: Any, max_range: float, source: str, remedy: str = "give --max-range, this sensor's") -> None:
    """Refuse a maximum range that the log's sensor demonstrably exceeds.

    More than 1 % of the returns just beyond it (within ``(max_range, 1.5 max_range]``) mean the sensor
    reaches farther (intel's SICK: 8 % between 5 and 7.5 m). Spurious far returns, which the model
    keeps apart (the Neato's lie near 17 m, 3 % of its returns), do not count. ``source`` says where
    ``max_range`` came from (the ``--max-range`` default, or the model being validated).

    Raises:
        InputError: naming the log, its field ``ranges``, the share of returns just beyond and the largest one.
    """
    r = np.asarray(log.ranges, dtype=np.float64)
    ret = r[np.isfinite(r) & (r > 0)]
    near = (ret > max_range * (1 + 1e-9)) & (ret <= NEAR_BEYOND * max_range)
    if ret.size and near.mean() > BEYOND_RANGE_SHARE:
        raise InputError(
            f"{log.source}: field 'ranges': {100 * near.mean():.1f} % of the returns lie between {max_range:g} and "
            f"{NEAR_BEYOND * max_range:g} m, beyond the maximum range {max_range:g} m ({source}): {remedy}"
        )


def _prepared_log(args: argparse.Namespace, max_range: float, source: str | None = None, *remedy: str):
    """The log, checked against a maximum range that is not the user's (``source`` says whose), prepared."""
    from sensor_envs.lidar.log import load_log, resample_bearings
    from sensor_envs.lidar.mapping import prepare_log

    log = load_log(args.log)
    if source is not None:
        check_range_fits(log, max_range, source, *remedy)
    if args.bearings is not None:
        log = resample_bearings(log, args.bearings)
    return prepare_log(
        log,
        map=args.map,
        part=args.part,
        block_scans=args.block_scans,
        test_every=args.test_every,
        max_range=max_range,
        align=args.align,
    )


NEATO_MAX_RANGE = 5.0
"""The Neato XV-11's maximum range [m]: the default of ``--max-range`` for the project's ``.npz`` logs only."""
MAX_TABLE_CELLS = 4000
"""Most range cells of a table: ``spur_above / table_range_step`` (``--table-range-step 1e-9`` would need 37 GiB)."""


def range_options(log: str, max_range: float | None, spur_above: float | None, step: float) -> tuple[float, float]:
    """``(max_range, spur_above)`` for a lidar fit on ``log``, checked against each other and the table step.

    The Neato's 5 m is the default only for the project's ``.npz`` logs: a CARMEN log or a ROS bag comes
    from another sensor (intel's SICK reaches 80 m), so ``--max-range`` must then be given.

    Raises:
        InputError: naming the option.
    """
    if max_range is None:
        if Path(log).suffix != ".npz":
            raise InputError(
                f"--max-range: required for {log} (a CARMEN log or ROS bag): the default {NEATO_MAX_RANGE:g} m is "
                "the Neato's; give this sensor's maximum range"
            )
        max_range = NEATO_MAX_RANGE
    spur = max_range + 1.0 if spur_above is None else spur_above
    if not spur > max_range:
        raise InputError(f"--spur-above: expected more than --max-range {max_range:g} m, got {spur:g}")
    if spur / step > MAX_TABLE_CELLS:
        raise InputError(
            f"--table-range-step: {step:g} m gives {spur / step:.0f} range cells up to {spur:g} m, more than "
            f"{MAX_TABLE_CELLS}; use a step of at least {spur / MAX_TABLE_CELLS:.3g} m"
        )
    return max_range, spur


MAX_RECORD_READINGS = 500_000
"""Most ``--poses x --repeats`` of ``record lidar`` (x 360 bearings: ~1.4 GB of float64 readings)."""


def _command() -> str:
    return printable("sensor-envs " + " ".join(shlex.quote(a) for a in sys.argv[1:]))


def _record(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.log import save_log
    from sensor_envs.lidar.rig import NeatoRig
    from sensor_envs.maps import load_map

    if args.poses * args.repeats > MAX_RECORD_READINGS:
        raise InputError(
            f"--poses x --repeats: {args.poses} x {args.repeats} readings per bearing, more than {MAX_RECORD_READINGS}"
        )
    check_inputs(args.rig)
    out = check_output(args.out, inputs=[args.map, args.rig], force=args.force, suffix=".npz")
    rig = NeatoRig.from_file(args.rig)
    if args.unit_seed is not None:
        rig = dataclasses.replace(rig, unit_seed=args.unit_seed)
    with about(args.map):  # e.g. a map without room for the poses names the map file
        log, _ = rig.record(
            load_map(args.map).segments, np.random.default_rng(args.seed), n_poses=args.poses, repeats=args.repeats
        )
    with OutputTransaction() as tx:
        save_log(log, tx.file(out))
    path = out
    print(f"wrote {path}: {log.n_poses} poses x {log.n_bearings} bearings x {log.ranges.shape[2]} repeats")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.calibrate import calibrate_rig, load_real_log, respurious_rig
    from sensor_envs.lidar.rig import NeatoRig

    if args.spurious_only is not None and args.max_evals is not None:
        raise InputError("--max-evals: --spurious-only runs no search; give one or the other")
    check_inputs(args.real_data, args.spurious_only)
    out = check_output(args.out, inputs=[args.real_data, args.spurious_only], force=args.force, suffix=".json")
    log = load_real_log(args.real_data)
    if args.spurious_only is not None:
        start = NeatoRig.from_file(args.spurious_only)
        rig, card = respurious_rig(
            log, start, args.spurious_only, seed=args.seed, card=NeatoRig.card_of(args.spurious_only)
        )
        b = card["spurious_refit"]["before"]["per_statistic"]
        before = args.spurious_only
    else:
        rig, card = calibrate_rig(log, seed=args.seed, max_evals=args.max_evals or 200)
        b, before = card["before"]["per_statistic"], "NeatoRig defaults"
    card["command"] = _command()
    with OutputTransaction() as tx:
        rig.to_file(tx.file(out), card)
    a = card["after"]["per_statistic"]
    print(f"discrepancy D before ({before}) {b['total']:.4g}, after {a['total']:.4g}")
    for k in b:
        if k != "total":
            print(f"  {k:20s} {b[k]:10.4g} -> {a[k]:10.4g}")
    law = card["spurious_law"] if args.spurious_only is None else card["spurious_refit"]["law"]
    cut, prior = law["cut_m"], law["prior_cells"]
    print(f"spurious-prone law: cells nearer than {cut:g} m, per-bearing shares shrunk by {prior:g} cells")
    if args.spurious_only is None:
        print(f"wrote {out} ({card['search']['evaluations']} simulations, {card['search']['seconds']} s)")
    else:
        print(f"wrote {out} (spurious-prone law of {args.spurious_only} re-derived, no search)")
    return 0


def lwlr_from_args(args: argparse.Namespace) -> Any:
    """The unfitted :class:`~sensor_envs.lidar.lwlr.LidarLWLR` that ``fit lidar`` with ``args`` fits."""
    from sensor_envs.lidar.lwlr import LidarLWLR

    max_range, spur_above = range_options(args.log, args.max_range, args.spur_above, args.table_range_step)
    return LidarLWLR(
        variant=args.variant,
        n_folds=args.folds,
        random_state=args.seed,
        max_range=max_range,
        spur_above=spur_above,
        table_range_step=args.table_range_step,
        bias_model=args.bias_model,
        verbose=True,  # bars only on a terminal (cli.main)
    )


def _fit(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.validate import fit_gaussian_lidar, model_card_markdown

    max_range, spur_above = range_options(args.log, args.max_range, args.spur_above, args.table_range_step)
    check_inputs(args.log, args.map)
    out = check_output(args.out, inputs=[args.log, args.map], force=args.force, suffix=".npz")
    card_out = check_output(
        out.with_suffix(".md"), inputs=[args.log, args.map], force=args.force, option="--out (model card)"
    )
    default = None if args.max_range is not None else f"the default, the Neato's {NEATO_MAX_RANGE:g} m"
    log, prep = _prepared_log(args, max_range, default)
    t0 = time.perf_counter()
    model = lwlr_from_args(args)
    # on stdout (the command's account, beside its last line): stderr keeps bad input's one line
    print(f"fitting {log.n_poses} scans x {log.n_bearings} bearings (kernel widths by cross-validation)", flush=True)
    with about(args.log):
        if log.ranges.shape[2] == 1:
            from sensor_envs.lidar.mapping import map_features
            from sensor_envs.lidar.validate_readings import fit_gaussian_readings

            model = model.fit(log, max_readings=args.max_readings, block_scans=args.cv_block_scans)
            r, a = map_features(log.poses, log.bearings, log.require_map(), model.max_range)
            g = fit_gaussian_readings(log, r, a, model.spur_above)
        else:
            model = model.fit(log)
        g = fit_gaussian_lidar(log, model.spur_above, model.max_range)
    model.update_card(
        {
            "log_preparation": prep,
            "gaussian_baseline": {k: float(v) for k, v in vars(g).items()},
            "fit_seconds": time.perf_counter() - t0,
            "commands": [*(printable(n) for n in args.note), _command()],
        }
    )
    with OutputTransaction() as tx:  # model and card: both or neither
        model.save(tx.file(out))
        tx.file(card_out).write_text(printable(model_card_markdown(model, model.card_["commands"])), encoding="utf-8")
    path = out
    print(f"wrote {path} and {path.with_suffix('.md')} in {time.perf_counter() - t0:.1f} s; kernel widths {model.h_}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.lidar.validate import metrics_markdown, model_card_markdown, validate
    from sensor_envs.lidar.validate_readings import readings_markdown

    check_inputs(args.model, args.log, args.map)
    inputs = [args.model, args.log, args.map]
    out = check_output(args.out, inputs=inputs, force=args.force, folder=True)
    card = Path(args.model).with_suffix(".md")
    if args.card:  # --card asks to rewrite the model's own card; it must still not be an input
        check_output(card, inputs=inputs, force=True, suffix=".md", option="--card")
    model = read_model(LidarLWLR, args.model)
    log, prep = _prepared_log(
        args, model.max_range, "the model's maximum range", "validate a model fitted on this sensor's logs"
    )
    per_reading = log.ranges.shape[2] == 1
    if args.card and per_reading:
        raise InputError(f"{args.model}: --card needs a repeated log (Table I); {args.log} has one reading per scan")
    with OutputTransaction() as tx:  # report folder and card: all or nothing
        folder = tx.folder(out)
        with about(args.log):
            report = validate(model, log, folder)
        if per_reading:  # per-reading report (scans at moving poses)
            print(readings_markdown(report["metrics"], Path(str(log.source)).name, log.n_poses))
            report["log_preparation"] = prep
            write_json(folder / "report.json", report)
        else:
            print(metrics_markdown(report["metrics"]))
            print(report.get("verdict", ""))
        if args.card:
            cmds = [*model.card_.get("commands", ["sensor-envs fit lidar ..."]), _command()]
            tx.file(card).write_text(printable(model_card_markdown(model, cmds, report)), encoding="utf-8")
    if args.card:
        print(f"rewrote {card}")
    print(f"wrote {Path(args.out) / 'report.json'}")
    return 0
