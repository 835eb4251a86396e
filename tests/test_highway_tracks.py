"""The highway radar's observation options: object-level clutter, stationary filter, tracks, history."""

import json
import re
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.envs.highway import RadarObservation
from sensor_envs.envs.highway.clutter import clutter_keep_probability
from sensor_envs.envs.highway.tracker import MultiTargetTracker, TrackerConfig
from sensor_envs.radar.object_clutter import (
    ObjectClutterLaw,
    doppler_period,
    frame_clutter_objects,
    load_object_clutter,
    sensor_velocity,
)
from tests.test_highway import _check, _rollout, _same

FAST = "sensor_envs/HighwayFast-v0"
OPTIONS = [
    {"tracks": True},
    {"tracks": True, "stationary": "drop"},
    {"history": 3},
    {"history": 2, "tracks": True},
    {"stationary": "drop"},
    {"clutter": "model"},
]


def _make(radar="kde", **kw):
    return gym.make(FAST, radar=radar, config={"vehicles_count": 10}, **kw)


def _radar(env):
    while not isinstance(env, RadarObservation):
        env = env.env
    return env


# ------------------------------------------------------------------------------- the tracker


def _cycle(tr, pts, radial=None, dt=1.0):
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    radial = np.zeros(len(pts)) if radial is None else np.asarray(radial, dtype=float)
    return tr.step(pts, radial, np.array([-100.0, 0.0]), dt)


def test_a_target_is_confirmed_after_m_of_n_hits_and_its_velocity_is_learnt():
    tr = MultiTargetTracker(TrackerConfig(confirm_hits=2, confirm_window=3, doppler_gate=None))
    for k in range(8):
        _cycle(tr, [[10.0 * k, 0.0]], radial=[10.0])
        if k == 0:
            assert len(tr.confirmed().ids) == 0
    out = tr.confirmed()
    assert len(out.ids) == 1
    assert np.allclose(out.velocity[0], [10.0, 0.0], atol=0.3)
    assert np.allclose(out.position[0], [70.0, 0.0], atol=0.3)
    assert out.age[0] == 8 and out.existence[0] == 1.0


def test_m_of_n_window_and_coasting_then_deletion():
    cfg = TrackerConfig(confirm_hits=2, confirm_window=3, delete_after=2, doppler_gate=None)
    tr = MultiTargetTracker(cfg)
    _cycle(tr, [[0.0, 0.0]])
    _cycle(tr, [])
    _cycle(tr, [])
    assert len(tr) == 0  # 1 hit and no chance left in the window
    tr = MultiTargetTracker(cfg)
    _cycle(tr, [[0.0, 0.0]])
    _cycle(tr, [])
    _cycle(tr, [[0.0, 0.0]])
    assert len(tr.confirmed().ids) == 1  # hits at 0 and 2: 2 of 3
    _cycle(tr, [])
    assert len(tr.confirmed().ids) == 1 and tr.confirmed().coasting[0]
    _cycle(tr, [])
    assert len(tr.confirmed().ids) == 0  # deleted after 2 consecutive misses


def test_gates_keep_far_and_doppler_mismatched_detections_apart():
    tr = MultiTargetTracker(TrackerConfig(doppler_gate=2.0))
    first = _cycle(tr, [[0.0, 0.0]], radial=[0.0])
    far = _cycle(tr, [[30.0, 0.0]], radial=[0.0])
    assert far[0] != first[0]  # outside the position gate: a new track
    tr = MultiTargetTracker(TrackerConfig(doppler_gate=2.0))
    first = _cycle(tr, [[0.0, 0.0]], radial=[0.0])
    fast = _cycle(tr, [[0.0, 0.0]], radial=[5.0])
    assert fast[0] != first[0]  # same place, but its Doppler is 5 m/s off
    same = _cycle(tr, [[0.0, 0.0]], radial=[0.0])
    assert same[0] == first[0]


