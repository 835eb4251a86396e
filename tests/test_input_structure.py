"""Bad input, second round (issue 42): generated *structural* malformations, and the rules they found.

The generators (``sensor_envs.testing.fuzz_structure``, ``fuzz_folders``, ``fuzz_options``,
``fuzz_api_types``) run here with a small hypothesis budget; ``benchmarks/fuzz_inputs.py`` runs them by
the thousand. Below them, one plain test per rule the generators found missing, each with the input that
was accepted or crashed before.
"""

from __future__ import annotations

import json
import os
import struct
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sensor_envs.testing.fuzz_api as fa
import sensor_envs.testing.fuzz_cases as fc
import sensor_envs.testing.fuzz_pieces as fp
from sensor_envs.cli.main import main
from sensor_envs.inputs import InputError, parse_json, parse_yaml
from sensor_envs.testing.fuzz_api_types import TYPE_CLASSES
from sensor_envs.testing.fuzz_pieces import DrawnChooser

SMALL = settings(max_examples=3, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


@pytest.mark.parametrize("family", sorted(fc.SECOND_ROUND))
@SMALL
@given(data=st.data())
def test_every_structural_malformation_is_refused_cleanly_or_accepted_sanely(family, data) -> None:
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        case = fc.make_case(family, DrawnChooser(data), Path(tmp))
        outcome = fc.classify(case, Path(tmp))
    assert outcome in ("clean error", "accepted"), f"{family}: {case.mutation!r} -> {outcome}"


@pytest.mark.parametrize("cls", sorted(TYPE_CLASSES))
@SMALL
@given(data=st.data())
def test_odd_types_of_plausible_api_values_are_refused_or_give_sane_results(cls, data) -> None:
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        case = fa.make_api_case(cls, DrawnChooser(data), Path(tmp))
        outcome = fc.classify(case, Path(tmp))
    assert outcome in ("clean error", "accepted"), f"{cls}: {case.mutation!r} -> {outcome}"


# --------------------------------------------------------------------------------- the rules, one by one
@pytest.mark.parametrize(
    "text",
    ["a: 1\na: 2\n", "a: {b: 1, b: 2}\n", "~: 1\n", "on: 1\n", "1: 2\n", "<<: {a: 1}\n", "a: !!binary aGk=\n"]
    + ["a: !!set {x}\n", "a: !local 1\n", "a: !!python/name:os.system\n"],
)
def test_yaml_keys_are_distinct_text_and_tags_plain(text) -> None:
    with pytest.raises(InputError, match="^src: "):
        parse_yaml(text, "src")


def test_yaml_dates_stay_text_and_plain_tags_pass() -> None:
    assert parse_yaml("a: 2001-12-14\nb: !!float 1\nc: !!str 2\n", "src") == {"a": "2001-12-14", "b": 1.0, "c": "2"}


def test_json_objects_name_each_key_once() -> None:
    with pytest.raises(InputError, match="'a' appears twice"):
        parse_json('{"b": [{"a": 1, "a": 2}]}', "src")
    assert parse_json('[{"a": 1}, {"a": 1}]', "src") == [{"a": 1}, {"a": 1}]


def _run(argv: list[str], capsys) -> tuple[int, str]:
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err.strip()


def test_a_flaser_line_with_one_field_more_is_refused(tmp_path, capsys) -> None:
    from sensor_envs.lidar.log import LidarLogError, load_log

    lines = fp.carmen_text().splitlines()
    tok = lines[2].split(" ")
    tok.insert(12, "1.0")
    lines[2] = " ".join(tok)
    p = fp.write_text_bytes(tmp_path / "log.log", "\n".join(lines) + "\n")
    with pytest.raises(LidarLogError, match=r"log\.log:3: .*n \+ 11 fields"):
        load_log(p)


def test_a_damaged_bag_index_record_is_a_clean_error(tmp_path) -> None:
    from sensor_envs.lidar.log import LidarLogError, load_log
    from sensor_envs.testing.fuzz_structure import bag_boundaries

    p = fp.write_bag(tmp_path)
    raw = bytearray(p.read_bytes())
    cut = bag_boundaries(bytes(raw))
    hits = 0
    for at in cut:  # the record whose assert fires in rosbags is one of them
        b = bytearray(raw)
        struct.pack_into("<I", b, at, 3)
        p.write_bytes(bytes(b))
        try:
            load_log(p)
        except LidarLogError:
            hits += 1
    assert hits >= 1


def test_astyx_columns_are_checked_by_name_and_frames_named_once(tmp_path) -> None:
    from sensor_envs.radar.astyx import load_astyx

    root = fp.write_astyx(tmp_path / "a", pc="\nMag V_r Z Y X\n50.0 0.0 0.0 1.0 10.0\n")
    with pytest.raises(InputError, match="field 'header'"):
        load_astyx(root)
    root = fp.write_astyx(tmp_path / "b")
    (root / "radar_6455" / "0.txt").write_text("\nX Y Z V_r Mag\n10.0 1.0 0.0 0.0 50.0\n")
    with pytest.raises(InputError, match="not an Astyx frame file"):
        load_astyx(root)


def test_a_link_loop_is_an_input_error(tmp_path) -> None:
    from sensor_envs.inputs import read_text

    os.symlink(tmp_path / "b", tmp_path / "a")
    os.symlink(tmp_path / "a", tmp_path / "b")
    with pytest.raises(InputError, match="cannot be read"):
        read_text(tmp_path / "a")


def test_structured_arrays_are_refused_in_npz_files(tmp_path) -> None:
    from sensor_envs.inputs import load_npz

    np.savez(tmp_path / "x.npz", a=np.zeros(2, dtype=[("u", "<f8")]))
    with pytest.raises(InputError, match="field 'a'"):
        load_npz(tmp_path / "x.npz")


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["fit", "radar", "{d}/log.csv", "--out", "{d}/m.npz", "--extra-state", ""], "--extra-state"),
        (["diagnose", "radar", "{d}/log.csv", "--out", "{d}/o", "--exclude", "\x1b[2J"], "--exclude"),
        (["fit", "radar", "{d}/log.csv", "--out", "{d}/m.npz", "--tail-weight", "4.9e-324"], "--tail-weight"),
        (["diagnose", "radar", "{d}/log.csv", "--out", "{d}/o", "--min-score", "1e-400"], "--min-score"),
        (["card", "{d}/m.npz", "--out", "{d}/c.md", "--metrics", " "], "--metrics"),
        (["train", "--env", "", "--out", "{d}/run"], "--env"),
        (["train", "--env", "sensor_envs/Neato-v0", "--out", "{d}/run", "--device", "nan"], "--device"),
        (["train", "--env", "sensor_envs/Neato-v0", "--out", "{d}/run", "--seed", "4294967296"], "--seed"),
        (["train", "--env", "sensor_envs/Neato-v0", "--out", "{d}/run", "--set", "x=*a"], "--set"),
        (["upgrade-model", "{d}/m.npz", "--out", "{d}/o.npz/"], "--out"),
    ],
)
def test_options_nobody_listed_are_refused_naming_the_option(argv, option, tmp_path, capsys) -> None:
    fp.write_radar_csv(tmp_path)
    (tmp_path / "m.npz").write_bytes((fp.SHIPPED / "radar_gaussian.npz").read_bytes())
    before = fc.snapshot(tmp_path)
    code, err = _run([a.replace("{d}", str(tmp_path)) for a in argv], capsys)
    assert code == 2 and len(err.splitlines()) == 1 and option in err, err
    assert fc.snapshot(tmp_path) == before


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("hyperparams={learning_rate: .nan}", "hyperparams"),
        ("hyperparams={no_such_argument: 1}", "hyperparams"),
        ("env_kwargs={no_such_argument: 1}", "env_kwargs"),
        ("n_timesteps=10000000000", "n_timesteps"),
        ("device=nan", "device"),
    ],
)
def test_training_configs_are_checked_before_any_output(override, field, tmp_path) -> None:
    from sensor_envs.training.train import DEFAULT_CONFIG, ConfigError, load_config

    with pytest.raises(ConfigError, match=field):
        load_config(DEFAULT_CONFIG, "sensor_envs/Neato-v0", [override])


