"""``sensor-envs diagnose lidar`` on the real scan logs: what effect the learned lidar lacks, before/after.

For ``carmen/intel-corrected`` and the three Neato ROS bags (``neato_ros1_bags/*.bag`` with
``mymap.yaml`` and ``--align``), runs the CLI with default diagnosis settings and prints, per log: the
top candidates (name, cross-fitted R^2, max-T adjusted p), the effects added, and the held-out mean
NLL per reading before and after. Reports go to ``OUT/<log>/`` (report.json, report.md, figures).
CARMEN logs have no map: :func:`sensor_envs.lidar.mapping.prepare_log` builds one from its training
blocks (its own split, not the diagnosis split: part of the held-out scans helped build the map).

Usage: ``PYTHONPATH=. python benchmarks/real_lidar_diagnose.py --data ../shared/data/real --out DIR [--only NAME]``
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from sensor_envs.cli.main import main

DATASETS = {  # name: (relative path, extra CLI options)
    "left_side": ("neato_ros1_bags/left_side.bag", ["--map", "neato_ros1_bags/mymap.yaml", "--align"]),
    "middle": ("neato_ros1_bags/middle.bag", ["--map", "neato_ros1_bags/mymap.yaml", "--align"]),
    "right_side": ("neato_ros1_bags/right_side.bag", ["--map", "neato_ros1_bags/mymap.yaml", "--align"]),
    "intel-corrected": (
        "carmen/intel-corrected.log.gz",
        ["--max-range", "30", "--spur-above", "31", "--table-range-step", "0.25"],
    ),
}


def run(data: Path, out: Path, only: list[str]) -> None:
    """Diagnose each log and print its summary."""
    for name, (rel, opts) in DATASETS.items():
        if only and name not in only:
            continue
        opts = [str(data / o) if o.endswith((".yaml",)) else o for o in opts]
        dest = out / name
        t0 = time.perf_counter()
        code = main(["diagnose", "lidar", str(data / rel), "--out", str(dest), "--force", "--quiet", *opts])
        wall = time.perf_counter() - t0
        if code != 0:
            print(f"{name}: exit code {code}")
            continue
        rep = json.loads((dest / "report.json").read_text())
        top = [(e["name"], round(e["score"], 4), round(e["p_value"], 4)) for e in rep["effects"][:5]]
        misfit = [(e["name"], round(e["score"], 4)) for e in rep["details"]["state_misfit"][:3]]
        print(f"== {name} ({wall:.0f} s, {rep['details']['readings_held_out']} held-out readings)")
        print(f"   top candidates (name, R^2, p): {top}")
        print(f"   state misfit (name, R^2): {misfit}")
        before, after = rep["error_before"], rep["error_after"]
        print(f"   added: {rep['added']}; held-out NLL per reading {before:.4f} -> {after:.4f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="the real-data folder (../shared/data/real)")
    ap.add_argument("--out", type=Path, required=True, help="reports go to OUT/<log>/")
    ap.add_argument("--only", action="append", default=[], help="only this log (repeatable)")
    a = ap.parse_args()
    run(a.data, a.out, a.only)
