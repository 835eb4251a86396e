"""Real-data algorithm-level evaluation: how far are the simulators' detector results from the real ones?

1. Neato lidar (``neato_mar27_train.npz``): the line-of-known-length detector's precision-recall
   trajectory on the real scans vs scans simulated at the same poses and map by the learned LWLR model
   (fitted leave-poses-out: ``--folds`` folds, never on the scans compared) and by the Gaussian baseline
   (refitted on the same training poses). ``model`` samples with :meth:`LidarLWLR.sample` (pose
   uncertainty, per-cell independent); ``model_world`` as the worlds' sensor does (poses taken as true).
2. Astyx HiRes2019 radar: the lane trigger ("car in my lane within 40 m" and 5 other zones) on the real
   object output vs the KDE model and the Gaussian baseline at the same reference boxes, (a) with the
   shipped rig-fitted model files and (b) with both fitted leave-blocks-out on Astyx.

Prints ``distance_to_real`` (mean point-wise distance in precision-recall space) per experiment and
writes each report (report.json, report.md, pr_trajectories.png) under ``--out``. Models fitted here stay
in memory (never saved: they would hold the real data).

    python benchmarks/real_evaluate_report.py --data ../shared/data/real --out /tmp/real_evaluate
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from sensor_envs.evaluate.lidar_experiments import log_experiment
from sensor_envs.evaluate.radar_detection import radar_detection_experiment
from sensor_envs.evaluate.report import closeness_sentence, write_report
from sensor_envs.lidar.log import load_log
from sensor_envs.radar.astyx import load_astyx


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="../shared/data/real", help="the real-data folder")
    ap.add_argument("--out", required=True, help="output folder (outside the repository; must not exist)")
    ap.add_argument("--repeats", type=int, default=10, help="scans per Neato pose and source")
    ap.add_argument("--folds", type=int, default=3, help="leave-poses-out folds of the Neato fit")
    ap.add_argument("--draws", type=int, default=20, help="simulated draws per Astyx frame")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    data, out = Path(args.data), Path(args.out)
    out.mkdir(parents=True, exist_ok=False)
    summary = {}
    t0 = time.perf_counter()
    neato = data / "neato_mar27_train.npz"
    if neato.exists():
        rep = log_experiment(load_log(neato), repeats=args.repeats, folds=args.folds, seed=args.seed)
        rep["command"] = f"python benchmarks/real_evaluate_report.py --data {args.data} --out {args.out}"
        (out / "neato_detection").mkdir()
        write_report(rep, out / "neato_detection")
        summary["neato_detection"] = rep["distance_to_real"]
        print("Neato detection:", rep["distance_to_real"], closeness_sentence(rep["distance_to_real"]), flush=True)
    else:
        print(f"{neato} absent: Neato detection skipped")
    astyx = data / "astyx_hires2019"
    if astyx.is_dir():
        log = load_astyx(astyx, progress=True)
        for name, fit in (("astyx_trigger_shipped_models", False), ("astyx_trigger_fitted_on_astyx", True)):
            rep = radar_detection_experiment(log, fit=fit, seed=args.seed, draws=args.draws)
            (out / name).mkdir()
            write_report(rep, out / name, f"radar lane trigger ({name})")
            summary[name] = rep["distance_to_real"]
            print(f"{name}:", rep["distance_to_real"], closeness_sentence(rep["distance_to_real"]), flush=True)
    else:
        print(f"{astyx} absent: Astyx trigger skipped")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps(summary, indent=2))
    print(f"done in {time.perf_counter() - t0:.0f} s; reports under {out}")


if __name__ == "__main__":
    main()
