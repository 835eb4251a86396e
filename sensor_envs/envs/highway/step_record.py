"""One policy step of the highway radar: the truth it looked at and what it reported.

Frames: ``*_s`` arrays are in the sensor frame (x forward, y left [m], origin at the sensor);
``*_w`` arrays and ``truth`` are in highway-env's world (road) frame [m]; velocities [m/s],
headings [rad].
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["Truth", "RadarFrame", "RadarInfo", "ObservedRows"]


@dataclass
class Truth:
    """True targets within perception distance (world frame)."""

    objects: list[Any]
    obstacle: NDArray[np.bool_]
    centre: NDArray[np.float64]
    heading: NDArray[np.float64]
    velocity: NDArray[np.float64]
    corners: NDArray[np.float64]


@dataclass
class RadarFrame:
    """What the radar reported in one policy step (see the module docstring for the ``info`` keys)."""

    truth: Truth
    sensor_pose: NDArray[np.float64]
    reference_s: NDArray[np.float64]
    visible: NDArray[np.bool_]
    detected: NDArray[np.bool_]
    det_s: NDArray[np.float64]
    det_w: NDArray[np.float64]
    det_v: NDArray[np.float64]
    det_heading: NDArray[np.float64]
    det_target: NDArray[np.int64]
    det_source: NDArray[np.int64]
    det_obstacle: NDArray[np.bool_]
    det_radial: NDArray[np.float64]
    det_track: NDArray[np.int64] | None = None

    @classmethod
    def assemble(
        cls,
        truth: Truth,
        pose: NDArray[np.float64],
        reference_s: NDArray[np.float64],
        visible: NDArray[np.bool_],
        detected: NDArray[np.bool_],
        target: NDArray[np.int64],
        det_s: NDArray[np.float64],
        det_w: NDArray[np.float64],
        velocity: NDArray[np.float64],
        heading: NDArray[np.float64],
        source: NDArray[np.int64],
        clutter_s: NDArray[np.float64],
        clutter_w: NDArray[np.float64],
        radial: NDArray[np.float64],
        clutter_radial: NDArray[np.float64] | None = None,
    ) -> RadarFrame:
        """Stack the ``k`` target detections and ``m`` clutter points (stationary, heading 0, target and source -1).

        ``det_s``/``clutter_s`` are sensor-frame points [m], ``det_w``/``clutter_w`` world points [m],
        ``velocity`` world velocities [m/s] and ``heading`` [rad] of the target detections, ``radial``
        their radial speed over ground [m/s] (the Doppler the radar measures, minus the ego's own
        motion), ``clutter_radial`` the clutter's (``None``: stationary, 0).
        """
        m = len(clutter_s)
        return cls(
            truth=truth,
            sensor_pose=pose,
            reference_s=reference_s,
            visible=visible,
            detected=detected,
            det_s=np.concatenate([det_s, clutter_s]),
            det_w=np.concatenate([det_w, clutter_w]),
            det_v=np.concatenate([velocity, np.zeros((m, 2))]),
            det_heading=np.concatenate([heading, np.zeros(m)]),
            det_target=np.concatenate([target, np.full(m, -1)]).astype(np.int64),
            det_source=np.concatenate([np.asarray(source, dtype=np.int64), np.full(m, -1, dtype=np.int64)]),
            det_obstacle=np.concatenate([truth.obstacle[target], np.zeros(m, dtype=bool)]),
            det_radial=np.concatenate([radial, np.zeros(m) if clutter_radial is None else clutter_radial]),
        )

    def info(self) -> dict[str, RadarInfo]:
        """The per-step ``info`` entry ``{"radar": RadarInfo}`` (fresh arrays)."""
        vis, det = self.visible, self.detected
        return {
            "radar": RadarInfo(
                truth_position=self.truth.centre.copy(),
                truth_velocity=self.truth.velocity.copy(),
                truth_reference=self.reference_s.copy(),
                visible=vis.copy(),
                detected=det.copy(),
                missed=vis & ~det,
                detections=self.det_s.copy(),
                detections_world=self.det_w.copy(),
                detection_target=self.det_target.copy(),
                source=self.det_source.copy(),
                sensor_pose=self.sensor_pose.copy(),
            )
        }


@dataclass(frozen=True, eq=False)
class RadarInfo:
    """Ground truth and radar output of one policy step, ``info["radar"]``.

    One object (not one ``info`` key per array) because the array lengths change from step to step:
    vector envs then collect it in an object array instead of stacking mismatched shapes.

    Attributes:
        truth_position: ``(n, 2)`` world centres [m] of the ``n`` targets within perception distance.
        truth_velocity: ``(n, 2)`` their world velocities [m/s].
        truth_reference: ``(n, 2)`` their reference points (closest corner or centre), sensor frame [m].
        visible: ``(n,)`` in the field of view and range, and not occluded.
        detected: ``(n,)`` reported by the radar.
        missed: ``(n,)`` visible but not reported.
        detections: ``(k, 2)`` reported positions, sensor frame [m]: targets first, then clutter.
        detections_world: ``(k, 2)`` the same in the world frame [m].
        detection_target: ``(k,)`` index of each detection's target, ``-1`` for clutter.
        source: ``(k,)`` the radar model's source-tuple id of each detection, ``-1`` for none.
        sensor_pose: ``(3,)`` world pose of the sensor ``x, y, yaw`` [m, m, rad].
    """

    truth_position: NDArray[np.float64]
    truth_velocity: NDArray[np.float64]
    truth_reference: NDArray[np.float64]
    visible: NDArray[np.bool_]
    detected: NDArray[np.bool_]
    missed: NDArray[np.bool_]
    detections: NDArray[np.float64]
    detections_world: NDArray[np.float64]
    detection_target: NDArray[np.int64]
    source: NDArray[np.int64]
    sensor_pose: NDArray[np.float64]

    def __eq__(self, other: object) -> bool:
        """Field-wise exact equality of the arrays."""
        if not isinstance(other, RadarInfo):
            return NotImplemented
        return all(np.array_equal(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class ObservedRows:
    """What the non-ego rows of the last observation hold (ground truth, for diagnostics), in row order.

    With ``order="shuffled"`` the order is before the shuffle.

    Attributes:
        objects: the highway-env object behind each row (``None``: clutter, or a track last updated by
            clutter); with ``tracks=True`` the object whose detection last updated the track.
        position: ``(r, 2)`` the rows' world positions [m] before normalisation.
        velocity: ``(r, 2)`` the rows' world velocities [m/s] before normalisation.
    """

    objects: list[Any]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
