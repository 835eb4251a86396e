"""Every public class and function of the front door has an Examples section, and it runs (doctest)."""

from __future__ import annotations

import doctest
import importlib
import io

import pytest

import sensor_envs
from sensor_envs import _PUBLIC

CONSTANTS = {"IDEAL_KINEMATICS"}  # a dict, documented where it is defined; no example to run
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _examples(obj: object, name: str) -> list[doctest.DocTest]:
    """The doctests of ``obj``'s own docstring (not its members')."""
    return [t for t in doctest.DocTestFinder(recurse=False).find(obj, name) if t.examples]


@pytest.mark.parametrize("name", sorted(set(_PUBLIC) - CONSTANTS))
def test_front_door_name_has_examples_that_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write a file write it here
    obj = getattr(importlib.import_module(_PUBLIC[name]), name)
    assert getattr(sensor_envs, name) is obj
    tests = _examples(obj, name)
    assert tests, f"{name}'s docstring has no Examples section"
    out = io.StringIO()
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in tests:
        runner.run(test, out=out.write)
    assert runner.failures == 0, out.getvalue()[-4000:]


def test_card_generator_examples_run(tmp_path, monkeypatch):
    from sensor_envs import cards

    monkeypatch.chdir(tmp_path)
    result = doctest.testmod(cards, optionflags=FLAGS)
    assert result.attempted > 0 and result.failed == 0


def test_api_reference_page_documents_every_front_door_name():
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "reference" / "api.md").read_text(encoding="utf-8")
    missing = [name for name, module in _PUBLIC.items() if f"::: {module}.{name}" not in page]
    assert missing == [], f"add these to docs/reference/api.md: {missing}"
