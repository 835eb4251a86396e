"""Diagnosis of the learned lidar's per-cell ``p_null`` residuals on held-out real poses (issue #3).

Record (issue 40; not maintained, see docs/history/scripts.md). Found: per-cell null fractions are bimodal and no
geometric feature generalises to unseen poses; led to per-cell null persistence (`null_rho`): held-out null-count LL
-0.224 -> -0.007 per reading (`20e635d`).

    python docs/history/scripts/real_neato_residuals.py --data ../shared/data/real [--folds 10] [--out DIR]

A cell is one (pose, bearing) of the real Neato log; its empirical ``p_null`` is its null fraction
over ~200 repeats. Cells without a nominal hit and the blocked bearings (posts) are left out.
Everything is leave-poses-out cross-validated with the outer folds of
``benchmarks/real_neato_report.py`` (same seed):

1. The extended model's ``p_null`` LWLR, with its kernel widths chosen per outer fold by the model's
   own inner CV (``LidarLWLR._cross_validate`` on the ``p_null`` group only; the full fit's tables
   clamp queries to the training range, so its MAE differs from the report's in the 4th digit).
2. Shares of the variance of the empirical ``p_null`` explained by ``bearing``, ``range``,
   ``incidence`` and their interactions (gradient-boosted trees, CV R^2).
3. Shares of the LWLR's held-out residual explained by what the model lacks (boosted trees on the
   residual, CV R^2; a negative R^2 means the feature does not generalise to unseen poses): hit
   segment and board side, distance of the hit point to the nearest segment end and the ray's
   angular margin to it, distance to the nearest break of the nominal scan, hit position on the map,
   world direction of the ray, and (a diagnostic that no sensor model can use) the held-out
   residual of the neighbouring bearings at the same pose.
4. What is pose-specific: the per-pose constant share of the residual variance and the residual's
   autocorrelation across bearings at a pose.
5. The metric: bimodality of the per-cell fractions, the MAE by the fraction's range, a reliability
   table, ``E|Y - q| = 2 q (1 - q)`` (the MAE a calibrated probability ``q`` must have when cells are
   all-or-nothing) and the MAE of a hard 0/1 prediction (lower, but useless as a probability).

Writes ``DIR/residuals.json``, ``DIR/residuals.md`` and ``DIR/residuals.png`` (default DIR:
/tmp/real_neato_residuals; never inside the repository).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import special, stats
from sklearn.ensemble import HistGradientBoostingRegressor

from sensor_envs.geometry import raycast_pose
from sensor_envs.lidar.log import LidarLog, load_log
from sensor_envs.lidar.lwlr import P_EPS, LidarLWLR, cell_statistics, lwlr
from sensor_envs.rng import fold_ids

DIRECT = {
    "bearing": ["bearing"],
    "range": ["r"],
    "incidence": ["alpha"],
    "range+incidence": ["r", "alpha"],
    "bearing+range+incidence": ["bearing", "r", "alpha"],
}
ON_RESIDUAL = {
    "segment+side": ["segment", "board_side"],
    "segment end (dist, margin)": ["edge_dist", "edge_margin"],
    "scan break distance": ["break_dist"],
    "range+incidence+scan break": ["r", "alpha", "break_dist"],
    "hit position (x, y)": ["hx", "hy"],
    "world direction": ["world_dir"],
    "neighbour residuals (same pose, diagnostic)": ["nb_res"],
}
Cells = dict[str, NDArray[np.float64]]


def scan_break_distance(
    r: NDArray[np.float64], alpha: NDArray[np.float64], cap: float = 16.0, jump: float = 0.1, corner: float = 0.15
) -> NDArray[np.float64]:
    """Distance [bearing steps] of each bearing to the nearest break of the nominal scan ``(..., K)`` (circular).

    A break lies between bearings ``k`` and ``k + 1`` when one ray hits and the other does not, when the
    range jumps by more than ``jump`` times the nearer range, or the incidence by more than ``corner``
    [rad] (a corner). Uses the nominal scan only (a sensor could compute it). Clipped to ``cap``.
    """
    hit = np.isfinite(r)
    r1, a1, h1 = np.roll(r, -1, -1), np.roll(alpha, -1, -1), np.roll(hit, -1, -1)
    with np.errstate(invalid="ignore"):
        brk = (hit != h1) | (hit & h1 & ((np.abs(r1 - r) > jump * np.minimum(r, r1)) | (np.abs(a1 - alpha) > corner)))
    k = r.shape[-1]
    idx = np.arange(3 * k, dtype=np.float64)
    b3 = np.concatenate([brk] * 3, axis=-1)
    last = np.maximum.accumulate(np.where(b3, idx, -np.inf), axis=-1)  # break i lies at bearing i + 0.5
    nxt = np.minimum.accumulate(np.where(b3, idx, np.inf)[..., ::-1], axis=-1)[..., ::-1]
    j = idx[k : 2 * k]
    return np.minimum(np.minimum(j - last[..., k - 1 : 2 * k - 1] - 0.5, nxt[..., k : 2 * k] - j + 0.5), cap)


def cell_table(log: LidarLog, max_range: float = 5.0) -> Cells:
    """Per-cell features and the empirical ``p_null``, each ``(P, K)``."""
    segs = log.require_map()
    r, a, idx = raycast_pose(log.poses, log.bearings, segs, max_range)
    st = cell_statistics(log, 6.0, split_spurious=True)
    th = log.poses[:, 2:3] + log.bearings[None]
    hx, hy = log.poses[:, :1] + r * np.cos(th), log.poses[:, 1:2] + r * np.sin(th)
    ends = segs.reshape(-1, 2)
    ang = np.arctan2(ends[:, 1] - log.poses[:, 1:2], ends[:, 0] - log.poses[:, :1])  # (P, E)
    return {
        "p_null": st["p_null"],
        "n": st["n"],
        "r": r,
        "alpha": a,
        "segment": idx.astype(float),
        "board_side": np.where(idx == len(segs) - 1, np.sign(log.poses[:, 1:2] - segs[-1, 0, 1]), 0.0),
        "edge_dist": np.hypot(hx[..., None] - ends[:, 0], hy[..., None] - ends[:, 1]).min(-1),
        "edge_margin": np.abs((th[..., None] - ang[:, None] + np.pi) % (2 * np.pi) - np.pi).min(-1),
        "break_dist": scan_break_distance(r, a),
        "hx": hx,
        "hy": hy,
        "world_dir": np.mod(th, 2 * np.pi),
        "bearing": np.broadcast_to(np.rad2deg(log.bearings), r.shape).copy(),
        "pose": np.broadcast_to(np.arange(log.n_poses)[:, None], r.shape).astype(float),
    }


def lwlr_p_null_oof(
    log: LidarLog, r: NDArray[np.float64], a: NDArray[np.float64], fold: NDArray[np.int64], inner: int
) -> tuple[NDArray[np.float64], list[list[float]]]:
    """Out-of-fold ``p_null`` ``(P, K)`` of the extended LWLR, widths by the model's inner CV per fold."""
    hit = np.isfinite(r)
    r0, a0 = np.where(hit, r, 0.0), np.nan_to_num(a)
    st = cell_statistics(log, 6.0, split_spurious=True)
    y, w = np.nan_to_num(st["p_null"])[..., None], (hit & (st["n"] > 0)).astype(float)
    out, widths = np.zeros(r.shape), []
    for k in np.unique(fold):
        tr, te = fold != k, fold == k
        m = LidarLWLR(variant="extended", n_folds=min(inner, int(tr.sum())), progress=False)
        h, _ = m._cross_validate(r0[tr], a0[tr], [(("p_null",), y[tr], w[tr], False)])
        h_r, h_a, h_b, deg = h["p_null"]
        out[te] = lwlr(r0[te], a0[te], r0[tr], a0[tr], y[tr], w[tr], h_r, h_a, (h_b,), (int(deg),))[0, 0, ..., 0]
        widths.append(h["p_null"])
    return np.clip(out, P_EPS, 1 - P_EPS), widths


