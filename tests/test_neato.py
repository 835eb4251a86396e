import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.envs.neato import NeatoEnv
from sensor_envs.lidar.gaussian import GaussianLidar

LIDARS = ["ideal", "gaussian", "learned"]


@pytest.mark.parametrize("lidar", LIDARS)
@pytest.mark.parametrize("map_name", ["seed_room", "cluttered"])
def test_checkers_pass_without_warnings(lidar, map_name):
    env = gym.make("sensor_envs/Neato-v0", lidar=lidar, map=map_name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=True)


def _rollout(env, seed, n=40):
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    seq, poses = [obs], []
    for _ in range(n):
        obs, _, term, trunc, info = env.step(env.action_space.sample())
        seq.append(obs)
        poses.append(info["pose"])
        if term or trunc:
            obs, _ = env.reset()
            seq.append(obs)
    return np.array(seq), np.array(poses)


@pytest.mark.parametrize("lidar", LIDARS)
def test_same_seed_same_observations(lidar):
    a, _ = _rollout(gym.make("sensor_envs/Neato-v0", lidar=lidar), seed=7)
    b, _ = _rollout(gym.make("sensor_envs/Neato-v0", lidar=lidar), seed=7)
    c, _ = _rollout(gym.make("sensor_envs/Neato-v0", lidar=lidar), seed=8)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_sensor_noise_does_not_change_the_world():
    _, ideal = _rollout(gym.make("sensor_envs/Neato-v0", lidar="ideal"), seed=3)
    _, noisy = _rollout(gym.make("sensor_envs/Neato-v0", lidar="gaussian"), seed=3)
    assert np.array_equal(ideal, noisy)


def test_ideal_scan_is_exact_in_the_seed_room():
    env = NeatoEnv(map="seed_room")
    obs, info = env.reset(seed=0, options={"start": [0.5, 0.5, 0.0], "goal": [3.0, 1.5, 0.0]})
    assert obs[0] == pytest.approx(3.16, abs=1e-5)  # straight ahead to the east wall
    assert obs[90] == pytest.approx(1.33, abs=1e-5)  # left, to the north wall
    assert obs[180] == pytest.approx(0.5, abs=1e-5)
    assert obs[360:362] == pytest.approx([2.5, 1.0], abs=1e-5)


def test_null_value_modes_and_range_cut():
    segs = np.array(
        [
            [[10.0, -5.0], [10.0, 5.0]],
            [[-1.0, -5.0], [-1.0, 5.0]],
            [[-1.0, 5.0], [10.0, 5.0]],
            [[-1.0, -5.0], [10.0, -5.0]],
        ]
    )
    for mode, fill in (("zero", 0.0), ("max", 5.0)):
        env = NeatoEnv(map=segs, null_value=mode)
        obs, info = env.reset(seed=0, options={"start": [0.0, 0.0, 0.0], "goal": [2.0, 0.0, 0.0]})
        assert obs[0] == fill and np.isinf(info["ideal_scan"][0]) and info["scan"][0] == 0.0
        assert obs[180] == pytest.approx(1.0)
    env = NeatoEnv(map=segs, null_value="nan")
    obs, _ = env.reset(seed=0, options={"start": [0.0, 0.0, 0.0], "goal": [2.0, 0.0, 0.0]})
    assert np.isnan(obs[0])


def test_goal_reached_and_collision_terminate():
    env = NeatoEnv(map="seed_room")
    env.reset(seed=0, options={"start": [1.0, 0.5, 0.0], "goal": [1.05, 0.5, 0.0]})
    _, r, term, _, info = env.step(np.array([0.0, 0.0], dtype=np.float32))
    assert term and info["is_success"] and r > 5
    env.reset(seed=0, options={"start": [3.4, 0.5, 0.0], "goal": [1.0, 1.0, 0.0]})
    for _ in range(10):
        _, r, term, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        if term:
            break
    assert term and info["collision"] and r < -5


def test_progress_reward_sign():
    env = NeatoEnv(map="seed_room")
    env.reset(seed=0, options={"start": [1.0, 0.5, 0.0], "goal": [3.0, 0.5, 0.0]})
    assert env.step(np.array([1.0, 0.0], dtype=np.float32))[1] > 0
    assert env.step(np.array([-1.0, 0.0], dtype=np.float32))[1] < 0


