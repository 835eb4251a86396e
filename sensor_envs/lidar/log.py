"""The project's planar lidar log format, its validation, and loaders for CARMEN logs and ROS bags.

Log format (``.npz``, loaded with ``allow_pickle=False``):

* ``ranges`` float ``(S, K)`` (S scans, K bearings) or ``(P, K, R)`` (P static poses, R repeated
  readings per bearing) [m]; ``0`` = null reading (no return), ``NaN`` = missing (padding).
* ``bearings`` ``(K,)`` [rad], counter-clockwise from the sensor's x axis (x forward, y left).
* ``poses`` ``(S or P, 3)`` approximate sensor pose ``x, y, theta`` in the map frame [m, m, rad].
* ``map_segments`` ``(M, 2, 2)`` nominal map ``[[x1, y1], [x2, y2]]`` [m].
* optional ``t`` ``(S or P,)`` time [s]; optional per-scan covariates ``cov_<name>`` ``(S or P,)``.

Declared values (checked by :func:`log_from_arrays`, which every loader goes through): real numeric
dtypes only (no bool, complex or object); ``0 <= ranges <=`` :data:`MAX_RANGE`; bearings finite,
distinct, within ``+-2 pi``; poses and covariates finite within :data:`MAX_COORD`; ``t`` finite and
non-decreasing; covariate names non-empty. Files are read through :mod:`sensor_envs.inputs`
(regular files only, size limits, the inflated size of an ``.npz`` checked before inflating).

Other arrays in the file are ignored. In memory a log is a :class:`LidarLog` whose ``ranges`` are
always ``(P, K, R)`` float64 (a scan log has ``R = 1``).
"""

from __future__ import annotations

import hashlib
import os
import re
import struct
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.geometry import as_segments, quaternion_yaw
from sensor_envs.inputs import InputError, bad_name, check_regular_file, load_npz, open_gzip_lines
from sensor_envs.outputs import atomic_write, check_suffix

__all__ = ["LidarLog", "LidarLogError", "load_log", "save_log", "read_carmen", "read_rosbag", "log_from_arrays"]
__all__ += ["motion_covariates", "resample_bearings", "training_summary"]

PathLike = str | os.PathLike[str]

MAX_RANGE = 1000.0
"""Largest accepted reading [m] (long-range lidars reach ~300 m)."""
MAX_SCANS = 200_000
"""Most scans of a CARMEN log or ROS bag (intel has 910; 200 000 scans of 360 readings are 0.6 GB, minutes to read)."""
MAX_COORD = 1e6
"""Largest accepted ``|pose|`` coordinate [m] and ``|covariate|``."""


class LidarLogError(InputError):
    """A lidar log is malformed; the message names the file and the field at fault."""


@dataclass(frozen=True)
class LidarLog:
    """A validated lidar log (build it with :func:`log_from_arrays` or a loader, which validate).

    Attributes:
        ranges: ``(P, K, R)`` readings [m]; ``0`` = null, ``NaN`` = missing.
        bearings: ``(K,)`` bearings [rad] in the sensor frame.
        poses: ``(P, 3)`` approximate sensor poses ``x, y, theta`` [m, rad] in the map frame.
        map_segments: ``(M, 2, 2)`` nominal map [m], or ``None`` when the source has no map.
        t: ``(P,)`` times [s] or ``None``.
        covariates: per-scan covariates, each ``(P,)``.
        source: where the log came from (used in error messages).

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import LidarLog
        >>> log = LidarLog(ranges=np.full((2, 4, 3), 1.5), bearings=np.linspace(0, np.pi, 4),
        ...                poses=np.zeros((2, 3)), map_segments=np.array([[[2.0, -1.0], [2.0, 1.0]]]))
        >>> log.n_poses, log.n_bearings, log.ranges.shape
        (2, 4, (2, 4, 3))
    """

    ranges: NDArray[np.float64]
    bearings: NDArray[np.float64]
    poses: NDArray[np.float64]
    map_segments: NDArray[np.float64] | None
    t: NDArray[np.float64] | None = None
    covariates: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    source: str = "<memory>"

    @property
    def n_poses(self) -> int:
        """Number of poses (scans) P."""
        return int(self.ranges.shape[0])

    @property
    def n_bearings(self) -> int:
        """Number of bearings K."""
        return int(self.ranges.shape[1])

    def subset(self, idx: ArrayLike) -> LidarLog:
        """The log restricted to poses ``idx`` (indices or boolean mask)."""
        i = np.asarray(idx)
        return LidarLog(
            self.ranges[i],
            self.bearings,
            self.poses[i],
            self.map_segments,
            None if self.t is None else self.t[i],
            {k: v[i] for k, v in self.covariates.items()},
            self.source,
        )

    def require_map(self) -> NDArray[np.float64]:
        """The map segments, or a :class:`LidarLogError` when the log has none."""
        if self.map_segments is None:
            raise LidarLogError(f"{self.source}: field 'map_segments' is missing; pass a map to the loader")
        return self.map_segments


