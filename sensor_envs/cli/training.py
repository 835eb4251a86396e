"""``sensor-envs train`` and ``sensor-envs robustness``: the commands of :mod:`sensor_envs.training`."""

from __future__ import annotations

import argparse
from typing import Any

from sensor_envs.cli.args import OneLineParser

__all__ = ["register"]

TRAIN_DESCRIPTION = """Train a stable-baselines3 agent on a sensor_envs env from a YAML config keyed by env id.

The default config is the shipped sensor_envs/training/configs/default.yaml. Writes into --out: config.json
(the resolved config, the seed and the command line), checkpoints/, tb/ (TensorBoard, with the train extra),
best_model.zip and evaluations.npz, final_model.zip and result.json (mean and std of the final evaluation
return). An existing --out is refused unless --force. A bad config or argument exits with status 2 and one line
naming the key."""

ROBUSTNESS_DESCRIPTION = """The robustness matrix: train on one sensor, evaluate on every sensor.

Rows are the sensor trained on, columns the sensor evaluated on. Per cell and metric: the interquartile mean
and the mean over seeds x episodes with 95 % bootstrap intervals (seeds resampled whole), and between rows the
probability of improvement. Jobs (sensor x seed) run in a local process pool or on Ray; a rerun with the same
settings resumes. Writes matrix.md, matrix.json and matrix.png into --out."""


def _train(args: argparse.Namespace) -> int:
    from sensor_envs.training import train

    train.run(args)
    return 0


def _robustness(args: argparse.Namespace) -> int:
    from sensor_envs.training import robustness

    robustness.run(args)
    return 0


def register(sub: argparse._SubParsersAction[OneLineParser]) -> None:
    """Add ``train`` and ``robustness`` to the command line (their options come from the training modules)."""
    from sensor_envs.training import robustness, train

    kw: dict[str, Any] = {"formatter_class": argparse.RawDescriptionHelpFormatter}
    p = sub.add_parser("train", help="train an SB3 agent from a YAML config", description=TRAIN_DESCRIPTION, **kw)
    train.add_arguments(p)
    p.set_defaults(func=_train)
    p = sub.add_parser(
        "robustness", help="the robustness matrix: train on one sensor, evaluate on every sensor",
        description=ROBUSTNESS_DESCRIPTION, **kw,
    )  # fmt: skip
    robustness.add_arguments(p)
    p.set_defaults(func=_robustness)
