"""Valid pieces of every input and the case type of the hand-written bad-input table.

The table itself: :mod:`sensor_envs.testing.bad_files` and :mod:`sensor_envs.testing.bad_options`.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.modelio import default_model_path

SHIPPED = default_model_path("radar_kde.npz").parent

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
    """A radar log CSV ``d/name`` of ``header`` and ``rows`` (valid by default)."""
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
    """The arrays of a valid lidar ``.npz`` log."""
    rng = np.random.default_rng(0)
    return {
        "ranges": rng.uniform(0.5, 2.0, (3, 8, 4)),
        "bearings": np.linspace(0, 2 * np.pi, 8, endpoint=False),
        "poses": np.tile([2.0, 1.5, 0.1], (3, 1)),
        "map_segments": SEGS,
        "t": np.array([0.0, 1.0, 2.0]),
    }


def lidar_npz(d: Path, name: str = "log.npz", **change: object) -> Path:
    """A lidar ``.npz`` log ``d/name``, valid but for the arrays in ``change`` (``None`` drops one)."""
    a: dict[str, Any] = dict(lidar_arrays())
    for k, v in change.items():
        if v is None:
            a.pop(k)
        else:
            a[k] = v
    p = d / name
    np.savez(p, **a)
    return p


def flaser(n: int = 4, ranges: str | None = None) -> str:
    """One CARMEN FLASER line of ``n`` readings (``ranges``: their text)."""
    r = ranges if ranges is not None else " ".join(["1.5"] * n)
    return f"FLASER {n} {r} 1.0 2.0 0.3 1.0 2.0 0.3 12.5 host 12.5\n"


def carmen(d: Path, text: str, name: str = "log.log") -> Path:
    """A CARMEN log ``d/name`` holding ``text``."""
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
    """A copy of the shipped Gaussian radar file with an edited header and arrays."""
    return mutate_model(SHIPPED / "radar_gaussian.npz", d / "base.npz", header, **arrays)


def lidar_model(d: Path, header: Callable | None = None, **arrays: object) -> Path:
    """A copy of the shipped lidar model file with an edited header and arrays."""
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
    """A ROS map_server YAML (and its PGM) whose fields are replaced by ``fields`` (raw YAML text)."""
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
    """An Astyx folder of one frame whose one label has the fields of ``change`` (``None`` drops one)."""
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
    """``fit radar`` of ``p``; the message must name ``p``."""
    return ["fit", "radar", str(p), "--out", str(p.parent / "m.npz")], str(p)


def fit_lidar(p: Path) -> tuple[list[str], str]:
    """``fit lidar``; a CARMEN log or ROS bag needs its sensor's ``--max-range`` (no Neato default)."""
    rng = [] if p.suffix == ".npz" else ["--max-range", "5"]
    return ["fit", "lidar", str(p), "--out", str(p.parent / "m.npz"), *rng], str(p)


def validate_radar(model: Path, log: Path | None = None, baseline: Path | None = None) -> tuple[list[str], str]:
    """``validate radar`` of ``model`` (and ``log``, ``--baseline``); the message must name the bad file."""
    d = model.parent
    argv = ["validate", "radar", str(model), str(log or radar_csv(d)), "--out", str(d / "rep")]
    return argv + (["--baseline", str(baseline)] if baseline else []), str(baseline or model)


def validate_radar_log(log: Path) -> tuple[list[str], str]:
    """``validate radar`` of the shipped KDE model on the radar log ``log``."""
    argv, _ = validate_radar(kde_model(log.parent), log)
    return argv, str(log)


def validate_lidar(model: Path) -> tuple[list[str], str]:
    """``validate lidar`` of ``model`` on a valid lidar log."""
    d = model.parent
    return ["validate", "lidar", str(model), str(lidar_npz(d)), "--out", str(d / "rep")], str(model)


def record_lidar_map(p: Path) -> tuple[list[str], str]:
    """``record lidar --map p``."""
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
    """``record lidar --map`` of a ROS YAML whose PGM is the bad file."""
    argv, _ = record_lidar_map(yaml_path)
    return argv, str(yaml_path.parent / "map.pgm")


def record_astyx(root: Path, bad: Path | None = None) -> tuple[list[str], str]:
    """``record radar --astyx root``; the message must name ``bad`` (default: the folder)."""
    return ["record", "radar", "--astyx", str(root), "--out", str(root.parent / "astyx.csv")], str(bad or root)


def opt(argv: list[str], option: str) -> Callable[[Path], tuple[list[str], str]]:
    """A case maker of the fixed command line ``argv`` (``{d}``: the case folder) whose message names ``option``."""

    def make(d: Path) -> tuple[list[str], str]:
        return [a.replace("{d}", str(d)) for a in argv], option

    return make


def C(cls: str, id: str, make: Callable[[Path], tuple[list[str], str]], field: str) -> Case:
    """A :class:`Case` (short for the table)."""
    return Case(cls, id, make, field)


def _bytes(p: Path, data: bytes) -> Path:
    p.write_bytes(data)
    return p


def snapshot(d: Path) -> dict[str, str]:
    """Every file and folder under ``d`` with a hash of its content."""
    out = {}
    for p in sorted(d.rglob("*")):
        rel = str(p.relative_to(d))
        out[rel] = "dir" if p.is_dir() else hashlib.sha1(p.read_bytes()).hexdigest()
    return out
