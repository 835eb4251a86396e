"""The reference radar rig's parameters: :class:`RigConfig`, its constraint table and the rig files.

What each parameter does is in :mod:`sensor_envs.radar.rig` (the rig that records with them); rig files are
small JSON files of these values (:func:`load_rig`, :func:`save_rig`; :mod:`sensor_envs.modelio`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.inputs import InputError
from sensor_envs.modelio import (
    Constraint,
    Interval,
    Numbers,
    Options,
    default_model_path,
    read_rig,
    save_rig_file,
    validate_params,
)
from sensor_envs.radar.alignment import MAX_AZIMUTH_BIAS

__all__ = ["RigConfig", "RIG_CONSTRAINTS", "RIG_KIND", "SCENE_TABLES", "load_rig", "save_rig", "default_rig_path"]


Table = tuple[float, ...] | None


@dataclass(frozen=True)
class RigConfig:
    """Parameters of the reference rig (defaults: a generic 77 GHz long-range object radar).

    The optional tables (``None`` = the generic rig's closed forms) are what
    :mod:`sensor_envs.radar.calibrate` fits to real data; values between knots are interpolated
    linearly, beyond the last knot the last value holds (detection: the logistic fall-off at
    ``max_range`` multiplies the range table; beyond the last azimuth knot the factor is 0).

    Attributes:
        detect_range_knots: range knots [m] (of the reflection point) of ``detect_range_table``.
        detect_range_table: detection probability at each range knot (replaces ``p_detect``).
        detect_azimuth_knots: azimuth knots [rad] of ``detect_azimuth_table``: ``|azimuth|`` in
            ``[0, pi]`` (left-right symmetric), or, with ``detect_azimuth_signed``, the signed azimuth
            in ``[-pi, pi]`` (sensor frame: positive to the left).
        detect_azimuth_table: detection factor in [0, 1] at each azimuth knot (replaces the
            field-of-view edge law; 0 beyond the last knot, and with ``detect_azimuth_signed`` also
            before the first).
        detect_azimuth_signed: whether ``detect_azimuth_knots`` are signed azimuths (a lopsided
            sensor) instead of ``|azimuth|`` (``False``: what rig files without the field mean).
        occlusion_loss_knots: range knots [m] (of the reflection point) of ``occlusion_loss_table``.
        occlusion_loss_table: share of the detection probability lost by a wholly hidden box at each
            range knot (replaces ``occlusion_loss``; the loss is this times the occluded fraction). On
            Astyx a hidden box is lost far more often near the sensor than beyond 50 m.
        offset_range_knots: range knots [m] of the offset-spread tables.
        sigma_range_table: radial noise std [m] at each knot (replaces ``sigma_range``).
        sigma_cross_table: cross-range noise std [m] at each knot (replaces ``sigma_azimuth * range``
            and the edge gain).
        range_bias: radial offset [m] of every detection (negative: towards the sensor).
        azimuth_bias: the radar's mounting yaw error [rad] (counter-clockwise positive): every target
            detection is rotated about the sensor by it, i.e. a cross-range error growing with range
            (0.1 deg is 0.17 m at 100 m). Clutter is not rotated: its azimuth law is fitted on the real
            clutter as measured.
        outlier_share: share of detections whose noise is scaled by ``outlier_scale`` (tail shape).
        outlier_scale: noise scale factor of those detections (>= 1).
        corner_share: probability that a cycle's reflection point is the closest corner instead of
            a point on the face most turned to the sensor.
        reflection_spread: half-width of the fraction along that face where the point lies (<= 0.5).
        reflection_center: mean position of that point along the face, as a fraction of the face's
            length from its end nearer the sensor (0.5: the face's midpoint; smaller: nearer the
            closest corner, where a real radar's strongest return tends to be).
        offset_mixture_edges: corner-range bin edges [m] of the offset mixture law (beyond the edges
            the first / last bin holds); ``None``: the reflection-point law.
        offset_mixture_weights: component weights, ``bins x components`` values (each bin's sum 1).
        offset_mixture_means: component means (radial, outward cross-range) [m], ``bins x components x 2``.
        offset_mixture_scales: lower Cholesky factors ``(l_rr, l_or, l_oo)`` [m] of the component
            covariances in the (radial, outward) frame, ``bins x components x 3`` (``l_rr, l_oo > 0``).
        offset_mixture_min_range: closest-corner range [m] from which the mixture law applies; nearer
            boxes keep the reflection-point law (0, the default: the mixture everywhere).
        clutter_dispersion: clutter count over-dispersion ``k``: variance = mean + k mean^2
            (negative binomial; 0 = Poisson).
        clutter_range_edges, clutter_range_weights: clutter range bins [m] and their shares
            (uniform in range inside a bin; ``None``: uniform in area inside ``max_range``).
        clutter_azimuth_edges, clutter_azimuth_weights: clutter azimuth bins [rad] and their shares
            (``None``: uniform in ``+-fov``).
        clutter_cell_weights: joint shares of the clutter's (range bin, azimuth bin) cells, ``range bins x
            azimuth bins`` values over ``clutter_range_edges`` and ``clutter_azimuth_edges`` (``None``: range
            and azimuth drawn independently from their own shares). Real clutter is not independent in the
            two: the road just ahead is empty while the roadside is not, so at short range the lane ahead
            gets far less clutter than its azimuth share says.
        scene_x_edges, scene_x_weights: the recorded SCENE (:func:`generate_scenario`; ``None``: the generic
            lane traffic): bins of the target centre's x [m] (sensor frame) and their shares.
        scene_y_edges: bins of the target centre's y [m] (sensor frame, left positive).
        scene_y_weights: shares of the y bins in each x bin, ``x bins x y bins`` values.
        scene_heading_edges: bins of the target's heading modulo pi [rad], in ``[-pi/2, pi/2]`` (a box turned
            by pi is the same box; 0 = along the sensor's x axis).
        scene_heading_weights: shares of the heading bins in each x bin, ``x bins x heading bins`` values.
        scene_length_range, scene_width_range: ``(low, high)`` [m] of the uniform box length and width.
        scene_speed_std: std [m/s] of the target's velocity relative to the sensor, along the sensor's x (the
            calibrated scene; the generic lane traffic has its own speeds).
    """

    cycle_time: float = 1.0
    latency: float = 0.05
    max_range: float = 90.0
    log_range: float = 110.0
    fov: float = np.deg2rad(50.0)
    sigma_range: float = 0.25
    sigma_azimuth: float = np.deg2rad(0.6)
    edge_gain: float = 3.0
    tracker_tau: float = 2.0
    p_detect: float = 0.95
    range_falloff: float = 6.0
    occlusion_loss: float = 0.9
    clutter_rate: float = 1.5
    reflection_tau: float = 5.0
    detect_range_knots: Table = None
    detect_range_table: Table = None
    detect_azimuth_knots: Table = None
    detect_azimuth_table: Table = None
    detect_azimuth_signed: bool = False
    occlusion_loss_knots: Table = None
    occlusion_loss_table: Table = None
    offset_range_knots: Table = None
    sigma_range_table: Table = None
    sigma_cross_table: Table = None
    range_bias: float = 0.0
    azimuth_bias: float = 0.0
    outlier_share: float = 0.0
    outlier_scale: float = 1.0
    corner_share: float = 0.0
    reflection_spread: float = 0.4
    reflection_center: float = 0.5
    offset_mixture_edges: Table = None
    offset_mixture_weights: Table = None
    offset_mixture_means: Table = None
    offset_mixture_scales: Table = None
    offset_mixture_min_range: float = 0.0
    clutter_dispersion: float = 0.0
    clutter_range_edges: Table = None
    clutter_range_weights: Table = None
    clutter_azimuth_edges: Table = None
    clutter_azimuth_weights: Table = None
    clutter_cell_weights: Table = None
    scene_x_edges: Table = None
    scene_x_weights: Table = None
    scene_y_edges: Table = None
    scene_y_weights: Table = None
    scene_heading_edges: Table = None
    scene_heading_weights: Table = None
    scene_length_range: Table = None
    scene_width_range: Table = None
    scene_speed_std: float = 1.5

    def __post_init__(self) -> None:
        """Check values and the relations between them (``ValueError`` naming the field)."""
        validate_params(self.__dict__, RIG_CONSTRAINTS)
        pairs = (
            ("detect_range_knots", "detect_range_table"),
            ("detect_azimuth_knots", "detect_azimuth_table"),
            ("occlusion_loss_knots", "occlusion_loss_table"),
            ("offset_range_knots", "sigma_range_table"),
            ("offset_range_knots", "sigma_cross_table"),
        )
        for knots, table in pairs:
            k, t = getattr(self, knots), getattr(self, table)
            if (k is None) != (t is None) or (k is not None and t is not None and len(k) != len(t)):
                raise InputError(f"{table}: must be given with {knots!r} and have one value per knot")
        if (
            not self.detect_azimuth_signed
            and self.detect_azimuth_knots is not None
            and self.detect_azimuth_knots[0] < 0
        ):
            raise InputError(
                "detect_azimuth_knots: |azimuth| knots must be >= 0 (signed knots need 'detect_azimuth_signed': true)"
            )
        for edges, weights in (
            ("clutter_range_edges", "clutter_range_weights"),
            ("clutter_azimuth_edges", "clutter_azimuth_weights"),
            ("scene_x_edges", "scene_x_weights"),
        ):
            e, w = getattr(self, edges), getattr(self, weights)
            if (e is None) != (w is None) or (e is not None and w is not None and len(e) != len(w) + 1):
                raise InputError(f"{weights}: must be given with {edges!r} and have one value per bin")
            if w is not None and not sum(w) > 0:
                raise InputError(f"{weights}: the shares must not all be 0")
        self._check_offset_mixture()
        self._check_scene()
        self._check_clutter_cells()

    def _check_clutter_cells(self) -> None:
        """``clutter_cell_weights`` comes with both clutter bin tables, one value per cell, not all 0."""
        w = self.clutter_cell_weights
        if w is None:
            return
        if self.clutter_range_edges is None or self.clutter_azimuth_edges is None:
            raise InputError(
                "clutter_cell_weights: needs 'clutter_range_edges' and 'clutter_azimuth_edges' (its cells' bins)"
            )
        n = (len(self.clutter_range_edges) - 1) * (len(self.clutter_azimuth_edges) - 1)
        if len(w) != n:
            raise InputError(f"clutter_cell_weights: must have {n} values (range bins x azimuth bins)")
        if not sum(w) > 0:
            raise InputError("clutter_cell_weights: the shares must not all be 0")

    def _check_scene(self) -> None:
        """The scene law's fields come together, its y and heading tables have one row per x bin, each row sums > 0.

        (``scene_x_weights`` against ``scene_x_edges`` is checked with the other bin tables.)
        """
        given = {n: getattr(self, n) for n in SCENE_TABLES}
        if all(v is None for v in given.values()):
            return
        for n, v in given.items():
            if v is None:
                raise InputError(f"{n}: the scene law's fields must be given together (with 'scene_x_edges')")
        n_x = len(given["scene_x_edges"]) - 1
        for edges, weights in (("scene_y_edges", "scene_y_weights"), ("scene_heading_edges", "scene_heading_weights")):
            n_b = len(given[edges]) - 1
            w = np.asarray(given[weights], dtype=np.float64)
            if w.size != n_x * n_b:
                raise InputError(f"{weights}: must have {n_x * n_b} values ({n_x} x bins x {n_b} bins of {edges!r})")
            if not np.all(w.reshape(n_x, n_b).sum(axis=1) > 0):
                raise InputError(f"{weights}: each x bin's shares must not all be 0")
        for n in ("scene_length_range", "scene_width_range"):
            lo, hi = given[n]
            if not lo <= hi:
                raise InputError(f"{n}: must be (low, high) with low <= high")

    def _check_offset_mixture(self) -> None:
        """The offset mixture's tables agree in size, each bin's weights sum to 1, scales are positive."""
        names = ("offset_mixture_weights", "offset_mixture_means", "offset_mixture_scales")
        e, given = self.offset_mixture_edges, [getattr(self, n) for n in names]
        if e is None:
            for n, v in zip(names, given, strict=True):
                if v is not None:
                    raise InputError(f"{n}: must be given with 'offset_mixture_edges'")
            if self.offset_mixture_min_range:
                raise InputError("offset_mixture_min_range: must be given with 'offset_mixture_edges'")
            return
        n_bins = len(e) - 1
        for n, v in zip(names, given, strict=True):
            if v is None:
                raise InputError(f"{n}: must be given with 'offset_mixture_edges'")
        w = np.asarray(given[0], dtype=np.float64)
        if w.size % n_bins:
            raise InputError(f"offset_mixture_weights: {w.size} values is not a multiple of {n_bins} bins")
        k = w.size // n_bins
        for n, v, per in zip(names[1:], given[1:], (2, 3), strict=True):
            if len(v) != n_bins * k * per:
                raise InputError(f"{n}: must have {n_bins * k * per} values ({n_bins} bins x {k} components x {per})")
        sums = w.reshape(n_bins, k).sum(axis=1)
        if not np.all(np.abs(sums - 1.0) <= 1e-6):
            raise InputError(
                f"offset_mixture_weights: each bin's weights must sum to 1 (sums {sums.round(6).tolist()})"
            )
        diag = np.asarray(given[2], dtype=np.float64).reshape(-1, 3)[:, [0, 2]]
        if not np.all(diag > 0):
            raise InputError("offset_mixture_scales: the Cholesky diagonals (l_rr, l_oo) must be > 0")

    def to_params(self) -> dict[str, Any]:
        """The parameters as plain JSON values (tuples as lists)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


_POS = Interval(0, 1e6, open_low=True)  # rig values: finite, sane magnitudes (a calibration search may try wide ones)
_PROB = Interval(0, 1)
_NONNEG = Interval(0, 1e6)
RIG_CONSTRAINTS: dict[str, list[Constraint]] = {
    "cycle_time": [_POS],
    "latency": [_NONNEG],
    "max_range": [_POS],
    "log_range": [_POS],
    "fov": [Interval(0, np.pi, open_low=True)],
    "sigma_range": [_NONNEG],
    "sigma_azimuth": [_NONNEG],
    "edge_gain": [_NONNEG],
    "tracker_tau": [_POS],
    "p_detect": [_PROB],
    "range_falloff": [_POS],
    "occlusion_loss": [_PROB],
    "clutter_rate": [_NONNEG],
    "reflection_tau": [_POS],
    "detect_range_knots": [None, Numbers(_NONNEG, min_length=2, increasing=True)],
    "detect_range_table": [None, Numbers(_PROB, min_length=2)],
    "detect_azimuth_knots": [None, Numbers(Interval(-np.pi, np.pi), min_length=2, increasing=True)],
    "detect_azimuth_table": [None, Numbers(_PROB, min_length=2)],
    "detect_azimuth_signed": [Options(True, False)],
    "occlusion_loss_knots": [None, Numbers(_NONNEG, min_length=2, increasing=True)],
    "occlusion_loss_table": [None, Numbers(_PROB, min_length=2)],
    "offset_range_knots": [None, Numbers(_NONNEG, min_length=2, increasing=True)],
    "sigma_range_table": [None, Numbers(_NONNEG, min_length=2)],
    "sigma_cross_table": [None, Numbers(_NONNEG, min_length=2)],
    "range_bias": [Interval(-10, 10)],
    "azimuth_bias": [Interval(-MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS)],
    "outlier_share": [_PROB],
    "outlier_scale": [Interval(1, 100)],
    "corner_share": [_PROB],
    "reflection_spread": [Interval(0, 0.5)],
    "reflection_center": [_PROB],
    "offset_mixture_edges": [None, Numbers(_NONNEG, min_length=2, increasing=True)],
    "offset_mixture_weights": [None, Numbers(_PROB, min_length=1)],
    "offset_mixture_means": [None, Numbers(Interval(-50, 50), min_length=2)],
    "offset_mixture_scales": [None, Numbers(Interval(-50, 50), min_length=3)],
    "offset_mixture_min_range": [_NONNEG],
    "clutter_dispersion": [Interval(0, 100)],
    "clutter_range_edges": [None, Numbers(_NONNEG, min_length=2, increasing=True)],
    "clutter_range_weights": [None, Numbers(_NONNEG, min_length=1)],
    "clutter_azimuth_edges": [None, Numbers(Interval(-np.pi, np.pi), min_length=2, increasing=True)],
    "clutter_azimuth_weights": [None, Numbers(_NONNEG, min_length=1)],
    "clutter_cell_weights": [None, Numbers(_NONNEG, min_length=1)],
    "scene_x_edges": [None, Numbers(Interval(0, 500), min_length=2, increasing=True)],
    "scene_x_weights": [None, Numbers(_NONNEG, min_length=1)],
    "scene_y_edges": [None, Numbers(Interval(-500, 500), min_length=2, increasing=True)],
    "scene_y_weights": [None, Numbers(_NONNEG, min_length=1)],
    "scene_heading_edges": [None, Numbers(Interval(-np.pi / 2, np.pi / 2), min_length=2, increasing=True)],
    "scene_heading_weights": [None, Numbers(_NONNEG, min_length=1)],
    "scene_length_range": [None, Numbers(Interval(0, 30, open_low=True), length=2)],
    "scene_width_range": [None, Numbers(Interval(0, 10, open_low=True), length=2)],
    "scene_speed_std": [Interval(0, 50)],
}
"""Accepted values of every :class:`RigConfig` field (the rig file's value checks)."""

SCENE_TABLES = (
    "scene_x_edges",
    "scene_x_weights",
    "scene_y_edges",
    "scene_y_weights",
    "scene_heading_edges",
    "scene_heading_weights",
    "scene_length_range",
    "scene_width_range",
)
"""The scene law's tables (all given, or none: the generic lane traffic)."""

RIG_KIND = "radar_rig"


def load_rig(path: str | os.PathLike[str]) -> tuple[RigConfig, dict[str, Any]]:
    """Read a radar rig file (kind ``"radar_rig"``); returns the config and the file's card.

    Raises:
        ModelFileError: naming the file and the field (a bad value, an unknown name, or a relation
            between fields that does not hold).
    """
    return read_rig(path, RIG_KIND, RIG_CONSTRAINTS, RigConfig)


def save_rig(path: str | os.PathLike[str], config: RigConfig, card: dict[str, Any] | None = None) -> Path:
    """Write ``config`` (and a ``card``) as a radar rig file (JSON, atomic); returns the path."""
    return save_rig_file(path, RIG_KIND, config.to_params(), card)


def default_rig_path() -> Path:
    """The shipped calibrated rig, ``models/radar_rig.json`` (package ``sensor_envs.models``)."""
    return default_model_path("radar_rig.json")
