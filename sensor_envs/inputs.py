"""The input layer: one exception for bad input and bounded readers that every loader goes through.

Contract (see ``docs/howto/inputs.md``):

* :class:`InputError` (a ``ValueError``) is the one exception for bad input: a malformed file, an
  option out of range, an unsafe output. Its message names the file (or option) and the field. The
  command line turns it, and an ``OSError`` from opening a user's path, into exit status 2 and one
  line; every other exception is a bug and keeps its traceback.
* Every file is read through :func:`read_bytes` / :func:`read_text` / :func:`open_gzip_lines` /
  :func:`load_npz`: only regular files (a FIFO, a device or a socket is refused before it is opened,
  so ``/dev/zero`` or a pipe cannot hang or fill memory), at most :data:`LIMITS` ``.file_bytes`` bytes,
  a compressed file's inflated size checked before (npz) or while (gzip) inflating, lines of at most
  ``.line_bytes``.
* Structured text goes through :func:`parse_json` / :func:`parse_yaml`: at most ``.depth`` levels of
  nesting and ``.nodes`` values; YAML aliases (``*name``) are refused (no alias bombs).
* Images: :func:`check_pixels` before any decoding (at most ``.pixels`` pixels).
* Numbers: :func:`check_number` / :func:`check_count` for scalars (finite, declared range).
"""

from __future__ import annotations

import gzip
import json
import math
import os
import re
import stat
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

__all__ = [
    "InputError",
    "InputTypeError",
    "Limits",
    "LIMITS",
    "check_path",
    "real_path",
    "check_regular_file",
    "read_bytes",
    "read_text",
    "open_gzip_lines",
    "load_npz",
    "parse_json",
    "parse_yaml",
    "check_pixels",
    "check_number",
    "plain_decimal",
    "check_count",
    "check_rng",
    "bad_name",
    "check_array",
]

PathLike = str | os.PathLike[str]


class InputError(ValueError):
    """Bad input (a file, an option, an argument): the message names the file or option and the field.

    The one exception the command line shows as one line with exit status 2 (subclasses:
    ``ModelFileError``, ``LidarLogError``, ``RadarLogError``, ``OutputError``).
    """


class InputTypeError(InputError, TypeError):
    """Bad input of the wrong kind (e.g. another observation type): an :class:`InputError` and a ``TypeError``."""


@dataclass(frozen=True)
class Limits:
    """Bounds of every read (module-wide; tests may replace :data:`LIMITS` fields with ``dataclasses.replace``).

    Attributes:
        file_bytes: largest file read [bytes] (the real logs are at most a few MB; 512 MiB leaves room).
        inflated_bytes: largest inflated content of a compressed file (gzip, npz) [bytes].
        line_bytes: longest text line [bytes].
        depth: deepest nesting of JSON/YAML containers.
        nodes: most values in one JSON/YAML document.
        pixels: largest map image [pixels] (a 10 000 x 10 000 grid at 5 cm is a 500 m square).
    """

    file_bytes: int = 512 * 2**20
    inflated_bytes: int = 1024 * 2**20
    line_bytes: int = 16 * 2**20
    depth: int = 64
    nodes: int = 2_000_000
    pixels: int = 100_000_000


