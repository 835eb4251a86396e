"""Astyx HiRes2019 radar frames -> radar object log, plus detection-rate and clutter statistics.

Layout (``astyx_hires2019/``): ``radar_6455/NNNNNN.txt`` (line 1 empty, line 2 ``X Y Z V_r Mag``,
then one detection per row, radar frame x forward / y left / z up, metres) and
``groundtruth_obj3d/NNNNNN.json`` (reference boxes, ``center3d``, ``dimension3d`` [l, w, h],
``orientation_quat`` [w, x, y, z], ``classname``, ...).

Clutter rate: every cluster (DBSCAN noise points count as one-point clusters) that matches no
annotated box; this includes real but unannotated reflectors (guard rails, poles, parked objects),
so it is an upper bound of false detections. Clutter rows carry ``n_points`` (cluster size).

Per frame:

1. **cluster** the detections in the ground plane (x, y) with scikit-learn ``DBSCAN``
   (``eps`` [m], ``min_samples``); DBSCAN noise points are single detections, each its own cluster;
2. **associate** each cluster with the reference box (any class) that contains most of its points,
   the box enlarged by ``margin`` [m] on every side; clusters without such a box are clutter;
   clusters of one box are merged (one object per target);
3. **object position** of a target's merged cluster: its detection nearest to the sensor
   (``position="nearest"``, the natural counterpart of the closest corner), or the
   magnitude-weighted mean (``position="centroid"``).

Targets are the boxes of ``classes`` (default cars); clusters on boxes of other classes are neither
targets nor clutter. Astyx frames are no time series: every target gets its own id (no ``z_{t-1}``),
``t`` is the frame index (no time stamps are given) and ``sequence`` is the block of ``block``
consecutive frames (used to split the data into train/test by blocks). Covariates: ``ref_z``,
``occlusion``, ``label_certainty``, ``n_points``, ``class_code`` (index into :data:`CLASS_CODES`) and
``aspect`` (box heading relative to the line of sight to its centre [rad],
:func:`sensor_envs.radar.features.aspect_angle`).
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import DBSCAN
from tqdm import tqdm

from sensor_envs.geometry import quaternion_yaw, to_frame
from sensor_envs.inputs import InputError, parse_json, read_text
from sensor_envs.radar.features import aspect_angle
from sensor_envs.radar.log import REQUIRED_COLUMNS, RadarLog

__all__ = ["CLASS_CODES", "read_frame", "frame_rows", "load_astyx", "detection_statistics"]

POINT_BOUNDS = {"X": 1000.0, "Y": 1000.0, "Z": 1000.0, "V_r": 1000.0, "Mag": 1e6}
"""Declared bounds of a point's columns: positions [m] and radial speed [m/s] within the radar's reach, magnitude."""
MAX_BOX_SIZE = 100.0
"""Largest length, width or height [m] of a labelled object."""
MAX_FRAME = 999_999_999
"""Largest frame index (nine digits: ``f * 1000 + box`` ids stay exact)."""
MAX_FRAMES = 100_000
"""Most frames in one folder (the HiRes2019 set has 546; every frame is two files read and checked)."""
CLASS_CODES = ("Car", "Truck", "Bus", "Person", "Trailer", "Other Vehicle", "Towed Object", "Cyclist")
"""``class_code`` covariate: index into this tuple (-1 for other names)."""


def _frame_name(stem: str) -> bool:
    """Whether ``stem`` is a frame name: the index written with at least 6 digits, as ``read_frame`` writes it.

    ``0.txt`` beside ``000000.txt`` would be frame 0 twice; ``0000001`` is no name ``read_frame`` opens.
    """
    return stem.isascii() and stem.isdigit() and len(stem) <= 9 and stem == f"{int(stem):06d}"


def read_frame(root: Path, index: int) -> tuple[NDArray[np.float64], NDArray[np.float64], list[str]]:
    """One frame: detections ``(m, 5)`` [x, y, z, v_r, mag], boxes ``(k, 8)`` and class names.

    Boxes: ``x, y, heading, length, width, z, occlusion, label_certainty`` (radar frame, m, rad).

    Raises:
        ValueError: naming the file and the field when a file is malformed.
    """
    if not 0 <= index <= MAX_FRAME:
        raise InputError(f"{root}: frame index {index} is outside [0, {MAX_FRAME}] (radar_6455/NNNNNN.txt)")
    name = f"{index:06d}"
    pc_path = root / "radar_6455" / f"{name}.txt"
    text = read_text(pc_path, "field 'X Y Z V_r Mag'")
    head = text.split("\n", 2)
    if len(head) < 2 or head[1].split() != list(POINT_BOUNDS):  # the columns are read by position
        got = head[1] if len(head) > 1 else ""
        raise InputError(f"{pc_path}: field 'header': line 2 must be 'X Y Z V_r Mag', got {got!r:.60}")
    try:
        with warnings.catch_warnings():  # a frame without detections is valid; loadtxt warns about it
            warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
            pts = np.loadtxt(io.StringIO(text), skiprows=2, ndmin=2)
    except ValueError as exc:
        raise InputError(f"{pc_path}: not a table of 5 numbers per row ({' '.join(str(exc).split())})") from None
    if pts.size and pts.shape[1] != 5:
        raise InputError(f"{pc_path}: expected 5 columns X Y Z V_r Mag, got {pts.shape[1]}")
    if not np.isfinite(pts).all():
        raise InputError(f"{pc_path}: field 'X Y Z V_r Mag' holds NaN or infinite values")
    for j, (column, bound) in enumerate(POINT_BOUNDS.items()):
        far = np.abs(pts[:, j]) > bound if pts.size else np.zeros(0, dtype=bool)
        if far.any():
            i = int(np.flatnonzero(far)[0])
            raise InputError(f"{pc_path}: column {column!r} row {i + 1} is {pts[i, j]:g}, beyond +-{bound:g}")
    gt_path = root / "groundtruth_obj3d" / f"{name}.json"
    try:
        doc = parse_json(read_text(gt_path, "not valid UTF-8 JSON"), f"{gt_path}: not valid UTF-8 JSON")
    except InputError as exc:
        msg = str(exc) if "UTF-8" in str(exc) else f"{gt_path}: not valid UTF-8 JSON ({exc})"
        raise InputError(msg) from None
    if isinstance(doc, dict) and "objects" not in doc:
        raise InputError(f"{gt_path}: field 'objects' is missing (an Astyx label file lists its objects there)")
    objs = doc.get("objects") if isinstance(doc, dict) else None
    if not isinstance(objs, list):
        raise InputError(f"{gt_path}: field 'objects' must be a list of objects, got {type(objs).__name__}")
    boxes, names = [], []
    for k, o in enumerate(objs):
        try:
            c, d = o["center3d"], o["dimension3d"]
            q = o["orientation_quat"]
            _numbers(c, d, q, o.get("occlusion", 0.0), o.get("label_certainty", 0.0))
            if not (isinstance(c, list) and len(c) == 3 and isinstance(d, list) and len(d) == 3):
                raise ValueError("'center3d' and 'dimension3d' must be lists of 3 numbers")
            if not (isinstance(q, list) and len(q) == 4 and abs(np.linalg.norm(q) - 1.0) < 0.1):
                raise ValueError(f"'orientation_quat' must be a unit quaternion [w, x, y, z], got {q!r:.60}")
            box = [
                float(c[0]),
                float(c[1]),
                quaternion_yaw(*[float(v) for v in o["orientation_quat"]]),
                float(d[0]),
                float(d[1]),
                float(c[2]),
                float(o.get("occlusion", np.nan)),
                float(o.get("label_certainty", np.nan)),
            ]
            names.append(str(o["classname"]))
        except (KeyError, IndexError) as exc:
            raise InputError(f"{gt_path}: object {k} lacks field {exc}") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{gt_path}: object {k}: a field is malformed ({exc})") from None
        if not (0 < box[3] <= MAX_BOX_SIZE and 0 < box[4] <= MAX_BOX_SIZE and 0 < float(d[2]) <= MAX_BOX_SIZE):
            raise InputError(f"{gt_path}: object {k}: field 'dimension3d' must be 3 sizes in (0, {MAX_BOX_SIZE:g}] m")
        if not (np.isfinite(box[:6]).all() and (np.abs(box[:2] + box[5:6]) <= 1000).all()):
            raise InputError(
                f"{gt_path}: object {k}: field 'center3d', 'dimension3d' or 'orientation_quat' is not finite "
                "(or 'center3d' lies beyond 1000 m)"
            )
        boxes.append(box)
    return pts.reshape(-1, 5), np.asarray(boxes, dtype=np.float64).reshape(-1, 8), names


def _numbers(*values: Any) -> None:
    """Refuse booleans, strings and nulls where a label holds numbers (``float(True)`` would be 1.0)."""
    for v in values:
        for x in v if isinstance(v, list) else [v]:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise TypeError(f"expected numbers, got {x!r:.40}")


def _points_in_boxes(xy: NDArray, boxes: NDArray, margin: float) -> NDArray[np.bool_]:
    """``(m, k)``: point ``i`` lies in box ``j`` enlarged by ``margin`` [m] (ground plane)."""
    inside = np.zeros((xy.shape[0], boxes.shape[0]), dtype=bool)
    for j, b in enumerate(boxes):  # one iteration per box (a handful per frame), vectorised over points
        p = to_frame(xy, b[:3])
        inside[:, j] = (np.abs(p[:, 0]) <= b[3] / 2 + margin) & (np.abs(p[:, 1]) <= b[4] / 2 + margin)
    return inside


def frame_rows(
    pts: NDArray,
    boxes: NDArray,
    names: list[str],
    *,
    eps: float = 1.5,
    min_samples: int = 2,
    margin: float = 0.5,
    classes: tuple[str, ...] = ("Car",),
    position: str = "nearest",
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Target rows and clutter positions of one frame.

    Returns:
        ``targets (k_t, 9)``: ``box x, y, heading, length, width, meas_x, meas_y, n_points, box index``
        per box of ``classes`` (``meas`` NaN when undetected); ``clutter (c, 3)``: position [m] of
        each clutter cluster (its detection nearest to the sensor) and its number of detections.
    """
    xy = pts[:, :2]
    labels = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(xy) if len(xy) else np.zeros(0, dtype=int)
    noise = labels < 0
    labels = labels.copy()
    labels[noise] = labels.max(initial=-1) + 1 + np.arange(noise.sum())
    n_cl = int(labels.max(initial=-1)) + 1
    inside = _points_in_boxes(xy, boxes, margin)
    votes = np.zeros((n_cl, boxes.shape[0] + 1))
    box_of = inside.argmax(axis=1) if boxes.shape[0] else np.zeros(len(xy), dtype=int)  # no boxes: all clutter
    np.add.at(votes, (labels, np.where(inside.any(axis=1), box_of, boxes.shape[0])), 1.0)
    owner = votes.argmax(axis=1)  # == boxes.shape[0]: no box -> clutter
    point_owner = owner[labels]
    r = np.hypot(xy[:, 0], xy[:, 1])
    is_target = np.array([n in classes for n in names], dtype=bool)
    rows = []
    for j in np.flatnonzero(is_target):  # one iteration per target box
        sel = point_owner == j
        meas = np.full(2, np.nan)
        if sel.any():
            if position == "nearest":
                meas = xy[sel][np.argmin(r[sel])]
            else:
                wgt = np.maximum(pts[sel, 4], 1e-9)
                meas = (xy[sel] * wgt[:, None]).sum(axis=0) / wgt.sum()
        rows.append([*boxes[j, :5], *meas, sel.sum(), j])
    cl = np.flatnonzero(owner == boxes.shape[0])
    size = np.bincount(labels, minlength=n_cl)
    cl_pos = np.array([xy[labels == c][np.argmin(r[labels == c])] for c in cl]).reshape(-1, 2)
    return np.asarray(rows, dtype=np.float64).reshape(-1, 9), np.concatenate([cl_pos, size[cl, None]], axis=1)


