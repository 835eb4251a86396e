"""Radar rig files, ``calibrate radar`` (recovery of known rig parameters) and ``record radar --rig``."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.geometry import closest_corner, rectangle_corners
from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.calibrate import (
    DET_RANGE_EDGES,
    _sim_setup,
    calibrate_rig,
    discrepancy,
    fit_azimuth_bias,
    frames_from_log,
    real_statistics,
    rig_statistics,
    snapshot_log,
)
from sensor_envs.radar.log import REF_COLUMNS, RadarLog, clutter_counts, read_log, write_log
from sensor_envs.radar.rig import (
    RadarRig,
    RigConfig,
    SnapshotDraws,
    _reflection_geometry,
    _reflection_point,
    generate_scenario,
    load_rig,
    save_rig,
)

SHIPPED_RIG = Path(__file__).resolve().parents[1] / "models" / "radar_rig.json"

TRUE = RigConfig(
    max_range=150.0,
    detect_range_knots=(0.0, 30.0, 60.0, 120.0),
    detect_range_table=(0.6, 0.8, 0.9, 0.5),
    detect_azimuth_knots=(0.0, 0.5, 1.0, 1.6),
    detect_azimuth_table=(1.0, 0.9, 0.6, 0.2),
    occlusion_loss=0.5,
    offset_range_knots=(0.0, 50.0, 110.0),
    sigma_range_table=(0.5, 0.5, 0.5),
    sigma_cross_table=(0.3, 0.3, 0.3),
    corner_share=0.7,
    reflection_spread=0.3,
    clutter_rate=12.0,
    clutter_dispersion=0.1,
    clutter_range_edges=(0.0, 20.0, 60.0),
    clutter_range_weights=(0.3, 0.7),
    clutter_azimuth_edges=(-1.0, 0.0, 1.0),
    clutter_azimuth_weights=(0.5, 0.5),
)


def synthetic_frames(config: RigConfig, n_frames: int = 150, seed: int = 0):
    """Single frames (static boxes of rig scenarios) observed by a rig with ``config``."""
    rng = np.random.default_rng(seed)
    boxes = generate_scenario(8 * n_frames, 1, 1.0, rng).boxes[0]
    keep = np.hypot(boxes[:, 0], boxes[:, 1]) < 110
    boxes = boxes[keep]
    frame = np.arange(boxes.shape[0]) % n_frames
    placeholder = np.full((boxes.shape[0], 2), np.nan)
    cols = {k: boxes[:, j] for j, k in enumerate(REF_COLUMNS)}
    cols.update(
        sequence=np.zeros(boxes.shape[0]),
        frame=frame.astype(float),
        t=frame.astype(float),
        target=np.arange(boxes.shape[0], dtype=float),
        meas_x=placeholder[:, 0],
        meas_y=placeholder[:, 1],
    )
    base = frames_from_log(RadarLog(cols, source="boxes"))
    return frames_from_log(snapshot_log(config, base, rng), source="synthetic")


def test_rig_file_round_trip_and_shipped_rig(tmp_path):
    path = save_rig(tmp_path / "rig.json", TRUE, {"against": "test"})
    cfg, card = load_rig(path)
    assert cfg == TRUE and card == {"against": "test"}
    empty = tmp_path / "generic.json"
    empty.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": {}}))
    assert load_rig(empty)[0] == RigConfig()  # missing names take the generic rig's values
    shipped, card = load_rig(SHIPPED_RIG)
    assert shipped.detect_range_table is not None
    assert card["calibrated_against"]["frames"] == 400
    assert card["discrepancy_after"]["total"] < card["discrepancy_before"]["total"]


SIGNED = {
    "detect_azimuth_knots": [-1.0, 0.0, 1.0],
    "detect_azimuth_table": [0.5, 1.0, 0.8],
    "detect_azimuth_signed": True,
}


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"occlusion_loss": 1.5}, "params.occlusion_loss"),
        ({"detect_range_knots": [0, 50, 20], "detect_range_table": [0.5, 0.5, 0.5]}, "params.detect_range_knots"),
        ({"detect_range_knots": [0, 50], "detect_range_table": [0.5, 0.5, 0.5]}, "params.detect_range_table"),
        ({"sigma_range_table": [0.1, 0.2]}, "params.sigma_range_table"),
        ({"clutter_rate": -1}, "params.clutter_rate"),
        ({"reflection_spread": 0.7}, "params.reflection_spread"),
        ({"colour": "red"}, "params.colour"),
        # the azimuth table: |azimuth| knots unless signed; signed knots in [-pi, pi], increasing, finite
        (
            {"detect_azimuth_knots": [-1.0, 0.0, 1.0], "detect_azimuth_table": [0.5, 1.0, 0.5]},
            "params.detect_azimuth_knots",
        ),
        ({**SIGNED, "detect_azimuth_table": [0.5, 1.2, 0.5]}, "params.detect_azimuth_table"),
        ({**SIGNED, "detect_azimuth_table": [0.5, float("nan"), 0.5]}, "params.detect_azimuth_table"),
        ({**SIGNED, "detect_azimuth_knots": [-1.0, 1.0, 0.0]}, "params.detect_azimuth_knots"),
        ({**SIGNED, "detect_azimuth_knots": [-4.0, 0.0, 1.0]}, "params.detect_azimuth_knots"),
        ({**SIGNED, "detect_azimuth_knots": [-1.0, float("inf"), 1.0]}, "params.detect_azimuth_knots"),
        ({**SIGNED, "detect_azimuth_table": [0.5, 1.0]}, "params.detect_azimuth_table"),
        ({**SIGNED, "detect_azimuth_signed": "yes"}, "params.detect_azimuth_signed"),
        ({**SIGNED, "detect_azimuth_signed": 1}, "params.detect_azimuth_signed"),
    ],
)
def test_bad_rig_values_fail_at_load_naming_file_and_field(tmp_path, params, field):
    path = tmp_path / "bad_rig.json"
    path.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": params}))
    with pytest.raises(ModelFileError, match=f"bad_rig.json: field '{field}'"):
        load_rig(path)


def test_snapshot_follows_the_detection_probability():
    frames = synthetic_frames(TRUE, n_frames=100)
    st = rig_statistics(TRUE, frames, replicates=8, seed=3)
    ex = rig_statistics(TRUE, frames, replicates=8, seed=3, expected=True)
    ok = np.isfinite(ex["det_range"])
    assert np.all(np.abs(st["det_range"][ok] - ex["det_range"][ok]) < 0.03)


@pytest.mark.slow
def test_calibrate_recovers_known_parameters():
    frames = synthetic_frames(TRUE, n_frames=150)
    generic = RigConfig()
    cfg, card = calibrate_rig(frames, generic, seed=1, replicates=2, max_evals=400)
    real = real_statistics(frames)
    after = discrepancy(rig_statistics(cfg, frames, 4, seed=5), real)
    assert after["total"] < 0.2 * card["discrepancy_before"]["total"]
    # detection probability along the boresight at the middle of each range bin
    mids = 0.5 * (np.array(DET_RANGE_EDGES[:-1]) + np.array(DET_RANGE_EDGES[1:]))[:4]
    zeros = np.zeros(mids.size)
    p_true = RadarRig(TRUE).detection_probability(mids, zeros, zeros)
    p_fit = RadarRig(cfg).detection_probability(mids, zeros, zeros)
    assert np.max(np.abs(p_fit - p_true)) < 0.1, (p_fit, p_true)
    assert abs(cfg.occlusion_loss - TRUE.occlusion_loss) < 0.3
    assert abs(cfg.corner_share - TRUE.corner_share) < 0.2
    # offsets: spread and tail trade off (sigma vs outlier share), so the law is checked, not each number
    assert after["offset"] < 0.2 * card["discrepancy_before"]["offset"]
    assert abs(cfg.clutter_rate - 12.0) < 1.0
    # true law: 30 % uniform in 0-20 m, so 22.5 % below 15 m (the calibrated bins are the joint cells' ranges)
    assert cfg.clutter_range_weights is not None and cfg.clutter_range_edges is not None
    upper = np.asarray(cfg.clutter_range_edges[1:])
    assert 15.0 in upper
    assert abs(float(np.sum(np.asarray(cfg.clutter_range_weights)[upper <= 15.0])) - 0.225) < 0.05


def test_reflection_center_moves_the_point_towards_the_faces_near_end():
    rng = np.random.default_rng(4)
    boxes = generate_scenario(200, 1, 1.0, rng).boxes[0]
    frac = rng.uniform(-0.2, 0.2, boxes.shape[0])
    _, mid, edge = _reflection_geometry(boxes)
    # 0.5 is the midpoint law (the rig files without the field keep their outputs exactly)
    np.testing.assert_array_equal(_reflection_point(boxes, frac, None, 0.5), mid + frac[:, None] * edge)
    ends = np.stack([mid - 0.5 * edge, mid + 0.5 * edge], axis=1)  # (n, 2 ends, 2)
    near = ends[np.arange(boxes.shape[0]), np.argmin(np.linalg.norm(ends, axis=-1), axis=1)]
    at_end = _reflection_point(boxes, np.zeros(boxes.shape[0]), None, 0.0)
    np.testing.assert_allclose(at_end, near, atol=1e-9)
    quarter = _reflection_point(boxes, np.zeros(boxes.shape[0]), None, 0.25)
    np.testing.assert_allclose(np.linalg.norm(quarter - near, axis=1), 0.25 * np.linalg.norm(edge, axis=1))


def test_offset_statistic_is_outward_so_mirrored_scenes_agree():
    """A mirrored scene (y -> -y) has the same offset quantiles: the cross-range is counted away from the boresight."""
    frames = synthetic_frames(replace(TRUE, corner_share=0.0), n_frames=80)  # reflections around face midpoints
    flip = np.array([1.0, -1.0])
    mirrored = replace(
        frames,
        boxes=frames.boxes * np.array([1.0, -1.0, -1.0, 1.0, 1.0]),
        corner=frames.corner * flip,
        meas=frames.meas * flip,
        clutter_xy=frames.clutter_xy * flip,
    )
    a, b = real_statistics(frames), real_statistics(mirrored)
    ok = np.isfinite(a["offset"])
    np.testing.assert_allclose(a["offset"][ok], b["offset"][ok], atol=1e-9)
    # the face's midpoint lies outward of the closest corner on either side: a clearly positive median
    # (a signed cross-range would pool left and right to about zero)
    assert np.all(a["offset"][:4, 3, 1] > 0.3), a["offset"][:, 3, 1]


@pytest.mark.slow
def test_calibrate_recovers_the_reflection_center():
    true = replace(TRUE, corner_share=0.0, reflection_center=0.15, reflection_spread=0.1)
    frames = synthetic_frames(true, n_frames=150)
    cfg, card = calibrate_rig(frames, RigConfig(), seed=2, replicates=2, max_evals=400)
    # a share of corner reflections and a centre further out trade off (the near end is the closest corner
    # for most boxes), so the identifiable quantity is checked: the mean fraction from the near end
    mean_fraction = (1 - cfg.corner_share) * cfg.reflection_center
    assert abs(mean_fraction - 0.15) < 0.05, (cfg.corner_share, cfg.reflection_center)
    assert card["discrepancy_after"]["offset"] < 0.2 * card["discrepancy_before"]["offset"]


LOPSIDED = replace(
    TRUE,
    detect_azimuth_knots=tuple(np.deg2rad([-90.0, -45.0, 0.0, 45.0, 90.0]).tolist()),
    detect_azimuth_table=(0.2, 0.3, 1.0, 1.0, 0.9),
    detect_azimuth_signed=True,
)
"""A rig that misses targets on its right (azimuth < 0) far more often than on its left."""


def test_calibrate_fits_a_signed_azimuth_table_to_a_lopsided_rig():
    frames = synthetic_frames(LOPSIDED, n_frames=150)
    real = real_statistics(frames)
    assert real["det_azimuth"][1] < real["det_azimuth"][5] - 0.2, real["n_azimuth"]  # -40..-20 vs 20..40 deg
    cfg, card = calibrate_rig(frames, RigConfig(), seed=1, replicates=2, max_evals=100, signed_azimuth=True)
    assert cfg.detect_azimuth_signed and card["signed_azimuth"] is True
    az = np.deg2rad([-30.0, 30.0])
    p_true = RadarRig(LOPSIDED).detection_probability(np.full(2, 30.0), az, np.zeros(2))
    p_fit = RadarRig(cfg).detection_probability(np.full(2, 30.0), az, np.zeros(2))
    assert p_fit[1] - p_fit[0] > 0.2 and np.max(np.abs(p_fit - p_true)) < 0.12, (p_fit, p_true)
    sim = rig_statistics(cfg, frames, 4, seed=5, expected=True)
    assert np.all(np.abs(sim["det_azimuth"] - real["det_azimuth"])[1:6] < 0.05), (sim["det_azimuth"], real)


def test_calibrate_cli_signed_azimuth_flag_fits_the_signed_table(tmp_path):
    real = _synthetic_csv(tmp_path)
    rig = tmp_path / "rig.json"
    assert main(["calibrate", "radar", str(real), "--out", str(rig), "--max-evals", "20", "--signed-azimuth"]) == 0
    cfg, card = load_rig(rig)
    assert cfg.detect_azimuth_signed and card["signed_azimuth"] is True
    knots = np.asarray(cfg.detect_azimuth_knots)
    assert knots.min() < -1.5 and knots.max() > 1.5  # -90 .. 90 deg, left and right apart
    assert cfg.detect_azimuth_table is not None and cfg.detect_azimuth_table[int(np.argmin(np.abs(knots)))] == 1.0


def _synthetic_csv(tmp_path: Path) -> Path:
    frames = synthetic_frames(replace(TRUE, clutter_rate=3.0), n_frames=60, seed=2)
    log = snapshot_log(TRUE, frames, np.random.default_rng(0))
    path = tmp_path / "real.csv"
    write_log(log, path)
    return path


def test_calibrate_cli_writes_a_rig_that_record_uses(tmp_path, capsys):
    real = _synthetic_csv(tmp_path)
    rig = tmp_path / "rig.json"
    assert main(["calibrate", "radar", str(real), "--out", str(rig), "--max-evals", "200"]) == 0
    cfg, card = load_rig(rig)
    assert card["calibrated_against"]["data"] == "real.csv" and card["calibrated_against"]["frames"] == 60
    # default: the symmetric |azimuth| table (the signed one generalises worse across real frames)
    assert not cfg.detect_azimuth_signed and card["signed_azimuth"] is False
    assert cfg.detect_azimuth_knots is not None and min(cfg.detect_azimuth_knots) == 0.0
    assert main(["calibrate", "radar", str(real), "--out", str(rig), "--max-evals", "200"]) == 2  # exists
    assert "--force" in capsys.readouterr().err
    out = tmp_path / "log.csv"
    args = ["record", "radar", "--rig", str(rig), "--out", str(out), "--sequences", "3", "--cycles", "10"]
    assert main(args) == 0
    counts, _ = clutter_counts(read_log(out))
    assert abs(counts.mean() - cfg.clutter_rate) < 5 * np.sqrt(cfg.clutter_rate * (1 + 12) / counts.size) + 1
    again = tmp_path / "again.csv"
    assert main([*args[:5], str(again), *args[6:]]) == 0
    assert out.read_bytes() == again.read_bytes()  # same seed, same log


def test_calibrate_cli_base_rig_is_the_starting_point(tmp_path):
    """``--base``: the parameters single frames cannot show come from the base rig, the card names it."""
    real = _synthetic_csv(tmp_path)
    base = save_rig(tmp_path / "base.json", replace(TRUE, tracker_tau=7.0, latency=0.2), {})
    rig = tmp_path / "rig.json"
    assert main(["calibrate", "radar", str(real), "--out", str(rig), "--max-evals", "50", "--base", str(base)]) == 0
    cfg, card = load_rig(rig)
    assert card["base"] == "base.json" and cfg.tracker_tau == 7.0 and cfg.latency == 0.2
    generic = tmp_path / "generic.json"
    assert main(["calibrate", "radar", str(real), "--out", str(generic), "--max-evals", "50"]) == 0
    assert (
        load_rig(generic)[1]["base"].startswith("generic")
        and load_rig(generic)[0].tracker_tau == RigConfig().tracker_tau
    )


@pytest.mark.parametrize(
    "case", ["missing", "no_targets", "bad_rig", "bad_signed_rig", "rig_and_astyx", "bad_suffix", "bad_base"]
)
def test_cli_bad_input_exit_2_one_line(tmp_path, capsys, case):
    if case == "missing":
        argv, name = ["calibrate", "radar", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "r.json")], "nope.csv"
    elif case == "no_targets":
        path = tmp_path / "clutter_only.csv"
        path.write_text(
            "sequence,frame,t,target,ref_x,ref_y,ref_heading,ref_length,ref_width,meas_x,meas_y\n0,0,0,-1,,,,,,5,1\n"
        )
        argv, name = ["calibrate", "radar", str(path), "--out", str(tmp_path / "r.json")], "clutter_only.csv"
    elif case == "bad_rig":
        path = tmp_path / "bad_rig.json"
        path.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": {"corner_share": 2}}))
        argv, name = ["record", "radar", "--rig", str(path), "--out", str(tmp_path / "l.csv")], "corner_share"
    elif case == "bad_signed_rig":
        path = tmp_path / "bad_rig.json"
        params = {**SIGNED, "detect_azimuth_table": [0.5, 1.0, 1.5]}
        path.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": params}))
        argv = ["record", "radar", "--rig", str(path), "--out", str(tmp_path / "l.csv")]
        name = "bad_rig.json: field 'params.detect_azimuth_table'"
    elif case == "rig_and_astyx":
        argv = [
            "record",
            "radar",
            "--rig",
            str(SHIPPED_RIG),
            "--astyx",
            str(tmp_path),
            "--out",
            str(tmp_path / "l.csv"),
        ]
        name = "--rig"
    elif case == "bad_base":
        path = tmp_path / "bad_base.json"
        path.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": {"reflection_center": -0.1}}))
        argv = [
            "calibrate",
            "radar",
            str(_synthetic_csv(tmp_path)),
            "--out",
            str(tmp_path / "r.json"),
            "--base",
            str(path),
        ]
        name = "bad_base.json: field 'params.reflection_center'"
    else:
        argv, name = ["calibrate", "radar", str(_synthetic_csv(tmp_path)), "--out", str(tmp_path / "r.txt")], ".json"
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and name in err, err
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "l.csv").exists()


def test_shipped_rig_matches_real_astyx_detection_rates(astyx_log):
    """The shipped rig at real boxes (every 4th frame, for speed): detection rate per range bin close to the
    real one, where the generic rig is far off (the full figures: benchmarks/real_radar_fidelity.py)."""
    frames = frames_from_log(astyx_log.select(astyx_log["frame"] % 4 == 0))
    real = real_statistics(frames)
    ok = real["n_range"] >= 80
    assert ok.sum() >= 3
    gaps = {}
    for name, cfg in (("shipped", load_rig(SHIPPED_RIG)[0]), ("generic", RigConfig())):
        sim = rig_statistics(cfg, frames, replicates=4, seed=9, expected=True)
        gaps[name] = np.abs(sim["det_range"][ok] - real["det_range"][ok])
    assert np.all(gaps["shipped"] < 0.08), gaps
    assert np.max(gaps["generic"]) > 0.15, gaps


def test_shipped_rig_loses_hidden_boxes_near_the_sensor_as_astyx_does(astyx_log):
    """Detection per corner range x occluded fraction at the real boxes: the shipped rig's loss per range knot
    follows the real cells (a hidden box lost often within 15 m, hardly beyond 50 m); one loss for every
    range (the rig's own laws with the table replaced by its mean) cannot."""
    frames = frames_from_log(astyx_log)
    real = real_statistics(frames)
    shipped = load_rig(SHIPPED_RIG)[0]
    assert shipped.occlusion_loss_table is not None
    flat = replace(shipped, occlusion_loss_knots=None, occlusion_loss_table=None,
                   occlusion_loss=float(np.mean(shipped.occlusion_loss_table)))  # fmt: skip
    ok = real["n_occlusion_range"] >= 80
    gap = {}
    for name, cfg in (("shipped", shipped), ("one loss", flat)):
        sim = rig_statistics(cfg, frames, replicates=4, seed=9, expected=True)
        gap[name] = np.abs(sim["det_occlusion_range"][ok] - real["det_occlusion_range"][ok])
    assert np.max(gap["shipped"]) < 0.06, gap
    assert np.max(gap["one loss"]) > 0.1, gap


# ------------------------------------------------------------------------------ offset mixture law

MIXTURE = replace(
    TRUE,
    offset_mixture_edges=(0.0, 40.0, 120.0),
    # near bin: a tight core on the corner plus a wide component 0.6 m outward; far bin: one component
    offset_mixture_weights=(0.7, 0.3, 1.0, 0.0),
    offset_mixture_means=(0.0, 0.0, -0.2, 0.6, -0.5, 0.3, 0.0, 0.0),
    offset_mixture_scales=(0.1, 0.0, 0.1, 0.4, 0.1, 0.3, 0.5, -0.2, 0.2, 0.1, 0.0, 0.1),
)
"""A rig with the offset mixture law (two range bins of two components; the far bin's second is padding)."""


def _polar_offsets(corner: np.ndarray, meas: np.ndarray) -> np.ndarray:
    """(radial, outward cross-range) offsets [m] of ``meas`` from ``corner``: the calibration's statistic."""
    from sensor_envs.geometry import to_polar_frame

    return to_polar_frame(meas - corner, corner)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["snapshot", "record"])
