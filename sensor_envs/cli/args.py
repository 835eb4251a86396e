"""Typed argparse helpers: values are checked when the command line is parsed, naming the option."""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

from sensor_envs.inputs import InputError

__all__ = [
    "about",
    "OneLineParser",
    "positive_int",
    "nonneg_int",
    "bounded_int",
    "positive_float",
    "float_between",
    "path_arg",
    "bounded_float",
    "declare_ranges",
    "INT_RANGES",
    "FLOAT_RANGES",
    "add_force",
    "printable",
    "text_arg",
    "MAX_SEED",
]

MAX_SEED = 2**63 - 1
"""Largest accepted seed (numpy's ``SeedSequence`` takes any integer >= 0; larger ones are refused as typos)."""


_INTEGER = re.compile(r"\s*\+?[0-9]+\s*")
_DECIMAL = re.compile(r"\s*[+-]?([0-9]+(?:\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?\s*")
"""Plain ASCII integers and decimals (``float``/``int`` would also take ``1_0``, ``nan`` and other scripts' digits)."""


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (exit status 2), naming the option."""

    def error(self, message: str) -> NoReturn:  # noqa: D102
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _integer_at_least(text: str, low: int, expected: str) -> int:
    """``text`` as an integer ``>= low``; ``"1e3"`` and ``"2.5"`` are refused, not truncated."""
    if not _INTEGER.fullmatch(text):  # int() would take "1_0" as 10 and Arabic-Indic digits
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    value = int(text)
    if value < low:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer ``>= 1`` (argparse ``type=``); ``"1e3"`` and ``"2.5"`` are refused, not truncated."""
    return _integer_at_least(text, 1, "a positive integer")


def nonneg_int(text: str) -> int:
    """An integer in ``[0, MAX_SEED]`` (argparse ``type=``), e.g. a seed."""
    value = _integer_at_least(text, 0, "an integer >= 0")
    if value > MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2**63 - 1], got {text!r}")
    return value


def bounded_int(low: int, high: int) -> Callable[[str], int]:
    """An argparse ``type=`` accepting an integer in ``[low, high]`` (counts: every count has an upper bound)."""
    expected = f"{'a positive integer' if low == 1 else f'an integer >= {low}'} up to {high}"

    def parse(text: str) -> int:
        value = _integer_at_least(text, low, expected)
        if value > high:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    return parse


_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
"""Control characters (C0, DEL, C1): no file name or word of an option holds one (a newline would split a message)."""
MAX_TEXT = 1000
"""Longest free-text option value [characters] (a note, a name, a ``KEY=VALUE``)."""


def path_arg(text: str) -> str:
    """A path option (argparse ``type=``): a non-blank name without control characters (``--rig ''`` is an error).

    A name that is not UTF-8 (surrogate escapes in ``sys.argv``) is a valid POSIX file name and passes.
    """
    if not text.strip() or _CONTROL.search(text):
        raise argparse.ArgumentTypeError(f"expected a file name, got {text!r}")
    return text


def text_arg(text: str) -> str:
    """A free-text option (argparse ``type=``): non-blank printable text of at most :data:`MAX_TEXT` characters.

    Every option without a declared type gets it (:func:`declare_ranges`): ``--extra-state ''``, ``--env ''``
    or an escape sequence are errors naming the option, never an empty name passed on.
    """
    if not text.strip() or not text.isprintable() or len(text) > MAX_TEXT:
        raise argparse.ArgumentTypeError(f"expected printable text of 1 to {MAX_TEXT} characters, got {text!r:.80}")
    return text


def path_object(text: str) -> Path:
    """:func:`path_arg` as a :class:`~pathlib.Path` (for options declared with ``type=Path``)."""
    return Path(path_arg(text))


def _decimal(text: str) -> float:
    """``text`` as a float: plain ASCII decimal, finite, representable (NaN for anything else).

    A subnormal (``4.9e-324``) or a non-zero number that rounds to zero (``1e-400``) is no value anyone
    meant: NaN, refused by the caller. ``-0`` is ``0.0``.
    """
    m = _DECIMAL.fullmatch(text)
    if not m:
        return math.nan
    value = float(text) + 0.0
    if (value == 0.0 and re.search(r"[1-9]", m.group(1))) or 0.0 < abs(value) < sys.float_info.min:
        return math.nan
    return value


