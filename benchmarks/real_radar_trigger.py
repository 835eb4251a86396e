"""Why the shipped KDE radar is farther from the real "car in my lane" trigger than the Gaussian, and a fix.

Part 1 (diagnosis, all frames, the shipped model files as they are): for the trigger zone of
``sensor-envs evaluate radar-detection`` (40 m x +-1.75 m), the share of the cycles without a car in the zone
where the trigger fires anyway (false triggers), split into those fired by clutter and those fired by a
target's output that moved into the zone; the clutter inside the lane per cycle and x bin; and per x bin of
the closest corner, the share of in-zone boxes whose output lands in the zone (misses and lateral offsets).

Part 2 (held out): folds of 10-frame blocks (those of ``evaluate radar-detection --fit``). For each fold, the
rig's clutter law is refitted on the OTHER folds' frames (:func:`sensor_envs.radar.calibrate.fit_clutter`:
joint range x azimuth cell shares) and a clutter log of ``--rig-cycles`` cycles is drawn from that rig; the
KDE and Gaussian files get the clutter their ``fit`` would take from a rig log with that clutter (the KDE:
counts and positions resampled; the Gaussian: Poisson rate and one 2-D Gaussian); their target outputs are
the shipped files'. Each fold's cycles are then scored as ``evaluate radar-detection`` does: mean distance of
the precision-recall points to the real ones over the trigger's operating points. Reported: mean over folds
with a 95 % t interval, and the paired difference KDE - Gaussian per fold.

    python benchmarks/real_radar_trigger.py --data ../shared/data/real/astyx_hires2019 \\
        [--kde models/radar_kde.npz --gaussian models/radar_gaussian.npz --rig models/radar_rig.json]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from sensor_envs.evaluate.lidar_experiments import summarise
from sensor_envs.evaluate.radar_detection import (
    TRIGGER_STEPS,
    _in_zone,
    _simulate,
    _trajectory,
    cycle_index,
    load_radar_source,
)
from sensor_envs.radar.calibrate import fit_clutter, frames_from_log
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import MAX_CLUTTER_POSITIONS, KDERadarModel
from sensor_envs.radar.log import target_tuples
from sensor_envs.radar.rig import RadarRig, load_rig
from sensor_envs.radar.sensors import make_radar

ZONE = TRIGGER_STEPS[2]
X_BINS = (0.0, 10.0, 20.0, 30.0, 40.0)


def decompose(truth: np.ndarray, runs: list, corner: np.ndarray, n: int) -> dict[str, Any]:
    """False-trigger and miss components of the 40 m x +-1.75 m trigger over a source's runs."""
    _, mx, hw = ZONE
    neg = ~truth
    fire_c = fire_t = fire = 0
    lane = np.zeros(len(X_BINS) - 1)
    moved_in = 0
    inzone = _in_zone(corner, mx, hw)
    bx = np.digitize(corner[:, 0], X_BINS) - 1
    hit = np.zeros(len(X_BINS) - 1)
    tot = np.zeros(len(X_BINS) - 1)
    det_n = inz_n = 0
    outward: list[np.ndarray] = []
    for cyc_t, meas, cyc_c, xy in runs:
        det = ~np.isnan(meas[:, 0]) & inzone
        det_n += det.sum()
        inz_n += _in_zone(meas[det], mx, hw).sum()
        outward.append((meas[det, 1] - corner[det, 1]) * np.sign(corner[det, 1]))
        fc = np.zeros(n, bool)
        fc[cyc_c[_in_zone(xy, mx, hw)]] = True
        ft = np.zeros(n, bool)
        ft[cyc_t[_in_zone(meas, mx, hw)]] = True
        fire_c += (fc & neg).sum()
        fire_t += (ft & neg).sum()
        fire += ((fc | ft) & neg).sum()
        in_lane = np.abs(xy[:, 1]) <= hw
        lane += np.histogram(xy[in_lane, 0], X_BINS)[0]
        moved_in += (_in_zone(meas, mx, hw) & ~inzone).sum()
        for b in range(len(X_BINS) - 1):
            sel = inzone & (bx == b)
            tot[b] += sel.sum()
            hit[b] += _in_zone(meas[sel], mx, hw).sum()
    k, m = len(runs), max(int(neg.sum()), 1)
    return {
        "false_trigger_share": round(fire / (k * m), 4),
        "by_clutter": round(fire_c / (k * m), 4),
        "by_targets": round(fire_t / (k * m), 4),
        "clutter_in_lane_per_cycle": [round(v, 3) for v in lane / (k * n)],
        "targets_moved_into_zone_per_cycle": round(moved_in / (k * n), 4),
        "in_zone_boxes_reported_in_zone": [round(h / t, 3) if t else None for h, t in zip(hit, tot, strict=True)],
        "in_zone_boxes": int(inzone.sum()),
        "in_zone_detected_share": round(det_n / max(k * inzone.sum(), 1), 4),
        "in_zone_output_in_zone_given_detected": round(inz_n / max(det_n, 1), 4),
        "in_zone_outward_offset_q10_q50_q90": [
            round(float(v), 3) for v in np.quantile(np.concatenate(outward), [0.1, 0.5, 0.9])
        ],
    }