LIMITS = Limits()


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device")):
        if test(mode):
            return name
    for test, name in ((stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a folder")):
        if test(mode):
            return name
    return "not a regular file"


def check_path(path: Any, field: str = "file") -> Path:
    """``path`` as a ``Path``: a non-empty ``str`` or ``os.PathLike`` without NUL bytes.

    Raises:
        InputError: ``"<field>: expected a file path, got ..."`` for anything else (``None``, a number, bytes).
    """
    if isinstance(path, os.PathLike):
        path = os.fspath(path)
    if not isinstance(path, str) or not path.strip() or "\x00" in path:
        raise InputError(f"{field}: expected a file path (a non-empty str or os.PathLike), got {path!r:.60}")
    return Path(path)


def real_path(path: PathLike) -> Path:
    """``path`` absolute, with every symbolic link followed: ``Path.resolve()`` that never raises.

    ``Path.resolve()`` raises ``RuntimeError`` on a symbolic-link loop (Python < 3.13); a loop is left in the
    path here, and the read that follows refuses it as an input error naming the file.
    """
    return Path(os.path.realpath(os.fspath(path)))


def check_regular_file(path: PathLike, field: str = "file", limit: int | None = None) -> int:
    """The size [bytes] of ``path``, a regular file of at most ``limit`` bytes (default ``LIMITS.file_bytes``).

    Raises:
        InputError: for a FIFO, device, socket or folder (checked before opening: no blocking read),
            or a file over the limit, naming the file and ``field``.
        FileNotFoundError: when ``path`` does not exist (the message names it).
    """
    p = check_path(path, field)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise FileNotFoundError(f"{p}: {field}: file not found") from None
    except OSError as exc:  # a symbolic-link loop, a name too long, a folder we may not enter
        raise InputError(f"{p}: {field}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{p}: {field}: is {_kind(st.st_mode)}, expected a regular file")
    cap = LIMITS.file_bytes if limit is None else limit
    if st.st_size > cap:
        raise InputError(f"{p}: {field}: the file has {st.st_size} bytes, more than the limit of {cap}")
    return int(st.st_size)


def read_bytes(path: PathLike, field: str = "file", limit: int | None = None) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (see :func:`check_regular_file`)."""
    cap = LIMITS.file_bytes if limit is None else limit
    size = check_regular_file(path, field, cap)
    with open(path, "rb") as fh:
        data = fh.read(size + 1)  # read(cap + 1) would allocate cap bytes up front, whatever the file's size
        if len(data) > size:  # the file has grown since the check
            data += fh.read(cap + 1 - len(data))
    if len(data) > cap:
        raise InputError(f"{path}: {field}: the file has more than the limit of {cap} bytes")
    return data


def read_text(path: PathLike, field: str = "file", limit: int | None = None, encoding: str = "utf-8") -> str:
    """The text of a regular file of at most ``limit`` bytes; bytes that are not ``encoding`` are an InputError."""
    raw = read_bytes(path, field, limit)
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(
            f"{path}: {field}: line {line}: byte {raw[exc.start : exc.start + 1]!r} is not {encoding.upper()} text"
        ) from None


def open_gzip_lines(path: PathLike, field: str = "file", gzipped: bool | None = None) -> Iterator[tuple[int, str]]:
    """``(line number, text)`` of a gzip (``gzipped``; ``None``: by its magic bytes) or plain UTF-8 text file, bounded.

    The compressed file is checked like any other (:func:`check_regular_file`); the inflated text may
    not exceed ``LIMITS.inflated_bytes`` and no line ``LIMITS.line_bytes`` (checked while inflating, a
    piece at a time: a gzip of one 4 GB line is refused after reading ``line_bytes``).

    Raises:
        InputError: naming the file and ``field`` (truncated or damaged gzip, not UTF-8, over a limit).
    """
    check_regular_file(path, field)
    with open(path, "rb") as raw:
        gz = raw.read(2) == b"\x1f\x8b"
    if gzipped and not gz:
        raise InputError(f"{path}: {field}: the file is not readable as gzip (no gzip header)")
    total = 0
    try:
        with gzip.open(path, "rb") if gz else open(path, "rb") as fh:
            for lineno in range(1, 2**62):
                line = fh.readline(LIMITS.line_bytes + 1)
                if not line:
                    return
                total += len(line)
                if len(line) > LIMITS.line_bytes:
                    raise InputError(f"{path}: {field}: line {lineno} is longer than {LIMITS.line_bytes} bytes")
                if total > LIMITS.inflated_bytes:
                    raise InputError(f"{path}: {field}: the inflated text exceeds {LIMITS.inflated_bytes} bytes")
                try:
                    yield lineno, line.decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise InputError(f"{path}: {field}: line {lineno} is not UTF-8 text ({exc.reason})") from None
    except (EOFError, OSError, zlib.error) as exc:  # gzip: truncated stream, bad header or CRC
        detail = "truncated" if isinstance(exc, EOFError) else " ".join(str(exc).split())
        raise InputError(f"{path}: {field}: the file is not readable as gzip ({detail})") from None


def load_npz(path: PathLike, what: str = "npz file") -> dict[str, NDArray[Any]]:
    """Every array of a ``.npz`` (no pickle), its inflated size checked before anything is inflated.

    Raises:
        InputError: naming the file: not a zip/npz, pickled (object) content, an inflated size over
            ``LIMITS.inflated_bytes``, or damaged content.
    """
    check_regular_file(path, what)
    try:
        with zipfile.ZipFile(path) as zf:
            inflated = sum(i.file_size for i in zf.infolist())
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise InputError(f"{path}: not a readable {what} ({' '.join(str(exc).split())})") from None
    if inflated > LIMITS.inflated_bytes:
        raise InputError(
            f"{path}: not a readable {what}: its arrays inflate to {inflated} bytes, more than the limit of "
            f"{LIMITS.inflated_bytes}"
        )
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except MemoryError:
        raise InputError(f"{path}: not a readable {what} (an array is too large)") from None
    except Exception as exc:  # zip/npy damage, pickled content, ...: all the file's fault
        raise InputError(f"{path}: not a readable {what} ({' '.join(str(exc).split())})") from None
    for k, a in arrays.items():
        if isinstance(a, np.ndarray) and a.dtype.kind == "f":  # -0.0 is 0.0 (numpy refuses a scale of -0.0)
            arrays[k] = a = a + 0.0
        if not isinstance(a, np.ndarray):  # a zip member that is no .npy (another zip, text): numpy hands bytes
            raise InputError(f"{path}: field {k!r}: not an array (.npy) member of the {what}")
        if a.dtype.names is not None or a.dtype.kind in "VMm":  # records, raw bytes, dates: no file holds them
            raise InputError(f"{path}: field {k!r}: an array of dtype {a.dtype}, expected numbers")
    return arrays


def _check_tree(doc: Any, source: str) -> Any:
    """``doc`` if it nests at most ``LIMITS.depth`` levels and holds at most ``LIMITS.nodes`` values."""
    stack: list[tuple[Any, int]] = [(doc, 1)]
    nodes = 0
    while stack:
        x, d = stack.pop()
        nodes += 1
        if nodes > LIMITS.nodes:
            raise InputError(f"{source}: holds more than {LIMITS.nodes} values")
        if isinstance(x, (dict, list)):
            if d > LIMITS.depth:
                raise InputError(f"{source}: nested deeper than {LIMITS.depth} levels")
            items = x.values() if isinstance(x, dict) else x
            stack.extend((v, d + 1) for v in items)
    return doc


def _float(text: str) -> float:
    """A float of an input file, ``-0.0`` read as ``0.0``.

    numpy's samplers refuse a scale of ``-0.0`` (``scale < 0``) that every ``>= 0`` check lets through.
    """
    return float(text) + 0.0


class _DuplicateKey(ValueError):
    """A JSON object that names one key twice (``json.loads`` would keep the last value silently)."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(f"the key {k!r:.60} appears twice in one object")
        out[k] = v
    return out


def parse_json(text: str | bytes, source: str) -> Any:
    """JSON text as Python data, bounded in depth and size, no key twice in one object.

    ``NaN`` and ``Infinity`` literals pass (a model header writes "chosen by CV" as ``NaN``): the caller checks values.

    Args:
        text: the JSON text.
        source: the file and field, for messages (e.g. ``"model.npz: field '__header__'"``).

    Raises:
        InputError: ``"<source>: not valid JSON (...)"`` or a depth / size limit.
    """
    sep = text.count(",") + text.count(":") if isinstance(text, str) else text.count(b",") + text.count(b":")
    if sep > 2 * LIMITS.nodes:  # before parsing: json.loads would build every value first
        raise InputError(f"{source}: holds more than {LIMITS.nodes} values")
    try:
        doc = json.loads(text, object_pairs_hook=_unique_keys, parse_float=_float)
    except RecursionError:
        raise InputError(f"{source}: nested deeper than {LIMITS.depth} levels") from None
    except _DuplicateKey as exc:
        raise InputError(f"{source}: {exc}") from None
    except ValueError as exc:  # JSONDecodeError, bad UTF-8, an integer of more than 4300 digits
        raise InputError(f"{source}: not valid JSON ({' '.join(str(exc).split())[:200]})") from None
    return _check_tree(doc, source)


class _PlainLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """``yaml.SafeLoader`` (libyaml's, linear in the input, when installed) with plain decimal numbers."""


_INT = "tag:yaml.org,2002:int"
_FLOAT = "tag:yaml.org,2002:float"
_TIMESTAMP = "tag:yaml.org,2002:timestamp"
_PlainLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag not in (_INT, _FLOAT, _TIMESTAMP)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_PlainLoader.add_implicit_resolver(_INT, re.compile(r"^[-+]?[0-9]+$"), list("-+0123456789"))
_PlainLoader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"^(?:[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
    ),
    list("-+0123456789."),
)
"""Plain decimal numbers only (YAML 1.1 would read ``1_0.5`` as 10.5, ``0x10`` as 16 and ``1:30`` as 90); no
implicit dates (``2001-12-14`` stays text)."""

