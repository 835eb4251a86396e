"""Power and proxies of the ``diagnose`` search, the static-pose shape, planted real-log effects, its defaults.

Seeded families of held-out evaluations (no model fit, fast): non-monotone causes of slow covariates
(U shapes, steps) found; a proxy of a cause already added to the model not significant; the main
basis of a candidate is a function of its ranks. The loop on one static pose recorded over time, the
planting of effects into a scan log, and the CLI's defaults are the package's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensor_envs.diagnose.core import DEFAULTS, Evaluation
from sensor_envs.diagnose.families import PLANT_KINDS, lidar_case, plant_lidar, static_scan_log
from sensor_envs.diagnose.search import rank_basis, rank_candidates

K = 24


def _ar1(rng: np.random.Generator, n: int, rho: float) -> np.ndarray:
    e = rng.normal(size=n) * np.sqrt(1 - rho**2)
    out = np.empty(n)
    out[0] = rng.normal()
    for i in range(1, n):
        out[i] = rho * out[i - 1] + e[i]
    return out


def _evaluation(resid: np.ndarray, cands: dict[str, np.ndarray]) -> Evaluation:
    s = resid.shape[0]
    scan = np.repeat(np.arange(s), K)
    bearing = np.tile(np.arange(K), s).astype(float)
    return Evaluation(
        nll=np.zeros(s * K),
        residuals={"range": resid.ravel()},
        candidates={n: np.repeat(v, K) for n, v in cands.items()},
        blocks=scan // 5,
        order=scan + bearing / K,
        state={"bearing": bearing},
        metric_kinds={"range": "mean"},
    )


def _shape(rng: np.random.Generator, c: np.ndarray) -> np.ndarray:
    """A U shape or a step of ``c`` (drawn), spanning 0..1 over its 5-95 % range, mean 0."""
    lo, hi = np.percentile(c, [5, 95])
    u = (c - lo) / (hi - lo)
    g = 4 * (u - 0.5) ** 2 if rng.random() < 0.5 else 1 / (1 + np.exp(-(u - rng.uniform(0.3, 0.7)) * 12))
    return g - g.mean()


def test_non_monotone_effects_of_slow_causes_are_found():
    """0.4 noise sd across a slow AR(1) cause's range, U-shaped or a step, AR(1) drift beside: >= 4 of 6 found.

    (A binned regressor shrunk by the cause's design effect saw a U shape at R^2 ~ 0 here; the
    curvature is not extrapolated beyond a time fold's range, which costs some power at this size.)
    """
    wins = []
    for seed in range(6):
        rng = np.random.default_rng(500 + seed)
        n = 800
        cause = _ar1(rng, n, 0.95)
        resid = rng.standard_t(5, size=(n, K)) / np.sqrt(5 / 3) + 0.2 * _ar1(rng, n, 0.9)[:, None]
        resid += 0.4 * _shape(rng, cause)[:, None]
        walk = np.cumsum(rng.normal(size=n))
        ev = _evaluation(resid, {"cause": cause, "walk": walk, "white": rng.normal(size=n)})
        rk = rank_candidates(ev, n_permutations=99, rng=np.random.default_rng(seed))
        wins.append(rk.effects[0]["name"] == "cause" and rk.effects[0]["significant"])
    assert sum(wins) >= 4, wins


def test_a_proxy_of_a_cause_already_added_is_not_significant():
    """The model took the cause as a linear term; its U-shaped remainder shows through a noisy copy of it."""
    hits = []
    for seed in range(4):
        rng = np.random.default_rng(600 + seed)
        n = 800
        cause = _ar1(rng, n, 0.9)
        proxy = 0.9 * cause + np.sqrt(1 - 0.81) * rng.normal(size=n)
        resid = rng.normal(size=(n, K)) + 0.5 * (cause**2 - 1)[:, None]  # the misfit left after a linear term
        ev = _evaluation(resid, {"cause": cause, "proxy": proxy, "white": rng.normal(size=n)})
        rk = rank_candidates(ev, ("cause",), n_permutations=99, given=("cause",), rng=np.random.default_rng(seed))
        px = next(e for e in rk.effects if e["name"] == "proxy")
        hits.append(px["proxy_of"] == "cause" and not px["significant"])
    assert sum(hits) >= 3, hits


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.one_of(st.integers(-1000, 1000).map(float), st.just(float("nan"))), min_size=3, max_size=60),
    st.sampled_from([lambda v: np.arctan(v / 10), lambda v: v**3, lambda v: 3 * v - 7]),
)
def test_rank_basis_depends_on_ranks_only(values, transform):
    """A strictly increasing transform of a candidate gives the same basis (ties and NaN kept)."""
    x = np.asarray(values)
    b = rank_basis(x)
    y = np.where(np.isfinite(x), transform(np.nan_to_num(x)), np.nan)
    np.testing.assert_allclose(rank_basis(y), b, atol=1e-9)
    assert b.shape == (x.size, 4)
    assert np.all(np.abs(b[:, 1:3]) <= 1 + 1e-9)
    np.testing.assert_array_equal(b[:, 3], np.isnan(x))


def test_the_cli_takes_its_search_defaults_from_the_package():
    from sensor_envs.cli.main import build_parser

    for kind in ("lidar", "radar"):
        args = build_parser().parse_args(["diagnose", kind, "x", "--out", "y"])
        assert args.permutations == DEFAULTS["n_permutations"]
        assert args.alpha == DEFAULTS["alpha"]
        assert args.min_score == DEFAULTS["min_score"]
        assert args.max_add == DEFAULTS["max_add"]
    from sensor_envs.cli.diagnose import DIAGNOSE_MAX_READINGS as CLI_ROWS
    from sensor_envs.diagnose.lidar import DIAGNOSE_MAX_READINGS

    assert build_parser().parse_args(["diagnose", "lidar", "x", "--out", "y"]).max_readings == DIAGNOSE_MAX_READINGS
    assert CLI_ROWS == DIAGNOSE_MAX_READINGS


FAST = {"variant": "seed", "n_folds": 3, "h_range_grid": (0.25, 1.6), "h_alpha_grid": (0.5, 4.0), "verbose": False}


def test_one_static_pose_over_time_is_diagnosed():
    """The calibration shape: one pose, many scans; folds are blocks of time. A planted mean effect is found."""
    from sensor_envs.diagnose.core import block_split, run_diagnose
    from sensor_envs.diagnose.lidar import LidarAdapter, lidar_blocks

    case = lidar_case("mean", 3, scans=400, bearings=24, static=True)
    assert np.unique(case.log.poses, axis=0).shape[0] == 1
    blocks = lidar_blocks(case.log.n_poses, 5)
    adapter = LidarAdapter(case.log, block_split(blocks), blocks, params=FAST, max_readings=100)
    res = run_diagnose(adapter, base_state=case.base_state, n_permutations=99, max_add=1)
    assert res.effects[0]["name"] == case.cause, res.effects[:2]
    assert res.added == [case.cause] and res.error_after < res.error_before


def test_static_scan_log_takes_one_pose_of_a_repeated_log():
    from sensor_envs.lidar.log import log_from_arrays

    box = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]], dtype=float)
    rng = np.random.default_rng(0)
    rep = log_from_arrays(rng.uniform(1, 2, (2, 8, 30)), np.linspace(0, 6, 8), [[2, 1.5, 0], [1, 1, 0]], box)
    log = static_scan_log(rep, 1)
    assert log.ranges.shape == (30, 8, 1) and np.all(log.poses == [1, 1, 0]) and log.t is not None
    np.testing.assert_array_equal(log.ranges[:, :, 0], rep.ranges[1].T)


@pytest.mark.parametrize("kind", PLANT_KINDS)
def test_planted_effects_move_the_readings_as_stated(kind):
    """Planting into a scan log: the cause and distractors are new columns; the readings move only as planted."""
    log = lidar_case("null", 11, scans=300, bearings=24).log
    base = replace(log, covariates={k: v for k, v in log.covariates.items() if k in ("v", "omega")})
    case = plant_lidar(base, kind, 4, strength=1.0)
    x0, x1 = base.ranges[..., 0], case.log.ranges[..., 0]
    assert set(case.log.covariates) - set(base.covariates) == set(case.info["planted"])
    assert case.base_state == ("prev_residual",)
    if kind == "null":
        assert case.cause is None
        np.testing.assert_array_equal(x0, x1)
        return
    c = case.log.covariates[case.cause]
    hi, lo = c > np.median(c), c <= np.median(c)
    if kind == "rate":
        assert np.mean(x1 == 0) > np.mean(x0 == 0)
        assert np.all((x1 == x0) | (x1 == 0))
    elif kind == "spread":  # noise added: the mean stays, the spread grows with the cause
        d = np.where(x0 > 0.1, x1 - x0, np.nan)
        sd, s = case.info["sd_m"], case.info["strength"]
        per_scan = np.nanstd(d, axis=1)  # the added noise's sd, from 0 to sd sqrt((1 + s)^2 - 1)
        assert abs(np.nanmean(d)) < 0.05 * sd and np.all(x1[x0 == 0] == 0)
        assert per_scan.min() < 0.2 * per_scan.max()
        assert per_scan.max() == pytest.approx(sd * np.sqrt((1 + s) ** 2 - 1), rel=0.3)
    else:
        assert np.any(x1 != x0) and np.all(x1[x0 == 0] == 0)
        assert not np.allclose(np.mean((x1 - x0)[hi]), np.mean((x1 - x0)[lo]), atol=1e-6) or kind == "interaction"


@pytest.mark.parametrize("kind", [k for k in PLANT_KINDS if k != "null"])
def test_a_planted_case_at_another_strength_is_the_same_case(kind):
    """A given strength changes only the effect's size: the cause, its form and the distractors stay."""
    log = lidar_case("null", 12, scans=200, bearings=16).log
    base = replace(log, covariates={k: v for k, v in log.covariates.items() if k in ("v", "omega")})
    drawn = plant_lidar(base, kind, 7)
    double = plant_lidar(base, kind, 7, strength=2 * drawn.info["strength"])
    assert (drawn.cause, drawn.proxy, drawn.info["form"]) == (double.cause, double.proxy, double.info["form"])
    for k, v in drawn.log.covariates.items():
        np.testing.assert_array_equal(v, double.log.covariates[k])
    moved = [np.abs(c.log.ranges - base.ranges).sum() for c in (drawn, double)]
    assert moved[1] > moved[0] > 0


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known miss (issue 39, docs/results/diagnose_suite.md, real logs): on the real intel log a planted "
    "random walk and the log's own `v` rank above the planted cause; passes (and must be un-marked) once fixed",
)
@pytest.mark.parametrize("kind", ["mean", "rate"])
def test_an_effect_planted_in_the_real_intel_log_is_found(real_data, kind):
    """The CSAIL CARMEN log with a planted cause of 1 residual sd (mean) or a null rate rising by 1 sd."""
    from sensor_envs.diagnose.core import block_split, run_diagnose
    from sensor_envs.diagnose.lidar import LidarAdapter, lidar_blocks
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.mapping import prepare_log

    log, _ = prepare_log(load_log(real_data / "carmen/intel-corrected.log.gz"), max_range=30.0)
    case = plant_lidar(log, kind, 1, strength=1.0)
    blocks = lidar_blocks(case.log.n_poses, 5)
    params = {**FAST, "max_range": 30.0, "spur_above": 31.0, "table_range_step": 0.25}
    adapter = LidarAdapter(case.log, block_split(blocks), blocks, params=params, max_readings=150)
    res = run_diagnose(adapter, base_state=case.base_state)
    assert case.cause in res.added, [(e["name"], e["p_value"]) for e in res.effects[:4]]


