"""The rig's scene law: the boxes a rig log records follow the real reference boxes' statistics."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.calibrate import frames_from_log, snapshot_log
from sensor_envs.radar.log import REF_COLUMNS, RadarLog, read_log, write_log
from sensor_envs.radar.rig import (
    SCENE_TABLES,
    RigConfig,
    generate_scenario,
    load_rig,
    record_rig_log,
    save_rig,
    scene_boxes,
)
from sensor_envs.radar.scene_law import (
    SCENE_HEADING_EDGES,
    SCENE_X_EDGES,
    SCENE_Y_EDGES,
    fit_scene_law,
    heading_mod_pi,
    scene_stats,
)

SHIPPED_RIG = Path(__file__).resolve().parents[1] / "models" / "radar_rig.json"

LAW: dict[str, Any] = {  # a known scene: near boxes on the right and across, far boxes along the road on the left
    "scene_x_edges": (0.0, 30.0, 90.0),
    "scene_x_weights": (0.4, 0.6),
    "scene_y_edges": (-20.0, -5.0, 0.0, 5.0, 20.0),
    "scene_y_weights": (0.6, 0.3, 0.1, 0.0, 0.0, 0.1, 0.2, 0.7),
    "scene_heading_edges": (-np.pi / 2, -1.2, -0.1, 0.1, 1.2, np.pi / 2),
    "scene_heading_weights": (0.4, 0.0, 0.2, 0.0, 0.4, 0.0, 0.1, 0.8, 0.1, 0.0),
    "scene_length_range": (4.0, 4.5),
    "scene_width_range": (1.7, 1.9),
    "scene_speed_std": 0.0,
}


def _without_scene(cfg: RigConfig) -> RigConfig:
    """``cfg`` with its scene law removed: the generic lane traffic (every rig file before the scene law)."""
    return replace(cfg, **dict.fromkeys(SCENE_TABLES))


def _shares_in(values, edges):
    return np.histogram(values, bins=np.asarray(edges))[0] / len(values)


def test_rig_without_a_scene_law_records_the_generic_traffic_as_before():
    """Every older rig file (no scene fields) draws the same scenario, number for number, as before the law."""
    shipped = load_rig(SHIPPED_RIG)[0]
    assert shipped.scene_x_edges is not None  # since 2026-11-27 the shipped rig records the real boxes' scene
    a = generate_scenario(8, 10, 1.0, np.random.default_rng(3))
    b = generate_scenario(8, 10, 1.0, np.random.default_rng(3), _without_scene(shipped))
    assert np.array_equal(a.boxes, b.boxes) and np.array_equal(a.velocity, b.velocity)
    expected_first = [5.1415579, 3.5, -0.0073068]  # the generic law's first box (stream of every older file)
    assert np.allclose(a.boxes[0, 0, :3], expected_first, atol=1e-5), a.boxes[0, 0, :3]


def test_scene_boxes_follow_the_law_per_x_bin():
    cfg = RigConfig(**LAW)
    boxes = scene_boxes(cfg, 20000, np.random.default_rng(0))
    near = boxes[:, 0] < 30
    assert near.mean() == pytest.approx(0.4, abs=0.015)
    for sel, w in ((near, LAW["scene_y_weights"][:4]), (~near, LAW["scene_y_weights"][4:])):
        assert np.allclose(_shares_in(boxes[sel, 1], LAW["scene_y_edges"]), w, atol=0.02)
    h = heading_mod_pi(boxes[:, 2])
    assert np.allclose(_shares_in(h[~near], LAW["scene_heading_edges"]), LAW["scene_heading_weights"][5:], atol=0.02)
    assert boxes[:, 3].min() >= 4.0 and boxes[:, 3].max() <= 4.5 and boxes[:, 4].max() <= 1.9


def test_fit_scene_law_recovers_a_known_scene():
    boxes = scene_boxes(RigConfig(**LAW), 5000, np.random.default_rng(1))
    fit = fit_scene_law(boxes, x_edges=LAW["scene_x_edges"], y_edges=LAW["scene_y_edges"],
                        heading_edges=LAW["scene_heading_edges"], prior=0.5, speed_std=0.0)  # fmt: skip
    for k in ("scene_x_weights", "scene_y_weights", "scene_heading_weights"):
        assert np.allclose(fit[k], LAW[k], atol=0.03), (k, fit[k])
    assert fit["scene_length_range"][0] == pytest.approx(4.025, abs=0.02)
    assert fit["scene_width_range"][1] == pytest.approx(1.89, abs=0.01)
    cfg = RigConfig(**fit)  # the fitted law is a valid rig
    assert cfg.scene_x_edges == LAW["scene_x_edges"]


def test_recorded_log_holds_the_law_s_boxes():
    """A rig log recorded with the law (static targets) holds boxes whose statistics are the law's."""
    cfg = replace(RigConfig(**LAW), clutter_rate=0.0)
    log = record_rig_log(40, 5, 20, np.random.default_rng(2), cfg)
    tgt = log["target"] >= 0
    y, x = log["ref_y"][tgt], log["ref_x"][tgt]
    far = x >= 30
    assert np.allclose(_shares_in(y[far], LAW["scene_y_edges"]), LAW["scene_y_weights"][4:], atol=0.05)
    # static (speed std 0): each target keeps its box over the sequence
    first = (log["frame"] == 0) & tgt
    last = (log["frame"] == 4) & tgt
    assert np.array_equal(log["ref_x"][first], log["ref_x"][last])


