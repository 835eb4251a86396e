"""The seed's line-of-known-length detector and its development trajectory in precision-recall space.

Tallavajhula & Kelly (Sec. IV) validate their lidar simulator by the behaviour of an algorithm: a
detector of a board of known length is developed step by step (all false-positive checks off, raise
recall, then turn on checks to raise precision) on real scans, and the same fixed sequence of
parameter steps is replayed on scans simulated by the learned model and by a baseline. A good
simulator gives a precision-recall trajectory close to the real one.

The detector (one scan, sensor frame x forward / y left, metres):

1. **points**: readings that are neither null (0 / NaN) nor beyond ``max_range`` become points, in
   bearing order (circular: the sequence starts after the widest gap between consecutive points);
   optional **median filter** (``median_window`` readings) of their ranges;
2. **grow** a line from every seed point ``i``: add the next points while the chord from the seed
   stays within ``length + length_tol`` and, with the gap check on, while consecutive points are
   at most ``gap_tol`` apart; the line is ``i..j`` at the last point added;
3. **length check**: the chord ``|p_j - p_i|`` is at least ``length - length_tol``;
4. false-positive checks (each off at its default): **gap check** (``gap_tol``: no internal gap above
   it, and the points just outside the line are more than ``gap_tol`` off its infinite line, so the
   line is a whole object and not a piece of a longer wall, even where nulls cut the wall), **line
   fit** (``max_rms_dist``: root mean square distance of the points to their total-least-squares
   line), **min points** (``min_points``);
5. accepted lines are taken greedily in bearing order, without overlap.

Scoring: a target board is *present* in a scan when the nominal raycast from the log's pose hits it
over at least ``present_fraction`` of its length; a detection is a true positive when its mid-point
(mapped with the log's pose) is within ``match_dist`` of a present target's mid-point and its
direction within ``match_angle``; each target counts once; detections matching a target that is
not present count neither way; every other detection is a false positive.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import median_filter

from sensor_envs.evaluate.metrics import precision_recall
from sensor_envs.geometry import as_segments, from_frame, raycast_pose
from sensor_envs.inputs import InputError

__all__ = [
    "DetectorParams",
    "detect_lines",
    "TRAJECTORY_STEPS",
    "trajectory_params",
    "present_targets",
    "score_scans",
    "run_trajectory",
    "target_indices",
    "flatten_repeats",
    "steps_table",
]

_MAX_SPAN = 256  # at most this many points are grown from one seed


@dataclass(frozen=True)
class DetectorParams:
    """Parameters of the line detector (see the module docstring); ``inf``/``0``/``1`` switch a check off.

    Attributes:
        length: known length of the target [m].
        length_tol: accepted chord lengths ``length +- length_tol`` [m].
        gap_tol: gap check [m] (``inf`` = off).
        max_rms_dist: line-fit check, RMS point-to-line distance [m] (``inf`` = off).
        min_points: minimum points per line (``0`` = off).
        median_window: median filter over this many consecutive points' ranges (``1`` = off).
        max_range: readings beyond this are dropped [m] (the sensor's range; drops spurious far returns).
    """

    length: float = 0.61
    length_tol: float = 0.05
    gap_tol: float = np.inf
    max_rms_dist: float = np.inf
    min_points: int = 0
    median_window: int = 1
    max_range: float = 5.0

    def __post_init__(self) -> None:
        """Check the values (``ValueError`` naming the field)."""
        for name in ("length", "length_tol", "gap_tol", "max_rms_dist", "max_range"):
            v = float(getattr(self, name))
            if not v > 0 or np.isnan(v):
                raise InputError(f"detector: {name} must be > 0, got {v}")
        if self.min_points < 0:
            raise InputError(f"detector: min_points must be >= 0, got {self.min_points}")
        if self.median_window < 1 or self.median_window % 2 == 0:
            raise InputError(f"detector: median_window must be an odd number >= 1, got {self.median_window}")


def _points(ranges: NDArray[np.float64], bearings: NDArray[np.float64], p: DetectorParams) -> NDArray[np.float64]:
    """``(n, 2)`` sensor-frame points of the valid readings, in bearing order (median-filtered ranges)."""
    ok = np.isfinite(ranges) & (ranges > 0) & (ranges <= p.max_range)
    r, b = ranges[ok], bearings[ok]
    if p.median_window > 1 and r.size:
        r = median_filter(r, size=p.median_window, mode="wrap")
    pts = np.column_stack([r * np.cos(b), r * np.sin(b)])
    if len(pts) > 2:  # the scan is circular: start it after its widest gap, so no line is cut at bearing 0
        gap = np.hypot(*(np.roll(pts, -1, axis=0) - pts).T)
        pts = np.roll(pts, -(int(np.argmax(gap)) + 1), axis=0)
    return pts


def detect_lines(ranges: ArrayLike, bearings: ArrayLike, params: DetectorParams) -> NDArray[np.float64]:
    """Detect lines of length ``params.length`` in one scan.

    Args:
        ranges: ``(K,)`` readings [m]; ``0`` or ``NaN`` = null.
        bearings: ``(K,)`` bearings [rad], counter-clockwise from the sensor x axis.
        params: the detector's parameters.

    Returns:
        ``(n, 2, 2)`` detected lines (first and last point) in the sensor frame [m].
    """
    pts = _points(np.asarray(ranges, dtype=np.float64), np.asarray(bearings, dtype=np.float64), params)
    n = len(pts)
    if n < 2:
        return np.zeros((0, 2, 2))
    first_stop, c = _grow(pts, np.arange(n), min(n - 1, 48), params)
    todo = first_stop >= min(n - 1, 48)  # rows that grew to the first window's end: grow them further
    if todo.any() and n - 1 > 48:
        first_stop[todo], c[todo] = _grow(pts, np.flatnonzero(todo), min(n - 1, _MAX_SPAN), params)
    ok = first_stop >= 1
    i = np.arange(n)
    m = np.maximum(first_stop, 1)
    j = i + m
    ok &= c >= params.length - params.length_tol
    ok &= (m + 1) >= params.min_points
    if np.isfinite(params.gap_tol):
        jj = np.minimum(j, n - 1)
        ok &= _off_line(pts, i, jj, i - 1) > params.gap_tol
        ok &= _off_line(pts, i, jj, jj + 1) > params.gap_tol
    if np.isfinite(params.max_rms_dist):
        ok &= _rms_line_distance(pts, i, np.minimum(j, n - 1)) <= params.max_rms_dist
    out, last = [], -1
    for a in np.flatnonzero(ok):  # accepted lines only (few per scan)
        if a > last:
            out.append([pts[a], pts[j[a]]])
            last = int(j[a])
    return np.asarray(out, dtype=np.float64).reshape(-1, 2, 2)


def _grow(
    pts: NDArray[np.float64], rows: NDArray[np.int64], span: int, params: DetectorParams
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Grow lines from seeds ``rows`` over at most ``span`` points: points added and the chord [m] of each."""
    pad = np.concatenate([pts, np.full((span, 2), np.nan)])
    idx = rows[:, None] + np.arange(span + 1)[None]
    win = pad[idx]  # (n_rows, span + 1, 2)
    chord = np.hypot(*(win[:, 1:] - win[:, :1]).transpose(2, 0, 1))  # (n_rows, span)
    stop = ~(chord <= params.length + params.length_tol)  # NaN (past the scan's end) stops too
    if np.isfinite(params.gap_tol):
        step = np.hypot(*np.diff(win, axis=1).transpose(2, 0, 1))  # spacing of consecutive points
        stop |= np.maximum.accumulate(np.nan_to_num(step, nan=np.inf), axis=1) > params.gap_tol
    first = np.where(stop.any(axis=1), stop.argmax(axis=1), span)
    c = chord[np.arange(len(rows)), np.maximum(first, 1) - 1] if span else np.zeros(len(rows))
    return first, c


def _off_line(pts: NDArray[np.float64], i: NDArray[np.int64], j: NDArray[np.int64], k: NDArray[np.int64]) -> NDArray:
    """Distance [m] of point ``k`` to the infinite line through points ``i`` and ``j`` (``inf`` past the ends)."""
    n = len(pts)
    kk = np.clip(k, 0, n - 1)
    d = pts[j] - pts[i]
    v = pts[kk] - pts[i]
    with np.errstate(invalid="ignore", divide="ignore"):
        dist = np.abs(d[:, 0] * v[:, 1] - d[:, 1] * v[:, 0]) / np.hypot(d[:, 0], d[:, 1])
    return np.where((k < 0) | (k >= n), np.inf, np.nan_to_num(dist, nan=np.inf))


def _rms_line_distance(pts: NDArray[np.float64], i: NDArray[np.int64], j: NDArray[np.int64]) -> NDArray[np.float64]:
    """RMS distance [m] of points ``i..j`` (inclusive) to their total-least-squares line, per pair."""
    q = pts - pts.mean(axis=0)
    cs = np.vstack([np.zeros(5), np.cumsum(np.column_stack([q, q[:, 0] ** 2, q[:, 1] ** 2, q[:, 0] * q[:, 1]]), 0)])
    s = cs[j + 1] - cs[i]
    n = (j - i + 1).astype(float)
    mx, my = s[:, 0] / n, s[:, 1] / n
    a, cc, b = s[:, 2] / n - mx**2, s[:, 3] / n - my**2, s[:, 4] / n - mx * my
    lam = (a + cc) / 2 - np.sqrt(((a - cc) / 2) ** 2 + b**2)
    return np.sqrt(np.maximum(lam, 0.0))


# ------------------------------------------------------------------------------------------ trajectory
TRAJECTORY_STEPS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("all false-positive checks off, length tolerance 2 cm", {"length_tol": 0.02}),
    ("recall: length tolerance 5 cm", {"length_tol": 0.05}),
    ("recall: length tolerance 10 cm", {"length_tol": 0.10}),
    ("recall: length tolerance 15 cm", {"length_tol": 0.15}),
    ("precision: gap check 10 cm", {"gap_tol": 0.10}),
    ("precision: line fit RMS <= 3 cm", {"max_rms_dist": 0.03}),
    ("precision: at least 6 points", {"min_points": 6}),
    ("precision: median filter over 3 points", {"median_window": 3}),
    ("precision: line fit RMS <= 1.5 cm", {"max_rms_dist": 0.015}),
)
"""The fixed development sequence: each step changes the previous step's parameters (cumulative)."""