@pytest.mark.slow
def test_a_strong_slow_cause_in_a_short_real_log_is_not_taken_for_drift(real_data):
    """The Neato left-side bag (173 scans) with a 2.4-sd step in a slowly wandering cause: the cause is the
    log's drift and hardly varies within the time blocks. Once the log's own turn-rate effect is in the
    model, the cause is significant, ranked first among the planted columns, and it beats independent
    series drawn like it (``p_surrogate``): it is not taken for a shadow of the drift, and it is added
    (the tables fitted as ``diagnose lidar`` fits them). (In the base model's ranking the unmodelled
    turn-rate effect hides it: 52 held-out scans.)"""
    from sensor_envs.diagnose.core import block_split, run_diagnose
    from sensor_envs.diagnose.lidar import DIAGNOSE_LIDAR_PARAMS, DIAGNOSE_MAX_READINGS, LidarAdapter, lidar_blocks
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.mapping import prepare_log

    bags = real_data / "neato_ros1_bags"
    log, _ = prepare_log(load_log(bags / "left_side.bag"), map=str(bags / "mymap.yaml"), align=True)
    drawn = plant_lidar(log, "mean", 0).info["strength"]
    case = plant_lidar(log, "mean", 0, strength=4 * drawn)
    blocks = lidar_blocks(case.log.n_poses, 5)
    adapter = LidarAdapter(
        case.log, block_split(blocks), blocks, params=DIAGNOSE_LIDAR_PARAMS, max_readings=DIAGNOSE_MAX_READINGS
    )
    res = run_diagnose(adapter, base_state=case.base_state)
    assert res.added and res.added[0] not in case.info["planted"], res.added  # the log's own effect first
    planted = [e for e in res.steps[1]["ranking"] if e["name"] in case.info["planted"]]
    first = planted[0]
    assert first["name"] == case.cause, [(e["name"], e["p_value"], e.get("proxy_of")) for e in planted]
    assert first["p_value"] < 0.05 and first.get("proxy_of") is None and first["p_surrogate"] < 0.05
    assert case.cause in res.added and res.error_after < res.steps[1]["error"], res.steps[1]["attempts"]


