"""Per-reading validation of lidar models on logs without repeats (time series of single scans).

For each model (the fitted one, ``ideal`` and ``gaussian``). Definitions (written into every ``report.json``):

* ``nll_per_reading``: mean over the log's readings of ``-log p_null`` (nulls) or minus the log
  density [1/m] of the reading; ``nll_null`` / ``nll_return`` split it by outcome (lower is better).
* Null-rate calibration: readings binned by predicted ``p_null`` (edges ``CAL_EDGES``); per bin the
  mean predicted and the observed null fraction and the count; ``ece`` = count-weighted mean
  ``|predicted - observed|`` (ideal: 0).
* PIT of non-null readings: the model's CDF of a reading given that it is not null, at the reading
  (``u`` in ``[0, 1]``); histogram in 10 bins as fractions (ideal: 0.1 each); ``pit_ks`` = the
  largest distance between the empirical CDF of ``u`` and the uniform one (ideal: 0).
* Lag-1 autocorrelation of residuals per bearing, between consecutive scans: of the normal scores
  ``Phi^-1(u)`` of the non-null readings (``acf1_range``) and of the null residuals
  ``null - p_null`` (``acf1_null``); per bearing and the mean over bearings (ideal: 0, white residuals).
* Baselines: ``ideal`` has ``mu = r``, ``sigma = 1 mm`` and ``p_null = P_EPS`` on a hit; ``gaussian``
  is :class:`~sensor_envs.lidar.gaussian.GaussianLidar` refitted per reading to the training part
  (:func:`fit_gaussian_readings`).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import stats as sps
from scipy.optimize import nnls

from sensor_envs.inputs import InputError
from sensor_envs.lidar.fit_readings import check_map_covers
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr import P_EPS, SIGMA_FLOOR, LidarLWLR, mixture_log_prob
from sensor_envs.lidar.mapping import map_features
from sensor_envs.lidar.sensors import GaussianLidar
from sensor_envs.outputs import write_json

__all__ = ["fit_gaussian_readings", "reading_metrics", "validate_readings", "CAL_EDGES", "GAUSS_RESIDUAL_CUT"]

CAL_EDGES = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0)
GAUSS_RESIDUAL_CUT = 1.0
"""Readings farther than this from the nominal range [m] are left out of the Gaussian baseline's fit."""
Params = dict[str, NDArray[np.float64]]
IDEAL_SIGMA = 1e-3


def baseline_params(
    name: str, r: NDArray[np.float64], a: NDArray[np.float64], gaussian: GaussianLidar | None = None
) -> Params:
    """Parameters ``p_null, p_spur, mu, sigma`` ``(..., K)`` of the ``"ideal"`` or ``"gaussian"`` baseline."""
    hit = np.isfinite(r)
    mu = np.where(hit, r, 0.0)
    if name == "ideal":
        p_null, sigma = np.where(hit, P_EPS, 1 - P_EPS), np.full(r.shape, IDEAL_SIGMA)
    elif name == "gaussian":
        g = gaussian or GaussianLidar()
        p_null = np.where(hit, np.clip(g.p_null_floor, P_EPS, 1 - P_EPS), 1 - P_EPS)
        sigma = np.maximum(np.nan_to_num(g.sigma(r, a), nan=1.0), SIGMA_FLOOR)
    else:
        raise InputError(f"baseline: expected 'ideal' or 'gaussian', got {name!r}")
    return {"p_null": p_null, "p_spur": np.zeros(r.shape), "mu": mu, "sigma": sigma, "tau": np.zeros(r.shape)}


