"""Tests of the radar wrapper for highway-env (sensor_envs.envs.highway)."""

import pickle
import re
import warnings
from dataclasses import dataclass

import gymnasium as gym
import highway_env  # noqa: F401  (registers highway-env's ids)
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.envs.highway import IDEAL_KINEMATICS, RadarObservation, load_radar, make_highway
from sensor_envs.geometry import occluded_fraction, rectangle_corners, to_frame
from sensor_envs.modelio import default_model_path
from sensor_envs.radar.sensors import DEFAULT_MODEL_FILES

FAST = "sensor_envs/HighwayFast-v0"
# Small scenes keep the slower worlds (merge 15 Hz, intersection) cheap.
SMALL = {
    "highway-v0": {"vehicles_count": 10},
    "highway-fast-v0": {"vehicles_count": 10},
    "merge-v0": {},
    "intersection-v0": {"initial_vehicle_count": 4},
    "roundabout-v0": {},
}


def _model_available(radar: str) -> bool:
    return radar == "ideal" or default_model_path(DEFAULT_MODEL_FILES[radar]).is_file()


RADARS = [
    pytest.param(r, marks=pytest.mark.skipif(not _model_available(r), reason=f"no shipped {r} model yet"))
    for r in ("ideal", "gaussian", "kde")
]


@dataclass(frozen=True)
class JitterRadar:
    """Test double: AR(1) jitter, 20 % misses, Poisson clutter in a +-1 rad sector out to 80 m."""

    miss: float = 0.2
    rho: float = 0.5
    sigma: float = 0.4

    def sample_cycle(self, corners, prev_z, rng):
        n = len(corners)
        z = self.rho * np.nan_to_num(prev_z) + rng.normal(0.0, self.sigma, (n, 2))
        z[rng.random(n) < self.miss] = np.nan
        return z, rng.integers(0, 1000, n)

    def sample_clutter(self, rng):
        m = rng.poisson(2.0)
        r, a = rng.uniform(1.0, 80.0, m), rng.uniform(-1.0, 1.0, m)
        return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


@dataclass(frozen=True)
class CountingRadar:
    """Test double: z = previous z + (1, 0) (a new track starts at 0), never misses, no clutter."""

    def sample_cycle(self, corners, prev_z, rng):
        z = np.where(np.isnan(prev_z), 0.0, prev_z + np.array([1.0, 0.0]))
        return z, np.arange(len(corners))

    def sample_clutter(self, rng):
        return np.zeros((0, 2))


def _fast(radar="ideal", **kw):
    base = gym.make("highway-fast-v0", config={"vehicles_count": 10}, disable_env_checker=True)
    return RadarObservation(base, radar, **kw)


def _rollout(env, seed, n=8):
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    out = [(obs, info)]
    for _ in range(n):
        obs, _, term, trunc, info = env.step(env.action_space.sample())
        out.append((obs, info))
        if term or trunc:
            out.append(env.reset())
    return out


def _same(a, b):
    return all(np.array_equal(oa, ob) and ia["radar"] == ib["radar"] for (oa, ia), (ob, ib) in zip(a, b, strict=True))


# ------------------------------------------------------------------------------------ checkers


def _check(env):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version.*")
        warnings.filterwarnings("ignore", category=DeprecationWarning, message=".*out of date.*")
        # Kinematics is a (vehicles, features) table by design; SB3's MlpPolicy flattens it
        warnings.filterwarnings("ignore", message=".*unconventional shape.*")
        check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=True)


@pytest.mark.parametrize("radar", RADARS)
def test_checkers_pass_for_each_radar(radar):
    env = gym.make(FAST, radar=radar, config={"vehicles_count": 10})
    _check(env)


HIGHWAY_IDS = sorted(
    k for k, s in gym.registry.items() if s.entry_point == "sensor_envs.envs.highway.wrapper:make_highway"
)


def test_every_highway_id_is_checked():
    assert FAST in HIGHWAY_IDS and len(HIGHWAY_IDS) >= 4
    assert {gym.spec(i).kwargs["base_id"] for i in HIGHWAY_IDS} <= set(SMALL)


