"""The fit of the KDE radar: tuples, the relevance variances (CV), the extra state and the bandwidth table."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.radar.alignment import estimate_azimuth_bias
from sensor_envs.radar.features import state_matrix, with_state_columns
from sensor_envs.radar.kde_bandwidth import cv_bandwidth_table, cv_groups
from sensor_envs.radar.kde_frames import to_model_frame
from sensor_envs.radar.kde_params import (
    MAX_CLUTTER_POSITIONS,
)
from sensor_envs.radar.kde_trees import build_trees
from sensor_envs.radar.log import RadarLog, clutter_counts, fit_cycle_time, target_tuples
from sensor_envs.radar.relevance import (
    select_corner_variance,
    select_corner_variances,
    select_extra_variances,
    select_prev_variance,
)

if TYPE_CHECKING:
    from sensor_envs.radar.kde import KDERadarModel

__all__ = ["fit_model", "fit_extra"]


def fit_model(
    m: KDERadarModel, log: RadarLog, cycle_time: float | None = None, progress: bool | None = None
) -> KDERadarModel:
    """:meth:`KDERadarModel.fit <sensor_envs.radar.kde.KDERadarModel.fit>`: tuples, relevance CV, bandwidths, trees."""
    cycle = fit_cycle_time(log, cycle_time)  # a RadarLog; the cycle time consistent with its t column
    m._check_params()
    progress = m._deprecated_progress(progress, m.verbose)
    rng = np.random.default_rng(m.random_state)
    tt = target_tuples(log)
    det = ~np.isnan(tt.z[:, 0])
    if det.sum() < 2:
        raise InputError(f"{log.source}: fewer than 2 detected target rows; cannot fit a KDE")
    m.azimuth_bias_ = estimate_azimuth_bias(tt.corner, tt.z) if m.azimuth_bias == "fit" else float(m.azimuth_bias)
    m.states_ = np.concatenate([tt.corner, to_model_frame(m, tt.z_prev, tt.corner)], axis=1)
    m.z_ = to_model_frame(m, tt.z, tt.corner)
    m.log_row_ = tt.row
    m.new_track_ = ~tt.has_prev_row  # first row of its target in the log
    m.rel_variance_ = tuple(float(v) for v in m.rel_variance)
    m.relevance_scores_ = np.zeros(0)
    polar = m.state_transform == "polar"
    if m.relevance in ("cv_axes", "cv_state") or (m.relevance == "cv" and polar):
        (v1, v2), m.relevance_scores_ = select_corner_variances(
            log,
            m,
            tuple(m.relevance_candidates),
            tuple(m.relevance_candidates_azimuth if polar else m.relevance_candidates),
            int(m.relevance_folds),
            progress,
        )
        m.rel_variance_ = (v1, v2, *m.rel_variance_[2:])
        if m.relevance == "cv_state" and m.use_prev:
            vp, sp = select_prev_variance(
                log,
                type(m)(**{**m.get_params(), "rel_variance": m.rel_variance_}),
                tuple(m.relevance_candidates_prev),
                int(m.relevance_folds),
                progress,
            )
            m.rel_variance_ = (v1, v2, vp, vp)
            m.relevance_scores_ = np.concatenate([m.relevance_scores_, sp])
    elif m.relevance == "cv":
        v, m.relevance_scores_ = select_corner_variance(
            log, m, tuple(m.relevance_candidates), int(m.relevance_folds), progress
        )
        m.rel_variance_ = (v, v, *m.rel_variance_[2:])
    m.scale_ = np.sqrt(np.asarray(m.rel_variance_, dtype=np.float64))
    fit_extra(m, log, tt.row, progress)
    m.cand_ = (
        np.asarray(m.cv_candidates, dtype=np.float64) if m.cv_candidates is not None else np.geomspace(0.02, 2.0, 14)
    )
    dims = 4 if m.use_prev else 2
    cv_rows = det & (~np.isnan(tt.z_prev[:, 0]) if m.use_prev else True)
    if cv_rows.sum() < m.cv_min_tuples:
        cv_rows = det
        dims = 2
    lo, hi = tt.corner.min(axis=0), tt.corner.max(axis=0)
    m.grid_x_ = np.arange(lo[0], hi[0] + m.cv_grid_step, m.cv_grid_step)
    m.grid_y_ = np.arange(lo[1], hi[1] + m.cv_grid_step, m.cv_grid_step)
    groups = cv_groups(tt, m.cv_group)
    m.log_h_, m.cv_counts_ = cv_bandwidth_table(
        np.concatenate([m.states_[cv_rows, :dims], m.extra_[cv_rows]], axis=1),
        m.z_[cv_rows],
        groups[cv_rows],
        m.grid_x_,
        m.grid_y_,
        np.concatenate([m.scale_[:dims], m.extra_scale_]),
        m.radius,
        m.cand_,
        m.cv_min_tuples,
        m.cv_max_tuples,
        rng,
        m.state_transform,
    )
    m.log_h_ = m.log_h_ + np.log(m.bandwidth_scale)  # no draw depends on it: the rest is the same
    counts, xy = clutter_counts(log)
    if xy.shape[0] > MAX_CLUTTER_POSITIONS:  # drawn last: smaller logs keep every earlier draw
        xy = xy[np.sort(rng.choice(xy.shape[0], MAX_CLUTTER_POSITIONS, replace=False))]
    m.clutter_counts_, m.clutter_xy_ = counts, xy
    m.cycle_time_ = cycle
    m.card_ = {}
    build_trees(m)
    return m


def fit_extra(m: KDERadarModel, log: RadarLog, rows: NDArray[np.int64], progress: bool) -> None:
    """Extra state columns at the tuples' ``rows``: values, NaN fill, relevance scales (CV if not given)."""
    m.extra_state_ = tuple(str(n) for n in m.extra_state)
    log = with_state_columns(log, m.extra_state_)  # derived features once, not per CV fold
    x = state_matrix(log, m.extra_state_, rows)
    fill = np.nanmedian(x, axis=0) if x.shape[1] and np.isfinite(x).any(axis=0).all() else np.zeros(x.shape[1])
    if x.shape[1] and not np.isfinite(x).any(axis=0).all():
        bad = m.extra_state_[int(np.argmin(np.isfinite(x).any(axis=0)))]
        raise InputError(f"{log.source}: column {bad!r} has no value on any target row")
    m.extra_fill_ = np.asarray(fill, dtype=np.float64)
    m.extra_ = np.where(np.isnan(x), m.extra_fill_, x)
    m.extra_scores_ = np.zeros((0, 0))
    if m.extra_variance is not None and not np.isnan(np.asarray(m.extra_variance, dtype=np.float64)).any():
        m.extra_variance_ = tuple(float(v) for v in m.extra_variance)
    elif x.shape[1]:
        std = np.maximum(m.extra_.std(axis=0), 1e-9)
        inner = type(m)(**{**m.get_params(), "rel_variance": m.rel_variance_, "relevance": "paper"})
        var, m.extra_scores_ = select_extra_variances(
            log, inner, std, tuple(m.extra_candidates), int(m.relevance_folds), progress
        )
        m.extra_variance_ = tuple(float(v) for v in var)
    else:
        m.extra_variance_ = ()
    m.extra_scale_ = np.sqrt(np.asarray(m.extra_variance_, dtype=np.float64)).reshape(-1)
