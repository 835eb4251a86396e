"""What the radar of the highway wrapper can see: the model, the mount, the field of view and occlusion.

Frames: the world frame is highway-env's road frame [m]; the sensor frame has x forward and y left
[m], origin at the sensor, which is mounted at ``SensorSpec.pose`` in the ego frame (by default the
middle of the front bumper). Angles are in radians, counter-clockwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.envs.highway.step_record import Truth
from sensor_envs.geometry import closest_corner, from_frame, occluded_fraction, rectangle_corners, to_frame, wrap_angle
from sensor_envs.inputs import InputError
from sensor_envs.modelio import Constraint, Interval, Numbers, Options, validate_params
from sensor_envs.radar.sensors import RADAR_NAMES, RadarSensor, make_radar
from sensor_envs.sensor_model import extra_state_names

__all__ = [
    "RADAR_NAMES",
    "DEFAULT_FOV",
    "DEFAULT_MAX_RANGE",
    "SensorSpec",
    "SENSOR_CONSTRAINTS",
    "load_radar",
    "truth_table",
    "sensor_pose",
    "reference_points",
    "track_velocities",
    "visible_targets",
    "model_state_names",
    "world_state",
]

DEFAULT_FOV = float(np.deg2rad(100.0))
"""Default full horizontal field of view [rad]: +-50 deg, that of the reference rig the shipped models are fitted on."""
MAX_MOUNT_OFFSET = 100.0
"""Largest ``|x|``, ``|y|`` [m] (and ``|yaw|`` [rad]) of a sensor mount in the ego frame."""
DEFAULT_MAX_RANGE = 120.0
"""Default hard range limit [m]: past the rig's 90 m, where the fitted models' own detection fall-off decides."""
SENSOR_CONSTRAINTS: dict[str, list[Constraint]] = {
    "sensor_pose": [None, Numbers(Interval(-MAX_MOUNT_OFFSET, MAX_MOUNT_OFFSET), length=3)],
    "fov": [Interval(0.0, 2 * np.pi + 1e-12, open_low=True)],
    "max_range": [Interval(0.0, 1e4, open_low=True), Options(float("inf"))],
    "occlusion_threshold": [None, Interval(0.0, 1.0, open_low=True)],
    "reference": [Options("corner", "centre")],
    "velocity": [Options("difference", "truth")],
    "occlusion_rays": [Interval(1, 1024, integer=True)],
}
"""Declared types and ranges of the radar mount and field of view [m, rad] (``inf`` range: no limit)."""


def load_radar(radar: str, radar_model: str | Path | None = None) -> RadarSensor:
    """Return the radar model ``radar`` (``"ideal" | "gaussian" | "kde"``), loaded once per process.

    The wrapper's check of its ``radar``/``radar_model`` arguments in front of the one cached factory,
    :func:`sensor_envs.radar.sensors.make_radar` (the instance is shared by every env of the process).

    Args:
        radar: model name.
        radar_model: path of a fitted model file, or ``None`` for the shipped default.

    Raises:
        InputError: naming ``radar`` or ``radar_model`` when the name is unknown or the ideal radar is
            given a model file.
    """
    if radar not in RADAR_NAMES:
        raise InputError(f"radar: expected one of {RADAR_NAMES}, got {radar!r:.60}")
    if radar == "ideal" and radar_model is not None:
        raise InputError("radar_model: the ideal radar takes no model file")
    return make_radar(radar, radar_model)


@dataclass(frozen=True)
class SensorSpec:
    """Where the radar sits and what it can see.

    Attributes:
        pose: ``(x, y, yaw)`` of the sensor in the ego frame [m, m, rad]; ``None`` = middle of the
            front bumper, ``(length / 2, 0, 0)``.
        fov: full horizontal field of view [rad], symmetric about the sensor x axis, in ``(0, 2 pi]``.
        max_range: maximum range [m] (``inf`` allowed).
        occlusion_threshold: a target is hidden when at least this fraction of its angular extent is
            behind nearer vehicles, in ``(0, 1]``; ``None`` disables occlusion.
        reference: the point the radar measures: ``"corner"`` (closest corner) or ``"centre"``.
        velocity: ``"difference"`` or ``"truth"`` (see the module docstring).
        occlusion_rays: rays per target for the occlusion test.
    """

    pose: tuple[float, float, float] | None = None
    fov: float = DEFAULT_FOV
    max_range: float = DEFAULT_MAX_RANGE
    occlusion_threshold: float | None = 0.5
    reference: str = "corner"
    velocity: str = "difference"
    occlusion_rays: int = 16

    def __post_init__(self) -> None:
        """Validate every field against :data:`SENSOR_CONSTRAINTS` (``InputError`` naming the bad one)."""
        validate_params(
            {
                "sensor_pose": self.pose,
                "fov": self.fov,
                "max_range": self.max_range,
                "occlusion_threshold": self.occlusion_threshold,
                "reference": self.reference,
                "velocity": self.velocity,
                "occlusion_rays": self.occlusion_rays,
            },
            SENSOR_CONSTRAINTS,
        )
        if self.pose is not None:
            object.__setattr__(self, "pose", tuple(float(v) for v in self.pose))
        object.__setattr__(self, "fov", float(self.fov))
        object.__setattr__(self, "max_range", float(self.max_range))

    def in_view(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which ``(n, 2)`` sensor-frame points [m] lie in the field of view and within range."""
        r = np.hypot(points[:, 0], points[:, 1])
        ok = r <= self.max_range
        if self.fov < 2 * np.pi:
            ok &= np.abs(np.arctan2(points[:, 1], points[:, 0])) <= 0.5 * self.fov
        return ok


