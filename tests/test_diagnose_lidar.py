"""`diagnose lidar` on scan logs with effects the TEST hides (the tool is not told), and on a log with none.

Synthetic scan logs in a 4 m x 3 m box: a robot wandering inside it, K bearings, readings = nominal
range + Gaussian noise (sigma = 1 cm + 0.5 % of range), 5 % nulls. Every log carries the covariates
``v``, ``omega`` (the motion), ``noise_a`` (pure noise) and ``weak`` (correlates weakly, r ~ 0.3, with
``omega``) and a time ``t``. Hidden effects: the null rate grows with time; a range bias of
``BIAS_PER_OMEGA * omega`` (motion blur of a rotating scan); AR(1) range errors along the scans
(temporal correlation, found through the previous residual).
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensor_envs.diagnose.core import block_split, run_diagnose
from sensor_envs.diagnose.lidar import LidarAdapter, lidar_blocks
from sensor_envs.geometry import raycast_pose
from sensor_envs.lidar.extra_state import SLOPE_CAP, range_slope
from sensor_envs.lidar.log import LidarLog, log_from_arrays, save_log
from sensor_envs.lidar.lwlr import LidarLWLR, lidar_features
from sensor_envs.modelio import ModelFileError
from sensor_envs.testing.synthetic_lidar import BIAS_PER_OMEGA, BOX, _ar1, make_log

MARGIN = 0.01
"""error_after must be below error_before by at least this [nats per reading]."""
FAST = {"variant": "seed", "n_folds": 3, "h_range_grid": (0.25, 1.6), "h_alpha_grid": (0.5, 4.0), "verbose": False}


def diagnose(log: LidarLog):
    blocks = lidar_blocks(log.n_poses, 5)
    adapter = LidarAdapter(log, block_split(blocks), blocks, params=FAST, max_readings=150)
    return run_diagnose(adapter, n_permutations=199)


@pytest.mark.parametrize(("kind", "cause"), [("time", "time"), ("omega", "omega"), ("corr", "prev_residual")])
def test_hidden_effect_ranks_first_and_is_added(kind, cause):
    res = diagnose(make_log(kind))
    assert res.effects[0]["name"] == cause, res.effects[:3]
    assert res.effects[0]["significant"]
    assert res.added[0] == cause
    assert res.error_after < res.error_before - MARGIN, (res.error_before, res.error_after)
    for e in res.effects:  # the distractors are never picked
        if e["name"] in ("noise_a", "v"):
            assert not e["significant"], e


def test_no_hidden_effect_reports_none():
    res = diagnose(make_log("none", seed=1))
    assert res.added == []
    assert not [e for e in res.effects if e["significant"]], res.effects[:3]
    assert res.error_after == res.error_before


def test_extra_state_model_round_trips_and_checks_values(tmp_path):
    log = make_log("omega", scans=200, bearings=36)
    m = LidarLWLR(**FAST, extra_state=("omega", "t", "prev_residual")).fit(log, max_readings=100)
    assert m.extra_state_ == ("omega", "t", "prev_residual")
    assert m.extra_coef_[1, 1] > 0.5 * BIAS_PER_OMEGA * log.covariates["omega"].std()  # bias grows with omega
    path = m.save(tmp_path / "m.npz")
    back = LidarLWLR.load(path)
    extra = np.zeros((2, 1, 3))
    extra[:, 0, 0] = [-1.0, 1.0]
    np.testing.assert_allclose(
        back.log_prob(log.ranges[:2, :, 0], log.poses[:2], BOX, extra=extra),
        m.log_prob(log.ranges[:2, :, 0], log.poses[:2], BOX, extra=extra),
    )
    mu = back.params_full(log.poses[[0, 0]], BOX, extra=extra)["mu"]
    assert np.all(mu[1] > mu[0])  # same pose, larger omega: larger mean range
    with pytest.raises(ValueError, match="extra_state includes|state includes"):
        back.params_full(log.poses[:2], BOX)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["extra_scale"] = -arrays["extra_scale"]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ModelFileError, match="field 'extra_scale'"):
        LidarLWLR.load(tmp_path / "bad.npz")
    arrays["extra_scale"] = -arrays["extra_scale"]
    arrays["extra_coef"] = arrays["extra_coef"][:, :2]
    np.savez(tmp_path / "bad2.npz", **arrays)
    with pytest.raises(ModelFileError, match="field 'extra_coef'"):
        LidarLWLR.load(tmp_path / "bad2.npz")
    arrays["extra_coef"] = np.load(path)["extra_coef"]
    arrays["extra_low"] = np.abs(arrays["extra_low"]) + 1.0  # a clamp range that excludes the fit's mean
    np.savez(tmp_path / "bad3.npz", **arrays)
    with pytest.raises(ModelFileError, match="field 'extra_low'"):
        LidarLWLR.load(tmp_path / "bad3.npz")
    top = float(log.covariates["omega"].max())  # a query beyond the fitted range is clamped to it
    far, edge = extra.copy(), extra.copy()
    far[:, 0, 0], edge[:, 0, 0] = 50.0 * top, top
    np.testing.assert_allclose(
        back.params_full(log.poses[:2], BOX, extra=far)["mu"],
        back.params_full(log.poses[:2], BOX, extra=edge)["mu"],
        atol=1e-6,
    )
    with pytest.raises(ValueError, match="cov_speed"):
        LidarLWLR(**FAST, extra_state=("speed",)).fit(log, max_readings=100)


@pytest.mark.parametrize("end", ["max", "min"])
def test_a_query_beyond_the_fit_is_taken_on_the_fitted_curve(end):
    """Modified terms of a variable follow its clamp: ``omega@sq`` at the edge's square, not at the larger one."""
    log = make_log("omega", scans=200, bearings=36)
    names = ("omega", "omega@sq", "omega@cos_bearing", "omega@sq@sin_bearing")
    m = LidarLWLR(**FAST, extra_state=names).fit(log, max_readings=100)
    edge_value, b = float(getattr(log.covariates["omega"], end)()), log.bearings

    def terms(v: float) -> np.ndarray:  # the raw terms the world would pass, (1 scan, K bearings, 4)
        return np.stack([np.full(b.size, v), np.full(b.size, v**2), v * np.cos(b), v**2 * np.sin(b)], axis=-1)[None]

    edge, far = terms(edge_value), terms(40.0 * edge_value)
    got = {k: m.params_full(log.poses[:1], BOX, extra=x) for k, x in (("edge", edge), ("far", far))}
    for key in ("mu", "sigma", "p_null"):
        np.testing.assert_allclose(got["far"][key], got["edge"][key], atol=1e-9, rtol=1e-9)


