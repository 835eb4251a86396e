"""The rule that chooses the KDE's bandwidth factors on real frames (sensor_envs.radar.tune; sensor-envs tune radar)."""

import numpy as np
import pytest

from sensor_envs.radar import tune
from sensor_envs.radar.fidelity import frames_report
from sensor_envs.radar.kde import KDERadarModel


@pytest.fixture(scope="module")
def script():
    """The bandwidth-factor rule, in the package since 2026-11-28 (tests import no benchmark script)."""
    return tune


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


def test_block_bootstrap_interval_of_the_measured_share_widens_with_scene_to_scene_spread(rig_split):
    """frames_report's measured share resamples whole blocks: alike blocks give a narrow interval, opposite wide."""
    from sensor_envs.radar.gaussian import GaussianRadar

    base = GaussianRadar().fit(rig_split[0])
    rng = np.random.default_rng(0)
    n = 400
    frame = np.arange(n)  # one target per frame, 20 blocks of 20 frames, 20 m ahead
    cols = {"sequence": np.zeros(n, dtype=np.int64), "frame": frame, "target": np.zeros(n, dtype=np.int64)}
    widths = []
    for detected in (rng.random(n) < 0.8, (frame // 20) % 2 == 0):  # alike blocks; half the scenes miss all
        log = _single_frames(cols, detected)
        rep = frames_report({"baseline_gaussian": base}, log, block=20, chains=2, cycles=1, n_boot=500)
        row = rep["start"]["detection_range"][1]  # the 15-30 m bin
        assert row["n"] == n and row["measured_ci"][0] <= row["measured"] <= row["measured_ci"][1]
        widths.append(row["measured_ci"][1] - row["measured_ci"][0])
    assert widths[0] < 0.12  # ~ binomial: 4 sd of sqrt(.16 / 400) = 0.08
    assert widths[1] > 0.3  # 20 scenes of all-or-nothing: the share moves by +-0.2


def _single_frames(cols: dict, detected: np.ndarray):
    """A single-frame log: one 4 x 2 m box 20 m ahead per frame, measured at its closest corner where ``detected``."""
    from sensor_envs.radar.log import RadarLog

    n = detected.size
    box = {"t": cols["frame"].astype(np.float64), "ref_x": np.full(n, 22.0), "ref_y": np.zeros(n)}
    box |= {"ref_heading": np.zeros(n), "ref_length": np.full(n, 4.0), "ref_width": np.full(n, 2.0)}
    meas = {"meas_x": np.where(detected, 20.0, np.nan), "meas_y": np.where(detected, 0.0, np.nan)}
    return RadarLog({**cols, **box, **meas}, source="single frames")
