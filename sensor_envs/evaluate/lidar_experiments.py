"""Detection experiments of the lidar seed: real (or rig) scans vs scans simulated by the learned model and baselines.

* :func:`log_experiment` (seed Sec. IV-A on a static-pose log such as the real Neato data): the
  detector's trajectory on the log's own scans, and on scans sampled at the log's poses and map by
  the learned model (:meth:`~sensor_envs.lidar.lwlr.LidarLWLR.sample`, pose uncertainty included)
  and by the Gaussian baseline (:class:`~sensor_envs.lidar.gaussian.GaussianLidar` on the nominal
  raycast) and the ideal lidar. Unless a model file is given, the model and the baseline are fitted
  leave-poses-out: the poses are dealt into ``folds`` folds, and the scans of each fold are simulated
  by a model fitted on the other folds (never on the scans being compared).
* :func:`boxworld_experiment` (the seed's box world): ``n_configs`` rooms with boards of several
  lengths at random places, recorded by the reference rig (:class:`~sensor_envs.lidar.rig.NeatoRig`,
  standing in for reality) and simulated at the rig log's approximate poses and nominal map.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm.auto import tqdm

from sensor_envs.evaluate.lidar_detection import (
    TRAJECTORY_STEPS,
    flatten_repeats,
    present_targets,
    run_trajectory,
    steps_table,
    target_indices,
)
from sensor_envs.evaluate.metrics import trajectory_distance
from sensor_envs.geometry import raycast_pose
from sensor_envs.inputs import InputError
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr import LidarLWLR
from sensor_envs.lidar.sensors import GaussianLidar, IdealLidar

__all__ = ["log_experiment", "boxworld_experiment", "boxworld_map", "simulate", "summarise"]

BOARD_LENGTHS = (0.3, 0.45, 0.61, 0.9)
"""Board lengths [m] of the box world (0.61 m is the target, as the real room's interior board)."""


def simulate(
    sensor: LidarLWLR | GaussianLidar | IdealLidar,
    poses: NDArray[np.float64],
    bearings: NDArray[np.float64],
    map_segments: NDArray[np.float64],
    repeats: int,
    rng: np.random.Generator,
    max_range: float = 5.0,
    pose_uncertainty: bool = True,
) -> NDArray[np.float64]:
    """``(P, K, repeats)`` readings [m] (``0`` = null) of a sensor at ``(P, 3)`` poses in a map.

    The learned model samples with its pose uncertainty (:meth:`LidarLWLR.sample`, as for a log's
    approximate poses: one rigid pose error per pose, then the worlds' draw at the perturbed pose) or,
    with ``pose_uncertainty=False``, as the worlds' sensor does (:class:`~sensor_envs.lidar.lwlr.LearnedLidar`:
    the poses taken as true). The Gaussian and ideal lidars measure the nominal raycast.
    """
    if isinstance(sensor, LidarLWLR):
        if pose_uncertainty:
            return sensor.sample(poses, map_segments, rng, n_repeats=repeats)
        p = {k: v[..., None] for k, v in sensor.params_full(poses, map_segments).items()}
        return sensor.sample_from_params(p, rng, p["mu"].shape[:2] + (int(repeats),))
    r, a, _ = raycast_pose(poses, bearings, map_segments, max_range)
    rr = np.repeat(r[..., None], repeats, axis=2)
    aa = np.repeat(a[..., None], repeats, axis=2)
    x = sensor.measure(rr, aa, rng)
    return np.nan_to_num(x, nan=0.0)


LIDAR_NOTES = (
    "'model' is LidarLWLR.sample at the log's approximate poses: one rigid pose error per pose (the model's "
    "pose_sd_, fitted from the training poses' corrections), shared by all bearings and repeats, then the "
    "worlds' per-reading draw at the perturbed pose, with persistent nulls per cell over the repeats (since "
    "issue 43; before, each cell's mean was drawn independently, which turned walls and boards jagged).",
    "'model_world' is the same fitted model sampled as the worlds' LearnedLidar does (poses taken as true, "
    "no pose error): the learned per-bearing noise, nulls and spurious returns.",
    "'baseline' is the Gaussian lidar (refitted on the same training poses when the model is fitted): no "
    "persistent nulls, so boards are seen whole more often than on the real sensor (recall too high at the "
    "recall steps).",
)


def _SOURCES(model: Any, gaussian: Any) -> tuple[tuple[str, Any], ...]:
    """The simulated sources: the learned model as specified (``sample``), as the worlds use it, the baselines."""
    return (("model", model), ("model_world", model), ("baseline", gaussian), ("ideal", IdealLidar()))


def summarise(trajs: dict[str, list[dict[str, Any]]], reference: str = "real") -> dict[str, float]:
    """``distance_to_<reference>`` of every other trajectory (mean point-wise distance in P-R space)."""
    return {k: round(trajectory_distance(v, trajs[reference]), 4) for k, v in trajs.items() if k != reference}


def log_experiment(
    log: LidarLog,
    *,
    model: LidarLWLR | None = None,
    baseline: str = "gaussian",
    length: float = 0.61,
    repeats: int = 10,
    folds: int = 3,
    cv_folds: int = 5,
    seed: int = 0,
    max_range: float = 5.0,
    fit_log: Callable[[LidarLog], tuple[LidarLWLR, GaussianLidar]] | None = None,
) -> dict[str, Any]:
    """Detection trajectories on a static-pose log vs the simulators at its poses (see the module docstring).

    Args:
        log: ``(P, K, R)`` log with a map containing a segment of ``length``.
        model: a fitted model to use for every pose; ``None`` fits one per fold, leave-poses-out.
        baseline: ``"gaussian"`` (refitted to the same training poses, or from the model's card /
            defaults when ``model`` is given).
        length: target length [m].
        repeats: scans per pose (the first ``repeats`` readings of each pose for the real source).
        folds: leave-poses-out folds (when fitting).
        cv_folds: kernel-width CV folds of each fit.
        seed: seed of the fold assignment and of the simulators' noise.
        max_range: sensor range [m].
        fit_log: replaces the fit of (model, baseline) on a training log (tests).

    Returns:
        The report dictionary (``trajectories``, ``distance_to_real``, ``steps``, ``data``).
    """
    if baseline != "gaussian":
        raise InputError(f"--baseline: only 'gaussian' is available, got {baseline!r}")
    segs = log.require_map()
    if not target_indices(segs, length).size:
        raise InputError(f"{log.source}: field 'map_segments' has no segment of the target length {length} m")
    if log.ranges.shape[2] < repeats:
        raise InputError(f"{log.source}: field 'ranges' has {log.ranges.shape[2]} repeats, fewer than {repeats}")
    rng = np.random.default_rng(seed)
    P = log.n_poses
    fold = rng.permutation(np.arange(P) % folds) if model is None else np.zeros(P, dtype=int)
    sims = {k: np.zeros((P, log.n_bearings, repeats)) for k, _ in _SOURCES(None, None)}
    fits = []
    for f in tqdm(range(int(fold.max()) + 1), desc="fit + simulate per fold", disable=model is not None):
        test = fold == f
        if model is None:
            train = log.subset(~test)
            if fit_log is not None:
                m, g = fit_log(train)
            else:
                from sensor_envs.lidar.validate import fit_gaussian_lidar

                m = LidarLWLR(n_folds=min(cv_folds, train.n_poses), random_state=seed, verbose=False).fit(train)
                g = fit_gaussian_lidar(train, m.spur_above, max_range)
            fits.append({"fold": f, "train_poses": int((~test).sum()), "test_poses": int(test.sum()), "h": m.h_})
        else:
            m, g = model, model.baseline() or GaussianLidar()
        poses = log.poses[test]
        for name, sensor in _SOURCES(m, g):
            sims[name][test] = simulate(
                sensor, poses, log.bearings, segs, repeats, rng, max_range, name != "model_world"
            )
    real = np.nan_to_num(log.ranges[:, :, :repeats], nan=0.0)
    sources = {"real": real, **sims}
    trajs = _trajectories(sources, log.poses, log.bearings, segs, length, max_range)
    return {
        "experiment": "detection on a static-pose log",
        "target_length_m": length,
        "steps": steps_table(),
        "trajectories": trajs,
        "distance_to_real": summarise(trajs),
        "notes": list(LIDAR_NOTES),
        "data": {
            "log": str(log.source),
            "poses": P,
            "scans_per_source": P * repeats,
            "repeats": repeats,
            "model": "fitted leave-poses-out" if model is None else "given model file",
            "folds": fits,
        },
    }


def _trajectories(
    sources: dict[str, NDArray[np.float64]],
    poses: NDArray[np.float64],
    bearings: NDArray[np.float64],
    segs: NDArray[np.float64],
    length: float,
    max_range: float,
    targets: NDArray[np.int64] | None = None,
) -> dict[str, list[dict[str, Any]]]:
    tg = target_indices(segs, length) if targets is None else targets
    out = {}
    bar = tqdm(total=len(sources) * len(TRAJECTORY_STEPS), desc="detector trajectories")
    for name, x in sources.items():
        scans, sp = flatten_repeats(x, poses)
        present = present_targets(sp, bearings, segs, tg, max_range)
        out[name] = run_trajectory(
            scans, bearings, sp, segs, length, max_range=max_range, present=present, targets=tg, progress=bar.update
        )
    bar.close()
    return out


def boxworld_map(rng: np.random.Generator, n_boards: int = 3, room: tuple[float, float] = (4.0, 3.0)) -> NDArray:
    """A room ``room`` [m] with ``n_boards`` boards of :data:`BOARD_LENGTHS` (one of 0.61 m) at random places.

    Boards are at least 0.5 m from the walls and their centres ``(l1 + l2) / 2 + 0.3`` m apart.
    """
    w, h = room
    walls = [[[0, 0], [w, 0]], [[w, 0], [w, h]], [[w, h], [0, h]], [[0, h], [0, 0]]]
    lengths = [0.61, *rng.choice(BOARD_LENGTHS, n_boards - 1)]
    boards: list[tuple[NDArray, float]] = []
    for L in lengths:  # rejection sampling, a few tries per board
        for _ in range(200):
            c = rng.uniform([0.5 + L / 2, 0.5 + L / 2], [w - 0.5 - L / 2, h - 0.5 - L / 2])
            if all(np.linalg.norm(c - c2) >= (L + L2) / 2 + 0.3 for c2, L2 in boards):
                boards.append((c, float(L)))
                break
    segs = list(walls)
    for c, L in boards:
        t = rng.uniform(0, np.pi)
        d = 0.5 * L * np.array([np.cos(t), np.sin(t)])
        segs.append([list(c - d), list(c + d)])
    return np.asarray(segs, dtype=np.float64)


def boxworld_experiment(
    model: LidarLWLR,
    *,
    baseline: GaussianLidar | None = None,
    n_configs: int = 50,
    poses_per_config: int = 2,
    repeats: int = 5,
    length: float = 0.61,
    seed: int = 0,
    unit_seed: int = 0,
    max_range: float = 5.0,
) -> dict[str, Any]:
    """The seed's box-world detection experiment with the rig standing in for reality (module docstring).

    Args:
        model: the learned model (fitted on other rig data, e.g. the shipped model).
        baseline: the Gaussian baseline (default: the one in the model's card, else defaults).
        n_configs: number of board configurations (rooms).
        poses_per_config: static poses per configuration.
        repeats: scans per pose.
        length: target length [m] (boards of other lengths are distractors).
        seed: seed of the configurations, the rig's noise and the simulators' noise.
        unit_seed: the rig unit.
        max_range: sensor range [m].
    """
    from sensor_envs.lidar.rig import NeatoRig

    rig = NeatoRig(unit_seed=unit_seed, max_range=max_range)
    g = baseline or model.baseline() or GaussianLidar()
    rng = np.random.default_rng(seed)
    per: dict[str, list[list[dict[str, Any]]]] = {}
    totals: dict[str, list[dict[str, Any]]] = {}
    n_boards = []
    for _ in tqdm(range(n_configs), desc="box-world configurations"):
        segs = boxworld_map(rng)
        n_boards.append(len(segs) - 4)
        log, _ = rig.record(segs, rng, n_poses=poses_per_config, repeats=repeats)
        sources = {"rig": np.nan_to_num(log.ranges, nan=0.0)}  # the rig plays reality: named for what it is
        for name, sensor in _SOURCES(model, g):
            sources[name] = simulate(
                sensor, log.poses, log.bearings, segs, repeats, rng, max_range, name != "model_world"
            )
        tg = target_indices(segs, length)
        for name, x in sources.items():
            scans, sp = flatten_repeats(x, log.poses)
            present = present_targets(sp, log.bearings, segs, tg, max_range)
            per.setdefault(name, []).append(
                run_trajectory(scans, log.bearings, sp, segs, length, max_range=max_range, present=present, targets=tg)
            )
    from sensor_envs.evaluate.metrics import precision_recall

    for name, runs in per.items():
        steps = []
        for k, (step_name, _) in enumerate(TRAJECTORY_STEPS):
            c = {key: sum(r[k][key] for r in runs) for key in ("tp", "fp", "fn", "detections", "scans")}
            p, r = precision_recall(c["tp"], c["fp"], c["fn"])
            steps.append({"step": k, "name": step_name, "precision": round(p, 4), "recall": round(r, 4), **c})
        totals[name] = steps
    return {
        "experiment": "box-world detection on the rig (rig = reality)",
        "target_length_m": length,
        "steps": steps_table(),
        "trajectories": totals,
        "distance_to_rig": summarise(totals, reference="rig"),
        "notes": list(LIDAR_NOTES),
        "data": {
            "configurations": n_configs,
            "boards_per_configuration": int(np.median(n_boards)),
            "board_lengths_m": list(BOARD_LENGTHS),
            "poses_per_configuration": poses_per_config,
            "repeats": repeats,
            "scans_per_source": n_configs * poses_per_config * repeats,
            "rig": f"NeatoRig(unit_seed={unit_seed})",
        },
    }