def test_the_suite_judges_a_cause_at_the_step_it_was_added():
    """``found_stepwise`` (the suite's ``recall_stepwise``): the cause first among the planted columns at
    the step it was added, after the log's own effect; a planted non-cause added, or the cause behind
    another planted column at its step, or no NLL gain, is not a find."""
    from types import SimpleNamespace

    from sensor_envs.diagnose.families import found_stepwise

    case = SimpleNamespace(cause="c", proxy="p", kind="mean", info={"planted": ["c", "p", "d"]})

    def res(added, second_ranking, after=-1.0):
        steps = [
            {
                "ranking": [{"name": "omega"}, {"name": "p"}, {"name": "c"}],
                "attempts": [{"candidate": "omega", "decision": "added omega as bias:omega"}],
            },
            {
                "ranking": [{"name": n} for n in second_ranking],
                "attempts": [{"candidate": a, "decision": f"added {a} as bias:{a}"} for a in added if a != "omega"],
            },
        ]
        return SimpleNamespace(added=added, error_before=0.0, error_after=after, steps=steps)

    assert found_stepwise(case, res(["omega", "c"], ["omega", "c", "p"]))
    assert not found_stepwise(case, res(["omega", "c", "p"], ["c", "p"]))  # the proxy added too
    assert not found_stepwise(case, res(["omega", "c"], ["p", "c"]))  # the proxy led that step
    assert not found_stepwise(case, res(["omega", "c"], ["c"], after=0.5))  # no held-out gain
    assert not found_stepwise(case, res(["omega"], ["c"]))  # never added
