"""Collision anatomy of a highway robustness run: what the observation showed in the last second before each crash.

    python benchmarks/highway_collision_report.py --run runs/hw_surround \
        --md docs/results/highway_collisions.md --json docs/results/highway_collisions.json \
        --png docs/results/highway_collisions.png [--columns ideal kde_tracks] [--episodes 30] \
        [--seeds 0 1 2] [--workers 2] --force

Replays every trained policy of the run (``runs/<row>/seed<s>/<policy>_model.zip``) on each column's radar
with the matrix's evaluation seeds and deterministic actions, and records, for every collision, the last
action (a lane change under way? braking?), whether the car hit was in the last observation (which row), in
the column radar's view and in the front radar's 100° view, and its bearing from the ego. The figures and
their definitions: :mod:`sensor_envs.training.collisions`; the page: :mod:`sensor_envs.training.collision_report`
(the text above its marker line of an existing ``--md`` is kept). Existing outputs are refused unless
``--force``. Each job folder caches its replays (``collision_replay.json``), so a rerun after more seeds
finished replays only the new policies.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from sensor_envs.training.collision_report import write_report


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="the --out folder of a finished highway matrix run")
    parser.add_argument("--md", type=Path, required=True, help="the page (text above the marker line is kept)")
    parser.add_argument("--json", type=Path, default=None, help="summary and every crash record")
    parser.add_argument("--png", type=Path, default=None, help="the plot")
    parser.add_argument("--columns", nargs="+", default=None, help="columns to replay (default: the run's)")
    parser.add_argument("--episodes", type=int, default=None, help="episodes per seed and column (default: the run's)")
    parser.add_argument("--seeds", nargs="+", type=int, default=None, help="training seeds (default: the run's)")
    parser.add_argument("--workers", type=int, default=1, help="policies replayed in parallel (spawned processes)")
    parser.add_argument("--force", action="store_true", help="replace existing outputs")
    args = parser.parse_args(argv)
    if not (args.run / "settings.json").is_file():
        print(f"highway_collision_report: error: {args.run / 'settings.json'}: not found", file=sys.stderr)
        raise SystemExit(2)
    for out in (args.md, args.json, args.png):
        if out is not None and out.exists() and not args.force:
            print(f"highway_collision_report: error: {out} exists (use --force)", file=sys.stderr)
            raise SystemExit(2)
    command = shlex.join(["python", "benchmarks/highway_collision_report.py", *argv])
    result = write_report(
        args.run, args.md, args.json, args.png, command, args.columns, args.episodes, args.workers, args.seeds
    )
    for key, cell in result["summary"]["cells"].items():
        c = cell["collision"]
        shares = ", ".join(f"{k} {v['k']}/{v['n']}" for k, v in cell["shares"].items())
        print(f"{key}: collision {c['k']}/{c['n']} = {c['rate']:.2f}; among crashes: {shares}")


if __name__ == "__main__":
    main()
