"""Shared fixtures: the real-data folder (skips cleanly when absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real"
REAL_DATA = Path(os.environ.get("SENSOR_ENVS_REAL_DATA", _DEFAULT)).resolve()


@pytest.fixture(scope="session")
def real_data() -> Path:
    """Path of ``../shared/data/real`` (or ``$SENSOR_ENVS_REAL_DATA``); skips the test when absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real data folder {REAL_DATA} is absent (set SENSOR_ENVS_REAL_DATA to point at it)")
    return REAL_DATA