def _err(source: str, name: str, msg: str) -> LidarLogError:
    return LidarLogError(f"{source}: field {name!r} {msg}")


def _float_array(source: str, name: str, value: Any) -> NDArray[np.float64]:
    if np.iscomplexobj(value):  # never drop an imaginary part silently
        raise _err(source, name, "holds complex numbers; expected real values")
    kind = getattr(getattr(value, "dtype", None), "kind", None)
    if kind is not None and kind not in "fiu":
        raise _err(source, name, f"has dtype {value.dtype}; expected real numbers")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _err(source, name, f"is not numeric ({exc})") from None
    return arr


def _check_ranges(source: str, value: Any) -> NDArray[np.float64]:
    r = _float_array(source, "ranges", value)
    if r.ndim == 2:
        r = r[:, :, None]
    if r.ndim != 3:
        raise _err(source, "ranges", f"must have shape (S, K) or (P, K, R), got {r.shape}")
    if r.size == 0:
        raise _err(source, "ranges", f"is empty (shape {r.shape})")
    if np.isinf(r).any():
        raise _err(source, "ranges", "holds infinite values (use 0 for a null reading, NaN for missing)")
    neg = r < 0
    if neg.any():
        raise _err(
            source,
            "ranges",
            f"holds {int(neg.sum())} negative ranges (first at index {tuple(int(v) for v in np.argwhere(neg)[0])})",
        )
    if np.isnan(r).all():
        raise _err(source, "ranges", "holds no readings (all NaN)")
    far = r > MAX_RANGE
    if far.any():
        raise _err(source, "ranges", f"holds {int(far.sum())} readings beyond the sanity limit {MAX_RANGE:g} m")
    return r


def _check_per_pose(source: str, name: str, value: Any, n: int, width: int | None) -> NDArray[np.float64]:
    a = _float_array(source, name, value)
    want = (n,) if width is None else (n, width)
    if a.shape != want:
        raise _err(source, name, f"must have shape {want} to match 'ranges', got {a.shape}")
    if not np.isfinite(a).all():
        raise _err(source, name, "holds NaN or infinite values")
    big = np.abs(a) > MAX_COORD
    if big.any():
        raise _err(source, name, f"holds {a[big].ravel()[0]:g}, beyond the sanity limit {MAX_COORD:g}")
    return a


def _check_bearings(source: str, b: NDArray[np.float64]) -> None:
    if not np.isfinite(b).all():
        raise _err(source, "bearings", "holds NaN or infinite values")
    if (np.abs(b) > 2 * np.pi + 1e-9).any():
        raise _err(source, "bearings", "holds values beyond +-2 pi rad")
    wrapped = np.round(np.mod(b, 2 * np.pi), 9) % np.round(2 * np.pi, 9)
    if np.unique(wrapped).size != b.size:
        raise _err(source, "bearings", "holds repeated bearings (every beam needs its own direction)")


def _check_times(source: str, t: NDArray[np.float64]) -> None:
    """Times run forward: a log whose ``t`` decreases is refused.

    Real logs jitter (intel's CARMEN log steps back 0.11 s once in 909 scans), so a step back is
    tolerated when it is rare (at most 5 % of the steps) and small (at most 10 median steps).
    """
    d = np.diff(t)
    back = d < 0
    if not back.any():
        return
    step = float(np.median(np.abs(d[d != 0]))) if (d != 0).any() else 0.0
    i = int(np.flatnonzero(back)[0])
    if back.mean() > 0.05 or (-d[back]).max() > 10 * step:
        raise _err(source, "t", f"decreases at scan {i + 1} ({t[i]:g} then {t[i + 1]:g} s): times must run forward")


