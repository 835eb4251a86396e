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
4. samples the radar model once (:class:`sensor_envs.radar.sensors.RadarSensor`) with each target's
   previous output ``z_{t-1}`` (its track state, cleared on ``reset``) and, for models that take
   it, its new-track flag (see "Tracks" below): misses, correlated position errors ``z`` and
   clutter. A measured point that falls outside the field of view or range is not reported (counted
   as a miss); clutter is kept only inside the field of view and range;
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

Tracks: the wrapper keeps, per vehicle, its previous output (``NaN`` when it was missed or out of
view last cycle) and whether it has been in view before. A visible vehicle never in view since
``reset`` (or since it last left highway-env's perception distance, as a rig target leaves the
log range) is a NEW track (``new_track=True``); a vehicle seen before without an output last cycle
is a LOST track (``False``). Models with separate start trees (:class:`~sensor_envs.radar.kde.KDERadarModel`
format 4) detect the two differently, as recorded; others ignore the flag.

Clutter level, stationary filter and tracks (``clutter=``, ``stationary=``, ``tracks=``): see
:mod:`sensor_envs.envs.highway.clutter` and :mod:`sensor_envs.envs.highway.tracker`. The target
detections carry their radial speed over ground (``RadarFrame.det_radial``: the true world velocity
along the line of sight, a noise-free Doppler; clutter 0), used by the stationary filter and by the
tracker's Doppler gate. Both options draw nothing from the world's generator; the object-level clutter
thinning draws one number per in-view clutter point from the wrapper's generator.

Rate (``radar_rate=``):

* ``"policy"`` (default): one radar cycle per policy step, when highway-env observes; ``z_{t-1}`` is
  the output one policy step earlier. The shipped ``radar_kde.npz`` is fitted at a cycle time of
  1.0 s, highway-env's default ``policy_frequency`` of 1 Hz.
* ``"simulation"``: one radar cycle after every simulation sub-step (``simulation_frequency`` Hz, e.g.
  15 Hz in highway-v0: 66.7 ms, a real radar's cycle), so ``z_{t-1}`` is the output one sub-step
  earlier; the observation is laid out once per policy step from the LATEST cycle. The shipped
  ``radar_kde_fast.npz`` is fitted at 1/15 s. Mechanism: highway-env's ``AbstractEnv._simulate``
  calls ``road.step(1 / simulation_frequency)`` exactly once per sub-step; after each ``reset`` (which
  builds a new ``Road``) the wrapper sets an instance attribute ``step`` on that road object, a
  :class:`RoadStepHook` that calls the class's own ``Road.step`` and then samples the radar. No class
  or module of highway-env is modified; other envs and roads are unaffected. If a future
  highway-env stops calling ``road.step`` per sub-step, ``step`` raises (the hook counts its calls).

The model's ``cycle_time`` (file header) must equal the period of the rate used (``1 /
policy_frequency`` or ``1 / simulation_frequency``, relative tolerance 1e-3); a mismatch raises
``InputError`` at construction and at ``reset`` (models without a cycle time are not checked).

Velocities (``velocity=``):

* ``"difference"`` (default): the reported world position of a track differenced over the radar
  cycle, ``(p_t - p_{t-1}) / dt`` (``dt`` = the policy step or, with ``radar_rate="simulation"``,
  the simulation step). A target detected now but not at the previous step has no
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

