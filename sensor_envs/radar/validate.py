"""Validation of radar models against a log: metrics, ``report.json`` and figures.

Metrics (each for the model and for its Gaussian baseline fitted on the same training data):

* held-out negative log-likelihood: ``nll_outcome`` (mean ``-log p`` of every target row's outcome,
  detection density [1/m^2] or miss probability) and ``nll_z_given_detected`` (detected rows only,
  the output density given a detection; mean and median) [nats];
* energy distance between simulated one-step outputs (at the log's states, incl. the recorded
  ``z_{t-1}``) and measured outputs, per corner-range bin [m] (2-D, numpy, subsampled);
* detection-rate calibration per range bin: measured vs simulated detection rate;
* lag-1 autocorrelation of ``z`` (x and y) along targets: the log's, and that of closed-loop
  rollouts of the model over the log's corner sequences (the model's own previous output is fed
  back), when the log is a time series.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.outputs import write_json
from sensor_envs.radar.features import model_extra
from sensor_envs.radar.log import RadarLog, TargetTuples, target_tuples
from sensor_envs.rng import fold_ids
from sensor_envs.sensor_model import has_capability

__all__ = [
    "RANGE_BINS",
    "split_by_blocks",
    "energy_distance_2d",
    "RowEnergy",
    "row_energy_terms",
    "weighted_energy",
    "block_multiplicities",
    "lag1_autocorr",
    "rollout",
    "detection_by_previous",
    "nll",
    "evaluate",
    "validate",
    "write_report",
]

RANGE_BINS = (0.0, 15.0, 30.0, 50.0, 75.0, 120.0)
"""Default corner-range bin edges [m] of the per-bin metrics."""


_Opt = NDArray | None


class _Model(Protocol):
    def sample_cycle(
        self, corners: NDArray, prev_z: _Opt, rng: np.random.Generator, extra: _Opt = None, new_track: _Opt = None
    ) -> tuple[NDArray, NDArray]: ...

    def log_prob(self, z: NDArray, state: NDArray, extra: _Opt = None, new_track: _Opt = None) -> NDArray: ...


def split_by_blocks(log: RadarLog, block: int, n_folds: int, fold: int) -> tuple[RadarLog, RadarLog]:
    """Split a log into (train, test) by blocks of ``block`` consecutive frames of each sequence.

    Block ``b`` (numbered over all sequences) goes to the test part when ``b % n_folds == fold``.
    """
    if not 0 <= fold < n_folds:
        raise InputError(f"fold must be in [0, {n_folds}), got {fold}")
    seq, frame = log["sequence"], log["frame"]
    test = fold_ids(np.stack([seq, frame // block], axis=1), n_folds) == fold
    return log.select(~test), log.select(test)


def energy_distance_2d(
    a: NDArray,
    b: NDArray,
    rng: np.random.Generator | None = None,
    max_n: int = 800,
    unbiased: bool = False,
) -> float:
    """Energy distance ``2E|A-B| - E|A-A'| - E|B-B'|`` between 2-D samples [m].

    By default the V-statistic (the self terms average over all pairs, a row with itself included): it
    is biased up by ``E|A-A'|/n_a + E|B-B'|/n_b``, which favours the narrower sample. ``unbiased``
    gives the U-statistic (self terms over distinct pairs), unbiased for the laws' energy distance and
    possibly slightly negative when they agree. With ``rng``, each sample is subsampled to at most
    ``max_n`` rows to bound the cost; without, every row is used (deterministic, e.g. for calibration
    under common random numbers). ``NaN`` if either sample is empty (or, unbiased, has one row).
    """
    from scipy.spatial.distance import cdist

    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape[0] == 0 or b.shape[0] == 0:
        return float("nan")
    if rng is not None and a.shape[0] > max_n:
        a = a[rng.choice(a.shape[0], max_n, replace=False)]
    if rng is not None and b.shape[0] > max_n:
        b = b[rng.choice(b.shape[0], max_n, replace=False)]

    def mean_self(p: NDArray) -> float:
        n = p.shape[0]
        return float(cdist(p, p).sum() / (n * (n - 1) if unbiased else n * n))

    if unbiased and min(a.shape[0], b.shape[0]) < 2:
        return float("nan")
    return 2 * float(cdist(a, b).mean()) - mean_self(a) - mean_self(b)


class RowEnergy(NamedTuple):
    """Row-level sums of the energy distance's three terms, for re-weighting rows (block bootstrap).

    Rows ``i, j`` of one bin; a model gives ``m`` draws per row (``NaN``: a miss), the data one output per
    row (``NaN``: a miss). Attributes: ``cross (n, n)`` sum over row ``i``'s draws of ``|x - y_j|``;
    ``model (n, n)`` sum over the pairs of draws of rows ``i`` and ``j`` of ``|x - x'|``; ``data (n, n)``
    ``|y_i - y_j|``; ``n_draws (n,)`` valid draws per row; ``n_data (n,)`` 1 where the row was detected.
    All distances in metres.
    """

    cross: NDArray[np.float64]
    model: NDArray[np.float64]
    data: NDArray[np.float64]
    n_draws: NDArray[np.float64]
    n_data: NDArray[np.float64]


def row_energy_terms(draws: NDArray, data: NDArray, chunk: int = 64) -> RowEnergy:
    """:class:`RowEnergy` of model ``draws (n, m, 2)`` and measured ``data (n, 2)`` [m] (``NaN`` rows: misses).

    Memory is bounded by ``chunk`` rows' draws against all draws at a time.
    """
    from scipy.spatial.distance import cdist

    draws = np.asarray(draws, dtype=np.float64)
    data = np.asarray(data, dtype=np.float64)
    n, m, _ = draws.shape
    ok = np.isfinite(draws[..., 0])
    det = np.isfinite(data[:, 0])
    x = np.where(ok[..., None], draws, 0.0).reshape(n * m, 2)
    y = np.where(det[:, None], data, 0.0)
    okf, detf = ok.reshape(-1).astype(np.float64), det.astype(np.float64)
    cross = (cdist(x, y) * okf[:, None] * detf[None, :]).reshape(n, m, n).sum(axis=1)
    model = np.empty((n, n))
    for i0 in range(0, n, chunk):  # one block of rows' draws against every draw
        i1 = min(n, i0 + chunk)
        d = cdist(x[i0 * m : i1 * m], x) * okf[i0 * m : i1 * m, None] * okf[None, :]
        model[i0:i1] = d.reshape(i1 - i0, m, n, m).sum(axis=(1, 3))
    dat = cdist(y, y) * detf[:, None] * detf[None, :]
    return RowEnergy(cross, model, dat, ok.sum(axis=1).astype(np.float64), detf)


def weighted_energy(terms: RowEnergy, weights: NDArray) -> NDArray[np.float64]:
    """Energy distance [m] (U-statistic) of the rows taken ``weights (R, n)`` times each, ``(R,)``.

    A row taken ``w`` times brings ``w`` copies of its draws and of its measured output; the self terms
    average over pairs of DISTINCT draws (a copy is never paired with another copy of the same draw),
    so at weights 1 this is :func:`energy_distance_2d` (``unbiased=True``) of the pooled draws and data.
    ``NaN`` where a replicate has fewer than two draws or two measured outputs.
    """
    w = np.atleast_2d(np.asarray(weights, dtype=np.float64))

    def quad(mat: NDArray) -> NDArray[np.float64]:
        return np.asarray(((w @ mat) * w).sum(axis=1), dtype=np.float64)

    wx, wy = w @ terms.n_draws, w @ terms.n_data
    pairs_x = wx**2 - (w**2) @ terms.n_draws
    pairs_y = wy**2 - (w**2) @ terms.n_data
    with np.errstate(divide="ignore", invalid="ignore"):
        e = 2 * quad(terms.cross) / (wx * wy) - quad(terms.model) / pairs_x - quad(terms.data) / pairs_y
    return np.where((pairs_x > 0) & (pairs_y > 0), e, np.nan)


def block_multiplicities(block: NDArray, n_boot: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """Row weights ``(n_boot, n)`` of a block bootstrap.

    Whole blocks (``block``: each row's block id) are drawn with replacement, as many as there are blocks;
    each row weighs its block's count.
    """
    _, blk = np.unique(np.asarray(block), return_inverse=True)
    nb = int(blk.max()) + 1
    counts = np.stack([np.bincount(rng.integers(0, nb, nb), minlength=nb) for _ in range(n_boot)])
    return counts[:, blk].astype(np.float64)


def lag1_autocorr(z: NDArray, z_prev: NDArray) -> NDArray[np.float64]:
    """Pearson correlation of ``z_t`` with ``z_{t-1}`` per component over rows where both are finite, ``(2,)``."""
    ok = np.isfinite(z[:, 0]) & np.isfinite(z_prev[:, 0])
    if ok.sum() < 3:
        return np.full(2, np.nan)
    return np.array([np.corrcoef(z[ok, j], z_prev[ok, j])[0, 1] for j in range(2)])


def rollout(
    model: _Model, tt: TargetTuples, rng: np.random.Generator, extra: NDArray | None = None
) -> tuple[NDArray, NDArray]:
    """Closed-loop simulation over the log's target tracks (``extra``: the model's extra state per row).

    Every cycle, all targets present are sampled at once with their own simulated previous output
    (``NaN`` when the previous cycle is absent from the log or was a simulated miss) and their
    new-track flag (``True`` where the previous cycle is absent from the log: the track is new;
    ``False`` otherwise, so a simulated miss continues as a lost track).

    Returns:
        ``z (n, 2)`` simulated outputs aligned with ``tt`` and ``z_prev (n, 2)`` the simulated previous ones.
    """
    n = tt.z.shape[0]
    order = np.lexsort((tt.frame, tt.target, tt.sequence))
    pos = np.empty(n, dtype=np.int64)
    pos[order] = np.arange(n)
    prev_row = np.full(n, -1, dtype=np.int64)  # row of the previous cycle of the same target
    has = tt.has_prev_row[order]
    prev_row[order[has]] = order[np.flatnonzero(has) - 1]
    z = np.full((n, 2), np.nan)
    zp = np.full((n, 2), np.nan)
    frames = tt.frame - tt.frame.min()
    for f in np.unique(frames):  # one iteration per cycle, vectorised over targets
        rows = np.flatnonzero(frames == f)
        pr = prev_row[rows]
        zp[rows] = np.where((pr >= 0)[:, None], z[np.maximum(pr, 0)], np.nan)
        ex = _extra_kw(extra, rows)
        z[rows], _ = model.sample_cycle(tt.corner[rows], zp[rows], rng, new_track=~tt.has_prev_row[rows], **ex)
    return z, zp


def detection_by_previous(tt: TargetTuples, z: NDArray, z_prev: NDArray) -> dict[str, dict[str, float]]:
    """Detection rate and row count split by the previous cycle of each target.

    Parts: ``new`` (no previous row in the log), ``after_miss`` and ``after_detection`` (judged on the
    outputs ``z``/``z_prev`` given: recorded, or simulated by :func:`rollout`).
    """
    det, prev_det = ~np.isnan(z[:, 0]), ~np.isnan(z_prev[:, 0])
    parts = {
        "new": ~tt.has_prev_row,
        "after_miss": tt.has_prev_row & ~prev_det,
        "after_detection": tt.has_prev_row & prev_det,
    }
    return {k: {"rate": float(det[v].mean()) if v.any() else float("nan"), "n": int(v.sum())} for k, v in parts.items()}


def _extra_kw(extra: NDArray | None, rows: Any = slice(None)) -> dict[str, NDArray]:
    """``{"extra": extra[rows]}`` for a model with extra state variables, ``{}`` otherwise."""
    return {} if extra is None else {"extra": np.asarray(extra)[rows]}


def nll(model: _Model, tt: TargetTuples, extra: NDArray | None = None) -> dict[str, float]:
    """Mean negative log-likelihoods [nats] of the log's outcomes (see the module docstring).

    ``extra (n, E)``: values of the model's extra state variables at the rows (:func:`features.model_extra`).
    """
    state = np.concatenate([tt.corner, tt.z_prev], axis=1)
    new = ~tt.has_prev_row
    lp = model.log_prob(tt.z, state, new_track=new, **_extra_kw(extra))
    det = ~np.isnan(tt.z[:, 0])
    lp_miss = model.log_prob(np.full_like(tt.z, np.nan), state, new_track=new, **_extra_kw(extra))
    with np.errstate(divide="ignore", invalid="ignore"):
        lp_det = np.log1p(-np.exp(lp_miss))
    cond = lp[det] - lp_det[det]
    return {
        "nll_outcome": float(-np.mean(lp)),
        "nll_z_given_detected": float(-np.mean(cond)),
        "nll_z_given_detected_median": float(-np.median(cond)),
        "n_rows": int(lp.size),
        "n_detected": int(det.sum()),
        "n_infinite": int((~np.isfinite(lp)).sum()),
    }


def _per_bin(tt: TargetTuples, z_sim: NDArray, edges: NDArray, rng: np.random.Generator) -> list[dict[str, Any]]:
    r = np.hypot(tt.corner[:, 0], tt.corner[:, 1])
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):  # one iteration per range bin
        sel = (r >= lo) & (r < hi)
        rec, sim = tt.z[sel], z_sim[sel]
        rd, sd = ~np.isnan(rec[:, 0]), ~np.isnan(sim[:, 0])
        out.append(
            {
                "range_lo": float(lo),
                "range_hi": float(hi),
                "n": int(sel.sum()),
                "detection_rate_measured": float(rd.mean()) if sel.any() else float("nan"),
                "detection_rate_simulated": float(sd.mean()) if sel.any() else float("nan"),
                "energy_distance": energy_distance_2d(sim[sd], rec[rd], rng),
            }
        )
    return out


def evaluate(
    model: _Model,
    log: RadarLog,
    rng: np.random.Generator,
    edges: tuple[float, ...] = RANGE_BINS,
    time_series: bool | None = None,
) -> dict[str, Any]:
    """All metrics of one model on ``log`` (see the module docstring)."""
    tt = target_tuples(log)
    extra = model_extra(model, log, tt.row)
    state = np.concatenate([tt.corner, tt.z_prev], axis=1)
    res: dict[str, Any] = nll(model, tt, extra)
    z_sim, _ = model.sample_cycle(state[:, :2], state[:, 2:], rng, new_track=~tt.has_prev_row, **_extra_kw(extra))
    res["per_range_bin"] = _per_bin(tt, z_sim, np.asarray(edges, dtype=np.float64), rng)
    is_ts = bool(tt.has_prev_row.any()) if time_series is None else time_series
    if is_ts:
        zr, zpr = rollout(model, tt, rng, extra)
        res["lag1_autocorr_measured"] = lag1_autocorr(tt.z, tt.z_prev).tolist()
        res["lag1_autocorr_simulated"] = lag1_autocorr(zr, zpr).tolist()
        res["detection_rate_rollout"] = float(np.mean(~np.isnan(zr[:, 0])))
        res["detection_rate_by_previous"] = {
            "recorded": detection_by_previous(tt, tt.z, tt.z_prev),
            "rollout": detection_by_previous(tt, zr, zpr),
        }
    res["detection_rate_measured"] = float(np.mean(~np.isnan(tt.z[:, 0])))
    return res


def validate(model: _Model, baseline: _Model, log: RadarLog, seed: int = 0) -> dict[str, Any]:
    """Metrics of ``model`` and ``baseline`` on the same (held-out) ``log``."""
    return {
        "log": log.source,
        "n_rows": len(log),
        "seed": seed,
        "model": evaluate(model, log, np.random.default_rng([seed, 1])),
        "baseline_gaussian": evaluate(baseline, log, np.random.default_rng([seed, 2])),
    }


def write_report(
    report: dict[str, Any], out_dir: str | os.PathLike[str], model: Any = None, log: RadarLog | None = None
) -> Path:
    """Write ``report.json`` (and figures when ``model``/``log`` are given) into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if model is not None and log is not None:
        plot_all(report, model, log, out)
    path = out / "report.json"
    write_json(path, report)
    return path


