"""Valid pieces of every input format and the generated mutations applied to them (for :mod:`fuzz_cases`).

A *chooser* is anything with ``integers(lo, hi)`` (inclusive) and ``choice(seq)``: hypothesis draws the
choices in the test suite, a seeded ``random.Random`` in ``benchmarks/fuzz_inputs.py``.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sensor_envs.modelio import default_model_path

SHIPPED = default_model_path("radar_kde.npz").parent
"""The shipped models folder (package ``sensor_envs.models``)."""


class Chooser(Protocol):
    """Draws the choices of a generator (hypothesis in tests, ``random.Random`` in the benchmark)."""

    def integers(self, lo: int, hi: int) -> int:
        """An integer in ``[lo, hi]`` (both inclusive)."""
        ...

    def choice(self, seq: Sequence[Any]) -> Any:
        """One element of ``seq``."""
        ...


class DrawnChooser:
    """A :class:`Chooser` whose choices hypothesis draws (and shrinks), from a test's ``st.data()``."""

    def __init__(self, data: Any) -> None:
        self.data = data

    def integers(self, lo: int, hi: int) -> int:
        """An integer in ``[lo, hi]`` drawn by hypothesis."""
        from hypothesis import strategies as st  # the test extra: imported by the tests that draw only

        return int(self.data.draw(st.integers(lo, hi)))

    def choice(self, seq: Sequence[Any]) -> Any:
        """One element of ``seq`` drawn by hypothesis."""
        from hypothesis import strategies as st

        return self.data.draw(st.sampled_from(list(seq)))


@dataclass
class Case:
    """One generated case: the command line, the loader behind it and whether it must be refused."""

    family: str
    mutation: str
    argv: list[str]
    load: Callable[[], Any] | None  # the reader behind the command (None: options only)
    must_refuse: bool
    inputs: list[Path]
    command_when_loaded: bool = True  # False: an input the loader takes is not also run through the command
    kind: str = ""  # Python API cases: "env", "radar", "lidar" or "checked" (how a result is judged); "" for files
    must_name: tuple[str, ...] = ()  # the error line must hold one of these (the option at fault), else "vague"


# ------------------------------------------------------------------------------------------- valid pieces
RADAR_HEADER = "sequence,frame,t,target,ref_x,ref_y,ref_heading,ref_length,ref_width,meas_x,meas_y,rcs"


def radar_rows(n_seq: int = 3, n_frames: int = 6) -> list[str]:
    """Rows of a valid radar log CSV (a missed detection every fourth frame, one clutter row per sequence)."""
    rows = []
    for s in range(n_seq):
        for f in range(n_frames):
            x = 10.0 + 2 * s + 0.5 * f
            meas = f"{x - 2.2:.2f},{0.4 + 0.1 * s:.2f}" if f % 4 != 3 else ","
            rows.append(f"{s},{f},{f * 1.0:.1f},{s},{x:.2f},1.0,0.1,4.5,1.8,{meas},{1.0 + f}")
        rows.append(f"{s},0,0.0,-1,,,,,,25.0,-3.0,")
    return rows


def write_radar_csv(d: Path) -> Path:
    """A valid radar log ``d/log.csv``."""
    p = d / "log.csv"
    p.write_text("\n".join([RADAR_HEADER, *radar_rows()]) + "\n", encoding="utf-8")
    return p


SEGS = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]], dtype=float)


def lidar_arrays() -> dict[str, np.ndarray]:
    """The arrays of a valid lidar ``.npz`` log (4 poses x 8 bearings x 3 repeats in a 4 x 3 m box)."""
    rng = np.random.default_rng(0)
    return {
        "ranges": rng.uniform(0.5, 2.0, (4, 8, 3)),
        "bearings": np.linspace(0, 2 * np.pi, 8, endpoint=False),
        "poses": np.array([[2.0, 1.5, 0.1], [2.2, 1.4, 0.3], [1.8, 1.6, -0.2], [2.0, 1.2, 1.0]]),
        "map_segments": SEGS.copy(),  # a copy: mutations edit arrays in place
        "t": np.array([0.0, 1.0, 2.0, 3.0]),
    }


