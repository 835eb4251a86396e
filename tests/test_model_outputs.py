"""Behaviour lock of the fitted sensor models: the same samples and log-probabilities for the same seeds.

Reference outputs live in ``tests/data/model_outputs.npz``: for every shipped model file (keyed by its
sha256), ``sample``/``sample_cycle``/``sample_clutter`` draws for fixed seeds and ``log_prob`` on a fixed
set of states; and, independent of the shipped files, small fits of each model class on seeded rig logs.
A refactor must reproduce them (the draws' discrete parts exactly; the shipped files' numbers to 1e-12
relative; a fit's numbers to 1e-6 relative, :data:`FIT_RTOL`: a fit's float32 tables come out of long sums
whose last bit depends on the numpy/BLAS build, and the tests run on whatever build the registry serves;
with ``SENSOR_ENVS_BIT_EXACT=1`` every array bit for bit, as on the machine that recorded them).

A shipped model refitted on purpose has another sha256: its cases skip with a message. Regenerate the
file then with ``python tests/test_model_outputs.py --regenerate`` (on the code before the refactor).
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sensor_envs.lidar.lwlr import LidarLWLR
from sensor_envs.lidar.rig import NeatoRig
from sensor_envs.maps import load_map
from sensor_envs.modelio import default_model_path, file_sha256
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.rig import record_rig_log

REFERENCE = Path(__file__).parent / "data" / "model_outputs.npz"
SHIPPED = {
    "radar_kde": KDERadarModel,
    "radar_kde_fast": KDERadarModel,
    "radar_gaussian": GaussianRadar,
    "radar_gaussian_fast": GaussianRadar,
    "neato_lidar": LidarLWLR,
}
ROOM = load_map("seed_room").segments


def _radar_states(n: int = 300) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners over the field of view, previous outputs (a third missing) and new-track flags."""
    rng = np.random.default_rng(12345)
    r, az = rng.uniform(2.0, 90.0, n), rng.uniform(-0.6, 0.6, n)
    corners = np.stack([r * np.cos(az), r * np.sin(az)], axis=1)
    prev = rng.normal(0.0, 0.4, (n, 2))
    gone = rng.random(n) < 0.35
    prev[gone] = np.nan
    new = gone & (rng.random(n) < 0.5)
    return corners, prev, new


def _radar_outputs(model: KDERadarModel | GaussianRadar) -> dict[str, np.ndarray]:
    corners, prev, new = _radar_states()
    state = np.concatenate([corners, prev], axis=1)
    out: dict[str, np.ndarray] = {}
    z, src = model.sample(state, np.random.default_rng(7))
    out["sample_z"], out["sample_src"] = z, src
    z2, src2 = model.sample_cycle(corners, prev, np.random.default_rng(8), new_track=new)
    out["cycle_z"], out["cycle_src"] = z2, src2
    out["clutter"] = np.concatenate([model.sample_clutter(np.random.default_rng(s)) for s in range(5)])
    probe = np.where(np.isnan(z2), np.nan, z2 + 0.05)
    out["log_prob"] = model.log_prob(probe, state)
    out["log_prob_new"] = model.log_prob(z2, state, new_track=new)
    out["log_prob_corners"] = model.log_prob(z, corners)
    return out


def _lidar_outputs(model: LidarLWLR) -> dict[str, np.ndarray]:
    from sensor_envs.geometry import sample_free_poses

    poses = sample_free_poses(ROOM, 6, np.random.default_rng(3), 0.3)
    scans = model.sample(poses, ROOM, np.random.default_rng(4))
    reps = model.sample(poses[:2], ROOM, np.random.default_rng(5), n_repeats=3)
    return {
        "scans": scans,
        "repeats": reps,
        "log_prob": model.log_prob(scans, poses, ROOM),
        "log_prob_repeats": model.log_prob(reps, poses[:2], ROOM),
    }


