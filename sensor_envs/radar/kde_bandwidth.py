"""The contribution bandwidths of the KDE radar: the leave-one-group-out CV table over corner positions.

Used by :meth:`sensor_envs.radar.kde.KDERadarModel.fit`; the relevance kernel's corner features
(:func:`corner_features`) are shared with its trees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from sensor_envs.inputs import InputError
from sensor_envs.radar.log import TargetTuples

if TYPE_CHECKING:
    pass

__all__ = ["cv_bandwidth_table", "corner_features", "relevance_features", "interp_log_h", "cv_groups"]


def interp_log_h(gx: NDArray, gy: NDArray, table: NDArray, pts: NDArray) -> NDArray[np.float64]:
    """Bilinear interpolation of ``table (nx, ny, 2)`` (log bandwidths) at ``pts (n, 2)``, clamped.

    ``gx``/``gy`` are the regular grid axes [m].
    """
    nx, ny = gx.size, gy.size
    fx = np.clip((pts[:, 0] - gx[0]) / (gx[-1] - gx[0] if nx > 1 else 1.0) * (nx - 1), 0, nx - 1)
    fy = np.clip((pts[:, 1] - gy[0]) / (gy[-1] - gy[0] if ny > 1 else 1.0) * (ny - 1), 0, ny - 1)
    ix, iy = np.minimum(fx.astype(np.int64), max(nx - 2, 0)), np.minimum(fy.astype(np.int64), max(ny - 2, 0))
    ax, ay = (fx - ix)[:, None], (fy - iy)[:, None]
    jx, jy = np.minimum(ix + 1, nx - 1), np.minimum(iy + 1, ny - 1)
    return (
        (1 - ax) * (1 - ay) * table[ix, iy]
        + ax * (1 - ay) * table[jx, iy]
        + (1 - ax) * ay * table[ix, jy]
        + ax * ay * table[jx, jy]
    )


def _loo_score(xs: NDArray, zs: NDArray, v: NDArray, groups: NDArray, cand: NDArray) -> NDArray[np.float64]:
    """Weighted leave-one-group-out log-likelihood ``(C, C)`` for bandwidth candidates ``(h_x, h_y)``.

    ``xs (M, d)`` scaled states, ``zs (M, 2)`` outputs, ``v (M,)`` weights of each held-out tuple,
    ``groups (M,)`` CV group ids: a held-out tuple is scored without every tuple of its group.
    """
    w = np.exp(-0.5 * np.sum((xs[:, None] - xs[None]) ** 2, axis=-1))  # w[i, j]: tuple i for query j
    w[groups[:, None] == groups[None, :]] = 0.0
    wsum = w.sum(axis=0)
    dz = zs[:, None] - zs[None]
    kx = np.exp(-0.5 * (dz[None, ..., 0] / cand[:, None, None]) ** 2) / cand[:, None, None]  # (C, M, M)
    ky = np.exp(-0.5 * (dz[None, ..., 1] / cand[:, None, None]) ** 2) / cand[:, None, None]
    dens = np.einsum("ij,aij,bij->abj", w, kx, ky, optimize=True) / (2 * np.pi * np.maximum(wsum, 1e-300))
    ok = wsum > 1e-12
    return np.sum(v[ok] * np.log(np.maximum(dens[..., ok], 1e-300)), axis=-1)


def cv_bandwidth_table(
    xs: NDArray,
    zs: NDArray,
    groups: NDArray,
    grid_x: NDArray,
    grid_y: NDArray,
    scale: NDArray,
    radius: float,
    cand: NDArray,
    min_tuples: int,
    max_tuples: int,
    rng: np.random.Generator,
    state_transform: str = "cartesian",
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Leave-one-out CV of the output bandwidths on a grid of corner positions.

    For each grid node ``g``, the detected tuples whose corner lies within ``radius`` relevance
    sigmas of ``g`` (at most ``max_tuples``, subsampled) are held out one at a time; each is scored
    by the conditional density of the tuples of OTHER groups (leave-one-group-out: consecutive
    cycles of one track are near-duplicates, and plain leave-one-out then picks far too small
    bandwidths), weighted by ``K_rel`` between full states; the held-out scores are weighted by
    ``K_rel(corner - g)``. The pair ``(h_x, h_y)`` of ``cand`` with the best score is kept. Nodes
    with fewer than ``min_tuples`` tuples take the value of the nearest node that has enough.

    Args:
        xs: ``(n, d)`` unscaled states of the detected tuples (corner first) [m].
        zs: ``(n, 2)`` outputs [m].
        groups: ``(n,)`` CV group id of each tuple (e.g. its track).
        grid_x: grid axis [m] of corner x.
        grid_y: grid axis [m] of corner y.
        scale: ``(d,)`` relevance standard deviations [m].
        radius: neighbourhood radius in relevance sigmas.
        cand: ``(C,)`` candidate bandwidths [m] for each output dimension.
        min_tuples: nodes with fewer tuples in reach take the median bandwidth of the others.
        max_tuples: larger neighbourhoods are subsampled to this size.
        rng: generator for subsampling.
        state_transform: corner features of the relevance kernel (:func:`corner_features`; ``scale``
            applies to the features, the grid stays in corner x/y).

    Returns:
        ``log_h (nx, ny, 2)`` log bandwidths [log m] and ``counts (nx, ny)`` tuples used per node.
    """
    s = relevance_features(xs, state_transform) / scale
    tree = cKDTree(s[:, :2])
    gx, gy = np.meshgrid(grid_x, grid_y, indexing="ij")
    nodes = corner_features(np.stack([gx.ravel(), gy.ravel()], axis=1), state_transform) / scale[:2]
    lists = tree.query_ball_point(nodes, radius)
    log_h = np.full((nodes.shape[0], 2), np.nan)
    counts = np.zeros(nodes.shape[0], dtype=np.int64)
    for n, idx in enumerate(lists):  # one iteration per grid node (tens), not per tuple
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size > max_tuples:
            idx = rng.choice(idx, max_tuples, replace=False)
        counts[n] = idx.size
        if idx.size < min_tuples:
            continue
        v = np.exp(-0.5 * np.sum((s[idx, :2] - nodes[n]) ** 2, axis=1))
        score = _loo_score(s[idx], zs[idx], v, groups[idx], cand)
        a, b = np.unravel_index(np.argmax(score), score.shape)
        log_h[n] = np.log([cand[a], cand[b]])
    good = ~np.isnan(log_h[:, 0])
    if not good.any():
        raise InputError(f"no grid node has {min_tuples} tuples within reach; lower cv_min_tuples")
    _, near = cKDTree(nodes[good]).query(nodes[~good], k=1)
    log_h[~good] = log_h[good][near]
    return log_h.reshape(grid_x.size, grid_y.size, 2), counts.reshape(grid_x.size, grid_y.size)


