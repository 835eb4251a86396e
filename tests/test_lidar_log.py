from __future__ import annotations

import gzip
import re

import numpy as np
import pytest

from sensor_envs.lidar.log import LidarLogError, load_log, log_from_arrays, save_log

SEGS = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]], dtype=float)


def _arrays(p: int = 3, k: int = 8, r: int = 4) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {
        "ranges": rng.uniform(0.5, 2.0, (p, k, r)),
        "bearings": np.linspace(0, 2 * np.pi, k, endpoint=False),
        "poses": np.tile([2.0, 1.5, 0.1], (p, 1)),
        "map_segments": SEGS,
    }


def _write(tmp_path, **arrays) -> str:
    path = tmp_path / "log.npz"
    np.savez(path, **arrays)
    return str(path)


def test_real_log_loads_as_is(real_data):
    log = load_log(real_data / "neato_mar27_train.npz")
    assert log.ranges.shape == (29, 360, 200)
    assert np.isnan(log.ranges).any()  # padding kept as missing
    assert 0.2 < (log.ranges[~np.isnan(log.ranges)] == 0).mean() < 0.3
    assert log.map_segments.shape == (5, 2, 2)


def test_scan_log_becomes_one_repeat_and_round_trips(tmp_path):
    a = _arrays()
    log = log_from_arrays(
        a["ranges"][:, :, 0],
        a["bearings"],
        a["poses"],
        a["map_segments"],
        t=[0.0, 0.1, 0.2],
        covariates={"temp": [20.0, 21.0, 22.0]},
    )
    assert log.ranges.shape == (3, 8, 1)
    back = load_log(save_log(log, tmp_path / "x.npz"))
    np.testing.assert_allclose(back.ranges, log.ranges.astype(np.float32))
    np.testing.assert_array_equal(back.covariates["temp"], [20.0, 21.0, 22.0])
    np.testing.assert_array_equal(back.t, log.t)


@pytest.mark.parametrize(
    ("field", "mutate", "message"),
    [
        ("bearings", lambda a: a.update(bearings=a["bearings"][:5]), "must have shape (8,)"),
        ("poses", lambda a: a["poses"].__setitem__((1, 0), np.nan), "holds NaN"),
        ("poses", lambda a: a.update(poses=a["poses"][:2]), "must have shape (3, 3)"),
        ("ranges", lambda a: a.update(ranges=np.zeros((0, 8, 4))), "is empty"),
        ("ranges", lambda a: a["ranges"].__setitem__((0, 1, 2), -0.5), "negative ranges"),
        ("ranges", lambda a: a.update(ranges=np.zeros(5)), "must have shape (S, K) or (P, K, R)"),
        ("map_segments", lambda a: a.update(map_segments=np.zeros((2, 3))), "expected shape"),
    ],
)
def test_bad_logs_name_file_and_field(tmp_path, field, mutate, message):
    a = _arrays()
    mutate(a)
    path = _write(tmp_path, **a)
    with pytest.raises(LidarLogError, match=re.escape(f"field '{field}'")) as info:
        load_log(path)
    assert path in str(info.value)
    assert message in str(info.value)


def test_missing_field_is_named(tmp_path):
    a = _arrays()
    del a["poses"]
    with pytest.raises(LidarLogError, match=re.escape("field 'poses' is missing")):
        load_log(_write(tmp_path, **a))


def test_carmen_flaser_and_robotlaser(tmp_path):
    fl = "FLASER 4 1.0 2.0 81.0 0.5 1.0 2.0 0.3 1.0 2.0 0.3 12.5 host 12.5\n"
    rl = (
        "ROBOTLASER1 0 -1.5708 3.1416 1.5708 20.0 0.01 0 3 1.0 25.0 0.0 0 1.1 2.1 0.4 1.0 2.0 0.3 0 0 0 0 0 "
        "13.0 host 13.0\n"
    )
    path = tmp_path / "x.log.gz"
    with gzip.open(path, "wt") as f:
        f.write("# comment\nODOM 0 0 0 0 0 0 1.0 h 1.0\n" + fl + fl)
    log = load_log(path)
    assert log.ranges.shape == (2, 4, 1)
    np.testing.assert_allclose(log.ranges[0, :, 0], [1.0, 2.0, 0.0, 0.5])  # >= 80 m is a null
    # n FLASER beams span [-pi/2, pi/2] with both ends included (this line asserted the old, wrong pi / n)
    np.testing.assert_allclose(log.bearings, -np.pi / 2 + np.arange(4) * np.pi / 3)
    np.testing.assert_allclose(log.poses[0], [1.0, 2.0, 0.3])
    path2 = tmp_path / "y.log"
    path2.write_text(rl)
    log2 = load_log(path2)
    np.testing.assert_allclose(log2.ranges[0, :, 0], [1.0, 0.0, 0.0])  # 25 m > 20 m max, 0 is a null
    np.testing.assert_allclose(log2.poses[0], [1.1, 2.1, 0.4])
    np.testing.assert_allclose(log2.bearings, [-1.5708, 0.0, 1.5708])


def test_carmen_361_beam_flaser_has_half_degree_steps(tmp_path):
    ranges = " ".join(["1.5"] * 361)
    path = tmp_path / "x.log"
    path.write_text(f"FLASER 361 {ranges} 1.0 2.0 0.3 1.0 2.0 0.3 12.5 host 12.5\n")
    b = load_log(path).bearings
    assert b.size == 361
    np.testing.assert_allclose(b[[0, 180, 360]], [-np.pi / 2, 0.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(np.diff(b), np.deg2rad(0.5))


def test_carmen_without_laser_lines(tmp_path):
    path = tmp_path / "empty.log"
    path.write_text("ODOM 0 0 0 0 0 0 1.0 h 1.0\n")
    with pytest.raises(LidarLogError, match=re.escape("field 'ranges': no FLASER")):
        load_log(path)


def test_real_carmen_and_rosbag(real_data):
    c = load_log(real_data / "carmen" / "intel-corrected.log.gz")
    assert c.ranges.shape == (910, 180, 1) and c.map_segments is None
    with pytest.raises(LidarLogError, match="map_segments"):
        c.require_map()
    b = load_log(real_data / "neato_ros1_bags" / "middle.bag")
    assert b.ranges.shape[1] == 361 and b.n_poses > 100
    assert np.isfinite(b.poses).all()
    with pytest.raises(LidarLogError, match=re.escape("topic '/nope' not in the bag")):
        load_log(real_data / "neato_ros1_bags" / "middle.bag", pose_topic="/nope")
