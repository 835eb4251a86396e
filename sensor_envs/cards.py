"""One-page model cards, generated from a model file's own header and a measured-metrics JSON.

``sensor-envs card MODEL.npz --metrics METRICS.json --out MODEL.md`` writes the card; the shipped cards
(``models/*.md``) are this function's output for the shipped files and ``models/metrics/*.json`` (a test
checks it), so a card cannot disagree with its model file.

What comes from where:

* the model file's header (:func:`read_header`): kind, format version, cycle time, state variables,
  hyperparameters (``params``), what cross-validation chose, and the ``card`` the fit stored (training
  data's file name and sha256, rows, options, fit time);
* the metrics JSON (:func:`read_metrics`), written by whoever measured the model, with the command and
  the date of the measurement::

    {
      "measured": {"command": "python benchmarks/...", "date": "YYYY-MM-DD", "data": "what was held out"},
      "metrics": [{"name": "...", "value": 1.0, "interval": [0.9, 1.1], "unit": "m",
                   "reference": "what it is compared with", "note": "..."}],
      "training_data": ["how the training log was made, one command or sentence per line"],
      "rebuild": ["commands that rebuild the file"],
      "limitations": ["..."],
      "intended_use": "optional: replaces the kind's default paragraph"
    }

Every key is optional but ``metrics`` entries need ``name`` and ``value``; the card says "not measured"
where there is nothing.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sensor_envs.inputs import InputError, parse_json, read_text
from sensor_envs.modelio import ModelFileError, read_header_and_arrays

__all__ = ["read_header", "read_metrics", "render_card", "write_card", "MetricsFileError"]

MAX_HEADER_BYTES = 1 << 20
"""Largest ``__header__`` read (1 MiB): a model header is a few kB."""
MAX_METRICS_BYTES = 1 << 20
"""Largest metrics JSON read (1 MiB)."""

_INTENDED = {
    "radar_kde": (
        "Object-level automotive radar for simulation: given the closest corner of each target box in the "
        "sensor frame (x forward, y left) and the target's previous output, draws whether the radar reports "
        "the target and where (a KDE over recorded tuples, Hirsenkorn et al. 2016), plus clutter. Default of "
        '`make_radar("kde")` and of the highway envs\' `radar="kde"`. Not a model of raw radar returns, '
        "Doppler or RCS."
    ),
    "radar_gaussian": (
        "Baseline object radar: per corner-range bin, a detection probability and a Gaussian offset of the "
        "measured position from the closest corner, plus clutter. The simple model the KDE is compared with; "
        '`radar="gaussian"` in the highway envs.'
    ),
    "sensor_envs.lidar_lwlr": (
        "Planar lidar for simulation: per bearing, a reading is null with probability `p_null`, a spurious far "
        "return with `p_spur`, else Normal(range + bias, sigma), the parameters tabulated over the ray's "
        "nominal range and incidence (Tallavajhula & Kelly, locally weighted linear regression). Default of "
        '`make_lidar("learned")` and of Neato-v0\'s `lidar="learned"`; fitted to a Neato XV-11-like unit.'
    ),
}
_TITLES = {
    "radar_kde": "KDE object radar (`KDERadarModel`)",
    "radar_gaussian": "Gaussian baseline radar (`GaussianRadar`)",
    "sensor_envs.lidar_lwlr": "Learned lidar (`LidarLWLR`)",
}
_FITTED = {  # header keys (beyond params and card) worth a line, per kind
    "radar_kde": ("rel_variance_fitted", "azimuth_bias_fitted", "new_track_flags", "extra_variance_fitted"),
    "radar_gaussian": (),
    "sensor_envs.lidar_lwlr": ("h", "bias_shrinkage", "null_rho", "spur_rho", "spur_mu", "spur_sigma", "p_out"),
}


class MetricsFileError(InputError):
    """A malformed metrics JSON (the message names the file and the field)."""


def read_header(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The JSON header of a model file (``.npz`` with ``__header__``), read through the bounded model reader.

    Raises:
        ModelFileError: when the file is not a model file or its header is malformed.
        FileNotFoundError: when ``path`` does not exist.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such model file")
    header, _ = read_header_and_arrays(path, MAX_HEADER_BYTES)
    if not isinstance(header.get("kind"), str):
        raise ModelFileError(f"{path}: field '__header__' must be a JSON object with a 'kind'")
    return header


def read_metrics(path: str | os.PathLike[str] | None) -> dict[str, Any]:
    """A metrics JSON checked against the schema of the module docstring (``None``: no metrics).

    Raises:
        MetricsFileError: naming the file and the field of the first problem.
        FileNotFoundError: when ``path`` does not exist.
    """
    if path is None:
        return {}
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such metrics file")
    try:  # bounded: size, depth, no duplicate keys (sensor_envs.inputs)
        blob = parse_json(read_text(path, "metrics", limit=MAX_METRICS_BYTES), str(path))
    except InputError as exc:
        raise MetricsFileError(str(exc)) from None
    if not isinstance(blob, dict):
        raise MetricsFileError(f"{path}: the top level must be a JSON object")
    for key in ("training_data", "rebuild", "limitations"):
        if not _is_str_list(blob.get(key, [])):
            raise MetricsFileError(f"{path}: field '{key}' must be a list of strings")
    for key in ("measured",):
        if not isinstance(blob.get(key, {}), dict):
            raise MetricsFileError(f"{path}: field '{key}' must be a JSON object")
    metrics = blob.get("metrics", [])
    if not isinstance(metrics, list):
        raise MetricsFileError(f"{path}: field 'metrics' must be a list")
    for i, m in enumerate(metrics):
        _check_metric(path, i, m)
    return blob


def _is_str_list(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def _check_metric(path: Path, i: int, m: Any) -> None:
    where = f"{path}: field 'metrics[{i}]"
    if not isinstance(m, dict) or not isinstance(m.get("name"), str):
        raise MetricsFileError(f"{where}.name' must be a string")
    if not _is_number(m.get("value")):
        raise MetricsFileError(f"{where}.value' must be a finite number")
    interval = m.get("interval")
    if interval is not None and not (
        isinstance(interval, list) and len(interval) == 2 and all(_is_number(v) for v in interval)
    ):
        raise MetricsFileError(f"{where}.interval' must be null or two finite numbers")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _fmt(value: Any) -> str:
    """A compact, stable text form of a header value."""
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        if len(value) > 8:
            return f"[{', '.join(_fmt(v) for v in value[:8])}, ... ({len(value)} values)]"
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_fmt(v)}" for k, v in value.items()) + "}"
    if value is None:
        return "none"
    return str(value)


def _table(rows: Sequence[tuple[str, str]], head: tuple[str, str]) -> list[str]:
    out = [f"| {head[0]} | {head[1]} |", "|---|---|"]
    out += [f"| {a} | {b.replace('|', '/')} |" for a, b in rows]
    return out


def _data_section(header: Mapping[str, Any], metrics: Mapping[str, Any]) -> list[str]:
    card = header.get("card", {})
    lines = ["## Training data and how it was made", ""]
    log = card.get("log")
    if isinstance(log, dict):
        lines.append(f"- log: `{log.get('file')}`, sha256 `{log.get('sha256')}`; {card.get('rows', '?')} rows")
    training = card.get("training")
    if isinstance(training, dict):
        lines.append(
            f"- log: `{training.get('source')}`; {training.get('n_poses')} poses x {training.get('n_bearings')} "
            f"bearings, {training.get('n_readings')} readings, null fraction {_fmt(training.get('null_fraction'))}"
        )
        lines.append(f"- sha256 of the ranges array: `{training.get('sha256_of_ranges')}`")
    if "fit_seconds" in card:
        lines.append(f"- fit time: {_fmt(card['fit_seconds'])} s")
    lines += [f"- {line}" for line in metrics.get("training_data", [])]
    if len(lines) == 2:
        lines.append("- not recorded in the file")
    lines.append("- no real recording is stored in the file")
    return lines + [""]


def _hyper_section(header: Mapping[str, Any]) -> list[str]:
    kind = header["kind"]
    rows = [(f"`{k}`", _fmt(v)) for k, v in sorted(header.get("params", {}).items())]
    lines = ["## Hyperparameters", "", *_table(rows, ("parameter", "value")), ""]
    fitted = [(f"`{k}`", _fmt(header[k])) for k in _FITTED.get(kind, ()) if k in header]
    card = header.get("card", {})
    for key in ("bandwidth_scale_choice", "start_bandwidth_scale_choice"):
        choice = card.get(key)
        if isinstance(choice, dict):
            fitted.append(
                (
                    f"`{key}`",
                    f"{_fmt(choice.get('final'))} (criterion {choice.get('criterion')} on {choice.get('data')})",
                )
            )
    if fitted:
        lines += ["Chosen by cross-validation or estimated from the data:", ""]
        lines += [*_table(fitted, ("fitted", "value")), ""]
    return lines


def _metrics_section(metrics: Mapping[str, Any]) -> list[str]:
    lines = ["## Metrics on real data", ""]
    items = metrics.get("metrics", [])
    if not items:
        return [*lines, "Not measured on real data.", ""]
    measured = metrics.get("measured", {})
    if measured:
        data, command, date = (measured.get(k, "?") for k in ("data", "command", "date"))
        lines.append(f"Measured on {data} by `{command}` ({date}); intervals are 95 %.")
        lines.append("")
    lines += ["| metric | value | 95 % interval | compared with | note |", "|---|---|---|---|---|"]
    for m in items:
        unit = f" {m['unit']}" if m.get("unit") else ""
        iv = m.get("interval")
        iv_text = f"[{_fmt(float(iv[0]))}, {_fmt(float(iv[1]))}]" if iv else "-"
        cells = [m["name"], f"{_fmt(float(m['value']))}{unit}", iv_text, m.get("reference", "-"), m.get("note", "")]
        lines.append("| " + " | ".join(str(c).replace("|", "/") for c in cells) + " |")
    return [*lines, ""]


def render_card(model: str | os.PathLike[str], metrics: Mapping[str, Any] | None = None) -> str:
    """The Markdown card of a model file (``metrics``: a dict of the metrics JSON schema, or ``None``).

    Args:
        model: the model file (``.npz``); only its header is read.
        metrics: the measured metrics (:func:`read_metrics`'s result).

    Returns:
        The card's text, ending in a newline; the same inputs give the same text.

    Examples:
        >>> from sensor_envs.modelio import default_model_path
        >>> card = render_card(default_model_path("radar_gaussian.npz"))
        >>> card.splitlines()[0]
        '# Model card: `radar_gaussian.npz`'
        >>> "## How to rebuild" in card
        True
    """
    metrics = dict(metrics or {})
    header = read_header(model)
    kind = header["kind"]
    name = Path(model).name
    lines = [f"# Model card: `{name}`", ""]
    lines += [
        f"{_TITLES.get(kind, kind)}; model file format {header.get('format_version', '?')}"
        + (f", cycle time {_fmt(header['cycle_time'])} s" if "cycle_time" in header else "")
        + (f", state: {', '.join(header['state_variables'])}" if header.get("state_variables") else "")
        + ". Generated by `sensor-envs card` from the file's header and its measured metrics: edit those, not this.",
        "",
        "## Intended use",
        "",
        metrics.get("intended_use", _INTENDED.get(kind, "See the class docstring.")),
        "",
    ]
    lines += _data_section(header, metrics)
    lines += _hyper_section(header)
    lines += _metrics_section(metrics)
    lines += ["## Limitations", ""]
    lines += [f"- {text}" for text in metrics.get("limitations", [])] or ["- none stated"]
    lines += ["", "## How to rebuild", ""]
    rebuild = metrics.get("rebuild", []) or header.get("card", {}).get("commands", [])
    if rebuild:
        lines += ["```bash", *rebuild, "```"]
    else:
        lines.append("Not recorded.")
    return "\n".join(lines) + "\n"


def write_card(
    model: str | os.PathLike[str],
    out: str | os.PathLike[str],
    metrics: str | os.PathLike[str] | None = None,
    force: bool = False,
) -> Path:
    """Render the card of ``model`` with the metrics JSON ``metrics`` and write it to ``out`` (atomically).

    Raises:
        OutputError: when ``out`` exists (unless ``force``) or is one of the inputs.
    """
    from sensor_envs.outputs import atomic_write, check_inputs, check_output

    check_inputs(model, metrics)
    path = check_output(out, inputs=[model, metrics], force=force, suffix=".md")
    text = render_card(model, read_metrics(metrics))
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return path
