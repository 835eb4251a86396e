"""Leak-free choice of the KDE radar model's relevance (state) bandwidth by cross-validation.

The corner part of the relevance kernel (variance ``v`` [m^2] on ``c_x`` and ``c_y``) is chosen from
a candidate list by K-fold cross-validation on the TRAINING log only: the log's sequences (for
Astyx: blocks of consecutive frames; for the rig: recordings) are dealt round-robin into ``folds``;
for each candidate, a model is fitted on ``folds - 1`` of them (with its own leave-one-group-out
output bandwidths) and the held-out log-likelihood of all outcomes (detections and misses, the
model's :meth:`~sensor_envs.radar.kde.KDERadarModel.log_prob`) is summed over the folds. The
candidate with the highest held-out log-likelihood wins. Used by ``KDERadarModel(relevance="cv")``;
when nested inside an outer train/test split, the outer test part is never seen.

The same held-out score chooses the relevance variances of extra state dimensions
(:func:`select_extra_variances`, candidates relative to each column's standard deviation).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from sklearn.base import clone
from tqdm import tqdm

from sensor_envs.inputs import InputError
from sensor_envs.radar.features import state_matrix
from sensor_envs.radar.log import RadarLog, target_tuples
from sensor_envs.rng import fold_ids

__all__ = [
    "inner_folds",
    "select_corner_variance",
    "select_extra_variances",
    "select_corner_variances",
    "select_prev_variance",
    "heldout_scores",
]


FRAME_BLOCK = 50
"""Frames per block when a log has fewer sequences than folds (contiguous blocks are then dealt instead)."""


def inner_folds(log: RadarLog, n_folds: int) -> NDArray[np.int64]:
    """Fold id ``(n_rows,)`` of every row: its sequence's rank modulo ``n_folds`` (see ``rng.fold_ids``).

    A log with fewer sequences than ``n_folds`` deals blocks of :data:`FRAME_BLOCK` consecutive frames
    of each sequence instead.
    """
    if np.unique(log["sequence"]).size < n_folds:
        return fold_ids(np.stack([log["sequence"], log["frame"] // FRAME_BLOCK], axis=1), n_folds)
    return fold_ids(log["sequence"], n_folds)


def select_corner_variance(
    log: RadarLog, estimator: Any, candidates: tuple[float, ...], n_folds: int, progress: bool = False
) -> tuple[float, NDArray[np.float64]]:
    """Pick the corner variance [m^2] with the best ``n_folds``-fold held-out log-likelihood on ``log``.

    Args:
        log: the training log.
        estimator: the (unfitted) model whose hyperparameters the inner models copy
            (``rel_variance`` gives the ``z_{t-1}`` variances; ``relevance`` is forced to ``"paper"``;
            extra state dimensions without a given variance use ``std^2`` of their column).
        candidates: corner variances [m^2] to try.
        n_folds: inner folds (sequences dealt round-robin; needs at least ``n_folds`` sequences).
        progress: show a tqdm bar over the ``len(candidates) * n_folds`` inner fits.

    Returns:
        The chosen variance and ``scores (len(candidates),)``: mean held-out log-likelihood per target row [nats].
    """
    params = estimator.get_params()
    rv = params.get("rel_variance", (3.0, 3.0, 0.03, 0.03))
    base = {}
    names = tuple(params.get("extra_state", ()) or ())
    if names:
        std = _extra_std(log, names)
        given = params.get("extra_variance")
        ev = np.asarray(given if given is not None else np.full(len(names), np.nan), dtype=np.float64)
        base["extra_variance"] = tuple(float(v) for v in np.where(np.isnan(ev), std**2, ev))
    overrides = [{**base, "rel_variance": (v, v, rv[2], rv[3])} for v in candidates]
    scores = heldout_scores(log, estimator, overrides, n_folds, progress, "relevance cv")
    return float(candidates[int(np.argmax(scores))]), scores


def select_corner_variances(
    log: RadarLog,
    estimator: Any,
    first_candidates: tuple[float, ...],
    second_candidates: tuple[float, ...],
    n_folds: int,
    progress: bool = False,
) -> tuple[tuple[float, float], NDArray[np.float64]]:
    """The two corner variances of the relevance kernel apart, by the same held-out CV.

    Cartesian corner features: x and y variances [m^2]; polar (``state_transform="polar"``): range
    [m^2] and azimuth [rad^2]. Coordinate-wise (``(len(first) + len(second)) * n_folds`` inner fits):
    the first variance with the second at its middle candidate, then the second at the chosen first.

    Args:
        log: the training log.
        estimator: the unfitted model (its ``rel_variance`` gives the ``z_{t-1}`` variances).
        first_candidates: variances of the first corner feature to try.
        second_candidates: variances of the second corner feature to try.
        n_folds: inner folds.
        progress: show a tqdm bar.

    Returns:
        ``(first, second)`` variances and the scores (mean held-out log-likelihood per target row
        [nats]) of the first candidates followed by those of the second.
    """
    rv = estimator.get_params().get("rel_variance", (3.0, 3.0, 0.03, 0.03))
    v2 = float(sorted(second_candidates)[(len(second_candidates) - 1) // 2])
    over = [{"rel_variance": (v, v2, rv[2], rv[3])} for v in first_candidates]
    s1 = heldout_scores(log, estimator, over, n_folds, progress, "relevance cv (first corner feature)")
    v1 = float(first_candidates[int(np.argmax(s1))])
    over = [{"rel_variance": (v1, v, rv[2], rv[3])} for v in second_candidates]
    s2 = heldout_scores(log, estimator, over, n_folds, progress, "relevance cv (second corner feature)")
    return (v1, float(second_candidates[int(np.argmax(s2))])), np.concatenate([s1, s2])


def select_prev_variance(
    log: RadarLog, estimator: Any, candidates: tuple[float, ...], n_folds: int, progress: bool = False
) -> tuple[float, NDArray[np.float64]]:
    """The ``z_{t-1}`` variance [m^2] of the relevance kernel (both components alike) by the same held-out CV.

    The seed fixes it at 0.03 m^2 (std 0.17 m): only tuples whose previous output lies within a few
    decimetres of the query's count, so the conditional law rests on few tuples and a chain fed its
    own outputs wanders off them. Chosen here like the corner variances, on the training log.

    Args:
        log: the training log.
        estimator: the unfitted model; its ``rel_variance`` gives the corner variances (kept).
        candidates: ``z_{t-1}`` variances to try [m^2].
        n_folds: inner folds.
        progress: show a tqdm bar.

    Returns:
        The chosen variance and the scores (mean held-out log-likelihood per target row [nats]).
    """
    rv = estimator.get_params().get("rel_variance", (3.0, 3.0, 0.03, 0.03))
    over = [{"rel_variance": (rv[0], rv[1], v, v)} for v in candidates]
    s = heldout_scores(log, estimator, over, n_folds, progress, "relevance cv (previous output)")
    return float(candidates[int(np.argmax(s))]), s


def _extra_std(log: RadarLog, names: tuple[str, ...]) -> NDArray[np.float64]:
    """Standard deviation of each extra state column over the target rows (at least 1e-9)."""
    rows = np.flatnonzero(~log.is_clutter)
    return np.maximum(np.nanstd(state_matrix(log, names, rows), axis=0), 1e-9)


def select_extra_variances(
    log: RadarLog,
    estimator: Any,
    std: NDArray[np.float64],
    factors: tuple[float, ...],
    n_folds: int,
    progress: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Relevance variances of the extra state dimensions by the same held-out CV, one dimension at a time.

    Dimension ``j`` tries ``(f * std_j)^2`` for ``f`` in ``factors`` with the others fixed (a given
    finite entry of ``extra_variance`` is kept, the not yet chosen ones at ``std^2``); the best is
    kept before the next dimension (coordinate-wise search: ``E * len(factors) * n_folds`` inner fits).

    Args:
        log: the training log.
        estimator: the unfitted model (its ``extra_state``, ``extra_variance`` and other parameters).
        std: ``(E,)`` standard deviations of the extra columns [unit].
        factors: candidate factors of ``std``.
        n_folds: inner folds.
        progress: show a tqdm bar.

    Returns:
        ``variance (E,)`` and ``scores (E, len(factors))`` mean held-out log-likelihood per target row
        (rows of given dimensions are NaN).
    """
    params = estimator.get_params()
    given = params.get("extra_variance")
    var = np.asarray(given if given is not None else np.full(std.size, np.nan), dtype=np.float64).copy()
    todo = np.flatnonzero(np.isnan(var))
    var[todo] = std[todo] ** 2
    scores = np.full((std.size, len(factors)), np.nan)
    for j in todo:  # one coordinate at a time
        overrides = []
        for f in factors:
            v = var.copy()
            v[j] = (f * std[j]) ** 2
            overrides.append({"extra_variance": tuple(float(x) for x in v)})
        scores[j] = heldout_scores(log, estimator, overrides, n_folds, progress, f"extra cv {j}")
        var[j] = (factors[int(np.argmax(scores[j]))] * std[j]) ** 2
    return var, scores


