"""The declared arguments of the radar wrapper and :func:`~sensor_envs.envs.highway.wrapper.make_highway`.

Their types and ranges (:data:`WRAPPER_CONSTRAINTS`, :data:`MAKE_HIGHWAY_CONSTRAINTS`, checked with
:func:`~sensor_envs.modelio.validate_params`), highway-env's configuration keys of an environment id before it is
built (:func:`default_config`) and a ``reset``'s ``options["config"]`` (:func:`check_reset_config`). Every bad
value is an :class:`~sensor_envs.inputs.InputError` naming the argument.
"""

from __future__ import annotations

from os import PathLike
from typing import Any

import gymnasium as gym

from sensor_envs.envs.checks import check_highway_config
from sensor_envs.envs.highway.clutter import CLUTTER_LEVELS, STATIONARY_MODES
from sensor_envs.envs.highway.observation import KinematicsLayout
from sensor_envs.inputs import InputError
from sensor_envs.modelio import Constraint, InstanceOf, Interval, Options, validate_params
from sensor_envs.radar.sensors import RADAR_NAMES

__all__ = [
    "RADAR_RATES",
    "WRAPPER_CONSTRAINTS",
    "MAKE_HIGHWAY_CONSTRAINTS",
    "default_config",
    "check_reset_config",
    "check_wrapper_args",
]

RADAR_RATES = ("policy", "simulation")
"""Values of ``radar_rate``: one radar cycle per policy step, or one per simulation sub-step."""
WRAPPER_CONSTRAINTS: dict[str, list[Constraint]] = {
    "radar": [Options(*RADAR_NAMES)],  # or a RadarSensor instance
    "radar_model": [None, InstanceOf(str, PathLike)],
    "radar_rate": [Options(*RADAR_RATES)],
    "clutter_fraction": [Interval(0.0, 1.0)],
    "clutter": [Options(*CLUTTER_LEVELS)],
    "stationary": [Options(*STATIONARY_MODES)],
    "tracks": [InstanceOf(bool)],
}
"""Declared types and ranges of ``RadarObservation``'s arguments (the mount: ``SENSOR_CONSTRAINTS``;
``tracker``: :func:`~sensor_envs.envs.highway.tracker.tracker_config` and ``TrackerConfig``'s own checks)."""
MAKE_HIGHWAY_CONSTRAINTS: dict[str, list[Constraint]] = {
    "base_id": [InstanceOf(str)],
    "history": [Interval(1, 64, integer=True)],
    "render_mode": [None, Options("rgb_array", "human")],
}
"""Declared ``make_highway`` arguments besides the wrapper's (``config``: :func:`check_highway_config`)."""


def check_wrapper_args(
    radar: Any, radar_model: Any, radar_rate: Any, clutter_fraction: Any, clutter: Any, stationary: Any, tracks: Any
) -> None:
    """``RadarObservation``'s arguments against :data:`WRAPPER_CONSTRAINTS` (a ``radar`` instance: checked there).

    Raises:
        InputError: naming the argument.
    """
    validate_params(
        {
            "radar": radar if isinstance(radar, str) else "ideal",  # an instance: checked by the wrapper
            "radar_model": radar_model,
            "radar_rate": radar_rate,
            "clutter_fraction": clutter_fraction,
            "clutter": clutter,
            "stationary": stationary,
            "tracks": tracks,
        },
        WRAPPER_CONSTRAINTS,
    )


def default_config(base_id: str) -> dict[str, Any]:
    """highway-env's ``default_config()`` of ``base_id``, read from its class without building the env.

    Raises:
        InputError: naming ``base_id`` when gymnasium knows no such id.
    """
    try:
        entry = gym.spec(base_id).entry_point
    except gym.error.Error as exc:
        raise InputError(f"base_id: {' '.join(str(exc).split())[:200]}") from None
    creator: Any = gym.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
    if not callable(getattr(creator, "default_config", None)):
        raise InputError(f"base_id: {base_id!r} is not a highway-env environment")
    return dict(creator.default_config())


def check_reset_config(options: dict[str, Any] | None, base: Any, layout: KinematicsLayout) -> None:
    """A ``reset``'s ``options["config"]``, checked before highway-env applies it.

    Every key declared for the environment ``base`` (:func:`check_highway_config`), and an observation layout
    equal to the wrapper's ``layout`` (it is fixed when the wrapper is built).

    Raises:
        InputError: naming ``options.config.<key>``.
    """
    if not options or "config" not in options:
        return
    if not isinstance(options["config"], dict):
        raise InputError(f"options.config: expected a dict, got {type(options['config']).__name__}")
    try:
        check_highway_config(options["config"], dict(base.default_config()), dict(getattr(base, "config", {})))
    except InputError as exc:
        raise InputError(f"options.{exc}") from None
    new = options["config"].get("observation")
    if new is not None and KinematicsLayout.from_config(new) != layout:
        raise InputError("options.config.observation: the observation layout is fixed when the wrapper is built")
