"""Bad input, end to end: every CLI verb and every loader behind it, fed malformed files and options.

Each case builds its inputs in ``tmp_path`` from small valid pieces made here (and copies of the
shipped models), runs ``sensor-envs`` in-process and asserts: exit status 2, ONE line on stderr that
names the file (or option) and the field, no traceback, and not a single file created or changed.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.lidar.log import log_from_arrays, save_log

SHIPPED = Path(__file__).resolve().parents[1] / "models"

# ---------------------------------------------------------------------------------------------- valid pieces
RADAR_HEADER = "sequence,frame,t,target,ref_x,ref_y,ref_heading,ref_length,ref_width,meas_x,meas_y"
RADAR_ROWS = [
    "0,0,0.0,0,10.0,1.0,0.0,4.5,1.8,8.0,0.5",
    "0,1,1.0,0,11.0,1.0,0.0,4.5,1.8,9.0,0.4",
    "0,2,2.0,0,12.0,1.0,0.0,4.5,1.8,,",
    "0,1,1.0,-1,,,,,,20.0,-3.0",
    "1,0,0.0,0,15.0,-2.0,0.1,4.0,1.7,13.2,-1.5",
]
COLS = RADAR_HEADER.split(",")


def radar_csv(d: Path, name: str = "log.csv", header: str = RADAR_HEADER, rows: list[str] | None = None) -> Path:
    p = d / name
    p.write_text("\n".join([header, *(RADAR_ROWS if rows is None else rows)]) + "\n", encoding="utf-8")
    return p


def radar_cell(d: Path, row: int, col: str, value: str) -> Path:
    """The valid CSV with one cell replaced."""
    rows = [r.split(",") for r in RADAR_ROWS]
    rows[row][COLS.index(col)] = value
    return radar_csv(d, rows=[",".join(r) for r in rows])


SEGS = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]], dtype=float)


def lidar_arrays() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {
        "ranges": rng.uniform(0.5, 2.0, (3, 8, 4)),
        "bearings": np.linspace(0, 2 * np.pi, 8, endpoint=False),
        "poses": np.tile([2.0, 1.5, 0.1], (3, 1)),
        "map_segments": SEGS,
        "t": np.array([0.0, 1.0, 2.0]),
    }


def lidar_npz(d: Path, name: str = "log.npz", **change: object) -> Path:
    a: dict[str, object] = dict(lidar_arrays())
    for k, v in change.items():
        if v is None:
            a.pop(k)
        else:
            a[k] = v
    p = d / name
    np.savez(p, **a)
    return p


def flaser(n: int = 4, ranges: str | None = None) -> str:
    r = ranges if ranges is not None else " ".join(["1.5"] * n)
    return f"FLASER {n} {r} 1.0 2.0 0.3 1.0 2.0 0.3 12.5 host 12.5\n"


def carmen(d: Path, text: str, name: str = "log.log") -> Path:
    p = d / name
    p.write_text(text, encoding="utf-8")
    return p


def bag(d: Path, name: str = "log.bag", topics: tuple[str, ...] = ("/scan", "/odom")) -> Path:
    """A tiny ROS1 bag with LaserScan on /scan and Odometry on /odom (rosbags writer)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    t_ = ts.types
    scan_t, odom_t = t_["sensor_msgs/msg/LaserScan"], t_["nav_msgs/msg/Odometry"]
    vec = t_["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    p = d / name
    with Writer(p) as w:
        conns = {}
        if "/scan" in topics:
            conns["/scan"] = w.add_connection("/scan", scan_t.__msgtype__, typestore=ts)
        if "/odom" in topics:
            conns["/odom"] = w.add_connection("/odom", odom_t.__msgtype__, typestore=ts)
        for i in range(3):
            stamp = int((1 + i) * 1e9)
            hdr = t_["std_msgs/msg/Header"](
                seq=i, stamp=t_["builtin_interfaces/msg/Time"](sec=1 + i, nanosec=0), frame_id="b"
            )
            if "/odom" in conns:
                pose = t_["geometry_msgs/msg/Pose"](
                    position=t_["geometry_msgs/msg/Point"](x=1.0, y=1.0, z=0.0),
                    orientation=t_["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                )
                msg = odom_t(
                    header=hdr,
                    child_frame_id="b",
                    pose=t_["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                    twist=t_["geometry_msgs/msg/TwistWithCovariance"](
                        twist=t_["geometry_msgs/msg/Twist"](linear=vec, angular=vec), covariance=np.zeros(36)
                    ),
                )
                w.write(conns["/odom"], stamp, ts.serialize_ros1(msg, odom_t.__msgtype__))
            if "/scan" in conns:
                msg = scan_t(
                    header=hdr,
                    angle_min=0.0,
                    angle_max=np.pi,
                    angle_increment=np.pi / 3,
                    time_increment=0.0,
                    scan_time=0.1,
                    range_min=0.1,
                    range_max=5.0,
                    ranges=np.array([1.0, 2.0, 0.0, 3.0], dtype=np.float32),
                    intensities=np.zeros(4, dtype=np.float32),
                )
                w.write(conns["/scan"], stamp + 1000, ts.serialize_ros1(msg, scan_t.__msgtype__))
    return p


def mutate_model(src: Path, dst: Path, header: Callable[[dict], object] | None = None, **arrays: object) -> Path:
    """Copy model file ``src`` to ``dst`` with the JSON header and/or arrays changed (``None`` drops an array)."""
    with np.load(src, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    if header is not None:
        h = json.loads(data["__header__"].tobytes().decode("utf-8"))
        new = header(h)
        h = h if new is None else new
        data["__header__"] = np.frombuffer(json.dumps(h).encode("utf-8"), dtype=np.uint8)
    for k, v in arrays.items():
        if v is None:
            data.pop(k)
        elif callable(v):
            data[k] = v(data[k])
        else:
            data[k] = v
    np.savez(dst, **data)
    return dst


def kde_model(d: Path, name: str = "kde.npz", header: Callable | None = None, **arrays: object) -> Path:
    """A copy of the shipped KDE model (with its Gaussian baseline beside it), optionally damaged."""
    shutil.copy(SHIPPED / "radar_gaussian.npz", d / (Path(name).stem + "_gaussian.npz"))
    return mutate_model(SHIPPED / "radar_kde.npz", d / name, header, **arrays)


def gauss_model(d: Path, header: Callable | None = None, **arrays: object) -> Path:
    return mutate_model(SHIPPED / "radar_gaussian.npz", d / "base.npz", header, **arrays)


def lidar_model(d: Path, header: Callable | None = None, **arrays: object) -> Path:
    return mutate_model(SHIPPED / "neato_lidar.npz", d / "lidar.npz", header, **arrays)


def ros_map(d: Path, yaml_text: str | None = None, pgm: bytes | None = None) -> Path:
    """A 6 x 5 ROS map_server map (a closed box of occupied cells), YAML and PGM."""
    img = np.full((5, 6), 254, dtype=np.uint8)
    img[0, :] = img[-1, :] = img[:, 0] = img[:, -1] = 0
    (d / "map.pgm").write_bytes(pgm if pgm is not None else b"P5\n6 5\n255\n" + img.tobytes())
    y = d / "map.yaml"
    y.write_text(
        yaml_text
        if yaml_text is not None
        else "image: map.pgm\nresolution: 0.5\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\n"
    )
    return y


def ros_yaml(d: Path, **fields: str) -> Path:
    base = {
        "image": "map.pgm",
        "resolution": "0.5",
        "origin": "[0.0, 0.0, 0.0]",
        "negate": "0",
        "occupied_thresh": "0.65",
    }
    base.update(fields)
    return ros_map(d, "".join(f"{k}: {v}\n" for k, v in base.items()))


def astyx(d: Path, gt: str | None = None, pc: str | None = None, extra: dict[str, str] | None = None) -> Path:
    """A one-frame Astyx HiRes2019 folder (one car and two detections on it)."""
    root = d / "astyx"
    (root / "radar_6455").mkdir(parents=True)
    (root / "groundtruth_obj3d").mkdir()
    (root / "radar_6455" / "000000.txt").write_text(
        pc if pc is not None else "\nX Y Z V_r Mag\n10.0 1.0 0.0 0.0 50.0\n10.5 1.2 0.0 0.0 40.0\n"
    )
    obj = {
        "center3d": [12.0, 1.0, 0.5],
        "dimension3d": [4.5, 1.8, 1.5],
        "orientation_quat": [1.0, 0.0, 0.0, 0.0],
        "classname": "Car",
    }
    (root / "groundtruth_obj3d" / "000000.json").write_text(gt if gt is not None else json.dumps({"objects": [obj]}))
    for rel, text in (extra or {}).items():
        (root / rel).write_text(text)
    return root


def astyx_obj(d: Path, **change: object) -> Path:
    obj: dict[str, object] = {
        "center3d": [12.0, 1.0, 0.5],
        "dimension3d": [4.5, 1.8, 1.5],
        "orientation_quat": [1.0, 0.0, 0.0, 0.0],
        "classname": "Car",
    }
    for k, v in change.items():
        if v is None:
            obj.pop(k)
        else:
            obj[k] = v
    return astyx(d, gt=json.dumps({"objects": [obj]}))


# ---------------------------------------------------------------------------------------------- cases
@dataclass(frozen=True)
class Case:
    """A malformed input: ``make(d)`` builds the files in ``d`` and returns ``(argv, bad path or option)``."""

    cls: str  # class of bad input (for the closing count)
    id: str
    make: Callable[[Path], tuple[list[str], str]]
    field: str  # what the one-line message must name besides the file


def fit_radar(p: Path) -> tuple[list[str], str]:
    return ["fit", "radar", str(p), "--out", str(p.parent / "m.npz")], str(p)


def fit_lidar(p: Path) -> tuple[list[str], str]:
    """``fit lidar``; a CARMEN log or ROS bag needs its sensor's ``--max-range`` (no Neato default)."""
    rng = [] if p.suffix == ".npz" else ["--max-range", "5"]
    return ["fit", "lidar", str(p), "--out", str(p.parent / "m.npz"), *rng], str(p)


def validate_radar(model: Path, log: Path | None = None, baseline: Path | None = None) -> tuple[list[str], str]:
    d = model.parent
    argv = ["validate", "radar", str(model), str(log or radar_csv(d)), "--out", str(d / "rep")]
    return argv + (["--baseline", str(baseline)] if baseline else []), str(baseline or model)


def validate_radar_log(log: Path) -> tuple[list[str], str]:
    argv, _ = validate_radar(kde_model(log.parent), log)
    return argv, str(log)


def validate_lidar(model: Path) -> tuple[list[str], str]:
    d = model.parent
    return ["validate", "lidar", str(model), str(lidar_npz(d)), "--out", str(d / "rep")], str(model)


def record_lidar_map(p: Path) -> tuple[list[str], str]:
    return [
        "record",
        "lidar",
        "--map",
        str(p),
        "--out",
        str(p.parent / "rec.npz"),
        "--poses",
        "2",
        "--repeats",
        "2",
    ], str(p)


def record_lidar_pgm(yaml_path: Path) -> tuple[list[str], str]:
    argv, _ = record_lidar_map(yaml_path)
    return argv, str(yaml_path.parent / "map.pgm")


def record_astyx(root: Path, bad: Path | None = None) -> tuple[list[str], str]:
    return ["record", "radar", "--astyx", str(root), "--out", str(root.parent / "astyx.csv")], str(bad or root)


def opt(argv: list[str], option: str) -> Callable[[Path], tuple[list[str], str]]:
    def make(d: Path) -> tuple[list[str], str]:
        return [a.replace("{d}", str(d)) for a in argv], option

    return make


def C(cls: str, id: str, make: Callable[[Path], tuple[list[str], str]], field: str) -> Case:
    return Case(cls, id, make, field)


def _bytes(p: Path, data: bytes) -> Path:
    p.write_bytes(data)
    return p


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
        lambda d: record_astyx(astyx(d, pc="\nX Y Z V_r\n1 2 3 4\n"), d / "astyx" / "radar_6455" / "000000.txt"),
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


def snapshot(d: Path) -> dict[str, str]:
    """Every file and folder under ``d`` with a hash of its content."""
    out = {}
    for p in sorted(d.rglob("*")):
        rel = str(p.relative_to(d))
        out[rel] = "dir" if p.is_dir() else hashlib.sha1(p.read_bytes()).hexdigest()
    return out


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


@pytest.mark.parametrize("case", CASES, ids=[f"{c.cls.split()[0]}-{c.id}" for c in CASES])
def test_bad_input_ends_in_one_line_and_exit_2_and_touches_nothing(case: Case, tmp_path: Path, capsys) -> None:
    argv, names = case.make(tmp_path)
    before = snapshot(tmp_path)
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert names in lines[0], f"message does not name {names!r}: {lines[0]}"
    assert case.field in lines[0], f"message does not name {case.field!r}: {lines[0]}"
    assert snapshot(tmp_path) == before, "a file was created or changed"


def test_the_suite_covers_more_than_100_bad_inputs_of_every_class() -> None:
    classes = {c.cls for c in CASES}
    assert len(CASES) >= 100
    assert classes == {RADAR, KDE, GAUSS, LMODEL, LNPZ, CARMEN, BAG, MAP, ASTYX, OPTION, OUTPUT, RIG, LRIG}
