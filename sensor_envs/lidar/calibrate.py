"""Simulation-based calibration of the reference Neato rig to a real static-pose log.

The rig (:class:`~sensor_envs.lidar.rig.NeatoRig`) records at the real log's poses on the real log's
map; the same summary statistics (:func:`log_summary`) are computed on the real log and on the rig's
log, and a weighted discrepancy between them (:func:`discrepancy`) is minimised over the rig's
parameters with Nelder-Mead (``scipy.optimize``). Every simulation uses the same seed (common random
numbers: the rig draws a fixed number of random values whatever its parameters), so the objective
changes smoothly with the parameters and a rerun with the same seed gives the same rig.

The discrepancy (stated in every calibrated rig file's card) is

    D = sum_s w_s * mean_i ((stat_sim[s, i] - stat_real[s, i]) / scale_s) ** 2

over the statistics ``s`` of :data:`STATISTICS` (entries undefined in either log are skipped); all
weights ``w_s`` are 1, so ``D`` counts squared errors in units of each statistic's scale.

Parameters set directly from the real log (statistics, not fitted by simulation): the blocked
bearings (never returning: mean null fraction > 0.99 over the poses), the spurious value's median and
spread, the shape of sigma versus range (median cell standard deviation per 0.5 m bin), the per-bearing
spurious weights and the spurious factor per range (the real spurious cells are all within 1 m), the
null law (:func:`fit_null_law`: a logistic regression of the cells' null fractions on per-bearing
intercepts, per-bearing range slopes (their ridge chosen by leave-poses-out CV, :func:`choose_slope_ridge`) and
piecewise-linear tables of range and incidence; the real null rate is flat up to 0.9 rad of incidence,
then steep, and levels off beyond 2.5 m, which the former linear logit could not follow),
and the range bias shared by the bearings (:func:`fit_bias_law`: tables of the median cell deviation
versus range and incidence; the real readings fall short by 0.03-0.17 m beyond 2.5 m). The
Nelder-Mead search then runs over the remaining parameters (:data:`SEARCH`), per block of coordinates
on the terms of ``D`` they act on (:data:`BLOCKS`), and after it each sigma knot is rescaled until the
simulated sigma statistic meets the real one (:func:`refine_sigma`). Last, the spurious-prone law the search
used (per-bearing weights times a factor per 0.5 m range bin) is replaced by the near-cell law
(:func:`with_spur_near_law`): only cells nearer than a cut are prone, each bearing with its own share of
prone near cells, cut and shrinkage chosen by leave-poses-out CV (:func:`fit_spur_near_law`). The real
unit's spurious cells are near (all but four of 329 within 0.7 m) and, at a bearing, nearly all or none of its near
cells; the per-bin law spread them over every bearing's cells up to 1.25 m, so a model fitted on the rig
predicted spurious returns where the real unit has none (MAE p_spur +26 % against a model fitted on the
real cells). ``--spurious-only RIG`` applies that last step alone to an existing rig file.

Units: metres, radians (bearings and post distances in the statistics: degrees).
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from sensor_envs.inputs import InputError
from sensor_envs.lidar.log import LidarLog, load_log
from sensor_envs.lidar.lwlr import cell_statistics, lidar_features
from sensor_envs.lidar.rig import NULL_SLOPE_CENTRE, NeatoRig
from sensor_envs.rng import fold_ids

__all__ = [
    "STATISTICS",
    "SEARCH",
    "REAL_LOG_NAME",
    "log_summary",
    "discrepancy",
    "calibrate_rig",
    "load_real_log",
    "bearing_profile",
    "fit_null_law",
    "fit_spur_near_law",
    "respurious_rig",
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
        sig.append(float(np.log(np.median(st["std"][s]))) if s.sum() >= MIN_CELLS else float("nan"))
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


# --------------------------------------------------------------------------------------- the search
def _logistic(z: NDArray[np.float64]) -> NDArray[np.float64]:
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def profile_bearing_intercepts(
    lin: NDArray[np.float64],
    hit: NDArray[np.bool_],
    target: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Per-bearing intercepts ``(K,)`` of logit ``p_null`` matching the target null rates.

    Solves ``mean_p logistic(b_k + lin_pk) = target_k`` over the hit cells ``hit (P, K)`` of each bearing by
    bisection on ``[-20, 20]``, ``lin (P, K)`` the range and incidence part of the logit
    (:meth:`NeatoRig.null_shape`); bearings without hit cells or target get 0.
    """
    lin = np.where(hit, lin, 0.0)
    cnt = hit.sum(0)
    use = (cnt > 0) & np.isfinite(target)
    y = np.clip(np.nan_to_num(target), 1e-3, 1 - 1e-3)
    lo, hi = np.full(hit.shape[1], -20.0), np.full(hit.shape[1], 20.0)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        rate = np.where(hit, _logistic(mid[None] + lin), 0.0).sum(0) / np.maximum(cnt, 1)
        up = rate < y
        lo, hi = np.where(up, mid, lo), np.where(up, hi, mid)
    return np.where(use, 0.5 * (lo + hi), 0.0)


