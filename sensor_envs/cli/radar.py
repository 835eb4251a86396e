"""``sensor-envs record|fit|validate radar``: rig/Astyx logs, KDE + Gaussian fits, validation reports."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.cli.args import (
    OneLineParser,
    about,
    add_force,
    float_between,
    nonneg_int,
    positive_float,
    positive_int,
)
from sensor_envs.inputs import InputError
from sensor_envs.modelio import data_reference, read_model
from sensor_envs.outputs import OutputTransaction, check_inputs, check_output


def register(verbs: dict[str, "argparse._SubParsersAction[OneLineParser]"]) -> None:
    """Add the ``radar`` sub-commands under each verb parser in ``verbs``."""
    rec = verbs["record"].add_parser("radar", help="record a radar object log from the reference rig (or Astyx)")
    rec.add_argument("--out", required=True, help="output CSV log")
    rec.add_argument("--seed", type=nonneg_int, default=0, help="seed of the rig's scenes and draws (default 0)")
    rec.add_argument("--sequences", type=positive_int, default=50, help="rig scenarios (default 50)")
    rec.add_argument("--cycles", type=positive_int, default=40, help="radar cycles per scenario (default 40)")
    rec.add_argument("--targets", type=positive_int, default=8, help="target boxes per scenario (default 8)")
    rec.add_argument("--cycle-time", type=positive_float, default=1.0, help="seconds between cycles (default 1.0)")
    rec.add_argument("--astyx", default=None, help="convert this astyx_hires2019 folder instead of the rig")
    rec.add_argument(
        "--rig",
        default=None,
        help="rig parameter file (.json; default: the shipped calibrated rig models/radar_rig.json)",
    )
    rec.add_argument(
        "--in-view-only",
        action="store_true",
        help="leave out target rows of boxes wholly outside the rig's field of view (never detectable, e.g. "
        "behind the sensor), as real reference annotations would (see models/radar_kde.md)",
    )
    add_force(rec)
    rec.set_defaults(func=_record)
    fit = verbs["fit"].add_parser("radar", help="fit the KDE radar model and its Gaussian baseline to a log")
    fit.add_argument("log", help="radar log CSV")
    fit.add_argument("--out", required=True, help="KDE model file (.npz); the baseline goes to <out>_gaussian.npz")
    fit.add_argument("--baseline-out", default=None, help="Gaussian baseline file (default <out>_gaussian.npz)")
    fit.add_argument("--no-prev", action="store_true", help="do not condition on z_{t-1} (for non-time-series logs)")
    fit.add_argument("--cycle-time", type=positive_float, default=None, help="seconds between frames of the log")
    fit.add_argument(
        "--cv-group",
        default="track",
        choices=("track", "sequence", "row"),
        help="what the relevance CV holds out together (default track)",
    )
    fit.add_argument(
        "--relevance",
        default="paper",
        choices=("paper", "cv", "cv_axes", "cv_state"),
        help="relevance kernel: the seed's (paper), the corner variance chosen by CV on this log (cv), the x "
        "and y variances chosen apart (cv_axes), or those and then the z_{t-1} variance (cv_state); with "
        "--state-transform polar the CV modes choose range and azimuth",
    )
    fit.add_argument(
        "--relevance-candidates",
        type=positive_float,
        nargs="+",
        default=None,
        help="corner variances [m^2] the CV tries (default 3 6 12 24 48)",
    )
    fit.add_argument(
        "--relevance-candidates-prev",
        type=positive_float,
        nargs="+",
        default=None,
        help="z_{t-1} variances [m^2] the CV of --relevance cv_state tries (default 0.03 0.06 0.12 0.24 0.48 0.96)",
    )
    fit.add_argument(
        "--bandwidth-scale",
        type=float_between(0.01, 100.0),  # the model's accepted range (KDERadarModel's constraint)
        default=1.0,
        help="factor on the contribution bandwidths the CV chose (default 1; the shipped KDE's factor was chosen "
        "on real frames: sensor-envs tune radar --what bandwidth)",
    )
    fit.add_argument(
        "--start-bandwidth-scale",
        type=float_between(0.01, 100.0),
        default=None,
        help="the same factor for the start trees (new tracks, after a miss; default: --bandwidth-scale's)",
    )
    fit.add_argument(
        "--tail-weight",
        type=float_between(0.0, 0.5),
        default=0.0,
        help="share w of the detection density in the wide tail kernels, (1-w) KDE_h + w KDE_{c h} (default 0: "
        "none; chosen on real held-out frames by sensor-envs tune radar --what tail)",
    )
    fit.add_argument(
        "--tail-scale",
        type=float_between(1.0, 100.0),
        default=4.0,
        help="factor c of the tail kernels' bandwidths over the main kernels' (default 4)",
    )
    fit.add_argument(
        "--state-transform",
        default="cartesian",
        choices=("cartesian", "polar"),
        help="corner features of the relevance kernel: corner x, y (the paper's) or range, azimuth",
    )
    fit.add_argument(
        "--output-frame",
        default="cartesian",
        choices=("cartesian", "polar"),
        help="frame the kernels act on the outputs in: the sensor's x, y (the paper's) or the corner's radial and "
        "outward cross-range axes (offsets toward the outer end of a face then pool across the boresight)",
    )
    fit.add_argument(
        "--azimuth-bias",
        type=_azimuth_bias,
        default=0.0,
        help="the radar's mounting yaw error [rad] undone before the kernels (counter-clockwise positive), or 'fit' "
        "to estimate it from the log's detections (default 0: none)",
    )
    fit.add_argument(
        "--extra-state",
        nargs="+",
        default=[],
        metavar="NAME",
        help="extra state variables of both models: numeric log columns or derived features (occluded, aspect, "
        "range, azimuth, rel_speed); the KDE's variances by CV, the Gaussian's linear terms (default: none)",
    )
    fit.add_argument("--seed", type=nonneg_int, default=0, help="seed of the CV folds and the model (default 0)")
    add_force(fit)
    fit.set_defaults(func=_fit)
    cal = verbs["calibrate"].add_parser(
        "radar", help="fit the reference radar rig's parameters to real single frames (simulation-based)"
    )
    cal.add_argument("real_data", help="astyx_hires2019 folder, or a radar log CSV of single frames")
    cal.add_argument("--out", required=True, help="rig parameter file to write (.json)")
    cal.add_argument("--seed", type=nonneg_int, default=0, help="seed of the common random numbers (default 0)")
    cal.add_argument(
        "--max-evals", type=positive_int, default=1500, help="evaluations of the offset stage (default 1500)"
    )
    cal.add_argument(
        "--signed-azimuth",
        action="store_true",
        help="fit a signed (left/right) azimuth detection table instead of the symmetric |azimuth| one "
        "(generalises worse across Astyx frames held out: docs/history/scripts/real_radar_calibration_cv.py)",
    )
    cal.add_argument(
        "--occlusion-by-range",
        action="store_true",
        help="fit the occlusion loss per range knot (a hidden box is lost more often near the sensor) with the "
        "detection rate per range x occluded-fraction cell in the fit, instead of one loss for every range",
    )
    cal.add_argument(
        "--offset-law",
        choices=["reflection", "mixture"],
        default="reflection",
        help="offset law: the reflection-point law's parameters by Powell on the energy distance (default), or "
        "a Gaussian mixture per range bin in the closest corner's polar frame (EM, component count by CV)",
    )
    cal.add_argument(
        "--mixture-max-components",
        type=positive_int,
        default=6,
        help="--offset-law mixture: the CV tries 1..N components per range bin (default 6)",
    )
    cal.add_argument(
        "--mixture-min-range",
        type=positive_float,
        default=None,
        metavar="M",
        help="--offset-law mixture: the mixture only from this closest-corner range [m] on; nearer boxes keep "
        "the reflection-point law, fitted too (default: the mixture at every range)",
    )
    cal.add_argument(
        "--azimuth-bias",
        action="store_true",
        help="also fit the radar's mounting yaw error (every detection rotated about the sensor), by a 1-D "
        "search on the signed cross-range offsets; the laws are then fitted on the de-rotated data (2 rounds)",
    )
    cal.add_argument(
        "--scene",
        action="store_true",
        help="also fit the scene the rig records (box positions, headings, sizes) to the real reference boxes",
    )
    cal.add_argument(
        "--scene-only",
        action="store_true",
        help="with --base: only fit the scene law (seconds); the base rig's sensor laws and card are kept",
    )
    cal.add_argument(
        "--clutter-only",
        action="store_true",
        help="with --base: only refit the clutter law (count, and joint range x azimuth cell shares of the "
        "positions; seconds); the base rig's other laws and card are kept",
    )
    cal.add_argument(
        "--base",
        metavar="RIG.json",
        help="rig file to start from (its parameters are the starting point, and the source of those single "
        "frames cannot show; default: the generic rig)",
    )
    add_force(cal)
    cal.set_defaults(func=_calibrate)
    val = verbs["validate"].add_parser("radar", help="compare a KDE model and its baseline with a (held-out) log")
    val.add_argument("model", help="KDE model file (.npz)")
    val.add_argument(
        "log",
        help="radar log CSV, or an astyx_hires2019 folder; real single frames (no previous cycle) are also scored "
        "as static boxes: start tuple and stationary law next to the Gaussian and the ideal radar, with verdicts",
    )
    val.add_argument("--block", type=positive_int, default=10, help="frames per block of the bootstrap (default 10)")
    val.add_argument("--chains", type=positive_int, default=16, help="stationary law: rollouts per row (default 16)")
    val.add_argument("--cycles", type=positive_int, default=5, help="stationary law: cycles per rollout (default 5)")
    val.add_argument("--n-boot", type=positive_int, default=2000, help="block-bootstrap replicates (default 2000)")
    val.add_argument("--out", required=True, help="output folder for report.json and figures")
    val.add_argument(
        "--baseline",
        default=None,
        help="Gaussian baseline (default <model>_gaussian.npz; <name>_gaussian.npz for <name>_kde.npz)",
    )
    val.add_argument("--seed", type=nonneg_int, default=0, help="seed of the rollouts and draws (default 0)")
    add_force(val)
    val.set_defaults(func=_validate)


MAX_RECORD_ROWS = 1_000_000
"""Most target rows of ``record radar`` (``--sequences x --cycles x --targets``): the CSV (about 70 bytes a row,
clutter rows besides) stays within the radar log reader's limit (:data:`sensor_envs.radar.log.MAX_LOG_BYTES`)."""


