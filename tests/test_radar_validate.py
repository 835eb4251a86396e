import numpy as np
from scipy.stats import energy_distance

from sensor_envs.radar.validate import (
    block_multiplicities,
    energy_distance_2d,
    lag1_autocorr,
    row_energy_terms,
    weighted_energy,
)


def test_energy_distance_matches_scipy_in_1d():
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 1, 300), rng.normal(0.5, 2, 200)
    pad = np.zeros
    ours = energy_distance_2d(np.c_[a, pad(300)], np.c_[b, pad(200)], rng, max_n=1000)
    assert ours == __import__("pytest").approx(energy_distance(a, b) ** 2, rel=1e-9)


def test_energy_distance_separates_distributions():
    rng = np.random.default_rng(1)
    same = energy_distance_2d(rng.normal(size=(500, 2)), rng.normal(size=(500, 2)), rng)
    shifted = energy_distance_2d(rng.normal(size=(500, 2)), rng.normal(size=(500, 2)) + [1.0, 0.0], rng)
    assert shifted > 10 * same


def test_lag1_autocorr_of_an_ar1_series():
    rng = np.random.default_rng(2)
    x = np.zeros((20_000, 2))
    for t in range(1, len(x)):
        x[t] = 0.7 * x[t - 1] + rng.normal(size=2)
    np.testing.assert_allclose(lag1_autocorr(x[1:], x[:-1]), 0.7, atol=0.03)


def test_unbiased_energy_distance_centres_on_zero_for_one_law_and_the_v_statistic_does_not():
    rng = np.random.default_rng(3)
    pairs = [(rng.normal(size=(40, 2)), rng.normal(size=(15, 2))) for _ in range(400)]
    u = np.array([energy_distance_2d(a, b, unbiased=True) for a, b in pairs])
    v = np.array([energy_distance_2d(a, b) for a, b in pairs])
    se = u.std() / np.sqrt(u.size)
    assert abs(u.mean()) < 3 * se  # unbiased: the mean over replicates is zero within noise
    # the V-statistic's bias is E|A-A'|/n_a + E|B-B'|/n_b, sqrt(pi) (mean distance of two N(0, I_2) draws) / n
    assert v.mean() - u.mean() > 0.5 * np.sqrt(np.pi) * (1 / 40 + 1 / 15)
    assert np.isnan(energy_distance_2d(np.zeros((1, 2)), np.ones((5, 2)), unbiased=True))


def _rows(rng, n=60, m=5, shift=0.0):
    """Model draws (n, m, 2) and data (n, 2), each with ~20 % misses (NaN)."""
    draws = rng.normal(size=(n, m, 2))
    draws[rng.random((n, m)) < 0.2] = np.nan
    data = rng.normal(size=(n, 2)) + [shift, 0.0]
    data[rng.random(n) < 0.2] = np.nan
    return draws, data


def test_row_weighted_energy_is_the_pooled_u_statistic_and_copies_never_pair_with_themselves():
    rng = np.random.default_rng(4)
    draws, data = _rows(rng, shift=0.4)
    terms = row_energy_terms(draws, data, chunk=7)  # a chunk that does not divide the rows
    pooled = draws.reshape(-1, 2)
    want = energy_distance_2d(pooled[np.isfinite(pooled[:, 0])], data[np.isfinite(data[:, 0])], unbiased=True)
    assert weighted_energy(terms, np.ones(60))[0] == __import__("pytest").approx(want, rel=1e-12)
    # every row twice: the same law, the same figure (a U-statistic that paired copies would shrink the self terms)
    assert weighted_energy(terms, np.full(60, 2.0))[0] == __import__("pytest").approx(want, rel=1e-12)
    # weight 0 drops a row
    keep = np.arange(60) >= 10
    sub = draws[keep].reshape(-1, 2)
    want_sub = energy_distance_2d(sub[np.isfinite(sub[:, 0])], data[keep][np.isfinite(data[keep][:, 0])], unbiased=True)
    assert weighted_energy(terms, keep.astype(float))[0] == __import__("pytest").approx(want_sub, rel=1e-12)


def test_block_bootstrap_weights_whole_blocks_and_its_energy_interval_separates_a_shifted_law():
    rng = np.random.default_rng(5)
    block = np.repeat(np.arange(30), 8)
    w = block_multiplicities(block, 200, rng)
    assert w.shape == (200, 240)
    assert np.all(w.reshape(200, 30, 8).std(axis=2) == 0)  # the rows of one block weigh alike
    assert np.all(w.sum(axis=1) == 240)  # as many blocks drawn as there are (equal sizes: as many rows)
    same = weighted_energy(row_energy_terms(*_rows(rng, n=240)), w)
    shifted = weighted_energy(row_energy_terms(*_rows(rng, n=240, shift=0.5)), w)
    lo_same, hi_same = np.quantile(same, [0.025, 0.975])
    assert lo_same < 0.0 < hi_same or abs(lo_same) < 0.02  # one law: the interval reaches 0
    assert np.quantile(shifted, 0.025) > hi_same  # a 0.5 sd shift lies above the same-law interval
