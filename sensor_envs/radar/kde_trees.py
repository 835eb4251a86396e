"""Search trees of the KDE radar: the main, start, new-track and after-miss trees, neighbours and miss odds.

Built once per fit or load (:func:`build_trees`); a query is routed to one tree (:func:`route`) and gets its
relevant tuples with truncated Gaussian weights (:func:`neighbours`, the ``fallback_k`` nearest where the ball
is empty) and ``P(miss | x)`` (:func:`outcome`).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import chain
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from sensor_envs.inputs import InputError
from sensor_envs.radar.buckets import build_buckets
from sensor_envs.radar.kde_bandwidth import interp_log_h
from sensor_envs.radar.kde_frames import as_prev, extra_query, features, scaled
from sensor_envs.radar.kde_params import (
    AUTO_BUCKET_MIN_NEIGHBOURS,
    GROUP_LOST,
    GROUP_MAIN,
    GROUP_NEW,
    GROUP_START,
)

if TYPE_CHECKING:
    from sensor_envs.radar.kde import KDERadarModel

__all__ = [
    "build_trees",
    "route",
    "bandwidth",
    "neighbours",
    "outcome",
    "nearest_detected",
    "with_detected_fallback",
    "neighbour_lists",
]


@dataclass(frozen=True)
class _Tree:
    """One search tree of stored tuples.

    The scaled-state tree, the global tuple index of each of its points, its bucket grid (``None``
    with extra state or when too large) and its prior miss rate.
    """

    tree: cKDTree
    idx: NDArray[np.int64]
    buckets: Any
    rate: float


def neighbour_lists(
    tree: cKDTree, q: NDArray, radius: float, k_max: int | None
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """Neighbours of every query within ``radius`` (all, or the ``k_max`` nearest).

    Returns flat ``(index, squared distance, query id)`` arrays, sorted by query id.
    """
    if k_max is not None:
        k = min(k_max, tree.n)
        d, i = tree.query(q, k=k, distance_upper_bound=radius)
        d, i = d.reshape(len(q), k), i.reshape(len(q), k)
        ok = np.isfinite(d)
        qid = np.broadcast_to(np.arange(len(q))[:, None], ok.shape)[ok]
        return i[ok].astype(np.int64), d[ok] ** 2, qid.astype(np.int64)
    lists = tree.query_ball_point(q, radius, return_sorted=False)
    lengths = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
    idx = np.fromiter(chain.from_iterable(lists), dtype=np.int64, count=int(lengths.sum()))
    qid = np.repeat(np.arange(len(q)), lengths)
    d2 = np.sum((tree.data[idx] - q[qid]) ** 2, axis=1)
    return idx, d2, qid


def build_trees(m: KDERadarModel) -> None:
    """Build the search trees from the stored tuples (at fit and at load; never per call)."""
    has_prev = ~np.isnan(m.states_[:, 2])
    empty = np.zeros(0, dtype=np.int64)
    flags = getattr(m, "new_track_", None)
    if m.use_prev:
        m._main_idx = np.flatnonzero(has_prev)
        m._start_idx = np.flatnonzero(~has_prev)
        if m._start_idx.size == 0:
            m._start_idx = np.arange(m.states_.shape[0])
        m._new_idx = empty if flags is None else np.flatnonzero(~has_prev & flags)
        m._lost_idx = empty if flags is None else np.flatnonzero(~has_prev & ~flags)
    else:
        m._main_idx = empty
        m._start_idx = np.arange(m.states_.shape[0])
        m._new_idx, m._lost_idx = empty, empty
    if not hasattr(m, "extra_"):  # models fitted/loaded before the extra state existed
        m.extra_state_, m.extra_ = (), np.zeros((m.states_.shape[0], 0))
        m.extra_fill_, m.extra_variance_, m.extra_scale_ = np.zeros(0), (), np.zeros(0)
    m.miss_ = np.isnan(m.z_[:, 0])
    m.miss_rate_ = float(m.miss_.mean())
    tree_rate = m.prior_rate == "tree"
    groups: list[_Tree | None] = []
    m._groups = groups
    for g, idx in enumerate((m._main_idx, m._start_idx, m._new_idx, m._lost_idx)):
        if idx.size == 0:
            m._groups.append(None)
            continue
        dims = 4 if g == GROUP_MAIN else 2
        tree = cKDTree(scaled(m, features(m, m.states_[idx, :dims]), m.extra_[idx]))
        buckets = None if m.extra_.shape[1] else build_buckets(tree.data, m.bucket_cell, m.radius, flag=m.miss_[idx])
        rate = float(m.miss_[idx].mean()) if tree_rate else m.miss_rate_
        m._groups.append(_Tree(tree, idx, buckets, rate))
    main, start = m._groups[GROUP_MAIN], m._groups[GROUP_START]
    assert start is not None  # the start tree always holds tuples
    m._main_tree = None if main is None else main.tree
    m._start_tree = start.tree
    m.prior_rate_main_ = m.miss_rate_ if main is None else main.rate
    m.prior_rate_start_ = start.rate
    new, lost = m._groups[GROUP_NEW], m._groups[GROUP_LOST]
    m.prior_rate_new_ = start.rate if new is None else new.rate
    m.prior_rate_lost_ = start.rate if lost is None else lost.rate
    m._det_idx = np.flatnonzero(~m.miss_)
    m._det_tree = cKDTree(features(m, m.states_[m._det_idx, :2]) / m.scale_[:2])
    tree = m._main_tree if m._main_tree is not None else m._start_tree
    probe = tree.data[:: max(1, tree.n // 256)]  # a deterministic sample of stored states
    m.median_neighbours_ = float(np.median(tree.query_ball_point(probe, m.radius, return_length=True)))
    m._auto_bucket = m.median_neighbours_ >= AUTO_BUCKET_MIN_NEIGHBOURS


def route(m: KDERadarModel, prev: NDArray, new_track: NDArray | None) -> NDArray[np.int64]:
    """Tree of each query ``(n,)`` (``GROUP_*``) from its previous output ``(n, 2)`` and ``new_track`` flag.

    Raises:
        ValueError: when ``new_track`` is not ``n`` booleans, or flags a query that has a previous output.
    """
    n = prev.shape[0]
    has = ~np.isnan(prev[:, 0])
    grp = np.where(has & (m._groups[GROUP_MAIN] is not None), GROUP_MAIN, GROUP_START).astype(np.int64)
    if new_track is None:
        return grp
    flag = np.asarray(new_track)
    if flag.dtype != np.bool_ or flag.shape not in ((n,), ()):
        raise InputError(f"new_track: expected None or ({n},) booleans, got {flag.dtype} of shape {flag.shape}")
    flag = np.broadcast_to(flag, (n,))
    if (flag & has).any():
        r = int(np.flatnonzero(flag & has)[0])
        raise InputError(f"new_track: row {r} is flagged new but has a previous output (prev_z is finite)")
    if not m.use_prev:
        return grp
    start = grp == GROUP_START
    for g, sel in ((GROUP_NEW, start & flag), (GROUP_LOST, start & ~flag)):
        if m._groups[g] is not None:
            grp[sel] = g
    return grp


def bandwidth(m: KDERadarModel, corners: NDArray, start: NDArray | bool = False) -> NDArray[np.float64]:
    """:meth:`KDERadarModel.bandwidth <sensor_envs.radar.kde.KDERadarModel.bandwidth>`."""
    m._check_fitted()
    h = np.exp(interp_log_h(m.grid_x_, m.grid_y_, m.log_h_, np.atleast_2d(corners)))
    ratio = start_ratio(m)
    if ratio == 1.0:
        return h
    return h * np.where(np.broadcast_to(np.asarray(start, dtype=bool), (h.shape[0],)), ratio, 1.0)[:, None]


def start_ratio(m: KDERadarModel) -> float:
    """Start-tree bandwidth over main-tree bandwidth (1 without ``start_bandwidth_scale``)."""
    s = m.start_bandwidth_scale
    return 1.0 if s is None else float(s) / float(m.bandwidth_scale)


def neighbours(
    m, corners: NDArray, prev_z: NDArray | None, extra: NDArray | None = None, grp: NDArray | None = None
) -> tuple[NDArray, NDArray, NDArray]:
    """Relevant tuples of each query: flat ``(global tuple index, weight, query id)``.

    ``grp (n,)`` is the tree of each query (:func:`route`; ``None`` = by ``prev_z`` alone).
    """
    corners = np.atleast_2d(np.asarray(corners, dtype=np.float64))
    n = corners.shape[0]
    ex = extra_query(m, extra, n)
    prev = np.atleast_2d(np.asarray(prev_z, dtype=np.float64)) if prev_z is not None else np.full((n, 2), np.nan)
    if prev.shape != (n, 2) or corners.shape != (n, 2):
        raise InputError(f"corners and prev_z must both be (n, 2); got {corners.shape} and {prev.shape}")
    if not np.isfinite(corners).all():
        raise InputError(f"corners: row {int(np.flatnonzero(~np.isfinite(corners).all(axis=1))[0])} is NaN or infinite")
    grp = route(m, prev, None) if grp is None else grp
    full = np.concatenate([features(m, corners), prev], axis=1)
    parts = []
    for g, node in enumerate(m._groups):
        qi = np.flatnonzero(grp == g)
        if qi.size == 0 or node is None:
            continue
        tree, idx_map = node.tree, node.idx
        qs = scaled(m, full[qi, : 4 if g == GROUP_MAIN else 2], ex[qi])
        j, d2, qid = neighbour_lists(tree, qs, m.radius, m.k_max)
        w = np.exp(-0.5 * d2)
        empty = np.bincount(qid, weights=w, minlength=qi.size) <= 0.0
        keep = ~empty[qid]
        parts.append((idx_map[j[keep]], w[keep], qi[qid[keep]]))
        if empty.any():  # no tuple in the ball: the fallback_k nearest tuples of the same tree
            parts.append(fallback(m, tree, idx_map, qs[empty], qi[empty]))
    gi, w, q = (np.concatenate(a) for a in zip(*parts, strict=True))
    order = np.argsort(q, kind="stable")
    return gi[order], w[order], q[order]


def fallback(
    m: KDERadarModel, tree: cKDTree, idx_map: NDArray, qs: NDArray, qi: NDArray
) -> tuple[NDArray, NDArray, NDArray]:
    """The ``fallback_k`` nearest tuples of scaled queries ``qs``, weighted ``exp(-(d^2 - d_min^2) / 2)``."""
    k = min(m.fallback_k, tree.n)
    d, j = tree.query(qs, k=k)
    d, j = d.reshape(len(qs), k), j.reshape(len(qs), k)
    w = np.exp(-0.5 * (d**2 - d[:, :1] ** 2))
    return idx_map[j.ravel()], w.ravel(), np.repeat(qi, k)


def outcome(
    m, corners: NDArray, prev_z: NDArray | None, extra: NDArray | None = None, grp: NDArray | None = None
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Neighbours ``(gi, w, q)`` and the miss probability ``(n,)`` of each query (``grp``: see :func:`route`)."""
    n = corners.shape[0]
    grp = route(m, as_prev(prev_z, n), None) if grp is None else grp
    gi, w, q = neighbours(m, corners, prev_z, extra, grp)
    wsum = np.bincount(q, weights=w, minlength=n)
    wmiss = np.bincount(q, weights=w * m.miss_[gi], minlength=n)
    rate = group_rates(m)[grp]
    p_miss = (wmiss + m.miss_prior * rate) / (wsum + m.miss_prior)
    return gi, w, q, p_miss


