"""Checks shared by the environments: actions against the action space, highway-env configurations.

Both worlds treat an action outside the action space alike: an :class:`~sensor_envs.inputs.InputError`
naming ``action`` (never clipped or wrapped silently, never a ``KeyError`` deep inside highway-env).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sensor_envs.inputs import InputError, check_array
from sensor_envs.modelio import Constraint, InstanceOf, Interval, Numbers, Options, validate_params

__all__ = [
    "check_action",
    "check_highway_config",
    "check_seed",
    "check_options",
    "default_constraint",
    "HIGHWAY_CONFIG_CONSTRAINTS",
    "ACTION_CONSTRAINTS",
    "VEHICLE_TYPES",
]


def check_seed(seed: Any) -> int | None:
    """``seed`` as ``reset`` takes it: ``None`` or a non-negative integer below 2**64 (numpy integers become ``int``).

    Raises:
        InputError: ``"seed: ..."`` for a bool, a float, a string, a negative or a too large integer.
    """
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**64:
        raise InputError(f"seed: expected None or an integer in [0, 2**64), got {seed!r:.60}")
    return int(seed)


def check_options(options: Any, keys: tuple[str, ...]) -> dict[str, Any]:
    """``reset``'s ``options`` as a dict (``None``: empty) whose keys are among ``keys``.

    Raises:
        InputError: ``"options: ..."`` for anything but a dict or ``None``, or an unknown key.
    """
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise InputError(f"options: expected a dict or None, got {type(options).__name__}")
    unknown = sorted(str(k) for k in set(options) - set(keys))
    if unknown:
        raise InputError(f"options: unknown keys {unknown}; expected {' and/or '.join(map(repr, keys))}")
    return dict(options)


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


VEHICLE_TYPES = (
    "highway_env.vehicle.behavior.IDMVehicle",
    "highway_env.vehicle.behavior.LinearVehicle",
    "highway_env.vehicle.behavior.AggressiveVehicle",
    "highway_env.vehicle.behavior.DefensiveVehicle",
)
"""Accepted ``other_vehicles_type`` values (highway-env imports the named class: any other string fails deep inside)."""

_FREQUENCY = Interval(0.01, 1000)
HIGHWAY_CONFIG_CONSTRAINTS: dict[str, list[Constraint]] = {
    "policy_frequency": [_FREQUENCY],
    "simulation_frequency": [_FREQUENCY],
    "duration": [Interval(0.01, 1e5)],
    "vehicles_count": [Interval(0, 1000, integer=True)],
    "initial_vehicle_count": [Interval(0, 1000, integer=True)],
    "lanes_count": [Interval(1, 100, integer=True)],
    "controlled_vehicles": [Interval(1, 100, integer=True)],
    "vehicles_density": [Interval(0.01, 100)],
    "initial_spacing": [Interval(0.01, 1000)],
    "ego_spacing": [Interval(0.01, 1000)],
    "initial_lane_id": [None, Interval(0, 99, integer=True)],
    "spawn_probability": [Interval(0, 1)],
    "destination": [None, Options("o0", "o1", "o2", "o3")],
    "other_vehicles_type": [Options(*VEHICLE_TYPES)],
    "reward_speed_range": [Numbers(Interval(-1000, 1000), length=2, increasing=True)],
    "centering_position": [Numbers(Interval(0, 1), length=2)],
    "screen_width": [Interval(1, 10_000, integer=True)],
    "screen_height": [Interval(1, 10_000, integer=True)],
    "scaling": [Interval(0.01, 1000)],
    "offscreen_rendering": [None, InstanceOf(bool)],
}
"""Declared ranges of highway-env configuration keys (``policy_frequency: 0`` divides by zero). Keys not named
here are checked by the type of their default (:func:`default_constraint`); ``observation`` and ``action``
by their own schema."""

ACTION_CONSTRAINTS: dict[str, list[Constraint]] = {
    "type": [Options("DiscreteMetaAction")],
    "longitudinal": [InstanceOf(bool)],
    "lateral": [InstanceOf(bool)],
    "target_speeds": [Numbers(Interval(-100, 100), increasing=True)],
}
"""Declared ``config["action"]`` (the wrapper's agents take highway-env's meta-actions)."""

MAX_REWARD = 1e6
"""Largest ``|value|`` of an undeclared numeric configuration key (rewards, weights)."""


def default_constraint(default: Any) -> list[Constraint]:
    """The constraint of an undeclared configuration key, from the type of its default value.

    A flag takes a flag; a number a finite real number within ``+-MAX_REWARD``; a list of numbers as
    many finite numbers; anything else (a string, ``None``, a mapping) only its default.
    """
    if isinstance(default, bool):
        return [InstanceOf(bool)]
    if isinstance(default, (int, float)):
        return [Interval(-MAX_REWARD, MAX_REWARD)]
    if isinstance(default, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in default):
        return [Numbers(Interval(-MAX_REWARD, MAX_REWARD), length=len(default))]
    return [Options(default)] if default is not None else [None]


def check_highway_config(
    config: Any, defaults: dict[str, Any] | None = None, current: dict[str, Any] | None = None
) -> None:
    """Check a highway-env ``config`` override against the declared schema, before the env is built.

    Args:
        config: the override (``None`` = none).
        defaults: the env's ``default_config()``; given, every key must be one of its keys and is checked
            (declared range, or by the type of its default); ``None`` checks the declared keys only.
        current: the configuration the override lands on (a running env's, for ``reset``; default
            ``defaults``), for the relations between keys: ``simulation_frequency >= policy_frequency``
            (highway-env simulates ``simulation_frequency // policy_frequency`` frames per step: 0 divides
            by zero).

    Raises:
        InputError: ``"config.<key>: ..."`` naming the key (and ``config.action.<key>`` /
            ``config.observation.<key>`` inside those).
    """
    if config is None:
        return
    if not isinstance(config, dict):
        raise InputError(f"config: expected a dict of highway-env settings or None, got {type(config).__name__}")
    for key, value in config.items():
        if not isinstance(key, str):
            raise InputError(f"config: keys must be strings, got {key!r:.40}")
        if defaults is not None and key not in defaults:
            raise InputError(f"config.{key}: unknown highway-env key (known: {sorted(defaults)})")
        if key == "action":
            _check_mapping(value, ACTION_CONSTRAINTS, "config.action", required=("type",))
            continue
        if key == "observation":
            from sensor_envs.envs.highway.observation import KinematicsLayout

            if not isinstance(value, dict):
                raise InputError(f"config.observation: expected a dict, got {type(value).__name__}")
            KinematicsLayout.from_config(value)  # InputError naming observation.<key>
            continue
        if key in HIGHWAY_CONFIG_CONSTRAINTS:
            table = {key: HIGHWAY_CONFIG_CONSTRAINTS[key]}
        elif defaults is not None:
            table = {key: default_constraint(defaults[key])}
        else:
            continue
        try:
            validate_params({key: value}, table)
        except InputError as exc:
            raise InputError(f"config.{exc}") from None
    merged = {**(current if current is not None else defaults or {}), **config}
    sim: Any = merged.get("simulation_frequency")
    policy: Any = merged.get("policy_frequency")
    if _real(sim) and _real(policy) and float(sim) < float(policy):
        key = "simulation_frequency" if "simulation_frequency" in config else "policy_frequency"
        raise InputError(
            f"config.{key}: simulation_frequency ({sim:g}) must be >= policy_frequency ({policy:g}): "
            "highway-env simulates simulation_frequency // policy_frequency frames per step"
        )


def _real(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _check_mapping(value: Any, table: dict[str, list[Constraint]], name: str, required: tuple[str, ...] = ()) -> None:
    """``value`` a dict whose keys are in ``table`` (each checked) and which holds ``required``."""
    if not isinstance(value, dict):
        raise InputError(f"{name}: expected a dict, got {type(value).__name__}")
    missing = [k for k in required if k not in value]
    if missing:
        raise InputError(f"{name}.{missing[0]}: missing")
    try:
        validate_params(value, table, what="key")
    except InputError as exc:
        raise InputError(f"{name}.{exc}") from None
