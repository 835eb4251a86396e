"""What ``validate radar`` tells a user about the shipped radar models on real Astyx frames, with the tail mixture.

Writes ``docs/results/radar_validate.md`` and ``models/metrics/<name>.heldout.json`` (the figures a model card
states, in the schema of :mod:`sensor_envs.cards`: mean and median NLL of ``z`` given a detection, with 95 %
block-bootstrap intervals, against the Gaussian baseline on held-out real frames, start tuple and stationary law).

The shipped KDEs were fitted on the calibrated rig's log: they never saw a real row. Their tail mixture
(``tail_weight``, ``tail_scale``) was chosen on these frames by ``sensor-envs tune radar`` (folds of 10-frame
blocks). The figures here are NESTED: the rows of fold ``k`` are scored with the tail chosen on the other
folds (``--tune-json``: ``tune radar --json``'s ``nested_choice``), so no row scores a parameter chosen on
it. The same KDE without the tail (``tail_weight = 0``, the files before 2026-11-28) is scored beside.

With ``--detection``, also ``sensor-envs evaluate radar-detection`` (the "car in my lane within 40 m" trigger)
on the same frames for the shipped ``radar_kde.npz`` and the same file without its tail: the distance of the
KDE's and the Gaussian's precision-recall points to the real ones. With ``--user-chain``, also the documented
commands of a user fitting their own real frames (``fit radar --no-prev``, ``tune radar --refit``), scored on
outer folds they never saw.

    python benchmarks/real_radar_validate.py --data ../shared/data/real/astyx_hires2019 \\
        --tune-json /tmp/radar_kde.tail.json /tmp/radar_kde_fast.tail.json [--detection] [--user-chain]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.outputs import write_json
from sensor_envs.radar.fidelity import (
    BASELINE,
    check_folds,
    concat_laws,
    fold_rows,
    load_real_log,
    row_blocks,
    score_laws,
    summarise,
    verdict_lines,
)
from sensor_envs.radar.gaussian import GaussianRadar
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import TargetTuples
from sensor_envs.radar.sensors import IdealRadar

ROOT = Path(__file__).resolve().parents[1]
PAIRS = {"radar_kde": "radar_gaussian", "radar_kde_fast": "radar_gaussian_fast"}
"""The shipped KDE files and their Gaussian baselines (``models/``)."""


def nested_report(
    kde: KDERadarModel, base: GaussianRadar, folds: list, nested: list, args: argparse.Namespace
) -> dict[str, Any]:
    """:func:`summarise` of the folds' rows, fold ``k`` scored with the tail ``nested[k]`` (and without a tail)."""
    parts, tts = [], []
    for k, (tt, test) in enumerate(folds):  # one iteration per fold
        models = {
            "model": kde.with_tail(*nested[k]),
            "model_without_tail": kde.with_tail(0.0, kde.tail_scale),
            BASELINE: base,
            "ideal": IdealRadar(),
        }
        parts.append(score_laws(models, tt, test, args.seed + k, args.chains, args.cycles))
        tts.append(tt)
        print(f"  fold {k}: tail {nested[k]}", file=sys.stderr, flush=True)
    return _pooled(parts, tts, args)


