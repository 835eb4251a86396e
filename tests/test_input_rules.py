"""Bad input, third round (issue 42): the rules that the seed-23 benchmark run and new probes found missing.

One test per rule, each with the input that was accepted, crashed, hung or was blamed on the wrong thing
before. The generators that keep each class covered (``map image`` cuts of every format, ``option value``)
run in ``tests/test_input_structure.py`` and ``benchmarks/fuzz_inputs.py``.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import sensor_envs.testing.fuzz_cases as fc
from sensor_envs.cli.main import main
from sensor_envs.inputs import InputError
from sensor_envs.testing.fuzz_pieces import SHIPPED, DrawnChooser, lidar_arrays, write_npz, write_radar_csv

SMALL = settings(max_examples=5, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


def _run(argv: list[str], capsys) -> tuple[int, str]:
    """Exit status and the error line of the command line ``argv`` (which must print at most one line)."""
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) <= 1, err
    return code, err[0] if err else ""


# ------------------------------------------------------------------------------------------ numbers
def test_a_subnormal_is_no_value_of_any_declared_range(tmp_path, capsys) -> None:
    """``clutter_dispersion: 5e-324`` in a rig passed ``[0, 100]``; ``1 / value`` overflowed inside numpy."""
    from sensor_envs.constraints import Interval, Numbers

    assert not Interval(0, 100).accepts(5e-324) and not Interval(None, None).accepts(-1e-310)
    assert Interval(0, 100).accepts(0.0) and Interval(0, 100).accepts(1e-300)
    assert not Numbers(Interval(0, 1)).accepts([0.5, 5e-324])
    rig = json.loads((SHIPPED / "radar_rig.json").read_text())
    rig["params"]["clutter_dispersion"] = 5e-324
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(rig))
    code, line = _run(
        ["record", "radar", "--rig", str(path), "--out", str(tmp_path / "r.csv"), "--cycles", "2"], capsys
    )
    assert code == 2 and "clutter_dispersion" in line and "subnormal" in line
    assert not (tmp_path / "r.csv").exists()


# ------------------------------------------------------------------------------------------ files
@pytest.mark.parametrize("fmt", ["PNG", "GIF", "BMP", "JPEG", "TIFF", "WEBP"])
def test_a_map_image_cut_short_is_refused_wherever_it_is_cut(fmt, tmp_path) -> None:
    """A PNG cut inside its last checksums (seed 23), a GIF without its trailer, a BMP without its last padding
    decoded into whole pictures."""
    import io

    from PIL import Image

    from sensor_envs.maps import load_map
    from sensor_envs.testing.fuzz_pieces import ROS_YAML, pgm_bytes

    img = np.frombuffer(pgm_bytes()[12:], dtype=np.uint8).reshape(8, 10)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format=fmt)
    raw = buf.getvalue()
    name = f"map.{fmt.lower()}"
    yaml_path = tmp_path / "map.yaml"
    yaml_path.write_text(ROS_YAML.replace("map.pgm", name))
    (tmp_path / name).write_bytes(raw)
    load_map(yaml_path)  # whole: a valid map
    for cut in sorted({len(raw) - 1, len(raw) - 4, len(raw) // 2, 8}):
        (tmp_path / name).write_bytes(raw[:cut])
        with pytest.raises(InputError, match=name):
            load_map(yaml_path)


def test_kde_clutter_positions_must_match_their_counts(tmp_path) -> None:
    """An empty ``clutter_xy`` beside non-zero ``clutter_counts`` was taken: the model then drew no clutter."""
    from sensor_envs.modelio import ModelFileError
    from sensor_envs.radar.kde import KDERadarModel
    from sensor_envs.testing.bad_pieces import kde_model

    for xy in (np.zeros((0, 2)), np.zeros((5, 2))):
        with pytest.raises(ModelFileError, match="clutter_xy"):
            KDERadarModel.load(kde_model(tmp_path, clutter_xy=xy))


def test_a_symbolic_link_loop_is_an_input_error_wherever_it_is_given(tmp_path, capsys) -> None:
    """``Path.resolve()`` raised ``RuntimeError`` on a loop given as ``--map`` (checked against ``--out``)."""
    loop = tmp_path / "loop"
    os.symlink(loop, loop)
    for argv in (
        ["record", "lidar", "--map", str(loop), "--out", str(tmp_path / "r.npz")],
        ["upgrade-model", str(SHIPPED / "radar_gaussian.npz"), "--out", str(tmp_path / "loop.npz")],
    ):
        if argv[0] == "upgrade-model":
            os.symlink(tmp_path / "loop.npz", tmp_path / "loop.npz")
        code, line = _run(argv, capsys)
        assert code == 2 and "loop" in line


def test_a_model_reached_through_a_link_is_named_as_given(tmp_path) -> None:
    """The model caches load by the resolved path: a link to ``/dev/zero`` was blamed on ``/dev/zero``."""
    from sensor_envs.radar.sensors import make_radar

    link = tmp_path / "model.npz"
    os.symlink("/dev/zero", link)
    with pytest.raises(InputError, match=str(link)):
        make_radar("kde", str(link))


def test_readings_that_repeat_exactly_give_no_sigma_knot() -> None:
    """A bin whose median spread is 0 (mm readings repeating exactly) made a knot of 0 and a refused rig."""
    from sensor_envs.lidar.calibrate_laws import _sigma_knots
    from sensor_envs.lidar.calibrate_stats import RANGE_BINS

    sigma = np.full(len(RANGE_BINS) - 1, np.log(0.01))
    sigma[[0, 3]] = [-np.inf, np.nan]  # a bin of exactly repeating readings, a bin of too few cells
    kr, kv = _sigma_knots({"sigma_range": sigma.tolist()})
    assert all(v > 0 for v in kv) and len(kr) == len(kv)


@SMALL
@given(
    m=st.integers(1, 40),
    n=st.integers(1, 400),
    kind=st.sampled_from(["even", "ros", "rounded"]),
    seed=st.integers(0, 9),
)
def test_bearings_are_resampled_to_the_nearest_beam_in_linear_memory(m, n, kind, seed) -> None:
    """``--bearings 100000`` built a 100000 x beams table of gaps (1.6 GB for 2000 beams); the sorted search
    picks the same beams (ties: the first in the log)."""
    from sensor_envs.lidar.log import _nearest_beams

    rng = np.random.default_rng(seed)
    two_pi = 2 * np.pi
    old = {
        "even": two_pi * np.arange(m) / m,
        "ros": np.linspace(-np.pi, np.pi, m),
        "rounded": np.round(rng.uniform(0, 7, m), 1),
    }
    old_b = np.mod(old[kind], two_pi)
    new = two_pi * np.arange(n) / n
    gap = np.abs((new[:, None] - old_b[None, :] + np.pi) % two_pi - np.pi)
    got, g = _nearest_beams(new, old_b)
    assert (got == np.argmin(gap, axis=1)).all() and np.allclose(g, gap.min(axis=1))


# ------------------------------------------------------------------------------------------ the Python API
def test_a_highway_config_simulating_fewer_frames_than_policy_steps_is_refused() -> None:
    """``simulation_frequency: 1, policy_frequency: 5`` divided by zero inside highway-env (intersection)."""
    import gymnasium as gym

    with pytest.raises(InputError, match="simulation_frequency"):
        gym.make("sensor_envs/Intersection-v0", config={"simulation_frequency": 1, "policy_frequency": 5})
    env = gym.make("sensor_envs/HighwayFast-v0")
    with pytest.raises(InputError, match="options.config.policy_frequency"):
        env.reset(seed=0, options={"config": {"policy_frequency": 1000}})
    env.close()


def test_the_api_generators_judge_a_no_op_as_no_mutation() -> None:
    """Seed 23's two API "accepted nonsense" cases were the generator's: a ``bool`` array cast to ``bool``, and
    ``reset(options={"config": {}})``; and a rig table set to ``None`` that the rig declares optional."""
    from sensor_envs.testing.fuzz_api import mutate_array

    class Pick:
        def __init__(self, *picks):
            self.picks = list(picks)

        def integers(self, lo, hi):
            return hi  # the rig generator's 1-in-6 nesting bomb is drawn at 0

        def choice(self, seq):
            want = self.picks.pop(0)
            return want if want in list(seq) else list(seq)[0]

    value, _, must = mutate_array(Pick("dtype", np.bool_), np.array([True, True]))
    assert value.dtype == bool and not must
    with tempfile.TemporaryDirectory() as tmp:
        blob = json.loads((SHIPPED / "radar_rig.json").read_text())
        key = "params.clutter_cell_weights"
        assert key.split(".")[1] in blob["params"]
        case = fc.FAMILIES["rig file"](Pick("radar_rig.json", key, None), Path(tmp))
        assert case.mutation.endswith("clutter_cell_weights = None") and not case.must_refuse


def test_a_nan_cycle_time_argument_is_refused_none_means_absent() -> None:
    """``KDERadarModel.fit(log, cycle_time=nan)`` (seed 29) fitted a model without a cycle time: NaN means
    "absent" in a model file's header only."""
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.rig import record_rig_log

    log = record_rig_log(2, 6, 2, np.random.default_rng(0))
    for value in (float("nan"), np.float64("nan")):
        with pytest.raises(InputError, match="cycle_time"):
            GaussianRadar().fit(log, cycle_time=value)
    assert np.isnan(GaussianRadar().fit(log, cycle_time=None).cycle_time_)


