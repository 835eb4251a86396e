"""Per-pose corrections of a static-pose lidar log's approximate poses, jointly with a per-bearing bias.

The seed's remedy for approximate poses: the cell means of a log with repeats are modelled as

    mean[p, k] = r_k(pose_p + d_p) + b_k + noise,

where ``r_k`` is the map's raycast at bearing ``k`` [m], ``d_p = (dx, dy, dtheta)`` the correction of
pose ``p`` [m, m, rad] and ``b_k`` a constant bias per bearing [m]. The fit alternates (``n_iter`` rounds):
every pose's correction by robust least squares (``scipy.optimize.least_squares``, soft-L1 loss with
scale :data:`LOSS_SCALE`, so rays that graze a corner or hit another surface do not drag it; bounded by
:data:`MAX_SHIFT` and :data:`MAX_TURN`) on the residuals ``mean - b - r(pose + d)`` of its usable cells,
then ``b_k`` as the median over poses of ``mean - r(corrected pose)``. The first round starts from
``b = 0``. The learned lidar (:class:`~sensor_envs.lidar.lwlr.LidarLWLR` with ``pose_correction=True``)
then learns its bias at the corrected poses.

Frames and units: poses ``x, y, theta`` in the map frame [m, rad]; bearings in the sensor frame [rad].
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from sensor_envs.geometry import as_segments, raycast_pose
from sensor_envs.lidar.log import LidarLog

__all__ = ["correct_poses", "pose_error_sd", "MAX_SHIFT", "MAX_TURN", "LOSS_SCALE", "RES_CLIP"]

MAX_SHIFT = 0.3
"""Largest correction of a pose's position per axis [m]."""
MAX_TURN = 0.2
"""Largest correction of a pose's heading [rad] (11.5 deg)."""
LOSS_SCALE = 0.02
"""Scale of the soft-L1 loss [m]: residuals beyond it count about linearly (robust to outlying cells)."""
RES_CLIP = 0.5
"""Residuals [m] are clipped to this (a ray that leaves the map under a trial correction counts as this)."""


