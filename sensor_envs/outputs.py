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
* :func:`atomic_write` is the one-file form used by the library's own writers (given a transaction's
  temporary, it writes that file directly: one temporary per output, never a temporary of a temporary).
* :func:`check_output` also **claims** the output for the rest of the command: the claim is the
  output's temporary itself (``.<stem>.sensor-envs.tmp<suffix>``, or ``.<name>.sensor-envs.tmp`` for a
  folder) held under an exclusive ``flock``. A second run writing the same output meanwhile is refused
  (even with ``--force``); a temporary left by a killed run holds no lock and is taken over. Claims end
  with :func:`release_claims` (the command line calls it on every exit path; also at interpreter exit).
"""

from __future__ import annotations

import atexit
import fcntl
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from sensor_envs.inputs import InputError, real_path

__all__ = [
    "OutputError",
    "release_claims",
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


class OutputError(InputError):
    """An output path is unsafe or unsuitable (the message names the option and the file)."""


def _same(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name the same file (resolved paths, or ``samefile`` for links)."""
    if real_path(a) == real_path(b):
        return True
    try:
        return a.exists() and b.exists() and a.samefile(b)
    except OSError:
        return False


def _inside(child: Path, folder: Path) -> bool:
    try:
        real_path(child).relative_to(real_path(folder))
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
    if not folder and os.fspath(path).endswith(("/", os.sep)):  # Path() would drop the slash silently
        raise OutputError(f"{option}: {os.fspath(path)} ends in '/', which names a folder; expected a file name")
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
    if folder and p.exists():
        _check_replaceable(p, option)
    fresh = _claim(p, folder, option)
    try:
        _check_existing(p, folder, force, option)
    except BaseException:
        if fresh:
            _release(Path(os.path.abspath(p)))
        raise
    return p


def _shipped_models() -> Path | None:
    """The shipped models folder (package ``sensor_envs.models``), or ``None`` when it cannot be found."""
    from importlib import resources

    try:
        return Path(str(resources.files("sensor_envs.models")))
    except (ModuleNotFoundError, TypeError):
        return None


def _check_replaceable(p: Path, option: str) -> None:
    """Refuse an output folder (replaced as a whole) that is or holds what no command may replace.

    The current folder (``--out .`` or a parent of it: every command would run to its end and then fail
    to rename onto it) and the shipped model files (read by default by every env, ``demo``, ``evaluate``,
    ``train`` and ``rebuild-models``, whatever the command's inputs name).
    """
    for held, what in ((Path.cwd(), "the current folder"), (_shipped_models(), "the shipped model files")):
        if held is not None and _inside(held, p):
            raise OutputError(f"{option}: {p} is or holds {what} ({held}); refusing to replace that folder")


def _check_existing(p: Path, folder: bool, force: bool, option: str) -> None:
    if p.exists() or p.is_symlink():
        if folder and p.is_dir() and not p.is_symlink() and not any(p.iterdir()):
            return  # an empty folder: nothing to lose
        if folder != p.is_dir():
            what = "a folder" if p.is_dir() else "a file"
            raise OutputError(f"{option}: {p} exists and is {what}; choose another name")
        if not force:
            raise OutputError(f"{option}: {p} already exists; pass --force to replace it")


class _Claim:
    """A claimed output: its temporary (file or folder), the locked descriptor, the parent folders made."""

    def __init__(self, tmp: Path, fd: int, is_dir: bool, created: list[Path]) -> None:
        self.tmp, self.fd, self.is_dir, self.created = tmp, fd, is_dir, created


_CLAIMS: dict[Path, _Claim] = {}
_TEMPORARIES: set[Path] = set()
"""Absolute paths of the temporaries handed out by live transactions (written directly by atomic_write)."""


def _claim_path(target: Path, folder: bool) -> Path:
    if folder:
        return target.parent / f".{target.name}.sensor-envs.tmp"
    return target.parent / f".{target.stem}.sensor-envs.tmp{target.suffix}"


def _claim(path: Path, folder: bool, option: str) -> bool:
    """Claim ``path`` for this process (see the module docstring); returns whether the claim is new.

    Raises:
        OutputError: when another live run holds the claim.
    """
    key = Path(os.path.abspath(path))
    if key in _CLAIMS:
        return False
    created: list[Path] = []
    _make_parent(key, created)
    tmp = _claim_path(key, folder)
    for _ in range(5):  # the holder may remove its temporary between our open and our lock
        if folder:
            try:
                tmp.mkdir()
            except FileExistsError:
                pass
        fd = os.open(tmp, os.O_RDONLY if folder else os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            _remove_created(created)
            raise OutputError(
                f"{option}: {path} is being written by another sensor-envs run (its temporary {tmp.name} is "
                "locked); wait for it to end or choose another name"
            ) from None
        try:
            same = os.stat(tmp).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    else:  # pragma: no cover - a claim that keeps moving
        _remove_created(created)
        raise OutputError(f"{option}: {path}: could not claim the output (its temporary keeps changing)")
    if folder:  # a temporary left by a killed run: start empty
        for child in tmp.iterdir():
            _remove(child, child.is_dir())
    else:
        os.ftruncate(fd, 0)
    _CLAIMS[key] = _Claim(tmp, fd, folder, created)
    return True


def _remove_created(created: list[Path]) -> None:
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            pass


def _release(key: Path) -> None:
    c = _CLAIMS.pop(key, None)
    if c is None:
        return
    try:
        if os.stat(c.tmp).st_ino == os.fstat(c.fd).st_ino:  # not renamed onto the target: unused or rolled back
            _remove(c.tmp, c.is_dir)
    except FileNotFoundError:
        pass
    finally:
        os.close(c.fd)
    _TEMPORARIES.discard(c.tmp)
    _remove_created(c.created)


def release_claims() -> None:
    """End every claim of this process: unused temporaries are removed, the locks released."""
    for key in list(_CLAIMS):
        _release(key)


atexit.register(release_claims)


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
        claim = _CLAIMS.get(Path(os.path.abspath(t)))
        if claim is not None and not claim.is_dir:  # the claimed temporary is this output's one temporary
            tmp = str(claim.tmp)
        else:
            _make_parent(t, self._created)
            fd, tmp = tempfile.mkstemp(prefix=f".{t.stem}.", suffix=f".tmp{t.suffix}", dir=t.parent)
            os.close(fd)
        os.chmod(tmp, _mode(t, 0o666))  # mkstemp makes 0600; give what a plain open() would (or the old mode)
        self._items.append((t, Path(tmp), False))
        _TEMPORARIES.add(Path(os.path.abspath(tmp)))
        return Path(tmp)

    def folder(self, target: PathLike) -> Path:
        """A temporary folder beside ``target`` to build the output folder in."""
        t = Path(target)
        claim = _CLAIMS.get(Path(os.path.abspath(t)))
        if claim is not None and claim.is_dir:
            tmp = claim.tmp
        else:
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
            _TEMPORARIES.discard(Path(os.path.abspath(tmp)))
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
        for _, tmp, _ in self._items:
            _TEMPORARIES.discard(Path(os.path.abspath(tmp)))
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
    if Path(os.path.abspath(path)) in _TEMPORARIES:  # already a transaction's temporary: no temporary of it
        return write(Path(path))
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
