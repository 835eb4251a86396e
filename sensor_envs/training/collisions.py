"""Collision anatomy of a highway robustness matrix: what the observation showed in the last second before a crash.

:func:`replay_run` replays the evaluation episodes of every trained policy of a finished
``sensor-envs robustness --domain highway`` run on the chosen columns' radars, with the matrix's own seeds
(episode ``e`` resets with ``EVAL_SEED + e``) and deterministic actions, and returns one
:class:`CrashRecord` per episode that ended in a collision; :func:`summarise` turns them into rates with
Wilson intervals per cell (``row->column``). highway-fast acts at 1 Hz, so "the last second" is the last
observation the policy acted on (``t - 1 s``, the step that ended in the crash); the one before it
(``t - 2 s``) is recorded too.

The car hit is the crashed vehicle nearest to the ego at the crash (highway-env marks both vehicles of a
collision ``crashed``). Geometry, at the last observation: ``bearing_ego_deg`` is the direction of the hit
car's centre from the ego's centre, in the ego frame rotated from highway-env's road frame [deg] (0 ahead,
+-180 behind; positive towards highway-env's +y, the side of the higher lane index, i.e. the driver's right
on highway-env's screen, whose y axis points down);
``bearing_ego_crash_deg`` the same at the crash; ``bearing_sensor_deg`` the direction of its radar
reference point (closest corner) from the sensor (front bumper, x forward) [deg]; ``dx_m`` its centre's
longitudinal offset from the ego's centre [m]; ``zone`` is ``"ahead"`` when ``dx_m > LENGTH``,
``"behind"`` when ``dx_m < -LENGTH``, else ``"beside"`` (``LENGTH`` = 5 m, a highway-env car);
``in_front_fov`` whether its reference point lay in the front radar's field of view (100 deg, 120 m:
:data:`~sensor_envs.envs.highway.sensor.DEFAULT_FOV`), whatever radar the column uses; ``visible``
whether the column's radar could see it (its field of view, range and occlusion); ``shown_row`` the
observation row (1 = the first non-ego row) that held it, ``None`` when no row did (with
``tracks=True``, a row counts when the hit car's detection last updated the track). A hit car outside
highway-env's perception distance at the last observation (or no crashed car: e.g. off the road) has
``zone="unknown"`` and is left out of the geometric shares.

Actions are highway-env's ``DiscreteMetaAction`` (0 LANE_LEFT, 1 IDLE, 2 LANE_RIGHT, 3 FASTER, 4 SLOWER).
``lane_change`` is true when the last action was a lane change or the ego's target lane differed from its
lane at the last observation (a change ordered earlier still under way); ``braking`` when the last action
was SLOWER; ``speed_change`` is the ego's speed at the crash minus its speed at the last observation [m/s].
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing as mp
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.evaluate.metrics import wilson_interval
from sensor_envs.inputs import parse_json, read_text
from sensor_envs.training.matrix_report import _write_atomic

__all__ = [
    "ACTIONS",
    "LENGTH",
    "CrashRecord",
    "crash_record",
    "replay_policy",
    "replay_run",
    "CACHE",
    "summarise",
    "SHARES",
]

ACTIONS = ("LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER")
"""highway-env's ``DiscreteMetaAction`` meta-actions by index."""
LANE_CHANGES = (0, 2)
SLOWER = 4
LENGTH = 5.0
"""Length of a highway-env car [m]: the hit car is beside the ego when their centres are closer along x."""


@dataclass(frozen=True)
class CrashRecord:
    """One evaluation episode that ended in a collision (see the module docstring for each field)."""

    row: str
    column: str
    seed: int
    episode: int
    step: int
    last_action: str
    action_before: str | None
    lane_change: bool
    braking: bool
    speed_change: float
    hit_found: bool
    shown_row: int | None
    shown_before: bool
    visible: bool
    in_front_fov: bool
    bearing_ego_deg: float
    bearing_sensor_deg: float
    bearing_ego_crash_deg: float
    dx_m: float
    zone: str


def _radar_wrapper(env: Any) -> Any:
    """The :class:`~sensor_envs.envs.highway.wrapper.RadarObservation` inside ``env``'s wrappers."""
    e = env
    while not hasattr(e, "last_rows"):
        e = e.env
    return e