def fit_gaussian_readings(
    log: LidarLog, r: NDArray[np.float64], a: NDArray[np.float64], spur_above: float = 6.0
) -> GaussianLidar:
    """The Gaussian baseline refitted on individual readings.

    ``sigma0, k_range, k_incidence``: non-negative least squares of ``sqrt(pi / 2) |x - r|`` (whose mean
    is ``sigma`` for a normal error) on ``1, r^2, r tan(alpha)`` over the in-range readings within
    :data:`GAUSS_RESIDUAL_CUT` of the nominal range; ``p_null_floor``: the null fraction on hit rays.
    """
    x = log.ranges[..., 0] if log.ranges.shape[2] == 1 else log.ranges.mean(2)
    hit = np.isfinite(r) & ~np.isnan(x)
    e = np.abs(x - np.where(hit, r, 0.0))
    m = hit & (x > 0) & (x <= spur_above) & (e < GAUSS_RESIDUAL_CUT)
    base = GaussianLidar()
    rm = r[m]
    design = np.column_stack([np.ones(m.sum()), rm**2, rm * base.tan_incidence(a[m])])
    coef, _ = nnls(design, np.sqrt(np.pi / 2) * e[m])
    return GaussianLidar(
        sigma0=float(max(coef[0], SIGMA_FLOOR)),
        k_range=float(coef[1]),
        k_incidence=float(coef[2]),
        p_null_floor=float(np.clip((x[hit] == 0).mean(), P_EPS, 1 - P_EPS)),
    )


def _pit(x: NDArray[np.float64], p: Params, spur: tuple[float, float]) -> NDArray[np.float64]:
    """CDF of a non-null reading at ``x`` under ``null | spurious | main`` (see :func:`mixture_log_prob`)."""
    s = np.sqrt(p["sigma"] ** 2 + p.get("tau", 0.0) ** 2)
    f = sps.norm.cdf((x - p["mu"]) / s)
    if "p_out" in p:
        f = (1 - p["p_out"]) * f + p["p_out"] * np.clip(x / p["out_range"], 0.0, 1.0)
    pn, ps = p["p_null"], p["p_spur"]
    fs = sps.norm.cdf((x - spur[0]) / spur[1])
    return np.clip(((1 - pn - ps) * f + ps * fs) / np.maximum(1 - pn, 1e-12), 0.0, 1.0)


