"""Overlay of the highway radar on highway-env's rendered frames.

Draws, in image pixels through highway-env's ``WorldSurface`` transform (world frame [m] to pixels),
the field-of-view edges, detections (magenta), clutter (orange) and missed targets (red).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.envs.highway.sensor import SensorSpec
from sensor_envs.envs.highway.step_record import RadarFrame
from sensor_envs.geometry import from_frame

__all__ = ["draw_radar"]


_DETECTION, _CLUTTER, _MISS, _FOV = (230, 0, 230), (255, 140, 0), (220, 0, 0), (120, 170, 255)


def _to_pixels(surface: Any, points_w: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """World points ``(n, 2)`` [m] to image ``(rows, cols)`` with highway-env's ``WorldSurface`` transform."""
    cols = ((points_w[:, 0] - surface.origin[0]) * surface.scaling).astype(np.int64)
    rows = ((points_w[:, 1] - surface.origin[1]) * surface.scaling).astype(np.int64)
    return rows, cols


def _paint(
    img: NDArray[np.uint8], rows: NDArray[np.int64], cols: NDArray[np.int64], color: tuple[int, int, int], half: int = 0
) -> None:
    """Paint squares of side ``2 * half + 1`` px centred on the pixels, clipped to the image."""
    dr, dc = np.mgrid[-half : half + 1, -half : half + 1]
    r, c = (rows[:, None] + dr.ravel()).ravel(), (cols[:, None] + dc.ravel()).ravel()
    ok = (r >= 0) & (r < img.shape[0]) & (c >= 0) & (c < img.shape[1])
    img[r[ok], c[ok]] = color


def draw_radar(image: NDArray[np.uint8], surface: Any, frame: RadarFrame, spec: SensorSpec) -> NDArray[np.uint8]:
    """Overlay the field of view edges, detections (magenta), clutter (orange) and misses (red) on a frame.

    Args:
        image: ``(H, W, 3)`` uint8 frame rendered by highway-env from ``surface``.
        surface: highway-env's ``WorldSurface`` (``origin`` [m], ``scaling`` [px/m]).
        frame: the radar output to draw.
        spec: the sensor (for the field of view).

    Returns:
        A new ``(H, W, 3)`` uint8 image.
    """
    img = np.array(image, dtype=np.uint8, copy=True)
    pose = frame.sensor_pose
    if spec.fov < 2 * np.pi:
        reach = min(spec.max_range, 60.0)
        t = np.linspace(0.0, reach, 200)
        for side in (-0.5, 0.5):
            ang = pose[2] + side * spec.fov
            pts = pose[:2] + t[:, None] * np.array([np.cos(ang), np.sin(ang)])
            _paint(img, *_to_pixels(surface, pts), _FOV)
    clutter = frame.det_target < 0
    _paint(img, *_to_pixels(surface, frame.det_w[~clutter]), _DETECTION, half=3)
    _paint(img, *_to_pixels(surface, frame.det_w[clutter]), _CLUTTER, half=3)
    missed = frame.visible & ~frame.detected
    if missed.any():
        miss_w = from_frame(frame.reference_s[missed], pose)
        _paint(img, *_to_pixels(surface, miss_w), _MISS, half=2)
    return img
