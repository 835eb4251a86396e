"""Seeded families of synthetic logs with one planted cause (or none), to measure ``diagnose`` as a property.

Every case is drawn at random from a seed: the kind of effect, its strength, its functional form,
which part of the model it acts on, its interaction with the model's state, a noisy proxy of the
cause, random-walk distractors, random column names and the noise structure (Gaussian or Student-t,
with or without a slowly drifting AR(1) component). The truth is returned beside the log, never
given to the tool.

Lidar logs (:func:`lidar_case`) are scan logs in a random rectangular room with a box obstacle, built
with :func:`~sensor_envs.lidar.log.log_from_arrays` and the project's raycaster; radar logs
(:func:`radar_case`: interactions with the azimuth side or the range, on either axis; in half the cases
a slowly drifting offset shared by all targets) take the target states of the project's rig
(:func:`~sensor_envs.radar.rig.record_rig_log`)
and draw outputs from a Gaussian radar fitted to it (outputs then depend on the corner only, so nothing
else in the log matters unless planted).

Strength is measured against the residual the model sees: a mean or rate effect of strength ``s``
moves the mean residual (or the detection / null rate) by ``s`` standard deviations of that residual
between the 5th and 95th percentiles of the cause; a spread effect of strength ``s`` scales the
standard deviation by ``1 + s`` across the same range.
"""

from __future__ import annotations

import string
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Case",
    "LIDAR_KINDS",
    "PLANT_KINDS",
    "RADAR_KINDS",
    "found_stepwise",
    "lidar_case",
    "plant_lidar",
    "radar_case",
    "static_scan_log",
]

LIDAR_KINDS = ("mean", "interaction", "spread", "rate", "correlation", "null")
"""Planted-effect kinds of the lidar family (``null``: no cause, drift and heavy tails only)."""
RADAR_KINDS = ("mean", "interaction", "spread", "rate", "null")
"""Planted-effect kinds of the radar family (the KDE's ``z_{t-1}`` already carries correlation)."""


@dataclass
class Case:
    """One generated log and its truth.

    Attributes:
        log: the :class:`~sensor_envs.lidar.log.LidarLog` or :class:`~sensor_envs.radar.log.RadarLog`.
        kind: the planted kind (``null`` = nothing planted).
        cause: the candidate name of the cause (``None`` for a null log).
        proxy: the name of the noisy proxy column (``None`` when there is none).
        base_state: state the diagnosed base model is given (e.g. ``prev_residual`` when the lidar's
            noise drifts, so the known correlation is in the model).
        info: the drawn parameters (strength, form, noise, sizes).
    """

    log: Any
    kind: str
    cause: str | None
    proxy: str | None
    base_state: tuple[str, ...] = ()
    info: dict[str, Any] = field(default_factory=dict)


def _name(rng: np.random.Generator, taken: set[str]) -> str:
    """A random column name (lowercase letters), distinct from ``taken``."""
    while True:
        n = "".join(rng.choice(list(string.ascii_lowercase), size=int(rng.integers(3, 8))))
        if n not in taken and n not in ("t", "v", "omega", "time", "scan", "range", "bearing"):
            taken.add(n)
            return n


def _ar1(rng: np.random.Generator, n: int, rho: float) -> NDArray[np.float64]:
    """A stationary unit-variance AR(1) series of length ``n``."""
    e = rng.normal(size=n) * np.sqrt(1 - rho**2)
    out = np.empty(n)
    out[0] = rng.normal()
    for i in range(1, n):  # sequential recursion
        out[i] = rho * out[i - 1] + e[i]
    return out


