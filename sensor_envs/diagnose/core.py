"""Sensor-independent diagnosis: block split, ranking of candidate effects, the add-refit-remeasure loop.

A sensor plugs in through a :class:`DiagnoseAdapter` (build candidates and residuals of a fitted model
on the held-out part, fit the base model with a given extra state, held-out NLL per reading).

**Split.** Readings are grouped into contiguous blocks (scans, frame blocks of a sequence); blocks are
dealt to the held-out part by rank (:func:`block_split`: ranks ``2, 5, 8`` modulo 10, i.e. 30 %), so
the held-out part is spread over the log but no block is cut.

**Search and significance.** :mod:`sensor_envs.diagnose.search`: every residual target (mean,
spread, rate, score kinds) regressed on each candidate by a trend + binned regressor and by its
interactions with the model's state features, cross-fitted over contiguous time segments with gaps;
block sign-flip tests with Westfall-Young max-T adjustment; proxies of a stronger cause marked.
Candidates with too few distinct values are refused (listed, not tested).

**State features.** Candidates that are functions of the model's own state (the adapter's
``state_features``) are tested in a separate family and reported as ``state_misfit``: a pattern
along them is misfit of how the model uses its state (e.g. kernel widths), not a missing effect, and
adding them cannot help. ``effects`` holds the other candidates only.

**Loop.** Fit the base model on the fit part, evaluate on the held-out part, rank; add the best
significant candidate the model can take into its state, refit, re-measure on the SAME held-out part;
keep it only when the held-out NLL improves beyond its block-to-block noise (:func:`improvement_interval`;
a finding at ``p < alpha / 10``: when it improves at all; on a short log, whose held-out part has fewer
than :data:`GATE_MIN_BLOCKS` blocks, the gain is cross-fitted: an adapter with ``other_folds()`` refits
on the other two folds of :data:`FOLD_RANKS`, so every block of the log is held out once;
else it is reported as rejected; an interaction is then tried as a main effect, then (where the adapter
has one) as a linear main effect (:data:`LINEAR_FORM`), and after that the next significant candidate);
re-rank after each addition; repeat while an effect is significant, with at most
``max_add`` (default 3) refits in all. An adapter with ``effect_terms(effect)`` (or ``state_terms(name,
form)``) turns a finding's kind and form (e.g. a null-rate effect interacting with bearing) into the state
terms that represent it, on the part of the model the finding measures; an added candidate stays in the
ranking, so its effect on another part (or in another form) can be added later, never its terms twice.
A significant effect the model cannot take is reported in words (``unrepresented``) with its kind and form.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from sensor_envs.diagnose.search import DEFAULTS, Ranking, bin_candidate, check_search_options, rank_candidates
from sensor_envs.inputs import InputError

__all__ = [
    "DEFAULTS",
    "Evaluation",
    "DiagnoseAdapter",
    "DiagnoseResult",
    "block_split",
    "bin_candidate",
    "FOLD_RANKS",
    "GATE_MIN_BLOCKS",
    "improvement_interval",
    "nll_gain",
    "rank_candidates",
    "run_diagnose",
]

FOLD_RANKS: tuple[tuple[int, ...], ...] = ((2, 5, 8), (1, 4, 7), (0, 3, 6, 9))
"""Block ranks (modulo 10) of the three folds; the first is the held-out part of :func:`block_split`."""

GATE_MIN_BLOCKS = 30
"""Held-out blocks below which the gain of an addition is measured on every fold (a 200-scan log of
5-scan blocks has 12 held-out blocks: too few for a block bootstrap to tell a real gain from noise)."""

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
        blocks: ``(n,)`` contiguous block id of each reading.
        order: ``(n,)`` time-order key of each reading (time folds and sign-flip blocks follow it;
            ``None``: the block ids).
        state: interaction features: the model's own state (bearing, range, azimuth, ...) ``(n,)`` each.
        metric_kinds: residual metric -> ``mean`` / ``spread`` / ``rate`` / ``score`` (default ``mean``).
    """

    nll: NDArray[np.float64]
    residuals: dict[str, NDArray[np.float64]]
    candidates: dict[str, NDArray[np.float64]]
    blocks: NDArray[np.int64]
    order: NDArray[np.float64] | None = None
    state: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    metric_kinds: dict[str, str] = field(default_factory=dict)

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


def block_split(blocks: NDArray, held_ranks: tuple[int, ...] = FOLD_RANKS[0], period: int = 10) -> NDArray[np.bool_]:
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


