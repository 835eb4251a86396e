"""Report files of the evaluations: ``report.json``, ``report.md`` and a precision-recall plot."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from sensor_envs.outputs import write_json

__all__ = ["write_report", "plot_trajectories", "report_markdown", "closeness_sentence"]

_STYLE: dict[str, dict[str, Any]] = {
    "real": dict(color="k", marker="o", lw=2.0),
    "rig": dict(color="k", marker="o", lw=2.0),
    "reference": dict(color="k", marker="o", lw=2.0),
    "model": dict(color="tab:blue", marker="s"),
    "model_world": dict(color="tab:green", marker="d", ls="--"),
    "baseline": dict(color="tab:orange", marker="^"),
    "ideal": dict(color="tab:gray", marker="x", ls=":"),
    # the same sources under the names the demo's report uses
    "learned (sample)": dict(color="tab:blue", marker="s"),
    "learned": dict(color="tab:green", marker="d", ls="--"),
    "gaussian": dict(color="tab:orange", marker="^"),
}


def plot_trajectories(trajs: dict[str, list[dict[str, Any]]], path: Path, title: str) -> None:
    """Precision (y) vs recall (x) trajectories, step numbers at the points (the seed's figure)."""
    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    for name, steps in trajs.items():
        r = [s["recall"] for s in steps]
        p = [s["precision"] for s in steps]
        ax.plot(r, p, label=name, ms=5, **_STYLE.get(name, {}))
        if name in ("real", "rig", "reference"):
            for s in steps:
                ax.annotate(
                    str(s["step"]), (s["recall"], s["precision"]), fontsize=7, xytext=(3, 3), textcoords="offset points"
                )
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def closeness_sentence(dist: dict[str, float], reference: str = "real") -> str:
    """One sentence: which simulator is closer to the reference, with both distances."""
    b = dist.get("baseline")
    out = []
    for key, what in (("model", "The learned model"), ("model_world", "The learned model as the worlds use it")):
        m = dist.get(key)
        if m is None or b is None:
            continue
        verdict = "closer to" if m < b else "NOT closer to"
        out.append(f"{what} is {verdict} the {reference} results than the baseline ({m:.3f} vs {b:.3f}).")
    return " ".join(out)


def report_markdown(report: dict[str, Any]) -> str:
    """Markdown summary of a detection-style report (trajectories table, distances, notes)."""
    ref = next((k for k in ("real", "rig") if k in report["trajectories"]), "reference")
    lines = [f"# {report['experiment']}", ""]
    if report.get("command"):
        lines += [f"Command: `{report['command']}`", ""]
    dist = report.get(f"distance_to_{ref}", {})
    lines += [f"## Distance to the {ref} trajectory (mean point-wise, precision-recall space)", ""]
    lines += [f"* {k}: **{v:.4f}**" for k, v in dist.items()]
    lines += ["", closeness_sentence(dist, ref), ""]
    for note in report.get("notes", []):
        lines += [f"* {note}"]
    names = list(report["trajectories"])
    lines += ["", "## Trajectories (precision / recall per step)", ""]
    lines += ["| step | " + " | ".join(names) + " | what changed |", "|---" * (len(names) + 2) + "|"]
    for k, s in enumerate(report["trajectories"][names[0]]):
        cells = [
            f"{report['trajectories'][n][k]['precision']:.3f} / {report['trajectories'][n][k]['recall']:.3f}"
            for n in names
        ]
        lines.append(f"| {s['step']} | " + " | ".join(cells) + f" | {s.get('name', '')} |")
    lines += ["", "## Data", "", "```json", json.dumps(report.get("data", {}), indent=1), "```", ""]
    return "\n".join(lines)


def write_report(report: dict[str, Any], folder: Path, plot_title: str | None = None) -> None:
    """Write ``report.json``, ``report.md`` and ``pr_trajectories.png`` into ``folder`` (which must exist)."""
    write_json(folder / "report.json", report)
    (folder / "report.md").write_text(report_markdown(report))
    title = plot_title or f"{report['experiment']}: detector development trajectory"
    plot_trajectories(report["trajectories"], folder / "pr_trajectories.png", title)
