"""Former name of :mod:`sensor_envs.envs.highway.step_record` (one policy step's record); imports still work."""

from sensor_envs.envs.highway.step_record import RadarFrame, RadarInfo, Truth

__all__ = ["Truth", "RadarFrame", "RadarInfo"]