def _record(args: argparse.Namespace) -> int:
    from sensor_envs.radar.log import write_log

    if args.astyx and args.rig:
        raise InputError("--rig: a rig file configures the simulated rig; it cannot be used with --astyx")
    if args.astyx and args.in_view_only:
        raise InputError("--in-view-only: filters the simulated rig's targets; it cannot be used with --astyx")
    rows = args.sequences * args.cycles * args.targets
    if not args.astyx and rows > MAX_RECORD_ROWS:
        raise InputError(
            f"--sequences x --cycles x --targets: {args.sequences} x {args.cycles} x {args.targets} = {rows} target "
            f"rows, more than {MAX_RECORD_ROWS}"
        )
    check_inputs(args.astyx, args.rig)
    out = check_output(args.out, inputs=[args.astyx, args.rig], force=args.force, suffix=".csv")
    if args.astyx:
        from sensor_envs.radar.astyx import load_astyx

        log = load_astyx(args.astyx, progress=sys.stderr.isatty())  # no bar in logs (or before a one-line error)
    else:
        from dataclasses import replace

        from sensor_envs.radar.rig import default_rig_path, load_rig, record_rig_log

        config, _ = load_rig(args.rig or default_rig_path())
        log = record_rig_log(
            args.sequences,
            args.cycles,
            args.targets,
            np.random.default_rng(args.seed),
            replace(config, cycle_time=args.cycle_time),
            progress=sys.stderr.isatty(),
            in_view_only=args.in_view_only,
        )
    with OutputTransaction() as tx:
        write_log(log, tx.file(out))
    print(f"wrote {len(log)} rows to {out}")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from sensor_envs.radar.calibrate import calibrate_rig, load_real
    from sensor_envs.radar.rig import load_rig, save_rig

    if args.mixture_min_range is not None and args.offset_law != "mixture":
        raise InputError("--mixture-min-range: only with --offset-law mixture")
    if args.scene_only and not args.base:
        raise InputError("--scene-only: needs --base (the rig whose sensor laws are kept)")
    if args.scene_only and (
        args.azimuth_bias or args.signed_azimuth or args.occlusion_by_range or args.offset_law != "reflection"
    ):
        raise InputError(
            "--scene-only: fits no sensor law; drop --azimuth-bias, --signed-azimuth, --occlusion-by-range "
            "and --offset-law"
        )
    _check_only_flags(args)
    check_inputs(args.real_data, args.base)
    out = check_output(args.out, inputs=[args.real_data, args.base], force=args.force, suffix=".json")
    base, base_card = load_rig(args.base) if args.base else (None, {})
    t0 = time.perf_counter()
    if args.scene_only:
        return _calibrate_scene_only(args, out, base, base_card, t0)
    if args.clutter_only:
        return _calibrate_clutter_only(args, out, base, base_card, t0)
    with about(args.real_data):
        frames = load_real(args.real_data, progress=sys.stderr.isatty())
        config, card = calibrate_rig(
            frames,
            base,
            seed=args.seed,
            max_evals=args.max_evals,
            signed_azimuth=args.signed_azimuth,
            offset_law=args.offset_law,
            mixture_components=tuple(range(1, args.mixture_max_components + 1)),
            mixture_min_range=args.mixture_min_range or 0.0,
            azimuth_bias=args.azimuth_bias,
            occlusion_by_range=args.occlusion_by_range,
            scene=args.scene,
            progress=sys.stderr.isatty(),
        )
    card["seconds"] = round(time.perf_counter() - t0, 1)
    card["base"] = Path(args.base).name if args.base else "generic rig (RigConfig defaults)"
    with OutputTransaction() as tx:
        save_rig(tx.file(out), config, card)
    before, after = card["discrepancy_before"], card["discrepancy_after"]
    print(
        f"calibrated on {frames.n_frames} frames in {card['seconds']} s -> {out}; discrepancy "
        f"({'base rig' if args.base else 'generic rig'} -> "
        f"calibrated): " + ", ".join(f"{k} {before[k]:.4g} -> {after[k]:.4g}" for k in before)
    )
    return 0