def _usable_cells(mean: NDArray[np.float64], n_ok: NDArray[np.float64], r: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Cells that inform the correction: a hit at the approximate pose and at least 2 in-range readings."""
    return np.isfinite(r) & (n_ok >= 2) & np.isfinite(mean)


def _residuals(
    d: NDArray[np.float64],
    pose: NDArray[np.float64],
    bearings: NDArray[np.float64],
    segs: NDArray[np.float64],
    target: NDArray[np.float64],
    max_range: float,
) -> NDArray[np.float64]:
    """``target - r(pose + d)`` [m] at the given bearings, clipped to ``+-RES_CLIP`` (no hit counts as the clip)."""
    r, _, _ = raycast_pose(pose + d, bearings, segs, max_range)
    return np.clip(np.where(np.isfinite(r), target - r, RES_CLIP), -RES_CLIP, RES_CLIP)


def correct_poses(
    log: LidarLog, mean: NDArray[np.float64], n_ok: NDArray[np.float64], max_range: float, n_iter: int = 3
) -> tuple[NDArray[np.float64], NDArray[np.float64], dict[str, Any]]:
    """Corrected poses and a per-bearing bias of a static-pose log (see the module docstring).

    Args:
        log: the log (approximate ``poses (P, 3)``, ``bearings (K,)``, a map).
        mean: ``(P, K)`` cell means of the in-range readings [m] (NaN where none).
        n_ok: ``(P, K)`` number of in-range readings per cell.
        max_range: farther hits count as no hit [m].
        n_iter: rounds of alternation between corrections and bias.

    Returns:
        ``poses (P, 3)`` corrected [m, rad] (theta wrapped to ``[-pi, pi)``), ``bias (K,)`` [m] (0 where no
        usable cell) and a summary: rms of ``dx``, ``dy`` [m] and ``dtheta`` [rad], the largest ``|d|``, the
        number of corrections at a bound, and the median absolute residual before and after [m].
    """
    segs = as_segments(log.require_map(), name="map")
    approx = np.asarray(log.poses, dtype=np.float64)
    r0, _, _ = raycast_pose(approx, log.bearings, segs, max_range)
    use = _usable_cells(mean, n_ok, r0)
    d = np.zeros_like(approx)
    bias = np.zeros(log.n_bearings)
    lo, hi = np.array([-MAX_SHIFT, -MAX_SHIFT, -MAX_TURN]), np.array([MAX_SHIFT, MAX_SHIFT, MAX_TURN])
    for _ in range(max(int(n_iter), 1)):
        for p in range(log.n_poses):
            k = use[p]
            if k.sum() < 6:  # too few cells to pin three numbers down: keep the pose
                continue
            fit = least_squares(
                _residuals,
                d[p],
                bounds=(lo, hi),
                loss="soft_l1",
                f_scale=LOSS_SCALE,
                diff_step=1e-4,
                args=(approx[p], log.bearings[k], segs, mean[p, k] - bias[k], max_range),
            )
            d[p] = fit.x
        r, _, _ = raycast_pose(approx + d, log.bearings, segs, max_range)
        ok = use & np.isfinite(r)
        res = np.where(ok, mean - np.where(ok, r, 0.0), np.nan)
        with warnings.catch_warnings():  # bearings without a usable cell (blocked) get bias 0
            warnings.simplefilter("ignore", RuntimeWarning)
            bias = np.nan_to_num(np.nanmedian(res, axis=0), nan=0.0)
    poses = approx + d
    poses[:, 2] = (poses[:, 2] + np.pi) % (2 * np.pi) - np.pi
    res0 = np.abs(np.where(use, mean - np.where(use, r0, 0.0), np.nan))
    r1, _, _ = raycast_pose(poses, log.bearings, segs, max_range)
    ok1 = use & np.isfinite(r1)
    res1 = np.abs(np.where(ok1, mean - bias[None] - np.where(ok1, r1, 0.0), np.nan))
    at_bound = np.isclose(np.abs(d), hi[None], rtol=0, atol=1e-6).any(axis=1)
    info = {
        "rms_dx": float(np.sqrt(np.mean(d[:, 0] ** 2))),
        "rms_dy": float(np.sqrt(np.mean(d[:, 1] ** 2))),
        "rms_dtheta": float(np.sqrt(np.mean(d[:, 2] ** 2))),
        "max_shift": float(np.abs(d[:, :2]).max(initial=0.0)),
        "max_turn": float(np.abs(d[:, 2]).max(initial=0.0)),
        "n_at_bound": int(at_bound.sum()),
        "median_abs_residual_before": float(np.nanmedian(res0)) if np.isfinite(res0).any() else float("nan"),
        "median_abs_residual_after": float(np.nanmedian(res1)) if np.isfinite(res1).any() else float("nan"),
        "n_iter": int(n_iter),
    }
    return poses, bias, info


def pose_error_sd(approx: NDArray[np.float64], corrected: NDArray[np.float64]) -> NDArray[np.float64]:
    """Spread of a log's rigid pose errors: robust sd (``1.4826`` x median absolute deviation) of ``dx, dy, dtheta``.

    Args:
        approx: ``(P, 3)`` the log's approximate poses [m, m, rad].
        corrected: ``(P, 3)`` their corrections by :func:`correct_poses`.

    Returns:
        ``(3,)`` standard deviations [m, m, rad] around the median correction (a common offset, e.g. the sensor's
        mounting yaw, is the bias's business, not a random pose error); zeros with fewer than 3 poses.
    """
    d = np.asarray(corrected, dtype=np.float64) - np.asarray(approx, dtype=np.float64)
    if d.shape[0] < 3:
        return np.zeros(3)
    d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return np.asarray(1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0), dtype=np.float64)
