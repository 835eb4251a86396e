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
buckets (:mod:`sensor_envs.radar.buckets`, :func:`sensor_envs.radar.kde_samplers.draw_bucket`), at a cost that
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
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from sensor_envs.modelio import Constraint
from sensor_envs.radar import kde_density, kde_frames, kde_params, kde_samplers, kde_trees
from sensor_envs.radar.gaussian import GaussianRadar, baseline_file
from sensor_envs.radar.kde_bandwidth import corner_features, cv_bandwidth_table, relevance_features
from sensor_envs.radar.kde_fit import fit_model
from sensor_envs.radar.kde_io import ARRAY_SCHEMA, UPGRADES, from_file, to_file
from sensor_envs.radar.kde_params import (
    AUTO_BUCKET_MIN_NEIGHBOURS,
    AZIMUTH_CANDIDATES,
    CV_RELEVANCE,
    GROUP_LOST,
    GROUP_MAIN,
    GROUP_NEW,
    GROUP_START,
    HEADER_SCHEMA,
    KDE_PARAMETERS,
    LOG_PROB_CHUNK,
    MAX_CLUTTER_POSITIONS,
    MAX_POSITION,
    MAX_TAIL_SCALE,
    MAX_TAIL_WEIGHT,
    OUTPUT_FRAMES,
    PREV_CANDIDATES,
    STATE_TRANSFORMS,
    check_extra_params,
)
from sensor_envs.radar.log import RadarLog, check_states
from sensor_envs.sensor_model import Arrays, Header, SensorModel

