"""Speed of the KDE radar model: us per sample at 1e4/1e5/1e6 tuples, 10 targets per cycle, fit time.

Tuples come from the reference rig (1 s cycles); larger N = more recorded sequences of the same
kind of traffic, so neighbourhoods get denser as N grows (the honest scaling). For every N, three
samplers are timed: the reference exact ball search (``sampler="ball"``), the exact bucket-rejection
sampler (``sampler="bucket"``; ``"auto"`` picks it from 3e4 tuples) and a k-nearest cap (k=64, not
exact). The fidelity of the bucket sampler and of the cap is checked against the exact analytic
PDF (chi-square p-values at 3 states, 95,000 samples each; a faithful sampler gives p-values spread
uniformly on [0, 1]).

    python benchmarks/bench_radar.py                # 1e4, 1e5, 1e6 (the 1e6 rig log takes ~1-2 min)
    python benchmarks/bench_radar.py --sizes 1e4 1e5
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.kde_trees import neighbours
from sensor_envs.radar.log import target_tuples
from sensor_envs.radar.rig import record_rig_log
from sensor_envs.radar.validate import chi_square


def rig_log_with(n_tuples: int, seed: int):
    per_seq = 40 * 8 * 0.92  # cycles x targets x share logged (measured: ~290 target rows per sequence)
    return record_rig_log(max(1, int(np.ceil(n_tuples / per_seq))), 40, 8, np.random.default_rng(seed), progress=True)


class SamplesVsExact:
    """Samples of one sampler, binned PDF of the exact reference model."""

    def __init__(self, sampler: KDERadarModel, exact: KDERadarModel) -> None:
        self.sampler, self.exact = sampler, exact

    def sample(self, s, rng):
        return self.sampler.sample(s, rng)

    def bin_probabilities(self, s, ex, ey):
        return self.exact.bin_probabilities(s, ex, ey)


def time_sampling(model: KDERadarModel, states: np.ndarray, batch: int, repeats: int) -> float:
    """Median us per target over ``repeats`` calls of ``sample_cycle`` with ``batch`` targets."""
    rng = np.random.default_rng(0)
    times = []
    for r in range(repeats):
        s = states[(r * batch) % (len(states) - batch) :][:batch]
        t0 = time.perf_counter()
        model.sample_cycle(s[:, :2], s[:, 2:], rng)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) / batch * 1e6)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    ap.add_argument("--k", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=400)
    args = ap.parse_args()
    results = []
    for n in args.sizes:
        log = rig_log_with(int(n), seed=int(n) % 1000)
        tt = target_tuples(log)
        t0 = time.perf_counter()
        model = KDERadarModel(random_state=0).fit(log, cycle_time=1.0)
        fit_s = time.perf_counter() - t0
        ok = np.isfinite(tt.z_prev[:, 0])
        states = np.concatenate([tt.corner, tt.z_prev], axis=1)[ok]
        states = states[np.random.default_rng(1).permutation(len(states))]
        row = {"n_tuples": int(model.states_.shape[0]), "fit_s_with_loo_cv": round(fit_s, 2)}
        for label, sampler, k in (("ball", "ball", None), ("bucket", "bucket", None), (f"k{args.k}", "ball", args.k)):
            model.sampler, model.k_max = sampler, k
            row[f"us_per_target_{label}_batch10"] = round(time_sampling(model, states, 10, args.repeats), 1)
            row[f"us_per_target_{label}_batch100"] = round(time_sampling(model, states, 100, args.repeats // 4), 1)
            row[f"ms_per_cycle_10_targets_{label}"] = round(row[f"us_per_target_{label}_batch10"] * 10 / 1000, 3)
        model.sampler, model.k_max = "ball", None
        gi, _, q = neighbours(model, states[:2000, :2], states[:2000, 2:])
        row["neighbours_per_query_median"] = float(np.median(np.bincount(q)))
        # fidelity: samples of the bucket sampler and of the cap against the EXACT model's analytic PDF
        other = KDERadarModel.load(model.save(Path(tempfile.gettempdir()) / "_bench_radar_model.npz"))
        for label, sampler, k in (("bucket", "bucket", None), (f"k{args.k}", "ball", args.k)):
            other.sampler, other.k_max = sampler, k
            both = SamplesVsExact(other, model)
            row[f"chi2_p_{label}_vs_exact_pdf"] = [
                round(chi_square(both, states[i], np.random.default_rng(i))["p_value"], 4) for i in range(3)
            ]
        row["chi2_p_ball"] = [
            round(chi_square(model, states[i], np.random.default_rng(i))["p_value"], 4) for i in range(3)
        ]
        print(json.dumps(row))
        results.append(row)
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
