"""The one sensor-model contract (sensor_envs.sensor_model): declared capabilities, the card, ``verbose``, and
old file formats read through one upgrade path (``sensor-envs upgrade-model``)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.lidar.lwlr import LidarLWLR
from sensor_envs.lidar.rig import NeatoRig
from sensor_envs.lidar.sensors import GaussianLidar
from sensor_envs.maps import load_map
from sensor_envs.modelio import ModelFileError, default_model_path
from sensor_envs.radar.gaussian import GaussianRadar, baseline_file
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.rig import record_rig_log
from sensor_envs.radar.sensors import IdealRadar, takes_new_track
from sensor_envs.sensor_model import CAPABILITIES, SensorModel, has_capability

MODELS = (KDERadarModel, GaussianRadar, LidarLWLR)
ROOM = load_map("seed_room").segments


def _read(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return json.loads(arrays.pop("__header__").tobytes().decode("utf-8")), arrays


def _write(path: Path, header: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    blob = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(path, __header__=blob, **arrays)
    return path


def _shipped(name: str) -> Path:
    path = default_model_path(name)
    if not path.is_file():
        pytest.skip(f"shipped model {name} is absent")
    return path


@pytest.fixture(scope="module")
def small_models(tmp_path_factory) -> dict[str, Path]:
    """Small fits with default hyperparameters (what every old format could hold), saved in the current format."""
    d = tmp_path_factory.mktemp("small")
    radar_log = record_rig_log(6, 12, 5, np.random.default_rng(0))
    lidar_log, _ = NeatoRig().record(ROOM, np.random.default_rng(0), n_poses=6, repeats=2)
    return {
        "kde": KDERadarModel(random_state=0).fit(radar_log, cycle_time=1.0).save(d / "kde.npz"),
        "gaussian": GaussianRadar().fit(radar_log, cycle_time=1.0).save(d / "gaussian.npz"),
        "lidar": LidarLWLR(variant="seed", n_folds=3, h_range_grid=(0.6,), h_alpha_grid=(0.5,))
        .fit(lidar_log)
        .save(d / "lidar.npz"),
    }


# ------------------------------------------------------------------------------- downgrades (test only)
def _kde_to(header: dict[str, Any], arrays: dict[str, np.ndarray], version: int) -> None:
    """Strip what each KDE format after ``version`` added (the inverse of the upgrade steps)."""
    p = header["params"]
    drops = {
        8: ("tail_weight", "tail_scale"),
        7: ("azimuth_bias", "start_bandwidth_scale"),
        6: ("output_frame",),
        5: ("state_transform", "relevance_candidates_azimuth"),
        3: ("extra_state", "extra_variance", "extra_candidates"),
        2: ("prior_rate",),
    }
    for v, names in drops.items():
        if v > version:
            for n in names:
                p.pop(n, None)
    if version < 7:
        header.pop("azimuth_bias_fitted", None)
    if version < 4:
        header.pop("new_track_flags", None)
        arrays.pop("new_track", None)
    if version < 3:
        arrays.pop("extra", None)
        header.pop("extra_variance_fitted", None)
        header.pop("extra_fill", None)
    header["format_version"] = version


def _lidar_to(header: dict[str, Any], arrays: dict[str, np.ndarray], version: int) -> None:
    p = header["params"]
    if version < 6:
        p.pop("bias_model", None)
        header.pop("pose_sd", None)
    if version < 5:
        header.pop("spur_rho", None)
    if version < 4:
        p.pop("bias_shrinkage", None)
        p.pop("pose_correction", None)
        header.pop("bias_shrinkage", None)
    if version < 3:
        p.pop("extra_state", None)
        for k in ("extra_mean", "extra_scale", "extra_coef"):
            arrays.pop(k, None)
    if version < 2:
        header.pop("null_rho", None)
    header["format_version"] = version


def _gaussian_to(header: dict[str, Any], arrays: dict[str, np.ndarray], version: int) -> None:
    if version < 2:
        header["params"].pop("extra_state", None)
        for k in ("extra_mean", "extra_std", "extra_coef", "extra_logit"):
            arrays.pop(k, None)
    header["format_version"] = version


DOWN = {"kde": (KDERadarModel, _kde_to), "gaussian": (GaussianRadar, _gaussian_to), "lidar": (LidarLWLR, _lidar_to)}
OLD = [(k, v) for k, (cls, _) in DOWN.items() for v in range(1, cls.FORMAT_VERSION)]


def _old_file(src: Path, kind: str, version: int, out: Path) -> Path:
    header, arrays = _read(src)
    DOWN[kind][1](header, arrays, version)
    return _write(out, header, arrays)


def _draws(model: SensorModel) -> list[np.ndarray]:
    if isinstance(model, LidarLWLR):
        poses = np.array([[1.0, 1.0, 0.3], [2.0, 1.5, -1.0]])
        scans = model.sample(poses, ROOM, np.random.default_rng(1))
        return [scans, model.log_prob(scans, poses, ROOM)]
    st = np.array([[12.0, 1.0, 0.1, -0.2], [30.0, -3.0, np.nan, np.nan], [55.0, 4.0, 0.3, 0.0]])
    z, src = model.sample(st, np.random.default_rng(1))
    return [z, src, model.log_prob(np.nan_to_num(z, nan=0.1), st)]


# --------------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize(("kind", "version"), OLD, ids=[f"{k}-v{v}" for k, v in OLD])
def test_every_old_format_loads_and_upgrades_to_the_same_model(kind, version, small_models, tmp_path, capsys):
    cls = DOWN[kind][0]
    old = _old_file(small_models[kind], kind, version, tmp_path / f"old_v{version}.npz")
    before = cls.load(old)
    assert main(["upgrade-model", str(old), "--out", str(tmp_path / "new.npz")]) == 0
    assert f"format {version} -> " in capsys.readouterr().out
    header, _ = _read(tmp_path / "new.npz")
    assert header["kind"] == cls.KIND and header["format_version"] == cls.FORMAT_VERSION
    after = cls.load(tmp_path / "new.npz")
    assert after.get_params() == before.get_params()
    for a, b in zip(_draws(after), _draws(before), strict=True):
        np.testing.assert_array_equal(a, b)
    assert after.card_ == before.card_


def test_old_formats_read_with_the_old_behaviour(small_models, tmp_path):
    """What a field's absence means: the behaviour before the format that added it."""
    header, arrays = _read(small_models["kde"])
    header["params"].update(tail_weight=0.2, tail_scale=8.0)
    tailed = _write(tmp_path / "tailed.npz", header, arrays)
    v7 = KDERadarModel.load(_old_file(tailed, "kde", 7, tmp_path / "kde7.npz"))
    assert (v7.tail_weight, v7.tail_scale) == (0.0, 4.0)  # format 7 had no tail mixture
    v3 = KDERadarModel.load(_old_file(small_models["kde"], "kde", 3, tmp_path / "kde3.npz"))
    assert v3.new_track_ is None and v3.output_frame == "cartesian" and v3.azimuth_bias_ == 0.0
    assert KDERadarModel.load(_old_file(small_models["kde"], "kde", 1, tmp_path / "kde1.npz")).prior_rate == "global"
    v1 = LidarLWLR.load(_old_file(small_models["lidar"], "lidar", 1, tmp_path / "l1.npz"))
    assert (v1.null_rho_, v1.spur_rho_, v1.bias_shrinkage_, v1.pose_sd_) == (0.0, 0.0, 0.0, None)
    assert v1.bias_model == "per_bearing" and v1.extra_state_ == ()
    g1 = GaussianRadar.load(_old_file(small_models["gaussian"], "gaussian", 1, tmp_path / "g1.npz"))
    assert g1.extra_state_ == () and g1.extra_coef_.shape == (0, 2)