def test_a_training_config_is_read_through_the_input_layer(tmp_path) -> None:
    from sensor_envs.training.train import ConfigError, load_config

    bomb = tmp_path / "c.yaml"
    bomb.write_text('a: &a ["x", "x"]\nb: [*a, *a]\n')
    with pytest.raises(ConfigError, match="aliases"):
        load_config(bomb, "sensor_envs/Neato-v0", [])
    with pytest.raises(ConfigError, match="character device"):
        load_config(Path("/dev/zero"), "sensor_envs/Neato-v0", [])


def test_a_metrics_file_with_a_key_twice_is_refused(tmp_path) -> None:
    from sensor_envs.cards import MetricsFileError, read_metrics

    p = tmp_path / "m.json"
    p.write_text(json.dumps({"measured": {}})[:-1] + ', "measured": {}}')
    with pytest.raises(MetricsFileError, match="appears twice"):
        read_metrics(p)


def test_negative_zero_in_a_file_is_zero(tmp_path, capsys) -> None:
    """A rig's ``scene_speed_std: -0.0`` passed the ``>= 0`` check and numpy's sampler refused it (``scale < 0``)."""
    blob = json.loads((fp.SHIPPED / "radar_rig.json").read_text())
    old = json.dumps(blob["params"]["scene_speed_std"])
    text = json.dumps(blob).replace(f'"scene_speed_std": {old}', '"scene_speed_std": -0.0')
    (tmp_path / "rig.json").write_text(text)
    argv = ["record", "radar", "--rig", str(tmp_path / "rig.json"), "--out", str(tmp_path / "r.csv")]
    code, err = _run([*argv, "--sequences", "1", "--cycles", "2"], capsys)
    assert code == 0, err
    assert str(parse_yaml("a: -0.0", "s")["a"]) == "0.0" and str(parse_json("[-0.0]", "s")[0]) == "0.0"


