"""Evaluate the model a robustness run did NOT evaluate (EvalCallback's `best_model.zip` or `final_model.zip`).

Record (issue 40; not maintained, see docs/history/scripts.md). Found: in the 2-seed highway matrix (10,000 steps),
EvalCallback's best checkpoint collided less than the final model on the held-out episodes (ideal 0.38 vs 0.65,
tracked KDE 0.27 vs 0.45; `2e25ba0`, `91ecbc0`); hence `sensor-envs robustness --policy best`, the full highway
preset's default.

    python docs/history/scripts/highway_checkpoint_eval.py --run runs/highway_matrix --columns ideal kde_tracks \
        [--episodes 30] [--json out.json]

For every job of the run (``runs/<row>/seed<s>/``), plays ``--episodes`` deterministic episodes of the
job's other model (``best_model.zip`` when the run evaluated ``final_model.zip``, the default, and the
reverse for a run made with ``--policy best``) on each column with the matrix's evaluation seeds
(``EVAL_SEED + e``, the same episodes as the matrix's cells) and prints, per row and column, the
collision rate and mean return of the best and the final model, each pooled over seeds with its 95 %
bootstrap interval (seeds resampled whole, as in the matrix). The best model is chosen by the job's
EvalCallback on its own sensor from the config's ``eval_episodes`` episodes with other seeds
(``seed + 10000``), so the matrix's evaluation episodes are held out from that choice.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> None:
    import stable_baselines3 as sb3
    import torch

    from sensor_envs.training import robustness, stats

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--columns", nargs="+", required=True)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    settings = json.loads((args.run / "settings.json").read_text())
    domain, env_id = settings["domain"], robustness.DOMAINS[settings["domain"]]["env_id"]
    evaluated = settings.get("policy", "final")  # runs made before --policy existed evaluated final models
    other = "final" if evaluated == "best" else "best"
    out: dict[str, dict[str, dict[str, list[list[float]]]]] = {}
    for row in settings["rows"]:
        for seed in settings["seeds"]:
            job = args.run / "runs" / row / f"seed{seed}"
            final = json.loads((job / "eval.json").read_text())["cells"]  # the run's own model
            model = sb3.DQN.load(job / f"{other}_model", device="cpu")
            for col in args.columns:
                kwargs = robustness.column_kwargs(domain, col, {}, settings["config"])
                got = robustness.evaluate(model, env_id, kwargs, args.episodes, None)
                cell = out.setdefault(f"{row}->{col}", {"best": {}, "final": {}})
                for metric in ("collision", "return"):
                    cell[other].setdefault(metric, []).append(got[metric])
                    cell[evaluated].setdefault(metric, []).append(final[col][metric][: args.episodes])
                print(
                    f"{row} seed {seed} on {col}: {other}-model collision {np.mean(got['collision']):.2f}",
                    file=sys.stderr,
                )
    print("| trained on -> evaluated on | model | collision (mean) [95 % CI] | return (IQM) [95 % CI] |")
    print("|---|---|---|---|")
    for key, cell in out.items():
        for which in ("best", "final"):
            c = np.array(cell[which]["collision"])
            r = np.array(cell[which]["return"])
            clo, chi = stats.bootstrap_ci(c, stats.mean, reps=robustness.BOOTSTRAP_REPS)
            rlo, rhi = stats.bootstrap_ci(r, stats.iqm, reps=robustness.BOOTSTRAP_REPS)
            print(
                f"| {key} | {which} | {stats.mean(c):.2f} [{clo:.2f}, {chi:.2f}] | "
                f"{stats.iqm(r):.2f} [{rlo:.2f}, {rhi:.2f}] |"
            )
    if args.json is not None:
        args.json.write_text(json.dumps(out))


if __name__ == "__main__":
    main()
