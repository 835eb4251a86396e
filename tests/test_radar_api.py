import pickle

import numpy as np
import pytest

from sensor_envs.modelio import default_model_path
from sensor_envs.radar.sensors import DEFAULT_MODEL_FILES, IdealRadar, RadarSensor, make_radar


def test_unknown_name_is_named():
    with pytest.raises(ValueError, match="unknown radar 'lidar'"):
        make_radar("lidar")


def test_ideal_takes_no_model():
    assert isinstance(make_radar("ideal"), IdealRadar)
    with pytest.raises(ValueError, match="takes no model"):
        make_radar("ideal", "x.npz")


@pytest.mark.parametrize("name", ["gaussian", "kde"])
def test_default_models_load_sample_and_pickle(name):
    assert default_model_path(DEFAULT_MODEL_FILES[name]).is_file()
    radar = make_radar(name)
    assert isinstance(radar, RadarSensor)
    corners = np.array([[20.0, 3.0], [45.0, -3.5], [70.0, 0.0]])
    prev = np.array([[0.2, 0.1], [np.nan, np.nan], [0.0, 0.3]])
    z, src = radar.sample_cycle(corners, prev, np.random.default_rng(0))
    assert z.shape == (3, 2) and src.shape == (3,) and src.dtype == np.int64
    again = pickle.loads(pickle.dumps(radar))
    z2, src2 = again.sample_cycle(corners, prev, np.random.default_rng(0))
    np.testing.assert_array_equal(z, z2)
    np.testing.assert_array_equal(src, src2)
    assert radar.sample_clutter(np.random.default_rng(1)).shape[1] == 2