def user_chain(log: Any, folds: list, args: argparse.Namespace) -> tuple[dict[str, Any], list]:
    """The documented commands of a user fitting their own real frames, scored on outer folds they never saw.

    Per outer fold: ``fit radar TRAIN --no-prev --cv-group sequence`` (KDE and Gaussian on the other folds),
    ``tune radar KDE TRAIN --what tail --refit`` (tail chosen on inner folds of TRAIN, each scored by a KDE
    fitted without it), then the held-out fold scored (``validate radar``). Returns the :func:`summarise`
    report (KDE with and without its tail vs the fold's Gaussian) and the tail chosen per outer fold.
    """
    from sensor_envs.radar.tune import choose_tail, refit, tail_scores
    from sensor_envs.radar.validate import split_by_blocks

    parts, tts, chosen = [], [], []
    for k, (tt, test) in enumerate(folds):  # one iteration per outer fold
        train, _ = split_by_blocks(log, block=args.block, n_folds=args.folds, fold=k)
        kde = KDERadarModel(use_prev=False, cv_group="sequence", random_state=args.seed).fit(train)
        base = GaussianRadar().fit(train)
        inner = [fold_rows(train, args.block, args.folds, j) for j in range(args.folds)]
        inner_models = [refit(kde, split_by_blocks(train, args.block, args.folds, j)[0]) for j in range(args.folds)]
        final, _ = choose_tail(tail_scores(inner_models, inner, seed=args.seed, chains=1, cycles=1))
        chosen.append(list(final))
        models = {"model": kde.with_tail(*final), "model_without_tail": kde, BASELINE: base, "ideal": IdealRadar()}
        parts.append(score_laws(models, tt, test, args.seed + k, args.chains, 1))
        tts.append(tt)
        print(f"  user chain, fold {k}: tail {final}", file=sys.stderr, flush=True)
    return _pooled(parts, tts, args), chosen


def _pooled(parts: list, tts: list, args: argparse.Namespace) -> dict[str, Any]:
    """:func:`summarise` of per-fold :func:`score_laws` results, blocks numbered apart per fold."""
    tt = TargetTuples(**{f: np.concatenate([getattr(t, f) for t in tts]) for f in TargetTuples.__dataclass_fields__})
    blocks = np.concatenate([row_blocks(t, args.block) + 100_000 * k for k, t in enumerate(tts)])
    _, blocks = np.unique(blocks, return_inverse=True)
    return summarise(concat_laws(parts), tt, blocks.reshape(-1), args.seed, args.n_boot)


def card_metrics(rep: dict[str, Any], name: str, tune: dict[str, Any], args: argparse.Namespace) -> dict[str, Any]:
    """The figures a model card states, from a :func:`nested_report`, in the schema of ``sensor_envs.cards``.

    ``metrics``: per law, the KDE's mean and median NLL of z given a detection with intervals and the
    Gaussian's beside them (``reference``), and the verdict; ``detail``: every figure, for a generator.
    """
    data = f"{Path(args.data).name}: {rep['n_detected']} detected car rows of {rep['n_rows']}, {rep['n_blocks']} blocks"
    out: dict[str, Any] = {
        "measured": {
            "command": "python benchmarks/real_radar_validate.py --data astyx_hires2019 --tune-json "
            + " ".join(f"{n}.tail.json" for n in args.names)
            + f" --chains {args.chains} --cycles {args.cycles}",
            "date": time.strftime("%Y-%m-%d", time.gmtime()),
            "data": f"{data}; held out: the KDE was fitted on the rig log, its tail chosen on the other folds",
        },
        "metrics": [],
    }
    detail: dict[str, Any] = {"tail": tune["final"], "tail_nested_choice": tune["nested_choice"], "folds": args.folds}
    for law in ("start", "stationary"):
        nll = rep[law]["nll_z_given_detected"]
        m, g, o = nll["model"], nll[BASELINE], nll["model_without_tail"]
        for st in ("mean", "median"):
            out["metrics"].append(
                {
                    "name": f"NLL of z given a detection, {law} {'tuple' if law == 'start' else 'law'}, {st}",
                    "value": round(m[st], 4),
                    "interval": [round(v, 4) for v in m[f"{st}_ci"]],
                    "unit": "nats",
                    "reference": f"Gaussian baseline {g[st]:.3f} [{g[f'{st}_ci'][0]:.3f}, {g[f'{st}_ci'][1]:.3f}]; "
                    f"without the tail {o[st]:.3f}",
                    "note": f"verdict vs the Gaussian: {m[f'{st}_verdict']} (paired 95 % interval of the difference "
                    f"[{m[f'{st}_diff_ci'][0]:+.3f}, {m[f'{st}_diff_ci'][1]:+.3f}], whole 10-frame scenes resampled)",
                }
            )
        detail[law] = {"kde": m, "kde_without_tail": o, "gaussian": g}
    out["detail"] = detail
    return out


