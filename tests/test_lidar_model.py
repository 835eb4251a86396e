from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from scipy import stats
from sklearn.exceptions import NotFittedError

import sensor_envs  # noqa: F401  (registers the ids)
from sensor_envs.cli.main import main as cli_main
from sensor_envs.lidar.lwlr import (
    P_EPS,
    LearnedLidar,
    LidarLWLR,
    lidar_features,
    load_learned_lidar,
    lwlr,
    mixture_log_prob,
    null_count_log_prob,
)
from sensor_envs.lidar.rig import NeatoRig
from sensor_envs.maps import load_map
from sensor_envs.modelio import ModelFileError

ROOM = load_map("seed_room").segments
SMALL = {
    "n_folds": 3,
    "h_range_grid": (0.4, 1.6),
    "h_alpha_grid": (0.5,),
    "h_bearing_grid": (0.0, 2.0),
    "verbose": False,
}
ALPHA = 1e-3  # each goodness-of-fit test below fails with probability ~1e-3 under a correct sampler


@pytest.fixture(scope="module")
def rig_fit():
    """An exact-pose rig (no pose/map error, so the per-bearing bias is identifiable) and fitted models."""
    rig = NeatoRig(pose_sd=(0.0, 0.0), map_sd=0.0, null_rho=0.0)
    log, truth = rig.record(ROOM, np.random.default_rng(1), n_poses=30, repeats=20)
    ext = LidarLWLR(variant="extended", **SMALL).fit(log)
    clean_rig = NeatoRig(pose_sd=(0.0, 0.0), map_sd=0.0, spur_prone=0.0, null_rho=0.0)
    clean_log, _ = clean_rig.record(ROOM, np.random.default_rng(2), n_poses=30, repeats=20)
    seed = LidarLWLR(variant="seed", **SMALL).fit(clean_log)
    return log, truth, ext, seed


def _table(model: LidarLWLR, name: str) -> np.ndarray:
    return model.tables_[model.param_names_.index(name)]


@pytest.mark.parametrize("variant", ["extended", "seed"])
def test_fit_recovers_rig_bias_and_blocked_bearings(rig_fit, variant):
    _, truth, ext, seed = rig_fit
    model = ext if variant == "extended" else seed
    ir = int(np.searchsorted(model.range_grid_, 1.0))
    bias = _table(model, "bias")[:, ir, 2]  # r = 1 m, alpha ~ 0.4 rad
    ok = ~truth["blocked"]
    assert np.corrcoef(bias[ok], truth["bias"][ok])[0, 1] > 0.95
    assert np.abs(bias[ok] - truth["bias"][ok]).mean() < 0.15 * truth["bias"].std()
    p_null = _table(model, "p_null")
    assert (p_null[truth["blocked"]] > 0.99).all()
    assert p_null[ok][:, ir, 2].max() < 0.5


def test_extended_sees_spurious_returns_near_posts(rig_fit):
    _, _, ext, _ = rig_fit
    rig = NeatoRig()
    near, far = rig.near_posts(), ~rig.near_posts() & ~rig.blocked_mask()
    p_spur = _table(ext, "p_spur")[:, :20].mean(axis=(1, 2))
    assert p_spur[near].mean() > 5 * p_spur[far].mean()
    assert abs(ext.spur_mu_ - rig.spur_value[0]) < 0.05


def test_samples_match_params(rig_fit):
    log, _, ext, _ = rig_fit
    rng = np.random.default_rng(5)
    p = ext.params_full(log.poses[:3], ROOM)
    n = 400
    pe = {k: v[..., None] for k, v in p.items()}
    x = ext.sample_from_params(pe, rng, p["mu"].shape + (n,))
    # null counts: chi-square over cells with 0 < p_null < 1
    cells = (p["p_null"] > 0.01) & (p["p_null"] < 0.99)
    obs = (x == 0).sum(-1)[cells]
    exp = n * p["p_null"][cells]
    chi2 = (((obs - exp) ** 2) / (exp * (1 - p["p_null"][cells]))).sum()
    assert stats.chi2.sf(chi2, cells.sum()) > ALPHA
    # spurious counts: pooled binomial
    n_spur = (x > ext.spur_above).sum()
    expected = n * p["p_spur"].sum()
    assert abs(n_spur - expected) < 4 * np.sqrt(expected)
    # in-range readings: standardised values are N(0, 1) (KS)
    inr = (x > 0) & (x <= ext.spur_above)
    z = ((x - pe["mu"]) / pe["sigma"])[inr]
    assert stats.kstest(z, "norm").pvalue > ALPHA