def positive_float(text: str) -> float:
    """A finite number ``> 0`` (argparse ``type=``); ``nan``, ``inf``, ``0`` and negatives are refused."""
    value = _decimal(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def float_between(low: float, high: float) -> Callable[[str], float]:
    """An argparse ``type=`` accepting a finite number in ``[low, high]`` (e.g. a model's accepted range)."""

    def parse(text: str) -> float:
        value = _decimal(text)
        if not (math.isfinite(value) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"expected a number in [{low:g}, {high:g}], got {text!r}")
        return value

    return parse


def printable(text: str) -> str:
    """``text`` as valid UTF-8: a file name that is not UTF-8 (surrogate escapes in ``sys.argv``) shown with U+FFFD.

    For model cards and reports that quote the command line: a log with such a name is valid input and
    must not fail when the card is written after the whole fit.
    """
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def add_force(parser: argparse.ArgumentParser) -> None:
    """Add ``--force`` (replace existing outputs; inputs are never replaced)."""
    parser.add_argument("--force", action="store_true", help="replace existing outputs (never an input of the command)")


@contextmanager
def about(path: str | Path) -> Iterator[None]:
    """Prefix ``path`` to an :class:`InputError` raised inside (e.g. a log too small to fit) unless it names a file.

    A message that names ``path``, or starts with another file's name (``/dev/null: model file: ...``: another
    input of the command is at fault), is left as it is. Only input errors: any other exception (a
    ``ValueError`` from numpy included) is a bug and passes unchanged.
    """
    try:
        yield
    except InputError as exc:
        first = str(exc).split(": ", 1)[0]
        if str(path) in str(exc) or (": " in str(exc) and ("/" in first or os.path.exists(first))):
            raise
        raise type(exc)(f"{path}: {exc}") from exc


def bounded_float(low: float, high: float) -> Callable[[str], float]:
    """An argparse ``type=`` accepting a finite number in ``[low, high]`` (``nan``, ``inf``, ``1e300`` refused)."""
    parse = float_between(low, high)
    parse.__name__ = f"bounded_float({low:g}, {high:g})"
    return parse


INT_RANGES: dict[str, tuple[int, int]] = {
    "repeats": (1, 10_000),
    "poses": (1, 100_000),
    "targets": (1, 1_000),
    "sequences": (1, 100_000),
    "cycles": (1, 100_000),
    "permutations": (1, 100_000),
    "shifts": (0, 10_000),
    "max_add": (1, 50),
    "block_frames": (1, 1_000_000),
    "block_scans": (1, 1_000_000),
    "test_every": (1, 1_000),
    "bearings": (1, 100_000),
    "folds": (1, 1_000),
    "max_readings": (1, 1_000_000),
    "cv_block_scans": (1, 1_000_000),
    "max_evals": (1, 1_000_000),
    "mixture_max_components": (1, 50),
    "episodes": (1, 10_000),
    "steps": (1, 100_000),
    "configs": (1, 100_000),
    "draws": (1, 10_000),
    "seed": (0, 2**63 - 1),
    "seed0": (0, 2**63 - 1),
    "seeds": (1, 1_000),
    "workers": (1, 1_024),
    "block": (1, 100_000),
    "chains": (1, 10_000),
    "n_boot": (1, 100_000),
    "eval_episodes": (1, 10_000),
    "select_episodes": (1, 10_000),
}
"""Declared range of every integer option (by ``dest``): counts have upper bounds (``--repeats 1e9`` is refused)."""
FLOAT_RANGES: dict[str, tuple[float, float]] = {
    "cycle_time": (1e-3, 3600.0),
    "max_range": (0.01, 1000.0),
    "spur_above": (0.01, 1000.0),
    "table_range_step": (1e-3, 10.0),
    "alpha": (1e-12, 0.5),
    "min_score": (0.0, 1.0),
    "length": (1e-3, 100.0),
    "mixture_min_range": (0.0, 1000.0),
    "relevance_candidates": (1e-6, 1e6),
    "relevance_candidates_prev": (1e-6, 1e6),
}
"""Declared range of every real-valued option (by ``dest``): finite, sane magnitudes."""
PATH_OPTIONS = frozenset(
    {"out", "log", "model", "map", "real_data", "real", "rig", "baseline", "baseline_out", "astyx", "base", "config"}
    | {"spurious_only", "json", "metrics", "recipes"}
)
"""Options naming files: an empty name (``--rig ''``) is an error, never a silent fall-back to the default."""
_UNBOUNDED = {positive_int, nonneg_int, positive_float, float, int}


MAX_VALUES = 64
"""Most values one list option holds (``--relevance-candidates``, ``--factors``, ``--set``, ``--exclude``, ...)."""
_BOUNDED: dict[type, type] = {}


def _bound_list(action: argparse.Action) -> None:
    """Make ``action`` (``nargs='+'``/``'*'`` or ``append``) refuse more than :data:`MAX_VALUES` values, or one twice.

    A list is a count too: 100 000 bandwidth candidates would run for days. The error is argparse's own
    one line, naming the option.
    """
    base = type(action)
    if base not in _BOUNDED:

        class Bounded(base):  # type: ignore[valid-type,misc]
            def __call__(self, parser: Any, namespace: Any, values: Any, option_string: Any = None) -> None:
                super().__call__(parser, namespace, values, option_string)
                held = getattr(namespace, self.dest, None)
                held = held if isinstance(held, list) else []
                if len(held) > MAX_VALUES:
                    raise argparse.ArgumentError(self, f"at most {MAX_VALUES} values, got {len(held)}")
                twice = next((v for i, v in enumerate(held) if v in held[:i]), None)
                if twice is not None:  # a sensor, a column, a candidate named twice: a typo, never meant
                    raise argparse.ArgumentError(self, f"{twice!r:.60} is given twice")

        _BOUNDED[base] = Bounded
    action.__class__ = _BOUNDED[base]


def declare_ranges(parser: argparse.ArgumentParser) -> None:
    """Give every numeric option of ``parser`` (and its sub-commands) its declared range, every path a check.

    An option of type ``int``/``float``/``positive_int``/``positive_float`` gets the range of
    :data:`INT_RANGES`/:data:`FLOAT_RANGES` for its ``dest``; a numeric option without a declared range
    is a programming error (``KeyError`` at start-up, caught by the tests). Seeds (``nonneg_int``) keep
    their ``[0, 2**63 - 1]``.
    """
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                declare_ranges(sub)
            continue
        if action.nargs in ("+", "*") or isinstance(action, argparse._AppendAction):
            _bound_list(action)
        if action.nargs == 0 or action.choices is not None:  # a flag, or a choice argparse checks
            continue
        if action.type is None:  # a path, or free text: never blank, never a control character
            action.type = path_arg if action.dest in PATH_OPTIONS else text_arg
        if action.dest in PATH_OPTIONS and action.type is Path:
            action.type = path_object
        if action.type not in _UNBOUNDED or action.type is nonneg_int:
            continue
        if action.type in (positive_int, int):
            action.type = bounded_int(*INT_RANGES[action.dest])
        else:
            action.type = bounded_float(*FLOAT_RANGES[action.dest])
