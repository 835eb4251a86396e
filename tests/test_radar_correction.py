"""The radar's add step: fitted corrections on top of a radar model (issue 39, radar half).

Seeded families: planted effects of each kind (mean, spread, rate; main and interaction) are
recovered by :func:`~sensor_envs.radar.correction.fit_term`; the corrected law samples what it
scores; model files round-trip and refuse bad values; the loop keeps a correction only when the
held-out NLL drops.
"""

from __future__ import annotations

import numpy as np
import pytest

from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.correction import CorrectedRadar, Term, fit_term, load_radar_file
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.log import target_tuples
from sensor_envs.radar.rig import record_rig_log


@pytest.fixture(scope="module")
def gauss():
    """A Gaussian radar fitted on a small rig log, and that log's target tuples."""
    log = record_rig_log(12, 20, 6, np.random.default_rng(3), velocity_columns=True)
    return GaussianRadar().fit(log), target_tuples(log)


def _shape(form: str, u: np.ndarray) -> np.ndarray:
    """A shape of ``u`` in [0, 1]: linear, step, U or saturating, spanning about 1."""
    return {"linear": u, "step": (u > 0.5) * 1.0, "u": 4 * (u - 0.5) ** 2, "sat": 1 - np.exp(-3 * u)}[form]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("form", ["linear", "step", "u", "sat"])
def test_mean_term_recovers_planted_offset(seed, form):
    rng = np.random.default_rng(seed)
    n = 6000
    c = rng.uniform(-2, 3, n)
    corners = np.column_stack([rng.uniform(5, 80, n), rng.uniform(-10, 10, n)])
    d = 0.3 * _shape(form, (c + 2) / 5)
    mu = np.zeros((n, 2))
    z = np.column_stack([rng.standard_t(4, n) * 0.2, d + rng.standard_t(4, n) * 0.2])
    t = fit_term("mean_y", "c", c, corners, z, mu, np.full(n, 0.1))
    err = np.sqrt(np.mean((t.value(c, corners) - d) ** 2))
    assert err < 0.05, err  # an effect of 0.3 m recovered to a few cm (a sharp step: to its knots)
    assert np.std(d) > 3 * err


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_interaction_term_follows_the_side(seed):
    rng = np.random.default_rng(seed)
    n = 8000
    c = rng.normal(size=n)
    corners = np.column_stack([rng.uniform(5, 60, n), rng.uniform(-8, 8, n)])
    d = 0.25 * np.tanh(c) * np.sign(corners[:, 1])
    z = np.column_stack([rng.normal(0, 0.2, n), d + rng.normal(0, 0.2, n)])
    main = fit_term("mean_y", "c", c, corners, z, np.zeros((n, 2)), np.zeros(n))
    inter = fit_term("mean_y", "c", c, corners, z, np.zeros((n, 2)), np.zeros(n), state="azimuth")
    assert np.abs(main.value(c, corners)).max() < 0.06  # zero mean over the sides: the main effect sees little
    assert np.corrcoef(inter.value(c, corners), d)[0, 1] > 0.9


@pytest.mark.parametrize("seed", [0, 1])
def test_spread_and_rate_terms_recover_planted_effects(seed):
    rng = np.random.default_rng(seed)
    n = 8000
    c = rng.uniform(0, 1, n)
    corners = np.column_stack([rng.uniform(5, 60, n), rng.uniform(-8, 8, n)])
    scale = np.exp(0.4 * (c - 0.5))
    z = rng.normal(0, 0.3, (n, 2)) * scale[:, None]
    p_det = 1 / (1 + np.exp(-(0.5 + 1.5 * (c - 0.5))))
    z[rng.random(n) > p_det] = np.nan
    pm0 = np.full(n, 1 - np.mean(p_det))
    sp = fit_term("spread", "c", c, corners, z, np.zeros((n, 2)), pm0)
    rt = fit_term("rate", "c", c, corners, z, np.zeros((n, 2)), pm0)
    a = sp.value(c, corners)
    assert abs(np.polyfit(c, a, 1)[0] - 0.4) < 0.12  # log scale slope 0.4 per unit of c
    b = rt.value(c, corners)
    assert abs(np.polyfit(c, b, 1)[0] - 1.5) < 0.4  # logit slope 1.5 per unit of c