@pytest.mark.slow  # end to end, several seconds: CI runs it with the slow tests
def test_cli_diagnose_lidar(tmp_path):
    log_path = save_log(make_log("omega", scans=400, bearings=36), tmp_path / "log.npz")
    out = tmp_path / "diag"
    cmd = [sys.executable, "-m", "sensor_envs.cli.main", "diagnose", "lidar", str(log_path), "--out", str(out)]
    cmd += ["--permutations", "199", "--max-readings", "100", "--quiet"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["effects"][0]["name"] == "omega" and rep["added"][0] == "omega"
    assert rep["error_after"] < rep["error_before"]
    assert (out / "report.md").exists()
    final = LidarLWLR.load(out / "model.npz")  # the tables with the added terms, as the report names them
    assert final.extra_state_ == tuple(rep["details"]["settings"]["state_after"]) and "bias:omega" in final.extra_state_
    again = subprocess.run(cmd, capture_output=True, text=True, check=False)  # existing output: refused
    assert again.returncode == 2 and again.stderr.count("\n") == 1, again.stderr


def test_neato_supplies_the_learned_lidars_extra_state():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import sensor_envs  # noqa: F401  (registers the envs)

    log = make_log("omega", scans=200, bearings=36)
    state = ("omega", "v", "t", "prev_residual", "omega@range_slope", "v@incidence", "t@range", "omega@sq@range_slope")
    m = LidarLWLR(**FAST, extra_state=state).fit(log, max_readings=100)
    assert np.all(m.extra_scale_ > 0) and np.isfinite(m.extra_coef_).all()
    env = gym.make("sensor_envs/Neato-v0", lidar="learned", model=m, n_bearings=36, map="seed_room")
    ex = env.unwrapped
    ex.reset(seed=1)
    ex.step(np.array([0.5, 1.0], dtype=np.float32))  # moving and turning: the terms are not all 0
    values = ex._extra_state()[0]  # the world's ray terms: the variable times the raycast's factor
    assert np.abs(values[:, 4]).max() > 0 and np.abs(values[:, 5]).max() > 0
    nominal, incidence, _ = raycast_pose(ex.pose[None], ex.bearings, ex.world_map.segments, ex.max_range)
    r = np.where(np.isfinite(nominal[0]), nominal[0], 0.0)
    slope = np.clip(range_slope(nominal[0], ex.bearings), -SLOPE_CAP * r, SLOPE_CAP * r)
    np.testing.assert_allclose(values[:, 4], ex._motion[1] * slope)
    np.testing.assert_allclose(values[:, 5], ex._motion[0] * np.where(np.isfinite(nominal[0]), incidence[0], 0.0))
    np.testing.assert_allclose(values[:, 7], ex._motion[1] ** 2 * slope)  # a chain: squared, then times the slope
    check_env(env.unwrapped, skip_render_check=True)
    obs_a, _ = env.reset(seed=3)
    obs_b, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs_a, obs_b)  # same seed, same observations
    for _ in range(3):
        obs, *_ = env.step(np.array([0.5, 1.0], dtype=np.float32))
    assert np.isfinite(obs).all()
    assert env.unwrapped._motion[1] == pytest.approx(env.unwrapped.omega_max)
    bad = LidarLWLR(**FAST, extra_state=("noise_a",)).fit(log, max_readings=100)
    with pytest.raises(ValueError, match=r"state names \['noise_a'\], which Neato-v0 cannot supply"):
        gym.make("sensor_envs/Neato-v0", lidar="learned", model=bad, n_bearings=36)


