"""Pickle-free model files: one ``.npz`` of plain arrays plus a JSON header, with a format version.

Layout of a model file: arrays under their own names, and ``__header__``, a uint8 array holding
UTF-8 JSON ``{"kind": ..., "format_version": ..., "params": {...}, "card": {...}}``. Files load
with ``allow_pickle=False``; every array is checked for the dtype kind and the shape rank the
loader declares, and for finiteness where asked.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from sensor_envs.outputs import atomic_write, check_suffix

__all__ = ["ModelFileError", "save_model_file", "load_model_file", "read_model"]


class ModelFileError(ValueError):
    """A model file is unreadable, of the wrong kind or version, or holds a malformed field."""


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
    atomic_write(
        path, lambda tmp: np.savez_compressed(tmp, __header__=blob, **{k: np.asarray(v) for k, v in arrays.items()})
    )
    return path


def load_model_file(
    path: str | os.PathLike[str],
    kind: str,
    supported_versions: tuple[int, ...],
    schema: dict[str, tuple[str, int | None, bool]],
) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """Read a model file written by :func:`save_model_file`, without pickle, and check it.

    Args:
        path: the ``.npz`` file.
        kind: the expected ``kind`` in the header.
        supported_versions: format versions this loader understands.
        schema: ``name -> (dtype kinds, ndim or None, must be finite)``; dtype kinds as numpy
            ``dtype.kind`` letters, e.g. ``"f"``, ``"iu"``, ``"b"``.

    Returns:
        ``(header, arrays)``.

    Raises:
        ModelFileError: naming the file and the field at fault.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise ModelFileError(f"{path}: model file not found") from None
    except Exception as exc:  # zip/npz damage, pickled content, ...
        raise ModelFileError(f"{path}: not a readable model file ({exc})") from exc
    if "__header__" not in data:
        raise ModelFileError(f"{path}: field '__header__' is missing (not a sensor_envs model file)")
    try:
        header = json.loads(data.pop("__header__").tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError) as exc:
        raise ModelFileError(f"{path}: field '__header__' is not valid JSON ({exc})") from None
    if not isinstance(header, dict):
        raise ModelFileError(f"{path}: field '__header__' must be a JSON object, got a JSON {type(header).__name__}")
    if header.get("kind") != kind:
        raise ModelFileError(f"{path}: field 'kind' is {header.get('kind')!r}, expected {kind!r}")
    if header.get("format_version") not in supported_versions:
        raise ModelFileError(
            f"{path}: field 'format_version' is {header.get('format_version')!r}; this version of sensor_envs "
            f"reads {list(supported_versions)}"
        )
    for key, typ in (("params", dict), ("card", dict)):
        if key not in header and key == "params":
            raise ModelFileError(f"{path}: field '__header__' lacks {key!r}")
        if key in header and not isinstance(header[key], typ):
            raise ModelFileError(f"{path}: field '__header__' entry {key!r} must be a JSON object")
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
    return header, data