def _snapshot(base: Any, wrapper: Any) -> dict[str, Any]:
    """What a crash record needs of one observation: the ego's state and what the radar and rows held."""
    ego, frame = base.vehicle, wrapper.last_frame
    return {
        "lane": tuple(ego.lane_index),
        "target_lane": tuple(ego.target_lane_index),
        "speed": float(ego.speed),
        "position": np.array(ego.position, dtype=np.float64),
        "heading": float(ego.heading),
        "objects": list(frame.truth.objects),
        "centres": frame.truth.centre.copy(),
        "reference_s": frame.reference_s.copy(),
        "visible": frame.visible.copy(),
        "rows": list(wrapper.last_rows.objects),
    }


def _hit_car(base: Any) -> Any:
    """The crashed vehicle nearest to the crashed ego (``None`` when there is none, e.g. off the road)."""
    ego = base.vehicle
    others = [v for v in base.road.vehicles if v is not ego and v.crashed]
    return min(others, key=lambda v: float(np.linalg.norm(v.position - ego.position))) if others else None


def _ego_frame(offset: Any, heading: float) -> Any:
    """A world offset [m] rotated into the ego frame (x forward, y left)."""
    c, s = np.cos(heading), np.sin(heading)
    return np.array([c * offset[0] + s * offset[1], -s * offset[0] + c * offset[1]])


def crash_record(
    base: Any, last: dict[str, Any], before: dict[str, Any] | None, actions: list[int], where: dict[str, Any]
) -> CrashRecord:
    """The record of a crash from the last observation ``last`` (and ``before``, one second earlier).

    Args:
        base: the unwrapped highway-env env just after the crash.
        last: :func:`_snapshot` of the observation the last action was taken on.
        before: the snapshot one policy step earlier (``None`` when the crash came on the first step).
        actions: the episode's actions so far (the last one led to the crash).
        where: ``row``, ``column``, ``seed``, ``episode`` of the record.
    """
    from sensor_envs.envs.highway.sensor import SensorSpec

    hit = _hit_car(base)
    last_action = int(actions[-1])
    lane_change = last_action in LANE_CHANGES or last["target_lane"] != last["lane"]
    common = {
        **where,
        "step": len(actions),
        "last_action": ACTIONS[last_action],
        "action_before": ACTIONS[int(actions[-2])] if len(actions) > 1 else None,
        "lane_change": bool(lane_change),
        "braking": last_action == SLOWER,
        "speed_change": round(float(base.vehicle.speed) - last["speed"], 3),
    }
    if hit is None or not any(o is hit for o in last["objects"]):  # not within perception distance: not observable
        nan = float("nan")
        return CrashRecord(
            **common,
            hit_found=hit is not None,
            shown_row=None,
            shown_before=False,
            visible=False,
            in_front_fov=False,
            bearing_ego_deg=nan,
            bearing_sensor_deg=nan,
            bearing_ego_crash_deg=nan,
            dx_m=nan,
            zone="unknown",
        )
    k = next(i for i, o in enumerate(last["objects"]) if o is hit)
    rel = _ego_frame(last["centres"][k] - last["position"], last["heading"])  # at the last observation
    at_crash = _ego_frame(np.asarray(hit.position, dtype=np.float64) - base.vehicle.position, base.vehicle.heading)
    ref = last["reference_s"][k]
    dx = float(rel[0])
    return CrashRecord(
        **common,
        hit_found=True,
        shown_row=next((i + 1 for i, o in enumerate(last["rows"]) if o is hit), None),
        shown_before=before is not None and any(o is hit for o in before["rows"]),
        visible=bool(last["visible"][k]),
        in_front_fov=bool(SensorSpec().in_view(ref.reshape(1, 2))[0]),
        bearing_ego_deg=round(float(np.degrees(np.arctan2(rel[1], rel[0]))), 2),
        bearing_sensor_deg=round(float(np.degrees(np.arctan2(ref[1], ref[0]))), 2),
        bearing_ego_crash_deg=round(float(np.degrees(np.arctan2(at_crash[1], at_crash[0]))), 2),
        dx_m=round(dx, 2),
        zone="ahead" if dx > LENGTH else "behind" if dx < -LENGTH else "beside",
    )


CACHE = "collision_replay.json"
"""A job folder's cache of its replays, one entry per column (reused while the policy, env and episodes match)."""