@dataclass
class DiagnoseResult:
    """Outcome of :func:`run_diagnose` (``model_before`` / ``model_after``: the fitted models the loop measured)."""

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
    model_before: Any = field(default=None, repr=False)
    model_after: Any = field(default=None, repr=False)

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


LINEAR_FORM = "main (linear)"
"""Form of a finding taken as a linear main effect (tried after its own form and its main form)."""


def _terms(adapter: DiagnoseAdapter, effect: dict[str, Any]) -> tuple[str, ...] | None:
    """State terms that add ``effect`` (its form included, e.g. an interaction with bearing), or ``None``."""
    if hasattr(adapter, "effect_terms"):  # the adapter reads the effect's kind, metric and form itself
        return adapter.effect_terms(effect)
    if hasattr(adapter, "state_terms"):
        return adapter.state_terms(effect["name"], effect.get("form", "main"))
    var = adapter.state_name(effect["name"])
    return None if var is None else (var,)


def _state_variables(adapter: DiagnoseAdapter, state: tuple[str, ...]) -> set[str]:
    """The variables the state terms ``state`` use (an adapter's ``term_variable``, else the names themselves)."""
    var = getattr(adapter, "term_variable", None)
    return {var(t) for t in state} if var is not None else set(state)


def _why_not(adapter: DiagnoseAdapter, effect: dict[str, Any]) -> str:
    """Words for a significant effect the model cannot take: its kind and form, and why."""
    form = "" if effect.get("form", "main") == "main" else f", interacting with {effect['form'][2:]}"
    what = f"{effect['name']}: a {effect.get('kind', 'mean')} effect on {effect['metric']}{form}"
    if adapter.state_name(effect["name"]) is None:
        return f"{what}; the model cannot take {effect['name']} into its state (not a variable the world supplies)"
    return f"{what}; the model's extra state has no term of this form"


def _ranking_rows(r: Ranking) -> list[dict[str, Any]]:
    keys = ("name", "score", "p_value", "p_raw", "metric", "kind", "form", "proxy_of", "test")
    # the two tests' own p-values and the drift checks, where they ran
    drift = ("p_search", "p_projection", "p_within_blocks", "explains_drift", "p_surrogate")
    return [{**{k: e.get(k) for k in keys}, **{k: e[k] for k in drift if k in e}} for e in r.effects]


def nll_gain(before: Evaluation, after: Evaluation) -> NDArray[np.float64]:
    """Per held-out reading, the capped NLL before minus after [nats] (positive: the change helped)."""
    return np.asarray(np.minimum(before.nll, NLL_CAP) - np.minimum(after.nll, NLL_CAP), dtype=np.float64)


def improvement_interval(
    before: Evaluation, after: Evaluation, rng: np.random.Generator, n_boot: int = 999
) -> tuple[float, float]:
    """90 % interval of the held-out NLL improvement per reading [nats] (``before`` minus ``after``).

    The readings' capped NLL differences are summed per held-out block and the blocks resampled with
    replacement (a block bootstrap: readings of one block share their time correlation). An addition
    is kept when its lower end is above 0, a one-sided 95 % bound (the claim is directional: the
    addition lowers the held-out NLL; a candidate reaches this step only after the family-wise test),
    or, for a strongly significant finding (family-wise ``p < alpha / 10``), when the held-out NLL is
    lower at all (:func:`run_diagnose`).
    A lower held-out NLL that the block-to-block noise explains is not an improvement (a random walk
    following slow drift, a proxy added after its cause,
    lower the NLL by a few thousandths by chance).
    """
    d = nll_gain(before, after)
    ok = np.isfinite(d)
    _, blk = np.unique(before.blocks[ok], return_inverse=True)
    sums, counts = np.bincount(blk, weights=d[ok]), np.bincount(blk).astype(np.float64)
    idx = rng.integers(0, sums.size, size=(n_boot, sums.size))
    boot = sums[idx].sum(axis=1) / counts[idx].sum(axis=1)
    lo, hi = np.quantile(boot, [0.05, 0.95])
    return float(lo), float(hi)


def _stack_nll(evs: list[Evaluation]) -> Evaluation:
    """The NLL and blocks of several folds' evaluations as one (block ids kept apart per fold)."""
    shift = [0, *np.cumsum([int(e.blocks.max(initial=-1)) + 1 for e in evs])[:-1]]
    return Evaluation(
        nll=np.concatenate([e.nll for e in evs]),
        residuals={},
        candidates={},
        blocks=np.concatenate([e.blocks + k for e, k in zip(evs, shift, strict=True)]).astype(np.int64),
    )


