"""The occluded fraction as a radar state variable: derived from the boxes, fitted, validated, supplied by highway."""

import json

import gymnasium as gym
import numpy as np
import pytest
from test_highway import _check, _place  # the tests folder is on the path (pytest's rootdir-relative import)

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.cli.main import main
from sensor_envs.envs.highway.sensor import world_state
from sensor_envs.radar.features import occluded_column, state_matrix, with_derived_columns
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import RadarLog, write_log
from sensor_envs.radar.rig import record_rig_log

FAST = "sensor_envs/HighwayFast-v0"


def _log(rows: list[tuple]) -> RadarLog:
    """A log of (sequence, frame, target, ref_x, ref_y, meas_x) rows; boxes 4.5 x 2 m along x; -1 = clutter."""
    names = ("sequence", "frame", "t", "target", "ref_x", "ref_y", "ref_heading", "ref_length", "ref_width")
    cols: dict[str, list] = {k: [] for k in (*names, "meas_x", "meas_y")}
    for seq, frame, target, x, y, mx in rows:
        clutter = target < 0
        vals = (seq, frame, float(frame), target, x, y, 0.0, 4.5, 2.0)
        for k, v in zip(names, vals, strict=True):
            cols[k].append(np.nan if clutter and k.startswith("ref_") else v)
        cols["meas_x"].append(mx)
        cols["meas_y"].append(np.nan if np.isnan(mx) else y)
    return RadarLog({k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}, source="toy log")


def test_occluded_column_hides_the_box_behind_and_only_within_its_cycle():
    log = _log(
        [
            (0, 0, 0, 10.0, 0.0, 8.0),
            (0, 0, 1, 30.0, 0.0, np.nan),  # behind target 0, same cycle: hidden
            (0, 0, 2, 30.0, 15.0, 28.0),  # far to the side: free
            (0, 0, -1, 50.0, 0.0, 50.0),  # clutter
            (0, 1, 1, 30.0, 0.0, 28.0),  # next cycle, target 0 gone: free
            (1, 0, 1, 30.0, 0.0, 28.0),  # another sequence: free
        ]
    )
    occ = occluded_column(log)
    assert occ[[0, 2, 4, 5]].tolist() == [0.0, 0.0, 0.0, 0.0]
    assert occ[1] == 1.0 and np.isnan(occ[3])
    assert np.array_equal(with_derived_columns(log)["occluded"], occ, equal_nan=True)
    # a model state variable the log lacks is derived; one that cannot be is an error naming it
    assert state_matrix(log, ("occluded",), np.array([1]))[0, 0] == 1.0
    with pytest.raises(ValueError, match="'nosuch'"):
        state_matrix(log, ("nosuch",), np.array([1]))


@pytest.fixture(scope="module")
def occlusion_log() -> RadarLog:
    """The generic rig: detection probability times (1 - 0.9 x occluded fraction)."""
    return record_rig_log(20, 20, 10, np.random.default_rng(3))


def test_kde_with_the_occluded_state_learns_the_occlusion_loss(occlusion_log):
    kde = KDERadarModel(
        extra_state=("occluded",), relevance="paper", extra_variance=(0.04,), random_state=0, use_prev=False
    ).fit(occlusion_log)
    corner = np.tile([[30.0, 2.0, np.nan, np.nan]], (2, 1))
    p_miss = np.exp(kde.log_prob(np.full((2, 2), np.nan), corner, extra=np.array([[0.0], [1.0]])))
    assert p_miss[1] > p_miss[0] + 0.3, p_miss  # the rig loses 90 % of the fully hidden boxes
    with pytest.raises(ValueError, match="occluded"):
        kde.log_prob(np.zeros((1, 2)), corner[:1])  # the variable must be passed


def _fit_argv(log: RadarLog, tmp_path, state: str) -> tuple[list[str], object]:
    """``fit radar`` of ``log`` (written to tmp_path/rig.csv) with ``--extra-state state``; argv and the output."""
    log_path, out = tmp_path / "rig.csv", tmp_path / "kde.npz"
    write_log(log, log_path)
    return ["fit", "radar", str(log_path), "--out", str(out), "--relevance", "paper", "--extra-state", state], out


def test_fit_cli_extra_state_then_validate_and_highway(occlusion_log, tmp_path, capsys):
    argv, out = _fit_argv(occlusion_log, tmp_path, "occluded")
    log_path = tmp_path / "rig.csv"
    assert main(argv) == 0
    kde, gauss = KDERadarModel.load(out), GaussianRadar.load(tmp_path / "kde_gaussian.npz")
    assert kde.extra_state_ == ("occluded",) and tuple(gauss.extra_state) == ("occluded",)
    assert kde.extra_variance_[0] > 0  # chosen by CV
    capsys.readouterr()
    assert main(["validate", "radar", str(out), str(log_path), "--out", str(tmp_path / "val")]) == 0
    rep = json.loads((tmp_path / "val" / "report.json").read_text())
    assert np.isfinite(rep["model"]["nll_outcome"]) and np.isfinite(rep["baseline_gaussian"]["nll_outcome"])
    assert 0.0 <= rep["model"]["chi_square_at_example_state"]["p_value"] <= 1.0
    # the highway world supplies the occluded fraction: the env runs and passes the checker
    env = gym.make(FAST, radar="kde", radar_model=str(out), config={"vehicles_count": 10})
    _check(env)  # gymnasium's and SB3's checkers, any unexpected warning an error
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
        assert obs in env.observation_space


def test_fit_cli_unknown_extra_state_exit_2_one_line(occlusion_log, tmp_path, capsys):
    argv, out = _fit_argv(occlusion_log, tmp_path, "nosuch")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nosuch" in err and "rig.csv" in err, err
    assert not out.exists() and not (tmp_path / "kde_gaussian.npz").exists()


def test_highway_world_state_occluded_is_the_hidden_fraction():
    env = gym.make(FAST, radar="ideal", config={"vehicles_count": 10})
    env.reset(seed=0)
    base = _place(env, [(120.0, 4.0), (140.0, 4.0), (140.0, 8.0)])  # ego at (100, 4), the rest far away
    others = [v for v in base.road.vehicles if v is not base.vehicle]
    frame = env.get_wrapper_attr("sense")()
    truth = frame.truth
    idx = np.flatnonzero([o in others[:3] for o in truth.objects])
    occ = world_state(("occluded",), truth, idx, frame.sensor_pose, base.vehicle)[:, 0]
    order = [truth.objects.index(o) for o in others[:3]]
    by_car = dict(zip(idx.tolist(), occ.tolist(), strict=True))
    assert by_car[order[0]] == 0.0  # in front, free
    assert by_car[order[1]] == 1.0  # behind it in the same lane
    assert by_car[order[2]] < 0.5  # next lane: mostly seen
