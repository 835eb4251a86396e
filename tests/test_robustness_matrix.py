"""The robustness matrix's cells and comparisons from seeded synthetic job outputs (no training), and its options."""

import argparse
import json

import numpy as np
import pytest

from sensor_envs.training import robustness


def _write_jobs(out, rows, seeds, columns, draw):
    """One ``eval.json`` per (row, seed): ``draw(row, seed, column)`` gives that cell's per-episode dict."""
    for r in rows:
        for s in seeds:
            job = out / "runs" / r / f"seed{s}"
            job.mkdir(parents=True)
            cells = {c: draw(r, s, c) for c in columns}
            (job / "eval.json").write_text(json.dumps({"cells": cells}))


def _episodes(rng, collision_p, speed, n=30):
    coll = (rng.random(n) < collision_p).astype(float)
    return {
        "return": list(20.0 * (1 - coll) + rng.normal(0, 1, n)),
        "collision": list(coll),
        "success": [0.0] * n,
        "speed": list(speed + rng.normal(0, 0.5, n)),
    }


def test_a_planted_safer_row_is_found_and_speed_is_described_not_compared(tmp_path):
    rng = np.random.default_rng(0)
    rows, seeds, cols = ["ideal", "kde_tracks"], [0, 1, 2, 3, 4], ["ideal", "kde_tracks"]
    p = {"ideal": 0.6, "kde_tracks": 0.1}  # planted: the second row collides far less on every column

    _write_jobs(tmp_path, rows, seeds, cols, lambda r, s, c: _episodes(rng, p[r], 24.0))
    m = robustness.build_matrix(tmp_path, "highway", rows, cols, seeds)
    assert m["metrics"] == ["return", "collision", "speed"]
    assert set(m["probability_of_improvement"]) == {"return", "collision"}  # speed has no "better"
    for c in cols:
        pi = m["probability_of_improvement"]["collision"][f"ideal vs kde_tracks @ {c}"]
        assert pi["ci95"][1] < 0.5  # P(ideal row safer): interval below one half
        for r in rows:
            cell = m["cells"][f"{r}->{c}"]
            lo, hi = cell["collision"]["mean_ci95"]
            assert 0.0 <= lo <= cell["collision"]["mean"] <= hi <= 1.0
            assert cell["speed"]["mean"] == pytest.approx(24.0, abs=0.5)


def test_jobs_without_a_metric_leave_it_out(tmp_path):
    rng = np.random.default_rng(1)

    def old_job(r, s, c):  # an eval.json written before speed was recorded
        cell = _episodes(rng, 0.3, 25.0, n=5)
        del cell["speed"]
        return cell

    _write_jobs(tmp_path, ["ideal"], [0, 1], ["ideal"], old_job)
    m = robustness.build_matrix(tmp_path, "highway", ["ideal"], ["ideal"], [0, 1])
    assert m["metrics"] == ["return", "collision"]


def _args(tmp_path, **kw):
    base = {
        "domain": "highway",
        "preset": "full",
        "out": tmp_path / "m",
        "config": robustness.DEFAULT_CONFIG,
        "sensors": ["ideal"],
        "columns": None,
        "seeds": 1,
        "seed0": 0,
        "set": [],
        "eval_episodes": None,
        "algo": None,
        "policy": None,
        "device": "cpu",
    }
    return argparse.Namespace(**{**base, **kw})


def test_full_highway_preset_evaluates_the_selected_checkpoint_with_enough_episodes(tmp_path):
    specs, settings = robustness.plan(_args(tmp_path), {})
    assert settings["policy"] == "selected" and all(s["policy"] == "selected" for s in specs)
    assert settings["select_episodes"] >= 50
    assert settings["eval_episodes"] >= 30
    assert robustness.PRESETS["full"]["highway"]["seeds"] >= 5
    _, final = robustness.plan(_args(tmp_path, policy="final"), {})
    assert final["policy"] == "final"


@pytest.mark.parametrize(
    ("domain", "rows", "algo"), [("highway", ["ideal", "kde_tracks"], "dqn"), ("neato", ["ideal", "learned"], None)]
)
def test_quick_preset_trains_ideal_and_realistic_rows_once_each(tmp_path, domain, rows, algo):
    specs, settings = robustness.plan(_args(tmp_path, domain=domain, preset="quick", sensors=None, seeds=None), {})
    assert settings["rows"] == rows and settings["columns"] == rows and settings["seeds"] == [0]
    assert [s["sensor"] for s in specs] == rows and settings["algo"] == algo and settings["policy"] == "final"
    # --sensors / --columns still choose
    _, narrowed = robustness.plan(
        _args(tmp_path, domain=domain, preset="quick", sensors=["ideal"], columns=["ideal"], seeds=None), {}
    )
    assert narrowed["rows"] == ["ideal"] and narrowed["columns"] == ["ideal"]


@pytest.mark.parametrize("policy", ["best", "selected"])
def test_a_checkpoint_policy_without_checkpoints_is_a_usage_error(tmp_path, policy):
    with pytest.raises(robustness.UsageError, match=f"--policy {policy}"):
        robustness.plan(_args(tmp_path, policy=policy, set=["eval_freq=1000000000"]), {})


def test_jobs_print_a_line_each_when_stderr_is_not_a_terminal(monkeypatch, capsys):
    import sys

    monkeypatch.setattr(robustness, "_job_command", lambda spec: [sys.executable, "-c", "pass", json.dumps(spec)])
    specs = [{"sensor": "ideal", "seed": s, "run_dir": f"/nowhere/{s}"} for s in (0, 1)]
    robustness.run_jobs(specs, "process", 1, None)
    err = capsys.readouterr().err
    assert "job ideal seed 0 done (" in err and "job ideal seed 1 done (2 of 2;" in err