_TAGS = frozenset({"!", *(f"tag:yaml.org,2002:{t}" for t in ("str", "int", "float", "bool", "null", "seq", "map"))})
"""Explicit tags an input file may use: the plain JSON-like types (``!!binary``, ``!!set``, ``!!timestamp``,
``!!python/...`` and local tags are refused)."""


def _construct_mapping(loader: Any, node: Any, deep: bool = False) -> Any:
    """A mapping whose keys are distinct strings (PyYAML keeps the last of two equal keys silently).

    Merge keys (``<<``) are refused with the aliases they exist for; so are keys that are no string
    (``~: 1``, ``1: 2``, ``on: 1``, ``[a, b]: 1``).
    """
    seen: set[str] = set()
    for key_node, _ in node.value:
        line = key_node.start_mark.line + 1
        if key_node.tag == "tag:yaml.org,2002:merge":
            raise yaml.constructor.ConstructorError(None, None, f"line {line}: merge keys (<<) are not accepted")
        key = loader.construct_object(key_node, deep=True)
        if not isinstance(key, str):
            raise yaml.constructor.ConstructorError(None, None, f"line {line}: the key {key!r:.40} is not text")
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"line {line}: the key {key!r:.60} appears twice")
        seen.add(key)
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_PlainLoader.add_constructor("tag:yaml.org,2002:map", lambda loader, node: _construct_mapping(loader, node, True))
_PlainLoader.add_constructor(
    _FLOAT,
    lambda loader, node: yaml.SafeLoader.construct_yaml_float(loader, node) + 0.0,  # -0.0 is 0.0
)