def trajectory_params(length: float, max_range: float = 5.0) -> list[DetectorParams]:
    """The detector parameters of every step of :data:`TRAJECTORY_STEPS` for a target of ``length`` [m]."""
    p = DetectorParams(length=length, max_range=max_range)
    out = []
    for _, change in TRAJECTORY_STEPS:
        p = replace(p, **change)
        out.append(p)
    return out


# ------------------------------------------------------------------------------------------- scoring
def target_indices(map_segments: ArrayLike, length: float, tol: float = 0.01) -> NDArray[np.int64]:
    """Indices of the map segments whose length is ``length +- tol`` [m] (the targets)."""
    s = as_segments(map_segments, name="map")
    return np.flatnonzero(np.abs(np.linalg.norm(s[:, 1] - s[:, 0], axis=1) - length) <= tol)


def present_targets(
    poses: ArrayLike,
    bearings: ArrayLike,
    map_segments: ArrayLike,
    targets: ArrayLike,
    max_range: float = 5.0,
    present_fraction: float = 0.75,
) -> NDArray[np.bool_]:
    """``(S, T)`` whether each target segment is seen over ``present_fraction`` of its length from each pose.

    Uses the nominal raycast (map and poses as given): the extent, along the segment, of the hits of
    the rays whose first hit is the segment.
    """
    segs = as_segments(map_segments, name="map")
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    b = np.asarray(bearings, dtype=np.float64)
    r, _, idx = raycast_pose(p, b, segs, max_range)
    out = np.zeros((len(p), len(np.atleast_1d(targets))), dtype=bool)
    ang = p[:, 2:3] + b[None]
    hx, hy = p[:, :1] + r * np.cos(ang), p[:, 1:2] + r * np.sin(ang)
    for k, t in enumerate(np.atleast_1d(np.asarray(targets, dtype=int))):  # few targets per map
        a, e = segs[t]
        d = e - a
        L = float(np.linalg.norm(d))
        proj = np.where(idx == t, ((hx - a[0]) * d[0] + (hy - a[1]) * d[1]) / L, np.nan)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            extent = np.nanmax(proj, axis=1) - np.nanmin(proj, axis=1)
        out[:, k] = np.nan_to_num(extent, nan=0.0) >= present_fraction * L
    return out


