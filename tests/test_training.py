import json

import pytest

from sensor_envs.cli.main import main
from sensor_envs.training import train as train_module


def _train_module():
    return train_module


@pytest.mark.slow
def test_training_smoke_run_writes_config_model_and_result(tmp_path):
    train = _train_module()
    out = tmp_path / "run"
    result = train.main(
        [
            "--env",
            "sensor_envs/Neato-v0",
            "--out",
            str(out),
            "--seed",
            "3",
            "--set",
            "n_timesteps=256",
            "--set",
            "n_envs=1",
            "--set",
            "eval_freq=128",
            "--set",
            "eval_episodes=1",
            "--set",
            "env_kwargs={lidar: gaussian}",
            "--set",
            "hyperparams={n_steps: 128, batch_size: 64, n_epochs: 1}",
        ]
    )
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["seed"] == 3 and cfg["config"]["env_kwargs"] == {"lidar": "gaussian"}
    assert (out / "final_model.zip").is_file() and (out / "evaluations.npz").is_file()
    assert json.loads((out / "result.json").read_text()) == result


def test_unknown_config_key_is_an_error(tmp_path):
    train = _train_module()
    with pytest.raises(SystemExit, match="unknown keys"):
        train.main(["--env", "sensor_envs/Neato-v0", "--out", str(tmp_path), "--set", "n_timestep=5"])


def test_config_errors_exit_2_with_one_line_naming_the_key(tmp_path, capsys):
    train = _train_module()
    cases = [
        (["--set", "vec_env=threads"], "vec_env"),
        (["--set", "n_timesteps=-3"], "n_timesteps"),
        (["--algo", "sac", "--env", "sensor_envs/HighwayFast-v0"], "algos.sac"),
        (["--env", "sensor_envs/Nope-v0"], "--env"),
        (["--env", "sensor_envs/HighwayFast-v0", "--set", "vec_env=vector"], "vec_env"),
    ]
    for extra, key in cases:
        argv = ["--env", "sensor_envs/Neato-v0", "--out", str(tmp_path / "x"), *extra]
        with pytest.raises(SystemExit) as err:
            train.main(argv)
        assert err.value.code == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and key in lines[0]
    with pytest.raises(train.ConfigError, match="unknown keys"):
        train.load_config(train.DEFAULT_CONFIG, "sensor_envs/Neato-v0", ["bogus=1"])


def test_existing_out_is_refused_unless_force(tmp_path, capsys):
    """train.py used to write into an existing --out silently; now exit 2, one line, nothing written."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("old run")
    assert main(["train", "--env", "sensor_envs/Neato-v0", "--out", str(out), "--set", "n_timesteps=64"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--out" in lines[0] and "--force" in lines[0]
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]


def test_train_and_robustness_are_cli_commands_with_the_shipped_config(capsys):
    from importlib import resources

    shipped = resources.files("sensor_envs.training").joinpath("configs", "default.yaml")
    assert shipped.is_file() and str(train_module.DEFAULT_CONFIG) == str(shipped)
    for command in ("train", "robustness"):
        with pytest.raises(SystemExit) as err:
            main([command, "--help"])
        assert err.value.code == 0 and "--out" in capsys.readouterr().out


def test_algo_block_sensor_and_device_resolve():
    train = _train_module()
    cfg = train.load_config(train.DEFAULT_CONFIG, "sensor_envs/HighwayFast-v0", [], algo="dqn", sensor="gaussian")
    assert cfg["algo"] == "dqn" and "buffer_size" in cfg["hyperparams"] and "n_steps" not in cfg["hyperparams"]
    assert cfg["env_kwargs"]["radar"] == "gaussian" and cfg["device"] == "auto" and cfg["vec_env"] == "dummy"
    for env_id in ("sensor_envs/Merge-v0", "sensor_envs/Intersection-v0"):
        assert train.load_config(train.DEFAULT_CONFIG, env_id, [])["algo"] == "ppo"
    neato = train.load_config(train.DEFAULT_CONFIG, "sensor_envs/Neato-v0", [], algo="sac", sensor="ideal")
    assert neato["algo"] == "sac" and neato["env_kwargs"]["lidar"] == "ideal"


@pytest.mark.slow
def test_subproc_vec_env_and_tensorboard_log(tmp_path):
    pytest.importorskip("tensorboard", reason="TensorBoard logs need the train extra (pip install tensorboard)")
    train = _train_module()
    out = tmp_path / "sub"
    result = train.main(
        [
            "--env", "sensor_envs/Neato-v0", "--out", str(out), "--seed", "1", "--sensor", "ideal", "--device", "cpu",
            "--set", "n_timesteps=128", "--set", "n_envs=2", "--set", "vec_env=subproc", "--set", "eval_freq=64",
            "--set", "eval_episodes=1", "--set", "hyperparams={n_steps: 64, batch_size: 64, n_epochs: 1}",
        ]
    )  # fmt: skip
    assert result["device"] == "cpu" and (out / "checkpoints").is_dir()
    assert any((out / "tb").rglob("events.out.tfevents.*"))
