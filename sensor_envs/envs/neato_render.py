"""Dependency-free rasterisation of the 2D worlds to RGB arrays (map, robot, goal, lidar rays and hits)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["render_world"]

_WALL, _RAY, _HIT, _ROBOT, _GOAL = (20, 20, 20), (170, 200, 240), (220, 30, 30), (90, 90, 90), (30, 160, 60)


class _Canvas:
    """A white image with a metric-to-pixel transform (y up in the world, row 0 at the top)."""

    def __init__(self, bounds: tuple[float, float, float, float], width_px: int = 640, margin: float = 0.3) -> None:
        xmin, ymin, xmax, ymax = bounds
        self.x0, self.y1 = xmin - margin, ymax + margin
        self.scale = width_px / (xmax - xmin + 2 * margin)
        h = int(np.ceil((ymax - ymin + 2 * margin) * self.scale))
        self.img = np.full((h, width_px, 3), 255, dtype=np.uint8)

    def px(self, pts: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        cols = np.round((pts[..., 0] - self.x0) * self.scale).astype(np.int64)
        rows = np.round((self.y1 - pts[..., 1]) * self.scale).astype(np.int64)
        return rows, cols

    def put(self, rows: NDArray[np.int64], cols: NDArray[np.int64], color: tuple[int, int, int]) -> None:
        h, w, _ = self.img.shape
        ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        self.img[rows[ok], cols[ok]] = color

    def lines(self, a: NDArray[np.float64], b: NDArray[np.float64], color: tuple[int, int, int]) -> None:
        """Draw segments from points ``a (N, 2)`` to ``b (N, 2)`` [m]."""
        if len(a) == 0:
            return
        n = int(max(2, np.ceil(np.max(np.linalg.norm(b - a, axis=1)) * self.scale * 1.5)))
        f = np.linspace(0.0, 1.0, n)[None, :, None]
        self.put(*self.px(a[:, None, :] + f * (b - a)[:, None, :]), color)

    def disc(self, centre: NDArray[np.float64], radius_m: float, color: tuple[int, int, int]) -> None:
        r = max(1, int(round(radius_m * self.scale)))
        dr, dc = np.mgrid[-r : r + 1, -r : r + 1]
        keep = dr**2 + dc**2 <= r * r
        row, col = self.px(centre)
        self.put(row + dr[keep], col + dc[keep], color)


def render_world(
    segments: NDArray[np.float64],
    pose: NDArray[np.float64],
    goal: NDArray[np.float64],
    bearings: NDArray[np.float64],
    scan: NDArray[np.float64],
    robot_radius: float,
) -> NDArray[np.uint8]:
    """Draw walls, the lidar rays to their readings and the hits, the robot and the goal; ``(H, W, 3)`` uint8.

    ``scan`` holds ranges [m] per bearing (sensor frame, counter-clockwise from x forward); 0 or NaN = null.
    """
    pts = segments.reshape(-1, 2)
    cv = _Canvas(
        (
            min(pts[:, 0].min(), pose[0], goal[0]),
            min(pts[:, 1].min(), pose[1], goal[1]),
            max(pts[:, 0].max(), pose[0], goal[0]),
            max(pts[:, 1].max(), pose[1], goal[1]),
        )
    )
    ok = np.isfinite(scan) & (scan > 0)
    ang = pose[2] + bearings[ok]
    hits = pose[:2] + scan[ok, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    cv.lines(np.broadcast_to(pose[:2], hits.shape), hits, _RAY)
    cv.lines(segments[:, 0], segments[:, 1], _WALL)
    for h in hits:
        cv.disc(h, 0.6 / cv.scale, _HIT)
    cv.disc(goal[:2], 0.06, _GOAL)
    cv.disc(pose[:2], robot_radius, _ROBOT)
    head = pose[:2] + robot_radius * np.array([np.cos(pose[2]), np.sin(pose[2])])
    cv.lines(pose[None, :2], head[None], (255, 255, 255))
    return cv.img
