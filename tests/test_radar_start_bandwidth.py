"""The start trees' own bandwidth factor (``start_bandwidth_scale``, format 7)."""

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import target_tuples, write_log

FAST = {"cv_candidates": (0.1, 0.3, 1.0), "cv_max_tuples": 150, "random_state": 0, "output_frame": "polar"}


@pytest.fixture(scope="module")
def log(outward_rig_log):
    return outward_rig_log(0.5)


@pytest.fixture(scope="module")
def model(log):
    return KDERadarModel(bandwidth_scale=0.5, **FAST).fit(log)


def _queries(log):
    """Corners with a previous output (main trees) and after a miss (start trees), as NaN-padded states."""
    tt = target_tuples(log)
    has_prev = np.isfinite(tt.z_prev[:, 0])
    main_rows = np.flatnonzero(has_prev & np.isfinite(tt.z[:, 0]))[:40]
    start_rows = np.flatnonzero(~has_prev & np.isfinite(tt.z[:, 0]))[:40]
    st_main = np.concatenate([tt.corner[main_rows], tt.z_prev[main_rows]], axis=1)
    st_start = np.concatenate([tt.corner[start_rows], np.full((len(start_rows), 2), np.nan)], axis=1)
    return (st_main, tt.z[main_rows]), (st_start, tt.z[start_rows])


def test_start_factor_widens_only_start_queries(model, log):
    wide = model.with_start_bandwidth_scale(1.0)
    corners = model.states_[:5, :2]
    np.testing.assert_allclose(wide.bandwidth(corners, start=True), 2.0 * model.bandwidth(corners, start=True))
    np.testing.assert_array_equal(wide.bandwidth(corners), model.bandwidth(corners))
    assert model.with_start_bandwidth_scale(None).start_bandwidth_scale is None
    (st_m, z_m), (st_s, z_s) = _queries(log)
    np.testing.assert_array_equal(wide.log_prob(z_m, st_m), model.log_prob(z_m, st_m))  # main trees: same bits
    assert not np.allclose(wide.log_prob(z_s, st_s), model.log_prob(z_s, st_s))
    # the start-tree samples spread about twice as far from their source tuple
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    many = np.repeat(st_s[:1], 4000, axis=0)
    a, b = model.sample(many, rng_a)[0], wide.sample(many, rng_b)[0]
    da, db = a - model.mean_output(st_s[:1])[0][0], b - model.mean_output(st_s[:1])[0][0]
    assert np.nanstd(db) > 1.2 * np.nanstd(da)
    # after a main-tree rescale, the start factor stays the absolute factor on the CV table
    both = wide.with_bandwidth_scale(0.5)
    np.testing.assert_allclose(both.bandwidth(corners, start=True), wide.bandwidth(corners, start=True))


def test_round_trip_older_file_and_bad_value(model, tmp_path, rewrite_kde_file):
    wide = model.with_start_bandwidth_scale(0.9)
    loaded = KDERadarModel.load(wide.save(tmp_path / "m.npz"))
    assert loaded.start_bandwidth_scale == 0.9
    corners = model.states_[:5, :2]
    np.testing.assert_array_equal(loaded.bandwidth(corners, start=True), wide.bandwidth(corners, start=True))
    old = KDERadarModel.load(rewrite_kde_file(model, tmp_path / "f6.npz", 6, ("start_bandwidth_scale",)))
    assert old.start_bandwidth_scale is None
    for bad in (-1.0, 0.0, float("nan"), "wide"):
        with pytest.raises(ModelFileError, match="start_bandwidth_scale"):
            KDERadarModel.load(rewrite_kde_file(model, tmp_path / "bad.npz", 7, params={"start_bandwidth_scale": bad}))
    with pytest.raises(ValueError, match="start_bandwidth_scale"):
        model.with_start_bandwidth_scale(-2.0)


def test_cli_fit_stores_the_start_factor(log, tmp_path, capsys):
    path = tmp_path / "log.csv"
    write_log(log, path)
    out = tmp_path / "m.npz"
    args = ["fit", "radar", str(path), "--out", str(out), "--output-frame", "polar", "--relevance", "paper"]
    assert main([*args, "--start-bandwidth-scale", "1.5"]) == 0
    assert KDERadarModel.load(out).start_bandwidth_scale == 1.5
    capsys.readouterr()
    bad = tmp_path / "bad.npz"
    with pytest.raises(SystemExit) as exc:
        main([*args[:3], "--out", str(bad), "--start-bandwidth-scale", "-1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "start-bandwidth-scale" in err[0].replace("_", "-") and not bad.exists()
