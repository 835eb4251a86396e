"""``sensor-envs rebuild-models``: rebuild the shipped model files from their recipes (``models/recipes/*.yaml``).

A recipe is the shipped file's chain written once, as data: the shipped rig it records from (``rig``), the
``record`` and ``fit`` command options, the bandwidth ``factors`` chosen on real data (radar), and the files
the fit writes (``outputs``). :func:`recipe_argv` turns a recipe into the ``record`` and ``fit`` command lines;
:func:`recipe_models` builds the unfitted models those command lines fit (their hyperparameters are what the
shipped files' headers hold: tested).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path
from typing import Any

from sensor_envs.cli.args import OneLineParser, add_force
from sensor_envs.inputs import InputError, parse_yaml, read_text
from sensor_envs.outputs import output_folder

__all__ = ["RECIPE_KEYS", "load_recipe", "recipe_names", "recipe_argv", "recipe_models", "rebuild", "register"]

RECIPE_KEYS = {"sensor", "outputs", "rig", "record", "fit", "factors"}
"""Keys a recipe may hold (``factors`` only for the radar)."""


def recipes_folder() -> Path:
    """The shipped recipes (package ``sensor_envs.models``, folder ``recipes``)."""
    return Path(str(resources.files("sensor_envs.models").joinpath("recipes")))


def recipe_names(folder: Path | None = None) -> list[str]:
    """Names of the recipes in ``folder`` (default: the shipped ones), sorted."""
    return sorted(p.stem for p in (folder or recipes_folder()).glob("*.yaml"))


def load_recipe(path: Path) -> dict[str, Any]:
    """Read and check one recipe file.

    Raises:
        ValueError: naming the file and the field, for a malformed recipe.
    """
    recipe = parse_yaml(read_text(path, "recipe"), str(path))  # bounded, no aliases or tags (sensor_envs.inputs)
    if not isinstance(recipe, dict):
        raise InputError(f"{path}: expected a mapping of {sorted(RECIPE_KEYS)}")
    unknown = set(recipe) - RECIPE_KEYS
    if unknown:
        raise InputError(f"{path}: unknown field(s) {sorted(unknown)}")
    if recipe.get("sensor") not in ("lidar", "radar"):
        raise InputError(f"{path}: field 'sensor' must be lidar or radar, got {recipe.get('sensor')!r}")
    for key in ("outputs", "record", "fit"):
        if not isinstance(recipe.get(key), dict):
            raise InputError(f"{path}: field {key!r} must be a mapping")
    if not isinstance(recipe["outputs"].get("model"), str):
        raise InputError(f"{path}: field 'outputs.model' must be a file name")
    if not isinstance(recipe.get("rig"), str):
        raise InputError(f"{path}: field 'rig' must be a file name")
    if not isinstance(recipe.get("factors", {}), dict) or (recipe["sensor"] == "lidar" and "factors" in recipe):
        raise InputError(f"{path}: field 'factors' must be a mapping, for the radar only")
    return recipe


def _options(options: dict[str, Any]) -> list[str]:
    """``{"cycle_time": 1.0, "in_view_only": True, "relevance_candidates": [6, 12]}`` as command-line options."""
    out: list[str] = []
    for key, value in options.items():
        flag = "--" + str(key).replace("_", "-")
        if value is True:
            out.append(flag)
        elif value is False or value is None:
            continue
        elif isinstance(value, list):
            out += [flag, *map(str, value)]
        else:
            out += [flag, str(value)]
    return out


def recipe_argv(recipe: dict[str, Any], rig: Path, work: Path, out: Path) -> tuple[list[str], list[str]]:
    """The ``record`` and ``fit`` command lines of ``recipe``: log in ``work``, the outputs in ``out``."""
    sensor, outputs = recipe["sensor"], recipe["outputs"]
    log = work / (f"{Path(outputs['model']).stem}_train" + (".csv" if sensor == "radar" else ".npz"))
    record = ["record", sensor, "--rig", str(rig), "--out", str(log), *_options(recipe["record"])]
    fit = ["fit", sensor, str(log), "--out", str(out / outputs["model"]), *_options(recipe["fit"])]
    if "baseline" in outputs:
        fit += ["--baseline-out", str(out / outputs["baseline"])]
    fit += _options(recipe.get("factors", {}))
    return record, fit


def recipe_models(recipe: dict[str, Any]) -> dict[str, Any]:
    """Output file name -> the unfitted model that the recipe's ``fit`` command fits into it."""
    from sensor_envs.cli.main import build_parser

    _, fit = recipe_argv(recipe, Path("RIG"), Path("WORK"), Path("OUT"))
    args = build_parser().parse_args(fit)
    outputs = recipe["outputs"]
    if recipe["sensor"] == "lidar":
        from sensor_envs.cli.lidar import lwlr_from_args

        return {outputs["model"]: lwlr_from_args(args)}
    from sensor_envs.cli.radar import gaussian_from_args, kde_from_args

    models = {outputs["model"]: kde_from_args(args)}
    if "baseline" in outputs:
        models[outputs["baseline"]] = gaussian_from_args(args)
    return models