def _random_walk(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    """A standardised Gaussian random walk of length ``n``."""
    w = np.cumsum(rng.normal(size=n))
    return (w - w.mean()) / max(w.std(), 1e-12)


def _form(rng: np.random.Generator, c: NDArray[np.float64]) -> tuple[str, NDArray[np.float64]]:
    """A random shape ``f(c)`` spanning 0..1 between the 5th and 95th percentiles of ``c``, centred to mean 0."""
    lo, hi = np.percentile(c, [5, 95])
    u = (c - lo) / max(hi - lo, 1e-12)
    form = str(rng.choice(["linear", "step", "u-shape", "saturating"]))
    if form == "linear":
        g = u
    elif form == "step":
        g = 1.0 / (1.0 + np.exp(-(u - rng.uniform(0.3, 0.7)) * 12))
    elif form == "u-shape":
        g = 4 * (u - 0.5) ** 2
    else:
        g = 1 - np.exp(-3 * np.clip(u, 0, None))
    glo, ghi = np.percentile(g, [5, 95])
    g = (g - glo) / max(ghi - glo, 1e-12)
    return form, g - g.mean()


def _noise(rng: np.random.Generator, shape: tuple[int, ...], heavy: bool, df: float) -> NDArray[np.float64]:
    """Unit-variance noise: Gaussian, or Student-t with ``df`` degrees of freedom when ``heavy``."""
    z = rng.normal(size=shape)
    if heavy:
        z *= np.sqrt((df - 2) / rng.chisquare(df, size=shape))
    return z


def _covariates(
    rng: np.random.Generator,
    n: int,
    cause: NDArray[np.float64],
    taken: set[str],
    with_proxy: bool,
    walk: Any = None,
) -> tuple[dict[str, NDArray[np.float64]], str, str | None, float]:
    """The cause under a random name, a noisy proxy of it, two random walks and one white-noise column.

    ``walk()`` draws a random-walk distractor with the log's time structure (default: one walk of ``n``).
    """
    walk = walk if walk is not None else (lambda: _random_walk(rng, n))
    cols: dict[str, NDArray[np.float64]] = {}
    cname = _name(rng, taken)
    cols[cname] = cause
    pname, rho = None, 0.0
    if with_proxy:
        rho = float(rng.uniform(0.7, 0.95))
        pname = _name(rng, taken)
        cols[pname] = rho * cause + np.sqrt(1 - rho**2) * rng.normal(size=n)
    for _ in range(2):
        cols[_name(rng, taken)] = walk()
    cols[_name(rng, taken)] = rng.normal(size=n)
    order = list(cols)
    rng.shuffle(order)
    return {k: cols[k] for k in order}, cname, pname, rho


# -- lidar --------------------------------------------------------------------------------------------


def _room(rng: np.random.Generator) -> tuple[NDArray[np.float64], float, float]:
    """A random rectangular room with one box obstacle: segments ``(8, 2, 2)``, width, height [m]."""
    w, h = rng.uniform(3.0, 5.0), rng.uniform(2.5, 4.0)
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]])
    segs = [[corners[i], corners[(i + 1) % 4]] for i in range(4)]
    bx, by, bs = rng.uniform(0.3, w - 0.8), rng.choice([0.2, h - 0.6]), rng.uniform(0.3, 0.5)
    box = np.array([[bx, by], [bx + bs, by], [bx + bs, by + bs], [bx, by + bs]])
    segs += [[box[i], box[(i + 1) % 4]] for i in range(4)]
    return np.asarray(segs, dtype=float), w, h


