"""``sensor-envs train`` and ``sensor-envs robustness``: the commands of :mod:`sensor_envs.training`."""

from __future__ import annotations

import argparse
from typing import Any

from sensor_envs.cli.args import OneLineParser

__all__ = ["register"]


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
    p = sub.add_parser("train", help="train an SB3 agent from a YAML config", description=train.__doc__, **kw)
    train.add_arguments(p)
    p.set_defaults(func=_train)
    p = sub.add_parser(
        "robustness", help="the robustness matrix: train on one sensor, evaluate on every sensor",
        description=robustness.__doc__, **kw,
    )  # fmt: skip
    robustness.add_arguments(p)
    p.set_defaults(func=_robustness)