@pytest.mark.parametrize("which", [2, 3])
def test_compiled_scan_gives_the_numpy_numbers(rig_fit, which, compiled_kernels):
    """The simulator's compiled lookup-and-draw passes (numba) and the two numpy methods: same readings, bit for bit.

    Both variants, shrunk bias, hits and misses (``inf`` range, NaN incidence), ranges and incidences beyond
    the grids, one and several leading axes; the draws come from the same generator states.
    """
    from sensor_envs.jit import compiled
    from sensor_envs.lidar import local_regression, scan_sampler
    from sensor_envs.rng import RowGenerators

    passes = (
        scan_sampler.scan_nodes,
        scan_sampler.scan_gather,
        scan_sampler.scan_readings,
        local_regression._bilinear_loops,
    )
    assert all(compiled(f) is not None for f in passes)
    model = rig_fit[which]
    k = model.tables_.shape[1]
    rng = np.random.default_rng(7)
    r = rng.uniform(-0.5, 1.3 * model.max_range, size=(6, k))
    r[rng.random(r.shape) < 0.2] = np.inf
    a = np.where(np.isfinite(r), rng.uniform(-0.2, 1.8, size=r.shape), np.nan)
    fitted = model.bias_shrinkage_
    for shrink in (0.0, 0.4, 1.0, fitted):  # 1.0: no bias lookup; the fixture's model is shared: its own value last
        model.bias_shrinkage_ = shrink
        for rows in (r, r[0]):
            gens = [[np.random.default_rng(s) for s in range(6)] for _ in range(2)]
            draw = [RowGenerators(g) if rows.ndim == 2 else g[0] for g in gens]
            ref = model.sample_from_params(
                model.params_from_features(rows, a[: len(rows)] if rows.ndim == 2 else a[0]), draw[0]
            )
            fast = model.sample_scan(rows, a[: len(rows)] if rows.ndim == 2 else a[0], draw[1])
            assert fast.shape == ref.shape and np.array_equal(fast, ref)
            assert 0 < (ref == 0).mean() < 1
            again = [np.random.default_rng(s) for s in range(6)]  # the sensor interface's nulls: NaN, same draws
            rows_a = a[: len(rows)] if rows.ndim == 2 else a[0]
            again_rng = RowGenerators(again) if rows.ndim == 2 else again[0]
            nan_null = model.sample_scan(rows, rows_a, again_rng, null=np.nan)
            assert np.array_equal(nan_null, np.where(ref == 0, np.nan, ref), equal_nan=True)
    aq = np.nan_to_num(a)
    rq = np.where(np.isfinite(r), r, model.range_grid_[-1])
    args = (model.tables_, model.range_grid_, model.alpha_grid_, rq, aq)
    assert np.array_equal(local_regression._bilinear(*args), local_regression._bilinear_numpy(*args))


def test_log_prob_integrates_to_one(rig_fit):
    log, _, ext, seed = rig_fit
    grid = np.arange(-0.5, 25.0, 2e-5) + 1e-6  # never exactly 0 (that is the null atom)
    for model in (ext, seed):
        p = model.params_full(log.poses[:1], ROOM)
        for k in (10, 45, 200):  # a few bearings (none blocked)
            pk = {key: v[0, k] for key, v in p.items()}
            dens = np.exp(mixture_log_prob(grid, pk, model.spur_mu_, model.spur_sigma_))
            total = np.trapezoid(dens, grid) + np.exp(mixture_log_prob(np.array(0.0), pk, 0.0, 1.0))
            assert total == pytest.approx(1.0, abs=2e-3)


