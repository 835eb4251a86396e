"""Generated and hand-written bad inputs, shared by the test suite and the benchmarks (issues 40 and 42).

Installed with the package so that ``benchmarks/`` never reaches into ``tests/``. Nothing here is imported
by the library itself; the modules import the command line and the models (the top layer).

* ``fuzz_pieces``: valid pieces of every input format (radar CSV, lidar npz, CARMEN, ROS bag, maps,
  Astyx) and the generated mutations applied to them.
* ``fuzz_cases``: the generated file and option cases per reader family, and ``classify`` (how a case ends).
* ``fuzz_api``: generated bad calls of the Python API (every env id and model class).
* second round (issue 42), the structure rather than one token: ``fuzz_structure`` (CSV columns and
  number spellings, ``.npz`` containers, CARMEN lines, ROS bag records, map images, YAML/JSON constructs),
  ``fuzz_folders`` (Astyx layouts, model-file containers), ``fuzz_options`` (every option of every
  sub-command, unsafe ``--out`` targets) and ``fuzz_api_types`` (odd types of plausible API values).
* ``bad_pieces``, ``bad_files``, ``bad_options``: the hand-written table of bad inputs of every command
  (``bad_options.CASES`` holds all of them).
* ``synthetic_lidar``: a synthetic scan log with one planted effect (diagnose tests and benchmark).
"""
