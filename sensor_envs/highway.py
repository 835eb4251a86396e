"""highway-env with a radar instead of ideal perception.

:class:`RadarObservation` wraps any highway-env environment whose observation is ``Kinematics``
(highway, highway-fast, merge, roundabout, intersection, ...). Every policy step it:

1. takes the true road objects within highway-env's perception distance of the ego vehicle;
2. computes, in the sensor frame (x forward, y left, metres; the sensor is mounted at ``sensor_pose``
   in the ego frame, by default the middle of the front bumper), the reference point of each target:
   its closest corner (``reference="corner"``, what the radar models are fitted on) or its centre;
3. keeps the targets whose reference point lies in the field of view (``fov`` [rad], symmetric about
   the sensor x axis) and within ``max_range`` [m], and that are not hidden behind nearer vehicles
   (at least ``occlusion_threshold`` of the target's angular extent hidden, see
   :func:`sensor_envs.geometry.occluded_fraction`; the ego's own body is not an occluder);
4. samples the radar model once (:class:`sensor_envs.radar_api.RadarSensor`) with each target's
   previous output ``z_{t-1}`` (its track state, cleared on ``reset``): misses, correlated position
   errors ``z`` and clutter. A measured point that falls outside the field of view or range is not
   reported (counted as a miss); clutter is kept only inside the field of view and range;
5. builds an observation with the exact layout of highway-env's ``KinematicObservation`` (ego row
   first, then up to ``vehicles_count - 1`` reported objects, the same selection, sorting,
   normalisation, clipping and zero padding) from the radar's detections instead of the truth.
   The ego row is the ego's true state (odometry is not what this models); every other row is a
   radar detection, clutter included (nothing marks clutter in the observation: a radar cannot).

When: after ``reset`` the wrapper replaces highway-env's observation type by a hook, so in ``step``
the radar samples exactly when highway-env would observe (e.g. before the intersection spawns new
vehicles) and highway-env's own ``Kinematics`` (about a fifth of a highway-fast step) is not
computed at all; only ``reset`` still computes it once.

Reference point: the radar models describe the closest corner, so by default even the ideal radar
reports closest corners, not the centres highway-env's ``Kinematics`` lists.

Rate: the radar is sampled once per policy step, so ``z_{t-1}`` is the output at the previous
policy step. The shipped KDE model is fitted on rig series with a cycle time of 1.0 s, matching
highway-env's default ``policy_frequency`` of 1 Hz; at other policy frequencies the model's time
correlation is applied per policy step, not per second.

Velocities (``velocity=``):

* ``"difference"`` (default): the reported world position of a track differenced over the policy
  step, ``(p_t - p_{t-1}) / dt``. A target detected now but not at the previous step has no
  difference; it gets a Doppler-like estimate: the ego velocity plus the radial component (along
  the line of sight from the sensor to the measured point) of the true relative velocity. Clutter
  is reported as stationary (zero world velocity). Headings (``heading``, ``cos_h``, ``sin_h``)
  are the direction of the reported velocity.
* ``"truth"``: the true velocity and heading of the detected vehicle (a perfect tracker); clutter
  is stationary with heading 0.

Reproducing ``Kinematics`` exactly: with ``radar="ideal"``, ``reference="centre"``,
``fov=2*pi``, ``max_range=inf``, ``occlusion_threshold=None`` and ``velocity="truth"`` (see
:data:`IDEAL_KINEMATICS`), every vehicle is reported at its centre with its true velocity and the
observation equals highway-env's to the bit (``order="shuffled"`` uses the wrapper's generator, not
highway-env's, so it shuffles differently). Supported features: ``presence, x, y, vx, vy,
heading, cos_h, sin_h``; others (lane offsets, destinations) are not radar measurements and raise.

Frames: in ``info`` sensor-frame arrays are x forward, y left [m] relative to the sensor; world
arrays are highway-env's road frame [m]. Positions in the observation are world positions (or
world offsets from the ego, not rotated, as in highway-env when ``absolute=False``).

Randomness: the wrapper owns a generator derived from ``reset(seed=...)`` and :data:`RNG_TAG`,
continued by ``reset()`` without a seed, fresh entropy if never seeded. It never draws from
highway-env's generator, so for one seed the traffic is identical whichever radar is used.

Processes: named radar models are loaded once per process (cached by name and resolved path) and
pickled by name, so ``SyncVectorEnv``, ``AsyncVectorEnv`` and SB3's ``SubprocVecEnv`` work. Worker
processes started by ``spawn``/``forkserver`` must import ``sensor_envs`` to know the ids: pass
``"sensor_envs:sensor_envs/HighwayFast-v0"`` (gymnasium imports the module before the id).

``info["radar"]`` (per step) is a :class:`RadarInfo`: ground truth of the ``n`` targets within
perception distance (world centres, velocities, reference points in the sensor frame), which were
visible, detected and missed, the ``k`` detections (sensor and world frames, targets first, then
clutter), the target of each detection (``-1`` = clutter), the model's source-tuple ids (``-1`` =
none) and the sensor's world pose.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from sensor_envs.geometry import (
    closest_corner,
    occluded_fraction,
    rectangle_corners,
    to_frame,
    wrap_angle,
)
from sensor_envs.radar_api import IdealRadar, RadarSensor

__all__ = [
    "RADARS",
    "RNG_TAG",
    "IDEAL_KINEMATICS",
    "DEFAULT_FOV",
    "DEFAULT_MAX_RANGE",
    "SensorSpec",
    "KinematicsLayout",
    "RadarObservation",
    "RadarInfo",
    "load_radar",
    "make_highway",
]

RADARS = ("ideal", "gaussian", "kde")
RNG_TAG = 0x52_41_44_52  # "RADR": separates the radar's stream from any other use of the same seed
DEFAULT_FOV = float(np.deg2rad(100.0))
"""Default full horizontal field of view [rad]: +-50 deg, that of the reference rig the shipped models are fitted on."""
DEFAULT_MAX_RANGE = 120.0
"""Default hard range limit [m]: past the rig's 90 m, where the fitted models' own detection fall-off decides."""
IDEAL_KINEMATICS: dict[str, Any] = {
    "radar": "ideal",
    "reference": "centre",
    "fov": 2 * np.pi,
    "max_range": np.inf,
    "occlusion_threshold": None,
    "velocity": "truth",
}
"""Keyword arguments of :func:`make_highway` under which the observation equals highway-env's ``Kinematics``."""