def test_mixture_law_draws_the_mixture_around_the_closest_corner(mode):
    """Snapshot and the running rig's stationary law are the bin's mixture in the corner's polar frame."""
    from sensor_envs.radar.rig import OffsetMixture

    mix = OffsetMixture.from_config(MIXTURE)
    assert mix is not None
    rng = np.random.default_rng(4)
    if mode == "snapshot":
        boxes = generate_scenario(20000, 1, 1.0, rng).boxes[0]
        meas, _ = RadarRig(MIXTURE).snapshot(boxes, np.zeros(boxes.shape[0]), SnapshotDraws.draw(boxes.shape[0], rng))
    else:  # static boxes, so every cycle's corner is the same; latency 0: the corner is the box's own
        cfg = replace(MIXTURE, latency=0.0, tracker_tau=1.0, reflection_tau=1.0)
        sc = generate_scenario(250, 40, 1.0, rng)
        sc = replace(sc, boxes=np.broadcast_to(sc.boxes[:1], sc.boxes.shape).copy(), velocity=0 * sc.velocity)
        log = RadarRig(cfg).record(sc, rng)
        tgt = ~log.is_clutter
        boxes = np.stack([log[c] for c in REF_COLUMNS], axis=1)[tgt]
        meas = np.stack([log["meas_x"], log["meas_y"]], axis=1)[tgt]
    corner, _, _ = _reflection_geometry(boxes)
    det = np.isfinite(meas[:, 0])
    z = _polar_offsets(corner[det], meas[det])
    b = mix.range_bin(corner[det])
    for k in range(2):  # one iteration per range bin: the mixture's mean and covariance
        mean, cov = _moments(mix, k)
        zk = z[b == k]
        assert zk.shape[0] > 1000
        np.testing.assert_allclose(zk.mean(axis=0), mean, atol=0.03)
        np.testing.assert_allclose(np.cov(zk.T), cov, atol=0.03)
    core = np.hypot(*(z[b == 0] - MIXTURE.offset_mixture_means[:2]).T) < 0.15  # the near bin's tight core
    assert abs(core.mean() - 0.7 * (1 - np.exp(-0.5 * 1.5**2))) < 0.05