def chi_square(
    model: Any,
    state: NDArray,
    rng: np.random.Generator,
    n: int = 95_000,
    n_bins: int = 12,
    min_expected: float = 5.0,
    extra: NDArray | None = None,
) -> dict[str, Any]:
    """Chi-square test of ``n`` two-stage samples against the binned analytic PDF at one state.

    ``extra (E,)``: the model's extra state variables at that state (None: the model has none).

    Bins: ``n_bins x n_bins`` over the central 99.8 % of the analytic output range, plus one bin for
    "outside" and one for a miss; bins with fewer than ``min_expected`` expected counts are pooled.

    Returns:
        ``statistic``, ``dof``, ``p_value`` and the binned ``expected``/``observed`` counts and edges.
    """
    from scipy.stats import chi2

    state = np.asarray(state, dtype=np.float64)
    xe = None if extra is None else np.asarray(extra, dtype=np.float64).reshape(1, -1)
    z, _ = model.sample(
        np.repeat(state[None], n, axis=0), rng, **_extra_kw(None if xe is None else np.repeat(xe, n, 0))
    )
    if has_capability(model, "output_frame"):  # bins along the axes the model's kernels are aligned with
        z = model.to_output_frame(z, np.repeat(state[None, :2], n, axis=0))
    det = ~np.isnan(z[:, 0])
    lo, hi = np.nanpercentile(z, 0.1, axis=0), np.nanpercentile(z, 99.9, axis=0)
    ex, ey = np.linspace(lo[0], hi[0], n_bins + 1), np.linspace(lo[1], hi[1], n_bins + 1)
    p, p_miss = model.bin_probabilities(state, ex, ey, **_extra_kw(xe))
    obs, _, _ = np.histogram2d(z[det, 0], z[det, 1], bins=[ex, ey])
    exp_all = np.concatenate([p.ravel(), [1.0 - p.sum() - p_miss, p_miss]]) * n
    obs_all = np.concatenate([obs.ravel(), [det.sum() - obs.sum(), (~det).sum()]])
    order = np.argsort(exp_all)
    e_sorted, o_sorted = exp_all[order], obs_all[order]
    small = e_sorted < min_expected
    e_pool = np.concatenate([[e_sorted[small].sum()], e_sorted[~small]]) if small.any() else e_sorted
    o_pool = np.concatenate([[o_sorted[small].sum()], o_sorted[~small]]) if small.any() else o_sorted
    keep = e_pool > 0
    stat = float(np.sum((o_pool[keep] - e_pool[keep]) ** 2 / e_pool[keep]))
    dof = int(keep.sum() - 1)
    return {
        "statistic": stat,
        "dof": dof,
        "p_value": float(chi2.sf(stat, dof)),
        "expected": p * n,
        "observed": obs,
        "edges_x": ex,
        "edges_y": ey,
        "p_miss": p_miss,
        "miss_share": float((~det).mean()),
    }


