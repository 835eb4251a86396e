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
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.modelio import load_model_file, save_model_file
from sensor_envs.radar.log import RadarLog, clutter_counts, target_tuples

__all__ = ["GaussianRadar"]

KIND = "radar_gaussian"
FORMAT_VERSION = 1


class GaussianRadar:
    """Range-binned Gaussian radar model (implements ``RadarSensor``).

    Args:
        range_edges: bin edges [m] of the corner range; outside values use the first/last bin.
        min_count: minimum detections per bin before falling back to the pooled estimate.
        cov_floor: variance [m^2] added to every covariance diagonal (keeps it positive definite).
    """

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
        edges = np.asarray(self.range_edges, dtype=np.float64)
        if edges.ndim != 1 or edges.size < 2 or not (np.diff(edges) > 0).all():
            raise ValueError(f"range_edges must be increasing with >= 2 values, got {self.range_edges!r}")
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
        self.cycle_time_ = float("nan") if cycle_time is None else float(cycle_time)
        return self

    @staticmethod
    def _bin(corners: NDArray, edges: NDArray) -> NDArray[np.int64]:
        r = np.hypot(corners[:, 0], corners[:, 1])
        return np.clip(np.searchsorted(edges, r, side="right") - 1, 0, edges.size - 2)

    def _check_fitted(self) -> None:
        if not hasattr(self, "mean_"):
            raise RuntimeError("this GaussianRadar is not fitted yet; call fit(log) or GaussianRadar.load(path)")

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
        p = dict(header["params"])
        p["range_edges"] = tuple(p["range_edges"])
        m = cls(**p)
        m.edges_, m.mean_, m.cov_, m.p_detect_ = a["edges"], a["mean"], a["cov"], a["p_detect"]
        nb = m.edges_.size - 1
        if m.mean_.shape != (nb, 2) or m.cov_.shape != (nb, 2, 2) or m.p_detect_.shape != (nb,):
            raise ValueError(f"{path}: fields 'mean'/'cov'/'p_detect' do not match field 'edges'")
        m.clutter_rate_ = float(a["clutter_rate"][0])
        m.clutter_mean_, m.clutter_cov_ = a["clutter_mean"], a["clutter_cov"]
        m.cycle_time_ = float(header.get("cycle_time", float("nan")))
        return m
