"""Declared forms of a value: the constraints of the hyperparameter tables and model-file header schemas.

Each constraint has ``accepts(value) -> bool`` and a ``str`` that says what it expects; a table maps a name to a
list of accepted forms (any one suffices; ``None`` in the list accepts ``None``). They are checked by
:func:`sensor_envs.modelio.validate_params` (hyperparameters, constructor and configuration arguments) and
:func:`sensor_envs.modelio.check_header` (a model file's fitted header fields); ``sensor_envs.modelio``
re-exports them.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

__all__ = [
    "Options",
    "Interval",
    "Numbers",
    "Names",
    "InstanceOf",
    "IsNaN",
    "Constraint",
    "MAX_MAGNITUDE",
    "is_subnormal",
    "RANDOM_STATE",
    "CYCLE_TIME",
]


class Options:
    """Constraint: the value is one of ``values`` (compared with ``==``, booleans kept apart from numbers)."""

    def __init__(self, *values: Any) -> None:
        self.values = values

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` satisfies the constraint."""
        return any(type(value) is type(v) and value == v for v in self.values) or any(
            isinstance(v, str) and isinstance(value, str) and value == v for v in self.values
        )

    def __str__(self) -> str:
        return f"one of {self.values}"


MAX_MAGNITUDE = 1e9
"""Largest ``|value|`` of a number (real or integer) on a side where its interval is unbounded (sane magnitudes)."""


class Interval:
    """Constraint: a real (or, with ``integer``, a whole) number in ``[low, high]`` (``None``: up to 1e9 in size).

    A declared bound may exceed 1e9 (e.g. a seed up to 2**63 - 1).

    ``open_low``/``open_high`` exclude the bound. Booleans are not numbers here, and neither is a subnormal
    (``0 < |value| < 2.2e-308``, e.g. ``5e-324``): no value anyone meant, and ``1 / value`` is infinite.
    """

    def __init__(
        self,
        low: float | None,
        high: float | None,
        *,
        integer: bool = False,
        open_low: bool = False,
        open_high: bool = False,
    ) -> None:
        self.low, self.high, self.integer = low, high, integer
        self.open_low, self.open_high = open_low, open_high

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` satisfies the constraint."""
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            return False
        if self.integer and not isinstance(value, (int, np.integer)):
            return False
        v = float(value)
        if not np.isfinite(v) or is_subnormal(v):
            return False
        if (self.high is None and v > MAX_MAGNITUDE) or (self.low is None and v < -MAX_MAGNITUDE):
            return False  # an unbounded side still has a sane magnitude (counts too: 10**19 tuples is no count)
        if self.low is not None and (v < self.low or (self.open_low and v == self.low)):
            return False
        return not (self.high is not None and (v > self.high or (self.open_high and v == self.high)))

    def __str__(self) -> str:
        kind = "an integer" if self.integer else "a finite number"
        lo = "(-inf" if self.low is None else f"{'(' if self.open_low else '['}{self.low:g}"
        hi = "inf)" if self.high is None else f"{self.high:g}{')' if self.open_high else ']'}"
        sane = f" within +-{MAX_MAGNITUDE:g}" if self.low is None or self.high is None else ""
        return f"{kind} in {lo}, {hi}{sane}"


class Numbers:
    """Constraint: a sequence (tuple or list) of numbers, each satisfying ``item``.

    Args:
        item: constraint of every element.
        length: exact length, or ``None``.
        min_length: least length.
        increasing: elements must be strictly increasing.
    """

    def __init__(
        self,
        item: Interval,
        *,
        length: int | None = None,
        min_length: int = 1,
        increasing: bool = False,
        nan: bool = False,
    ) -> None:
        self.item, self.length, self.min_length, self.increasing = item, length, min_length, increasing
        self.nan = nan

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` satisfies the constraint."""
        if not isinstance(value, (tuple, list, np.ndarray)) or (isinstance(value, np.ndarray) and value.ndim != 1):
            return False
        if len(value) < self.min_length or (self.length is not None and len(value) != self.length):
            return False
        if not all(self.item.accepts(v) or (self.nan and _is_nan(v)) for v in value):
            return False
        return not (self.increasing and not bool(np.all(np.diff(np.asarray(value, dtype=np.float64)) > 0)))

    def __str__(self) -> str:
        n = f"{self.length}" if self.length is not None else f">= {self.min_length}"
        inc = " strictly increasing" if self.increasing else ""
        return f"a sequence of {n}{inc} values, each {self.item}" + (" or NaN" if self.nan else "")


def is_subnormal(value: Any) -> bool:
    """Whether ``value`` is a non-zero real number smaller in size than the smallest normal float (``5e-324``)."""
    try:
        v = abs(float(value))
    except (TypeError, ValueError, OverflowError):
        return False
    return 0.0 < v < sys.float_info.min


def _is_nan(v: Any) -> bool:
    return isinstance(v, (float, np.floating)) and bool(np.isnan(v))


class Names:
    """Constraint: a sequence (tuple or list) of distinct non-empty strings (column or variable names).

    Args:
        max_length: most names.
    """

    def __init__(self, max_length: int = 64) -> None:
        self.max_length = max_length

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` satisfies the constraint."""
        if not isinstance(value, (tuple, list)) or len(value) > self.max_length:
            return False
        if not all(isinstance(v, str) and v.strip() and "\x00" not in v for v in value):
            return False
        return len(set(value)) == len(value)

    def __str__(self) -> str:
        return f"a sequence of at most {self.max_length} distinct non-empty names"


class InstanceOf:
    """Constraint: ``isinstance(value, types)`` (``bool`` only matches booleans)."""

    def __init__(self, *types: type) -> None:
        self.types = types

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` satisfies the constraint."""
        if isinstance(value, (bool, np.bool_)) and bool not in self.types:
            return False
        return isinstance(value, self.types)

    def __str__(self) -> str:
        if self.types == (bool,):
            return "True or False"
        return "an instance of " + " or ".join(t.__name__ for t in self.types)


class IsNaN:
    """Constraint: a NaN float (JSON ``NaN``: an absent fitted value, e.g. a model fitted without a cycle time)."""

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` satisfies the constraint."""
        return _is_nan(value)

    def __str__(self) -> str:
        return "NaN"


class _NoneConstraint:
    def accepts(self, value: Any) -> bool:
        return value is None

    def __str__(self) -> str:
        return "None"


Constraint = Options | Interval | Numbers | Names | InstanceOf | IsNaN | _NoneConstraint | None
"""One accepted form of a hyperparameter; ``None`` in a constraint list accepts ``None``."""
RANDOM_STATE: list[Constraint] = [None, Interval(0, 2**63 - 1, integer=True), InstanceOf(np.random.Generator)]
"""The constraints of a ``random_state`` hyperparameter (seed, generator or ``None``)."""
CYCLE_TIME: list[Constraint] = [None, IsNaN(), Interval(0, 1e4, open_low=True)]
"""The header field ``cycle_time`` [s] of a radar model: absent (``None``/NaN) or a positive duration."""
