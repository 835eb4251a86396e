"""A gymnasium 1.x ``VectorEnv`` as a stable-baselines3 ``VecEnv`` (for the vector entry point of Neato-v0).

SB3 trains on its own ``VecEnv`` API; :class:`SB3VecEnv` translates a gymnasium vector env to it, so that
``gym.make_vec("sensor_envs/Neato-v0", num_envs=N, vectorization_mode="vector_entry_point")`` (one batched
raycast for N robots) can replace SB3's ``DummyVecEnv`` of N single envs. :func:`make_sb3_vector_env`
builds the whole stack (vector entry point, adapter, SB3 ``VecMonitor`` for the episode statistics).

Autoreset: SB3 resets a finished sub-env in the SAME step (the returned observation is the first of the
next episode; ``infos[i]["terminal_observation"]`` is the last one), gymnasium's ``NEXT_STEP`` mode on the
step after. The adapter resets the finished rows at once with ``reset(options={"reset_mask": done})``,
which also clears their pending autoreset, so the vector env's next step steps every row with its action.
``DISABLED`` works the same way; ``SAME_STEP`` vector envs are refused.

Seeding follows ``DummyVecEnv``: ``seed(s)`` then ``reset()`` resets sub-env ``i`` with seed ``s + i``, later
resets continue each sub-env's streams; hence the same seed gives the same observations, rewards, dones and
infos as SB3's ``DummyVecEnv`` over N single envs (rewards as float32, scalar infos as Python scalars).

This module needs stable-baselines3 (the ``train`` extra); ``import sensor_envs`` never imports it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode, VectorEnv
from numpy.typing import NDArray
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sensor_envs.inputs import InputError

__all__ = ["SB3VecEnv", "make_sb3_vector_env", "unbatch_info"]


class SB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` view of a gymnasium ``VectorEnv`` with ``NEXT_STEP`` or ``DISABLED`` autoreset.

    Attributes and methods (``get_attr``, ``set_attr``, ``env_method``) are the vector env's own, one value
    shared by all sub-envs: ``get_attr`` repeats it per index; ``set_attr`` and ``env_method`` act once and
    only for all indices.

    Args:
        venv: the gymnasium vector env (array observations: ``Box``, ``Discrete``, ``MultiBinary``, ...);
            its ``reset`` must accept ``options["reset_mask"]`` (gymnasium's ``SyncVectorEnv`` and
            :class:`~sensor_envs.envs.neato_vector.NeatoVectorEnv` do).
    """

    def __init__(self, venv: VectorEnv[Any, Any, Any]) -> None:
        mode = venv.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED):
            raise InputError(f"venv: autoreset mode {mode!r} is not supported (NEXT_STEP or DISABLED)")
        if isinstance(venv.single_observation_space, (spaces.Dict, spaces.Tuple)):
            raise InputError("venv: only array observation spaces are supported, not Dict or Tuple")
        self.venv = venv
        self._actions: NDArray[Any] | None = None
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)

    # ------------------------------------------------------------------------------- SB3 VecEnv API
    def reset(self) -> VecEnvObs:
        """Reset every sub-env with the seeds of :meth:`seed` and the options of :meth:`set_options` (used once)."""
        seeds = list(self._seeds)
        options = self._options[0] if self._options else {}
        if any(not data_equivalence(o, options) for o in self._options):
            raise InputError("set_options: a gymnasium VectorEnv takes one options dict for all sub-envs")
        seed: Any = None  # gymnasium: an int s seeds sub-env i with s + i; SyncVectorEnv also takes a list
        if any(s is not None for s in seeds):
            first = seeds[0]
            seed = first if first is not None and seeds == [first + i for i in range(self.num_envs)] else seeds
        obs, info = self.venv.reset(seed=seed, options=dict(options) if options else None)
        self.reset_infos = unbatch_info(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return np.array(obs)

    def step_async(self, actions: np.ndarray) -> None:
        """Store the actions ``(num_envs, ...)`` for :meth:`step_wait`."""
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        """Step every sub-env; reset the finished ones in the same step (SB3's autoreset)."""
        if self._actions is None:
            raise RuntimeError("SB3VecEnv: step_async() must come before step_wait()")
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        self._actions = None
        obs = np.array(obs)
        terminated, truncated = np.asarray(terminated, dtype=bool), np.asarray(truncated, dtype=bool)
        dones = terminated | truncated
        infos = unbatch_info(info, self.num_envs)
        for i, item in enumerate(infos):
            item["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        if dones.any():
            reset_obs, reset_info = self.venv.reset(options={"reset_mask": dones})
            reset_infos = unbatch_info(reset_info, self.num_envs)
            for row in np.flatnonzero(dones):
                infos[row]["terminal_observation"] = obs[row].copy()
                self.reset_infos[row] = reset_infos[row]
            obs[dones] = np.asarray(reset_obs)[dones]
        return obs, np.asarray(reward, dtype=np.float32), dones, infos

    def close(self) -> None:
        """Close the vector env."""
        self.venv.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One RGB image per sub-env (``render_mode="rgb_array"``), else Nones."""
        frames = self.venv.render() if self.render_mode == "rgb_array" else None
        return [np.asarray(f) for f in frames] if frames is not None else [None] * self.num_envs

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The vector env's attribute ``attr_name``, once per index."""
        value = getattr(self.venv, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set the vector env's attribute (``indices`` must name every sub-env)."""
        self._all_indices(indices, "set_attr")
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call the vector env's method once (``indices`` must name every sub-env); its result once per sub-env."""
        self._all_indices(indices, "env_method")
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result] * self.num_envs

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper[Any, Any, Any, Any]], indices: VecEnvIndices = None
    ) -> list[bool]:
        """Whether the vector env's single envs (its ``envs`` list, if any) are wrapped in ``wrapper_class``."""
        envs = getattr(self.venv, "envs", None)
        if not isinstance(envs, (list, tuple)) or len(envs) != self.num_envs:
            return [False for _ in self._get_indices(indices)]
        return [is_wrapped(envs[i], wrapper_class) for i in self._get_indices(indices)]

    def _all_indices(self, indices: VecEnvIndices, what: str) -> None:
        """Raise unless ``indices`` names every sub-env (a vector env's attributes are shared)."""
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise InputError(f"{what}: a gymnasium VectorEnv shares its attributes; use indices=None")


