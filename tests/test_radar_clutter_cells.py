"""The rig's joint (range x azimuth) clutter law: an empty lane ahead stays empty in the rig's clutter."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.inputs import InputError
from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.calibrate import (
    CLUTTER_CELL_AZIMUTH_EDGES,
    CLUTTER_CELL_RANGE_EDGES,
    clutter_cell_shares,
    fit_clutter,
    frames_from_log,
)
from sensor_envs.radar.log import REQUIRED_COLUMNS, RadarLog, write_log
from sensor_envs.radar.rig import RadarRig, RigConfig, load_rig, record_rig_log, save_rig

SHIPPED_RIG = Path(__file__).resolve().parents[1] / "models" / "radar_rig.json"


def _planted_log(seed: int, lane: float, near: float, frames: int = 300) -> RadarLog:
    """Frames with one target box each and clutter uniform in x in [0, 80] m, |y| <= 15 m, except the lane
    ``|y| <= lane`` nearer than ``near`` m, which is empty (a road ahead of the sensor)."""
    rng = np.random.default_rng(seed)
    rows = []
    for f in range(frames):
        rows.append([0, f, f, 0, 20.0, 0.0, 0.0, 4.5, 1.8, 20.0, 0.0])
        m = rng.poisson(30)
        x, y = rng.uniform(0.5, 80.0, 3 * m), rng.uniform(-15.0, 15.0, 3 * m)
        keep = ~((np.abs(y) <= lane) & (x < near))
        for xi, yi in zip(x[keep][:m], y[keep][:m], strict=True):
            rows.append([0, f, f, -1, *([np.nan] * 5), xi, yi])
    a = np.asarray(rows, dtype=np.float64)
    return RadarLog({c: a[:, j] for j, c in enumerate(REQUIRED_COLUMNS)}, source=f"planted{seed}")


def _lane_share(cfg: RigConfig, near: float, seed: int, cycles: int = 300) -> float:
    rig, rng = RadarRig(cfg), np.random.default_rng(seed)
    r, az = (np.concatenate(v) for v in zip(*(rig.sample_clutter_polar(rng) for _ in range(cycles)), strict=True))
    x, y = r * np.cos(az), r * np.sin(az)
    return float(np.mean((np.abs(y) <= 1.0) & (x > 0) & (x < near)))


@pytest.mark.parametrize("seed, lane, near", [(0, 2.0, 20.0), (1, 3.0, 30.0), (2, 1.5, 15.0)])
def test_joint_cells_keep_a_planted_empty_lane_that_independent_shares_fill(seed, lane, near):
    frames = frames_from_log(_planted_log(seed, lane, near))
    cfg = fit_clutter(RigConfig(), frames)
    assert cfg.clutter_cell_weights is not None
    joint = _lane_share(cfg, near, seed)
    independent = _lane_share(replace(cfg, clutter_cell_weights=None), near, seed)
    # the planted law has no clutter at |y| <= lane < near: the joint cells put a few per cent there at most
    # (cells straddle the lane edge), the product of the marginals several times as much
    assert joint < 0.35 * independent, (joint, independent)
    assert independent > 0.01
    # the marginals stay those of the data: the range shares over the cells' range bins
    want = clutter_cell_shares(frames.clutter_xy, CLUTTER_CELL_RANGE_EDGES, CLUTTER_CELL_AZIMUTH_EDGES)
    grid = want.reshape(len(CLUTTER_CELL_RANGE_EDGES) - 1, -1)
    assert np.allclose(cfg.clutter_range_weights, grid.sum(axis=1))
    assert cfg.clutter_rate == pytest.approx(frames.clutter_counts.mean())


@pytest.mark.parametrize("seed", range(3))
def test_a_rig_log_keeps_its_target_rows_when_the_clutter_law_becomes_joint(seed):
    """The joint law draws the same numbers in the same order as the independent one: only clutter moves."""
    frames = frames_from_log(_planted_log(seed, 2.0, 20.0, frames=40))
    joint = fit_clutter(load_rig(SHIPPED_RIG)[0], frames)
    independent = replace(joint, clutter_cell_weights=None)
    a = record_rig_log(4, 5, 3, np.random.default_rng(seed), independent)
    b = record_rig_log(4, 5, 3, np.random.default_rng(seed), joint)
    assert np.array_equal(a.is_clutter, b.is_clutter)
    tgt = ~a.is_clutter
    for c in a.columns:
        assert np.array_equal(a[c][tgt], b[c][tgt], equal_nan=True), c
    assert not np.array_equal(a["meas_x"][~tgt], b["meas_x"][~tgt])


def test_cell_shares_count_only_positions_inside_the_edges():
    xy = np.array([[10.0, 0.0], [10.0, 0.1], [200.0, 0.0], [-5.0, 0.0]])
    s = clutter_cell_shares(xy, (0.0, 50.0, 100.0), (-0.5, 0.0, 0.5))
    assert s.tolist() == [0.0, 1.0, 0.0, 0.0]  # (-5, 0) is at azimuth pi: outside; 200 m: outside
    assert clutter_cell_shares(np.zeros((0, 2)), (0.0, 1.0), (-1.0, 1.0)).tolist() == [0.0]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"clutter_cell_weights": (1.0, 2.0)}, "clutter_cell_weights: needs"),
        (
            {"clutter_range_edges": (0.0, 10.0), "clutter_range_weights": (1.0,), "clutter_azimuth_edges": (-1.0, 1.0),
             "clutter_azimuth_weights": (1.0,), "clutter_cell_weights": (1.0, 2.0)},
            "must have 1 values",
        ),
        (
            {"clutter_range_edges": (0.0, 10.0), "clutter_range_weights": (1.0,), "clutter_azimuth_edges": (-1.0, 1.0),
             "clutter_azimuth_weights": (1.0,), "clutter_cell_weights": (0.0,)},
            "must not all be 0",
        ),
    ],
)  # fmt: skip
def test_bad_cell_table_is_refused_naming_the_field(tmp_path, change, message):
    with pytest.raises(InputError, match=message):
        RigConfig(**change)
    path = tmp_path / "rig.json"
    save_rig(path, RigConfig(), {})
    data = json.loads(path.read_text())
    data["params"].update({k: list(v) for k, v in change.items()})
    path.write_text(json.dumps(data))
    with pytest.raises(ModelFileError, match="rig.json.*clutter_cell_weights"):
        load_rig(path)


def test_calibrate_clutter_only_refits_the_clutter_and_keeps_the_rest(tmp_path, capsys):
    real = tmp_path / "real.csv"
    write_log(_planted_log(3, 2.0, 20.0, frames=60), real)
    out = tmp_path / "rig.json"
    argv = ["calibrate", "radar", str(real), "--base", str(SHIPPED_RIG), "--clutter-only", "--out", str(out)]
    assert main(argv) == 0
    cfg, card = load_rig(out)
    base, base_card = load_rig(SHIPPED_RIG)
    clutter = ("clutter_rate", "clutter_dispersion", "clutter_range_edges", "clutter_range_weights")
    clutter += ("clutter_azimuth_edges", "clutter_azimuth_weights", "clutter_cell_weights")
    assert replace(cfg, **{k: getattr(base, k) for k in clutter}) == base  # every other law kept
    assert card["clutter"]["frames"] == 60 and card["clutter"]["base"] == "radar_rig.json"
    assert card["calibrated_against"] == base_card["calibrated_against"]
    assert "clutter law fitted on" in capsys.readouterr().out
    assert main(argv) == 2  # an existing output is refused without --force


@pytest.mark.parametrize(
    "extra, message", [([], "needs --base"), (["--base", str(SHIPPED_RIG), "--scene"], "--clutter-only")]
)
def test_calibrate_clutter_only_bad_use_exit_2_one_line(tmp_path, capsys, extra, message):
    real = tmp_path / "real.csv"
    write_log(_planted_log(4, 2.0, 20.0, frames=5), real)
    argv = ["calibrate", "radar", str(real), "--clutter-only", *extra, "--out", str(tmp_path / "r.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "r.json").exists()


@pytest.mark.slow
def test_shipped_rig_clutter_in_the_lane_ahead_near_the_real_astyx_clutter(astyx_log):
    """Real Astyx clutter inside |y| <= 1.75 m nearer than 10 m: ~0.02 per frame; the rig's independent range
    and azimuth shares gave ~1.2 (the KDE's false triggers); the joint cells (5 m x 2.5-5 deg, coarser than
    the lane edge) give ~0.2: a guard against the independent law's level, not a match of the real 0.02."""
    log = astyx_log
    cl = log.is_clutter
    x, y = log["meas_x"][cl], log["meas_y"][cl]
    n_frames = np.unique(log["frame"]).size
    real = float(np.sum((np.abs(y) <= 1.75) & (x > 0) & (x < 10.0))) / n_frames
    cfg = load_rig(SHIPPED_RIG)[0]
    rig, rng = RadarRig(cfg), np.random.default_rng(0)
    polar = [rig.sample_clutter_polar(rng) for _ in range(400)]
    r, az = np.concatenate([p[0] for p in polar]), np.concatenate([p[1] for p in polar])
    sim = float(np.sum((np.abs(r * np.sin(az)) <= 1.75) & (r * np.cos(az) < 10.0))) / 400
    assert real < 0.1
    assert sim < 0.4, (sim, real)  # independent law: ~1.2


@pytest.mark.slow
def test_a_kde_fitted_on_the_joint_rigs_log_differs_only_in_its_clutter(tmp_path):
    """Why the shipped radar files could change their clutter alone: the same target rows give the same fit."""
    from sensor_envs.modelio import read_header_and_arrays
    from sensor_envs.radar.kde import KDERadarModel

    joint = load_rig(SHIPPED_RIG)[0]
    arrays = []
    for cfg in (replace(joint, clutter_cell_weights=None), joint):
        log = record_rig_log(20, 20, 6, np.random.default_rng(3), cfg, in_view_only=True)
        path = KDERadarModel(random_state=0, output_frame="polar", azimuth_bias="fit").fit(log).save(tmp_path / "k.npz")
        arrays.append(read_header_and_arrays(path)[1])
    a, b = arrays
    assert [k for k in a if not np.array_equal(a[k], b[k], equal_nan=True)] == ["clutter_xy"]
