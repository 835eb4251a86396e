"""The search of ``diagnose``: score candidate causes against a model's held-out residuals, test them.

**Targets.** Every residual metric of the :class:`~sensor_envs.diagnose.core.Evaluation` is a target;
the adapter states each metric's kind (``mean``: a signed residual; ``spread``: a transform of its
size such as ``sqrt(|residual| / sigma)``; ``rate``: ``1{event} - P(event)``; ``score``: per-reading
excess NLL), so an effect on the spread or on a rate is as visible as one on the mean.

**Learner.** For a candidate ``c`` and a target ``r``, two regressors are cross-fitted by folds:

* main: ``r ~ a + b c + g(bin(c))``, a linear trend (it extrapolates a real trend, e.g. in time,
  to the other fold) plus a binned correction (10 quantile bins, bin means of the trend's remainder
  shrunk toward 0 with ``10 x D`` pseudo-readings, ``D`` the mean run length of equal consecutive
  values: a per-scan covariate repeated over K bearings carries one scan's information, not K
  readings'): monotone, U-shaped and step effects alike;
* interaction with each of the model's state features ``s`` (e.g. bearing sector, range, azimuth),
  in two forms: ``r ~ h(bin(c), bin(s))`` on a 6 x 8 grid (any shape, many cells), and a smooth one,
  the main basis plus ``P1(u_c), P2(u_c) x (cos, sin of pi u_s, P1(u_s), P2(u_s))`` (8 more coefficients: an
  effect whose sign follows the bearing, the azimuth side or the range, with zero mean over a scan or
  a cycle, is seen at a strength the grid's cells dilute).

Every target is first freed of the additive binned pattern of the state features (misfit along the
model's own state, e.g. a kernel width, is not credited to a candidate that correlates with the state).

The score of a candidate is the largest held-out ``R^2`` over its regressors and the targets.

**Folds with gaps.** The held-out readings, in time order, are cut into :data:`N_SEGMENTS`
contiguous segments dealt alternately to the two folds, and the readings within :data:`GAP` of a
segment boundary are left out of both: a candidate that follows time cannot interpolate slow drift
between neighbouring blocks, it must carry over to a distant part of the log.

**Significance.** A block sign-flip test (a wild block bootstrap): the centred residual targets are
multiplied by random signs, one sign per contiguous time block (:data:`N_BLOCKS` blocks of the
held-out readings in time order), all candidates alike. Within a block the residuals keep their
correlation (slow drift, AR(1), a scan's shared offset), across blocks any alignment with a candidate
is broken, and the candidates keep their own time structure (a random walk stays a random walk, a
trend stays a trend), so the null spread of a score is that of a time-correlated residual. Each
(candidate, target, regressor) score is studentised by its own null distribution (``z``), so a
target whose scores vary widely under the null (e.g. a drifting range residual) does not drown the
others; the adjusted p-value is Westfall-Young max-T of ``z`` over all of them. Where a drift outlasts
the blocks the flips' null is too narrow, so what they find is confirmed by circular shifts of the
residuals relative to the candidates (:mod:`~sensor_envs.diagnose.shifts`: every series keeps its whole
time structure); the p-value is the larger of the two. Candidates are ranked by ``z``, except that the
significant ones come first: those with ``p < alpha / 10`` before the others, each group ordered by its
held-out ``R^2`` (the largest effect first: the loop adds in this order).

**A second test** (:mod:`~sensor_envs.diagnose.projection`): every candidate in a few two-coefficient
forms, in sample, on every reading, with the same kind of block sign-flips and min-P over all its tests,
confirmed by shifts in the same way; a small effect of a simple form that the held-out scores cannot
resolve is found there. A candidate is significant when either test finds it at ``alpha / 2`` (``test``:
which one; ``p_search``, ``p_projection``); partial projection tests then tell a cause from its noisy copy.

**Surrogate check** (:mod:`~sensor_envs.diagnose.surrogates`): a significant candidate that is one value
per instant is tested against independent series drawn from an AR(1) law fitted to it, on the residuals
as they are; one no better than such series is a shadow of the drift, not significant.

**Conditional check.** Among the top candidates, and the candidates whose rank scale is correlated
(>= 0.5) with a top one, ``i`` is a *proxy* of ``j`` when, once ``j``'s fit is removed, ``i`` explains
less than a fifth of its own score and less than ``j`` does given ``i``; a proxy is not significant and
is ranked below its cause, and a cause that the test had not found itself takes its significant proxy's
finding (``via_proxy``): the effect was found, the conditional check says whose it is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from sensor_envs.diagnose.projection import (
    DRIFT,
    PROXY_CORR,
    combine_tests,
    drift_confounded,
    inherit,
    projection_proxies,
    projection_tests,
)
from sensor_envs.diagnose.projection import FLIPS as PROJECTION_FLIPS
from sensor_envs.diagnose.regressors import (
    _RIDGE,
    GAP,
    N_SEGMENTS,
    _block_stats,
    _free_of_state,
    _main_r2,
    _main_stats,
    _r2_from_stats,
    _within_instant,
    bin_candidate,
    interaction_basis,
    rank_basis,
    time_folds,
)
from sensor_envs.diagnose.regressors import POLY_DEGREE as POLY_DEGREE
from sensor_envs.diagnose.shifts import N_SHIFTS, projection_shift_p, shift_p_values
from sensor_envs.diagnose.surrogates import surrogate_check
from sensor_envs.inputs import InputError

__all__ = ["Ranking", "DEFAULTS", "bin_candidate", "rank_basis", "rank_candidates", "time_folds", "N_SEGMENTS", "GAP"]

DEFAULTS: dict[str, Any] = {
    "n_permutations": 499,
    "n_shifts": N_SHIFTS,
    "alpha": 0.05,
    "min_score": 0.001,
    "max_add": 3,
}
"""The one source of the search's defaults: :func:`rank_candidates`, :func:`~sensor_envs.diagnose.core.run_diagnose`,
``sensor-envs diagnose`` and ``benchmarks/diagnose_suite.py`` all take theirs from here (the suite measures
what a user's command does). ``min_score`` is a held-out ``R^2`` per reading: an effect of 0.3 residual sd
across its cause's range explains about 0.003-0.01 of a lidar residual's variance."""

N_BLOCKS = 32
"""Most contiguous time blocks of the held-out readings whose residual signs are flipped together; fewer
(down to :data:`MIN_BLOCKS`) when the residuals are correlated over longer times (:func:`n_flip_blocks`)."""
MIN_BLOCKS = 16
_SHRINK = 10.0
_INT_BINS = (6, 8)
_TOP_COND = 5


@dataclass
class _Design:
    """The regressors of one ranking: main rows (one per candidate) and interaction rows (candidate x state)."""

    names: list[str]
    main_basis: NDArray[np.float64]  # (C, n, p) intercept, Legendre polynomials of the rank scale, NaN indicator
    int_cbins: NDArray[np.int64]  # (C, n) coarse candidate bins
    deff: NDArray[np.float64]  # (C,) readings per run of equal values (design effect of repeated values)
    state_bins: list[NDArray[np.int64]]  # per state feature (n,)
    state_basis: list[NDArray[np.float64]]  # per state feature (n, 4): cos, sin of pi u, P1(u), P2(u) of its ranks
    state_names: list[str]

    def grid_cells(self, s: int) -> NDArray[np.int64]:
        """``(C, n)``: every candidate's cell of its coarse-bin x state-feature ``s`` grid."""
        return self.int_cbins * (_INT_BINS[1] + 1) + self.state_bins[s][None]

    def smooth_basis(self, s: int) -> NDArray[np.float64]:
        """``(C, n, p + 4)``: every candidate's smooth interaction basis with state feature ``s``."""
        return interaction_basis(self.main_basis, self.state_basis[s][None])


def _design(cands: dict[str, NDArray], names: list[str], state: dict[str, NDArray]) -> _Design:
    nc, ns = _INT_BINS
    return _Design(
        names=names,
        main_basis=np.stack([rank_basis(cands[c]) for c in names]),
        int_cbins=np.stack([bin_candidate(cands[c], nc) for c in names]),
        deff=np.array([_design_effect(cands[c]) for c in names]),
        state_bins=[bin_candidate(v, ns) for v in state.values()],
        state_basis=[_state_basis(v) for v in state.values()],
        state_names=list(state),
    )


def _state_basis(x: NDArray) -> NDArray[np.float64]:
    """``(n, 4)``: ``cos(pi u)``, ``sin(pi u)``, ``P1(u)``, ``P2(u)`` of a state feature's rank scale ``u``.

    A smooth interaction basis: the first two carry a sign that follows the bearing (a circular state,
    e.g. ``cos(bearing - phase)``), the last two a trend or curvature along range or incidence.
    """
    u = rank_basis(x, 1)[:, 1]
    return np.stack([np.cos(np.pi * u), np.sin(np.pi * u), u, 1.5 * u**2 - 0.5], axis=1)


def _design_effect(x: NDArray) -> float:
    """Readings per independent unit of information in a candidate's values, in time order.

    The mean run length of equal consecutive values (e.g. the bearings of a scan sharing a covariate)
    times the AR(1) variance inflation ``(1 + rho) / (1 - rho)`` of the run values (capped at 20): a slow
    candidate's bins gather neighbouring times, whose residuals share drift, so their means are noisier
    than their counts suggest.
    """
    x = np.nan_to_num(np.asarray(x, dtype=np.float64), nan=np.inf)
    change = np.flatnonzero(x[1:] != x[:-1]) + 1
    runs = x[np.concatenate([[0], change])]
    runs = runs[np.isfinite(runs)]
    infl = 1.0
    if runs.size > 10 and runs.std() > 0:
        rho = float(np.clip(np.corrcoef(runs[1:], runs[:-1])[0, 1], 0.0, 0.95))
        infl = min((1 + rho) / (1 - rho), 20.0)
    return x.size / (1 + change.size) * infl


def n_flip_blocks(series: list[NDArray], chunks: int = 96) -> int:
    """Blocks for the sign-flip test: each block at least twice the residuals' correlation length.

    Each residual series (in time order) is averaged in ``chunks`` equal parts and freed of a linear
    trend; the largest lag-1 autocorrelation ``rho`` of those means over the series gives a
    correlation length of ``(1 + rho) / (1 - rho)`` chunks. At least :data:`MIN_BLOCKS`: with fewer,
    no sign pattern is rare enough for p < 0.01.
    """
    return int(np.clip(round(chunks / (2 * _correlation_length(series, chunks))), MIN_BLOCKS, N_BLOCKS))


def drift_outlasts_blocks(series: list[NDArray], chunks: int = 96) -> bool:
    """Whether the residuals stay correlated over more than :data:`MIN_BLOCKS` blocks can absorb.

    The blocks are then shorter than twice the correlation length, the sign flips' null is too narrow for a
    covariate that wanders with the drift, and a finding needs evidence within the blocks
    (:func:`~sensor_envs.diagnose.projection.drift_confounded`).
    """
    return chunks / (2 * _correlation_length(series, chunks)) < MIN_BLOCKS


def _correlation_length(series: list[NDArray], chunks: int) -> float:
    """The largest correlation length over ``series``, in chunks (see :func:`n_flip_blocks`)."""
    length = 1.0
    for r in series:
        if r.size < 4 * chunks:
            continue
        m = np.array([c.mean() for c in np.array_split(r, chunks)])  # one mean per chunk
        u = np.arange(chunks, dtype=np.float64)
        m = m - np.polyval(np.polyfit(u, m, 1), u)  # a trend is a candidate's effect, not correlation
        if m.std() > 0:
            rho = float(np.clip(np.corrcoef(m[1:], m[:-1])[0, 1], 0.0, 0.98))
            length = max(length, (1 + rho) / (1 - rho))
    return length


def _all_stats(d: _Design, targets: list, n_blocks: tuple[int, int]) -> list[list[tuple[NDArray, ...]]]:
    """Per target, per regressor (main, each state's grid, each state's smooth interaction): block statistics.

    ``n_blocks``: blocks of the main regressors' and of the grids' targets. The grids see the
    within-instant residual (an instant's shared drift left out); the smooth interactions, few
    coefficients, see the residual itself, with the main regressors' blocks.
    """
    nc, ns = _INT_BINS
    nbi = (nc + 1) * (ns + 1)
    sh_int = _SHRINK * np.maximum(1.0, d.deff / ns)
    out = []
    smooth = [d.smooth_basis(s) for s in range(len(d.state_bins))]  # (C, n, p) each, shared by the targets
    for r, mask, variants, fold, block, block_int in targets:
        row: list[tuple[NDArray, ...]] = [_main_stats(d.main_basis[:, mask], r, fold, block, n_blocks[0])]
        for s, rv in enumerate(variants):
            joint = d.grid_cells(s)[:, mask]
            row.append(
                (
                    *_block_stats(joint, None, rv, fold, block_int, nbi, n_blocks[1]),
                    np.array([np.sum(rv[fold == f] ** 2) for f in (0, 1)]),
                    sh_int,
                )
            )
        row += [_main_stats(b[:, mask], r, fold, block, n_blocks[0]) for b in smooth]
        out.append(row)
    return out


def _scores(stats: list, flips: tuple[NDArray, NDArray], n_cand: int, null: bool = True) -> NDArray[np.float64]:
    """``(P, C, m, 1 + 2 S)`` scores (main, S grids, S smooth interactions) for block sign-flips of the targets.

    ``flips``: ``(P, blocks)`` signs for the main regressors' targets and for the interactions' targets
    (drawn independently: the max over cells is then, if anything, conservative). ``null``: the main
    regressors' draws flip each candidate's null residual (:func:`_main_stats`); ``False``: the target
    itself (the observed scores, with all signs +1).
    """
    m, f = len(stats), len(stats[0])
    out = np.full((flips[0].shape[0], n_cand, m, f), -np.inf)
    for j, row in enumerate(stats):
        for g, st in enumerate(row):
            if len(st) == 5:  # least squares on a basis: the main regressor, a smooth interaction
                gram, xr, rr, xe, ee = st
                out[:, :, j, g] = _main_r2(gram, xe, ee, flips[0]) if null else _main_r2(gram, xr, rr, flips[0])
                continue
            cnt, sx, sxx, sr_b, sxr_b, rr, shrink = st
            fl = flips[1]
            sr = np.tensordot(fl, sr_b, axes=(1, 0))
            sxr = np.tensordot(fl, sxr_b, axes=(1, 0))
            out[:, :, j, g] = _r2_from_stats(cnt, sx, sxx, sr, sxr, rr, shrink)
    return out


@dataclass
class Ranking:
    """Candidate effects scored on one evaluation, best first (``refused``: candidates not tested, with why)."""

    effects: list[dict[str, Any]]
    alpha: float
    min_score: float
    n_permutations: int
    refused: list[dict[str, str]]
    n_blocks: int = 0

    def significant(self) -> list[dict[str, Any]]:
        """The effects with ``p_value < alpha`` and ``score >= min_score`` (proxies excluded), best first."""
        return [e for e in self.effects if e["significant"]]


def _refusal(x: NDArray) -> str | None:
    """Why a candidate cannot be tested (too few distinct values), or ``None``."""
    f = np.asarray(x, dtype=np.float64)
    f = f[np.isfinite(f)]
    if f.size == 0:
        return "no finite value"
    vals, counts = np.unique(f, return_counts=True)
    if vals.size < 2:
        return f"a single distinct value ({vals[0]:.6g})"
    if counts.max() > 0.99 * f.size:
        return f"{counts.max() / f.size:.1%} of its values equal {vals[np.argmax(counts)]:.6g}"
    return None


def _form_basis(d: _Design, i: int, form: int, mask: NDArray) -> NDArray[np.float64]:
    """Smooth regressors of candidate ``i`` in ``form`` (0: main; ``1 + s``: with its state-``s`` products).

    The state's own pattern is not in it (the targets are freed of it): the smooth interaction basis of
    the scores (:func:`~sensor_envs.diagnose.regressors.interaction_basis`).
    """
    main = d.main_basis[i, mask]
    if form == 0:
        return main
    return interaction_basis(main, d.state_basis[(form - 1) % len(d.state_basis)][mask])


def _cond(
    di: _Design, i: int, fi: int, dj: _Design, j: int, fj: int, r: NDArray, mask: NDArray, fold: NDArray
) -> float:
    """Conditional importance of candidate ``i`` (form ``fi``) given ``j`` (form ``fj``).

    The held-out loss increase when ``i`` is dropped from a joint least-squares model of both (smooth
    regressors, :func:`_form_basis`), relative to the loss of ``j``'s model alone; cross-fitted over
    the two time folds.
    """
    bj = _form_basis(dj, j, fj, mask)
    both = np.concatenate([bj, _form_basis(di, i, fi, mask)[:, 1:]], axis=1)
    out = 0.0
    for a in (0, 1):
        fa, fb = fold == a, fold == 1 - a
        sse_j = np.sum((r[fb] - _fit_predict(bj, r, fa)[fb]) ** 2)
        sse_ij = np.sum((r[fb] - _fit_predict(both, r, fa)[fb]) ** 2)
        out += 0.5 * (1 - sse_ij / max(sse_j, 1e-300))
    return float(out)


def _fit_predict(basis: NDArray, r: NDArray, fa: NDArray) -> NDArray[np.float64]:
    """The main regressor (least squares on ``basis (n, p)``, small ridge) fitted on ``fa``, predicted everywhere."""
    xa = basis[fa]
    ridge = np.diag(np.r_[0.0, np.full(basis.shape[1] - 1, _RIDGE)])
    beta = np.linalg.solve(xa.T @ xa + ridge, xa.T @ r[fa])
    return np.asarray(basis @ beta, dtype=np.float64)


def check_search_options(
    n_permutations: Any,
    n_shifts: Any,
    alpha: Any,
    min_score: Any,
    max_add: Any = None,
    names: dict[str, str] | None = None,
) -> None:
    """Reject search options that cannot give a test (an :class:`~sensor_envs.inputs.InputError` naming one).

    ``n_permutations`` an integer >= 19 with ``1 / (n_permutations + 1) < alpha``; ``n_shifts`` 0 (none)
    or an integer in 19 to 10,000; ``alpha`` in (0, 1); ``min_score`` finite and < 1; ``max_add`` (unless
    ``None``) an integer >= 1. ``names``: how the message names each argument (e.g. the CLI's
    ``--permutations``; default the argument's own name).
    """
    name = {k: (names or {}).get(k, k) for k in ("n_permutations", "n_shifts", "alpha", "min_score", "max_add")}

    def whole(v: Any) -> bool:
        return isinstance(v, (int, np.integer)) and not isinstance(v, bool)

    if max_add is not None and (not whole(max_add) or max_add < 1):
        raise InputError(f"{name['max_add']}: expected an integer >= 1, got {max_add!r}")
    if not whole(n_permutations) or n_permutations < 19:
        raise InputError(f"{name['n_permutations']}: expected an integer >= 19, got {n_permutations!r}")
    if not isinstance(alpha, (int, float)) or not 0.0 < float(alpha) < 1.0:
        raise InputError(f"{name['alpha']}: expected a level in (0, 1), got {alpha!r}")
    if 1.0 / (n_permutations + 1) >= alpha:
        raise InputError(
            f"{name['n_permutations']}: {n_permutations} cannot give p < {name['alpha']} {alpha}; use at least "
            f"{int(np.ceil(1.0 / alpha))}"
        )
    if not whole(n_shifts) or not (n_shifts == 0 or 19 <= n_shifts <= 10_000):
        raise InputError(f"{name['n_shifts']}: expected 0 (none) or an integer in [19, 10000], got {n_shifts!r}")
    if not isinstance(min_score, (int, float)) or not np.isfinite(min_score) or min_score >= 1.0:
        raise InputError(f"{name['min_score']}: expected a finite held-out R^2 below 1, got {min_score!r}")


def rank_candidates(
    ev: Any,
    exclude: tuple[str, ...] = (),
    *,
    n_permutations: int = DEFAULTS["n_permutations"],
    alpha: float = DEFAULTS["alpha"],
    min_score: float = DEFAULTS["min_score"],
    max_readings: int = 60_000,
    rng: np.random.Generator | None = None,
    progress: bool = False,
    given: tuple[str, ...] = (),
    n_shifts: int = DEFAULTS["n_shifts"],
) -> Ranking:
    """Score every candidate of ``ev`` (except ``exclude``) on every residual target; block sign-flip test.

    Args:
        ev: held-out :class:`~sensor_envs.diagnose.core.Evaluation`.
        exclude: candidate names not to rank (e.g. already in the model's state).
        n_permutations: block sign-flips (p-values resolve down to ``1 / (P + 1)``).
        alpha: family-wise level of the max-T adjusted p-value.
        min_score: minimum held-out ``R^2`` of a significant effect.
        max_readings: readings used (an even subsample in time order beyond this).
        rng: generator of the flips (default seed 0).
        progress: tqdm bar over the flips.
        given: candidates already added to the model: an effect they explain is marked a proxy of them
            (``proxy_of``) and is not significant (a candidate is not its own proxy: one added on one part
            of the model is ranked again for the others).
        n_shifts: most circular shifts that confirm a held-out finding (:mod:`~sensor_envs.diagnose.shifts`;
            0: the flips alone).

    Returns:
        The :class:`Ranking`; each effect dict holds ``name``, ``score``, ``p_value``, ``p_raw``,
        ``metric``, ``kind`` (the metric's kind), ``form`` (``main`` or ``x <state feature>``),
        ``metric_scores``, ``significant``, ``proxy_of``.
    """
    check_search_options(n_permutations, n_shifts, alpha, min_score)
    rng = rng if rng is not None else np.random.default_rng(0)
    order = np.asarray(ev.order if getattr(ev, "order", None) is not None else ev.blocks, dtype=np.float64)
    idx = np.argsort(order, kind="stable")
    if idx.size > max_readings:
        idx = idx[np.linspace(0, idx.size - 1, max_readings).astype(np.int64)]
    refused = []
    names = []
    for c in ev.candidates:
        if c in exclude:
            continue
        why = _refusal(ev.candidates[c][idx])
        if why is None:
            names.append(c)
        else:
            refused.append({"name": c, "reason": f"not tested: {why}"})
    if not names:
        return Ranking([], alpha, min_score, n_permutations, refused)
    cands = {c: np.asarray(ev.candidates[c], dtype=np.float64)[idx] for c in names}
    state = {s: np.asarray(v, dtype=np.float64)[idx] for s, v in getattr(ev, "state", {}).items()}
    d = _design(cands, names, state)
    given = tuple(g for g in given if g in ev.candidates and _refusal(ev.candidates[g][idx]) is None)
    given_design = (
        _design({g: np.asarray(ev.candidates[g], dtype=np.float64)[idx] for g in given}, list(given), state)
        if given
        else None
    )
    fold_all = time_folds(order[idx])
    rank = np.argsort(np.argsort(order[idx], kind="stable"), kind="stable")
    instant = np.floor(order[idx])  # readings of one time instant (a scan, a radar cycle)
    metrics = list(ev.residuals)
    kinds = getattr(ev, "metric_kinds", {}) or {}

    def centred_free(r: NDArray, mask: NDArray) -> NDArray[np.float64]:
        # centred: a sign flip must not create structure from the mean
        return _free_of_state(r[mask] - r[mask].mean(), d.state_bins, mask)

    freed, within, shift_targets = [], [], []
    proj_targets = {}  # every finite reading (no fold gaps: nothing is fitted on one part and scored on another)
    for m in metrics:
        r = np.asarray(ev.residuals[m], dtype=np.float64)[idx]
        mask = np.isfinite(r) & (fold_all >= 0)
        rc = centred_free(r, mask)
        freed.append((rc, mask))
        # shifts move the freed residual: a raw one would carry its state pattern to other readings
        shift_targets.append({"r": rc, "mask": mask, "fold": fold_all[mask], "instant": instant[mask]})
        within.append(_within_instant(rc, instant[mask]))
        proj_targets[m] = (centred_free(r, np.isfinite(r)), np.isfinite(r))
    # main regressors see drift shared by an instant's readings; interactions see the within-instant part
    n_blocks = (n_flip_blocks([f[0] for f in freed]), n_flip_blocks(within))
    blocks = [(rank * b // max(rank.size, 1)).astype(np.int64) for b in n_blocks]
    targets = [
        (rc, mask, [w] * len(d.state_bins), fold_all[mask], blocks[0][mask], blocks[1][mask])
        for (rc, mask), w in zip(freed, within, strict=True)
    ]
    stats = _all_stats(d, targets, n_blocks)
    ones = (np.ones((1, n_blocks[0])), np.ones((1, n_blocks[1])))
    obs = _scores(stats, ones, len(names), null=False)[0]  # (C, m, 1 + S)
    perm = np.empty((n_permutations, *obs.shape))
    bar = tqdm(total=n_permutations, disable=not progress, desc="block sign-flip test")
    for p0 in range(0, n_permutations, 50):  # batches of flips, vectorised inside
        k = min(50, n_permutations - p0)
        fl = (rng.choice([-1.0, 1.0], size=(k, n_blocks[0])), rng.choice([-1.0, 1.0], size=(k, n_blocks[1])))
        perm[p0 : p0 + k] = _scores(stats, fl, len(names))
        bar.update(k)
    bar.close()
    # studentise every (candidate, target, regressor) cell by its own null distribution, then max-T
    finite = np.isfinite(perm).all(axis=0) & np.isfinite(obs)
    # centre and scale of each cell's null from its upper tail (median, 95th percentile): the scores
    # are skewed (an overfitting regressor's R^2 is bounded above by chance alignment, not below)
    q50, q95 = np.percentile(np.nan_to_num(perm, neginf=0.0), [50, 95], axis=0)
    mu = np.where(finite, q50, 0.0)
    sd = np.where(finite, (q95 - q50) / 1.645, 1.0)
    # floor: half the median spread of the same (target, regressor) over the candidates, so a degenerate
    # cell (e.g. time's interaction cells, which cannot carry over between time segments) cannot dominate
    med = np.array(
        [
            [np.median(sd[:, j, f][finite[:, j, f]]) if finite[:, j, f].any() else 0.0 for f in range(sd.shape[2])]
            for j in range(sd.shape[1])
        ]
    )
    sd = np.maximum(sd, np.maximum(0.5 * med[None], 1e-9))
    z_obs = np.where(finite, (obs - mu) / sd, -np.inf).reshape(len(names), -1)
    z_perm = np.where(finite[None], (np.nan_to_num(perm) - mu) / sd, -np.inf).reshape(n_permutations, len(names), -1)
    best_z = z_obs.max(axis=1)
    perm_best = z_perm.max(axis=2)  # (P, C)
    p_raw = (1 + np.sum(perm_best >= best_z[None], axis=0)) / (1 + n_permutations)
    p_adj = (1 + np.sum(perm_best.max(axis=1)[:, None] >= best_z[None], axis=0)) / (1 + n_permutations)
    confirm = p_adj < alpha / 2
    if n_shifts and confirm.any():  # the flips' null is too narrow under drift that outlasts blocks: shifts confirm
        p_adj = np.maximum(p_adj, shift_p_values(d, shift_targets, stats, obs, finite, rng, n_shifts))
    forms = ["main", *(f"x {s}" for s in d.state_names), *(f"x {s}" for s in d.state_names)]
    effects: list[dict[str, Any]] = []
    crit = float(np.quantile(z_perm.max(axis=(1, 2)), 1 - alpha))  # family-wise critical z of one cell
    spread = np.array([kinds.get(m, "mean") == "spread" for m in metrics])
    for i, c in enumerate(names):
        j, f = np.unravel_index(_reported_cell(z_obs[i], spread, crit), obs[i].shape)
        score = float(obs[i, j, f])
        effects.append(
            {
                "name": c,
                "score": score,
                "z": float(best_z[i]),
                "p_value": float(p_adj[i]),
                "p_raw": float(p_raw[i]),
                "metric": metrics[j],
                "kind": kinds.get(metrics[j], "mean"),
                "form": forms[f],
                "metric_scores": {m: float(obs[i, jj].max()) for jj, m in enumerate(metrics)},
                "significant": bool(p_adj[i] < alpha and score >= min_score),
                "proxy_of": None,
            }
        )
    _settle_forms(effects, obs, d, targets, metrics, forms, alpha)
    flips = rng.choice([-1.0, 1.0], size=(PROJECTION_FLIPS, n_blocks[0]))
    preferred = tuple(m for m in metrics if kinds.get(m, "mean") in ("mean", "rate"))
    proj = projection_tests(proj_targets, cands, state, blocks[0], flips, preferred, alpha / 2)
    found = [c for c, pr in proj.items() if pr.p_value < alpha / 2]
    if n_shifts and found:  # as the held-out test: shifts confirm what the flips find
        for c, p in projection_shift_p(proj_targets, cands, state, d.state_bins, found, rng, n_shifts).items():
            proj[c].p_value = max(proj[c].p_value, p)
    for e in effects:
        combine_tests(e, proj.get(e["name"]), kinds, alpha, min_score)
    if drift_outlasts_blocks([f[0] for f in freed]):
        drift_confounded(
            effects, proj, cands, proj_targets, state, (blocks[0], flips), alpha, order[idx], drift_outlasts_blocks
        )
    if n_shifts:  # with the shifts: could an unrelated series like the candidate explain as much?
        surrogate_check(effects, cands, proj_targets, state, order[idx], alpha, rng.spawn(1)[0])
    _mark_proxies(effects, d, names, targets, metrics, forms, given_design)
    given_values = {g: np.asarray(ev.candidates[g], dtype=np.float64)[idx] for g in given}
    projection_proxies(effects, proj, cands, proj_targets, state, (blocks[0], flips), alpha, given_values)
    # significant effects with strong evidence (p < alpha / 10) first, then the others; within each, by how
    # much of the held-out residual they explain (the loop adds the largest first): a distractor that
    # follows slow drift may explain as much as the cause, but at a p-value near the level
    effects.sort(
        key=lambda e: (
            e["proxy_of"] is not None,
            not e["significant"],
            not (e["significant"] and e["p_value"] < alpha / 10),
            -float(e["score"] if e["significant"] else e["z"]),
        )
    )
    return Ranking(effects, alpha, min_score, n_permutations, refused, n_blocks[0])


def _reported_cell(z: NDArray, spread: NDArray, crit: float) -> int:
    """The cell (flat index over targets x regressors) a candidate's finding is reported in.

    Its best ``z``, except that a significant cell of a mean or rate target is preferred over a spread
    target: a mean effect whose sign follows the bearing, or a U-shaped mean effect, also widens the
    spread about the scan's centre (the spread is then a consequence, not the finding).
    """
    best = int(np.argmax(z))
    n_forms = z.size // spread.size
    ok = (z >= crit) & ~np.repeat(spread, n_forms)
    if spread[best // n_forms] and ok.any():
        return int(np.argmax(np.where(ok, z, -np.inf)))
    return best


def _interaction_gain(d: _Design, i: int, s: int, r: NDArray, mask: NDArray, fold: NDArray) -> float:
    """Held-out ``R^2`` the candidate x state grid adds beyond the candidate's main effect and the state's pattern."""
    nc, ns = _INT_BINS
    sb = d.state_bins[s][mask]
    joint = d.int_cbins[i, mask] * (ns + 1) + sb
    out = 0.0
    for a in (0, 1):
        fa, fb = fold == a, fold == 1 - a
        u = r - _fit_predict(d.main_basis[i, mask], r, fa)
        st = np.bincount(sb[fa], weights=u[fa], minlength=ns + 1) / np.maximum(np.bincount(sb[fa], minlength=ns + 1), 1)
        u = u - st[sb]
        size = (nc + 1) * (ns + 1)
        g = np.bincount(joint[fa], weights=u[fa], minlength=size) / (
            np.bincount(joint[fa], minlength=size) + _SHRINK * max(1.0, d.deff[i] / ns)
        )
        out += 0.5 * (1 - np.sum((u[fb] - g[joint[fb]]) ** 2) / max(np.sum(u[fb] ** 2), 1e-300))
    return float(out)


def _smooth_gain(d: _Design, i: int, s: int, r: NDArray, mask: NDArray, fold: NDArray) -> float:
    """Held-out ``R^2`` the smooth candidate x state basis adds beyond the candidate's main basis."""
    main = d.main_basis[i, mask]
    both = interaction_basis(main, d.state_basis[s][mask])
    out = 0.0
    for a in (0, 1):
        fa, fb = fold == a, fold == 1 - a
        sse_main = np.sum((r[fb] - _fit_predict(main, r, fa)[fb]) ** 2)
        sse_both = np.sum((r[fb] - _fit_predict(both, r, fa)[fb]) ** 2)
        out += 0.5 * (sse_main - sse_both) / max(np.sum((r[fb] - r[fa].mean()) ** 2), 1e-300)
    return float(out)


def _settle_forms(
    effects: list[dict[str, Any]], obs: NDArray, d: _Design, targets: list, metrics: list, forms: list, alpha: float
) -> None:
    """An effect found through an interaction regressor keeps that form only if the grid adds to its main effect.

    Otherwise (a main effect that the interaction grid also fits) the form is ``main`` on the same target.
    """
    for i, e in enumerate(effects):
        if e["form"] == "main" or not e["p_raw"] < max(alpha, 0.05):
            continue
        j = metrics.index(e["metric"])
        r, mask, _, fold, _b, _bi = targets[j]
        s = forms.index(e["form"]) - 1
        gain = max(_interaction_gain(d, i, s, r, mask, fold), _smooth_gain(d, i, s, r, mask, fold))
        e["interaction_gain"] = gain
        main = float(obs[i, j, 0])
        if gain < max(0.001, 0.1 * max(main, 0.0)):
            e["form"], e["score"] = "main", max(main, e["score"] if main <= 0 else main)


def _mark_proxies(
    effects: list[dict[str, Any]],
    d: _Design,
    names: list[str],
    targets: list,
    metrics: list,
    forms: list,
    given: _Design | None = None,
) -> None:
    """Mark a top candidate whose effect another candidate explains (``proxy_of``; no longer significant).

    ``i`` is a proxy of ``j`` when, once ``j``'s fit (in ``j``'s form) is removed, ``i`` (in its form)
    explains less than a fifth of its own score and less than ``j`` explains given ``i``. ``j`` ranges
    over the other top candidates and over ``given`` (candidates already added to the model, in their
    best form on the target): a proxy of a cause already in the model is not added after it.
    """
    top = sorted(range(len(effects)), key=lambda i: -effects[i]["z"])[:_TOP_COND]
    top = [i for i in top if effects[i]["p_raw"] < 0.05]
    u = d.main_basis[:, :, 1]  # rank scales: a proxy's is correlated with its cause's, whatever their units
    corr = np.abs(np.nan_to_num(np.corrcoef(u))) if len(names) > 1 else np.zeros((1, 1))
    top = [i for i in top if effects[i]["proxy_of"] != DRIFT]  # the drift's shadows explain no one
    for i in top:
        ei = effects[i]
        jm = metrics.index(ei["metric"])
        r, mask, _, fold, _b, _bi = targets[jm]
        fi = forms.index(ei["form"])
        # the other top candidates, and any candidate correlated with i (a cause may score below its noisy
        # copy by chance, even out of the top: it is still the better explanation given the copy)
        near = [
            j
            for j in np.flatnonzero(corr[i] >= PROXY_CORR)
            if j != i and j not in top and effects[j]["proxy_of"] != DRIFT
        ]
        others: list[tuple[_Design, int, int, str]] = [
            (d, j, forms.index(effects[j]["form"]), names[j]) for j in top if j != i and effects[j]["proxy_of"] is None
        ] + [(d, int(j), fi, names[j]) for j in near]
        if given is not None:
            others += [
                (given, g, _best_form(given, g, r, mask, fold), n)
                for g, n in enumerate(given.names)
                if n != names[i]  # itself, already added on another part, is not its own cause
            ]
        for dj, j, fj, name in others:
            ci = _cond(d, i, fi, dj, j, fj, r, mask, fold)
            cj = _cond(dj, j, fj, d, i, fi, r, mask, fold)
            if ci < 0.2 * ei["score"] and cj > ci:
                if dj is d and ei["significant"] and not effects[j]["significant"]:
                    inherit(effects[j], ei, cj)
                ei["proxy_of"] = name
                ei["conditional_score"] = ci
                ei["significant"] = False
                break


def _best_form(d: _Design, i: int, r: NDArray, mask: NDArray, fold: NDArray) -> int:
    """The form (0: main, ``1 + s``: with state ``s``) in which candidate ``i`` explains most of ``r`` (held out)."""
    scores = []
    for f in range(1 + len(d.state_bins)):
        basis = _form_basis(d, i, f, mask)
        sc = 0.0
        for a in (0, 1):
            fa, fb = fold == a, fold == 1 - a
            sc += np.sum(r[fb] ** 2) - np.sum((r[fb] - _fit_predict(basis, r, fa)[fb]) ** 2)
        scores.append(sc)
    return int(np.argmax(scores))
