"""Line-segment maps for the 2D worlds: built-in maps, a small text/JSON/YAML format, ROS map_server maps.

File formats (all coordinates in metres, map frame):

* text (``.txt`` or any other suffix): one segment per line, ``x1 y1 x2 y2``; ``#`` starts a comment.
* JSON / YAML (``.json``, ``.yaml``, ``.yml``): ``{"name": "...", "segments": [[x1, y1, x2, y2], ...]}``
  (each segment may also be written ``[[x1, y1], [x2, y2]]``).
* ROS map_server (a ``.yaml`` with an ``image:`` key and its ``.pgm``/``.png``): the occupancy grid
  is thresholded at ``occupied_thresh`` and the boundary between occupied and other cells becomes
  axis-aligned segments, merged into runs, so that the grid can be raycast exactly.

Built-in maps: ``seed_room`` (the seed paper's 3.66 x 1.83 m room with one interior board),
``corridor`` (a 6 x 1.2 m closed corridor with two door recesses), ``cluttered`` (a 4 x 3 m room
with boxes and a pillar).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.geometry import as_segments, from_frame
from sensor_envs.inputs import (
    InputError,
    bad_name,
    check_pixels,
    parse_json,
    parse_yaml,
    plain_decimal,
    read_bytes,
    read_text,
)

__all__ = ["SegmentMap", "load_map", "BUILTIN_MAPS", "read_ros_map", "ros_occupancy", "occupancy_to_segments"]


@dataclass(frozen=True)
class SegmentMap:
    """A validated line-segment map: ``segments`` ``(M, 2, 2)`` [m] in the map frame and a name.

    Examples:
        >>> from sensor_envs import SegmentMap, load_map
        >>> room = load_map("seed_room")
        >>> isinstance(room, SegmentMap), room.segments.shape[1:]  # (M, 2, 2) end points [m]
        (True, (2, 2))
    """

    segments: NDArray[np.float64]
    name: str = "map"

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of all segment end points [m]."""
        pts = self.segments.reshape(-1, 2)
        return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max()))


