"""``validate lidar``'s verdict per Table I parameter: better / not distinguishable / WORSE (poses resampled)."""

from __future__ import annotations

import numpy as np
import pytest

from sensor_envs.lidar.log import LidarLog
from sensor_envs.lidar.validate import pose_intervals, verdict_markdown
from sensor_envs.maps import load_map


def _case(seed: int, shift: float, poses: int = 12, bearings: int = 40):
    """A log with known cell means and a model whose mu error is the baseline's plus ``shift`` [m] on average."""
    rng = np.random.default_rng(seed)
    true = rng.uniform(0.5, 3.0, (poses, bearings))
    ranges = true[..., None] + 0.01 * rng.standard_normal((poses, bearings, 30))
    log = LidarLog(ranges, np.linspace(0, 2 * np.pi, bearings, endpoint=False), np.zeros((poses, 3)),
                   load_map("seed_room").segments)  # fmt: skip
    base_err = np.abs(0.03 * rng.standard_normal((poses, bearings)))
    model_err = np.maximum(base_err + shift + 0.01 * rng.standard_normal((poses, bearings)), 0.0)
    ones = np.ones((poses, bearings))

    def par(mu):
        return {"mu": mu, "sigma": 0.01 * ones, "p_null": 0.0 * ones}

    params = {"model_extended": par(true + model_err), "ideal": par(true + base_err), "gaussian": par(true + base_err)}
    return log, params


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize(("shift", "word"), [(-0.02, "better"), (0.02, "WORSE")])
def test_the_verdict_follows_a_planted_difference(seed, shift, word):
    log, params = _case(seed, shift)
    iv = pose_intervals(log, params, spur_above=6.0, n_boot=500)
    lo, hi = iv["mae_mu"]["ci95"]
    assert lo <= iv["mae_mu"]["difference"] <= hi
    assert (hi < 0) if shift < 0 else (lo > 0), iv["mae_mu"]
    metrics = {}
    for k, p in params.items():
        err = np.abs(p["mu"] - log.ranges.mean(axis=2)).mean()
        metrics[k] = {"all": {"mae_mu": float(err), "mae_sigma": 0.001, "mae_p_null": 0.0}}
    text = verdict_markdown(metrics, iv)
    line = next(s for s in text.splitlines() if s.startswith("- mean mu"))
    assert line.endswith(word), line
    assert f"over {log.n_poses} poses" in line and "raycast" in line and "Gaussian" in line


def test_the_same_model_as_the_baseline_is_not_distinguishable_from_it():
    log, params = _case(1, 0.0)
    true = log.ranges.mean(axis=2)
    err = np.abs(0.03 * np.random.default_rng(7).standard_normal(true.shape))  # the baseline's error law, drawn anew
    params["model_extended"] = dict(params["ideal"], mu=true + err)
    iv = pose_intervals(log, params, spur_above=6.0, n_boot=500)
    lo, hi = iv["mae_mu"]["ci95"]
    assert lo < 0 < hi, iv["mae_mu"]  # errors of the same law: no verdict
    metrics = {
        k: {"all": {"mae_mu": 0.03 + 1e-4 * (k == "ideal"), "mae_sigma": 0.001, "mae_p_null": 0.0}} for k in params
    }
    assert "poses: not distinguishable" in verdict_markdown(metrics, iv)


def test_one_pose_gives_a_point_interval():
    log, params = _case(0, 0.02, poses=1)
    iv = pose_intervals(log, params, spur_above=6.0, n_boot=50)
    assert iv["mae_mu"]["ci95"][0] == iv["mae_mu"]["ci95"][1] == pytest.approx(iv["mae_mu"]["difference"])
    assert pose_intervals(log, {"ideal": params["ideal"]}, spur_above=6.0) == {}
