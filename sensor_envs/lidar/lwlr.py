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

import hashlib
import itertools
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats as sps
from tqdm.auto import tqdm

from sensor_envs.geometry import as_segments, raycast_pose
from sensor_envs.inputs import InputError
from sensor_envs.jit import compiled
from sensor_envs.lidar.bias_transfer import (
    BIAS_MODELS,
    choose_bias,
    choose_global_widths,
    global_lookup,
    global_table,
    pooled_oof,
    support_gate,
)
from sensor_envs.lidar.extra_state import MAX_COEF, apply_extra, check_extra_state, fit_extra_terms
from sensor_envs.lidar.kernel import (
    P_EPS,
    P_SPUR_EPS,
    SHRINKAGE_GRID,
    SIGMA_FLOOR,
    TAU_CLIP,
    _bilinear,
    _finish,
    choose_shrinkage,
    lwlr,
)
from sensor_envs.lidar.log import LidarLog, check_model_call
from sensor_envs.lidar.pose_correction import correct_poses, pose_error_sd
from sensor_envs.modelio import (
    RANDOM_STATE,
    Constraint,
    InstanceOf,
    Interval,
    ModelFileError,
    Numbers,
    Options,
    check_finite,
    check_increasing,
    check_model_arrays,
    check_positive,
    check_probability,
    check_range,
    check_shape,
    default_model_path,
)
from sensor_envs.rng import fold_ids
from sensor_envs.sensor_model import Arrays, Header, SensorModel, set_param_defaults

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
]

"""Probabilities of null are clipped to ``[P_EPS, 1 - P_EPS]`` so that log-likelihoods stay finite."""
"""Floor of the spurious-return probability (extended variant)."""
"""Floor of every standard deviation [m] (half the sensor's 1 mm range quantum)."""
"""Cell-mean residuals [m] are clipped to this before their variance ``tau^2`` is regressed."""
VARIANTS = ("seed", "extended")
MODEL_KIND = "sensor_envs.lidar_lwlr"  # the file format's kind string (kept: shipped files carry it)
FORMAT_VERSION = 6
"""2 adds ``null_rho`` to the header (version 1 files load with ``null_rho = 0``, independent nulls); 3 adds the
extra state (``params.extra_state``, arrays ``extra_mean``, ``extra_scale``, ``extra_coef``; older files load
with no extra state); 4 adds the bias shrinkage (header ``bias_shrinkage``, ``params.bias_shrinkage``,
``params.pose_correction``; older files load with shrinkage 0 and no pose correction, their old behaviour);
5 adds ``spur_rho`` (persistent spurious returns; older files load with ``spur_rho = 0``, independent ones);
6 adds ``params.bias_model`` (older files load with ``"per_bearing"``, the bias they were fitted with) and the header's
``pose_sd`` (older files load with ``None``: see :meth:`LidarLWLR.sample`)."""
RHO_GRID = (0.0, 0.01, 0.03, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95)
"""Candidate intra-cell correlations of nulls and of spurious returns (extended variant)."""
_PARAMS = {"seed": ("p_null", "bias", "sigma"), "extended": ("p_null", "p_spur", "bias", "log_sigma")}
_TABLES = {"seed": _PARAMS["seed"], "extended": _PARAMS["extended"] + ("tau2",)}
MAX_SIGMA = 1e3
"""Largest standard deviation [m] (and bias magnitude) a model file may give: beyond it the file is corrupt."""
DEFAULT_MODEL_FILE = "neato_lidar.npz"
"""File name of the shipped rig-fitted model in ``models/``."""


