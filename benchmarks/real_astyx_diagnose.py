"""``diagnose radar`` on the real Astyx HiRes2019 data: which effect does the KDE radar lack?

Loads the frames into a radar object log (:func:`sensor_envs.radar.astyx.load_astyx`; covariates
``ref_z``, ``occlusion``, ``label_certainty``, ``n_points``, ``class_code``, ``aspect``), splits it by
contiguous frame blocks into fit and held-out parts, fits the KDE radar without ``z_{t-1}`` (Astyx is
no time series; corner relevance variance by 3-fold CV on the fit part, as for the shipped model;
output-bandwidth grid 8 m and 3 candidate widths per extra dimension, to keep it within minutes) on
the fit part, ranks the candidates on the held-out residuals with the permutation test, adds the best
significant effect, refits and re-measures (at most 3 refits), and writes ``report.json``,
``report.md`` and the before/after figures into ``--out`` (never into the repository: the data are
CC BY-NC-SA; no model is saved).

``n_points`` (radar detections on the box) is an outcome of the measurement, not a cause: it is 0
exactly when the target is missed, so it is excluded from the candidates by default
(``--keep-n-points`` keeps it, to show that the tool then finds it).

    python benchmarks/real_astyx_diagnose.py --data ../shared/data/real/astyx_hires2019 --out /tmp/astyx_diag
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from sensor_envs.cli.diagnose import write_folder_atomically
from sensor_envs.diagnose.core import block_split, run_diagnose
from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks
from sensor_envs.diagnose.report import write_report
from sensor_envs.radar.astyx import load_astyx

DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "astyx_hires2019"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT), help="astyx_hires2019 folder")
    ap.add_argument("--out", required=True, help="output folder (outside the repository)")
    ap.add_argument("--force", action="store_true", help="replace an existing --out")
    ap.add_argument("--block", type=int, default=10, help="frames per sequence block of the loader")
    ap.add_argument("--model-kind", default="kde", choices=("kde", "gaussian"))
    ap.add_argument("--permutations", type=int, default=999)
    ap.add_argument("--keep-n-points", action="store_true", help="keep n_points among the candidates")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    log = load_astyx(args.data, block=args.block, progress=True)
    held = block_split(radar_blocks(log, args.block))
    params = (
        {
            "use_prev": False,
            "cv_group": "sequence",
            "relevance": "cv",
            "relevance_folds": 3,
            "cv_grid_step": 8.0,
            "extra_candidates": (0.5, 1.0, 2.0),
        }
        if args.model_kind == "kde"
        else {}
    )
    exclude = () if args.keep_n_points else ("n_points",)
    adapter = RadarAdapter(log, held, model_kind=args.model_kind, params=params, progress=True, exclude=exclude)
    res = run_diagnose(adapter, n_permutations=args.permutations, seed=args.seed, progress=True)
    res.extra["model"] = {"kind": args.model_kind, "params": {k: repr(v) for k, v in params.items()}}
    res.extra["excluded_candidates"] = list(exclude)
    data = write_folder_atomically(
        Path(args.out), args.force, lambda tmp: write_report(res, tmp, source=str(args.data))
    )
    wall = time.perf_counter() - t0
    tt_rows = int((~log.is_clutter).sum())
    print(f"Astyx: {len(log)} rows, {tt_rows} target rows; held-out readings {data['details']['readings_held_out']}")
    print(f"model: {args.model_kind} {params}; excluded candidates: {list(exclude)}")
    print("effects (outside the model's state), best first:")
    for e in res.effects:
        flag = "SIGNIFICANT" if e["significant"] else ""
        print(f"  {e['name']:>16s}  R2 {e['score']:+.4f}  p {e['p_value']:.4f}  ({e['metric']}) {flag}")
    print("misfit along the model's own state:")
    for e in res.state_misfit:
        flag = "SIGNIFICANT" if e["significant"] else ""
        print(f"  {e['name']:>16s}  R2 {e['score']:+.4f}  p {e['p_value']:.4f}  ({e['metric']}) {flag}")
    for i, st in enumerate(res.steps):
        print(f"step {i + 1}: model NLL {st['error']:.4f}")
        for at in st.get("attempts", []):
            base = "" if at["baseline_with"] is None else f"; Gaussian baseline with it {at['baseline_with']:.4f}"
            print(f"  refit with {at['candidate']}: NLL {at['error_with']:.4f}{base}: {at['decision']}")
        if not st.get("attempts"):
            print(f"  {st.get('decision', '')}")
    print(f"added: {res.added or 'nothing'}")
    print(f"held-out NLL per reading: before {res.error_before:.4f} -> after {res.error_after:.4f}")
    if res.baseline_before is not None:
        print(f"Gaussian baseline, same state: before {res.baseline_before:.4f} -> after {res.baseline_after:.4f}")
    print(f"figures: {[str(Path(args.out) / f) for f in data['details']['figures']]}")
    print(f"wall time {wall:.1f} s")
    print(json.dumps({k: data[k] for k in ("added", "error_before", "error_after")}))


if __name__ == "__main__":
    main()