def test_range_slope_is_the_walls_slope_along_the_scan():
    """From a pose 1 m in front of a straight wall, ``r = 1 / cos(b)``: ``dr/db = sin(b) / cos(b)^2``."""
    b = np.linspace(-0.6, 0.6, 121)
    r = 1.0 / np.cos(b)[None]
    got = range_slope(np.where(np.abs(b) < 0.6, r, np.inf), b)  # the ends miss the map: no slope there
    np.testing.assert_allclose(got[0, 5:-5], (np.sin(b) / np.cos(b) ** 2)[5:-5], rtol=1e-3)
    assert got[0, 0] == 0.0 and got[0, -1] == 0.0


def smeared_log(scans: int = 600, bearings: int = 90, seed: int = 1) -> LidarLog:
    """The box log with a rotation smear: bearing ``k`` is measured ``omega x 0.2 s x k / K`` later."""
    rng = np.random.default_rng(seed)
    i = np.arange(scans)
    omega, v = _ar1(rng, scans, 0.95, 0.15), 0.25 + _ar1(rng, scans, 0.9, 0.08)
    poses = np.stack([2 + 0.8 * np.sin(0.03 * i), 1.5 + 0.6 * np.cos(0.021 * i), np.cumsum(0.2 * omega)], axis=1)
    b = np.linspace(0, 2 * np.pi, bearings, endpoint=False)
    r = np.stack([lidar_features(poses[s : s + 1], b + omega[s] * 0.2 * np.arange(bearings) / bearings, BOX, 5.0)[0][0]
                  for s in range(scans)])  # fmt: skip
    x = r + (0.01 + 0.005 * r) * rng.normal(size=r.shape)
    x = np.where(rng.random(r.shape) < 0.05, 0.0, x)
    cov = {"v": v, "omega": omega, "noise_a": rng.normal(size=scans)}
    return log_from_arrays(x[..., None], b, poses, BOX, t=0.2 * i, covariates=cov, source="synthetic smear")


