"""The KDE radar's two-stage samplers: the reference ball sampler and the exact bucket-rejection sampler.

Both draw the outcome with ``P(miss | x)``, then a tuple of that outcome with probability proportional to its
relevance weight, then the Gaussian offset (:func:`sample_cycle`); the bucket sampler draws the same
distribution over the grid buckets of :mod:`sensor_envs.radar.buckets`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from sensor_envs.radar.buckets import sample_proportional
from sensor_envs.radar.kde_frames import as_prev, extra_query, features, to_model_frame, to_sensor_frame
from sensor_envs.radar.kde_params import (
    GROUP_MAIN,
)
from sensor_envs.radar.kde_trees import nearest_detected, neighbours, outcome, route
from sensor_envs.radar.log import check_cycle_states

if TYPE_CHECKING:
    from sensor_envs.radar.kde import KDERadarModel

__all__ = ["sample_cycle", "draw_ball", "draw_bucket", "pick", "unique_states", "unique_rows"]


def sample_cycle(
    m: KDERadarModel,
    corners: NDArray,
    prev_z: NDArray | None,
    rng: np.random.Generator,
    extra: NDArray | None = None,
    new_track: NDArray | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """:meth:`KDERadarModel.sample_cycle <sensor_envs.radar.kde.KDERadarModel.sample_cycle>`."""
    m._check_fitted()
    corners = check_cycle_states(corners, prev_z, rng, extra=extra, new_track=new_track, extra_names=m.extra_state_)
    n = corners.shape[0]
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
    prev = to_model_frame(m, as_prev(None if not m.use_prev else prev_z, n), corners)
    grp = route(m, prev, new_track)
    ex = extra_query(m, extra, n)
    bucket = m.sampler == "bucket" or (m.sampler == "auto" and m._auto_bucket)
    if m.k_max is None and bucket and ex.shape[1] == 0:
        miss, src = draw_bucket(m, corners, prev, rng, grp)
    else:
        miss, src = draw_ball(m, corners, prev, rng, ex, grp)
    h = m.bandwidth(corners, start=grp != GROUP_MAIN)
    noise = rng.standard_normal((n, 2))
    if m.tail_weight > 0:  # the tail component: drawn after the offsets, so w = 0 draws as before
        noise *= np.where(rng.random(n) < m.tail_weight, m.tail_scale, 1.0)[:, None]
    z = np.where(miss[:, None], np.nan, m.z_[np.maximum(src, 0)] + h * noise)
    return to_sensor_frame(m, z, corners), src


def pick(gi: NDArray, w: NDArray, q: NDArray, groups: NDArray, rng: np.random.Generator) -> NDArray[np.int64]:
    """One tuple per query, with probability ``w / sum w`` within the query's neighbour group.

    ``gi, w, q`` are flat neighbour lists sorted by group id ``q``; ``groups (n,)`` is the group of
    each query. Returns global tuple indices, ``-1`` where the group has zero weight.
    """
    n_groups = int(groups.max(initial=-1)) + 1
    cw = np.cumsum(w)
    g = np.arange(n_groups)
    starts, ends = np.searchsorted(q, g, side="left"), np.searchsorted(q, g, side="right")
    base = np.where(starts > 0, cw[np.maximum(starts - 1, 0)], 0.0)[groups]
    top = np.where(ends > starts, cw[np.maximum(ends - 1, 0)], 0.0)[groups]
    u = base + rng.random(groups.size) * (top - base)
    pick = np.clip(np.searchsorted(cw, u, side="right"), starts[groups], np.maximum(ends[groups] - 1, 0))
    ok = top > base
    return np.where(ok, gi[np.minimum(pick, gi.size - 1)] if gi.size else -1, -1).astype(np.int64)


def draw_ball(
    m: KDERadarModel,
    corners: NDArray,
    prev: NDArray,
    rng: np.random.Generator,
    extra: NDArray | None = None,
    grp: NDArray | None = None,
) -> tuple[NDArray, NDArray]:
    """Reference sampler (``sampler="ball"``): full ball query, outcome, then tuple; ``(miss, source)``."""
    n = corners.shape[0]
    ex = extra_query(m, extra, n)
    grp = route(m, prev, None) if grp is None else grp
    rep, inv = unique_states(corners, np.concatenate([prev, ex, grp[:, None].astype(np.float64)], axis=1))
    gi, w, q, p_miss = outcome(m, corners[rep], prev[rep], ex[rep], grp[rep])
    miss = rng.random(n) < p_miss[inv]
    miss_t = m.miss_[gi]
    if rep.size == n:  # one group per query: pick among the tuples of the drawn outcome at once
        src = pick(gi, w * (miss_t == miss[rep][q]), q, inv, rng)
    else:
        src = np.where(miss, pick(gi, w * miss_t, q, inv, rng), pick(gi, w * ~miss_t, q, inv, rng))
    lost = ~miss & (src < 0)
    if lost.any():
        src[lost] = nearest_detected(m, corners[lost])
    return miss, src


def pick_detected_ball(m, corners: NDArray, prev: NDArray, rng: np.random.Generator, grp: NDArray) -> NDArray[np.int64]:
    """A detected tuple with probability ``w_i / sum_{detected} w`` (reference search), per query."""
    gi, w, q = neighbours(m, corners, prev, None, grp)
    src = pick(gi, w * ~m.miss_[gi], q, np.arange(corners.shape[0]), rng)
    lost = src < 0
    if lost.any():
        src[lost] = nearest_detected(m, corners[lost])
    return src


def draw_bucket(m, corners: NDArray, prev: NDArray, rng: np.random.Generator, grp: NDArray) -> tuple[NDArray, NDArray]:
    """Exact bucket-rejection sampler (``sampler="bucket"``), same distribution as :func:`draw_ball`.

    One proposal stage picks tuple ``i`` with probability ``w_i / (sum w + a)`` or the ``miss_prior``
    pseudo-tuple with ``a / (sum w + a)`` (:func:`sensor_envs.radar.buckets.sample_proportional`);
    the pseudo-tuple is a miss with the log's miss rate ``m``, else a detected tuple is drawn with
    ``w_i / sum_{detected} w``. Hence ``P(miss) = (w_miss + a m) / (sum w + a)`` and, given a
    detection, tuple ``i`` has probability ``w_i / sum_{detected} w``: Eq. 10 exactly. Queries
    with an empty ball (fallback tuples), rejection give-ups and the detected-after-pseudo draws
    use the reference search.
    """
    n = corners.shape[0]
    miss, src = np.zeros(n, dtype=bool), np.full(n, -1, dtype=np.int64)
    todo, need_det = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    full = np.concatenate([features(m, corners), prev], axis=1)
    for g, node in enumerate(m._groups):
        qi = np.flatnonzero(grp == g)
        if qi.size == 0 or node is None or node.buckets is None:  # no queries, or a grid too large for memory
            todo[qi] = True
            continue
        tree, buckets, idx_map, rate = node.tree, node.buckets, node.idx, node.rate
        d = 4 if g == GROUP_MAIN else 2
        qs = full[qi, :d] / m.scale_[:d]
        rep, inv = unique_rows(qs)
        pick, done, via = sample_proportional(
            buckets, qs[rep], m.miss_prior, rng, allowed=~buckets.flag, pseudo_stop=rate, inv=inv
        )
        if via.any():  # the pseudo-tuple is only right when the ball holds a tuple (else: fallback_k)
            near, _ = tree.query(qs[via], k=1, distance_upper_bound=m.radius)
            empty = np.flatnonzero(via)[~np.isfinite(near)]
            done[empty], via[empty] = False, False
        todo[qi[~done & ~via]] = True
        need_det[qi[~done & via]] = True
        tup = done & (pick >= 0)
        src[qi[tup]] = idx_map[pick[tup]]
        miss[qi[done]] = np.where(tup[done], m.miss_[idx_map[np.maximum(pick[done], 0)]], True)
    if todo.any():
        miss[todo], src[todo] = draw_ball(m, corners[todo], prev[todo], rng, None, grp[todo])
    if need_det.any():  # pseudo-tuple drawn as a detection, rejection gave up: reference pick
        src[need_det] = pick_detected_ball(m, corners[need_det], prev[need_det], rng, grp[need_det])
    return miss, src


def unique_states(corners: NDArray, prev: NDArray, min_n: int = 64) -> tuple[NDArray, NDArray]:
    """Representative rows and inverse map of identical query states (only for batches >= ``min_n``)."""
    return unique_rows(np.nan_to_num(np.concatenate([corners, prev], axis=1), nan=1e300), min_n)


def unique_rows(a: NDArray, min_n: int = 64) -> tuple[NDArray, NDArray]:
    """Representative rows and inverse map of identical rows of ``a`` (only for batches >= ``min_n``)."""
    n = a.shape[0]
    if n < min_n:
        return np.arange(n), np.arange(n)
    _, rep, inv = np.unique(a, axis=0, return_index=True, return_inverse=True)
    return rep, inv.ravel()
