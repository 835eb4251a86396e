"""The input layer's contract, case by case: limits of every read, the one error path, the --out claim."""

from __future__ import annotations

import dataclasses
import gzip
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

import sensor_envs.testing.fuzz_pieces as fp
from sensor_envs import inputs
from sensor_envs.cli.main import main
from sensor_envs.inputs import InputError


@pytest.fixture
def small_limits(monkeypatch):
    """Limits small enough to test with small files."""
    monkeypatch.setattr(
        inputs, "LIMITS", dataclasses.replace(inputs.LIMITS, file_bytes=4096, inflated_bytes=8192, line_bytes=512)
    )


def _one_line(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def test_fifo_and_device_are_refused_before_they_are_opened(tmp_path, capsys):
    fifo = tmp_path / "log.csv"
    os.mkfifo(fifo)
    assert main(["fit", "radar", str(fifo), "--out", str(tmp_path / "m.npz")]) == 2  # would block on open
    assert "FIFO" in _one_line(capsys)
    assert main(["fit", "lidar", "/dev/zero", "--out", str(tmp_path / "m.npz"), "--max-range", "5"]) == 2
    assert "/dev/zero" in _one_line(capsys) and "character device" in capsys.readouterr().err + "character device"


def test_size_inflated_size_and_line_length_are_bounded(tmp_path, small_limits):
    big = tmp_path / "big.csv"
    big.write_text("x" * 5000)
    with pytest.raises(InputError, match="limit of 4096"):
        inputs.read_bytes(big)
    gz = tmp_path / "log.gz"
    gz.write_bytes(gzip.compress(b"a" * 600 + b"\n"))
    with pytest.raises(InputError, match="line 1 is longer"):
        list(inputs.open_gzip_lines(gz, gzipped=True))
    gz.write_bytes(gzip.compress(b"abc\n" * 3000))
    with pytest.raises(InputError, match="inflated text exceeds"):
        list(inputs.open_gzip_lines(gz, gzipped=True))
    npz = tmp_path / "a.npz"
    np.savez_compressed(npz, a=np.zeros(2000))  # 16 kB inflated, a few hundred bytes on disk
    with pytest.raises(InputError, match="inflate to"):
        inputs.load_npz(npz)


def test_npz_bomb_is_refused_from_its_zip_directory(tmp_path):
    p = tmp_path / "log.npz"
    p.write_bytes(fp.npz_bomb())
    with pytest.raises(InputError, match="inflate to 2147483776 bytes"):
        inputs.load_npz(p)


def test_json_and_yaml_depth_aliases_and_size(tmp_path):
    with pytest.raises(InputError, match="nested deeper than 64"):
        inputs.parse_json("[" * 100_000 + "]" * 100_000, "h.json")
    with pytest.raises(InputError, match="nested deeper than 64"):
        inputs.parse_json("[" * 65 + "]" * 65, "h.json")
    assert inputs.parse_json("[" * 64 + "]" * 64, "h.json") is not None
    with pytest.raises(InputError, match="aliases"):
        inputs.parse_yaml("a: &a [1, 2]\nb: *a\n", "m.yaml")
    with pytest.raises(InputError, match="nested deeper"):
        inputs.parse_yaml("[" * 70 + "]" * 70, "m.yaml")
    assert inputs.parse_yaml("a: &anchor 1\nb: 2\n", "m.yaml") == {"a": 1, "b": 2}  # anchors alone are harmless


def test_csv_field_limit_and_unclosed_quote_name_the_line(tmp_path, capsys):
    p = fp.write_radar_csv(tmp_path)
    rows = p.read_text().splitlines()
    p.write_text("\n".join([*rows[:3], rows[3] + "," + "9" * 200_000, *rows[4:]]) + "\n")
    assert main(["fit", "radar", str(p), "--out", str(tmp_path / "m.npz")]) == 2
    line = _one_line(capsys)
    assert str(p) in line and "line 4" in line and "field larger than field limit" in line
    p.write_text("\n".join([*rows[:3], '0,"1', *rows[4:]]) + "\n")
    assert main(["fit", "radar", str(p), "--out", str(tmp_path / "m.npz")]) == 2
    assert "not valid CSV" in _one_line(capsys)


def test_only_input_errors_take_the_one_line_path(tmp_path, monkeypatch, capsys):
    from sensor_envs.radar import kde_fit as kde  # the KDE fit (radar/kde_fit.py) reads the cycle time

    def bug(*a, **k):
        raise ValueError("a bug inside numpy")

    monkeypatch.setattr(kde, "fit_cycle_time", bug)
    p = fp.write_radar_csv(tmp_path)
    with pytest.raises(ValueError, match="a bug inside numpy"):
        main(["fit", "radar", str(p), "--out", str(tmp_path / "m.npz")])
    assert not (tmp_path / "m.npz").exists()


def test_an_oserror_names_its_file(tmp_path, capsys):
    p = fp.write_radar_csv(tmp_path)
    p.chmod(0)
    if os.access(p, os.R_OK):  # root reads anything
        pytest.skip("running as root: file permissions do not apply")
    assert main(["fit", "radar", str(p), "--out", str(tmp_path / "m.npz")]) == 2
    assert str(p) in _one_line(capsys)


def test_second_run_on_a_claimed_output_is_refused_even_with_force(tmp_path, capsys):
    from sensor_envs.outputs import check_output, release_claims

    out = tmp_path / "log.csv"
    check_output(out)  # this process claims it, as a running command would
    child = (
        "import sys; from sensor_envs.cli.main import main; "
        f"sys.exit(main(['record', 'radar', '--out', {str(out)!r}, '--force', '--sequences', '1', '--cycles', '2']))"
    )
    import subprocess

    r = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=300)
    release_claims()
    assert r.returncode == 2 and "being written by another sensor-envs run" in r.stderr
    assert not any(tmp_path.iterdir())  # the claim's temporary is gone with the claim