Code: this module holds the wrapper and :func:`make_highway`; :mod:`sensor_envs.envs.highway.sensor` what
the radar can see (model loading, :class:`SensorSpec`, truth, reference points, field of view,
occlusion, track velocities); :mod:`sensor_envs.envs.highway.step_record` one step's output (:class:`RadarFrame`,
:class:`RadarInfo`); :mod:`sensor_envs.envs.highway.observation` the ``Kinematics`` layout
(:class:`KinematicsLayout`, selection, normalisation); :mod:`sensor_envs.envs.highway.render` the overlay.
The public names of all of them are importable from the package, :mod:`sensor_envs.envs.highway`.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from sensor_envs.envs.checks import check_action, check_highway_config, check_options, check_seed
from sensor_envs.envs.highway.clutter import (
    STATIONARY_SPEED,
    clutter_keep_probability,
    law_edges,
    radial_speed,
    range_bins,
)
from sensor_envs.envs.highway.hooks import ObservationHook, RoadStepHook
from sensor_envs.envs.highway.observation import (
    KinematicsLayout,
    default_features_range,
    feature_table,
    normalise,
    select,
)
from sensor_envs.envs.highway.render import draw_radar
from sensor_envs.envs.highway.sensor import (
    DEFAULT_FOV,
    DEFAULT_MAX_RANGE,
    SensorSpec,
    check_cycle_time,
    cycle_period,
    load_radar,
    model_state_names,
    reference_points,
    sensor_pose,
    track_velocities,
    truth_table,
    visible_targets,
    world_state,
)
from sensor_envs.envs.highway.stacking import StackedRows
from sensor_envs.envs.highway.step_record import ObservedRows, RadarFrame, Truth
from sensor_envs.envs.highway.tracker import MultiTargetTracker, TrackerConfig, tracked_frame, tracker_config
from sensor_envs.envs.highway.wrapper_schema import (
    MAKE_HIGHWAY_CONSTRAINTS,
    RADAR_RATES,
    WRAPPER_CONSTRAINTS,
    check_reset_config,
    check_wrapper_args,
    default_config,
)
from sensor_envs.geometry import from_frame
from sensor_envs.inputs import InputError, real_path
from sensor_envs.modelio import validate_params
from sensor_envs.radar.sensors import NEW_TRACK_KEYWORD, RADAR_NAMES, RadarSensor, takes_new_track
from sensor_envs.rng import sensor_rng

# The split modules' public names are gathered by the package (sensor_envs.envs.highway).
__all__ = [
    "RNG_TAG",
    "RADAR_RATES",
    "IDEAL_KINEMATICS",
    "RadarObservation",
    "ObservedRows",
    "StackedRows",
    "make_highway",
    "WRAPPER_CONSTRAINTS",
    "MAKE_HIGHWAY_CONSTRAINTS",
    "cycle_period",
    "check_cycle_time",
]

RNG_TAG = 0x52_41_44_52  # "RADR": separates the radar's stream from any other use of the same seed
IDEAL_KINEMATICS: dict[str, Any] = {
    "radar": "ideal",
    "reference": "centre",
    "fov": 2 * np.pi,
    "max_range": np.inf,
    "occlusion_threshold": None,
    "velocity": "truth",
}
"""Keyword arguments of :func:`make_highway` under which the observation equals highway-env's ``Kinematics``."""

_NAN2 = np.full(2, np.nan)


# ---------------------------------------------------------------------------------------- the wrapper


class RadarObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Replace a highway-env ``Kinematics`` observation by what a radar reports (see the module docstring).

    Args:
        env: a highway-env environment (possibly wrapped) whose observation type is ``Kinematics``.
        radar: ``"ideal" | "gaussian" | "kde"`` (loaded once per process), or any
            :class:`~sensor_envs.radar.sensors.RadarSensor` instance.
        radar_model: path of a fitted model file for ``radar`` (``None`` = the shipped default).
        sensor_pose: ``(x, y, yaw)`` in the ego frame [m, rad]; ``None`` = middle of the front bumper.
        fov: full horizontal field of view [rad], symmetric about the sensor x axis.
        max_range: maximum range [m].
        occlusion_threshold: hidden fraction of a target's angular extent that hides it; ``None`` = off.
        reference: ``"corner"`` (closest corner) or ``"centre"``.
        velocity: ``"difference"`` or ``"truth"`` (see the module docstring).
        radar_rate: ``"policy"`` (one radar cycle per policy step) or ``"simulation"`` (one per
            simulation sub-step; the observation keeps the latest); see the module docstring.
        clutter_fraction: share of the model's clutter detections kept, each independently, in [0, 1].
            The calibrated KDE radar reports the Astyx rate, ~94 clutter detections per cycle (every
            unannotated cluster, static infrastructure included), which crowds the nearest observation
            rows; lower it to model a radar whose tracker suppresses more of them. Applied after ``clutter``.
        clutter: ``"objects"`` (default): the model's clutter thinned, per range bin, to the object-level
            rate measured on Astyx (clusters of >= 2 detections outside the boxes,
            ``models/radar_object_clutter.json``); ``"model"``: the model's own (point-level) clutter.
            See :mod:`sensor_envs.envs.highway.clutter`.
        stationary: ``"keep"`` (default): report stationary detections; ``"drop"``: the Doppler
            stationary filter of radar object lists (drops every detection whose radial speed over ground
            is within 0.5 m/s: clutter, and stopped vehicles or obstacles too).
        tracks: ``True``: the agent sees the confirmed tracks of a multi-target tracker fed with the
            detections (:mod:`sensor_envs.envs.highway.tracker`) in the same layout: filtered positions and
            velocities, ``presence`` = the track's existence (share of hits in the confirmation window);
            ``info["tracks"]`` holds the confirmed :class:`~sensor_envs.envs.highway.tracker.TrackList`.
        tracker: tracker settings (a :class:`~sensor_envs.envs.highway.tracker.TrackerConfig` or a dict of
            its fields; ``None`` = the defaults); only with ``tracks=True``.

    Raises:
        TypeError: when ``env`` is not a highway-env environment with a ``Kinematics`` observation.
        InputError: naming the bad argument or observation key, or when the model's cycle time does
            not match the radar rate.

    Examples:
        >>> import gymnasium as gym
        >>> import highway_env  # registers highway-env's ids
        >>> from sensor_envs import RadarObservation
        >>> env = RadarObservation(gym.make("highway-fast-v0"), radar="gaussian")
        >>> obs, info = env.reset(seed=0)
        >>> obs, reward, terminated, truncated, info = env.step(1)
        >>> obs.shape == env.observation_space.shape and bool(info["radar"].visible.any())
        True
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
        radar_rate: str = "policy",
        clutter_fraction: float = 1.0,
        clutter: str = "objects",
        stationary: str = "keep",
        tracks: bool = False,
        tracker: TrackerConfig | dict[str, Any] | None = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            radar=radar,
            radar_model=radar_model,
            sensor_pose=sensor_pose,
            fov=fov,
            max_range=max_range,
            occlusion_threshold=occlusion_threshold,
            reference=reference,
            velocity=velocity,
            radar_rate=radar_rate,
            clutter_fraction=clutter_fraction,
            clutter=clutter,
            stationary=stationary,
            tracks=tracks,
            tracker=tracker,
        )
        check_wrapper_args(radar, radar_model, radar_rate, clutter_fraction, clutter, stationary, tracks)
        self.radar_rate = radar_rate
        self.clutter_fraction = float(clutter_fraction)
        self.clutter, self.stationary, self.tracks = clutter, stationary, bool(tracks)
        self.tracker: MultiTargetTracker | None = MultiTargetTracker(tracker_config(tracker)) if tracks else None
        if tracker is not None and not tracks:
            raise InputError("tracker: tracker settings need tracks=True")
        gym.Wrapper.__init__(self, env)
        base: Any = env.unwrapped
        if not hasattr(base, "road") or not hasattr(base, "PERCEPTION_DISTANCE"):
            raise TypeError(f"env: expected a highway-env environment, got {type(base).__name__}")
        self.layout = KinematicsLayout.from_config(base.config["observation"])
        self.spec_sensor = SensorSpec(
            pose=sensor_pose,
            fov=fov,
            max_range=max_range,
            occlusion_threshold=occlusion_threshold,
            reference=reference,
            velocity=velocity,
        )
        if isinstance(radar, str):
            self.radar = load_radar(radar, radar_model)
            path = None if radar_model is None else str(real_path(Path(radar_model).expanduser()))
            self._radar_key: tuple[str, str | None] | None = (radar, path)
        else:
            if not isinstance(radar, RadarSensor):
                raise InputError(
                    f"radar: expected a name in {RADAR_NAMES} or a RadarSensor, got {type(radar).__name__}"
                )
            self._radar_key = None
            self.radar = radar
        self._state_names = model_state_names(self.radar)
        self._takes_new_track = takes_new_track(self.radar)
        check_cycle_time(self.radar, base.config, radar_rate)
        self._clutter_keep = clutter_keep_probability(self.radar) if clutter == "objects" else None
        low, high = self.layout.bounds()
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._rng = sensor_rng(None, RNG_TAG, None)
        self._tracks: dict[Any, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        self._seen: set[Any] = set()
        self._cycles = 0
        self._features_range: dict[str, tuple[float, float]] | None = None
        self.last_frame: RadarFrame | None = None
        self._last_obs: NDArray[np.float32] | None = None
        self._track_truth: dict[int, Any] = {}
        self.last_rows: ObservedRows | None = None

    # -- gymnasium API ------------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Reset the world and the radar's tracks; reseed the radar's own generator when ``seed`` is given.

        After the reset, highway-env's observation type is replaced by a hook so that, in ``step``, the
        radar samples exactly when highway-env would observe (before, e.g., the intersection spawns
        vehicles) and highway-env's own ``Kinematics`` is not computed a second time.
        """
        seed = check_seed(seed)
        options = check_options(options, ("config",)) or None
        base: Any = self.env.unwrapped
        check_reset_config(options, base, self.layout)
        _, info = self.env.reset(seed=seed, options=options)
        check_cycle_time(self.radar, base.config, self.radar_rate)
        self._rng = sensor_rng(seed, RNG_TAG, self._rng)
        self._tracks = {}
        self._seen = set()
        self._features_range = None
        if self.tracker is not None:
            self.tracker.reset()
        self._track_truth = {}
        base.observation_type = ObservationHook(base.observation_type, self._on_observe)
        if self.radar_rate == "simulation":
            RoadStepHook.install(base.road, self._cycle)
        self.last_frame = self.sense()
        obs = self._observe()
        assert self.last_frame is not None  # set by _observe
        info.update(self._info())
        return obs, info

    def step(self, action: Any) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Step the world; the hooks sample the radar.

        Once when highway-env observes (``radar_rate="policy"``) or after every simulation sub-step
        (``"simulation"``).
        """
        action = check_action(self.action_space, action)  # outside the space: InputError, as in Neato-v0
        self._last_obs = None
        self._cycles = 0
        _, reward, terminated, truncated, info = self.env.step(action)
        if self._last_obs is None:
            raise RuntimeError("the radar hook was not called: reset() the wrapper before step()")
        if self.radar_rate == "simulation" and self._cycles == 0:
            raise RuntimeError(
                "radar_rate='simulation': highway-env did not call road.step() during this step; "
                "this highway-env version simulates differently (see the wrapper's module docstring)"
            )
        info.update(self._info())
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
        """Sample the radar once on the current world state and advance the track state.

        Draws from the wrapper's generator in a fixed order: the targets' cycle, then clutter.
        """
        base: Any = self.env.unwrapped
        spec = self.spec_sensor
        truth = truth_table(base, self.layout.include_obstacles)
        pose = sensor_pose(base.vehicle, spec.pose)
        ref_s, ref_w, corners_s = reference_points(truth, pose, spec.reference)
        visible = visible_targets(spec, ref_s, corners_s)
        vis = np.flatnonzero(visible)
        meas_s, meas_w, ok, source, prev_w = self._measure_targets(truth, ref_s[vis], ref_w[vis], vis, pose)
        detected = np.zeros(len(truth.objects), dtype=bool)
        detected[vis[ok]] = True
        if spec.velocity == "truth":
            vel, head = truth.velocity[vis[ok]], truth.heading[vis[ok]]
        else:
            dt = self._period(base)
            vel, head = track_velocities(
                base.vehicle.velocity, truth.velocity[vis[ok]], pose, meas_w[ok], prev_w[ok], dt
            )
        radial = radial_speed(truth.velocity[vis[ok]], meas_w[ok], pose)
        clut_s = np.asarray(self.radar.sample_clutter(self._rng), dtype=np.float64).reshape(-1, 2)
        clut_s = clut_s[spec.in_view(clut_s)]
        if self._clutter_keep is not None and len(clut_s):  # object level (one draw per in-view point)
            p = self._clutter_keep[range_bins(np.hypot(clut_s[:, 0], clut_s[:, 1]), law_edges())]
            clut_s = clut_s[self._rng.random(len(clut_s)) < p]
        if self.clutter_fraction < 1.0:  # independent thinning (draws nothing at the default 1.0)
            clut_s = clut_s[self._rng.random(len(clut_s)) < self.clutter_fraction]
        keep = np.flatnonzero(ok)
        if self.stationary == "drop":  # Doppler filter: clutter is stationary infrastructure
            moving = np.abs(radial) > STATIONARY_SPEED
            keep, radial = keep[moving], radial[moving]
            clut_s = clut_s[:0]
            detected = np.zeros(len(truth.objects), dtype=bool)
            detected[vis[keep]] = True
            vel, head = vel[moving], head[moving]
        frame = RadarFrame.assemble(
            truth,
            pose,
            ref_s,
            visible,
            detected,
            vis[keep],
            meas_s[keep],
            meas_w[keep],
            vel,
            head,
            source[keep],
            clut_s,
            from_frame(clut_s, pose),
            radial,
        )
        if self.tracker is not None:
            heading = float(base.vehicle.lane.heading_at(base.vehicle.lane.local_coordinates(base.vehicle.position)[0]))
            frame.det_track = self.tracker.step(frame.det_w, frame.det_radial, pose, self._period(base), heading)
            self._label_tracks(frame)
        return frame

    def _label_tracks(self, frame: RadarFrame) -> None:
        """Remember, per live track, the object whose detection last updated it (``None``: clutter)."""
        assert self.tracker is not None and frame.det_track is not None
        objs = frame.truth.objects
        labels = self._track_truth
        for t, j in zip(frame.det_track.tolist(), frame.det_target.tolist(), strict=True):
            labels[t] = objs[j] if j >= 0 else None
        self._track_truth = {t: labels[t] for t in self.tracker.ids.tolist()}

    def _measure_targets(
        self,
        truth: Truth,
        ref_s: NDArray[np.float64],
        ref_w: NDArray[np.float64],
        vis: NDArray[np.int64],
        pose: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.int64], NDArray[np.float64]]:
        """One radar cycle for the visible targets ``vis`` (reference points ``ref_s``/``ref_w`` [m]).

        Continues each target's track (previous output ``z`` and world position), replaces the track
        state by this cycle's, and returns the measured points in the sensor and world frames [m],
        which were reported (finite and in view), the source ids, and the previous world positions.
        """
        prev = [self._tracks.get(truth.objects[i], (_NAN2, _NAN2)) for i in vis]
        prev_z = np.array([p[0] for p in prev]).reshape(-1, 2)
        prev_w = np.array([p[1] for p in prev]).reshape(-1, 2)
        new_track = np.array([truth.objects[i] not in self._seen for i in vis], dtype=bool)
        # seen: in view before, and within perception distance ever since (a vehicle that leaves the
        # truth table and comes back is new, as a rig target that leaves the log range)
        self._seen = {o for o in truth.objects if o in self._seen} | {truth.objects[i] for i in vis}
        base: Any = self.env.unwrapped  # highway-env's AbstractEnv (untyped)
        extra = world_state(self._state_names, truth, vis, pose, base.vehicle) if self._state_names else None
        z, source = self._sample_targets(ref_s, prev_z, extra, new_track)
        meas_s = ref_s + z
        ok = np.asarray(np.isfinite(z).all(axis=1))
        ok[ok] = self.spec_sensor.in_view(meas_s[ok])
        meas_w = ref_w + from_frame(np.where(ok[:, None], z, 0.0), (0.0, 0.0, pose[2]))  # offsets rotated
        self._tracks = {
            truth.objects[i]: (z[j] if ok[j] else _NAN2, meas_w[j] if ok[j] else _NAN2) for j, i in enumerate(vis)
        }
        return meas_s, meas_w, ok, source, prev_w

    def _sample_targets(
        self,
        ref_s: NDArray[np.float64],
        prev_z: NDArray[np.float64],
        extra: NDArray[np.float64] | None = None,
        new_track: NDArray[np.bool_] | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """One radar cycle for the visible targets (no call, and no draw, when there are none).

        ``extra`` holds the model's extra state variables (:func:`world_state`), when it names any;
        ``new_track`` the targets' new-track flags, passed to models that take them.
        """
        if len(ref_s) == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
        kw: dict[str, Any] = {}
        if extra is not None:
            kw["extra"] = extra
        if new_track is not None and self._takes_new_track:
            kw[NEW_TRACK_KEYWORD] = new_track
        z, source = self.radar.sample_cycle(ref_s, prev_z, self._rng, **kw)
        return np.asarray(z, dtype=np.float64).reshape(-1, 2), np.asarray(source, dtype=np.int64).reshape(-1)

    # -- observation --------------------------------------------------------------------------------

    def _on_observe(self) -> NDArray[np.float32]:
        """highway-env observes: sample the radar (``radar_rate="policy"``), then lay out the latest cycle."""
        if self.radar_rate == "policy":
            self.last_frame = self.sense()
        return self._observe()

    def _cycle(self) -> None:
        """One radar cycle after a simulation sub-step (``radar_rate="simulation"``)."""
        self.last_frame = self.sense()
        self._cycles += 1

    def _observe(self) -> NDArray[np.float32]:
        """Lay the objects reported in the latest radar cycle out as highway-env's ``Kinematics`` would."""
        frame = self.last_frame
        assert frame is not None  # sensed at reset, then by the hooks
        base: Any = self.env.unwrapped
        ego = base.vehicle
        lay = self.layout
        tracks = self.tracker.confirmed() if self.tracker is not None else None
        if tracks is not None:
            frame = tracked_frame(frame, tracks)[0]
        rows = select(base, frame, lay)
        table = feature_table(ego, frame, rows, lay)
        if tracks is None:
            objects = [frame.truth.objects[i] if i >= 0 else None for i in frame.det_target[rows]]
        else:
            objects = [self._track_truth.get(int(t)) for t in tracks.ids[rows]]
            if "presence" in lay.features:
                table[1:, lay.features.index("presence")] = tracks.existence[rows]
        self.last_rows = ObservedRows(objects, frame.det_w[rows].copy(), frame.det_v[rows].copy())
        if lay.normalize:
            table = normalise(table, lay, self._default_range(base))
        obs = np.zeros((lay.vehicles_count, len(lay.features)), dtype=np.float64)
        obs[: table.shape[0]] = table
        if lay.order == "shuffled":
            self._rng.shuffle(obs[1:])
        space = self.observation_space
        assert isinstance(space, spaces.Box)
        low, high = space.low, space.high
        self._last_obs = np.clip(obs.astype(np.float32), low, high)
        return self._last_obs.copy()

    def _info(self) -> dict[str, Any]:
        """``info["radar"]`` and, with ``tracks=True``, ``info["tracks"]`` (the confirmed :class:`TrackList`)."""
        assert self.last_frame is not None
        info: dict[str, Any] = dict(self.last_frame.info())
        if self.tracker is not None:
            info["tracks"] = self.tracker.confirmed()
        return info

    def _period(self, base: Any) -> float:
        """Seconds between radar cycles."""
        return cycle_period(base.config, self.radar_rate)

    def _default_range(self, base: Any) -> dict[str, tuple[float, float]]:
        """Normalisation ranges: the layout's, or highway-env's defaults fixed at the first observation after reset."""
        if self.layout.features_range:
            return self.layout.features_range
        if self._features_range is None:
            self._features_range = default_features_range(base)
        return self._features_range


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
    radar_rate: str = "policy",
    clutter_fraction: float = 1.0,
    clutter: str = "objects",
    stationary: str = "keep",
    tracks: bool = False,
    tracker: TrackerConfig | dict[str, Any] | None = None,
    history: int = 1,
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
        radar_rate: ``"policy"`` or ``"simulation"`` (see the module docstring); the model's cycle time
            must match (e.g. ``radar_model=default_model_path("radar_kde_fast.npz")`` at 15 Hz).
        clutter_fraction: share of the model's clutter detections kept, each independently, in [0, 1]
            (1 = the model's calibrated clutter; 0 = none).
        clutter: ``"objects"`` (object-level clutter rate) or ``"model"`` (see :class:`RadarObservation`).
        stationary: ``"keep"`` or ``"drop"`` (Doppler stationary filter; see :class:`RadarObservation`).
        tracks: the agent sees the confirmed tracks of a multi-target tracker instead of raw detections.
        tracker: tracker settings (:class:`~sensor_envs.envs.highway.tracker.TrackerConfig` or a dict of
            its fields); only with ``tracks=True``.
        history: the observation stacks the last ``history`` observations (gymnasium's
            ``FrameStackObservation``, zero-padded after ``reset``, then :class:`StackedRows`): a
            ``(history * vehicles_count, n_features)`` table, the oldest observation's rows first and the
            latest's last; 1 = no stacking.

    Raises:
        InputError: naming the argument (``config.<key>`` for a configuration key) outside its declared
            type or range (``WRAPPER_CONSTRAINTS``, ``SENSOR_CONSTRAINTS``, ``MAKE_HIGHWAY_CONSTRAINTS``,
            :func:`~sensor_envs.envs.checks.check_highway_config`).

    Examples:
        >>> from sensor_envs import make_highway
        >>> env = make_highway("highway-fast-v0", radar="kde")
        >>> obs, info = env.reset(seed=0)
        >>> obs, reward, terminated, truncated, info = env.step(1)
        >>> radar = info["radar"]
        >>> int(radar.detected.sum()) <= int(radar.visible.sum())
        True
    """
    import highway_env  # noqa: F401  (registers highway-env's ids)

    validate_params({"base_id": base_id, "history": history, "render_mode": render_mode}, MAKE_HIGHWAY_CONSTRAINTS)
    check_highway_config(config, default_config(base_id))  # every key declared, before the env is built

    with warnings.catch_warnings():  # the sensor_envs id is current even when its base id has newer versions
        warnings.filterwarnings("ignore", message=".*is out of date.*", category=DeprecationWarning)
        env = gym.make(base_id, render_mode=render_mode, config=config, disable_env_checker=True)
    wrapped = RadarObservation(
        env,
        radar,
        radar_model,
        sensor_pose=sensor_pose,
        fov=fov,
        max_range=max_range,
        occlusion_threshold=occlusion_threshold,
        reference=reference,
        velocity=velocity,
        radar_rate=radar_rate,
        clutter_fraction=clutter_fraction,
        clutter=clutter,
        stationary=stationary,
        tracks=tracks,
        tracker=tracker,
    )
    if history == 1:
        return wrapped
    return StackedRows(gym.wrappers.FrameStackObservation(wrapped, int(history), padding_type="zero"))