def log_from_arrays(
    ranges: ArrayLike,
    bearings: ArrayLike,
    poses: ArrayLike,
    map_segments: ArrayLike | None,
    t: ArrayLike | None = None,
    covariates: Mapping[str, ArrayLike] | None = None,
    source: str = "<memory>",
) -> LidarLog:
    """Validate arrays and build a :class:`LidarLog` (see the module docstring for the fields).

    Raises:
        LidarLogError: naming ``source`` and the field when a shape, value or type is wrong.
    """
    r = _check_ranges(source, ranges)
    p, k = r.shape[:2]
    b = _float_array(source, "bearings", bearings)
    if b.shape != (k,):
        raise _err(source, "bearings", f"must have shape ({k},) to match 'ranges', got {b.shape}")
    _check_bearings(source, b)
    ps = _check_per_pose(source, "poses", poses, p, 3)
    segs = None
    if map_segments is not None:
        try:
            segs = as_segments(
                _float_array(source, "map_segments", map_segments), name=f"{source}: field 'map_segments'"
            )
        except ValueError as exc:
            raise LidarLogError(str(exc)) from None
    tt = None if t is None else _check_per_pose(source, "t", t, p, None)
    if tt is not None:
        _check_times(source, tt)
    empty = [k2 for k2 in (covariates or {}) if bad_name(k2)]
    if empty:
        raise _err(source, f"cov_{empty[0]}", f"is no covariate name: it {bad_name(empty[0])}")
    cov = {k2: _check_per_pose(source, f"cov_{k2}", v, p, None) for k2, v in (covariates or {}).items()}
    return LidarLog(r, b, ps, segs, tt, cov, source)


