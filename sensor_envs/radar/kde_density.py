"""Densities of the KDE radar: ``log_prob`` (the seed's Eq. 10 with the tail mixture), bin probabilities, means."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from sensor_envs.radar.kde_frames import as_prev, extra_query, model_state, to_model_frame, to_sensor_frame
from sensor_envs.radar.kde_params import (
    GROUP_MAIN,
    LOG_2PI,
    LOG_PROB_CHUNK,
)
from sensor_envs.radar.kde_trees import outcome, route, with_detected_fallback
from sensor_envs.radar.log import check_states

if TYPE_CHECKING:
    from sensor_envs.radar.kde import KDERadarModel

__all__ = ["log_prob", "log_density", "bin_probabilities", "mean_output", "group_logsumexp"]


def log_prob(
    m, z: NDArray, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
) -> NDArray[np.float64]:
    """:meth:`KDERadarModel.log_prob <sensor_envs.radar.kde.KDERadarModel.log_prob>`."""
    m._check_fitted()
    check_states(state, z, extra=extra, new_track=new_track, extra_names=m.extra_state_)
    st = np.atleast_2d(np.asarray(state, dtype=np.float64))
    z = np.atleast_2d(np.asarray(z, dtype=np.float64))
    n = st.shape[0]
    if n > LOG_PROB_CHUNK:  # bounded memory: every (query, tuple) pair of a chunk is held at once
        ex = None if extra is None else np.atleast_2d(np.asarray(extra, dtype=np.float64))
        nt = None if new_track is None else np.asarray(new_track)
        return np.concatenate(
            [
                m.log_prob(
                    z[a : a + LOG_PROB_CHUNK],
                    st[a : a + LOG_PROB_CHUNK],
                    None if ex is None else ex[a : a + LOG_PROB_CHUNK],
                    None if nt is None else nt[a : a + LOG_PROB_CHUNK],
                )
                for a in range(0, n, LOG_PROB_CHUNK)  # one iteration per chunk of rows
            ]
        )
    st, z = model_state(m, st), to_model_frame(m, z, st[:, :2])
    prev = st[:, 2:4] if (st.shape[1] == 4 and m.use_prev) else None
    grp = route(m, as_prev(prev, n), new_track)
    gi, w, q, p_miss = outcome(m, st[:, :2], prev, extra_query(m, extra, n), grp)
    gi, w, q = with_detected_fallback(m, gi, w, q, st[:, :2])
    h = m.bandwidth(st[:, :2], start=grp != GROUP_MAIN)
    dens = log_density(m, z, gi, w, q, h)
    if m.tail_weight > 0:  # the defensive mixture: the same tuples, a share w of c-times wider kernels
        wide = log_density(m, z, gi, w, q, h * m.tail_scale)
        with np.errstate(invalid="ignore"):  # a miss row: -inf in both parts
            dens = np.logaddexp(np.log1p(-m.tail_weight) + dens, np.log(m.tail_weight) + wide)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.isnan(z[:, 0]), np.log(p_miss), np.log1p(-p_miss) + dens)


def log_density(m: KDERadarModel, z: NDArray, gi: NDArray, w: NDArray, q: NDArray, h: NDArray) -> NDArray[np.float64]:
    """``log p(z | x, detected)`` ``(n,)`` of one kernel mixture: neighbours ``(gi, w, q)``, bandwidths ``h``.

    Model-frame outputs ``z (n, 2)`` [m]; ``-inf`` for a ``NaN`` row (a miss).
    """
    n = z.shape[0]
    det_t = ~m.miss_[gi]
    r = (z[q] - np.where(det_t[:, None], m.z_[gi], 0.0)) / h[q]
    logk = -0.5 * np.sum(r**2, axis=1) - LOG_2PI - np.log(h[q]).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        logk = np.where(det_t & ~np.isnan(z[q, 0]), logk + np.log(w), -np.inf)
        log_wdet = np.log(np.bincount(q, weights=w * det_t, minlength=n))
        return group_logsumexp(logk, q, n) - log_wdet


def bin_probabilities(
    m: KDERadarModel,
    state: NDArray,
    edges_x: NDArray,
    edges_y: NDArray,
    extra: NDArray | None = None,
    new_track: NDArray | None = None,
) -> tuple[NDArray[np.float64], float]:
    """:meth:`KDERadarModel.bin_probabilities <sensor_envs.radar.kde.KDERadarModel.bin_probabilities>`."""
    m._check_fitted()
    st = model_state(m, np.atleast_2d(np.asarray(state, dtype=np.float64))[:1])
    prev = st[:, 2:4] if (st.shape[1] == 4 and m.use_prev) else None
    grp = route(m, as_prev(prev, 1), new_track)
    gi, w, q, p_miss = outcome(m, st[:, :2], prev, extra_query(m, extra, 1), grp)
    gi, w, _ = with_detected_fallback(m, gi, w, q, st[:, :2])
    h = m.bandwidth(st[:, :2], start=grp != GROUP_MAIN)[0]
    det = ~m.miss_[gi]
    zi, wd = m.z_[gi[det]], w[det] / w[det].sum()
    ex, ey = np.asarray(edges_x)[None, :], np.asarray(edges_y)[None, :]
    p = np.zeros((ex.size - 1, ey.size - 1))
    parts = ((1.0 - m.tail_weight, 1.0), (m.tail_weight, m.tail_scale))
    for share, c in parts if m.tail_weight > 0 else parts[:1]:  # the main kernels, then the tail's
        px = np.diff(ndtr((ex - zi[:, :1]) / (c * h[0])), axis=1)
        py = np.diff(ndtr((ey - zi[:, 1:]) / (c * h[1])), axis=1)
        p += share * np.einsum("i,ia,ib->ab", wd, px, py)
    return (1.0 - p_miss[0]) * p, float(p_miss[0])


def mean_output(
    m, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
) -> tuple[NDArray, NDArray]:
    """:meth:`KDERadarModel.mean_output <sensor_envs.radar.kde.KDERadarModel.mean_output>`."""
    m._check_fitted()
    st = model_state(m, np.atleast_2d(np.asarray(state, dtype=np.float64)))
    n = st.shape[0]
    ex = extra_query(m, extra, n)
    prev = st[:, 2:4] if (st.shape[1] == 4 and m.use_prev) else None
    gi, w, q, p_miss = outcome(m, st[:, :2], prev, ex, route(m, as_prev(prev, n), new_track))
    gi, w, q = with_detected_fallback(m, gi, w, q, st[:, :2])
    wd = w * ~m.miss_[gi]
    zi = np.nan_to_num(m.z_[gi])  # missed tuples have NaN outputs and zero weight here
    zsum = np.stack([np.bincount(q, weights=wd * zi[:, k], minlength=n) for k in range(2)], axis=1)
    mean = zsum / np.bincount(q, weights=wd, minlength=n)[:, None]
    return to_sensor_frame(m, mean, st[:, :2]), p_miss


def group_logsumexp(values: NDArray, groups: NDArray, n: int) -> NDArray[np.float64]:
    """``logsumexp`` of ``values`` within each of ``n`` sorted groups (empty/-inf groups give -inf)."""
    out = np.full(n, -np.inf)
    if values.size == 0:
        return out
    mx = np.full(n, -np.inf)
    np.maximum.at(mx, groups, values)
    safe = np.where(np.isfinite(mx), mx, 0.0)
    s = np.bincount(groups, weights=np.exp(values - safe[groups]), minlength=n)
    with np.errstate(divide="ignore"):
        out = np.where(s > 0, np.log(s) + safe, -np.inf)
    return out