_FLOW = re.compile(r"\"(?:[^\"\\\n]|\\.)*\"|'(?:[^'\n]|'')*'|#[^\n]*|[\[\]{}]")


def _flow_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` outside quoted scalars and comments (one linear pass)."""
    depth = deepest = 0
    for m in _FLOW.finditer(text):
        tok = m.group()
        if tok in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif tok in "]}":
            depth = max(depth - 1, 0)
    return deepest


def _check_events(text: str, source: str) -> None:
    """Refuse aliases (``*name``: a 600-byte alias bomb expands to 10^8 values), deep nesting and huge documents.

    One pass over the parser's events, before any node is built.
    """
    depth = count = 0
    for event in yaml.parse(text, Loader=_PlainLoader):
        count += 1
        tag = getattr(event, "tag", None)
        if tag is not None and tag not in _TAGS:
            raise InputError(
                f"{source}: line {event.start_mark.line + 1}: the tag {tag} is not accepted in input files"
            )
        if isinstance(event, yaml.AliasEvent):
            raise InputError(
                f"{source}: aliases (*name) are not accepted in input files (line {event.start_mark.line + 1})"
            )
        if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            depth += 1
            if depth > LIMITS.depth:
                raise InputError(f"{source}: nested deeper than {LIMITS.depth} levels")
        elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            depth -= 1
        if count > LIMITS.nodes:
            raise InputError(f"{source}: holds more than {LIMITS.nodes} values")


def parse_yaml(text: str, source: str) -> Any:
    """YAML text (safe tags only) as Python data: no aliases, bounded depth and size.

    Raises:
        InputError: ``"<source>: not valid YAML (...)"``, an alias, or a depth / size limit.
    """
    if _flow_depth(text) > LIMITS.depth:  # PyYAML's Python scanner is quadratic in the flow nesting: check first
        raise InputError(f"{source}: nested deeper than {LIMITS.depth} levels")
    try:
        _check_events(text, source)
        doc = yaml.load(text, Loader=_PlainLoader)
    except RecursionError:
        raise InputError(f"{source}: nested deeper than {LIMITS.depth} levels") from None
    except InputError:
        raise
    except yaml.YAMLError as exc:
        raise InputError(f"{source}: not valid YAML ({' '.join(str(exc).split())[:200]})") from None
    except (ValueError, TypeError, OverflowError) as exc:  # e.g. a timestamp out of range
        raise InputError(f"{source}: not valid YAML ({' '.join(str(exc).split())[:200]})") from None
    return _check_tree(doc, source)


def check_pixels(width: int, height: int, source: str) -> None:
    """Refuse an image of more than ``LIMITS.pixels`` pixels (checked from its header, before decoding)."""
    if width < 1 or height < 1:
        raise InputError(f"{source}: fields 'width'/'height' must be >= 1, got {width} x {height}")
    if width * height > LIMITS.pixels:
        raise InputError(f"{source}: the image has {width} x {height} pixels, more than the limit of {LIMITS.pixels}")


_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def plain_decimal(text: str) -> float | None:
    """``text`` as a float if it is plain ASCII decimal text (``-0`` as ``0.0``), else ``None``.

    ``float`` alone would take ``1_0.5`` (10.5), ``nan``, ``infinity``, padding and other scripts' digits
    (``١``, ``１``): text readers use this instead.
    """
    return float(text) + 0.0 if _DECIMAL.fullmatch(text) else None


def check_number(
    value: Any,
    name: str,
    low: float | None = None,
    high: float | None = None,
    *,
    open_low: bool = False,
    integer: bool = False,
) -> float:
    """``value`` as a float: a real (not bool) finite number in ``[low, high]`` (``(low, high]`` if ``open_low``).

    Raises:
        InputError: ``"<name>: expected ..., got ..."``.
    """
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if integer:
        ok = ok and isinstance(value, (int, np.integer))
    v = float(value) + 0.0 if ok else math.nan  # -0.0 is 0.0
    if ok and math.isfinite(v):
        ok = (low is None or v > low or (v == low and not open_low)) and (high is None or v <= high)
    else:
        ok = False
    if not ok:
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        kind = "an integer" if integer else "a finite number"
        raise InputError(f"{name}: expected {kind} in {'(' if open_low else '['}{lo}, {hi}], got {value!r}")
    return v


def check_count(value: Any, name: str, low: int = 1, high: int = 10**9) -> int:
    """``value`` as an int in ``[low, high]`` (booleans and floats are refused)."""
    return int(check_number(value, name, low, high, integer=True))


MAX_NAME = 200
"""Longest column or variable name [characters]."""


def bad_name(name: Any) -> str | None:
    """Why ``name`` is no column or variable name (``None`` if it is one): a non-empty printable string.

    Control characters (a NUL, a tab, an escape) or blank names are refused: a NUL in a CSV header would
    otherwise make a new, invisible column.
    """
    if not isinstance(name, str):
        return f"is {type(name).__name__}, not a name"
    if not name.strip():
        return "is empty"
    if not name.isprintable():
        return f"{name!r:.60} holds a control character"
    if len(name) > MAX_NAME:
        return f"is longer than {MAX_NAME} characters"
    return None


def check_rng(rng: Any, name: str = "rng") -> np.random.Generator:
    """``rng`` if it is a ``numpy.random.Generator`` (a seed or ``RandomState`` is refused: pass ``default_rng``)."""
    if not isinstance(rng, np.random.Generator):
        raise InputError(f"{name}: expected a numpy.random.Generator (np.random.default_rng(seed)), got {rng!r:.60}")
    return rng


def _holds_bool(value: Any) -> bool:
    """Whether a nested list/tuple holds a ``bool`` (numpy turns ``[True, 1.0]`` into ``[1.0, 1.0]`` silently)."""
    stack = [value]
    while stack:
        x = stack.pop()
        if isinstance(x, (bool, np.bool_)):
            return True
        if isinstance(x, (list, tuple)):
            stack.extend(x)
    return False


def check_array(
    value: Any,
    name: str,
    shape: tuple[int | tuple[int, ...] | None, ...],
    *,
    low: float | None = None,
    high: float | None = None,
    nan: bool = False,
) -> NDArray[np.float64]:
    """``value`` as a float64 array of a declared shape and range.

    Args:
        value: array-like of real numbers (bool, complex, object and strings are refused).
        name: the argument, for messages.
        shape: per axis ``None`` (any length), a length, or a tuple of accepted lengths.
        low: lower bound of every (non-NaN) entry.
        high: upper bound of every (non-NaN) entry.
        nan: whether NaN entries (missing values) are accepted; infinities never are.

    Raises:
        InputError: ``"<name>: ..."`` naming the first offending entry.
    """
    if isinstance(value, np.ma.MaskedArray) and np.ma.getmaskarray(value).any():  # asarray would drop the mask
        raise InputError(f"{name}: expected real numbers, got a masked array with masked entries")
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged nesting, unconvertible objects
        raise InputError(f"{name}: expected an array of real numbers ({' '.join(str(exc).split())})") from None
    if isinstance(value, (list, tuple)) and arr.dtype.kind in "fiu" and _holds_bool(value):
        raise InputError(f"{name}: expected real numbers, got a flag (True/False) among them")
    if arr.dtype.kind not in "fiu":
        raise InputError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64, copy=False)
    ok = arr.ndim == len(shape) and all(
        s is None or (d in s if isinstance(s, tuple) else d == s) for d, s in zip(arr.shape, shape, strict=False)
    )
    if not ok:
        want = ", ".join("n" if s is None else "|".join(map(str, s)) if isinstance(s, tuple) else str(s) for s in shape)
        raise InputError(f"{name}: expected shape ({want}), got {arr.shape}")
    bad = np.isinf(arr) if nan else ~np.isfinite(arr)
    if bad.any():
        raise InputError(f"{name}: entry {tuple(int(i) for i in np.argwhere(bad)[0])} is {arr[bad][0]}, not finite")
    with np.errstate(invalid="ignore"):
        out = (arr < low if low is not None else False) | (arr > high if high is not None else False)
    if np.any(out):
        i = tuple(int(j) for j in np.argwhere(out)[0])
        raise InputError(f"{name}: entry {i} is {arr[i]:g}, outside [{low}, {high}]")
    return arr
