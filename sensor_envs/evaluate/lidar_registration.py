"""Registration along a corridor (the lidar seed's Fig. 6): a Kalman filter with a gradient-descent scan matcher.

A robot drives a fixed trajectory through the ``corridor`` map. Odometry increments (noisy) drive the
prediction of a Kalman filter on the pose ``(x, y, theta)`` [m, m, rad]; its measurement is the pose
found by a scan matcher: gradient descent, from the predicted pose, of the mean squared distance of
the scan's points (mapped with the pose) to their nearest map segment, for a fixed number of
refining iterations. For ``iterations`` in (10, 30, 50, 100), the report gives the mean matching time
per scan and the mean point-wise distance [m] of the filter's estimated positions to those of the
100-iteration run, per scan source: the rig (standing in for reality), the learned model (as the
worlds use it), the Gaussian baseline and the ideal lidar. The same odometry noise and, per source, the
same scans are used for every iteration count. ``distance_to_reference`` of a simulator: the mean
absolute difference of its distance-vs-iterations curve from the rig's [m].
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.geometry import raycast_pose
from sensor_envs.maps import load_map
from sensor_envs.outputs import write_json

__all__ = ["corridor_trajectory", "match_scan", "run_filter", "registration_experiment", "ITERATIONS"]

ITERATIONS = (10, 30, 50, 100)


def corridor_trajectory(n: int = 40) -> NDArray[np.float64]:
    """``(n, 3)`` true poses along the corridor's centre line with a gentle weave [m, m, rad]."""
    x = np.linspace(0.6, 5.4, n)
    y = 0.6 + 0.15 * np.sin(x * 1.3)
    th = np.arctan2(np.gradient(y), np.gradient(x))
    return np.column_stack([x, y, th])


