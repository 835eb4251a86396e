"""`diagnose radar` on logs with effects the TEST hides (the tool is not told), and on a log with none.

Latency log: rig sequences with covariate columns ``rel_vx``/``rel_vy`` (the targets' relative
velocity, which the rig knows), the measurement shifted by ``-LATENCY * v`` (an undeclared latency),
plus distractors: two pure-noise columns and ``weak``, which correlates weakly (r ~ 0.3) with the cause.
Null log: the rig's target states, with outputs drawn independently per reading from a Gaussian
radar fitted to the rig (they depend on the corner's range only, so nothing outside the diagnosed
model's state matters), plus the same kind of noise columns. (Outputs resampled from a KDE are no
null: the resampled tuples carry their source track's aspect and repeat along a track.)
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.diagnose.core import block_split, rank_candidates, run_diagnose
from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import RadarLog, target_tuples, write_log
from sensor_envs.radar.rig import record_rig_log

LATENCY = 0.4
"""Hidden latency [s]: meas = true - LATENCY * relative velocity."""
MARGIN = 0.005
"""error_after must be below error_before by at least this [nats per reading]."""
FAST = {"extra_candidates": (0.5, 1.0), "relevance_folds": 2}


def _with_distractors(cols: dict, rng: np.random.Generator) -> dict:
    tgt = ~np.isnan(cols["ref_x"])
    n = tgt.size
    cols["noise_a"] = np.where(tgt, rng.normal(size=n), np.nan)
    cols["noise_b"] = rng.uniform(size=n)
    return cols


@pytest.fixture(scope="module")
def latency_log() -> RadarLog:
    rng = np.random.default_rng(7)
    log = record_rig_log(24, 30, 10, rng, velocity_columns=True)
    c = _with_distractors(dict(log.columns), rng)
    vx, vy = np.nan_to_num(c["rel_vx"]), np.nan_to_num(c["rel_vy"])
    c["meas_x"], c["meas_y"] = c["meas_x"] - LATENCY * vx, c["meas_y"] - LATENCY * vy
    c["weak"] = np.where(np.isnan(c["ref_x"]), np.nan, 0.3 * vx / np.nanstd(c["rel_vx"]) + rng.normal(size=len(log)))
    return RadarLog(c, source="latency log")


@pytest.fixture(scope="module")
def occlusion_log() -> RadarLog:
    """The generic rig: detection probability times (1 - 0.9 x occluded fraction), which the KDE's state lacks."""
    rng = np.random.default_rng(5)
    log = record_rig_log(24, 30, 10, rng)
    return RadarLog(_with_distractors(dict(log.columns), rng), source="occlusion log")


@pytest.fixture(scope="module")
def null_log() -> RadarLog:
    rng = np.random.default_rng(11)
    log = record_rig_log(24, 30, 10, rng)
    model = GaussianRadar().fit(log)  # outputs depend on the corner's range only, independently per reading
    tt = target_tuples(log)
    z, _ = model.sample(tt.corner, rng)
    c = dict(log.columns)
    c["meas_x"], c["meas_y"] = c["meas_x"].copy(), c["meas_y"].copy()
    c["meas_x"][tt.row], c["meas_y"][tt.row] = tt.corner[:, 0] + z[:, 0], tt.corner[:, 1] + z[:, 1]
    return RadarLog(_with_distractors(c, rng), source="null log")


def test_latency_is_found_first_added_and_lowers_the_error(latency_log):
    """The rig's occlusion loss is a second true effect (test_occlusion_is_found...): excluded here."""
    held = block_split(radar_blocks(latency_log))
    adapter = RadarAdapter(latency_log, held, params=FAST, exclude=("occluded",))
    res = run_diagnose(adapter, max_add=1, n_permutations=199)
    names = [e["name"] for e in res.effects]
    assert names[0] in ("rel_vx", "rel_vy"), names[:5]
    assert res.effects[0]["p_value"] < 0.01
    for distractor in ("noise_a", "noise_b", "weak"):
        e = next(x for x in res.effects if x["name"] == distractor)
        assert not e["significant"], e
    assert res.added == [names[0]]
    assert res.error_after < res.error_before - MARGIN, (res.error_before, res.error_after)
    # like with like: the Gaussian baseline with the same (linear) extra state improves too
    assert res.baseline_after < res.baseline_before - MARGIN


