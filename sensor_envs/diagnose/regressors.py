"""The regressors of :mod:`~sensor_envs.diagnose.search` and their sufficient statistics.

Time folds with gaps (:func:`time_folds`), a candidate's bins (:func:`bin_candidate`) and main-effect basis
(:func:`rank_basis`), and the per-fold, per-time-block sums from which the search computes each regressor's
cross-fitted held-out ``R^2`` for the observed residuals and for every block sign-flip draw at once. The
method is described in :mod:`~sensor_envs.diagnose.search`, which re-exports the public names.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

__all__ = ["GAP", "N_SEGMENTS", "POLY_DEGREE", "bin_candidate", "interaction_basis", "rank_basis", "time_folds"]

N_SEGMENTS = 6
"""Contiguous time segments of the held-out readings, dealt alternately to the two cross-fitting folds."""
GAP = 0.08
"""Share of each segment's length left out at either end (the gap between fit and scored readings)."""
POLY_DEGREE = 2
"""Degree of the main regressor's Legendre polynomials of a candidate's rank scale (a cubic extrapolates wildly
from one time fold to the next: a trend in time lost its held-out R^2 with it)."""
_RIDGE = 1.0
_NULL_CHUNKS = 8
"""Most contiguous time chunks of the null residual's prediction (fewer, down to 4, when the residuals are
correlated over longer times): each chunk is predicted by a fit that leaves out the chunk and its two
neighbours (:func:`_main_stats`)."""


def bin_candidate(x: NDArray, n_bins: int = 16) -> NDArray[np.int64]:
    """Bin index ``(n,)``: one bin per value (at most ``n_bins`` values), else quantile bins; NaN last."""
    x = np.asarray(x, dtype=np.float64)
    ok = np.isfinite(x)
    out = np.full(x.shape, n_bins, dtype=np.int64)
    if not ok.any():
        return out
    vals = np.unique(x[ok])
    if vals.size <= n_bins:
        out[ok] = np.searchsorted(vals, x[ok])
    else:
        edges = np.unique(np.quantile(x[ok], np.linspace(0, 1, n_bins + 1)[1:-1]))
        out[ok] = np.searchsorted(edges, x[ok], side="right")
    return out


def time_folds(order: NDArray, n_segments: int = N_SEGMENTS, gap: float = GAP) -> NDArray[np.int64]:
    """Fold ``(n,)`` of each reading: 0 or 1 by contiguous time segment, -1 in the gaps at segment ends."""
    rank = np.argsort(np.argsort(np.asarray(order, dtype=np.float64), kind="stable"), kind="stable")
    q = (rank + 0.5) / max(rank.size, 1) * n_segments
    seg = np.minimum(np.floor(q).astype(np.int64), n_segments - 1)
    frac = q - seg
    return np.where((frac < gap) | (frac > 1 - gap), -1, seg % 2).astype(np.int64)


def rank_basis(x: NDArray, degree: int = POLY_DEGREE) -> NDArray[np.float64]:
    """Main-effect basis ``(n, degree + 2)`` of a candidate: 1, Legendre ``P_1 .. P_degree``, NaN indicator.

    The polynomials are of the candidate's mid-rank scale ``u`` in ``[-1, 1]`` (a monotone transform:
    outliers and skewed units do not dominate; ties, e.g. a per-scan value repeated over the bearings,
    share one ``u``); NaN readings get ``u = 0`` and the indicator 1.
    """
    x = np.asarray(x, dtype=np.float64)
    ok = np.isfinite(x)
    u = np.zeros(x.shape)
    if ok.sum() > 1:
        _, inv, cnt = np.unique(x[ok], return_inverse=True, return_counts=True)
        mid = np.cumsum(cnt) - (cnt + 1) / 2.0  # mid-ranks 0 .. n - 1
        u[ok] = 2.0 * mid[inv.ravel()] / (ok.sum() - 1) - 1.0
    basis = np.polynomial.legendre.legvander(u, degree)
    basis[~ok, 1:] = 0.0
    return np.concatenate([basis, (~ok).astype(np.float64)[:, None]], axis=1)


