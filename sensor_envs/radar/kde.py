"""The KDE radar model of Hirsenkorn et al. (2016): two-stage sampling from recorded tuples.

Tuples (from :func:`sensor_envs.radar.log.target_tuples`): state ``x = (c_x, c_y, z_{t-1,x}, z_{t-1,y})``
(closest corner of the target and its previous output, sensor frame, metres) and output
``z = measured position - closest corner`` [m], or a miss (object loss).

Density (the seed's Eq. 10), with a relevance kernel ``K_rel`` on the state and a contribution
kernel ``K_con`` on the output::

    p(z | x, detected) = sum_{i detected} w_i(x) N(z; z_i, diag(h(x)^2)) / sum_{i detected} w_i(x)
    P(miss | x) = (sum_{i missed} w_i(x) + a * m) / (sum_i w_i(x) + a)
    w_i(x) = exp(-|S^-1 (x - x_i)|^2 / 2)  if |S^-1 (x - x_i)| <= radius, else 0

with ``a = miss_prior`` (``a = 0`` is exactly the seed's estimate; the default ``a = 1``, one
kernel-peak weight, keeps both outcomes possible everywhere so held-out likelihoods stay finite) and
``m`` the miss rate of the tuples the query is matched against (``prior_rate="tree"``: those with a
previous output, or the start tuples) or the log's overall rate (``"global"``, format-1 models).

**Output frame** (``output_frame``, format 6): the paper's kernels act on sensor-frame offsets
(``"cartesian"``). With ``"polar"`` the model stores ``z`` and ``z_{t-1}`` in the polar frame of the
CURRENT cycle's corner, in training and in queries alike (radial, OUTWARD cross-range: mirrored right of
the boresight, :func:`sensor_envs.geometry.polar_frame`)
and the contribution bandwidths are radial and cross-range ones. A corner kernel wide enough to pool
targets left and right of the boresight then keeps an offset toward the outer end of the face, which
in the sensor frame points opposite ways on the two sides and averages out. Callers pass and receive
sensor-frame offsets either way; the change of frame is orthonormal, so densities are unchanged.

**Mounting yaw error** (``azimuth_bias``, format 7): a radar mounted with a yaw error ``b`` reports every
target rotated about the sensor by ``b``, a cross-range error growing with range and of the same sign on
both sides of the boresight. The outward frame mirrors it (the two sides cancel when pooled) and the
sensor frame cancels the outward offset instead. With ``azimuth_bias`` set (a number [rad], or ``"fit"``:
estimated from the training log by :func:`sensor_envs.radar.alignment.estimate_azimuth_bias`), the model
undoes the rotation before storing ``z`` and ``z_{t-1}`` (``R(-b) (corner + z) - corner``, then the output
frame) and applies it to what it samples; ``log_prob`` scores the de-rotated offset (a rotation: densities
unchanged). ``z_{t-1}`` is turned about the CURRENT corner, in training and in queries alike.

**Relevance bandwidth**: ``relevance="paper"`` uses ``rel_variance`` as given; ``relevance="cv"``
chooses the corner variance from ``relevance_candidates`` by cross-validation on the training log
(:mod:`sensor_envs.radar.relevance`); ``relevance="cv_axes"`` chooses the two corner variances
separately (x then y; coordinate-wise). With polar corner features (``state_transform="polar"``:
range, azimuth) both CV modes choose the range variance, then the azimuth variance.

**Reading of "covariance diag(3, 3, 0.03, 0.03) in metres":** the numbers are variances [m^2] of
the Gaussian relevance kernel, so ``S = diag(sqrt 3, sqrt 3, sqrt 0.03, sqrt 0.03)`` =
``(1.73, 1.73, 0.17, 0.17)`` m standard deviations (``rel_variance``). States are scaled by ``S^-1``
and a Euclidean ball of ``radius`` (default 3, i.e. 3 sigma) is the fixed-radius neighbour search
(scipy ``cKDTree``); the kernel is truncated there, and sampling and ``log_prob`` use the same
truncated weights, so they agree exactly.

**Contribution bandwidths** ``h(x) = (h_x, h_y)`` come from leave-one-group-out (default: one
track) cross-validation of the conditional density on a regular grid of corner positions, and are
bilinearly interpolated (in log) at run time; see :func:`cv_bandwidth_table`.

**Missing previous output** (new target, or missed last cycle): the "start" model - separate trees
over the 2-D corner state of the tuples whose own previous output is missing, with the corner part
of ``K_rel``. Format 4 keeps two of them apart (``new_track_``, one flag per tuple): the **new-track**
tree (tuples whose target has no previous row in the log: first seen) and the **after-miss** tree
(the previous row exists but was a miss: a lost track). A query picks its tree by the caller's
``new_track`` flag (``True`` = first seen, ``False`` = missed last cycle); without a flag (``None``,
and always for format-3 files, which lack the per-tuple flags) it uses the combined start tree of
all such tuples, as before. An empty new-track or after-miss tree falls back to the combined one.
Without ``z_{t-1}`` (``use_prev=False``, e.g. Astyx, which is no time series) every query uses a
2-D tree over all tuples and the flag is ignored.

**Two-stage sampling** (``sampler="ball"``, the reference): ball query, pick one neighbour with
probability ``w_i / sum w``, a missed tuple yields a miss (implemented as: draw the outcome with
``P(miss | x)``, then pick a tuple of that outcome with probability proportional to ``w_i``, which
is the same for ``a = 0``), else draw
``z ~ N(z_i, diag(h(x)^2))``. The index of the picked tuple is returned (traceability). A query
whose ball is empty uses the ``fallback_k`` nearest tuples of the same tree (keeping the memory of
``z_{t-1}`` in sparse regions). With ``k_max`` set, the search keeps only the ``k_max`` nearest
tuples in the ball (constant cost in the number of tuples, but it truncates kernel mass: see the
benchmark). ``sampler="bucket"`` draws from the same distribution by rejection sampling over grid
buckets (:mod:`sensor_envs.radar.buckets`, :meth:`KDERadarModel._draw_bucket`), at a cost that
follows the number of candidate buckets instead of neighbours; ``"auto"`` picks by model size.

**Clutter**: the number of clutter detections per cycle is resampled from the log's per-cycle
counts; positions are clutter rows of the log plus Gaussian jitter ``clutter_jitter`` [m]. At most
:data:`MAX_CLUTTER_POSITIONS` positions are stored (a uniform subsample of the log's clutter rows,
drawn from ``random_state``): clutter is resampled i.i.d., so the subsample keeps its spatial law
while a long, cluttered log (e.g. the calibrated rig at 15 Hz, ~750,000 rows) stays a small file.

**Extra state** (``extra_state``, format 3): names of numeric log columns (e.g. ``rel_vx``,
``aspect``, ``occlusion``; :mod:`sensor_envs.radar.features`) appended to the state as further
relevance dimensions, in both the main and the start tree. Their relevance variances are
``extra_variance`` or, when that is ``None``, chosen by the same held-out CV as the corner variance
(:func:`sensor_envs.radar.relevance.select_extra_variances`) from ``(f * std)^2`` for ``f`` in
``extra_candidates`` (``std`` of the column in the training log). Missing values (NaN) are replaced
by the training median. Queries must then pass ``extra=(n, len(extra_state))``; the sampler is the
ball sampler (the bucket grid is kept for the 2-D/4-D states).

**Tails** (``tail_weight`` ``w``, ``tail_scale`` ``c``, format 8): a defensive mixture of the contribution
kernels, ``p(z | x, detected) = (1 - w) KDE_h(z | x) + w KDE_{c h}(z | x)``: the same relevance weights and
tuples, a share ``w`` of the kernel mass ``c`` times wider. A detection far from every recorded tuple then
costs ``-log w`` plus a wide kernel's log density instead of the narrow kernel's quadratic penalty. ``sample``
draws the same mixture (after the tuple is picked and the Gaussian offset drawn, a detection's offset is
scaled by ``c`` with probability ``w``); ``log_prob`` and ``bin_probabilities`` score it. ``w = 0`` (the
default, and every file before format 8) is the paper's model and draws exactly what it drew before. The
pair is chosen on real held-out rows by :mod:`sensor_envs.radar.tune` (``sensor-envs tune radar``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from itertools import chain
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.special import ndtr

from sensor_envs.geometry import from_polar_frame, to_polar_frame
from sensor_envs.inputs import InputError
from sensor_envs.modelio import (
    RANDOM_STATE,
    Constraint,
    InstanceOf,
    Interval,
    ModelFileError,
    Numbers,
    Options,
    check_finite,
    check_increasing,
    check_positive,
    check_range,
    check_shape,
    optional_positive,
    validate_params,
)
from sensor_envs.radar.alignment import MAX_AZIMUTH_BIAS, derotate_offsets, estimate_azimuth_bias, rotate_offsets
from sensor_envs.radar.buckets import build_buckets, sample_proportional
from sensor_envs.radar.features import state_matrix, with_state_columns
from sensor_envs.radar.log import (
    RadarLog,
    TargetTuples,
    check_states,
    clutter_counts,
    fit_cycle_time,
    target_tuples,
)
from sensor_envs.radar.relevance import (
    select_corner_variance,
    select_corner_variances,
    select_extra_variances,
    select_prev_variance,
)
from sensor_envs.sensor_model import Arrays, Header, SensorModel, set_param_defaults

__all__ = ["KDERadarModel", "corner_features", "cv_bandwidth_table"]

KIND = "radar_kde"
FORMAT_VERSION = 8
"""Model file format: 1 = up to the ball sampler; 2 adds ``sampler``/``bucket_cell``, the relevance
selection (``relevance*`` params, the fitted ``rel_variance_``) and ``start_split``; 3 adds the extra
state (``extra_*`` params, the ``extra`` array, ``state_variables`` in the header); 4 adds the
per-tuple ``new_track`` flags (uint8 0/1; new-track vs after-miss start trees); 5 adds the
``state_transform`` parameter (cartesian or polar corner features of the relevance kernel) and
``relevance_candidates_azimuth``; 6 adds ``output_frame`` (outputs and previous outputs stored in
the sensor frame or in the corner's polar frame); 7 adds ``azimuth_bias`` (the mounting yaw error undone
before the kernels, and its fitted value ``azimuth_bias_fitted``) and ``start_bandwidth_scale``; 8 adds the
defensive tail mixture ``tail_weight``/``tail_scale``. Older files load with the defaults of the new parameters
(no extra state; one combined start tree; cartesian corner features; sensor-frame outputs; no yaw error; one
bandwidth factor; no tail component), so they behave exactly as before."""
STATE_TRANSFORMS = ("cartesian", "polar")
"""Corner features of the relevance kernel: ``(c_x, c_y)`` [m] or ``(range [m], azimuth [rad])``."""
OUTPUT_FRAMES = ("cartesian", "polar")
"""Frame the model stores outputs ``z`` and ``z_{t-1}`` in: the sensor frame, or the corner's polar frame
(radial, OUTWARD cross-range; :func:`sensor_envs.geometry.polar_frame`). Callers always pass and get
sensor-frame offsets."""
AZIMUTH_CANDIDATES = (0.0025, 0.01, 0.04, 0.16)
"""Default azimuth variances [rad^2] the CV tries with polar corner features (``relevance_candidates_azimuth``)."""
LOG_PROB_CHUNK = 1024
"""Rows per chunk of :meth:`KDERadarModel.log_prob` (wide kernels on long logs hold thousands of
tuples per query: all rows at once ran a 1/15 s rig log's CV out of 24 GB of memory)."""
CV_RELEVANCE = ("cv", "cv_axes", "cv_state")
"""Relevance modes whose state variances are chosen by CV on the training log (``"paper"``: given)."""
PREV_CANDIDATES = (0.03, 0.06, 0.12, 0.24, 0.48, 0.96)
"""Default ``z_{t-1}`` variances [m^2] the CV of ``relevance="cv_state"`` tries (``relevance_candidates_prev``;
0.03 is the seed's)."""
GROUP_MAIN, GROUP_START, GROUP_NEW, GROUP_LOST = 0, 1, 2, 3
"""Tree of a query: with ``z_{t-1}``; start (flag unknown); new track; after a miss."""
AUTO_BUCKET_MIN_NEIGHBOURS = 100
"""``sampler="auto"`` uses the bucket sampler when the median number of tuples in the ball of a stored
state is at least this (the ball sampler's cost follows it; benchmarks/bench_radar.py, 10-target
cycles: 25 neighbours, ball 0.28 ms vs bucket 0.42 ms; 250 neighbours, 0.91 vs 0.45 ms)."""
MAX_POSITION = 1e3
MAX_CLUTTER_POSITIONS = 200_000
"""Most clutter positions a fitted model stores (a uniform subsample beyond that)."""
"""Largest sensor-frame coordinate, output offset, bandwidth or relevance sigma [m] a model file may hold."""
MAX_TAIL_WEIGHT = 0.5
"""Largest share of the detection density the tail component may hold."""
MAX_TAIL_SCALE = 100.0
"""Largest factor of the tail component's bandwidths over the main kernels'."""
_LOG_2PI = np.log(2.0 * np.pi)
_POSITIVE = Interval(0, None, open_low=True)


@dataclass(frozen=True)
class _Tree:
    """One search tree of stored tuples.

    The scaled-state tree, the global tuple index of each of its points, its bucket grid (``None``
    with extra state or when too large) and its prior miss rate.
    """

    tree: cKDTree
    idx: NDArray[np.int64]
    buckets: Any
    rate: float


def _neighbour_lists(
    tree: cKDTree, q: NDArray, radius: float, k_max: int | None
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """Neighbours of every query within ``radius`` (all, or the ``k_max`` nearest).

    Returns flat ``(index, squared distance, query id)`` arrays, sorted by query id.
    """
    if k_max is not None:
        k = min(k_max, tree.n)
        d, i = tree.query(q, k=k, distance_upper_bound=radius)
        d, i = d.reshape(len(q), k), i.reshape(len(q), k)
        ok = np.isfinite(d)
        qid = np.broadcast_to(np.arange(len(q))[:, None], ok.shape)[ok]
        return i[ok].astype(np.int64), d[ok] ** 2, qid.astype(np.int64)
    lists = tree.query_ball_point(q, radius, return_sorted=False)
    lengths = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
    idx = np.fromiter(chain.from_iterable(lists), dtype=np.int64, count=int(lengths.sum()))
    qid = np.repeat(np.arange(len(q)), lengths)
    d2 = np.sum((tree.data[idx] - q[qid]) ** 2, axis=1)
    return idx, d2, qid


def _interp_log_h(gx: NDArray, gy: NDArray, table: NDArray, pts: NDArray) -> NDArray[np.float64]:
    """Bilinear interpolation of ``table (nx, ny, 2)`` (log bandwidths) at ``pts (n, 2)``, clamped.

    ``gx``/``gy`` are the regular grid axes [m].
    """
    nx, ny = gx.size, gy.size
    fx = np.clip((pts[:, 0] - gx[0]) / (gx[-1] - gx[0] if nx > 1 else 1.0) * (nx - 1), 0, nx - 1)
    fy = np.clip((pts[:, 1] - gy[0]) / (gy[-1] - gy[0] if ny > 1 else 1.0) * (ny - 1), 0, ny - 1)
    ix, iy = np.minimum(fx.astype(np.int64), max(nx - 2, 0)), np.minimum(fy.astype(np.int64), max(ny - 2, 0))
    ax, ay = (fx - ix)[:, None], (fy - iy)[:, None]
    jx, jy = np.minimum(ix + 1, nx - 1), np.minimum(iy + 1, ny - 1)
    return (
        (1 - ax) * (1 - ay) * table[ix, iy]
        + ax * (1 - ay) * table[jx, iy]
        + (1 - ax) * ay * table[ix, jy]
        + ax * ay * table[jx, jy]
    )


def _loo_score(xs: NDArray, zs: NDArray, v: NDArray, groups: NDArray, cand: NDArray) -> NDArray[np.float64]:
    """Weighted leave-one-group-out log-likelihood ``(C, C)`` for bandwidth candidates ``(h_x, h_y)``.

    ``xs (M, d)`` scaled states, ``zs (M, 2)`` outputs, ``v (M,)`` weights of each held-out tuple,
    ``groups (M,)`` CV group ids: a held-out tuple is scored without every tuple of its group.
    """
    w = np.exp(-0.5 * np.sum((xs[:, None] - xs[None]) ** 2, axis=-1))  # w[i, j]: tuple i for query j
    w[groups[:, None] == groups[None, :]] = 0.0
    wsum = w.sum(axis=0)
    dz = zs[:, None] - zs[None]
    kx = np.exp(-0.5 * (dz[None, ..., 0] / cand[:, None, None]) ** 2) / cand[:, None, None]  # (C, M, M)
    ky = np.exp(-0.5 * (dz[None, ..., 1] / cand[:, None, None]) ** 2) / cand[:, None, None]
    dens = np.einsum("ij,aij,bij->abj", w, kx, ky, optimize=True) / (2 * np.pi * np.maximum(wsum, 1e-300))
    ok = wsum > 1e-12
    return np.sum(v[ok] * np.log(np.maximum(dens[..., ok], 1e-300)), axis=-1)


def cv_bandwidth_table(
    xs: NDArray,
    zs: NDArray,
    groups: NDArray,
    grid_x: NDArray,
    grid_y: NDArray,
    scale: NDArray,
    radius: float,
    cand: NDArray,
    min_tuples: int,
    max_tuples: int,
    rng: np.random.Generator,
    state_transform: str = "cartesian",
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Leave-one-out CV of the output bandwidths on a grid of corner positions.

    For each grid node ``g``, the detected tuples whose corner lies within ``radius`` relevance
    sigmas of ``g`` (at most ``max_tuples``, subsampled) are held out one at a time; each is scored
    by the conditional density of the tuples of OTHER groups (leave-one-group-out: consecutive
    cycles of one track are near-duplicates, and plain leave-one-out then picks far too small
    bandwidths), weighted by ``K_rel`` between full states; the held-out scores are weighted by
    ``K_rel(corner - g)``. The pair ``(h_x, h_y)`` of ``cand`` with the best score is kept. Nodes
    with fewer than ``min_tuples`` tuples take the value of the nearest node that has enough.

    Args:
        xs: ``(n, d)`` unscaled states of the detected tuples (corner first) [m].
        zs: ``(n, 2)`` outputs [m].
        groups: ``(n,)`` CV group id of each tuple (e.g. its track).
        grid_x: grid axis [m] of corner x.
        grid_y: grid axis [m] of corner y.
        scale: ``(d,)`` relevance standard deviations [m].
        radius: neighbourhood radius in relevance sigmas.
        cand: ``(C,)`` candidate bandwidths [m] for each output dimension.
        min_tuples: nodes with fewer tuples in reach take the median bandwidth of the others.
        max_tuples: larger neighbourhoods are subsampled to this size.
        rng: generator for subsampling.
        state_transform: corner features of the relevance kernel (:func:`corner_features`; ``scale``
            applies to the features, the grid stays in corner x/y).

    Returns:
        ``log_h (nx, ny, 2)`` log bandwidths [log m] and ``counts (nx, ny)`` tuples used per node.
    """
    s = relevance_features(xs, state_transform) / scale
    tree = cKDTree(s[:, :2])
    gx, gy = np.meshgrid(grid_x, grid_y, indexing="ij")
    nodes = corner_features(np.stack([gx.ravel(), gy.ravel()], axis=1), state_transform) / scale[:2]
    lists = tree.query_ball_point(nodes, radius)
    log_h = np.full((nodes.shape[0], 2), np.nan)
    counts = np.zeros(nodes.shape[0], dtype=np.int64)
    for n, idx in enumerate(lists):  # one iteration per grid node (tens), not per tuple
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size > max_tuples:
            idx = rng.choice(idx, max_tuples, replace=False)
        counts[n] = idx.size
        if idx.size < min_tuples:
            continue
        v = np.exp(-0.5 * np.sum((s[idx, :2] - nodes[n]) ** 2, axis=1))
        score = _loo_score(s[idx], zs[idx], v, groups[idx], cand)
        a, b = np.unravel_index(np.argmax(score), score.shape)
        log_h[n] = np.log([cand[a], cand[b]])
    good = ~np.isnan(log_h[:, 0])
    if not good.any():
        raise InputError(f"no grid node has {min_tuples} tuples within reach; lower cv_min_tuples")
    _, near = cKDTree(nodes[good]).query(nodes[~good], k=1)
    log_h[~good] = log_h[good][near]
    return log_h.reshape(grid_x.size, grid_y.size, 2), counts.reshape(grid_x.size, grid_y.size)


def corner_features(corners: NDArray, state_transform: str) -> NDArray[np.float64]:
    """Corner features ``(n, 2)`` of the relevance kernel from sensor-frame corners ``(n, 2)`` [m].

    ``"cartesian"``: the corners themselves (returned as given); ``"polar"``: ``(range [m], azimuth
    [rad], left > 0)``. The azimuth does not wrap at +-pi (a forward radar's field of view does not
    reach behind the sensor), so two corners just either side of the sensor's back axis are far apart.
    """
    if state_transform == "cartesian":
        return corners
    c = np.asarray(corners, dtype=np.float64)
    return np.stack([np.hypot(c[:, 0], c[:, 1]), np.arctan2(c[:, 1], c[:, 0])], axis=1)


def relevance_features(states: NDArray, state_transform: str) -> NDArray[np.float64]:
    """States ``(n, d)`` (corner x, y first [m]) with the corner columns as :func:`corner_features`."""
    if state_transform == "cartesian":
        return states
    return np.concatenate([corner_features(states[:, :2], state_transform), states[:, 2:]], axis=1)


class KDERadarModel(SensorModel):
    """Joint-KDE radar model with two-stage sampling (implements ``RadarSensor``; a scikit-learn estimator).

    Args:
        rel_variance: variances of the relevance kernel on ``(c_x, c_y, z_{t-1,x}, z_{t-1,y})`` [m^2]; with
            ``state_transform="polar"`` the first two are of (corner range [m^2], corner azimuth [rad^2]).
        use_prev: condition on the previous output ``z_{t-1}``.
        radius: fixed search radius in relevance sigmas.
        k_max: keep only the ``k_max`` nearest tuples in the ball (``None`` = exact).
        cv_grid_step: spacing [m] of the LOO-CV bandwidth grid over corner positions.
        cv_candidates: candidate output bandwidths [m] tried by the CV (per output dimension).
        cv_min_tuples: grid nodes with fewer tuples in reach take the median bandwidth.
        cv_max_tuples: larger CV neighbourhoods are subsampled to this size.
        cv_group: CV hold-out unit: ``"track"`` (same sequence and target), ``"sequence"`` or ``"row"``
            (plain leave-one-out).
        fallback_k: a query with no tuple inside the ball uses its ``fallback_k`` nearest tuples of the
            same tree, weighted ``exp(-(d^2 - d_min^2) / 2)`` (scaled distances ``d``).
        miss_prior: pseudo-weight ``a`` of a prior miss rate ``m`` in ``P(miss | x)``
            (``(w_miss + a * m) / (w_sum + a)``); keeps both outcomes possible everywhere so that
            held-out likelihoods are finite. ``0`` gives the seed's estimate.
        prior_rate: ``m`` of ``miss_prior``: ``"tree"`` (the miss rate of the tuples the query is
            matched against: those with a previous output, or the start tuples) or ``"global"`` (the
            log's overall miss rate; format-1 models). Where neighbours are few (e.g. a simulated
            ``z_{t-1}`` off the recorded ones), ``"global"`` pulls the detection rate after a
            detection (rig: 81 %) toward the overall 52 %.
        clutter_jitter: std [m] of the Gaussian jitter added to resampled clutter positions.
        sampler: ``"bucket"`` (exact rejection sampling over grid buckets of the scaled state space; cost
            follows the number of candidate buckets, flat in the number of tuples), ``"ball"`` (the
            reference: full ball query; cost follows the number of neighbours) or ``"auto"`` (bucket
            from a median of :data:`AUTO_BUCKET_MIN_NEIGHBOURS` tuples per ball on). All sample the
            same distribution; ``k_max`` forces ``"ball"``.
        bucket_cell: side of the bucket grid cells in relevance sigmas.
        relevance: ``"paper"`` (use ``rel_variance`` as given), ``"cv"`` (choose the corner variance
            of the relevance kernel from ``relevance_candidates`` by ``relevance_folds``-fold CV on the
            training log, :mod:`sensor_envs.radar.relevance`; the ``z_{t-1}`` variances stay as given)
            or ``"cv_axes"`` (the same CV for the x and the y variance apart, coordinate-wise:
            :func:`~sensor_envs.radar.relevance.select_corner_variances`) or ``"cv_state"`` (``"cv_axes"``,
            then the ``z_{t-1}`` variance - one value for both components - from
            ``relevance_candidates_prev`` by the same CV with the corner variances chosen:
            :func:`~sensor_envs.radar.relevance.select_prev_variance`). Polar corner features: the CV
            modes choose the range and then the azimuth variance.
        relevance_candidates: corner variances [m^2] tried by the CV (polar: range variances).
        relevance_candidates_azimuth: azimuth variances [rad^2] tried by the CV with
            ``state_transform="polar"`` (after the range variance; unused otherwise).
        relevance_candidates_prev: ``z_{t-1}`` variances [m^2] tried by ``relevance="cv_state"``.
        bandwidth_scale: factor on every contribution bandwidth the leave-one-track-out CV chose (1: the
            seed's CV bandwidths). A KDE fitted on a SIMULATED log (the rig) may need narrower kernels
            for the real sensor than that log's CV picks: :mod:`sensor_envs.radar.tune` (``sensor-envs tune radar``)
            chooses the factor by held-out likelihood on real frames (model card).
        start_bandwidth_scale: the same factor for the START trees (queries without ``z_{t-1}``: new tracks,
            after a miss), or ``None`` (default): ``bandwidth_scale``. A start tuple is drawn once, while a
            chain fed its own outputs draws every cycle and its stationary law spreads wider than the tuples
            it resamples; the two may need different factors (model card).
        state_transform: corner features of the relevance kernel: ``"cartesian"`` (``(c_x, c_y)``, the
            paper's; what files before format 5 hold) or ``"polar"`` (``(range, azimuth)``: a kernel
            narrow in azimuth at every range, so near targets left and right are not mixed).
        output_frame: frame of the stored outputs and previous outputs, in which the kernels act:
            ``"cartesian"`` (the sensor frame, the paper's; files before format 6) or ``"polar"`` (the
            corner's radial and OUTWARD cross-range axes, mirrored right of the boresight: a corner
            kernel wide enough to pool targets left and right of the boresight keeps an offset toward
            the outer end of the face, which in the sensor frame points opposite ways on the two sides
            and cancels). ``sample``/``log_prob`` take and return sensor-frame offsets either way
            (the change of frame is a rotation or reflection: densities are unchanged).
        relevance_folds: folds of ``relevance="cv"`` (sequences dealt round-robin).
        random_state: seed or generator for the CV subsampling.
        extra_state: names of extra numeric log columns appended to the state (see the module docstring).
        extra_variance: relevance variances of the extra dimensions [unit^2]; ``None`` (or a NaN entry) =
            chosen by CV.
        extra_candidates: factors ``f`` of the column std tried by that CV (variance ``(f * std)^2``).
        azimuth_bias: the radar's mounting yaw error [rad] (counter-clockwise positive) undone before the
            kernels and applied to samples (see the module docstring), or ``"fit"``: estimated from the
            training log's detections (``azimuth_bias_``; :func:`~sensor_envs.radar.alignment.estimate_azimuth_bias`).
            ``0`` (the default, and every file before format 7) is the paper's model.
        tail_weight: share ``w`` in ``[0, 0.5]`` of the detection density in the wide (tail) component (see
            the module docstring); ``0`` (the default, and every file before format 8): none.
        tail_scale: factor ``c`` in ``[1, 100]`` of the tail component's bandwidths over the main kernels'.
        verbose: show progress bars of the relevance CV (``relevance != "paper"``, the extra-state CV).

    Attributes:
        states_: ``(N, 4)`` stored tuple states: corner [m] (sensor frame) and previous output ``z_{t-1}`` [m]
            in the stored frame (``NaN``: none).
        z_: ``(N, 2)`` stored outputs [m] in the stored frame (``NaN`` rows: misses).
        log_row_: ``(N,)`` row of the training log each tuple comes from.
        new_track_: ``(N,)`` True where the tuple's target is first seen, or ``None`` (files without the flags).
        rel_variance_: the relevance variances used (``rel_variance``, or those the CV chose).
        relevance_scores_: held-out scores of the relevance CV candidates (empty for ``"paper"``).
        scale_: ``(4,)`` relevance sigmas ``sqrt(rel_variance_)``.
        extra_state_: names of the extra state variables; extra_: ``(N, E)`` their values;
            extra_fill_: ``(E,)`` training medians (NaN fill); extra_variance_, extra_scale_: their relevance
            variances and sigmas; extra_scores_: the extra-state CV's scores.
        azimuth_bias_: the mounting yaw error [rad] undone before the kernels.
        grid_x_, grid_y_: the CV bandwidth grid over corner x, y [m]; log_h_: ``(nx, ny, 2)`` log
            bandwidths [log m] (``bandwidth_scale`` included); cv_counts_: tuples per grid node; cand_: the
            candidate bandwidths [m].
        clutter_counts_: clutter detections per training cycle; clutter_xy_: ``(M, 2)`` clutter positions [m].
        cycle_time_: seconds between the frames of the training log (NaN: unknown).
        miss_rate_: the log's miss rate; prior_rate_main_, prior_rate_start_, prior_rate_new_,
            prior_rate_lost_: each tree's prior miss rate ``m``.
        median_neighbours_: median tuples in the ball of a stored state (``sampler="auto"``).
        card_: the model card entries (:class:`~sensor_envs.sensor_model.SensorModel`).

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import KDERadarModel
        >>> from sensor_envs.radar.rig import record_rig_log
        >>> log = record_rig_log(8, 20, 6, np.random.default_rng(0))  # sequences x cycles x targets of the rig
        >>> model = KDERadarModel(random_state=0).fit(log, cycle_time=1.0)
        >>> z, source = model.sample(np.array([[15.0, 1.0]]), np.random.default_rng(1))
        >>> z.shape
        (1, 2)
    """

    KIND = KIND
    FORMAT_VERSION = FORMAT_VERSION
    CAPABILITIES = frozenset({"new_track", "extra_state", "prev_output", "log_prob", "clutter"})
    _FITTED = "states_"
    _SCHEMA: ClassVar[dict[str, tuple[str, int | None, bool]]] = {
        "states": ("f", 2, False),
        "z": ("f", 2, False),
        "log_row": ("iu", 1, True),
        "grid_x": ("f", 1, True),
        "grid_y": ("f", 1, True),
        "log_h": ("f", 3, True),
        "cv_counts": ("iu", 2, True),
        "cv_candidates": ("f", 1, True),
        "clutter_counts": ("iu", 1, True),
        "clutter_xy": ("f", 2, True),
    }
    _PARAM_DEFAULTS: ClassVar[dict[str, Any]] = {  # files written before the factors and the prev CV
        "relevance_candidates_prev": PREV_CANDIDATES,
        "bandwidth_scale": 1.0,
    }
    _parameter_constraints: ClassVar[dict[str, list[Constraint]]] = {
        "rel_variance": [Numbers(Interval(0, MAX_POSITION**2, open_low=True), length=4)],
        "use_prev": [InstanceOf(bool)],
        "radius": [_POSITIVE],
        "k_max": [None, Interval(1, None, integer=True)],
        "cv_grid_step": [_POSITIVE],
        "cv_candidates": [None, Numbers(Interval(0, MAX_POSITION, open_low=True))],
        "cv_min_tuples": [Interval(1, None, integer=True)],
        "cv_max_tuples": [Interval(1, None, integer=True)],
        "cv_group": [Options("track", "sequence", "row")],
        "fallback_k": [Interval(1, None, integer=True)],
        "miss_prior": [Interval(0, None)],
        "clutter_jitter": [Interval(0, MAX_POSITION)],
        "sampler": [Options("auto", "bucket", "ball")],
        "bucket_cell": [_POSITIVE],
        "relevance": [Options("paper", *CV_RELEVANCE)],
        "relevance_candidates": [Numbers(_POSITIVE)],
        "relevance_candidates_azimuth": [Numbers(Interval(0, np.pi**2, open_low=True))],
        "relevance_candidates_prev": [Numbers(Interval(0, MAX_POSITION**2, open_low=True))],
        "state_transform": [Options(*STATE_TRANSFORMS)],
        "output_frame": [Options(*OUTPUT_FRAMES)],
        "relevance_folds": [Interval(2, None, integer=True)],
        "prior_rate": [Options("tree", "global")],
        "random_state": RANDOM_STATE,
        "extra_state": [InstanceOf(tuple, list)],  # details: _check_extra_params
        "extra_variance": [None, InstanceOf(tuple, list)],
        "extra_candidates": [InstanceOf(tuple, list)],
        "bandwidth_scale": [Interval(0.01, 100)],
        "start_bandwidth_scale": [None, Interval(0.01, 100)],
        "azimuth_bias": [Options("fit"), Interval(-MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS)],
        "tail_weight": [Interval(0, MAX_TAIL_WEIGHT)],
        "tail_scale": [Interval(1, MAX_TAIL_SCALE)],
        "verbose": [InstanceOf(bool)],
    }
    """One declarative check of every hyperparameter, used by :meth:`fit` and :meth:`load`."""

    def __init__(
        self,
        *,
        rel_variance: tuple[float, float, float, float] = (3.0, 3.0, 0.03, 0.03),
        use_prev: bool = True,
        radius: float = 3.0,
        k_max: int | None = None,
        cv_grid_step: float = 4.0,
        cv_candidates: tuple[float, ...] | None = None,
        cv_min_tuples: int = 30,
        cv_max_tuples: int = 300,
        cv_group: str = "track",
        fallback_k: int = 8,
        miss_prior: float = 1.0,
        clutter_jitter: float = 0.5,
        sampler: str = "auto",
        bucket_cell: float = 3.0,
        relevance: str = "paper",
        relevance_candidates: tuple[float, ...] = (3.0, 6.0, 12.0, 24.0, 48.0),
        relevance_folds: int = 4,
        prior_rate: str = "tree",
        random_state: int | np.random.Generator | None = None,
        extra_state: tuple[str, ...] = (),
        extra_variance: tuple[float, ...] | None = None,
        extra_candidates: tuple[float, ...] = (0.25, 0.5, 1.0, 2.0),
        state_transform: str = "cartesian",
        relevance_candidates_azimuth: tuple[float, ...] = AZIMUTH_CANDIDATES,
        relevance_candidates_prev: tuple[float, ...] = PREV_CANDIDATES,
        bandwidth_scale: float = 1.0,
        start_bandwidth_scale: float | None = None,
        output_frame: str = "cartesian",
        azimuth_bias: float | str = 0.0,
        tail_weight: float = 0.0,
        tail_scale: float = 4.0,
        verbose: bool = False,
    ) -> None:
        self.rel_variance = rel_variance
        self.use_prev = use_prev
        self.radius = radius
        self.k_max = k_max
        self.cv_grid_step = cv_grid_step
        self.cv_candidates = cv_candidates
        self.cv_min_tuples = cv_min_tuples
        self.cv_max_tuples = cv_max_tuples
        self.cv_group = cv_group
        self.fallback_k = fallback_k
        self.miss_prior = miss_prior
        self.clutter_jitter = clutter_jitter
        self.sampler = sampler
        self.bucket_cell = bucket_cell
        self.relevance = relevance
        self.relevance_candidates = relevance_candidates
        self.relevance_folds = relevance_folds
        self.prior_rate = prior_rate
        self.random_state = random_state
        self.extra_state = extra_state
        self.extra_variance = extra_variance
        self.extra_candidates = extra_candidates
        self.state_transform = state_transform
        self.relevance_candidates_azimuth = relevance_candidates_azimuth
        self.relevance_candidates_prev = relevance_candidates_prev
        self.bandwidth_scale = bandwidth_scale
        self.start_bandwidth_scale = start_bandwidth_scale
        self.output_frame = output_frame
        self.azimuth_bias = azimuth_bias
        self.tail_weight = tail_weight
        self.tail_scale = tail_scale
        self.verbose = verbose

    # ------------------------------------------------------------------ fit
    def _check_params_relations(self, source: str | os.PathLike[str] | None) -> None:
        """The ``extra_*`` hyperparameters agree with each other (``InputError`` naming the parameter)."""
        _check_extra_params(self.extra_state, self.extra_variance, self.extra_candidates)

    def fit(self, log: RadarLog, cycle_time: float | None = None, progress: bool | None = None) -> KDERadarModel:
        """Fit on a radar log: store the tuples, build the trees, run the LOO-CV bandwidth table.

        Args:
            log: the radar object log.
            cycle_time: seconds between consecutive frames of the log (stored in the model file).
            progress: deprecated; the ``verbose`` hyperparameter.

        Returns:
            self.
        """
        cycle = fit_cycle_time(log, cycle_time)  # a RadarLog; the cycle time consistent with its t column
        self._check_params()
        progress = self._deprecated_progress(progress, self.verbose)
        rng = np.random.default_rng(self.random_state)
        tt = target_tuples(log)
        det = ~np.isnan(tt.z[:, 0])
        if det.sum() < 2:
            raise InputError(f"{log.source}: fewer than 2 detected target rows; cannot fit a KDE")
        self.azimuth_bias_ = (
            estimate_azimuth_bias(tt.corner, tt.z) if self.azimuth_bias == "fit" else float(self.azimuth_bias)
        )
        self.states_ = np.concatenate([tt.corner, self._to_model_frame(tt.z_prev, tt.corner)], axis=1)
        self.z_ = self._to_model_frame(tt.z, tt.corner)
        self.log_row_ = tt.row
        self.new_track_: NDArray[np.bool_] | None = ~tt.has_prev_row  # first row of its target in the log
        self.rel_variance_ = tuple(float(v) for v in self.rel_variance)
        self.relevance_scores_ = np.zeros(0)
        polar = self.state_transform == "polar"
        if self.relevance in ("cv_axes", "cv_state") or (self.relevance == "cv" and polar):
            (v1, v2), self.relevance_scores_ = select_corner_variances(
                log,
                self,
                tuple(self.relevance_candidates),
                tuple(self.relevance_candidates_azimuth if polar else self.relevance_candidates),
                int(self.relevance_folds),
                progress,
            )
            self.rel_variance_ = (v1, v2, *self.rel_variance_[2:])
            if self.relevance == "cv_state" and self.use_prev:
                vp, sp = select_prev_variance(
                    log,
                    type(self)(**{**self.get_params(), "rel_variance": self.rel_variance_}),
                    tuple(self.relevance_candidates_prev),
                    int(self.relevance_folds),
                    progress,
                )
                self.rel_variance_ = (v1, v2, vp, vp)
                self.relevance_scores_ = np.concatenate([self.relevance_scores_, sp])
        elif self.relevance == "cv":
            v, self.relevance_scores_ = select_corner_variance(
                log, self, tuple(self.relevance_candidates), int(self.relevance_folds), progress
            )
            self.rel_variance_ = (v, v, *self.rel_variance_[2:])
        self.scale_ = np.sqrt(np.asarray(self.rel_variance_, dtype=np.float64))
        self._fit_extra(log, tt.row, progress)
        self.cand_ = (
            np.asarray(self.cv_candidates, dtype=np.float64)
            if self.cv_candidates is not None
            else np.geomspace(0.02, 2.0, 14)
        )
        dims = 4 if self.use_prev else 2
        cv_rows = det & (~np.isnan(tt.z_prev[:, 0]) if self.use_prev else True)
        if cv_rows.sum() < self.cv_min_tuples:
            cv_rows = det
            dims = 2
        lo, hi = tt.corner.min(axis=0), tt.corner.max(axis=0)
        self.grid_x_ = np.arange(lo[0], hi[0] + self.cv_grid_step, self.cv_grid_step)
        self.grid_y_ = np.arange(lo[1], hi[1] + self.cv_grid_step, self.cv_grid_step)
        groups = _cv_groups(tt, self.cv_group)
        self.log_h_, self.cv_counts_ = cv_bandwidth_table(
            np.concatenate([self.states_[cv_rows, :dims], self.extra_[cv_rows]], axis=1),
            self.z_[cv_rows],
            groups[cv_rows],
            self.grid_x_,
            self.grid_y_,
            np.concatenate([self.scale_[:dims], self.extra_scale_]),
            self.radius,
            self.cand_,
            self.cv_min_tuples,
            self.cv_max_tuples,
            rng,
            self.state_transform,
        )
        self.log_h_ = self.log_h_ + np.log(self.bandwidth_scale)  # no draw depends on it: the rest is the same
        counts, xy = clutter_counts(log)
        if xy.shape[0] > MAX_CLUTTER_POSITIONS:  # drawn last: smaller logs keep every earlier draw
            xy = xy[np.sort(rng.choice(xy.shape[0], MAX_CLUTTER_POSITIONS, replace=False))]
        self.clutter_counts_, self.clutter_xy_ = counts, xy
        self.cycle_time_ = cycle
        self.card_: dict[str, Any] = {}
        self._build()
        return self

    def _fit_extra(self, log: RadarLog, rows: NDArray[np.int64], progress: bool) -> None:
        """Extra state columns at the tuples' ``rows``: values, NaN fill, relevance scales (CV if not given)."""
        self.extra_state_ = tuple(str(n) for n in self.extra_state)
        log = with_state_columns(log, self.extra_state_)  # derived features once, not per CV fold
        x = state_matrix(log, self.extra_state_, rows)
        fill = np.nanmedian(x, axis=0) if x.shape[1] and np.isfinite(x).any(axis=0).all() else np.zeros(x.shape[1])
        if x.shape[1] and not np.isfinite(x).any(axis=0).all():
            bad = self.extra_state_[int(np.argmin(np.isfinite(x).any(axis=0)))]
            raise InputError(f"{log.source}: column {bad!r} has no value on any target row")
        self.extra_fill_ = np.asarray(fill, dtype=np.float64)
        self.extra_ = np.where(np.isnan(x), self.extra_fill_, x)
        self.extra_scores_ = np.zeros((0, 0))
        if self.extra_variance is not None and not np.isnan(np.asarray(self.extra_variance, dtype=np.float64)).any():
            self.extra_variance_ = tuple(float(v) for v in self.extra_variance)
        elif x.shape[1]:
            std = np.maximum(self.extra_.std(axis=0), 1e-9)
            inner = type(self)(**{**self.get_params(), "rel_variance": self.rel_variance_, "relevance": "paper"})
            var, self.extra_scores_ = select_extra_variances(
                log, inner, std, tuple(self.extra_candidates), int(self.relevance_folds), progress
            )
            self.extra_variance_ = tuple(float(v) for v in var)
        else:
            self.extra_variance_ = ()
        self.extra_scale_ = np.sqrt(np.asarray(self.extra_variance_, dtype=np.float64)).reshape(-1)

    def to_output_frame(self, z: NDArray, corners: NDArray) -> NDArray[np.float64]:
        """Sensor-frame offsets ``z (n, 2)`` [m] at ``corners (n, 2)`` on the axes of ``output_frame``.

        The axes :meth:`bin_probabilities` and :meth:`bandwidth` refer to, after the mounting yaw error
        ``azimuth_bias_`` is undone (identity for ``"cartesian"`` without one).
        """
        self._check_fitted()
        return self._to_model_frame(np.atleast_2d(np.asarray(z, dtype=np.float64)), np.atleast_2d(corners))

    def _to_model_frame(self, z: NDArray, corners: NDArray) -> NDArray[np.float64]:
        """Sensor-frame offsets ``z (n, 2)`` [m] at ``corners (n, 2)`` in the stored frame.

        The mounting yaw error ``azimuth_bias_`` undone first, then the axes of ``output_frame``.
        """
        z = derotate_offsets(z, corners, self.azimuth_bias_)
        return z if self.output_frame == "cartesian" else to_polar_frame(z, corners)

    def _to_sensor_frame(self, z: NDArray, corners: NDArray) -> NDArray[np.float64]:
        """Inverse of :meth:`_to_model_frame`: stored-frame offsets back to the sensor frame [m]."""
        z = z if self.output_frame == "cartesian" else from_polar_frame(z, corners)
        return rotate_offsets(z, corners, self.azimuth_bias_)

    def _model_state(self, st: NDArray) -> NDArray[np.float64]:
        """Query states ``(n, 2|4)`` with the previous output (columns 2-3) in the stored frame."""
        if st.shape[1] < 4:
            return st
        return np.concatenate([st[:, :2], self._to_model_frame(st[:, 2:4], st[:, :2]), st[:, 4:]], axis=1)

    def _features(self, states: NDArray) -> NDArray[np.float64]:
        """States ``(n, d)`` with the corner columns as relevance features (:func:`relevance_features`)."""
        return relevance_features(states, self.state_transform)

    def _scaled(self, base: NDArray, extra: NDArray) -> NDArray[np.float64]:
        """Scaled query/tuple states: ``base (n, d)`` by the first ``d`` relevance scales, then the extras."""
        return np.concatenate([base / self.scale_[: base.shape[1]], extra / self.extra_scale_], axis=1)

    def _extra_query(self, extra: NDArray | None, n: int) -> NDArray[np.float64]:
        """Validated ``(n, E)`` extra state of ``n`` queries (NaN -> training median)."""
        e = len(self.extra_state_)
        if e == 0:
            return np.zeros((n, 0))
        if extra is None:
            raise InputError(f"extra: this model's state includes {list(self.extra_state_)}; pass their values")
        x = np.asarray(extra, dtype=np.float64)
        if x.size != n * e:
            raise InputError(f"extra: expected ({n}, {e}) values of {list(self.extra_state_)}, got shape {x.shape}")
        x = x.reshape(n, e)
        return np.where(np.isnan(x), self.extra_fill_, x)

    @property
    def state_variables(self) -> tuple[str, ...]:
        """Names of the state dimensions: corner, previous output, then the extra state."""
        self._check_fitted()
        return ("corner_x", "corner_y", "prev_z_x", "prev_z_y", *self.extra_state_)

    def mean_output(
        self, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> tuple[NDArray, NDArray]:
        """Expected output given a detection ``(n, 2)`` [m] and ``P(miss)`` ``(n,)`` (arguments as :meth:`log_prob`)."""
        self._check_fitted()
        st = self._model_state(np.atleast_2d(np.asarray(state, dtype=np.float64)))
        n = st.shape[0]
        ex = self._extra_query(extra, n)
        prev = st[:, 2:4] if (st.shape[1] == 4 and self.use_prev) else None
        gi, w, q, p_miss = self._outcome(st[:, :2], prev, ex, self._route(_as_prev(prev, n), new_track))
        gi, w, q = self._with_detected_fallback(gi, w, q, st[:, :2])
        wd = w * ~self.miss_[gi]
        zi = np.nan_to_num(self.z_[gi])  # missed tuples have NaN outputs and zero weight here
        zsum = np.stack([np.bincount(q, weights=wd * zi[:, k], minlength=n) for k in range(2)], axis=1)
        mean = zsum / np.bincount(q, weights=wd, minlength=n)[:, None]
        return self._to_sensor_frame(mean, st[:, :2]), p_miss

    def _build(self) -> None:
        """Build the search trees from the stored tuples (at fit and at load; never per call)."""
        has_prev = ~np.isnan(self.states_[:, 2])
        empty = np.zeros(0, dtype=np.int64)
        flags = getattr(self, "new_track_", None)
        if self.use_prev:
            self.main_idx_ = np.flatnonzero(has_prev)
            self.start_idx_ = np.flatnonzero(~has_prev)
            if self.start_idx_.size == 0:
                self.start_idx_ = np.arange(self.states_.shape[0])
            self.new_idx_ = empty if flags is None else np.flatnonzero(~has_prev & flags)
            self.lost_idx_ = empty if flags is None else np.flatnonzero(~has_prev & ~flags)
        else:
            self.main_idx_ = empty
            self.start_idx_ = np.arange(self.states_.shape[0])
            self.new_idx_, self.lost_idx_ = empty, empty
        if not hasattr(self, "extra_"):  # models fitted/loaded before the extra state existed
            self.extra_state_, self.extra_ = (), np.zeros((self.states_.shape[0], 0))
            self.extra_fill_, self.extra_variance_, self.extra_scale_ = np.zeros(0), (), np.zeros(0)
        self.miss_ = np.isnan(self.z_[:, 0])
        self.miss_rate_ = float(self.miss_.mean())
        tree_rate = self.prior_rate == "tree"
        self._groups: list[_Tree | None] = []
        for g, idx in enumerate((self.main_idx_, self.start_idx_, self.new_idx_, self.lost_idx_)):
            if idx.size == 0:
                self._groups.append(None)
                continue
            dims = 4 if g == GROUP_MAIN else 2
            tree = cKDTree(self._scaled(self._features(self.states_[idx, :dims]), self.extra_[idx]))
            buckets = (
                None
                if self.extra_.shape[1]
                else build_buckets(tree.data, self.bucket_cell, self.radius, flag=self.miss_[idx])
            )
            rate = float(self.miss_[idx].mean()) if tree_rate else self.miss_rate_
            self._groups.append(_Tree(tree, idx, buckets, rate))
        main, start = self._groups[GROUP_MAIN], self._groups[GROUP_START]
        assert start is not None  # the start tree always holds tuples
        self._main_tree = None if main is None else main.tree
        self._start_tree = start.tree
        self.prior_rate_main_ = self.miss_rate_ if main is None else main.rate
        self.prior_rate_start_ = start.rate
        new, lost = self._groups[GROUP_NEW], self._groups[GROUP_LOST]
        self.prior_rate_new_ = start.rate if new is None else new.rate
        self.prior_rate_lost_ = start.rate if lost is None else lost.rate
        self.det_idx_ = np.flatnonzero(~self.miss_)
        self._det_tree = cKDTree(self._features(self.states_[self.det_idx_, :2]) / self.scale_[:2])
        tree = self._main_tree if self._main_tree is not None else self._start_tree
        probe = tree.data[:: max(1, tree.n // 256)]  # a deterministic sample of stored states
        self.median_neighbours_ = float(np.median(tree.query_ball_point(probe, self.radius, return_length=True)))
        self._auto_bucket = self.median_neighbours_ >= AUTO_BUCKET_MIN_NEIGHBOURS

    def _route(self, prev: NDArray, new_track: NDArray | None) -> NDArray[np.int64]:
        """Tree of each query ``(n,)`` (``GROUP_*``) from its previous output ``(n, 2)`` and ``new_track`` flag.

        Raises:
            ValueError: when ``new_track`` is not ``n`` booleans, or flags a query that has a previous output.
        """
        n = prev.shape[0]
        has = ~np.isnan(prev[:, 0])
        grp = np.where(has & (self._groups[GROUP_MAIN] is not None), GROUP_MAIN, GROUP_START).astype(np.int64)
        if new_track is None:
            return grp
        flag = np.asarray(new_track)
        if flag.dtype != np.bool_ or flag.shape not in ((n,), ()):
            raise InputError(f"new_track: expected None or ({n},) booleans, got {flag.dtype} of shape {flag.shape}")
        flag = np.broadcast_to(flag, (n,))
        if (flag & has).any():
            r = int(np.flatnonzero(flag & has)[0])
            raise InputError(f"new_track: row {r} is flagged new but has a previous output (prev_z is finite)")
        if not self.use_prev:
            return grp
        start = grp == GROUP_START
        for g, sel in ((GROUP_NEW, start & flag), (GROUP_LOST, start & ~flag)):
            if self._groups[g] is not None:
                grp[sel] = g
        return grp

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for key in ("_main_tree", "_start_tree", "_det_tree", "_main_buckets", "_start_buckets", "_groups"):
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if hasattr(self, "states_"):
            self._build()

    # ------------------------------------------------------------------ query
    def bandwidth(self, corners: NDArray, start: NDArray | bool = False) -> NDArray[np.float64]:
        """Output bandwidths ``(n, 2)`` [m] interpolated from the CV table at ``corners (n, 2)`` [m].

        Along the axes of ``output_frame``: sensor x, y, or the corner's radial and outward cross-range.
        ``start`` (one flag, or one per corner): the bandwidths of a start-tree query (no ``z_{t-1}``), the
        table times ``start_bandwidth_scale`` instead of ``bandwidth_scale``.
        """
        self._check_fitted()
        h = np.exp(_interp_log_h(self.grid_x_, self.grid_y_, self.log_h_, np.atleast_2d(corners)))
        ratio = self._start_ratio()
        if ratio == 1.0:
            return h
        return h * np.where(np.broadcast_to(np.asarray(start, dtype=bool), (h.shape[0],)), ratio, 1.0)[:, None]

    def _start_ratio(self) -> float:
        """Start-tree bandwidth over main-tree bandwidth (1 without ``start_bandwidth_scale``)."""
        s = self.start_bandwidth_scale
        return 1.0 if s is None else float(s) / float(self.bandwidth_scale)

    def _neighbours(
        self, corners: NDArray, prev_z: NDArray | None, extra: NDArray | None = None, grp: NDArray | None = None
    ) -> tuple[NDArray, NDArray, NDArray]:
        """Relevant tuples of each query: flat ``(global tuple index, weight, query id)``.

        ``grp (n,)`` is the tree of each query (:meth:`_route`; ``None`` = by ``prev_z`` alone).
        """
        corners = np.atleast_2d(np.asarray(corners, dtype=np.float64))
        n = corners.shape[0]
        ex = self._extra_query(extra, n)
        prev = np.atleast_2d(np.asarray(prev_z, dtype=np.float64)) if prev_z is not None else np.full((n, 2), np.nan)
        if prev.shape != (n, 2) or corners.shape != (n, 2):
            raise InputError(f"corners and prev_z must both be (n, 2); got {corners.shape} and {prev.shape}")
        if not np.isfinite(corners).all():
            raise InputError(
                f"corners: row {int(np.flatnonzero(~np.isfinite(corners).all(axis=1))[0])} is NaN or infinite"
            )
        grp = self._route(prev, None) if grp is None else grp
        full = np.concatenate([self._features(corners), prev], axis=1)
        parts = []
        for g, node in enumerate(self._groups):
            qi = np.flatnonzero(grp == g)
            if qi.size == 0 or node is None:
                continue
            tree, idx_map = node.tree, node.idx
            qs = self._scaled(full[qi, : 4 if g == GROUP_MAIN else 2], ex[qi])
            j, d2, qid = _neighbour_lists(tree, qs, self.radius, self.k_max)
            w = np.exp(-0.5 * d2)
            empty = np.bincount(qid, weights=w, minlength=qi.size) <= 0.0
            keep = ~empty[qid]
            parts.append((idx_map[j[keep]], w[keep], qi[qid[keep]]))
            if empty.any():  # no tuple in the ball: the fallback_k nearest tuples of the same tree
                parts.append(self._fallback(tree, idx_map, qs[empty], qi[empty]))
        gi, w, q = (np.concatenate(a) for a in zip(*parts, strict=True))
        order = np.argsort(q, kind="stable")
        return gi[order], w[order], q[order]

    def _fallback(self, tree: cKDTree, idx_map: NDArray, qs: NDArray, qi: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """The ``fallback_k`` nearest tuples of scaled queries ``qs``, weighted ``exp(-(d^2 - d_min^2) / 2)``."""
        k = min(self.fallback_k, tree.n)
        d, j = tree.query(qs, k=k)
        d, j = d.reshape(len(qs), k), j.reshape(len(qs), k)
        w = np.exp(-0.5 * (d**2 - d[:, :1] ** 2))
        return idx_map[j.ravel()], w.ravel(), np.repeat(qi, k)

    def sample(
        self, state: NDArray, rng: np.random.Generator, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Two-stage sample for a batch of states.

        Args:
            state: ``(n, 2)`` corners or ``(n, 4)`` corners + previous outputs (``NaN`` = missing) [m],
                sensor frame.
            rng: generator.
            extra: ``(n, E)`` values of the extra state variables (required when the model has any).
            new_track: ``(n,)`` booleans for the rows without a previous output: ``True`` = the target
                is seen for the first time (new-track tree), ``False`` = it was missed last cycle
                (after-miss tree); ``None`` = unknown (the combined start tree). Must be ``False``
                where the previous output is finite.

        Returns:
            ``z (n, 2)`` [m] (``NaN`` rows = missed) and ``source (n,)`` the picked tuple's index.
        """
        self._check_fitted()
        check_states(state, rng=rng)
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        prev = st[:, 2:4] if (st.shape[1] == 4 and self.use_prev) else None
        return self.sample_cycle(st[:, :2], prev, rng, extra=extra, new_track=new_track)

    def _outcome(
        self, corners: NDArray, prev_z: NDArray | None, extra: NDArray | None = None, grp: NDArray | None = None
    ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """Neighbours ``(gi, w, q)`` and the miss probability ``(n,)`` of each query (``grp``: see :meth:`_route`)."""
        n = corners.shape[0]
        grp = self._route(_as_prev(prev_z, n), None) if grp is None else grp
        gi, w, q = self._neighbours(corners, prev_z, extra, grp)
        wsum = np.bincount(q, weights=w, minlength=n)
        wmiss = np.bincount(q, weights=w * self.miss_[gi], minlength=n)
        rate = self._group_rates()[grp]
        p_miss = (wmiss + self.miss_prior * rate) / (wsum + self.miss_prior)
        return gi, w, q, p_miss

    def _group_rates(self) -> NDArray[np.float64]:
        """Prior miss rate ``m`` of each tree (``GROUP_*`` order)."""
        return np.array([self.prior_rate_main_, self.prior_rate_start_, self.prior_rate_new_, self.prior_rate_lost_])

    @staticmethod
    def _pick(gi: NDArray, w: NDArray, q: NDArray, groups: NDArray, rng: np.random.Generator) -> NDArray[np.int64]:
        """One tuple per query, with probability ``w / sum w`` within the query's neighbour group.

        ``gi, w, q`` are flat neighbour lists sorted by group id ``q``; ``groups (n,)`` is the group of
        each query. Returns global tuple indices, ``-1`` where the group has zero weight.
        """
        n_groups = int(groups.max(initial=-1)) + 1
        cw = np.cumsum(w)
        g = np.arange(n_groups)
        starts, ends = np.searchsorted(q, g, side="left"), np.searchsorted(q, g, side="right")
        base = np.where(starts > 0, cw[np.maximum(starts - 1, 0)], 0.0)[groups]
        top = np.where(ends > starts, cw[np.maximum(ends - 1, 0)], 0.0)[groups]
        u = base + rng.random(groups.size) * (top - base)
        pick = np.clip(np.searchsorted(cw, u, side="right"), starts[groups], np.maximum(ends[groups] - 1, 0))
        ok = top > base
        return np.where(ok, gi[np.minimum(pick, gi.size - 1)] if gi.size else -1, -1).astype(np.int64)

    def _nearest_detected(self, corners: NDArray) -> NDArray[np.int64]:
        """Global index of the detected tuple with the nearest corner (fallback of empty groups)."""
        _, j = self._det_tree.query(self._features(corners) / self.scale_[:2], k=1)
        return self.det_idx_[j]

    def sample_cycle(
        self,
        corners: NDArray,
        prev_z: NDArray | None,
        rng: np.random.Generator,
        extra: NDArray | None = None,
        new_track: NDArray | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """``RadarSensor.sample_cycle``: outputs for ``n`` targets of one cycle (see :meth:`sample`).

        ``new_track (n,)`` tells a target seen for the first time (``True``) from one missed last
        cycle (``False``) where ``prev_z`` is ``NaN``; ``None`` = unknown (combined start tree).

        The outcome has ``P(miss | x)``; a detected outcome comes from a detected tuple picked with
        probability proportional to its relevance weight, then ``z ~ N(z_i, diag(h^2))``. With
        ``miss_prior = 0`` this is exactly the seed's pick-any-tuple sampler. ``source`` is -1 for a
        miss drawn from the ``miss_prior`` share (``"bucket"``: always; ``"ball"``: where no missed
        tuple is in reach). Identical states in a large batch share one neighbour/bucket search.
        """
        self._check_fitted()
        check_states(corners if prev_z is None else np.column_stack([np.atleast_2d(corners), prev_z]), rng=rng)
        corners = np.atleast_2d(np.asarray(corners, dtype=np.float64))
        n = corners.shape[0]
        if n == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
        prev = self._to_model_frame(_as_prev(None if not self.use_prev else prev_z, n), corners)
        grp = self._route(prev, new_track)
        ex = self._extra_query(extra, n)
        bucket = self.sampler == "bucket" or (self.sampler == "auto" and self._auto_bucket)
        if self.k_max is None and bucket and ex.shape[1] == 0:
            miss, src = self._draw_bucket(corners, prev, rng, grp)
        else:
            miss, src = self._draw_ball(corners, prev, rng, ex, grp)
        h = self.bandwidth(corners, start=grp != GROUP_MAIN)
        noise = rng.standard_normal((n, 2))
        if self.tail_weight > 0:  # the tail component: drawn after the offsets, so w = 0 draws as before
            noise *= np.where(rng.random(n) < self.tail_weight, self.tail_scale, 1.0)[:, None]
        z = np.where(miss[:, None], np.nan, self.z_[np.maximum(src, 0)] + h * noise)
        return self._to_sensor_frame(z, corners), src

    def _draw_ball(
        self,
        corners: NDArray,
        prev: NDArray,
        rng: np.random.Generator,
        extra: NDArray | None = None,
        grp: NDArray | None = None,
    ) -> tuple[NDArray, NDArray]:
        """Reference sampler (``sampler="ball"``): full ball query, outcome, then tuple; ``(miss, source)``."""
        n = corners.shape[0]
        ex = self._extra_query(extra, n)
        grp = self._route(prev, None) if grp is None else grp
        rep, inv = _unique_states(corners, np.concatenate([prev, ex, grp[:, None].astype(np.float64)], axis=1))
        gi, w, q, p_miss = self._outcome(corners[rep], prev[rep], ex[rep], grp[rep])
        miss = rng.random(n) < p_miss[inv]
        miss_t = self.miss_[gi]
        if rep.size == n:  # one group per query: pick among the tuples of the drawn outcome at once
            src = self._pick(gi, w * (miss_t == miss[rep][q]), q, inv, rng)
        else:
            src = np.where(miss, self._pick(gi, w * miss_t, q, inv, rng), self._pick(gi, w * ~miss_t, q, inv, rng))
        lost = ~miss & (src < 0)
        if lost.any():
            src[lost] = self._nearest_detected(corners[lost])
        return miss, src

    def _pick_detected_ball(
        self, corners: NDArray, prev: NDArray, rng: np.random.Generator, grp: NDArray
    ) -> NDArray[np.int64]:
        """A detected tuple with probability ``w_i / sum_{detected} w`` (reference search), per query."""
        gi, w, q = self._neighbours(corners, prev, None, grp)
        src = self._pick(gi, w * ~self.miss_[gi], q, np.arange(corners.shape[0]), rng)
        lost = src < 0
        if lost.any():
            src[lost] = self._nearest_detected(corners[lost])
        return src

    def _draw_bucket(
        self, corners: NDArray, prev: NDArray, rng: np.random.Generator, grp: NDArray
    ) -> tuple[NDArray, NDArray]:
        """Exact bucket-rejection sampler (``sampler="bucket"``), same distribution as :meth:`_draw_ball`.

        One proposal stage picks tuple ``i`` with probability ``w_i / (sum w + a)`` or the ``miss_prior``
        pseudo-tuple with ``a / (sum w + a)`` (:func:`sensor_envs.radar.buckets.sample_proportional`);
        the pseudo-tuple is a miss with the log's miss rate ``m``, else a detected tuple is drawn with
        ``w_i / sum_{detected} w``. Hence ``P(miss) = (w_miss + a m) / (sum w + a)`` and, given a
        detection, tuple ``i`` has probability ``w_i / sum_{detected} w``: Eq. 10 exactly. Queries
        with an empty ball (fallback tuples), rejection give-ups and the detected-after-pseudo draws
        use the reference search.
        """
        n = corners.shape[0]
        miss, src = np.zeros(n, dtype=bool), np.full(n, -1, dtype=np.int64)
        todo, need_det = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        full = np.concatenate([self._features(corners), prev], axis=1)
        for g, node in enumerate(self._groups):
            qi = np.flatnonzero(grp == g)
            if qi.size == 0 or node is None or node.buckets is None:  # no queries, or a grid too large for memory
                todo[qi] = True
                continue
            tree, buckets, idx_map, rate = node.tree, node.buckets, node.idx, node.rate
            d = 4 if g == GROUP_MAIN else 2
            qs = full[qi, :d] / self.scale_[:d]
            rep, inv = _unique_rows(qs)
            pick, done, via = sample_proportional(
                buckets, qs[rep], self.miss_prior, rng, allowed=~buckets.flag, pseudo_stop=rate, inv=inv
            )
            if via.any():  # the pseudo-tuple is only right when the ball holds a tuple (else: fallback_k)
                near, _ = tree.query(qs[via], k=1, distance_upper_bound=self.radius)
                empty = np.flatnonzero(via)[~np.isfinite(near)]
                done[empty], via[empty] = False, False
            todo[qi[~done & ~via]] = True
            need_det[qi[~done & via]] = True
            tup = done & (pick >= 0)
            src[qi[tup]] = idx_map[pick[tup]]
            miss[qi[done]] = np.where(tup[done], self.miss_[idx_map[np.maximum(pick[done], 0)]], True)
        if todo.any():
            miss[todo], src[todo] = self._draw_ball(corners[todo], prev[todo], rng, None, grp[todo])
        if need_det.any():  # pseudo-tuple drawn as a detection, rejection gave up: reference pick
            src[need_det] = self._pick_detected_ball(corners[need_det], prev[need_det], rng, grp[need_det])
        return miss, src

    def sample_clutter(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Clutter of one cycle, ``(m, 2)`` sensor-frame positions [m] (empirical count and positions)."""
        self._check_fitted()
        m = int(rng.choice(self.clutter_counts_)) if self.clutter_counts_.size else 0
        if m == 0 or self.clutter_xy_.shape[0] == 0:
            return np.zeros((0, 2))
        xy = self.clutter_xy_[rng.integers(0, self.clutter_xy_.shape[0], m)]
        return xy + self.clutter_jitter * rng.standard_normal((m, 2))

    def log_prob(
        self, z: NDArray, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> NDArray[np.float64]:
        """Log-probability of outcomes under the truncated-kernel density (the seed's Eq. 10).

        Args:
            z: ``(n, 2)`` outputs [m]; a ``NaN`` row is a miss and scores ``log P(miss | x)``.
            state: ``(n, 2)`` or ``(n, 4)`` as in :meth:`sample`.
            extra: ``(n, E)`` values of the extra state variables (required when the model has any).
            new_track: ``(n,)`` new-track flags as in :meth:`sample` (``None`` = unknown).

        Returns:
            ``(n,)``: ``log(1 - P(miss | x)) + log p(z | x, detected)`` [log 1/m^2] for detections,
            ``log P(miss | x)`` for misses.
        """
        self._check_fitted()
        check_states(state, z)
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        n = st.shape[0]
        if n > LOG_PROB_CHUNK:  # bounded memory: every (query, tuple) pair of a chunk is held at once
            ex = None if extra is None else np.atleast_2d(np.asarray(extra, dtype=np.float64))
            nt = None if new_track is None else np.asarray(new_track)
            return np.concatenate(
                [
                    self.log_prob(
                        z[a : a + LOG_PROB_CHUNK],
                        st[a : a + LOG_PROB_CHUNK],
                        None if ex is None else ex[a : a + LOG_PROB_CHUNK],
                        None if nt is None else nt[a : a + LOG_PROB_CHUNK],
                    )
                    for a in range(0, n, LOG_PROB_CHUNK)  # one iteration per chunk of rows
                ]
            )
        st, z = self._model_state(st), self._to_model_frame(z, st[:, :2])
        prev = st[:, 2:4] if (st.shape[1] == 4 and self.use_prev) else None
        grp = self._route(_as_prev(prev, n), new_track)
        gi, w, q, p_miss = self._outcome(st[:, :2], prev, self._extra_query(extra, n), grp)
        gi, w, q = self._with_detected_fallback(gi, w, q, st[:, :2])
        h = self.bandwidth(st[:, :2], start=grp != GROUP_MAIN)
        dens = self._log_density(z, gi, w, q, h)
        if self.tail_weight > 0:  # the defensive mixture: the same tuples, a share w of c-times wider kernels
            wide = self._log_density(z, gi, w, q, h * self.tail_scale)
            with np.errstate(invalid="ignore"):  # a miss row: -inf in both parts
                dens = np.logaddexp(np.log1p(-self.tail_weight) + dens, np.log(self.tail_weight) + wide)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.isnan(z[:, 0]), np.log(p_miss), np.log1p(-p_miss) + dens)

    def _log_density(self, z: NDArray, gi: NDArray, w: NDArray, q: NDArray, h: NDArray) -> NDArray[np.float64]:
        """``log p(z | x, detected)`` ``(n,)`` of one kernel mixture: neighbours ``(gi, w, q)``, bandwidths ``h``.

        Model-frame outputs ``z (n, 2)`` [m]; ``-inf`` for a ``NaN`` row (a miss).
        """
        n = z.shape[0]
        det_t = ~self.miss_[gi]
        r = (z[q] - np.where(det_t[:, None], self.z_[gi], 0.0)) / h[q]
        logk = -0.5 * np.sum(r**2, axis=1) - _LOG_2PI - np.log(h[q]).sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            logk = np.where(det_t & ~np.isnan(z[q, 0]), logk + np.log(w), -np.inf)
            log_wdet = np.log(np.bincount(q, weights=w * det_t, minlength=n))
            return _group_logsumexp(logk, q, n) - log_wdet

    def _with_detected_fallback(
        self, gi: NDArray, w: NDArray, q: NDArray, corners: NDArray
    ) -> tuple[NDArray, NDArray, NDArray]:
        """Add the nearest detected tuple (weight 1) to queries without a detected neighbour."""
        n = corners.shape[0]
        none = np.bincount(q, weights=(~self.miss_[gi]).astype(np.float64), minlength=n) == 0
        if not none.any():
            return gi, w, q
        e = np.flatnonzero(none)
        gi, w, q = (
            np.concatenate([gi, self._nearest_detected(corners[e])]),
            np.concatenate([w, np.ones(e.size)]),
            np.concatenate([q, e]),
        )
        order = np.argsort(q, kind="stable")
        return gi[order], w[order], q[order]

    def bin_probabilities(
        self,
        state: NDArray,
        edges_x: NDArray,
        edges_y: NDArray,
        extra: NDArray | None = None,
        new_track: NDArray | None = None,
    ) -> tuple[NDArray[np.float64], float]:
        """Exact probability of each output bin for ONE state (for the chi-square check).

        The bins are along the axes of ``output_frame`` (where the kernels are axis-aligned Gaussians):
        sensor x, y, or the corner's radial and outward cross-range; :meth:`to_output_frame` puts
        sensor-frame samples on the same axes.

        Args:
            state: ``(2,)``/``(4,)`` state as in :meth:`sample` [m] (previous output in the sensor frame).
            edges_x: bin edges [m] of the output's first component (``z_x``, or radial).
            edges_y: bin edges [m] of the second (``z_y``, or outward cross-range).
            extra: ``(1, E)`` extra state values (required when the model has any).
            new_track: ``(1,)`` new-track flag as in :meth:`sample` (``None`` = unknown).

        Returns:
            ``(len(edges_x) - 1, len(edges_y) - 1)`` bin probabilities and ``P(miss)``.
        """
        self._check_fitted()
        st = self._model_state(np.atleast_2d(np.asarray(state, dtype=np.float64))[:1])
        prev = st[:, 2:4] if (st.shape[1] == 4 and self.use_prev) else None
        grp = self._route(_as_prev(prev, 1), new_track)
        gi, w, q, p_miss = self._outcome(st[:, :2], prev, self._extra_query(extra, 1), grp)
        gi, w, _ = self._with_detected_fallback(gi, w, q, st[:, :2])
        h = self.bandwidth(st[:, :2], start=grp != GROUP_MAIN)[0]
        det = ~self.miss_[gi]
        zi, wd = self.z_[gi[det]], w[det] / w[det].sum()
        ex, ey = np.asarray(edges_x)[None, :], np.asarray(edges_y)[None, :]
        p = np.zeros((ex.size - 1, ey.size - 1))
        parts = ((1.0 - self.tail_weight, 1.0), (self.tail_weight, self.tail_scale))
        for share, c in parts if self.tail_weight > 0 else parts[:1]:  # the main kernels, then the tail's
            px = np.diff(ndtr((ex - zi[:, :1]) / (c * h[0])), axis=1)
            py = np.diff(ndtr((ey - zi[:, 1:]) / (c * h[1])), axis=1)
            p += share * np.einsum("i,ia,ib->ab", wd, px, py)
        return (1.0 - p_miss[0]) * p, float(p_miss[0])

    # ------------------------------------------------------------------ files
    def with_bandwidth_scale(self, factor: float) -> KDERadarModel:
        """A copy whose contribution bandwidths are ``factor`` times this model's (``bandwidth_scale`` too).

        The same model as fitting with ``bandwidth_scale`` multiplied by ``factor`` (the factor is applied
        after the bandwidth CV, and no random draw of :meth:`fit` depends on it).
        """
        import copy

        self._check_fitted()
        check = {"bandwidth_scale": self._parameter_constraints["bandwidth_scale"]}
        for value in (factor, self.bandwidth_scale * factor):  # the factor, and the model's factor after it
            validate_params({"bandwidth_scale": value}, check)
        out = copy.deepcopy(self)
        out.bandwidth_scale = float(self.bandwidth_scale * factor)
        out.log_h_ = self.log_h_ + np.log(factor)
        return out

    def with_start_bandwidth_scale(self, value: float | None) -> KDERadarModel:
        """A copy with ``start_bandwidth_scale = value``: the same model as a fit with it.

        ``value`` is the start trees' factor on the CV table (``None``: ``bandwidth_scale``'s); the main trees
        are unchanged.
        """
        import copy

        self._check_fitted()
        validate_params({"start_bandwidth_scale": value}, self._parameter_constraints)
        out = copy.deepcopy(self)
        out.start_bandwidth_scale = None if value is None else float(value)
        return out

    def with_tail(self, weight: float, scale: float) -> KDERadarModel:
        """A copy with the tail mixture ``tail_weight = weight``, ``tail_scale = scale`` (checked).

        The same model as a fit with them: the pair acts only at :meth:`sample`/:meth:`log_prob` time, and no
        random draw of :meth:`fit` depends on it.
        """
        import copy

        self._check_fitted()
        validate_params({"tail_weight": weight, "tail_scale": scale}, self._parameter_constraints)
        out = copy.deepcopy(self)
        out.tail_weight, out.tail_scale = float(weight), float(scale)
        return out

    def _to_file(self) -> tuple[Header, Arrays]:
        """Header and arrays of the current format (:class:`~sensor_envs.sensor_model.SensorModel`)."""
        params = self._saved_params(self, skip=("cv_candidates",))  # the candidates are stored as an array
        params["rel_variance"] = [float(v) for v in self.rel_variance]
        params["relevance_candidates"] = [float(v) for v in self.relevance_candidates]
        params["extra_state"] = [str(v) for v in self.extra_state_]
        params["extra_variance"] = None if self.extra_variance is None else [float(v) for v in self.extra_variance]
        params["extra_candidates"] = [float(v) for v in self.extra_candidates]
        params["relevance_candidates_azimuth"] = [float(v) for v in self.relevance_candidates_azimuth]
        params["relevance_candidates_prev"] = [float(v) for v in self.relevance_candidates_prev]
        header = {
            "params": params,
            "cycle_time": self.cycle_time_,
            "rel_variance_fitted": list(self.rel_variance_),
            "relevance_scores": [float(v) for v in self.relevance_scores_],
            "state_variables": list(self.state_variables),
            "extra_variance_fitted": [float(v) for v in self.extra_variance_],
            "extra_fill": [float(v) for v in self.extra_fill_],
            "new_track_flags": self.new_track_ is not None,
            "azimuth_bias_fitted": float(self.azimuth_bias_),
        }
        arrays = {
            "states": self.states_,
            "z": self.z_,
            "log_row": self.log_row_,
            "grid_x": self.grid_x_,
            "grid_y": self.grid_y_,
            "log_h": self.log_h_,
            "cv_counts": self.cv_counts_,
            "cv_candidates": self.cand_,
            "clutter_counts": self.clutter_counts_,
            "clutter_xy": self.clutter_xy_,
            "extra": self.extra_,
        }
        if self.new_track_ is not None:
            arrays["new_track"] = self.new_track_.astype(np.uint8)
        return header, arrays

    @classmethod
    def _from_file(cls, path: Path, header: Header, arrays: Arrays) -> KDERadarModel:
        """The model of a current-format file (values checked; trees rebuilt here)."""
        a = arrays
        model = cls(**cls._params_from(path, header, not_saved=("cv_candidates",)))
        _check_arrays(path, a)
        model.states_, model.z_, model.log_row_ = a["states"], a["z"], a["log_row"].astype(np.int64)
        model.grid_x_, model.grid_y_, model.log_h_ = a["grid_x"], a["grid_y"], a["log_h"]
        model.cv_counts_, model.cand_ = a["cv_counts"].astype(np.int64), a["cv_candidates"]
        model.cv_candidates = tuple(float(c) for c in model.cand_)
        model.clutter_counts_, model.clutter_xy_ = a["clutter_counts"].astype(np.int64), a["clutter_xy"]
        rv = header.get("rel_variance_fitted", model.rel_variance)
        check_shape(path, "rel_variance_fitted", rv, (4,))
        model.rel_variance_ = tuple(float(v) for v in check_positive(path, "rel_variance_fitted", rv, MAX_POSITION**2))
        model.relevance_scores_ = np.asarray(header.get("relevance_scores", []), dtype=np.float64)
        model.scale_ = np.sqrt(np.asarray(model.rel_variance_, dtype=np.float64))
        model.cycle_time_ = optional_positive(path, "cycle_time", header.get("cycle_time"))
        model.azimuth_bias_ = _load_azimuth_bias(header, path, model.azimuth_bias)
        _load_extra(model, header, a, path)
        model.new_track_ = _load_new_track(header, a, path, model.states_)
        model._build()
        return model


# ------------------------------------------------------------------------------- format upgrades
def _upgrade_1(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 1 matched misses against the log's overall miss rate (``prior_rate="global"``)."""
    set_param_defaults(header, prior_rate="global")


def _upgrade_2(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 2 has no extra state."""
    set_param_defaults(header, extra_state=[], extra_variance=None, extra_candidates=[0.25, 0.5, 1.0, 2.0])
    n = arrays["states"].shape[0]
    if "extra" not in arrays:
        arrays["extra"] = np.zeros((n, 0))
    header.setdefault("extra_variance_fitted", [])
    header.setdefault("extra_fill", [])


def _upgrade_3(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 3 has no per-tuple new-track flags (one combined start tree)."""
    if "new_track" in arrays:
        raise ModelFileError(f"{path}: field 'new_track' is present but 'new_track_flags' is not true")
    header["new_track_flags"] = False


def _upgrade_4(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 4 has cartesian corner features."""
    set_param_defaults(header, state_transform="cartesian", relevance_candidates_azimuth=list(AZIMUTH_CANDIDATES))


def _upgrade_5(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 5 stores sensor-frame outputs."""
    set_param_defaults(header, output_frame="cartesian")


def _upgrade_6(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 6 has no mounting yaw error and one bandwidth factor."""
    set_param_defaults(header, azimuth_bias=0.0, start_bandwidth_scale=None)
    header["azimuth_bias_fitted"] = 0.0


def _upgrade_7(path: Path, header: Header, arrays: Arrays) -> None:
    """Format 7 has no tail mixture."""
    set_param_defaults(header, tail_weight=0.0, tail_scale=4.0)


KDERadarModel._UPGRADES = {
    1: _upgrade_1,
    2: _upgrade_2,
    3: _upgrade_3,
    4: _upgrade_4,
    5: _upgrade_5,
    6: _upgrade_6,
    7: _upgrade_7,
}


def _check_arrays(path: str | os.PathLike[str], a: dict[str, NDArray[Any]]) -> None:
    """Sane VALUES and consistent lengths of a KDE model file's arrays (not only their format).

    Raises:
        ModelFileError: naming the file and the field.
    """
    n = a["states"].shape[0]
    check_shape(path, "states", a["states"], (n, 4))
    check_shape(path, "z", a["z"], (n, 2))
    check_shape(path, "log_row", a["log_row"], (n,))
    check_range(path, "states", a["states"][:, :2], -MAX_POSITION, MAX_POSITION)  # corners: always present
    prev, z = a["states"][:, 2:], a["z"]
    for field, v in (("states", prev), ("z", z)):  # NaN rows: no previous output / a miss, both coordinates
        gone = np.isnan(v)
        if (gone[:, 0] != gone[:, 1]).any():
            raise ModelFileError(f"{path}: field {field!r} has rows with one NaN coordinate")
        check_range(path, field, v[~gone[:, 0]], -MAX_POSITION, MAX_POSITION)
    if (~np.isnan(z[:, 0])).sum() < 2:
        raise ModelFileError(f"{path}: field 'z' holds fewer than 2 detected tuples")
    check_range(path, "log_row", a["log_row"], 0, None)
    gx = check_increasing(path, "grid_x", a["grid_x"], min_size=1, regular=True)
    gy = check_increasing(path, "grid_y", a["grid_y"], min_size=1, regular=True)
    check_range(path, "grid_x", gx, -MAX_POSITION, MAX_POSITION)
    check_range(path, "grid_y", gy, -MAX_POSITION, MAX_POSITION)
    check_shape(path, "log_h", a["log_h"], (gx.size, gy.size, 2))
    check_range(path, "log_h", a["log_h"], np.log(1e-6), np.log(MAX_POSITION))  # bandwidths 1 um .. 1 km
    check_shape(path, "cv_counts", a["cv_counts"], (gx.size, gy.size))
    check_range(path, "cv_counts", a["cv_counts"], 0, None)
    if a["cv_candidates"].size == 0:
        raise ModelFileError(f"{path}: field 'cv_candidates' is empty")
    check_positive(path, "cv_candidates", a["cv_candidates"], MAX_POSITION)
    check_range(path, "clutter_counts", a["clutter_counts"], 0, 1e6)
    check_shape(path, "clutter_xy", a["clutter_xy"], (a["clutter_xy"].shape[0], 2))
    check_range(path, "clutter_xy", a["clutter_xy"], -MAX_POSITION, MAX_POSITION)
    check_finite(path, "cv_candidates", a["cv_candidates"])


def _load_azimuth_bias(header: dict[str, Any], path: Any, given: float | str) -> float:
    """The fitted mounting yaw error [rad] of a current-format file, checked finite and within bounds.

    Raises:
        ModelFileError: naming the file and the field ``azimuth_bias_fitted`` (missing from a format-7 file,
            not a finite number within ``+-MAX_AZIMUTH_BIAS``, or unlike a given ``params.azimuth_bias``).
    """
    if "azimuth_bias_fitted" not in header:
        raise ModelFileError(f"{path}: field 'azimuth_bias_fitted' is missing")
    raw = header["azimuth_bias_fitted"]
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise ModelFileError(f"{path}: field 'azimuth_bias_fitted' must be an angle [rad], got {raw!r}")
    b = float(check_range(path, "azimuth_bias_fitted", raw, -MAX_AZIMUTH_BIAS, MAX_AZIMUTH_BIAS))
    if given != "fit" and b != float(given):
        raise ModelFileError(f"{path}: field 'azimuth_bias_fitted' ({b}) differs from 'params.azimuth_bias' ({given})")
    return b


def _load_new_track(
    header: dict[str, Any], a: dict[str, NDArray[Any]], path: Any, states: NDArray
) -> NDArray[np.bool_] | None:
    """The per-tuple new-track flags of a current-format file (``None``: saved without them).

    Raises:
        ModelFileError: when the flags are announced but missing, not ``n`` values in {0, 1}, or flag a
            tuple that has a previous output (a new track has none).
    """
    announced = header.get("new_track_flags", False)
    if not isinstance(announced, bool):
        raise ModelFileError(f"{path}: field 'new_track_flags' must be true or false")
    if not announced:
        if "new_track" in a:
            raise ModelFileError(f"{path}: field 'new_track' is present but 'new_track_flags' is not true")
        return None
    if "new_track" not in a:
        raise ModelFileError(f"{path}: field 'new_track' is missing")
    f = a["new_track"]
    if f.dtype.kind not in "ub" or f.shape != (states.shape[0],):
        raise ModelFileError(
            f"{path}: field 'new_track' must be {states.shape[0]} unsigned flags, got {f.dtype} {f.shape}"
        )
    if not np.isin(f, (0, 1)).all():
        raise ModelFileError(f"{path}: field 'new_track' holds values other than 0 and 1")
    flags = f.astype(bool)
    if (flags & ~np.isnan(states[:, 2])).any():
        raise ModelFileError(f"{path}: field 'new_track' flags a tuple that has a previous output")
    return flags


def _check_extra_params(names: Any, variance: Any, candidates: Any) -> None:
    """Validate the ``extra_*`` hyperparameters (raises ValueError naming the parameter)."""
    if isinstance(names, str) or not all(isinstance(n, str) and n for n in names):
        raise InputError(f"extra_state must be a tuple of column names, got {names!r}")
    if len(set(names)) != len(names):
        raise InputError(f"extra_state has duplicate names: {names!r}")
    if variance is not None:
        v = np.asarray(variance, dtype=np.float64)
        if v.shape != (len(names),) or not (np.isnan(v) | (np.isfinite(v) & (v > 0))).all():
            raise InputError(
                f"extra_variance must be {len(names)} positive variances (NaN = by CV) or None, got {variance!r}"
            )
    c = np.asarray(candidates, dtype=np.float64)
    if c.ndim != 1 or c.size == 0 or not (np.isfinite(c).all() and (c > 0).all()):
        raise InputError(f"extra_candidates must be positive factors, got {candidates!r}")


def _load_extra(model: KDERadarModel, header: dict[str, Any], a: dict[str, NDArray], path: Any) -> None:
    """Restore and check the extra state of a loaded model."""
    names = tuple(str(v) for v in header.get("params", {}).get("extra_state", ()) or ())
    n = model.states_.shape[0]
    if "extra" not in a:
        raise ModelFileError(f"{path}: field 'extra' is missing")
    extra = np.asarray(a["extra"])
    if extra.dtype.kind != "f" or extra.ndim != 2:
        raise ModelFileError(f"{path}: field 'extra' must be a 2-D float array")
    var = np.asarray(header.get("extra_variance_fitted", []), dtype=np.float64)
    fill = np.asarray(header.get("extra_fill", []), dtype=np.float64)
    if extra.shape != (n, len(names)) or var.shape != (len(names),) or fill.shape != (len(names),):
        raise ModelFileError(f"{path}: field 'extra' does not match the {len(names)} names of 'extra_state'")
    if not (np.isfinite(extra).all() and np.isfinite(var).all() and (var > 0).all() and np.isfinite(fill).all()):
        raise ModelFileError(f"{path}: field 'extra'/'extra_variance_fitted' must be finite (variances > 0)")
    model.extra_state_, model.extra_ = names, extra
    model.extra_variance_, model.extra_fill_ = tuple(float(v) for v in var), fill
    model.extra_scale_ = np.sqrt(var)


def _as_prev(prev_z: NDArray | None, n: int) -> NDArray[np.float64]:
    """Previous outputs ``(n, 2)`` [m] (``None`` = all missing); ``ValueError`` on a wrong shape."""
    if prev_z is None:
        return np.full((n, 2), np.nan)
    prev = np.atleast_2d(np.asarray(prev_z, dtype=np.float64))
    if prev.shape != (n, 2):
        raise InputError(f"prev_z must be ({n}, 2) like corners; got {prev.shape}")
    return prev


def _unique_states(corners: NDArray, prev: NDArray, min_n: int = 64) -> tuple[NDArray, NDArray]:
    """Representative rows and inverse map of identical query states (only for batches >= ``min_n``)."""
    return _unique_rows(np.nan_to_num(np.concatenate([corners, prev], axis=1), nan=1e300), min_n)


def _unique_rows(a: NDArray, min_n: int = 64) -> tuple[NDArray, NDArray]:
    """Representative rows and inverse map of identical rows of ``a`` (only for batches >= ``min_n``)."""
    n = a.shape[0]
    if n < min_n:
        return np.arange(n), np.arange(n)
    _, rep, inv = np.unique(a, axis=0, return_index=True, return_inverse=True)
    return rep, inv.ravel()


def _cv_groups(tt: TargetTuples, kind: str) -> NDArray[np.int64]:
    """CV group id of every tuple: its track, its sequence, or itself."""
    if kind == "row":
        return np.arange(tt.z.shape[0])
    key = np.stack([tt.sequence, tt.target], axis=1) if kind == "track" else tt.sequence[:, None]
    return np.unique(key, axis=0, return_inverse=True)[1].ravel().astype(np.int64)


def _group_logsumexp(values: NDArray, groups: NDArray, n: int) -> NDArray[np.float64]:
    """``logsumexp`` of ``values`` within each of ``n`` sorted groups (empty/-inf groups give -inf)."""
    out = np.full(n, -np.inf)
    if values.size == 0:
        return out
    mx = np.full(n, -np.inf)
    np.maximum.at(mx, groups, values)
    safe = np.where(np.isfinite(mx), mx, 0.0)
    s = np.bincount(groups, weights=np.exp(values - safe[groups]), minlength=n)
    with np.errstate(divide="ignore"):
        out = np.where(s > 0, np.log(s) + safe, -np.inf)
    return out
