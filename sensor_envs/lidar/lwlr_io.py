"""Files of :class:`~sensor_envs.lidar.lwlr.LidarLWLR`: the current format, its value checks, the format upgrades.

:class:`~sensor_envs.sensor_model.SensorModel` reads any supported format through :data:`UPGRADES` (one step
per version) and then :func:`from_file`; :func:`to_file` writes the current format only.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.lidar.extra_state import MAX_COEF, PARTS, check_extra_state, part_columns
from sensor_envs.modelio import (
    Constraint,
    InstanceOf,
    Interval,
    ModelFileError,
    Names,
    Numbers,
    check_finite,
    check_increasing,
    check_model_arrays,
    check_positive,
    check_probability,
    check_range,
    check_shape,
)
from sensor_envs.sensor_model import Arrays, Header, Upgrade, set_param_defaults

if TYPE_CHECKING:
    from sensor_envs.lidar.lwlr import LidarLWLR

__all__ = ["to_file", "from_file", "UPGRADES", "PARAMS", "TABLES", "MAX_SIGMA", "HEADER_SCHEMA"]

PARAMS = {"seed": ("p_null", "bias", "sigma"), "extended": ("p_null", "p_spur", "bias", "log_sigma")}
"""The regressed parameters of each variant."""
TABLES = {"seed": PARAMS["seed"], "extended": PARAMS["extended"] + ("tau2",)}
"""The tables a model file of each variant holds, in order."""
UNCLAMPED = 1e6
"""Clamp bound [standard deviations] of an extra term in a file older than format 7 (no clamp in effect)."""
MAX_SIGMA = 1e3
"""Largest standard deviation [m] (and bias magnitude) a model file may give: beyond it the file is corrupt."""
_RHO: list[Constraint] = [Interval(0.0, 0.999)]
HEADER_SCHEMA: dict[str, list[Constraint]] = {
    "h": [InstanceOf(dict)],  # parameter name -> 4 kernel widths, checked against param_names by _check_values
    "param_names": [Names(max_length=8)],
    "spur_mu": [Interval(0.0, MAX_SIGMA)],  # mean range of spurious returns [m]
    "spur_sigma": [Interval(0.0, MAX_SIGMA, open_low=True)],
    "p_out": [Interval(0.0, 1.0)],
    "null_rho": _RHO,
    "spur_rho": _RHO,
    "bias_shrinkage": [Interval(0.0, 1.0)],
    "pose_sd": [None, Numbers(Interval(0.0, np.pi), length=3)],
}
"""Declared fitted fields of a lidar model file's header, any format (their consistency with the tables: the
loader); checked by :meth:`~sensor_envs.sensor_model.SensorModel.read_current` before the upgrades."""


def to_file(m: LidarLWLR) -> tuple[Header, Arrays]:
    """Header and arrays of the current format (:class:`~sensor_envs.sensor_model.SensorModel`)."""
    header: Header = {
        "params": m._saved_params(m),
        "h": m.h_,
        "param_names": m.param_names_,
        "spur_mu": m.spur_mu_,
        "spur_sigma": m.spur_sigma_,
        "p_out": m.p_out_,
        "null_rho": m.null_rho_,
        "spur_rho": m.spur_rho_,
        "bias_shrinkage": m.bias_shrinkage_,
        "pose_sd": None if (sd := getattr(m, "pose_sd_", None)) is None else [float(v) for v in sd],
        "card": {"training": m.training_, "cv_scores": m.cv_scores_},
    }
    arrays: Arrays = {
        "tables": m.tables_.astype(np.float32),
        "bearings": m.bearings_,
        "range_grid": m.range_grid_,
        "alpha_grid": m.alpha_grid_,
        "extra_mean": np.asarray(m.extra_mean_, dtype=np.float64),
        "extra_scale": np.asarray(m.extra_scale_, dtype=np.float64),
        "extra_coef": np.asarray(m.extra_coef_, dtype=np.float64),
        "extra_low": np.asarray(m.extra_low_, dtype=np.float64),
        "extra_high": np.asarray(m.extra_high_, dtype=np.float64),
    }
    return header, arrays


def from_file(cls: type[LidarLWLR], path: Path, header: Header, arrays: Arrays) -> LidarLWLR:
    """The model of a current-format file (values checked)."""
    arr = arrays
    try:
        params = cls._params_from(path, header)
        try:
            params["extra_state"] = check_extra_state(params["extra_state"])
        except ValueError as exc:
            raise ModelFileError(f"{path}: field 'params.extra_state' is invalid: {exc}") from None
        model = cls(**params)
        model.h_, model.param_names_ = dict(header["h"]), list(header["param_names"])
        model.spur_mu_, model.spur_sigma_ = float(header["spur_mu"]), float(header["spur_sigma"])
        model.p_out_ = float(header["p_out"])
        model.null_rho_ = float(header.get("null_rho", 0.0))
        model.spur_rho_ = float(header["spur_rho"])
        model.bias_shrinkage_ = float(check_range(path, "bias_shrinkage", header["bias_shrinkage"], 0.0, 1.0))
        model.pose_sd_ = _load_pose_sd(path, header.get("pose_sd"))
        card = dict(header["card"])
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        if isinstance(exc, ModelFileError):
            raise
        raise ModelFileError(f"{path}: field '__header__' lacks or misstates {exc}") from None
    if model.param_names_ != list(TABLES[model.variant]):
        raise ModelFileError(f"{path}: field 'param_names' is {model.param_names_} for variant {model.variant!r}")
    t = arr["tables"]
    want = (len(model.param_names_), arr["bearings"].size, arr["range_grid"].size, arr["alpha_grid"].size)
    if t.shape != want:
        raise ModelFileError(f"{path}: field 'tables' has shape {t.shape}, expected {want}")
    check_model_arrays(
        path,
        arr,
        {
            "extra_mean": ("f", 1, True),
            "extra_scale": ("f", 1, True),
            "extra_coef": ("f", 2, True),
            "extra_low": ("f", 1, True),
            "extra_high": ("f", 1, True),
        },
    )
    _check_extra_values(path, model, arr)
    _check_values(path, model, arr)
    model.tables_, model.bearings_ = t.astype(np.float64), arr["bearings"]
    model.range_grid_, model.alpha_grid_ = arr["range_grid"], arr["alpha_grid"]
    model.training_, model.cv_scores_ = card.pop("training", {}), card.pop("cv_scores", {})
    model.card_ = card
    return model


def _upgrade_1(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 1 has independent nulls."""
    header.setdefault("null_rho", 0.0)


