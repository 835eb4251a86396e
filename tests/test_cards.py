"""Model cards: the shipped cards are the generator's output, one page each, and the files' metadata is right."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from sensor_envs.cards import MetricsFileError, read_header, read_metrics, render_card
from sensor_envs.cli.main import main

MODELS = Path(__file__).resolve().parents[1] / "models"
SHIPPED = ("radar_kde", "radar_gaussian", "radar_kde_fast", "radar_gaussian_fast", "neato_lidar")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_card_is_the_generators_output_and_one_page(name):
    card = (MODELS / f"{name}.md").read_text(encoding="utf-8")
    expected = render_card(MODELS / f"{name}.npz", read_metrics(MODELS / "metrics" / f"{name}.json"))
    assert card == expected, f"models/{name}.md differs from `sensor-envs card` (regenerate it, docs/howto/cards.md)"
    assert len(card.splitlines()) <= 120
    for section in ("Intended use", "Training data", "Hyperparameters", "Metrics on real data", "Limitations",
                    "How to rebuild"):  # fmt: skip
        assert f"## {section}" in card
    assert not re.search(r"/(work|home|root|Users)/", card), "a machine's absolute path in a card"


@pytest.mark.parametrize("name", [n for n in SHIPPED if n.startswith("radar")])
def test_radar_files_store_their_own_card_with_the_logs_name_and_sha256(name):
    header = read_header(MODELS / f"{name}.npz")
    log = header["card"]["log"]
    assert set(log) == {"file", "sha256"} and "/" not in log["file"] and re.fullmatch(r"[0-9a-f]{64}", log["sha256"])
    if header["kind"] == "radar_gaussian":  # not the KDE's card (relevance, bandwidths, the KDE's fit time)
        assert not {"relevance", "rel_variance_fitted", "fit_seconds", "bandwidth_scale_choice"} & set(header["card"])


def test_lidar_card_commands_have_no_machine_paths():
    header = read_header(MODELS / "neato_lidar.npz")
    assert not any("/work/" in c for c in header["card"]["commands"])


def test_fit_radar_stores_name_and_sha256_and_the_baseline_its_own_card(tmp_path, rig_split):
    from sensor_envs.modelio import file_sha256
    from sensor_envs.radar.log import write_log

    log = write_log(rig_split[1], tmp_path / "some_dir_name" / "log.csv")
    out = tmp_path / "kde.npz"
    assert main(["fit", "radar", str(log), "--out", str(out), "--cycle-time", "1.0"]) == 0
    kde, base = read_header(out), read_header(tmp_path / "kde_gaussian.npz")
    assert kde["card"]["log"] == {"file": "log.csv", "sha256": file_sha256(log)}
    assert base["card"]["log"] == kde["card"]["log"] and "relevance" not in base["card"]
    assert base["card"]["fitted_with"] == "kde.npz"


def test_card_command_writes_refuses_existing_and_inputs(tmp_path, capsys):
    model, metrics = MODELS / "radar_gaussian.npz", MODELS / "metrics" / "radar_gaussian.json"
    out = tmp_path / "card.md"
    assert main(["card", str(model), "--metrics", str(metrics), "--out", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == (MODELS / "radar_gaussian.md").read_text(encoding="utf-8")
    assert main(["card", str(model), "--metrics", str(metrics), "--out", str(out)]) == 2  # exists, no --force
    assert main(["card", str(model), "--metrics", str(metrics), "--out", str(out), "--force"]) == 0
    assert main(["card", str(model), "--out", str(metrics)]) == 2  # never over an input (nor a non-.md file)
    err = capsys.readouterr().err.strip().splitlines()
    assert all(line.startswith("sensor-envs card: error:") for line in err) and len(err) == 2


BAD_METRICS = {
    "not json": "{",
    "not an object": "[]",
    "metrics not a list": '{"metrics": {}}',
    "metric without name": '{"metrics": [{"value": 1}]}',
    "value not a number": '{"metrics": [{"name": "a", "value": "1"}]}',
    "value NaN": '{"metrics": [{"name": "a", "value": NaN}]}',
    "value a bool": '{"metrics": [{"name": "a", "value": true}]}',
    "interval of one number": '{"metrics": [{"name": "a", "value": 1, "interval": [1]}]}',
    "interval with infinity": '{"metrics": [{"name": "a", "value": 1, "interval": [0, Infinity]}]}',
    "rebuild not strings": '{"rebuild": [1]}',
    "measured not an object": '{"measured": "today"}',
}


@pytest.mark.parametrize("case", sorted(BAD_METRICS))
def test_bad_metrics_file_exit_2_one_line_naming_the_file_nothing_written(case, tmp_path, capsys):
    bad = tmp_path / "metrics.json"
    bad.write_text(BAD_METRICS[case], encoding="utf-8")
    with pytest.raises(MetricsFileError, match=re.escape(str(bad))):
        read_metrics(bad)
    out = tmp_path / "card.md"
    assert main(["card", str(MODELS / "radar_kde.npz"), "--metrics", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and not out.exists()


@pytest.mark.parametrize("content", [b"not a zip", None])
def test_bad_model_file_exit_2_one_line(content, tmp_path, capsys):
    model = tmp_path / "m.npz"
    if content is not None:
        model.write_bytes(content)
    else:
        np.savez(model, x=np.zeros(3))  # an .npz without a header
    assert main(["card", str(model), "--out", str(tmp_path / "c.md")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(model) in err[0]


def test_metrics_card_names_command_and_date():
    for name in SHIPPED:
        blob = json.loads((MODELS / "metrics" / f"{name}.json").read_text(encoding="utf-8"))
        if blob.get("metrics"):
            assert blob["measured"]["command"].startswith("python benchmarks/") and blob["measured"]["date"]