def write_npz(p: Path, arrays: dict[str, Any]) -> Path:
    """``arrays`` saved as ``p`` (``np.savez``)."""
    np.savez(p, **arrays)
    return p


def carmen_text(n: int = 5) -> str:
    """A valid CARMEN log of ``n`` FLASER lines."""
    lines = []
    for i in range(n):
        r = " ".join(f"{1.0 + 0.1 * ((i + k) % 7):.2f}" for k in range(8))
        lines.append(f"FLASER 8 {r} {1.0 + 0.1 * i} 1.5 0.1 {1.0 + 0.1 * i} 1.5 0.1 {10.0 + i} host {10.0 + i}")
    return "# a CARMEN log\n" + "\n".join(lines) + "\n"


MAP_TXT = "0 0 4 0\n4 0 4 3\n4 3 0 3\n0 3 0 0\n1 1 2 1\n"
MAP_JSON = json.dumps({"name": "box", "segments": [[0, 0, 4, 0], [4, 0, 4, 3], [4, 3, 0, 3], [0, 3, 0, 0]]})
MAP_YAML = "segments:\n  - [0, 0, 4, 0]\n  - [4, 0, 4, 3]\n  - [4, 3, 0, 3]\n  - [0, 3, 0, 0]\n"
ROS_YAML = (
    "image: map.pgm\nresolution: 0.5\norigin: [0.0, 0.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
)


def pgm_bytes() -> bytes:
    """A valid 10 x 8 binary PGM map (walls around a free room)."""
    img = np.full((8, 10), 254, dtype=np.uint8)
    img[0, :] = img[-1, :] = img[:, 0] = img[:, -1] = 0
    return b"P5\n10 8\n255\n" + img.tobytes()


def write_astyx(d: Path, pc: str | None = None, gt: str | None = None, name: str = "000000") -> Path:
    """An Astyx folder ``d/astyx`` of one frame (point cloud ``pc`` and labels ``gt``, valid by default)."""
    root = d / "astyx"
    (root / "radar_6455").mkdir(parents=True, exist_ok=True)
    (root / "groundtruth_obj3d").mkdir(exist_ok=True)
    write_text_bytes(
        root / "radar_6455" / f"{name}.txt",
        pc if pc is not None else "\nX Y Z V_r Mag\n10.0 1.0 0.0 0.0 50.0\n10.5 1.2 0.0 0.0 40.0\n",
    )
    obj = {"center3d": [12.0, 1.0, 0.5], "dimension3d": [4.5, 1.8, 1.5], "orientation_quat": [1, 0, 0, 0]}
    obj["classname"] = "Car"
    write_text_bytes(
        root / "groundtruth_obj3d" / f"{name}.json", gt if gt is not None else json.dumps({"objects": [obj]})
    )
    return root


# ----------------------------------------------------------------------------------------------- mutations
NASTY_TOKENS = ["nan", "inf", "-inf", "abc", "1_0.5", "1e300", "-1e300", "0x10", "--1", "1e", "١", "\x00", "�"]
"""Tokens that are no valid value of any numeric field (a field holding one must be refused)."""
NASTY_JSON: list[Any] = [True, None, "x", [], {}, 1e308, -1, [[[[[[[[1]]]]]]]], "NaN", 10**30]
"""JSON values that are no valid hyperparameter / format field."""


def deep(k: int, open_: str = "[", close: str = "]") -> str:
    """``k`` nested brackets."""
    return open_ * k + close * k


