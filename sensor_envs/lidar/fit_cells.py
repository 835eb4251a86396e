"""The per-cell fit of :class:`~sensor_envs.lidar.lwlr.LidarLWLR`: one of its two fit strategies (logs with repeats).

Each pose-bearing cell is summarised (:func:`cell_statistics`: null and spurious fractions, mean, spread); every
parameter is regressed per bearing by LWLR on ``(r, alpha)`` with kernel widths chosen by leave-poses-out CV,
the bias (pooled or per bearing) and its shrinkage on the same folds, ``tau`` and the intra-cell correlations of
nulls and spurious returns; then tabulated. The other strategy, on individual readings, is
:mod:`sensor_envs.lidar.fit_readings`.
"""

from __future__ import annotations

import itertools
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm.auto import tqdm

from sensor_envs.geometry import as_segments, raycast_pose
from sensor_envs.inputs import InputError
from sensor_envs.lidar.bias_transfer import (
    choose_bias,
    choose_global_widths,
    global_lookup,
    global_table,
    pooled_oof,
    support_gate,
)
from sensor_envs.lidar.local_regression import (
    P_EPS,
    SIGMA_FLOOR,
    TAU_CLIP,
    _finish,
    choose_shrinkage,
    lwlr,
)
from sensor_envs.lidar.log import LidarLog, training_summary
from sensor_envs.lidar.lwlr_io import PARAMS
from sensor_envs.lidar.pose_correction import correct_poses, pose_error_sd
from sensor_envs.lidar.reading_law import null_count_log_prob
from sensor_envs.rng import fold_ids

if TYPE_CHECKING:
    from sensor_envs.lidar.lwlr import LidarLWLR

__all__ = ["fit_cells", "lidar_features", "cell_statistics", "pose_fold_groups", "RHO_GRID"]

RHO_GRID = (0.0, 0.01, 0.03, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95)
"""Candidate intra-cell correlations of nulls and of spurious returns (extended variant)."""


