"""Gaussian radar baseline: range-binned Gaussian output, detection probability and Poisson clutter.

Fitted on the same log as the KDE model. Per range bin of the closest corner (``range_edges`` [m]):
the mean and covariance of ``z = meas - corner`` [m] over detected rows and the detection
probability; bins with fewer than ``min_count`` detections use the pooled values. Outputs are
independent between cycles (no ``z_{t-1}``). Clutter: Poisson count with the log's mean rate per
cycle, positions from a 2-D Gaussian fitted to the clutter rows (sensor frame, metres).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_is_fitted

from sensor_envs.modelio import (
    Constraint,
    Interval,
    ModelFileError,
    Numbers,
    check_increasing,
    check_positive,
    check_probability,
    check_range,
    check_shape,
    load_model_file,
    optional_positive,
    params_from_header,
    save_model_file,
    validate_params,
)
from sensor_envs.radar.log import RadarLog, clutter_counts, target_tuples

__all__ = ["GaussianRadar"]

KIND = "radar_gaussian"
FORMAT_VERSION = 1
MAX_POSITION = 1e3
"""Largest range edge, mean offset, clutter position or standard deviation [m] a model file may hold."""
_NOT_FITTED = "This %(name)s is not fitted yet; call fit(log) or GaussianRadar.load(path) first"


class GaussianRadar(BaseEstimator):
    """Range-binned Gaussian radar model (implements ``RadarSensor``; a scikit-learn estimator).

    Args:
        range_edges: bin edges [m] of the corner range; outside values use the first/last bin.
        min_count: minimum detections per bin before falling back to the pooled estimate.
        cov_floor: variance [m^2] added to every covariance diagonal (keeps it positive definite).
    """

    _hyperparameter_constraints: ClassVar[dict[str, list[Constraint]]] = {
        "range_edges": [Numbers(Interval(0, MAX_POSITION), min_length=2, increasing=True)],
        "min_count": [Interval(1, None, integer=True)],
        "cov_floor": [Interval(0, MAX_POSITION**2)],
    }
    """One declarative check of every hyperparameter, used by :meth:`fit` and :meth:`load`."""

    def __init__(
        self,
        *,
        range_edges: tuple[float, ...] = (0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 80.0, 100.0, 150.0),
        min_count: int = 20,
        cov_floor: float = 1e-4,
    ) -> None:
        self.range_edges = range_edges
        self.min_count = min_count
        self.cov_floor = cov_floor

    def fit(self, log: RadarLog, cycle_time: float | None = None) -> GaussianRadar:
        """Fit means, covariances, detection probabilities and clutter on ``log``; returns self."""
        validate_params(self.get_params(), self._hyperparameter_constraints)
        cycle = optional_positive(None, "cycle_time", cycle_time)
        edges = np.asarray(self.range_edges, dtype=np.float64)
        tt = target_tuples(log)
        det = ~np.isnan(tt.z[:, 0])
        if det.sum() < 3:
            raise ValueError(f"{log.source}: fewer than 3 detected target rows; cannot fit a Gaussian")
        b = self._bin(tt.corner, edges)
        nb = edges.size - 1
        pooled_mu, pooled_cov = tt.z[det].mean(axis=0), np.cov(tt.z[det].T) + self.cov_floor * np.eye(2)
        self.mean_, self.cov_ = np.tile(pooled_mu, (nb, 1)), np.tile(pooled_cov, (nb, 1, 1))
        self.p_detect_ = np.full(nb, det.mean())
        for k in range(nb):  # one iteration per range bin
            sel = det & (b == k)
            if sel.sum() >= self.min_count:
                self.mean_[k] = tt.z[sel].mean(axis=0)
                self.cov_[k] = np.cov(tt.z[sel].T) + self.cov_floor * np.eye(2)
            if (b == k).sum() >= self.min_count:
                self.p_detect_[k] = det[b == k].mean()
        counts, xy = clutter_counts(log)
        self.clutter_rate_ = float(counts.mean())
        if xy.shape[0] >= 3:
            self.clutter_mean_, self.clutter_cov_ = xy.mean(axis=0), np.cov(xy.T) + self.cov_floor * np.eye(2)
        else:
            self.clutter_mean_, self.clutter_cov_ = np.zeros(2), np.eye(2)
        self.edges_ = edges
        self.cycle_time_ = cycle
        return self

    @staticmethod
    def _bin(corners: NDArray, edges: NDArray) -> NDArray[np.int64]:
        r = np.hypot(corners[:, 0], corners[:, 1])
        return np.clip(np.searchsorted(edges, r, side="right") - 1, 0, edges.size - 2)

    def _check_fitted(self) -> None:
        """Raise sklearn's ``NotFittedError`` unless the model is fitted or loaded."""
        check_is_fitted(self, "mean_", msg=_NOT_FITTED)

    def detection_probability(self, corners: NDArray) -> NDArray[np.float64]:
        """Detection probability ``(n,)`` at corners ``(n, 2)`` [m]."""
        self._check_fitted()
        return self.p_detect_[self._bin(np.atleast_2d(corners), self.edges_)]

    def sample_cycle(
        self, corners: NDArray, prev_z: NDArray | None, rng: np.random.Generator
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """``RadarSensor.sample_cycle``; ``prev_z`` is ignored; ``source`` is always -1."""
        self._check_fitted()
        corners = np.atleast_2d(np.asarray(corners, dtype=np.float64))
        n = corners.shape[0]
        b = self._bin(corners, self.edges_)
        chol = np.linalg.cholesky(self.cov_[b])
        z = self.mean_[b] + np.einsum("nij,nj->ni", chol, rng.standard_normal((n, 2)))
        z[rng.random(n) >= self.p_detect_[b]] = np.nan
        return z, np.full(n, -1, dtype=np.int64)

    def sample(self, state: NDArray, rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Sample for ``(n, 2)`` or ``(n, 4)`` states (only the corner is used)."""
        self._check_fitted()
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        return self.sample_cycle(st[:, :2], None, rng)

    def sample_clutter(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Poisson number of clutter points from the fitted 2-D Gaussian, ``(m, 2)`` [m]."""
        self._check_fitted()
        m = int(rng.poisson(self.clutter_rate_))
        return rng.multivariate_normal(self.clutter_mean_, self.clutter_cov_, size=m).reshape(m, 2)

    def log_prob(self, z: NDArray, state: NDArray) -> NDArray[np.float64]:
        """``log p_d + log N(z; mean, cov)`` for detections, ``log(1 - p_d)`` for ``NaN`` rows, ``(n,)``."""
        self._check_fitted()
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        b = self._bin(st[:, :2], self.edges_)
        d = z - self.mean_[b]
        inv = np.linalg.inv(self.cov_[b])
        maha = np.einsum("ni,nij,nj->n", d, inv, d)
        logn = -0.5 * maha - np.log(2 * np.pi) - 0.5 * np.log(np.linalg.det(self.cov_[b]))
        pd = self.p_detect_[b]
        with np.errstate(divide="ignore"):
            return np.where(np.isnan(z[:, 0]), np.log(1 - pd), np.log(pd) + np.nan_to_num(logn, nan=0.0))

    def save(self, path: str | os.PathLike[str], card: dict[str, Any] | None = None) -> Path:
        """Save to a pickle-free model file."""
        self._check_fitted()
        header = {
            "params": {
                "range_edges": [float(e) for e in self.range_edges],
                "min_count": self.min_count,
                "cov_floor": self.cov_floor,
            },
            "cycle_time": self.cycle_time_,
            "card": card or {},
        }
        arrays = {
            "edges": self.edges_,
            "mean": self.mean_,
            "cov": self.cov_,
            "p_detect": self.p_detect_,
            "clutter_rate": np.array([self.clutter_rate_]),
            "clutter_mean": self.clutter_mean_,
            "clutter_cov": self.clutter_cov_,
        }
        return save_model_file(path, KIND, FORMAT_VERSION, header, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> GaussianRadar:
        """Load a model file written by :meth:`save` (no pickle)."""
        schema = {
            "edges": ("f", 1, True),
            "mean": ("f", 2, True),
            "cov": ("f", 3, True),
            "p_detect": ("f", 1, True),
            "clutter_rate": ("f", 1, True),
            "clutter_mean": ("f", 1, True),
            "clutter_cov": ("f", 2, True),
        }
        header, a = load_model_file(path, KIND, (FORMAT_VERSION,), schema)
        m = cls(**params_from_header(path, header, cls._hyperparameter_constraints))
        _check_arrays(path, a)
        m.edges_, m.mean_, m.cov_, m.p_detect_ = a["edges"], a["mean"], a["cov"], a["p_detect"]
        m.clutter_rate_ = float(a["clutter_rate"][0])
        m.clutter_mean_, m.clutter_cov_ = a["clutter_mean"], a["clutter_cov"]
        m.cycle_time_ = optional_positive(path, "cycle_time", header.get("cycle_time"))
        return m


def _check_arrays(path: str | os.PathLike[str], a: dict[str, NDArray[Any]]) -> None:
    """Sane VALUES and consistent lengths of a Gaussian radar file's arrays (not only their format).

    Raises:
        ModelFileError: naming the file and the field: e.g. a detection probability outside ``[0, 1]``, a
            covariance that is not symmetric positive definite, edges that are not increasing.
    """
    edges = check_increasing(path, "edges", a["edges"])
    check_range(path, "edges", edges, 0.0, MAX_POSITION)
    nb = edges.size - 1
    check_shape(path, "mean", a["mean"], (nb, 2))
    check_shape(path, "cov", a["cov"], (nb, 2, 2))
    check_shape(path, "p_detect", a["p_detect"], (nb,))
    check_range(path, "mean", a["mean"], -MAX_POSITION, MAX_POSITION)
    check_probability(path, "p_detect", a["p_detect"])
    check_shape(path, "clutter_rate", a["clutter_rate"], (1,))
    check_range(path, "clutter_rate", a["clutter_rate"], 0.0, 1e6)
    check_shape(path, "clutter_mean", a["clutter_mean"], (2,))
    check_range(path, "clutter_mean", a["clutter_mean"], -MAX_POSITION, MAX_POSITION)
    check_shape(path, "clutter_cov", a["clutter_cov"], (2, 2))
    for field in ("cov", "clutter_cov"):
        cov = check_range(path, field, a[field], -(MAX_POSITION**2), MAX_POSITION**2)
        if not np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=1e-6, atol=1e-12):
            raise ModelFileError(f"{path}: field {field!r} is not symmetric")
        check_positive(path, f"{field} (eigenvalues)", np.linalg.eigvalsh(cov))
