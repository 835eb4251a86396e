"""Issue 43 (lidar): a bias that carries over to unseen poses (pooled trend + weighted per-bearing part), and one
sampling semantics (one rigid pose error per pose) behind ``LidarLWLR.sample`` and the worlds' sensor."""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pytest

from sensor_envs.lidar.bias_transfer import LOCAL_WEIGHT_GRID, choose_bias, global_lookup, global_table
from sensor_envs.lidar.lwlr import LearnedLidar, LidarLWLR, cell_statistics, lidar_features
from sensor_envs.lidar.pose_correction import correct_poses, pose_error_sd
from sensor_envs.lidar.rig import NeatoRig
from sensor_envs.maps import load_map
from sensor_envs.modelio import ModelFileError
from sensor_envs.rng import fold_ids

ROOM = load_map("seed_room").segments
SMALL = {
    "n_folds": 4,
    "h_range_grid": (0.4, 1.6),
    "h_alpha_grid": (0.5,),
    "h_bearing_grid": (0.0, 2.0),
    "verbose": False,
}
RIG = {"n_bearings": 90, "blocked": (), "spur_prone": 0.0}
GRID = (np.linspace(0.0, 5.0, 41), np.linspace(0.0, np.pi / 2, 9))


def _mae_mu(model: LidarLWLR, log, min_range: float = 0.0) -> tuple[float, float]:
    """MAE of mu [m] of the raycast and of ``model`` on hit cells with >= 2 in-range readings and ``r >= min_range``."""
    r, a = lidar_features(log.poses, log.bearings, ROOM, model.max_range)
    st = cell_statistics(log, model.spur_above, split_spurious=True)
    m = np.isfinite(r) & (st["n_ok"] >= 2) & (np.nan_to_num(r, posinf=0.0) >= min_range)
    mu = model.params_from_features(r, a)["mu"]
    return float(np.abs(r - st["mean"])[m].mean()), float(np.abs(mu - st["mean"])[m].mean())


def _every_fold(model: LidarLWLR) -> None:
    for row in model.cv_scores_["bias_shrinkage"]["per_fold"]:
        assert row["n_cells"] > 0 and row["mae_chosen"] <= row["mae_raycast"] + 1e-12


# ------------------------------------------------------------------------------------------- pooled trend
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_global_table_recovers_a_planted_trend(seed):
    """A trend in range and incidence shared by every bearing, plus per-cell noise: G recovers it within the noise."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.3, 4.0, (30, 60))
    a = rng.uniform(0.0, 1.3, (30, 60))
    trend = -0.02 * (r - 1.0) ** 2 * (r > 1.0) + 0.01 * a
    y = trend + rng.normal(0.0, 0.005, r.shape)
    w = (rng.random(r.shape) > 0.1).astype(float)
    tab = global_table(r, a, y, w, (0.25, 0.5), (1,), GRID)[0]
    q_r, q_a = rng.uniform(0.5, 3.8, 500), rng.uniform(0.1, 1.2, 500)
    truth = -0.02 * (q_r - 1.0) ** 2 * (q_r > 1.0) + 0.01 * q_a
    err = np.abs(global_lookup(tab, GRID, q_r, q_a) - truth)
    assert np.median(err) < 0.003 and err.max() < 0.02
    assert global_lookup(tab, GRID, np.array([np.inf]), np.array([np.nan]))[0] == 0.0  # no hit: no bias


def test_choose_bias_weighs_the_per_bearing_part_by_the_folds():
    """``lam`` = 0 when the per-bearing part is noise that hurts every fold, 1 when it carries over."""
    rng = np.random.default_rng(0)
    fold = np.repeat(np.arange(5), 6)
    g = rng.normal(0.0, 0.01, (30, 40))
    local = rng.normal(0.0, 0.01, (30, 40))
    mask = np.ones((30, 40), dtype=bool)
    y = g + 0.002 * rng.standard_normal(g.shape)  # the trend is all there is
    lam, s, rep = choose_bias(y, g, local, mask, fold)
    assert lam == 0.0 and s < 0.5 and rep["local_weight"] == 0.0
    assert len(rep["per_local_weight"]) == len(LOCAL_WEIGHT_GRID)
    y = g + local + 0.002 * rng.standard_normal(g.shape)  # the per-bearing part is real
    lam, s, rep = choose_bias(y, g, local, mask, fold)
    assert lam == 1.0 and s < 0.5
    assert all(p["mae_chosen"] < p["mae_raycast"] for p in rep["per_fold"])
    lam, s, rep = choose_bias(y, -g, -local, mask, fold)  # exactly wrong: the raycast
    assert s == 1.0 and all(p["mae_chosen"] == p["mae_raycast"] for p in rep["per_fold"])


@pytest.fixture(scope="module")
def pose_error_unit():
    """No bias at all, large pose errors (4 cm, 3 deg): what a fit learns as bias is the poses' own errors."""
    rig = NeatoRig(bias_mean=0.0, bias_sd=0.0, map_sd=0.0, pose_sd=(0.04, float(np.deg2rad(3.0))), **RIG)
    log, truth = rig.record(ROOM, np.random.default_rng(1), n_poses=20, repeats=5)
    fresh, _ = rig.record(ROOM, np.random.default_rng(101), n_poses=20, repeats=5)
    return log, truth, fresh, LidarLWLR(**SMALL).fit(log)


