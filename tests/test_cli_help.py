"""The command line's help: every option of every command documented, no reST markup."""

import argparse
import re

from sensor_envs.cli.main import build_parser


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def test_every_option_of_every_command_has_help():
    missing = [
        (" ".join(path), action.option_strings or action.dest)
        for path, parser in _parsers(build_parser())
        for action in parser._actions
        if not action.help and not isinstance(action, (argparse._HelpAction, argparse._SubParsersAction))
    ]
    assert missing == []


def test_help_text_has_no_rest_markup():
    found = [
        (" ".join(path), m.group(0))
        for path, parser in _parsers(build_parser())
        for m in re.finditer(r"``|:(func|class|data|meth|mod):", parser.format_help())
    ]
    assert found == []
