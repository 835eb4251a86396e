"""Circular-shift null of the search's tests: the alignment broken, every series' time structure kept.

The block sign-flips of :mod:`~sensor_envs.diagnose.search` keep a residual's correlation within a block
and break it across blocks. A residual that drifts over longer than a block (a slow drift shared by
neighbouring time segments, hence by both cross-fitting folds) has a wider null than the flips give: a
candidate that wanders slowly (a random walk, time itself, lane changes clustered in time) aligns with
that drift by chance more often than the flips say, and looks significant.

A circular shift of each residual target along time, relative to the candidates and the folds, keeps the
residual's whole time structure (its drift, its correlation, its distribution) and the candidates', and
breaks only their alignment. Each shift's statistics are computed exactly as the observed ones (the same
folds, regressors, forms and state freeing; :func:`shift_p_values` for the held-out scores,
:func:`projection_shift_p` for the projection tests), every cell is put on its own scale by its shifted
values (a random walk whose chance alignments are large does not set the bar for a cause), and the
family-wise p-value is Westfall-Young max-T over the shifts. Shifts are drawn in :data:`SHIFT_RANGE` of a
target's length (near 0 or the length they would keep the observed alignment). A p-value is the share of
shifts whose maximum reaches the candidate's; where none does, the Gumbel law of the maxima (moments
matched) gives its tail below ``1 / (shifts + 1)``, so strong findings keep their order.

The search confirms with shifts what the flips find: a finding is significant when both nulls agree.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.special import gammaincc

from sensor_envs.diagnose.projection import candidate_forms, state_factors
from sensor_envs.diagnose.regressors import _clip_curvature, _free_of_state, _main_r2, _r2_from_stats, _within_instant

__all__ = ["N_SHIFTS", "SHIFT_RANGE", "projection_shift_p", "shift_p_values", "tail_p"]

N_SHIFTS = 99
"""Most circular shifts of the residuals (p-values resolve down to ``1 / (N_SHIFTS + 1)``)."""
SHIFT_RANGE = (0.2, 0.8)
"""Shifts drawn uniformly in this share of a target's length (a linear trend shifted by a fifth of its
length is uncorrelated with itself, by a tenth it keeps a correlation of 0.46)."""


def tail_p(null_max: NDArray, obs: NDArray) -> NDArray[np.float64]:
    """p-values of ``obs`` against the null maxima ``null_max (S,)``: empirical; a Gumbel tail where none reach it."""
    exceed = np.sum(null_max[:, None] >= obs[None], axis=0)
    emp = (1 + exceed) / (1 + null_max.size)
    finite = null_max[np.isfinite(null_max)]
    sd = float(np.std(finite)) if finite.size > 1 else 0.0
    if sd <= 0:
        return np.asarray(emp, dtype=np.float64)
    beta = sd * np.sqrt(6.0) / np.pi
    loc = float(np.mean(finite)) - 0.5772156649 * beta
    gumbel = -np.expm1(-np.exp(-(obs - loc) / beta))
    return np.where(exceed > 0, emp, np.clip(gumbel, 1e-12, emp))


def _ls_scores(basis: NDArray, gram: NDArray, r: NDArray, fold: NDArray) -> NDArray[np.float64]:
    """``(S, C)`` cross-fitted ``R^2`` of least-squares regressors ``basis (C, n, p)`` on each column of ``r``."""
    c, _, p = basis.shape
    s = r.shape[1]
    xr = np.empty((s, 2, c, 2, p))
    x0 = _clip_curvature(basis, fold == 0)
    # variant 1 differs from variant 0 in the curvature column only (intercept, P1, P2 and the NaN indicator)
    lead = np.concatenate([basis[:, :, :3], basis[:, :, -1:]], axis=2) if p >= 4 else None
    curv1 = _clip_curvature(lead, fold == 1)[:, :, 2] if lead is not None else None
    for f in (0, 1):
        sel = fold == f
        rs = np.ascontiguousarray(r[sel])
        flat = np.ascontiguousarray(x0.transpose(1, 0, 2)[sel]).reshape(int(sel.sum()), c * p)
        xr[:, 0, :, f] = (flat.T @ rs).T.reshape(s, c, p)  # one product for every shift
        xr[:, 1, :, f] = xr[:, 0, :, f]
        if curv1 is not None:
            xr[:, 1, :, f, 2] = (curv1[:, sel] @ rs).T
    rr = np.stack([np.sum(r[fold == f] ** 2, axis=0) for f in (0, 1)], axis=-1)[:, None, :]  # (S, 1, 2)
    return _main_r2(gram, xr, rr, np.eye(s))


def _grid_scores(stat: tuple[NDArray, ...], joint: NDArray, w: NDArray, fold: NDArray) -> NDArray[np.float64]:
    """``(S, C)`` cross-fitted ``R^2`` of the candidate x state grids ``joint (C, n)`` on each column of ``w``."""
    cnt, sx, sxx, _, _, _, shrink = stat
    c, nb = cnt.shape[0], cnt.shape[2]
    ids = (joint + nb * fold[None] + (np.arange(c) * 2 * nb)[:, None]).ravel()
    m = sparse.csr_matrix((np.ones(ids.size), (ids, np.tile(np.arange(w.shape[0]), c))), shape=(c * 2 * nb, w.shape[0]))
    sr = np.asarray(m @ w).T.reshape(w.shape[1], c, 2, nb)
    rr = np.stack([np.sum(w[fold == f] ** 2, axis=0) for f in (0, 1)], axis=-1)[:, None, :]
    return _r2_from_stats(cnt, sx, sxx, sr, np.zeros_like(sr), rr, shrink)


def _shifted_scores(d: Any, targets: list[dict[str, Any]], stats: list, fracs: NDArray) -> NDArray[np.float64]:
    """``(S, C, m, 1 + 2 S_state)`` held-out scores of every candidate on each shift of every target."""
    n_state = len(d.state_bins)
    out = np.full((fracs.size, len(d.names), len(targets), 1 + 2 * n_state), -np.inf)
    smooth = [d.smooth_basis(s) for s in range(n_state)]  # (C, n, p) each, shared by the targets
    grid = [d.grid_cells(s) for s in range(n_state)]
    for j, t in enumerate(targets):
        rc, mask, fold = _shifted(t["r"], fracs, d.state_bins, t["mask"]), t["mask"], t["fold"]
        w = _within_instant(rc, t["instant"])
        row = stats[j]
        out[:, :, j, 0] = _ls_scores(d.main_basis[:, mask], row[0][0], rc, fold)
        for s in range(n_state):
            out[:, :, j, 1 + s] = _grid_scores(row[1 + s], grid[s][:, mask], w, fold)
            out[:, :, j, 1 + n_state + s] = _ls_scores(smooth[s][:, mask], row[1 + n_state + s][0], rc, fold)
    return out


def shift_p_values(
    d: Any,
    targets: list[dict[str, Any]],
    stats: list,
    observed: NDArray,
    finite: NDArray,
    rng: np.random.Generator,
    n_shifts: int = N_SHIFTS,
) -> NDArray[np.float64]:
    """Family-wise p-values ``(C,)`` of the candidates' held-out scores under circular shifts of the targets.

    Each (candidate, target, regressor) cell is studentised by its own shifts (median, 95th percentile;
    the spread floored at half the median spread of the same target and regressor over the candidates),
    so a random walk whose chance alignments with a drift are large is measured on its own scale and does
    not set the bar for the others; the p-value is Westfall-Young max-T of those ``z`` over the shifts.

    Args:
        d: the search's design (candidates' bases and bins, state features).
        targets: per residual target, ``r`` (the centred residual freed of its state pattern, on its scored
            readings in time order: what is shifted), ``mask`` (those readings among the search's), ``fold``,
            ``instant``.
        stats: the observed sufficient statistics (their Gram matrices and grid counts are reused).
        observed: the observed scores ``(C, m, F)``.
        finite: the cells ``(C, m, F)`` that have a score.
        rng: generator of the shifts.
        n_shifts: shifts drawn.
    """
    fracs = rng.uniform(*SHIFT_RANGE, size=n_shifts)
    shifted = _shifted_scores(d, targets, stats, fracs)  # every shift at once: one product per basis
    ok = finite & np.isfinite(shifted).all(axis=0)
    q50, q95 = np.percentile(np.where(ok[None], shifted, 0.0), [50, 95], axis=0)
    sd = q95 - q50
    floor = np.array(
        [
            [np.median(sd[:, j, f][ok[:, j, f]]) if ok[:, j, f].any() else 0.0 for f in range(sd.shape[2])]
            for j in range(sd.shape[1])
        ]
    )
    sd = np.maximum(sd, np.maximum(0.5 * floor[None], 1e-9)) / 1.645
    z_obs = np.where(ok, (observed - q50) / sd, -np.inf).reshape(observed.shape[0], -1).max(axis=1)
    null = np.where(ok[None], (shifted - q50[None]) / sd[None], -np.inf).reshape(n_shifts, -1).max(axis=1)
    return tail_p(null, z_obs)


def _shifted(r: NDArray, fracs: NDArray, state_bins: list[NDArray], mask: NDArray) -> NDArray[np.float64]:
    """``(n, S)``: ``r`` (on ``mask``'s readings) circularly shifted by each share in ``fracs``.

    Each shift is centred and freed of the state bins' pattern, as the observed targets are.
    """
    shifted = np.stack([np.roll(r, int(round(f * r.size))) for f in fracs], axis=1)
    return _free_of_state(shifted - shifted.mean(axis=0), state_bins, mask)


def _gamma_fit_tail(null: NDArray, x: NDArray) -> NDArray[np.float64]:
    """Upper tail at ``x`` of the Gamma law with the mean and variance of ``null (S, T)`` (per column ``T``)."""
    mean, var = null.mean(axis=0), null.var(axis=0)
    ok = (mean > 0) & (var > 0)
    m, v = np.where(ok, mean, 1.0), np.where(ok, var, 1.0)
    return np.where(ok, gammaincc(m**2 / v, np.maximum(x, 0.0) / (v / m)), 1.0)


def projection_shift_p(
    targets: dict[str, tuple[NDArray, NDArray]],
    cands: dict[str, NDArray],
    state: dict[str, NDArray],
    state_bins: list[NDArray],
    confirm: list[str],
    rng: np.random.Generator,
    n_shifts: int = N_SHIFTS,
) -> dict[str, float]:
    """Family-wise p-values of the ``confirm`` candidates' projection tests under circular shifts.

    Every (candidate, target, form) test's explained sum of squares is computed on each shift of the
    target; a Gamma law with the moments of its shifted values gives each test's tail (its own scale, so a
    random walk whose chance alignments with a drift are large does not set the bar for the others); the
    p-value is Westfall-Young min-P of those tails over the shifts.

    Args:
        targets: ``{metric: (r, mask)}``: each residual target as the projection tests take it (centred,
            freed of its state pattern, on its finite readings ``mask``, in time order).
        cands: candidate values on the search's readings.
        state: state features on the search's readings (the forms' factors).
        state_bins: the state features' bins (the targets are freed of their pattern, as the observed ones).
        confirm: candidates whose p-values are returned.
        rng: generator of the shifts.
        n_shifts: shifts drawn.
    """
    factors = state_factors(state)
    fracs = rng.uniform(*SHIFT_RANGE, size=n_shifts)
    low = np.ones(n_shifts + 1)
    best = {c: 1.0 for c in confirm}
    for r, mask in targets.values():
        rs = np.column_stack([r, _shifted(r, fracs, state_bins, mask)])  # column 0: the observed alignment
        for name, c in cands.items():
            qs = []
            for x in candidate_forms(c, factors).values():
                q, tri = np.linalg.qr(x[mask] - x[mask].mean(axis=0))
                qs.append(q[:, np.abs(np.diag(tri)) > 1e-9 * max(float(np.abs(tri).max(initial=0.0)), 1e-300)])
            if not any(q.shape[1] for q in qs):
                continue
            proj = rs.T @ np.concatenate(qs, axis=1)  # (1 + S, columns of every form): one product
            ends = np.cumsum([q.shape[1] for q in qs])
            ess = np.stack(
                [np.sum(proj[:, e - q.shape[1] : e] ** 2, axis=1) for q, e in zip(qs, ends, strict=True) if q.shape[1]],
                axis=1,
            )  # explained sum of squares of each form, observed (row 0) and per shift
            tail = _gamma_fit_tail(ess[1:], ess)
            np.minimum(low[1:], tail[1:].min(axis=1), out=low[1:])
            if name in best:
                best[name] = min(best[name], float(tail[0].min()))
    null = -np.log(np.maximum(low[1:], 1e-300))
    p = tail_p(null, -np.log(np.maximum([best[c] for c in confirm], 1e-300)))
    return {c: float(v) for c, v in zip(confirm, p, strict=True)}