def _box(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    """The four edges of an axis-aligned box as ``[x1, y1, x2, y2]`` rows."""
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


def _seed_room() -> list[list[float]]:
    return _box(0.0, 0.0, 3.66, 1.83) + [[1.525, 0.915, 2.135, 0.915]]


def _corridor() -> list[list[float]]:
    south = [
        [0.0, 0.0, 2.0, 0.0],
        [2.0, 0.0, 2.0, -0.4],
        [2.0, -0.4, 2.9, -0.4],
        [2.9, -0.4, 2.9, 0.0],
        [2.9, 0.0, 6.0, 0.0],
    ]
    north = [
        [0.0, 1.2, 3.8, 1.2],
        [3.8, 1.2, 3.8, 1.6],
        [3.8, 1.6, 4.7, 1.6],
        [4.7, 1.6, 4.7, 1.2],
        [4.7, 1.2, 6.0, 1.2],
    ]
    return south + north + [[6.0, 0.0, 6.0, 1.2], [0.0, 1.2, 0.0, 0.0]]


def _cluttered() -> list[list[float]]:
    segs = _box(0.0, 0.0, 4.0, 3.0) + _box(0.8, 0.7, 1.3, 1.1) + _box(2.6, 1.8, 3.2, 2.2)
    segs += [[1.8, 2.4, 2.3, 2.1], [2.9, 0.5, 3.5, 0.9]]  # two slanted boards
    pillar = [
        [2.0 + 0.15 * np.cos(a), 1.2 + 0.15 * np.sin(a), 2.0 + 0.15 * np.cos(b), 1.2 + 0.15 * np.sin(b)]
        for a, b in zip(np.linspace(0, 2 * np.pi, 9)[:-1], np.linspace(0, 2 * np.pi, 9)[1:], strict=True)
    ]
    return segs + pillar


BUILTIN_MAPS = {"seed_room": _seed_room, "corridor": _corridor, "cluttered": _cluttered}


def load_map(spec: str | os.PathLike[str] | ArrayLike | SegmentMap) -> SegmentMap:
    """Load a map from a built-in name, a file, or an array of segments.

    Args:
        spec: a name in :data:`BUILTIN_MAPS`, a path to a text/JSON/YAML segment file or a ROS
            map_server YAML, an ``(M, 2, 2)``/``(M, 4)`` array [m], or a :class:`SegmentMap`.

    Raises:
        ValueError: naming the file (or ``map``) and the problem: unknown name, unreadable file,
            no segments, NaN coordinates, zero-length segments.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import load_map
        >>> load_map(np.array([[[0.0, 0.0], [1.0, 0.0]]])).segments.shape
        (1, 2, 2)
        >>> load_map("corridor").name
        'corridor'
    """
    if isinstance(spec, SegmentMap):
        return spec
    if isinstance(spec, str) and spec in BUILTIN_MAPS:
        return SegmentMap(as_segments(BUILTIN_MAPS[spec](), name=spec), name=spec)
    if isinstance(spec, (str, os.PathLike)):
        path = Path(spec)
        if not path.is_file():
            raise InputError(f"map: {str(spec)!r} is neither a built-in map {sorted(BUILTIN_MAPS)} nor a readable file")
        return _load_map_file(path)
    return SegmentMap(as_segments(spec, name="map"), name="array")


def _load_map_file(path: Path) -> SegmentMap:
    text = read_text(path, "cannot read map file")
    suffix = path.suffix.lower()
    if suffix in (".json", ".yaml", ".yml"):
        doc = parse_json(text, str(path)) if suffix == ".json" else parse_yaml(text, str(path))
        if isinstance(doc, dict) and "image" in doc:
            return read_ros_map(path)
        if not isinstance(doc, dict) or "segments" not in doc:
            raise InputError(f"{path}: expected a mapping with a 'segments' list (or a ROS map_server 'image' key)")
        unknown = sorted(set(doc) - {"name", "segments"})
        if unknown:
            raise InputError(f"{path}: field {unknown[0]!r:.60} is no map field (name, segments)")
        name = doc.get("name", path.stem)
        if bad_name(name):
            raise InputError(f"{path}: field 'name' {bad_name(name)}")
        rows = _segment_rows(doc["segments"], path)
        return SegmentMap(as_segments(rows, name=f"{path}: field 'segments'"), name=name)
    text_rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        parsed = [plain_decimal(p) for p in parts]  # float() would take 1_0.5, nan and other scripts' digits
        vals = [v for v in parsed if v is not None]
        if len(vals) != len(parsed):
            raise InputError(f"{path}:{lineno}: expected four numbers 'x1 y1 x2 y2', got {line!r:.80}")
        if len(vals) != 4:
            raise InputError(f"{path}:{lineno}: expected four numbers 'x1 y1 x2 y2', got {len(vals)}")
        text_rows.append(vals)
    if not text_rows:
        raise InputError(f"{path}: the map has no segments")
    return SegmentMap(as_segments(text_rows, name=str(path)), name=path.stem)


def _segment_rows(raw: Any, path: Path) -> NDArray[np.float64]:
    stack = [raw]
    while stack:  # every leaf a JSON/YAML number (true, "1" and null are no coordinates)
        x = stack.pop()
        if isinstance(x, list):
            stack.extend(x)
        elif isinstance(x, bool) or not isinstance(x, (int, float)):
            raise InputError(f"{path}: field 'segments' holds {x!r}; expected lists of [x1, y1, x2, y2] numbers")
    try:
        arr = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: field 'segments' must be a list of [x1, y1, x2, y2] numbers ({exc})") from None
    if arr.size == 0:
        raise InputError(f"{path}: field 'segments': the map has no segments")
    return arr


def read_ros_map(yaml_path: str | os.PathLike[str]) -> SegmentMap:
    """Read a ROS map_server map (YAML + PGM/PNG image) into boundary segments.

    Cells with occupancy probability ``> occupied_thresh`` are obstacles (``p = (255 - v) / 255``,
    or ``v / 255`` with ``negate: 1``). Unknown cells are treated as free space for raycasting.

    Raises:
        InputError: naming the YAML (or image) file and the field at fault.
    """
    path = Path(yaml_path)
    occupied, res, origin = ros_occupancy(path)
    segs = occupancy_to_segments(occupied, res, origin)
    return SegmentMap(as_segments(segs, name=f"{path}: occupied cells"), name=path.stem)


MAX_RESOLUTION = 100.0
"""Largest accepted map cell [m] (``resolution``); the smallest is :data:`MIN_RESOLUTION`."""
MIN_RESOLUTION = 1e-4
MAX_ORIGIN = 1e6
"""Largest accepted ``|origin|`` coordinate [m]."""


ROS_MAP_KEYS = frozenset({"image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode"})
"""The fields of a ROS map_server YAML (an unknown one is refused, not ignored: a typo would drop a threshold)."""


def ros_occupancy(yaml_path: str | os.PathLike[str]) -> tuple[NDArray[np.bool_], float, NDArray[np.float64]]:
    """Occupied cells ``(H, W)`` (row 0 at the smallest y), resolution [m], origin ``(x, y, yaw)`` of a ROS map.

    Every field is checked: ``image`` a file name beside the YAML (a regular file within the size and
    pixel limits), ``resolution`` in ``[1e-4, 100]`` m, ``origin`` three finite numbers, ``free_thresh`` a
    probability below 1 (default 0.196) and ``occupied_thresh`` one between it and 1 (exclusive), ``negate``
    0 or 1, ``mode`` trinary or scale (the occupied cells are the same in both); no other field.

    Raises:
        InputError: naming the file and the field.
    """
    path = Path(yaml_path)
    meta = parse_yaml(read_text(path, "ROS map YAML"), str(path))
    for key in ("image", "resolution", "origin"):
        if not isinstance(meta, dict) or key not in meta:
            raise InputError(f"{path}: field {key!r} is missing (not a ROS map_server YAML)")
    unknown = sorted(set(meta) - ROS_MAP_KEYS)
    if unknown:
        raise InputError(f"{path}: field {unknown[0]!r} is no ROS map_server field (expected {sorted(ROS_MAP_KEYS)})")
    if meta.get("mode", "trinary") not in ("trinary", "scale"):  # raw: pixel values are occupancies, not greys
        raise InputError(f"{path}: field 'mode' must be trinary or scale, got {meta['mode']!r:.40}")
    res = _yaml_number(meta, "resolution", path)
    if not MIN_RESOLUTION <= res <= MAX_RESOLUTION:
        raise InputError(f"{path}: field 'resolution' must be in [{MIN_RESOLUTION:g}, {MAX_RESOLUTION:g}] m, got {res}")
    try:
        origin = np.asarray(meta["origin"], dtype=np.float64)
    except (TypeError, ValueError):
        origin = np.zeros(0)
    if origin.shape != (3,) or not np.isfinite(origin).all() or (np.abs(origin) > MAX_ORIGIN).any():
        raise InputError(f"{path}: field 'origin' must be [x, y, yaw] (finite, within 1e6), got {meta['origin']!r}")
    free = _yaml_number(meta, "free_thresh", path, 0.196)
    if not 0.0 <= free < 1.0:
        raise InputError(f"{path}: field 'free_thresh' must be a probability in [0, 1), got {free}")
    thresh = _yaml_number(meta, "occupied_thresh", path, 0.65)
    if not free < thresh < 1.0:  # 0 would make every pixel but pure white a wall, 1 none
        raise InputError(
            f"{path}: field 'occupied_thresh' must be a probability in (free_thresh = {free:g}, 1), got {thresh}"
        )
    negate = _yaml_number(meta, "negate", path, 0)
    if negate not in (0, 1):
        raise InputError(f"{path}: field 'negate' must be 0 or 1, got {meta['negate']!r}")
    if not isinstance(meta["image"], str) or not meta["image"].strip():
        raise InputError(f"{path}: field 'image' must be a file name, got {meta['image']!r}")
    img = _read_image(path.parent / meta["image"], path)
    p = img / 255.0 if negate else (255.0 - img) / 255.0
    return (p > thresh)[::-1], res, origin  # image row 0 is the top (largest y)


def _yaml_number(meta: dict[str, Any], key: str, path: Path, default: float | None = None) -> float:
    """Field ``key`` of a ROS map YAML as a finite float (``default`` when absent), else a ValueError naming it."""
    value = meta.get(key, default)
    try:
        v = float(value) if value is not None and not isinstance(value, bool) else float("nan")
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v):
        raise InputError(f"{path}: field {key!r} must be a finite number, got {value!r}")
    return v


