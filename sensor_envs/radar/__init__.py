"""Automotive radar (object level): sensors, the KDE model, logs, rig, validation.

Automotive radar (object level): ``sensors`` (the :class:`~sensor_envs.radar.sensors.RadarSensor`
protocol, the ideal radar, ``make_radar``), ``kde`` (the KDE model), ``buckets`` (its exact sampler),
``relevance`` (CV of its relevance kernel), ``gaussian`` (the baseline), ``log`` (the CSV object log),
``astyx`` (the Astyx reader), ``rig`` (the reference rig), ``calibrate`` (the rig fitted to real frames),
``scene_law`` (the scene the rig records, fitted to real reference boxes), ``validate`` (reports).
"""
