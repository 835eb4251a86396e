"""Frames of the KDE radar's stored outputs: the mounting yaw error and the corner's polar frame.

The model stores ``z`` and ``z_{t-1}`` after undoing ``azimuth_bias_`` and on the axes of ``output_frame``
(:class:`sensor_envs.radar.kde.KDERadarModel`); queries are turned the same way, samples back.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from sensor_envs.geometry import from_polar_frame, to_polar_frame
from sensor_envs.inputs import InputError
from sensor_envs.radar.alignment import derotate_offsets, rotate_offsets
from sensor_envs.radar.kde_bandwidth import relevance_features

if TYPE_CHECKING:
    from sensor_envs.radar.kde import KDERadarModel

__all__ = [
    "to_output_frame",
    "to_model_frame",
    "to_sensor_frame",
    "model_state",
    "features",
    "scaled",
    "extra_query",
    "as_prev",
]


def to_output_frame(m: KDERadarModel, z: NDArray, corners: NDArray) -> NDArray[np.float64]:
    """:meth:`KDERadarModel.to_output_frame <sensor_envs.radar.kde.KDERadarModel.to_output_frame>`."""
    m._check_fitted()
    return to_model_frame(m, np.atleast_2d(np.asarray(z, dtype=np.float64)), np.atleast_2d(corners))


def to_model_frame(m: KDERadarModel, z: NDArray, corners: NDArray) -> NDArray[np.float64]:
    """Sensor-frame offsets ``z (n, 2)`` [m] at ``corners (n, 2)`` in the stored frame.

    The mounting yaw error ``azimuth_bias_`` undone first, then the axes of ``output_frame``.
    """
    z = derotate_offsets(z, corners, m.azimuth_bias_)
    return z if m.output_frame == "cartesian" else to_polar_frame(z, corners)


def to_sensor_frame(m: KDERadarModel, z: NDArray, corners: NDArray) -> NDArray[np.float64]:
    """Inverse of :func:`to_model_frame`: stored-frame offsets back to the sensor frame [m]."""
    z = z if m.output_frame == "cartesian" else from_polar_frame(z, corners)
    return rotate_offsets(z, corners, m.azimuth_bias_)


def model_state(m: KDERadarModel, st: NDArray) -> NDArray[np.float64]:
    """Query states ``(n, 2|4)`` with the previous output (columns 2-3) in the stored frame."""
    if st.shape[1] < 4:
        return st
    return np.concatenate([st[:, :2], to_model_frame(m, st[:, 2:4], st[:, :2]), st[:, 4:]], axis=1)


def features(m: KDERadarModel, states: NDArray) -> NDArray[np.float64]:
    """States ``(n, d)`` with the corner columns as relevance features (:func:`relevance_features`)."""
    return relevance_features(states, m.state_transform)


def scaled(m: KDERadarModel, base: NDArray, extra: NDArray) -> NDArray[np.float64]:
    """Scaled query/tuple states: ``base (n, d)`` by the first ``d`` relevance scales, then the extras."""
    return np.concatenate([base / m.scale_[: base.shape[1]], extra / m.extra_scale_], axis=1)


def extra_query(m: KDERadarModel, extra: NDArray | None, n: int) -> NDArray[np.float64]:
    """Validated ``(n, E)`` extra state of ``n`` queries (NaN -> training median)."""
    e = len(m.extra_state_)
    if e == 0:
        return np.zeros((n, 0))
    if extra is None:
        raise InputError(f"extra: this model's state includes {list(m.extra_state_)}; pass their values")
    x = np.asarray(extra, dtype=np.float64)
    if x.size != n * e:
        raise InputError(f"extra: expected ({n}, {e}) values of {list(m.extra_state_)}, got shape {x.shape}")
    x = x.reshape(n, e)
    return np.where(np.isnan(x), m.extra_fill_, x)


def as_prev(prev_z: NDArray | None, n: int) -> NDArray[np.float64]:
    """Previous outputs ``(n, 2)`` [m] (``None`` = all missing); ``ValueError`` on a wrong shape."""
    if prev_z is None:
        return np.full((n, 2), np.nan)
    prev = np.atleast_2d(np.asarray(prev_z, dtype=np.float64))
    if prev.shape != (n, 2):
        raise InputError(f"prev_z must be ({n}, 2) like corners; got {prev.shape}")
    return prev
