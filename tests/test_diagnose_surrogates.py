"""The surrogate-candidate check: a wandering covariate aligned with a drifting residual by chance is not a cause."""

from __future__ import annotations

import numpy as np
import pytest

from sensor_envs.diagnose.projection import DRIFT
from sensor_envs.diagnose.surrogates import ar1_surrogates, instant_series, surrogate_check

SCANS, BEARINGS = 120, 24


def _log(seed: int, effect: float) -> tuple[dict, dict, dict, np.ndarray, dict]:
    """Held-out-like readings: every third block of 5 scans; a residual drifting over the log plus AR(1) noise;
    a random walk (no effect) and an AR(1) covariate with ``effect`` residual sd per unit."""
    rng = np.random.default_rng(seed)
    scans = np.array([s for s in range(SCANS) if (s // 5) % 3 == 1])
    drift = np.cumsum(rng.normal(size=SCANS))
    drift = 2.0 * (drift - drift.mean()) / drift.std()
    ar = np.zeros(SCANS)
    for i in range(1, SCANS):
        ar[i] = 0.9 * ar[i - 1] + np.sqrt(1 - 0.81) * rng.normal()
    walk = np.cumsum(rng.normal(size=SCANS))
    order = np.repeat(scans.astype(np.float64), BEARINGS) + np.tile(np.arange(BEARINGS) / BEARINGS, scans.size)
    s = np.floor(order).astype(np.int64)
    r = drift[s] + effect * ar[s] + rng.normal(size=order.size)
    r = r - r.mean()
    cands = {"walk": walk[s], "cause": ar[s]}
    targets = {"range": (r, np.ones(r.size, dtype=bool))}
    state = {"bearing": np.tile(np.arange(BEARINGS, dtype=np.float64), scans.size)}
    effects = {n: {"name": n, "significant": True, "proxy_of": None} for n in cands}
    return cands, targets, state, order, effects


def test_an_ar1_series_is_fitted_and_drawn_on_its_instants_with_gaps():
    """The law is read off the candidate (a random walk: a coefficient near 1, draws that wander), gaps included."""
    rng = np.random.default_rng(0)
    t = np.array([s for s in range(600) if (s // 5) % 3 == 1], dtype=np.float64)
    walk = np.cumsum(rng.normal(size=600))[t.astype(int)]
    white = rng.normal(size=t.size)
    for v, lag1 in ((walk, (0.9, 1.01)), (white, (-0.3, 0.3))):
        x = ar1_surrogates(t, v, 200, rng)
        assert x.shape == (200, t.size)
        within = np.diff(t) == 1
        c = np.mean([np.corrcoef(row[:-1][within], row[1:][within])[0, 1] for row in x])
        assert lag1[0] < c < lag1[1]


def test_only_candidates_constant_within_an_instant_are_series():
    pos = np.repeat(np.arange(20), 3)
    assert instant_series(np.repeat(np.arange(20.0), 3), pos, 20) is not None
    assert instant_series(np.arange(60.0), pos, 20) is None  # a per-reading value: not a series over instants


def test_a_random_walk_aligned_with_drift_is_a_shadow_and_a_real_cause_is_not():
    """Over 40 seeded logs whose residual drifts over the whole log: an unrelated random walk keeps its
    significance at about the level's rate (the check is calibrated on THIS residual, whatever its drift),
    an AR(1) covariate with an effect of 1.5 noise sd (under a drift of 2 noise sd) keeps it nearly always."""
    kept = {"walk": 0, "cause": 0}
    n = 40
    for seed in range(n):
        cands, targets, state, order, effects = _log(seed, 1.5)
        surrogate_check(list(effects.values()), cands, targets, state, order, 0.05, np.random.default_rng(seed))
        for name, e in effects.items():
            assert 0.0 < e["p_surrogate"] <= 1.0
            kept[name] += e["significant"]
            if not e["significant"]:
                assert e["proxy_of"] == DRIFT
    assert kept["walk"] / n <= 0.15, kept
    assert kept["cause"] / n >= 0.85, kept


@pytest.mark.parametrize("effect", [0.0, 1.0])
def test_a_non_significant_or_time_like_finding_is_left_alone(effect):
    cands, targets, state, order, effects = _log(3, effect)
    cands["time"] = order.copy()
    effects["time"] = {"name": "time", "significant": True, "proxy_of": None}
    effects["walk"]["significant"] = False
    surrogate_check(list(effects.values()), cands, targets, state, order, 0.05, np.random.default_rng(0))
    assert "p_surrogate" not in effects["time"] and effects["time"]["significant"]
    assert not effects["walk"]["significant"] and effects["walk"]["proxy_of"] is None
