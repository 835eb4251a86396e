"""fdlibm's arccos and tangent (sensor_envs.trig): accurate to about an ulp, the same bits compiled and in numpy."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest

from sensor_envs import trig
from sensor_envs.jit import compiled


def _ulps(value: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """|value - exact| in units in the last place of the float64 result (``exact`` in long double)."""
    return np.abs(value.astype(np.longdouble) - exact) / np.spacing(np.abs(exact.astype(np.float64)))


def _acos_points() -> np.ndarray:
    rng = np.random.default_rng(0)
    edges = [0.0, 1e-300, 0.5, np.nextafter(0.5, 1), np.nextafter(0.5, 0), np.nextafter(1, 0), 1.0]
    cosines = np.cos(rng.uniform(0, 1.6, 9999))
    return np.concatenate([rng.uniform(0, 1, 200_000), np.linspace(0, 1, 100_001), cosines, edges])


def _tan_points() -> np.ndarray:
    rng = np.random.default_rng(1)
    d = trig._TAN_DIRECT
    edges = [0.0, 1e-300, d, np.nextafter(d, 0), trig._PIO2_1 - d, np.nextafter(trig._PIO2_1 - d, 2), 1.5707963]
    return np.concatenate([rng.uniform(0, 1.5707963, 200_000), np.linspace(0, 1.5707963, 100_001), edges])


def test_acos_unit_is_within_an_ulp():
    x = _acos_points()
    got = trig.acos_unit(x)
    assert got.shape == x.shape and got.dtype == np.float64
    exact = np.arccos(x.astype(np.longdouble))
    assert _ulps(got, exact).max() <= 1.0
    assert np.all(got[x == 1.0] == 0.0) and np.all(got[x == 0.0] == np.float64(np.pi / 2))
    assert np.isnan(trig.acos_unit(np.array([np.nan, 0.3]))[0])
    assert trig.acos_unit(np.full((3, 4), 0.25)).shape == (3, 4)


def test_tan_half_pi_is_within_three_ulps_and_falls_back_outside():
    x = _tan_points()
    got = trig.tan_half_pi(x)
    exact = np.tan(x.astype(np.longdouble))
    assert _ulps(got[x > 0], exact[x > 0]).max() <= 3.0
    outside = np.array([-0.3, -1e-3, 2.0, 4.0, -np.inf, np.inf, np.nan])
    libm = [math.tan(v) if math.isfinite(v) else math.nan for v in outside]  # libm's, not numpy's own SIMD tan
    assert np.array_equal(trig.tan_half_pi(outside), libm, equal_nan=True)


def test_shapes_are_kept_and_the_gaussian_lidar_takes_scalars():
    """0-d in, 0-d out (a scalar call of GaussianLidar.sigma worked before the fast tangent; so must it now)."""
    from sensor_envs.lidar.sensors import GaussianLidar

    assert trig.acos_unit(0.5).shape == () and trig.tan_half_pi(0.3).shape == ()
    assert trig.tan_half_pi(np.full((4, 6), 0.3)[:, ::2]).shape == (4, 3)  # not contiguous
    lidar = GaussianLidar()
    sigma = lidar.sigma(2.0, 0.3)
    assert np.shape(sigma) == () and np.isclose(sigma, 0.005 + 0.0028 + 0.01 * np.tan(0.3))
    # np.nan_to_num's rules: NaN incidence as 0, +inf capped at alpha_max, -inf as the lowest float64
    got = lidar.tan_incidence(np.array([np.nan, np.inf, -np.inf, 0.2]))
    assert np.array_equal(got, [0.0, trig.tan_half_pi(lidar.alpha_max), math.tan(np.finfo(np.float64).min), got[3]])


def test_compiled_and_numpy_paths_give_the_same_bits(compiled_kernels):
    """The numba loops (this process) and the numpy path (a process with SENSOR_ENVS_NO_NUMBA=1): equal bits."""
    code = (
        "import sys, numpy as np; from sensor_envs import trig; x, t = np.load(sys.argv[1]), np.load(sys.argv[2]);"
        "np.save(sys.argv[1], trig.acos_unit(x)); np.save(sys.argv[2], trig.tan_half_pi(t))"
    )
    assert compiled(trig._acos_unit_loops) is not None and compiled(trig._tan_half_pi_loops) is not None
    x, t = np.concatenate([_acos_points(), [np.nan]]), np.concatenate([_tan_points(), [np.nan, -0.5, 3.0]])
    with tempfile.TemporaryDirectory() as d:
        fx, ft = os.path.join(d, "x.npy"), os.path.join(d, "t.npy")
        np.save(fx, x)
        np.save(ft, t)
        env = {**os.environ, "SENSOR_ENVS_NO_NUMBA": "1"}
        subprocess.run([sys.executable, "-c", code, fx, ft], check=True, env=env)
        acos_numpy, tan_numpy = np.load(fx), np.load(ft)
    assert np.array_equal(trig.acos_unit(x), acos_numpy, equal_nan=True)
    assert np.array_equal(trig.tan_half_pi(t), tan_numpy, equal_nan=True)


@pytest.mark.slow
@pytest.mark.parametrize("lidar", ["ideal", "gaussian"])
def test_vector_step_does_not_page_fault(lidar):
    """A 64-robot vector step reuses freed heap (sensor_envs.heap): under 5 minor page faults a step.

    Without the tuning glibc's dynamic thresholds decide: 0 to ~200 faults a step from run to run.
    """
    if not sys.platform.startswith("linux"):
        pytest.skip("glibc's malloc thresholds: Linux only")
    code = f"""
import resource, numpy as np, gymnasium as gym, sensor_envs
from sensor_envs.heap import keep_freed_heap
env = gym.make_vec("sensor_envs/Neato-v0", num_envs=64, vectorization_mode="vector_entry_point", lidar="{lidar}",
                   tune_heap=True)
env.reset(seed=0)
acts = np.random.default_rng(0).uniform(-1, 1, (60, 64, 2)).astype(np.float32)
for a in acts[:10]:
    env.step(a)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for a in acts[10:]:
    env.step(a)
print(keep_freed_heap(), (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 50)
"""

    def run(**env: str) -> tuple[str, float]:
        out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, env=env)
        applied, faults = out.stdout.split()
        return applied, float(faults)

    applied, faults = run(**os.environ)
    assert applied == "True" and faults < 5, (applied, faults)
    assert run(**os.environ, SENSOR_ENVS_NO_HEAP_TUNING="1")[0] == "False"
