"""Deprecated former name of :mod:`sensor_envs.lidar.fit_readings` (the per-reading fit of ``LidarLWLR``).

Re-exports it; importing it warns (``FutureWarning``); the name goes in the release after next.
"""

import warnings

from sensor_envs.lidar.fit_readings import *  # noqa: F403
from sensor_envs.lidar.fit_readings import __all__  # noqa: F401

warnings.warn("sensor_envs.lidar.readings is renamed sensor_envs.lidar.fit_readings", FutureWarning, stacklevel=2)
