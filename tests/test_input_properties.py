"""Bad input as a property: generated mutations of valid inputs, each accepted sanely or refused cleanly.

Files and options (``tests/fuzz_cases.py``): hypothesis draws the mutation of a valid piece for every
reader family; the case must end as a clean error (exit 2, one line naming the file or option, nothing
written) or, for a mutation that may be valid, be accepted. Python API: generated constructor arguments,
actions, states and poses for the envs and models must either raise :class:`InputError` or give finite,
in-space results. Small example budgets here; ``benchmarks/fuzz_inputs.py --examples N`` runs thousands
of file/option cases in subprocesses under memory and time limits.
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import sensor_envs.testing.fuzz_api as fa
import sensor_envs.testing.fuzz_cases as fc
from sensor_envs.inputs import InputError
from sensor_envs.testing.fuzz_api_types import TYPE_CLASSES
from sensor_envs.testing.fuzz_pieces import DrawnChooser

FAST = settings(max_examples=6, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


@pytest.mark.parametrize("family", [f for f in fc.FAMILIES if f not in fc.SECOND_ROUND])
@FAST
@given(data=st.data())
def test_every_reader_and_option_refuses_a_mutation_cleanly_or_accepts_it_sanely(family, data) -> None:
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        case = fc.make_case(family, DrawnChooser(data), Path(tmp))
        outcome = fc.classify(case, Path(tmp))
    assert outcome in ("clean error", "accepted"), f"{family}: {case.mutation!r} -> {outcome}"


# ------------------------------------------------------------------------------------------------ Python API
ANY_SCALAR = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**12), 10**12),
    st.booleans(),
    st.none(),
    st.text(max_size=3),
    st.just([1.0]),
)


@pytest.fixture(scope="module")
def radar_models():
    from sensor_envs.modelio import default_model_path
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel

    return [
        GaussianRadar.load(default_model_path("radar_gaussian.npz")),
        KDERadarModel.load(default_model_path("radar_kde.npz")),
    ]


@pytest.fixture(scope="module")
def lidar_model():
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.modelio import default_model_path

    return LidarLWLR.load(default_model_path("neato_lidar.npz"))


def _neato_arg_names():
    from sensor_envs.envs.neato import NEATO_CONSTRAINTS

    return sorted(NEATO_CONSTRAINTS)


@FAST
@given(name=st.sampled_from(_neato_arg_names()), value=ANY_SCALAR)
def test_neato_arguments_are_refused_or_give_finite_in_space_steps(name, value) -> None:
    from sensor_envs.envs.neato import NeatoEnv

    try:
        env = NeatoEnv(**{name: value})
    except InputError as exc:
        assert name in str(exc)
        return
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    obs, reward, *_ = env.step(np.array([0.5, 0.2], dtype=np.float32))
    assert env.observation_space.contains(obs) and np.isfinite(reward)


ACTIONS = st.one_of(
    hnp.arrays(np.float64, st.sampled_from([(2,), (3,), (1, 2), (0,)]), elements=st.floats(allow_nan=True)),
    st.lists(ANY_SCALAR, max_size=3),
    ANY_SCALAR,
)


@FAST
@given(action=ACTIONS)
def test_neato_actions_outside_the_space_are_refused_never_clipped(action) -> None:
    from sensor_envs.envs.neato import NeatoEnv

    env = NeatoEnv()
    env.reset(seed=0)
    try:
        obs, reward, *_ = env.step(action)
    except InputError as exc:
        assert "action" in str(exc)
        return
    a = np.asarray(action, dtype=np.float64).ravel()
    assert a.shape == (2,) and np.all(np.abs(a) <= 1.0)  # only in-space actions pass
    assert env.observation_space.contains(obs) and np.isfinite(reward)


@pytest.fixture(scope="module")
def highway():
    from sensor_envs.envs.highway.wrapper import make_highway

    env = make_highway("highway-fast-v0", radar="gaussian")
    env.reset(seed=0)
    return env


@FAST
@given(action=st.one_of(st.integers(-(10**6), 10**6), st.floats(allow_nan=True), st.booleans(), ACTIONS))
def test_highway_actions_outside_the_space_are_refused(highway, action) -> None:
    try:
        obs, reward, *_ = highway.step(action)
    except InputError as exc:
        assert "action" in str(exc)
        return
    assert highway.action_space.contains(int(np.asarray(action).reshape(())))
    assert highway.observation_space.contains(obs) and np.isfinite(reward)


@FAST
@given(key=st.sampled_from(["policy_frequency", "simulation_frequency", "duration", "lanes_count"]), value=ANY_SCALAR)
def test_highway_config_values_are_checked_at_construction(key, value) -> None:
    from sensor_envs.envs.checks import check_highway_config

    try:
        check_highway_config({key: value})
    except InputError as exc:
        assert key in str(exc)
        return
    assert isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value <= 1e5


STATES = hnp.arrays(
    np.float64,
    st.tuples(st.integers(0, 3), st.sampled_from([1, 2, 3, 4, 5])),
    elements=st.one_of(st.floats(-50, 50), st.just(np.nan), st.just(np.inf), st.just(1e300)),
)


@FAST
@given(state=STATES, seed=st.integers(0, 3))
def test_radar_models_sample_and_score_or_refuse(radar_models, state, seed) -> None:
    for model in radar_models:
        try:
            z, _ = model.sample(state, np.random.default_rng(seed))
        except InputError:
            continue
        assert state.shape[1] in (2, 4) and np.isfinite(state[:, :2]).all()
        assert z.shape == (state.shape[0], 2) and (np.isfinite(z).all(axis=1) | np.isnan(z).all(axis=1)).all()
        lp = model.log_prob(z, state)
        assert not np.isnan(lp).any() and (lp < np.inf).all()


@FAST
@given(rng=ANY_SCALAR)
def test_radar_models_refuse_a_seed_or_none_as_rng(radar_models, rng) -> None:
    for model in radar_models:
        with pytest.raises(InputError, match="rng"):
            model.sample(np.array([[10.0, 1.0]]), rng)


@FAST
@given(log=st.one_of(ANY_SCALAR, st.dictionaries(st.text(max_size=3), st.integers(), max_size=2)))
def test_fit_on_anything_but_a_log_is_an_input_error(radar_models, lidar_model, log) -> None:
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel

    for model in (GaussianRadar(), KDERadarModel(), LidarLWLR()):
        with pytest.raises(InputError, match="log"):
            model.fit(log)


POSES = hnp.arrays(
    np.float64,
    st.tuples(st.integers(1, 2), st.sampled_from([2, 3, 4])),
    elements=st.one_of(st.floats(0.2, 3.5), st.just(np.nan), st.just(-np.inf), st.just(1e300)),
)


@FAST
@given(poses=POSES, seed=st.integers(0, 3))
def test_lidar_model_samples_and_scores_or_refuses(lidar_model, poses, seed) -> None:
    segs = fc.SEGS
    try:
        r = lidar_model.sample(poses, segs, np.random.default_rng(seed))
    except InputError:
        assert poses.shape[1] != 3 or not (np.abs(poses) < 1e6).all()
        return
    assert r.shape == (poses.shape[0], lidar_model.bearings_.size) and np.isfinite(r).all() and (r >= 0).all()
    lp = lidar_model.log_prob(r, poses, segs)
    assert not np.isnan(lp).any()


# ------------------------------------------------------------------------------ Python API, every class
@pytest.mark.parametrize("cls", [c for c in fa.API_CLASSES if c not in TYPE_CLASSES])
@FAST
@given(data=st.data())
def test_every_api_class_refuses_a_bad_argument_cleanly_or_gives_sane_results(cls, data) -> None:
    """Generated calls of every env id and model class (``testing/fuzz_api.py``): InputError, or a sane result."""
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        case = fa.make_api_case(cls, DrawnChooser(data), Path(tmp))
        outcome = fc.classify(case, Path(tmp))
    assert outcome in ("clean error", "accepted"), f"{cls}: {case.mutation!r} -> {outcome}"


def test_the_api_fuzz_covers_every_registered_env_id() -> None:
    import gymnasium as gym

    import sensor_envs  # noqa: F401

    assert set(fa.ENV_IDS) == {k for k in gym.registry if k.startswith("sensor_envs/")}


def test_every_env_argument_has_a_declared_check() -> None:
    """A new constructor argument must join a declared table (or be named here with the check it gets)."""
    from sensor_envs.envs.highway.sensor import SENSOR_CONSTRAINTS
    from sensor_envs.envs.highway.wrapper import MAKE_HIGHWAY_CONSTRAINTS, WRAPPER_CONSTRAINTS
    from sensor_envs.envs.neato import NEATO_CONSTRAINTS

    highway = set(WRAPPER_CONSTRAINTS) | set(SENSOR_CONSTRAINTS) | set(MAKE_HIGHWAY_CONSTRAINTS)
    own = {"config", "tracker"}  # check_highway_config (every highway-env key); tracker_config (TrackerConfig)
    assert set(fa._signature("sensor_envs/Highway-v0")) <= highway | own
    neato_own = {"map", "lidar", "model", "lidar_kwargs", "null_value", "render_mode"}  # name/file checks
    assert set(fa._signature("sensor_envs/Neato-v0")) <= set(NEATO_CONSTRAINTS) | neato_own


@pytest.mark.parametrize("base_id", ["highway-v0", "highway-fast-v0", "merge-v0", "intersection-v0"])
def test_every_highway_config_key_has_a_declared_form(base_id) -> None:
    """Each key of highway-env's default config is accepted at its default and refuses NaN/strings/None."""
    import gymnasium as gym
    import highway_env  # noqa: F401

    from sensor_envs.envs.checks import check_highway_config

    defaults = gym.envs.registration.load_env_creator(gym.spec(base_id).entry_point).default_config()
    check_highway_config(dict(defaults), defaults)
    for key, value in defaults.items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            for bad in (float("nan"), "1", None, 1e300):
                with pytest.raises(InputError, match=f"config.{key}"):
                    check_highway_config({key: bad}, defaults)
