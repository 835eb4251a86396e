"""Generated bad calls of the Python API: every registered env id and model class, one bad argument each.

Shared by ``tests/test_input_properties.py`` (hypothesis draws the choices, small budget) and
``benchmarks/fuzz_inputs.py --api N`` (a seeded ``random.Random``, each call in a forked child under a
memory and a time limit). A call is built by :func:`make_api_case` as a :class:`fuzz_cases.Case` of kind
``"checked"``: running ``case.load()`` either raises (an :class:`~sensor_envs.inputs.InputError` is a
clean error, anything else a traceback) or returns whether its result is sane (finite observations in
the observation space and a finite reward; finite samples, or NaN rows for radar misses; log-probabilities
that are not NaN). ``must_refuse`` marks an argument that is certainly invalid (another type than the
parameter's, not finite, beyond 1e6 in size, a shape or an action outside the space): taking it, even
with a sane-looking result, is accepted nonsense.

Classes (the benchmark counts per class): ``env constructor``, ``env reset``, ``env step``,
``vector env``, ``model constructor``, ``model fit``, ``model sample``, ``model log_prob``, ``model load``.
"""

from __future__ import annotations

import inspect
import math
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import sensor_envs.testing.fuzz_pieces as fp
from sensor_envs.testing.fuzz_pieces import Case, Chooser

ENV_IDS = (
    "sensor_envs/Neato-v0",
    "sensor_envs/Highway-v0",
    "sensor_envs/HighwayFast-v0",
    "sensor_envs/Merge-v0",
    "sensor_envs/Intersection-v0",
)
"""Every registered env id (``tests/test_input_properties.py`` checks the list against gymnasium's registry)."""
MODEL_CLASSES = ("GaussianRadar", "KDERadarModel", "LidarLWLR")
MAX_PLAUSIBLE = 1e6
"""A number beyond this size is no valid value of any argument here (positions, rates, rewards, counts)."""


# ------------------------------------------------------------------------------------------ values
def any_value(c: Chooser) -> Any:
    """A generated argument value of any type: numbers of every size and sign, NaN/inf, other types, arrays."""
    kind = c.choice(["float", "float", "int", "bool", "none", "str", "list", "nested", "dict", "array", "other"])
    if kind == "float":
        if c.integers(0, 1):
            return c.choice([math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 5e-324, 1e-300, 1e300, -1e300, 0.5])
        return (-1) ** c.integers(0, 1) * c.integers(1, 9) * 10.0 ** c.integers(-12, 12)
    if kind == "int":
        return c.choice([-1, 0, 1, 2, 3, 7, 10**30, -(2**63), 2**64, c.integers(-1000, 1000)])
    if kind == "bool":
        return c.choice([True, False])
    if kind == "none":
        return None
    if kind == "str":
        return c.choice(["", " ", "x", "1", "nan", "0x10", "\x00", "/dev/zero", "seed_room", "kde", "ideal"])
    if kind == "list":
        return [c.choice([1.0, -1.0, 0.0, math.nan, 1e300, 3.0]) for _ in range(c.integers(0, 4))]
    if kind == "nested":
        v: Any = 1.0
        for _ in range(c.integers(1, 40)):
            v = [v]
        return v
    if kind == "dict":
        return c.choice([{}, {"x": 1}, {"": None}])
    if kind == "array":
        dtype = c.choice([np.float64, np.float32, np.float16, np.int8, np.bool_, np.complex128, np.str_, object])
        shape = c.choice([(), (1,), (2,), (3,), (2, 2), (0,)])
        return np.full(shape, c.choice([1, 0, -1]), dtype=dtype) if dtype is not object else np.empty(shape, object)
    return c.choice([1j, b"1", np.float32("nan"), np.int64(-5), np.float64(2.0), object(), (1.0, 2.0, 3.0)])


