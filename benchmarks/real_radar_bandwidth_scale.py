"""Choose the KDE radar's contribution-bandwidth factor on real Astyx frames (held-out likelihood or energy distance).

The KDE fitted on the calibrated rig's log chooses its contribution bandwidths by leave-one-track-out
CV on that SIMULATED log; at the real boxes they come out wider than those a KDE fitted on real frames
chooses (model card). This script scores the model (``--model``, default the shipped
``models/radar_kde.npz``) with every factor of ``--factors`` applied to its bandwidth table
(:meth:`KDERadarModel.with_bandwidth_scale`) on the real car rows: the stationary law at the static box
(:func:`sensor_envs.radar.fidelity.marginal`: ``--chains`` rollouts of ``--cycles`` cycles, ``z_{t-1}`` fed back),
on the folds of 10-frame blocks (``validate.split_by_blocks``, the folds of the fidelity benchmark).
The model itself never saw a real row, so every row is held out for it; the FACTOR is chosen on the rows
by ``--criterion``:

* ``nll`` (the default; the files up to 2026-11-25): the mean NLL of outcomes;
* ``energy``: the energy distance between the model's and the real detected offsets per corner-range bin,
  weighted by the real detected rows per bin (U-statistic, sensor frame, every chain's draw; the
  discrepancy the rig's offset stage is calibrated by, and the fidelity benchmark's per-bin metric),
  among the factors whose mean NLL is within ``--nll-guard`` (default 5 %) of the least one, by the
  one-standard-error rule: the factor nearest 1 whose mean over folds is within one standard error of the
  least mean (the distance is flat near its optimum: on Astyx 0.2, 0.3 and 0.35 were within 1 %).
  Minimum-energy-distance estimation scores the law of the offsets per range, which
  the likelihood of single rows weighs against the tails (a too wide kernel is cheap for the NLL, a too
  narrow one dear); the guard keeps the likelihood near its optimum (unguarded, the energy distance
  chose the narrowest factor on Astyx, whose NLL was 17 % above the least).

Both are printed for every factor; the choice is:

* nested (the honest figure for the choice): for each fold, the factor chosen on the other folds, scored on
  that fold (the energy distance of the nested choice pools every fold's held-out rows, each scored with
  its own choice);
* final: the factor chosen on all folds (ties: the one nearer 1), written with ``--write``.

``--tree`` says which kernels the factor acts on:

* ``both`` (the default; the files up to 2026-11-26): every tree's (:meth:`KDERadarModel.with_bandwidth_scale`;
  a model with its own start factor keeps it);
* ``start``: the start trees' only (``start_bandwidth_scale``, :meth:`KDERadarModel.with_start_bandwidth_scale`),
  scored on the START tuple (one draw of a new track at each real box, ``--cycles`` is 1), the law a
  track's first cycle and every real frame without a history come from;
* ``main``: the trees with ``z_{t-1}`` only, the start trees' bandwidths held where they are (their factor
  made explicit first), scored on the stationary law as ``both``.

A chain fed its own outputs draws from the main trees every cycle and its law spreads wider than the tuples
it resamples, while a start tuple is drawn once: the two can want different factors (model card).

Detection rates do not depend on the factor (it only narrows or widens the contribution kernels).

The logic is the package's (:mod:`sensor_envs.radar.tune`); the command a user runs is
``sensor-envs tune radar MODEL DATA --what bandwidth --tree T --criterion C --out OUT.npz``. This script prints
the per-fold table of the model card.
~1 min per factor on 2 cores.

    python benchmarks/real_radar_bandwidth_scale.py --data ../shared/data/real/astyx_hires2019 \
        [--criterion nll|energy] [--tree both|start|main] --write /tmp/radar_kde.npz
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sensor_envs.modelio import ModelFileError
from sensor_envs.outputs import OutputError, OutputTransaction, check_output
from sensor_envs.radar.astyx import load_astyx
from sensor_envs.radar.fidelity import fold_rows
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.tune import FACTORS, NLL_GUARD, choose, criterion, energy_per_bin, fold_scores, with_factor
from sensor_envs.radar.validate import RANGE_BINS

ROOT = Path(__file__).resolve().parents[1]
CRITERIA = ("nll", "energy")
TREES = ("both", "start", "main")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real" / "astyx_hires2019"))
    ap.add_argument("--model", default=str(ROOT / "models" / "radar_kde.npz"), help="KDE model file (.npz)")
    ap.add_argument("--factors", type=float, nargs="+", default=list(FACTORS))
    ap.add_argument("--criterion", choices=CRITERIA, default="nll", help="what chooses the factor (default nll)")
    ap.add_argument("--tree", choices=TREES, default="both", help="the kernels the factor acts on (default both)")
    ap.add_argument(
        "--nll-guard",
        type=float,
        default=NLL_GUARD,
        help=f"--criterion energy: largest share above the least mean NLL (default {NLL_GUARD:g})",
    )
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--chains", type=int, default=16)
    ap.add_argument("--cycles", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--write", default=None, help="write the model with the final factor here (.npz)")
    ap.add_argument("--force", action="store_true", help="overwrite --write / --json")
    args = ap.parse_args()
    t0 = time.perf_counter()
    try:  # bad input: one line naming the file, exit 2, before anything is written
        if any(not 0.01 <= f <= 100 for f in args.factors):
            raise ValueError(f"--factors: each must be in [0.01, 100], got {args.factors}")
        if not 0.0 <= args.nll_guard <= 10.0:
            raise ValueError(f"--nll-guard: must be in [0, 10], got {args.nll_guard}")
        model = KDERadarModel.load(args.model)
        log = load_astyx(args.data, block=args.block, progress=False)
        out = (
            check_output(args.write, inputs=[args.model], force=args.force, suffix=".npz", option="--write")
            if args.write
            else None
        )
        js = (
            check_output(args.json, inputs=[args.model], force=args.force, suffix=".json", option="--json")
            if args.json
            else None
        )
    except (FileNotFoundError, ValueError, ModelFileError, OutputError) as exc:
        print(exc, file=sys.stderr)
        raise SystemExit(2) from None
    folds = [fold_rows(log, args.block, args.folds, k) for k in range(args.folds)]
    scores = {}
    cycles = 1 if args.tree == "start" else args.cycles  # the start tuple: a new track's first draw
    for f in tqdm(args.factors, desc="bandwidth factors", unit="factor"):  # one iteration per factor
        scores[f] = fold_scores(with_factor(model, f, args.tree), folds, args.seed, args.chains, cycles)
    final, nested = choose(scores, args.criterion, args.seed, args.nll_guard)
    nll = {f: np.array([p["nll"] for p in v]) for f, v in scores.items()}
    energy = {f: energy_per_bin(v, args.seed)[0] for f, v in scores.items()}
    held_parts = [scores[f][k] for k, f in enumerate(nested)]
    held_nll = float(np.mean([p["nll"] for p in held_parts]))
    held_energy = energy_per_bin(held_parts, args.seed)[0]
    bins = [f"{lo:g}-{hi:g} m" for lo, hi in zip(RANGE_BINS[:-1], RANGE_BINS[1:], strict=True)]
    name = Path(args.data).name
    print(f"\nOn the real rows of {args.folds} folds ({name}), per factor: NLL of outcomes [nats] per fold, "
          "energy distance [m] per corner-range bin (pooled), the criteria\n")  # fmt: skip
    print("| factor | " + " | ".join(f"NLL fold {k}" for k in range(args.folds)) + " | NLL mean | "
          + " | ".join(f"ED {b}" for b in bins) + " | ED row-weighted |")  # fmt: skip
    print("|---" * (args.folds + len(bins) + 3) + "|")
    for f in sorted(scores):
        weighted = criterion(scores[f], "energy", args.seed)
        print(f"| {f:g} | " + " | ".join(f"{v:.3f}" for v in nll[f]) + f" | {nll[f].mean():.3f} | "
              + " | ".join(f"{v:.4f}" for v in energy[f]) + f" | {weighted:.4f} |")  # fmt: skip
    print(
        f"\ncriterion {args.criterion}; nested (factor chosen on the other folds): {[f'{f:g}' for f in nested]}, "
        f"held-out NLL {held_nll:.3f}, energy distance per bin {np.round(held_energy, 4).tolist()}"
    )
    chosen = with_factor(model, final, args.tree)
    print(
        f"final factor: {final:g} on the {args.tree} trees (bandwidth_scale {model.bandwidth_scale:g} -> "
        f"{chosen.bandwidth_scale:g}, start_bandwidth_scale {model.start_bandwidth_scale} -> "
        f"{chosen.start_bandwidth_scale})"
    )
    seconds = round(time.perf_counter() - t0, 1)
    print(f"{seconds} s")
    report = {
        "args": vars(args),
        "criterion": args.criterion,
        "tree": args.tree,
        "nll_guard": args.nll_guard,
        "nll_per_fold": {f"{f:g}": v.tolist() for f, v in nll.items()},
        "energy_per_bin": {f"{f:g}": v.tolist() for f, v in energy.items()},
        "range_bins_m": list(RANGE_BINS),
        "nested_choice": nested,
        "nested_nll": held_nll,
        "nested_energy_per_bin": held_energy.tolist(),
        "final": final,
        "seconds": seconds,
    }
    with OutputTransaction() as tx:
        if out is not None:
            keys = ("criterion", "tree", "nll_guard", "nested_choice", "nested_nll", "nested_energy_per_bin", "final")
            choice = {k: report[k] for k in keys} | {"data": Path(args.data).name}
            key = "start_bandwidth_scale_choice" if args.tree == "start" else "bandwidth_scale_choice"
            chosen.save(tx.file(out), card={**model.card_, key: choice})
        if js is not None:
            tx.file(js).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
