"""The radar's add step: fit the corrections that represent a found effect on top of the base model.

A finding of the search (a candidate column, the residual metric it moves, its form) is added as a
:class:`~sensor_envs.radar.correction.Term` of :class:`~sensor_envs.radar.correction.CorrectedRadar`
(labels such as ``mean_y(speed x azimuth)``, see :meth:`~sensor_envs.diagnose.radar.RadarAdapter.effect_terms`),
for the KDE and for its Gaussian baseline alike.

The terms are fitted on the base model's OUT-OF-FOLD outputs on the fit part: the fit part's blocks
are dealt to two folds, the base model is refitted on each fold and queried on the other (a KDE
queried at its own tuples would see its own outputs and shrink every residual toward 0). The
corrected model is then the base model fitted on the whole fit part plus the terms; the loop keeps
it only if the held-out NLL drops (:func:`sensor_envs.diagnose.core.run_diagnose`). Base fits and
out-of-fold outputs are cached per (model kind, base columns): trying a correction costs one term
fit and one held-out evaluation.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.radar.correction import CorrectedRadar, Term, fit_term
from sensor_envs.radar.features import state_matrix
from sensor_envs.radar.log import RadarLog, target_tuples
from sensor_envs.sensor_model import extra_state_names

__all__ = [
    "fit_corrected",
    "parse_label",
    "is_label",
    "radar_blocks",
    "tune_relevance",
    "describe_terms",
    "nll_parts",
    "loop_extras",
]

_LABEL = re.compile(r"^(mean_x|mean_y|spread|rate)\((.+?)(?: x (azimuth|range))?\)$")


def radar_blocks(log: RadarLog, block_frames: int = 25) -> NDArray[np.int64]:
    """Block id ``(n_rows,)``: ``block_frames`` consecutive frames of one sequence form a block."""
    key = np.stack([log["sequence"], log["frame"] // block_frames], axis=1)
    return np.unique(key, axis=0, return_inverse=True)[1].ravel().astype(np.int64)


def is_label(name: str) -> bool:
    """Whether ``name`` is a correction label (else a log column of the base model's state)."""
    return _LABEL.match(name) is not None


def parse_label(label: str) -> tuple[str, str, str]:
    """``(part, column, state)`` of a label such as ``mean_y(speed x azimuth)`` (state ``""`` for a main effect)."""
    m = _LABEL.match(label)
    if m is None:
        raise ValueError(f"not a correction label: {label!r}")
    return m.group(1), m.group(2), m.group(3) or ""


def _cache(adapter: Any) -> dict[Any, Any]:
    cache = adapter.__dict__.setdefault("_add_cache", {})
    assert isinstance(cache, dict)
    return cache


def _base(adapter: Any, kind: str, cols: tuple[str, ...], means: tuple[Term, ...] = ()) -> Any:
    """The base model of ``kind`` with extra columns ``cols`` on the fit part freed of ``means`` (cached)."""
    cache = _cache(adapter)
    key = ("base", kind, cols, tuple(t.label for t in means))
    if key not in cache:
        cache[key] = adapter.fit_base(kind, cols, log=_freed(adapter.fit_log, means))
    return cache[key]


def _freed(log: RadarLog, means: tuple[Term, ...]) -> RadarLog:
    """``log`` with the offsets of the mean terms taken off its target rows' measurements (no copy without terms)."""
    if not means:
        return log
    tt = target_tuples(log)
    values = {t.column: state_matrix(log, (t.column,), tt.row)[:, 0] for t in means}
    shift = CorrectedRadar(None, list(means))._parts(values, tt.corner)[0]
    cols = dict(log.columns)
    for k, name in enumerate(("meas_x", "meas_y")):
        v = np.array(cols[name], dtype=np.float64)
        v[tt.row] -= shift[:, k]
        cols[name] = v
    return RadarLog(cols, source=log.source)


def _out_of_fold(adapter: Any, kind: str, cols: tuple[str, ...], means: tuple[Term, ...] = ()) -> dict[str, Any]:
    """Out-of-fold mean output and miss probability of the base model at every target row of the fit part.

    ``means``: the fit part is first freed of these offsets (the outputs ``z`` returned are freed too).
    """
    cache = _cache(adapter)
    key = ("oof", kind, cols, tuple(t.label for t in means))
    if key in cache:
        return dict(cache[key])
    log = _freed(adapter.fit_log, means)
    tt = target_tuples(log)
    fold = np.unique(radar_blocks(log), return_inverse=True)[1].ravel() % 2
    n = tt.z.shape[0]
    mu, p_miss = np.full((n, 2), np.nan), np.full(n, np.nan)
    for f in (0, 1):  # fit on one fold, query the other
        train = log.select(fold != f)
        train.source = log.source
        model = adapter.fit_base(kind, cols, log=train)
        sel = fold[tt.row] == f
        st = np.concatenate([tt.corner[sel], tt.z_prev[sel]], axis=1)
        ex = state_matrix(log, cols, tt.row[sel]) if cols else None
        mu[sel], p_miss[sel] = model.mean_output(st, extra=ex, new_track=~tt.has_prev_row[sel])
    out = {"tt": tt, "mu": mu, "p_miss": p_miss}
    cache[key] = out
    return dict(out)


def fit_corrected(adapter: Any, kind: str, extra_state: tuple[str, ...]) -> Any:
    """The base model of ``kind`` with the log columns of ``extra_state``, plus its correction labels as terms.

    Mean terms first: fitted on the offsets from the out-of-fold mean of the Gaussian baseline (a
    mean without the previous output: the KDE's ``z_{t-1}`` already carries most of a slow offset,
    so its own residuals would show a fraction of it); the base model is then refitted on the fit
    part freed of those offsets (its previous outputs freed alike, see
    :class:`~sensor_envs.radar.correction.CorrectedRadar`). Spread and rate terms next, in order,
    each on the refitted base model's out-of-fold outputs corrected by the terms before it.

    Returns:
        The base model itself when ``extra_state`` holds no label, else a
        :class:`~sensor_envs.radar.correction.CorrectedRadar`.
    """
    cols = tuple(s for s in extra_state if not is_label(s))
    labels = [parse_label(s) for s in extra_state if is_label(s)]
    if not labels:
        return _base(adapter, kind, cols)
    tt = target_tuples(adapter.fit_log)
    values = {col: state_matrix(adapter.fit_log, (col,), tt.row)[:, 0] for _, col, _ in labels}
    means: list[Term] = []
    ref = _out_of_fold(adapter, "gaussian", ())
    for part, col, state in (lab for lab in labels if lab[0].startswith("mean")):
        z_in, _ = _corrected_inputs(means, values, tt.corner, tt.z, ref["mu"], ref["p_miss"])
        means.append(fit_term(part, col, values[col], tt.corner, z_in, ref["mu"], ref["p_miss"], state=state))
    base = _base(adapter, kind, cols, tuple(means))
    others: list[Term] = []
    rest = [lab for lab in labels if not lab[0].startswith("mean")]
    if rest:
        oof = _out_of_fold(adapter, kind, cols, tuple(means))
        z0, mu, p_miss = oof["tt"].z, oof["mu"], oof["p_miss"]
        for part, col, state in rest:
            z_in, pm_in = _corrected_inputs(others, values, tt.corner, z0, mu, p_miss)
            others.append(fit_term(part, col, values[col], tt.corner, z_in, mu, pm_in, state=state))
    return CorrectedRadar(base, [*means, *others], free_previous=bool(means))


def _corrected_inputs(
    terms: list[Term], values: dict[str, NDArray], corners: NDArray, z: NDArray, mu: NDArray, p_miss: NDArray
) -> tuple[NDArray, NDArray]:
    """Outputs mapped back through the earlier terms (offset and scale undone) and their miss probability."""
    if not terms:
        return z, p_miss
    shift, log_s, logit = CorrectedRadar(None, terms)._parts(values, corners)
    _, p1 = CorrectedRadar._p_detect(p_miss, logit)
    return mu + (z - shift - mu) * np.exp(-log_s)[:, None], 1.0 - p1


TUNE_CORNER = (3.0, 12.0, 48.0)
"""Corner variances [m^2] of the KDE's relevance kernel tried by :func:`tune_relevance`."""
TUNE_PREV = (0.03, 0.12, 0.48)
"""``z_{t-1}`` variances [m^2] tried by :func:`tune_relevance` (after the corner's)."""


def tune_relevance(adapter: Any) -> dict[str, Any]:
    """Re-tune the KDE's own state kernel (corner, then previous output) before looking for causes.

    The base model's misfit along its own state (e.g. a previous-output kernel too narrow for the
    log, which shows as its ``prev_offset_*`` residuals ranking first) is handled here, not by the
    search: the fit part's blocks are dealt to two folds, the KDE is fitted on one and scored (mean
    NLL per reading) on the other for each corner variance in :data:`TUNE_CORNER`, then each
    ``z_{t-1}`` variance in :data:`TUNE_PREV` with the best corner (their output bandwidths by a
    coarser CV, at most 120 tuples per node; a kernel that cannot be fitted on half the fit part, e.g.
    too narrow for the bandwidth grid, scores infinity). The held-out part is not used.
    Sets ``adapter.params["rel_variance"]`` to the winner.

    Returns:
        ``{"rel_variance": [...], "scores": {label: NLL}}`` for the report.
    """
    from sensor_envs.radar.kde import KDERadarModel

    log = adapter.fit_log
    fold = np.unique(radar_blocks(log), return_inverse=True)[1].ravel() % 2
    train = log.select(fold == 0)
    train.source = log.source
    tt = target_tuples(log)
    sel = fold[tt.row] == 1
    st = np.concatenate([tt.corner[sel], tt.z_prev[sel]], axis=1)
    params = {k: v for k, v in adapter.params.items() if k != "relevance"}
    params["cv_max_tuples"] = min(int(params.get("cv_max_tuples", 120)), 120)  # a coarser bandwidth CV: 4x faster
    rv = list(params.get("rel_variance", (3.0, 3.0, 0.03, 0.03)))
    scores: dict[str, float] = {}

    def score(v: list[float]) -> float:
        key = f"corner {v[0]:g} m^2, z_prev {v[2]:g} m^2"
        if key not in scores:
            try:
                m = KDERadarModel(**{**params, "relevance": "paper", "rel_variance": tuple(v)}).fit(train)
            except InputError:  # e.g. too few tuples in reach of the bandwidth grid on half the fit part
                scores[key] = float("inf")
                return scores[key]
            lp = m.log_prob(tt.z[sel], st, new_track=~tt.has_prev_row[sel])
            scores[key] = float(np.mean(np.minimum(-lp, 50.0)))
        return scores[key]

    best_c = min(TUNE_CORNER, key=lambda c: score([c, c, rv[2], rv[3]]))
    best_p = min(TUNE_PREV, key=lambda p: score([best_c, best_c, p, p]))
    adapter.params.update(relevance="paper", rel_variance=(best_c, best_c, best_p, best_p))
    return {"rel_variance": [best_c, best_c, best_p, best_p], "scores": scores}


_UNITS = {"mean_x": "m (sensor x)", "mean_y": "m (sensor y)", "spread": "x scale factor", "rate": "logit of P(detect)"}


def describe_terms(model: Any) -> list[dict[str, Any]]:
    """Per correction term of a :class:`~sensor_envs.radar.correction.CorrectedRadar`: its form and size in words.

    Each dict: ``label``, ``part``, ``column``, ``state``, ``knots`` (column units), ``values`` (per state
    bin, at the knots: metres for a mean term, the scale factor ``exp(a)`` for spread, the logit shift for
    rate), ``size`` (largest minus smallest value) and ``text``.
    """
    out: list[dict[str, Any]] = []
    for t in getattr(model, "terms", []):
        vals = np.exp(t.coef) if t.part == "spread" else t.coef
        size = float(vals.max() - vals.min())
        lo, hi = int(np.argmin(t.coef[0])), int(np.argmax(t.coef[0]))
        what = {"mean_x": "x offset", "mean_y": "y offset", "spread": "spread", "rate": "detection logit"}[t.part]
        text = (
            f"{t.label}: the {what} varies by {size:.3g} {_UNITS[t.part]} over {t.column} "
            f"{t.knots[0]:.3g}..{t.knots[-1]:.3g}; lowest {vals[0, lo]:.3g} at {t.column} = {t.knots[lo]:.3g}, "
            f"highest {vals[0, hi]:.3g} at {t.knots[hi]:.3g}"
        )
        if t.state:
            text += f" (first {t.state} bin; {t.edges.size + 1} bins with edges {np.round(t.edges, 3).tolist()})"
        out.append(
            {
                "label": t.label,
                "part": t.part,
                "column": t.column,
                "state": t.state,
                "knots": t.knots.tolist(),
                "values": vals.tolist(),
                "size": size,
                "text": text,
            }
        )
    return out


def nll_parts(adapter: Any, model: Any) -> dict[str, float]:
    """Held-out NLL per reading [nats] split into the detection part and the position part of detections.

    ``rate``: ``-log P(detected)`` or ``-log P(miss)`` per reading; ``position``: ``-log p(z | x, detected)``
    per detected reading; ``total``: the mean of the sum (as the loop's error, each reading capped at 50).
    """
    names = extra_state_names(model)
    tt = adapter._tt
    ex = state_matrix(adapter.held_log, names, tt.row) if names else None
    st, new = adapter._state, ~tt.has_prev_row
    lp = model.log_prob(tt.z, st, extra=ex, new_track=new)
    _, p_miss = model.mean_output(st, extra=ex, new_track=new)
    det = np.isfinite(tt.z[:, 0])
    p_miss = np.clip(p_miss, 1e-12, 1 - 1e-12)
    rate = np.where(det, -np.log1p(-p_miss), -np.log(p_miss))
    pos = np.minimum(-lp[det], 50.0) - rate[det]
    return {
        "rate": float(rate.mean()),
        "position": float(pos.mean()) if pos.size else float("nan"),
        "total": float(np.mean(np.minimum(-lp, 50.0))),
    }


def loop_extras(adapter: Any, result: Any, before: Any = None) -> dict[str, Any]:
    """What a radar diagnosis adds to its report, from the models the loop measured.

    The final model's corrections in words (:func:`describe_terms`), the held-out NLL per part
    (:func:`nll_parts`) of ``before`` (default ``result.model_before``; the CLI passes a ``--model`` file's
    own model) and of ``result.model_after``, and the state kernel's tuning.
    """
    return {
        "corrections": describe_terms(result.model_after),
        "nll_parts_before": nll_parts(adapter, result.model_before if before is None else before),
        "nll_parts_after": nll_parts(adapter, result.model_after),
        "state_tuning": adapter.tuning,
    }