def rebuild(out: Path, only: list[str] | None, force: bool, recipes: Path | None = None) -> list[Path]:
    """Run the recipes (all, or those named in ``only``) into the folder ``out``; the files written.

    Each recipe records its training log into a temporary folder and fits into ``out``; ``out`` appears
    only when every recipe succeeded (an existing ``out`` needs ``force``).
    """
    from sensor_envs.cli.main import main

    folder = recipes or recipes_folder()
    names = recipe_names(folder)
    if not names:
        raise InputError(f"--recipes: no recipe (*.yaml) in {folder}")
    unknown = sorted(set(only or []) - set(names))
    if unknown:
        raise InputError(f"--only: no recipe named {unknown} in {folder} (have {names})")
    chosen = {n: load_recipe(folder / f"{n}.yaml") for n in names if not only or n in only}
    rigs = {n: _rig_path(folder, r["rig"]) for n, r in chosen.items()}
    written: list[Path] = []
    inputs = [folder, *[folder / f"{n}.yaml" for n in chosen], *rigs.values()]  # --out may hold none of them
    with (
        output_folder(out, force, inputs) as tmp,
        tempfile.TemporaryDirectory(prefix="rebuild_", dir=tmp.parent) as work,
    ):
        for name, recipe in chosen.items():
            for argv in recipe_argv(recipe, rigs[name], Path(work), tmp):
                t0 = time.perf_counter()
                print(f"[{name}] sensor-envs {' '.join(argv)}", file=sys.stderr, flush=True)
                try:
                    code = main(argv)
                except SystemExit as exc:
                    if exc.code != 2:  # e.g. SIGTERM (143): the command ends, rolled back, with that status
                        raise
                    # argparse refused an option (its message is printed above)
                    raise InputError(f"{folder / name}.yaml: the {argv[0]} options are refused") from None
                if code:
                    raise InputError(f"{name}: `sensor-envs {argv[0]} {argv[1]}` failed (exit {code})")
                print(f"[{name}] done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
            written += [out / f for f in recipe["outputs"].values()]
    return written


def _rig_path(folder: Path, name: str) -> Path:
    """A recipe's ``rig``: the file of that name beside the recipes, else the shipped one."""
    from sensor_envs.modelio import default_model_path

    return folder / name if (folder / name).is_file() else default_model_path(name)


def _run(args: argparse.Namespace) -> int:
    written = rebuild(Path(args.out), args.only, args.force, Path(args.recipes) if args.recipes else None)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def register(sub: argparse._SubParsersAction[OneLineParser]) -> None:
    """Add ``rebuild-models`` to the command line."""
    p = sub.add_parser(
        "rebuild-models",
        help="rebuild the shipped model files from their recipes (models/recipes/*.yaml; hours for all)",
    )
    p.add_argument("--out", required=True, help="output folder (the rebuilt .npz files)")
    p.add_argument(
        "--only", nargs="+", metavar="NAME", help="recipe names (default: all): " + ", ".join(recipe_names())
    )
    p.add_argument("--recipes", default=None, help="folder of recipes (default: the shipped models/recipes)")
    add_force(p)
    p.set_defaults(func=_run)