def test_a_pose_given_as_a_numeric_array_is_plausible_to_the_api_generator() -> None:
    """Seed 29 counted ``sensor_pose=np.array([1, 1, 1], float16)`` as nonsense; the env rightly takes it."""
    from sensor_envs.testing.fuzz_api import certainly_bad

    assert not certainly_bad(np.array([1.0, 1.0, 1.0], dtype=np.float16), None, "pose")
    assert certainly_bad(np.array([True, True, True]), None, "pose")
    assert certainly_bad(np.array([np.nan, 1.0, 1.0]), None, "pose")


# ------------------------------------------------------------------------------------------ options
def test_every_option_error_names_the_option(tmp_path, capsys) -> None:
    """``train --sensor nan`` blamed ``env_kwargs: lidar``; ``fit lidar --map nan`` said ``nan: input not found``;
    ``diagnose radar --model /dev/null`` blamed the log; ``train --config /dev/null`` named no option."""
    log = write_npz(tmp_path / "log.npz", lidar_arrays())
    csv = write_radar_csv(tmp_path)
    out = str(tmp_path / "out")
    cases = [
        (["train", "--env", "sensor_envs/Neato-v0", "--out", out, "--sensor", "nan"], "--sensor nan"),
        (["train", "--env", "sensor_envs/Neato-v0", "--out", out, "--config", "/dev/null"], "--config /dev/null"),
        (["train", "--env", "sensor_envs/Neato-v0", "--out", out, "--algo", "dqn"], "--algo dqn"),
        (["fit", "lidar", str(log), "--out", f"{out}.npz", "--note", "nan", "--map", "nan"], "--map nan"),
        (["diagnose", "radar", str(csv), "--out", out, "--model", "/dev/null"], "--model /dev/null"),
        (["fit", "radar", str(csv), "--out", f"{out}.npz", "--extra-state", "nan"], "--extra-state nan"),
    ]
    for argv, named in cases:
        code, line = _run(argv, capsys)
        assert code == 2 and line.startswith(f"sensor-envs {argv[0]}: error: {named}"), (argv, line)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv", "log.npz"]


