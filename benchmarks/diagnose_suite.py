"""Measure ``diagnose`` as a property: recall per effect kind and false positives on null logs.

Draws cases from the seeded families of :mod:`sensor_envs.diagnose.families` (lidar: mean,
interaction with bearing, spread, null rate, AR(1) correlation, null; radar: mean, interaction with
azimuth side, spread, detection rate, null; ``lidar-static``: the lidar families at one pose recorded
over time; ``real``: causes planted into the shared real logs by :func:`~sensor_envs.diagnose.families.plant_lidar`,
skipped when ``--real`` is absent; planted at the smallest multiple of the drawn strength the log
resolves unless ``--real-strength drawn``), runs the diagnosis loop on each as the CLI does
(:func:`sensor_envs.diagnose.core.run_diagnose` with the sensor's adapter, a block split and the
package's search defaults, :data:`sensor_envs.diagnose.search.DEFAULTS`; the lidar tables with the
fast seed variant unless ``--full-fit``), and prints, per sensor and kind:

* recall: the cause ranked first (in the base model's ranking) AND added AND the held-out NLL down; recall
  step by step: the cause first at the step it was added (after the effects added before it) and no other
  planted column added; the share of cases where a proxy, and where any column other than the cause
  (proxy or distractor), was added;
* for null logs, the false-positive rate: any effect significant (and, separately, any added);
* detectability: whether an oracle that knows the cause finds it in the base model's held-out
  residuals at ``alpha / candidates`` (:func:`sensor_envs.diagnose.power.detectable`), and the recall
  on the detectable cases: a miss below the log's detection limit is told from a miss of the search.

On a real log only the planted columns count: "ranked first" is first among them, a false positive
is a planted distractor significant (the log's own time, speed, turn-rate effects may be real).

Writes ``suite.json`` (every case: drawn parameters, ranking head, decision) and ``suite.md``.

Usage (a few minutes, niced)::

    nice -n 10 python benchmarks/diagnose_suite.py --cases 3 --seed 0 --out /tmp/suite

``--cases N`` cases per kind and sensor; ``--sensor lidar lidar-static radar both real``; ``--real DIR
--real-cases N``; ``--scans``/``--bearings``
and ``--sequences`` set the log sizes (the shared real logs: ~2,500 scans x 360 bearings; ~20,000
radar rows = ``--sequences 60``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.diagnose.core import DEFAULTS, NLL_CAP, block_split, run_diagnose
from sensor_envs.diagnose.families import (
    LIDAR_KINDS,
    PLANT_KINDS,
    RADAR_KINDS,
    Case,
    found_stepwise,
    lidar_case,
    plant_lidar,
    radar_case,
    static_scan_log,
)
from sensor_envs.diagnose.power import detectable

LIDAR_FIT = {
    "variant": "seed",
    "n_folds": 3,
    "h_range_grid": (0.25, 1.6),
    "h_alpha_grid": (0.5, 4.0),
    "verbose": False,
}
"""Table fit of the lidar cases (the fast seed variant: the suite measures the search, not the tables)."""


CARMEN_FIT = {"max_range": 30.0, "spur_above": 31.0, "table_range_step": 0.25}
REAL_LOGS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "intel": ("carmen/intel-corrected.log.gz", {"max_range": 30.0}, CARMEN_FIT),
    "aces": ("carmen/aces-corrected.log.gz", {"max_range": 30.0}, CARMEN_FIT),
    "neato-middle": ("neato_ros1_bags/middle.bag", {"map": "neato_ros1_bags/mymap.yaml", "align": True}, {}),
    "neato-left": ("neato_ros1_bags/left_side.bag", {"map": "neato_ros1_bags/mymap.yaml", "align": True}, {}),
    "neato-right": ("neato_ros1_bags/right_side.bag", {"map": "neato_ros1_bags/mymap.yaml", "align": True}, {}),
    "neato-static": ("neato_mar27_train.npz", {"static_pose": 0}, {}),
    "neato-static-14": ("neato_mar27_train.npz", {"static_pose": 14}, {}),
}
"""Real logs of the shared folder (name: relative path, how the CLI would prepare it, table options).
``neato-static``, ``neato-static-14``: the repeated Neato log's first and fifteenth pose, each one static pose
recorded over time."""


def load_real(root: Path, name: str) -> Any:
    """The real log ``name`` of :data:`REAL_LOGS` read and prepared as ``sensor-envs diagnose lidar`` does."""
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.mapping import prepare_log

    rel, prep, _ = REAL_LOGS[name]
    log = load_log(root / rel)
    if "static_pose" in prep:
        return static_scan_log(log, prep["static_pose"])
    opts = {k: (str(root / v) if k == "map" else v) for k, v in prep.items()}
    return prepare_log(log, **opts)[0]


def _adapter(case: Case, sensor: str, full_fit: bool, fit: dict[str, Any] | None) -> Any:
    """The sensor's adapter on the case's log with the CLI's block split (see :func:`diagnose_case`)."""
    if sensor == "lidar":
        from sensor_envs.diagnose.lidar import DIAGNOSE_LIDAR_PARAMS, DIAGNOSE_MAX_READINGS, LidarAdapter, lidar_blocks

        blocks = lidar_blocks(case.log.n_poses, 5)
        params, rows = (DIAGNOSE_LIDAR_PARAMS, DIAGNOSE_MAX_READINGS) if full_fit else (LIDAR_FIT, 150)
        params = {**params, **(fit or {})}
        return LidarAdapter(case.log, block_split(blocks), blocks, params=params, max_readings=rows)
    from sensor_envs.diagnose.radar import RadarAdapter, radar_blocks

    return RadarAdapter(case.log, block_split(radar_blocks(case.log)))


