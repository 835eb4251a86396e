"""Learned lidar mean never worse than the raycast (issue #12): CV bias shrinkage, pose correction, pose folds."""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pytest

from sensor_envs.lidar.lwlr import (
    LidarLWLR,
    cell_statistics,
    choose_shrinkage,
    lidar_features,
    pose_fold_groups,
)
from sensor_envs.lidar.pose_correction import correct_poses
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


def _mae_mu(model: LidarLWLR, log, shrinkage: float | None = None) -> tuple[float, float]:
    """MAE of mu [m] of the raycast and of ``model`` on a log's hit cells (at the log's poses)."""
    r, a = lidar_features(log.poses, log.bearings, ROOM, model.max_range)
    st = cell_statistics(log, model.spur_above, split_spurious=True)
    m = np.isfinite(r) & (st["n_ok"] >= 2)
    if shrinkage is not None:
        model = copy.copy(model)
        model.bias_shrinkage_ = shrinkage
    mu = model.params_from_features(r, a)["mu"]
    return float(np.abs(r - st["mean"])[m].mean()), float(np.abs(mu - st["mean"])[m].mean())


@pytest.fixture(scope="module")
def pose_error_fit():
    """A unit WITHOUT bias whose log has big pose errors (4 cm, 3 deg): its learned "bias" is pose error."""
    rig = NeatoRig(bias_mean=0.0, bias_sd=0.0, map_sd=0.0, pose_sd=(0.04, float(np.deg2rad(3.0))), **RIG)
    log, truth = rig.record(ROOM, np.random.default_rng(1), n_poses=20, repeats=5)
    fresh, _ = rig.record(ROOM, np.random.default_rng(101), n_poses=20, repeats=5)
    return log, truth, fresh, LidarLWLR(**SMALL).fit(log)


@pytest.fixture(scope="module")
def real_bias_fit():
    """A unit with a real per-bearing bias (sd 3 cm) and small pose errors (3 mm, 0.2 deg)."""
    rig = NeatoRig(bias_sd=0.03, pose_sd=(0.003, float(np.deg2rad(0.2))), **RIG)
    log, truth = rig.record(ROOM, np.random.default_rng(2), n_poses=20, repeats=20)
    fresh, _ = rig.record(ROOM, np.random.default_rng(102), n_poses=20, repeats=20)
    return log, truth, fresh, LidarLWLR(**SMALL).fit(log)


def _check_every_fold(model: LidarLWLR) -> dict:
    sc = model.cv_scores_["bias_shrinkage"]
    assert len(sc["per_fold"]) == SMALL["n_folds"]
    for row in sc["per_fold"]:
        assert row["n_cells"] > 0 and row["mae_chosen"] <= row["mae_raycast"] + 1e-12
    return sc


def test_pose_error_bias_is_shrunk_to_the_raycast(pose_error_fit):
    log, _, fresh, model = pose_error_fit
    sc = _check_every_fold(model)
    assert model.bias_shrinkage == "cv" and model.bias_shrinkage_ >= 0.8
    assert sc["cv_mae_unshrunk"] > sc["cv_mae_raycast"]  # the unshrunk bias does not generalise
    ray, chosen = _mae_mu(model, fresh)
    _, unshrunk = _mae_mu(model, fresh, 0.0)
    assert unshrunk > ray and chosen <= ray + 0.02 * (unshrunk - ray)  # unseen poses: (almost) the raycast


def test_real_bias_is_kept_and_beats_the_raycast(real_bias_fit):
    _, _, fresh, model = real_bias_fit
    sc = _check_every_fold(model)
    assert model.bias_shrinkage_ <= 0.15
    assert all(row["mae_chosen"] < 0.8 * row["mae_raycast"] for row in sc["per_fold"])
    ray, chosen = _mae_mu(model, fresh)
    assert chosen < 0.8 * ray


