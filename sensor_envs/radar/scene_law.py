"""The rig's scene law fitted to real reference boxes (``sensor-envs calibrate radar --scene``).

The KDE radar model's state is the closest corner (and the previous output). Its density at a corner
position is therefore an average over the boxes the training log had there: their headings and sizes.
A rig log whose SCENE differs from the real one (the generic lane traffic: 80 % of the cars along x on
five lanes within +-7 m, all 3.8-5 m long) teaches the KDE the offsets of other boxes than those a real
sensor sees at that place. The scene law makes the rig's recorded boxes follow the real reference
boxes' statistics: a few dozen numbers, no rows (:func:`fit_scene_law`):

* the share of boxes per bin of the centre's x (:data:`SCENE_X_EDGES`);
* per x bin, the shares of the centre's y bins (:data:`SCENE_Y_EDGES`, signed: left and right apart);
* per x bin, the shares of the heading-modulo-pi bins (:data:`SCENE_HEADING_EDGES`; a box turned by pi
  is the same box): along the road, angled, across;
* the length and width ranges (5th to 95th percentile).

Each share is ``(count + prior) / (total + prior * bins)`` (``prior`` pseudo-counts, so a bin thin in
the data keeps a little mass). The relative speed cannot be seen in single frames; it is a stated
choice (``speed_std``). Frames: sensor frame (x forward, y left), metres, radians.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.radar.rig import RadarRig, RigConfig, generate_scenario

__all__ = [
    "SCENE_X_EDGES",
    "SCENE_Y_EDGES",
    "SCENE_HEADING_EDGES",
    "fit_scene_law",
    "with_scene_law",
    "scene_stats",
    "scene_card",
]

SCENE_X_EDGES = (0.0, 15.0, 30.0, 50.0, 75.0, 120.0)
"""Bins of the box centre's x [m] (the range bins of the calibration's statistics)."""
SCENE_Y_EDGES = (-30.0, -18.0, -12.0, -7.0, -3.5, 0.0, 3.5, 7.0, 12.0, 18.0, 30.0)
"""Bins of the box centre's y [m] (values beyond are counted in the end bins)."""
SCENE_HEADING_EDGES = tuple(np.deg2rad([-90.0, -75.0, -45.0, -15.0, -5.0, 5.0, 15.0, 45.0, 75.0, 90.0]).tolist())
"""Bins of the heading modulo pi [rad]: across (|h| > 75 deg), angled, along (|h| < 15 deg, < 5 deg)."""
SCENE_SPEED_STD = 0.25
"""Default std [m/s] of the targets' speed relative to the sensor: a choice (single frames show no motion),
small so that a target stays near where the law put it over a 40-cycle sequence (about 3 m in x)."""


def heading_mod_pi(heading: NDArray) -> NDArray[np.float64]:
    """Heading [rad] modulo pi, in ``[-pi/2, pi/2)`` (a box turned by pi is the same box)."""
    return np.asarray((np.asarray(heading, dtype=np.float64) + np.pi / 2) % np.pi - np.pi / 2, dtype=np.float64)


def _bin_clipped(values: NDArray, edges: tuple[float, ...]) -> NDArray[np.intp]:
    """Bin index of each value in ``edges`` (values beyond the edges counted in the end bins)."""
    e = np.asarray(edges, dtype=np.float64)
    return np.asarray(np.clip(np.searchsorted(e, values, side="right") - 1, 0, e.size - 2), dtype=np.intp)


def _shares(values: NDArray, edges: tuple[float, ...], prior: float) -> NDArray[np.float64]:
    """Shares of ``values`` per bin of ``edges`` (clipped into the end bins), with ``prior`` pseudo-counts."""
    counts = np.bincount(_bin_clipped(values, edges), minlength=len(edges) - 1).astype(np.float64) + prior
    return counts / counts.sum()


