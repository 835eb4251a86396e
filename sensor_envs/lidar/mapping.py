"""Maps for lidar logs that have none: features on large maps, a nominal map from scans, scan-to-map alignment.

* :func:`map_features`: nominal range and incidence like :func:`~sensor_envs.lidar.lwlr.lidar_features`,
  in chunks of poses and with the segments out of reach dropped per chunk (grid maps have thousands
  of segments; the plain raycast holds a ``(P, K, M)`` array).
* :func:`map_from_scans`: an occupancy grid accumulated from a log's (corrected) poses and returns
  (a cell is occupied when at least ``min_hits`` returns end in it), turned into boundary segments by
  :func:`sensor_envs.maps.occupancy_to_segments`. Build it from the TRAINING part of a log only.
* :func:`align_to_grid`: the map <- odom transform of a bag's odometry poses by scan matching its
  first scans against an occupancy grid (e.g. a ROS map_server map): an exhaustive search over the
  heading (2 degree steps) with the translation found by FFT cross-correlation of the scan points
  with a likelihood field (0.05 m cells), then point-to-point ICP (``scipy.spatial.cKDTree``) on
  the occupied cell centres. :func:`alignment_quality` measures how well all scans then fit.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.geometry import as_segments, quaternion_yaw, raycast_pose
from sensor_envs.inputs import InputError
from sensor_envs.lidar.log import LidarLog, LidarLogError
from sensor_envs.maps import occupancy_to_segments

__all__ = [
    "map_features",
    "scan_points",
    "map_from_scans",
    "read_occupancy",
    "align_to_grid",
    "alignment_quality",
    "compose",
    "laser_offset_from_bag",
    "with_poses",
]

_CHUNK = 4_000_000  # poses x bearings x segments per raycast call


def map_features(
    poses: ArrayLike, bearings: ArrayLike, segments: ArrayLike, max_range: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nominal range ``(S, K)`` [m] (``inf`` = no hit) and incidence [rad] (NaN = no hit), in chunks.

    Same values as :func:`sensor_envs.lidar.lwlr.lidar_features`; segments whose bounding box lies
    farther than ``max_range`` from a chunk's poses' bounding box are skipped.
    """
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    b = np.asarray(bearings, dtype=np.float64)
    segs = as_segments(segments, name="map")
    r = np.full((p.shape[0], b.size), np.inf)
    a = np.full((p.shape[0], b.size), np.nan)
    lo, hi = segs.min(1), segs.max(1)  # (M, 2) bounding boxes
    step = 64
    i = 0
    while i < p.shape[0]:
        q = p[i : i + step]
        near = ((lo <= q[:, :2].max(0) + max_range) & (hi >= q[:, :2].min(0) - max_range)).all(1)
        if near.sum() * q.shape[0] * b.size > _CHUNK and step > 1:
            step //= 2
            continue
        if near.any():
            rr, aa, _ = raycast_pose(q, b, segs[near], max_range)
            r[i : i + step], a[i : i + step] = rr, aa
        i += q.shape[0]
        step = 64
    return r, a


def scan_points(log: LidarLog, max_range: float, idx: ArrayLike | None = None) -> NDArray[np.float64]:
    """Map-frame end points ``(N, 2)`` [m] of the in-range returns of scans ``idx`` (default all)."""
    i = np.arange(log.n_poses) if idx is None else np.asarray(idx)
    x = log.ranges[i]  # (S, K, R)
    pose = log.poses[i]
    ang = pose[:, 2, None, None] + log.bearings[None, :, None]
    ok = ~np.isnan(x) & (x > 0) & (x <= max_range)
    px = pose[:, 0, None, None] + x * np.cos(ang)
    py = pose[:, 1, None, None] + x * np.sin(ang)
    return np.stack([px[ok], py[ok]], axis=1)


