"""The sensor-envs command line.

Commands: demo, record, fit, validate, calibrate, tune, diagnose, evaluate, rebuild-models, card,
upgrade-model, train, robustness.
"""

from __future__ import annotations

import argparse
import os
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
from sensor_envs.cli import upgrade as cli_upgrade
from sensor_envs.cli.args import PATH_OPTIONS, OneLineParser, add_force, bounded_int, declare_ranges, nonneg_int
from sensor_envs.inputs import InputError

USER_ERRORS: tuple[type[BaseException], ...] = (InputError, OSError)
"""Exceptions that mean bad input: one line naming the file and the field, exit status 2.

:class:`~sensor_envs.inputs.InputError` (``ModelFileError``, ``LidarLogError``, ``RadarLogError``,
``OutputError`` are subclasses) and an ``OSError`` from opening a user's path (shown with its file name);
anything else, a plain ``ValueError`` from numpy or scipy included, is a bug and keeps its traceback.
"""


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, with the lidar and radar sub-commands registered."""
    parser = OneLineParser(prog="sensor-envs", description=" ".join((__doc__ or "").split()))
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the main job: drive every env with every sensor, write pictures and a report")
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument("--seed", type=nonneg_int, default=0, help="seed of the first episode of every run (default: 0)")
    demo.add_argument(
        "--episodes", type=bounded_int(1, 10_000), default=10, help="episodes per env and sensor (default: 10)"
    )
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
    cli_upgrade.register(sub)
    cli_training.register(sub)
    declare_ranges(parser)  # every numeric option its declared range, every path option non-empty
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
    previous = _terminate_cleanly()  # first: a SIGTERM during parsing or the commands' imports rolls back too
    quiet_bars = _bars_only_on_a_terminal()
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)  # the command line, for reports that quote it
        try:
            return int(args.func(args) or 0)
        except USER_ERRORS as exc:
            _close_bars()
            line = name_option(one_line(exc, getattr(args, "out", None)), args, parser)
            print(f"sensor-envs {args.command}: error: {line}", file=sys.stderr)
            return 2
    finally:
        _close_bars()
        from sensor_envs.outputs import release_claims

        release_claims()
        quiet_bars()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous[0])
            sys.unraisablehook = previous[1]


def _terminate_cleanly() -> tuple[Any, Any] | None:
    """Turn SIGTERM into ``SystemExit(143)`` so that pending outputs are rolled back.

    Returns the old handler and ``sys.unraisablehook``. Python ignores an exception raised where it
    cannot propagate (a weak-reference callback of the import machinery, a ``__del__``): the hook
    installed here sees that ``SystemExit`` and sends the signal again, so that it lands where it can.
    """
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    old_hook = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, SystemExit) and unraisable.exc_value.code == 128 + signal.SIGTERM:
            os.kill(os.getpid(), signal.SIGTERM)  # delivered again at the next bytecode boundary
            return
        old_hook(unraisable)

    sys.unraisablehook = hook
    return signal.signal(signal.SIGTERM, handler), old_hook


def _bars_only_on_a_terminal() -> Any:
    """Disable every tqdm bar when stderr is not a terminal (a log file, a pipe); returns the undo function.

    ``TQDM_DISABLE`` covers bars created without ``disable=``; bars created with ``disable=False`` (a
    library's ``progress=True`` default) are disabled by wrapping ``tqdm``'s constructor for this command.
    """
    if sys.stderr.isatty():
        return lambda: None
    import tqdm.std

    old_env, old_init = os.environ.get("TQDM_DISABLE"), tqdm.std.tqdm.__init__
    os.environ["TQDM_DISABLE"] = "1"

    def quiet_init(self: Any, *args: Any, **kwargs: Any) -> None:
        kwargs["disable"] = True
        old_init(self, *args, **kwargs)

    tqdm.std.tqdm.__init__ = quiet_init

    def undo() -> None:
        tqdm.std.tqdm.__init__ = old_init
        if old_env is None:
            os.environ.pop("TQDM_DISABLE", None)
        else:
            os.environ["TQDM_DISABLE"] = old_env

    return undo


def _close_bars() -> None:
    """Clear every open tqdm bar from the terminal (so that an error line is not drawn over)."""
    tqdm_mod = sys.modules.get("tqdm")
    if tqdm_mod is None:
        return
    for bar in list(getattr(tqdm_mod.tqdm, "_instances", ())):
        bar.leave = False
        bar.close()


def _command_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The (sub-)sub-command parser that parsed ``args`` (``record lidar``'s for ``record lidar ...``)."""
    current = parser
    for dest in ("command", "kind"):
        sub = next((a for a in current._actions if isinstance(a, argparse._SubParsersAction)), None)
        if sub is None or getattr(args, dest, None) not in sub.choices:
            break
        current = sub.choices[getattr(args, dest)]
    return current


def name_option(line: str, args: argparse.Namespace, parser: argparse.ArgumentParser) -> str:
    """``line`` with the option whose value it is about put first, when it names none of the command's options.

    A reader's error names the file or the value (``nan: input not found``, ``map: 'x' is neither a built-in
    map ...``), not the option it came from: the option whose value is the line's subject (the line starts
    with ``value:`` or quotes ``'value'``) is named in front (``--map nan: input not found``). Positional
    arguments have no option to name: their file is named.
    """
    command = _command_parser(parser, args)
    options = [a for a in command._actions if a.option_strings and a.nargs != 0 and a.dest != "help"]
    if any(f"{o}" in line for a in options for o in a.option_strings if o.startswith("--")):
        return line
    options.sort(key=lambda a: a.dest not in PATH_OPTIONS)  # a file's name first: the lines name files
    for action in options:
        values = getattr(args, action.dest, None)
        for value in values if isinstance(values, list) else [values]:
            text = str(value) if isinstance(value, (str, os.PathLike)) else None
            if text and text.strip() and line.startswith((f"{text}:", f"{text} (-> ")):
                return f"{action.option_strings[-1]} {line}"
            if text and text.strip() and f"'{text}'" in line:
                return f"{action.option_strings[-1]} {text}: {line}"
    return line


def one_line(exc: BaseException, out: object = None) -> str:
    """The exception's message on one line; an ``OSError`` names its file (or ``out``, e.g. a full disk)."""
    text = " ".join(str(exc).split())
    if isinstance(exc, OSError) and exc.strerror:
        name = exc.filename if exc.filename is not None else out
        where = f"{name}: " if name is not None else ""
        return f"{where}{exc.strerror}"
    return text or f"{type(exc).__name__}: no detail"


if __name__ == "__main__":
    raise SystemExit(main())
