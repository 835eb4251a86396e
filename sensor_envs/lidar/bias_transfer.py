"""A learned lidar bias that carries over to unseen poses: a trend pooled over bearings plus a weighted per-bearing one.

The bias ``mean - r`` [m] a static log teaches is, per cell, the sum of what the sensor does everywhere (a trend
in range ``r`` [m] and incidence ``alpha`` [rad], e.g. far readings falling short), what one bearing does (its
calibration offset) and what belongs to the poses the log was recorded at: their registration error (a few mm to
cm and a fraction of a degree) and the map's error at the walls they see. The last part does not recur at other
poses, yet a per-bearing regression on ``(r, alpha)`` learns it as bias wherever few poses inform a table node.

With ``bias_model="pooled"`` (:class:`~sensor_envs.lidar.lwlr.LidarLWLR`'s default) the bias is

    bias_k(r, alpha) = G(r, alpha) + lam L_k(r, alpha),    mu = r + (1 - s) bias_k(r, alpha),
 where ``G`` is an LWLR of every bearing's cells pooled (the part many poses and bearings support; kernel widths and
degree chosen by the leave-poses-out folds), ``L_k`` the per-bearing LWLR of the residual ``bias - G`` (the model's
usual per-bearing fit), set to 0 outside the range/incidence span of bearing ``k``'s own training cells
(:func:`support_gate`: no extrapolation of a per-bearing effect), and the local weight ``lam`` (in
:data:`LOCAL_WEIGHT_GRID`) and the shrinkage ``s`` (in :data:`~sensor_envs.lidar.local_regression.SHRINKAGE_GRID`) are
chosen together by :func:`choose_bias`: the pair of least pooled held-out MAE of ``mu`` among those no worse than the
raycast in EVERY fold (``s = 1`` always is). The held-out predictions are honest: per fold, ``G`` and ``L`` are
refitted on the training poses only.

``G`` is fitted on cells binned on a fine ``(r, alpha)`` grid (:data:`BIN_RANGE` x :data:`BIN_ALPHA`; weighted
means, exact for the local-constant fit and within the bin size for the local-linear one) and tabulated on the
model's table grid, clamped to the training cells' range widened by one kernel width (as the per-bearing tables).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.lidar.local_regression import _bilinear, choose_shrinkage, lwlr

__all__ = [
    "GLOBAL_H_RANGE_GRID",
    "GLOBAL_H_ALPHA_GRID",
    "LOCAL_WEIGHT_GRID",
    "BIAS_MODELS",
    "global_table",
    "global_lookup",
    "choose_global_widths",
    "pooled_oof",
    "choose_bias",
    "support_gate",
]

BIAS_MODELS = ("pooled", "per_bearing")
"""``pooled``: a trend over all bearings plus a CV-weighted per-bearing part; ``per_bearing``: the seed's fit."""
GLOBAL_H_RANGE_GRID = (0.25, 0.6, 1.6)
"""Candidate range kernel widths [m] of the pooled trend ``G``."""
GLOBAL_H_ALPHA_GRID = (0.5, 4.0)
"""Candidate incidence kernel widths [rad] of ``G``."""
LOCAL_WEIGHT_GRID = (0.0, 0.25, 0.5, 0.75, 1.0)
"""Candidate weights ``lam`` of the per-bearing part (``0``: the pooled trend alone)."""
BIN_RANGE, BIN_ALPHA = 0.025, 0.025
"""Bin sizes [m, rad] of the cells pooled for ``G``."""

Grid = tuple[NDArray[np.float64], NDArray[np.float64]]


def _bins(
    r: NDArray[np.float64], a: NDArray[np.float64], y: NDArray[np.float64], w: NDArray[np.float64]
) -> tuple[NDArray[np.float64], ...]:
    """Cells with ``w > 0`` pooled over bearings in ``(r, alpha)`` bins: centres of mass, mean target, weight sum."""
    m = w > 0
    rr, aa, yy, ww = r[m], a[m], y[m], w[m]
    key = np.stack([np.floor(rr / BIN_RANGE), np.floor(aa / BIN_ALPHA)], axis=1)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    sw = np.bincount(inv, ww).astype(np.float64)
    br, ba, by = (np.bincount(inv, ww * v) / sw for v in (rr, aa, yy))
    return br, ba, by, sw


