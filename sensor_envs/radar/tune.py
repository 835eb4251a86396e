"""Tune a fitted KDE radar on real held-out rows: bandwidth factors and tail mixture (``sensor-envs tune radar``).

A KDE fitted on a SIMULATED log (the calibrated rig) never saw a real row, so every real row is held out for
it; what is chosen on real rows is a post-fit factor, by cross-validation over folds of frame blocks
(:func:`sensor_envs.radar.fidelity.fold_rows`: block ``b`` in test fold ``b % n_folds``):

* **bandwidth factor** (:func:`with_factor`, ``tree`` ``both``/``start``/``main``): a factor on the
  contribution bandwidths of the chosen trees. Criterion ``nll``: the mean NLL of outcomes; ``energy``: the
  row-weighted energy distance per corner-range bin among the factors whose mean NLL is within ``guard`` of the
  least, by the one-standard-error rule (the factor nearest 1 within one standard error of the least);
* **tail mixture** (:func:`choose_tail`): the pair ``(tail_weight, tail_scale)`` of
  :meth:`KDERadarModel.with_tail` minimising the mean NLL of ``z`` given a detection, averaged over the start
  tuple and the stationary law (both are what a user simulates: a new track, and a track that has run).

Each choice is reported twice: nested (per fold, the candidate chosen on the other folds and scored on that
fold: the honest held-out figure of the choice) and final (chosen on every fold: what is written).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.radar.features import model_extra
from sensor_envs.radar.fidelity import marginal, nll_given_detected
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.validate import RANGE_BINS, energy_distance_2d

__all__ = [
    "FACTORS",
    "TAIL_WEIGHTS",
    "TAIL_SCALES",
    "NLL_GUARD",
    "ENERGY_MAX_N",
    "with_factor",
    "fold_scores",
    "energy_per_bin",
    "criterion",
    "choose",
    "refit",
    "tail_scores",
    "choose_tail",
]

FACTORS = (0.35, 0.5, 0.6, 0.7, 0.85, 1.0)
"""Bandwidth factors tried by default."""
TAIL_WEIGHTS = (0.0, 0.01, 0.03, 0.1, 0.2)
"""Tail weights ``w`` tried by default (0: no tail component)."""
TAIL_SCALES = (2.0, 4.0, 8.0, 16.0)
"""Tail bandwidth factors ``c`` tried by default."""
NLL_GUARD = 0.05
"""``criterion="energy"`` considers the factors whose mean NLL is within this share of the least one."""
ENERGY_MAX_N = 4000
"""Simulated draws per range bin for the energy distance."""
Fold = tuple[Any, Any]
"""A fold's test rows: ``(TargetTuples, RadarLog)`` of :func:`sensor_envs.radar.fidelity.fold_rows`."""


def with_factor(model: KDERadarModel, factor: float, tree: str) -> KDERadarModel:
    """``model`` with the bandwidths of ``tree`` ``factor`` times its own.

    ``both``: every tree's (a model with its own start factor keeps the ratio); ``start``: the start trees'
    only (``start_bandwidth_scale``); ``main``: the trees with ``z_{t-1}`` only, the start trees' bandwidths
    held where they are (their factor made explicit first).
    """
    start = model.start_bandwidth_scale if model.start_bandwidth_scale is not None else model.bandwidth_scale
    if tree == "both":
        return model.with_bandwidth_scale(factor)
    if tree == "start":
        return model.with_start_bandwidth_scale(start * factor)
    if tree == "main":
        return model.with_start_bandwidth_scale(start).with_bandwidth_scale(factor)
    raise InputError(f"tree: expected 'both', 'start' or 'main', got {tree!r}")