@pytest.mark.parametrize("name", ["radar_kde.npz", "radar_gaussian.npz", "neato_lidar.npz"])
def test_the_shipped_files_upgrade_to_identical_draws(name, tmp_path):
    """The shipped files are current: an upgrade rewrites them as the same model (they are never re-saved here)."""
    src = _shipped(name)
    cls = {"radar_kde.npz": KDERadarModel, "radar_gaussian.npz": GaussianRadar, "neato_lidar.npz": LidarLWLR}[name]
    assert main(["upgrade-model", str(src), "--out", str(tmp_path / name)]) == 0
    for a, b in zip(_draws(cls.load(tmp_path / name)), _draws(cls.load(src)), strict=True):
        np.testing.assert_array_equal(a, b)


def test_upgrade_model_refuses_bad_inputs_and_existing_outputs(small_models, tmp_path, capsys):
    out = tmp_path / "up.npz"
    assert main(["upgrade-model", str(small_models["gaussian"]), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["upgrade-model", str(small_models["gaussian"]), "--out", str(out)]) == 2  # exists, no --force
    assert "exists" in capsys.readouterr().err
    assert main(["upgrade-model", str(small_models["gaussian"]), "--out", str(out), "--force"]) == 0
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a model")
    assert main(["upgrade-model", str(junk), "--out", str(tmp_path / "j2.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(junk) in err[0] and "Traceback" not in err[0]
    header, arrays = _read(small_models["gaussian"])
    header.update(kind="radar_unknown")
    odd = _write(tmp_path / "odd.npz", header, arrays)
    assert main(["upgrade-model", str(odd), "--out", str(tmp_path / "o2.npz")]) == 2
    assert "field 'kind'" in capsys.readouterr().err
    header, arrays = _read(small_models["gaussian"])
    header.update(format_version=99)
    future = _write(tmp_path / "future.npz", header, arrays)
    with pytest.raises(ModelFileError, match="field 'format_version' is 99"):
        GaussianRadar.load(future)
    assert not (tmp_path / "j2.npz").exists() and not (tmp_path / "o2.npz").exists()


def test_capabilities_are_declared_not_probed():
    assert has_capability(KDERadarModel(), "new_track") and has_capability(KDERadarModel(), "prev_output")
    assert has_capability(GaussianRadar(), "new_track") and not has_capability(GaussianRadar(), "prev_output")
    assert has_capability(LidarLWLR(), "extra_state") and not has_capability(LidarLWLR(), "new_track")
    assert takes_new_track(IdealRadar()) and takes_new_track(KDERadarModel())

    class Undeclared:  # takes the flags, but does not say so: called without them
        def sample_cycle(self, corners, prev_z, rng, new_track=None): ...

    assert not takes_new_track(Undeclared())
    with pytest.raises(ValueError, match="capability"):
        has_capability(KDERadarModel(), "new_tracks")
    for cls in MODELS:
        assert set(cls.CAPABILITIES) <= set(CAPABILITIES)


@pytest.mark.parametrize("cls", MODELS)
def test_one_contract(cls):
    assert issubclass(cls, SensorModel) and cls.KIND and cls.FORMAT_VERSION >= 1
    assert set(cls().get_params()) == set(cls._parameter_constraints)
    assert cls._hyperparameter_constraints is cls._parameter_constraints
    assert sorted(cls._UPGRADES) == list(range(1, cls.FORMAT_VERSION))  # one step per older version
    assert "Attributes:" in (cls.__doc__ or "")


def test_verbose_replaces_progress():
    assert KDERadarModel().verbose is False and LidarLWLR().verbose is False
    assert KDERadarModel().random_state == LidarLWLR().random_state == 0  # one seed semantics
    with pytest.warns(FutureWarning, match="progress"):
        assert LidarLWLR(progress=True).verbose is True
    with pytest.raises(TypeError, match="bogus"):
        LidarLWLR(bogus=1)
    log = record_rig_log(6, 12, 5, np.random.default_rng(0))
    with pytest.warns(FutureWarning, match="progress"):
        KDERadarModel(random_state=0).fit(log, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        KDERadarModel(random_state=0, verbose=False).fit(log)


def test_the_card_is_the_models(small_models, tmp_path):
    g = GaussianRadar.load(small_models["gaussian"])
    assert g.card_ == {}
    g.update_card({"log": {"file": "x.csv"}}, note="fitted for a test")
    path = g.save(tmp_path / "g.npz", card={"only_in_this_file": 1})
    back = GaussianRadar.load(path)
    assert back.card_ == {"log": {"file": "x.csv"}, "note": "fitted for a test", "only_in_this_file": 1}
    lidar = LidarLWLR.load(small_models["lidar"])
    assert "training" not in lidar.card_ and lidar.training_  # fitted attributes, not card entries
    lidar.update_card(gaussian_baseline={"sigma0": 0.01, "k_range": 0.001})
    assert vars(lidar.baseline()) == vars(GaussianLidar(sigma0=0.01, k_range=0.001))
    header, _ = _read(lidar.save(tmp_path / "l.npz"))
    assert header["card"]["training"] == lidar.training_ and header["card"]["gaussian_baseline"]["sigma0"] == 0.01
    assert KDERadarModel.load(small_models["kde"]).baseline() is None  # no kde_gaussian.npz beside it


@pytest.mark.parametrize(
    ("kde", "gaussian"), [("radar_kde.npz", "radar_gaussian.npz"), ("radar_kde_fast.npz", "radar_gaussian_fast.npz")]
)
def test_one_baseline_method_for_both_sensors(kde, gaussian, small_models):
    """``baseline()`` is the fitted baseline ready to simulate: the radar's file beside it, the lidar's card entry."""
    base = KDERadarModel.load(default_model_path(kde)).baseline()
    assert isinstance(base, GaussianRadar) and base.baseline() is None
    assert base._file == default_model_path(gaussian)
    assert baseline_file(default_model_path(kde)) == default_model_path(gaussian)
    assert isinstance(LidarLWLR.load(default_model_path("neato_lidar.npz")).baseline(), GaussianLidar)
    assert KDERadarModel(random_state=0).fit(record_rig_log(6, 12, 5, np.random.default_rng(0))).baseline() is None
