"""Measured metrics of the shipped models on real data, as the JSON the model cards are generated from.

    python benchmarks/card_metrics.py lidar --data ../shared/data/real --out models/metrics/neato_lidar.json
    python benchmarks/card_metrics.py radar --fidelity DIR/fidelity.json --out models/metrics/radar_kde.json

``lidar``: the shipped learned lidar on every pose of the real Neato log ``neato_mar27_train.npz`` (29 static
poses x 200 repeats; the model never saw them: it is fitted on the calibrated rig's log). Table I (MAE of
``mu``, ``sigma``, ``p_null`` over pose-bearing cells) and the null-count log-likelihood, pooled over poses
as ``validate lidar`` pools them, with 95 % percentile intervals from a bootstrap over whole poses (cells of a
pose are correlated), beside the ideal and the Gaussian lidar on the same cells.

``radar``: the figures of ``benchmarks/real_radar_fidelity.py``'s ``fidelity.json`` (run with ``--models-from
models``) for the shipped KDE and Gaussian: NLL relative to a KDE fitted on the held-out folds' real frames,
energy distance per range bin against the real-fitted KDE's with the block-bootstrap interval of the margin,
detection bins within 0.05 of the real share. The model-independent parts of each card (how the training data
was made, how to rebuild, limitations) are kept from the existing ``--out`` file.

The output is the metrics JSON of ``sensor_envs/cards.py`` with the command and the date (UTC) of the
measurement; ``sensor-envs card MODEL --metrics JSON --out CARD.md`` renders the card.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BOOTSTRAP = 2000


def _kept(out: Path) -> dict[str, Any]:
    """The hand-written parts of an existing metrics file (training data, rebuild, limitations, use)."""
    if not out.is_file():
        return {}
    old = json.loads(out.read_text(encoding="utf-8"))
    return {k: old[k] for k in ("intended_use", "training_data", "rebuild", "limitations") if k in old}


def _portable(arg: str) -> str:
    """An argument as the repository's commands write it: the real-data folder as ``../shared/data/real``."""
    head, sep, tail = arg.partition("/shared/data/real")
    return f"../shared/data/real{tail}" if sep and Path(head).is_absolute() else arg


def _measured(data: str) -> dict[str, str]:
    args = [Path(sys.argv[0]).as_posix(), *sys.argv[1:]]
    command = "python " + " ".join(shlex.quote(_portable(a)) for a in args)
    return {"command": command, "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d"), "data": data}


def _pose_table(model: Any, log: Any, gaussian: Any) -> dict[str, list[dict[str, Any]]]:
    """Table I per pose for the model and the two baselines (one entry per pose)."""
    from sensor_envs.lidar.lwlr import lidar_features
    from sensor_envs.lidar.validate import baseline_params, table_one

    r, a = lidar_features(log.poses, log.bearings, log.require_map(), model.max_range)
    params = {
        "model": model.params_from_features(r, a),
        "ideal": baseline_params("ideal", r, a),
        "gaussian": baseline_params("gaussian", r, a, gaussian),
    }
    spur = {"model": (model.spur_mu_, model.spur_sigma_)}
    rows: dict[str, list[dict[str, Any]]] = {k: [] for k in params}
    for i in range(log.n_poses):
        sub = log.subset(np.array([i]))
        for name, p in params.items():
            one = {k: (v[i : i + 1] if np.ndim(v) and np.shape(v)[0] == log.n_poses else v) for k, v in p.items()}
            rows[name].append(table_one(sub, one, spur.get(name, (0.0, 1.0)), model.spur_above))
    return rows