@pytest.mark.parametrize("verbose", [float("nan"), {}, 1e-5, np.array([1.0, 1.0])])
def test_verbose_is_a_flag_checked_at_fit_not_coerced_in_the_constructor(verbose, tmp_path) -> None:
    from sensor_envs.lidar.lwlr import LidarLWLR

    model = LidarLWLR(n_folds=2, variant="seed", verbose=verbose)  # stores it as given (sklearn style)
    with pytest.raises(InputError, match="verbose"):
        model.fit(fa._small_log("LidarLWLR", tmp_path))


def test_masked_entries_are_refused_never_unmasked() -> None:
    state = np.ma.masked_array([[10.0, 1.0]], mask=[[True, False]])
    with pytest.raises(InputError, match="masked"):
        fa.shipped_model("GaussianRadar").sample(state, np.random.default_rng(0))


def test_the_vector_env_takes_its_action_space_shape_only() -> None:
    import gymnasium as gym

    env = gym.make_vec("sensor_envs/Neato-v0", num_envs=2, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    with pytest.raises(InputError, match="actions"):
        env.step(np.array([0.5, 0.2, 0.5, 0.2]))  # a flat batch: (4,), not (2, 2)


def test_a_clutter_row_copied_whole_is_refused(tmp_path) -> None:
    from sensor_envs.radar.log import read_log

    rows = fp.radar_rows()
    clutter = next(r for r in rows if ",-1," in r)
    p = tmp_path / "log.csv"
    p.write_text("\n".join([fp.RADAR_HEADER, *rows, clutter]) + "\n")
    with pytest.raises(InputError, match="repeats the clutter detection"):
        read_log(p)


def test_a_radar_log_is_read_in_a_few_times_its_size(tmp_path) -> None:
    """Rows are parsed into 8-byte columns as they are read (they were held as lists of strings: 35x the file)."""
    import tracemalloc

    from sensor_envs.radar.log import read_log

    rows = [f"{i // 100},{i % 100},{i % 100}.0,0,10.0,1.0,0.1,4.5,1.8,8.0,1.1,1.0" for i in range(20_000)]
    p = tmp_path / "log.csv"
    p.write_text("\n".join([fp.RADAR_HEADER, *rows]) + "\n")
    tracemalloc.start()
    read_log(p)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 12 * p.stat().st_size, (peak, p.stat().st_size)


def test_a_json_document_of_too_many_values_is_refused_before_parsing() -> None:
    from sensor_envs.inputs import LIMITS

    with pytest.raises(InputError, match="more than"):
        parse_json("[" + "0," * (2 * LIMITS.nodes + 1) + "0]", "src")


@pytest.mark.parametrize("token", ["1_0.5", "nan", "infinity", "١", "１", " 1e"])
def test_a_text_map_takes_plain_decimal_numbers_only(token, tmp_path) -> None:
    from sensor_envs.maps import load_map

    (tmp_path / "m.txt").write_text(fp.MAP_TXT.replace("4 0 4 3", f"{token} 0 4 3"))
    with pytest.raises(InputError, match="four numbers"):
        load_map(tmp_path / "m.txt")