def _read_image(img_path: Path, yaml_path: Path) -> NDArray[np.float64]:
    try:
        raw = read_bytes(img_path, f"field 'image' of {yaml_path}")
    except FileNotFoundError:
        raise InputError(f"{yaml_path}: field 'image' points at a missing file {img_path}") from None
    except OSError as exc:
        raise InputError(f"{yaml_path}: field 'image' points at an unreadable file {img_path} ({exc})") from None
    if raw[:2] == b"P5":
        return _parse_pgm(raw, img_path)
    import io
    import warnings

    from PIL import Image  # only for non-PGM images

    _check_image_complete(raw, img_path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(raw)) as im:  # the container first: every chunk's checksum, nothing cut
                check_pixels(im.size[0], im.size[1], f"{img_path}: map image")
                im.verify()
            with Image.open(io.BytesIO(raw)) as im:
                check_pixels(im.size[0], im.size[1], f"{img_path}: map image")  # from the header, before decoding
                if im.mode.startswith(("I", "F")):  # convert("L") would clip, not scale: grey would turn white
                    raise InputError(f"{img_path}: a map image of mode {im.mode} (more than 8 bits per sample)")
                return np.asarray(im.convert("L"), dtype=np.float64)
    except InputError:
        raise
    except Exception as exc:  # PIL: unidentified or damaged image, decompression bomb
        raise InputError(f"{img_path}: cannot decode map image ({' '.join(str(exc).split())})") from None


