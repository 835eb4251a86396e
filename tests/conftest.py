"""Shared fixtures: the real-data folder (skips cleanly when absent); a rig radar log and its KDE model."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

_DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real"
REAL_DATA = Path(os.environ.get("SENSOR_ENVS_REAL_DATA", _DEFAULT)).resolve()


@pytest.fixture(scope="session")
def real_data() -> Path:
    """Path of ``../shared/data/real`` (or ``$SENSOR_ENVS_REAL_DATA``); skips the test when absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real data folder {REAL_DATA} is absent (set SENSOR_ENVS_REAL_DATA to point at it)")
    return REAL_DATA


@pytest.fixture(scope="session")
def astyx_log(real_data):
    """The whole Astyx HiRes2019 recording (400 frames) as a radar log (``load_astyx``), converted once for the
    session. Each frame is converted on its own, so its rows of some frames (``log.select(log["frame"] % 4 == 0)``)
    are ``load_astyx(root, frames=range(0, 400, 4))``: the tests take subsets of it."""
    from sensor_envs.radar.astyx import load_astyx

    return load_astyx(real_data / "astyx_hires2019")


@pytest.fixture
def compiled_kernels() -> None:
    """Skips the test unless the numba kernels are in use: numba installed and ``SENSOR_ENVS_NO_NUMBA`` unset."""
    pytest.importorskip("numba", reason="numba is not installed (the fast extra)")
    if os.environ.get("SENSOR_ENVS_NO_NUMBA", "") not in ("", "0"):
        pytest.skip("SENSOR_ENVS_NO_NUMBA is set: the numpy path is forced, there is no compiled kernel to compare")


@pytest.fixture(scope="session")
def rig_split():
    """A generic-rig radar log (60 sequences x 40 cycles x 8 targets, seed 11) as ``(train, test)`` blocks."""
    from sensor_envs.radar.rig import record_rig_log
    from sensor_envs.radar.validate import split_by_blocks

    log = record_rig_log(60, 40, 8, np.random.default_rng(11))
    return split_by_blocks(log, block=1000, n_folds=4, fold=0)


@pytest.fixture(scope="session")
def model(rig_split):
    """The KDE radar fitted on ``rig_split``'s training part at 1 s cycles (shared, never modified)."""
    from sensor_envs.radar.kde import KDERadarModel

    return KDERadarModel(random_state=0).fit(rig_split[0], cycle_time=1.0)


def _outward_rig_log(outward: float, rotation: float = 0.0):
    """A rig log whose detections sit ``outward`` m outward of the closest corner (radial noise 0.3 m, outward
    0.15 m), on both sides of the boresight, then rotated about the sensor by ``rotation`` [rad]."""
    from sensor_envs.geometry import from_polar_frame
    from sensor_envs.radar.alignment import rotate_offsets
    from sensor_envs.radar.log import RadarLog, target_tuples
    from sensor_envs.radar.rig import record_rig_log

    rng = np.random.default_rng(5)
    log = record_rig_log(16, 25, 8, rng)
    tt = target_tuples(log)
    det = np.isfinite(tt.z[:, 0])
    local = np.stack([rng.normal(0.0, 0.3, det.sum()), outward + rng.normal(0.0, 0.15, det.sum())], axis=1)
    meas = tt.corner[det] + rotate_offsets(from_polar_frame(local, tt.corner[det]), tt.corner[det], rotation)
    c = {k: v.copy() for k, v in log.columns.items()}
    c["meas_x"][tt.row[det]], c["meas_y"][tt.row[det]] = meas[:, 0], meas[:, 1]
    return RadarLog(c, source="outward log" if rotation == 0.0 else "rotated outward log")


def _rewrite_kde_file(model, path, version, drop=(), params=None):
    """Write ``model`` as a KDE file of format ``version`` whose params lack ``drop`` and take ``params``."""
    import json

    from sensor_envs.modelio import save_model_file
    from sensor_envs.radar.kde import KIND

    model.save(path)
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    header = json.loads(data.pop("__header__").tobytes().decode("utf-8"))
    for k in drop:
        header["params"].pop(k)
    header["params"].update(params or {})
    for k in ("kind", "format_version"):
        header.pop(k)
    save_model_file(path, KIND, version, header, data)
    return path


@pytest.fixture
def rewrite_kde_file():
    """``f(model, path, version, drop=(), params=None)``: a KDE file as an older format or with edited params."""
    return _rewrite_kde_file


@pytest.fixture(scope="session")
def outward_rig_log():
    """``f(outward, rotation=0)``: a rig log with detections ``outward`` m toward the outer end of the face,
    rotated about the sensor by ``rotation`` [rad] (``_outward_rig_log``)."""
    return _outward_rig_log
