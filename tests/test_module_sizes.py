"""The package's pieces stay small (issue 40): modules of at most ~700 lines, classes of at most 400.

Counted as physical lines, docstrings included. A piece that grows past a limit is split by job, as
``radar/kde_*.py`` and ``lidar/fit_*.py``: the model estimators keep their numpydoc and delegate the work (e.g.
``KDERadarModel.with_*`` to ``kde_params``, ``LidarLWLR.params_from_features`` to ``reading_law``).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "sensor_envs"
MAX_MODULE_LINES = 700
MAX_CLASS_LINES = 400


def _sizes() -> tuple[dict[str, int], dict[str, int]]:
    modules, classes = {}, {}
    for path in sorted(PACKAGE.rglob("*.py")):
        src = path.read_text(encoding="utf-8")
        name = str(path.relative_to(PACKAGE.parent))
        modules[name] = src.count("\n")
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, ast.ClassDef):
                classes[f"{name}:{node.name}"] = node.end_lineno - node.lineno + 1
    return modules, classes


def test_no_module_over_700_lines():
    modules, _ = _sizes()
    over = {k: v for k, v in modules.items() if v > MAX_MODULE_LINES}
    assert not over, over


def test_no_class_over_about_400_lines():
    _, classes = _sizes()
    over = {k: v for k, v in classes.items() if v > MAX_CLASS_LINES}
    assert not over, over
    assert len(classes) > 50  # the walk saw the package