def lidar_case(kind: str, seed: int, scans: int = 500, bearings: int = 60, static: bool = False) -> Case:
    """A scan log of ``scans x bearings`` readings with one planted effect of ``kind`` (:data:`LIDAR_KINDS`).

    ``static``: the calibration shape, one pose recorded over time (no ``v``/``omega`` columns; the
    model's folds are then blocks of time, never poses).
    """
    from sensor_envs.lidar.log import log_from_arrays
    from sensor_envs.lidar.lwlr import lidar_features

    if kind not in LIDAR_KINDS:
        raise ValueError(f"kind: expected one of {LIDAR_KINDS}, got {kind!r}")
    rng = np.random.default_rng(seed)
    segs, w, h = _room(rng)
    i = np.arange(scans)
    period = 0.2
    t = period * i
    omega = 0.5 * _ar1(rng, scans, 0.95)
    v = 0.25 + 0.08 * _ar1(rng, scans, 0.9)
    ph = rng.uniform(0, 2 * np.pi, 2)
    poses = np.stack(
        [
            w / 2 + 0.25 * w * np.sin(0.023 * i + ph[0]),
            h / 2 + 0.2 * h * np.cos(0.017 * i + ph[1]) * (1 if rng.random() < 0.5 else -1),
            np.cumsum(period * omega),
        ],
        axis=1,
    )
    if static:
        poses = np.repeat(poses[:1], scans, axis=0)
    b = np.linspace(0, 2 * np.pi, bearings, endpoint=False)
    r, _ = lidar_features(poses, b, segs, 5.0)
    heavy = bool(rng.random() < 0.5)
    df = float(rng.uniform(3.0, 6.0))
    drift = kind == "null" or bool(rng.random() < 0.5)
    drift = drift and kind != "correlation"
    sig = 0.01 + 0.005 * np.nan_to_num(r, nan=2.0)  # [m]
    e = _noise(rng, r.shape, heavy, df)
    info: dict[str, Any] = {"scans": scans, "bearings": bearings, "heavy_tails": heavy, "df": df if heavy else None}
    info["static"] = static
    if drift:  # slowly drifting common range offset (AR(1) per scan): the spurious-regression trap
        rho_d, sd_d = float(rng.uniform(0.8, 0.98)), float(rng.uniform(0.2, 0.5))
        e = e + sd_d * _ar1(rng, scans, rho_d)[:, None]
        info["drift"] = {"rho": rho_d, "sd_in_sigma": sd_d}
    cause_raw = _ar1(rng, scans, float(rng.uniform(0.85, 0.98)))
    taken: set[str] = set()
    cov, cname, pname, prho = _covariates(rng, scans, cause_raw, taken, with_proxy=kind not in ("null", "correlation"))
    if not static:
        cov["v"], cov["omega"] = v, omega
    p_null = np.full(r.shape, 0.05)
    strength = float(np.exp(rng.uniform(np.log(0.3), np.log(1.0))))
    form, f = _form(rng, cause_raw)
    info.update(strength=strength, form=form, proxy_corr=prho)
    if kind == "mean":
        e = e + strength * f[:, None]
    elif kind == "interaction":  # the sign follows cos(bearing): zero mean over the scan
        phase = float(rng.uniform(0, 2 * np.pi))
        e = e + strength * np.sqrt(2) * f[:, None] * np.cos(b - phase)[None]
        info["interaction"] = f"cos(bearing - {phase:.2f})"
    elif kind == "spread":
        strength = float(rng.uniform(0.3, 0.6))
        scale = np.exp(np.log1p(strength) * (f - f.min()) / max(np.ptp(f), 1e-12))
        e = e * scale[:, None] / np.sqrt(np.mean(scale**2))
        info.update(strength=strength)
    elif kind == "rate":
        p_null = np.clip(0.05 + strength * np.sqrt(0.05 * 0.95) * f[:, None], 0.005, 0.6) * np.ones_like(r)
    elif kind == "correlation":
        rho = float(rng.uniform(0.3, 0.7))
        for s in range(1, scans):  # AR(1) along the scans, same marginal variance
            e[s] = rho * e[s - 1] + np.sqrt(1 - rho**2) * e[s]
        info.update(strength=rho, form="AR(1) per bearing")
        cname, pname = "prev_residual", None
    x = r + sig * e
    x = np.where(rng.random(r.shape) < p_null, 0.0, np.maximum(x, 0.02))
    x = np.where(np.isfinite(r), x, 0.0)
    log = log_from_arrays(x[..., None], b, poses, segs, t=t, covariates=cov, source=f"suite lidar {kind} {seed}")
    cause = None if kind == "null" else cname
    base = ("prev_residual",) if drift else ()
    return Case(log, kind, cause, pname if kind != "null" else None, base, info)


# -- radar --------------------------------------------------------------------------------------------


