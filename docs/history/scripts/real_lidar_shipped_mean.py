"""The SHIPPED learned lidar's mean vs the raycast on the real Neato poses, per fold and per pose (issue 12).

Record (issue 40; not maintained, see docs/history/scripts.md). Found: the shipped learned lidar's mean beats the
raycast on the real poses in 5 of 5 folds, is worse on 8 of 29 poses, worst +2.19 mm (`41f5f6d`).

    python docs/history/scripts/real_lidar_shipped_mean.py --data ../shared/data/real [--model models/neato_lidar.npz]
        [--folds 5] [--seed 0]

The shipped model is fitted on logs of the calibrated rig, never on the real log, so every real pose is an
unseen pose for it. For each pose of the real log ``neato_mar27_train.npz`` and for the leave-poses-out folds
of ``real_lidar_fidelity.py`` (same fold assignment), the MAE of ``mu`` [m] against the cells' mean of
in-range readings, over cells whose ray hits the map and that have at least 2 in-range readings (Table I's
``mae_mu``): the shipped model (``mu = r + (1 - s) bias`` at the log's approximate poses) and the raycast
(``mu = r``). Prints both tables and how many folds and poses the model is worse on.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sensor_envs.lidar.calibrate import load_real_log
from sensor_envs.lidar.lwlr import LidarLWLR, cell_statistics, lidar_features
from sensor_envs.rng import fold_ids

ROOT = Path(__file__).resolve().parents[3]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real"), help="real data folder")
    ap.add_argument("--model", default=str(ROOT / "models" / "neato_lidar.npz"), help="learned lidar model file")
    ap.add_argument("--folds", type=int, default=5, help="leave-poses-out folds (default: 5, as the fidelity report)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the fold assignment (default: 0)")
    args = ap.parse_args()
    try:  # bad input: one line naming the file, exit 2
        real = load_real_log(args.data)
        model = LidarLWLR.load(args.model)
    except (FileNotFoundError, ValueError) as exc:
        print(f"{exc}: nothing to report", file=sys.stderr)
        raise SystemExit(2) from None
    r, a = lidar_features(real.poses, real.bearings, real.require_map(), 5.0)
    mu = model.params_from_features(r, a)["mu"]
    st = cell_statistics(real, 6.0, split_spurious=True)
    ok = (st["n_ok"] >= 2) & np.isfinite(r)
    err_model, err_ray = np.abs(mu - st["mean"]), np.abs(r - st["mean"])
    fold = fold_ids(real.n_poses, args.folds, random_state=args.seed)
    print(
        f"{Path(args.model).name} (bias shrinkage s = {getattr(model, 'bias_shrinkage_', 0.0)}) on "
        f"{Path(real.source).name}: {real.n_poses} poses, MAE of mu [m] on hit cells with >= 2 in-range readings"
    )
    print("\n| fold | cells | raycast | shipped model | model - raycast [mm] |\n|---|---:|---:|---:|---:|")
    worse_folds = 0
    for f in range(args.folds):
        sel = ok & (fold == f)[:, None]
        m, rc = err_model[sel].mean(), err_ray[sel].mean()
        worse_folds += int(m > rc)
        print(f"| {f} | {int(sel.sum())} | {rc:.5f} | {m:.5f} | {1e3 * (m - rc):+.2f} |")
    print(
        f"| pooled | {int(ok.sum())} | {err_ray[ok].mean():.5f} | {err_model[ok].mean():.5f} | "
        f"{1e3 * (err_model[ok].mean() - err_ray[ok].mean()):+.2f} |"
    )
    per_pose = [(err_model[i][ok[i]].mean(), err_ray[i][ok[i]].mean()) for i in range(real.n_poses) if ok[i].any()]
    worse_poses = sum(m > rc for m, rc in per_pose)
    diffs = np.array([1e3 * (m - rc) for m, rc in per_pose])
    print(
        f"\nworse than the raycast: {worse_folds} of {args.folds} folds, {worse_poses} of {len(per_pose)} poses "
        f"(per-pose difference [mm]: median {np.median(diffs):+.2f}, worst {diffs.max():+.2f})"
    )


if __name__ == "__main__":
    main()
