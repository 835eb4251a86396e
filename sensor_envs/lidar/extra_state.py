"""Extra state of the learned lidar (scan logs): variables beyond ``(range, incidence)`` as linear terms.

A :class:`~sensor_envs.lidar.lwlr.LidarLWLR` with ``extra_state`` (names) keeps its per-bearing tables
over ``(r, alpha)`` and adds, for every reading on a ray that hits the map, linear terms in the
standardised extra variables ``z`` (``(z - mean) / scale`` of the training readings):

* ``logit p_null += c_null . [1, z]`` (Bernoulli likelihood, Newton, on all hit readings);
* ``mu += c_bias . [1, z]`` [m] (bisquare-weighted least squares of ``x - mu`` over the in-range
  non-null readings, cut-off 6 mean absolute residuals, 3 passes);
* ``log sigma += c_sigma . [1, z]`` (Gaussian likelihood of the same residuals, Newton): an effect
  that explains part of the spread (e.g. the previous residual) also narrows it.

State variables (names):

* ``t``: time since the log's first scan [s] (at run time: time since reset);
* ``prev_residual``: the same bearing's residual ``x - mu_table`` [m] at the previous scan (clipped to
  +-:data:`PREV_CLIP`; 0 after a null, a missing reading, a ray without hit, the first scan or a time
  gap of more than 1.5 median scan periods), ``mu_table`` being the tables' mean (without extra terms);
* any other name: the log's per-scan covariate ``cov_<name>`` (e.g. ``v``, ``omega``);
* ``<name>@cos_bearing`` / ``<name>@sin_bearing``: an interaction term, the variable ``<name>`` times
  the cosine / sine of the reading's bearing (an effect whose sign follows the bearing, e.g. a range
  bias from translating during the scan: its mean over the scan is zero); ``<name>@sq``: its square
  (a U-shaped effect, standardised like every term);
* ``<part>:<term>`` (``null:``, ``bias:`` or ``sigma:``, :data:`PARTS`): the term acts on that part only
  (a term without a part acts on all three): an effect found on the null rate, the mean or the spread
  is added where it acts, and the other parts keep their fit (fewer coefficients to carry over);
* ``<name>@range`` / ``<name>@incidence`` / ``<name>@range_slope``: the variable times the ray's nominal
  range [m], incidence [rad] or the nominal range's slope along the scan [m/rad] (:func:`range_slope`,
  clipped to :data:`SLOPE_CAP` times the range;
  e.g. a scan smeared by the robot's turn: each reading is taken a little later than its bearing says,
  so its error is the turn rate times the wall's slope along the scan). They are computed from the
  map's raycast at the reading's pose, in the log as in the worlds.

The terms are fitted after the tables (on the same readings), so the tables stay what they were.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.geometry import as_segments, raycast_pose
from sensor_envs.inputs import InputError
from sensor_envs.lidar.local_regression import P_EPS
from sensor_envs.lidar.log import LidarLog

if TYPE_CHECKING:
    from sensor_envs.lidar.lwlr import LidarLWLR

__all__ = [
    "PREV",
    "TIME",
    "PREV_CLIP",
    "MODIFIERS",
    "check_extra_state",
    "split_term",
    "term_part",
    "part_columns",
    "PARTS",
    "needs_geometry",
    "modify",
    "range_slope",
    "GEOMETRY_MODIFIERS",
    "SLOPE_CAP",
    "scan_features",
    "fit_extra_terms",
    "apply_extra",
]

PREV = "prev_residual"
TIME = "t"
PREV_CLIP = 1.0
"""Previous residuals are clipped to +- this [m] (a spurious return would otherwise dominate)."""
MAX_COEF = 50.0
"""Largest magnitude of a fitted coefficient (logit, m, log m per standard deviation) in a model file."""
_RIDGE = 1.0
MODIFIERS = ("cos_bearing", "sin_bearing", "sq", "range", "incidence", "range_slope")
"""Interaction / shape modifiers of a state term ``<name>@<modifier>``."""
PARTS = ("null", "bias", "sigma")
"""Parts a term may be restricted to (``<part>:<term>``): logit p_null, bias [m], log sigma (``extra_coef_`` rows)."""
GEOMETRY_MODIFIERS = ("range", "incidence", "range_slope")
"""Modifiers that need the ray's nominal range and incidence (the map's raycast)."""
SLOPE_CAP = 5.7
"""``<name>@range_slope`` uses the slope clipped to ``+- SLOPE_CAP x`` the nominal range (``dr / d bearing =
r tan(incidence)``: 5.7 is an incidence of 80 deg). Near-grazing rays' slopes grow without bound; unclipped,
a few of them would set a linear term's fit."""


