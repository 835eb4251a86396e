import json

import pytest

from sensor_envs.cli.main import main


def test_record_fit_validate_radar(tmp_path):
    train, test, model = tmp_path / "train.csv", tmp_path / "test.csv", tmp_path / "kde.npz"
    assert main(["record", "radar", "--out", str(train), "--sequences", "8", "--cycles", "20", "--seed", "1"]) == 0
    assert main(["record", "radar", "--out", str(test), "--sequences", "4", "--cycles", "20", "--seed", "2"]) == 0
    assert main(["fit", "radar", str(train), "--out", str(model), "--cycle-time", "1.0"]) == 0
    assert (tmp_path / "kde_gaussian.npz").is_file()
    assert main(["validate", "radar", str(model), str(test), "--out", str(tmp_path / "rep")]) == 0
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    for key in ("model", "baseline_gaussian"):
        assert {"nll_outcome", "per_range_bin", "lag1_autocorr_simulated", "lag1_autocorr_measured"} <= set(rep[key])
    assert (tmp_path / "rep" / "pdf_heatmap.png").is_file()


def test_bad_log_gives_exit_code_2_and_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("sequence,frame\n0,0\n")
    assert main(["fit", "radar", str(bad), "--out", str(tmp_path / "m.npz")]) == 2
    assert f"{bad}: required column 't' is missing" in capsys.readouterr().err


@pytest.mark.slow
def test_validate_the_shipped_model_finds_its_shipped_baseline(tmp_path):
    from sensor_envs.modelio import default_model_path
    from sensor_envs.radar.sensors import DEFAULT_MODEL_FILES

    test = tmp_path / "test.csv"
    assert main(["record", "radar", "--out", str(test), "--sequences", "3", "--cycles", "10", "--seed", "2"]) == 0
    kde = default_model_path(DEFAULT_MODEL_FILES["kde"])
    assert main(["validate", "radar", str(kde), str(test), "--out", str(tmp_path / "r")]) == 0
    rep = json.loads((tmp_path / "r" / "report.json").read_text())
    assert rep["baseline_file"] == str(default_model_path(DEFAULT_MODEL_FILES["gaussian"]))


def test_record_in_view_only_and_fit_polar(tmp_path):
    """``record radar --in-view-only`` and ``fit radar --state-transform polar`` end to end."""
    from sensor_envs.radar.kde import KDERadarModel
    from sensor_envs.radar.log import read_log

    full, view, model = tmp_path / "full.csv", tmp_path / "view.csv", tmp_path / "kde.npz"
    # the generic lane traffic crosses the field of view's edge (the shipped rig's scene law keeps ~99 % inside)
    generic = tmp_path / "generic_rig.json"
    generic.write_text(json.dumps({"kind": "radar_rig", "format_version": 1, "params": {}}))
    rec = ["record", "radar", "--sequences", "6", "--cycles", "15", "--seed", "5", "--rig", str(generic)]
    assert main([*rec, "--out", str(full)]) == 0
    assert main([*rec, "--out", str(view), "--in-view-only"]) == 0
    a, b = read_log(full), read_log(view)
    assert (
        len(b) < len(a) and (~b.is_clutter).sum() < (~a.is_clutter).sum() and b.is_clutter.sum() == a.is_clutter.sum()
    )
    fit = ["fit", "radar", str(view), "--out", str(model), "--state-transform", "polar", "--cycle-time", "1.0"]
    assert main(fit) == 0
    m = KDERadarModel.load(model)
    assert m.state_transform == "polar" and m.relevance == "paper"  # the CV modes: tests/test_radar_polar.py
    bad = ["record", "radar", "--astyx", str(tmp_path), "--in-view-only", "--out", str(tmp_path / "x.csv")]
    assert main(bad) == 2
