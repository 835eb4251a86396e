"""``resample_bearings`` / ``--bearings N``: a scan of another beam count on the Neato world's 360 bearings."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensor_envs.cli.main import main
from sensor_envs.lidar.log import LidarLog, LidarLogError, load_log, resample_bearings, save_log
from sensor_envs.maps import load_map

ROOM = load_map("seed_room").segments


def _log(bearings: np.ndarray, repeats: int = 2) -> LidarLog:
    """A log whose reading at each beam encodes the beam's direction: 1 + (direction in [0, 360) deg) / 1000."""
    deg = np.mod(np.rad2deg(bearings), 360.0)
    ranges = np.broadcast_to((1.0 + deg / 1000.0)[None, :, None], (3, bearings.size, repeats)).copy()
    return LidarLog(ranges, bearings, np.array([[1.8, 0.9, 0.0]] * 3), ROOM, source="planted.npz")


def test_ros_scan_of_361_beams_over_the_circle_gives_the_worlds_360_one_degree_bearings():
    log = _log(-np.pi + np.arange(361) * (2 * np.pi / 360))  # bin 0 == bin 360 (-180 and +180 deg)
    out = resample_bearings(log, 360)
    assert out.n_bearings == 360
    assert np.allclose(out.bearings, np.deg2rad(np.arange(360)))
    assert np.allclose(out.ranges[0, :, 0], 1.0 + np.arange(360) / 1000.0)  # beam k deg is world bearing k
    assert out.ranges.shape == (3, 360, 2) and np.array_equal(out.poses, log.poses)


@settings(max_examples=40, deadline=None)
@given(
    k=st.integers(min_value=90, max_value=800),
    start=st.floats(min_value=-np.pi, max_value=np.pi),
    n=st.sampled_from([90, 180, 360, 720]),
    closed=st.booleans(),
)
def test_every_new_bearing_reads_the_nearest_logged_beam(k, start, n, closed):
    step = 2 * np.pi / (k - 1 if closed else k)  # closed: the last beam repeats the first direction
    log = _log(start + np.arange(k) * step)
    out = resample_bearings(log, n)
    got = (out.ranges[0, :, 0] - 1.0) * 1000.0  # the direction [deg] of the beam each new bearing took
    want = np.rad2deg(out.bearings)
    err = np.abs((got - want + 180.0) % 360.0 - 180.0)
    assert err.max() <= 0.5 * np.rad2deg(step) + 1e-6


@pytest.mark.parametrize("n", [360, 720])
def test_a_half_circle_scan_is_refused_naming_the_field(n):
    log = _log(np.deg2rad(np.linspace(-90.0, 90.0, 181)))  # a SICK's 180 deg
    with pytest.raises(LidarLogError, match=r"planted.npz: field 'bearings': no logged beam"):
        resample_bearings(log, n)


def _bag_361(path, scans: int = 30) -> None:
    """A ROS1 bag: /scan of 361 beams over -180..180 deg (bin 0 == bin 360) seeing ROOM from a moving robot, /odom."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from sensor_envs.lidar.mapping import map_features

    ts = get_typestore(Stores.ROS1_NOETIC)
    t = ts.types
    bearings = -np.pi + np.arange(361) * (2 * np.pi / 360)
    poses = np.stack([1.0 + 0.05 * np.arange(scans), 0.6 + 0.01 * np.arange(scans), 0.02 * np.arange(scans)], 1)
    r, _ = map_features(poses, bearings, ROOM, 5.0)
    rng = np.random.default_rng(0)
    with Writer(path) as w:
        c_scan = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        c_odom = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        for i in range(scans):
            ns = 1_000_000_000 + i * 200_000_000
            stamp = t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            hdr = t["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="laser")
            ranges = (r[i] + 0.01 * rng.standard_normal(361)).astype(np.float32)
            scan = t["sensor_msgs/msg/LaserScan"](
                header=hdr, angle_min=-np.pi, angle_max=np.pi, angle_increment=2 * np.pi / 360, time_increment=0.0,
                scan_time=0.2, range_min=0.06, range_max=5.0, ranges=ranges, intensities=np.zeros(361, np.float32),
            )  # fmt: skip
            w.write(c_scan, ns, ts.serialize_ros1(scan, "sensor_msgs/msg/LaserScan"))
            x, y, th = poses[i]
            q = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(th / 2), w=np.cos(th / 2))
            p = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0), orientation=q)
            v = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            odom = t["nav_msgs/msg/Odometry"](
                header=hdr, child_frame_id="base",
                pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=p, covariance=np.zeros(36)),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t["geometry_msgs/msg/Twist"](linear=v, angular=v), covariance=np.zeros(36)
                ),
            )  # fmt: skip
            w.write(c_odom, ns - 1000 if i == 0 else ns, ts.serialize_ros1(odom, "nav_msgs/msg/Odometry"))


@pytest.mark.slow
def test_fit_lidar_with_bearings_360_fits_a_361_beam_ros_bag_on_the_worlds_bearings(tmp_path, capsys):
    pytest.importorskip("rosbags")
    bag = tmp_path / "scan361.bag"
    _bag_361(bag)
    room = tmp_path / "room.txt"
    room.write_text("\n".join(" ".join(f"{v:g}" for v in s.ravel()) for s in ROOM) + "\n")
    assert load_log(bag).n_bearings == 361
    out = tmp_path / "m.npz"
    argv = ["fit", "lidar", str(bag), "--map", str(room), "--max-range", "5", "--bearings", "360"]
    argv += ["--folds", "2", "--out", str(out)]
    assert main(argv) == 0, capsys.readouterr().err
    from sensor_envs.lidar.lwlr import LidarLWLR

    model = LidarLWLR.load(out)
    assert np.allclose(model.bearings_, np.deg2rad(np.arange(360)))


@pytest.mark.parametrize("value", ["0", "-3", "1e3", "100001"])
def test_bad_bearings_option_exit_2_one_line(tmp_path, capsys, value):
    path = save_log(_log(np.deg2rad(np.arange(360.0))), tmp_path / "scan.npz")
    argv = ["fit", "lidar", str(path), "--bearings", value, "--out", str(tmp_path / "m.npz")]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--bearings" in err, err
    assert not (tmp_path / "m.npz").exists()


def test_fit_lidar_bearings_on_a_half_circle_log_exit_2_naming_the_file(tmp_path, capsys):
    path = save_log(_log(np.deg2rad(np.linspace(-90.0, 90.0, 181))), tmp_path / "sick.npz")
    argv = ["fit", "lidar", str(path), "--bearings", "360", "--out", str(tmp_path / "m.npz")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "sick.npz" in err and "'bearings'" in err, err
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.slow
def test_real_neato_bag_resamples_to_the_worlds_bearings(real_data):
    pytest.importorskip("rosbags")
    bag = load_log(real_data / "neato_ros1_bags" / "middle.bag")
    assert bag.n_bearings == 361
    out = resample_bearings(bag, 360)
    k = np.round(np.rad2deg(np.mod(bag.bearings, 2 * np.pi))).astype(int) % 360
    # world bearing 0 deg reads the bag's beam at 0 deg (index 180), world bearing 90 the beam at +90 deg
    assert np.array_equal(out.ranges[:, 0], bag.ranges[:, int(np.flatnonzero(k == 0)[0])], equal_nan=True)
    assert np.array_equal(out.ranges[:, 90], bag.ranges[:, int(np.flatnonzero(k == 90)[0])], equal_nan=True)
