"""A reference Neato lidar "rig": a simulated sensor richer than the learned model.

It stands in for recorded scans when no real data is at hand, and is the ground truth of the
recovery tests (its per-bearing bias and blocked bearings are known). Its default effects were set
from the real log ``neato_mar27_train.npz`` (``python docs/history/scripts/real_neato_report.py --data
../shared/data/real`` prints the real and rig statistics side by side; the figures measured when each
effect was added are in the documentation, concepts/rigs.md):

* per-bearing bias ``b_k ~ Normal(3.8 mm, 7.6 mm)``;
* 26 bearings blocked by the casing's posts (they never return);
* noise standard deviation growing with range: a table per 0.5 m range bin, plus ``k_far * (r - 4)^2``
  past 4 m;
* dropout ``p_null = logistic(-4.03 + 1.38 r + 1.36 alpha)`` (``r`` [m], ``alpha`` [rad]), independent per
  reading by default (``null_rho = 0``). With ``null_rho > 0``, :meth:`NeatoRig.record` draws each pose and
  bearing's null probability from ``Beta(p_null c, (1 - p_null) c)``, ``c = 1 / null_rho - 1`` (persistent
  nulls, but not along the bearings: the copula below does that). :meth:`NeatoRig.measure` (one scan, no pose
  identity) uses ``p_null`` itself;
* spurious far returns near the post bearings: a share ``spur_prone`` (9 %) of the cells within
  ``spur_window`` (15) bearings of a post are prone, and read ``Normal(16.9 m, 0.1 m)`` in a fraction
  ``Uniform(0.4, 1)`` of their readings;
* 1 mm range quantisation;
* pose error: ``Normal(0, 1.77 cm)`` per axis (2.5 cm rms) and ``Normal(0, 2 deg)`` in heading,
  fixed per pose; map error: segment end points moved by ``Normal(0, 1 cm)``.

Effects off by default, set by a calibrated rig file (``sensor-envs calibrate lidar``, shipped as
``models/neato_rig.json``; :meth:`NeatoRig.from_file` / :meth:`NeatoRig.to_file`):

* ``null_bearing_logit`` ``(K,)``: the unit's per-bearing offsets of logit ``p_null``;
* ``null_cell_corr``, ``null_arc``: persistent nulls by a Gaussian copula: a reading is null when
  ``sqrt(c) u + sqrt(1 - c) e < Phi^-1(p_null)``, ``u`` a per-cell standard normal shared by the cell's
  readings, ``e`` per reading, ``c = null_cell_corr``; the null rate stays ``p_null`` on average and cells
  become all-or-nothing as ``c -> 1``. ``u`` is correlated along the bearings of a pose by a Gaussian kernel
  of ``null_arc`` bearings (standard deviation), so persistent nulls come in arcs. Unlike ``null_rho`` (a Beta
  draw) it uses a fixed number of normal draws, so simulations with common random numbers change
  smoothly with the parameters (simulation-based calibration);
* ``spur_bearing_weight`` ``(K,)``: relative proneness of each bearing to spurious far returns; a cell is
  prone with probability ``min(spur_prone * weight, 1)`` instead of ``spur_prone`` within ``spur_window`` of
  a post;
* ``null_range_knots`` / ``null_range_logit`` and ``null_incidence_knots`` / ``null_incidence_logit``:
  piecewise-linear tables [m -> logit] and [rad -> logit] ADDED to the linear law of logit ``p_null``
  (constant beyond the end knots), for a null rate that is not logistic-linear;
* ``null_bearing_range_slope`` ``(K,)``: per-bearing slopes [logit / m] of logit ``p_null`` versus the range
  about :data:`NULL_SLOPE_CENTRE` (added to the shared range table): how fast the null rate rises with the
  range, per bearing;
* ``spur_range_knots`` / ``spur_range_weight``: a piecewise-linear factor [m -> 1] on the probability
  that a cell is spurious-prone, by its true range (range ``inf``, no hit, takes the last weight);
* ``spur_near_range``: the spurious-prone cells lie nearer than this true range [m] (0: no cut); with it,
  ``spur_bearing_weight`` is a per-bearing rate on the near cells over ``spur_prone``
  (:func:`sensor_envs.lidar.calibrate.fit_spur_near_law`);
* ``pose_sd_spread``: the pose error's standard deviations ``pose_sd`` are multiplied per pose by
  ``exp(pose_sd_spread * z)``, ``z`` a standard normal per pose (a log-normal scale mixture: poses either
  precise or clearly off);
* ``bias_range_knots`` / ``bias_range`` and ``bias_incidence_knots`` / ``bias_incidence``: piecewise-linear
  tables [m -> m] and [rad -> m] of a range bias shared by all bearings, added to the per-bearing bias
  (constant beyond the end knots);
* ``out_cell_rate``, ``out_cell_arc``: outlying cells, whose ray meets a surface the map lacks or
  passes a gap the map closes: a share ``out_cell_rate`` of a pose's hit cells, chosen by a unit normal field
  smoothed over ``out_cell_arc`` bearings (as the persistent nulls), read around a true range drawn
  uniformly on ``[0, max_range]`` instead of the map's.

Frames and units: metres and radians; bearings counter-clockwise from the sensor's x axis.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.geometry import as_segments, raycast_pose, sample_free_poses
from sensor_envs.inputs import InputError
from sensor_envs.lidar.log import LidarLog, log_from_arrays
from sensor_envs.modelio import (
    Constraint,
    Interval,
    Numbers,
    default_model_path,
    load_rig_file,
    read_rig,
    save_rig_file,
    validate_params,
)

__all__ = ["NeatoRig", "POST_BEARINGS", "BLOCKED_BEARINGS", "RIG_KIND", "RIG_CONSTRAINTS", "sample_free_poses"]

RIG_KIND = "neato_rig"
"""``kind`` of a Neato rig parameter file."""
SHIPPED_RIG = "neato_rig.json"
"""File name of the shipped calibrated rig in ``models/``."""

BLOCKED_BEARINGS = tuple(
    list(range(30, 33)) + list(range(81, 86)) + list(range(165, 171)) + list(range(250, 257)) + list(range(326, 331))
)
"""Bearing indices (degrees) that never return in the real data (the casing's posts)."""
POST_BEARINGS = (31.0, 83.0, 167.5, 253.0, 328.0)
"""Centres of the blocked bearing groups [deg]."""
_SIGMA_KNOTS_R = (0.0, 0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.25, 4.0)
_SIGMA_KNOTS = (0.0002, 0.0002, 0.0007, 0.0034, 0.0095, 0.0293, 0.0379, 0.0488, 0.06)


NULL_SLOPE_CENTRE = 2.0
"""Range [m] about which the per-bearing slopes ``null_bearing_range_slope`` act (mid-range of the real cells)."""


def _logistic(z: NDArray[np.float64]) -> NDArray[np.float64]:
    return 1.0 / (1.0 + np.exp(-z))


_FINITE = Interval(-1e6, 1e6)
_NONNEG = Interval(0, 1e4)  # rig values are metres, rates and knots: 1e4 bounds them all (sane magnitudes)
RIG_CONSTRAINTS: dict[str, list[Constraint]] = {
    "unit_seed": [Interval(0, None, integer=True)],
    "n_bearings": [Interval(1, 100_000, integer=True)],
    "max_range": [Interval(0, None, open_low=True)],
    "bias_mean": [Interval(-1, 1)],
    "bias_sd": [Interval(0, 1)],
    "blocked": [Numbers(Interval(0, None, integer=True), min_length=0)],
    "null_logit": [Numbers(_FINITE, length=3)],
    "null_bearing_logit": [Numbers(Interval(-50, 50), min_length=0)],
    "null_rho": [Interval(0, 1, open_high=True)],
    "null_cell_corr": [Interval(0, 1, open_high=True)],
    "null_arc": [Interval(0, 180)],
    "k_far": [_NONNEG],
    "sigma_knots_r": [Numbers(_NONNEG, min_length=2, increasing=True)],
    "sigma_knots": [Numbers(Interval(0, 10, open_low=True), min_length=2)],
    "spur_window": [Interval(0, 180)],
    "spur_prone": [Interval(0, 1)],
    "spur_bearing_weight": [Numbers(Interval(0, 1e4), min_length=0)],
    "null_range_knots": [Numbers(_NONNEG, min_length=0, increasing=True)],
    "null_range_logit": [Numbers(Interval(-50, 50), min_length=0)],
    "null_incidence_knots": [Numbers(_NONNEG, min_length=0, increasing=True)],
    "null_incidence_logit": [Numbers(Interval(-50, 50), min_length=0)],
    "null_bearing_range_slope": [Numbers(Interval(-50, 50), min_length=0)],
    "spur_range_knots": [Numbers(_NONNEG, min_length=0, increasing=True)],
    "spur_range_weight": [Numbers(Interval(0, 1e4), min_length=0)],
    "spur_near_range": [_NONNEG],
    "pose_sd_spread": [Interval(0, 5)],
    "bias_range_knots": [Numbers(_NONNEG, min_length=0, increasing=True)],
    "bias_range": [Numbers(Interval(-1, 1), min_length=0)],
    "bias_incidence_knots": [Numbers(_NONNEG, min_length=0, increasing=True)],
    "bias_incidence": [Numbers(Interval(-1, 1), min_length=0)],
    "out_cell_rate": [Interval(0, 1, open_high=True)],
    "out_cell_arc": [Interval(0, 180)],
    "spur_frac": [Numbers(Interval(0, 1), length=2)],
    "spur_value": [Numbers(_NONNEG, length=2)],
    "quantum": [Interval(0, 1, open_low=True)],
    "pose_sd": [Numbers(_NONNEG, length=2)],
    "map_sd": [_NONNEG],
}
"""Accepted values of every :class:`NeatoRig` parameter (checked at construction and when a rig file loads)."""


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Circular runs ``(start, length)`` of True entries of a 1-D mask (a run may wrap past the end)."""
    n = mask.size
    if not mask.any():
        return []
    if mask.all():
        return [(0, n)]
    start = int(np.flatnonzero(~mask)[0]) + 1  # begin just after a False entry: no run is cut
    m = np.roll(mask, -start)
    d = np.diff(np.r_[0, m.astype(np.int8), 0])
    return [
        ((int(a) + start) % n, int(b - a)) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True)
    ]


def smooth_along_bearings(z: NDArray[np.float64], width: float) -> NDArray[np.float64]:
    """Unit-variance circular Gaussian smoothing of white noise ``z (..., K)`` along the last axis.

    ``width`` is the kernel's standard deviation [bearing steps]; ``0`` returns ``z``. The result is a
    stationary field whose neighbouring bearings are correlated over about ``width`` steps.
    """
    if width <= 0:
        return z
    k = z.shape[-1]
    d = (np.arange(k) + k // 2) % k - k // 2
    ker = np.exp(-0.5 * (d / width) ** 2)
    ker /= np.sqrt((ker**2).sum())
    return np.fft.irfft(np.fft.rfft(z, axis=-1) * np.fft.rfft(ker), n=k, axis=-1)


@dataclass(frozen=True)
class NeatoRig:
    """Reference Neato lidar: 360 bearings, effects calibrated on real data (see the module docstring).

    The unit's own properties (per-bearing bias, spurious-prone cells) come from ``unit_seed``;
    the noise of each recording from the generator passed to :meth:`record` / :meth:`measure`.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import NeatoRig
        >>> from sensor_envs.maps import load_map
        >>> rig = NeatoRig(unit_seed=0)
        >>> log, truth = rig.record(load_map("seed_room").segments, np.random.default_rng(0), n_poses=2, repeats=3)
        >>> log.ranges.shape  # poses x bearings x repeats [m], 0 = null
        (2, 360, 3)
    """

    unit_seed: int = 0
    n_bearings: int = 360
    max_range: float = 5.0
    bias_mean: float = 0.0038
    bias_sd: float = 0.0076
    blocked: tuple[int, ...] = BLOCKED_BEARINGS
    null_logit: tuple[float, float, float] = (-4.03, 1.38, 1.36)
    null_bearing_logit: tuple[float, ...] = ()
    null_rho: float = 0.0
    null_cell_corr: float = 0.0
    null_arc: float = 0.0
    k_far: float = 0.05
    sigma_knots_r: tuple[float, ...] = _SIGMA_KNOTS_R
    sigma_knots: tuple[float, ...] = _SIGMA_KNOTS
    spur_window: float = 15.0
    spur_bearing_weight: tuple[float, ...] = ()
    spur_prone: float = 0.09
    spur_frac: tuple[float, float] = (0.4, 1.0)
    spur_value: tuple[float, float] = (16.9, 0.1)
    quantum: float = 0.001
    pose_sd: tuple[float, float] = (0.0177, float(np.deg2rad(2.0)))
    map_sd: float = 0.01
    null_range_knots: tuple[float, ...] = ()
    null_range_logit: tuple[float, ...] = ()
    null_incidence_knots: tuple[float, ...] = ()
    null_incidence_logit: tuple[float, ...] = ()
    null_bearing_range_slope: tuple[float, ...] = ()
    spur_range_knots: tuple[float, ...] = ()
    spur_range_weight: tuple[float, ...] = ()
    spur_near_range: float = 0.0
    pose_sd_spread: float = 0.0
    out_cell_rate: float = 0.0
    out_cell_arc: float = 0.0
    bias_range_knots: tuple[float, ...] = ()
    bias_range: tuple[float, ...] = ()
    bias_incidence_knots: tuple[float, ...] = ()
    bias_incidence: tuple[float, ...] = ()
    bearings: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        validate_params(self.params(), RIG_CONSTRAINTS)
        for name, msg in self._relation_errors():
            raise InputError(f"{name}: {msg}")
        object.__setattr__(self, "bearings", np.deg2rad(np.arange(self.n_bearings) * 360.0 / self.n_bearings))

    def _relation_errors(self) -> list[tuple[str, str]]:
        """``(field, message)`` for values that are fine alone but inconsistent with the others."""
        bad = []
        if self.null_bearing_logit and len(self.null_bearing_logit) != self.n_bearings:
            bad.append(("null_bearing_logit", f"has {len(self.null_bearing_logit)} values, expected 0 or n_bearings"))
        n_slopes = len(self.null_bearing_range_slope)
        if n_slopes and n_slopes != self.n_bearings:
            bad.append(("null_bearing_range_slope", f"has {n_slopes} values, expected 0 or n_bearings"))
        if self.spur_bearing_weight and len(self.spur_bearing_weight) != self.n_bearings:
            bad.append(("spur_bearing_weight", f"has {len(self.spur_bearing_weight)} values, expected 0 or n_bearings"))
        if len(self.sigma_knots) != len(self.sigma_knots_r):
            bad.append(("sigma_knots", f"has {len(self.sigma_knots)} values, sigma_knots_r {len(self.sigma_knots_r)}"))
        for knots, values in (
            ("null_range_knots", "null_range_logit"),
            ("null_incidence_knots", "null_incidence_logit"),
            ("spur_range_knots", "spur_range_weight"),
            ("bias_range_knots", "bias_range"),
            ("bias_incidence_knots", "bias_incidence"),
        ):
            nk, nv = len(getattr(self, knots)), len(getattr(self, values))
            if nk != nv or nk == 1:
                bad.append((values, f"has {nv} values, {knots} {nk} (equal, and 0 or >= 2)"))
        if any(b >= self.n_bearings for b in self.blocked):
            bad.append(("blocked", f"holds an index >= n_bearings ({self.n_bearings})"))
        if self.spur_frac[0] > self.spur_frac[1]:
            bad.append(("spur_frac", f"low {self.spur_frac[0]} > high {self.spur_frac[1]}"))
        return bad

    # ------------------------------------------------------------------------------------ rig files
    def params(self) -> dict[str, Any]:
        """The rig's parameters ``name -> value`` (what a rig file holds)."""
        return {k: getattr(self, k) for k in RIG_CONSTRAINTS}

    def to_file(self, path: str | os.PathLike[str], card: dict[str, Any] | None = None) -> Path:
        """Write the parameters (and a ``card``: what they were calibrated against) to a JSON rig file."""
        return save_rig_file(path, RIG_KIND, self.params(), card)

    @classmethod
    def from_file(cls, path: str | os.PathLike[str] | None = None) -> NeatoRig:
        """The rig of a rig file (default: the shipped calibrated ``models/neato_rig.json``).

        Raises:
            ModelFileError: naming the file and the field at fault (missing parameters take the defaults).
        """
        path = default_model_path(SHIPPED_RIG) if path is None else Path(path)
        return read_rig(path, RIG_KIND, RIG_CONSTRAINTS, cls)[0]

    @staticmethod
    def card_of(path: str | os.PathLike[str] | None = None) -> dict[str, Any]:
        """The card of a rig file (default: the shipped one): what it was calibrated against, discrepancies."""
        path = default_model_path(SHIPPED_RIG) if path is None else Path(path)
        return load_rig_file(path, RIG_KIND, RIG_CONSTRAINTS)[1]

    # ------------------------------------------------------------------------------ unit properties
    def bias(self) -> NDArray[np.float64]:
        """Per-bearing range bias ``(K,)`` [m] of this unit."""
        return np.random.default_rng([self.unit_seed, 1]).normal(self.bias_mean, self.bias_sd, self.n_bearings)

    def blocked_mask(self) -> NDArray[np.bool_]:
        """``(K,)`` True at bearings blocked by the casing's posts."""
        m = np.zeros(self.n_bearings, dtype=bool)
        m[np.asarray(self.blocked, dtype=int) % self.n_bearings] = True
        return m

    def post_bearings(self) -> NDArray[np.float64]:
        """Centres [deg] of the groups of adjacent blocked bearings (the casing's posts)."""
        step = 360.0 / self.n_bearings
        return np.array([((a + (n - 1) / 2.0) * step) % 360.0 for a, n in _runs(self.blocked_mask())])

    def post_distance(self) -> NDArray[np.float64]:
        """``(K,)`` angular distance [deg] of each bearing to the nearest post (inf without posts)."""
        posts = self.post_bearings()
        if posts.size == 0:
            return np.full(self.n_bearings, np.inf)
        deg = np.rad2deg(self.bearings)
        return np.abs((deg[:, None] - posts[None] + 180.0) % 360.0 - 180.0).min(axis=1)

    def near_posts(self) -> NDArray[np.bool_]:
        """``(K,)`` True at unblocked bearings within ``spur_window`` degrees of a post."""
        return (self.post_distance() <= self.spur_window) & ~self.blocked_mask()

    def spur_prone_per_bearing(self) -> NDArray[np.float64]:
        """``(K,)`` probability that a cell at each bearing is prone to spurious far returns."""
        if self.spur_bearing_weight:
            w = np.asarray(self.spur_bearing_weight, dtype=np.float64)
            return np.where(self.blocked_mask(), 0.0, np.minimum(self.spur_prone * w, 1.0))
        return np.asarray(self.near_posts() * self.spur_prone, dtype=np.float64)

    def has_spur_range_law(self) -> bool:
        """True when the spurious-prone probability depends on the range (a table or a near-range cut)."""
        return bool(self.spur_range_knots) or self.spur_near_range > 0

    def spur_range_factor(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        """Factor [1] on the spurious-prone probability of a cell at true range ``r`` [m].

        The table ``spur_range_knots -> spur_range_weight`` (1 without one), times 0 at ``r >= spur_near_range``
        when that cut is set; no hit (``inf`` / NaN) counts as infinitely far.
        """
        rr = np.minimum(np.where(np.isnan(r), np.inf, r), 1e9)
        out = (
            np.interp(rr, self.spur_range_knots, self.spur_range_weight)
            if self.spur_range_knots
            else np.ones(np.shape(r))
        )
        if self.spur_near_range > 0:
            out = np.where(rr < self.spur_near_range, out, 0.0)
        return out

    def bias_shape(self, r: NDArray[np.float64], alpha: NDArray[np.float64]) -> NDArray[np.float64]:
        """Range bias [m] shared by all bearings at true range ``r`` [m] and incidence ``alpha`` [rad] (tables)."""
        out = np.zeros(np.broadcast_shapes(np.shape(r), np.shape(alpha)))
        if self.bias_range_knots:
            out = out + np.interp(np.where(np.isfinite(r), r, 0.0), self.bias_range_knots, self.bias_range)
        if self.bias_incidence_knots:
            out = out + np.interp(np.nan_to_num(alpha), self.bias_incidence_knots, self.bias_incidence)
        return out

    def sigma(self, r: NDArray[np.float64]) -> NDArray[np.float64]:
        """Noise standard deviation [m] at true range ``r`` [m]."""
        return np.interp(r, self.sigma_knots_r, self.sigma_knots) + self.k_far * np.maximum(r - 4.0, 0.0) ** 2

    def p_null(self, r: NDArray[np.float64], alpha: NDArray[np.float64]) -> NDArray[np.float64]:
        """Dropout probability at true range ``r`` [m] and incidence ``alpha`` [rad] (1 if no hit/blocked)."""
        return np.where(np.isfinite(r) & ~self.blocked_mask(), _logistic(self.null_linear(r, alpha)), 1.0)

    def null_linear(self, r: NDArray[np.float64], alpha: NDArray[np.float64]) -> NDArray[np.float64]:
        """Logit of the dropout probability ``(..., K)`` before the per-cell effect (any value where no hit)."""
        z = self.null_logit[0] + self.null_shape(r, alpha)
        if self.null_bearing_logit:
            z = z + np.asarray(self.null_bearing_logit, dtype=np.float64)
        if self.null_bearing_range_slope:
            rr = np.where(np.isfinite(r), r, 0.0)
            z = z + np.asarray(self.null_bearing_range_slope, dtype=np.float64) * (rr - NULL_SLOPE_CENTRE)
        return np.asarray(z, dtype=np.float64)

    def null_shape(self, r: NDArray[np.float64], alpha: NDArray[np.float64]) -> NDArray[np.float64]:
        """The range and incidence part of logit ``p_null`` (no intercept, no bearing offsets; 0-filled where no hit).

        ``c1 r + c2 alpha`` plus the piecewise-linear tables ``null_range_*`` and ``null_incidence_*`` when set.
        """
        _, c1, c2 = self.null_logit
        rr, aa = np.where(np.isfinite(r), r, 0.0), np.nan_to_num(alpha)
        z = c1 * rr + c2 * aa
        if self.null_range_knots:
            z = z + np.interp(rr, self.null_range_knots, self.null_range_logit)
        if self.null_incidence_knots:
            z = z + np.interp(aa, self.null_incidence_knots, self.null_incidence_logit)
        return np.asarray(z, dtype=np.float64)

    # ------------------------------------------------------------------------------------ readings
    def cell_p_null(
        self, r: NDArray[np.float64], alpha: NDArray[np.float64], rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """One null probability per cell ``(..., K)``.

        With ``null_cell_corr = c > 0``: ``Phi((Phi^-1(p_null) - sqrt(c) u) / sqrt(1 - c))``, ``u`` a unit
        normal field smoothed along the bearings over ``null_arc`` steps (mean over cells: ``p_null``);
        else, with ``null_rho > 0``, ``Beta`` with mean :meth:`p_null` and intra-cell correlation
        ``null_rho``; else :meth:`p_null`.
        """
        p = self.p_null(r, alpha)
        if self.null_cell_corr > 0:
            from scipy.special import ndtr, ndtri

            u = smooth_along_bearings(rng.standard_normal(np.shape(p)), self.null_arc)
            c = self.null_cell_corr
            q = ndtr((ndtri(np.clip(p, 1e-12, 1 - 1e-12)) - np.sqrt(c) * u) / np.sqrt(1 - c))
            return np.where(p < 1.0, q, 1.0)
        if self.null_rho <= 0:
            return p
        c = 1 / self.null_rho - 1
        q = np.clip(p, 1e-6, 1 - 1e-6)
        return np.where((p > 0) & (p < 1), rng.beta(q * c, (1 - q) * c), p)

    def _readings(
        self,
        r: NDArray[np.float64],
        alpha: NDArray[np.float64],
        p_spur: NDArray[np.float64],
        rng: np.random.Generator,
        p_null: NDArray[np.float64] | None = None,
    ) -> NDArray[np.float64]:
        """Readings ``(..., K, R)`` [m], 0 = null, from true features ``(..., K, 1)`` and spurious rates.

        ``p_null (..., K)`` overrides :meth:`p_null` (per-cell null probabilities).
        """
        shape = np.broadcast_shapes(r.shape, p_spur.shape)
        u = rng.random(shape)
        rr = np.where(np.isfinite(r), r, 0.0)
        x = rr + self.bias()[:, None] + self.sigma(rr) * rng.standard_normal(shape)
        if self.bias_range_knots or self.bias_incidence_knots:
            x = x + self.bias_shape(rr, alpha)
        spur = rng.normal(*self.spur_value, size=shape)
        pn = (self.p_null(r[..., 0], alpha[..., 0]) if p_null is None else p_null)[..., None]
        x = np.where(u < pn, 0.0, np.where(u < pn + (1 - pn) * p_spur, spur, x))
        x = np.where(x > 0, np.maximum(np.round(x / self.quantum) * self.quantum, self.quantum), 0.0)
        return np.where((x > self.max_range) & (x < self.spur_value[0] - 1.0), 0.0, x)

    def measure(
        self, nominal_range: NDArray[np.float64], incidence: NDArray[np.float64], rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """One scan ``(K,)`` [m], NaN = null, from true features (a :class:`~sensor_envs.lidar.sensors.LidarSensor`).

        A scan has no pose identity, so each near-post bearing is spurious with the average rate; with
        ``null_cell_corr > 0`` each scan draws its own per-cell null effects (the marginal null rate).
        """
        r = np.asarray(nominal_range, float)
        p_spur = self.spur_prone_per_bearing() * float(np.mean(self.spur_frac))
        if self.has_spur_range_law():
            p_spur = np.minimum(p_spur * self.spur_range_factor(r), 1.0)
        a = np.asarray(incidence, float)
        pn = self.cell_p_null(r, a, rng) if self.null_cell_corr > 0 else None
        x = self._readings(r[:, None], a[:, None], p_spur[:, None], rng, pn)[:, 0]
        return np.where(x == 0, np.nan, x)

    def record(
        self,
        map_segments: ArrayLike,
        rng: np.random.Generator,
        *,
        n_poses: int = 30,
        repeats: int = 200,
        poses: ArrayLike | None = None,
    ) -> tuple[LidarLog, dict[str, NDArray[np.float64]]]:
        """Record a static-pose log, as the real data set was made.

        Args:
            map_segments: ``(M, 2, 2)`` nominal map [m] (the world is this map moved by ``map_sd``).
            rng: generator of poses, map error and noise.
            n_poses: number of poses drawn in free space (ignored when ``poses`` is given).
            repeats: readings per pose and bearing.
            poses: optional ``(P, 3)`` TRUE poses.

        Returns:
            The log (approximate poses, nominal map; ``ranges (P, K, repeats)``) and the truth:
            ``true_poses (P, 3)``, ``true_map (M, 2, 2)``, ``bias (K,)``, ``blocked (K,)``, ``p_spur (P, K)``.
        """
        nominal = as_segments(map_segments, name="map_segments")
        true_map = nominal + rng.normal(0.0, self.map_sd, nominal.shape)
        true_poses = (
            sample_free_poses(nominal, n_poses, rng)
            if poses is None
            else np.atleast_2d(np.asarray(poses, dtype=np.float64))
        )
        r, a, _ = raycast_pose(true_poses, self.bearings, true_map, self.max_range)
        if self.out_cell_rate > 0:  # drawn only then: rigs without outlying cells keep their random stream
            from scipy.special import ndtri

            z = smooth_along_bearings(rng.standard_normal(r.shape), self.out_cell_arc)
            far = rng.uniform(0.0, self.max_range, r.shape)
            r = np.where(np.isfinite(r) & (z < ndtri(self.out_cell_rate)), far, r)
        unit = np.random.default_rng([self.unit_seed, 2])  # prone cells belong to the unit and the place
        prone_p = self.spur_prone_per_bearing()[None]
        if self.has_spur_range_law():
            prone_p = np.minimum(prone_p * self.spur_range_factor(r), 1.0)
        prone = rng.random(r.shape) < prone_p
        p_spur = np.where(prone, unit.uniform(*self.spur_frac, r.shape), 0.0)
        pn = self.cell_p_null(r, a, rng)
        x = self._readings(
            r[..., None], a[..., None], np.broadcast_to(p_spur[..., None], r.shape + (repeats,)), rng, pn
        )
        err = np.column_stack(
            [rng.normal(0, self.pose_sd[0], (len(true_poses), 2)), rng.normal(0, self.pose_sd[1], len(true_poses))]
        )
        if self.pose_sd_spread > 0:  # drawn last: rigs without the spread keep their random stream
            err = err * np.exp(self.pose_sd_spread * rng.standard_normal(len(true_poses)))[:, None]
        approx = true_poses + err
        approx[:, 2] = (approx[:, 2] + np.pi) % (2 * np.pi) - np.pi
        log = log_from_arrays(x, self.bearings, approx, nominal, source=f"NeatoRig(unit_seed={self.unit_seed})")
        truth = {
            "true_poses": true_poses,
            "true_map": true_map,
            "bias": self.bias(),
            "blocked": self.blocked_mask(),
            "p_spur": p_spur,
        }
        return log, truth