def _fit_cases() -> dict[str, Callable[[], dict[str, np.ndarray]]]:
    """Small fits on seeded rig logs: every fitted array and the fitted model's outputs."""

    def radar_log():
        return record_rig_log(8, 15, 6, np.random.default_rng(0))

    def kde_paper():
        m = KDERadarModel(random_state=0).fit(radar_log(), cycle_time=1.0)
        return {"log_h": m.log_h_, "scale": m.scale_, **_radar_outputs(m)}

    def kde_recipe():
        m = KDERadarModel(
            random_state=0,
            relevance="cv_state",
            relevance_candidates=(6.0, 24.0),
            relevance_candidates_prev=(0.03, 0.24),
            output_frame="polar",
            azimuth_bias="fit",
            bandwidth_scale=0.5,
            start_bandwidth_scale=0.7,
            tail_weight=0.1,
            sampler="bucket",
            cv_min_tuples=10,
        ).fit(radar_log(), cycle_time=1.0)
        return {"log_h": m.log_h_, "scale": m.scale_, "bias": np.array([m.azimuth_bias_]), **_radar_outputs(m)}

    def kde_extra():
        m = KDERadarModel(random_state=1, state_transform="polar", extra_state=("range",), sampler="ball")
        m.fit(radar_log(), cycle_time=1.0)
        corners, prev, _ = _radar_states(50)
        extra = np.random.default_rng(2).normal(0, 2, (50, 1))
        z, src = m.sample(np.concatenate([corners, prev], axis=1), np.random.default_rng(3), extra=extra)
        lp = m.log_prob(z, np.concatenate([corners, prev], axis=1), extra=extra)
        return {"log_h": m.log_h_, "extra_scale": m.extra_scale_, "z": z, "src": src, "log_prob": lp}

    def gaussian():
        m = GaussianRadar().fit(radar_log(), cycle_time=1.0)
        return {"mean": m.mean_, "cov": m.cov_, **_radar_outputs(m)}

    def lidar(variant: str, **kw):
        def run():
            log, _ = NeatoRig().record(ROOM, np.random.default_rng(0), n_poses=8, repeats=2)
            m = LidarLWLR(variant=variant, n_folds=3, random_state=0, **kw).fit(log)
            return {"tables": m.tables_[:, ::7, ::3, ::2], **_lidar_outputs(m)}  # a lattice of the table

        return run

    return {
        "fit_kde_paper": kde_paper,
        "fit_kde_recipe": kde_recipe,
        "fit_kde_extra": kde_extra,
        "fit_gaussian": gaussian,
        "fit_lidar_seed": lidar("seed"),
        "fit_lidar_extended": lidar("extended"),
    }


def _shipped_outputs(name: str) -> tuple[str, dict[str, np.ndarray]]:
    path = default_model_path(f"{name}.npz")
    model = SHIPPED[name].load(path)
    out = _lidar_outputs(model) if name == "neato_lidar" else _radar_outputs(model)
    return file_sha256(path), out


def _reference() -> dict[str, np.ndarray]:
    if not REFERENCE.is_file():
        pytest.skip(f"{REFERENCE} is absent (python tests/test_model_outputs.py --regenerate)")
    with np.load(REFERENCE, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


FIT_RTOL = 1e-6
"""Relative tolerance of a fit's floating outputs (a few float32 ulps of its tables)."""


def _compare(case: str, got: dict[str, np.ndarray], ref: dict[str, np.ndarray], rtol: float = 1e-12) -> None:
    keys = sorted(k.split("/", 1)[1] for k in ref if k.startswith(case + "/") and not k.endswith("#sha256"))
    assert keys and sorted(got) == keys, (sorted(got), keys)
    exact = os.environ.get("SENSOR_ENVS_BIT_EXACT") == "1"
    for k in keys:
        a, b = np.asarray(got[k]), ref[f"{case}/{k}"]
        assert a.shape == b.shape and a.dtype == b.dtype, (case, k, a.shape, b.shape, a.dtype, b.dtype)
        if exact or a.dtype.kind in "iub":
            assert _digest(a) == _digest(b), f"{case}/{k} differs"
        else:
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=f"{case}/{k}: NaN pattern")
            np.testing.assert_allclose(a, b, rtol=rtol, atol=1e-300, err_msg=f"{case}/{k}")


def _digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_models_draw_and_score_as_recorded(name):
    path = default_model_path(f"{name}.npz")
    if not path.is_file():
        pytest.skip(f"shipped model {path.name} is absent")
    ref = _reference()
    sha, got = _shipped_outputs(name)
    recorded = str(ref[f"{name}/#sha256"])
    if sha != recorded:
        pytest.skip(f"{path.name} was refitted (sha256 {sha[:12]} != {recorded[:12]}); regenerate {REFERENCE.name}")
    _compare(name, got, ref)


SLOW_FITS = {"fit_kde_recipe", "fit_kde_extra", "fit_lidar_extended"}


@pytest.mark.parametrize(
    "case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW_FITS else c for c in sorted(_fit_cases())]
)
def test_fits_reproduce_the_recorded_models(case):
    ref = _reference()
    _compare(case, _fit_cases()[case](), ref, rtol=FIT_RTOL)


def test_reference_covers_every_shipped_model_and_fit():
    ref = _reference()
    cases = {k.split("/", 1)[0] for k in ref}
    assert cases == set(SHIPPED) | set(_fit_cases())


def _regenerate() -> None:
    arrays: dict[str, np.ndarray] = {}
    for name in SHIPPED:
        sha, out = _shipped_outputs(name)
        arrays[f"{name}/#sha256"] = np.array(sha)
        arrays.update({f"{name}/{k}": np.asarray(v) for k, v in out.items()})
    for case, run in _fit_cases().items():
        arrays.update({f"{case}/{k}": np.asarray(v) for k, v in run().items()})
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, **arrays)
    print(f"wrote {REFERENCE} ({len(arrays)} arrays)")


if __name__ == "__main__":
    if sys.argv[1:] != ["--regenerate"]:
        sys.exit("usage: python tests/test_model_outputs.py --regenerate")
    _regenerate()