def _check_only_flags(args: argparse.Namespace) -> None:
    """``--clutter-only`` needs ``--base`` and takes no other stage's option."""
    if not args.clutter_only:
        return
    if not args.base:
        raise InputError("--clutter-only: needs --base (the rig whose other laws are kept)")
    if args.scene_only or args.scene:
        raise InputError("--clutter-only: fits no scene law; drop --scene and --scene-only")
    if args.azimuth_bias or args.signed_azimuth or args.occlusion_by_range or args.offset_law != "reflection":
        raise InputError(
            "--clutter-only: fits no sensor law but the clutter; drop --azimuth-bias, --signed-azimuth, "
            "--occlusion-by-range and --offset-law"
        )


def _calibrate_clutter_only(
    args: argparse.Namespace, out: Path, base: Any, base_card: dict[str, Any], t0: float
) -> int:
    """``calibrate radar --clutter-only``: the base rig, its clutter law refitted; its card gains a clutter section."""
    from sensor_envs.radar.calibrate import calibrate_clutter, load_real
    from sensor_envs.radar.rig import save_rig

    with about(args.real_data):
        frames = load_real(args.real_data, progress=sys.stderr.isatty())
        config, clutter = calibrate_clutter(frames, base)
    clutter["seconds"] = round(time.perf_counter() - t0, 1)
    clutter["base"] = Path(args.base).name
    with OutputTransaction() as tx:
        save_rig(tx.file(out), config, {**base_card, "clutter": clutter})
    print(
        f"clutter law fitted on {clutter['clutter_rows']} clutter rows of {frames.n_frames} frames -> {out}; "
        "the base rig's other laws kept"
    )
    return 0


