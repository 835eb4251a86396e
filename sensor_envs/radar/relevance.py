"""Leak-free choice of the KDE radar model's relevance (state) bandwidth by cross-validation.

The corner part of the relevance kernel (variance ``v`` [m^2] on ``c_x`` and ``c_y``) is chosen from
a candidate list by K-fold cross-validation on the TRAINING log only: the log's sequences (for
Astyx: blocks of consecutive frames; for the rig: recordings) are dealt round-robin into ``folds``;
for each candidate, a model is fitted on ``folds - 1`` of them (with its own leave-one-group-out
output bandwidths) and the held-out log-likelihood of all outcomes (detections and misses, the
model's :meth:`~sensor_envs.radar.kde.KDERadarModel.log_prob`) is summed over the folds. The
candidate with the highest held-out log-likelihood wins. Used by ``KDERadarModel(relevance="cv")``;
when nested inside an outer train/test split, the outer test part is never seen.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from sklearn.base import clone
from tqdm import tqdm

from sensor_envs.radar.log import RadarLog, target_tuples
from sensor_envs.rng import fold_ids

__all__ = ["inner_folds", "select_corner_variance"]


def inner_folds(log: RadarLog, n_folds: int) -> NDArray[np.int64]:
    """Fold id ``(n_rows,)`` of every row: its sequence's rank modulo ``n_folds`` (see ``rng.fold_ids``)."""
    return fold_ids(log["sequence"], n_folds)


def select_corner_variance(
    log: RadarLog, estimator: Any, candidates: tuple[float, ...], n_folds: int, progress: bool = False
) -> tuple[float, NDArray[np.float64]]:
    """Pick the corner variance [m^2] with the best ``n_folds``-fold held-out log-likelihood on ``log``.

    Args:
        log: the training log.
        estimator: the (unfitted) model whose hyperparameters the inner models copy
            (``rel_variance`` gives the ``z_{t-1}`` variances; ``relevance`` is forced to ``"paper"``).
        candidates: corner variances [m^2] to try.
        n_folds: inner folds (sequences dealt round-robin; needs at least ``n_folds`` sequences).
        progress: show a tqdm bar over the ``len(candidates) * n_folds`` inner fits.

    Returns:
        The chosen variance and ``scores (len(candidates),)``: mean held-out log-likelihood per target row [nats].
    """
    rv = estimator.get_params()["rel_variance"]
    fold = inner_folds(log, n_folds)
    if np.unique(fold).size < n_folds:
        raise ValueError(f"{log.source}: relevance CV needs at least {n_folds} sequences")
    total = np.zeros(len(candidates))
    n_rows = 0
    bar = tqdm(total=len(candidates) * n_folds, disable=not progress, desc="relevance cv")
    for k in range(n_folds):  # one iteration per inner fold
        train, test = log.select(fold != k), log.select(fold == k)
        tt = target_tuples(test)
        state = np.concatenate([tt.corner, tt.z_prev], axis=1)
        n_rows += state.shape[0]
        for j, v in enumerate(candidates):  # one inner fit per candidate
            inner = clone(estimator).set_params(relevance="paper", rel_variance=(v, v, rv[2], rv[3]))
            lp = inner.fit(train).log_prob(tt.z, state)
            total[j] += float(np.sum(lp))
            bar.update()
    bar.close()
    scores = total / n_rows
    return float(candidates[int(np.argmax(scores))]), scores
