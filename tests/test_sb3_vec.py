"""The SB3 adapter of gymnasium vector envs: the same numbers as SB3's DummyVecEnv of single envs, and training."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode

pytest.importorskip("stable_baselines3")

from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecMonitor

import sensor_envs  # noqa: F401
from sensor_envs.envs.sb3_vec import SB3VecEnv, make_sb3_vector_env, unbatch_info

ID = "sensor_envs/Neato-v0"


def _assert_same_rollout(vec, dummy, n, steps, seed_actions=0):
    """Step both SB3 VecEnvs with the same random actions; everything must be equal bit for bit."""
    ends = {"terminated": 0, "truncated": 0}
    rng = np.random.default_rng(seed_actions)
    for t in range(steps):
        actions = rng.uniform(-1, 1, size=(n, 2)).astype(np.float32)
        obs_v, rew_v, done_v, infos_v = vec.step(actions)
        obs_d, rew_d, done_d, infos_d = dummy.step(actions)
        assert obs_v.dtype == obs_d.dtype and np.array_equal(obs_v, obs_d), t
        assert rew_v.dtype == rew_d.dtype and np.array_equal(rew_v, rew_d), t
        assert np.array_equal(done_v, done_d), t
        assert isinstance(infos_v, list) and len(infos_v) == n
        for iv, idd in zip(infos_v, infos_d, strict=True):
            ep_v, ep_d = iv.pop("episode", None), idd.pop("episode", None)
            assert iv.keys() == idd.keys() and data_equivalence(iv, idd, exact=True), t
            assert (ep_v is None) == (ep_d is None), t
            if ep_d is not None:  # VecMonitor sums in float32, Monitor in float64 rounded to 6 digits
                assert ep_v["l"] == ep_d["l"] and ep_v["r"] == pytest.approx(ep_d["r"], rel=1e-5, abs=1e-5)
            if "terminal_observation" in idd:
                ends["truncated" if idd["TimeLimit.truncated"] else "terminated"] += 1
    return ends


@pytest.mark.parametrize("lidar", ["gaussian", "learned"])
def test_adapter_matches_dummy_vec_env_through_episode_ends(lidar):
    n, kwargs = 4, {"lidar": lidar, "max_episode_steps": 15}
    vec = make_sb3_vector_env(ID, n, seed=7, env_kwargs=kwargs)
    dummy = make_vec_env(f"sensor_envs:{ID}", n_envs=n, seed=7, env_kwargs=kwargs)
    assert isinstance(vec, VecMonitor) and isinstance(vec.venv, SB3VecEnv)
    assert vec.observation_space == dummy.observation_space and vec.action_space == dummy.action_space
    assert np.array_equal(vec.reset(), dummy.reset())
    assert data_equivalence(vec.venv.reset_infos, dummy.reset_infos, exact=True)
    ends = _assert_same_rollout(vec, dummy, n, 40)
    assert ends["terminated"] > 0 and ends["truncated"] > 0, ends  # both kinds of episode end were exercised
    assert data_equivalence(vec.venv.reset_infos, dummy.reset_infos, exact=True)
    # a reset without a seed continues each robot's streams, as DummyVecEnv's single envs do
    assert np.array_equal(vec.reset(), dummy.reset())
    _assert_same_rollout(vec, dummy, n, 5, seed_actions=1)
    # seed() applies to the next reset only, as in DummyVecEnv
    vec.seed(123)
    dummy.seed(123)
    assert np.array_equal(vec.reset(), dummy.reset())
    vec.close()
    dummy.close()


def test_adapter_over_gymnasium_sync_vector_env():
    n, kwargs = 2, {"lidar": "gaussian", "max_episode_steps": 10}
    sync = gym.make_vec(ID, num_envs=n, vectorization_mode="sync", **kwargs)
    vec = VecMonitor(SB3VecEnv(sync))
    dummy = make_vec_env(f"sensor_envs:{ID}", n_envs=n, seed=3, env_kwargs=kwargs)
    vec.seed(3)
    assert np.array_equal(vec.reset(), dummy.reset())
    assert _assert_same_rollout(vec, dummy, n, 25)["truncated"] > 0
    assert vec.get_attr("render_mode") == [None, None] and vec.env_is_wrapped(gym.wrappers.TimeLimit) == [True] * n
    with pytest.raises(ValueError, match="indices=None"):
        vec.set_attr("render_mode", None, indices=[0])
    same_step = gym.make_vec(ID, num_envs=n, vectorization_mode="sync", vector_kwargs={"autoreset_mode": "SameStep"})
    assert same_step.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    with pytest.raises(ValueError, match="autoreset mode"):
        SB3VecEnv(same_step)


def test_unbatch_info_honours_masks_and_gives_python_scalars():
    info = {
        "d": np.array([1.5, 2.5]),
        "_d": np.array([True, False]),
        "row": np.arange(6).reshape(2, 3),
        "_row": np.array([True, True]),
        "sub": {"x": np.array([1, 2]), "_x": np.array([False, True])},
        "_sub": np.array([True, True]),
    }
    a, b = unbatch_info(info, 2)
    assert a == {"d": 1.5, "row": a["row"], "sub": {}} and type(a["d"]) is float
    assert a["row"].tolist() == [0, 1, 2] and b["row"].tolist() == [3, 4, 5]
    assert b.keys() == {"row", "sub"} and b["sub"] == {"x": 2}


def _train_module():
    from sensor_envs.training import train

    return train


def _short_vector_run(train, out, seed):
    return train.main(
        [
            "--env", ID, "--out", str(out), "--seed", str(seed), "--sensor", "gaussian", "--device", "cpu",
            "--set", "n_timesteps=256", "--set", "n_envs=2", "--set", "vec_env=vector", "--set", "eval_freq=128",
            "--set", "eval_episodes=1", "--set", "hyperparams={n_steps: 128, batch_size: 64, n_epochs: 1}",
        ]
    )  # fmt: skip


@pytest.mark.slow
def test_ppo_trains_on_the_vector_entry_point_and_same_seed_gives_same_model(tmp_path):
    import torch
    from stable_baselines3 import PPO

    train = _train_module()
    first = _short_vector_run(train, tmp_path / "a", 5)
    second = _short_vector_run(train, tmp_path / "b", 5)
    assert (tmp_path / "a" / "final_model.zip").is_file() and (tmp_path / "a" / "evaluations.npz").is_file()
    assert first == second
    pa = PPO.load(tmp_path / "a" / "final_model.zip", device="cpu").policy.state_dict()
    pb = PPO.load(tmp_path / "b" / "final_model.zip", device="cpu").policy.state_dict()
    assert pa.keys() == pb.keys() and all(torch.equal(pa[k], pb[k]) for k in pa)
    evals_a, evals_b = np.load(tmp_path / "a" / "evaluations.npz"), np.load(tmp_path / "b" / "evaluations.npz")
    assert np.array_equal(evals_a["results"], evals_b["results"]) and len(evals_a["timesteps"]) == 2
