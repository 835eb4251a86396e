"""``python -m sensor_envs.cli ...`` runs the ``sensor-envs`` command line."""

from sensor_envs.cli.main import main

raise SystemExit(main())
