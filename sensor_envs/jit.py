"""Optional numba compilation of hot loops (the ``fast`` extra), written once for every kernel.

A kernel is a plain Python function of numpy arrays and floats, written in loops that do the same float64
operations in the same order as the numpy path it replaces (no fused multiply-add, no fast-math), so the
compiled and the numpy path return the same bits. :func:`compiled` returns the numba version when numba is
installed and ``SENSOR_ENVS_NO_NUMBA`` is unset (or ``0``), else None (callers then take the numpy path).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

__all__ = ["compiled"]

_COMPILED: dict[Callable[..., Any], Callable[..., Any] | None] = {}


def compiled(loops: Callable[..., Any]) -> Callable[..., Any] | None:
    """``numba.njit(cache=True, nogil=True, error_model="numpy")(loops)``, built once per function; None without numba.

    ``error_model="numpy"``: a division by zero gives inf or NaN as in numpy, the path a kernel replaces,
    instead of raising; without the check per division, loops of divisions run ~3x faster.
    """
    if loops not in _COMPILED:
        kernel = None
        if os.environ.get("SENSOR_ENVS_NO_NUMBA", "") in ("", "0"):
            try:
                import numba
            except ImportError:
                pass
            else:
                kernel = numba.njit(cache=True, nogil=True, error_model="numpy")(loops)
        _COMPILED[loops] = kernel
    return _COMPILED[loops]