def load_log(path: PathLike, **kwargs: Any) -> LidarLog:
    """Load a lidar log: the project's ``.npz``, a CARMEN log (``.log``, ``.clf``, ``.gz``) or a ROS bag.

    Args:
        path: the file (a ROS2 bag may be a folder).
        **kwargs: passed to :func:`read_carmen` / :func:`read_rosbag` (e.g. ``map=...``).

    Raises:
        LidarLogError: for a malformed log, naming the file and the field.
        FileNotFoundError: when ``path`` does not exist.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import load_log
        >>> from sensor_envs.lidar.log import save_log
        >>> from sensor_envs import LidarLog
        >>> scans = np.full((2, 4, 1), 1.5)  # 2 scans x 4 bearings, one reading each [m]
        >>> wall = np.array([[[2.0, -1.0], [2.0, 1.0]]])  # the map: one segment [m]
        >>> path = save_log(LidarLog(scans, np.linspace(0, np.pi, 4), np.zeros((2, 3)), wall), "example_log.npz")
        >>> load_log(path).ranges.shape  # (scans, bearings, 1): one reading per scan and bearing
        (2, 4, 1)
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: lidar log not found")
    if p.is_dir() or p.suffix in (".bag", ".db3", ".mcap"):
        return read_rosbag(p, **kwargs)
    if p.suffix == ".npz":
        if kwargs:
            raise TypeError(f"load_log: options {sorted(kwargs)} apply to CARMEN logs and ROS bags only")
        return _read_npz(p)
    return read_carmen(p, **kwargs)


def _read_npz(p: Path) -> LidarLog:
    try:
        data = load_npz(p, ".npz lidar log")
    except InputError as exc:
        raise LidarLogError(str(exc)) from None
    for name in ("ranges", "bearings", "poses", "map_segments"):
        if name not in data:
            raise _err(str(p), name, "is missing")
    cov = {k[4:]: v for k, v in data.items() if k.startswith("cov_")}
    return log_from_arrays(
        data["ranges"], data["bearings"], data["poses"], data["map_segments"], data.get("t"), cov, source=str(p)
    )


def save_log(log: LidarLog, path: PathLike) -> Path:
    """Write ``log`` in the project's ``.npz`` format (``(S, K)`` ranges when it has one repeat).

    Written to a temporary sibling and renamed; a path not ending in ``.npz`` is an ``OutputError``.
    """
    p = check_suffix(path, ".npz", option="lidar log")
    arrays: dict[str, NDArray[Any]] = {
        "ranges": (log.ranges[:, :, 0] if log.ranges.shape[2] == 1 else log.ranges).astype(np.float32),
        "bearings": log.bearings,
        "poses": log.poses,
    }
    if log.map_segments is not None:
        arrays["map_segments"] = log.map_segments
    if log.t is not None:
        arrays["t"] = log.t
    arrays.update({f"cov_{k}": v for k, v in log.covariates.items()})
    # typed as Any values: numpy's stub would otherwise match a ``**dict`` of arrays against ``allow_pickle: bool``
    payload: dict[str, Any] = arrays
    atomic_write(p, lambda tmp: np.savez_compressed(tmp, **payload))
    return p


def _map_or_none(map: Any) -> NDArray[np.float64] | None:
    if map is None:
        return None
    from sensor_envs.maps import load_map

    return load_map(map).segments


# ---------------------------------------------------------------------------------------------- CARMEN
def _parse_flaser(tok: list[str]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float, float]:
    n = int(tok[1])
    if n < 2 or len(tok) != 11 + n:  # FLASER n r_1..r_n x y theta odom_x odom_y odom_theta t host t_logger
        raise InputError(f"{n} readings in a line of {len(tok)} fields; FLASER needs at least 2 and n + 11 fields")
    r = np.asarray(tok[2 : 2 + n], dtype=np.float64)
    pose = np.asarray(tok[2 + n : 5 + n], dtype=np.float64)
    b = -np.pi / 2 + np.arange(n) * np.pi / (n - 1)  # n beams over [-pi/2, pi/2], both ends included
    return r, b, pose, float(tok[8 + n]), 80.0


def _parse_robotlaser1(
    tok: list[str],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float, float]:
    start, res, max_r = float(tok[2]), float(tok[4]), float(tok[5])
    n = int(tok[8])
    if not 2 <= n <= len(tok) - 10:
        raise InputError(f"{n} readings in a line of {len(tok)} fields")
    r = np.asarray(tok[9 : 9 + n], dtype=np.float64)
    m = int(tok[9 + n])
    if not 0 <= m or len(tok) != 24 + n + m:  # ... n ranges m remissions, 2 poses, 5 motion values, t host t_logger
        raise InputError(f"{n} readings and {m} remission values in a line of {len(tok)} fields, not n + m + 24")
    if not (np.isfinite([start, res, max_r]).all() and res != 0 and max_r > 0):
        raise InputError(f"start angle {start:g}, resolution {res:g} and maximum range {max_r:g} are not a scan")
    rest = tok[10 + n + m :]
    pose = np.asarray(rest[0:3], dtype=np.float64)  # laser pose
    return r, np.asarray(start + np.arange(n) * res, dtype=np.float64), pose, float(rest[11]), max_r


def read_carmen(path: PathLike, *, map: Any = None, max_range: float | None = None) -> LidarLog:
    r"""Read ``FLASER`` and ``ROBOTLASER1`` lines of a CARMEN log (optionally gzipped) into a log.

    FLASER bearing ``i`` of ``n`` is ``-pi/2 + i * pi / (n - 1)`` [rad] (``n`` beams over the 180 degrees
    field of view, both ends included: 361 beams are 0.5 degree steps); ROBOTLASER1 uses its start angle and
    resolution and its laser pose. A range ``>= max_range`` (default: 80 m for FLASER, the message's
    maximum range for ROBOTLASER1) or ``<= 0`` is a null (stored as ``0``).

    Args:
        path: the log.
        map: optional map (name, file or ``(M, 2, 2)`` array, see :func:`sensor_envs.maps.load_map`);
            CARMEN logs carry none.
        max_range: override of the null threshold [m].

    Raises:
        LidarLogError: when the file holds no laser line, a line is malformed, scans differ in size, or
            the file is unreadable (truncated or non-gzip ``.gz``, bytes that are not UTF-8 text).

    Examples:
        >>> from pathlib import Path
        >>> from sensor_envs import read_carmen
        >>> _ = Path("example.log").write_text("FLASER 3 1.0 2.0 0.0 0.0 0.0 0.0 0.0 0.0 0.0 0.5 robot 0.5\n")
        >>> log = read_carmen("example.log")  # FLASER n ranges... x y theta odom_x odom_y odom_theta t host t_local
        >>> log.ranges.shape, log.bearings.round(3).tolist()
        ((1, 3, 1), [-1.571, 0.0, 1.571])
    """
    p = Path(path)
    try:
        scans, poses, times, bearings = _read_carmen_lines(p, max_range)
    except InputError as exc:
        raise LidarLogError(str(exc)) from None
    if not scans:
        raise LidarLogError(f"{p}: field 'ranges': no FLASER or ROBOTLASER1 line found")
    ps, ts = np.stack(poses), scan_times(np.asarray(times), str(p))
    return log_from_arrays(
        np.stack(scans), bearings, ps, _map_or_none(map), ts, motion_covariates(ts, ps, str(p)), source=str(p)
    )


_CARMEN_TOKEN = re.compile(r"[+-]?([0-9]+(?:\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?|[+-]?(nan|inf)|[A-Za-z_][\w.-]*")
"""A field of a CARMEN laser line: a plain decimal number (not ``1_0``) or a word (the host name)."""


def _read_carmen_lines(p: Path, max_range: float | None) -> tuple[list[Any], list[Any], list[float], Any]:
    """Scans (nulls as 0), poses, times and bearings of the laser lines of CARMEN log ``p``."""
    scans, poses, times, bearings = [], [], [], None
    # bounded: regular file, size, inflated size and line length (sensor_envs.inputs)
    for lineno, line in open_gzip_lines(p, "field 'ranges'", gzipped=p.suffix == ".gz"):
        tok = line.split()
        if not tok or tok[0] not in ("FLASER", "ROBOTLASER1"):
            continue
        try:
            bad = next((t for t in tok[1:] if not _CARMEN_TOKEN.fullmatch(t)), None)
            if bad is not None:
                raise InputError(f"{bad[:20]!r} is not a plain decimal number")
            r, b, pose, ts, mx = (_parse_flaser if tok[0] == "FLASER" else _parse_robotlaser1)(tok)
        except (IndexError, ValueError) as exc:
            raise LidarLogError(f"{p}:{lineno}: field 'ranges': malformed {tok[0]} line ({exc})") from None
        if bearings is None:
            bearings = b
        elif b.shape != bearings.shape:
            raise LidarLogError(f"{p}:{lineno}: field 'ranges': {b.size} readings, expected {bearings.size}")
        thr = mx if max_range is None else max_range
        scans.append(np.where((r >= thr) | (r <= 0), 0.0, r))
        if len(scans) > MAX_SCANS:
            raise LidarLogError(f"{p}:{lineno}: field 'ranges': more than {MAX_SCANS} scans")
        poses.append(pose)
        times.append(ts)
    return scans, poses, times, bearings


# ---------------------------------------------------------------------------------------------- ROS bags
_SCAN_TYPES = frozenset({"sensor_msgs/msg/LaserScan"})
_POSE_TYPES = frozenset(
    {"nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped"}
)


def _deserialize(reader: Any, raw: bytes, conn: Any, p: Path) -> Any:
    """One message; a damaged one is a :class:`LidarLogError` naming the bag and the topic."""
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as exc:  # rosbags raises AssertionError/IndexError/struct.error... on damaged bytes
        raise LidarLogError(
            f"{p}: topic {conn.topic!r}: a damaged {conn.msgtype} message ({type(exc).__name__})"
        ) from None


def _check_scan_header(msg: Any, p: Path, topic: str, i: int) -> None:
    """A LaserScan's angles and limits: finite, a non-zero increment, ``0 <= range_min < range_max``."""
    vals = [msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max]
    ok = np.isfinite(vals).all() and msg.angle_increment != 0 and 0 <= msg.range_min < msg.range_max <= 10 * MAX_RANGE
    if not ok:
        raise LidarLogError(
            f"{p}: field 'bearings': {topic} scan {i} has angle_min {msg.angle_min:g}, angle_increment "
            f"{msg.angle_increment:g}, range_min {msg.range_min:g}, range_max {msg.range_max:g}"
        )