def map_from_scans(
    log: LidarLog, max_range: float, resolution: float = 0.05, min_hits: int = 2
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """A nominal map ``(M, 2, 2)`` [m] from the log's poses and returns (occupancy grid -> segments).

    Args:
        log: the (training) log with corrected poses in a common frame.
        max_range: returns farther than this are not used [m].
        resolution: grid cell size [m].
        min_hits: returns a cell needs to be occupied (1 keeps single stray returns).

    Returns:
        The segments and a summary (cells, occupied cells, segments, resolution, scans used).

    Raises:
        LidarLogError: when the poses are not finite or no cell is occupied.
    """
    if not np.isfinite(log.poses).all():
        raise LidarLogError(f"{log.source}: field 'poses' holds NaN or infinite values; cannot build a map")
    pts = scan_points(log, max_range)
    if pts.shape[0] == 0:
        raise LidarLogError(f"{log.source}: field 'ranges' has no return within {max_range} m to build a map from")
    origin = pts.min(0) - 2 * resolution
    ij = np.floor((pts - origin) / resolution).astype(np.int64)
    shape = (int(ij[:, 1].max()) + 3, int(ij[:, 0].max()) + 3)  # rows = y, columns = x
    counts = np.zeros(shape, dtype=np.int64)
    np.add.at(counts, (ij[:, 1], ij[:, 0]), 1)
    occ = counts >= min_hits
    if not occ.any():
        raise LidarLogError(f"{log.source}: field 'ranges': no grid cell has {min_hits} returns; no map")
    segs = occupancy_to_segments(occ, resolution, (origin[0], origin[1], 0.0))
    info = {
        "resolution_m": resolution,
        "min_hits": min_hits,
        "scans": log.n_poses,
        "returns": int(pts.shape[0]),
        "occupied_cells": int(occ.sum()),
        "segments": int(segs.shape[0]),
    }
    return segs, info


def with_poses(log: LidarLog, poses: NDArray[np.float64], segments: NDArray[np.float64] | None) -> LidarLog:
    """The log with new poses (and map)."""
    return dataclasses.replace(log, poses=np.asarray(poses, dtype=np.float64), map_segments=segments)


# --------------------------------------------------------------------------------------------- alignment
def read_occupancy(yaml_path: str | os.PathLike[str]) -> tuple[NDArray[np.bool_], float, NDArray[np.float64]]:
    """Occupied cells ``(H, W)`` (row 0 at the smallest y), resolution [m], origin ``(x, y, yaw)`` of a ROS map.

    The same checked reader as :func:`sensor_envs.maps.read_ros_map` (every field validated).
    """
    from sensor_envs.maps import ros_occupancy

    return ros_occupancy(yaml_path)


def compose(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Pose composition ``a (+) b`` for ``(..., 3)`` arrays ``x, y, theta`` [m, rad]."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    th = (a[..., 2] + b[..., 2] + np.pi) % (2 * np.pi) - np.pi
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1], th], -1)


def laser_offset_from_bag(path: str | os.PathLike[str], child: str = "laser") -> NDArray[np.float64]:
    """The base -> laser transform ``(x, y, yaw)`` [m, rad] from a bag's ``/tf`` (zeros when absent).

    Raises:
        LidarLogError: naming the bag and the topic: a ``/tf`` of another message type, a damaged message,
            a translation that is not finite within 100 m or a rotation that is not a unit quaternion.
    """
    from rosbags.highlevel import AnyReader

    from sensor_envs.lidar.log import LidarLogError, _deserialize

    with AnyReader([Path(path)]) as reader:
        conns = [c for c in reader.connections if c.topic in ("/tf", "/tf_static")]
        for conn in conns:
            if conn.msgtype != "tf2_msgs/msg/TFMessage":
                raise LidarLogError(f"{path}: topic {conn.topic!r} is {conn.msgtype}, expected tf2_msgs/msg/TFMessage")
        for conn, _, raw in reader.messages(connections=conns):
            msg: Any = _deserialize(reader, raw, conn, Path(path))  # a ROS message class generated at run time
            for tr in msg.transforms:
                if child in tr.child_frame_id:
                    t, q = tr.transform.translation, tr.transform.rotation
                    xyz, quat = np.array([t.x, t.y, t.z]), np.array([q.w, q.x, q.y, q.z])
                    ok = np.isfinite(xyz).all() and (np.abs(xyz) <= 100).all() and np.isfinite(quat).all()
                    if not ok or abs(float(np.linalg.norm(quat)) - 1.0) > 0.1:
                        raise LidarLogError(
                            f"{path}: topic {conn.topic!r}: the transform to {tr.child_frame_id!r} is not a finite "
                            "translation within 100 m and a unit quaternion"
                        )
                    return np.array([t.x, t.y, quaternion_yaw(q.w, q.x, q.y, q.z)])
    return np.zeros(3)


def _likelihood_field(occ: NDArray[np.bool_], res: float, sigma: float) -> NDArray[np.float64]:
    from scipy.ndimage import distance_transform_edt

    d = distance_transform_edt(~occ) * res
    return np.exp(-0.5 * (d / sigma) ** 2)