def radar_case(kind: str, seed: int, sequences: int = 24, cycles: int = 30, targets: int = 10) -> Case:
    """A radar log on the rig's target states with one planted effect of ``kind`` (:data:`RADAR_KINDS`)."""
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.log import RadarLog, target_tuples
    from sensor_envs.radar.rig import record_rig_log

    if kind not in RADAR_KINDS:
        raise ValueError(f"kind: expected one of {RADAR_KINDS}, got {kind!r}")
    rng = np.random.default_rng(seed)
    rig = record_rig_log(sequences, cycles, targets, rng, velocity_columns=True)
    tt = target_tuples(rig)
    g = GaussianRadar().fit(rig)
    z, _ = g.sample(tt.corner, rng)
    mu, p_miss = g.mean_output(tt.corner)
    det = ~np.isnan(z[:, 0])
    dev = np.where(det[:, None], z - mu, 0.0)
    heavy = bool(rng.random() < 0.5)
    df = float(rng.uniform(3.0, 6.0))
    if heavy:
        dev *= np.sqrt((df - 2) / rng.chisquare(df, size=dev.shape[0]))[:, None]
    info: dict[str, Any] = {"rows": len(rig), "heavy_tails": heavy, "df": df if heavy else None}
    # per-track AR(1) offsets in some cases (the KDE's z_{t-1} carries them; as the corner moves, the
    # model's mean moves under them, so relative speed then matters a little given z_{t-1})
    order = np.lexsort((tt.frame, tt.target, tt.sequence))
    rho_t = float(rng.uniform(0.3, 0.9))
    sd = np.nanstd(dev, axis=0)
    ar = np.zeros_like(dev)
    for j in range(1, order.size):  # along each track, in frame order
        a, p = order[j], order[j - 1]
        same = tt.sequence[a] == tt.sequence[p] and tt.target[a] == tt.target[p]
        ar[a] = rho_t * ar[p] + np.sqrt(1 - rho_t**2) * rng.normal(size=2) if same else rng.normal(size=2)
    frac = float(rng.uniform(0.0, 0.5)) if rng.random() < 0.5 else 0.0
    dev = np.sqrt(1 - frac**2) * dev + frac * sd * ar
    info["track_ar1"] = {"rho": rho_t, "share_sd": frac}
    if kind == "null" or rng.random() < 0.5:  # a slowly drifting offset shared by all targets (a temperature)
        rho_d, sd_d = float(rng.uniform(0.9, 0.99)), float(rng.uniform(0.2, 0.5))
        frames = tt.sequence * (cycles + 1) + tt.frame  # the log's cycles in time order
        drift = np.stack([_ar1(rng, sequences * (cycles + 1), rho_d) for _ in range(2)], axis=1)
        dev = dev + sd_d * sd * drift[frames]
        info["drift"] = {"rho": rho_d, "sd_in_sd": sd_d}
    # covariates: per (sequence, frame) slow processes plus a per-target level
    n = tt.z.shape[0]
    seq_frame = tt.sequence * (cycles + 1) + tt.frame
    keys, inv = np.unique(seq_frame, return_inverse=True)
    proc = np.concatenate([_ar1(rng, cycles + 1, 0.95) for _ in range(sequences)])
    level = rng.normal(size=(sequences, targets + 1))[tt.sequence, np.clip(tt.target, 0, targets)]
    cause = (proc[keys][inv] + 0.5 * level) / np.sqrt(1.25)
    taken = set(rig.columns)

    def walk() -> NDArray[np.float64]:  # one random walk per sequence over its frames
        return np.concatenate([_random_walk(rng, cycles + 1) for _ in range(sequences)])[keys][inv]

    cov, cname, pname, prho = _covariates(rng, n, cause, taken, with_proxy=kind != "null", walk=walk)
    strength = float(np.exp(rng.uniform(np.log(0.3), np.log(1.0))))
    form, f = _form(rng, cause)
    info.update(strength=strength, form=form, proxy_corr=prho)
    sd = np.std(dev[det], axis=0)
    if kind == "mean":
        axis = int(rng.integers(2))
        dev[:, axis] += strength * sd[axis] * f
        info["axis"] = "xy"[axis]
    elif kind == "interaction":  # an offset whose sign follows the model's own state: azimuth side or range
        axis = int(rng.integers(2))
        if rng.random() < 0.5:
            sign = np.sign(tt.corner[:, 1] - np.median(tt.corner[:, 1]))
            info["interaction"] = "sign of the lateral position (azimuth side)"
        else:
            rank = np.argsort(np.argsort(np.hypot(*tt.corner.T)))
            sign = np.sqrt(3.0) * (2.0 * (rank + 0.5) / rank.size - 1.0)  # unit variance, flips at the median
            info["interaction"] = "range (linear in its rank, sign flips at the median range)"
        dev[:, axis] += strength * sd[axis] * f * sign
        info["axis"] = "xy"[axis]
    elif kind == "spread":
        strength = float(rng.uniform(0.3, 0.6))
        scale = np.exp(np.log1p(strength) * (f - f.min()) / max(np.ptp(f), 1e-12))
        dev *= (scale / np.sqrt(np.mean(scale**2)))[:, None]
        info.update(strength=strength)
    elif kind == "rate":
        p_det = 1 - p_miss
        sdd = np.sqrt(np.mean(p_det * (1 - p_det)))
        top = np.percentile(f, 95)  # the drop spans the cause's 5-95 % range, not its extremes
        keep = rng.random(n) < np.clip(1 + strength * sdd * (np.minimum(f, top) - top) / np.clip(p_det, 0.05, 1), 0, 1)
        det = det & keep
    znew = np.where(det[:, None], mu + dev, np.nan)
    c = {k: np.asarray(v).copy() for k, v in rig.columns.items()}
    c["meas_x"][tt.row] = tt.corner[:, 0] + znew[:, 0]
    c["meas_y"][tt.row] = tt.corner[:, 1] + znew[:, 1]
    for k, vals in cov.items():
        col = np.full(len(rig), np.nan)
        col[tt.row] = vals
        c[k] = col
    log = RadarLog(c, source=f"suite radar {kind} {seed}")
    return Case(log, kind, None if kind == "null" else cname, pname, (), info)


