"""The hot path of :class:`~sensor_envs.lidar.lwlr.LidarLWLR`: one scan's readings from nominal ranges, compiled.

:func:`sample_scan` draws exactly what ``sample_from_params(params_from_features(r, alpha), rng)`` draws (the
same float64 operations and draws), in three numba passes when the ``fast`` extra is installed.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.inputs import InputError
from sensor_envs.jit import compiled
from sensor_envs.lidar.local_regression import (
    P_EPS,
    P_SPUR_EPS,
)

if TYPE_CHECKING:
    from sensor_envs.lidar.lwlr import LidarLWLR

__all__ = ["sample_scan", "scan_tables", "scan_constants", "nominal_ranges"]


def sample_scan(
    m: LidarLWLR, r: NDArray[np.float64], alpha: NDArray[np.float64], rng: np.random.Generator, null: float = 0.0
) -> NDArray[np.float64]:
    """:meth:`LidarLWLR.sample_scan <sensor_envs.lidar.lwlr.LidarLWLR.sample_scan>` (arguments and returns there)."""
    nodes, gather, readings = compiled(scan_nodes), compiled(scan_gather), compiled(scan_readings)
    if nodes is None or gather is None or readings is None or len(getattr(m, "extra_state_", ())) > 0:
        x = m.sample_from_params(m.params_from_features(r, alpha), rng)
        return x if null == 0 else np.where(x == 0, null, x)
    r = nominal_ranges(m, r)
    shape, k = r.shape, r.shape[-1]
    u = rng.random(shape)
    z = rng.standard_normal(shape)
    cells, grid, draw, log_scale = scan_constants(m)
    rows = np.ascontiguousarray(r.reshape(-1, k))
    node = np.empty(rows.shape, dtype=np.int64)
    wr, wa, rq = np.empty(rows.shape), np.empty(rows.shape), np.empty(rows.shape)
    alpha_rows = np.ascontiguousarray(np.asarray(alpha, dtype=np.float64).reshape(-1, k))
    nodes(*grid, rows, alpha_rows, node, wr, wa, rq)
    p_null, bias, scale, p_spur = (np.empty(rows.shape) for _ in range(4))
    gather(cells.ravel(), 4 * grid[1], node, wr, wa, p_null, bias, scale, p_spur)
    sigma = np.exp(scale, out=scale) if log_scale else scale  # numpy's exp, as params_from_features'
    u_rows, z_rows = np.ascontiguousarray(u.reshape(-1, k)), np.ascontiguousarray(z.reshape(-1, k))
    readings(p_null, bias, sigma, p_spur, rq, grid[4], u_rows, z_rows, *draw, float(null), rq)
    return rq.reshape(shape)


def scan_constants(
    m: LidarLWLR,
) -> tuple[
    NDArray[np.floating[Any]],
    tuple[int, int, float, float, float, float, float],
    tuple[float, bool, bool, float, float],
    bool,
]:
    """What :meth:`sample_scan`'s passes take besides the cells: ``(cells, grid, draw, log_scale)``.

    ``cells``: :func:`scan_tables` (the bias left out when shrunk fully to zero); ``grid``: :func:`scan_nodes`'
    leading arguments ``(nr, na, r0, r1, r_last, a0, a1)`` (grid sizes, then nodes [m, rad]); ``draw``:
    :func:`scan_readings`' ``(bias_weight, has_spur, spurious, spur_mu, spur_sigma)`` (``bias_weight = 1 -
    shrinkage``, 0 without a bias; spurious returns only in the extended variant); ``log_scale``: whether the
    scale slot holds ``log_sigma`` (then ``sigma = exp``).
    """
    shrink = float(getattr(m, "bias_shrinkage_", 0.0))
    cells, idx = scan_tables(m, with_bias=shrink != 1.0)
    rg, ag = m.range_grid_, m.alpha_grid_
    grid = (cells.shape[1], cells.shape[2], float(rg[0]), float(rg[1]), float(rg[-1]), float(ag[0]), float(ag[1]))
    extended, has_spur = m.variant == "extended", bool(idx[2] >= 0)
    draw = (
        1.0 - shrink if idx[0] >= 0 else 0.0,
        has_spur,
        extended and has_spur,
        float(m.spur_mu_) if extended else 0.0,
        float(m.spur_sigma_) if extended else 0.0,
    )
    return cells, grid, draw, bool(idx[3] == 1)


def nominal_ranges(m: LidarLWLR, r: ArrayLike) -> NDArray[np.float64]:
    """``r`` [m] as float64 ``(..., K)``, checked against the fitted model's ``K`` bearings."""
    m._check_fitted()
    r = np.asarray(r, dtype=np.float64)
    k = m.tables_.shape[1]
    if r.shape[-1] != k:
        raise InputError(f"nominal_range: last axis has {r.shape[-1]} bearings, the model has {k}")
    return r


