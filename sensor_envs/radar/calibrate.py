"""Calibrate the reference radar rig to real single-frame data by simulation (``sensor-envs calibrate radar``).

The rig (:class:`sensor_envs.radar.rig.RadarRig`) is simulated at the real frames' reference boxes
(:meth:`RadarRig.snapshot`: one cycle of a running rig, tracker error and reflection fraction from
their stationary laws), and the same statistics are computed on the rig's output and on the real
data:

* ``det_range`` / ``det_azimuth``: detection rate per corner-range bin (:data:`DET_RANGE_EDGES`) and
  per signed corner-azimuth bin (:data:`DET_AZIMUTH_EDGES`; left > 0, so a lopsided sensor shows);
* ``det_occlusion``: detection rate per bin of the box's occluded fraction (geometric, from the
  frame's boxes: :func:`sensor_envs.geometry.occluded_fraction`; 0, (0, 0.5), [0.5, 1]);
* ``det_cells``: detection rate per (corner range x signed azimuth) cell (:data:`CELL_AZIMUTH_EDGES`;
  the joint the marginals hide);
* ``det_occlusion_range``: detection rate per (corner range x occluded-fraction) cell (a joint the
  ``det_occlusion`` marginal pools);
* ``offset``: the radial and OUTWARD cross-range components of ``z = measured - closest corner``
  [m] of the detected rows per corner-range bin (their distribution: spread and shape; outward =
  away from the boresight, i.e. mirrored on the right, so a reflection displaced along the face
  shows alike on both sides instead of cancelling when pooled); their quantiles
  (:data:`QUANTILES`) are kept for reports;
* ``clutter_count``: mean and standard deviation of the clutter count per frame;
* ``clutter_range`` / ``clutter_azimuth``: shares of clutter per range bin / azimuth bin.

**Discrepancy** (stated; the card reports every term before and after): ``D = sum of the terms``,

* detection terms: ``sum_b (n_b / N) (rate_sim_b - rate_real_b)^2`` (``n_b`` real rows in bin ``b``);
* ``offset``: ``sum_b (n_b / N) ED_b`` [m], ``ED_b`` the energy distance between the rig's and the
  real polar offsets (radial, outward cross-range) of the detected rows in range bin ``b``
  (``n_b``: real detected rows; a proper distance between distributions, so point masses and
  shape count);
* ``offset_signed``: the same with a SIGNED cross-range (counter-clockwise positive on both sides). The
  outward frame mirrors the right side, so it cannot see a rotation of every detection (a mounting yaw
  error: outward on one side, inward on the other); this term can (see :func:`fit_azimuth_bias`);
* ``clutter_count``: ``((mean_sim - mean_real) / mean_real)^2 + ((std_sim - std_real) / std_real)^2``;
* clutter density terms: ``sum_b (share_sim_b - share_real_b)^2``.

**Procedure** (reproducible: every random number comes from ``seed``; common random numbers: the
same draws :class:`~sensor_envs.radar.rig.SnapshotDraws` for every candidate parameter vector, so
the discrepancy is a deterministic function of the parameters):

1. detection tables and occlusion loss (with ``occlusion_by_range=True`` a loss per range knot,
   :data:`OCCLUSION_LOSS_KNOTS`, and the ``det_occlusion_range`` term joins the fit; else one loss, fitted
   on the other detection terms as before): ``scipy.optimize.least_squares`` on the detection terms'
   residuals (the rig's detection PROBABILITY at the simulated reflection points, i.e. the exact
   expectation of its detection rate given the draws), plus a small ridge on second differences
   of the tables' probabilities (smoothness where data are thin). By default the azimuth table is
   left-right SYMMETRIC (knots ``0, 15, ..., 90`` deg of ``|azimuth|``, factor 1 at 0 deg); with
   ``signed_azimuth=True`` it is SIGNED (:data:`DETECT_AZIMUTH_KNOTS` over ``[-90, 90]`` deg,
   ``detect_azimuth_signed``): left and right of the boresight fitted apart. The signed table is not
   the default: it generalises worse across held-out frames (measured: docs/concepts/rigs.md);
2. offset parameters (radial/cross-range spread per range knot, radial bias, outlier share and
   scale, closest-corner share, reflection spread and reflection centre along the face):
   ``scipy.optimize.minimize(method="Powell")`` on the ``offset`` term (derivative-free; under
   common random numbers the term is a deterministic, piecewise smooth function of the parameters);
3. step 1 again (the reflection points moved);
4. clutter: the count's mean and over-dispersion and the range/azimuth shares are set to the real
   data's (each is the exact minimiser of its term: the rig's expected statistic equals the parameter),
   then checked by simulation; the positions are drawn from the joint (range, azimuth) cell shares of
   the real clutter (:func:`fit_clutter`, finer cells :data:`CLUTTER_CELL_RANGE_EDGES` x
   :data:`CLUTTER_CELL_AZIMUTH_EDGES`), not from the two shares independently: real clutter is sparse
   in the lane just ahead and dense at the roadside at the same azimuth farther out.

With ``offset_law="mixture"`` (``calibrate radar --offset-law mixture``) steps 2-3 are replaced by
:func:`fit_offset_mixture`: the rig's offset law becomes a Gaussian mixture per corner-range bin in
the closest corner's polar frame (radial, outward cross-range). The rig's offset at a box is then
exactly a draw of that mixture, so its discrepancy to the real offsets is minimised in closed form
(maximum likelihood by EM, i.e. the Kullback-Leibler discrepancy), and the ``offset`` energy-distance
term is reported as the check. It is a few dozen numbers of statistics (weights, means and Cholesky
factors per bin), no real rows. The reflection-point law can only place the point on a face, at a
Gaussian-plus-tail spread, a shape real offsets need not have. With ``mixture_min_range``
(``--mixture-min-range M``) the mixture applies from that closest-corner range on and steps 2-3 run after
it is set, so the reflection-point law is fitted on the nearer boxes, which keep it.

**Mounting yaw error** (``azimuth_bias=True``, ``calibrate radar --azimuth-bias``): a radar mounted a
fraction of a degree off its reference frame reports every detection rotated about the sensor, a
cross-range error that grows with range and has the SAME sign on both sides of the boresight. The outward
offset frame above mirrors the right side, so the ``offset`` term cannot see it, and a law fitted there
absorbs it as extra spread. :func:`fit_azimuth_bias` finds it by a 1-D search on the ``offset_signed`` term
(signed cross-range), with the current laws; the real frames are then de-rotated by it
(:func:`rotate_frames`) and steps 1-4 fitted on them, so the laws describe the reflection alone; two rounds
(search, laws, search, laws).

The rig's time-series parameters (latency, tracker and reflection time constants) cannot be seen in
single frames and keep their generic values. All lengths in metres, angles in radians.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from sensor_envs.geometry import from_frame
from sensor_envs.inputs import InputError
from sensor_envs.radar.calibrate_clutter import (
    CLUTTER_CELL_AZIMUTH_EDGES,
    CLUTTER_CELL_RANGE_EDGES,
    calibrate_clutter,
    clutter_cell_shares,
    fit_clutter,
)
from sensor_envs.radar.calibrate_stats import (
    _AZ0,
    DET_AZIMUTH_EDGES,
    DET_RANGE_EDGES,
    DETECT_AZIMUTH_KNOTS,
    DETECT_RANGE_KNOTS,
    DETECTION_TERMS,
    OCCLUSION_LOSS_KNOTS,
    OFFSET_RANGE_KNOTS,
    QUANTILES,
    RealFrames,
    _bin,
    _bin_weights,
    _detection_stats,
    _offset_energy,
    _offset_samples,
    _offset_term,
    _signed_offset_samples,
    _Sim,
    _sim_setup,
    detection_discrepancy,
    discrepancy,
    frames_from_log,
    load_real,
    real_statistics,
    rig_statistics,
)
from sensor_envs.radar.log import RadarLog
from sensor_envs.radar.rig import RadarRig, RigConfig, SnapshotDraws
from sensor_envs.radar.scene_law import scene_card, with_scene_law
from sensor_envs.rng import fold_ids

__all__ = [
    "DET_RANGE_EDGES",
    "DET_AZIMUTH_EDGES",
    "QUANTILES",
    "RealFrames",
    "frames_from_log",
    "load_real",
    "rig_statistics",
    "real_statistics",
    "DETECTION_TERMS",
    "detection_discrepancy",
    "discrepancy",
    "calibrate_rig",
    "fit_offset_law",
    "fit_offset_mixture",
    "fit_clutter",
    "clutter_cell_shares",
    "calibrate_clutter",
    "CLUTTER_CELL_RANGE_EDGES",
    "CLUTTER_CELL_AZIMUTH_EDGES",
    "snapshot_log",
]


# ---------------------------------------------------------------------------------------- optimisation
def _logit(p: NDArray | float) -> NDArray[np.float64]:
    q = np.clip(np.asarray(p, dtype=np.float64), 1e-4, 1 - 1e-4)
    return np.log(q / (1 - q))


def _sigmoid(x: NDArray | float) -> NDArray[np.float64]:
    return 1.0 / (1.0 + np.exp(-np.asarray(x, dtype=np.float64)))


def _az_knots(signed: bool) -> tuple[tuple[float, ...], int]:
    """The azimuth knots [rad] of the fitted table and the index of its 0-deg knot (factor fixed at 1).

    ``signed``: :data:`DETECT_AZIMUTH_KNOTS` (left > 0); else their ``|azimuth|`` half (symmetric table).
    """
    return (DETECT_AZIMUTH_KNOTS, _AZ0) if signed else (DETECT_AZIMUTH_KNOTS[_AZ0:], 0)


def _az_logits(x: NDArray, signed: bool) -> NDArray[np.float64]:
    """The azimuth table's logits at every knot, the fixed 0-deg knot included (factor ~1)."""
    knots, i0 = _az_knots(signed)
    nr = len(DETECT_RANGE_KNOTS)
    free = x[nr : nr + len(knots) - 1]
    return np.concatenate([free[:i0], [_logit(0.999)], free[i0:]])


