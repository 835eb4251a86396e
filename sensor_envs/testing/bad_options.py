"""Hand-written bad inputs: command-line options, unsafe outputs, rig files; :data:`CASES` holds all of them."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sensor_envs.testing.bad_files import ASTYX, GAUSS, KDE, LMODEL, LNPZ, MAP, RADAR
from sensor_envs.testing.bad_files import CASES as FILE_CASES
from sensor_envs.testing.bad_pieces import (
    RADAR_HEADER,
    SHIPPED,
    C,
    Case,
    _bytes,
    astyx,
    astyx_obj,
    fit_lidar,
    fit_radar,
    gauss_model,
    kde_model,
    lidar_model,
    lidar_npz,
    opt,
    radar_csv,
    record_astyx,
    record_lidar_map,
    ros_yaml,
    validate_lidar,
    validate_radar,
)

CASES: list[Case] = list(FILE_CASES)
OPTION = "command-line option"
CASES += [
    C(
        OPTION,
        "record-radar-cycle-time-minus-1",
        opt(["record", "radar", "--out", "{d}/r.csv", "--cycle-time", "-1"], "--cycle-time"),
        "expected a number in",
    ),
    C(
        OPTION,
        "record-radar-cycle-time-0",
        opt(["record", "radar", "--out", "{d}/r.csv", "--cycle-time", "0"], "--cycle-time"),
        "expected a number in",
    ),
    C(
        OPTION,
        "record-radar-cycle-time-nan",
        opt(["record", "radar", "--out", "{d}/r.csv", "--cycle-time", "nan"], "--cycle-time"),
        "expected a number in",
    ),
    C(
        OPTION,
        "fit-radar-cycle-time-nan",
        opt(["fit", "radar", "{d}/x.csv", "--out", "{d}/m.npz", "--cycle-time", "nan"], "--cycle-time"),
        "expected a number in",
    ),
    C(
        OPTION,
        "fit-radar-bandwidth-scale-out-of-range",
        opt(["fit", "radar", "{d}/x.csv", "--out", "{d}/m.npz", "--bandwidth-scale", "1000"], "--bandwidth-scale"),
        "[0.01, 100]",
    ),
    C(
        OPTION,
        "calibrate-radar-mixture-min-range-negative",
        opt(
            [
                "calibrate",
                "radar",
                "{d}/x.csv",
                "--out",
                "{d}/r.json",
                "--offset-law",
                "mixture",
                "--mixture-min-range",
                "-5",
            ],
            "--mixture-min-range",
        ),
        "expected a number in",
    ),  # fmt: skip
    C(
        OPTION,
        "fit-radar-cycle-time-inf",
        opt(["fit", "radar", "{d}/x.csv", "--out", "{d}/m.npz", "--cycle-time", "inf"], "--cycle-time"),
        "expected a number in",
    ),
    C(
        OPTION,
        "record-radar-sequences-0",
        opt(["record", "radar", "--out", "{d}/r.csv", "--sequences", "0"], "--sequences"),
        "positive integer",
    ),
    C(
        OPTION,
        "record-radar-sequences-1e3",
        opt(["record", "radar", "--out", "{d}/r.csv", "--sequences", "1e3"], "--sequences"),
        "positive integer",
    ),
    C(
        OPTION,
        "record-radar-targets-0",
        opt(["record", "radar", "--out", "{d}/r.csv", "--targets", "0"], "--targets"),
        "positive integer",
    ),
    C(
        OPTION,
        "record-radar-cycles-2.5",
        opt(["record", "radar", "--out", "{d}/r.csv", "--cycles", "2.5"], "--cycles"),
        "positive integer",
    ),
    C(
        OPTION,
        "record-radar-seed-minus-1",
        opt(["record", "radar", "--out", "{d}/r.csv", "--seed", "-1"], "--seed"),
        "integer >= 0",
    ),
    C(
        OPTION,
        "record-lidar-poses-0",
        opt(["record", "lidar", "--out", "{d}/l.npz", "--poses", "0"], "--poses"),
        "positive integer",
    ),
    C(
        OPTION,
        "record-lidar-repeats-minus-3",
        opt(["record", "lidar", "--out", "{d}/l.npz", "--repeats", "-3"], "--repeats"),
        "positive integer",
    ),
    C(
        OPTION,
        "record-lidar-unit-seed-word",
        opt(["record", "lidar", "--out", "{d}/l.npz", "--unit-seed", "x"], "--unit-seed"),
        "integer >= 0",
    ),
    C(
        OPTION,
        "fit-lidar-folds-0",
        opt(["fit", "lidar", "{d}/x.npz", "--out", "{d}/m.npz", "--folds", "0"], "--folds"),
        "positive integer",
    ),
    C(
        OPTION,
        "fit-lidar-variant-unknown",
        opt(["fit", "lidar", "{d}/x.npz", "--out", "{d}/m.npz", "--variant", "huge"], "--variant"),
        "invalid choice",
    ),
    C(
        OPTION,
        "demo-episodes-0",
        opt(["demo", "--out", "{d}/demo", "--episodes", "0"], "--episodes"),
        "positive integer",
    ),
    C(
        OPTION,
        "validate-radar-seed-minus-5",
        opt(["validate", "radar", "{d}/m.npz", "{d}/x.csv", "--out", "{d}/r", "--seed", "-5"], "--seed"),
        "integer >= 0",
    ),
    C(
        OPTION,
        "fit-radar-cv-group-unknown",
        opt(["fit", "radar", "{d}/x.csv", "--out", "{d}/m.npz", "--cv-group", "car"], "--cv-group"),
        "invalid choice",
    ),
]


def _existing(d: Path, name: str, data: bytes = b"precious") -> Path:
    return _bytes(d / name, data)


OUTPUT = "unsafe output"
CASES += [
    C(
        OUTPUT,
        "fit-lidar-out-is-its-log",
        lambda d: (["fit", "lidar", str(lidar_npz(d)), "--out", str(d / "log.npz")], str(d / "log.npz")),
        "input",
    ),
    C(
        OUTPUT,
        "fit-lidar-out-md",
        lambda d: (["fit", "lidar", str(lidar_npz(d)), "--out", str(d / "log.md")], "--out"),
        ".npz",
    ),
    C(
        OUTPUT,
        "fit-lidar-out-exists",
        lambda d: (["fit", "lidar", str(lidar_npz(d)), "--out", str(_existing(d, "m.npz"))], str(d / "m.npz")),
        "--force",
    ),
    C(
        OUTPUT,
        "fit-lidar-card-exists",
        lambda d: (["fit", "lidar", str(lidar_npz(d)), "--out", str(d / "m.npz")], str(_existing(d, "m.md"))),
        "--force",
    ),
    C(OUTPUT, "record-lidar-out-txt", lambda d: (["record", "lidar", "--out", str(d / "l.txt")], "--out"), ".npz"),
    C(
        OUTPUT,
        "record-radar-out-is-a-model",
        lambda d: (["record", "radar", "--out", str(kde_model(d))], "--out"),
        ".csv",
    ),
    C(
        OUTPUT,
        "record-radar-out-exists",
        lambda d: (["record", "radar", "--out", str(_existing(d, "precious.csv"))], str(d / "precious.csv")),
        "--force",
    ),
    C(
        OUTPUT,
        "fit-radar-out-exists",
        lambda d: (["fit", "radar", str(radar_csv(d)), "--out", str(_existing(d, "m.npz"))], str(d / "m.npz")),
        "--force",
    ),
    C(
        OUTPUT,
        "fit-radar-out-is-its-log",
        lambda d: (["fit", "radar", str(radar_csv(d, "log.npz")), "--out", str(d / "log.npz")], str(d / "log.npz")),
        "input",
    ),
    C(
        OUTPUT,
        "fit-radar-baseline-is-the-model",
        lambda d: (
            ["fit", "radar", str(radar_csv(d)), "--out", str(d / "m.npz"), "--baseline-out", str(d / "m.npz")],
            "--baseline-out",
        ),
        "input",
    ),
    C(
        OUTPUT,
        "fit-radar-baseline-exists",
        lambda d: (["fit", "radar", str(radar_csv(d)), "--out", str(d / "m.npz")], str(_existing(d, "m_gaussian.npz"))),
        "--force",
    ),
    C(
        OUTPUT,
        "validate-radar-out-holds-the-model-even-with-force",
        lambda d: (["validate", "radar", str(kde_model(d)), str(radar_csv(d)), "--out", str(d), "--force"], str(d)),
        "holds the input",
    ),
    C(
        OUTPUT,
        "validate-radar-out-is-the-log",
        lambda d: (
            ["validate", "radar", str(kde_model(d)), str(radar_csv(d)), "--out", str(d / "log.csv"), "--force"],
            str(d / "log.csv"),
        ),
        "input",
    ),
    C(
        OUTPUT,
        "validate-lidar-out-is-a-file",
        lambda d: (
            ["validate", "lidar", str(lidar_model(d)), str(lidar_npz(d)), "--out", str(_existing(d, "rep"))],
            str(d / "rep"),
        ),
        "file",
    ),
    C(
        OUTPUT,
        "validate-lidar-out-exists",
        lambda d: (
            ["validate", "lidar", str(lidar_model(d)), str(lidar_npz(d)), "--out", str(_full_dir(d / "rep"))],
            str(d / "rep"),
        ),
        "--force",
    ),
    C(
        OUTPUT,
        "demo-out-is-a-file",
        lambda d: (["demo", "--out", str(_existing(d, "demo_out"))], str(d / "demo_out")),
        "file",
    ),
    C(
        OUTPUT,
        "demo-out-not-empty",
        lambda d: (["demo", "--out", str(_full_dir(d / "demo_out"))], str(d / "demo_out")),
        "--force",
    ),
]


def _full_dir(p: Path) -> Path:
    p.mkdir()
    (p / "keep.txt").write_text("mine")
    return p


RIG = "radar rig file"


def _record_radar_rig(d: Path, params: dict) -> tuple[list[str], str]:
    """``record radar --rig`` with a rig file of ``params``."""
    rig = d / "rig.json"
    rig.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": params}))
    return ["record", "radar", "--rig", str(rig), "--out", str(d / "out.csv"), "--sequences", "1"], str(rig)


CASES += [
    C(
        RIG,
        "occlusion-loss-above-1",
        lambda d: _record_radar_rig(d, {"occlusion_loss_knots": [10, 90], "occlusion_loss_table": [0.8, 1.2]}),
        "'params.occlusion_loss_table'",
    ),
    C(
        RIG,
        "occlusion-loss-table-without-knots",
        lambda d: _record_radar_rig(d, {"occlusion_loss_table": [0.8, 0.2]}),
        "'params.occlusion_loss_table'",
    ),
    C(
        RIG,
        "occlusion-loss-knots-decreasing",
        lambda d: _record_radar_rig(d, {"occlusion_loss_knots": [90, 10], "occlusion_loss_table": [0.8, 0.2]}),
        "'params.occlusion_loss_knots'",
    ),
]


LRIG = "lidar rig file"


def _calibrate_lidar_spurious_only(d: Path, params: dict) -> tuple[list[str], str]:
    """``calibrate lidar LOG --spurious-only RIG`` with a rig file of ``params`` and a valid static-pose log."""
    rig = d / "neato_rig.json"
    rig.write_text(json.dumps({"kind": "neato_rig", "format_version": 1, "params": params}))
    argv = ["calibrate", "lidar", str(lidar_npz(d)), "--out", str(d / "out.json"), "--spurious-only", str(rig)]
    return argv, str(rig)


CASES += [
    C(
        LRIG,
        "spur-near-range-negative",
        lambda d: _calibrate_lidar_spurious_only(d, {"spur_near_range": -0.5}),
        "'params.spur_near_range'",
    ),
    C(
        LRIG,
        "spur-near-range-nan",
        lambda d: _calibrate_lidar_spurious_only(d, {"spur_near_range": float("nan")}),
        "'params.spur_near_range'",
    ),
    C(
        LRIG,
        "spur-prone-above-1",
        lambda d: _calibrate_lidar_spurious_only(d, {"spur_prone": 1.5}),
        "'params.spur_prone'",
    ),
    C(
        OPTION,
        "calibrate-lidar-max-evals-with-spurious-only",
        lambda d: (_calibrate_lidar_spurious_only(d, {})[0] + ["--max-evals", "50"], "--max-evals"),
        "no search",
    ),
    C(
        LRIG,
        "spur-bearing-weight-wrong-length",
        lambda d: _calibrate_lidar_spurious_only(d, {"spur_bearing_weight": [1.0, 2.0]}),
        "spur_bearing_weight",
    ),
]


# ------------------------------------------------------------- classes found by the generated fuzz (issue 42)
def _long_range_log(d: Path) -> Path:
    """A static-pose log of a longer-range sensor: a third of its returns between 5 and 7.5 m."""
    r = np.random.default_rng(1).uniform(0.5, 7.5, (3, 8, 4))
    return lidar_npz(d, ranges=r)


def _header(**fields: object) -> Callable[[dict], None]:
    """A header edit setting top-level (or ``params.<name>``) fields."""

    def edit(h: dict) -> None:
        for k, v in fields.items():
            top, _, sub = k.partition("__")
            if sub:
                h[top][sub] = v
            else:
                h[k] = v

    return edit


CASES += [
    C(LNPZ, "long-range-with-default-max-range", lambda d: fit_lidar(_long_range_log(d)), "'ranges'"),
    C(
        LNPZ,
        "long-range-validated-with-neato-model",
        lambda d: (
            ["validate", "lidar", str(SHIPPED / "neato_lidar.npz"), str(_long_range_log(d)), "--out", str(d / "r")],
            str(d / "log.npz"),
        ),
        "'ranges'",
    ),
    C(
        LNPZ,
        "long-range-diagnosed-with-default",
        lambda d: (["diagnose", "lidar", str(_long_range_log(d)), "--out", str(d / "g")], str(d / "log.npz")),
        "'ranges'",
    ),
    C(
        RADAR,
        "astyx-frame-file-as-log",
        lambda d: fit_radar(astyx(d) / "radar_6455" / "000000.txt"),
        "record radar --astyx",
    ),
    C(RADAR, "nul-in-column-name", lambda d: fit_radar(radar_csv(d, header=RADAR_HEADER + ",rc\x00s")), "header"),
    C(RADAR, "tab-in-column-name", lambda d: fit_radar(radar_csv(d, header=RADAR_HEADER + ",r\tcs")), "header"),
    C(
        KDE,
        "params-extra-candidates-nested",
        lambda d: validate_radar(kde_model(d, header=_header(params__extra_candidates=[[[[1.0]]]]))),
        "'params.extra_candidates'",
    ),
    C(
        KDE,
        "params-extra-state-nested",
        lambda d: validate_radar(kde_model(d, header=_header(params__extra_state=[["rcs"]]))),
        "'params.extra_state'",
    ),
    C(
        KDE,
        "header-relevance-scores-text",
        lambda d: validate_radar(kde_model(d, header=_header(relevance_scores="high"))),
        "'relevance_scores'",
    ),
    C(
        KDE,
        "header-new-track-flags-number",
        lambda d: validate_radar(kde_model(d, header=_header(new_track_flags=1))),
        "'new_track_flags'",
    ),
    C(
        KDE,
        "header-unknown-field",
        lambda d: validate_radar(kde_model(d, header=_header(bandwidth_fitted=[1.0]))),
        "'bandwidth_fitted'",
    ),
    C(
        KDE,
        "header-cycle-time-negative",
        lambda d: validate_radar(kde_model(d, header=_header(cycle_time=-1.0))),
        "'cycle_time'",
    ),
    C(
        GAUSS,
        "params-min-count-1e19",
        lambda d: validate_radar(kde_model(d), baseline=gauss_model(d, header=_header(params__min_count=10**19))),
        "'params.min_count'",
    ),
    C(
        GAUSS,
        "header-state-variables-nested",
        lambda d: validate_radar(kde_model(d), baseline=gauss_model(d, header=_header(state_variables=[["x"]]))),
        "'state_variables'",
    ),
    C(LMODEL, "header-spur-mu-negative", lambda d: validate_lidar(lidar_model(d, _header(spur_mu=-3.0))), "'spur_mu'"),
    C(
        LMODEL,
        "header-param-names-duplicate",
        lambda d: validate_lidar(lidar_model(d, _header(param_names=["p_null", "p_null"]))),
        "'param_names'",
    ),
    C(LMODEL, "header-p-out-text", lambda d: validate_lidar(lidar_model(d, _header(p_out="0.1"))), "'p_out'"),
    C(
        MAP,
        "occupied-thresh-0",
        lambda d: record_lidar_map(ros_yaml(d, occupied_thresh="0")),
        "'occupied_thresh'",
    ),
    C(
        MAP,
        "occupied-below-free-thresh",
        lambda d: record_lidar_map(ros_yaml(d, occupied_thresh="0.3", free_thresh="0.5")),
        "'occupied_thresh'",
    ),
    C(MAP, "free-thresh-1", lambda d: record_lidar_map(ros_yaml(d, free_thresh="1")), "'free_thresh'"),
    C(
        ASTYX,
        "point-magnitude-1e300",
        lambda d: record_astyx(
            astyx(d, pc="\nX Y Z V_r Mag\n10.0 1.0 0.0 0.0 -1e300\n"), d / "astyx/radar_6455/000000.txt"
        ),
        "'Mag'",
    ),
    C(
        ASTYX,
        "point-x-beyond-1km",
        lambda d: record_astyx(
            astyx(d, pc="\nX Y Z V_r Mag\n1e5 1.0 0.0 0.0 40.0\n"), d / "astyx/radar_6455/000000.txt"
        ),
        "'X'",
    ),
    C(
        ASTYX,
        "box-width-negative",
        lambda d: record_astyx(astyx_obj(d, dimension3d=[4.5, -1.8, 1.5]), d / "astyx/groundtruth_obj3d/000000.json"),
        "'dimension3d'",
    ),
]
