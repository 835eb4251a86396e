"""The main job (``sensor-envs demo``): drive every world with every sensor and write pictures and a report.

For each lidar of the Neato world, a simple reactive controller that sees only the observation
(head for the goal along the free direction nearest to it, never drive into a return ahead) runs the
same seeded episodes (same starts and goals: the world's stream does not depend on the lidar); the
demo saves the first episode's last frame per lidar, one scan of every lidar at a shared pose (polar
plot), and ``report.json`` with, per lidar, success and collision rates, mean return and steps, and the
share of null readings. Then highway-fast runs 20 policy steps with each radar (same traffic for one
seed): detection rate of visible targets, clutter per step and median position error of the
detections against the true closest corners, plus a frame with the radar overlay per radar. It ends
with a small algorithm-level evaluation where the sensors differ (``report["evaluation"]``): the seed's
board detector on the rig's box world per lidar (``detection_pr.png``) and a forward-collision warning
per radar (false alarms, missed warnings); ``sensor-envs evaluate`` runs the full experiments.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.lidar.sensors import LIDAR_NAMES
from sensor_envs.outputs import OutputTransaction, check_output, write_json
from sensor_envs.radar.sensors import RADAR_NAMES

__all__ = ["run_demo", "reactive_action"]


def reactive_action(obs: NDArray[np.float32], n_bearings: int = 360, clearance: float = 0.45) -> NDArray[np.float32]:
    """A normalised ``(v, omega)`` toward the goal along the free direction nearest to it.

    Uses only the observation (scan with nulls = 0, then goal x, y in the robot frame). A bearing is
    free when every reading within +-25 degrees of it is beyond ``clearance`` [m] or beyond the goal;
    nulls count as free (the lidar saw nothing), which is how null readings mislead a planner.
    """
    scan = np.asarray(obs[:n_bearings], dtype=np.float64)
    scan = np.where(scan > 0, scan, np.inf)
    gx, gy = float(obs[n_bearings]), float(obs[n_bearings + 1])
    g_dist, g_dir = np.hypot(gx, gy), np.arctan2(gy, gx)
    half = max(1, n_bearings * 25 // 360)
    windows = np.lib.stride_tricks.sliding_window_view(np.concatenate([scan[-half:], scan, scan[:half]]), 2 * half + 1)
    need = np.minimum(clearance, g_dist)
    free = windows.min(axis=1) > need
    bearings = np.arange(n_bearings) * (2 * np.pi / n_bearings)
    err = (bearings - g_dir + np.pi) % (2 * np.pi) - np.pi
    if not free.any():
        return np.array([-0.3, 1.0], dtype=np.float32)
    b = err[free][np.argmin(np.abs(err[free]))] + g_dir
    b = (b + np.pi) % (2 * np.pi) - np.pi
    # Safety limiter: a forward move d brings a return at (r, phi) to about r - d cos(phi); keep it
    # beyond the robot's radius plus a margin (0.22 m) for every return in the front half-plane.
    cosb = np.cos(bearings)
    front = cosb > 0.05
    d_max = np.min((scan[front] - 0.22) / cosb[front])
    v = np.clip(min(g_dist, 0.5) / 0.5, 0.0, 1.0) * max(0.0, np.cos(b)) ** 2
    v = float(np.clip(v, 0.0, max(0.0, d_max) / 0.06))  # 0.06 m = v_max * dt at full speed
    return np.array([v, np.clip(2.0 * b, -1.0, 1.0)], dtype=np.float32)


def _drive(lidar: str, seed: int, episodes: int, out: Path, map_name: str = "seed_room") -> dict[str, Any]:
    """Run ``episodes`` seeded episodes with the reactive controller; save the first episode's last frame."""
    env = gym.make("sensor_envs/Neato-v0", lidar=lidar, map=map_name, render_mode="rgb_array")
    outcomes, returns, steps, nulls, readings = [], [], [], 0, 0
    for ep in range(episodes):
        obs, info = env.reset(seed=seed + ep)
        total, term, trunc, t = 0.0, False, False, 0
        while not (term or trunc):
            obs, r, term, trunc, info = env.step(reactive_action(obs))
            total, t = total + float(r), t + 1
            nulls += int(np.sum(info["scan"] == 0.0))
            readings += info["scan"].size
        if ep == 0:
            plt.imsave(out / f"neato_{lidar}.png", np.asarray(env.render()))
        outcomes.append("success" if info["is_success"] else "collision" if info["collision"] else "timeout")
        returns.append(total)
        steps.append(t)
    env.close()
    return {
        "map": map_name,
        "episodes": episodes,
        "success_rate": outcomes.count("success") / episodes,
        "collision_rate": outcomes.count("collision") / episodes,
        "mean_return": round(float(np.mean(returns)), 3),
        "mean_steps": round(float(np.mean(steps)), 1),
        "null_share": round(nulls / max(readings, 1), 4),
    }


