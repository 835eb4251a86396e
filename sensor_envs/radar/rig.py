"""A reference radar "rig": a simulated object-list radar richer than the KDE model.

Used when no recording is at hand and for time series (Astyx has none). Per radar cycle and target:

* **reflection point** on the visible contour, depending on aspect: the face most turned towards
  the sensor dominates; the point is that face's midpoint (or, with ``reflection_center`` < 0.5, a
  point nearer the face's end closer to the sensor) moved along the face by a persistent, slowly
  varying fraction (so it wanders as the aspect changes); a share ``corner_share`` of cycles
  reflects at the closest corner;
* **latency**: the measurement describes the target ``latency`` seconds ago;
* **polar noise**: range std ``sigma_range``, azimuth std ``sigma_azimuth`` growing quadratically
  towards the field-of-view edge (``edge_gain``);
* **tracker smoothing**: the reported error (measured - true reflection point) is exponentially
  smoothed, ``e_t = rho e_{t-1} + sqrt(1 - rho^2) n_t`` with ``rho = exp(-cycle_time / tracker_tau)``,
  so consecutive outputs are correlated; the tracker restarts after a miss;
* **detection probability** vs range (logistic fall-off at ``max_range``), azimuth (zero outside the
  field of view, lower near its edge; a calibrated table of ``|azimuth|`` or, with
  ``detect_azimuth_signed``, of the signed azimuth: left and right may differ) and occlusion
  (``geometry.occluded_fraction`` times a loss, constant or, with ``occlusion_loss_table``, a table over
  range): object loss;
* **clutter**: Poisson(``clutter_rate``) detections per cycle, uniform in range and azimuth.

**Offset mixture law** (optional, ``offset_mixture_*``; what ``calibrate radar --offset-law mixture``
fits): the measured position is the closest corner of the (latency-delayed) box plus an offset drawn
from a Gaussian mixture per corner-range bin in the corner's polar frame (radial, OUTWARD
cross-range: away from the boresight on either side). The mixture component persists from cycle to
cycle with probability ``exp(-cycle_time / reflection_tau)`` (else it is drawn afresh from the bin's
weights) and its standard-normal draw follows the tracker's AR(1) process, so the stationary law of
one cycle is exactly the mixture and consecutive outputs stay correlated. The reflection point, its
fraction along the face and the polar noise tables then only place the point whose range and
azimuth the detection probability reads. With ``offset_mixture_min_range`` the mixture applies from
that corner range on only; nearer boxes keep the reflection-point law (its own tracker error, driven
by the same normal draws, so the random stream is the same).

**Mounting yaw error** (``azimuth_bias``): every target detection is finally rotated about the sensor
by it (:meth:`RadarRig.mounted`); 0 (the default, and every older rig file) leaves them as they are.

**Scene law** (optional, ``scene_*``; what ``calibrate radar --scene`` fits to real reference boxes,
:mod:`sensor_envs.radar.scene_law`): the boxes a rig log records are drawn from shares of x bins and,
per x bin, of y bins and heading bins, instead of the generic lane traffic. It is not a property of the
sensor but of the data a model learns from: the KDE's state is the closest corner, so its law at a corner
position is an average over the boxes (headings, sizes) the log had there.

The sensor sits at the origin of its frame (x forward, y left); targets are boxes moving in that
frame (:func:`generate_scenario`). All lengths in metres, angles in radians, times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from sensor_envs.geometry import (
    closest_corner,
    from_frame,
    from_polar_frame,
    occluded_fraction,
    rectangle_corners,
)
from sensor_envs.inputs import InputError
from sensor_envs.radar.log import REQUIRED_COLUMNS, RadarLog
from sensor_envs.radar.rig_config import (
    RIG_CONSTRAINTS,
    RIG_KIND,
    SCENE_TABLES,
    RigConfig,
    default_rig_path,
    load_rig,
    save_rig,
)

__all__ = [
    "RigConfig",
    "RIG_CONSTRAINTS",
    "RIG_KIND",
    "SCENE_TABLES",
    "load_rig",
    "save_rig",
    "default_rig_path",
    "Scenario",
    "generate_scenario",
    "scene_boxes",
    "RadarRig",
    "OffsetMixture",
    "record_rig_log",
]


@dataclass(frozen=True)
class Scenario:
    """Moving target boxes over ``n_cycles`` radar cycles (sensor frame, sensor at the origin).

    Attributes:
        t: ``(n_cycles,)`` times [s].
        boxes: ``(n_cycles, n_targets, 5)`` ``x, y, heading, length, width`` [m, rad].
        velocity: ``(n_targets, 2)`` constant velocity [m/s] in the sensor frame.
    """

    t: NDArray[np.float64]
    boxes: NDArray[np.float64]
    velocity: NDArray[np.float64]


def generate_scenario(
    n_targets: int, n_cycles: int, cycle_time: float, rng: np.random.Generator, config: RigConfig | None = None
) -> Scenario:
    """Random traffic ahead of the sensor: the generic lane traffic, or the rig's calibrated scene law.

    **Generic lane traffic** (``config`` without a scene law, or ``None``; the random stream of every
    older rig file): lane vehicles (80 %) drive along x on lanes ``y in {-7, -3.5, 0, 3.5, 7}`` m with
    relative speed ~N(0, 1.5) m/s; the others cross with headings uniform in ``[-pi, pi)`` at 0.5-3 m/s.
    Vehicles are 3.8-5 m long, 1.7-2.0 m wide, starting 5-100 m ahead.

    **Scene law** (``config.scene_*``, what ``calibrate radar --scene`` fits to the real reference
    boxes): see :func:`scene_boxes`; each target moves relative to the sensor along its x axis (the
    ego driving past parked and queued cars) at ~N(0, ``scene_speed_std``) m/s, and it is at the drawn
    place at a cycle drawn uniformly in the sequence, so every cycle's boxes follow the law up to that
    drift in x (y and the heading are kept exactly).
    """
    if config is not None and config.scene_x_edges is not None:
        return _scene_scenario(config, n_targets, n_cycles, cycle_time, rng)
    lane = rng.random(n_targets) < 0.8
    y0 = np.where(lane, rng.choice([-7.0, -3.5, 0.0, 3.5, 7.0], n_targets), rng.uniform(-25, 25, n_targets))
    x0 = rng.uniform(5.0, 100.0, n_targets)
    heading = np.where(lane, rng.normal(0.0, 0.03, n_targets), rng.uniform(-np.pi, np.pi, n_targets))
    speed = np.where(lane, rng.normal(0.0, 1.5, n_targets), rng.uniform(0.5, 3.0, n_targets))
    dims = np.stack([rng.uniform(3.8, 5.0, n_targets), rng.uniform(1.7, 2.0, n_targets)], axis=1)
    vel = np.stack([np.cos(heading), np.sin(heading)], axis=1) * speed[:, None]
    return _moving_boxes(np.stack([x0, y0], axis=1), heading, vel, dims, np.zeros(n_targets), n_cycles, cycle_time)


def scene_boxes(config: RigConfig, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``n`` boxes ``(n, 5)`` ``x, y, heading, length, width`` [m, rad] drawn from the rig's scene law.

    x from its bins' shares (uniform inside a bin); y and the heading (modulo pi) from the shares of
    their bins in that x bin (uniform inside); length and width uniform in their ranges.

    Raises:
        ValueError: when ``config`` has no scene law.
    """
    c = config
    if c.scene_x_edges is None:
        raise InputError("scene_x_edges: the rig has no scene law (calibrate radar --scene fits one)")
    x_edges = np.asarray(c.scene_x_edges, dtype=np.float64)
    n_x = x_edges.size - 1
    x_weights = np.asarray(c.scene_x_weights, dtype=np.float64)
    bx = rng.choice(n_x, n, p=x_weights / x_weights.sum())
    cols = [_uniform_in_bins(x_edges, bx, rng)]
    for edges_name, weights_name in (
        ("scene_y_edges", "scene_y_weights"),
        ("scene_heading_edges", "scene_heading_weights"),
    ):
        edges = np.asarray(getattr(c, edges_name), dtype=np.float64)
        w = np.asarray(getattr(c, weights_name), dtype=np.float64).reshape(n_x, -1)
        cdf = np.cumsum(w, axis=1) / w.sum(axis=1, keepdims=True)
        b = np.minimum((rng.random(n)[:, None] > cdf[bx]).sum(axis=1), edges.size - 2)
        cols.append(_uniform_in_bins(edges, b, rng))
    lo_l, hi_l = np.asarray(c.scene_length_range, dtype=np.float64)
    lo_w, hi_w = np.asarray(c.scene_width_range, dtype=np.float64)
    cols += [rng.uniform(lo_l, hi_l, n), rng.uniform(lo_w, hi_w, n)]
    return np.stack(cols, axis=1)


