"""Algorithm-level evaluation of the sensor models (tools level: imports lidar/, radar/, envs/; nothing imports it).

Does a simulator predict how an algorithm performs on the real sensor? Detection precision/recall
trajectories of the lidar seed's line detector (:mod:`~sensor_envs.evaluate.detection`,
:mod:`~sensor_envs.evaluate.lidar_experiments`), an ADAS trigger on object-level radar output
(:mod:`~sensor_envs.evaluate.radar_detection`), and a forward-collision warning and a tracker in
highway-env (:mod:`~sensor_envs.evaluate.aeb`).
"""