def fold_scores(
    model: Any, folds: list[Fold], seed: int, chains: int, cycles: int, start: int = 0
) -> list[dict[str, Any]]:
    """``model``'s law (start tuple at ``cycles == 1``, else stationary) on each fold's real rows.

    Fold ``k`` of ``folds`` draws from the generator seeded ``[seed, start + k]`` (``start``: the index of
    ``folds[0]`` among all folds, so one fold scored alone draws what it draws among the others).

    Returns per fold: ``nll`` (mean NLL of outcomes [nats]), ``nll_det`` (per detected row, NLL of ``z`` given
    a detection [nats]), the real rows ``corner``, ``z`` [m] and the chains' last draws ``samples (n, chains, 2)``.
    """
    out = []
    for k, (tt, test) in enumerate(folds):  # one iteration per fold
        rng = np.random.default_rng([seed, start + k])
        res = marginal(
            model, tt.corner, tt.z, rng, chains, cycles, all_samples=True, extra=model_extra(model, test, tt.row)
        )
        out.append(
            {
                "nll": float(-res["logp"].mean()),
                "nll_det": nll_given_detected(res, tt.z),
                "corner": tt.corner,
                "z": tt.z,
                "samples": res["samples"],
            }
        )
    return out


def energy_per_bin(parts: list[dict[str, Any]], seed: int) -> tuple[NDArray, NDArray]:
    """Energy distance [m] per corner-range bin and the real detected rows per bin.

    The U-statistic between the pooled draws and the real detected offsets of ``parts`` (items of
    :func:`fold_scores`).
    """
    corner = np.concatenate([p["corner"] for p in parts])
    z = np.concatenate([p["z"] for p in parts])
    sim = np.concatenate([p["samples"] for p in parts])
    r = np.hypot(corner[:, 0], corner[:, 1])
    rng = np.random.default_rng([seed, 99])
    ed, n = [], []
    for lo, hi in zip(RANGE_BINS[:-1], RANGE_BINS[1:], strict=True):  # one iteration per range bin
        s = (r >= lo) & (r < hi)
        a = sim[s].reshape(-1, 2)
        b = z[s & np.isfinite(z[:, 0])]
        ed.append(energy_distance_2d(a[np.isfinite(a[:, 0])], b, rng, max_n=ENERGY_MAX_N, unbiased=True))
        n.append(b.shape[0])
    return np.asarray(ed), np.asarray(n, dtype=np.float64)


def criterion(parts: list[dict[str, Any]], kind: str, seed: int) -> float:
    """A factor's score on ``parts`` (lower is better): mean NLL (``nll``), or row-weighted energy distance."""
    if kind == "nll":
        return float(np.mean([p["nll"] for p in parts]))
    ed, n = energy_per_bin(parts, seed)
    ok = np.isfinite(ed)
    return float(np.sum(n[ok] * ed[ok]) / max(n[ok].sum(), 1.0))


def _pick(scores: dict[float, list[dict]], folds: list[int], kind: str, seed: int, guard: float) -> float:
    """The factor chosen on ``folds`` (indices into each factor's parts; ties: nearer 1); see the module docstring."""
    factors = sorted(scores, key=lambda f: abs(np.log(f)))
    nll = {f: criterion([scores[f][j] for j in folds], "nll", seed) for f in factors}
    if kind == "energy":  # the energy distance among the factors whose NLL stays near its optimum
        factors = [f for f in factors if nll[f] <= (1.0 + guard) * min(nll.values())]
        per_fold = {f: np.array([criterion([scores[f][j]], "energy", seed) for j in folds]) for f in factors}
        best = min(factors, key=lambda f: per_fold[f].mean())
        se = float(per_fold[best].std(ddof=1) / np.sqrt(len(folds))) if len(folds) > 1 else 0.0
        return next(f for f in factors if per_fold[f].mean() <= per_fold[best].mean() + se)
    if kind != "nll":
        raise InputError(f"criterion: expected 'nll' or 'energy', got {kind!r}")
    return min(factors, key=lambda f: nll[f])


def choose(
    scores: dict[float, list[dict]], kind: str, seed: int, guard: float = NLL_GUARD
) -> tuple[float, list[float]]:
    """Final factor (``kind`` criterion on all folds) and the nested choice of each fold (on the others)."""
    n = len(next(iter(scores.values())))
    final = _pick(scores, list(range(n)), kind, seed, guard)
    nested = [_pick(scores, [j for j in range(n) if j != k], kind, seed, guard) for k in range(n)]
    return final, nested