def plot_pdf_vs_samples(
    model: Any, state: NDArray, rng: np.random.Generator, path: Path, n: int = 95_000, extra: NDArray | None = None
) -> dict:
    """The seed's Fig. 5: binned analytic PDF next to the histogram of ``n`` two-stage samples."""
    import matplotlib.pyplot as plt

    res = chi_square(model, state, rng, n=n, n_bins=30, extra=extra)
    fig, ax = plt.subplots(1, 2, figsize=(9, 4), sharex=True, sharey=True)
    ext = [res["edges_x"][0], res["edges_x"][-1], res["edges_y"][0], res["edges_y"][-1]]
    vmax = max(res["expected"].max(), res["observed"].max())
    for a, img, title in (
        (ax[0], res["expected"], "analytic (Eq. 10), binned"),
        (ax[1], res["observed"], f"{n} two-stage samples"),
    ):
        a.imshow(img.T, origin="lower", extent=ext, aspect="auto", vmin=0, vmax=vmax)
        a.set_title(title)
        a.set_xlabel("z_x [m]")
    ax[0].set_ylabel("z_y [m]")
    fig.suptitle(
        f"state {np.round(state, 2).tolist()}: chi2 = {res['statistic']:.1f}, dof {res['dof']}, "
        f"p = {res['p_value']:.3f}"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return {k: res[k] for k in ("statistic", "dof", "p_value")}


def plot_pdf_heatmap(
    model: Any, box: NDArray, prev_z: NDArray | None, path: Path, half: float = 6.0, extra: NDArray | None = None
) -> None:
    """The seed's Fig. 3: density of the measured position around a target box (sensor frame).

    Args:
        model: a fitted model with ``log_prob``.
        box: ``(5,)`` ``x, y, heading, length, width`` [m, rad].
        prev_z: ``(2,)`` previous output [m] or ``None``.
        path: output image.
        half: half-width [m] of the plotted square around the box centre.
        extra: ``(E,)`` the model's extra state variables at the box (None: the model has none).
    """
    import matplotlib.pyplot as plt

    from sensor_envs.geometry import closest_corner, rectangle_corners

    corners = rectangle_corners(*box)
    corner = closest_corner(corners)[0][0]
    gx = np.linspace(box[0] - half, box[0] + half, 121)
    gy = np.linspace(box[1] - half, box[1] + half, 121)
    mx, my = np.meshgrid(gx, gy, indexing="ij")
    pos = np.stack([mx.ravel(), my.ravel()], axis=1)
    prev = np.full(2, np.nan) if prev_z is None else np.asarray(prev_z, dtype=np.float64)
    state = np.concatenate([np.broadcast_to(corner, pos.shape), np.broadcast_to(prev, pos.shape)], axis=1)
    ex = None if extra is None else np.repeat(np.asarray(extra, dtype=np.float64).reshape(1, -1), len(pos), axis=0)
    dens = np.exp(model.log_prob(pos - corner, state, **_extra_kw(ex))).reshape(mx.shape)
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.imshow(dens.T, origin="lower", extent=(float(gx[0]), float(gx[-1]), float(gy[0]), float(gy[-1])), cmap="viridis")
    ring = np.vstack([corners[0], corners[0][:1]])
    ax.plot(ring[:, 0], ring[:, 1], "w-", lw=1)
    ax.plot(*corner, "r+", ms=10)
    ax.set_xlabel("x [m] (sensor frame)")
    ax.set_ylabel("y [m]")
    ax.set_title("p(measured position | x), box and closest corner (+)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_all(report: dict[str, Any], model: Any, log: RadarLog, out: Path) -> None:
    """Figures of a validation report: detection calibration, energy distance, autocorrelation, PDFs."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for key, style in (("model", "o-"), ("baseline_gaussian", "s--")):
        bins = report[key]["per_range_bin"]
        mid = [0.5 * (b["range_lo"] + b["range_hi"]) for b in bins]
        ax[0].plot(mid, [b["detection_rate_simulated"] for b in bins], style, label=f"{key} simulated")
        ax[1].plot(mid, [b["energy_distance"] for b in bins], style, label=key)
    ax[0].plot(mid, [b["detection_rate_measured"] for b in bins], "k^-", label="measured")
    ax[0].set(xlabel="corner range [m]", ylabel="detection rate", title="detection calibration")
    ax[1].set(xlabel="corner range [m]", ylabel="energy distance [m]", title="sim vs measured outputs")
    for a in ax:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "calibration.png", dpi=90)
    plt.close(fig)
    tt = target_tuples(log)
    det = np.flatnonzero(~np.isnan(tt.z[:, 0]))
    if det.size:
        i = det[np.argmin(np.abs(np.hypot(*tt.corner[det].T) - 25.0))]
        row = tt.row[i]
        box = np.array([log[c][row] for c in ("ref_x", "ref_y", "ref_heading", "ref_length", "ref_width")])
        extra = model_extra(model, log, tt.row[i : i + 1])
        ex = None if extra is None else extra[0]
        prev = tt.z_prev[i] if np.isfinite(tt.z_prev[i, 0]) else None
        plot_pdf_heatmap(model, box, prev, out / "pdf_heatmap.png", extra=ex)
        if has_capability(model, "bin_probabilities"):
            st = np.concatenate([tt.corner[i], tt.z_prev[i]])
            report["model"]["chi_square_at_example_state"] = plot_pdf_vs_samples(
                model, st, np.random.default_rng(0), out / "pdf_vs_samples.png", extra=ex
            )