SUPPORTED_FEATURES = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h")
_KINEMATICS_KEYS = frozenset(
    {"type", "features", "vehicles_count", "features_range", "absolute", "order", "normalize", "clip",
     "see_behind", "observe_intentions", "include_obstacles", "flatten"}
)
_UNBOUNDED = 1.0e6  # finite bound [m, m/s, rad] of features that are not normalised and clipped
_NAN2 = np.full(2, np.nan)
_RADAR_CACHE: dict[tuple[str, str | None], RadarSensor] = {}


# --------------------------------------------------------------------------------------------- models


def load_radar(radar: str, radar_model: str | Path | None = None) -> RadarSensor:
    """Return the radar model ``radar`` (``"ideal" | "gaussian" | "kde"``), loading it once per process.

    Args:
        radar: model name.
        radar_model: path of a fitted model file, or ``None`` for the shipped default.

    Raises:
        ValueError: naming ``radar`` or ``radar_model`` when the name is unknown or the ideal radar is
            given a model file.
    """
    if radar not in RADARS:
        raise ValueError(f"radar: expected one of {RADARS}, got {radar!r}")
    path = None if radar_model is None else str(Path(radar_model).expanduser().resolve())
    if radar == "ideal" and path is not None:
        raise ValueError("radar_model: the ideal radar takes no model file")
    key = (radar, path)
    if key not in _RADAR_CACHE:
        _RADAR_CACHE[key] = _build_radar(radar, path)
    return _RADAR_CACHE[key]


def _build_radar(radar: str, path: str | None) -> RadarSensor:
    """Build a radar through :func:`sensor_envs.radar_api.make_radar` (the ideal radar needs no factory)."""
    if radar == "ideal":
        return IdealRadar()
    from sensor_envs.radar_api import make_radar

    return make_radar(radar, path)


