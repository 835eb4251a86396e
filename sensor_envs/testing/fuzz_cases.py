"""Generated malformed inputs for every reader and option: valid pieces and the mutations applied to them.

Shared by ``tests/test_input_properties.py`` (hypothesis draws the choices, small budget, in-process) and
``benchmarks/fuzz_inputs.py`` (a seeded ``random.Random`` draws them, each case in a subprocess under a
memory and a time limit). A case is built in a fresh folder by :func:`make_case`; it carries the command
line, the loader call behind it and whether the mutation certainly breaks the format (``must_refuse``: a
loader or command accepting it is "accepted nonsense").

Valid pieces and mutations: :mod:`sensor_envs.testing.fuzz_pieces`.
"""

from __future__ import annotations

import io
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.testing.fuzz_folders import FOLDER_FAMILIES
from sensor_envs.testing.fuzz_options import OPTION_FAMILIES
from sensor_envs.testing.fuzz_pieces import (
    MAP_JSON,
    MAP_TXT,
    MAP_YAML,
    NASTY_JSON,
    ROS_YAML,
    SEGS,
    SHIPPED,
    Case,
    Chooser,
    array_mutation,
    carmen_text,
    deep,
    lidar_arrays,
    npz_bomb,
    pgm_bytes,
    snapshot,
    special_path,
    text_mutation,
    write_astyx,
    write_bag,
    write_npz,
    write_radar_csv,
    write_text_bytes,
)
from sensor_envs.testing.fuzz_structure import STRUCTURE_FAMILIES


# --------------------------------------------------------------------------------------------- families
def _radar(c: Chooser, d: Path) -> Case:
    from sensor_envs.radar.log import read_log, target_tuples

    p = write_radar_csv(d)
    if c.integers(0, 9) == 0:
        name, p = special_path(c, d)
        must = True
    else:
        name, text, must = text_mutation(c, p.read_text(), numeric_tokens=True)
        write_text_bytes(p, text)
    argv = ["fit", "radar", str(p), "--out", str(d / "k.npz"), "--relevance", "paper"]
    return Case("radar log CSV", name, argv, lambda: target_tuples(read_log(p)), must, [p])