@SMALL
@given(data=st.data())
def test_a_plausible_word_or_file_that_names_nothing_is_refused_naming_its_option(data) -> None:
    """The ``option value`` family: every input and word option of every command, given ``nan``, a missing
    file, a folder, a device, an empty or NUL file, a FIFO, a link loop or a link to ``/dev/zero``."""
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        case = fc.make_case("option value", DrawnChooser(data), Path(tmp))
        outcome = fc.classify(case, Path(tmp))
    assert outcome == "clean error", f"{case.mutation!r} -> {outcome}"


def test_robustness_checks_every_job_before_anything_is_written(tmp_path, capsys) -> None:
    """``--algo dqn`` (no block for the Neato), ``--set x=1`` and a bad ``--real-data`` failed inside a job
    process (a ``RuntimeError`` traceback) after ``--out`` was made; a preset's own keys were blamed on --set."""
    out = tmp_path / "o"
    for extra, named in (
        (["--algo", "dqn"], "--algo dqn"),
        (["--set", "x=1"], "with --set x:"),
        (["--real-data", str(tmp_path / "none")], "--real-data"),
        (["--columns", "kde"], "--columns"),
    ):
        code, line = _run(["robustness", "--out", str(out), "--device", "cpu", *extra], capsys)
        assert code == 2 and named in line and "--set n_timesteps" not in line, line
        assert not out.exists()


