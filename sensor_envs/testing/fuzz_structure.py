"""Generated malformed inputs, second round (issue 42): the *structure* of each format, not one token.

The first round (:mod:`sensor_envs.testing.fuzz_cases`) mutates one token, line or array of a valid
file. These families break what holds a file together: the CSV's columns (duplicated, reordered,
renamed with invisible characters, rows wider or shorter than the header, line endings, byte-order
marks, number spellings such as ``" 1 "``, ``1_0``, ``+-1``, ``-0``, subnormals, integers past 2**63,
time that runs backwards or stands still), the ``.npz`` container (pickled object arrays, structured
or 0-d arrays, Fortran order, zip entries that lie about their size, nested zips, stray entries,
duplicated or degenerate geometry), CARMEN lines with extra or missing fields or only odometry, ROS
bags cut at every record boundary, map images of every mode (16-bit, palette, CMYK, 1x1, truncated
PNG, ASCII PGM), and YAML/JSON tricks (anchors and merge keys, tags, huge integers, ``NaN`` and
``Infinity`` literals, duplicate keys).

Each family returns a :class:`~sensor_envs.testing.fuzz_pieces.Case`; ``must_refuse`` marks inputs
that are certainly invalid (a loader taking one is "accepted nonsense").
"""

from __future__ import annotations

import io
import json
import struct
import warnings
import zipfile
from pathlib import Path

import numpy as np

from sensor_envs.testing.fuzz_pieces import (
    MAP_TXT,
    RADAR_HEADER,
    ROS_YAML,
    Case,
    Chooser,
    carmen_text,
    lidar_arrays,
    pgm_bytes,
    radar_rows,
    write_bag,
    write_npz,
    write_text_bytes,
)

# ------------------------------------------------------------------------------------------ radar CSV
NUMBER_SPELLINGS: dict[str, bool] = {
    " 1 ": False,
    "+1": False,
    "-0": False,
    "1.": False,
    "1e-400": False,  # underflows to 0 (a position of 0 m is valid)
    "1_0": True,
    "0x10": True,
    "1e": True,
    "+-1": True,
    "--1": True,
    "1.5.2": True,
    "1,5": True,
    "١": True,
    "１": True,  # a full-width digit
    "NaN": True,
    "-inf": True,
    "Infinity": True,
    "9223372036854775808": True,  # past int64 (and 2**53)
    "-9223372036854775809": True,
    "1e309": True,
    "0b1": True,
    "1j": True,
    "true": True,
}
"""Spellings of a number in a CSV cell and whether the cell must be refused (positions and ids)."""
INVISIBLE = ["\u200b", "\u202e", "\ufeff", "\x7f", "\u00a0\u00a0", "\t", "\r"]
"""Invisible or control characters that make a column name look like another (or like none)."""


def _csv_table() -> tuple[list[str], list[list[str]]]:
    rows = [r.split(",") for r in radar_rows()]
    return RADAR_HEADER.split(","), rows


def _join(header: list[str], rows: list[list[str]], nl: str = "\n") -> str:
    return nl.join([",".join(header), *(",".join(r) for r in rows)]) + nl


