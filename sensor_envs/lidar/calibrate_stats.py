"""The statistics the lidar rig calibration matches: the real log, its summary and the discrepancy.

:func:`log_summary` summarises a log (null, bias, spread and spurious-return statistics per range, incidence
and bearing; :data:`STATISTICS` lists them with their weights), :func:`discrepancy` compares two summaries; the
search blocks of :func:`sensor_envs.lidar.calibrate.calibrate_rig` are :data:`SEARCH` and :data:`BLOCKS`.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.lidar.log import LidarLog, load_log
from sensor_envs.lidar.lwlr import cell_statistics, lidar_features
from sensor_envs.lidar.rig import NeatoRig

__all__ = [
    "REAL_LOG_NAME",
    "STATISTICS",
    "SEARCH",
    "BLOCKS",
    "load_real_log",
    "ranges_sha256",
    "log_summary",
    "discrepancy",
]


REAL_LOG_NAME = "neato_mar27_train.npz"
"""File looked for when ``calibrate lidar`` is given a folder."""
RANGE_BINS = np.arange(0.0, 4.01, 0.5)
"""Nominal-range bins [m] of the null and sigma statistics."""
RANGE_CENTRES = 0.5 * (RANGE_BINS[:-1] + RANGE_BINS[1:])
"""Centres [m] of :data:`RANGE_BINS` (the knots of the tables fitted per range bin)."""
INCIDENCE_BINS = np.arange(0.0, 1.51, 0.25)
"""Incidence bins [rad] of the null statistic."""
MIN_CELLS = 20
"""Least number of cells for a bin's statistic to count (fewer: undefined)."""

STATISTICS: dict[str, tuple[float, str]] = {
    "p_null_range": (0.05, "null fraction of unblocked hit cells per 0.5 m bin of nominal range (0-4 m)"),
    "p_null_incidence": (0.05, "null fraction of unblocked hit cells per 0.25 rad bin of incidence (0-1.5 rad)"),
    "p_null_bearing": (0.05, "null fraction of unblocked hit cells per bearing (over the poses)"),
    "blocked": (2.0, "number of bearings blocked in one log only (never return: mean null fraction > 0.99)"),
    "mixed_null": (0.02, "share of unblocked hit cells with a null fraction in [0.05, 0.95] (persistence)"),
    "null_arc": (1.0, "mean length [bearings] of the runs of always-null (> 0.95) unblocked hit cells of a pose"),
    "spur_rate": (0.005, "fraction of readings beyond spur_above (spurious far returns)"),
    "spur_cells": (0.005, "share of unblocked cells with at least one spurious reading"),
    "spur_post_distance": (3.0, "mean distance [deg] of the spurious cells to the nearest post"),
    "spur_bearing": (0.05, "share of the poses whose cell at a bearing has spurious readings, per bearing"),
    "spur_cell_frac": (0.1, "mean spurious fraction of the cells with spurious readings"),
    "spur_value": (0.05, "median and standard deviation [m] of the spurious readings"),
    "sigma_range": (0.2, "log of the median standard deviation of clean cells per 0.5 m bin (0-4 m)"),
    "bias_mean": (0.002, "mean over bearings of the per-bearing median of cell mean - nominal range [m]"),
    "bias_sd": (0.002, "standard deviation over bearings of that per-bearing median [m]"),
    "mu_error": (0.002, "mean |cell mean - nominal range| [m] (pose and map error, bias)"),
    "mu_error_quantiles": (
        0.1,
        "log of the 25, 50, 75 and 90 % quantiles of |cell mean - nominal range| [m] of clean cells (its shape)",
    ),
    "pose_error_spread": (
        0.15,
        "log of the 10, 50 and 90 % quantiles over the poses of a pose's median |cell mean - nominal range| [m]",
    ),
    "mu_error_far": (0.005, "share of clean cells with |cell mean - nominal range| > 0.2 m (outlying cells)"),
    "mu_error_far_arc": (1.0, "mean length [bearings] of the runs of such outlying cells of a pose"),
    "spur_range": (0.01, "share of unblocked hit cells with spurious readings per 0.5 m bin of nominal range (0-4 m)"),
}
"""Statistic -> (scale, definition). Weight 1 each; a statistic's term is its mean squared error / scale**2."""