def _acf1(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """Lag-1 correlation per column of ``z (S, K)`` over consecutive rows where both are present (NaN if < 3)."""
    a, b = z[:-1], z[1:]
    ok = np.isfinite(a) & np.isfinite(b)
    n = ok.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        a0 = np.where(ok, a - np.nanmean(np.where(ok, a, np.nan), 0), np.nan)
        b0 = np.where(ok, b - np.nanmean(np.where(ok, b, np.nan), 0), np.nan)
        c = np.nansum(a0 * b0, 0) / np.sqrt(np.nansum(a0**2, 0) * np.nansum(b0**2, 0))
    return np.where(n >= 3, c, np.nan)


def reading_metrics(x: NDArray[np.float64], p: Params, spur: tuple[float, float]) -> dict[str, Any]:
    """Per-reading metrics (see the module docstring) of readings ``x (S, K)`` [m] under parameters ``p``."""
    valid = ~np.isnan(x)
    null = valid & (x == 0)
    ret = valid & (x > 0)
    lp = mixture_log_prob(x, p, spur[0], spur[1])
    edges = np.asarray(CAL_EDGES)
    pn = p["p_null"]
    b = np.clip(np.searchsorted(edges, pn, side="right") - 1, 0, edges.size - 2)
    cal = []
    ece = 0.0
    for i in range(edges.size - 1):
        m = valid & (b == i)
        if m.any():
            pred, obs = float(pn[m].mean()), float(null[m].mean())
            cal.append(
                {"bin": [float(edges[i]), float(edges[i + 1])], "predicted": pred, "observed": obs, "n": int(m.sum())}
            )
            ece += m.sum() * abs(pred - obs)
    u = _pit(np.where(ret, x, 0.0), p, spur)
    uu = u[ret]
    hist = np.histogram(uu, bins=10, range=(0, 1))[0] / max(uu.size, 1)
    ks = float(sps.kstest(uu, "uniform").statistic) if uu.size else float("nan")
    z = np.where(ret, sps.norm.ppf(np.clip(u, 1e-6, 1 - 1e-6)), np.nan)
    nres = np.where(valid, null - pn, np.nan)
    acf_r, acf_n = _acf1(z), _acf1(nres)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = {
            "nll_per_reading": float(-lp[valid].mean()),
            "nll_null": float(-lp[null].mean()) if null.any() else None,
            "nll_return": float(-lp[ret].mean()) if ret.any() else None,
            "n_readings": int(valid.sum()),
            "null_fraction": float(null.sum() / max(valid.sum(), 1)),
            "calibration": cal,
            "ece": float(ece / max(valid.sum(), 1)),
            "pit_hist": [float(v) for v in hist],
            "pit_ks": ks,
            "acf1_range_mean": float(np.nanmean(acf_r)),
            "acf1_null_mean": float(np.nanmean(acf_n)),
            "acf1_range_per_bearing": [None if not np.isfinite(v) else float(v) for v in acf_r],
            "acf1_null_per_bearing": [None if not np.isfinite(v) else float(v) for v in acf_n],
            "nll_per_bearing": [
                float(v) if np.isfinite(v) else None for v in -np.nanmean(np.where(valid, lp, np.nan), 0)
            ],
        }
    return out


def validate_readings(
    model: LidarLWLR,
    log: LidarLog,
    out_dir: str | os.PathLike[str] | None,
    gaussian: GaussianLidar | None = None,
) -> dict[str, Any]:
    """Per-reading validation of ``model`` and both baselines on ``log`` (held-out scans).

    Args:
        model: the fitted model.
        log: the held-out log (its poses and map give the features); repeats are flattened to scans.
        out_dir: where ``report.json``, ``report.md`` and ``per_reading.png`` go (``None``: no files).
        gaussian: the Gaussian baseline (default: the model card's, else the defaults).

    Raises:
        LidarLogError: when the log has no map or the map does not cover its scans.
    """
    r, a = map_features(log.poses, log.bearings, log.require_map(), model.max_range)
    check_map_covers(log, r, model.max_range)
    if gaussian is None:
        gaussian = model.baseline()
    p_model = model.params_from_features(r, a)
    params = {
        f"model_{model.variant}": (p_model, (model.spur_mu_, model.spur_sigma_)),
        "ideal": (baseline_params("ideal", r, a), (0.0, 1.0)),
        "gaussian": (baseline_params("gaussian", r, a, gaussian), (0.0, 1.0)),
    }
    reps = log.ranges.shape[2]
    metrics = {}
    for name, (p, spur) in params.items():
        ms = [reading_metrics(log.ranges[..., j], p, spur) for j in range(reps)]
        metrics[name] = ms[0] if reps == 1 else _pool(ms)
    report = {
        "log": log.source,
        "n_scans": log.n_poses,
        "model_training": model.training_,
        "model_h": model.h_,
        "gaussian_baseline": vars(gaussian) if gaussian else vars(GaussianLidar()),
        "definitions": __doc__.split("Definitions (written into every ``report.json``):")[1].strip(),
        "metrics": metrics,
    }
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "report.json", report)
        (out / "report.md").write_text(readings_markdown(metrics, Path(str(log.source)).name, log.n_poses))
        plot_readings(metrics, np.rad2deg(log.bearings), out / "per_reading.png")
    return report


def _pool(ms: list[dict[str, Any]]) -> dict[str, Any]:
    """Metrics of several repeats: reading-weighted means of the scalar metrics, the first repeat's lists."""
    w = np.array([m["n_readings"] for m in ms], dtype=float)
    out = dict(ms[0])
    for k in ("nll_per_reading", "ece", "pit_ks", "acf1_range_mean", "acf1_null_mean", "null_fraction"):
        out[k] = float(np.average([m[k] for m in ms], weights=w))
    out["n_readings"] = int(w.sum())
    return out