def test_fixed_shrinkage_scales_the_bias(real_bias_fit):
    log, _, _, model = real_bias_fit
    half = LidarLWLR(bias_shrinkage=0.5, **SMALL).fit(log)
    assert half.bias_shrinkage_ == 0.5 and half.cv_scores_["bias_shrinkage"]["rule"] == "given"
    np.testing.assert_array_equal(
        half.tables_[half.param_names_.index("bias")], model.tables_[model.param_names_.index("bias")]
    )
    r, a = lidar_features(log.poses[:3], log.bearings, ROOM, 5.0)
    mu0 = copy.copy(half)
    mu0.bias_shrinkage_ = 0.0
    hit = np.isfinite(r)
    full = mu0.params_from_features(r, a)["mu"] - np.where(hit, r, 0)
    got = half.params_from_features(r, a)["mu"] - np.where(hit, r, 0)
    np.testing.assert_allclose(got[hit], 0.5 * full[hit], atol=1e-12)
    with pytest.raises(
        ValueError, match=re.escape("bias_shrinkage: expected one of ('cv',) or a finite number in [0, 1], got 1.5")
    ):
        LidarLWLR(bias_shrinkage=1.5, **SMALL).fit(log)


def test_choose_shrinkage_checks_every_fold():
    rng = np.random.default_rng(0)
    fold = np.repeat(np.arange(4), 5)
    y = rng.normal(0.0, 0.01, (20, 30))
    oof = y + rng.normal(0.0, 0.002, (20, 30))  # a bias that generalises ...
    oof[fold == 3] = -y[fold == 3]  # ... except in fold 3, where it is exactly wrong
    mask = np.ones((20, 30), dtype=bool)
    s, rep = choose_shrinkage(y, oof, mask, fold)
    pooled_best = min(rep["candidates"], key=lambda c: np.abs((1 - c) * oof - y).mean())
    assert pooled_best < 0.5 and s == 1.0  # best on average, but worse than the raycast in fold 3
    assert rep["n_pass_every_fold"] == 1 and rep["per_fold"][3]["mae_unshrunk"] > rep["per_fold"][3]["mae_raycast"]
    oof[fold == 3] = y[fold == 3]
    s, rep = choose_shrinkage(y, oof, mask, fold)
    assert s == 0.0 and all(p["mae_chosen"] < p["mae_raycast"] for p in rep["per_fold"])


def test_cv_folds_group_rows_of_one_pose():
    poses = np.array([[1.0, 0.5, 0.1], [2.0, 0.5, 0.2], [1.0, 0.5, 0.1], [3.0, 1.0, -0.3], [2.0, 0.5, 0.2]])
    g = pose_fold_groups(poses)
    assert g.tolist() == [0, 1, 0, 2, 1]
    fold = fold_ids(g, 2, random_state=0)
    assert fold[0] == fold[2] and fold[1] == fold[4]
    distinct = np.random.default_rng(0).uniform(0, 3, (12, 3))
    np.testing.assert_array_equal(fold_ids(pose_fold_groups(distinct), 4, 0), fold_ids(12, 4, 0))  # folds unchanged
    rig = NeatoRig(**RIG)
    log, _ = rig.record(ROOM, np.random.default_rng(3), n_poses=3, repeats=2)
    twice = log.subset([0, 1, 2, 0, 1, 2])
    with pytest.raises(ValueError, match=re.escape("n_folds: must be in [2, number of distinct poses = 3]")):
        LidarLWLR(**{**SMALL, "n_folds": 4}).fit(twice)


