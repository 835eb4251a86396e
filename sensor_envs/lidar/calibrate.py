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
spread, the shape of sigma versus range (median cell standard deviation per 0.5 m bin). The per-bearing
null offsets (``null_bearing_logit``) are profiled inside each evaluation: for the current range and
incidence slopes, each bearing's intercept is solved (bisection) so that its expected null rate at the
real poses equals the real one (the per-cell copula of persistent nulls keeps the mean rate).
The Nelder-Mead search then runs over the remaining parameters (:data:`SEARCH`).

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
from tqdm.auto import tqdm

from sensor_envs.lidar.log import LidarLog, load_log
from sensor_envs.lidar.lwlr import cell_statistics, lidar_features
from sensor_envs.lidar.rig import NeatoRig

__all__ = [
    "STATISTICS",
    "SEARCH",
    "REAL_LOG_NAME",
    "log_summary",
    "discrepancy",
    "calibrate_rig",
    "load_real_log",
    "bearing_profile",
]

REAL_LOG_NAME = "neato_mar27_train.npz"
"""File looked for when ``calibrate lidar`` is given a folder."""
RANGE_BINS = np.arange(0.0, 4.01, 0.5)
"""Nominal-range bins [m] of the null and sigma statistics."""
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
}
"""Statistic -> (scale, definition). Weight 1 each; a statistic's term is its mean squared error / scale**2."""

SEARCH: tuple[str, ...] = (
    "null_slope_range",
    "null_slope_incidence",
    "logit_null_cell_corr",
    "log_null_arc",
    "bias_mean_mm",
    "log_bias_sd_mm",
    "logit_spur_prone",
    "logit_spur_frac_low",
    "log_pose_sd_xy_cm",
    "log_pose_sd_theta_deg",
    "log_sigma_scale",
)
"""The coordinates of the Nelder-Mead search (transformed rig parameters)."""
BLOCKS: tuple[tuple[tuple[int, ...], float], ...] = (
    ((0, 1, 2, 3), 0.3),  # nulls: range and incidence slopes, persistence, arcs
    ((6, 7), 0.1),  # spurious returns: prone share, fraction
    ((4, 5, 8, 9, 10), 0.3),  # bias, pose error, sigma scale
    (tuple(range(11)), 0.3),  # all together
)
"""Blocks of :data:`SEARCH` coordinates searched in turn, with their shares of the evaluations."""


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
        raise ValueError(f"{p}: not a static-pose lidar log (.npz with ranges of shape poses x bearings x repeats)")
    log = load_log(p)
    if log.ranges.shape[2] < 2:
        raise ValueError(
            f"{p}: field 'ranges' has one reading per pose and bearing; calibration needs repeated readings"
        )
    if log.map_segments is None:
        raise ValueError(f"{p}: field 'map_segments' is missing; calibration needs the log's map")
    k = log.n_bearings
    if not np.allclose(log.bearings, np.deg2rad(np.arange(k) * 360.0 / k), atol=1e-6):
        raise ValueError(f"{p}: field 'bearings' is not the rig's regular full circle (j * 360 / K degrees)")
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
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    hit: NDArray[np.bool_],
    target: NDArray[np.float64],
    slopes: tuple[float, float],
) -> NDArray[np.float64]:
    """Per-bearing intercepts ``(K,)`` of logit ``p_null`` matching the target null rates at given features.

    Solves ``mean_p logistic(b_k + c1 r_pk + c2 alpha_pk) = target_k`` over the hit cells ``hit (P, K)`` of
    each bearing by bisection on ``[-20, 20]``; bearings without hit cells or target get 0.
    """
    lin = slopes[0] * np.where(hit, r, 0.0) + slopes[1] * np.where(hit, np.nan_to_num(a), 0.0)
    cnt = hit.sum(0)
    use = (cnt > 0) & np.isfinite(target)
    y = np.clip(np.nan_to_num(target), 1e-3, 1 - 1e-3)
    lo, hi = np.full(r.shape[1], -20.0), np.full(r.shape[1], 20.0)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        rate = np.where(hit, _logistic(mid[None] + lin), 0.0).sum(0) / np.maximum(cnt, 1)
        up = rate < y
        lo, hi = np.where(up, mid, lo), np.where(up, hi, mid)
    return np.where(use, 0.5 * (lo + hi), 0.0)


