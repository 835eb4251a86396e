"""The ``sensor-envs`` command line: ``demo``, ``bench``, ``record``, ``fit``, ``validate``, ``diagnose``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from sensor_envs.cli import diagnose as cli_diagnose
from sensor_envs.cli import lidar as cli_lidar
from sensor_envs.cli import radar as cli_radar


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, with the lidar and radar sub-commands registered."""
    parser = argparse.ArgumentParser(prog="sensor-envs", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the main job: drive every env with every sensor, write pictures and a report")
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--episodes", type=int, default=10, help="episodes per env and sensor (default: 10)")
    demo.set_defaults(func=_run_demo)
    verbs = {}
    for verb, text in (
        ("record", "record a log from a reference rig"),
        ("fit", "fit a sensor model to a log"),
        ("validate", "compare a model with a log and its baselines"),
    ):
        p = sub.add_parser(verb, help=text)
        verbs[verb] = p.add_subparsers(dest="kind", required=True)
    cli_lidar.register(verbs)
    cli_radar.register(verbs)
    cli_diagnose.register(sub)
    return parser


def _run_demo(args: argparse.Namespace) -> int:
    from sensor_envs.cli.demo import run_demo  # noqa: PLC0415

    run_demo(args.out, seed=args.seed, episodes=args.episodes)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``sensor-envs``; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"sensor-envs {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
