"""Fitting the learned lidar on individual readings: logs of single scans at moving poses (time series).

:meth:`LidarLWLR.fit <sensor_envs.lidar.lwlr.LidarLWLR.fit>` dispatches here for logs with one reading
per pose and bearing (``ranges (S, K, 1)``: S scans, K bearings), and on request for repeated logs.
Each reading (one scan or repeat, one bearing) is one training point at the features ``(r, alpha)``
of its scan's pose; the parameters are regressed per bearing by the same LWLR as the per-cell path
(same kernels, same bearing pooling, same tables), on per-reading targets:

* ``p_null`` (and ``p_spur``, extended): LWLR of the binary outcome (null / spurious far return) of
  every reading whose ray hits the map; kernel widths by held-out Bernoulli log-loss.
* ``bias`` (``mu - r``): LWLR of ``x - r`` over the in-range non-null readings (the extended variant
  excludes spurious far returns ``> spur_above``, which are their own outcome), made robust by
  bisquare weights (LOWESS, 3 passes) from a local-constant pilot fit: readings farther from it
  than ``6`` local mean absolute residuals (the cut-off ``c``; local, as the noise grows with range)
  get weight 0, so spurious far returns and rays that hit another surface do not
  drag ``mu``. Kernel widths by held-out absolute error truncated at ``c``.
* ``sigma`` (seed) / ``log_sigma`` (extended): ``sigma = sqrt(pi / 2) m`` where ``m`` is the LWLR of the
  absolute out-of-fold residuals ``min(|x - r - bias_oof|, c)`` of the inlying readings (linear in
  sigma, like the per-cell path's regression of cell standard deviations; regressing ``e^2`` would
  let the large far-range spread swamp the small near-range one under a wide kernel); widths by
  held-out Gaussian negative log-likelihood of those residuals. With one reading per pose this ``sigma`` is the whole
  spread around ``mu`` (pose error included): ``tau2`` (extended) is tabulated as 0.
* ``p_out`` (extended): the fraction of in-range hit readings with bisquare weight 0 (the uniform
  outlier component); ``null_rho = spur_rho = 0`` (persistence of nulls and spurious returns needs repeats).

Cross-validation folds are contiguous blocks of scans (consecutive scans are correlated; random rows
would leak): block ``b`` of ``L`` consecutive scans goes to fold ``b mod n_folds``. ``L`` is
:func:`block_length`: the first lag at which the autocorrelations of the readings' residuals
from the nominal range and of the null indicator (per bearing, pooled, and per scan: median absolute
residual, null fraction, which carry a slowly drifting pose error) all drop below :data:`ACF_CUTOFF`;
at least 1 and at most ``S // 2``. The folds are ``min(n_folds, number of blocks)``. A static log with
repeats has ``L = 1`` pose (leave-poses-out). ``L`` is stored in ``cv_scores_["blocks"]``.

Kernel widths are chosen per parameter in two stages: ``(h_range, h_alpha)`` (and the degree) with
the narrowest bearing width, then the bearing width (and the degree) at those; the per-cell path
searches the full product, which costs ``len(h_bearing_grid)`` times more per reading.

Speed: LWLR at a query costs one pass over the training points of the bearing and its pooled
neighbours, so the fit uses at most ``max_readings`` rows (scans or repeats), the same rows for all
bearings, picked evenly spaced in log order (a fixed stride: every part of the time series stays
represented, and the choice is deterministic). The run-time model is unchanged: parameter tables per
bearing over ``(r, alpha)``, read bilinearly.
"""

from __future__ import annotations

import itertools
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from tqdm.auto import tqdm

from sensor_envs.inputs import InputError
from sensor_envs.lidar.local_regression import (
    P_EPS,
    SIGMA_FLOOR,
    _bearing_offsets,
    _bilinear,
    _finish,
    _solve,
    _target_sums,
    choose_shrinkage,
    lwlr,
)
from sensor_envs.lidar.log import LidarLog, LidarLogError, training_summary
from sensor_envs.lidar.mapping import map_features

if TYPE_CHECKING:
    from sensor_envs.lidar.lwlr import LidarLWLR

__all__ = [
    "fit_per_reading",
    "block_length",
    "block_folds",
    "pooled_acf",
    "reading_rows",
    "check_map_covers",
    "DEFAULT_MAX_READINGS",
    "ACF_CUTOFF",
    "MIN_HIT_FRACTION",
]

