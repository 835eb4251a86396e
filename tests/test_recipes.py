"""The shipped models' recipes (models/recipes/*.yaml) and ``sensor-envs rebuild-models``."""

import json
from pathlib import Path

import numpy as np
import pytest

from sensor_envs.cli.main import main
from sensor_envs.cli.rebuild import load_recipe, recipe_argv, recipe_models, recipe_names, recipes_folder
from sensor_envs.outputs import jsonable
from sensor_envs.sensor_model import NOT_SAVED as RUN_TIME

MODELS = Path(__file__).resolve().parents[1] / "models"
SHIPPED = sorted(p.name for p in MODELS.glob("*.npz"))
NOT_SAVED = (*RUN_TIME, "cv_candidates")  # run-time only (random_state, verbose), or stored as an array


def _header(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        header = json.loads(bytes(z["__header__"]).decode())
    for key in ("params", "card"):
        if isinstance(header.get(key), str):
            header[key] = json.loads(header[key])
    return header


def _recipes() -> dict[str, dict]:
    return {n: load_recipe(recipes_folder() / f"{n}.yaml") for n in recipe_names()}


def test_every_shipped_model_file_has_exactly_one_recipe():
    made = [f for r in _recipes().values() for f in r["outputs"].values()]
    assert sorted(made) == SHIPPED


@pytest.mark.parametrize("name", recipe_names())
def test_recipe_reproduces_the_shipped_files_hyperparameters(name):
    """The models the recipe's fit command builds have the hyperparameters stored in the shipped headers."""
    recipe = _recipes()[name]
    for file, model in recipe_models(recipe).items():
        header = _header(MODELS / file)
        if recipe["sensor"] == "lidar" and header["format_version"] < 6:  # fitted before the pooled bias existed
            header["params"].setdefault("bias_model", "per_bearing")
        params = {k: v for k, v in model.get_params().items() if k not in NOT_SAVED}
        assert jsonable(params) == header["params"], file
        card = header.get("card", {})
        if "seed" in card:  # the radar cards record the fit's seed
            assert recipe["fit"]["seed"] == card["seed"], file
            assert model.get_params().get("random_state", card["seed"]) == card["seed"], file
        if "rows" in card:  # the card's log: cycle time of the record and of the fit agree with the file
            assert recipe["record"]["cycle_time"] == pytest.approx(header["cycle_time"], rel=1e-5), file
    assert (MODELS / "recipes" / recipe["rig"]).is_file() or (MODELS / recipe["rig"]).is_file()  # as rebuild looks


def test_a_changed_recipe_no_longer_matches(tmp_path):
    """The comparison can fail: a recipe with another bandwidth factor differs from the shipped header."""
    recipe = _recipes()["radar_kde"]
    recipe["factors"] = {**recipe["factors"], "bandwidth_scale": 0.35}
    model = recipe_models(recipe)[recipe["outputs"]["model"]]
    params = {k: v for k, v in model.get_params().items() if k not in NOT_SAVED}
    assert jsonable(params) != _header(MODELS / recipe["outputs"]["model"])["params"]


def test_recipe_argv_spells_the_card_commands():
    recipe = _recipes()["radar_kde"]
    record, fit = recipe_argv(recipe, Path("R.json"), Path("W"), Path("O"))
    assert record == ["record", "radar", "--rig", "R.json", "--out", "W/radar_kde_train.csv", "--seed", "0",
                      "--sequences", "50", "--cycles", "40", "--targets", "8", "--cycle-time", "1.0",
                      "--in-view-only"]  # fmt: skip
    assert fit[:5] == ["fit", "radar", "W/radar_kde_train.csv", "--out", "O/radar_kde.npz"]
    assert "--baseline-out" in fit and fit[-8:] == ["--bandwidth-scale", "0.3", "--start-bandwidth-scale", "0.7",
                                                    "--tail-weight", "0.1", "--tail-scale", "4.0"]  # fmt: skip


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("- a list", "expected a mapping"),
        ("sensor: sonar\n", "'sensor'"),
        ("sensor: lidar\noutputs: {model: m.npz}\nrig: r.json\nrecord: {}\nfit: {}\nfactors: {a: 1}\n", "'factors'"),
        ("sensor: radar\noutputs: {}\nrig: r.json\nrecord: {}\nfit: {}\n", "'outputs.model'"),
        ("sensor: radar\nbogus: 1\n", "unknown field"),
        ("sensor: [\n", "not valid YAML"),
    ],
)
def test_bad_recipe_is_one_line_naming_the_file_and_field(tmp_path, capsys, text, field):
    (tmp_path / "recipes").mkdir()
    (tmp_path / "recipes" / "bad.yaml").write_text(text)
    assert main(["rebuild-models", "--recipes", str(tmp_path / "recipes"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.yaml" in err and field in err
    assert not (tmp_path / "o").exists()


def test_rebuild_models_smoke_on_a_tiny_recipe(tmp_path, capsys):
    """The command end to end on a tiny lidar recipe (the shipped rig, 3 poses); refuses an existing --out."""
    folder = tmp_path / "recipes"
    folder.mkdir()
    (folder / "tiny.yaml").write_text(
        "sensor: lidar\noutputs: {model: tiny.npz}\nrig: neato_rig.json\n"
        "record: {poses: 3, repeats: 5, seed: 1}\nfit: {variant: seed, folds: 2, seed: 0}\n"
    )
    out = tmp_path / "rebuilt"
    assert main(["rebuild-models", "--recipes", str(folder), "--out", str(out), "--only", "tiny"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["tiny.md", "tiny.npz"]
    assert _header(out / "tiny.npz")["params"]["variant"] == "seed"
    assert main(["rebuild-models", "--recipes", str(folder), "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["rebuild-models", "--recipes", str(folder), "--out", str(tmp_path / "x"), "--only", "nope"]) == 2
    (folder / "tiny.yaml").write_text((folder / "tiny.yaml").read_text().replace("variant: seed", "variant: nope"))
    assert main(["rebuild-models", "--recipes", str(folder), "--out", str(tmp_path / "y")]) == 2
    assert "tiny.yaml: the fit options" in capsys.readouterr().err.splitlines()[-1]
    assert not (tmp_path / "y").exists()