def _r2(y: NDArray[np.float64], pred: NDArray[np.float64]) -> float:
    return float(1 - ((y - pred) ** 2).sum() / ((y - y.mean()) ** 2).sum())


def _boosted_oof(
    x: NDArray[np.float64], y: NDArray[np.float64], f: NDArray[np.int64], cat: list[bool]
) -> NDArray[np.float64]:
    """Leave-poses-out predictions of ``y`` from features ``x`` (folds ``f`` per cell)."""
    out = np.zeros_like(y)
    for k in np.unique(f):
        est = HistGradientBoostingRegressor(
            max_iter=100,
            learning_rate=0.1,
            min_samples_leaf=40,
            random_state=0,
            categorical_features=cat if any(cat) else None,
        )
        out[f == k] = est.fit(x[f != k], y[f != k]).predict(x[f == k])
    return out


def _explained(
    cells: Cells, m: NDArray[np.bool_], f: NDArray[np.int64], target: NDArray[np.float64], sets: dict[str, list[str]]
) -> dict[str, float]:
    out = {}
    for name, cols in sets.items():
        x = np.column_stack([cells[c][m] for c in cols])
        out[name] = _r2(target, _boosted_oof(x, target, f, [c in ("segment", "board_side") for c in cols]))
    return out


def diagnose(log: LidarLog, n_folds: int, seed: int, inner: int) -> tuple[dict[str, Any], tuple[Any, ...]]:
    """All figures of the diagnosis (see the module docstring) and the arrays of the plot."""
    fold = fold_ids(log.n_poses, n_folds, random_state=seed)
    cells = cell_table(log)
    q_all, widths = lwlr_p_null_oof(log, cells["r"], cells["alpha"], fold, inner)
    hit = np.isfinite(cells["r"]) & (cells["n"] > 0)
    blocked = np.nanmean(cells["p_null"], 0) > 0.99
    m = hit & ~blocked[None]
    res_all = np.where(m, cells["p_null"] - q_all, np.nan)
    cells["nb_res"] = np.nan_to_num(0.5 * (np.roll(res_all, 1, 1) + np.roll(res_all, -1, 1)))
    y, q, res = cells["p_null"][m], q_all[m], res_all[m]
    f = fold[cells["pose"][m].astype(int)]
    pose = cells["pose"][m].astype(int)
    pose_mean = np.bincount(pose, res) / np.maximum(np.bincount(pose), 1)
    d: dict[str, Any] = {
        "n_cells": int(m.sum()),
        "blocked_bearings": int(blocked.sum()),
        "var_p_null": float(y.var()),
        "binomial_noise_var": float((y * (1 - y) / cells["n"][m]).mean()),
        "lwlr": {
            "mae_all_hit_cells": float(np.abs(cells["p_null"] - q_all)[hit].mean()),
            "mae": float(np.abs(res).mean()),
            "cv_r2": _r2(y, q),
            "widths_per_fold": widths,
            "expected_mae_if_all_or_nothing": float((2 * q * (1 - q)).mean()),
            "mae_hard_0_1": float(np.abs(y - (q > 0.5)).mean()),
        },
        "bimodality": {
            "p<0.05": float((y < 0.05).mean()),
            "0.05<=p<=0.95": float(((y >= 0.05) & (y <= 0.95)).mean()),
            "p>0.95": float((y > 0.95).mean()),
        },
        "direct_cv_r2": _explained(cells, m, f, y, DIRECT),
        "residual_cv_r2": _explained(cells, m, f, res, ON_RESIDUAL),
        "residual_per_pose_constant_share": float(pose_mean[pose].var() / res.var()),
        "residual_autocorrelation_by_bearing_lag": _autocorr(res_all, (1, 2, 5, 10, 30)),
        "null_count_ll_per_reading": persistence_ll(np.round(y * cells["n"][m]), cells["n"][m], q, f),
        "break_offset": break_offset_mae(y, q, cells["break_dist"][m], f),
    }
    d["mae_by_empirical_p"] = {
        k: {
            "share_of_cells": float(s.mean()),
            "mae": float(np.abs(res[s]).mean()),
            "share_of_abs_error": float(np.abs(res[s]).sum() / np.abs(res).sum()),
        }
        for k, s in (("p<0.05", y < 0.05), ("0.05<=p<=0.95", (y >= 0.05) & (y <= 0.95)), ("p>0.95", y > 0.95))
    }
    d["reliability"] = _by_bins(q, {"empirical": y, "predicted": q}, (0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.01))
    cols = {"empirical": y, "predicted": q, "abs_error": np.abs(res)}
    d["by_break_distance"] = _by_bins(cells["break_dist"][m], cols, (0, 1, 2, 4, 8, 17))
    d["by_edge_margin_rad"] = _by_bins(cells["edge_margin"][m], cols, (0, 0.02, 0.05, 0.1, 0.2, 7))
    return d, (y, q, cells["r"][m], cells["break_dist"][m], res_all)