STRENGTH_FACTORS = (1.0, 2.0, 4.0, 8.0)
"""Multiples of a real case's drawn strength tried, in order, until the oracle resolves the cause."""


def resolvable_plant(log: Any, kind: str, seed: int, fit: dict[str, Any], full_fit: bool) -> tuple[Case, Any]:
    """A cause planted into a real log at the smallest strength the log resolves.

    The case of :func:`~sensor_envs.diagnose.families.plant_lidar` (same seed: the same cause, form and
    distractors) at its drawn strength times 1, 2, 4, 8 until an oracle that knows the cause finds it in
    the base model's held-out residuals at ``alpha / candidates``
    (:func:`~sensor_envs.diagnose.power.detectable`): a strength the log can resolve.
    ``info["strength_factor"]`` records the multiple (8 and ``resolvable: False`` when none sufficed);
    a null case is planted as drawn. Returns the case and the adapter of the last strength tried (its
    base fit is the diagnosis's).
    """
    case = plant_lidar(log, kind, seed)
    if kind == "null":
        return case, None
    drawn, adapter = case.info["strength"], None
    for factor in STRENGTH_FACTORS:
        case = plant_lidar(log, kind, seed, strength=drawn * factor)
        adapter = _adapter(case, "lidar", full_fit, fit)
        ev = adapter.evaluate(adapter.fit(case.base_state))
        n_cand = len(set(ev.candidates) - set(adapter.state_features()))
        ok, _ = detectable(ev, str(case.cause), n_cand)
        case.info.update(strength_factor=factor, drawn_strength=drawn, resolvable=ok)
        if ok:
            break
    return case, adapter


