"""Time ``sensor-envs diagnose radar`` on a 20,000-row rig log with a hidden latency and distractors,
and ``sensor-envs diagnose lidar`` on a 2,500-scan x 360-bearing synthetic scan log (``--lidar``).

Issue 39's budget on a quiet 2-core machine: 20,000 radar rows in <= 1 min, a 2,500-scan x
360-bearing lidar log in <= 3 min (the load average is printed beside the wall time: a shared machine
is not quiet). The log: reference
rig sequences (``record_rig_log``, with ``rel_vx``/``rel_vy`` columns), measurements shifted by
``-0.4 s * relative velocity`` (undeclared latency), two noise columns and one weak correlate of the
cause. Runs the full CLI path (read CSV, fit, rank, add, refit, report) with default settings.

The lidar log: :func:`sensor_envs.testing.synthetic_lidar.make_log`'s box world with a hidden range bias of
3 cm per rad/s of turn rate (``omega``) beside the distractors ``v``, ``noise_a``, ``weak``.

Usage: ``PYTHONPATH=. python benchmarks/bench_diagnose.py [--rows 20000] [--out DIR]``,
``PYTHONPATH=. python benchmarks/bench_diagnose.py --lidar [--scans 2500] [--bearings 360] [--out DIR]``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from sensor_envs.cli.main import main
from sensor_envs.radar.log import RadarLog, write_log
from sensor_envs.radar.rig import record_rig_log


def make_log(rows: int, seed: int = 0) -> RadarLog:
    """A rig log of about ``rows`` rows with a hidden latency of 0.4 s and three distractor columns."""
    rng = np.random.default_rng(seed)
    n_seq = max(4, int(np.ceil(rows / 300)))  # ~330 rows per 30-cycle, 10-target sequence: at least `rows`
    log = record_rig_log(n_seq, 30, 10, rng, velocity_columns=True)
    c = dict(log.columns)
    tgt = ~np.isnan(c["ref_x"])
    vx, vy = np.nan_to_num(c["rel_vx"]), np.nan_to_num(c["rel_vy"])
    c["meas_x"], c["meas_y"] = c["meas_x"] - 0.4 * vx, c["meas_y"] - 0.4 * vy
    n = tgt.size
    c["noise_a"] = np.where(tgt, rng.normal(size=n), np.nan)
    c["noise_b"] = rng.uniform(size=n)
    c["weak"] = np.where(tgt, 0.3 * vx / np.nanstd(c["rel_vx"]) + rng.normal(size=n), np.nan)
    return RadarLog(c, source=f"bench log ({n} rows)")


def run(rows: int, out: Path | None) -> None:
    """Build the log, run the CLI and print rows, wall time, CPU count and the result."""
    with tempfile.TemporaryDirectory() as tmp:
        log = make_log(rows)
        path = write_log(log, Path(tmp) / "log.csv")
        dest = out if out is not None else Path(tmp) / "out"
        t0, c0 = time.perf_counter(), time.process_time()
        code = main(["diagnose", "radar", str(path), "--out", str(dest), "--force"])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        rep = json.loads((dest / "report.json").read_text())
    print(f"rows: {len(log)} (target rows {int((~log.is_clutter).sum())}), cpus available: {os.cpu_count()}")
    print(f"diagnose radar wall time: {wall:.1f} s (budget 60 s), exit code {code}, load {os.getloadavg()[0]:.1f}")
    print(f"  process CPU time {cpu:.1f} s (all threads; on a loaded machine closer to a quiet run's wall time)")
    print(f"effects (top 3): {[(e['name'], round(e['score'], 4), e['p_value']) for e in rep['effects'][:3]]}")
    print(f"added: {rep['added']}; error_before {rep['error_before']:.4f} -> error_after {rep['error_after']:.4f}")


def run_lidar(scans: int, bearings: int, out: Path | None) -> None:
    """Build the scan log, run ``diagnose lidar`` (default settings) and print size, wall time and result."""
    from sensor_envs.lidar.log import save_log
    from sensor_envs.testing.synthetic_lidar import make_log

    with tempfile.TemporaryDirectory() as tmp:
        path = save_log(make_log("omega", scans=scans, bearings=bearings), Path(tmp) / "log.npz")
        dest = out if out is not None else Path(tmp) / "out"
        t0, c0 = time.perf_counter(), time.process_time()
        code = main(["diagnose", "lidar", str(path), "--out", str(dest), "--force"])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        rep = json.loads((dest / "report.json").read_text())
    print(f"scans x bearings: {scans} x {bearings} = {scans * bearings} readings, cpus available: {os.cpu_count()}")
    print(f"diagnose lidar wall time: {wall:.1f} s (budget 180 s), exit code {code}, load {os.getloadavg()[0]:.1f}")
    print(f"process CPU time: {cpu:.1f} s (all threads; on a loaded machine closer to a quiet run's wall time)")
    print(f"effects (top 3): {[(e['name'], round(e['score'], 4), e['p_value']) for e in rep['effects'][:3]]}")
    print(f"added: {rep['added']}; error_before {rep['error_before']:.4f} -> error_after {rep['error_after']:.4f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=20000)
    ap.add_argument("--lidar", action="store_true", help="time diagnose lidar instead of diagnose radar")
    ap.add_argument("--scans", type=int, default=2500)
    ap.add_argument("--bearings", type=int, default=360)
    ap.add_argument("--out", type=Path, default=None, help="keep the report here (default: a temporary folder)")
    a = ap.parse_args()
    if a.lidar:
        run_lidar(a.scans, a.bearings, a.out)
    else:
        run(a.rows, a.out)