def test_mixture_law_is_correlated_from_cycle_to_cycle():
    """Components persist (reflection time constant) and the normal draw is the tracker's AR(1)."""
    rng = np.random.default_rng(5)
    sc = generate_scenario(150, 20, 1.0, rng)
    fast = RadarRig(replace(MIXTURE, tracker_tau=20.0, reflection_tau=20.0)).record(sc, np.random.default_rng(1))
    slow = RadarRig(replace(MIXTURE, tracker_tau=0.05, reflection_tau=0.05)).record(sc, np.random.default_rng(1))

    def lag1(log: RadarLog) -> float:
        tgt = ~log.is_clutter
        boxes = np.stack([log[c] for c in REF_COLUMNS], axis=1)[tgt]
        meas = np.stack([log["meas_x"], log["meas_y"]], axis=1)[tgt]
        corner, _ = closest_corner(rectangle_corners(*boxes.T))
        z = _polar_offsets(corner, meas)[:, 1]
        tid, cyc = log["target"][tgt], log["frame"][tgt]
        order = np.lexsort((cyc, tid))
        z, tid, cyc = z[order], tid[order], cyc[order]
        nxt = (tid[1:] == tid[:-1]) & (cyc[1:] == cyc[:-1] + 1) & np.isfinite(z[1:]) & np.isfinite(z[:-1])
        return float(np.corrcoef(z[:-1][nxt], z[1:][nxt])[0, 1])

    assert lag1(fast) > 0.8 and abs(lag1(slow)) < 0.15, (lag1(fast), lag1(slow))


