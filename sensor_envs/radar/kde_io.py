"""Files of the KDE radar: the current format's header and arrays, the value checks, the format upgrades.

:class:`~sensor_envs.sensor_model.SensorModel` reads any supported format through :data:`UPGRADES` (one step
per version) and then :func:`from_file`; :func:`to_file` writes the current format only.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.modelio import (
    ModelFileError,
    check_finite,
    check_increasing,
    check_positive,
    check_range,
    check_shape,
    optional_positive,
)
from sensor_envs.radar.alignment import MAX_AZIMUTH_BIAS
from sensor_envs.radar.kde_params import (
    AZIMUTH_CANDIDATES,
    MAX_CLUTTER_POSITIONS,
    MAX_POSITION,
)
from sensor_envs.radar.kde_trees import build_trees
from sensor_envs.sensor_model import Arrays, Header, Upgrade, set_param_defaults

if TYPE_CHECKING:
    from sensor_envs.radar.kde import KDERadarModel

__all__ = ["to_file", "from_file", "UPGRADES", "ARRAY_SCHEMA"]


def to_file(m: KDERadarModel) -> tuple[Header, Arrays]:
    """Header and arrays of the current format (:class:`~sensor_envs.sensor_model.SensorModel`)."""
    params = m._saved_params(m, skip=("cv_candidates",))  # the candidates are stored as an array
    params["rel_variance"] = [float(v) for v in m.rel_variance]
    params["relevance_candidates"] = [float(v) for v in m.relevance_candidates]
    params["extra_state"] = [str(v) for v in m.extra_state_]
    params["extra_variance"] = None if m.extra_variance is None else [float(v) for v in m.extra_variance]
    params["extra_candidates"] = [float(v) for v in m.extra_candidates]
    params["relevance_candidates_azimuth"] = [float(v) for v in m.relevance_candidates_azimuth]
    params["relevance_candidates_prev"] = [float(v) for v in m.relevance_candidates_prev]
    header = {
        "params": params,
        "cycle_time": m.cycle_time_,
        "rel_variance_fitted": list(m.rel_variance_),
        "relevance_scores": [float(v) for v in m.relevance_scores_],
        "state_variables": list(m.state_variables),
        "extra_variance_fitted": [float(v) for v in m.extra_variance_],
        "extra_fill": [float(v) for v in m.extra_fill_],
        "new_track_flags": m.new_track_ is not None,
        "azimuth_bias_fitted": float(m.azimuth_bias_),
    }
    arrays = {
        "states": m.states_,
        "z": m.z_,
        "log_row": m.log_row_,
        "grid_x": m.grid_x_,
        "grid_y": m.grid_y_,
        "log_h": m.log_h_,
        "cv_counts": m.cv_counts_,
        "cv_candidates": m.cand_,
        "clutter_counts": m.clutter_counts_,
        "clutter_xy": m.clutter_xy_,
        "extra": m.extra_,
    }
    if m.new_track_ is not None:
        arrays["new_track"] = m.new_track_.astype(np.uint8)
    return header, arrays


def from_file(model: KDERadarModel, path: Path, header: Header, arrays: Arrays) -> KDERadarModel:
    """Fill ``model`` (built from the file's checked ``params``) with a current-format file's arrays; trees rebuilt."""
    a = arrays
    _check_arrays(path, a)
    model.states_, model.z_, model.log_row_ = a["states"], a["z"], a["log_row"].astype(np.int64)
    model.grid_x_, model.grid_y_, model.log_h_ = a["grid_x"], a["grid_y"], a["log_h"]
    model.cv_counts_, model.cand_ = a["cv_counts"].astype(np.int64), a["cv_candidates"]
    model.cv_candidates = tuple(float(c) for c in model.cand_)
    model.clutter_counts_, model.clutter_xy_ = a["clutter_counts"].astype(np.int64), a["clutter_xy"]
    rv = header.get("rel_variance_fitted", model.rel_variance)
    check_shape(path, "rel_variance_fitted", rv, (4,))
    model.rel_variance_ = tuple(float(v) for v in check_positive(path, "rel_variance_fitted", rv, MAX_POSITION**2))
    model.relevance_scores_ = np.asarray(header.get("relevance_scores", []), dtype=np.float64)
    model.scale_ = np.sqrt(np.asarray(model.rel_variance_, dtype=np.float64))
    model.cycle_time_ = optional_positive(path, "cycle_time", header.get("cycle_time"))
    model.azimuth_bias_ = _load_azimuth_bias(header, path, model.azimuth_bias)
    _load_extra(model, header, a, path)
    model.new_track_ = _load_new_track(header, a, path, model.states_)
    build_trees(model)
    return model


# ------------------------------------------------------------------------------- format upgrades
def _upgrade_1(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 1 matched misses against the log's overall miss rate (``prior_rate="global"``)."""
    set_param_defaults(header, prior_rate="global")


def _upgrade_2(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 2 has no extra state."""
    set_param_defaults(header, extra_state=[], extra_variance=None, extra_candidates=[0.25, 0.5, 1.0, 2.0])
    n = arrays["states"].shape[0]
    if "extra" not in arrays:
        arrays["extra"] = np.zeros((n, 0))
    header.setdefault("extra_variance_fitted", [])
    header.setdefault("extra_fill", [])


def _upgrade_3(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 3 has no per-tuple new-track flags (one combined start tree)."""
    if "new_track" in arrays:
        raise ModelFileError(f"{path}: field 'new_track' is present but 'new_track_flags' is not true")
    header["new_track_flags"] = False


def _upgrade_4(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 4 has cartesian corner features."""
    set_param_defaults(header, state_transform="cartesian", relevance_candidates_azimuth=list(AZIMUTH_CANDIDATES))


def _upgrade_5(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 5 stores sensor-frame outputs."""
    set_param_defaults(header, output_frame="cartesian")


def _upgrade_6(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 6 has no mounting yaw error and one bandwidth factor."""
    set_param_defaults(header, azimuth_bias=0.0, start_bandwidth_scale=None)
    header["azimuth_bias_fitted"] = 0.0


def _upgrade_7(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 7 has no tail mixture."""
    set_param_defaults(header, tail_weight=0.0, tail_scale=4.0)


def _check_arrays(path: str | os.PathLike[str], a: dict[str, NDArray[Any]]) -> None:
    """Sane VALUES and consistent lengths of a KDE model file's arrays (not only their format).

    Raises:
        ModelFileError: naming the file and the field.
    """
    n = a["states"].shape[0]
    check_shape(path, "states", a["states"], (n, 4))
    check_shape(path, "z", a["z"], (n, 2))
    check_shape(path, "log_row", a["log_row"], (n,))
    check_range(path, "states", a["states"][:, :2], -MAX_POSITION, MAX_POSITION)  # corners: always present
    prev, z = a["states"][:, 2:], a["z"]
    for field, v in (("states", prev), ("z", z)):  # NaN rows: no previous output / a miss, both coordinates
        gone = np.isnan(v)
        if (gone[:, 0] != gone[:, 1]).any():
            raise ModelFileError(f"{path}: field {field!r} has rows with one NaN coordinate")
        check_range(path, field, v[~gone[:, 0]], -MAX_POSITION, MAX_POSITION)
    if (~np.isnan(z[:, 0])).sum() < 2:
        raise ModelFileError(f"{path}: field 'z' holds fewer than 2 detected tuples")
    check_range(path, "log_row", a["log_row"], 0, None)
    gx = check_increasing(path, "grid_x", a["grid_x"], min_size=1, regular=True)
    gy = check_increasing(path, "grid_y", a["grid_y"], min_size=1, regular=True)
    check_range(path, "grid_x", gx, -MAX_POSITION, MAX_POSITION)
    check_range(path, "grid_y", gy, -MAX_POSITION, MAX_POSITION)
    check_shape(path, "log_h", a["log_h"], (gx.size, gy.size, 2))
    check_range(path, "log_h", a["log_h"], np.log(1e-6), np.log(MAX_POSITION))  # bandwidths 1 um .. 1 km
    check_shape(path, "cv_counts", a["cv_counts"], (gx.size, gy.size))
    check_range(path, "cv_counts", a["cv_counts"], 0, None)
    if a["cv_candidates"].size == 0:
        raise ModelFileError(f"{path}: field 'cv_candidates' is empty")
    check_positive(path, "cv_candidates", a["cv_candidates"], MAX_POSITION)
    check_range(path, "clutter_counts", a["clutter_counts"], 0, 1e6)
    check_shape(path, "clutter_xy", a["clutter_xy"], (a["clutter_xy"].shape[0], 2))
    check_range(path, "clutter_xy", a["clutter_xy"], -MAX_POSITION, MAX_POSITION)
    _check_clutter_rows(path, a["clutter_counts"], a["clutter_xy"])
    check_finite(path, "cv_candidates", a["cv_candidates"])


def _check_clutter_rows(path: Any, counts: NDArray[Any], xy: NDArray[Any]) -> None:
    """``clutter_xy`` holds the positions ``clutter_counts`` counts: all of them, or a subsample of the cap.

    A fit stores every clutter position of the log, or :data:`MAX_CLUTTER_POSITIONS` of them drawn
    uniformly when the log has more (files from before the cap hold them all). Positions without counts,
    or counts without positions (the sampler would then draw no clutter at all), are a damaged file.

    Raises:
        ModelFileError: naming the file and both fields.
    """
    total, rows = int(np.sum(counts, dtype=np.int64)), int(xy.shape[0])
    if rows != total and not (total > MAX_CLUTTER_POSITIONS and rows == MAX_CLUTTER_POSITIONS):
        raise ModelFileError(
            f"{path}: field 'clutter_xy' has {rows} positions, but 'clutter_counts' counts {total} clutter "
            f"detections (expected all of them, or {MAX_CLUTTER_POSITIONS} when there are more)"
        )


def _load_azimuth_bias(header: dict[str, Any], path: Any, given: float | str) -> float:
    """The fitted mounting yaw error [rad] of a current-format file, checked finite and within bounds.

    Raises:
        ModelFileError: naming the file and the field ``azimuth_bias_fitted`` (missing from a format-7 file,
            not a finite number within ``+-MAX_AZIMUTH_BIAS``, or unlike a given ``params.azimuth_bias``).
    """
    if "azimuth_bias_fitted" not in header:
        raise ModelFileError(f"{path}: field 'azimuth_bias_fitted' is missing")
    raw = header["azimuth_bias_fitted"]
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise ModelFileError(f"{path}: field 'azimuth_bias_fitted' must be an angle [rad], got {raw!r}")
    b = float(check_range(path, "azimuth_bias_fitted", raw, -MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS))
    if given != "fit" and b != float(given):
        raise ModelFileError(f"{path}: field 'azimuth_bias_fitted' ({b}) differs from 'params.azimuth_bias' ({given})")
    return b


def _load_new_track(
    header: dict[str, Any], a: dict[str, NDArray[Any]], path: Any, states: NDArray
) -> NDArray[np.bool_] | None:
    """The per-tuple new-track flags of a current-format file (``None``: saved without them).

    Raises:
        ModelFileError: when the flags are announced but missing, not ``n`` values in {0, 1}, or flag a
            tuple that has a previous output (a new track has none).
    """
    announced = header.get("new_track_flags", False)
    if not isinstance(announced, bool):
        raise ModelFileError(f"{path}: field 'new_track_flags' must be true or false")
    if not announced:
        if "new_track" in a:
            raise ModelFileError(f"{path}: field 'new_track' is present but 'new_track_flags' is not true")
        return None
    if "new_track" not in a:
        raise ModelFileError(f"{path}: field 'new_track' is missing")
    f = a["new_track"]
    if f.dtype.kind not in "ub" or f.shape != (states.shape[0],):
        raise ModelFileError(
            f"{path}: field 'new_track' must be {states.shape[0]} unsigned flags, got {f.dtype} {f.shape}"
        )
    if not np.isin(f, (0, 1)).all():
        raise ModelFileError(f"{path}: field 'new_track' holds values other than 0 and 1")
    flags = f.astype(bool)
    if (flags & ~np.isnan(states[:, 2])).any():
        raise ModelFileError(f"{path}: field 'new_track' flags a tuple that has a previous output")
    return flags


def _load_extra(model: KDERadarModel, header: dict[str, Any], a: dict[str, NDArray], path: Any) -> None:
    """Restore and check the extra state of a loaded model."""
    names = tuple(str(v) for v in header.get("params", {}).get("extra_state", ()) or ())
    n = model.states_.shape[0]
    if "extra" not in a:
        raise ModelFileError(f"{path}: field 'extra' is missing")
    extra = np.asarray(a["extra"])
    if extra.dtype.kind != "f" or extra.ndim != 2:
        raise ModelFileError(f"{path}: field 'extra' must be a 2-D float array")
    var = np.asarray(header.get("extra_variance_fitted", []), dtype=np.float64)
    fill = np.asarray(header.get("extra_fill", []), dtype=np.float64)
    if extra.shape != (n, len(names)) or var.shape != (len(names),) or fill.shape != (len(names),):
        raise ModelFileError(f"{path}: field 'extra' does not match the {len(names)} names of 'extra_state'")
    if not (np.isfinite(extra).all() and np.isfinite(var).all() and (var > 0).all() and np.isfinite(fill).all()):
        raise ModelFileError(f"{path}: field 'extra'/'extra_variance_fitted' must be finite (variances > 0)")
    model.extra_state_, model.extra_ = names, extra
    model.extra_variance_, model.extra_fill_ = tuple(float(v) for v in var), fill
    model.extra_scale_ = np.sqrt(var)


ARRAY_SCHEMA: dict[str, tuple[str, int | None, bool]] = {
    "states": ("f", 2, False),
    "z": ("f", 2, False),
    "log_row": ("iu", 1, True),
    "grid_x": ("f", 1, True),
    "grid_y": ("f", 1, True),
    "log_h": ("f", 3, True),
    "cv_counts": ("iu", 2, True),
    "cv_candidates": ("f", 1, True),
    "clutter_counts": ("iu", 1, True),
    "clutter_xy": ("f", 2, True),
}
"""Arrays every supported format holds: ``name -> (dtype kinds, ndim, finite)`` (``SensorModel._SCHEMA``)."""

UPGRADES: dict[int, Upgrade] = {
    1: _upgrade_1,
    2: _upgrade_2,
    3: _upgrade_3,
    4: _upgrade_4,
    5: _upgrade_5,
    6: _upgrade_6,
    7: _upgrade_7,
}
"""``{v: step}``: ``step(path, header, arrays)`` turns a format-``v`` file into format ``v + 1`` in place."""
