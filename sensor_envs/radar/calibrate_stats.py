"""The statistics the radar rig calibration matches: real frames, their binned statistics, the discrepancy.

:class:`RealFrames` holds real single frames (reference boxes and detections; :func:`load_real`),
:func:`real_statistics` and :func:`rig_statistics` bin the same statistics of the real frames and of the rig
recording at them (detection per range, azimuth and occlusion, offsets, clutter), :func:`discrepancy` compares
them (the objective of :func:`sensor_envs.radar.calibrate.calibrate_rig`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sensor_envs.geometry import closest_corner, rectangle_corners, to_polar_frame
from sensor_envs.inputs import InputError
from sensor_envs.radar.features import occluded_column
from sensor_envs.radar.log import REF_COLUMNS, RadarLog, clutter_counts
from sensor_envs.radar.rig import RadarRig, RigConfig, SnapshotDraws
from sensor_envs.radar.validate import energy_distance_2d

__all__ = [
    "DET_RANGE_EDGES",
    "DET_AZIMUTH_EDGES",
    "QUANTILES",
    "RealFrames",
    "frames_from_log",
    "load_real",
    "rig_statistics",
    "real_statistics",
    "DETECTION_TERMS",
    "detection_discrepancy",
    "discrepancy",
]


DET_RANGE_EDGES = (0.0, 15.0, 30.0, 50.0, 75.0, 120.0)
"""Corner-range bins [m] of the detection and offset statistics (those of ``validate radar``)."""
DET_AZIMUTH_EDGES = tuple(np.deg2rad([-180.0, -40.0, -20.0, -5.0, 5.0, 20.0, 40.0, 180.0]).tolist())
"""Signed corner-azimuth bins [rad] of the detection statistic (left > 0)."""
CELL_AZIMUTH_EDGES = tuple(
    np.deg2rad([-180.0, -55.0, -40.0, -25.0, -10.0, 0.0, 10.0, 25.0, 40.0, 55.0, 180.0]).tolist()
)
"""Signed azimuth bins [rad] of the joint range x azimuth detection cells (left > 0)."""
OCCLUSION_EDGES = (0.0, 1e-9, 0.5, 1.0 + 1e-9)
"""Occluded-fraction bins: none, partly (< 0.5), mostly."""
QUANTILES = (0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95)
"""Quantiles of the offset components compared per range bin."""
CLUTTER_RANGE_EDGES = (0.0, 15.0, 30.0, 50.0, 75.0, 100.0, 150.0)
"""Clutter range bins [m] (statistic and calibrated rig's table)."""
CLUTTER_AZIMUTH_EDGES = tuple(np.deg2rad([-90.0, -60.0, -40.0, -20.0, -5.0, 5.0, 20.0, 40.0, 60.0, 90.0]).tolist())
"""Clutter azimuth bins [rad]."""
DETECT_RANGE_KNOTS = (0.0, 10.0, 20.0, 35.0, 50.0, 75.0, 100.0, 120.0)
"""Range knots [m] of the calibrated detection table."""
DETECT_AZIMUTH_KNOTS = tuple(np.deg2rad(np.arange(-90.0, 91.0, 15.0)).tolist())
"""Signed azimuth knots [rad] (left > 0) of the calibrated detection factor (1 at 0 by construction)."""
_AZ0 = DETECT_AZIMUTH_KNOTS.index(0.0)
"""Index of the 0-deg knot (the fixed factor 1)."""
OCCLUSION_LOSS_KNOTS = (7.5, 22.5, 40.0, 62.5, 97.5)
"""Range knots [m] of the calibrated occlusion-loss table (``occlusion_by_range``): the detection bins' centres."""
OFFSET_RANGE_KNOTS = (0.0, 20.0, 40.0, 70.0, 110.0)
"""Range knots [m] of the calibrated offset-spread tables."""


@dataclass(frozen=True)
class RealFrames:
    """Single frames of real (or synthetic "real") data: target boxes, outcomes and clutter.

    Attributes:
        boxes: ``(n, 5)`` reference boxes ``x, y, heading, length, width`` [m, rad] of the target rows.
        frame: ``(n,)`` frame id of each row (0..n_frames-1).
        occluded: ``(n,)`` occluded fraction of each box among its frame's target boxes.
        corner: ``(n, 2)`` closest corner [m].
        meas: ``(n, 2)`` measured position [m] (``NaN``: missed).
        clutter_counts: ``(n_frames,)`` clutter detections per frame.
        clutter_xy: ``(m, 2)`` clutter positions [m].
        source: where the data came from (a folder or file name; no data).
    """

    boxes: NDArray[np.float64]
    frame: NDArray[np.int64]
    occluded: NDArray[np.float64]
    corner: NDArray[np.float64]
    meas: NDArray[np.float64]
    clutter_counts: NDArray[np.float64]
    clutter_xy: NDArray[np.float64]
    source: str

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(self.clutter_counts.size)


def frames_from_log(log: RadarLog, source: str | None = None) -> RealFrames:
    """The single frames of a log: every ``(sequence, frame)`` is one frame (time order ignored).

    Raises:
        ValueError: when the log holds no target row.
    """
    tgt = ~log.is_clutter
    if not tgt.any():
        raise InputError("no target rows (reference boxes) to calibrate against")
    keys = np.stack([log["sequence"], log["frame"]], axis=1)
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    boxes = np.stack([log[c] for c in REF_COLUMNS], axis=1)[tgt]
    frame = inv[tgt].astype(np.int64)
    corner, _ = closest_corner(rectangle_corners(*boxes.T))
    occ = occluded_column(log)[tgt]
    counts = np.bincount(inv[log.is_clutter], minlength=uniq.shape[0]).astype(np.float64)
    _, xy = clutter_counts(log)
    meas = np.stack([log["meas_x"], log["meas_y"]], axis=1)[tgt]
    return RealFrames(boxes, frame, occ, corner, meas, counts, xy, source or log.source)


def load_real(path: str | os.PathLike[str], progress: bool = False) -> RealFrames:
    """Real data for calibration: an ``astyx_hires2019`` folder or a radar log CSV of single frames."""
    p = Path(path)
    if p.is_dir():
        from sensor_envs.radar.astyx import load_astyx

        return frames_from_log(load_astyx(p, progress=progress), source=p.name)
    from sensor_envs.radar.log import read_log

    return frames_from_log(read_log(p), source=p.name)


# ------------------------------------------------------------------------------------------- statistics
def _bin(v: NDArray, edges: tuple[float, ...]) -> NDArray[np.int64]:
    """Bin index of each value (``-1`` outside the edges)."""
    e = np.asarray(edges)
    b = np.searchsorted(e, v, side="right") - 1
    return np.where((v >= e[0]) & (v < e[-1]), b, -1)


def _rates(det: NDArray, b: NDArray, n_bins: int) -> NDArray[np.float64]:
    """Mean of ``det`` per bin (NaN for empty bins)."""
    ok = b >= 0
    n = np.bincount(b[ok], minlength=n_bins).astype(np.float64)
    s = np.bincount(b[ok], weights=det[ok].astype(np.float64), minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return s / n


@dataclass(frozen=True)
class _Bins:
    """Bin indices of the real rows (fixed: they depend on the boxes only)."""

    range: NDArray[np.int64]
    azimuth: NDArray[np.int64]
    occlusion: NDArray[np.int64]
    cell: NDArray[np.int64]


def _bins(frames: RealFrames) -> _Bins:
    r = np.hypot(frames.corner[:, 0], frames.corner[:, 1])
    az = np.arctan2(frames.corner[:, 1], frames.corner[:, 0])
    rb, ab = _bin(r, DET_RANGE_EDGES), _bin(az, CELL_AZIMUTH_EDGES)
    cell = np.where((rb >= 0) & (ab >= 0), rb * (len(CELL_AZIMUTH_EDGES) - 1) + ab, -1)
    return _Bins(rb, _bin(az, DET_AZIMUTH_EDGES), _bin(frames.occluded, OCCLUSION_EDGES), cell)


_N_CELLS = (len(DET_RANGE_EDGES) - 1) * (len(CELL_AZIMUTH_EDGES) - 1)
_N_OCC = len(OCCLUSION_EDGES) - 1
_N_OCC_RANGE = (len(DET_RANGE_EDGES) - 1) * _N_OCC


def _occlusion_range_bin(bins: _Bins) -> NDArray[np.int64]:
    """Cell index ``range bin x occluded-fraction bin`` of each row (``-1`` outside the bins)."""
    ok = (bins.range >= 0) & (bins.occlusion >= 0)
    return np.where(ok, bins.range * _N_OCC + bins.occlusion, -1)


def _detection_stats(det: NDArray, bins: _Bins) -> dict[str, NDArray[np.float64]]:
    return {
        "det_range": _rates(det, bins.range, len(DET_RANGE_EDGES) - 1),
        "det_azimuth": _rates(det, bins.azimuth, len(DET_AZIMUTH_EDGES) - 1),
        "det_occlusion": _rates(det, bins.occlusion, _N_OCC),
        "det_cells": _rates(det, bins.cell, _N_CELLS),
        "det_occlusion_range": _rates(det, _occlusion_range_bin(bins), _N_OCC_RANGE),
    }


def _offset_samples(corner: NDArray, meas: NDArray, range_bin: NDArray) -> tuple[NDArray, NDArray]:
    """Polar ``(radial, outward cross-range)`` ``z`` [m] of the detected rows and their range bins."""
    det = np.isfinite(meas[:, 0])
    return to_polar_frame(meas[det] - corner[det], corner[det]), range_bin[det]


def _offset_energy(
    z_sim: NDArray, b_sim: NDArray, z_real: NDArray, b_real: NDArray, max_sim: int = 1500
) -> NDArray[np.float64]:
    """Energy distance [m] between the rig's and the real polar offsets per range bin (V-statistic).

    NaN where the real data have fewer than 5 detected rows; ``2.0`` m where the real data have rows
    but the rig detects none (it never detects there). At most the first ``max_sim`` simulated rows
    of a bin are used (deterministic: the discrepancy stays a function of the parameters under
    common random numbers).
    """
    out = np.full(len(DET_RANGE_EDGES) - 1, np.nan)
    for b in range(out.size):  # one iteration per range bin
        r = z_real[b_real == b]
        if r.shape[0] < 5:
            continue
        s = z_sim[b_sim == b][:max_sim]
        if s.shape[0] == 0:
            out[b] = 2.0
            continue
        out[b] = energy_distance_2d(s, r)  # no rng: every row, deterministic
    return out


def _offset_term(z_sim: NDArray, b_sim: NDArray, z_real: NDArray, real: dict[str, NDArray]) -> float:
    """An offset term of :func:`discrepancy` [m]: the bins' energy distances weighted by the real detected rows."""
    w = real["n_offset"] / max(real["n_offset"].sum(), 1.0)
    return float(np.sum(w * np.nan_to_num(_offset_energy(z_sim, b_sim, z_real, real["offset_bin"]))))


def _signed_offset_samples(corner: NDArray, meas: NDArray, range_bin: NDArray) -> tuple[NDArray, NDArray]:
    """``(radial, SIGNED cross-range)`` ``z`` [m] of the detected rows and their range bins.

    The cross-range is counter-clockwise positive on both sides of the boresight, so a rotation of every
    detection shows (the outward frame of :func:`~sensor_envs.geometry.to_polar_frame` mirrors it away).
    """
    pz, rb = _offset_samples(corner, meas, range_bin)
    return _signed_cross_range(pz, corner, meas), rb


def _signed_cross_range(pz: NDArray, corner: NDArray, meas: NDArray) -> NDArray[np.float64]:
    """The polar samples ``pz`` of :func:`_offset_samples` (detected rows) with the outward cross-range signed."""
    det = np.isfinite(meas[:, 0])
    side = np.where(np.arctan2(corner[det, 1], corner[det, 0]) < 0, -1.0, 1.0)
    return np.stack([pz[:, 0], side * pz[:, 1]], axis=1)


def _offset_stats(corner: NDArray, meas: NDArray, range_bin: NDArray) -> dict[str, NDArray]:
    """The offset statistics of the detected rows.

    ``offset_z`` / ``offset_bin``: polar samples [m] and their range bins (:func:`_offset_samples`);
    ``offset_signed_z``: the same rows with a signed cross-range (:func:`_signed_offset_samples`);
    ``offset``: their quantiles ``(n_range_bins, n_quantiles, 2)`` (reports).
    """
    pz, rb = _offset_samples(corner, meas, range_bin)
    out = np.full((len(DET_RANGE_EDGES) - 1, len(QUANTILES), 2), np.nan)
    for b in range(out.shape[0]):  # one iteration per range bin
        sel = rb == b
        if sel.sum() >= 5:
            out[b] = np.quantile(pz[sel], QUANTILES, axis=0)
    signed = _signed_cross_range(pz, corner, meas)
    return {"offset": out, "offset_z": pz, "offset_bin": rb, "offset_signed_z": signed}


def _clutter_stats(counts: NDArray, xy: NDArray) -> dict[str, NDArray[np.float64]]:
    r, az = np.hypot(xy[:, 0], xy[:, 1]), np.arctan2(xy[:, 1], xy[:, 0])

    def shares(v: NDArray, edges: tuple[float, ...]) -> NDArray[np.float64]:
        b = _bin(v, edges)
        h = np.bincount(b[b >= 0], minlength=len(edges) - 1).astype(np.float64)
        return h / max(h.sum(), 1.0)

    return {
        "clutter_count": np.array([counts.mean(), counts.std()]),
        "clutter_range": shares(r, CLUTTER_RANGE_EDGES),
        "clutter_azimuth": shares(az, CLUTTER_AZIMUTH_EDGES),
    }


def real_statistics(frames: RealFrames) -> dict[str, NDArray[np.float64]]:
    """The calibration statistics of the real data (see the module docstring)."""
    bins = _bins(frames)
    occ_range = _occlusion_range_bin(bins)
    det = np.isfinite(frames.meas[:, 0])
    return {
        **_detection_stats(det, bins),
        **_offset_stats(frames.corner, frames.meas, bins.range),
        **_clutter_stats(frames.clutter_counts, frames.clutter_xy),
        "n_range": np.bincount(bins.range[bins.range >= 0], minlength=len(DET_RANGE_EDGES) - 1).astype(float),
        "n_azimuth": np.bincount(bins.azimuth[bins.azimuth >= 0], minlength=len(DET_AZIMUTH_EDGES) - 1).astype(float),
        "n_occlusion": np.bincount(bins.occlusion[bins.occlusion >= 0], minlength=len(OCCLUSION_EDGES) - 1).astype(
            float
        ),
        "n_cells": np.bincount(bins.cell[bins.cell >= 0], minlength=_N_CELLS).astype(float),
        "n_occlusion_range": np.bincount(occ_range[occ_range >= 0], minlength=_N_OCC_RANGE).astype(float),
        "n_offset": np.bincount(bins.range[det & (bins.range >= 0)], minlength=len(DET_RANGE_EDGES) - 1).astype(float),
    }


@dataclass(frozen=True)
class _Sim:
    """Replicated real rows and their fixed draws (common random numbers)."""

    boxes: NDArray[np.float64]
    occluded: NDArray[np.float64]
    corner: NDArray[np.float64]
    bins: _Bins
    draws: SnapshotDraws


def _sim_setup(frames: RealFrames, replicates: int, rng: np.random.Generator) -> _Sim:
    rep = np.tile(np.arange(frames.boxes.shape[0]), replicates)
    b = _bins(frames)
    bins = _Bins(*(getattr(b, f)[rep] for f in ("range", "azimuth", "occlusion", "cell")))
    return _Sim(frames.boxes[rep], frames.occluded[rep], frames.corner[rep], bins, SnapshotDraws.draw(rep.size, rng))


def rig_statistics(
    config: RigConfig, frames: RealFrames, replicates: int = 4, seed: int = 0, expected: bool = False
) -> dict[str, NDArray[np.float64]]:
    """The calibration statistics of the rig simulated at the real frames' boxes (``replicates`` times).

    Args:
        config: rig parameters.
        frames: the real frames (only their boxes are used).
        replicates: independent simulations of every frame.
        seed: seed of the draws.
        expected: detection rates from the rig's detection probability (the exact expectation given
            the draws) instead of sampled detections.
    """
    rng = np.random.default_rng([seed, 11])
    sim = _sim_setup(frames, replicates, rng)
    rig = RadarRig(config)
    meas, p = rig.snapshot(sim.boxes, sim.occluded, sim.draws)
    det = p if expected else np.isfinite(meas[:, 0]).astype(np.float64)
    n_cycles = replicates * frames.n_frames
    counts, xys = [], []
    for _ in range(n_cycles):  # one iteration per simulated frame (clutter only)
        r, az = rig.sample_clutter_polar(rng)
        counts.append(r.size)
        xys.append(np.stack([r * np.cos(az), r * np.sin(az)], axis=1))
    xy = np.concatenate(xys) if xys else np.zeros((0, 2))
    return {
        **_detection_stats(det, sim.bins),
        **_offset_stats(sim.corner, meas, sim.bins.range),
        **_clutter_stats(np.asarray(counts, dtype=np.float64), xy),
    }


DETECTION_TERMS = (
    ("det_range", "n_range"),
    ("det_azimuth", "n_azimuth"),
    ("det_occlusion", "n_occlusion"),
    ("det_cells", "n_cells"),
    ("det_occlusion_range", "n_occlusion_range"),
)
"""The discrepancy's detection terms: (rate statistic per bin, the real row count per bin that weighs it)."""


def _bin_weights(real: dict[str, NDArray], nkey: str) -> NDArray[np.float64]:
    """Each bin's share of the real rows counted by ``nkey``: the weight of its squared rate gap."""
    return np.asarray(real[nkey] / max(real[nkey].sum(), 1.0), dtype=np.float64)


def detection_discrepancy(sim: dict[str, NDArray], real: dict[str, NDArray]) -> dict[str, float]:
    """The discrepancy's detection terms (:data:`DETECTION_TERMS`): row-weighted squared rate gaps per bin."""
    return {
        key: float(np.sum(_bin_weights(real, nkey) * np.nan_to_num(sim[key] - real[key]) ** 2))
        for key, nkey in DETECTION_TERMS
    }


def discrepancy(sim: dict[str, NDArray], real: dict[str, NDArray]) -> dict[str, float]:
    """The stated discrepancy, per term and ``total`` (see the module docstring)."""
    out = detection_discrepancy(sim, real)
    out["offset"] = _offset_term(sim["offset_z"], sim["offset_bin"], real["offset_z"], real)
    out["offset_signed"] = _offset_term(sim["offset_signed_z"], sim["offset_bin"], real["offset_signed_z"], real)
    m, s = real["clutter_count"]
    ms, ss = sim["clutter_count"]
    out["clutter_count"] = float(((ms - m) / max(m, 1e-9)) ** 2 + ((ss - s) / max(s, 1e-9)) ** 2)
    out["clutter_range"] = float(np.sum((sim["clutter_range"] - real["clutter_range"]) ** 2))
    out["clutter_azimuth"] = float(np.sum((sim["clutter_azimuth"] - real["clutter_azimuth"]) ** 2))
    out["total"] = float(sum(out.values()))
    return out
