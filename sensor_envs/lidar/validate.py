"""Validation of lidar models against a log: the seed's Table I metrics, log-likelihood, baselines, plots.

Definitions (written into every ``report.json``):

* A cell is one pose and one bearing. Its empirical ``p_null`` is the fraction of null readings; its
  empirical ``mu``/``sigma`` [m] are the mean and standard deviation (ddof 1) of its in-range
  readings (non-null and ``<= spur_above``), over cells with at least 2 of them. Spurious far
  returns (``> spur_above``) are a separate outcome with empirical fraction ``p_spur``.
* Table I: mean absolute error, over cells, between a model's ``p_null``/``mu``/``sigma`` at the
  log's (approximate) pose and the empirical ones; reported on all cells and on the "clean" cells
  without any spurious reading.
* Log-likelihood: mean over readings of ``log p_null`` (nulls) or the log density [1/m] of the
  reading, on all readings and on the in-range readings only.
* Null-count log-likelihood: mean over readings of the log-probability of each cell's number of
  nulls among its readings, beta-binomial with mean ``p_null`` and the model's intra-cell correlation
  ``null_rho`` (persistent nulls); ``..._independent`` uses ``null_rho = 0`` (binomial: readings
  independent, as the per-reading log-likelihood assumes). Baselines have ``null_rho = 0``.
* MSE of ``p_spur``: mean squared error over cells between the model's ``p_spur`` and the cell's
  spurious fraction (a Brier score: least in expectation for the cell's true probability).
* Spurious-count log-likelihood: the same for each cell's number of spurious far returns, beta-binomial
  with mean ``p_spur`` and the model's ``spur_rho`` (``..._independent``: ``spur_rho = 0``). Unlike the
  MAE of ``p_spur`` these two are proper scores: the real spurious cells are rare and near-binary (a cell is
  spurious in almost all or none of its readings), so a cell's MAE is least at ``p_spur = 0`` whenever the
  cell is more likely clean than spurious, as almost all are: a model that predicts no spurious return
  at all has a lower MAE than one whose ``p_spur`` is the true probability. Baselines (no spurious
  outcome) have ``p_spur = 0``, scored at the floor ``P_EPS``.
* Baselines (same features): ``ideal`` has ``mu = r``, ``sigma = IDEAL_SIGMA`` (the 1 mm range quantum:
  a floor that keeps its likelihood finite) and ``p_null = P_EPS`` on a hit (``1 - P_EPS`` without);
  ``gaussian`` is :class:`~sensor_envs.lidar.gaussian.GaussianLidar` with its ``sigma0``, ``k_range``,
  ``k_incidence`` and ``p_null_floor`` refitted to the training data (:func:`fit_gaussian_lidar`).
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls
from tqdm.auto import tqdm

from sensor_envs.geometry import to_frame
from sensor_envs.inputs import InputError
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr import (
    FORMAT_VERSION,
    MODEL_KIND,
    SIGMA_FLOOR,
    LidarLWLR,
    cell_statistics,
    lidar_features,
    mixture_log_prob,
    null_count_log_prob,
)
from sensor_envs.lidar.sensors import GaussianLidar
from sensor_envs.lidar.validate_readings import IDEAL_SIGMA, Params, baseline_params
from sensor_envs.outputs import write_json
from sensor_envs.rng import fold_ids

__all__ = [
    "IDEAL_SIGMA",
    "fit_gaussian_lidar",
    "baseline_params",
    "table_one",
    "pose_intervals",
    "verdict_markdown",
    "validate",
    "cross_validate_log",
    "model_card_markdown",
    "log_statistics",
]

"""Standard deviation [m] given to the ideal baseline for its likelihood (the 1 mm range quantum)."""


def fit_gaussian_lidar(log: LidarLog, spur_above: float = 6.0, max_range: float = 5.0) -> GaussianLidar:
    """Refit the Gaussian baseline to a log (for a fair comparison).

    ``sigma0, k_range, k_incidence``: non-negative least squares on the cells' standard deviations of
    in-range readings; ``p_null_floor``: the null fraction of the cells whose ray hits the map.
    """
    r, a = lidar_features(log.poses, log.bearings, log.require_map(), max_range)
    st = cell_statistics(log, spur_above, split_spurious=True)
    base = GaussianLidar()
    hit = np.isfinite(r)
    m = hit & (st["n_ok"] >= 2)
    rm = r[m]
    coef, _ = nnls(np.column_stack([np.ones(m.sum()), rm**2, rm * base.tan_incidence(a[m])]), st["std"][m])
    n = st["n"][hit]
    p_null = float((st["p_null"][hit] * n).sum() / max(n.sum(), 1))
    return GaussianLidar(
        sigma0=float(max(coef[0], SIGMA_FLOOR)), k_range=float(coef[1]), k_incidence=float(coef[2]), p_null_floor=p_null
    )


def _ll(log: LidarLog, p: Params, spur: tuple[Any, Any], spur_above: float) -> dict[str, float]:
    """Mean log-likelihood per reading, all readings and in-range readings only."""
    x = log.ranges
    pe = {k: v[..., None] for k, v in p.items()}
    lp = mixture_log_prob(
        x,
        pe,
        np.asarray(spur[0])[..., None, None] if np.ndim(spur[0]) else spur[0],
        np.asarray(spur[1])[..., None, None] if np.ndim(spur[1]) else spur[1],
    )
    valid = ~np.isnan(x)
    inr = valid & (x <= spur_above)
    return {
        "ll_per_reading": float(lp[valid].mean()),
        "ll_per_reading_in_range": float(lp[inr].mean()),
        "n_readings": int(valid.sum()),
    }


def table_one(log: LidarLog, p: Params, spur: tuple[Any, Any] = (0.0, 1.0), spur_above: float = 6.0) -> dict[str, Any]:
    """Table I MAEs (all and clean cells), ``p_spur`` MAE and log-likelihoods of parameters ``p`` ``(P, K)``."""
    st = cell_statistics(log, spur_above, split_spurious=True)
    has = st["n"] > 0
    ms = st["n_ok"] >= 2
    clean = st["p_spur"] == 0
    out: dict[str, Any] = {}
    for tag, sel in (("all", np.ones_like(has)), ("clean", clean)):
        out[tag] = {
            "mae_mu": float(np.abs(p["mu"] - st["mean"])[ms & sel].mean()),
            "mae_sigma": float(np.abs(p["sigma"] - st["std"])[ms & sel].mean()),
            "mae_p_null": float(np.abs(p["p_null"] - st["p_null"])[has & sel].mean()),
            "n_cells_mu_sigma": int((ms & sel).sum()),
            "n_cells_p_null": int((has & sel).sum()),
        }
    out["mae_p_spur"] = float(np.abs(p["p_spur"] - st["p_spur"])[has].mean())
    out["mse_p_spur"] = float(((p["p_spur"] - st["p_spur"]) ** 2)[has].mean())
    out.update(_ll(log, p, spur, spur_above))
    n = st["n"][has]
    for outcome in ("null", "spur"):  # counts per cell, beta-binomial with the model's rho and independent
        k, q = np.round(st[f"p_{outcome}"][has] * n), p[f"p_{outcome}"][has]
        rho = p[f"{outcome}_rho"][has] if f"{outcome}_rho" in p else 0.0
        out[f"ll_{outcome}_counts_per_reading"] = float(null_count_log_prob(k, n, q, rho).sum() / n.sum())
        out[f"ll_{outcome}_counts_per_reading_independent"] = float(null_count_log_prob(k, n, q, 0.0).sum() / n.sum())
    return out


def _model_spur(model: LidarLWLR) -> tuple[float, float]:
    return model.spur_mu_, model.spur_sigma_


def validate(
    model: LidarLWLR,
    log: LidarLog,
    out_dir: str | os.PathLike[str],
    gaussian: GaussianLidar | None = None,
    rng: np.random.Generator | None = None,
) -> dict[str, Any]:
    """Compare a fitted model and the baselines with a log; write ``report.json``, ``report.md`` and plots.

    Args:
        model: the fitted model.
        log: the validation log (its approximate poses and map give the features).
        out_dir: output folder.
        gaussian: the Gaussian baseline (default: the one stored in the model's card, else the defaults).
        rng: generator of the simulated scan in the plot (default: seeded 0).

    Returns:
        The report (also written to ``out_dir/report.json``). A log with one reading per pose and bearing
        (scans at moving poses) gets the per-reading report of
        :func:`sensor_envs.lidar.validate_readings.validate_readings` instead of Table I.
    """
    if log.bearings.size != model.bearings_.size:
        raise InputError(
            f"{log.source}: field 'bearings': the log has {log.bearings.size} bearings, the model "
            f"{model.bearings_.size} (a model scores logs of its own sensor)"
        )
    if log.ranges.shape[2] == 1:
        from sensor_envs.lidar.validate_readings import validate_readings

        return validate_readings(model, log, out_dir, gaussian)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    r, a = lidar_features(log.poses, log.bearings, log.require_map(), model.max_range)
    if gaussian is None:
        gaussian = model.baseline()
    params = {
        f"model_{model.variant}": model.params_from_features(r, a),
        "ideal": baseline_params("ideal", r, a),
        "gaussian": baseline_params("gaussian", r, a, gaussian),
    }
    spur = {f"model_{model.variant}": _model_spur(model)}
    metrics = {k: table_one(log, p, spur.get(k, (0.0, 1.0)), model.spur_above) for k, p in params.items()}
    intervals = pose_intervals(log, params, model.spur_above)
    verdict = verdict_markdown(metrics, intervals)
    report = {
        "log": log.source,
        "n_poses": log.n_poses,
        "model_training": model.training_,
        "model_h": model.h_,
        "gaussian_baseline": vars(gaussian) if gaussian else vars(GaussianLidar()),
        "definitions": __doc__.split("Definitions (written into every ``report.json``):")[1].strip(),
        "metrics": metrics,
        "verdict_intervals": intervals,
        "verdict": verdict,
    }
    write_json(out / "report.json", report)
    (out / "report.md").write_text(metrics_markdown(metrics) + "\n" + verdict)
    plot_scan(model, log, params, out / "scan.png", rng or np.random.default_rng(0))
    plot_per_bearing(log, params, out / "per_bearing_error.png", model.spur_above)
    return report


def metrics_markdown(metrics: dict[str, dict[str, Any]]) -> str:
    """A Markdown table of :func:`table_one` results keyed by model name."""
    lines = [
        "| model | MAE mu [m] | MAE sigma [m] | MAE p_null | clean: MAE mu | clean: MAE sigma | "
        "clean: MAE p_null | MAE p_spur | MSE p_spur | LL/reading | LL/reading in range | null-count LL/reading | "
        "null-count LL/reading (independent) | spurious-count LL/reading | spurious-count LL/reading (independent) |",
        "|" + "---|" * 15,
    ]
    for k, m in metrics.items():
        a, c = m["all"], m["clean"]
        lines.append(
            f"| {k} | {a['mae_mu']:.4f} | {a['mae_sigma']:.4f} | {a['mae_p_null']:.4f} | {c['mae_mu']:.4f} | "
            f"{c['mae_sigma']:.4f} | {c['mae_p_null']:.4f} | {m['mae_p_spur']:.4f} | "
            f"{m['mse_p_spur']:.4f} | "
            f"{m['ll_per_reading']:.4g} | {m['ll_per_reading_in_range']:.4g} | "
            f"{m['ll_null_counts_per_reading']:.4g} | {m['ll_null_counts_per_reading_independent']:.4g} | "
            f"{m['ll_spur_counts_per_reading']:.4g} | "
            f"{m['ll_spur_counts_per_reading_independent']:.4g} |"
        )
    return "\n".join(lines) + "\n"


VERDICT_TOL = 1e-5
"""MAEs within this of each other [m, or probability] are called the same by :func:`verdict_markdown`."""


VERDICT_PARAMS = (
    ("mae_mu", "mu", "ideal", "mean mu vs the raycast"),
    ("mae_sigma", "sigma", "gaussian", "spread sigma vs the Gaussian baseline"),
    ("mae_p_null", "p_null", "gaussian", "null probability vs the Gaussian baseline"),
)
"""Table I parameters of the verdict: metric key, parameter, the baseline it is judged against, label."""
N_BOOT = 2000
"""Bootstrap resamples of the poses behind the verdict's intervals."""


def pose_intervals(
    log: LidarLog, params: dict[str, Params], spur_above: float, n_boot: int = N_BOOT, seed: int = 0
) -> dict[str, dict[str, Any]]:
    """95 % intervals of (model MAE - baseline MAE) per Table I parameter, whole poses resampled.

    The cells are those of :func:`table_one` (all cells); each resample draws the poses with replacement
    and recomputes both MAEs over the drawn poses' cells (paired: the same cells for both). Empty without
    a ``model_*`` entry.
    """
    name = next((k for k in params if k.startswith("model")), None)
    if name is None:
        return {}
    st = cell_statistics(log, spur_above, split_spurious=True)
    cells = {"mu": st["n_ok"] >= 2, "sigma": st["n_ok"] >= 2, "p_null": st["n"] > 0}
    target = {"mu": st["mean"], "sigma": st["std"], "p_null": st["p_null"]}
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, log.n_poses, (n_boot, log.n_poses))
    out: dict[str, dict[str, Any]] = {}
    for key, par, base, _ in VERDICT_PARAMS:
        sel = cells[par]
        cnt = sel.sum(axis=1).astype(np.float64)
        err = {
            k: np.where(sel, np.abs(np.nan_to_num(params[k][par] - target[par])), 0.0).sum(axis=1) for k in (name, base)
        }
        d = err[name] - err[base]
        boot = d[draws].sum(axis=1) / np.maximum(cnt[draws].sum(axis=1), 1.0)
        point = float(d.sum() / max(cnt.sum(), 1.0))
        lo, hi = np.percentile(boot, [2.5, 97.5]) if log.n_poses > 1 else (point, point)
        out[key] = {"baseline": base, "difference": point, "ci95": [float(lo), float(hi)], "poses": log.n_poses}
    return out


