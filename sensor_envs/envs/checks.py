"""Checks shared by the environments: actions against the action space, highway-env configurations.

Both worlds treat an action outside the action space alike: an :class:`~sensor_envs.inputs.InputError`
naming ``action`` (never clipped or wrapped silently, never a ``KeyError`` deep inside highway-env).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sensor_envs.inputs import InputError, check_array
from sensor_envs.modelio import Constraint, Interval, validate_params

__all__ = ["check_action", "check_highway_config", "HIGHWAY_CONFIG_CONSTRAINTS"]


def check_action(space: spaces.Space[Any], action: Any, name: str = "action") -> Any:
    """``action`` if it lies in ``space`` (a ``Discrete`` action as a Python ``int``).

    ``Discrete``: an integer (Python or numpy, or a 0-d/1-element integer array) in ``[start, start + n)``;
    ``1.5``, ``NaN``, ``True`` and ``99`` are refused. ``Box``: finite numbers of the space's shape within
    its bounds. Other spaces: ``space.contains``.

    Raises:
        InputError: ``"action: ..."`` stating the space.
    """
    if isinstance(space, spaces.Discrete):
        a = np.asarray(action) if not isinstance(action, (int, np.integer)) else action
        if isinstance(a, np.ndarray):
            if a.size != 1 or a.dtype.kind not in "iu":
                raise InputError(
                    f"{name}: expected an integer in [{space.start}, {space.start + space.n - 1}], got {action!r:.60}"
                )
            a = a.reshape(()).item()
        if isinstance(a, (bool, np.bool_)) or not space.start <= int(a) < space.start + space.n:
            raise InputError(
                f"{name}: expected an integer in [{space.start}, {space.start + space.n - 1}], got {action!r:.60}"
            )
        return int(a)
    if isinstance(space, spaces.Box):
        low, high = float(np.min(space.low)), float(np.max(space.high))
        arr = check_array(action, name, tuple(space.shape), low=low, high=high)
        if not (np.all(arr >= space.low) and np.all(arr <= space.high)):
            raise InputError(f"{name}: {action!r:.60} lies outside the action space {space}")
        return arr.astype(space.dtype)
    if not space.contains(action):
        raise InputError(f"{name}: {action!r:.60} is not in the action space {space}")
    return action


HIGHWAY_CONFIG_CONSTRAINTS: dict[str, list[Constraint]] = {
    "policy_frequency": [Interval(0.01, 1000)],
    "simulation_frequency": [Interval(0.01, 1000)],
    "duration": [Interval(0.01, 1e5)],
    "vehicles_count": [Interval(0, 1000, integer=True)],
    "lanes_count": [Interval(1, 100, integer=True)],
    "controlled_vehicles": [Interval(1, 100, integer=True)],
    "vehicles_density": [Interval(0.01, 100)],
    "initial_spacing": [Interval(0.01, 1000)],
    "ego_spacing": [Interval(0.01, 1000)],
}
"""Declared ranges of the numeric highway-env configuration keys (``policy_frequency: 0`` divides by zero)."""


def check_highway_config(config: Any) -> None:
    """Check a highway-env ``config`` override: a mapping whose declared numeric keys are in range.

    Raises:
        InputError: ``"config.<key>: expected ..., got ..."``.
    """
    if config is None:
        return
    if not isinstance(config, dict):
        raise InputError(f"config: expected a dict of highway-env settings or None, got {type(config).__name__}")
    known = {k: v for k, v in config.items() if k in HIGHWAY_CONFIG_CONSTRAINTS}
    try:
        validate_params(known, HIGHWAY_CONFIG_CONSTRAINTS)
    except InputError as exc:
        raise InputError(f"config.{exc}") from None
