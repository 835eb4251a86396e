"""Held-out check of the radar calibration's detection stage: the ridge weight, the signed azimuth table and
the occlusion loss per range knot.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: the signed azimuth table generalises WORSE
than the symmetric one (252.9 vs 238.2 x 1e-4 held-out discrepancy), hence `calibrate radar`'s symmetric default
(`e2d6e53`, `2721bdd`).

The detection stage of ``sensor-envs calibrate radar`` (``sensor_envs/radar/calibrate.py``, stage 1/3:
least squares on the detection terms plus a ridge on second differences of the tables) is fitted on
4 of 5 folds of real frames (blocks of ``--block`` consecutive frames, block ``b`` in fold ``b % 5``)
and its detection terms are scored on the held-out fold (the rig's expected detection rates at the
held-out boxes, ``--replicates`` simulations per box, seed ``--seed``). The offset and reflection
parameters are those of ``--rig`` (held fixed: the reflection points the detection law sees); the
detection law starts from the generic rig's, as in the calibration. Candidates: the ridge weights
``--ridges``, each with the signed azimuth table and, for comparison, with the symmetric ``|azimuth|``
table (``calibrate_rig(signed_azimuth=False)``, the default: this check is why), and the symmetric table with the
occlusion loss per range knot (``--kinds occlusion_by_range``: ``calibrate_rig(occlusion_by_range=True)``). The
held-out terms include ``det_occlusion_range`` (detection per range x occluded-fraction cell), which only the
last kind fits. Prints the mean held-out discrepancy
per term (x 1e-4), its sum per fold, and the held-out detection rate per signed azimuth bin (pooled
over folds) as a markdown table. Models and data stay in memory (~2 min for 4 ridges).

    python docs/history/scripts/real_radar_calibration_cv.py --data ../shared/data/real/astyx_hires2019
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from sensor_envs.radar import calibrate as cal
from sensor_envs.radar.rig import RigConfig, load_rig

ROOT = Path(__file__).resolve().parents[3]
TERMS = tuple(key for key, _ in cal.DETECTION_TERMS)
POOLED = ("det_azimuth", "det_occlusion_range")
"""Statistics whose held-out rates are pooled over folds for the tables (row-weighted)."""
KINDS = ("signed", "symmetric", "occlusion_by_range")


def subset(frames: cal.RealFrames, keep: np.ndarray) -> cal.RealFrames:
    """The rows of the frames where ``keep[frame]`` (frame ids renumbered; clutter left out: unused here)."""
    rows = keep[frames.frame]
    new_id = np.cumsum(keep) - 1
    return cal.RealFrames(
        frames.boxes[rows],
        new_id[frames.frame[rows]],
        frames.occluded[rows],
        frames.corner[rows],
        frames.meas[rows],
        frames.clutter_counts[keep],
        np.zeros((0, 2)),
        frames.source,
    )


class _NoBar:
    def update(self, n: int) -> None:
        """tqdm's interface, silent."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real" / "astyx_hires2019"))
    ap.add_argument("--rig", default=str(ROOT / "models" / "radar_rig.json"), help="offset/reflection parameters")
    ap.add_argument("--ridges", type=float, nargs="+", default=[0.0005, 0.002, 0.01, 0.05])
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--replicates", type=int, default=4)
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS), help="detection laws to compare")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    try:  # bad input: one line naming the file, exit 2
        frames = cal.load_real(args.data)
        base, _ = load_rig(args.rig)
    except (FileNotFoundError, ValueError) as exc:
        print(exc, file=sys.stderr)
        raise SystemExit(2) from None
    generic = RigConfig()
    base = replace(  # the calibration's start: the generic rig's detection law, --rig's reflection and offsets
        base,
        max_range=150.0,
        p_detect=generic.p_detect,
        detect_range_knots=None,
        detect_range_table=None,
        detect_azimuth_knots=None,
        detect_azimuth_table=None,
        detect_azimuth_signed=False,
        occlusion_loss=generic.occlusion_loss,
        occlusion_loss_knots=None,
        occlusion_loss_table=None,
    )
    fold_of = (np.arange(frames.n_frames) // args.block) % args.folds
    rows = []
    for ridge in args.ridges:  # one iteration per candidate ridge weight
        for kind in args.kinds:
            terms = {t: [] for t in TERMS}
            pooled: dict[str, list[np.ndarray]] = {}
            for k in range(args.folds):  # one iteration per held-out fold
                train, test = subset(frames, fold_of != k), subset(frames, fold_of == k)
                real_tr, real_te = cal.real_statistics(train), cal.real_statistics(test)
                sim = cal._sim_setup(train, args.replicates, np.random.default_rng([args.seed, 7]))
                by_range = kind == "occlusion_by_range"
                cfg = cal._fit_detection(
                    base, sim, real_tr, ridge, _NoBar(), signed=kind == "signed", by_range=by_range
                )
                st = cal.rig_statistics(cfg, test, args.replicates, args.seed + 1, expected=True)
                d = cal.detection_discrepancy(st, real_te)
                for t in TERMS:
                    terms[t].append(d[t])
                for key in POOLED:  # rate x real rows per bin, and the rows
                    n = real_te[dict(cal.DETECTION_TERMS)[key]]
                    ok = np.isfinite(st[key])
                    acc = pooled.setdefault(key, [np.zeros(n.size), np.zeros(n.size)])
                    acc[0][ok] += st[key][ok] * n[ok]
                    acc[1] += n
            mean = {t: 1e4 * float(np.mean(v)) for t, v in terms.items()}
            det_az, det_or = (pooled[k][0] / np.maximum(pooled[k][1], 1) for k in POOLED)
            rows.append((ridge, kind, mean, det_az, det_or))
            per_fold = 1e4 * np.sum([terms[t] for t in TERMS], axis=0)
            print(f"ridge {ridge:g} {kind}: " + ", ".join(f"{t} {v:.2f}" for t, v in mean.items())
                  + "; sum per fold " + " ".join(f"{v:.1f}" for v in per_fold), flush=True)  # fmt: skip
    real = cal.real_statistics(frames)
    az = np.rad2deg(cal.DET_AZIMUTH_EDGES)
    labels = [f"{lo:g}..{hi:g}" for lo, hi in zip(az[:-1], az[1:], strict=True)]
    print(f"\nHeld-out detection discrepancy (x 1e-4, mean of {args.folds} folds) and held-out detection rate per")
    print("signed azimuth bin [deg] (left > 0)\n")
    print("| ridge | table | " + " | ".join(TERMS) + " | sum | " + " | ".join(labels) + " |")
    print("|---" * (3 + len(TERMS) + len(labels)) + "|")
    print("| real | | " + " | " * len(TERMS) + " | " + " | ".join(f"{v:.3f}" for v in real["det_azimuth"]) + " |")
    for ridge, kind, mean, rates, _ in rows:
        cells = " | ".join(f"{mean[t]:.2f}" for t in TERMS)
        print(f"| {ridge:g} | {kind} | {cells} | {sum(mean.values()):.2f} | " + " | ".join(f"{v:.3f}" for v in rates)
              + " |")  # fmt: skip
    occ = ("0", "(0, 0.5)", "[0.5, 1]")
    rb = cal.DET_RANGE_EDGES
    cells = [f"{lo:g}-{hi:g} m, {o}" for lo, hi in zip(rb[:-1], rb[1:], strict=True) for o in occ]
    print("\nHeld-out detection rate per corner range x occluded fraction (pooled over folds; rows in brackets)\n")
    print("| cell (rows) | real | " + " | ".join(f"{r[0]:g} {r[1]}" for r in rows) + " |")
    print("|---" * (2 + len(rows)) + "|")
    for i, lab in enumerate(cells):
        n = int(real["n_occlusion_range"][i])
        print(
            f"| {lab} ({n}) | {real['det_occlusion_range'][i]:.3f} | "
            + " | ".join(f"{r[4][i]:.3f}" for r in rows)
            + " |"
        )
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
