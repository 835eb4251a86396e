"""Exact proportional sampling from a truncated Gaussian kernel by rejection over spatial buckets.

Target, per query ``q`` (scaled coordinates, ``n`` stored points ``x_i``)::

    P(i) = w_i / (sum_j w_j + a),   P(pseudo) = a / (sum_j w_j + a),
    w_i = exp(-|q - x_i|^2 / 2) if |q - x_i| <= radius else 0

(``a`` = a pseudo-weight, e.g. the KDE's ``miss_prior``). The points are grouped into the cells of
a regular grid (``cell`` scaled units); each bucket keeps its members' bounding box. For a query,
the buckets whose box is within ``radius`` (grid look-ups of the cells overlapping the cube
``q +- radius``, no tree search) get the
envelope mass ``count_b * exp(-d_min(q, box_b)^2 / 2) >= sum_{i in b} w_i``. A proposal picks the
pseudo entry with probability ``a / (sum_b env_b + a)`` (always accepted), else a bucket with
probability ``env_b / (...)``, then a member uniformly; the member is accepted with probability
``w_i / exp(-d_min^2 / 2)`` (0 outside the radius). Accepted proposals are distributed exactly as
the target (standard rejection sampling); their number does not depend on the sum ``sum_j w_j``,
so the cost follows the number of candidate BUCKETS, not of neighbours. Proposals are drawn
``per_round`` at a time per query, vectorised across queries; a query that accepts nothing within
``max_rounds`` is reported as not done (the caller then uses an exact reference; that keeps the
result exact because acceptance is independent of the accepted value).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["BucketIndex", "build_buckets", "sample_proportional"]


DENSE_MAX_CELLS = 20_000_000
"""Largest grid (cells, incl. padding) :func:`build_buckets` accepts (int32 ids: 80 MB)."""


@dataclass(frozen=True)
class BucketIndex:
    """Grid buckets over ``points (n, d)`` (scaled coordinates).

    Attributes:
        points: ``(n, d)`` the stored points.
        cell: side of the grid cells.
        radius: the kernel radius the grid was built for.
        span: cells per dimension of a query's cube ``q +- radius``.
        origin: ``(d,)`` integer cell coordinates of grid cell 0 (data start ``span`` cells later).
        shape: ``(d,)`` grid extent in cells (data extent + ``span`` cells of padding on each side).
        strides: ``(d,)`` linear-index strides of the grid.
        offsets: ``(span^d,)`` linear offsets of the cells of a query's cube ``q +- radius``.
        dense: ``(prod(shape),)`` bucket id of every cell (``-1`` = empty).
        order: ``(n,)`` point indices sorted by bucket.
        start: ``(B,)`` first position of each bucket in ``order``.
        count: ``(B,)`` members per bucket.
        lo: ``(B, d)`` lower corner of each bucket's members' bounding box.
        hi: ``(B, d)`` upper corner.
        flag: ``(n,)`` a per-point boolean the caller attached (e.g. "is a miss").
    """

    points: NDArray[np.float64]
    cell: float
    radius: float
    span: int
    origin: NDArray[np.int64]
    shape: NDArray[np.int64]
    strides: NDArray[np.int64]
    offsets: NDArray[np.int64]
    dense: NDArray[np.int32]
    order: NDArray[np.int64]
    start: NDArray[np.int64]
    count: NDArray[np.int64]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    flag: NDArray[np.bool_]


def build_buckets(
    points: NDArray, cell: float, radius: float, flag: NDArray[np.bool_] | None = None
) -> BucketIndex | None:
    """Group ``points (n, d)`` into grid cells of side ``cell`` for kernel ``radius`` (vectorised).

    ``flag (n,)`` is stored with the points (default all false).

    Returns ``None`` when the padded grid would exceed :data:`DENSE_MAX_CELLS` cells.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    d = points.shape[1]
    span = int(np.ceil(2 * radius / cell)) + 1
    g = np.floor(points / cell).astype(np.int64)
    origin = g.min(axis=0) - span
    shape = g.max(axis=0) - origin + 1 + span
    if np.prod(shape.astype(np.float64)) > DENSE_MAX_CELLS:
        return None
    strides = np.concatenate([np.cumprod(shape[::-1])[::-1][1:], [1]]).astype(np.int64)
    lin = (g - origin) @ strides
    keys, inv = np.unique(lin, return_inverse=True)
    order = np.argsort(inv, kind="stable").astype(np.int64)
    count = np.bincount(inv).astype(np.int64)
    start = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    sorted_pts = points[order]
    lo = np.minimum.reduceat(sorted_pts, start, axis=0)
    hi = np.maximum.reduceat(sorted_pts, start, axis=0)
    dense = np.full(int(np.prod(shape)), -1, dtype=np.int32)
    dense[keys] = np.arange(keys.size, dtype=np.int32)
    offs = np.stack(np.meshgrid(*([np.arange(span)] * d), indexing="ij"), axis=-1).reshape(-1, d) @ strides
    return BucketIndex(
        points,
        float(cell),
        float(radius),
        span,
        origin,
        shape,
        strides,
        offs,
        dense,
        order,
        start,
        count,
        lo,
        hi,
        np.zeros(len(points), dtype=bool) if flag is None else np.asarray(flag, bool),
    )


