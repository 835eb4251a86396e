"""``sensor-envs upgrade-model``: rewrite a model file of an older format version in the current one.

Every fitted sensor model reads its older formats through one upgrade path (:mod:`sensor_envs.sensor_model`:
one step per version, then one reader of the current format) and writes only the current format; this command
is that path applied to a file: load (upgraded, value-checked), save (current format, the same card).
"""

from __future__ import annotations

import argparse
from typing import Any

from sensor_envs.cli.args import add_force
from sensor_envs.outputs import check_inputs, check_output

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``upgrade-model`` sub-command to ``sub`` (the sub-parsers of ``sensor-envs``)."""
    p = sub.add_parser(
        "upgrade-model",
        help="rewrite a model file of an older format version in the current format",
        description="Read a model file (KDE radar, Gaussian radar, learned lidar) of any supported format version "
        "and write it in the current format: the same model (same draws, same densities), the same card. The "
        "input is never written over.",
    )
    p.add_argument("model", help="model file (.npz) of any supported format version")
    p.add_argument("--out", required=True, help="the upgraded model file (.npz)")
    add_force(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel
    from sensor_envs.sensor_model import upgrade_model_file

    check_inputs(args.model)
    out = check_output(args.out, inputs=[args.model], force=args.force, suffix=".npz")
    model, old, new = upgrade_model_file(args.model, out, (KDERadarModel, GaussianRadar, LidarLWLR))
    print(f"{args.model}: {model.KIND} format {old} -> {out}: format {new}")
    return 0
