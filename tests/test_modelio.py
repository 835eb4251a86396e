import numpy as np
import pytest

from sensor_envs.modelio import ModelFileError, load_model_file, save_model_file

SCHEMA = {"table": ("f", 2, True), "idx": ("iu", 1, False)}


def _save(path, **over):
    arrays = {"table": np.arange(6.0).reshape(2, 3), "idx": np.array([1, 2, 3])}
    arrays.update(over)
    return save_model_file(path, "demo", 1, {"params": {"h": 0.5}}, arrays)


def test_round_trip_is_exact(tmp_path):
    p = _save(tmp_path / "m.npz")
    header, arrays = load_model_file(p, "demo", (1,), SCHEMA)
    assert header["params"] == {"h": 0.5} and header["format_version"] == 1
    assert np.array_equal(arrays["table"], np.arange(6.0).reshape(2, 3))


def test_errors_name_file_and_field(tmp_path):
    p = _save(tmp_path / "m.npz")
    with pytest.raises(ModelFileError, match="field 'kind' is 'demo'"):
        load_model_file(p, "other", (1,), SCHEMA)
    with pytest.raises(ModelFileError, match="format_version"):
        load_model_file(p, "demo", (2,), SCHEMA)
    with pytest.raises(ModelFileError, match="'extra' is missing"):
        load_model_file(p, "demo", (1,), {**SCHEMA, "extra": ("f", None, False)})
    bad = _save(tmp_path / "nan.npz", table=np.array([[np.nan, 1.0]]))
    with pytest.raises(ModelFileError, match=r"nan.npz: field 'table' holds NaN"):
        load_model_file(bad, "demo", (1,), SCHEMA)
    with pytest.raises(ModelFileError, match="dimensions"):
        load_model_file(_save(tmp_path / "dim.npz", table=np.zeros(3)), "demo", (1,), SCHEMA)
    with pytest.raises(ModelFileError, match="not found"):
        load_model_file(tmp_path / "missing.npz", "demo", (1,), SCHEMA)


def test_pickled_content_is_refused(tmp_path):
    p = tmp_path / "evil.npz"
    np.savez(p, __header__=np.frombuffer(b"{}", dtype=np.uint8), table=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ModelFileError, match="not a readable model file"):
        load_model_file(p, "demo", (1,), SCHEMA)
    with pytest.raises(TypeError, match="dtype object"):
        _save(tmp_path / "o.npz", table=np.array([{"a": 1}], dtype=object))
