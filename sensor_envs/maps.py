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

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from sensor_envs.geometry import as_segments, from_frame

__all__ = ["SegmentMap", "load_map", "BUILTIN_MAPS", "read_ros_map", "occupancy_to_segments"]


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
            raise ValueError(f"map: {str(spec)!r} is neither a built-in map {sorted(BUILTIN_MAPS)} nor a readable file")
        return _load_map_file(path)
    return SegmentMap(as_segments(spec, name="map"), name="array")


def _load_map_file(path: Path) -> SegmentMap:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read map file ({exc})") from exc
    suffix = path.suffix.lower()
    if suffix in (".json", ".yaml", ".yml"):
        try:
            doc = json.loads(text) if suffix == ".json" else yaml.safe_load(text)
        except (json.JSONDecodeError, yaml.YAMLError) as exc:
            raise ValueError(f"{path}: not valid {suffix[1:].upper()} ({exc})") from exc
        if isinstance(doc, dict) and "image" in doc:
            return read_ros_map(path)
        if not isinstance(doc, dict) or "segments" not in doc:
            raise ValueError(f"{path}: expected a mapping with a 'segments' list (or a ROS map_server 'image' key)")
        rows = _segment_rows(doc["segments"], path)
        return SegmentMap(as_segments(rows, name=f"{path}: field 'segments'"), name=str(doc.get("name", path.stem)))
    text_rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.replace(",", " ").split()
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"{path}:{lineno}: expected four numbers 'x1 y1 x2 y2', got {line!r}") from None
        if len(vals) != 4:
            raise ValueError(f"{path}:{lineno}: expected four numbers 'x1 y1 x2 y2', got {len(vals)}")
        text_rows.append(vals)
    if not text_rows:
        raise ValueError(f"{path}: the map has no segments")
    return SegmentMap(as_segments(text_rows, name=str(path)), name=path.stem)


def _segment_rows(raw: Any, path: Path) -> NDArray[np.float64]:
    try:
        arr = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: field 'segments' must be a list of [x1, y1, x2, y2] numbers ({exc})") from None
    if arr.size == 0:
        raise ValueError(f"{path}: field 'segments': the map has no segments")
    return arr


def read_ros_map(yaml_path: str | os.PathLike[str]) -> SegmentMap:
    """Read a ROS map_server map (YAML + PGM/PNG image) into boundary segments.

    Cells with occupancy probability ``> occupied_thresh`` are obstacles (``p = (255 - v) / 255``,
    or ``v / 255`` with ``negate: 1``). Unknown cells are treated as free space for raycasting.
    """
    path = Path(yaml_path)
    try:
        meta = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read ROS map YAML ({exc})") from exc
    for key in ("image", "resolution", "origin"):
        if not isinstance(meta, dict) or key not in meta:
            raise ValueError(f"{path}: field {key!r} is missing (not a ROS map_server YAML)")
    res = _yaml_number(meta, "resolution", path)
    if not res > 0:
        raise ValueError(f"{path}: field 'resolution' must be > 0, got {res}")
    try:
        origin = np.asarray(meta["origin"], dtype=np.float64)
    except (TypeError, ValueError):
        origin = np.zeros(0)
    if origin.shape != (3,) or not np.isfinite(origin).all():
        raise ValueError(f"{path}: field 'origin' must be [x, y, yaw], got {meta['origin']!r}")
    thresh = _yaml_number(meta, "occupied_thresh", path, 0.65)
    if not 0.0 <= thresh <= 1.0:
        raise ValueError(f"{path}: field 'occupied_thresh' must be a probability in [0, 1], got {thresh}")
    negate = _yaml_number(meta, "negate", path, 0)
    if negate not in (0, 1):
        raise ValueError(f"{path}: field 'negate' must be 0 or 1, got {meta['negate']!r}")
    img = _read_image(path.parent / str(meta["image"]), path)
    p = img / 255.0 if negate else (255.0 - img) / 255.0
    occupied = p > thresh
    segs = occupancy_to_segments(occupied[::-1], res, origin)  # image row 0 is the top (largest y)
    return SegmentMap(as_segments(segs, name=f"{path}: occupied cells"), name=path.stem)


def _yaml_number(meta: dict[str, Any], key: str, path: Path, default: float | None = None) -> float:
    """Field ``key`` of a ROS map YAML as a finite float (``default`` when absent), else a ValueError naming it."""
    value = meta.get(key, default)
    try:
        v = float(value) if value is not None and not isinstance(value, bool) else float("nan")
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v):
        raise ValueError(f"{path}: field {key!r} must be a finite number, got {value!r}")
    return v


def _read_image(img_path: Path, yaml_path: Path) -> NDArray[np.float64]:
    try:
        raw = img_path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{yaml_path}: field 'image' points at an unreadable file {img_path} ({exc})") from exc
    if raw[:2] == b"P5":
        return _parse_pgm(raw, img_path)
    try:
        from PIL import Image  # only for non-PGM images

        with Image.open(img_path) as im:
            return np.asarray(im.convert("L"), dtype=np.float64)
    except Exception as exc:
        raise ValueError(f"{img_path}: cannot decode map image ({exc})") from exc


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
        raise ValueError(f"{path}: malformed PGM header or pixel data ({exc})") from None


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
    width, height, maxval = (int(t) for t in tokens)
    pos += 1
    if maxval > 255:
        raise ValueError(f"{path}: 16-bit PGM is not supported (maxval {maxval})")
    if maxval < 1:
        raise ValueError(f"{path}: field 'maxval' of the PGM header must be in 1..255, got {maxval}")
    if width < 1 or height < 1:
        raise ValueError(f"{path}: fields 'width'/'height' of the PGM header must be >= 1, got {width} x {height}")
    if len(raw) - pos < width * height:
        raise ValueError(f"{path}: pixel data holds {len(raw) - pos} bytes, the header says {width} x {height}")
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
