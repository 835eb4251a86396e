"""The lidar side of ``sensor-envs diagnose``: :class:`LidarAdapter` for the learned lidar on scan logs.

Readings are the (scan, bearing) readings of a scan log ``(S, K, 1)`` on rays that hit the map.
Blocks are ``block_scans`` consecutive scans (:func:`lidar_blocks`); the held-out part is whole blocks.

Residuals of a fitted model on the held-out part:

* ``null``: ``1{null} - p_null``;
* ``range``: ``x - mu`` [m] of non-null in-range readings (NaN otherwise; spurious far returns
  ``> spur_above`` excluded), clipped to +-1 m;
* ``pit``: the reading's PIT under the model minus 0.5 (non-null readings);
* ``range_spread``: ``sqrt(|z - c|)`` with ``z = (x - mu) / sigma`` of the same readings as ``range``
  and ``c`` the scan's mean of ``z`` clipped to +-3 (kind ``spread``: an effect on the noise's scale or
  tails moves it while the mean residual stays 0; an offset shared by a scan, e.g. slow drift, does not);
* ``pit_spread``: ``|u - c|``, ``u`` the reading's PIT and ``c`` its scan's median PIT (non-null
  readings; kind ``spread``): the same on a bounded scale, for real logs whose residuals are
  heavy-tailed (map errors, moving people), where a few far readings dominate ``range_spread``.

Interaction features (the model's own state, see :mod:`sensor_envs.diagnose.search`): bearing,
nominal range, incidence and ``range_slope``, the nominal range's slope along the scan [m/rad] (an
error from a reading taken later or earlier than its bearing says, e.g. a scan smeared by the robot's
turn, follows the wall's slope: found as turn rate x ``range_slope``). A finding's form maps to state
terms (:meth:`LidarAdapter.state_terms`): a main effect to the variable itself (``<name>``, and
``<name>@sq`` for a U-shaped one), an interaction with bearing to ``<name>``, ``<name>@cos_bearing``,
``<name>@sin_bearing``, with range, incidence or range slope to ``<name>`` and ``<name>@range`` (...)
(:mod:`sensor_envs.lidar.extra_state`), each on the part the finding's metric measures
(:data:`METRIC_PARTS`: ``null`` on the null rate, ``range``/``pit`` on the bias and log sigma, the spreads on
log sigma).

Candidates: every per-scan covariate of the log by its name (``cov_omega`` as ``omega``), ``time``
(time since the first scan), ``scan`` (index, only when the log has no time), ``bearing`` (index),
``range`` and ``incidence``
(nominal, from the map) and ``prev_residual`` (the same bearing's residual from the tables' mean at the
previous scan, :mod:`sensor_envs.lidar.extra_state`). The model can take covariates, ``time`` and
``prev_residual`` into its state; ``range``, ``incidence`` and ``bearing`` are its own state (tested as
``state_misfit``); ``scan`` cannot be added.

The base tables do not depend on the extra state (the extra terms are fitted after them), so they are
fitted once and each refit only adds the linear terms (:func:`~sensor_envs.lidar.extra_state.fit_extra_terms`).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.diagnose.core import FOLD_RANKS, LINEAR_FORM, Evaluation, block_split
from sensor_envs.inputs import InputError
from sensor_envs.lidar.extra_state import (
    GEOMETRY_MODIFIERS,
    PREV,
    TIME,
    fit_extra_terms,
    range_slope,
    scan_features,
    split_term,
)
from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.lwlr import LidarLWLR, lidar_features, mixture_log_prob
from sensor_envs.lidar.validate_readings import _pit

__all__ = ["LidarAdapter", "lidar_blocks", "DIAGNOSE_LIDAR_PARAMS", "DIAGNOSE_MAX_READINGS", "METRIC_PARTS"]

DIAGNOSE_LIDAR_PARAMS: dict[str, Any] = {"variant": "extended", "n_folds": 3, "random_state": 0, "verbose": False}
"""Hyperparameters of the diagnosis fits unless ``--model`` gives others (3 folds of time blocks: the
kernel-width search is the costly part of a diagnosis, its cost grows with the folds and with the
square of :data:`DIAGNOSE_MAX_READINGS`)."""
DIAGNOSE_MAX_READINGS = 240
"""Scans the table fit of ``diagnose lidar`` uses by default (evenly spaced; the held-out evaluation
and the search use every held-out reading)."""
METRIC_PARTS: dict[str, tuple[str, ...]] = {
    "null": ("null",),
    "range": ("bias", "sigma"),
    "pit": ("bias", "sigma"),
    "range_spread": ("sigma",),
    "pit_spread": ("sigma",),
}
"""The model parts (:data:`~sensor_envs.lidar.extra_state.PARTS`) a finding on each residual metric is added
to: a mean effect to the bias and to sigma (what its linear terms miss of it, e.g. a step, widens the spread
where it acts), a spread effect to sigma, a null-rate effect to p_null."""
_RENAME = {TIME: "time"}
_RANGE_CLIP = 1.0


def lidar_blocks(n_scans: int, block_scans: int = 5) -> NDArray[np.int64]:
    """Block id ``(S,)`` of each scan: ``block_scans`` consecutive scans form a block."""
    return (np.arange(n_scans) // max(int(block_scans), 1)).astype(np.int64)


def _within_scan_spread(z: NDArray[np.float64], scan: NDArray[np.int64]) -> NDArray[np.float64]:
    """``sqrt(|z - c_scan|)`` (capped at 5): the size of each standardised residual about its scan's centre.

    ``c_scan`` is the scan's mean of ``z`` clipped to +-3 (NaN readings excluded): an offset shared by a
    scan's readings (slow drift, a pose error) is not spread, so a change of the noise's scale is not
    buried under the drift's variance.
    """
    ok = np.isfinite(z)
    zc = np.where(ok, np.clip(z, -3.0, 3.0), 0.0)
    n = np.bincount(scan, weights=ok.astype(np.float64))
    centre = np.bincount(scan, weights=zc) / np.maximum(n, 1.0)
    return np.sqrt(np.minimum(np.abs(z - centre[scan]), 25.0))


def _pit_spread(pit: NDArray[np.float64], scan: NDArray[np.int64]) -> NDArray[np.float64]:
    """``|pit - c_scan|``: each reading's PIT distance from its scan's median PIT (NaN readings stay NaN).

    An offset shared by a scan's readings (slow drift, a pose error) moves the scan's PITs together and
    is not spread, so a change of the noise's scale is not buried under the drift.
    """
    ok = np.isfinite(pit)
    order = np.lexsort((np.where(ok, pit, np.inf), scan))  # by scan, then PIT, NaN last within a scan
    s_sorted = scan[order]
    start = np.flatnonzero(np.r_[True, s_sorted[1:] != s_sorted[:-1]])
    n_ok = np.add.reduceat(ok[order].astype(np.int64), start)
    p_sorted = np.where(ok, pit, 0.0)[order]
    med = 0.5 * (p_sorted[start + np.maximum(n_ok - 1, 0) // 2] + p_sorted[start + n_ok // 2])  # the finite ones'
    centre = np.zeros(int(scan.max(initial=0)) + 1)
    centre[s_sorted[start]] = med
    return np.where(ok, np.abs(pit - centre[scan]), np.nan)


class LidarAdapter:
    """Diagnosis adapter of the learned lidar (implements :class:`sensor_envs.diagnose.core.DiagnoseAdapter`).

    Args:
        log: the whole scan log (with a map).
        held_out: ``(S,)`` scans of the held-out part (whole blocks).
        blocks: ``(S,)`` block id of each scan.
        params: hyperparameters of :class:`~sensor_envs.lidar.lwlr.LidarLWLR` (extra state excluded).
        base_model: a fitted model whose tables are used instead of fitting them (``--model``).
        max_readings: rows used by the per-reading fit of the tables.
    """

    kind = "lidar"

    def __init__(
        self,
        log: LidarLog,
        held_out: NDArray[np.bool_],
        blocks: NDArray[np.int64],
        params: dict[str, Any] | None = None,
        base_model: LidarLWLR | None = None,
        max_readings: int | None = DIAGNOSE_MAX_READINGS,
    ) -> None:
        if log.ranges.shape[2] != 1:
            raise InputError(f"{log.source}: field 'ranges': diagnose lidar needs a scan log (one reading per scan)")
        self.log = log
        self.params = {k: v for k, v in {**DIAGNOSE_LIDAR_PARAMS, **(params or {})}.items() if k != "extra_state"}
        self.max_readings = max_readings
        self._given = base_model
        segs = log.require_map()
        max_range = float(base_model.max_range if base_model is not None else self.params.get("max_range", 5.0))
        self.r, self.a = lidar_features(log.poses, log.bearings, segs, max_range)
        self.slope = range_slope(self.r, log.bearings)
        self.x = log.ranges[:, :, 0]
        self.scan_blocks = np.asarray(blocks)
        self._hold(np.asarray(held_out, dtype=bool))

    def _hold(self, held: NDArray[np.bool_]) -> None:
        """Set the held-out part (scans) and what depends on it; the tables are refitted on demand."""
        self.held = held
        self.fit_log = self.log.subset(~held)
        self._base = self._given
        sel = held[:, None] & np.isfinite(self.r) & ~np.isnan(self.x)  # (S, K) held-out readings on hit rays
        self.sel = sel
        self.scan_idx, self.bearing_idx = np.nonzero(sel)
        self.blocks = self.scan_blocks[self.scan_idx].astype(np.int64)
        if self.scan_idx.size == 0:
            raise InputError(f"{self.log.source}: no held-out reading lies on a ray that hits the map")
        self._candidates = self._static_candidates()

    def other_folds(self) -> list[LidarAdapter]:
        """The same log held out on each other fold of :data:`~sensor_envs.diagnose.core.FOLD_RANKS`.

        Used by the loop's gain gate on a short log. Empty when the held-out part is not the first fold
        (a split of the caller's own) or a fold would hold no reading on a hit ray.
        """
        if not np.array_equal(self.held, block_split(self.scan_blocks)):
            return []
        out = []
        for ranks in FOLD_RANKS[1:]:
            fold = copy.copy(self)
            try:
                fold._hold(block_split(self.scan_blocks, held_ranks=ranks))
            except InputError:
                return []
            out.append(fold)
        return out

    # -- candidates -------------------------------------------------------------------------------
    def _static_candidates(self) -> dict[str, NDArray[np.float64]]:
        s, k = self.scan_idx, self.bearing_idx
        out = {name: np.asarray(v, dtype=np.float64)[s] for name, v in sorted(self.log.covariates.items())}
        if self.log.t is not None:
            out["time"] = (self.log.t - self.log.t[0])[s]
        else:  # the scan index stands for time (not addable); with ``t`` it would duplicate ``time``
            out["scan"] = s.astype(np.float64)
        out["bearing"] = k.astype(np.float64)
        out["range"] = self.r[s, k]
        out["incidence"] = np.nan_to_num(self.a[s, k])
        return out

    def state_name(self, candidate: str) -> str | None:
        """State variable that adds ``candidate``: a covariate's name, ``t`` for ``time``, ``prev_residual``."""
        if candidate == "time":
            return TIME if self.log.t is not None else None
        if candidate == PREV or candidate in self.log.covariates:
            return candidate
        return None

    def state_terms(self, candidate: str, form: str = "main") -> tuple[str, ...] | None:
        """State terms representing a finding of ``candidate`` with ``form`` (``main``, ``x bearing``, ...).

        A main effect maps to ``<var>``, ``<var>@sq`` (linear and U-shaped), its linear form
        (:data:`~sensor_envs.diagnose.core.LINEAR_FORM`) to ``<var>``; an interaction with the
        bearing to those and each times ``cos_bearing``, ``sin_bearing`` (``<var>@cos_bearing``,
        ``<var>@sq@cos_bearing``, ...); with the range, incidence or the range's slope along the scan,
        times ``range``, ``incidence`` or ``range_slope`` (:mod:`sensor_envs.lidar.extra_state`).
        ``None`` when the model cannot take it (not a state variable).
        """
        var = self.state_name(candidate)
        if var is None:
            return None
        main = (var, f"{var}@sq") if var != PREV else (var,)
        if form == "main":
            return main
        if form == LINEAR_FORM:
            return (var,)
        if form == "x bearing":
            mods: tuple[str, ...] = ("cos_bearing", "sin_bearing")
        elif form.startswith("x ") and form[2:] in GEOMETRY_MODIFIERS:
            mods = (form[2:],)
        else:
            return None
        # linear and U-shaped in the variable, times the state (a U-shaped effect has no linear part)
        return main + tuple(f"{t}@{m}" for m in mods for t in main)

    @staticmethod
    def term_variable(term: str) -> str:
        """The state variable of a term (``bias:v@sq@cos_bearing`` -> ``v``)."""
        return split_term(term)[0]

    def effect_terms(self, effect: dict[str, Any]) -> tuple[str, ...] | None:
        """State terms of a finding on the parts its metric measures (:data:`METRIC_PARTS`), or ``None``.

        The terms of :meth:`state_terms` (its form), each restricted to a part (``null:``, ``bias:``,
        ``sigma:``; :func:`~sensor_envs.lidar.extra_state.term_part`): a null-rate finding changes
        p_null only, a mean finding the bias and sigma, a spread finding sigma.
        """
        terms = self.state_terms(effect["name"], str(effect.get("form", "main")))
        parts = METRIC_PARTS.get(str(effect.get("metric")))
        if terms is None or parts is None:
            return terms
        return tuple(f"{p}:{t}" for t in terms for p in parts)

    def state_features(self) -> tuple[str, ...]:
        """The model's own state: nominal range, incidence and bearing (per-bearing tables)."""
        return ("range", "incidence", "bearing")

    # -- fit / evaluate ----------------------------------------------------------------------------
    def base(self) -> LidarLWLR:
        """The tables: fitted once on the fit part (or the given model's)."""
        if self._base is None:
            self._base = LidarLWLR(**self.params).fit(self.fit_log, max_readings=self.max_readings)
        return self._base

    def fit(self, extra_state: tuple[str, ...]) -> LidarLWLR:
        """The base tables with linear terms of ``extra_state`` fitted on the fit part."""
        model = copy.copy(self.base())
        model.extra_state = tuple(extra_state)
        fit_extra_terms(model, self.fit_log)
        return model

    def evaluate(self, model: LidarLWLR) -> Evaluation:
        """Residuals, candidates and NLL of ``model`` on the held-out readings (hit rays only)."""
        base = model.params_from_features(self.r, self.a, base_only=True)
        mu_table = np.where(np.isfinite(self.r), base["mu"], np.nan)
        names = tuple(model.extra_state_)
        feats = scan_features(self.log, tuple(dict.fromkeys((*names, PREV))), mu_table, self.r, self.a)
        extra = feats[..., : len(names)] if names else None
        p = model.params_from_features(self.r, self.a, extra) if names else base
        s, k = self.scan_idx, self.bearing_idx
        ps = {n: v[s, k] for n, v in p.items()}
        x = self.x[s, k]
        lp = mixture_log_prob(x, ps, model.spur_mu_, model.spur_sigma_)
        null = x == 0
        inr = (x > 0) & (x <= model.spur_above)
        pit = np.where(x > 0, _pit(np.where(x > 0, x, 1.0), ps, (model.spur_mu_, model.spur_sigma_)) - 0.5, np.nan)
        rng_res = np.where(inr, np.clip(x - ps["mu"], -_RANGE_CLIP, _RANGE_CLIP), np.nan)
        resid = {
            "null": null - ps["p_null"],
            "range": rng_res,
            "pit": pit,
            "range_spread": _within_scan_spread(rng_res / ps["sigma"], s),
            "pit_spread": _pit_spread(pit, s),
        }
        cand = dict(self._candidates)
        cand[PREV] = feats[s, k, -1 if PREV not in names else names.index(PREV)]
        kb = self.log.n_bearings
        return Evaluation(
            nll=-lp,
            residuals=resid,
            candidates=cand,
            blocks=self.blocks,
            order=s + k / kb,
            state={
                "bearing": k.astype(np.float64),
                "range": self.r[s, k],
                "incidence": np.nan_to_num(self.a[s, k]),
                "range_slope": self.slope[s, k],
            },
            metric_kinds={
                "null": "rate",
                "range": "mean",
                "pit": "mean",
                "range_spread": "spread",
                "pit_spread": "spread",
            },
        )

    def baseline(self, extra_state: tuple[str, ...]) -> float | None:
        """No baseline with extra state for the lidar (``None``)."""
        return None
