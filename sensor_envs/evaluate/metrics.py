"""Precision/recall arithmetic, Wilson intervals and distances between precision-recall trajectories."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["precision_recall", "wilson_interval", "trajectory_distance"]


def precision_recall(tp: int, fp: int, fn: int) -> tuple[float, float]:
    """Precision ``tp / (tp + fp)`` and recall ``tp / (tp + fn)``.

    An empty denominator gives precision 1 (no detection, no false one) and recall 1 (nothing to find),
    the usual convention that keeps trajectories finite.
    """
    if min(tp, fp, fn) < 0:
        raise ValueError(f"counts must be >= 0, got tp={tp}, fp={fp}, fn={fn}")
    p = tp / (tp + fp) if tp + fp else 1.0
    r = tp / (tp + fn) if tp + fn else 1.0
    return float(p), float(r)


def wilson_interval(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``k / n`` (95 % for ``z = 1.96``); ``(0, 1)`` for ``n = 0``."""
    if not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return float(max(0.0, centre - half)), float(min(1.0, centre + half))


def trajectory_distance(a: Sequence[dict[str, Any]], b: Sequence[dict[str, Any]]) -> float:
    """Mean point-wise Euclidean distance in (precision, recall) between two trajectories of the same steps.

    Args:
        a: list of ``{"step", "precision", "recall"}``.
        b: the same steps in the same order.

    Raises:
        ValueError: when the steps differ.
    """
    if [s["step"] for s in a] != [s["step"] for s in b]:
        raise ValueError("trajectories: the two lists have different steps")
    if not a:
        raise ValueError("trajectories: empty")
    pa = np.array([[s["precision"], s["recall"]] for s in a], dtype=float)
    pb = np.array([[s["precision"], s["recall"]] for s in b], dtype=float)
    return float(np.linalg.norm(pa - pb, axis=1).mean())