__all__ = [
    "KDERadarModel",
    "corner_features",
    "relevance_features",
    "cv_bandwidth_table",
    "KIND",
    "FORMAT_VERSION",
    "CV_RELEVANCE",
    "STATE_TRANSFORMS",
    "OUTPUT_FRAMES",
    "AZIMUTH_CANDIDATES",
    "PREV_CANDIDATES",
    "LOG_PROB_CHUNK",
    "AUTO_BUCKET_MIN_NEIGHBOURS",
    "MAX_POSITION",
    "MAX_CLUTTER_POSITIONS",
    "MAX_TAIL_WEIGHT",
    "MAX_TAIL_SCALE",
    "GROUP_MAIN",
    "GROUP_START",
    "GROUP_NEW",
    "GROUP_LOST",
]

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
        random_state: seed (default 0, as every sensor model), generator or ``None`` (fresh entropy) for the CV
            subsampling and the clutter subsample.
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
    CAPABILITIES = frozenset(
        {"new_track", "extra_state", "prev_output", "log_prob", "clutter", "output_frame", "bin_probabilities"}
    )
    _FITTED = "states_"
    _SCHEMA = ARRAY_SCHEMA
    _PARAM_DEFAULTS: ClassVar[dict[str, Any]] = {  # files written before the factors and the prev CV
        "relevance_candidates_prev": PREV_CANDIDATES,
        "bandwidth_scale": 1.0,
    }
    _parameter_constraints: ClassVar[dict[str, list[Constraint]]] = KDE_PARAMETERS
    _HEADER_SCHEMA: ClassVar[dict[str, list[Constraint]] | None] = HEADER_SCHEMA
    _UPGRADES = UPGRADES

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
        random_state: int | np.random.Generator | None = 0,
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

    def _check_params_relations(self, source: str | os.PathLike[str] | None) -> None:
        """The ``extra_*`` hyperparameters agree with each other (``InputError`` naming the parameter)."""
        check_extra_params(self.extra_state, self.extra_variance, self.extra_candidates)

    def fit(self, log: RadarLog, cycle_time: float | None = None, progress: bool | None = None) -> KDERadarModel:
        """Fit on a radar log: store the tuples, build the trees, run the LOO-CV bandwidth table.

        Args:
            log: the radar object log.
            cycle_time: seconds between consecutive frames of the log (stored in the model file).
            progress: deprecated; the ``verbose`` hyperparameter.

        Returns:
            self.
        """
        return fit_model(self, log, cycle_time, progress)

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
        check_states(state, rng=rng, extra=extra, new_track=new_track, extra_names=self.extra_state_)
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        prev = st[:, 2:4] if (st.shape[1] == 4 and self.use_prev) else None
        return self.sample_cycle(st[:, :2], prev, rng, extra=extra, new_track=new_track)

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
        return kde_samplers.sample_cycle(self, corners, prev_z, rng, extra, new_track)

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
        return kde_density.log_prob(self, z, state, extra, new_track)

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
        return kde_density.bin_probabilities(self, state, edges_x, edges_y, extra, new_track)

    def mean_output(
        self, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> tuple[NDArray, NDArray]:
        """Expected output given a detection ``(n, 2)`` [m] and ``P(miss)`` ``(n,)`` (arguments as :meth:`log_prob`)."""
        return kde_density.mean_output(self, state, extra, new_track)

    def bandwidth(self, corners: NDArray, start: NDArray | bool = False) -> NDArray[np.float64]:
        """Output bandwidths ``(n, 2)`` [m] interpolated from the CV table at ``corners (n, 2)`` [m].

        Along the axes of ``output_frame``: sensor x, y, or the corner's radial and outward cross-range.
        ``start`` (one flag, or one per corner): the bandwidths of a start-tree query (no ``z_{t-1}``), the
        table times ``start_bandwidth_scale`` instead of ``bandwidth_scale``.
        """
        return kde_trees.bandwidth(self, corners, start)

    def to_output_frame(self, z: NDArray, corners: NDArray) -> NDArray[np.float64]:
        """Sensor-frame offsets ``z (n, 2)`` [m] at ``corners (n, 2)`` on the axes of ``output_frame``.

        The axes :meth:`bin_probabilities` and :meth:`bandwidth` refer to, after the mounting yaw error
        ``azimuth_bias_`` is undone (identity for ``"cartesian"`` without one).
        """
        return kde_frames.to_output_frame(self, z, corners)

    @property
    def state_variables(self) -> tuple[str, ...]:
        """Names of the state dimensions: corner, previous output, then the extra state."""
        self._check_fitted()
        return ("corner_x", "corner_y", "prev_z_x", "prev_z_y", *self.extra_state_)

    def with_bandwidth_scale(self, factor: float) -> KDERadarModel:
        """A copy whose contribution bandwidths are ``factor`` times this model's (``bandwidth_scale`` too).

        The same model as fitting with ``bandwidth_scale`` multiplied by ``factor`` (the factor is applied
        after the bandwidth CV, and no random draw of :meth:`fit` depends on it).
        """
        self._check_fitted()
        return kde_params.scaled_copy(self, factor)

    def with_start_bandwidth_scale(self, value: float | None) -> KDERadarModel:
        """A copy with ``start_bandwidth_scale = value``: the same model as a fit with it.

        ``value`` is the start trees' factor on the CV table (``None``: ``bandwidth_scale``'s); the main trees
        are unchanged.
        """
        self._check_fitted()
        return kde_params.start_scaled_copy(self, value)

    def with_tail(self, weight: float, scale: float) -> KDERadarModel:
        """A copy with the tail mixture ``tail_weight = weight``, ``tail_scale = scale`` (checked).

        The same model as a fit with them: the pair acts only at :meth:`sample`/:meth:`log_prob` time, and no
        random draw of :meth:`fit` depends on it.
        """
        self._check_fitted()
        return kde_params.tail_copy(self, weight, scale)

    def baseline(self) -> GaussianRadar | None:
        """The Gaussian baseline fitted with this model (:meth:`SensorModel.baseline`), or ``None``.

        The file beside the one this model was loaded from (:func:`~sensor_envs.radar.gaussian.baseline_file`).
        """
        base = None if self._file is None else baseline_file(self._file)
        return GaussianRadar.load(base) if base is not None and base.is_file() else None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for key in ("_main_tree", "_start_tree", "_det_tree", "_main_buckets", "_start_buckets", "_groups"):
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if hasattr(self, "states_"):
            kde_trees.build_trees(self)

    def _to_file(self) -> tuple[Header, Arrays]:
        """Header and arrays of the current format (:mod:`sensor_envs.radar.kde_io`)."""
        return to_file(self)

    @classmethod
    def _from_file(cls, path: Path, header: Header, arrays: Arrays) -> KDERadarModel:
        """The model of a current-format file (values checked; trees rebuilt here)."""
        return from_file(cls(**cls._params_from(path, header, not_saved=("cv_candidates",))), path, header, arrays)
