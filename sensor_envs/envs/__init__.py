"""The worlds.

Modules: ``neato`` (the 2D Neato robot, :class:`~sensor_envs.envs.neato.NeatoEnv`, drawn by
``neato_render``), ``neato_vector`` (N Neato robots stepped together, the vector entry point), ``sb3_vec``
(that vector env as a stable-baselines3 ``VecEnv``), ``checks`` (declared ranges of env arguments and actions)
and ``highway`` (highway-env with a radar, a package).

The public names below are importable from here, each imported on first use.
"""

from sensor_envs.lazy import lazy_exports

_PUBLIC: dict[str, str] = {
    "NeatoEnv": "sensor_envs.envs.neato",
    "render_world": "sensor_envs.envs.neato_render",
    "NeatoVectorEnv": "sensor_envs.envs.neato_vector",
    "SB3VecEnv": "sensor_envs.envs.sb3_vec",
    "make_sb3_vector_env": "sensor_envs.envs.sb3_vec",
    "RadarObservation": "sensor_envs.envs.highway",
    "make_highway": "sensor_envs.envs.highway",
}

__all__ = list(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