@pytest.mark.parametrize("radar", RADARS)
@pytest.mark.parametrize("env_id", [i for i in HIGHWAY_IDS if i != FAST])
def test_checkers_pass_for_other_worlds(env_id, radar):
    base = gym.spec(env_id).kwargs["base_id"]
    env = gym.make(env_id, radar=radar, config=SMALL[base])
    _check(env)


# --------------------------------------------------------------------------------- determinism


@pytest.mark.parametrize("radar", [*RADARS, JitterRadar()])
def test_same_seed_same_rollout(radar):
    a = _rollout(_fast(radar), seed=5)
    b = _rollout(_fast(radar), seed=5)
    c = _rollout(_fast(radar), seed=6)
    assert _same(a, b)
    assert not _same(a, c)


def test_reset_without_seed_continues_the_radar_stream():
    env = _fast(JitterRadar())
    env.reset(seed=1)
    first = env.reset()[1]["radar"].detections
    env.reset(seed=1)
    again = env.reset()[1]["radar"].detections
    assert np.array_equal(first, again)


def test_radar_noise_does_not_change_the_traffic():
    ideal = _rollout(_fast("ideal"), seed=3, n=6)
    noisy = _rollout(_fast(JitterRadar()), seed=3, n=6)
    for (_, a), (_, b) in zip(ideal, noisy, strict=True):
        assert np.array_equal(a["radar"].truth_position, b["radar"].truth_position)


# ------------------------------------------------------------------------- exact Kinematics


@pytest.mark.parametrize("base_id", list(SMALL))
def test_ideal_radar_reproduces_kinematics_to_the_bit(base_id):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        ref = gym.make(base_id, config=SMALL[base_id])
        env = make_highway(base_id, config=SMALL[base_id], **IDEAL_KINEMATICS)
    for seed in (0, 1):
        o_ref, _ = ref.reset(seed=seed)
        o, _ = env.reset(seed=seed)
        assert o.dtype == np.float32 and np.array_equal(o, o_ref)
        ref.action_space.seed(seed)
        for _ in range(6):
            action = ref.action_space.sample()
            o_ref, r_ref, t_ref, tr_ref, _ = ref.step(action)
            o, r, t, tr, _ = env.step(action)
            assert np.array_equal(o, o_ref) and r == r_ref and (t, tr) == (t_ref, tr_ref)
            if t or tr:
                break


def test_ideal_radar_reproduces_kinematics_with_options():
    obs_cfg = {
        "type": "Kinematics",
        "vehicles_count": 7,
        "features": ["presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h"],
        "absolute": True,
        "see_behind": True,
        "normalize": False,
    }
    cfg = {"vehicles_count": 10, "observation": obs_cfg}
    ref = gym.make("highway-fast-v0", config=cfg)
    env = make_highway("highway-fast-v0", config=cfg, **IDEAL_KINEMATICS)
    assert np.array_equal(ref.reset(seed=2)[0], env.reset(seed=2)[0])
    for _ in range(4):
        assert np.array_equal(ref.step(3)[0], env.step(3)[0])


# ------------------------------------------------------------------- field of view, occlusion


def _in_fov(points, fov, max_range):
    r = np.hypot(points[:, 0], points[:, 1])
    return (np.abs(np.arctan2(points[:, 1], points[:, 0])) <= fov / 2 + 1e-12) & (r <= max_range + 1e-9)


def _ray_box(origin, ang, corners):
    """Distance along a ray to a box (inf if missed): slow, loop-based reference."""
    d = np.array([np.cos(ang), np.sin(ang)])
    best = np.inf
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        e = b - a
        den = d[0] * e[1] - d[1] * e[0]
        if abs(den) < 1e-12:
            continue
        w = a - origin
        t = (w[0] * e[1] - w[1] * e[0]) / den
        u = (w[0] * d[1] - w[1] * d[0]) / den
        if t > 1e-9 and 0 <= u <= 1:
            best = min(best, t)
    return best


