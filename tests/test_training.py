import importlib.util
import json
from pathlib import Path

import pytest

TRAIN = Path(__file__).resolve().parents[1] / "training" / "train.py"


def _train_module():
    spec = importlib.util.spec_from_file_location("train", TRAIN)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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