def _real(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def plausible_number(v: Any) -> bool:
    """A real (not bool) finite number within +-1e6."""
    return _real(v) and math.isfinite(float(v)) and abs(float(v)) <= MAX_PLAUSIBLE


def certainly_bad(value: Any, default: Any, hint: str = "") -> bool:
    """Whether ``value`` is certainly no valid value of a parameter whose default is ``default``.

    ``hint`` names the kind of a parameter that defaults to ``None``: ``"number"``, ``"path"``, ``"dict"``,
    ``"str"``, ``"pose"`` (three numbers), ``"map"``, ``"lidar"``, ``"radar"``.
    """
    if value is None:
        return default is not None and hint not in ("number", "path", "dict", "str", "pose", "seed")
    if isinstance(default, bool):
        return not isinstance(value, (bool, np.bool_))
    if _real(default):
        return not plausible_number(value)
    if hint == "number":
        return not plausible_number(value)
    if hint == "numbers" or (isinstance(default, (tuple, list)) and all(map(_real, default))):
        flat = isinstance(value, (list, tuple)) and all(map(plausible_number, value))
        return not (flat and (len(value) > 0 or hint != "numbers"))
    if hint.startswith("number or "):  # a number in [0, 1] (shrinkage) or within 1e6, or the named word
        return not ((isinstance(value, str) and value == hint.split()[-1]) or plausible_number(value))
    if hint == "seed":
        return not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and 0 <= value < 2**32)
    if hint == "pose":  # three real numbers: a list, a tuple or a 1-d numeric array (any width: float16 too)
        numeric = isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind in "fiu"
        sequence = isinstance(value, (list, tuple)) or numeric
        return not (sequence and len(value) == 3 and all(map(plausible_number, value)))
    if hint == "dict":
        return not isinstance(value, dict) or bool(value)  # {} is no override; generated keys are unknown
    if hint in ("path", "map", "lidar", "radar", "str") or isinstance(default, str):
        known = {"map": ("seed_room",), "lidar": ("ideal",), "radar": ("kde", "ideal")}.get(hint, (default,))
        return not any(type(value) is type(k) and value == k for k in known)
    return True


# --------------------------------------------------------------------------------------- the worlds
def _judge_env(env: Any, obs: Any, reward: Any) -> bool:
    obs = np.asarray(obs)
    return bool(
        obs.dtype.kind == "f"
        and np.isfinite(obs).all()
        and env.observation_space.contains(obs)
        and np.isfinite(np.asarray(reward, dtype=np.float64)).all()
    )


def _valid_action(env_id: str) -> Any:
    return np.array([0.5, 0.2], dtype=np.float32) if "Neato" in env_id else 1


def _make(env_id: str, **kwargs: Any) -> Any:
    """``gym.make(env_id, **kwargs)`` (highway: the ideal radar unless given).

    A ``render_mode`` that is not a string goes to the env's own constructor instead: ``gym.make`` itself
    calls ``render_mode.endswith`` before any sensor_envs code runs (gymnasium's ``AttributeError``).
    """
    import gymnasium as gym

    import sensor_envs  # noqa: F401  (registers the ids)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        kw = kwargs if "Neato" in env_id else {"radar": kwargs.pop("radar", "ideal"), **kwargs}
        mode = kw.get("render_mode")
        if mode is None or isinstance(mode, str):
            return gym.make(env_id, **kw)
        spec: Any = gym.spec(env_id)
        return gym.envs.registration.load_env_creator(spec.entry_point)(**{**spec.kwargs, **kw})


def _signature(env_id: str) -> dict[str, Any]:
    """``name -> default`` of every keyword argument of the env id's constructor."""
    if "Neato" in env_id:
        from sensor_envs.envs.neato import NeatoEnv

        fn: Callable[..., Any] = NeatoEnv.__init__
    else:
        from sensor_envs.envs.highway.wrapper import make_highway

        fn = make_highway
    out = {}
    for p in inspect.signature(fn).parameters.values():
        if p.name not in ("self", "base_id") and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD):
            out[p.name] = p.default
    return out


HINTS = {
    "model": "path",
    "radar_model": "path",
    "lidar_kwargs": "dict",
    "tracker": "dict",
    "goal_heading_tolerance": "number",
    "occlusion_threshold": "number",
    "sensor_pose": "pose",
    "render_mode": "str",
    "map": "map",
    "lidar": "lidar",
    "radar": "radar",
    "k_max": "number",
    "start_bandwidth_scale": "number",
    "cv_candidates": "numbers",
    "extra_variance": "numbers",
    "random_state": "seed",
    "bias_shrinkage": "number or cv",
    "azimuth_bias": "number or fit",
}
"""Kinds of the constructor arguments that default to ``None`` or take a name (see :func:`certainly_bad`)."""