def test_the_batched_filter_equals_filterpy_per_track():
    fp = pytest.importorskip("filterpy", reason="filterpy (the test extra) is the reference filter")
    from filterpy.common import Q_discrete_white_noise
    from filterpy.kalman import predict, update

    assert fp is not None
    cfg = TrackerConfig(doppler_gate=None, accel_std=2.0, position_std=0.6)
    tr = MultiTargetTracker(cfg)
    rng = np.random.default_rng(3)
    start = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]]) + rng.uniform(-1, 1, (4, 2))
    _cycle(tr, start, radial=rng.normal(0, 0.5, 4), dt=0.5)
    ref = [(tr.x[k].copy(), tr.P[k].copy()) for k in range(4)]
    F = np.eye(4)
    F[0, 2] = F[1, 3] = 0.5
    Q = Q_discrete_white_noise(dim=2, dt=0.5, var=4.0, block_size=2, order_by_dim=False)
    H, R = np.eye(2, 4), 0.36 * np.eye(2)
    meas = start + rng.normal(0, 0.3, (4, 2))
    _cycle(tr, meas, radial=np.zeros(4), dt=0.5)
    assert len(tr) == 4  # every measurement updated its track
    for k, (x, P) in enumerate(ref):
        x, P = predict(x, P, F, Q)
        x, P = update(x, P, meas[k], R, H)
        assert tr.ids[k] == k and np.allclose(tr.x[k], x) and np.allclose(tr.P[k], P)


def _target_in_clutter(seed):
    """A car at 25 m/s along x (Doppler from the sensor behind it) amid 40 stationary clutter points per cycle."""
    rng = np.random.default_rng(seed)
    tr = MultiTargetTracker()
    ids = []
    for k in range(12):
        car = np.array([[25.0 * k, 1.0]])
        clutter = rng.uniform([25.0 * k - 40, -10], [25.0 * k + 40, 10], (40, 2))
        pts = np.concatenate([car, clutter])
        u = (car[0] - [-100.0, 0.0]) / np.linalg.norm(car[0] - [-100.0, 0.0])
        radial = np.concatenate([[25.0 * u[0]], np.zeros(40)])
        ids.append(tr.step(pts, radial, np.array([-100.0, 0.0]), 1.0, road_heading=0.0))
    return ids, tr


def test_a_car_amid_stationary_clutter_keeps_its_track_and_the_tracker_is_deterministic():
    ids, tr = _target_in_clutter(0)
    again, _ = _target_in_clutter(0)
    assert all(np.array_equal(a, b) for a, b in zip(ids, again, strict=True))
    assert len({int(i[0]) for i in ids}) == 1  # the Doppler gate keeps clutter off the car's track
    out = tr.confirmed()
    k = int(np.flatnonzero(out.ids == ids[0][0])[0])
    assert np.allclose(out.velocity[k], [25.0, 0.0], atol=0.5)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"confirm_hits": 0}, "confirm_hits"),
        ({"confirm_hits": 3, "confirm_window": 2}, "confirm_window"),
        ({"delete_after": 1.5}, "delete_after"),
        ({"gate": -1.0}, "gate"),
        ({"doppler_gate": float("nan")}, "doppler_gate"),
        ({"position_std": 0}, "position_std"),
        ({"accel_std": True}, "accel_std"),
    ],
)
def test_bad_tracker_settings_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=re.escape(f"tracker.{field}")):
        TrackerConfig(**kwargs)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.floats(-50, 50), st.floats(-50, 50)), max_size=60))
def test_tracker_state_stays_consistent(dets):
    tr = MultiTargetTracker()
    for k in range(7):
        pts = [(x, y) for c, x, y in dets if c == k]
        ids = _cycle(tr, pts)
        assert len(ids) == len(pts) and len(set(ids.tolist())) == len(ids)
        assert tr.x.shape == (len(tr), 4) and tr.P.shape == (len(tr), 4, 4)
        assert np.all(np.isfinite(tr.x)) and np.all(np.linalg.eigvalsh(tr.P) > 0)
        out = tr.confirmed()
        assert np.all((out.existence >= 0) & (out.existence <= 1))


# -------------------------------------------------------------------------------- the env options


@pytest.mark.parametrize("kw", OPTIONS, ids=lambda k: ",".join(f"{a}={b}" for a, b in k.items()))
def test_checkers_pass_for_each_option(kw):
    _check(_make(**kw))


@pytest.mark.parametrize("kw", OPTIONS[:4], ids=lambda k: ",".join(f"{a}={b}" for a, b in k.items()))
def test_same_seed_same_rollout_and_the_traffic_is_the_radars(kw):
    def roll(radar, seed):
        env = _make(radar, **kw)
        out = []
        obs, info = env.reset(seed=seed)
        env.action_space.seed(seed)
        out.append((obs, info))
        for _ in range(6):
            obs, _, term, trunc, info = env.step(env.action_space.sample())
            out.append((obs, info))
            if term or trunc:
                break
        return out

    a, b, c = roll("kde", 4), roll("kde", 4), roll("kde", 5)
    assert _same(a, b) and not _same(a, c)
    ideal = roll("ideal", 4)
    for (_, x), (_, y) in zip(a, ideal, strict=False):
        assert np.array_equal(x["radar"].truth_position, y["radar"].truth_position)


