"""Leave-poses-out CV of the lidar rig's null law on the real Neato cells: the ridge of the per-bearing slopes.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: per-bearing slopes of the null law with a CV-
chosen ridge: held-out MAE of `p_null` on the real cells 0.117 -> 0.098 (`bf0985b`); what `calibrate lidar` does
since (`choose_slope_ridge`).

    python docs/history/scripts/real_lidar_null_law_cv.py --data ../shared/data/real [--folds 5] [--seeds 0 1 2]
        [--ridges inf 1 0.3 0.1 0.03 0.01 0.003 0.001]

The calibrated rig's mean null probability per cell is ``logistic(c0 + b_k + s_k (r - 2 m) + f(r) + g(alpha))``
(:func:`sensor_envs.lidar.calibrate.fit_null_law`: per-bearing intercepts ``b_k``, per-bearing range slopes
``s_k`` with a ridge, shared range and incidence tables), fitted directly to the real cells' null fractions.
For each ridge (``inf`` = no slopes, the law before the slopes) and each fold assignment, the law is fitted on
the training poses' cells and its ``p_null`` compared with the held-out poses' empirical null fractions: MAE
over the held-out hit cells (unblocked bearings, ray hits the map), pooled over the folds. The learned lidar
fitted on the real training folds reaches 0.1015 on the same folds (seed 0; ``real_lidar_fidelity.py``).
Prints one row per ridge, the ridge with the lowest mean MAE over the seeds, and the ridge that
:func:`~sensor_envs.lidar.calibrate.choose_slope_ridge` (what ``calibrate lidar`` uses: 5 folds, seed 0, the
strongest ridge within 1 % of the best) picks on the whole log.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from sensor_envs.lidar.calibrate import choose_slope_ridge, fit_null_law, load_real_log, log_summary, null_law_rig
from sensor_envs.lidar.lwlr import cell_statistics, lidar_features
from sensor_envs.rng import fold_ids

ROOT = Path(__file__).resolve().parents[3]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real"), help="real data folder")
    ap.add_argument("--folds", type=int, default=5, help="leave-poses-out folds (default: 5)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="fold assignments (default: 0 1 2)")
    ap.add_argument("--ridges", type=float, nargs="+", default=[np.inf, 1.0, 0.3, 0.1, 0.03, 0.01, 0.003, 0.001])
    args = ap.parse_args()
    try:  # bad input: one line naming the file, exit 2
        real = load_real_log(args.data)
    except (FileNotFoundError, ValueError) as exc:
        print(f"{exc}: nothing to report", file=sys.stderr)
        raise SystemExit(2) from None
    t0 = time.perf_counter()
    r, a = lidar_features(real.poses, real.bearings, real.require_map(), 5.0)
    st = cell_statistics(real, 6.0, split_spurious=True)
    blocked = np.zeros(real.n_bearings, dtype=bool)
    blocked[log_summary(real, 5.0)["blocked"]] = True
    hit = np.isfinite(r) & ~blocked[None] & (st["n"] > 0)
    print(
        f"{Path(real.source).name}: {real.n_poses} poses, {int(hit.sum())} hit cells; null law MAE p_null on "
        f"held-out poses ({args.folds} folds), per fold assignment seed"
    )
    print("\n| ridge on slopes | " + " | ".join(f"seed {s}" for s in args.seeds) + " | mean |")
    print("|---|" + "---:|" * (len(args.seeds) + 1))
    means = {}
    for ridge in args.ridges:
        maes = []
        for seed in args.seeds:
            fold = fold_ids(real.n_poses, args.folds, random_state=seed)
            err = []
            for f in range(args.folds):
                te = fold == f
                law = fit_null_law(r, a, hit & ~te[:, None], st["p_null"], slope_ridge=ridge)
                p = null_law_rig(law, real.n_bearings).p_null(r[te], a[te])
                err.append(np.abs(p - st["p_null"][te])[hit[te]])
            maes.append(float(np.concatenate(err).mean()))
        means[ridge] = float(np.mean(maes))
        name = "no slopes" if not np.isfinite(ridge) else f"{ridge:g}"
        print(f"| {name} | " + " | ".join(f"{m:.4f}" for m in maes) + f" | {means[ridge]:.4f} |", flush=True)
    best = min(means, key=lambda k: means[k])
    pick, cv = choose_slope_ridge(r, a, hit, st["p_null"])
    print(f"\nlowest mean MAE: ridge {best:g} ({means[best]:.4f}); calibrate's choice on the whole log: {pick:g}")
    print("its CV (5 folds, seed 0): " + ", ".join(f"{k}: {v:.4f}" for k, v in cv.items()))
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