def heldout_scores(
    log: RadarLog, estimator: Any, overrides: list[dict[str, Any]], n_folds: int, progress: bool, desc: str
) -> NDArray[np.float64]:
    """Mean ``n_folds``-fold held-out log-likelihood per target row of each parameter override.

    Inner models copy ``estimator``'s parameters with ``relevance="paper"`` and the override; the
    held-out log-likelihood includes the extra state of the held-out rows when the model has any.
    """
    fold = inner_folds(log, n_folds)
    if np.unique(fold).size < n_folds:
        raise InputError(f"{log.source}: relevance CV needs at least {n_folds} sequences or frame blocks")
    total = np.zeros(len(overrides))
    n_rows = 0
    bar = tqdm(total=len(overrides) * n_folds, disable=not progress, desc=desc)
    for k in range(n_folds):  # one iteration per inner fold
        train, test = log.select(fold != k), log.select(fold == k)
        tt = target_tuples(test)
        state = np.concatenate([tt.corner, tt.z_prev], axis=1)
        n_rows += state.shape[0]
        for j, ov in enumerate(overrides):  # one inner fit per candidate
            quiet = {"verbose": False} if "verbose" in estimator.get_params() else {}  # one bar: this one
            model = clone(estimator).set_params(relevance="paper", **quiet, **ov).fit(train)
            names = tuple(model.extra_state or ())
            lp = (
                model.log_prob(tt.z, state, extra=state_matrix(test, names, tt.row))
                if names
                else model.log_prob(tt.z, state)
            )
            total[j] += float(np.sum(lp))
            bar.update()
    bar.close()
    return total / n_rows