def diagnose_case(
    case: Case,
    sensor: str,
    permutations: int = DEFAULTS["n_permutations"],
    seed: int = 0,
    alpha: float = DEFAULTS["alpha"],
    full_fit: bool = False,
    fit: dict[str, Any] | None = None,
    adapter: Any = None,
) -> Any:
    """Run the loop on one case as the CLI would (block split, adapter, run_diagnose with its defaults).

    ``full_fit``: the lidar tables are fitted as ``sensor-envs diagnose lidar`` fits them (its
    ``DIAGNOSE_LIDAR_PARAMS`` and ``--max-readings`` default) instead of the fast seed variant;
    ``fit``: table options of the log (e.g. a CARMEN log's ``max_range``); ``adapter``: one already built
    on the case (its base fit is reused).
    """
    adapter = _adapter(case, sensor, full_fit, fit) if adapter is None else adapter
    res = run_diagnose(adapter, base_state=case.base_state, n_permutations=permutations, alpha=alpha, seed=seed)
    if sensor == "radar":  # what was added, in words, and the held-out NLL per part (detection, position)
        from sensor_envs.diagnose.radar_add import loop_extras

        res.extra.update(loop_extras(adapter, res))
        res.extra["corrections"] = [t["text"] for t in res.extra["corrections"]]
        res.extra["gaussian_before_after"] = (res.baseline_before, res.baseline_after)
    return res