def refit(model: KDERadarModel, log: Any) -> KDERadarModel:
    """A copy of ``model``'s hyperparameters (no tail) fitted on ``log``: the fold model of ``tune radar --refit``."""
    params = {**model.get_params(), "tail_weight": 0.0}
    return KDERadarModel(**params).fit(log, cycle_time=None if np.isnan(model.cycle_time_) else model.cycle_time_)


def tail_scores(
    model: KDERadarModel | list[KDERadarModel],
    folds: list[Fold],
    weights: tuple[float, ...] = TAIL_WEIGHTS,
    scales: tuple[float, ...] = TAIL_SCALES,
    seed: int = 0,
    chains: int = 16,
    cycles: int = 5,
    progress: Any = None,
) -> dict[tuple[float, float], dict[str, list[NDArray]]]:
    """Per tail pair ``(w, c)``, per law (``start``, ``stationary``) and fold: NLL of ``z`` given a detection per row.

    ``model``: one model for every fold (fitted on other data, e.g. the rig), or one per fold (fitted without
    that fold's rows: :func:`refit`). ``w = 0`` is scored once (as ``(0, c)`` of the first scale); the
    stationary law only for a model with ``z_{t-1}``. ``progress``: a callable given each pair before it is
    scored (e.g. a progress line).
    """
    per_fold = model if isinstance(model, list) else [model] * len(folds)
    if len(per_fold) != len(folds):
        raise InputError(f"model: {len(per_fold)} fold models for {len(folds)} folds")
    laws = {"start": 1, **({"stationary": cycles} if per_fold[0].use_prev and cycles > 1 else {})}
    pairs = [(float(w), float(c)) for w in weights for c in scales if w > 0]
    if 0.0 in weights:
        pairs.insert(0, (0.0, float(scales[0])))
    out: dict[tuple[float, float], dict[str, list[NDArray]]] = {}
    for w, c in pairs:  # one iteration per candidate pair
        if progress is not None:
            progress((w, c))
        out[(w, c)] = {law: [] for law in laws}
        for k, m in enumerate(per_fold):  # one iteration per fold (its own model, or the same one)
            tailed = m.with_tail(w, c)
            for law, cy in laws.items():
                part = fold_scores(tailed, folds[k : k + 1], seed, chains, cy, start=k)[0]
                out[(w, c)][law].append(part["nll_det"])
    return out


def _tail_loss(per_law: dict[str, list[NDArray]], folds: list[int]) -> float:
    """Mean NLL of ``z`` given a detection on ``folds``' rows, averaged over the laws."""
    return float(np.mean([np.concatenate([v[j] for j in folds]).mean() for v in per_law.values()]))


def choose_tail(
    scores: dict[tuple[float, float], dict[str, list[NDArray]]],
) -> tuple[tuple[float, float], list[tuple[float, float]]]:
    """Final tail pair (least :func:`_tail_loss` on every fold) and the nested choice of each fold (on the others).

    Ties go to the smaller weight, then the smaller scale (the model nearest the paper's).
    """
    n = len(next(iter(next(iter(scores.values())).values())))

    def pick(folds: list[int]) -> tuple[float, float]:
        return min(sorted(scores), key=lambda p: _tail_loss(scores[p], folds))

    return pick(list(range(n))), [pick([j for j in range(n) if j != k]) for k in range(n)]


def nested_rows(
    scores: dict[tuple[float, float], dict[str, list[NDArray]]], nested: list[tuple[float, float]]
) -> dict[str, NDArray]:
    """Per law, the held-out rows' NLL of ``z`` given a detection, each fold scored with its nested choice."""
    laws = next(iter(scores.values())).keys()
    return {law: np.concatenate([scores[p][law][k] for k, p in enumerate(nested)]) for law in laws}
