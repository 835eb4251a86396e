"""Deprecated former name of :mod:`sensor_envs.lidar.local_regression` (the LWLR kernel regression); re-exports it.

Importing it warns (``FutureWarning``); the name goes in the release after next.
"""

import warnings

from sensor_envs.lidar.local_regression import *  # noqa: F403
from sensor_envs.lidar.local_regression import __all__  # noqa: F401

warnings.warn("sensor_envs.lidar.kernel is renamed sensor_envs.lidar.local_regression", FutureWarning, stacklevel=2)
