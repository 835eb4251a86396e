import pickle

import numpy as np
import pytest
from sklearn.exceptions import NotFittedError

from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import REQUIRED_COLUMNS, RadarLog, target_tuples
from sensor_envs.radar.rig import record_rig_log
from sensor_envs.radar.validate import chi_square, lag1_autocorr, rollout

P_MIN = 1e-3  # chi-square tests: a correct sampler fails each with probability 0.1 % (seeds are fixed)
AUTOCORR_TOL = 0.15  # |lag-1 autocorrelation simulated - recorded| allowed with z_{t-1} (rig, 1 s cycles)


def _states(model):
    tt_idx = np.flatnonzero(~np.isnan(model.states_[:, 2]) & ~np.isnan(model.z_[:, 0]))
    i = tt_idx[np.argsort(np.hypot(*model.states_[tt_idx, :2].T))]
    picks = model.states_[i[[len(i) // 5, len(i) // 2, 4 * len(i) // 5]]]
    start = picks[0].copy()
    start[2:] = np.nan
    return [*picks, start]


@pytest.mark.parametrize("sampler", ["bucket", "ball"])  # "ball" = the reference sampler
def test_samples_follow_the_analytic_pdf(model, sampler):
    m = pickle.loads(pickle.dumps(model))
    m.sampler = sampler
    for k, state in enumerate(_states(model)):
        res = chi_square(m, state, np.random.default_rng(100 + k), n=95_000)
        assert res["dof"] > 20
        assert res["p_value"] > P_MIN, (state, res["statistic"], res["dof"])


@pytest.mark.slow
def test_bucket_sampler_with_strong_miss_prior_and_fine_grid(rig_split):
    # a large pseudo-weight makes the pseudo-tuple paths (miss / detected-after-pseudo) frequent
    m = KDERadarModel(miss_prior=30.0, bucket_cell=1.5, sampler="bucket", random_state=0).fit(rig_split[0])
    for k, state in enumerate(_states(m)[2:]):  # one state with z_{t-1}, one start state
        res = chi_square(m, state, np.random.default_rng(200 + k), n=95_000)
        assert res["p_value"] > P_MIN, (state, res["statistic"], res["dof"])


@pytest.fixture(scope="module")
def no_prev_model(rig_split):
    """The KDE without ``z_{t-1}`` in its state, on ``rig_split``'s training part (shared, never modified)."""
    return KDERadarModel(use_prev=False, random_state=0).fit(rig_split[0])


def test_without_previous_output_samples_follow_pdf(no_prev_model):
    m = no_prev_model
    res = chi_square(m, np.array([30.0, 3.0]), np.random.default_rng(5), n=95_000)
    assert res["p_value"] > P_MIN


def test_chi_square_detects_a_wrong_sampler(model):
    state = _states(model)[1]

    class Shifted:
        def sample(self, s, rng):
            z, src = model.sample(s, rng)
            return z + np.array([0.05, 0.0]), src

        def bin_probabilities(self, s, ex, ey):
            return model.bin_probabilities(s, ex, ey)

    assert chi_square(Shifted(), state, np.random.default_rng(3), n=95_000)["p_value"] < P_MIN


def _brute_log_prob(m, z, state):
    """Slow reference: loop over every stored tuple (the 4-D tree only for states with z_{t-1})."""
    out = []
    for zz, st in zip(z, state, strict=True):
        has_prev = m.use_prev and np.isfinite(st[2])
        idx = m._main_idx if has_prev else m._start_idx
        d = 4 if has_prev else 2
        w = np.array([np.exp(-0.5 * np.sum(((m.states_[i, :d] - st[:d]) / m.scale_[:d]) ** 2)) for i in idx])
        r = np.array([np.sqrt(np.sum(((m.states_[i, :d] - st[:d]) / m.scale_[:d]) ** 2)) for i in idx])
        w[r > m.radius] = 0.0
        miss = np.isnan(m.z_[idx, 0])
        rate = np.isnan(m.z_[idx, 0]).mean() if m.prior_rate == "tree" else np.isnan(m.z_[:, 0]).mean()
        p_miss = (w[miss].sum() + m.miss_prior * rate) / (w.sum() + m.miss_prior)
        if np.isnan(zz[0]):
            out.append(np.log(p_miss))
            continue
        h = m.bandwidth(st[None, :2])[0]
        k = [np.exp(-0.5 * np.sum(((zz - m.z_[i]) / h) ** 2)) / (2 * np.pi * h[0] * h[1]) for i in idx[~miss]]
        out.append(np.log1p(-p_miss) + np.log(np.dot(w[~miss], k) / w[~miss].sum()))
    return np.array(out)


def test_log_prob_matches_brute_force(model):
    states = np.array(_states(model))
    z = np.array([[0.1, -0.2], [np.nan, np.nan], [0.5, 0.3], [-0.3, 0.4]])
    np.testing.assert_allclose(model.log_prob(z, states), _brute_log_prob(model, z, states), rtol=1e-9)


@pytest.mark.parametrize("distinct", [False, True])
def test_source_tuple_is_traceable(model, distinct):
    # repeated states share one neighbour search; distinct ones (>= 64) go through the sorted-group path
    states = model.states_[:300] if distinct else np.array(_states(model) * 50)
    z, src = model.sample(states, np.random.default_rng(0))
    det = ~np.isnan(z[:, 0])
    assert (src[det] >= 0).all() and det.any() and (~det).any()
    traced = src >= 0  # misses drawn from the miss_prior share have no source tuple
    assert np.array_equal(np.isnan(z[traced, 0]), np.isnan(model.z_[src[traced], 0]))
    h = model.bandwidth(states[det, :2])
    assert np.all(np.abs(z[det] - model.z_[src[det]]) < 6 * h)


def _uniform_miss_log(rate, rng, n=4000):
    cols = {c: np.zeros(n) for c in REQUIRED_COLUMNS}
    cols["frame"] = np.arange(n)
    cols["t"] = cols["frame"] * 1.0  # one cycle per second: later frames, later times
    cols["target"] = np.arange(n)  # no z_{t-1}
    cols["ref_x"], cols["ref_y"] = rng.uniform(10, 30, n), rng.uniform(-5, 5, n)
    cols["ref_length"], cols["ref_width"] = np.full(n, 4.0), np.full(n, 2.0)
    miss = rng.random(n) < rate
    cols["meas_x"] = np.where(miss, np.nan, cols["ref_x"] - 2 + rng.normal(0, 0.3, n))
    cols["meas_y"] = np.where(miss, np.nan, cols["ref_y"] + rng.normal(0, 0.3, n))
    return RadarLog(cols), miss.mean()


def test_missing_measurement_tuples_give_misses_at_the_recorded_rate():
    log, recorded = _uniform_miss_log(0.3, np.random.default_rng(2))
    m = KDERadarModel(use_prev=False, miss_prior=0.0, random_state=0).fit(log)
    corners = target_tuples(log).corner
    z, src = m.sample(np.repeat(corners, 10, axis=0), np.random.default_rng(3))
    sim = np.isnan(z[:, 0]).mean()
    n = z.shape[0]
    # local kernel estimates average to the recorded rate (tolerance: 4 binomial sigmas of the log + sampling)
    tol = 4 * np.sqrt(recorded * (1 - recorded) * (1 / len(log) + 1 / n))
    assert abs(sim - recorded) < tol, (sim, recorded, tol)
    assert np.isnan(m.z_[src[np.isnan(z[:, 0])], 0]).all()


def test_autocorrelation_reproduced_with_previous_output(rig_split, model, no_prev_model):
    _, test = rig_split
    tt = target_tuples(test)
    measured = lag1_autocorr(tt.z, tt.z_prev)
    # mean of 5 rollouts: one rollout's lag-1 autocorrelation varies by ~0.015-0.05 (std) from seed to seed
    with_prev = np.mean([lag1_autocorr(*rollout(model, tt, np.random.default_rng(s))) for s in range(5)], axis=0)
    without = np.mean([lag1_autocorr(*rollout(no_prev_model, tt, np.random.default_rng(s))) for s in range(5)], axis=0)
    assert np.all(np.abs(with_prev - measured) < AUTOCORR_TOL), (with_prev, measured)
    assert np.all(without < with_prev - 0.1), (without, with_prev)


def test_detection_rate_after_a_detection_is_kept_in_closed_loop(rig_split, model):
    # simulated z_{t-1} often has few recorded neighbours; the miss prior must then shrink toward the
    # miss rate of tuples WITH a previous output, not the log's overall rate (measured: 0.65-0.68 vs 0.79)
    tt = target_tuples(rig_split[1])
    after = tt.has_prev_row & ~np.isnan(tt.z_prev[:, 0])
    recorded = np.mean(~np.isnan(tt.z[after, 0]))
    z, zp = rollout(model, tt, np.random.default_rng(0))
    sim_after = tt.has_prev_row & ~np.isnan(zp[:, 0])
    assert abs(np.mean(~np.isnan(z[sim_after, 0])) - recorded) < 0.04, recorded


def _offset_log(rng, sharp, n=800):
    """Outputs independent of position (``sharp=False``) or flipping sign every 2 m of ``ref_y``."""
    cols = {c: np.zeros(n) for c in REQUIRED_COLUMNS}
    cols["sequence"], cols["frame"], cols["target"] = np.arange(n) % 8, np.arange(n), np.zeros(n)
    cols["t"] = cols["frame"] * 1.0  # one cycle per second: later frames, later times
    cols["ref_x"], cols["ref_y"] = rng.uniform(10, 40, n), rng.uniform(-8, 8, n)
    cols["ref_length"], cols["ref_width"] = np.full(n, 4.0), np.full(n, 2.0)
    sign = np.where(np.floor(cols["ref_y"] / 2) % 2 == 0, 1.0, -1.0) if sharp else rng.choice([-1.0, 1.0], n)
    cols["meas_x"] = cols["ref_x"] - 2 + 0.1 * rng.standard_normal(n)
    cols["meas_y"] = cols["ref_y"] + sign + 0.1 * rng.standard_normal(n)
    return RadarLog(cols)


@pytest.mark.parametrize(("sharp", "expected"), [(True, 1.0), (False, 48.0)])
def test_relevance_cv_picks_the_kernel_width_the_data_support(sharp, expected):
    log = _offset_log(np.random.default_rng(3), sharp)
    m = KDERadarModel(
        use_prev=False,
        cv_group="sequence",
        relevance="cv",
        relevance_candidates=(1.0, 48.0),
        relevance_folds=2,
        cv_grid_step=8.0,
        cv_max_tuples=100,
        random_state=0,
    ).fit(log)
    assert m.rel_variance_[:2] == (expected, expected), m.relevance_scores_
    assert m.rel_variance == (3.0, 3.0, 0.03, 0.03)  # the hyper-parameter is untouched


def test_exact_and_capped_search_agree_when_cap_is_large(model, tmp_path):
    path = model.save(tmp_path / "m.npz")
    capped = KDERadarModel.load(path)
    capped.k_max = 100_000
    states = np.array(_states(model))
    np.testing.assert_allclose(capped.log_prob(np.zeros((4, 2)), states), model.log_prob(np.zeros((4, 2)), states))


def test_save_load_roundtrip_without_pickle(model, tmp_path):
    path = model.save(tmp_path / "m.npz", card={"note": "test"})
    with np.load(path, allow_pickle=False) as f:
        assert all(f[k].dtype != object for k in f.files)
    back = KDERadarModel.load(path)
    states = np.array(_states(model) * 20)
    for other in (back, pickle.loads(pickle.dumps(model))):
        a = model.sample(states, np.random.default_rng(7))
        b = other.sample(states, np.random.default_rng(7))
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])
    assert back.cycle_time_ == 1.0


def test_bad_model_file_and_unfitted(tmp_path):
    with pytest.raises(NotFittedError):
        KDERadarModel().sample(np.zeros((1, 2)), np.random.default_rng(0))
    bad = tmp_path / "bad.npz"
    np.savez(bad, x=np.zeros(3))
    with pytest.raises(ModelFileError, match="__header__"):
        KDERadarModel.load(bad)
    with pytest.raises(ValueError, match="rel_variance"):
        KDERadarModel(rel_variance=(1.0, -1.0, 1.0, 1.0)).fit(_uniform_miss_log(0.1, np.random.default_rng(0))[0])


def test_same_seed_same_samples_and_clutter(model):
    s = np.array(_states(model))
    a, b = model.sample(s, np.random.default_rng(1)), model.sample(s, np.random.default_rng(1))
    np.testing.assert_array_equal(a[0], b[0])
    c = [model.sample_clutter(np.random.default_rng(2)) for _ in range(2)]
    np.testing.assert_array_equal(*c)


def test_row_order_invariance():
    log = record_rig_log(8, 20, 6, np.random.default_rng(4))
    perm = np.random.default_rng(0).permutation(len(log))
    shuffled = RadarLog({k: v[perm] for k, v in log.columns.items()})
    kw = {"cv_max_tuples": 10**6, "cv_min_tuples": 10, "random_state": 0}
    a, b = KDERadarModel(**kw).fit(log), KDERadarModel(**kw).fit(shuffled)
    tt = target_tuples(log)
    st = np.concatenate([tt.corner, tt.z_prev], axis=1)[:200]
    np.testing.assert_allclose(a.log_prob(tt.z[:200], st), b.log_prob(tt.z[:200], st), rtol=1e-10)


def test_clutter_follows_the_log(rig_split, model):
    from sensor_envs.radar.log import clutter_counts

    counts, xy = clutter_counts(rig_split[0])
    rng = np.random.default_rng(9)
    sims = [model.sample_clutter(rng) for _ in range(4000)]
    n = np.array([len(s) for s in sims])
    assert abs(n.mean() - counts.mean()) < 4 * counts.std() / np.sqrt(len(n)) + 4 * counts.std() / np.sqrt(len(counts))
    pts = np.concatenate(sims)
    assert abs(np.median(np.hypot(*pts.T)) - np.median(np.hypot(*xy.T))) < 3.0


def test_stored_clutter_is_capped_by_a_uniform_subsample(rig_split, model, monkeypatch):
    """Beyond ``MAX_CLUTTER_POSITIONS`` the model stores a uniform subsample of the clutter rows (same law)."""
    import sensor_envs.radar.kde_fit as kde  # the fit reads the cap

    train, _ = rig_split
    full = model  # the same fit, under the default cap
    n = full.clutter_xy_.shape[0]
    monkeypatch.setattr(kde, "MAX_CLUTTER_POSITIONS", n // 4)
    capped = KDERadarModel(random_state=0).fit(train, cycle_time=1.0)
    assert capped.clutter_xy_.shape[0] == n // 4
    np.testing.assert_array_equal(capped.clutter_counts_, full.clutter_counts_)  # counts per cycle untouched
    rows = {tuple(r) for r in full.clutter_xy_}
    assert all(tuple(r) in rows for r in capped.clutter_xy_)  # a subset of the log's rows
    np.testing.assert_allclose(capped.clutter_xy_.mean(0), full.clutter_xy_.mean(0), atol=3.0)
    np.testing.assert_array_equal(capped.z_, full.z_)  # the cap is drawn last: nothing else changes


def test_bandwidth_scale_fits_the_same_model_as_rescaling_after(tmp_path, rewrite_kde_file):
    """``bandwidth_scale=f`` multiplies the CV bandwidths and changes nothing else; ``with_bandwidth_scale``
    gives the same model from a fit at 1; the factor survives save / load; files without it load as 1."""
    from sensor_envs.radar.rig import record_rig_log

    log = record_rig_log(12, 20, 6, np.random.default_rng(3))
    plain = KDERadarModel(random_state=0).fit(log, cycle_time=1.0)
    narrow = KDERadarModel(random_state=0, bandwidth_scale=0.5).fit(log, cycle_time=1.0)
    np.testing.assert_allclose(narrow.log_h_, plain.log_h_ + np.log(0.5))
    np.testing.assert_array_equal(narrow.z_, plain.z_)
    after = plain.with_bandwidth_scale(0.5)
    assert after.bandwidth_scale == 0.5 and plain.bandwidth_scale == 1.0  # a copy: the original is unchanged
    np.testing.assert_array_equal(after.log_h_, narrow.log_h_)
    states = np.array(_states(plain) * 10)
    a, b = narrow.sample(states, np.random.default_rng(5)), after.sample(states, np.random.default_rng(5))
    np.testing.assert_array_equal(a[0], b[0])
    corners = states[:, :2]
    np.testing.assert_allclose(narrow.bandwidth(corners), 0.5 * plain.bandwidth(corners))
    back = KDERadarModel.load(narrow.save(tmp_path / "narrow.npz"))
    assert back.bandwidth_scale == 0.5
    np.testing.assert_array_equal(back.log_h_, narrow.log_h_)
    old = rewrite_kde_file(plain, tmp_path / "f6.npz", 6, ("bandwidth_scale", "start_bandwidth_scale", "azimuth_bias"))
    assert KDERadarModel.load(old).bandwidth_scale == 1.0  # written before the factor: 1


@pytest.mark.parametrize("bad", [0.0, -0.5, float("nan"), 1000.0])
def test_bad_bandwidth_scale_is_refused_naming_it(bad):
    with pytest.raises(ValueError, match="bandwidth_scale"):
        KDERadarModel(bandwidth_scale=bad).fit(_uniform_miss_log(0.1, np.random.default_rng(0))[0])
    fitted = KDERadarModel(random_state=0).fit(_uniform_miss_log(0.1, np.random.default_rng(0))[0])
    with pytest.raises(ValueError, match="bandwidth_scale"):
        fitted.with_bandwidth_scale(bad)