def _config_value(c: Chooser, env_id: str) -> tuple[str, Any, bool]:
    """A highway-env ``config`` override of one key (its default's kind, or anything)."""
    import gymnasium as gym

    import sensor_envs  # noqa: F401

    base = gym.spec(env_id).kwargs["base_id"]
    entry: Any = gym.envs.registration.load_env_creator(str(gym.spec(base).entry_point))
    defaults = entry.default_config()
    key = c.choice(sorted(defaults) + ["unknown_key"])
    value = any_value(c)
    if key == "unknown_key":
        return key, value, True
    default = defaults[key]
    if isinstance(default, dict):
        sub = dict(default)
        k = c.choice(sorted(sub) + ["vehicles_count", "features_range", "target_speeds", "type"])
        sub[k] = value
        return f"{key}.{k}", {key: sub}, False  # judged by the result
    if isinstance(default, list) and c.integers(0, 1):
        lst = list(default)
        lst[c.integers(0, len(lst) - 1)] = value
        return key, {key: lst}, not plausible_number(value)
    must = certainly_bad(value, default, "number" if default is None and key == "initial_lane_id" else "")
    if key in ("policy_frequency", "simulation_frequency", "duration") and _real(value) and float(value) <= 0:
        must = True
    return key, {key: value}, must


def _env_constructor(c: Chooser, d: Path) -> Case:
    env_id = c.choice(ENV_IDS)
    sig = _signature(env_id)
    name = c.choice(sorted(sig))
    value = any_value(c)
    must = certainly_bad(value, sig[name], HINTS.get(name, ""))
    shown = f"{value!r:.40}"
    if name == "config":
        key, value, must = _config_value(c, env_id)
        shown = f"{{{key!r}: {str(value)[:40]}}}"
    if name == "render_mode":
        must = not (value is None or (isinstance(value, str) and value == "rgb_array"))
    if name in ("tracker",) and isinstance(value, dict) and not value:
        must = False
    kwargs = {name: value}
    if name == "tracker" and isinstance(value, dict):
        kwargs["tracks"] = True

    def call() -> bool:
        env = _make(env_id, **kwargs)
        obs, _ = env.reset(seed=0)
        ok = _judge_env(env, obs, 0.0)
        obs, reward, *_ = env.step(_valid_action(env_id))
        return ok and _judge_env(env, obs, reward)

    return Case("env constructor", f"{env_id}({name}={shown})", [], call, must, [], kind="checked")


_ENVS: dict[str, Any] = {}


def cached_env(env_id: str) -> Any:
    """One default env per id and process (the benchmark builds them before forking its children)."""
    if env_id not in _ENVS:
        _ENVS[env_id] = _make(env_id)
        _ENVS[env_id].reset(seed=0)
    return _ENVS[env_id]


def _in_space(env_id: str, action: Any) -> bool:
    try:
        a = np.asarray(action)
    except Exception:
        return False
    if "Neato" in env_id:
        return bool(
            a.dtype.kind in "fiu" and a.shape == (2,) and np.isfinite(a.astype(float)).all() and (abs(a) <= 1).all()
        )
    return bool(a.dtype.kind in "iu" and a.size == 1 and 0 <= int(a.reshape(())) < 5)


def bad_action(c: Chooser, env_id: str) -> Any:
    """A generated action: out of range, NaN, another shape or type (sometimes a valid one)."""
    v = any_value(c)
    if "Neato" in env_id:
        return c.choice([[v, 0.0], [0.0, v], v, [1.5, 0.0], [100.0, -100.0], [0.1, 0.1, 0.1], np.array([0.2, -0.3])])
    return c.choice([v, 99, -1, 5, 1.5, math.nan, True, "1", [1, 2], np.int64(2), np.array([3]), np.array(1.0)])


def _env_step(c: Chooser, d: Path) -> Case:
    env_id = c.choice(ENV_IDS)
    action = bad_action(c, env_id)

    def call() -> bool:
        env = cached_env(env_id)
        obs, reward, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset(seed=0)
        return _judge_env(env, obs, reward)

    must = not _in_space(env_id, action)
    return Case("env step", f"{env_id}.step({action!r:.50})", [], call, must, [], kind="checked")