# (column, metric key, how far from the ideal value): the columns that rank the models
RANKED = (
    ("NLL/reading", "nll_per_reading", lambda v: v),
    ("null-rate ECE", "ece", lambda v: v),
    ("PIT KS", "pit_ks", lambda v: v),
    ("lag-1 ACF range", "acf1_range_mean", abs),
    ("lag-1 ACF null", "acf1_null_mean", abs),
)


def readings_markdown(metrics: dict[str, dict[str, Any]], source: str | None = None, n_scans: int | None = None) -> str:
    """A Markdown report of the scalar per-reading metrics keyed by model name, the nearest to ideal per column.

    Args:
        metrics: per model name, the output of :func:`reading_metrics`.
        source: the log's name for the title (``None``: no title).
        n_scans: the log's scan count for the title line.
    """
    lines = []
    if source is not None:
        n = next(iter(metrics.values()))["n_readings"] if metrics else 0
        scans = "" if n_scans is None else f"{n_scans} scans, "
        lines += [f"# Per-reading validation on {source}", "", f"{scans}{n} readings per model.", ""]
    lines += [
        "| model | NLL/reading | NLL null | NLL return | null-rate ECE | PIT KS | lag-1 ACF range | lag-1 ACF null |",
        "|" + "---|" * 8,
    ]
    for k, m in metrics.items():
        f = [m["nll_per_reading"], m["nll_null"], m["nll_return"], m["ece"], m["pit_ks"]]
        f += [m["acf1_range_mean"], m["acf1_null_mean"]]
        lines.append(f"| {k} | " + " | ".join("n/a" if v is None else f"{v:.4g}" for v in f) + " |")
    lines.append("")
    lines.append(
        "NLL: minus the mean log-likelihood of a reading (a null's probability, a return's density in 1/m; lower is "
        "better; NLL null / NLL return split it by outcome). Ideal values: ECE 0, PIT KS 0 (uniform PIT), lag-1 ACF 0 "
        "(white residuals)."
    )
    best = []
    for column, key, distance in RANKED:
        scored = {k: distance(m[key]) for k, m in metrics.items() if m.get(key) is not None and np.isfinite(m[key])}
        if scored:
            best.append(f"{column}: {min(scored, key=lambda k: scored[k])}")
    if best:
        lines += ["", "Nearest the ideal value (no interval: one log): " + "; ".join(best) + "."]
    return "\n".join(lines) + "\n"


def plot_readings(metrics: dict[str, dict[str, Any]], bearings_deg: NDArray[np.float64], path: Path) -> None:
    """Calibration, PIT histograms, lag-1 ACF and NLL per bearing, one line per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    ax[0, 0].plot([0, 1], [0, 1], c="0.6", ls="--", label="ideal calibration")
    for name, m in metrics.items():
        c = m["calibration"]
        ax[0, 0].plot([b["predicted"] for b in c], [b["observed"] for b in c], "o-", ms=3, label=name)
        ax[0, 1].step(np.arange(10) / 10, m["pit_hist"], where="post", label=f"{name} (KS {m['pit_ks']:.2f})")
        acf = np.array([np.nan if v is None else v for v in m["acf1_range_per_bearing"]])
        ax[1, 0].plot(bearings_deg, acf, lw=0.7, label=name)
        nll = np.array([np.nan if v is None else v for v in m["nll_per_bearing"]])
        ax[1, 1].plot(bearings_deg, nll, lw=0.7, label=name)
    ax[0, 0].set(xlabel="predicted p_null", ylabel="observed null fraction", title="null-rate calibration")
    ax[0, 1].axhline(0.1, c="0.6", ls="--", label="uniform (ideal)")
    ax[0, 1].set(xlabel="PIT of non-null readings", ylabel="fraction", title="PIT histogram", yscale="log")
    ax[1, 0].axhline(0.0, c="0.6", ls="--")
    ax[1, 0].set(xlabel="bearing [deg]", ylabel="lag-1 ACF of range residuals", title="temporal correlation")
    ax[1, 1].set(xlabel="bearing [deg]", ylabel="NLL per reading", title="held-out NLL", yscale="symlog")
    for a in ax.flat:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
