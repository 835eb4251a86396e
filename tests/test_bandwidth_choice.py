"""The rule that chooses the KDE's bandwidth factors on real frames (benchmarks/real_radar_bandwidth_scale.py)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from sensor_envs.radar.kde import KDERadarModel

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "real_radar_bandwidth_scale.py"


@pytest.fixture(scope="module")
def script():
    sys.path.insert(0, str(SCRIPT.parent))  # the script imports its sibling real_radar_fidelity
    try:
        spec = importlib.util.spec_from_file_location("real_radar_bandwidth_scale", SCRIPT)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(SCRIPT.parent))
    return mod


def _parts(spread: float, nll: float, seed: int, folds: int = 5) -> list[dict]:
    """Fold scores of a model whose draws spread ``spread`` x the real offsets' (sd 0.5 m), 20 m ahead."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(folds):
        corner = np.column_stack([np.full(200, 20.0), rng.uniform(-3, 3, 200)])
        z = rng.normal(0.0, 0.5, (200, 2))
        samples = rng.normal(0.0, 0.5 * spread, (200, 4, 2))
        out.append({"nll": nll, "corner": corner, "z": z, "samples": samples})
    return out


def test_energy_criterion_keeps_the_nll_guard_and_prefers_the_true_spread(script):
    scores = {
        0.3: _parts(1.0, 3.0, 0),  # the right spread, but its NLL is 20 % above the least: guarded out
        0.6: _parts(1.3, 2.55, 1),
        1.0: _parts(2.0, 2.5, 2),  # the least NLL, far too wide
    }
    final, nested = script.choose(scores, "energy", seed=0)
    assert final == 0.6 and nested == [0.6] * 5
    assert script.choose(scores, "nll", seed=0)[0] == 1.0
    assert script.choose(scores, "energy", seed=0, guard=0.5)[0] == 0.3  # a looser guard admits it


def test_one_standard_error_rule_breaks_a_flat_optimum_toward_one(script):
    same = {0.35: _parts(1.0, 2.5, 4), 0.7: _parts(1.0, 2.5, 3), 1.0: _parts(1.6, 2.5, 5)}
    mean = {f: np.mean([script.criterion([p], "energy", 0) for p in v]) for f, v in same.items()}
    assert mean[0.35] < mean[0.7] < mean[1.0]  # the least mean alone would choose 0.35
    final, _ = script.choose(same, "energy", seed=0)
    assert final == 0.7  # 0.35 and 0.7 draw from the same law: within one standard error, 0.7 is nearer 1


def test_tree_factors_act_on_their_own_kernels(script, outward_rig_log):
    model = KDERadarModel(cv_candidates=(0.1, 0.3, 1.0), cv_max_tuples=150, random_state=0).fit(outward_rig_log(0.5))
    corners = model.states_[:4, :2]
    base = model.bandwidth(corners)
    start = script.with_factor(model, 0.5, "start")
    assert start.start_bandwidth_scale == 0.5 and start.bandwidth_scale == 1.0
    np.testing.assert_allclose(start.bandwidth(corners, start=True), 0.5 * base)
    main = script.with_factor(start, 0.4, "main")
    np.testing.assert_allclose(main.bandwidth(corners), 0.4 * base)
    np.testing.assert_allclose(main.bandwidth(corners, start=True), 0.5 * base)  # the start trees held
    both = script.with_factor(model, 0.4, "both")
    np.testing.assert_allclose(both.bandwidth(corners, start=True), 0.4 * base)


def test_block_bootstrap_interval_of_the_measured_share_widens_with_scene_to_scene_spread(script):
    """real_rates' interval resamples whole blocks: alike blocks give a narrow one, opposite blocks a wide one."""
    fid = sys.modules["real_radar_fidelity"]
    rng = np.random.default_rng(0)
    n = 400
    corner = np.column_stack([np.full(n, 20.0), np.zeros(n)])  # one range bin, the 0-deg azimuth bin
    block = np.repeat(np.arange(20), n // 20)
    alike = np.where((rng.random(n) < 0.8)[:, None], 0.0, np.nan) * np.ones((n, 2))
    split = np.where((block % 2 == 0)[:, None], 0.0, np.nan) * np.ones((n, 2))  # half the scenes miss all
    ci_alike = fid.real_rates(corner, alike, block, np.random.default_rng(1))["det_range_ci"][1]
    ci_split = fid.real_rates(corner, split, block, np.random.default_rng(1))["det_range_ci"][1]
    assert ci_alike[0] <= np.mean(np.isfinite(alike[:, 0])) <= ci_alike[1]
    assert ci_alike[1] - ci_alike[0] < 0.12  # ~ binomial: 4 sd of sqrt(.16 / 400) = 0.08
    assert ci_split[1] - ci_split[0] > 0.3  # 20 scenes of all-or-nothing: the share moves by +-0.2