def global_table(
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    y: NDArray[np.float64],
    w: NDArray[np.float64],
    h: tuple[float, float],
    degrees: tuple[int, ...],
    grid: Grid,
) -> NDArray[np.float64]:
    """The pooled trend ``G`` [m] tabulated on ``grid = (range_grid, alpha_grid)``: ``(len(degrees), n_r, n_alpha)``.

    Args:
        r: ``(T, K)`` training ranges [m] (finite where ``w > 0``).
        a: ``(T, K)`` training incidences [rad].
        y: ``(T, K)`` bias target [m].
        w: ``(T, K)`` cell weights (0 = not used).
        h: kernel widths ``(h_range [m], h_alpha [rad])``.
        degrees: local polynomial degrees (0, 1) evaluated together.
        grid: the model's table grid.
    """
    br, ba, by, bw = _bins(r, a, y, w)
    rg, ag = grid
    qr, qa = (v.ravel() for v in np.meshgrid(rg, ag, indexing="ij"))
    qr = np.clip(qr, br.min() - h[0], br.max() + h[0]) if br.size else qr
    qa = np.clip(qa, ba.min() - h[1], ba.max() + h[1]) if ba.size else qa
    out = lwlr(
        qr[:, None], qa[:, None], br[:, None], ba[:, None], by[:, None, None], bw[:, None], h[0], h[1], (0.0,), degrees
    )
    return out[:, 0, :, 0, 0].reshape(len(degrees), rg.size, ag.size)