def lidar_features(
    poses: ArrayLike, bearings: ArrayLike, segments: ArrayLike, max_range: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nominal range and incidence per pose and bearing.

    Args:
        poses: ``(S, 3)`` sensor poses ``x, y, theta`` in the map frame [m, rad].
        bearings: ``(K,)`` bearings in the sensor frame [rad].
        segments: ``(M, 2, 2)`` map [m].
        max_range: farther hits count as no hit [m].

    Returns:
        ``r (S, K)`` [m] (``inf`` = no hit) and ``alpha (S, K)`` [rad] (``NaN`` = no hit).
    """
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    r, a, _ = raycast_pose(p, bearings, as_segments(segments, name="map"), max_range)
    return r, a


def cell_statistics(log: LidarLog, spur_above: float, split_spurious: bool) -> dict[str, NDArray[np.float64]]:
    """Per pose-bearing cell statistics of a log's readings.

    Args:
        log: the log (``ranges (P, K, R)``).
        spur_above: readings farther than this [m] are spurious returns.
        split_spurious: if True, ``mean``/``std`` use in-range readings only; else all non-null readings.

    Returns:
        ``(P, K)`` arrays: ``n`` readings, ``n_ok`` readings entering mean/std, ``p_null``, ``p_spur``,
        ``mean`` [m], ``std`` [m] (ddof 1; NaN where ``n_ok < 2``).
    """
    x = log.ranges
    valid = ~np.isnan(x)
    null = valid & (x == 0)
    spur = valid & (x > spur_above)
    ok = valid & (x > 0) & ~(spur if split_spurious else np.zeros_like(spur))
    n, n_ok = valid.sum(2).astype(float), ok.sum(2).astype(float)
    xs = np.where(ok, x, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = xs.sum(2) / n_ok
        var = np.where(ok, (x - mean[..., None]) ** 2, 0.0).sum(2) / (n_ok - 1)
        out = {
            "n": n,
            "n_ok": n_ok,
            "p_null": null.sum(2) / n,
            "p_spur": spur.sum(2) / n,
            "mean": np.where(n_ok >= 1, mean, np.nan),
            "std": np.where(n_ok >= 2, np.sqrt(var), np.nan),
        }
    return out


def targets(
    stats: dict[str, NDArray[np.float64]], r: NDArray[np.float64], name: str
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Regression target ``(P, K)`` of parameter ``name`` and the mask of cells that inform it."""
    hit = np.isfinite(r)
    if name in ("p_null", "p_spur"):
        return np.nan_to_num(stats[name]), hit & (stats["n"] > 0)
    m = hit & (stats["n_ok"] >= 2)
    if name == "bias":
        return np.where(m, stats["mean"] - np.where(hit, r, 0.0), 0.0), m
    s = np.where(m, stats["std"], 1.0)
    return (np.log(np.maximum(s, SIGMA_FLOOR)) if name == "log_sigma" else s), m


def robust_weights(
    t_r: NDArray[np.float64], t_a: NDArray[np.float64], y: NDArray[np.float64], weight: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Bisquare robustness weights (as in LOWESS) from a pilot LWLR fit, ``(T, K)``.

    Cells whose target lies more than 6 median absolute residuals from the pilot fit (e.g. rays that
    graze a corner, where a few cm of pose error move the hit to another wall) get weight 0.
    """
    pilot = lwlr(t_r, t_a, t_r, t_a, y, weight, 0.4, 0.5, (0.0,))[0, 0]
    res = np.abs(y - pilot)
    ok = weight > 0
    scale = np.array([np.median(res[..., j][ok]) for j in range(y.shape[2])])
    u = res / (6 * np.maximum(scale, 1e-9))
    return weight * np.prod(np.where(u < 1, (1 - u * u) ** 2, 0.0), axis=2)


def cv_loss(name: str, pred: NDArray[np.float64], y: NDArray[np.float64], m: NDArray[np.bool_]) -> tuple[float, float]:
    """Sum of absolute errors (in the parameter's natural unit) over ``m`` and the cell count."""
    p = _finish(name, pred)
    if name == "log_sigma":
        p, y = np.exp(p), np.exp(y)
    return float(np.abs(p - y)[m].sum()), float(m.sum())


def pose_fold_groups(poses: ArrayLike, decimals: int = 4) -> NDArray[np.int64]:
    """Group id of every row for leave-poses-out folds: rows at the same pose share one id.

    Readings of one pose are near-duplicates (the same rays, the same pose error), so a pose recorded in
    several rows must not be split between training and held-out folds. Poses equal after rounding to
    ``decimals`` (0.1 mm, 1e-4 rad) are one group; ids follow the first occurrence, so a log whose poses
    are all distinct gets ``0 .. P - 1`` (the folds of :func:`~sensor_envs.rng.fold_ids` with ``P`` rows).

    Args:
        poses: ``(P, 3)`` poses ``x, y, theta`` [m, rad].
        decimals: rounding before comparison.

    Returns:
        ``(P,)`` group ids.
    """
    key = np.round(np.atleast_2d(np.asarray(poses, dtype=np.float64)), decimals)
    if key.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))
    return rank[inv.ravel()].astype(np.int64)


def fit_cells(m: LidarLWLR, log: LidarLog) -> LidarLWLR:
    """The per-cell fit of :meth:`LidarLWLR.fit <sensor_envs.lidar.lwlr.LidarLWLR.fit>` (logs with repeats).

    Summarises each pose-bearing cell (:func:`cell_statistics`), chooses the kernel widths by leave-poses-out CV,
    the bias model and its shrinkage on the same folds, ``tau`` and the intra-cell correlations, and tabulates
    every parameter; fills ``m``'s fitted attributes (not the extra-state terms) and returns it.
    """
    m._check_params_for(log)
    if m.extra_state:
        raise InputError(f"{log.source}: extra_state needs a scan log (one reading per scan and bearing)")
    segs = log.require_map()
    r_ap, a_ap = lidar_features(log.poses, log.bearings, segs, m.max_range)
    stats = cell_statistics(log, m.spur_above, split_spurious=m.variant == "extended")
    poses, _, corr_info = correct_poses(log, stats["mean"], stats["n_ok"], m.max_range)
    sd = pose_error_sd(log.poses, poses)
    m.pose_sd_ = sd  # the rigid pose error of :meth:`sample`
    if m.pose_correction:
        r, a = lidar_features(poses, log.bearings, segs, m.max_range)
    else:
        r, a = r_ap, a_ap
    groups = cell_groups(m, stats, r)
    r0, a0 = np.where(np.isfinite(r), r, 0.0), np.nan_to_num(a)
    fold = pose_folds(m, log)
    pooled = pool_bias(m, r0, a0, groups, fold) if m.bias_model == "pooled" else None
    m.h_, m.cv_scores_ = cross_validate(m, r0, a0, groups, fold)
    held_out = held_out_bias(m, stats, r_ap, a_ap, r0, a0, groups, fold)
    if pooled is None:
        m.bias_shrinkage_, m.cv_scores_["bias_shrinkage"] = choose_shrinkage(*held_out, fold, m.bias_shrinkage)
    else:
        held_out = choose_pooled(m, pooled, held_out, r_ap, a_ap, r0, a0, fold)
    if m.pose_correction:
        m.cv_scores_["pose_correction"] = corr_info
    m.cv_scores_["pose_error_sd"] = {"sd": [float(v) for v in sd], "rms_corrections": corr_info}
    m.bearings_ = log.bearings.copy()
    if m.variant == "extended":
        groups.append(tau_group(m, r0, a0, groups, stats["n_ok"], held_out))
        m.h_["tau2"] = list(m.h_["bias"])
    tabulate(m, r, a, groups)
    if pooled is not None:  # bias = G + lam L (L where bearing k has cells), same grid, float32 values
        j = m.param_names_.index("bias")
        m.tables_[j] = combined_bias(m, pooled, m.tables_[j], r0, a0)
    del m._bias_oof
    if m.variant == "seed":
        m.p_out_ = 0.0
    extended = m.variant == "extended"
    m.null_rho_ = fit_count_rho(m, "p_null", "null_rho", stats, r) if extended else 0.0
    m.spur_rho_ = fit_count_rho(m, "p_spur", "spur_rho", stats, r) if extended else 0.0
    del m._count_oof
    m._fit_spurious(log)
    m.training_ = training_summary(log)
    return m


def cell_groups(
    m: LidarLWLR, stats: dict[str, NDArray[np.float64]], r: NDArray[np.float64]
) -> list[tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.float64], bool]]:
    """Parameters sharing cell weights: ``(names, y (P, K, n), weight (P, K), robust)``.

    The extended variant down-weights outlying cells of ``bias``/``log_sigma`` (bisquare, LOWESS-style).
    """
    names = PARAMS[m.variant]
    out = []
    for grp in (names[:-2], names[-2:]):
        ys, ms = zip(*(targets(stats, r, n) for n in grp), strict=True)
        out.append((grp, np.stack(ys, axis=-1), ms[0].astype(np.float64), m.variant == "extended" and grp[0] == "bias"))
    return out