def _word(m: float, b: float, ci: list[float] | None) -> str:
    if abs(m - b) <= VERDICT_TOL:
        return "the same"
    if ci is None:
        return "better" if m < b else "WORSE"
    return "better" if ci[1] < 0 else ("WORSE" if ci[0] > 0 else "not distinguishable")


def verdict_markdown(metrics: dict[str, dict[str, Any]], intervals: dict[str, dict[str, Any]] | None = None) -> str:
    """One line per Table I parameter: the learned model against its baseline, in words (all cells).

    ``mu`` against the raycast (``ideal``: ``mu = r``), ``sigma`` and ``p_null`` against the Gaussian baseline:
    "the same" (within :data:`VERDICT_TOL`), else with ``intervals`` (:func:`pose_intervals`) "better" /
    "not distinguishable" / "WORSE" from the 95 % interval of the difference over poses, and without them
    "better" / "WORSE" by the point values. Empty without a ``model_*`` entry.
    """
    name = next((k for k in metrics if k.startswith("model")), None)
    if name is None or "ideal" not in metrics or "gaussian" not in metrics:
        return ""
    head = "Verdict (MAE on all cells, lower is better"
    head += "; 95 % interval of the difference, poses resampled):" if intervals else "):"
    lines = [head, ""]
    for key, _, base, label in VERDICT_PARAMS:
        m, b = metrics[name]["all"][key], metrics[base]["all"][key]
        iv = (intervals or {}).get(key)
        if iv is None:
            lines.append(f"- {label}: {m:.4f} vs {b:.4f}: {_word(m, b, None)}")
            continue
        ideal, gauss = metrics["ideal"]["all"][key], metrics["gaussian"]["all"][key]
        ci = iv["ci95"]
        lines.append(
            f"- {label}: {m:.4f} vs {b:.4f} (raycast {ideal:.4f}, Gaussian {gauss:.4f}), difference "
            f"{iv['difference']:+.4f} [{ci[0]:+.4f}, {ci[1]:+.4f}] over {iv['poses']} poses: {_word(m, b, ci)}"
        )
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ plots
def _sample(p: Params, rng: np.random.Generator) -> NDArray[np.float64]:
    u, z = rng.random(p["mu"].shape), rng.standard_normal(p["mu"].shape)
    return np.where(u < p["p_null"], 0.0, np.maximum(p["mu"] + p["sigma"] * z, 1e-4))