def _terms(corners: np.ndarray) -> list[Term]:
    knots = np.array([0.0, 1.0])
    return [
        Term("mean_x", "c", knots, "", np.zeros(0), np.array([[0.0, 0.5]]), 0.5),
        Term("spread", "c", knots, "", np.zeros(0), np.array([[0.0, np.log(1.5)]]), 0.5),
        Term("rate", "c", knots, "", np.zeros(0), np.array([[0.0, -1.0]]), 0.5),
    ]


def test_corrected_law_samples_what_it_scores(gauss):
    base, tt = gauss
    corner = np.array([[30.0, 2.0]])
    model = CorrectedRadar(base, _terms(corner))
    n = 20000
    st = np.repeat(corner, n, axis=0)
    rng = np.random.default_rng(0)
    mu0, pm0 = base.mean_output(st[:1])
    p0 = 1 - pm0[0]
    for c, shift, scale, logit in ((0.0, 0.0, 1.0, 0.0), (1.0, 0.5, 1.5, -1.0)):
        ex = np.full((n, 1), c)
        z, _ = model.sample(st, rng, extra=ex)
        det = np.isfinite(z[:, 0])
        p1 = 1 / (1 + np.exp(-(np.log(p0 / (1 - p0)) + logit)))
        assert abs(det.mean() - p1) < 0.02
        base_z, _ = base.sample(st, np.random.default_rng(1))
        sd0 = np.nanstd(base_z[:, 0])
        assert abs(np.mean(z[det, 0]) - (mu0[0, 0] + shift)) < 0.05 * sd0 + 0.01
        assert abs(np.std(z[det, 0]) / sd0 - scale) < 0.05
        # the density integrates to P(detected) over a grid around the mean output
        mu1, _ = model.mean_output(st[:1], extra=ex[:1])
        g = np.linspace(-8, 8, 161) * sd0 * scale
        gx, gy = np.meshgrid(mu1[0, 0] + g, mu1[0, 1] + g)
        zz = np.column_stack([gx.ravel(), gy.ravel()])
        lp = model.log_prob(zz, np.repeat(corner, zz.shape[0], 0), extra=np.full((zz.shape[0], 1), c))
        mass = np.exp(lp).sum() * (g[1] - g[0]) ** 2
        assert abs(mass - p1) < 0.02
        lp_miss = model.log_prob(np.full((1, 2), np.nan), corner, extra=ex[:1])
        assert np.isclose(np.exp(lp_miss[0]), 1 - p1)


def test_model_file_round_trips_and_refuses_bad_values(gauss, tmp_path):
    base, tt = gauss
    model = CorrectedRadar(base, _terms(tt.corner))
    path = model.save(tmp_path / "m.npz")
    kind, back = load_radar_file(path)
    assert kind == "corrected" and back.extra_state_ == ("c",)
    ex = np.linspace(0, 1, 50)[:, None]
    st, z = tt.corner[:50], tt.z[:50]
    assert np.allclose(back.log_prob(z, st, extra=ex), model.log_prob(z, st, extra=ex), equal_nan=True)
    with pytest.raises(Exception, match="extra"):
        back.log_prob(z, st)  # the covariate must be given
    data = dict(np.load(path))
    for key, value, field in (
        ("term0_coef", np.array([[0.0, 500.0]]), "term0_coef"),
        ("term0_knots", np.array([1.0, 0.0]), "term0_knots"),
        ("term1_coef", np.array([[0.0, np.nan]]), "term1_coef"),
    ):
        bad = dict(data, **{key: value})
        p = tmp_path / f"bad_{key}.npz"
        np.savez(p, **bad)
        with pytest.raises(ModelFileError, match=field):
            CorrectedRadar.load(p)
    p = tmp_path / "bad_base.npz"
    np.savez(p, **dict(data, base_file=np.frombuffer(b"not a model", dtype=np.uint8)))
    with pytest.raises(ModelFileError, match="base_file"):
        CorrectedRadar.load(p)


