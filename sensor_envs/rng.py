"""The sensors' own random streams, kept apart from the world's."""

from __future__ import annotations

import numpy as np

__all__ = ["sensor_rng"]


def sensor_rng(seed: int | None, tag: int, current: np.random.Generator | None) -> np.random.Generator:
    """The generator a sensor uses after ``reset(seed=seed)``.

    A given ``seed`` derives a fresh stream from ``SeedSequence([seed, tag])`` (``tag`` tells sensors
    apart), so sensor noise never draws from the world's stream; ``seed=None`` continues ``current``,
    or starts from fresh entropy when the sensor was never seeded.
    """
    if seed is not None:
        return np.random.default_rng(np.random.SeedSequence([int(seed), int(tag)]))
    return current if current is not None else np.random.default_rng()
