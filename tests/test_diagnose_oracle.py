"""The oracle's detectability test: it finds a planted effect and holds its level on slow null residuals."""

from __future__ import annotations

import numpy as np

from sensor_envs.diagnose.core import Evaluation
from sensor_envs.diagnose.power import detectable, oracle_test


def _ev(rng: np.random.Generator, effect: float, n: int = 3000) -> Evaluation:
    """Residuals with slow AR(1) drift, a random-walk candidate ``c`` and a lateral state; ``effect`` x c x side."""
    drift = np.zeros(n)
    for i in range(1, n):
        drift[i] = 0.99 * drift[i - 1] + 0.14 * rng.normal()
    c = np.cumsum(rng.normal(size=n)) / np.sqrt(n)
    y = rng.normal(size=n)
    side = np.sign(y)
    cz = (c - c.mean()) / c.std()
    r = rng.standard_t(4, size=n) + drift + effect * cz * side
    return Evaluation(
        nll=np.zeros(n),
        residuals={"offset": r, "noise": rng.normal(size=n)},
        candidates={"c": c, "other": rng.normal(size=n)},
        blocks=np.arange(n) // 50,
        order=np.arange(n, dtype=np.float64),
        state={"lateral": y},
    )


def test_a_planted_interaction_is_detectable_and_located() -> None:
    rng = np.random.default_rng(3)
    ok, t = detectable(_ev(rng, 0.6), "c", n_candidates=30)
    assert ok and t["best"].startswith("offset x lateral")
    assert t["tests"] == 2 * 3  # two targets x (main + two factors of one state feature)


def test_slow_null_residuals_keep_the_oracle_near_its_level() -> None:
    rng = np.random.default_rng(4)
    tests = [oracle_test(_ev(rng, 0.0), "c", n_flips=4000) for _ in range(60)]
    # the best raw p of 6 tests: about 1 - 0.95 ** 6 = 0.26 of null draws fall below 0.05
    assert np.mean([t["p_raw"] < 0.05 for t in tests]) < 0.45
    assert np.mean([t["p_value"] < 0.05 for t in tests]) <= 0.15  # Bonferroni over the 6: about 0.05
