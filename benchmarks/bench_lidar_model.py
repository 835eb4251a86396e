"""Speed of the learned lidar: one 360-bearing scan (features + params + sample), and fit with CV.

    python benchmarks/bench_lidar_model.py [--model models/neato_lidar.npz] [--fit-log LOG.npz] [--repeats 5]

Prints medians over ``--repeats`` runs (per-scan times are medians of 2,000 scans per run).
Without ``--fit-log`` the fit is timed on a rig log shaped like the real data (29 poses x 200 repeats).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from sensor_envs.geometry import raycast_pose
from sensor_envs.lidar.log import load_log
from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LearnedLidar, LidarLWLR
from sensor_envs.lidar.rig import NeatoRig, sample_free_poses
from sensor_envs.maps import load_map
from sensor_envs.modelio import default_model_path


def per_scan_us(model: LidarLWLR, n: int, rng: np.random.Generator) -> dict[str, float]:
    segs = load_map("seed_room").segments
    poses = sample_free_poses(segs, n, rng)
    sensor = LearnedLidar(model)
    t = {"features": 0.0, "params": 0.0, "sample": 0.0}
    for p in poses:
        t0 = time.perf_counter()
        r, a, _ = raycast_pose(p, model.bearings_, segs, model.max_range)
        t1 = time.perf_counter()
        par = model.params_from_features(r, a)
        t2 = time.perf_counter()
        sensor.model.sample_from_params(par, rng)
        t3 = time.perf_counter()
        t["features"] += t1 - t0
        t["params"] += t2 - t1
        t["sample"] += t3 - t2
    out = {k: 1e6 * v / n for k, v in t.items()}
    out["total"] = sum(out.values())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="model file (default: the shipped model)")
    ap.add_argument("--fit-log", default=None, help="log to time the fit on (default: a rig log)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--scans", type=int, default=2000)
    args = ap.parse_args()
    model = LidarLWLR.load(args.model or default_model_path(DEFAULT_MODEL_FILE))
    rng = np.random.default_rng(0)
    runs = [per_scan_us(model, args.scans, rng) for _ in range(args.repeats)]
    med = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
    print("learned 360-bearing scan [us], median of runs: " + ", ".join(f"{k} {v:.1f}" for k, v in med.items()))
    if args.fit_log:
        log = load_log(args.fit_log)
    else:
        log, _ = NeatoRig().record(load_map("seed_room").segments, np.random.default_rng(1), n_poses=29, repeats=200)
    for variant in ("seed", "extended"):
        t0 = time.perf_counter()
        LidarLWLR(variant=variant).fit(log)
        print(f"fit with 10-fold CV, {variant}: {time.perf_counter() - t0:.1f} s on {log.n_poses} poses ({log.source})")


if __name__ == "__main__":
    main()
