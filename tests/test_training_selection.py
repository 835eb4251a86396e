"""``sensor-envs robustness --policy selected`` and ``--reevaluate`` (sensor_envs.training.selection).

The choice itself is tested on fake checkpoints with a stub episode loop (no training); the command end to end on
the highway ``short`` preset with checkpoints saved (``--set eval_freq=64``: 64 and 128 steps).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
from pathlib import Path

import pytest

from sensor_envs.training import robustness, selection


class _Model:
    def __init__(self, path: Path, steps: int):
        self.path, self.num_timesteps = path, steps


def _fake_job(tmp_path, steps=(1000, 2000, 3000), final_steps=3000):
    """A job folder with fake checkpoints (distinct bytes) and the config.json robustness writes."""
    run = tmp_path / "runs" / "ideal" / "seed0"
    (run / "checkpoints").mkdir(parents=True)
    for s in steps:
        (run / "checkpoints" / f"model_{s}_steps.zip").write_bytes(f"weights {s}".encode())
    (run / "final_model.zip").write_bytes(f"final weights {final_steps}".encode())
    cfg = {"algo": "dqn", "env_kwargs": {"radar": "ideal", "fov": 6.28}}
    (run / "config.json").write_text(json.dumps({"env_id": "sensor_envs/HighwayFast-v0", "seed": 0, "config": cfg}))
    return run, final_steps


@pytest.fixture
def stub(monkeypatch):
    """Load a fake model (its path and steps); ``play`` maps a file name to (collision rate, mean return)."""
    calls: list[dict] = []
    play: dict[str, tuple[float, float]] = {}

    def load(algo, path, device):
        name = Path(path).name
        steps = int(name.split("_")[1]) if name.startswith("model_") else int(Path(path).read_text().split()[-1])
        return _Model(Path(path), steps)

    def evaluate(model, env_id, kwargs, episodes, max_steps, seed0=robustness.EVAL_SEED):
        calls.append(
            {"file": model.path.name, "env_id": env_id, "kwargs": kwargs, "episodes": episodes, "seed0": seed0}
        )
        rate, ret = play[model.path.name]
        hits = round(rate * episodes)
        return {
            "return": [ret] * episodes,
            "collision": [1.0] * hits + [0.0] * (episodes - hits),
            "success": [0.0] * episodes,
            "speed": [25.0] * episodes,
        }

    monkeypatch.setattr(selection, "_load", load)
    return evaluate, play, calls


def test_fewest_collisions_win_ties_go_to_the_higher_return(tmp_path, stub):
    evaluate, play, calls = stub
    run, _ = _fake_job(tmp_path)
    play.update({"model_1000_steps.zip": (0.2, 30.0), "model_2000_steps.zip": (0.1, 20.0)})
    play["model_3000_steps.zip"] = (0.1, 22.0)  # same collisions as 2000, more return: chosen
    lines: list[str] = []
    res = selection.select(run, 10, None, "cpu", evaluate, log=lines.append)
    assert res["chosen"]["steps"] == 3000 and res["chosen"]["checkpoint"] == "checkpoints/model_3000_steps.zip"
    # the final model has a checkpoint's step count: not played again
    assert [c["file"] for c in calls] == [f"model_{s}_steps.zip" for s in (1000, 2000, 3000)]
    # the job's own training sensor, the validation seeds
    assert all(c["kwargs"] == {"radar": "ideal", "fov": 6.28} and c["seed0"] == selection.SELECT_SEED for c in calls)
    assert all(c["env_id"] == "sensor_envs/HighwayFast-v0" and c["episodes"] == 10 for c in calls)
    assert (run / "selected_model.zip").read_bytes() == b"weights 3000"
    assert len([line for line in lines if "of 3" in line]) == 3  # a line per checkpoint


def test_selection_json_records_every_checkpoint_and_the_choice(tmp_path, stub):
    evaluate, play, _ = stub
    run, _ = _fake_job(tmp_path, steps=(1000, 2000), final_steps=2500)
    play.update({"model_1000_steps.zip": (0.5, 10.0), "model_2000_steps.zip": (0.3, 18.0)})
    play["final_model.zip"] = (0.0, 15.0)  # its own step count: a candidate, and the safest
    selection.select(run, 4, 30, "cpu", evaluate, log=lambda line: None)
    rec = json.loads((run / "selection.json").read_text())
    seeds = [selection.SELECT_SEED, selection.SELECT_SEED + 3]
    assert rec["episodes"] == 4 and rec["seeds"] == seeds and rec["env_kwargs"] == {"radar": "ideal", "fov": 6.28}
    assert [(c["checkpoint"], c["steps"]) for c in rec["candidates"]] == [
        ("checkpoints/model_1000_steps.zip", 1000),
        ("checkpoints/model_2000_steps.zip", 2000),
        ("final_model.zip", 2500),
    ]
    first = rec["candidates"][0]
    assert first["collision_rate"] == 0.5 and first["mean_return"] == 10.0 and first["mean_speed"] == 25.0
    assert first["episodes"] == 4 and first["seeds"] == seeds
    assert rec["chosen"]["checkpoint"] == "final_model.zip" and rec["chosen"]["steps"] == 2500
    from sensor_envs.modelio import file_sha256

    assert rec["chosen"]["sha256"] == file_sha256(run / "final_model.zip") == file_sha256(run / "selected_model.zip")


def test_selected_model_is_replaced_atomically(tmp_path, stub, monkeypatch):
    evaluate, play, _ = stub
    run, _ = _fake_job(tmp_path, steps=(1000,), final_steps=1000)
    play["model_1000_steps.zip"] = (0.0, 1.0)
    (run / "selected_model.zip").write_bytes(b"the previous choice")

    def broken_copy(src, dst):  # a copy that dies half way
        Path(dst).write_bytes(b"weig")
        raise OSError("disk full")

    monkeypatch.setattr(selection.shutil, "copyfile", broken_copy)
    with pytest.raises(OSError, match="disk full"):
        selection.select(run, 2, None, "cpu", evaluate, log=lambda line: None)
    assert (run / "selected_model.zip").read_bytes() == b"the previous choice"
    assert sorted(p.name for p in run.iterdir()) == [
        "checkpoints",
        "config.json",
        "final_model.zip",
        "selected_model.zip",
    ]
    monkeypatch.undo()
    monkeypatch.setattr(selection, "_load", lambda algo, path, device: _Model(Path(path), 1000))
    selection.select(run, 2, None, "cpu", evaluate, log=lambda line: None)
    assert (run / "selected_model.zip").read_bytes() == b"weights 1000"
    assert not [p for p in run.iterdir() if p.name.startswith(".")]  # no temporary left


def test_a_job_without_checkpoints_is_refused_naming_it(tmp_path, stub):
    evaluate, _, _ = stub
    run, _ = _fake_job(tmp_path, steps=())
    with pytest.raises(selection.UsageError, match=f"{re.escape(str(run))}.*no checkpoints"):
        selection.select(run, 2, None, "cpu", evaluate)
    assert not (run / "selected_model.zip").exists() and not (run / "selection.json").exists()


def test_previous_evaluation_is_kept_under_its_policy(tmp_path):
    run = tmp_path / "job"
    run.mkdir()
    old = {"spec": {"policy": "best"}, "cells": {"ideal": {"collision": [1.0]}}}  # no "policy": spec's
    (run / "eval.json").write_text(json.dumps(old))
    assert selection.write_eval(run, {"policy": "selected", "cells": {}}, keep=True) == run / "eval_best.json"
    assert json.loads((run / "eval_best.json").read_text()) == old
    assert json.loads((run / "eval.json").read_text())["policy"] == "selected"
    # the same policy again with another evaluation: a second name, nothing overwritten
    (run / "eval.json").write_text(json.dumps({**old, "cells": {}}))
    assert selection.write_eval(run, {"policy": "final"}, keep=True) == run / "eval_best.1.json"
    assert json.loads((run / "eval_best.json").read_text()) == old
    # without keep (a job's first evaluation) nothing is kept
    assert selection.write_eval(run, {"policy": "final"}, keep=False) is None
    assert sorted(p.name for p in run.iterdir()) == ["eval.json", "eval_best.1.json", "eval_best.json"]


def _args(**kw):
    return argparse.Namespace(**{"select_episodes": None, **kw})


def test_select_episodes_is_a_setting_of_the_selected_policy_only():
    short = {"n_timesteps": 128, "eval_freq": 64}
    assert selection.settings(_args(), "selected", short) == {"select_episodes": selection.SELECT_EPISODES}
    assert selection.settings(_args(select_episodes=7), "selected", short) == {"select_episodes": 7}
    assert selection.settings(_args(), "best", short) == {}  # old runs' settings stay the same
    with pytest.raises(selection.UsageError, match="--select-episodes applies to --policy selected"):
        selection.settings(_args(select_episodes=7), "final", short)
    with pytest.raises(selection.UsageError, match="--select-episodes: must be >= 1"):
        selection.settings(_args(select_episodes=0), "selected", short)
    with pytest.raises(selection.UsageError, match="--policy selected: no checkpoint is saved"):
        selection.settings(_args(), "selected", {"n_timesteps": 128, "eval_freq": 10**9})


# ---------------------------------------------------------------------------------------------- end to end
SHORT = ["--domain", "highway", "--preset", "short", "--sensors", "ideal", "--columns", "ideal", "--seeds", "1"]
SHORT += ["--set", "eval_freq=64", "--device", "cpu", "--workers", "1"]


def _job(out: Path) -> Path:
    return out / "runs" / "ideal" / "seed0"


@pytest.mark.slow
def test_policy_selected_end_to_end(tmp_path):
    out = tmp_path / "sel"
    matrix = robustness.main([*SHORT, "--out", str(out), "--policy", "selected", "--select-episodes", "3"])
    job = _job(out)
    assert json.loads((out / "settings.json").read_text())["select_episodes"] == 3
    res = json.loads((job / "eval.json").read_text())
    rec = json.loads((job / "selection.json").read_text())
    assert res["policy"] == "selected" and res["selection"] == rec and res["spec"]["select_episodes"] == 3
    assert [c["steps"] for c in rec["candidates"]] == [64, 128]  # final_model.zip: 128 steps, not again
    assert all(c["episodes"] == 3 and c["mean_speed"] > 0 for c in rec["candidates"])
    best = min(rec["candidates"], key=lambda c: (c["collision_rate"], -c["mean_return"], -c["steps"]))
    assert rec["chosen"]["checkpoint"] == best["checkpoint"]
    assert (job / "selected_model.zip").read_bytes() == (job / best["checkpoint"]).read_bytes()
    assert list(matrix["cells"]) == ["ideal->ideal"]
    hashes = json.loads((out / "matrix.json").read_text())["run"]["sha256"]["policies"]
    assert list(hashes) == ["ideal/seed0/selected_model.zip"] and hashes["ideal/seed0/selected_model.zip"]


@pytest.fixture(scope="module")
def best_run(tmp_path_factory):
    """A finished short run that evaluated EvalCallback's best model."""
    out = tmp_path_factory.mktemp("reeval") / "best"
    robustness.main([*SHORT, "--out", str(out), "--policy", "best"])
    return out


