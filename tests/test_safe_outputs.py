"""Outputs never destroy a user's file: no overwrite without --force, atomic writes, all-or-nothing pairs."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.cli.main import main
from sensor_envs.envs.neato import NeatoEnv
from sensor_envs.lidar.sensors import GaussianLidar
from sensor_envs.outputs import OutputError, OutputTransaction, atomic_write, check_output
from sensor_envs.radar.log import read_log

RADAR_ARGS = ["--sequences", "8", "--cycles", "20", "--seed", "1"]


def _files(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def radar_log(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("radar") / "train.csv"
    assert main(["record", "radar", "--out", str(p), *RADAR_ARGS]) == 0
    return p


# ------------------------------------------------------------------------------------------ no overwrite
def test_existing_output_is_refused_then_replaced_with_force(tmp_path, capsys):
    out = tmp_path / "log.csv"
    out.write_text("precious\n")
    assert main(["record", "radar", "--out", str(out), *RADAR_ARGS]) == 2
    assert "already exists; pass --force" in capsys.readouterr().err
    assert out.read_text() == "precious\n"
    assert main(["record", "radar", "--out", str(out), *RADAR_ARGS, "--force"]) == 0
    assert len(read_log(out)) > 100
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv"]  # no temporary left


def test_force_never_replaces_an_input(tmp_path, radar_log, capsys):
    log = tmp_path / "log.npz"
    log.write_bytes(radar_log.read_bytes())  # a CSV under a .npz name, as a careless user might keep it
    before = log.read_bytes()
    assert main(["fit", "radar", str(log), "--out", str(log), "--force"]) == 2
    assert "is also an input" in capsys.readouterr().err
    assert log.read_bytes() == before


def test_output_given_through_a_link_is_still_the_input(tmp_path, radar_log, capsys):
    copy = tmp_path / "copy.csv"
    copy.write_bytes(radar_log.read_bytes())
    (tmp_path / "sym.csv").symlink_to(copy)
    os.link(copy, tmp_path / "hard.csv")
    (tmp_path / "m.npz").write_bytes(b"a model")
    before = _files(tmp_path)
    for alias in ("sym.csv", "hard.csv"):
        argv = ["validate", "radar", str(tmp_path / "m.npz"), str(copy), "--out", str(tmp_path / alias), "--force"]
        assert main(argv) == 2
        assert "is also an input" in capsys.readouterr().err
    assert _files(tmp_path) == before


def test_suffix_mismatch_is_an_error_not_a_rename(tmp_path, radar_log, capsys):
    assert main(["fit", "radar", str(radar_log), "--out", str(tmp_path / "model.md")]) == 2
    assert "must end in .npz" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
    from sensor_envs.lidar.log import log_from_arrays, save_log
    from sensor_envs.modelio import save_model_file

    with pytest.raises(OutputError, match="must end in .npz"):
        save_model_file(tmp_path / "m.md", "demo", 1, {"params": {}}, {"a": np.zeros(2)})
    log = log_from_arrays(np.ones((2, 3)), np.arange(3) * 0.1, np.zeros((2, 3)), None)  # distinct bearings
    with pytest.raises(OutputError, match="must end in .npz"):
        save_log(log, tmp_path / "log.csv")
    assert not any(tmp_path.iterdir())


def test_fit_radar_refuses_an_existing_baseline_and_replaces_both_with_force(tmp_path, radar_log, capsys):
    model, base = tmp_path / "m.npz", tmp_path / "m_gaussian.npz"
    base.write_bytes(b"old baseline")
    assert main(["fit", "radar", str(radar_log), "--out", str(model)]) == 2
    assert "--force" in capsys.readouterr().err
    assert not model.exists() and base.read_bytes() == b"old baseline"
    assert main(["fit", "radar", str(radar_log), "--out", str(model), "--force"]) == 0
    assert model.stat().st_size > 1000 and base.read_bytes()[:2] == b"PK"


def test_written_files_get_normal_permissions(tmp_path):
    out = tmp_path / "log.csv"
    assert main(["record", "radar", "--out", str(out), *RADAR_ARGS]) == 0
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask


# ------------------------------------------------------------------------------------------ atomic writes
def test_a_write_that_fails_midway_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    out = tmp_path / "precious.csv"
    out.write_text("17487 lines of a precious log\n")
    real_writer = csv.writer

    class Dying:
        def __init__(self, fh):
            self.w, self.n = real_writer(fh), 0

        def writerow(self, row):
            self.n += 1
            if self.n > 100:
                raise KeyboardInterrupt  # as if killed mid-write
            return self.w.writerow(row)

    monkeypatch.setattr(csv, "writer", Dying)
    with pytest.raises(KeyboardInterrupt):
        main(["record", "radar", "--out", str(out), *RADAR_ARGS, "--force"])
    assert out.read_text() == "17487 lines of a precious log\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["precious.csv"]


def test_fit_radar_is_all_or_nothing_when_the_baseline_cannot_be_written(tmp_path, radar_log, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    model = tmp_path / "m.npz"
    code = main(["fit", "radar", str(radar_log), "--out", str(model), "--baseline-out", str(blocker / "b.npz")])
    assert code == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]  # no model without its baseline


def test_fit_lidar_writes_model_and_card_or_neither(tmp_path, monkeypatch):
    from sensor_envs.lidar import validate as lv
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LidarLWLR
    from sensor_envs.modelio import default_model_path

    rec = tmp_path / "rec.npz"
    assert main(["record", "lidar", "--out", str(rec), "--poses", "2", "--repeats", "2"]) == 0
    monkeypatch.setattr(
        LidarLWLR, "fit", lambda self, log: LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE))
    )  # fast stand-in
    real_card = lv.model_card_markdown

    def broken_card(*a, **k):
        raise ValueError("card template broken")  # a bug: keeps its traceback (not an InputError)

    monkeypatch.setattr(lv, "model_card_markdown", broken_card)
    with pytest.raises(ValueError, match="card template broken"):
        main(["fit", "lidar", str(rec), "--out", str(tmp_path / "m.npz"), "--folds", "2"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]
    monkeypatch.setattr(lv, "model_card_markdown", real_card)
    assert main(["fit", "lidar", str(rec), "--out", str(tmp_path / "m.npz"), "--folds", "2"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.md", "m.npz", "rec.npz"]


def test_failed_validate_leaves_no_half_written_report_folder(tmp_path, monkeypatch, capsys):
    from sensor_envs.lidar import validate as lv
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE
    from sensor_envs.modelio import default_model_path

    rec = tmp_path / "rec.npz"
    assert main(["record", "lidar", "--out", str(rec), "--poses", "2", "--repeats", "2"]) == 0

    def broken_plot(*a, **k):
        raise OSError(28, "No space left on device")  # an input/OS error: exit 2, one line naming --out

    monkeypatch.setattr(lv, "plot_per_bearing", broken_plot)  # fails after report.json, report.md, scan.png
    rep = tmp_path / "rep"
    assert main(["validate", "lidar", str(default_model_path(DEFAULT_MODEL_FILE)), str(rec), "--out", str(rep)]) == 2
    assert f"{rep}: No space left on device" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]


def test_validate_with_force_replaces_the_old_report_only_after_success(tmp_path, radar_log, monkeypatch):
    from sensor_envs.radar import validate as rv

    model = tmp_path / "m.npz"
    assert main(["fit", "radar", str(radar_log), "--out", str(model)]) == 0
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "old.txt").write_text("old report")
    monkeypatch.setattr(rv, "plot_all", lambda *a, **k: (_ for _ in ()).throw(ValueError("plot failed")))
    with pytest.raises(ValueError, match="plot failed"):  # a bug keeps its traceback; the old report stays
        main(["validate", "radar", str(model), str(radar_log), "--out", str(rep), "--force"])
    assert _files(rep) == {"old.txt": b"old report"}
    monkeypatch.undo()
    assert main(["validate", "radar", str(model), str(radar_log), "--out", str(rep), "--force"]) == 0
    assert "old.txt" not in _files(rep) and json.loads((rep / "report.json").read_text())["n_rows"] > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz", "m_gaussian.npz", "rep"]


def test_transaction_restores_every_target_when_a_rename_fails(tmp_path, monkeypatch):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    real = os.replace
    calls = {"n": 0}

    def flaky(src, dst):
        calls["n"] += 1
        if Path(dst) == b and Path(src).name.startswith(".b."):
            raise OSError("disk full")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", flaky)
    with pytest.raises(OSError, match="disk full"), OutputTransaction() as tx:
        tx.file(a).write_text("new a")
        tx.file(b).write_text("new b")
    assert a.read_text() == "old a" and not b.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_atomic_write_and_check_output_units(tmp_path):
    p = tmp_path / "sub" / "x.txt"
    with pytest.raises(RuntimeError):
        atomic_write(p, lambda tmp: (tmp.write_text("half"), (_ for _ in ()).throw(RuntimeError()))[0])
    assert not (tmp_path / "sub").exists()  # the folder it created is removed again
    atomic_write(p, lambda tmp: tmp.write_text("whole"))
    assert p.read_text() == "whole" and [q.name for q in p.parent.iterdir()] == ["x.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert check_output(empty, folder=True) == empty  # an empty folder holds nothing to lose
    with pytest.raises(OutputError, match="is a file"):
        check_output(p, folder=True, force=True)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc to see the signal handler")
def test_sigterm_rolls_back_and_keeps_the_old_file(tmp_path):
    out = tmp_path / "precious.csv"
    out.write_text("precious\n")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    cmd = [sys.executable, "-m", "sensor_envs.cli.main", "record", "radar", "--out", str(out), "--force"]
    proc = subprocess.Popen([*cmd, "--sequences", "20000"], env=env, stderr=subprocess.PIPE, text=True)
    status = Path(f"/proc/{proc.pid}/status")
    # No timing: signal only once the CLI has installed its SIGTERM handler (the bit in SigCgt), however long the
    # import takes on a loaded machine; the generous limits below only turn a hang into a failure.
    deadline = time.monotonic() + 600
    while proc.poll() is None:
        caught = next((ln for ln in status.read_text().splitlines() if ln.startswith("SigCgt:")), "SigCgt: 0")
        if int(caught.split()[1], 16) & (1 << (signal.SIGTERM - 1)):
            break
        assert time.monotonic() < deadline, "the CLI never installed its SIGTERM handler"
        time.sleep(0.05)
    assert proc.poll() is None, "the record finished before the signal"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err
    assert out.read_text() == "precious\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["precious.csv"]


@pytest.mark.slow
def test_subprocess_bad_input_has_no_traceback(tmp_path):
    bad = tmp_path / "bad.log.gz"
    bad.write_bytes(b"\x1f\x8b\x08\x00garbage")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    r = subprocess.run(
        [sys.executable, "-m", "sensor_envs.cli.main", "fit", "lidar", str(bad), "--out", str(tmp_path / "m.npz")],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,  # a hang guard only: a loaded machine may take minutes to import
    )
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr and str(bad) in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.log.gz"]


def test_utf8_bom_csv_is_accepted(tmp_path, radar_log):
    bom = tmp_path / "excel.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + radar_log.read_bytes())
    assert len(read_log(bom)) == len(read_log(radar_log))


# ------------------------------------------------------------------------------------------ Neato-v0
def test_nan_or_inf_action_is_a_clear_error_and_the_pose_stays_finite():
    env = gym.make("sensor_envs/Neato-v0")
    env.reset(seed=0)
    for bad in ([np.nan, 0.0], [0.0, np.inf], [np.nan, np.nan]):
        with pytest.raises(ValueError, match="action"):
            env.step(np.array(bad, dtype=np.float32))
    assert np.isfinite(env.unwrapped.pose).all()
    obs, *_ = env.step(np.array([0.5, 0.0], dtype=np.float32))
    assert env.observation_space.contains(obs)


def test_start_outside_the_map_or_in_a_wall_is_refused():
    env = NeatoEnv()
    with pytest.raises(ValueError, match=r"options\['start'\].*outside map"):
        env.reset(seed=0, options={"start": [100, 100, 0]})
    with pytest.raises(ValueError, match=r"options\['start'\].*robot radius"):
        env.reset(seed=0, options={"start": [0.05, 0.9, 0.0]})
    with pytest.raises(ValueError, match=r"options\['goal'\].*outside map"):
        env.reset(seed=0, options={"goal": [-5.0, 0.5, 0.0]})
    obs, _ = env.reset(seed=0, options={"start": [0.9, 0.5, 0.6]})
    assert env.observation_space.contains(obs)


def test_step_before_reset_is_a_clear_error():
    env = NeatoEnv()
    with pytest.raises(gym.error.ResetNeeded, match=r"reset\(\) before step\(\)"):
        env.step(np.zeros(2, dtype=np.float32))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"sigma0": -1.0},
        {"sigma0": float("nan")},
        {"k_range": -0.001},
        {"k_incidence": float("inf")},
        {"alpha_max": 2.0},
        {"p_null_floor": 1.5},
        {"p_null_floor": -0.1},
        {"sigma0": "0.01"},
    ],
)
def test_gaussian_lidar_rejects_negative_or_non_finite_parameters(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=name):
        GaussianLidar(**kwargs)
    with pytest.raises(ValueError, match=name):
        gym.make("sensor_envs/Neato-v0", lidar="gaussian", lidar_kwargs=kwargs)
