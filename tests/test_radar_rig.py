import numpy as np

from sensor_envs.radar.log import clutter_counts, target_tuples
from sensor_envs.radar.rig import RadarRig, RigConfig, generate_scenario, record_rig_log


def test_detection_probability_falls_with_range_azimuth_and_occlusion():
    rig = RadarRig()
    p = rig.detection_probability(
        np.array([20.0, 85.0, 120.0, 20.0, 20.0]),
        np.array([0.0, 0.0, 0.0, np.deg2rad(45), np.deg2rad(70)]),
        np.array([0.0, 0.0, 0.0, 0.0, 0.0]),
    )
    assert p[0] > p[1] > p[2] and p[0] > p[3] > p[4] == 0.0
    assert rig.detection_probability(np.array([20.0]), np.array([0.0]), np.array([0.8]))[0] < p[0]


def test_log_is_a_time_series_with_correlated_outputs_and_clutter_rate():
    cfg = RigConfig(clutter_rate=2.0)
    log = record_rig_log(20, 30, 6, np.random.default_rng(0), cfg)
    tt = target_tuples(log)
    ok = np.isfinite(tt.z[:, 0]) & np.isfinite(tt.z_prev[:, 0])
    assert ok.sum() > 500
    assert np.corrcoef(tt.z[ok, 0], tt.z_prev[ok, 0])[0, 1] > 0.5  # tracker smoothing
    counts, xy = clutter_counts(log)
    assert abs(counts.mean() - 2.0) < 4 * np.sqrt(2.0 / counts.size)
    az = np.arctan2(xy[:, 1], xy[:, 0])
    assert np.all(np.abs(az) <= cfg.fov + 1e-9)
    # detections come from reflection points inside the field of view (+ azimuth noise, + tracker lag)
    meas = ~log.is_clutter & ~log.is_miss
    az_m = np.arctan2(log["meas_y"][meas], log["meas_x"][meas])
    assert np.mean(np.abs(az_m) <= cfg.fov + 0.05) > 0.99


def test_same_seed_same_log():
    sc = generate_scenario(5, 10, 1.0, np.random.default_rng(1))
    a = RadarRig().record(sc, np.random.default_rng(2))
    b = RadarRig().record(sc, np.random.default_rng(2))
    for k in a.columns:
        np.testing.assert_array_equal(a[k], b[k])
