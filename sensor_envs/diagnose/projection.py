"""Projection tests of candidate causes: few-coefficient forms, block sign-flips, min-P over every test.

The search's held-out scores (:mod:`~sensor_envs.diagnose.search`) see effects of any shape, but pay for
it: half the readings fit, half score, and dozens of grid cells overfit. A small effect of a simple form
(a step in the cause whose sign follows the azimuth side, 0.3 residual sd) is then below their noise,
although a test that regresses the residual on a few regressors of the right form finds it easily.

This module is that test, for every candidate and every simple form at once:

* **Forms** of a candidate ``c`` (its mid-rank scale ``u``): the main effect ``P1(u), P2(u)`` (linear,
  step, saturating and U-shaped effects alike), and the same times each state factor: a state feature's
  centred rank (an effect that grows along the range) and its side of the median (an effect whose sign
  follows the azimuth side or the bearing half), :func:`state_factors`.
* **Statistic**: the explained sum of squares of a residual target on a form's centred regressors (in
  sample: no readings are spent on fitting).
* **Null**: the residual's signs flipped per contiguous time block (as many blocks as the search's test
  uses), the same draws for every test: within a block the residual keeps its correlation, the candidate
  its own time structure.
* **Multiplicity**: Westfall-Young min-P over every (candidate, target, form) test, each statistic put on
  one scale by the upper tail of a Gamma law with its exact mean and variance under the flips (a smooth
  p-value, so the adjusted one is not floored at ``tests / flips``); the adjusted p-value is the share
  of flip draws whose smallest tail over all tests is at most the test's own: the family-wise level
  holds, and correlated tests (the forms of one candidate) cost less than a Bonferroni correction.
* **Conditional**: :func:`partial_test` tests one candidate's form given another's (both residualised on
  the other), so a noisy copy of a cause is told from the cause.
* **Slow drift**: :func:`drift_confounded` tests a significant candidate within its time blocks only
  (both the residual and the candidate freed of each block's mean). A random walk that follows a log's
  own slow drift explains the residual across blocks, not within them: on one log it cannot be told
  from the drift, and is not offered as a cause.

:mod:`~sensor_envs.diagnose.power`'s oracle makes the same test of the planted cause alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaincc

from sensor_envs.diagnose.regressors import bin_candidate, rank_basis

__all__ = [
    "FLIPS",
    "DRIFT",
    "PROXY_CORR",
    "TIME_CORR",
    "time_like",
    "ProjectionResult",
    "candidate_forms",
    "combine_tests",
    "drift_confounded",
    "flip_p",
    "inherit",
    "partial_test",
    "projection_proxies",
    "projection_tests",
    "state_factors",
]

DRIFT = "the slow drift over time"
"""``proxy_of`` of a candidate that explains the residual only across time blocks (:func:`drift_confounded`)."""
TIME_CORR = 0.99
"""Rank correlation with the readings' time order from which a candidate is time itself (not checked for drift)."""
PROXY_CORR = 0.5
"""Rank correlation above which a candidate is checked as the cause of another (its noisy copy may rank above it)."""
FLIPS = 20_000
"""Block sign-flip draws of the search's projection tests (p-values resolve down to ``1 / (FLIPS + 1)``)."""


def state_factors(state: dict[str, NDArray]) -> dict[str, NDArray[np.float64]]:
    """Per state feature ``s``: centred rank in ``[-1, 1]`` (``x s (trend)``), side of the median (``x s (side)``)."""
    out: dict[str, NDArray[np.float64]] = {}
    for name, s in state.items():
        b = rank_basis(s, degree=1)
        out[f"x {name} (trend)"] = b[:, 1]
        out[f"x {name} (side)"] = np.sign(b[:, 1])
    return out