def test_moving_targets_are_at_their_drawn_place_at_an_anchor_cycle():
    cfg = replace(RigConfig(**LAW), scene_speed_std=2.0)
    sc = generate_scenario(200, 30, 0.5, np.random.default_rng(4), cfg)
    again = scene_boxes(cfg, 200, np.random.default_rng(4))  # the same first draws: the places
    dist = np.hypot(*(sc.boxes[:, :, :2] - again[None, :, :2]).transpose(2, 0, 1))
    assert np.all(dist.min(axis=0) < 1e-9)  # every target passes its drawn place at one cycle
    assert np.all(np.abs(sc.boxes[:, :, 2] - again[None, :, 2]) < 1e-12)
    assert np.all(np.hypot(*sc.velocity.T) > 0)


@pytest.mark.parametrize(
    "change, field",
    [
        ({"scene_y_weights": None}, "scene_y_weights"),
        ({"scene_y_weights": LAW["scene_y_weights"][:-1]}, "scene_y_weights"),
        ({"scene_heading_weights": (0.0,) * 10}, "scene_heading_weights"),
        ({"scene_x_weights": (0.5, -0.5)}, "scene_x_weights"),
        ({"scene_length_range": (5.0, 4.0)}, "scene_length_range"),
        ({"scene_width_range": (0.0, 2.0)}, "scene_width_range"),
        ({"scene_heading_edges": (-2.0, 0.0, 2.0)}, "scene_heading_edges"),
        ({"scene_speed_std": float("nan")}, "scene_speed_std"),
    ],
)  # fmt: skip
def test_bad_scene_law_fails_at_load_naming_file_and_field(tmp_path, change, field):
    path = tmp_path / "rig.json"
    save_rig(path, RigConfig(**LAW), {})
    data = json.loads(path.read_text())
    data["params"].update({k: (list(v) if isinstance(v, tuple) else v) for k, v in change.items()})
    path.write_text(json.dumps(data))
    with pytest.raises(ModelFileError, match=f"rig.json.*{field}"):
        load_rig(path)


ALIGNED: dict[str, Any] = {**LAW, "scene_x_edges": (0.0, 30.0, 75.0), "scene_y_edges": (-18.0, -7.0, 0.0, 7.0, 18.0)}
"""LAW on bins that are unions of the fit's bins (SCENE_X_EDGES, SCENE_Y_EDGES): the fit can resolve it."""


def _real_csv(tmp_path: Path) -> Path:
    """A "real" single-frame log whose boxes follow ALIGNED, observed by the shipped rig."""
    rng = np.random.default_rng(5)
    boxes = scene_boxes(RigConfig(**ALIGNED), 3000, rng)
    n = boxes.shape[0]
    frame = np.arange(n) % 500
    cols = {k: boxes[:, j] for j, k in enumerate(REF_COLUMNS)}
    nan = np.full(n, np.nan)
    ids = {"sequence": np.zeros(n), "frame": frame.astype(float), "t": frame.astype(float)}
    cols.update(ids, target=np.arange(n, dtype=float), meas_x=nan, meas_y=nan)
    frames = frames_from_log(RadarLog(cols, source="boxes"))
    path = tmp_path / "real.csv"
    write_log(snapshot_log(load_rig(SHIPPED_RIG)[0], frames, rng), path)
    return path


