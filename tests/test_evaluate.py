"""Algorithm-level evaluation (sensor_envs.evaluate): detector, P/R arithmetic, experiments and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.evaluate.lidar_detection import (
    TRAJECTORY_STEPS,
    DetectorParams,
    detect_lines,
    present_targets,
    run_trajectory,
    target_indices,
)
from sensor_envs.evaluate.metrics import precision_recall, trajectory_distance, wilson_interval
from sensor_envs.evaluate.radar_aeb import NNTracker, gospa
from sensor_envs.geometry import raycast_pose
from sensor_envs.lidar.log import save_log

BEARINGS = np.deg2rad(np.arange(360.0))
ROOM = [[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]]


def _scan(board_length: float, pose=(1.0, 1.5, 0.0)) -> np.ndarray:
    board = [[[2.0, 1.5 - board_length / 2], [2.0, 1.5 + board_length / 2]]]
    r, _, _ = raycast_pose(np.asarray(pose), BEARINGS, np.asarray(ROOM + board, float), 5.0)
    return np.where(np.isfinite(r), r, 0.0)


def test_detector_finds_board_of_known_length_and_not_a_shorter_one():
    p = DetectorParams(length=0.61, length_tol=0.1, gap_tol=0.1, max_rms_dist=0.01, min_points=5)
    lines = detect_lines(_scan(0.61), BEARINGS, p)
    assert len(lines) == 1
    mid = lines[0].mean(axis=0)  # board at x = 1 m ahead of the sensor, centred on its axis
    assert abs(mid[0] - 1.0) < 0.02 and abs(mid[1]) < 0.05
    assert abs(np.linalg.norm(lines[0][1] - lines[0][0]) - 0.61) <= 0.1
    assert len(detect_lines(_scan(0.40), BEARINGS, p)) == 0
    assert len(detect_lines(_scan(0.90), BEARINGS, p)) == 0


def test_gap_check_removes_wall_pieces():
    loose = DetectorParams(length=0.61, length_tol=0.1)
    strict = DetectorParams(length=0.61, length_tol=0.1, gap_tol=0.1)
    scan = _scan(0.61)
    n_loose = len(detect_lines(scan, BEARINGS, loose))
    assert n_loose > 8  # pieces of walls count without the check
    # with it: the board, and only whole wall pieces of the right length (here none: the back wall's
    # pieces beside the board's shadow are 0.79 m long from this pose)
    found = detect_lines(_scan(0.61, pose=(0.5, 1.5, 0.0)), BEARINGS, strict)
    assert len(found) == 1 and abs(found[0, 0, 0] - 1.5) < 0.02


def test_detector_rejects_bad_parameters():
    with pytest.raises(ValueError, match="median_window"):
        DetectorParams(median_window=2)
    with pytest.raises(ValueError, match="length_tol"):
        DetectorParams(length_tol=0.0)


def test_precision_recall_arithmetic():
    assert precision_recall(3, 1, 2) == (0.75, 0.6)
    assert precision_recall(0, 0, 4) == (1.0, 0.0)
    assert precision_recall(0, 5, 0) == (0.0, 1.0)
    lo, hi = wilson_interval(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-3) and hi == pytest.approx(0.9433, abs=1e-3)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    a = [{"step": 0, "precision": 0.5, "recall": 0.5}, {"step": 1, "precision": 1.0, "recall": 0.0}]
    b = [{"step": 0, "precision": 0.8, "recall": 0.9}, {"step": 1, "precision": 1.0, "recall": 0.0}]
    assert trajectory_distance(a, b) == pytest.approx(0.25)
    with pytest.raises(ValueError):
        trajectory_distance(a, b[:1])


def test_trajectory_on_ideal_scans_counts_every_present_board():
    segs = np.asarray(ROOM + [[[2.0, 1.195], [2.0, 1.805]]], float)
    poses = np.array([[1.0, 1.5, 0.0], [1.2, 0.8, 0.5], [3.0, 2.5, 3.0]])
    r, _, _ = raycast_pose(poses, BEARINGS, segs, 5.0)
    scans = np.where(np.isfinite(r), r, 0.0)
    tg = target_indices(segs, 0.61)
    assert tg.tolist() == [4]
    present = present_targets(poses, BEARINGS, segs, tg)
    traj = run_trajectory(scans, BEARINGS, poses, segs, 0.61)
    assert len(traj) == len(TRAJECTORY_STEPS)
    last = traj[-1]
    assert last["tp"] + last["fn"] == int(present.sum()) > 0
    assert last["recall"] == 1.0  # the ideal scan shows every present board whole
    assert traj[0]["fp"] > 5 * last["fp"]  # with the checks off, wall pieces are false positives
    assert last["precision"] > 10 * traj[0]["precision"]


def test_gospa_and_tracker():
    assert gospa(np.zeros((1, 2)), np.zeros((1, 2))) == 0.0
    assert gospa(np.zeros((0, 2)), np.zeros((1, 2))) == pytest.approx(5 / np.sqrt(2))
    assert gospa(np.array([[0.0, 0.0]]), np.array([[3.0, 4.0]])) == pytest.approx(
        5.0
    )  # capped at c: same as a miss + a false
    trk = NNTracker()
    for t in range(4):
        trk.step(np.array([[10.0 * t, 0.0]]), np.zeros(2))
    assert trk.confirmed.sum() == 1
    np.testing.assert_allclose(trk.v[trk.confirmed][0], [10.0, 0.0], atol=1e-9)


def _rig_log(tmp_path, poses=6, repeats=3):
    from sensor_envs.lidar.rig import NeatoRig
    from sensor_envs.maps import load_map

    log, _ = NeatoRig().record(load_map("seed_room").segments, np.random.default_rng(3), n_poses=poses, repeats=repeats)
    return save_log(log, tmp_path / "rig.npz")


def test_log_experiment_with_model_file_on_rig(tmp_path):
    from sensor_envs.evaluate.lidar_experiments import log_experiment
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LidarLWLR
    from sensor_envs.modelio import default_model_path

    rep = log_experiment(
        load_log(_rig_log(tmp_path)), model=LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE)), repeats=3
    )
    assert set(rep["trajectories"]) >= {"real", "model", "baseline"}
    for traj in rep["trajectories"].values():
        assert [s["step"] for s in traj] == list(range(len(TRAJECTORY_STEPS)))
        assert all(0 <= s["precision"] <= 1 and 0 <= s["recall"] <= 1 for s in traj)
    assert set(rep["distance_to_real"]) >= {"model", "baseline"}
    assert all(np.isfinite(v) for v in rep["distance_to_real"].values())


def test_boxworld_small():
    from sensor_envs.evaluate.lidar_experiments import boxworld_experiment, boxworld_map
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LidarLWLR
    from sensor_envs.modelio import default_model_path

    segs = boxworld_map(np.random.default_rng(0))
    assert target_indices(segs, 0.61).size >= 1
    rep = boxworld_experiment(
        LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE)), n_configs=2, poses_per_config=1, repeats=2
    )
    assert rep["data"]["scans_per_source"] == 4
    assert rep["trajectories"]["rig"][0]["scans"] == 4  # the rig plays reality and is named so
    assert "real" not in rep["trajectories"] and "distance_to_real" not in rep
    assert all(np.isfinite(v) for v in rep["distance_to_rig"].values())


def test_cli_detection_writes_report_refuses_existing_out(tmp_path, capsys):
    log = _rig_log(tmp_path, poses=4, repeats=2)
    out = tmp_path / "ev"
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE
    from sensor_envs.modelio import default_model_path

    args = [
        "evaluate",
        "detection",
        "--real",
        str(log),
        "--model",
        str(default_model_path(DEFAULT_MODEL_FILE)),
        "--repeats",
        "2",
    ]
    assert main([*args, "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert set(rep["trajectories"]) >= {"real", "model", "baseline"} and "distance_to_real" in rep
    assert (out / "report.md").exists() and (out / "pr_trajectories.png").exists()
    capsys.readouterr()
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--force" in err[0]
    assert main([*args, "--out", str(out), "--force"]) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ev")]  # no temporary folder left


def test_cli_detection_bad_input_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    np.savez(bad, ranges=np.ones((2, 3, 2)), bearings=np.zeros(4), poses=np.zeros((2, 3)))
    assert main(["evaluate", "detection", "--real", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.npz" in err[0]
    assert not (tmp_path / "o").exists()
    assert main(["evaluate", "detection", "--real", str(bad), "--out", str(bad)]) == 2


def test_aeb_small():
    from sensor_envs.evaluate.radar_aeb import aeb_experiment

    rep = aeb_experiment(episodes=2, max_steps=4, radars=("ideal", "kde"))
    for v in rep["radars"].values():
        assert v["hits"] + v["missed_warnings"] == v["truth_steps"]
        assert v["hits"] + v["false_alarms"] == v["warnings"]
        assert v["recall_ci95"][0] <= v["recall"] <= v["recall_ci95"][1]


def test_radar_trigger_on_rig_log():
    from sensor_envs.evaluate.radar_detection import TRIGGER_STEPS, radar_detection_experiment
    from sensor_envs.radar.rig import record_rig_log

    log = record_rig_log(2, 20, 5, np.random.default_rng(0))
    rep = radar_detection_experiment(log, draws=2)
    assert len(rep["trajectories"]["real"]) == len(TRIGGER_STEPS)
    ideal = rep["trajectories"]["ideal"]
    assert all(s["fn"] == 0 for s in ideal)  # the ideal radar reports every box at its corner
    assert set(rep["distance_to_real"]) >= {"model", "baseline"}


# ----------------------------------------------------------------------------------------- real data
def test_real_neato_detection_trajectory(real_data):
    from sensor_envs.evaluate.lidar_experiments import log_experiment
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LidarLWLR
    from sensor_envs.modelio import default_model_path

    log = load_log(real_data / "neato_mar27_train.npz").subset(np.arange(0, 29, 3))
    rep = log_experiment(log, model=LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE)), repeats=2)
    real = rep["trajectories"]["real"]
    assert real[3]["recall"] > real[0]["recall"]  # recall steps raise recall on the real scans
    assert real[-1]["precision"] > real[3]["precision"]  # precision steps raise precision


def test_real_astyx_trigger(real_data):
    from sensor_envs.evaluate.radar_detection import radar_detection_experiment
    from sensor_envs.radar.astyx import load_astyx

    root = real_data / "astyx_hires2019"
    if not root.is_dir():
        pytest.skip(f"{root} is absent")
    rep = radar_detection_experiment(load_astyx(root, frames=range(40)), draws=2)
    assert rep["data"]["cycles"] == 40
    assert 0 < rep["trajectories"]["real"][2]["recall"] <= 1


def test_scan_matcher_converges_and_registration_small():
    from sensor_envs.evaluate.lidar_registration import match_scan, registration_experiment
    from sensor_envs.maps import load_map

    segs = load_map("corridor").segments
    truth = np.array([2.5, 0.6, 0.1])
    r, _, _ = raycast_pose(truth, BEARINGS, segs, 5.0)
    ok = np.isfinite(r)
    pts = np.column_stack([r[ok] * np.cos(BEARINGS[ok]), r[ok] * np.sin(BEARINGS[ok])])
    start = truth + np.array([0.05, -0.04, 0.03])
    err = [np.linalg.norm(match_scan(pts, start, segs, it)[:2] - truth[:2]) for it in (0, 10, 100)]
    assert err[0] > err[1] > err[2] and err[2] < 0.01
    rep = registration_experiment(n_poses=4, iterations=(2, 5))
    assert set(rep["curves"]) == {"reference", "model", "baseline", "ideal"}
    assert all(c[-1]["distance_to_final_m"] == 0.0 for c in rep["curves"].values())
