"""Occlusion on real Astyx frames: what it does to the radar, what the rig does, what a KDE gains from it.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: detection share and polar offsets per
occluded-fraction bin, real vs rig, and the real-fitted KDE with each occlusion state (`114afe1`).

1. Per bin of the geometric occluded fraction (``features.occluded_column``: the share of a car box's
   angular extent hidden behind the frame's other car boxes; 0, (0, 0.5), [0.5, 1]): the measured
   detection share and the detected offsets ``z = meas - closest corner`` in the corner's polar frame
   (radial, OUTWARD cross-range; mean / sd [m]), against the rig (``--rig``, default the shipped
   ``models/radar_rig.json``) simulated at the same boxes (``RadarRig.snapshot``, 8 draws).
2. A KDE fitted directly on the real training folds (the fidelity benchmark's reference: no ``z_{t-1}``,
   corner variance 48 m^2, 5 folds of 10-frame blocks) with each extra state: none, the annotators'
   ``occlusion`` label (0/1/2), the geometric ``occluded`` fraction (variance by CV). Held-out NLL of
   outcomes and of z given a detection [nats], detection log-loss [nats], detection rate per azimuth bin.

    python docs/history/scripts/real_radar_occlusion.py --data ../shared/data/real/astyx_hires2019 [--rig RIG.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from sensor_envs.geometry import to_polar_frame
from sensor_envs.radar.astyx import load_astyx
from sensor_envs.radar.calibrate import DET_AZIMUTH_EDGES, frames_from_log
from sensor_envs.radar.features import model_extra
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import RadarLog, target_tuples
from sensor_envs.radar.rig import RadarRig, SnapshotDraws, load_rig
from sensor_envs.radar.validate import split_by_blocks

ROOT = Path(__file__).resolve().parents[3]
OCC_BINS = ((0.0, 1e-9, "0"), (1e-9, 0.5, "(0, 0.5)"), (0.5, 1.01, "[0.5, 1]"))


def by_occlusion(log: RadarLog, rig_path: str, seed: int) -> None:
    """Part 1: detection share and polar offsets per occluded-fraction bin, real vs rig."""
    frames = frames_from_log(log)
    cfg, _ = load_rig(rig_path)
    rng = np.random.default_rng(seed)
    sims = [RadarRig(cfg).snapshot(frames.boxes, frames.occluded, SnapshotDraws.draw(len(frames.boxes), rng))
            for _ in range(8)]  # fmt: skip
    real = to_polar_frame(frames.meas - frames.corner, frames.corner)
    print("| occluded | rows | detected real / rig | radial mean, sd real | rig | outward mean, sd real | rig |")
    print("|---|---|---|---|---|---|---|")
    for lo, hi, lab in OCC_BINS:
        m = (frames.occluded >= lo) & (frames.occluded < hi)
        d = m & np.isfinite(real[:, 0])
        sim = np.concatenate([to_polar_frame(s[0] - frames.corner, frames.corner)[m] for s in sims])
        sim = sim[np.isfinite(sim[:, 0])]
        p_rig = np.mean([s[1][m].mean() for s in sims])
        cols = [f"{v[:, j].mean():+.2f}, {v[:, j].std():.2f}" for j in (0, 1) for v in (real[d], sim)]
        print(f"| {lab} | {m.sum()} | {np.isfinite(real[m, 0]).mean():.3f} / {p_rig:.3f} | " + " | ".join(cols) + " |")


def real_fitted(log: RadarLog, folds: int, block: int) -> None:
    """Part 2: the real-fitted KDE with each extra state, scored on held-out folds (``log`` in ``block``-frame
    sequences)."""
    print("\n| extra state | NLL outcomes | NLL z given det. | detection log-loss | det. rate per azimuth bin "
          f"({', '.join(f'{np.rad2deg(a):g}' for a in DET_AZIMUTH_EDGES)} deg): model / real |")  # fmt: skip
    print("|---|---|---|---|---|")
    for state in ((), ("occlusion",), ("occluded",)):
        t0 = time.perf_counter()
        p_det, corner, z, lp = [], [], [], []
        var: list[float] = []
        for k in range(folds):  # one iteration per fold
            train, test = split_by_blocks(log, block=block, n_folds=folds, fold=k)
            kde = KDERadarModel(use_prev=False, cv_group="sequence", rel_variance=(48.0, 48.0, 0.03, 0.03),
                                extra_state=state, random_state=k).fit(train)  # fmt: skip
            tt = target_tuples(test)
            ex = {} if not state else {"extra": model_extra(kde, test, tt.row)}
            st = np.concatenate([tt.corner, np.full_like(tt.corner, np.nan)], axis=1)
            lp.append(kde.log_prob(tt.z, st, **ex))
            p_det.append(-np.expm1(kde.log_prob(np.full_like(tt.z, np.nan), st, **ex)))
            corner.append(tt.corner)
            z.append(tt.z)
            var.extend(kde.extra_variance_)
        p, c, zz, lpp = (np.concatenate(v) for v in (p_det, corner, z, lp))
        det = np.isfinite(zz[:, 0])
        az = np.arctan2(c[:, 1], c[:, 0])
        cells = []
        for lo, hi in zip(DET_AZIMUTH_EDGES[:-1], DET_AZIMUTH_EDGES[1:], strict=True):
            s = (az >= lo) & (az < hi)
            cells.append(f"{p[s].mean():.3f}/{det[s].mean():.3f}")
        name = ", ".join(state) or "none"
        if var:
            name += f" (CV variance {min(var):.3g}-{max(var):.3g})"
        print(f"| {name} | {-lpp.mean():.3f} | {-(lpp[det] - np.log(p[det])).mean():.3f} | "
              f"{-np.mean(np.where(det, np.log(p), np.log1p(-p))):.4f} | {' '.join(cells)} |")  # fmt: skip
        print(f"  ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real" / "astyx_hires2019"))
    ap.add_argument("--rig", default=str(ROOT / "models" / "radar_rig.json"))
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    try:  # bad input: one line naming the file, exit 2
        load_rig(args.rig)
        if not Path(args.data).is_dir():
            raise FileNotFoundError(f"{args.data}: no such folder (astyx_hires2019)")
    except (FileNotFoundError, ValueError) as exc:
        print(f"{exc}", file=sys.stderr)
        raise SystemExit(2) from None
    log = load_astyx(args.data, block=args.block)  # read once: the frames of part 1 ignore the blocks
    by_occlusion(log, args.rig, args.seed)
    real_fitted(log, args.folds, args.block)


if __name__ == "__main__":
    main()
