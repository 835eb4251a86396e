"""The KDE radar's corner features (format 5): cartesian as before, or polar (range, azimuth)."""

from pathlib import Path

import numpy as np
import pytest

from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.kde import KDERadarModel, corner_features
from sensor_envs.radar.kde_trees import neighbours
from sensor_envs.radar.relevance import select_corner_variances, select_prev_variance
from sensor_envs.radar.rig import record_rig_log
from sensor_envs.radar.validate import chi_square

SHIPPED = Path(__file__).resolve().parents[1] / "models" / "radar_kde.npz"
POLAR_VAR = (12.0, 0.01, 0.03, 0.03)  # range 3.5 m, azimuth 5.7 deg, z_{t-1} 0.17 m


OLD_DROP = ("state_transform", "relevance_candidates_azimuth")
"""Parameters files before format 5 lack."""


@pytest.fixture(scope="module")
def polar():
    log = record_rig_log(20, 30, 8, np.random.default_rng(11))
    return KDERadarModel(
        rel_variance=POLAR_VAR,
        state_transform="polar",
        cv_candidates=(0.1, 0.3, 1.0),
        cv_max_tuples=150,
        random_state=0,
    ).fit(log)


def test_format4_files_load_cartesian_and_behave_as_saved(model, tmp_path, rewrite_kde_file):
    old = KDERadarModel.load(rewrite_kde_file(model, tmp_path / "f4.npz", 4, OLD_DROP))
    assert old.state_transform == "cartesian" and KDERadarModel.load(SHIPPED).state_transform == "cartesian"
    states = model.states_[::97]
    z = np.where(np.isnan(model.z_[::97]), 0.3, model.z_[::97])
    np.testing.assert_array_equal(old.log_prob(z, states), model.log_prob(z, states))
    a, b = old.sample(states, np.random.default_rng(1)), model.sample(states, np.random.default_rng(1))
    np.testing.assert_array_equal(a[1], b[1])


def test_format5_file_must_name_its_corner_features(model, tmp_path, rewrite_kde_file):
    with pytest.raises(ModelFileError, match="params.state_transform"):
        KDERadarModel.load(rewrite_kde_file(model, tmp_path / "f5.npz", 5, drop=("state_transform",)))


def test_polar_kernel_weights_range_and_azimuth(polar, tmp_path):
    """Weights are exp(-((dr / s_r)^2 + (daz / s_az)^2) / 2): near left and right corners are not mixed."""
    q = np.array([[8.0, 3.0]])
    gi, w, _ = neighbours(polar, q, None, grp=np.array([1]))  # start tree: corner features only
    f, fq = corner_features(polar.states_[gi, :2], "polar"), corner_features(q, "polar")
    expect = np.exp(-0.5 * (((f - fq) / np.sqrt(POLAR_VAR[:2])) ** 2).sum(axis=1))
    np.testing.assert_allclose(w, expect, rtol=1e-12)
    assert (f[:, 1] > 0).all()  # nothing right of the boresight for a corner 20 deg left
    loaded = KDERadarModel.load(polar.save(tmp_path / "polar.npz"))
    assert loaded.state_transform == "polar"
    states = polar.states_[::89]
    z = np.where(np.isnan(polar.z_[::89]), 0.3, polar.z_[::89])
    np.testing.assert_array_equal(loaded.log_prob(z, states), polar.log_prob(z, states))


@pytest.mark.parametrize("sampler", ["bucket", "ball"])
def test_polar_samples_follow_the_analytic_pdf(polar, sampler):
    polar.sampler = sampler
    try:
        det = np.flatnonzero(~np.isnan(polar.states_[:, 2]) & ~np.isnan(polar.z_[:, 0]))
        state = polar.states_[det[len(det) // 3]]
        res = chi_square(polar, state, np.random.default_rng(7), n=60_000)
        assert res["p_value"] > 1e-3, (res["statistic"], res["dof"])
    finally:
        polar.sampler = "auto"


def test_polar_relevance_cv_picks_from_the_candidates():
    log = record_rig_log(8, 15, 6, np.random.default_rng(2))
    est = KDERadarModel(state_transform="polar", cv_min_tuples=10, random_state=0)
    (vr, va), scores = select_corner_variances(log, est, (6.0, 48.0), (0.005, 0.08), 2)
    assert vr in (6.0, 48.0) and va in (0.005, 0.08) and scores.shape == (4,) and np.isfinite(scores).all()
    assert scores[2 + (0.005, 0.08).index(va)] == scores[2:].max()


@pytest.mark.slow
def test_cv_state_chooses_the_previous_output_variance_on_the_training_log(tmp_path, rewrite_kde_file):
    """``relevance="cv_state"``: corner x and y variances, then the z_{t-1} variance, all from their candidates."""
    log = record_rig_log(8, 15, 6, np.random.default_rng(3))
    prev = (0.01, 0.3, 3.0)
    model = KDERadarModel(
        relevance="cv_state",
        relevance_candidates=(6.0, 48.0),
        relevance_candidates_prev=prev,
        relevance_folds=2,
        cv_min_tuples=10,
        random_state=0,
    ).fit(log)
    vx, vy, px, py = model.rel_variance_
    assert vx in (6.0, 48.0) and vy in (6.0, 48.0) and px == py and px in prev
    scores = model.relevance_scores_
    assert scores.shape == (2 + 2 + 3,) and np.isfinite(scores).all()
    assert scores[4 + prev.index(px)] == scores[4:].max()
    # the same score as a plain fit with the chosen variances, held out by the same folds
    ref = select_prev_variance(log, KDERadarModel(rel_variance=(vx, vy, 0.03, 0.03), cv_min_tuples=10), prev, 2)[1]
    np.testing.assert_allclose(ref, scores[4:])
    path = model.save(tmp_path / "m.npz")
    again = KDERadarModel.load(path)
    assert again.rel_variance_ == model.rel_variance_ and tuple(again.relevance_candidates_prev) == prev
    # files written before the parameter existed load with its default
    old = KDERadarModel.load(rewrite_kde_file(model, tmp_path / "old.npz", 5, drop=("relevance_candidates_prev",)))
    assert old.rel_variance_ == model.rel_variance_


def test_log_prob_in_chunks_equals_all_rows_at_once(monkeypatch):
    """``log_prob`` splits long inputs into chunks of rows (bounded memory); the figures do not change."""
    import sensor_envs.radar.kde_density as kde_module  # log_prob reads the chunk size there

    log = record_rig_log(6, 15, 6, np.random.default_rng(5))
    model = KDERadarModel(rel_variance=(12.0, 12.0, 0.5, 0.5), cv_min_tuples=10, random_state=0).fit(log)
    rows = model.states_[:300]
    z = model.z_[:300] + 0.1
    flags = np.isnan(rows[:, 2]) & (np.arange(300) % 2 == 0)  # new tracks among the rows without z_{t-1}
    whole = model.log_prob(z, rows, new_track=flags)
    monkeypatch.setattr(kde_module, "LOG_PROB_CHUNK", 37)
    np.testing.assert_array_equal(model.log_prob(z, rows, new_track=flags), whole)
    assert np.isfinite(whole).all()
