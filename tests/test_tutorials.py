"""Every tutorial of the documentation (docs/tutorials/*.md) and the README's quick starts run end to end.

Each tutorial's fenced ``python`` and ``bash`` blocks are run in order, as one program, in a temporary folder:
python blocks share one namespace, each bash block runs in ``bash -euo pipefail`` with the test's Python
first on ``PATH`` (so ``sensor-envs`` and ``python`` are this environment's) and ``training/`` /
``benchmarks/`` pointing at the repository. Budgets are shrunk by the replacements of :data:`TUTORIALS`, each
of which must occur in its tutorial (a test checks it), so the text a reader runs is the text tested, but for
those numbers. Tutorials on real recordings skip cleanly when ``../shared/data/real`` is absent.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL_DIR = ROOT / "docs" / "tutorials"
FENCE = re.compile(r"^```(python|bash)[^\n]*\n(.*?)^```", re.S | re.M)


@dataclass(frozen=True)
class Tutorial:
    """How the suite runs one tutorial: real data or not, and the budget replacements."""

    real: bool = False
    shrink: dict[str, str] = field(default_factory=dict)
    needs: tuple[str, ...] = ()


TUTORIALS: dict[str, Tutorial] = {
    "highway-kde-radar.md": Tutorial(
        shrink={
            "TIMESTEPS = 20_000": "TIMESTEPS = 40",
            "EPISODES = 8": "EPISODES = 1",
            "n_timesteps=20000": "n_timesteps=40",
        },
        needs=("stable_baselines3",),
    ),
    "lidar-from-logs.md": Tutorial(
        real=True,
        shrink={"--max-readings 300": "--max-readings 24", "MAX_READINGS = 300": "MAX_READINGS = 24"},  # every use
        needs=("rosbags",),
    ),
    "radar-from-astyx.md": Tutorial(
        real=True, shrink={"--max-evals 1500": "--max-evals 4", "--sequences 50": "--sequences 2"}
    ),
    "diagnose.md": Tutorial(shrink={"SEQUENCES = 24": "SEQUENCES = 10", "--permutations 499": "--permutations 199"}),
    "detector-sim-vs-real.md": Tutorial(
        real=True,
        shrink={
            "--folds 3 --repeats 10": "--folds 2 --repeats 1",
            "--draws 20": "--draws 1",
            "--configs 50": "--configs 2",
        },
    ),
    "robustness-matrix.md": Tutorial(
        shrink={"--preset short --workers 2": "--preset short --sensors ideal gaussian --seeds 1 --workers 2"},
        needs=("stable_baselines3", "ray"),
    ),
}


# The README's two quick starts (its sections whose heading starts with the key), run the same way
README = ROOT / "README.md"
QUICK_STARTS: dict[str, Tutorial] = {
    "## Quick start: a highway agent": Tutorial(
        shrink={"--preset quick --out": "--preset quick --set n_timesteps=40 --eval-episodes 1 --out"},
        needs=("stable_baselines3",),
    ),
    "## Quick start: a lidar fitted": Tutorial(
        real=True, shrink={"--part train --out": "--part train --max-readings 24 --out"}, needs=("rosbags",)
    ),
}


def blocks(path: Path | str) -> list[tuple[str, str]]:
    """The ``(language, code)`` of each fenced python / bash block of a markdown file (or text), in order."""
    text = path.read_text(encoding="utf-8") if isinstance(path, Path) else path
    return [(m.group(1), m.group(2)) for m in FENCE.finditer(text)]


def readme_section(heading: str) -> str:
    """The README's section whose heading starts with ``heading``, up to the next ``## `` heading."""
    text = README.read_text(encoding="utf-8")
    start = text.index(heading)
    end = text.find("\n## ", start + len(heading))
    return text[start : end if end >= 0 else len(text)]


def program(path: Path | str, shrink: dict[str, str]) -> str:
    """One Python program running the tutorial's (or a text's) blocks in order, budgets shrunk."""
    parts = ["import subprocess as _subprocess\n"]
    for lang, code in blocks(path):
        for old, new in shrink.items():
            code = code.replace(old, new)
        if lang == "python":
            parts.append(code)
        else:
            code = re.sub(r"(^|\s)(training|benchmarks)/", rf"\1{ROOT}/\2/", code)
            parts.append(f"_subprocess.run(['bash', '-euo', 'pipefail', '-c', {code!r}], check=True)\n")
    return "\n".join(parts)


def test_every_tutorial_is_run_and_every_budget_replacement_applies():
    pages = {p.name for p in TUTORIAL_DIR.glob("*.md")} - {"index.md"}
    assert pages == set(TUTORIALS), "a tutorial page without an entry in TUTORIALS (or an entry without a page)"
    for name, tutorial in TUTORIALS.items():
        text = (TUTORIAL_DIR / name).read_text(encoding="utf-8")
        assert blocks(TUTORIAL_DIR / name), f"{name}: no python or bash block"
        for old in tutorial.shrink:
            assert old in text, f"{name}: the budget {old!r} is no longer in the text"
        index = (TUTORIAL_DIR / "index.md").read_text(encoding="utf-8")
        assert f"({name})" in index, f"{name} is not listed in tutorials/index.md"


def test_every_readme_quick_start_is_run_and_every_budget_replacement_applies():
    headings = [line for line in README.read_text(encoding="utf-8").splitlines() if line.startswith("## Quick start")]
    assert len(headings) == len(QUICK_STARTS)
    assert all(any(h.startswith(key) for h in headings) for key in QUICK_STARTS)
    for heading, quick in QUICK_STARTS.items():
        text = readme_section(heading)
        assert blocks(text), f"{heading}: no python or bash block"
        for old in quick.shrink:
            assert old in text, f"{heading}: the budget {old!r} is no longer in the README"


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(TUTORIALS) + sorted(QUICK_STARTS))
def test_tutorial_runs_end_to_end(name, tmp_path, request):
    tutorial = TUTORIALS.get(name) or QUICK_STARTS[name]
    source = TUTORIAL_DIR / name if name in TUTORIALS else readme_section(name)
    for module in tutorial.needs:
        pytest.importorskip(module, reason=f"{name} needs {module}")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env["MPLBACKEND"] = "Agg"
    if tutorial.real:
        env["SENSOR_ENVS_REAL_DATA"] = str(request.getfixturevalue("real_data"))
    script = tmp_path / "tutorial.py"
    script.write_text(program(source, tutorial.shrink), encoding="utf-8")
    run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert run.returncode == 0, f"{name} failed:\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
