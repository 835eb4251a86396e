"""The collision anatomy's report: markdown tables, a JSON record and a plot (see :mod:`.collisions`).

:func:`write_report` replays a finished highway robustness run (:func:`~sensor_envs.training.collisions.replay_run`),
summarises it and writes the page (the text above :data:`MARKER` of an existing page, written by hand, is
kept), the JSON (the summary, every crash record, the run's settings and its policies' SHA-256) and the plot;
each file through a temporary file and a rename.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.training.collisions import SHARES, replay_run, summarise
from sensor_envs.training.matrix_report import _write_atomic

__all__ = ["MARKER", "markdown", "plot", "write_report"]

MARKER = "<!-- generated below by benchmarks/highway_collision_report.py: do not edit below this line -->"


def _fmt(share: dict[str, Any]) -> str:
    if not share["n"]:
        return "-"
    lo, hi = share["ci95"]
    return f"{share['k']}/{share['n']} = {share['rate']:.2f} [{lo:.2f}, {hi:.2f}]"


def markdown(summary: dict[str, Any], meta: dict[str, Any]) -> str:
    """The generated part of the page: how it was made, then one table row per cell."""
    cells = summary["cells"]
    agree = [
        (v["replay_matches_matrix"], v["episodes"]) for v in cells.values() if v["replay_matches_matrix"] is not None
    ]
    lines = [
        MARKER,
        "",
        f"## The replay ({meta['date_utc']})",
        "",
        f"Command: `{meta['command']}` ({meta['seconds'] / 60:.0f} min). Run folder: `{meta['run']}`, made by "
        f"`{meta.get('run_command', 'command not recorded')}`; evaluated policy of each job: "
        f"`{meta['policy']}_model.zip`; seeds {meta['seeds']}; {summary['episodes']} episodes per seed and column, "
        "the matrix's own (episode e resets with seed 1,000,000 + e), deterministic actions.",
        "",
        f"The replay reproduces the matrix's recorded collision outcome in {sum(a for a, _ in agree)} of "
        f"{sum(n for _, n in agree)} episodes.",
        "",
        "Rates pool the seeds' episodes (crashes / episodes) and shares the cell's crashes, each with a 95 % Wilson "
        "interval (episodes and crashes taken as independent: a seed's episodes share its policy, so these are "
        "narrower than the matrix's seed bootstrap). Geometry (field of view, shown, zone) counts the crashes whose "
        "hit car was within highway-env's perception distance at the last observation.",
        "",
        "| trained on -> evaluated on | collision | lane change under way | hit car outside the front 100° view "
        "1 s before | both | hit car in the last observation | visible to this column's radar | "
        "braking (SLOWER) | zone 1 s before: ahead / beside / behind |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for key, v in cells.items():
        s, z = v["shares"], v["zones"]
        lines.append(
            f"| {key.replace('->', ' -> ')} | {_fmt(v['collision'])} | {_fmt(s['lane_change'])} | "
            f"{_fmt(s['outside_front_fov'])} | {_fmt(v['lane_change_and_outside_front_fov'])} | {_fmt(s['shown'])} | "
            f"{_fmt(v['visible_to_column_radar'])} | {_fmt(s['braking'])} | "
            f"{z['ahead']} / {z['beside']} / {z['behind']} |"
        )
    lines += ["", f"![collision anatomy]({meta['plot']})" if meta.get("plot") else "", ""]
    return "\n".join(lines)


def plot(summary: dict[str, Any], path: Path) -> None:
    """Two panels: each cell's collision rate, and the shares of :data:`SHARES` among its crashes (Wilson bars)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = summary["cells"]
    keys = list(cells)
    labels = [k.replace("->", "\n-> ") for k in keys]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(13, 4.8), gridspec_kw={"width_ratios": [1, 2]})
    x = np.arange(len(keys))
    rate = np.array([cells[k]["collision"]["rate"] for k in keys])
    ci = np.array([cells[k]["collision"]["ci95"] for k in keys])
    ax0.bar(x, rate, color="0.5", label="collision rate")
    yerr = np.clip([rate - ci[:, 0], ci[:, 1] - rate], 0, None)  # Wilson bounds hold the rate up to rounding
    ax0.errorbar(x, rate, yerr=yerr, fmt="none", color="k", capsize=3, label="95 % Wilson")
    ax0.set(xticks=x, ylim=(0, 1), ylabel="share of evaluation episodes", title="Collision rate per cell")
    ax0.set_xticklabels(labels, fontsize=7, rotation=90)
    ax0.legend(fontsize=8)
    width = 0.8 / len(SHARES)
    for i, (name, label) in enumerate(SHARES.items()):
        shares = [cells[k]["shares"][name] for k in keys]
        val = np.array([s["rate"] if s["n"] else np.nan for s in shares])
        lo = np.array([s["ci95"][0] for s in shares])
        hi = np.array([s["ci95"][1] for s in shares])
        pos = x + (i - (len(SHARES) - 1) / 2) * width
        ax1.bar(pos, val, width, label=label)
        err = np.clip([val - lo, hi - val], 0, None)
        ax1.errorbar(pos, val, yerr=err, fmt="none", color="k", capsize=2, lw=0.8)
    ax1.set(xticks=x, ylim=(0, 1.05), ylabel="share of the cell's crashes", title="What preceded the crashes")
    ax1.set_xticklabels(labels, fontsize=7, rotation=90)
    ax1.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.suptitle("Crash anatomy, trained on -> evaluated on (error bars: 95 % Wilson intervals)")
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=90, bbox_inches="tight")
    plt.close(fig)
    tmp.replace(path)


def write_report(
    run: Path,
    md: Path,
    json_path: Path | None,
    png: Path | None,
    command: str,
    columns: list[str] | None = None,
    episodes: int | None = None,
    workers: int = 1,
    seeds: list[int] | None = None,
) -> dict[str, Any]:
    """Replay ``run``, then write ``md`` (keeping the hand-written text above :data:`MARKER`), the JSON and plot."""
    t0 = time.perf_counter()
    replay = replay_run(run, columns=columns, episodes=episodes, workers=workers, seeds=seeds)
    summary = summarise(replay)
    matrix = json.loads((run / "matrix.json").read_text()) if (run / "matrix.json").is_file() else {}
    settings = replay["settings"]
    meta = {
        "command": command,
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "seconds": time.perf_counter() - t0,
        "run": str(run),
        "run_command": matrix.get("run", {}).get("command"),
        "policy": settings.get("policy", "final"),
        "seeds": replay["seeds"],
        "plot": png.name if png is not None else None,
    }
    if png is not None:
        plot(summary, png)
    head = md.read_text(encoding="utf-8").split(MARKER)[0] if md.is_file() else "# Collision anatomy\n\n"
    _write_atomic(md, head + markdown(summary, meta))
    if json_path is not None:
        record = {
            **summary,
            "meta": meta,
            "run_settings": settings,
            "sha256": matrix.get("run", {}).get("sha256"),
            "crashes": replay["crashes"],
        }
        _write_atomic(json_path, json.dumps(record, indent=None, separators=(",", ":")) + "\n")
    return {"summary": summary, "meta": meta}