@pytest.mark.slow
def test_calibrate_cli_scene_only_fits_the_scene_and_keeps_the_base_rig(tmp_path, capsys):
    real = _real_csv(tmp_path)
    out = tmp_path / "rig.json"
    argv = ["calibrate", "radar", str(real), "--base", str(SHIPPED_RIG), "--scene-only", "--out", str(out)]
    assert main(argv) == 0
    cfg, card = load_rig(out)
    base, base_card = load_rig(SHIPPED_RIG)
    assert replace(cfg, **{k: getattr(base, k) for k in LAW}) == base  # every sensor law kept
    assert card["calibrated_against"] == base_card["calibrated_against"] and card["scene"]["base"] == "radar_rig.json"
    fit = np.asarray(cfg.scene_x_weights)
    assert fit[:2].sum() == pytest.approx(0.4, abs=0.06), fit  # LAW: 40 % at x < 30 m, SCENE_X_EDGES' first 2 bins
    assert cfg.scene_x_edges == SCENE_X_EDGES and cfg.scene_y_edges == SCENE_Y_EDGES
    assert cfg.scene_heading_edges == pytest.approx(SCENE_HEADING_EDGES)
    real_rows = card["scene"]["real_boxes"]
    assert sum(r["boxes"] for r in real_rows) == 3000
    rec = card["scene"]["recorded_boxes"]
    assert rec[3]["boxes"] > 0 and rec[1]["boxes"] > 0
    # a log recorded from the calibrated rig holds boxes whose |y| spread follows the real ones per x bin
    log_path = tmp_path / "log.csv"
    record = ["record", "radar", "--rig", str(out), "--out", str(log_path), "--sequences", "400", "--cycles", "2"]
    assert main(record) == 0
    log = read_log(log_path)
    tgt = log["target"] >= 0
    rec_boxes = np.stack([log[c][tgt] for c in REF_COLUMNS], axis=1)
    for got, want in zip(scene_stats(rec_boxes), real_rows, strict=True):
        if want["boxes"] >= 100 and got["boxes"] >= 100:
            assert got["abs_y_q50"] == pytest.approx(want["abs_y_q50"], abs=1.0), (got, want)
            assert got["along_share"] == pytest.approx(want["along_share"], abs=0.08), (got, want)
    assert "scene law fitted on 3000 reference boxes" in capsys.readouterr().out


@pytest.mark.parametrize("extra, message", [([], "--scene-only: needs --base"), (["--azimuth-bias"], "--scene-only")])
def test_calibrate_cli_scene_only_bad_use_exit_2_one_line(tmp_path, capsys, extra, message):
    real = _real_csv(tmp_path)
    base = [] if not extra else ["--base", str(SHIPPED_RIG)]
    argv = ["calibrate", "radar", str(real), "--scene-only", *base, *extra, "--out", str(tmp_path / "r.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "r.json").exists()


def test_scene_law_fitted_on_astyx_spreads_the_recorded_boxes_like_the_real_ones(astyx_log):
    """On Astyx the generic lane traffic is far narrower than the real boxes at 30-75 m (|y| 75th percentile
    about 7.3 m vs 11-12 m); the rig with the fitted law records boxes close to the real quartiles."""
    from sensor_envs.radar.calibrate import calibrate_scene
    from sensor_envs.radar.scene_law import recorded_boxes

    frames = frames_from_log(astyx_log, source="astyx_hires2019")  # as load_real(the folder) reads it
    shipped = load_rig(SHIPPED_RIG)[0]
    real = scene_stats(frames.boxes)
    generic = scene_stats(recorded_boxes(_without_scene(shipped), np.random.default_rng(0)))
    cfg, card = calibrate_scene(frames, _without_scene(shipped))
    assert card["real_boxes"] == real
    assert cfg.scene_x_weights == shipped.scene_x_weights  # the shipped rig's law is this fit
    for want, old, new in zip(real, generic, card["recorded_boxes"], strict=True):
        if 30 <= want["x_low"] < 75:
            assert want["abs_y_q75"] - old["abs_y_q75"] > 3.0, (want, old)
        assert new["abs_y_q75"] == pytest.approx(want["abs_y_q75"], abs=2.5), (new, want)
        assert new["abs_y_q50"] == pytest.approx(want["abs_y_q50"], abs=1.0), (new, want)
        assert new["along_share"] == pytest.approx(want["along_share"], abs=0.1), (new, want)


@pytest.mark.slow
def test_calibrate_rig_with_scene_fits_the_laws_and_the_scene(tmp_path):
    """``calibrate radar --scene``: the same sensor laws as without it, plus the scene law of the real boxes."""
    from sensor_envs.radar.calibrate import calibrate_rig, load_real

    frames = load_real(_real_csv(tmp_path))
    cfg, card = calibrate_rig(frames, RigConfig(), seed=0, replicates=1, max_evals=40, scene=True)
    plain, plain_card = calibrate_rig(frames, RigConfig(), seed=0, replicates=1, max_evals=40)
    assert plain.scene_x_edges is None and "scene" not in plain_card
    assert replace(cfg, **{k: getattr(plain, k) for k in LAW}) == plain  # the sensor laws are the same
    assert cfg.scene_x_edges == SCENE_X_EDGES and card["scene"]["real_boxes"] == scene_stats(frames.boxes)
    assert np.asarray(cfg.scene_x_weights)[:2].sum() == pytest.approx(0.4, abs=0.06)
