"""``sensor_envs/Neato-v0``: a differential-drive robot with a 360-bearing planar lidar in a 2D world.

Task: drive to a goal pose without touching a wall. Actions are continuous and normalised,
``a in [-1, 1]^2``, commanding ``v = a[0] * v_max`` [m/s] and ``omega = a[1] * omega_max`` [rad/s], held for
``dt`` seconds (exact unicycle arcs).

Observation (flat ``float32``, for SB3's ``MlpPolicy``)::

    [0:K]     lidar ranges [m] at bearings k * 360/K degrees counter-clockwise from the robot's x axis;
              nulls (no return, or a reading beyond max_range) read ``null_value``
    [K:K+2]   goal position in the robot frame (x forward, y left) [m]
    [K+2]     goal heading minus robot heading, wrapped to [-pi, pi) [rad]

Reward: ``progress_reward`` per metre of progress toward the goal, ``step_penalty`` per step,
``+goal_reward`` on reaching the goal (terminated), ``-collision_penalty`` on touching a wall
(terminated). Episodes are truncated after 500 steps (``max_episode_steps`` of the registration).

``info``: ``pose`` (true x, y, theta), ``ideal_scan`` (nominal ranges [m], ``inf`` where no wall within
max_range), ``incidence`` [rad] (0 where no hit), ``scan`` (the sensor's raw readings [m] before the range
cut, 0 = null as in the log format; NaN is avoided in ``info`` so that seeded rollouts compare equal),
``goal``, ``distance_to_goal``, ``is_success``, ``collision``.

Randomness: start and goal come from the env's ``np_random`` (the world's stream); the lidar draws
from its own generator derived from the reset seed, so changing the lidar never changes the world.
"""

from __future__ import annotations

import math
import sys
from os import PathLike
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from sensor_envs.envs.checks import check_options, check_seed
from sensor_envs.envs.neato_render import render_world
from sensor_envs.geometry import nearest_wall_distance, raycast_pose, sample_free_poses, to_frame, wrap_angle
from sensor_envs.inputs import InputError, check_array
from sensor_envs.jit import compiled
from sensor_envs.lidar.extra_state import modify, needs_geometry, split_term
from sensor_envs.lidar.sensors import GaussianLidar, IdealLidar, LidarSensor, make_lidar
from sensor_envs.maps import SegmentMap, load_map
from sensor_envs.modelio import Constraint, Interval, validate_params
from sensor_envs.rng import RowGenerators, sensor_rng
from sensor_envs.sensor_model import extra_state_names

__all__ = ["NeatoEnv", "NULL_VALUES", "unicycle_step", "apply_null", "collides", "step_reward", "observe_batch"]

NULL_VALUES = ("zero", "nan", "max")
_LIDAR_TAG = 0x4C494441  # "LIDA": tags the lidar's stream derived from the reset seed
WORLD_STATE = ("v", "omega", "t", "prev_residual")
"""Extra lidar state variables Neato-v0 supplies: the commanded speed [m/s] and turn rate [rad/s] of the last
action (0 after reset), the time since reset [s] and each bearing's previous residual (from the model's tables)."""
_BATCHED_LIDARS = (IdealLidar, GaussianLidar)  # and LearnedLidar: measure() broadcasts over leading axes


def _one_row(action: Any) -> Any:
    """A ``(1, 2)`` action as ``(2,)`` (a batch of one, as SB3 passes it); anything else unchanged."""
    try:
        return np.ravel(action) if np.ndim(action) == 2 and np.size(action) == 2 else action
    except ValueError:  # ragged nesting: check_array names it
        return action


NEATO_CONSTRAINTS: dict[str, list[Constraint]] = {
    "n_bearings": [Interval(1, 3600, integer=True)],
    "max_range": [Interval(0.01, 1000)],
    "dt": [Interval(1e-3, 10)],
    "v_max": [Interval(1e-3, 10)],
    "omega_max": [Interval(1e-3, 20)],
    "robot_radius": [Interval(1e-3, 10)],
    "goal_tolerance": [Interval(1e-3, 100)],
    "goal_heading_tolerance": [None, Interval(0, np.pi, open_low=True)],
    "min_goal_distance": [Interval(0, 1000)],
    "progress_reward": [Interval(-1e6, 1e6)],
    "step_penalty": [Interval(-1e6, 1e6)],
    "goal_reward": [Interval(-1e6, 1e6)],
    "collision_penalty": [Interval(-1e6, 1e6)],
}
"""Declared ranges of ``NeatoEnv``'s numeric arguments [m, s, m/s, rad/s, reward units] (finite, sane magnitudes)."""


class NeatoEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """A Neato-like robot (radius 0.17 m) with a planar lidar, driving to a goal in a segment map.

    ## Description

    A differential-drive robot must reach a goal position (and, if ``goal_heading_tolerance`` is set, a
    heading) without touching a wall, seeing the world only through its lidar. The lidar is the ideal
    raycast, the seed paper's Gaussian lidar or a learned model fitted to a real unit's readings, so a policy
    meets the nulls, biases and spurious returns of a real sensor.

    ## Action space

    ``Box(-1, 1, (2,), float32)``: ``a[0]`` scales the forward speed ``v = a[0] * v_max`` [m/s] (negative:
    backwards), ``a[1]`` the turn rate ``omega = a[1] * omega_max`` [rad/s]; held for ``dt`` seconds.

    ## Observation space

    ``Box((n_bearings + 3,), float32)``: the lidar's ``n_bearings`` ranges [m] (bearing ``k`` at
    ``k * 360 / n_bearings`` degrees counter-clockwise from the robot's heading; nulls read ``null_value``),
    then the goal's x, y in the robot frame [m] and the heading error [rad], wrapped to ``[-pi, pi)``.

    ## Rewards

    ``progress_reward`` per metre of progress toward the goal, ``-step_penalty`` per step, ``+goal_reward`` on
    reaching the goal, ``-collision_penalty`` on touching a wall.

    ## Episode end

    Terminated on reaching the goal (``info["is_success"]``) or touching a wall (``info["collision"]``);
    truncated after 500 steps (the registration's ``max_episode_steps``).

    ## Starting state

    Start and goal are drawn from the free space of the map by the world's random stream (``reset(seed=...)``),
    at least ``min_goal_distance`` apart; ``reset(options={"start": [x, y, theta], "goal": [x, y, theta]})``
    sets them. The lidar draws from its own stream derived from the same seed, so the lidar never changes the
    world.

    Args:
        map: the world: a built-in name (``"seed_room"``, ``"corridor"``, ``"cluttered"``), a map file (text,
            JSON/YAML, ROS map_server YAML), a :class:`~sensor_envs.maps.SegmentMap` or an ``(M, 2, 2)`` array of
            segment end points [m].
        lidar: ``"ideal"``, ``"gaussian"``, ``"learned"``, or any object with ``measure(nominal_range,
            incidence, rng)`` (the :class:`~sensor_envs.lidar.sensors.LidarSensor` protocol).
        model: model file of the learned lidar (``None``: the shipped ``models/neato_lidar.npz``); must have
            ``n_bearings`` bearings.
        lidar_kwargs: keyword arguments of the lidar's constructor (e.g. ``{"sigma0": 0.01}`` for the Gaussian
            lidar).
        n_bearings: bearings per scan, evenly spaced over 360 degrees (> 0).
        max_range: the lidar's maximum range [m] (> 0): readings beyond it are nulls.
        null_value: what a null reads in the observation: ``"zero"``, ``"max"`` (``max_range``) or ``"nan"``
            (outside the Box: for perception work, not for RL checkers).
        dt: seconds per step (> 0).
        v_max: forward speed at ``a[0] = 1`` [m/s] (> 0).
        omega_max: turn rate at ``a[1] = 1`` [rad/s] (> 0).
        robot_radius: the robot's radius [m] (> 0): a wall nearer than this to its centre is a collision.
        goal_tolerance: distance to the goal that counts as reached [m].
        goal_heading_tolerance: if set, the heading must also be within this of the goal's [rad].
        min_goal_distance: least distance between a drawn start and goal [m].
        progress_reward: reward per metre of progress toward the goal.
        step_penalty: penalty per step.
        goal_reward: reward on reaching the goal.
        collision_penalty: penalty on touching a wall.
        render_mode: ``"rgb_array"`` (map, robot, goal, rays and returns) or ``None``.

    Raises:
        ValueError: for a bad argument (naming it), or a learned model whose extra state the world cannot supply.

    Examples:
        >>> import gymnasium as gym
        >>> import sensor_envs
        >>> env = gym.make("sensor_envs/Neato-v0", lidar="learned", map="cluttered")
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape  # 360 ranges [m], goal x, y [m], heading error [rad]
        (363,)
        >>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        >>> sorted(info)[:4]
        ['collision', 'distance_to_goal', 'goal', 'ideal_scan']
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(
        self,
        *,
        map: str | PathLike[str] | SegmentMap | NDArray[np.float64] = "seed_room",
        lidar: str | LidarSensor = "ideal",
        model: str | PathLike[str] | None = None,
        lidar_kwargs: dict[str, Any] | None = None,
        n_bearings: int = 360,
        max_range: float = 5.0,
        null_value: str = "zero",
        dt: float = 0.2,
        v_max: float = 0.3,
        omega_max: float = 2.0,
        robot_radius: float = 0.17,
        goal_tolerance: float = 0.15,
        goal_heading_tolerance: float | None = None,
        min_goal_distance: float = 0.5,
        progress_reward: float = 10.0,
        step_penalty: float = 0.01,
        goal_reward: float = 10.0,
        collision_penalty: float = 10.0,
        render_mode: str | None = None,
    ) -> None:
        if lidar_kwargs is not None and not isinstance(lidar_kwargs, dict):
            raise InputError(f"lidar_kwargs: expected a dict or None, got {type(lidar_kwargs).__name__}")
        if not isinstance(null_value, str) or null_value not in NULL_VALUES:
            raise InputError(f"null_value: expected one of {NULL_VALUES}, got {null_value!r}")
        if render_mode is not None and (
            not isinstance(render_mode, str) or render_mode not in self.metadata["render_modes"]
        ):
            raise InputError(
                f"render_mode: expected one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        validate_params(
            {
                "n_bearings": n_bearings,
                "max_range": max_range,
                "dt": dt,
                "v_max": v_max,
                "omega_max": omega_max,
                "robot_radius": robot_radius,
                "goal_tolerance": goal_tolerance,
                "goal_heading_tolerance": goal_heading_tolerance,
                "min_goal_distance": min_goal_distance,
                "progress_reward": progress_reward,
                "step_penalty": step_penalty,
                "goal_reward": goal_reward,
                "collision_penalty": collision_penalty,
            },
            NEATO_CONSTRAINTS,
        )
        self.world_map = load_map(map)
        self.lidar = make_lidar(lidar, model=model, **(lidar_kwargs or {}))
        self._extra_names = lidar_extra_state(self.lidar)
        missing = [n for n in self._extra_names if split_term(n)[0] not in WORLD_STATE]
        if missing:
            raise InputError(
                f"lidar: the learned model's state names {missing}, which Neato-v0 cannot supply "
                f"(it supplies {list(WORLD_STATE)})"
            )
        self._motion = np.zeros(3)  # v [m/s], omega [rad/s], time since reset [s]
        self._prev_res = np.zeros(n_bearings)
        self.bearings = np.deg2rad(np.arange(n_bearings) * (360.0 / n_bearings))
        self.max_range, self.null_value, self.dt = float(max_range), null_value, float(dt)
        self.robot_radius, self.goal_tolerance = float(robot_radius), float(goal_tolerance)
        self.goal_heading_tolerance, self.min_goal_distance = goal_heading_tolerance, float(min_goal_distance)
        self.rewards = (float(progress_reward), float(step_penalty), float(goal_reward), float(collision_penalty))
        self.render_mode = render_mode
        xmin, ymin, xmax, ymax = self.world_map.bounds
        self._diag = float(np.hypot(xmax - xmin, ymax - ymin))
        self.v_max, self.omega_max = float(v_max), float(omega_max)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        low = np.concatenate([np.zeros(n_bearings), [-self._diag, -self._diag, -np.pi]]).astype(np.float32)
        high = np.concatenate([np.full(n_bearings, self.max_range), [self._diag, self._diag, np.pi]]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._sensor_rng: np.random.Generator | None = None
        self.pose = np.zeros(3)
        self.goal = np.zeros(3)
        self._last: dict[str, Any] = {}

    # ----------------------------------------------------------------------------------- gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Start a new episode; ``options`` may fix ``start`` and/or ``goal`` poses ``(x, y, theta)``."""
        self.start_episode(seed=seed, options=options)
        obs, info = self._observe(collision=False)
        self._prev_dist = info["distance_to_goal"]
        return obs, info

    def start_episode(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        """:meth:`reset` without the first observation: seed the streams, then draw (or take) start and goal.

        The vector entry point starts its robots' episodes with this and observes them all in one batch.
        """
        seed = check_seed(seed)
        options = check_options(options, ("start", "goal"))
        super().reset(seed=seed)
        self._sensor_rng = sensor_rng(seed, _LIDAR_TAG, self._sensor_rng)
        self._motion, self._prev_res = np.zeros(3), np.zeros(self.bearings.size)
        self.pose = self._pose_option(options, "start") if "start" in options else self._sample_free_pose()
        if "goal" in options:
            self.goal = self._pose_option(options, "goal")
        else:
            self.goal = self._sample_free_pose(away_from=self.pose[:2])

    def step(self, action: NDArray[np.float32]) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Drive with normalised ``(v, omega)``, each in ``[-1, 1]`` (the action space), for ``dt`` seconds.

        Raises:
            gymnasium.error.ResetNeeded: when called before :meth:`reset`.
            InputError: for an action outside the action space: not two finite numbers in ``[-1, 1]`` (never
                clipped silently; SB3 clips its policies' actions to the space before ``step``).
        """
        if self._sensor_rng is None:
            raise gym.error.ResetNeeded("Neato-v0: call reset() before step()")
        a = check_array(_one_row(action), "action", (2,), low=-1.0, high=1.0)
        self.pose = unicycle_step(self.pose, a[0] * self.v_max, a[1] * self.omega_max, self.dt)
        self._motion = np.array([a[0] * self.v_max, a[1] * self.omega_max, self._motion[2] + self.dt])
        collision = self._collides(self.pose)
        obs, info = self._observe(collision=collision)
        reward = step_reward(self.rewards, self._prev_dist, info["distance_to_goal"], info["is_success"], collision)
        self._prev_dist = info["distance_to_goal"]
        return obs, float(reward), bool(info["is_success"] or collision), False, info

    def render(self) -> NDArray[np.uint8] | None:
        """An RGB image of map, robot, goal, rays and hits (``render_mode="rgb_array"``)."""
        if self.render_mode != "rgb_array":
            return None
        return render_world(
            self.world_map.segments,
            self.pose,
            self.goal,
            self.bearings,
            self._last.get("scan", np.zeros(self.bearings.shape)),
            self.robot_radius,
        )

    # ----------------------------------------------------------------------------------- internals
    def _observe(self, collision: bool) -> tuple[NDArray[np.float32], dict[str, Any]]:
        assert self._sensor_rng is not None
        extra = self._extra_state() if self._extra_names else None
        obs, batch = observe_batch(
            self, self.pose[None], self.goal[None], [self._sensor_rng], np.array([collision]), extra=extra
        )
        info = {key: val[0] for key, val in batch.items()}
        if self._extra_names:
            self._prev_res = self._residual(info["ideal_scan"], info["incidence"], info["scan"])
        info["distance_to_goal"] = float(info["distance_to_goal"])
        info["is_success"], info["collision"] = bool(info["is_success"]), bool(info["collision"])
        self._last = info
        return obs[0], info

    def _extra_state(self) -> NDArray[np.float64]:
        """``(1, K, d)`` values of the learned lidar's extra state variables (see :data:`WORLD_STATE`)."""
        k = self.bearings.size
        cols = {"v": self._motion[0], "omega": self._motion[1], "t": self._motion[2], "prev_residual": self._prev_res}
        terms = [split_term(n) for n in self._extra_names]  # a term may interact with the bearing or the ray
        nominal = incidence = None
        if any(needs_geometry(m) for _, m in terms):  # the ray's nominal range, incidence, range slope
            ray = raycast_pose(self.pose[None], self.bearings, self.world_map.segments, self.max_range)
            nominal, incidence = ray[0][0], ray[1][0]
        vals = [
            modify(np.broadcast_to(cols[n], (k,)).astype(np.float64), m, self.bearings, nominal, incidence)
            for n, m in terms
        ]
        return np.stack(vals, axis=-1)[None]

    def _residual(
        self, nominal: NDArray[np.float64], incidence: NDArray[np.float64], scan: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Each bearing's residual from the learned lidar's table mean (the next scan's ``prev_residual``)."""
        from sensor_envs.lidar.extra_state import base_residual

        model = self.lidar.model  # type: ignore[attr-defined]  # a LearnedLidar: only it has extra state
        mu = model.params_from_features(nominal, incidence, base_only=True)["mu"]
        return base_residual(scan, mu, np.isfinite(nominal))

    def _collides(self, pose: NDArray[np.float64]) -> bool:
        return bool(collides(pose, self.world_map.segments, self.robot_radius)[0])

    def _pose_option(self, options: dict[str, Any], key: str) -> NDArray[np.float64]:
        p = check_array(options[key], f"options[{key!r}]", (3,), low=-1e6, high=1e6)  # a finite pose (x, y, theta)
        if abs(p[2]) > 4 * np.pi:  # any heading is written within +-2 pi; 1e6 rad is a unit or parsing slip
            raise InputError(f"options[{key!r}]: heading {p[2]:g} rad is beyond +-4 pi")
        if not self._enclosed(p):
            raise InputError(f"options[{key!r}]: {options[key]!r} lies outside map {self.world_map.name!r}")
        if key == "start" and self._collides(p):
            raise InputError(
                f"options[{key!r}]: {options[key]!r} is within the robot radius {self.robot_radius} m of a wall"
            )
        return p

    def _enclosed(self, p: NDArray[np.float64]) -> bool:
        """Whether rays in 8 directions from ``p`` all hit the map (``p`` lies inside its enclosure)."""
        return bool(
            np.isfinite(raycast_pose(p, np.linspace(0, 2 * np.pi, 8, endpoint=False), self.world_map.segments)[0]).all()
        )

    def _sample_free_pose(self, away_from: NDArray[np.float64] | None = None, tries: int = 2000) -> NDArray[np.float64]:
        """A pose with clearance from every wall, enclosed by the map, drawn from the world's stream."""
        clearance = self.robot_radius + 0.08
        try:
            return sample_free_poses(
                self.world_map.segments,
                1,
                self.np_random,
                clearance,
                away_from=away_from,
                min_distance=self.min_goal_distance,
                enclosure_rays=8,
                max_tries=tries // 4,  # 4 candidates per try
            )[0]
        except ValueError:
            raise InputError(
                f"map {self.world_map.name!r}: found no free pose with {clearance:.2f} m clearance "
                f"in {tries} tries; is the map enclosed and large enough for the robot?"
            ) from None


def unicycle_step(pose: ArrayLike, v: ArrayLike, omega: ArrayLike, dt: float) -> NDArray[np.float64]:
    """Exact differential-drive motion: arc of speed ``v`` [m/s] and turn rate ``omega`` [rad/s] for ``dt`` [s].

    Args:
        pose: ``(3,)`` or ``(N, 3)`` poses ``x, y, theta`` in the map frame [m, rad].
        v: speed(s) [m/s], broadcast against the poses' leading axes.
        omega: turn rate(s) [rad/s]; below 1e-9 in magnitude the robot drives straight.
        dt: duration [s].

    Returns:
        The poses after ``dt``, shaped like ``pose``; the heading is wrapped to [-pi, pi) after a turn.
    """
    p = np.asarray(pose, dtype=np.float64)
    x, y, th = p[..., 0], p[..., 1], p[..., 2]
    v, omega = np.asarray(v, dtype=np.float64), np.asarray(omega, dtype=np.float64)
    straight = np.abs(omega) < 1e-9
    th2 = th + omega * dt
    with np.errstate(divide="ignore", invalid="ignore"):
        r = v / omega
        arc = np.stack([x + r * (np.sin(th2) - np.sin(th)), y - r * (np.cos(th2) - np.cos(th)), wrap_angle(th2)], -1)
    line = np.stack([x + v * dt * np.cos(th), y + v * dt * np.sin(th), th], axis=-1)
    return np.where(straight[..., None], line, arc)


def apply_null(raw: NDArray[np.float64], max_range: float, null_value: str) -> NDArray[np.float64]:
    """Readings [m] with nulls (NaN, ``<= 0`` or beyond ``max_range``) set to the ``null_value`` fill."""
    null = ~np.isfinite(raw) | (raw > max_range) | (raw <= 0.0)
    return np.where(null, null_fill(null_value, max_range), raw)


def null_fill(null_value: str, max_range: float) -> float:
    """The reading [m] a null stands as in the observation: 0, NaN or ``max_range`` (see :data:`NULL_VALUES`)."""
    return {"zero": 0.0, "nan": np.nan, "max": max_range}[null_value]


def finish_observation(
    raw: NDArray[np.float64],
    incidence: NDArray[np.float64],
    goal_rel: NDArray[np.float64],
    dth: NDArray[np.float64],
    low: NDArray[np.float32],
    high: NDArray[np.float32],
    max_range: float,
    null_value: str,
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
    """Observations of N robots and the NaN-free ``scan`` and ``incidence`` of their ``info``.

    Args:
        raw: ``(N, K)`` lidar readings [m], NaN = null.
        incidence: ``(N, K)`` incidence [rad], NaN where no hit.
        goal_rel: ``(N, 2)`` goal position in the robot frame [m].
        dth: ``(N,)`` goal heading minus robot heading [rad].
        low: the observation space's float32 lower bounds ``(K + 3,)``.
        high: its upper bounds ``(K + 3,)``.
        max_range: readings beyond it [m] are nulls.
        null_value: the nulls' fill (see :data:`NULL_VALUES`).

    Returns:
        ``obs (N, K + 3)`` float32: :func:`apply_null`'s ranges, ``goal_rel``, ``dth``, cast to float32 and
        clipped to the bounds; ``raw`` and ``incidence`` with NaN as 0 (``np.nan_to_num``). With numba one
        compiled pass computes the same bits as those numpy calls.
    """
    kernel = compiled(_finish_loops)
    if kernel is not None:
        return kernel(
            np.ascontiguousarray(raw, dtype=np.float64),
            np.ascontiguousarray(incidence, dtype=np.float64),
            np.ascontiguousarray(goal_rel, dtype=np.float64),
            np.ascontiguousarray(dth, dtype=np.float64),
            np.ascontiguousarray(low, dtype=np.float32),
            np.ascontiguousarray(high, dtype=np.float32),
            float(max_range),
            float(null_fill(null_value, max_range)),
        )
    ranges = apply_null(raw, max_range, null_value)
    obs = np.concatenate([ranges, goal_rel, dth[:, None]], axis=1).astype(np.float32)
    obs = np.clip(obs, low, high)
    return obs, np.nan_to_num(raw, nan=0.0), np.nan_to_num(incidence, nan=0.0)


def _finish_loops(
    raw: NDArray[np.float64],
    incidence: NDArray[np.float64],
    goal_rel: NDArray[np.float64],
    dth: NDArray[np.float64],
    low: NDArray[np.float32],
    high: NDArray[np.float32],
    max_range: float,
    fill: float,
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`finish_observation` in one loop over the cells: each value as the numpy calls compute it.

    ``np.clip`` is ``minimum(maximum(x, low), high)``, which keeps NaN; ``np.nan_to_num`` maps NaN to 0 and
    +-inf to the largest finite float64.
    """
    n, k = raw.shape
    obs = np.empty((n, k + 3), dtype=np.float32)
    scan = np.empty((n, k))
    inc = np.empty((n, k))
    big = np.finfo(np.float64).max
    for p in range(n):
        for j in range(k):  # selects, no branch: the loop vectorises (nulls are frequent and unpredictable)
            x = raw[p, j]
            null = (not math.isfinite(x)) | (x > max_range) | (x <= 0.0)
            f = np.float32(fill if null else x)
            f = low[j] if f < low[j] else f
            obs[p, j] = high[j] if f > high[j] else f
            scan[p, j] = 0.0 if math.isnan(x) else (big if x == math.inf else (-big if x == -math.inf else x))
            a = incidence[p, j]
            inc[p, j] = 0.0 if math.isnan(a) else (big if a == math.inf else (-big if a == -math.inf else a))
        for j in range(k, k + 3):
            f = np.float32(goal_rel[p, j - k] if j < k + 2 else dth[p])
            f = low[j] if f < low[j] else f
            obs[p, j] = high[j] if f > high[j] else f
    return obs, scan, inc


def collides(poses: ArrayLike, segments: NDArray[np.float64], robot_radius: float) -> NDArray[np.bool_]:
    """``(N,)`` whether a round robot of ``robot_radius`` [m] at ``(3,)``/``(N, 3)`` poses touches a wall."""
    return nearest_wall_distance(poses, segments) < robot_radius


def step_reward(
    rewards: tuple[float, float, float, float],
    prev_dist: ArrayLike,
    dist: ArrayLike,
    success: ArrayLike,
    collision: ArrayLike,
) -> Any:
    """Reward of a step: progress [m] times ``rewards[0]``, minus the step penalty, plus goal, minus collision.

    ``rewards = (progress_reward, step_penalty, goal_reward, collision_penalty)``; the other arguments are
    scalars (a float is returned) or ``(N,)`` arrays (an ``(N,)`` array is returned).
    """
    k_prog, k_step, k_goal, k_col = rewards
    reward = k_prog * (np.asarray(prev_dist) - np.asarray(dist)) - k_step
    reward = np.where(success, reward + k_goal, reward)
    reward = np.where(collision, reward - k_col, reward)
    return float(reward) if reward.ndim == 0 else reward


def lidar_extra_state(lidar: LidarSensor) -> tuple[str, ...]:
    """Names of a learned lidar's extra state variables (``()`` for other lidars or a model without any)."""
    model = getattr(lidar, "model", None)
    return extra_state_names(model) if model is not None else ()


def measure_rows(
    lidar: LidarSensor,
    nominal: NDArray[np.float64],
    incidence: NDArray[np.float64],
    rngs: list[np.random.Generator] | RowGenerators,
    extra: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Readings ``(N, K)`` [m] (NaN = null) for N robots; row ``i`` draws from ``rngs[i]`` only.

    The shipped lidars broadcast over leading axes, so they serve all robots in one call (per-row draws
    through :class:`~sensor_envs.rng.RowGenerators`, the same numbers as N separate calls); any other
    :class:`LidarSensor` is called once per robot with ``(K,)`` arrays, as its protocol states.
    """
    lwlr = sys.modules.get("sensor_envs.lidar.lwlr")  # a LearnedLidar exists only once its module is loaded
    if isinstance(lidar, _BATCHED_LIDARS + ((lwlr.LearnedLidar,) if lwlr is not None else ())):
        rng = rngs if isinstance(rngs, RowGenerators) else rngs[0] if len(rngs) == 1 else RowGenerators(rngs)
        if extra is not None:  # only a LearnedLidar has extra state
            return np.asarray(lidar.measure(nominal, incidence, rng, extra=extra), dtype=np.float64)
        return np.asarray(lidar.measure(nominal, incidence, rng), dtype=np.float64)
    gens = rngs.generators if isinstance(rngs, RowGenerators) else rngs
    rows = zip(nominal, incidence, gens, strict=True)
    return np.stack([np.asarray(lidar.measure(n, a, g), dtype=np.float64) for n, a, g in rows])


def observe_batch(
    env: NeatoEnv,
    poses: NDArray[np.float64],
    goals: NDArray[np.float64],
    rngs: list[np.random.Generator] | RowGenerators,
    collision: NDArray[np.bool_],
    extra: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float32], dict[str, NDArray[Any]]]:
    """Observations ``(N, K + 3)`` and info arrays of N robots in ``env``'s world, one raycast and one lidar call.

    Args:
        env: the world (map, bearings, lidar, ranges, tolerances and observation bounds are read from it).
        poses: ``(N, 3)`` true robot poses [m, rad] in the map frame.
        goals: ``(N, 3)`` goal poses [m, rad].
        rngs: the N robots' lidar generators (a :class:`~sensor_envs.rng.RowGenerators` that a caller keeps
            across steps saves building one per call).
        collision: ``(N,)`` whether each robot touches a wall.
        extra: ``(N, K, d)`` values of a learned lidar's extra state variables, or ``None``.

    Returns:
        ``obs`` (see :class:`NeatoEnv`) and the ``info`` entries of :class:`NeatoEnv`, each with a leading
        robot axis.
    """
    nominal, incidence, _ = raycast_pose(poses, env.bearings, env.world_map.segments, env.max_range)
    raw = measure_rows(env.lidar, nominal, incidence, rngs, extra)
    goal_rel = to_frame(goals[:, :2], poses.T)
    dth = wrap_angle(goals[:, 2] - poses[:, 2])
    box = env.observation_space
    assert isinstance(box, spaces.Box)
    obs, scan, incidence_info = finish_observation(
        raw, incidence, goal_rel, dth, box.low, box.high, env.max_range, env.null_value
    )
    d = goals[:, :2] - poses[:, :2]
    dist = np.hypot(d[:, 0], d[:, 1])
    success = (dist <= env.goal_tolerance) & ~collision
    if env.goal_heading_tolerance is not None:
        success &= np.abs(dth) <= env.goal_heading_tolerance
    info = {
        "pose": poses.copy(),
        "ideal_scan": nominal,
        "incidence": incidence_info,
        "scan": scan,
        "goal": goals.copy(),
        "distance_to_goal": dist,
        "is_success": success,
        "collision": np.asarray(collision, dtype=bool).copy(),
    }
    return obs, info