def _det_config(x: NDArray, base: RigConfig, signed: bool, by_range: bool = False) -> RigConfig:
    """The detection law of parameters ``x``.

    ``x`` = logits of the range table, of the azimuth table without its 0-deg knot (fixed at 1), and
    of the occlusion loss (``by_range``: of its table at :data:`OCCLUSION_LOSS_KNOTS`).
    """
    nr = len(DETECT_RANGE_KNOTS)
    knots, i0 = _az_knots(signed)
    table = _sigmoid(x[nr : nr + len(knots) - 1]).tolist()
    occ = _sigmoid(x[nr + len(knots) - 1 :])
    cfg = replace(
        base,
        detect_range_knots=DETECT_RANGE_KNOTS,
        detect_range_table=tuple(_sigmoid(x[:nr]).tolist()),
        detect_azimuth_knots=knots,
        detect_azimuth_table=(*table[:i0], 1.0, *table[i0:]),
        detect_azimuth_signed=signed,
    )
    if by_range:
        return replace(cfg, occlusion_loss_knots=OCCLUSION_LOSS_KNOTS, occlusion_loss_table=tuple(occ.tolist()))
    return replace(cfg, occlusion_loss=float(occ[0]), occlusion_loss_knots=None, occlusion_loss_table=None)


def _det_x0(base: RigConfig, signed: bool, by_range: bool = False) -> NDArray[np.float64]:
    rig = RadarRig(base)
    pr = rig.detection_probability(
        np.asarray(DETECT_RANGE_KNOTS), np.zeros(len(DETECT_RANGE_KNOTS)), np.zeros(len(DETECT_RANGE_KNOTS))
    )
    knots, i0 = _az_knots(signed)
    na = len(knots)
    pa = rig.detection_probability(np.full(na, 20.0), np.asarray(knots), np.zeros(na))
    pa = np.delete(np.clip(pa / max(pa[i0], 1e-6), 0.05, 0.95), i0)
    occ_at = np.asarray(OCCLUSION_LOSS_KNOTS if by_range else (20.0,))
    occ = np.clip(np.broadcast_to(rig.occlusion_loss(occ_at), occ_at.shape), 0.05, 0.95)
    return np.concatenate([_logit(np.clip(pr, 0.05, 0.95)), _logit(pa), _logit(occ)])


