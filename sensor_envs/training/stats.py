"""rliable-style statistics of a few RL runs: interquartile mean, bootstrap intervals, probability of improvement.

After Agarwal et al., "Deep Reinforcement Learning at the Edge of the Statistical Precipice" (NeurIPS 2021) and
their ``rliable`` library, written here with numpy and scipy: ``rliable`` installs from PyPI, but its required
dependency ``arch`` (< 8) does not import with pandas 3 (``deprecate_kwarg`` changed signature), so the
package cannot use it.

A score matrix has one row per run (a training seed's policy) and one column per evaluation episode (every
run plays episode ``e`` from the same start: evaluation seed ``EVAL_SEED + e``). The bootstrap is stratified
by cell (each cell of the matrix, and each side of a comparison, is resampled on its own) and resamples the
runs of a cell whole, with all their episodes: a run's episodes share its policy, so they are not independent
draws. (rliable resamples runs within each *task*; taking episodes as the tasks would resample the runs
independently per episode and lose the shared policy: see docs/howto/training.md for what that does to the
coverage.) With a single run the episodes are resampled instead. Percentile intervals of a statistic of
values in [0, 1] (a rate) stay inside [0, 1].
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["iqm", "mean", "bootstrap_ci", "probability_of_improvement", "probability_of_improvement_ci"]

Statistic = Callable[[NDArray[np.float64]], float]


def _scores(scores: ArrayLike) -> NDArray[np.float64]:
    """``scores`` as a float (runs, strata) matrix; a 1-D array is one stratum."""
    x = np.asarray(scores, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.size == 0:
        raise ValueError(f"scores: expected a non-empty (runs, strata) matrix, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("scores: not all finite")
    return x


def iqm(scores: ArrayLike) -> float:
    """Interquartile mean of all values: the mean of the middle 50 % (``scipy.stats.trim_mean(x, 0.25)``)."""
    from scipy import stats

    return float(stats.trim_mean(_scores(scores).ravel(), 0.25))


def mean(scores: ArrayLike) -> float:
    """Mean of all values."""
    return float(_scores(scores).mean())


def _runs(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """The resampling units of a cell: its runs (rows), or the episodes of a single run."""
    return x.T if x.shape[0] == 1 else x


def _resample(x: NDArray[np.float64], rng: np.random.Generator, reps: int) -> NDArray[np.float64]:
    """``reps`` bootstrap replicates of ``x`` stacked as ``(reps, runs, strata)``.

    Each replicate has as many rows as ``x``, drawn whole with replacement.
    """
    return x[rng.integers(0, x.shape[0], size=(reps, x.shape[0]))]


def _batched(statistic: Statistic, samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """``statistic`` of each replicate of ``samples`` (reps, runs, strata); :func:`iqm` and :func:`mean` at once."""
    from scipy import stats

    flat = samples.reshape(samples.shape[0], -1)
    if statistic is iqm:
        return np.asarray(stats.trim_mean(flat, 0.25, axis=1), dtype=np.float64)
    if statistic is mean:
        return flat.mean(axis=1)
    return np.array([statistic(sample) for sample in samples])


def _percentile(values: NDArray[np.float64], level: float) -> tuple[float, float]:
    alpha = (1.0 - level) / 2
    lo, hi = np.quantile(values, [alpha, 1 - alpha])
    return float(lo), float(hi)


def bootstrap_ci(
    scores: ArrayLike, statistic: Statistic = iqm, reps: int = 2000, seed: int = 0, level: float = 0.95
) -> tuple[float, float]:
    """Percentile interval of ``statistic`` of one cell's (runs, episodes) ``scores``, runs resampled whole.

    With a single run, its episodes are resampled. ``seed`` fixes the replicates (the same scores give the
    same interval).
    """
    x = _runs(_scores(scores))
    rng = np.random.default_rng(seed)
    return _percentile(_batched(statistic, _resample(x, rng, reps)), level)


def probability_of_improvement(x: ArrayLike, y: ArrayLike) -> float:
    """P(X > Y) + P(X = Y) / 2 for a run of X and a run of Y, averaged over the strata (rliable's definition).

    ``x`` and ``y`` are (runs, strata) matrices with the same strata (columns); per stratum the probability is
    the Mann-Whitney U statistic over the two sets of runs divided by the number of pairs.
    """
    a, b = _scores(x), _scores(y)
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"x, y: different numbers of strata ({a.shape[1]} and {b.shape[1]})")
    return float(_improvement(a[None], b[None])[0])


def _improvement(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`probability_of_improvement` of each replicate pair of (reps, runs, strata) stacks."""
    pa, pb = a[:, :, None, :], b[:, None, :, :]  # every run of a against every run of b, per stratum
    return ((pa > pb).mean(axis=(1, 2)) + 0.5 * (pa == pb).mean(axis=(1, 2))).mean(axis=1)


def probability_of_improvement_ci(
    x: ArrayLike, y: ArrayLike, reps: int = 2000, seed: int = 0, level: float = 0.95
) -> tuple[float, float]:
    """Percentile interval of :func:`probability_of_improvement`, each side's runs resampled whole on its own."""
    a, b = _scores(x), _scores(y)
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"x, y: different numbers of strata ({a.shape[1]} and {b.shape[1]})")
    rng = np.random.default_rng(seed)
    values = np.concatenate(  # in chunks: a replicate compares runs(a) x runs(b) x strata values
        [
            _improvement(_resample(a, rng, n), _resample(b, rng, n))
            for n in _chunks(reps, a.shape[0] * b.shape[0] * a.shape[1])
        ]
    )
    return _percentile(values, level)


def _chunks(reps: int, per_rep: int, budget: int = 4_000_000) -> list[int]:
    """Split ``reps`` replicates into chunks of at most ``budget`` compared values (at least one replicate)."""
    size = max(1, budget // max(1, per_rep))
    return [min(size, reps - i) for i in range(0, reps, size)]