def _lidar_npz(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.log import load_log

    arrays = lidar_arrays()
    p = d / "log.npz"
    roll = c.integers(0, 19)
    if roll == 0:
        p.write_bytes(npz_bomb())
        name, must = "npz bomb (2 GiB inflated)", True
    elif roll == 1:
        raw = write_npz(p, arrays).read_bytes()
        k = c.integers(0, len(raw) - 1)
        p.write_bytes(raw[:k])
        name, must = f"truncated at {k}", True
    elif roll == 2:
        name, p = special_path(c, d)
        must = True
    else:
        name, must = array_mutation(c, arrays, ("ranges", "bearings", "poses", "map_segments", "t"), optional=("t",))
        write_npz(p, arrays)
    argv = ["fit", "lidar", str(p), "--out", str(d / "m.npz"), "--folds", "2", "--variant", "seed"]
    return Case("lidar log npz", name, argv, lambda: load_log(p), must, [p])


def _carmen(c: Chooser, d: Path) -> Case:
    import gzip

    from sensor_envs.lidar.log import load_log

    text = carmen_text()
    name, text, must = text_mutation(c, text, numeric_tokens=False)
    gz = c.integers(0, 2) == 0
    p = d / ("log.log.gz" if gz else "log.log")
    raw = text.encode("utf-8", errors="surrogateescape")
    p.write_bytes(gzip.compress(raw) if gz else raw)
    if gz and c.integers(0, 3) == 0:
        b = p.read_bytes()
        p.write_bytes(b[: c.integers(0, len(b) - 1)])
        name, must = name + " + gzip truncated", True
    m = write_text_bytes(d / "m.txt", MAP_TXT)
    argv = ["fit", "lidar", str(p), "--out", str(d / "m.npz"), "--max-range", "5", "--map", str(m), "--folds", "2"]
    return Case("CARMEN log", name, argv, lambda: load_log(p), must, [p, m])


def _map(c: Chooser, d: Path) -> Case:
    from sensor_envs.maps import load_map

    kind = c.choice(["txt", "json", "yaml", "ros_yaml", "pgm", "alias"])
    pgm = d / "map.pgm"
    pgm.write_bytes(pgm_bytes())
    if kind == "txt":
        name, text, must = text_mutation(c, MAP_TXT, numeric_tokens=True)
        p = write_text_bytes(d / "map.txt", text)
    elif kind == "json":
        doc = json.loads(MAP_JSON)
        i, j = c.integers(0, 3), c.integers(0, 3)
        v = c.choice(NASTY_JSON + ["deep"])
        if v == "deep":
            text = MAP_JSON.replace("[0, 0, 4, 0]", deep(c.choice([100, 10_000])))
        else:
            doc["segments"][i][j] = v
            text = json.dumps(doc)
        name, must = f"segments[{i}][{j}] = {str(v)[:20]}", v not in (-1, 10**30)
        p = write_text_bytes(d / "map.json", text)
    elif kind == "yaml":
        name, text, must = text_mutation(c, MAP_YAML, numeric_tokens=True)
        p = write_text_bytes(d / "map.yaml", text)
    elif kind == "alias":
        bomb = 'a: &a ["x", "x", "x", "x", "x", "x", "x", "x", "x", "x"]\n'
        for k in range(1, 9):
            prev = chr(ord("a") + k - 1)
            cur = chr(ord("a") + k)
            bomb += f"{cur}: &{cur} [*{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}, *{prev}]\n"
        p = write_text_bytes(d / "map.yaml", bomb + "segments: *i\n")
        name, must = "YAML alias bomb", True
    elif kind == "ros_yaml":
        field = c.choice(["image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"])
        value = c.choice(["[1, 2]", "0", "-1", ".nan", "1e300", "true", "''", "/dev/zero", "{a: 1}", "*x", deep(200)])
        text = ROS_YAML.replace(ROS_YAML.split(field + ": ")[1].split("\n")[0], value, 1)
        p = write_text_bytes(d / "map.yaml", text)
        plausible = (field, value) in {("negate", "0"), ("negate", "true"), ("free_thresh", "0")}
        name, must = f"ROS {field}: {value}", not plausible
        if field == "image" and value == "/dev/zero":
            must = True
    else:
        raw = pgm_bytes()
        v = c.choice(["w", "h", "maxval", "trunc", "bomb"])
        if v == "trunc":
            raw = raw[: c.integers(0, len(raw) - 1)]
        elif v == "bomb":
            raw = b"P5\n100000 100000\n255\n" + raw[13:]
        else:
            raw = raw.replace(b"10 8\n255", {"w": b"0 8\n255", "h": b"10 99999\n255", "maxval": b"10 8\n0"}[v])
        pgm.write_bytes(raw)
        p = write_text_bytes(d / "map.yaml", ROS_YAML)
        name, must = f"PGM {v}", v != "trunc" or len(raw) < len(pgm_bytes())
    argv = ["record", "lidar", "--map", str(p), "--out", str(d / "r.npz"), "--poses", "2", "--repeats", "2"]
    return Case("map file", name, argv, lambda: load_map(p), must, [p, pgm])


def _model(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.modelio import read_model
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel

    which = c.choice(["radar_kde.npz", "radar_gaussian.npz", "neato_lidar.npz"])
    cls = {"radar_kde.npz": KDERadarModel, "radar_gaussian.npz": GaussianRadar, "neato_lidar.npz": LidarLWLR}[which]
    with np.load(SHIPPED / which, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    header = json.loads(data["__header__"].tobytes().decode("utf-8"))
    if c.integers(0, 1) == 0:
        nested = [f"{k}.{j}" for k in ("params", "h") if isinstance(header.get(k), dict) for j in header[k]]
        where = c.choice([k for k in header if k != "card"] + nested)  # every header field, every hyperparameter
        value = c.choice(NASTY_JSON)
        if "." in where:
            top, key = where.split(".", 1)
            old = header[top][key]
            header[top][key] = value
            must = _changes_meaning(old, value, key)
        elif where in ("kind", "format_version", "params"):
            old = header[where]
            header[where] = value
            must = old != value
        else:
            old = header[where]
            header[where] = value
            must = _changes_meaning(old, value, where) and not (value is None and where in OPTIONAL_FIELDS)
        if c.integers(0, 4) == 0:
            text = json.dumps(header).replace('"kind"', '"x": ' + deep(100_000) + ', "kind"', 1)
            name, must = "header nested 100000 deep", True
        else:
            text = json.dumps(header)
            name = f"header {where} = {str(value)[:20]}"
        data["__header__"] = np.frombuffer(text.encode(), dtype=np.uint8)
    else:
        arrays = {k: v for k, v in data.items() if k != "__header__"}
        keys = [k for k in arrays if np.asarray(arrays[k]).size > 0]
        name, must = array_mutation(c, arrays, keys)
        data = {"__header__": data["__header__"], **arrays}
    p = d / which
    np.savez(p, **data)
    log = write_radar_csv(d) if cls is not LidarLWLR else write_npz(d / "log.npz", lidar_arrays())
    kind = "radar" if cls is not LidarLWLR else "lidar"
    argv = ["validate", kind, str(p), str(log), "--out", str(d / "report")]
    if which == "radar_kde.npz":
        shutil.copy(SHIPPED / "radar_gaussian.npz", d / "radar_gaussian.npz")
    return Case("model file", name, argv, lambda: read_model(cls, p), must, [p, log], command_when_loaded=False)


def _changes_meaning(old: Any, value: Any, key: str = "") -> bool:
    """Whether ``value`` in place of ``old`` certainly breaks the field.

    Another JSON type does (a number for a number, a flag for a flag, a flat list for a list stay
    plausible), and so do magnitudes beyond 1e6 and a negative number where a non-negative one was.
    """
    if isinstance(old, bool) or isinstance(value, bool):
        return not (isinstance(old, bool) and isinstance(value, bool))
    if isinstance(old, int) and isinstance(value, int) and key.endswith("seed"):
        return value < 0  # any non-negative integer seeds numpy
    if isinstance(old, (int, float)) and isinstance(value, (int, float)):
        return abs(value) > 1e6 or (old >= 0 > value)
    if isinstance(old, list) and isinstance(value, list):
        return any(isinstance(v, list) for v in value)
    if old is None and key in LIST_OR_NONE:  # e.g. extra_variance = [] for a model without extra state
        return not (isinstance(value, list) and not any(isinstance(v, (list, bool, str)) for v in value))
    return type(old) is not type(value)


OPTIONAL_FIELDS = ("cycle_time", "pose_sd")
"""Header fields whose ``null`` means "absent" (a radar fitted without a cycle time, a lidar without pose noise)."""
LIST_OR_NONE = ("extra_variance",)
"""Hyperparameters that are ``None`` or a list: an empty list is the explicit form of "none" there."""


def _rig(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.rig import RIG_CONSTRAINTS as NEATO_CONSTRAINTS
    from sensor_envs.lidar.rig import NeatoRig
    from sensor_envs.radar.rig import load_rig
    from sensor_envs.radar.rig_config import RIG_CONSTRAINTS as RADAR_CONSTRAINTS

    which = c.choice(["radar_rig.json", "neato_rig.json"])
    blob = json.loads((SHIPPED / which).read_text())
    keys = ["kind", "format_version", *[f"params.{k}" for k in blob["params"]]]
    where = c.choice(keys)
    value = c.choice(NASTY_JSON)
    if "." in where:
        k = where.split(".", 1)[1]
        declared = (RADAR_CONSTRAINTS if which == "radar_rig.json" else NEATO_CONSTRAINTS).get(k, [])
        # a table the rig declares optional (None: the generic closed form) may be dropped; any rule may refuse it
        must = _changes_meaning(blob["params"][k], value, k) and not (value is None and None in declared)
        blob["params"][k] = value
    else:
        must = blob[where] != value
        blob[where] = value
    p = d / which
    text = json.dumps(blob)
    if c.integers(0, 5) == 0:
        text, where, must = '{"kind": ' + deep(100_000) + "}", "nesting", True
    p.write_text(text)
    if which == "radar_rig.json":
        argv = ["record", "radar", "--rig", str(p), "--out", str(d / "r.csv"), "--sequences", "1", "--cycles", "2"]
        load: Callable[[], Any] = lambda: load_rig(p)  # noqa: E731
    else:
        argv = ["record", "lidar", "--rig", str(p), "--out", str(d / "r.npz"), "--poses", "2", "--repeats", "2"]
        load = lambda: NeatoRig.from_file(p)  # noqa: E731
    return Case("rig file", f"{which} {where} = {str(value)[:20]}", argv, load, must, [p])


def _astyx(c: Chooser, d: Path) -> Case:
    from sensor_envs.radar.astyx import load_astyx

    kind = c.choice(["pc", "gt", "name", "gtvalue"])
    pc = gt = None
    name = "000000"
    if kind == "pc":
        base = "\nX Y Z V_r Mag\n10.0 1.0 0.0 0.0 50.0\n10.5 1.2 0.0 0.0 40.0\n"
        what, pc, must = text_mutation(c, base, True)
        data = pc.split("\n", 2)[2] if pc.count("\n") >= 2 else None
        must = must and data != base.split("\n", 2)[2]  # the first two lines are skipped (empty line, header)
    elif kind == "gt":
        base = json.dumps({"objects": [{"center3d": [12.0, 1.0, 0.5], "dimension3d": [4.5, 1.8, 1.5]}]})
        what, gt, must = text_mutation(c, base, True)
        must = True  # no orientation_quat/classname: the base itself is incomplete
    elif kind == "gtvalue":
        field = c.choice(["center3d", "dimension3d", "orientation_quat", "classname"])
        value = c.choice(NASTY_JSON + [[0, 0, 0, 0], [1e300, 0, 0]])
        obj = {"center3d": [12.0, 1.0, 0.5], "dimension3d": [4.5, 1.8, 1.5], "orientation_quat": [1, 0, 0, 0]}
        obj["classname"] = "Car"
        obj[field] = value
        gt = json.dumps({"objects": [obj]})
        what, must = f"{field} = {str(value)[:20]}", not (field == "classname" and isinstance(value, str))
    else:
        name = c.choice(["9" * 20, "-1", "0x10", "١٢", "00000a"])
        what, must = f"frame file {name}.txt", True
    root = write_astyx(d, pc, gt, name)
    argv = ["record", "radar", "--astyx", str(root), "--out", str(d / "r.csv")]
    return Case("Astyx folder", f"{kind}: {what}", argv, lambda: load_astyx(root), must, [root])


OPTIONS: dict[str, list[str]] = {
    "record lidar": ["--poses", "--repeats", "--seed", "--unit-seed", "--map", "--rig", "--out"],
    "record radar": ["--sequences", "--cycles", "--targets", "--cycle-time", "--seed", "--rig", "--out"],
    "fit lidar": ["--folds", "--max-range", "--spur-above", "--table-range-step", "--max-readings", "--block-scans"],
    "fit radar": ["--cycle-time", "--bandwidth-scale", "--relevance-candidates", "--azimuth-bias", "--seed"],
    "diagnose radar": ["--permutations", "--shifts", "--alpha", "--min-score", "--max-add", "--block-frames"],
    "diagnose lidar": ["--permutations", "--shifts", "--max-range", "--table-range-step", "--min-score", "--alpha"],
    "calibrate radar": ["--max-evals", "--mixture-max-components", "--mixture-min-range", "--seed"],
    "evaluate aeb": ["--episodes", "--steps", "--seed"],
    "demo": ["--episodes", "--seed"],
}
BAD_OPTION_VALUES = ["nan", "inf", "-inf", "-1", "-0.5", "1e300", "1e12", "", " ", "abc", "1_0", "0x1A", "١", "+-1"]
"""Values no numeric or path option may take (every declared range lies within +-1e6)."""


def _option(c: Chooser, d: Path) -> Case:
    cmd = c.choice(sorted(OPTIONS))
    opt = c.choice(OPTIONS[cmd])
    value = c.choice(BAD_OPTION_VALUES)
    if opt in ("--map", "--rig", "--out") and value.strip():
        value = c.choice(["", " "])
    log = write_radar_csv(d) if "radar" in cmd else write_npz(d / "log.npz", lidar_arrays())
    argv = cmd.split()
    if cmd in ("fit lidar", "fit radar", "diagnose radar", "diagnose lidar", "calibrate radar"):
        argv.append(str(log))
    if opt != "--out":
        argv += ["--out", str(d / ("o.npz" if cmd.startswith("fit") or cmd == "record lidar" else "o.csv"))]
    if cmd.startswith(("diagnose", "evaluate", "demo")):
        argv[-1] = str(d / "o")
    argv += [f"{opt}={value}"]
    return Case("command-line option", f"{cmd} {opt}={value!r}", argv, None, True, [log])


def _bag(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.log import load_log

    kind = c.choice(["bytes", "truncate", "field", "quaternion"])
    must = True
    if kind == "field":
        field = c.choice(["angle_increment", "angle_min", "range_min", "range_max", "ranges"])
        value = c.choice([0.0, np.nan, np.inf, -1.0, 1e30])
        if field == "ranges":
            value = np.array([1.0, value, 0.0, 3.0], dtype=np.float32)
            must = False  # NaN = missing, inf/<=0/>max = null: all valid LaserScan conventions
        elif (field == "angle_min" and value in (0.0, -1.0)) or (field == "angle_increment" and value == -1.0):
            must = False  # a scan may start anywhere and turn clockwise
        elif field == "range_min" and value == 0.0:
            must = False  # no lower limit: valid LaserScan (simulators publish it), readings of 0 stay nulls
        p = write_bag(d, scan={field: value})
        name = f"LaserScan {field} = {value!r}"[:60]
    elif kind == "quaternion":
        q = c.choice([(0.0, 0.0, 0.0, 0.0), (np.nan, 0.0, 0.0, 1.0), (2.0, 0.0, 0.0, 0.0), (1e30, 0.0, 0.0, 0.0)])
        p, name = write_bag(d, quat=q), f"odometry quaternion {q}"
    else:
        p = write_bag(d)
        raw = bytearray(p.read_bytes())
        if kind == "truncate":
            k = c.integers(0, len(raw) - 1)
            raw = raw[:k]
            name = f"truncated at {k} of {p.stat().st_size}"
        else:
            for _ in range(c.integers(1, 8)):
                raw[c.integers(0, len(raw) - 1)] = c.integers(0, 255)
            name, must = "bytes overwritten", False  # may hit padding or a value that stays valid
        p.write_bytes(bytes(raw))
    m = write_text_bytes(d / "m.txt", MAP_TXT)
    argv = ["fit", "lidar", str(p), "--out", str(d / "m.npz"), "--max-range", "5", "--map", str(m), "--folds", "2"]
    return Case("ROS bag", name, argv, lambda: load_log(p), must, [p, m])


NASTY_NUMBERS: list[Any] = [np.nan, np.inf, -np.inf, 1e300, -1e300, -1.0, 0.0, 5e-324, 10**30, True, None, "1", [1.0]]
"""Argument values that are no valid value of a bounded positive real parameter (0 and -1 included)."""


def _api_result_ok(kind: str, result: Any) -> bool:
    """Whether an accepted API call's result is sane: finite (or NaN rows for misses) and in its space."""
    if kind == "checked":  # the call judged its own result (tests/fuzz_api.py)
        return bool(result)
    if kind == "env":
        env, obs, reward = result
        return bool(env.observation_space.contains(obs) and np.isfinite(reward))
    z = np.asarray(result, dtype=np.float64)
    if kind == "radar":
        return bool((np.isfinite(z).all(axis=1) | np.isnan(z).all(axis=1)).all())
    return bool(np.isfinite(z).all() and (z >= 0).all())


def _api(c: Chooser, d: Path) -> Case:
    """A Python API call with one generated bad argument: env constructor or step, model sample or fit."""
    what = c.choice(["neato arg", "neato action", "highway action", "highway config", "radar sample", "lidar sample"])
    value = c.choice(NASTY_NUMBERS)
    if what == "neato arg":
        from sensor_envs.envs.neato import NEATO_CONSTRAINTS, NeatoEnv

        name = c.choice(sorted(NEATO_CONSTRAINTS))
        number = isinstance(value, float) and np.isfinite(value) and abs(value) <= 1e6
        must = not (
            (name.endswith(("reward", "penalty")) and number)
            or (name == "min_goal_distance" and number and value >= 0)
            or (name == "goal_heading_tolerance" and value is None)
        )

        def call() -> Any:
            env = NeatoEnv(**{name: value})
            obs, _ = env.reset(seed=0)
            obs, reward, *_ = env.step(np.array([0.5, 0.2], dtype=np.float32))
            return env, obs, reward

        return Case("Python API", f"NeatoEnv({name}={value!r})", [], call, must, [], kind="env")
    if what == "neato action":
        from sensor_envs.envs.neato import NeatoEnv

        action = c.choice([[value, 0.0], [0.0, value], [100.0, 100.0], [1.5, 0.0], value, [0.1, 0.1, 0.1]])

        def call() -> Any:
            env = NeatoEnv()
            env.reset(seed=0)
            obs, reward, *_ = env.step(action)
            return env, obs, reward

        try:
            a = np.asarray(action, dtype=np.float64)
            in_space = a.shape == (2,) and bool(np.all(np.abs(a) <= 1.0))
        except (TypeError, ValueError):
            in_space = False
        return Case("Python API", f"Neato step({action!r})", [], call, not in_space, [], kind="env")
    if what.startswith("highway"):
        from sensor_envs.envs.highway.wrapper import make_highway

        action = c.choice([99, -1, 5, 1.5, np.nan, True, "1", [1, 2], value])
        key = c.choice(["policy_frequency", "simulation_frequency", "duration"])

        def call() -> Any:
            config = {key: value} if what == "highway config" else None
            env = make_highway("highway-fast-v0", radar="ideal", config=config)
            env.reset(seed=0)
            obs, reward, *_ = env.step(1 if what == "highway config" else action)
            return env, obs, reward

        name = f"highway config {key}={value!r}" if what == "highway config" else f"highway step({action!r})"
        return Case("Python API", name, [], call, True, [], kind="env")
    if what == "radar sample":
        from sensor_envs.modelio import default_model_path
        from sensor_envs.radar.gaussian import GaussianRadar

        state = np.array([[10.0, 1.0]])
        j = c.integers(0, 1)
        bad = value if isinstance(value, float) else np.nan
        state[0, j] = bad
        rng_bad = c.integers(0, 3) == 0

        def call() -> Any:
            model = GaussianRadar.load(default_model_path("radar_gaussian.npz"))
            rng: Any = 0 if rng_bad else np.random.default_rng(0)
            return model.sample(state, rng)[0]

        must = rng_bad or not (isinstance(bad, float) and np.isfinite(bad) and abs(bad) <= 1000)
        return Case(
            "Python API",
            f"GaussianRadar.sample(corner {state[0].tolist()}, rng 0: {rng_bad})",
            [],
            call,
            must,
            [],
            kind="radar",
        )
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.modelio import default_model_path

    pose = np.array([[2.0, 1.5, 0.0]])
    pose[0, c.integers(0, 2)] = value if isinstance(value, float) else np.nan
    fit_none = c.integers(0, 3) == 0

    def call_lidar() -> Any:
        model = LidarLWLR.load(default_model_path("neato_lidar.npz"))
        if fit_none:
            return model.fit(value)
        return model.sample(pose, SEGS, np.random.default_rng(0))

    must = fit_none or not (np.isfinite(pose).all() and (np.abs(pose) <= 1e6).all())
    return Case(
        "Python API",
        f"LidarLWLR {'fit' if fit_none else 'sample'}({pose[0].tolist()})",
        [],
        call_lidar,
        must,
        [],
        kind="lidar",
    )


FAMILIES: dict[str, Callable[[Chooser, Path], Case]] = {
    "radar log CSV": _radar,
    "lidar log npz": _lidar_npz,
    "CARMEN log": _carmen,
    "ROS bag": _bag,
    "map file": _map,
    "model file": _model,
    "rig file": _rig,
    "Astyx folder": _astyx,
    "command-line option": _option,
    "Python API": _api,
    **STRUCTURE_FAMILIES,
    **OPTION_FAMILIES,
    **FOLDER_FAMILIES,
}
SECOND_ROUND = frozenset({*STRUCTURE_FAMILIES, *OPTION_FAMILIES, *FOLDER_FAMILIES})
"""The families of the second round (issue 42: the structure of each format, every option, unsafe outputs)."""


def make_case(family: str, c: Chooser, d: Path) -> Case:
    """Build one generated case of ``family`` in the empty folder ``d``."""
    return FAMILIES[family](c, d)


def classify(case: Case, d: Path) -> str:
    """How ``case`` (built in ``d``) ends, in-process: the loader behind it, then the command line.

    Classes: ``clean error`` (exit 2, one line naming the file or option, no traceback, nothing written),
    ``vague message`` (exit 2 and one line that names neither), ``traceback`` (loader or command raised
    anything but an input error), ``accepted nonsense`` (a must-refuse input taken by the loader or the
    command), ``accepted`` (a plausible input taken), ``files changed`` (an input changed, or a file
    left after a failure), ``exit N`` (any other ending).
    """
    import contextlib

    from sensor_envs.cli.main import main
    from sensor_envs.inputs import InputError

    if case.kind:  # a Python API call
        try:
            result = case.load()  # type: ignore[misc]
        except InputError:
            return "clean error"
        except Exception as exc:
            import traceback

            frame = traceback.extract_tb(exc.__traceback__)[-1]
            where = f"{Path(frame.filename).name}:{frame.lineno}"
            return f"traceback ({type(exc).__name__} at {where}: {' '.join(str(exc).split())[:120]})"
        if case.must_refuse or not _api_result_ok(case.kind, result):
            return "accepted nonsense"
        return "accepted"
    before = snapshot(d)
    loaded = None
    if case.load is not None:
        try:
            case.load()
            loaded = True
        except (InputError, FileNotFoundError):
            loaded = False
        except Exception as exc:
            return f"traceback (loader {type(exc).__name__})"
        if loaded and not case.command_when_loaded:  # e.g. a model file: validating it takes minutes
            return "accepted nonsense" if case.must_refuse else "accepted"
    err = io.StringIO()
    code: Any = None
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = main(case.argv)
            except SystemExit as exc:
                code = exc.code
    except Exception as exc:
        return f"traceback ({type(exc).__name__})"
    after = snapshot(d)
    if any(after.get(k) != v for k, v in before.items()) or (code != 0 and after != before):
        return "files changed"
    if code == 0 or (loaded and case.must_refuse):
        return "accepted nonsense" if case.must_refuse else "accepted"
    lines = err.getvalue().strip().splitlines()
    if code != 2 or len(lines) != 1 or "Traceback" in err.getvalue():
        return f"exit {code}, {len(lines)} lines"
    if case.must_name:  # the option whose value is at fault, never just any file or option of the line
        return "clean error" if any(n in lines[0] for n in case.must_name) else "vague message"
    names = [str(p) for p in case.inputs] + [p.name for p in case.inputs] + ["/dev/zero", str(d)]
    names += [a.split("=")[0] for a in case.argv if a.startswith("--")]
    return "clean error" if any(n and n in lines[0] for n in names) else "vague message"
