import numpy as np
import pytest
from scipy.stats import chi2

from sensor_envs.radar.buckets import build_buckets, sample_proportional

P_MIN = 1e-3  # a correct sampler fails each chi-square test with probability 0.1 % (seeds are fixed)


def _chi2_p(counts, probs):
    exp = probs * counts.sum()
    keep = exp > 0
    assert counts[~keep].sum() == 0, "a zero-probability outcome was drawn"
    stat = np.sum((counts[keep] - exp[keep]) ** 2 / exp[keep])
    return chi2.sf(stat, keep.sum() - 1)


@pytest.mark.parametrize(
    ("dim", "cell", "pseudo", "stop"), [(2, 1.0, 0.0, 1.0), (4, 3.0, 1.0, 1.0), (4, 2.0, 2.0, 0.3), (2, 5.0, 0.5, 0.0)]
)
def test_picks_follow_the_truncated_kernel_weights(dim, cell, pseudo, stop):
    rng = np.random.default_rng(dim)
    pts = rng.normal(0, 2.0, (60, dim))
    flag = rng.random(60) < 0.4  # "not allowed" after a non-final pseudo draw
    index = build_buckets(pts, cell, 3.0, flag=flag)
    q = np.full(dim, 0.5)
    d2 = np.sum((pts - q) ** 2, axis=1)
    w = np.where(d2 <= 9.0, np.exp(-0.5 * d2), 0.0)
    # brute force: P(i) = w_i/(W+a) + a/(W+a) (1-stop) w_i [allowed] / W_allowed; P(pseudo final) = a stop/(W+a)
    wa = w * ~flag
    p = w / (w.sum() + pseudo) + (pseudo * (1 - stop) / (w.sum() + pseudo)) * wa / wa.sum()
    probs = np.append(p, pseudo * stop / (w.sum() + pseudo))
    n = 20_000
    pick, done, _ = sample_proportional(
        index, np.repeat(q[None], n, axis=0), pseudo, rng, allowed=~flag, pseudo_stop=stop
    )
    assert done.all()
    counts = np.bincount(np.where(pick < 0, 60, pick), minlength=61)
    assert _chi2_p(counts, probs) > P_MIN


def test_empty_reach_gives_up_or_pseudo():
    index = build_buckets(np.zeros((5, 2)), 1.0, 3.0)
    far = np.array([[50.0, 50.0]])
    pick, done, via = sample_proportional(index, far, 0.0, np.random.default_rng(0))
    assert not done[0] and pick[0] == -1 and not via[0]
    pick, done, via = sample_proportional(index, far, 1.0, np.random.default_rng(0))
    assert done[0] and pick[0] == -1 and via[0]


def test_grid_too_large_is_refused():
    assert build_buckets(np.array([[0.0, 0.0], [1e6, 1e6]]), 1.0, 3.0) is None
