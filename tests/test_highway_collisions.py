"""Collision anatomy of a highway matrix run (sensor_envs.training.collisions, collision_report)."""

import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from sensor_envs.training import collision_report, collisions, robustness

ROOT = Path(__file__).resolve().parents[1]


def _car(x, y, crashed=False):
    return SimpleNamespace(position=np.array([x, y], dtype=float), crashed=crashed, speed=25.0, heading=0.0)


def _scene(hit_at, rows, lane=("a", "b", 1), target=("a", "b", 1)):
    """An ego at the origin heading +x, a crashed car at ``hit_at`` and a far car; the last observation's snapshot."""
    ego, hit, far = _car(0.0, 0.0, True), _car(*hit_at, True), _car(60.0, 4.0)
    ego.speed = 20.0
    objects = [hit, far]
    centres = np.array([hit.position, far.position])
    sensor = np.array([2.5, 0.0])  # front bumper
    reference = centres - sensor - np.sign(centres - sensor) * np.array([2.5, 1.0])  # a near corner, sensor frame
    last = {
        "lane": lane,
        "target_lane": target,
        "speed": 25.0,
        "position": np.zeros(2),
        "heading": 0.0,
        "objects": objects,
        "centres": centres,
        "reference_s": reference,
        "visible": np.array([True, True]),
        "rows": [objects[i] if i is not None else None for i in rows],
    }
    base = SimpleNamespace(vehicle=ego, road=SimpleNamespace(vehicles=[ego, far, hit]))
    return base, last


WHERE = {"row": "ideal", "column": "ideal_surround", "seed": 0, "episode": 3}


def test_a_car_beside_after_a_lane_change_is_outside_the_front_view_and_not_shown():
    base, last = _scene((1.0, 4.0), rows=[1], target=("a", "b", 0))
    rec = collisions.crash_record(base, last, None, [3, 0], WHERE)
    assert rec.lane_change and rec.last_action == "LANE_LEFT" and rec.action_before == "FASTER"
    assert rec.zone == "beside" and rec.bearing_ego_deg == pytest.approx(math.degrees(math.atan2(4, 1)), abs=0.01)
    assert not rec.in_front_fov and rec.shown_row is None and not rec.shown_before
    assert rec.speed_change == pytest.approx(-5.0) and not rec.braking
    assert (rec.row, rec.column, rec.seed, rec.episode, rec.step) == ("ideal", "ideal_surround", 0, 3, 2)


def test_a_car_ahead_while_braking_is_in_view_and_its_row_is_named():
    base, last = _scene((12.0, 0.0), rows=[1, 0])
    rec = collisions.crash_record(base, last, last, [4], WHERE)
    assert rec.braking and not rec.lane_change and rec.action_before is None
    assert rec.zone == "ahead" and rec.in_front_fov and rec.shown_row == 2 and rec.shown_before
    assert rec.bearing_ego_deg == 0.0 and rec.dx_m == 12.0


def test_an_ordered_lane_change_still_under_way_counts_and_a_crash_without_a_car_is_unknown():
    base, last = _scene((-9.0, -4.0), rows=[], lane=("a", "b", 1), target=("a", "b", 2))
    rec = collisions.crash_record(base, last, None, [1], WHERE)
    assert rec.lane_change and rec.zone == "behind" and not rec.in_front_fov
    base.road.vehicles[2].crashed = False  # no crashed car: e.g. off the road
    rec = collisions.crash_record(base, last, None, [1], WHERE)
    assert not rec.hit_found and rec.zone == "unknown" and math.isnan(rec.bearing_ego_deg)


def test_summary_shares_count_the_cell_crashes_with_wilson_intervals():
    rec = {"row": "a", "column": "b", "hit_found": True, "braking": False, "shown_row": None}
    crashes = [
        {**rec, "lane_change": True, "in_front_fov": False, "visible": True, "zone": "beside"},
        {**rec, "lane_change": True, "in_front_fov": True, "visible": True, "zone": "ahead", "shown_row": 1},
        {**rec, "lane_change": False, "in_front_fov": True, "visible": False, "zone": "unknown", "braking": True},
    ]
    replay = {
        "rows": ["a"],
        "columns": ["b"],
        "episodes": 5,
        "crashes": crashes,
        "collision": {"a": {0: {"b": [1, 1, 1, 0, 0]}}},
        "matrix_collision": {"a": {0: {"b": [1, 1, 1, 0, 1]}}},
    }
    cell = collisions.summarise(replay)["cells"]["a->b"]
    assert cell["collision"]["k"] == 3 and cell["collision"]["n"] == 5 and cell["replay_matches_matrix"] == 4
    shares = cell["shares"]
    assert (shares["lane_change"]["k"], shares["lane_change"]["n"]) == (2, 3)
    assert (shares["outside_front_fov"]["k"], shares["outside_front_fov"]["n"]) == (1, 2)  # "unknown" left out
    assert (shares["shown"]["k"], shares["braking"]["k"]) == (1, 1)
    assert cell["zones"] == {"ahead": 1, "beside": 1, "behind": 0, "unknown": 1}
    lo, hi = shares["lane_change"]["ci95"]
    assert 0 < lo < 2 / 3 < hi < 1
    assert "2/3 = 0.67" in collision_report.markdown(collisions.summarise(replay), _meta())