def test_make_radar_runs_a_corrected_model_file(gauss, tmp_path):
    from sensor_envs.radar.sensors import make_radar

    base, tt = gauss
    path = CorrectedRadar(base, _terms(tt.corner)).save(tmp_path / "m.npz")
    radar = make_radar("gaussian", path)
    assert isinstance(radar, CorrectedRadar)
    z, src = radar.sample_cycle(tt.corner[:5], None, np.random.default_rng(0), extra=np.ones((5, 1)))
    assert z.shape == (5, 2) and src.shape == (5,)


# -- the add step of the loop, on seeded families ---------------------------------------------------

_PART = {"mean": None, "spread": "spread", "rate": "rate"}


def _add_case(kind: str, seed: int, model_kind: str, sequences: int):
    """The held-out NLL before and after adding the planted cause's correction (the search is skipped)."""
    from sensor_envs.diagnose.core import block_split
    from sensor_envs.diagnose.families import radar_case
    from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks

    case = radar_case(kind, seed, sequences=sequences)
    ad = RadarAdapter(case.log, block_split(radar_blocks(case.log)), model_kind=model_kind)  # as the loop fits
    part = _PART[kind] or f"mean_{case.info['axis']}"
    before = ad.evaluate(ad.fit(())).error
    model = ad.fit((f"{part}({case.cause})",))
    return before, ad.evaluate(model).error, model, case


@pytest.mark.parametrize(("kind", "seed"), [("mean", 2000), ("spread", 34), ("rate", 51)])
def test_planted_cause_correction_lowers_held_out_nll_gaussian(kind, seed):
    before, after, model, case = _add_case(kind, seed, "gaussian", 24)
    assert isinstance(model, CorrectedRadar) and model.extra_state_ == (case.cause,)
    assert after < before, (kind, seed, before, after)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "seed"), [("mean", 2000), ("mean", 4000), ("spread", 34), ("spread", 1034), ("rate", 51), ("rate", 1051)]
)
def test_planted_cause_correction_lowers_held_out_nll_kde(kind, seed):
    before, after, model, case = _add_case(kind, seed, "kde", 60)
    assert after < before, (kind, seed, before, after)


def test_highway_runs_a_corrected_kde_and_names_a_missing_covariate(tmp_path):
    """A corrected KDE on rel_vx runs in the highway world; one on a log-only column fails at make, naming it."""
    import gymnasium as gym

    from sensor_envs.radar.kde import KDERadarModel

    log = record_rig_log(6, 20, 6, np.random.default_rng(4), velocity_columns=True)
    base = KDERadarModel(random_state=0).fit(log)
    t = Term("mean_x", "rel_vx", np.array([-5.0, 5.0]), "", np.zeros(0), np.array([[-0.2, 0.2]]), 0.0)
    path = CorrectedRadar(base, [t], free_previous=True).save(tmp_path / "good.npz")
    env = gym.make("sensor_envs/HighwayFast-v0", radar="kde", radar_model=str(path), config={"vehicles_count": 5})
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
    assert np.isfinite(obs).all()
    env.close()
    t.column = "wheel_slip"
    bad = CorrectedRadar(base, [t]).save(tmp_path / "bad.npz")
    with pytest.raises(ValueError, match="'wheel_slip', which the highway world cannot supply"):
        gym.make("sensor_envs/HighwayFast-v0", radar="kde", radar_model=str(bad), config={"vehicles_count": 5})


