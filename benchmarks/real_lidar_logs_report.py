"""Real-data figures of the learned lidar fitted on robot logs (issue #10): held-out NLL per reading, fit time.

    python benchmarks/real_lidar_logs_report.py --data ../shared/data/real [--max-readings 300] [--out DIR]

For ``carmen/intel-corrected``, ``carmen/aces-corrected`` and the three Neato ROS bags: splits the
scans into blocks of ``--block-scans`` consecutive scans, every ``--test-every``-th block held out
(:func:`sensor_envs.lidar.mapping.split_parts`); fits the extended model and the Gaussian baseline on
the training blocks (per reading, CV by contiguous blocks) and prints, on the held-out blocks, the
NLL per reading of the model, the ideal and the Gaussian baseline, the null-rate ECE, PIT KS, mean
lag-1 ACF of range residuals, and the fit time.

Maps: CARMEN logs have none, so a nominal map is built from the TRAINING blocks only (occupancy grid
of the corrected poses and returns, 5 cm cells, >= 2 returns per cell -> segments). The ROS bags use
``mymap.yaml`` with the map <- odom transform estimated by scan matching the first 15 scans
(:func:`sensor_envs.lidar.mapping.align_to_grid`); the alignment's fit over all scans is printed.
CARMEN ``aces``: readings of exactly 50 m (0.8 %, the saturated maximum) are nulls. Writes
``DIR/<name>/report.json`` and plots (default DIR: /tmp/real_lidar_logs_report; never the repository).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from sensor_envs.lidar.log import load_log
from sensor_envs.lidar.lwlr import LidarLWLR
from sensor_envs.lidar.mapping import map_features, prepare_log
from sensor_envs.lidar.validate_readings import fit_gaussian_readings, validate_readings

DATASETS = {
    # name: (relative path, loader options, max_range [m], spur_above [m], table range step [m], map, align)
    "left_side": ("neato_ros1_bags/left_side.bag", {}, 5.0, 6.0, 0.125, "neato_ros1_bags/mymap.yaml", True),
    "middle": ("neato_ros1_bags/middle.bag", {}, 5.0, 6.0, 0.125, "neato_ros1_bags/mymap.yaml", True),
    "right_side": ("neato_ros1_bags/right_side.bag", {}, 5.0, 6.0, 0.125, "neato_ros1_bags/mymap.yaml", True),
    "intel-corrected": ("carmen/intel-corrected.log.gz", {}, 30.0, 31.0, 0.25, None, False),
    "aces-corrected": ("carmen/aces-corrected.log.gz", {"max_range": 50.0}, 45.0, 49.0, 0.25, None, False),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="../shared/data/real")
    ap.add_argument("--max-readings", type=int, default=300, help="scans used by each fit (evenly spaced)")
    ap.add_argument("--block-scans", type=int, default=40, help="scans per block of the train/test split")
    ap.add_argument("--test-every", type=int, default=4, help="every N-th block is held out")
    ap.add_argument("--folds", type=int, default=10, help="CV folds (contiguous blocks) of the kernel widths")
    ap.add_argument("--only", nargs="*", default=None, help="names of the datasets to run (default: all)")
    ap.add_argument("--out", default="/tmp/real_lidar_logs_report")
    args = ap.parse_args()
    data = Path(args.data)
    rows = []
    for name, (rel, opts, max_range, spur_above, step, map_rel, align) in DATASETS.items():
        if args.only and name not in args.only:
            continue
        path = data / rel
        if not path.exists():
            print(f"{name}: {path} is absent, skipped")
            continue
        raw = load_log(path, **opts)
        common = {
            "map": None if map_rel is None else data / map_rel,
            "block_scans": args.block_scans,
            "test_every": args.test_every,
            "max_range": max_range,
            "align": align,
        }
        train, info = prepare_log(raw, part="train", **common)
        test, _ = prepare_log(raw, part="test", **common)
        t0 = time.perf_counter()
        model = LidarLWLR(
            variant="extended",
            n_folds=args.folds,
            max_range=max_range,
            spur_above=spur_above,
            table_range_step=step,
            progress=False,
        ).fit(train, max_readings=args.max_readings)
        fit_s = time.perf_counter() - t0
        r, a = map_features(train.poses, train.bearings, train.require_map(), max_range)
        gauss = fit_gaussian_readings(train, r, a, spur_above)
        rep = validate_readings(model, test, Path(args.out) / name, gauss)
        rep["preparation"], rep["fit_seconds"], rep["model_cv"] = info, fit_s, model.cv_scores_
        (Path(args.out) / name / "report.json").write_text(json.dumps(rep, indent=2, default=float))
        m = rep["metrics"]
        row = {
            "name": name,
            "scans": f"{train.n_poses}+{test.n_poses}",
            "K": raw.n_bearings,
            "model": m["model_extended"]["nll_per_reading"],
            "ideal": m["ideal"]["nll_per_reading"],
            "gaussian": m["gaussian"]["nll_per_reading"],
            "ece": (m["model_extended"]["ece"], m["gaussian"]["ece"]),
            "ks": (m["model_extended"]["pit_ks"], m["gaussian"]["pit_ks"]),
            "acf1": m["model_extended"]["acf1_range_mean"],
            "block": model.cv_scores_["blocks"]["scans_per_block"],
            "fit_s": fit_s,
        }
        rows.append(row)
        extra = ""
        if "alignment" in info:
            q = info["alignment"]["fit_of_all_scans"]
            t = info["alignment"]["transform_map_odom"]
            extra = (
                f"; alignment map<-odom ({t[0]:.3f} m, {t[1]:.3f} m, {t[2]:.3f} rad): all scans' returns median "
                f"{100 * q['median_m']:.1f} cm from the map, {100 * q['within_10cm']:.0f} % within 10 cm"
            )
        print(
            f"{name}: map {info['map'].get('segments')} segments ({info['map']['source']}); "
            f"CV block {row['block']} scans{extra}",
            flush=True,
        )
    print()
    print(
        "| log | scans train+test | bearings | NLL/reading model | ideal | Gaussian | ECE model / Gaussian | "
        "PIT KS model / Gaussian | lag-1 ACF (model) | CV block [scans] | fit time [s] |"
    )
    print("|" + "---|" * 11)
    for r in rows:
        print(
            f"| {r['name']} | {r['scans']} | {r['K']} | {r['model']:.3f} | {r['ideal']:.1f} | {r['gaussian']:.3f} | "
            f"{r['ece'][0]:.3f} / {r['ece'][1]:.3f} | {r['ks'][0]:.3f} / {r['ks'][1]:.3f} | {r['acf1']:.3f} | "
            f"{r['block']} | {r['fit_s']:.1f} |"
        )


if __name__ == "__main__":
    main()