DEFAULT_MAX_READINGS = 300
"""Rows (scans or repeats) used by a per-reading fit, evenly spaced in the log."""
ACF_CUTOFF = 0.1
"""The block length is the first lag where the pooled residual autocorrelation is below this."""
MIN_HIT_FRACTION = 0.5
"""A map covers a log when at least this fraction of its in-range returns lie on rays that hit the map."""
_BISQUARE_C = 6.0
_ROOT_HALF_PI = float(np.sqrt(np.pi / 2))  # sigma = sqrt(pi / 2) E|e| for a normal error e
_CHUNK = 3_000_000  # query x training points x bearings per LWLR call (memory bound)


# --------------------------------------------------------------------------------------- rows, blocks
def reading_rows(log: LidarLog, max_readings: int | None) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Rows of readings used by the fit: the pose of each row and its readings ``(T, K)`` [m].

    A row is one repeat of one pose (one scan for a scan log), rows in log order (pose-major); at
    most ``max_readings`` rows are kept, evenly spaced (``None`` keeps all).
    """
    p, k, r = log.ranges.shape
    x = log.ranges.transpose(0, 2, 1).reshape(p * r, k)
    pose = np.repeat(np.arange(p), r)
    keep = ~np.isnan(x).all(1)
    x, pose = x[keep], pose[keep]
    if max_readings is not None and x.shape[0] > max_readings:
        idx = np.unique(np.round(np.linspace(0, x.shape[0] - 1, int(max_readings))).astype(np.int64))
        x, pose = x[idx], pose[idx]
    return pose, x


def pooled_acf(res: NDArray[np.float64], max_lag: int) -> NDArray[np.float64]:
    """Autocorrelation at lags ``1..max_lag`` of ``res (S, K)`` along axis 0, pooled over columns.

    Each column is standardised by its own mean and standard deviation (NaN = missing, ignored);
    lag ``l`` is the mean of ``z[s] z[s + l]`` over the pairs where both are present.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        z = (res - np.nanmean(res, 0)) / np.nanstd(res, 0)
    z = np.where(np.isfinite(z), z, np.nan)
    out = np.full(max_lag, np.nan)
    for lag in range(1, max_lag + 1):
        prod = z[:-lag] * z[lag:]
        if np.isfinite(prod).any():
            out[lag - 1] = float(np.nanmean(prod))
    return out