def test_log_prob_matches_brute_force(rig_fit):
    log, _, ext, _ = rig_fit
    p = {k: v[0, 7] for k, v in ext.params_full(log.poses[:1], ROOM).items()}
    x = np.array([0.0, p["mu"] + 0.01, 16.8, np.nan])
    lp = mixture_log_prob(x, p, ext.spur_mu_, ext.spur_sigma_)
    s = np.hypot(p["sigma"], p["tau"])
    main = (1 - p["p_out"]) * stats.norm.pdf(x[1:3], p["mu"], s) + p["p_out"] / p["out_range"] * (x[1:3] <= 5.0)
    ref = (1 - p["p_null"] - p["p_spur"]) * main + p["p_spur"] * stats.norm.pdf(x[1:3], ext.spur_mu_, ext.spur_sigma_)
    np.testing.assert_allclose(lp[0], np.log(p["p_null"]))
    np.testing.assert_allclose(lp[1:3], np.log(ref), rtol=1e-9)
    assert np.isnan(lp[3])
    assert ext.log_prob(log.ranges[:2], log.poses[:2], ROOM).shape == log.ranges[:2].shape


def test_null_count_log_prob_is_a_beta_binomial():
    n, q = 12, 0.3
    k = np.arange(n + 1)
    np.testing.assert_allclose(null_count_log_prob(k, n, q, 0.0), stats.binom.logpmf(k, n, q), rtol=1e-12)
    grid = np.linspace(0.0, 1.0, 200_001)
    for rho in (0.1, 0.2):  # brute force: the binomial mixed over Beta(q c, (1 - q) c), c = 1 / rho - 1
        c = 1 / rho - 1
        dens = stats.beta.pdf(grid, q * c, (1 - q) * c)
        ref = np.array([np.trapezoid(stats.binom.pmf(kk, n, grid) * dens, grid) for kk in k])
        np.testing.assert_allclose(np.exp(null_count_log_prob(k, n, q, rho)), ref, rtol=1e-5)
    for rho in (0.7, 0.95):  # U-shaped mixing density: check normalisation, mean and variance
        pmf = np.exp(null_count_log_prob(k, n, q, rho))
        assert pmf.sum() == pytest.approx(1.0, abs=1e-12)
        assert pmf @ k == pytest.approx(n * q, rel=1e-9)
        assert pmf @ (k - n * q) ** 2 == pytest.approx(n * q * (1 - q) * (1 + (n - 1) * rho), rel=1e-9)


@pytest.mark.parametrize("outcome", ["null", "spur"])
@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_sampled_null_and_spurious_counts_follow_the_beta_binomial(rig_fit, rho, outcome):
    _, _, ext, _ = rig_fit
    cells, n, q = 4000, 20, 0.3
    null = outcome == "null"
    p = {
        "p_null": np.full((cells, 1), q if null else 1e-4),
        "p_spur": np.full((cells, 1), 1e-4 if null else q),
        "mu": np.full((cells, 1), 2.0),
        "sigma": np.full((cells, 1), 0.01),
        "tau": np.zeros((cells, 1)),
        "p_out": np.zeros((cells, 1)),
        "out_range": np.full((cells, 1), 5.0),
        "null_rho": np.full((cells, 1), rho if null else 0.0),
        "spur_rho": np.full((cells, 1), 0.0 if null else rho),
    }
    x = ext.sample_from_params(p, np.random.default_rng(11), (cells, n), pose_uncertainty=True)
    hits = (x == 0) if null else (x > ext.spur_above)
    obs = np.bincount(hits.sum(1), minlength=n + 1)
    exp = cells * np.exp(null_count_log_prob(np.arange(n + 1), n, q, rho))
    keep = exp >= 5  # pool the sparse tails into one bin
    o, e = np.append(obs[keep], obs[~keep].sum()), np.append(exp[keep], exp[~keep].sum())
    o, e = o[e > 0], e[e > 0]
    assert stats.chi2.sf(((o - e) ** 2 / e).sum(), o.size - 1) > ALPHA


