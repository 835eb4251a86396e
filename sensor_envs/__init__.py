"""sensor_envs: Gymnasium environments and wrappers whose perception is realistic instead of ideal.

Importing the package registers the environments with Gymnasium:

* ``sensor_envs/Neato-v0``: a differential-drive robot with a 360-bearing planar lidar in a 2D world
  (``lidar="ideal" | "gaussian" | "learned"``).
* ``sensor_envs/Highway-v0``, ``HighwayFast-v0``, ``Merge-v0``, ``Intersection-v0``: highway-env with
  its ideal perception replaced by a radar model (``radar="ideal" | "gaussian" | "kde"``).
"""

from __future__ import annotations

import gymnasium as gym

__version__ = "0.1.0"

_HIGHWAY_IDS = {
    "sensor_envs/Highway-v0": "highway-v0",
    "sensor_envs/HighwayFast-v0": "highway-fast-v0",
    "sensor_envs/Merge-v0": "merge-v0",
    "sensor_envs/Intersection-v0": "intersection-v0",
}


def _register() -> None:
    """Register every env id (safe to call more than once)."""
    if "sensor_envs/Neato-v0" not in gym.registry:
        gym.register(id="sensor_envs/Neato-v0", entry_point="sensor_envs.neato:NeatoEnv", max_episode_steps=500)
    for env_id, base_id in _HIGHWAY_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point="sensor_envs.highway:make_highway", kwargs={"base_id": base_id})


_register()
