"""The radar targets' bookkeeping of the real-data fidelity report (:func:`sensor_envs.radar.fidelity.target_gaps`,
used by benchmarks/real_radar_fidelity.py): counted as the issue states them."""

import pytest

from sensor_envs.radar.fidelity import target_gaps


def _row(det_range, det_azimuth, energy):
    n = len(energy)
    return {
        "det_range": det_range,
        "det_azimuth": det_azimuth,
        "nll_outcome": 2.5,
        "nll_z_given_detected": 2.4,
        "energy": energy,
        "energy_one_sample": energy,
        "energy_all": energy,
        "energy_margin_ci": [[-0.01, 0.01]] * n,
    }


def test_detection_target_is_counted_against_the_real_share_and_against_the_real_fitted_kde():
    real = {"det_range": [0.80, 0.90], "det_azimuth": [0.77], "det_range_ci": [[0.7, 0.9]] * 2,
            "det_azimuth_ci": [[0.66, 0.89]]}  # fmt: skip
    ref = _row([0.81, 0.90], [0.85], [0.01, 0.01])  # the real-fitted KDE: 0.08 off the real share at azimuth
    model = _row([0.82, 0.96], [0.86], [0.01, 0.02])
    t = target_gaps(model, real, ref)
    assert t["det_bins_within_0.05"] == "1/3"  # 0.02 in; 0.06 and 0.09 off the real share
    assert t["det_bins_within_0.05_of_real_fitted"] == "2/3"  # 0.01, 0.06, 0.01 off the reference
    assert t["max_det_gap"] == pytest.approx(0.09) and t["max_det_gap_to_real_fitted"] == pytest.approx(0.06)
    assert t["energy_bins_within_target"] == "1/2"  # 0.02 > 1.15 x 0.01
