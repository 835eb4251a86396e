"""How detectable a known cause is in a model's held-out residuals: an oracle's test, for measuring recall.

The search of :mod:`sensor_envs.diagnose.search` does not know which candidate is the cause, nor the
form of its effect; it pays for that with a family-wise correction over every candidate, regressor
and residual target. An *oracle* knows the cause: :func:`oracle_test` regresses each residual target
on the cause alone (its mid-rank scale ``u``: ``P1(u)``, ``P2(u)``), as a main effect and times each
state feature (its centred rank, and its side of the median: an effect whose sign follows the range
or the azimuth side), and tests it as the search does: the residual's signs flipped per contiguous
time block, as many blocks as the search's test uses (:func:`~sensor_envs.diagnose.search.n_flip_blocks`:
each at least twice the residuals' correlation length). Its p-value is Bonferroni-corrected over
those forms and targets only. The oracle makes the search's
assumptions about time correlation; it differs only in knowing the cause.

A cause the oracle cannot separate from noise at ``alpha / n_candidates`` (what any search that
corrects over ``n_candidates`` candidates must at least overcome) is below the log's detection limit:
:func:`detectable`. The suite (``benchmarks/diagnose_suite.py``) reports recall on the detectable
cases beside the overall recall, so a miss at the limit of the data is told from a miss of the search.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sensor_envs.diagnose.core import Evaluation
from sensor_envs.diagnose.projection import candidate_forms, flip_p, state_factors
from sensor_envs.diagnose.search import n_flip_blocks

__all__ = ["detectable", "oracle_test", "FLIPS"]

FLIPS = 50_000
"""Block sign-flips of the oracle's test: enough that a p-value below ``alpha / candidates``, corrected
over its few dozen forms and targets, can be reached (the search's own test flips 499 times, and
corrects by max-T instead)."""


def oracle_test(ev: Evaluation, cause: str, n_flips: int = FLIPS, seed: int = 0) -> dict[str, Any]:
    """The oracle's test of ``cause`` on ``ev``'s residuals (every target, main effect and x each state factor).

    Returns:
        ``{"p_value": Bonferroni-corrected p, "tests": int, "best": "metric form", "p_raw": best raw p}``.
    """
    c = ev.candidates[cause]
    forms = candidate_forms(c, state_factors(ev.state))
    order = np.arange(c.size, dtype=np.float64) if ev.order is None else ev.order
    idx = np.argsort(order, kind="stable")
    rank = np.argsort(idx, kind="stable")
    series = [np.nan_to_num(np.asarray(r, dtype=np.float64)[idx]) for r in ev.residuals.values()]
    n_blocks = n_flip_blocks(series)  # the search's own block count
    block = rank * n_blocks // max(c.size, 1)
    flips = np.random.default_rng(seed).choice([-1.0, 1.0], size=(n_flips, n_blocks))
    best, p_best, tests = "", 1.0, 0
    for metric, r in ev.residuals.items():
        for form, x in forms.items():
            tests += 1
            p = flip_p(np.asarray(r, dtype=np.float64), x, block, flips)
            if p < p_best:
                best, p_best = f"{metric} {form}", p
    return {"p_value": min(1.0, p_best * tests), "tests": tests, "best": best, "p_raw": p_best}


def detectable(
    ev: Evaluation, cause: str, n_candidates: int, alpha: float = 0.05, seed: int = 0
) -> tuple[bool, dict[str, Any]]:
    """Whether an oracle that knows ``cause`` finds it at ``alpha / n_candidates``, and its test."""
    t = oracle_test(ev, cause, seed=seed)
    return bool(t["p_value"] < alpha / max(n_candidates, 1)), t