def _fit_detection(
    base: RigConfig,
    sim: _Sim,
    real: dict[str, NDArray],
    ridge: float,
    bar: Any,
    signed: bool = False,
    by_range: bool = False,
) -> RigConfig:
    """Stage 1/3: detection tables by least squares on the detection terms (expected rates).

    The ridge penalises second differences of the tables' PROBABILITIES (not logits: near 1 a logit
    ridge makes any dip prohibitively expensive and would pin the table to a straight logit line).
    ``by_range``: the occlusion loss is a table over range, fitted with the ``det_occlusion_range`` term
    too (and its second differences under the same ridge).
    """
    from scipy.optimize import least_squares

    keys = [(k, n) for k, n in DETECTION_TERMS if by_range or k != "det_occlusion_range"]
    weights = {k: np.sqrt(_bin_weights(real, n)) for k, n in keys}
    nr = len(DETECT_RANGE_KNOTS)
    n_occ = len(OCCLUSION_LOSS_KNOTS) if by_range else 1

    def residuals(x: NDArray) -> NDArray[np.float64]:
        bar.update(1)
        cfg = _det_config(x, base, signed, by_range)
        _, p = RadarRig(cfg).snapshot(sim.boxes, sim.occluded, sim.draws)
        st = _detection_stats(p, sim.bins)
        res = [weights[k] * np.nan_to_num(st[k] - real[k]) for k, _ in keys]
        res.append(np.sqrt(ridge) * np.diff(_sigmoid(x[:nr]), 2))
        res.append(np.sqrt(ridge) * np.diff(_sigmoid(_az_logits(x, signed)), 2))
        if n_occ > 2:
            res.append(np.sqrt(ridge) * np.diff(_sigmoid(x[-n_occ:]), 2))
        return np.concatenate(res)

    fit = least_squares(residuals, _det_x0(base, signed, by_range), max_nfev=300, x_scale=1.0)
    return _det_config(fit.x, base, signed, by_range)


