"""``report.json`` + ``report.md`` + figures of a :class:`~sensor_envs.diagnose.core.DiagnoseResult`."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.diagnose.core import DiagnoseResult, Evaluation, bin_candidate
from sensor_envs.outputs import write_json

__all__ = ["write_report"]


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _binned(x: np.ndarray, r: np.ndarray, n_bins: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-bin centre (median candidate value), mean residual and its standard error."""
    ok = np.isfinite(x) & np.isfinite(r)
    b = bin_candidate(x[ok], n_bins)
    centre, mean, se = [], [], []
    for k in np.unique(b):  # one iteration per bin (at most n_bins + 1)
        sel = b == k
        centre.append(np.median(x[ok][sel]))
        mean.append(r[ok][sel].mean())
        se.append(r[ok][sel].std() / np.sqrt(max(sel.sum(), 1)))
    return np.asarray(centre), np.asarray(mean), np.asarray(se)


def plot_effect(before: Evaluation, after: Evaluation, name: str, metric: str, path: Path) -> Path:
    """Residual ``metric`` vs candidate ``name`` on the held-out readings, before and after (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for ev, label, colour in ((before, "before", "tab:red"), (after, "after", "tab:blue")):
        x, r = ev.candidates[name], ev.residuals[metric]
        ok = np.isfinite(x) & np.isfinite(r)
        idx = np.flatnonzero(ok)
        if idx.size > 3000:
            idx = idx[:: idx.size // 3000]
        ax.scatter(x[idx], r[idx], s=3, alpha=0.15, color=colour)
        c, m, se = _binned(x, r)
        ax.errorbar(c, m, yerr=2 * se, color=colour, marker="o", ms=3, lw=1.5, label=f"{label} (binned mean, 2 s.e.)")
    ax.axhline(0.0, color="k", lw=0.5)
    lo, hi = np.nanpercentile(np.concatenate([before.residuals[metric], after.residuals[metric]]), [1, 99])
    pad = 0.1 * (hi - lo + 1e-9)
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel(name)
    ax.set_ylabel(f"held-out residual {metric}")
    ax.set_title(f"{metric} vs {name}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(result: DiagnoseResult, out: Path, source: str = "") -> dict[str, Any]:
    """Write ``report.json``, ``report.md`` and one figure per added (or, if none, the top) effect into ``out``.

    Returns:
        The JSON content.
    """
    assert result.before is not None and result.after is not None
    out.mkdir(parents=True, exist_ok=True)
    data = result.to_json()
    data["details"]["source"] = source
    figs = []
    shown = result.added or [e["name"] for e in result.effects[:1]]
    for name in shown:
        e = (
            next(x for x in result.effects if x["name"] == name)
            if name in [x["name"] for x in result.effects]
            else None
        )
        metric = e["metric"] if e else "nll"
        fname = f"effect_{_slug(name)}_{metric}.png"
        plot_effect(result.before, result.after, name, metric, out / fname)
        figs.append((name, metric, fname))
    data["details"]["figures"] = [f for _, _, f in figs]
    write_json(out / "report.json", data)
    (out / "report.md").write_text(_markdown(result, data, figs, source), encoding="utf-8")
    return data


def _markdown(result: DiagnoseResult, data: dict[str, Any], figs: list[tuple[str, str, str]], source: str) -> str:
    s = data["details"]["settings"]
    lines = [
        f"# Diagnosis of the {result.kind} model",
        "",
        f"Log: `{source}`. Held-out readings: {data['details']['readings_held_out']}.",
        "",
        f"Significance: max-T adjusted p < {s['alpha']} (Westfall-Young, {s['n_permutations']} permutations, "
        f"family-wise over all candidates and residual metrics) and cross-fitted R^2 >= {s['min_score']}.",
        "",
    ]
    if not any(e["significant"] for e in result.effects):
        lines += [
            "**No effect is significant**: no candidate outside the model's state explains its held-out residuals.",
            "",
        ]
    lines += [
        f"Added to the state: {', '.join(result.added) if result.added else 'nothing'}.",
        "",
        "| | held-out NLL per reading [nats] |",
        "|---|---|",
        f"| before | {result.error_before:.4f} |",
        f"| after | {result.error_after:.4f} |",
    ]
    if result.baseline_before is not None:
        lines += [
            f"| Gaussian baseline, same state before | {result.baseline_before:.4f} |",
            f"| Gaussian baseline, same state after | {result.baseline_after:.4f} |",
        ]
    lines += ["", "## Candidate effects (residuals of the base model), best first", ""]
    lines += ["| effect | score (R^2) | p (max-T) | p (raw) | metric | significant |", "|---|---|---|---|---|---|"]
    for e in result.effects:
        lines.append(
            f"| {e['name']} | {e['score']:.4f} | {e['p_value']:.4f} | {e['p_raw']:.4f} | {e['metric']} | "
            f"{'yes' if e['significant'] else 'no'} |"
        )
    if result.state_misfit:
        lines += [
            "",
            "## Misfit along the model's own state (not an effect it lacks; e.g. kernel widths)",
            "",
            "| state feature | score (R^2) | p (max-T) | metric | significant |",
            "|---|---|---|---|---|",
        ]
        for e in result.state_misfit:
            sig = "yes" if e["significant"] else "no"
            lines.append(f"| {e['name']} | {e['score']:.4f} | {e['p_value']:.4f} | {e['metric']} | {sig} |")
    lines += ["", "## Steps", ""]
    for i, st in enumerate(result.steps):
        lines.append(f"{i + 1}. model with held-out NLL {st['error']:.4f}:")
        for at in st.get("attempts", []):
            base = "" if at["baseline_with"] is None else f", Gaussian baseline with it {at['baseline_with']:.4f}"
            lines.append(f"   - refit with {at['candidate']}: NLL {at['error_with']:.4f}{base}: {at['decision']}")
        if not st.get("attempts"):
            lines.append(f"   - {st.get('decision', '')}")
    lines += ["", "## Residual vs effect, before and after", ""]
    for name, metric, fname in figs:
        lines += [f"![{metric} vs {name}]({fname})", ""]
    return "\n".join(lines) + "\n"
