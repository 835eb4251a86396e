"""Clutter at object level: what an object-list radar reports per cycle, measured on Astyx HiRes2019.

The radar models are fitted at OBJECT level (one detection per target box), but the clutter of the
calibrated rig (and so of the KDE and Gaussian radars fitted on it) counts every Astyx cluster outside
the boxes, each DBSCAN noise point as a cluster of its own (~94 per frame): a point-level figure. This
module measures the object-level counterpart on the same frames and ships it as a small law the highway
wrapper thins the model's clutter to (``clutter="objects"``):

1. **sensor velocity per frame** from the Doppler of the whole point cloud: the stationary world gives
   ``v_r = -(v_x cos az + v_y sin az)`` for the sensor's velocity ``(v_x, v_y)``; Astyx's ``V_r`` is
   ambiguous (it wraps every :func:`doppler_period` m/s), so the fit maximises the number of points whose
   WRAPPED residual is within ``speed_tol`` (a grid search, :func:`sensor_velocity`);
2. **clutter objects**: the points outside every annotated box (any class, enlarged by ``margin``) are
   clustered with scikit-learn ``DBSCAN(eps, min_samples)``; a cluster of at least ``min_points``
   detections is one clutter object (DBSCAN noise points are dropped: a single detection does not make
   an object); its position is its detection nearest to the sensor;
3. **stationary vs moving**: an object is stationary when the median of its points' wrapped Doppler
   residuals is within ``speed_tol`` of the ego-motion prediction (what radar object lists flag as
   stationary; with aliasing, an object moving by a multiple of the period looks stationary too).

The law (:class:`ObjectClutterLaw`) holds, per range bin of the nearest detection, the mean number of
stationary and moving clutter objects per cycle and the signed residual radial speeds [m/s] of the moving
ones (quantiles). Frames: radar frame, x forward, y left [m]; speeds [m/s].
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sklearn.cluster import DBSCAN
from tqdm import tqdm

from sensor_envs.inputs import InputError, parse_json, read_text
from sensor_envs.modelio import default_model_path

__all__ = [
    "RANGE_EDGES",
    "OBJECT_CLUTTER_FILE",
    "ObjectClutterLaw",
    "doppler_period",
    "sensor_velocity",
    "frame_clutter_objects",
    "measure_object_clutter",
    "object_clutter_document",
    "load_object_clutter",
]

RANGE_EDGES = (0.0, 15.0, 30.0, 50.0, 75.0, 100.0, 150.0)
"""Range bins [m] of the law (those of the rig's clutter range shares)."""
OBJECT_CLUTTER_FILE = "radar_object_clutter.json"
"""File name in ``models/`` of the shipped law (written by ``benchmarks/real_astyx_object_clutter.py``
through :func:`object_clutter_document`)."""
FORMAT_VERSION = 1
N_QUANTILES = 21
_VX_GRID_STEP, _VY_GRID = 0.05, np.arange(-1.0, 1.0001, 0.1)


@dataclass(frozen=True)
class ObjectClutterLaw:
    """Object-level clutter per radar cycle, per range bin (see the module docstring).

    Attributes:
        range_edges: ``(b + 1,)`` increasing range bin edges [m].
        stationary: ``(b,)`` mean stationary clutter objects per cycle in each bin.
        moving: ``(b,)`` mean moving clutter objects per cycle in each bin.
        moving_speed_quantiles: ``(q,)`` increasing quantiles (evenly spaced probabilities 0..1) of the
            moving objects' signed residual radial speed [m/s] (positive: receding faster than the world).
        speed_tol: the stationary threshold the law was measured with [m/s].
    """

    range_edges: NDArray[np.float64]
    stationary: NDArray[np.float64]
    moving: NDArray[np.float64]
    moving_speed_quantiles: NDArray[np.float64]
    speed_tol: float

    def __post_init__(self) -> None:
        """Check shapes and values (``ValueError`` naming the field)."""
        e = np.asarray(self.range_edges, dtype=np.float64)
        if e.ndim != 1 or e.size < 2 or not np.all(np.isfinite(e)) or np.any(np.diff(e) <= 0) or e[0] < 0:
            raise InputError(f"range_edges: expected >= 2 increasing finite ranges >= 0 [m], got {self.range_edges!r}")
        for name in ("stationary", "moving"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (e.size - 1,) or not np.all(np.isfinite(v)) or np.any(v < 0):
                raise InputError(f"{name}: expected {e.size - 1} finite counts >= 0, got {getattr(self, name)!r}")
        q = np.asarray(self.moving_speed_quantiles, dtype=np.float64)
        if q.ndim != 1 or q.size < 2 or not np.all(np.isfinite(q)) or np.any(np.diff(q) < 0):
            raise InputError("moving_speed_quantiles: expected >= 2 finite non-decreasing speeds [m/s]")
        if not (np.isfinite(self.speed_tol) and self.speed_tol > 0):
            raise InputError(f"speed_tol: expected a positive speed [m/s], got {self.speed_tol!r}")

    @property
    def total(self) -> NDArray[np.float64]:
        """``(b,)`` clutter objects per cycle in each range bin, stationary and moving."""
        return np.asarray(self.stationary, dtype=np.float64) + np.asarray(self.moving, dtype=np.float64)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (lists of floats)."""
        return {
            "range_edges": [float(v) for v in self.range_edges],
            "stationary": [float(v) for v in self.stationary],
            "moving": [float(v) for v in self.moving],
            "moving_speed_quantiles": [float(v) for v in self.moving_speed_quantiles],
            "speed_tol": float(self.speed_tol),
        }


def doppler_period(v_r: NDArray[np.float64]) -> float:
    """Unambiguous Doppler interval [m/s] of a quantised radial-speed column (levels x resolution).

    Returns ``inf`` when fewer than two distinct values exist (nothing to infer: no wrapping assumed).
    """
    levels = np.unique(np.round(np.asarray(v_r, dtype=np.float64), 6))
    if levels.size < 2:
        return float("inf")
    step = float(np.min(np.diff(levels)))
    return float((round((levels[-1] - levels[0]) / step) + 1) * step)


def _wrap(v: NDArray[np.float64], period: float) -> NDArray[np.float64]:
    """``v`` wrapped into ``[-period / 2, period / 2)`` (unchanged when ``period`` is infinite)."""
    if not np.isfinite(period):
        return v
    return np.asarray((v + period / 2) % period - period / 2, dtype=np.float64)


def sensor_velocity(
    xyz: NDArray[np.float64], v_r: NDArray[np.float64], period: float, speed_tol: float = 0.25
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The sensor's velocity ``(v_x, v_y)`` [m/s] that most points call stationary, and every point's residual.

    Grid search: ``v_x`` over one Doppler period (or 0..40 m/s when unambiguous) in 0.05 m/s steps,
    ``v_y`` over -1..1 m/s; the residual is ``wrap(v_r + v . u_xy)`` with ``u`` the unit line of sight.

    Args:
        xyz: ``(m, 3)`` detections [m], radar frame.
        v_r: ``(m,)`` measured radial speeds [m/s].
        period: the Doppler period [m/s] (``inf``: no wrapping).
        speed_tol: a point within this residual [m/s] counts as stationary in the search.
    """
    if len(xyz) == 0:
        return np.zeros(2), np.zeros(0)
    u = xyz[:, :2] / np.maximum(np.linalg.norm(xyz, axis=1, keepdims=True), 1e-9)
    vx_grid = np.arange(0.0, period if np.isfinite(period) else 40.0, _VX_GRID_STEP)
    best, best_n = np.zeros(2), -1
    for vy in _VY_GRID:  # 21 lateral speeds, vectorised over v_x and points
        res = _wrap(v_r[None, :] + vx_grid[:, None] * u[None, :, 0] + vy * u[None, :, 1], period)
        n = (np.abs(res) <= speed_tol).sum(axis=1)
        k = int(np.argmax(n))
        if n[k] > best_n:
            best, best_n = np.array([vx_grid[k], vy]), int(n[k])
    return best, _wrap(v_r + u @ best, period)


def frame_clutter_objects(
    pts: NDArray[np.float64],
    outside: NDArray[np.bool_],
    residual: NDArray[np.float64],
    *,
    eps: float = 1.5,
    min_samples: int = 2,
    min_points: int = 2,
    speed_tol: float = 0.5,
) -> NDArray[np.float64]:
    """Clutter objects of one frame: ``(c, 4)`` range [m], azimuth [rad], moving (0/1), median residual [m/s].

    Args:
        pts: ``(m, >=2)`` detections, x and y first [m].
        outside: ``(m,)`` points outside every annotated box.
        residual: ``(m,)`` wrapped Doppler residuals [m/s] (:func:`sensor_velocity`).
        eps: DBSCAN radius [m] (ground plane).
        min_samples: DBSCAN core-point neighbourhood size.
        min_points: smallest cluster that is an object.
        speed_tol: an object whose median residual exceeds this [m/s] is moving.
    """
    xy = pts[outside, :2]
    if len(xy) == 0:
        return np.zeros((0, 4))
    labels = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(xy)
    res, r = residual[outside], np.hypot(xy[:, 0], xy[:, 1])
    rows = []
    for c in np.unique(labels[labels >= 0]):  # one iteration per cluster (tens per frame)
        sel = labels == c
        if sel.sum() < min_points:
            continue
        k = np.flatnonzero(sel)[np.argmin(r[sel])]
        med = float(np.median(res[sel]))
        rows.append([r[k], np.arctan2(xy[k, 1], xy[k, 0]), float(abs(med) > speed_tol), med])
    return np.asarray(rows, dtype=np.float64).reshape(-1, 4)


def measure_object_clutter(
    root: str | os.PathLike[str],
    *,
    frames: Sequence[int] | None = None,
    eps: float = 1.5,
    min_points: int = 2,
    margin: float = 0.5,
    speed_tol: float = 0.5,
    progress: bool = False,
) -> dict[str, Any]:
    """Measure object- and point-level clutter per cycle on Astyx HiRes2019 (see the module docstring).

    Args:
        root: the ``astyx_hires2019`` folder.
        frames: frame indices (default: every ``radar_6455/*.txt``).
        eps: DBSCAN radius [m].
        min_points: smallest cluster counted as a clutter object.
        margin: box enlargement [m] on every side (points inside any box are not clutter).
        speed_tol: stationary threshold [m/s] on the Doppler residual.
        progress: show a tqdm bar.

    Returns:
        Plain JSON values: ``law`` (:meth:`ObjectClutterLaw.to_dict`), per-bin point-level clusters
        (``point_level``: every cluster and noise point outside the boxes), the Doppler period, the
        frames' sensor speeds and per-frame counts.

    Raises:
        FileNotFoundError: when ``root`` lacks ``radar_6455``.
    """
    from sensor_envs.radar.astyx import _points_in_boxes, read_frame

    root = Path(root)
    if not (root / "radar_6455").is_dir():
        raise FileNotFoundError(f"{root}: no 'radar_6455' folder (expected the Astyx HiRes2019 layout)")
    if frames is None:
        frames = sorted(int(p.stem) for p in (root / "radar_6455").glob("*.txt") if p.stem.isdigit())
    raw = [read_frame(root, f) for f in tqdm(frames, disable=not progress, desc="astyx read")]
    period = doppler_period(np.concatenate([p[:, 3] for p, _, _ in raw])) if raw else float("inf")
    edges = np.asarray(RANGE_EDGES)
    nb = edges.size - 1
    stat, mov, pts_lvl = np.zeros((len(raw), nb)), np.zeros((len(raw), nb)), np.zeros((len(raw), nb))
    speeds, moving_res, explained = [], [], []
    for i, (pts, boxes, _) in enumerate(tqdm(raw, disable=not progress, desc="astyx clutter")):
        v, res = sensor_velocity(pts[:, :3], pts[:, 3], period)
        speeds.append(float(np.hypot(*v)))
        explained.append(float(np.mean(np.abs(res) <= speed_tol)) if len(res) else 1.0)
        outside = np.asarray(~_points_in_boxes(pts[:, :2], boxes, margin).any(axis=1), dtype=bool)
        obj = frame_clutter_objects(pts, outside, res, eps=eps, min_points=min_points, speed_tol=speed_tol)
        b = np.clip(np.searchsorted(edges, obj[:, 0], side="right") - 1, 0, nb - 1)
        stat[i] = np.bincount(b[obj[:, 2] == 0], minlength=nb)
        mov[i] = np.bincount(b[obj[:, 2] == 1], minlength=nb)
        moving_res.append(obj[obj[:, 2] == 1, 3])
        pts_lvl[i] = _point_level_counts(pts[outside, :2], eps, edges)
    mres = np.concatenate(moving_res) if moving_res else np.zeros(0)
    quant = np.quantile(mres, np.linspace(0, 1, N_QUANTILES)) if mres.size else np.array([-speed_tol, speed_tol])
    law = ObjectClutterLaw(edges, stat.mean(axis=0), mov.mean(axis=0), quant, speed_tol)
    return {
        "law": law.to_dict(),
        "point_level": [float(v) for v in pts_lvl.mean(axis=0)],
        "per_frame": {
            "stationary": [float(v) for v in stat.sum(axis=1)],
            "moving": [float(v) for v in mov.sum(axis=1)],
            "point_level": [float(v) for v in pts_lvl.sum(axis=1)],
        },
        "doppler_period": period,
        "sensor_speed": {"median": float(np.median(speeds)), "share_below_1": float(np.mean(np.array(speeds) < 1))},
        # share of a frame's points the ego-motion fit calls stationary (a clean fit explains most of them)
        "stationary_fit_share": {"median": float(np.median(explained)), "q25": float(np.quantile(explained, 0.25))},
        "frames": len(raw),
        "params": {"eps": eps, "min_points": min_points, "margin": margin, "speed_tol": speed_tol},
    }


def _point_level_counts(xy: NDArray[np.float64], eps: float, edges: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per range bin: clusters outside the boxes with every DBSCAN noise point its own cluster (the rig's count)."""
    if len(xy) == 0:
        return np.zeros(edges.size - 1)
    labels = DBSCAN(eps=eps, min_samples=2).fit_predict(xy)
    r = np.hypot(xy[:, 0], xy[:, 1])
    near = [r[labels == c].min() for c in np.unique(labels[labels >= 0])]
    every = np.concatenate([np.asarray(near), r[labels < 0]])
    b = np.clip(np.searchsorted(edges, every, side="right") - 1, 0, edges.size - 2)
    return np.bincount(b, minlength=edges.size - 1).astype(np.float64)


def object_clutter_document(run: dict[str, Any], data: str, command: str, note: str = "") -> dict[str, Any]:
    """The law file's content (what :func:`load_object_clutter` reads) from a :func:`measure_object_clutter` run.

    Args:
        run: the measurement (its ``law``, ``frames``, ``params`` and ``point_level`` are kept).
        data: the data set's name.
        command: the command that measured it.
        note: a caveat for the card (left out when empty).
    """
    card = {
        "data": data,
        "frames": run["frames"],
        "command": command,
        "params": run["params"],
        "point_level": run["point_level"],
    }
    if note:
        card["note"] = note
    return {"format_version": FORMAT_VERSION, "kind": "radar_object_clutter", "law": run["law"], "card": card}


def load_object_clutter(path: str | os.PathLike[str] | None = None) -> ObjectClutterLaw:
    """Load an object-clutter law file (``None``: the shipped ``models/radar_object_clutter.json``).

    Raises:
        ValueError: naming the file and the field when the file is malformed or of another format version.
    """
    p = Path(path) if path is not None else default_model_path(OBJECT_CLUTTER_FILE)
    doc = parse_json(read_text(p, "object-clutter law", limit=1_000_000), str(p))  # bounded (sensor_envs.inputs)
    if not isinstance(doc, dict) or doc.get("format_version") != FORMAT_VERSION:
        raise InputError(f"{p}: field 'format_version': expected {FORMAT_VERSION}")
    law = doc.get("law")
    if not isinstance(law, dict):
        raise InputError(f"{p}: field 'law': expected an object")
    try:
        return ObjectClutterLaw(
            np.asarray(law["range_edges"], dtype=np.float64),
            np.asarray(law["stationary"], dtype=np.float64),
            np.asarray(law["moving"], dtype=np.float64),
            np.asarray(law["moving_speed_quantiles"], dtype=np.float64),
            float(law["speed_tol"]),
        )
    except KeyError as exc:
        raise InputError(f"{p}: field 'law.{exc.args[0]}' is missing") from None
    except (TypeError, ValueError) as exc:  # the law's own messages start with the field's name
        name, _, rest = str(exc).partition(": ")
        raise InputError(f"{p}: field 'law.{name}': {rest or exc}") from None