SEARCH: tuple[str, ...] = (
    "logit_null_cell_corr",
    "log_null_arc",
    "bias_mean_mm",
    "log_bias_sd_mm",
    "logit_spur_prone",
    "logit_spur_frac_low",
    "log_pose_sd_xy_cm",
    "log_pose_sd_theta_deg",
    "log_map_sd_cm",
    "log_sigma_scale",
    "logit_out_cell_rate",
    "log_out_cell_arc",
)
"""The coordinates of the Nelder-Mead search (transformed rig parameters)."""
NULL_GRID_CORR = tuple(float(np.log(c / (1 - c))) for c in (0.85, 0.9, 0.94, 0.97, 0.985))
"""Grid of ``logit_null_cell_corr`` the null block starts from (its best point)."""
NULL_GRID_ARC = tuple(float(np.log(a)) for a in (1.0, 3.0))
"""Grid of ``log_null_arc`` the null block starts from."""
_NULL_TERMS = ("p_null_range", "p_null_incidence", "p_null_bearing", "blocked", "mixed_null", "null_arc")
_MU_TERMS = (
    "bias_mean",
    "bias_sd",
    "mu_error",
    "mu_error_quantiles",
    "pose_error_spread",
    "mu_error_far",
    "mu_error_far_arc",
    "sigma_range",
)
_SPUR_TERMS = ("spur_rate", "spur_cells", "spur_post_distance", "spur_bearing", "spur_cell_frac", "spur_range")
BLOCKS: tuple[tuple[tuple[int, ...], float, tuple[str, ...] | None], ...] = (
    ((10, 11), 0.1, _MU_TERMS),  # outlying cells
    ((2, 3, 6, 7, 8, 9), 0.25, _MU_TERMS),  # bias, pose and map error, sigma scale
    ((0, 1), 0.3, _NULL_TERMS),  # nulls: persistence, arcs
    ((4, 5), 0.1, _SPUR_TERMS),  # spurious returns: prone share, fraction
    (tuple(range(2, 12)), 0.25, None),  # all but the null persistence together (the total D)
)
"""Blocks of :data:`SEARCH` coordinates searched in turn, with their shares of the evaluations and the terms of
``D`` each block minimises (``None``: the total). A block's terms are those its coordinates act on: the other
terms hardly change but add noise (which cells are clean moves with the nulls), which stalls the search. Each
block starts where the previous one ended; the result is the point of least total ``D`` seen. The null
persistence (``null_cell_corr``, ``null_arc``) is left out of the last block: against the total its moves
mostly trade the noise of the pose-error terms."""


# ----------------------------------------------------------------------------------------------- data
def load_real_log(path: str | Path) -> LidarLog:
    """The real static-pose log: ``path`` is the ``.npz`` or a folder holding :data:`REAL_LOG_NAME`.

    Raises:
        FileNotFoundError: when the file or folder is absent.
        ValueError: (``LidarLogError``) when it is not a static-pose lidar log with repeats and a map.
    """
    p = Path(path)
    if p.is_dir():
        p = p / REAL_LOG_NAME
    if not p.exists():
        raise FileNotFoundError(f"{p}: real data not found (give the .npz or the folder holding {REAL_LOG_NAME})")
    if p.suffix != ".npz":
        raise InputError(f"{p}: not a static-pose lidar log (.npz with ranges of shape poses x bearings x repeats)")
    log = load_log(p)
    if log.ranges.shape[2] < 2:
        raise InputError(
            f"{p}: field 'ranges' has one reading per pose and bearing; calibration needs repeated readings"
        )
    if log.map_segments is None:
        raise InputError(f"{p}: field 'map_segments' is missing; calibration needs the log's map")
    k = log.n_bearings
    if not np.allclose(log.bearings, np.deg2rad(np.arange(k) * 360.0 / k), atol=1e-6):
        raise InputError(f"{p}: field 'bearings' is not the rig's regular full circle (j * 360 / K degrees)")
    return log


def ranges_sha256(log: LidarLog) -> str:
    """sha256 of the log's ranges array as loaded (float64, C order): identifies the data, stores none of it."""
    return hashlib.sha256(np.ascontiguousarray(log.ranges).tobytes()).hexdigest()


# ------------------------------------------------------------------------------------------ statistics
def _binned_mean(values: NDArray[np.float64], x: NDArray[np.float64], edges: NDArray[np.float64]) -> list[float]:
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        s = (x >= lo) & (x < hi)
        out.append(float(values[s].mean()) if s.sum() >= MIN_CELLS else float("nan"))
    return out


def _log_quantiles(values: NDArray[np.float64], q: tuple[float, ...], least: int) -> list[float]:
    """Logs of the quantiles ``q`` of positive ``values`` (NaN each when fewer than ``least`` values)."""
    if values.size < least:
        return [float("nan")] * len(q)
    return [float(v) for v in np.log(np.maximum(np.quantile(values, q), 1e-6))]


def _mean_run(mask: NDArray[np.bool_]) -> float:
    """Mean length of the runs of True along the last axis (runs stop at the ends)."""
    m = np.pad(mask.astype(np.int8), [(0, 0)] * (mask.ndim - 1) + [(1, 1)])
    d = np.diff(m, axis=-1)
    n = int((d == 1).sum())
    return float(mask.sum() / n) if n else float("nan")