def test_rig_without_the_mixture_records_as_before():
    """Rig files without ``offset_mixture_*`` keep the reflection-point law, draw for draw: the numbers
    below were printed by the code before the mixture law existed (commit c6099aa)."""
    sc = generate_scenario(8, 10, 1.0, np.random.default_rng(2))
    log = RadarRig(TRUE).record(sc, np.random.default_rng(3))
    meas = np.stack([log["meas_x"], log["meas_y"]], axis=1)[~log.is_clutter]
    assert meas.shape == (80, 2) and int(np.isnan(meas[:, 0]).sum()) == 24
    last = [[79.52516288, 7.13932957], [94.83064211, 2.41560932], [7.69498214, -2.76553736],
            [np.nan, np.nan], [61.2092296, -3.49102347], [48.62778417, -6.27557335]]  # fmt: skip
    np.testing.assert_allclose(meas[-6:], last, atol=1e-8)
    rng = np.random.default_rng(4)
    boxes = generate_scenario(50, 1, 1.0, rng).boxes[0]
    snap, _ = RadarRig(TRUE).snapshot(boxes, np.zeros(50), SnapshotDraws.draw(50, rng))
    first = [[61.48558344, -1.11307323], [53.15142756, 2.71336078], [63.92467662, 11.06092181],
             [48.29677568, -6.25441322]]  # fmt: skip
    np.testing.assert_allclose(snap[:4], first, atol=1e-8)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"offset_mixture_weights": [0.7, 0.2, 1.0, 0.0]}, "params.offset_mixture_weights"),  # sums to 0.9
        ({"offset_mixture_weights": [0.7, 0.3, 1.2, -0.2]}, "params.offset_mixture_weights"),  # not in [0, 1]
        ({"offset_mixture_weights": [0.7, 0.3, 1.0]}, "params.offset_mixture_weights"),  # not bins x components
        ({"offset_mixture_means": [0.0] * 6}, "params.offset_mixture_means"),  # wrong length
        ({"offset_mixture_means": [float("nan")] * 8}, "params.offset_mixture_means"),
        ({"offset_mixture_scales": [0.0, 0.0, 0.1] + [0.1, 0.0, 0.1] * 3}, "params.offset_mixture_scales"),
        ({"offset_mixture_scales": [0.1, 0.0, -0.1] + [0.1, 0.0, 0.1] * 3}, "params.offset_mixture_scales"),
        ({"offset_mixture_edges": None}, "params.offset_mixture_weights"),  # tables without edges
        ({"offset_mixture_scales": None}, "params.offset_mixture_scales"),  # edges without every table
    ],
)
def test_bad_mixture_values_fail_at_load_naming_file_and_field(tmp_path, change, field):
    params = {k: v for k, v in MIXTURE.to_params().items() if v is not None}
    params.update(change)
    params = {k: v for k, v in params.items() if v is not None}
    path = tmp_path / "bad_rig.json"
    path.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": params}))
    with pytest.raises(ModelFileError, match=f"bad_rig.json: field '{field}'"):
        load_rig(path)


