"""How the radar wrapper hooks into highway-env: a radar cycle after every road step, the observation replaced.

:class:`RoadStepHook` (``radar_rate="simulation"``) runs one radar cycle after every simulation sub-step of one
``Road`` instance; :class:`ObservationHook` stands in for highway-env's observation type so that ``observe()``
samples the radar.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["RoadStepHook", "ObservationHook"]


class RoadStepHook:
    """Set as the ``step`` attribute of ONE highway-env ``Road`` instance (``radar_rate="simulation"``).

    highway-env's ``AbstractEnv._simulate`` calls ``road.step(1 / simulation_frequency)`` once per
    simulation sub-step; the instance attribute shadows the class's method for this road only, runs
    the class's ``Road.step`` and then ``after()`` (one radar cycle). A new road (every ``reset``)
    needs a new hook; re-installing on a hooked road replaces the callback.
    """

    def __init__(self, step: Any, after: Any) -> None:
        self.step = step
        self.after = after

    def __call__(self, dt: float) -> None:
        """Advance the road by ``dt`` [s], then sample the radar."""
        self.step(dt)
        self.after()

    @classmethod
    def install(cls, road: Any, after: Any) -> None:
        """Hook ``road.step`` (highway-env's ``Road``) to call ``after()`` after every sub-step."""
        current = road.__dict__.get("step")
        inner = current.step if isinstance(current, cls) else type(road).step.__get__(road)
        road.step = cls(inner, after)


class ObservationHook:
    """Stands in for highway-env's observation type: ``observe()`` samples the radar instead.

    Everything else (``space()``, attributes) is delegated to the original observation type.
    """

    def __init__(self, inner: Any, observe: Any) -> None:
        self.inner = inner
        self._observe = observe

    def observe(self) -> NDArray[np.float32]:
        """The radar observation (samples the radar once)."""
        return self._observe()

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("inner", "_observe"):
            raise AttributeError(name)
        return getattr(self.inner, name)