def test_pose_correction_recovers_poses_and_bias():
    rig = NeatoRig(pose_sd=(0.04, float(np.deg2rad(3.0))), map_sd=0.0, **RIG)
    log, truth = rig.record(ROOM, np.random.default_rng(4), n_poses=8, repeats=10)
    st = cell_statistics(log, 6.0, split_spurious=True)
    poses, bias, info = correct_poses(log, st["mean"], st["n_ok"], 5.0)
    wrap = lambda d: (d + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    before = np.abs(
        np.c_[log.poses[:, :2] - truth["true_poses"][:, :2], wrap(log.poses[:, 2] - truth["true_poses"][:, 2])]
    )
    after = np.abs(np.c_[poses[:, :2] - truth["true_poses"][:, :2], wrap(poses[:, 2] - truth["true_poses"][:, 2])])
    assert after.mean(0)[0] < 0.2 * before.mean(0)[0] and after.mean(0)[2] < 0.2 * before.mean(0)[2]
    assert np.corrcoef(bias, truth["bias"])[0, 1] > 0.9
    assert info["median_abs_residual_after"] < 0.5 * info["median_abs_residual_before"]


def test_pose_correction_fit_and_refusals(pose_error_fit):
    log, _, fresh, model = pose_error_fit
    pc = LidarLWLR(pose_correction=True, **SMALL).fit(log)
    assert pc.cv_scores_["pose_correction"]["rms_dx"] > 0.01  # the 4 cm pose errors were seen and corrected
    _check_every_fold(pc)
    ray, chosen = _mae_mu(pc, fresh)
    _, unshrunk = _mae_mu(pc, fresh, 0.0)
    _, plain = _mae_mu(model, fresh, 0.0)
    assert unshrunk < plain  # learned at corrected poses, the bias holds less pose error
    assert chosen <= ray + 0.02 * abs(plain - ray)
    scans, _ = NeatoRig(**RIG).record(ROOM, np.random.default_rng(0), n_poses=4, repeats=1)
    with pytest.raises(ValueError, match="pose_correction needs a static log with repeats"):
        LidarLWLR(pose_correction=True, **{**SMALL, "n_folds": 2}).fit(scans)


def test_shrinkage_round_trips_and_bad_values_fail_at_load(pose_error_fit, tmp_path):
    log, _, _, model = pose_error_fit
    path = model.save(tmp_path / "m.npz")
    back = LidarLWLR.load(path)
    assert back.bias_shrinkage_ == model.bias_shrinkage_ and back.bias_shrinkage == "cv"
    assert back.cv_scores_["bias_shrinkage"]["per_fold"] == model.cv_scores_["bias_shrinkage"]["per_fold"]
    np.testing.assert_array_equal(back.params(log.poses, ROOM)[1], model.params(log.poses, ROOM)[1])
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(arrays["__header__"].tobytes().decode("utf-8"))

    def write(name: str, h: dict) -> str:
        arrays["__header__"] = np.frombuffer(json.dumps(h).encode("utf-8"), dtype=np.uint8)
        np.savez(tmp_path / name, **arrays)
        return str(tmp_path / name)

    bad = write("bad.npz", {**header, "bias_shrinkage": 1.5})
    with pytest.raises(ModelFileError, match=re.escape(f"{bad}: field 'bias_shrinkage' holds 1.5")):
        LidarLWLR.load(bad)
    bad = write("nan.npz", {**header, "bias_shrinkage": "half"})
    with pytest.raises(ModelFileError, match=re.escape(f"{bad}: field 'bias_shrinkage' is not numeric")):
        LidarLWLR.load(bad)
    bad = write("param.npz", {**header, "params": {**header["params"], "bias_shrinkage": -0.1}})
    with pytest.raises(ModelFileError, match=re.escape(f"{bad}: field 'params.bias_shrinkage' is invalid")):
        LidarLWLR.load(bad)
    bad = write("clash.npz", {**header, "params": {**header["params"], "bias_shrinkage": 0.25}})
    with pytest.raises(ModelFileError, match=re.escape(f"{bad}: field 'bias_shrinkage' is")):
        LidarLWLR.load(bad)
    no = {k: v for k, v in header.items() if k != "bias_shrinkage"}
    bad = write("missing.npz", no)
    with pytest.raises(ModelFileError, match=re.escape(f"{bad}: field '__header__' lacks or misstates")):
        LidarLWLR.load(bad)


def test_shipped_model_file_still_loads():
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "models" / "neato_lidar.npz"
    if not path.exists():
        pytest.skip(f"{path} absent")
    m = LidarLWLR.load(path)
    # refitted in format 4 with the default CV shrinkage (older formats load with 0: test_lidar_model)
    assert m.bias_shrinkage == "cv" and 0.0 <= m.bias_shrinkage_ <= 1.0 and m.pose_correction is False


def test_real_log_shrinkage_never_worse_in_any_fold(real_data):
    """On the real Neato log (when present): the chosen shrinkage passes every inner CV fold."""
    from sensor_envs.lidar.log import load_log

    log = load_log(real_data / "neato_mar27_train.npz").subset(np.arange(0, 29, 3))
    model = LidarLWLR(**SMALL).fit(log)
    _check_every_fold(model)