def test_rosbag_without_rosbags_says_how_to_install(tmp_path, monkeypatch):
    from sensor_envs.lidar.log import LidarLogError, load_log

    bag = tmp_path / "x.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n")
    for name in [m for m in sys.modules if m == "rosbags" or m.startswith("rosbags.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "rosbags", None)  # an install without the ros extra
    with pytest.raises(LidarLogError, match=r"pip install rosbags"):
        load_log(bag)


def test_defaults_that_do_not_fit_the_log_are_refused(tmp_path, capsys):
    log = tmp_path / "log.log"
    log.write_text(fp.carmen_text())
    assert main(["fit", "lidar", str(log), "--out", str(tmp_path / "m.npz")]) == 2
    assert "--max-range: required" in _one_line(capsys)
    root = fp.write_astyx(tmp_path)
    assert main(["fit", "radar", str(root), "--out", str(tmp_path / "m.npz")]) == 2
    assert "record radar --astyx" in _one_line(capsys)
    for opt in ("--rig", "--out"):
        with pytest.raises(SystemExit) as e:
            main(["record", "radar", "--out", str(tmp_path / "r.csv"), opt, ""])
        assert e.value.code == 2 and "expected a file name" in _one_line(capsys)


def test_every_numeric_option_has_a_declared_range():
    import argparse

    from sensor_envs.cli.args import nonneg_int, path_arg, path_object, text_arg
    from sensor_envs.cli.main import build_parser

    def walk(p):
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub in a.choices.values():
                    yield from walk(sub)
            elif a.type is not None:
                yield a

    for action in walk(build_parser()):
        if action.type in (nonneg_int, path_arg, path_object, text_arg):
            continue
        for bad in ("nan", "inf", "1e300", "1e12", "-1", "1_0"):
            with pytest.raises(argparse.ArgumentTypeError):
                action.type(bad)


def test_model_header_true_is_not_format_version_1(tmp_path):
    from sensor_envs.modelio import ModelFileError, read_model
    from sensor_envs.radar.gaussian import GaussianRadar

    with np.load(fp.SHIPPED / "radar_gaussian.npz") as z:
        data = {k: z[k] for k in z.files}
    h = json.loads(data["__header__"].tobytes())
    h["format_version"] = True
    data["__header__"] = np.frombuffer(json.dumps(h).encode(), dtype=np.uint8)
    np.savez(tmp_path / "g.npz", **data)
    with pytest.raises(ModelFileError, match="'format_version' is True"):
        read_model(GaussianRadar, tmp_path / "g.npz")


def test_a_log_whose_name_is_not_utf8_is_fitted_and_carded(tmp_path):
    import subprocess

    name = os.fsencode(tmp_path) + b"/log\xe9.npz"
    fp.write_npz(Path(os.fsdecode(name)), fp.lidar_arrays())
    cli = [sys.executable, "-m", "sensor_envs.cli.main", "fit", "lidar"]
    out = os.fsencode(tmp_path / "m.npz")
    r = subprocess.run(
        [*cli, name, "--out", out, "--folds", "2", "--variant", "seed"], capture_output=True, timeout=600
    )
    assert r.returncode == 0, r.stderr[-400:]
    assert "log\ufffd.npz" in (tmp_path / "m.md").read_text(encoding="utf-8")


def test_new_commands_refuse_bad_inputs_before_writing(tmp_path, capsys):
    """card on an empty file, rebuild-models with no recipes, robustness with a config of no env: exit 2,
    one line naming the file or option, and no output made."""
    from sensor_envs.cli.main import main

    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    config = tmp_path / "config.yaml"
    config.write_text("x\n")
    cases = [
        (["card", str(empty), "--out", str(tmp_path / "c.md")], "empty.npz", tmp_path / "c.md"),
        (
            ["rebuild-models", "--recipes", str(tmp_path / "none"), "--out", str(tmp_path / "r")],
            "--recipes",
            tmp_path / "r",
        ),
        (
            ["robustness", "--domain", "highway", "--config", str(config), "--out", str(tmp_path / "rr")],
            "--config",
            tmp_path / "rr",
        ),
    ]
    for argv, named, out in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and named in err and "Traceback" not in err, (argv, err)
        assert not out.exists(), argv
