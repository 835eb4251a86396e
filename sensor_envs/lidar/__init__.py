"""Planar lidar: sensors, the learned model, logs, rig, validation.

Planar lidar: ``sensors`` (the :class:`~sensor_envs.lidar.sensors.LidarSensor` protocol, ideal and
Gaussian lidars, ``make_lidar``), ``lwlr`` (the learned per-bearing model), ``log`` (lidar logs: npz,
CARMEN, ROS bags), ``rig`` (the reference rig that records synthetic logs), ``validate`` (reports).
"""
