"""The ``sensor-envs`` command line.

The ``sensor-envs`` command line: ``main`` (the entry point), one module per sensor's verbs
(``lidar``, ``radar``) and ``demo`` (the main job).
"""
