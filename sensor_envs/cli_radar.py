"""``sensor-envs record|fit|validate radar`` (filled in by the learned-radar work)."""

from __future__ import annotations

import argparse


def register(verbs: dict[str, "argparse._SubParsersAction[argparse.ArgumentParser]"]) -> None:
    """Add the ``radar`` sub-commands under each verb parser in ``verbs``."""
