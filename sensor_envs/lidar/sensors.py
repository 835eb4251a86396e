"""Planar lidar sensors for the 2D worlds: the interface, the ideal lidar and the factory ``make_lidar``.

A lidar sensor turns per-bearing geometry (nominal range and angle of incidence, from
:func:`sensor_envs.geometry.raycast_pose` on the TRUE pose) into a reading per bearing. Readings are
ranges [m] with ``NaN`` meaning a null (no return); the world maps nulls to its configured
``null_value``. The Gaussian baseline (:mod:`sensor_envs.lidar.gaussian`, importable from here too) and the
learned per-bearing model (:mod:`sensor_envs.lidar.lwlr`) implement the same interface.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from os import PathLike
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.lidar.gaussian import GaussianLidar
from sensor_envs.modelio import default_model_path, model_file_key, named_as_given

__all__ = ["LidarSensor", "IdealLidar", "GaussianLidar", "make_lidar", "LIDAR_NAMES"]


@runtime_checkable
class LidarSensor(Protocol):
    """What a world needs from a lidar sensor model.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import LidarSensor, make_lidar
        >>> lidar = make_lidar("gaussian")
        >>> isinstance(lidar, LidarSensor)  # anything with measure(nominal_range, incidence, rng)
        True
        >>> lidar.measure(np.array([1.0, 2.0, np.inf]), np.zeros(3), np.random.default_rng(0)).shape
        (3,)
    """

    def measure(
        self, nominal_range: NDArray[np.float64], incidence: NDArray[np.float64], rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """Sample one scan.

        Args:
            nominal_range: ``(K,)`` ray length to the map [m] from the true pose; ``inf`` = no hit
                within the sensor's maximum range.
            incidence: ``(K,)`` angle between ray and wall normal [rad], ``NaN`` where no hit.
            rng: the sensor's own generator.

        Returns:
            ``(K,)`` ranges [m]; ``NaN`` for a null reading.
        """
        ...


@dataclass(frozen=True)
class IdealLidar:
    """Perfect lidar: the nominal range where the ray hits within range, else a null.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import IdealLidar
        >>> IdealLidar().measure(np.array([1.0, np.inf]), np.zeros(2), np.random.default_rng(0))
        array([ 1., nan])
    """

    def measure(
        self, nominal_range: NDArray[np.float64], incidence: NDArray[np.float64], rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """Return the nominal ranges [m], ``NaN`` where no hit (``rng`` is unused)."""
        r = np.asarray(nominal_range, dtype=np.float64)
        return np.where(np.isfinite(r), r, np.nan)


LIDAR_NAMES = ("ideal", "gaussian", "learned")
"""Names accepted by :func:`make_lidar` (the one list of lidar names)."""


def make_lidar(name: str | LidarSensor, model: str | PathLike[str] | None = None, **kwargs: Any) -> LidarSensor:
    """Build a lidar sensor from its name (``"ideal"``, ``"gaussian"``, ``"learned"``) or pass one through.

    A learned model file is loaded once per process (cached by resolved path and modification time) and
    the sensor is SHARED by every caller, e.g. all ``Neato-v0`` envs.

    Args:
        name: sensor name or an object implementing :class:`LidarSensor`.
        model: for ``"learned"``, the model file (default: the model shipped in ``models/``), or a fitted
            :class:`~sensor_envs.lidar.lwlr.LidarLWLR` (used as it is, not cached).
        **kwargs: for ``"gaussian"``, :class:`GaussianLidar` fields.

    Raises:
        ValueError: for an unknown name, or ``model``/kwargs given to a sensor that takes none.

    Examples:
        >>> from sensor_envs import make_lidar
        >>> type(make_lidar("ideal")).__name__, type(make_lidar("learned")).__name__
        ('IdealLidar', 'LearnedLidar')
    """
    if not isinstance(name, str):
        if not isinstance(name, LidarSensor):
            raise InputError(f"lidar: expected a name in {LIDAR_NAMES} or a LidarSensor, got {type(name).__name__}")
        return name
    if name not in LIDAR_NAMES:
        raise InputError(f"lidar: unknown lidar {name!r}; choose one of {LIDAR_NAMES}")
    if name != "learned" and model is not None:
        raise InputError(f"lidar: 'model' applies to lidar='learned' only, not {name!r}")
    if name == "ideal":
        if kwargs:
            raise InputError(f"lidar: the ideal lidar takes no parameters, got {sorted(kwargs)}")
        return IdealLidar()
    if name == "gaussian":
        known = {f.name for f in fields(GaussianLidar)}
        unknown = sorted(str(k) for k in set(kwargs) - known)
        if unknown:
            raise InputError(
                f"lidar_kwargs: unknown parameters {unknown} of the Gaussian lidar (known: {sorted(known)})"
            )
        return GaussianLidar(**kwargs)
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, load_learned_lidar  # heavy: only when asked for

    if kwargs or not (model is None or isinstance(model, (str, PathLike))):
        return load_learned_lidar(model, **kwargs)  # a fitted model passes through; kwargs are refused there
    key = model_file_key(default_model_path(DEFAULT_MODEL_FILE) if model is None else model)
    with named_as_given(model, key[0]):
        return _load_learned(*key)


@functools.lru_cache(maxsize=16)
def _load_learned(path: str, mtime_ns: int) -> LidarSensor:
    """The learned lidar from the model file at ``path`` (``mtime_ns`` only keys the cache)."""
    from sensor_envs.lidar.lwlr import load_learned_lidar

    return load_learned_lidar(path)
