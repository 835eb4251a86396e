"""Surrogate-candidate check of the search: would an unrelated series like the candidate explain as much.

A slow covariate (a random walk, a temperature) and a residual that drifts over the whole log (a real
sensor warming up, a pose estimate wandering) align by chance: two unrelated wandering series look
related (the spurious regression). The block sign-flips break the residual's time structure beyond a block,
the circular shifts wrap it (a drift over the whole log becomes a saw-tooth), and the within-block check
of :func:`~sensor_envs.diagnose.projection.drift_confounded` keeps a candidate that accounts for the drift;
none of them asks how well a series with the candidate's own time structure, drawn independently of the
residual, would do on THIS residual.

This check asks it. Each candidate that is constant within a time instant (a per-scan covariate) is
seen as a series over the instants; an AR(1) law is fitted to it (its lag-one coefficient over consecutive
instants, gaps between the held-out blocks included: a random walk gets a coefficient near 1) and
:data:`N_SURROGATES` independent series are drawn from that law on the same instants. The residual
targets stay as they are (their drift, their correlation, their distribution): only the candidate is
replaced. The statistic is that of the projection test (:mod:`~sensor_envs.diagnose.projection`): the
explained sum of squares of each residual target by the candidate's two-coefficient forms (``P1, P2`` of
its rank scale, alone and times each state factor), each (target, form) cell put on its own scale by a
Gamma law with the moments of its surrogate values, and min-P over the cells against the surrogates'
min-P. Each finding is checked on its own, at ``alpha``, as the within-block check is: a confirmation of
what the family-wise tests found.
A significant finding whose ``p_surrogate`` is not below ``alpha`` is no better than a chance alignment
of a series like it: it is marked a shadow of the drift
(``proxy_of`` :data:`~sensor_envs.diagnose.projection.DRIFT`)
and is not significant. The law only has to describe the candidate, which the log shows, not the residual,
which may drift in any way.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.diagnose.projection import DRIFT, state_factors, time_like
from sensor_envs.diagnose.regressors import rank_basis
from sensor_envs.diagnose.shifts import _gamma_fit_tail, tail_p

__all__ = ["N_SURROGATES", "ar1_surrogates", "instant_series", "surrogate_check"]

N_SURROGATES = 199
"""Independent surrogate series drawn per checked candidate."""
_MIN_INSTANTS = 10


def instant_series(c: NDArray, pos: NDArray, n_instants: int) -> NDArray[np.float64] | None:
    """Values per instant of a candidate constant within each instant, else ``None``.

    ``pos``: each reading's instant in ``[0, n_instants)`` (instants in time order); a value is NaN at an
    instant without a finite reading of the candidate.
    """
    ok = np.isfinite(c)
    lo, hi = np.full(n_instants, np.inf), np.full(n_instants, -np.inf)
    np.minimum.at(lo, pos[ok], c[ok])
    np.maximum.at(hi, pos[ok], c[ok])
    seen = np.isfinite(lo)
    if seen.sum() < _MIN_INSTANTS or np.any(hi[seen] - lo[seen] > 1e-9 * np.maximum(1.0, np.abs(lo[seen]))):
        return None  # a per-reading candidate (e.g. a radar target's speed): the shifts and flips judge it
    return np.where(seen, lo, np.nan)


def ar1_surrogates(t: NDArray, v: NDArray, m: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``(m, T)`` independent draws of the AR(1) law fitted to the series ``v`` at instants ``t`` (any scale).

    The instants' unit is their smallest spacing; a gap of ``g`` units carries a coefficient ``rho^g``.
    ``rho`` is the correlation of each finite value with the previous one over unit gaps (over every
    gap, per median gap, when fewer than 8 are units), in ``[0, 1]``; the draws start from the stationary
    law (a coefficient near 1 gives a random walk plus a slow trend). NaN values are only left out of the fit.
    """
    d = np.diff(t)
    unit = float(d[d > 0].min()) if np.any(d > 0) else 1.0
    gaps = np.clip(np.rint(d / unit), 1, 1e6)
    both = np.isfinite(v[:-1]) & np.isfinite(v[1:])
    unit_pairs = both & (gaps == 1)
    pairs = unit_pairs if unit_pairs.sum() >= 8 else both
    a, b = v[:-1][pairs], v[1:][pairs]
    ok = a.size > 2 and np.std(a) > 0 and np.std(b) > 0
    slope = float(np.clip(np.corrcoef(a, b)[0, 1], 0.0, 1.0)) if ok else 0.0
    rho = slope if unit_pairs.sum() >= 8 else slope ** (1.0 / float(np.median(gaps[pairs])) if pairs.any() else 1.0)
    phi = rho**gaps
    sd = np.sqrt(gaps) if rho >= 1.0 else np.sqrt(1.0 - phi**2)
    e = rng.standard_normal((m, v.size))
    x = np.empty((m, v.size))
    x[:, 0] = 0.0 if rho >= 1.0 else e[:, 0]
    for i in range(1, v.size):
        x[:, i] = phi[i - 1] * x[:, i - 1] + sd[i - 1] * e[:, i]
    return x