def test_occlusion_is_found_as_a_derived_feature_and_added(occlusion_log):
    """The occluded fraction is no log column: diagnose derives it from the boxes (features.occluded_column)."""
    held = block_split(radar_blocks(occlusion_log))
    adapter = RadarAdapter(occlusion_log, held, params=FAST)
    res = run_diagnose(adapter, max_add=1, n_permutations=199)
    assert res.effects[0]["name"] == "occluded", [e["name"] for e in res.effects[:5]]
    assert res.effects[0]["p_value"] < 0.01
    for distractor in ("noise_a", "noise_b"):
        assert not next(x for x in res.effects if x["name"] == distractor)["significant"]
    assert res.added == ["occluded"]
    assert res.error_after < res.error_before - MARGIN, (res.error_before, res.error_after)


@pytest.mark.slow  # end to end, several seconds: CI runs it with the slow tests
def test_no_hidden_effect_reports_none(null_log, tmp_path):
    held = block_split(radar_blocks(null_log))
    adapter = RadarAdapter(null_log, held, params={**FAST, "use_prev": False})
    res = run_diagnose(adapter, max_add=1, n_permutations=199)
    assert [e["name"] for e in res.effects if e["significant"]] == [], res.effects[:3]
    assert res.added == [] and res.error_after == res.error_before
    from sensor_envs.diagnose.report import write_report

    write_report(res, tmp_path / "r", source="null log")
    assert "No effect is significant" in (tmp_path / "r" / "report.md").read_text()


def test_permutation_test_rejects_chance_correlation():
    """A pure-noise candidate on pure-noise residuals is not significant, a real one is."""
    rng = np.random.default_rng(3)
    from sensor_envs.diagnose.core import Evaluation

    n = 3000
    cause, noise = rng.normal(size=n), rng.normal(size=n)
    ev = Evaluation(
        nll=np.zeros(n),
        residuals={"r": 0.3 * cause + rng.normal(size=n)},
        candidates={"cause": cause, "noise": noise},
        blocks=np.arange(n) // 50,
    )
    rk = rank_candidates(ev, n_permutations=199, rng=rng)
    assert [e["name"] for e in rk.significant()] == ["cause"]
    assert next(e for e in rk.effects if e["name"] == "noise")["p_value"] > 0.05


def test_block_split_keeps_blocks_whole():
    blocks = np.repeat(np.arange(40), 7)
    held = block_split(blocks)
    assert 0.2 < held.mean() < 0.4
    for b in range(40):
        assert held[blocks == b].all() or not held[blocks == b].any()
    with pytest.raises(ValueError, match="too few"):
        block_split(np.zeros(10))


def test_models_with_extra_state_save_load_and_refuse_missing_values(latency_log, tmp_path):
    log = latency_log.select(latency_log["sequence"] < 8)
    kde = KDERadarModel(extra_state=("rel_vx",), extra_variance=(1.0,), random_state=0).fit(log)
    gau = GaussianRadar(extra_state=("rel_vx",)).fit(log)
    tt = target_tuples(log)
    state = np.concatenate([tt.corner, tt.z_prev], axis=1)
    ex = log["rel_vx"][tt.row][:, None]
    for m, cls in ((kde, KDERadarModel), (gau, GaussianRadar)):
        path = m.save(tmp_path / f"{cls.__name__}.npz")
        m2 = cls.load(path)
        assert m2.state_variables[-1] == "rel_vx"
        np.testing.assert_allclose(m2.log_prob(tt.z, state, extra=ex), m.log_prob(tt.z, state, extra=ex))
        with pytest.raises(ValueError, match="rel_vx"):
            m2.log_prob(tt.z, state)
        z, _ = m2.sample(state[:20], np.random.default_rng(0), extra=ex[:20])
        assert z.shape == (20, 2)
    with pytest.raises(ValueError, match="'nope'"):
        KDERadarModel(extra_state=("nope",)).fit(log)


