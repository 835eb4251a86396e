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

Outputs: ``report.json`` and ``report.md`` (the same numbers, every field defined: :data:`FIELDS`), and
figures, each titled with its units and a legend. Sensor names are the same everywhere: ``ideal``,
``gaussian``, ``learned`` / ``kde``; in the box-world evaluation the calibrated rig plays reality and is
called ``rig``, ``learned (sample)`` is the learned model sampled per cell with its pose uncertainty.
When stderr is not a terminal (a log file, CI), each stage also prints one line to stderr.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch
from numpy.typing import NDArray
from tqdm import tqdm

# highway-env renders with pygame: SDL's off-screen driver draws without a display (the "dummy" driver draws black
# frames) and does not probe for one, which printed "XDG_RUNTIME_DIR is invalid" lines on machines without one
os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.inputs import real_path
from sensor_envs.lidar.sensors import LIDAR_NAMES
from sensor_envs.outputs import OutputTransaction, check_output, write_json
from sensor_envs.radar.sensors import RADAR_NAMES

__all__ = ["run_demo", "reactive_action", "report_markdown", "FIELDS"]

FIELDS: dict[str, str] = {
    "success_rate": "share of episodes that reached the goal (terminated, is_success)",
    "collision_rate": "share of episodes that ended touching a wall (terminated, collision)",
    "timeout_rate": "share of episodes cut at the step limit (truncated: neither goal nor wall in 500 steps)",
    "mean_return": "mean undiscounted episode return",
    "mean_steps": "mean episode length [policy steps of 0.2 s]",
    "null_share": "share of lidar readings that were nulls (no return)",
    "steps": "policy steps driven (1 s each; fewer than 20 when the ego vehicle crashed)",
    "ended_by": "why the highway run stopped: 'steps' (all 20 driven), 'crash' (terminated) or 'time' (truncated)",
    "visible_targets": "vehicle-steps inside the radar's field of view and range, not hidden (the detectable ones)",
    "detection_rate": "detected / visible targets",
    "clutter_per_step": "detections matching no vehicle, per step",
    "median_position_error_m": "median distance of a detection from its vehicle's true closest corner [m]",
    "precision": "true detections / all detections (board detection) or correct warnings / warnings (FCW)",
    "recall": "boards detected / boards present, or warned steps / steps that needed a warning (FCW)",
    "tp, fp, fn": "true positives, false positives, false negatives (counts)",
    "distance to rig": "mean point-wise distance of a sensor's precision-recall trajectory from the rig's",
    "warnings, false_alarms, missed_warnings": "forward-collision warnings given, given without need, needed "
    "but not given (policy steps)",
    "mean_gospa_m": "mean GOSPA distance of the tracker's objects from the true vehicles [m] (lower is better)",
}
"""Every field of ``report.json`` / ``report.md``, defined (written into ``report.md``)."""

_BOX_NAMES = {
    "rig": "rig",
    "model": "learned (sample)",
    "model_world": "learned",
    "baseline": "gaussian",
    "ideal": "ideal",
}
"""The box-world evaluation's sources under the names the rest of the report uses."""


def _stage(text: str) -> None:
    """One line per stage on stderr when it is not a terminal (tqdm's bars show progress on a terminal)."""
    if not sys.stderr.isatty():
        print(f"sensor-envs demo: {text}", file=sys.stderr, flush=True)


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
            _frame_figure(
                np.asarray(env.render()),
                out / f"neato_{lidar}.png",
                f"Neato-v0 ({map_name}), {lidar} lidar: last frame of episode 1 (robot radius 0.17 m)",
                _NEATO_LEGEND,
            )
        outcomes.append("success" if info["is_success"] else "collision" if info["collision"] else "timeout")
        returns.append(total)
        steps.append(t)
    env.close()
    return {
        "map": map_name,
        "episodes": episodes,
        "success_rate": outcomes.count("success") / episodes,
        "collision_rate": outcomes.count("collision") / episodes,
        "timeout_rate": outcomes.count("timeout") / episodes,
        "mean_return": round(float(np.mean(returns)), 3),
        "mean_steps": round(float(np.mean(steps)), 1),
        "null_share": round(nulls / max(readings, 1), 4),
    }


_NEATO_LEGEND = {
    "walls": (20, 20, 20),
    "rays": (170, 200, 240),
    "returns": (220, 30, 30),
    "robot (0.17 m)": (90, 90, 90),
    "goal": (30, 160, 60),
}
_HIGHWAY_LEGEND = {
    "detection": (230, 0, 230),
    "clutter": (255, 140, 0),
    "missed vehicle": (220, 0, 0),
    "field of view": (120, 170, 255),
    "ego vehicle": (50, 200, 0),
    "other vehicles": (100, 200, 255),
}