def test_robustness_refuses_an_address_where_no_cluster_answers(tmp_path, capsys) -> None:
    """``ray.init`` waited more than ten minutes on ``--address 127.0.0.1:1``; ``--address nan`` was a
    ``ValueError`` traceback from ray."""
    pytest.importorskip("ray")
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for address in ("nan", f"127.0.0.1:{port}", "ray://:1"):
        code, line = _run(
            ["robustness", "--out", str(tmp_path / "o"), "--backend", "ray", "--address", address], capsys
        )
        assert code == 2 and "--address" in line
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------------ outputs
def test_an_output_folder_may_not_hold_what_the_command_reads(tmp_path, capsys, monkeypatch) -> None:
    """``train --config DIR/c.yaml --out DIR --force`` trained, then replaced DIR (and the config) with the
    run; ``rebuild-models --out models --force`` would replace the shipped models and recipes; ``--out .``
    ran to its end and then failed to rename onto the current folder."""
    config = tmp_path / "c.yaml"
    shutil.copy(Path(__file__).parents[1] / "sensor_envs" / "training" / "configs" / "default.yaml", config)
    code, line = _run(
        ["train", "--env", "sensor_envs/Neato-v0", "--config", str(config), "--out", str(tmp_path), "--force"], capsys
    )
    assert code == 2 and "--out" in line and str(config) in line
    recipes = tmp_path / "recipes"
    recipes.mkdir()
    shutil.copy(SHIPPED / "recipes" / "neato_lidar.yaml", recipes)
    code, line = _run(["rebuild-models", "--recipes", str(recipes), "--out", str(tmp_path), "--force"], capsys)
    assert code == 2 and "--out" in line and "recipes" in line
    code, line = _run(["evaluate", "aeb", "--out", str(SHIPPED), "--force", "--episodes", "1"], capsys)
    assert code == 2 and "shipped model files" in line
    monkeypatch.chdir(recipes)
    code, line = _run(["evaluate", "aeb", "--out", str(tmp_path), "--force", "--episodes", "1"], capsys)
    assert code == 2 and "current folder" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml", "recipes"]


def test_a_sigterm_inside_rebuild_is_no_refused_option(tmp_path, monkeypatch) -> None:
    """``rebuild-models`` turned the ``SystemExit(143)`` of a SIGTERM in a nested command into "the fit options
    are refused"; the command must end with that status, rolled back."""
    import sensor_envs.cli.main as cli_main
    from sensor_envs.cli.rebuild import rebuild

    def killed(argv):
        raise SystemExit(143)

    monkeypatch.setattr(cli_main, "main", killed)
    with pytest.raises(SystemExit) as err:
        rebuild(tmp_path / "b", ["neato_lidar"], force=False)
    assert err.value.code == 143 and not (tmp_path / "b").exists()


def test_boxworld_bounds_the_scans_it_draws_at_once(tmp_path, capsys) -> None:
    """``evaluate boxworld --poses 100000 --repeats 10000`` asked numpy for 2.6 TiB (a MemoryError traceback)."""
    argv = ["evaluate", "boxworld", "--out", str(tmp_path / "e"), "--poses", "100000", "--repeats", "10000"]
    code, line = _run(argv, capsys)
    assert code == 2 and "--poses x --repeats" in line and not (tmp_path / "e").exists()
