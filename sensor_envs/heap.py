"""Keep freed heap memory in the process, so per-step batch arrays do not page-fault (glibc only).

A vector step of 64 Neato robots allocates and frees a dozen ``(64, 360)`` float64 arrays (184 KB each).
glibc's malloc serves such sizes with ``mmap`` or trims them off the heap top when freed, so every step
touches fresh pages: ~200 minor page faults and ~0.55 ms of a ~1.4 ms ideal-lidar step (measured with
``benchmarks/bench_neato_vector.py``). Raising glibc's mmap and trim thresholds keeps that memory mapped
for reuse, at the cost of holding up to :data:`TRIM_THRESHOLD` bytes of freed memory in the process.

Opt-in: nothing in the package calls :func:`keep_freed_heap` as a side effect. Call it yourself (e.g. at the
start of a training script) or build the vector env with ``tune_heap=True``::

    gym.make_vec("sensor_envs/Neato-v0", num_envs=64, vectorization_mode="vector_entry_point", tune_heap=True)
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["keep_freed_heap", "MMAP_THRESHOLD", "TRIM_THRESHOLD"]

MMAP_THRESHOLD = 32 << 20
"""Allocations below this many bytes come from the heap, not from their own ``mmap`` (glibc's default is
128 KB, raised dynamically up to 32 MB as large blocks are freed)."""
TRIM_THRESHOLD = 64 << 20
"""Freed memory at the heap top is returned to the system only beyond this many bytes."""

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameter numbers (malloc.h)
_applied: bool | None = None


def keep_freed_heap() -> bool:
    """Set glibc's mmap and trim thresholds once per process; whether they are set.

    Does nothing (returns False) off Linux, without glibc's ``mallopt``, or when the environment variable
    ``SENSOR_ENVS_NO_HEAP_TUNING`` is set to anything but ``0`` or empty. The same effect from outside:
    ``MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=67108864`` in the environment of the process.
    """
    global _applied
    if _applied is None:
        _applied = False
        if sys.platform.startswith("linux") and os.environ.get("SENSOR_ENVS_NO_HEAP_TUNING", "") in ("", "0"):
            try:
                mallopt = ctypes.CDLL(None).mallopt  # the process's C library
            except (OSError, AttributeError):
                return False
            mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
                mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
            )
    return _applied
