"""``sensor-envs tune radar``: choose a fitted KDE radar's bandwidth factor or tail mixture on real held-out rows.

The logic is :mod:`sensor_envs.radar.tune`; this module reads the inputs, prints the table and writes the model
with the final choice (its card gains the choice, the nested held-out figures and the data's name).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.cli.args import OneLineParser, about, add_force, bounded_int, float_between, positive_int
from sensor_envs.inputs import InputError
from sensor_envs.modelio import read_model
from sensor_envs.outputs import OutputTransaction, check_inputs, check_output


def register(verbs: dict[str, "argparse._SubParsersAction[OneLineParser]"]) -> None:
    """Add ``tune radar`` under the ``tune`` verb parser in ``verbs``."""
    from sensor_envs.radar.tune import FACTORS, TAIL_SCALES, TAIL_WEIGHTS

    p = verbs["tune"].add_parser(
        "radar", help="choose a KDE radar's bandwidth factor or tail mixture on real frames (folds of frame blocks)"
    )
    p.add_argument("model", help="fitted KDE model file (.npz)")
    p.add_argument("real", help="real frames: an astyx_hires2019 folder or a radar log CSV (record radar --astyx)")
    p.add_argument("--out", required=True, help="model file to write with the final choice (.npz)")
    p.add_argument(
        "--what",
        choices=("tail", "bandwidth"),
        default="tail",
        help="tail: the tail mixture (weight, scale) by the mean NLL of z given a detection, start tuple and "
        "stationary law averaged (default); bandwidth: a factor on the contribution bandwidths of --tree",
    )
    p.add_argument(
        "--refit",
        action="store_true",
        help="--what tail: MODEL was fitted on these frames; score each fold with a copy fitted on the other folds "
        "(its hyperparameters, no tail) instead of MODEL itself, which has seen every row",
    )
    p.add_argument("--tree", choices=("both", "start", "main"), default="both", help="--what bandwidth: trees")
    p.add_argument("--criterion", choices=("nll", "energy"), default="nll", help="--what bandwidth: criterion")
    p.add_argument("--nll-guard", type=float_between(0.0, 10.0), default=0.05, help="--criterion energy: NLL guard")
    p.add_argument(
        "--factors",
        type=float_between(0.01, 100.0),
        nargs="+",
        default=list(FACTORS),
        help="--what bandwidth: candidate bandwidth factors (default: %(default)s)",
    )
    p.add_argument(
        "--tail-weights",
        type=float_between(0.0, 0.5),
        nargs="+",
        default=list(TAIL_WEIGHTS),
        help="--what tail: candidate weights of the wide component (default: %(default)s)",
    )
    p.add_argument(
        "--tail-scales",
        type=float_between(1.0, 100.0),
        nargs="+",
        default=list(TAIL_SCALES),
        help="--what tail: candidate widths of the wide component, in bandwidths (default: %(default)s)",
    )
    p.add_argument("--block", type=positive_int, default=10, help="frames per block (default 10)")
    p.add_argument("--folds", type=bounded_int(2, 1000), default=5, help="folds of blocks (default 5)")
    p.add_argument("--chains", type=positive_int, default=16, help="rollouts per row of the stationary law")
    p.add_argument("--cycles", type=positive_int, default=5, help="cycles per rollout (the last is scored)")
    p.add_argument("--seed", type=int, default=0, help="seed of the stationary-law rollouts (default 0)")
    p.add_argument("--json", default=None, help="also write every candidate's figures to this JSON file")
    add_force(p)
    p.set_defaults(func=_tune)


def _progress(what: str) -> Any:
    """A callable printing one line per candidate to stderr (long work shows progress)."""
    t0 = time.perf_counter()

    def show(candidate: Any) -> None:
        print(f"{what} {candidate} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)

    return show


def _tune(args: argparse.Namespace) -> int:
    from sensor_envs.radar.fidelity import check_folds, fold_rows, load_real_log
    from sensor_envs.radar.kde import KDERadarModel

    folds_n = args.folds
    if args.refit and args.what != "tail":
        raise InputError("--refit: only with --what tail")
    check_inputs(args.model, args.real)
    out = check_output(args.out, inputs=[args.model, args.real], force=args.force, suffix=".npz")
    js = (
        check_output(args.json, inputs=[args.model, args.real, out], force=args.force, suffix=".json", option="--json")
        if args.json
        else None
    )
    model = read_model(KDERadarModel, args.model)
    with about(args.real):
        log = load_real_log(args.real, block=args.block, progress=sys.stderr.isatty())
        check_folds(log, args.block, folds_n)
        folds = [fold_rows(log, args.block, folds_n, k) for k in range(folds_n)]
    if args.what == "tail":
        fold_models = None
        if args.refit:  # per fold, the model's hyperparameters fitted without the fold's rows
            from sensor_envs.radar.tune import refit
            from sensor_envs.radar.validate import split_by_blocks

            show = _progress("refit without fold")
            with about(args.real):
                fold_models = []
                for k in range(folds_n):  # one fit per fold
                    show(k)
                    fold_models.append(refit(model, split_by_blocks(log, args.block, folds_n, k)[0]))
        chosen, report = _tune_tail(model, folds, args, fold_models)
    else:
        chosen, report = _tune_bandwidth(model, folds, args)
    report.update(model=str(args.model), data=Path(args.real).name, folds=folds_n, block=args.block)
    with OutputTransaction() as tx:
        key = "tail_choice" if args.what == "tail" else f"bandwidth_choice_{args.tree}"
        summary = {k: v for k, v in report.items() if k not in ("candidates",)}
        chosen.save(tx.file(out), card={**model.card_, key: summary})
        if js is not None:
            tx.file(js).write_text(json.dumps(report, indent=1), encoding="utf-8")
    print(f"wrote {out}")
    return 0


def _tune_tail(model: Any, folds: list, args: argparse.Namespace, fold_models: Any) -> tuple[Any, dict[str, Any]]:
    from sensor_envs.radar.tune import choose_tail, nested_rows, tail_scores

    scores = tail_scores(
        model if fold_models is None else fold_models,
        folds,
        tuple(args.tail_weights),
        tuple(args.tail_scales),
        args.seed,
        args.chains,
        args.cycles,
        progress=_progress("tail (weight, scale)"),
    )
    final, nested = choose_tail(scores)
    laws = list(next(iter(scores.values())))
    print("| tail weight | tail scale | " + " | ".join(f"{law} mean | {law} median" for law in laws) + " |")
    print("|---|---|" + "---|---|" * len(laws))
    cands = {}
    for (w, c), per_law in scores.items():
        pooled = {law: np.concatenate(v) for law, v in per_law.items()}
        cands[f"{w:g},{c:g}"] = {law: [float(v.mean()), float(np.median(v))] for law, v in pooled.items()}
        cells = " | ".join(f"{v.mean():.3f} | {np.median(v):.3f}" for v in pooled.values())
        print(f"| {w:g} | {c:g} | {cells} |")
    held = nested_rows(scores, nested)
    held_txt = ", ".join(f"{law} mean {v.mean():.3f} median {np.median(v):.3f}" for law, v in held.items())
    print(f"nested choices (weight, scale) per fold: {nested}; held-out NLL(z | detected): {held_txt}")
    print(f"final: tail_weight {final[0]:g}, tail_scale {final[1]:g}")
    report = {
        "what": "tail",
        "refit": bool(args.refit),
        "final": {"tail_weight": final[0], "tail_scale": final[1]},
        "nested_choice": [list(p) for p in nested],
        "nested_nll_z_given_detected": {law: [float(v.mean()), float(np.median(v))] for law, v in held.items()},
        "chains": args.chains,
        "cycles": args.cycles,
        "seed": args.seed,
        "candidates": cands,
    }
    return model.with_tail(*final), report


def _tune_bandwidth(model: Any, folds: list, args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    from sensor_envs.radar.tune import choose, criterion, energy_per_bin, fold_scores, with_factor

    cycles = 1 if args.tree == "start" else args.cycles  # the start tuple: a new track's first draw
    show = _progress("bandwidth factor")
    scores = {}
    for f in args.factors:  # one scoring per candidate factor
        show(f)
        scores[f] = fold_scores(with_factor(model, f, args.tree), folds, args.seed, args.chains, cycles)
    final, nested = choose(scores, args.criterion, args.seed, args.nll_guard)
    print("| factor | NLL outcomes (mean of folds) | energy distance, row-weighted [m] |")
    print("|---|---|---|")
    cands = {}
    for f in sorted(scores):
        nll, ed = criterion(scores[f], "nll", args.seed), criterion(scores[f], "energy", args.seed)
        cands[f"{f:g}"] = {"nll": nll, "energy": ed, "energy_per_bin": energy_per_bin(scores[f], args.seed)[0].tolist()}
        print(f"| {f:g} | {nll:.3f} | {ed:.4f} |")
    held = [scores[f][k] for k, f in enumerate(nested)]
    held_nll = float(np.mean([p["nll"] for p in held]))
    chosen = with_factor(model, final, args.tree)
    print(f"nested choices per fold: {nested}; held-out NLL of outcomes {held_nll:.3f}")
    print(
        f"final factor {final:g} on the {args.tree} trees (bandwidth_scale {model.bandwidth_scale:g} -> "
        f"{chosen.bandwidth_scale:g}, start_bandwidth_scale {model.start_bandwidth_scale} -> "
        f"{chosen.start_bandwidth_scale})"
    )
    report = {
        "what": "bandwidth",
        "tree": args.tree,
        "criterion": args.criterion,
        "nll_guard": args.nll_guard,
        "final": final,
        "nested_choice": nested,
        "nested_nll": held_nll,
        "nested_energy_per_bin": energy_per_bin(held, args.seed)[0].tolist(),
        "candidates": cands,
    }
    return chosen, report