def _replay_column(model: Any, task: dict[str, Any], column: str) -> tuple[list[dict[str, Any]], list[float]]:
    """Play the matrix's evaluation episodes of one column; the crash records and each episode's collision."""
    import gymnasium as gym

    from sensor_envs.training.robustness import EVAL_SEED

    extra = {"max_episode_steps": task["max_episode_steps"]} if task["max_episode_steps"] else {}
    env = gym.make(task["env_id"], **task["columns"][column], **extra)
    base, wrapper = env.unwrapped, _radar_wrapper(env)
    crashes: list[dict[str, Any]] = []
    outcomes: list[float] = []
    for e in range(task["episodes"]):
        obs, _ = env.reset(seed=EVAL_SEED + e)
        history: list[dict[str, Any]] = []
        actions: list[int] = []
        done = False
        info: dict[str, Any] = {}
        while not done:
            history = [*history[-1:], _snapshot(base, wrapper)]
            action, _ = model.predict(obs, deterministic=True)
            actions.append(int(action))
            obs, _, term, trunc, info = env.step(action)
            done = term or trunc
        crashed = bool(info.get("collision", info.get("crashed", False)))
        outcomes.append(float(crashed))
        if crashed:
            where = {"row": task["row"], "column": column, "seed": task["seed"], "episode": e}
            before = history[-2] if len(history) > 1 else None
            crashes.append(asdict(crash_record(base, history[-1], before, actions, where)))
    env.close()
    return crashes, outcomes


def replay_policy(task: dict[str, Any]) -> dict[str, Any]:
    """Replay one trained policy on the columns of ``task``; returns its crash records and episode outcomes.

    ``task``: ``run_dir`` (a job folder with ``<policy>_model.zip``), ``algo``, ``policy``, ``row``, ``seed``,
    ``columns`` (column -> env keyword arguments), ``env_id``, ``episodes``, ``max_episode_steps``, ``cache``
    (reuse and update the job folder's :data:`CACHE`). Returns ``{"row", "seed", "crashes": [record dicts],
    "collision": {column: [0/1 per episode]}}``.
    """
    import stable_baselines3 as sb3
    import torch

    from sensor_envs.training.robustness import sha256

    torch.set_num_threads(1)  # as the matrix's jobs: one core, reproducible
    path = Path(task["run_dir"]) / f"{task['policy']}_model.zip"
    cache_path = Path(task["run_dir"]) / CACHE
    cache = parse_json(read_text(cache_path), str(cache_path)) if task.get("cache") and cache_path.is_file() else {}
    model = None
    crashes: list[dict[str, Any]] = []
    outcomes: dict[str, list[float]] = {}
    for column, kwargs in task["columns"].items():
        key = json.dumps([sha256(path), kwargs, task["episodes"], task["max_episode_steps"], task["env_id"]])
        if cache.get(column, {}).get("key") != key:
            if model is None:
                model = getattr(sb3, task["algo"].upper()).load(path, device="cpu")
            found, collided = _replay_column(model, task, column)
            cache[column] = {"key": key, "crashes": found, "collision": collided}
        crashes += cache[column]["crashes"]
        outcomes[column] = cache[column]["collision"]
    if task.get("cache"):
        _write_atomic(cache_path, json.dumps(cache))
    return {"row": task["row"], "seed": task["seed"], "crashes": crashes, "collision": outcomes}


def replay_run(
    run: Path,
    columns: list[str] | None = None,
    rows: list[str] | None = None,
    episodes: int | None = None,
    workers: int = 1,
    seeds: list[int] | None = None,
    cache: bool = True,
) -> dict[str, Any]:
    """Replay every (row, seed) policy of the robustness run in ``run`` on ``columns`` (default: the run's).

    Episodes default to the run's evaluation episodes, ``seeds`` to the run's (a subset: e.g. the seeds whose
    jobs are done). With ``cache``, each job folder keeps its replays (:data:`CACHE`), reused while the
    policy file, the column's env keywords and the episodes are the same (not the code: delete the caches after
    changing what a record holds). Returns ``settings`` (the run's),
    ``rows``, ``columns``, ``seeds``, ``episodes``, ``crashes`` (all records), ``collision`` (``{row: {seed:
    {column: [0/1 per episode]}}}``) and ``matrix_collision`` (the same from the run's ``eval.json``, for the
    check that the replay reproduces the matrix).
    """
    from sensor_envs.training.robustness import DOMAINS, column_kwargs

    settings = json.loads((run / "settings.json").read_text())
    if settings["domain"] != "highway":
        raise ValueError(f"{run}: a {settings['domain']} run; the collision anatomy is for highway runs")
    columns = list(columns or settings["columns"])
    rows = list(rows or settings["rows"])
    n = int(episodes or settings["eval_episodes"])
    config = settings["config"] if Path(settings["config"]).is_file() else None
    kwargs = {
        c: column_kwargs("highway", c, {}, config) if config else column_kwargs("highway", c, {}) for c in columns
    }
    seeds = list(settings["seeds"] if seeds is None else seeds)
    tasks: list[dict[str, Any]] = []
    matrix_collision: dict[str, dict[int, dict[str, list[float]]]] = {}
    for r in rows:
        for s in seeds:
            job = run / "runs" / r / f"seed{s}"
            ev = json.loads((job / "eval.json").read_text())
            matrix_collision.setdefault(r, {})[s] = {
                c: ev["cells"][c]["collision"][:n] for c in columns if c in ev["cells"]
            }
            tasks.append(
                {
                    "run_dir": str(job),
                    "algo": json.loads((job / "config.json").read_text())["config"]["algo"],
                    "policy": settings.get("policy", "final"),
                    "row": r,
                    "seed": s,
                    "columns": kwargs,
                    "env_id": DOMAINS["highway"]["env_id"],
                    "episodes": n,
                    "max_episode_steps": settings.get("max_episode_steps"),
                    "cache": cache,
                }
            )
    if workers > 1:
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
            results = list(pool.map(replay_policy, tasks))
    else:
        results = [replay_policy(t) for t in tasks]
    collision: dict[str, dict[int, dict[str, list[float]]]] = {}
    for res in results:
        collision.setdefault(res["row"], {})[res["seed"]] = res["collision"]
    return {
        "settings": settings,
        "rows": rows,
        "columns": columns,
        "seeds": seeds,
        "episodes": n,
        "crashes": [c for res in results for c in res["crashes"]],
        "collision": collision,
        "matrix_collision": matrix_collision,
    }