def term_part(name: str) -> str | None:
    """The part (:data:`PARTS`) a term ``<part>:<term>`` acts on, ``None`` for a term on all three."""
    head, sep, _ = name.partition(":")
    return head if sep and head in PARTS else None


def split_term(name: str) -> tuple[str, str | None]:
    """``(variable, modifier)`` of a state term name (``modifier`` ``None`` for a plain variable).

    A part prefix (``null:``, ``bias:``, ``sigma:``, :func:`term_part`) is dropped: it says where the
    term acts, not what it is.

    A modifier may be a chain of two, ``sq@<modifier>`` (a U-shaped effect whose sign follows the
    bearing or grows with the ray's range: ``v@sq@cos_bearing`` is ``v**2 cos(bearing)``).

    Raises:
        ValueError: an unknown modifier, naming ``extra_state``.
    """
    if term_part(name) is not None:
        name = name.partition(":")[2]
        if not name:
            raise InputError("extra_state: a part prefix (null:, bias:, sigma:) needs a term after it")
    base, sep, mod = name.partition("@")
    if not sep:
        return name, None
    chain = mod.split("@")
    ok = bool(base) and all(m in MODIFIERS for m in chain) and len(chain) <= 2
    if ok and len(chain) == 2:
        ok = chain[0] == "sq" and chain[1] != "sq"
    if not ok:
        raise InputError(
            f"extra_state: term {name!r}: expected <name>@<modifier> or <name>@sq@<modifier> with a modifier "
            f"in {MODIFIERS}"
        )
    return base, mod


def needs_geometry(mod: str | None) -> bool:
    """Whether a term's modifier (chain) needs the rays' nominal range or incidence (:data:`GEOMETRY_MODIFIERS`)."""
    return mod is not None and any(m in GEOMETRY_MODIFIERS for m in mod.split("@"))


