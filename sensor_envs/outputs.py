"""Safe outputs: never write over an input, refuse an existing output unless forced, write atomically.

Every command that writes files goes through this module:

* :func:`check_output` refuses an output that is one of the command's inputs (same file, or a folder
  holding an input), an existing output unless ``force`` (an existing *empty* folder holds nothing to
  lose and is accepted), and a file suffix that does not match the format (an error, never a silent
  rename).
* :class:`OutputTransaction` hands out temporary paths in the target's own folder (files: a hidden
  sibling with the same suffix; folders: a hidden sibling folder) and only on success renames them
  onto the targets with :func:`os.replace`; an existing target is replaced only after every output
  was written, so a failed or killed command leaves the old files intact and no half-written output.
* :func:`atomic_write` is the one-file form used by the library's own writers.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

__all__ = [
    "OutputError",
    "check_inputs",
    "check_output",
    "check_suffix",
    "OutputTransaction",
    "atomic_write",
    "jsonable",
    "output_folder",
    "write_json",
]

PathLike = str | os.PathLike[str]
T = TypeVar("T")


class OutputError(ValueError):
    """An output path is unsafe or unsuitable (the message names the option and the file)."""


def _same(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name the same file (resolved paths, or ``samefile`` for links)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and a.samefile(b)
    except OSError:
        return False


def _inside(child: Path, folder: Path) -> bool:
    try:
        child.resolve().relative_to(folder.resolve())
    except ValueError:
        return False
    return True


def check_suffix(path: PathLike, suffixes: str | tuple[str, ...], option: str = "--out") -> Path:
    """``path`` as a :class:`Path` if its suffix is one of ``suffixes``, else an :class:`OutputError`."""
    p = Path(path)
    allowed = (suffixes,) if isinstance(suffixes, str) else suffixes
    if p.suffix not in allowed:
        raise OutputError(
            f"{option}: {p}: the file name must end in {' or '.join(allowed)} for this format, got "
            f"{p.suffix or 'no suffix'!r}"
        )
    return p


def check_inputs(*paths: PathLike | None) -> None:
    """Raise ``FileNotFoundError`` naming the first input that does not exist (checked before the outputs)."""
    for p in paths:
        if p is not None and not Path(p).exists():
            raise FileNotFoundError(f"{p}: input not found")


def check_output(
    path: PathLike,
    *,
    inputs: Iterable[PathLike | None] = (),
    force: bool = False,
    suffix: str | tuple[str, ...] | None = None,
    folder: bool = False,
    option: str = "--out",
) -> Path:
    """Check that writing ``path`` is safe, before any work is done.

    Args:
        path: the output file or folder.
        inputs: the command's input files/folders (``None`` entries are ignored).
        force: allow replacing an existing output (never an input).
        suffix: required file suffix(es), e.g. ``".npz"``.
        folder: ``path`` is an output folder (replaced as a whole).
        option: the command-line option, for messages.

    Returns:
        ``path`` as a :class:`Path`.

    Raises:
        OutputError: naming the option and the file.
    """
    p = Path(path)
    if suffix is not None:
        check_suffix(p, suffix, option)
    for src in inputs:
        if src is None:
            continue
        s = Path(src)
        if _same(p, s):
            raise OutputError(f"{option}: {p} is also an input of this command; refusing to write over it")
        if folder and p.exists() and _inside(s, p):
            raise OutputError(f"{option}: {p} holds the input {s}; refusing to replace that folder")
    if p.exists() or p.is_symlink():
        if folder and p.is_dir() and not p.is_symlink() and not any(p.iterdir()):
            return p  # an empty folder: nothing to lose
        if folder != p.is_dir():
            what = "a folder" if p.is_dir() else "a file"
            raise OutputError(f"{option}: {p} exists and is {what}; choose another name")
        if not force:
            raise OutputError(f"{option}: {p} already exists; pass --force to replace it")
    return p


def _make_parent(path: Path, created: list[Path]) -> None:
    """``mkdir -p`` the parent of ``path``, recording the folders created (deepest last)."""
    missing = []
    d = path.parent
    while not d.exists():
        missing.append(d)
        d = d.parent
    for m in reversed(missing):
        m.mkdir()
        created.append(m)


class OutputTransaction:
    """All-or-nothing outputs: temporary siblings while writing, renamed onto the targets on success.

    Use as a context manager::

        with OutputTransaction() as tx:
            save_model(tx.file("model.npz"))
            write_card(tx.file("model.md"))
        # both renamed here; on an exception neither target is touched and the temporaries are gone
    """

    def __init__(self) -> None:
        self._items: list[tuple[Path, Path, bool]] = []  # (target, temporary, is_folder)
        self._created: list[Path] = []

    def file(self, target: PathLike) -> Path:
        """A temporary path beside ``target`` (same suffix) to write the file into."""
        t = Path(target)
        _make_parent(t, self._created)
        fd, tmp = tempfile.mkstemp(prefix=f".{t.stem}.", suffix=f".tmp{t.suffix}", dir=t.parent)
        os.close(fd)
        os.chmod(tmp, _mode(t, 0o666))  # mkstemp makes 0600; give what a plain open() would (or the old mode)
        self._items.append((t, Path(tmp), False))
        return Path(tmp)

    def folder(self, target: PathLike) -> Path:
        """A temporary folder beside ``target`` to build the output folder in."""
        t = Path(target)
        _make_parent(t, self._created)
        tmp = Path(tempfile.mkdtemp(prefix=f".{t.name}.", suffix=".tmp", dir=t.parent))
        os.chmod(tmp, _mode(t, 0o777))
        self._items.append((t, tmp, True))
        return tmp

    def __enter__(self) -> OutputTransaction:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.rollback()

    def rollback(self) -> None:
        """Remove every temporary (and the parent folders this transaction created)."""
        for _, tmp, is_dir in self._items:
            _remove(tmp, is_dir)
        self._items.clear()
        for d in reversed(self._created):
            try:
                d.rmdir()
            except OSError:
                pass
        self._created.clear()

    def commit(self) -> None:
        """Rename the temporaries onto the targets; if a rename fails, every target is restored."""
        kept: list[tuple[Path, Path | None, bool]] = []  # (target, its old version set aside or None, is_folder)
        try:
            for target, tmp, is_dir in self._items:
                aside = None
                if target.exists():
                    aside = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
                    aside.rmdir()
                    if is_dir:
                        os.replace(target, aside)  # a folder cannot be replaced in one step
                    else:
                        try:
                            os.link(target, aside)  # the target stays in place until os.replace below
                        except OSError:
                            shutil.copy2(target, aside)
                kept.append((target, aside, is_dir))
                os.replace(tmp, target)
        except BaseException:
            for target, aside, is_dir in reversed(kept):  # undo: new outputs away, old ones back
                if aside is None:
                    _remove(target, is_dir)
                else:
                    if is_dir and target.exists():
                        _remove(target, True)
                    os.replace(aside, target)
            self.rollback()
            raise
        for _, aside, is_dir in kept:
            if aside is not None:
                _remove(aside, is_dir)
        self._items.clear()
        self._created.clear()


def _mode(target: Path, base: int) -> int:
    """Permission bits for a new ``target``: the existing file's, else ``base`` minus the umask."""
    try:
        return target.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return base & ~umask