def with_rig_clutter(kde: Any, gauss: Any, rig: RadarRig, cycles: int, rng: np.random.Generator) -> tuple[Any, Any]:
    """Copies of the two models with the clutter their ``fit`` takes from a log of ``cycles`` rig cycles."""
    polar = [rig.sample_clutter_polar(rng) for _ in range(cycles)]
    counts = np.array([r.size for r, _ in polar], dtype=np.int64)
    r = np.concatenate([p[0] for p in polar])
    az = np.concatenate([p[1] for p in polar])
    xy = np.stack([r * np.cos(az), r * np.sin(az)], axis=1)
    k, g = copy.deepcopy(kde), copy.deepcopy(gauss)
    sub = (
        xy[np.sort(rng.choice(xy.shape[0], MAX_CLUTTER_POSITIONS, replace=False))]
        if len(xy) > MAX_CLUTTER_POSITIONS
        else xy
    )
    k.clutter_counts_, k.clutter_xy_ = counts, sub
    g.clutter_rate_ = float(counts.mean())
    g.clutter_mean_, g.clutter_cov_ = xy.mean(axis=0), np.cov(xy.T) + g.cov_floor * np.eye(2)
    return k, g


def t_interval(v: list[float]) -> list[float]:
    a = np.asarray(v, dtype=float)
    h = stats.t.ppf(0.975, a.size - 1) * a.std(ddof=1) / np.sqrt(a.size)
    return [round(float(a.mean()), 4), round(float(a.mean() - h), 4), round(float(a.mean() + h), 4)]


