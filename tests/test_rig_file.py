"""Rig parameter files (``modelio.save_rig_file`` / ``load_rig_file``): JSON, versioned, value-checked."""

from __future__ import annotations

import json

import pytest

from sensor_envs.modelio import Interval, ModelFileError, load_rig_file, save_rig_file

CONSTRAINTS = {"p_detect": [Interval(0, 1)], "sigma": [Interval(0, None, open_low=True)]}


def test_round_trip(tmp_path):
    path = save_rig_file(tmp_path / "rig.json", "test_rig", {"p_detect": 0.9, "sigma": 0.2}, {"against": "x"})
    params, card = load_rig_file(path, "test_rig", CONSTRAINTS)
    assert params == {"p_detect": 0.9, "sigma": 0.2}
    assert card == {"against": "x"}


@pytest.mark.parametrize(
    ("blob", "field"),
    [
        ({"kind": "other", "format_version": 1, "params": {}}, "kind"),
        ({"kind": "test_rig", "format_version": 9, "params": {}}, "format_version"),
        ({"kind": "test_rig", "format_version": 1, "params": {"p_detect": 1.7}}, "params.p_detect"),
        ({"kind": "test_rig", "format_version": 1, "params": {"sigma": -1.0}}, "params.sigma"),
        ({"kind": "test_rig", "format_version": 1, "params": {"bogus": 1.0}}, "params.bogus"),
        ({"kind": "test_rig", "format_version": 1, "params": []}, "params"),
    ],
)
def test_bad_values_name_file_and_field(tmp_path, blob, field):
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(blob))
    with pytest.raises(ModelFileError, match=f"rig.json: field '{field}'"):
        load_rig_file(path, "test_rig", CONSTRAINTS)


def test_suffix_and_garbage(tmp_path):
    with pytest.raises(ValueError, match="json"):
        save_rig_file(tmp_path / "rig.txt", "test_rig", {})
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ModelFileError, match="bad.json: not a JSON rig file"):
        load_rig_file(bad, "test_rig", CONSTRAINTS)