def range_slope(r: NDArray[np.float64], bearings: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(..., K)`` slope of the nominal range along the scan, ``dr / d bearing`` [m/rad] (central difference).

    A reading taken a little later or earlier than its bearing says (a scan smeared by the robot's turn,
    a timing offset) is off by this slope times the angle turned: its error follows the wall's slope
    along the scan. 0 where a neighbour misses the map or the two sides disagree in sign (an edge).
    """
    r = np.asarray(r, dtype=np.float64)
    if r.shape[-1] < 3:
        return np.zeros_like(r)
    db = np.diff(np.unwrap(np.r_[bearings[-1] - 2 * np.pi, bearings, bearings[0] + 2 * np.pi]))
    with np.errstate(invalid="ignore"):  # inf - inf where both neighbours miss the map: no slope
        fwd = (np.roll(r, -1, axis=-1) - r) / db[1:]
        back = (r - np.roll(r, 1, axis=-1)) / db[:-1]
        ok = np.isfinite(fwd) & np.isfinite(back) & (np.sign(fwd) == np.sign(back))
        return np.where(ok, 0.5 * (fwd + back), 0.0)


def modify(
    values: NDArray[np.float64],
    mod: str | None,
    bearings: NDArray[np.float64],
    nominal: NDArray[np.float64] | None = None,
    incidence: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """A variable's values ``(..., K)`` with the modifier applied.

    Args:
        values: the variable at every reading ``(..., K)``.
        mod: the modifier (:data:`MODIFIERS`) or ``None``.
        bearings: ``(K,)`` [rad].
        nominal: ``(..., K)`` nominal ranges [m] (non-finite off the map); needed by the
            :data:`GEOMETRY_MODIFIERS` (a ray off the map gets 0: the terms act at hits only).
        incidence: ``(..., K)`` incidence angles [rad]; needed by ``incidence``.
    """
    if mod is None:
        return values
    if "@" in mod:  # a chain: sq, then the second modifier
        first, second = mod.split("@", 1)
        return modify(modify(values, first, bearings, nominal, incidence), second, bearings, nominal, incidence)
    if mod == "sq":
        return values**2
    if mod in ("cos_bearing", "sin_bearing"):
        return values * (np.cos(bearings) if mod == "cos_bearing" else np.sin(bearings))
    if nominal is None or (mod == "incidence" and incidence is None):
        raise ValueError(f"modifier {mod!r} needs the nominal range and incidence of the rays")
    r = np.asarray(nominal, dtype=np.float64)
    if mod == "range":
        factor = np.where(np.isfinite(r), r, 0.0)
    elif mod == "incidence":
        a = np.asarray(incidence, dtype=np.float64)
        factor = np.where(np.isfinite(r) & np.isfinite(a), a, 0.0)
    else:
        reach = SLOPE_CAP * np.where(np.isfinite(r), r, 0.0)
        factor = np.clip(range_slope(r, bearings), -reach, reach)
    return values * factor


def check_extra_state(names: Any) -> tuple[str, ...]:
    """``names`` as a tuple of distinct non-empty strings, else a ``ValueError`` naming ``extra_state``."""
    if not isinstance(names, (tuple, list)) or not all(isinstance(n, str) and n for n in names):
        raise InputError(f"extra_state: expected a tuple of variable names, got {names!r}")
    if len(set(names)) != len(names):
        raise InputError(f"extra_state: duplicate names in {names!r}")
    for n in names:
        split_term(n)
    return tuple(names)


def base_residual(x: NDArray[np.float64], mu: NDArray[np.float64], hit: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Residual ``x - mu`` [m] clipped to +-:data:`PREV_CLIP`; 0 for nulls, missing readings, rays without hit."""
    ok = hit & np.isfinite(x) & (x > 0)
    return np.where(ok, np.clip(np.where(ok, x, 0.0) - np.where(ok, mu, 0.0), -PREV_CLIP, PREV_CLIP), 0.0)


def consecutive(t: NDArray[np.float64] | None, n: int) -> NDArray[np.bool_]:
    """``(n,)``: whether scan ``s`` directly follows scan ``s - 1`` (no time gap > 1.5 median periods)."""
    ok = np.ones(n, dtype=bool)
    ok[:1] = False
    if t is not None and n > 2:
        dt = np.diff(t)
        med = float(np.median(dt))
        ok[1:] = (dt > 0) & (dt <= 1.5 * med) if med > 0 else dt >= 0
    return ok


def scan_features(
    log: LidarLog,
    names: tuple[str, ...],
    mu_table: NDArray[np.float64] | None,
    nominal: NDArray[np.float64] | None = None,
    incidence: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Raw extra variables ``(S, K, d)`` of the log's readings (see the module docstring).

    Args:
        log: a scan log ``(S, K, 1)``.
        names: the state variable names.
        mu_table: ``(S, K)`` tables' mean [m] (``NaN``/``inf`` off the map); needed for ``prev_residual``.
        nominal: ``(S, K)`` nominal ranges [m] of the map's raycast; needed by the :data:`GEOMETRY_MODIFIERS`.
        incidence: ``(S, K)`` incidence angles [rad] of the raycast.

    Raises:
        ValueError: naming the variable the log lacks.
    """
    s, k = log.n_poses, log.n_bearings
    out = np.zeros((s, k, len(names)))
    for i, term in enumerate(names):
        n, mod = split_term(term)
        if n == TIME:
            if log.t is None:
                raise InputError(f"{log.source}: field 't' is missing, but the lidar's extra state names 't'")
            out[:, :, i] = (log.t - log.t[0])[:, None]
        elif n == PREV:
            if mu_table is None:
                raise InputError("prev_residual needs the tables' mean")
            x = log.ranges[:, :, 0]
            e = base_residual(x, mu_table, np.isfinite(mu_table))
            prev = np.zeros_like(e)
            prev[1:] = e[:-1]
            out[:, :, i] = np.where(consecutive(log.t, s)[:, None], prev, 0.0)
        else:
            if n not in log.covariates:
                raise InputError(
                    f"{log.source}: field 'cov_{n}' is missing, but the lidar's extra state names {n!r} "
                    f"(covariates: {sorted(log.covariates)})"
                )
            out[:, :, i] = np.asarray(log.covariates[n], dtype=np.float64)[:, None]
        out[:, :, i] = modify(out[:, :, i], mod, log.bearings, nominal, incidence)
    if not np.isfinite(out).all():
        bad = names[int(np.argmin(np.isfinite(out).all(axis=(0, 1))))]
        raise InputError(f"{log.source}: extra state variable {bad!r} holds NaN or infinite values")
    return out


def _design(z: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.concatenate([np.ones(z.shape[:-1] + (1,)), z], axis=-1)


def _newton_logit(xd: NDArray[np.float64], y: NDArray[np.float64], offset: NDArray[np.float64]) -> NDArray[np.float64]:
    """Ridge-penalised logistic regression coefficients of ``y`` on ``xd`` with a fixed logit ``offset``."""
    beta = np.zeros(xd.shape[1])
    for _ in range(25):
        p = 1.0 / (1.0 + np.exp(-np.clip(offset + xd @ beta, -30, 30)))
        g = xd.T @ (p - y) + _RIDGE * beta
        h = (xd * (p * (1 - p))[:, None]).T @ xd + _RIDGE * np.eye(xd.shape[1])
        step = np.linalg.solve(h, g)
        beta -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return beta


def _fit_bias_sigma(
    xb: NDArray[np.float64], xs: NDArray[np.float64], e: NDArray[np.float64], log_sigma: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Bias coefficients on ``xb`` (bisquare IRLS) and log-sigma ones on ``xs`` (Gaussian likelihood) of ``e``."""
    w = np.ones(e.size)
    cb = np.zeros(xb.shape[1])
    eye_b, eye = np.eye(xb.shape[1]), np.eye(xs.shape[1])
    for _ in range(4):
        a = (xb * w[:, None]).T @ xb + 1e-9 * _RIDGE * eye_b * max(w.sum(), 1.0)
        cb = np.linalg.solve(a, (xb * w[:, None]).T @ e)
        res = np.abs(e - xb @ cb)
        cut = 6.0 * max(float(np.average(res, weights=np.maximum(w, 1e-12))), 1e-4)
        u = res / cut
        w = np.where(u < 1, (1 - u * u) ** 2, 0.0)
    m = w > 0
    r2 = (e - xb @ cb)[m] ** 2
    xm, ls = xs[m], log_sigma[m]
    cs = np.zeros(xs.shape[1])
    for _ in range(30):
        q = r2 * np.exp(-2 * np.clip(ls + xm @ cs, -20, 20))
        g = xm.T @ (1 - q) + _RIDGE * cs
        h = 2 * (xm * q[:, None]).T @ xm + _RIDGE * eye
        step = np.linalg.solve(h, g)
        step *= min(1.0, 1.0 / max(np.max(np.abs(step)), 1e-12))  # damped: at most 1 (log m) per step
        cs -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return cb, cs


def part_columns(names: tuple[str, ...]) -> list[NDArray[np.int64]]:
    """Per part (:data:`PARTS`), the design columns it uses: the intercept and the terms that act on it."""
    return [
        np.array([0] + [i + 1 for i, n in enumerate(names) if term_part(n) in (None, part)], dtype=np.int64)
        for part in PARTS
    ]


def fit_extra_terms(model: LidarLWLR, log: LidarLog) -> None:
    """Fit the linear extra-state terms of a fitted ``model`` (tables set) on a scan log; sets the attributes.

    Sets ``extra_state_`` (names), ``extra_mean_``/``extra_scale_`` ``(d,)`` (standardisation),
    ``extra_low_``/``extra_high_`` ``(d,)`` (the standardised terms' range on the fit readings: a query is
    clamped to it, so a U-shaped or steep term is not extrapolated beyond the data it was fitted on; a
    variable's modified terms follow its plain term's clamp, :func:`apply_extra`) and
    ``extra_coef_`` ``(3, d + 1)`` (rows: logit p_null, bias [m], log sigma; columns: intercept, variables;
    0 where a term is restricted to another part, :func:`term_part`).
    """
    names = check_extra_state(model.extra_state)
    model.extra_state_ = names
    d = len(names)
    model.extra_mean_, model.extra_scale_ = np.zeros(d), np.ones(d)
    model.extra_low_, model.extra_high_ = np.zeros(d), np.zeros(d)
    model.extra_coef_ = np.zeros((3, d + 1))
    if not names:
        return
    if log.ranges.shape[2] != 1:
        raise InputError(f"{log.source}: extra_state needs a scan log (one reading per scan and bearing)")
    r, a, _ = raycast_pose(log.poses, model.bearings_, as_segments(log.require_map(), name="map"), model.max_range)
    p = model.params_from_features(r, a, extra=None, base_only=True)
    hit = np.isfinite(r)
    raw = scan_features(log, names, np.where(hit, p["mu"], np.nan), r, a)
    x = log.ranges[:, :, 0]
    valid = hit & ~np.isnan(x)
    mean = raw[valid].mean(0) if valid.any() else np.zeros(d)
    scale = raw[valid].std(0) if valid.any() else np.ones(d)
    scale = np.where(scale > 1e-12, scale, 1.0)
    z = (raw - mean) / scale
    if valid.any():
        model.extra_low_, model.extra_high_ = np.minimum(z[valid].min(0), 0.0), np.maximum(z[valid].max(0), 0.0)
    xd = _design(z)
    cols = part_columns(names)
    coef = np.zeros((3, d + 1))
    q = np.clip(p["p_null"][valid], P_EPS, 1 - P_EPS)
    coef[0, cols[0]] = _newton_logit(xd[valid][:, cols[0]], (x[valid] == 0).astype(float), np.log(q / (1 - q)))
    ok = valid & (x > 0) & (x <= (model.spur_above if model.variant == "extended" else np.inf))
    ok &= np.abs(np.where(ok, x, 0.0) - np.where(ok, p["mu"], 0.0)) < PREV_CLIP
    if ok.sum() > 2 * (d + 1):
        xo = xd[ok]
        coef[1, cols[1]], coef[2, cols[2]] = _fit_bias_sigma(
            xo[:, cols[1]], xo[:, cols[2]], x[ok] - p["mu"][ok], np.log(p["sigma"][ok])
        )
    model.extra_mean_, model.extra_scale_ = mean, scale
    model.extra_coef_ = np.clip(coef, -MAX_COEF, MAX_COEF)


def _clamp_by_variable(model: LidarLWLR, ex: NDArray[np.float64]) -> NDArray[np.float64]:
    """Raw terms ``ex (..., d)`` with each modified term of a variable taken at its plain term's clamped value.

    ``v@sq`` is ``clamp(v)**2`` and ``v@cos_bearing`` ``clamp(v) cos(bearing)``, ``clamp`` being the range of
    the plain term ``v`` on the fit readings: clamped term by term, a query beyond that range would take
    ``v`` at one end and ``v**2`` at the larger square of the two ends, a point off the fitted curve (a
    U-shaped fit then misses by its whole curvature). Terms whose variable has no plain term are left as
    they are (their own clamp applies).
    """
    terms = [split_term(n) for n in model.extra_state_]
    plain = {v: j for j, (v, m) in enumerate(terms) if m is None}
    out = None
    for i, (v, mod) in enumerate(terms):
        j = plain.get(v)
        if mod is None or j is None:
            continue
        lo, hi = (model.extra_mean_[j] + model.extra_scale_[j] * b for b in (model.extra_low_[j], model.extra_high_[j]))
        x = ex[..., j]
        xc = np.clip(x, lo, hi)
        if np.array_equal(xc, x):
            continue
        power = 2 if mod.split("@")[0] == "sq" else 1
        small = np.abs(x) <= 1e-12
        ratio = np.where(small, 1.0, xc / np.where(small, 1.0, x)) ** power
        out = np.array(ex, dtype=np.float64) if out is None else out
        out[..., i] = np.where(small & (mod == "sq"), xc**2, ex[..., i] * ratio)
    return ex if out is None else out


def apply_extra(
    model: LidarLWLR, out: dict[str, NDArray[np.float64]], hit: NDArray[np.bool_], extra: Any
) -> dict[str, NDArray[np.float64]]:
    """Table values ``out`` (``p_null``, ``bias``, ``sigma`` or ``log_sigma``) with the extra terms added at hits.

    Args:
        model: the fitted model.
        out: table values, each ``(..., K)``.
        hit: ``(..., K)`` rays that hit the map.
        extra: raw extra variables broadcastable to ``(..., K, d)`` (e.g. ``(d,)`` for one scan's
            per-scan variables, ``(S, 1, d)`` or ``(S, K, d)``).

    Raises:
        ValueError: when ``extra`` is missing or has the wrong last axis.
    """
    names = model.extra_state_
    if extra is None:
        raise InputError(f"extra: this lidar model's state includes {list(names)}; pass their values")
    ex = np.asarray(extra, dtype=np.float64)
    if ex.ndim == 0 or ex.shape[-1] != len(names):
        raise InputError(f"extra: expected a last axis of {len(names)} values ({list(names)}), got shape {ex.shape}")
    ex = _clamp_by_variable(model, np.broadcast_to(ex, hit.shape + (len(names),)))
    z = (ex - model.extra_mean_) / model.extra_scale_
    xd = _design(np.clip(z, model.extra_low_, model.extra_high_))  # no extrapolation beyond the fit's range
    lin = xd @ model.extra_coef_.T  # (..., K, 3)
    q = np.clip(out["p_null"], 1e-12, 1 - 1e-12)
    res = dict(out)
    res["p_null"] = np.where(hit, 1.0 / (1.0 + np.exp(-np.clip(np.log(q / (1 - q)) + lin[..., 0], -30, 30))), q)
    res["bias"] = np.where(hit, out["bias"] + lin[..., 1], out["bias"])
    ds = np.where(hit, lin[..., 2], 0.0)
    if "log_sigma" in out:
        res["log_sigma"] = out["log_sigma"] + ds
    else:
        res["sigma"] = out["sigma"] * np.exp(ds)
    return res
