import json

import pytest

from sensor_envs.cli.main import main


@pytest.mark.slow  # end to end, several seconds: CI runs it with the slow tests
def test_demo_main_job_writes_pictures_and_report(tmp_path):
    assert main(["demo", "--out", str(tmp_path), "--episodes", "1"]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert set(report["neato"]) == {"ideal", "gaussian", "learned"}
    assert set(report["highway_fast"]) == {"ideal", "gaussian", "kde"}
    assert report["highway_fast"]["ideal"]["detection_rate"] == 1.0
    assert report["highway_fast"]["kde"]["detection_rate"] < 1.0  # a realistic radar misses targets
    assert report["neato"]["learned"]["null_share"] > report["neato"]["ideal"]["null_share"]
    ev = report["evaluation"]
    assert set(ev["board_detection_rig"]) >= {"rig", "learned", "gaussian", "ideal"}
    assert set(ev["forward_collision_warning"]) == {"ideal", "gaussian", "kde"}
    for name in ("neato_ideal.png", "neato_learned.png", "neato_scans.png", "highway_kde.png", "detection_pr.png"):
        assert (tmp_path / name).stat().st_size > 1000
    # report.md beside report.json: the same numbers, every reported field defined
    text = (tmp_path / "report.md").read_text()
    from sensor_envs.cli.demo import FIELDS

    for row in (*report["neato"]["ideal"], *report["highway_fast"]["kde"]):
        assert row in ("map", "episodes") or row in FIELDS, f"{row} is reported but not defined"
    assert all(f"`{k}`" in text for k in FIELDS)
    for lidar, r in report["neato"].items():  # why each episode ended: the three shares add up
        assert abs(r["success_rate"] + r["collision_rate"] + r["timeout_rate"] - 1.0) < 1e-9, lidar
        assert f"| {lidar} | seed_room |" in text
    assert all(r["ended_by"] in ("steps", "crash", "time") for r in report["highway_fast"].values())
    # the box-world sources are named as everywhere else: the rig is the reference, not "real"
    assert "real" not in ev["board_detection_rig"] and "model_world" not in ev["board_detection_rig"]


@pytest.mark.slow  # a whole demo in a subprocess (~20 s)
def test_demo_stderr_has_a_line_per_stage_and_no_sdl_noise(tmp_path):
    import subprocess
    import sys

    run = subprocess.run(
        [sys.executable, "-m", "sensor_envs.cli", "demo", "--out", str(tmp_path / "d"), "--episodes", "1"],
        capture_output=True,
        text=True,
        env={k: v for k, v in __import__("os").environ.items() if k not in ("SDL_VIDEODRIVER", "XDG_RUNTIME_DIR")},
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "XDG_RUNTIME_DIR" not in run.stderr
    stages = [line for line in run.stderr.replace("\r", "\n").splitlines() if "sensor-envs demo:" in line]
    assert len(stages) >= 8  # 3 lidars, the scan figure, 3 radars, the evaluation
    import numpy as np
    from matplotlib.image import imread

    assert np.asarray(imread(tmp_path / "d" / "highway_kde.png"))[..., :3].std() > 0.05  # not a black frame