def _scan_figure(lidars: tuple[str, ...], seed: int, path: Path) -> None:
    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="polar")
    for lidar in lidars:
        env = gym.make("sensor_envs/Neato-v0", lidar=lidar, map="seed_room")
        _, info = env.reset(seed=seed, options={"start": [0.9, 0.5, 0.6], "goal": [3.0, 1.5, 0.0]})
        scan = np.where(info["scan"] > 0, info["scan"], np.nan)
        style: dict[str, Any] = {"ideal": dict(lw=1.0, color="k")}.get(lidar, dict(ls="", marker=".", ms=3))
        base: Any = env.unwrapped
        ax.plot(base.bearings, scan, label=lidar, **style)
        env.close()
    ax.set_ylim(0.0, 5.0)  # the lidar's max range: spurious ~16.9 m returns fall outside (counted in the title)
    ax.set_title("One scan of each lidar from the same pose (seed room), range [m];\nreturns beyond 5 m not drawn")
    ax.legend(loc="upper left", bbox_to_anchor=(-0.12, 1.0), fontsize=8)  # outside the 225-degree label
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _highway(radar: str, seed: int, steps: int, out: Path) -> dict[str, Any]:
    """Drive highway-fast with the IDLE meta-action; measure what the radar reports against the truth."""
    env = gym.make("sensor_envs/HighwayFast-v0", radar=radar, render_mode="rgb_array")
    env.reset(seed=seed)
    visible = detected = clutter = 0
    errors: list[NDArray[np.float64]] = []
    for t in range(steps):
        _, _, term, trunc, info = env.step(1)  # IDLE: keep lane and speed
        ri = info["radar"]
        visible += int(ri.visible.sum())
        detected += int(ri.detected.sum())
        own = ri.detection_target >= 0
        clutter += int((~own).sum())
        errors.append(np.linalg.norm(ri.detections[own] - ri.truth_reference[ri.detection_target[own]], axis=1))
        if t == steps // 2:
            plt.imsave(out / f"highway_{radar}.png", np.asarray(env.render()))
        if term or trunc:
            break
    env.close()
    err = np.concatenate(errors) if errors else np.zeros(0)
    return {
        "steps": t + 1,
        "visible_targets": visible,
        "detection_rate": round(detected / max(visible, 1), 4),
        "clutter_per_step": round(clutter / (t + 1), 3),
        "median_position_error_m": round(float(np.median(err)), 3) if err.size else None,
    }


_FCW_KEYS = ("warnings", "false_alarms", "missed_warnings", "precision", "recall", "mean_gospa_m")


def _evaluation(seed: int, out: Path) -> dict[str, Any]:
    """A small algorithm-level evaluation where the sensors differ (``sensor-envs evaluate`` does the full one).

    Board detection on the rig's box world (rig = reality; the seed's detector, final step of its
    trajectory) for the ideal, Gaussian and learned lidars, and the forward-collision warning on
    highway-fast for each radar (false alarms, missed warnings).
    """
    from sensor_envs.evaluate.lidar_experiments import boxworld_experiment
    from sensor_envs.evaluate.radar_aeb import aeb_experiment
    from sensor_envs.evaluate.report import plot_trajectories
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LidarLWLR
    from sensor_envs.modelio import default_model_path

    box = boxworld_experiment(
        LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE)), n_configs=6, poses_per_config=1, repeats=3, seed=seed
    )
    plot_trajectories(box["trajectories"], out / "detection_pr.png", "board detection on the rig's box world")
    names = {
        "real": "rig",
        "model": "learned (sample)",
        "model_world": "learned",
        "baseline": "gaussian",
        "ideal": "ideal",
    }
    aeb = aeb_experiment(episodes=6, max_steps=20, seed=seed)
    return {
        "board_detection_rig": {
            names[k]: {key: v[-1][key] for key in ("precision", "recall", "tp", "fp", "fn")}
            for k, v in box["trajectories"].items()
        },
        "board_detection_distance_to_rig": {names[k]: v for k, v in box["distance_to_real"].items()},
        "forward_collision_warning": {k: {key: v[key] for key in _FCW_KEYS} for k, v in aeb["radars"].items()},
    }


def run_demo(out: str | Path, seed: int = 0, episodes: int = 10, force: bool = False) -> dict[str, Any]:
    """Run the demo into folder ``out``; returns (and writes to ``out/report.json``) the summary.

    The folder is built beside ``out`` and renamed onto it at the end (an existing non-empty ``out``
    is refused unless ``force``, and replaced only after the demo succeeded).
    """
    out = check_output(out, folder=True, force=force)
    report: dict[str, Any] = {"seed": seed, "neato": {}}
    with OutputTransaction() as tx:
        tmp = tx.folder(out)
        for lidar in tqdm(LIDAR_NAMES, desc="Neato-v0 lidars"):
            report["neato"][lidar] = _drive(lidar, seed, episodes, tmp)
        _scan_figure(LIDAR_NAMES, seed, tmp / "neato_scans.png")
        report["highway_fast"] = {radar: _highway(radar, seed, 20, tmp) for radar in tqdm(RADAR_NAMES, desc="radars")}
        report["evaluation"] = _evaluation(seed, tmp)
        write_json(tmp / "report.json", report)
    print(json.dumps(report, indent=2))
    print(f"pictures and report.json written to {out.resolve()}")
    return report
