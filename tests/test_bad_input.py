"""Bad input, end to end: every CLI verb and every loader behind it, fed malformed files and options.

Each case builds its inputs in ``tmp_path`` from small valid pieces made here (and copies of the
shipped models), runs ``sensor-envs`` in-process and asserts: exit status 2, ONE line on stderr that
names the file (or option) and the field, no traceback, and not a single file created or changed.
"""

from pathlib import Path

import pytest

from sensor_envs.cli.main import main
from sensor_envs.testing.bad_files import ASTYX, BAG, CARMEN, GAUSS, KDE, LMODEL, LNPZ, MAP, RADAR
from sensor_envs.testing.bad_options import CASES, LRIG, OPTION, OUTPUT, RIG
from sensor_envs.testing.bad_pieces import Case, snapshot


@pytest.mark.parametrize("case", CASES, ids=[f"{c.cls.split()[0]}-{c.id}" for c in CASES])
def test_bad_input_ends_in_one_line_and_exit_2_and_touches_nothing(case: Case, tmp_path: Path, capsys) -> None:
    argv, names = case.make(tmp_path)
    before = snapshot(tmp_path)
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert names in lines[0], f"message does not name {names!r}: {lines[0]}"
    assert case.field in lines[0], f"message does not name {case.field!r}: {lines[0]}"
    assert snapshot(tmp_path) == before, "a file was created or changed"


def test_the_suite_covers_more_than_100_bad_inputs_of_every_class() -> None:
    classes = {c.cls for c in CASES}
    assert len(CASES) >= 100
    assert classes == {RADAR, KDE, GAUSS, LMODEL, LNPZ, CARMEN, BAG, MAP, ASTYX, OPTION, OUTPUT, RIG, LRIG}