def _nearest_on_map(pts: NDArray[np.float64], segs: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n, 2)`` nearest point of the map to each of ``pts (n, 2)`` [m]."""
    a, b = segs[:, 0], segs[:, 1]
    d = b - a
    t = np.clip(((pts[:, None] - a[None]) * d[None]).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)[None], 0, 1)
    q = a[None] + t[..., None] * d[None]
    k = np.argmin(((pts[:, None] - q) ** 2).sum(-1), axis=1)
    return q[np.arange(len(pts)), k]


def match_scan(
    pts_s: NDArray[np.float64], pose0: NDArray[np.float64], segs: NDArray[np.float64], iterations: int, lr: float = 0.1
) -> NDArray[np.float64]:
    """Gradient descent of the mean squared point-to-map distance over the pose, ``iterations`` steps.

    Args:
        pts_s: ``(n, 2)`` scan points in the sensor frame [m].
        pose0: ``(3,)`` starting pose [m, m, rad].
        segs: ``(M, 2, 2)`` map [m].
        iterations: number of gradient steps.
        lr: step size (the gradient of the mean squared distance is scaled by it; ``theta`` step
            divided by the points' mean squared range).
    """
    pose = np.asarray(pose0, dtype=np.float64).copy()
    if len(pts_s) < 3:
        return pose
    r2 = float(np.mean((pts_s**2).sum(1)))
    for _ in range(iterations):  # the refining iterations are the experiment's variable
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rot = np.array([[c, -s], [s, c]])
        w = pts_s @ rot.T + pose[:2]
        e = w - _nearest_on_map(w, segs)
        drot = pts_s @ np.array([[-s, -c], [c, -s]]).T  # d(w)/d(theta)
        g = np.array([e[:, 0].mean(), e[:, 1].mean(), (e * drot).sum(1).mean()]) * 2
        pose -= lr * np.array([g[0], g[1], g[2] / max(r2, 1e-6)])
    return pose


def run_filter(
    scans: NDArray[np.float64],
    bearings: NDArray[np.float64],
    odometry: NDArray[np.float64],
    start: NDArray[np.float64],
    segs: NDArray[np.float64],
    iterations: int,
    max_range: float = 5.0,
    q: tuple[float, float, float] = (0.03, 0.03, 0.03),
    r: tuple[float, float, float] = (0.02, 0.02, 0.02),
) -> tuple[NDArray[np.float64], float]:
    """Kalman filter over a trajectory: ``(T, 3)`` estimates and the mean matching time per scan [s].

    Args:
        scans: ``(T, K)`` readings [m] (``0``/``NaN`` = null).
        bearings: ``(K,)`` [rad].
        odometry: ``(T - 1, 3)`` increments in the robot frame ``dx, dy, dtheta``.
        start: ``(3,)`` initial pose.
        segs: map.
        iterations: scan-matcher iterations.
        max_range: readings beyond are dropped [m].
        q: process noise standard deviations per step (x [m], y [m], theta [rad]).
        r: measurement (matched pose) standard deviations.
    """
    est = [np.asarray(start, dtype=np.float64)]
    P = np.diag(np.square(r))
    Q, R = np.diag(np.square(q)), np.diag(np.square(r))
    times = []
    for t in range(len(scans)):  # one filter step per scan
        x = est[-1].copy()
        if t > 0:
            dx, dy, dth = odometry[t - 1]
            c, s = np.cos(x[2]), np.sin(x[2])
            x = x + np.array([c * dx - s * dy, s * dx + c * dy, dth])
            F = np.array([[1, 0, -s * dx - c * dy], [0, 1, c * dx - s * dy], [0, 0, 1]])
            P = F @ P @ F.T + Q
        ok = np.isfinite(scans[t]) & (scans[t] > 0) & (scans[t] <= max_range)
        pts = np.column_stack([scans[t, ok] * np.cos(bearings[ok]), scans[t, ok] * np.sin(bearings[ok])])
        t0 = time.perf_counter()
        z = match_scan(pts, x, segs, iterations)
        times.append(time.perf_counter() - t0)
        K = P @ np.linalg.inv(P + R)
        innov = z - x
        innov[2] = (innov[2] + np.pi) % (2 * np.pi) - np.pi
        x = x + K @ innov
        P = (np.eye(3) - K) @ P
        if t == 0:
            est[0] = x
        else:
            est.append(x)
    return np.asarray(est), float(np.mean(times))


def registration_experiment(
    model: Any = None, *, n_poses: int = 40, seed: int = 0, iterations: tuple[int, ...] = ITERATIONS
) -> dict[str, Any]:
    """The corridor registration experiment for every scan source (see the module docstring)."""
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LearnedLidar, LidarLWLR
    from sensor_envs.lidar.rig import NeatoRig
    from sensor_envs.lidar.sensors import GaussianLidar, IdealLidar
    from sensor_envs.modelio import default_model_path

    m = model if isinstance(model, LidarLWLR) else LidarLWLR.load(model or default_model_path(DEFAULT_MODEL_FILE))
    gauss = m.baseline() or GaussianLidar()
    rig = NeatoRig()
    segs = load_map("corridor").segments
    truth = corridor_trajectory(n_poses)
    rng = np.random.default_rng(seed)
    inc = np.diff(truth, axis=0)
    c, s = np.cos(truth[:-1, 2]), np.sin(truth[:-1, 2])
    odo = np.column_stack([c * inc[:, 0] + s * inc[:, 1], -s * inc[:, 0] + c * inc[:, 1], inc[:, 2]])
    odo = odo + rng.normal(0, [0.02, 0.01, 0.02], odo.shape)
    start = truth[0] + rng.normal(0, [0.05, 0.05, 0.03])
    r, a, _ = raycast_pose(truth, rig.bearings, segs, rig.max_range)
    sources: dict[str, Any] = {"reference": rig, "model": LearnedLidar(m), "baseline": gauss, "ideal": IdealLidar()}
    out: dict[str, Any] = {}
    for name, sensor in sources.items():
        scans = np.stack([sensor.measure(r[t], a[t], rng) for t in range(len(truth))])
        runs = {it: run_filter(scans, rig.bearings, odo, start, segs, it) for it in iterations}
        best = runs[max(iterations)][0]
        out[name] = [
            {
                "iterations": it,
                "mean_match_time_ms": round(1000 * runs[it][1], 3),
                "distance_to_final_m": round(float(np.linalg.norm(runs[it][0][:, :2] - best[:, :2], axis=1).mean()), 4),
                "error_to_truth_m": round(float(np.linalg.norm(runs[it][0][:, :2] - truth[:, :2], axis=1).mean()), 4),
            }
            for it in iterations
        ]
    ref = np.array([s["distance_to_final_m"] for s in out["reference"]])
    dist = {
        k: round(float(np.abs(np.array([s["distance_to_final_m"] for s in v]) - ref).mean()), 4)
        for k, v in out.items()
        if k != "reference"
    }
    return {
        "experiment": "registration along the corridor (Kalman filter + gradient-descent scan matcher), rig = reality",
        "poses": n_poses,
        "iterations": list(iterations),
        "curves": out,
        "distance_to_reference": dist,
    }


def write_registration_report(report: dict[str, Any], folder: Any) -> None:
    """``report.json``, ``report.md`` and ``registration.png`` (the seed's Fig. 6 layout) into ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    write_json(folder / "report.json", report)
    md = [
        f"# {report['experiment']}",
        "",
        f"Command: `{report.get('command', '')}`",
        "",
        f"distance_to_reference (mean |curve - rig curve| [m]): {report['distance_to_reference']}",
        "",
        "| source | iterations | mean match time [ms] | distance to final estimate [m] | error to truth [m] |",
        "|---|---|---|---|---|",
    ]
    for k, v in report["curves"].items():
        md += [
            f"| {k} | {s['iterations']} | {s['mean_match_time_ms']} | {s['distance_to_final_m']} "
            f"| {s['error_to_truth_m']} |"
            for s in v
        ]
    (folder / "report.md").write_text("\n".join(md) + "\n")
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.8))
    for k, v in report["curves"].items():
        its = [s["iterations"] for s in v]
        ax[0].plot(its, [s["mean_match_time_ms"] for s in v], marker="o", label=k)
        ax[1].plot(its, [s["distance_to_final_m"] for s in v], marker="o", label=k)
    ax[0].set_xlabel("refining iterations")
    ax[0].set_ylabel("mean matching time [ms]")
    ax[1].set_xlabel("refining iterations")
    ax[1].set_ylabel("distance to the 100-iteration estimate [m]")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(folder / "registration.png", dpi=120)
    plt.close(fig)