def score_case(case: Case, res: Any) -> dict[str, Any]:
    """The case's outcome: top-ranked effect, added, errors, and whether the loop closed (or stayed quiet)."""
    planted = case.info.get("planted")  # a real log: its own effects (time, motion, correlation) may be real
    ranked = [e for e in res.effects if planted is None or e["name"] in planted]
    top = ranked[0]["name"] if ranked else None
    sig = [e["name"] for e in res.effects if e["significant"]]
    out: dict[str, Any] = {
        "kind": case.kind,
        "cause": case.cause,
        "proxy": case.proxy,
        "top": top,
        "top3": [(e["name"], round(e["score"], 5), e["p_value"]) for e in res.effects[:3]],
        "significant": sig,
        "added": list(res.added),
        "error_before": res.error_before,
        "error_after": res.error_after,
        # median held-out NLL per reading (capped as the mean): a change a few readings carry shows here
        "median_before": float(np.median(np.minimum(res.before.nll, NLL_CAP))) if res.before is not None else None,
        "median_after": float(np.median(np.minimum(res.after.nll, NLL_CAP))) if res.after is not None else None,
        "info": case.info,
        "radar": {
            k: res.extra[k]
            for k in ("corrections", "nll_parts_before", "nll_parts_after", "state_tuning", "gaussian_before_after")
            if k in res.extra
        },
    }
    if case.cause is not None and res.before is not None and case.cause in res.before.candidates:
        ok, test = detectable(res.before, case.cause, len(res.effects))  # the candidates the search tested
        out["detectable"], out["oracle"] = ok, test
    if case.kind == "null":  # on a real log only the planted columns count
        out["false_positive"] = any(planted is None or s in planted for s in sig)
        out["false_addition"] = any(planted is None or s in planted for s in res.added)
    else:
        out["recall"] = bool(top == case.cause and case.cause in res.added and res.error_after < res.error_before)
        out["proxy_added"] = bool(case.proxy is not None and case.proxy in res.added)
        out["recall_stepwise"] = found_stepwise(case, res)
    return out


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per sensor and kind: cases, recall (or false-positive rates), proxy additions."""
    out: dict[str, Any] = {}
    for sensor in sorted({r["sensor"] for r in rows}):
        for kind in dict.fromkeys(r["kind"] for r in rows if r["sensor"] == sensor):
            sel = [r for r in rows if r["sensor"] == sensor and r["kind"] == kind]
            d: dict[str, Any] = {"cases": len(sel)}
            if kind == "null":
                d["false_positive_rate"] = float(np.mean([r["false_positive"] for r in sel]))
                d["false_addition_rate"] = float(np.mean([r["false_addition"] for r in sel]))
            else:
                d["recall"] = float(np.mean([r["recall"] for r in sel]))
                d["recall_stepwise"] = float(np.mean([r.get("recall_stepwise", False) for r in sel]))
                d["cause_first"] = float(np.mean([r["top"] == r["cause"] for r in sel]))
                d["proxy_added"] = float(np.mean([r["proxy_added"] for r in sel]))
                d["other_added"] = float(np.mean([any(a != r["cause"] for a in r["added"]) for r in sel]))
                det = [r for r in sel if r.get("detectable")]
                d["detectable"] = len(det)
                d["recall_detectable"] = float(np.mean([r["recall"] for r in det])) if det else float("nan")
            # held-out NLL change per reading (after minus before; negative: better), mean and median over cases
            dm = [r["error_after"] - r["error_before"] for r in sel]
            dmed = [r["median_after"] - r["median_before"] for r in sel if r.get("median_before") is not None]
            d["nll_change_mean"] = float(np.mean(dm))
            d["nll_change_median"] = float(np.median(dmed)) if dmed else float("nan")
            out[f"{sensor}/{kind}"] = d
    return out


def markdown(summary: dict[str, Any], rows: list[dict[str, Any]], command: str) -> str:
    """The summary table and one line per case."""
    lines = [
        "# diagnose suite",
        "",
        f"Command: `{command}`, run on {time.strftime('%Y-%m-%d', time.gmtime())} (UTC).",
        "",
    ]
    lines += [
        "| sensor/kind | cases | recall | recall step by step | cause first | proxy added | any non-cause added "
        "| false pos. (significant) "
        "| false pos. (added) | detectable (oracle) | recall on detectable | held-out NLL change, mean "
        "(median) [nats] |"
    ]
    lines += ["|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for k, d in summary.items():

        def f(key: str, d: dict[str, Any] = d) -> str:
            return f"{d[key]:.2f}" if key in d else ""

        lines.append(
            f"| {k} | {d['cases']} | {f('recall')} | {f('recall_stepwise')} | {f('cause_first')} | "
            f"{f('proxy_added')} | {f('other_added')} | "
            f"{f('false_positive_rate')} | {f('false_addition_rate')} | {d.get('detectable', '')} | "
            f"{f('recall_detectable')} | {d['nll_change_mean']:+.4f} ({d['nll_change_median']:+.4f}) |"
        )
    lines += ["", "## Cases", ""]
    for r in rows:
        lines.append(
            f"- {r['sensor']} {r['kind']} seed {r['seed']}: cause {r['cause']}, top {r['top3']}, added {r['added']}, "
            f"NLL {r['error_before']:.4f} -> {r['error_after']:.4f}"
            + (
                f" (median {r['median_before']:.4f} -> {r['median_after']:.4f})"
                if r.get("median_before") is not None
                else ""
            )
            + f", strength {r['info'].get('strength', 0):.2f} "
            f"({r['info'].get('form')}), "
            + (f"x{r['info']['strength_factor']:g} of the drawn, " if "strength_factor" in r["info"] else "")
            + (f"oracle p {r['oracle']['p_value']:.2g} ({r['oracle']['best']}), " if "oracle" in r else "")
            + f"{r['seconds']:.0f} s"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=3, help="cases per kind and sensor (default 3)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first case (cases use seed, seed+1, ...)")
    ap.add_argument(
        "--sensor",
        choices=("lidar", "lidar-static", "radar", "both", "real", "none"),
        nargs="*",
        default=["both"],
        help="families: lidar (moving scans), lidar-static (one pose over time), radar, both (lidar and radar), "
        "real (needs --real), none",
    )
    ap.add_argument("--real", type=Path, default=None, help="the shared real-data folder (skipped when absent)")
    ap.add_argument("--real-cases", type=int, default=2, help="planted cases per kind and real log (default 2)")
    ap.add_argument(
        "--real-logs", nargs="*", choices=list(REAL_LOGS), default=None, help="only these real logs, in this order"
    )
    ap.add_argument(
        "--real-strength",
        choices=("resolvable", "drawn"),
        default="resolvable",
        help="real cases: the drawn strength times the smallest of 1, 2, 4, 8 the log resolves (default), or as drawn",
    )
    ap.add_argument("--kinds", nargs="*", default=None, help="only these kinds")
    ap.add_argument("--scans", type=int, default=500)
    ap.add_argument("--bearings", type=int, default=60)
    ap.add_argument("--sequences", type=int, default=24, help="radar sequences (30 cycles x 10 targets each)")
    ap.add_argument("--permutations", type=int, default=DEFAULTS["n_permutations"], help="default: the CLI's")
    ap.add_argument("--alpha", type=float, default=DEFAULTS["alpha"], help="family-wise level (default: the CLI's)")
    ap.add_argument("--full-fit", action="store_true", help="lidar tables fitted as the CLI fits them (slow)")
    ap.add_argument("--out", type=Path, default=Path("diagnose_suite_out"))
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for label, kind, seed, make, fit in _jobs(a):
        t0 = time.perf_counter()
        made = make()
        case, adapter = made if isinstance(made, tuple) else (made, None)
        sensor = "radar" if label == "radar" else "lidar"
        res = diagnose_case(case, sensor, a.permutations, seed, a.alpha, a.full_fit, fit, adapter)
        row = {"sensor": label, "seed": seed, **score_case(case, res)}
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        partial_rows = {"command": "(partial: the cases done so far)", "summary": summarise(rows), "cases": rows}
        (a.out / "suite.partial.json").write_text(json.dumps(partial_rows, indent=1))  # a long run survives a stop
        ok = row.get("recall", not row.get("false_positive", False))
        print(
            f"{label} {kind} seed {seed}: {'ok' if ok else 'MISS'} top {row['top3'][:2]} "
            f"cause {case.cause} added {row['added']} oracle {row.get('oracle', {}).get('p_value', float('nan')):.2g} "
            f"({row['seconds']:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
    summary = summarise(rows)
    command = "python benchmarks/diagnose_suite.py " + " ".join(sys.argv[1:] if argv is None else argv)
    (a.out / "suite.json").write_text(json.dumps({"command": command, "summary": summary, "cases": rows}, indent=1))
    (a.out / "suite.partial.json").unlink(missing_ok=True)
    (a.out / "suite.md").write_text(markdown(summary, rows, command))
    for k, d in summary.items():
        print(k, json.dumps(d))
    return 0


def _jobs(a: argparse.Namespace) -> list[tuple[str, str, int, Any, dict[str, Any]]]:
    """(label, kind, seed, case maker, table options) of every case the options ask for."""
    sensors = [x for s in a.sensor for x in (("lidar", "radar") if s == "both" else (s,))]
    jobs: list[tuple[str, str, int, Any, dict[str, Any]]] = []
    for sensor in [s for s in sensors if s in ("lidar", "lidar-static", "radar")]:
        kinds = RADAR_KINDS if sensor == "radar" else LIDAR_KINDS
        for kind in [k for k in kinds if a.kinds is None or k in a.kinds]:
            for j in range(a.cases):
                seed = a.seed + 1000 * j + 17 * kinds.index(kind)
                if sensor == "radar":
                    make = partial(radar_case, kind, seed, sequences=a.sequences)
                else:
                    make = partial(lidar_case, kind, seed, a.scans, a.bearings, sensor == "lidar-static")
                jobs.append((sensor, kind, seed, make, {}))
    if "real" in sensors:
        if a.real is None or not a.real.is_dir():
            print(f"real logs skipped: --real {a.real} is not a folder", file=sys.stderr)
            return jobs
        for name in REAL_LOGS if a.real_logs is None else a.real_logs:
            rel, _, fit = REAL_LOGS[name]
            if not (a.real / rel).is_file():
                print(f"real log {name} skipped: {a.real / rel} is absent", file=sys.stderr)
                continue
            log = load_real(a.real, name)
            for kind in [k for k in PLANT_KINDS if a.kinds is None or k in a.kinds]:
                for j in range(a.real_cases):
                    seed = a.seed + 1000 * j + 17 * PLANT_KINDS.index(kind)
                    plant = (
                        partial(plant_lidar, log, kind, seed)
                        if a.real_strength == "drawn"
                        else partial(resolvable_plant, log, kind, seed, fit, a.full_fit)
                    )
                    jobs.append((f"real:{name}", kind, seed, plant, fit))
    return jobs


if __name__ == "__main__":
    raise SystemExit(main())
