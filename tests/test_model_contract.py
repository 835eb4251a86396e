"""One contract for the fitted sensor models: sklearn estimators, one parameter table, value-checked files."""

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sklearn.base import BaseEstimator, clone
from sklearn.exceptions import NotFittedError

from sensor_envs.geometry import quaternion_yaw, sample_free_poses
from sensor_envs.lidar.lwlr import LidarLWLR
from sensor_envs.lidar.rig import NeatoRig
from sensor_envs.maps import load_map
from sensor_envs.modelio import ModelFileError, default_model_path
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.rig import record_rig_log
from sensor_envs.rng import fold_ids

MODELS = {"lidar": (LidarLWLR, "neato_lidar.npz"), "kde": (KDERadarModel, "radar_kde.npz")}
MODELS["gaussian"] = (GaussianRadar, "radar_gaussian.npz")
ROOM = load_map("seed_room").segments


def _shipped(kind: str) -> Path:
    path = default_model_path(MODELS[kind][1])
    if not path.is_file():
        pytest.skip(f"shipped model {path.name} is absent")
    return path


def _read(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return json.loads(arrays.pop("__header__").tobytes().decode("utf-8")), arrays


def _write(path: Path, header: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    blob = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(path, __header__=blob, **arrays)
    return path


# ------------------------------------------------------------------------------------ corruptions
def _table(name: str, value: float):
    """Set one cell of the lidar table of parameter ``name``."""

    def f(h, a):
        i = h["param_names"].index(name)
        a["tables"] = a["tables"].copy()
        a["tables"][i, 7, 3, 2] = value

    return f


def _arr(name: str, fn):
    def f(h, a):
        a[name] = fn(a[name].copy())

    return f


def _hdr(*keys: str, value: Any):
    def f(h, a):
        d = h
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value

    return f


def _set(a: np.ndarray, idx: Any, value: float) -> np.ndarray:
    a[idx] = value
    return a


def _swap(a: np.ndarray) -> np.ndarray:
    a[[2, 3]] = a[[3, 2]]
    return a


CORRUPTIONS = [
    # kind, case id, field named in the error, corruption
    ("lidar", "p_null_above_1", "tables[p_null]", _table("p_null", 1.7)),
    ("lidar", "p_spur_negative", "tables[p_spur]", _table("p_spur", -0.2)),
    ("lidar", "log_sigma_50", "tables[log_sigma]", _table("log_sigma", 50.0)),  # sigma 5e21 m
    ("lidar", "bias_absurd", "tables[bias]", _table("bias", 1e7)),
    ("lidar", "tau2_negative", "tables[tau2]", _table("tau2", -1.0)),
    ("lidar", "table_nan", "tables", _table("bias", np.nan)),
    ("lidar", "range_grid_not_monotone", "range_grid", _arr("range_grid", _swap)),
    ("lidar", "alpha_grid_wrong_length", "tables", _arr("alpha_grid", lambda a: a[:-1])),
    ("lidar", "alpha_grid_beyond_90deg", "alpha_grid", _arr("alpha_grid", lambda a: a * 3)),
    ("lidar", "bearings_nan", "bearings", _arr("bearings", lambda a: _set(a, 5, np.nan))),
    ("lidar", "p_out_above_1", "p_out", _hdr("p_out", value=1.5)),
    ("lidar", "spur_sigma_negative", "spur_sigma", _hdr("spur_sigma", value=-0.1)),
    ("lidar", "null_rho_1", "null_rho", _hdr("null_rho", value=1.0)),
    ("lidar", "spur_rho_nan", "spur_rho", _hdr("spur_rho", value=float("nan"))),
    ("lidar", "spur_rho_negative", "spur_rho", _hdr("spur_rho", value=-0.2)),
    ("lidar", "kernel_width_negative", "h[bias]", _hdr("h", "bias", value=[-6.4, 0.5, 12.0, 0.0])),
    ("lidar", "unknown_variant", "variant", _hdr("params", "variant", value="sead")),
    ("lidar", "n_folds_1", "n_folds", _hdr("params", "n_folds", value=1)),
    ("kde", "unknown_sampler", "sampler", _hdr("params", "sampler", value="bukcet")),
    ("kde", "radius_negative", "radius", _hdr("params", "radius", value=-3.0)),
    ("kde", "unknown_param", "bogus", _hdr("params", "bogus", value=1)),
    ("kde", "rel_variance_3_values", "rel_variance", _hdr("params", "rel_variance", value=[3.0, 3.0, 0.03])),
    ("kde", "rel_variance_fitted_negative", "rel_variance_fitted", _hdr("rel_variance_fitted", value=[48, -48, 1, 1])),
    ("kde", "log_h_50", "log_h", _arr("log_h", lambda a: _set(a, (3, 4, 0), 50.0))),
    ("kde", "log_h_nan", "log_h", _arr("log_h", lambda a: _set(a, (3, 4, 0), np.nan))),
    ("kde", "grid_x_not_monotone", "grid_x", _arr("grid_x", _swap)),
    ("kde", "grid_y_wrong_length", "log_h", _arr("grid_y", lambda a: a[:-1])),
    ("kde", "cv_candidates_negative", "cv_candidates", _arr("cv_candidates", lambda a: -a)),
    ("kde", "log_row_wrong_length", "log_row", _arr("log_row", lambda a: a[:-1])),
    ("kde", "z_absurd", "z", _arr("z", lambda a: _set(a, np.flatnonzero(~np.isnan(a[:, 0]))[0], 1e9))),
    ("kde", "corner_nan", "states", _arr("states", lambda a: _set(a, (0, 0), np.nan))),
    ("kde", "clutter_count_negative", "clutter_counts", _arr("clutter_counts", lambda a: _set(a, 0, -1))),
    ("kde", "cycle_time_negative", "cycle_time", _hdr("cycle_time", value=-1.0)),
    ("gaussian", "p_detect_above_1", "p_detect", _arr("p_detect", lambda a: _set(a, 2, 1.7))),
    ("gaussian", "p_detect_nan", "p_detect", _arr("p_detect", lambda a: _set(a, 2, np.nan))),
    ("gaussian", "cov_negative_variance", "cov", _arr("cov", lambda a: _set(a, (1, 0, 0), -0.5))),
    ("gaussian", "cov_not_symmetric", "cov", _arr("cov", lambda a: _set(a, (1, 0, 1), 5.0))),
    ("gaussian", "edges_not_monotone", "edges", _arr("edges", _swap)),
    ("gaussian", "mean_wrong_length", "mean", _arr("mean", lambda a: a[:-1])),
    ("gaussian", "mean_absurd", "mean", _arr("mean", lambda a: _set(a, (0, 0), 1e6))),
    ("gaussian", "clutter_rate_negative", "clutter_rate", _arr("clutter_rate", lambda a: -a)),
    ("gaussian", "clutter_cov_singular", "clutter_cov", _arr("clutter_cov", lambda a: np.zeros((2, 2)))),
    ("gaussian", "min_count_0", "min_count", _hdr("params", "min_count", value=0)),
    ("gaussian", "range_edges_decreasing", "range_edges", _hdr("params", "range_edges", value=[10.0, 5.0])),
]


@pytest.mark.parametrize(("kind", "case", "field", "corrupt"), CORRUPTIONS, ids=[c[1] for c in CORRUPTIONS])
def test_corrupt_model_file_names_the_file_and_the_field(kind, case, field, corrupt, tmp_path):
    header, arrays = _read(_shipped(kind))
    corrupt(header, arrays)
    path = _write(tmp_path / f"{kind}_{case}.npz", header, arrays)
    with pytest.raises(ModelFileError) as err:
        MODELS[kind][0].load(path)
    msg = str(err.value)
    assert str(path) in msg, msg
    assert f"'{field}" in msg or f"'params.{field}'" in msg, msg


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_shipped_files_pass_the_value_checks_and_round_trip(kind, tmp_path):
    header, arrays = _read(_shipped(kind))
    path = _write(tmp_path / f"{kind}.npz", header, arrays)  # an untouched rewrite loads
    model = MODELS[kind][0].load(path)
    assert model.get_params() == MODELS[kind][0].load(_shipped(kind)).get_params()


def test_corruptions_cover_every_kind_and_the_issue_examples():
    kinds = [c[0] for c in CORRUPTIONS]
    assert len(CORRUPTIONS) >= 15 and all(kinds.count(k) >= 5 for k in MODELS)
    assert {"unknown_sampler", "log_sigma_50", "p_detect_above_1"} <= {c[1] for c in CORRUPTIONS}


def test_corrupt_values_written_by_the_models_own_save_are_refused(tmp_path):
    g = GaussianRadar.load(_shipped("gaussian"))
    g.p_detect_ = g.p_detect_.copy()
    g.p_detect_[0] = 1.7
    path = g.save(tmp_path / "g.npz")
    with pytest.raises(ModelFileError, match=re.escape(f"{path}: field 'p_detect' holds 1.7")):
        GaussianRadar.load(path)
    lidar = LidarLWLR.load(_shipped("lidar"))
    lidar.tables_ = lidar.tables_.copy()
    lidar.tables_[lidar.param_names_.index("log_sigma")] = 50.0  # would give scans of 1e21 m
    path = lidar.save(tmp_path / "l.npz")
    with pytest.raises(ModelFileError, match=re.escape(f"{path}: field 'tables[log_sigma]' holds 50")):
        LidarLWLR.load(path)
    kde = KDERadarModel.load(_shipped("kde"))
    kde.sampler = "bukcet"
    path = kde.save(tmp_path / "k.npz")
    with pytest.raises(ModelFileError, match=re.escape(f"{path}: field 'params.sampler' is invalid")):
        KDERadarModel.load(path)


# ---------------------------------------------------------------------------------------- contract
@pytest.mark.parametrize("cls", [LidarLWLR, KDERadarModel, GaussianRadar])
def test_sklearn_estimator_contract(cls):
    assert issubclass(cls, BaseEstimator)
    est = cls()
    params = est.get_params()
    assert set(params) == set(cls._hyperparameter_constraints)  # the table covers every hyperparameter
    twin = clone(est)
    assert twin is not est and twin.get_params() == params
    name, value = {
        LidarLWLR: ("n_folds", 3),
        KDERadarModel: ("sampler", "ball"),
        GaussianRadar: ("min_count", 5),
    }[cls]
    assert est.set_params(**{name: value}) is est and est.get_params()[name] == value
    assert clone(est).get_params()[name] == value
    with pytest.raises(ValueError, match="bogus"):
        est.set_params(bogus=1)
    assert repr(est).startswith(cls.__name__)


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_clone_of_a_fitted_model_is_unfitted(kind):
    model = MODELS[kind][0].load(_shipped(kind))
    twin = clone(model)
    assert twin.get_params() == model.get_params()
    with pytest.raises(NotFittedError, match="not fitted"):
        twin.save("never_written.npz")
    assert not Path("never_written.npz").exists()


def test_unfitted_models_raise_sklearn_not_fitted_error():
    rng = np.random.default_rng(0)
    lidar = LidarLWLR()
    for call in (
        lambda: lidar.params(np.zeros((1, 3)), ROOM),
        lambda: lidar.sample(np.zeros((1, 3)), ROOM, rng),
        lambda: lidar.log_prob(np.ones((1, 360)), np.zeros((1, 3)), ROOM),
        lambda: KDERadarModel().sample(np.zeros((1, 2)), rng),
        lambda: KDERadarModel().log_prob(np.zeros((1, 2)), np.zeros((1, 2))),
        lambda: KDERadarModel().sample_cycle(np.zeros((1, 2)), None, rng),
        lambda: GaussianRadar().sample(np.zeros((1, 2)), rng),
        lambda: GaussianRadar().log_prob(np.zeros((1, 2)), np.zeros((1, 2))),
        lambda: GaussianRadar().sample_clutter(rng),
    ):
        with pytest.raises(NotFittedError, match="not fitted yet; call fit"):
            call()


def test_fit_uses_the_same_parameter_table_as_load():
    radar_log = record_rig_log(1, 5, 4, np.random.default_rng(0))
    with pytest.raises(ValueError, match=re.escape("sampler: expected one of ('auto', 'bucket', 'ball')")):
        KDERadarModel(sampler="bukcet").fit(radar_log)
    with pytest.raises(ValueError, match=re.escape("k_max: expected None or an integer in [1, inf)")):
        KDERadarModel(k_max=0).fit(radar_log)
    with pytest.raises(ValueError, match="min_count: expected an integer"):
        GaussianRadar(min_count=2.5).fit(radar_log)
    lidar_log, _ = NeatoRig().record(ROOM, np.random.default_rng(0), n_poses=4, repeats=2)
    with pytest.raises(ValueError, match="h_range_grid: expected a sequence"):
        LidarLWLR(h_range_grid=(0.1, -0.2)).fit(lidar_log)
    with pytest.raises(ValueError, match="degree_grid"):
        LidarLWLR(degree_grid=(2,)).fit(lidar_log)


# ----------------------------------------------------------------------------------- shared pieces
def test_fold_ids_deal_groups_round_robin():
    np.testing.assert_array_equal(
        fold_ids(29, 10, random_state=3), np.random.default_rng(3).permutation(np.arange(29) % 10)
    )
    seq = np.array([7, 7, 2, 9, 2, 4, 9])  # ranks: 2 -> 0, 4 -> 1, 7 -> 2, 9 -> 3
    np.testing.assert_array_equal(fold_ids(seq, 2), [0, 0, 0, 1, 0, 1, 1])
    keys = np.stack([seq, np.arange(7) // 4], axis=1)
    f = fold_ids(keys, 3)
    for k in np.unique(keys, axis=0):  # rows sharing a key share a fold
        assert np.unique(f[(keys == k).all(axis=1)]).size == 1
    assert np.bincount(f).max() - np.bincount(f, minlength=3).min() <= 2


def test_quaternion_yaw():
    for yaw in (-3.0, -0.4, 0.0, 1.2, 3.1):
        assert quaternion_yaw(np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)) == pytest.approx(yaw)


def test_free_poses_keep_clearance_and_distance():
    rng = np.random.default_rng(5)
    p = sample_free_poses(ROOM, 50, rng, 0.3)
    q = sample_free_poses(ROOM, 50, np.random.default_rng(5), 0.3)
    np.testing.assert_array_equal(p, q)
    from sensor_envs.geometry import point_segment_distance

    assert p.shape == (50, 3) and (point_segment_distance(p[:, :2], ROOM).min(axis=1) >= 0.3).all()
    far = sample_free_poses(ROOM, 20, rng, 0.2, away_from=p[0, :2], min_distance=1.0, enclosure_rays=8)
    assert (np.hypot(*(far[:, :2] - p[0, :2]).T) >= 1.0).all()
    with pytest.raises(ValueError, match="free poses"):
        sample_free_poses(ROOM, 1, rng, clearance=100.0, max_tries=3)


def test_each_model_file_is_loaded_once_per_process(tmp_path):
    import os
    import shutil

    import gymnasium as gym

    import sensor_envs  # noqa: F401  (registers the ids)
    from sensor_envs.envs.highway import load_radar
    from sensor_envs.lidar.sensors import make_lidar
    from sensor_envs.radar.sensors import make_radar

    kde = make_radar("kde", _shipped("kde"))
    assert make_radar("kde") is kde and load_radar("kde") is kde and make_radar("ideal") is load_radar("ideal")
    mine = tmp_path / "mine.npz"
    shutil.copy(_shipped("kde"), mine)
    other = make_radar("kde", mine)
    assert other is not kde and load_radar("kde", str(mine)) is other
    st = mine.stat()
    os.utime(mine, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # a rewritten file is loaded again
    assert make_radar("kde", mine) is not other
    _shipped("lidar")
    envs = [gym.make("sensor_envs/Neato-v0", lidar="learned") for _ in range(2)]
    assert envs[0].unwrapped.lidar is envs[1].unwrapped.lidar is make_lidar("learned")


def test_cli_help_lists_only_commands_that_exist():
    from sensor_envs.cli.main import build_parser

    parser = build_parser()
    commands = set(parser._subparsers._group_actions[0].choices)
    listed = re.search(r"Commands: ([\w, -]+)\.", parser.description)
    assert listed, parser.description
    advertised = {name.strip() for name in listed.group(1).split(",")}
    assert advertised == commands, advertised ^ commands


def test_fit_refuses_a_cycle_time_the_file_could_not_hold():
    log = record_rig_log(1, 5, 4, np.random.default_rng(0))
    for cls in (GaussianRadar, KDERadarModel):
        with pytest.raises(ValueError, match=re.escape("cycle_time: expected a finite number > 0 or None, got -1.0")):
            cls().fit(log, cycle_time=-1.0)