def fit_scene_law(
    boxes: NDArray[np.float64],
    *,
    x_edges: tuple[float, ...] = SCENE_X_EDGES,
    y_edges: tuple[float, ...] = SCENE_Y_EDGES,
    heading_edges: tuple[float, ...] = SCENE_HEADING_EDGES,
    prior: float = 0.5,
    speed_std: float = SCENE_SPEED_STD,
) -> dict[str, Any]:
    """The scene law's :class:`RigConfig` fields fitted to reference boxes (see the module docstring).

    Args:
        boxes: ``(n, 5)`` ``x, y, heading, length, width`` [m, rad] of the real reference boxes.
        x_edges: bins of the box centre's x [m].
        y_edges: bins of the box centre's y [m] (per x bin).
        heading_edges: bins of the heading modulo pi [rad], within ``[-pi/2, pi/2]`` (per x bin).
        prior: pseudo-count per bin (> 0: no bin of the law is empty).
        speed_std: the targets' relative speed std [m/s] (not in single frames: a choice).

    Raises:
        ValueError: with fewer than 10 boxes, or non-finite box values.
    """
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.ndim != 2 or boxes.shape[1] != 5 or boxes.shape[0] < 10:
        raise InputError(f"boxes: need at least 10 reference boxes (n, 5), got shape {boxes.shape}")
    if not np.all(np.isfinite(boxes)):
        raise InputError("boxes: reference boxes must be finite")
    x, y, h, length, width = boxes.T
    bx = _bin_clipped(x, x_edges)
    y_w, h_w = [], []
    for b in range(len(x_edges) - 1):  # one iteration per x bin (five)
        s = bx == b
        y_w.append(_shares(y[s], y_edges, prior))
        h_w.append(_shares(heading_mod_pi(h[s]), heading_edges, prior))
    return {
        "scene_x_edges": tuple(float(v) for v in x_edges),
        "scene_x_weights": tuple(_shares(x, x_edges, prior).tolist()),
        "scene_y_edges": tuple(float(v) for v in y_edges),
        "scene_y_weights": tuple(np.concatenate(y_w).tolist()),
        "scene_heading_edges": tuple(float(v) for v in heading_edges),
        "scene_heading_weights": tuple(np.concatenate(h_w).tolist()),
        "scene_length_range": tuple(np.percentile(length, [5, 95]).tolist()),
        "scene_width_range": tuple(np.percentile(width, [5, 95]).tolist()),
        "scene_speed_std": float(speed_std),
    }


def with_scene_law(config: RigConfig, boxes: NDArray[np.float64], **kwargs: Any) -> RigConfig:
    """``config`` with the scene law fitted to ``boxes`` (:func:`fit_scene_law`; other fields unchanged)."""
    return replace(config, **fit_scene_law(boxes, **kwargs))


def scene_stats(boxes: NDArray[np.float64], x_edges: tuple[float, ...] = SCENE_X_EDGES) -> list[dict[str, float]]:
    """Per x bin: box count, ``|y|`` quartiles [m] and the share along the road (|heading mod pi| < 15 deg).

    The check a card reports for the real boxes and for the rig's recorded ones side by side.
    """
    boxes = np.asarray(boxes, dtype=np.float64)
    xe = np.asarray(x_edges, dtype=np.float64)
    out = []
    for lo, hi in zip(xe[:-1], xe[1:], strict=True):  # one iteration per x bin
        s = (boxes[:, 0] >= lo) & (boxes[:, 0] < hi)
        row: dict[str, float] = {"x_low": float(lo), "x_high": float(hi), "boxes": int(s.sum())}
        if s.any():
            q = np.percentile(np.abs(boxes[s, 1]), [25, 50, 75])
            row.update({"abs_y_q25": float(q[0]), "abs_y_q50": float(q[1]), "abs_y_q75": float(q[2])})
            row["along_share"] = float(np.mean(np.abs(heading_mod_pi(boxes[s, 2])) < np.deg2rad(15.0)))
        out.append(row)
    return out


def recorded_boxes(
    config: RigConfig, rng: np.random.Generator, n_sequences: int = 200, n_cycles: int = 10, n_targets: int = 8
) -> NDArray[np.float64]:
    """The boxes ``(m, 5)`` [m, rad] a rig log records from ``config``'s scenes (in view, within ``log_range``).

    The defaults are the logs of the scene-law experiments of models/radar_kde.md (``record radar
    --sequences 200 --cycles 10``), so that 1,600 targets sample the scene; the shipped models' logs are 50 x 40.
    """
    rig, out = RadarRig(config), []
    for _ in range(n_sequences):  # one iteration per scenario
        b = generate_scenario(n_targets, n_cycles, config.cycle_time, rng, config).boxes.reshape(-1, 5)
        out.append(b[rig.in_view(b) & (np.hypot(b[:, 0], b[:, 1]) <= config.log_range)])
    return np.concatenate(out)


def scene_card(config: RigConfig, boxes: NDArray[np.float64], seed: int = 0) -> dict[str, Any]:
    """The card's scene section: the real boxes' :func:`scene_stats` beside those of the rig's recorded boxes."""
    return {
        "procedure": "sensor_envs.radar.scene_law.fit_scene_law (shares of x bins, and per x bin of y and "
        "heading-modulo-pi bins, with 0.5 pseudo-counts; length and width 5th-95th percentiles)",
        "speed_std_chosen": config.scene_speed_std,
        "real_boxes": scene_stats(boxes),
        "recorded_boxes": scene_stats(recorded_boxes(config, np.random.default_rng(seed))),
    }