def _pooled(rows: list[dict[str, Any]], idx: np.ndarray, key: str) -> float:
    """A metric pooled over poses ``idx`` as over their cells (weights: the cells or readings it averages)."""
    if key.startswith("mae_"):
        weight = "n_cells_p_null" if key == "mae_p_null" else "n_cells_mu_sigma"
        v = np.array([rows[i]["all"][key] for i in idx])
        w = np.array([rows[i]["all"][weight] for i in idx], float)
    else:
        v = np.array([rows[i][key] for i in idx])
        w = np.array([rows[i]["n_readings"] for i in idx], float)
    ok = np.isfinite(v) & (w > 0)
    return float(np.sum(v[ok] * w[ok]) / np.sum(w[ok]))


def lidar_metrics(data: Path) -> dict[str, Any]:
    """The shipped learned lidar on the real Neato poses (module docstring)."""
    from sensor_envs.lidar.calibrate import load_real_log
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LidarLWLR
    from sensor_envs.lidar.sensors import GaussianLidar
    from sensor_envs.modelio import default_model_path

    model = LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE))
    log = load_real_log(data)
    gaussian = model.baseline() or GaussianLidar()
    rows = _pose_table(model, log, gaussian)
    rng = np.random.default_rng(0)
    poses = np.arange(log.n_poses)
    boots = [rng.choice(poses, poses.size) for _ in range(BOOTSTRAP)]
    metrics = []
    for key, name, unit in (
        ("mae_mu", "MAE of mu (Table I)", "m"),
        ("mae_sigma", "MAE of sigma (Table I)", "m"),
        ("mae_p_null", "MAE of p_null (Table I)", ""),
        ("ll_null_counts_per_reading", "null-count log-likelihood per reading (higher is better)", "nats"),
    ):
        value = _pooled(rows["model"], poses, key)
        draws = [_pooled(rows["model"], b, key) for b in boots]
        ideal, gauss = _pooled(rows["ideal"], poses, key), _pooled(rows["gaussian"], poses, key)
        metrics.append(
            {
                "name": name,
                "value": round(value, 5),
                "interval": [round(float(np.percentile(draws, 2.5)), 5), round(float(np.percentile(draws, 97.5)), 5)],
                "unit": unit,
                "reference": f"ideal {ideal:.5g}, Gaussian {gauss:.5g}",
                "note": f"{log.n_poses} real poses, bootstrap over poses",
            }
        )
    return {"measured": _measured(f"the real Neato log {log.source and Path(log.source).name}"), "metrics": metrics}


def radar_metrics(fidelity: Path, model: str) -> dict[str, Any]:
    """The shipped radar ``model`` ("kde" or "gaussian") from real_radar_fidelity.py's JSON (module docstring)."""
    rep = json.loads(fidelity.read_text(encoding="utf-8"))
    frames = f"{rep['n_frames']} frames, {rep['folds']} folds of {rep['block']}-frame blocks"
    measured = _measured(f"Astyx HiRes2019 ({frames})")
    source = (  # the run that wrote the report, then this one (the report's folder as DIR: no machine path)
        f"python benchmarks/real_radar_fidelity.py --data ../shared/data/real/{rep['data_name']} --out DIR "
        f"--models-from {Path(str(rep['after_from'])).name} --seed {rep['seed']}"
    )
    measured["command"] = f"{source} && " + measured["command"].replace(str(fidelity.parent), "DIR")
    return {"measured": measured, "metrics": radar_rows(rep, model)}