@pytest.mark.slow
def test_cli_diagnose_writes_the_corrected_model_and_its_findings(tmp_path):
    """A latency (offset ~ relative velocity) found by the CLI is written as a correction the world can run."""
    import json

    from sensor_envs.cli.main import main
    from sensor_envs.radar.log import RadarLog, write_log

    rng = np.random.default_rng(7)
    log = record_rig_log(24, 30, 10, rng, velocity_columns=True)
    c = dict(log.columns)
    c["meas_x"] = c["meas_x"] - 0.4 * np.nan_to_num(c["rel_vx"])
    c["noise_a"] = np.where(np.isnan(c["ref_x"]), np.nan, rng.normal(size=len(log)))
    path = tmp_path / "log.csv"
    write_log(RadarLog(c, source="latency"), path)
    out = tmp_path / "out"
    argv = ["diagnose", "radar", str(path), "--out", str(out), "--model-kind", "gaussian", "--quiet"]
    assert main([*argv, "--max-add", "2", "--permutations", "99"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert "rel_vx" in rep["added"]  # (the rig's own occlusion effect on detection may come first)
    det = rep["details"]
    assert any(c["label"].startswith("mean_x(rel_vx") for c in det["corrections"])
    assert det["nll_parts_after"]["total"] < det["nll_parts_before"]["total"]
    assert "mean_x(rel_vx" in (out / "report.md").read_text()
    kind, model = load_radar_file(out / "model.npz")
    assert kind == "corrected" and "rel_vx" in model.extra_state_


def test_effect_terms_follow_the_found_kind_and_form():
    from sensor_envs.diagnose.core import block_split
    from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks
    from sensor_envs.diagnose.radar_add import parse_label

    log = record_rig_log(6, 20, 6, np.random.default_rng(2), velocity_columns=True)
    ad = RadarAdapter(log, block_split(radar_blocks(log, 5)), model_kind="gaussian")
    e = {"name": "rel_vx", "metric": "offset_y", "form": "x azimuth"}
    assert ad.effect_terms(e) == ("mean_y(rel_vx x azimuth)",)
    assert parse_label("mean_y(rel_vx x azimuth)") == ("mean_y", "rel_vx", "azimuth")
    assert ad.effect_terms({**e, "metric": "offset_spread", "form": "main"}) == ("spread(rel_vx)",)
    assert ad.effect_terms({**e, "metric": "detection", "form": "x range"}) == ("rate(rel_vx x range)",)
    assert len(ad.effect_terms({**e, "metric": "nll", "form": "main"})) == 4
    assert ad.effect_terms({**e, "name": "prev_offset_x"}) is None  # the model's own z_{t-1}: not addable
    assert ad.effect_terms({**e, "form": "x corner_x"}) is None  # no term of that form: reported in words


def test_cli_refuses_a_corrected_model_as_model_exit_2_one_line(gauss, tmp_path):
    import subprocess
    import sys

    from sensor_envs.radar.log import write_log

    base, tt = gauss
    model = CorrectedRadar(base, _terms(tt.corner)).save(tmp_path / "corrected.npz")
    log = write_log(record_rig_log(4, 10, 4, np.random.default_rng(0)), tmp_path / "log.csv")
    argv = ["diagnose", "radar", str(log), "--out", str(tmp_path / "o"), "--model", str(model)]
    r = subprocess.run([sys.executable, "-m", "sensor_envs.cli.main", *argv], capture_output=True, text=True)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(model) in lines[0] and "'kind'" in lines[0]
    assert not (tmp_path / "o").exists()


class _NoMeanBase:
    """A base model whose mean output is missing (NaN) at every state: a KDE query without weighted detections."""

    extra_state_ = ()
    state_variables = ("corner_x", "corner_y")

    def mean_output(self, state, extra=None, new_track=None):
        n = np.atleast_2d(state).shape[0]
        return np.full((n, 2), np.nan), np.full(n, 0.2)

    def log_prob(self, z, state, extra=None, new_track=None):
        z = np.atleast_2d(z)
        dens = -0.5 * np.sum(z**2, axis=1) - np.log(2 * np.pi)
        return np.where(np.isnan(z[:, 0]), np.log(0.2), np.log(0.8) + dens)


def test_a_missing_base_mean_does_not_turn_detections_into_misses():
    t = Term("rate", "c", np.array([0.0, 1.0]), "", np.zeros(0), np.array([[0.5, 0.5]]), 0.5)
    model = CorrectedRadar(_NoMeanBase(), [t])
    z = np.array([[0.1, -0.2], [np.nan, np.nan]])
    lp = model.log_prob(z, np.array([[10.0, 1.0], [10.0, 1.0]]), extra=np.array([[0.5], [0.5]]))
    p1 = 1 / (1 + np.exp(-(np.log(4.0) + 0.5)))
    assert np.isclose(lp[0], np.log(p1) - 0.5 * 0.05 - np.log(2 * np.pi))  # a detection, scored as one
    assert np.isclose(lp[1], np.log1p(-p1))
