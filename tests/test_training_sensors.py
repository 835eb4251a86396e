"""Named sensor variants of the training config (`sensors:`) in `train` and the robustness matrix."""

import json
import math
import warnings

import gymnasium as gym
import pytest
import yaml
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.training import robustness
from sensor_envs.training import train as train_module

HW = "sensor_envs/HighwayFast-v0"
SHIPPED = {
    "ideal": {"radar": "ideal"},
    "gaussian": {"radar": "gaussian"},
    "kde": {"radar": "kde"},
    "kde_drop": {"radar": "kde", "stationary": "drop"},
    "kde_tracks": {"radar": "kde", "stationary": "drop", "tracks": True},
    "ideal_surround": {"radar": "ideal", "fov": 2 * math.pi},
    "kde_tracks_surround": {"radar": "kde", "stationary": "drop", "tracks": True, "fov": 2 * math.pi},
}
SURROUND = ("ideal_surround", "kde_tracks_surround")


def _config(tmp_path, block):
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump({HW: {"algo": "ppo", "policy": "MlpPolicy", "n_timesteps": 8, **block}}))
    return path


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_highway_sensors_select_their_env_kwargs_and_nothing_stale(name):
    cfg = train_module.load_config(train_module.DEFAULT_CONFIG, HW, [], algo="dqn", sensor=name)
    table_keys = {k for entry in SHIPPED.values() for k in entry}
    kwargs = cfg["env_kwargs"]
    assert {k: v for k, v in kwargs.items() if k in table_keys} == SHIPPED[name]
    assert robustness.column_kwargs("highway", name, {}) == kwargs  # columns resolve as rows train


@pytest.mark.parametrize("name", SURROUND)
def test_surround_variants_build_pass_the_checkers_and_show_cars_behind(name):
    kwargs = train_module.load_config(train_module.DEFAULT_CONFIG, HW, [], algo="dqn", sensor=name)["env_kwargs"]
    env = gym.make(HW, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version.*")
        warnings.filterwarnings("ignore", category=DeprecationWarning, message=".*out of date.*")
        warnings.filterwarnings("ignore", message=".*unconventional shape.*")  # Kinematics is a table by design
        check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=True)
    # the ego starts among traffic: over a few idle steps a car behind the front bumper is reported
    behind = []
    obs, info = env.reset(seed=0)
    for _ in range(6):
        assert obs in env.observation_space
        behind.append(bool(((obs[1:, 0] > 0) & (obs[1:, 1] < 0)).any()))  # presence, x relative to the ego
        obs, _, terminated, truncated, info = env.step(1)
        if terminated or truncated:
            break
    assert any(behind)


def test_a_name_outside_the_table_sets_the_sensor_keyword_as_before():
    cfg = train_module.load_config(train_module.DEFAULT_CONFIG, HW, [], sensor="gaussian")
    assert cfg["env_kwargs"]["radar"] == "gaussian"
    neato = train_module.load_config(train_module.DEFAULT_CONFIG, "sensor_envs/Neato-v0", [], sensor="ideal")
    assert neato["env_kwargs"]["lidar"] == "ideal" and "sensors" not in neato


keys = st.sampled_from(["radar", "stationary", "tracks", "clutter_fraction", "history"])
values = st.one_of(st.booleans(), st.integers(0, 5), st.sampled_from(["kde", "ideal", "drop", "keep"]))
entries = st.dictionaries(keys, values, min_size=1, max_size=3)


@settings(max_examples=60, deadline=None)
@given(
    table=st.dictionaries(st.sampled_from(["a", "b", "c"]), entries, min_size=1, max_size=3),
    defaults=st.dictionaries(st.sampled_from(["radar", "tracks", "vehicles_count", "lanes_count"]), values),
    data=st.data(),
)
def test_selected_sensor_is_its_entry_over_the_defaults_it_does_not_own(table, defaults, data):
    name = data.draw(st.sampled_from(sorted(table)))
    cfg = {"env_kwargs": defaults, "sensors": table}
    got = train_module.sensor_kwargs(cfg, HW, name)
    owned = {k for entry in table.values() for k in entry}
    assert got == {**{k: v for k, v in defaults.items() if k not in owned}, **table[name]}
    assert not (owned - set(table[name])) & set(got)  # no option of another variant leaks in


@pytest.mark.parametrize(
    ("sensors", "message"),
    [
        ([1, 2], "sensors must be a mapping"),
        ({"kde_x": "kde"}, "sensors.kde_x must be a non-empty mapping"),
        ({"kde_x": {}}, "sensors.kde_x must be a non-empty mapping"),
    ],
)
def test_bad_sensor_tables_are_config_errors_naming_the_key(tmp_path, sensors, message):
    path = _config(tmp_path, {"sensors": sensors})
    for sensor in (None, "kde_x"):
        with pytest.raises(train_module.ConfigError, match=message) as err:
            train_module.load_config(path, HW, [], sensor=sensor)
        assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_robustness_refuses_unknown_rows_and_columns_with_exit_2(tmp_path, capsys):
    base = ["--domain", "highway", "--out", str(tmp_path / "o"), "--device", "cpu"]
    for flag in ("--sensors", "--columns"):
        with pytest.raises(SystemExit) as err:
            robustness.main([*base, flag, "kde_nope"])
        line = capsys.readouterr().err.strip()
        assert err.value.code == 2 and flag in line and "kde_nope" in line and "kde_tracks" in line
        assert len(line.splitlines()) == 1
    for bad in (["--eval-episodes", "0"], ["--set", "novalue"]):
        with pytest.raises(SystemExit) as err:
            robustness.main([*base, *bad])
        assert err.value.code == 2 and bad[0] in capsys.readouterr().err


