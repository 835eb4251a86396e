"""Measure ``diagnose`` as a property: recall per effect kind and false positives on null logs.

Draws cases from the seeded families of :mod:`sensor_envs.diagnose.families` (lidar: mean,
interaction with bearing, spread, null rate, AR(1) correlation, null; radar: mean, interaction with
azimuth side, spread, detection rate, null), runs the diagnosis loop on each exactly as the CLI does
(:func:`sensor_envs.diagnose.core.run_diagnose` with the sensor's adapter and a block split), and
prints, per sensor and kind:

* recall: the cause ranked first AND added AND the held-out NLL down; the share of cases where a
  proxy, and where any column other than the cause (proxy or distractor), was added;
* for null logs, the false-positive rate: any effect significant (and, separately, any added).

Writes ``suite.json`` (every case: drawn parameters, ranking head, decision) and ``suite.md``.

Usage (a few minutes, niced)::

    nice -n 10 python benchmarks/diagnose_suite.py --cases 3 --seed 0 --out /tmp/suite

``--cases N`` cases per kind and sensor; ``--sensor lidar|radar|both``; ``--scans``/``--bearings``
and ``--sequences`` set the log sizes (the shared real logs: ~2,500 scans x 360 bearings; ~20,000
radar rows = ``--sequences 60``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.diagnose.core import block_split, run_diagnose
from sensor_envs.diagnose.families import LIDAR_KINDS, RADAR_KINDS, Case, lidar_case, radar_case

LIDAR_FIT = {
    "variant": "seed",
    "n_folds": 3,
    "h_range_grid": (0.25, 1.6),
    "h_alpha_grid": (0.5, 4.0),
    "verbose": False,
}
"""Table fit of the lidar cases (the fast seed variant: the suite measures the search, not the tables)."""


def diagnose_case(case: Case, sensor: str, permutations: int, seed: int, alpha: float = 0.05) -> Any:
    """Run the loop on one case as the CLI would (block split, adapter, run_diagnose)."""
    if sensor == "lidar":
        from sensor_envs.diagnose.lidar import LidarAdapter, lidar_blocks

        blocks = lidar_blocks(case.log.n_poses, 5)
        adapter: Any = LidarAdapter(case.log, block_split(blocks), blocks, params=LIDAR_FIT, max_readings=150)
    else:
        from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks

        adapter = RadarAdapter(case.log, block_split(radar_blocks(case.log)))
    return run_diagnose(adapter, base_state=case.base_state, n_permutations=permutations, alpha=alpha, seed=seed)


def score_case(case: Case, res: Any) -> dict[str, Any]:
    """The case's outcome: top-ranked effect, added, errors, and whether the loop closed (or stayed quiet)."""
    top = res.effects[0]["name"] if res.effects else None
    sig = [e["name"] for e in res.effects if e["significant"]]
    out: dict[str, Any] = {
        "kind": case.kind,
        "cause": case.cause,
        "proxy": case.proxy,
        "top": top,
        "top3": [(e["name"], round(e["score"], 5), e["p_value"]) for e in res.effects[:3]],
        "significant": sig,
        "added": list(res.added),
        "error_before": res.error_before,
        "error_after": res.error_after,
        "info": case.info,
    }
    if case.kind == "null":
        out["false_positive"] = bool(sig)
        out["false_addition"] = bool(res.added)
    else:
        out["recall"] = bool(top == case.cause and case.cause in res.added and res.error_after < res.error_before)
        out["proxy_added"] = bool(case.proxy is not None and case.proxy in res.added)
    return out


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per sensor and kind: cases, recall (or false-positive rates), proxy additions."""
    out: dict[str, Any] = {}
    for sensor in sorted({r["sensor"] for r in rows}):
        for kind in dict.fromkeys(r["kind"] for r in rows if r["sensor"] == sensor):
            sel = [r for r in rows if r["sensor"] == sensor and r["kind"] == kind]
            d: dict[str, Any] = {"cases": len(sel)}
            if kind == "null":
                d["false_positive_rate"] = float(np.mean([r["false_positive"] for r in sel]))
                d["false_addition_rate"] = float(np.mean([r["false_addition"] for r in sel]))
            else:
                d["recall"] = float(np.mean([r["recall"] for r in sel]))
                d["cause_first"] = float(np.mean([r["top"] == r["cause"] for r in sel]))
                d["proxy_added"] = float(np.mean([r["proxy_added"] for r in sel]))
                d["other_added"] = float(np.mean([any(a != r["cause"] for a in r["added"]) for r in sel]))
            out[f"{sensor}/{kind}"] = d
    return out


def markdown(summary: dict[str, Any], rows: list[dict[str, Any]], command: str) -> str:
    """The summary table and one line per case."""
    lines = ["# diagnose suite", "", f"Command: `{command}`", ""]
    lines += [
        "| sensor/kind | cases | recall | cause first | proxy added | any non-cause added | false pos. (significant) "
        "| false pos. (added) |"
    ]
    lines += ["|---|---|---|---|---|---|---|---|"]
    for k, d in summary.items():

        def f(key: str, d: dict[str, Any] = d) -> str:
            return f"{d[key]:.2f}" if key in d else ""

        lines.append(
            f"| {k} | {d['cases']} | {f('recall')} | {f('cause_first')} | {f('proxy_added')} | {f('other_added')} | "
            f"{f('false_positive_rate')} | {f('false_addition_rate')} |"
        )
    lines += ["", "## Cases", ""]
    for r in rows:
        lines.append(
            f"- {r['sensor']} {r['kind']} seed {r['seed']}: cause {r['cause']}, top {r['top3']}, added {r['added']}, "
            f"NLL {r['error_before']:.4f} -> {r['error_after']:.4f}, strength {r['info'].get('strength', 0):.2f} "
            f"({r['info'].get('form')}), {r['seconds']:.0f} s"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=3, help="cases per kind and sensor (default 3)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first case (cases use seed, seed+1, ...)")
    ap.add_argument("--sensor", choices=("lidar", "radar", "both"), default="both")
    ap.add_argument("--kinds", nargs="*", default=None, help="only these kinds")
    ap.add_argument("--scans", type=int, default=500)
    ap.add_argument("--bearings", type=int, default=60)
    ap.add_argument("--sequences", type=int, default=24, help="radar sequences (30 cycles x 10 targets each)")
    ap.add_argument("--permutations", type=int, default=199)
    ap.add_argument("--alpha", type=float, default=0.05, help="family-wise level (default 0.05, as the CLI)")
    ap.add_argument("--out", type=Path, default=Path("diagnose_suite_out"))
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    sensors = ("lidar", "radar") if a.sensor == "both" else (a.sensor,)
    for sensor in sensors:
        kinds = LIDAR_KINDS if sensor == "lidar" else RADAR_KINDS
        for kind in [k for k in kinds if a.kinds is None or k in a.kinds]:
            for j in range(a.cases):
                seed = a.seed + 1000 * j + 17 * kinds.index(kind)
                t0 = time.perf_counter()
                if sensor == "lidar":
                    case = lidar_case(kind, seed, scans=a.scans, bearings=a.bearings)
                else:
                    case = radar_case(kind, seed, sequences=a.sequences)
                res = diagnose_case(case, sensor, a.permutations, seed, a.alpha)
                row = {"sensor": sensor, "seed": seed, **score_case(case, res)}
                row["seconds"] = time.perf_counter() - t0
                rows.append(row)
                ok = row.get("recall", not row.get("false_positive", False))
                print(
                    f"{sensor} {kind} seed {seed}: {'ok' if ok else 'MISS'} top {row['top3'][:2]} "
                    f"cause {case.cause} added {row['added']} ({row['seconds']:.0f} s)",
                    file=sys.stderr,
                    flush=True,
                )
    summary = summarise(rows)
    command = "python benchmarks/diagnose_suite.py " + " ".join(sys.argv[1:] if argv is None else argv)
    (a.out / "suite.json").write_text(json.dumps({"command": command, "summary": summary, "cases": rows}, indent=1))
    (a.out / "suite.md").write_text(markdown(summary, rows, command))
    for k, d in summary.items():
        print(k, json.dumps(d))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
