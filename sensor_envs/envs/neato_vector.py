"""N Neato robots stepped together: the vector entry point of ``sensor_envs/Neato-v0``.

``gym.make_vec("sensor_envs/Neato-v0", num_envs=N, vectorization_mode="vector_entry_point", **kwargs)``
builds a :class:`NeatoVectorEnv`: one batched raycast (``N`` poses x ``K`` bearings) and one batched lidar
call per step serve all robots, instead of N Python-level env steps. The world, dynamics, reward and
observation are :class:`~sensor_envs.envs.neato.NeatoEnv`'s own functions; episodes are started by N
``NeatoEnv`` instances (sharing one map and one lidar; :meth:`~sensor_envs.envs.neato.NeatoEnv.start_episode`),
so start/goal sampling, seeding and ``options`` are exactly the single env's, and the first observations
of the robots that start are made in the step's (or the reset's) one batched raycast and lidar call.

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

from sensor_envs import heap
from sensor_envs.envs.checks import check_options, check_seed
from sensor_envs.envs.neato import NeatoEnv, collides, observe_batch, step_reward, unicycle_step
from sensor_envs.envs.neato_render import render_world
from sensor_envs.inputs import InputError, check_array, check_count
from sensor_envs.rng import RowGenerators

__all__ = ["NeatoVectorEnv"]


class NeatoVectorEnv(VectorEnv[NDArray[np.float32], NDArray[np.float32], NDArray[Any]]):
    """``num_envs`` Neato robots in one world configuration, stepped with batched numpy calls.

    Args:
        num_envs: number of robots N (independent episodes).
        max_episode_steps: episodes are truncated after this many steps (the registration's 500).
        render_mode: ``"rgb_array"`` renders one image per robot, or None.
        tune_heap: if True, call :func:`~sensor_envs.heap.keep_freed_heap` (opt-in, off by default): glibc
            then keeps freed memory for reuse, so the step's batch arrays do not page-fault (~0.55 ms of a
            ~1.4 ms 64-robot ideal step). This changes the malloc settings of the whole process, for good;
            ``SENSOR_ENVS_NO_HEAP_TUNING=1`` vetoes it. The same effect from outside the process:
            ``MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=67108864``.
        **kwargs: :class:`~sensor_envs.envs.neato.NeatoEnv` keyword arguments (``lidar``, ``map``, ...).

    Construction leaves the process's malloc settings alone unless ``tune_heap=True``.

    Examples:
        >>> import gymnasium as gym
        >>> import sensor_envs
        >>> envs = gym.make_vec(
        ...     "sensor_envs/Neato-v0", num_envs=4, vectorization_mode="vector_entry_point", lidar="gaussian"
        ... )
        >>> obs, infos = envs.reset(seed=0)
        >>> obs.shape
        (4, 363)
        >>> obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())
        >>> rewards.shape
        (4,)
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int = 500,
        render_mode: str | None = None,
        tune_heap: bool = False,
        **kwargs: Any,
    ) -> None:
        check_count(num_envs, "num_envs", 1, 4096)
        check_count(max_episode_steps, "max_episode_steps", 1, 10**7)
        if not isinstance(tune_heap, (bool, np.bool_)):
            raise InputError(f"tune_heap: must be a bool, got {tune_heap!r}")
        first = NeatoEnv(render_mode=render_mode, **kwargs)
        if tune_heap:
            heap.keep_freed_heap()
        if first._extra_names:
            raise InputError(
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
        self._pose, self._goal = np.zeros((n, 3)), np.zeros((n, 3))
        self._prev_dist = np.zeros(n)
        self._steps = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=bool)
        self._scan = np.zeros((n, first.bearings.size))
        self._obs = np.zeros((n, int(first.observation_space.shape[0])), dtype=np.float32)  # type: ignore[index]
        self._rngs: RowGenerators | None = None  # the robots' lidar generators, kept across steps
        self._started = False

    # ----------------------------------------------------------------------------------- gym API
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float32], dict[str, Any]]:
        """Reset the robots (all, or those of ``options["reset_mask"]``); seeds as in ``SyncVectorEnv``."""
        if isinstance(seed, (list, tuple)):
            seed = [check_seed(v) for v in seed]
        else:
            seed = check_seed(seed)
        super().reset(seed=seed if isinstance(seed, int) else None)
        options = check_options(options, ("reset_mask", "start", "goal"))
        mask = np.asarray(options.pop("reset_mask", np.ones(self.num_envs, dtype=bool)))
        if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
            raise InputError(f"options['reset_mask']: expected a bool array of shape ({self.num_envs},)")
        if seed is None or isinstance(seed, (int, np.integer)):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise InputError(f"seed: expected {self.num_envs} seeds, got {len(seeds)}")
        rows = np.flatnonzero(mask)
        self._start_rows(rows, [seeds[i] for i in rows], options or None)
        rngs = self._row_generators()
        obs, info = observe_batch(
            self.envs[0],
            self._pose[rows],
            self._goal[rows],
            rngs if rows.size == self.num_envs else rngs.select(rows),
            np.zeros(rows.size, dtype=bool),
        )
        # new arrays, not writes into the old: a step's info holds the old ones (a caller may keep that info)
        self._prev_dist, self._scan = self._prev_dist.copy(), self._scan.copy()
        self._obs[rows], self._prev_dist[rows], self._scan[rows] = obs, info["distance_to_goal"], info["scan"]
        self._steps[rows] = 0
        self._autoreset[rows] = False
        self._started = True
        return self._obs.copy(), _with_masks({k: _scatter(v, rows, self.num_envs) for k, v in info.items()}, mask)

    def step(
        self, actions: NDArray[np.float32]
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Drive every robot with its normalised ``(v, omega)`` row of ``actions``, each in ``[-1, 1]``.

        Raises:
            InputError: for actions outside the action space (not ``(num_envs, 2)`` finite numbers in
                ``[-1, 1]``; never clipped silently), as ``Neato-v0``'s ``step``.
        """
        if not self._started:
            raise RuntimeError("NeatoVectorEnv: call reset() before step()")
        # exactly the action space's (num_envs, 2): a flat (2 num_envs,) batch is refused, not reshaped
        a = check_array(actions, "actions", (self.num_envs, 2), low=-1.0, high=1.0)
        env = self.envs[0]
        restart = self._autoreset  # these robots start a new episode this step (NEXT_STEP autoreset)
        # every robot moves (numpy's elementwise arithmetic: a row's result does not depend on the others);
        # the restarting robots' new poses are then replaced by their episodes' starts
        pose = unicycle_step(self._pose, a[:, 0] * env.v_max, a[:, 1] * env.omega_max, env.dt)
        hit = collides(pose, env.world_map.segments, env.robot_radius) & ~restart
        self._pose = pose
        rows = np.flatnonzero(restart)
        if rows.size:
            self._start_rows(rows, [None] * rows.size, None)
        obs, info = observe_batch(env, self._pose, self._goal, self._row_generators(), hit)
        dist, success = info["distance_to_goal"], info["is_success"]
        reward = np.where(restart, 0.0, step_reward(env.rewards, self._prev_dist, dist, success, hit))
        terminated = (success | hit) & ~restart
        self._steps = np.where(restart, 0, self._steps + 1)
        truncated = (self._steps >= self.max_episode_steps) & ~restart
        self._prev_dist, self._scan = dist, info["scan"]
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
    def _start_rows(self, rows: NDArray[np.int64], seeds: list[int | None], options: dict[str, Any] | None) -> None:
        """Start new episodes of robots ``rows`` through their single envs (seeds, start and goal poses).

        Their first observations are then made in one batch with the others, as each single env's
        ``reset`` would make it (the same draws of its own sensor stream).
        """
        for i, s in zip(rows, seeds, strict=True):
            e = self.envs[i]
            e.start_episode(seed=s, options=options)
            self._pose[i], self._goal[i] = e.pose, e.goal
            if self._rngs is not None:  # a seeded start gives the robot a new stream
                self._rngs.replace(int(i), e._sensor_rng)

    def _row_generators(self) -> RowGenerators:
        """The robots' lidar generators, row ``i`` robot ``i``'s (built once, kept across steps)."""
        if self._rngs is None:
            self._rngs = RowGenerators([e._sensor_rng for e in self.envs])  # type: ignore[misc]
        return self._rngs


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