def global_lookup(
    table: NDArray[np.float64], grid: Grid, r: NDArray[np.float64], a: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``G`` [m] at features ``r, a`` (any shape; 0 where ``r`` is not finite), bilinear in ``table (n_r, n_alpha)``."""
    hit = np.isfinite(r)
    rq = np.where(hit, r, grid[0][0]).reshape(-1, 1)
    aq = np.nan_to_num(np.asarray(a, dtype=np.float64), nan=0.0).reshape(-1, 1)
    v = _bilinear(table[None, None], grid[0], grid[1], rq, aq)[0, :, 0].reshape(np.shape(r))
    return np.where(hit, v, 0.0)


def support_gate(
    q_r: NDArray[np.float64],
    q_a: NDArray[np.float64],
    t_r: NDArray[np.float64],
    t_a: NDArray[np.float64],
    w: NDArray[np.float64],
) -> NDArray[np.bool_]:
    """Where the per-bearing part may act: ``(Q, K)`` True within its own bearing's training span.

    A query counts when it lies within the range and incidence span (not widened) of its OWN bearing's training
    cells (``w > 0``). Beyond that span a per-bearing regression extrapolates (its table is clamped to the nearest
    edge value), and what it learned at a few poses there is least likely to recur; the bias falls back to ``G``.
    """
    ok = w > 0
    with np.errstate(invalid="ignore"):
        rr, aa = np.where(ok, t_r, np.nan), np.where(ok, t_a, np.nan)
        has = ok.any(0)
        lo_r, hi_r = np.nanmin(np.where(has, rr, 0.0), 0), np.nanmax(np.where(has, rr, 0.0), 0)
        lo_a, hi_a = np.nanmin(np.where(has, aa, 0.0), 0), np.nanmax(np.where(has, aa, 0.0), 0)
    inside = (q_r >= lo_r) & (q_r <= hi_r) & (q_a >= lo_a) & (q_a <= hi_a)
    return np.asarray(inside & has, dtype=bool)


def choose_global_widths(
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    y: NDArray[np.float64],
    w: NDArray[np.float64],
    fold: NDArray[np.int64],
    grid: Grid,
) -> tuple[list[float], dict[str, Any]]:
    """Kernel widths and degree of ``G`` of least leave-poses-out MAE of the bias: ``[h_range, h_alpha, 0, degree]``.

    ``r, a, y, w`` are ``(P, K)`` (rows = poses); ``fold`` the fold of every row; held-out cells: those with ``w > 0``.
    """
    degs = (0, 1)
    cand = list(itertools.product(GLOBAL_H_RANGE_GRID, GLOBAL_H_ALPHA_GRID))
    err = np.zeros((len(cand), len(degs)))
    n = 0.0
    for f in np.unique(fold):
        tr, te = fold != f, fold == f
        m = w[te] > 0
        n += m.sum()
        for i, h in enumerate(cand):
            tabs = global_table(r[tr], a[tr], y[tr], w[tr], h, degs, grid)
            for j in range(len(degs)):
                err[i, j] += np.abs(global_lookup(tabs[j], grid, r[te], a[te]) - y[te])[m].sum()
    mae = err / max(n, 1.0)
    bi, bj = (int(v) for v in np.unravel_index(int(np.argmin(mae)), mae.shape))
    best = [float(cand[bi][0]), float(cand[bi][1]), 0.0, float(degs[bj])]
    return best, {"cv_mae_best": float(mae[bi, bj]), "cv_mae_worst": float(mae.max()), "n_candidates": int(mae.size)}


def pooled_oof(
    fit: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    query: tuple[NDArray[np.float64], NDArray[np.float64]],
    fold: NDArray[np.int64],
    h_global: list[float],
    h_local: list[float],
    grid: Grid,
    robust_weights: Any,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Out-of-fold ``G`` and ``L`` [m] at the query features, each ``(P, K)``, refitted per fold on its training rows.

    Args:
        fit: ``(r, a, y, w)`` ``(P, K)``: features the tables learn at, bias target, cell weights.
        query: ``(r, a)`` features the held-out rows are scored at (the log's approximate poses).
        fold: fold of every row.
        h_global: ``G``'s ``[h_range, h_alpha, h_bearing, degree]``.
        h_local: the per-bearing part's kernel widths (the model's ``h_["bias"]``).
        grid: the model's table grid.
        robust_weights: ``f(r, a, y (T, K, 1), w) -> w'``, the outlier weights of the training rows (bisquare on a
            pilot fit of the bias), used by both ``G`` and ``L``; ``None`` uses ``w``.
    """
    r, a, y, w = fit
    q_r, q_a = query
    g_oof, l_oof = np.zeros_like(y), np.zeros_like(y)
    h_r, h_a, h_b, deg = h_local
    for f in np.unique(fold):
        tr, te = fold != f, fold == f
        w_tr = robust_weights(r[tr], a[tr], y[tr][..., None], w[tr]) if robust_weights is not None else w[tr]
        tab = global_table(r[tr], a[tr], y[tr], w_tr, (h_global[0], h_global[1]), (int(h_global[3]),), grid)[0]
        res = (y[tr] - global_lookup(tab, grid, r[tr], a[tr]))[..., None]
        g_oof[te] = global_lookup(tab, grid, q_r[te], q_a[te])
        pred = lwlr(q_r[te], q_a[te], r[tr], a[tr], res, w_tr, h_r, h_a, (h_b,), (int(deg),))
        l_oof[te] = np.where(support_gate(q_r[te], q_a[te], r[tr], a[tr], w_tr), pred[0, 0, ..., 0], 0.0)
    return g_oof, l_oof


def choose_bias(
    y: NDArray[np.float64],
    g_oof: NDArray[np.float64],
    l_oof: NDArray[np.float64],
    mask: NDArray[np.bool_],
    fold: NDArray[np.int64],
    setting: str | float = "cv",
) -> tuple[float, float, dict[str, Any]]:
    """Local weight ``lam`` and shrinkage ``s`` of ``mu = r + (1 - s) (G + lam L)``, checked fold by fold.

    For every ``lam`` in :data:`LOCAL_WEIGHT_GRID`, :func:`~sensor_envs.lidar.local_regression.choose_shrinkage`
    picks ``s``
    (its rule: no worse than the raycast in any fold, least pooled MAE; or ``setting`` when a number); the pair of
    least pooled CV MAE among those that pass every fold wins (ties: the smaller ``lam``). ``lam = 0, s = 1`` is the
    raycast, so some pair always passes.

    Returns:
        ``lam``, ``s`` and :func:`choose_shrinkage`'s report of the chosen pair, with ``local_weight`` and a
        ``per_local_weight`` list (``lam``, its ``s``, pooled CV MAE, whether it passes every fold).
    """
    rows = []
    for lam in LOCAL_WEIGHT_GRID:
        s, rep = choose_shrinkage(y, g_oof + lam * l_oof, mask, fold, setting)
        passes = all(p["mae_chosen"] <= p["mae_raycast"] + 1e-12 for p in rep["per_fold"])
        rows.append((lam, s, rep, passes))
    ok = [row for row in rows if row[3]] or rows
    lam, s, rep, _ = min(ok, key=lambda row: (round(row[2]["cv_mae_chosen"], 12), row[0]))
    report = dict(rep)
    report["local_weight"] = float(lam)
    report["bias_model"] = "pooled"
    report["per_local_weight"] = [
        {"local_weight": float(v), "shrinkage": float(si), "cv_mae": float(ri["cv_mae_chosen"]), "passes_every_fold": p}
        for v, si, ri, p in rows
    ]
    return float(lam), float(s), report
