"""Gaussian radar baseline: range-binned Gaussian output, detection probability and Poisson clutter.

Fitted on the same log as the KDE model. Per range bin of the closest corner (``range_edges`` [m]):
the mean and covariance of ``z = meas - corner`` [m] over detected rows and the detection
probability; bins with fewer than ``min_count`` detections use the pooled values. Outputs are
independent between cycles (no ``z_{t-1}``), so the model has no start state: the ``new_track``
flags of the radar API (new track vs lost track, see :class:`sensor_envs.radar.kde.KDERadarModel`)
are accepted and ignored - a new and a lost target at the same corner are detected alike. Clutter:
Poisson count with the log's mean rate per cycle, positions from a 2-D Gaussian fitted to the
clutter rows (sensor frame, metres).

**Extra state** (``extra_state``, format 2): names of numeric log columns (as for the KDE model)
entering linearly: the mean is ``mean_bin + B^T (x - x_mean) / x_std`` (least squares, alternated
with the bin means) and the detection probability ``logit p = logit p_bin + c^T (x - x_mean) / x_std``
(ridge-regularised logistic regression, Newton steps). The bin covariances are those of the
residuals after the linear term. Missing values (NaN) count as the training mean.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.modelio import (
    CYCLE_TIME,
    Constraint,
    Interval,
    ModelFileError,
    Names,
    Numbers,
    check_increasing,
    check_positive,
    check_probability,
    check_range,
    check_shape,
    optional_positive,
)
from sensor_envs.radar.features import state_matrix
from sensor_envs.radar.log import (
    RadarLog,
    check_cycle_states,
    check_states,
    clutter_counts,
    fit_cycle_time,
    target_tuples,
)
from sensor_envs.sensor_model import Arrays, Header, SensorModel, set_param_defaults

__all__ = ["GaussianRadar", "baseline_file"]

KIND = "radar_gaussian"
FORMAT_VERSION = 2
"""1 = range bins only; 2 adds the extra state's linear terms (``extra_*`` arrays, ``state_variables``)."""
HEADER_SCHEMA: dict[str, list[Constraint]] = {"cycle_time": CYCLE_TIME, "state_variables": [Names()]}
"""Declared fitted fields of a Gaussian radar file's header."""
MAX_POSITION = 1e3
"""Largest range edge, mean offset, clutter position or standard deviation [m] a model file may hold."""
_EXTRA_ZERO = {"extra_mean": (0,), "extra_std": (0,), "extra_coef": (0, 2), "extra_logit": (0,)}


