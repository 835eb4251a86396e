"""The radar sensor interface used by the driving wrappers, and the ideal radar.

A radar sensor model maps, per radar cycle, the closest visible corner of each target in the sensor
frame (x forward, y left, metres) and that target's previous output to a measurement:

* ``z = measured position - closest corner`` [m] (the output of Hirsenkorn et al. 2016), or a miss;
* the index of the recorded tuple the sample came from (``-1`` where none), for traceability;
* clutter: detections that belong to no target, drawn per cycle.

Models: :class:`IdealRadar` (here), ``GaussianRadar`` and ``KDERadarModel``
(:mod:`sensor_envs.radar.kde`).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.modelio import default_model_path, model_file_key, named_as_given
from sensor_envs.sensor_model import has_capability

__all__ = [
    "RadarSensor",
    "IdealRadar",
    "RADAR_NAMES",
    "DEFAULT_MODEL_FILES",
    "NEW_TRACK_KEYWORD",
    "make_radar",
    "takes_new_track",
]


@runtime_checkable
class RadarSensor(Protocol):
    """What a wrapper needs from a radar model (one call per radar cycle).

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import RadarSensor, make_radar
        >>> radar = make_radar("gaussian")
        >>> isinstance(radar, RadarSensor)  # anything with sample_cycle(corners, prev_z, rng) and sample_clutter(rng)
        True
    """

    def sample_cycle(
        self, corners: NDArray[np.float64], prev_z: NDArray[np.float64], rng: np.random.Generator
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Sample the outputs for ``n`` visible targets in one cycle.

        Models that tell a new track from a lost one (:data:`NEW_TRACK_KEYWORD`) also take
        ``new_track``: ``(n,)`` booleans, ``True`` where the target is seen for the first time,
        ``False`` where it was seen before (its ``prev_z`` is ``NaN`` when it was missed last cycle);
        ``None`` = unknown. Callers pass it only to models that DECLARE it: ``"new_track"`` in the class
        attribute ``CAPABILITIES`` (:func:`takes_new_track`; no signature probing), so a sensor without a
        start state need not accept it.

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
    """Perfect radar: reports every visible target exactly at its closest corner, no clutter.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import IdealRadar
        >>> corners, prev_z = np.array([[10.0, 1.0]]), np.full((1, 2), np.nan)  # [m]
        >>> z, source = IdealRadar().sample_cycle(corners, prev_z, np.random.default_rng(0))
        >>> z.tolist(), source.tolist()  # zero offsets from the closest corner, no source tuple
        ([[0.0, 0.0]], [-1])
    """

    CAPABILITIES: ClassVar[frozenset[str]] = frozenset({"new_track", "clutter"})
    """Declared capabilities (:mod:`sensor_envs.sensor_model`): it takes the new-track flags (and ignores them)."""

    def sample_cycle(
        self,
        corners: NDArray[np.float64],
        prev_z: NDArray[np.float64],
        rng: np.random.Generator,
        new_track: NDArray[np.bool_] | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Return zero offsets and no source tuple for every target (``rng`` and ``new_track`` are unused)."""
        n = np.asarray(corners).shape[0]
        return np.zeros((n, 2)), np.full(n, -1, dtype=np.int64)

    def sample_clutter(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """No clutter."""
        return np.zeros((0, 2))


NEW_TRACK_KEYWORD = "new_track"
"""Keyword of ``sample_cycle`` carrying the per-target new-track flags (see :class:`RadarSensor`)."""


def takes_new_track(radar: object) -> bool:
    """Whether ``radar`` declares the ``"new_track"`` capability (its class's ``CAPABILITIES``).

    A sensor whose ``sample_cycle`` takes the :data:`NEW_TRACK_KEYWORD` argument says so with
    ``CAPABILITIES = frozenset({"new_track"})``; undeclared sensors are called without it.
    """
    return has_capability(radar, "new_track")


RADAR_NAMES = ("ideal", "gaussian", "kde")
"""Names accepted by :func:`make_radar` (the one list of radar names)."""

DEFAULT_MODEL_FILES = {"gaussian": "radar_gaussian.npz", "kde": "radar_kde.npz"}
"""File name in ``models/`` of the shipped model of each fitted radar (see ``modelio.default_model_path``)."""


def make_radar(name: str, model: str | os.PathLike[str] | None = None) -> RadarSensor:
    """Build a radar sensor model by name, loading each model file once per process.

    The result is cached by name, resolved path and the file's modification time, and SHARED by every
    caller (the highway wrapper's envs, the CLI): ``sklearn.base.clone`` it before changing its parameters.

    Args:
        name: ``"ideal"``, ``"gaussian"`` (:class:`sensor_envs.radar.gaussian.GaussianRadar`) or
            ``"kde"`` (:class:`sensor_envs.radar.kde.KDERadarModel`).
        model: model file (``.npz``) for ``"gaussian"``/``"kde"``; ``None`` loads the default shipped
            in ``models/`` (fitted on the reference rig at ``cycle_time = 1.0`` s, see
            ``models/radar_kde.md``). Must be ``None`` for ``"ideal"``.

    Raises:
        ValueError: naming ``name`` when it is unknown, or when ``"ideal"`` is given a model file.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import make_radar
        >>> radar = make_radar("kde")  # the shipped KDE radar
        >>> z, source = radar.sample_cycle(np.array([[20.0, 2.0], [60.0, -4.0]]), np.full((2, 2), np.nan),
        ...                                np.random.default_rng(0))
        >>> z.shape  # offsets from the closest corners [m], NaN = missed
        (2, 2)
    """
    if name not in RADAR_NAMES:
        raise InputError(f"unknown radar {name!r}; expected one of {list(RADAR_NAMES)}")
    if name == "ideal":
        if model is not None:
            raise InputError(f"radar 'ideal' takes no model file (got {model!r})")
        return _load_radar(name, None, 0)
    key = model_file_key(default_model_path(DEFAULT_MODEL_FILES[name]) if model is None else model)
    with named_as_given(model, key[0]):
        return _load_radar(name, *key)


@functools.lru_cache(maxsize=32)
def _load_radar(name: str, path: str | None, mtime_ns: int) -> RadarSensor:
    """The radar ``name`` from the file at ``path`` (``mtime_ns`` only keys the cache)."""
    if name == "ideal" or path is None:
        return IdealRadar()
    from sensor_envs.radar.correction import load_radar_file
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel

    kind, model = load_radar_file(path)  # a corrected model (``diagnose radar``) runs under either name
    if kind in (name, "corrected"):
        return model
    return GaussianRadar.load(path) if name == "gaussian" else KDERadarModel.load(path)  # their kind message