def markdown(out: dict[str, Any], kde_name: str) -> str:
    """The report's tables (diagnosis on all frames; held-out folds)."""
    d = out["diagnosis"]
    lines = [
        f"### Diagnosis: trigger zone 40 m x +-1.75 m, all {out['cycles']} frames, {kde_name} as shipped",
        "",
        f"Generated on {time.strftime('%Y-%m-%d', time.gmtime())} (UTC) by "
        f"`python benchmarks/real_radar_trigger.py {' '.join(sys.argv[1:])}`.",
        "",
        "| source | false triggers (share of cycles without a car in the zone) | fired by clutter | fired by a "
        "target | clutter in the lane per cycle, x 0-10 / 10-20 / 20-30 / 30-40 m | target outputs moved into the "
        "zone per cycle | in-zone boxes reported in the zone, x 0-10 / 10-20 / 20-30 / 30-40 m |",
        "|---|---|---|---|---|---|---|",
    ]
    for k, v in d.items():
        lane = " / ".join(f"{x:.3f}" for x in v["clutter_in_lane_per_cycle"])
        inz = " / ".join("-" if x is None else f"{x:.3f}" for x in v["in_zone_boxes_reported_in_zone"])
        lines.append(
            f"| {k} | {v['false_trigger_share']:.3f} | {v['by_clutter']:.3f} | {v['by_targets']:.3f} | {lane} | "
            f"{v['targets_moved_into_zone_per_cycle']:.3f} | {inz} |"
        )
    lines += [
        "",
        "In-zone boxes (closest corner in the zone): detected share, share of the detected outputs in the zone, "
        "cross-range offset of the output from the corner, outward positive (q10 / median / q90, m):",
        "",
        "| source | boxes | P(detected) | P(output in the zone given detected) | outward offset q10 / q50 / q90 |",
        "|---|---|---|---|---|",
    ]
    for k, v in d.items():
        q = " / ".join(f"{x:+.2f}" for x in v["in_zone_outward_offset_q10_q50_q90"])
        lines.append(
            f"| {k} | {v['in_zone_boxes']} | {v['in_zone_detected_share']:.3f} | "
            f"{v['in_zone_output_in_zone_given_detected']:.3f} | {q} |"
        )
    h = out["held_out"]
    lines += [
        "",
        f"### Held out: distance to the real precision-recall trajectory, {len(h['per_fold']['kde'])} folds "
        "(lower is closer)",
        "",
        "| source | per fold | mean [95 % t interval] |",
        "|---|---|---|",
    ]
    for k, v in h["per_fold"].items():
        m = h["mean_ci95"][k]
        lines.append(f"| {k} | {' '.join(f'{x:.3f}' for x in v)} | {m[0]:.3f} [{m[1]:.3f}, {m[2]:.3f}] |")
    lines += ["", "| paired difference per fold | mean [95 % t interval] | verdict |", "|---|---|---|"]
    for key, label in (
        ("kde_minus_gaussian_ci95", "KDE - Gaussian (clutter as shipped)"),
        ("kde_joint_minus_gaussian_joint_ci95", "KDE - Gaussian (both with the joint clutter law)"),
        ("kde_joint_minus_gaussian_ci95", "KDE with the joint clutter law - the Gaussian as shipped"),
        ("kde_user_fit_minus_gaussian_user_fit_ci95", "KDE - Gaussian, both fitted on the other folds' real frames"),
    ):
        if key not in h:
            continue
        m = h[key]
        word = "closer" if m[2] < 0 else ("farther" if m[1] > 0 else "not distinguishable")
        lines.append(f"| {label} | {m[0]:+.4f} [{m[1]:+.4f}, {m[2]:+.4f}] | {word} |")
    lines += ["", f"Command: `{out['command']}` ({out['seconds']} s)."]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--kde", default=None)
    ap.add_argument("--gaussian", default=None)
    ap.add_argument("--rig", default="models/radar_rig.json")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--rig-cycles", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    ap.add_argument("--out-md", default=None)
    ap.add_argument(
        "--user-fit", action="store_true", help="also KDE and Gaussian fitted on each fold's training frames"
    )
    a = ap.parse_args()
    t0 = time.time()
    log = load_radar_source(a.data)
    tt = target_tuples(log)
    cyc, n = cycle_index(log)
    cyc_t = cyc[tt.row]
    cl = log.is_clutter
    real = (
        cyc_t,
        np.stack([log["meas_x"][tt.row], log["meas_y"][tt.row]], 1),
        cyc[cl],
        np.stack([log["meas_x"][cl], log["meas_y"][cl]], 1),
    )
    truth_by_step = []
    for _, mx, hw in TRIGGER_STEPS:
        t = np.zeros(n, dtype=bool)
        t[cyc_t[_in_zone(tt.corner, mx, hw)]] = True
        truth_by_step.append(t)
    kde, gauss = make_radar("kde", a.kde), make_radar("gaussian", a.gaussian)
    cfg, _ = load_rig(a.rig)
    rng = np.random.default_rng(a.seed)
    flags = [
        f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}")
        for k, v in vars(a).items()
        if v is not None and v is not False and k not in ("json", "out_md")
    ]
    out: dict[str, Any] = {"command": "python benchmarks/real_radar_trigger.py " + " ".join(flags)}
    # Part 1: diagnosis on all frames, the files as given
    runs = {
        "real": [real],
        "kde": _simulate(kde, tt.corner, cyc_t, n, a.draws, rng),
        "gaussian": _simulate(gauss, tt.corner, cyc_t, n, a.draws, rng),
    }
    out["diagnosis"] = {k: decompose(truth_by_step[2], v, tt.corner, n) for k, v in runs.items()}
    # Part 2: held-out folds, clutter law refitted on the other folds
    _, bid = np.unique(np.stack([log["sequence"], log["frame"] // a.block], axis=1), axis=0, return_inverse=True)
    fold_of_cycle = np.zeros(n, dtype=int)
    fold_of_cycle[cyc] = bid.ravel() % a.folds
    per_fold: dict[str, list[float]] = {}
    diag_after: dict[str, list] = {"kde_joint": [], "gaussian_joint": []}
    for f in range(a.folds):
        test_c = np.flatnonzero(fold_of_cycle == f)
        remap = -np.ones(n, dtype=np.int64)
        remap[test_c] = np.arange(test_c.size)
        train = log.select(fold_of_cycle[cyc] != f)
        cfg_f = fit_clutter(cfg, frames_from_log(train))
        k_j, g_j = with_rig_clutter(kde, gauss, RadarRig(cfg_f), a.rig_cycles, rng)
        sel = fold_of_cycle[cyc_t] == f
        m = test_c.size
        cyc_sel = remap[cyc_t[sel]]
        keep = fold_of_cycle[cyc[cl]] == f
        real_f = (cyc_sel, real[1][sel], remap[real[2][keep]], real[3][keep])
        truth_f = [t[test_c] for t in truth_by_step]
        trajs = {"real": _trajectory(truth_f, [real_f], m)}
        srcs = {"kde": kde, "gaussian": gauss, "kde_joint": k_j, "gaussian_joint": g_j, "ideal": make_radar("ideal")}
        if a.user_fit:  # what `evaluate radar-detection --fit` fits: both models on the other folds' real frames
            srcs["kde_user_fit"] = KDERadarModel(use_prev=False, cv_group="sequence", random_state=a.seed + f).fit(
                train
            )
            srcs["gaussian_user_fit"] = GaussianRadar().fit(train)
        for name, model in srcs.items():
            r = _simulate(model, tt.corner[sel], cyc_sel, m, a.draws, rng)
            trajs[name] = _trajectory(truth_f, r, m)
            if name in diag_after:
                diag_after[name].append(decompose(truth_f[2], r, tt.corner[sel], m))
        for name, d in summarise(trajs).items():
            per_fold.setdefault(name, []).append(d)
        print(f"fold {f}: " + ", ".join(f"{k} {v[-1]:.3f}" for k, v in per_fold.items()), flush=True)
    out["held_out"] = {
        "per_fold": per_fold,
        "mean_ci95": {k: t_interval(v) for k, v in per_fold.items()},
        "kde_minus_gaussian_ci95": t_interval(
            [x - y for x, y in zip(per_fold["kde"], per_fold["gaussian"], strict=True)]
        ),
        "kde_joint_minus_gaussian_joint_ci95": t_interval(
            [x - y for x, y in zip(per_fold["kde_joint"], per_fold["gaussian_joint"], strict=True)]
        ),
        "kde_joint_minus_gaussian_ci95": t_interval(
            [x - y for x, y in zip(per_fold["kde_joint"], per_fold["gaussian"], strict=True)]
        ),
        "diagnosis_joint_fold0": {k: v[0] for k, v in diag_after.items()},
    }
    if a.user_fit:
        out["held_out"]["kde_user_fit_minus_gaussian_user_fit_ci95"] = t_interval(
            [x - y for x, y in zip(per_fold["kde_user_fit"], per_fold["gaussian_user_fit"], strict=True)]
        )
    out["cycles"] = n
    out["seconds"] = round(time.time() - t0, 1)
    text = json.dumps(out, indent=1)
    print(text)
    if a.json:
        Path(a.json).write_text(text + "\n")
    if a.out_md:
        Path(a.out_md).write_text(markdown(out, Path(a.kde or "radar_kde.npz").name))


if __name__ == "__main__":
    main()