def text_mutation(c: Chooser, text: str, numeric_tokens: bool) -> tuple[str, str, bool]:
    """A mutated ``text`` (name, new text, must_refuse)."""
    kind = c.choice(["truncate", "token", "nul", "long", "quote", "nonutf8", "dupline", "delline", "deep"])
    if kind == "truncate":
        k = c.integers(0, max(len(text) - 1, 0))
        return "truncate", text[:k], False
    lines = text.splitlines(keepends=True)
    i = c.integers(0, max(len(lines) - 1, 0))
    if kind == "dupline":
        return "duplicate line", "".join(lines[: i + 1] + [lines[i]] * c.integers(1, 3) + lines[i + 1 :]), False
    if kind == "delline":
        return "delete line", "".join(lines[:i] + lines[i + 1 :]), False
    if kind == "token":
        tokens = text.replace(",", " , ").split(" ")
        numeric = [j for j, t in enumerate(tokens) if _is_number(t.strip())]
        if not numeric:
            return "token", text + c.choice(NASTY_TOKENS), False
        j = c.choice(numeric)
        tok = c.choice(NASTY_TOKENS)
        tokens[j] = tok + ("\n" if tokens[j].endswith("\n") else "")
        return f"token {tok!r}", " ".join(tokens).replace(" , ", ","), numeric_tokens
    pos = c.integers(0, len(text))
    insert = {
        "nul": "\x00",
        "long": "9" * 200_000 + "x",  # a token no number parser takes (a long digit string alone may be valid)
        "quote": '"',
        "nonutf8": "\udcff",
        "deep": deep(c.choice([50, 1000, 100_000])),
    }[kind]
    must = kind == "nonutf8" or (kind in ("nul", "deep", "long") and numeric_tokens)  # CARMEN: comment lines
    return kind, text[:pos] + insert + text[pos:], must