def candidate_forms(c: NDArray, factors: dict[str, NDArray]) -> dict[str, NDArray[np.float64]]:
    """``{form: (n, 2)}``: ``P1(u), P2(u)`` of the candidate's rank scale, alone (``main``) and times each factor.

    A non-finite reading of the candidate contributes 0 to every regressor.
    """
    main = _main(c)
    return {"main": main, **{k: main * f[:, None] for k, f in factors.items()}}


def _main(c: NDArray) -> NDArray[np.float64]:
    """``(n, 2)``: ``P1(u), P2(u)`` of the candidate's rank scale (0 at a non-finite reading)."""
    return rank_basis(c, degree=2)[:, 1:3]


def _form(c: NDArray, factors: dict[str, NDArray], form: str) -> NDArray[np.float64]:
    """One form of :func:`candidate_forms` (``main`` or a factor's name), without computing the others."""
    main = _main(c)
    return main if form == "main" else main * factors[form][:, None]


def _per_block(r: NDArray, x: NDArray, block: NDArray, n_blocks: int) -> NDArray[np.float64] | None:
    """``(n_blocks, k)`` block sums of ``r`` times an orthonormal basis of the centred ``x`` (``None``: degenerate)."""
    xc = x - x.mean(axis=0)
    q, tri = np.linalg.qr(xc)
    q = q[:, np.abs(np.diag(tri)) > 1e-9 * max(float(np.abs(tri).max(initial=0.0)), 1e-300)]
    if q.shape[1] == 0:
        return None
    return np.stack([np.bincount(block, weights=q[:, j] * r, minlength=n_blocks) for j in range(q.shape[1])], axis=1)


def _gamma_tail(per_block: NDArray) -> tuple[float, Any]:
    """The statistic's exact mean under the flips, and its upper tail under a moment-matched Gamma law.

    With ``v_b`` the blocks' contributions, the flipped statistic ``|sum_b s_b v_b|^2`` has mean
    ``sum_b |v_b|^2`` and variance ``2 sum_{b != c} (v_b . v_c)^2`` exactly; the Gamma law with those
    moments gives every test a continuous tail (:func:`projection_tests` compares tests by it, so
    the family-wise p-value is not floored at ``tests / flips`` as ranks would floor it).
    """
    gram = per_block @ per_block.T
    mean = float(np.trace(gram))
    var = 2.0 * float(np.sum(gram**2) - np.sum(np.diag(gram) ** 2))
    if mean <= 0 or var <= 0:
        return mean, lambda t: np.ones(np.shape(t))
    shape, scale = mean**2 / var, var / mean
    return mean, lambda t: gammaincc(shape, np.asarray(t, dtype=np.float64) / scale)


def _flip_test(per_block: NDArray, flips: NDArray) -> tuple[float, NDArray[np.float64], float]:
    """Observed explained sum of squares, its value under every sign-flip draw ``flips (B, blocks)``, p-value."""
    obs = float(np.sum(per_block.sum(axis=0) ** 2))
    null = np.sum((flips @ per_block) ** 2, axis=1)
    return obs, null, float((1 + np.sum(null >= obs * (1 - 1e-12))) / (1 + flips.shape[0]))


def flip_p(r: NDArray, x: NDArray, block: NDArray, flips: NDArray) -> float:
    """p-value of ``r ~ 1 + x`` (H0: the slopes of ``x (n, k)`` are 0) by block sign-flips of ``r``.

    ``block (n,)``: each reading's time block in ``[0, flips.shape[1])``. Readings where ``r`` or ``x``
    is not finite are left out.
    """
    ok = np.isfinite(r) & np.all(np.isfinite(x), axis=1)
    if ok.sum() < 10 * (x.shape[1] + 1):
        return 1.0
    pb = _per_block(r[ok] - r[ok].mean(), x[ok], block[ok], flips.shape[1])
    if pb is None:
        return 1.0
    return _flip_test(pb, flips)[2]