def _calibrate_scene_only(args: argparse.Namespace, out: Path, base: Any, base_card: dict[str, Any], t0: float) -> int:
    """``calibrate radar --scene-only``: the base rig with its scene law fitted; its card gains a scene section."""
    from sensor_envs.radar.calibrate import calibrate_scene, load_real
    from sensor_envs.radar.rig import save_rig

    with about(args.real_data):
        frames = load_real(args.real_data, progress=sys.stderr.isatty())
        config, scene = calibrate_scene(frames, base, seed=args.seed)
    scene["seconds"] = round(time.perf_counter() - t0, 1)
    scene["base"] = Path(args.base).name
    with OutputTransaction() as tx:
        save_rig(tx.file(out), config, {**base_card, "scene": scene})
    print(
        f"scene law fitted on {frames.boxes.shape[0]} reference boxes of {frames.n_frames} frames -> {out}; "
        "the base rig's sensor laws kept"
    )
    return 0


def _azimuth_bias(text: str) -> float | str:
    """``--azimuth-bias``: ``fit`` or an angle [rad] within the model's bound."""
    from sensor_envs.radar.alignment import MAX_AZIMUTH_BIAS

    if text == "fit":
        return "fit"
    try:
        return float_between(-MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"expected 'fit' or a number in [{-MAX_AZIMUTH_BIAS:g}, {MAX_AZIMUTH_BIAS:g}], got {text!r}"
        ) from None


