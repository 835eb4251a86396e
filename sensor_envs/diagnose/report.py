"""``report.json`` + ``report.md`` + figures of a :class:`~sensor_envs.diagnose.core.DiagnoseResult`."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.diagnose.core import DiagnoseResult, Evaluation, bin_candidate
from sensor_envs.outputs import write_json

__all__ = ["write_report", "describe_effect"]

UNITS = {
    "null": "null probability",
    "detection": "detection probability",
    "range": "m",
    "offset_x": "m",
    "offset_y": "m",
    "pit": "PIT",
    "nll": "nats",
    "range_spread": "sqrt(|residual| / sigma)",
    "pit_spread": "PIT distance from the scan median",
    "offset_spread": "sqrt(offset / RMS)",
}
"""Unit of each residual metric (the size of a finding is stated in it)."""


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


def _slope(x: np.ndarray, r: np.ndarray) -> tuple[float, float, float, float]:
    """OLS slope of ``r`` on ``x``, the 5th/95th percentiles of ``x`` and the binned-mean change between them."""
    ok = np.isfinite(x) & np.isfinite(r)
    if ok.sum() < 10 or np.ptp(x[ok]) == 0:
        return float("nan"), float("nan"), float("nan"), float("nan")
    xo, ro = x[ok], r[ok]
    lo, hi = np.percentile(xo, [5, 95])
    slope = float(np.polyfit(xo, ro, 1)[0])
    c, m, _ = _binned(xo, ro, 10)
    change = float(m[-1] - m[0]) if len(m) > 1 else float("nan")
    return slope, float(lo), float(hi), change


def describe_effect(ev: Evaluation, effect: dict[str, Any]) -> dict[str, Any]:
    """Kind, form and size of a finding in the metric's units, measured on the held-out readings of ``ev``.

    A main effect: the OLS slope of the residual metric per unit of the candidate and the change of its
    binned mean from the candidate's lowest to highest tenth. An interaction with a state feature: the
    same slope within each quarter of that feature (e.g. bearing sector), so the sign pattern shows.
    """
    name, metric = effect["name"], effect["metric"]
    x, r = ev.candidates[name], ev.residuals[metric]
    unit = UNITS.get(metric, "")
    slope, lo, hi, change = _slope(x, r)
    out: dict[str, Any] = {
        "name": name,
        "kind": effect.get("kind", "mean"),
        "form": effect.get("form", "main"),
        "metric": metric,
        "unit": unit,
        "p_value": effect["p_value"],
        "test": effect.get("test", "held-out"),
        "slope_per_unit": slope,
        "range_of_cause": [lo, hi],
        "change_across_range": change,
    }
    text = (
        f"{metric} changes by {change:+.3g} {unit} from {name} = {lo:.3g} to {hi:.3g} "
        f"(slope {slope:+.3g} {unit} per unit of {name})"
    )
    form = effect.get("form", "main")
    if form.startswith("x ") and form[2:] in ev.state:
        s = ev.state[form[2:]]
        edges = np.nanpercentile(s, [0, 25, 50, 75, 100])
        parts = []
        for k in range(4):  # the slope within each quarter of the state feature
            sel = (s >= edges[k]) & (s <= edges[k + 1])
            sl = _slope(x[sel], r[sel])[0]
            parts.append({"state_from": float(edges[k]), "state_to": float(edges[k + 1]), "slope_per_unit": sl})
        out["by_state"] = parts
        text = f"slope of {metric} per unit of {name}, by {form[2:]} quarter: " + ", ".join(
            f"{p['slope_per_unit']:+.3g} {unit} ({form[2:]} {p['state_from']:.3g}..{p['state_to']:.3g})" for p in parts
        )
    if effect.get("via_proxy"):
        text += f"; found through its proxy {effect['via_proxy']}, which it explains (not the other way round)"
    out["text"] = text
    return out


def plot_effect(before: Evaluation, after: Evaluation, name: str, metric: str, path: Path, form: str = "main") -> Path:
    """Residual ``metric`` vs candidate ``name`` on the held-out readings, before and after (PNG).

    An interaction (``form`` ``x <state feature>``): one panel per quarter of that state feature (e.g.
    bearing sector, range band), so a sign that follows the state shows; a main effect: one panel.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    state = form[2:] if form.startswith("x ") and form[2:] in before.state else ""
    panels = _state_quarters(before, state) if state else [("", None)]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels) + 1.2, 4.0), squeeze=False, sharey=True)
    unit = UNITS.get(metric, "")
    lo, hi = np.nanpercentile(np.concatenate([before.residuals[metric], after.residuals[metric]]), [1, 99])
    pad = 0.1 * (hi - lo + 1e-9)
    for ax, (label, sel) in zip(axes[0], panels, strict=True):
        for ev, when, colour in ((before, "before", "tab:red"), (after, "after", "tab:blue")):
            x, r = ev.candidates[name], ev.residuals[metric]
            keep = np.isfinite(x) & np.isfinite(r) & (True if sel is None else sel)
            idx = np.flatnonzero(keep)
            if idx.size > 3000:
                idx = idx[:: idx.size // 3000]
            ax.scatter(x[idx], r[idx], s=3, alpha=0.15, color=colour)
            if keep.sum() >= 2:
                c, m, se = _binned(x[keep], r[keep], 10)
                ax.errorbar(c, m, yerr=2 * se, color=colour, marker="o", ms=3, lw=1.5, label=f"{when} (mean, 2 s.e.)")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_xlabel(name)
        ax.set_title(label or f"{metric} vs {name}", fontsize=9)
    axes[0][0].set_ylabel(f"held-out residual {metric}" + (f" [{unit}]" if unit else ""))
    axes[0][0].legend(fontsize=7)
    if state:
        fig.suptitle(f"{metric} vs {name}, by quarter of {state}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _state_quarters(ev: Evaluation, state: str) -> list[tuple[str, np.ndarray]]:
    """``(label, mask)`` of each quarter of a state feature's held-out values."""
    s = ev.state[state]
    edges = np.nanpercentile(s, [0, 25, 50, 75, 100])
    out = []
    for k in range(4):
        sel = (s >= edges[k]) & ((s < edges[k + 1]) if k < 3 else (s <= edges[k + 1]))
        out.append((f"{state} {edges[k]:.3g}..{edges[k + 1]:.3g}", sel))
    return out


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
        plot_effect(result.before, result.after, name, metric, out / fname, str(e.get("form", "main")) if e else "main")
        figs.append((name, metric, fname))
    data["details"]["figures"] = [f for _, _, f in figs]
    findings = [e for e in result.effects if e["significant"]] or result.effects[:1]
    data["details"]["findings"] = [describe_effect(result.before, e) for e in findings] + _later_findings(result)
    data["details"]["metrics_before_after"] = {
        m: {
            "rms_before": data["details"]["metrics_before"][m]["rms"],
            "rms_after": data["details"]["metrics_after"][m]["rms"],
        }
        for m in data["details"]["metrics_before"]
        if m in data["details"]["metrics_after"]
    }
    write_json(out / "report.json", data)
    (out / "report.md").write_text(_markdown(result, data, figs, source), encoding="utf-8")
    return data


def _later_findings(result: DiagnoseResult) -> list[dict[str, Any]]:
    """Findings added after the first step (found once earlier additions were in the model).

    Each is described on the base model's residuals (``step``: the ranking that found it; ``terms``: what
    was added).
    """
    assert result.before is not None
    out = []
    for i, st in enumerate(result.steps[1:], start=2):
        for at in st.get("attempts", []):
            if not str(at.get("decision", "")).startswith("added"):
                continue
            row = next((r for r in st["ranking"] if r["name"] == at["candidate"]), None)
            if row is None or row["metric"] not in result.before.residuals:
                continue
            f = describe_effect(result.before, {**row, "form": at.get("form") or row["form"]})
            f.update(step=i, terms=list(at["terms"]))
            out.append(f)
    return out


def _markdown(result: DiagnoseResult, data: dict[str, Any], figs: list[tuple[str, str, str]], source: str) -> str:
    s = data["details"]["settings"]
    lines = [
        f"# Diagnosis of the {result.kind} model",
        "",
        f"Log: `{source}`. Held-out readings: {data['details']['readings_held_out']}.",
        "",
        f"Significance: max-T adjusted p < {s['alpha']} (Westfall-Young, {s['n_permutations']} block sign-flips "
        f"of the residuals, family-wise over all candidates, regressors and residual metrics; a finding "
        f"confirmed by {s.get('n_shifts', 0)} circular shifts of the residuals along time) and held-out "
        f"R^2 >= {s['min_score']}.",
        "",
    ]
    if not any(e["significant"] for e in result.effects):
        lines += [
            "**No effect is significant**: no candidate outside the model's state explains its held-out residuals.",
            "",
        ]
    lines += [
        f"Added to the state: {', '.join(result.added) if result.added else 'nothing'}"
        + (
            f" (terms: {', '.join(f'`{t}`' for t in s['state_after'] if t not in s['state_before'])})."
            if result.added
            else "."
        ),
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
    lines += ["", "## Findings", ""]
    for f in data["details"]["findings"]:
        added = "added" if f["name"] in result.added else "not added"
        if "step" in f:  # found after earlier additions: say when, and what it added
            added = f"found at step {f['step']}, added as {', '.join(f['terms'])}; size on the base model's residuals"
        lines.append(
            f"- **{f['name']}** ({f['kind']} effect, form {f['form']}, p {f['p_value']:.3g} by the {f['test']} test, "
            f"{added}): {f['text']}"
        )
    for u in data["details"].get("unrepresented", []):
        lines.append(f"- cannot be represented: {u['why']}")
    for u in data["details"].get("refused", []):
        lines.append(f"- candidate {u['name']} {u['reason']}")
    lines += ["", "| residual metric | RMS before | RMS after |", "|---|---|---|"]
    for m, v in data["details"]["metrics_before_after"].items():
        lines.append(f"| {m} | {v['rms_before']:.4g} | {v['rms_after']:.4g} |")
    lines += ["", "## Candidate effects (residuals of the base model), best first", ""]
    lines += [
        "| effect | score (R^2) | p (family-wise) | p (raw, held-out) | metric | kind | form | test | significant |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for e in result.effects:
        sig = "yes" if e["significant"] else (f"no (proxy of {e['proxy_of']})" if e.get("proxy_of") else "no")
        if "p_surrogate" in e:  # how unrelated series like the candidate do on the same residuals
            sig += f"; p {e['p_surrogate']:.3f} against series like it"
        lines.append(
            f"| {e['name']} | {e['score']:.4f} | {e['p_value']:.4f} | {e['p_raw']:.4f} | {e['metric']} | "
            f"{e.get('kind', '')} | {e.get('form', '')} | {e.get('test', 'held-out')} | {sig} |"
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
            form = f" ({at['kind'] or 'mean'} effect, form {at['form']})" if at.get("form") else ""
            lines.append(f"   - refit with {at['candidate']}{form}: NLL {at['error_with']:.4f}{base}: {at['decision']}")
        if not st.get("attempts"):
            lines.append(f"   - {st.get('decision', '')}")
    lines += ["", "## Residual vs effect, before and after", ""]
    for name, metric, fname in figs:
        lines += [f"![{metric} vs {name}]({fname})", ""]
    return "\n".join(lines) + "\n"
