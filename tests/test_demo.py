import json

from sensor_envs.cli.main import main


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