def test_fit_finds_persistent_nulls(rig_fit):
    log, _, _, _ = rig_fit
    rng = np.random.default_rng(4)
    dead_cells = np.where(rng.random(log.ranges.shape[:2] + (1,)) < 0.3, 0.0, log.ranges)
    dead_readings = np.where(rng.random(log.ranges.shape) < 0.3, 0.0, log.ranges)
    kw = dict(SMALL, h_bearing_grid=(0.0,), degree_grid=(1,))
    persistent = LidarLWLR(variant="extended", **kw).fit(dataclasses.replace(log, ranges=dead_cells))
    independent = LidarLWLR(variant="extended", **kw).fit(dataclasses.replace(log, ranges=dead_readings))
    assert persistent.null_rho_ >= 0.5
    assert independent.null_rho_ <= 0.1
    s = persistent.cv_scores_["null_rho"]
    assert s["ll_per_reading_best"] > s["ll_per_reading_independent"]


def test_fit_finds_persistent_spurious_returns(rig_fit):
    log, _, ext, _ = rig_fit
    x = log.ranges
    assert np.any(x > ext.spur_above)  # the rig's spurious-prone cells
    assert ext.spur_rho_ >= 0.5
    s = ext.cv_scores_["spur_rho"]
    assert s["ll_per_reading_best"] > s["ll_per_reading_independent"]
    # the same share of spurious readings, scattered independently over the readings: no persistence
    rng = np.random.default_rng(5)
    share = float(np.nanmean(np.where(np.isnan(x), np.nan, x > ext.spur_above)))
    clean = np.where(x > ext.spur_above, 0.0, x)
    scattered = np.where((rng.random(x.shape) < share) & (clean > 0), 16.9, clean)
    kw = dict(SMALL, h_bearing_grid=(0.0,), degree_grid=(1,))
    independent = LidarLWLR(variant="extended", **kw).fit(dataclasses.replace(log, ranges=scattered))
    assert independent.spur_rho_ <= 0.1


def test_rig_nulls_persist_per_cell_and_the_fit_finds_them():
    from sensor_envs.lidar.validate import log_statistics

    log, _ = NeatoRig(null_rho=0.9).record(ROOM, np.random.default_rng(6), n_poses=12, repeats=40)
    independent, _ = NeatoRig().record(ROOM, np.random.default_rng(6), n_poses=12, repeats=40)
    mixed, mixed_ind = log_statistics(log)["mixed_null_cells"], log_statistics(independent)["mixed_null_cells"]
    assert mixed < 0.5 * mixed_ind
    assert abs(log_statistics(log)["null_fraction"] - log_statistics(independent)["null_fraction"]) < 0.02
    kw = dict(SMALL, h_bearing_grid=(0.0,), degree_grid=(1,))
    assert LidarLWLR(variant="extended", **kw).fit(log).null_rho_ >= 0.5


def test_lwlr_matches_brute_force_weighted_least_squares():
    rng = np.random.default_rng(3)
    t_r, t_a = rng.uniform(0.3, 3.0, (25, 4)), rng.uniform(0.0, 1.2, (25, 4))
    y = (0.01 * t_r + 0.02 * t_a + 0.002 * rng.standard_normal((25, 4)))[..., None]
    w = np.ones((25, 4))
    q_r, q_a = np.array([[1.0, 2.0, 1.5, 0.7]]), np.array([[0.3, 0.6, 0.1, 1.0]])
    got = lwlr(q_r, q_a, t_r, t_a, y, w, 0.5, 0.4)[0, 0, 0, :, 0]
    const = lwlr(q_r, q_a, t_r, t_a, y, w, 0.5, 0.4, degrees=(0,))[0, 0, 0, :, 0]
    for k in range(4):
        dr, da = (t_r[:, k] - q_r[0, k]) / 0.5, (t_a[:, k] - q_a[0, k]) / 0.4
        ww = np.exp(-0.5 * (dr**2 + da**2))
        x = np.column_stack([np.ones(25), dr, da])
        a = x.T @ (ww[:, None] * x) + np.diag([1e-3, 1e-2, 1e-2])
        prior = y[:, k, 0].mean()
        b = x.T @ (ww * y[:, k, 0]) + np.array([1e-3 * prior, 0, 0])
        assert got[k] == pytest.approx(np.linalg.solve(a, b)[0], rel=1e-9)
        assert const[k] == pytest.approx((ww @ y[:, k, 0] + 1e-3 * prior) / (ww.sum() + 1e-3), rel=1e-9)