def interaction_basis(main: NDArray, state: NDArray) -> NDArray[np.float64]:
    """Smooth candidate x state basis ``(..., n, p + 4 d)``: the main basis, ``P_j(u) x state`` before its NaN column.

    ``main (..., n, p)`` is :func:`rank_basis` of the candidate (NaN indicator last), ``state (n, 4)`` the
    state feature's smooth basis (``cos``, ``sin`` of ``pi u_s``, ``P1(u_s)``, ``P2(u_s)``): an effect whose
    sign or size follows the state (a bearing's ``cos``, a trend in range), linear or U-shaped in the
    candidate (``P1``, ``P2``: ``d`` = 2), with 8 more coefficients than the main effect, where a binned
    grid needs dozens. The state's own additive pattern is not in it: the
    targets are freed of it first.
    """
    prod = [main[..., j : j + 1] * state for j in range(1, main.shape[-1] - 1)]  # P1 .. P_degree, each x state
    return np.concatenate([main[..., :-1], *prod, main[..., -1:]], axis=-1)


def _group_sums(groups: NDArray, r: NDArray, n_groups: int) -> NDArray[np.float64]:
    """Sums of ``r`` (``(n,)``, or each column of ``(n, S)``) per group index ``groups (n,)``."""
    if r.ndim == 1:
        return np.asarray(np.bincount(groups, weights=r, minlength=n_groups), dtype=np.float64)
    onehot = sparse.csr_matrix((np.ones(groups.size), (groups, np.arange(groups.size))), shape=(n_groups, groups.size))
    return np.asarray(onehot @ r, dtype=np.float64)


