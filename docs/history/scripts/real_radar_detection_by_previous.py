"""A tracker-state radar model's detection probability at the real Astyx boxes, split by the previous cycle.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: repeated misses are where the KDE's
stationary law loses detections (detection probability at the real boxes as a new track, after a miss and after a
detection; `2721bdd`).

For every real car row (closest corner of its reference box) the model's detection probability is
queried as a NEW track (``z_{t-1}`` missing, ``new_track=True``), AFTER A MISS (``z_{t-1}`` missing,
``new_track=False``) and AFTER A DETECTION (``z_{t-1}`` = one sample of the model's own new-track
output at that corner, seed ``--seed``; rows whose sample was a miss are left out). With ``p_d`` and
``p_m`` the bin means after a detection and after a miss, ``p_m / (1 - p_d + p_m)`` is the stationary
detection rate of the two-state chain (what a running radar at a static box converges to). Printed per
corner-range bin and per signed azimuth bin (left > 0) next to the real detected share: it shows
where the stationary law of ``benchmarks/real_radar_fidelity.py`` loses detections (a repeated miss).

    python docs/history/scripts/real_radar_detection_by_previous.py --data ../shared/data/real/astyx_hires2019 \
        --model models/radar_kde.npz [--bootstrap 2000]

``--bootstrap B`` also prints the real detected share per bin with 95 % percentile intervals of a cluster
bootstrap (B resamples) over frames and over blocks of 20 consecutive frames (a stand-in for scenes: Astyx
frames of one drive are numbered in a row): how far a bin's real rate is pinned down by 400 frames.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sensor_envs.radar.calibrate import DET_AZIMUTH_EDGES, load_real
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.validate import RANGE_BINS

ROOT = Path(__file__).resolve().parents[3]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real" / "astyx_hires2019"))
    ap.add_argument("--model", nargs="+", default=[str(ROOT / "models" / "radar_kde.npz")], help="KDE model files")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bootstrap", type=int, default=0, help="resamples of the real rates' cluster bootstrap")
    args = ap.parse_args()
    if args.bootstrap < 0:
        ap.error(f"--bootstrap: must be >= 0, got {args.bootstrap}")
    try:  # bad input: one line naming the file, exit 2
        frames = load_real(args.data)
        models = [(path, KDERadarModel.load(path)) for path in args.model]
    except (FileNotFoundError, ValueError) as exc:
        print(exc, file=sys.stderr)
        raise SystemExit(2) from None
    c = frames.corner
    n = c.shape[0]
    r = np.hypot(c[:, 0], c[:, 1])
    az = np.arctan2(c[:, 1], c[:, 0])
    det = np.isfinite(frames.meas[:, 0])
    bins = {f"{lo:g}-{hi:g} m": (r >= lo) & (r < hi) for lo, hi in zip(RANGE_BINS[:-1], RANGE_BINS[1:], strict=True)}
    deg = np.rad2deg(DET_AZIMUTH_EDGES)
    for lo, hi, a, b in zip(deg[:-1], deg[1:], DET_AZIMUTH_EDGES[:-1], DET_AZIMUTH_EDGES[1:], strict=True):
        bins[f"az {lo:g}..{hi:g} deg"] = (az >= a) & (az < b)
    bins["all"] = np.ones(n, dtype=bool)
    if args.bootstrap > 0:
        print_real_intervals(bins, det, np.asarray(frames.frame), args.bootstrap, np.random.default_rng(args.seed))
    nan = np.full((n, 2), np.nan)
    for path, model in models:  # one iteration per model file
        rng = np.random.default_rng(args.seed)

        def p_detect(prev: np.ndarray, new: bool, m: KDERadarModel = model) -> np.ndarray:
            state = np.concatenate([c, prev], axis=1)
            return 1.0 - np.exp(m.log_prob(nan, state, new_track=np.full(n, new)))

        p_new, p_miss = p_detect(nan, True), p_detect(nan, False)
        z, _ = model.sample_cycle(c, nan, rng, new_track=np.full(n, True))
        p_det = np.where(np.isfinite(z[:, 0]), p_detect(z, False), np.nan)
        print(f"\n{path} (n = real car rows)\n")
        print("| bin | n | real | new track | after a detection | after a miss | two-state stationary |")
        print("|---|---|---|---|---|---|---|")
        for name, s in bins.items():
            pd, pm = float(np.nanmean(p_det[s])), float(p_miss[s].mean())
            print(f"| {name} | {s.sum()} | {det[s].mean():.3f} | {p_new[s].mean():.3f} | {pd:.3f} | {pm:.3f} | "
                  f"{pm / (1 - pd + pm):.3f} |")  # fmt: skip


def print_real_intervals(
    bins: dict[str, np.ndarray], det: np.ndarray, frame: np.ndarray, n_boot: int, rng: np.random.Generator
) -> None:
    """The real detected share per bin with 95 % cluster-bootstrap intervals (frames; blocks of 20 frames)."""
    order = np.searchsorted(np.unique(frame), frame)  # frame rank 0, 1, ...
    print("\nreal detected share per bin, 95 % cluster-bootstrap interval (percentile)\n")
    print("| bin | n | real | over frames | over blocks of 20 frames |")
    print("|---|---|---|---|---|")
    cols = []
    for group in (order, order // 20):
        members = [np.flatnonzero(group == g) for g in np.unique(group)]
        draws = [
            np.concatenate([members[i] for i in rng.integers(0, len(members), len(members))]) for _ in range(n_boot)
        ]
        cols.append(
            {name: np.nanpercentile([_share(det[d], s[d]) for d in draws], [2.5, 97.5]) for name, s in bins.items()}
        )
    for name, s in bins.items():
        (a, b), (c, d) = cols[0][name], cols[1][name]
        print(f"| {name} | {s.sum()} | {det[s].mean():.3f} | [{a:.3f}, {b:.3f}] | [{c:.3f}, {d:.3f}] |")


def _share(det: np.ndarray, sel: np.ndarray) -> float:
    """Detected share of the selected rows (NaN when none is selected)."""
    return float(det[sel].mean()) if sel.any() else float("nan")


if __name__ == "__main__":
    main()
