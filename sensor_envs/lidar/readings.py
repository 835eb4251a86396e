"""Former name of :mod:`sensor_envs.lidar.fit_readings` (the per-reading fit of ``LidarLWLR``); imports still work."""

from sensor_envs.lidar.fit_readings import *  # noqa: F403
from sensor_envs.lidar.fit_readings import __all__  # noqa: F401
