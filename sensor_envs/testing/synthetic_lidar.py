"""A synthetic lidar scan log with one planted effect, for the diagnose tests and ``benchmarks/bench_diagnose.py``."""

from __future__ import annotations

import numpy as np

from sensor_envs.lidar.log import LidarLog, log_from_arrays
from sensor_envs.lidar.lwlr import lidar_features

BOX = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]], dtype=float)
BIAS_PER_OMEGA = 0.03
"""Hidden range bias [m] per rad/s of turn rate."""


def _ar1(rng: np.random.Generator, n: int, rho: float, sd: float) -> np.ndarray:
    """A stationary AR(1) series with lag-1 correlation ``rho`` and standard deviation ``sd``."""
    e = rng.normal(0, sd * np.sqrt(1 - rho**2), n)
    out = np.empty(n)
    out[0] = rng.normal(0, sd)
    for i in range(1, n):
        out[i] = rho * out[i - 1] + e[i]
    return out


def make_log(kind: str, scans: int = 400, bearings: int = 48, seed: int = 0) -> LidarLog:
    """A synthetic scan log with the hidden effect ``kind`` (``none``, ``time``, ``omega``, ``corr``).

    ``omega_both``: the turn rate biases the range (as ``omega``) and raises the null rate (one cause
    acting on two parts of the model).
    """
    rng = np.random.default_rng(seed)
    i = np.arange(scans)
    t = 0.2 * i
    omega, v = _ar1(rng, scans, 0.95, 0.5), 0.25 + _ar1(rng, scans, 0.9, 0.08)  # stationary motion [rad/s, m/s]
    poses = np.stack([2 + 0.8 * np.sin(0.03 * i), 1.5 + 0.6 * np.cos(0.021 * i), np.cumsum(0.2 * omega)], axis=1)
    b = np.linspace(0, 2 * np.pi, bearings, endpoint=False)
    r, _ = lidar_features(poses, b, BOX, 5.0)
    noise = rng.normal(size=r.shape)
    if kind == "corr":  # AR(1) along the scans, same marginal variance
        for s in range(1, scans):
            noise[s] = 0.8 * noise[s - 1] + 0.6 * noise[s]
    x = r + (0.01 + 0.005 * r) * noise
    p_null = np.full(r.shape, 0.05)
    if kind in ("omega", "omega_both"):
        x = x + BIAS_PER_OMEGA * omega[:, None]
    if kind == "omega_both":
        p_null = np.clip(0.02 + 0.12 * np.abs(omega) / omega.std(), 0.0, 0.5)[:, None] * np.ones_like(r)
    if kind == "time":
        p_null = 0.02 + 0.25 * (t / t[-1])[:, None] * np.ones_like(r)
    x = np.where(rng.random(r.shape) < p_null, 0.0, x)
    cov = {"v": v, "omega": omega, "noise_a": rng.normal(size=scans), "weak": 0.3 * omega / omega.std()}
    cov["weak"] = cov["weak"] + rng.normal(size=scans)
    return log_from_arrays(x[..., None], b, poses, BOX, t=t, covariates=cov, source=f"synthetic {kind}")
