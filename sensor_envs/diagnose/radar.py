"""The radar side of ``sensor-envs diagnose``: :class:`RadarAdapter` for the KDE radar (and its Gaussian baseline).

Readings are the target rows of the log (detections and misses). Blocks are ``block_frames``
consecutive frames of one sequence (:func:`radar_blocks`).

Residuals of a fitted model on the held-out part (sensor frame, metres):

* ``offset_x``, ``offset_y``: ``z - E[z | x, detected]`` of detected rows (NaN on misses);
* ``detection``: ``1{detected} - P(detected | x)``;
* ``nll``: the reading's negative log-likelihood minus its expectation under the model at the same
  state (Monte Carlo, 2 draws from the model): NLL itself varies over the state space where the model
  is right (wider noise far away), its excess over the model's own expectation does not;
* ``offset_spread``: ``sqrt`` of the offset's length in units of the offsets' RMS per axis (kind
  ``spread``: a covariate that widens the scatter moves it while the mean offset stays 0).

Interaction features (the model's own state, see :mod:`sensor_envs.diagnose.search`): range and
azimuth of the box. The KDE takes an added column as a full kernel dimension, so main effects and
interactions with its state alike are represented; the Gaussian baseline takes it linearly (an
interaction is reported as unrepresented for it).

Candidates: every extra numeric column of the log by its name (``t`` as ``time``), the ``frame``
index, derived features (``range``, ``azimuth``, ``aspect`` = target heading relative to the line of
sight, ``occluded`` = the share of the box hidden behind the other boxes of its cycle, ``corner_x``/
``corner_y`` = closest-corner position, ``rel_speed`` when ``rel_vx``/``rel_vy`` exist;
:mod:`sensor_envs.radar.features`) and the previous cycle's residuals of the same target
(``prev_offset_x``, ``prev_offset_y``, ``prev_detection``). The model can take any log column into
its state (``extra_state``); the previous residuals (the KDE's ``z_{t-1}`` plays that part) cannot be
added. The corner, range and azimuth are functions of the state the models already have (the box
position, up to its size), and the previous residuals are the KDE's own ``z_{t-1}`` conditioning: all
of them are tested as ``state_misfit`` (see :mod:`sensor_envs.diagnose.core`), set aside from the
search for missing effects.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.diagnose.core import Evaluation
from sensor_envs.diagnose.radar_add import fit_corrected, radar_blocks, tune_relevance
from sensor_envs.inputs import InputError
from sensor_envs.radar.astyx import OUTCOME_COLUMNS
from sensor_envs.radar.correction import PARTS, STATE_FEATURES
from sensor_envs.radar.features import state_matrix, with_derived_columns
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import CV_RELEVANCE, KDERadarModel
from sensor_envs.radar.log import INT_COLUMNS, REQUIRED_COLUMNS, RadarLog, TargetTuples, target_tuples
from sensor_envs.sensor_model import extra_state_names

__all__ = ["RadarAdapter", "radar_blocks", "DIAGNOSE_KDE_PARAMS"]

DIAGNOSE_KDE_PARAMS: dict[str, Any] = {
    "relevance": "paper",
    "relevance_folds": 3,
    "random_state": 0,
    "cv_grid_step": 8.0,
}
"""KDE hyperparameters of the diagnosis fits unless ``--model`` gives others (state variances re-tuned
on the fit part, :func:`~sensor_envs.diagnose.radar_add.tune_relevance`; extra dimensions' variances by
3-fold CV; the output bandwidths' CV on an 8 m grid of corner positions, 4x fewer nodes than the
default: on the suite's logs the held-out NLL differs by about 0.002 nats, the fit is 4x faster)."""
_NOT_ADDABLE = ("corner_x", "corner_y", "range", "azimuth", "prev_offset_x", "prev_offset_y", "prev_detection")
_RENAME = {"t": "time"}
_METRIC_PARTS = {
    "offset_x": ("mean_x",),
    "offset_y": ("mean_y",),
    "offset_spread": ("spread",),
    "detection": ("rate",),
}


class RadarAdapter:
    """Diagnosis adapter of the KDE radar (implements :class:`sensor_envs.diagnose.core.DiagnoseAdapter`).

    Args:
        log: the whole radar log.
        held_out: ``(n_rows,)`` rows of the held-out part (whole blocks).
        model_kind: ``"kde"`` or ``"gaussian"``: the model that is diagnosed.
        params: hyperparameters of that model (extra state excluded).
        progress: progress bars of the fits.
        exclude: log columns that are not candidates (e.g. outcomes of the measurement itself, such as
            Astyx's ``n_points``, which is 0 exactly when the target is missed).
        tune: re-tune the KDE's own state kernel (corner and ``z_{t-1}`` variances) on the fit part
            before the first fit (:func:`~sensor_envs.diagnose.radar_add.tune_relevance`; the result
            is in ``tuning``). Off when the configuration is given (``--model``).
    """

    kind = "radar"

    def __init__(
        self,
        log: RadarLog,
        held_out: NDArray[np.bool_],
        model_kind: str = "kde",
        params: dict[str, Any] | None = None,
        progress: bool = False,
        exclude: tuple[str, ...] = (),
        tune: bool = True,
    ) -> None:
        if model_kind not in ("kde", "gaussian"):
            raise InputError(f"model_kind must be 'kde' or 'gaussian', got {model_kind!r}")
        self.log = with_derived_columns(log)
        missing = [c for c in exclude if c not in self.log.columns]  # a derived feature may be excluded too
        if missing:
            raise InputError(f"{log.source}: excluded column {missing[0]!r} is not in the log")
        outcomes = [c for c in self.log.columns if c in OUTCOME_COLUMNS or c.startswith("outcome_")]
        self.outcomes = tuple(outcomes)  # outcomes of the measurement (e.g. Astyx's n_points): never causes
        self.exclude = tuple(dict.fromkeys((*exclude, *outcomes)))
        self.fit_log = self.log.select(~held_out)
        self.held_log = self.log.select(held_out)
        self.fit_log.source = self.held_log.source = log.source
        self.model_kind = model_kind
        self.params = dict(DIAGNOSE_KDE_PARAMS if model_kind == "kde" else {}, **(params or {}))
        for k in ("extra_state", "extra_variance"):
            self.params.pop(k, None)
        self.progress = progress
        self.n_mc = 2
        self._variances: dict[str, float] = {}
        self.tune = tune and model_kind == "kde" and "rel_variance" not in (params or {})
        self.tuning: dict[str, Any] | None = None
        self._tt = _held_out_tuples(self.log, held_out)
        self._state = np.concatenate([self._tt.corner, self._tt.z_prev], axis=1)
        self._candidates = self._static_candidates()

    # -- columns --------------------------------------------------------------------------------

    def columns(self) -> list[str]:
        """Numeric log columns a model can take into its state (covariates, derived, ``t``, ``frame``)."""
        skip = (
            {c for c in REQUIRED_COLUMNS if c not in ("t", "frame")} | set(INT_COLUMNS) - {"frame"} | set(self.exclude)
        )
        return [c for c in self.log.columns if c not in skip]

    def state_name(self, candidate: str) -> str | None:
        """Log column that adds ``candidate`` to the state, or ``None`` (corner, previous residuals)."""
        if candidate in _NOT_ADDABLE:
            return None
        col = {v: k for k, v in _RENAME.items()}.get(candidate, candidate)
        return col if col in self.log.columns else None

    def _static_candidates(self) -> dict[str, NDArray[np.float64]]:
        """Candidates that do not depend on the model: log columns and the corner, at the held-out readings."""
        rows = self._tt.row
        out = {_RENAME.get(c, c): np.asarray(self.held_log[c], dtype=np.float64)[rows] for c in self.columns()}
        out["corner_x"], out["corner_y"] = self._tt.corner[:, 0], self._tt.corner[:, 1]
        return out

    # -- fit / evaluate ---------------------------------------------------------------------------

    def fit(self, extra_state: tuple[str, ...]) -> Any:
        """Fit the diagnosed model with ``extra_state`` on the fit part.

        ``extra_state`` holds log columns (extra kernel dimensions of the KDE, linear terms of the
        Gaussian: a ``--model``'s own state) and correction labels (:meth:`effect_terms`, e.g.
        ``mean_y(speed x azimuth)``): those are fitted as :class:`~sensor_envs.radar.correction.Term`
        objects on top of the base model (:mod:`sensor_envs.diagnose.radar_add`).
        """
        return fit_corrected(self, self.model_kind, tuple(extra_state))

    def fit_base(self, model_kind: str, columns: tuple[str, ...], log: RadarLog | None = None) -> Any:
        """The base model (no correction) of ``model_kind`` with extra state ``columns``, fitted on ``log``.

        ``log`` defaults to the fit part. Relevance variances chosen by CV in an earlier fit (the state's
        with ``relevance="cv"``, ``"cv_axes"`` or ``"cv_state"``, those of earlier extra dimensions) are
        reused; only a new dimension's variance is chosen by CV.
        """
        log = self.fit_log if log is None else log
        if model_kind == "kde" and self.tune and self.tuning is None:
            self.tuning = tune_relevance(self)
        if model_kind == "gaussian":
            gparams = self.params if self.model_kind == "gaussian" else {}
            return GaussianRadar(**gparams, extra_state=tuple(columns)).fit(log)
        var = tuple(self._variances.get(n, float("nan")) for n in columns) if columns else None
        model = KDERadarModel(**self.params, extra_state=tuple(columns), extra_variance=var)
        model.set_params(verbose=bool(self.progress)).fit(log)
        self._variances.update(zip(model.extra_state_, model.extra_variance_, strict=True))
        if self.params.get("relevance") in CV_RELEVANCE:  # the state variances are chosen once, by the first fit
            self.params.update(relevance="paper", rel_variance=tuple(model.rel_variance_))
        return model

    @staticmethod
    def term_variable(term: str) -> str:
        """The log column of a correction label (``mean_x(v x azimuth)`` -> ``v``); a bare name as is."""
        inner = term[term.find("(") + 1 : term.rfind(")")] if term.endswith(")") and "(" in term else term
        return inner.split(" x ")[0]

    def effect_terms(self, effect: dict[str, Any]) -> tuple[str, ...] | None:
        """Correction labels that represent a found effect (its kind, metric and form), or ``None``.

        ``offset_x``/``offset_y`` -> a mean term on that axis, ``offset_spread`` -> a spread term,
        ``detection`` -> a rate term, ``nll`` (a score: any part) -> all four; an interaction with
        ``azimuth`` or ``range`` keeps that form. ``None`` for a candidate the model cannot take.
        """
        col = self.state_name(effect["name"])
        if col is None:
            return None
        form = str(effect.get("form", "main"))
        state = form[2:] if form.startswith("x ") else ""
        if state not in STATE_FEATURES:
            return None
        parts = _METRIC_PARTS.get(str(effect.get("metric")), PARTS)
        return tuple(f"{p}({col}{' x ' + state if state else ''})" for p in parts)

    def evaluate(self, model: Any) -> Evaluation:
        """Residuals, candidates and NLL of ``model`` on the held-out target rows."""
        names = extra_state_names(model)
        ex = state_matrix(self.held_log, names, self._tt.row) if names else None
        z, new = self._tt.z, self._new_track()
        lp = model.log_prob(z, self._state, extra=ex, new_track=new)
        mu, p_miss = model.mean_output(self._state, extra=ex, new_track=new)
        det = ~np.isnan(z[:, 0])
        off = np.where(det[:, None], z - mu, np.nan)
        rms = np.sqrt(np.nanmean(off**2, axis=0)) if det.any() else np.ones(2)
        resid = {
            "offset_x": _winsorised(off[:, 0]),
            "offset_y": _winsorised(off[:, 1]),
            "detection": det - (1.0 - p_miss),
            "nll": np.minimum(-lp, 50.0) - self._expected_nll(model, ex),
            "offset_spread": np.sqrt(np.minimum(np.hypot(*(off / np.maximum(rms, 1e-9)).T), 25.0)),
        }
        cand = dict(self._candidates)
        prev = self._previous_index()
        for k in ("offset_x", "offset_y", "detection"):
            cand[f"prev_{k}"] = np.where(prev >= 0, resid[k][np.maximum(prev, 0)], np.nan)
        tt = self._tt
        return Evaluation(
            nll=-lp,
            residuals=resid,
            candidates=cand,
            blocks=self._blocks(),
            order=(tt.sequence * (float(tt.frame.max(initial=0)) + 2.0) + tt.frame).astype(np.float64),
            state={k: cand[k] for k in ("range", "azimuth") if k in cand},
            metric_kinds={
                "offset_x": "mean",
                "offset_y": "mean",
                "detection": "rate",
                "nll": "score",
                "offset_spread": "spread",
            },
        )

    def _expected_nll(self, model: Any, ex: NDArray | None) -> NDArray[np.float64]:
        """Model-expected NLL of each held-out state, by ``n_mc`` samples from the model itself (seeded)."""
        rng = np.random.default_rng(12345)
        total = np.zeros(self._state.shape[0])
        new = self._new_track()
        for _ in range(self.n_mc):  # a few Monte Carlo draws per reading
            zs, _ = model.sample(self._state, rng, extra=ex, new_track=new)
            total += np.minimum(-model.log_prob(zs, self._state, extra=ex, new_track=new), 50.0)
        return total / self.n_mc

    def _new_track(self) -> NDArray[np.bool_]:
        """``(n,)`` True where a held-out reading's target has no previous cycle in the whole log (new track)."""
        return ~self._tt.has_prev_row

    def _previous_index(self) -> NDArray[np.int64]:
        """Index of the same target's previous-frame reading among the held-out readings (-1: none)."""
        tt = self._tt
        order = np.lexsort((tt.frame, tt.target, tt.sequence))
        s, g, f = tt.sequence[order], tt.target[order], tt.frame[order]
        ok = np.zeros(order.size, dtype=bool)
        ok[1:] = (s[1:] == s[:-1]) & (g[1:] == g[:-1]) & (f[1:] == f[:-1] + 1)
        prev_sorted = np.where(ok, np.roll(order, 1), -1)
        out = np.empty(order.size, dtype=np.int64)
        out[order] = prev_sorted
        return out

    def _blocks(self) -> NDArray[np.int64]:
        return radar_blocks(self.held_log)[self._tt.row]

    def state_features(self) -> tuple[str, ...]:
        """The models' own state: the corner, range/azimuth of the box, and the previous residuals (``z_{t-1}``)."""
        return ("corner_x", "corner_y", "range", "azimuth", "prev_offset_x", "prev_offset_y", "prev_detection")

    def baseline(self, extra_state: tuple[str, ...]) -> float | None:
        """Held-out NLL of the Gaussian baseline with the same extra state and corrections, per reading."""
        if self.model_kind == "gaussian":
            return None
        g = fit_corrected(self, "gaussian", tuple(extra_state))
        names = tuple(g.extra_state_)
        ex = state_matrix(self.held_log, names, self._tt.row) if names else None
        lp = g.log_prob(self._tt.z, self._state, extra=ex)
        return float(np.mean(np.minimum(-lp, 50.0)))


def _winsorised(r: NDArray, k: float = 2.5) -> NDArray[np.float64]:
    """``r`` clipped at ``k`` robust standard deviations (1.4826 MAD) about its median; NaN kept.

    Radar offsets are heavy-tailed (Student-t like): a few far readings would dominate a least-squares
    score of a mean effect; clipped, they still count by their sign.
    """
    f = r[np.isfinite(r)]
    if f.size == 0:
        return np.asarray(r, dtype=np.float64)
    med = float(np.median(f))
    s = 1.4826 * float(np.median(np.abs(f - med))) + 1e-12
    return np.asarray(np.clip(r, med - k * s, med + k * s), dtype=np.float64)


def _held_out_tuples(log: RadarLog, held_out: NDArray[np.bool_]) -> TargetTuples:
    """Tuples of the held-out target rows, their previous outputs taken from the WHOLE log.

    A held-out block starts mid-track: its first cycle's previous output lies in the fit part. It is an
    input of the model (``z_{t-1}``), not a held-out outcome, so it is taken from there, and only a target
    without a previous cycle anywhere in the log is a new track. ``row`` indexes the held-out log.
    """
    full = target_tuples(log)
    held = full.take(held_out[full.row])
    held_row = np.cumsum(held_out) - 1  # a log row's index in log.select(held_out)
    return replace(held, row=held_row[held.row])
