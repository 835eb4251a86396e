"""The worlds.

The worlds: ``neato`` (the 2D Neato robot, :class:`~sensor_envs.envs.neato.NeatoEnv`, drawn by
``neato_render``) and ``highway`` (highway-env with a radar, a package).
"""