def pool_bias(
    m: LidarLWLR, r: NDArray[np.float64], a: NDArray[np.float64], groups: list[Any], fold: NDArray[np.int64]
) -> dict[str, Any]:
    """The pooled trend ``G`` of the bias (``bias_model="pooled"``, :mod:`sensor_envs.lidar.bias_transfer`).

    Chooses ``G``'s kernel widths on the folds, tabulates it on all cells, and replaces the bias target of
    ``groups`` by its residual ``bias - G`` (the per-bearing part ``L`` the usual fit then learns). Returns
    ``G``'s widths, CV score and table, and the original target and cell weights.
    """
    i = next(j for j, g in enumerate(groups) if g[0][0] == "bias")
    names, y, weight, robust = groups[i]
    yb = y[..., 0].copy()
    w = robust_weights(r, a, y[..., :1], weight) if robust else weight
    grid = m._grid()
    h, score = choose_global_widths(r, a, yb, w, fold, grid)
    table = global_table(r, a, yb, w, (h[0], h[1]), (int(h[3]),), grid)[0]
    y2 = y.copy()
    y2[..., 0] = np.where(weight > 0, yb - global_lookup(table, grid, r, a), 0.0)
    groups[i] = (names, y2, weight, robust)
    return {"h": h, "score": score, "table": table, "y": yb, "weight": weight, "robust": robust}


