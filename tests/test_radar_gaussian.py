import numpy as np
import pytest
from scipy.stats import multivariate_normal
from sklearn.exceptions import NotFittedError

from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.log import target_tuples
from sensor_envs.radar.rig import record_rig_log


@pytest.fixture(scope="module")
def fitted():
    log = record_rig_log(20, 30, 8, np.random.default_rng(3))
    return GaussianRadar().fit(log, cycle_time=1.0), log


def test_log_prob_matches_scipy(fitted):
    g, log = fitted
    tt = target_tuples(log)
    st = np.concatenate([tt.corner, tt.z_prev], axis=1)[:50]
    z = np.where(np.isnan(tt.z[:50]), np.nan, tt.z[:50])
    lp = g.log_prob(z, st)
    b = g._bin(st[:, :2], g.edges_)
    for i in range(50):
        pd = g.p_detect_[b[i]]
        mvn = multivariate_normal(g.mean_[b[i]], g.cov_[b[i]])
        ref = np.log(1 - pd) if np.isnan(z[i, 0]) else np.log(pd) + mvn.logpdf(z[i])
        assert lp[i] == pytest.approx(ref, rel=1e-9)


def test_detection_rate_and_moments_of_samples(fitted):
    g, _ = fitted
    corner = np.tile([[40.0, 2.0]], (40_000, 1))
    z, src = g.sample_cycle(corner, None, np.random.default_rng(0))
    b = g._bin(corner[:1], g.edges_)[0]
    det = ~np.isnan(z[:, 0])
    p = g.p_detect_[b]
    assert abs(det.mean() - p) < 4 * np.sqrt(p * (1 - p) / len(det))
    tol = 5 * np.sqrt(g.cov_[b].diagonal().max() / det.sum())
    np.testing.assert_allclose(z[det].mean(axis=0), g.mean_[b], atol=tol)
    assert (src == -1).all()


def test_save_load_roundtrip(fitted, tmp_path):
    g, _ = fitted
    back = GaussianRadar.load(g.save(tmp_path / "g.npz"))
    c = np.array([[10.0, 0.0], [60.0, -5.0]])
    np.testing.assert_array_equal(
        g.sample_cycle(c, None, np.random.default_rng(1))[0], back.sample_cycle(c, None, np.random.default_rng(1))[0]
    )
    assert back.cycle_time_ == 1.0


def test_unfitted_and_bad_edges():
    with pytest.raises(NotFittedError, match="not fitted"):
        GaussianRadar().sample_clutter(np.random.default_rng(0))
    log = record_rig_log(1, 5, 4, np.random.default_rng(0))
    with pytest.raises(ValueError, match="range_edges"):
        GaussianRadar(range_edges=(10.0, 5.0)).fit(log)