@pytest.mark.slow  # a full diagnosis of a 600-scan log: CI runs it with the slow tests
def test_rotation_smear_is_found_through_the_range_slope():
    """Issue 39's smeared scan: its error follows the wall's slope along the scan, not the bearing.

    Found as turn rate x range slope and added in that form (``bias:omega@range_slope``), which lowers the held-out
    NLL more than the turn rate's main terms do.
    """
    log = smeared_log()
    res = diagnose(log)
    top = res.effects[0]
    assert top["name"] == "omega" and top["significant"] and top["form"] == "x range_slope", res.effects[:3]
    assert res.added[:1] == ["omega"] and "bias:omega@range_slope" in res.settings["state_after"]  # a mean effect
    assert not res.to_json()["details"]["unrepresented"]
    held = block_split(lidar_blocks(log.n_poses, 5))
    adapter = LidarAdapter(log, held, lidar_blocks(log.n_poses, 5), params=FAST, max_readings=150)
    main_only = adapter.evaluate(adapter.fit(("omega", "omega@sq"))).error
    with_slope = adapter.evaluate(adapter.fit(("omega", "omega@range_slope"))).error
    assert with_slope < main_only - 0.005 and res.error_after < res.error_before


@given(st.lists(st.tuples(st.integers(0, 12), st.one_of(st.none(), st.floats(-0.5, 0.5))), min_size=1, max_size=80))
@settings(max_examples=60, deadline=None)
def test_pit_spread_is_the_distance_from_the_scans_median(rows):
    """``pit_spread``: each finite PIT's distance from its scan's median PIT; NaN stays NaN."""
    from sensor_envs.diagnose.lidar import _pit_spread

    scan = np.array([r[0] for r in rows], dtype=np.int64)  # in any order
    pit = np.array([np.nan if r[1] is None else r[1] for r in rows])
    out = _pit_spread(pit, scan)
    for j in np.unique(scan):
        m = (scan == j) & np.isfinite(pit)
        np.testing.assert_allclose(out[m], np.abs(pit[m] - np.median(pit[m])) if m.any() else [], atol=1e-12)
    assert np.array_equal(np.isnan(out), np.isnan(pit))


def test_part_terms_act_on_their_part_only(tmp_path):
    from sensor_envs.diagnose.lidar import METRIC_PARTS
    from sensor_envs.lidar.extra_state import check_extra_state, split_term, term_part

    assert split_term("sigma:v@sq@cos_bearing") == ("v", "sq@cos_bearing") and term_part("null:t") == "null"
    assert term_part("v") is None and term_part("other:v") is None
    with pytest.raises(ValueError, match="part prefix"):
        check_extra_state(("null:",))
    log = make_log("omega", scans=200, bearings=36)
    state = ("bias:omega", "null:t", "sigma:omega", "v")
    m = LidarLWLR(**FAST, extra_state=state).fit(log, max_readings=100)
    c = m.extra_coef_
    assert c[1, 1] > 0.5 * BIAS_PER_OMEGA * log.covariates["omega"].std()  # the bias term still finds the blur
    assert c[0, 1] == 0 and c[2, 1] == 0 and c[1, 2] == 0 and c[2, 2] == 0 and c[0, 3] == 0 and c[1, 3] == 0
    assert np.all(c[:, 4] != 0)  # a term without a part acts on all three
    path = m.save(tmp_path / "m.npz")
    back = LidarLWLR.load(path)
    assert back.extra_state_ == state
    np.testing.assert_array_equal(back.extra_coef_, c)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["extra_coef"][0, 1] = 0.3  # the bias-only term acting on the null rate: refused at load
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ModelFileError, match="field 'extra_coef'"):
        LidarLWLR.load(tmp_path / "bad.npz")
    blocks = lidar_blocks(log.n_poses, 5)
    adapter = LidarAdapter(log, block_split(blocks), blocks, params=FAST, max_readings=100)
    for metric, parts in METRIC_PARTS.items():
        terms = adapter.effect_terms({"name": "omega", "metric": metric, "form": "x bearing"})
        assert terms is not None and {t.split(":")[0] for t in terms} == set(parts) and len(terms) == 6 * len(parts)
    assert adapter.term_variable("sigma:omega@sq@range") == "omega"
    import gymnasium as gym

    import sensor_envs  # noqa: F401  (registers the envs)

    env = gym.make("sensor_envs/Neato-v0", lidar="learned", model=back, n_bearings=36, map="seed_room")
    env.reset(seed=1)
    obs = env.step(np.array([0.5, 1.0], dtype=np.float32))[0]  # the world supplies the part terms' variables
    assert obs.shape == (39,) and np.isfinite(obs).all()