def _env_reset(c: Chooser, d: Path) -> Case:
    env_id = c.choice(ENV_IDS)
    if c.integers(0, 1):
        seed = c.choice([any_value(c), -1, 2**64, 1.5, "1", True, np.int64(3), None, 7])
        options: Any = None
        integer = isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_))
        must = not (seed is None or (integer and 0 <= int(seed) < 2**64))
        what = f"seed={seed!r:.40}"
    else:
        seed = 0
        v = any_value(c)
        if "Neato" in env_id:
            options = c.choice([{"start": v}, {"goal": [v, 1.0, 0.0]}, {"start": [1.0, 1.0, v]}, {"x": 1}, v])
        else:
            options = c.choice([{"config": {"duration": v}}, {"config": v}, {"x": 1}, v])
        must = not (options is None or (isinstance(options, dict) and not options))  # no option
        config = options.get("config") if isinstance(options, dict) else None
        if isinstance(config, dict) and not config:
            must = False  # an empty config changes nothing, like no option
        elif isinstance(config, dict) and "duration" in config and "Merge" not in env_id:
            must = not (plausible_number(v) and float(v) > 0)  # merge-v0 has no duration
        what = f"options={options!r:.50}"

    def call() -> bool:
        env = cached_env(env_id)
        obs, _ = env.reset(seed=seed, options=options)
        ok = _judge_env(env, obs, 0.0)
        obs, reward, *_ = env.step(_valid_action(env_id))
        return ok and _judge_env(env, obs, reward)

    # a pose option may well be valid (a free pose of the map): judged by the result
    if "Neato" in env_id and isinstance(options, dict) and options and set(options) <= {"start", "goal"}:
        pose = options.get("start", options.get("goal"))
        must = not (isinstance(pose, list) and len(pose) == 3 and all(map(plausible_number, pose)))
        must = must or (not isinstance(pose, list) and pose is not None)
    return Case("env reset", f"{env_id}.reset({what})", [], call, must, [], kind="checked")


def _vector_env(c: Chooser, d: Path) -> Case:
    import gymnasium as gym

    k = c.choice(["num_envs", "max_episode_steps", "tune_heap", "action"])
    v = any_value(c)
    n = 2

    def call() -> bool:
        kw: dict[str, Any] = {"num_envs": n}
        if k != "action":
            kw[k] = v
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make_vec(
                "sensor_envs/Neato-v0",
                vectorization_mode="vector_entry_point",
                **kw,
            )
        obs, _ = env.reset(seed=0)
        a = v if k == "action" else np.zeros((env.num_envs, 2), dtype=np.float32)
        obs, reward, *_ = env.step(a)
        return bool(np.isfinite(obs).all() and env.observation_space.contains(obs) and np.isfinite(reward).all())

    if k == "action":
        must = True
        try:
            a = np.asarray(v)
            must = not (a.dtype.kind in "fiu" and a.shape == (n, 2) and np.isfinite(a).all() and (abs(a) <= 1).all())
        except Exception:
            pass
    elif k == "tune_heap":
        must = not isinstance(v, (bool, np.bool_))
    else:
        must = not (isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) and 1 <= v <= 4096)
        if k == "num_envs" and not must and v > 64:
            v = 3  # keep the child small: a valid count of 64 robots is no input error
    return Case("vector env", f"Neato vector {k}={v!r:.40}", [], call, must, [], kind="checked")


# ------------------------------------------------------------------------------------------- models
_MODELS: dict[str, Any] = {}


def shipped_model(name: str) -> Any:
    """The shipped model of a class, loaded once per process."""
    if name not in _MODELS:
        from sensor_envs.lidar.lwlr import LidarLWLR
        from sensor_envs.modelio import default_model_path
        from sensor_envs.radar.gaussian import GaussianRadar
        from sensor_envs.radar.kde import KDERadarModel

        cls: Any
        cls, file = {
            "GaussianRadar": (GaussianRadar, "radar_gaussian.npz"),
            "KDERadarModel": (KDERadarModel, "radar_kde.npz"),
            "LidarLWLR": (LidarLWLR, "neato_lidar.npz"),
        }[name]
        _MODELS[name] = cls.load(default_model_path(file))
    return _MODELS[name]


