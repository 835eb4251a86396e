"""sensor_envs: Gymnasium environments and wrappers whose perception is realistic instead of ideal.

Importing the package registers the environments with Gymnasium:

* ``sensor_envs/Neato-v0``: a differential-drive robot with a 360-bearing planar lidar in a 2D world
  (``lidar="ideal" | "gaussian" | "learned"``).
* ``sensor_envs/Highway-v0``, ``HighwayFast-v0``, ``Merge-v0``, ``Intersection-v0``: highway-env with
  its ideal perception replaced by a radar model (``radar="ideal" | "gaussian" | "kde"``).

The public API below is importable from here (``from sensor_envs import KDERadarModel``); each name is
imported lazily on first use (module-level ``__getattr__``, as ``gymnasium.wrappers`` does), so
``import sensor_envs`` stays cheap.

Packages: ``lidar`` and ``radar`` (the sensor models), ``envs`` (the worlds), ``diagnose``, ``evaluate`` and
``training`` (tools), ``cli`` (the ``sensor-envs`` command), ``testing`` (bad inputs shared by tests and
benchmarks). Shared modules: ``geometry`` (rays and segments), ``maps``
(2D segment maps), ``modelio`` (model files), ``constraints`` (the declared forms of hyperparameters and header
fields), ``sensor_model`` (the one contract of the fitted sensor models:
``SensorModel``), ``outputs`` (safe output files), ``rng`` (seeded generators),
``trig`` and ``jit`` (compiled kernels), ``heap`` (opt-in malloc tuning), ``lazy`` (lazy public names),
``cards`` (model cards from a file's header and measured metrics), ``inputs`` (the input layer: bounded reads,
declared ranges, ``InputError``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

import gymnasium as gym

__version__ = "0.1.0"

# public name -> module that defines it (one line per name: the front door's table of contents)
_PUBLIC: dict[str, str] = {
    # worlds and wrappers
    "NeatoEnv": "sensor_envs.envs.neato",
    "NeatoVectorEnv": "sensor_envs.envs.neato_vector",
    "RadarObservation": "sensor_envs.envs.highway.wrapper",
    "make_highway": "sensor_envs.envs.highway.wrapper",
    "IDEAL_KINEMATICS": "sensor_envs.envs.highway.wrapper",
    "SensorModel": "sensor_envs.sensor_model",
    # lidar
    "LidarSensor": "sensor_envs.lidar.sensors",
    "IdealLidar": "sensor_envs.lidar.sensors",
    "GaussianLidar": "sensor_envs.lidar.gaussian",
    "make_lidar": "sensor_envs.lidar.sensors",
    "LidarLWLR": "sensor_envs.lidar.lwlr",
    "LearnedLidar": "sensor_envs.lidar.lwlr",
    "LidarLog": "sensor_envs.lidar.log",
    "load_log": "sensor_envs.lidar.log",
    "read_carmen": "sensor_envs.lidar.log",
    "read_rosbag": "sensor_envs.lidar.log",
    "NeatoRig": "sensor_envs.lidar.rig",
    # radar
    "RadarSensor": "sensor_envs.radar.sensors",
    "IdealRadar": "sensor_envs.radar.sensors",
    "make_radar": "sensor_envs.radar.sensors",
    "KDERadarModel": "sensor_envs.radar.kde",
    "GaussianRadar": "sensor_envs.radar.gaussian",
    "RadarLog": "sensor_envs.radar.log",
    "read_log": "sensor_envs.radar.log",
    "load_astyx": "sensor_envs.radar.astyx",
    "RadarRig": "sensor_envs.radar.rig",
    # shared pieces
    "SegmentMap": "sensor_envs.maps",
    "load_map": "sensor_envs.maps",
    "ModelFileError": "sensor_envs.modelio",
}

__all__ = ["__version__", *_PUBLIC]

if TYPE_CHECKING:  # static type checkers see the real names
    from sensor_envs.envs.highway.wrapper import IDEAL_KINEMATICS, RadarObservation, make_highway
    from sensor_envs.envs.neato import NeatoEnv
    from sensor_envs.envs.neato_vector import NeatoVectorEnv
    from sensor_envs.lidar.log import LidarLog, load_log, read_carmen, read_rosbag
    from sensor_envs.lidar.lwlr import LearnedLidar, LidarLWLR
    from sensor_envs.lidar.rig import NeatoRig
    from sensor_envs.lidar.sensors import GaussianLidar, IdealLidar, LidarSensor, make_lidar
    from sensor_envs.maps import SegmentMap, load_map
    from sensor_envs.modelio import ModelFileError
    from sensor_envs.radar.astyx import load_astyx
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel
    from sensor_envs.radar.log import RadarLog, read_log
    from sensor_envs.radar.rig import RadarRig
    from sensor_envs.radar.sensors import IdealRadar, RadarSensor, make_radar


def __getattr__(name: str) -> Any:
    """Import a public name on first use."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'sensor_envs' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    """The public names (for tab completion)."""
    return sorted(__all__)


_HIGHWAY_IDS = {
    "sensor_envs/Highway-v0": "highway-v0",
    "sensor_envs/HighwayFast-v0": "highway-fast-v0",
    "sensor_envs/Merge-v0": "merge-v0",
    "sensor_envs/Intersection-v0": "intersection-v0",
}


def _register() -> None:
    """Register every env id (safe to call more than once)."""
    if "sensor_envs/Neato-v0" not in gym.registry:
        gym.register(
            id="sensor_envs/Neato-v0",
            entry_point="sensor_envs.envs.neato:NeatoEnv",
            vector_entry_point="sensor_envs.envs.neato_vector:NeatoVectorEnv",
            max_episode_steps=500,
        )
    for env_id, base_id in _HIGHWAY_IDS.items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id, entry_point="sensor_envs.envs.highway.wrapper:make_highway", kwargs={"base_id": base_id}
            )


_register()
