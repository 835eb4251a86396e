"""Generated bad Python API calls, second round (issue 42): odd *types* of otherwise plausible values.

The first round (:mod:`sensor_envs.testing.fuzz_api`) draws values of every size and sign. These classes
keep the value plausible and change its type: numpy scalars of every width (``float16``, ``uint64``,
``bool_``), 0-d and ``(1, n)`` arrays, masked, object, big-endian, Fortran-ordered, read-only and
non-contiguous arrays, ``Decimal``, ``Fraction``, ``memoryview``, tuples, and a ``RandomState`` where a
``Generator`` is asked for. A call must raise an :class:`~sensor_envs.inputs.InputError` or give a sane
result; ``must_refuse`` marks types that are certainly wrong (a masked or object array, a flag for a
number, an action of another shape).
"""

from __future__ import annotations

from decimal import Decimal
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.testing import fuzz_api as fa
from sensor_envs.testing.fuzz_pieces import SEGS, Case, Chooser


def typed(c: Chooser, value: float) -> tuple[Any, str, bool | None]:
    """``value`` in an odd type: (new value, description, must_refuse; ``None``: judged by the result)."""
    kind = c.choice(["f16", "f32", "i64", "u64", "bool", "0d", "decimal", "fraction", "str", "complex", "masked"])
    out: dict[str, tuple[Any, bool | None]] = {
        "f16": (np.float16(value), None),
        "f32": (np.float32(value), False),
        "i64": (np.int64(round(value)), None),
        "u64": (np.uint64(2**64 - 1), True),
        "bool": (np.bool_(True), True),
        "0d": (np.array(value), None),
        "decimal": (Decimal(str(value)), None),
        "fraction": (Fraction(value).limit_denominator(1000), None),
        "str": (str(value), True),
        "complex": (np.complex128(value), True),
        "masked": (np.ma.masked_array([value], mask=[True])[0], True),
    }
    v, must = out[kind]
    return v, f"{kind} {v!r:.30}", must


def odd_array(c: Chooser, base: np.ndarray) -> tuple[Any, str, bool | None]:
    """``base`` in an odd container: (value, description, must_refuse; ``None``: judged by the result)."""
    kind = c.choice(["list", "tuple", "bigendian", "fortran", "readonly", "strided", "object", "masked", "row"])
    kind = c.choice([kind, "f16", "u64", "memoryview", "0d"])
    if kind == "list":
        return [[np.float32(x) for x in r] for r in np.atleast_2d(base)] if base.ndim == 2 else list(base), kind, False
    if kind == "tuple":
        return tuple(map(tuple, base)) if base.ndim == 2 else tuple(base), kind, False
    if kind == "bigendian":
        return base.astype(">f8"), kind, False
    if kind == "fortran":
        return np.asfortranarray(base), kind, False
    if kind == "readonly":
        a = base.copy()
        a.flags.writeable = False
        return a, kind, False
    if kind == "strided":
        return np.repeat(base, 2, axis=-1)[..., ::2], kind, False
    if kind == "object":
        return base.astype(object), kind, True
    if kind == "masked":  # the first entry masked: its value must not be used
        mask = np.zeros_like(base, dtype=bool)
        mask.reshape(-1)[0] = True
        return np.ma.masked_array(base, mask=mask), kind, True
    if kind == "row":
        return base[None], f"shape {base[None].shape}", None
    if kind == "f16":
        return base.astype(np.float16), kind, None
    if kind == "u64":
        return np.full(base.shape, 2**63, dtype=np.uint64), kind, True
    if kind == "memoryview":
        return memoryview(np.ascontiguousarray(base).tobytes()).cast("d", base.shape), kind, None
    return np.array(base.reshape(-1)[0]), "0-d", True


def _env_typed_arg(c: Chooser, d: Path) -> Case:
    """A Neato constructor argument of an odd type around its default (valid when the type is)."""
    from sensor_envs.envs.neato import NEATO_CONSTRAINTS

    sig = fa._signature("sensor_envs/Neato-v0")
    name = c.choice(sorted(k for k in NEATO_CONSTRAINTS if isinstance(sig.get(k), (int, float))))
    value, desc, must = typed(c, float(sig[name]))
    if name == "n_bearings" and desc.startswith(("f16", "f32", "fraction", "decimal", "0d")):
        must = True if not desc.startswith("0d") else must  # a count is an integer

    def call() -> bool:
        env = fa._make("sensor_envs/Neato-v0", **{name: value})
        obs, _ = env.reset(seed=0)
        obs, reward, *_ = env.step(np.array([0.5, 0.2], dtype=np.float32))
        return fa._judge_env(env, obs, reward)

    return Case("env typed argument", f"Neato({name}={desc})", [], call, bool(must), [], kind="checked")


def _env_typed_action(c: Chooser, d: Path) -> Case:
    env_id = c.choice(["sensor_envs/Neato-v0", "sensor_envs/HighwayFast-v0"])
    if "Neato" in env_id:
        action, desc, must = odd_array(c, np.array([0.5, -0.2]))
        if c.integers(0, 1):
            x, desc, must = typed(c, 0.5)
            action, desc = [x, 0.0], f"[{desc}, 0.0]"
            must = must or isinstance(x, (np.bool_, np.complexfloating, str))
    else:
        action, desc, must = typed(c, 1.0)
        must = True if desc.startswith(("f16", "f32", "decimal", "fraction")) else must  # Discrete: an integer

    def call() -> bool:
        env = fa.cached_env(env_id)
        obs, reward, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset(seed=0)
        return fa._judge_env(env, obs, reward)

    return Case("env typed action", f"{env_id}.step({desc})", [], call, bool(must), [], kind="checked")


def _model_typed_input(c: Chooser, d: Path) -> Case:
    name = c.choice(fa.MODEL_CLASSES)
    which = c.choice(["state", "state", "rng"])
    if name == "LidarLWLR":
        base = np.array([[2.0, 1.5, 0.1], [1.0, 1.0, 2.0]])
    else:
        base = np.array([[10.0, 1.0], [25.0, -2.0]])
    must: bool | None
    if which == "rng":
        state: Any = base
        rng: Any = c.choice([np.random.RandomState(0), np.random.PCG64(0), np.random.SeedSequence(0)])
        desc, must = f"rng {type(rng).__name__}", True
    else:
        state, desc, must = odd_array(c, base)
        rng = np.random.default_rng(0)

    def call() -> bool:
        m = fa.shipped_model(name)
        if name == "LidarLWLR":
            r = m.sample(state, SEGS, rng)
            return bool(np.isfinite(r).all() and (r >= 0).all())
        z, _ = m.sample(state, rng)
        z = np.asarray(z, dtype=np.float64)
        return bool(z.ndim == 2 and (np.isfinite(z).all(axis=1) | np.isnan(z).all(axis=1)).all())

    return Case("model typed input", f"{name}.sample({which}: {desc})", [], call, bool(must), [], kind="checked")


TYPE_CLASSES = {
    "env typed argument": _env_typed_arg,
    "env typed action": _env_typed_action,
    "model typed input": _model_typed_input,
}
"""The second-round API classes (:data:`sensor_envs.testing.fuzz_api.API_CLASSES` includes them)."""
