"""The checked arguments of a lidar model's calls (``fit``, ``sample``, ``log_prob``): one validation line at their top.

:func:`check_model_call` checks the arrays and options as passed; :func:`check_query` reads what the fitted model
adds (its bearings, its extra state variables) and asks for the readings ``log_prob`` scores.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sensor_envs.geometry import as_segments
from sensor_envs.inputs import InputError, check_array, check_count, check_rng
from sensor_envs.lidar.log import MAX_COORD, MAX_RANGE, LidarLog
from sensor_envs.sensor_model import extra_state_names

__all__ = ["check_model_call", "check_query", "MAX_REPEATS"]

_UNSET: Any = object()
MAX_REPEATS = 10_000
"""Most repeated readings per cell a lidar model samples in one call (``n_repeats``)."""


def check_model_call(
    poses: Any,
    map_segments: Any = None,
    rng: Any = _UNSET,
    ranges: Any = None,
    log: Any = _UNSET,
    *,
    n_bearings: int | None = None,
    extra: Any = None,
    extra_names: tuple[str, ...] | None = None,
    n_repeats: Any = None,
    per_reading: Any = None,
) -> None:
    """The checked arguments of a lidar model's ``fit``/``sample``/``log_prob`` (a validation line at their top).

    ``poses`` ``(3,)`` or ``(S, 3)`` finite within :data:`MAX_COORD`; ``map_segments`` valid segments;
    ``rng`` a Generator; ``ranges`` readings ``>= 0`` (NaN = missing) up to :data:`MAX_RANGE`, ``(S, K)``
    or ``(S, K, R)`` with ``K = n_bearings`` when given; ``log`` (for ``fit``) a :class:`LidarLog`;
    ``extra`` ``None`` for a model without extra state variables (``extra_names`` empty), else real
    numbers (NaN = missing); ``n_repeats`` ``None`` or an integer in ``[1, MAX_REPEATS]``; ``per_reading``
    (``fit``'s strategy) ``None``, ``True`` or ``False``.

    Raises:
        InputError: naming the argument.
    """
    if log is not _UNSET and not isinstance(log, LidarLog):
        raise InputError(f"log: expected a LidarLog (sensor_envs.lidar.log.load_log), got {type(log).__name__}")
    if log is _UNSET and (poses is None or map_segments is None):  # sample / log_prob: both required
        raise InputError(f"{'poses' if poses is None else 'map_segments'}: required, got None")
    if per_reading is not None and not isinstance(per_reading, (bool, np.bool_)):
        raise InputError(f"per_reading: expected True, False or None, got {per_reading!r:.40}")
    if rng is not _UNSET:
        check_rng(rng)
    if n_repeats is not None:
        check_count(n_repeats, "n_repeats", 1, MAX_REPEATS)
    if poses is not None:
        ps = check_array(np.atleast_2d(poses), "poses", (None, 3), low=-MAX_COORD, high=MAX_COORD)
        if ranges is not None:
            r = np.asarray(ranges)
            shape = (ps.shape[0], n_bearings) + ((None,) if r.ndim == 3 else ())
            check_array(r, "ranges", shape, low=0, high=MAX_RANGE, nan=True)
    if map_segments is not None:
        as_segments(map_segments, name="map_segments")
    if extra_names is not None and extra is not None:
        if not extra_names and np.size(extra):
            raise InputError("extra: this model has no extra state variables; pass None")
        if extra_names:
            check_array(np.asarray(extra), "extra", (None,) * np.ndim(extra), low=-1e12, high=1e12, nan=True)


def check_query(
    model: Any, poses: Any, map_segments: Any, rng: Any = _UNSET, ranges: Any = _UNSET, **kwargs: Any
) -> None:
    """:func:`check_model_call` for a fitted ``model``'s ``sample`` (``rng`` given) or ``log_prob`` (``ranges`` given).

    ``extra`` is checked against the model's ``extra_state_`` names and ``ranges`` against its bearings;
    ``kwargs``: ``extra``, ``n_repeats``.

    Raises:
        InputError: naming the argument (``ranges: ... got None`` for ``log_prob`` without readings).
    """
    names = extra_state_names(model)
    if ranges is _UNSET:
        check_model_call(poses, map_segments, rng, extra_names=names, **kwargs)
        return
    if ranges is None:
        raise InputError("ranges: expected (S, K) or (S, K, R) readings [m], got None")
    n = model.bearings_.size
    check_model_call(poses, map_segments, ranges=ranges, n_bearings=n, extra_names=names, **kwargs)