@pytest.mark.slow
def test_fit_offset_mixture_recovers_a_known_offset_law():
    """EM per range bin recovers the rig's mixture; the CV keeps one component where one suffices."""
    from sensor_envs.radar.calibrate import fit_offset_mixture
    from sensor_envs.radar.rig import OffsetMixture

    frames = synthetic_frames(MIXTURE, n_frames=200, seed=6)
    cfg, report = fit_offset_mixture(frames, RigConfig(), seed=0, components=(1, 2, 3))
    assert cfg.offset_mixture_edges == DET_RANGE_EDGES
    comps = [b["components"] for b in report["bins"]]
    assert comps[3] == 1 and comps[0] >= 2, comps  # 50-75 m: the true far law is one Gaussian
    true, fit = OffsetMixture.from_config(MIXTURE), OffsetMixture.from_config(cfg)
    assert true is not None and fit is not None
    r = np.hypot(frames.corner[:, 0], frames.corner[:, 1])
    for k, t in ((0, 0), (1, 0), (3, 1)):  # calibration bins 0-15, 15-30 and 50-75 m lie in true bins 0, 0, 1
        (m_fit, c_fit), (m_true, c_true) = _moments(fit, k), _moments(true, t)
        s = (r >= DET_RANGE_EDGES[k]) & (r < DET_RANGE_EDGES[k + 1]) & np.isfinite(frames.meas[:, 0])
        z = _polar_offsets(frames.corner[s], frames.meas[s])
        # maximum likelihood keeps the sample's mean and covariance (EM's fixed point), up to the 1e-4 m^2 floor
        np.testing.assert_allclose(m_fit, z.mean(axis=0), atol=0.01)
        np.testing.assert_allclose(c_fit, np.cov(z.T, bias=True), atol=0.01)
        # and the sample comes from the true law (sampling noise of a few hundred heavy-tailed rows)
        np.testing.assert_allclose(m_fit, m_true, atol=0.08)
        np.testing.assert_allclose(np.sqrt(np.diag(c_fit)), np.sqrt(np.diag(c_true)), rtol=0.3)


