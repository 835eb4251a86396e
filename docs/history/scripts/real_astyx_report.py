"""Real-data figures on Astyx HiRes2019: detection share vs range/azimuth, clutter rate, held-out NLL.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: Astyx HiRes2019 (400 frames, 2,161 cars):
88.8 % of cars detected, 94 clutter clusters per frame; held-out NLL of z given a detection (nested 5 folds of
10-frame blocks): Gaussian 2.91, KDE with the seed kernel 3.05, KDE with `relevance="cv"` 2.40 (`8f15227`); it led
to the relevance CV. `sensor-envs validate radar` on real frames reports such figures for any model since.

Held-out NLL: frames are grouped in blocks of ``--block`` consecutive frames (the log's ``sequence``);
block ``b`` is in test fold ``b % folds``. For each outer fold, fitted on the other folds and scored
on it: the Gaussian baseline; the KDE model (no ``z_{t-1}``: Astyx is no time series;
leave-one-block-out CV output bandwidths) with the seed's relevance kernel (``kde``, corner variance
3 m^2); and the KDE with ``relevance="cv"`` (``kde_cv``), whose corner variance is chosen from
``--corner-variance`` by ``--inner-folds``-fold CV on the outer TRAINING folds only (nested CV: the
scored fold is never seen by the selection). Models fitted here stay in memory (never saved: the
data are CC BY-NC-SA).

    python docs/history/scripts/real_astyx_report.py --out /tmp/astyx_report
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from sensor_envs.radar.astyx import detection_statistics, load_astyx
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.validate import evaluate, split_by_blocks, write_report

DEFAULT = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "real" / "astyx_hires2019"


def summarise(folds: list[dict]) -> dict:
    keys = ("nll_outcome", "nll_z_given_detected", "nll_z_given_detected_median")
    out = {}
    for who in [k for k in folds[0] if k != "fold"]:
        for k in keys:
            v = np.array([f[who][k] for f in folds])
            out[f"{who}_{k}"] = {"mean": float(v.mean()), "per_fold": v.round(3).tolist()}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", default=str(DEFAULT), help="astyx_hires2019 folder")
    ap.add_argument("--out", required=True, help="output folder (outside the repository)")
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--position", default="nearest", choices=("nearest", "centroid"))
    ap.add_argument(
        "--corner-variance",
        nargs="+",
        type=float,
        default=[3.0, 6.0, 12.0, 24.0, 48.0],
        help="candidate corner variances [m^2] of relevance='cv'",
    )
    ap.add_argument("--inner-folds", type=int, default=4)
    args = ap.parse_args()
    log = load_astyx(args.data, block=args.block, position=args.position, progress=True)
    stats = detection_statistics(
        log, np.array([0, 15, 30, 50, 75, 100, 150.0]), np.deg2rad([-60, -40, -20, -5, 5, 20, 40, 60.0])
    )
    folds, kde = [], None
    for k in range(args.folds):
        train, test = split_by_blocks(log, block=args.block, n_folds=args.folds, fold=k)
        gauss = GaussianRadar().fit(train)
        rng = np.random.default_rng(k)
        row = {"fold": k, "gaussian": evaluate(gauss, test, rng, time_series=False)}
        kde = KDERadarModel(use_prev=False, cv_group="sequence", random_state=k).fit(train)
        row["kde"] = evaluate(kde, test, rng, time_series=False)
        sel = KDERadarModel(
            use_prev=False,
            cv_group="sequence",
            relevance="cv",
            relevance_candidates=tuple(args.corner_variance),
            relevance_folds=args.inner_folds,
            random_state=k,
            verbose=True,
        ).fit(train)
        row["kde_cv"] = evaluate(sel, test, rng, time_series=False)
        row["kde_cv"]["corner_variance_chosen"] = sel.rel_variance_[0]
        row["kde_cv"]["inner_cv_loglik_per_row"] = dict(
            zip(map(str, args.corner_variance), sel.relevance_scores_.round(4).tolist(), strict=True)
        )
        folds.append(row)
        print(
            f"fold {k}: chosen corner variance {sel.rel_variance_[0]:g} m^2; NLL(z|det) mean/median "
            + ", ".join(
                f"{key} {v['nll_z_given_detected']:.3f}/{v['nll_z_given_detected_median']:.3f}"
                for key, v in row.items()
                if key != "fold"
            ),
            flush=True,
        )
    report = {
        "data": str(args.data),
        "block": args.block,
        "folds": args.folds,
        "position": args.position,
        "detection": stats,
        "held_out": summarise(folds),
        "per_fold": folds,
    }
    out = Path(args.out)
    last = {"model": folds[-1]["kde"], "baseline_gaussian": folds[-1]["gaussian"]}
    write_report(last, out / "last_fold", model=kde, log=test)
    (out / "astyx_report.json").write_text(json.dumps(report, indent=1, default=float))
    print(json.dumps({"detection": {k: v for k, v in stats.items()}, "held_out": report["held_out"]}, indent=1))


if __name__ == "__main__":
    main()