def corner_features(corners: NDArray, state_transform: str) -> NDArray[np.float64]:
    """Corner features ``(n, 2)`` of the relevance kernel from sensor-frame corners ``(n, 2)`` [m].

    ``"cartesian"``: the corners themselves (returned as given); ``"polar"``: ``(range [m], azimuth
    [rad], left > 0)``. The azimuth does not wrap at +-pi (a forward radar's field of view does not
    reach behind the sensor), so two corners just either side of the sensor's back axis are far apart.
    """
    if state_transform == "cartesian":
        return corners
    c = np.asarray(corners, dtype=np.float64)
    return np.stack([np.hypot(c[:, 0], c[:, 1]), np.arctan2(c[:, 1], c[:, 0])], axis=1)


def relevance_features(states: NDArray, state_transform: str) -> NDArray[np.float64]:
    """States ``(n, d)`` (corner x, y first [m]) with the corner columns as :func:`corner_features`."""
    if state_transform == "cartesian":
        return states
    return np.concatenate([corner_features(states[:, :2], state_transform), states[:, 2:]], axis=1)


def cv_groups(tt: TargetTuples, kind: str) -> NDArray[np.int64]:
    """CV group id of every tuple: its track, its sequence, or itself."""
    if kind == "row":
        return np.arange(tt.z.shape[0])
    key = np.stack([tt.sequence, tt.target], axis=1) if kind == "track" else tt.sequence[:, None]
    return np.unique(key, axis=0, return_inverse=True)[1].ravel().astype(np.int64)
