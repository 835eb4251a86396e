import re

import numpy as np
import pytest

from sensor_envs.radar.log import REQUIRED_COLUMNS, RadarLog, RadarLogError, read_log, target_tuples, write_log

HEADER = ",".join(REQUIRED_COLUMNS)


def _write(tmp_path, lines, header=HEADER):
    p = tmp_path / "log.csv"
    p.write_text("\n".join([header, *lines]) + "\n")
    return p


def _cols(**over):
    base = {
        "sequence": [0, 0, 0, 0],
        "frame": [0, 1, 2, 2],
        "t": [0.0, 1.0, 2.0, 2.0],
        "target": [3, 3, 3, -1],
        "ref_x": [10.0, 11.0, 12.0, np.nan],
        "ref_y": [0.0, 0.0, 0.0, np.nan],
        "ref_heading": [0.0, 0.0, 0.0, np.nan],
        "ref_length": [4.0, 4.0, 4.0, np.nan],
        "ref_width": [2.0, 2.0, 2.0, np.nan],
        "meas_x": [8.5, np.nan, 10.3, 30.0],
        "meas_y": [1.2, np.nan, -0.9, 5.0],
    }
    base.update(over)
    return {k: np.asarray(v, dtype=float) for k, v in base.items()}


def test_roundtrip_keeps_values_nan_and_covariates(tmp_path):
    cols = _cols(rcs=[1.0, 2.0, np.nan, 4.0])
    log = RadarLog(cols, source="mem")
    back = read_log(write_log(log, tmp_path / "a.csv"))
    assert back.covariates == ["rcs"]
    for k, v in log.columns.items():
        np.testing.assert_array_equal(back[k], v)
    assert back.is_clutter.tolist() == [False, False, False, True]
    assert back.is_miss.tolist() == [False, True, False, False]


def test_tuples_closest_corner_and_previous_output():
    tt = target_tuples(RadarLog(_cols()))
    # box centred at (10, 0), 4 x 2, heading 0: closest corner to the origin is (8, +-1) -> tie, first is rear-right
    np.testing.assert_allclose(np.abs(tt.corner[0]), [8.0, 1.0])
    assert np.isnan(tt.z_prev[0]).all() and not tt.has_prev_row[0]
    assert tt.has_prev_row[1] and np.allclose(tt.z_prev[1], tt.z[0])
    assert tt.has_prev_row[2] and np.isnan(tt.z_prev[2]).all()  # previous cycle was a miss


def test_literal_nan_in_ref_column_names_column_and_file(tmp_path):
    p = _write(tmp_path, ["0,0,0.0,1,nan,0,0,4,2,9,1"])
    with pytest.raises(RadarLogError, match=re.escape(f"{p}: column 'ref_x' row 0")):
        read_log(p)


def test_partly_empty_ref_is_an_error(tmp_path):
    p = _write(tmp_path, ["0,0,0.0,1,10,0,,4,2,9,1"])
    with pytest.raises(RadarLogError, match="column 'ref_heading' row 0 is empty"):
        read_log(p)


def test_covariate_of_wrong_type(tmp_path):
    p = _write(tmp_path, ["0,0,0.0,1,10,0,0,4,2,9,1,car"], header=HEADER + ",kind")
    with pytest.raises(RadarLogError, match=re.escape(f"{p}: column 'kind' row 0 holds 'car'")):
        read_log(p)


def test_no_rows_and_missing_column(tmp_path):
    with pytest.raises(RadarLogError, match="has no rows"):
        read_log(_write(tmp_path, []))
    with pytest.raises(RadarLogError, match="required column 'meas_y' is missing"):
        read_log(_write(tmp_path, ["0,0,0.0,1,10,0,0,4,2,9"], header=HEADER.rsplit(",", 1)[0]))


def test_neither_ref_nor_meas_and_duplicates():
    with pytest.raises(RadarLogError, match="neither ref nor meas"):
        RadarLog(_cols(meas_x=[8.5, np.nan, 10.3, np.nan], meas_y=[1.2, np.nan, -0.9, np.nan]))
    with pytest.raises(RadarLogError, match="repeats"):
        target_tuples(RadarLog(_cols(frame=[0, 0, 2, 2], t=[0.0, 0.0, 2.0, 2.0])))
