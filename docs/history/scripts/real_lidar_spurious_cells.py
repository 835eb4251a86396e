"""Per-cell structure of the spurious far returns: the real Neato log vs logs the learned lidar samples at its poses.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: the real unit's spurious far returns persist
per cell (few cells have any, those have them in almost every reading); led to `spur_rho_` (model format 5) and the
beta-binomial score of `p_spur` (`319863c`).

    python docs/history/scripts/real_lidar_spurious_cells.py --data ../shared/data/real
        [--model models/neato_lidar.npz [--model OTHER.npz ...]] [--seeds 3]

A cell is one pose and one bearing of the real log ``neato_mar27_train.npz`` (29 poses x 360 bearings x
200 repeats). Its spurious fraction is the share of its readings beyond ``spur_above`` (6 m). On the real
unit the spurious returns persist per cell: few cells have any, and those have them in almost every
reading. For the real log and for each model (``sample`` at the real approximate poses, as many repeats as
the real log, ``--seeds`` draws pooled), the script prints: the share of cells with any spurious return, the
median spurious fraction of those cells, the share of those at >= 0.9 and at <= 0.1, and the mean spurious
rate (the per-reading rate a model's ``p_spur`` is fitted to). A model with independent spurious returns
(``spur_rho_ = 0``: model files before format 5) spreads the same rate thinly over many cells.

Then the per-cell scores of ``p_spur`` (``sensor_envs.lidar.validate.table_one``: MAE, MSE and the
beta-binomial log-likelihood of the cells' spurious counts, with and without the model's ``spur_rho_``)
of the given models, of the model fitted on the real training poses of ``--folds`` leave-poses-out folds
(``--seed``: the fold assignment of ``real_lidar_fidelity.py``; held-out cells pooled) and of a model
that predicts no spurious return (``p_spur = 0``, scored at the floor). ~2 min (the real fits).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sensor_envs.lidar.calibrate import load_real_log
from sensor_envs.lidar.lwlr import LidarLWLR, cell_statistics, lidar_features
from sensor_envs.lidar.validate import table_one
from sensor_envs.rng import fold_ids

ROOT = Path(__file__).resolve().parents[3]


def cell_summary(frac: NDArray[np.float64]) -> dict[str, float]:
    """Structure of per-cell spurious fractions ``frac`` (one value per cell, in [0, 1])."""
    some = frac[frac > 0]
    return {
        "cells_with_any": float(np.mean(frac > 0)),
        "median_fraction_of_those": float(np.median(some)) if some.size else float("nan"),
        "share_of_those_at_least_0.9": float(np.mean(some >= 0.9)) if some.size else float("nan"),
        "share_of_those_at_most_0.1": float(np.mean(some <= 0.1)) if some.size else float("nan"),
        "mean_rate": float(np.mean(frac)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real"), help="real data folder")
    ap.add_argument(
        "--model", action="append", default=None, help="learned lidar model file (repeatable; default: the shipped)"
    )
    ap.add_argument("--seeds", type=int, default=3, help="sampled logs per model, pooled (default: 3)")
    ap.add_argument("--folds", type=int, default=5, help="leave-poses-out folds of the real fit (default: 5)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the fold assignment (default: 0)")
    args = ap.parse_args()
    paths = args.model or [str(ROOT / "models" / "neato_lidar.npz")]
    try:  # bad input: one line naming the file, exit 2
        real = load_real_log(args.data)
        models = [LidarLWLR.load(p) for p in paths]
    except (FileNotFoundError, ValueError) as exc:
        print(f"{exc}: nothing to report", file=sys.stderr)
        raise SystemExit(2) from None
    names = [Path(p).name for p in paths]
    labels = [p if names.count(n) > 1 else n for p, n in zip(paths, names, strict=True)]  # rows must not collide
    st = cell_statistics(real, 6.0, split_spurious=True)
    has = st["n"] > 0
    rows = {"real": cell_summary(st["p_spur"][has])}
    repeats = real.ranges.shape[2]
    for label, model in zip(labels, models, strict=True):
        frac = []
        for seed in range(args.seeds):
            x = model.sample(real.poses, real.require_map(), np.random.default_rng(seed), n_repeats=repeats)
            frac.append((x > model.spur_above).mean(2)[has])
        rows[f"{label} (spur_rho {model.spur_rho_})"] = cell_summary(np.concatenate(frac))
    keys = list(rows["real"])
    print(f"{int(has.sum())} real cells x {repeats} readings; models sampled at the real poses, {args.seeds} seeds")
    print("| log | " + " | ".join(k.replace("_", " ") for k in keys) + " |")
    print("|---|" + "---|" * len(keys))
    for name, row in rows.items():
        print(f"| {name} | " + " | ".join(f"{row[k]:.3f}" for k in keys) + " |")

    r, a = lidar_features(real.poses, real.bearings, real.require_map(), 5.0)
    fold = fold_ids(real.n_poses, args.folds, random_state=args.seed)
    held: dict[str, NDArray[np.float64]] = {}
    for f in range(args.folds):
        tr, te = fold != f, fold == f
        fitted = LidarLWLR(variant="extended", n_folds=10, random_state=0, progress=False).fit(real.subset(tr))
        for k, v in fitted.params_from_features(r[te], a[te]).items():
            held.setdefault(k, np.zeros(te.shape + v.shape[1:]))[te] = v
    none = {**held, "p_spur": np.zeros(r.shape), "spur_rho": np.zeros(r.shape)}
    scores = {"real-fitted (held out)": table_one(real, held), "no spurious return": table_one(real, none)}
    for label, model in zip(labels, models, strict=True):
        scores[label] = table_one(real, model.params_from_features(r, a))
    cols = ["mae_p_spur", "mse_p_spur", "ll_spur_counts_per_reading", "ll_spur_counts_per_reading_independent"]
    print(
        f"\nScores of p_spur on the real cells ({args.folds} leave-poses-out folds for the real fit, seed {args.seed})"
    )
    print("| model | MAE p_spur | MSE p_spur | spurious-count LL/reading | the same, independent readings |")
    print("|---|---|---|---|---|")
    for name, m in scores.items():
        print(f"| {name} | " + " | ".join(f"{m[c]:.5f}" for c in cols) + " |")


if __name__ == "__main__":
    main()