# -- a real scan log with a planted cause -------------------------------------------------------------

PLANT_KINDS = ("mean", "interaction", "spread", "rate", "null")
"""Kinds :func:`plant_lidar` plants into a real scan log (``null``: distractor columns only)."""


def plant_lidar(log: Any, kind: str, seed: int, strength: float | None = None) -> Case:
    """A real scan log (with a map, ``(S, K, 1)``) with one cause planted, the distractors of the families.

    The cause is a random AR(1) column (as a slow covariate such as a temperature); a noisy proxy,
    two random walks and a white-noise column are added under random names. The effect is sized by the
    log's own spread: ``sd`` = 1.4826 x the median absolute deviation of ``x - r`` (reading minus the
    nominal range from the map) over the hit, non-null readings. ``mean``: ``x + s sd f(c)``;
    ``interaction``: ``x + s sd sqrt(2) f(c) cos(bearing - phase)``; ``spread``: independent noise of
    sd ``sd sqrt(g^2 - 1)`` added, ``g`` rising from 1 to ``1 + s`` across the cause's range (a
    spread of ``sd`` grows to ``g sd``, the mean stays; scaling the deviation from the map instead would
    also scale the map's own errors, a mean effect per bearing); ``rate``: extra nulls with probability
    rising by ``s sqrt(p (1 - p))`` (``p`` the log's null rate, at least 0.05) across it. Real effects
    already in the log (of time, speed, turn rate) stay: the truth is only what was planted. The base
    model is given ``prev_residual`` (a real log's readings are correlated in time).

    Args:
        log: the prepared real log (:func:`sensor_envs.lidar.mapping.prepare_log`).
        kind: one of :data:`PLANT_KINDS`.
        seed: seed of everything drawn.
        strength: ``s``; default drawn log-uniformly from 0.5-1.0 (0.3-0.6 for a spread change).
    """
    from sensor_envs.lidar.log import LidarLog
    from sensor_envs.lidar.lwlr import lidar_features

    if kind not in PLANT_KINDS:
        raise ValueError(f"kind: expected one of {PLANT_KINDS}, got {kind!r}")
    rng = np.random.default_rng(seed)
    n, k = log.ranges.shape[:2]
    x = log.ranges[:, :, 0].copy()
    r, _ = lidar_features(log.poses, log.bearings, log.require_map(), float(np.nanmax(np.where(x > 0, x, 0))))
    hit = np.isfinite(r) & (x > 0) & np.isfinite(x)
    dev = np.where(hit, x - np.nan_to_num(r), 0.0)
    sd = 1.4826 * float(np.median(np.abs(dev[hit] - np.median(dev[hit]))))
    cause = _ar1(rng, n, float(rng.uniform(0.85, 0.98)))
    taken = set(log.covariates)
    cov, cname, pname, prho = _covariates(rng, n, cause, taken, with_proxy=kind != "null")
    form, f = _form(rng, cause)
    lo, hi = (0.3, 0.6) if kind == "spread" else (0.5, 1.0)
    drawn = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # drawn always: the same case at any strength
    strength = drawn if strength is None else float(strength)
    info: dict[str, Any] = {"source": log.source, "scans": n, "bearings": k, "strength": strength, "form": form}
    info.update(sd_m=sd, proxy_corr=prho, planted=list(cov))
    if kind == "mean":
        x = np.where(hit, x + strength * sd * f[:, None], x)
    elif kind == "interaction":
        phase = float(rng.uniform(0, 2 * np.pi))
        x = np.where(hit, x + strength * sd * np.sqrt(2) * f[:, None] * np.cos(log.bearings - phase)[None], x)
        info["interaction"] = f"cos(bearing - {phase:.2f})"
    elif kind == "spread":  # extra noise: the spread grows from the log's own to (1 + s) x, the mean stays
        g = 1.0 + strength * (f - f.min()) / max(np.ptp(f), 1e-12)
        x = np.where(hit, np.maximum(x + sd * np.sqrt(g**2 - 1.0)[:, None] * rng.normal(size=x.shape), 0.02), x)
    elif kind == "rate":
        p = max(float(np.mean(x[np.isfinite(r) & np.isfinite(x)] == 0)), 0.05)
        p_add = np.clip(strength * np.sqrt(p * (1 - p)) * (f - f.min()), 0.0, 0.9)
        x = np.where(hit & (rng.random(x.shape) < p_add[:, None]), 0.0, x)
    covariates = {**log.covariates, **cov}
    planted = LidarLog(x[..., None], log.bearings, log.poses, log.map_segments, log.t, covariates, log.source)
    truth = None if kind == "null" else cname
    return Case(planted, kind, truth, pname if kind != "null" else None, ("prev_residual",), info)


