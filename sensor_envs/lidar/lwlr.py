"""Per-bearing learned lidar model (Tallavajhula & Kelly's seed), with a mixture extension.

Each bearing ``k``'s reading is an outcome of a per-bearing distribution whose parameters depend on
the features of the state: the nominal range ``r`` [m] and the angle of incidence ``alpha`` [rad] of
the ray, computed from the (approximate) sensor pose and the nominal map.

* ``variant="seed"`` (the paper): null with probability ``p_null``, else ``Normal(mu, sigma)``. All
  non-null readings, including spurious far returns, enter ``mu`` and ``sigma``.
* ``variant="extended"`` (this project): null with ``p_null``, a spurious far return with
  ``p_spur`` (reading ``> spur_above``, value ``Normal(spur_mu_, spur_sigma_)`` shared by all bearings),
  else ``Normal(mu, sigma)`` fitted on the in-range readings; ``log sigma`` is regressed (positive,
  heteroscedastic) and the kernel also pools neighbouring bearings (width ``h_bearing``, chosen by
  cross-validation, 0 = the seed's strictly per-bearing fit); cells whose mean or spread is an
  outlier of a pilot fit are down-weighted (LOWESS bisquare); and ``tau`` [m], the spread of a
  cell's mean around ``mu`` when the pose is approximate (regressed on the squared out-of-fold
  residuals), widens the density of :meth:`LidarLWLR.log_prob` to ``sqrt(sigma^2 + tau^2)`` (a marginal
  per reading). Sampling has one semantics (issue 43): the world's sensor (:class:`LearnedLidar`) knows the
  true pose; :meth:`LidarLWLR.sample` at approximate poses draws ONE rigid pose error per pose
  (``pose_sd_``, the robust spread of the training log's pose corrections) and then the world's draw at
  the perturbed pose, so neighbouring rays move together as on the real unit. Nulls persist per cell:
  the readings of one pose and bearing are
  not independent Bernoulli draws (on the real Neato log most cells are all-null or never null), so
  the extended variant also fits ``null_rho_``, the intra-cell correlation of nulls (a beta-binomial
  over a cell's repeats with mean ``p_null``, chosen by leave-poses-out likelihood). :meth:`LidarLWLR.sample`
  draws each cell's null probability once from ``Beta(p_null c, (1 - p_null) c)``, ``c = 1 / rho - 1``,
  shared by its repeats; :func:`null_count_log_prob` scores a cell's null count. The per-reading
  :meth:`LidarLWLR.log_prob` and the world's sensor use the marginal ``p_null`` (unchanged). Spurious
  far returns persist per cell too (on the real log, a cell that has any is spurious in a median 96 %
  of its readings): ``spur_rho_`` is their intra-cell correlation, chosen the same way from the
  cells' spurious counts around the out-of-fold ``p_spur``, and :meth:`LidarLWLR.sample` draws each
  cell's spurious probability from the same kind of Beta (mean ``p_spur``).

Each parameter is regressed per bearing by locally weighted linear regression (LWLR) on
``(r, alpha)`` of the training cells (one cell = one pose and one bearing, summarised by its
null fraction, spurious fraction, mean and standard deviation), with Gaussian kernel widths chosen
per parameter by leave-poses-out cross-validation. Exact LWLR is too slow at run time, so the fit
tabulates every parameter on a regular ``(r, alpha)`` grid per bearing; :meth:`LidarLWLR.params`
interpolates bilinearly. Queries outside the training cells' range of ``r``/``alpha`` at a bearing
(widened by one kernel width) are clamped to it (constant extrapolation). Rays with no hit within
``max_range`` are nulls with probability ``1 - P_EPS``.

The bias (``mu - r``) learned at approximate poses partly fits those poses' errors, which do not
recur at other poses. ``bias_shrinkage`` shrinks it toward zero at prediction, ``mu = r + (1 - s) bias``
(``s = 1`` is the plain raycast), with ``s`` chosen by leave-poses-out CV (:func:`choose_shrinkage`,
rule there: never worse than the raycast in any CV fold) or given. ``pose_correction=True`` (static
logs with repeats) first corrects every training pose by least squares of its cell means against the
map's raycast, jointly with a per-bearing constant bias (:mod:`sensor_envs.lidar.pose_correction`,
the seed's remedy for approximate poses), and learns the tables at the corrected poses; the
shrinkage CV and ``tau`` still score the held-out poses at their approximate poses, as a user's are.
``bias_model="pooled"`` (the default since format 6) learns the bias as a trend over ``(r, alpha)``
pooled over all bearings plus a per-bearing part whose weight is chosen with ``s`` on the same folds
(:mod:`sensor_envs.lidar.bias_transfer`: what one bearing learns at a few poses is mostly those poses'
registration and map errors); ``"per_bearing"`` is the seed's per-bearing bias alone.

Model files hold only the tables, hyperparameters and the card (never training readings).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.inputs import InputError
from sensor_envs.lidar import scan_sampler
from sensor_envs.lidar.bias_transfer import (
    BIAS_MODELS,
)
from sensor_envs.lidar.extra_state import check_extra_state, fit_extra_terms
from sensor_envs.lidar.fit_cells import RHO_GRID, cell_statistics, fit_cells, lidar_features, pose_fold_groups
from sensor_envs.lidar.fit_readings import fit_per_reading
from sensor_envs.lidar.gaussian import GaussianLidar
from sensor_envs.lidar.local_regression import (
    P_EPS,
    SHRINKAGE_GRID,
    SIGMA_FLOOR,
    choose_shrinkage,
    lwlr,
)
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr_io import HEADER_SCHEMA, MAX_SIGMA, UPGRADES, from_file, to_file
from sensor_envs.lidar.model_call import check_model_call, check_query
from sensor_envs.lidar.reading_law import (
    cell_probability,
    draw_readings,
    mixture_log_prob,
    null_count_log_prob,
    reading_params,
)
from sensor_envs.modelio import (
    RANDOM_STATE,
    Constraint,
    InstanceOf,
    Interval,
    Names,
    Numbers,
    Options,
    default_model_path,
)
from sensor_envs.sensor_model import Arrays, Header, SensorModel

__all__ = [
    "LidarLWLR",
    "LearnedLidar",
    "load_learned_lidar",
    "lidar_features",
    "cell_statistics",
    "mixture_log_prob",
    "null_count_log_prob",
    "RHO_GRID",
    "SHRINKAGE_GRID",
    "choose_shrinkage",
    "pose_fold_groups",
    "P_EPS",
    "SIGMA_FLOOR",
    "VARIANTS",
    "MODEL_KIND",
    "FORMAT_VERSION",
    "MAX_SIGMA",
    "lwlr",
]

"""Probabilities of null are clipped to ``[P_EPS, 1 - P_EPS]`` so that log-likelihoods stay finite."""
"""Floor of the spurious-return probability (extended variant)."""
"""Floor of every standard deviation [m] (half the sensor's 1 mm range quantum)."""
"""Cell-mean residuals [m] are clipped to this before their variance ``tau^2`` is regressed."""
VARIANTS = ("seed", "extended")
MODEL_KIND = "sensor_envs.lidar_lwlr"  # the file format's kind string (kept: shipped files carry it)
FORMAT_VERSION = 7
"""2 adds ``null_rho`` to the header (version 1 files load with ``null_rho = 0``, independent nulls); 3 adds the
extra state (``params.extra_state``, arrays ``extra_mean``, ``extra_scale``, ``extra_coef``; older files load
with no extra state); 4 adds the bias shrinkage (header ``bias_shrinkage``, ``params.bias_shrinkage``,
``params.pose_correction``; older files load with shrinkage 0 and no pose correction, their old behaviour);
5 adds ``spur_rho`` (persistent spurious returns; older files load with ``spur_rho = 0``, independent ones);
6 adds ``params.bias_model`` (older files load with ``"per_bearing"``, the bias they were fitted with) and the header's
``pose_sd`` (older files load with ``None``: see :meth:`LidarLWLR.sample`); 7 adds ``extra_low``, ``extra_high``
(the extra terms' fitted range, queries clamped to it; older files load unclamped)."""
DEFAULT_MODEL_FILE = "neato_lidar.npz"
"""File name of the shipped rig-fitted model in ``models/``."""


# --------------------------------------------------------------------------------------------- features


# ------------------------------------------------------------------------------------------------ model
class LidarLWLR(SensorModel):
    """Per-bearing LWLR lidar model (a scikit-learn estimator: ``get_params``/``set_params``/``clone``).

    Args:
        variant: ``"seed"`` (3 parameters) or ``"extended"`` (adds spurious returns, log-sigma, bearing pooling).
        n_folds: folds of the leave-poses-out cross-validation of the kernel widths.
        h_range_grid: candidate range kernel widths [m].
        h_alpha_grid: candidate incidence kernel widths [rad].
        h_bearing_grid: candidate bearing kernel widths [bearing steps] (extended only; the seed uses 0).
        degree_grid: candidate local polynomial degrees, 0 (local constant) or 1 (local linear)
            (extended only; the seed uses 1).
        max_range: the sensor's maximum range [m] (farther hits are no hit).
        spur_above: readings farther than this are spurious returns [m] (extended).
        table_range_step: range step of the parameter tables [m].
        table_alpha_steps: number of incidence knots of the tables over ``[0, pi/2]``.
        random_state: seed or Generator for the fold assignment.
        extra_state: names of extra state variables of scan logs (``t``, ``prev_residual``, covariate
            names such as ``v``, ``omega``), linear terms on top of the tables
            (:mod:`sensor_envs.lidar.extra_state`); queries then pass ``extra``.
        bias_shrinkage: ``"cv"`` (default) or a number in ``[0, 1]``: the learned bias is shrunk toward
            zero, ``mu = r + (1 - s) bias``; ``"cv"`` chooses ``s`` in :data:`SHRINKAGE_GRID` by the
            leave-poses-out folds of the kernel widths with the rule of :func:`choose_shrinkage`: the
            candidate of least CV MAE of ``mu`` among those whose MAE is <= the raycast's (``s = 1``)
            in EVERY fold, so the chosen ``mu`` is never worse than the raycast in any CV fold.
        pose_correction: correct the training poses (dx, dy, dtheta each) jointly with a per-bearing bias
            before learning the tables (:mod:`sensor_envs.lidar.pose_correction`; static logs with repeats).
        bias_model: ``"pooled"`` (default): bias = a trend pooled over bearings + ``lam`` x the per-bearing
            residual fit, ``lam`` chosen with the shrinkage by the folds (:mod:`sensor_envs.lidar.bias_transfer`);
            ``"per_bearing"``: the per-bearing fit alone (the behaviour before format 6). Scan logs fitted per
            reading (:mod:`sensor_envs.lidar.fit_readings`) always use the per-bearing bias.
        verbose: show tqdm progress bars of the fit.
        **deprecated: ``progress`` (the name of ``verbose`` before the model contract; a ``FutureWarning``).

    Attributes:
        tables_: ``(n_params, K, n_r, n_alpha)`` parameter tables per bearing on the ``(r, alpha)`` grid.
        param_names_: the parameters of ``tables_`` (``p_null``, ``bias``, ``sigma`` or ``log_sigma``, ...).
        range_grid_: ``(n_r,)`` nominal ranges [m]; alpha_grid_: ``(n_alpha,)`` incidences [rad] of the tables.
        bearings_: ``(K,)`` bearings [rad].
        h_: per parameter, ``[h_range [m], h_alpha [rad], h_bearing [steps], degree]`` chosen by CV.
        cv_scores_: the CV's scores and choices (kernel widths, shrinkage, pose error).
        spur_mu_, spur_sigma_: mean and std [m] of the spurious far returns.
        p_out_: share of outlying cells; null_rho_, spur_rho_: intra-cell correlations of nulls and spurious
            returns (0: independent readings).
        bias_shrinkage_: the shrinkage ``s`` of the bias in use.
        pose_sd_: ``(3,)`` rigid pose error sd ``(dx [m], dy [m], dtheta [rad])`` of :meth:`sample`, or ``None``.
        extra_state_, extra_mean_, extra_scale_, extra_coef_: the extra state's names, standardisation and
            linear terms (:mod:`sensor_envs.lidar.extra_state`).
        extra_low_, extra_high_: ``(d,)`` range of the standardised extra terms on the fit readings; queries
            are clamped to it (a variable's modified terms, e.g. ``v@sq``, at its plain term's clamp).
        training_: a summary of the training log (no readings).
        card_: the model card entries (:class:`~sensor_envs.sensor_model.SensorModel`), e.g. ``gaussian_baseline``.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import LidarLWLR
        >>> from sensor_envs.modelio import default_model_path
        >>> model = LidarLWLR.load(default_model_path("neato_lidar.npz"))  # the shipped model
        >>> r, alpha = np.full((1, 360), 2.0), np.zeros((1, 360))  # nominal range [m], incidence [rad]
        >>> scan = model.sample_scan(r, alpha, np.random.default_rng(0))  # readings [m], 0 = null
        >>> scan.shape, bool((scan == 0).any())
        ((1, 360), True)
    """

    KIND = MODEL_KIND
    FORMAT_VERSION = FORMAT_VERSION
    CAPABILITIES = frozenset({"extra_state", "log_prob"})
    _FITTED = "tables_"
    _SCHEMA: ClassVar[dict[str, tuple[str, int | None, bool]]] = {
        "tables": ("f", 4, True),
        "bearings": ("f", 1, True),
        "range_grid": ("f", 1, True),
        "alpha_grid": ("f", 1, True),
    }
    _PARAM_DEFAULTS: ClassVar[dict[str, Any]] = {"extra_state": ()}
    _UPGRADES = UPGRADES
    _HEADER_SCHEMA: ClassVar[dict[str, list[Constraint]] | None] = HEADER_SCHEMA
    FIT_STRATEGIES: ClassVar[dict[str, Callable[..., Any]]] = {"cells": fit_cells, "readings": fit_per_reading}
    """The model's two fits, ``strategy(model, log, **options)``: per-cell statistics (logs with repeats) or
    individual readings (scan logs); :meth:`fit` picks one."""
    _parameter_constraints: ClassVar[dict[str, list[Constraint]]] = {
        "variant": [Options(*VARIANTS)],
        "n_folds": [Interval(2, None, integer=True)],
        "h_range_grid": [Numbers(Interval(0, None, open_low=True))],
        "h_alpha_grid": [Numbers(Interval(0, None, open_low=True))],
        "h_bearing_grid": [Numbers(Interval(0, None))],
        "degree_grid": [Numbers(Interval(0, 1, integer=True))],
        "max_range": [Interval(0, MAX_SIGMA, open_low=True)],
        "spur_above": [Interval(0, 1000, open_low=True)],  # MAX_RANGE of a lidar log [m]
        "table_range_step": [Interval(1e-3, 10)],  # at most spur_above / 1e-3 table cells
        "table_alpha_steps": [Interval(2, None, integer=True)],
        "random_state": RANDOM_STATE,
        "verbose": [InstanceOf(bool)],
        "extra_state": [Names()],  # each a term of the extra-state grammar: check_extra_state
        "bias_shrinkage": [Options("cv"), Interval(0, 1)],
        "pose_correction": [InstanceOf(bool)],
        "bias_model": [Options(*BIAS_MODELS)],
    }
    """One declarative check of every hyperparameter, used by :meth:`fit` and :meth:`load`."""

    def __init__(
        self,
        *,
        variant: str = "extended",
        n_folds: int = 10,
        h_range_grid: tuple[float, ...] = (0.1, 0.25, 0.6, 1.6, 6.4),
        h_alpha_grid: tuple[float, ...] = (0.15, 0.5, 4.0),
        h_bearing_grid: tuple[float, ...] = (0.0, 1.0, 3.0, 12.0),
        degree_grid: tuple[int, ...] = (0, 1),
        max_range: float = 5.0,
        spur_above: float = 6.0,
        table_range_step: float = 0.125,
        table_alpha_steps: int = 9,
        random_state: int | np.random.Generator | None = 0,
        extra_state: tuple[str, ...] = (),
        bias_shrinkage: str | float = "cv",
        pose_correction: bool = False,
        bias_model: str = "pooled",
        verbose: bool = False,
        **deprecated: Any,
    ) -> None:
        self.variant = variant
        self.n_folds = n_folds
        self.h_range_grid = h_range_grid
        self.h_alpha_grid = h_alpha_grid
        self.h_bearing_grid = h_bearing_grid
        self.degree_grid = degree_grid
        self.max_range = max_range
        self.spur_above = spur_above
        self.table_range_step = table_range_step
        self.table_alpha_steps = table_alpha_steps
        self.random_state = random_state
        self.extra_state = extra_state
        self.bias_shrinkage = bias_shrinkage
        self.pose_correction = pose_correction
        self.bias_model = bias_model
        unknown = sorted(set(deprecated) - {"progress"})
        if unknown:
            raise TypeError(f"LidarLWLR got unexpected keyword arguments {unknown}")
        self.verbose = self._deprecated_progress(deprecated.get("progress"), verbose)

    # ---------------------------------------------------------------------------------------- fitting
    def _check_params_relations(self, source: str | os.PathLike[str] | None) -> None:
        """The ``extra_state`` names are valid (``InputError`` naming the parameter)."""
        check_extra_state(self.extra_state)

    def _check_params_for(self, log: LidarLog) -> None:
        """The hyperparameters (:meth:`_check_params`) and ``n_folds`` within the log's distinct poses."""
        self._check_params()
        n = int(pose_fold_groups(log.poses).max(initial=-1)) + 1
        if not 2 <= self.n_folds <= n:
            what = "number of poses" if n == log.n_poses else "number of distinct poses"
            raise InputError(f"n_folds: must be in [2, {what} = {n}], got {self.n_folds}")

    def fit(self, log: LidarLog, *, per_reading: bool | None = None, **reading_options: Any) -> LidarLWLR:
        """Fit the model to a log (approximate poses + nominal map), choosing kernel widths by CV.

        Args:
            log: a :class:`~sensor_envs.lidar.log.LidarLog` with a map.
            per_reading: the fit strategy (:attr:`FIT_STRATEGIES`): on individual readings
                (``"readings"``, :func:`sensor_envs.lidar.fit_readings.fit_per_reading`) or on per-cell statistics
                (``"cells"``, :func:`sensor_envs.lidar.fit_cells.fit_cells`); default: readings for logs with one
                reading per pose and bearing (scans at moving poses), cells for repeated logs.
            **reading_options: ``max_readings``, ``block_scans`` of the per-reading fit.

        Returns:
            ``self``, with ``tables_`` ``(n_params, K, n_r, n_alpha)``, ``param_names_``, ``range_grid_`` [m],
            ``alpha_grid_`` [rad], ``h_`` (per parameter: h_range, h_alpha, h_bearing, degree),
            ``cv_scores_``, ``bearings_`` [rad], ``spur_mu_``/``spur_sigma_`` [m], ``p_out_`` and
            ``training_`` (a summary of the log, no readings) set.

        Raises:
            ValueError: for bad hyperparameters or a log without map.
        """
        check_model_call(None, log=log, per_reading=per_reading)  # fit(None): an InputError, not AttributeError
        strategy = "readings" if per_reading or (per_reading is None and log.ranges.shape[2] < 2) else "cells"
        if strategy == "cells" and reading_options:
            raise TypeError(f"fit: options {sorted(reading_options)} apply to the per-reading fit only")
        self.FIT_STRATEGIES[strategy](self, log, **reading_options)
        fit_extra_terms(self, log)
        self.card_ = {}
        return self

    def _grid(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n_r = int(np.ceil(self.max_range / self.table_range_step)) + 1
        return np.linspace(0.0, (n_r - 1) * self.table_range_step, n_r), np.linspace(
            0.0, np.pi / 2, self.table_alpha_steps
        )

    def _fit_spurious(self, log: LidarLog) -> None:
        x = log.ranges[~np.isnan(log.ranges) & (log.ranges > self.spur_above)]
        if x.size >= 2:
            self.spur_mu_, self.spur_sigma_ = float(x.mean()), float(max(x.std(ddof=1), SIGMA_FLOOR))
        else:  # no spurious return seen: a broad placeholder far beyond the in-range readings
            self.spur_mu_, self.spur_sigma_ = float(2 * self.spur_above), float(self.spur_above)

    # ------------------------------------------------------------------------------------ prediction
    def _check_fitted(self) -> None:
        """Raise sklearn's ``NotFittedError`` unless the model is fitted or loaded (fast when it is: scans call it)."""
        if "tables_" not in self.__dict__:
            super()._check_fitted()

    def baseline(self) -> GaussianLidar | None:
        """The :class:`~sensor_envs.lidar.gaussian.GaussianLidar` fitted with this model (:meth:`SensorModel.baseline`).

        Built from the card's ``gaussian_baseline`` keyword arguments; ``None`` when the card keeps none.
        """
        g = self.__dict__.get("card_", {}).get("gaussian_baseline")
        if not isinstance(g, dict):
            return None
        keys = ("sigma0", "k_range", "k_incidence", "alpha_max", "p_null_floor")
        return GaussianLidar(**{k: float(g[k]) for k in keys if k in g})

    @property
    def card_extra_(self) -> dict[str, Any]:
        """Card entries beyond ``training_`` and ``cv_scores_`` (the name of ``card_`` before the contract)."""
        return self.__dict__.setdefault("card_", {})

    @card_extra_.setter
    def card_extra_(self, value: dict[str, Any]) -> None:
        self.card_ = dict(value)

    def params_from_features(
        self, r: ArrayLike, alpha: ArrayLike, extra: ArrayLike | None = None, base_only: bool = False
    ) -> dict[str, NDArray[np.float64]]:
        """Reading-distribution parameters from features, by bilinear table lookup.

        Args:
            r: ``(..., K)`` nominal ranges [m] (``inf``/NaN = no hit), K = the model's bearings.
            alpha: ``(..., K)`` incidence [rad] (NaN where no hit).
            extra: raw values of the extra state variables ``extra_state_``, broadcastable to
                ``(..., K, d)``; required when the model has extra state.
            base_only: the tables alone (extra terms left out; used to fit them).

        Returns:
            ``p_null``, ``p_spur`` (0 for the seed variant), ``mu = r + (1 - bias_shrinkage_) bias`` [m]
            (plus the extra terms), ``sigma`` [m] (spread of repeated
            readings) and ``tau`` [m] (spread of a cell's mean around ``mu`` at an approximate pose; 0 for
            the seed variant), each ``(..., K)``.
        """
        return reading_params(self, r, alpha, extra, base_only)

    def params(
        self, poses: ArrayLike, map_segments: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(p_null, mu, sigma)``, each ``(S, K)``, at ``(S, 3)`` poses in a ``(M, 2, 2)`` map [m, rad].

        ``mu``/``sigma`` [m] are those of the in-range (non-spurious) component.
        """
        p = self.params_full(poses, map_segments)
        return p["p_null"], p["mu"], p["sigma"]

    def params_full(
        self, poses: ArrayLike, map_segments: ArrayLike, extra: ArrayLike | None = None
    ) -> dict[str, NDArray[np.float64]]:
        """All parameters (``p_null``, ``p_spur``, ``mu``, ``sigma``), each ``(S, K)``, at poses in a map.

        ``extra``: values of the extra state variables (see :meth:`params_from_features`).
        """
        self._check_fitted()
        r, a = lidar_features(poses, self.bearings_, map_segments, self.max_range)
        return self.params_from_features(r, a, extra)

    def sample_from_params(
        self,
        p: dict[str, NDArray[np.float64]],
        rng: np.random.Generator,
        shape: tuple[int, ...] | None = None,
        pose_uncertainty: bool = False,
    ) -> NDArray[np.float64]:
        """Draw readings [m] (``0`` = null) with parameter arrays ``p`` broadcast to ``shape``.

        With ``pose_uncertainty``, the in-range component's mean is drawn once per entry of ``p`` (one
        cell), shared by the repeats along the extra axes of ``shape``: with probability ``p_out``
        uniform on ``[0, out_range]`` (a ray whose nominal hit is another surface), else ``mu + tau z``;
        and so is the cell's null probability, from ``Beta(p_null c, (1 - p_null) c)``, ``c = 1 / null_rho - 1``
        (persistent nulls; ``p_null`` itself where ``null_rho`` is 0 or absent), then its spurious probability
        from the same Beta with mean ``p_spur`` and ``spur_rho`` (at most ``1 -`` the cell's null probability).
        """
        return draw_readings(self, p, rng, shape, pose_uncertainty)

    def sample_scan(
        self, r: NDArray[np.float64], alpha: NDArray[np.float64], rng: np.random.Generator, null: float = 0.0
    ) -> NDArray[np.float64]:
        """Readings [m] (``0`` = null), one per cell: ``sample_from_params(params_from_features(r, alpha), rng)``.

        The simulator's hot path (no extra state, no pose uncertainty): with numba (the ``fast`` extra) three
        compiled passes over the cells, split where vectorisation stops:
        :func:`~sensor_envs.lidar.scan_sampler.scan_nodes` (where each cell reads; vectorised),
        :func:`~sensor_envs.lidar.scan_sampler.scan_gather` (the table reads), numpy's ``exp`` of the
        log-scales (an exponential per cell inside a loop cost ~6 ns a value), then
        :func:`~sensor_envs.lidar.scan_sampler.scan_readings` (the draw; vectorised). The same float64
        operations in the same order as the two numpy methods and the same draws of ``rng``, so it returns the
        same bits.

        Args:
            r: ``(..., K)`` nominal ranges [m] (``inf``/NaN = no hit).
            alpha: ``(..., K)`` incidence [rad] (NaN where no hit).
            rng: a ``Generator`` (or :class:`~sensor_envs.rng.RowGenerators`) for the uniform and normal draws.
            null: the value of a null reading (``0``, the model's convention; the sensor interface's NaN).
        """
        return scan_sampler.sample_scan(self, r, alpha, rng, null)

    def sample(
        self,
        poses: ArrayLike,
        map_segments: ArrayLike,
        rng: np.random.Generator,
        n_repeats: int | None = None,
        extra: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Sample a log at ``(S, 3)`` approximate poses: ``(S, K)`` or ``(S, K, n_repeats)`` [m], ``0`` = null.

        One sampling semantics with the worlds' sensor (:class:`LearnedLidar`): each pose gets ONE rigid pose error
        ``(dx, dy, dtheta) ~ Normal(0, pose_sd_)`` [m, m, rad], shared by all its bearings and repeats (a real
        static pose's registration error shifts the whole scan; see ``docs/results/lidar_sampling.md``), drawn first
        from ``rng`` (``S x 3`` normals, none when ``pose_sd_`` is 0 or absent); the readings at the perturbed pose
        are then drawn as the worlds' sensor draws them (:meth:`sample_from_params`: null, spurious return or
        ``Normal(mu, sigma)`` per reading; no per-cell ``tau`` or ``p_out`` draw). So with ``n_repeats=None`` and no
        pose error this is :meth:`sample_scan` at the poses' features, bit for bit. With ``n_repeats``, each cell's
        null and spurious probabilities are drawn once (``Beta`` with means ``p_null``/``p_spur`` and intra-cell
        correlations ``null_rho_``/``spur_rho_``) and shared by its repeats (persistent nulls of a static pose); the
        cell counts then follow :func:`null_count_log_prob`.

        Files of format < 6 have no ``pose_sd_`` (read as 0): their ``sample`` is the worlds' draw at the given poses.
        """
        self._check_fitted()
        check_query(self, poses, map_segments, rng, extra=extra, n_repeats=n_repeats)
        p0 = np.atleast_2d(np.asarray(poses, dtype=np.float64))
        sd = getattr(self, "pose_sd_", None)
        sd = np.zeros(3) if sd is None else np.asarray(sd, dtype=np.float64)
        if np.any(sd > 0):
            p0 = p0 + rng.standard_normal(p0.shape) * sd
        p = self.params_full(p0, map_segments, extra)
        if n_repeats is None:
            return self.sample_from_params(p, rng)
        p = {k: v[..., None] for k, v in p.items()}
        p["p_null"] = cell_probability(p["p_null"], p["null_rho"], rng)
        p["p_spur"] = np.minimum(cell_probability(p["p_spur"], p["spur_rho"], rng), 1 - p["p_null"])
        return self.sample_from_params(p, rng, p["mu"].shape[:2] + (int(n_repeats),))

    def log_prob(
        self, ranges: ArrayLike, poses: ArrayLike, map_segments: ArrayLike, extra: ArrayLike | None = None
    ) -> NDArray[np.float64]:
        """Log-probability of readings: ``log p_null`` for a null, else a log density [1/m].

        Args:
            ranges: ``(S, K)`` or ``(S, K, R)`` readings [m], ``0`` = null, ``NaN`` = missing.
            poses: ``(S, 3)`` approximate sensor poses ``x, y, theta`` [m, rad].
            map_segments: ``(M, 2, 2)`` nominal map [m].
            extra: values of the extra state variables (see :meth:`params_from_features`).

        Returns:
            Same shape as ``ranges``; ``NaN`` where missing.
        """
        self._check_fitted()
        check_query(self, poses, map_segments, ranges=ranges, extra=extra)
        x = np.asarray(ranges, dtype=np.float64)
        p = self.params_full(poses, map_segments, extra)
        if x.ndim == 3:
            p = {k: v[..., None] for k, v in p.items()}
        return mixture_log_prob(x, p, self.spur_mu_, self.spur_sigma_)

    # ----------------------------------------------------------------------------------------- files
    def to_header(self) -> dict[str, Any]:
        """JSON header of the model file: hyperparameters, fitted scalars and the card."""
        self._check_fitted()
        header, _ = self._to_file()
        header["card"] = {**header["card"], **self.card_}
        return header

    def _to_file(self) -> tuple[Header, Arrays]:
        """Header and arrays of the current format (:mod:`sensor_envs.lidar.lwlr_io`)."""
        return to_file(self)

    @classmethod
    def _from_file(cls, path: Path, header: Header, arrays: Arrays) -> LidarLWLR:
        """The model of a current-format file (values checked)."""
        return from_file(cls, path, header, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> LidarLWLR:
        """Read a model file of any supported format (:meth:`SensorModel.load`); ``card_`` without ``training``."""
        header, arrays = cls.read_current(path)  # checks that path is a path
        return cls._from_file(Path(path), header, arrays)


# ---------------------------------------------------------------------------------------- the adapter
@dataclass(frozen=True)
class LearnedLidar:
    """:class:`~sensor_envs.lidar.sensors.LidarSensor` adapter around a fitted :class:`LidarLWLR`.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import make_lidar
        >>> lidar = make_lidar("learned")  # a LearnedLidar around the shipped LidarLWLR
        >>> lidar.measure(np.full(360, 2.0), np.zeros(360), np.random.default_rng(0)).shape
        (360,)
    """

    model: LidarLWLR

    def measure(
        self,
        nominal_range: NDArray[np.float64],
        incidence: NDArray[np.float64],
        rng: np.random.Generator,
        extra: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Sample one scan: ``(K,)`` ranges [m] from ``(K,)`` nominal ranges/incidences; ``NaN`` = null.

        ``extra``: values of the model's extra state variables (``(..., K, d)``, see
        :meth:`LidarLWLR.params_from_features`), needed when the model has extra state.
        """
        if extra is None and not getattr(self.model, "extra_state_", ()):
            return self.model.sample_scan(nominal_range, incidence, rng, null=np.nan)
        x = self.model.sample_from_params(self.model.params_from_features(nominal_range, incidence, extra), rng)
        return np.where(x == 0, np.nan, x)


def load_learned_lidar(model: str | os.PathLike[str] | LidarLWLR | None = None, **kwargs: Any) -> LearnedLidar:
    """The learned lidar sensor from a model file (default: the shipped rig-fitted model).

    Raises:
        ValueError: for any keyword argument (the learned lidar takes none besides ``model``).
        ModelFileError: when the file is missing or malformed.
    """
    if kwargs:
        raise InputError(f"lidar_kwargs: the learned lidar takes only 'model', got {sorted(kwargs)}")
    if isinstance(model, LidarLWLR):
        return LearnedLidar(model)
    return LearnedLidar(LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE) if model is None else model))
