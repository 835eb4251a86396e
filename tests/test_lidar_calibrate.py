"""Neato rig files, ``calibrate lidar`` (simulation-based rig calibration) and ``record lidar --rig``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.lidar.calibrate import calibrate_rig, discrepancy, load_real_log, log_summary
from sensor_envs.lidar.log import load_log, save_log
from sensor_envs.lidar.rig import NeatoRig, smooth_along_bearings
from sensor_envs.maps import load_map
from sensor_envs.modelio import ModelFileError

ROOM = load_map("seed_room").segments


def _rig_json(tmp_path, **params):
    path = tmp_path / "rig.json"
    path.write_text(json.dumps({"kind": "neato_rig", "format_version": 1, "params": params}))
    return path


def test_rig_file_round_trip(tmp_path):
    rig = NeatoRig(
        unit_seed=3,
        null_logit=(-3.0, 2.0, 0.5),
        null_bearing_logit=tuple(np.linspace(-1, 1, 360)),
        null_cell_corr=0.9,
        null_arc=2.5,
        spur_prone=0.2,
        pose_sd=(0.01, 0.02),
        blocked=(5, 6, 7),
    )
    path = rig.to_file(tmp_path / "rig.json", {"calibrated_against": "synthetic"})
    back = NeatoRig.from_file(path)
    assert back.params() == rig.params()
    assert NeatoRig.card_of(path) == {"calibrated_against": "synthetic"}
    a, _ = rig.record(ROOM, np.random.default_rng(0), n_poses=2, repeats=3)
    b, _ = back.record(ROOM, np.random.default_rng(0), n_poses=2, repeats=3)
    np.testing.assert_array_equal(a.ranges, b.ranges)


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"spur_prone": 1.7}, "params.spur_prone"),
        ({"bias_sd": -0.01}, "params.bias_sd"),
        ({"sigma_knots": [0.001, -0.002]}, "params.sigma_knots"),
        ({"null_cell_corr": 1.0}, "params.null_cell_corr"),
        ({"pose_sd": [0.01]}, "params.pose_sd"),
        ({"null_bearing_logit": [0.0, 1.0]}, "params.null_bearing_logit"),
        ({"spur_frac": [0.9, 0.2]}, "params.spur_frac"),
        ({"blocked": [400]}, "params.blocked"),
        ({"max_range": "far"}, "params.max_range"),
        ({"warp": 1}, "params.warp"),
    ],
)
def test_bad_rig_values_name_file_and_field(tmp_path, params, field):
    with pytest.raises(ModelFileError, match=f"rig.json: field '{field}'"):
        NeatoRig.from_file(_rig_json(tmp_path, **params))


def test_constructor_checks_values():
    with pytest.raises(ValueError, match="spur_prone"):
        NeatoRig(spur_prone=1.7)
    with pytest.raises(ValueError, match="null_bearing_logit"):
        NeatoRig(null_bearing_logit=(0.0,))


def test_shipped_rig_loads_and_says_what_it_was_calibrated_against():
    rig = NeatoRig.from_file()
    card = NeatoRig.card_of()
    assert len(card["calibrated_against"]["sha256_of_ranges"]) == 64
    after, before = card["after"]["per_statistic"], card["before"]["per_statistic"]
    assert after["total"] < before["total"]
    assert len(rig.null_bearing_logit) == rig.n_bearings and rig.null_cell_corr > 0


def test_copula_nulls_keep_the_mean_rate_and_persist():
    rig = NeatoRig(null_cell_corr=0.95, null_arc=2.0, pose_sd=(0.0, 0.0), map_sd=0.0, spur_prone=0.0)
    r = np.full((40, 360), 1.5)
    a = np.zeros((40, 360))
    p = rig.cell_p_null(r, a, np.random.default_rng(0))
    free = ~rig.blocked_mask()
    assert abs(p[:, free].mean() - rig.p_null(r, a)[:, free].mean()) < 0.02
    assert ((p[:, free] > 0.05) & (p[:, free] < 0.95)).mean() < 0.3  # mostly all-or-nothing cells
    z = smooth_along_bearings(np.random.default_rng(1).standard_normal((200, 360)), 3.0)
    assert abs(z.std() - 1) < 0.05 and np.corrcoef(z[:, :-1].ravel(), z[:, 1:].ravel())[0, 1] > 0.8


def test_calibrate_recovers_known_rig(tmp_path):
    """A synthetic "real" log from a rig with non-default effects: calibration moves toward them."""
    truth = NeatoRig(
        unit_seed=5,
        null_logit=(-3.0, 1.38, 1.36),
        null_cell_corr=0.97,
        null_arc=3.0,
        spur_prone=0.3,
        bias_mean=0.015,
        pose_sd=(0.005, 0.005),
    )
    poses = np.array([[0.6, 0.5, 0.3], [3.0, 1.3, 2.0], [1.0, 1.4, -1.0], [2.8, 0.4, 1.0], [1.8, 0.5, 0.0]])
    log, _ = truth.record(ROOM, np.random.default_rng(7), poses=poses, repeats=30)
    path = save_log(log, tmp_path / "fake_real.npz")
    real = load_real_log(path)
    rig, card = calibrate_rig(real, seed=0, max_evals=70, progress=False)
    before, after = card["before"]["per_statistic"], card["after"]["per_statistic"]
    assert after["total"] < 0.3 * before["total"]
    assert after["mixed_null"] < 0.3 * before["mixed_null"]
    assert rig.null_cell_corr > 0.9  # default 0: independent readings
    assert 1.5 < rig.null_arc < 5.0  # truth 3 bearings
    assert abs(rig.bias_mean - 0.015) < 0.004  # default 0.0038

    def prone(x):
        return x.spur_prone_per_bearing()[~x.blocked_mask()].mean()

    assert 0.07 < prone(rig) < 0.16 and prone(truth) > 3 * prone(NeatoRig())  # truth 0.115, default 0.034
    stats = log_summary(real)
    assert stats["blocked"] == list(truth.blocked)
    assert discrepancy(stats, stats)["total"] == 0.0


def test_cli_calibrate_bad_input_exit_2(tmp_path, capsys):
    out = tmp_path / "rig.json"
    assert main(["calibrate", "lidar", str(tmp_path / "absent"), "--out", str(out)]) == 2
    assert "absent" in capsys.readouterr().err
    assert main(["calibrate", "lidar", str(tmp_path), "--out", str(out)]) == 2  # folder without the log
    assert "neato_mar27_train.npz" in capsys.readouterr().err
    rig = NeatoRig().to_file(tmp_path / "a_rig.json")
    assert main(["calibrate", "lidar", str(rig), "--out", str(out)]) == 2  # wrong kind of file
    err = capsys.readouterr().err
    assert "a_rig.json" in err and len(err.strip().splitlines()) == 1
    scans, _ = NeatoRig().record(ROOM, np.random.default_rng(0), n_poses=3, repeats=1)
    one = save_log(scans, tmp_path / "scans.npz")
    assert main(["calibrate", "lidar", str(one), "--out", str(out)]) == 2
    assert "field 'ranges'" in capsys.readouterr().err
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    assert main(["calibrate", "lidar", str(junk), "--out", str(out)]) == 2
    assert "junk.npz" in capsys.readouterr().err
    out.write_text("keep")
    log, _ = NeatoRig().record(ROOM, np.random.default_rng(0), n_poses=2, repeats=3)
    good = save_log(log, tmp_path / "good.npz")
    assert main(["calibrate", "lidar", str(good), "--out", str(out)]) == 2  # exists, no --force
    assert "--force" in capsys.readouterr().err and out.read_text() == "keep"
    assert main(["calibrate", "lidar", str(good), "--out", str(tmp_path / "rig.txt")]) == 2


def test_cli_calibrate_writes_rig_file(tmp_path):
    truth = NeatoRig(null_cell_corr=0.9, pose_sd=(0.005, 0.005))
    log, _ = truth.record(ROOM, np.random.default_rng(2), n_poses=3, repeats=10)
    real = save_log(log, tmp_path / "real.npz")
    out = tmp_path / "rig.json"
    assert main(["calibrate", "lidar", str(real), "--out", str(out), "--max-evals", "15"]) == 0
    card = NeatoRig.card_of(out)
    assert card["calibrated_against"]["file"] == "real.npz" and card["search"]["evaluations"] <= 16
    assert card["command"].startswith("sensor-envs")
    assert out.stat().st_size < 40_000  # statistics, not data
    assert main(["record", "lidar", "--out", str(tmp_path / "rec.npz"), "--rig", str(out), "--poses", "2"]) == 0


def test_cli_record_from_rig_file(tmp_path, capsys):
    quiet = _rig_json(tmp_path, blocked=[], null_logit=[-30.0, 0.0, 0.0], spur_prone=0.0)
    out = tmp_path / "quiet.npz"
    assert main(["record", "lidar", "--out", str(out), "--rig", str(quiet), "--poses", "3", "--repeats", "4"]) == 0
    x = load_log(out).ranges
    assert (x[np.isfinite(x)] == 0).mean() < 0.05  # no blocked bearings, no dropout: only misses
    default = tmp_path / "default.npz"
    assert main(["record", "lidar", "--out", str(default), "--poses", "3", "--repeats", "4"]) == 0
    y = load_log(default).ranges
    assert np.all(y[:, list(NeatoRig.from_file().blocked)] == 0)  # the shipped calibrated rig
    bad = _rig_json(tmp_path, spur_prone=1.7)
    assert main(["record", "lidar", "--out", str(tmp_path / "b.npz"), "--rig", str(bad), "--force"]) == 2
    err = capsys.readouterr().err
    assert "rig.json: field 'params.spur_prone'" in err and len(err.strip().splitlines()) == 1
    assert main(["record", "lidar", "--out", str(tmp_path / "c.npz"), "--rig", str(tmp_path / "none.json")]) == 2
    assert not (tmp_path / "b.npz").exists() and not (tmp_path / "c.npz").exists()


def test_calibrate_on_real_data_statistics(real_data):
    """The real log's statistics the rig is calibrated to (blocked bearings detected, not hard-coded)."""
    real = load_real_log(real_data)
    s = log_summary(real)
    assert len(s["blocked"]) == 26 and 0.04 < s["mixed_null"] < 0.09
    card = NeatoRig.card_of()
    from sensor_envs.lidar.calibrate import ranges_sha256

    assert card["calibrated_against"]["sha256_of_ranges"] == ranges_sha256(real)