@pytest.mark.slow
def test_calibrate_cli_offset_law_mixture(tmp_path):
    real = _synthetic_csv_of(tmp_path, MIXTURE, synthetic_frames(MIXTURE, n_frames=40, seed=2))
    rig = tmp_path / "rig.json"
    argv = [
        "calibrate",
        "radar",
        str(real),
        "--out",
        str(rig),
        "--offset-law",
        "mixture",
        "--mixture-max-components",
        "2",
    ]
    assert main(argv) == 0
    cfg, card = load_rig(rig)
    assert card["offset_law"] == "mixture" and cfg.offset_mixture_edges == DET_RANGE_EDGES
    assert all(b["components"] <= 2 and len(b["cv_loglik"]) == 2 for b in card["offset_mixture"]["bins"])
    assert card["discrepancy_after"]["offset"] < 0.1 * card["discrepancy_before"]["offset"]
    out = tmp_path / "log.csv"
    assert main(["record", "radar", "--rig", str(rig), "--out", str(out), "--sequences", "2", "--cycles", "5"]) == 0


def test_mixture_min_range_keeps_the_reflection_law_nearer():
    """``offset_mixture_min_range``: boxes whose closest corner is nearer keep the reflection-point law,
    the others draw the mixture, draw for draw (same random stream; the far rows are the pure mixture's)."""
    rng = np.random.default_rng(8)
    boxes = generate_scenario(400, 1, 1.0, rng).boxes[0]
    draws = SnapshotDraws.draw(boxes.shape[0], rng)
    occ = np.zeros(boxes.shape[0])
    near = np.hypot(*_reflection_geometry(boxes)[0].T) < 40.0
    assert 50 < near.sum() < 350
    hybrid, _ = RadarRig(replace(MIXTURE, offset_mixture_min_range=40.0)).snapshot(boxes, occ, draws)
    for cfg, rows in ((TRUE, near), (MIXTURE, ~near)):  # reflection law nearer, mixture from 40 m on
        pure, _ = RadarRig(cfg).snapshot(boxes, occ, draws)
        np.testing.assert_array_equal(hybrid[rows], pure[rows])
    sc = generate_scenario(30, 15, 1.0, np.random.default_rng(9))
    mix_log = RadarRig(MIXTURE).record(sc, np.random.default_rng(3))
    hyb_log = RadarRig(replace(MIXTURE, offset_mixture_min_range=40.0)).record(sc, np.random.default_rng(3))
    m0, m1 = (np.stack([lg["meas_x"], lg["meas_y"]], axis=1) for lg in (mix_log, hyb_log))
    rng_ref = np.hypot(mix_log["ref_x"], mix_log["ref_y"])
    same = np.all((m0 == m1) | (np.isnan(m0) & np.isnan(m1)), axis=1)
    assert np.all(same[rng_ref > 45.0]) and not np.any(same[(rng_ref < 35.0) & np.isfinite(m0[:, 0])])


@pytest.mark.parametrize(
    ("change", "field"),
    [({"offset_mixture_min_range": -1.0}, "params.offset_mixture_min_range"),
     ({"offset_mixture_edges": None, "offset_mixture_weights": None, "offset_mixture_means": None,
       "offset_mixture_scales": None, "offset_mixture_min_range": 30.0}, "params.offset_mixture_min_range")],
)  # fmt: skip
def test_bad_mixture_min_range_fails_at_load(tmp_path, change, field):
    test_bad_mixture_values_fail_at_load_naming_file_and_field(tmp_path, change, field)


