"""``sensor-envs evaluate``: does the simulator predict how an algorithm performs on the real sensor.

    sensor-envs evaluate detection --real LOG [--model fit|MODEL] [--baseline gaussian] --out DIR [--force]
    sensor-envs evaluate boxworld [--model MODEL] --out DIR [--configs 50] [--force]
    sensor-envs evaluate radar-detection --real ASTYX_DIR|LOG.csv [--model MODEL] --out DIR [--force]
    sensor-envs evaluate registration [--model MODEL] --out DIR [--poses 40] [--force]
    sensor-envs evaluate aeb --out DIR [--episodes 30] [--force]

Each writes ``report.json``, ``report.md`` and plots into ``DIR`` (built in a temporary folder beside it
and renamed at the end: an interrupted run leaves nothing half-written; an existing ``DIR`` is refused
unless ``--force``).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from sensor_envs.cli.args import nonneg_int, positive_float, positive_int, printable
from sensor_envs.inputs import InputError
from sensor_envs.outputs import output_folder

__all__ = ["register"]


def _command() -> str:
    return printable("sensor-envs " + " ".join(shlex.quote(a) for a in sys.argv[1:]))


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``evaluate`` sub-commands to the ``evaluate`` parser."""
    sub = parser.add_subparsers(dest="kind", required=True)
    det = sub.add_parser("detection", help="line-of-known-length detector: real log vs learned model vs baseline")
    det.add_argument("--real", required=True, help="static-pose lidar log (.npz) with a map holding the target")
    det.add_argument(
        "--model", default="fit", help="'fit' (default: LWLR fitted leave-poses-out on the log) or a model file (.npz)"
    )
    det.add_argument(
        "--baseline", default="gaussian", choices=("gaussian",), help="baseline simulator: the Gaussian lidar"
    )
    det.add_argument("--length", type=positive_float, default=0.61, help="target length [m] (default: 0.61)")
    det.add_argument("--repeats", type=positive_int, default=10, help="scans per pose and source (default: 10)")
    det.add_argument("--folds", type=positive_int, default=3, help="leave-poses-out folds when fitting (default: 3)")
    det.add_argument("--seed", type=nonneg_int, default=0, help="seed of the folds and simulated scans (default: 0)")
    _common(det)
    det.set_defaults(func=_detection)
    box = sub.add_parser("boxworld", help="the seed's box-world detection experiment on the rig (rig = reality)")
    box.add_argument("--model", default=None, help="learned lidar model (default: the shipped one)")
    box.add_argument("--configs", type=positive_int, default=50, help="board configurations (default: 50)")
    box.add_argument("--poses", type=positive_int, default=2, help="poses per configuration (default: 2)")
    box.add_argument("--repeats", type=positive_int, default=5, help="scans per pose (default: 5)")
    box.add_argument("--seed", type=nonneg_int, default=0, help="seed of the box worlds and scans (default: 0)")
    _common(box)
    box.set_defaults(func=_boxworld)
    rad = sub.add_parser("radar-detection", help="ADAS trigger on object radar output: real vs KDE vs Gaussian")
    rad.add_argument("--real", required=True, help="Astyx HiRes2019 folder or a radar object log (.csv)")
    rad.add_argument("--model", default=None, help="KDE radar model file (default: the shipped one)")
    rad.add_argument("--baseline", default=None, help="Gaussian radar model file (default: the shipped one)")
    rad.add_argument("--fit", action="store_true", help="fit the KDE and Gaussian models leave-blocks-out on the log")
    rad.add_argument("--seed", type=nonneg_int, default=0, help="seed of the simulated draws (default: 0)")
    rad.add_argument("--draws", type=positive_int, default=20, help="simulated draws per reference box (default: 20)")
    _common(rad)
    rad.set_defaults(func=_radar_detection)
    reg = sub.add_parser("registration", help="corridor registration (Kalman filter + scan matcher) vs iterations")
    reg.add_argument("--model", default=None, help="learned lidar model (default: the shipped one)")
    reg.add_argument("--poses", type=positive_int, default=40, help="poses along the corridor (default: 40)")
    reg.add_argument("--seed", type=nonneg_int, default=0, help="seed of the corridor scans (default: 0)")
    _common(reg)
    reg.set_defaults(func=_registration)
    aeb = sub.add_parser("aeb", help="forward-collision warning + tracker on highway-fast with each radar")
    aeb.add_argument("--episodes", type=positive_int, default=30, help="seeded episodes per radar (default: 30)")
    aeb.add_argument("--steps", type=positive_int, default=40, help="policy steps per episode at most (default: 40)")
    aeb.add_argument("--seed", type=nonneg_int, default=0, help="seed of the first episode (default: 0)")
    _common(aeb)
    aeb.set_defaults(func=_aeb)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output folder (report.json, report.md, plots)")
    p.add_argument("--force", action="store_true", help="replace an existing --out")


