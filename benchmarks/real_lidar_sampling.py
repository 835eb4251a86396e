"""Which sampling semantics matches the real sensor: per-cell pose spread or one rigid pose error per scan (issue 43).

    python benchmarks/real_lidar_sampling.py --data ../shared/data/real [--folds 5] [--seed 0] [--repeats 200]
        [--out-md docs/results/lidar_sampling.md] [--out-json docs/results/lidar_sampling.json]

On the real static log ``neato_mar27_train.npz`` (29 poses x 360 bearings x ~200 repeats), per leave-poses-out fold
a model is fitted on the other poses as ``sensor-envs fit lidar`` does with its defaults, and logs are sampled at
the held-out poses (as many repeats as the real log) with three semantics:

* ``per_cell`` (``LidarLWLR.sample`` before issue 43): each cell's mean drawn independently, ``mu + tau z`` or, with
  probability ``p_out``, uniform on ``[0, max_range]``;
* ``rigid`` (``LidarLWLR.sample`` now): one pose error ``(dx, dy, dtheta) ~ Normal(0, pose_sd_)`` per pose, shared by
  all its bearings and repeats, then the worlds' per-reading draw at the perturbed pose;
* ``world`` (the worlds' ``LearnedLidar`` at the given poses: no pose error).

For the real log and each sampled one, with ``e = cell mean - mu`` (``mu`` of the held-out model at the log's
pose; cells with >= 2 in-range readings and ``|e| < 0.1 m``):

* the correlation of ``e`` between bearings ``lag`` apart at the same pose (a rigid pose error moves neighbouring
  rays together; independent cell draws do not);
* the median and 90 % quantile of ``|e|`` (how far cell means stray at an approximate pose);
* the correlation, within one scan (one repeat), of the readings' deviations from their cell means between
  neighbouring bearings (a scan-level jitter would show here; every semantics draws it independently);
* unless ``--no-detection``: the line detector's precision-recall distance to the real trajectory
  (``sensor-envs evaluate detection``) with ``sample`` as it is and as it was.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.lidar.calibrate import load_real_log, ranges_sha256
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr import LidarLWLR, lidar_features
from sensor_envs.outputs import write_json
from sensor_envs.rng import fold_ids

ROOT = Path(__file__).resolve().parents[1]
LAGS = (1, 2, 5, 10)
SOURCES = ("real", "per_cell", "rigid", "world")


def _fit(log: LidarLog) -> LidarLWLR:
    return LidarLWLR(variant="extended", n_folds=10, random_state=0).fit(log)


def per_cell_sample(
    self: LidarLWLR, poses: Any, map_segments: Any, rng: Any, n_repeats: int | None = None, extra: Any = None
) -> np.ndarray:
    """``LidarLWLR.sample`` before issue 43: each cell's mean drawn on its own (``mu + tau z`` / ``p_out``)."""
    p = self.params_full(poses, map_segments, extra)
    if n_repeats is None:
        return self.sample_from_params(p, rng, pose_uncertainty=True)
    p = {k: v[..., None] for k, v in p.items()}
    return self.sample_from_params(p, rng, p["mu"].shape[:2] + (int(n_repeats),), pose_uncertainty=True)


def draw(model: LidarLWLR, how: str, poses: np.ndarray, segs: np.ndarray, repeats: int, rng: Any) -> np.ndarray:
    """``(P, K, repeats)`` readings [m] (0 = null) at ``poses`` with one of the semantics of the module docstring."""
    if how == "rigid":
        return model.sample(poses, segs, rng, n_repeats=repeats)
    if how == "per_cell":
        return per_cell_sample(model, poses, segs, rng, n_repeats=repeats)
    p = {k: v[..., None] for k, v in model.params_full(poses, segs).items()}
    return model.sample_from_params(p, rng, p["mu"].shape[:2] + (repeats,))


def detection(real: LidarLog, seed: int) -> dict[str, dict[str, float]]:
    """``sensor-envs evaluate detection --real LOG --seed SEED`` (3 leave-poses-out folds, 10 repeats): distances to
    the real precision-recall trajectory with ``sample`` as it is (``rigid``) and as it was (``per_cell``)."""
    from sensor_envs.evaluate.lidar_experiments import log_experiment

    out = {"rigid": log_experiment(real, seed=seed)["distance_to_real"]}
    original = LidarLWLR.sample
    LidarLWLR.sample = per_cell_sample  # type: ignore[method-assign]
    try:
        out["per_cell"] = log_experiment(real, seed=seed)["distance_to_real"]
    finally:
        LidarLWLR.sample = original  # type: ignore[method-assign]
    return out