# --------------------------------------------------------------------------------------------- config


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
        """Validate every field, naming the bad one."""
        if self.pose is not None:
            pose = tuple(float(v) for v in self.pose)
            if len(pose) != 3 or not np.all(np.isfinite(pose)):
                raise ValueError(f"sensor_pose: expected finite (x, y, yaw), got {self.pose!r}")
            object.__setattr__(self, "pose", pose)
        if not 0.0 < float(self.fov) <= 2 * np.pi + 1e-12:
            raise ValueError(f"fov: expected a field of view in (0, 2 pi] rad, got {self.fov!r}")
        if not float(self.max_range) > 0.0:
            raise ValueError(f"max_range: expected a positive range [m], got {self.max_range!r}")
        t = self.occlusion_threshold
        if t is not None and not 0.0 < float(t) <= 1.0:
            raise ValueError(f"occlusion_threshold: expected a fraction in (0, 1] or None, got {t!r}")
        if self.reference not in ("corner", "centre"):
            raise ValueError(f"reference: expected 'corner' or 'centre', got {self.reference!r}")
        if self.velocity not in ("difference", "truth"):
            raise ValueError(f"velocity: expected 'difference' or 'truth', got {self.velocity!r}")
        if int(self.occlusion_rays) < 1:
            raise ValueError(f"occlusion_rays: expected a positive count, got {self.occlusion_rays!r}")

    def in_view(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which ``(n, 2)`` sensor-frame points [m] lie in the field of view and within range."""
        r = np.hypot(points[:, 0], points[:, 1])
        ok = r <= self.max_range
        if self.fov < 2 * np.pi:
            ok &= np.abs(np.arctan2(points[:, 1], points[:, 0])) <= 0.5 * self.fov
        return ok


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
        """Read highway-env's ``config["observation"]``.

        Raises:
            TypeError: when the observation type is not ``Kinematics``.
            ValueError: naming an unknown key, an unsupported feature or a bad value.
        """
        if config.get("type") != "Kinematics":
            raise TypeError(f"observation type: the radar wrapper needs 'Kinematics', got {config.get('type')!r}")
        unknown = sorted(set(config) - _KINEMATICS_KEYS)
        if unknown:
            raise ValueError(f"observation.{unknown[0]}: unknown key (allowed: {sorted(_KINEMATICS_KEYS)})")
        if config.get("flatten", False):
            raise ValueError("observation.flatten: not supported (highway-env ignores it too)")
        features = tuple(config.get("features") or cls.features)
        bad = [f for f in features if f not in SUPPORTED_FEATURES]
        if bad:
            raise ValueError(f"observation.features: {bad[0]!r} is not a radar feature "
                             f"(supported: {SUPPORTED_FEATURES})")
        count = int(config.get("vehicles_count", cls.vehicles_count))
        if count < 1:
            raise ValueError(f"observation.vehicles_count: expected >= 1, got {count}")
        order = config.get("order", cls.order)
        if order not in ("sorted", "shuffled"):
            raise ValueError(f"observation.order: expected 'sorted' or 'shuffled', got {order!r}")
        ranges = config.get("features_range") or None
        if ranges is not None:
            ranges = {k: (v[0], v[1]) for k, v in ranges.items()}
        return cls(features=features, vehicles_count=count, features_range=ranges,
                   absolute=bool(config.get("absolute", cls.absolute)), order=order,
                   normalize=bool(config.get("normalize", cls.normalize)), clip=bool(config.get("clip", cls.clip)),
                   see_behind=bool(config.get("see_behind", cls.see_behind)),
                   include_obstacles=bool(config.get("include_obstacles", cls.include_obstacles)))

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
        return (np.broadcast_to(np.float32(lo), shape).copy(), np.broadcast_to(np.float32(hi), shape).copy())


# ------------------------------------------------------------------------------------------ sensing


@dataclass
class _Truth:
    """True targets within perception distance (world frame)."""

    objects: list[Any]
    obstacle: NDArray[np.bool_]
    centre: NDArray[np.float64]
    heading: NDArray[np.float64]
    velocity: NDArray[np.float64]
    corners: NDArray[np.float64]


@dataclass
class RadarFrame:
    """What the radar reported in one policy step (see the module docstring for the ``info`` keys)."""

    truth: _Truth
    sensor_pose: NDArray[np.float64]
    reference_s: NDArray[np.float64]
    visible: NDArray[np.bool_]
    detected: NDArray[np.bool_]
    det_s: NDArray[np.float64]
    det_w: NDArray[np.float64]
    det_v: NDArray[np.float64]
    det_heading: NDArray[np.float64]
    det_target: NDArray[np.int64]
    det_source: NDArray[np.int64]
    det_obstacle: NDArray[np.bool_]

    def info(self) -> dict[str, RadarInfo]:
        """The per-step ``info`` entry ``{"radar": RadarInfo}`` (fresh arrays)."""
        vis, det = self.visible, self.detected
        return {"radar": RadarInfo(
            truth_position=self.truth.centre.copy(), truth_velocity=self.truth.velocity.copy(),
            truth_reference=self.reference_s.copy(), visible=vis.copy(), detected=det.copy(), missed=vis & ~det,
            detections=self.det_s.copy(), detections_world=self.det_w.copy(),
            detection_target=self.det_target.copy(), source=self.det_source.copy(),
            sensor_pose=self.sensor_pose.copy(),
        )}


@dataclass(frozen=True, eq=False)
class RadarInfo:
    """Ground truth and radar output of one policy step, ``info["radar"]``.

    One object (not one ``info`` key per array) because the array lengths change from step to step:
    vector envs then collect it in an object array instead of stacking mismatched shapes.

    Attributes:
        truth_position: ``(n, 2)`` world centres [m] of the ``n`` targets within perception distance.
        truth_velocity: ``(n, 2)`` their world velocities [m/s].
        truth_reference: ``(n, 2)`` their reference points (closest corner or centre), sensor frame [m].
        visible: ``(n,)`` in the field of view and range, and not occluded.
        detected: ``(n,)`` reported by the radar.
        missed: ``(n,)`` visible but not reported.
        detections: ``(k, 2)`` reported positions, sensor frame [m]: targets first, then clutter.
        detections_world: ``(k, 2)`` the same in the world frame [m].
        detection_target: ``(k,)`` index of each detection's target, ``-1`` for clutter.
        source: ``(k,)`` the radar model's source-tuple id of each detection, ``-1`` for none.
        sensor_pose: ``(3,)`` world pose of the sensor ``x, y, yaw`` [m, m, rad].
    """

    truth_position: NDArray[np.float64]
    truth_velocity: NDArray[np.float64]
    truth_reference: NDArray[np.float64]
    visible: NDArray[np.bool_]
    detected: NDArray[np.bool_]
    missed: NDArray[np.bool_]
    detections: NDArray[np.float64]
    detections_world: NDArray[np.float64]
    detection_target: NDArray[np.int64]
    source: NDArray[np.int64]
    sensor_pose: NDArray[np.float64]

    def __eq__(self, other: object) -> bool:
        """Field-wise exact equality of the arrays."""
        if not isinstance(other, RadarInfo):
            return NotImplemented
        return all(np.array_equal(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]


def _truth(base: Any, include_obstacles: bool) -> _Truth:
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
    return _Truth([o for o, _ in objs], np.array([ob for _, ob in objs], dtype=bool), centre, heading, velocity,
                  corners)


def _sensor_pose(ego: Any, mount: tuple[float, float, float] | None) -> NDArray[np.float64]:
    """World pose ``(x, y, yaw)`` of the sensor mounted at ``mount`` in the ego frame."""
    mx, my, myaw = mount if mount is not None else (ego.LENGTH / 2.0, 0.0, 0.0)
    c, s = np.cos(ego.heading), np.sin(ego.heading)
    x, y = ego.position
    return np.array([x + c * mx - s * my, y + s * mx + c * my, float(wrap_angle(ego.heading + myaw))])


def _rotate(v: NDArray[np.float64], yaw: float) -> NDArray[np.float64]:
    """Rotate ``(n, 2)`` vectors by ``yaw`` [rad] (sensor frame offsets to world offsets)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=-1)