def _off_config(x: NDArray, base: RigConfig) -> RigConfig:
    k = len(OFFSET_RANGE_KNOTS)
    return replace(
        base,
        offset_range_knots=OFFSET_RANGE_KNOTS,
        sigma_range_table=tuple(np.exp(x[:k]).tolist()),
        sigma_cross_table=tuple(np.exp(x[k : 2 * k]).tolist()),
        range_bias=float(np.clip(x[2 * k], -2.0, 2.0)),
        outlier_share=float(_sigmoid(x[2 * k + 1]) * 0.5),
        outlier_scale=float(1.0 + np.exp(x[2 * k + 2])),
        corner_share=float(_sigmoid(x[2 * k + 3])),
        reflection_spread=float(_sigmoid(x[2 * k + 4]) * 0.5),
        reflection_center=float(_sigmoid(x[2 * k + 5]) * 0.5),
    )


def _off_x0(base: RigConfig) -> NDArray[np.float64]:
    k = len(OFFSET_RANGE_KNOTS)
    rig = RadarRig(base)
    sr, sc = rig._noise_std(np.asarray(OFFSET_RANGE_KNOTS) + 1.0, np.zeros(k))
    return np.concatenate(
        [
            np.log(np.maximum(sr, 0.05)),
            np.log(np.maximum(sc, 0.05)),
            [base.range_bias],
            _logit(min(max(2 * base.outlier_share, 0.4), 0.95))[None],  # start with a tail: Powell finds it badly
            [np.log(max(base.outlier_scale - 1.0, 3.0))],
            _logit(min(max(base.corner_share, 0.1), 0.9))[None],
            _logit(min(max(2 * base.reflection_spread, 0.05), 0.95))[None],
            _logit(min(max(2 * base.reflection_center, 0.05), 0.95))[None],
        ]
    )


def _fit_offsets(
    base: RigConfig, sim: _Sim, real: dict[str, NDArray], max_evals: int, bar: Any, fit_center: bool = True
) -> RigConfig:
    """Stage 2: offset spread and shape by Powell's method on the ``offset`` term.

    With ``fit_center=False`` the reflection centre stays ``base``'s (the face-midpoint law of the
    rigs before it was a parameter, for comparisons).
    """
    from scipy.optimize import minimize

    w = real["n_offset"] / max(real["n_offset"].sum(), 1.0)
    x0 = _off_x0(base)
    n = x0.size if fit_center else x0.size - 1  # the centre is the last parameter

    def config(x: NDArray) -> RigConfig:
        cfg = _off_config(np.concatenate([x, x0[n:]]), base)
        return cfg if fit_center else replace(cfg, reflection_center=base.reflection_center)

    def objective(x: NDArray) -> float:
        bar.update(1)
        cfg = config(x)
        meas, _ = RadarRig(cfg).snapshot(sim.boxes, sim.occluded, sim.draws)
        z, b = _offset_samples(sim.corner, meas, sim.bins.range)
        return float(np.sum(w * np.nan_to_num(_offset_energy(z, b, real["offset_z"], real["offset_bin"]))))

    fit = minimize(objective, x0[:n], method="Powell", options={"maxfev": max_evals, "xtol": 1e-3, "ftol": 1e-6})
    return config(fit.x)


OFFSET_LAWS = ("reflection", "mixture")
"""Offset laws ``calibrate_rig`` can fit (``offset_law``)."""

MIXTURE_COMPONENTS = (1, 2, 3, 4, 5, 6)
"""Component counts the offset mixture's per-bin CV tries (``offset_law="mixture"``)."""


MIXTURE_FOLDS, MIXTURE_BLOCK = 5, 10
"""Folds and frames per block of the component count's CV (block ``b`` in fold ``b % 5``)."""

MIXTURE_TOLERANCE = 0.01
"""The fewest components whose held-out log-likelihood is within this many nats per row of the best."""