@pytest.mark.slow
def test_calibrate_cli_mixture_min_range(tmp_path, capsys):
    """``--mixture-min-range``: the reflection law is fitted for the nearer boxes, the mixture beyond;
    refused (exit 2, one line naming the option, nothing written) without ``--offset-law mixture``."""
    real = _synthetic_csv_of(tmp_path, MIXTURE, synthetic_frames(MIXTURE, n_frames=40, seed=2))
    rig = tmp_path / "rig.json"
    argv = ["calibrate", "radar", str(real), "--out", str(rig), "--mixture-min-range", "30", "--max-evals", "60"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--mixture-min-range" in err and not rig.exists(), err
    assert main([*argv, "--offset-law", "mixture", "--mixture-max-components", "2"]) == 0
    cfg, card = load_rig(rig)
    assert cfg.offset_mixture_min_range == 30.0 and cfg.offset_mixture_edges == DET_RANGE_EDGES
    assert "below 30 m" in card["procedure"] and cfg.reflection_center != RigConfig().reflection_center


def _moments(mix, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance (2, 2) of bin ``k`` of an offset mixture [m, m^2]."""
    w, mu, L = mix.weights[k], mix.means[k], mix.chol[k]
    mean = (w[:, None] * mu).sum(axis=0)
    cov = sum(w[j] * (L[j] @ L[j].T + np.outer(mu[j] - mean, mu[j] - mean)) for j in range(w.size))
    return mean, cov


def _synthetic_csv_of(tmp_path: Path, config: RigConfig, frames) -> Path:
    log = snapshot_log(config, frames, np.random.default_rng(0))
    path = tmp_path / "real.csv"
    write_log(log, path)
    return path


# ------------------------------------------------------------------ mounting yaw error (azimuth_bias)
def test_azimuth_bias_rotates_every_detection_about_the_sensor_and_changes_nothing_else():
    rng = np.random.default_rng(4)
    boxes = generate_scenario(40, 1, 1.0, rng).boxes[0]
    occ, draws = np.zeros(40), SnapshotDraws.draw(40, rng)
    bias = np.deg2rad(0.5)
    m0, p0 = RadarRig(TRUE).snapshot(boxes, occ, draws)
    m1, p1 = RadarRig(replace(TRUE, azimuth_bias=bias)).snapshot(boxes, occ, draws)
    np.testing.assert_array_equal(p0, p1)  # detection reads the reflection point, not the report
    np.testing.assert_array_equal(np.isnan(m0[:, 0]), np.isnan(m1[:, 0]))
    ok = np.isfinite(m0[:, 0])
    assert ok.sum() > 20
    np.testing.assert_allclose(np.hypot(*m1[ok].T), np.hypot(*m0[ok].T), rtol=1e-12)
    dang = np.arctan2(m1[ok, 1], m1[ok, 0]) - np.arctan2(m0[ok, 1], m0[ok, 0])
    np.testing.assert_allclose(dang, bias, atol=1e-12)
    # a recording rotates alike, with the same random draws (clutter, detections) as without the bias
    scen = generate_scenario(6, 5, 1.0, np.random.default_rng(5))
    a = RadarRig(TRUE).record(scen, np.random.default_rng(6))
    b = RadarRig(replace(TRUE, azimuth_bias=bias)).record(scen, np.random.default_rng(6))
    tgt = ~a.is_clutter
    np.testing.assert_array_equal(a["meas_x"][~tgt], b["meas_x"][~tgt])
    xa, ya, xb, yb = a["meas_x"][tgt], a["meas_y"][tgt], b["meas_x"][tgt], b["meas_y"][tgt]
    det = np.isfinite(xa)
    np.testing.assert_array_equal(det, np.isfinite(xb))
    np.testing.assert_allclose(np.arctan2(yb[det], xb[det]) - np.arctan2(ya[det], xa[det]), bias, atol=1e-12)


def test_bad_azimuth_bias_fails_at_load_naming_file_and_field(tmp_path):
    path = save_rig(tmp_path / "rig.json", TRUE)
    data = json.loads(path.read_text())
    data["params"]["azimuth_bias"] = 0.5  # 29 deg: not a mounting error
    path.write_text(json.dumps(data))
    with pytest.raises(ModelFileError, match="azimuth_bias"):
        load_rig(path)


def test_fit_azimuth_bias_finds_an_undeclared_mounting_yaw_error():
    """Data from a rig whose detections are all rotated by 0.3 deg; the calibrated rig was told nothing of it."""
    true_bias = np.deg2rad(0.3)
    frames = synthetic_frames(replace(TRUE, azimuth_bias=true_bias), n_frames=150)
    sim = _sim_setup(frames, 4, np.random.default_rng(0))
    bias, rep = fit_azimuth_bias(frames, TRUE, sim)
    assert abs(np.rad2deg(bias - true_bias)) < 0.06, rep["azimuth_bias_deg"]
    assert rep["offset_signed_at_best"] < 0.5 * rep["offset_signed_at_zero"]
    # the outward-frame term the calibration used before cannot tell the two rigs apart as well
    real = real_statistics(frames)
    d0 = discrepancy(rig_statistics(TRUE, frames, 4, seed=5), real)
    d1 = discrepancy(rig_statistics(replace(TRUE, azimuth_bias=bias), frames, 4, seed=5), real)
    assert d1["offset_signed"] < 0.5 * d0["offset_signed"]
    assert d0["offset_signed"] - d1["offset_signed"] > 2 * (d0["offset"] - d1["offset"])


@pytest.mark.slow
def test_calibrate_with_azimuth_bias_recovers_it_and_fits_the_laws_on_derotated_data():
    true_bias = np.deg2rad(-0.4)
    frames = synthetic_frames(replace(TRUE, azimuth_bias=true_bias), n_frames=150)
    cfg, card = calibrate_rig(frames, RigConfig(), seed=1, replicates=2, max_evals=150, azimuth_bias=True)
    assert abs(np.rad2deg(cfg.azimuth_bias - true_bias)) < 0.08, card["azimuth_bias"]
    assert len(card["azimuth_bias"]["rounds"]) == 2
    assert card["discrepancy_after"]["offset_signed"] < 0.5 * card["discrepancy_before"]["offset_signed"]
    plain, _ = calibrate_rig(frames, RigConfig(), seed=1, replicates=2, max_evals=150)
    assert plain.azimuth_bias == 0.0  # without the option the bias stays the base's


@pytest.mark.slow
def test_calibrate_cli_azimuth_bias_flag_writes_the_fitted_bias(tmp_path):
    yawed = replace(TRUE, azimuth_bias=float(np.deg2rad(0.5)))
    real = _synthetic_csv_of(tmp_path, yawed, synthetic_frames(yawed, n_frames=60, seed=3))
    rig = tmp_path / "rig.json"
    assert main(["calibrate", "radar", str(real), "--out", str(rig), "--max-evals", "60", "--azimuth-bias"]) == 0
    cfg, card = load_rig(rig)
    assert abs(np.rad2deg(cfg.azimuth_bias) - 0.5) < 0.1, card["azimuth_bias"]
    assert card["azimuth_bias"]["deg"] == pytest.approx(np.rad2deg(cfg.azimuth_bias))
    assert "mounting yaw error" in card["procedure"]


def test_astyx_detections_carry_a_mounting_yaw_error_that_fit_azimuth_bias_finds(astyx_log):
    """The closed loop's finding on Astyx: the real detections are rotated about the sensor (signed cross-range
    offsets, same sign on both sides). ``fit_azimuth_bias`` with the shipped rig's laws finds a small negative
    angle; the rig with it has a far smaller signed-offset discrepancy at the real boxes (every 2nd frame)."""
    frames = frames_from_log(astyx_log.select(astyx_log["frame"] % 2 == 0))
    real = real_statistics(frames)
    shipped = load_rig(SHIPPED_RIG)[0]
    sim = _sim_setup(frames, 4, np.random.default_rng(0))
    bias, _ = fit_azimuth_bias(frames, shipped, sim)
    assert np.deg2rad(-0.3) < bias < np.deg2rad(-0.05), np.rad2deg(bias)
    cfg = replace(shipped, azimuth_bias=bias)
    with_bias = discrepancy(rig_statistics(cfg, frames, 4, seed=9), real)["offset_signed"]
    without = discrepancy(rig_statistics(replace(cfg, azimuth_bias=0.0), frames, 4, seed=9), real)["offset_signed"]
    assert with_bias < 0.8 * without, (with_bias, without)


@pytest.mark.slow
def test_occlusion_loss_per_range_knot_is_recovered_where_one_loss_cannot_fit():
    """A rig that loses hidden boxes near the sensor only: calibrate's ``occlusion_by_range`` finds the table
    (near loss high, far loss low) and fits the range x occlusion cells better than one loss for every range."""
    from tqdm import tqdm

    from sensor_envs.radar.calibrate import OCCLUSION_LOSS_KNOTS, _fit_detection

    true = replace(TRUE, occlusion_loss_knots=(10.0, 50.0, 90.0), occlusion_loss_table=(0.95, 0.5, 0.0))
    frames = synthetic_frames(true, n_frames=400, seed=2)
    assert (frames.occluded > 0.5).sum() > 150  # enough hidden boxes to see the law
    real = real_statistics(frames)
    sim = _sim_setup(frames, 2, np.random.default_rng(3))
    fits = {}
    for by_range in (False, True):
        with tqdm(disable=True) as bar:
            fits[by_range] = _fit_detection(
                replace(RigConfig(), max_range=150.0), sim, real, 0.002, bar, by_range=by_range
            )
    table = fits[True].occlusion_loss_table
    assert fits[True].occlusion_loss_knots == OCCLUSION_LOSS_KNOTS and table is not None
    assert table[0] > 0.7 and table[-1] < 0.3, table
    assert fits[False].occlusion_loss_table is None
    cells = {k: discrepancy(rig_statistics(c, frames, 4, seed=5, expected=True), real)["det_occlusion_range"]
             for k, c in fits.items()}  # fmt: skip
    assert cells[True] < 0.6 * cells[False], cells


def test_occlusion_loss_table_reads_and_is_checked_at_load(tmp_path):
    cfg = replace(TRUE, occlusion_loss_knots=(10.0, 90.0), occlusion_loss_table=(0.8, 0.2))
    rig = RadarRig(cfg)
    r = np.array([5.0, 50.0, 100.0])
    np.testing.assert_allclose(rig.occlusion_loss(r), [0.8, 0.5, 0.2])
    p_free = rig.detection_probability(r, np.zeros(3), np.zeros(3))
    np.testing.assert_allclose(rig.detection_probability(r, np.zeros(3), np.ones(3)), p_free * [0.2, 0.5, 0.8])
    assert load_rig(save_rig(tmp_path / "rig.json", cfg))[0] == cfg
    for params, field in (
        ({"occlusion_loss_knots": [10, 90], "occlusion_loss_table": [0.8, 1.2]}, "occlusion_loss_table"),
        ({"occlusion_loss_knots": [10, 90], "occlusion_loss_table": [0.8]}, "occlusion_loss_table"),
        ({"occlusion_loss_knots": [90, 10], "occlusion_loss_table": [0.8, 0.2]}, "occlusion_loss_knots"),
        ({"occlusion_loss_table": [0.8, 0.2]}, "occlusion_loss_table"),
    ):
        path = tmp_path / "bad_rig.json"
        path.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": params}))
        with pytest.raises(ModelFileError, match=f"bad_rig.json: field 'params.{field}'"):
            load_rig(path)


def test_calibrate_cli_occlusion_by_range_writes_the_table(tmp_path):
    real = _synthetic_csv(tmp_path)
    rig = tmp_path / "rig.json"
    argv = ["calibrate", "radar", str(real), "--out", str(rig), "--max-evals", "20", "--occlusion-by-range"]
    assert main(argv) == 0
    cfg, card = load_rig(rig)
    assert card["occlusion_by_range"] is True and "occlusion loss per range knot" in card["procedure"]
    assert cfg.occlusion_loss_knots is not None and len(cfg.occlusion_loss_table or ()) == len(cfg.occlusion_loss_knots)
    assert "det_occlusion_range" in card["discrepancy_after"]
    argv = ["calibrate", "radar", str(real), "--out", str(tmp_path / "r2.json"), "--scene-only", "--occlusion-by-range"]
    assert main([*argv, "--base", str(rig)]) == 2  # --scene-only fits no sensor law