def kde_from_args(args: argparse.Namespace) -> Any:
    """The unfitted :class:`~sensor_envs.radar.kde.KDERadarModel` that ``fit radar`` with ``args`` fits."""
    from sensor_envs.radar.kde import KDERadarModel

    extra: dict[str, Any] = {}
    if args.relevance_candidates is not None:
        extra["relevance_candidates"] = tuple(args.relevance_candidates)
    if args.relevance_candidates_prev is not None:
        extra["relevance_candidates_prev"] = tuple(args.relevance_candidates_prev)
    model = KDERadarModel(
        use_prev=not args.no_prev,
        cv_group=args.cv_group,
        relevance=args.relevance,
        random_state=args.seed,
        state_transform=args.state_transform,
        output_frame=args.output_frame,
        bandwidth_scale=args.bandwidth_scale,
        start_bandwidth_scale=args.start_bandwidth_scale,
        azimuth_bias=args.azimuth_bias,
        extra_state=tuple(args.extra_state),
        tail_weight=args.tail_weight,
        tail_scale=args.tail_scale,
        **extra,
    )
    return model


def gaussian_from_args(args: argparse.Namespace) -> Any:
    """The unfitted Gaussian baseline that ``fit radar`` with ``args`` fits beside the KDE."""
    from sensor_envs.radar.gaussian import GaussianRadar

    return GaussianRadar(extra_state=tuple(args.extra_state))