def _visible(spec: SensorSpec, ref_s: NDArray[np.float64], corners_s: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Targets whose reference point is in view and which are not hidden behind nearer targets."""
    vis = spec.in_view(ref_s)
    if spec.occlusion_threshold is None or not vis.any() or len(vis) < 2:
        return vis
    # An occluder is hit before the target it hides, so it has a point nearer than the farthest
    # corner of a target in view; every point of a box is at least (nearest corner - diagonal) away.
    dist = np.linalg.norm(corners_s, axis=-1)
    diagonal = np.linalg.norm(corners_s[:, 0] - corners_s[:, 2], axis=-1)
    idx = np.flatnonzero(dist.min(axis=1) - diagonal <= dist[vis].max())
    frac = occluded_fraction(corners_s[idx], (0.0, 0.0), int(spec.occlusion_rays))
    hidden = np.zeros_like(vis)
    hidden[idx] = frac >= spec.occlusion_threshold
    return vis & ~hidden


# ---------------------------------------------------------------------------------------- the wrapper


class RadarObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Replace a highway-env ``Kinematics`` observation by what a radar reports (see the module docstring).

    Args:
        env: a highway-env environment (possibly wrapped) whose observation type is ``Kinematics``.
        radar: ``"ideal" | "gaussian" | "kde"`` (loaded once per process), or any
            :class:`~sensor_envs.radar_api.RadarSensor` instance.
        radar_model: path of a fitted model file for ``radar`` (``None`` = the shipped default).
        sensor_pose: ``(x, y, yaw)`` in the ego frame [m, rad]; ``None`` = middle of the front bumper.
        fov: full horizontal field of view [rad], symmetric about the sensor x axis.
        max_range: maximum range [m].
        occlusion_threshold: hidden fraction of a target's angular extent that hides it; ``None`` = off.
        reference: ``"corner"`` (closest corner) or ``"centre"``.
        velocity: ``"difference"`` or ``"truth"`` (see the module docstring).

    Raises:
        TypeError: when ``env`` is not a highway-env environment with a ``Kinematics`` observation.
        ValueError: naming the bad argument or observation key.
    """

    def __init__(
        self,
        env: gym.Env,
        radar: str | RadarSensor = "kde",
        radar_model: str | Path | None = None,
        *,
        sensor_pose: tuple[float, float, float] | None = None,
        fov: float = DEFAULT_FOV,
        max_range: float = DEFAULT_MAX_RANGE,
        occlusion_threshold: float | None = 0.5,
        reference: str = "corner",
        velocity: str = "difference",
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, radar=radar, radar_model=radar_model, sensor_pose=sensor_pose, fov=fov, max_range=max_range,
            occlusion_threshold=occlusion_threshold, reference=reference, velocity=velocity)
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        if not hasattr(base, "road") or not hasattr(base, "PERCEPTION_DISTANCE"):
            raise TypeError(f"env: expected a highway-env environment, got {type(base).__name__}")
        self.layout = KinematicsLayout.from_config(base.config["observation"])
        self.spec_sensor = SensorSpec(pose=sensor_pose, fov=fov, max_range=max_range,
                                      occlusion_threshold=occlusion_threshold, reference=reference,
                                      velocity=velocity)
        if isinstance(radar, str):
            self.radar = load_radar(radar, radar_model)
            path = None if radar_model is None else str(Path(radar_model).expanduser().resolve())
            self._radar_key: tuple[str, str | None] | None = (radar, path)
        else:
            if not isinstance(radar, RadarSensor):
                raise TypeError(f"radar: expected a name in {RADARS} or a RadarSensor, got {type(radar).__name__}")
            self._radar_key = None
            self.radar = radar
        low, high = self.layout.bounds()
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._rng = np.random.default_rng(np.random.SeedSequence())
        self._tracks: dict[Any, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        self._features_range: dict[str, tuple[float, float]] | None = None
        self.last_frame: RadarFrame | None = None
        self._last_obs: NDArray[np.float32] | None = None

    # -- gymnasium API ------------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[NDArray[np.float32],
                                                                                            dict[str, Any]]:
        """Reset the world and the radar's tracks; reseed the radar's own generator when ``seed`` is given.

        After the reset, highway-env's observation type is replaced by a hook so that, in ``step``, the
        radar samples exactly when highway-env would observe (before, e.g., the intersection spawns
        vehicles) and highway-env's own ``Kinematics`` is not computed a second time.
        """
        _, info = self.env.reset(seed=seed, options=options)
        base = self.env.unwrapped
        if options and "config" in options and KinematicsLayout.from_config(base.config["observation"]) != self.layout:
            raise ValueError("options.config.observation: the observation layout is fixed when the wrapper is built")
        if seed is not None:
            self._rng = np.random.default_rng(np.random.SeedSequence([int(seed), RNG_TAG]))
        self._tracks = {}
        self._features_range = None
        base.observation_type = _ObservationHook(base.observation_type, self._observe)
        obs = self._observe()
        info.update(self.last_frame.info())
        return obs, info

    def step(self, action: Any) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Step the world; the radar is sampled once, by the hook, when highway-env observes."""
        self._last_obs = None
        _, reward, terminated, truncated, info = self.env.step(action)
        if self._last_obs is None:
            raise RuntimeError("the radar hook was not called: reset() the wrapper before step()")
        info.update(self.last_frame.info())
        return self._last_obs, reward, terminated, truncated, info

    def render(self) -> Any:
        """highway-env's frame with the field of view, detections (magenta), clutter (orange) and misses (red)."""
        frame = self.env.render()
        viewer = getattr(self.env.unwrapped, "viewer", None)
        if not isinstance(frame, np.ndarray) or viewer is None or self.last_frame is None:
            return frame
        return draw_radar(frame, viewer.sim_surface, self.last_frame, self.spec_sensor)

    def __getstate__(self) -> dict[str, Any]:
        """Pickle named radars by name (re-loaded from the per-process cache on unpickling)."""
        state = self.__dict__.copy()
        if self._radar_key is not None:
            state["radar"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Restore, loading a named radar through the per-process cache."""
        self.__dict__.update(state)
        if self._radar_key is not None:
            self.radar = load_radar(*self._radar_key)

    # -- sensing ------------------------------------------------------------------------------------

    def sense(self) -> RadarFrame:
        """Sample the radar once on the current world state and advance the track state."""
        base = self.env.unwrapped
        ego, spec = base.vehicle, self.spec_sensor
        truth = _truth(base, self.layout.include_obstacles)
        pose = _sensor_pose(ego, spec.pose)
        corners_s = to_frame(truth.corners, pose)
        n = len(truth.objects)
        if spec.reference == "corner" and n:
            ref_s, k = closest_corner(corners_s)
            ref_w = truth.corners[np.arange(n), k]
        else:
            ref_s, ref_w = to_frame(truth.centre, pose).reshape(n, 2), truth.centre
        visible = _visible(spec, ref_s, corners_s)
        vis = np.flatnonzero(visible)
        prev = [self._tracks.get(truth.objects[i], (_NAN2, _NAN2)) for i in vis]
        prev_z = np.array([p[0] for p in prev]).reshape(-1, 2)
        prev_w = np.array([p[1] for p in prev]).reshape(-1, 2)
        z, source = self._sample_targets(ref_s[vis], prev_z)
        meas_s = ref_s[vis] + z
        ok = np.isfinite(z).all(axis=1)
        ok[ok] = spec.in_view(meas_s[ok])
        meas_w = ref_w[vis] + _rotate(np.where(ok[:, None], z, 0.0), pose[2])
        self._tracks = {truth.objects[i]: (z[j] if ok[j] else _NAN2, meas_w[j] if ok[j] else _NAN2)
                        for j, i in enumerate(vis)}
        detected = np.zeros(n, dtype=bool)
        detected[vis[ok]] = True
        vel, head = self._velocities(base, truth, pose, vis[ok], meas_w[ok], prev_w[ok])
        clut_s = np.asarray(self.radar.sample_clutter(self._rng), dtype=np.float64).reshape(-1, 2)
        clut_s = clut_s[spec.in_view(clut_s)]
        clut_w = _to_world(clut_s, pose)
        m = len(clut_s)
        return RadarFrame(
            truth=truth, sensor_pose=pose, reference_s=ref_s, visible=visible, detected=detected,
            det_s=np.concatenate([meas_s[ok], clut_s]), det_w=np.concatenate([meas_w[ok], clut_w]),
            det_v=np.concatenate([vel, np.zeros((m, 2))]), det_heading=np.concatenate([head, np.zeros(m)]),
            det_target=np.concatenate([vis[ok], np.full(m, -1)]).astype(np.int64),
            det_source=np.concatenate([np.asarray(source, dtype=np.int64)[ok], np.full(m, -1, dtype=np.int64)]),
            det_obstacle=np.concatenate([truth.obstacle[vis[ok]], np.zeros(m, dtype=bool)]),
        )

    def _sample_targets(self, ref_s: NDArray[np.float64], prev_z: NDArray[np.float64]) -> tuple[
        NDArray[np.float64], NDArray[np.int64]
    ]:
        """One radar cycle for the visible targets (no call, and no draw, when there are none)."""
        if len(ref_s) == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
        z, source = self.radar.sample_cycle(ref_s, prev_z, self._rng)
        return np.asarray(z, dtype=np.float64).reshape(-1, 2), np.asarray(source, dtype=np.int64).reshape(-1)

    def _velocities(self, base: Any, truth: _Truth, pose: NDArray[np.float64], idx: NDArray[np.int64],
                    meas_w: NDArray[np.float64], prev_w: NDArray[np.float64]) -> tuple[
        NDArray[np.float64], NDArray[np.float64]
    ]:
        """World velocities [m/s] and headings [rad] of the detected targets ``idx``."""
        if self.spec_sensor.velocity == "truth":
            return truth.velocity[idx], truth.heading[idx]
        ego_v = np.asarray(base.vehicle.velocity, dtype=np.float64)
        los = meas_w - pose[:2]
        u = los / np.maximum(np.linalg.norm(los, axis=1, keepdims=True), 1e-9)
        radial = np.sum((truth.velocity[idx] - ego_v) * u, axis=1, keepdims=True)
        doppler = ego_v + radial * u
        dt = 1.0 / base.config["policy_frequency"]
        diff = (meas_w - prev_w) / dt
        vel = np.where(np.isfinite(diff).all(axis=1, keepdims=True), diff, doppler)
        return vel, np.arctan2(vel[:, 1], vel[:, 0])

    # -- observation --------------------------------------------------------------------------------

    def _observe(self) -> NDArray[np.float32]:
        """Sense, then lay the reported objects out as highway-env's ``Kinematics`` would."""
        self.last_frame = frame = self.sense()
        base = self.env.unwrapped
        ego = base.vehicle
        lay = self.layout
        rows = _select(base, frame, lay)
        table = _feature_table(ego, frame, rows, lay)
        if lay.normalize:
            table = _normalise(table, lay, self._default_range(base))
        obs = np.zeros((lay.vehicles_count, len(lay.features)), dtype=np.float64)
        obs[: table.shape[0]] = table
        if lay.order == "shuffled":
            self._rng.shuffle(obs[1:])
        low, high = self.observation_space.low, self.observation_space.high
        self._last_obs = np.clip(obs.astype(np.float32), low, high)
        return self._last_obs.copy()

    def _default_range(self, base: Any) -> dict[str, tuple[float, float]]:
        """highway-env's normalisation ranges, fixed at the first observation after reset as highway-env does."""
        if self.layout.features_range:
            return self.layout.features_range
        if self._features_range is None:
            from highway_env.road.lane import AbstractLane
            from highway_env.vehicle.kinematics import Vehicle

            side = len(base.road.network.all_side_lanes(base.vehicle.lane_index))
            self._features_range = {
                "x": (-5.0 * Vehicle.MAX_SPEED, 5.0 * Vehicle.MAX_SPEED),
                "y": (-AbstractLane.DEFAULT_WIDTH * side, AbstractLane.DEFAULT_WIDTH * side),
                "vx": (-2 * Vehicle.MAX_SPEED, 2 * Vehicle.MAX_SPEED),
                "vy": (-2 * Vehicle.MAX_SPEED, 2 * Vehicle.MAX_SPEED),
            }
        return self._features_range


class _ObservationHook:
    """Stands in for highway-env's observation type: ``observe()`` samples the radar instead.

    Everything else (``space()``, attributes) is delegated to the original observation type.
    """

    def __init__(self, inner: Any, observe: Any) -> None:
        self.inner = inner
        self._observe = observe

    def observe(self) -> NDArray[np.float32]:
        """The radar observation (samples the radar once)."""
        return self._observe()

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("inner", "_observe"):
            raise AttributeError(name)
        return getattr(self.inner, name)


def _to_world(points_s: NDArray[np.float64], pose: NDArray[np.float64]) -> NDArray[np.float64]:
    """Sensor-frame points ``(n, 2)`` [m] to the world frame."""
    return pose[:2] + _rotate(points_s, pose[2])


def _select(base: Any, frame: RadarFrame, lay: KinematicsLayout) -> NDArray[np.int64]:
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


def _feature_table(ego: Any, frame: RadarFrame, rows: NDArray[np.int64], lay: KinematicsLayout) -> NDArray[
    np.float64
]:
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


def _normalise(table: NDArray[np.float64], lay: KinematicsLayout, ranges: dict[str, tuple[float, float]]) -> NDArray[
    np.float64
]:
    """highway-env's ``lmap`` to ``[-1, 1]`` (same operation order, so the same bits) and optional clip."""
    for feature, (a, b) in ranges.items():
        if feature in lay.features:
            j = lay.features.index(feature)
            table[:, j] = -1 + (table[:, j] - a) * 2 / (b - a)
            if lay.clip:
                table[:, j] = np.clip(table[:, j], -1, 1)
    return table


# ---------------------------------------------------------------------------------------- rendering

_DETECTION, _CLUTTER, _MISS, _FOV = (230, 0, 230), (255, 140, 0), (220, 0, 0), (120, 170, 255)


def _to_pixels(surface: Any, points_w: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """World points ``(n, 2)`` [m] to image ``(rows, cols)`` with highway-env's ``WorldSurface`` transform."""
    cols = ((points_w[:, 0] - surface.origin[0]) * surface.scaling).astype(np.int64)
    rows = ((points_w[:, 1] - surface.origin[1]) * surface.scaling).astype(np.int64)
    return rows, cols


def _paint(img: NDArray[np.uint8], rows: NDArray[np.int64], cols: NDArray[np.int64], color: tuple[int, int, int],
           half: int = 0) -> None:
    """Paint squares of side ``2 * half + 1`` px centred on the pixels, clipped to the image."""
    dr, dc = np.mgrid[-half:half + 1, -half:half + 1]
    r, c = (rows[:, None] + dr.ravel()).ravel(), (cols[:, None] + dc.ravel()).ravel()
    ok = (r >= 0) & (r < img.shape[0]) & (c >= 0) & (c < img.shape[1])
    img[r[ok], c[ok]] = color


def draw_radar(image: NDArray[np.uint8], surface: Any, frame: RadarFrame, spec: SensorSpec) -> NDArray[np.uint8]:
    """Overlay the field of view edges, detections (magenta), clutter (orange) and misses (red) on a frame.

    Args:
        image: ``(H, W, 3)`` uint8 frame rendered by highway-env from ``surface``.
        surface: highway-env's ``WorldSurface`` (``origin`` [m], ``scaling`` [px/m]).
        frame: the radar output to draw.
        spec: the sensor (for the field of view).

    Returns:
        A new ``(H, W, 3)`` uint8 image.
    """
    img = np.array(image, dtype=np.uint8, copy=True)
    pose = frame.sensor_pose
    if spec.fov < 2 * np.pi:
        reach = min(spec.max_range, 60.0)
        t = np.linspace(0.0, reach, 200)
        for side in (-0.5, 0.5):
            ang = pose[2] + side * spec.fov
            pts = pose[:2] + t[:, None] * np.array([np.cos(ang), np.sin(ang)])
            _paint(img, *_to_pixels(surface, pts), _FOV)
    clutter = frame.det_target < 0
    _paint(img, *_to_pixels(surface, frame.det_w[~clutter]), _DETECTION, half=3)
    _paint(img, *_to_pixels(surface, frame.det_w[clutter]), _CLUTTER, half=3)
    missed = frame.visible & ~frame.detected
    if missed.any():
        miss_w = _to_world(frame.reference_s[missed], pose)
        _paint(img, *_to_pixels(surface, miss_w), _MISS, half=2)
    return img


# ------------------------------------------------------------------------------------------ factory


def make_highway(
    base_id: str,
    radar: str = "kde",
    radar_model: str | Path | None = None,
    render_mode: str | None = None,
    config: dict[str, Any] | None = None,
    *,
    sensor_pose: tuple[float, float, float] | None = None,
    fov: float = DEFAULT_FOV,
    max_range: float = DEFAULT_MAX_RANGE,
    occlusion_threshold: float | None = 0.5,
    reference: str = "corner",
    velocity: str = "difference",
) -> gym.Env:
    """Build highway-env's ``base_id`` (e.g. ``"highway-fast-v0"``) and put a radar in front of it.

    Args:
        base_id: a highway-env id whose observation is ``Kinematics``.
        radar: ``"ideal" | "gaussian" | "kde"``.
        radar_model: path of a fitted radar model (``None`` = the shipped default).
        render_mode: ``None`` or ``"rgb_array"`` (or ``"human"``).
        config: highway-env configuration overrides; unknown keys raise.
        sensor_pose: ``(x, y, yaw)`` in the ego frame [m, rad]; ``None`` = middle of the front bumper.
        fov: full horizontal field of view [rad].
        max_range: maximum range [m].
        occlusion_threshold: hidden fraction of a target's angular extent that hides it; ``None`` = off.
        reference: ``"corner"`` (closest corner) or ``"centre"``.
        velocity: ``"difference"`` or ``"truth"`` (see the module docstring).

    Raises:
        ValueError: naming an unknown ``config`` key or a bad sensor argument.
    """
    import highway_env  # noqa: F401  (registers highway-env's ids)

    with warnings.catch_warnings():  # the sensor_envs id is current even when its base id has newer versions
        warnings.filterwarnings("ignore", message=".*is out of date.*", category=DeprecationWarning)
        env = gym.make(base_id, render_mode=render_mode, config=config, disable_env_checker=True)
    unknown = sorted(set(config or {}) - set(env.unwrapped.default_config()))
    if unknown:
        raise ValueError(f"config.{unknown[0]}: unknown highway-env key for {base_id}")
    return RadarObservation(env, radar, radar_model, sensor_pose=sensor_pose, fov=fov, max_range=max_range,
                            occlusion_threshold=occlusion_threshold, reference=reference, velocity=velocity)
