"""The highway wrapper's per-vehicle track flags (new vs lost) and its radar rate option."""

import warnings

import gymnasium as gym
import highway_env  # noqa: F401  (registers highway-env's ids)
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from test_highway import CountingRadar  # the test double, written once (tests/ is on the path)

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.envs.highway import RadarObservation
from sensor_envs.modelio import default_model_path

FAST = "sensor_envs/HighwayFast-v0"
FAST_MODEL = default_model_path("radar_kde_fast.npz")
needs_fast_model = pytest.mark.skipif(not FAST_MODEL.is_file(), reason="no shipped radar_kde_fast.npz")
SIM15 = {"vehicles_count": 10, "simulation_frequency": 15}


class FlagRadar:
    """Test double: records each call's previous outputs and new-track flags; misses half the targets."""

    CAPABILITIES = frozenset({"new_track"})  # declared: the wrapper passes the flags

    def __init__(self, miss=0.5, cycle_time=None):
        self.miss, self.cycle_time_, self.calls = miss, cycle_time, []

    def sample_cycle(self, corners, prev_z, rng, new_track=None):
        n = len(corners)
        self.calls.append((np.isnan(prev_z[:, 0]), new_track))
        z = np.zeros((n, 2))
        z[rng.random(n) < self.miss] = np.nan
        return z, np.full(n, -1)

    def sample_clutter(self, rng):
        return np.zeros((0, 2))


def _base(config=None):
    return gym.make("highway-fast-v0", config=config or {"vehicles_count": 10}, disable_env_checker=True)


def test_first_seen_vehicles_are_new_and_missed_ones_lost():
    radar = FlagRadar()
    env = RadarObservation(_base(), radar)
    env.reset(seed=3)
    seen = set()
    lost = 0
    for step in range(12):
        frame = env.last_frame
        objs, vis = frame.truth.objects, np.flatnonzero(frame.visible)
        if vis.size:
            no_prev, flags = radar.calls[-1]
            expected = np.array([objs[i] not in seen for i in vis])
            np.testing.assert_array_equal(flags, expected)
            assert not (flags & ~no_prev).any()  # a new track never has a previous output
            lost += int((no_prev & ~flags).sum())
            if step == 0:
                assert flags.all()  # at reset every visible vehicle is new
        seen = {o for o in objs if o in seen} | {objs[i] for i in vis}
        *_, term, trunc, _ = env.step(1)
        if term or trunc:
            break
    assert lost > 0  # the 50 % misses produced lost tracks, flagged as such


def test_radars_without_the_flag_keep_working():
    env = RadarObservation(_base(), CountingRadar())
    env.reset(seed=0)
    env.step(1)


@pytest.mark.parametrize(("rate", "cycles"), [("policy", 1), ("simulation", 5)])
def test_simulation_rate_samples_every_sub_step_and_keeps_the_latest(rate, cycles):
    env = RadarObservation(_base(), CountingRadar(), radar_rate=rate)
    _, info = env.reset(seed=1)
    for k in range(1, 3):
        _, _, term, trunc, info = env.step(1)
        assert not (term or trunc)
        r = info["radar"]
        tgt = r.detection_target >= 0
        z = r.detections[tgt] - r.truth_reference[r.detection_target[tgt]]
        # a track followed since reset has counted one cycle per sub-step (highway-fast: 5 per step)
        assert z[:, 0].max() == pytest.approx(k * cycles)


def test_simulation_rate_counts_road_steps():
    radar = FlagRadar(miss=0.0)
    env = RadarObservation(_base(SIM15), radar, radar_rate="simulation")
    env.reset(seed=2)
    n0 = len(radar.calls)
    env.step(1)
    assert len(radar.calls) - n0 == 15  # simulation_frequency / policy_frequency


@pytest.mark.parametrize(
    ("rate", "cycle", "config"),
    [("simulation", 1.0, None), ("policy", 1 / 15, None), ("simulation", 1 / 15, None), ("policy", 0.5, None)],
)
def test_cycle_time_mismatch_is_refused(rate, cycle, config):
    with pytest.raises(ValueError, match=r"radar_rate: the radar model is fitted at a cycle time of"):
        RadarObservation(_base(config), FlagRadar(cycle_time=cycle), radar_rate=rate)


def test_cycle_time_match_is_accepted_and_checked_again_at_reset():
    env = RadarObservation(_base(SIM15), FlagRadar(cycle_time=1 / 15), radar_rate="simulation")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="cycle time"):
        env.reset(options={"config": {"simulation_frequency": 10}})


def test_shipped_default_refuses_the_simulation_rate():
    with pytest.raises(ValueError, match="radar_kde_fast.npz"):
        gym.make(FAST, radar="kde", radar_rate="simulation", config={"vehicles_count": 10})


def test_bad_radar_rate_names_the_argument():
    with pytest.raises(ValueError, match="radar_rate: expected one of"):
        gym.make(FAST, radar="ideal", radar_rate="radar")


@needs_fast_model
def test_fast_model_refuses_the_policy_rate():
    with pytest.raises(ValueError, match="cycle time"):
        gym.make(FAST, radar="kde", radar_model=str(FAST_MODEL), config=SIM15)


def _fast_env():
    return gym.make(FAST, radar="kde", radar_model=str(FAST_MODEL), radar_rate="simulation", config=SIM15)


@needs_fast_model
def test_checkers_pass_with_the_simulation_rate():
    env = _fast_env()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version.*")
        warnings.filterwarnings("ignore", category=DeprecationWarning, message=".*out of date.*")
        warnings.filterwarnings("ignore", message=".*unconventional shape.*")
        check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=True)


@needs_fast_model
def test_same_seed_same_observations_with_the_simulation_rate():
    def run(seed):
        env = _fast_env()
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for _ in range(3):
            out.append(env.step(1)[0])
        return out

    a, b, c = run(4), run(4), run(5)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c, strict=True))