def radar_rows(rep: dict[str, Any], model: str) -> list[dict[str, Any]]:
    """Metric rows of one shipped radar model from a fidelity report (keys as real_radar_fidelity.py writes).

    The KDE is scored at its stationary law (``kde_after_stationary``), the Gaussian as it is
    (``gaussian_after``); the reference is the KDE fitted on the other folds' real frames (``kde_real_fitted``).
    """
    name = {"kde": "kde_after_stationary", "gaussian": "gaussian_after"}[model]
    row, ref, real = rep["models"][name], rep["models"]["kde_real_fitted"], rep["real"]
    tgt = rep["targets"][name]
    folds = [f[name]["nll_outcome"] / f["kde_real_fitted"]["nll_outcome"] - 1 for f in rep["per_fold"] if name in f]
    rows: list[dict[str, Any]] = []
    for key, what in (
        ("nll_outcome", "NLL of outcomes (miss or offset)"),
        ("nll_z_given_detected", "NLL of z given a detection"),
    ):
        rows.append(
            {
                "name": what,
                "value": round(row[key], 4),
                "interval": None,
                "unit": "nats",
                "reference": f"real-fitted KDE {ref[key]:.4f} ({100 * tgt[f'{key}_rel']:+.1f} %)",
                "note": f"{rep['folds']} folds"
                + (
                    f"; per fold {100 * min(folds):+.1f} to {100 * max(folds):+.1f} %"
                    if key == "nll_outcome" and folds
                    else ""
                ),
            }
        )
    bins = rep["range_bins_m"]
    for b, (lo, hi) in enumerate(zip(bins[:-1], bins[1:], strict=True)):
        e, e_ref = row["energy_all"][b], ref["energy_all"][b]
        lo_m, hi_m = row["energy_margin_ci"][b]
        rows.append(
            {
                "name": f"energy distance of z, {lo:g}-{hi:g} m",
                "value": round(e, 4),
                "interval": [round(v, 4) for v in row["energy_ci"][b]],
                "unit": "m",
                "reference": f"real-fitted KDE {e_ref:.4f} (ratio {e / e_ref:.2f}; target 1.15)",
                "note": f"margin to target [{lo_m:+.3f}, {hi_m:+.3f}] m",
            }
        )
    for b, (lo, hi) in enumerate(zip(bins[:-1], bins[1:], strict=True)):
        lo_r, hi_r = real["det_range_ci"][b]
        rows.append(
            {
                "name": f"detection share, {lo:g}-{hi:g} m",
                "value": round(row["det_range"][b], 3),
                "interval": None,
                "unit": "",
                "reference": f"real {real['det_range'][b]:.3f} [{lo_r:.3f}, {hi_r:.3f}] ({real['n_range'][b]} rows)",
                "note": "",
            }
        )
    rows.append(
        {
            "name": "detection bins (range, azimuth) within 0.05 of the real share",
            "value": int(tgt["det_bins_within_0.05"].split("/")[0]),
            "interval": None,
            "unit": f"of {tgt['det_bins_within_0.05'].split('/')[1]}",
            "reference": f"inside the real share's 95 % interval: {tgt['det_bins_within_block_ci']}",
            "note": f"largest gap {tgt['max_det_gap']:.3f}",
        }
    )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    lid = sub.add_parser("lidar")
    lid.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real"), help="real data folder")
    lid.add_argument("--out", required=True, help="metrics JSON to write")
    rad = sub.add_parser("radar")
    rad.add_argument("--fidelity", required=True, help="fidelity.json of benchmarks/real_radar_fidelity.py")
    rad.add_argument("--model", choices=("kde", "gaussian"), default="kde")
    rad.add_argument(
        "--heldout",
        default=None,
        help="also the rows of benchmarks/real_radar_validate.py's models/metrics/NAME.heldout.json (mean and "
        "median NLL with intervals against the Gaussian, the tail chosen on other folds)",
    )
    rad.add_argument("--out", required=True, help="metrics JSON to write")
    args = ap.parse_args()
    out = Path(args.out)
    blob = lidar_metrics(Path(args.data)) if args.what == "lidar" else radar_metrics(Path(args.fidelity), args.model)
    if getattr(args, "heldout", None):
        held = json.loads(Path(args.heldout).read_text(encoding="utf-8"))
        blob["metrics"] = blob["metrics"] + held["metrics"]
        blob["measured"]["command"] += f" --heldout {Path(args.heldout).name} (from: {held['measured']['command']})"
    blob = {**blob, **_kept(out)}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(blob, indent=1) + "\n", encoding="utf-8")
    for m in blob["metrics"]:
        print(f"{m['name']}: {m['value']} {m.get('unit', '')} {m.get('interval')} ({m.get('reference', '')})")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
