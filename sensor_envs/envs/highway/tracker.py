"""A multi-target tracker for the highway radar: what a driving function acts on instead of raw detections.

Per radar cycle (:meth:`MultiTargetTracker.step`), in highway-env's world frame [m, m/s]:

1. **predict** every track with a constant-velocity Kalman filter (state ``x, y, vx, vy``; discrete
   white-noise acceleration of std ``accel_std`` [m/s^2], the ``Q`` of filterpy's ``Q_discrete_white_noise``);
2. **associate** detections to tracks by global nearest neighbour (``scipy.optimize.linear_sum_assignment``
   on the squared Mahalanobis distance of the position innovation), confirmed tracks first, then
   tentative ones on the detections left; a pair is allowed only inside the chi-square ``gate`` and, with
   ``doppler_gate``, when the detection's radial speed (Doppler, along the line of sight from the sensor)
   is within ``doppler_gate`` [m/s] of the track's predicted one;
3. **update** the matched tracks (Kalman update, position measurement of std ``position_std`` [m]);
4. **confirm** a tentative track after ``confirm_hits`` hits within its last ``confirm_window`` cycles
   (M-of-N); delete a tentative track once it can no longer reach that, and a confirmed track after
   ``delete_after`` consecutive misses (it coasts on its prediction until then);
5. **start** a tentative track at every unmatched detection: position measured; velocity from the
   detection's radial speed (Doppler) with a ROAD prior: objects move along the road direction given to
   :meth:`~MultiTargetTracker.step`, so the velocity is ``v_r / cos(angle between line of sight and
   road) * road direction`` (std ``radial_speed_std / |cos|`` along the road, ``lateral_speed_std``
   across it). Where the line of sight is within ``acos(0.3)`` of perpendicular to the road, or no
   direction is given, the velocity is ``v_r`` along the line of sight and zero across it (std
   ``init_speed_std``: a radar does not measure the tangential speed).

Output (:meth:`MultiTargetTracker.confirmed`): confirmed tracks' filtered positions and velocities,
their age (cycles since the first hit) and existence (share of hits in the last ``confirm_window``
cycles, in ``[0, 1]``). The filter is batched over tracks in numpy rather than one filterpy
``KalmanFilter`` per track: the KDE radar's clutter keeps a hundred or more tentative tracks alive, and a
per-track filterpy loop costs more than the 2 ms per policy step budget (``benchmarks/bench_highway.py``
times both); ``tests/test_highway_tracks.py`` checks the batched filter against filterpy's ``predict`` and
``update``. Deterministic: the tracker draws no random numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from sensor_envs.inputs import InputError

__all__ = ["TrackerConfig", "MultiTargetTracker", "TrackList", "tracker_config", "tracked_frame"]

if TYPE_CHECKING:
    from sensor_envs.envs.highway.step_record import RadarFrame


_BIG = 1.0e12


@dataclass(frozen=True)
class TrackerConfig:
    """Tracker parameters (units in the names' docs; defaults documented in docs/howto/highway_tracks.md).

    Attributes:
        confirm_hits: M of the M-of-N confirmation.
        confirm_window: N of the M-of-N confirmation (cycles), ``>= confirm_hits``.
        delete_after: consecutive misses after which a confirmed track is dropped (>= 1).
        gate: chi-square gate on the squared Mahalanobis distance of the position innovation (2 dof;
            9.21 = probability 0.99).
        doppler_gate: largest |detection - predicted| radial speed [m/s] of a pair; ``None`` = no Doppler gate.
        position_std: measurement noise std [m] per axis.
        accel_std: process noise: std of the white-noise acceleration [m/s^2].
        radial_speed_std: std [m/s] of a new track's radial speed (the Doppler measurement).
        init_speed_std: std [m/s] of a new track's speed across the line of sight (unmeasured) when the
            road prior does not apply.
        lateral_speed_std: std [m/s] of a new track's speed across the road (road prior).
    """

    confirm_hits: int = 2
    confirm_window: int = 3
    delete_after: int = 2
    gate: float = 9.21
    doppler_gate: float | None = 2.0
    position_std: float = 0.75
    accel_std: float = 1.5
    radial_speed_std: float = 0.5
    init_speed_std: float = 5.0
    lateral_speed_std: float = 1.0

    def __post_init__(self) -> None:
        """Check every field (``InputError`` naming it)."""
        for name in ("confirm_hits", "confirm_window", "delete_after"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise InputError(f"tracker.{name}: expected an integer >= 1, got {v!r}")
        if self.confirm_window < self.confirm_hits or self.confirm_window > 30:
            raise InputError(
                f"tracker.confirm_window: expected confirm_hits ({self.confirm_hits}) <= N <= 30, "
                f"got {self.confirm_window!r}"
            )
        for name in ("gate", "position_std", "accel_std", "radial_speed_std", "init_speed_std", "lateral_speed_std"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not (np.isfinite(v) and 0 < v <= 1e6):
                raise InputError(f"tracker.{name}: expected a number in (0, 1e6], got {v!r}")
        d = self.doppler_gate
        if d is not None and (
            not isinstance(d, (int, float)) or isinstance(d, bool) or not (np.isfinite(d) and 0 < d <= 1e6)
        ):
            raise InputError(f"tracker.doppler_gate: expected a speed [m/s] in (0, 1e6] or None, got {d!r}")


@dataclass(frozen=True, eq=False)
class TrackList:
    """Confirmed tracks of one cycle (world frame).

    Attributes:
        ids: ``(t,)`` track ids (unique since the tracker's last reset).
        position: ``(t, 2)`` filtered positions [m].
        velocity: ``(t, 2)`` filtered velocities [m/s].
        age: ``(t,)`` cycles since the track's first hit.
        existence: ``(t,)`` share of hits in the last ``confirm_window`` cycles, in ``[0, 1]``.
        coasting: ``(t,)`` not updated this cycle.
    """

    ids: NDArray[np.int64]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    age: NDArray[np.int64]
    existence: NDArray[np.float64]
    coasting: NDArray[np.bool_]

    def __eq__(self, other: object) -> bool:
        """Field-wise exact equality of the arrays."""
        if not isinstance(other, TrackList):
            return NotImplemented
        return all(np.array_equal(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]


class MultiTargetTracker:
    """Constant-velocity Kalman tracker with gating, GNN association and M-of-N confirmation (module docstring)."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self.reset()

    def reset(self) -> None:
        """Drop every track."""
        self.x = np.zeros((0, 4))
        self.P = np.zeros((0, 4, 4))
        self.hist = np.zeros(0, dtype=np.int64)  # bit i: hit i cycles ago
        self.age = np.zeros(0, dtype=np.int64)
        self.misses = np.zeros(0, dtype=np.int64)
        self.confirmed_ = np.zeros(0, dtype=bool)
        self.ids = np.zeros(0, dtype=np.int64)
        self._next_id = 0

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def step(
        self,
        det_w: NDArray[np.float64],
        det_radial: NDArray[np.float64],
        sensor_xy: NDArray[np.float64],
        dt: float,
        road_heading: float | None = None,
    ) -> NDArray[np.int64]:
        """One radar cycle: predict, associate, update, confirm/delete, start tracks.

        Args:
            det_w: ``(k, 2)`` detections, world frame [m].
            det_radial: ``(k,)`` their radial speed over ground [m/s]: the world velocity's component
                along the line of sight from the sensor (what a radar's Doppler gives after removing the
                ego's own motion; 0 for stationary objects).
            sensor_xy: ``(2,)`` the sensor's world position [m].
            dt: seconds since the previous cycle (> 0).
            road_heading: direction [rad] objects move along (the road's, world frame), for new tracks'
                velocity; ``None`` = no road prior.

        Returns:
            ``(k,)`` the id of the track each detection updated or started.
        """
        c = self.config
        det_w = np.asarray(det_w, dtype=np.float64).reshape(-1, 2)
        det_radial = np.asarray(det_radial, dtype=np.float64).reshape(-1)
        self._predict(dt)
        los = det_w - np.asarray(sensor_xy, dtype=np.float64)[:2]
        u = los / np.maximum(np.linalg.norm(los, axis=1, keepdims=True), 1e-9)
        match = np.full(len(det_w), -1, dtype=np.int64)  # track index per detection
        cost = self._cost(det_w, det_radial, u)
        free = np.ones(len(det_w), dtype=bool)
        for stage in (self.confirmed_, ~self.confirmed_):  # confirmed tracks pick first
            t_idx, d_idx = np.flatnonzero(stage), np.flatnonzero(free)
            if t_idx.size and d_idx.size:
                sub = cost[np.ix_(t_idx, d_idx)]
                rows, cols = (sub < _BIG).any(axis=1), (sub < _BIG).any(axis=0)  # only gated pairs compete
                t_idx, d_idx, sub = t_idx[rows], d_idx[cols], sub[np.ix_(rows, cols)]
                r, k = linear_sum_assignment(sub)
                ok = sub[r, k] <= c.gate
                match[d_idx[k[ok]]] = t_idx[r[ok]]
                free[d_idx[k[ok]]] = False
        self._update(det_w, match)
        out = np.full(len(det_w), -1, dtype=np.int64)
        out[match >= 0] = self.ids[match[match >= 0]]
        hit = np.zeros(len(self), dtype=bool)
        hit[match[match >= 0]] = True
        self._maintain(hit)
        out[free] = self._start(det_w[free], det_radial[free], u[free], road_heading)
        return out

    def confirmed(self) -> TrackList:
        """The confirmed tracks now (fresh arrays)."""
        s = self.confirmed_
        n = self.config.confirm_window
        hits = _popcount(self.hist[s], n).astype(np.float64)
        return TrackList(
            ids=self.ids[s].copy(),
            position=self.x[s, :2].copy(),
            velocity=self.x[s, 2:].copy(),
            age=self.age[s].copy(),
            existence=np.minimum(hits / n, 1.0),
            coasting=(self.misses[s] > 0).copy(),
        )

    # -- the filter ----------------------------------------------------------------------------------

    def _predict(self, dt: float) -> None:
        """Constant-velocity prediction of every track over ``dt`` [s]."""
        if not len(self):
            return
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        g = self.config.accel_std**2
        q = np.zeros((4, 4))  # state order x, y, vx, vy
        q[0, 0] = q[1, 1] = g * dt**4 / 4
        q[0, 2] = q[2, 0] = q[1, 3] = q[3, 1] = g * dt**3 / 2
        q[2, 2] = q[3, 3] = g * dt**2
        self.x = self.x @ F.T
        self.P = F @ self.P @ F.T + q

    def _cost(self, det_w: NDArray[np.float64], det_radial: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray:
        """``(t, k)`` squared Mahalanobis distances, ``_BIG`` outside the gates.

        Only pairs inside a box bounding each track's gate ellipse (half-width ``sqrt(gate * trace S)``)
        are evaluated; the others are outside the gate anyway.
        """
        cost = np.full((len(self), len(det_w)), _BIG)
        if not len(self) or not len(det_w):
            return cost
        c = self.config
        S = self.P[:, :2, :2] + c.position_std**2 * np.eye(2)
        half = np.sqrt(c.gate * (S[:, 0, 0] + S[:, 1, 1]))
        dx = det_w[None, :, 0] - self.x[:, None, 0]
        dy = det_w[None, :, 1] - self.x[:, None, 1]
        t, k = np.nonzero((np.abs(dx) <= half[:, None]) & (np.abs(dy) <= half[:, None]))
        if not t.size:
            return cost
        a, b, d = S[t, 0, 0], S[t, 0, 1], S[t, 1, 1]
        x, y = dx[t, k], dy[t, k]
        m = (d * x * x - 2 * b * x * y + a * y * y) / (a * d - b * b)
        ok = m <= c.gate
        if c.doppler_gate is not None:
            pred = self.x[t, 2] * u[k, 0] + self.x[t, 3] * u[k, 1]
            ok &= np.abs(pred - det_radial[k]) <= c.doppler_gate
        cost[t[ok], k[ok]] = m[ok]
        return cost

    def _update(self, det_w: NDArray[np.float64], match: NDArray[np.int64]) -> None:
        """Kalman update of the tracks matched by ``match`` (track index per detection, -1 = none)."""
        d = np.flatnonzero(match >= 0)
        if not d.size:
            return
        t = match[d]
        P = self.P[t]
        S = P[:, :2, :2] + self.config.position_std**2 * np.eye(2)
        K = P[:, :, :2] @ np.linalg.inv(S)  # (m, 4, 2): P H^T S^-1
        innov = det_w[d] - self.x[t, :2]
        self.x[t] = self.x[t] + np.einsum("mij,mj->mi", K, innov)
        self.P[t] = P - K @ P[:, :2, :]

    def _maintain(self, hit: NDArray[np.bool_]) -> None:
        """Hit history, ages, confirmation and deletion after an association."""
        c = self.config
        mask = (1 << c.confirm_window) - 1
        self.hist = ((self.hist << 1) | hit.astype(np.int64)) & mask
        self.age += 1
        self.misses = np.where(hit, 0, self.misses + 1)
        hits = _popcount(self.hist, c.confirm_window)
        self.confirmed_ |= hits >= c.confirm_hits
        # a tentative track dies when the hits it can still get within its window no longer reach M
        reachable = hits + np.maximum(c.confirm_window - self.age, 0) >= c.confirm_hits
        keep = np.where(self.confirmed_, self.misses < c.delete_after, reachable)
        for name in ("x", "P", "hist", "age", "misses", "confirmed_", "ids"):
            setattr(self, name, getattr(self, name)[keep])

    def _start(
        self,
        det_w: NDArray[np.float64],
        det_radial: NDArray[np.float64],
        u: NDArray[np.float64],
        road_heading: float | None,
    ) -> NDArray[np.int64]:
        """Start tentative tracks at ``det_w``; returns their ids."""
        n = len(det_w)
        if not n:
            return np.zeros(0, dtype=np.int64)
        x, pv = self._initial_velocity(det_radial, u, road_heading)
        x = np.concatenate([det_w, x], axis=1)
        c = self.config
        P = np.zeros((n, 4, 4))
        P[:, 0, 0] = P[:, 1, 1] = c.position_std**2
        P[:, 2:, 2:] = pv
        ids = np.arange(self._next_id, self._next_id + n, dtype=np.int64)
        self._next_id += n
        self.x = np.concatenate([self.x, x])
        self.P = np.concatenate([self.P, P])
        self.hist = np.concatenate([self.hist, np.ones(n, dtype=np.int64)])
        self.age = np.concatenate([self.age, np.ones(n, dtype=np.int64)])
        self.misses = np.concatenate([self.misses, np.zeros(n, dtype=np.int64)])
        self.confirmed_ = np.concatenate([self.confirmed_, np.full(n, c.confirm_hits <= 1)])
        self.ids = np.concatenate([self.ids, ids])
        return ids

    def _initial_velocity(
        self, det_radial: NDArray[np.float64], u: NDArray[np.float64], road_heading: float | None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """New tracks' velocities ``(n, 2)`` [m/s] and covariances ``(n, 2, 2)`` (module docstring, step 5)."""
        c = self.config
        tang = np.stack([-u[:, 1], u[:, 0]], axis=1)
        rot = np.stack([u, tang], axis=2)  # columns: radial, tangential
        v = det_radial[:, None] * u
        pv = rot @ np.diag([c.radial_speed_std**2, c.init_speed_std**2]) @ rot.transpose(0, 2, 1)
        if road_heading is None:
            return v, pv
        d = np.array([np.cos(road_heading), np.sin(road_heading)])
        cos = u @ d
        ok = np.abs(cos) >= 0.3
        along = np.stack([d, np.array([-d[1], d[0]])], axis=1)  # columns: along, across the road
        v[ok] = (det_radial[ok] / cos[ok])[:, None] * d
        var = np.zeros((int(ok.sum()), 2, 2))
        var[:, 0, 0] = (c.radial_speed_std / cos[ok]) ** 2
        var[:, 1, 1] = c.lateral_speed_std**2
        pv[ok] = along @ var @ along.T
        return v, pv


def tracker_config(value: TrackerConfig | dict[str, Any] | None) -> TrackerConfig:
    """A :class:`TrackerConfig` from itself, a dict of its fields, or ``None`` (the defaults).

    Raises:
        InputError: naming an unknown key or a bad value (``tracker.<field>``).
    """
    if value is None:
        return TrackerConfig()
    if isinstance(value, TrackerConfig):
        return value
    if not isinstance(value, dict):
        raise InputError(f"tracker: expected a TrackerConfig, a dict of its fields or None, got {type(value).__name__}")
    known = {f.name for f in fields(TrackerConfig)}
    unknown = sorted(set(value) - known)
    if unknown:
        raise InputError(f"tracker.{unknown[0]}: unknown tracker setting (known: {sorted(known)})")
    return TrackerConfig(**value)


def tracked_frame(frame: RadarFrame, tracks: TrackList) -> tuple[RadarFrame, NDArray[np.float64]]:
    """``frame`` with its reported objects replaced by the confirmed ``tracks``, and their existence.

    Only the fields the observation layout reads (world positions, velocities, headings, obstacle
    flags) are replaced; headings are the direction of the track velocity [rad].
    """
    n = len(tracks.ids)
    heading = np.arctan2(tracks.velocity[:, 1], tracks.velocity[:, 0])
    out = replace(
        frame,
        det_w=tracks.position,
        det_v=tracks.velocity,
        det_heading=heading,
        det_obstacle=np.zeros(n, dtype=bool),
    )
    return out, tracks.existence


def _popcount(bits: NDArray[np.int64], width: int) -> NDArray[np.int64]:
    """Number of set bits among the low ``width`` bits of each value."""
    out = np.zeros(bits.shape, dtype=np.int64)
    for i in range(width):  # width <= 30
        out += (bits >> i) & 1
    return out