def _pose_of(msg: Any, p: Path | None = None, i: int = 0) -> NDArray[np.float64]:
    """x, y, yaw of a nav_msgs/Odometry, geometry_msgs/PoseStamped or PoseWithCovarianceStamped."""
    pose = msg.pose
    if hasattr(pose, "pose"):
        pose = pose.pose
    q = pose.orientation
    norm = np.sqrt(q.w**2 + q.x**2 + q.y**2 + q.z**2)
    if not (np.isfinite(norm) and abs(norm - 1.0) < 0.1):
        raise LidarLogError(f"{p}: field 'poses': pose {i} has a quaternion of norm {norm:g}, expected 1")
    return np.array([pose.position.x, pose.position.y, quaternion_yaw(q.w, q.x, q.y, q.z)])


def resample_bearings(log: LidarLog, n: int) -> LidarLog:
    """The log on ``n`` evenly spaced bearings ``2 pi k / n`` (k = 0..n-1, counter-clockwise from the sensor's x).

    Each new bearing takes the readings of the logged beam nearest to it in angle (no interpolation: a
    reading between two walls is no reading of either). A scan whose first and last beams point the same
    way (a ROS ``LaserScan`` of 361 beams over -180..+180 degrees) therefore gives the Neato world's 360
    one-degree bearings from 0 degrees, in order, without the duplicate.

    Args:
        log: a log whose beams cover the full circle.
        n: number of bearings (the Neato world and the shipped lidar model: 360).

    Raises:
        LidarLogError: naming the log's field ``bearings`` when a new bearing has no logged beam within
            half a step of either grid (e.g. a 180-degree SICK scan resampled to 360 bearings).
    """
    if n < 1:
        raise LidarLogError(f"{log.source}: field 'bearings': cannot resample to {n} bearings")
    two_pi = 2.0 * np.pi
    new = two_pi * np.arange(n) / n
    old = np.mod(log.bearings, two_pi)
    nearest, nearest_gap = _nearest_beams(new, old)
    step_old = float(np.median(np.diff(np.sort(np.unique(np.round(old, 9)))))) if old.size > 1 else two_pi
    tol = 0.5 * max(step_old, two_pi / n) + 1e-9
    far = nearest_gap > tol
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise LidarLogError(
            f"{log.source}: field 'bearings': no logged beam within {np.rad2deg(tol):.3g} deg of bearing "
            f"{np.rad2deg(new[k]):.4g} deg (the {log.n_bearings} beams cover "
            f"{np.rad2deg(np.ptp(log.bearings)):.4g} deg; resampling to {n} bearings needs the full circle)"
        )
    return replace(log, ranges=log.ranges[:, nearest], bearings=new)


