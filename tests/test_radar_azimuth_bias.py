"""The radar's mounting yaw error in the KDE (format 7): estimated from a log, undone before the kernels."""

import json

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.geometry import from_polar_frame
from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.alignment import derotate_offsets, estimate_azimuth_bias, rotate_offsets
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import RadarLog, target_tuples, write_log
from sensor_envs.radar.rig import RigConfig, record_rig_log

BIAS = np.deg2rad(0.4)
"""The mounting yaw error of the synthetic radar [rad] (0.7 m of cross-range at 100 m)."""
OUTWARD = 0.5
"""Offset [m] of every detection toward the outer end of the face, before the rotation."""
WIDE = (400.0, 400.0, 0.12, 0.12)
"""A corner kernel of 20 m sd: it pools corners left and right of the boresight."""
FAST = {"cv_candidates": (0.1, 0.3, 1.0), "cv_max_tuples": 150, "random_state": 0}


def _signed_cross(z: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Counter-clockwise cross-range component [m] of offsets ``z`` at the corners' azimuths."""
    az = np.arctan2(corners[:, 1], corners[:, 0])
    return -np.sin(az) * z[:, 0] + np.cos(az) * z[:, 1]


@pytest.fixture(scope="module")
def rotated_log(outward_rig_log) -> RadarLog:
    """Detections ``OUTWARD`` m outward of the corner (plus noise), then all rotated by ``BIAS`` about the sensor."""
    return outward_rig_log(OUTWARD, BIAS)


@pytest.fixture(scope="module")
def models(rotated_log):
    """Polar-output KDEs (wide corner kernel) with the yaw error estimated, and without one."""
    kw = {"rel_variance": WIDE, "output_frame": "polar", **FAST}
    return KDERadarModel(azimuth_bias="fit", **kw).fit(rotated_log), KDERadarModel(**kw).fit(rotated_log)


def test_rotation_helpers_invert_and_keep_misses():
    rng = np.random.default_rng(0)
    corners = rng.uniform(-40, 40, (50, 2)) + [60.0, 0.0]
    z = rng.normal(size=(50, 2))
    z[4] = np.nan
    back = derotate_offsets(rotate_offsets(z, corners, 0.01), corners, 0.01)
    np.testing.assert_allclose(back, z, atol=1e-12)
    assert np.isnan(back[4]).all()
    assert rotate_offsets(z, corners, 0.0) is z  # no yaw error: the same array, the same bits
    moved = rotate_offsets(np.zeros((1, 2)), np.array([[100.0, 0.0]]), 0.01)  # a target dead ahead at 100 m
    np.testing.assert_allclose(moved, [[100 * np.cos(0.01) - 100, 100 * np.sin(0.01)]])


def test_estimate_recovers_a_rotation_beside_an_outward_offset(rotated_log):
    tt = target_tuples(rotated_log)
    got = estimate_azimuth_bias(tt.corner, tt.z)
    assert abs(got - BIAS) < np.deg2rad(0.03), np.rad2deg(got)
    # no rotation: the outward offset (mirrored on the two sides) is not taken for one
    unrotated = derotate_offsets(tt.z, tt.corner, BIAS)
    assert abs(estimate_azimuth_bias(tt.corner, unrotated)) < np.deg2rad(0.03)
    assert estimate_azimuth_bias(tt.corner[:5], tt.z[:5]) == 0.0  # too few detections to tell


@pytest.mark.parametrize("bias_deg", [0.0, -0.3])
def test_estimate_on_rig_logs_with_and_without_a_mounting_error(bias_deg):
    """The reference rig's own reflection law (no outward shift imposed) with its mounting yaw error."""
    log = record_rig_log(30, 20, 8, np.random.default_rng(2), RigConfig(azimuth_bias=np.deg2rad(bias_deg)))
    tt = target_tuples(log)
    assert abs(np.rad2deg(estimate_azimuth_bias(tt.corner, tt.z)) - bias_deg) < 0.08  # generic rig: -0.05 deg at 0


def test_the_model_keeps_both_the_outward_offset_and_the_rotation(models, rotated_log):
    fitted, plain = models
    assert abs(fitted.azimuth_bias_ - BIAS) < np.deg2rad(0.03) and plain.azimuth_bias_ == 0.0
    tt = target_tuples(rotated_log)
    far = (tt.corner[:, 0] > 70) & (np.abs(tt.corner[:, 1]) > 4)
    corners = tt.corner[far][:60]
    outward = from_polar_frame(np.tile([0.0, OUTWARD], (60, 1)), corners)
    truth = _signed_cross(rotate_offsets(outward, corners, BIAS), corners)
    for m, tol in ((fitted, 0.1), (plain, None)):
        mean, _ = m.mean_output(corners)
        err = np.abs(_signed_cross(mean, corners) - truth)
        if tol is not None:
            assert err.mean() < tol, err.mean()
        else:  # the outward frame mirrors the rotation: left and right pooled, it averages out
            assert err.mean() > 0.25, err.mean()
    rng = np.random.default_rng(1)
    z, _ = fitted.sample(np.repeat(corners[:4], 4000, axis=0), rng)
    np.testing.assert_allclose(np.nanmean(z.reshape(4, 4000, 2), axis=1), fitted.mean_output(corners[:4])[0], atol=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("with_prev", [False, True])
def test_log_prob_is_a_density_in_the_sensor_frame(models, rotated_log, with_prev):
    fitted, _ = models
    tt = target_tuples(rotated_log)
    r = np.flatnonzero(np.isfinite(tt.z_prev[:, 0]) & (tt.corner[:, 0] > 60))[3]
    state = np.concatenate([tt.corner[r], tt.z_prev[r]]) if with_prev else tt.corner[r]
    centre = fitted.mean_output(state[None])[0][0]
    g = np.linspace(-3.0, 3.0, 97)
    gx, gy = np.meshgrid(g + centre[0], g + centre[1], indexing="ij")
    zz = np.stack([gx.ravel(), gy.ravel()], axis=1)
    mass = np.exp(fitted.log_prob(zz, np.repeat(state[None], zz.shape[0], axis=0))).sum() * (g[1] - g[0]) ** 2
    p_miss = np.exp(fitted.log_prob(np.full((1, 2), np.nan), state[None]))[0]
    assert abs(mass + p_miss - 1.0) < 0.01, (mass, p_miss)


def test_file_round_trip_and_older_formats(models, tmp_path, rewrite_kde_file):
    fitted, plain = models
    loaded = KDERadarModel.load(fitted.save(tmp_path / "m.npz"))
    assert loaded.azimuth_bias == "fit" and loaded.azimuth_bias_ == fitted.azimuth_bias_
    states = fitted.states_[::37]
    a = fitted.sample(states, np.random.default_rng(3))[0]
    np.testing.assert_array_equal(a, loaded.sample(states, np.random.default_rng(3))[0])
    old = KDERadarModel.load(rewrite_kde_file(plain, tmp_path / "f6.npz", 6, ("azimuth_bias",)))
    assert old.azimuth_bias == 0.0 and old.azimuth_bias_ == 0.0
    with pytest.raises(ModelFileError, match="params.azimuth_bias"):  # format 7 must state it
        KDERadarModel.load(rewrite_kde_file(plain, tmp_path / "f7.npz", 7, ("azimuth_bias",)))


@pytest.mark.parametrize("value", [float("nan"), 0.2, "left", None])
def test_bad_fitted_angle_is_refused_naming_the_field(models, tmp_path, value):
    fitted, _ = models
    path = fitted.save(tmp_path / "m.npz")
    with np.load(path, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    header = json.loads(data["__header__"].tobytes().decode("utf-8"))
    if value is None:
        header.pop("azimuth_bias_fitted")
    else:
        header["azimuth_bias_fitted"] = value
    data["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(path, **data)
    with pytest.raises(ModelFileError, match="azimuth_bias_fitted"):
        KDERadarModel.load(path)


def test_given_angle_must_match_the_stored_one(models, tmp_path, rewrite_kde_file):
    _, plain = models
    with pytest.raises(ModelFileError, match="differs from 'params.azimuth_bias'"):
        KDERadarModel.load(rewrite_kde_file(plain, tmp_path / "m.npz", 7, params={"azimuth_bias": 0.01}))
    with pytest.raises(ValueError, match="azimuth_bias"):
        KDERadarModel(azimuth_bias=0.5).fit(RadarLog.__new__(RadarLog))


def test_cli_fit_estimates_the_angle_and_refuses_a_bad_one(rotated_log, tmp_path, capsys):
    log = tmp_path / "log.csv"
    write_log(rotated_log, log)
    out = tmp_path / "m.npz"
    assert main(["fit", "radar", str(log), "--out", str(out), "--output-frame", "polar", "--azimuth-bias", "fit"]) == 0
    m = KDERadarModel.load(out)
    assert abs(m.azimuth_bias_ - BIAS) < np.deg2rad(0.03)
    assert abs(m.card_["azimuth_bias_fitted_deg"] - np.rad2deg(m.azimuth_bias_)) < 1e-3
    capsys.readouterr()
    bad = tmp_path / "bad.npz"
    with pytest.raises(SystemExit) as exc:
        main(["fit", "radar", str(log), "--out", str(bad), "--azimuth-bias", "0.3"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--azimuth-bias" in err[0] and not bad.exists()