def partial_test(r: NDArray, xi: NDArray, xj: NDArray, block: NDArray, flips: NDArray) -> tuple[float, float]:
    """``(p, share)`` of candidate form ``xi`` given ``xj``: both ``r`` and ``xi`` residualised on ``[1, xj]``.

    ``share``: the explained sum of squares ``xi`` adds to ``xj``, over ``r``'s sum of squares.
    """
    base = np.column_stack([np.ones(r.size), xj])
    beta = np.linalg.lstsq(base, np.column_stack([r, xi]), rcond=None)[0]
    res = np.column_stack([r, xi]) - base @ beta
    pb = _per_block(res[:, 0], res[:, 1:], block, flips.shape[1])
    if pb is None:
        return 1.0, 0.0
    obs, _, p = _flip_test(pb, flips)
    return p, obs / max(float(np.sum((r - r.mean()) ** 2)), 1e-300)


@dataclass
class ProjectionResult:
    """One candidate's best projection test.

    Attributes:
        p_value: min-P adjusted p-value over every test of every candidate.
        p_raw: the best test's own p-value.
        metric: residual target of the best test.
        form: ``main`` or ``x <state feature> (trend|side)``.
        share: explained sum of squares beyond its null mean, over the target's sum of squares (an
            in-sample ``R^2`` freed of its chance part).
    """

    p_value: float
    p_raw: float
    metric: str
    form: str
    share: float


def projection_tests(
    targets: dict[str, tuple[NDArray, NDArray]],
    cands: dict[str, NDArray],
    state: dict[str, NDArray],
    block: NDArray,
    flips: NDArray,
    prefer: tuple[str, ...] = (),
    alpha: float = 0.05,
) -> dict[str, ProjectionResult]:
    """Every candidate x target x form test, min-P adjusted over all of them.

    Args:
        targets: ``{metric: (r, mask)}``: each residual target on its readings ``mask`` (boolean over the
            candidates' readings), centred.
        cands: ``{name: (n,)}`` candidate values, in the same reading order as ``block``.
        state: ``{name: (n,)}`` state features (their factors multiply the forms).
        block: ``(n,)`` time block of each reading, in ``[0, flips.shape[1])``.
        flips: ``(B, blocks)`` signs, shared by every test.
        prefer: metrics whose significant test is reported before a better one of another metric (a mean
            effect whose sign follows the state also widens the spread: the spread is its consequence).
        alpha: the level at which a preferred metric's test counts as significant.

    Returns:
        ``{candidate: ProjectionResult}``.
    """
    factors = state_factors(state)
    n_flips = flips.shape[0]
    min_tail = np.ones(n_flips)
    rows: list[tuple[str, str, str, float, float, float]] = []  # candidate, metric, form, raw p, share, tail
    for name, c in cands.items():
        forms = candidate_forms(c, factors)
        for metric, (r, mask) in targets.items():
            ss = max(float(np.sum(r**2)), 1e-300)
            for form, x in forms.items():
                pb = _per_block(r, x[mask], block[mask], flips.shape[1])
                if pb is None:
                    continue
                obs, null, p = _flip_test(pb, flips)
                mean, tail = _gamma_tail(pb)
                np.minimum(min_tail, tail(null), out=min_tail)
                rows.append((name, metric, form, p, (obs - mean) / ss, float(tail(np.array([obs]))[0])))
    out: dict[str, ProjectionResult] = {}
    for name in cands:
        mine = [row for row in rows if row[0] == name]
        if not mine:
            continue
        adj = {id(row): float((1 + np.sum(min_tail <= row[5] * (1 + 1e-12))) / (1 + n_flips)) for row in mine}
        best = min(mine, key=lambda row: (row[3], -row[4]))
        pref = [row for row in mine if row[1] in prefer and adj[id(row)] < alpha]
        if best[1] not in prefer and pref:
            best = min(pref, key=lambda row: (row[3], -row[4]))
        out[name] = ProjectionResult(min(adj.values()), best[3], best[1], best[2], best[4])
    return out


