import json
import os

import pytest

from sensor_envs.training import robustness


def _module():
    return robustness


@pytest.fixture(scope="module")
def short_matrix(tmp_path_factory):
    out = tmp_path_factory.mktemp("robust") / "neato"
    mod = _module()
    argv = ["--domain", "neato", "--preset", "short", "--out", str(out), "--workers", "2", "--device", "cpu"]
    matrix = mod.main(argv)
    return mod, out, matrix


@pytest.mark.slow
def test_short_preset_matrix_rows_columns_intervals_and_files(short_matrix):
    mod, out, matrix = short_matrix
    sensors = ["ideal", "gaussian", "learned"]
    assert matrix["rows_trained_on"] == sensors and matrix["columns_evaluated_on"] == sensors
    assert matrix["seeds"] == [0, 1] and "seeds resampled whole" in matrix["interval"]
    assert set(matrix["cells"]) == {f"{r}->{c}" for r in sensors for c in sensors}
    for cell in matrix["cells"].values():
        assert set(cell) == {"success", "collision", "return"}
        for m in cell.values():
            for stat in ("iqm", "mean"):
                lo, hi = m[f"{stat}_ci95"]
                assert lo <= m[stat] <= hi
            assert len(m["per_seed"]) == 2
        for rate in ("success", "collision"):
            assert 0.0 <= cell[rate]["mean_ci95"][0] <= cell[rate]["mean_ci95"][1] <= 1.0
    pairs = matrix["probability_of_improvement"]["return"]
    assert set(pairs) == {f"{a} vs {b} @ {c}" for a, b in [sensors[:2], sensors[::2], sensors[1:]] for c in sensors}
    assert json.loads((out / "matrix.json").read_text())["cells"] == matrix["cells"]
    md = (out / "matrix.md").read_text()
    assert "| learned |" in md and "95 % CI" in md and "Probability of improvement" in md
    assert (out / "matrix.png").stat().st_size > 0
    for r in sensors:
        for s in (0, 1):
            run = out / "runs" / r / f"seed{s}"
            assert (run / "done").is_file() and (run / "final_model.zip").is_file() and (run / "checkpoints").is_dir()


@pytest.mark.slow
def test_rerun_skips_finished_jobs_and_other_settings_are_refused(short_matrix, capsys):
    mod, out, matrix = short_matrix
    again = mod.main(["--domain", "neato", "--preset", "short", "--out", str(out), "--device", "cpu"])
    assert "6 of 6 jobs already done; running 0" in capsys.readouterr().out
    assert again["cells"] == matrix["cells"]
    with pytest.raises(SystemExit) as err:
        mod.main(["--domain", "neato", "--preset", "short", "--out", str(out), "--seeds", "3"])
    assert err.value.code == 2 and "seeds" in capsys.readouterr().err


@pytest.mark.slow
def test_ray_backend_gives_the_process_pool_numbers(short_matrix, tmp_path):
    if os.environ.get("CI"):  # the test extra installs ray: in CI a missing ray is a failure, not a skip
        import ray
    else:
        ray = pytest.importorskip("ray", reason="ray is not installed: pip install -e '.[test]'")
    mod, out, matrix = short_matrix
    ray.init(num_cpus=2, include_dashboard=False)
    try:
        argv = ["--domain", "neato", "--preset", "short", "--out", str(tmp_path / "ray"), "--backend", "ray"]
        res = mod.main([*argv, "--sensors", "ideal", "gaussian", "--seeds", "1", "--device", "cpu"])
    finally:
        ray.shutdown()
    for r in ("ideal", "gaussian"):  # same seed -> same evaluation numbers, whichever backend ran the job
        a = json.loads((out / "runs" / r / "seed0" / "eval.json").read_text())["cells"]
        b = json.loads((tmp_path / "ray" / "runs" / r / "seed0" / "eval.json").read_text())["cells"]
        assert a == b
    assert res["rows_trained_on"] == ["ideal", "gaussian"] and "single seed" in res["interval"]


@pytest.mark.slow
def test_real_data_column_fitted_once_and_cached_in_out(real_data, tmp_path):
    mod = _module()
    out = tmp_path / "real"
    argv = ["--domain", "neato", "--preset", "short", "--out", str(out), "--sensors", "ideal", "--seeds", "1"]
    matrix = mod.main([*argv, "--real-data", str(real_data), "--device", "cpu"])
    assert matrix["columns_evaluated_on"] == ["ideal", "gaussian", "learned", "learned-real"]
    model = out / "real_models" / "neato_lidar_real.npz"
    stamp = model.stat().st_mtime_ns
    mod.main([*argv, "--real-data", str(real_data), "--device", "cpu"])  # rerun: neither refits nor retrains
    assert model.stat().st_mtime_ns == stamp
