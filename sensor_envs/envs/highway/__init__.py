"""highway-env with a radar instead of ideal perception (see :mod:`sensor_envs.envs.highway.wrapper`).

Modules: ``wrapper`` (:class:`RadarObservation`, :func:`make_highway`), ``sensor`` (what the radar can see: model
loading, field of view, occlusion, reference points), ``step_record`` (one step's record: the truth it looked at, its
output and ``info["radar"]``), ``frame`` (the deprecated former name of ``step_record``), ``observation``
(highway-env's ``Kinematics`` layout), ``render`` (the overlay), ``hooks`` (the wrapper's hooks into highway-env's
road step and observation), ``stacking`` (frame stacking: ``StackedRows``), ``wrapper_schema`` (the declared arguments
of the wrapper and ``make_highway``, a reset's ``options["config"]``), ``clutter`` (object-level clutter and the
Doppler stationary filter), ``tracker`` (the multi-target tracker of ``tracks=True``).
"""

from sensor_envs.envs.highway.clutter import CLUTTER_LEVELS, STATIONARY_MODES
from sensor_envs.envs.highway.observation import SUPPORTED_FEATURES, KinematicsLayout
from sensor_envs.envs.highway.render import draw_radar
from sensor_envs.envs.highway.sensor import DEFAULT_FOV, DEFAULT_MAX_RANGE, SensorSpec, load_radar
from sensor_envs.envs.highway.step_record import RadarFrame, RadarInfo
from sensor_envs.envs.highway.tracker import MultiTargetTracker, TrackerConfig, TrackList
from sensor_envs.envs.highway.wrapper import (
    IDEAL_KINEMATICS,
    RNG_TAG,
    ObservedRows,
    RadarObservation,
    StackedRows,
    make_highway,
)
from sensor_envs.radar.sensors import RADAR_NAMES

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
    "ObservedRows",
    "StackedRows",
    "CLUTTER_LEVELS",
    "STATIONARY_MODES",
    "TrackerConfig",
    "TrackList",
    "MultiTargetTracker",
    "RadarFrame",
    "RadarInfo",
    "draw_radar",
    "load_radar",
    "make_highway",
]