def combine_tests(e: dict[str, Any], pr: ProjectionResult | None, kinds: dict, alpha: float, min_score: float) -> None:
    """One p-value from the held-out max-T test and the projection test (Bonferroni over the two).

    A candidate is significant when either test finds it at ``alpha / 2`` with an effect of at least
    ``min_score``; found by the projection test alone, it is reported in that test's metric and form,
    scored by its in-sample share beyond chance (``test``: which test found it).
    """
    held = e["p_value"] < alpha / 2 and e["score"] >= min_score
    e["p_search"] = e["p_value"]
    e["test"] = "held-out"
    if pr is None:
        e["p_value"] = min(1.0, 2 * e["p_value"])
        e["significant"] = held
        return
    e["p_projection"] = pr.p_value
    e["p_value"] = min(1.0, 2 * min(e["p_value"], pr.p_value))
    by_projection = pr.p_value < alpha / 2 and pr.share >= min_score
    e["significant"] = held or by_projection
    if by_projection and not held:
        e.update(metric=pr.metric, kind=kinds.get(pr.metric, "mean"), form=pr.form.split(" (")[0])
        e.update(score=pr.share, test="projection", form_detail=pr.form)


def projection_proxies(
    effects: list[dict[str, Any]],
    proj: dict[str, ProjectionResult],
    cands: dict[str, NDArray],
    targets: dict[str, tuple[NDArray, NDArray]],
    state: dict[str, NDArray],
    flips: tuple[NDArray, NDArray],
    alpha: float,
    given: dict[str, NDArray] | None = None,
) -> None:
    """Tell causes from proxies by partial projection tests, strongest significant candidate first.

    A significant candidate ``i`` is a proxy of ``j`` (a candidate kept before it, or one whose rank
    scale is correlated with ``i``'s) when, in ``i``'s metric and form, ``i`` adds nothing significant
    given ``j`` (``p >= alpha``) and ``j`` adds more given ``i`` than ``i`` given ``j``. A cause that
    was not significant itself takes its proxy's finding (``via_proxy``). ``given``: candidates already
    in the model (their values); a significant candidate correlated with one of them that adds nothing
    significant given it is its proxy (a noisy copy of a cause, seen again after the cause was added).
    """
    block, signs = flips
    factors = state_factors(state)
    names = [e["name"] for e in effects]
    by_name = {e["name"]: e for e in effects}
    u = {n: rank_basis(cands[n], degree=1)[:, 1] for n in names if n in cands}
    given = given or {}
    given_u = {g: rank_basis(cg, degree=1)[:, 1] for g, cg in given.items()}
    order = sorted(
        (e for e in effects if e["significant"] and e["name"] in proj),
        key=lambda e: (proj[e["name"]].p_raw, -proj[e["name"]].share),
    )
    kept: list[str] = []
    for ei in order:
        if not ei["significant"]:
            continue
        pi = proj[ei["name"]]
        r, mask = targets[pi.metric]
        xi = _form(cands[ei["name"]], factors, pi.form)[mask]
        near = [
            n
            for n in u
            if n != ei["name"]
            and n not in kept
            and by_name[n].get("proxy_of") != DRIFT  # a shadow of the drift is no one's cause
            and abs(np.corrcoef(u[n], u[ei["name"]])[0, 1]) >= PROXY_CORR
        ]
        for n in kept + near:
            form = proj[n].form if n in kept else pi.form
            xj = _form(cands[n], factors, form)[mask]
            p_ij, s_ij = partial_test(r, xi, xj, block[mask], signs)
            p_ji, s_ji = partial_test(r, xj, xi, block[mask], signs)
            if p_ij >= alpha and s_ji > s_ij:
                ej = by_name[n]
                if not ej["significant"]:
                    inherit(ej, ei, s_ji)
                    ej.update(proxy_of=None, test=ei.get("test"))
                    ei["proxy_of"] = None
                    kept.append(n)
                ei.update(proxy_of=n, significant=False, conditional_score=s_ij)
                break
        else:
            kept.append(ei["name"])
        for g, ug in given_u.items():  # itself, already added on another part, is not its own cause
            if g == ei["name"] or not ei["significant"] or abs(np.corrcoef(ug, u[ei["name"]])[0, 1]) < PROXY_CORR:
                continue
            xg = _form(given[g], factors, pi.form)[mask]
            p_ig, s_ig = partial_test(r, xi, xg, block[mask], signs)
            if p_ig >= alpha:
                kept.remove(ei["name"])
                ei.update(proxy_of=g, significant=False, conditional_score=s_ig)