def scan_tables(m: LidarLWLR, with_bias: bool = True) -> tuple[NDArray[np.floating[Any]], NDArray[np.int64]]:
    """What :func:`scan_gather` reads: the looked-up tables laid out ``(K, n_r, n_alpha, 4)``, and their slots.

    The 4 slots of a cell are ``p_null``, the bias, the scale (``log_sigma`` of the extended variant, ``sigma``
    of the seed's) and ``p_spur``; a parameter the model lacks (or the bias when ``with_bias`` is False: a
    bias shrunk fully to zero adds nothing) holds zeros and is marked absent in the index
    ``(bias slot, scale slot, p_spur slot, scale is log_sigma)`` by a slot of -1. The layout reads one cell's
    parameters together (one group of 4 per grid node) and holds no table the scan does not read; it is
    float32 when that is exact (tables are rounded to float32 at fit and in the file), so the lookup's
    float64 arithmetic gives the same bits from half the memory (a 64-robot step walks most of it, so its
    size sets the step's cache misses). Cached beside the array it was made from and rebuilt when ``tables_``
    is replaced (fit, load), so the hot path pays for neither.
    """
    cache = m.__dict__.setdefault("_scan_cache", {})
    hit = cache.get(with_bias)
    if hit is None or hit[0] is not m.tables_:
        names = list(m.param_names_)
        scale = "log_sigma" if "log_sigma" in names else "sigma"
        slots = ("p_null", "bias" if with_bias else "", scale, "p_spur")
        cells = np.zeros(m.tables_.shape[1:] + (len(slots),))
        for slot, name in enumerate(slots):
            if name in names:
                cells[..., slot] = m.tables_[names.index(name)]
        if np.array_equal(cells.astype(np.float32), cells):  # fitted/loaded tables are float32 values
            cells = cells.astype(np.float32)  # exact, and half the memory a lookup walks
        idx = np.array(
            [1 if slots[1] in names else -1, 2, 3 if "p_spur" in names else -1, int(scale == "log_sigma")],
            dtype=np.int64,
        )
        hit = (m.tables_, np.ascontiguousarray(cells), idx)
        cache[with_bias] = hit
    return hit[1], hit[2]


def scan_nodes(
    nr: int,
    na: int,
    r0: float,
    r1: float,
    r_last: float,
    a0: float,
    a1: float,
    r: NDArray[np.float64],
    alpha: NDArray[np.float64],
    node: NDArray[np.int64],
    wr: NDArray[np.float64],
    wa: NDArray[np.float64],
    rq: NDArray[np.float64],
) -> None:
    """Pass 1 of :meth:`LidarLWLR.sample_scan` over cells ``(P, K)``: where each cell's bilinear lookup reads.

    ``nr, na`` are the sizes of the range and incidence grids, ``r0, r1, r_last`` and ``a0, a1`` grid nodes
    [m, rad]; ``r, alpha`` the nominal ranges [m] (``inf``/NaN = no hit) and incidences [rad] (NaN = 0).
    Writes per cell the flat offset ``node`` of its lower node in :func:`scan_tables`' layout
    ``(K, nr, na, 4)``, the weights ``wr, wa`` of the upper range and incidence nodes, and the queried range
    ``rq`` [m] (NaN for no hit, which is looked up at ``r_last``), in :func:`_bilinear_numpy`'s operations.
    Arithmetic only, no table read: the loop vectorises.
    """
    n_p, n_k = r.shape
    hi_r, hi_a = nr - 1 - 1e-9, na - 1 - 1e-9
    inv_dr, inv_da = 1.0 / (r1 - r0), 1.0 / (a1 - a0)
    for p in range(n_p):
        for k in range(n_k):
            rk = r[p, k]
            hit = math.isfinite(rk)
            rk = rk if hit else r_last
            ak = alpha[p, k]
            ak = 0.0 if math.isnan(ak) else ak
            fr = min(max((rk - r0) * inv_dr, 0.0), hi_r)
            fa = min(max((ak - a0) * inv_da, 0.0), hi_a)
            i, j = int(fr), int(fa)
            wr[p, k] = fr - i
            wa[p, k] = fa - j
            rq[p, k] = rk if hit else math.nan
            node[p, k] = ((k * nr + i) * na + j) * 4


