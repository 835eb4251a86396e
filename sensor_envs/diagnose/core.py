"""Sensor-independent diagnosis: block split, ranking of candidate effects, the add-refit-remeasure loop.

A sensor plugs in through a :class:`DiagnoseAdapter` (build candidates and residuals of a fitted model
on the held-out part, fit the base model with a given extra state, held-out NLL per reading).

**Split.** Readings are grouped into contiguous blocks (scans, frame blocks of a sequence); blocks are
dealt to the held-out part by rank (:func:`block_split`: ranks ``2, 5, 8`` modulo 10, i.e. 30 %), so
the held-out part is spread over the log but no block is cut.

**Score of a candidate.** On the held-out readings, each residual metric ``r`` (NaN where undefined)
is regressed on the candidate by a regularised binned mean (16 quantile bins, or one bin per value
for discrete candidates, NaN its own bin; bin mean shrunk toward the fold mean with 10 pseudo-readings:
a one-feature piecewise-constant regressor, like a depth-1 gradient-boosting stage with 16 leaves).
It is cross-fitted by blocks: fitted on the even held-out blocks and scored on the odd ones, and vice
versa. The score is the held-out explained variance ``R^2 = 1 - SSE / SST`` (SST about the fitting
fold's mean), averaged over the two directions; the candidate's score is its best metric's ``R^2``.
A distractor that correlates by chance within some blocks does not carry over to other blocks, so its
cross-fitted ``R^2`` is near zero or negative.

**Permutation test and multiple testing.** ``n_permutations`` random permutations of the held-out
readings are applied to every candidate's values at once (the residuals stay), and the scores
recomputed. ``p_raw`` of a candidate is ``(1 + #{perm score >= score}) / (1 + P)``; the reported
``p_value`` is the Westfall-Young max-T adjusted one, ``(1 + #{perm max over all candidates >=
score}) / (1 + P)``, which controls the family-wise error rate over all candidates and metrics at
once. An effect is **significant** when ``p_value < alpha`` (default 0.01) and its score is at least
``min_score`` (default 0.005, half a percent of residual variance: on large logs tiny but real
effects would otherwise be added). Permuting single readings ignores the correlation inside blocks;
the cross-fitting by blocks is what protects against that.

**State features.** Candidates that are functions of the model's own state (the adapter's
``state_features``) are tested in a separate family and reported as ``state_misfit``: a pattern
along them is misfit of how the model uses its state (e.g. kernel widths), not a missing effect, and
adding them cannot help. ``effects`` holds the other candidates only.

**Loop.** Fit the base model on the fit part, evaluate on the held-out part, rank; add the best
significant candidate the model can take into its state, refit, re-measure on the SAME held-out part;
keep it only when the held-out NLL improves (else it is reported as rejected and the next significant
candidate is tried); re-rank after each addition; repeat while an effect is significant, with at most
``max_add`` (default 3) refits in all.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from sensor_envs.inputs import InputError

__all__ = [
    "Evaluation",
    "DiagnoseAdapter",
    "DiagnoseResult",
    "block_split",
    "bin_candidate",
    "rank_candidates",
    "run_diagnose",
]

NLL_CAP = 50.0
"""Per-reading NLL [nats] above which a reading is capped (an impossible outcome under a model would
otherwise make the mean infinite); the number of capped readings is reported."""


@dataclass
class Evaluation:
    """A fitted model measured on the held-out readings (all arrays aligned, ``n`` readings).

    Attributes:
        nll: ``(n,)`` negative log-likelihood per reading [nats].
        residuals: metric name -> ``(n,)`` residual (NaN where the metric is undefined).
        candidates: candidate name -> ``(n,)`` value (NaN = missing).
        blocks: ``(n,)`` contiguous block id of each reading (the cross-fitting unit).
    """

    nll: NDArray[np.float64]
    residuals: dict[str, NDArray[np.float64]]
    candidates: dict[str, NDArray[np.float64]]
    blocks: NDArray[np.int64]

    @property
    def error(self) -> float:
        """Held-out mean NLL per reading [nats], each reading capped at :data:`NLL_CAP`."""
        return float(np.mean(np.minimum(self.nll, NLL_CAP)))

    @property
    def n_capped(self) -> int:
        """Readings whose NLL exceeds :data:`NLL_CAP` (or is infinite)."""
        return int(np.sum(~(self.nll <= NLL_CAP)))


class DiagnoseAdapter(Protocol):
    """What a sensor must provide to be diagnosed (the radar's is :class:`sensor_envs.diagnose.radar.RadarAdapter`)."""

    kind: str

    def fit(self, extra_state: tuple[str, ...]) -> Any:
        """Fit the base model with ``extra_state`` (adapter column names) on the fit part."""

    def evaluate(self, model: Any) -> Evaluation:
        """Residuals, candidates and NLL of ``model`` on the held-out part."""

    def state_name(self, candidate: str) -> str | None:
        """The state variable that adds ``candidate`` to the model, or ``None`` if the model cannot take it."""

    def baseline(self, extra_state: tuple[str, ...]) -> float | None:
        """Held-out NLL of the sensor's baseline model with the same extra state (``None``: no baseline)."""

    def state_features(self) -> tuple[str, ...]:
        """Candidates that are functions of the base model's own state (e.g. the radar's corner, range).

        Their residual patterns are misfit ALONG the state (bandwidth, smoothing), not an effect the
        model lacks: they are ranked in a family of their own and reported as ``state_misfit``.
        """


def block_split(blocks: NDArray, held_ranks: tuple[int, ...] = (2, 5, 8), period: int = 10) -> NDArray[np.bool_]:
    """Held-out mask ``(n,)``: readings whose block's rank modulo ``period`` is in ``held_ranks``.

    Args:
        blocks: ``(n,)`` block id of every reading (any sortable ids; ranks follow their sort order).
        held_ranks: ranks (mod ``period``) dealt to the held-out part.
        period: dealing period.

    Raises:
        ValueError: when either part would be empty.
    """
    _, inv = np.unique(blocks, return_inverse=True)
    held = np.isin(inv.ravel() % period, held_ranks)
    if held.all() or not held.any():
        raise InputError(f"the log has {inv.max(initial=-1) + 1} blocks: too few to split into fit and held-out parts")
    return held


def bin_candidate(x: NDArray, n_bins: int = 16) -> NDArray[np.int64]:
    """Bin index ``(n,)``: one bin per value (at most ``n_bins`` values), else quantile bins; NaN last."""
    x = np.asarray(x, dtype=np.float64)
    ok = np.isfinite(x)
    out = np.full(x.shape, n_bins, dtype=np.int64)
    if not ok.any():
        return out
    vals = np.unique(x[ok])
    if vals.size <= n_bins:
        out[ok] = np.searchsorted(vals, x[ok])
    else:
        edges = np.unique(np.quantile(x[ok], np.linspace(0, 1, n_bins + 1)[1:-1]))
        out[ok] = np.searchsorted(edges, x[ok], side="right")
    return out


def _r2_batch(bins: NDArray, r: NDArray, fold: NDArray, nb: int, shrink: float) -> NDArray[np.float64]:
    """Cross-fitted ``R^2`` of ``r`` on each row of ``bins (K, n)``, averaged over both fold directions."""
    k, n = bins.shape
    out = np.zeros(k)
    off = (np.arange(k) * nb)[:, None]
    for a in (0, 1):  # fit on fold a, score on the other
        fa, fb = fold == a, fold != a
        if fa.sum() < 2 or fb.sum() < 2:
            return np.full(k, -np.inf)
        mean_a = r[fa].mean()
        ids = (bins[:, fa] + off).ravel()
        s = np.bincount(ids, weights=np.tile(r[fa], k), minlength=k * nb).reshape(k, nb)
        c = np.bincount(ids, minlength=k * nb).reshape(k, nb)
        pred = (s + shrink * mean_a) / (c + shrink)
        rb = r[fb]
        p = np.take_along_axis(pred, bins[:, fb], axis=1)
        sse = np.sum((rb[None] - p) ** 2, axis=1)
        sst = np.sum((rb - mean_a) ** 2)
        out += 0.5 * (1.0 - sse / max(sst, 1e-300))
    return out


def _scores(
    bins: NDArray, residuals: list[NDArray], masks: list[NDArray], folds: list[NDArray], nb: int, shrink: float
) -> NDArray[np.float64]:
    """``(K, m)`` cross-fitted ``R^2`` of every binning row against every residual metric."""
    return np.stack(
        [_r2_batch(bins[:, mk], r, f, nb, shrink) for r, mk, f in zip(residuals, masks, folds, strict=True)], axis=1
    )


@dataclass
class Ranking:
    """Candidate effects scored on one evaluation, best first."""

    effects: list[dict[str, Any]]
    alpha: float
    min_score: float
    n_permutations: int

    def significant(self) -> list[dict[str, Any]]:
        """The effects with ``p_value < alpha`` and ``score >= min_score``, best first."""
        return [e for e in self.effects if e["significant"]]


def rank_candidates(
    ev: Evaluation,
    exclude: tuple[str, ...] = (),
    *,
    n_permutations: int = 499,
    alpha: float = 0.01,
    min_score: float = 0.005,
    n_bins: int = 16,
    shrink: float = 10.0,
    rng: np.random.Generator | None = None,
    progress: bool = False,
) -> Ranking:
    """Score every candidate of ``ev`` (except ``exclude``) against its residuals, with the permutation test.

    Args:
        ev: held-out evaluation.
        exclude: candidate names not to rank (e.g. already in the model's state).
        n_permutations: permutations of the candidates (p-values resolve down to ``1 / (P + 1)``).
        alpha: family-wise significance level of the max-T adjusted p-value.
        min_score: minimum cross-fitted ``R^2`` of a significant effect.
        n_bins: bins of continuous candidates.
        shrink: pseudo-readings pulling bin means toward the fold mean.
        rng: generator of the permutations (default seed 0).
        progress: tqdm bar over the permutations.

    Returns:
        The :class:`Ranking` (``effects``: dicts with ``name``, ``score``, ``p_value``, ``p_raw``,
        ``metric``, ``metric_scores``, ``significant``), best score first.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    names = [c for c in ev.candidates if c not in exclude]
    metrics = list(ev.residuals)
    nb = n_bins + 1
    if not names:
        return Ranking([], alpha, min_score, n_permutations)
    bins = np.stack([bin_candidate(ev.candidates[c], n_bins) for c in names])  # (C, n)
    _, bl = np.unique(ev.blocks, return_inverse=True)
    fold_all = (bl.ravel() % 2).astype(np.int64)
    masks = [np.isfinite(ev.residuals[m]) for m in metrics]
    res = [ev.residuals[m][mk] for m, mk in zip(metrics, masks, strict=True)]
    folds = [fold_all[mk] for mk in masks]
    obs = _scores(bins, res, masks, folds, nb, shrink)  # (C, m)
    best = obs.max(axis=1)
    ge_raw = np.zeros(len(names))
    ge_max = np.zeros(len(names))
    n = bins.shape[1]
    chunk = max(1, 4_000_000 // (len(names) * max(n, 1)))  # bounds the (chunk * C, n) permuted bin array
    done = 0
    bar = tqdm(total=n_permutations, disable=not progress, desc="permutation test")
    while done < n_permutations:  # chunks of permutations, vectorised inside
        k = min(chunk, n_permutations - done)
        perms = np.argsort(rng.random((k, n)), axis=1)
        pb = bins[:, perms].transpose(1, 0, 2).reshape(k * len(names), n)  # (k*C, n)
        ps = _scores(pb, res, masks, folds, nb, shrink).max(axis=1).reshape(k, len(names))
        ge_raw += np.sum(ps >= best[None], axis=0)
        ge_max += np.sum(ps.max(axis=1)[:, None] >= best[None], axis=0)
        done += k
        bar.update(k)
    bar.close()
    p_raw = (1 + ge_raw) / (1 + n_permutations)
    p_adj = (1 + ge_max) / (1 + n_permutations)
    effects: list[dict[str, Any]] = [
        {
            "name": c,
            "score": float(best[i]),
            "p_value": float(p_adj[i]),
            "p_raw": float(p_raw[i]),
            "metric": metrics[int(np.argmax(obs[i]))],
            "metric_scores": {m: float(obs[i, j]) for j, m in enumerate(metrics)},
            "significant": bool(p_adj[i] < alpha and best[i] >= min_score),
        }
        for i, c in enumerate(names)
    ]
    effects.sort(key=lambda e: -float(e["score"]))
    return Ranking(effects, alpha, min_score, n_permutations)


@dataclass
class DiagnoseResult:
    """Outcome of :func:`run_diagnose`."""

    kind: str
    effects: list[dict[str, Any]]
    added: list[str]
    error_before: float
    error_after: float
    steps: list[dict[str, Any]] = field(default_factory=list)
    before: Evaluation | None = None
    after: Evaluation | None = None
    baseline_before: float | None = None
    baseline_after: float | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    state_misfit: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """The ``report.json`` content (floats, lists and dicts only)."""
        assert self.before is not None and self.after is not None
        return {
            "kind": self.kind,
            "effects": [{k: e[k] for k in ("name", "score", "p_value")} for e in self.effects],
            "added": list(self.added),
            "error_before": self.error_before,
            "error_after": self.error_after,
            "significant": [e["name"] for e in self.effects if e["significant"]],
            "details": {
                "error_unit": "held-out mean negative log-likelihood per reading [nats], lower is better",
                "readings_held_out": int(self.before.nll.size),
                "nll_capped_before": self.before.n_capped,
                "nll_capped_after": self.after.n_capped,
                "metrics_before": _metric_summary(self.before),
                "metrics_after": _metric_summary(self.after),
                "effects_full": self.effects,
                "state_misfit": self.state_misfit,
                "steps": self.steps,
                "baseline_error_before": self.baseline_before,
                "baseline_error_after": self.baseline_after,
                "settings": self.settings,
                **self.extra,
            },
        }


def _metric_summary(ev: Evaluation) -> dict[str, dict[str, float]]:
    """Mean, RMS and count of each residual metric."""
    out = {}
    for m, r in ev.residuals.items():
        f = r[np.isfinite(r)]
        out[m] = {
            "mean": float(f.mean()) if f.size else float("nan"),
            "rms": float(np.sqrt(np.mean(f**2))) if f.size else float("nan"),
            "n": int(f.size),
        }
    return out


def run_diagnose(
    adapter: DiagnoseAdapter,
    *,
    base_state: tuple[str, ...] = (),
    base_model: Any = None,
    max_add: int = 3,
    n_permutations: int = 499,
    alpha: float = 0.01,
    min_score: float = 0.005,
    seed: int = 0,
    progress: bool = False,
) -> DiagnoseResult:
    """The loop: fit (or take ``base_model``), evaluate, rank, add the best significant effect, refit, repeat.

    Args:
        adapter: the sensor's adapter (fit/held-out parts fixed inside it).
        base_state: extra state the base model already has.
        base_model: an already fitted base model (``--model``); ``None`` = fit one on the fit part.
        max_add: at most this many effects are added.
        n_permutations: permutations per ranking.
        alpha: family-wise significance level.
        min_score: minimum cross-fitted ``R^2`` of a significant effect.
        seed: seed of the permutations.
        progress: show progress bars.

    Returns:
        The :class:`DiagnoseResult`; ``effects`` is the first ranking (of the base model's residuals).
    """
    rng = np.random.default_rng(seed)
    bar = tqdm(total=max_add + 1, disable=not progress, desc=f"diagnose {adapter.kind}")
    model = base_model if base_model is not None else adapter.fit(base_state)
    ev = adapter.evaluate(model)
    before = ev
    state = tuple(base_state)
    added: list[str] = []
    steps: list[dict[str, Any]] = []
    feats = tuple(adapter.state_features())
    exclude = tuple(c for c in ev.candidates if adapter.state_name(c) in state) + feats
    first: Ranking | None = None
    misfit = rank_candidates(
        ev,
        tuple(c for c in ev.candidates if c not in feats),
        n_permutations=n_permutations,
        alpha=alpha,
        min_score=min_score,
        rng=rng,
        progress=progress,
    )
    rejected: list[str] = []
    ranking: Ranking | None = None
    for _ in range(max_add):  # at most max_add refits (added or rejected)
        if ranking is None:  # the model changed: rank its residuals again
            ranking = rank_candidates(
                ev, exclude, n_permutations=n_permutations, alpha=alpha, min_score=min_score, rng=rng, progress=progress
            )
            first = first or ranking
            step: dict[str, Any] = {
                "error": ev.error,
                "ranking": [
                    {k: e[k] for k in ("name", "score", "p_value", "p_raw", "metric")} for e in ranking.effects
                ],
                "attempts": [],
            }
            steps.append(step)
        pick = next(
            (
                e
                for e in ranking.significant()
                if adapter.state_name(e["name"]) is not None and e["name"] not in rejected
            ),
            None,
        )
        if pick is None:
            step["decision"] = "no (further) significant effect the model can take"
            break
        var = adapter.state_name(pick["name"])
        assert var is not None
        new_model = adapter.fit((*state, var))
        new_ev = adapter.evaluate(new_model)
        bar.update()
        attempt = {
            "candidate": pick["name"],
            "error_with": new_ev.error,
            "baseline_with": adapter.baseline((*state, var)),
        }
        step["attempts"].append(attempt)
        if not new_ev.error < ev.error:
            attempt["decision"] = f"{pick['name']} rejected: held-out NLL {new_ev.error:.4f} >= {ev.error:.4f}"
            step["decision"] = attempt["decision"]
            rejected.append(pick["name"])
            continue
        attempt["decision"] = step["decision"] = f"added {pick['name']}"
        state, model, ev = (*state, var), new_model, new_ev
        added.append(pick["name"])
        exclude = (*exclude, pick["name"])
        ranking = None
    if ranking is None:  # the refit budget ended on an addition: rank the final model's residuals too
        final = rank_candidates(
            ev, exclude, n_permutations=n_permutations, alpha=alpha, min_score=min_score, rng=rng, progress=progress
        )
        steps.append(
            {
                "error": ev.error,
                "ranking": [{k: e[k] for k in ("name", "score", "p_value", "p_raw", "metric")} for e in final.effects],
                "decision": f"stopped: {max_add} refits done",
            }
        )
    bar.update(bar.total - bar.n)
    bar.close()
    assert first is not None
    return DiagnoseResult(
        state_misfit=misfit.effects,
        kind=adapter.kind,
        effects=first.effects,
        added=added,
        error_before=before.error,
        error_after=ev.error,
        steps=steps,
        before=before,
        after=ev,
        baseline_before=adapter.baseline(tuple(base_state)),
        baseline_after=adapter.baseline(state) if added else adapter.baseline(tuple(base_state)),
        settings={
            "alpha": alpha,
            "multiple_testing": "Westfall-Young max-T over all candidates and metrics (permutation of candidates)",
            "min_score": min_score,
            "n_permutations": n_permutations,
            "max_add": max_add,
            "seed": seed,
            "score": "block-cross-fitted R^2 of a binned-mean regression of the residual on the candidate",
            "state_before": list(base_state),
            "state_after": list(state),
        },
    )
