"""Generated bad command lines, second round (issue 42): every option of every sub-command, and unsafe outputs.

* ``every option``: the parser itself is walked (so a new option is fuzzed without a change here); one
  option of one sub-command gets a value no option of its kind may take: numbers spelled as ``nan``,
  ``1_0``, ``0x10``, ``1e``, ``+-1``, Arabic-Indic or full-width digits, ``1e309``, a subnormal, a
  number that rounds to zero, 30 digits; paths and free text that are blank, hold a NUL, a newline, a
  tab or an escape sequence; choices outside the list; 65 values, or one value twice, for a list option. The
  value must be refused when the command line is parsed (exit 2, one line naming the option): a case
  whose value the parser takes is accepted nonsense without running the command.
* ``output target``: ``--out`` naming an input, a symbolic link to an input, a folder, a FIFO, an
  existing file (no ``--force``), a dangling link, ``/dev/null``, a name ending in ``/``; two outputs of
  one command naming one file. Nothing may be written over an input, and an input's bytes must not change.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
from pathlib import Path
from typing import Any

from sensor_envs.inputs import InputError
from sensor_envs.testing.fuzz_pieces import SHIPPED, Case, Chooser, write_radar_csv

NUMBER_VALUES = ["nan", "-nan", "inf", "1e", "0x10", "1_0", "+-1", "١", "１", "1e309", "9" * 30, "4.9e-324", "1e-400"]
"""Values no numeric option may take (every declared range lies within +-1e6 and above 1e-300 in size)."""
TEXT_VALUES = ["", " ", "\t", "\x00", "a\x00b", "x\ny", "\x1b[2J", "\x7f", " \u00a0"]
"""Values no path or free-text option may take: blank, or holding a control character."""
CHOICE_VALUES = ["", "x", "nan", "PAPER", " paper"]


def _kind(action: argparse.Action) -> str:
    if action.choices is not None:
        return "choice"
    name = getattr(action.type, "__qualname__", "") or ""
    if name.startswith(("path_", "text_arg")):
        return "text"
    return "number"


def option_actions() -> list[tuple[list[str], list[str], argparse.Action]]:
    """``(sub-command words, required arguments, action)`` of every option that takes a value."""
    from sensor_envs.cli.main import build_parser

    out: list[tuple[list[str], list[str], argparse.Action]] = []

    def walk(parser: argparse.ArgumentParser, words: list[str]) -> None:
        required: list[str] = []
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    walk(sub, [*words, name])
                return
            if a.option_strings and a.required:
                required += [a.option_strings[0], f"{{d}}/{a.dest}.x"]
            elif not a.option_strings and a.dest != "help":
                required.append(f"{{d}}/{a.dest}.x")
        out.extend((words, required, a) for a in parser._actions if a.nargs != 0 and a.dest != "help")

    walk(build_parser(), [])
    return out


def _parse_only(argv: list[str]) -> Any:
    """Parse ``argv`` as the command line does; a usage error becomes an :class:`InputError` (nothing runs)."""
    from sensor_envs.cli.main import build_parser

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            return build_parser().parse_args(argv)
    except SystemExit:
        raise InputError(err.getvalue().strip() or "usage error") from None


def _every_option(c: Chooser, d: Path) -> Case:
    words, required, action = c.choice(option_actions())
    kind = _kind(action)
    value = c.choice({"number": NUMBER_VALUES, "text": TEXT_VALUES, "choice": CHOICE_VALUES}[kind])
    args = [a.replace("{d}", str(d)) for a in required]
    inputs = [Path(a) for a in args if not a.startswith("--")]
    many = action.option_strings and (action.nargs in ("+", "*") or isinstance(action, argparse._AppendAction))
    if many and c.integers(0, 2) == 0:  # a list is a count too (at most 64 values), and names each value once
        n = c.choice([65, 2])
        value = f"{n} equal values"
        one = {"number": "1", "text": "a=1", "choice": str(next(iter(action.choices or ["a"])))}[kind]
        opt = action.option_strings[0]
        args = [a for i, a in enumerate(args) if a != opt and (i == 0 or args[i - 1] != opt)]
        args += [opt, *[one] * n] if action.nargs in ("+", "*") else [f"{opt}={one}"] * n
    elif action.option_strings:
        opt = action.option_strings[0]
        args = [a for i, a in enumerate(args) if a != opt and (i == 0 or args[i - 1] != opt)]
        args += [f"{opt}={value}"]
    else:  # a positional argument: its dest names it in argparse's message
        args[args.index(str(d / f"{action.dest}.x"))] = value
        inputs += [Path(action.dest), Path(str(action.metavar or action.dest))]
    argv = [*words, *args]
    what = f"{' '.join(words)} {action.option_strings[0] if action.option_strings else action.dest}={value!r}"

    def load() -> Any:
        return _parse_only(argv)

    return Case("every option", what, argv, load, True, inputs, command_when_loaded=False)


# ------------------------------------------------------------------------------------------- outputs
def _model_copy(d: Path) -> Path:
    p = d / "m.npz"
    shutil.copy(SHIPPED / "radar_gaussian.npz", p)
    return p


def _output_target(c: Chooser, d: Path) -> Case:
    """A command whose ``--out`` is unsafe; ``upgrade-model`` (fast) or ``fit radar`` (two outputs)."""
    model = _model_copy(d)
    kind = c.choice(["input", "link", "folder", "fifo", "exists", "dangling", "devnull", "slash", "twice", "inside"])
    force = c.integers(0, 1) == 1 and kind in ("input", "link", "twice")
    out: Path | str = d / "out.npz"
    argv: list[str] | None = None
    if kind == "input":
        out = model
    elif kind == "link":
        out = d / "link.npz"
        os.symlink(model, out)
    elif kind == "folder":
        out = d / "dir.npz"
        out.mkdir()
        (out / "keep.txt").write_text("mine")
    elif kind == "fifo":
        out = d / "pipe.npz"
        os.mkfifo(out)
    elif kind == "exists":
        out = d / "old.npz"
        out.write_bytes(b"precious")
    elif kind == "dangling":
        out = d / "dangling.npz"
        os.symlink(d / "nowhere.npz", out)
    elif kind == "devnull":
        out = "/dev/null"
    elif kind == "slash":
        out = f"{d / 'out.npz'}/"
    elif kind == "inside":
        out = model / "x.npz"  # below a file: no folder can be made there
    else:
        log = write_radar_csv(d)
        argv = ["fit", "radar", str(log), "--out", str(d / "k.npz"), "--baseline-out", str(d / "k.npz")]
    if argv is None:
        argv = ["upgrade-model", str(model), "--out", str(out)]
    argv += ["--force"] if force else []
    what = f"--out {kind}{' --force' if force else ''}"
    inputs = [model, d] if kind != "devnull" else [model, Path("/dev/null")]
    return Case("output target", what, argv, None, True, inputs)


CONFIG_KEYS = ["n_timesteps", "n_envs", "eval_freq", "eval_episodes", "device", "policy", "algo", "vec_env"]
CONFIG_KEYS += ["hyperparams.learning_rate", "hyperparams.gamma", "hyperparams.nosuch", "env_kwargs.lidar"]
CONFIG_KEYS += ["env_kwargs.nosuch"]
CONFIG_VALUES = ["0", "-1", "1.5", "2", "0.5", "1e9", "10000000000", ".nan", ".inf", "true", "''", "x", "[1]"]
CONFIG_VALUES += ["{a: 1}", "~", "cuda:7", "auto", "cpu", "MlpPolicy", "ppo", "dqn", "vector", "learned", "1_000"]


def _config_must(key: str, v: Any) -> bool:
    """Whether the value ``v`` of config ``key`` is certainly invalid (Neato-v0's block, this CPU machine)."""
    from sensor_envs.training.train import COUNT_LIMITS

    number = isinstance(v, (int, float)) and not isinstance(v, bool)
    if key in COUNT_LIMITS:
        return not (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= COUNT_LIMITS[key])
    if key.startswith("hyperparams.") or key.endswith("nosuch"):
        return key.endswith("nosuch") or not (number and 0 < v <= 1)
    allowed = {"device": ("auto", "cpu"), "policy": ("MlpPolicy",), "algo": ("ppo",), "vec_env": ("dummy", "vector")}
    allowed["env_kwargs.lidar"] = ("ideal", "gaussian", "learned")
    return v not in allowed[key]


def _training_config(c: Chooser, d: Path) -> Case:
    """A ``train --set`` override of one config key (or one entry of ``hyperparams``/``env_kwargs``)."""
    from sensor_envs.inputs import parse_yaml
    from sensor_envs.training.train import DEFAULT_CONFIG, load_config

    key, value = c.choice(CONFIG_KEYS), c.choice(CONFIG_VALUES)
    top, _, sub = key.partition(".")
    base = {"hyperparams": "n_steps: 512, batch_size: 256, ", "env_kwargs": "map: seed_room, "}.get(top, "")
    item = f"{top}={{{base}{sub}: {value}}}" if sub else f"{key}={value}"
    must = _config_must(key, parse_yaml(value, "value"))
    env = "sensor_envs/Neato-v0"
    argv = ["train", "--env", env, "--out", str(d / "run"), "--set", item]
    load = lambda: load_config(DEFAULT_CONFIG, env, [item])  # noqa: E731
    return Case("training config", f"--set {item}", argv, load, must, [], command_when_loaded=False)


# ------------------------------------------------------------------------------------------- option values
def _base_argv(words: tuple[str, ...], d: Path) -> list[str] | None:
    """A valid, cheap command line of the sub-command ``words`` (inputs written into ``d``); ``None``: none."""
    from sensor_envs.testing.fuzz_pieces import lidar_arrays, write_npz

    def shipped(name: str) -> str:
        p = d / name
        if not p.exists():
            shutil.copy(SHIPPED / name, p)
        return str(p)

    def csv() -> str:
        return str(write_radar_csv(d))

    def npz() -> str:
        return str(d / "log.npz") if (d / "log.npz").exists() else str(write_npz(d / "log.npz", lidar_arrays()))

    table: dict[tuple[str, ...], Any] = {
        ("record", "lidar"): lambda: ["--out", str(d / "r.npz"), "--poses", "2", "--repeats", "2"],
        ("record", "radar"): lambda: ["--out", str(d / "r.csv"), "--sequences", "1", "--cycles", "2"],
        ("fit", "lidar"): lambda: [npz(), "--out", str(d / "m.npz"), "--folds", "2", "--variant", "seed"],
        ("fit", "radar"): lambda: [csv(), "--out", str(d / "k.npz"), "--relevance", "paper"],
        ("validate", "lidar"): lambda: [shipped("neato_lidar.npz"), npz(), "--out", str(d / "v")],
        ("validate", "radar"): lambda: [
            shipped("radar_kde.npz"),
            csv(),
            "--out",
            str(d / "v"),
            "--baseline",
            shipped("radar_gaussian.npz"),
        ],  # fmt: skip
        ("calibrate", "lidar"): lambda: [npz(), "--out", str(d / "c.json"), "--max-evals", "1"],
        ("calibrate", "radar"): lambda: [csv(), "--out", str(d / "c.json"), "--max-evals", "1"],
        ("tune", "radar"): lambda: [shipped("radar_kde.npz"), csv(), "--out", str(d / "t.npz")],
        ("diagnose", "radar"): lambda: [csv(), "--out", str(d / "d")],
        ("diagnose", "lidar"): lambda: [npz(), "--out", str(d / "d")],
        ("evaluate", "detection"): lambda: ["--real", npz(), "--out", str(d / "e")],
        ("evaluate", "boxworld"): lambda: ["--out", str(d / "e"), "--configs", "1", "--poses", "1", "--repeats", "1"],
        ("evaluate", "radar-detection"): lambda: ["--real", csv(), "--out", str(d / "e"), "--draws", "1"],
        ("evaluate", "registration"): lambda: ["--out", str(d / "e"), "--poses", "2"],
        ("rebuild-models",): lambda: ["--out", str(d / "b")],
        ("card",): lambda: [shipped("radar_kde.npz"), "--out", str(d / "card.md")],
        ("upgrade-model",): lambda: [shipped("radar_kde.npz"), "--out", str(d / "u.npz")],
        ("train",): lambda: ["--env", "sensor_envs/Neato-v0", "--out", str(d / "run"), "--set", "n_timesteps=1"],
        ("robustness",): lambda: ["--out", str(d / "rob"), "--seeds", "1"],
    }
    return [*words, *table[words]()] if words in table else None


NOT_AN_INPUT = frozenset({"out", "baseline_out", "json", "note"})
"""Text and path options any value of which is valid (outputs, a free note): no bad value to give them."""
INPUT_VALUES = ["nan", "{d}/missing{s}", "{d}/empty_folder", "/dev/null", "{d}/empty{s}", "{d}/nul{s}"]
INPUT_VALUES += ["{d}/fifo{s}", "{d}/loop{s}", "{d}/zero_link{s}"]
"""Values no input file or folder option may take here: no such file, an empty folder, a device, an empty file,
4 KiB of NUL bytes, a FIFO, a symbolic-link loop, a link to ``/dev/zero`` (``{s}``: the suffix of the input the
value stands for)."""


def _bad_inputs(d: Path, suffix: str) -> None:
    """The files :data:`INPUT_VALUES` names, made in ``d``."""
    (d / "empty_folder").mkdir(exist_ok=True)
    (d / f"empty{suffix}").write_bytes(b"")
    (d / f"nul{suffix}").write_bytes(bytes(4096))
    if not (d / f"fifo{suffix}").exists():
        os.mkfifo(d / f"fifo{suffix}")
    for name, target in ((f"loop{suffix}", d / f"loop{suffix}"), (f"zero_link{suffix}", Path("/dev/zero"))):
        if not (d / name).is_symlink():
            os.symlink(target, d / name)


WORD_VALUES = ["nan", "x", "nan=1"]
"""Values no option naming a thing (an env id, a sensor, a device, a column, a recipe, a key) may take."""


def value_options() -> list[tuple[tuple[str, ...], argparse.Action, int]]:
    """``(sub-command words, action, position)`` of every input path and word option of :data:`BASE_COMMANDS`.

    ``position`` is a positional argument's index among the command's positionals (-1 for an option).
    """
    from sensor_envs.cli.main import build_parser

    out = []
    for words, _, action in option_actions():
        if tuple(words) not in BASE_COMMANDS or _kind(action) != "text" or action.dest in NOT_AN_INPUT:
            continue
        position = -1
        if not action.option_strings:
            sub = build_parser()
            for w in words:
                sub = next(a for a in sub._actions if isinstance(a, argparse._SubParsersAction)).choices[w]
            positionals = [a.dest for a in sub._actions if not a.option_strings]
            position = positionals.index(action.dest)
        out.append((tuple(words), action, position))
    return out


BASE_COMMANDS = frozenset(
    {
        ("record", "lidar"), ("record", "radar"), ("fit", "lidar"), ("fit", "radar"), ("validate", "lidar"),
        ("validate", "radar"), ("calibrate", "lidar"), ("calibrate", "radar"), ("tune", "radar"),
        ("diagnose", "radar"), ("diagnose", "lidar"), ("evaluate", "detection"), ("evaluate", "boxworld"),
        ("evaluate", "radar-detection"), ("evaluate", "registration"), ("rebuild-models",), ("card",),
        ("upgrade-model",), ("train",), ("robustness",),
    }
)  # fmt: skip
"""The sub-commands :func:`_base_argv` has a valid command line for."""


def _option_value(c: Chooser, d: Path) -> Case:
    """A valid command line with one input or word option given a printable value that names nothing valid.

    The value passes the parser (it is plain text), so the command itself must refuse it, before any
    work and any output, with one line that names the option (``--map nan: input not found``), not only
    the file or the value. A positional input's line names its value.
    """
    from sensor_envs.cli.args import PATH_OPTIONS

    words, action, position = c.choice(value_options())
    is_path = action.dest in PATH_OPTIONS or position >= 0
    argv = _base_argv(words, d)
    assert argv is not None
    suffix = Path(argv[len(words) + position]).suffix if position >= 0 else ""
    value = c.choice(INPUT_VALUES if is_path else WORD_VALUES).replace("{d}", str(d)).replace("{s}", suffix)
    _bad_inputs(d, suffix)
    if action.option_strings:
        opt = action.option_strings[-1]
        argv = [a for i, a in enumerate(argv) if a != opt and (i == 0 or argv[i - 1] != opt)]
        argv += [opt, value]
        names = tuple(o for o in action.option_strings if o.startswith("--"))
    else:  # the base command lines give their positionals first, in order
        argv[len(words) + position] = value
        names = (value,)
    what = f"{' '.join(words)} {action.option_strings[-1] if action.option_strings else action.dest}={value!r}"
    inputs = [p for p in d.iterdir()]
    return Case("option value", what, argv, None, True, inputs, must_name=names)


OPTION_FAMILIES = {
    "every option": _every_option,
    "output target": _output_target,
    "training config": _training_config,
    "option value": _option_value,
}
"""The second-round command-line families (:data:`sensor_envs.testing.fuzz_cases.FAMILIES` includes them)."""