def scan_gather(
    flat: NDArray[np.floating[Any]],
    row: int,
    node: NDArray[np.int64],
    wr: NDArray[np.float64],
    wa: NDArray[np.float64],
    v0: NDArray[np.float64],
    v1: NDArray[np.float64],
    v2: NDArray[np.float64],
    v3: NDArray[np.float64],
) -> None:
    """Pass 2 of :meth:`LidarLWLR.sample_scan`: the bilinear values of the 4 table slots of every cell.

    ``flat`` is :func:`scan_tables`' array raveled (float32 or float64, read as float64), ``row`` the offset of the
    next range node (``4 na``), ``node, wr, wa`` :func:`scan_nodes`' output. Writes slots 0-3 (``p_null``, bias,
    scale, ``p_spur``) into ``v0..v3``, each :func:`~sensor_envs.lidar.local_regression._bilinear`'s expression. The
    loop does only the table reads and their weighting (two runs of 8 adjacent values per cell); a per-cell gather
    does not vectorise, so everything that can is left to the passes around it.
    """
    nd, wrf, waf = node.ravel(), wr.ravel(), wa.ravel()
    o0, o1, o2, o3 = v0.ravel(), v1.ravel(), v2.ravel(), v3.ravel()
    for q in range(nd.size):
        c = nd[q]
        d = c + row
        w_r, w_a = wrf[q], waf[q]
        u_r, u_a = 1 - w_r, 1 - w_a
        x = (np.float64(flat[c]) * u_a + np.float64(flat[c + 4]) * w_a) * u_r
        o0[q] = x + (np.float64(flat[d]) * u_a + np.float64(flat[d + 4]) * w_a) * w_r
        x = (np.float64(flat[c + 1]) * u_a + np.float64(flat[c + 5]) * w_a) * u_r
        o1[q] = x + (np.float64(flat[d + 1]) * u_a + np.float64(flat[d + 5]) * w_a) * w_r
        x = (np.float64(flat[c + 2]) * u_a + np.float64(flat[c + 6]) * w_a) * u_r
        o2[q] = x + (np.float64(flat[d + 2]) * u_a + np.float64(flat[d + 6]) * w_a) * w_r
        x = (np.float64(flat[c + 3]) * u_a + np.float64(flat[c + 7]) * w_a) * u_r
        o3[q] = x + (np.float64(flat[d + 3]) * u_a + np.float64(flat[d + 7]) * w_a) * w_r


def scan_readings(
    p_null: NDArray[np.float64],
    bias: NDArray[np.float64],
    sigma: NDArray[np.float64],
    p_spur: NDArray[np.float64],
    rq: NDArray[np.float64],
    r_last: float,
    u: NDArray[np.float64],
    z: NDArray[np.float64],
    bias_weight: float,
    has_spur: bool,
    spurious: bool,
    spur_mu: float,
    spur_sigma: float,
    null: float,
    out: NDArray[np.float64],
) -> None:
    """Pass 3 of :meth:`LidarLWLR.sample_scan`: readings [m] from the looked-up parameters and the draws ``u, z``.

    :meth:`LidarLWLR.params_from_features`' clipping and :meth:`LidarLWLR.sample_from_params`' selection,
    elementwise and branch-free (it vectorises; a branch on the null decision, which no predictor can guess,
    cost more than the work it skipped): a no-hit cell (``rq`` NaN) has ``p_null = 1 - P_EPS``; ``mu = r +
    bias_weight bias`` (``bias_weight`` 0 without a bias); ``null`` where ``u < p_null``, else
    ``spur_mu + spur_sigma z`` where ``u < p_null + p_spur`` (``spurious`` only), else ``max(mu + sigma z,
    1e-4)``. ``out`` may be ``rq``.
    """
    n0, b, s, n3, rr, uf, zf, o = (
        p_null.ravel(),
        bias.ravel(),
        sigma.ravel(),
        p_spur.ravel(),
        rq.ravel(),
        u.ravel(),
        z.ravel(),
        out.ravel(),
    )
    for q in range(o.size):
        r = rr[q]
        hit = r == r  # not NaN
        r = r if hit else r_last
        pn = n0[q] if hit else 1 - P_EPS
        if has_spur:
            pn = min(pn, 1 - P_EPS - P_SPUR_EPS)
        ps = min(max(n3[q], P_SPUR_EPS), 1 - P_EPS - pn) if spurious else 0.0
        x = max(r + bias_weight * b[q] + s[q] * zf[q], 1e-4)
        uq = uf[q]
        x = spur_mu + spur_sigma * zf[q] if uq < pn + ps else x
        o[q] = null if uq < pn else x