def block_length(log: LidarLog, r: NDArray[np.float64], max_lag: int = 100) -> tuple[int, dict[str, Any]]:
    """Block length ``L`` [scans] of the contiguous-block cross-validation (see the module docstring).

    ``L`` is the first lag at which these autocorrelations are all below :data:`ACF_CUTOFF`: of each
    bearing's range residual ``x - r`` (clipped to +-1 m) and null indicator, pooled over bearings, and
    of the per-scan median absolute residual and null fraction (slow, scan-wide errors such as a
    drifting pose). At most ``S // 2`` (two blocks) and ``max_lag``.

    Args:
        log: the log (a repeated log gives ``L = 1``: its poses are independent set-ups).
        r: ``(S, K)`` nominal ranges [m] of the log's poses.
        max_lag: the largest lag examined [scans].

    Returns:
        ``L`` and a summary (the autocorrelations, the rule, ``L`` in seconds when the log has times).
    """
    s = log.n_poses
    if log.ranges.shape[2] > 1:
        return 1, {"scans_per_block": 1, "rule": "repeated log: one pose per block (leave-poses-out)"}
    x = log.ranges[:, :, 0]
    ok = np.isfinite(r) & (x > 0)
    res = np.where(ok, np.clip(x - np.where(ok, r, 0.0), -1.0, 1.0), np.nan)
    null = np.where(np.isfinite(r) & ~np.isnan(x), (x == 0).astype(float), np.nan)
    cap = max(1, min(s // 2, max_lag))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        scan_level = np.stack([np.nanmedian(np.abs(res), 1), np.nanmean(null, 1)], axis=1)
    series = {
        "bearing_residual": pooled_acf(res, cap),
        "bearing_null": pooled_acf(null, cap),
        "scan_median_abs_residual": pooled_acf(scan_level[:, :1], cap),
        "scan_null_fraction": pooled_acf(scan_level[:, 1:], cap),
    }
    acf = np.nanmax(np.stack(list(series.values())), axis=0)
    below = np.nonzero(~(acf >= ACF_CUTOFF))[0]  # NaN counts as decorrelated
    length = int(below[0] + 1 if below.size else cap)
    info: dict[str, Any] = {
        "scans_per_block": length,
        "rule": f"first lag where every residual/null autocorrelation is < {ACF_CUTOFF} (at most S // 2 = {cap})",
        "acf": {k: [round(float(v), 4) for v in a[: length + 5]] for k, a in series.items()},
    }
    if log.t is not None and s > 1:
        info["seconds_per_block"] = float(length * np.median(np.diff(log.t)))
    return length, info


def block_folds(n_scans: int, n_folds: int, block: int) -> NDArray[np.int64]:
    """Fold of each scan: block ``b = s // block`` goes to fold ``b mod n_folds``."""
    return (np.arange(n_scans) // max(int(block), 1)) % n_folds


def check_map_covers(log: LidarLog, r: NDArray[np.float64], max_range: float, map_name: str = "") -> float:
    """Fraction of in-range returns on rays that hit the map; a :class:`LidarLogError` below :data:`MIN_HIT_FRACTION`.

    Args:
        log: the log.
        r: ``(S, K)`` nominal ranges [m] of its poses in the map (``inf`` = no hit).
        max_range: readings up to this range count [m].
        map_name: the map's name for the message.
    """
    x = log.ranges
    ret = ~np.isnan(x) & (x > 0) & (x <= max_range)
    n = int(ret.sum())
    if n == 0:
        return 1.0
    frac = float((ret & np.isfinite(r)[..., None]).sum() / n)
    if frac < MIN_HIT_FRACTION:
        raise LidarLogError(
            f"{log.source}: field 'map_segments': the map{' ' + map_name if map_name else ''} does not cover the "
            "scans: only "
            f"{100 * frac:.1f} % of the {n} returns within {max_range} m lie on rays that hit it "
            f"(need {100 * MIN_HIT_FRACTION:.0f} %); wrong map, map frame or poses?"
        )
    return frac


# ----------------------------------------------------------------------------------------------- LWLR
def lwlr_chunked(
    q_r: NDArray[np.float64],
    q_a: NDArray[np.float64],
    t_r: NDArray[np.float64],
    t_a: NDArray[np.float64],
    y: NDArray[np.float64],
    weight: NDArray[np.float64],
    h_r: float,
    h_a: float,
    h_bearings: tuple[float, ...] = (0.0,),
    degrees: tuple[int, ...] = (1,),
) -> NDArray[np.float64]:
    """:func:`~sensor_envs.lidar.lwlr.lwlr` evaluated in chunks of queries (bounded memory); same result."""
    q, k = q_r.shape
    step = max(1, _CHUNK // max(1, t_r.shape[0] * k))
    parts = [
        lwlr(q_r[i : i + step], q_a[i : i + step], t_r, t_a, y, weight, h_r, h_a, h_bearings, degrees)
        for i in range(0, q, step)
    ]
    return np.concatenate(parts, axis=2)


def _robust(
    r: NDArray[np.float64], a: NDArray[np.float64], y: NDArray[np.float64], weight: NDArray[np.float64], iters: int = 3
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Bisquare weights ``(T, K)`` and the per-reading cut-off ``c`` [m], as LOWESS with a local scale.

    The pilot is a local-constant fit (stable where data are sparse) of ``y``; the scale is the local-constant
    fit of the absolute residuals (the noise grows with range: one global scale would cut the far readings'
    honest spread); ``c = 6`` local mean absolute residuals (about 4.8 sigma for normal noise), at least 1 mm.
    Both are refitted ``iters`` times with the previous weights, so far outliers do not hide themselves.
    """
    w = weight
    cut = np.ones_like(y)
    for _ in range(iters):
        pilot = lwlr_chunked(r, a, r, a, y[..., None], w, 0.4, 0.5, (0.0,), (0,))[0, 0, ..., 0]
        res = np.abs(y - pilot)
        scale = lwlr_chunked(r, a, r, a, res[..., None], w, 0.4, 0.5, (0.0,), (0,))[0, 0, ..., 0]
        cut = _BISQUARE_C * np.maximum(scale, 1e-3 / _BISQUARE_C)
        u = res / cut
        w = weight * np.where(u < 1, (1 - u * u) ** 2, 0.0)
    return w, cut


def _loss(
    kind: str, pred: NDArray[np.float64], y: NDArray[np.float64], cut: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per-reading held-out loss: Bernoulli log-loss, truncated absolute error, or Gaussian NLL of residuals."""
    if kind == "binary":
        p = np.clip(pred, P_EPS, 1 - P_EPS)
        return -(y * np.log(p) + (1 - y) * np.log1p(-p))
    if kind == "bias":
        return np.minimum(np.abs(y - pred), cut)
    sig = np.maximum(_ROOT_HALF_PI * pred, SIGMA_FLOOR)  # y = |residual|, pred = its local mean
    return np.log(sig) + 0.5 * (y / sig) ** 2


# ------------------------------------------------------------------------------------------------ fit
def fit_per_reading(
    model: LidarLWLR,
    log: LidarLog,
    *,
    max_readings: int | None = DEFAULT_MAX_READINGS,
    block_scans: int | None = None,
) -> LidarLWLR:
    """Fit ``model`` on the log's individual readings (see the module docstring); returns the model.

    Args:
        model: an unfitted :class:`~sensor_envs.lidar.lwlr.LidarLWLR` (its hyperparameters are used).
        log: a log with a map; ``(S, K, 1)`` scans or ``(P, K, R)`` repeats.
        max_readings: rows used by the fit (evenly spaced; ``None`` = all).
        block_scans: CV block length [scans]; ``None`` chooses it by :func:`block_length`.

    Raises:
        ValueError: for bad hyperparameters, a log without map or a map that does not cover the scans.
    """
    # folds here are blocks of scans, not poses (no pose-count check): one static pose over time is a log
    model._check_params()
    if model.pose_correction:
        raise InputError(f"{log.source}: pose_correction needs a static log with repeats (the per-cell fit)")
    segs = log.require_map()
    r, a = map_features(log.poses, log.bearings, segs, model.max_range)
    coverage = check_map_covers(log, r, model.max_range)
    if block_scans is None:
        block, block_info = block_length(log, r)
    else:
        block, block_info = int(block_scans), {"scans_per_block": int(block_scans), "rule": "given"}
    n_folds = max(2, min(model.n_folds, -(-log.n_poses // block)))  # no more folds than blocks
    pose, x = reading_rows(log, max_readings)
    fold = block_folds(log.n_poses, n_folds, block)[pose]
    if np.unique(fold).size < 2:
        raise InputError(f"{log.source}: only {np.unique(fold).size} CV fold has readings; use fewer or shorter blocks")
    ext = model.variant == "extended"
    hit = np.isfinite(r[pose])
    tr_r, tr_a = np.where(hit, r[pose], 0.0), np.where(hit, np.nan_to_num(a[pose]), 0.0)
    valid = ~np.isnan(x) & hit
    spur = valid & (x > model.spur_above)
    ok = valid & (x > 0) & ~(spur if ext else False)
    y_bias = np.where(ok, x - tr_r, 0.0)
    w_bias, cut = _robust(tr_r, tr_a, y_bias, ok.astype(float))
    binary = [("p_null", (x == 0).astype(float))] + ([("p_spur", spur.astype(float))] if ext else [])

    hb = (0.0,) if not ext else tuple(float(v) for v in model.h_bearing_grid)
    degs = (1,) if not ext else tuple(int(v) for v in model.degree_grid)
    hra = list(itertools.product(model.h_range_grid, model.h_alpha_grid))
    folds = np.unique(fold)
    stages = 2 if len(hb) > 1 else 1
    bar = tqdm(
        total=(len(binary) + 2) * folds.size * stages,
        desc=f"CV lidar LWLR per reading ({model.variant})",
        disable=not model.verbose,
    )

    def cv(kind: str, y: NDArray[np.float64], w: NDArray[np.float64]) -> tuple[list[float], dict[str, Any]]:
        """Kernel widths and degree with the least mean held-out loss, in two stages (see the docstring)."""
        best: tuple[float, float, float, int] = (0.0, 0.0, 0.0, 1)
        scores: dict[str, Any] = {}
        h_b: tuple[float, ...]
        for stage in range(stages):
            if stage == 0:
                cands, h_b = hra, (min(hb),)
            else:
                cands, h_b = [best[:2]], hb
            grid = [(h_r, h_a, b, d) for h_r, h_a in cands for d in degs for b in h_b]
            tot, cnt = np.zeros(len(grid)), 0.0
            for f in folds:
                tr, te = fold != f, fold == f
                m = w[te] > 0
                for i, (h_r, h_a) in enumerate(cands):
                    pred = lwlr_chunked(
                        tr_r[te], tr_a[te], tr_r[tr], tr_a[tr], y[tr][..., None], w[tr], h_r, h_a, h_b, degs
                    )
                    pred = pred.reshape((-1,) + pred.shape[2:4])
                    for b in range(pred.shape[0]):
                        tot[i * pred.shape[0] + b] += _loss(kind, pred[b], y[te], cut[te])[m].sum()
                cnt += m.sum()
                bar.update(1)
            mean = tot / max(cnt, 1.0)
            i = int(np.argmin(mean))
            best = grid[i]
            scores[f"stage_{stage}"] = {
                "cv_loss_best": float(mean[i]),
                "cv_loss_worst": float(mean.max()),
                "n_candidates": len(grid),
            }
        scores["cv_loss_best"] = scores[f"stage_{stages - 1}"]["cv_loss_best"]
        return [float(v) for v in best], scores

    h: dict[str, list[float]] = {}
    scores: dict[str, dict[str, Any]] = {}
    w_bin = valid.astype(float)
    targets: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    for name, y in binary:
        h[name], scores[name] = cv("binary", y, w_bin)
        scores[name]["loss"] = "held-out Bernoulli log-loss per reading"
        targets[name] = (y, w_bin)
    h["bias"], scores["bias"] = cv("bias", y_bias, w_bias)
    scores["bias"]["loss"] = "held-out absolute error [m] truncated at the bisquare cut-off c"
    targets["bias"] = (y_bias, w_bias)
    bias_oof = np.zeros_like(y_bias)  # out-of-fold bias of the chosen widths (for the sigma target)
    h_r, h_a, h_b, deg = h["bias"]
    for f in folds:
        tr, te = fold != f, fold == f
        bias_oof[te] = lwlr_chunked(
            tr_r[te], tr_a[te], tr_r[tr], tr_a[tr], y_bias[tr][..., None], w_bias[tr], h_r, h_a, (h_b,), (int(deg),)
        )[0, 0, ..., 0]
    model.bias_shrinkage_, shrink_scores = choose_shrinkage(y_bias, bias_oof, w_bias > 0, fold, model.bias_shrinkage)
    e_abs = np.where(w_bias > 0, np.minimum(np.abs(y_bias - (1 - model.bias_shrinkage_) * bias_oof), cut), 0.0)
    w_sig = (w_bias > 0).astype(float)
    s_name = "log_sigma" if ext else "sigma"
    h[s_name], scores[s_name] = cv("sigma", e_abs, w_sig)
    bar.close()
    scores[s_name]["loss"] = "held-out Gaussian NLL of out-of-fold residuals (nats, without log(2 pi) / 2)"
    targets[s_name] = (e_abs, w_sig)

    model.h_, model.bearings_ = h, log.bearings.copy()
    if ext:
        h["tau2"] = list(h["bias"])
    scores["blocks"] = {**block_info, "n_folds": int(folds.size)}
    scores["bias_shrinkage"] = {**shrink_scores, "cells": "inlying in-range readings (bisquare weight > 0)"}
    scores["per_reading"] = {
        "rows_used": int(x.shape[0]),
        "rows_in_log": int(log.n_poses * log.ranges.shape[2]),
        "subsampling": "evenly spaced rows (scans or repeats) in log order, the same rows for every bearing",
        "robust_cutoff_median_m": float(np.median(cut[ok])) if ok.any() else None,
        "map_hit_fraction_of_returns": coverage,
    }
    model.cv_scores_ = scores
    _tabulate(model, tr_r, tr_a, targets, ext)
    n_in = (ok & hit).sum()
    model.p_out_ = float(np.clip(((w_bias == 0) & ok).sum() / max(n_in, 1), P_EPS, 0.5)) if ext else 0.0
    model.null_rho_ = model.spur_rho_ = 0.0
    model._fit_spurious(log)
    model.training_ = {**training_summary(log), "fit": "per reading"}
    return model


def lwlr_grid(
    q_r: NDArray[np.float64],
    q_a: NDArray[np.float64],
    t_r: NDArray[np.float64],
    t_a: NDArray[np.float64],
    y: NDArray[np.float64],
    weight: NDArray[np.float64],
    h_r: float,
    h_a: float,
    h_b: float,
    degree: int,
) -> NDArray[np.float64]:
    """:func:`~sensor_envs.lidar.lwlr.lwlr` at queries ``(Q,)`` shared by all bearings: ``(Q, K)``.

    With the same queries at every bearing, the weighted sums of bearing ``k + d`` are those of bearing
    ``k`` rolled by ``d``: the sums are computed once and pooled over bearings by rolling (exactly the
    pooling of :func:`~sensor_envs.lidar.lwlr.lwlr`, at a fraction of its cost for wide bearing kernels).
    """
    ok = weight > 0
    w0 = np.where(ok, weight, 0.0)
    tr, ta = np.where(ok, t_r, 0.0), np.where(ok, t_a, 0.0)
    ty = np.where(ok[..., None], y, 0.0)
    prior = (w0[..., None] * ty).sum(0) / np.maximum(w0.sum(0), 1e-12)[:, None]
    n = ty.shape[2]
    step = max(1, _CHUNK // max(1, t_r.shape[0] * t_r.shape[1]))
    sums = []
    for i in range(0, q_r.size, step):
        dr = (tr[None] - q_r[i : i + step, None, None]) / h_r  # (Q, T, K)
        da = (ta[None] - q_a[i : i + step, None, None]) / h_a
        w = w0[None] * np.exp(-0.5 * (dr * dr + da * da))
        wdr, wda = w * dr, w * da
        parts = [w, wdr, wda, wdr * dr, wdr * da, wda * da]
        sums.append(np.stack([v.sum(1) for v in parts] + _target_sums(w, wdr, wda, ty)))
    base = np.concatenate(sums, axis=1)  # (6 + 3n, Q, K)
    acc = np.zeros_like(base)
    for d, cnt in _bearing_offsets(float(h_b)):
        wb = cnt * np.exp(-0.5 * (d / h_b) ** 2) if h_b > 0 else float(d == 0)
        if wb and (h_b == 0 or abs(d) <= np.ceil(3 * h_b)):
            acc += wb * np.roll(base, -d, axis=2)
    return _solve(acc[None], prior, n, int(degree))[0, ..., 0]


def _tabulate(
    model: LidarLWLR,
    r: NDArray[np.float64],
    a: NDArray[np.float64],
    targets: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]],
    ext: bool,
) -> None:
    """Evaluate each parameter's LWLR on the ``(r, alpha)`` grid of every bearing (as the per-cell path).

    Queries outside a bearing's training range (widened by one kernel width) are clamped to it, as in the
    per-cell path; the clamped values are read bilinearly from the unclamped grid (:func:`lwlr_grid`).
    """
    rg, ag = model._grid()
    model.range_grid_, model.alpha_grid_ = rg, ag
    qr, qa = (v.ravel() for v in np.meshgrid(rg, ag, indexing="ij"))
    names = ["p_null", "p_spur", "bias", "log_sigma"] if ext else ["p_null", "bias", "sigma"]
    tables = []
    for n in names:
        y, w = targets[n]
        h_r, h_a, h_b, deg = model.h_[n]
        rr, aa = np.where(w > 0, r, np.nan), np.where(w > 0, a, np.nan)
        with warnings.catch_warnings():  # bearings without any reading (blocked): whole grid
            warnings.simplefilter("ignore", RuntimeWarning)
            lo_r = np.nan_to_num(np.nanmin(rr, 0) - h_r, nan=0.0)
            hi_r = np.nan_to_num(np.nanmax(rr, 0) + h_r, nan=model.max_range)
            lo_a = np.nan_to_num(np.nanmin(aa, 0) - h_a, nan=0.0)
            hi_a = np.nan_to_num(np.nanmax(aa, 0) + h_a, nan=np.pi / 2)
        raw = lwlr_grid(qr, qa, r, a, y[..., None], w, h_r, h_a, h_b, int(deg))  # (Q, K)
        q_r = np.clip(qr[:, None], lo_r[None], hi_r[None])
        q_a = np.clip(qa[:, None], lo_a[None], hi_a[None])
        v = _bilinear(raw.T.reshape(1, -1, rg.size, ag.size), rg, ag, q_r, q_a)[0]
        if n in ("sigma", "log_sigma"):
            sig = np.maximum(_ROOT_HALF_PI * v, SIGMA_FLOOR)
            v = np.log(sig) if n == "log_sigma" else sig
        tables.append(_finish(n, v).T.reshape(-1, rg.size, ag.size))
    if ext:
        tables.append(np.zeros_like(tables[0]))  # tau2: no repeats, the spread is all in sigma
        names.append("tau2")
    model.tables_ = np.stack(tables).astype(np.float32).astype(np.float64)
    model.param_names_ = names