def inherit(cause: dict[str, Any], proxy: dict[str, Any], gain: float) -> None:
    """The cause of a significant proxy takes its finding: the effect the test found is the cause's.

    The family-wise test found the proxy's effect; the conditional check attributes it to ``cause``
    (which explains it given the proxy, not the other way round), so ``cause`` is significant in the
    proxy's metric and form, at the proxy's p-value, scored by its conditional gain (``via_proxy``).
    """
    cause.update(
        significant=True,
        p_value=min(cause["p_value"], proxy["p_value"]),
        metric=proxy["metric"],
        kind=proxy["kind"],
        form=proxy["form"],
        score=max(cause["score"], gain),
        via_proxy=proxy["name"],
    )


def _within_blocks(x: NDArray, block: NDArray, factor: NDArray | None = None) -> NDArray[np.float64]:
    """``x`` (``(n,)`` or ``(n, k)``) freed, in each time block, of its mean (and of its slope on ``factor``).

    With a state factor, a drift of the residual's dependence on the state (a range-dependent misfit
    that wanders over time) is removed as well as a drift of its level.
    """
    x2 = np.asarray(x, dtype=np.float64).reshape(x.shape[0], -1).copy()
    for b in np.unique(block):
        sel = block == b
        base = (
            np.ones((int(sel.sum()), 1)) if factor is None else np.column_stack([np.ones(int(sel.sum())), factor[sel]])
        )
        x2[sel] -= base @ np.linalg.lstsq(base, x2[sel], rcond=None)[0]
    return x2.reshape(x.shape)


def _binned_form(c: NDArray, factors: dict[str, NDArray], form: str, n_bins: int = 8) -> NDArray[np.float64]:
    """The candidate's quantile-bin indicators in a form (``n_bins - 1``; with a factor, ``n_bins`` more).

    The intercept stands for the first bin; a form times a state factor adds each bin times the factor.
    Any shape of effect (a step, a saturation), for the fit whose remainder :func:`_explains_drift` tests;
    a non-finite reading is in no bin.
    """
    onehot = bin_candidate(c, n_bins)[:, None] == np.arange(n_bins)[None]  # a NaN's bin is n_bins: none here
    x = onehot.astype(np.float64)[:, 1:]  # the intercept stands for the first bin
    return x if form == "main" else np.column_stack([x, onehot * factors[form][:, None]])


def _explains_drift(r: NDArray, xs: list[NDArray], outlasts: Callable[[list[NDArray]], bool]) -> bool:
    """Whether ``r`` (in time order) does not drift beyond the blocks, or no longer does once fitted on an ``x``."""
    if not outlasts([r]):
        return True
    for x in xs:
        base = np.column_stack([np.ones(r.size), x])
        if not outlasts([r - base @ np.linalg.lstsq(base, r, rcond=None)[0]]):
            return True
    return False


def _finding_forms(
    e: dict[str, Any], pi: ProjectionResult, factors: dict[str, NDArray], targets: dict[str, Any]
) -> tuple[str, list[str]]:
    """The metric and projection forms of a finding: the projection test's own, or the held-out test's.

    A held-out finding keeps its metric (unless the metric is a score, the per-reading NLL, or not one of
    ``targets``: then the projection test's); its form ``main``, or ``x <state>`` as that state's trend and
    side.
    """
    held_out = e.get("test") == "held-out" and e.get("metric") in targets
    if not held_out or e.get("kind") == "score":
        return pi.metric, [pi.form]  # the per-reading NLL (a score) has too little power within blocks
    if e.get("form", "main") == "main":
        return e["metric"], ["main"]
    forms = [k for k in (f"{e['form']} (trend)", f"{e['form']} (side)") if k in factors]
    return e["metric"], forms or ["main"]