def plot_scan(
    model: LidarLWLR,
    log: LidarLog,
    params: dict[str, Params],
    path: Path,
    rng: np.random.Generator,
    pose_index: int = 0,
) -> None:
    """The seed's Fig. 2: one real scan and one simulated scan per model at a pose (sensor frame, x fwd)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    b = log.bearings
    fig, axes = plt.subplots(1, len(params) + 1, figsize=(4.2 * (len(params) + 1), 4.2), sharex=True, sharey=True)
    real = log.ranges[pose_index, :, 0]
    name = next(iter(params))
    scans = {
        f"log {Path(log.source).name} (repeat 0)": real,
        **{f"{name} (sampled)": model.sample_from_params({k: v[pose_index] for k, v in params[name].items()}, rng)},
        **{
            f"{k} (sampled)": _sample({kk: v[pose_index] for kk, v in p.items()}, rng)
            for k, p in params.items()
            if k != name
        },
    }
    walls = to_frame(log.require_map(), log.poses[pose_index])  # (M, 2, 2) in the sensor frame
    for ax, (title, x) in zip(axes, scans.items(), strict=False):
        for seg in walls:
            ax.plot(seg[:, 0], seg[:, 1], c="0.8", lw=1, zorder=0)
        ok = (x > 0) & (x <= model.spur_above) & np.isfinite(x)
        ax.scatter(x[ok] * np.cos(b[ok]), x[ok] * np.sin(b[ok]), s=3)
        nul = (x == 0) | ~np.isfinite(x)
        ax.scatter(0.2 * np.cos(b[nul]), 0.2 * np.sin(b[nul]), s=2, c="r", label="null")
        sp = np.isfinite(x) & (x > model.spur_above)
        ax.scatter(0.3 * np.cos(b[sp]), 0.3 * np.sin(b[sp]), s=4, c="m", marker="x", label="spurious (far)")
        ax.set_title(title, fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m] (sensor frame, forward)")
    axes[0].set_ylabel("y [m] (left)")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_per_bearing(log: LidarLog, params: dict[str, Params], path: Path, spur_above: float) -> None:
    """Per-bearing MAE of ``mu``, ``sigma`` and ``p_null`` over the log's poses, per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    st = cell_statistics(log, spur_above, split_spurious=True)
    deg = np.rad2deg(log.bearings)
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for name, p in params.items():
        for ax, key, emp in zip(axes, ("mu", "sigma", "p_null"), ("mean", "std", "p_null"), strict=True):
            with warnings.catch_warnings():  # bearings without any usable cell (blocked) stay NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                e = np.nanmean(np.abs(p[key] - st[emp]), axis=0)
            ax.plot(deg, e, lw=0.8, label=name)
    for ax, lab in zip(axes, ("MAE mu [m]", "MAE sigma [m]", "MAE p_null"), strict=True):
        ax.set_ylabel(lab)
        ax.set_yscale("log")
    axes[-1].set_xlabel("bearing [deg]")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------- cross-validated table
