"""The clutter stage of the radar rig calibration: count law and joint range x azimuth cell shares.

:func:`fit_clutter` is stage 4 of :func:`sensor_envs.radar.calibrate.calibrate_rig` (closed form: the count's mean
and over-dispersion, the shares of the real clutter positions per cell of :data:`CLUTTER_CELL_RANGE_EDGES` x
:data:`CLUTTER_CELL_AZIMUTH_EDGES`); :func:`calibrate_clutter` refits only it (``calibrate radar --clutter-only``).
:mod:`sensor_envs.radar.calibrate` re-exports the public names.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.radar.calibrate_stats import RealFrames, _bin
from sensor_envs.radar.rig import RigConfig

__all__ = [
    "CLUTTER_CELL_AZIMUTH_EDGES",
    "CLUTTER_CELL_RANGE_EDGES",
    "calibrate_clutter",
    "clutter_cell_shares",
    "fit_clutter",
]

CLUTTER_CELL_RANGE_EDGES = (0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0, 75.0, 100.0, 150.0)
"""Range bins [m] of the calibrated rig's joint clutter cells (``clutter_cell_weights``)."""
CLUTTER_CELL_AZIMUTH_EDGES = tuple(
    np.deg2rad(
        [-90.0, -60.0, -40.0, -30.0, -20.0, -15.0, -10.0, -5.0, -2.5, 0.0, 2.5, 5.0, 10.0, 15.0, 20.0, 30.0, 40.0]
        + [60.0, 90.0]
    ).tolist()
)
"""Azimuth bins [rad] of the calibrated rig's joint clutter cells."""


def clutter_cell_shares(
    xy: NDArray, range_edges: tuple[float, ...], azimuth_edges: tuple[float, ...]
) -> NDArray[np.float64]:
    """Shares of clutter positions ``xy`` (sensor frame [m]) per (range bin, azimuth bin) cell, flattened.

    Positions outside the edges are not counted; all zeros when none is inside.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    rb = _bin(np.hypot(xy[:, 0], xy[:, 1]), range_edges)
    ab = _bin(np.arctan2(xy[:, 1], xy[:, 0]), azimuth_edges)
    n_a = len(azimuth_edges) - 1
    ok = (rb >= 0) & (ab >= 0)
    h = np.bincount(rb[ok] * n_a + ab[ok], minlength=(len(range_edges) - 1) * n_a).astype(np.float64)
    return h / max(h.sum(), 1.0)


def fit_clutter(base: RigConfig, frames: RealFrames) -> RigConfig:
    """Stage 4: clutter count mean and dispersion, joint range x azimuth cell shares (closed form).

    The rig's range and azimuth shares are the cells' marginals over :data:`CLUTTER_CELL_RANGE_EDGES`
    and :data:`CLUTTER_CELL_AZIMUTH_EDGES`; with no clutter inside the cells the generic position law
    is kept.
    """
    counts = frames.clutter_counts
    m, v = float(counts.mean()), float(counts.var())
    k = max(0.0, (v - m) / m**2) if m > 0 else 0.0
    cells = clutter_cell_shares(frames.clutter_xy, CLUTTER_CELL_RANGE_EDGES, CLUTTER_CELL_AZIMUTH_EDGES)
    if cells.sum() <= 0:  # no clutter inside the bins: keep the generic law
        return replace(base, clutter_rate=m, clutter_dispersion=min(k, 100.0))
    grid = cells.reshape(len(CLUTTER_CELL_RANGE_EDGES) - 1, -1)
    return replace(
        base,
        clutter_rate=m,
        clutter_dispersion=min(k, 100.0),
        clutter_range_edges=CLUTTER_CELL_RANGE_EDGES,
        clutter_range_weights=tuple(grid.sum(axis=1).tolist()),
        clutter_azimuth_edges=CLUTTER_CELL_AZIMUTH_EDGES,
        clutter_azimuth_weights=tuple(grid.sum(axis=0).tolist()),
        clutter_cell_weights=tuple(cells.tolist()),
    )


def calibrate_clutter(frames: RealFrames, base: RigConfig) -> tuple[RigConfig, dict[str, Any]]:
    """``base`` with its clutter law refitted to ``frames`` (:func:`fit_clutter`); the card's clutter section.

    Only the clutter count and positions change (``calibrate radar --clutter-only``): a rig calibrated
    before the joint cell law gains it without re-running the detection and offset stages.
    """
    cfg = fit_clutter(base, frames)
    return cfg, {
        "data": frames.source,
        "frames": frames.n_frames,
        "clutter_rows": int(frames.clutter_xy.shape[0]),
        "procedure": "sensor_envs.radar.calibrate.fit_clutter (count mean and over-dispersion; joint range x "
        "azimuth cell shares of the real clutter positions, uniform inside a cell)",
        "joint_cells": cfg.clutter_cell_weights is not None,
    }