@pytest.mark.parametrize("seed", [3, 4])
def test_range_trend_is_learned_and_carries_over(seed):
    """A unit whose far readings fall short (a range trend, as the real Neato) and small pose errors."""
    rig = NeatoRig(
        bias_sd=0.0,
        pose_sd=(0.005, float(np.deg2rad(0.3))),
        bias_range_knots=(0.0, 1.5, 3.0, 4.5),
        bias_range=(0.0, 0.0, -0.04, -0.12),
        **RIG,
    )
    log, _ = rig.record(ROOM, np.random.default_rng(seed), n_poses=20, repeats=10)
    fresh, _ = rig.record(ROOM, np.random.default_rng(100 + seed), n_poses=20, repeats=10)
    model = LidarLWLR(**SMALL).fit(log)
    assert model.bias_model == "pooled"
    _every_fold(model)
    ray, chosen = _mae_mu(model, fresh)
    assert chosen < ray
    ray, chosen = _mae_mu(model, fresh, min_range=3.0)  # where the trend is (-4 cm at 3 m, -12 cm at 4.5 m)
    assert chosen < 0.7 * ray


def test_pose_error_only_unit_stays_at_the_raycast(pose_error_unit):
    _, _, fresh, model = pose_error_unit
    _every_fold(model)
    ray, chosen = _mae_mu(model, fresh)
    unshrunk = copy.copy(model)
    unshrunk.bias_shrinkage_ = 0.0
    assert chosen <= ray + 0.1 * max(_mae_mu(unshrunk, fresh)[1] - ray, 0.0) + 1e-4


def test_real_per_bearing_bias_keeps_its_weight():
    """A unit with a real per-bearing bias (3 cm) and small pose errors: the per-bearing part is kept."""
    rig = NeatoRig(bias_sd=0.03, pose_sd=(0.003, float(np.deg2rad(0.2))), **RIG)
    log, _ = rig.record(ROOM, np.random.default_rng(2), n_poses=20, repeats=20)
    fresh, _ = rig.record(ROOM, np.random.default_rng(102), n_poses=20, repeats=20)
    model = LidarLWLR(**SMALL).fit(log)
    sc = model.cv_scores_["bias_shrinkage"]
    assert sc["local_weight"] >= 0.75 and model.bias_shrinkage_ <= 0.15
    ray, chosen = _mae_mu(model, fresh)
    assert chosen < 0.8 * ray


def test_per_bearing_setting_is_the_old_fit(pose_error_unit):
    log, _, _, _ = pose_error_unit
    old = LidarLWLR(bias_model="per_bearing", **SMALL).fit(log)
    assert "local_weight" not in old.cv_scores_["bias_shrinkage"]
    with pytest.raises(ValueError, match=re.escape("bias_model: expected one of ('pooled', 'per_bearing')")):
        LidarLWLR(bias_model="global", **SMALL).fit(log)


# --------------------------------------------------------------------------------------- rigid pose error
def test_pose_error_sd_recovers_the_rig(pose_error_unit):
    log, truth, _, model = pose_error_unit
    d = truth["true_poses"] - log.poses
    want = d.std(0)
    assert model.pose_sd_.shape == (3,)
    np.testing.assert_allclose(model.pose_sd_, want, rtol=0.5)
    st = cell_statistics(log, 6.0, split_spurious=True)
    poses, _, _ = correct_poses(log, st["mean"], st["n_ok"], 5.0)
    np.testing.assert_array_equal(pose_error_sd(log.poses, poses), model.pose_sd_)
    assert np.all(pose_error_sd(log.poses[:2], poses[:2]) == 0)


@pytest.mark.parametrize("seed", [0, 7, 21])
def test_sample_without_pose_error_is_the_worlds_draw(pose_error_unit, seed):
    """``sample`` with no pose error = ``sample_scan`` (the worlds' draw) at the poses' features, bit for bit."""
    log, _, _, model = pose_error_unit
    m = copy.copy(model)
    m.pose_sd_ = np.zeros(3)
    poses = log.poses[: 1 + seed % 5]
    r, a = lidar_features(poses, log.bearings, ROOM, m.max_range)
    x = m.sample(poses, ROOM, np.random.default_rng(seed))
    np.testing.assert_array_equal(x, m.sample_scan(r, a, np.random.default_rng(seed)))
    world = LearnedLidar(m).measure(r, a, np.random.default_rng(seed))
    np.testing.assert_array_equal(np.where(x == 0, np.nan, x), world)


