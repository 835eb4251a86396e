import numpy as np
import pytest

from sensor_envs.radar.astyx import detection_statistics, frame_rows, load_astyx
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import target_tuples


def test_frame_rows_on_a_synthetic_frame():
    boxes = np.array([[20.0, 0.0, 0.0, 4.0, 2.0, 0, 0, 0], [40.0, 5.0, 0.0, 4.0, 2.0, 0, 0, 0]])
    pts = np.array(
        [
            [18.2, 0.1, 0, 0, 50],
            [18.6, -0.4, 0, 0, 40],
            [19.0, 0.5, 0, 0, 45],  # on box 0
            [70.0, -20.0, 0, 0, 30],
            [70.5, -20.3, 0, 0, 30],
        ]
    )  # clutter cluster
    rows, clutter = frame_rows(pts, boxes, ["Car", "Car"])
    assert rows.shape == (2, 9)
    np.testing.assert_allclose(rows[0, 5:7], [18.2, 0.1])  # nearest detection to the sensor
    assert np.isnan(rows[1, 5]) and rows[1, 7] == 0  # box 1 missed
    assert clutter.shape == (1, 3) and clutter[0, 2] == 2


def test_load_real_frames(real_data):
    root = real_data / "astyx_hires2019"
    if not root.is_dir():
        pytest.skip(f"{root} is absent")
    log = load_astyx(root, frames=range(0, 40))
    stats = detection_statistics(log, np.array([0, 30, 60, 150.0]), np.deg2rad([-60, 0, 60.0]))
    assert 0.3 < stats["detected_share"] < 1.0 and stats["clutter_per_cycle"] > 0
    tt = target_tuples(log)
    assert not np.isfinite(tt.z_prev).any()  # Astyx is no time series
    det = np.isfinite(tt.z[:, 0])
    assert np.median(np.linalg.norm(tt.z[det], axis=1)) < 3.0  # detections lie near their box corner
    m = KDERadarModel(use_prev=False, cv_group="sequence", cv_min_tuples=10, random_state=0).fit(log)
    z, _ = m.sample_cycle(tt.corner[:5], None, np.random.default_rng(0))
    assert z.shape == (5, 2)


def test_real_frames_carry_the_covariates_diagnose_needs(real_data):
    root = real_data / "astyx_hires2019"
    if not root.is_dir():
        pytest.skip(f"{root} is absent")
    log = load_astyx(root, frames=range(0, 10))
    for col in ("occlusion", "label_certainty", "class_code", "n_points", "aspect"):
        assert col in log.covariates
    tgt = ~log.is_clutter
    from sensor_envs.radar.features import aspect_angle

    np.testing.assert_allclose(
        log["aspect"][tgt], aspect_angle(log["ref_x"][tgt], log["ref_y"][tgt], log["ref_heading"][tgt])
    )
    assert np.all(np.abs(log["aspect"][tgt]) <= np.pi) and np.isnan(log["aspect"][~tgt]).all()