def mutate_array(c: Chooser, base: np.ndarray) -> tuple[Any, str, bool]:
    """A mutated copy of a valid array argument: (value, description, certainly bad)."""
    kind = c.choice(["entry", "entry", "shape", "dtype", "type", "empty", "valid"])
    if kind == "valid":
        return base.copy(), "valid", False
    if kind == "entry":
        a = base.astype(np.float64).copy()
        v = c.choice([math.nan, math.inf, -math.inf, 1e300, -1e300, 1e7, -1.0, 0.0, 1e-300, 500.0])
        i = c.integers(0, a.size - 1)
        a.reshape(-1)[i] = v
        return a, f"entry {i} = {v}", not math.isfinite(v) or abs(v) > MAX_PLAUSIBLE
    if kind == "shape":
        new = c.choice([base[None], base.reshape(-1), base[..., :1], base[:, None], np.repeat(base, 2, axis=-1)])
        return new, f"shape {new.shape}", new.shape != base.shape
    if kind == "dtype":
        dt = c.choice([np.bool_, np.complex128, np.str_, object, np.float16, np.float32, np.int64])
        good = dt in (np.float16, np.float32, np.int64) or np.dtype(dt) == base.dtype  # its own dtype: no change
        return base.astype(dt), f"dtype {np.dtype(dt)}", not good
    if kind == "empty":
        return base[:0], "no rows", False
    v = any_value(c)
    return v, f"{v!r:.40}", True


def _radar_state(c: Chooser) -> np.ndarray:
    return np.array([[10.0, 1.0, 8.0, 1.2], [25.0, -2.0, np.nan, np.nan]])[:, : c.choice([2, 4])]


def _radar_state_sane(s: Any) -> bool:
    """A state the contract takes: ``(n, 2|4)`` or one row ``(2|4,)`` of real numbers, corners finite."""
    a = np.atleast_2d(np.asarray(s))
    if a.dtype.kind not in "fiu" or a.ndim != 2 or a.shape[1] not in (2, 4):
        return False
    a = a.astype(np.float64)
    if not np.isfinite(a[:, :2]).all() or np.isinf(a).any() or (np.abs(a[np.isfinite(a)]) > MAX_PLAUSIBLE).any():
        return False
    return not (a.shape[1] == 4 and (np.isnan(a[:, 2]) != np.isnan(a[:, 3])).any())


def _model_sample(c: Chooser, d: Path) -> Case:
    name = c.choice(MODEL_CLASSES)
    what = c.choice(["state", "state", "rng", "extra", "other"])
    rng_v: Any = None
    if name == "LidarLWLR":
        poses = np.array([[2.0, 1.5, 0.1], [1.0, 1.0, 2.0]])
        segs = fp.SEGS.copy()
        reps: Any = None
        if what == "state":
            poses, desc, must = mutate_array(c, poses)
        elif what == "other":
            segs, desc, must = mutate_array(c, segs)
            must = must or (isinstance(segs, np.ndarray) and segs.size == 0)
            if c.integers(0, 1):
                segs, reps = fp.SEGS.copy(), any_value(c)
                desc, must = (
                    f"n_repeats={reps!r:.30}",
                    not (
                        reps is None
                        or (isinstance(reps, (int, np.integer)) and not isinstance(reps, bool) and reps >= 1)
                    ),
                )
                if not must and reps is not None and reps > 1000:
                    must = True  # 10^30 repeats of a 360-bearing scan cannot be memory
        elif what == "rng":
            rng_v = any_value(c)
            desc, must = f"rng={rng_v!r:.30}", True
        else:
            desc, must = "extra=[[1.0]] for a model without extra state", True

        def call() -> bool:
            m = shipped_model(name)
            rng = rng_v if what == "rng" else np.random.default_rng(0)
            extra = np.ones((2, 1)) if what == "extra" else None
            r = m.sample(poses, segs, rng, n_repeats=reps, extra=extra)
            return bool(np.isfinite(r).all() and (r >= 0).all())

        return Case("model sample", f"{name}.sample({what}: {desc})", [], call, must, [], kind="checked")
    state = _radar_state(c)
    nt: Any = None
    if what == "state":
        state, desc, _ = mutate_array(c, state)
        must = not _radar_state_sane(state)  # another shape may be valid: (n, 2) corners or (n, 4) with outputs
    elif what == "rng":
        rng_v = any_value(c)
        desc, must = f"rng={rng_v!r:.30}", True
    elif what == "extra":
        desc, must = "extra=[[1.0]] for a model without extra state", True
    else:
        nt, desc, must = mutate_array(c, np.array([True, True]))
        must = must or not (isinstance(nt, np.ndarray) and nt.dtype.kind == "b" and nt.shape == (len(state),))
        if (
            state.shape[1] == 4
            and isinstance(nt, np.ndarray)
            and nt.dtype.kind == "b"
            and nt.size
            and nt.reshape(-1)[0]
        ):
            must = True  # a new track has no previous output
        desc = f"new_track {desc}"

    def call_radar() -> bool:
        m = shipped_model(name)
        rng = rng_v if what == "rng" else np.random.default_rng(0)
        extra = np.ones((2, 1)) if what == "extra" else None
        z, _ = m.sample(state, rng, extra=extra, new_track=nt)
        z = np.asarray(z, dtype=np.float64)
        return bool(z.ndim == 2 and z.shape[1] == 2 and (np.isfinite(z).all(axis=1) | np.isnan(z).all(axis=1)).all())

    return Case("model sample", f"{name}.sample({what}: {desc})", [], call_radar, must, [], kind="checked")