def _scene_scenario(c: RigConfig, n: int, n_cycles: int, cycle_time: float, rng: np.random.Generator) -> Scenario:
    """The scene law's scenario (:func:`generate_scenario`)."""
    box = scene_boxes(c, n, rng)
    vel = np.stack([rng.normal(0.0, c.scene_speed_std, n), np.zeros(n)], axis=1)  # along the sensor's x
    anchor = rng.integers(0, n_cycles, n) * cycle_time  # the time at which each target is at its drawn place
    return _moving_boxes(box[:, :2], box[:, 2], vel, box[:, 3:], anchor, n_cycles, cycle_time)


def _moving_boxes(
    xy: NDArray, heading: NDArray, vel: NDArray, dims: NDArray, anchor: NDArray, n_cycles: int, cycle_time: float
) -> Scenario:
    """Boxes of ``heading`` [rad] moving at velocity ``vel`` ``(n, 2)`` [m/s], at ``xy`` [m] at time ``anchor`` [s]."""
    t = np.arange(n_cycles, dtype=np.float64) * cycle_time
    pos = xy[None] + (t[:, None] - anchor[None, :])[:, :, None] * vel[None]
    n_targets = xy.shape[0]
    boxes = np.concatenate(
        [
            pos,
            np.broadcast_to(heading[None, :, None], (n_cycles, n_targets, 1)),
            np.broadcast_to(dims[None], (n_cycles, n_targets, 2)),
        ],
        axis=2,
    )
    return Scenario(t, boxes, vel)


