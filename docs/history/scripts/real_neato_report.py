"""Real-data figures of the learned lidar (issue #3): cross-validated Table I, LL, rig calibration.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: the real-versus-rig statistics that set the
Neato rig's defaults (per-bearing bias Normal(3.8 mm, 7.6 mm), 26 bearings blocked by the casing's posts, noise sd
per 0.5 m range bin; docs/concepts/rigs.md) and the cross-validated Table I of the seed and extended models on the
29 real poses (`0b8f74a`, `20e635d`). The rig is calibrated by `sensor-envs calibrate lidar` since.

    python docs/history/scripts/real_neato_report.py --data ../shared/data/real [--folds 10] \
        [--inner-folds 10] [--out DIR]

Fits the seed and extended models on the real Neato log (29 poses) with leave-poses-out CV (each
outer fold refits both models, with their own inner CV of kernel widths, and the Gaussian baseline
on the other poses) and prints Table I for the seed model, the extended model and the ideal and
Gaussian baselines, plus the real-versus-rig statistics used to calibrate the rig. Writes
``DIR/real_cv_report.json`` (default DIR: /tmp/real_neato_report; never inside the repository).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from sensor_envs.lidar.log import load_log
from sensor_envs.lidar.rig import NeatoRig
from sensor_envs.lidar.validate import cross_validate_log, log_statistics, metrics_markdown
from sensor_envs.maps import load_map


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="../shared/data/real", help="folder holding neato_mar27_train.npz")
    ap.add_argument("--folds", type=int, default=10)
    ap.add_argument("--inner-folds", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="/tmp/real_neato_report")
    args = ap.parse_args()
    path = Path(args.data) / "neato_mar27_train.npz"
    if not path.exists():
        raise SystemExit(f"{path} is absent: nothing to report")
    log = load_log(path)
    rig_log, _ = NeatoRig().record(
        load_map("seed_room").segments,
        np.random.default_rng(args.seed),
        n_poses=log.n_poses,
        repeats=log.ranges.shape[2],
    )
    stats = {"real": log_statistics(log), "rig": log_statistics(rig_log)}
    print("## Real vs rig statistics (rig: same number of poses and repeats, seed_room)")
    for k in (
        "null_fraction",
        "spurious_fraction",
        "cells_with_spurious",
        "blocked_bearings",
        "mixed_null_cells",
        "mae_mean_minus_nominal",
        "median_cell_std",
    ):
        print(f"{k:28s} real {stats['real'][k]:.4g}   rig {stats['rig'][k]:.4g}")
    for a, b in zip(stats["real"]["by_range"], stats["rig"]["by_range"], strict=True):
        print(
            f"r {a['r']} m: p_null real {a['p_null']}  rig {b['p_null']};  median std real {a['median_std']}  "
            f"rig {b['median_std']}"
        )
    t0 = time.perf_counter()
    table = cross_validate_log(log, n_folds=args.folds, inner_folds=args.inner_folds, random_state=args.seed)
    secs = time.perf_counter() - t0
    print(f"\n## Cross-validated Table I on {path.name} ({args.folds} leave-poses-out folds, {secs:.0f} s)\n")
    print(metrics_markdown(table))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "real_cv_report.json").write_text(
        json.dumps({"statistics": stats, "cv_table": table, "seconds": secs, "args": vars(args)}, indent=2)
    )
    print(f"wrote {out / 'real_cv_report.json'}")


if __name__ == "__main__":
    main()
