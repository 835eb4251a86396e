"""The highway robustness matrix's results page, generated from a finished `sensor-envs robustness` run.

    python benchmarks/highway_matrix_report.py --run runs/highway_matrix \
        --md docs/results/highway_matrix.md --png docs/results/highway_matrix.png \
        --json docs/results/highway_matrix.json [--baseline ideal_surround] --force

Reads the run folder (``matrix.json``, ``matrix.md``, ``matrix.png``, and per job ``eval.json``,
``config.json`` and the ``EvalCallback`` learning curve ``evaluations.npz``) and writes below the marker
line of ``--md`` (the text above it, written by hand, is kept): the command, date and SHA-256 of the sensor
models and policies (from ``matrix.json``), the matrix tables with their intervals (``matrix.md`` as the
command wrote it), each job's learning curve (mean return and episode length of the curve's evaluation
episodes at each evaluation step) and its cost (training and evaluation seconds,
training steps per second). Prints the same figures. ``--md`` / ``--png`` are refused when they exist
unless ``--force``; both are written through a temporary file and a rename.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

MARKER = "<!-- generated below by benchmarks/highway_matrix_report.py: do not edit below this line -->"


def learning_curves(run: Path, rows: list[str], seeds: list[int]) -> list[str]:
    """Markdown table of each job's EvalCallback curve (return, episode length) and its cost."""
    lines = [
        "| job | steps | eval return (mean) | eval episode length (of 30) | best checkpoint: step, crashes in the "
        "callback's episodes | its collision rate on the matrix's 30 episodes, own radar | train s | steps/s | "
        "matrix eval s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for s in seeds:
            job = run / "runs" / r / f"seed{s}"
            ev = json.loads((job / "eval.json").read_text())
            steps = int(ev["spec"]["set"]["n_timesteps"])
            curve = np.load(job / "evaluations.npz")
            t = curve["timesteps"].tolist()
            ret = curve["results"].mean(axis=1)
            length = curve["ep_lengths"].mean(axis=1)
            best = int(np.argmax(ret))  # EvalCallback keeps the first evaluation with the highest mean return
            crashed = curve["ep_lengths"][best] < EPISODE_STEPS  # a highway-fast episode ends early on a crash
            own = np.mean(ev["cells"][r]["collision"]) if r in ev["cells"] else float("nan")
            picked = f"{t[best]:,}: {int(crashed.sum())} of {crashed.size}"
            if ev["spec"].get("policy", "final") != "best":
                picked += " (not the evaluated model)"
            lines.append(
                f"| {r} seed {s} | {', '.join(f'{v:,}' for v in t)} | {', '.join(f'{v:.1f}' for v in ret)} | "
                f"{', '.join(f'{v:.1f}' for v in length)} | {picked} | {own:.2f} | {ev['train_seconds']:.0f} | "
                f"{steps / ev['train_seconds']:.1f} | {ev['eval_seconds']:.0f} |"
            )
    return lines


EPISODE_STEPS = 30  # highway-fast-v0's duration in policy steps
TARGET = 0.2  # issue 41: an ideal-trained agent collides in <= 0.2 of the episodes on its own radar


def _cell(matrix: dict, row: str, col: str, metric: str) -> str:
    v = matrix["cells"][f"{row}->{col}"][metric]
    return f"{v['mean']:.2f} [{v['mean_ci95'][0]:.2f}, {v['mean_ci95'][1]:.2f}]"


def targets(matrix: dict, baseline: str = "ideal") -> list[str]:
    """Issue 41's two targets, read off the matrix: the baseline row on its own radar against ``TARGET``, and
    each other row against the baseline row on that row's radar (collision probability of improvement)."""
    rows, cols = matrix["rows_trained_on"], matrix["columns_evaluated_on"]
    if baseline not in rows or baseline not in cols:
        return []
    own = matrix["cells"][f"{baseline}->{baseline}"]["collision"]
    per_seed = own["per_seed"]
    has_speed = "speed" in matrix["cells"][f"{baseline}->{baseline}"]
    lines = [
        "## Issue 41's targets, read off this run",
        "",
        f"* `{baseline}`-trained on `{baseline}`: collision {_cell(matrix, baseline, baseline, 'collision')} "
        f"(mean [95 % CI]); target <= {TARGET}: **{'met' if own['mean'] <= TARGET else 'NOT met'}** by the mean, "
        f"{sum(v <= TARGET for v in per_seed)} of {len(per_seed)} seeds at or below it "
        f"(per seed: {', '.join(f'{v:.2f}' for v in per_seed)})"
        + (f"; mean speed {_cell(matrix, baseline, baseline, 'speed')} m/s." if has_speed else "."),
    ]
    for r in rows:
        if r == baseline or r not in cols:
            continue
        key = f"{baseline} vs {r} @ {r}"
        pi = matrix["probability_of_improvement"]["collision"][key]
        p, (lo, hi) = 1 - pi["p"], (1 - pi["ci95"][1], 1 - pi["ci95"][0])  # P(row r safer than the baseline row)
        verdict = "shown (interval above 0.5)" if lo > 0.5 else "NOT shown (interval includes or is below 0.5)"
        lines.append(
            f"* On `{r}`: trained on `{r}` collision {_cell(matrix, r, r, 'collision')} vs trained on `{baseline}` "
            f"{_cell(matrix, baseline, r, 'collision')}; P(a `{r}`-trained policy is safer) = {p:.2f} "
            f"[{lo:.2f}, {hi:.2f}]: **{verdict}**"
            + (
                f"; mean speed {_cell(matrix, r, r, 'speed')} vs {_cell(matrix, baseline, r, 'speed')} m/s."
                if has_speed
                else "."
            )
        )
    return [*lines, ""]


def callback_episodes(run: Path, matrix: dict) -> str:
    """The number of episodes of the jobs' EvalCallback evaluations (from the first job's curve)."""
    job = run / "runs" / matrix["rows_trained_on"][0] / f"seed{matrix['seeds'][0]}"
    return str(np.load(job / "evaluations.npz")["results"].shape[1])


def render(run: Path, baseline: str = "ideal") -> str:
    """The generated part of the page (issue 41's targets against the ``baseline`` row)."""
    matrix = json.loads((run / "matrix.json").read_text())
    meta = matrix["run"]
    table = (run / "matrix.md").read_text().split("\n", 2)[2]  # without the title line
    lines = [
        MARKER,
        "",
        f"## The run ({meta.get('date_utc', 'date not recorded')})",
        "",
        f"Command: `{meta['command']}` (backend {meta['backend']}, wall time {meta['wall_seconds'] / 60:.0f} min "
        f"for the {meta.get('jobs_run', '?')} jobs this invocation ran; jobs already done are not timed again). "
        f"Evaluated policy of each job: `{meta.get('policy', 'final')}_model.zip`"
        + {
            "best": " (EvalCallback's best on held-out seeds)",
            "selected": " (each job's checkpoint with the fewest "
            "collisions on validation episodes of its own sensor: selection.json)",
        }.get(meta.get("policy"), "")
        + ". Page: `python benchmarks/highway_matrix_report.py --run <out> --md ... --force`.",
        "",
        *targets(matrix, baseline),
        table.replace("\n## ", "\n### "),
        "## Learning curves and cost per job",
        "",
        f"`EvalCallback` during training: {callback_episodes(run, matrix)} deterministic episodes on the job's own "
        "sensor (other seeds than the matrix's) at each evaluation step "
        "(highway-fast episodes last at most 30 policy steps; a shorter mean length means crashes).",
        "",
        *learning_curves(run, matrix["rows_trained_on"], matrix["seeds"]),
        "",
    ]
    return "\n".join(lines)


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path`` and rename it into place."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="the --out folder of a finished robustness run")
    parser.add_argument("--md", type=Path, required=True, help="results page (text above the marker is kept)")
    parser.add_argument("--png", type=Path, default=None, help="copy of the run's matrix.png")
    parser.add_argument("--json", type=Path, default=None, help="copy of the run's matrix.json (cells, hashes)")
    parser.add_argument(
        "--baseline", default="ideal", help="the row issue 41's targets compare with (e.g. ideal_surround)"
    )
    parser.add_argument("--force", action="store_true", help="replace existing --md / --png")
    args = parser.parse_args(argv)
    if not (args.run / "matrix.json").is_file():
        print(f"highway_matrix_report: error: {args.run / 'matrix.json'}: not found", file=sys.stderr)
        raise SystemExit(2)
    for out in (args.md, args.png, args.json):
        if out is not None and out.exists() and not args.force:
            print(f"highway_matrix_report: error: {out} exists (use --force)", file=sys.stderr)
            raise SystemExit(2)
    head = ""
    if args.md.is_file():
        head = args.md.read_text(encoding="utf-8").split(MARKER)[0]
    body = render(args.run, args.baseline)
    write_atomic(args.md, (head + body).encode("utf-8"))
    if args.png is not None:
        write_atomic(args.png, (args.run / "matrix.png").read_bytes())
    if args.json is not None:
        write_atomic(args.json, (args.run / "matrix.json").read_bytes())
    print(body)


if __name__ == "__main__":
    main()