def _upgrade_1_to_2(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 1 has no extra state: no ``extra_state`` names and empty linear terms."""
    set_param_defaults(header, extra_state=[])
    for name, shape in _EXTRA_ZERO.items():
        arrays.setdefault(name, np.zeros(shape))


class GaussianRadar(SensorModel):
    """Range-binned Gaussian radar model (implements ``RadarSensor``; a scikit-learn estimator).

    Args:
        range_edges: bin edges [m] of the corner range; outside values use the first/last bin.
        min_count: minimum detections per bin before falling back to the pooled estimate.
        cov_floor: variance [m^2] added to every covariance diagonal (keeps it positive definite).
        extra_state: names of extra numeric log columns entering the mean and detection linearly.

    Attributes:
        edges_: ``(B + 1,)`` range bin edges [m] (``range_edges``).
        mean_: ``(B, 2)`` mean output ``z`` [m] per range bin (given a detection).
        cov_: ``(B, 2, 2)`` output covariance [m^2] per range bin (``cov_floor`` added).
        p_detect_: ``(B,)`` detection probability per range bin.
        clutter_rate_: mean number of clutter detections per cycle.
        clutter_mean_, clutter_cov_: mean [m] and covariance [m^2] of the clutter positions.
        extra_state_: names of the extra state variables.
        extra_mean_, extra_std_: ``(E,)`` standardisation of the extra state.
        extra_coef_: ``(E, 2)`` linear terms of the mean [m per std].
        extra_logit_: ``(E,)`` linear terms of the detection logit [per std].
        cycle_time_: seconds between the frames of the training log (NaN: unknown).
        card_: the model card entries (:class:`~sensor_envs.sensor_model.SensorModel`).

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import GaussianRadar
        >>> from sensor_envs.radar.rig import record_rig_log
        >>> model = GaussianRadar().fit(record_rig_log(4, 10, 4, np.random.default_rng(0)))
        >>> z, source = model.sample(np.array([[15.0, 1.0]]), np.random.default_rng(1))
        >>> z.shape
        (1, 2)
    """

    KIND = KIND
    FORMAT_VERSION = FORMAT_VERSION
    CAPABILITIES = frozenset({"new_track", "extra_state", "log_prob", "clutter"})  # new_track: accepted, ignored
    _FITTED = "mean_"
    _SCHEMA: ClassVar[dict[str, tuple[str, int | None, bool]]] = {
        "edges": ("f", 1, True),
        "mean": ("f", 2, True),
        "cov": ("f", 3, True),
        "p_detect": ("f", 1, True),
        "clutter_rate": ("f", 1, True),
        "clutter_mean": ("f", 1, True),
        "clutter_cov": ("f", 2, True),
    }
    _UPGRADES = {1: _upgrade_1_to_2}
    _PARAM_DEFAULTS: ClassVar[dict[str, Any]] = {"extra_state": ()}
    _HEADER_SCHEMA: ClassVar[dict[str, list[Constraint]] | None] = HEADER_SCHEMA
    _parameter_constraints: ClassVar[dict[str, list[Constraint]]] = {
        "range_edges": [Numbers(Interval(0, MAX_POSITION), min_length=2, increasing=True)],
        "min_count": [Interval(1, None, integer=True)],
        "cov_floor": [Interval(0, MAX_POSITION**2)],
        "extra_state": [Names()],
    }
    """One declarative check of every hyperparameter, used by :meth:`fit` and :meth:`load`."""

    def __init__(
        self,
        *,
        range_edges: tuple[float, ...] = (0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 80.0, 100.0, 150.0),
        min_count: int = 20,
        cov_floor: float = 1e-4,
        extra_state: tuple[str, ...] = (),
    ) -> None:
        self.range_edges = range_edges
        self.min_count = min_count
        self.cov_floor = cov_floor
        self.extra_state = extra_state

    def fit(self, log: RadarLog, cycle_time: float | None = None) -> GaussianRadar:
        """Fit means, covariances, detection probabilities and clutter on ``log``; returns self."""
        cycle = fit_cycle_time(log, cycle_time)  # a RadarLog; the cycle time consistent with its t column
        self._check_params()
        edges = np.asarray(self.range_edges, dtype=np.float64)
        tt = target_tuples(log)
        det = ~np.isnan(tt.z[:, 0])
        if det.sum() < 3:
            raise InputError(f"{log.source}: fewer than 3 detected target rows; cannot fit a Gaussian")
        b = self._bin(tt.corner, edges)
        nb = edges.size - 1
        x = self._fit_extra_scaling(state_matrix(log, tuple(self.extra_state), tt.row))
        z_lin = tt.z.copy()
        self.extra_coef_ = np.zeros((x.shape[1], 2))
        for _ in range(3 if x.shape[1] else 0):  # alternate bin means and the linear term
            mu = np.array(
                [z_lin[det & (b == k)].mean(axis=0) if (det & (b == k)).any() else np.zeros(2) for k in range(nb)]
            )
            r = tt.z[det] - mu[b[det]]
            self.extra_coef_ = np.linalg.solve(x[det].T @ x[det] + 1e-6 * np.eye(x.shape[1]), x[det].T @ r)
            z_lin = tt.z - x @ self.extra_coef_
        pooled_mu, pooled_cov = z_lin[det].mean(axis=0), np.cov(z_lin[det].T) + self.cov_floor * np.eye(2)
        self.mean_, self.cov_ = np.tile(pooled_mu, (nb, 1)), np.tile(pooled_cov, (nb, 1, 1))
        self.p_detect_ = np.full(nb, det.mean())
        for k in range(nb):  # one iteration per range bin
            sel = det & (b == k)
            if sel.sum() >= self.min_count:
                self.mean_[k] = z_lin[sel].mean(axis=0)
                self.cov_[k] = np.cov(z_lin[sel].T) + self.cov_floor * np.eye(2)
            if (b == k).sum() >= self.min_count:
                self.p_detect_[k] = det[b == k].mean()
        self.extra_logit_ = _logistic_offset_fit(x, det, self.p_detect_[b])
        counts, xy = clutter_counts(log)
        self.clutter_rate_ = float(counts.mean())
        if xy.shape[0] >= 3:
            self.clutter_mean_, self.clutter_cov_ = xy.mean(axis=0), np.cov(xy.T) + self.cov_floor * np.eye(2)
        else:
            self.clutter_mean_, self.clutter_cov_ = np.zeros(2), np.eye(2)
        self.edges_ = edges
        self.cycle_time_ = cycle
        self.card_: dict[str, Any] = {}
        return self

    def _fit_extra_scaling(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Store the extra columns' mean and std; return them standardised (NaN -> 0)."""
        self.extra_state_ = tuple(str(n) for n in self.extra_state)
        self.extra_mean_ = np.nan_to_num(np.nanmean(x, axis=0)) if x.shape[1] else np.zeros(0)
        self.extra_std_ = np.maximum(np.nan_to_num(np.nanstd(x, axis=0)), 1e-9) if x.shape[1] else np.zeros(0)
        return np.nan_to_num((x - self.extra_mean_) / self.extra_std_)

    def _extra_x(self, extra: NDArray | None, n: int) -> NDArray[np.float64]:
        """Standardised ``(n, E)`` extra state of ``n`` queries (raises when the model needs it and it is absent)."""
        names = getattr(self, "extra_state_", ())
        if not names:
            return np.zeros((n, 0))
        if extra is None:
            raise InputError(f"extra: this model's state includes {list(names)}; pass their values")
        x = np.asarray(extra, dtype=np.float64)
        if x.size != n * len(names):
            raise InputError(f"extra: expected ({n}, {len(names)}) values of {list(names)}, got shape {x.shape}")
        return np.nan_to_num((x.reshape(n, len(names)) - self.extra_mean_) / self.extra_std_)

    def _mean_pd(self, corners: NDArray, extra: NDArray | None) -> tuple[NDArray, NDArray, NDArray]:
        """Bin index, mean output ``(n, 2)`` [m] and detection probability ``(n,)`` at corners and extra state."""
        b = self._bin(corners, self.edges_)
        x = self._extra_x(extra, corners.shape[0])
        if x.shape[1] == 0:
            return b, self.mean_[b], self.p_detect_[b]
        pd = np.clip(self.p_detect_[b], 1e-9, 1 - 1e-9)
        logit = np.log(pd) - np.log1p(-pd) + x @ self.extra_logit_
        return b, self.mean_[b] + x @ self.extra_coef_, 1.0 / (1.0 + np.exp(-logit))

    @property
    def state_variables(self) -> tuple[str, ...]:
        """Names of the state: the corner, then the extra state variables."""
        return ("corner_x", "corner_y", *getattr(self, "extra_state_", ()))

    def mean_output(
        self, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> tuple[NDArray, NDArray]:
        """Mean output ``(n, 2)`` [m] given a detection and ``P(miss)`` ``(n,)`` at ``state`` (``new_track`` unused)."""
        self._check_fitted()
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        _, mu, pd = self._mean_pd(st[:, :2], extra)
        return mu, 1.0 - pd

    @staticmethod
    def _bin(corners: NDArray, edges: NDArray) -> NDArray[np.int64]:
        r = np.hypot(corners[:, 0], corners[:, 1])
        return np.clip(np.searchsorted(edges, r, side="right") - 1, 0, edges.size - 2)

    def detection_probability(self, corners: NDArray) -> NDArray[np.float64]:
        """Detection probability ``(n,)`` at corners ``(n, 2)`` [m]."""
        self._check_fitted()
        return self.p_detect_[self._bin(np.atleast_2d(corners), self.edges_)]

    def sample_cycle(
        self,
        corners: NDArray,
        prev_z: NDArray | None,
        rng: np.random.Generator,
        extra: NDArray | None = None,
        new_track: NDArray | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """``RadarSensor.sample_cycle``; ``prev_z`` and ``new_track`` are ignored; ``source`` is always -1."""
        self._check_fitted()
        corners = check_cycle_states(
            corners, prev_z, rng, extra=extra, new_track=new_track, extra_names=self.extra_state_
        )
        n = corners.shape[0]
        b, mu, pd = self._mean_pd(corners, extra)
        chol = np.linalg.cholesky(self.cov_[b])
        z = mu + np.einsum("nij,nj->ni", chol, rng.standard_normal((n, 2)))
        z[rng.random(n) >= pd] = np.nan
        return z, np.full(n, -1, dtype=np.int64)

    def sample(
        self, state: NDArray, rng: np.random.Generator, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Sample for ``(n, 2)`` or ``(n, 4)`` states (only the corner is used) and the extra state."""
        self._check_fitted()
        check_states(state, rng=rng, extra=extra, new_track=new_track, extra_names=self.extra_state_)
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        return self.sample_cycle(st[:, :2], None, rng, extra=extra)

    def sample_clutter(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Poisson number of clutter points from the fitted 2-D Gaussian, ``(m, 2)`` [m]."""
        self._check_fitted()
        m = int(rng.poisson(self.clutter_rate_))
        return rng.multivariate_normal(self.clutter_mean_, self.clutter_cov_, size=m).reshape(m, 2)

    def log_prob(
        self, z: NDArray, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> NDArray[np.float64]:
        """``log p_d + log N(z; mean, cov)`` for detections, ``log(1 - p_d)`` for ``NaN`` rows, ``(n,)``.

        ``new_track`` is accepted for the common radar API and ignored (no start state).
        """
        self._check_fitted()
        check_states(state, z, extra=extra, new_track=new_track, extra_names=self.extra_state_)
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        b, mu, pd = self._mean_pd(st[:, :2], extra)
        d = z - mu
        inv = np.linalg.inv(self.cov_[b])
        maha = np.einsum("ni,nij,nj->n", d, inv, d)
        logn = -0.5 * maha - np.log(2 * np.pi) - 0.5 * np.log(np.linalg.det(self.cov_[b]))
        with np.errstate(divide="ignore"):
            return np.where(np.isnan(z[:, 0]), np.log(1 - pd), np.log(pd) + np.nan_to_num(logn, nan=0.0))

    # ------------------------------------------------------------------ files
    def _to_file(self) -> tuple[Header, Arrays]:
        """Header and arrays of the current format (:class:`~sensor_envs.sensor_model.SensorModel`)."""
        header = {
            "params": {
                "range_edges": [float(e) for e in self.range_edges],
                "min_count": self.min_count,
                "cov_floor": self.cov_floor,
                "extra_state": list(self.extra_state_),
            },
            "state_variables": list(self.state_variables),
            "cycle_time": self.cycle_time_,
        }
        arrays = {
            "edges": self.edges_,
            "mean": self.mean_,
            "cov": self.cov_,
            "p_detect": self.p_detect_,
            "clutter_rate": np.array([self.clutter_rate_]),
            "clutter_mean": self.clutter_mean_,
            "clutter_cov": self.clutter_cov_,
            "extra_mean": self.extra_mean_,
            "extra_std": self.extra_std_,
            "extra_coef": self.extra_coef_.reshape(-1, 2),
            "extra_logit": self.extra_logit_,
        }
        return header, arrays

    @classmethod
    def _from_file(cls, path: Path, header: Header, arrays: Arrays) -> GaussianRadar:
        """The model of a current-format file (values checked)."""
        a = arrays
        m = cls(**cls._params_from(path, header))
        _check_arrays(path, a)
        m.edges_, m.mean_, m.cov_, m.p_detect_ = a["edges"], a["mean"], a["cov"], a["p_detect"]
        m.clutter_rate_ = float(a["clutter_rate"][0])
        m.clutter_mean_, m.clutter_cov_ = a["clutter_mean"], a["clutter_cov"]
        m.cycle_time_ = optional_positive(path, "cycle_time", header.get("cycle_time"))
        _load_extra(m, a, path)
        return m


def baseline_file(model: str | os.PathLike[str]) -> Path:
    """The Gaussian baseline's file beside a KDE radar file (``sensor-envs fit radar`` writes the pair).

    ``<stem>_gaussian.npz``, else the model's name with its last ``_kde`` word as ``_gaussian`` (the shipped pairs
    ``radar_kde.npz`` / ``radar_gaussian.npz`` and ``radar_kde_fast.npz`` / ``radar_gaussian_fast.npz``): the first
    of the two that exists, else the first.
    """
    p = Path(model)
    candidates = [p.with_name(p.stem + "_gaussian.npz")]
    words = p.stem.split("_")
    if "kde" in words[1:]:
        i = len(words) - 1 - words[::-1].index("kde")
        candidates.append(p.with_name("_".join([*words[:i], "gaussian", *words[i + 1 :]]) + ".npz"))
    return next((c for c in candidates if c.exists()), candidates[0])


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


def _load_extra(m: GaussianRadar, a: dict[str, NDArray], path: Any) -> None:
    """Restore and check the linear extra-state terms (format 2; format-1 files have none)."""
    e = len(m.extra_state)
    m.extra_state_ = tuple(str(n) for n in m.extra_state)
    zero = {
        "extra_mean": np.zeros(0),
        "extra_std": np.zeros(0),
        "extra_coef": np.zeros((0, 2)),
        "extra_logit": np.zeros(0),
    }
    missing = [k for k in zero if k not in a]
    if missing:
        raise ModelFileError(f"{path}: field {missing[0]!r} is missing")
    v = {k: np.asarray(a[k], dtype=np.float64) for k in zero}
    shapes = {"extra_mean": (e,), "extra_std": (e,), "extra_coef": (e, 2), "extra_logit": (e,)}
    for k, shape in shapes.items():
        if v[k].shape != shape or not np.isfinite(v[k]).all():
            raise ModelFileError(f"{path}: field {k!r} must be {shape} finite values (one per 'extra_state' name)")
    if (v["extra_std"] <= 0).any():
        raise ModelFileError(f"{path}: field 'extra_std' must be positive")
    m.extra_mean_, m.extra_std_, m.extra_coef_, m.extra_logit_ = (
        v["extra_mean"],
        v["extra_std"],
        v["extra_coef"],
        v["extra_logit"],
    )


def _logistic_offset_fit(x: NDArray, y: NDArray, p0: NDArray, ridge: float = 1.0, steps: int = 15) -> NDArray:
    """Coefficients ``c (E,)`` of ``logit p = logit p0 + x c`` by ridge-regularised Newton steps (``y`` in {0, 1})."""
    if x.shape[1] == 0:
        return np.zeros(0)
    p0 = np.clip(p0, 1e-6, 1 - 1e-6)
    off = np.log(p0) - np.log1p(-p0)
    c = np.zeros(x.shape[1])
    for _ in range(steps):  # Newton iterations (E is a handful of variables)
        p = 1.0 / (1.0 + np.exp(-(off + x @ c)))
        g = x.T @ (y - p) - ridge * c
        h = (x * (p * (1 - p))[:, None]).T @ x + ridge * np.eye(x.shape[1])
        c = c + np.linalg.solve(h, g)
    return c
