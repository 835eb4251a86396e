"""Closing the loop: find the effect a sensor model lacks, add it to the model's state, report before/after.

Tool level: imports :mod:`sensor_envs.radar` and :mod:`sensor_envs.lidar`, never the other way round.
:mod:`~sensor_envs.diagnose.core` is sensor-independent; a sensor plugs in with an adapter
(:class:`~sensor_envs.diagnose.core.DiagnoseAdapter`); :mod:`~sensor_envs.diagnose.radar` is the radar's
(:mod:`~sensor_envs.diagnose.radar_add` its add step: corrections fitted on the base model),
:mod:`~sensor_envs.diagnose.lidar` the learned lidar's; :mod:`~sensor_envs.diagnose.search` scores and
tests candidate causes (:mod:`~sensor_envs.diagnose.regressors` its regressors and their sufficient
statistics, :mod:`~sensor_envs.diagnose.projection` its second, in-sample test of few-coefficient forms
and the partial tests that tell a cause from its proxy, :mod:`~sensor_envs.diagnose.shifts` the
circular-shift null that confirms both tests' findings, :mod:`~sensor_envs.diagnose.surrogates` the
check of a slow candidate against independent series drawn like it); :mod:`~sensor_envs.diagnose.report` writes the
before/after report;
:mod:`~sensor_envs.diagnose.families` draws seeded synthetic logs with planted causes (the suite's);
:mod:`~sensor_envs.diagnose.power` tests a known cause as an oracle would (how detectable it is).
The adapters and ``write_report`` are imported on first use.
"""

from sensor_envs.diagnose.core import (
    DiagnoseAdapter,
    DiagnoseResult,
    Evaluation,
    block_split,
    rank_candidates,
    run_diagnose,
)
from sensor_envs.lazy import lazy_exports

_LAZY: dict[str, str] = {
    "LidarAdapter": "sensor_envs.diagnose.lidar",
    "RadarAdapter": "sensor_envs.diagnose.radar",
    "write_report": "sensor_envs.diagnose.report",
}

__all__ = ["DiagnoseAdapter", "DiagnoseResult", "Evaluation", "block_split", "rank_candidates", "run_diagnose", *_LAZY]
__getattr__, _dir_lazy = lazy_exports(__name__, _LAZY)


def __dir__() -> list[str]:
    """The public names (for tab completion)."""
    return sorted(__all__)