def align_to_grid(
    points_odom: NDArray[np.float64],
    occ: NDArray[np.bool_],
    res: float,
    origin: ArrayLike,
    coarse: float = 0.05,
    theta_step_deg: float = 2.0,
    icp_iters: int = 30,
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """The transform ``T = (x, y, theta)`` (map <- odom) that best lays ``points_odom (N, 2)`` onto the grid.

    Args:
        points_odom: scan end points in the odometry frame [m] (from the first scans, where drift is small).
        occ: ``(H, W)`` occupied cells, row 0 at the smallest y.
        res: grid resolution [m].
        origin: ``(x, y, yaw)`` of cell (0, 0) [m, rad] (yaw must be 0).
        coarse: cell size of the exhaustive search [m].
        theta_step_deg: heading step of the exhaustive search [deg].
        icp_iters: point-to-point ICP iterations after the search.

    Returns:
        ``T`` and a summary: the search score of the best and second-best separated heading, the ICP rms.
    """
    from scipy.signal import fftconvolve
    from scipy.spatial import cKDTree

    ox, oy = float(np.asarray(origin)[0]), float(np.asarray(origin)[1])
    f = max(1, int(round(coarse / res)))
    h, w = occ.shape
    occ_c = np.asarray(occ[: h - h % f, : w - w % f].reshape(h // f, f, w // f, f).any((1, 3)))
    cres = res * f
    field = _likelihood_field(occ_c, cres, 1.5 * cres)
    pts = points_odom[np.random.default_rng(0).permutation(points_odom.shape[0])[:3000]]
    half = int(np.ceil(np.linalg.norm(pts, axis=1).max() / cres)) + 1
    best: list[tuple[float, float, float, float]] = []
    for th in np.deg2rad(np.arange(0.0, 360.0, theta_step_deg)):
        c, s = np.cos(th), np.sin(th)
        q = pts @ np.array([[c, s], [-s, c]])
        img = np.zeros((2 * half + 1, 2 * half + 1))
        np.add.at(img, (np.round(q[:, 1] / cres).astype(int) + half, np.round(q[:, 0] / cres).astype(int) + half), 1)
        score = fftconvolve(
            field, img[::-1, ::-1], mode="full"
        )  # score[i + half, j + half] = sum field[i + dy, j + dx]
        k = int(np.argmax(score))
        i, j = np.unravel_index(k, score.shape)
        best.append((float(score.flat[k]) / pts.shape[0], th, ox + (j - half) * cres, oy + (i - half) * cres))
    best.sort(reverse=True)
    runner = next((b for b in best[1:] if abs(np.angle(np.exp(1j * (b[1] - best[0][1])))) > np.deg2rad(10)), best[-1])
    t = np.array([best[0][2], best[0][3], best[0][1]])
    cells = np.argwhere(occ)
    tree = cKDTree(np.stack([ox + (cells[:, 1] + 0.5) * res, oy + (cells[:, 0] + 0.5) * res], axis=1))
    rms = np.nan
    for _ in range(icp_iters):
        q = compose(t, np.column_stack([points_odom, np.zeros(len(points_odom))]))[:, :2]
        d, nn = tree.query(q, distance_upper_bound=0.3)
        m = np.isfinite(d)
        if m.sum() < 10:
            break
        rms = float(np.sqrt(np.mean(d[m] ** 2)))
        src, dst = q[m], tree.data[nn[m]]
        mu_s, mu_d = src.mean(0), dst.mean(0)
        u, _, vt = np.linalg.svd((src - mu_s).T @ (dst - mu_d))
        rot = (u @ vt).T
        if np.linalg.det(rot) < 0:
            rot = (u @ np.diag([1, -1]) @ vt).T
        dth = float(np.arctan2(rot[1, 0], rot[0, 0]))
        shift = mu_d - rot @ mu_s
        t = compose(np.array([shift[0], shift[1], dth]), t)
    info = {
        "search_score_best": best[0][0],
        "search_score_runner_up_heading": runner[0],
        "search_heading_deg": float(np.rad2deg(best[0][1])),
        "icp_rms_m": rms,
        "points": int(points_odom.shape[0]),
    }
    return t, info


def alignment_quality(
    points_map: NDArray[np.float64], occ: NDArray[np.bool_], res: float, origin: ArrayLike
) -> dict[str, float]:
    """Distances [m] from map-frame points to the nearest occupied cell: median and shares within 5/10 cm."""
    from scipy.spatial import cKDTree

    ox, oy = float(np.asarray(origin)[0]), float(np.asarray(origin)[1])
    cells = np.argwhere(occ)
    tree = cKDTree(np.stack([ox + (cells[:, 1] + 0.5) * res, oy + (cells[:, 0] + 0.5) * res], axis=1))
    d, _ = tree.query(points_map)
    return {
        "median_m": float(np.median(d)),
        "within_5cm": float((d <= 0.05).mean()),
        "within_10cm": float((d <= 0.10).mean()),
        "points": int(d.size),
    }


# ------------------------------------------------------------------------------------------ preparation
def split_parts(n_scans: int, block_scans: int, test_every: int) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Training and held-out masks ``(S,)``.

    Block ``b`` (scans ``b * block_scans ..``) is held out when ``b mod test_every == test_every - 1``.
    """
    if block_scans < 1 or test_every < 2:
        raise InputError(f"split: block_scans must be >= 1 and test_every >= 2, got {block_scans}, {test_every}")
    test = (np.arange(n_scans) // block_scans) % test_every == test_every - 1
    return ~test, test


def prepare_log(
    log: LidarLog,
    *,
    map: Any = None,
    part: str = "all",
    block_scans: int = 40,
    test_every: int = 4,
    max_range: float = 5.0,
    align: bool = False,
    map_resolution: float = 0.05,
) -> tuple[LidarLog, dict[str, Any]]:
    """A log ready to fit or validate: a map, poses in the map's frame, and the requested part of the scans.

    Args:
        log: the log as read.
        map: a map file or name (:func:`sensor_envs.maps.load_map`; ROS map_server YAML included); it
            replaces the log's own map. Without one and without a map in the log, a nominal map is built
            by :func:`map_from_scans` from the TRAINING part only (:func:`split_parts`), whatever ``part`` is.
        part: ``"all"``, ``"train"`` or ``"test"`` (:func:`split_parts` with ``block_scans``, ``test_every``).
        block_scans: scans per block of the train/test split.
        test_every: every ``test_every``-th block is held out.
        max_range: returns farther than this do not build the map [m].
        align: estimate the map <- odom transform by :func:`align_to_grid` on the first 15 scans (needs
            ``map`` to be a ROS map_server YAML); the laser's mounting from the bag's ``/tf`` is applied.
        map_resolution: cell size of a built map [m].

    Returns:
        The log and a summary (map source, alignment, split).

    Raises:
        LidarLogError / ValueError: naming the file and field (no map can be had, bad part, all-NaN poses).
    """
    from sensor_envs.maps import load_map

    if part not in ("all", "train", "test"):
        raise InputError(f"part: expected 'all', 'train' or 'test', got {part!r}")
    if not np.isfinite(log.poses).any():
        raise LidarLogError(f"{log.source}: field 'poses' holds no finite pose")
    train, test = split_parts(log.n_poses, block_scans, test_every)
    info: dict[str, Any] = {
        "split": {
            "block_scans": block_scans,
            "test_every": test_every,
            "train_scans": int(train.sum()),
            "test_scans": int(test.sum()),
        },
        "part": part,
    }
    segs = log.map_segments
    if align:
        if map is None or Path(str(map)).suffix.lower() not in (".yaml", ".yml"):
            raise InputError("align: needs --map pointing at a ROS map_server YAML (an occupancy grid)")
        occ, res, origin = read_occupancy(map)
        src = Path(log.source)
        offset = laser_offset_from_bag(src) if src.suffix == ".bag" or src.is_dir() else np.zeros(3)
        sensor = compose(log.poses, offset[None])
        first = with_poses(log, sensor, None)
        t, ainfo = align_to_grid(scan_points(first, max_range, np.arange(min(15, log.n_poses))), occ, res, origin)
        log = with_poses(log, compose(t[None], sensor), segs)
        ainfo.update({"transform_map_odom": [float(v) for v in t], "laser_offset": [float(v) for v in offset]})
        ainfo["fit_of_all_scans"] = alignment_quality(scan_points(log, max_range), occ, res, origin)
        info["alignment"] = ainfo
    if map is not None:
        m = load_map(map)
        segs = m.segments
        info["map"] = {"source": str(map), "segments": int(segs.shape[0])}
    elif segs is None:
        segs, minfo = map_from_scans(log.subset(train), max_range, map_resolution)
        info["map"] = {"source": "built from the training part (occupancy grid -> segments)", **minfo}
    else:
        info["map"] = {"source": "the log's own map", "segments": int(segs.shape[0])}
    log = with_poses(log, log.poses, segs)
    if part != "all":
        log = log.subset(train if part == "train" else test)
    return log, info
