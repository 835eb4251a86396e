"""A reference radar "rig": a simulated object-list radar richer than the KDE model.

Used when no recording is at hand and for time series (Astyx has none). Per radar cycle and target:

* **reflection point** on the visible contour, depending on aspect: the face most turned towards
  the sensor dominates; the point is that face's midpoint moved along the face by a persistent,
  slowly varying fraction (so it wanders as the aspect changes) - never simply the closest corner;
* **latency**: the measurement describes the target ``latency`` seconds ago;
* **polar noise**: range std ``sigma_range``, azimuth std ``sigma_azimuth`` growing quadratically
  towards the field-of-view edge (``edge_gain``);
* **tracker smoothing**: the reported error (measured - true reflection point) is exponentially
  smoothed, ``e_t = rho e_{t-1} + sqrt(1 - rho^2) n_t`` with ``rho = exp(-cycle_time / tracker_tau)``,
  so consecutive outputs are correlated; the tracker restarts after a miss;
* **detection probability** vs range (logistic fall-off at ``max_range``), azimuth (zero outside the
  field of view, lower near its edge) and occlusion (``geometry.occluded_fraction``): object loss;
* **clutter**: Poisson(``clutter_rate``) detections per cycle, uniform in range and azimuth.

The sensor sits at the origin of its frame (x forward, y left); targets are boxes moving in that
frame (:func:`generate_scenario`). All lengths in metres, angles in radians, times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from sensor_envs.geometry import occluded_fraction, rectangle_corners
from sensor_envs.radar.log import REQUIRED_COLUMNS, RadarLog

__all__ = ["RigConfig", "Scenario", "generate_scenario", "RadarRig", "record_rig_log"]


@dataclass(frozen=True)
class RigConfig:
    """Parameters of the reference rig (defaults: a generic 77 GHz long-range object radar)."""

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


def generate_scenario(n_targets: int, n_cycles: int, cycle_time: float, rng: np.random.Generator) -> Scenario:
    """Random traffic ahead of the sensor: lane vehicles plus some crossing or turning ones.

    Lane vehicles (80 %) drive along x on lanes ``y in {-7, -3.5, 0, 3.5, 7}`` m with relative speed
    ~N(0, 1.5) m/s; the others cross with headings uniform in ``[-pi, pi)`` at 0.5-3 m/s. Vehicles
    are 3.8-5 m long, 1.7-2.0 m wide, starting 5-100 m ahead.
    """
    lane = rng.random(n_targets) < 0.8
    y0 = np.where(lane, rng.choice([-7.0, -3.5, 0.0, 3.5, 7.0], n_targets), rng.uniform(-25, 25, n_targets))
    x0 = rng.uniform(5.0, 100.0, n_targets)
    heading = np.where(lane, rng.normal(0.0, 0.03, n_targets), rng.uniform(-np.pi, np.pi, n_targets))
    speed = np.where(lane, rng.normal(0.0, 1.5, n_targets), rng.uniform(0.5, 3.0, n_targets))
    vel = np.stack([np.cos(heading), np.sin(heading)], axis=1) * speed[:, None]
    t = np.arange(n_cycles, dtype=np.float64) * cycle_time
    xy = np.stack([x0, y0], axis=1)[None] + t[:, None, None] * vel[None]
    dims = np.stack([rng.uniform(3.8, 5.0, n_targets), rng.uniform(1.7, 2.0, n_targets)], axis=1)
    boxes = np.concatenate(
        [
            xy,
            np.broadcast_to(heading[None, :, None], (n_cycles, n_targets, 1)),
            np.broadcast_to(dims[None], (n_cycles, n_targets, 2)),
        ],
        axis=2,
    )
    return Scenario(t, boxes, vel)


def _reflection_point(box: NDArray[np.float64], frac: NDArray[np.float64]) -> NDArray[np.float64]:
    """Reflection point ``(n, 2)`` on the face most turned to the sensor; ``frac`` in [-0.5, 0.5] along it."""
    corners = rectangle_corners(box[:, 0], box[:, 1], box[:, 2], box[:, 3], box[:, 4])  # (n, 4, 2)
    nxt = np.roll(corners, -1, axis=1)
    mid = 0.5 * (corners + nxt)
    centre = box[:, None, :2]
    normal = mid - centre
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    to_sensor = -mid / np.maximum(np.linalg.norm(mid, axis=-1, keepdims=True), 1e-9)
    face = np.argmax(np.sum(normal * to_sensor, axis=-1), axis=1)
    i = np.arange(box.shape[0])
    return mid[i, face] + frac[:, None] * (nxt[i, face] - corners[i, face])


class RadarRig:
    """The reference radar: turns a :class:`Scenario` into a :class:`RadarLog` (one sequence).

    Args:
        config: rig parameters.
    """

    def __init__(self, config: RigConfig | None = None) -> None:
        self.config = config or RigConfig()

    def detection_probability(self, rng_m: NDArray, az: NDArray, occluded: NDArray) -> NDArray[np.float64]:
        """Detection probability ``(n,)`` at range [m], azimuth [rad] and occluded fraction [0, 1]."""
        c = self.config
        p_range = 1.0 / (1.0 + np.exp((rng_m - c.max_range) / c.range_falloff))
        edge = np.clip(np.abs(az) / c.fov, 0.0, None)
        p_az = np.where(edge <= 1.0, 1.0 - 0.4 * edge**4, 0.0)
        return c.p_detect * p_range * p_az * (1.0 - c.occlusion_loss * occluded)

    def _noise_std(self, az: NDArray) -> tuple[NDArray, NDArray]:
        c = self.config
        edge = np.clip(np.abs(az) / c.fov, 0.0, 1.0)
        return np.full_like(az, c.sigma_range), c.sigma_azimuth * (1.0 + c.edge_gain * edge**2)

    def record(self, scenario: Scenario, rng: np.random.Generator, sequence: int = 0) -> RadarLog:
        """Simulate every cycle of ``scenario``; returns the log (targets within ``log_range``)."""
        c = self.config
        n_cyc, n_tgt, _ = scenario.boxes.shape
        rho = np.exp(-c.cycle_time / c.tracker_tau)
        rho_ref = np.exp(-c.cycle_time / c.reflection_tau)
        err = np.zeros((n_tgt, 2))
        frac = rng.uniform(-0.4, 0.4, n_tgt)
        tracked = np.zeros(n_tgt, dtype=bool)
        rows: list[NDArray[np.float64]] = []
        for k in range(n_cyc):
            box = scenario.boxes[k]
            lag = box.copy()
            lag[:, :2] -= c.latency * scenario.velocity
            frac = np.clip(rho_ref * frac + np.sqrt(1 - rho_ref**2) * rng.uniform(-0.4, 0.4, n_tgt), -0.5, 0.5)
            refl = _reflection_point(lag, frac)
            r, az = np.hypot(refl[:, 0], refl[:, 1]), np.arctan2(refl[:, 1], refl[:, 0])
            corners = rectangle_corners(box[:, 0], box[:, 1], box[:, 2], box[:, 3], box[:, 4])
            occ = occluded_fraction(corners)
            det = rng.random(n_tgt) < self.detection_probability(r, az, occ)
            sr, sa = self._noise_std(az)
            innov = np.stack([rng.normal(0, 1, n_tgt) * sr, rng.normal(0, 1, n_tgt) * sa * r], axis=1)
            err = np.where(tracked[:, None], rho * err + np.sqrt(1 - rho**2) * innov, innov)
            tracked = det
            u = np.stack([np.cos(az), np.sin(az)], axis=1)
            v = np.stack([-np.sin(az), np.cos(az)], axis=1)
            meas = refl + err[:, :1] * u + err[:, 1:] * v
            meas[~det] = np.nan
            keep = np.hypot(box[:, 0], box[:, 1]) <= c.log_range
            rows.append(self._target_rows(sequence, k, scenario.t[k], box, meas)[keep])
            rows.append(self._clutter_rows(sequence, k, scenario.t[k], rng))
        return _rows_to_log(np.concatenate(rows), f"rig sequence {sequence}")

    @staticmethod
    def _target_rows(seq: int, k: int, t: float, box: NDArray, meas: NDArray) -> NDArray[np.float64]:
        n = box.shape[0]
        ids = np.stack([np.full(n, seq), np.full(n, k), np.full(n, t), np.arange(n)], axis=1)
        return np.concatenate([ids, box, meas], axis=1)

    def _clutter_rows(self, seq: int, k: int, t: float, rng: np.random.Generator) -> NDArray[np.float64]:
        c = self.config
        m = rng.poisson(c.clutter_rate)
        r = c.max_range * np.sqrt(rng.random(m))
        az = rng.uniform(-c.fov, c.fov, m)
        out = np.full((m, len(REQUIRED_COLUMNS)), np.nan)
        out[:, :4] = [seq, k, t, -1]
        out[:, 9], out[:, 10] = r * np.cos(az), r * np.sin(az)
        return out


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
    """
    rig = RadarRig(config)
    logs, vel = [], []
    for s in tqdm(range(n_sequences), disable=not progress, desc="rig"):
        sc = generate_scenario(n_targets, n_cycles, rig.config.cycle_time, rng)
        logs.append(rig.record(sc, rng, sequence=s))
        tgt = logs[-1]["target"]
        vel.append(np.where((tgt >= 0)[:, None], sc.velocity[np.maximum(tgt, 0)], np.nan))
    cols = {k: np.concatenate([lg.columns[k] for lg in logs]) for k in REQUIRED_COLUMNS}
    if velocity_columns:
        v = np.concatenate(vel)
        cols["rel_vx"], cols["rel_vy"] = v[:, 0], v[:, 1]
    return RadarLog(cols, source=f"rig log ({n_sequences} sequences)")
