"""The per-reading law of :class:`~sensor_envs.lidar.lwlr.LidarLWLR`: the mixture density and the null counts.

A reading is a null (``p_null``), a spurious far return (``p_spur``, ``Normal(spur_mu, spur_sigma)``) or
``Normal(mu, sigma)`` (:func:`mixture_log_prob`); a cell's null count over its repeats is beta-binomial with mean
``p_null`` and intra-cell correlation ``rho`` (:func:`null_count_log_prob`, :func:`cell_probability`). The
law's parameters come from the model's tables (:func:`reading_params`); :func:`draw_readings` draws from them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats as sps

from sensor_envs.lidar import scan_sampler
from sensor_envs.lidar.extra_state import apply_extra
from sensor_envs.lidar.local_regression import P_EPS, P_SPUR_EPS, _bilinear

if TYPE_CHECKING:
    from sensor_envs.lidar.lwlr import LidarLWLR

__all__ = ["mixture_log_prob", "null_count_log_prob", "cell_probability", "reading_params", "draw_readings"]


def cell_probability(
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


def reading_params(
    model: LidarLWLR, r: ArrayLike, alpha: ArrayLike, extra: ArrayLike | None = None, base_only: bool = False
) -> dict[str, NDArray[np.float64]]:
    """The law's parameters at features ``r``, ``alpha`` by the fitted ``model``'s table lookup.

    What :meth:`LidarLWLR.params_from_features <sensor_envs.lidar.lwlr.LidarLWLR.params_from_features>`
    returns (see there for shapes and units).
    """
    r = scan_sampler.nominal_ranges(model, r)
    hit = np.isfinite(r)
    rq = np.where(hit, r, model.range_grid_[-1])
    aq = np.nan_to_num(np.asarray(alpha, dtype=np.float64), nan=0.0)
    v = _bilinear(model.tables_, model.range_grid_, model.alpha_grid_, rq, aq)
    out = dict(zip(model.param_names_, v, strict=True))
    out["bias"] = (1.0 - getattr(model, "bias_shrinkage_", 0.0)) * out["bias"]  # toward the raycast
    if getattr(model, "extra_state_", ()) and not base_only:
        out = apply_extra(model, out, hit, extra)
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
        "p_out": np.full(rq.shape, model.p_out_),
        "out_range": np.full(rq.shape, model.max_range),
        "null_rho": np.full(rq.shape, model.null_rho_),
        "spur_rho": np.full(rq.shape, model.spur_rho_),
    }


def draw_readings(
    model: LidarLWLR,
    p: dict[str, NDArray[np.float64]],
    rng: np.random.Generator,
    shape: tuple[int, ...] | None = None,
    pose_uncertainty: bool = False,
) -> NDArray[np.float64]:
    """Readings [m] (``0`` = null) drawn from the law's parameters ``p`` broadcast to ``shape``.

    What :meth:`LidarLWLR.sample_from_params <sensor_envs.lidar.lwlr.LidarLWLR.sample_from_params>` returns (see
    there for the draw with ``pose_uncertainty``).
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
        p_null = cell_probability(p_null, p.get("null_rho"), rng)
        p_spur = np.minimum(cell_probability(p_spur, p.get("spur_rho"), rng), 1 - p_null)
    x = np.maximum(mu + p["sigma"] * z, 1e-4)
    if model.variant == "extended":
        spur = (u >= p_null) & (u < p_null + p_spur)
        x = np.where(spur, model.spur_mu_ + model.spur_sigma_ * z, x)
    return np.where(u < p_null, 0.0, x)