def score_scans(
    scans: ArrayLike,
    bearings: ArrayLike,
    poses: ArrayLike,
    map_segments: ArrayLike,
    params: DetectorParams,
    present: NDArray[np.bool_],
    targets: ArrayLike,
    match_dist: float = 0.15,
    match_angle: float = np.deg2rad(20.0),
) -> dict[str, int]:
    """Run the detector on scans and count true/false positives and misses.

    Args:
        scans: ``(S, K)`` readings [m] (``0``/``NaN`` = null).
        bearings: ``(K,)`` [rad].
        poses: ``(S, 3)`` poses the detections are mapped with [m, rad].
        map_segments: ``(M, 2, 2)`` map [m].
        params: detector parameters.
        present: ``(S, T)`` from :func:`present_targets`.
        targets: ``(T,)`` target segment indices.
        match_dist: mid-point distance of a match [m].
        match_angle: direction difference of a match [rad].

    Returns:
        ``{"tp", "fp", "fn", "detections", "scans"}``.
    """
    segs = as_segments(map_segments, name="map")
    x = np.asarray(scans, dtype=np.float64)
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    tg = segs[np.atleast_1d(np.asarray(targets, dtype=int))]
    t_mid, t_dir = tg.mean(axis=1), np.arctan2(*(tg[:, 1] - tg[:, 0])[:, ::-1].T)
    tp = fp = n_det = 0
    for s in range(x.shape[0]):  # one detector run per scan
        lines = detect_lines(x[s], bearings, params)
        n_det += len(lines)
        if not len(lines):
            continue
        w = from_frame(lines.reshape(-1, 2), p[s]).reshape(-1, 2, 2)
        mid, d = w.mean(axis=1), w[:, 1] - w[:, 0]
        ang = np.arctan2(d[:, 1], d[:, 0])
        dist = np.linalg.norm(mid[:, None] - t_mid[None], axis=2)
        dang = np.abs((ang[:, None] - t_dir[None] + np.pi / 2) % np.pi - np.pi / 2)
        match = (dist <= match_dist) & (dang <= match_angle)
        found = np.zeros(len(tg), dtype=bool)
        for k in range(len(lines)):  # few detections per scan
            hit = np.flatnonzero(match[k])
            if not hit.size:
                fp += 1
                continue
            t = hit[np.argmin(dist[k, hit])]
            if not present[s, t]:
                continue
            if found[t]:
                fp += 1
            else:
                found[t] = True
                tp += 1
    n_present = int(present.sum())
    return {"tp": tp, "fp": fp, "fn": n_present - tp, "detections": n_det, "scans": int(x.shape[0])}