def _partial_ess(z: NDArray, y: NDArray, w: NDArray, base: NDArray) -> NDArray[np.float64]:
    """``(S,)`` weighted explained sum of squares of ``y (N,)`` by ``z (S, N, 2)``, both freed of ``base (N, q)``."""
    inv = np.linalg.pinv((base * w[:, None]).T @ base)
    zw = (z * w[None, :, None]).transpose(0, 2, 1)  # (S, 2, N)
    zb = zw @ base
    g = zw @ z - zb @ inv @ zb.transpose(0, 2, 1)
    b = zw @ y - zb @ (inv @ (base.T @ (w * y)))
    det = g[:, 0, 0] * g[:, 1, 1] - g[:, 0, 1] ** 2
    ok = det > 1e-9 * np.maximum(g[:, 0, 0] * g[:, 1, 1], 1e-300)
    num = g[:, 1, 1] * b[:, 0] ** 2 - 2 * g[:, 0, 1] * b[:, 0] * b[:, 1] + g[:, 0, 0] * b[:, 1] ** 2
    return np.where(ok, num / np.where(ok, det, 1.0), 0.0)


def _cells(u: NDArray, cells: list[tuple[NDArray, NDArray]], step: NDArray) -> NDArray[np.float64]:
    """``(S, 2 x cells)`` statistics of the two-coefficient forms at instant ranks ``u (S, T)``.

    ``cells``: per (target, form) cell, per instant the residual's projection on the form's factor ``y``
    (the mean residual for the main form) and its weight ``w`` (the factor's sum of squares). Each cell
    gives two statistics: in levels (freed of a constant: a cause that is the drift), and in first
    differences over the consecutive instants ``step`` (a cause that moves the residual from one instant to
    the next; a drift the candidate does not explain hardly moves there, and a wandering candidate's steps
    do not follow it).
    """
    p = np.stack([u, 1.5 * u**2 - 0.5], axis=-1)  # (S, T, 2): Legendre P1, P2 of the rank scale
    dp = p[:, 1:][:, step] - p[:, :-1][:, step]
    one, one_d = np.ones((u.shape[1], 1)), np.ones((int(step.sum()), 1))
    out = []
    for y, w in cells:
        out.append(_partial_ess(p, y, w, one))
        wd = np.where(
            (w[1:] > 0) & (w[:-1] > 0), 1.0 / (1.0 / np.maximum(w[1:], 1e-300) + 1.0 / np.maximum(w[:-1], 1e-300)), 0.0
        )
        out.append(_partial_ess(dp, (y[1:] - y[:-1])[step], wd[step], one_d))
        out.append(_partial_ess(dp, y[1:][step], np.where(w[:-1] > 0, w[1:], 0.0)[step], one_d))
    return np.stack(out, axis=1)