def unbatch_info(info: dict[str, Any], num_envs: int) -> list[dict[str, Any]]:
    """Gymnasium's vector ``info`` (arrays with ``_key`` masks) as SB3's list of one dict per sub-env.

    Entries a sub-env does not report (mask False) are left out; 0-d numpy values become Python scalars,
    as the single envs report them; nested dicts are split the same way.
    """
    out: list[dict[str, Any]] = [{} for _ in range(num_envs)]
    for key, value in info.items():
        if key.startswith("_") and key[1:] in info:
            continue
        mask = info.get(f"_{key}", np.ones(num_envs, dtype=bool))
        rows = unbatch_info(value, num_envs) if isinstance(value, dict) else value
        for i in np.flatnonzero(mask):
            item = rows[i]
            out[i][key] = item.item() if isinstance(item, np.generic) else item
    return out


def make_sb3_vector_env(
    env_id: str, n_envs: int, seed: int | None = None, env_kwargs: dict[str, Any] | None = None
) -> VecEnv:
    """SB3 ``VecEnv`` of ``n_envs`` sub-envs stepped by ``env_id``'s vector entry point, with episode statistics.

    ``gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", **env_kwargs)`` wrapped
    in :class:`SB3VecEnv` and SB3's ``VecMonitor`` (``info["episode"]`` at episode ends, as ``make_vec_env``'s
    ``Monitor`` writes); seeded like ``make_vec_env`` (sub-env ``i`` gets ``seed + i`` at the first reset).
    Raises gymnasium's ``Error`` when ``env_id`` has no vector entry point.
    """
    venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", **(env_kwargs or {}))
    vec = VecMonitor(SB3VecEnv(venv))
    vec.seed(seed)
    return vec
