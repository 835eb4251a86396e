"""Hand-written bad inputs, files: radar CSV, model files, lidar logs, CARMEN, ROS bags, maps, Astyx folders."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from sensor_envs.lidar.log import log_from_arrays, save_log
from sensor_envs.testing.bad_pieces import (
    RADAR_HEADER,
    RADAR_ROWS,
    SEGS,
    SHIPPED,
    C,
    Case,
    _bytes,
    astyx,
    astyx_obj,
    bag,
    carmen,
    fit_lidar,
    fit_radar,
    flaser,
    gauss_model,
    kde_model,
    lidar_arrays,
    lidar_model,
    lidar_npz,
    mutate_model,
    radar_cell,
    radar_csv,
    record_astyx,
    record_lidar_map,
    record_lidar_pgm,
    ros_map,
    ros_yaml,
    validate_lidar,
    validate_radar,
    validate_radar_log,
)

RADAR = "radar log CSV"
CASES: list[Case] = [
    # --- radar log CSV (fit radar) ---------------------------------------------------------------------------
    C(RADAR, "empty-file", lambda d: fit_radar(_bytes(d / "log.csv", b"")), "empty"),
    C(RADAR, "header-only", lambda d: fit_radar(radar_csv(d, rows=[])), "no rows"),
    C(
        RADAR,
        "missing-column-t",
        lambda d: fit_radar(radar_csv(d, header=RADAR_HEADER.replace(",t,", ",time,"))),
        "'t'",
    ),
    C(
        RADAR,
        "semicolon-separated",
        lambda d: fit_radar(
            radar_csv(d, header=RADAR_HEADER.replace(",", ";"), rows=[r.replace(",", ";") for r in RADAR_ROWS])
        ),
        "';'",
    ),
    C(
        RADAR,
        "tab-separated",
        lambda d: fit_radar(
            radar_csv(d, header=RADAR_HEADER.replace(",", "\t"), rows=[r.replace(",", "\t") for r in RADAR_ROWS])
        ),
        "'\\t'",
    ),
    C(
        RADAR,
        "latin1-bytes",
        lambda d: fit_radar(_bytes(d / "log.csv", (RADAR_HEADER + ",vitesse_é\n").encode("latin-1"))),
        "UTF-8",
    ),
    C(RADAR, "binary-garbage", lambda d: fit_radar(_bytes(d / "log.csv", bytes(range(256)) * 4)), "UTF-8"),
    C(RADAR, "ref_x-1e12", lambda d: fit_radar(radar_cell(d, 1, "ref_x", "1e12")), "'ref_x' row 1"),
    C(RADAR, "ref_y-minus-5e3", lambda d: fit_radar(radar_cell(d, 0, "ref_y", "-5e3")), "'ref_y' row 0"),
    C(RADAR, "ref_length-1e9", lambda d: fit_radar(radar_cell(d, 4, "ref_length", "1e9")), "'ref_length' row 4"),
    C(RADAR, "ref_width-500", lambda d: fit_radar(radar_cell(d, 0, "ref_width", "500")), "'ref_width' row 0"),
    C(RADAR, "meas_x-1e7", lambda d: fit_radar(radar_cell(d, 3, "meas_x", "1e7")), "'meas_x' row 3"),
    C(RADAR, "meas_y-1e300", lambda d: fit_radar(radar_cell(d, 0, "meas_y", "1e300")), "'meas_y' row 0"),
    C(RADAR, "sequence-1e30", lambda d: fit_radar(radar_cell(d, 0, "sequence", "1e30")), "'sequence' row 0"),
    C(RADAR, "frame-2**63", lambda d: fit_radar(radar_cell(d, 2, "frame", str(2**63))), "'frame' row 2"),
    C(RADAR, "target-1e20", lambda d: fit_radar(radar_cell(d, 0, "target", "1e20")), "'target' row 0"),
    C(RADAR, "frame-not-integer", lambda d: fit_radar(radar_cell(d, 1, "frame", "1.5")), "'frame' row 1"),
    C(RADAR, "target-negative-on-target-row", lambda d: fit_radar(radar_cell(d, 0, "target", "-1")), "'target' row 0"),
    C(RADAR, "ref_x-nan-text", lambda d: fit_radar(radar_cell(d, 0, "ref_x", "nan")), "'ref_x' row 0"),
    C(
        RADAR,
        "ref_heading-inf-text",
        lambda d: fit_radar(radar_cell(d, 1, "ref_heading", "inf")),
        "'ref_heading' row 1",
    ),
    C(RADAR, "meas_x-overflow-1e400", lambda d: fit_radar(radar_cell(d, 1, "meas_x", "1e400")), "'meas_x' row 1"),
    C(RADAR, "t-empty", lambda d: fit_radar(radar_cell(d, 1, "t", "")), "'t' row 1"),
    C(RADAR, "t-inf", lambda d: fit_radar(radar_cell(d, 1, "t", "inf")), "'t' row 1"),
    C(RADAR, "ref_width-zero", lambda d: fit_radar(radar_cell(d, 1, "ref_width", "0")), "'ref_width' row 1"),
    C(RADAR, "ref_length-negative", lambda d: fit_radar(radar_cell(d, 0, "ref_length", "-2")), "'ref_length' row 0"),
    C(RADAR, "ref-partly-empty", lambda d: fit_radar(radar_cell(d, 0, "ref_heading", "")), "'ref_heading' row 0"),
    C(RADAR, "meas_y-alone-empty", lambda d: fit_radar(radar_cell(d, 0, "meas_y", "")), "'meas_y' row 0"),
    C(
        RADAR,
        "neither-ref-nor-meas",
        lambda d: fit_radar(radar_csv(d, rows=[*RADAR_ROWS, "0,3,3.0,-1,,,,,,,"])),
        "row 5",
    ),
    C(RADAR, "extra-field", lambda d: fit_radar(radar_csv(d, rows=[*RADAR_ROWS, RADAR_ROWS[0] + ",7"])), "row 5"),
    C(RADAR, "word-in-ref_x", lambda d: fit_radar(radar_cell(d, 0, "ref_x", "ten")), "'ref_x' row 0"),
    C(RADAR, "complex-meas_x", lambda d: fit_radar(radar_cell(d, 0, "meas_x", "1+2j")), "'meas_x' row 0"),
    C(RADAR, "duplicate-header", lambda d: fit_radar(radar_csv(d, header=RADAR_HEADER + ",t")), "duplicate column"),
    C(
        RADAR,
        "covariate-not-numeric",
        lambda d: fit_radar(radar_csv(d, header=RADAR_HEADER + ",speed", rows=[r + ",fast" for r in RADAR_ROWS])),
        "'speed' row 0",
    ),
    C(
        RADAR,
        "repeated-sequence-frame-target",
        lambda d: fit_radar(radar_csv(d, rows=[*RADAR_ROWS, RADAR_ROWS[0]])),
        "row 5 repeats",
    ),
    C(RADAR, "only-clutter", lambda d: fit_radar(radar_csv(d, rows=[RADAR_ROWS[3]])), "no target rows"),
    C(RADAR, "one-detection", lambda d: fit_radar(radar_csv(d, rows=RADAR_ROWS[:1])), "fewer than"),
    C(RADAR, "log-is-a-folder", lambda d: fit_radar(_mkdir(d / "log.csv")), "is a folder"),
    C(RADAR, "log-missing", lambda d: fit_radar(d / "nope.csv"), "not found"),
    C(
        RADAR,
        "validate-with-ref_x-1e12",
        lambda d: validate_radar_log(radar_cell(d, 1, "ref_x", "1e12")),
        "'ref_x' row 1",
    ),
    C(
        RADAR,
        "validate-with-semicolons",
        lambda d: validate_radar_log(radar_csv(d, header=RADAR_HEADER.replace(",", ";"))),
        "';'",
    ),
    C(
        RADAR,
        "validate-with-sequence-1e30",
        lambda d: validate_radar_log(radar_cell(d, 0, "sequence", "1e30")),
        "'sequence'",
    ),
    C(  # a state variable the log neither has nor can derive (occluded, aspect, ... are derived)
        RADAR,
        "fit-extra-state-not-in-the-log",
        lambda d: (fit_radar(radar_csv(d))[0] + ["--relevance", "paper", "--extra-state", "bogus"], str(d / "log.csv")),
        "'bogus'",
    ),
]


def _mkdir(p: Path) -> Path:
    p.mkdir()
    return p


KDE = "KDE radar model file"
CASES += [
    C(KDE, "text-not-npz", lambda d: validate_radar(_bytes(d / "kde.npz", b"hello")), "not a readable model file"),
    C(KDE, "empty-file", lambda d: validate_radar(_bytes(d / "kde.npz", b"")), "not a readable model file"),
    C(
        KDE,
        "truncated-zip",
        lambda d: validate_radar(_bytes(d / "kde.npz", (SHIPPED / "radar_kde.npz").read_bytes()[:20000])),
        "not a readable model file",
    ),
    C(KDE, "no-header", lambda d: validate_radar(kde_model(d, __header__=None)), "'__header__'"),
    C(
        KDE,
        "header-not-json",
        lambda d: validate_radar(kde_model(d, __header__=np.frombuffer(b"{nope", np.uint8))),
        "'__header__'",
    ),
    C(KDE, "header-json-list", lambda d: validate_radar(kde_model(d, header=lambda h: [h])), "'__header__'"),
    C(KDE, "header-json-number", lambda d: validate_radar(kde_model(d, header=lambda h: 5)), "'__header__'"),
    C(
        KDE,
        "header-lacks-params",
        lambda d: validate_radar(kde_model(d, header=lambda h: h.pop("params") and None)),
        "'params'",
    ),
    C(
        KDE,
        "params-is-a-list",
        lambda d: validate_radar(kde_model(d, header=lambda h: h.update(params=[1, 2]))),
        "'params'",
    ),
    C(KDE, "card-is-a-string", lambda d: validate_radar(kde_model(d, header=lambda h: h.update(card="x"))), "'card'"),
    C(
        KDE,
        "params-lack-rel_variance",
        lambda d: validate_radar(kde_model(d, header=lambda h: h["params"].pop("rel_variance") and None)),
        "'params.rel_variance'",
    ),
    C(KDE, "kind-wrong", lambda d: validate_radar(kde_model(d, header=lambda h: h.update(kind="lidar"))), "'kind'"),
    C(
        KDE,
        "format-version-99",
        lambda d: validate_radar(kde_model(d, header=lambda h: h.update(format_version=99))),
        "'format_version'",
    ),
    C(KDE, "empty-grid_x", lambda d: validate_radar(kde_model(d, grid_x=np.zeros(0))), "'grid_x'"),
    C(KDE, "empty-grid_y", lambda d: validate_radar(kde_model(d, grid_y=np.zeros(0))), "'grid_y'"),
    C(KDE, "empty-log_h", lambda d: validate_radar(kde_model(d, log_h=lambda a: a[:, :0])), "'log_h'"),
    C(
        KDE,
        "log_h-nan",
        lambda d: validate_radar(kde_model(d, log_h=lambda a: np.where(a == a.flat[0], np.nan, a))),
        "'log_h'",
    ),
    C(KDE, "states-missing", lambda d: validate_radar(kde_model(d, states=None)), "'states'"),
    C(KDE, "states-three-columns", lambda d: validate_radar(kde_model(d, states=lambda a: a[:, :3])), "'states'"),
    C(KDE, "z-integer", lambda d: validate_radar(kde_model(d, z=lambda a: np.zeros(a.shape, np.int64))), "'z'"),
    C(KDE, "clutter_xy-1d", lambda d: validate_radar(kde_model(d, clutter_xy=np.zeros(4))), "'clutter_xy'"),
    C(KDE, "cv_counts-shape", lambda d: validate_radar(kde_model(d, cv_counts=lambda a: a[:1])), "'cv_counts'"),
    C(
        KDE,
        "pickled-array",
        lambda d: validate_radar(kde_model(d, clutter_xy=np.array([{"a": 1}], dtype=object))),
        "model file",
    ),
]

GAUSS = "Gaussian radar baseline file"
CASES += [
    C(
        GAUSS,
        "header-json-list",
        lambda d: validate_radar(kde_model(d), baseline=gauss_model(d, header=lambda h: [h])),
        "'__header__'",
    ),
    C(
        GAUSS,
        "lacks-params",
        lambda d: validate_radar(kde_model(d), baseline=gauss_model(d, header=lambda h: h.pop("params") and None)),
        "'params'",
    ),
    C(
        GAUSS,
        "mean-nan",
        lambda d: validate_radar(kde_model(d), baseline=gauss_model(d, mean=lambda a: a * np.nan)),
        "'mean'",
    ),
    C(GAUSS, "edges-missing", lambda d: validate_radar(kde_model(d), baseline=gauss_model(d, edges=None)), "'edges'"),
    C(
        GAUSS,
        "p_detect-shape",
        lambda d: validate_radar(kde_model(d), baseline=gauss_model(d, p_detect=lambda a: a[:1])),
        "'p_detect'",
    ),
    C(
        GAUSS,
        "a-kde-file-as-baseline",
        lambda d: validate_radar(kde_model(d), baseline=mutate_model(SHIPPED / "radar_kde.npz", d / "base.npz")),
        "'kind'",
    ),
    C(GAUSS, "baseline-missing", lambda d: validate_radar(kde_model(d), baseline=d / "base.npz"), "not found"),
    C(
        GAUSS,
        "params-lack-range_edges",
        lambda d: validate_radar(
            kde_model(d), baseline=gauss_model(d, header=lambda h: h["params"].pop("range_edges") and None)
        ),
        "'params.range_edges'",
    ),
]

LMODEL = "lidar model file"
CASES += [
    C(LMODEL, "header-json-list", lambda d: validate_lidar(lidar_model(d, header=lambda h: [h])), "'__header__'"),
    C(
        LMODEL,
        "lacks-params",
        lambda d: validate_lidar(lidar_model(d, header=lambda h: h.pop("params") and None)),
        "'params'",
    ),
    C(LMODEL, "lacks-h", lambda d: validate_lidar(lidar_model(d, header=lambda h: h.pop("h") and None)), "'h'"),
    C(LMODEL, "tables-nan", lambda d: validate_lidar(lidar_model(d, tables=lambda a: a * np.nan)), "'tables'"),
    C(LMODEL, "tables-3d", lambda d: validate_lidar(lidar_model(d, tables=lambda a: a[0])), "'tables'"),
    C(LMODEL, "tables-shape", lambda d: validate_lidar(lidar_model(d, tables=lambda a: a[:, :3])), "'tables'"),
    C(LMODEL, "bearings-missing", lambda d: validate_lidar(lidar_model(d, bearings=None)), "'bearings'"),
    C(
        LMODEL,
        "param-names-wrong",
        lambda d: validate_lidar(lidar_model(d, header=lambda h: h.update(param_names=["x"]))),
        "'param_names'",
    ),
    C(
        LMODEL,
        "format-version-0",
        lambda d: validate_lidar(lidar_model(d, header=lambda h: h.update(format_version=0))),
        "'format_version'",
    ),
    C(
        LMODEL,
        "kind-wrong",
        lambda d: validate_lidar(lidar_model(d, header=lambda h: h.update(kind="radar_kde"))),
        "'kind'",
    ),
    C(
        LMODEL,
        "truncated",
        lambda d: validate_lidar(_bytes(d / "lidar.npz", (SHIPPED / "neato_lidar.npz").read_bytes()[:50000])),
        "not a readable model file",
    ),
    C(
        LMODEL,
        "a-radar-model",
        lambda d: validate_lidar(mutate_model(SHIPPED / "radar_kde.npz", d / "lidar.npz")),
        "'kind'",
    ),
]

LNPZ = "lidar log .npz"
CASES += [
    C(LNPZ, "ranges-missing", lambda d: fit_lidar(lidar_npz(d, ranges=None)), "'ranges'"),
    C(LNPZ, "ranges-negative", lambda d: fit_lidar(lidar_npz(d, ranges=-lidar_arrays()["ranges"])), "'ranges'"),
    C(LNPZ, "ranges-inf", lambda d: fit_lidar(lidar_npz(d, ranges=lidar_arrays()["ranges"] * np.inf)), "'ranges'"),
    C(
        LNPZ,
        "ranges-complex",
        lambda d: fit_lidar(lidar_npz(d, ranges=lidar_arrays()["ranges"] * (1 + 1j))),
        "'ranges'",
    ),
    C(LNPZ, "ranges-1d", lambda d: fit_lidar(lidar_npz(d, ranges=np.ones(5))), "'ranges'"),
    C(LNPZ, "ranges-empty", lambda d: fit_lidar(lidar_npz(d, ranges=np.zeros((3, 8, 0)))), "'ranges'"),
    C(LNPZ, "ranges-all-nan", lambda d: fit_lidar(lidar_npz(d, ranges=np.full((3, 8, 2), np.nan))), "'ranges'"),
    C(LNPZ, "ranges-strings", lambda d: fit_lidar(lidar_npz(d, ranges=np.array(["a", "b"]))), "'ranges'"),
    C(LNPZ, "bearings-shape", lambda d: fit_lidar(lidar_npz(d, bearings=np.zeros(5))), "'bearings'"),
    C(LNPZ, "bearings-nan", lambda d: fit_lidar(lidar_npz(d, bearings=np.full(8, np.nan))), "'bearings'"),
    C(LNPZ, "poses-shape", lambda d: fit_lidar(lidar_npz(d, poses=np.zeros((2, 3)))), "'poses'"),
    C(LNPZ, "poses-nan", lambda d: fit_lidar(lidar_npz(d, poses=np.full((3, 3), np.nan))), "'poses'"),
    C(LNPZ, "map-missing", lambda d: fit_lidar(lidar_npz(d, map_segments=None)), "'map_segments'"),
    C(LNPZ, "map-nan", lambda d: fit_lidar(lidar_npz(d, map_segments=SEGS * np.nan)), "'map_segments'"),
    C(LNPZ, "map-zero-length", lambda d: fit_lidar(lidar_npz(d, map_segments=np.zeros((1, 2, 2)))), "'map_segments'"),
    C(LNPZ, "t-length", lambda d: fit_lidar(lidar_npz(d, t=np.zeros(2))), "'t'"),
    C(LNPZ, "covariate-length", lambda d: fit_lidar(lidar_npz(d, cov_speed=np.zeros(7))), "'cov_speed'"),
    C(
        LNPZ,
        "pickled-array",
        lambda d: fit_lidar(lidar_npz(d, poses=np.array([{"x": 1}], dtype=object))),
        "not a readable",
    ),
    C(LNPZ, "not-a-zip", lambda d: fit_lidar(_bytes(d / "log.npz", b"PK not really")), "not a readable"),
    C(LNPZ, "one-pose-too-few-for-folds", lambda d: fit_lidar(save_log(_one_pose_log(), d / "log.npz")), "n_folds"),
]


def _one_pose_log():
    a = lidar_arrays()
    return log_from_arrays(a["ranges"][:1], a["bearings"], a["poses"][:1], a["map_segments"])


def _gz(p: Path, text: str) -> Path:
    with gzip.open(p, "wt") as f:
        f.write(text)
    return p


CARMEN = "CARMEN log"
CASES += [
    C(
        CARMEN,
        "truncated-gz",
        lambda d: fit_lidar(_bytes(d / "log.gz", _gz(d / "full.gz", flaser() * 400).read_bytes()[:-30])),
        "truncated",
    ),
    C(CARMEN, "not-gzip-gz", lambda d: fit_lidar(carmen(d, flaser(), "log.gz")), "gzip"),
    C(
        CARMEN,
        "latin1-bytes",
        lambda d: fit_lidar(_bytes(d / "log.log", ("# café\n" + flaser()).encode("latin-1"))),
        "UTF-8",
    ),
    C(CARMEN, "no-laser-lines", lambda d: fit_lidar(carmen(d, "ODOM 0 0 0 0 0 0 1.0 h 1.0\n")), "'ranges'"),
    C(CARMEN, "empty-file", lambda d: fit_lidar(carmen(d, "")), "'ranges'"),
    C(CARMEN, "empty-gz", lambda d: fit_lidar(_gz(d / "log.gz", "")), "'ranges'"),
    C(CARMEN, "word-for-range", lambda d: fit_lidar(carmen(d, flaser(4, "1.0 x 2.0 3.0"))), "'ranges'"),
    C(CARMEN, "count-beyond-line", lambda d: fit_lidar(carmen(d, "FLASER 400 1.0 2.0\n")), "'ranges'"),
    C(CARMEN, "scans-differ-in-size", lambda d: fit_lidar(carmen(d, flaser(4) + flaser(5))), "'ranges'"),
    C(CARMEN, "one-beam", lambda d: fit_lidar(carmen(d, flaser(1))), "'ranges'"),
    C(CARMEN, "complex-range", lambda d: fit_lidar(carmen(d, flaser(4, "1.0 1+2j 2.0 3.0"))), "'ranges'"),
    C(CARMEN, "negative-count", lambda d: fit_lidar(carmen(d, "FLASER -3 1.0\n")), "'ranges'"),
    C(CARMEN, "all-ranges-nan", lambda d: fit_lidar(carmen(d, flaser(4, "nan nan nan nan") * 2)), "'ranges'"),
]

BAG = "ROS bag"
CASES += [
    C(BAG, "empty-bag", lambda d: fit_lidar(_bytes(d / "log.bag", b"")), "ROS bag"),
    C(
        BAG,
        "truncated-bag",
        lambda d: fit_lidar(_bytes(d / "log.bag", bag(d, "full.bag").read_bytes()[:3000])),
        "ROS bag",
    ),
    C(BAG, "random-bytes-bag", lambda d: fit_lidar(_bytes(d / "log.bag", bytes(range(256)) * 8)), "ROS bag"),
    C(BAG, "bag-without-scan", lambda d: fit_lidar(bag(d, topics=("/odom",))), "'/scan'"),
    C(BAG, "bag-without-odom", lambda d: fit_lidar(bag(d, topics=("/scan",))), "'/odom'"),
]

MAP = "map file"
PGM_OK = b"P5\n6 5\n255\n" + bytes(30)
CASES += [
    C(MAP, "pgm-maxval-0", lambda d: record_lidar_pgm(ros_map(d, pgm=b"P5\n6 5\n0\n" + bytes(30))), "'maxval'"),
    C(MAP, "pgm-truncated-pixels", lambda d: record_lidar_pgm(ros_map(d, pgm=PGM_OK[:20])), "pixel data"),
    C(
        MAP,
        "pgm-header-garbage",
        lambda d: record_lidar_pgm(ros_map(d, pgm=b"P5\nsix five\n255\n" + bytes(30))),
        "PGM header",
    ),
    C(MAP, "pgm-header-cut", lambda d: record_lidar_pgm(ros_map(d, pgm=b"P5\n6")), "PGM header"),
    C(MAP, "pgm-zero-width", lambda d: record_lidar_pgm(ros_map(d, pgm=b"P5\n0 5\n255\n")), "'width'"),
    C(MAP, "image-not-an-image", lambda d: record_lidar_pgm(ros_map(d, pgm=b"not an image")), "map image"),
    C(
        MAP,
        "occupied_thresh-null",
        lambda d: record_lidar_map(ros_yaml(d, occupied_thresh="null")),
        "'occupied_thresh'",
    ),
    C(MAP, "occupied_thresh-5", lambda d: record_lidar_map(ros_yaml(d, occupied_thresh="5")), "'occupied_thresh'"),
    C(
        MAP,
        "occupied_thresh-word",
        lambda d: record_lidar_map(ros_yaml(d, occupied_thresh="high")),
        "'occupied_thresh'",
    ),
    C(MAP, "resolution-0", lambda d: record_lidar_map(ros_yaml(d, resolution="0")), "'resolution'"),
    C(MAP, "resolution-word", lambda d: record_lidar_map(ros_yaml(d, resolution="fine")), "'resolution'"),
    C(MAP, "resolution-null", lambda d: record_lidar_map(ros_yaml(d, resolution="null")), "'resolution'"),
    C(MAP, "origin-two-values", lambda d: record_lidar_map(ros_yaml(d, origin="[0.0, 0.0]")), "'origin'"),
    C(MAP, "origin-words", lambda d: record_lidar_map(ros_yaml(d, origin="[a, b, c]")), "'origin'"),
    C(MAP, "negate-7", lambda d: record_lidar_map(ros_yaml(d, negate="7")), "'negate'"),
    C(MAP, "image-missing", lambda d: record_lidar_map(ros_yaml(d, image="nope.pgm")), "'image'"),
    C(MAP, "yaml-broken", lambda d: record_lidar_map(_bytes(d / "map.yaml", b"image: [unclosed\n")), "YAML"),
    C(MAP, "text-map-three-numbers", lambda d: record_lidar_map(_bytes(d / "map.txt", b"0 0 4\n")), "x1 y1 x2 y2"),
    C(MAP, "text-map-empty", lambda d: record_lidar_map(_bytes(d / "map.txt", b"# nothing\n")), "no segments"),
    C(
        MAP,
        "text-map-latin1",
        lambda d: record_lidar_map(_bytes(d / "map.txt", "# caf\xe9\n0 0 4 0\n".encode("latin-1"))),
        "cannot read",
    ),
    C(MAP, "json-map-no-segments", lambda d: record_lidar_map(_bytes(d / "map.json", b'{"name": "x"}')), "'segments'"),
    C(
        MAP,
        "json-map-nan",
        lambda d: record_lidar_map(_bytes(d / "map.json", b'{"segments": [[0, 0, NaN, 0]]}')),
        "'segments'",
    ),
    C(
        MAP,
        "json-map-words",
        lambda d: record_lidar_map(_bytes(d / "map.json", b'{"segments": [["a", 0, 1, 0]]}')),
        "'segments'",
    ),
    C(MAP, "unknown-map-name", lambda d: record_lidar_map(d / "no_such_map"), "built-in map"),
]

ASTYX = "Astyx folder"
CASES += [
    C(
        ASTYX,
        "objects-is-5",
        lambda d: record_astyx(astyx(d, gt='{"objects": 5}'), d / "astyx" / "groundtruth_obj3d" / "000000.json"),
        "'objects'",
    ),
    C(
        ASTYX,
        "json-broken",
        lambda d: record_astyx(astyx(d, gt='{"objects": [}'), d / "astyx" / "groundtruth_obj3d" / "000000.json"),
        "JSON",
    ),
    C(
        ASTYX,
        "json-is-a-list",
        lambda d: record_astyx(astyx(d, gt="[1, 2]"), d / "astyx" / "groundtruth_obj3d" / "000000.json"),
        "'objects'",
    ),
    C(
        ASTYX,
        "json-latin1",
        lambda d: record_astyx(
            astyx(d), _bytes(d / "astyx" / "groundtruth_obj3d" / "000000.json", '{"n": "é"}'.encode("latin-1"))
        ),
        "JSON",
    ),
    C(
        ASTYX,
        "stray-file",
        lambda d: record_astyx(
            astyx(d, extra={"radar_6455/notes.txt": "hi"}), d / "astyx" / "radar_6455" / "notes.txt"
        ),
        "frame file",
    ),
    C(
        ASTYX,
        "object-lacks-center3d",
        lambda d: record_astyx(astyx_obj(d, center3d=None), d / "astyx" / "groundtruth_obj3d" / "000000.json"),
        "'center3d'",
    ),
    C(
        ASTYX,
        "center3d-nan",
        lambda d: record_astyx(
            astyx_obj(d, center3d=[float("nan"), 1.0, 0.5]), d / "astyx" / "groundtruth_obj3d" / "000000.json"
        ),
        "center3d",
    ),
    C(
        ASTYX,
        "center3d-words",
        lambda d: record_astyx(
            astyx_obj(d, center3d=["a", 1.0, 0.5]), d / "astyx" / "groundtruth_obj3d" / "000000.json"
        ),
        "object 0",
    ),
    C(ASTYX, "center3d-1e12", lambda d: record_astyx(astyx_obj(d, center3d=[1e12, 1.0, 0.5])), "'center3d'"),
    C(ASTYX, "dimension3d-1e9", lambda d: record_astyx(astyx_obj(d, dimension3d=[1e9, 1.8, 1.5])), "'dimension3d'"),
    C(
        ASTYX,
        "radar-four-columns",
        lambda d: record_astyx(astyx(d, pc="\nX Y Z V_r Mag\n1 2 3 4\n"), d / "astyx" / "radar_6455" / "000000.txt"),
        "5 columns",
    ),
    C(
        ASTYX,
        "radar-words",
        lambda d: record_astyx(astyx(d, pc="\nX Y Z V_r Mag\n1 2 x 4 5\n"), d / "astyx" / "radar_6455" / "000000.txt"),
        "5 numbers",
    ),
    C(
        ASTYX,
        "radar-nan",
        lambda d: record_astyx(
            astyx(d, pc="\nX Y Z V_r Mag\n1 2 nan 4 5\n"), d / "astyx" / "radar_6455" / "000000.txt"
        ),
        "NaN",
    ),
    C(ASTYX, "no-radar-folder", lambda d: record_astyx(_mkdir(d / "astyx")), "'radar_6455'"),
    C(
        ASTYX,
        "frame-without-json",
        lambda d: record_astyx(
            astyx(d, extra={"radar_6455/000001.txt": "\nX Y Z V_r Mag\n"}),
            d / "astyx" / "groundtruth_obj3d" / "000001.json",
        ),
        "not found",
    ),
]
