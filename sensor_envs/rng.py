"""The sensors' own random streams, kept apart from the world's."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.inputs import InputError
from sensor_envs.jit import compiled

__all__ = ["sensor_rng", "fold_ids", "RowGenerators"]


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
        raise InputError(f"n_folds: must be >= 1, got {n_folds!r}")
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


class RowGenerators:
    """Batched draws whose row ``i`` comes from ``generators[i]`` alone (a stand-in for one ``Generator``).

    A sensor that samples a ``(N, ...)`` batch with ``rng.random(shape)`` / ``rng.standard_normal(shape)``
    / ``rng.uniform(low, high, shape)`` gets, row by row, exactly the numbers that N separate calls with
    ``shape[1:]`` on the N generators would give: one batched sensor call serves N independent worlds
    whose streams stay their own (a vector env then matches N single envs seed for seed).

    With numba (the ``fast`` extra) one compiled loop draws all rows from the generators themselves (numba
    draws a ``Generator``'s own stream, number for number); it reads them from a numba list built once per
    object, so a caller that draws every step keeps one ``RowGenerators`` (see :meth:`replace`, :meth:`select`).
    """

    def __init__(self, generators: Sequence[np.random.Generator]) -> None:
        self.generators = list(generators)
        self._typed: Any = None  # numba list of the generators, built on the first compiled draw
        self._parent: RowGenerators | None = None  # a select()ion draws through its parent's list ...
        self._index: NDArray[np.int64] | None = None  # ... at these rows of it

    def __getstate__(self) -> dict[str, Any]:
        """Pickle (and deepcopy) the generators only: the copy stands alone, its numba list built on its first draw."""
        return {"generators": self.generators, "_typed": None, "_parent": None, "_index": None}

    def replace(self, row: int, generator: np.random.Generator) -> None:
        """Row ``row`` draws from ``generator`` from now on (a robot's stream after a seeded reset)."""
        if self._parent is not None:
            raise ValueError("RowGenerators: replace a row of the full set, not of a select()ion")
        if self.generators[row] is not generator:
            self.generators[row] = generator
            if self._typed is not None:
                self._typed[row] = generator

    def select(self, rows: ArrayLike) -> RowGenerators:
        """The generators of ``rows`` (in that order) as a ``RowGenerators`` drawing through this one's numba list."""
        idx = np.asarray(rows, dtype=np.int64)
        out = RowGenerators([self.generators[i] for i in idx])
        out._parent = self if self._parent is None else self._parent
        out._index = idx if self._index is None else self._index[idx]
        return out

    def _compiled_list(self) -> Any:
        """The numba list drawn from (a selection's is its parent's), built once.

        None without numba, or when a generator is not a ``numpy.random.Generator`` (then numpy draws).
        """
        if self._parent is not None:
            return self._parent._compiled_list()
        if self._typed is None and compiled(_draw_rows) is not None:
            if all(type(g) is np.random.Generator for g in self.generators):
                from numba.typed import List

                self._typed = List(self.generators)
        return self._typed

    def _rows(
        self, draw: Callable[[np.random.Generator, tuple[int, ...]], Any], size: Any, kind: int, low: float, high: float
    ) -> NDArray[np.float64]:
        shape = (size,) if isinstance(size, (int, np.integer)) else tuple(size or ())
        if not shape or shape[0] != len(self.generators):
            raise ValueError(f"RowGenerators: size {shape} must lead with the number of rows {len(self.generators)}")
        typed = self._compiled_list()
        if typed is None:
            return np.stack([draw(g, shape[1:]) for g in self.generators])
        out = np.empty(shape)
        index = np.arange(shape[0], dtype=np.int64) if self._index is None else self._index
        kernel = compiled(_draw_rows)
        assert kernel is not None
        kernel(typed, index, out.reshape(shape[0], -1), kind, float(low), float(high))
        return out

    def random(self, size: Any = None) -> NDArray[np.float64]:
        """Uniform [0, 1) draws of shape ``size`` (``size[0]`` = number of rows)."""
        return self._rows(lambda g, s: g.random(s), size, 0, 0.0, 1.0)

    def standard_normal(self, size: Any = None) -> NDArray[np.float64]:
        """Standard normal draws of shape ``size`` (``size[0]`` = number of rows)."""
        return self._rows(lambda g, s: g.standard_normal(s), size, 1, 0.0, 1.0)

    def uniform(self, low: float = 0.0, high: float = 1.0, size: Any = None) -> NDArray[np.float64]:
        """Uniform ``[low, high)`` draws (scalar bounds) of shape ``size`` (``size[0]`` = number of rows)."""
        return self._rows(lambda g, s: g.uniform(low, high, s), size, 2, low, high)

    def __getattr__(self, name: str) -> Any:
        raise AttributeError(f"RowGenerators: {name!r} is not supported row by row (random, standard_normal, uniform)")


def _draw_rows(
    generators: Any, index: NDArray[np.int64], out: NDArray[np.float64], kind: int, low: float, high: float
) -> None:
    """Fill row ``p`` of ``out (P, n)`` from ``generators[index[p]]``, element by element.

    ``kind``: 0 uniform [0, 1), 1 standard normal, 2 uniform [low, high). Numba draws a ``Generator``'s own
    stream one number at a time, which is the stream a batched numpy call of that generator draws.
    """
    for p in range(out.shape[0]):
        g = generators[index[p]]
        if kind == 0:
            for i in range(out.shape[1]):
                out[p, i] = g.random()
        elif kind == 1:
            for i in range(out.shape[1]):
                out[p, i] = g.standard_normal()
        else:
            for i in range(out.shape[1]):
                out[p, i] = g.uniform(low, high)
