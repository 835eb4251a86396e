"""Pickle-free model files: one ``.npz`` of plain arrays plus a JSON header, with a format version.

Layout of a model file: arrays under their own names, and ``__header__``, a uint8 array holding
UTF-8 JSON ``{"kind": ..., "format_version": ..., "params": {...}, "card": {...}}``. Files load
with ``allow_pickle=False``; every array is checked for the dtype kind and the shape rank the
loader declares, and for finiteness where asked. Hyperparameters and header fields are checked against
declarative tables of constraints (:mod:`sensor_envs.constraints`, re-exported here): :func:`validate_params`,
:func:`check_header`.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from sensor_envs.constraints import CYCLE_TIME as CYCLE_TIME
from sensor_envs.constraints import MAX_MAGNITUDE as MAX_MAGNITUDE
from sensor_envs.constraints import RANDOM_STATE as RANDOM_STATE
from sensor_envs.constraints import Constraint, Interval, Numbers, _NoneConstraint, is_subnormal
from sensor_envs.constraints import InstanceOf as InstanceOf
from sensor_envs.constraints import IsNaN as IsNaN
from sensor_envs.constraints import Names as Names
from sensor_envs.constraints import Options as Options
from sensor_envs.inputs import InputError, check_path, load_npz, parse_json, read_text, real_path
from sensor_envs.outputs import atomic_write, check_suffix

__all__ = [
    "ModelFileError",
    "save_model_file",
    "load_model_file",
    "check_model_arrays",
    "read_header_and_arrays",
    "read_model",
    "save_rig_file",
    "load_rig_file",
    "read_rig",
]


class ModelFileError(InputError):
    """A model file is unreadable, of the wrong kind or version, or holds a malformed field.

    Examples:
        >>> from pathlib import Path
        >>> from sensor_envs import KDERadarModel, ModelFileError
        >>> _ = Path("broken.npz").write_bytes(b"not a model")
        >>> try:
        ...     KDERadarModel.load("broken.npz")
        ... except ModelFileError as err:
        ...     print("broken.npz" in str(err))
        True
    """


M = TypeVar("M")


def read_model(cls: Callable[[], M] | type[M], path: str | os.PathLike[str]) -> M:
    """``cls.load(path)``, with a malformed header turned into a :class:`ModelFileError` naming the file.

    The loaders check format, dtypes and shapes; a header entry of the wrong type or a missing
    hyperparameter would otherwise surface as ``KeyError``/``TypeError`` from the model's constructor.
    """
    try:
        return cls.load(path)  # type: ignore[union-attr]
    except KeyError as exc:
        raise ModelFileError(f"{path}: field '__header__' lacks {exc}") from None
    except (TypeError, AttributeError, IndexError) as exc:
        raise ModelFileError(f"{path}: field '__header__' holds a malformed entry ({exc})") from None


def save_model_file(
    path: str | os.PathLike[str],
    kind: str,
    format_version: int,
    header: dict[str, Any],
    arrays: dict[str, NDArray[Any]],
) -> Path:
    """Write ``arrays`` and a JSON ``header`` to ``path`` (``.npz``); returns the path written.

    The header gets ``kind`` and ``format_version`` added; it must be JSON-serialisable. The file is
    written to a temporary sibling and renamed (an interrupted save leaves the old file intact).

    Raises:
        OutputError: when ``path`` does not end in ``.npz`` (never silently renamed).
    """
    path = check_suffix(path, ".npz", option="model file")
    meta = dict(header, kind=kind, format_version=int(format_version))
    blob = np.frombuffer(json.dumps(meta, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    for name, arr in arrays.items():
        if np.asarray(arr).dtype == object:
            raise TypeError(f"array {name!r} has dtype object, which cannot be saved without pickle")
    # typed as Any values: numpy's stub would otherwise match a ``**dict`` of arrays against ``allow_pickle: bool``
    payload: dict[str, Any] = {k: np.asarray(v) for k, v in arrays.items()}
    atomic_write(path, lambda tmp: np.savez_compressed(tmp, __header__=blob, **payload))
    return path


def read_header_and_arrays(
    path: str | os.PathLike[str], max_header_bytes: int | None = None
) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """The JSON header (a dict) and the other arrays of a model file, read without pickle, bounded.

    Raises:
        ModelFileError: naming the file and the field (a folder, a missing or unreadable file, no or a
            malformed ``__header__``, one larger than ``max_header_bytes``).
    """
    try:
        path = check_path(path, "model file")
    except InputError as exc:
        raise ModelFileError(str(exc)) from None
    if path.is_dir():
        raise ModelFileError(f"{path}: is a folder, expected a model file (.npz)")
    try:
        data = load_npz(path, "model file")  # bounded: regular file, size, inflated size before inflating
    except FileNotFoundError:
        raise ModelFileError(f"{path}: model file not found") from None
    except InputError as exc:
        raise ModelFileError(str(exc)) from None
    if "__header__" not in data:
        raise ModelFileError(f"{path}: field '__header__' is missing (not a sensor_envs model file)")
    blob = data.pop("__header__")
    if max_header_bytes is not None and blob.nbytes > max_header_bytes:
        raise ModelFileError(f"{path}: field '__header__' is larger than {max_header_bytes} bytes")
    if blob.dtype != np.uint8 or blob.ndim != 1:
        raise ModelFileError(f"{path}: field '__header__' must be 1-D uint8 (UTF-8 JSON bytes), got {blob.dtype}")
    try:
        header = parse_json(blob.tobytes().decode("utf-8"), f"{path}: field '__header__'")
    except UnicodeDecodeError as exc:
        raise ModelFileError(f"{path}: field '__header__' is not valid JSON ({exc})") from None
    except InputError as exc:
        raise ModelFileError(str(exc)) from None
    if not isinstance(header, dict):
        raise ModelFileError(f"{path}: field '__header__' must be a JSON object, got a JSON {type(header).__name__}")
    return header, data


def load_model_file(
    path: str | os.PathLike[str],
    kind: str,
    supported_versions: tuple[int, ...],
    schema: Mapping[str, tuple[str, int | None, bool]],
    header_schema: Mapping[str, list[Constraint]] | None = None,
) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """Read a model file written by :func:`save_model_file`, without pickle, and check it.

    Args:
        path: the ``.npz`` file.
        kind: the expected ``kind`` in the header.
        supported_versions: format versions this loader understands.
        schema: ``name -> (dtype kinds, ndim or None, must be finite)``; dtype kinds as numpy
            ``dtype.kind`` letters, e.g. ``"f"``, ``"iu"``, ``"b"``.
        header_schema: ``header field -> accepted forms`` of the fitted values the header holds besides
            ``kind``, ``format_version``, ``params`` and ``card`` (see :func:`check_header`); ``None``: not checked.

    Returns:
        ``(header, arrays)``.

    Raises:
        ModelFileError: naming the file and the field at fault.
    """
    header, data = read_header_and_arrays(path)  # checks that path is a path
    path = Path(path)
    if header.get("kind") != kind:
        raise ModelFileError(f"{path}: field 'kind' is {header.get('kind')!r}, expected {kind!r}")
    version = header.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int) or version not in supported_versions:
        raise ModelFileError(
            f"{path}: field 'format_version' is {header.get('format_version')!r}; this version of sensor_envs "
            f"reads {list(supported_versions)}"
        )
    for key, typ in (("params", dict), ("card", dict)):
        if key not in header and key == "params":
            raise ModelFileError(f"{path}: field '__header__' lacks {key!r}")
        if key in header and not isinstance(header[key], typ):
            raise ModelFileError(f"{path}: field '__header__' entry {key!r} must be a JSON object")
    if header_schema is not None:
        check_header(path, header, header_schema)
    check_model_arrays(path, data, schema)
    return header, data


def check_model_arrays(
    path: str | os.PathLike[str], data: Mapping[str, NDArray[Any]], schema: Mapping[str, tuple[str, int | None, bool]]
) -> None:
    """Each array ``schema`` names is present, of its dtype kind and rank, finite where asked.

    Raises:
        ModelFileError: naming the file and the field.
    """
    for name, (kinds, ndim, finite) in schema.items():
        if name not in data:
            raise ModelFileError(f"{path}: field {name!r} is missing")
        arr = data[name]
        if arr.dtype.kind not in kinds:
            raise ModelFileError(f"{path}: field {name!r} has dtype {arr.dtype}, expected kind {kinds!r}")
        if ndim is not None and arr.ndim != ndim:
            raise ModelFileError(f"{path}: field {name!r} has {arr.ndim} dimensions, expected {ndim}")
        if finite and arr.dtype.kind == "f" and not np.isfinite(arr).all():
            raise ModelFileError(f"{path}: field {name!r} holds NaN or infinite values")


HEADER_KEYS = ("kind", "format_version", "params", "card")
"""Header fields of every model file (checked by :func:`load_model_file` itself)."""


def check_header(
    path: str | os.PathLike[str], header: dict[str, Any], header_schema: Mapping[str, list[Constraint]]
) -> None:
    """Every header field besides :data:`HEADER_KEYS` is declared in ``header_schema`` and takes a declared form.

    Fields a format does not have may be absent (the loader asks for those its version needs); an
    undeclared field is an error (a misspelled or foreign field would otherwise be ignored silently).

    Raises:
        ModelFileError: ``"<file>: field '<name>' ..."``.
    """
    for name, value in header.items():
        if name in HEADER_KEYS:
            continue
        if name not in header_schema:
            raise ModelFileError(f"{path}: field {name!r} is not a field of this model's files")
        forms = [_NoneConstraint() if c is None else c for c in header_schema[name]]
        if any(c.accepts(value) for c in forms):
            continue
        expected = " or ".join(str(c) for c in forms)
        if any(isinstance(c, Interval) for c in forms):  # a scalar field: the wording of check_range
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            what = f"holds {value!r}" if number else f"is not numeric ({_shown(value, forms)})"
            raise ModelFileError(f"{path}: field {name!r} {what}; expected {expected}")
        raise ModelFileError(f"{path}: field {name!r} is invalid: expected {expected}, got {_shown(value, forms)}")


# ------------------------------------------------------------------------------- hyperparameter tables
def validate_params(
    params: dict[str, Any],
    constraints: dict[str, list[Constraint]],
    source: str | os.PathLike[str] | None = None,
    what: str = "hyperparameter",
) -> None:
    """Check hyperparameters against a declarative table (one table per model, used by ``fit`` and ``load``).

    Args:
        params: ``name -> value`` (e.g. ``estimator.get_params()`` or a model file's header ``params``).
        constraints: ``name -> list of accepted forms`` (any one suffices; ``None`` accepts ``None``).
        source: the model file the values come from, or ``None`` for constructor arguments.
        what: what a name is, for the message of an unknown one (``"hyperparameter"``, ``"key"``).

    Raises:
        ValueError: ``"<name>: expected ..., got ..."`` for a bad constructor argument.
        ModelFileError: ``"<file>: field 'params.<name>' ..."`` for a bad value read from ``source``, or a
            name the table does not know (unknown keys are errors).
    """
    for name, value in params.items():
        if name not in constraints:
            msg = f"unknown {what} (known: {sorted(constraints)})"
            if source is not None:
                raise ModelFileError(f"{source}: field 'params.{name}': {msg}")
            raise InputError(f"{name}: {msg}")
        forms = [_NoneConstraint() if c is None else c for c in constraints[name]]
        if any(c.accepts(value) for c in forms):
            continue
        msg = f"expected {' or '.join(str(c) for c in forms)}, got {_shown(value, forms)}"
        if source is not None:
            raise ModelFileError(f"{source}: field 'params.{name}' is invalid: {msg}")
        raise InputError(f"{name}: {msg}")


SHOWN_ITEMS = 8
"""Longer sequences are not echoed whole in an error (a per-bearing table has 360 values)."""


def _shown(value: Any, forms: list[Any]) -> str:
    """``value`` as a hyperparameter error shows it.

    Whole when short; a long sequence by its length and the first entry that no :class:`Numbers` form's item
    accepts.
    """
    if not isinstance(value, (tuple, list, np.ndarray)) or np.ndim(value) == 0 or len(value) <= SHOWN_ITEMS:
        return f"{value!r:.200}" + (" (a subnormal number)" if is_subnormal(value) else "")
    items = [c.item for c in forms if isinstance(c, Numbers)]
    bad = next((i for i, v in enumerate(value) if items and not any(it.accepts(v) for it in items)), None)
    return f"{len(value)} values" + (f", first rejected entry [{bad}] = {value[bad]!r}" if bad is not None else "")


# ----------------------------------------------------------------------------------- value checks
# Each raises ModelFileError("<file>: field '<field>' ...") naming the first offending entry.
def _first_bad(bad: NDArray[np.bool_]) -> str:
    """`` at [i, j]``: where the first offending entry of an array is (empty for a scalar)."""
    idx = np.argwhere(bad)[0]
    return f" at [{', '.join(str(int(i)) for i in idx)}]" if idx.size else ""


def check_finite(path: str | os.PathLike[str], field: str, arr: np.typing.ArrayLike) -> NDArray[np.float64]:
    """``arr`` as float64, every entry finite (no NaN or inf)."""
    a = _as_float(path, field, arr)
    bad = ~np.isfinite(a)
    if bad.any():
        where = _first_bad(bad)
        raise ModelFileError(
            f"{path}: field {field!r} holds NaN or infinite values" + (f" (first{where})" if where else "")
        )
    return a


def check_range(
    path: str | os.PathLike[str],
    field: str,
    arr: np.typing.ArrayLike,
    low: float | None = None,
    high: float | None = None,
) -> NDArray[np.float64]:
    """``arr`` finite with every entry in ``[low, high]`` (``None`` = unbounded): sane magnitudes."""
    a = check_finite(path, field, arr)
    bad = np.zeros(a.shape, dtype=bool)
    if low is not None:
        bad |= a < low
    if high is not None:
        bad |= a > high
    if bad.any():
        raise ModelFileError(
            f"{path}: field {field!r} holds {a[bad].ravel()[0]:g}{_first_bad(bad)}, outside "
            f"[{'-inf' if low is None else f'{low:g}'}, {'inf' if high is None else f'{high:g}'}]"
        )
    return a


def check_probability(path: str | os.PathLike[str], field: str, arr: np.typing.ArrayLike) -> NDArray[np.float64]:
    """``arr`` finite with every entry a probability in ``[0, 1]``."""
    return check_range(path, field, arr, 0.0, 1.0)


def check_positive(
    path: str | os.PathLike[str], field: str, arr: np.typing.ArrayLike, high: float | None = None
) -> NDArray[np.float64]:
    """``arr`` finite with every entry ``> 0`` (widths, sigmas, variances) and, if given, ``<= high``."""
    a = check_range(path, field, arr, None, high)
    bad = a <= 0
    if bad.any():
        raise ModelFileError(f"{path}: field {field!r} holds {a[bad].ravel()[0]:g}{_first_bad(bad)}; must be > 0")
    return a


def check_increasing(
    path: str | os.PathLike[str], field: str, arr: np.typing.ArrayLike, *, min_size: int = 2, regular: bool = False
) -> NDArray[np.float64]:
    """``arr`` a finite 1-D grid of at least ``min_size`` strictly increasing values (evenly spaced if ``regular``)."""
    a = check_finite(path, field, arr)
    if a.ndim != 1 or a.size < min_size:
        raise ModelFileError(f"{path}: field {field!r} has shape {a.shape}; expected at least {min_size} values")
    d = np.diff(a)
    if (d <= 0).any():
        i = int(np.flatnonzero(d <= 0)[0])
        raise ModelFileError(f"{path}: field {field!r} is not strictly increasing ({a[i]:g} then {a[i + 1]:g} at {i})")
    if regular and d.size and not np.allclose(d, d[0], rtol=1e-6, atol=1e-9):
        raise ModelFileError(f"{path}: field {field!r} is not evenly spaced (steps {d.min():g} to {d.max():g})")
    return a


def check_shape(path: str | os.PathLike[str], field: str, arr: np.typing.ArrayLike, shape: tuple[int, ...]) -> None:
    """``arr`` has exactly ``shape`` (lengths consistent with the other fields)."""
    got = np.shape(arr)
    if tuple(got) != tuple(shape):
        raise ModelFileError(f"{path}: field {field!r} has shape {tuple(got)}, expected {tuple(shape)}")


def _as_float(path: str | os.PathLike[str], field: str, arr: np.typing.ArrayLike) -> NDArray[np.float64]:
    try:
        return np.asarray(arr, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}: field {field!r} is not numeric ({exc})") from None


def file_sha256(path: str | os.PathLike[str]) -> str:
    """The sha256 hex digest of a file's bytes (read in 1 MiB chunks), for model cards: name + hash, never a path."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def data_reference(path: str | os.PathLike[str]) -> dict[str, str]:
    """``{"file": name, "sha256": digest}`` of an input file: what a card stores instead of its absolute path."""
    return {"file": Path(path).name, "sha256": file_sha256(path)}


def default_model_path(file_name: str) -> Path:
    """Path of a model file shipped in ``models/`` (package ``sensor_envs.models``), e.g. ``"radar_kde.npz"``.

    The file may be absent (a checkout without the shipped models): loading it then raises ``ModelFileError``.

    Raises:
        ValueError: when ``file_name`` is not a bare file name.
    """
    from importlib import resources

    if not file_name or Path(file_name).name != file_name:
        raise InputError(f"model: expected the bare file name of a shipped model, got {file_name!r}")
    return Path(str(resources.files("sensor_envs.models").joinpath(file_name)))


def model_file_key(path: str | os.PathLike[str]) -> tuple[str, int]:
    """``(resolved path, modification time [ns])`` of a model file: the key of the per-process model caches.

    A file rewritten in place gets a new key (and is loaded again); a missing file gets time ``-1``.
    """
    p = real_path(Path(path).expanduser())
    try:
        return str(p), p.stat().st_mtime_ns
    except OSError:
        return str(p), -1


@contextmanager
def named_as_given(given: str | os.PathLike[str] | None, resolved: str) -> Iterator[None]:
    """An :class:`InputError` raised inside that names ``resolved`` names the path the caller gave instead.

    The model caches load a file by its resolved path (:func:`model_file_key`); a link to ``/dev/zero`` or a
    file reached through a link must be named as the user wrote it.
    """
    try:
        yield
    except InputError as exc:
        if given is None or str(given) == resolved or resolved not in str(exc):
            raise
        raise type(exc)(str(exc).replace(resolved, f"{given} (-> {resolved})")) from None


def params_from_header(
    path: str | os.PathLike[str],
    header: dict[str, Any],
    constraints: dict[str, list[Constraint]],
    defaults: dict[str, Any] | None = None,
    not_saved: tuple[str, ...] = ("progress", "random_state"),
) -> dict[str, Any]:
    """A model file's hyperparameters (header field ``params``), checked against the model's table.

    JSON lists become tuples; ``defaults`` fill parameters that older format versions lack; any other
    missing hyperparameter is an error, except the run-time-only ones named in ``not_saved``.

    Raises:
        ModelFileError: naming the file and the field: ``params`` missing or not a mapping, an unknown
            hyperparameter, a missing one, or a value the table refuses.
    """
    raw = header.get("params") if isinstance(header, dict) else None
    if not isinstance(raw, dict):
        raise ModelFileError(f"{path}: field 'params' is missing or not a mapping")
    params = {**(defaults or {}), **{k: (tuple(v) if isinstance(v, list) else v) for k, v in raw.items()}}
    missing = sorted(set(constraints) - set(params) - set(not_saved))
    if missing:  # a silently defaulted hyperparameter would be another model than the one saved
        raise ModelFileError(f"{path}: field 'params.{missing[0]}' is missing")
    validate_params(params, constraints, path)
    return params


def optional_positive(path: str | os.PathLike[str] | None, field: str, value: Any) -> float:
    """A scalar that is either absent (returned as NaN) or a finite number ``> 0``, e.g. a cycle time.

    Absent is ``None``; in a model file (``path`` given) also NaN, the value a file written without one holds.
    A NaN given as a function argument is refused: it is what a computation gone wrong yields, never a way
    to say "none" (``fit(log, cycle_time=nan)`` silently fitted a model without a cycle time).

    Raises:
        ModelFileError: naming the file and the field, for a value read from the model file ``path``.
        InputError: ``"<field>: ..."`` for a function argument (``path=None``).
    """
    if value is None or (path is not None and isinstance(value, float) and np.isnan(value)):
        return float("nan")
    if path is not None:
        return float(check_positive(path, field, value))
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not 0 < value < np.inf
    ):
        raise InputError(f"{field}: expected a finite number > 0 or None, got {value!r}")
    return float(value)