def _gmm(z: NDArray, k: int, seed: int) -> Any:
    """A ``k``-component full-covariance Gaussian mixture fitted to ``z`` ``(n, 2)`` [m] by EM."""
    from sklearn.mixture import GaussianMixture

    return GaussianMixture(k, covariance_type="full", reg_covar=1e-4, n_init=3, random_state=seed).fit(z)


def _choose_components(z: NDArray, fold: NDArray, seed: int, components: tuple[int, ...]) -> dict[int, float]:
    """Held-out log-likelihood per row of each component count (rows' CV folds ``fold``)."""
    out: dict[int, float] = {}
    for k in components:  # one iteration per candidate count
        ll, n = 0.0, 0
        for f in range(int(fold.max()) + 1):  # one iteration per held-out fold
            tr, te = fold != f, fold == f
            if te.sum() == 0 or tr.sum() < 5 * k:
                continue
            ll += float(_gmm(z[tr], k, seed).score_samples(z[te]).sum())
            n += int(te.sum())
        if n:
            out[k] = ll / n
    return out


def fit_offset_mixture(
    frames: RealFrames, base: RigConfig, seed: int = 0, components: tuple[int, ...] = MIXTURE_COMPONENTS
) -> tuple[RigConfig, dict[str, Any]]:
    """Stage 2 of ``offset_law="mixture"``: a Gaussian mixture of the real polar offsets per range bin.

    The rig's offset at a box is then exactly a draw of the bin's mixture in the closest corner's polar
    frame (radial, outward cross-range), so the discrepancy minimised is the Kullback-Leibler one:
    maximum likelihood (EM, ``sklearn.mixture.GaussianMixture``) of the real detected offsets of each
    corner-range bin of :data:`DET_RANGE_EDGES`; the component count (``components``, 1-6) by held-out log-likelihood
    over 5 folds of 10-frame blocks (each bin apart; the fewest components within
    :data:`MIXTURE_TOLERANCE` of the best, so a bin with few rows gets few components). Returns
    the config and a report (the chosen count and the CV scores per bin).
    """
    rb = _bin(np.hypot(frames.corner[:, 0], frames.corner[:, 1]), DET_RANGE_EDGES)
    rb = np.where(rb < 0, len(DET_RANGE_EDGES) - 2, rb)  # beyond the last edge: the last bin
    z, b = _offset_samples(frames.corner, frames.meas, rb)
    blocks = np.arange(frames.n_frames) // MIXTURE_BLOCK  # frame blocks dealt round-robin into the folds
    fold = fold_ids(blocks, MIXTURE_FOLDS)[frames.frame[np.isfinite(frames.meas[:, 0])]]
    fits, report = [], []
    for k in range(len(DET_RANGE_EDGES) - 1):  # one iteration per range bin
        sel = b == k
        if sel.sum() < 10:
            raise InputError(f"offsets: only {int(sel.sum())} detected rows in range bin {k}; a mixture needs 10")
        scores = _choose_components(z[sel], fold[sel], seed, components)
        top = max(scores.values())
        best = min(c for c, v in scores.items() if v >= top - MIXTURE_TOLERANCE)
        fits.append(_gmm(z[sel], best, seed))
        report.append({"rows": int(sel.sum()), "components": best, "cv_loglik": scores})
    n_comp = max(g.n_components for g in fits)
    w = np.zeros((len(fits), n_comp))
    mu = np.zeros((len(fits), n_comp, 2))
    sc = np.tile([0.1, 0.0, 0.1], (len(fits), n_comp, 1))  # padding components (weight 0)
    for k, g in enumerate(fits):  # one iteration per range bin
        m = g.n_components
        w[k, :m], mu[k, :m] = g.weights_, g.means_
        L = np.linalg.cholesky(g.covariances_)
        sc[k, :m] = np.stack([L[:, 0, 0], L[:, 1, 0], L[:, 1, 1]], axis=1)
    w /= w.sum(axis=1, keepdims=True)
    cfg = replace(
        base,
        offset_mixture_edges=DET_RANGE_EDGES,
        offset_mixture_weights=tuple(w.ravel().tolist()),
        offset_mixture_means=tuple(mu.ravel().tolist()),
        offset_mixture_scales=tuple(sc.ravel().tolist()),
    )
    return cfg, {"bins": report}


AZIMUTH_BIAS_GRID = np.deg2rad(np.arange(-1.0, 1.0001, 0.05))
"""Coarse candidates [rad] of :func:`fit_azimuth_bias` (+-1 deg in 0.05 deg steps; then 0.005 deg steps)."""