def persistence_ll(
    k: NDArray[np.float64], n: NDArray[np.float64], q: NDArray[np.float64], f: NDArray[np.int64]
) -> dict[str, float]:
    """Held-out log-likelihood per reading of the cells' null counts ``k`` of ``n``: independent readings
    (binomial with the model's ``q``, what the model assumes) vs. persistent cells (beta-binomial with the
    same mean ``q`` and an intra-cell correlation ``rho`` fitted on the training folds)."""
    grid = np.array([0.01, 0.03, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95])

    def ll(rho: float, s: NDArray[np.bool_]) -> NDArray[np.float64]:
        c = 1 / rho - 1
        return stats.betabinom.logpmf(k[s], n[s], q[s] * c, (1 - q[s]) * c)

    bb = np.zeros_like(q)
    rhos = []
    for j in np.unique(f):
        rho = float(grid[np.argmax([ll(g, f != j).sum() for g in grid])])
        bb[f == j] = ll(rho, f == j)
        rhos.append(rho)
    return {
        "independent": float(stats.binom.logpmf(k, n, q).sum() / n.sum()),
        "persistent": float(bb.sum() / n.sum()),
        "rho_per_fold": rhos,
    }


def break_offset_mae(
    y: NDArray[np.float64], q: NDArray[np.float64], brk: NDArray[np.float64], f: NDArray[np.int64]
) -> dict[str, float]:
    """MAE of ``q`` and of ``q`` with a pooled logit offset by scan-break distance (nested: offsets fitted
    on the other folds' held-out residuals, kernel width 0.5 bearing on knots 0.5..16)."""
    knots = np.array([0.5, 1.5, 2.5, 3.5, 5.5, 8.5, 16.0])
    z = special.logit(np.clip(y, 0.02, 0.98)) - special.logit(np.clip(q, 0.02, 0.98))
    out = q.copy()
    for j in np.unique(f):
        w = np.exp(-0.5 * ((brk[f != j][:, None] - knots) / 0.5) ** 2)
        g = (w * z[f != j, None]).sum(0) / np.maximum(w.sum(0), 1e-9)
        out[f == j] = special.expit(special.logit(q[f == j]) + np.interp(brk[f == j], knots, g))
    return {"mae": float(np.abs(y - q).mean()), "mae_with_break_offset": float(np.abs(y - out).mean())}


