"""``sensor-envs diagnose radar|lidar LOG --out DIR [--model MODEL]``: find, add and report the effect a model lacks.

Output: ``DIR/report.json``, ``DIR/report.md``, figures and, when something was added, ``DIR/model.npz``
(the model with the added state, fitted on the fit part), written to a temporary folder beside
``DIR`` and renamed into place; an existing ``DIR`` is refused unless ``--force``. With ``--model``,
the loop refits that model's kind, hyperparameters and state on the fit part (like with like); the
given model's own held-out NLL is reported beside it.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sensor_envs.cli.args import OneLineParser, about, add_force, nonneg_int, positive_int
from sensor_envs.inputs import InputError
from sensor_envs.outputs import check_inputs, check_output, output_folder

DIAGNOSE_MAX_READINGS = 240
"""``diagnose lidar --max-readings`` default (:data:`sensor_envs.diagnose.lidar.DIAGNOSE_MAX_READINGS`; a test
checks that they agree, the lidar adapter is not imported when the parser is built)."""


def register(sub: "argparse._SubParsersAction[OneLineParser]") -> None:
    """Add ``diagnose radar`` to the top-level sub-command parser ``sub``."""
    diag = sub.add_parser("diagnose", help="find the effect a sensor model lacks, add it, report before/after")
    kinds = diag.add_subparsers(dest="kind", required=True)
    p = kinds.add_parser("radar", help="diagnose the KDE radar (or its Gaussian baseline) on a radar log")
    p.add_argument("log", help="radar log CSV")
    p.add_argument(
        "--out",
        required=True,
        help="output folder (report.json, report.md, figures, model.npz when an effect is added)",
    )
    p.add_argument("--model", default=None, help="a fitted model file (.npz) to diagnose instead of fitting one")
    p.add_argument("--model-kind", default="kde", choices=("kde", "gaussian"), help="model fitted when no --model")
    add_force(p)
    _search_options(p)
    p.add_argument("--block-frames", type=positive_int, default=25, help="frames per contiguous block (default 25)")
    p.add_argument("--no-prev", action="store_true", help="do not condition the KDE on z_{t-1}")
    p.add_argument("--exclude", action="append", default=[], help="a log column that is not a candidate (repeatable)")
    p.add_argument(
        "--seed", type=nonneg_int, default=0, help="seed of the block split, fits and permutations (default: 0)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_naming_the_log(_diagnose_radar))
    q = kinds.add_parser("lidar", help="diagnose the learned lidar on a scan log (.npz, CARMEN log, ROS bag)")
    q.add_argument("log", help="lidar scan log (.npz, CARMEN log or ROS bag)")
    q.add_argument(
        "--out",
        required=True,
        help="output folder (report.json, report.md, figures, model.npz when an effect is added)",
    )
    q.add_argument("--model", default=None, help="a fitted lidar model file (.npz) whose tables are diagnosed")
    q.add_argument("--map", default=None, help="map file for the log (segments, JSON/YAML, ROS map_server YAML)")
    q.add_argument("--align", action="store_true", help="scan-match the odometry poses onto the --map grid")
    q.add_argument(
        "--max-range", type=float, default=None, help="sensor's maximum range [m] (default: 5 for a .npz log)"
    )
    q.add_argument(
        "--max-readings",
        type=positive_int,
        default=DIAGNOSE_MAX_READINGS,
        help=f"scans used by the table fit (default {DIAGNOSE_MAX_READINGS})",
    )
    q.add_argument("--spur-above", type=float, default=None, help="spurious returns beyond [m] (default max-range + 1)")
    q.add_argument("--table-range-step", type=float, default=0.125, help="range step of the tables [m] (default 0.125)")
    add_force(q)
    _search_options(q)
    q.add_argument(
        "--block-scans", dest="block_frames", type=positive_int, default=5, help="scans per block (default 5)"
    )
    q.add_argument(
        "--seed", type=nonneg_int, default=0, help="seed of the block split, fits and permutations (default: 0)"
    )
    q.add_argument("--quiet", action="store_true", help="no progress bars")
    q.set_defaults(func=_naming_the_log(_diagnose_lidar))


def _search_options(p: argparse.ArgumentParser) -> None:
    """``--max-add``, ``--permutations``, ``--alpha``, ``--min-score`` with the package's defaults."""
    from sensor_envs.diagnose.search import DEFAULTS as D

    p.add_argument("--max-add", type=positive_int, default=D["max_add"], help=f"effects added at most ({D['max_add']})")
    p.add_argument(
        "--permutations",
        type=positive_int,
        default=D["n_permutations"],
        help=f"block sign-flips of the test (default {D['n_permutations']})",
    )
    p.add_argument(
        "--shifts",
        type=int,
        default=D["n_shifts"],
        help=f"circular shifts of the residuals that confirm a finding (0: none; default {D['n_shifts']})",
    )
    p.add_argument("--alpha", type=float, default=D["alpha"], help=f"family-wise level (default {D['alpha']})")
    p.add_argument(
        "--min-score", type=float, default=D["min_score"], help=f"minimum cross-fitted R^2 (default {D['min_score']})"
    )


