import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode

import sensor_envs  # noqa: F401
from sensor_envs.envs.neato_vector import NeatoVectorEnv
from sensor_envs.rng import RowGenerators

ID = "sensor_envs/Neato-v0"


def _pair(lidar, n, **kwargs):
    vec = gym.make_vec(ID, num_envs=n, vectorization_mode="vector_entry_point", lidar=lidar, **kwargs)
    sync = gym.make_vec(ID, num_envs=n, vectorization_mode="sync", lidar=lidar, **kwargs)
    return vec, sync


@pytest.mark.parametrize("lidar", ["ideal", "gaussian", "learned"])
def test_vector_entry_point_matches_sync_vector_env(lidar):
    vec, sync = _pair(lidar, 4, max_episode_steps=25)
    assert isinstance(vec.unwrapped, NeatoVectorEnv)
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vec.observation_space == sync.observation_space and vec.action_space == sync.action_space
    o1, i1 = vec.reset(seed=11)
    o2, i2 = sync.reset(seed=11)
    assert data_equivalence(o1, o2, exact=True) and data_equivalence(i1, i2, exact=True)
    rng = np.random.default_rng(0)
    ended = np.zeros(2, dtype=int)  # terminated, truncated
    for _ in range(60):
        a = rng.uniform(-1, 1, size=(4, 2)).astype(np.float32)
        out_v, out_s = vec.step(a), sync.step(a)
        for x, y in zip(out_v, out_s, strict=True):
            assert data_equivalence(x, y, exact=True)
        assert out_v[0] in vec.observation_space
        ended += [out_v[2].sum(), out_v[3].sum()]
    assert ended[0] > 0 and ended[1] > 0  # both kinds of episode end (and their autoresets) were exercised
    # reset without a seed continues every robot's streams, as in the single envs
    for x, y in zip(vec.reset(), sync.reset(), strict=True):
        assert data_equivalence(x, y, exact=True)


def test_vector_reset_seeds_options_and_mask():
    vec, sync = _pair("gaussian", 3)
    opts = {"start": (1.0, 1.0, 0.0)}
    for x, y in zip(vec.reset(seed=[3, 5, 7], options=opts), sync.reset(seed=[3, 5, 7], options=opts), strict=True):
        assert data_equivalence(x, y, exact=True)
    mask = np.array([False, True, False])
    obs0 = vec.reset(seed=1)[0]
    obs, info = vec.reset(seed=[None, 99, None], options={"reset_mask": mask})
    assert np.array_equal(obs[~mask], obs0[~mask]) and not np.array_equal(obs[mask], obs0[mask])
    assert info["_pose"].tolist() == mask.tolist()
    with pytest.raises(ValueError, match="unknown keys"):
        vec.reset(options={"bogus": 1})


def test_vector_step_before_reset_and_bad_sizes():
    env = NeatoVectorEnv(num_envs=2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros((2, 2), dtype=np.float32))
    with pytest.raises(ValueError, match="num_envs"):
        NeatoVectorEnv(num_envs=0)


def test_what_a_call_returned_stays_as_returned():
    """Later steps and (partial) resets write new arrays: an observation or info a caller keeps does not change."""
    import copy

    env = NeatoVectorEnv(num_envs=3, lidar="gaussian", max_episode_steps=2)
    first = env.reset(seed=0)
    kept = [(first, copy.deepcopy(first))]
    for _ in range(3):  # the second step truncates every robot; the third restarts them
        out = env.step(np.full((3, 2), 0.3, dtype=np.float32))
        kept.append((out, copy.deepcopy(out)))
        part = env.reset(options={"reset_mask": np.array([True, False, True])})
        kept.append((part, copy.deepcopy(part)))
    for returned, snapshot in kept:
        assert data_equivalence(returned, snapshot, exact=True)


def test_vector_render_gives_one_frame_per_robot():
    env = NeatoVectorEnv(num_envs=2, render_mode="rgb_array")
    env.reset(seed=0)
    frames = env.render()
    assert len(frames) == 2 and frames[0].ndim == 3 and frames[0].dtype == np.uint8