def _print_distances(report: dict[str, Any], key: str = "distance_to_real") -> None:
    from sensor_envs.evaluate.report import closeness_sentence

    print(f"{key}: " + ", ".join(f"{k} {v:.4f}" for k, v in report[key].items()))
    print(closeness_sentence(report[key], key.removeprefix("distance_to_")))


def _detection(args: argparse.Namespace) -> int:
    from sensor_envs.evaluate.lidar_experiments import log_experiment
    from sensor_envs.evaluate.report import write_report
    from sensor_envs.lidar.log import load_log
    from sensor_envs.lidar.lwlr import LidarLWLR

    model_file = None if args.model == "fit" else args.model
    with output_folder(args.out, args.force, (args.real, model_file)) as tmp:
        log = load_log(args.real)
        if log.ranges.shape[2] < 2:
            raise InputError(f"{args.real}: field 'ranges' needs repeated readings at static poses (P, K, R >= 2)")
        model = None if model_file is None else LidarLWLR.load(model_file)
        report = log_experiment(
            log,
            model=model,
            baseline=args.baseline,
            length=args.length,
            repeats=args.repeats,
            folds=args.folds,
            seed=args.seed,
        )
        report["command"] = _command()
        write_report(report, tmp)
    _print_distances(report)
    print(f"wrote {Path(args.out) / 'report.json'}")
    return 0


def _boxworld(args: argparse.Namespace) -> int:
    from sensor_envs.cli.lidar import MAX_RECORD_READINGS
    from sensor_envs.evaluate.lidar_experiments import boxworld_experiment
    from sensor_envs.evaluate.report import write_report
    from sensor_envs.lidar.lwlr import DEFAULT_MODEL_FILE, LidarLWLR
    from sensor_envs.modelio import default_model_path

    if args.poses * args.repeats > MAX_RECORD_READINGS:  # one configuration's scans are drawn at once
        raise InputError(
            f"--poses x --repeats: {args.poses} x {args.repeats} scans per configuration, more than "
            f"{MAX_RECORD_READINGS}"
        )
    with output_folder(args.out, args.force, (args.model,)) as tmp:
        model = LidarLWLR.load(default_model_path(DEFAULT_MODEL_FILE) if args.model is None else args.model)
        report = boxworld_experiment(
            model, n_configs=args.configs, poses_per_config=args.poses, repeats=args.repeats, seed=args.seed
        )
        report["command"] = _command()
        write_report(report, tmp)
    _print_distances(report, key="distance_to_rig")
    print(f"wrote {Path(args.out) / 'report.json'}")
    return 0


def _radar_detection(args: argparse.Namespace) -> int:
    from sensor_envs.evaluate.radar_detection import radar_detection_experiment
    from sensor_envs.evaluate.report import write_report

    with output_folder(args.out, args.force, (args.real, args.model, args.baseline)) as tmp:
        report = radar_detection_experiment(
            args.real, model=args.model, baseline=args.baseline, fit=args.fit, seed=args.seed, draws=args.draws
        )
        report["command"] = _command()
        write_report(report, tmp, "radar ADAS trigger: precision/recall per operating point")
    _print_distances(report)
    print(f"wrote {Path(args.out) / 'report.json'}")
    return 0


def _aeb(args: argparse.Namespace) -> int:
    from sensor_envs.evaluate.radar_aeb import aeb_experiment, write_aeb_report

    with output_folder(args.out, args.force) as tmp:
        report = aeb_experiment(episodes=args.episodes, max_steps=args.steps, seed=args.seed)
        report["command"] = _command()
        write_aeb_report(report, tmp)
    _print_distances(report, "distance_to_ideal")
    print(f"wrote {Path(args.out) / 'report.json'}")
    return 0


def _registration(args: argparse.Namespace) -> int:
    from sensor_envs.evaluate.lidar_registration import registration_experiment, write_registration_report

    with output_folder(args.out, args.force, (args.model,)) as tmp:
        report = registration_experiment(args.model, n_poses=args.poses, seed=args.seed)
        report["command"] = _command()
        write_registration_report(report, tmp)
    _print_distances(report, "distance_to_reference")
    print(f"wrote {Path(args.out) / 'report.json'}")
    return 0
