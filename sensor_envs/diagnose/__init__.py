"""Closing the loop: find the effect a sensor model lacks, add it to the model's state, report before/after.

Tool level: imports :mod:`sensor_envs.radar` and :mod:`sensor_envs.lidar`, never the other way round.
:mod:`~sensor_envs.diagnose.core` is sensor-independent; a sensor plugs in with an adapter
(:class:`~sensor_envs.diagnose.core.DiagnoseAdapter`); :mod:`~sensor_envs.diagnose.radar` is the radar's,
:mod:`~sensor_envs.diagnose.lidar` the learned lidar's.
"""

from sensor_envs.diagnose.core import (
    DiagnoseAdapter,
    DiagnoseResult,
    Evaluation,
    block_split,
    rank_candidates,
    run_diagnose,
)

__all__ = ["DiagnoseAdapter", "DiagnoseResult", "Evaluation", "block_split", "rank_candidates", "run_diagnose"]