def test_save_load_round_trip(rig_fit, tmp_path):
    log, _, ext, _ = rig_fit
    path = ext.save(tmp_path / "m.npz")
    back = LidarLWLR.load(path)
    np.testing.assert_array_equal(back.tables_, ext.tables_)
    assert back.h_ == ext.h_ and back.p_out_ == ext.p_out_ and back.spur_mu_ == ext.spur_mu_
    assert back.null_rho_ == ext.null_rho_ and back.spur_rho_ == ext.spur_rho_
    a = ext.sample(log.poses[:2], ROOM, np.random.default_rng(9), n_repeats=3)
    b = back.sample(log.poses[:2], ROOM, np.random.default_rng(9), n_repeats=3)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ext.log_prob(a, log.poses[:2], ROOM), back.log_prob(b, log.poses[:2], ROOM))


def test_format_version_1_files_load_with_independent_nulls(rig_fit, tmp_path):
    _, _, ext, _ = rig_fit
    path = ext.save(tmp_path / "m.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(arrays["__header__"].tobytes().decode("utf-8"))
    assert header["format_version"] == 7
    assert arrays["extra_low"].shape == arrays["extra_high"].shape == arrays["extra_mean"].shape
    del arrays["extra_low"], arrays["extra_high"]  # format 7 added the extra terms' clamp
    header["format_version"] = 6
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(tmp_path / "v6.npz", **arrays)
    v6 = LidarLWLR.load(tmp_path / "v6.npz")
    assert v6.extra_low_.shape == v6.extra_mean_.shape and np.all(v6.extra_low_ <= -1e5)
    assert header["params"]["bias_model"] == ext.bias_model and "pose_sd" in header
    del header["params"]["bias_model"], header["pose_sd"]  # format 6 added the pooled bias and the pose error
    header["format_version"] = 5
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(tmp_path / "v5.npz", **arrays)
    v5 = LidarLWLR.load(tmp_path / "v5.npz")
    assert v5.bias_model == "per_bearing" and v5.pose_sd_ is None
    np.testing.assert_array_equal(v5.tables_, ext.tables_)
    assert header["spur_rho"] == ext.spur_rho_
    del header["spur_rho"]  # format 5 added the persistence of spurious returns
    header["format_version"] = 4
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(tmp_path / "v4.npz", **arrays)
    v4 = LidarLWLR.load(tmp_path / "v4.npz")
    assert v4.spur_rho_ == 0.0 and v4.null_rho_ == ext.null_rho_
    np.testing.assert_array_equal(v4.tables_, ext.tables_)
    for k in ("bias_shrinkage", "pose_correction"):  # format 4 added the bias shrinkage
        del header["params"][k]
    del header["bias_shrinkage"]
    header["format_version"] = 3
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(tmp_path / "v3.npz", **arrays)
    v3 = LidarLWLR.load(tmp_path / "v3.npz")
    assert v3.bias_shrinkage_ == 0.0 and v3.bias_shrinkage == 0.0 and v3.pose_correction is False
    np.testing.assert_array_equal(v3.tables_, ext.tables_)
    del header["params"]["extra_state"]  # format 3 added the extra state (params and arrays)
    for k in ("extra_mean", "extra_scale", "extra_coef"):
        del arrays[k]
    header["format_version"] = 2
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(tmp_path / "v2.npz", **arrays)
    v2 = LidarLWLR.load(tmp_path / "v2.npz")
    assert v2.extra_state_ == () and v2.null_rho_ == ext.null_rho_
    np.testing.assert_array_equal(v2.tables_, ext.tables_)
    del header["null_rho"]
    header["format_version"] = 1
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(tmp_path / "v1.npz", **arrays)
    old = LidarLWLR.load(tmp_path / "v1.npz")
    assert old.null_rho_ == 0.0
    np.testing.assert_array_equal(old.tables_, ext.tables_)
    header["format_version"] = 8
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(tmp_path / "v8.npz", **arrays)
    with pytest.raises(ModelFileError, match=re.escape("field 'format_version' is 8")):
        LidarLWLR.load(tmp_path / "v8.npz")


def test_bad_model_files_name_the_field(rig_fit, tmp_path):
    _, _, ext, _ = rig_fit
    path = ext.save(tmp_path / "m.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["tables"] = arrays["tables"][:, :10]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ModelFileError, match=re.escape("field 'tables' has shape")):
        LidarLWLR.load(tmp_path / "bad.npz")
    with pytest.raises(ModelFileError, match="not found"):
        LidarLWLR.load(tmp_path / "absent.npz")


def test_estimator_contract():
    m = LidarLWLR(variant="nope")
    assert vars(m)["variant"] == "nope"  # __init__ only stores
    with pytest.raises(NotFittedError, match="not fitted"):
        m.params(np.zeros((1, 3)), ROOM)
    log, _ = NeatoRig().record(ROOM, np.random.default_rng(0), n_poses=4, repeats=2)
    with pytest.raises(ValueError, match=re.escape("variant: expected one of")):
        m.fit(log)
    with pytest.raises(ValueError, match=re.escape("n_folds: must be in [2, number of poses = 4]")):
        LidarLWLR(n_folds=10).fit(log)
    scans, _ = NeatoRig().record(ROOM, np.random.default_rng(0), n_poses=4, repeats=1)
    # one reading per pose and bearing: fitted per reading since issue #10 (was refused before)
    assert LidarLWLR(n_folds=2, variant="seed", verbose=False).fit(scans).training_["fit"] == "per reading"


def test_learned_lidar_in_neato_env(rig_fit, tmp_path):
    _, _, ext, _ = rig_fit
    path = ext.save(tmp_path / "m.npz")
    sensor = load_learned_lidar(path)
    r, a = lidar_features(np.array([[1.0, 0.9, 0.0]]), ext.bearings_, ROOM, 5.0)
    rng = np.random.default_rng(0)
    x = np.stack([sensor.measure(r[0], a[0], rng) for _ in range(200)])
    assert x.shape == (200, 360) and np.isnan(x[:, NeatoRig().blocked_mask()]).mean() > 0.99
    far = sensor.measure(np.full(360, np.inf), np.full(360, np.nan), np.random.default_rng(0))
    assert np.isnan(far).mean() > 1 - 10 * P_EPS
    with pytest.raises(ValueError, match="nominal_range: last axis has 10 bearings"):
        sensor.measure(np.ones(10), np.zeros(10), np.random.default_rng(0))
    with pytest.raises(ValueError, match="takes only 'model'"):
        load_learned_lidar(path, sigma0=1.0)
    env = gym.make("sensor_envs/Neato-v0", lidar="learned", model=str(path))
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
    assert isinstance(env.unwrapped.lidar, LearnedLidar)


def test_default_model_is_shipped_and_loads():
    from sensor_envs.cli.rebuild import load_recipe, recipe_argv, recipes_folder

    sensor = load_learned_lidar()
    # fitted on the log that its recipe records from the calibrated rig (sensor-envs rebuild-models)
    recipe = load_recipe(recipes_folder() / "neato_lidar.yaml")
    record, _ = recipe_argv(recipe, Path("RIG.json"), Path("W"), Path("O"))
    assert recipe["rig"] == "neato_rig.json" and record[:4] == ["record", "lidar", "--rig", "RIG.json"]
    assert sensor.model.training_["source"] == Path(record[record.index("--out") + 1]).name
    env = gym.make("sensor_envs/Neato-v0", lidar="learned")
    obs, _ = env.reset(seed=1)
    assert env.observation_space.contains(obs)


def test_cli_record_fit_validate(tmp_path, capsys):
    log = tmp_path / "rig.npz"
    model = tmp_path / "m.npz"
    assert cli_main(["record", "lidar", "--out", str(log), "--poses", "6", "--repeats", "5", "--seed", "3"]) == 0
    assert cli_main(["fit", "lidar", str(log), "--out", str(model), "--folds", "2", "--variant", "seed"]) == 0
    assert model.with_suffix(".md").exists()
    assert cli_main(["validate", "lidar", str(model), str(log), "--out", str(tmp_path / "val"), "--card"]) == 0
    rep = json.loads((tmp_path / "val" / "report.json").read_text())
    assert set(rep["metrics"]) == {"model_seed", "ideal", "gaussian"}
    for m in rep["metrics"].values():
        assert np.isfinite(m["ll_per_reading_in_range"]) and m["all"]["mae_p_null"] >= 0
    assert (tmp_path / "val" / "scan.png").exists() and (tmp_path / "val" / "per_bearing_error.png").exists()
    assert "## Validation" in model.with_suffix(".md").read_text()
    assert cli_main(["fit", "lidar", str(tmp_path / "absent.npz"), "--out", str(model)]) == 2
    assert "not found" in capsys.readouterr().err


def test_real_data_model_beats_baselines_on_held_out_poses(real_data):
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.validate import fit_gaussian_lidar, table_one
    from sensor_envs.lidar.validate_readings import baseline_params

    log = load_log(real_data / "neato_mar27_train.npz")
    train, test = log.subset(np.arange(29) % 3 != 0), log.subset(np.arange(29) % 3 == 0)
    model = LidarLWLR(variant="extended", **SMALL).fit(train)
    r, a = lidar_features(test.poses, test.bearings, test.map_segments, 5.0)
    ours = table_one(test, model.params_from_features(r, a), (model.spur_mu_, model.spur_sigma_))
    gauss = table_one(test, baseline_params("gaussian", r, a, fit_gaussian_lidar(train)))
    assert ours["all"]["mae_p_null"] < gauss["all"]["mae_p_null"]
    assert ours["all"]["mae_sigma"] < gauss["all"]["mae_sigma"]
    assert ours["ll_per_reading"] > gauss["ll_per_reading"]
    # real nulls persist per cell: the fitted intra-cell correlation scores held-out null counts better
    assert model.null_rho_ >= 0.3
    assert ours["ll_null_counts_per_reading"] > ours["ll_null_counts_per_reading_independent"] + 0.05
    # and so do the real spurious returns (a cell has them in almost all or none of its readings)
    assert model.spur_rho_ >= 0.5
    assert ours["ll_spur_counts_per_reading"] > ours["ll_spur_counts_per_reading_independent"] + 0.01


def test_mae_of_p_spur_favours_predicting_none_the_proper_scores_do_not():
    from sensor_envs.lidar.log import LidarLog
    from sensor_envs.lidar.validate import table_one

    # 400 cells of 50 readings at 1 m; 5 % of the cells are spurious in every reading (persistent)
    cells, n = 400, 50
    x = np.full((cells, 1, n), 1.0)
    x[: cells // 20] = 16.9
    log = LidarLog(ranges=x, bearings=np.zeros(1), poses=np.zeros((cells, 3)), map_segments=None, source="synthetic")

    def params(p_spur: float, rho: float) -> dict[str, np.ndarray]:
        full = np.full((cells, 1), 1.0)
        return {
            "p_null": full * 1e-4,
            "p_spur": full * p_spur,
            "mu": full,
            "sigma": full * 0.01,
            "tau": full * 0,
            "spur_rho": full * rho,
        }

    none, calibrated = table_one(log, params(0.0, 0.0)), table_one(log, params(0.05, 0.95))
    assert none["mae_p_spur"] < calibrated["mae_p_spur"]  # 0.05 vs 0.095: the MAE rewards predicting none
    assert calibrated["mse_p_spur"] < none["mse_p_spur"]  # the Brier score and the count likelihood do not
    assert calibrated["ll_spur_counts_per_reading"] > none["ll_spur_counts_per_reading"]


def test_cross_validated_table_runs_on_a_small_rig_log():
    from sensor_envs.lidar.validate import cross_validate_log

    log, _ = NeatoRig().record(ROOM, np.random.default_rng(4), n_poses=6, repeats=10)
    small = {k: v for k, v in SMALL.items() if k not in ("n_folds", "verbose")}
    table = cross_validate_log(log, n_folds=2, inner_folds=2, model_kwargs=small, progress=False)
    assert set(table) == {"seed", "seed_without_spurious", "extended", "ideal", "gaussian"}
    # the learned models see the blocked bearings and range-dependent dropout; the baselines do not
    assert table["extended"]["all"]["mae_p_null"] < table["gaussian"]["all"]["mae_p_null"]
    assert table["extended"]["ll_per_reading"] > table["gaussian"]["ll_per_reading"]
