"""The sensor-envs command line.

Commands: demo, record, fit, validate, calibrate, tune, diagnose, evaluate, rebuild-models, card, train, robustness.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any

from sensor_envs.cli import diagnose as cli_diagnose
from sensor_envs.cli import evaluate as cli_evaluate
from sensor_envs.cli import lidar as cli_lidar
from sensor_envs.cli import radar as cli_radar
from sensor_envs.cli import rebuild as cli_rebuild
from sensor_envs.cli import training as cli_training
from sensor_envs.cli import tune as cli_tune
from sensor_envs.cli.args import OneLineParser, add_force, nonneg_int, positive_int

USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, EOFError)
"""Exceptions that mean bad input (a malformed file, an unsafe output, a missing file...): one line, exit 2.

The loaders turn their failures into these (``ModelFileError``, ``LidarLogError``, ``RadarLogError``,
``OutputError`` are ``ValueError``s); anything else is a bug and keeps its traceback.
"""


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, with the lidar and radar sub-commands registered."""
    parser = OneLineParser(prog="sensor-envs", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the main job: drive every env with every sensor, write pictures and a report")
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument("--seed", type=nonneg_int, default=0, help="seed of the first episode of every run (default: 0)")
    demo.add_argument("--episodes", type=positive_int, default=10, help="episodes per env and sensor (default: 10)")
    add_force(demo)
    demo.set_defaults(func=_run_demo)
    verbs = {}
    for verb, text in (
        ("record", "record a log from a reference rig"),
        ("fit", "fit a sensor model to a log"),
        ("validate", "compare a model with a log and its baselines"),
        ("calibrate", "fit a reference rig's parameters to real data (simulation-based)"),
        ("tune", "choose a fitted model's post-fit factors on real held-out data"),
    ):
        p = sub.add_parser(verb, help=text)
        verbs[verb] = p.add_subparsers(dest="kind", required=True)
    cli_lidar.register(verbs)
    cli_radar.register(verbs)
    cli_tune.register(verbs)
    cli_diagnose.register(sub)
    cli_evaluate.register(
        sub.add_parser("evaluate", help="does the simulator predict an algorithm's performance on the real sensor?")
    )
    cli_rebuild.register(sub)
    card = sub.add_parser(
        "card",
        help="write the one-page model card of a model file (from its header and a measured-metrics JSON)",
        description="Write the one-page Markdown card of a model file, generated from the file's own header and "
        "a measured-metrics JSON (schema: sensor_envs/cards.py).",
    )
    card.add_argument("model", help="model file (.npz)")
    card.add_argument("--metrics", default=None, help="measured-metrics JSON (default: none; the card says so)")
    card.add_argument("--out", required=True, help="output card (.md)")
    add_force(card)
    card.set_defaults(func=_run_card)
    cli_training.register(sub)
    return parser


def _run_card(args: argparse.Namespace) -> int:
    from sensor_envs.cards import write_card

    path = write_card(args.model, args.out, metrics=args.metrics, force=args.force)
    print(f"wrote {path}")
    return 0


def _run_demo(args: argparse.Namespace) -> int:
    from sensor_envs.cli.demo import run_demo

    run_demo(args.out, seed=args.seed, episodes=args.episodes, force=args.force)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``sensor-envs``; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command line, for reports that quote it
    previous = _terminate_cleanly()
    try:
        return int(args.func(args) or 0)
    except USER_ERRORS as exc:
        print(f"sensor-envs {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _terminate_cleanly() -> Any:
    """Turn SIGTERM into ``SystemExit(143)`` so that pending outputs are rolled back; returns the old handler."""

    def handler(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, handler)


def one_line(exc: BaseException) -> str:
    """The exception's message on one line (``EOFError`` etc. get their type name when the text is bare)."""
    text = " ".join(str(exc).split())
    return text if text and not isinstance(exc, EOFError) else f"{type(exc).__name__}: {text or 'no detail'}"


if __name__ == "__main__":
    raise SystemExit(main())