SHARES = {
    "lane_change": "lane change under way",
    "outside_front_fov": "hit car outside the front radar's 100° view, 1 s before",
    "shown": "hit car in the last observation",
    "braking": "last action SLOWER (braking)",
}
"""The shares of a cell's crashes :func:`summarise` reports (key: label)."""


def _share(k: int, n: int) -> dict[str, Any]:
    lo, hi = wilson_interval(k, n)
    return {"k": k, "n": n, "rate": k / n if n else float("nan"), "ci95": [lo, hi]}


def summarise(replay: dict[str, Any]) -> dict[str, Any]:
    """Per cell ``row->column``: collision rate, the shares of :data:`SHARES` among its crashes, the zones.

    Rates and shares pool the seeds' episodes, with 95 % Wilson intervals (which treat episodes and crashes as
    independent; a seed's episodes share its policy, so the intervals are narrower than a seed bootstrap's).
    ``replay_matches_matrix``: episodes whose replayed collision equals the matrix's ``eval.json``.
    """
    cells: dict[str, Any] = {}
    for r in replay["rows"]:
        for c in replay["columns"]:
            outcomes = [v for s in replay["collision"][r].values() for v in s[c]]
            recorded = [v for s in replay["matrix_collision"][r].values() for v in s.get(c, [])]
            crashes = [x for x in replay["crashes"] if x["row"] == r and x["column"] == c]
            found = [x for x in crashes if x["hit_found"] and x["zone"] != "unknown"]
            flags = {
                "lane_change": sum(x["lane_change"] for x in crashes),
                "outside_front_fov": sum(not x["in_front_fov"] for x in found),
                "shown": sum(x["shown_row"] is not None for x in found),
                "braking": sum(x["braking"] for x in crashes),
            }
            totals = {
                "lane_change": len(crashes),
                "outside_front_fov": len(found),
                "shown": len(found),
                "braking": len(crashes),
            }
            cells[f"{r}->{c}"] = {
                "episodes": len(outcomes),
                "collision": _share(int(sum(outcomes)), len(outcomes)),
                "replay_matches_matrix": (
                    int(sum(a == b for a, b in zip(outcomes, recorded, strict=False))) if recorded else None
                ),
                "shares": {k: _share(flags[k], totals[k]) for k in SHARES},
                "lane_change_and_outside_front_fov": _share(
                    sum(x["lane_change"] and not x["in_front_fov"] for x in found), len(found)
                ),
                "zones": {z: sum(x["zone"] == z for x in crashes) for z in ("ahead", "beside", "behind", "unknown")},
                "visible_to_column_radar": _share(sum(x["visible"] for x in found), len(found)),
                "shown_rows": {
                    str(i): sum(x["shown_row"] == i for x in found)
                    for i in sorted({x["shown_row"] for x in found if x["shown_row"] is not None})
                },
            }
    return {"rows": replay["rows"], "columns": replay["columns"], "episodes": replay["episodes"], "cells": cells}
