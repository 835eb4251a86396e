"""N Neato robots stepped together: the vector entry point of ``sensor_envs/Neato-v0``.

``gym.make_vec("sensor_envs/Neato-v0", num_envs=N, vectorization_mode="vector_entry_point", **kwargs)``
builds a :class:`NeatoVectorEnv`: one batched raycast (``N`` poses x ``K`` bearings) and one batched lidar
call per step serve all robots, instead of N Python-level env steps. The world, dynamics, reward and
observation are :class:`~sensor_envs.envs.neato.NeatoEnv`'s own functions; resets are done by N
``NeatoEnv`` instances (sharing one map and one lidar), so start/goal sampling, seeding and ``options``
are exactly the single env's.

Seeding and autoreset follow gymnasium 1.x's :class:`~gymnasium.vector.SyncVectorEnv`: ``reset(seed=s)``
seeds robot ``i`` with ``s + i`` (or takes a list of seeds); autoreset is ``NEXT_STEP`` (the step after an
episode ends resets that robot, ignores its action and returns reward 0, not terminated, not truncated).
Hence the same seeds give the same observations, rewards and infos as ``SyncVectorEnv`` over N single
envs. ``info`` holds the single env's entries stacked along a leading robot axis, each with its
``_key`` mask.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from sensor_envs.envs.neato import NeatoEnv, collides, observe_batch, step_reward, unicycle_step
from sensor_envs.envs.neato_render import render_world
from sensor_envs.heap import keep_freed_heap
from sensor_envs.rng import RowGenerators

__all__ = ["NeatoVectorEnv"]


class NeatoVectorEnv(VectorEnv[NDArray[np.float32], NDArray[np.float32], NDArray[Any]]):
    """``num_envs`` Neato robots in one world configuration, stepped with batched numpy calls.

    Args:
        num_envs: number of robots N (independent episodes).
        max_episode_steps: episodes are truncated after this many steps (the registration's 500).
        render_mode: ``"rgb_array"`` renders one image per robot, or None.
        **kwargs: :class:`~sensor_envs.envs.neato.NeatoEnv` keyword arguments (``lidar``, ``map``, ...).

    Construction calls :func:`~sensor_envs.heap.keep_freed_heap` (glibc keeps freed memory for reuse, so the
    step's batch arrays do not page-fault; ``SENSOR_ENVS_NO_HEAP_TUNING=1`` turns it off).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self, num_envs: int = 1, max_episode_steps: int = 500, render_mode: str | None = None, **kwargs: Any
    ) -> None:
        if int(num_envs) < 1:
            raise ValueError(f"num_envs: must be >= 1, got {num_envs!r}")
        if int(max_episode_steps) < 1:
            raise ValueError(f"max_episode_steps: must be >= 1, got {max_episode_steps!r}")
        first = NeatoEnv(render_mode=render_mode, **kwargs)
        keep_freed_heap()
        if first._extra_names:
            raise ValueError(
                f"lidar: the vector Neato entry does not supply extra lidar state yet; the model's state names "
                f"{list(first._extra_names)} (use Neato-v0)"
            )
        shared = {k: v for k, v in kwargs.items() if k not in ("lidar", "model", "lidar_kwargs", "map")}
        self.envs = [first] + [
            NeatoEnv(render_mode=render_mode, map=first.world_map, lidar=first.lidar, **shared)
            for _ in range(int(num_envs) - 1)
        ]
        self.num_envs, self.max_episode_steps, self.render_mode = int(num_envs), int(max_episode_steps), render_mode
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        n = self.num_envs
        self._obs_shape = (n, int(first.observation_space.shape[0]))  # type: ignore[index]
        self._pose, self._goal = np.zeros((n, 3)), np.zeros((n, 3))
        self._prev_dist = np.zeros(n)
        self._steps = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=bool)
        self._scan = np.zeros((n, first.bearings.size))
        self._obs = np.zeros(self._obs_shape, dtype=np.float32)
        self._rngs: RowGenerators | None = None  # the robots' lidar generators, kept across steps
        self._started = False

    # ----------------------------------------------------------------------------------- gym API
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Reset the robots (all, or those of ``options["reset_mask"]``); seeds as in ``SyncVectorEnv``."""
        super().reset(seed=int(seed) if isinstance(seed, (int, np.integer)) else None)
        options = dict(options or {})
        mask = np.asarray(options.pop("reset_mask", np.ones(self.num_envs, dtype=bool)))
        if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
            raise ValueError(f"options['reset_mask']: expected a bool array of shape ({self.num_envs},)")
        if seed is None or isinstance(seed, (int, np.integer)):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed: expected {self.num_envs} seeds, got {len(seeds)}")
        rows = np.flatnonzero(mask)
        infos = self._reset_rows(rows, self._obs, seeds=[seeds[i] for i in rows], options=options or None)
        if self._rngs is None:
            self._rngs = RowGenerators([e._sensor_rng for e in self.envs])  # type: ignore[misc]
        for i in rows:  # a seeded reset gives a robot a new stream
            self._rngs.replace(int(i), self.envs[i]._sensor_rng)  # type: ignore[arg-type]
        self._steps[rows] = 0
        self._autoreset[rows] = False
        self._started = True
        return self._obs.copy(), _with_masks(infos, mask)

    def step(
        self, actions: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Drive every robot with its normalised ``(v, omega)`` row of ``actions`` (clipped to [-1, 1])."""
        if not self._started:
            raise RuntimeError("NeatoVectorEnv: call reset() before step()")
        a = np.clip(np.asarray(actions, dtype=np.float64).reshape(self.num_envs, 2), -1.0, 1.0)
        env = self.envs[0]
        done_before = self._autoreset.copy()
        live = np.flatnonzero(~done_before)
        obs = np.zeros(self._obs_shape, dtype=np.float32)
        reward = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        info: dict[str, NDArray[Any]] = {}
        if live.size:
            pose = unicycle_step(self._pose[live], a[live, 0] * env.v_max, a[live, 1] * env.omega_max, env.dt)
            hit = collides(pose, env.world_map.segments, env.robot_radius)
            assert self._rngs is not None
            rngs = self._rngs if live.size == self.num_envs else self._rngs.select(live)
            live_obs, info = observe_batch(env, pose, self._goal[live], rngs, hit)
            dist, success = info["distance_to_goal"], info["is_success"]
            reward[live] = step_reward(env.rewards, self._prev_dist[live], dist, success, hit)
            self._pose[live], self._prev_dist[live], self._scan[live] = pose, dist, info["scan"]
            self._steps[live] += 1
            obs[live] = live_obs
            terminated[live] = success | hit
            truncated[live] = self._steps[live] >= self.max_episode_steps
            info = {k: _scatter(v, live, self.num_envs) for k, v in info.items()}
        rows = np.flatnonzero(done_before)
        if rows.size:
            resets = self._reset_rows(rows, obs, seeds=[None] * rows.size, options=None)
            for k, v in resets.items():
                if k not in info:
                    info[k] = np.zeros_like(v)
                info[k][rows] = v[rows]
            self._steps[rows] = 0
        self._autoreset = terminated | truncated
        self._obs = obs
        return obs.copy(), reward, terminated, truncated, _with_masks(info, np.ones(self.num_envs, dtype=bool))

    def render(self) -> tuple[NDArray[np.uint8], ...] | None:
        """One RGB image per robot (``render_mode="rgb_array"``), else None."""
        if self.render_mode != "rgb_array":
            return None
        env = self.envs[0]
        segs = env.world_map.segments
        return tuple(
            render_world(segs, p, g, env.bearings, s, env.robot_radius)
            for p, g, s in zip(self._pose, self._goal, self._scan, strict=True)
        )

    # ----------------------------------------------------------------------------------- internals
    def _reset_rows(
        self, rows: NDArray[np.int64], obs: NDArray[np.float32], seeds: list[int | None], options: dict[str, Any] | None
    ) -> dict[str, NDArray[Any]]:
        """Reset robots ``rows`` through their single envs; fill ``obs`` rows; return the infos stacked (N, ...)."""
        infos: dict[str, NDArray[Any]] = {}
        for i, s in zip(rows, seeds, strict=True):
            e = self.envs[i]
            o, inf = e.reset(seed=s, options=options)
            obs[i] = o
            self._pose[i], self._goal[i], self._prev_dist[i] = e.pose, e.goal, inf["distance_to_goal"]
            self._scan[i] = inf["scan"]
            for k, v in inf.items():
                if k not in infos:
                    infos[k] = np.zeros((self.num_envs, *np.shape(v)), dtype=np.asarray(v).dtype)
                infos[k][i] = v
        return infos


def _scatter(values: NDArray[Any], rows: NDArray[np.int64], n: int) -> NDArray[Any]:
    """``values`` for ``rows`` placed into a zero array with ``n`` rows."""
    if rows.size == n:
        return values
    out = np.zeros((n, *values.shape[1:]), dtype=values.dtype)
    out[rows] = values
    return out


def _with_masks(info: dict[str, NDArray[Any]], mask: NDArray[np.bool_]) -> dict[str, Any]:
    """Gymnasium's vector ``info`` layout: each entry beside a ``_key`` mask of the robots that report it."""
    out: dict[str, Any] = {}
    for k, v in info.items():
        out[k], out[f"_{k}"] = v, mask.copy()
    return out
