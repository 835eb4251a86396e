"""The closed-form laws of the lidar rig calibration: nulls, bias and spurious returns fitted to a real log.

Each law is fitted directly to statistics of the real log (a logistic null law with its slope ridge chosen by
cross-validation, a bias law over range and incidence, the near spurious-return law), so the simulation search
of :func:`sensor_envs.lidar.calibrate.calibrate_rig` tunes only the rest.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from sensor_envs.lidar.calibrate_stats import RANGE_CENTRES, log_summary
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr import cell_statistics, lidar_features
from sensor_envs.lidar.rig import NULL_SLOPE_CENTRE, NeatoRig
from sensor_envs.rng import fold_ids

__all__ = [
    "fit_null_law",
    "null_law_rig",
    "choose_slope_ridge",
    "fit_bias_law",
    "fit_spur_near_law",
    "with_spur_near_law",
    "bearing_profile",
    "profile_bearing_intercepts",
]


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
    """Knots of sigma versus range [m] from the real median cell standard deviation per range bin.

    A bin without a measured spread (too few cells, or a median spread of 0: readings quantized to millimetres
    that repeat exactly) is NaN and gives no knot; with no bin left, the rig's defaults.
    """
    s = np.exp(np.asarray(real["sigma_range"], dtype=np.float64))
    ok = np.isfinite(s) & (s > 0)
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