def _within_instant(r: NDArray, instant: NDArray) -> NDArray[np.float64]:
    """``r`` (or each column of ``r (n, S)``) minus its time instant's mean (where it has more than one reading)."""
    _, inv, cnt = np.unique(instant, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    mean = _group_sums(inv, r, cnt.size) / (cnt if r.ndim == 1 else cnt[:, None])
    many = cnt[inv] > 1
    return np.where(many if r.ndim == 1 else many[:, None], r - mean[inv], r)


def _free_of_state(r: NDArray, state_bins: list[NDArray], mask: NDArray, passes: int = 2) -> NDArray[np.float64]:
    """``r`` (or each column of ``r (n, S)``) freed of the state features' additive binned pattern (backfitting).

    Misfit along the model's own state is then not credited to a candidate that correlates with the state.
    """
    out = np.asarray(r, dtype=np.float64).copy()
    for _ in range(passes if state_bins else 0):
        for sb in state_bins:
            b = sb[mask]
            s = _group_sums(b, out, int(b.max()) + 1)
            c = np.bincount(b, minlength=b.max() + 1)
            out -= (s / (np.maximum(c, 1) if out.ndim == 1 else np.maximum(c, 1)[:, None]))[b]
    return out


def _main_stats(basis: NDArray, r: NDArray, fold: NDArray, block: NDArray, n_blocks: int) -> tuple[NDArray, ...]:
    """Sufficient statistics of the main regressors (``basis (C, n, p)``) against ``r`` and for the null draws.

    Returns the Gram matrices ``(C, 2, p, p)`` per fold; the sums of ``basis * r`` ``(n_blocks, C, 2, p)``
    per time block and fold and the sums of ``r^2`` ``(C, 2)`` (the observed scores); and the same two of
    each candidate's null residual ``e_c = r - pred_c``, whose block sign-flips are the candidate's null
    draws. ``pred_c`` predicts each of 4 to :data:`_NULL_CHUNKS` contiguous time chunks (a quarter of
    the sign-flip blocks) from a fit that leaves out the chunk and its neighbours (linear beyond the
    fitted range, :func:`_chunk_predict`): an effect of the candidate carries over any distance and is
    removed (flipped, it would widen the null and cap the attainable z near ``sqrt(n_blocks)``), while
    a chance alignment with slow drift does not carry over a whole chunk and stays in ``e_c``
    (removing it would narrow the null: false alarms).
    """
    c, _, p = basis.shape
    bases = [_clip_curvature(basis, fold == a) for a in (0, 1)]  # variant a: fitted on fold a, scores fold b
    gram = np.stack(
        [np.stack([np.einsum("cni,cnj->cij", x[:, fold == f], x[:, fold == f]) for f in (0, 1)], axis=1) for x in bases]
    )
    key = block * 2 + fold
    ids = (key[:, None] * p + np.arange(p)[None]).ravel()
    ridge = np.diag(np.r_[0.0, np.full(p - 1, _RIDGE)])
    n_chunks = int(np.clip(n_blocks // 4, 4, _NULL_CHUNKS))  # each chunk >= ~8 correlation lengths of r
    chunk = np.arange(r.size) * n_chunks // max(r.size, 1)  # readings are in time order
    xr = np.empty((n_blocks, 2, c, 2, p))
    xe = np.empty((n_blocks, 2, c, 2, p))
    ee = np.empty((c, 2))
    size = n_blocks * 2 * p
    for i in range(c):
        e = r.copy()
        for k in range(n_chunks):  # each chunk minus the prediction fitted on the chunks not next to it
            tr, te = np.abs(chunk - k) >= 2, chunk == k
            e[te] -= _chunk_predict(basis[i, tr], r[tr], basis[i, te], ridge)
        e -= e.mean()
        ee[i] = [np.sum(e[fold == f] ** 2) for f in (0, 1)]
        for v, x in enumerate(bases):
            xr[:, v, i] = np.bincount(ids, (x[i] * r[:, None]).ravel(), size).reshape(n_blocks, 2, p)
            xe[:, v, i] = np.bincount(ids, (x[i] * e[:, None]).ravel(), size).reshape(n_blocks, 2, p)
    rr = np.broadcast_to(np.array([np.sum(r[fold == f] ** 2) for f in (0, 1)]), (c, 2))
    return gram, xr, rr, xe, ee


def _clip_curvature(basis: NDArray, fit: NDArray) -> NDArray[np.float64]:
    """``basis (C, n, p)`` with its curvature column ``P2(u)`` at ``u`` clipped to the range of ``fit``'s readings.

    Scoring a fit on one time fold at the other fold's readings, a candidate like time lies partly
    beyond the fitted range there: its trend carries on (``P1``), its curvature is not extrapolated (a
    quadratic extrapolated to the log's ends lost the held-out ``R^2`` of a plain trend in time).
    """
    out = basis.copy()
    if basis.shape[2] < 4:
        return out
    finite = basis[:, :, -1] == 0
    u = basis[:, :, 1]
    lo = np.min(np.where(fit[None] & finite, u, np.inf), axis=1, keepdims=True)
    hi = np.max(np.where(fit[None] & finite, u, -np.inf), axis=1, keepdims=True)
    uc = np.clip(u, np.minimum(lo, hi), np.maximum(lo, hi))
    out[:, :, 2] = np.where(finite, 1.5 * uc**2 - 0.5, 0.0)
    return out


def _chunk_predict(xa: NDArray, ra: NDArray, xb: NDArray, ridge: NDArray) -> NDArray[np.float64]:
    """The main regressor fitted on ``(xa, ra)``, predicted at ``xb``; linear beyond the fitted rank range.

    Inside the candidate's fitted range (its rank scale ``u``, column 1) the full polynomial; beyond it
    the polynomial at the range's end plus the slope of a straight-line fit (a trend in time carries on,
    a curvature is not extrapolated).
    """
    beta = np.linalg.solve(xa.T @ xa + ridge, xa.T @ ra)
    if xa.shape[1] != POLY_DEGREE + 2:  # an interaction basis (:func:`interaction_basis`): no extrapolation rule
        return np.asarray(xb @ beta, dtype=np.float64)
    lin = [0, 1, xa.shape[1] - 1]  # intercept, u, NaN indicator
    slope = np.linalg.solve(xa[:, lin].T @ xa[:, lin] + ridge[np.ix_(lin, lin)], xa[:, lin].T @ ra)[1]
    u = xb[:, 1]
    finite = xa[:, -1] == 0
    lo, hi = (xa[finite, 1].min(), xa[finite, 1].max()) if finite.any() else (0.0, 0.0)
    uc = np.where(xb[:, -1] == 0, np.clip(u, lo, hi), 0.0)
    inside = np.polynomial.legendre.legvander(uc, xb.shape[1] - 2)
    inside = np.concatenate([inside, xb[:, -1:]], axis=1)
    inside[xb[:, -1] == 1, 1:-1] = 0.0
    return np.asarray(inside @ beta + slope * (u - uc), dtype=np.float64)


def _main_r2(gram: NDArray, xr_b: NDArray, rr: NDArray, flips: NDArray) -> NDArray[np.float64]:
    """Cross-fitted ``R^2`` ``(P, C)`` of the main regressors (least squares, small ridge) for each sign-flip.

    ``gram (2, C, 2, p, p)`` and ``xr_b (n_blocks, 2, C, 2, p)`` (block sums of ``basis * r``): per basis
    variant ``a`` (fitted on fold ``a``, :func:`_clip_curvature`) and fold; ``rr (C, 2)``: sums of ``r^2``.
    """
    xr = np.tensordot(flips, xr_b, axes=(1, 0))  # (P, 2, C, 2, p)
    p = gram.shape[-1]
    ridge = np.diag(np.r_[0.0, np.full(p - 1, _RIDGE)])
    out = np.zeros((xr.shape[0], xr.shape[2]))
    for a in (0, 1):
        b = 1 - a
        g, x = gram[a], xr[:, a]
        na, nb = g[:, a, 0, 0], g[:, b, 0, 0]
        if na.min() < 10 or nb.min() < 10:
            return np.full(out.shape, -np.inf)
        beta = np.einsum("cij,...cj->...ci", np.linalg.inv(g[:, a] + ridge), x[..., a, :])
        quad = np.einsum("...ci,cij,...cj->...c", beta, g[:, b], beta)
        sse = rr[..., b] - 2 * np.sum(beta * x[..., b, :], -1) + quad
        mean_a = x[..., a, 0] / na
        sst = rr[..., b] - 2 * mean_a * x[..., b, 0] + nb * mean_a**2
        out += 0.5 * (1.0 - sse / np.maximum(sst, 1e-300))
    return out


def _r2_from_stats(
    cnt: NDArray, sx: NDArray, sxx: NDArray, sr: NDArray, sxr: NDArray, rr: NDArray, shrink: NDArray
) -> NDArray[np.float64]:
    """Cross-fitted ``R^2`` ``(..., R)`` from per-(row, fold, bin) sufficient statistics.

    ``cnt``, ``sx``, ``sxx`` ``(R, 2, nb)`` (counts, sums of ``x``, ``x^2``); ``sr``, ``sxr``
    ``(..., R, 2, nb)`` (sums of ``r``, ``x r``; leading axes: sign-flip draws); ``rr (2,)``: sum of
    ``r^2`` per fold; ``shrink (R,)``: pseudo-readings pulling bin means toward the trend.
    """
    out = np.zeros(sr.shape[:-2])
    for a in (0, 1):  # fit on fold a, score on the other
        b = 1 - a
        na = cnt[:, a].sum(-1)
        if na.min() < 10 or cnt[:, b].sum(-1).min() < 10:
            return np.full(sr.shape[:-2], -np.inf)
        mean_a = sr[..., a, :].sum(-1) / na
        xm = sx[:, a].sum(-1) / na
        slope = (sxr[..., a, :].sum(-1) - na * xm * mean_a) / (sxx[:, a].sum(-1) - na * xm**2 + 1.0)
        rem = sr[..., a, :] - cnt[:, a] * mean_a[..., None] - slope[..., None] * (sx[:, a] - cnt[:, a] * xm[:, None])
        alpha = (mean_a - slope * xm)[..., None] + rem / (cnt[:, a] + shrink[:, None])
        beta = slope[..., None]
        srb, sxrb = sr[..., b, :], sxr[..., b, :]
        sse = rr[..., b] + np.sum(
            -2 * alpha * srb
            - 2 * beta * sxrb
            + alpha**2 * cnt[:, b]
            + 2 * alpha * beta * sx[:, b]
            + beta**2 * sxx[:, b],
            axis=-1,
        )
        sst = rr[..., b] - 2 * mean_a * srb.sum(-1) + cnt[:, b].sum(-1) * mean_a**2
        out += 0.5 * (1.0 - sse / np.maximum(sst, 1e-300))
    return out


def _block_stats(
    bins: NDArray, xs: NDArray | None, r: NDArray, fold: NDArray, block: NDArray, nb: int, n_blocks: int
) -> tuple[NDArray, ...]:
    """Sufficient statistics of rows ``bins (R, n)`` (+ ``xs``) against ``r``: fixed ones and per time block.

    Returns ``cnt, sx, sxx`` ``(R, 2, nb)`` and ``sr_b, sxr_b`` ``(n_blocks, R, 2, nb)`` (sums of ``r`` and
    ``x r`` within each block), so that any block sign-flip of ``r`` is a product with the flips.
    """
    k, n = bins.shape
    size = k * 2 * nb
    ids = (bins + nb * fold[None] + (np.arange(k) * 2 * nb)[:, None]).ravel()
    idb = ids + size * np.tile(block, k)

    def sums(w: NDArray | None, by_block: bool) -> NDArray[np.float64]:
        wf = None if w is None else np.ravel(np.broadcast_to(w, (k, n)))
        if by_block:
            return np.asarray(np.bincount(idb, wf, size * n_blocks), dtype=np.float64).reshape(n_blocks, k, 2, nb)
        return np.asarray(np.bincount(ids, wf, size), dtype=np.float64).reshape(k, 2, nb)

    cnt = sums(None, False)
    sr_b = sums(r[None], True)
    if xs is None:
        z = np.zeros_like(cnt)
        return cnt, z, z, sr_b, np.zeros_like(sr_b)
    return cnt, sums(xs, False), sums(xs * xs, False), sr_b, sums(xs * r[None], True)