def _meta():
    return {"date_utc": "d", "command": "c", "seconds": 1.0, "run": "r", "policy": "best", "seeds": [0], "plot": None}


def _fake_run(tmp_path, columns, episodes):
    """A run folder with one untrained DQN per row whose eval.json is robustness.evaluate's own output."""
    import gymnasium as gym
    import stable_baselines3 as sb3

    env_id = robustness.DOMAINS["highway"]["env_id"]
    settings = {"domain": "highway", "policy": "final", "seeds": [0], "rows": ["ideal"], "columns": columns}
    settings |= {"eval_episodes": episodes, "max_episode_steps": 8, "config": str(robustness.DEFAULT_CONFIG)}
    (tmp_path / "settings.json").write_text(json.dumps(settings))
    job = tmp_path / "runs" / "ideal" / "seed0"
    job.mkdir(parents=True)
    model = sb3.DQN("MlpPolicy", gym.make(env_id, radar="ideal"), seed=0, device="cpu", buffer_size=10)
    model.save(job / "final_model")
    cells = {
        c: robustness.evaluate(model, env_id, robustness.column_kwargs("highway", c, {}), episodes, 8) for c in columns
    }
    (job / "eval.json").write_text(json.dumps({"spec": {"algo": "dqn"}, "cells": cells}))
    (job / "config.json").write_text(json.dumps({"config": {"algo": "dqn"}}))
    return cells


def test_the_replay_reproduces_the_matrix_episodes_and_records_every_crash(tmp_path):
    columns = ["ideal", "ideal_surround"]
    cells = _fake_run(tmp_path, columns, episodes=2)
    replay = collisions.replay_run(tmp_path)
    for c in columns:
        assert replay["collision"]["ideal"][0][c] == cells[c]["collision"]
        crashes = [x for x in replay["crashes"] if x["column"] == c]
        assert len(crashes) == sum(cells[c]["collision"])
    summary = collisions.summarise(replay)
    assert all(v["replay_matches_matrix"] == 2 for v in summary["cells"].values())
    cache = tmp_path / "runs" / "ideal" / "seed0" / collisions.CACHE
    assert set(json.loads(cache.read_text())) == set(columns)
    stored = json.loads(cache.read_text())
    stored["ideal"]["collision"] = [0.5, 0.5]  # a marker: a rerun with the same policy and settings reads the cache
    cache.write_text(json.dumps(stored))
    assert collisions.replay_run(tmp_path, seeds=[0])["collision"]["ideal"][0]["ideal"] == [0.5, 0.5]
    again = collisions.replay_run(tmp_path, episodes=1, columns=["ideal"])  # other settings: replayed
    assert again["collision"]["ideal"][0]["ideal"] == cells["ideal"]["collision"][:1]


@pytest.mark.slow
def test_the_report_script_on_a_tiny_matrix_writes_page_json_and_plot(tmp_path):
    run = tmp_path / "run"
    robustness.main(
        ["--domain", "highway", "--preset", "short", "--seeds", "1", "--sensors", "ideal", "--columns", "ideal",
         "ideal_surround", "--eval-episodes", "3", "--workers", "1", "--device", "cpu", "--out", str(run)]
    )  # fmt: skip
    md, js, png = tmp_path / "c.md", tmp_path / "c.json", tmp_path / "c.png"
    md.write_text(f"# By hand\n\nkept\n\n{collision_report.MARKER}\nSTALE-LINE\n")
    script = ROOT / "benchmarks" / "highway_collision_report.py"
    argv = [sys.executable, str(script), "--run", str(run), "--md", str(md), "--json", str(js), "--png", str(png)]
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    assert subprocess.run(argv, capture_output=True, env=env, check=False).returncode == 2  # outputs exist
    done = subprocess.run([*argv, "--force"], capture_output=True, text=True, env=env, check=False)
    assert done.returncode == 0, done.stderr
    page = md.read_text()
    assert page.startswith("# By hand\n\nkept\n") and "STALE-LINE" not in page and "ideal -> ideal_surround" in page
    record = json.loads(js.read_text())
    assert set(record["cells"]) == {"ideal->ideal", "ideal->ideal_surround"} and png.stat().st_size > 10_000
    assert all(c["replay_matches_matrix"] == 3 for c in record["cells"].values())