# ----------------------------------------------------------------------------------- rig files
RIG_FORMAT_VERSION = 1
"""Format version of the rig parameter files written by :func:`save_rig_file`."""


def save_rig_file(
    path: str | os.PathLike[str], kind: str, params: Mapping[str, Any], card: Mapping[str, Any] | None = None
) -> Path:
    """Write a reference rig's parameters as JSON ``{"kind", "format_version", "params", "card"}``.

    Rig files are small (a few dozen numbers: statistics of the data they were calibrated on, never
    the data). ``card`` says what the parameters were calibrated against and how close the rig came.
    Written to a temporary sibling and renamed.

    Raises:
        OutputError: when ``path`` does not end in ``.json``.
    """
    from sensor_envs.outputs import jsonable

    path = check_suffix(path, ".json", option="rig file")
    blob = {"kind": kind, "format_version": RIG_FORMAT_VERSION, "params": jsonable(dict(params))}
    if card is not None:
        blob["card"] = jsonable(dict(card))
    text = json.dumps(blob, indent=2, sort_keys=True, allow_nan=False) + "\n"
    atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
    return path


def load_rig_file(
    path: str | os.PathLike[str], kind: str, constraints: dict[str, list[Constraint]]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Read a rig file written by :func:`save_rig_file`; returns ``(params, card)``.

    ``params`` are checked against ``constraints`` (unknown names are errors; missing names take the
    rig's defaults); the rig's own ``__post_init__`` checks relations between values.

    Raises:
        ModelFileError: naming the file and the field at fault.
    """
    path = Path(path)
    try:
        blob = parse_json(read_text(path, "rig file", limit=64 * 2**20), f"{path}: not a JSON rig file")
    except FileNotFoundError:
        raise ModelFileError(f"{path}: rig file not found") from None
    except InputError as exc:
        raise ModelFileError(str(exc)) from None
    if not isinstance(blob, dict):
        raise ModelFileError(f"{path}: a rig file must hold a JSON object")
    unknown = sorted(set(blob) - {"kind", "format_version", "params", "card"})
    if unknown:  # never ignored: a misspelt "card" would drop the card silently
        raise ModelFileError(
            f"{path}: field {unknown[0]!r:.60} is no rig file field (kind, format_version, params, card)"
        )
    if blob.get("kind") != kind:
        raise ModelFileError(f"{path}: field 'kind' is {blob.get('kind')!r}, expected {kind!r}")
    if isinstance(blob.get("format_version"), bool) or blob.get("format_version") != RIG_FORMAT_VERSION:
        raise ModelFileError(
            f"{path}: field 'format_version' is {blob.get('format_version')!r}; this version reads "
            f"[{RIG_FORMAT_VERSION}]"
        )
    params, card = blob.get("params"), blob.get("card", {})
    if not isinstance(params, dict):
        raise ModelFileError(f"{path}: field 'params' must be a JSON object")
    if not isinstance(card, dict):
        raise ModelFileError(f"{path}: field 'card' must be a JSON object")
    validate_params(params, constraints, source=path)
    return params, card


R = TypeVar("R")


def read_rig(
    path: str | os.PathLike[str], kind: str, constraints: dict[str, list[Constraint]], cls: Callable[..., R]
) -> tuple[R, dict[str, Any]]:
    """Read a rig file and build ``cls(**params)`` (JSON lists as tuples); returns ``(rig, card)``.

    The rig's constructor checks relations between values and raises ``ValueError("<name>: <message>")``;
    that becomes a :class:`ModelFileError` naming the file and the field ``params.<name>``.

    Raises:
        ModelFileError: naming the file and the field at fault.
    """
    params, card = load_rig_file(path, kind, constraints)
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}
    try:
        return cls(**values), card
    except ValueError as exc:
        name, _, msg = str(exc).partition(":")
        raise ModelFileError(f"{path}: field 'params.{name}' is invalid: {msg.strip()}") from None
