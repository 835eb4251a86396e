"""Fast, accurate arccos and tangent on the ranges the sensors need (fdlibm's polynomials).

glibc's ``acos`` and ``tan`` are correctly rounded and slow (12-14 ns a value here): the incidence's arccos
was the largest part of a raycast of a few segments, and the tangent almost all of the Gaussian lidar's
noise pass. fdlibm's polynomial kernels (Sun Microsystems, freely redistributable; the code behind most
libm's) are within about 1 ulp and ~6x faster. Each function has a compiled loop (numba, when installed)
and a numpy path doing the same float64 operations in the same order, so both return the same bits.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.jit import compiled

__all__ = ["acos_unit", "tan_half_pi"]

# asin(s) = s + s R(s^2), R = P / Q (e_acos.c; highest power first)
_ACOS_P = (
    3.47933107596021167570e-05,
    7.91534994289814532176e-04,
    -4.00555345006794114027e-02,
    2.01212532134862925881e-01,
    -3.25565818622400915405e-01,
    1.66666666666666657415e-01,
)
_ACOS_Q = (
    7.70381505559019352791e-02,
    -6.88283971605453293030e-01,
    2.02094576023350569471e00,
    -2.40339491173441421878e00,
)
_PIO2_HI, _PIO2_LO = 1.57079632679489655800e00, 6.12323399573676603587e-17
_SPLIT = 134217729.0  # 2**27 + 1: Veltkamp's split of a double into a 26-bit head and its tail
# tan(x) = x + T0 x^3 + x^5 (T1 + T2 x^2 + ...) on |x| <= 0.6744 (k_tan.c)
_TAN_T = (
    3.33333333333334091986e-01,
    1.33333333333201242699e-01,
    5.39682539762260521377e-02,
    2.18694882948595424599e-02,
    8.86323982359930005737e-03,
    3.59207910759131235356e-03,
    1.45620945432529025516e-03,
    5.88041240820264096874e-04,
    2.46463134818469906812e-04,
    7.81794442939557092300e-05,
    7.14072491382608190305e-05,
    -1.85586374855275456654e-05,
    2.59073051863633712884e-05,
)
_TAN_DIRECT = 0.6744  # tan's polynomial holds below; near pi/4 tan(pi/4 + d) = (1 + tan d) / (1 - tan d)
_PIO4_HI, _PIO4_LO = 7.85398163397448278999e-01, 3.06161699786838301793e-17
_PIO2_1, _PIO2_1T = 1.57079632673412561417e00, 6.07710050650619224932e-11  # pi/2 in two parts (e_rem_pio2.c)


def _elementwise(
    loops: Callable[[NDArray[np.float64], NDArray[np.float64]], None], x: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """``loops(x, out)`` compiled over ``x`` flattened, shaped like ``x`` (0-d too); None without numba."""
    kernel = compiled(loops)
    if kernel is None:
        return None
    out = np.empty(x.shape)
    kernel(np.ascontiguousarray(x).reshape(-1), out.reshape(-1))
    return out


# ---------------------------------------------------------------------------------------------- arccos on [0, 1]
def acos_unit(x: ArrayLike) -> NDArray[np.float64]:
    """``arccos(x)`` [rad] of ``x`` in ``[0, 1]`` (NaN stays NaN) within 0.8 ulp; other values are not supported."""
    x = np.asarray(x, dtype=np.float64)
    out = _elementwise(_acos_unit_loops, x)
    if out is not None:
        return out
    big = x > 0.5
    z = np.where(big, (1.0 - x) * 0.5, x * x)
    r = _asin_ratio(z)
    s = np.sqrt(z)
    h = _SPLIT * s
    head = h - (h - s)  # s to 26 bits: head * head is exact
    with np.errstate(invalid="ignore", divide="ignore"):  # x = 1: 0 / 0 in the branch not taken
        big_value = 2.0 * (head + (r * s + (z - head * head) / (s + head)))
    return np.where(x >= 1.0, 0.0, np.where(big, big_value, _PIO2_HI - (x - (_PIO2_LO - x * r))))


def _asin_ratio(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ratio ``R(z) = P(z) / Q(z)`` (Horner, highest power first) of ``asin(s) = s + s R(s^2)``."""
    p = np.full_like(z, _ACOS_P[0])
    for c in _ACOS_P[1:]:
        p = p * z + c
    p = p * z
    q = np.full_like(z, _ACOS_Q[0])
    for c in _ACOS_Q[1:]:
        q = q * z + c
    q = q * z + 1.0
    return p / q