def _reflection_geometry(box: NDArray[np.float64]) -> tuple[NDArray, NDArray, NDArray]:
    """Closest corner, and midpoint and edge vector of the face most turned to the sensor, each ``(n, 2)`` [m]."""
    corners = rectangle_corners(box[:, 0], box[:, 1], box[:, 2], box[:, 3], box[:, 4])  # (n, 4, 2)
    nxt = np.roll(corners, -1, axis=1)
    mid = 0.5 * (corners + nxt)
    centre = box[:, None, :2]
    normal = mid - centre
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    to_sensor = -mid / np.maximum(np.linalg.norm(mid, axis=-1, keepdims=True), 1e-9)
    face = np.argmax(np.sum(normal * to_sensor, axis=-1), axis=1)
    i = np.arange(box.shape[0])
    corner, _ = closest_corner(corners)
    return corner, mid[i, face], nxt[i, face] - corners[i, face]


def _reflection_point(
    box: NDArray[np.float64],
    frac: NDArray[np.float64],
    at_corner: NDArray[np.bool_] | None = None,
    center: float = 0.5,
    geometry: tuple[NDArray, NDArray, NDArray] | None = None,
) -> NDArray[np.float64]:
    """Reflection point ``(n, 2)`` [m] on the face most turned to the sensor.

    The point is ``frac`` (in [-0.5, 0.5], along the face's edge vector) of the face's length from
    the face's reference point: its midpoint for ``center = 0.5``, else the point ``center`` of the
    length from the face's end nearer the sensor. Rows where ``at_corner`` is true reflect at the
    box's closest corner instead. ``geometry``: :func:`_reflection_geometry` of ``box`` when the caller
    already has it.
    """
    corner, mid, edge = _reflection_geometry(box) if geometry is None else geometry
    pt = mid + frac[:, None] * edge
    if center != 0.5:  # move the reference point along the face towards its near end (0.5 - center) lengths
        a, b = mid - 0.5 * edge, mid + 0.5 * edge
        near_first = np.hypot(a[:, 0], a[:, 1]) <= np.hypot(b[:, 0], b[:, 1])
        towards_near = np.where(near_first[:, None], -edge, edge)
        pt = pt + (0.5 - center) * towards_near
    return pt if at_corner is None else np.where(at_corner[:, None], corner, pt)


def _tracker_ar1(err: NDArray, innov: NDArray, tracked: NDArray, rho: float) -> NDArray[np.float64]:
    """One cycle of the tracker's AR(1) error ``(n, 2)``.

    ``rho err + sqrt(1 - rho^2) innov`` where the target was ``tracked`` last cycle; the innovation alone
    where its track (re)starts.
    """
    return np.where(tracked[:, None], rho * err + np.sqrt(1 - rho**2) * innov, innov)