def _fit(args: argparse.Namespace) -> int:
    from sensor_envs.radar.gaussian import baseline_file
    from sensor_envs.radar.log import read_log

    check_inputs(args.log)
    out = check_output(args.out, inputs=[args.log], force=args.force, suffix=".npz")
    base_out = check_output(
        args.baseline_out or baseline_file(str(out)),
        inputs=[args.log, out],
        force=args.force,
        suffix=".npz",
        option="--baseline-out",
    )
    log = read_log(args.log)
    t0 = time.perf_counter()
    model = kde_from_args(args)
    with about(args.log):
        model.set_params(verbose=args.relevance != "paper").fit(log, cycle_time=args.cycle_time)
    fit_s = time.perf_counter() - t0
    data = data_reference(args.log)  # the log's name and sha256, never the path of the machine that fitted it
    card = {
        "log": data,
        "rows": len(log),
        "fit_seconds": round(fit_s, 2),
        "cv_group": args.cv_group,
        "use_prev": not args.no_prev,
        "seed": args.seed,
        "relevance": args.relevance,
        "state_transform": args.state_transform,
        "output_frame": args.output_frame,
        "azimuth_bias": args.azimuth_bias,
        "azimuth_bias_fitted_deg": round(float(np.rad2deg(model.azimuth_bias_)), 4),
        "rel_variance_fitted": list(model.rel_variance_),
        "extra_state": list(model.extra_state_),
        "extra_variance_fitted": list(model.extra_variance_),
    }
    t0 = time.perf_counter()
    with about(args.log):  # like with like: the baseline has the same extra state
        baseline = gaussian_from_args(args).fit(log, cycle_time=args.cycle_time)
    base_card = {  # its own card: the KDE's choices (relevance, bandwidths, fit time) are not the baseline's
        "log": data,
        "rows": len(log),
        "fit_seconds": round(time.perf_counter() - t0, 2),
        "extra_state": list(args.extra_state),
        "fitted_with": Path(out).name,
    }
    with OutputTransaction() as tx:  # model and baseline: both or neither
        model.save(tx.file(out), card=card)
        baseline.save(tx.file(base_out), card=base_card)
    print(f"fitted {model.states_.shape[0]} tuples in {fit_s:.1f} s -> {out}; baseline -> {base_out}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    from sensor_envs.radar.fidelity import BASELINE, frames_report, load_real_log, verdict_lines
    from sensor_envs.radar.gaussian import GaussianRadar, baseline_file
    from sensor_envs.radar.kde import KDERadarModel
    from sensor_envs.radar.log import target_tuples
    from sensor_envs.radar.sensors import IdealRadar
    from sensor_envs.radar.validate import validate, write_report

    check_inputs(args.model, args.log)
    base_path = Path(args.baseline) if args.baseline else baseline_file(args.model)
    out = check_output(args.out, inputs=[args.model, base_path, args.log], force=args.force, folder=True)
    model = read_model(KDERadarModel, args.model)
    if not base_path.exists():
        raise FileNotFoundError(f"{base_path}: Gaussian baseline not found; pass --baseline (fit radar writes one)")
    baseline = read_model(GaussianRadar, base_path)
    with about(args.log):
        log = load_real_log(args.log, block=args.block, progress=sys.stderr.isatty())
        report = validate(model, baseline, log, seed=args.seed)
        single = not target_tuples(log).has_prev_row.any()
        if single:  # real single frames: static boxes, start tuple and stationary law, with verdicts
            models = {"model": model, BASELINE: baseline, "ideal": IdealRadar()}
            report["frames"] = frames_report(models, log, args.block, args.chains, args.cycles, args.seed, args.n_boot)
    report.update(model_file=str(args.model), baseline_file=str(base_path))
    with OutputTransaction() as tx:
        with about(args.log):
            write_report(report, tx.folder(out), model=model, log=log)
    path = out / "report.json"
    summary = {k: report[k]["nll_z_given_detected"] for k in ("model", "baseline_gaussian")}
    print(f"wrote {path}; NLL(z | detected): {json.dumps(summary)}")
    by_prev = report["model"].get("detection_rate_by_previous")
    if by_prev:  # time-series logs: closed-loop rollout vs recorded, split by the previous cycle
        parts = ", ".join(
            f"{k.replace('_', ' ')} {by_prev['rollout'][k]['rate']:.3f} vs {by_prev['recorded'][k]['rate']:.3f}"
            f" ({by_prev['recorded'][k]['n']} rows)"
            for k in ("new", "after_miss", "after_detection")
        )
        print(f"rollout detection rate vs recorded: {parts}")
    if "frames" in report:
        print("\n".join(verdict_lines(report["frames"])))
    return 0