def load_astyx(
    root: str | os.PathLike[str],
    *,
    frames: Sequence[int] | None = None,
    block: int = 10,
    progress: bool = False,
    **cluster_args: Any,
) -> RadarLog:
    """Turn Astyx frames into a radar object log (see the module docstring).

    Args:
        root: the ``astyx_hires2019`` folder.
        frames: frame indices (default: every ``radar_6455/*.txt``).
        block: frames per ``sequence`` block.
        progress: show a tqdm bar.
        **cluster_args: ``eps``, ``min_samples``, ``margin``, ``classes``, ``position`` of :func:`frame_rows`.

    Raises:
        FileNotFoundError: when ``root`` lacks the ``radar_6455`` folder.

    Examples:
        >>> import os
        >>> from sensor_envs import load_astyx
        >>> root = os.path.join(os.environ.get("SENSOR_ENVS_REAL_DATA", "../shared/data/real"), "astyx_hires2019")
        >>> log = load_astyx(root, frames=range(10))  # doctest: +SKIP
        >>> int(log["frame"].max())  # doctest: +SKIP
        9
    """
    root = Path(root)
    if not (root / "radar_6455").is_dir():
        raise FileNotFoundError(f"{root}: no 'radar_6455' folder (expected the Astyx HiRes2019 layout)")
    if cluster_args.get("position", "nearest") not in ("nearest", "centroid"):
        raise InputError(f"position must be 'nearest' or 'centroid', got {cluster_args['position']!r}")
    if frames is None:
        files = []
        for f in (root / "radar_6455").glob("*.txt"):  # counted while listed: a folder of 10^7 files is refused
            files.append(f)
            if len(files) > MAX_FRAMES:
                raise InputError(f"{root / 'radar_6455'}: more than {MAX_FRAMES} frame files")
        files.sort()
        stray = [p for p in files if not _frame_name(p.stem)]
        if stray:
            raise InputError(f"{stray[0]}: not an Astyx frame file (expected radar_6455/NNNNNN.txt)")
        frames = [int(p.stem) for p in files]
    out = []
    for f in tqdm(frames, disable=not progress, desc="astyx"):
        pts, boxes, names = read_frame(root, f)
        tgt, clutter = frame_rows(pts, boxes, names, **cluster_args)
        box_idx = tgt[:, 8].astype(int)
        cov = np.stack(
            [
                boxes[box_idx, 5],
                boxes[box_idx, 6],
                boxes[box_idx, 7],
                tgt[:, 7],
                [CLASS_CODES.index(names[j]) if names[j] in CLASS_CODES else -1 for j in box_idx],
                aspect_angle(tgt[:, 0], tgt[:, 1], tgt[:, 2]),
            ],
            axis=1,
        ).reshape(-1, 6)
        ids = np.stack(
            [np.full(len(tgt), f // block), np.full(len(tgt), f), np.full(len(tgt), f), f * 1000 + box_idx], axis=1
        )
        t_rows = np.concatenate([ids, tgt[:, :7], cov], axis=1)
        c_rows = np.full((len(clutter), 17), np.nan)
        c_rows[:, :4] = [f // block, f, f, -1]
        c_rows[:, 9:11] = clutter[:, :2]
        c_rows[:, 14] = clutter[:, 2]
        out.append(np.concatenate([t_rows, c_rows]))
    data = np.concatenate(out) if out else np.zeros((0, 17))
    names_all = [*REQUIRED_COLUMNS, "ref_z", "occlusion", "label_certainty", "n_points", "class_code", "aspect"]
    return RadarLog({n: data[:, j] for j, n in enumerate(names_all)}, source=f"astyx {root}")


OUTCOME_COLUMNS = ("n_points",)
"""Columns this converter writes that are OUTCOMES of the measurement, not causes: ``n_points`` (radar
points inside the box) is 0 exactly when the target is missed. ``diagnose radar`` never offers them (nor
any column named ``outcome_*``) as candidate causes."""


def detection_statistics(log: RadarLog, range_edges: NDArray, azimuth_edges: NDArray) -> dict[str, Any]:
    """Share of target rows detected per range bin and per azimuth bin, and the clutter rate.

    Range [m] and azimuth [rad] are of the reference box centre. Returns plain Python values.
    """
    tgt = ~log.is_clutter
    r = np.hypot(log["ref_x"], log["ref_y"])[tgt]
    az = np.arctan2(log["ref_y"], log["ref_x"])[tgt]
    det = ~log.is_miss[tgt]

    def share(v: NDArray, edges: NDArray) -> list[dict[str, float]]:
        b = np.digitize(v, edges) - 1
        res = []
        for k in range(len(edges) - 1):  # one iteration per bin
            s = b == k
            res.append(
                {
                    "lo": float(edges[k]),
                    "hi": float(edges[k + 1]),
                    "n": int(s.sum()),
                    "detected_share": float(det[s].mean()) if s.any() else float("nan"),
                }
            )
        return res

    n_cycles = np.unique(np.stack([log["sequence"], log["frame"]], axis=1), axis=0).shape[0]
    res = {
        "n_targets": int(tgt.sum()),
        "detected_share": float(det.mean()),
        "by_range": share(r, np.asarray(range_edges)),
        "by_azimuth": share(az, np.asarray(azimuth_edges)),
        "n_cycles": int(n_cycles),
        "clutter_per_cycle": float(log.is_clutter.sum() / n_cycles),
    }
    if "n_points" in log.columns:
        multi = log.is_clutter & (log["n_points"] >= 2)
        res["clutter_per_cycle_min2_points"] = float(multi.sum() / n_cycles)
    return res
