"""Algorithm-level evaluation of the sensor models (tools level: imports lidar/, radar/, envs/; nothing imports it).

Does a simulator predict how an algorithm performs on the real sensor? Modules, the sensor first in each
sensor's own: ``lidar_detection`` (the lidar seed's line detector and its precision/recall trajectories),
``lidar_experiments`` (those trajectories on a real log and in a box world), ``lidar_registration`` (a
Kalman filter with a scan matcher along a corridor), ``radar_detection`` (an ADAS trigger on object-level
radar output), ``radar_aeb`` (a forward-collision warning and a tracker in highway-env); shared:
``metrics`` (precision/recall, Wilson intervals, trajectory distance) and ``report`` (figures and markdown).

The public names below are importable from here, each imported on first use.
"""

from sensor_envs.lazy import lazy_exports

_PUBLIC: dict[str, str] = {
    "DetectorParams": "sensor_envs.evaluate.lidar_detection",
    "detect_lines": "sensor_envs.evaluate.lidar_detection",
    "run_trajectory": "sensor_envs.evaluate.lidar_detection",
    "log_experiment": "sensor_envs.evaluate.lidar_experiments",
    "boxworld_experiment": "sensor_envs.evaluate.lidar_experiments",
    "match_scan": "sensor_envs.evaluate.lidar_registration",
    "registration_experiment": "sensor_envs.evaluate.lidar_registration",
    "radar_detection_experiment": "sensor_envs.evaluate.radar_detection",
    "NNTracker": "sensor_envs.evaluate.radar_aeb",
    "gospa": "sensor_envs.evaluate.radar_aeb",
    "aeb_experiment": "sensor_envs.evaluate.radar_aeb",
    "write_aeb_report": "sensor_envs.evaluate.radar_aeb",
    "precision_recall": "sensor_envs.evaluate.metrics",
    "wilson_interval": "sensor_envs.evaluate.metrics",
    "trajectory_distance": "sensor_envs.evaluate.metrics",
    "write_report": "sensor_envs.evaluate.report",
}

__all__ = list(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