@dataclass(frozen=True)
class OffsetMixture:
    """The rig's offset mixture law as arrays (see :class:`RigConfig`'s ``offset_mixture_*``).

    Attributes:
        edges: ``(B + 1,)`` corner-range bin edges [m].
        weights: ``(B, K)`` component weights.
        means: ``(B, K, 2)`` means (radial, outward) [m].
        chol: ``(B, K, 2, 2)`` lower Cholesky factors [m].
        min_range: closest-corner range [m] from which the mixture applies (nearer: reflection-point law).
    """

    edges: NDArray[np.float64]
    weights: NDArray[np.float64]
    means: NDArray[np.float64]
    chol: NDArray[np.float64]
    min_range: float = 0.0

    @classmethod
    def from_config(cls, c: RigConfig) -> OffsetMixture | None:
        """The mixture of ``c``, or ``None`` for the reflection-point law."""
        if c.offset_mixture_edges is None or c.offset_mixture_weights is None:
            return None
        edges = np.asarray(c.offset_mixture_edges, dtype=np.float64)
        b = edges.size - 1
        w = np.asarray(c.offset_mixture_weights, dtype=np.float64).reshape(b, -1)
        k = w.shape[1]
        s = np.asarray(c.offset_mixture_scales, dtype=np.float64).reshape(b, k, 3)
        chol = np.zeros((b, k, 2, 2))
        chol[..., 0, 0], chol[..., 1, 0], chol[..., 1, 1] = s[..., 0], s[..., 1], s[..., 2]
        means = np.asarray(c.offset_mixture_means, dtype=np.float64).reshape(b, k, 2)
        return cls(edges, w, means, chol, float(c.offset_mixture_min_range))

    def near(self, corner: NDArray) -> NDArray[np.bool_]:
        """Which corners ``(n, 2)`` [m] lie nearer than ``min_range``: the reflection-point law's boxes."""
        return np.asarray(np.hypot(corner[:, 0], corner[:, 1]) < self.min_range, dtype=bool)

    def range_bin(self, corner: NDArray) -> NDArray[np.intp]:
        """Bin index ``(n,)`` of each corner's range (clipped to the first / last bin)."""
        r = np.hypot(corner[:, 0], corner[:, 1])
        return np.clip(np.searchsorted(self.edges, r, side="right") - 1, 0, self.weights.shape[0] - 1)

    def component(self, b: NDArray, u: NDArray) -> NDArray[np.intp]:
        """Component ``(n,)`` drawn by inverse CDF from uniforms ``u`` ``(n,)`` in bins ``b``."""
        cdf = np.cumsum(self.weights[b], axis=1)
        return np.minimum((u[:, None] >= cdf).sum(axis=1), self.weights.shape[1] - 1)

    def offset(self, corner: NDArray, b: NDArray, comp: NDArray, normal: NDArray) -> NDArray[np.float64]:
        """Sensor-frame offset ``(n, 2)`` [m] of component ``comp`` in bins ``b`` from standard normals ``(n, 2)``."""
        local = self.means[b, comp] + np.einsum("nij,nj->ni", self.chol[b, comp], normal)
        return from_polar_frame(local, corner)


