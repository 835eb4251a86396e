"""Training agents on the sensor_envs worlds (tools level: imports envs/, lidar/, radar/; the CLI imports it).

Modules: ``train`` (``sensor-envs train``: a stable-baselines3 agent from a YAML config keyed by env id, the
shipped one in ``configs/default.yaml``), ``robustness`` (``sensor-envs robustness``: train on one sensor,
evaluate on every sensor, on a process pool or a Ray cluster), ``robustness_inputs`` (its options, checked
before ``--out`` is made), ``selection`` (its ``--policy selected``: each job's checkpoint with the fewest
collisions on validation episodes; ``--reevaluate``), ``matrix_report`` (its reports: ``matrix.json``,
``matrix.md``, ``matrix.png``), ``stats`` (rliable-style statistics: IQM,
bootstrap intervals, probability of improvement), ``collisions`` (a highway run's collision anatomy: what the
observation showed in the last second before each crash) and ``collision_report`` (its page, JSON and plot).
Training needs the ``train`` extra (``pip install 'sensor_envs[train]'``).
"""

from sensor_envs.lazy import lazy_exports

_PUBLIC: dict[str, str] = {
    "load_config": "sensor_envs.training.train",
    "make_env": "sensor_envs.training.train",
    "DEFAULT_CONFIG": "sensor_envs.training.train",
    "ConfigError": "sensor_envs.training.train",
    "build_matrix": "sensor_envs.training.robustness",
    "iqm": "sensor_envs.training.stats",
    "bootstrap_ci": "sensor_envs.training.stats",
    "probability_of_improvement": "sensor_envs.training.stats",
}

__all__ = list(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