NULL_RANGE_KNOTS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 3.5, 4.0)
"""Knots [m] of the rig's table of logit ``p_null`` versus nominal range."""
NULL_INCIDENCE_KNOTS = (0.0, 0.3, 0.6, 0.9, 1.05, 1.2, 1.35, 1.5, 1.6)
"""Knots [rad] of the rig's table of logit ``p_null`` versus incidence."""
NULL_SMOOTHING = 2.0
"""Penalty on the squared second differences of the two tables [logit^2], against the cells' cross-entropy."""
NULL_SLOPE_RIDGES = (float("inf"), 0.1, 0.01, 0.003)
"""Candidate ridges on the per-bearing range slopes of logit ``p_null`` (``inf`` = no slopes), one chosen per log
by leave-poses-out CV (:func:`choose_slope_ridge`). On the real Neato log: held-out MAE p_null 0.117 without
slopes, 0.105 at 0.1, 0.099 at 0.01, 0.098 at 0.003 (0.097 at 0.001, slower to fit and not kept;
``docs/history/scripts/real_lidar_null_law_cv.py``)."""
NULL_SLOPE_CV_FOLDS = 5
"""Leave-poses-out folds of the ridge choice."""
NULL_SLOPE_CV_TOLERANCE = 0.01
"""The strongest ridge whose held-out MAE is within this fraction of the best one is chosen."""


def _hat_basis(v: NDArray[np.float64], knots: tuple[float, ...]) -> NDArray[np.float64]:
    """``(N, len(knots))`` piecewise-linear interpolation weights of ``v`` (constant beyond the end knots)."""
    eye = np.eye(len(knots))
    return np.column_stack([np.interp(v, knots, eye[j]) for j in range(len(knots))])


