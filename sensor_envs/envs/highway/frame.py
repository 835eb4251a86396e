"""Deprecated former name of :mod:`sensor_envs.envs.highway.step_record` (one policy step's record).

Re-exports it; importing it warns (``FutureWarning``); the name goes in the release after next.
"""

import warnings

from sensor_envs.envs.highway.step_record import RadarFrame, RadarInfo, Truth

__all__ = ["Truth", "RadarFrame", "RadarInfo"]

warnings.warn(
    "sensor_envs.envs.highway.frame is renamed sensor_envs.envs.highway.step_record", FutureWarning, stacklevel=2
)