def _radar_structure(c: Chooser, d: Path) -> Case:
    from sensor_envs.radar.log import read_log, target_tuples

    header, rows = _csv_table()
    kind = c.choice(
        ["bom", "crlf", "cr", "dupcol", "reorder", "wide", "short", "rows", "spelling", "invisible", "time", "dup"]
        + ["widecols", "quoted"]
    )
    nl, prefix, must = "\n", "", True
    if kind == "bom":
        prefix, what, must = "\ufeff", "byte-order mark", False
    elif kind == "crlf":
        nl, what, must = "\r\n", "CRLF line ends", False
    elif kind == "cr":
        nl, what, must = "\r", "CR-only line ends", False  # old Mac text: refused or read, never half-read
    elif kind == "dupcol":
        j = c.integers(0, len(header) - 1)
        header = [*header, header[j]]
        rows = [[*r, r[j]] for r in rows]
        what = f"column {header[j]!r} twice"
    elif kind == "reorder":
        order = list(range(len(header)))
        for i in range(len(order) - 1, 0, -1):
            k = c.integers(0, i)
            order[i], order[k] = order[k], order[i]
        header, rows = [header[i] for i in order], [[r[i] for i in order] for r in rows]
        what, must = "columns in another order", False
    elif kind in ("wide", "short"):
        i = c.integers(0, len(rows) - 1)
        rows[i] = [*rows[i], "1.0"] * 1 if kind == "wide" else rows[i][:-1]
        what = f"row {i + 2} {'one field more' if kind == 'wide' else 'one field less'} than the header"
    elif kind == "rows":
        n = c.choice([0, 1])
        rows = rows[:n]
        what, must = f"{n} data rows", False  # a valid file; the command refuses too few tuples
    elif kind == "spelling":
        col = c.choice(["sequence", "frame", "target", "ref_x", "meas_y", "ref_length", "t"])
        tok = c.choice(sorted(NUMBER_SPELLINGS))
        i = c.integers(0, len(rows) - 2)
        rows[i][header.index(col)] = f'"{tok}"' if "," in tok else tok
        must = NUMBER_SPELLINGS[tok]
        if col in ("sequence", "frame", "target") and tok in ("1.", "1e-400"):
            must = True  # an id is an integer
        if col == "ref_length" and tok in ("-0", "1e-400"):
            must = True  # a box of no length
        if col in ("t", "frame", "sequence") and not must:
            must = False  # may break the order of the cycles: refused or read, judged by the loader
        what = f"{col} = {tok!r}"
    elif kind == "invisible":
        j = c.choice([header.index("rcs"), header.index("meas_x")])
        ch = c.choice(INVISIBLE)
        header[j] = header[j][:2] + ch + header[j][2:]
        what = f"column name {header[j]!r}"
    elif kind == "time":
        i = c.integers(1, 4)
        t_col = header.index("t")
        how = c.choice(["back", "same"])
        rows[i][t_col] = rows[i - 1][t_col] if how == "same" else "-5.0"
        what = f"t of row {i + 2} {'equal to' if how == 'same' else 'before'} the previous cycle's"
    elif kind == "dup":
        i = c.integers(0, len(rows) - 2)
        rows.insert(i + 1, list(rows[i]))
        what = f"row {i + 2} twice (one target seen twice in one cycle)"
    elif kind == "widecols":
        extra = c.choice([300, 5000])
        header = header + [f"c{k}" for k in range(extra)]
        rows = [r + ["0"] * extra for r in rows]
        what, must = f"{extra} covariate columns", False
    else:
        j = c.integers(0, len(header) - 1)
        header[j] = f'"{header[j]}"'
        what, must = f"quoted column name {header[j]}", False
    p = write_text_bytes(d / "log.csv", prefix + _join(header, rows, nl))
    argv = ["fit", "radar", str(p), "--out", str(d / "k.npz"), "--relevance", "paper"]
    return Case("radar CSV structure", what, argv, lambda: target_tuples(read_log(p)), must, [p])


# ----------------------------------------------------------------------------------------- npz container
def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, arr, allow_pickle=True)
    return buf.getvalue()


def _zip(entries: list[tuple[str, bytes]]) -> bytes:
    buf = io.BytesIO()
    with warnings.catch_warnings(), zipfile.ZipFile(buf, "w") as zf:
        warnings.simplefilter("ignore")  # "Duplicate name": wanted here
        for name, data in entries:
            zf.writestr(name, data)
    return buf.getvalue()


def _lying_zip(entries: list[tuple[str, bytes]], lie: int) -> bytes:
    """A stored zip whose central directory declares ``lie`` as the first entry's size."""
    raw = bytearray(_zip(entries))
    cd = raw.rfind(b"PK\x01\x02")
    first = raw.find(b"PK\x01\x02")
    for at in {first, cd} if first == cd else {first}:
        struct.pack_into("<I", raw, at + 24, lie & 0xFFFFFFFF)
    return bytes(raw)