def _check_image_complete(raw: bytes, path: Path) -> None:
    """Refuse an image file cut short, which a decoder may still turn into pixels.

    PIL decodes a PNG cut inside its last data chunk's checksums, a GIF without its trailer and a BMP
    without its last row's padding into a whole picture; a cut file is damaged, whatever survived it. PNG:
    the file must end with its ``IEND`` chunk; GIF: with the trailer byte; BMP: hold the size its header
    declares. (JPEG, TIFF and WebP cut short are refused by their decoders.)

    Raises:
        InputError: ``"<file>: the map image is cut short (...)"``.
    """
    why = ""
    if raw.startswith(b"\x89PNG\r\n\x1a\n") and not raw.endswith(b"\x00\x00\x00\x00IEND\xaeB`\x82"):
        why = "a PNG must end with its IEND chunk"
    elif raw.startswith((b"GIF87a", b"GIF89a")) and not raw.endswith(b";"):
        why = "a GIF must end with its trailer byte ';'"
    elif raw.startswith(b"BM") and len(raw) >= 6 and len(raw) < int.from_bytes(raw[2:6], "little"):
        why = f"the BMP header declares {int.from_bytes(raw[2:6], 'little')} bytes, the file has {len(raw)}"
    if why:
        raise InputError(f"{path}: the map image is cut short or damaged ({why})")


