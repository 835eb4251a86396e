"""The observation layout of highway-env's ``KinematicObservation``, rebuilt from radar detections.

Selection, sorting, normalisation and clipping follow highway-env's ``Kinematics`` to the bit, so the
ideal radar (see :data:`sensor_envs.envs.highway.IDEAL_KINEMATICS`) reproduces it exactly. Positions are
world positions [m] (or world offsets from the ego, not rotated, when ``absolute=False``), velocities
[m/s], headings [rad].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.envs.highway.step_record import RadarFrame
from sensor_envs.inputs import InputError, InputTypeError
from sensor_envs.modelio import Constraint, InstanceOf, Interval, Numbers, Options, validate_params

__all__ = [
    "SUPPORTED_FEATURES",
    "OBSERVATION_CONSTRAINTS",
    "KinematicsLayout",
    "select",
    "feature_table",
    "normalise",
    "default_features_range",
]

SUPPORTED_FEATURES = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h")
_UNBOUNDED = 1.0e6  # finite bound [m, m/s, rad] of features that are not normalised and clipped
_FLAG: list[Constraint] = [InstanceOf(bool)]
_RANGE = Numbers(Interval(-_UNBOUNDED, _UNBOUNDED), length=2, increasing=True)
OBSERVATION_CONSTRAINTS: dict[str, list[Constraint]] = {
    "type": [Options("Kinematics")],
    "features": [None, InstanceOf(list, tuple)],  # each a SUPPORTED_FEATURES name, checked in from_config
    "vehicles_count": [Interval(1, 1000, integer=True)],
    "features_range": [None, InstanceOf(dict)],  # each feature -> (low, high), checked in from_config
    "absolute": _FLAG,
    "order": [Options("sorted", "shuffled")],
    "normalize": _FLAG,
    "clip": _FLAG,
    "see_behind": _FLAG,
    "observe_intentions": [Options(False)],  # the radar cannot see intentions
    "include_obstacles": _FLAG,
    "flatten": [Options(False)],  # highway-env ignores it too
}
"""Declared keys of ``config["observation"]`` (the radar wrapper needs highway-env's ``Kinematics``)."""


@dataclass(frozen=True)
class KinematicsLayout:
    """The parameters of highway-env's ``KinematicObservation`` that shape the observation."""

    features: tuple[str, ...] = ("presence", "x", "y", "vx", "vy")
    vehicles_count: int = 5
    features_range: dict[str, tuple[float, float]] | None = None
    absolute: bool = False
    order: str = "sorted"
    normalize: bool = True
    clip: bool = True
    see_behind: bool = False
    include_obstacles: bool = True

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> KinematicsLayout:
        """Read highway-env's ``config["observation"]``, checked against :data:`OBSERVATION_CONSTRAINTS`.

        Raises:
            InputError: naming the key (``observation.<key>``): another type than ``Kinematics``, an unknown
                key, an unsupported feature, a value outside its declared type or range.
        """
        if not isinstance(config, dict):
            raise InputError(f"observation: expected a dict, got {type(config).__name__}")
        if config.get("type") != "Kinematics":
            raise InputTypeError(
                f"observation type: the radar wrapper needs 'Kinematics', got {config.get('type')!r:.60}"
            )
        try:
            validate_params(config, OBSERVATION_CONSTRAINTS, what="key")
        except InputError as exc:
            raise InputError(f"observation.{exc}") from None
        features = tuple(config.get("features") or cls.features)
        bad = [f for f in features if not isinstance(f, str) or f not in SUPPORTED_FEATURES]
        if bad or len(set(features)) != len(features):
            what = f"{bad[0]!r:.40} is not a radar feature" if bad else "a feature is listed twice"
            raise InputError(f"observation.features: {what} (supported: {SUPPORTED_FEATURES})")
        ranges = config.get("features_range") or None
        if ranges is not None:
            if not isinstance(ranges, dict):
                raise InputError(f"observation.features_range: expected a dict, got {type(ranges).__name__}")
            try:
                validate_params(ranges, dict.fromkeys(SUPPORTED_FEATURES, [_RANGE]), what="feature")
            except InputError as exc:
                raise InputError(f"observation.features_range.{exc}") from None
            ranges = {k: (float(v[0]), float(v[1])) for k, v in ranges.items()}
        return cls(
            features=features,
            vehicles_count=int(config.get("vehicles_count", cls.vehicles_count)),
            features_range=ranges,
            absolute=bool(config.get("absolute", cls.absolute)),
            order=config.get("order", cls.order),
            normalize=bool(config.get("normalize", cls.normalize)),
            clip=bool(config.get("clip", cls.clip)),
            see_behind=bool(config.get("see_behind", cls.see_behind)),
            include_obstacles=bool(config.get("include_obstacles", cls.include_obstacles)),
        )

    def bounds(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Finite ``(vehicles_count, n_features)`` bounds of the observation."""
        lo, hi = [], []
        normalised = set(self.features_range or ("x", "y", "vx", "vy")) if self.normalize and self.clip else set()
        for f in self.features:
            if f in normalised or f in ("cos_h", "sin_h"):
                b = (-1.0, 1.0)
            elif f == "presence":
                b = (0.0, 1.0)
            else:
                b = (-_UNBOUNDED, _UNBOUNDED)
            lo.append(b[0])
            hi.append(b[1])
        shape = (self.vehicles_count, len(self.features))
        return (
            np.broadcast_to(np.asarray(lo, dtype=np.float32), shape).copy(),
            np.broadcast_to(np.asarray(hi, dtype=np.float32), shape).copy(),
        )


def select(base: Any, frame: RadarFrame, lay: KinematicsLayout) -> NDArray[np.int64]:
    """Indices of the reported objects highway-env would list, in its order.

    Within perception distance of the ego, ahead unless ``see_behind``, sorted by absolute lane
    distance, at most ``vehicles_count - 1``.
    """
    ego = base.vehicle
    d = np.linalg.norm(frame.det_w - ego.position, axis=1)
    cand = np.flatnonzero(d < base.PERCEPTION_DISTANCE)
    if lay.vehicles_count <= 1 or len(cand) == 0:
        return cand[:0]
    lane = ego.lane
    ego_s = lane.local_coordinates(ego.position)[0]
    ld = np.array([lane.local_coordinates(frame.det_w[i])[0] - ego_s for i in cand])
    keep = (-2 * ego.LENGTH < ld) | (lay.see_behind & ~frame.det_obstacle[cand])  # obstacles: never behind
    cand, ld = cand[keep], ld[keep]
    if lay.order == "sorted":
        order = np.argsort(np.abs(ld), kind="stable")
        cand = cand[order]
    return cand[: lay.vehicles_count - 1]


def feature_table(ego: Any, frame: RadarFrame, rows: NDArray[np.int64], lay: KinematicsLayout) -> NDArray[np.float64]:
    """``(1 + len(rows), n_features)``: the ego's true state, then the reported objects."""
    ego_p, ego_v = np.asarray(ego.position, dtype=np.float64), np.asarray(ego.velocity, dtype=np.float64)
    pos, vel, head = frame.det_w[rows], frame.det_v[rows], frame.det_heading[rows]
    if not lay.absolute:
        pos, vel = pos - ego_p, vel - ego_v
    cols = {
        "presence": (1.0, np.ones(len(rows))),
        "x": (ego_p[0], pos[:, 0]),
        "y": (ego_p[1], pos[:, 1]),
        "vx": (ego_v[0], vel[:, 0]),
        "vy": (ego_v[1], vel[:, 1]),
        "heading": (ego.heading, head),
        "cos_h": (np.cos(ego.heading), np.cos(head)),
        "sin_h": (np.sin(ego.heading), np.sin(head)),
    }
    table = np.empty((1 + len(rows), len(lay.features)), dtype=np.float64)
    for j, f in enumerate(lay.features):
        table[0, j], table[1:, j] = cols[f]
    return table


def normalise(
    table: NDArray[np.float64], lay: KinematicsLayout, ranges: dict[str, tuple[float, float]]
) -> NDArray[np.float64]:
    """highway-env's ``lmap`` to ``[-1, 1]`` (same operation order, so the same bits) and optional clip.

    Args:
        table: ``(rows, n_features)`` raw features [m, m/s, rad]; modified in place.
        lay: the layout (which columns hold which feature, whether to clip).
        ranges: ``feature -> (low, high)`` mapped to ``(-1, 1)``; features not in the layout are ignored.

    Returns:
        ``table``.
    """
    names = [f for f in ranges if f in lay.features]
    if not names:
        return table
    cols = [lay.features.index(f) for f in names]
    low = np.array([ranges[f][0] for f in names], dtype=np.float64)
    span = np.array([ranges[f][1] - ranges[f][0] for f in names], dtype=np.float64)
    mapped = -1 + (table[:, cols] - low) * 2 / span
    table[:, cols] = np.clip(mapped, -1, 1) if lay.clip else mapped
    return table


def default_features_range(base: Any) -> dict[str, tuple[float, float]]:
    """highway-env's default normalisation ranges [m, m/s] for the ego's current road.

    ``x``: +-5 maximum speeds, ``y``: +- the width of the ego's side lanes, ``vx``/``vy``: +-2
    maximum speeds, as ``KinematicObservation.normalize_obs`` computes them.
    """
    from highway_env.road.lane import AbstractLane
    from highway_env.vehicle.kinematics import Vehicle

    side = len(base.road.network.all_side_lanes(base.vehicle.lane_index))
    return {
        "x": (-5.0 * Vehicle.MAX_SPEED, 5.0 * Vehicle.MAX_SPEED),
        "y": (-AbstractLane.DEFAULT_WIDTH * side, AbstractLane.DEFAULT_WIDTH * side),
        "vx": (-2 * Vehicle.MAX_SPEED, 2 * Vehicle.MAX_SPEED),
        "vy": (-2 * Vehicle.MAX_SPEED, 2 * Vehicle.MAX_SPEED),
    }
