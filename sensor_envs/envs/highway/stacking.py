"""Frame stacking for the highway radar's observations: a ``(k, rows, features)`` stack as one table."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

__all__ = ["StackedRows"]


class StackedRows(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Turn a ``(k, rows, features)`` stack of observations into one ``(k * rows, features)`` table.

    The 2-D layout of ``Kinematics`` is kept (a 3-D float array would be taken for an image by SB3's
    checker); the oldest observation's rows come first. Picklable, unlike a lambda-based reshape.

    Raises:
        TypeError: when the observation space is not a 3-D ``Box``.
    """

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.ObservationWrapper.__init__(self, env)
        space = env.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 3:
            raise TypeError(f"env: expected a 3-D Box observation space, got {space}")
        k, rows, feats = space.shape
        self.observation_space = spaces.Box(
            space.low.reshape(k * rows, feats), space.high.reshape(k * rows, feats), dtype=space.dtype
        )

    def observation(self, observation: NDArray[np.float32]) -> NDArray[np.float32]:
        """The stack as one table (a view, rows of the oldest observation first)."""
        return np.asarray(observation).reshape(self.observation_space.shape)