def static_scan_log(log: Any, pose: int = 0, period: float = 0.2) -> Any:
    """The static-pose-over-time shape from a repeated log ``(P, K, R)``: pose ``pose``'s ``R`` scans in order.

    Times are ``period`` [s] apart (the repeats' order; a Neato XV-11 turns at 5 Hz).
    """
    from sensor_envs.lidar.log import LidarLog

    rep = np.moveaxis(log.ranges[pose], 1, 0)[..., None]  # (R, K, 1)
    m = rep.shape[0]
    poses = np.repeat(log.poses[pose : pose + 1], m, axis=0)
    return LidarLog(rep, log.bearings, poses, log.map_segments, period * np.arange(m), {}, f"{log.source} pose {pose}")


def found_stepwise(case: Case, res: Any) -> bool:
    """Whether the loop found ``case``'s cause judged step by step (the suite's ``recall_stepwise``).

    The cause ranked first among the planted columns at the step it was added (after the log's own
    effects were taken), no other planted column added, and the held-out NLL down (the suite's
    ``recall`` asks the cause to lead the FIRST ranking). On a real log only the planted columns
    (``case.info["planted"]``) count; on a synthetic one every column does.
    ``res``: the case's :class:`~sensor_envs.diagnose.core.DiagnoseResult`.
    """
    planted = case.info.get("planted")
    if case.cause not in res.added or not res.error_after < res.error_before:
        return False
    if any(a != case.cause and (planted is None or a in planted) for a in res.added):
        return False
    for step in res.steps:
        if any(a["candidate"] == case.cause and a["decision"].startswith("added") for a in step.get("attempts", [])):
            names = [e["name"] for e in step["ranking"] if planted is None or e["name"] in planted]
            return bool(names) and names[0] == case.cause
    return False