def test_history_stacks_the_last_observations():
    plain, stacked = _make(), _make(history=3)
    seq_plain = [o for o, _ in _rollout(plain, seed=2, n=4)]
    seq_stack = [o for o, _ in _rollout(stacked, seed=2, n=4)]
    v, f = plain.observation_space.shape
    assert stacked.observation_space.shape == (3 * v, f)
    assert np.array_equal(seq_stack[0][-v:], seq_plain[0]) and not seq_stack[0][:-v].any()  # zero-padded
    for t in range(2, 5):
        assert np.array_equal(seq_stack[t], np.concatenate(seq_plain[t - 2 : t + 1]))


def test_tracks_fill_the_same_layout_with_existence_as_presence():
    env = _make("kde", tracks=True)
    obs, info = env.reset(seed=1)
    for _ in range(5):
        obs, *_, info = env.step(1)
    tl = info["tracks"]
    assert obs.shape == _make("kde").observation_space.shape
    shown = obs[1:, 0] > 0
    assert np.all((obs[1:, 0] >= 0) & (obs[1:, 0] <= 1))
    assert shown.sum() == min(len(_radar(env).last_rows.objects), 4)
    assert len(tl.ids) >= shown.sum()


def test_ideal_tracks_follow_the_cars():
    env = _make("ideal", tracks=True)
    env.reset(seed=0)
    errs = []
    for _ in range(8):
        _, _, term, trunc, info = env.step(1)
        rows = _radar(env).last_rows
        r = info["radar"]
        objs = _radar(env).last_frame.truth.objects
        for obj, pos in zip(rows.objects, rows.position, strict=True):
            assert obj is not None  # the ideal radar has no clutter
            k = objs.index(obj)
            corner = r.sensor_pose[:2] + _rot(r.sensor_pose[2]) @ r.truth_reference[k]
            errs.append(np.linalg.norm(pos - corner))
        if term or trunc:
            break
    assert len(errs) > 10 and np.median(errs) < 1.0


def _rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def test_the_stationary_filter_lets_the_cars_into_the_rows():
    def car_rows(**kw):
        env = _make("kde", **kw)
        env.reset(seed=3)
        n = []
        for _ in range(12):
            _, _, term, trunc, _ = env.step(1)
            n.append(sum(o is not None for o in _radar(env).last_rows.objects))
            if term or trunc:
                break
        return np.mean(n)

    raw = car_rows()
    assert car_rows(stationary="drop") > raw + 1.0
    assert car_rows(stationary="drop", tracks=True) > raw + 1.0


def test_stationary_drop_removes_clutter_and_stopped_objects():
    env = _make("kde", stationary="drop")
    _, info = env.reset(seed=0)
    for _ in range(3):
        *_, info = env.step(1)
        r = info["radar"]
        assert np.all(r.detection_target >= 0)  # no clutter
        speed = np.linalg.norm(r.truth_velocity[r.detection_target], axis=1)
        assert np.all(speed > 0.5)


@dataclass(frozen=True)
class RingClutter:
    """Test double: no targets detected, 200 clutter points per cycle at 20 m range, +-0.5 rad."""

    def sample_cycle(self, corners, prev_z, rng):
        return np.full((len(corners), 2), np.nan), np.full(len(corners), -1)

    def sample_clutter(self, rng):
        a = rng.uniform(-0.5, 0.5, 200)
        return np.stack([20 * np.cos(a), 20 * np.sin(a)], axis=1)