def _parse_pgm(raw: bytes, path: Path) -> NDArray[np.float64]:
    """Decode a binary (P5) PGM with 8-bit samples; comments allowed in the header.

    Raises:
        ValueError: naming the file and the header field (width, height, maxval) or the pixel data.
    """
    try:
        return _parse_pgm_raw(raw, path)
    except (ValueError, IndexError) as exc:
        if str(exc).startswith(str(path)):
            raise
        raise InputError(f"{path}: malformed PGM header or pixel data ({exc})") from None


def _parse_pgm_raw(raw: bytes, path: Path) -> NDArray[np.float64]:
    tokens: list[bytes] = []
    pos = 2
    while len(tokens) < 3:
        while pos < len(raw) and raw[pos : pos + 1].isspace():
            pos += 1
        if raw[pos : pos + 1] == b"#":
            pos = raw.index(b"\n", pos) + 1
            continue
        start = pos
        while pos < len(raw) and not raw[pos : pos + 1].isspace():
            pos += 1
        tokens.append(raw[start:pos])
    bad = next((t for t in tokens if not (t.isascii() and t.isdigit())), None)
    if bad is not None:  # int() would take b"1_0" as 10
        raise InputError(f"{path}: PGM header field {bad[:20]!r} is not a plain decimal integer")
    width, height, maxval = (int(t) for t in tokens)
    pos += 1
    check_pixels(width, height, f"{path}: PGM header")
    if maxval > 255:
        raise InputError(f"{path}: 16-bit PGM is not supported (maxval {maxval})")
    if maxval < 1:
        raise InputError(f"{path}: field 'maxval' of the PGM header must be in 1..255, got {maxval}")
    if width < 1 or height < 1:
        raise InputError(f"{path}: fields 'width'/'height' of the PGM header must be >= 1, got {width} x {height}")
    if len(raw) - pos < width * height:
        raise InputError(f"{path}: pixel data holds {len(raw) - pos} bytes, the header says {width} x {height}")
    data = np.frombuffer(raw, dtype=np.uint8, count=width * height, offset=pos)
    return data.reshape(height, width).astype(np.float64) * (255.0 / maxval)


def occupancy_to_segments(occupied: NDArray[np.bool_], resolution: float, origin: ArrayLike) -> NDArray[np.float64]:
    """Boundary segments ``(M, 2, 2)`` [m] of the occupied cells of a grid.

    Args:
        occupied: ``(H, W)`` bool grid, row 0 at the smallest y (map_server origin corner).
        resolution: cell size [m].
        origin: ``(x, y, yaw)`` of cell (0, 0)'s outer corner in the map frame [m, rad].
    """
    occ = np.pad(np.asarray(occupied, dtype=bool), 1)
    segs = []
    # Horizontal edges: between rows i-1 and i where occupancy changes; merge runs along columns.
    h_change = occ[1:, :] != occ[:-1, :]  # (H+1, W+2): edge at y = i (grid units, padded)
    for i, j0, j1 in _runs(h_change):
        segs.append([j0 - 1, i, j1 - 1, i])
    v_change = occ[:, 1:] != occ[:, :-1]  # (H+2, W+1): edge at x = j
    for j, i0, i1 in _runs(v_change.T):
        segs.append([j, i0 - 1, j, i1 - 1])
    if not segs:
        return np.zeros((0, 2, 2))
    s = np.asarray(segs, dtype=np.float64).reshape(-1, 2, 2) * resolution
    return from_frame(s, origin)


def _runs(change: NDArray[np.bool_]) -> list[tuple[int, int, int]]:
    """Maximal runs of True along axis 1: ``(row, start, end)`` with end exclusive."""
    padded = np.pad(change, ((0, 0), (1, 1))).astype(np.int8)
    d = np.diff(padded, axis=1)
    rows, starts = np.nonzero(d == 1)
    _, ends = np.nonzero(d == -1)
    return list(zip(rows.tolist(), starts.tolist(), ends.tolist(), strict=True))
