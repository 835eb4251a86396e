"""The radar's mounting yaw error (azimuth bias), estimated from target offsets and undone around a model.

A radar mounted with a small yaw error ``b`` [rad] reports every target rotated about the sensor by
``b``: a cross-range error ``~ b * range`` of the SAME sign on both sides of the boresight (0.13 deg is
0.23 m at 100 m). A kernel model pooling targets left and right of the boresight in the corner's
outward frame (:func:`sensor_envs.geometry.to_polar_frame`) mirrors that error away, and one pooling in
the sensor frame cancels the outward offset of the reflection instead; with the rotation undone first,
the pooled law is the same on both sides and neither is lost. The real Astyx radar has one
(``models/radar_kde.md``, "Mounting yaw error").

Frames: sensor frame, x forward, y left, metres; angles counter-clockwise positive, radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from sensor_envs.geometry import from_frame

__all__ = ["MAX_AZIMUTH_BIAS", "derotate_offsets", "estimate_azimuth_bias", "rotate_offsets"]

MAX_AZIMUTH_BIAS = 0.05
"""Largest mounting yaw error [rad] (2.9 deg) a model estimates or accepts; the rig's bound as well."""
OUTWARD_RANGE_EDGES = (0.0, 15.0, 30.0, 50.0, 75.0, 120.0, np.inf)
"""Corner-range bins [m] of the nuisance outward offset of :func:`estimate_azimuth_bias`."""
OUTWARD_LATERAL_EDGES = (0.0, 2.0, 4.0, 8.0, 16.0, np.inf)
"""``|corner y|`` bins [m] of that nuisance (the face a target turns to the sensor changes with it)."""


def rotate_offsets(z: NDArray, corners: NDArray, angle: float) -> NDArray[np.float64]:
    """Offsets ``z (n, 2)`` [m] from ``corners (n, 2)`` [m] after rotating the measured positions about the sensor.

    Returns ``R(angle) (corner + z) - corner``: the offset of the position ``corner + z`` turned by
    ``angle`` [rad] (counter-clockwise). ``NaN`` rows (misses) stay ``NaN``; ``angle == 0`` returns ``z``.
    """
    z = np.asarray(z, dtype=np.float64)
    if angle == 0.0:
        return z
    c = np.asarray(corners, dtype=np.float64)
    return from_frame(z + c, (0.0, 0.0, angle)) - c


def derotate_offsets(z: NDArray, corners: NDArray, bias: float) -> NDArray[np.float64]:
    """Offsets as a radar without the mounting yaw error ``bias`` [rad] would report them (inverse of the error)."""
    return rotate_offsets(z, corners, -bias)


def estimate_azimuth_bias(
    corners: NDArray,
    z: NDArray,
    range_edges: tuple[float, ...] = OUTWARD_RANGE_EDGES,
    lateral_edges: tuple[float, ...] = OUTWARD_LATERAL_EDGES,
) -> float:
    """Mounting yaw error [rad] from detected targets: robust least squares on the signed cross-range offset.

    Model, per detection ``i`` at corner range ``r_i`` and side ``s_i`` (+1 left of the boresight, -1 right)::

        e_i = b * r_i + s_i * o_k(i) + noise,     e_i = z_i . (-sin az_i, cos az_i)

    ``e`` is the counter-clockwise cross-range component of the offset at the corner's azimuth ``az``;
    ``o_k`` is an outward offset per cell ``k`` of corner range x ``|corner y|`` (mirrored: toward the outer
    end of the face on both sides), the nuisance a rotation must be told apart from: ``b`` comes from the
    left/right imbalance within the cells. Soft-L1 loss (scale: 1.4826 x the median
    absolute residual of the ordinary fit), since offsets have heavy tails. The result is clipped to
    ``+-MAX_AZIMUTH_BIAS``.

    Args:
        corners: ``(n, 2)`` closest corners [m] of the detected targets, sensor frame.
        z: ``(n, 2)`` offsets ``measured - corner`` [m]; rows with ``NaN`` (misses) are ignored.
        range_edges: corner-range bin edges [m] of the outward nuisance term.
        lateral_edges: ``|corner y|`` bin edges [m] of that term.

    Returns:
        ``b`` [rad]; 0 when fewer than 10 detections are given or all lie on one side.
    """
    c, z = np.asarray(corners, dtype=np.float64), np.asarray(z, dtype=np.float64)
    ok = np.isfinite(z).all(axis=1) & np.isfinite(c).all(axis=1)
    c, z = c[ok], z[ok]
    side = np.where(c[:, 1] >= 0, 1.0, -1.0)
    if c.shape[0] < 10 or np.unique(side).size < 2:
        return 0.0
    az = np.arctan2(c[:, 1], c[:, 0])
    e = -np.sin(az) * z[:, 0] + np.cos(az) * z[:, 1]
    r = np.hypot(c[:, 0], c[:, 1])
    kr = np.clip(np.searchsorted(np.asarray(range_edges), r, side="right") - 1, 0, len(range_edges) - 2)
    ye = np.asarray(lateral_edges)
    ky = np.clip(np.searchsorted(ye, np.abs(c[:, 1]), side="right") - 1, 0, ye.size - 2)
    k = kr * len(lateral_edges) + ky
    used = np.unique(k)
    design = np.column_stack([r, *(side * (k == b) for b in used)])
    beta0, *_ = np.linalg.lstsq(design, e, rcond=None)
    scale = max(1.4826 * float(np.median(np.abs(e - design @ beta0))), 1e-3)
    fit = least_squares(lambda beta: design @ beta - e, beta0, loss="soft_l1", f_scale=scale)
    return float(np.clip(fit.x[0], -MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS))