def combined_bias(
    m: LidarLWLR, pooled: dict[str, Any], local: NDArray[np.float64], r: NDArray[np.float64], a: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The bias table ``(K, n_r, n_alpha)``: ``G + lam L``, ``L`` gated to each bearing's training span."""
    rg, ag = m.range_grid_, m.alpha_grid_
    qr, qa = (v.ravel() for v in np.meshgrid(rg, ag, indexing="ij"))
    gate = support_gate(qr[:, None], qa[:, None], r, a, pooled["weight"])  # (Q, K)
    lam = m.cv_scores_["bias_shrinkage"]["local_weight"]
    combined = pooled["table"][None] + lam * np.where(gate.T.reshape(local.shape), local, 0.0)
    return np.asarray(combined.astype(np.float32), dtype=np.float64)


def choose_pooled(
    m: LidarLWLR,
    pooled: dict[str, Any],
    held_out: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
    r_ap: NDArray[np.float64],
    a_ap: NDArray[np.float64],
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    fold: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Local weight and shrinkage of the pooled bias by the folds; returns the held-out target, ``mu - r``, mask.

    The held-out ``G`` and ``L`` are refitted per fold on its training poses
    (:func:`~sensor_envs.lidar.bias_transfer.pooled_oof`) and read at the log's approximate poses.
    """
    y_ev, _, m_ev = held_out
    if not m.pose_correction:  # the groups' bias target is now the residual of G: score the bias itself
        y_ev, m_ev = pooled["y"], pooled["weight"] > 0
    query = (np.where(m_ev, r_ap, 0.0), np.nan_to_num(a_ap)) if m.pose_correction else (r, a)
    g_oof, l_oof = pooled_oof(
        (r, a, pooled["y"], pooled["weight"]),
        query,
        fold,
        pooled["h"],
        m.h_["bias"],
        m._grid(),
        robust_weights if pooled["robust"] else None,
    )
    lam, s, report = choose_bias(y_ev, g_oof, l_oof, m_ev, fold, m.bias_shrinkage)
    report["global"] = {"h": pooled["h"], **pooled["score"]}
    m.bias_shrinkage_, m.cv_scores_["bias_shrinkage"] = s, report
    return y_ev, g_oof + lam * l_oof, m_ev


def tau_group(
    m: LidarLWLR,
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    groups: list[Any],
    n_ok: NDArray[np.float64],
    held_out: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
) -> tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.float64], bool]:
    """Target of ``tau2`` (squared out-of-fold residual of the cell means) on the non-outlying cells.

    The residual is that of the shrunk ``mu`` (``bias_shrinkage_``) at the held-out cells' approximate
    poses (``held_out``: target, out-of-fold bias and mask of :func:`held_out_bias`). Also sets
    ``p_out_``: the fraction of in-range readings in cells whose mean is an outlier (bisquare weight 0),
    the weight of the uniform outlier component of :meth:`log_prob`.
    """
    _, y, weight, _ = next(g for g in groups if g[0][0] == "bias")
    w = robust_weights(r, a, y[..., :1], weight)
    out = (weight > 0) & (w == 0)
    m.p_out_ = float(np.clip((n_ok * out).sum() / max((n_ok * (weight > 0)).sum(), 1), P_EPS, 0.5))
    y_ev, oof, m_ev = held_out
    e2 = np.where(m_ev, np.minimum((y_ev - (1 - m.bias_shrinkage_) * oof) ** 2, TAU_CLIP**2), 0.0)
    return ("tau2",), e2[..., None], w * m_ev, False


def held_out_bias(
    m: LidarLWLR,
    stats: dict[str, NDArray[np.float64]],
    r_ap: NDArray[np.float64],
    a_ap: NDArray[np.float64],
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    groups: list[Any],
    fold: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Held-out bias target ``mean - r`` [m], its out-of-fold prediction and the cells scored, each ``(P, K)``.

    Every cell is scored at its log's (approximate) pose, as a user's poses are. Without pose correction
    these are the bandwidth CV's own out-of-fold predictions; with it, the chosen kernel widths are refitted
    per fold on the training folds' corrected cells and read at the held-out approximate features.
    """
    names, y, weight, robust = next(g for g in groups if g[0][0] == "bias")
    if not m.pose_correction:
        return y[..., 0], m._bias_oof, weight > 0
    y_ap, m_ap = targets(stats, r_ap, "bias")
    q_r, q_a = np.where(m_ap, r_ap, 0.0), np.nan_to_num(a_ap)
    h_r, h_a, h_b, deg = m.h_["bias"]
    oof = np.zeros_like(y_ap)
    for f in np.unique(fold):
        tr, te = fold != f, fold == f
        w_tr = robust_weights(r[tr], a[tr], y[tr], weight[tr]) if robust else weight[tr]
        pred = lwlr(q_r[te], q_a[te], r[tr], a[tr], y[tr][..., :1], w_tr, h_r, h_a, (h_b,), (int(deg),))
        oof[te] = pred[0, 0, ..., 0]
    return y_ap, oof, m_ap


def fit_count_rho(
    m: LidarLWLR, name: str, score: str, stats: dict[str, NDArray[np.float64]], r: NDArray[np.float64]
) -> float:
    """Intra-cell correlation of the outcome ``name`` (``p_null``: nulls, ``p_spur``: spurious returns).

    The ``RHO_GRID`` value maximising the beta-binomial likelihood of the training cells' counts of
    that outcome around its out-of-fold probability at the chosen kernel widths (``0`` = independent
    readings); the scores go to ``cv_scores_[score]``.
    """
    cells = np.isfinite(r) & (stats["n"] > 0)
    n = stats["n"][cells]
    k = np.round(stats[name][cells] * n)
    q = m._count_oof[name][cells]
    ll = [null_count_log_prob(k, n, q, rho).sum() for rho in RHO_GRID]
    m.cv_scores_[score] = {
        "ll_per_reading_best": float(max(ll) / n.sum()),
        "ll_per_reading_independent": float(ll[0] / n.sum()),
        "n_candidates": len(RHO_GRID),
    }
    return float(RHO_GRID[int(np.argmax(ll))])


def pose_folds(m: LidarLWLR, log: LidarLog) -> NDArray[np.int64]:
    """Leave-poses-out fold of every row of ``log``; rows at one pose share a fold (:func:`pose_fold_groups`)."""
    return fold_ids(pose_fold_groups(log.poses), m.n_folds, random_state=m.random_state)


def cross_validate(
    m: LidarLWLR, r: NDArray[np.float64], a: NDArray[np.float64], groups: list[Any], fold: NDArray[np.int64]
) -> tuple[dict[str, list[float]], dict[str, Any]]:
    """Leave-poses-out CV (folds ``fold`` per row): per parameter, the kernel widths and degree of least MAE."""
    hb = (0.0,) if m.variant == "seed" else tuple(float(v) for v in m.h_bearing_grid)
    hra = list(itertools.product(m.h_range_grid, m.h_alpha_grid))
    degs = (1,) if m.variant == "seed" else tuple(int(v) for v in m.degree_grid)
    grid = [(h_r, h_a, h_b, deg) for h_r, h_a in hra for deg in degs for h_b in hb]
    per = len(degs) * len(hb)
    err = {n: np.zeros(len(grid)) for g in groups for n in g[0]}
    oof = np.zeros((len(grid),) + r.shape)  # out-of-fold bias predictions (for tau)
    counts = ("p_null", "p_spur")  # out-of-fold probabilities of the counted outcomes (for null_rho, spur_rho)
    oof_p = {n: np.zeros((len(grid),) + r.shape) for g in groups for n in g[0] if n in counts}
    cnt = {n: np.zeros(len(grid)) for g in groups for n in g[0]}
    for f in tqdm(range(m.n_folds), desc=f"CV lidar LWLR ({m.variant})", disable=not m.verbose):
        tr, te = fold != f, fold == f
        for names, y, weight, robust in groups:
            w_tr = robust_weights(r[tr], a[tr], y[tr], weight[tr]) if robust else weight[tr]
            m_te = weight[te] > 0
            for i, (h_r, h_a) in enumerate(hra):
                pred = lwlr(r[te], a[te], r[tr], a[tr], y[tr], w_tr, h_r, h_a, hb, degs)
                pred = pred.reshape((per,) + pred.shape[2:])  # (degrees x bearing widths, Q, K, n)
                if names[0] == "bias":
                    oof[i * per : (i + 1) * per, te] = pred[..., 0]
                for j, n in enumerate(names):
                    if n in oof_p:
                        oof_p[n][i * per : (i + 1) * per, te] = _finish(n, pred[..., j])
                    for b in range(per):
                        e, c = cv_loss(n, pred[b, ..., j], y[te][..., j], m_te)
                        err[n][i * per + b] += e
                        cnt[n][i * per + b] += c
    best, scores = {}, {}
    m._count_oof = {}
    for n in err:
        mae = err[n] / np.maximum(cnt[n], 1)
        i = int(np.argmin(mae))
        best[n] = [float(v) for v in grid[i]]
        scores[n] = {"cv_mae_best": float(mae[i]), "cv_mae_worst": float(mae.max()), "n_candidates": len(grid)}
        if n == "bias":
            m._bias_oof = oof[i]
        if n in oof_p:
            m._count_oof[n] = oof_p[n][i]
    return best, scores


def tabulate(m: LidarLWLR, r: NDArray[np.float64], a: NDArray[np.float64], groups: list[Any]) -> None:
    """Evaluate each parameter's LWLR on the ``(r, alpha)`` grid of every bearing."""
    rg, ag = m._grid()
    m.range_grid_, m.alpha_grid_ = rg, ag
    qr, qa = (v.ravel() for v in np.meshgrid(rg, ag, indexing="ij"))
    hit = np.isfinite(r)
    r0, a0 = np.where(hit, r, 0.0), np.nan_to_num(a)
    tables, names = [], []
    for grp, y, weight, robust in tqdm(groups, desc="tabulating", disable=not m.verbose):
        w = robust_weights(r0, a0, y, weight) if robust else weight
        for j, n in enumerate(grp):
            h_r, h_a, h_b, deg = m.h_[n]
            rr, aa = np.where(w > 0, r, np.nan), np.where(w > 0, a, np.nan)
            with warnings.catch_warnings():  # bearings without any cell (blocked): whole grid
                warnings.simplefilter("ignore", RuntimeWarning)
                lo_r = np.nan_to_num(np.nanmin(rr, 0) - h_r, nan=0.0)
                hi_r = np.nan_to_num(np.nanmax(rr, 0) + h_r, nan=m.max_range)
                lo_a = np.nan_to_num(np.nanmin(aa, 0) - h_a, nan=0.0)
                hi_a = np.nan_to_num(np.nanmax(aa, 0) + h_a, nan=np.pi / 2)
            q_r = np.clip(qr[:, None], lo_r[None], hi_r[None])
            q_a = np.clip(qa[:, None], lo_a[None], hi_a[None])
            v = _finish(n, lwlr(q_r, q_a, r0, a0, y[..., j : j + 1], w, h_r, h_a, (h_b,), (int(deg),))[0, 0, ..., 0])
            tables.append(v.T.reshape(-1, rg.size, ag.size))
            names.append(n)
    # (n_params, K, n_r, n_alpha), rounded to float32 (the file's dtype) so that save/load is exact
    m.tables_ = np.stack(tables).astype(np.float32).astype(np.float64)
    m.param_names_ = names
