"""``sensor-envs record|fit|validate lidar`` (filled in by the learned-lidar work)."""

from __future__ import annotations

import argparse


def register(verbs: dict[str, "argparse._SubParsersAction[argparse.ArgumentParser]"]) -> None:
    """Add the ``lidar`` sub-commands under each verb parser in ``verbs``."""
