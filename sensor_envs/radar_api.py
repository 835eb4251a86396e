"""The radar sensor interface used by the driving wrappers, and the ideal radar.

A radar sensor model maps, per radar cycle, the closest visible corner of each target in the sensor
frame (x forward, y left, metres) and that target's previous output to a measurement:

* ``z = measured position - closest corner`` [m] (the output of Hirsenkorn et al. 2016), or a miss;
* the index of the recorded tuple the sample came from (``-1`` where none), for traceability;
* clutter: detections that belong to no target, drawn per cycle.

Models: :class:`IdealRadar` (here), ``GaussianRadar`` and ``KDERadarModel``
(:mod:`sensor_envs.radar_kde`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = ["RadarSensor", "IdealRadar"]


@runtime_checkable
class RadarSensor(Protocol):
    """What a wrapper needs from a radar model (one call per radar cycle)."""

    def sample_cycle(
        self, corners: NDArray[np.float64], prev_z: NDArray[np.float64], rng: np.random.Generator
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Sample the outputs for ``n`` visible targets in one cycle.

        Args:
            corners: ``(n, 2)`` closest visible corner of each target, sensor frame [m].
            prev_z: ``(n, 2)`` each target's previous output ``z_{t-1}`` [m]; ``NaN`` rows where the
                target was missed last cycle or is new.
            rng: the sensor's own generator.

        Returns:
            ``z (n, 2)`` [m], ``NaN`` rows for targets the radar missed (object loss), and
            ``source (n,)`` the index of the recorded tuple each sample came from (``-1`` if none).
        """
        ...

    def sample_clutter(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Clutter detections of one cycle, ``(m, 2)`` positions in the sensor frame [m]."""
        ...


@dataclass(frozen=True)
class IdealRadar:
    """Perfect radar: reports every visible target exactly at its closest corner, no clutter."""

    def sample_cycle(
        self, corners: NDArray[np.float64], prev_z: NDArray[np.float64], rng: np.random.Generator
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Return zero offsets and no source tuple for every target (``rng`` is unused)."""
        n = np.asarray(corners).shape[0]
        return np.zeros((n, 2)), np.full(n, -1, dtype=np.int64)

    def sample_clutter(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """No clutter."""
        return np.zeros((0, 2))