def _sigma_knots(real: dict[str, Any]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Knots of sigma versus range [m] from the real median cell standard deviation per range bin."""
    centres = 0.5 * (RANGE_BINS[:-1] + RANGE_BINS[1:])
    s = np.exp(np.asarray(real["sigma_range"], dtype=np.float64))
    ok = np.isfinite(s)
    if not ok.any():
        return NeatoRig.sigma_knots_r, NeatoRig.sigma_knots
    kr = np.r_[0.0, centres[ok], max(4.0, centres[ok][-1] + 0.25)]
    kv = np.r_[s[ok][0], s[ok], s[ok][-1]]
    return tuple(float(v) for v in kr), tuple(float(f"{v:.3g}") for v in kv)


def _null_offsets(
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    hit: NDArray[np.bool_],
    target: NDArray[np.float64],
    slopes: tuple[float, float],
) -> tuple[float, tuple[float, ...]]:
    """Intercept and per-bearing offsets (rounded to 0.01) of logit ``p_null`` matching per-bearing null rates."""
    b = profile_bearing_intercepts(r, a, hit, target, slopes)
    used = hit.any(0) & np.isfinite(target)
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


def bearing_profile(rig: NeatoRig, log: LidarLog) -> NeatoRig:
    """``rig`` with its per-bearing effects (null offsets, spurious weights) re-derived from ``log``.

    Keeps every other parameter (slopes, persistence, noise, pose error...). Used to measure the
    calibration honestly by leave-poses-out folds: the per-bearing effects are statistics of the
    poses they were computed on.
    """
    stats = log_summary(log, rig.max_range)
    r, a = lidar_features(log.poses, log.bearings, log.require_map(), rig.max_range)
    blocked = np.zeros(log.n_bearings, dtype=bool)
    blocked[stats["blocked"]] = True
    hit = np.isfinite(r) & ~blocked[None]
    target = np.asarray(stats["p_null_bearing"], dtype=np.float64)
    c0, off = _null_offsets(r, a, hit, target, (rig.null_logit[1], rig.null_logit[2]))
    return dataclasses.replace(
        rig,
        null_logit=(round(c0, 4), rig.null_logit[1], rig.null_logit[2]),
        null_bearing_logit=off,
        spur_bearing_weight=_spur_weights(stats),
    )


class _Problem:
    """The rig as a function of the search coordinates, and the discrepancy of its recording."""

    def __init__(self, real_log: LidarLog, real: dict[str, Any], seed: int, base: NeatoRig) -> None:
        self.log, self.real, self.seed = real_log, real, seed
        self.r, self.a = lidar_features(real_log.poses, real_log.bearings, real_log.require_map(), base.max_range)
        blocked = np.zeros(real_log.n_bearings, dtype=bool)
        blocked[real["blocked"]] = True
        self.hit = np.isfinite(self.r) & ~blocked[None]
        self.target = np.asarray(real["p_null_bearing"], dtype=np.float64)
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
        )

    def x0(self, rig: NeatoRig) -> NDArray[np.float64]:
        """Search coordinates of a rig (the start of the search)."""
        return np.array(
            [
                rig.null_logit[1],
                rig.null_logit[2],
                np.log(max(rig.null_cell_corr, 0.9) / (1 - min(rig.null_cell_corr, 0.999))),
                np.log(max(rig.null_arc, 2.0)),
                rig.bias_mean * 1e3,
                np.log(max(rig.bias_sd * 1e3, 0.1)),
                np.log(max(rig.spur_prone, 1e-3) / (1 - min(rig.spur_prone, 1 - 1e-3))),
                np.log(max(rig.spur_frac[0], 1e-3) / (1 - min(rig.spur_frac[0], 1 - 1e-3))),
                np.log(max(rig.pose_sd[0] * 100, 0.01)),
                np.log(max(np.rad2deg(rig.pose_sd[1]), 0.01)),
                0.0,
            ]
        )

    def rig(self, x: NDArray[np.float64]) -> NeatoRig:
        """The rig at search coordinates ``x`` (per-bearing null offsets profiled, rounded to 0.01)."""
        c1, c2 = float(x[0]), float(x[1])
        corr, arc = float(np.clip(_logistic(np.array(x[2])), 0.0, 0.9999)), float(min(np.exp(x[3]), 60.0))
        c0, off = _null_offsets(self.r, self.a, self.hit, self.target, (c1, c2))
        scale = float(np.exp(x[10]))
        return dataclasses.replace(
            self.base,
            null_logit=(round(c0, 4), round(c1, 4), round(c2, 4)),
            null_bearing_logit=off,
            null_cell_corr=round(corr, 5),
            null_arc=round(arc, 3),
            bias_mean=round(float(np.clip(x[4], -100, 100)) * 1e-3, 6),
            bias_sd=round(float(min(np.exp(x[5]), 100.0)) * 1e-3, 6),
            spur_prone=round(float(_logistic(np.array(x[6]))), 5),
            spur_frac=(round(float(_logistic(np.array(x[7]))), 4), 1.0),
            pose_sd=(round(float(np.exp(x[8])) / 100, 5), round(float(np.deg2rad(np.exp(x[9]))), 5)),
            sigma_knots=tuple(float(f"{v * scale:.3g}") for v in self.knots),
        )

    def evaluate(self, rig: NeatoRig, seed: int | None = None) -> tuple[dict[str, float], dict[str, Any]]:
        """Discrepancy terms and statistics of ``rig`` recorded at the real poses (seed: the CRN seed)."""
        log, _ = rig.record(
            self.log.require_map(),
            np.random.default_rng(self.seed if seed is None else seed),
            poses=self.log.poses,
            repeats=self.log.ranges.shape[2],
        )
        stats = log_summary(log, rig.max_range)
        return discrepancy(stats, self.real), stats


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
        x0[4], x0[5] = real["bias_mean"] * 1e3, np.log(max(real["bias_sd"] * 1e3, 0.1))
    steps = np.array([0.3, 0.3, 0.5, 0.5, 2.0, 0.5, 0.7, 0.7, 0.5, 0.5, 0.2])
    n_eval = 0
    best = (np.inf, x0)
    bar = tqdm(total=max_evals, desc="calibrate lidar rig", disable=not progress)

    def objective(x: NDArray[np.float64]) -> float:
        nonlocal n_eval, best
        d = prob.evaluate(prob.rig(x))[0]["total"]
        n_eval += 1
        if d < best[0]:
            best = (d, np.array(x))
        bar.update(1)
        bar.set_postfix(D=f"{best[0]:.3g}")
        if callback is not None:
            callback(n_eval, d)
        return d

    converged = []
    for block, share in BLOCKS:  # nearly separable: Nelder-Mead per block of coordinates, then all together
        idx = np.asarray(block, dtype=int)
        budget = max(int(share * max_evals), len(idx) + 2)
        budget = min(budget, max_evals - n_eval)
        if budget < len(idx) + 2:
            break
        x_best = best[1].copy()

        def sub(y: NDArray[np.float64], idx: NDArray[np.int64] = idx, x_best: NDArray[np.float64] = x_best) -> float:
            x = x_best.copy()
            x[idx] = y
            return objective(x)

        y0 = x_best[idx]
        simplex = np.vstack([y0, y0 + np.diag(steps[idx])])
        res = minimize(
            sub,
            y0,
            method="Nelder-Mead",
            options={"maxfev": budget, "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-3},
        )
        converged.append(bool(res.success))
    bar.close()
    rig = prob.rig(best[1])
    after, after_stats = prob.evaluate(rig)
    fresh, _ = prob.evaluate(rig, seed=seed + 1)
    fresh_before, _ = prob.evaluate(before_rig, seed=seed + 1)
    card = {
        "calibrated_against": {
            "file": Path(real_log.source).name,
            "sha256_of_ranges": ranges_sha256(real_log),
            "sha256_convention": "sha256 of the ranges array as loaded by sensor_envs.lidar.log.load_log "
            "(float64, C order; 0 = null, NaN = padding)",
            "shape": list(real_log.ranges.shape),
        },
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
        "search": {
            "method": "scipy.optimize.minimize Nelder-Mead, common random numbers",
            "coordinates": list(SEARCH),
            "evaluations": n_eval,
            "blocks": [[SEARCH[i] for i in blk] for blk, _ in BLOCKS],
            "block_converged": converged,
            "seed": seed,
            "seconds": round(time.perf_counter() - t0, 1),
        },
    }
    return rig, card