def test_cli_diagnose_writes_report_and_refuses_existing_out(latency_log, tmp_path):
    path = write_log(latency_log.select(latency_log["sequence"] < 10), tmp_path / "log.csv")
    out = tmp_path / "out"
    args = ["diagnose", "radar", str(path), "--out", str(out), "--max-add", "1", "--permutations", "199", "--quiet"]
    args += ["--model-kind", "gaussian"]
    assert main(args) == 0
    rep = json.loads((out / "report.json").read_text())
    assert {"effects", "added", "error_before", "error_after", "details"} <= set(rep)
    assert all({"name", "score", "p_value"} == set(e) for e in rep["effects"])
    assert isinstance(rep["error_before"], float) and isinstance(rep["error_after"], float)
    assert (out / "report.md").is_file() and list(out.glob("*.png"))
    before = (out / "report.json").read_bytes()
    assert main(args) == 2  # refuses the existing folder
    assert (out / "report.json").read_bytes() == before


def test_cli_bad_log_exit_2_one_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("sequence,frame\n0,0\n")
    r = subprocess.run(
        [sys.executable, "-m", "sensor_envs.cli.main", "diagnose", "radar", str(bad), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(bad) in lines[0] and "'t'" in lines[0]
    assert not (tmp_path / "o").exists()


def test_highway_supplies_the_models_state_and_refuses_unknown_variables(latency_log, tmp_path):
    """A KDE whose state names rel_vx runs in the highway world; one naming 'noise_a' fails at make."""
    import gymnasium as gym

    log = latency_log.select(latency_log["sequence"] < 8)
    good = KDERadarModel(extra_state=("rel_vx", "aspect"), extra_variance=(1.0, 1.0), random_state=0)
    from sensor_envs.radar.features import with_derived_columns

    good_path = good.fit(with_derived_columns(log)).save(tmp_path / "good.npz")
    env = gym.make("sensor_envs/HighwayFast-v0", radar="kde", radar_model=str(good_path), config={"vehicles_count": 5})
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
    assert np.isfinite(obs).all()
    env.close()
    bad_path = KDERadarModel(extra_state=("noise_a",), extra_variance=(1.0,)).fit(log).save(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match="'noise_a', which the highway world cannot supply"):
        gym.make("sensor_envs/HighwayFast-v0", radar="kde", radar_model=str(bad_path), config={"vehicles_count": 5})


def test_world_state_values_in_the_sensor_frame():
    """Ego heading +90 deg at speed 10 m/s; a target 20 m ahead (world +y) driving at 15 m/s along world +x."""
    from types import SimpleNamespace

    from sensor_envs.envs.highway.sensor import world_state
    from sensor_envs.envs.highway.step_record import Truth

    truth = Truth(
        objects=[object()],
        obstacle=np.array([False]),
        centre=np.array([[0.0, 20.0]]),
        heading=np.array([0.0]),
        velocity=np.array([[15.0, 0.0]]),
        corners=np.zeros((1, 4, 2)),
    )
    ego = SimpleNamespace(velocity=np.array([0.0, 10.0]))
    pose = np.array([0.0, 0.0, np.pi / 2])
    names = ("rel_vx", "rel_vy", "rel_speed", "target_heading", "aspect", "ego_speed", "range", "azimuth")
    v = dict(zip(names, world_state(names, truth, np.array([0]), pose, ego)[0], strict=True))
    # relative velocity (15, -10) in the world -> sensor frame (x = world +y, y = world -x): (-10, -15)
    np.testing.assert_allclose([v["rel_vx"], v["rel_vy"]], [-10.0, -15.0], atol=1e-9)
    np.testing.assert_allclose(v["rel_speed"], np.hypot(10, 15))
    np.testing.assert_allclose([v["target_heading"], v["aspect"]], [-np.pi / 2, -np.pi / 2], atol=1e-9)
    np.testing.assert_allclose([v["ego_speed"], v["range"], v["azimuth"]], [10.0, 20.0, 0.0], atol=1e-9)


def test_cli_diagnose_with_a_given_model(latency_log, tmp_path):
    small = latency_log.select(latency_log["sequence"] < 10)
    path = write_log(small, tmp_path / "log.csv")
    model = GaussianRadar().fit(small).save(tmp_path / "g.npz")
    out = tmp_path / "out"
    args = ["diagnose", "radar", str(path), "--out", str(out), "--model", str(model), "--max-add", "3"]
    assert main([*args, "--permutations", "199", "--quiet"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["details"]["model"]["kind"] == "gaussian" and rep["details"]["model"]["file"] == str(model)
    # the Gaussian has no z_{t-1}: the rig's correlated tracker errors (prev_offset_*, not addable) rank high,
    # and so does the rig's aspect-dependent reflection point (circular: a linear term cannot take it);
    # the hidden latency is significant and is added
    assert {"rel_vx", "rel_vy"} & set(rep["significant"]), rep["effects"][:6]
    assert {"rel_vx", "rel_vy"} & set(rep["added"]), rep["details"]["steps"]
    assert isinstance(rep["details"]["given_model_error_held_out"], float)
    assert rep["error_after"] < rep["error_before"] - MARGIN


def test_held_out_scores_take_previous_outputs_from_the_whole_log_and_route_new_tracks(latency_log):
    held = block_split(radar_blocks(latency_log))
    adapter = RadarAdapter(latency_log, held, params=FAST)
    model = KDERadarModel(relevance="paper", random_state=0).fit(adapter.fit_log)
    full = target_tuples(adapter.log)
    keep = held[full.row]
    local = target_tuples(adapter.held_log)  # the held-out log alone: blocks start without z_{t-1}
    np.testing.assert_array_equal(local.z, full.z[keep])
    block_start = ~local.has_prev_row & full.has_prev_row[keep]
    assert block_start.any() and (~full.has_prev_row[keep]).any()  # mid-track block starts and true new tracks
    state = np.concatenate([full.corner[keep], full.z_prev[keep]], axis=1)
    new = ~full.has_prev_row[keep]
    routed = model.log_prob(full.z[keep], state, new_track=new)
    assert not np.allclose(routed[new], model.log_prob(full.z[keep], state)[new])  # the flag matters here
    np.testing.assert_allclose(adapter.evaluate(model).nll, -routed)


@pytest.mark.slow
def test_state_variances_chosen_by_cv_once_then_reused(latency_log):
    """A model whose relevance variances come from CV (e.g. the shipped one) is not re-cross-validated per refit."""
    held = block_split(radar_blocks(latency_log))
    cands = {"relevance_candidates": (6.0, 48.0), "relevance_candidates_prev": (0.03, 0.3)}
    params = {**FAST, "relevance": "cv_state", **cands}
    adapter = RadarAdapter(latency_log, held, params=params)
    first = adapter.fit(())
    assert adapter.params["relevance"] == "paper"
    assert tuple(adapter.params["rel_variance"]) == first.rel_variance_
    assert adapter.fit(()).rel_variance_ == first.rel_variance_


def test_correction_labels_name_their_column():
    from sensor_envs.diagnose.radar import RadarAdapter

    assert RadarAdapter.term_variable("mean_x(rel_vx x azimuth)") == "rel_vx"
    assert RadarAdapter.term_variable("rate(v)") == "v" and RadarAdapter.term_variable("ego_speed") == "ego_speed"