def rotate_frames(frames: RealFrames, angle: float) -> RealFrames:
    """``frames`` with every measured target position rotated about the sensor by ``angle`` [rad] (ccw).

    Calibration de-rotates the real data by the fitted mounting yaw error (``-azimuth_bias``) before it fits
    the offset laws, which then describe the reflection alone. Clutter is left as measured.
    """
    return replace(frames, meas=from_frame(frames.meas, (0.0, 0.0, angle)))


def fit_azimuth_bias(
    frames: RealFrames, base: RigConfig, sim: _Sim, grid: NDArray | None = None
) -> tuple[float, dict[str, Any]]:
    """The rig's mounting yaw error ``azimuth_bias`` [rad] by a 1-D search on the ``offset_signed`` term.

    ``base``'s laws simulated at the real boxes (common random numbers ``sim``) with each candidate rotation,
    and the signed-cross-range offset discrepancy to ``frames`` (as measured) computed: the coarse
    :data:`AZIMUTH_BIAS_GRID` (or ``grid``), then 0.005 deg steps around its best. Returns the best angle and a
    report (the coarse scores, for the card).
    """
    real = real_statistics(frames)

    def score(angle: float) -> float:
        meas, _ = RadarRig(replace(base, azimuth_bias=float(angle))).snapshot(sim.boxes, sim.occluded, sim.draws)
        z, b = _signed_offset_samples(sim.corner, meas, sim.bins.range)
        return _offset_term(z, b, real["offset_signed_z"], real)

    coarse = AZIMUTH_BIAS_GRID if grid is None else np.asarray(grid, dtype=np.float64)
    scores = np.array([score(a) for a in coarse])  # one simulation per candidate
    best = float(coarse[int(np.argmin(scores))])
    step = float(np.min(np.diff(coarse))) if coarse.size > 1 else np.deg2rad(0.05)
    fine = best + np.arange(-step, step * 1.0001, np.deg2rad(0.005))
    fine_scores = np.array([score(a) for a in fine])
    angle = float(fine[int(np.argmin(fine_scores))])
    report = {
        "azimuth_bias_deg": float(np.rad2deg(angle)),
        "offset_signed_at_best": float(fine_scores.min()),
        "offset_signed_at_zero": score(0.0),
        "coarse_deg": np.rad2deg(coarse).round(4).tolist(),
        "coarse_scores": scores.round(6).tolist(),
    }
    return angle, report


def _uses_reflection_law(offset_law: str, mixture_min_range: float) -> bool:
    """Whether the rig places some boxes' points by the reflection-point law.

    All boxes, or with the mixture those nearer than ``mixture_min_range``: then Powell fits that law and the
    detection terms are refitted.
    """
    return offset_law == "reflection" or mixture_min_range > 0


def fit_offset_law(
    frames: RealFrames,
    base: RigConfig,
    sim: _Sim,
    real: dict[str, NDArray],
    offset_law: str,
    seed: int,
    components: tuple[int, ...],
    mixture_min_range: float,
    max_evals: int,
    bar: Any,
) -> tuple[RigConfig, dict[str, Any] | None]:
    """Stages 2 (offsets) of :func:`calibrate_rig` for ``offset_law``; returns the config and the mixture report.

    ``"reflection"``: Powell on the offsets' energy distance. ``"mixture"``: the mixture per range bin
    (:func:`fit_offset_mixture`) with ``offset_mixture_min_range = mixture_min_range``; when that is > 0,
    Powell runs AFTER the mixture is set, so only the nearer boxes' offset terms move it and the
    reflection-point law is fitted where the rig uses it. The detection refit (stage 3) is the caller's.
    """
    mixture: dict[str, Any] | None = None
    cfg = base
    if offset_law == "mixture":
        cfg, mixture = fit_offset_mixture(frames, cfg, seed, components)
        cfg = replace(cfg, offset_mixture_min_range=float(mixture_min_range))
    if _uses_reflection_law(offset_law, mixture_min_range):
        cfg = _fit_offsets(cfg, sim, real, max_evals, bar)
    return cfg, mixture


def _offset_procedure(offset_law: str, mixture_min_range: float) -> str:
    """How the offset law was fitted, for the rig card's ``procedure``."""
    powell = "Powell on the offsets' energy distance"
    if offset_law != "mixture":
        return powell
    mixture = "offset mixture per range bin by EM, component count by held-out likelihood"
    if mixture_min_range > 0:
        return f"{powell} below {mixture_min_range:g} m corner range, beyond it {mixture}"
    return mixture