def _frame_figure(frame: NDArray[np.uint8], path: Path, title: str, legend: dict[str, tuple[int, int, int]]) -> None:
    """An env frame saved with a title and a colour legend."""
    h, w = frame.shape[:2]
    fig, ax = plt.subplots(figsize=(min(12.0, w / 80 + 1), h / 80 + 1.2))
    ax.imshow(frame)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)
    handles = [Patch(color=(c[0] / 255, c[1] / 255, c[2] / 255), label=k) for k, c in legend.items()]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=len(handles), fontsize=7)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


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
    ax.set_xlabel("bearing [deg], counter-clockwise from the robot's heading")
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
            _frame_figure(
                np.asarray(env.render()),
                out / f"highway_{radar}.png",
                f"highway-fast, {radar} radar: step {t + 1} (lanes 4 m wide; 100 deg field of view, 120 m)",
                _HIGHWAY_LEGEND,
            )
        if term or trunc:
            break
    env.close()
    err = np.concatenate(errors) if errors else np.zeros(0)
    return {
        "steps": t + 1,
        "ended_by": "crash" if term else "time" if trunc else "steps",
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
    names = _BOX_NAMES
    plot_trajectories(
        {names[k]: v for k, v in box["trajectories"].items()},
        out / "detection_pr.png",
        "Board detection on the rig's box world (the rig plays reality):\nprecision vs recall per step of the "
        "detector's development (unitless shares)",
    )
    aeb = aeb_experiment(episodes=6, max_steps=20, seed=seed)
    return {
        "board_detection_rig": {
            names[k]: {key: v[-1][key] for key in ("precision", "recall", "tp", "fp", "fn")}
            for k, v in box["trajectories"].items()
        },
        "board_detection_distance_to_rig": {names[k]: v for k, v in box["distance_to_rig"].items()},
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
            _stage(f"Neato-v0: {episodes} episodes with the {lidar} lidar")
            report["neato"][lidar] = _drive(lidar, seed, episodes, tmp)
        _stage("Neato-v0: one scan of each lidar from one pose")
        _scan_figure(LIDAR_NAMES, seed, tmp / "neato_scans.png")
        report["highway_fast"] = {}
        for radar in tqdm(RADAR_NAMES, desc="radars"):
            _stage(f"highway-fast: 20 steps with the {radar} radar")
            report["highway_fast"][radar] = _highway(radar, seed, 20, tmp)
        _stage("evaluation: board detection on the rig's box world, forward-collision warning per radar")
        report["evaluation"] = _evaluation(seed, tmp)
        write_json(tmp / "report.json", report)
        (tmp / "report.md").write_text(report_markdown(report), encoding="utf-8")
    print(json.dumps(report, indent=2))
    print(f"pictures, report.json and report.md written to {real_path(out)}")
    return report


def _md_table(rows: dict[str, dict[str, Any]], first: str) -> list[str]:
    keys = list(next(iter(rows.values())))
    lines = [f"| {first} | " + " | ".join(keys) + " |", "|---" * (len(keys) + 1) + "|"]
    lines += [f"| {name} | " + " | ".join(str(v) for v in row.values()) + " |" for name, row in rows.items()]
    return lines


def report_markdown(report: dict[str, Any]) -> str:
    """``report.md``: the report's numbers as tables, then the definition of every field (:data:`FIELDS`)."""
    ev = report["evaluation"]
    lines = [f"# sensor-envs demo (seed {report['seed']})", ""]
    lines += ["## Neato-v0: a reactive controller, the same seeded episodes with each lidar", ""]
    lines += _md_table(report["neato"], "lidar") + [""]
    lines += ["Figures: `neato_<lidar>.png` (last frame of episode 1), `neato_scans.png` (one scan per lidar).", ""]
    lines += ["## highway-fast: 20 IDLE steps with each radar (the same traffic)", ""]
    lines += _md_table(report["highway_fast"], "radar") + ["", "Figures: `highway_<radar>.png`.", ""]
    lines += ["## Board detection on the rig's box world (the rig plays reality; final detector step)", ""]
    rows = {
        k: {**v, "distance to rig": ev["board_detection_distance_to_rig"].get(k, "-")}
        for k, v in ev["board_detection_rig"].items()
    }
    lines += _md_table(rows, "source") + ["", "Figure: `detection_pr.png`.", ""]
    lines += ["## Forward-collision warning on highway-fast, per radar", ""]
    lines += _md_table(ev["forward_collision_warning"], "radar") + [""]
    lines += ["## Fields", ""] + [f"- `{k}`: {v}" for k, v in FIELDS.items()] + [""]
    return "\n".join(lines)