def _candidates(index: BucketIndex, qs: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Buckets whose box is within ``radius`` of each query: flat ``(bucket, d_min^2, query id)``.

    The cells of the cube ``q +- radius`` are looked up in the grid (a fixed number per query, no
    tree search), then pruned by the exact distance to each bucket's members' bounding box. A cube
    partly outside the grid is shifted inside; the cells it gains are pruned by that distance, the
    cells it loses lie in the empty padding or beyond.
    """
    first = np.clip(
        np.floor((qs - index.radius) / index.cell).astype(np.int64) - index.origin, 0, index.shape - index.span
    )
    b = index.dense[(first @ index.strides)[:, None] + index.offsets[None]]
    qid, k = np.nonzero(b >= 0)
    b = b[qid, k].astype(np.int64)
    q = qs[qid]
    gap = np.maximum(np.maximum(index.lo[b] - q, q - index.hi[b]), 0.0)
    d2 = np.einsum("ij,ij->i", gap, gap)
    keep = d2 <= index.radius**2
    return b[keep], d2[keep], qid[keep]


def sample_proportional(
    index: BucketIndex,
    qs: NDArray,
    pseudo: float,
    rng: np.random.Generator,
    allowed: NDArray[np.bool_] | None = None,
    pseudo_stop: float = 1.0,
    inv: NDArray[np.int64] | None = None,
    per_round: int = 32,
    max_rounds: int = 16,
) -> tuple[NDArray[np.int64], NDArray[np.bool_], NDArray[np.bool_]]:
    """One point per query with probability ``w_i / (sum w + pseudo)`` (see the module docstring).

    When the pseudo outcome is drawn, it is final with probability ``pseudo_stop``; otherwise the
    query goes on (pseudo removed) with the points outside ``allowed`` given weight 0, i.e. it then
    picks ``i`` with probability ``w_i / sum_{allowed} w``.

    Args:
        index: the buckets.
        qs: ``(m, d)`` scaled queries.
        pseudo: pseudo-weight ``a >= 0`` of the extra outcome.
        rng: generator.
        allowed: ``(n,)`` points that may be picked after a non-final pseudo draw (``None``: all).
        pseudo_stop: probability that a pseudo draw is final.
        inv: ``(m,)`` optional map of the ``m`` draws to rows of ``qs`` (identical queries share one
            bucket look-up); default one draw per row of ``qs``.
        per_round: proposals per query and round.
        max_rounds: rounds before a query is given up.

    Returns:
        ``pick (m,)`` point index (``-1`` = the final pseudo outcome), ``done (m,)`` and
        ``via_pseudo (m,)`` (the pseudo outcome was drawn). Queries with ``done = False`` accepted
        nothing within ``max_rounds`` (e.g. an empty ball and ``pseudo = 0``) and must be sampled
        otherwise (after a pseudo draw: restricted to ``allowed``).
    """
    inv = np.arange(qs.shape[0]) if inv is None else np.asarray(inv, dtype=np.int64)
    m = inv.size
    b, d2min, qid = _candidates(index, qs)
    pick = np.full(m, -1, dtype=np.int64)
    done = np.zeros(m, dtype=bool)
    via = np.zeros(m, dtype=bool)
    if b.size == 0:  # nothing in reach: only the pseudo outcome is possible
        via[:] = pseudo > 0
        done[:] = via & (rng.random(m) < pseudo_stop)
        return pick, done, via
    r2 = index.radius**2
    cw = np.cumsum(index.count[b] * np.exp(-0.5 * d2min))
    bounds = np.searchsorted(qid, np.arange(qs.shape[0] + 1), side="left")
    starts, last = bounds[:-1][inv], np.maximum(bounds[1:] - 1, 0)[inv]
    cw0 = np.concatenate([[0.0], cw])
    base, tot = cw0[starts], cw0[bounds[1:][inv]] - cw0[starts]
    ps = np.full(m, float(pseudo))
    pending = np.flatnonzero(tot + ps > 0)
    for _ in range(max_rounds):  # rounds of rejection (few), vectorised over queries and proposals
        if pending.size == 0:
            break
        tp = tot[pending, None]
        r = rng.random((3, pending.size, per_round))
        u = r[0] * (tp + ps[pending, None])
        is_pseudo = u >= tp
        j = np.minimum(
            np.maximum(np.searchsorted(cw, base[pending, None] + u, side="right"), starts[pending, None]),
            last[pending, None],
        )
        bb = b[j]
        member = index.order[index.start[bb] + (r[1] * index.count[bb]).astype(np.int64)]
        diff = index.points[member] - qs[inv[pending], None]
        dd = np.einsum("ijk,ijk->ij", diff, diff)
        ok = (dd <= r2) & (r[2] < np.exp(-0.5 * (dd - d2min[j])))
        if allowed is not None:
            ok &= ~via[pending, None] | allowed[member]
        acc = is_pseudo | ok
        first = np.argmax(acc, axis=1)
        hit = acc[np.arange(pending.size), first]
        f = first[hit]
        rows = pending[hit]
        got_pseudo = is_pseudo[hit, f]
        pick[rows] = np.where(got_pseudo, -1, member[hit, f])
        stop = got_pseudo & (rng.random(rows.size) < pseudo_stop)
        go_on = got_pseudo & ~stop
        via[rows[got_pseudo]] = True
        ps[rows[go_on]] = 0.0
        done[rows[~go_on]] = True
        pending = np.concatenate([pending[~hit], rows[go_on]])
    return pick, done, via