def truth_table(base: Any, include_obstacles: bool) -> Truth:
    """Road objects (not the ego) whose centre is within highway-env's perception distance."""
    ego, road = base.vehicle, base.road
    pool = [(v, False) for v in road.vehicles if v is not ego]
    if include_obstacles:
        pool += [(o, True) for o in road.objects]
    every = np.array([o.position for o, _ in pool], dtype=np.float64).reshape(len(pool), 2)
    near = np.linalg.norm(every - ego.position, axis=1) < base.PERCEPTION_DISTANCE  # highway-env's horizon
    objs = [p for p, keep in zip(pool, near, strict=True) if keep]
    n = len(objs)
    centre = every[near]
    heading = np.array([o.heading for o, _ in objs], dtype=np.float64)
    velocity = np.array([o.velocity for o, _ in objs], dtype=np.float64).reshape(n, 2)
    length = np.array([o.LENGTH for o, _ in objs], dtype=np.float64)
    width = np.array([o.WIDTH for o, _ in objs], dtype=np.float64)
    corners = rectangle_corners(centre[:, 0], centre[:, 1], heading, length, width) if n else np.zeros((0, 4, 2))
    return Truth([o for o, _ in objs], np.array([ob for _, ob in objs], dtype=bool), centre, heading, velocity, corners)


def sensor_pose(ego: Any, mount: tuple[float, float, float] | None) -> NDArray[np.float64]:
    """World pose ``(x, y, yaw)`` of the sensor mounted at ``mount`` in the ego frame."""
    mx, my, myaw = mount if mount is not None else (ego.LENGTH / 2.0, 0.0, 0.0)
    x, y = from_frame((mx, my), (*ego.position, ego.heading))
    return np.array([x, y, float(wrap_angle(ego.heading + myaw))])


