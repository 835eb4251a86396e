"""The robustness matrix's reports: ``matrix.json``, ``matrix.md`` (tables) and ``matrix.png`` (heat maps).

:func:`write_reports` writes what :func:`sensor_envs.training.robustness.build_matrix` computed, each file
atomically (a temporary file beside it, then a rename); :mod:`sensor_envs.training.robustness` re-exports it.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["HIGHER_IS_BETTER", "headline", "write_reports"]

HIGHER_IS_BETTER = {"return": True, "success": True, "collision": False}
"""Metrics compared between rows (probability of improvement); others (``speed``) are descriptive only."""


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path`` and rename it into place."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(tmp, path)


def headline(metric: str) -> str:
    """The statistic a table shows: the mean for rates (0/1 per episode) and speeds, the IQM otherwise."""
    return "mean" if metric in ("success", "collision", "speed") else "iqm"


def write_reports(out: Path, matrix: dict[str, Any], meta: dict[str, Any]) -> None:
    """``matrix.json``, ``matrix.md`` and ``matrix.png`` (one heat map per metric), each written atomically."""
    import matplotlib

    matrix = {**matrix, "run": meta}
    _write_atomic(out / "matrix.json", json.dumps(matrix, indent=1))
    rows, cols = matrix["rows_trained_on"], matrix["columns_evaluated_on"]
    lines = [
        f"# Robustness matrix: {matrix['env_id']}",
        "",
        "Rows: sensor trained on; columns: sensor evaluated on. Cells: IQM of returns, mean of rates, "
        f"[95 % CI] ({matrix['interval']}).",
        f"Seeds {matrix['seeds']}, {meta['eval_episodes']} evaluation episodes per seed and column; "
        f"preset {meta['preset']!r}; algo {meta['algo']}; wall time {meta['wall_seconds']:.0f} s.",
        f"Command: `{meta['command']}`",
        "",
    ]
    if "sha256" in meta:
        digests = meta["sha256"]
        when = (
            "as the jobs recorded them" if digests.get("hashed_at") == "jobs" else "hashed when the report was written"
        )
        if "sensor_models_by_job" in digests:
            when += "; the jobs used DIFFERENT sensor models (matrix.json: sensor_models_by_job)"
        lines += [f"Report written {meta['date_utc']}. SHA-256 of the sensor models ({when}) and policies:", ""]
        for group in ("sensor_models", "policies"):
            lines += [f"- {name}: `{digest}`" for name, digest in digests[group].items()]
        lines.append("")
    for m in matrix["metrics"]:
        stat = headline(m)
        lines += [f"## {m} ({stat.upper() if stat == 'iqm' else stat})", ""]
        lines += ["| trained on \\ evaluated on | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
        for r in rows:
            vals = [matrix["cells"][f"{r}->{c}"][m] for c in cols]
            cells = [f"{v[stat]:.2f} [{v[stat + '_ci95'][0]:.2f}, {v[stat + '_ci95'][1]:.2f}]" for v in vals]
            lines.append(f"| {r} | " + " | ".join(cells) + " |")
        pairs = matrix["probability_of_improvement"].get(m)
        if pairs:
            better = "higher" if HIGHER_IS_BETTER[m] else "lower"
            lines += ["", f"Probability of improvement ({better} {m} is better), P(first row better) [95 % CI]:", ""]
            lines += [f"- {k}: {v['p']:.2f} [{v['ci95'][0]:.2f}, {v['ci95'][1]:.2f}]" for k, v in pairs.items()]
        lines.append("")
    _write_atomic(out / "matrix.md", "\n".join(lines))
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(matrix["metrics"]), figsize=(4.2 * len(matrix["metrics"]), 3.6), squeeze=False)
    for ax, m in zip(axes[0], matrix["metrics"], strict=True):
        grid = np.array([[matrix["cells"][f"{r}->{c}"][m][headline(m)] for c in cols] for r in rows])
        im = ax.imshow(grid, cmap="viridis")
        for (i, j), v in np.ndenumerate(grid):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", color="w", fontsize=8)
        ax.set(xticks=range(len(cols)), xticklabels=cols, yticks=range(len(rows)), yticklabels=rows, title=m)
        ax.set_xlabel("evaluated on")
        ax.set_ylabel("trained on")
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    fd, tmp = tempfile.mkstemp(dir=out, prefix=".matrix.", suffix=".png")
    os.close(fd)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, out / "matrix.png")
