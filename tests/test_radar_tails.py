"""The KDE radar's defensive tail mixture (format 8): sample and log_prob agree, old files load, values are checked,
``tune radar`` chooses a tail where the held-out rows have one, and ``validate radar`` gives verdicts on frames."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensor_envs.modelio import ModelFileError
from sensor_envs.radar.kde import KDERadarModel
from sensor_envs.radar.log import target_tuples
from sensor_envs.radar.validate import chi_square


def _states(model: KDERadarModel, n: int = 40) -> np.ndarray:
    """Stored states of detected tuples with a previous output (the main tree), ``(n, 4)``."""
    rows = np.flatnonzero(np.isfinite(model.states_[:, 2]) & ~model.miss_)[:n]
    return model.states_[rows]


def test_no_tail_draws_exactly_what_the_paper_model_draws(model):
    states = _states(model)
    a = model.sample(states, np.random.default_rng(3))
    b = model.with_tail(0.0, 8.0).sample(states, np.random.default_rng(3))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@settings(max_examples=12, deadline=None)
@given(w=st.floats(0.01, 0.5), c=st.floats(1.0, 20.0), seed=st.integers(0, 2**31 - 1))
def test_log_prob_is_the_mixture_of_the_narrow_and_the_wide_kernels(model, w, c, seed):
    """exp(log_prob) = (1 - w) p_h + w p_{c h} for detections and misses alike (the miss law is unchanged)."""
    rng = np.random.default_rng(seed)
    states = _states(model)
    z = model.sample(states, rng)[0] + rng.normal(0.0, 3.0, (states.shape[0], 2))  # near and far offsets
    z[::7] = np.nan  # some misses
    mixed = model.with_tail(w, c).log_prob(z, states)
    narrow, wide = model.log_prob(z, states), model.with_bandwidth_scale(c).log_prob(z, states)
    expect = np.where(np.isnan(z[:, 0]), narrow, np.logaddexp(np.log1p(-w) + narrow, np.log(w) + wide))
    np.testing.assert_allclose(mixed, expect, rtol=1e-9, atol=1e-9)


def test_samples_follow_the_mixture_log_prob_chi_square(model):
    """Two-stage samples of a tailed model against its binned analytic law (bin_probabilities holds the tail)."""
    tailed = model.with_tail(0.2, 6.0)
    state = _states(model, 1)[0]
    res = chi_square(tailed, state, np.random.default_rng(5), n=40_000)
    assert res["p_value"] > 1e-3, res["statistic"]
    p, p_miss = tailed.bin_probabilities(state, res["edges_x"], res["edges_y"])
    q, _ = model.bin_probabilities(state, res["edges_x"], res["edges_y"])
    assert p.sum() < q.sum()  # the wide kernels put mass beyond the central bins


def test_a_far_detection_costs_at_most_minus_log_w_plus_the_wide_kernel(model):
    states = _states(model, 20)
    far = np.tile([25.0, 25.0], (20, 1))
    paper, tailed = model.log_prob(far, states), model.with_tail(0.05, 16.0).log_prob(far, states)
    assert np.all(tailed > paper + 10.0)  # tens of nats saved at 35 m off
    assert np.all(np.isfinite(tailed))


def test_tail_survives_save_and_load_and_old_files_load_without_one(model, tmp_path):
    tailed = model.with_tail(0.1, 4.0)
    back = KDERadarModel.load(tailed.save(tmp_path / "t.npz"))
    assert (back.tail_weight, back.tail_scale) == (0.1, 4.0)
    states = _states(model)
    np.testing.assert_array_equal(
        tailed.sample(states, np.random.default_rng(1))[0], back.sample(states, np.random.default_rng(1))[0]
    )
    old = _rewrite_header(tmp_path / "t.npz", tmp_path / "old.npz", lambda h: _as_format_7(h))
    loaded = KDERadarModel.load(old)
    assert loaded.tail_weight == 0.0
    np.testing.assert_array_equal(loaded.log_prob(states[:, :2] * 0, states), model.log_prob(states[:, :2] * 0, states))


@pytest.mark.parametrize(("field", "value"), [("tail_weight", 0.7), ("tail_weight", -0.1), ("tail_scale", 0.5)])
def test_bad_tail_values_are_refused_at_load_naming_the_field(model, tmp_path, field, value):
    model.with_tail(0.1, 4.0).save(tmp_path / "t.npz")

    def bad(h: dict) -> dict:
        h["params"][field] = value
        return h

    path = _rewrite_header(tmp_path / "t.npz", tmp_path / "bad.npz", bad)
    with pytest.raises(ModelFileError, match=field):
        KDERadarModel.load(path)
    with pytest.raises(ValueError, match=field):
        model.with_tail(value if field == "tail_weight" else 0.1, value if field == "tail_scale" else 4.0)


def test_validate_cli_bad_tail_exits_2_with_one_line(model, tmp_path, capsys):
    from sensor_envs.cli.main import main

    model.with_tail(0.1, 4.0).save(tmp_path / "t.npz")

    def bad(h: dict) -> dict:
        h["params"]["tail_scale"] = float("nan")
        return h

    path = _rewrite_header(tmp_path / "t.npz", tmp_path / "bad.npz", bad)
    rc = main(["tune", "radar", str(path), str(tmp_path), "--out", str(tmp_path / "o.npz")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "bad.npz" in err[0] and "tail_scale" in err[0]
    assert not (tmp_path / "o.npz").exists()


@pytest.mark.parametrize("outliers", [0.0, 0.08])
def test_tune_chooses_a_tail_only_where_the_held_out_rows_have_one(model, rig_split, outliers):
    """A planted share of detections far off every tuple: the fold-chosen weight is > 0; none planted: the
    least weight tried or a small one, and the held-out NLL never worse than without a tail."""
    from sensor_envs.radar.fidelity import fold_rows
    from sensor_envs.radar.tune import choose_tail, nested_rows, tail_scores

    test = rig_split[1]
    rng = np.random.default_rng(17)
    far = np.isfinite(test["meas_x"]) & (rng.random(len(test)) < outliers)
    cols = dict(test.columns)
    cols["meas_x"] = np.where(far, cols["meas_x"] + rng.choice([-12.0, 12.0], len(test)), cols["meas_x"])
    log = type(test)(cols, source="planted")
    folds = [fold_rows(log, 5, 3, k) for k in range(3)]
    scores = tail_scores(model, folds, (0.0, 0.05, 0.2), (8.0,), seed=0, chains=2, cycles=2)
    final, nested = choose_tail(scores)
    held, none = nested_rows(scores, nested), nested_rows(scores, [(0.0, 8.0)] * 3)
    for law in held:
        assert held[law].mean() <= none[law].mean() + 0.05
    if outliers:
        assert final[0] > 0.0 and all(p[0] > 0.0 for p in nested)
    else:
        assert final[0] <= 0.05


def _as_format_7(h: dict) -> dict:
    h["format_version"] = 7
    h["params"].pop("tail_weight")
    h["params"].pop("tail_scale")
    return h


def _rewrite_header(src, dst, edit):
    """Copy a model file with its JSON header edited by ``edit`` (a file another version or a bad writer made)."""
    with np.load(src) as a:
        arrays = {k: a[k] for k in a.files}
    header = edit(json.loads(arrays.pop("__header__").tobytes().decode("utf-8")))
    blob = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    np.savez(dst, __header__=blob, **arrays)
    assert zipfile.is_zipfile(dst)
    return dst


def test_target_tuples_of_a_rig_log_have_previous_rows(rig_split):
    """The fixture the tune test plants outliers in is a time series (both laws are scored)."""
    assert target_tuples(rig_split[1]).has_prev_row.any()


def test_validate_radar_gives_a_verdict_per_metric_on_single_frames(model, rig_split, tmp_path, capsys):
    """Single frames (no previous cycle in the log): start tuple and stationary law, mean and median NLL and
    detection per bin, each with a verdict word, in the printout and in report.json."""
    from sensor_envs.cli.main import main
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.log import write_log

    test = rig_split[1]
    frames = test.select(test["frame"] % 2 == 0)  # no row's previous cycle is in the log
    write_log(frames, tmp_path / "frames.csv")
    model.with_tail(0.05, 8.0).save(tmp_path / "m.npz")
    GaussianRadar().fit(rig_split[0]).save(tmp_path / "m_gaussian.npz")
    args = ["validate", "radar", str(tmp_path / "m.npz"), str(tmp_path / "frames.csv"), "--out", str(tmp_path / "v")]
    assert main([*args, "--chains", "2", "--cycles", "2", "--n-boot", "100"]) == 0
    out = capsys.readouterr().out.splitlines()
    words = ("BETTER", "NOT DISTINGUISHABLE", "WORSE")
    for law in ("start", "stationary"):
        for what in ("NLL of z given a detection (mean)", "NLL of z given a detection (median)", "detection range"):
            hits = [line for line in out if line.startswith(f"{law} law, {what}")]
            assert hits and all(line.rstrip().endswith(words) for line in hits), (law, what)
    rep = json.loads((tmp_path / "v" / "report.json").read_text())["frames"]
    nll = rep["stationary"]["nll_z_given_detected"]["model"]
    assert nll["mean_ci"][0] <= nll["mean"] <= nll["mean_ci"][1] and nll["median_verdict"] in {w.lower() for w in words}
    assert {"ideal", "baseline_gaussian", "model"} <= set(rep["start"]["detection_range"][0])


def test_tune_radar_refit_chooses_a_tail_for_a_model_fitted_on_frames_with_outliers(rig_split, tmp_path, capsys):
    """A KDE fitted on the user's own frames (no z_{t-1}), 8 % of them far off: ``--refit`` scores each fold with a
    copy fitted without it and keeps a tail; the written model carries it and the card records the choice."""
    from sensor_envs.cli.main import main
    from sensor_envs.radar.log import write_log

    test = rig_split[1]
    rng = np.random.default_rng(23)
    far = np.isfinite(test["meas_x"]) & (rng.random(len(test)) < 0.08)
    cols = dict(test.columns)
    cols["meas_y"] = np.where(far, cols["meas_y"] + rng.choice([-10.0, 10.0], len(test)), cols["meas_y"])
    log = type(test)(cols, source="planted")
    write_log(log, tmp_path / "frames.csv")
    KDERadarModel(use_prev=False, cv_group="sequence", random_state=0).fit(log).save(tmp_path / "m.npz")
    out = tmp_path / "tailed.npz"
    args = ["tune", "radar", str(tmp_path / "m.npz"), str(tmp_path / "frames.csv"), "--out", str(out), "--refit"]
    assert main([*args, "--folds", "3", "--block", "5", "--tail-weights", "0", "0.1", "--tail-scales", "8"]) == 0
    tailed = KDERadarModel.load(out)
    assert (tailed.tail_weight, tailed.tail_scale) == (0.1, 8.0)
    assert tailed.card_["tail_choice"]["refit"] is True
    assert "nested choices" in capsys.readouterr().out
    assert main([*args, "--what", "bandwidth", "--force"]) == 2  # --refit is for the tail only
    assert "--refit" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        (["--block", "1000", "--folds", "500"], "blocks of 1000 frames"),
        (["--folds", "2.5"], "--folds"),
        (["--tail-weights", "0.7"], "--tail-weights"),
        (["--tail-scales", "0.5"], "--tail-scales"),
    ],
)
def test_tune_radar_bad_input_exits_2_one_line_nothing_written(model, rig_split, tmp_path, capsys, extra, field):
    from sensor_envs.cli.main import main
    from sensor_envs.radar.log import write_log

    write_log(rig_split[1], tmp_path / "frames.csv")
    model.save(tmp_path / "m.npz")
    out = tmp_path / "o.npz"
    with pytest.raises(SystemExit) if field.startswith(("--tail", "--folds")) else _nothing():
        code = main(["tune", "radar", str(tmp_path / "m.npz"), str(tmp_path / "frames.csv"), "--out", str(out), *extra])
        assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and field in err[-1] and not out.exists()


class _nothing:
    """A context that expects nothing (argparse errors raise SystemExit(2) instead of returning 2)."""

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> bool:
        return False
