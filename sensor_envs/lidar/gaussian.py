"""The Gaussian baseline lidar: raycast plus range- and incidence-dependent normal noise (:class:`GaussianLidar`).

It implements :class:`~sensor_envs.lidar.sensors.LidarSensor` (and is importable from there); the learned lidar's
:meth:`~sensor_envs.lidar.lwlr.LidarLWLR.baseline` returns one fitted with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.jit import compiled
from sensor_envs.trig import tan_half_pi

__all__ = ["GaussianLidar"]


@dataclass(frozen=True)
class GaussianLidar:
    """The seed's baseline: raycast plus normal noise whose spread depends on range and incidence.

    ``sigma(r, alpha) = sigma0 + k_range * r**2 + k_incidence * r * tan(min(alpha, alpha_max))`` [m]

    * ``r**2`` growth: the XV-11-type sensor is a laser triangulation rangefinder (Konolige et al.,
      "A low-cost laser distance sensor", ICRA 2008), whose range error grows with the square of
      range (error ~ r^2 * pixel error / (focal length * baseline)). That paper reports "3 cm accuracy
      out to 6 m"; ``sigma0 = 5 mm`` and ``k_range = 0.7 mm/m^2`` give 5 mm + 25 mm = 3.0 cm at 6 m.
    * ``r * tan(alpha)`` growth: the beam's footprint on a wall stretches by ``1/cos(alpha)``, spreading
      the returned range (the incidence term of the noise models discussed by Tallavajhula & Kelly and
      by Pomerleau et al., "Noise characterization of depth sensors for surface inspections", 2012).
      ``k_incidence = 5 mm/m`` is a chosen default (about 1 cm at 2 m and 45 degrees), not a fit.
    * These are defaults: the validation (:mod:`sensor_envs.lidar.validate`) refits the baseline's
      parameters to the training part of each log, so the comparison with the learned model is fair.

    Null readings happen only where the ray has no hit within range (``p_null_floor`` adds a constant
    dropout, 0 by default).

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import GaussianLidar
        >>> lidar = GaussianLidar(sigma0=0.01)
        >>> scan = lidar.measure(np.full(1000, 2.0), np.zeros(1000), np.random.default_rng(0))
        >>> bool(abs(scan.mean() - 2.0) < 0.01)
        True
    """

    sigma0: float = 0.005
    k_range: float = 0.0007
    k_incidence: float = 0.005
    alpha_max: float = np.deg2rad(80.0)
    p_null_floor: float = 0.0

    def __post_init__(self) -> None:
        """Reject negative or non-finite parameters (a negative spread would silently flip the noise)."""
        for name in ("sigma0", "k_range", "k_incidence", "alpha_max", "p_null_floor"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise InputError(f"GaussianLidar: {name} must be a number, got {v!r}")
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"GaussianLidar: {name} must be finite and >= 0, got {v!r}")
        if not self.alpha_max < np.pi / 2:
            raise InputError(f"GaussianLidar: alpha_max must be < pi/2 [rad], got {self.alpha_max!r}")
        if not self.p_null_floor <= 1:
            raise InputError(f"GaussianLidar: p_null_floor must be a probability in [0, 1], got {self.p_null_floor!r}")

    def sigma(self, nominal_range: NDArray[np.float64], incidence: NDArray[np.float64]) -> NDArray[np.float64]:
        """Noise standard deviation [m] per bearing (``NaN`` where no hit)."""
        r = np.asarray(nominal_range, dtype=np.float64)
        hit = np.isfinite(r)
        rh = np.where(hit, r, 0.0)
        s = self.sigma0 + self.k_range * rh**2 + self.k_incidence * rh * self.tan_incidence(incidence)
        return np.where(hit, s, np.nan)

    def tan_incidence(self, incidence: NDArray[np.float64]) -> NDArray[np.float64]:
        """``tan(min(nan_to_num(alpha), alpha_max))`` per bearing (:func:`~sensor_envs.trig.tan_half_pi`).

        ``np.nan_to_num`` (NaN -> 0, -inf -> the lowest float64) spelled out: it costs ~9 us a call, a single
        env's step pays it every step.
        """
        a = np.clip(np.asarray(incidence, dtype=np.float64), np.finfo(np.float64).min, self.alpha_max)
        return tan_half_pi(np.where(np.isnan(a), 0.0, a))

    def measure(
        self, nominal_range: NDArray[np.float64], incidence: NDArray[np.float64], rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """Sample ranges [m]: ``Normal(r, sigma(r, alpha))``, ``NaN`` where no hit or dropped.

        With numba (the ``fast`` extra) one compiled pass does the arithmetic of :meth:`sigma` and the draw,
        in the numpy order, from the same draws of ``rng``: the same bits.
        """
        r = np.asarray(nominal_range, dtype=np.float64)
        noise = rng.standard_normal(r.shape)
        drop = rng.random(r.shape) if self.p_null_floor > 0 else None
        kernel = compiled(_gaussian_loops)
        if kernel is not None:
            shape = np.broadcast_shapes(r.shape, np.shape(incidence))
            out = kernel(
                np.ascontiguousarray(np.broadcast_to(r, shape)).ravel(),
                np.ascontiguousarray(np.broadcast_to(self.tan_incidence(incidence), shape)).ravel(),
                noise.ravel(),
                np.zeros(1) if drop is None else drop.ravel(),
                float(self.sigma0),
                float(self.k_range),
                float(self.k_incidence),
                float(self.p_null_floor),
            )
            return np.asarray(out).reshape(shape)
        hit = np.isfinite(r)
        out = np.where(hit, np.where(hit, r, 0.0) + noise * np.nan_to_num(self.sigma(r, incidence)), np.nan)
        if drop is not None:
            out = np.where(drop < self.p_null_floor, np.nan, out)
        return np.maximum(out, 0.0)


def _gaussian_loops(
    r: NDArray[np.float64],
    tan_incidence: NDArray[np.float64],
    noise: NDArray[np.float64],
    drop: NDArray[np.float64],
    sigma0: float,
    k_range: float,
    k_incidence: float,
    p_null_floor: float,
) -> NDArray[np.float64]:
    """:meth:`GaussianLidar.measure` per cell (flat arrays): the numpy path's operations in its order.

    ``tan_incidence`` is :meth:`GaussianLidar.tan_incidence`; ``drop`` holds the dropout draws when
    ``p_null_floor > 0`` (else it is not read); NaN = null. ``np.nan_to_num`` is spelled out: NaN -> 0,
    +-inf -> +-``big``.
    """
    big = np.finfo(np.float64).max
    out = np.empty(r.shape[0])
    for i in range(r.shape[0]):
        x = r[i]
        if not math.isfinite(x):
            out[i] = np.nan
            continue
        s = sigma0 + k_range * (x * x) + k_incidence * x * tan_incidence[i]
        s = 0.0 if math.isnan(s) else (big if s == math.inf else (-big if s == -math.inf else s))
        y = x + noise[i] * s
        if p_null_floor > 0 and drop[i] < p_null_floor:
            y = np.nan
        out[i] = y if (y >= 0.0 or math.isnan(y)) else 0.0
    return out