@pytest.mark.parametrize("seed", [1, 5])
def test_sample_draws_one_rigid_pose_error_per_pose(pose_error_unit, seed):
    """With ``pose_sd_``: the worlds' draw at ``pose + d``, ``d`` drawn first, one per pose (all bearings move)."""
    log, _, _, model = pose_error_unit
    poses = log.poses[:4]
    rng = np.random.default_rng(seed)
    d = rng.standard_normal(poses.shape) * model.pose_sd_
    r, a = lidar_features(poses + d, log.bearings, ROOM, model.max_range)
    want = model.sample_scan(r, a, rng)
    np.testing.assert_array_equal(model.sample(poses, ROOM, np.random.default_rng(seed)), want)
    many = model.sample(poses, ROOM, np.random.default_rng(seed), n_repeats=30)
    assert many.shape == (4, log.n_bearings, 30)
    # the repeats of a pose share its pose error: their cell means move together along a wall
    r0, _ = lidar_features(poses, log.bearings, ROOM, model.max_range)
    ok = (many > 0) & (many < 6.0)
    with np.errstate(invalid="ignore"):
        mean = np.where(ok, many, 0.0).sum(2) / ok.sum(2)
    e = mean - r0
    pairs = np.isfinite(e[:, :-1]) & np.isfinite(e[:, 1:]) & (np.abs(e[:, :-1]) < 0.1) & (np.abs(e[:, 1:]) < 0.1)
    assert np.corrcoef(e[:, :-1][pairs], e[:, 1:][pairs])[0, 1] > 0.5


def test_pose_sd_round_trips_and_bad_values_fail_at_load(pose_error_unit, tmp_path):
    _, _, _, model = pose_error_unit
    path = model.save(tmp_path / "m.npz")
    back = LidarLWLR.load(path)
    np.testing.assert_array_equal(back.pose_sd_, model.pose_sd_)
    assert back.bias_model == "pooled"
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(arrays["__header__"].tobytes().decode("utf-8"))

    def write(name: str, h: dict) -> str:
        arrays["__header__"] = np.frombuffer(json.dumps(h).encode("utf-8"), dtype=np.uint8)
        np.savez(tmp_path / name, **arrays)
        return str(tmp_path / name)

    for bad_value in ([0.01, -0.01, 0.01], [0.01, 0.01], [0.01, 0.01, 9.0], ["x", 0.0, 0.0], [2.0, 0.0, 0.0]):
        bad = write("bad.npz", {**header, "pose_sd": bad_value})
        with pytest.raises(ModelFileError, match=re.escape(f"{bad}: field 'pose_sd'")):
            LidarLWLR.load(bad)
    old = {**header, "format_version": 5, "params": {k: v for k, v in header["params"].items() if k != "bias_model"}}
    old = {k: v for k, v in old.items() if k != "pose_sd"}
    back = LidarLWLR.load(write("v5.npz", old))
    assert back.bias_model == "per_bearing" and back.pose_sd_ is None


def test_sample_of_a_file_without_pose_sd_is_the_worlds_draw(pose_error_unit):
    log, _, _, model = pose_error_unit
    m = copy.copy(model)
    m.pose_sd_ = None
    r, a = lidar_features(log.poses[:2], log.bearings, ROOM, m.max_range)
    np.testing.assert_array_equal(
        m.sample(log.poses[:2], ROOM, np.random.default_rng(3)), m.sample_scan(r, a, np.random.default_rng(3))
    )


# ------------------------------------------------------------------------------------------- real data
@pytest.mark.slow  # end to end, several seconds: CI runs it with the slow tests
def test_real_fit_mean_never_worse_than_the_raycast_at_held_out_poses(real_data):
    """The real Neato log (when present): fitted on 4 of 5 pose folds, no worse than the raycast on the fifth."""
    from sensor_envs.lidar.log import load_log

    log = load_log(real_data / "neato_mar27_train.npz")
    fold = fold_ids(log.n_poses, 5, random_state=0)
    for f in (1, 2):
        model = LidarLWLR(**SMALL).fit(log.subset(fold != f))
        _every_fold(model)
        ray, chosen = _mae_mu(model, log.subset(fold == f))
        assert chosen <= ray
        assert np.all(model.pose_sd_ < np.array([0.05, 0.05, np.deg2rad(3.0)]))


# ----------------------------------------------------------------------------------------- validate, words
@pytest.mark.parametrize(
    ("model_mu", "word"), [(0.040, "better"), (0.04290, "the same"), (0.0452, "WORSE"), (0.042904, "the same")]
)
def test_validate_says_the_verdict_in_words(model_mu, word):
    from sensor_envs.lidar.validate import verdict_markdown

    def row(mu: float, sigma: float, p_null: float) -> dict:
        return {"all": {"mae_mu": mu, "mae_sigma": sigma, "mae_p_null": p_null}}

    metrics = {
        "model_extended": row(model_mu, 0.0053, 0.40),
        "ideal": row(0.0429, 0.009, 0.2),
        "gaussian": row(0.0429, 0.0081, 0.361),
    }
    text = verdict_markdown(metrics)
    assert f"- mean mu vs the raycast: {model_mu:.4f} vs 0.0429: {word}" in text
    assert "- spread sigma vs the Gaussian baseline: 0.0053 vs 0.0081: better" in text
    assert "- null probability vs the Gaussian baseline: 0.4000 vs 0.3610: WORSE" in text
    assert verdict_markdown({"ideal": metrics["ideal"]}) == ""