def reference_points(
    truth: Truth, pose: NDArray[np.float64], reference: str
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The point the radar measures on each target, and the targets' corners, seen from the sensor at ``pose``.

    Args:
        truth: the ``n`` targets (world frame).
        pose: the sensor's world pose ``(x, y, yaw)`` [m, m, rad].
        reference: ``"corner"`` (closest corner to the sensor) or ``"centre"``.

    Returns:
        ``ref_s (n, 2)`` in the sensor frame [m], ``ref_w (n, 2)`` the same points in the world frame
        [m], and ``corners_s (n, 4, 2)`` in the sensor frame [m].
    """
    corners_s = to_frame(truth.corners, pose)
    n = len(truth.objects)
    if reference == "corner" and n:
        ref_s, k = closest_corner(corners_s)
        return ref_s, truth.corners[np.arange(n), k], corners_s
    return to_frame(truth.centre, pose).reshape(n, 2), truth.centre, corners_s


def track_velocities(
    ego_velocity: Any,
    true_velocity: NDArray[np.float64],
    pose: NDArray[np.float64],
    meas_w: NDArray[np.float64],
    prev_w: NDArray[np.float64],
    dt: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World velocities [m/s] and headings [rad] of ``k`` detections, for ``velocity="difference"``.

    Args:
        ego_velocity: ``(2,)`` the ego's world velocity [m/s].
        true_velocity: ``(k, 2)`` the detected targets' true world velocities [m/s].
        pose: the sensor's world pose ``(x, y, yaw)`` [m, m, rad].
        meas_w: ``(k, 2)`` measured world positions now [m].
        prev_w: ``(k, 2)`` measured world positions at the previous policy step [m] (``nan`` = none).
        dt: the policy step [s].

    Returns:
        The track difference ``(meas_w - prev_w) / dt`` where there is a previous position, else the
        Doppler-like estimate (ego velocity plus the radial part of the true relative velocity along
        the sensor's line of sight); and the direction of that velocity [rad].
    """
    ego_v = np.asarray(ego_velocity, dtype=np.float64)
    los = meas_w - pose[:2]
    u = los / np.maximum(np.linalg.norm(los, axis=1, keepdims=True), 1e-9)
    radial = np.sum((true_velocity - ego_v) * u, axis=1, keepdims=True)
    doppler = ego_v + radial * u
    diff = (meas_w - prev_w) / dt
    vel = np.where(np.isfinite(diff).all(axis=1, keepdims=True), diff, doppler)
    return vel, np.arctan2(vel[:, 1], vel[:, 0])


def visible_targets(spec: SensorSpec, ref_s: NDArray[np.float64], corners_s: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Targets whose reference point is in view and which are not hidden behind nearer targets."""
    vis = spec.in_view(ref_s)
    if spec.occlusion_threshold is None or not vis.any() or len(vis) < 2:
        return vis
    # An occluder is hit before the target it hides, so it has a point nearer than the farthest
    # corner of a target in view; every point of a box is at least (nearest corner - diagonal) away.
    dist = np.linalg.norm(corners_s, axis=-1)
    diagonal = np.linalg.norm(corners_s[:, 0] - corners_s[:, 2], axis=-1)
    idx = np.flatnonzero(dist.min(axis=1) - diagonal <= dist[vis].max())
    targets = np.flatnonzero(vis[idx])  # rays are cast for the targets in view only
    frac = occluded_fraction(corners_s[idx], (0.0, 0.0), int(spec.occlusion_rays), targets=targets)
    hidden = np.zeros_like(vis)
    hidden[idx[targets]] = frac >= spec.occlusion_threshold
    return vis & ~hidden


def model_state_names(radar: Any) -> tuple[str, ...]:
    """The extra state variables a radar model names (``extra_state_``), checked against what the world supplies.

    Raises:
        InputError: naming the variable when the highway world cannot supply it.
    """
    from sensor_envs.radar.features import WORLD_VARIABLES

    names = extra_state_names(radar)  # declared, not probed
    for name in names:
        if name not in WORLD_VARIABLES:
            raise InputError(
                f"radar_model: the model's state names {name!r}, which the highway world cannot supply "
                f"(it supplies {sorted(WORLD_VARIABLES)})"
            )
    return names


def world_state(
    names: tuple[str, ...], truth: Truth, idx: NDArray[np.int64], pose: NDArray[np.float64], ego: Any
) -> NDArray[np.float64]:
    """``(len(idx), len(names))`` values of the state variables ``names`` for targets ``idx`` (sensor frame).

    See :data:`sensor_envs.radar.features.WORLD_VARIABLES` for the names, units and frames.
    """
    from sensor_envs.radar.features import aspect_angle

    k = len(idx)
    ego_v = np.asarray(ego.velocity, dtype=np.float64)
    rel_v = to_frame(truth.velocity[idx] - ego_v, (0.0, 0.0, pose[2])).reshape(k, 2)  # vectors: rotate only
    heading = np.asarray(wrap_angle(truth.heading[idx] - pose[2]), dtype=np.float64).reshape(k)
    centre = to_frame(truth.centre[idx], pose).reshape(k, 2)
    values = {
        "rel_vx": lambda: rel_v[:, 0],
        "rel_vy": lambda: rel_v[:, 1],
        "rel_speed": lambda: np.hypot(rel_v[:, 0], rel_v[:, 1]),
        "target_heading": lambda: heading,
        "aspect": lambda: aspect_angle(centre[:, 0], centre[:, 1], heading),
        "ego_speed": lambda: np.full(k, float(np.hypot(*ego_v))),
        "range": lambda: np.hypot(centre[:, 0], centre[:, 1]),
        "azimuth": lambda: np.arctan2(centre[:, 1], centre[:, 0]),
        # every object within perception distance occludes, as every box of a rig cycle does
        "occluded": lambda: occluded_fraction(to_frame(truth.corners, pose), (0.0, 0.0), 16, targets=idx),
    }
    return np.stack([values[n]() for n in names], axis=1).reshape(k, len(names))


CYCLE_TIME_RTOL = 1e-3
"""Relative tolerance between a model's ``cycle_time`` and the radar period of the wrapper."""


def cycle_period(config: dict[str, Any], radar_rate: str) -> float:
    """Seconds between radar cycles at ``radar_rate`` under highway-env's ``config``."""
    key = "policy_frequency" if radar_rate == "policy" else "simulation_frequency"
    return 1.0 / float(config[key])


def check_cycle_time(radar: Any, config: dict[str, Any], radar_rate: str) -> None:
    """Refuse a model whose ``cycle_time_`` [s] differs from the radar period at ``radar_rate``.

    Models without a cycle time (``None``/NaN, or no attribute: the ideal radar, test doubles) pass.

    Raises:
        InputError: naming ``radar_rate``, both periods and the remedies.
    """
    cycle = getattr(radar, "cycle_time_", None)
    if cycle is None or not math.isfinite(float(cycle)):  # NaN: fitted without a cycle time
        return
    period = cycle_period(config, radar_rate)
    if not math.isclose(float(cycle), period, rel_tol=CYCLE_TIME_RTOL):
        key = "policy_frequency" if radar_rate == "policy" else "simulation_frequency"
        raise InputError(
            f"radar_rate: the radar model is fitted at a cycle time of {float(cycle):.4g} s, but radar_rate="
            f"{radar_rate!r} samples it every {period:.4g} s (1 / {key} = 1 / {config[key]}); use a model "
            f"fitted at {period:.4g} s (e.g. radar_kde_fast.npz at 1/15 s with radar_rate='simulation' and "
            f"simulation_frequency 15), or change radar_rate or {key}"
        )