def _naming_the_log(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """``run`` with every input error it raises prefixed by the log's name (e.g. "the log has 2 blocks")."""

    def wrapped(args: argparse.Namespace) -> int:
        with about(args.log):
            return run(args)

    return wrapped


def write_folder_atomically(
    out: Path, force: bool, write: Callable[[Path], Any], inputs: tuple[str | Path | None, ...] = ()
) -> Any:
    """Run ``write(tmp)`` into a temporary folder beside ``out``, renamed onto ``out`` only on success.

    The shared safe-output rules (:mod:`sensor_envs.outputs`): ``out`` must not be (or hold) an input,
    an existing ``out`` needs ``force``.
    """
    with output_folder(out, force, inputs) as tmp:
        return write(tmp)


def _check_args(args: argparse.Namespace) -> None:
    """Reject bad numeric options naming the option (the search's own check, with the CLI's names)."""
    from sensor_envs.diagnose.search import check_search_options

    check_search_options(args.permutations, args.shifts, args.alpha, args.min_score, args.max_add, names=_OPTION_NAMES)
    if args.block_frames < 1:
        raise InputError(f"--block-frames: expected >= 1, got {args.block_frames}")


_OPTION_NAMES = {
    "n_permutations": "--permutations",
    "n_shifts": "--shifts",
    "alpha": "--alpha",
    "min_score": "--min-score",
    "max_add": "--max-add",
}


def load_radar_model(path: str) -> tuple[str, Any]:
    """``("kde" | "gaussian", model)`` from a model file, by the ``kind`` in its header.

    A corrected model (what ``diagnose radar`` writes) is refused: diagnose its base configuration.
    """
    from sensor_envs.radar.correction import load_radar_file

    kind, model = load_radar_file(path)
    if kind == "corrected":
        raise InputError(
            f"{path}: field 'kind' is 'radar_corrected' (a model written by diagnose); --model takes a KDE or "
            "Gaussian model file"
        )
    return kind, model


def _diagnose_radar(args: argparse.Namespace) -> int:
    from sensor_envs.diagnose.core import block_split, run_diagnose
    from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks
    from sensor_envs.diagnose.radar_add import loop_extras
    from sensor_envs.diagnose.report import write_report
    from sensor_envs.radar.log import read_log

    _check_args(args)
    check_inputs(args.log, args.model)
    out = check_output(args.out, inputs=[args.log, args.model], force=args.force, folder=True)
    log = read_log(args.log)
    held = block_split(radar_blocks(log, args.block_frames))
    base_model, base_state, kind, params = None, (), args.model_kind, {}
    if args.model is not None:
        kind, base_model = load_radar_model(args.model)
        params = {k: v for k, v in base_model.get_params().items() if k not in ("extra_state", "extra_variance")}
        base_state = tuple(base_model.extra_state_)
    elif args.no_prev:
        params["use_prev"] = False
    adapter = RadarAdapter(
        log, held, model_kind=kind, params=params, progress=not args.quiet, exclude=tuple(args.exclude)
    )
    result = run_diagnose(
        adapter,
        base_state=base_state,
        max_add=args.max_add,
        n_permutations=args.permutations,
        n_shifts=args.shifts,
        alpha=args.alpha,
        min_score=args.min_score,
        seed=args.seed,
        progress=not args.quiet,
    )
    result.extra["model"] = {"kind": kind, "file": args.model, "params": {k: repr(v) for k, v in params.items()}}
    if base_model is not None:  # like with like: the loop refits the given model's kind, parameters and state
        result.extra["given_model_error_held_out"] = adapter.evaluate(base_model).error
        result.extra["given_model_note"] = (
            "the given model itself on the held-out part; it may have been fitted on these readings, so the "
            "loop compares refits on the fit part (error_before = the given model's configuration refitted)"
        )
    result.extra.update(loop_extras(adapter, result, before=base_model))
    final = result.model_after

    def write(tmp: Path) -> dict[str, Any]:
        data = write_report(result, tmp, source=str(args.log))
        with open(tmp / "report.md", "a", encoding="utf-8") as fh:
            fh.write(_corrections_markdown(result.extra))
        if result.added:  # the corrected model, fitted on the fit part: usable by sample AND log_prob
            final.save(tmp / "model.npz", card={"source": str(args.log), "diagnose": result.settings})
        return data

    data = write_folder_atomically(out, args.force, write, (args.log, args.model))
    summary = {k: data[k] for k in ("added", "error_before", "error_after")}
    summary["effects"] = data["effects"][:5]
    summary["corrections"] = [c["text"] for c in result.extra["corrections"]]
    print(json.dumps(summary, indent=1))
    return 0


def _corrections_markdown(extra: dict[str, Any]) -> str:
    """The radar's corrections in words and the held-out NLL per part, as a report.md section."""
    lines = ["", "## Corrections added to the radar model", ""]
    lines += [f"- {c['text']}" for c in extra["corrections"]] or ["- none"]
    b, a = extra["nll_parts_before"], extra["nll_parts_after"]
    lines += ["", "| held-out NLL per reading [nats] | before | after |", "|---|---|---|"]
    lines += [f"| {k} | {b[k]:.4f} | {a[k]:.4f} |" for k in ("rate", "position", "total")]
    if extra.get("state_tuning"):
        lines += ["", f"State kernel re-tuned on the fit part: rel_variance {extra['state_tuning']['rel_variance']}"]
    return "\n".join(lines) + "\n"


def _diagnose_lidar(args: argparse.Namespace) -> int:
    from sensor_envs.cli.lidar import check_range_fits, range_options
    from sensor_envs.diagnose.core import block_split, run_diagnose
    from sensor_envs.diagnose.lidar import LidarAdapter, lidar_blocks
    from sensor_envs.diagnose.report import write_report
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.lidar.mapping import prepare_log

    _check_args(args)
    max_range, spur = (
        range_options(args.log, args.max_range, args.spur_above, args.table_range_step)
        if args.model is None
        else (0.0, 0.0)  # the model's own
    )
    check_inputs(args.log, args.model, args.map)
    out = check_output(args.out, inputs=[args.log, args.model, args.map], force=args.force, folder=True)
    base_model, base_state = None, ()
    params: dict[str, Any] = {"max_range": max_range, "spur_above": spur, "verbose": not args.quiet}
    params["table_range_step"] = args.table_range_step
    if args.model is not None:
        base_model = LidarLWLR.load(args.model)
        base_state = tuple(base_model.extra_state_)
        params = {k: v for k, v in base_model.get_params().items() if k != "extra_state"}
    raw = load_log(args.log)
    if args.model is not None or args.max_range is None:  # a range that is not the user's must fit the log
        check_range_fits(raw, params["max_range"], "the model's" if args.model is not None else "the default")
    log, prep = prepare_log(raw, map=args.map, max_range=params["max_range"], align=args.align)
    blocks = lidar_blocks(log.n_poses, args.block_frames)
    held = block_split(blocks)
    adapter = LidarAdapter(log, held, blocks, params=params, base_model=base_model, max_readings=args.max_readings)
    result = run_diagnose(
        adapter,
        base_state=base_state,
        max_add=args.max_add,
        n_permutations=args.permutations,
        n_shifts=args.shifts,
        alpha=args.alpha,
        min_score=args.min_score,
        seed=args.seed,
        progress=not args.quiet,
    )
    result.extra["model"] = {"file": args.model, "params": {k: repr(v) for k, v in adapter.params.items()}}
    result.extra["log"] = {
        "scans": log.n_poses,
        "bearings": log.n_bearings,
        "prepared": {k: repr(v) for k, v in prep.items()},
    }
    if base_model is not None:
        result.extra["given_model_note"] = (
            "the given model's tables are used as they are (they may have been fitted on the held-out scans); "
            "the extra-state terms are refitted on the fit part"
        )
    final = result.model_after if result.added else None

    def write(tmp: Path) -> dict[str, Any]:
        data = write_report(result, tmp, source=str(args.log))
        if final is not None:  # the tables with the added terms (fitted on the fit part): Neato-v0 runs it
            final.save(tmp / "model.npz", card={"source": str(args.log), "diagnose": result.settings})
        return data

    data = write_folder_atomically(out, args.force, write, (args.log, args.model, args.map))
    summary = {k: data[k] for k in ("added", "error_before", "error_after")}
    summary["effects"] = data["effects"][:5]
    print(json.dumps(summary, indent=1))
    return 0