def log_summary(log: LidarLog, max_range: float = 5.0, spur_above: float = 6.0) -> dict[str, Any]:
    """The calibration statistics of a static-pose log (definitions in :data:`STATISTICS`).

    Computed identically on real and simulated logs, at the log's own (approximate) poses and map.
    """
    r, a = lidar_features(log.poses, log.bearings, log.require_map(), max_range)
    st = cell_statistics(log, spur_above, split_spurious=True)
    has = st["n"] > 0
    pn = st["p_null"]
    with np.errstate(invalid="ignore"):
        blocked = np.nanmean(np.where(has, pn, np.nan), axis=0) > 0.99
    hit = np.isfinite(r) & ~blocked[None] & has
    x = log.ranges
    valid = ~np.isnan(x)
    spur = valid & (x > spur_above)
    sp_cells = (st["p_spur"] > 0) & ~blocked[None] & has
    dist = NeatoRig(n_bearings=log.n_bearings, blocked=tuple(int(i) for i in np.flatnonzero(blocked))).post_distance()
    ok = (st["n_ok"] >= 2) & ~blocked[None]
    clean = ok & (st["p_spur"] == 0) & np.isfinite(r)
    with np.errstate(invalid="ignore"):
        per_bearing = np.where(hit.any(0), np.where(hit, pn, 0.0).sum(0) / np.maximum(hit.sum(0), 1), np.nan)
        dev = np.where(ok & np.isfinite(r), st["mean"] - r, np.nan)
        okb = np.isfinite(dev).any(0)
        b = np.array([np.median(dev[np.isfinite(dev[:, k]), k]) for k in np.flatnonzero(okb)])
    sig = []
    for lo, hi in zip(RANGE_BINS[:-1], RANGE_BINS[1:], strict=True):
        s = clean & (r >= lo) & (r < hi)
        med = float(np.median(st["std"][s])) if s.sum() >= MIN_CELLS else float("nan")
        sig.append(float(np.log(med)) if med > 0 else float("nan"))  # 0: quantized readings, no spread measured
    sv = x[spur]
    cdev = np.abs(np.where(clean, st["mean"] - r, np.nan))
    pose_dev = np.array([np.median(c[np.isfinite(c)]) for c in cdev if np.isfinite(c).any()])
    far = np.nan_to_num(cdev) > 0.2
    return {
        "p_null_range": _binned_mean(pn[hit], r[hit], RANGE_BINS),
        "p_null_incidence": _binned_mean(pn[hit], a[hit], INCIDENCE_BINS),
        "p_null_bearing": per_bearing.tolist(),
        "blocked": [int(i) for i in np.flatnonzero(blocked)],
        "mixed_null": float(((pn[hit] >= 0.05) & (pn[hit] <= 0.95)).mean()),
        "null_arc": _mean_run((pn > 0.95) & hit),
        "spur_rate": float(spur.sum() / max(valid.sum(), 1)),
        "spur_cells": float(sp_cells.sum() / max((has & ~blocked[None]).sum(), 1)),
        "spur_post_distance": float(np.broadcast_to(dist, pn.shape)[sp_cells].mean()) if sp_cells.any() else None,
        "spur_cell_frac": float(st["p_spur"][sp_cells].mean()) if sp_cells.any() else None,
        "spur_bearing": np.where(blocked, np.nan, sp_cells.mean(0)).tolist(),
        "spur_value": [float(np.median(sv)), float(np.std(sv))] if sv.size >= 2 else [None, None],
        "sigma_range": sig,
        "bias_mean": float(b.mean()) if b.size else None,
        "bias_sd": float(b.std()) if b.size else None,
        "mu_error": float(np.nanmean(np.abs(dev))) if okb.any() else None,
        "mu_error_quantiles": _log_quantiles(cdev[np.isfinite(cdev)], (0.25, 0.5, 0.75, 0.9), MIN_CELLS),
        "pose_error_spread": _log_quantiles(pose_dev, (0.1, 0.5, 0.9), 3),
        "mu_error_far": float(far.sum() / max(int(np.isfinite(cdev).sum()), 1)),
        "mu_error_far_arc": _mean_run(far),
        "spur_range": _binned_mean((st["p_spur"][hit] > 0).astype(np.float64), r[hit], RANGE_BINS),
        "n_poses": log.n_poses,
    }


def discrepancy(sim: dict[str, Any], real: dict[str, Any]) -> dict[str, float]:
    """Per-statistic terms of the discrepancy ``D`` (module docstring) and their sum under ``"total"``."""
    out: dict[str, float] = {}
    for name, (scale, _) in STATISTICS.items():
        if name == "blocked":
            d = float(len(set(sim[name]) ^ set(real[name]))) / scale
            out[name] = d * d
            continue
        s = np.array(np.atleast_1d(sim[name]), dtype=np.float64)
        t = np.array(np.atleast_1d(real[name]), dtype=np.float64)
        both = np.isfinite(s) & np.isfinite(t)
        out[name] = float(np.mean(((s[both] - t[both]) / scale) ** 2)) if both.any() else 0.0
    out["total"] = float(sum(out.values()))
    return out
