"""Neato rig files, ``calibrate lidar`` (simulation-based rig calibration) and ``record lidar --rig``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

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
    tmp_path.mkdir(exist_ok=True)
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
    assert rig.null_range_knots and rig.null_incidence_knots and rig.bias_range_knots  # the flexible laws (issue 12)


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


# ------------------------------------------------------------- flexible laws (issue 12: lidar fidelity)
OLD_RIG = Path(__file__).parent / "data" / "neato_rig_ab26d34.json"
"""The rig file shipped at commit ab26d34 (linear null law, no tables): it must load and behave as before."""


def _old_style_rig(tmp_path):
    params = {
        "unit_seed": 3,
        "null_logit": [-3.0, 2.0, 0.5],
        "null_bearing_logit": list(np.round(np.linspace(-1, 1, 360), 3)),
        "null_cell_corr": 0.9,
        "null_arc": 2.5,
        "spur_prone": 0.2,
        "spur_bearing_weight": list(np.round(np.linspace(0.5, 1.5, 360), 3)),
        "pose_sd": [0.01, 0.02],
        "blocked": [5, 6, 7],
    }
    return NeatoRig.from_file(_rig_json(tmp_path, **params))


def test_old_rig_files_record_as_before(tmp_path):
    """A rig file without the new parameters records the readings the code of commit ab26d34 recorded.

    ``tests/data/neato_rig_ab26d34_recording.npz`` was written by that commit's ``sensor_envs`` on the same inputs
    (on the machine of the change, the arrays were bit-identical). The comparison allows float64 rounding in the
    last bits (numpy's SIMD math may differ between CPUs) but no other change: same nulls, same draws.
    """
    ref = np.load(Path(__file__).parent / "data" / "neato_rig_ab26d34_recording.npz")
    rig = _old_style_rig(tmp_path)
    log, _ = rig.record(ROOM, np.random.default_rng(4), n_poses=3, repeats=5)
    x = rig.measure(np.linspace(0.3, 4.5, 360), np.linspace(0, 1.4, 360), np.random.default_rng(5))
    for got, want in ((log.ranges, ref["ranges"]), (log.poses, ref["poses"]), (x, ref["measure"])):
        assert got.shape == want.shape and np.array_equal(got == 0, want == 0)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert 0 < (ref["ranges"] == 0).mean() < 1


def test_previously_shipped_rig_file_loads_with_its_linear_law():
    old = NeatoRig.from_file(OLD_RIG)
    assert old.null_range_knots == () and old.out_cell_rate == 0.0 and old.pose_sd_spread == 0.0
    r = np.linspace(0.3, 4.0, old.n_bearings)[None]
    a = np.linspace(0.0, 1.5, old.n_bearings)[None]
    c0, c1, c2 = old.null_logit
    np.testing.assert_allclose(old.null_linear(r, a), c0 + c1 * r + c2 * a + np.asarray(old.null_bearing_logit))
    assert np.all(old.bias_shape(r, a) == 0) and np.all(old.spur_range_factor(r) == 1)


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"null_range_knots": [0.0, 1.0], "null_range_logit": [0.0]}, "params.null_range_logit"),
        ({"null_range_knots": [1.0, 0.5], "null_range_logit": [0.0, 1.0]}, "params.null_range_knots"),
        ({"null_incidence_knots": [0.0, 1.0], "null_incidence_logit": [0.0, 99.0]}, "params.null_incidence_logit"),
        ({"spur_range_knots": [0.5, 1.0], "spur_range_weight": [1.0, -0.5]}, "params.spur_range_weight"),
        ({"spur_range_knots": [0.5], "spur_range_weight": [1.0]}, "params.spur_range_weight"),
        ({"bias_range_knots": [0.0, 4.0], "bias_range": [0.0, 2.0]}, "params.bias_range"),
        ({"bias_incidence_knots": [-0.1, 1.0], "bias_incidence": [0.0, 0.0]}, "params.bias_incidence_knots"),
        ({"pose_sd_spread": 7.0}, "params.pose_sd_spread"),
        ({"pose_sd_spread": float("nan")}, "params.pose_sd_spread"),
        ({"out_cell_rate": 1.0}, "params.out_cell_rate"),
        ({"out_cell_arc": -1.0}, "params.out_cell_arc"),
        ({"null_bearing_range_slope": [0.0] * 359 + [99.0]}, "params.null_bearing_range_slope"),
    ],
)
def test_bad_new_rig_values_name_file_and_field(tmp_path, params, field):
    with pytest.raises(ModelFileError, match=f"rig.json: field '{field}'"):
        NeatoRig.from_file(_rig_json(tmp_path, **params))


def test_null_tables_add_to_the_linear_law():
    rig = NeatoRig(
        null_logit=(0.0, 0.0, 0.0),
        null_range_knots=(0.0, 2.0),
        null_range_logit=(-4.0, 4.0),
        null_incidence_knots=(0.0, 1.0, 1.5),
        null_incidence_logit=(0.0, 0.0, 3.0),
    )
    k = np.flatnonzero(~rig.blocked_mask())[:3]
    r = np.zeros((1, rig.n_bearings))
    a = np.zeros_like(r)
    r[0, k], a[0, k] = (1.0, 3.0, 1.0), (0.0, 0.0, 1.25)
    p = rig.p_null(r, a)[0, k]
    np.testing.assert_allclose(p, 1 / (1 + np.exp(-np.array([0.0, 4.0, 1.5]))))  # constant beyond the end knot


def test_a_bad_entry_of_a_long_table_is_named_not_the_whole_table(tmp_path):
    slopes = [0.0] * 360
    slopes[5] = 99.0
    with pytest.raises(ModelFileError) as err:
        NeatoRig.from_file(_rig_json(tmp_path, null_bearing_range_slope=slopes))
    msg = str(err.value)
    assert "field 'params.null_bearing_range_slope'" in msg
    assert msg.endswith("got 360 values, first rejected entry [5] = 99.0") and len(msg) < 300


def test_per_bearing_range_slopes_add_to_the_null_logit():
    from sensor_envs.lidar.rig import NULL_SLOPE_CENTRE

    slopes = np.zeros(360)
    slopes[[10, 20]] = (1.0, -2.0)
    rig = NeatoRig(null_logit=(0.0, 0.0, 0.0), null_bearing_range_slope=tuple(slopes))
    r = np.full((1, 360), 3.0)
    z = rig.null_linear(r, np.zeros_like(r))[0]
    np.testing.assert_allclose(z[[10, 20, 30]], np.array([1.0, -2.0, 0.0]) * (3.0 - NULL_SLOPE_CENTRE))
    with pytest.raises(ValueError, match="null_bearing_range_slope"):
        NeatoRig(null_bearing_range_slope=(0.0, 1.0))


def test_fit_null_law_recovers_per_bearing_range_slopes():
    from sensor_envs.lidar.calibrate import fit_null_law
    from sensor_envs.lidar.rig import NULL_SLOPE_CENTRE

    rng = np.random.default_rng(1)
    p_, k = 200, 40
    r, a = rng.uniform(0.2, 3.8, (p_, k)), rng.uniform(0.0, 1.5, (p_, k))
    off, slope = rng.normal(0, 1, k), rng.normal(0, 1, k)
    slope -= slope.mean()  # the slopes sum to 0: a common trend belongs to the shared range table
    z = -1.0 + off[None] + slope[None] * (r - NULL_SLOPE_CENTRE)
    law = fit_null_law(r, a, np.ones((p_, k), bool), 1 / (1 + np.exp(-z)), slope_ridge=0.01)
    s = np.asarray(law["range_slopes"])
    assert s.shape == (k,) and np.corrcoef(s, slope)[0, 1] > 0.98 and abs(s.sum()) < 0.05
    none = fit_null_law(r, a, np.ones((p_, k), bool), 1 / (1 + np.exp(-z)), slope_ridge=np.inf)
    assert none["range_slopes"] == ()


def test_slope_ridge_is_chosen_by_leave_poses_out_cv():
    from sensor_envs.lidar.calibrate import NULL_SLOPE_RIDGES, choose_slope_ridge
    from sensor_envs.lidar.rig import NULL_SLOPE_CENTRE

    rng = np.random.default_rng(2)
    p_, k = 25, 6
    r, a = rng.uniform(0.2, 3.8, (p_, k)), rng.uniform(0.0, 1.5, (p_, k))
    off = rng.normal(0, 1, k)
    hit = np.ones((p_, k), bool)
    flat = np.broadcast_to(1 / (1 + np.exp(-(-1.0 + off[None]))), (p_, k))
    sloped = 1 / (1 + np.exp(-(-1.0 + off[None] + 3.0 * np.sign(off)[None] * (r - NULL_SLOPE_CENTRE))))
    noisy = lambda p: rng.binomial(20, p) / 20  # noqa: E731 - 20 readings per cell
    ridge_flat, cv = choose_slope_ridge(r, a, hit, noisy(flat))
    assert ridge_flat == np.inf and set(cv) == {f"{v:g}" for v in NULL_SLOPE_RIDGES}  # slopes only add noise
    ridge_sloped, cv = choose_slope_ridge(r, a, hit, noisy(sloped))
    assert np.isfinite(ridge_sloped) and cv[f"{ridge_sloped:g}"] < cv["inf"]


def test_spurious_returns_follow_the_range_factor():
    rig = NeatoRig(
        spur_prone=0.5,
        spur_range_knots=(0.9, 1.0),
        spur_range_weight=(1.0, 0.0),
        pose_sd=(0.0, 0.0),
        map_sd=0.0,
    )
    log, truth = rig.record(ROOM, np.random.default_rng(3), n_poses=6, repeats=2)
    from sensor_envs.lidar.lwlr import lidar_features

    r, _ = lidar_features(truth["true_poses"], rig.bearings, ROOM, rig.max_range)
    prone = truth["p_spur"] > 0
    assert prone[r < 0.9].mean() > 0.1 and not prone[r > 1.0].any()


def test_bias_tables_and_outlying_cells():
    quiet = {"pose_sd": (0.0, 0.0), "map_sd": 0.0, "spur_prone": 0.0, "bias_sd": 0.0, "bias_mean": 0.0}
    rig = NeatoRig(bias_range_knots=(1.0, 3.0), bias_range=(0.0, -0.1), null_logit=(-30.0, 0.0, 0.0), **quiet)
    poses = np.array([[1.0, 0.8, 0.0], [2.5, 1.0, 1.0]])
    log, _ = rig.record(ROOM, np.random.default_rng(0), poses=poses, repeats=20)
    from sensor_envs.lidar.lwlr import cell_statistics, lidar_features

    r, _ = lidar_features(poses, rig.bearings, ROOM, rig.max_range)
    st = cell_statistics(log, 6.0, split_spurious=True)
    ok = np.isfinite(r) & (st["n_ok"] > 10) & (r < 3.5)
    want = np.interp(r[ok], (1.0, 3.0), (0.0, -0.1))
    assert np.median(np.abs(st["mean"][ok] - r[ok] - want)) < 0.003
    out = NeatoRig(out_cell_rate=0.2, out_cell_arc=2.0, null_logit=(-30.0, 0.0, 0.0), **quiet)
    log, _ = out.record(ROOM, np.random.default_rng(0), poses=poses, repeats=5)
    st = cell_statistics(log, 6.0, split_spurious=True)
    far = np.abs(st["mean"] - r) > 0.2
    assert 0.08 < far[ok].mean() < 0.35


def test_pose_error_spread_scales_the_pose_errors_per_pose():
    rig = NeatoRig(pose_sd=(0.01, 0.0), pose_sd_spread=1.5, map_sd=0.0)
    poses = np.tile([[1.5, 1.0, 0.0]], (400, 1))
    log, truth = rig.record(ROOM, np.random.default_rng(1), poses=poses, repeats=1)
    e = np.linalg.norm(log.poses[:, :2] - truth["true_poses"][:, :2], axis=1)
    # a log-normal scale mixture: heavier tails than the Rayleigh of a fixed sd (90 % / 50 % ratio 1.83)
    assert np.quantile(e, 0.9) / np.median(e) > 3.0


def test_fit_null_law_recovers_tables_and_bearing_offsets():
    from sensor_envs.lidar.calibrate import NULL_INCIDENCE_KNOTS, NULL_RANGE_KNOTS, fit_null_law

    rng = np.random.default_rng(0)
    p_, k = 200, 40
    r, a = rng.uniform(0.2, 3.8, (p_, k)), rng.uniform(0.0, 1.5, (p_, k))
    off = rng.normal(0, 1, k)
    f = lambda v: np.interp(v, (0.0, 2.0, 4.0), (0.0, 3.0, 3.0))  # noqa: E731 - rises, then flat
    g = lambda v: np.interp(v, (0.0, 1.0, 1.5), (0.0, 0.0, 4.0))  # noqa: E731 - flat, then steep
    z = -3.0 + off[None] + f(r) + g(a)
    law = fit_null_law(r, a, np.ones((p_, k), bool), 1 / (1 + np.exp(-z)))
    fr = np.asarray(law["null_range_logit"])
    gi = np.asarray(law["null_incidence_logit"])
    np.testing.assert_allclose(fr - fr[0], f(np.asarray(NULL_RANGE_KNOTS)), atol=0.35)
    seen = np.asarray(NULL_INCIDENCE_KNOTS) <= 1.5  # a knot beyond the data follows the smoothing
    np.testing.assert_allclose((gi - gi[0])[seen], g(np.asarray(NULL_INCIDENCE_KNOTS))[seen], atol=0.35)
    b = law["c0"] + np.asarray(law["offsets"])
    assert np.corrcoef(b, off)[0, 1] > 0.98


def test_fit_bias_law_recovers_a_range_bias():
    from sensor_envs.lidar.calibrate import BIAS_RANGE_KNOTS, fit_bias_law

    rng = np.random.default_rng(1)
    r, a = rng.uniform(0.2, 3.9, (60, 100)), rng.uniform(0.0, 1.2, (60, 100))
    want = np.interp(r, (0.0, 2.0, 4.0), (0.0, 0.0, -0.15))
    dev = want + rng.normal(0, 0.005, r.shape)
    dev[:, :5] = 1.0  # outlying cells are left out
    law = fit_bias_law(r, a, dev)
    got = np.interp(r, law["bias_range_knots"], law["bias_range"]) + np.interp(
        a, law["bias_incidence_knots"], law["bias_incidence"]
    )
    shift = np.median(got - want)
    assert np.abs(got - want - shift)[:, 5:].max() < 0.01
    assert len(law["bias_range"]) == len(BIAS_RANGE_KNOTS)


# ------------------------------------------------------- spurious-prone near cells (issue 12: MAE p_spur)
def _near_law_cells(seed=0, p_=40, k=60, cut=0.6):
    """Cells whose bearings 0-19 are always spurious nearer than ``cut``, 20-39 never, 40-59 half the time."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.2, 3.0, (p_, k))
    share = np.r_[np.ones(20), np.zeros(20), np.full(20, 0.5)]
    prone = (r < cut) & (rng.random((p_, k)) < share[None])
    frac = np.where(prone, rng.uniform(0.8, 1.0, (p_, k)), 0.0)
    return r, frac, np.ones((p_, k), dtype=bool)


def test_fit_spur_near_law_recovers_the_cut_and_the_bearings():
    from sensor_envs.lidar.calibrate import SPUR_NEAR_CUTS, SPUR_NEAR_PRIORS, fit_spur_near_law

    r, frac, used = _near_law_cells()
    params, info = fit_spur_near_law(r, frac, used)
    assert params["spur_near_range"] == info["cut_m"] == 0.6  # the planted cut, among the candidates
    assert len(info["cv_mse"]) == len(SPUR_NEAR_CUTS) * len(SPUR_NEAR_PRIORS)
    rate = params["spur_prone"] * np.asarray(params["spur_bearing_weight"])
    assert rate[:20].min() > 0.85 and rate[20:40].max() < 0.15 and 0.3 < rate[40:].mean() < 0.7
    assert params["spur_range_knots"] == () and abs(np.mean(rate) - params["spur_prone"]) < 0.05
    # no spurious cell at all: a law that predicts none (weights 1, share 0), no division by zero
    params, _ = fit_spur_near_law(r, np.zeros_like(frac), used)
    assert params["spur_prone"] == 0 and set(params["spur_bearing_weight"]) == {1.0}


def test_near_cut_keeps_spurious_cells_near_and_rig_files_without_it_unchanged(tmp_path):
    quiet = {"pose_sd": (0.0, 0.0), "map_sd": 0.0}
    near = NeatoRig(spur_prone=0.5, spur_bearing_weight=(1.0,) * 360, spur_near_range=0.7, **quiet)
    r = np.array([0.3, 0.69, 0.71, 2.0, np.inf, np.nan])
    assert near.spur_range_factor(r).tolist() == [1, 1, 0, 0, 0, 0] and near.has_spur_range_law()
    log, truth = near.record(ROOM, np.random.default_rng(3), n_poses=8, repeats=2)
    from sensor_envs.lidar.lwlr import lidar_features

    rr, _ = lidar_features(truth["true_poses"], near.bearings, ROOM, near.max_range)
    prone = truth["p_spur"] > 0
    assert prone[rr < 0.7].mean() > 0.3 and not prone[~(rr < 0.7)].any()
    assert NeatoRig.from_file(near.to_file(tmp_path / "near.json")).spur_near_range == 0.7
    assert NeatoRig().spur_near_range == 0 and not NeatoRig().has_spur_range_law()
    assert NeatoRig.from_file(OLD_RIG).spur_near_range == 0  # files before the cut: no cut


@pytest.mark.parametrize("value", [-0.5, float("nan"), "near"])
def test_bad_near_cut_names_file_and_field(tmp_path, value):
    with pytest.raises(ModelFileError, match=r"rig\.json.*spur_near_range"):
        NeatoRig.from_file(_rig_json(tmp_path, spur_near_range=value))


def test_bearing_profile_rederives_the_near_law_from_the_given_poses():
    from sensor_envs.lidar.calibrate import bearing_profile

    truth = NeatoRig(
        spur_prone=0.3,
        spur_bearing_weight=tuple(np.r_[np.full(180, 3.0), np.zeros(180)]),
        spur_near_range=1.0,
        pose_sd=(0.0, 0.0),
        map_sd=0.0,
    )
    log, _ = truth.record(ROOM, np.random.default_rng(0), n_poses=40, repeats=10)
    start = dataclasses.replace(truth, spur_bearing_weight=(1.0,) * 360)
    got = bearing_profile(start, log)
    w = np.asarray(got.spur_bearing_weight)
    assert got.spur_prone == start.spur_prone and got.spur_near_range > 0  # the scale is the rig's own
    assert np.mean(w[:180]) > 5 * max(np.mean(w[180:]), 1e-3)


def test_cli_calibrate_spurious_only_keeps_the_other_parameters(tmp_path, capsys):
    truth = NeatoRig(
        spur_prone=0.4, spur_near_range=0.8, spur_bearing_weight=tuple(np.r_[np.full(180, 2.0), np.zeros(180)])
    )
    log, _ = truth.record(ROOM, np.random.default_rng(1), n_poses=12, repeats=6)
    real = save_log(log, tmp_path / "real.npz")
    start = NeatoRig(null_cell_corr=0.9, spur_range_knots=(0.25, 0.75), spur_range_weight=(2.0, 1.0))
    start_file = start.to_file(tmp_path / "start.json", {"note": "kept"})
    out = tmp_path / "rig.json"
    assert main(["calibrate", "lidar", str(real), "--out", str(out), "--spurious-only", str(start_file)]) == 0
    assert "re-derived" in capsys.readouterr().out
    got, card = NeatoRig.from_file(out), NeatoRig.card_of(out)
    changed = {k for k, v in got.params().items() if v != start.params()[k]}
    assert changed <= {"spur_near_range", "spur_prone", "spur_bearing_weight", "spur_range_knots", "spur_range_weight"}
    assert got.spur_near_range > 0 and got.spur_range_knots == () and card["note"] == "kept"
    refit = card["spurious_refit"]
    assert refit["from_rig"] == str(start_file) and refit["after"]["per_statistic"] == card["after"]["per_statistic"]
    # bad input: exit 2, one line naming the file, nothing written; an existing output is kept
    bad = _rig_json(tmp_path / "bad", spur_prone=2.0)  # bad/rig.json
    out2 = tmp_path / "rig2.json"
    assert main(["calibrate", "lidar", str(real), "--out", str(out2), "--spurious-only", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "spur_prone" in err and len(err.strip().splitlines()) == 1 and not out2.exists()
    assert main(["calibrate", "lidar", str(real), "--out", str(out2), "--spurious-only", str(tmp_path / "no")]) == 2
    assert not out2.exists()
    before = out.read_bytes()
    assert main(["calibrate", "lidar", str(real), "--out", str(out), "--spurious-only", str(start_file)]) == 2
    assert out.read_bytes() == before