def _upgrade_2(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 2 has no extra state."""
    set_param_defaults(header, extra_state=[])
    if "extra_coef" not in arrays:
        arrays.update(extra_mean=np.zeros(0), extra_scale=np.ones(0), extra_coef=np.zeros((3, 1)))


def _upgrade_3(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 3 uses the learned bias as is (no shrinkage) and no pose correction."""
    set_param_defaults(header, bias_shrinkage=0.0, pose_correction=False)
    header["bias_shrinkage"] = 0.0


def _upgrade_4(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 4 has independent spurious returns."""
    header["spur_rho"] = 0.0


def _upgrade_5(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 5 has the per-bearing bias and no rigid pose error in :meth:`LidarLWLR.sample`."""
    set_param_defaults(header, bias_model="per_bearing")
    header["pose_sd"] = None


def _upgrade_6(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 6 extrapolates the extra terms (no clamp: the widest finite range)."""
    d = int(np.asarray(arrays.get("extra_mean", np.zeros(0))).size)
    arrays.setdefault("extra_low", np.full(d, -UNCLAMPED))
    arrays.setdefault("extra_high", np.full(d, UNCLAMPED))


def _check_extra_values(path: str | os.PathLike[str], model: LidarLWLR, arr: dict[str, NDArray[Any]]) -> None:
    """Extra-state arrays: shapes matching ``extra_state``, finite, positive scales, bounded coefficients.

    Sets ``extra_state_``, ``extra_mean_``, ``extra_scale_``, ``extra_coef_``, ``extra_low_``, ``extra_high_``
    (none for format < 3).
    """
    d = len(model.extra_state)
    if "extra_coef" not in arr:
        if d:
            raise ModelFileError(f"{path}: field 'extra_coef' is missing for extra_state {list(model.extra_state)}")
        model.extra_state_, model.extra_mean_, model.extra_scale_ = (), np.zeros(0), np.ones(0)
        model.extra_coef_, model.extra_low_, model.extra_high_ = np.zeros((3, 1)), np.zeros(0), np.zeros(0)
        return
    check_shape(path, "extra_mean", arr["extra_mean"], (d,))
    check_shape(path, "extra_scale", arr["extra_scale"], (d,))
    check_shape(path, "extra_coef", arr["extra_coef"], (3, d + 1))
    check_finite(path, "extra_mean", arr["extra_mean"])
    check_positive(path, "extra_scale", arr["extra_scale"])
    check_range(path, "extra_coef", arr["extra_coef"], -MAX_COEF, MAX_COEF)
    for name, lo, hi in (("extra_low", -UNCLAMPED, 0.0), ("extra_high", 0.0, UNCLAMPED)):  # the fit's mean lies inside
        check_shape(path, name, arr[name], (d,))
        check_range(path, name, arr[name], lo, hi)
    for row, cols in enumerate(part_columns(tuple(model.extra_state))):  # a part's term acts on it alone
        off = np.setdiff1d(np.arange(d + 1), cols)
        if off.size and np.any(arr["extra_coef"][row, off] != 0):
            raise ModelFileError(f"{path}: field 'extra_coef': a term restricted to another part acts on {PARTS[row]}")
    model.extra_state_ = tuple(model.extra_state)
    model.extra_mean_, model.extra_scale_ = arr["extra_mean"].astype(np.float64), arr["extra_scale"].astype(np.float64)
    model.extra_coef_ = arr["extra_coef"].astype(np.float64)
    model.extra_low_, model.extra_high_ = arr["extra_low"].astype(np.float64), arr["extra_high"].astype(np.float64)


def _check_values(path: str | os.PathLike[str], model: LidarLWLR, arr: dict[str, NDArray[Any]]) -> None:
    """Sane VALUES of a model file's tables, grids and fitted scalars (not only their format).

    Raises:
        ModelFileError: naming the file and the field: a probability outside ``[0, 1]``, a width or sigma
            ``<= 0`` or above :data:`MAX_SIGMA` m, a grid that is not increasing and evenly spaced, ...
    """
    check_range(path, "bearings", arr["bearings"], -2 * np.pi, 2 * np.pi)  # any order: some scanners turn clockwise
    check_range(path, "range_grid", check_increasing(path, "range_grid", arr["range_grid"], regular=True), 0.0)
    ag = check_increasing(path, "alpha_grid", arr["alpha_grid"], regular=True)
    check_range(path, "alpha_grid", ag, 0.0, np.pi / 2 + 1e-9)
    for name, table in zip(model.param_names_, arr["tables"], strict=True):
        field = f"tables[{name}]"
        if name in ("p_null", "p_spur"):
            check_probability(path, field, table)
        elif name == "sigma":
            check_positive(path, field, table, high=MAX_SIGMA)
        elif name == "log_sigma":  # exp(50) m = 5e21 m scans: a corrupt file, not a model
            check_range(path, field, table, np.log(1e-6), np.log(MAX_SIGMA))
        elif name == "tau2":
            check_range(path, field, table, 0.0, MAX_SIGMA**2)
        else:  # bias [m]
            check_range(path, field, table, -MAX_SIGMA, MAX_SIGMA)
    check_range(path, "spur_mu", model.spur_mu_, -MAX_SIGMA, MAX_SIGMA)
    check_positive(path, "spur_sigma", model.spur_sigma_, high=MAX_SIGMA)
    check_probability(path, "p_out", model.p_out_)
    check_range(path, "null_rho", model.null_rho_, 0.0, 0.999)
    check_range(path, "spur_rho", model.spur_rho_, 0.0, 0.999)
    check_range(path, "bias_shrinkage", model.bias_shrinkage_, 0.0, 1.0)
    if model.bias_shrinkage != "cv" and model.bias_shrinkage_ != float(model.bias_shrinkage):
        raise ModelFileError(
            f"{path}: field 'bias_shrinkage' is {model.bias_shrinkage_}, but params.bias_shrinkage fixes it at "
            f"{model.bias_shrinkage}"
        )
    if not set(model.param_names_) <= set(model.h_):
        raise ModelFileError(
            f"{path}: field 'h' lacks kernel widths of {sorted(set(model.param_names_) - set(model.h_))}"
        )
    for name in model.param_names_:
        h = model.h_[name]
        check_shape(path, f"h[{name}]", h, (4,))
        check_positive(path, f"h[{name}]", h[:2], high=MAX_SIGMA)
        check_range(path, f"h[{name}]", h[2:], 0.0, None)


def _load_pose_sd(path: str | os.PathLike[str], value: Any) -> NDArray[np.float64] | None:
    """The header's ``pose_sd`` (3 standard deviations ``dx, dy`` [m] <= 1 m, ``dtheta`` [rad] <= pi, or absent)."""
    if value is None:
        return None
    try:
        sd = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelFileError(f"{path}: field 'pose_sd' is not numeric") from None
    check_shape(path, "pose_sd", sd, (3,))
    check_range(path, "pose_sd", sd[:2], 0.0, 1.0)
    check_range(path, "pose_sd", sd[2:], 0.0, np.pi)
    return sd


UPGRADES: dict[int, Upgrade] = {
    1: _upgrade_1,
    2: _upgrade_2,
    3: _upgrade_3,
    4: _upgrade_4,
    5: _upgrade_5,
    6: _upgrade_6,
}
"""``{v: step}``: ``step(path, header, arrays)`` turns a format-``v`` file into format ``v + 1`` in place."""
