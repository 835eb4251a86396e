"""Automotive radar (object level): sensors, the KDE model, logs, rig, calibration, validation.

Modules: ``sensors`` (the :class:`~sensor_envs.radar.sensors.RadarSensor` protocol, the ideal radar,
``make_radar``), ``kde`` (the KDE model, :class:`~sensor_envs.radar.kde.KDERadarModel`) and its pieces, one job
each: ``kde_params`` (its hyperparameter table and limits), ``kde_fit`` (the fit), ``kde_bandwidth`` (the bandwidth
CV table), ``kde_frames`` (yaw error and output frames), ``kde_trees`` (search trees, neighbours, miss odds),
``kde_samplers`` (the ball and bucket samplers), ``kde_density`` (``log_prob``, bin probabilities), ``kde_io`` (its
file format and upgrades); ``buckets`` (the bucket sampler's grid), ``relevance`` (CV of its relevance kernel),
``features`` (derived state columns: aspect angle, occlusion), ``alignment`` (the azimuth bias and the frame
rotation of offsets), ``gaussian`` (the baseline), ``log`` (the CSV object log), ``astyx`` (the Astyx reader),
``rig`` (the reference rig), ``rig_config`` (its parameters and rig files), ``calibrate`` (the rig fitted to real
frames: the fits and the search), ``calibrate_stats`` (the statistics it matches),
``calibrate_clutter`` (its clutter stage: count law, joint range x azimuth cell shares), ``scene_law`` (the scene
the rig records, fitted to real reference boxes), ``object_clutter`` (object-level clutter per cycle measured on
Astyx, the law the highway wrapper thins to), ``validate`` (reports), ``fidelity`` (real single frames: start tuple and
stationary law, block-bootstrap intervals and verdicts against the Gaussian), ``tune`` (post-fit factors chosen on
real held-out frames: bandwidth factor, tail mixture), ``correction`` (fitted conditional corrections on top of a
radar model: what ``diagnose radar`` adds for a found cause, :class:`~sensor_envs.radar.correction.CorrectedRadar`).

The public names below are importable from here (``from sensor_envs.radar import KDERadarModel``), each
imported on first use.
"""

from sensor_envs.lazy import lazy_exports

_PUBLIC: dict[str, str] = {
    "RadarSensor": "sensor_envs.radar.sensors",
    "IdealRadar": "sensor_envs.radar.sensors",
    "make_radar": "sensor_envs.radar.sensors",
    "RADAR_NAMES": "sensor_envs.radar.sensors",
    "KDERadarModel": "sensor_envs.radar.kde",
    "BucketIndex": "sensor_envs.radar.buckets",
    "build_buckets": "sensor_envs.radar.buckets",
    "with_derived_columns": "sensor_envs.radar.features",
    "estimate_azimuth_bias": "sensor_envs.radar.alignment",
    "GaussianRadar": "sensor_envs.radar.gaussian",
    "RadarLog": "sensor_envs.radar.log",
    "RadarLogError": "sensor_envs.radar.log",
    "read_log": "sensor_envs.radar.log",
    "write_log": "sensor_envs.radar.log",
    "load_astyx": "sensor_envs.radar.astyx",
    "RadarRig": "sensor_envs.radar.rig",
    "RigConfig": "sensor_envs.radar.rig",
    "load_rig": "sensor_envs.radar.rig",
    "save_rig": "sensor_envs.radar.rig",
    "record_rig_log": "sensor_envs.radar.rig",
    "calibrate_rig": "sensor_envs.radar.calibrate",
    "load_real": "sensor_envs.radar.calibrate",
    "fit_scene_law": "sensor_envs.radar.scene_law",
    "ObjectClutterLaw": "sensor_envs.radar.object_clutter",
    "load_object_clutter": "sensor_envs.radar.object_clutter",
    "measure_object_clutter": "sensor_envs.radar.object_clutter",
    "select_corner_variances": "sensor_envs.radar.relevance",
    "energy_distance_2d": "sensor_envs.radar.validate",
    "write_report": "sensor_envs.radar.validate",
    "frames_report": "sensor_envs.radar.fidelity",
    "choose_tail": "sensor_envs.radar.tune",
}

__all__ = list(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