def calibrate_rig(
    frames: RealFrames,
    base: RigConfig | None = None,
    *,
    seed: int = 0,
    replicates: int = 4,
    max_evals: int = 1500,
    ridge: float = 0.002,
    signed_azimuth: bool = False,
    offset_law: str = "reflection",
    mixture_components: tuple[int, ...] = MIXTURE_COMPONENTS,
    mixture_min_range: float = 0.0,
    azimuth_bias: bool = False,
    occlusion_by_range: bool = False,
    scene: bool = False,
    progress: bool = False,
) -> tuple[RigConfig, dict[str, Any]]:
    """Fit the rig's parameters to ``frames`` (see the module docstring); returns the config and its card.

    Args:
        frames: the real data (:func:`load_real`).
        base: starting point and source of the parameters single frames cannot show (default: generic rig).
        seed: seed of the common random numbers and of the before/after check.
        replicates: simulations of every real frame per discrepancy evaluation.
        max_evals: function evaluations of the offset stage (Powell).
        ridge: weight of the smoothness penalty (second differences) on the detection tables' probabilities.
        signed_azimuth: ``False`` (default): an ``|azimuth|`` table (left-right symmetric); ``True``: a
            signed azimuth table (left and right apart; generalises worse across Astyx frames, see the
            module docstring).
        offset_law: ``"reflection"`` (default): the reflection-point law's parameters by Powell on the
            offsets' energy distance (stage 2 above); ``"mixture"``: a Gaussian mixture per range bin
            (:func:`fit_offset_mixture`; the detection stage is not repeated, the reflection points
            it reads do not move).
        mixture_components: component counts the mixture's CV tries (``offset_law="mixture"``).
        mixture_min_range: with ``offset_law="mixture"``: closest-corner range [m] from which the mixture
            applies (``offset_mixture_min_range``); when > 0 the reflection-point law is fitted too
            (stages 2-3, after the mixture is set, so that only the nearer boxes' offsets move its terms).
        azimuth_bias: also fit the radar's mounting yaw error (``RigConfig.azimuth_bias``), alternating
            twice: :func:`fit_azimuth_bias` with the current laws (first ``base``'s), then every stage
            above on the real frames de-rotated by it (:func:`rotate_frames`), so the laws describe the
            reflection alone; the rig then rotates its detections back. ``False``: the bias stays ``base``'s.
        occlusion_by_range: the occlusion loss as a table over range (:data:`OCCLUSION_LOSS_KNOTS`), fitted
            with the ``det_occlusion_range`` term too; ``False``: one loss for every range (as before).
        scene: also fit the scene the rig records to the real reference boxes
            (:func:`sensor_envs.radar.scene_law.fit_scene_law`; closed form). ``False``: ``base``'s scene.
        progress: show a tqdm bar over function evaluations.
    """
    if offset_law not in OFFSET_LAWS:
        raise InputError(f"offset_law: must be one of {OFFSET_LAWS}, got {offset_law!r}")
    if not (np.isfinite(mixture_min_range) and mixture_min_range >= 0):
        raise InputError(f"mixture_min_range: must be a finite range >= 0 m, got {mixture_min_range!r}")
    if mixture_min_range > 0 and offset_law != "mixture":
        raise InputError("mixture_min_range: only with offset_law 'mixture'")
    base = base or RigConfig()
    sim = _sim_setup(frames, replicates, np.random.default_rng([seed, 7]))
    rounds = 2 if azimuth_bias else 1
    bar = tqdm(total=rounds * (2 * 300 + max_evals), disable=not progress, desc="calibrate radar", unit="eval")
    cfg, bias, bias_reports = base, base.azimuth_bias, []
    try:
        for _ in range(rounds):  # one iteration per round of (mounting yaw error, laws)
            if azimuth_bias:
                bias, rep = fit_azimuth_bias(frames, cfg, sim)
                bias_reports.append(rep)
            cfg, mixture = _fit_laws(
                rotate_frames(frames, -bias) if bias else frames,
                replace(cfg, azimuth_bias=0.0),
                sim,
                seed=seed,
                max_evals=max_evals,
                ridge=ridge,
                signed_azimuth=signed_azimuth,
                offset_law=offset_law,
                mixture_components=mixture_components,
                mixture_min_range=mixture_min_range,
                occlusion_by_range=occlusion_by_range,
                bar=bar,
            )
            cfg = replace(cfg, azimuth_bias=bias)
    finally:
        bar.close()
    real = real_statistics(frames)
    check = {"seed": seed + 1, "replicates": 8}
    before = discrepancy(rig_statistics(base, frames, 8, seed + 1), real)
    after = discrepancy(rig_statistics(cfg, frames, 8, seed + 1), real)
    card = {
        "calibrated_against": {
            "data": frames.source,
            "frames": frames.n_frames,
            "target_rows": int(frames.boxes.shape[0]),
            "detected_share": float(np.isfinite(frames.meas[:, 0]).mean()),
            "clutter_per_frame": float(frames.clutter_counts.mean()),
        },
        "procedure": "sensor_envs.radar.calibrate (simulation at the real boxes, common random numbers; "
        f"least_squares on detection terms ({'signed azimuth' if signed_azimuth else 'symmetric |azimuth|'} table"
        f"{', occlusion loss per range knot' if occlusion_by_range else ''}), "
        f"{_offset_procedure(offset_law, mixture_min_range)}, closed-form clutter"
        f"{'; mounting yaw error by 1-D search on the signed offsets, 2 rounds' if azimuth_bias else ''})",
        "offset_law": offset_law,
        "seed": seed,
        "replicates": replicates,
        "ridge": ridge,
        "signed_azimuth": signed_azimuth,
        "occlusion_by_range": occlusion_by_range,
        "discrepancy_check": check,
        "discrepancy_before": before,
        "discrepancy_after": after,
        "not_calibrated": ["cycle_time", "latency", "tracker_tau", "reflection_tau"],
    }
    if mixture is not None:
        card["offset_mixture"] = mixture
    if bias_reports:
        card["azimuth_bias"] = {"deg": float(np.rad2deg(bias)), "rounds": bias_reports}
    if scene:
        cfg, card["scene"] = calibrate_scene(frames, cfg, seed=seed)
    return cfg, card