@pytest.mark.slow  # the first KDE env of a process estimates its clutter rate (~10-30 s)
@pytest.mark.parametrize(("name", "tracks", "stationary"), [("kde_drop", False, "drop"), ("kde_tracks", True, "drop")])
def test_column_env_is_built_with_the_variant(name, tracks, stationary):
    env = gym.make(HW, **robustness.column_kwargs("highway", name, {}))
    try:
        env.reset(seed=3)
        wrapper = next(w for w in _wrappers(env) if hasattr(w, "stationary"))
        assert wrapper.tracks is tracks and wrapper.stationary == stationary
        _, _, _, _, info = env.step(1)
        assert ("tracks" in info) is tracks
    finally:
        env.close()


def _wrappers(env):
    while True:
        yield env
        if not hasattr(env, "env"):
            return
        env = env.env


@pytest.mark.slow
def test_tiny_highway_matrix_trains_and_evaluates_the_radar_variants(tmp_path):
    out = tmp_path / "hw"
    argv = ["--domain", "highway", "--preset", "short", "--out", str(out), "--device", "cpu", "--workers", "1"]
    argv += ["--sensors", "kde_drop", "kde_tracks", "--columns", "ideal", "kde_tracks", "--seeds", "1"]
    matrix = robustness.main([*argv, "--eval-episodes", "2", "--set", "n_timesteps=64"])
    assert matrix["rows_trained_on"] == ["kde_drop", "kde_tracks"]
    assert matrix["columns_evaluated_on"] == ["ideal", "kde_tracks"]
    for row in ("kde_drop", "kde_tracks"):
        job = json.loads((out / "runs" / row / "seed0" / "eval.json").read_text())
        assert job["spec"]["set"]["n_timesteps"] == 64 and job["spec"]["eval_episodes"] == 2
        assert all(len(job["cells"][c]["collision"]) == 2 for c in ("ideal", "kde_tracks"))
        trained = json.loads((out / "runs" / row / "seed0" / "config.json").read_text())["config"]["env_kwargs"]
        assert trained == train_module.load_config(train_module.DEFAULT_CONFIG, HW, [], sensor=row)["env_kwargs"]
    md = (out / "matrix.md").read_text()
    assert "| kde_tracks |" in md and "SHA-256" in md
    digests = json.loads((out / "matrix.json").read_text())["run"]["sha256"]
    assert set(digests["policies"]) == {"kde_drop/seed0/final_model.zip", "kde_tracks/seed0/final_model.zip"}
    assert all(len(d) == 64 for d in digests["policies"].values()) and digests["hashed_at"] == "jobs"
    assert set(digests["sensor_models"]) == {
        "radar_gaussian.npz",
        "radar_kde.npz",
        "radar_object_clutter.json",
        "radar_rig.json",
    }


def _fake_job(out, row, seed, sensor_hashes, policy=b"policy"):
    job = out / "runs" / row / f"seed{seed}"
    job.mkdir(parents=True)
    (job / "final_model.zip").write_bytes(policy)
    record = {} if sensor_hashes is None else {"sensor_models_sha256": sensor_hashes}
    (job / "eval.json").write_text(json.dumps(record))


def test_model_hashes_come_from_the_jobs_and_flag_jobs_that_used_other_models(tmp_path):
    import hashlib

    _fake_job(tmp_path, "ideal", 0, {"radar_kde.npz": "a"})
    _fake_job(tmp_path, "kde_tracks", 0, {"radar_kde.npz": "a"}, policy=b"other")
    got = robustness.model_hashes("highway", tmp_path, ["ideal", "kde_tracks"], [0], {})
    assert got["hashed_at"] == "jobs" and got["sensor_models"] == {"radar_kde.npz": "a"}
    assert "sensor_models_by_job" not in got
    assert got["policies"]["kde_tracks/seed0/final_model.zip"] == hashlib.sha256(b"other").hexdigest()
    _fake_job(tmp_path, "ideal", 1, {"radar_kde.npz": "b"})  # a resumed run after the model changed
    _fake_job(tmp_path, "kde_tracks", 1, {"radar_kde.npz": "a"})
    got = robustness.model_hashes("highway", tmp_path, ["ideal", "kde_tracks"], [0, 1], {})
    assert got["sensor_models_by_job"]["ideal/seed1"] == {"radar_kde.npz": "b"}
    _fake_job(tmp_path, "ideal", 2, None)  # a job from before jobs recorded them: hashed at report time
    _fake_job(tmp_path, "kde_tracks", 2, None)
    got = robustness.model_hashes("highway", tmp_path, ["ideal"], [2], {})
    assert got["hashed_at"] == "report" and set(got["sensor_models"]) == {
        "radar_gaussian.npz",
        "radar_kde.npz",
        "radar_object_clutter.json",
        "radar_rig.json",
    }


def test_a_model_file_set_in_the_config_is_hashed_by_its_path(tmp_path):
    import hashlib

    model = tmp_path / "radar_kde.npz"  # same name as the shipped model: must not hide it
    model.write_bytes(b"not the shipped model")
    got = robustness.sensor_model_hashes("highway", {str(model): str(model)})
    assert got[str(model)] == hashlib.sha256(b"not the shipped model").hexdigest()
    assert got["radar_kde.npz"] != got[str(model)]
