"""Clutter level and stationary-object handling of the highway radar.

``clutter="objects"`` (the default): the fitted radar models draw the Astyx POINT-level clutter (every
cluster and noise point outside the reference boxes, ~94 per cycle), while their targets are objects
(one detection per box). The wrapper thins the model's clutter, independently per point, to the
object-level rate measured on the same frames (:mod:`sensor_envs.radar.object_clutter`, shipped as
``models/radar_object_clutter.json``): in each range bin the keep probability is ``min(1, law rate /
model rate)``, the model's own rate per bin being estimated once per model from 400 cycles of a private
generator (seed 0; the env's streams are not touched). ``clutter="model"`` keeps the model's clutter.

``stationary="drop"``: the Doppler stationary filter of radar object lists and ADAS functions. A
detection whose radial speed over ground (the world velocity's component along the line of sight
from the sensor, i.e. measured radial speed minus the ego's own motion) is within
``STATIONARY_SPEED`` [m/s] is stationary and removed: clutter (stationary infrastructure in this world)
and stopped vehicles or obstacles alike, the known blind spot of such filters. ``"keep"`` (the default)
reports them, as the radar does: highway-env's crashed or stopped vehicles and obstacles stay visible.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.radar.object_clutter import ObjectClutterLaw, load_object_clutter

__all__ = ["CLUTTER_LEVELS", "STATIONARY_MODES", "STATIONARY_SPEED", "clutter_keep_probability", "radial_speed"]

CLUTTER_LEVELS = ("objects", "model")
"""Values of ``clutter``: thinned to the object-level law, or the model's own clutter."""
STATIONARY_MODES = ("keep", "drop")
"""Values of ``stationary``: report stationary detections, or drop them (Doppler filter)."""
STATIONARY_SPEED = 0.5
"""Largest |radial speed over ground| [m/s] of a stationary detection (the law's ``speed_tol``)."""
_RATE_CYCLES = 400


@functools.lru_cache(maxsize=1)
def _shipped_law() -> ObjectClutterLaw:
    return load_object_clutter(None)


def clutter_keep_probability(radar: Any, law: ObjectClutterLaw | None = None) -> NDArray[np.float64]:
    """Per range bin of ``law`` (default: the shipped one): probability of keeping a model clutter point.

    ``min(1, law rate / model rate)`` per bin; a bin where the model draws nothing keeps everything.
    Estimated from :data:`_RATE_CYCLES` cycles of ``radar.sample_clutter`` with a private generator.
    """
    law = law if law is not None else _shipped_law()
    edges = np.asarray(law.range_edges, dtype=np.float64)
    rng = np.random.default_rng(0)
    counts = np.zeros(edges.size - 1)
    for _ in range(_RATE_CYCLES):  # one model clutter draw per iteration (~50 us each)
        c = np.asarray(radar.sample_clutter(rng), dtype=np.float64).reshape(-1, 2)
        counts += range_bin_counts(np.hypot(c[:, 0], c[:, 1]), edges)
    rate = counts / _RATE_CYCLES
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(rate > 0, law.total / rate, 1.0)
    return np.asarray(np.clip(p, 0.0, 1.0), dtype=np.float64)


def range_bin_counts(r: NDArray[np.float64], edges: NDArray[np.float64]) -> NDArray[np.float64]:
    """Counts of ranges ``r`` [m] per bin of ``edges`` (beyond the edges: the end bins)."""
    return np.bincount(range_bins(r, edges), minlength=edges.size - 1).astype(np.float64)


def range_bins(r: NDArray[np.float64], edges: NDArray[np.float64]) -> NDArray[np.intp]:
    """Bin index of each range [m] (beyond the edges: the end bins)."""
    return np.asarray(np.clip(np.searchsorted(edges, r, side="right") - 1, 0, edges.size - 2), dtype=np.intp)


def law_edges() -> NDArray[np.float64]:
    """Range edges [m] of the shipped law."""
    return np.asarray(_shipped_law().range_edges, dtype=np.float64)


def radial_speed(velocity_w: NDArray[np.float64], det_w: NDArray[np.float64], sensor_xy: NDArray) -> NDArray:
    """``(k,)`` radial speed over ground [m/s]: world velocity along the line of sight from the sensor."""
    los = det_w - np.asarray(sensor_xy, dtype=np.float64)[:2]
    u = los / np.maximum(np.linalg.norm(los, axis=1, keepdims=True), 1e-9)
    return np.asarray(np.sum(velocity_w * u, axis=1), dtype=np.float64)