def test_render_draws_the_scene():
    env = NeatoEnv(map="seed_room", render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert (img == 20).all(axis=2).sum() > 500  # walls
    assert ((img[..., 0] == 220) & (img[..., 1] == 30)).sum() > 100  # lidar hits


def test_env_pickles_and_config_errors():
    env = NeatoEnv(lidar="gaussian")
    env.reset(seed=1)
    clone = pickle.loads(pickle.dumps(env))
    a = np.array([0.5, 0.1], dtype=np.float32)
    assert np.array_equal(env.step(a)[0], clone.step(a)[0])
    with pytest.raises(ValueError, match="unknown lidar 'perfect'"):
        NeatoEnv(lidar="perfect")
    with pytest.raises(ValueError, match="null_value"):
        NeatoEnv(null_value="none")
    with pytest.raises(TypeError):
        NeatoEnv(lidars="ideal")
    with pytest.raises(ValueError, match="options"):
        NeatoEnv().reset(seed=0, options={"star": [0, 0, 0]})


def test_gaussian_lidar_noise_grows_with_range_and_incidence():
    lid = GaussianLidar()
    s = lid.sigma(np.array([1.0, 4.0, 4.0]), np.array([0.0, 0.0, 1.0]))
    assert s[0] < s[1] < s[2]
    rng = np.random.default_rng(0)
    x = np.array([lid.measure(np.array([3.0]), np.array([0.3]), rng)[0] for _ in range(4000)])
    assert x.mean() == pytest.approx(3.0, abs=4 * s[1] / np.sqrt(4000) + 1e-3)
    assert x.std() == pytest.approx(lid.sigma(np.array([3.0]), np.array([0.3]))[0], rel=0.08)


def test_ros_map_world(real_data):
    env = NeatoEnv(map=real_data / "neato_ros1_bags" / "mymap.yaml")
    obs, _ = env.reset(seed=0)
    assert obs in env.observation_space


def test_compiled_observation_gives_the_numpy_numbers(monkeypatch, compiled_kernels):
    """The fused observation pass (numba) and the numpy calls it replaces: same obs, scan and incidence bits,
    for every null fill, with NaN, +-inf, negative and beyond-range readings and values beyond the bounds."""
    from sensor_envs.envs import neato

    rng = np.random.default_rng(5)
    raw = rng.uniform(-1.0, 8.0, size=(4, 20))
    raw[rng.random(raw.shape) < 0.2] = np.nan
    raw[0, :3] = [np.inf, -np.inf, 0.0]
    inc = np.where(np.isnan(raw), np.nan, rng.uniform(0, 1.6, raw.shape))
    inc[1, 0] = np.inf
    goal_rel, dth = rng.uniform(-30, 30, size=(4, 2)), rng.uniform(-4, 4, size=4)
    low = np.concatenate([np.zeros(20), [-20.0, -20.0, -np.pi]]).astype(np.float32)
    high = np.concatenate([np.full(20, 6.0), [20.0, 20.0, np.pi]]).astype(np.float32)
    for null_value in ("zero", "nan", "max"):
        fast = neato.finish_observation(raw, inc, goal_rel, dth, low, high, 6.0, null_value)
        with monkeypatch.context() as m:
            m.setattr(neato, "compiled", lambda loops: None)
            ref = neato.finish_observation(raw, inc, goal_rel, dth, low, high, 6.0, null_value)
        for x, y in zip(fast, ref, strict=True):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y, equal_nan=True)
        assert (fast[0][:, 20:] != np.float32(np.c_[goal_rel, dth])).any()  # some goals were clipped


@pytest.mark.parametrize("lidar", [GaussianLidar(), GaussianLidar(p_null_floor=0.1, k_range=1e300)])
def test_compiled_gaussian_lidar_gives_the_numpy_numbers(monkeypatch, compiled_kernels, lidar):
    """The Gaussian lidar's compiled pass and its numpy path: same readings from the same draws, bit for bit
    (misses, NaN/+-inf incidence, incidences beyond alpha_max, a spread that overflows, dropout)."""
    from sensor_envs.lidar import gaussian
    from sensor_envs.rng import RowGenerators

    rng = np.random.default_rng(0)
    r, a = rng.uniform(0.2, 5, (6, 50)), rng.uniform(-0.3, 1.7, (6, 50))
    r[:, :5], a[:, :5] = np.inf, np.nan
    a[0, 10], a[1, 11], a[2, 12] = np.inf, -np.inf, np.nan
    out = []
    for kernel in (True, False):
        with monkeypatch.context() as m:
            if not kernel:
                m.setattr(gaussian, "compiled", lambda loops: None)
            rows = lidar.measure(r, a, RowGenerators([np.random.default_rng(i) for i in range(6)]))
            one = lidar.measure(r[0], a[0], np.random.default_rng(1))
            out.append((rows, one))
    for x, y in zip(out[0], out[1], strict=True):
        assert x.shape == y.shape and np.array_equal(x, y, equal_nan=True)
    assert 0 < np.isnan(out[0][0]).mean() < 0.5