# --------------------------------------------------------------------------------------------- features
def lidar_features(
    poses: ArrayLike, bearings: ArrayLike, segments: ArrayLike, max_range: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nominal range and incidence per pose and bearing.

    Args:
        poses: ``(S, 3)`` sensor poses ``x, y, theta`` in the map frame [m, rad].
        bearings: ``(K,)`` bearings in the sensor frame [rad].
        segments: ``(M, 2, 2)`` map [m].
        max_range: farther hits count as no hit [m].

    Returns:
        ``r (S, K)`` [m] (``inf`` = no hit) and ``alpha (S, K)`` [rad] (``NaN`` = no hit).
    """
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    r, a, _ = raycast_pose(p, bearings, as_segments(segments, name="map"), max_range)
    return r, a


def cell_statistics(log: LidarLog, spur_above: float, split_spurious: bool) -> dict[str, NDArray[np.float64]]:
    """Per pose-bearing cell statistics of a log's readings.

    Args:
        log: the log (``ranges (P, K, R)``).
        spur_above: readings farther than this [m] are spurious returns.
        split_spurious: if True, ``mean``/``std`` use in-range readings only; else all non-null readings.

    Returns:
        ``(P, K)`` arrays: ``n`` readings, ``n_ok`` readings entering mean/std, ``p_null``, ``p_spur``,
        ``mean`` [m], ``std`` [m] (ddof 1; NaN where ``n_ok < 2``).
    """
    x = log.ranges
    valid = ~np.isnan(x)
    null = valid & (x == 0)
    spur = valid & (x > spur_above)
    ok = valid & (x > 0) & ~(spur if split_spurious else np.zeros_like(spur))
    n, n_ok = valid.sum(2).astype(float), ok.sum(2).astype(float)
    xs = np.where(ok, x, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = xs.sum(2) / n_ok
        var = np.where(ok, (x - mean[..., None]) ** 2, 0.0).sum(2) / (n_ok - 1)
        out = {
            "n": n,
            "n_ok": n_ok,
            "p_null": null.sum(2) / n,
            "p_spur": spur.sum(2) / n,
            "mean": np.where(n_ok >= 1, mean, np.nan),
            "std": np.where(n_ok >= 2, np.sqrt(var), np.nan),
        }
    return out


def _targets(
    stats: dict[str, NDArray[np.float64]], r: NDArray[np.float64], name: str
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Regression target ``(P, K)`` of parameter ``name`` and the mask of cells that inform it."""
    hit = np.isfinite(r)
    if name in ("p_null", "p_spur"):
        return np.nan_to_num(stats[name]), hit & (stats["n"] > 0)
    m = hit & (stats["n_ok"] >= 2)
    if name == "bias":
        return np.where(m, stats["mean"] - np.where(hit, r, 0.0), 0.0), m
    s = np.where(m, stats["std"], 1.0)
    return (np.log(np.maximum(s, SIGMA_FLOOR)) if name == "log_sigma" else s), m


def _robust_weights(
    t_r: NDArray[np.float64], t_a: NDArray[np.float64], y: NDArray[np.float64], weight: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Bisquare robustness weights (as in LOWESS) from a pilot LWLR fit, ``(T, K)``.

    Cells whose target lies more than 6 median absolute residuals from the pilot fit (e.g. rays that
    graze a corner, where a few cm of pose error move the hit to another wall) get weight 0.
    """
    pilot = lwlr(t_r, t_a, t_r, t_a, y, weight, 0.4, 0.5, (0.0,))[0, 0]
    res = np.abs(y - pilot)
    ok = weight > 0
    scale = np.array([np.median(res[..., j][ok]) for j in range(y.shape[2])])
    u = res / (6 * np.maximum(scale, 1e-9))
    return weight * np.prod(np.where(u < 1, (1 - u * u) ** 2, 0.0), axis=2)


def _cv_loss(name: str, pred: NDArray[np.float64], y: NDArray[np.float64], m: NDArray[np.bool_]) -> tuple[float, float]:
    """Sum of absolute errors (in the parameter's natural unit) over ``m`` and the cell count."""
    p = _finish(name, pred)
    if name == "log_sigma":
        p, y = np.exp(p), np.exp(y)
    return float(np.abs(p - y)[m].sum()), float(m.sum())


def pose_fold_groups(poses: ArrayLike, decimals: int = 4) -> NDArray[np.int64]:
    """Group id of every row for leave-poses-out folds: rows at the same pose share one id.

    Readings of one pose are near-duplicates (the same rays, the same pose error), so a pose recorded in
    several rows must not be split between training and held-out folds. Poses equal after rounding to
    ``decimals`` (0.1 mm, 1e-4 rad) are one group; ids follow the first occurrence, so a log whose poses
    are all distinct gets ``0 .. P - 1`` (the folds of :func:`~sensor_envs.rng.fold_ids` with ``P`` rows).

    Args:
        poses: ``(P, 3)`` poses ``x, y, theta`` [m, rad].
        decimals: rounding before comparison.

    Returns:
        ``(P,)`` group ids.
    """
    key = np.round(np.atleast_2d(np.asarray(poses, dtype=np.float64)), decimals)
    if key.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))
    return rank[inv.ravel()].astype(np.int64)


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
            reading (:mod:`sensor_envs.lidar.readings`) always use the per-bearing bias.
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
        "extra_state": [InstanceOf(tuple, list)],  # details: check_extra_state
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
            per_reading: fit on individual readings (:func:`sensor_envs.lidar.readings.fit_per_reading`);
                default: for logs with one reading per pose and bearing (scans at moving poses), while
                repeated logs use the per-cell statistics.
            **reading_options: ``max_readings``, ``block_scans`` of the per-reading fit.

        Returns:
            ``self``, with ``tables_`` ``(n_params, K, n_r, n_alpha)``, ``param_names_``, ``range_grid_`` [m],
            ``alpha_grid_`` [rad], ``h_`` (per parameter: h_range, h_alpha, h_bearing, degree),
            ``cv_scores_``, ``bearings_`` [rad], ``spur_mu_``/``spur_sigma_`` [m], ``p_out_`` and
            ``training_`` (a summary of the log, no readings) set.

        Raises:
            ValueError: for bad hyperparameters or a log without map.
        """
        check_model_call(None, log=log)  # a LidarLog (fit(None) is an InputError, not an AttributeError)
        if per_reading or (per_reading is None and log.ranges.shape[2] < 2):
            from sensor_envs.lidar.readings import fit_per_reading

            fit_per_reading(self, log, **reading_options)
            fit_extra_terms(self, log)
            self.card_ = {}
            return self
        if reading_options:
            raise TypeError(f"fit: options {sorted(reading_options)} apply to the per-reading fit only")
        self._check_params_for(log)
        if self.extra_state:
            raise InputError(f"{log.source}: extra_state needs a scan log (one reading per scan and bearing)")
        segs = log.require_map()
        r_ap, a_ap = lidar_features(log.poses, log.bearings, segs, self.max_range)
        stats = cell_statistics(log, self.spur_above, split_spurious=self.variant == "extended")
        poses, _, corr_info = correct_poses(log, stats["mean"], stats["n_ok"], self.max_range)
        sd = pose_error_sd(log.poses, poses)
        self.pose_sd_: NDArray[np.float64] | None = sd  # the rigid pose error of :meth:`sample`
        if self.pose_correction:
            r, a = lidar_features(poses, log.bearings, segs, self.max_range)
        else:
            r, a = r_ap, a_ap
        groups = self._groups(stats, r)
        r0, a0 = np.where(np.isfinite(r), r, 0.0), np.nan_to_num(a)
        fold = self._folds(log)
        pooled = self._pool_bias(r0, a0, groups, fold) if self.bias_model == "pooled" else None
        self.h_, self.cv_scores_ = self._cross_validate(r0, a0, groups, fold)
        held_out = self._held_out_bias(stats, r_ap, a_ap, r0, a0, groups, fold)
        if pooled is None:
            self.bias_shrinkage_, self.cv_scores_["bias_shrinkage"] = choose_shrinkage(
                *held_out, fold, self.bias_shrinkage
            )
        else:
            held_out = self._choose_pooled(pooled, held_out, r_ap, a_ap, r0, a0, fold)
        if self.pose_correction:
            self.cv_scores_["pose_correction"] = corr_info
        self.cv_scores_["pose_error_sd"] = {"sd": [float(v) for v in sd], "rms_corrections": corr_info}
        self.bearings_ = log.bearings.copy()
        if self.variant == "extended":
            groups.append(self._tau_group(r0, a0, groups, stats["n_ok"], held_out))
            self.h_["tau2"] = list(self.h_["bias"])
        self._tabulate(r, a, groups)
        if pooled is not None:  # bias = G + lam L (L where bearing k has cells), same grid, float32 values
            j = self.param_names_.index("bias")
            self.tables_[j] = self._combined_bias(pooled, self.tables_[j], r0, a0)
        del self._bias_oof
        if self.variant == "seed":
            self.p_out_ = 0.0
        extended = self.variant == "extended"
        self.null_rho_ = self._fit_count_rho("p_null", "null_rho", stats, r) if extended else 0.0
        self.spur_rho_ = self._fit_count_rho("p_spur", "spur_rho", stats, r) if extended else 0.0
        del self._count_oof
        self._fit_spurious(log)
        self.training_ = {
            "source": Path(log.source).name,
            "n_poses": log.n_poses,
            "n_bearings": log.n_bearings,
            "n_readings": int((~np.isnan(log.ranges)).sum()),
            "null_fraction": float(np.nanmean(np.where(np.isnan(log.ranges), np.nan, log.ranges == 0))),
            "sha256_of_ranges": hashlib.sha256(np.ascontiguousarray(log.ranges).tobytes()).hexdigest(),
        }
        fit_extra_terms(self, log)
        self.card_ = {}
        return self

    def _groups(
        self, stats: dict[str, NDArray[np.float64]], r: NDArray[np.float64]
    ) -> list[tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.float64], bool]]:
        """Parameters sharing cell weights: ``(names, y (P, K, n), weight (P, K), robust)``.

        The extended variant down-weights outlying cells of ``bias``/``log_sigma`` (bisquare, LOWESS-style).
        """
        names = _PARAMS[self.variant]
        out = []
        for grp in (names[:-2], names[-2:]):
            ys, ms = zip(*(_targets(stats, r, n) for n in grp), strict=True)
            out.append(
                (grp, np.stack(ys, axis=-1), ms[0].astype(np.float64), self.variant == "extended" and grp[0] == "bias")
            )
        return out

    def _pool_bias(
        self, r: NDArray[np.float64], a: NDArray[np.float64], groups: list[Any], fold: NDArray[np.int64]
    ) -> dict[str, Any]:
        """The pooled trend ``G`` of the bias (``bias_model="pooled"``, :mod:`sensor_envs.lidar.bias_transfer`).

        Chooses ``G``'s kernel widths on the folds, tabulates it on all cells, and replaces the bias target of
        ``groups`` by its residual ``bias - G`` (the per-bearing part ``L`` the usual fit then learns). Returns
        ``G``'s widths, CV score and table, and the original target and cell weights.
        """
        i = next(j for j, g in enumerate(groups) if g[0][0] == "bias")
        names, y, weight, robust = groups[i]
        yb = y[..., 0].copy()
        w = _robust_weights(r, a, y[..., :1], weight) if robust else weight
        grid = self._grid()
        h, score = choose_global_widths(r, a, yb, w, fold, grid)
        table = global_table(r, a, yb, w, (h[0], h[1]), (int(h[3]),), grid)[0]
        y2 = y.copy()
        y2[..., 0] = np.where(weight > 0, yb - global_lookup(table, grid, r, a), 0.0)
        groups[i] = (names, y2, weight, robust)
        return {"h": h, "score": score, "table": table, "y": yb, "weight": weight, "robust": robust}

    def _combined_bias(
        self, pooled: dict[str, Any], local: NDArray[np.float64], r: NDArray[np.float64], a: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """The bias table ``(K, n_r, n_alpha)``: ``G + lam L``, ``L`` gated to each bearing's training span."""
        rg, ag = self.range_grid_, self.alpha_grid_
        qr, qa = (v.ravel() for v in np.meshgrid(rg, ag, indexing="ij"))
        gate = support_gate(qr[:, None], qa[:, None], r, a, pooled["weight"])  # (Q, K)
        lam = self.cv_scores_["bias_shrinkage"]["local_weight"]
        combined = pooled["table"][None] + lam * np.where(gate.T.reshape(local.shape), local, 0.0)
        return np.asarray(combined.astype(np.float32), dtype=np.float64)

    def _choose_pooled(
        self,
        pooled: dict[str, Any],
        held_out: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
        r_ap: NDArray[np.float64],
        a_ap: NDArray[np.float64],
        r: NDArray[np.float64],
        a: NDArray[np.float64],
        fold: NDArray[np.int64],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Local weight and shrinkage of the pooled bias by the folds; returns the held-out target, ``mu - r``, mask.

        The held-out ``G`` and ``L`` are refitted per fold on its training poses
        (:func:`~sensor_envs.lidar.bias_transfer.pooled_oof`) and read at the log's approximate poses.
        """
        y_ev, _, m_ev = held_out
        if not self.pose_correction:  # the groups' bias target is now the residual of G: score the bias itself
            y_ev, m_ev = pooled["y"], pooled["weight"] > 0
        query = (np.where(m_ev, r_ap, 0.0), np.nan_to_num(a_ap)) if self.pose_correction else (r, a)
        g_oof, l_oof = pooled_oof(
            (r, a, pooled["y"], pooled["weight"]),
            query,
            fold,
            pooled["h"],
            self.h_["bias"],
            self._grid(),
            _robust_weights if pooled["robust"] else None,
        )
        lam, s, report = choose_bias(y_ev, g_oof, l_oof, m_ev, fold, self.bias_shrinkage)
        report["global"] = {"h": pooled["h"], **pooled["score"]}
        self.bias_shrinkage_, self.cv_scores_["bias_shrinkage"] = s, report
        return y_ev, g_oof + lam * l_oof, m_ev

    def _tau_group(
        self,
        r: NDArray[np.float64],
        a: NDArray[np.float64],
        groups: list[Any],
        n_ok: NDArray[np.float64],
        held_out: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
    ) -> tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.float64], bool]:
        """Target of ``tau2`` (squared out-of-fold residual of the cell means) on the non-outlying cells.

        The residual is that of the shrunk ``mu`` (``bias_shrinkage_``) at the held-out cells' approximate
        poses (``held_out``: target, out-of-fold bias and mask of :meth:`_held_out_bias`). Also sets
        ``p_out_``: the fraction of in-range readings in cells whose mean is an outlier (bisquare weight 0),
        the weight of the uniform outlier component of :meth:`log_prob`.
        """
        _, y, weight, _ = next(g for g in groups if g[0][0] == "bias")
        w = _robust_weights(r, a, y[..., :1], weight)
        out = (weight > 0) & (w == 0)
        self.p_out_ = float(np.clip((n_ok * out).sum() / max((n_ok * (weight > 0)).sum(), 1), P_EPS, 0.5))
        y_ev, oof, m_ev = held_out
        e2 = np.where(m_ev, np.minimum((y_ev - (1 - self.bias_shrinkage_) * oof) ** 2, TAU_CLIP**2), 0.0)
        return ("tau2",), e2[..., None], w * m_ev, False

    def _held_out_bias(
        self,
        stats: dict[str, NDArray[np.float64]],
        r_ap: NDArray[np.float64],
        a_ap: NDArray[np.float64],
        r: NDArray[np.float64],
        a: NDArray[np.float64],
        groups: list[Any],
        fold: NDArray[np.int64],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Held-out bias target ``mean - r`` [m], its out-of-fold prediction and the cells scored, each ``(P, K)``.

        Every cell is scored at its log's (approximate) pose, as a user's poses are. Without pose correction
        these are the bandwidth CV's own out-of-fold predictions; with it, the chosen kernel widths are refitted
        per fold on the training folds' corrected cells and read at the held-out approximate features.
        """
        names, y, weight, robust = next(g for g in groups if g[0][0] == "bias")
        if not self.pose_correction:
            return y[..., 0], self._bias_oof, weight > 0
        y_ap, m_ap = _targets(stats, r_ap, "bias")
        q_r, q_a = np.where(m_ap, r_ap, 0.0), np.nan_to_num(a_ap)
        h_r, h_a, h_b, deg = self.h_["bias"]
        oof = np.zeros_like(y_ap)
        for f in np.unique(fold):
            tr, te = fold != f, fold == f
            w_tr = _robust_weights(r[tr], a[tr], y[tr], weight[tr]) if robust else weight[tr]
            pred = lwlr(q_r[te], q_a[te], r[tr], a[tr], y[tr][..., :1], w_tr, h_r, h_a, (h_b,), (int(deg),))
            oof[te] = pred[0, 0, ..., 0]
        return y_ap, oof, m_ap

    def _fit_count_rho(
        self, name: str, score: str, stats: dict[str, NDArray[np.float64]], r: NDArray[np.float64]
    ) -> float:
        """Intra-cell correlation of the outcome ``name`` (``p_null``: nulls, ``p_spur``: spurious returns).

        The ``RHO_GRID`` value maximising the beta-binomial likelihood of the training cells' counts of
        that outcome around its out-of-fold probability at the chosen kernel widths (``0`` = independent
        readings); the scores go to ``cv_scores_[score]``.
        """
        m = np.isfinite(r) & (stats["n"] > 0)
        n = stats["n"][m]
        k = np.round(stats[name][m] * n)
        q = self._count_oof[name][m]
        ll = [null_count_log_prob(k, n, q, rho).sum() for rho in RHO_GRID]
        self.cv_scores_[score] = {
            "ll_per_reading_best": float(max(ll) / n.sum()),
            "ll_per_reading_independent": float(ll[0] / n.sum()),
            "n_candidates": len(RHO_GRID),
        }
        return float(RHO_GRID[int(np.argmax(ll))])

    def _folds(self, log: LidarLog) -> NDArray[np.int64]:
        """Leave-poses-out fold of every row of ``log``; rows at one pose share a fold (:func:`pose_fold_groups`)."""
        return fold_ids(pose_fold_groups(log.poses), self.n_folds, random_state=self.random_state)

    def _cross_validate(
        self, r: NDArray[np.float64], a: NDArray[np.float64], groups: list[Any], fold: NDArray[np.int64]
    ) -> tuple[dict[str, list[float]], dict[str, Any]]:
        """Leave-poses-out CV (folds ``fold`` per row): per parameter, the kernel widths and degree of least MAE."""
        hb = (0.0,) if self.variant == "seed" else tuple(float(v) for v in self.h_bearing_grid)
        hra = list(itertools.product(self.h_range_grid, self.h_alpha_grid))
        degs = (1,) if self.variant == "seed" else tuple(int(v) for v in self.degree_grid)
        grid = [(h_r, h_a, h_b, deg) for h_r, h_a in hra for deg in degs for h_b in hb]
        per = len(degs) * len(hb)
        err = {n: np.zeros(len(grid)) for g in groups for n in g[0]}
        oof = np.zeros((len(grid),) + r.shape)  # out-of-fold bias predictions (for tau)
        counts = ("p_null", "p_spur")  # out-of-fold probabilities of the counted outcomes (for null_rho, spur_rho)
        oof_p = {n: np.zeros((len(grid),) + r.shape) for g in groups for n in g[0] if n in counts}
        cnt = {n: np.zeros(len(grid)) for g in groups for n in g[0]}
        for f in tqdm(range(self.n_folds), desc=f"CV lidar LWLR ({self.variant})", disable=not self.verbose):
            tr, te = fold != f, fold == f
            for names, y, weight, robust in groups:
                w_tr = _robust_weights(r[tr], a[tr], y[tr], weight[tr]) if robust else weight[tr]
                m_te = weight[te] > 0
                for i, (h_r, h_a) in enumerate(hra):
                    pred = lwlr(r[te], a[te], r[tr], a[tr], y[tr], w_tr, h_r, h_a, hb, degs)
                    pred = pred.reshape((per,) + pred.shape[2:])  # (degrees x bearing widths, Q, K, n)
                    if names[0] == "bias":
                        oof[i * per : (i + 1) * per, te] = pred[..., 0]
                    for j, n in enumerate(names):
                        if n in oof_p:
                            oof_p[n][i * per : (i + 1) * per, te] = _finish(n, pred[..., j])
                        for b in range(per):
                            e, c = _cv_loss(n, pred[b, ..., j], y[te][..., j], m_te)
                            err[n][i * per + b] += e
                            cnt[n][i * per + b] += c
        best, scores = {}, {}
        self._count_oof: dict[str, NDArray[np.float64]] = {}
        for n in err:
            mae = err[n] / np.maximum(cnt[n], 1)
            i = int(np.argmin(mae))
            best[n] = [float(v) for v in grid[i]]
            scores[n] = {"cv_mae_best": float(mae[i]), "cv_mae_worst": float(mae.max()), "n_candidates": len(grid)}
            if n == "bias":
                self._bias_oof = oof[i]
            if n in oof_p:
                self._count_oof[n] = oof_p[n][i]
        return best, scores

    def _grid(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n_r = int(np.ceil(self.max_range / self.table_range_step)) + 1
        return np.linspace(0.0, (n_r - 1) * self.table_range_step, n_r), np.linspace(
            0.0, np.pi / 2, self.table_alpha_steps
        )

    def _tabulate(self, r: NDArray[np.float64], a: NDArray[np.float64], groups: list[Any]) -> None:
        """Evaluate each parameter's LWLR on the ``(r, alpha)`` grid of every bearing."""
        rg, ag = self._grid()
        self.range_grid_, self.alpha_grid_ = rg, ag
        qr, qa = (v.ravel() for v in np.meshgrid(rg, ag, indexing="ij"))
        hit = np.isfinite(r)
        r0, a0 = np.where(hit, r, 0.0), np.nan_to_num(a)
        tables, names = [], []
        for grp, y, weight, robust in tqdm(groups, desc="tabulating", disable=not self.verbose):
            w = _robust_weights(r0, a0, y, weight) if robust else weight
            for j, n in enumerate(grp):
                h_r, h_a, h_b, deg = self.h_[n]
                rr, aa = np.where(w > 0, r, np.nan), np.where(w > 0, a, np.nan)
                with warnings.catch_warnings():  # bearings without any cell (blocked): whole grid
                    warnings.simplefilter("ignore", RuntimeWarning)
                    lo_r = np.nan_to_num(np.nanmin(rr, 0) - h_r, nan=0.0)
                    hi_r = np.nan_to_num(np.nanmax(rr, 0) + h_r, nan=self.max_range)
                    lo_a = np.nan_to_num(np.nanmin(aa, 0) - h_a, nan=0.0)
                    hi_a = np.nan_to_num(np.nanmax(aa, 0) + h_a, nan=np.pi / 2)
                q_r = np.clip(qr[:, None], lo_r[None], hi_r[None])
                q_a = np.clip(qa[:, None], lo_a[None], hi_a[None])
                v = _finish(
                    n, lwlr(q_r, q_a, r0, a0, y[..., j : j + 1], w, h_r, h_a, (h_b,), (int(deg),))[0, 0, ..., 0]
                )
                tables.append(v.T.reshape(-1, rg.size, ag.size))
                names.append(n)
        # (n_params, K, n_r, n_alpha), rounded to float32 (the file's dtype) so that save/load is exact
        self.tables_ = np.stack(tables).astype(np.float32).astype(np.float64)
        self.param_names_ = names

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

    def baseline(self) -> dict[str, float] | None:
        """Keyword arguments of the :class:`~sensor_envs.lidar.sensors.GaussianLidar` fitted with this model.

        From the card's ``gaussian_baseline``; ``None`` when the model keeps none.
        """
        g = self.__dict__.get("card_", {}).get("gaussian_baseline")
        if not isinstance(g, dict):
            return None
        keys = ("sigma0", "k_range", "k_incidence", "alpha_max", "p_null_floor")
        return {k: float(g[k]) for k in keys if k in g}

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
        r = self._nominal_ranges(r)
        hit = np.isfinite(r)
        rq = np.where(hit, r, self.range_grid_[-1])
        aq = np.nan_to_num(np.asarray(alpha, dtype=np.float64), nan=0.0)
        v = _bilinear(self.tables_, self.range_grid_, self.alpha_grid_, rq, aq)
        out = dict(zip(self.param_names_, v, strict=True))
        out["bias"] = (1.0 - getattr(self, "bias_shrinkage_", 0.0)) * out["bias"]  # toward the raycast
        if getattr(self, "extra_state_", ()) and not base_only:
            out = apply_extra(self, out, hit, extra)
        p_null = np.where(hit, out["p_null"], 1 - P_EPS)
        if "p_spur" in out:  # null takes precedence: the three outcomes keep >= P_EPS for in-range readings
            p_null = np.minimum(p_null, 1 - P_EPS - P_SPUR_EPS)
            p_spur = np.clip(out["p_spur"], P_SPUR_EPS, 1 - P_EPS - p_null)
        else:
            p_spur = np.zeros_like(rq)
        sigma = np.exp(out["log_sigma"]) if "log_sigma" in out else out["sigma"]
        tau = np.sqrt(np.maximum(out["tau2"], 0.0)) if "tau2" in out else np.zeros_like(rq)
        return {
            "p_null": p_null,
            "p_spur": p_spur,
            "mu": rq + out["bias"],
            "sigma": sigma,
            "tau": tau,
            "p_out": np.full(rq.shape, self.p_out_),
            "out_range": np.full(rq.shape, self.max_range),
            "null_rho": np.full(rq.shape, self.null_rho_),
            "spur_rho": np.full(rq.shape, self.spur_rho_),
        }

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
        shape = p["mu"].shape if shape is None else shape
        u = rng.random(shape)
        z = rng.standard_normal(shape)
        mu, p_null, p_spur = p["mu"], p["p_null"], p["p_spur"]
        if pose_uncertainty:
            cell = p["tau"].shape
            mu = np.where(
                rng.random(cell) < p["p_out"],
                rng.uniform(0.0, 1.0, cell) * p["out_range"],
                mu + p["tau"] * rng.standard_normal(cell),
            )
            p_null = _cell_probability(p_null, p.get("null_rho"), rng)
            p_spur = np.minimum(_cell_probability(p_spur, p.get("spur_rho"), rng), 1 - p_null)
        x = np.maximum(mu + p["sigma"] * z, 1e-4)
        if self.variant == "extended":
            spur = (u >= p_null) & (u < p_null + p_spur)
            x = np.where(spur, self.spur_mu_ + self.spur_sigma_ * z, x)
        return np.where(u < p_null, 0.0, x)

    def sample_scan(
        self, r: NDArray[np.float64], alpha: NDArray[np.float64], rng: np.random.Generator, null: float = 0.0
    ) -> NDArray[np.float64]:
        """Readings [m] (``0`` = null), one per cell: ``sample_from_params(params_from_features(r, alpha), rng)``.

        The simulator's hot path (no extra state, no pose uncertainty): with numba (the ``fast`` extra) three
        compiled passes over the cells, split where vectorisation stops: :func:`_scan_nodes` (where each cell
        reads; vectorised), :func:`_scan_gather` (the table reads), numpy's ``exp`` of the log-scales (an
        exponential per cell inside a loop cost ~6 ns a value), then :func:`_scan_readings` (the draw;
        vectorised). The same float64 operations in the same order as the two numpy methods and the same draws
        of ``rng``, so it returns the same bits.

        Args:
            r: ``(..., K)`` nominal ranges [m] (``inf``/NaN = no hit).
            alpha: ``(..., K)`` incidence [rad] (NaN where no hit).
            rng: a ``Generator`` (or :class:`~sensor_envs.rng.RowGenerators`) for the uniform and normal draws.
            null: the value of a null reading (``0``, the model's convention; the sensor interface's NaN).
        """
        nodes, gather, readings = compiled(_scan_nodes), compiled(_scan_gather), compiled(_scan_readings)
        if nodes is None or gather is None or readings is None or len(getattr(self, "extra_state_", ())) > 0:
            x = self.sample_from_params(self.params_from_features(r, alpha), rng)
            return x if null == 0 else np.where(x == 0, null, x)
        r = self._nominal_ranges(r)
        shape, k = r.shape, r.shape[-1]
        u = rng.random(shape)
        z = rng.standard_normal(shape)
        cells, grid, draw, log_scale = self._scan_constants()
        rows = np.ascontiguousarray(r.reshape(-1, k))
        node = np.empty(rows.shape, dtype=np.int64)
        wr, wa, rq = np.empty(rows.shape), np.empty(rows.shape), np.empty(rows.shape)
        alpha_rows = np.ascontiguousarray(np.asarray(alpha, dtype=np.float64).reshape(-1, k))
        nodes(*grid, rows, alpha_rows, node, wr, wa, rq)
        p_null, bias, scale, p_spur = (np.empty(rows.shape) for _ in range(4))
        gather(cells.ravel(), 4 * grid[1], node, wr, wa, p_null, bias, scale, p_spur)
        sigma = np.exp(scale, out=scale) if log_scale else scale  # numpy's exp, as params_from_features'
        u_rows, z_rows = np.ascontiguousarray(u.reshape(-1, k)), np.ascontiguousarray(z.reshape(-1, k))
        readings(p_null, bias, sigma, p_spur, rq, grid[4], u_rows, z_rows, *draw, float(null), rq)
        return rq.reshape(shape)

    def _scan_constants(
        self,
    ) -> tuple[
        NDArray[np.floating[Any]],
        tuple[int, int, float, float, float, float, float],
        tuple[float, bool, bool, float, float],
        bool,
    ]:
        """What :meth:`sample_scan`'s passes take besides the cells: ``(cells, grid, draw, log_scale)``.

        ``cells``: :meth:`_scan_tables` (the bias left out when shrunk fully to zero); ``grid``: :func:`_scan_nodes`'
        leading arguments ``(nr, na, r0, r1, r_last, a0, a1)`` (grid sizes, then nodes [m, rad]); ``draw``:
        :func:`_scan_readings`' ``(bias_weight, has_spur, spurious, spur_mu, spur_sigma)`` (``bias_weight = 1 -
        shrinkage``, 0 without a bias; spurious returns only in the extended variant); ``log_scale``: whether the
        scale slot holds ``log_sigma`` (then ``sigma = exp``).
        """
        shrink = float(getattr(self, "bias_shrinkage_", 0.0))
        cells, idx = self._scan_tables(with_bias=shrink != 1.0)
        rg, ag = self.range_grid_, self.alpha_grid_
        grid = (cells.shape[1], cells.shape[2], float(rg[0]), float(rg[1]), float(rg[-1]), float(ag[0]), float(ag[1]))
        extended, has_spur = self.variant == "extended", bool(idx[2] >= 0)
        draw = (
            1.0 - shrink if idx[0] >= 0 else 0.0,
            has_spur,
            extended and has_spur,
            float(self.spur_mu_) if extended else 0.0,
            float(self.spur_sigma_) if extended else 0.0,
        )
        return cells, grid, draw, bool(idx[3] == 1)

    def _nominal_ranges(self, r: ArrayLike) -> NDArray[np.float64]:
        """``r`` [m] as float64 ``(..., K)``, checked against the fitted model's ``K`` bearings."""
        self._check_fitted()
        r = np.asarray(r, dtype=np.float64)
        k = self.tables_.shape[1]
        if r.shape[-1] != k:
            raise ValueError(f"nominal_range: last axis has {r.shape[-1]} bearings, the model has {k}")
        return r

    def _scan_tables(self, with_bias: bool = True) -> tuple[NDArray[np.floating[Any]], NDArray[np.int64]]:
        """What :func:`_scan_gather` reads: the looked-up tables laid out ``(K, n_r, n_alpha, 4)``, and their slots.

        The 4 slots of a cell are ``p_null``, the bias, the scale (``log_sigma`` of the extended variant, ``sigma``
        of the seed's) and ``p_spur``; a parameter the model lacks (or the bias when ``with_bias`` is False: a
        bias shrunk fully to zero adds nothing) holds zeros and is marked absent in the index
        ``(bias slot, scale slot, p_spur slot, scale is log_sigma)`` by a slot of -1. The layout reads one cell's
        parameters together (one group of 4 per grid node) and holds no table the scan does not read; it is
        float32 when that is exact (tables are rounded to float32 at fit and in the file), so the lookup's
        float64 arithmetic gives the same bits from half the memory (a 64-robot step walks most of it, so its
        size sets the step's cache misses). Cached beside the array it was made from and rebuilt when ``tables_``
        is replaced (fit, load), so the hot path pays for neither.
        """
        cache = self.__dict__.setdefault("_scan_cache", {})
        hit = cache.get(with_bias)
        if hit is None or hit[0] is not self.tables_:
            names = list(self.param_names_)
            scale = "log_sigma" if "log_sigma" in names else "sigma"
            slots = ("p_null", "bias" if with_bias else "", scale, "p_spur")
            cells = np.zeros(self.tables_.shape[1:] + (len(slots),))
            for slot, name in enumerate(slots):
                if name in names:
                    cells[..., slot] = self.tables_[names.index(name)]
            if np.array_equal(cells.astype(np.float32), cells):  # fitted/loaded tables are float32 values
                cells = cells.astype(np.float32)  # exact, and half the memory a lookup walks
            idx = np.array(
                [1 if slots[1] in names else -1, 2, 3 if "p_spur" in names else -1, int(scale == "log_sigma")],
                dtype=np.int64,
            )
            hit = (self.tables_, np.ascontiguousarray(cells), idx)
            cache[with_bias] = hit
        return hit[1], hit[2]

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
        check_model_call(poses, map_segments, rng)
        p0 = np.atleast_2d(np.asarray(poses, dtype=np.float64))
        sd = getattr(self, "pose_sd_", None)
        sd = np.zeros(3) if sd is None else np.asarray(sd, dtype=np.float64)
        if np.any(sd > 0):
            p0 = p0 + rng.standard_normal(p0.shape) * sd
        p = self.params_full(p0, map_segments, extra)
        if n_repeats is None:
            return self.sample_from_params(p, rng)
        p = {k: v[..., None] for k, v in p.items()}
        p["p_null"] = _cell_probability(p["p_null"], p["null_rho"], rng)
        p["p_spur"] = np.minimum(_cell_probability(p["p_spur"], p["spur_rho"], rng), 1 - p["p_null"])
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
        check_model_call(poses, map_segments, ranges=ranges)
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
        """Header and arrays of the current format (:class:`~sensor_envs.sensor_model.SensorModel`)."""
        header: Header = {
            "params": self._saved_params(self),
            "h": self.h_,
            "param_names": self.param_names_,
            "spur_mu": self.spur_mu_,
            "spur_sigma": self.spur_sigma_,
            "p_out": self.p_out_,
            "null_rho": self.null_rho_,
            "spur_rho": self.spur_rho_,
            "bias_shrinkage": self.bias_shrinkage_,
            "pose_sd": None if (sd := getattr(self, "pose_sd_", None)) is None else [float(v) for v in sd],
            "card": {"training": self.training_, "cv_scores": self.cv_scores_},
        }
        arrays: Arrays = {
            "tables": self.tables_.astype(np.float32),
            "bearings": self.bearings_,
            "range_grid": self.range_grid_,
            "alpha_grid": self.alpha_grid_,
            "extra_mean": np.asarray(self.extra_mean_, dtype=np.float64),
            "extra_scale": np.asarray(self.extra_scale_, dtype=np.float64),
            "extra_coef": np.asarray(self.extra_coef_, dtype=np.float64),
        }
        return header, arrays

    @classmethod
    def _from_file(cls, path: Path, header: Header, arrays: Arrays) -> LidarLWLR:
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
        if model.param_names_ != list(_TABLES[model.variant]):
            raise ModelFileError(f"{path}: field 'param_names' is {model.param_names_} for variant {model.variant!r}")
        t = arr["tables"]
        want = (len(model.param_names_), arr["bearings"].size, arr["range_grid"].size, arr["alpha_grid"].size)
        if t.shape != want:
            raise ModelFileError(f"{path}: field 'tables' has shape {t.shape}, expected {want}")
        check_model_arrays(
            path, arr, {"extra_mean": ("f", 1, True), "extra_scale": ("f", 1, True), "extra_coef": ("f", 2, True)}
        )
        _check_extra_values(path, model, arr)
        _check_values(path, model, arr)
        model.tables_, model.bearings_ = t.astype(np.float64), arr["bearings"]
        model.range_grid_, model.alpha_grid_ = arr["range_grid"], arr["alpha_grid"]
        model.training_, model.cv_scores_ = card.pop("training", {}), card.pop("cv_scores", {})
        model.card_ = card
        return model

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> LidarLWLR:
        """Read a model file of any supported format (:meth:`SensorModel.load`); ``card_`` without ``training``."""
        header, arrays = cls.read_current(Path(path))
        return cls._from_file(Path(path), header, arrays)


# ------------------------------------------------------------------------------- format upgrades
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


LidarLWLR._UPGRADES = {1: _upgrade_1, 2: _upgrade_2, 3: _upgrade_3, 4: _upgrade_4, 5: _upgrade_5}


def _check_extra_values(path: str | os.PathLike[str], model: LidarLWLR, arr: dict[str, NDArray[Any]]) -> None:
    """Extra-state arrays: shapes matching ``extra_state``, finite, positive scales, bounded coefficients.

    Sets ``extra_state_``, ``extra_mean_``, ``extra_scale_``, ``extra_coef_`` (none for format < 3).
    """
    d = len(model.extra_state)
    if "extra_coef" not in arr:
        if d:
            raise ModelFileError(f"{path}: field 'extra_coef' is missing for extra_state {list(model.extra_state)}")
        model.extra_state_, model.extra_mean_, model.extra_scale_ = (), np.zeros(0), np.ones(0)
        model.extra_coef_ = np.zeros((3, 1))
        return
    check_shape(path, "extra_mean", arr["extra_mean"], (d,))
    check_shape(path, "extra_scale", arr["extra_scale"], (d,))
    check_shape(path, "extra_coef", arr["extra_coef"], (3, d + 1))
    check_finite(path, "extra_mean", arr["extra_mean"])
    check_positive(path, "extra_scale", arr["extra_scale"])
    check_range(path, "extra_coef", arr["extra_coef"], -MAX_COEF, MAX_COEF)
    model.extra_state_ = tuple(model.extra_state)
    model.extra_mean_, model.extra_scale_ = arr["extra_mean"].astype(np.float64), arr["extra_scale"].astype(np.float64)
    model.extra_coef_ = arr["extra_coef"].astype(np.float64)


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


def _cell_probability(
    p: NDArray[np.float64], rho: NDArray[np.float64] | None, rng: np.random.Generator
) -> NDArray[np.float64]:
    """One probability of an outcome (null, spurious) per cell: ``Beta(p c, (1 - p) c)``, mean ``p``.

    ``c = 1 / rho - 1``; ``p`` itself (and no draw) where ``rho`` is 0 or absent.
    """
    if rho is None or not np.any(rho > 0):
        return p
    c = 1 / np.maximum(rho, 1e-9) - 1
    q = np.clip(p, P_EPS, 1 - P_EPS)
    draw = rng.beta(q * c, (1 - q) * c)
    return np.where(rho > 0, draw, p)


def null_count_log_prob(k: ArrayLike, n: ArrayLike, p_null: ArrayLike, rho: ArrayLike) -> NDArray[np.float64]:
    """Log-probability of ``k`` nulls among a cell's ``n`` readings, beta-binomial with mean ``p_null``.

    Also scores the counts of spurious returns (``p_null`` = ``p_spur``, ``rho`` = ``spur_rho``).

    ``rho`` is the intra-cell correlation of nulls (``0`` = independent readings, binomial); shapes broadcast.
    """
    k, n = np.asarray(k, dtype=np.float64), np.asarray(n, dtype=np.float64)
    q = np.clip(np.asarray(p_null, dtype=np.float64), P_EPS, 1 - P_EPS)
    rho = np.asarray(rho, dtype=np.float64)
    out = sps.binom.logpmf(k, n, q)
    if not np.any(rho > 0):
        return out
    c = 1 / np.clip(rho, 1e-6, 1 - 1e-6) - 1
    return np.where(rho > 0, sps.betabinom.logpmf(k, n, q * c, (1 - q) * c), out)


def _norm_logpdf(
    x: NDArray[np.float64], mu: float | NDArray[np.float64], sigma: float | NDArray[np.float64]
) -> NDArray[np.float64]:
    z = (x - mu) / sigma
    return -0.5 * z * z - np.log(sigma) - 0.5 * np.log(2 * np.pi)


def mixture_log_prob(
    x: ArrayLike,
    p: dict[str, NDArray[np.float64]],
    spur_mu: float | NDArray[np.float64],
    spur_sigma: float | NDArray[np.float64],
) -> NDArray[np.float64]:
    """Log-probability of readings ``x`` [m] under ``null | spurious | Normal(mu, sigma)``.

    A null (``x == 0``) has probability ``p_null``; a reading has density
    ``(1 - p_null - p_spur) N(x; mu, sqrt(sigma^2 + tau^2)) + p_spur N(x; spur_mu, spur_sigma)`` [1/m]
    (``tau = 0`` when ``p`` has none); with ``p_out`` in ``p``, that normal is itself mixed with
    ``Uniform(0, out_range)`` at weight ``p_out`` (outlying cells). NaN stays NaN.
    """
    x = np.asarray(x, dtype=np.float64)
    s = np.sqrt(p["sigma"] ** 2 + p["tau"] ** 2) if "tau" in p else p["sigma"]
    main = _norm_logpdf(x, p["mu"], s)
    if "p_out" in p:
        with np.errstate(divide="ignore", invalid="ignore"):
            unif = np.where((x >= 0) & (x <= p["out_range"]), -np.log(p["out_range"]), -np.inf)
            main = np.logaddexp(np.log1p(-p["p_out"]) + main, np.log(p["p_out"]) + unif)
    main = np.log1p(-(p["p_null"] + p["p_spur"])) + main
    with np.errstate(divide="ignore", invalid="ignore"):
        spur = np.log(p["p_spur"]) + _norm_logpdf(x, spur_mu, spur_sigma)
        dens = np.logaddexp(main, spur)
    out = np.where(x == 0, np.log(p["p_null"]) + 0 * dens, dens)
    return np.where(np.isnan(x), np.nan, out)


def _scan_nodes(
    nr: int,
    na: int,
    r0: float,
    r1: float,
    r_last: float,
    a0: float,
    a1: float,
    r: NDArray[np.float64],
    alpha: NDArray[np.float64],
    node: NDArray[np.int64],
    wr: NDArray[np.float64],
    wa: NDArray[np.float64],
    rq: NDArray[np.float64],
) -> None:
    """Pass 1 of :meth:`LidarLWLR.sample_scan` over cells ``(P, K)``: where each cell's bilinear lookup reads.

    ``nr, na`` are the sizes of the range and incidence grids, ``r0, r1, r_last`` and ``a0, a1`` grid nodes
    [m, rad]; ``r, alpha`` the nominal ranges [m] (``inf``/NaN = no hit) and incidences [rad] (NaN = 0).
    Writes per cell the flat offset ``node`` of its lower node in :meth:`LidarLWLR._scan_tables`' layout
    ``(K, nr, na, 4)``, the weights ``wr, wa`` of the upper range and incidence nodes, and the queried range
    ``rq`` [m] (NaN for no hit, which is looked up at ``r_last``), in :func:`_bilinear_numpy`'s operations.
    Arithmetic only, no table read: the loop vectorises.
    """
    n_p, n_k = r.shape
    hi_r, hi_a = nr - 1 - 1e-9, na - 1 - 1e-9
    inv_dr, inv_da = 1.0 / (r1 - r0), 1.0 / (a1 - a0)
    for p in range(n_p):
        for k in range(n_k):
            rk = r[p, k]
            hit = math.isfinite(rk)
            rk = rk if hit else r_last
            ak = alpha[p, k]
            ak = 0.0 if math.isnan(ak) else ak
            fr = min(max((rk - r0) * inv_dr, 0.0), hi_r)
            fa = min(max((ak - a0) * inv_da, 0.0), hi_a)
            i, j = int(fr), int(fa)
            wr[p, k] = fr - i
            wa[p, k] = fa - j
            rq[p, k] = rk if hit else math.nan
            node[p, k] = ((k * nr + i) * na + j) * 4


def _scan_gather(
    flat: NDArray[np.floating[Any]],
    row: int,
    node: NDArray[np.int64],
    wr: NDArray[np.float64],
    wa: NDArray[np.float64],
    v0: NDArray[np.float64],
    v1: NDArray[np.float64],
    v2: NDArray[np.float64],
    v3: NDArray[np.float64],
) -> None:
    """Pass 2 of :meth:`LidarLWLR.sample_scan`: the bilinear values of the 4 table slots of every cell.

    ``flat`` is :meth:`LidarLWLR._scan_tables`' array raveled (float32 or float64, read as float64), ``row``
    the offset of the next range node (``4 na``), ``node, wr, wa`` :func:`_scan_nodes`' output. Writes slots
    0-3 (``p_null``, bias, scale, ``p_spur``) into ``v0..v3``, each :func:`~sensor_envs.lidar.kernel._bilinear`'s
    expression. The loop does only the table reads and their weighting (two runs of 8 adjacent values per
    cell); a per-cell gather does not vectorise, so everything that can is left to the passes around it.
    """
    nd, wrf, waf = node.ravel(), wr.ravel(), wa.ravel()
    o0, o1, o2, o3 = v0.ravel(), v1.ravel(), v2.ravel(), v3.ravel()
    for q in range(nd.size):
        c = nd[q]
        d = c + row
        w_r, w_a = wrf[q], waf[q]
        u_r, u_a = 1 - w_r, 1 - w_a
        x = (np.float64(flat[c]) * u_a + np.float64(flat[c + 4]) * w_a) * u_r
        o0[q] = x + (np.float64(flat[d]) * u_a + np.float64(flat[d + 4]) * w_a) * w_r
        x = (np.float64(flat[c + 1]) * u_a + np.float64(flat[c + 5]) * w_a) * u_r
        o1[q] = x + (np.float64(flat[d + 1]) * u_a + np.float64(flat[d + 5]) * w_a) * w_r
        x = (np.float64(flat[c + 2]) * u_a + np.float64(flat[c + 6]) * w_a) * u_r
        o2[q] = x + (np.float64(flat[d + 2]) * u_a + np.float64(flat[d + 6]) * w_a) * w_r
        x = (np.float64(flat[c + 3]) * u_a + np.float64(flat[c + 7]) * w_a) * u_r
        o3[q] = x + (np.float64(flat[d + 3]) * u_a + np.float64(flat[d + 7]) * w_a) * w_r


def _scan_readings(
    p_null: NDArray[np.float64],
    bias: NDArray[np.float64],
    sigma: NDArray[np.float64],
    p_spur: NDArray[np.float64],
    rq: NDArray[np.float64],
    r_last: float,
    u: NDArray[np.float64],
    z: NDArray[np.float64],
    bias_weight: float,
    has_spur: bool,
    spurious: bool,
    spur_mu: float,
    spur_sigma: float,
    null: float,
    out: NDArray[np.float64],
) -> None:
    """Pass 3 of :meth:`LidarLWLR.sample_scan`: readings [m] from the looked-up parameters and the draws ``u, z``.

    :meth:`LidarLWLR.params_from_features`' clipping and :meth:`LidarLWLR.sample_from_params`' selection,
    elementwise and branch-free (it vectorises; a branch on the null decision, which no predictor can guess,
    cost more than the work it skipped): a no-hit cell (``rq`` NaN) has ``p_null = 1 - P_EPS``; ``mu = r +
    bias_weight bias`` (``bias_weight`` 0 without a bias); ``null`` where ``u < p_null``, else
    ``spur_mu + spur_sigma z`` where ``u < p_null + p_spur`` (``spurious`` only), else ``max(mu + sigma z,
    1e-4)``. ``out`` may be ``rq``.
    """
    n0, b, s, n3, rr, uf, zf, o = (
        p_null.ravel(),
        bias.ravel(),
        sigma.ravel(),
        p_spur.ravel(),
        rq.ravel(),
        u.ravel(),
        z.ravel(),
        out.ravel(),
    )
    for q in range(o.size):
        r = rr[q]
        hit = r == r  # not NaN
        r = r if hit else r_last
        pn = n0[q] if hit else 1 - P_EPS
        if has_spur:
            pn = min(pn, 1 - P_EPS - P_SPUR_EPS)
        ps = min(max(n3[q], P_SPUR_EPS), 1 - P_EPS - pn) if spurious else 0.0
        x = max(r + bias_weight * b[q] + s[q] * zf[q], 1e-4)
        uq = uf[q]
        x = spur_mu + spur_sigma * zf[q] if uq < pn + ps else x
        o[q] = null if uq < pn else x


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
        raise ValueError(f"lidar: the learned lidar takes only 'model', got {sorted(kwargs)}")
    if isinstance(model, LidarLWLR):
        return LearnedLidar(model)
    return LearnedLidar(LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE) if model is None else model))