def test_row_generators_match_separate_generators():
    gens = [np.random.default_rng(s) for s in (1, 2)]
    rows = RowGenerators([np.random.default_rng(s) for s in (1, 2)])
    z = rows.standard_normal((2, 5))
    u = rows.random((2, 3))
    assert np.array_equal(z, np.stack([g.standard_normal(5) for g in gens]))
    assert np.array_equal(u, np.stack([g.random(3) for g in gens]))
    with pytest.raises(ValueError, match="rows"):
        rows.random((3, 5))
    with pytest.raises(AttributeError, match="not supported"):
        rows.beta(1.0, 1.0, (2, 5))


def test_row_generators_select_and_replace_keep_each_rows_stream():
    """A kept ``RowGenerators`` (compiled draws with numba, else numpy): a selection of rows and a replaced row
    draw what the generators alone would draw, and the generators themselves advance."""
    gens = [np.random.default_rng(s) for s in range(5)]
    ref = [np.random.default_rng(s) for s in range(5)]
    rows = RowGenerators(gens)
    assert np.array_equal(rows.uniform(-1.0, 2.0, (5, 2, 3)), np.stack([g.uniform(-1.0, 2.0, (2, 3)) for g in ref]))
    part = rows.select([4, 1])
    assert np.array_equal(part.standard_normal((2, 7)), np.stack([ref[i].standard_normal(7) for i in (4, 1)]))
    assert np.array_equal(part.select([1]).random((1, 2)), ref[1].random((1, 2)))  # a selection of a selection
    rows.replace(2, np.random.default_rng(99))
    ref[2] = np.random.default_rng(99)
    assert np.array_equal(rows.random((5, 4)), np.stack([g.random(4) for g in ref]))
    assert all(g.random() == r.random() for g, r in zip(rows.generators, ref, strict=True))  # same states after


def test_vector_env_pickles_and_copies_with_its_streams():
    """A stepped vector env survives pickle and deepcopy (the compiled draws' list is rebuilt) and the copy
    continues with the same observations as the original."""
    import copy
    import pickle

    env = gym.make_vec("sensor_envs/Neato-v0", num_envs=3, vectorization_mode="vector_entry_point", lidar="learned")
    env.reset(seed=1)
    a = np.full((3, 2), 0.3, dtype=np.float32)
    env.step(a)
    copies = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    ref = [env.step(a)[0] for _ in range(3)]
    for c in copies:
        assert all(np.array_equal(c.step(a)[0], r) for r in ref)


def test_heap_tuning_is_opt_in(monkeypatch):
    """Building the vector env leaves the process's malloc settings alone unless tune_heap=True."""
    from sensor_envs import heap

    calls: list[int] = []
    monkeypatch.setattr(heap, "keep_freed_heap", lambda: calls.append(1) or True)
    NeatoVectorEnv(num_envs=2, lidar="ideal")
    gym.make_vec("sensor_envs/Neato-v0", num_envs=2, vectorization_mode="vector_entry_point", lidar="ideal")
    assert calls == []
    NeatoVectorEnv(num_envs=2, lidar="ideal", tune_heap=True)
    assert calls == [1]
    with pytest.raises(ValueError, match="tune_heap"):
        NeatoVectorEnv(num_envs=2, lidar="ideal", tune_heap="yes")


def test_building_a_vector_env_does_not_call_mallopt():
    """In a fresh process: no mallopt call (heap's once-per-process flag never set) after build, reset, step."""
    import subprocess
    import sys

    code = """
import gymnasium as gym, numpy as np, sensor_envs
from sensor_envs import heap
env = gym.make_vec("sensor_envs/Neato-v0", num_envs=4, vectorization_mode="vector_entry_point", lidar="ideal")
env.reset(seed=0)
env.step(np.zeros((4, 2), dtype=np.float32))
print(heap._applied)
"""
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    assert out.stdout.split()[-1] == "None"