def _container_mutation(c: Chooser, arrays: dict[str, np.ndarray]) -> tuple[str, bytes, bool]:
    """(what, file bytes, must_refuse) of a broken ``.npz`` container around valid ``arrays``."""
    key = c.choice(sorted(arrays))
    entries = [(f"{k}.npy", _npy(v)) for k, v in arrays.items()]
    kind = c.choice(["pickle", "struct", "0d", "ndim", "fortran", "bigendian", "lie", "nested", "stray", "dup"])
    if kind == "pickle":
        obj = np.empty(np.shape(arrays[key]), dtype=object)
        obj[...] = 1.0
        return f"{key} pickled (object dtype)", _zip(_replace(entries, key, _npy(obj))), True
    if kind == "struct":
        a = np.zeros(len(np.atleast_1d(arrays[key])), dtype=[("a", "<f8"), ("b", "<f8")])
        return f"{key} of a structured dtype", _zip(_replace(entries, key, _npy(a))), True
    if kind == "0d":
        return f"{key} 0-d", _zip(_replace(entries, key, _npy(np.array(1.0)))), True
    if kind == "ndim":
        a = np.asarray(arrays[key])[..., None, None]
        return f"{key} with two more axes", _zip(_replace(entries, key, _npy(a))), True
    if kind == "fortran":
        a = np.asfortranarray(arrays[key])
        return f"{key} in Fortran order", _zip(_replace(entries, key, _npy(a))), False
    if kind == "bigendian":
        a = np.asarray(arrays[key]).astype(np.asarray(arrays[key]).dtype.newbyteorder(">"))
        return f"{key} big-endian", _zip(_replace(entries, key, _npy(a))), False
    if kind == "lie":
        lie = c.choice([2**32 - 1, 0, 7])
        return f"zip entry declares {lie} bytes", _lying_zip(entries, lie), True
    if kind == "nested":
        inner = _zip(entries)
        return "an npz inside the npz", _zip([("inner.npz", inner)]), True
    if kind == "stray":
        name = c.choice(["notes.txt", "../escape.npy", "/abs.npy", "dir/", "a\x00b.npy"])
        return f"stray entry {name!r}", _zip([*entries, (name, b"hello")]), True  # every member is an array"
    return f"entry {key}.npy twice", _zip([*entries, (f"{key}.npy", _npy(np.zeros(3)))]), True


def _replace(entries: list[tuple[str, bytes]], key: str, data: bytes) -> list[tuple[str, bytes]]:
    return [(n, data if n == f"{key}.npy" else b) for n, b in entries]


def _geometry_mutation(c: Chooser, arrays: dict[str, np.ndarray]) -> tuple[str, bool]:
    """Valid arrays holding degenerate values: duplicate bearings, a zero-length wall, time standing still."""
    kind = c.choice(["bearing dup", "bearing order", "segment point", "segments same", "t same", "t back"])
    kind = c.choice([kind, "subnormal", "negzero", "int64", "uint64"])
    if kind == "bearing dup":
        arrays["bearings"][1] = arrays["bearings"][0]
        return "two equal bearings", True
    if kind == "bearing order":
        arrays["bearings"] = arrays["bearings"][::-1].copy()
        return "bearings in decreasing order", False  # a scanner may turn clockwise
    if kind == "segment point":
        arrays["map_segments"][0, 1] = arrays["map_segments"][0, 0]
        return "a wall of zero length", True
    if kind == "segments same":
        arrays["map_segments"][:] = arrays["map_segments"][0]
        return "every wall the same segment", False  # a valid (if poor) map: judged by the command
    if kind == "t same":
        arrays["t"][2] = arrays["t"][1]
        return "two scans at the same time", False  # static repeats share a stamp: judged by the loader
    if kind == "t back":
        arrays["t"][2] = arrays["t"][0] - 1.0
        return "time running backwards", True
    if kind == "subnormal":
        arrays["poses"][0, 0] = 5e-324
        return "a subnormal pose coordinate", False
    if kind == "negzero":
        arrays["poses"][0, 2] = -0.0
        return "a heading of -0.0", False
    if kind == "int64":
        arrays["t"] = np.array([0, 1, 2, 3], dtype=np.int64)
        return "t as int64", False
    arrays["t"] = np.array([0, 1, 2, 2**64 - 1], dtype=np.uint64)
    return "t of 2**64 - 1", True