def _model_log_prob(c: Chooser, d: Path) -> Case:
    name = c.choice(MODEL_CLASSES)
    if name == "LidarLWLR":
        k = 360
        ranges = np.full((2, k), 1.5)
        poses = np.array([[2.0, 1.5, 0.1], [1.0, 1.0, 2.0]])
        which = c.choice(["ranges", "poses"])
        if which == "ranges":
            ranges, desc, must = mutate_array(c, ranges)
            if isinstance(ranges, np.ndarray) and ranges.dtype.kind in "fiu" and ranges.shape == (2, k):
                r = ranges.astype(np.float64)
                must = bool(np.isinf(r).any() or (r < 0).any() or (r > 1000).any())  # NaN = missing, 0 = null
        else:
            poses, desc, must = mutate_array(c, poses)

        def call() -> bool:
            lp = shipped_model(name).log_prob(ranges, poses, fp.SEGS)
            return bool(not np.isnan(np.asarray(lp, dtype=np.float64)[np.isfinite(ranges)]).any())

        return Case("model log_prob", f"{name}.log_prob({which}: {desc})", [], call, must, [], kind="checked")
    state = _radar_state(c)
    z = np.array([[9.0, 1.1], [np.nan, np.nan]])
    which = c.choice(["z", "state"])
    if which == "z":
        z, desc, must = mutate_array(c, z)
        a = np.asarray(z) if isinstance(z, np.ndarray) else None
        if a is not None and a.dtype.kind in "fiu" and a.shape == (2, 2):
            f = a.astype(np.float64)
            must = bool(np.isinf(f).any() or (np.abs(f[np.isfinite(f)]) > MAX_PLAUSIBLE).any())
            must = must or bool((np.isnan(f[:, 0]) != np.isnan(f[:, 1])).any())
    else:
        state, desc, _ = mutate_array(c, state)
        must = not _radar_state_sane(state) or np.shape(state)[0] != 2

    def call_radar() -> bool:
        lp = np.asarray(shipped_model(name).log_prob(z, state), dtype=np.float64)
        return bool(not np.isnan(lp).any() and (lp < np.inf).all())

    return Case("model log_prob", f"{name}.log_prob({which}: {desc})", [], call_radar, must, [], kind="checked")


def _constraints(name: str) -> dict[str, Any]:
    return type(shipped_model(name))._hyperparameter_constraints


def _model_constructor(c: Chooser, d: Path) -> Case:
    """One generated hyperparameter: the constructor takes it (sklearn style), ``fit`` must refuse it or fit."""
    name = c.choice(MODEL_CLASSES)
    cls = type(shipped_model(name))
    table = _constraints(name)
    param = c.choice(sorted(table))
    value = any_value(c)
    must = certainly_bad(value, cls().get_params()[param], HINTS.get(param, ""))
    log = _small_log(name, d)

    def call() -> bool:
        base = {"relevance": "paper", "cv_min_tuples": 2} if name == "KDERadarModel" else {}
        if name == "LidarLWLR":
            base = {"n_folds": 2, "variant": "seed"}
        m = cls(**{**base, param: value}).fit(log)
        return _sane_fit(name, m)

    return Case("model constructor", f"{name}({param}={value!r:.40})", [], call, must, [], kind="checked")


def _small_log(name: str, d: Path) -> Any:
    from sensor_envs.lidar.log import load_log
    from sensor_envs.radar.log import read_log

    if name == "LidarLWLR":
        return load_log(fp.write_npz(d / "log.npz", fp.lidar_arrays()))
    p = d / "log.csv"
    p.write_text("\n".join([fp.RADAR_HEADER, *fp.radar_rows(6, 12)]) + "\n", encoding="utf-8")
    return read_log(p)


