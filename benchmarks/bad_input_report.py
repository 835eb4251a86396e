"""How every malformed input of the bad-input suite ends, counted per class of input.

    PYTHONPATH=. python benchmarks/bad_input_report.py

Runs each case of ``sensor_envs/testing/bad_options.py`` (every CLI verb and the loaders behind it) in-process
in a fresh temporary folder and classifies the outcome: a traceback (uncaught exception), an exit
status other than 2, several lines on stderr, a one-line message that misses the file or the field,
or the contract (exit 2, one line naming file and field); ", files created/changed" is appended when
the folder differs afterwards. Run it with another checkout first on ``PYTHONPATH`` to compare.
"""

from __future__ import annotations

import collections
import contextlib
import io
import tempfile
import warnings
from pathlib import Path

from sensor_envs.cli.main import main
from sensor_envs.testing import bad_options, bad_pieces


def outcome(case: bad_pieces.Case) -> str:
    """How ``case`` ends (see the module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        argv, names = case.make(d)
        before = bad_pieces.snapshot(d)
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                try:
                    code = main(argv)
                except SystemExit as exc:  # argparse
                    code = exc.code
        except Exception as exc:  # a traceback for the user
            return f"traceback ({type(exc).__name__})"
        lines = err.getvalue().strip().splitlines()
        if code != 2:
            kind = f"exit {code}"
        elif len(lines) != 1:
            kind = "exit 2, several lines"
        elif names not in lines[0] or case.field not in lines[0]:
            kind = "exit 2, message misses file or field"
        else:
            kind = "exit 2, one line naming file and field"
        return kind + (", files created/changed" if bad_pieces.snapshot(d) != before else "")


def main_report() -> None:
    """Print the table."""
    warnings.simplefilter("ignore")
    table: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for case in bad_options.CASES:
        table[case.cls][outcome(case)] += 1
    print("| class of bad input | cases | outcome |\n|---|---:|---|")
    for cls, counts in table.items():
        text = "; ".join(f"{n} {k}" for k, n in counts.most_common())
        print(f"| {cls} | {sum(counts.values())} | {text} |")
    print(f"| all | {len(bad_options.CASES)} | |")


if __name__ == "__main__":
    main_report()