def _autocorr(res: NDArray[np.float64], lags: tuple[int, ...]) -> dict[str, float]:
    out = {}
    for lag in lags:
        b = np.roll(res, lag, axis=1)
        ok = np.isfinite(res) & np.isfinite(b)
        out[str(lag)] = float(np.corrcoef(res[ok], b[ok])[0, 1])
    return out


def _by_bins(x: NDArray[np.float64], vals: dict[str, NDArray[np.float64]], edges: tuple[float, ...]) -> dict[str, Any]:
    out = {}
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        s = (x >= lo) & (x < hi)
        out[f"[{lo}, {hi})"] = {
            "cells": int(s.sum()),
            **{k: float(v[s].mean()) if s.any() else None for k, v in vals.items()},
        }
    return out


def _table(title: str, rows: dict[str, dict[str, Any]]) -> list[str]:
    cols = list(next(iter(rows.values())))
    out = ["", f"| {title} | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for k, v in rows.items():
        cells = (f"{v[c]:.4g}" if isinstance(v[c], float) else str(v[c]) for c in cols)
        out.append(f"| {k} | " + " | ".join(cells) + " |")
    return out


def markdown(d: dict[str, Any]) -> str:
    """The report as Markdown."""
    lw, ll, bo = d["lwlr"], d["null_count_ll_per_reading"], d["break_offset"]
    lines = [
        f"# p_null residual diagnosis ({d['n_cells']} hit cells; {d['blocked_bearings']} blocked bearings left out)",
        "",
        f"- variance of the empirical p_null {d['var_p_null']:.4f}; binomial noise {d['binomial_noise_var']:.5f}",
        "- bimodality: " + ", ".join(f"{k} {v:.3f}" for k, v in d["bimodality"].items()),
        f"- extended LWLR p_null (held out): MAE {lw['mae']:.4f} (all hit cells incl. blocked "
        f"{lw['mae_all_hit_cells']:.4f}), CV R2 {lw['cv_r2']:.3f}",
        f"- MAE a calibrated q must have if cells were all-or-nothing, mean 2q(1-q): "
        f"{lw['expected_mae_if_all_or_nothing']:.4f}; MAE of the hard 0/1 prediction q > 0.5: "
        f"{lw['mae_hard_0_1']:.4f}",
        f"- per-pose constant share of the residual variance: {d['residual_per_pose_constant_share']:.3f}",
        "- residual autocorrelation across bearings at a pose (lag: r): "
        + ", ".join(f"{k}: {v:.3f}" for k, v in d["residual_autocorrelation_by_bearing_lag"].items()),
        "- held-out LL per reading of the cells' null counts: independent readings (the model) "
        f"{ll['independent']:.4f}, persistent cells (beta-binomial, same mean) {ll['persistent']:.4f} "
        f"(rho per fold {ll['rho_per_fold']})",
        f"- p_null MAE {bo['mae']:.4f}; with a pooled logit offset by scan-break distance (nested CV) "
        f"{bo['mae_with_break_offset']:.4f}",
        "",
        "| features -> empirical p_null | CV R2 |",
        "|---|---|",
    ]
    lines += [f"| {k} | {v:.3f} |" for k, v in d["direct_cv_r2"].items()]
    lines += ["", "| features -> LWLR residual | CV R2 |", "|---|---|"]
    lines += [f"| {k} | {v:.3f} |" for k, v in d["residual_cv_r2"].items()]
    lines += _table("empirical p_null", d["mae_by_empirical_p"])
    lines += _table("predicted q (reliability)", d["reliability"])
    lines += _table("break distance [bearings]", d["by_break_distance"])
    lines += _table("edge margin [rad]", d["by_edge_margin_rad"])
    return "\n".join(lines) + "\n"


def plot(data: tuple[Any, ...], path: Path) -> None:
    """Histogram of the fractions, residual vs range and break distance, residual map (pose x bearing)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    y, q, r, brk, res_all = data
    fig, ax = plt.subplots(1, 4, figsize=(18, 4))
    ax[0].hist(y, bins=50)
    ax[0].set_yscale("log")
    ax[0].set_xlabel("empirical p_null per cell")
    ax[1].scatter(r, y - q, s=2, alpha=0.3)
    ax[1].set_xlabel("nominal range [m]")
    ax[1].set_ylabel("empirical - LWLR p_null (held out)")
    ax[2].scatter(brk + np.random.default_rng(0).uniform(-0.3, 0.3, brk.shape), y - q, s=2, alpha=0.3)
    ax[2].set_xlabel("distance to the nearest nominal-scan break [bearings] (jittered)")
    im = ax[3].imshow(res_all, aspect="auto", cmap="coolwarm", vmin=-1, vmax=1, interpolation="nearest")
    ax[3].set_xlabel("bearing [deg]")
    ax[3].set_ylabel("pose")
    fig.colorbar(im, ax=ax[3], label="residual")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="../shared/data/real", help="folder holding neato_mar27_train.npz")
    ap.add_argument("--folds", type=int, default=10)
    ap.add_argument("--inner-folds", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="/tmp/real_neato_residuals")
    args = ap.parse_args()
    path = Path(args.data) / "neato_mar27_train.npz"
    if not path.exists():
        raise SystemExit(f"{path} is absent: nothing to diagnose")
    t0 = time.perf_counter()
    d, data = diagnose(load_log(path), args.folds, args.seed, args.inner_folds)
    d["seconds"], d["args"] = time.perf_counter() - t0, vars(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "residuals.json").write_text(json.dumps(d, indent=2))
    (out / "residuals.md").write_text(markdown(d))
    plot(data, out / "residuals.png")
    print(markdown(d))
    print(f"wrote {out}/residuals.json, residuals.md, residuals.png ({d['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