def _nearest_beams(new: NDArray[np.float64], old: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Index of the beam of ``old`` nearest in angle to each of ``new`` (both in [0, 2 pi)), and that gap [rad].

    Sorted search over the circle: memory in ``len(new) + len(old)`` (a ``new x old`` table of gaps was 1.6 GB
    for a 2000-beam scan resampled to ``--bearings 100000``). Ties go to the earlier beam in the log's order.
    """
    two_pi = 2.0 * np.pi
    order = np.lexsort((np.arange(old.size), old))  # by angle, then by place in the log
    keep = np.r_[True, np.diff(old[order]) != 0]  # beams pointing one way: the first in the log stands for all
    order = order[keep]
    ring = old[order]
    right = np.searchsorted(ring, new) % ring.size
    left = (right - 1) % ring.size
    gaps = [np.abs((new - ring[k] + np.pi) % two_pi - np.pi) for k in (left, right)]
    cand = np.stack([order[left], order[right]])
    gap = np.stack(gaps)
    pick = np.where((gap[0] < gap[1]) | ((gap[0] == gap[1]) & (cand[0] <= cand[1])), 0, 1)
    cols = np.arange(new.size)
    return cand[pick, cols].astype(np.int64), gap[pick, cols]


def read_rosbag(
    path: PathLike,
    *,
    scan_topic: str = "/scan",
    pose_topic: str = "/odom",
    map: Any = None,
) -> LidarLog:
    """Read ``sensor_msgs/LaserScan`` messages and a pose topic of a ROS1 or ROS2 bag (``rosbags``).

    Each scan gets the pose interpolated at its bag time (x, y linear, yaw on the unwrapped angle);
    scans outside the pose topic's time span are dropped. Readings that are ``0``, ``inf``, below
    ``range_min`` or above ``range_max`` are nulls; NaN readings are missing.

    Args:
        path: a ``.bag`` file or a ROS2 bag folder.
        scan_topic: the LaserScan topic.
        pose_topic: ``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped`` or ``PoseWithCovarianceStamped``.
        map: optional map (see :func:`sensor_envs.maps.load_map`).

    Raises:
        LidarLogError: naming the bag and topic when a topic is absent or scans differ in size, or when
            the bag is empty, truncated or damaged.

    Examples:
        >>> import os
        >>> from sensor_envs import read_rosbag
        >>> data = os.environ.get("SENSOR_ENVS_REAL_DATA", "../shared/data/real")
        >>> log = read_rosbag(os.path.join(data, "neato_ros1_bags", "middle.bag"))  # doctest: +SKIP
        >>> log.ranges.shape[1]  # doctest: +SKIP
        360
    """
    p = Path(path)
    try:
        from rosbags.highlevel import AnyReaderError  # optional dependency
        from rosbags.rosbag1 import ReaderError as Ros1Error
        from rosbags.rosbag2 import ReaderError as Ros2Error
    except ImportError:
        raise LidarLogError(
            f"{p}: reading a ROS bag needs the optional package rosbags: pip install rosbags "
            "(in a clone: pip install -e '.[ros]')"
        ) from None
    if not p.is_dir():  # a ROS2 bag may be a folder; a FIFO or device is refused before rosbags opens it
        check_regular_file(p, "ROS bag")
    try:
        scans, st, pts, pt, twists, bearings = _read_bag_messages(p, scan_topic, pose_topic)
    except (AnyReaderError, Ros1Error, Ros2Error, EOFError, OSError, struct.error, UnicodeDecodeError) as exc:
        raise LidarLogError(f"{p}: not a readable ROS bag ({' '.join(str(exc).split())})") from None
    except (AssertionError, IndexError, KeyError) as exc:  # rosbags checks its index records with assert
        raise LidarLogError(f"{p}: not a readable ROS bag (damaged record: {type(exc).__name__})") from None
    if not scans:
        raise LidarLogError(f"{p}: field 'ranges': no message on {scan_topic!r}")
    if not pts:
        raise LidarLogError(f"{p}: field 'poses': no message on {pose_topic!r}")
    st_a, pt_a, pose_a = np.asarray(st), np.asarray(pt), np.stack(pts)
    keep = (st_a >= pt_a[0]) & (st_a <= pt_a[-1])
    if not keep.any():
        raise LidarLogError(f"{p}: field 'poses': no {scan_topic} scan lies within the {pose_topic} time span")
    yaw = np.unwrap(pose_a[:, 2])
    ts = st_a[keep]
    poses = np.stack(
        [np.interp(ts, pt_a, pose_a[:, 0]), np.interp(ts, pt_a, pose_a[:, 1]), np.interp(ts, pt_a, yaw)], axis=1
    )
    poses[:, 2] = (poses[:, 2] + np.pi) % (2 * np.pi) - np.pi
    if len(twists) == len(pts):
        tw = np.asarray(twists, dtype=np.float64)
        cov = {"v": np.interp(ts, pt_a, tw[:, 0]), "omega": np.interp(ts, pt_a, tw[:, 1])}
    else:
        cov = motion_covariates(ts, poses, str(p))
    return log_from_arrays(np.stack(scans)[keep], bearings, poses, _map_or_none(map), ts - ts[0], cov, source=str(p))


def _read_bag_messages(
    p: Path, scan_topic: str, pose_topic: str
) -> tuple[list[Any], list[float], list[Any], list[float], list[tuple[float, float]], Any]:
    """Scans (nulls as 0), scan times [s], poses, pose times [s], twists ``(v, omega)`` and bearings of bag ``p``.

    The twists list is empty when the pose topic carries none (e.g. PoseStamped).
    """
    from rosbags.highlevel import AnyReader

    scans: list[NDArray[np.float64]] = []
    pts: list[NDArray[np.float64]] = []
    st: list[float] = []
    pt: list[float] = []
    bearings = None
    twists: list[tuple[float, float]] = []
    with AnyReader([p]) as reader:
        topics = {c.topic for c in reader.connections}
        for topic in (scan_topic, pose_topic):
            if topic not in topics:
                raise LidarLogError(f"{p}: topic {topic!r} not in the bag (topics: {sorted(topics)})")
        conns = [c for c in reader.connections if c.topic in (scan_topic, pose_topic)]
        for conn in conns:
            want = _SCAN_TYPES if conn.topic == scan_topic else _POSE_TYPES
            if conn.msgtype not in want:
                field = "ranges" if conn.topic == scan_topic else "poses"
                raise LidarLogError(
                    f"{p}: field {field!r}: topic {conn.topic!r} carries {conn.msgtype}, expected one of {sorted(want)}"
                )
        for conn, t, raw in reader.messages(connections=conns):
            msg: Any = _deserialize(reader, raw, conn, p)  # a ROS message class generated at run time
            if conn.topic == pose_topic:
                pts.append(_pose_of(msg, p, len(pts)))
                pt.append(t * 1e-9)
                if hasattr(msg, "twist"):  # nav_msgs/Odometry: v [m/s] and omega [rad/s] in the base frame
                    tw = msg.twist.twist
                    twists.append((tw.linear.x, tw.angular.z))
                continue
            r = np.asarray(msg.ranges, dtype=np.float64)
            _check_scan_header(msg, p, scan_topic, len(scans))
            b = msg.angle_min + np.arange(r.size) * msg.angle_increment
            if bearings is None:
                bearings = b
            elif b.shape != bearings.shape:
                raise LidarLogError(
                    f"{p}: field 'ranges': a {scan_topic} scan has {b.size} readings, expected {bearings.size}"
                )
            null = ~np.isnan(r) & ((r <= 0) | ~np.isfinite(r) | (r < msg.range_min) | (r > msg.range_max))
            scans.append(np.where(null, 0.0, r))
            if len(scans) > MAX_SCANS:
                raise LidarLogError(f"{p}: field 'ranges': more than {MAX_SCANS} scans on {scan_topic!r}")
            st.append(t * 1e-9)
    return scans, st, pts, pt, twists, bearings


def scan_times(t: NDArray[np.float64], source: str) -> NDArray[np.float64]:
    """Scan times [s] a user can trust: the logged ones, or evenly spread ones when those are too coarse.

    Too coarse: fewer distinct values than half the scans (e.g. timestamps cut to 6 significant digits).
    Then the times are spread evenly over the logged span at the scan rate it implies, and a
    ``UserWarning`` names the file and field ``t``.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size < 3 or not np.isfinite(t).all() or np.unique(t).size >= 0.5 * t.size:
        return t
    span = float(t[-1] - t[0])
    period = span / (t.size - 1) if span > 0 else 0.2
    warnings.warn(
        f"{source}: field 't': {np.unique(t).size} distinct times for {t.size} scans; time, speed and turn "
        f"rate derived from the scan rate instead ({1 / period:.3g} Hz{'' if span > 0 else ', assumed'})",
        stacklevel=3,
    )
    return t[0] + period * np.arange(t.size)


def motion_covariates(
    t: NDArray[np.float64], poses: NDArray[np.float64], source: str
) -> dict[str, NDArray[np.float64]]:
    """Per-scan speed ``v`` [m/s] and turn rate ``omega`` [rad/s] from poses ``(S, 3)`` at times ``t (S,)`` [s].

    Central differences (one-sided at the ends) of the position and the unwrapped heading; a
    single scan or non-increasing times give zeros where the time step is not positive.
    """
    if t.size < 2 or not np.isfinite(poses).all():
        return {"v": np.zeros(t.size), "omega": np.zeros(t.size)}
    if not np.isfinite(t).all():
        raise _err(source, "t", "holds NaN or infinite times")
    dt = np.gradient(t)
    good = dt > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.hypot(np.gradient(poses[:, 0]), np.gradient(poses[:, 1])) / dt
        w = np.gradient(np.unwrap(poses[:, 2])) / dt
    return {"v": np.where(good, v, 0.0), "omega": np.where(good, w, 0.0)}


def training_summary(log: LidarLog) -> dict[str, Any]:
    """What a fitted lidar model records of its training log (``training_``).

    The log's file name, sizes, null share and the sha256 of its ranges: a card names its data without
    storing it.
    """
    return {
        "source": Path(log.source).name,
        "n_poses": log.n_poses,
        "n_bearings": log.n_bearings,
        "n_readings": int((~np.isnan(log.ranges)).sum()),
        "null_fraction": float(np.nanmean(np.where(np.isnan(log.ranges), np.nan, log.ranges == 0))),
        "sha256_of_ranges": hashlib.sha256(np.ascontiguousarray(log.ranges).tobytes()).hexdigest(),
    }
