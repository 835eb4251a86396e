"""Planar lidar: sensors, the learned model, logs, rig, calibration, validation.

Modules: ``sensors`` (the :class:`~sensor_envs.lidar.sensors.LidarSensor` protocol, the ideal lidar,
``make_lidar``), ``gaussian`` (the Gaussian baseline lidar, :class:`~sensor_envs.lidar.gaussian.GaussianLidar`),
``lwlr`` (the learned per-bearing model, :class:`~sensor_envs.lidar.lwlr.LidarLWLR`), its pieces, one job each:
``fit_cells`` (its per-cell fit strategy, logs with repeats), ``fit_readings`` (its per-reading fit strategy, scan
logs; block folds), ``readings`` (the deprecated former name of ``fit_readings``), ``scan_sampler`` (its compiled scan
draw), ``reading_law`` (its per-reading mixture law, null counts), ``lwlr_io`` (its file format and upgrades),
``local_regression`` (its locally weighted linear regression (LWLR) kernel fits, table lookup and shrinkage choice;
``kernel`` is its deprecated former name), ``bias_transfer`` (its bias pooled over bearings plus a weighted
per-bearing part), ``extra_state`` (extra state terms: previous reading, time), ``model_call`` (the checked arguments
of its ``fit``, ``sample`` and ``log_prob``), ``log`` (lidar logs: npz, CARMEN, ROS bags), ``mapping`` (maps from
scans, occupancy grids), ``pose_correction`` (scan-to-map pose correction), ``rig`` (the reference rig that records
synthetic logs), ``calibrate`` (the rig fitted to a real log: the search), ``calibrate_stats`` (the statistics it
matches), ``calibrate_laws`` (the laws it fits in closed form), ``validate`` (per-bearing reports, the Gaussian
baseline), ``validate_readings`` (per-reading reports).

The public names below are importable from here (``from sensor_envs.lidar import LidarLWLR``), each
imported on first use.
"""

from sensor_envs.lazy import lazy_exports

_PUBLIC: dict[str, str] = {
    "LidarSensor": "sensor_envs.lidar.sensors",
    "IdealLidar": "sensor_envs.lidar.sensors",
    "GaussianLidar": "sensor_envs.lidar.gaussian",
    "make_lidar": "sensor_envs.lidar.sensors",
    "LIDAR_NAMES": "sensor_envs.lidar.sensors",
    "LidarLWLR": "sensor_envs.lidar.lwlr",
    "LearnedLidar": "sensor_envs.lidar.lwlr",
    "load_learned_lidar": "sensor_envs.lidar.lwlr",
    "choose_shrinkage": "sensor_envs.lidar.local_regression",
    "fit_per_reading": "sensor_envs.lidar.fit_readings",
    "check_extra_state": "sensor_envs.lidar.extra_state",
    "LidarLog": "sensor_envs.lidar.log",
    "LidarLogError": "sensor_envs.lidar.log",
    "load_log": "sensor_envs.lidar.log",
    "save_log": "sensor_envs.lidar.log",
    "read_carmen": "sensor_envs.lidar.log",
    "read_rosbag": "sensor_envs.lidar.log",
    "log_from_arrays": "sensor_envs.lidar.log",
    "map_from_scans": "sensor_envs.lidar.mapping",
    "read_occupancy": "sensor_envs.lidar.mapping",
    "correct_poses": "sensor_envs.lidar.pose_correction",
    "NeatoRig": "sensor_envs.lidar.rig",
    "sample_free_poses": "sensor_envs.lidar.rig",
    "calibrate_rig": "sensor_envs.lidar.calibrate",
    "load_real_log": "sensor_envs.lidar.calibrate",
    "fit_gaussian_lidar": "sensor_envs.lidar.validate",
    "cross_validate_log": "sensor_envs.lidar.validate",
    "fit_gaussian_readings": "sensor_envs.lidar.validate_readings",
}

__all__ = list(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
