"""Choose the KDE radar's contribution-bandwidth factor on real Astyx frames by held-out likelihood.

The KDE fitted on the calibrated rig's log chooses its contribution bandwidths by leave-one-track-out
CV on that SIMULATED log; at the real boxes they come out wider than those a KDE fitted on real frames
chooses (model card). This script scores the model (``--model``, default the shipped
``models/radar_kde.npz``) with every factor of ``--factors`` applied to its bandwidth table
(:meth:`KDERadarModel.with_bandwidth_scale`) on the real car rows: the stationary law at the static box
(``real_radar_fidelity.marginal``: ``--chains`` rollouts of ``--cycles`` cycles, ``z_{t-1}`` fed back),
NLL of outcomes per fold of 10-frame blocks (``validate.split_by_blocks``, the folds of the fidelity
benchmark). The model itself never saw a real row, so every row is held out for it; the FACTOR is
chosen on the rows:

* nested (the honest figure for the choice): for each fold, the factor of least mean NLL over the other
  folds, scored on that fold;
* final: the factor of least mean NLL over all folds (ties: the one nearer 1), written with ``--write``.

Detection rates do not depend on the factor (it only narrows or widens the contribution kernels).
~1 min per factor on 2 cores.

    python benchmarks/real_radar_bandwidth_scale.py --data ../shared/data/real/astyx_hires2019 \
        --write /tmp/radar_kde.npz
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sensor_envs.modelio import ModelFileError
from sensor_envs.outputs import OutputError, OutputTransaction, check_output
from sensor_envs.radar.astyx import load_astyx
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import target_tuples
from sensor_envs.radar.validate import split_by_blocks

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_radar_fidelity import marginal  # noqa: E402  (benchmarks are scripts, not a package)

FACTORS = (0.35, 0.5, 0.6, 0.7, 0.85, 1.0)


def fold_nll(model: KDERadarModel, folds: list, seed: int, chains: int, cycles: int) -> np.ndarray:
    """Mean NLL of outcomes [nats] of ``model``'s stationary law on each fold's real rows."""
    out = []
    for k, tt in enumerate(folds):  # one iteration per fold
        res = marginal(model, tt.corner, tt.z, np.random.default_rng([seed, k]), chains, cycles)
        out.append(float(-res["logp"].mean()))
    return np.asarray(out)


def choose(nll: dict[float, np.ndarray]) -> tuple[float, list[float], np.ndarray]:
    """Final factor (least mean NLL over all folds; ties: nearer 1), nested choices and their held-out NLLs."""
    factors = sorted(nll, key=lambda f: abs(np.log(f)))
    final = min(factors, key=lambda f: float(nll[f].mean()))
    n = next(iter(nll.values())).size
    nested = [min(factors, key=lambda f: float(np.delete(nll[f], k).mean())) for k in range(n)]
    return final, nested, np.array([nll[f][k] for k, f in enumerate(nested)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data" / "real" / "astyx_hires2019"))
    ap.add_argument("--model", default=str(ROOT / "models" / "radar_kde.npz"), help="KDE model file (.npz)")
    ap.add_argument("--factors", type=float, nargs="+", default=list(FACTORS))
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--chains", type=int, default=16)
    ap.add_argument("--cycles", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--write", default=None, help="write the model with the final factor here (.npz)")
    ap.add_argument("--force", action="store_true", help="overwrite --write / --json")
    args = ap.parse_args()
    t0 = time.perf_counter()
    try:  # bad input: one line naming the file, exit 2, before anything is written
        if any(not 0.01 <= f <= 100 for f in args.factors):
            raise ValueError(f"--factors: each must be in [0.01, 100], got {args.factors}")
        model = KDERadarModel.load(args.model)
        log = load_astyx(args.data, block=args.block, progress=False)
        out = (
            check_output(args.write, inputs=[args.model], force=args.force, suffix=".npz", option="--write")
            if args.write
            else None
        )
        js = (
            check_output(args.json, inputs=[args.model], force=args.force, suffix=".json", option="--json")
            if args.json
            else None
        )
    except (FileNotFoundError, ValueError, ModelFileError, OutputError) as exc:
        print(exc, file=sys.stderr)
        raise SystemExit(2) from None
    folds = [
        target_tuples(split_by_blocks(log, block=args.block, n_folds=args.folds, fold=k)[1]) for k in range(args.folds)
    ]
    nll = {}
    for f in tqdm(args.factors, desc="bandwidth factors", unit="factor"):  # one iteration per factor
        nll[f] = fold_nll(model.with_bandwidth_scale(f), folds, args.seed, args.chains, args.cycles)
    final, nested, held = choose(nll)
    print(f"\nNLL of outcomes [nats] on the real rows of {args.folds} folds ({Path(args.data).name}), per factor\n")
    print("| factor | " + " | ".join(f"fold {k}" for k in range(args.folds)) + " | mean |")
    print("|---" * (args.folds + 2) + "|")
    for f in sorted(nll):
        print(f"| {f:g} | " + " | ".join(f"{v:.3f}" for v in nll[f]) + f" | {nll[f].mean():.3f} |")
    print(
        f"\nnested (factor chosen on the other folds): {[f'{f:g}' for f in nested]}, held-out NLL {held.mean():.3f} "
        f"(factor 1: {nll[1.0].mean():.3f})"
        if 1.0 in nll
        else ""
    )
    scale = model.bandwidth_scale
    print(f"final factor: {final:g} (bandwidth_scale of the model: {scale:g} -> {scale * final:g})")
    seconds = round(time.perf_counter() - t0, 1)
    print(f"{seconds} s")
    report = {
        "args": vars(args),
        "nll_per_fold": {f"{f:g}": v.tolist() for f, v in nll.items()},
        "nested_choice": nested,
        "nested_nll": float(held.mean()),
        "final": final,
        "seconds": seconds,
    }
    with OutputTransaction() as tx:
        if out is not None:
            card = {
                **model.card_,
                "bandwidth_scale_choice": {k: report[k] for k in ("nested_choice", "nested_nll", "final")},
            }
            card["bandwidth_scale_choice"]["data"] = Path(args.data).name
            model.with_bandwidth_scale(final).save(tx.file(out), card=card)
        if js is not None:
            tx.file(js).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