def _files(job: Path) -> dict[str, int]:
    """The training outputs of a job and their modification times (a retraining would rewrite them)."""
    paths = [job / "config.json", job / "final_model.zip", job / "best_model.zip", *(job / "checkpoints").iterdir()]
    return {p.name: p.stat().st_mtime_ns for p in paths}


@pytest.mark.slow
def test_reevaluate_switches_the_policy_and_keeps_the_old_evaluation(best_run, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(best_run, out)
    job = _job(out)
    before, trained = (job / "eval.json").read_text(), _files(job)
    argv = [*SHORT, "--out", str(out), "--policy", "selected", "--select-episodes", "2", "--reevaluate"]
    with pytest.raises(SystemExit) as err:  # another policy is another setting: --force, as for any setting
        robustness.main(argv)
    assert err.value.code == 2 and "policy" in capsys.readouterr().err
    assert (job / "eval.json").read_text() == before and not (job / "eval_best.json").exists()
    robustness.main([*argv, "--force"])
    assert "1 of 1 done jobs to evaluate again" in capsys.readouterr().out
    assert (job / "eval_best.json").read_text() == before  # the previous evaluation, kept
    res = json.loads((job / "eval.json").read_text())
    assert res["policy"] == "selected" and res["spec"]["reevaluate"] and res["selection"]["episodes"] == 2
    assert res["train_seconds"] == json.loads(before)["train_seconds"]
    assert _files(job) == trained  # not trained again
    assert (job / "selected_model.zip").is_file() and (job / "done").is_file()
    hashes = json.loads((out / "matrix.json").read_text())["run"]["sha256"]["policies"]
    assert list(hashes) == ["ideal/seed0/selected_model.zip"]
    # the same again: nothing to do; back to best: the selected evaluation is kept in its turn
    robustness.main([*argv])
    assert "0 of 1 done jobs to evaluate again (1 already evaluated so)" in capsys.readouterr().out
    robustness.main([*SHORT, "--out", str(out), "--policy", "best", "--reevaluate", "--force"])
    assert json.loads((job / "eval_selected.json").read_text()) == res
    assert json.loads((job / "eval.json").read_text())["cells"] == json.loads(before)["cells"]  # deterministic


@pytest.mark.slow
def test_reevaluate_selected_without_checkpoints_is_an_input_error(best_run, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(best_run, out)
    job = _job(out)
    shutil.rmtree(job / "checkpoints")
    settings = (out / "settings.json").read_text()
    with pytest.raises(SystemExit) as err:
        robustness.main([*SHORT, "--out", str(out), "--policy", "selected", "--reevaluate", "--force"])
    msg = capsys.readouterr().err.strip()
    assert err.value.code == 2 and len(msg.splitlines()) == 1 and str(job) in msg and "no checkpoints" in msg
    assert (out / "settings.json").read_text() == settings  # refused before anything was written
    assert not (job / "eval_best.json").exists() and not (job / "selected_model.zip").exists()
