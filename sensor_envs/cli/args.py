"""Typed argparse helpers: values are checked when the command line is parsed, naming the option."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import NoReturn

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
    "add_force",
    "MAX_SEED",
]

MAX_SEED = 2**63 - 1
"""Largest accepted seed (numpy's ``SeedSequence`` takes any integer >= 0; larger ones are refused as typos)."""


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (exit status 2), naming the option."""

    def error(self, message: str) -> NoReturn:  # noqa: D102
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _integer_at_least(text: str, low: int, expected: str) -> int:
    """``text`` as an integer ``>= low``; ``"1e3"`` and ``"2.5"`` are refused, not truncated."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
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


def path_arg(text: str) -> str:
    """A path option (argparse ``type=``): a non-empty name without NUL bytes (``--rig ''`` is an error)."""
    if not text.strip() or "\x00" in text:
        raise argparse.ArgumentTypeError(f"expected a file name, got {text!r}")
    return text


def positive_float(text: str) -> float:
    """A finite number ``> 0`` (argparse ``type=``); ``nan``, ``inf``, ``0`` and negatives are refused."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def float_between(low: float, high: float) -> Callable[[str], float]:
    """An argparse ``type=`` accepting a finite number in ``[low, high]`` (e.g. a model's accepted range)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"expected a number in [{low:g}, {high:g}], got {text!r}")
        return value

    return parse


def add_force(parser: argparse.ArgumentParser) -> None:
    """Add ``--force`` (replace existing outputs; inputs are never replaced)."""
    parser.add_argument("--force", action="store_true", help="replace existing outputs (never an input of the command)")


@contextmanager
def about(path: str | Path) -> Iterator[None]:
    """Prefix ``path`` to a ``ValueError`` raised inside (e.g. a log too small to fit) unless it names it."""
    try:
        yield
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise InputError(f"{path}: {exc}") from exc
