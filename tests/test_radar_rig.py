import json
from pathlib import Path

import numpy as np

from sensor_envs.radar.log import clutter_counts, target_tuples
from sensor_envs.radar.rig import RadarRig, RigConfig, generate_scenario, load_rig, record_rig_log


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


def _left_right_rates(config: RigConfig) -> tuple[float, float]:
    """Detection share of rig-recorded target rows left (azimuth > 10 deg) and right (< -10 deg) of the boresight."""
    log = record_rig_log(30, 10, 8, np.random.default_rng(4), config)
    tgt = ~log.is_clutter
    x, y = log["ref_x"][tgt], log["ref_y"][tgt]
    det = np.isfinite(log["meas_x"][tgt])
    az = np.arctan2(y, x)
    left, right = (az > np.deg2rad(10)) & (az < np.deg2rad(80)), (az < -np.deg2rad(10)) & (az > -np.deg2rad(80))
    assert left.sum() > 150 and right.sum() > 150
    return float(det[left].mean()), float(det[right].mean())


def test_signed_azimuth_table_detects_left_and_right_differently():
    flat = {
        "detect_range_knots": (0.0, 150.0),
        "detect_range_table": (1.0, 1.0),
        "max_range": 400.0,
        "occlusion_loss": 0.0,
    }
    knots = tuple(np.deg2rad([-90.0, -5.0, 5.0, 90.0]).tolist())
    lopsided = RigConfig(
        **flat, detect_azimuth_knots=knots, detect_azimuth_table=(0.3, 0.3, 0.9, 0.9), detect_azimuth_signed=True
    )
    left, right = _left_right_rates(lopsided)
    # ~0.9 left, ~0.3 right (no range or occlusion loss; the reflection point's azimuth differs a little from the box's)
    assert left > right + 0.4 and left > 0.75 and right < 0.35, (left, right)
    mirrored = RigConfig(
        **flat, detect_azimuth_knots=knots, detect_azimuth_table=(0.9, 0.9, 0.3, 0.3), detect_azimuth_signed=True
    )
    m_left, m_right = _left_right_rates(mirrored)
    assert m_right > m_left + 0.4, (m_left, m_right)
    # the same numbers read as an |azimuth| table would be symmetric: refused unless signed
    p = RadarRig(lopsided).detection_probability(np.full(3, 30.0), np.deg2rad([-30.0, 30.0, 95.0]), np.zeros(3))
    np.testing.assert_allclose(p, [0.3, 0.9, 0.0])


SYMMETRIC_RIG = Path(__file__).resolve().parent / "data" / "radar_rig_symmetric.json"
"""The calibrated rig shipped before the signed azimuth law (|azimuth| table, no ``detect_azimuth_signed``)."""


def test_symmetric_rig_file_loads_and_behaves_as_before():
    assert "detect_azimuth_signed" not in json.loads(SYMMETRIC_RIG.read_text())["params"]
    cfg, _ = load_rig(SYMMETRIC_RIG)
    assert cfg.detect_azimuth_signed is False
    r = np.linspace(0.0, 140.0, 29)
    az = np.deg2rad(np.linspace(-100.0, 100.0, 29))
    occ = np.linspace(0.0, 1.0, 29)
    p = RadarRig(cfg).detection_probability(r, az, occ)
    # the law before: range table x logistic fall-off x |azimuth| table (0 beyond its last knot) x occlusion
    p_range = 1.0 / (1.0 + np.exp((r - cfg.max_range) / cfg.range_falloff))
    p_range = p_range * np.interp(r, cfg.detect_range_knots, cfg.detect_range_table)
    p_az = np.interp(np.abs(az), cfg.detect_azimuth_knots, cfg.detect_azimuth_table, right=0.0)
    np.testing.assert_array_equal(p, p_range * p_az * (1.0 - cfg.occlusion_loss * occ))
    np.testing.assert_array_equal(p, RadarRig(cfg).detection_probability(r, -az, occ))
    # a short recording gives the numbers the code before the signed law gave (measured with that code)
    log = record_rig_log(4, 10, 8, np.random.default_rng(5), cfg)
    tgt = ~log.is_clutter
    assert int(np.isfinite(log["meas_x"][tgt]).sum()) == 284 and int(tgt.sum()) == 320
    np.testing.assert_allclose(np.nansum(log["meas_x"][tgt]), 14520.110058203449, rtol=1e-10)
    np.testing.assert_allclose(np.nansum(log["meas_y"][tgt]), -34.07249180078684, rtol=1e-10)


def test_in_view_only_drops_just_the_boxes_outside_the_field_of_view():
    """``in_view_only`` leaves out never-detectable boxes (e.g. behind the sensor) and keeps every other row as is."""
    rig = RadarRig(load_rig(Path(__file__).resolve().parents[1] / "models" / "radar_rig.json")[0])
    boxes = np.array([[20.0, 0.0, 0.0, 4.5, 1.8], [-20.0, 3.0, 0.0, 4.5, 1.8], [0.5, 4.0, 0.0, 4.5, 1.8]])
    np.testing.assert_array_equal(rig.in_view(boxes), [True, False, True])  # ahead, behind, beside (front corners)
    sc = generate_scenario(8, 40, 1.0, np.random.default_rng(5))  # 35 rows of boxes that pass behind the sensor
    full = rig.record(sc, np.random.default_rng(7))
    view = rig.record(sc, np.random.default_rng(7), in_view_only=True)
    key = ("frame", "target")
    ids_full = {tuple(r) for r in np.stack([full[k] for k in key], axis=1)[~full.is_clutter]}
    ids_view = {tuple(r) for r in np.stack([view[k] for k in key], axis=1)[~view.is_clutter]}
    gone = ids_full - ids_view
    assert ids_view <= ids_full and len(gone) > 0
    tgt = ~full.is_clutter
    dropped = np.array([tuple(r) in gone for r in np.stack([full[k] for k in key], axis=1)]) & tgt
    assert np.isnan(full["meas_x"][dropped]).all()  # only never-detected rows go
    assert (full["ref_x"][dropped] < 1.0).all()
    for k in full.columns:  # the same draws: the kept rows are the rows of the full log
        np.testing.assert_array_equal(view[k], full[k][~dropped])