def _reference_occlusion(boxes, i, n_rays=64):
    """Fraction of box i's angular extent (seen from the origin) hidden by another box."""
    c = boxes[i]
    centre = np.arctan2(c[:, 1].mean(), c[:, 0].mean())
    rel = [(np.arctan2(p[1], p[0]) - centre + np.pi) % (2 * np.pi) - np.pi for p in c]
    hidden = 0
    for f in (np.arange(n_rays) + 0.5) / n_rays:
        ang = centre + min(rel) + f * (max(rel) - min(rel))
        own = _ray_box(np.zeros(2), ang, c)
        other = min(_ray_box(np.zeros(2), ang, b) for j, b in enumerate(boxes) if j != i)
        hidden += other < own
    return hidden / n_rays


def _check_frame(env, info, fov, max_range):
    """Check one step against slow references; return (clutter, detections, occluded targets) counts."""
    r = info["radar"]
    assert _in_fov(r.detections, fov, max_range).all()  # targets and clutter alike
    base = env.unwrapped
    by_position = {tuple(o.position): o for o in base.road.vehicles if o is not base.vehicle}
    tobj = [by_position[tuple(p)] for p in r.truth_position]
    boxes = to_frame(
        rectangle_corners(
            r.truth_position[:, 0],
            r.truth_position[:, 1],
            [o.heading for o in tobj],
            [o.LENGTH for o in tobj],
            [o.WIDTH for o in tobj],
        ),
        r.sensor_pose,
    )
    ref_in = _in_fov(r.truth_reference, fov, max_range)
    assert not r.detected[~ref_in].any()
    n_det = n_hidden = 0
    for i in np.flatnonzero(ref_in):
        frac = _reference_occlusion(boxes, i)
        if r.detected[i]:
            n_det += 1
            assert frac < 0.5 + 1 / 16 + 1e-9  # the wrapper uses 16 rays, the reference 64
        if frac > 0.5 + 1 / 16:
            assert not r.visible[i]
            n_hidden += 1
    return int((r.detection_target < 0).sum()), n_det, n_hidden


@pytest.mark.parametrize("radar", [JitterRadar(), *RADARS])
def test_detections_only_inside_fov_and_never_behind_an_occluder(radar):
    fov, max_range = np.deg2rad(70.0), 60.0
    env = _fast(radar, fov=fov, max_range=max_range)
    _, info = env.reset(seed=11)
    totals = np.array(_check_frame(env, info, fov, max_range))
    for _ in range(10):
        _, _, term, trunc, info = env.step(1)
        totals += _check_frame(env, info, fov, max_range)
        if term or trunc:
            break
    assert (totals[1:] > 0).all(), totals  # detections and occluded targets were exercised
    if isinstance(radar, JitterRadar):
        assert totals[0] > 0  # and clutter (the test double always makes some)


def test_occlusion_prefilter_changes_nothing():
    env = _fast("ideal")
    env.reset(seed=21)
    checked = 0
    for _ in range(8):
        env.step(1)
        f = env.last_frame
        corners_s = to_frame(f.truth.corners, f.sensor_pose)
        full = occluded_fraction(corners_s, (0.0, 0.0), 16) >= 0.5
        assert np.array_equal(f.visible, env.spec_sensor.in_view(f.reference_s) & ~full)
        checked += int(full.sum())
    assert checked > 0


def _place(env, positions):
    """Put the ego at x=100 in lane y=4 and the other vehicles at ``positions`` (x, y), heading 0."""
    base = env.unwrapped
    base.vehicle.position = np.array([100.0, 4.0])
    base.vehicle.heading = 0.0
    others = [v for v in base.road.vehicles if v is not base.vehicle]
    for v, p in zip(others, positions, strict=False):
        v.position, v.heading = np.array(p, dtype=float), 0.0
    for v in others[len(positions) :]:
        v.position = np.array([-1000.0, 0.0])
    return base


