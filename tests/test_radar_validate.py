import numpy as np
from scipy.stats import energy_distance

from sensor_envs.radar.validate import energy_distance_2d, lag1_autocorr


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
