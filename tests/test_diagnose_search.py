"""The search of ``diagnose`` on seeded families of held-out evaluations (no model fit: fast).

Each test draws residuals with a planted relation (or none) from a seed and checks the property over
several seeds: causes of each kind found with their kind and form, proxies ranked below their cause,
correlated noise (AR(1) drift, random-walk candidates, Student-t tails) not declared significant.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from sensor_envs.diagnose.core import Evaluation
from sensor_envs.diagnose.search import rank_candidates, time_folds

S, K = 300, 24  # scans x bearings of a synthetic held-out part


def _ar1(rng: np.random.Generator, n: int, rho: float) -> np.ndarray:
    e = rng.normal(size=n) * np.sqrt(1 - rho**2)
    out = np.empty(n)
    out[0] = rng.normal()
    for i in range(1, n):
        out[i] = rho * out[i - 1] + e[i]
    return out


def _walk(rng: np.random.Generator, n: int) -> np.ndarray:
    w = np.cumsum(rng.normal(size=n))
    return (w - w.mean()) / w.std()


def _evaluation(rng: np.random.Generator, resid: np.ndarray, cands: dict[str, np.ndarray]) -> Evaluation:
    """A lidar-like held-out evaluation: per-scan candidates broadcast over K bearings."""
    s = resid.shape[0]
    scan = np.repeat(np.arange(s), K)
    bearing = np.tile(np.arange(K), s).astype(float)
    return Evaluation(
        nll=np.zeros(s * K),
        residuals={"range": resid.ravel(), "range_spread": np.sqrt(np.abs(resid.ravel()))},
        candidates={n: np.repeat(v, K) for n, v in cands.items()},
        blocks=scan // 5,
        order=scan + bearing / K,
        state={"bearing": bearing},
        metric_kinds={"range": "mean", "range_spread": "spread"},
    )


def _noise(rng: np.random.Generator, drift: float = 0.4, s: int = S) -> np.ndarray:
    """Student-t (df 4) noise per reading plus a slowly drifting AR(1) offset per scan."""
    t = rng.standard_t(4, size=(s, K)) / np.sqrt(2)
    return t + drift * _ar1(rng, s, 0.97)[:, None]


def _distractors(rng: np.random.Generator, s: int = S) -> dict[str, np.ndarray]:
    return {"walk_a": _walk(rng, s), "walk_b": _walk(rng, s), "time": np.arange(s) * 0.2}


def test_null_family_stays_quiet():
    """AR(1)-drifting, heavy-tailed residuals with random-walk and time candidates, 20 seeds.

    At the default family-wise alpha (0.05) about one log with a false alarm is expected; more than 3
    (probability 0.016 for a valid test) fails, and so does any alarm at alpha 0.01 beyond 1.
    """
    logs, strict = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        ev = _evaluation(rng, _noise(rng, drift=rng.uniform(0.2, 0.6)), _distractors(rng))
        rk = rank_candidates(ev, n_permutations=199, rng=np.random.default_rng(seed))
        assert rk.alpha == 0.05
        sig = [(seed, e["name"], e["form"], e["p_value"]) for e in rk.significant()]
        logs += sig[:1]
        strict += [s for s in sig if s[3] < 0.01]
    assert len(logs) <= 3, logs
    assert len(strict) <= 1, strict


def test_mean_cause_ranks_above_its_noisy_proxy():
    """A cause of 0.25 noise sd per unit beside a copy correlated 0.85 with it: the cause first in >= 5 of 6."""
    wins = []
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        n = 1000  # scans: a proxy correlated 0.85 with its cause needs a log of realistic length
        cause = _ar1(rng, n, 0.9)
        proxy = 0.85 * cause + np.sqrt(1 - 0.85**2) * rng.normal(size=n)
        resid = _noise(rng, 0.2, n) + 0.25 * cause[:, None]
        ev = _evaluation(rng, resid, {"cause": cause, "proxy": proxy, **_distractors(rng, n)})
        rk = rank_candidates(ev, n_permutations=199, rng=np.random.default_rng(seed))
        top = rk.effects[0]
        px = next(e for e in rk.effects if e["name"] == "proxy")
        wins.append(top["name"] == "cause" and top["significant"] and top["kind"] == "mean" and not px["significant"])
    assert sum(wins) >= 5, wins


def test_effect_whose_sign_follows_the_bearing_is_found_as_an_interaction():
    """``r = a c cos(bearing)``: zero mean over the scan, visible only through the bearing (>= 3 of 4 seeds)."""
    wins = []
    for seed in range(4):
        rng = np.random.default_rng(200 + seed)
        n = 600
        cause = _ar1(rng, n, 0.9)
        b = np.arange(K) * 2 * np.pi / K
        resid = _noise(rng, 0.2, n) + 0.4 * cause[:, None] * np.cos(b)[None]
        ev = _evaluation(rng, resid, {"cause": cause, **_distractors(rng, n)})
        rk = rank_candidates(ev, n_permutations=199, rng=np.random.default_rng(seed))
        top = rk.effects[0]
        wins.append(top["name"] == "cause" and top["significant"] and top["form"] == "x bearing")
    assert sum(wins) >= 3, wins


def _radar_like(rng: np.random.Generator, n: int, resid_of: object) -> tuple[Evaluation, np.ndarray]:
    """A radar-like held-out evaluation: 10 readings per cycle, each with its own range and a slow cause."""
    cyc = np.repeat(np.arange(n // 10), 10)
    rng_m = rng.uniform(5.0, 90.0, n)
    cause = np.repeat(_ar1(rng, n // 10, 0.95), 10) + 0.5 * rng.normal(size=n)
    resid = rng.standard_t(4, size=n) / np.sqrt(2) + resid_of(cause, rng_m)  # type: ignore[operator]
    ev = Evaluation(
        nll=np.zeros(n),
        residuals={"offset": resid},
        candidates={"cause": cause, "walk": np.repeat(_walk(rng, n // 10), 10), "white": rng.normal(size=n)},
        blocks=cyc // 10,
        order=cyc + np.tile(np.arange(10), n // 10) / 10,
        state={"range": rng_m},
    )
    return ev, cause


def test_effect_whose_sign_follows_the_range_is_found_as_an_interaction():
    """``r = a c sign(range - median)`` per reading (a radar offset flipping between near and far targets).

    Zero mean over each cycle; a 6 x 8 grid of cells dilutes it, a smooth candidate x state term does
    not: found, with the form ``x range``, in >= 3 of 4 seeds.
    """
    wins = []
    for seed in range(4):
        rng = np.random.default_rng(400 + seed)
        ev, _ = _radar_like(rng, 4000, lambda c, r: 0.15 * c * np.sign(r - 47.5))
        rk = rank_candidates(ev, n_permutations=199, rng=np.random.default_rng(seed))
        top = rk.effects[0]
        wins.append(top["name"] == "cause" and top["significant"] and top["form"] == "x range")
    assert sum(wins) >= 3, wins


@pytest.mark.parametrize("seed", range(3))
def test_spread_cause_is_found_as_a_spread_effect(seed):
    """The noise's scale grows by 50 % across the cause's range; its mean does not move."""
    rng = np.random.default_rng(300 + seed)
    cause = rng.uniform(0, 1, S)
    resid = rng.normal(size=(S, K)) * (1 + 0.5 * cause)[:, None]
    ev = _evaluation(rng, resid, {"cause": cause, **_distractors(rng)})
    rk = rank_candidates(ev, n_permutations=199, rng=np.random.default_rng(seed))
    top = rk.effects[0]
    assert top["name"] == "cause" and top["significant"] and top["kind"] == "spread", top


def test_a_real_trend_in_time_is_found_against_drift():
    """A trend of 2 noise sd over the log, with AR(1) drift: time is significant (no random walk beside it:
    a random walk can follow a trend as closely as time itself). The circular shifts that confirm a finding
    turn a trend into a sawtooth that still follows time: measured over 6 seeds, a 2-sd trend is confirmed
    on 6, a 1.5-sd one on 5, a 1-sd one on 3 (the flips alone found it on all, and time on null logs with
    slow drift as well)."""
    rng = np.random.default_rng(7)
    resid = _noise(rng, 0.2) + 2.0 * np.linspace(-0.5, 0.5, S)[:, None]
    ev = _evaluation(rng, resid, {"time": np.arange(S) * 0.2, "white": rng.normal(size=S)})
    rk = rank_candidates(ev, n_permutations=199)
    assert rk.effects[0]["name"] == "time" and rk.effects[0]["significant"], rk.effects[:2]


def test_candidates_with_too_few_values_are_refused_not_tested():
    rng = np.random.default_rng(1)
    flag = np.zeros(S)
    flag[0] = 1.0
    ev = _evaluation(rng, _noise(rng), {"const": np.full(S, 3.0), "flag": flag, "walk": _walk(rng, S)})
    rk = rank_candidates(ev, n_permutations=39)
    assert {r["name"] for r in rk.refused} == {"const", "flag"}
    assert [e["name"] for e in rk.effects] == ["walk"]
    assert "single distinct value" in next(r["reason"] for r in rk.refused if r["name"] == "const")


def test_time_folds_leave_gaps_and_alternate_contiguous_segments():
    f = time_folds(np.arange(600.0))
    assert set(np.unique(f)) == {-1, 0, 1}
    assert 0.1 < np.mean(f == -1) < 0.25
    runs = np.flatnonzero(np.diff(f[f >= 0]) != 0)  # fold changes in time order: one per segment boundary
    assert len(runs) == 5


def test_lidar_state_terms_interact_with_the_bearing():
    from sensor_envs.lidar.extra_state import check_extra_state, scan_features, split_term
    from sensor_envs.lidar.log import log_from_arrays

    b = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    box = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]], dtype=float)
    log = log_from_arrays(
        np.ones((3, 8, 1)), b, np.tile([2.0, 1.5, 0.0], (3, 1)), box, t=np.arange(3.0), covariates={"v": [1, 2, 3]}
    )
    f = scan_features(log, ("v", "v@cos_bearing", "v@sin_bearing", "v@sq", "v@sq@cos_bearing"), None)
    np.testing.assert_allclose(f[..., 1], np.array([1, 2, 3])[:, None] * np.cos(b)[None])
    np.testing.assert_allclose(f[..., 3], np.array([1, 4, 9])[:, None] * np.ones(8))
    np.testing.assert_allclose(f[..., 4], np.array([1, 4, 9])[:, None] * np.cos(b)[None])  # U-shaped x cos
    assert split_term("t@sin_bearing") == ("t", "sin_bearing")
    assert split_term("v@sq@range") == ("v", "sq@range")
    for bad in ("v@tan", "v@cos_bearing@sq", "v@sq@sq", "v@sq@range@incidence", "@sq"):
        with pytest.raises(ValueError, match="extra_state"):
            check_extra_state((bad,))


def test_coarse_carmen_times_are_derived_from_the_scan_rate_with_a_warning():
    from sensor_envs.lidar.log import scan_times

    t = np.repeat([100.0, 110.0], 50)
    with pytest.warns(UserWarning, match="field 't'"):
        out = scan_times(t, "x.log")
    assert np.unique(out).size == 100 and np.all(np.diff(out) > 0)
    fine = np.arange(100) * 0.2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(scan_times(fine, "x.log"), fine)


def test_improvement_interval_excludes_zero_only_for_a_real_gain():
    """Held-out NLL differences shared within blocks (drift): a gain of 0.001 nats per reading with
    block-level noise of 0.05 is not an improvement; a gain of 0.05 is."""
    from sensor_envs.diagnose.core import improvement_interval

    rng = np.random.default_rng(0)
    n, nb = 6000, 120
    blocks = np.repeat(np.arange(nb), n // nb)
    before = 1.0 + rng.normal(0.0, 0.3, n)
    shared = rng.normal(0.0, 0.05, nb)[blocks]  # a block-level wobble of the difference
    ev = Evaluation(nll=before, residuals={}, candidates={}, blocks=blocks)
    for gain, real in ((0.001, False), (0.05, True)):
        after = Evaluation(nll=before - gain - shared, residuals={}, candidates={}, blocks=blocks)
        lo, hi = improvement_interval(ev, after, np.random.default_rng(1))
        assert lo < gain < hi
        assert (lo > 0) == real, (gain, lo, hi)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"n_permutations": 5}, "n_permutations"),
        ({"n_permutations": 19}, "n_permutations"),  # 1 / 20 cannot be below alpha 0.05
        ({"n_permutations": 99.5}, "n_permutations"),
        ({"n_shifts": -1}, "n_shifts"),
        ({"n_shifts": 5}, "n_shifts"),
        ({"n_shifts": 20_000}, "n_shifts"),
        ({"alpha": 0.0}, "alpha"),
        ({"alpha": float("nan")}, "alpha"),
        ({"min_score": float("nan")}, "min_score"),
        ({"min_score": 1.0}, "min_score"),
    ],
)
def test_search_options_are_checked_in_the_python_api(kwargs, field):
    from sensor_envs.inputs import InputError

    rng = np.random.default_rng(2)
    ev = _evaluation(rng, _noise(rng), {"walk": _walk(rng, S)})
    with pytest.raises(InputError, match=f"^{field}:"):
        rank_candidates(ev, **kwargs)