def test_a_car_hidden_behind_a_car_in_the_same_lane_is_not_detected():
    env = _fast("ideal")
    env.reset(seed=0)
    _place(env, [(120.0, 4.0), (140.0, 4.0)])
    frame = env.sense()
    assert list(frame.visible) == [True, False]
    _place(env, [(120.0, 4.0), (140.0, 8.0)])  # next lane: visible again
    frame = env.sense()
    assert list(frame.visible) == [True, True] and list(frame.det_target) == [0, 1]
    # the ideal radar reports the closest corner: rear right corner of the left-lane car
    front = 100.0 + 2.5
    assert np.allclose(frame.det_s[1], [140.0 - 2.5 - front, 8.0 - 1.0 - 4.0])


def test_field_of_view_and_range_limit_the_targets():
    env = _fast("ideal", fov=np.deg2rad(20.0), max_range=50.0)
    env.reset(seed=0)
    _place(env, [(108.0, 8.0), (130.0, 4.0), (170.0, 0.0)])  # beside (out of fov), ahead, too far
    assert list(env.sense().visible) == [False, True, False]


def test_sensor_pose_moves_the_frame():
    env = _fast("ideal", sensor_pose=(0.0, 0.0, np.pi), fov=np.deg2rad(90.0))  # rear-facing, at the centre
    env.reset(seed=0)
    _place(env, [(80.0, 6.0), (130.0, 4.0)])
    frame = env.sense()
    assert list(frame.visible) == [True, False]
    assert np.allclose(frame.det_s[0], [20.0 - 2.5, -1.0])  # its front-right corner (82.5, 5), on our right


# ------------------------------------------------------------------------------ track state


def test_previous_output_is_kept_per_target_and_cleared_on_reset():
    env = _fast(CountingRadar(), fov=2 * np.pi, max_range=np.inf, occlusion_threshold=None)
    _, info = env.reset(seed=4)
    z = info["radar"].detections - info["radar"].truth_reference[info["radar"].detection_target]
    assert np.allclose(z, 0.0)
    for k in range(1, 4):
        _, _, term, trunc, info = env.step(1)
        assert not (term or trunc)
        z = info["radar"].detections - info["radar"].truth_reference[info["radar"].detection_target]
        assert np.allclose(z, [k, 0.0])  # every target stays visible, so every track has age k
    _, info = env.reset(seed=4)
    z = info["radar"].detections - info["radar"].truth_reference[info["radar"].detection_target]
    assert np.allclose(z, 0.0)


def test_difference_velocity_of_the_ideal_radar_is_the_corner_displacement():
    env = _fast("ideal", fov=2 * np.pi, max_range=np.inf, occlusion_threshold=None)
    _, before = env.reset(seed=4)
    env.step(1)
    after = env.last_frame
    dt = 1.0 / env.unwrapped.config["policy_frequency"]
    prev = dict(zip(before["radar"].detection_target, before["radar"].detections_world, strict=True))
    assert len(after.det_target) > 0
    for j, t in enumerate(after.det_target):
        # targets keep their truth index here: nobody leaves the 200 m horizon in one step of this seed
        assert np.allclose(after.det_v[j], (after.det_w[j] - prev[t]) / dt)


def test_new_tracks_get_the_doppler_velocity_and_clutter_is_stationary():
    env = _fast(JitterRadar(miss=0.0), fov=2 * np.pi, max_range=np.inf, occlusion_threshold=None)
    env.reset(seed=4)  # no previous outputs: every detection is a new track
    f, ego = env.last_frame, env.unwrapped.vehicle
    tgt = f.det_target >= 0
    u = f.det_w[tgt] - f.sensor_pose[:2]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    radial = np.sum((f.truth.velocity[f.det_target[tgt]] - ego.velocity) * u, axis=1, keepdims=True)
    assert np.allclose(f.det_v[tgt], ego.velocity + radial * u)
    assert np.array_equal(f.det_v[~tgt], np.zeros(((~tgt).sum(), 2)))


# ----------------------------------------------------------------------- observation, config


def test_observations_are_fresh_and_inside_the_space():
    env = _fast(JitterRadar())
    for obs, _ in _rollout(env, seed=2, n=5):
        assert obs in env.observation_space
    a = env.reset(seed=0)[0]
    a[:] = 7.0
    b = env.step(1)[0]
    assert not np.shares_memory(a, b) and b.max() <= 1.0