def _ranks(x: NDArray, w: NDArray) -> NDArray[np.float64]:
    """Mid-rank scale in ``[-1, 1]`` of each row of ``x (S, T)``, instant ``t`` weighing ``w[t]`` readings."""
    order = np.argsort(x, axis=1, kind="stable")
    ws = w[order]
    mid = np.cumsum(ws, axis=1) - (ws + 1) / 2.0
    u = np.empty(x.shape)
    np.put_along_axis(u, order, 2.0 * mid / max(float(w.sum()) - 1, 1.0) - 1.0, axis=1)
    return u


def surrogate_check(
    effects: list[dict[str, Any]],
    cands: dict[str, NDArray],
    targets: dict[str, tuple[NDArray, NDArray]],
    state: dict[str, NDArray],
    order: NDArray,
    alpha: float,
    rng: np.random.Generator,
    n_surrogates: int = N_SURROGATES,
) -> None:
    """Mark significant findings that series like their candidate, drawn independently, match as well.

    Sets ``p_surrogate`` on every checked effect; a significant one at ``p_surrogate >= alpha`` becomes
    ``proxy_of`` :data:`~sensor_envs.diagnose.projection.DRIFT`, not significant (see the module).

    Args:
        effects: the ranking's effect dicts (``name``, ``significant``, ``proxy_of``).
        cands: candidate values on the search's readings (time order).
        targets: ``{metric: (r, mask)}`` as the projection tests take them (centred, freed of the state's
            pattern, on the finite readings ``mask``).
        state: state features on the search's readings (the forms' factors).
        order: time-order key of the readings (its integer part: the instant).
        alpha: level of the check.
        rng: generator of the surrogates.
        n_surrogates: surrogate series per candidate.
    """
    t, pos = np.unique(np.floor(order), return_inverse=True)  # the instants in time order; each reading's
    step = np.rint(np.diff(t) / max(float(np.diff(t).min(initial=1.0)), 1e-300)) == 1
    t_rank = rank_basis(np.asarray(order, dtype=np.float64), degree=1)[:, 1]
    factors = {"main": np.ones(pos.size), **state_factors(state)}
    checked: dict[str, NDArray] = {}
    for name, c in cands.items():
        if time_like(c, t_rank):
            continue  # time itself: the drift's own name
        series = instant_series(c, pos, t.size)
        if series is not None:
            checked[name] = series
    if not checked:
        return
    p_of = {}
    for name, v in checked.items():
        ok = np.isfinite(cands[name])
        cells = []
        for r, mask in targets.values():
            sel = mask & ok  # the candidate's NaN readings are 0 in its forms
            rr = np.zeros(pos.size)
            rr[mask] = r
            for f in factors.values():
                fr = np.bincount(pos[sel], weights=f[sel] * rr[sel], minlength=t.size)
                f2 = np.bincount(pos[sel], weights=f[sel] ** 2, minlength=t.size)
                cells.append((np.where(f2 > 0, fr / np.maximum(f2, 1e-300), 0.0), f2))
        w = np.bincount(pos[ok], minlength=t.size).astype(np.float64)
        draws = np.vstack([np.nan_to_num(v)[None], ar1_surrogates(t, v, n_surrogates, rng)])
        ess = _cells(_ranks(draws, w), cells, step)  # (1 + S, cells): row 0 observed
        tails = -np.log(np.maximum(_gamma_fit_tail(ess[1:], ess).min(axis=1), 1e-300))  # min-P over the cells
        p_of[name] = float(tail_p(tails[1:], tails[:1])[0])
    for e in effects:
        if e["name"] not in p_of:
            continue
        e["p_surrogate"] = p_of[e["name"]]
        if e["significant"] and e.get("proxy_of") is None and e["p_surrogate"] >= alpha:
            e.update(proxy_of=DRIFT, significant=False)