def _sane_fit(name: str, m: Any) -> bool:
    rng = np.random.default_rng(0)
    if name == "LidarLWLR":
        r = m.sample(np.array([[2.0, 1.5, 0.1]]), fp.SEGS, rng)
        return bool(np.isfinite(r).all() and (r >= 0).all())
    z, _ = m.sample(np.array([[10.0, 1.0]]), rng)
    return bool((np.isfinite(z).all(axis=1) | np.isnan(z).all(axis=1)).all())


def _model_fit(c: Chooser, d: Path) -> Case:
    """``fit`` given something that is not a log of its kind (or the other world's log), or bad fit options."""
    name = c.choice(MODEL_CLASSES)
    cls = type(shipped_model(name))
    what = c.choice(["log", "other log", "option"])
    extra: dict[str, Any] = {}
    if what == "log":
        log: Any = any_value(c)
        desc = f"{log!r:.40}"
    elif what == "other log":
        log = _small_log("GaussianRadar" if name == "LidarLWLR" else "LidarLWLR", d)
        desc = "the other world's log"
    else:
        log = _small_log(name, d)
        key = "per_reading" if name == "LidarLWLR" else "cycle_time"
        extra = {key: any_value(c)}
        desc = f"{key}={extra[key]!r:.40}"

    must = True
    if what == "option":
        v = extra.get("per_reading", extra.get("cycle_time"))
        must = not (v is None or isinstance(v, bool)) if name == "LidarLWLR" else not (v is None or plausible_number(v))

    def call() -> bool:
        base = {"relevance": "paper", "cv_min_tuples": 2} if name == "KDERadarModel" else {}
        if name == "LidarLWLR":
            base = {"n_folds": 2, "variant": "seed"}
        m = cls(**base).fit(log, **extra)
        return _sane_fit(name, m)

    return Case("model fit", f"{name}.fit({desc})", [], call, must, [], kind="checked")


def _model_load(c: Chooser, d: Path) -> Case:
    name = c.choice(MODEL_CLASSES)
    cls = type(shipped_model(name))
    kind = c.choice(["value", "folder", "missing", "text", "other model", "devzero", "empty"])
    if kind == "value":
        path: Any = any_value(c)
    elif kind == "folder":
        path = d
    elif kind == "missing":
        path = d / "none.npz"
    elif kind == "text":
        path = d / "m.npz"
        path.write_text("not a model\n")
    elif kind == "other model":
        other = {
            "GaussianRadar": "radar_kde.npz",
            "KDERadarModel": "neato_lidar.npz",
            "LidarLWLR": "radar_gaussian.npz",
        }
        path = fp.SHIPPED / other[name]
    elif kind == "devzero":
        path = "/dev/zero"
    else:
        path = d / "e.npz"
        path.write_bytes(b"")

    def call() -> bool:
        cls.load(path)
        return True

    return Case("model load", f"{name}.load({kind}: {str(path)[:40]!r})", [], call, True, [], kind="checked")


API_CLASSES: dict[str, Callable[[Chooser, Path], Case]] = {
    "env constructor": _env_constructor,
    "env reset": _env_reset,
    "env step": _env_step,
    "vector env": _vector_env,
    "model constructor": _model_constructor,
    "model fit": _model_fit,
    "model sample": _model_sample,
    "model log_prob": _model_log_prob,
    "model load": _model_load,
}


def _second_round() -> None:
    """Add the classes of odd types (:mod:`sensor_envs.testing.fuzz_api_types`, which builds on this module)."""
    from sensor_envs.testing.fuzz_api_types import TYPE_CLASSES

    API_CLASSES.update(TYPE_CLASSES)


def make_api_case(cls: str, c: Chooser, d: Path) -> Case:
    """Build one generated call of class ``cls`` (files it needs go in the empty folder ``d``)."""
    return API_CLASSES[cls](c, d)


def warm_up() -> None:
    """Import and load what every call shares (once per process; the benchmark's children inherit it)."""
    import highway_env  # noqa: F401

    for name in MODEL_CLASSES:
        shipped_model(name)
    from sensor_envs.radar.sensors import make_radar

    for radar in ("gaussian", "kde"):
        make_radar(radar, None)
    for env_id in ENV_IDS:
        cached_env(env_id)
    with tempfile.TemporaryDirectory() as tmp:
        _small_log("GaussianRadar", Path(tmp))


_second_round()