def group_rates(m: KDERadarModel) -> NDArray[np.float64]:
    """Prior miss rate ``m`` of each tree (``GROUP_*`` order)."""
    return np.array([m.prior_rate_main_, m.prior_rate_start_, m.prior_rate_new_, m.prior_rate_lost_])


def nearest_detected(m: KDERadarModel, corners: NDArray) -> NDArray[np.int64]:
    """Global index of the detected tuple with the nearest corner (fallback of empty groups)."""
    _, j = m._det_tree.query(features(m, corners) / m.scale_[:2], k=1)
    return m._det_idx[j]


def with_detected_fallback(
    m, gi: NDArray, w: NDArray, q: NDArray, corners: NDArray
) -> tuple[NDArray, NDArray, NDArray]:
    """Add the nearest detected tuple (weight 1) to queries without a detected neighbour."""
    n = corners.shape[0]
    none = np.bincount(q, weights=(~m.miss_[gi]).astype(np.float64), minlength=n) == 0
    if not none.any():
        return gi, w, q
    e = np.flatnonzero(none)
    gi, w, q = (
        np.concatenate([gi, nearest_detected(m, corners[e])]),
        np.concatenate([w, np.ones(e.size)]),
        np.concatenate([q, e]),
    )
    order = np.argsort(q, kind="stable")
    return gi[order], w[order], q[order]