def test_clutter_and_misses_reach_the_observation():
    env = _fast(JitterRadar(miss=0.5), fov=2 * np.pi, max_range=np.inf, occlusion_threshold=None)
    ref = _fast("ideal", fov=2 * np.pi, max_range=np.inf, occlusion_threshold=None)
    differ = 0
    for (o, info), (o_ref, _) in zip(_rollout(env, seed=9, n=4), _rollout(ref, seed=9, n=4), strict=True):
        differ += not np.array_equal(o, o_ref)
        assert info["radar"].missed.any()
    assert differ >= 4


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"config": {"bogus": 1}}, "config.bogus: unknown highway-env key"),
        ({"config": {"observation": {"type": "Kinematics", "foo": 1}}}, "observation.foo: unknown key"),
        (
            {"config": {"observation": {"type": "Kinematics", "features": ["presence", "long_off"]}}},
            "observation.features: 'long_off' is not a radar feature",
        ),
        ({"fov": 0.0}, "fov: expected"),
        ({"max_range": -1.0}, "max_range: expected"),
        ({"occlusion_threshold": 1.5}, "occlusion_threshold: expected"),
        ({"reference": "edge"}, "reference: expected"),
        ({"velocity": "doppler"}, "velocity: expected"),
        ({"radar": "lidar"}, "radar: expected one of"),
        ({"radar": "ideal", "radar_model": "x.npz"}, "radar_model: the ideal radar takes no model file"),
    ],
)
def test_bad_configuration_names_the_key(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        make_highway("highway-fast-v0", **{"radar": "ideal", **kwargs})


def test_changing_the_layout_on_reset_is_an_error():
    env = _fast("ideal")
    env.reset(seed=0, options={"config": {"lanes_count": 3}})  # other keys may change
    with pytest.raises(ValueError, match=re.escape("options.config.observation: the observation layout is fixed")):
        env.reset(options={"config": {"observation": {"type": "Kinematics", "vehicles_count": 9}}})


def test_non_kinematics_observation_is_a_type_error():
    with pytest.raises(TypeError, match=re.escape("observation type: the radar wrapper needs 'Kinematics'")):
        make_highway("highway-fast-v0", radar="ideal", config={"observation": {"type": "OccupancyGrid"}})


def test_unknown_sensor_option_is_an_error():
    with pytest.raises(TypeError, match="bogus"):
        gym.make(FAST, radar="ideal", bogus=1)


# ------------------------------------------------------------------- pickling, vector envs


def test_pickle_round_trip_keeps_the_rollout_and_shares_the_model():
    env = _fast("ideal")
    env.reset(seed=0)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.radar is env.radar is load_radar("ideal")
    assert np.array_equal(env.step(1)[0], clone.step(1)[0])


def test_async_vector_env_of_four_runs():
    fns = [lambda: gym.make(FAST, radar="ideal", config={"vehicles_count": 10}) for _ in range(4)]
    venv = gym.vector.AsyncVectorEnv(fns)
    try:
        obs, info = venv.reset(seed=0)
        assert obs.shape == (4, 5, 5)
        for _ in range(3):
            obs, _, _, _, info = venv.step(venv.action_space.sample())
        assert obs.shape == (4, 5, 5) and np.isfinite(obs).all()
        assert info["radar"].shape == (4,) and info["radar"][3].detections.shape[1] == 2
    finally:
        venv.close()


def test_sync_vector_env_matches_single_envs():
    venv = gym.vector.SyncVectorEnv([lambda: _fast(JitterRadar()) for _ in range(2)])
    obs, _ = venv.reset(seed=[3, 4])
    assert np.array_equal(obs[0], _fast(JitterRadar()).reset(seed=3)[0])
    assert np.array_equal(obs[1], _fast(JitterRadar()).reset(seed=4)[0])


@pytest.mark.slow
def test_sb3_subproc_vec_env_runs():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    # "module:id" makes gymnasium import sensor_envs (which registers the ids) in the worker processes
    venv = make_vec_env(
        f"sensor_envs:{FAST}",
        n_envs=2,
        seed=0,
        vec_env_cls=SubprocVecEnv,
        env_kwargs={"radar": "ideal", "config": {"vehicles_count": 10}},
    )
    try:
        obs = venv.reset()
        obs, *_ = venv.step(np.array([1, 1]))
        assert obs.shape == (2, 5, 5)
    finally:
        venv.close()


def test_async_vector_env_of_four_with_the_kde_radar_is_seeded():
    if not _model_available("kde"):
        pytest.skip("no shipped kde model yet")
    fns = [lambda: gym.make(FAST, radar="kde", config={"vehicles_count": 10}) for _ in range(4)]
    runs = []
    for _ in range(2):
        venv = gym.vector.AsyncVectorEnv(fns)
        try:
            obs, _ = venv.reset(seed=7)
            steps = [obs] + [venv.step(np.array([1, 1, 1, 1]))[0] for _ in range(2)]
        finally:
            venv.close()
        runs.append(np.stack(steps))
    assert runs[0].shape == (3, 4, 5, 5) and np.array_equal(runs[0], runs[1])


# -------------------------------------------------------------------------------- rendering


def test_render_overlays_detections():
    env = make_highway("highway-fast-v0", radar="ideal", render_mode="rgb_array", config={"vehicles_count": 10})
    env.reset(seed=0)
    env.step(1)
    img = env.render()
    plain = env.env.render()
    assert img.shape == plain.shape and img.dtype == np.uint8
    magenta = np.all(img == (230, 0, 230), axis=-1)
    assert magenta.any() and not np.all(plain == (230, 0, 230), axis=-1).any()
    # the overlay sits where highway-env draws the detected positions
    surface = env.unwrapped.viewer.sim_surface
    col, row = surface.vec2pix(env.last_frame.det_w[0])
    assert magenta[row, col]


@pytest.mark.skipif(not _model_available("kde"), reason="no shipped kde model yet")
def test_public_names_of_the_split_modules():
    import sensor_envs.envs.highway as hw

    for name in hw.__all__:
        assert getattr(hw, name) is not None
    for module in ("sensor", "step_record", "observation", "render", "wrapper"):
        mod = __import__(f"sensor_envs.envs.highway.{module}", fromlist=["__all__"])
        assert all(hasattr(mod, name) for name in mod.__all__), module
    assert hw.RadarInfo.__module__ == "sensor_envs.envs.highway.step_record"


def test_user_model_file_is_loaded_once_per_path(tmp_path):
    import shutil

    mine = tmp_path / "my_radar.npz"
    shutil.copy(default_model_path(DEFAULT_MODEL_FILES["kde"]), mine)
    a = gym.make(FAST, radar="kde", radar_model=str(mine), config={"vehicles_count": 10})
    b = gym.make(FAST, radar="kde", radar_model=mine, config={"vehicles_count": 10})
    ra, rb = a.get_wrapper_attr("radar"), b.get_wrapper_attr("radar")
    assert ra is rb and ra is not load_radar("kde")
    assert a.reset(seed=0)[0] in a.observation_space


def test_clutter_fraction_thins_the_models_clutter():
    """``clutter_fraction=0`` removes every clutter detection; 1 keeps the model's; bad values are refused."""
    counts = {}
    for frac in (0.0, 1.0):
        env = gym.make("sensor_envs/HighwayFast-v0", radar="kde", clutter_fraction=frac)
        _, info = env.reset(seed=3)
        n = 0
        for _ in range(3):
            _, _, term, trunc, info = env.step(1)
            n += int(np.sum(np.asarray(info["radar"].detection_target) < 0))
            if term or trunc:
                break
        counts[frac] = n
        env.close()
    assert counts[0.0] == 0 and counts[1.0] > 0
    for bad in (-0.1, 1.5, float("nan"), True):
        with pytest.raises(ValueError, match="clutter_fraction"):
            gym.make("sensor_envs/HighwayFast-v0", radar="kde", clutter_fraction=bad)
