"""The sensors' own random streams, kept apart from the world's."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["sensor_rng", "fold_ids"]


def sensor_rng(seed: int | None, tag: int, current: np.random.Generator | None) -> np.random.Generator:
    """The generator a sensor uses after ``reset(seed=seed)``.

    A given ``seed`` derives a fresh stream from ``SeedSequence([seed, tag])`` (``tag`` tells sensors
    apart), so sensor noise never draws from the world's stream; ``seed=None`` continues ``current``,
    or starts from fresh entropy when the sensor was never seeded.
    """
    if seed is not None:
        return np.random.default_rng(np.random.SeedSequence([int(seed), int(tag)]))
    return current if current is not None else np.random.default_rng()


def fold_ids(
    groups: int | ArrayLike, n_folds: int, random_state: int | np.random.Generator | None = None
) -> NDArray[np.int64]:
    """Cross-validation fold of every row: the groups dealt round-robin into ``n_folds`` folds.

    The one fold assignment of the project (leave-poses-out lidar CV, the radar's sequence and block folds).

    Args:
        groups: ``n`` (``n`` rows, each its own group) or the group key of every row, ``(n,)`` or ``(n, d)``;
            rows with equal keys share a fold. Groups are ranked by key (``np.unique`` order).
        n_folds: number of folds (``>= 1``).
        random_state: ``None`` deals group ``g`` (by rank) to fold ``g % n_folds``; a seed or generator
            shuffles that deal (``permutation(arange(n_groups) % n_folds)``), keeping the fold sizes.

    Returns:
        ``(n,)`` fold ids in ``[0, n_folds)``.
    """
    if int(n_folds) < 1:
        raise ValueError(f"n_folds: must be >= 1, got {n_folds!r}")
    if isinstance(groups, (int, np.integer)):
        rank: Any = np.arange(int(groups))
        n_groups = int(groups)
    else:
        keys = np.asarray(groups)
        _, inv = np.unique(keys, axis=0 if keys.ndim > 1 else None, return_inverse=True)
        rank = inv.ravel()
        n_groups = int(rank.max(initial=-1)) + 1
    deal = np.arange(n_groups) % int(n_folds)
    if random_state is not None:
        deal = np.random.default_rng(random_state).permutation(deal)
    return deal[rank].astype(np.int64)