def _is_number(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return bool(t)


def write_text_bytes(p: Path, text: str) -> Path:
    """``text`` written as UTF-8 (lone surrogates as the raw bytes they stand for)."""
    p.write_bytes(text.encode("utf-8", errors="surrogateescape"))
    return p


def array_mutation(
    c: Chooser, arrays: dict[str, Any], required: Sequence[str], optional: Sequence[str] = ()
) -> tuple[str, bool]:
    """Mutate ``arrays`` in place; returns (name, must_refuse)."""
    key = c.choice(list(required))
    a = np.asarray(arrays[key])
    kind = c.choice(["drop", "bool", "complex", "str", "float16", "shape", "nan", "inf", "huge", "neg", "const", "rev"])
    if kind == "drop":
        arrays.pop(key)
        return f"drop {key}", key not in optional
    if kind == "bool":
        arrays[key] = a.astype(bool)
        return f"{key} as bool", key not in FLAG_ARRAYS
    if kind == "complex":
        arrays[key] = a.astype(complex) + 1j
        return f"{key} as complex", True
    if kind == "str":
        arrays[key] = a.astype(str)
        return f"{key} as str", True
    if kind == "float16":
        arrays[key] = a.astype(np.float16)
        return f"{key} as float16", False
    if kind == "shape":
        arrays[key] = c.choice(
            [a[None], a.reshape(-1), a[..., :1] if a.ndim else a[None], np.zeros((0,) + a.shape[1:])]
        )
        new = np.shape(arrays[key])
        scan_log = key == "ranges" and len(new) in (2, 3) and new[:2] == a.shape[:2]  # (P, K) or (P, K, R)
        return f"{key} reshaped", new != a.shape and not scan_log
    flat = a.astype(np.float64).copy().reshape(-1)
    if flat.size == 0:
        return "noop", False
    j = c.integers(0, flat.size - 1)
    if kind == "const":
        flat[:] = flat[0]
        arrays[key] = flat.reshape(a.shape)
        return f"{key} constant", False
    if kind == "rev":
        arrays[key] = flat[::-1].reshape(a.shape)
        return f"{key} reversed", False
    flat[j] = {"nan": np.nan, "inf": np.inf, "huge": 1e300, "neg": -1e9}[kind]
    arrays[key] = flat.reshape(a.shape)
    return f"{key}[{j}] = {kind}", kind in ("inf", "huge", "neg") or key != "ranges"


FLAG_ARRAYS = ("new_track",)
"""Arrays of 0/1 flags (uint8 in the files): stored as bool they hold the same values (the loader takes both)."""

_BOMB: bytes | None = None


def npz_bomb() -> bytes:
    """A 2 MB ``.npz`` whose one array inflates to 2 GiB (zeros), built once per process."""
    global _BOMB
    if _BOMB is None:
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (2**28,)})
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
            with zf.open("ranges.npy", "w", force_zip64=True) as fh:
                fh.write(header.getvalue())
                chunk = bytes(2**24)
                for _ in range(2**31 // 2**24):
                    fh.write(chunk)
        _BOMB = buf.getvalue()
    return _BOMB


def special_path(c: Chooser, d: Path) -> tuple[str, Path]:
    """A path that is not a regular file: a FIFO, ``/dev/zero``, a folder."""
    kind = c.choice(["fifo", "devzero", "folder"])
    if kind == "fifo":
        p = d / "pipe.csv"
        os.mkfifo(p)
        return "FIFO", p
    if kind == "devzero":
        return "/dev/zero", Path("/dev/zero")
    p = d / "folder.npz"
    p.mkdir()
    return "folder", p


def write_bag(d: Path, scan: dict[str, Any] | None = None, quat: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0)) -> Path:
    """A small ROS1 bag: LaserScan on /scan (``scan`` overrides its fields) and Odometry on /odom."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    t_ = ts.types
    scan_t, odom_t = t_["sensor_msgs/msg/LaserScan"], t_["nav_msgs/msg/Odometry"]
    vec = t_["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    p = d / "log.bag"
    with Writer(p) as w:
        c_scan = w.add_connection("/scan", scan_t.__msgtype__, typestore=ts)
        c_odom = w.add_connection("/odom", odom_t.__msgtype__, typestore=ts)
        for i in range(4):
            stamp = int((1 + i) * 1e9)
            hdr = t_["std_msgs/msg/Header"](
                seq=i, stamp=t_["builtin_interfaces/msg/Time"](sec=1 + i, nanosec=0), frame_id="b"
            )
            x, y, z, qw = quat[1], quat[2], quat[3], quat[0]
            pose = t_["geometry_msgs/msg/Pose"](
                position=t_["geometry_msgs/msg/Point"](x=1.0 + 0.1 * i, y=1.0, z=0.0),
                orientation=t_["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=qw),
            )
            odom = odom_t(
                header=hdr,
                child_frame_id="b",
                pose=t_["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=t_["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t_["geometry_msgs/msg/Twist"](linear=vec, angular=vec), covariance=np.zeros(36)
                ),
            )
            w.write(c_odom, stamp, ts.serialize_ros1(odom, odom_t.__msgtype__))
            fields: dict[str, Any] = {
                "angle_min": 0.0,
                "angle_max": np.pi,
                "angle_increment": np.pi / 3,
                "time_increment": 0.0,
                "scan_time": 0.1,
                "range_min": 0.1,
                "range_max": 5.0,
                "ranges": np.array([1.0, 2.0, 0.0, 3.0], dtype=np.float32),
                "intensities": np.zeros(4, dtype=np.float32),
            }
            fields.update(scan or {})
            w.write(c_scan, stamp + 1000, ts.serialize_ros1(scan_t(header=hdr, **fields), scan_t.__msgtype__))
    return p


def snapshot(d: Path) -> dict[str, str]:
    """``relative path -> content digest`` of every regular file under ``d`` (FIFOs by name only)."""
    import hashlib
    import stat

    out = {}
    for p in sorted(d.rglob("*")):
        st = p.lstat()
        if stat.S_ISREG(st.st_mode):
            out[str(p.relative_to(d))] = hashlib.sha1(p.read_bytes()).hexdigest()
        elif not stat.S_ISDIR(st.st_mode):
            out[str(p.relative_to(d))] = "special"
    return out
