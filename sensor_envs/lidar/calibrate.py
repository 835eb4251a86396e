"""Simulation-based calibration of the reference Neato rig to a real static-pose log.

The rig (:class:`~sensor_envs.lidar.rig.NeatoRig`) records at the real log's poses on the real log's
map; the same summary statistics (:func:`log_summary`) are computed on the real log and on the rig's
log, and a weighted discrepancy between them (:func:`discrepancy`) is minimised over the rig's
parameters with Nelder-Mead (``scipy.optimize``). Every simulation uses the same seed (common random
numbers: the rig draws a fixed number of random values whatever its parameters), so the objective
changes smoothly with the parameters and a rerun with the same seed gives the same rig.

The discrepancy (stated in every calibrated rig file's card) is

    D = sum_s w_s * mean_i ((stat_sim[s, i] - stat_real[s, i]) / scale_s) ** 2

over the statistics ``s`` of :data:`STATISTICS` (entries undefined in either log are skipped); all
weights ``w_s`` are 1, so ``D`` counts squared errors in units of each statistic's scale.

Parameters set directly from the real log (statistics, not fitted by simulation): the blocked
bearings (never returning: mean null fraction > 0.99 over the poses), the spurious value's median and
spread, the shape of sigma versus range (median cell standard deviation per 0.5 m bin), the per-bearing
spurious weights and the spurious factor per range (the real spurious cells are all within 1 m), the
null law (:func:`fit_null_law`: a logistic regression of the cells' null fractions on per-bearing
intercepts, per-bearing range slopes (their ridge chosen by leave-poses-out CV, :func:`choose_slope_ridge`) and
piecewise-linear tables of range and incidence; the real null rate is flat up to 0.9 rad of incidence,
then steep, and levels off beyond 2.5 m, which the former linear logit could not follow),
and the range bias shared by the bearings (:func:`fit_bias_law`: tables of the median cell deviation
versus range and incidence; the real readings fall short by 0.03-0.17 m beyond 2.5 m). The
Nelder-Mead search then runs over the remaining parameters (:data:`SEARCH`), per block of coordinates
on the terms of ``D`` they act on (:data:`BLOCKS`), and after it each sigma knot is rescaled until the
simulated sigma statistic meets the real one (:func:`refine_sigma`). Last, the spurious-prone law the search
used (per-bearing weights times a factor per 0.5 m range bin) is replaced by the near-cell law
(:func:`with_spur_near_law`): only cells nearer than a cut are prone, each bearing with its own share of
prone near cells, cut and shrinkage chosen by leave-poses-out CV (:func:`fit_spur_near_law`). The real
unit's spurious cells are near (all but four of 329 within 0.7 m) and, at a bearing, nearly all or none of its near
cells; the per-bin law spread them over every bearing's cells up to 1.25 m, so a model fitted on the rig
predicted spurious returns where the real unit has none (MAE p_spur +26 % against a model fitted on the
real cells). ``--spurious-only RIG`` applies that last step alone to an existing rig file.

Units: metres, radians (bearings and post distances in the statistics: degrees).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize
from tqdm.auto import tqdm

from sensor_envs.lidar.calibrate_laws import (
    BIAS_RANGE_KNOTS,
    NULL_INCIDENCE_KNOTS,
    NULL_RANGE_KNOTS,
    NULL_SLOPE_RIDGES,
    SPUR_NEAR_CUTS,
    SPUR_NEAR_PRIORS,
    _logistic,
    _null_law_params,
    _sigma_knots,
    _spur_range,
    _spur_weights,
    bearing_profile,
    choose_slope_ridge,
    fit_bias_law,
    fit_null_law,
    fit_spur_near_law,
    null_law_rig,
    with_spur_near_law,
)
from sensor_envs.lidar.calibrate_stats import (
    _NULL_TERMS,
    BLOCKS,
    NULL_GRID_ARC,
    NULL_GRID_CORR,
    RANGE_CENTRES,
    REAL_LOG_NAME,
    SEARCH,
    STATISTICS,
    discrepancy,
    load_real_log,
    log_summary,
    ranges_sha256,
)
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr import cell_statistics, lidar_features
from sensor_envs.lidar.rig import NeatoRig

__all__ = [
    "BIAS_RANGE_KNOTS",
    "NULL_INCIDENCE_KNOTS",
    "NULL_RANGE_KNOTS",
    "NULL_SLOPE_RIDGES",
    "SPUR_NEAR_CUTS",
    "SPUR_NEAR_PRIORS",
    "choose_slope_ridge",
    "fit_bias_law",
    "null_law_rig",
    "ranges_sha256",
    "STATISTICS",
    "SEARCH",
    "REAL_LOG_NAME",
    "log_summary",
    "discrepancy",
    "calibrate_rig",
    "load_real_log",
    "bearing_profile",
    "fit_null_law",
    "fit_spur_near_law",
    "respurious_rig",
]


class _Problem:
    """The rig as a function of the search coordinates, and the discrepancy of its recording."""

    def __init__(self, real_log: LidarLog, real: dict[str, Any], seed: int, base: NeatoRig) -> None:
        self.log, self.real, self.seed = real_log, real, seed
        r, a = lidar_features(real_log.poses, real_log.bearings, real_log.require_map(), base.max_range)
        blocked = np.zeros(real_log.n_bearings, dtype=bool)
        blocked[real["blocked"]] = True
        st = cell_statistics(real_log, 6.0, split_spurious=True)
        self.knots_r, self.knots = _sigma_knots(real)
        sv = real["spur_value"]
        self.base = dataclasses.replace(
            base,
            n_bearings=real_log.n_bearings,
            blocked=tuple(real["blocked"]),
            sigma_knots_r=self.knots_r,
            sigma_knots=self.knots,
            spur_value=(float(sv[0]), float(sv[1])) if sv[0] is not None else base.spur_value,
            spur_bearing_weight=_spur_weights(real),
            **_null_law_params(r, a, np.isfinite(r) & ~blocked[None] & (st["n"] > 0), st["p_null"]),
            **_spur_range(real),
            **fit_bias_law(r, a, np.where((st["n_ok"] >= 2) & (st["p_spur"] == 0), st["mean"] - r, np.nan)),
        )

    def x0(self, rig: NeatoRig) -> NDArray[np.float64]:
        """Search coordinates of a rig (the start of the search)."""
        return np.array(
            [
                np.log(max(rig.null_cell_corr, 0.9) / (1 - min(rig.null_cell_corr, 0.999))),
                np.log(max(rig.null_arc, 2.0)),
                rig.bias_mean * 1e3,
                np.log(max(rig.bias_sd * 1e3, 0.1)),
                np.log(max(rig.spur_prone, 1e-3) / (1 - min(rig.spur_prone, 1 - 1e-3))),
                np.log(max(rig.spur_frac[0], 1e-3) / (1 - min(rig.spur_frac[0], 1 - 1e-3))),
                np.log(max(rig.pose_sd[0] * 100, 0.01)),
                np.log(max(np.rad2deg(rig.pose_sd[1]), 0.01)),
                np.log(max(rig.map_sd * 100, 0.01)),
                0.0,
                np.log(max(rig.out_cell_rate, 0.03) / (1 - min(rig.out_cell_rate, 0.99))),
                np.log(max(rig.out_cell_arc, 2.0)),
            ]
        )

    def rig(self, x: NDArray[np.float64]) -> NeatoRig:
        """The rig at search coordinates ``x`` (the null law and per-bearing effects are fixed statistics)."""
        corr, arc = float(np.clip(_logistic(np.array(x[0])), 0.0, 0.9999)), float(min(np.exp(x[1]), 60.0))
        scale = float(np.exp(x[9]))
        return dataclasses.replace(
            self.base,
            null_cell_corr=round(corr, 5),
            null_arc=round(arc, 3),
            bias_mean=round(float(np.clip(x[2], -100, 100)) * 1e-3, 6),
            bias_sd=round(float(min(np.exp(x[3]), 100.0)) * 1e-3, 6),
            spur_prone=round(float(_logistic(np.array(x[4]))), 5),
            spur_frac=(round(float(_logistic(np.array(x[5]))), 4), 1.0),
            pose_sd=(
                round(float(min(np.exp(x[6]), 100.0)) / 100, 5),
                round(float(np.deg2rad(min(np.exp(x[7]), 90))), 5),
            ),
            map_sd=round(float(min(np.exp(x[8]), 100.0)) / 100, 5),
            sigma_knots=tuple(float(f"{v * scale:.3g}") for v in self.knots),
            out_cell_rate=round(float(np.clip(_logistic(np.array(x[10])), 0.0, 0.5)), 5),
            out_cell_arc=round(float(min(np.exp(x[11]), 60.0)), 3),
        )

    def evaluate(self, rig: NeatoRig, seed: int | None = None) -> tuple[dict[str, float], dict[str, Any]]:
        """Discrepancy terms and statistics of ``rig`` recorded at the real poses (seed: the CRN seed)."""
        return recorded_discrepancy(rig, self.log, self.real, self.seed if seed is None else seed)


def recorded_discrepancy(
    rig: NeatoRig, real_log: LidarLog, real: dict[str, Any], seed: int
) -> tuple[dict[str, float], dict[str, Any]]:
    """Discrepancy terms (vs the real statistics ``real``) and statistics of ``rig`` recorded at the real poses.

    ``seed`` seeds the recording (common random numbers: the same seed, the same draws for every rig).
    """
    log, _ = rig.record(
        real_log.require_map(),
        np.random.default_rng(seed),
        poses=real_log.poses,
        repeats=real_log.ranges.shape[2],
    )
    stats = log_summary(log, rig.max_range)
    return discrepancy(stats, real), stats


SIGMA_REFINE_STEPS = 4
"""Fixed-point steps of :func:`refine_sigma`."""


def refine_sigma(prob: _Problem, rig: NeatoRig, steps: int = SIGMA_REFINE_STEPS) -> NeatoRig:
    """``rig`` with each knot of sigma versus range rescaled until the simulated statistic meets the real one.

    Per 0.5 m bin the knot is multiplied by ``exp(real - simulated)`` of ``sigma_range`` (the log median cell
    standard deviation; factor clipped to [1/3, 3]), ``steps`` times; the knots outside the bins follow their
    neighbours. The median of quantised readings (1 mm) is not the noise's sigma: at short range the real
    cells mostly read one value, which a single scale over all knots cannot match. Keeps the step that
    lowers the whole discrepancy most (possibly none).
    """
    real = np.asarray(prob.real["sigma_range"], dtype=np.float64)
    d, stats = prob.evaluate(rig)
    best = (d["total"], rig)
    for _ in range(steps):
        sim = np.asarray(stats["sigma_range"], dtype=np.float64)
        kv = np.asarray(rig.sigma_knots, dtype=np.float64).copy()
        kr = np.asarray(rig.sigma_knots_r, dtype=np.float64)
        ok = np.isfinite(real) & np.isfinite(sim)
        if not ok.any():
            break
        f = np.exp(np.clip(real[ok] - sim[ok], -np.log(3), np.log(3)))
        # knots at bin centres take their bin's factor; the others the nearest one's
        kv = kv * np.interp(kr, RANGE_CENTRES[ok], f)
        rig = dataclasses.replace(rig, sigma_knots=tuple(float(f"{v:.3g}") for v in np.maximum(kv, 1e-6)))
        d, stats = prob.evaluate(rig)
        if d["total"] < best[0]:
            best = (d["total"], rig)
    return best[1]


def calibrate_rig(
    real_log: LidarLog,
    *,
    seed: int = 0,
    max_evals: int = 150,
    start: NeatoRig | None = None,
    progress: bool = True,
    callback: Callable[[int, float], None] | None = None,
) -> tuple[NeatoRig, dict[str, Any]]:
    """Fit the rig's parameters to a real static-pose log (module docstring: statistics, discrepancy, search).

    Args:
        real_log: the real log (``(P, K, R)`` ranges with ``R >= 2``, approximate poses, map).
        seed: seed of the common random numbers of every simulation.
        max_evals: most discrepancy evaluations of the Nelder-Mead search.
        start: rig the search starts from (default: :class:`NeatoRig` defaults, also the "before"); its
            per-bearing bias mean and spread start at the real log's statistics.
        progress: show a tqdm bar.
        callback: called with ``(evaluation, discrepancy)`` after each evaluation.

    Returns:
        ``(rig, card)``: the calibrated rig and its card (data identity, discrepancy per statistic before
        and after, on the search's seed and on a fresh seed, the search's settings and time).
    """
    t0 = time.perf_counter()
    before_rig = start or NeatoRig()
    real = log_summary(real_log, before_rig.max_range)
    prob = _Problem(real_log, real, seed, before_rig)
    before, before_stats = prob.evaluate(before_rig)
    x0 = prob.x0(before_rig)
    if real["bias_mean"] is not None:  # start the bias at the real per-bearing statistics (the search refines it)
        x0[2], x0[3] = real["bias_mean"] * 1e3, np.log(max(real["bias_sd"] * 1e3, 0.1))
    steps = np.array([0.5, 0.5, 2.0, 0.5, 0.7, 0.7, 0.5, 0.5, 0.7, 0.2, 0.7, 0.5])
    n_eval = 0
    best = (np.inf, x0)
    bar = tqdm(total=max_evals, desc="calibrate lidar rig", disable=not progress)

    def objective(x: NDArray[np.float64], terms: tuple[str, ...] | None = None) -> float:
        nonlocal n_eval, best
        dd = prob.evaluate(prob.rig(x))[0]
        n_eval += 1
        if dd["total"] < best[0]:
            best = (dd["total"], np.array(x))
        bar.update(1)
        bar.set_postfix(D=f"{best[0]:.3g}")
        if callback is not None:
            callback(n_eval, dd["total"])
        return dd["total"] if terms is None else float(sum(dd[t] for t in terms))

    converged = []
    x_cur = x0.copy()
    for block, share, terms in BLOCKS:  # nearly separable: Nelder-Mead per block of coordinates, then all together
        idx = np.asarray(block, dtype=int)
        budget = max(int(share * max_evals), len(idx) + 2)
        budget = min(budget, max_evals - n_eval)
        if budget < len(idx) + 2:
            break
        x_start = (best[1] if terms is None else x_cur).copy()

        def sub(
            y: NDArray[np.float64],
            idx: NDArray[np.int64] = idx,
            x_start: NDArray[np.float64] = x_start,
            terms: tuple[str, ...] | None = terms,
        ) -> float:
            x = x_start.copy()
            x[idx] = y
            return objective(x, terms)

        y0 = x_start[idx]
        if terms == _NULL_TERMS:  # rugged in the persistence: start from the best of a coarse grid
            grid = [np.array([c, a]) for c in NULL_GRID_CORR for a in NULL_GRID_ARC]
            y0 = min(grid, key=sub)
            budget = max(budget - len(grid), len(idx) + 2)
        simplex = np.vstack([y0, y0 + np.diag(steps[idx])])
        res = minimize(
            sub,
            y0,
            method="Nelder-Mead",
            options={"maxfev": budget, "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-3},
        )
        x_cur = x_start.copy()
        x_cur[idx] = res.x
        converged.append(bool(res.success))
    bar.close()
    rig = refine_sigma(prob, prob.rig(best[1]))
    rig, spur_law = with_spur_near_law(rig, real_log)
    after, after_stats = prob.evaluate(rig)
    fresh, _ = prob.evaluate(rig, seed=seed + 1)
    fresh_before, _ = prob.evaluate(before_rig, seed=seed + 1)
    card = {
        "calibrated_against": _data_identity(real_log),
        "procedure": __doc__.strip(),
        "discrepancy": {
            "formula": "D = sum_s w_s * mean_i ((stat_sim[s, i] - stat_real[s, i]) / scale_s) ** 2, w_s = 1",
            "statistics": {k: {"scale": v[0], "definition": v[1]} for k, v in STATISTICS.items()},
        },
        "before": {"rig": "NeatoRig() defaults", "seed": seed, "per_statistic": before},
        "after": {"rig": "this file", "seed": seed, "per_statistic": after},
        "before_fresh_seed": {"seed": seed + 1, "per_statistic": fresh_before},
        "after_fresh_seed": {"seed": seed + 1, "per_statistic": fresh},
        "statistics": {
            k: {"real": real[k], "before": before_stats[k], "after": after_stats[k]}
            for k in STATISTICS
            if k not in ("p_null_bearing", "spur_bearing")
        },
        "spurious_law": spur_law,
        "search": {
            "method": "scipy.optimize.minimize Nelder-Mead, common random numbers",
            "coordinates": list(SEARCH),
            "evaluations": n_eval,
            "blocks": [[SEARCH[i] for i in blk] for blk, _, _ in BLOCKS],
            "block_terms": [list(t) if t is not None else "total" for _, _, t in BLOCKS],
            "block_converged": converged,
            "seed": seed,
            "seconds": round(time.perf_counter() - t0, 1),
        },
    }
    return rig, card


def _data_identity(real_log: LidarLog) -> dict[str, Any]:
    """What a rig card names as the real data it was calibrated against (file, sha256 of the ranges, shape)."""
    return {
        "file": Path(real_log.source).name,
        "sha256_of_ranges": ranges_sha256(real_log),
        "sha256_convention": "sha256 of the ranges array as loaded by sensor_envs.lidar.log.load_log "
        "(float64, C order; 0 = null, NaN = padding)",
        "shape": list(real_log.ranges.shape),
    }


def respurious_rig(
    real_log: LidarLog, rig: NeatoRig, source: str | Path, *, seed: int = 0, card: dict[str, Any] | None = None
) -> tuple[NeatoRig, dict[str, Any]]:
    """``rig`` with only its spurious-prone law re-derived from a real log (:func:`with_spur_near_law`), no search.

    Args:
        real_log: the real static-pose log.
        rig: the rig to start from (e.g. a rig file calibrated before the near-cell law existed).
        source: where ``rig`` came from (named in the card).
        seed: seed of the common random numbers of the before/after discrepancies.
        card: ``rig``'s own card (kept, its discrepancies replaced by this rig's).

    Returns:
        ``(rig, card)``: the card holds ``rig``'s card with ``after`` / ``after_fresh_seed`` measured on the new
        rig and a ``spurious_refit`` entry (the law's choice, the discrepancy before and after it).
    """
    real = log_summary(real_log, rig.max_range)
    before, _ = recorded_discrepancy(rig, real_log, real, seed)
    new, law = with_spur_near_law(rig, real_log)
    after, after_stats = recorded_discrepancy(new, real_log, real, seed)
    fresh, _ = recorded_discrepancy(new, real_log, real, seed + 1)
    out = dict(card or {})
    out.update(
        {
            "calibrated_against": _data_identity(real_log),
            "after": {"rig": "this file", "seed": seed, "per_statistic": after},
            "after_fresh_seed": {"seed": seed + 1, "per_statistic": fresh},
            "spurious_refit": {
                "from_rig": str(source),
                "procedure": (with_spur_near_law.__doc__ or "").strip(),
                "law": law,
                "seed": seed,
                "before": {"rig": str(source), "per_statistic": before},
                "after": {"rig": "this file", "per_statistic": after},
            },
        }
    )
    if "statistics" in out:
        out["statistics"] = {
            k: {**v, "after": after_stats[k]} for k, v in out["statistics"].items() if k in after_stats
        }
    return new, out