def statistics(x: np.ndarray, mu: np.ndarray) -> dict[str, Any]:
    """The statistics of the module docstring for readings ``x (P, K, R)`` [m] (0 = null, NaN = missing)."""
    ok_r = ~np.isnan(x) & (x > 0) & (x <= 6.0)
    n = ok_r.sum(2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ok_r, x, 0.0).sum(2) / n
    e = np.where((n >= 2) & np.isfinite(mu), mean - mu, np.nan)
    e = np.where(np.abs(e) < 0.1, e, np.nan)
    out: dict[str, Any] = {}
    for lag in LAGS:
        a, b = e[:, :-lag].ravel(), e[:, lag:].ravel()
        m = np.isfinite(a) & np.isfinite(b)
        out[f"corr_lag{lag}"] = float(np.corrcoef(a[m], b[m])[0, 1])
    ae = np.abs(e[np.isfinite(e)])
    out["median_abs_e_mm"] = float(1e3 * np.median(ae))
    out["q90_abs_e_mm"] = float(1e3 * np.quantile(ae, 0.9))
    dev = np.where(ok_r, x - mean[..., None], np.nan)
    a, b = dev[:, :-1, :].ravel(), dev[:, 1:, :].ravel()
    m = np.isfinite(a) & np.isfinite(b) & (np.abs(a) < 0.05) & (np.abs(b) < 0.05)
    out["within_scan_corr_lag1"] = float(np.corrcoef(a[m], b[m])[0, 1])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real"), help="real data folder or .npz")
    ap.add_argument("--folds", type=int, default=5, help="leave-poses-out folds (default: 5)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the folds and the draws (default: 0)")
    ap.add_argument("--repeats", type=int, default=None, help="repeats sampled per pose (default: the real log's)")
    ap.add_argument("--no-detection", dest="detection", action="store_false", help="skip the detector comparison")
    ap.add_argument("--out-md", default=str(ROOT / "docs" / "results" / "lidar_sampling.md"))
    ap.add_argument("--out-json", default=str(ROOT / "docs" / "results" / "lidar_sampling.json"))
    args = ap.parse_args()
    t0 = time.perf_counter()
    try:  # bad input: one line naming the file, exit 2
        real = load_real_log(args.data)
    except (FileNotFoundError, ValueError) as exc:
        print(f"{exc}: nothing to report", file=sys.stderr)
        raise SystemExit(2) from None
    segs = real.require_map()
    repeats = args.repeats or real.ranges.shape[2]
    r, a = lidar_features(real.poses, real.bearings, segs, 5.0)
    fold = fold_ids(real.n_poses, args.folds, random_state=args.seed)
    rng = np.random.default_rng(args.seed)
    mu = np.full(r.shape, np.nan)
    sims = {k: np.zeros((real.n_poses, real.n_bearings, repeats)) for k in SOURCES[1:]}
    pose_sd = []
    for f in range(args.folds):
        tr, te = fold != f, fold == f
        m = _fit(real.subset(tr))
        pose_sd.append([float(v) for v in m.pose_sd_])
        mu[te] = np.where(np.isfinite(r[te]), m.params_from_features(r[te], a[te])["mu"], np.nan)
        for how in sims:
            sims[how][te] = draw(m, how, real.poses[te], segs, repeats, rng)
        print(f"fold {f + 1}/{args.folds}: pose sd {np.round(pose_sd[-1], 4).tolist()}", flush=True)

    stats = {"real": statistics(real.ranges, mu), **{k: statistics(v, mu) for k, v in sims.items()}}
    keys = [*(f"corr_lag{lag}" for lag in LAGS), "median_abs_e_mm", "q90_abs_e_mm", "within_scan_corr_lag1"]
    lines = [
        "# Sampling semantics of the learned lidar vs the real repeated scans (issue 43)",
        "",
        f"Generated on {time.strftime('%Y-%m-%d', time.gmtime())} (UTC) by "
        f"`python benchmarks/real_lidar_sampling.py {' '.join(sys.argv[1:])}`.",
        "",
        f"Real log `{Path(real.source).name}` (sha256 of ranges `{ranges_sha256(real)[:16]}...`), "
        f"{real.n_poses} poses; {args.folds} leave-poses-out folds (seed {args.seed}), {repeats} repeats per "
        "sampled pose. "
        "`e` = cell mean - "
        "mu of the held-out model, cells with >= 2 in-range readings and |e| < 0.1 m.",
        "",
        "| statistic | " + " | ".join(SOURCES) + " |",
        "|---|" + "---|" * len(SOURCES),
    ]
    for k in keys:
        lines.append(f"| {k} | " + " | ".join(f"{stats[s][k]:.3f}" for s in SOURCES) + " |")
    sd = np.array(pose_sd)
    det = detection(real, args.seed) if args.detection else {}
    lines += [
        "",
        f"Rigid pose error sd fitted per fold (dx, dy [m], dtheta [rad]): mean {np.round(sd.mean(0), 4).tolist()}.",
        "",
    ]
    if det:
        lines += [
            "Line-detector precision-recall, distance to the real trajectory (`sensor-envs evaluate detection --real "
            f"LOG --seed {args.seed}`: 3 leave-poses-out folds, 10 repeats; lower is closer). `model` is "
            "`LidarLWLR.sample`; `model_world` the worlds' draw; each run draws its own noise:",
            "",
            "| run | model (`sample`) | model_world | Gaussian baseline | ideal |",
            "|---|---|---|---|---|",
        ]
        for k, v in det.items():
            lines.append(
                f"| `sample` {k} | {v['model']:.3f} | {v['model_world']:.3f} | {v['baseline']:.3f} | {v['ideal']:.3f} |"
            )
        lines.append("")
    lines += [
        f"Command: `python {' '.join(sys.argv)}` ({time.perf_counter() - t0:.0f} s).",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    Path(args.out_md).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out_md).write_text(text, encoding="utf-8")
    write_json(
        Path(args.out_json),
        {"statistics": stats, "pose_sd_per_fold": pose_sd, "detection_distance_to_real": det, "args": vars(args)},
    )
    print(f"wrote {args.out_md} and {args.out_json}")


if __name__ == "__main__":
    main()