def _remove(path: Path, is_dir: bool) -> None:
    if is_dir and path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


@contextmanager
def _one(target: Path) -> Iterator[Path]:
    with OutputTransaction() as tx:
        yield tx.file(target)


def atomic_write(path: PathLike, write: Callable[[Path], T]) -> T:
    """Call ``write(tmp)`` on a temporary sibling of ``path``, then rename it onto ``path``.

    A failure inside ``write`` leaves ``path`` as it was (old content or absent) and no temporary.
    """
    with _one(Path(path)) as tmp:
        return write(tmp)


def jsonable(x: Any) -> Any:
    """``x`` as strict JSON data: numpy scalars and arrays as Python numbers and lists, NaN/inf as ``None``."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if hasattr(x, "tolist") and not isinstance(x, (str, bytes)):  # numpy arrays and scalars
        return jsonable(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_json(path: PathLike, data: Any) -> Path:
    """Write ``data`` as strict JSON (no bare ``NaN``: undefined figures are ``null``) to ``path``."""
    p = Path(path)
    p.write_text(json.dumps(jsonable(data), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return p


@contextmanager
def output_folder(out: PathLike, force: bool, inputs: Iterable[PathLike | None] = ()) -> Iterator[Path]:
    """A temporary folder beside ``out``, renamed onto ``out`` only when the block succeeds.

    The inputs must exist; ``out`` must not be (or hold) one of them; an existing ``out`` needs ``force``.
    """
    inputs = list(inputs)
    check_inputs(*inputs)
    target = check_output(out, inputs=inputs, force=force, folder=True)
    with OutputTransaction() as tx:
        yield tx.folder(target)