def test_object_level_clutter_thins_to_the_law_rate():
    law = load_object_clutter()
    p = clutter_keep_probability(RingClutter())
    assert p[1] == pytest.approx(min(1.0, law.total[1] / 200.0))  # 15-30 m bin
    env = gym.make(FAST, radar=RingClutter(), config={"vehicles_count": 10})
    _, info = env.reset(seed=0)
    counts = [len(info["radar"].detections)]
    for _ in range(20):
        *_, info = env.step(1)
        counts.append(len(info["radar"].detections))
    n = len(counts) * 200
    # binomial(n, p): 5 standard deviations (fails with probability < 1e-6 for a correct thinning)
    assert abs(sum(counts) - n * p[1]) < 5 * np.sqrt(n * p[1] * (1 - p[1]))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"tracks": "yes"}, "tracks: expected True or False"),
        ({"tracker": {"gate": 1.0}}, "tracker: tracker settings need tracks=True"),
        ({"tracks": True, "tracker": {"gates": 1.0}}, "tracker.gates: unknown tracker setting"),
        ({"tracks": True, "tracker": {"confirm_hits": -1}}, "tracker.confirm_hits"),
        ({"tracks": True, "tracker": 3}, "tracker: expected a TrackerConfig"),
        ({"history": 0}, "history: expected an integer in [1, 64]"),
        ({"history": 2.0}, "history: expected an integer in [1, 64]"),
        ({"history": True}, "history: expected an integer in [1, 64]"),
        ({"clutter": "none"}, "clutter: expected one of"),
        ({"stationary": "filter"}, "stationary: expected one of"),
    ],
)
def test_bad_constructor_arguments_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        _make("kde", **kwargs)


# --------------------------------------------------------------------- the object-clutter law


def _synthetic_frame(rng, v=(6.0, 0.3), period=10.4):
    """Stationary points seen from a sensor moving at ``v``, plus one moving cluster at (30, 5)."""
    xy = rng.uniform([5, -30], [90, 30], (400, 2))
    mov = rng.normal([30.0, 5.0], 0.3, (6, 2))
    pts = np.concatenate([xy, mov])
    u = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    vr = -(u @ np.asarray(v))
    vr[-6:] += 3.0  # receding 3 m/s faster than the world
    vr = (vr + period / 2) % period - period / 2
    vr = np.round(vr / (period / 128)) * (period / 128)
    return np.concatenate([pts, np.zeros((len(pts), 1)), vr[:, None], np.ones((len(pts), 1))], axis=1)


def test_sensor_velocity_and_moving_objects_on_a_planted_frame():
    pts = _synthetic_frame(np.random.default_rng(1))
    period = doppler_period(pts[:, 3])
    assert period == pytest.approx(10.4, rel=0.02)
    v, res = sensor_velocity(pts[:, :3], pts[:, 3], period)
    assert v[0] == pytest.approx(6.0, abs=0.15) and abs(v[1] - 0.3) <= 0.5  # lateral: weakly observable
    objs = frame_clutter_objects(pts, np.ones(len(pts), dtype=bool), res, min_points=4)
    moving = objs[objs[:, 2] == 1]
    assert len(moving) == 1 and moving[0, 3] == pytest.approx(3.0, abs=0.3)


def _law_doc(**law):
    base = load_object_clutter().to_dict()
    base.update(law)
    return {"format_version": 1, "law": base}


@pytest.mark.parametrize(
    "doc, field",
    [
        ({"format_version": 2, "law": {}}, "format_version"),
        (_law_doc(stationary=[-1, 0, 0, 0, 0, 0]), "law.stationary"),
        (_law_doc(range_edges=[0, 10, 5, 20, 30, 40, 50]), "law.range_edges"),
        (_law_doc(moving=[1, 2]), "law.moving"),
        ({"format_version": 1, "law": {"range_edges": [0, 1]}}, "law.stationary"),
    ],
)
def test_bad_object_clutter_file_names_file_and_field(tmp_path, doc, field):
    p = tmp_path / "law.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=re.escape(f"{p}: field '{field}")):
        load_object_clutter(p)


def test_shipped_law_is_object_level():
    law = load_object_clutter()
    assert isinstance(law, ObjectClutterLaw) and law.total.sum() > 0


@pytest.mark.parametrize("kw", [{"tracks": True}, {"history": 2}], ids=["tracks", "history"])
def test_pickle_round_trip_keeps_the_rollout(kw):
    import pickle

    env = _make("kde", **kw)
    env.reset(seed=9)
    clone = pickle.loads(pickle.dumps(env))
    for a in (1, 0, 2):
        oa, *_ = env.step(a)
        ob, *_ = clone.step(a)
        assert np.array_equal(oa, ob)


def test_stacked_rows_refuses_a_flat_space():
    from sensor_envs.envs.highway import StackedRows

    with pytest.raises(TypeError, match=re.escape("env: expected a 3-D Box observation space")):
        StackedRows(_make("ideal"))
