"""Extra state variables of the radar models: names, derived features and lookup in a log.

Both radar models (:class:`~sensor_envs.radar.kde.KDERadarModel`, :class:`~sensor_envs.radar.gaussian.GaussianRadar`)
can take extra state variables (``extra_state``): names of numeric columns of the radar log (any
covariate column, e.g. ``rel_vx``, ``occlusion``, or a derived feature added with
:func:`with_derived_columns`). A world that runs a model must supply every variable the model names;
:data:`WORLD_VARIABLES` lists the ones the highway wrapper supplies.

Frames and units: sensor frame (x forward, y left), metres, radians, m/s.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from sensor_envs.geometry import occluded_fraction, rectangle_corners, wrap_angle
from sensor_envs.inputs import InputError
from sensor_envs.radar.log import REF_COLUMNS, RadarLog
from sensor_envs.sensor_model import has_capability

__all__ = [
    "WORLD_VARIABLES",
    "aspect_angle",
    "occluded_column",
    "derived_columns",
    "with_derived_columns",
    "state_matrix",
    "with_state_columns",
    "model_extra",
]

WORLD_VARIABLES = {
    "rel_vx": "target velocity minus ego velocity, sensor-frame x [m/s]",
    "rel_vy": "target velocity minus ego velocity, sensor-frame y [m/s]",
    "rel_speed": "norm of the relative velocity [m/s]",
    "target_heading": "target heading in the sensor frame [rad]",
    "aspect": "target heading relative to the line of sight to its centre [rad], 0 = driving away",
    "ego_speed": "ego speed [m/s]",
    "range": "distance to the target centre [m]",
    "azimuth": "bearing of the target centre [rad]",
    "occluded": "fraction of the target's angular extent hidden behind other vehicles, seen from the sensor [0, 1]",
}
"""State variables the highway wrapper can supply at run time (name -> meaning)."""


def aspect_angle(x: NDArray, y: NDArray, heading: NDArray) -> NDArray[np.float64]:
    """Target aspect [rad]: heading minus the line-of-sight bearing ``atan2(y, x)``, wrapped to ``[-pi, pi)``.

    Args:
        x: target centre x in the sensor frame [m].
        y: target centre y in the sensor frame [m].
        heading: target heading in the sensor frame [rad].
    """
    return np.asarray(wrap_angle(np.asarray(heading, dtype=np.float64) - np.arctan2(y, x)), dtype=np.float64)


def occluded_column(log: RadarLog) -> NDArray[np.float64]:
    """Occluded fraction of every target row's reference box among its cycle's target boxes (NaN on clutter).

    A cycle is one ``(sequence, frame)``; the fraction is :func:`sensor_envs.geometry.occluded_fraction`
    seen from the sensor at the origin (16 rays per box): the share of the box's angular extent
    whose first hit is another box of the same cycle. Boxes the log does not hold (other classes,
    beyond the log range) do not occlude. Range ``[0, 1]``.
    """
    out = np.full(len(log["frame"]), np.nan)
    rows = np.flatnonzero(~log.is_clutter)
    if rows.size == 0:
        return out
    corners = rectangle_corners(*(np.asarray(log[c], dtype=np.float64)[rows] for c in REF_COLUMNS))
    keys = np.stack([log["sequence"][rows], log["frame"][rows]], axis=1)
    _, cycle = np.unique(keys, axis=0, return_inverse=True)
    cycle = cycle.ravel()
    order = np.argsort(cycle, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(cycle[order]) != 0])
    occ = np.zeros(rows.size)
    for a, b in zip(starts, np.r_[starts[1:], order.size], strict=True):  # one iteration per cycle
        idx = order[a:b]
        if idx.size > 1:
            occ[idx] = occluded_fraction(corners[idx])
    out[rows] = occ
    return out


def derived_columns(log: RadarLog, names: tuple[str, ...] | None = None) -> dict[str, NDArray[np.float64]]:
    """Features derivable from every log row's reference box (NaN on clutter rows).

    Returns ``range`` [m] and ``azimuth`` [rad] of the box centre, ``aspect`` [rad], ``occluded``
    (:func:`occluded_column`, [0, 1]), and ``rel_speed`` [m/s] when the log has ``rel_vx`` and
    ``rel_vy`` columns; with ``names``, only those of them (the others are not computed: ``occluded``
    costs a pass over the log's cycles). Columns the log already has are not recomputed.
    """
    x, y, h = log["ref_x"], log["ref_y"], log["ref_heading"]
    makers: dict[str, Callable[[], NDArray[np.float64]]] = {
        "range": lambda: np.hypot(x, y),
        "azimuth": lambda: np.arctan2(y, x),
        "aspect": lambda: aspect_angle(x, y, h),
        "occluded": lambda: occluded_column(log),
    }
    if "rel_vx" in log.columns and "rel_vy" in log.columns:
        makers["rel_speed"] = lambda: np.hypot(log["rel_vx"], log["rel_vy"])
    wanted = makers if names is None else [n for n in names if n in makers]
    return {k: makers[k]() for k in wanted if k not in log.columns}


def with_derived_columns(log: RadarLog) -> RadarLog:
    """A copy of ``log`` with the :func:`derived_columns` added as covariate columns."""
    return RadarLog({**log.columns, **derived_columns(log)}, source=log.source)


def with_state_columns(log: RadarLog, names: tuple[str, ...]) -> RadarLog:
    """``log`` itself when it has every column of ``names``, else a copy with the derivable ones added.

    Derive once before many :func:`state_matrix` calls on parts of a log (CV folds): a derived feature
    such as ``occluded`` costs a pass over the log's cycles.
    """
    missing = tuple(n for n in names if n not in log.columns)
    if not missing:
        return log
    return RadarLog({**log.columns, **derived_columns(log, missing)}, source=log.source)


def state_matrix(log: RadarLog, names: tuple[str, ...], rows: NDArray[np.int64]) -> NDArray[np.float64]:
    """``(len(rows), len(names))`` values of the extra state columns ``names`` at log ``rows``.

    A name the log lacks is taken from :func:`derived_columns` when it is derivable (e.g. ``occluded``).

    Raises:
        ValueError: naming the log and the first column it lacks (and cannot derive).
    """
    log = with_state_columns(log, names)
    for name in names:
        if name not in log.columns:
            raise InputError(f"{log.source}: column {name!r} (a state variable of the model) is missing from the log")
    if not names:
        return np.zeros((len(rows), 0))
    return np.stack([np.asarray(log[n], dtype=np.float64)[rows] for n in names], axis=1)


def model_extra(model: object, log: RadarLog, rows: NDArray[np.int64]) -> NDArray[np.float64] | None:
    """The ``extra`` argument of ``model``'s queries at log ``rows``: its ``extra_state_`` values, or None.

    Raises:
        ValueError: as :func:`state_matrix`, when the log lacks (and cannot derive) a variable the model names.
    """
    names = tuple(model.extra_state_) if has_capability(model, "extra_state") else ()  # type: ignore[attr-defined]
    return state_matrix(log, names, rows) if names else None
