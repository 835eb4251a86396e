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

from os import PathLike
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from sensor_envs.envs.neato_render import render_world
from sensor_envs.geometry import point_segment_distance, raycast_pose, sample_free_poses, to_frame, wrap_angle
from sensor_envs.lidar.sensors import LidarSensor, make_lidar
from sensor_envs.maps import SegmentMap, load_map
from sensor_envs.rng import sensor_rng

__all__ = ["NeatoEnv", "NULL_VALUES"]

NULL_VALUES = ("zero", "nan", "max")
_LIDAR_TAG = 0x4C494441  # "LIDA": tags the lidar's stream derived from the reset seed


class NeatoEnv(gym.Env[NDArray[np.float32], NDArray[np.float32]]):
    """A Neato-like robot (radius 0.17 m) with a planar lidar, driving to a goal in a segment map."""

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
        if null_value not in NULL_VALUES:
            raise ValueError(f"null_value: expected one of {NULL_VALUES}, got {null_value!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode: expected one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        for name, val in (
            ("n_bearings", n_bearings),
            ("max_range", max_range),
            ("dt", dt),
            ("v_max", v_max),
            ("omega_max", omega_max),
            ("robot_radius", robot_radius),
        ):
            if not val > 0:
                raise ValueError(f"{name}: must be > 0, got {val!r}")
        self.world_map = load_map(map)
        self.lidar = make_lidar(lidar, model=model, **(lidar_kwargs or {}))
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
        super().reset(seed=seed)
        self._sensor_rng = sensor_rng(seed, _LIDAR_TAG, self._sensor_rng)
        options = dict(options or {})
        unknown = set(options) - {"start", "goal"}
        if unknown:
            raise ValueError(f"options: unknown keys {sorted(unknown)}; expected 'start' and/or 'goal'")
        self.pose = self._pose_option(options, "start") if "start" in options else self._sample_free_pose()
        if "goal" in options:
            self.goal = self._pose_option(options, "goal")
        else:
            self.goal = self._sample_free_pose(away_from=self.pose[:2])
        obs, info = self._observe(collision=False)
        self._prev_dist = info["distance_to_goal"]
        return obs, info

    def step(self, action: NDArray[np.float32]) -> tuple[NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        """Drive with normalised ``(v, omega)`` (clipped to ``[-1, 1]``) for ``dt`` seconds.

        Raises:
            gymnasium.error.ResetNeeded: when called before :meth:`reset`.
            ValueError: for an action that is not two finite numbers (NaN cannot be clipped).
        """
        if self._sensor_rng is None:
            raise gym.error.ResetNeeded("Neato-v0: call reset() before step()")
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action: expected two numbers (v, omega) in [-1, 1], got {action!r}") from None
        if a.size != 2 or not np.isfinite(a).all():
            raise ValueError(f"action: expected two finite numbers (v, omega) in [-1, 1], got {action!r}")
        a = np.clip(a.reshape(2), -1.0, 1.0)
        self.pose = unicycle_step(self.pose, a[0] * self.v_max, a[1] * self.omega_max, self.dt)
        collision = self._collides(self.pose)
        obs, info = self._observe(collision=collision)
        k_prog, k_step, k_goal, k_col = self.rewards
        reward = k_prog * (self._prev_dist - info["distance_to_goal"]) - k_step
        self._prev_dist = info["distance_to_goal"]
        if info["is_success"]:
            reward += k_goal
        if collision:
            reward -= k_col
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
        nominal, incidence, _ = raycast_pose(self.pose, self.bearings, self.world_map.segments, self.max_range)
        assert self._sensor_rng is not None
        raw = np.asarray(self.lidar.measure(nominal, incidence, self._sensor_rng), dtype=np.float64)
        ranges = self._apply_null(raw)
        goal_rel = to_frame(self.goal[:2], self.pose)
        dth = float(wrap_angle(self.goal[2] - self.pose[2]))
        obs = np.concatenate([ranges, goal_rel, [dth]]).astype(np.float32)
        obs = np.clip(obs, self.observation_space.low, self.observation_space.high)
        dist = float(np.hypot(*(self.goal[:2] - self.pose[:2])))
        success = (
            dist <= self.goal_tolerance
            and not collision
            and (self.goal_heading_tolerance is None or abs(dth) <= self.goal_heading_tolerance)
        )
        info = {
            "pose": self.pose.copy(),
            "ideal_scan": nominal,
            "incidence": np.nan_to_num(incidence, nan=0.0),
            "scan": np.nan_to_num(raw, nan=0.0),
            "goal": self.goal.copy(),
            "distance_to_goal": dist,
            "is_success": bool(success),
            "collision": bool(collision),
        }
        self._last = info
        return obs, info

    def _apply_null(self, raw: NDArray[np.float64]) -> NDArray[np.float64]:
        null = ~np.isfinite(raw) | (raw > self.max_range) | (raw <= 0.0)
        fill = {"zero": 0.0, "nan": np.nan, "max": self.max_range}[self.null_value]
        return np.where(null, fill, raw)

    def _collides(self, pose: NDArray[np.float64]) -> bool:
        return bool(point_segment_distance(pose[:2], self.world_map.segments).min() < self.robot_radius)

    def _pose_option(self, options: dict[str, Any], key: str) -> NDArray[np.float64]:
        p = np.asarray(options[key], dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"options[{key!r}]: expected a finite pose (x, y, theta), got {options[key]!r}")
        if not self._enclosed(p):
            raise ValueError(f"options[{key!r}]: {options[key]!r} lies outside map {self.world_map.name!r}")
        if key == "start" and self._collides(p):
            raise ValueError(
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
            raise ValueError(
                f"map {self.world_map.name!r}: found no free pose with {clearance:.2f} m clearance "
                f"in {tries} tries; is the map enclosed and large enough for the robot?"
            ) from None


def unicycle_step(pose: NDArray[np.float64], v: float, omega: float, dt: float) -> NDArray[np.float64]:
    """Exact differential-drive motion: arc of speed ``v`` [m/s] and turn rate ``omega`` [rad/s] for ``dt`` [s]."""
    x, y, th = pose
    if abs(omega) < 1e-9:
        return np.array([x + v * dt * np.cos(th), y + v * dt * np.sin(th), th])
    th2 = th + omega * dt
    r = v / omega
    return np.array([x + r * (np.sin(th2) - np.sin(th)), y - r * (np.cos(th2) - np.cos(th)), float(wrap_angle(th2))])
