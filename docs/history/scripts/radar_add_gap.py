"""Held-out NLL of the radar models on the suite's families, with and without the planted cause's correction.

Record (issue 40; not maintained, see docs/history/scripts.md). Found: on the diagnose suite's Gaussian-drawn
families the KDE is structurally worse than the Gaussian and re-tuning its state kernel closes most of the gap
(held-out NLL per reading, mean seed 2000: paper kernel 2.174, re-tuned 1.961, Gaussian 1.912); the planted cause's
correction then gains 0.006-0.031 nats (`89a73aa`; table in docs/results/diagnose_suite.md).

For each case (``sensor_envs.diagnose.families.radar_case``; outputs drawn from a Gaussian radar, one
planted cause), fits on the fit part and scores on the held-out part (the split ``diagnose`` uses):

* the KDE with the paper's state kernel (corner 3 m^2, ``z_{t-1}`` 0.03 m^2), the KDE with the state
  kernel re-tuned on the fit part (``tune_relevance``), the Gaussian baseline;
* each of the last two with the planted cause's correction (the search skipped: the known cause and
  the part it acts on), fitted as ``diagnose`` fits it.

Prints one line per case and model (held-out NLL per reading [nats], lower is better).

Usage::

    nice -n 10 python docs/history/scripts/radar_add_gap.py --cases mean:2000 interaction:1017 spread:34 rate:1051
"""

from __future__ import annotations

import argparse
import time

from sensor_envs.diagnose.core import block_split
from sensor_envs.diagnose.families import radar_case
from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks


def label(case) -> str:
    """The correction label of the planted cause (mean and interaction: the planted axis; spread; rate)."""
    kind = case.kind
    if kind == "mean":
        return f"mean_{case.info['axis']}({case.cause})"
    if kind == "interaction":
        return f"mean_y({case.cause} x azimuth)"
    return f"{kind}({case.cause})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["mean:2000", "interaction:1017", "spread:34", "rate:1051"])
    ap.add_argument("--sequences", type=int, default=60)
    a = ap.parse_args()
    for spec in a.cases:
        kind, seed = spec.split(":")
        case = radar_case(kind, int(seed), sequences=a.sequences)
        held = block_split(radar_blocks(case.log))
        t0 = time.perf_counter()
        out = {}
        paper = RadarAdapter(case.log, held, tune=False)
        out["KDE paper kernel"] = paper.evaluate(paper.fit(())).error
        tuned = RadarAdapter(case.log, held)
        out["KDE re-tuned"] = tuned.evaluate(tuned.fit(())).error
        out["KDE re-tuned + correction"] = tuned.evaluate(tuned.fit((label(case),))).error
        gauss = RadarAdapter(case.log, held, model_kind="gaussian")
        out["Gaussian"] = gauss.evaluate(gauss.fit(())).error
        out["Gaussian + correction"] = gauss.evaluate(gauss.fit((label(case),))).error
        cells = ", ".join(f"{k} {v:.4f}" for k, v in out.items())
        print(
            f"{kind} seed {seed} ({label(case)}; strength {case.info['strength']:.2f}): {cells}; "
            f"re-tuned kernel {tuned.tuning['rel_variance']} ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )


if __name__ == "__main__":
    main()