def time_like(c: NDArray, t_rank: NDArray) -> bool:
    """Whether candidate ``c`` is time itself (the drift's own name, not checked for drift).

    Its rank scale correlates with ``t_rank`` (the readings' time-order rank scale) at :data:`TIME_CORR` or more.
    """
    ok = np.isfinite(c)
    u = rank_basis(c, degree=1)[:, 1]
    return bool(ok.sum() > 2 and abs(np.corrcoef(u[ok], t_rank[ok])[0, 1]) >= TIME_CORR)


def drift_confounded(
    effects: list[dict[str, Any]],
    proj: dict[str, ProjectionResult],
    cands: dict[str, NDArray],
    targets: dict[str, tuple[NDArray, NDArray]],
    state: dict[str, NDArray],
    flips: tuple[NDArray, NDArray],
    alpha: float,
    order: NDArray,
    outlasts: Callable[[list[NDArray]], bool],
) -> None:
    """Mark a significant candidate that explains the residual only across time blocks (``proxy_of`` :data:`DRIFT`).

    In the finding's metric and form (the held-out test's, or the projection test's), the residual and the
    candidate's regressors are freed of each time block's mean (and, for a form times a state factor, of
    each block's slope on that factor) and tested by the same block sign-flips (``p_within_blocks``). A slow
    drift the model does not carry (a temperature, a warming sensor) makes every covariate that wanders
    slowly, a random walk above all, explain the residual between blocks; a cause also explains it within
    them.
    Without within-block evidence (``p_within >= alpha``) a candidate cannot be told from the drift on
    this log and is not significant, unless it accounts for the drift: a finding whose metric does not
    drift, or whose fit (in its form) leaves a remainder that no longer outlasts the blocks (``outlasts``,
    the search's test of the residuals), is kept (``explains_drift``; the conditional check that follows
    tells a cause from its copy). A strong slow cause is then the drift; a covariate that follows the drift by
    chance (a spurious regression) leaves most of it. Time itself (rank correlation with ``order`` >=
    :data:`TIME_CORR`) is not checked: it is the drift's own name, a trend over the log shows mostly
    across the blocks, and the block sign-flip test is the one that weighs a trend against a drifting noise.
    """
    block, signs = flips
    factors = state_factors(state)
    t_rank = rank_basis(np.asarray(order, dtype=np.float64), degree=1)[:, 1]
    checked, explains = [], {}
    for e in effects:
        name = e["name"]
        if not e["significant"] or e.get("proxy_of") is not None or name not in proj:
            continue
        if time_like(cands[name], t_rank):
            continue
        metric, forms = _finding_forms(e, proj[name], factors, targets)
        r, mask = targets[metric]
        b = block[mask]
        p = 1.0
        for form in forms:
            f = None if form == "main" else factors[form][mask]
            x = _within_blocks(_form(cands[name], factors, form)[mask], b, f)
            pb = _per_block(_within_blocks(r, b, f), x, b, signs.shape[1])
            p = min(p, 1.0 if pb is None else _flip_test(pb, signs)[2])
        e["p_within_blocks"] = p
        checked.append(e)
        if p >= alpha:
            explains[name] = _explains_drift(
                r, [_binned_form(cands[name], factors, form)[mask] for form in forms], outlasts
            )
    for e in checked:
        if e["p_within_blocks"] >= alpha:
            if explains[e["name"]]:  # it accounts for the drift: a cause (or its copy, for the proxy check)
                e["explains_drift"] = True
            else:
                e.update(proxy_of=DRIFT, significant=False)