class _GateFolds:
    """The other folds of a short log and their evaluations per state (the gain gate's cross-fitting)."""

    def __init__(self, adapter: DiagnoseAdapter, ev: Evaluation) -> None:
        other = getattr(adapter, "other_folds", None)
        short = np.unique(ev.blocks).size < GATE_MIN_BLOCKS
        self.adapters: list[Any] = list(other()) if short and other is not None else []
        self._evs: dict[tuple[str, ...], list[Evaluation]] = {}

    def evaluations(self, state: tuple[str, ...]) -> list[Evaluation]:
        """Each other fold's held-out evaluation of the model with ``state`` fitted on that fold."""
        if state not in self._evs:
            self._evs[state] = [a.evaluate(a.fit(state)) for a in self.adapters]
        return self._evs[state]

    def pair(
        self, ev: Evaluation, new_ev: Evaluation, state: tuple[str, ...], new_state: tuple[str, ...]
    ) -> tuple[Evaluation, Evaluation]:
        """Before / after over every fold (just ``ev``, ``new_ev`` when the log is not short)."""
        if not self.adapters:
            return ev, new_ev
        return _stack_nll([ev, *self.evaluations(state)]), _stack_nll([new_ev, *self.evaluations(new_state)])


def run_diagnose(
    adapter: DiagnoseAdapter,
    *,
    base_state: tuple[str, ...] = (),
    base_model: Any = None,
    max_add: int = DEFAULTS["max_add"],
    n_permutations: int = DEFAULTS["n_permutations"],
    alpha: float = DEFAULTS["alpha"],
    min_score: float = DEFAULTS["min_score"],
    seed: int = 0,
    progress: bool = False,
    n_shifts: int = DEFAULTS["n_shifts"],
) -> DiagnoseResult:
    """The loop: fit (or take ``base_model``), evaluate, rank, add the best significant effect, refit, repeat.

    Args:
        adapter: the sensor's adapter (fit/held-out parts fixed inside it).
        base_state: extra state the base model already has.
        base_model: an already fitted base model (``--model``); ``None`` = fit one on the fit part.
        max_add: at most this many refits (effects added or rejected).
        n_permutations: block sign-flips per ranking.
        alpha: family-wise significance level.
        min_score: minimum held-out ``R^2`` of a significant effect.
        seed: seed of the sign-flips.
        progress: show progress bars.
        n_shifts: circular shifts that confirm a finding of the flips (0: the flips alone).

    Returns:
        The :class:`DiagnoseResult`; ``effects`` is the first ranking (of the base model's residuals).
    """
    check_search_options(n_permutations, n_shifts, alpha, min_score, max_add)
    rng = np.random.default_rng(seed)
    boot_rng = np.random.default_rng([seed, 1])  # the improvement intervals' own stream
    bar = tqdm(total=max_add + 1, disable=not progress, desc=f"diagnose {adapter.kind}")
    model = base_model if base_model is not None else adapter.fit(base_state)
    model_before = model
    ev = adapter.evaluate(model)
    before = ev
    gate = _GateFolds(adapter, ev)
    state = tuple(base_state)
    added: list[str] = []
    steps: list[dict[str, Any]] = []
    feats = tuple(adapter.state_features())
    in_state = _state_variables(adapter, state)
    exclude = tuple(c for c in ev.candidates if adapter.state_name(c) in in_state) + feats
    first: Ranking | None = None
    opts = {
        "n_permutations": n_permutations,
        "n_shifts": n_shifts,
        "alpha": alpha,
        "min_score": min_score,
        "rng": rng,
        "progress": progress,
    }
    misfit = rank_candidates(
        replace(ev, state={}),
        tuple(c for c in ev.candidates if c not in feats),
        **opts,  # type: ignore[arg-type]
    )
    rejected: set[tuple[str, ...]] = set()  # state terms of refits that did not improve
    unrepresented: dict[str, str] = {}
    ranking: Ranking | None = None
    step: dict[str, Any] = {}
    for _ in range(max_add):  # at most max_add refits (added or rejected)
        if ranking is None:  # the model changed: rank its residuals again
            ranking = rank_candidates(ev, exclude, given=tuple(added), **opts)  # type: ignore[arg-type]
            first = first or ranking
            step = {"error": ev.error, "ranking": _ranking_rows(ranking), "attempts": []}
            steps.append(step)
        pick, terms = None, None
        for e in ranking.significant():
            # the effect in its form, then as a main effect: what the model cannot take in that form, or
            # what did not carry over to the held-out part in it (e.g. a steep interaction term), may
            # still be represented by its main terms
            tries = [e] if e.get("form", "main") == "main" else [e, {**e, "form": "main"}]
            # last, its simplest form (linear in the candidate) where the adapter has one: a U-shaped
            # fit's ends may not carry over to held-out values near or beyond the fit's range
            tries.append({**e, "form": LINEAR_FORM})
            for t in tries:
                terms = _terms(adapter, t)
                if terms is None:
                    if t["form"] != LINEAR_FORM:
                        unrepresented.setdefault(t["name"], _why_not(adapter, t))
                    continue
                terms = tuple(x for x in terms if x not in state)  # an added candidate on another part or form
                if not terms or terms in rejected:  # already in, or refitted (in this form or another's name)
                    continue
                pick = t
                break
            if pick is not None:
                break
        if pick is None or terms is None:
            step["decision"] = "no (further) significant effect the model can take"
            break
        new_model = adapter.fit((*state, *terms))
        new_ev = adapter.evaluate(new_model)
        bar.update()
        attempt = {
            "candidate": pick["name"],
            "terms": list(terms),
            "kind": pick.get("kind"),
            "form": pick.get("form"),
            "error_with": new_ev.error,
            "baseline_with": adapter.baseline((*state, *terms)),
        }
        step["attempts"].append(attempt)
        gate_before, gate_after = gate.pair(ev, new_ev, state, (*state, *terms))
        low, high = improvement_interval(gate_before, gate_after, boot_rng)
        attempt["improvement_interval"] = [low, high]
        attempt["gate_folds"] = 1 + len(gate.adapters)
        gain = float(np.nanmean(nll_gain(gate_before, gate_after)))
        strong = float(pick.get("p_value", 1.0)) < alpha / 10
        # strong evidence (the search's family-wise p < alpha / 10) needs a held-out gain; weaker evidence
        # needs the gain's one-sided 95 % bound above 0
        folds = f", over {attempt['gate_folds']} folds" if gate.adapters else ""
        if not (low > 0.0 or (strong and gain > 0.0)):
            need = "a gain (strongly significant)" if strong else "its one-sided 95 % bound above 0"
            attempt["decision"] = (
                f"{pick['name']} rejected: held-out NLL {ev.error:.4f} -> {new_ev.error:.4f}, improvement "
                f"[{low:.4f}, {high:.4f}] nats per reading (90 %, held-out blocks resampled{folds}); needed {need}"
            )
            step["decision"] = attempt["decision"]
            rejected.add(tuple(terms))
            continue
        attempt["decision"] = step["decision"] = (
            f"added {pick['name']} as {', '.join(terms)}: improvement {gain:.4f} [{low:.4f}, {high:.4f}] nats per "
            f"reading (90 %{folds}){'; strongly significant: a gain suffices' if strong and low <= 0.0 else ''}"
        )
        state, model, ev = (*state, *terms), new_model, new_ev
        if pick["name"] not in added:  # still ranked: its effect on the model's other parts may be added later
            added.append(pick["name"])
        ranking = None
    if ranking is None:  # the refit budget ended on an addition: rank the final model's residuals too
        final = rank_candidates(ev, exclude, given=tuple(added), **opts)  # type: ignore[arg-type]
        steps.append(
            {"error": ev.error, "ranking": _ranking_rows(final), "decision": f"stopped: {max_add} refits done"}
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
        model_before=model_before,
        model_after=model,
        baseline_before=adapter.baseline(tuple(base_state)),
        baseline_after=adapter.baseline(state) if added else adapter.baseline(tuple(base_state)),
        settings={
            "alpha": alpha,
            "multiple_testing": "Westfall-Young max-T over candidates, regressors and residual targets "
            "(block sign-flips of the residual targets, in time order), and min-P over the projection tests "
            "(two-coefficient forms, in sample); Bonferroni over the two tests; what the flips find is "
            "confirmed by circular shifts of the residuals along time (the larger p-value is reported)",
            "n_shifts": n_shifts,
            "min_score": min_score,
            "n_permutations": n_permutations,
            "max_add": max_add,
            "seed": seed,
            "score": "held-out R^2 of a trend + binned regressor (and candidate x state interactions), "
            "cross-fitted over contiguous time segments with gaps",
            "state_before": list(base_state),
            "state_after": list(state),
        },
        extra={"unrepresented": [{"name": k, "why": v} for k, v in unrepresented.items()], "refused": first.refused},
    )