def fit_null_law(
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    hit: NDArray[np.bool_],
    p_null: NDArray[np.float64],
    slope_ridge: float | None = None,
) -> dict[str, Any]:
    """Fit logit ``p_null = c0 + b_k + s_k (r - NULL_SLOPE_CENTRE) + f(r) + g(alpha)`` to a log's cell null fractions.

    A logistic regression (each hit cell weight 1, its null fraction the response, clipped to [0.001, 0.999]
    so that a bearing never or always null in few cells is not certain) with per-bearing intercepts ``b_k``,
    per-bearing range slopes ``s_k`` (ridge ``slope_ridge`` on them; ``None`` = chosen among
    :data:`NULL_SLOPE_RIDGES` by :func:`choose_slope_ridge`, ``inf`` = no slopes) and piecewise-linear tables
    ``f`` (:data:`NULL_RANGE_KNOTS`) and ``g``
    (:data:`NULL_INCIDENCE_KNOTS`), ``f`` and ``g`` 0 at their first knot, smoothed by
    :data:`NULL_SMOOTHING`; solved by L-BFGS-B (values within +-20). Statistics of the log, set directly.

    Args:
        r: ``(P, K)`` nominal range [m] at the log's poses.
        a: ``(P, K)`` incidence [rad] there.
        hit: ``(P, K)`` the cells used (unblocked, ray hits the map, readings present).
        p_null: ``(P, K)`` the cells' null fractions.
        slope_ridge: penalty on the squared per-bearing slopes [logit^2 m^2 per unit cross-entropy].

    Returns:
        ``c0`` (median intercept), ``offsets (K,)`` (``b_k - c0``, rounded to 0.01; 0 at unused bearings),
        ``range_slopes (K,)`` (rounded to 0.001; 0 at unused bearings; empty without slopes), ``slope_ridge``
        (the ridge used) and ``slope_cv`` (the held-out MAE per candidate ridge when it was chosen), the tables as
        rig parameters (``null_range_knots``, ``null_range_logit``, ``null_incidence_knots``,
        ``null_incidence_logit``; rounded to 0.001).
    """
    cv: dict[str, float] = {}
    if slope_ridge is None:
        slope_ridge, cv = choose_slope_ridge(r, a, hit, p_null)
    ridge = float(slope_ridge)
    k_idx = np.broadcast_to(np.arange(hit.shape[1]), hit.shape)[hit]
    y = np.clip(p_null[hit], 1e-3, 1 - 1e-3)  # as the per-bearing profile: no bearing is made certain
    br, ba = _hat_basis(r[hit], NULL_RANGE_KNOTS)[:, 1:], _hat_basis(a[hit], NULL_INCIDENCE_KNOTS)[:, 1:]
    rc = r[hit] - NULL_SLOPE_CENTRE
    nk, nr, na = hit.shape[1], br.shape[1], ba.shape[1]
    ns = nk if np.isfinite(ridge) else 0
    used = np.bincount(k_idx, minlength=nk) > 0
    d2r, d2a = np.diff(np.eye(nr + 1), 2, axis=0), np.diff(np.eye(na + 1), 2, axis=0)

    n_used = max(int(used.sum()), 1)

    def zero_sum(v: NDArray[np.float64]) -> NDArray[np.float64]:
        """``v`` minus its mean over the used bearings there (the slopes' free part; the range table has the trend)."""
        return v - float(v @ used) / n_used * used if ns else v

    def loss(theta: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        b, s = theta[:nk], zero_sum(theta[nk : nk + ns])
        f, g = theta[nk + ns : nk + ns + nr], theta[nk + ns + nr :]
        z = b[k_idx] + br @ f + ba @ g
        if ns:
            z = z + s[k_idx] * rc
        ll = np.logaddexp(0.0, z) - y * z  # cross-entropy of logistic(z) against y
        e = _logistic(z) - y
        fr, ga = d2r @ np.r_[0.0, f], d2a @ np.r_[0.0, g]
        pen = NULL_SMOOTHING * (fr @ fr + ga @ ga) + (ridge * (s @ s) if ns else 0.0)
        grad = np.r_[
            np.bincount(k_idx, e, minlength=nk),
            zero_sum(np.bincount(k_idx, e * rc, minlength=nk) + 2 * ridge * s) if ns else np.zeros(0),
            br.T @ e + 2 * NULL_SMOOTHING * (d2r.T @ fr)[1:],
            ba.T @ e + 2 * NULL_SMOOTHING * (d2a.T @ ga)[1:],
        ]
        return float(ll.sum() + pen), grad

    rate = np.bincount(k_idx, y, minlength=nk) / np.maximum(np.bincount(k_idx, minlength=nk), 1)
    q = np.clip(rate, 1e-3, 1 - 1e-3)
    theta0 = np.r_[np.log(q / (1 - q)), np.zeros(ns + nr + na)]
    with threadpool_limits(1):  # small dense steps: BLAS threads only add overhead (25x on the shared 2 cores)
        res = minimize(loss, theta0, jac=True, method="L-BFGS-B", bounds=[(-20.0, 20.0)] * theta0.size)
    c0, offsets = _intercept_and_offsets(res.x[:nk], used)
    slopes = np.where(used, np.round(zero_sum(res.x[nk : nk + ns]), 3), 0.0) if ns else np.zeros(0)
    t = res.x[nk + ns :]
    return {
        "c0": round(c0, 4),
        "offsets": offsets,
        "range_slopes": tuple(float(v) for v in slopes),
        "slope_ridge": ridge,
        "slope_cv": cv,
        "null_range_knots": NULL_RANGE_KNOTS,
        "null_range_logit": tuple(float(v) for v in np.asarray(np.round(np.r_[0.0, t[:nr]], 3))),
        "null_incidence_knots": NULL_INCIDENCE_KNOTS,
        "null_incidence_logit": tuple(float(v) for v in np.asarray(np.round(np.r_[0.0, t[nr:]], 3))),
    }


def null_law_rig(law: dict[str, Any], n_bearings: int) -> NeatoRig:
    """A rig holding only a :func:`fit_null_law` law (no blocked bearings): its ``p_null`` is the law's probability."""
    return NeatoRig(n_bearings=n_bearings, blocked=(), **_law_as_rig_params(law))


def _law_as_rig_params(law: dict[str, Any]) -> dict[str, Any]:
    """The rig parameters of a :func:`fit_null_law` law (linear slopes 0: the tables carry the shape)."""
    return {
        "null_logit": (law["c0"], 0.0, 0.0),
        "null_bearing_logit": law["offsets"],
        "null_bearing_range_slope": law["range_slopes"],
        **{k: law[k] for k in ("null_range_knots", "null_range_logit", "null_incidence_knots", "null_incidence_logit")},
    }


def choose_slope_ridge(
    r: NDArray[np.float64], a: NDArray[np.float64], hit: NDArray[np.bool_], p_null: NDArray[np.float64]
) -> tuple[float, dict[str, float]]:
    """The ridge of the per-bearing range slopes, by leave-poses-out CV of :func:`fit_null_law` on a log's cells.

    For each candidate of :data:`NULL_SLOPE_RIDGES` (``inf``: no slopes), the law is fitted on the cells of
    all but one of :data:`NULL_SLOPE_CV_FOLDS` folds of poses (:func:`~sensor_envs.rng.fold_ids`, seed 0) and its
    ``p_null`` compared with the held-out cells' null fractions (mean absolute error over the folds' hit
    cells). Returns the strongest ridge within :data:`NULL_SLOPE_CV_TOLERANCE` (relative) of the lowest MAE, and
    the MAE per candidate (``"inf"``, ``"0.1"``, ...). With fewer than 2 poses with hit cells: ``inf``.
    """
    poses = np.flatnonzero(hit.any(1))
    if poses.size < 2:
        return float("inf"), {}
    fold = np.full(hit.shape[0], -1)
    fold[poses] = fold_ids(poses.size, min(NULL_SLOPE_CV_FOLDS, poses.size), random_state=0)
    mae: dict[float, float] = {}
    for ridge in NULL_SLOPE_RIDGES:
        err = []
        for f in range(int(fold.max()) + 1):
            te = fold == f
            law = fit_null_law(r, a, hit & ~te[:, None], p_null, slope_ridge=ridge)
            err.append(np.abs(null_law_rig(law, hit.shape[1]).p_null(r[te], a[te]) - p_null[te])[hit[te]])
        mae[ridge] = float(np.concatenate(err).mean())
    best = min(mae.values())
    pick = max(k for k, v in mae.items() if v <= best * (1 + NULL_SLOPE_CV_TOLERANCE))
    return pick, {f"{k:g}": v for k, v in mae.items()}


def _null_law_params(
    r: NDArray[np.float64], a: NDArray[np.float64], hit: NDArray[np.bool_], stats_pn: Any
) -> dict[str, Any]:
    """Rig parameters of the null law fitted by :func:`fit_null_law` to the cells ``hit``."""
    return _law_as_rig_params(fit_null_law(r, a, hit, stats_pn))


BIAS_RANGE_KNOTS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
"""Knots [m] of the rig's range bias table."""
BIAS_INCIDENCE_KNOTS = (0.0, 0.5, 0.9, 1.1, 1.3)
"""Knots [rad] of the rig's incidence bias table."""
BIAS_OUTLYING = 0.2
"""Cells whose mean is farther than this [m] from the nominal range are left out of the bias tables."""


def fit_bias_law(r: NDArray[np.float64], a: NDArray[np.float64], dev: NDArray[np.float64]) -> dict[str, Any]:
    """Range and incidence bias tables [m] shared by all bearings, from cell deviations ``dev = mean - nominal``.

    Least absolute deviations (iteratively reweighted least squares, 30 steps) of the finite cells with
    ``|dev| <= BIAS_OUTLYING`` on piecewise-linear bases at :data:`BIAS_RANGE_KNOTS` and
    :data:`BIAS_INCIDENCE_KNOTS` (the incidence table 0 at its first knot), with a small ridge on the
    second differences; the range table is then shifted so the tables' sum has median 0 over the cells
    (the level is the rig's ``bias_mean``). Values rounded to 0.1 mm.
    """
    ok = np.isfinite(dev) & np.isfinite(r) & (np.abs(np.nan_to_num(dev)) <= BIAS_OUTLYING)
    if ok.sum() < 2 * (len(BIAS_RANGE_KNOTS) + len(BIAS_INCIDENCE_KNOTS)):
        return {"bias_range_knots": (), "bias_range": (), "bias_incidence_knots": (), "bias_incidence": ()}
    x = np.column_stack(
        [_hat_basis(r[ok], BIAS_RANGE_KNOTS), _hat_basis(np.nan_to_num(a[ok]), BIAS_INCIDENCE_KNOTS)[:, 1:]]
    )
    y = dev[ok]
    nr = len(BIAS_RANGE_KNOTS)
    pen = np.zeros((0, x.shape[1]))
    for lo, n in ((0, nr), (nr, x.shape[1] - nr)):
        d2 = np.zeros((max(n - 2, 0), x.shape[1]))
        d2[:, lo : lo + n] = np.diff(np.eye(n), 2, axis=0)
        pen = np.vstack([pen, d2])
    w = np.ones(y.size)
    for _ in range(30):
        sw = np.sqrt(w)
        beta = np.linalg.lstsq(np.vstack([x * sw[:, None], 0.1 * pen]), np.r_[y * sw, np.zeros(len(pen))], rcond=None)[
            0
        ]
        w = 1.0 / np.maximum(np.abs(y - x @ beta), 1e-4)
    beta[:nr] -= np.median(x @ beta)
    return {
        "bias_range_knots": BIAS_RANGE_KNOTS,
        "bias_range": tuple(float(v) for v in np.round(beta[:nr], 4)),
        "bias_incidence_knots": BIAS_INCIDENCE_KNOTS,
        "bias_incidence": tuple(float(v) for v in np.asarray(np.round(np.r_[0.0, beta[nr:]], 4))),
    }


def _spur_range(stats: dict[str, Any]) -> dict[str, Any]:
    """Spurious-prone factor per range (mean 1 over the hit cells) from a log's ``spur_range`` and ``spur_cells``."""
    share = np.asarray(stats["spur_range"], dtype=np.float64)
    overall = stats["spur_cells"]
    ok = np.isfinite(share)
    if not ok.any() or not overall:
        return {"spur_range_knots": (), "spur_range_weight": ()}
    return {
        "spur_range_knots": tuple(float(v) for v in RANGE_CENTRES[ok]),
        "spur_range_weight": tuple(float(f"{v:.3g}") for v in share[ok] / overall),
    }


def _sigma_knots(real: dict[str, Any]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Knots of sigma versus range [m] from the real median cell standard deviation per range bin."""
    s = np.exp(np.asarray(real["sigma_range"], dtype=np.float64))
    ok = np.isfinite(s)
    if not ok.any():
        return NeatoRig.sigma_knots_r, NeatoRig.sigma_knots
    kr = np.r_[0.0, RANGE_CENTRES[ok], max(4.0, RANGE_CENTRES[ok][-1] + 0.25)]
    kv = np.r_[s[ok][0], s[ok], s[ok][-1]]
    return tuple(float(v) for v in kr), tuple(float(f"{v:.3g}") for v in kv)


def _null_offsets(
    lin: NDArray[np.float64], hit: NDArray[np.bool_], target: NDArray[np.float64]
) -> tuple[float, tuple[float, ...]]:
    """Intercept and per-bearing offsets (rounded to 0.01) of logit ``p_null`` matching per-bearing null rates."""
    b = profile_bearing_intercepts(lin, hit, target)
    return _intercept_and_offsets(b, hit.any(0) & np.isfinite(target))


def _intercept_and_offsets(b: NDArray[np.float64], used: NDArray[np.bool_]) -> tuple[float, tuple[float, ...]]:
    """Per-bearing logit intercepts ``b (K,)`` as one intercept and offsets from it.

    The intercept is their median over the ``used`` bearings (-4 when none); the offsets are rounded to 0.01,
    0 at unused bearings.
    """
    c0 = float(np.median(b[used])) if used.any() else -4.0
    return c0, tuple(float(v) for v in np.where(used, np.round(b - c0, 2), 0.0))


SPUR_WEIGHT_PRIOR = 0.1
"""Pseudo-count of spurious cells per bearing added before normalising the per-bearing weights."""


def _spur_weights(stats: dict[str, Any]) -> tuple[float, ...]:
    """Per-bearing proneness to spurious returns (mean 1 over unblocked bearings) from a log's statistics."""
    share = np.asarray(stats["spur_bearing"], dtype=np.float64)
    ok = np.isfinite(share)
    if not ok.any():
        return ()
    w = np.where(ok, share + SPUR_WEIGHT_PRIOR / max(int(stats["n_poses"]), 1), 0.0)
    w = w / w[ok].mean()
    return tuple(float(f"{v:.3g}") for v in w)


SPUR_NEAR_CUTS = (0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.9, 1.0, 1.25, 1.5, 2.0)
"""Candidate near-range cuts [m] of :func:`fit_spur_near_law`."""
SPUR_NEAR_PRIORS = (0.25, 0.5, 1.0, 2.0, 5.0)
"""Candidate pseudo-counts of near cells at the pooled rate added to each bearing's (:func:`fit_spur_near_law`)."""
SPUR_PRONE_CELL = 0.0
"""A cell counts as spurious-prone when more than this share of its readings is spurious (0: any, as in the
statistics ``spur_cells`` / ``spur_bearing``; the leave-poses-out MSE is the same at 0.5, the discrepancy
``D`` of the shipped rig's recording 25.3 at 0 vs 34.5 at 0.5, through the share of spurious cells)."""
SPUR_NEAR_CV_FOLDS = 5
"""Leave-poses-out folds of :func:`fit_spur_near_law`."""


def _near_rates(
    r: NDArray[np.float64], prone: NDArray[np.bool_], used: NDArray[np.bool_], cut: float, prior: float
) -> tuple[NDArray[np.float64], float]:
    """Per-bearing share of prone cells among the used cells nearer than ``cut`` [m], shrunk to the pooled share.

    Returns ``(rate (K,), pooled)``; a bearing without near cells takes the pooled share.
    """
    near = used & (r < cut)
    n, k = near.sum(0).astype(np.float64), (near & prone).sum(0).astype(np.float64)
    pooled = float(k.sum() / n.sum()) if n.sum() else 0.0
    return (k + prior * pooled) / np.maximum(n + prior, 1e-12), pooled


def fit_spur_near_law(
    r: NDArray[np.float64], p_spur: NDArray[np.float64], used: NDArray[np.bool_]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Spurious-prone law "near cells, per-bearing rate": its rig parameters, cut and shrinkage chosen by CV.

    A cell (pose, bearing) is prone when more than :data:`SPUR_PRONE_CELL` of its readings are spurious. The
    law: a cell nearer than ``cut`` [m] (nominal range) is prone with its bearing's share of prone cells among
    the near cells, shrunk toward the pooled share by ``prior`` pseudo-cells; farther cells never are. Its
    prediction of a cell's spurious fraction is that rate times the mean fraction of the prone cells. ``cut``
    (:data:`SPUR_NEAR_CUTS`) and ``prior`` (:data:`SPUR_NEAR_PRIORS`) minimise the mean squared error of that
    prediction on held-out poses (:data:`SPUR_NEAR_CV_FOLDS` folds, :func:`~sensor_envs.rng.fold_ids` seed 0;
    a proper score: the mean absolute error would favour predicting no spurious return at all).

    Args:
        r: ``(P, K)`` nominal range of each cell [m] (``inf``: no hit).
        p_spur: ``(P, K)`` spurious fraction of each cell.
        used: ``(P, K)`` cells that count (hit, unblocked, with readings).

    Returns:
        ``(params, info)``: the rig parameters (``spur_near_range``, ``spur_bearing_weight`` = rate / pooled,
        ``spur_prone`` = pooled share, no range table) and the choice (cut, prior, CV MSE per candidate).
    """
    ps = np.nan_to_num(p_spur)
    prone = ps > SPUR_PRONE_CELL
    poses = np.flatnonzero(used.any(1))
    fold = np.full(used.shape[0], -1)
    fold[poses] = fold_ids(poses.size, min(SPUR_NEAR_CV_FOLDS, max(poses.size, 1)), random_state=0)
    splits = []  # per fold: training cells, held-out cells, mean spurious fraction of the training prone cells
    for f in range(int(fold.max()) + 1):
        tr, te = used & (fold != f)[:, None], used & (fold == f)[:, None]
        splits.append((tr, te, float(ps[tr & prone].mean()) if (tr & prone).any() else 0.0))
    mse: dict[tuple[float, float], float] = {}
    for cut in SPUR_NEAR_CUTS:
        for prior in SPUR_NEAR_PRIORS:
            err = [
                (np.where(r < cut, _near_rates(r, prone, tr, cut, prior)[0][None] * frac, 0.0) - ps)[te]
                for tr, te, frac in splits
            ]
            e = np.concatenate(err) if err else np.zeros(0)
            mse[(cut, prior)] = float(np.mean(e**2)) if e.size else 0.0
    cut, prior = min(mse, key=lambda c: (mse[c], -c[1]))
    rate, pooled = _near_rates(r, prone, used, cut, prior)
    w = rate / pooled if pooled > 0 else np.ones_like(rate)
    params = {
        "spur_near_range": cut,
        "spur_range_knots": (),
        "spur_range_weight": (),
        "spur_prone": round(pooled, 5),
        "spur_bearing_weight": tuple(float(f"{v:.4g}") for v in w),
    }
    info = {
        "rule": "cut and prior of least leave-poses-out MSE of the cells' spurious fractions",
        "cut_m": cut,
        "prior_cells": prior,
        "pooled_rate": pooled,
        "cv_mse": {f"{c:g} m, prior {p:g}": v for (c, p), v in mse.items()},
    }
    return params, info


def with_spur_near_law(rig: NeatoRig, log: LidarLog) -> tuple[NeatoRig, dict[str, Any]]:
    """``rig`` with its spurious-prone law replaced by the near-cell law of ``log`` (:func:`fit_spur_near_law`).

    The last step of :func:`calibrate_rig`: the search runs with the per-range-bin law (its ``spur_frac``, the
    share of a prone cell's readings, is kept); the near law's prone probabilities are statistics of the log's
    cells (``spur_prone`` = the pooled share of prone near cells, the weights = per-bearing shares over it), so
    the other parameters stay those of the search. Returns the rig and the law's choice (for the card).
    """
    r, _ = lidar_features(log.poses, log.bearings, log.require_map(), rig.max_range)
    st = cell_statistics(log, 6.0, split_spurious=True)
    used = np.isfinite(r) & ~rig.blocked_mask()[None] & (st["n"] > 0)
    params, info = fit_spur_near_law(r, st["p_spur"], used)
    return dataclasses.replace(rig, **params), info


def bearing_profile(rig: NeatoRig, log: LidarLog) -> NeatoRig:
    """``rig`` with its effects that are statistics of a log re-derived from ``log``.

    Those are the per-bearing null offsets and spurious weights, and, for a rig with null tables (the
    calibration's law), the whole null law (:func:`fit_null_law`) and the spurious factor per range. Keeps
    every other parameter (persistence, noise, pose error...). Used to measure the calibration honestly by
    leave-poses-out folds: these effects are statistics of the poses they were computed on.
    """
    stats = log_summary(log, rig.max_range)
    r, a = lidar_features(log.poses, log.bearings, log.require_map(), rig.max_range)
    blocked = np.zeros(log.n_bearings, dtype=bool)
    blocked[stats["blocked"]] = True
    hit = np.isfinite(r) & ~blocked[None]
    st = cell_statistics(log, 6.0, split_spurious=True)
    extra: dict[str, Any] = {}
    if rig.null_range_knots or rig.null_incidence_knots:
        extra = _null_law_params(r, a, hit & (st["n"] > 0), st["p_null"])
        if rig.spur_range_knots:
            extra.update(_spur_range(stats))
    else:
        target = np.asarray(stats["p_null_bearing"], dtype=np.float64)
        c0, off = _null_offsets(rig.null_shape(r, a), hit, target)
        extra = {"null_logit": (round(c0, 4), rig.null_logit[1], rig.null_logit[2]), "null_bearing_logit": off}
    if rig.spur_near_range > 0:
        extra.update(fit_spur_near_law(r, st["p_spur"], hit & (st["n"] > 0))[0])
        extra.pop("spur_prone")  # the rig's own scale; these poses give the per-bearing shares
    else:
        extra["spur_bearing_weight"] = _spur_weights(stats)
    return dataclasses.replace(rig, **extra)


class _Problem:
    """The rig as a function of the search coordinates, and the discrepancy of its recording."""

    def __init__(self, real_log: LidarLog, real: dict[str, Any], seed: int, base: NeatoRig) -> None:
        self.log, self.real, self.seed = real_log, real, seed
        r, a = lidar_features(real_log.poses, real_log.bearings, real_log.require_map(), base.max_range)
        blocked = np.zeros(real_log.n_bearings, dtype=bool)
        blocked[real["blocked"]] = True
        st = cell_statistics(real_log, 6.0, split_spurious=True)
        self.knots_r, self.knots = _sigma_knots(real)
        sv = real["spur_value"]
        self.base = dataclasses.replace(
            base,
            n_bearings=real_log.n_bearings,
            blocked=tuple(real["blocked"]),
            sigma_knots_r=self.knots_r,
            sigma_knots=self.knots,
            spur_value=(float(sv[0]), float(sv[1])) if sv[0] is not None else base.spur_value,
            spur_bearing_weight=_spur_weights(real),
            **_null_law_params(r, a, np.isfinite(r) & ~blocked[None] & (st["n"] > 0), st["p_null"]),
            **_spur_range(real),
            **fit_bias_law(r, a, np.where((st["n_ok"] >= 2) & (st["p_spur"] == 0), st["mean"] - r, np.nan)),
        )

    def x0(self, rig: NeatoRig) -> NDArray[np.float64]:
        """Search coordinates of a rig (the start of the search)."""
        return np.array(
            [
                np.log(max(rig.null_cell_corr, 0.9) / (1 - min(rig.null_cell_corr, 0.999))),
                np.log(max(rig.null_arc, 2.0)),
                rig.bias_mean * 1e3,
                np.log(max(rig.bias_sd * 1e3, 0.1)),
                np.log(max(rig.spur_prone, 1e-3) / (1 - min(rig.spur_prone, 1 - 1e-3))),
                np.log(max(rig.spur_frac[0], 1e-3) / (1 - min(rig.spur_frac[0], 1 - 1e-3))),
                np.log(max(rig.pose_sd[0] * 100, 0.01)),
                np.log(max(np.rad2deg(rig.pose_sd[1]), 0.01)),
                np.log(max(rig.map_sd * 100, 0.01)),
                0.0,
                np.log(max(rig.out_cell_rate, 0.03) / (1 - min(rig.out_cell_rate, 0.99))),
                np.log(max(rig.out_cell_arc, 2.0)),
            ]
        )

    def rig(self, x: NDArray[np.float64]) -> NeatoRig:
        """The rig at search coordinates ``x`` (the null law and per-bearing effects are fixed statistics)."""
        corr, arc = float(np.clip(_logistic(np.array(x[0])), 0.0, 0.9999)), float(min(np.exp(x[1]), 60.0))
        scale = float(np.exp(x[9]))
        return dataclasses.replace(
            self.base,
            null_cell_corr=round(corr, 5),
            null_arc=round(arc, 3),
            bias_mean=round(float(np.clip(x[2], -100, 100)) * 1e-3, 6),
            bias_sd=round(float(min(np.exp(x[3]), 100.0)) * 1e-3, 6),
            spur_prone=round(float(_logistic(np.array(x[4]))), 5),
            spur_frac=(round(float(_logistic(np.array(x[5]))), 4), 1.0),
            pose_sd=(
                round(float(min(np.exp(x[6]), 100.0)) / 100, 5),
                round(float(np.deg2rad(min(np.exp(x[7]), 90))), 5),
            ),
            map_sd=round(float(min(np.exp(x[8]), 100.0)) / 100, 5),
            sigma_knots=tuple(float(f"{v * scale:.3g}") for v in self.knots),
            out_cell_rate=round(float(np.clip(_logistic(np.array(x[10])), 0.0, 0.5)), 5),
            out_cell_arc=round(float(min(np.exp(x[11]), 60.0)), 3),
        )

    def evaluate(self, rig: NeatoRig, seed: int | None = None) -> tuple[dict[str, float], dict[str, Any]]:
        """Discrepancy terms and statistics of ``rig`` recorded at the real poses (seed: the CRN seed)."""
        return recorded_discrepancy(rig, self.log, self.real, self.seed if seed is None else seed)


def recorded_discrepancy(
    rig: NeatoRig, real_log: LidarLog, real: dict[str, Any], seed: int
) -> tuple[dict[str, float], dict[str, Any]]:
    """Discrepancy terms (vs the real statistics ``real``) and statistics of ``rig`` recorded at the real poses.

    ``seed`` seeds the recording (common random numbers: the same seed, the same draws for every rig).
    """
    log, _ = rig.record(
        real_log.require_map(),
        np.random.default_rng(seed),
        poses=real_log.poses,
        repeats=real_log.ranges.shape[2],
    )
    stats = log_summary(log, rig.max_range)
    return discrepancy(stats, real), stats


SIGMA_REFINE_STEPS = 4
"""Fixed-point steps of :func:`refine_sigma`."""


def refine_sigma(prob: _Problem, rig: NeatoRig, steps: int = SIGMA_REFINE_STEPS) -> NeatoRig:
    """``rig`` with each knot of sigma versus range rescaled until the simulated statistic meets the real one.

    Per 0.5 m bin the knot is multiplied by ``exp(real - simulated)`` of ``sigma_range`` (the log median cell
    standard deviation; factor clipped to [1/3, 3]), ``steps`` times; the knots outside the bins follow their
    neighbours. The median of quantised readings (1 mm) is not the noise's sigma: at short range the real
    cells mostly read one value, which a single scale over all knots cannot match. Keeps the step that
    lowers the whole discrepancy most (possibly none).
    """
    real = np.asarray(prob.real["sigma_range"], dtype=np.float64)
    d, stats = prob.evaluate(rig)
    best = (d["total"], rig)
    for _ in range(steps):
        sim = np.asarray(stats["sigma_range"], dtype=np.float64)
        kv = np.asarray(rig.sigma_knots, dtype=np.float64).copy()
        kr = np.asarray(rig.sigma_knots_r, dtype=np.float64)
        ok = np.isfinite(real) & np.isfinite(sim)
        if not ok.any():
            break
        f = np.exp(np.clip(real[ok] - sim[ok], -np.log(3), np.log(3)))
        # knots at bin centres take their bin's factor; the others the nearest one's
        kv = kv * np.interp(kr, RANGE_CENTRES[ok], f)
        rig = dataclasses.replace(rig, sigma_knots=tuple(float(f"{v:.3g}") for v in np.maximum(kv, 1e-6)))
        d, stats = prob.evaluate(rig)
        if d["total"] < best[0]:
            best = (d["total"], rig)
    return best[1]


def calibrate_rig(
    real_log: LidarLog,
    *,
    seed: int = 0,
    max_evals: int = 150,
    start: NeatoRig | None = None,
    progress: bool = True,
    callback: Callable[[int, float], None] | None = None,
) -> tuple[NeatoRig, dict[str, Any]]:
    """Fit the rig's parameters to a real static-pose log (module docstring: statistics, discrepancy, search).

    Args:
        real_log: the real log (``(P, K, R)`` ranges with ``R >= 2``, approximate poses, map).
        seed: seed of the common random numbers of every simulation.
        max_evals: most discrepancy evaluations of the Nelder-Mead search.
        start: rig the search starts from (default: :class:`NeatoRig` defaults, also the "before"); its
            per-bearing bias mean and spread start at the real log's statistics.
        progress: show a tqdm bar.
        callback: called with ``(evaluation, discrepancy)`` after each evaluation.

    Returns:
        ``(rig, card)``: the calibrated rig and its card (data identity, discrepancy per statistic before
        and after, on the search's seed and on a fresh seed, the search's settings and time).
    """
    t0 = time.perf_counter()
    before_rig = start or NeatoRig()
    real = log_summary(real_log, before_rig.max_range)
    prob = _Problem(real_log, real, seed, before_rig)
    before, before_stats = prob.evaluate(before_rig)
    x0 = prob.x0(before_rig)
    if real["bias_mean"] is not None:  # start the bias at the real per-bearing statistics (the search refines it)
        x0[2], x0[3] = real["bias_mean"] * 1e3, np.log(max(real["bias_sd"] * 1e3, 0.1))
    steps = np.array([0.5, 0.5, 2.0, 0.5, 0.7, 0.7, 0.5, 0.5, 0.7, 0.2, 0.7, 0.5])
    n_eval = 0
    best = (np.inf, x0)
    bar = tqdm(total=max_evals, desc="calibrate lidar rig", disable=not progress)

    def objective(x: NDArray[np.float64], terms: tuple[str, ...] | None = None) -> float:
        nonlocal n_eval, best
        dd = prob.evaluate(prob.rig(x))[0]
        n_eval += 1
        if dd["total"] < best[0]:
            best = (dd["total"], np.array(x))
        bar.update(1)
        bar.set_postfix(D=f"{best[0]:.3g}")
        if callback is not None:
            callback(n_eval, dd["total"])
        return dd["total"] if terms is None else float(sum(dd[t] for t in terms))

    converged = []
    x_cur = x0.copy()
    for block, share, terms in BLOCKS:  # nearly separable: Nelder-Mead per block of coordinates, then all together
        idx = np.asarray(block, dtype=int)
        budget = max(int(share * max_evals), len(idx) + 2)
        budget = min(budget, max_evals - n_eval)
        if budget < len(idx) + 2:
            break
        x_start = (best[1] if terms is None else x_cur).copy()

        def sub(
            y: NDArray[np.float64],
            idx: NDArray[np.int64] = idx,
            x_start: NDArray[np.float64] = x_start,
            terms: tuple[str, ...] | None = terms,
        ) -> float:
            x = x_start.copy()
            x[idx] = y
            return objective(x, terms)

        y0 = x_start[idx]
        if terms == _NULL_TERMS:  # rugged in the persistence: start from the best of a coarse grid
            grid = [np.array([c, a]) for c in NULL_GRID_CORR for a in NULL_GRID_ARC]
            y0 = min(grid, key=sub)
            budget = max(budget - len(grid), len(idx) + 2)
        simplex = np.vstack([y0, y0 + np.diag(steps[idx])])
        res = minimize(
            sub,
            y0,
            method="Nelder-Mead",
            options={"maxfev": budget, "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-3},
        )
        x_cur = x_start.copy()
        x_cur[idx] = res.x
        converged.append(bool(res.success))
    bar.close()
    rig = refine_sigma(prob, prob.rig(best[1]))
    rig, spur_law = with_spur_near_law(rig, real_log)
    after, after_stats = prob.evaluate(rig)
    fresh, _ = prob.evaluate(rig, seed=seed + 1)
    fresh_before, _ = prob.evaluate(before_rig, seed=seed + 1)
    card = {
        "calibrated_against": _data_identity(real_log),
        "procedure": __doc__.strip(),
        "discrepancy": {
            "formula": "D = sum_s w_s * mean_i ((stat_sim[s, i] - stat_real[s, i]) / scale_s) ** 2, w_s = 1",
            "statistics": {k: {"scale": v[0], "definition": v[1]} for k, v in STATISTICS.items()},
        },
        "before": {"rig": "NeatoRig() defaults", "seed": seed, "per_statistic": before},
        "after": {"rig": "this file", "seed": seed, "per_statistic": after},
        "before_fresh_seed": {"seed": seed + 1, "per_statistic": fresh_before},
        "after_fresh_seed": {"seed": seed + 1, "per_statistic": fresh},
        "statistics": {
            k: {"real": real[k], "before": before_stats[k], "after": after_stats[k]}
            for k in STATISTICS
            if k not in ("p_null_bearing", "spur_bearing")
        },
        "spurious_law": spur_law,
        "search": {
            "method": "scipy.optimize.minimize Nelder-Mead, common random numbers",
            "coordinates": list(SEARCH),
            "evaluations": n_eval,
            "blocks": [[SEARCH[i] for i in blk] for blk, _, _ in BLOCKS],
            "block_terms": [list(t) if t is not None else "total" for _, _, t in BLOCKS],
            "block_converged": converged,
            "seed": seed,
            "seconds": round(time.perf_counter() - t0, 1),
        },
    }
    return rig, card


def _data_identity(real_log: LidarLog) -> dict[str, Any]:
    """What a rig card names as the real data it was calibrated against (file, sha256 of the ranges, shape)."""
    return {
        "file": Path(real_log.source).name,
        "sha256_of_ranges": ranges_sha256(real_log),
        "sha256_convention": "sha256 of the ranges array as loaded by sensor_envs.lidar.log.load_log "
        "(float64, C order; 0 = null, NaN = padding)",
        "shape": list(real_log.ranges.shape),
    }


def respurious_rig(
    real_log: LidarLog, rig: NeatoRig, source: str | Path, *, seed: int = 0, card: dict[str, Any] | None = None
) -> tuple[NeatoRig, dict[str, Any]]:
    """``rig`` with only its spurious-prone law re-derived from a real log (:func:`with_spur_near_law`), no search.

    Args:
        real_log: the real static-pose log.
        rig: the rig to start from (e.g. a rig file calibrated before the near-cell law existed).
        source: where ``rig`` came from (named in the card).
        seed: seed of the common random numbers of the before/after discrepancies.
        card: ``rig``'s own card (kept, its discrepancies replaced by this rig's).

    Returns:
        ``(rig, card)``: the card holds ``rig``'s card with ``after`` / ``after_fresh_seed`` measured on the new
        rig and a ``spurious_refit`` entry (the law's choice, the discrepancy before and after it).
    """
    real = log_summary(real_log, rig.max_range)
    before, _ = recorded_discrepancy(rig, real_log, real, seed)
    new, law = with_spur_near_law(rig, real_log)
    after, after_stats = recorded_discrepancy(new, real_log, real, seed)
    fresh, _ = recorded_discrepancy(new, real_log, real, seed + 1)
    out = dict(card or {})
    out.update(
        {
            "calibrated_against": _data_identity(real_log),
            "after": {"rig": "this file", "seed": seed, "per_statistic": after},
            "after_fresh_seed": {"seed": seed + 1, "per_statistic": fresh},
            "spurious_refit": {
                "from_rig": str(source),
                "procedure": (with_spur_near_law.__doc__ or "").strip(),
                "law": law,
                "seed": seed,
                "before": {"rig": str(source), "per_statistic": before},
                "after": {"rig": "this file", "per_statistic": after},
            },
        }
    )
    if "statistics" in out:
        out["statistics"] = {
            k: {**v, "after": after_stats[k]} for k, v in out["statistics"].items() if k in after_stats
        }
    return new, out
