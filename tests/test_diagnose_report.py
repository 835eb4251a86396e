"""The diagnosis report of an interaction: its size per state quarter and a figure split the same way."""

from __future__ import annotations

import numpy as np

from sensor_envs.diagnose.core import Evaluation
from sensor_envs.diagnose.report import describe_effect, plot_effect


def _interaction(n: int = 4000) -> Evaluation:
    """``offset = 0.2 c`` for targets nearer than 50 m, ``-0.2 c`` beyond (metres)."""
    rng = np.random.default_rng(0)
    c, rng_m = rng.normal(size=n), rng.uniform(0.0, 100.0, n)
    r = 0.2 * c * np.sign(rng_m - 50.0) + 0.1 * rng.normal(size=n)
    return Evaluation(
        nll=np.zeros(n),
        residuals={"offset_y": r},
        candidates={"c": c},
        blocks=np.arange(n) // 40,
        state={"range": rng_m},
    )


def test_interaction_is_sized_per_state_quarter_with_its_sign():
    ev = _interaction()
    d = describe_effect(ev, {"name": "c", "metric": "offset_y", "form": "x range", "p_value": 0.002})
    slopes = [p["slope_per_unit"] for p in d["by_state"]]
    assert len(slopes) == 4
    assert slopes[0] < -0.15 and slopes[1] < -0.15 and slopes[2] > 0.15 and slopes[3] > 0.15, slopes
    assert "range" in d["text"] and d["unit"] == "m"


def test_interaction_figure_has_one_panel_per_quarter(tmp_path, monkeypatch):
    import matplotlib.figure

    ev = _interaction()
    panels: list[int] = []
    real = matplotlib.figure.Figure.savefig

    def spy(fig, *a, **k):  # count the figure's data panels as it is saved
        panels.append(len(fig.axes))
        return real(fig, *a, **k)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    path = plot_effect(ev, ev, "c", "offset_y", tmp_path / "int.png", "x range")
    assert path.is_file() and path.stat().st_size > 1000
    main = plot_effect(ev, ev, "c", "offset_y", tmp_path / "main.png")
    assert main.is_file()
    assert panels == [4, 1]
