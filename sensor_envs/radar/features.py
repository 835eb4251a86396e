"""Extra state variables of the radar models: names, derived features and lookup in a log.

Both radar models (:class:`~sensor_envs.radar.kde.KDERadarModel`, :class:`~sensor_envs.radar.gaussian.GaussianRadar`)
can take extra state variables (``extra_state``): names of numeric columns of the radar log (any
covariate column, e.g. ``rel_vx``, ``occlusion``, or a derived feature added with
:func:`with_derived_columns`). A world that runs a model must supply every variable the model names;
:data:`WORLD_VARIABLES` lists the ones the highway wrapper supplies.

Frames and units: sensor frame (x forward, y left), metres, radians, m/s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from sensor_envs.geometry import wrap_angle
from sensor_envs.radar.log import RadarLog

__all__ = ["WORLD_VARIABLES", "aspect_angle", "derived_columns", "with_derived_columns", "state_matrix"]

WORLD_VARIABLES = {
    "rel_vx": "target velocity minus ego velocity, sensor-frame x [m/s]",
    "rel_vy": "target velocity minus ego velocity, sensor-frame y [m/s]",
    "rel_speed": "norm of the relative velocity [m/s]",
    "target_heading": "target heading in the sensor frame [rad]",
    "aspect": "target heading relative to the line of sight to its centre [rad], 0 = driving away",
    "ego_speed": "ego speed [m/s]",
    "range": "distance to the target centre [m]",
    "azimuth": "bearing of the target centre [rad]",
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


def derived_columns(log: RadarLog) -> dict[str, NDArray[np.float64]]:
    """Features derivable from every log row's reference box (NaN on clutter rows).

    Returns ``range`` [m] and ``azimuth`` [rad] of the box centre, ``aspect`` [rad], and
    ``rel_speed`` [m/s] when the log has ``rel_vx`` and ``rel_vy`` columns. Columns the log already
    has are not recomputed.
    """
    x, y, h = log["ref_x"], log["ref_y"], log["ref_heading"]
    out = {"range": np.hypot(x, y), "azimuth": np.arctan2(y, x), "aspect": aspect_angle(x, y, h)}
    if "rel_vx" in log.columns and "rel_vy" in log.columns:
        out["rel_speed"] = np.hypot(log["rel_vx"], log["rel_vy"])
    return {k: v for k, v in out.items() if k not in log.columns}


def with_derived_columns(log: RadarLog) -> RadarLog:
    """A copy of ``log`` with the :func:`derived_columns` added as covariate columns."""
    return RadarLog({**log.columns, **derived_columns(log)}, source=log.source)


def state_matrix(log: RadarLog, names: tuple[str, ...], rows: NDArray[np.int64]) -> NDArray[np.float64]:
    """``(len(rows), len(names))`` values of the extra state columns ``names`` at log ``rows``.

    Raises:
        ValueError: naming the log and the first column it lacks.
    """
    for name in names:
        if name not in log.columns:
            raise ValueError(f"{log.source}: column {name!r} (a state variable of the model) is missing from the log")
    if not names:
        return np.zeros((len(rows), 0))
    return np.stack([np.asarray(log[n], dtype=np.float64)[rows] for n in names], axis=1)