def _acos_unit_loops(x: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """:func:`acos_unit` in a loop: ``out[i] = arccos(x[i])``, the numpy path's arithmetic in its order.

    Both branches are computed and one selected (no branch: the loop vectorises).
    """
    for i in range(x.shape[0]):
        xi = x[i]
        big = xi > 0.5
        z = (1.0 - xi) * 0.5 if big else xi * xi
        p = _ACOS_P[0]
        for c in _ACOS_P[1:]:
            p = p * z + c
        p = p * z
        q = _ACOS_Q[0]
        for c in _ACOS_Q[1:]:
            q = q * z + c
        q = q * z + 1.0
        r = p / q
        s = math.sqrt(z)
        h = _SPLIT * s
        head = h - (h - s)
        big_value = 2.0 * (head + (r * s + (z - head * head) / (s + head)))
        small_value = _PIO2_HI - (xi - (_PIO2_LO - xi * r))
        out[i] = 0.0 if xi >= 1.0 else (big_value if big else small_value)


# ---------------------------------------------------------------------------------------------- tan on [0, pi/2)
def tan_half_pi(x: ArrayLike) -> NDArray[np.float64]:
    """``tan(x)`` of angles ``x`` [rad] in ``[0, pi/2)`` within 3 ulp (NaN stays NaN; up to pi/2 - 1e-7).

    Other values take libm's ``tan`` (``math.tan``, element by element, in both paths: numpy's ``np.tan`` has its
    own SIMD code on AVX-512 machines, which differs from libm's by an ulp; ``inf`` gives NaN).
    Three regimes: below 0.6744 fdlibm's polynomial; up to ``pi/2 - 0.6744`` the polynomial of
    ``d = x - pi/4`` and ``(1 + tan d) / (1 - tan d)``; above, ``1 / tan(pi/2 - x)`` with ``pi/2`` in two parts.
    """
    x = np.asarray(x, dtype=np.float64)
    out = _elementwise(_tan_half_pi_loops, x)
    if out is not None:
        return out
    mid = (x >= _TAN_DIRECT) & (x <= _PIO2_1 - _TAN_DIRECT)
    high = x > _PIO2_1 - _TAN_DIRECT
    y = np.where(mid, (x - _PIO4_HI) - _PIO4_LO, np.where(high, (_PIO2_1 - x) + _PIO2_1T, x))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # values outside [0, pi/2) are replaced
        t = _tan_poly(y)
        fast = np.where(mid, (1.0 + t) / (1.0 - t), np.where(high, 1.0 / t, t))
    outside = ~((x >= 0.0) & (x < _PIO2_HI)) & ~np.isnan(x)
    if outside.any():  # libm's tan, as the compiled loop's: numpy's own np.tan differs by an ulp on AVX-512 machines
        fast[outside] = [math.tan(v) if math.isfinite(v) else math.nan for v in x[outside].tolist()]
    return fast


def _tan_poly(y: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ``tan(y)`` polynomial for ``|y| <= 0.6744`` (fdlibm's ``__kernel_tan`` with no low part)."""
    t = _TAN_T
    z = y * y
    w = z * z
    r = t[1] + w * (t[3] + w * (t[5] + w * (t[7] + w * (t[9] + w * t[11]))))
    v = z * (t[2] + w * (t[4] + w * (t[6] + w * (t[8] + w * (t[10] + w * t[12])))))
    s = z * y
    return y + (z * (s * (r + v)) + t[0] * s)


def _tan_half_pi_loops(x: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """:func:`tan_half_pi` in loops: ``out[i] = tan(x[i])``, the numpy path's arithmetic in its order.

    The first loop computes every regime and selects one (no branch: it vectorises; with branches, or one
    value at a time, it is no faster than libm); the second puts libm's ``tan`` where ``x`` is outside
    ``[0, pi/2)``.
    """
    t = _TAN_T
    for i in range(x.shape[0]):
        xi = x[i]
        mid = (xi >= _TAN_DIRECT) & (xi <= _PIO2_1 - _TAN_DIRECT)
        high = xi > _PIO2_1 - _TAN_DIRECT
        y = (xi - _PIO4_HI) - _PIO4_LO if mid else ((_PIO2_1 - xi) + _PIO2_1T if high else xi)
        z = y * y
        w = z * z
        r = t[1] + w * (t[3] + w * (t[5] + w * (t[7] + w * (t[9] + w * t[11]))))
        v = z * (t[2] + w * (t[4] + w * (t[6] + w * (t[8] + w * (t[10] + w * t[12])))))
        s = z * y
        tn = y + (z * (s * (r + v)) + t[0] * s)
        near = (1.0 + tn) / (1.0 - tn)
        far = 1.0 / tn
        out[i] = near if mid else (far if high else tn)
    for i in range(x.shape[0]):
        xi = x[i]
        if not (xi >= 0.0 and xi < _PIO2_HI) and not math.isnan(xi):
            out[i] = math.tan(xi)