def cross_validate_log(
    log: LidarLog,
    n_folds: int = 10,
    inner_folds: int = 10,
    random_state: int = 0,
    model_kwargs: dict[str, Any] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Leave-poses-out cross-validated Table I of the seed and extended models and both baselines.

    ``seed_without_spurious`` is the seed model fitted with the spurious far returns removed from the
    training readings (they are kept in the held-out readings).

    Each outer fold fits the models (with their own inner CV of kernel widths) and the Gaussian
    baseline on the other poses, and predicts the held-out poses; metrics pool all held-out cells.
    """
    fold = fold_ids(log.n_poses, n_folds, random_state=random_state)
    r, a = lidar_features(log.poses, log.bearings, log.require_map(), 5.0)
    names = ("seed", "seed_without_spurious", "extended", "ideal", "gaussian")
    pred: dict[str, Params] = {n: {} for n in names}
    spur = {n: (np.zeros(log.n_poses), np.ones(log.n_poses)) for n in names}
    for f in tqdm(range(n_folds), desc="outer CV folds", disable=not progress):
        tr, te = fold != f, fold == f
        train = log.subset(tr)
        for name, v, data in (
            ("seed", "seed", train),
            ("seed_without_spurious", "seed", _drop_spurious(train)),
            ("extended", "extended", train),
        ):
            m = LidarLWLR(
                variant=v,
                n_folds=min(inner_folds, int(tr.sum())),
                verbose=False,
                random_state=random_state,
                **(model_kwargs or {}),
            ).fit(data)
            _put(pred[name], te, m.params_from_features(r[te], a[te]))
            spur[name][0][te], spur[name][1][te] = m.spur_mu_, m.spur_sigma_
        _put(pred["ideal"], te, baseline_params("ideal", r[te], a[te]))
        _put(pred["gaussian"], te, baseline_params("gaussian", r[te], a[te], fit_gaussian_lidar(train)))
    return {n: table_one(log, pred[n], spur[n]) for n in names}


def _drop_spurious(log: LidarLog, spur_above: float = 6.0) -> LidarLog:
    """The log with its spurious far returns marked missing (the seed model fitted on cleaned data)."""
    return dataclasses.replace(log, ranges=np.where(log.ranges > spur_above, np.nan, log.ranges))


def _shrinkage_markdown(model: LidarLWLR) -> list[str]:
    """Card lines on the bias shrinkage (rule, per-fold MAE of mu vs the raycast) and the pose correction."""
    sc = model.cv_scores_.get("bias_shrinkage")
    if not sc:
        return [
            f"Bias shrinkage: {getattr(model, 'bias_shrinkage_', 0.0)} (older model file: not cross-validated).",
            "",
        ]
    lines = [
        f"Bias shrinkage toward the raycast, `mu = r + (1 - s) bias`: s = {model.bias_shrinkage_} "
        f"(setting `{model.bias_shrinkage}`; rule: {sc['rule']}). Held-out MAE of mu [m] per CV fold:",
        "",
        "| fold | cells | raycast | learned (s = 0) | chosen s |",
        "|---|---|---|---|---|",
    ]
    for p in sc["per_fold"]:
        maes = " | ".join(f"{p[k]:.5f}" for k in ("mae_raycast", "mae_unshrunk", "mae_chosen"))
        lines.append(f"| {p['fold']} | {p['n_cells']} | {maes} |")
    lines.append(f"| pooled | | {sc['cv_mae_raycast']:.5f} | {sc['cv_mae_unshrunk']:.5f} | {sc['cv_mae_chosen']:.5f} |")
    if "local_weight" in sc:  # bias_model="pooled": bias = G + lam L (sensor_envs.lidar.bias_transfer)
        g = sc["global"]
        lines += [
            "",
            f"Pooled bias (`bias_model` pooled): bias = G + lam L, G pooled over bearings (h_range {g['h'][0]} m, "
            f"h_alpha {g['h'][1]} rad, degree {int(g['h'][3])}), L the per-bearing remainder; lam = "
            f"{sc['local_weight']} chosen with s on the same folds. Pooled CV MAE of mu per lam: "
            + ", ".join(
                f"{row['local_weight']}: {row['cv_mae']:.5f} (s {row['shrinkage']})" for row in sc["per_local_weight"]
            )
            + ".",
        ]
    sd = model.cv_scores_.get("pose_error_sd")
    if sd:
        lines += [
            "",
            f"Rigid pose error of `sample` (robust spread of the training poses' corrections): dx {sd['sd'][0]:.4f} m,"
            f" dy {sd['sd'][1]:.4f} m, dtheta {sd['sd'][2]:.4f} rad.",
        ]
    pc = model.cv_scores_.get("pose_correction")
    if pc:
        lines += [
            "",
            f"Pose correction of the training poses: rms dx {pc['rms_dx']:.4f} m, dy {pc['rms_dy']:.4f} m, "
            f"dtheta {pc['rms_dtheta']:.4f} rad (largest shift {pc['max_shift']:.3f} m); median |residual| "
            f"{pc['median_abs_residual_before']:.4f} -> {pc['median_abs_residual_after']:.4f} m.",
        ]
    return lines + [""]


def _put(dst: Params, idx: NDArray[np.bool_], src: Params) -> None:
    for k, v in src.items():
        dst.setdefault(k, np.zeros(idx.shape + v.shape[1:]))[idx] = v


# ------------------------------------------------------------------------------------- statistics, card
def log_statistics(log: LidarLog, max_range: float = 5.0, spur_above: float = 6.0) -> dict[str, Any]:
    """Summary statistics of a static-pose log (for calibrating the rig against real data).

    ``mixed_null_cells`` is the share of unblocked hit cells that are neither always nor never null
    (null fraction in ``[0.05, 0.95]``): low when nulls persist per cell.
    """
    r, _ = lidar_features(log.poses, log.bearings, log.require_map(), max_range)
    st = cell_statistics(log, spur_above, split_spurious=True)
    valid = ~np.isnan(log.ranges)
    blocked = np.nanmean(st["p_null"], axis=0) > 0.99
    ok = (st["n_ok"] >= 2) & ~blocked[None]
    bins = np.arange(0.0, 4.01, 0.5)
    by_r = []
    for lo, hi in zip(bins[:-1], bins[1:], strict=True):
        s = (r >= lo) & (r < hi) & ~blocked[None]
        so = s & ok & (st["p_spur"] == 0)
        by_r.append(
            {
                "r": f"{lo:.1f}-{hi:.1f}",
                "cells": int(s.sum()),
                "p_null": float(st["p_null"][s].mean()) if s.any() else None,
                "median_std": float(np.median(st["std"][so])) if so.any() else None,
            }
        )
    return {
        "null_fraction": float((log.ranges[valid] == 0).mean()),
        "spurious_fraction": float((log.ranges[valid] > spur_above).mean()),
        "cells_with_spurious": float((st["p_spur"] > 0).mean()),
        "blocked_bearings": int(blocked.sum()),
        "mixed_null_cells": float(_mixed(st["p_null"][np.isfinite(r) & ~blocked[None] & (st["n"] > 0)])),
        "mae_mean_minus_nominal": float(np.abs(st["mean"] - r)[ok].mean()),
        "median_cell_std": float(np.median(st["std"][ok])),
        "by_range": by_r,
    }


def _mixed(p_null: NDArray[np.float64]) -> float:
    """Share of cells whose null fraction is in ``[0.05, 0.95]`` (neither always nor never null)."""
    return float(((p_null >= 0.05) & (p_null <= 0.95)).mean()) if p_null.size else float("nan")


def model_card_markdown(model: LidarLWLR, commands: list[str], validation: dict[str, Any] | None = None) -> str:
    """The model card (Markdown): data used, hyperparameters, CV scores, validation metrics, commands."""
    t = model.training_
    lines = [
        f"# Learned Neato lidar model ({model.variant} variant)",
        "",
        "Per-bearing LWLR model of `sensor_envs.lidar.lwlr` (seed: Tallavajhula & Kelly), stored as "
        "per-bearing (range, incidence) parameter tables; no training readings are stored.",
        "",
        "## Data",
        "",
        f"- source: `{t.get('source')}`; {t.get('n_poses')} poses x {t.get('n_bearings')} "
        f"bearings, {t.get('n_readings')} readings, null fraction {t.get('null_fraction', float('nan')):.3f}",
        f"- sha256 of the ranges array: `{t.get('sha256_of_ranges')}`",
        "",
        "## Hyperparameters (by CV)",
        "",
        "| parameter | h_range [m] | h_alpha [rad] | h_bearing [steps] | degree | CV MAE (best) | CV MAE (worst) |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, h in model.h_.items():
        s = model.cv_scores_.get(n, {})
        lines.append(
            f"| {n} | {h[0]} | {h[1]} | {h[2]} | {int(h[3])} | {s.get('cv_mae_best', float('nan')):.5f} | "
            f"{s.get('cv_mae_worst', float('nan')):.5f} |"
        )
    lines += [
        "",
        "CV MAE of `log_sigma` is in metres of sigma; of `bias` in metres of mu; `tau2` (spread of cell "
        "means at an approximate pose) reuses the widths of `bias` and is not cross-validated.",
        "",
    ]
    rho_s = model.cv_scores_.get("null_rho")
    if rho_s:
        lines += [
            f"Persistent nulls: intra-cell correlation `null_rho` = {model.null_rho_} (beta-binomial over a "
            f"cell's repeats; chosen among {rho_s['n_candidates']} values by the likelihood of the training cells' "
            f"null counts around the out-of-fold `p_null`: {rho_s['ll_per_reading_best']:.4f} per reading vs "
            f"{rho_s['ll_per_reading_independent']:.4f} for independent readings).",
            "",
        ]
    spur_s = model.cv_scores_.get("spur_rho")
    if spur_s:
        lines += [
            f"Persistent spurious returns: intra-cell correlation `spur_rho` = {model.spur_rho_} (the same "
            f"beta-binomial on the training cells' spurious counts around the out-of-fold `p_spur`: "
            f"{spur_s['ll_per_reading_best']:.4f} per reading vs {spur_s['ll_per_reading_independent']:.4f} for "
            "independent readings).",
            "",
        ]
    lines += _shrinkage_markdown(model)
    lines += [f"File format version {FORMAT_VERSION} (`{MODEL_KIND}`).", ""]
    if validation is not None:
        lines += [
            "## Validation",
            "",
            f"On `{validation.get('log')}` ({validation.get('n_poses')} poses):",
            "",
            metrics_markdown(validation["metrics"]),
        ]
    lines += ["## Reproduce", ""] + [f"    {c}" for c in commands] + [""]
    return "\n".join(lines)
