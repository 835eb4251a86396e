"""Object-level clutter per cycle on Astyx HiRes2019, and the shipped law the highway wrapper thins to.

    python benchmarks/real_astyx_object_clutter.py --data ../shared/data/real/astyx_hires2019 \
        --law models/radar_object_clutter.json --md docs/results/astyx_object_clutter.md --json /tmp/aoc.json --force

Counts per frame and range bin (see :mod:`sensor_envs.radar.object_clutter`): clusters outside the
boxes with every DBSCAN noise point its own cluster (the point-level figure the rig's clutter rate is
calibrated to) against clutter OBJECTS (clusters of >= ``min_points`` detections), for several
``min_points``; stationary vs moving by the Doppler residual after an ego-motion fit. The law file is
written for ``--law-min-points`` (default 2).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from sensor_envs.outputs import atomic_write
from sensor_envs.radar.object_clutter import measure_object_clutter, object_clutter_document


def _write(path: Path, text: str, force: bool) -> None:
    if path.exists() and not force:
        sys.exit(f"{path}: exists (use --force)")
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _markdown(runs: dict[int, dict], law_mp: int, command: str) -> str:
    r0 = runs[law_mp]
    edges = r0["law"]["range_edges"]
    bins = [f"{edges[i]:.0f}-{edges[i + 1]:.0f} m" for i in range(len(edges) - 1)]
    lines = [
        "# Astyx HiRes2019: clutter per radar cycle, point level vs object level",
        "",
        f"Generated on {time.strftime('%Y-%m-%d', time.gmtime())} (UTC) by `{command}` ({r0['frames']} frames). "
        "Code: `sensor_envs/radar/object_clutter.py`.",
        "",
        "Clutter = detections outside every annotated box (any class, box enlarged by "
        f"{r0['params']['margin']} m), clustered in the ground plane by DBSCAN (eps {r0['params']['eps']} m).",
        "*Point level* counts every cluster and every DBSCAN noise point (the rig's, and so the KDE's, "
        "clutter rate); *objects* counts clusters of at least `min_points` detections.",
        "",
        "| per cycle | " + " | ".join(bins) + " | total (mean) | total (median) |",
        "|---|" + "---|" * (len(bins) + 2),
    ]
    pl = r0["point_level"]
    tot = np.asarray(r0["per_frame"]["point_level"])
    lines.append(
        "| point level | " + " | ".join(f"{v:.1f}" for v in pl) + f" | {tot.mean():.1f} | {np.median(tot):.0f} |"
    )
    for mp, r in sorted(runs.items()):
        law = r["law"]
        t = np.asarray(law["stationary"]) + np.asarray(law["moving"])
        pf = np.asarray(r["per_frame"]["stationary"]) + np.asarray(r["per_frame"]["moving"])
        lines.append(
            f"| objects, >= {mp} detections | "
            + " | ".join(f"{v:.1f}" for v in t)
            + f" | {pf.mean():.1f} | {np.median(pf):.0f} |"
        )
    law = r0["law"]
    lines += [
        f"| of which stationary (>= {law_mp}) | " + " | ".join(f"{v:.1f}" for v in law["stationary"]) + " | | |",
        f"| of which moving (>= {law_mp}) | " + " | ".join(f"{v:.1f}" for v in law["moving"]) + " | | |",
        "",
        f"Doppler: the radial speed is quantised and wraps every {r0['doppler_period']:.2f} m/s; the ego-motion fit "
        f"(sensor velocity that most points call stationary, residual within {law['speed_tol']} m/s) calls a median "
        f"{r0['stationary_fit_share']['median']:.0%} of a frame's points stationary (quartile "
        f"{r0['stationary_fit_share']['q25']:.0%}); median fitted sensor speed "
        f"{r0['sensor_speed']['median']:.1f} m/s. **The moving/stationary split is therefore not reliable on "
        "these frames** (no ego odometry, aliased Doppler, a fit that leaves most points unexplained): it is "
        "recorded, but the highway wrapper uses only the total per range bin and treats its clutter as "
        "stationary infrastructure (see docs/howto/highway_tracks.md).",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="astyx_hires2019 folder")
    ap.add_argument("--law", type=Path, help="write the law file here (e.g. models/radar_object_clutter.json)")
    ap.add_argument("--law-min-points", type=int, default=2)
    ap.add_argument("--min-points", type=int, nargs="+", default=[2, 3, 5])
    ap.add_argument("--md", type=Path, help="markdown table output")
    ap.add_argument("--json", type=Path, help="full JSON output")
    ap.add_argument("--every", type=int, default=1, help="use every n-th frame (quick look)")
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args()
    frames = sorted(int(p.stem) for p in (Path(a.data) / "radar_6455").glob("*.txt") if p.stem.isdigit())[:: a.every]
    mps = sorted(set(a.min_points) | {a.law_min_points})
    runs = {}
    for mp in mps:
        print(f"stage: min_points={mp}", file=sys.stderr, flush=True)
        runs[mp] = measure_object_clutter(a.data, frames=frames, min_points=mp, progress=sys.stderr.isatty())
    command = "python benchmarks/real_astyx_object_clutter.py " + " ".join(sys.argv[1:])
    summary = {mp: {"law": r["law"], "point_level": r["point_level"]} for mp, r in runs.items()}
    print(json.dumps(summary, indent=1))
    if a.json:
        _write(a.json, json.dumps(runs, indent=1), a.force)
    if a.law:
        note = (
            "moving/stationary split unreliable on Astyx (aliased Doppler, no odometry); "
            "the highway wrapper uses the total per range bin"
        )
        doc = object_clutter_document(runs[a.law_min_points], "astyx_hires2019", command, note)
        _write(a.law, json.dumps(doc, indent=1) + "\n", a.force)
    if a.md:
        _write(a.md, _markdown(runs, a.law_min_points, command), a.force)


if __name__ == "__main__":
    main()
