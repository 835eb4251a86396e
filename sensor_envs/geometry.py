"""Planar geometry shared by worlds, rigs and sensor models.

Written once, used everywhere (world truth -> geometry -> sensor model -> wrapper):

* line-segment maps: exact, vectorised raycasting of K bearings from P poses against
  M segments, returning range [m], angle of incidence [rad] and the index of the hit segment;
* rectangles (vehicles): corners, closest corner, angular extent and occlusion as seen from a
  sensor;
* frames: points to and from a pose's frame, quaternion to yaw, free poses in a map.

Conventions: metres and radians; a pose is ``(x, y, theta)`` in the map (world) frame; the sensor
frame has x forward and y left; bearings are measured counter-clockwise from the sensor x axis.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.inputs import InputError
from sensor_envs.jit import compiled
from sensor_envs.trig import acos_unit

__all__ = [
    "RAY_EPS",
    "as_segments",
    "raycast",
    "raycast_pose",
    "point_segment_distance",
    "nearest_wall_distance",
    "wrap_angle",
    "to_frame",
    "from_frame",
    "quaternion_yaw",
    "sample_free_poses",
    "rectangle_corners",
    "rectangle_segments",
    "closest_corner",
    "angular_interval",
    "occluded_fraction",
    "polar_frame",
    "to_polar_frame",
    "from_polar_frame",
]

RAY_EPS = 1e-9
"""Hits closer than this along a ray [m] are ignored: a ray that starts on a wall does not see it."""


def wrap_angle(a: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles [rad] to [-pi, pi)."""
    a = np.asarray(a, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def as_segments(segments: ArrayLike, *, name: str = "segments") -> NDArray[np.float64]:
    """Validate and return line segments as an ``(M, 2, 2)`` float64 array ``[[x1, y1], [x2, y2]]``.

    Accepts ``(M, 2, 2)`` or ``(M, 4)`` input in metres.

    Raises:
        InputError: naming ``name`` when the array is empty, not real numbers, has the wrong shape, holds NaN/inf,
            or contains a zero-length segment.
    """
    try:
        raw = np.asarray(segments)
    except (TypeError, ValueError) as exc:  # ragged nesting
        raise InputError(f"{name}: expected an array of numbers ({' '.join(str(exc).split())[:120]})") from None
    if raw.dtype.kind not in "fiu":  # booleans, strings, objects, complex: no coordinates
        raise InputError(f"{name}: expected real coordinates [m], got dtype {raw.dtype}")
    arr = raw.astype(np.float64)
    if arr.ndim == 2 and arr.shape[1] == 4:
        arr = arr.reshape(-1, 2, 2)
    if arr.ndim != 3 or arr.shape[1:] != (2, 2):
        raise InputError(f"{name}: expected shape (M, 2, 2) or (M, 4), got {arr.shape}")
    if arr.shape[0] == 0:
        raise InputError(f"{name}: the map has no segments")
    bad = ~np.isfinite(arr).all(axis=(1, 2))
    if bad.any():
        raise InputError(f"{name}: segment {int(np.flatnonzero(bad)[0])} has a NaN or infinite coordinate")
    far = (np.abs(arr) > 1e6).any(axis=(1, 2))
    if far.any():
        raise InputError(f"{name}: segment {int(np.flatnonzero(far)[0])} has a coordinate beyond +-1e6 m")
    length = np.linalg.norm(arr[:, 1] - arr[:, 0], axis=1)
    zero = length <= 1e-12
    if zero.any():
        raise InputError(f"{name}: segment {int(np.flatnonzero(zero)[0])} has zero length")
    return arr


_BLOCK_ELEMENTS = 16384  # rays x segments per block of poses in raycast (about 128 kB per temporary)


def raycast(
    origins: ArrayLike,
    angles: ArrayLike,
    segments: NDArray[np.float64],
    max_range: float = np.inf,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Exact raycast of rays against line segments.

    Args:
        origins: ``(P, 2)`` ray origins in the map frame [m].
        angles: ``(P, K)`` (or ``(K,)``, shared by all origins) absolute ray directions in the map
            frame [rad].
        segments: ``(M, 2, 2)`` segments, already validated by :func:`as_segments`.
        max_range: rays with no hit closer than this return ``inf`` [m].

    Returns:
        ``ranges (P, K)`` distance to the nearest hit [m] (``inf`` if none within ``max_range``),
        ``incidence (P, K)`` angle between the ray and the hit segment's normal in ``[0, pi/2]``
        [rad] (``nan`` where no hit), and ``index (P, K)`` of the hit segment (``-1`` if none).

    A ray collinear with a segment that lies ahead hits the segment's nearer end with incidence
    ``pi/2``; a ray parallel to but off a segment misses it. A ray that starts on a segment (at an end
    or inside it) does not see that segment: hits at distance ``<= RAY_EPS`` are ignored.
    """
    o = np.atleast_2d(np.asarray(origins, dtype=np.float64))
    ang = np.asarray(angles, dtype=np.float64)
    if ang.ndim == 1:
        ang = np.broadcast_to(ang, (o.shape[0], ang.shape[0]))
    one, zero = np.ones(o.shape[0]), np.zeros(o.shape[0])  # no rotation: the directions are the angles' own
    return _raycast_dirs(o, one, zero, np.cos(ang), np.sin(ang), segments, max_range)


def _raycast_dirs(
    o: NDArray[np.float64],
    ct: NDArray[np.float64],
    st: NDArray[np.float64],
    cb: NDArray[np.float64],
    sb: NDArray[np.float64],
    segments: NDArray[np.float64],
    max_range: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """:func:`raycast` of rays from ``o (P, 2)`` in the map frame, given by direction cosines.

    Ray ``(p, k)`` points along ``(cb, sb)[p, k]`` (or ``[0, k]`` when ``cb, sb`` have one row: bearings shared by
    all poses) rotated by the heading whose cosine and sine are ``ct[p], st[p]``: ``dx = ct cb - st sb``,
    ``dy = st cb + ct sb``. The compiled kernel when numba is installed, else numpy; both do that arithmetic
    in that order, so they return the same bits.
    """
    kernel = _compiled_kernel()
    if kernel is None:
        dx = ct[:, None] * cb - st[:, None] * sb
        dy = st[:, None] * cb + ct[:, None] * sb
        return _raycast_numpy(o, dx, dy, segments, max_range)
    a = segments[:, 0]
    e = segments[:, 1] - a
    ex, ey = np.ascontiguousarray(e[:, 0]), np.ascontiguousarray(e[:, 1])
    seg_len = np.hypot(ex, ey)
    rng, cosine, idx = kernel(
        np.ascontiguousarray(o[:, 0]),
        np.ascontiguousarray(o[:, 1]),
        np.ascontiguousarray(ct),
        np.ascontiguousarray(st),
        np.ascontiguousarray(cb),
        np.ascontiguousarray(sb),
        np.ascontiguousarray(a[:, 0]),
        np.ascontiguousarray(a[:, 1]),
        ex,
        ey,
        1e-12 * (1.0 + seg_len),
        ex / seg_len,
        ey / seg_len,
        RAY_EPS,
        float(max_range),
    )
    return rng, acos_unit(cosine), idx


def _finish(
    t: NDArray[np.float64],
    idx: NDArray[np.int64],
    dx: NDArray[np.float64],
    dy: NDArray[np.float64],
    ex: NDArray[np.float64],
    ey: NDArray[np.float64],
    max_range: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Ranges, incidence and segment index from the nearest hit ``t (P, K)`` and its segment ``idx (P, K)``."""
    hit = np.isfinite(t) & (t <= max_range)
    rng = np.where(hit, t, np.inf)
    # Incidence: |cos| between ray and segment direction -> angle to normal = arccos(|sin|).
    seg_len = np.hypot(ex, ey)
    cx, cy = (ex / seg_len)[idx], (ey / seg_len)[idx]
    sin_ = np.abs(dx * cy - dy * cx)
    incidence = np.where(hit, acos_unit(np.clip(sin_, 0.0, 1.0)), np.nan)
    return rng, incidence, np.where(hit, idx, -1).astype(np.int64)


def _raycast_numpy(
    o: NDArray[np.float64],
    dx2: NDArray[np.float64],
    dy2: NDArray[np.float64],
    segments: NDArray[np.float64],
    max_range: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """:func:`_raycast_dirs` in numpy (no compiled kernel): ``(M, P, K)`` temporaries, in blocks of poses."""
    block = max(1, _BLOCK_ELEMENTS // (segments.shape[0] * max(1, dx2.shape[1])))
    if o.shape[0] > block:  # many poses: blocks whose (M, P, K) temporaries stay in cache; same numbers
        parts = [
            _raycast_numpy(o[i : i + block], dx2[i : i + block], dy2[i : i + block], segments, max_range)
            for i in range(0, len(o), block)
        ]
        return tuple(np.concatenate(x) for x in zip(*parts, strict=True))  # type: ignore[return-value]
    # Layout (M, P, K): the long bearing axis innermost keeps numpy's inner loops long and contiguous.
    dx, dy = dx2[None], dy2[None]  # (1, P, K)
    a = segments[:, 0]  # (M, 2)
    e = segments[:, 1] - a  # (M, 2)
    ex, ey = e[:, 0], e[:, 1]
    ex3, ey3 = ex[:, None, None], ey[:, None, None]  # (M, 1, 1)
    wx = (a[:, 0][:, None] - o[:, 0][None, :])[..., None]  # (M, P, 1)
    wy = (a[:, 1][:, None] - o[:, 1][None, :])[..., None]
    den = dx * ey3 - dy * ex3  # (M, P, K)  cross(d, e)
    t_num = wx * ey3 - wy * ex3  # cross(w, e), (M, P, 1)
    u_num = wx * dy - wy * dx  # cross(w, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = t_num / den
        u = u_num / den
    ok = (np.abs(den) > 1e-12) & (u >= 0.0) & (u <= 1.0) & (t > RAY_EPS)
    t = np.where(ok, t, np.inf)
    # Collinear rays (den == 0 and origin on the segment's line): hit at the nearer end.
    col = (np.abs(den) <= 1e-12) & (np.abs(t_num) <= 1e-12 * (1.0 + np.hypot(ex3, ey3)))
    if col.any():
        bx, by = wx + ex3, wy + ey3  # end b relative to origin
        ta = wx * dx + wy * dy
        tb = bx * dx + by * dy
        ahead = (ta > RAY_EPS) & (tb > RAY_EPS)  # origin off the segment, segment ahead
        tc = np.where(ahead, np.minimum(ta, tb), np.inf)
        t = np.where(col & (tc < t), tc, t)
    idx = np.argmin(t, axis=0)  # (P, K)
    rng = np.take_along_axis(t, idx[None], axis=0)[0]
    return _finish(rng, idx, dx[0], dy[0], ex, ey, max_range)


# ---------------------------------------------------------------------------------------------- compiled kernel
_RaycastResult = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]


def _compiled_kernel() -> Callable[..., _RaycastResult] | None:
    """The numba kernel of :func:`raycast` when numba is installed (the ``fast`` extra), else None.

    ``SENSOR_ENVS_NO_NUMBA=1`` forces the numpy path. Both paths do the same float64 operations in the same
    order per ray and segment (no fused multiply-add, no fast-math), so they return the same bits.
    """
    return compiled(_raycast_loops)


def _raycast_loops(
    ox: NDArray[np.float64],
    oy: NDArray[np.float64],
    ct: NDArray[np.float64],
    st: NDArray[np.float64],
    cb: NDArray[np.float64],
    sb: NDArray[np.float64],
    ax: NDArray[np.float64],
    ay: NDArray[np.float64],
    ex: NDArray[np.float64],
    ey: NDArray[np.float64],
    col_tol: NDArray[np.float64],
    cx: NDArray[np.float64],
    cy: NDArray[np.float64],
    eps: float,
    max_range: float,
) -> _RaycastResult:
    """:func:`raycast` in loops: per ray and segment the arithmetic of :func:`_raycast_numpy`, in its order.

    Segments are tried in order and a later one wins only when strictly nearer (``argmin``'s first-minimum
    rule); the rays' directions are ``(cb, sb)`` rotated by ``(ct, st)`` as in :func:`_raycast_dirs`, ``cx, cy``
    are the segments' unit directions and ``col_tol`` the collinearity tolerances. Returns ranges, the
    incidences' cosines (their :func:`acos_unit` is the incidence) and segment indices.
    """
    n_p, n_k = ct.shape[0], cb.shape[1]
    shared = cb.shape[0] == 1
    n_m = ax.shape[0]
    rng = np.empty((n_p, n_k))
    inc = np.empty((n_p, n_k))
    idx = np.empty((n_p, n_k), dtype=np.int64)
    dxs, dys, best = np.empty(n_k), np.empty(n_k), np.empty(n_k)  # per pose: ray directions, nearest hit
    best_m = np.empty(n_k, dtype=np.int64)
    for p in range(n_p):
        b = 0 if shared else p
        for k in range(n_k):
            dxs[k] = ct[p] * cb[b, k] - st[p] * sb[b, k]
            dys[k] = st[p] * cb[b, k] + ct[p] * sb[b, k]
            best[k], best_m[k] = np.inf, 0
        for m in range(n_m):  # segment-major: the inner loop over rays has no branch and vectorises
            wx, wy = ax[m] - ox[p], ay[m] - oy[p]
            t_num = wx * ey[m] - wy * ex[m]
            on_line = abs(t_num) <= col_tol[m]
            for k in range(n_k):
                dxk, dyk = dxs[k], dys[k]
                den = dxk * ey[m] - dyk * ex[m]
                regular = abs(den) > 1e-12
                u = (wx * dyk - wy * dxk) / den
                tt = t_num / den
                ok = regular & (u >= 0.0) & (u <= 1.0) & (tt > eps)
                ta = wx * dxk + wy * dyk  # collinear: the nearer end, if the segment lies ahead
                tb = (wx + ex[m]) * dxk + (wy + ey[m]) * dyk
                ahead = (not regular) & on_line & (ta > eps) & (tb > eps)
                t = tt if ok else (min(ta, tb) if ahead else np.inf)
                nearer = t < best[k]
                best[k] = t if nearer else best[k]
                best_m[k] = m if nearer else best_m[k]
        for k in range(n_k):
            if best[k] < np.inf and best[k] <= max_range:  # a hit
                m = best_m[k]
                rng[p, k] = best[k]
                inc[p, k] = min(max(abs(dxs[k] * cy[m] - dys[k] * cx[m]), 0.0), 1.0)  # the cosine; arccos after
                idx[p, k] = m
            else:
                rng[p, k], inc[p, k], idx[p, k] = np.inf, np.nan, -1
    return rng, inc, idx


def raycast_pose(
    poses: ArrayLike,
    bearings: ArrayLike,
    segments: NDArray[np.float64],
    max_range: float = np.inf,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Raycast the bearings of a planar range sensor at one or more poses.

    Args:
        poses: ``(3,)`` or ``(P, 3)`` sensor poses ``x, y, theta`` in the map frame [m, rad].
        bearings: ``(K,)`` bearings in the sensor frame, counter-clockwise from x forward [rad].
        segments: ``(M, 2, 2)`` map segments [m].
        max_range: maximum range [m]; farther hits return ``inf``.

    Returns:
        As :func:`raycast`, shaped ``(K,)`` for one pose or ``(P, K)`` for several.
    """
    p = np.asarray(poses, dtype=np.float64)
    single = p.ndim == 1
    p = np.atleast_2d(p)
    b = np.asarray(bearings, dtype=np.float64)
    cb, sb = np.cos(b)[None], np.sin(b)[None]  # a ray's direction: the bearing's rotated by the heading
    out = _raycast_dirs(p[:, :2], np.cos(p[:, 2]), np.sin(p[:, 2]), cb, sb, segments, max_range)
    if single:
        return out[0][0], out[1][0], out[2][0]
    return out


def point_segment_distance(points: ArrayLike, segments: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance [m] from each of ``(N, 2)`` points to each of ``(M, 2, 2)`` segments, ``(N, M)``."""
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))[:, None, :]
    a, b = segments[None, :, 0], segments[None, :, 1]
    e = b - a
    s = np.clip(np.sum((p - a) * e, axis=-1) / np.sum(e * e, axis=-1), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[..., None] * e), axis=-1)


def nearest_wall_distance(points: ArrayLike, segments: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance [m] from each of ``(N, 2)`` points (or the x, y of ``(N, 3)`` poses) to the nearest segment, ``(N,)``.

    ``point_segment_distance(points, segments).min(axis=1)`` for ``(M, 2, 2)`` segments; with numba one compiled
    loop does the same arithmetic per point and segment (no ``(N, M, 2)`` temporaries): the same bits.
    """
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))[:, :2]
    kernel = compiled(_nearest_wall_loops)
    if kernel is None:
        return point_segment_distance(p, segments).min(axis=1)
    return kernel(np.ascontiguousarray(p), np.ascontiguousarray(segments, dtype=np.float64))


def _nearest_wall_loops(p: NDArray[np.float64], segments: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`nearest_wall_distance` in loops, each distance computed as :func:`point_segment_distance` does."""
    out = np.empty(p.shape[0])
    for i in range(p.shape[0]):
        best = np.inf
        for m in range(segments.shape[0]):
            ax, ay = segments[m, 0, 0], segments[m, 0, 1]
            ex, ey = segments[m, 1, 0] - ax, segments[m, 1, 1] - ay
            s = ((p[i, 0] - ax) * ex + (p[i, 1] - ay) * ey) / (ex * ex + ey * ey)
            s = min(max(s, 0.0), 1.0)
            dx, dy = p[i, 0] - (ax + s * ex), p[i, 1] - (ay + s * ey)
            d = math.sqrt(dx * dx + dy * dy)
            if m == 0 or d < best or math.isnan(d):  # np.min: the least, NaN if any
                best = d
                if math.isnan(d):
                    break
        out[i] = best
    return out


def to_frame(points: ArrayLike, pose: ArrayLike) -> NDArray[np.float64]:
    """Express world points ``(..., 2)`` in the frame of ``pose = (x, y, theta)`` (x fwd, y left)."""
    pts = np.asarray(points, dtype=np.float64)
    x, y, th = np.asarray(pose, dtype=np.float64)
    c, s = np.cos(th), np.sin(th)
    dx, dy = pts[..., 0] - x, pts[..., 1] - y
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def from_frame(points: ArrayLike, pose: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`to_frame`: points ``(..., 2)`` in the frame of ``pose`` to the world frame."""
    pts = np.asarray(points, dtype=np.float64)
    x, y, th = np.asarray(pose, dtype=np.float64)
    c, s = np.cos(th), np.sin(th)
    return np.stack([x + c * pts[..., 0] - s * pts[..., 1], y + s * pts[..., 0] + c * pts[..., 1]], axis=-1)


def quaternion_yaw(w: float, x: float, y: float, z: float) -> float:
    """Yaw [rad] (rotation about z, counter-clockwise, in ``[-pi, pi]``) of the unit quaternion ``w + xi + yj + zk``."""
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def sample_free_poses(
    segments: NDArray[np.float64],
    n: int,
    rng: np.random.Generator,
    clearance: float = 0.2,
    *,
    away_from: ArrayLike | None = None,
    min_distance: float = 0.0,
    enclosure_rays: int = 4,
    max_tries: int = 100,
) -> NDArray[np.float64]:
    """``(n, 3)`` poses ``x, y, theta`` [m, rad] drawn uniformly in free space of a segment map.

    Positions are uniform in the map's bounding box, at least ``clearance`` [m] from every wall, at least
    ``min_distance`` [m] from ``away_from`` (a point, if given) and enclosed: rays in ``enclosure_rays``
    evenly spaced directions all hit a wall. Each try draws ``4 n`` candidate positions; headings are
    uniform in ``[-pi, pi)`` and drawn after the positions.

    Args:
        segments: ``(M, 2, 2)`` map [m].
        n: number of poses.
        rng: the generator to draw from (e.g. the world's stream).
        clearance: least distance to every wall [m].
        away_from: ``(2,)`` a position [m] the poses keep ``min_distance`` from, or ``None``.
        min_distance: see ``away_from`` [m].
        enclosure_rays: number of rays of the enclosure test.
        max_tries: rounds of ``4 n`` candidates before giving up.

    Raises:
        ValueError: when fewer than ``n`` free positions are found.
    """
    lo, hi = segments.reshape(-1, 2).min(0), segments.reshape(-1, 2).max(0)
    span = hi - lo
    rays = np.arange(enclosure_rays) * (2 * np.pi / enclosure_rays)
    out: list[NDArray[np.float64]] = []
    for _ in range(max_tries):
        xy = lo + span * rng.random((4 * n, 2))  # rng.uniform(lo, hi, ...)'s numbers, without its broadcasting cost
        ok = nearest_wall_distance(xy, segments) >= clearance
        if away_from is not None:
            ok &= np.hypot(*(xy - np.asarray(away_from, dtype=np.float64)).T) >= min_distance
        r, _, _ = raycast(xy, rays, segments)  # the enclosure test: rays in the map frame
        ok &= np.isfinite(r).all(axis=1)
        out.extend(xy[ok])
        if len(out) >= n:
            xy = np.asarray(out[:n])
            return np.column_stack([xy, rng.uniform(-np.pi, np.pi, n)])
    raise InputError(f"map: found only {len(out)} of {n} free poses (clearance {clearance} m)")


def rectangle_corners(
    x: ArrayLike, y: ArrayLike, heading: ArrayLike, length: ArrayLike, width: ArrayLike
) -> NDArray[np.float64]:
    """Corners ``(N, 4, 2)`` of oriented rectangles centred at ``(x, y)`` [m] with ``heading`` [rad].

    Order: front-left, front-right, rear-right, rear-left (counter-clockwise is not assumed).
    """
    x, y, h, ln, w = (np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (x, y, heading, length, width))
    c, s = np.cos(h), np.sin(h)
    lx = np.array([0.5, 0.5, -0.5, -0.5])[None, :] * ln[:, None]
    ly = np.array([0.5, -0.5, -0.5, 0.5])[None, :] * w[:, None]
    cx = x[:, None] + c[:, None] * lx - s[:, None] * ly
    cy = y[:, None] + s[:, None] * lx + c[:, None] * ly
    return np.stack([cx, cy], axis=-1)


def rectangle_segments(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """Edges ``(N * 4, 2, 2)`` of rectangles given by :func:`rectangle_corners`."""
    nxt = np.roll(corners, -1, axis=1)
    return np.stack([corners, nxt], axis=2).reshape(-1, 2, 2)


def closest_corner(
    corners: NDArray[np.float64], origin: ArrayLike = (0.0, 0.0)
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Closest corner of each rectangle to ``origin`` (the sensor), and its index 0..3.

    For a convex box seen from outside, the closest corner is always visible. ``corners`` is
    ``(N, 4, 2)`` in any frame; ``origin`` in the same frame. Returns ``(N, 2)`` and ``(N,)``.
    """
    d = np.linalg.norm(corners - np.asarray(origin, dtype=np.float64), axis=-1)
    i = np.argmin(d, axis=1)
    return corners[np.arange(corners.shape[0]), i], i


def angular_interval(
    corners: NDArray[np.float64], origin: ArrayLike = (0.0, 0.0)
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Angular extent ``(lo, hi)`` [rad] of each rectangle seen from ``origin``.

    Angles are relative to the bearing of the rectangle's centre, so intervals do not wrap;
    returns absolute bearings ``lo <= hi`` (``hi - lo < pi`` for a sensor outside the box).
    """
    rel = corners - np.asarray(origin, dtype=np.float64)
    centre = np.arctan2(rel[..., 1].mean(axis=1), rel[..., 0].mean(axis=1))
    a = wrap_angle(np.arctan2(rel[..., 1], rel[..., 0]) - centre[:, None])
    return centre + a.min(axis=1), centre + a.max(axis=1)


def occluded_fraction(
    corners: NDArray[np.float64],
    origin: ArrayLike = (0.0, 0.0),
    n_rays: int = 16,
    *,
    targets: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Fraction of each rectangle's angular extent hidden behind the other rectangles.

    ``n_rays`` rays spread over each rectangle's extent (seen from ``origin``) are cast against
    all rectangles' edges; a ray counts as occluded when the nearest edge it hits belongs to
    another box. The result is that of casting the rays with :func:`raycast`, which is what
    happens when a ray is within ``1e-12`` of parallel to an edge; otherwise a lean ray-vs-edge
    test (the same arithmetic, without incidence angles and collinear hits) gives the same bits.

    Args:
        corners: ``(N, 4, 2)`` rectangles from :func:`rectangle_corners` [m], any frame.
        origin: ``(2,)`` the sensor position in the same frame [m].
        n_rays: rays per rectangle.
        targets: indices of the rectangles whose fraction is wanted (all of them still occlude;
            negative indices count from the end); ``None`` = all.

    Returns:
        ``(N,)`` (or ``(len(targets),)``) hidden fractions in ``[0, 1]``, multiples of ``1 / n_rays``.
    """
    n = corners.shape[0]
    sel = np.arange(n) if targets is None else np.arange(n)[np.asarray(targets, dtype=np.int64).reshape(-1)]
    if n < 2 or len(sel) == 0:
        return np.zeros(len(sel))
    o = np.asarray(origin, dtype=np.float64)
    lo, hi = angular_interval(corners[sel], o)
    f = (np.arange(n_rays) + 0.5) / n_rays
    ang = lo[:, None] + (hi - lo)[:, None] * f[None, :]  # (T, R) ray directions [rad]
    found = _first_edge_hit(o, ang, corners)
    if found is not None:
        hit, first = found
    else:  # a ray (nearly) parallel to an edge: the full raycast handles collinear hits
        rng, _, first = raycast(np.broadcast_to(o, (len(sel), 2)), ang, rectangle_segments(corners))
        hit = np.isfinite(rng)
    hidden = hit & ((first >> 2) != sel[:, None])  # edge 4 i + k belongs to box i
    return np.count_nonzero(hidden, axis=1) / n_rays


def _first_edge_hit(
    origin: NDArray[np.float64], angles: NDArray[np.float64], corners: NDArray[np.float64]
) -> tuple[NDArray[np.bool_], NDArray[np.int64]] | None:
    """Which rays hit a rectangle edge, and the index ``4 * box + edge`` of the first edge each hits.

    The ray-vs-segment test of :func:`raycast` (the same operations, so the same bits) without
    incidence angles or collinear hits: returns ``None`` when a ray is within
    ``1e-12`` of parallel to an edge, where :func:`raycast`'s collinear rule may apply.

    Args:
        origin: ``(2,)`` ray origin [m].
        angles: ``(T, R)`` absolute ray directions [rad], in the frame of ``corners``.
        corners: ``(N, 4, 2)`` rectangles [m]; edge ``k`` of box ``i`` runs from corner ``k`` to
            corner ``k + 1 (mod 4)``.

    Returns:
        ``hit (T, R)`` and ``index (T, R)`` (meaningless where there is no hit), or ``None``.
    """
    a = corners.reshape(-1, 2)  # (M, 2) edge starts
    e = corners.take((1, 2, 3, 0), axis=1).reshape(-1, 2) - a
    wx, wy = a[:, 0] - origin[0], a[:, 1] - origin[1]
    dx, dy = np.cos(angles).reshape(-1, 1), np.sin(angles).reshape(-1, 1)  # (K, 1)
    ey_wy = np.stack([e[:, 1], wy])[:, None, :]  # (2, 1, M)
    ex_wx = np.stack([e[:, 0], wx])[:, None, :]
    # [cross(d, e), cross(d, w)] = [ey, wy] dx - [ex, wx] dy, (2, K, M); cross(d, w) = -cross(w, d)
    cross = ey_wy * dx - ex_wx * dy
    den = cross[0].copy()
    if not np.abs(den).min() > 1e-12:
        return None
    cross[0] = wx * e[:, 1] - wy * e[:, 0]  # cross(w, e)
    t, neg_u = cross / den  # distance along the ray [m], minus the position along the edge
    ok = (neg_u <= 0.0) & (neg_u >= -1.0) & (t > RAY_EPS)
    first = np.argmin(np.where(ok, t, np.inf), axis=1)
    return ok.any(axis=1).reshape(angles.shape), first.reshape(angles.shape)


def polar_frame(corner: NDArray) -> tuple[NDArray, NDArray]:
    """Unit vectors ``(n, 2)`` of the polar frame at ``corner`` [m]: radial, and OUTWARD cross-range.

    Outward points away from the boresight: to the left for corners left of it (azimuth >= 0), to the
    right otherwise (sensor frame, x forward, y left).
    """
    az = np.arctan2(corner[:, 1], corner[:, 0])
    side = np.where(az < 0, -1.0, 1.0)
    return np.stack([np.cos(az), np.sin(az)], axis=1), side[:, None] * np.stack([-np.sin(az), np.cos(az)], axis=1)


def to_polar_frame(vectors: NDArray, corner: NDArray) -> NDArray[np.float64]:
    """Sensor-frame vectors ``(n, 2)`` [m] as (radial, OUTWARD cross-range) components at ``corner (n, 2)``.

    The frame of :func:`polar_frame` (orthonormal, mirrored right of the boresight). NaN rows stay NaN.
    A positive cross-range component always points away from the boresight, so an offset toward the
    outer end of the face turned to the sensor shows alike on both sides (with a signed cross-range
    the two sides cancel when pooled).
    """
    u, v = polar_frame(corner)
    return np.stack([(vectors * u).sum(axis=1), (vectors * v).sum(axis=1)], axis=1)


def from_polar_frame(local: NDArray, corner: NDArray) -> NDArray[np.float64]:
    """Inverse of :func:`to_polar_frame`: (radial, outward) components ``(n, 2)`` [m] back to the sensor frame."""
    u, v = polar_frame(corner)
    return local[:, :1] * u + local[:, 1:] * v