def nll_table(rep: dict[str, Any]) -> list[str]:
    """Markdown rows: NLL of z given a detection per law, model / without tail / Gaussian, with verdicts."""
    lines = [
        "| law | statistic | KDE with tail | KDE without tail | Gaussian | KDE - Gaussian [95 %] | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for law in ("start", "stationary"):
        nll = rep[law]["nll_z_given_detected"]
        for st in ("mean", "median"):
            cells = []
            for k in ("model", "model_without_tail", BASELINE):
                ci = nll[k][f"{st}_ci"]
                cells.append(f"{nll[k][st]:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]")
            d = nll["model"]
            diff = f"{d[f'{st}_diff']:+.3f} [{d[f'{st}_diff_ci'][0]:+.3f}, {d[f'{st}_diff_ci'][1]:+.3f}]"
            lines.append(f"| {law} | {st} | " + " | ".join(cells) + f" | {diff} | {d[f'{st}_verdict']} |")
    return lines


def detection_table(rep: dict[str, Any], law: str) -> list[str]:
    """Markdown rows: detection per range and azimuth bin, measured vs KDE, Gaussian and ideal radar."""
    lines = [
        "| bin | n | measured [95 %] | KDE | Gaussian | ideal | KDE gap vs Gaussian gap |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, unit in (("detection_range", "m"), ("detection_azimuth", "deg")):
        for row in rep[law][key]:
            if "measured" not in row:
                continue
            ci = row["measured_ci"]
            lines.append(
                f"| {key.split('_')[1]} {row['lo']:g}..{row['hi']:g} {unit} | {row['n']} | {row['measured']:.3f} "
                f"[{ci[0]:.3f}, {ci[1]:.3f}] | {row['model']:.3f} | {row[BASELINE]:.3f} | {row['ideal']:.3f} | "
                f"{row['model_verdict']} |"
            )
    return lines


def detection_runs(args: argparse.Namespace, work: Path) -> list[dict[str, Any]]:
    """``sensor-envs evaluate radar-detection`` on the frames: the shipped KDE, and the same file without its tail
    (written to ``work``: the file shipped before 2026-11-28)."""
    shipped = ROOT / "models" / "radar_kde.npz"
    kde = KDERadarModel.load(shipped)
    no_tail = work / "radar_kde_without_tail.npz"
    kde.with_tail(0.0, kde.tail_scale).save(no_tail, card=kde.card_)
    out = []
    for i, model in enumerate([str(no_tail), str(shipped)]):  # one run per KDE file
        dest = work / f"detection_{i}"
        cmd = ["evaluate", "radar-detection", "--real", str(args.data), "--model", model,
               "--baseline", str(ROOT / "models" / "radar_gaussian.npz"), "--out", str(dest), "--force"]  # fmt: skip
        print("$ sensor-envs " + " ".join(cmd), file=sys.stderr, flush=True)
        subprocess.run([sys.executable, "-m", "sensor_envs.cli.main", *cmd], check=True, cwd=ROOT)
        rep = json.loads((dest / "report.json").read_text(encoding="utf-8"))
        out.append({"file": model, "command": "sensor-envs " + " ".join(cmd), **rep["distance_to_real"]})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real" / "astyx_hires2019"))
    ap.add_argument("--names", nargs="*", default=list(PAIRS), choices=list(PAIRS), help="shipped KDEs to score")
    ap.add_argument("--tune-json", nargs="*", default=[], help="tune radar --json of each of --names, in order")
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--chains", type=int, default=16)
    ap.add_argument("--cycles", type=int, default=5)
    ap.add_argument("--n-boot", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--detection", action="store_true", help="also run evaluate radar-detection")
    ap.add_argument("--user-chain", action="store_true", help="also score fit + tune --refit on real folds")
    ap.add_argument("--work", default="/tmp/real_radar_validate", help="folder of the evaluate runs (created)")
    ap.add_argument("--md", default=str(ROOT / "docs" / "results" / "radar_validate.md"))
    ap.add_argument("--metrics-dir", default=str(ROOT / "models" / "metrics"), help="where <name>.heldout.json go")
    args = ap.parse_args()
    if len(args.tune_json) != len(args.names):
        print("--tune-json: one file per --names entry", file=sys.stderr)
        raise SystemExit(2)
    t0 = time.perf_counter()
    try:
        log = load_real_log(args.data, block=args.block)
        check_folds(log, args.block, args.folds)
        tunes = [json.loads(Path(p).read_text(encoding="utf-8")) for p in args.tune_json]
    except (OSError, ValueError) as exc:
        print(f"{exc}: nothing written", file=sys.stderr)
        raise SystemExit(2) from None
    folds = [fold_rows(log, args.block, args.folds, k) for k in range(args.folds)]
    Path(args.work).mkdir(parents=True, exist_ok=True)
    md = ["# `validate radar` on real Astyx frames: the KDE's tails against the Gaussian", "", *intro(args), ""]
    for name, tune in zip(args.names, tunes, strict=True):  # one iteration per shipped model
        print(f"{name}:", file=sys.stderr, flush=True)
        kde = KDERadarModel.load(ROOT / "models" / f"{name}.npz")
        base = GaussianRadar.load(ROOT / "models" / f"{PAIRS[name]}.npz")
        nested = [tuple(p) for p in tune["nested_choice"]]
        rep = nested_report(kde, base, folds, nested, args)
        write_json(Path(args.metrics_dir) / f"{name}.heldout.json", card_metrics(rep, name, tune, args))
        md += model_section(name, kde, tune, rep)
    if args.user_chain:
        rep, chosen = user_chain(log, folds, args)
        write_json(Path(args.work) / "user_chain.json", {"tails": chosen, "report": rep})
        md += user_section(rep, chosen)
    if args.detection:
        md += detection_section(detection_runs(args, Path(args.work)))
    md += ["", f"Generated on {time.strftime('%Y-%m-%d', time.gmtime())} (UTC) by "
           f"`python benchmarks/real_radar_validate.py {' '.join(sys.argv[1:])}` "
           f"in {time.perf_counter() - t0:.0f} s."]  # fmt: skip
    Path(args.md).write_text("\n".join(md) + "\n", encoding="utf-8")
    print("\n".join(md))


def intro(args: argparse.Namespace) -> list[str]:
    """The page's opening: what is measured and the commands a user runs."""
    return [
        f"Data: `{Path(args.data).name}`, {args.folds} folds of {args.block}-frame blocks. The shipped KDEs were "
        "fitted on the calibrated rig's log and never saw a real row; their tail mixture "
        "(`tail_weight`, `tail_scale`: `p(z | x, det) = (1 - w) KDE_h + w KDE_{c h}`) was chosen on these "
        "frames by cross-validation. Figures are nested: fold k's rows are scored with the tail chosen on "
        "the other folds. NLL in nats of z given a detection; intervals: 95 % block bootstrap (whole "
        "10-frame scenes), paired with the Gaussian's; verdict: the interval of (KDE - Gaussian) wholly below 0 "
        "(better), straddling 0 (not distinguishable) or above (worse).",
        "",
        "Commands (a user's own data: an Astyx folder, or a log written by `sensor-envs record radar --astyx`):",
        "",
        "```",
        "sensor-envs tune radar models/radar_kde.npz ASTYX_DIR --what tail --out my_kde.npz --json tail.json",
        "sensor-envs validate radar my_kde.npz ASTYX_DIR --baseline models/radar_gaussian.npz --out validate_out",
        "sensor-envs tune radar MODEL.npz ASTYX_DIR --what bandwidth --tree main --criterion energy --out OUT.npz",
        "```",
        "",
        "`validate radar` prints one line per metric (start tuple and stationary law; mean and median NLL; "
        "detection per range and azimuth bin next to the Gaussian and the ideal radar) ending in "
        "BETTER / NOT DISTINGUISHABLE / WORSE, and writes them to `report.json` (`frames`).",
    ]


def model_section(name: str, kde: KDERadarModel, tune: dict[str, Any], rep: dict[str, Any]) -> list[str]:
    """The page's section of one shipped model: the tail choice, the NLL table, detection, the verdict lines."""
    cands = tune["candidates"]
    laws = list(next(iter(cands.values())))
    lines = [
        f"## models/{name}.npz",
        "",
        f"Tail chosen on every fold: `tail_weight` {tune['final']['tail_weight']:g}, `tail_scale` "
        f"{tune['final']['tail_scale']:g} (in the shipped file: {kde.tail_weight:g}, {kde.tail_scale:g}); nested "
        f"choices per fold: {tune['nested_choice']}. Candidates (`tune radar --json`, every row; NLL of z given a "
        "detection, mean / median):",
        "",
        "| weight, scale | " + " | ".join(f"{law} mean | {law} median" for law in laws) + " |",
        "|---|" + "---|---|" * len(laws),
    ]
    for key, per_law in cands.items():
        lines.append(
            f"| {key} | " + " | ".join(f"{per_law[law][0]:.3f} | {per_law[law][1]:.3f}" for law in laws) + " |"
        )
    lines += ["", f"Held-out NLL of z given a detection ({rep['n_detected']} detected rows of {rep['n_rows']}, "
              f"{rep['n_blocks']} blocks):", "", *nll_table(rep), ""]  # fmt: skip
    lines += ["Detection (stationary law; the start tuple's is in the JSON):", "", *detection_table(rep, "stationary")]
    lines += ["", "What `validate radar` says (nested tails):", "", "```", *verdict_lines(rep), "```", ""]
    return lines


def user_section(rep: dict[str, Any], chosen: list) -> list[str]:
    """The page's section of a user's own fit on real frames (fit radar --no-prev, tune radar --refit)."""
    return [
        "## A KDE fitted on your own real frames",
        "",
        "Outer folds: the KDE and the Gaussian fitted on the other folds' frames (`fit radar TRAIN.csv --no-prev "
        "--cv-group sequence --out my_kde.npz`), the tail chosen on inner folds of those frames, each scored by "
        "a KDE fitted without it (`tune radar my_kde.npz TRAIN.csv --what tail --refit --out my_kde_tail.npz`), "
        "then the held-out fold scored (`validate radar my_kde_tail.npz TEST.csv --out v`). A model without "
        f"`z_{{t-1}}` has one law (start = stationary). Tails chosen per outer fold: {chosen}.",
        "",
        *nll_table(rep),
        "",
        "```",
        *(line for line in verdict_lines(rep) if line.startswith("start law")),
        "```",
        "",
    ]


def detection_section(runs: list[dict[str, Any]]) -> list[str]:
    """The page's section of the algorithm-level check (evaluate radar-detection)."""
    lines = [
        "## Algorithm level: the 'car in my lane within 40 m' trigger (`evaluate radar-detection`)",
        "",
        "Mean distance of each simulator's precision-recall points to the real radar's on these frames (lower "
        "is closer):",
        "",
        "| KDE file | KDE | Gaussian | ideal |",
        "|---|---|---|---|",
    ]
    for r in runs:
        lines.append(f"| {Path(r['file']).name} | {r['model']:.3f} | {r['baseline']:.3f} | {r['ideal']:.3f} |")
    far = [r for r in runs if r["model"] > r["baseline"]]
    lines += [""]
    for r in far:
        lines.append(
            f"The KDE ({Path(r['file']).name}) is still FARTHER from the real precision-recall than the Gaussian: "
            f"{r['model']:.3f} vs {r['baseline']:.3f}."
        )
    lines += ["", "Commands:", "", "```", *(r["command"] for r in runs), "```"]
    return lines


if __name__ == "__main__":
    main()
