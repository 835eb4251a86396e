"""Learned lidar mean vs the raycast on unseen real poses: bias shrinkage and pose correction (issue #12).

Record (issue 40; not maintained, see docs/history/scripts.md). Found: per-fold MAE of `mu` on held-out real poses
for the raycast, the learned bias unshrunk and CV-shrunk, with and without pose correction (`0fdb5b9`); its outcome
is the default `bias_shrinkage="cv"`.

    PYTHONPATH=. python docs/history/scripts/real_lidar_bias.py --data ../shared/data/real --out DIR [--folds 10]
        [--inner-folds 10] [--seed 0] [--variant extended] [--force]

On the real Neato log ``neato_mar27_train.npz`` (29 static poses, approximate poses), leave-poses-out
outer folds: each fold fits :class:`~sensor_envs.lidar.lwlr.LidarLWLR` on the other poses (its own inner
leave-poses-out CV of kernel widths and of the bias shrinkage) and predicts ``mu`` at the held-out poses'
log (approximate) poses. MAE of ``mu`` [m] against the held-out cells' mean of in-range readings, over
cells whose ray hits the map and that have at least 2 in-range readings (Table I's ``mae_mu`` on hit cells):

* ``raycast``: ``mu = r`` (the zero-bias model);
* ``learned_unshrunk``: the learned bias as is (``bias_shrinkage=0``);
* ``learned_cv_shrinkage``: the default ``bias_shrinkage="cv"``;
* ``pose_corrected_unshrunk`` / ``pose_corrected_cv_shrinkage``: the same with ``pose_correction=True``
  (training poses corrected by least squares jointly with a per-bearing bias before the bias is learned).

The shrinkage only scales the bias table at lookup (kernel widths and tables do not depend on it), so
each fold fits two models (with and without pose correction) and reads the unshrunk ``mu`` from the same
tables with the shrinkage set to 0. Prints the per-fold table, the pooled MAE and the number of folds where
a model is worse than the raycast; writes ``DIR/real_lidar_bias.md`` and ``DIR/real_lidar_bias.json``
(refuses an existing DIR unless ``--force``; never write it inside the repository).
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from sensor_envs.lidar.log import load_log
from sensor_envs.lidar.lwlr import LidarLWLR, cell_statistics, lidar_features, pose_fold_groups
from sensor_envs.lidar.pose_correction import correct_poses
from sensor_envs.outputs import output_folder, write_json
from sensor_envs.rng import fold_ids

MODELS = (
    "raycast",
    "learned_unshrunk",
    "learned_cv_shrinkage",
    "pose_corrected_unshrunk",
    "pose_corrected_cv_shrinkage",
)


def _mu(model: LidarLWLR, r: np.ndarray, a: np.ndarray, shrinkage: float | None = None) -> np.ndarray:
    """``mu`` [m] of ``model`` at features ``r, a``; ``shrinkage`` overrides the fitted one (same tables)."""
    if shrinkage is not None:
        model = copy.copy(model)
        model.bias_shrinkage_ = shrinkage
    return model.params_from_features(r, a)["mu"]


def run(path: Path, n_folds: int, inner_folds: int, seed: int, variant: str) -> dict[str, Any]:
    """Outer leave-poses-out folds on the log at ``path``: per-fold and pooled MAE of ``mu`` per model."""
    log = load_log(path)
    fold = fold_ids(pose_fold_groups(log.poses), n_folds, random_state=seed)
    r, a = lidar_features(log.poses, log.bearings, log.require_map(), 5.0)
    st = cell_statistics(log, 6.0, split_spurious=True)
    err = {m: np.zeros(n_folds) for m in MODELS}
    err_c = {m: np.zeros(n_folds) for m in MODELS}
    cnt, cnt_c = np.zeros(n_folds), np.zeros(n_folds)
    folds: list[dict[str, Any]] = []
    for f in tqdm(range(n_folds), desc="outer folds"):
        tr, te = fold != f, fold == f
        train = log.subset(tr)
        kw = {"variant": variant, "n_folds": min(inner_folds, int(tr.sum())), "random_state": seed, "progress": False}
        t0 = time.perf_counter()
        plain = LidarLWLR(**kw).fit(train)
        corrected = LidarLWLR(pose_correction=True, **kw).fit(train)
        secs = time.perf_counter() - t0
        # diagnostic: the held-out poses corrected by the raycast alone (their own readings, zero bias)
        pc, _, _ = correct_poses(log.subset(te), st["mean"][te], st["n_ok"][te], 5.0, n_iter=1)
        rc, ac = lidar_features(pc, log.bearings, log.require_map(), 5.0)
        row: dict[str, Any] = {"fold": f, "held_out_poses": np.flatnonzero(te).tolist()}
        for tag, rr, aa, e, c in (("", r[te], a[te], err, cnt), ("corrected_test_", rc, ac, err_c, cnt_c)):
            mus = {
                "raycast": np.where(np.isfinite(rr), rr, 0.0),
                "learned_unshrunk": _mu(plain, rr, aa, 0.0),
                "learned_cv_shrinkage": _mu(plain, rr, aa),
                "pose_corrected_unshrunk": _mu(corrected, rr, aa, 0.0),
                "pose_corrected_cv_shrinkage": _mu(corrected, rr, aa),
            }
            m = np.isfinite(rr) & (st["n_ok"][te] >= 2)
            c[f] = m.sum()
            row[f"{tag}n_cells"] = int(c[f])
            for name, mu in mus.items():
                e[name][f] = np.abs(mu - st["mean"][te])[m].sum()
                row[f"{tag}mae_{name}"] = e[name][f] / max(c[f], 1)
        for tag, model in (("learned", plain), ("pose_corrected", corrected)):
            sc = model.cv_scores_["bias_shrinkage"]
            row[f"shrinkage_{tag}"] = model.bias_shrinkage_
            row[f"inner_{tag}"] = {
                k: sc[k] for k in ("cv_mae_raycast", "cv_mae_unshrunk", "cv_mae_chosen", "n_pass_every_fold")
            }
            row[f"inner_{tag}"]["inner_folds_unshrunk_worse"] = int(
                sum(p["mae_unshrunk"] > p["mae_raycast"] for p in sc["per_fold"])
            )
        row["pose_correction"] = corrected.cv_scores_["pose_correction"]
        row["fit_seconds"] = secs
        folds.append(row)
    pooled = {name: float(err[name].sum() / cnt.sum()) for name in MODELS}
    pooled_c = {name: float(err_c[name].sum() / cnt_c.sum()) for name in MODELS}
    kw = {"variant": variant, "n_folds": min(inner_folds, log.n_poses), "random_state": seed, "progress": False}
    whole = {}
    for tag, model in (
        ("learned", LidarLWLR(**kw).fit(log)),
        ("pose_corrected", LidarLWLR(pose_correction=True, **kw).fit(log)),
    ):
        whole[tag] = {"shrinkage": model.bias_shrinkage_, "inner_cv": model.cv_scores_["bias_shrinkage"]}
    worse = {
        name: int(sum(r[f"mae_{name}"] > r["mae_raycast"] + 1e-12 for r in folds))
        for name in MODELS
        if name != "raycast"
    }
    return {
        "data": path.name,
        "n_poses": log.n_poses,
        "outer_folds": n_folds,
        "inner_folds": inner_folds,
        "seed": seed,
        "variant": variant,
        "cells": "held-out cells whose ray hits the map (at the log's pose) with >= 2 in-range readings",
        "metric": "MAE of mu [m] vs the cell mean of in-range readings, at the log's (approximate) poses",
        "pooled_mae_mu": pooled,
        "pooled_mae_mu_at_corrected_test_poses": pooled_c,
        "corrected_test_poses": "each held-out pose corrected by least squares of its own cell means "
        "against the raycast (zero bias; favours the raycast), cells re-selected at the corrected pose",
        "fit_on_all_poses": whole,
        "mean_of_fold_mae_mu": {name: float(np.mean([r[f"mae_{name}"] for r in folds])) for name in MODELS},
        "folds_worse_than_raycast": worse,
        "per_fold": folds,
    }


def markdown(rep: dict[str, Any]) -> str:
    """The per-fold table and the pooled MAE of ``mu`` [mm] as markdown."""
    short = ["raycast", "learned", "learned+CV shrink", "pose-corr.", "pose-corr.+CV shrink"]
    lines = [
        f"# Learned lidar mu vs raycast on unseen poses ({rep['data']}, {rep['variant']} variant)",
        "",
        f"{rep['outer_folds']} leave-poses-out outer folds (seed {rep['seed']}), inner CV {rep['inner_folds']} folds. "
        f"Metric: {rep['metric']}; cells: {rep['cells']}. MAE in mm; s = chosen shrinkage.",
        "",
        "| fold | poses | cells | " + " | ".join(short) + " | s (learned) | s (pose-corr.) |",
        "|---:|---|---:|" + "---:|" * len(short) + "---:|---:|",
    ]
    for r in rep["per_fold"]:
        vals = " | ".join(f"{1000 * r[f'mae_{m}']:.2f}" for m in MODELS)
        lines.append(
            f"| {r['fold']} | {','.join(map(str, r['held_out_poses']))} | {r['n_cells']} | {vals} | "
            f"{r['shrinkage_learned']:.2f} | {r['shrinkage_pose_corrected']:.2f} |"
        )
    pooled = " | ".join(f"**{1000 * rep['pooled_mae_mu'][m]:.2f}**" for m in MODELS)
    mean = " | ".join(f"{1000 * rep['mean_of_fold_mae_mu'][m]:.2f}" for m in MODELS)
    lines += [f"| pooled | | | {pooled} | | |", f"| mean of folds | | | {mean} | | |", ""]
    lines.append(
        "Folds worse than the raycast: "
        + ", ".join(f"{m} {n}/{rep['outer_folds']}" for m, n in rep["folds_worse_than_raycast"].items())
    )
    lines += ["", f"Diagnostic, {rep['corrected_test_poses']} (MAE in mm):", ""]
    lines += ["| fold | cells | " + " | ".join(short) + " |", "|---:|---:|" + "---:|" * len(short)]
    for r in rep["per_fold"]:
        vals = " | ".join(f"{1000 * r[f'corrected_test_mae_{m}']:.2f}" for m in MODELS)
        lines.append(f"| {r['fold']} | {r['corrected_test_n_cells']} | {vals} |")
    pooled_c = " | ".join(f"**{1000 * rep['pooled_mae_mu_at_corrected_test_poses'][m]:.2f}**" for m in MODELS)
    lines += [f"| pooled | | {pooled_c} |", ""]
    for tag, w in rep["fit_on_all_poses"].items():
        cv = w["inner_cv"]
        lines.append(
            f"Fit on all {rep['n_poses']} poses ({tag}): chosen s = {w['shrinkage']}; its CV MAE of mu [mm]: raycast "
            f"{1000 * cv['cv_mae_raycast']:.2f}, unshrunk {1000 * cv['cv_mae_unshrunk']:.2f}, chosen "
            f"{1000 * cv['cv_mae_chosen']:.2f}; inner folds where the unshrunk bias is worse than the raycast: "
            f"{sum(p['mae_unshrunk'] > p['mae_raycast'] for p in cv['per_fold'])}/{len(cv['per_fold'])}."
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="folder holding neato_mar27_train.npz")
    ap.add_argument("--out", type=Path, required=True, help="report folder (refused if it exists, unless --force)")
    ap.add_argument("--folds", type=int, default=10)
    ap.add_argument("--inner-folds", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variant", choices=("extended", "seed"), default="extended")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    path = args.data / "neato_mar27_train.npz"
    if not path.exists():
        print(f"{path}: absent, nothing to report", file=sys.stderr)
        return 2
    with output_folder(args.out, args.force, inputs=[path]) as folder:
        rep = run(path, args.folds, args.inner_folds, args.seed, args.variant)
        md = markdown(rep)
        print(md)
        (folder / "real_lidar_bias.md").write_text(md, encoding="utf-8")
        write_json(folder / "real_lidar_bias.json", {**rep, "args": {k: str(v) for k, v in vars(args).items()}})
    print(f"wrote {args.out}/real_lidar_bias.md and .json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
