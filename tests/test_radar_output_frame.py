"""The KDE radar's output frame (format 6): kernels on sensor-frame offsets, or in the corner's polar frame."""

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.geometry import from_polar_frame, polar_frame, to_polar_frame
from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import RadarLog, target_tuples, write_log
from sensor_envs.radar.validate import chi_square

OUTWARD = 0.5
"""Offset [m] of every detection toward the outer end of the face (away from the boresight)."""
WIDE = (400.0, 400.0, 0.12, 0.12)
"""A corner kernel of 20 m sd: it pools corners left and right of the boresight."""
FAST = {"cv_candidates": (0.1, 0.3, 1.0), "cv_max_tuples": 150, "random_state": 0}


@pytest.fixture(scope="module")
def outward_log(outward_rig_log) -> RadarLog:
    """A rig log whose detections sit ``OUTWARD`` m outward of the corner (plus noise), on both sides."""
    return outward_rig_log(OUTWARD)


@pytest.fixture(scope="module")
def pair(outward_log):
    """The same KDE (wide corner kernel) with sensor-frame and with polar-frame outputs."""
    kw = {"rel_variance": WIDE, **FAST}
    return tuple(KDERadarModel(output_frame=f, **kw).fit(outward_log) for f in ("cartesian", "polar"))


def test_polar_frame_is_orthonormal_mirrored_and_inverted():
    rng = np.random.default_rng(0)
    corner = rng.uniform(-50, 50, (200, 2)) + [60.0, 0.0]
    u, v = polar_frame(corner)
    np.testing.assert_allclose(np.sum(u * v, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.hypot(*v.T), 1.0)
    left = corner[:, 1] > 0
    assert (v[left, 1] > 0).all() and (v[~left, 1] < 0).all()  # outward: away from the boresight
    z = rng.normal(size=(200, 2))
    z[3] = np.nan
    back = from_polar_frame(to_polar_frame(z, corner), corner)
    np.testing.assert_allclose(back, z, atol=1e-12)
    assert np.isnan(back[3]).all()


def test_polar_outputs_keep_the_outward_offset_the_sensor_frame_pools_away(pair, outward_log):
    cart, polar = pair
    tt = target_tuples(outward_log)
    near = np.flatnonzero((np.abs(tt.corner[:, 1]) < 2.5) & (tt.corner[:, 0] > 10))[:60]
    assert near.size >= 20
    corners = tt.corner[near]
    out = {}
    for name, m in (("cartesian", cart), ("polar", polar)):
        mean, p_miss = m.mean_output(corners)  # start states: no previous output
        out[name] = to_polar_frame(mean, corners)[:, 1]
        assert np.all((p_miss > 0) & (p_miss < 1))
    assert abs(out["polar"].mean() - OUTWARD) < 0.1, out["polar"].mean()
    assert out["cartesian"].mean() < OUTWARD - 0.2, out["cartesian"].mean()  # left and right cancel
    # samples in the sensor frame follow mean_output
    rng = np.random.default_rng(1)
    z, _ = polar.sample(np.repeat(corners[:5], 4000, axis=0), rng)
    sim = np.nanmean(z.reshape(5, 4000, 2), axis=1)
    np.testing.assert_allclose(sim, polar.mean_output(corners[:5])[0], atol=0.05)


@pytest.mark.parametrize("with_prev", [False, True])
def test_polar_samples_pass_the_chi_square_test_in_the_output_frame(pair, outward_log, with_prev):
    """Two-stage samples against the binned analytic PDF (bins on the radial and outward axes)."""
    _, polar = pair
    tt = target_tuples(outward_log)
    r = np.flatnonzero(np.isfinite(tt.z_prev[:, 0]) & (tt.corner[:, 1] < -3))[11]
    state = np.concatenate([tt.corner[r], tt.z_prev[r]]) if with_prev else tt.corner[r]
    res = chi_square(polar, state, np.random.default_rng(8), n=60_000)
    assert res["p_value"] > 1e-3, res["p_value"]
    shifted = chi_square(_Shifted(polar), state, np.random.default_rng(8), n=60_000)
    assert shifted["p_value"] < 1e-6  # the test sees a 0.1 m bias along the outward axis


class _Shifted:
    """A model whose samples are 0.1 m further outward than its ``bin_probabilities`` say."""

    def __init__(self, m):
        self.m = m

    def sample(self, s, rng):
        z, src = self.m.sample(s, rng)
        return z + from_polar_frame(np.tile([0.0, 0.1], (len(z), 1)), s[:, :2]), src

    def to_output_frame(self, z, c):
        return self.m.to_output_frame(z, c)

    def bin_probabilities(self, s, ex, ey):
        return self.m.bin_probabilities(s, ex, ey)


@pytest.mark.slow
@pytest.mark.parametrize("with_prev", [False, True])
def test_polar_log_prob_is_a_density_in_the_sensor_frame(pair, outward_log, with_prev):
    _, polar = pair
    tt = target_tuples(outward_log)
    rows = np.flatnonzero(np.isfinite(tt.z_prev[:, 0]) & (np.abs(tt.corner[:, 1]) > 3))[[7, 19][with_prev] :][:1]
    g = np.linspace(-3.0, 3.0, 97)  # steps of 0.0625 m, below the smallest bandwidth candidate (0.1 m)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    zz = np.stack([gx.ravel(), gy.ravel()], axis=1)
    cell = (g[1] - g[0]) ** 2
    for r in rows:
        state = np.concatenate([tt.corner[r], tt.z_prev[r]]) if with_prev else tt.corner[r]
        states = np.repeat(state[None], zz.shape[0], axis=0)
        mass = np.exp(polar.log_prob(zz, states)).sum() * cell
        p_miss = np.exp(polar.log_prob(np.full((1, 2), np.nan), state[None]))[0]
        assert abs(mass + p_miss - 1.0) < 0.01, (mass, p_miss)


def test_sample_and_log_prob_pass_previous_outputs_in_the_sensor_frame(pair, outward_log):
    """A chain fed its own (sensor-frame) outputs keeps the outward offset; log_prob scores them finite."""
    _, polar = pair
    tt = target_tuples(outward_log)
    corners = np.repeat(tt.corner[np.abs(tt.corner[:, 1]) > 3][:40], 50, axis=0)
    rng = np.random.default_rng(2)
    prev = np.full_like(corners, np.nan)
    for _ in range(6):  # one iteration per cycle
        z, _ = polar.sample_cycle(corners, prev, rng)
        prev = z
    det = np.isfinite(z[:, 0])
    assert abs(to_polar_frame(z[det], corners[det])[:, 1].mean() - OUTWARD) < 0.1
    lp = polar.log_prob(z[det][:100], np.concatenate([corners, prev], axis=1)[det][:100])
    assert np.isfinite(lp).all()


def test_cartesian_default_and_polar_file_round_trip(pair, tmp_path):
    cart, polar = pair
    assert KDERadarModel().output_frame == "cartesian"
    loaded = KDERadarModel.load(polar.save(tmp_path / "p.npz"))
    assert loaded.output_frame == "polar"
    states = np.concatenate(
        [polar.states_[:200, :2], from_polar_frame(polar.states_[:200, 2:], polar.states_[:200, :2])], 1
    )
    a = polar.sample(states, np.random.default_rng(3))
    b = loaded.sample(states, np.random.default_rng(3))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(cart.to_output_frame(states[:5, 2:], states[:5, :2]), states[:5, 2:])


def test_format5_files_load_with_sensor_frame_outputs_and_format6_must_name_it(pair, tmp_path, rewrite_kde_file):
    cart, _ = pair
    old = KDERadarModel.load(rewrite_kde_file(cart, tmp_path / "f5.npz", 5, ("output_frame",)))
    assert old.output_frame == "cartesian"
    states = cart.states_[::53]
    np.testing.assert_array_equal(
        old.sample(states, np.random.default_rng(4))[0], cart.sample(states, np.random.default_rng(4))[0]
    )
    with pytest.raises(ModelFileError, match="params.output_frame"):
        KDERadarModel.load(rewrite_kde_file(cart, tmp_path / "f6.npz", 6, ("output_frame",)))
    bad = rewrite_kde_file(cart, tmp_path / "bad.npz", 6, params={"output_frame": "spherical"})
    with pytest.raises(ModelFileError, match="output_frame"):
        KDERadarModel.load(bad)


def test_cli_fits_polar_outputs(outward_log, tmp_path):
    log = tmp_path / "log.csv"
    write_log(outward_log, log)
    out = tmp_path / "m.npz"
    assert main(["fit", "radar", str(log), "--out", str(out), "--output-frame", "polar"]) == 0
    m = KDERadarModel.load(out)
    assert m.output_frame == "polar" and m.card_["output_frame"] == "polar"