def calibrate_scene(frames: RealFrames, base: RigConfig, *, seed: int = 0) -> tuple[RigConfig, dict[str, Any]]:
    """``base`` with its scene law fitted to ``frames``' reference boxes; returns it and the card's scene section.

    The sensor's laws are not touched (``calibrate radar --scene-only``): the scene decides which boxes a
    rig log holds, not how the radar sees a box.
    """
    cfg = with_scene_law(base, frames.boxes)
    return cfg, {"data": frames.source, **scene_card(cfg, frames.boxes, seed)}


def _fit_laws(
    frames: RealFrames,
    base: RigConfig,
    sim: _Sim,
    *,
    seed: int,
    max_evals: int,
    ridge: float,
    signed_azimuth: bool,
    offset_law: str,
    mixture_components: tuple[int, ...],
    mixture_min_range: float,
    bar: Any,
    occlusion_by_range: bool = False,
) -> tuple[RigConfig, dict[str, Any] | None]:
    """Stages 1-4 of :func:`calibrate_rig` on ``frames``: detection, offset law, detection again, clutter."""
    real = real_statistics(frames)
    cfg = _fit_detection(replace(base, max_range=150.0), sim, real, ridge, bar, signed_azimuth, occlusion_by_range)
    cfg, mixture = fit_offset_law(
        frames, cfg, sim, real, offset_law, seed, mixture_components, mixture_min_range, max_evals, bar
    )
    if _uses_reflection_law(offset_law, mixture_min_range):  # the reflection points moved
        cfg = _fit_detection(cfg, sim, real, ridge, bar, signed_azimuth, occlusion_by_range)
    return fit_clutter(cfg, frames), mixture


def snapshot_log(config: RigConfig, frames: RealFrames, rng: np.random.Generator) -> RadarLog:
    """A single-frame log of the rig at ``frames``' boxes: target rows plus clutter (one sequence, frame ids)."""
    from sensor_envs.radar.log import REQUIRED_COLUMNS

    rig = RadarRig(config)
    meas, _ = rig.snapshot(frames.boxes, frames.occluded, SnapshotDraws.draw(frames.boxes.shape[0], rng))
    n = frames.boxes.shape[0]
    tgt = np.concatenate(
        [np.zeros((n, 1)), frames.frame[:, None], frames.frame[:, None], np.arange(n)[:, None], frames.boxes, meas],
        axis=1,
    )
    rows = [tgt]
    for f in range(frames.n_frames):  # one iteration per frame (clutter only)
        r, az = rig.sample_clutter_polar(rng)
        c = np.full((r.size, len(REQUIRED_COLUMNS)), np.nan)
        c[:, :4] = [0, f, f, -1]
        c[:, 9], c[:, 10] = r * np.cos(az), r * np.sin(az)
        rows.append(c)
    data = np.concatenate(rows)
    return RadarLog({k: data[:, j] for j, k in enumerate(REQUIRED_COLUMNS)}, source="rig snapshot")