def _npz_structure(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.log import load_log

    arrays = {k: np.array(v, copy=True) for k, v in lidar_arrays().items()}  # SEGS is shared: never edit it
    p = d / "log.npz"
    if c.integers(0, 1):
        what, raw, must = _container_mutation(c, arrays)
        p.write_bytes(raw)
    else:
        what, must = _geometry_mutation(c, arrays)
        write_npz(p, arrays)
    argv = ["fit", "lidar", str(p), "--out", str(d / "m.npz"), "--folds", "2", "--variant", "seed"]
    return Case("npz container", what, argv, lambda: load_log(p), must, [p])


# ----------------------------------------------------------------------------------------------- CARMEN
def _carmen_lines(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.log import load_log

    lines = carmen_text().splitlines()
    i = c.integers(1, len(lines) - 1)
    tok = lines[i].split(" ")
    kind = c.choice(["extra", "missing", "count", "odom", "time", "crlf", "bom", "tabs", "empty", "robot"])
    must = True
    if kind == "extra":
        tok.insert(c.integers(10, len(tok)), "1.0")
        what = "one field more"
    elif kind == "missing":
        del tok[c.integers(2, len(tok) - 1)]
        what = "one field less"
    elif kind == "count":
        tok[1] = c.choice(["7", "9", "0", "-1", "999999999", "8.0", "1e3"])
        what = f"reading count {tok[1]}"
    elif kind == "odom":
        lines = [lines[0]] + [f"ODOM {1.0 + 0.1 * k} 1.5 0.1 0 0 0 {10.0 + k} host {10.0 + k}" for k in range(5)]
        what = "only ODOM lines (no scan)"
    elif kind == "time":
        tok[-1] = tok[-3] = c.choice(["5.0", "nan", lines[i - 1].split(" ")[-1] if i > 1 else "nan"])
        what = f"timestamp {tok[-1]} (before, or equal to, the previous)"
        # Equal stamps are valid (CARMEN logs cut them to a few digits; scan_times spreads them); an earlier
        # one is not, unless it is the first scan's; NaN never is.
        must = tok[-1] == "nan" or (tok[-1] == "5.0" and i > 1)
    elif kind == "crlf":
        what, must = "CRLF line ends", False
    elif kind == "bom":
        lines[0] = "\ufeff" + lines[0]
        what, must = "byte-order mark", False
    elif kind == "tabs":
        tok = "\t".join(tok).split(" ")
        what, must = "tab-separated line", False
    elif kind == "empty":
        lines = [lines[0]]
        what = "comments only"
    else:
        tok[0] = c.choice(["ROBOTLASER1", "RAWLASER1", "FLASER2", "flaser"])
        what = f"message {tok[0]} with FLASER fields"
        must = tok[0] == "ROBOTLASER1"  # other message types are skipped, as CARMEN readers do
    if kind not in ("odom", "empty", "crlf", "bom"):
        lines[i] = " ".join(tok)
    p = write_text_bytes(d / "log.log", ("\r\n" if kind == "crlf" else "\n").join(lines) + "\n")
    m = write_text_bytes(d / "m.txt", MAP_TXT)
    argv = ["fit", "lidar", str(p), "--out", str(d / "m.npz"), "--max-range", "5", "--map", str(m), "--folds", "2"]
    return Case("CARMEN lines", what, argv, lambda: load_log(p), must, [p, m])


# ---------------------------------------------------------------------------------------------- ROS bag
def bag_boundaries(raw: bytes) -> list[int]:
    """Byte offsets of every record boundary of a ROS1 bag (after the version line)."""
    out, at = [], raw.find(b"\n") + 1
    while at + 4 <= len(raw):
        out.append(at)
        (hlen,) = struct.unpack_from("<I", raw, at)
        at += 4 + hlen
        if at + 4 > len(raw):
            break
        (dlen,) = struct.unpack_from("<I", raw, at)
        at += 4 + dlen
    return out


def _bag_records(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.log import load_log

    p = write_bag(d)
    raw = p.read_bytes()
    cuts = bag_boundaries(raw)
    k = c.choice(cuts[1:] + [len(raw) - 1])
    kind = c.choice(["cut", "cut", "length"])
    must = True
    if kind == "cut":
        p.write_bytes(raw[:k])
        what = f"cut at record boundary {k} of {len(raw)}"
    else:
        b = bytearray(raw)
        at = c.choice(cuts)
        struct.pack_into("<I", b, at, c.choice([0, 2**31 - 1, 2**32 - 1, 3]))
        p.write_bytes(bytes(b))
        what = f"record header length at {at} overwritten"
        must = False  # an index record the reader never needs may be damaged unnoticed
    m = write_text_bytes(d / "m.txt", MAP_TXT)
    argv = ["fit", "lidar", str(p), "--out", str(d / "m.npz"), "--max-range", "5", "--map", str(m), "--folds", "2"]
    return Case("ROS bag records", what, argv, lambda: load_log(p), must, [p, m])


# ------------------------------------------------------------------------------------------- map images
def _image_bytes(c: Chooser) -> tuple[str, str, bytes, bool]:
    """(what, suffix, bytes, must_refuse) of a map image of an odd mode."""
    from PIL import Image

    img = np.frombuffer(pgm_bytes()[12:], dtype=np.uint8).reshape(8, 10)
    kind = c.choice(["I;16", "P", "CMYK", "1x1", "LA", "RGBA", "1", "trunc", "pgm16", "pgm ascii", "F", "0px"])
    if kind == "pgm16":
        raw = b"P5\n10 8\n65535\n" + (img.astype(">u2") * 257).tobytes()
        return "16-bit PGM", ".pgm", raw, True  # 8-bit samples only (a 16-bit grey is refused, never clipped)
    if kind == "pgm ascii":
        raw = b"P2\n10 8\n255\n" + " ".join(map(str, img.reshape(-1))).encode() + b"\n"
        return "ASCII PGM (P2)", ".pgm", raw, False
    if kind == "0px":
        return "PGM of 0 x 0 pixels", ".pgm", b"P5\n0 0\n255\n", True
    buf = io.BytesIO()
    pil = Image.fromarray(img)
    fmt = "PNG"
    if kind == "I;16":
        pil = Image.fromarray(img.astype(np.uint16) * 257)
    elif kind == "1x1":
        pil = pil.resize((1, 1))
    elif kind == "F":
        pil, fmt = Image.fromarray(img.astype(np.float32)), "TIFF"
    elif kind == "CMYK":
        pil, fmt = pil.convert("CMYK"), "JPEG"
    elif kind == "trunc":  # any format, cut anywhere past its signature (a checksum or trailer byte included)
        fmt = c.choice(["PNG", "GIF", "BMP", "JPEG", "TIFF", "WEBP"])
    else:
        pil = pil.convert(kind)
    pil.save(buf, format=fmt)
    raw = buf.getvalue()
    if kind == "trunc":
        raw = raw[: c.integers(8, len(raw) - 1)]
    suffix = {"PNG": ".png", "TIFF": ".tif", "JPEG": ".jpg", "GIF": ".gif", "BMP": ".bmp", "WEBP": ".webp"}[fmt]
    kind = f"{fmt} cut" if kind == "trunc" else kind
    return f"{kind} image", suffix, raw, kind.endswith(" cut") or kind in ("1x1", "I;16", "F")


def _map_image(c: Chooser, d: Path) -> Case:
    from sensor_envs.maps import load_map

    what, suffix, raw, must = _image_bytes(c)
    img = d / f"map{suffix}"
    img.write_bytes(raw)
    p = write_text_bytes(d / "map.yaml", ROS_YAML.replace("map.pgm", img.name))
    argv = ["record", "lidar", "--map", str(p), "--out", str(d / "r.npz"), "--poses", "2", "--repeats", "2"]
    return Case("map image", what, argv, lambda: load_map(p), must, [p, img])


# ------------------------------------------------------------------------------------ YAML and JSON text
YAML_TRICKS: dict[str, tuple[str, bool]] = {
    "merge key": ("base: &b {resolution: 0.5}\n<<: *b\n", True),
    "python tag": ("resolution: !!python/object/apply:os.getcwd []\n", True),
    "binary tag": ("resolution: !!binary aGVsbG8=\n", True),
    "timestamp": ("resolution: 2001-12-14\n", True),
    "huge int": ("resolution: 1" + "0" * 5000 + "\n", True),
    "duplicate key": ("resolution: 0.5\nresolution: 0.25\n", True),
    "two documents": ("resolution: 0.5\n---\nresolution: 0.25\n", True),
    "octal": ("negate: 0o1\n", True),
    "sexagesimal": ("resolution: 1:30\n", True),
    "yes/no": ("negate: yes\n", False),
    "null key": ("~: 1\n", True),
    "complex key": ("? [a, b]\n: 1\n", True),
    "tab indent": ("origin:\n\t- 0\n", True),
    "misspelt key": ("occupied_threshold: 0.5\n", True),
    "mode raw": ("mode: raw\n", True),
    "mode scale": ("mode: scale\n", False),
}
"""YAML constructs a map file may not use (aliases, tags, ambiguous scalars) and whether to refuse them."""
JSON_TRICKS: dict[str, tuple[str, bool]] = {
    "NaN literal": ("NaN", True),
    "Infinity literal": ("Infinity", True),
    "-Infinity literal": ("-Infinity", True),
    "1e400": ("1e400", True),
    "huge int": ("1" + "0" * 5000, True),
    "negative zero": ("-0.0", False),
    "subnormal": ("5e-324", False),
}
"""JSON number spellings in a field and whether a loader must refuse them (a field in ``[0, 1e6]``)."""


def _yaml_text(c: Chooser, d: Path) -> Case:
    from sensor_envs.maps import load_map

    (d / "map.pgm").write_bytes(pgm_bytes())
    name = c.choice(sorted(YAML_TRICKS))
    trick, must = YAML_TRICKS[name]
    lines = [ln for ln in ROS_YAML.splitlines(keepends=True) if ln.split(":")[0] not in trick.split(":")[0]]
    p = write_text_bytes(d / "map.yaml", "".join(lines) + trick)
    argv = ["record", "lidar", "--map", str(p), "--out", str(d / "r.npz"), "--poses", "2", "--repeats", "2"]
    return Case("YAML constructs", name, argv, lambda: load_map(p), must, [p])


def _json_text(c: Chooser, d: Path) -> Case:
    from sensor_envs.radar.rig import load_rig
    from sensor_envs.testing.fuzz_pieces import SHIPPED

    blob = json.loads((SHIPPED / "radar_rig.json").read_text())
    keys = [k for k, v in blob["params"].items() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    key = c.choice(sorted(keys))
    name = c.choice(sorted(JSON_TRICKS) + ["duplicate key", "duplicate params", "unknown field"])
    text = json.dumps(blob)
    if name == "duplicate key":
        text = text.replace(f'"{key}": ', f'"{key}": 0.5, "{key}": ', 1)
        must = True
    elif name == "duplicate params":
        text = text[:-1] + ', "params": {}}'
        must = True
    elif name == "unknown field":
        text = text[:-1] + ', "crad": {}}'
        must = True
    else:
        tok, must = JSON_TRICKS[name]
        old = json.dumps(blob["params"][key])
        text = text.replace(f'"{key}": {old}', f'"{key}": {tok}', 1)
        if not must and tok in ("-0.0", "5e-324"):
            must = False  # a zero may be valid for the field: judged by its declared range
    p = write_text_bytes(d / "rig.json", text)
    argv = ["record", "radar", "--rig", str(p), "--out", str(d / "r.csv"), "--sequences", "1", "--cycles", "2"]
    return Case("JSON constructs", f"params.{key}: {name}", argv, lambda: load_rig(p), must, [p])


STRUCTURE_FAMILIES = {
    "radar CSV structure": _radar_structure,
    "npz container": _npz_structure,
    "CARMEN lines": _carmen_lines,
    "ROS bag records": _bag_records,
    "map image": _map_image,
    "YAML constructs": _yaml_text,
    "JSON constructs": _json_text,
}
"""The second-round file families (:data:`sensor_envs.testing.fuzz_cases.FAMILIES` includes them)."""