def test_one_cause_on_two_parts_is_added_on_both(tmp_path):
    from sensor_envs.diagnose.report import write_report

    res = diagnose(make_log("omega_both", seed=3))
    after = res.settings["state_after"]
    assert res.added[0] == "omega", res.steps[0]["ranking"][:3]
    assert any(t.startswith("bias:omega") for t in after) and any(t.startswith("null:omega") for t in after), after
    assert res.error_after < res.error_before - MARGIN
    data = write_report(res, tmp_path)  # the report names both findings, the later one with its step and terms
    later = [f for f in data["details"]["findings"] if "step" in f]
    assert [(f["name"], f["kind"], f["metric"]) for f in later] == [("omega", "rate", "null")]
    assert "found at step 2, added as null:omega" in (tmp_path / "report.md").read_text()


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from([None, "null", "bias", "sigma"]),
            st.from_regex(r"[a-z][a-z0-9_]{0,8}", fullmatch=True),
            st.sampled_from([None, "sq", "cos_bearing", "sq@range", "range_slope"]),
        ),
        min_size=1,
        max_size=8,
        unique_by=lambda t: t,
    )
)
def test_part_prefixes_parse_and_select_their_columns(terms):
    """Any term list with or without part prefixes: the variable and modifier survive the prefix, and each
    part's design columns are the intercept plus exactly the terms that act on it."""
    from sensor_envs.lidar.extra_state import PARTS, check_extra_state, part_columns, split_term, term_part

    names = [f"{p + ':' if p else ''}{v}{'@' + m if m else ''}" for p, v, m in terms]
    assert check_extra_state(names) == tuple(names)
    for (p, v, m), n in zip(terms, names, strict=True):
        assert split_term(n) == (v, m) and term_part(n) == p
    for part, cols in zip(PARTS, part_columns(tuple(names)), strict=True):
        assert cols[0] == 0
        assert [names[c - 1] for c in cols[1:]] == [
            n for (p, _, _), n in zip(terms, names, strict=True) if p in (None, part)
        ]


def test_a_short_logs_gain_is_measured_on_every_fold():
    """A log with few held-out blocks: the gain gate refits on the two other folds, so every block is held
    out once (the folds partition the scans); a longer log keeps its one held-out part."""
    log = make_log("omega", scans=150, seed=5)
    blocks = lidar_blocks(log.n_poses, 5)
    adapter = LidarAdapter(log, block_split(blocks), blocks, params=FAST, max_readings=150)
    folds = adapter.other_folds()
    held = np.stack([adapter.held, *(f.held for f in folds)])
    assert held.shape == (3, 150) and (held.sum(axis=0) == 1).all()
    res = run_diagnose(adapter, n_permutations=199)
    assert res.added[:1] == ["omega"], res.steps[0]["ranking"][:3]
    assert {a["gate_folds"] for s in res.steps for a in s["attempts"]} == {3}
    assert res.error_after < res.error_before - MARGIN
    long_log = make_log("omega", scans=600, seed=5)
    blocks = lidar_blocks(long_log.n_poses, 5)
    res = run_diagnose(LidarAdapter(long_log, block_split(blocks), blocks, params=FAST, max_readings=150), max_add=1)
    assert [a["gate_folds"] for s in res.steps for a in s.get("attempts", [])] == [1]
    custom = block_split(blocks, held_ranks=(0, 5))  # a split of the caller's own: no other folds
    assert LidarAdapter(long_log, custom, blocks, params=FAST, max_readings=150).other_folds() == []
