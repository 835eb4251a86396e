"""The ``sensor-envs`` command line.

Modules: ``main`` (the entry point and its subcommands' table), ``__main__`` (``python -m sensor_envs.cli``),
``args`` (shared argument types and the one-line input-error exit), one module per sensor's verbs (``lidar``,
``radar``), ``tune`` (``tune radar``: post-fit factors chosen on real frames), ``diagnose``, ``evaluate``,
``rebuild`` (``rebuild-models``: the shipped models from their recipes), ``upgrade`` (``upgrade-model``: a model
file of an older format rewritten in the current one), ``training`` (``train`` and
``robustness``) and ``demo`` (the main job).
"""
