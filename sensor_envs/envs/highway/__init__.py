"""highway-env with a radar instead of ideal perception (see :mod:`sensor_envs.envs.highway.wrapper`).

Modules: ``wrapper`` (:class:`RadarObservation`, :func:`make_highway`), ``sensor`` (what the radar can
see: model loading, field of view, occlusion, reference points), ``frame`` (one step's output and
``info["radar"]``), ``observation`` (highway-env's ``Kinematics`` layout), ``render`` (the overlay).
"""

from sensor_envs.envs.highway.wrapper import (
    DEFAULT_FOV,
    DEFAULT_MAX_RANGE,
    IDEAL_KINEMATICS,
    RADAR_NAMES,
    RNG_TAG,
    SUPPORTED_FEATURES,
    KinematicsLayout,
    RadarFrame,
    RadarInfo,
    RadarObservation,
    SensorSpec,
    draw_radar,
    load_radar,
    make_highway,
)

__all__ = [
    "RADAR_NAMES",
    "RNG_TAG",
    "IDEAL_KINEMATICS",
    "DEFAULT_FOV",
    "DEFAULT_MAX_RANGE",
    "SUPPORTED_FEATURES",
    "SensorSpec",
    "KinematicsLayout",
    "RadarObservation",
    "RadarFrame",
    "RadarInfo",
    "draw_radar",
    "load_radar",
    "make_highway",
]