def run_trajectory(
    scans: ArrayLike,
    bearings: ArrayLike,
    poses: ArrayLike,
    map_segments: ArrayLike,
    length: float,
    *,
    max_range: float = 5.0,
    present: NDArray[np.bool_] | None = None,
    targets: ArrayLike | None = None,
    progress: Callable[[], None] | None = None,
) -> list[dict[str, Any]]:
    """The detector's trajectory over :data:`TRAJECTORY_STEPS` on ``(S, K)`` scans at ``(S, 3)`` poses.

    Returns:
        One ``{"step", "name", "precision", "recall", "tp", "fp", "fn"}`` per step.
    """
    segs = as_segments(map_segments, name="map")
    tg = target_indices(segs, length) if targets is None else np.atleast_1d(np.asarray(targets, dtype=int))
    if not tg.size:
        raise InputError(f"map: no segment of the target length {length} m")
    if present is None:
        present = present_targets(poses, bearings, segs, tg, max_range)
    out = []
    for k, ((name, _), prm) in enumerate(zip(TRAJECTORY_STEPS, trajectory_params(length, max_range), strict=True)):
        c = score_scans(scans, bearings, poses, segs, prm, present, tg)
        pr, rc = precision_recall(c["tp"], c["fp"], c["fn"])
        out.append({"step": k, "name": name, "precision": round(pr, 4), "recall": round(rc, 4), **c})
        if progress is not None:
            progress()
    return out


def steps_table() -> list[dict[str, Any]]:
    """The steps with their full parameters (for reports)."""
    return [
        {"step": k, "name": name, "params": {kk: (None if v == np.inf else v) for kk, v in asdict(p).items()}}
        for k, ((name, _), p) in enumerate(zip(TRAJECTORY_STEPS, trajectory_params(0.61), strict=True))
    ]


def flatten_repeats(ranges: NDArray[np.float64], poses: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """``(P, K, R)`` readings and ``(P, 3)`` poses -> ``(P * R, K)`` scans and their ``(P * R, 3)`` poses."""
    P, K, R = ranges.shape
    return ranges.transpose(0, 2, 1).reshape(P * R, K), np.repeat(poses, R, axis=0)


def sequence_names(trajs: dict[str, Sequence[dict[str, Any]]]) -> list[str]:
    """Names of the trajectories in a stable order (real first)."""
    return sorted(trajs, key=lambda k: (k != "real", k != "reference", k))