class RadarRig:
    """The reference radar: turns a :class:`Scenario` into a :class:`RadarLog` (one sequence).

    Args:
        config: rig parameters.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import RadarRig
        >>> from sensor_envs.radar.rig import record_rig_log
        >>> rig = RadarRig()  # the generic rig (a rig file gives the calibrated one: sensor_envs.radar.rig.load_rig)
        >>> log = record_rig_log(2, 5, 3, np.random.default_rng(0))
        >>> len(log) > 0
        True
    """

    def __init__(self, config: RigConfig | None = None) -> None:
        self.config = config or RigConfig()
        self.mixture = OffsetMixture.from_config(self.config)

    def detection_probability(self, rng_m: NDArray, az: NDArray, occluded: NDArray) -> NDArray[np.float64]:
        """Detection probability ``(n,)`` at range [m], azimuth [rad] (left > 0) and occluded fraction [0, 1]."""
        c = self.config
        p_range = 1.0 / (1.0 + np.exp((rng_m - c.max_range) / c.range_falloff))
        if c.detect_range_table is not None and c.detect_range_knots is not None:
            p_range = p_range * np.interp(rng_m, np.asarray(c.detect_range_knots), np.asarray(c.detect_range_table))
        else:
            p_range = c.p_detect * p_range
        return p_range * self.azimuth_factor(az) * (1.0 - self.occlusion_loss(rng_m) * occluded)

    def occlusion_loss(self, rng_m: NDArray) -> NDArray[np.float64] | float:
        """Share of the detection probability a wholly hidden box loses at range [m] (the table, or the scalar)."""
        c = self.config
        if c.occlusion_loss_table is not None and c.occlusion_loss_knots is not None:
            return np.interp(rng_m, np.asarray(c.occlusion_loss_knots), np.asarray(c.occlusion_loss_table))
        return c.occlusion_loss

    def azimuth_factor(self, az: NDArray) -> NDArray[np.float64]:
        """Azimuth factor ``(n,)`` in [0, 1] of the detection probability at azimuth [rad] (left > 0).

        0 outside the field of view (beyond the azimuth table's knots, or ``fov`` for the generic rig).
        """
        c = self.config
        if c.detect_azimuth_table is not None and c.detect_azimuth_knots is not None:
            knots, table = np.asarray(c.detect_azimuth_knots), np.asarray(c.detect_azimuth_table)
            if c.detect_azimuth_signed:  # signed azimuth (left > 0): 0 outside the knots on either side
                return np.interp(az, knots, table, left=0.0, right=0.0)
            return np.interp(np.abs(az), knots, table, right=0.0)
        edge = np.clip(np.abs(az) / c.fov, 0.0, None)
        return np.where(edge <= 1.0, 1.0 - 0.4 * edge**4, 0.0)

    def in_view(self, box: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which boxes ``(n, 5)`` (``x, y, heading, length, width`` [m, rad]) the rig could ever detect.

        A box is in view when at least one of its corners lies at an azimuth whose detection factor
        (:meth:`azimuth_factor`) is positive; a box wholly outside the field of view (e.g. behind the
        sensor) never yields a detection, whatever its range or occlusion.
        """
        corners = rectangle_corners(box[:, 0], box[:, 1], box[:, 2], box[:, 3], box[:, 4])  # (n, 4, 2)
        az = np.arctan2(corners[..., 1], corners[..., 0])
        return np.asarray((self.azimuth_factor(az.ravel()).reshape(az.shape) > 0).any(axis=1), dtype=bool)

    def _noise_std(self, rng_m: NDArray, az: NDArray) -> tuple[NDArray, NDArray]:
        """Radial and cross-range noise std [m] at range [m] and azimuth [rad]."""
        c = self.config
        if c.offset_range_knots is not None and c.sigma_range_table is not None and c.sigma_cross_table is not None:
            k = np.asarray(c.offset_range_knots)
            return np.interp(rng_m, k, np.asarray(c.sigma_range_table)), np.interp(
                rng_m, k, np.asarray(c.sigma_cross_table)
            )
        edge = np.clip(np.abs(az) / c.fov, 0.0, 1.0)
        return np.full_like(az, c.sigma_range), c.sigma_azimuth * (1.0 + c.edge_gain * edge**2) * rng_m

    def innovation(self, rng_m: NDArray, az: NDArray, normal: NDArray, u_outlier: NDArray) -> NDArray[np.float64]:
        """Polar noise ``(n, 2)`` (radial, cross-range) [m] from standard normals ``(n, 2)`` and uniforms ``(n,)``."""
        c = self.config
        sr, sc = self._noise_std(rng_m, az)
        scale = np.where(u_outlier < c.outlier_share, c.outlier_scale, 1.0)
        return np.stack([normal[:, 0] * sr * scale, normal[:, 1] * sc * scale], axis=1)

    @staticmethod
    def _to_xy(point: NDArray, err: NDArray, bias: float) -> NDArray[np.float64]:
        """``point`` moved by a polar error (radial + ``bias``, cross-range) [m]."""
        az = np.arctan2(point[:, 1], point[:, 0])
        u = np.stack([np.cos(az), np.sin(az)], axis=1)
        v = np.stack([-np.sin(az), np.cos(az)], axis=1)
        return point + (err[:, :1] + bias) * u + err[:, 1:] * v

    def mounted(self, meas: NDArray[np.float64]) -> NDArray[np.float64]:
        """Positions ``(n, 2)`` [m] (sensor frame) as the radar reports them.

        Rotated about the sensor by ``azimuth_bias`` (the mounting yaw error); the same array when it is 0.
        """
        bias = self.config.azimuth_bias
        return meas if bias == 0 else from_frame(meas, (0.0, 0.0, bias))

    def record(
        self, scenario: Scenario, rng: np.random.Generator, sequence: int = 0, in_view_only: bool = False
    ) -> RadarLog:
        """Simulate every cycle of ``scenario``; returns the log (targets within ``log_range``).

        With ``in_view_only``, target rows of boxes wholly outside the field of view (:meth:`in_view`:
        never detectable, e.g. behind the sensor) are left out of the log, as a real radar's reference
        annotations would be; the random draws (and so every logged row) are the same either way.
        """
        c = self.config
        n_cyc, n_tgt, _ = scenario.boxes.shape
        rho = np.exp(-c.cycle_time / c.tracker_tau)
        rho_ref = np.exp(-c.cycle_time / c.reflection_tau)
        err = np.zeros((n_tgt, 2))  # the reflection-point law's tracker error (polar, metres)
        err_mix = np.zeros((n_tgt, 2))  # the mixture law's standard-normal tracker draw
        spread = c.reflection_spread
        frac = rng.uniform(-spread, spread, n_tgt)
        tracked = np.zeros(n_tgt, dtype=bool)
        mix = self.mixture
        comp = np.zeros(n_tgt, dtype=np.intp)  # mixture law: each target's current component
        rows: list[NDArray[np.float64]] = []
        for k in range(n_cyc):
            box = scenario.boxes[k]
            lag = box.copy()
            lag[:, :2] -= c.latency * scenario.velocity
            frac = np.clip(rho_ref * frac + np.sqrt(1 - rho_ref**2) * rng.uniform(-spread, spread, n_tgt), -0.5, 0.5)
            at_corner: NDArray[np.bool_] | None = None
            if c.corner_share > 0:
                at_corner = np.asarray(rng.random(n_tgt)) < c.corner_share
            geom = _reflection_geometry(lag)
            refl = _reflection_point(lag, frac, at_corner, c.reflection_center, geom)
            r, az = np.hypot(refl[:, 0], refl[:, 1]), np.arctan2(refl[:, 1], refl[:, 0])
            corners = rectangle_corners(box[:, 0], box[:, 1], box[:, 2], box[:, 3], box[:, 4])
            occ = occluded_fraction(corners)
            det = rng.random(n_tgt) < self.detection_probability(r, az, occ)
            normal = np.stack([rng.normal(0, 1, n_tgt), rng.normal(0, 1, n_tgt)], axis=1)
            u_out = np.ones(n_tgt) if c.outlier_share == 0 else np.asarray(rng.random(n_tgt), dtype=np.float64)
            if mix is None or mix.min_range > 0:  # the reflection-point law (with a mixture: nearer boxes)
                err = _tracker_ar1(err, self.innovation(r, az, normal, u_out), tracked, rho)
                meas = self._to_xy(refl, err, c.range_bias)
            if mix is not None:  # the component persists (reflection time constant), its normal draw is the AR(1)
                corner = geom[0]
                b = mix.range_bin(corner)
                fresh = mix.component(b, np.asarray(rng.random(n_tgt), dtype=np.float64))
                keep_comp = (np.asarray(rng.random(n_tgt)) < rho_ref) & (k > 0)
                comp = np.where(keep_comp, comp, fresh)
                err_mix = _tracker_ar1(err_mix, normal, tracked, rho)
                mixed = corner + mix.offset(corner, b, comp, err_mix)
                meas = np.where(mix.near(corner)[:, None], meas, mixed) if mix.min_range > 0 else mixed
            meas = self.mounted(meas)
            tracked = det
            meas[~det] = np.nan
            keep = np.hypot(box[:, 0], box[:, 1]) <= c.log_range
            if in_view_only:
                keep &= self.in_view(box)
            rows.append(self._target_rows(sequence, k, scenario.t[k], box, meas)[keep])
            rows.append(self._clutter_rows(sequence, k, scenario.t[k], rng))
        return _rows_to_log(np.concatenate(rows), f"rig sequence {sequence}")

    def snapshot(
        self, boxes: NDArray[np.float64], occluded: NDArray[np.float64], draws: SnapshotDraws
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One cycle of a rig that has been running, at static boxes (single frames such as Astyx).

        The tracker error and the reflection fraction are drawn from their stationary laws (the AR(1)
        processes of :meth:`record` keep the innovation's variance and the uniform fraction's range).

        Args:
            boxes: ``(n, 5)`` ``x, y, heading, length, width`` [m, rad].
            occluded: ``(n,)`` occluded fraction of each box (:func:`geometry.occluded_fraction` of its frame).
            draws: the random numbers (common random numbers in calibration).

        Returns:
            ``meas (n, 2)`` [m] (``NaN`` rows: missed) and the detection probability ``(n,)``.
        """
        c = self.config
        spread = c.reflection_spread
        geom = _reflection_geometry(boxes)
        refl = _reflection_point(
            boxes, spread * (2 * draws.u_frac - 1), draws.u_corner < c.corner_share, c.reflection_center, geom
        )
        r, az = np.hypot(refl[:, 0], refl[:, 1]), np.arctan2(refl[:, 1], refl[:, 0])
        p = self.detection_probability(r, az, occluded)
        mix = self.mixture
        if mix is None:
            meas = self._to_xy(refl, self.innovation(r, az, draws.normal, draws.u_outlier), c.range_bias)
        else:  # the mixture's stationary law: component from the outlier uniform, normal draw as drawn
            corner = geom[0]
            b = mix.range_bin(corner)
            meas = corner + mix.offset(corner, b, mix.component(b, draws.u_outlier), draws.normal)
            near = mix.near(corner)  # nearer than min_range: the reflection-point law
            if near.any():
                innov = self.innovation(r[near], az[near], draws.normal[near], draws.u_outlier[near])
                meas[near] = self._to_xy(refl[near], innov, c.range_bias)
        meas = self.mounted(meas)
        meas[~(draws.u_detect < p)] = np.nan
        return meas, p

    @staticmethod
    def _target_rows(seq: int, k: int, t: float, box: NDArray, meas: NDArray) -> NDArray[np.float64]:
        n = box.shape[0]
        ids = np.stack([np.full(n, seq), np.full(n, k), np.full(n, t), np.arange(n)], axis=1)
        return np.concatenate([ids, box, meas], axis=1)

    def sample_clutter_polar(self, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
        """One cycle's clutter: range [m] and azimuth [rad] arrays."""
        c = self.config
        if c.clutter_dispersion > 0 and c.clutter_rate > 0:
            m = rng.poisson(rng.gamma(1.0 / c.clutter_dispersion, c.clutter_rate * c.clutter_dispersion))
        else:
            m = rng.poisson(c.clutter_rate)
        if c.clutter_cell_weights is not None:
            return _from_cells(c, m, rng)
        if c.clutter_range_edges is not None and c.clutter_range_weights is not None:
            r = _from_bins(np.asarray(c.clutter_range_edges), np.asarray(c.clutter_range_weights), m, rng)
        else:
            r = c.max_range * np.sqrt(rng.random(m))
        if c.clutter_azimuth_edges is not None and c.clutter_azimuth_weights is not None:
            az = _from_bins(np.asarray(c.clutter_azimuth_edges), np.asarray(c.clutter_azimuth_weights), m, rng)
        else:
            az = rng.uniform(-c.fov, c.fov, m)
        return r, az

    def _clutter_rows(self, seq: int, k: int, t: float, rng: np.random.Generator) -> NDArray[np.float64]:
        r, az = self.sample_clutter_polar(rng)
        out = np.full((r.size, len(REQUIRED_COLUMNS)), np.nan)
        out[:, :4] = [seq, k, t, -1]
        out[:, 9], out[:, 10] = r * np.cos(az), r * np.sin(az)
        return out


@dataclass(frozen=True)
class SnapshotDraws:
    """Random numbers of one :meth:`RadarRig.snapshot` of ``n`` boxes (fixed for common random numbers)."""

    u_frac: NDArray[np.float64]
    u_corner: NDArray[np.float64]
    u_detect: NDArray[np.float64]
    u_outlier: NDArray[np.float64]
    normal: NDArray[np.float64]

    @classmethod
    def draw(cls, n: int, rng: np.random.Generator) -> SnapshotDraws:
        """Fresh draws for ``n`` boxes."""
        return cls(rng.random(n), rng.random(n), rng.random(n), rng.random(n), rng.standard_normal((n, 2)))


def _from_bins(edges: NDArray, weights: NDArray, m: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``m`` values uniform inside bins ``edges`` chosen with probabilities ``weights`` (normalised)."""
    return _uniform_in_bins(edges, rng.choice(weights.size, m, p=weights / weights.sum()), rng)


def _from_cells(c: RigConfig, m: int, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
    """``m`` clutter (range [m], azimuth [rad]) pairs from the joint ``clutter_cell_weights``, uniform inside a cell.

    Drawn as the range bin from the cells' range marginal, the range inside it, the azimuth bin from the
    conditional shares of that range bin, the azimuth inside it: the same four ``m``-draws in the same order
    as the independent law, so a rig log's other draws (its targets) do not change with the clutter law.
    """
    r_edges = np.asarray(c.clutter_range_edges, dtype=np.float64)
    a_edges = np.asarray(c.clutter_azimuth_edges, dtype=np.float64)
    w = np.asarray(c.clutter_cell_weights, dtype=np.float64).reshape(r_edges.size - 1, a_edges.size - 1)
    rb = rng.choice(w.shape[0], m, p=w.sum(axis=1) / w.sum())
    r = _uniform_in_bins(r_edges, rb, rng)
    cdf = np.cumsum(w, axis=1)
    cdf = cdf / np.where(cdf[:, -1:] > 0, cdf[:, -1:], 1.0)
    u = rng.random(m)
    ab = np.minimum((u[:, None] >= cdf[rb]).sum(axis=1), a_edges.size - 2)
    return r, _uniform_in_bins(a_edges, ab, rng)


def _uniform_in_bins(edges: NDArray, b: NDArray, rng: np.random.Generator) -> NDArray[np.float64]:
    """One value uniform inside bin ``b[i]`` of ``edges`` for each ``i`` (one ``rng.random`` draw per value)."""
    return np.asarray(edges[b] + (edges[b + 1] - edges[b]) * rng.random(b.size), dtype=np.float64)


def _rows_to_log(rows: NDArray[np.float64], source: str) -> RadarLog:
    return RadarLog({name: rows[:, j] for j, name in enumerate(REQUIRED_COLUMNS)}, source=source)


def record_rig_log(
    n_sequences: int,
    n_cycles: int,
    n_targets: int,
    rng: np.random.Generator,
    config: RigConfig | None = None,
    progress: bool = False,
    velocity_columns: bool = False,
    in_view_only: bool = False,
) -> RadarLog:
    """Record ``n_sequences`` independent rig sequences into one log (sequence ids 0..n-1).

    Args:
        n_sequences: number of scenarios.
        n_cycles: radar cycles per scenario (spaced ``config.cycle_time`` seconds).
        n_targets: target boxes per scenario.
        rng: the generator for scenarios and radar noise.
        config: rig parameters (default :class:`RigConfig`).
        progress: show a tqdm bar.
        velocity_columns: add covariate columns ``rel_vx``, ``rel_vy``: the target's velocity relative to
            the (static) sensor, sensor frame [m/s] (empty on clutter rows).
        in_view_only: leave out target rows of boxes wholly outside the field of view
            (:meth:`RadarRig.in_view`); same random draws, so the other rows are unchanged.
    """
    rig = RadarRig(config)
    logs, vel = [], []
    for s in tqdm(range(n_sequences), disable=not progress, desc="rig"):
        sc = generate_scenario(n_targets, n_cycles, rig.config.cycle_time, rng, rig.config)
        logs.append(rig.record(sc, rng, sequence=s, in_view_only=in_view_only))
        tgt = logs[-1]["target"]
        vel.append(np.where((tgt >= 0)[:, None], sc.velocity[np.maximum(tgt, 0)], np.nan))
    cols = {k: np.concatenate([lg.columns[k] for lg in logs]) for k in REQUIRED_COLUMNS}
    if velocity_columns:
        v = np.concatenate(vel)
        cols["rel_vx"], cols["rel_vy"] = v[:, 0], v[:, 1]
    return RadarLog(cols, source=f"rig log ({n_sequences} sequences)")
