"""The KDE radar's hyperparameter table, its limits and shared constants (:class:`sensor_envs.radar.kde.KDERadarModel`).

One declarative table (:data:`KDE_PARAMETERS`) checks the hyperparameters in ``fit`` and in ``load`` alike;
:func:`check_extra_params` checks what the table cannot (relations between the ``extra_*`` values).
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Any

import numpy as np

from sensor_envs.inputs import InputError
from sensor_envs.modelio import (
    CYCLE_TIME,
    RANDOM_STATE,
    Constraint,
    InstanceOf,
    Interval,
    Names,
    Numbers,
    Options,
    validate_params,
)
from sensor_envs.radar.alignment import MAX_AZIMUTH_BIAS

if TYPE_CHECKING:
    from sensor_envs.radar.kde import KDERadarModel

__all__ = [
    "KDE_PARAMETERS",
    "HEADER_SCHEMA",
    "check_extra_params",
    "CV_RELEVANCE",
    "STATE_TRANSFORMS",
    "OUTPUT_FRAMES",
    "scaled_copy",
    "start_scaled_copy",
    "tail_copy",
]

STATE_TRANSFORMS = ("cartesian", "polar")
"""Corner features of the relevance kernel: ``(c_x, c_y)`` [m] or ``(range [m], azimuth [rad])``."""
OUTPUT_FRAMES = ("cartesian", "polar")
"""Frame the model stores outputs ``z`` and ``z_{t-1}`` in: the sensor frame, or the corner's polar frame
(radial, OUTWARD cross-range; :func:`sensor_envs.geometry.polar_frame`). Callers always pass and get
sensor-frame offsets."""
AZIMUTH_CANDIDATES = (0.0025, 0.01, 0.04, 0.16)
"""Default azimuth variances [rad^2] the CV tries with polar corner features (``relevance_candidates_azimuth``)."""
LOG_PROB_CHUNK = 1024
"""Rows per chunk of :meth:`KDERadarModel.log_prob` (wide kernels on long logs hold thousands of
tuples per query: all rows at once ran a 1/15 s rig log's CV out of 24 GB of memory)."""
CV_RELEVANCE = ("cv", "cv_axes", "cv_state")
"""Relevance modes whose state variances are chosen by CV on the training log (``"paper"``: given)."""
PREV_CANDIDATES = (0.03, 0.06, 0.12, 0.24, 0.48, 0.96)
"""Default ``z_{t-1}`` variances [m^2] the CV of ``relevance="cv_state"`` tries (``relevance_candidates_prev``;
0.03 is the seed's)."""
GROUP_MAIN, GROUP_START, GROUP_NEW, GROUP_LOST = 0, 1, 2, 3
"""Tree of a query: with ``z_{t-1}``; start (flag unknown); new track; after a miss."""
AUTO_BUCKET_MIN_NEIGHBOURS = 100
"""``sampler="auto"`` uses the bucket sampler when the median number of tuples in the ball of a stored
state is at least this (the ball sampler's cost follows it; benchmarks/bench_radar.py, 10-target
cycles: 25 neighbours, ball 0.28 ms vs bucket 0.42 ms; 250 neighbours, 0.91 vs 0.45 ms)."""
MAX_POSITION = 1e3
"""Largest sensor-frame coordinate, output offset, bandwidth or relevance sigma [m] a model file may hold."""
MAX_CLUTTER_POSITIONS = 200_000
"""Most clutter positions a fitted model stores (a uniform subsample beyond that)."""
MAX_TAIL_WEIGHT = 0.5
"""Largest share of the detection density the tail component may hold."""
MAX_TAIL_SCALE = 100.0
"""Largest factor of the tail component's bandwidths over the main kernels'."""
LOG_2PI = float(np.log(2.0 * np.pi))
_POSITIVE = Interval(0, None, open_low=True)
MAX_EXTRA_FACTOR = 100.0
"""Largest factor of an extra state variable's standard deviation among ``extra_candidates``."""
HEADER_SCHEMA: dict[str, list[Constraint]] = {
    "cycle_time": CYCLE_TIME,
    "rel_variance_fitted": [Numbers(Interval(0, MAX_POSITION**2, open_low=True), length=4)],
    "relevance_scores": [Numbers(Interval(None, None), min_length=0, nan=True)],
    "state_variables": [Names()],
    "extra_variance_fitted": [Numbers(_POSITIVE, min_length=0)],
    "extra_fill": [Numbers(Interval(None, None), min_length=0)],
    "new_track_flags": [InstanceOf(bool)],
    "azimuth_bias_fitted": [Interval(-MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS)],
}
"""Declared fitted fields of a KDE model file's header (their consistency with the arrays: the loader)."""


KDE_PARAMETERS: dict[str, list[Constraint]] = {
    "rel_variance": [Numbers(Interval(0, MAX_POSITION**2, open_low=True), length=4)],
    "use_prev": [InstanceOf(bool)],
    "radius": [_POSITIVE],
    "k_max": [None, Interval(1, None, integer=True)],
    "cv_grid_step": [_POSITIVE],
    "cv_candidates": [None, Numbers(Interval(0, MAX_POSITION, open_low=True))],
    "cv_min_tuples": [Interval(1, None, integer=True)],
    "cv_max_tuples": [Interval(1, None, integer=True)],
    "cv_group": [Options("track", "sequence", "row")],
    "fallback_k": [Interval(1, None, integer=True)],
    "miss_prior": [Interval(0, None)],
    "clutter_jitter": [Interval(0, MAX_POSITION)],
    "sampler": [Options("auto", "bucket", "ball")],
    "bucket_cell": [_POSITIVE],
    "relevance": [Options("paper", *CV_RELEVANCE)],
    "relevance_candidates": [Numbers(_POSITIVE)],
    "relevance_candidates_azimuth": [Numbers(Interval(0, np.pi**2, open_low=True))],
    "relevance_candidates_prev": [Numbers(Interval(0, MAX_POSITION**2, open_low=True))],
    "state_transform": [Options(*STATE_TRANSFORMS)],
    "output_frame": [Options(*OUTPUT_FRAMES)],
    "relevance_folds": [Interval(2, None, integer=True)],
    "prior_rate": [Options("tree", "global")],
    "random_state": RANDOM_STATE,
    "extra_state": [Names()],  # names of log columns; relations to the other two: check_extra_params
    "extra_variance": [None, Numbers(_POSITIVE, min_length=0, nan=True)],  # NaN: chosen by CV
    "extra_candidates": [Numbers(Interval(0, MAX_EXTRA_FACTOR, open_low=True))],
    "bandwidth_scale": [Interval(0.01, 100)],
    "start_bandwidth_scale": [None, Interval(0.01, 100)],
    "azimuth_bias": [Options("fit"), Interval(-MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS)],
    "tail_weight": [Interval(0, MAX_TAIL_WEIGHT)],
    "tail_scale": [Interval(1, MAX_TAIL_SCALE)],
    "verbose": [InstanceOf(bool)],
}
"""One declarative check of every hyperparameter, used by ``fit`` and ``load``."""


def check_extra_params(names: Any, variance: Any, candidates: Any) -> None:
    """Validate the ``extra_*`` hyperparameters (raises ValueError naming the parameter)."""
    if isinstance(names, str) or not all(isinstance(n, str) and n for n in names):
        raise InputError(f"extra_state must be a tuple of column names, got {names!r}")
    if len(set(names)) != len(names):
        raise InputError(f"extra_state has duplicate names: {names!r}")
    if variance is not None:
        v = np.asarray(variance, dtype=np.float64)
        if v.shape != (len(names),) or not (np.isnan(v) | (np.isfinite(v) & (v > 0))).all():
            raise InputError(
                f"extra_variance must be {len(names)} positive variances (NaN = by CV) or None, got {variance!r}"
            )
    c = np.asarray(candidates, dtype=np.float64)
    if c.ndim != 1 or c.size == 0 or not (np.isfinite(c).all() and (c > 0).all()):
        raise InputError(f"extra_candidates must be positive factors, got {candidates!r}")


# --------------------------------------------------------------------- post-fit copies (KDERadarModel.with_*)
def scaled_copy(model: KDERadarModel, factor: float) -> KDERadarModel:
    """A copy of a fitted ``model`` with every contribution bandwidth (and ``bandwidth_scale``) times ``factor``."""
    check = {"bandwidth_scale": KDE_PARAMETERS["bandwidth_scale"]}
    for value in (factor, model.bandwidth_scale * factor):  # the factor, and the model's factor after it
        validate_params({"bandwidth_scale": value}, check)
    out = copy.deepcopy(model)
    out.bandwidth_scale = float(model.bandwidth_scale * factor)
    out.log_h_ = model.log_h_ + np.log(factor)
    return out


def start_scaled_copy(model: KDERadarModel, value: float | None) -> KDERadarModel:
    """A copy of a fitted ``model`` with ``start_bandwidth_scale = value`` (checked)."""
    validate_params({"start_bandwidth_scale": value}, KDE_PARAMETERS)
    out = copy.deepcopy(model)
    out.start_bandwidth_scale = None if value is None else float(value)
    return out


def tail_copy(model: KDERadarModel, weight: float, scale: float) -> KDERadarModel:
    """A copy of a fitted ``model`` with the tail mixture ``tail_weight = weight``, ``tail_scale = scale`` (checked)."""
    validate_params({"tail_weight": weight, "tail_scale": scale}, KDE_PARAMETERS)
    out = copy.deepcopy(model)
    out.tail_weight, out.tail_scale = float(weight), float(scale)
    return out
