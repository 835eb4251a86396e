"""The radar object log: a CSV format of the project's own, its reader/writer and derived tuples.

Format (UTF-8 CSV, header line, one row per (radar cycle, target)):

============== ===== =====================================================================
column         unit  meaning
============== ===== =====================================================================
sequence       -     integer id of a recording (a time series, or one Astyx frame block)
frame          -     integer cycle index inside the sequence (consecutive cycles differ by 1)
t              s     time stamp of the cycle
target         -     integer id of the reference target inside the sequence; -1 for clutter
ref_x, ref_y   m     centre of the reference box, sensor frame (x forward, y left)
ref_heading    rad   heading of the reference box, counter-clockwise from the sensor x axis
ref_length     m     box length (along its heading)
ref_width      m     box width
meas_x, meas_y m     the radar's reported object position, sensor frame
============== ===== =====================================================================

* ``meas_x``/``meas_y`` empty: the radar missed the target in this cycle (object loss).
* all five ``ref_*`` empty: a detection that matches no target (clutter); ``meas`` must then be set.
* an empty field is the only way to write "missing"; literal ``nan``/``inf`` text in a required
  column is an error, and so are partly empty ``ref`` or ``meas`` groups.
* any other column is a numeric covariate (empty = missing) kept for later analysis.
* sanity ranges (checked before any model allocates grids over the log): positions ``ref_x``,
  ``ref_y``, ``meas_x``, ``meas_y`` within :data:`MAX_POSITION` (1 km) of the sensor, box sizes
  ``ref_length``/``ref_width`` at most :data:`MAX_SIZE` (100 m), integer ids below ``2**53``.
* the file is UTF-8 (a byte-order mark, as Excel writes, is accepted) and comma-separated, at most
  :data:`MAX_LOG_BYTES` (128 MiB) long; a field over the csv module's field limit or
  an unclosed quote is an error naming the line. Numbers are plain decimal text (``1_0.5`` is refused).
* consistency: every column name is non-empty; clutter rows have ``target`` -1; rows of one cycle
  ``(sequence, frame)`` share one ``t``, and ``t`` increases with ``frame`` within a sequence;
  ``|ref_heading|`` at most :data:`MAX_HEADING`, box sizes at least :data:`MIN_SIZE`, ``|t|`` and
  covariates within :data:`MAX_VALUE`.

The model tuples of Hirsenkorn et al. (2016) are derived by :func:`target_tuples`: the closest
corner of each reference box (sensor at the origin), the output ``z = meas - corner`` and the
previous output ``z_{t-1}`` of the same target (``NaN`` when the previous cycle is absent or missed).
"""

from __future__ import annotations

import array
import csv
import io
import os
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensor_envs.geometry import closest_corner, rectangle_corners
from sensor_envs.inputs import InputError, bad_name, read_bytes
from sensor_envs.outputs import atomic_write

__all__ = [
    "REQUIRED_COLUMNS",
    "REF_COLUMNS",
    "MEAS_COLUMNS",
    "RadarLog",
    "RadarLogError",
    "read_log",
    "write_log",
    "target_tuples",
    "clutter_counts",
]

INT_COLUMNS = ("sequence", "frame", "target")
MAX_POSITION = 1000.0
"""Largest accepted ``|ref_x|``, ``|ref_y|``, ``|meas_x|``, ``|meas_y|`` [m] (automotive radars reach ~300 m)."""
MAX_SIZE = 100.0
"""Largest accepted ``ref_length``/``ref_width`` [m]."""
MIN_SIZE = 0.01
"""Smallest accepted ``ref_length``/``ref_width`` [m] (1 cm: anything smaller is a unit or parsing error)."""
MAX_HEADING = 4 * np.pi
"""Largest accepted ``|ref_heading|`` [rad] (any heading can be written within +-2 pi)."""
MAX_VALUE = 1e12
"""Largest accepted ``|t|`` [s] and ``|covariate|`` (a Unix time in seconds is ~2e9)."""
MAX_LOG_BYTES = 128 * 2**20
"""Largest radar log CSV [bytes]: about 2 million rows, read in about a minute and 1 GB (the real logs are MBs)."""
MAX_ID = 2.0**53
"""Integer columns must stay below this in magnitude (exact in float64, no int64 wrap-around)."""
REF_COLUMNS = ("ref_x", "ref_y", "ref_heading", "ref_length", "ref_width")
MEAS_COLUMNS = ("meas_x", "meas_y")
REQUIRED_COLUMNS = ("sequence", "frame", "t", "target", *REF_COLUMNS, *MEAS_COLUMNS)


class RadarLogError(InputError):
    """A radar log is malformed; the message names the file, the column and the row."""


@dataclass
class RadarLog:
    """A radar object log held as columns (see the module docstring for the format).

    Attributes:
        columns: name -> ``(n,)`` array; ``sequence``, ``frame``, ``target`` are int64, all others
            float64 with ``NaN`` for empty fields.
        source: where the log came from (file name or a description), used in error messages.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import RadarLog
        >>> from sensor_envs.radar.rig import record_rig_log
        >>> log = record_rig_log(2, 5, 3, np.random.default_rng(0))
        >>> isinstance(log, RadarLog), int(log["frame"].max())
        (True, 4)
    """

    columns: dict[str, NDArray] = field(default_factory=dict)
    source: str = "<memory>"

    def __post_init__(self) -> None:
        """Validate the columns (raises :class:`RadarLogError`)."""
        self.columns = _validate(self.columns, self.source)

    def __len__(self) -> int:
        return int(self.columns["sequence"].shape[0])

    def __getitem__(self, name: str) -> NDArray:
        return self.columns[name]

    @property
    def covariates(self) -> list[str]:
        """Names of the extra numeric columns."""
        return [c for c in self.columns if c not in REQUIRED_COLUMNS]

    @property
    def is_clutter(self) -> NDArray[np.bool_]:
        """``(n,)`` rows that are detections matching no target."""
        return np.isnan(self.columns["ref_x"])

    @property
    def is_miss(self) -> NDArray[np.bool_]:
        """``(n,)`` target rows the radar missed."""
        return np.isnan(self.columns["meas_x"])

    def select(self, mask: NDArray[np.bool_]) -> RadarLog:
        """A new log with the rows where ``mask`` is true (raises if none are left)."""
        return RadarLog({k: v[mask] for k, v in self.columns.items()}, source=f"{self.source}[subset]")


def _as_column(name: str, values: NDArray, source: str) -> NDArray:
    """Convert one column to its dtype, or raise naming the column and file."""
    if np.iscomplexobj(values):  # never drop an imaginary part silently
        raise RadarLogError(f"{source}: column {name!r} holds complex numbers; expected real values")
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise RadarLogError(f"{source}: column {name!r} is not numeric") from None
    if arr.ndim != 1:
        raise RadarLogError(f"{source}: column {name!r} must be 1-D, got shape {arr.shape}")
    if name in INT_COLUMNS:
        bad = ~np.isfinite(arr) | (arr != np.round(arr))
        if bad.any():
            raise RadarLogError(f"{source}: column {name!r} row {int(np.flatnonzero(bad)[0])} is not an integer")
        big = np.abs(arr) >= MAX_ID
        if big.any():
            r = int(np.flatnonzero(big)[0])
            raise RadarLogError(f"{source}: column {name!r} row {r} holds {arr[r]:g}, out of range (|id| < 2**53)")
        return arr.astype(np.int64)
    return arr


def _first(mask: ArrayLike) -> int:
    return int(np.flatnonzero(mask)[0])


def _validate(columns: dict[str, NDArray], source: str) -> dict[str, NDArray]:
    """Check the required columns, dtypes, lengths and the empty-field rules."""
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        raise RadarLogError(f"{source}: required column {missing[0]!r} is missing")
    out = {k: _as_column(k, v, source) for k, v in columns.items()}
    n = {v.shape[0] for v in out.values()}
    if len(n) != 1:
        raise RadarLogError(f"{source}: columns have different lengths {sorted(n)}")
    if n.pop() == 0:
        raise RadarLogError(f"{source}: the log has no rows")
    for name, arr in out.items():
        if np.isinf(arr).any():
            raise RadarLogError(f"{source}: column {name!r} row {_first(np.isinf(arr))} is infinite")
    if np.isnan(out["t"]).any():
        raise RadarLogError(f"{source}: column 't' row {_first(np.isnan(out['t']))} is empty")
    ref_nan = np.stack([np.isnan(out[c]) for c in REF_COLUMNS], axis=1)
    partial = ref_nan.any(axis=1) & ~ref_nan.all(axis=1)
    if partial.any():
        r = _first(partial)
        col = REF_COLUMNS[int(np.argmax(ref_nan[r]))]
        raise RadarLogError(
            f"{source}: column {col!r} row {r} is empty but other ref columns are not "
            "(ref must be all empty for clutter or all set)"
        )
    meas_nan = np.isnan(out["meas_x"])
    if (meas_nan != np.isnan(out["meas_y"])).any():
        raise RadarLogError(
            f"{source}: column 'meas_y' row {_first(meas_nan != np.isnan(out['meas_y']))} "
            "is empty while 'meas_x' is not (or vice versa)"
        )
    clutter = ref_nan[:, 0]
    if (clutter & meas_nan).any():
        raise RadarLogError(f"{source}: row {_first(clutter & meas_nan)} has neither ref nor meas columns set")
    target_rows = ~clutter
    for c in ("ref_length", "ref_width"):
        bad = target_rows & ~(out[c] >= MIN_SIZE)
        if bad.any():
            raise RadarLogError(f"{source}: column {c!r} row {_first(bad)} must be >= {MIN_SIZE:g} m")
        bad = target_rows & (out[c] > MAX_SIZE)
        if bad.any():
            r = _first(bad)
            raise RadarLogError(
                f"{source}: column {c!r} row {r} is {out[c][r]:g} m, above the sanity limit {MAX_SIZE:g} m"
            )
    for c in ("ref_x", "ref_y", "meas_x", "meas_y"):
        bad = np.abs(out[c]) > MAX_POSITION  # NaN (empty) compares False
        if bad.any():
            r = _first(bad)
            raise RadarLogError(
                f"{source}: column {c!r} row {r} is {out[c][r]:g} m from the sensor, beyond the sanity limit "
                f"{MAX_POSITION:g} m"
            )
    if (out["target"][target_rows] < 0).any():
        raise RadarLogError(
            f"{source}: column 'target' row {_first(target_rows & (out['target'] < 0))} is negative on a target row"
        )
    _check_consistency(out, clutter, source)
    return out


def _check_consistency(out: dict[str, NDArray], clutter: NDArray[np.bool_], source: str) -> None:
    """Magnitudes of heading, time and covariates; clutter ids; one ``t`` per cycle, increasing with frame."""
    bad_names = [(i, why) for i, name in enumerate(out) if (why := bad_name(name))]
    if bad_names:
        i, why = bad_names[0]
        raise RadarLogError(f"{source}: header field {i + 1}: the column name {why}")
    bad = np.abs(out["ref_heading"]) > MAX_HEADING
    if bad.any():
        raise RadarLogError(f"{source}: column 'ref_heading' row {_first(bad)} is beyond +-{MAX_HEADING:g} rad")
    for name in ["t", *(c for c in out if c not in REQUIRED_COLUMNS)]:
        bad = np.abs(out[name]) > MAX_VALUE
        if bad.any():
            raise RadarLogError(f"{source}: column {name!r} row {_first(bad)} is beyond +-{MAX_VALUE:g}")
    bad = clutter & (out["target"] != -1)
    if bad.any():
        raise RadarLogError(f"{source}: column 'target' row {_first(bad)} is a clutter row (no ref) but not -1")
    _check_clutter_repeats(out, clutter, source)
    seq, frame, t = out["sequence"], out["frame"], out["t"]
    order = np.lexsort((frame, seq))
    same_seq = seq[order][1:] == seq[order][:-1]
    d_frame, d_t = np.diff(frame[order]), np.diff(t[order])
    bad = same_seq & (((d_frame == 0) & (d_t != 0)) | ((d_frame > 0) & (d_t <= 0)))
    if bad.any():
        r = int(order[1:][bad][0])
        raise RadarLogError(
            f"{source}: column 't' row {r} does not increase with 'frame' within sequence {int(seq[r])} "
            "(each cycle has one time, later frames later times)"
        )


def _check_clutter_repeats(out: dict[str, NDArray], clutter: NDArray[np.bool_], source: str) -> None:
    """No clutter detection twice in one cycle: the same (sequence, frame, meas_x, meas_y) is a row copied whole."""
    rows = np.flatnonzero(clutter)
    key = np.stack([out[k][rows] for k in ("sequence", "frame", "meas_x", "meas_y")], axis=1)
    order = np.lexsort(key.T[::-1])
    dup = (np.diff(key[order], axis=0) == 0).all(axis=1)
    if dup.any():
        r = int(rows[order[1:][dup][0]])
        raise RadarLogError(
            f"{source}: row {r} repeats the clutter detection (sequence, frame, meas_x, meas_y) of an earlier row"
        )


_NUMBER = re.compile(r"[+-]?([0-9]+(?:\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?|[+-]?(nan|inf|infinity)", re.IGNORECASE)
"""Plain decimal text (``float`` would also take ``1_0.5`` as 10.5)."""


def _parse_cell(text: str, name: str, row: int, source: str, required: bool) -> float:
    """One CSV field: empty -> NaN; literal nan/inf text in a required column is an error."""
    s = text.strip()
    if s == "":
        return np.nan
    try:
        if not _NUMBER.fullmatch(s):
            raise ValueError(s)
        v = float(s)
    except ValueError:
        raise RadarLogError(f"{source}: column {name!r} row {row} holds {s!r}, which is not a number") from None
    if required and not np.isfinite(v):
        raise RadarLogError(
            f"{source}: column {name!r} row {row} holds {s!r}; write an empty field for 'missing', not NaN/inf"
        )
    return v


def read_log(path: str | os.PathLike[str]) -> RadarLog:
    """Read and validate a radar log CSV.

    Raises:
        RadarLogError: naming the file, the column and the row of the first problem.
        FileNotFoundError: when ``path`` does not exist.

    Examples:
        >>> import numpy as np
        >>> from sensor_envs import read_log
        >>> from sensor_envs.radar.log import write_log
        >>> from sensor_envs.radar.rig import record_rig_log
        >>> path = write_log(record_rig_log(2, 5, 3, np.random.default_rng(0)), "example_radar.csv")
        >>> sorted(read_log(path).columns)[:4]
        ['frame', 'meas_x', 'meas_y', 'ref_heading']
    """
    path = Path(path)
    src = str(path)
    if path.is_dir():
        hint = " (convert an Astyx folder with: sensor-envs record radar --astyx FOLDER --out LOG.csv)"
        raise RadarLogError(f"{src}: is a folder; a radar log is a CSV file{hint}")
    raw = read_bytes(path, "radar log", limit=MAX_LOG_BYTES)
    try:
        text = raw.decode("utf-8-sig")  # Excel writes a byte-order mark
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise RadarLogError(
            f"{src}: line {line}: byte {raw[exc.start : exc.start + 1]!r} is not UTF-8 text (save the CSV as UTF-8)"
        ) from None
    del raw
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        return _read_rows(reader, src)
    except csv.Error as exc:  # a field over csv.field_size_limit(), an unclosed quote, a stray quote
        raise RadarLogError(f"{src}: line {reader.line_num}: not valid CSV ({exc})") from None


def _read_rows(reader: Any, src: str) -> RadarLog:
    """The log from a ``csv.reader`` over its text (``csv.Error`` passes to the caller)."""
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise RadarLogError(f"{src}: the file is empty (no header line)") from None
    if len(header) == 1:
        for sep in (";", "\t", "|"):
            if sep in header[0]:
                raise RadarLogError(
                    f"{src}: the header is one column {header[0][:60]!r}: the file seems separated by {sep!r}; "
                    "expected commas"
                )
    if len(set(header)) != len(header):
        raise RadarLogError(f"{src}: duplicate column names in the header")
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:  # before any row: an Astyx point cloud or another table is named as such, not by a row count
        astyx = Path(src).parent.name.startswith("radar_") or not any(header)
        hint = " (an Astyx frame? convert the folder with: sensor-envs record radar --astyx FOLDER --out LOG.csv)"
        raise RadarLogError(f"{src}: required column {missing[0]!r} is missing from the header{hint if astyx else ''}")
    req = [h in REQUIRED_COLUMNS for h in header]
    cols = {h: array.array("d") for h in header}  # 8 bytes a cell, rows never held as lists of strings
    for i, r in enumerate(r for r in reader if r):
        if len(r) != len(header):
            raise RadarLogError(f"{src}: row {i} has {len(r)} fields, the header has {len(header)}")
        for h, cell, rq in zip(header, r, req, strict=True):
            cols[h].append(_parse_cell(cell, h, i, src, rq))
    return RadarLog({h: np.frombuffer(v, dtype=np.float64).copy() for h, v in cols.items()}, source=src)


def write_log(log: RadarLog, path: str | os.PathLike[str]) -> Path:
    """Write ``log`` as CSV (required columns first, then covariates); NaN is written as empty.

    Written to a temporary sibling and renamed: an interrupted write leaves the old file intact.
    """
    path = Path(path)
    names = list(REQUIRED_COLUMNS) + log.covariates
    cols = [log.columns[c] for c in names]

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(names)
            for i in range(len(log)):
                w.writerow(["" if (c.dtype.kind == "f" and np.isnan(c[i])) else repr(c[i].item()) for c in cols])

    atomic_write(path, write)
    return path


@dataclass(frozen=True)
class TargetTuples:
    """Model tuples derived from the target rows of a log (all arrays aligned, ``n`` rows).

    Attributes:
        corner: ``(n, 2)`` closest corner of the reference box to the sensor, sensor frame [m].
        z: ``(n, 2)`` output ``meas - corner`` [m]; ``NaN`` rows are misses.
        z_prev: ``(n, 2)`` the same target's output in the previous cycle (``frame - 1``) [m];
            ``NaN`` when that cycle is absent from the log or was a miss.
        has_prev_row: ``(n,)`` whether the previous cycle of this target is in the log at all.
        row: ``(n,)`` row index in the log (traceability).
        sequence, frame, target: ``(n,)`` int64 ids copied from the log.
    """

    corner: NDArray[np.float64]
    z: NDArray[np.float64]
    z_prev: NDArray[np.float64]
    has_prev_row: NDArray[np.bool_]
    row: NDArray[np.int64]
    sequence: NDArray[np.int64]
    frame: NDArray[np.int64]
    target: NDArray[np.int64]

    def take(self, mask: NDArray[np.bool_]) -> TargetTuples:
        """The tuples where ``mask`` ``(n,)`` is true, every field alike."""
        return TargetTuples(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})


def target_tuples(log: RadarLog) -> TargetTuples:
    """Derive the (corner, z, z_{t-1}) tuples of every target row of ``log`` (vectorised)."""
    rows = np.flatnonzero(~log.is_clutter)
    if rows.size == 0:
        raise RadarLogError(f"{log.source}: the log has no target rows (only clutter)")
    c = {k: log.columns[k][rows] for k in (*REF_COLUMNS, *MEAS_COLUMNS, "sequence", "frame", "target")}
    box = rectangle_corners(c["ref_x"], c["ref_y"], c["ref_heading"], c["ref_length"], c["ref_width"])
    corner, _ = closest_corner(box)
    z = np.stack([c["meas_x"], c["meas_y"]], axis=1) - corner
    key = np.stack([c["sequence"], c["target"], c["frame"]], axis=1)
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    ks = key[order]
    dup = (np.diff(ks, axis=0) == 0).all(axis=1)
    if dup.any():
        r = int(rows[order[1:][dup][0]])
        raise RadarLogError(f"{log.source}: row {r} repeats (sequence, frame, target) of an earlier row")
    prev_ok = np.zeros(len(rows), dtype=bool)
    prev_ok[1:] = (ks[1:, 0] == ks[:-1, 0]) & (ks[1:, 1] == ks[:-1, 1]) & (ks[1:, 2] == ks[:-1, 2] + 1)
    z_sorted = z[order]
    zp_sorted = np.full_like(z_sorted, np.nan)
    zp_sorted[1:][prev_ok[1:]] = z_sorted[:-1][prev_ok[1:]]
    z_prev = np.empty_like(z)
    z_prev[order] = zp_sorted
    has_prev = np.empty(len(rows), dtype=bool)
    has_prev[order] = prev_ok
    return TargetTuples(corner, z, z_prev, has_prev, rows.astype(np.int64), c["sequence"], c["frame"], c["target"])


_UNSET = object()


def check_states(
    state: Any,
    z: Any = _UNSET,
    rng: Any = _UNSET,
    *,
    extra: Any = None,
    new_track: Any = None,
    extra_names: tuple[str, ...] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """The checked arguments of a radar model's ``sample``/``log_prob``: states ``(n, 2|4)`` and outputs ``(n, 2)``.

    Corners (columns 0-1) finite within :data:`MAX_POSITION`; previous outputs (columns 2-3) and ``z``
    finite or NaN (missing / a miss, both columns alike) within the same bound; ``rng`` a Generator;
    ``new_track`` ``None`` or ``n`` booleans; with ``extra_names`` given (the model's extra state
    variables), ``extra`` ``None`` or ``(n, E)`` real numbers (NaN = missing) for ``E`` names, and ``None``
    (or no columns) for a model without any.

    Raises:
        InputError: naming the argument and the first offending entry.
    """
    from sensor_envs.inputs import check_array, check_rng

    if rng is not _UNSET:
        check_rng(rng)
    st = check_array(np.atleast_2d(state), "state", (None, (2, 4)), low=-MAX_POSITION, high=MAX_POSITION, nan=True)
    if np.isnan(st[:, :2]).any():
        raise InputError(f"state: row {_first(np.isnan(st[:, :2]).any(axis=1))} has a NaN corner")
    if st.shape[1] == 4 and (np.isnan(st[:, 2]) != np.isnan(st[:, 3])).any():
        raise InputError(
            f"state: row {_first(np.isnan(st[:, 2]) != np.isnan(st[:, 3]))} has a half-NaN previous output"
        )
    if z is None:
        raise InputError("z: expected (n, 2) outputs [m] (NaN rows = misses), got None")
    zz = None
    if z is not _UNSET:
        zz = check_array(np.atleast_2d(z), "z", (st.shape[0], 2), low=-MAX_POSITION, high=MAX_POSITION, nan=True)
        if (np.isnan(zz[:, 0]) != np.isnan(zz[:, 1])).any():
            raise InputError(f"z: row {_first(np.isnan(zz[:, 0]) != np.isnan(zz[:, 1]))} is half NaN")
    if new_track is not None:
        nt = np.asarray(new_track)
        if nt.dtype.kind != "b" or nt.shape != (st.shape[0],):
            raise InputError(f"new_track: expected {st.shape[0]} booleans or None, got {nt.dtype} {nt.shape}")
        if st.shape[1] == 4 and (nt & np.isfinite(st[:, 2])).any():
            raise InputError(
                f"new_track: row {_first(nt & np.isfinite(st[:, 2]))} is a new track with a previous output"
            )
    if extra_names is not None and extra is not None:
        if not extra_names and np.size(extra):
            raise InputError("extra: this model has no extra state variables; pass None")
        if extra_names:
            check_array(np.atleast_2d(extra), "extra", (st.shape[0], len(extra_names)), low=-1e12, high=1e12, nan=True)
    return st, zz


def check_cycle_states(
    corners: Any,
    prev_z: Any,
    rng: Any,
    *,
    extra: Any = None,
    new_track: Any = None,
    extra_names: tuple[str, ...] | None = None,
) -> NDArray[np.float64]:
    """The checked arguments of a radar model's ``sample_cycle``; returns the corners ``(n, 2)`` as floats.

    :func:`check_states` on the corners and previous outputs side by side.
    """
    state = corners if prev_z is None else np.column_stack([np.atleast_2d(corners), prev_z])
    check_states(state, rng=rng, extra=extra, new_track=new_track, extra_names=extra_names)
    return np.atleast_2d(np.asarray(corners, dtype=np.float64))


CYCLE_TIME_TOLERANCE = 0.05
"""Relative difference allowed between a given cycle time and the log's median frame interval."""


def fit_cycle_time(log: Any, cycle_time: float | None) -> float:
    """The cycle time [s] a model fit on ``log`` stores: ``cycle_time`` checked against the log, NaN if ``None``.

    A fit's first check: ``log`` must be a :class:`RadarLog`; a given cycle time must be a finite number
    ``> 0`` within 5 % of the log's median interval between consecutive frames of a sequence (when the log
    has consecutive frames: ``--cycle-time 7.5`` on a log whose frames are 1 s apart is refused).

    Raises:
        InputError: naming ``log`` or ``cycle_time``.
    """
    from sensor_envs.modelio import optional_positive

    if not isinstance(log, RadarLog):
        raise InputError(f"log: expected a RadarLog (sensor_envs.radar.log.read_log), got {type(log).__name__}")
    cycle = optional_positive(None, "cycle_time", cycle_time)
    if np.isnan(cycle):
        return cycle
    seq, frame, t = log["sequence"], log["frame"], log["t"]
    order = np.lexsort((frame, seq))
    step = (np.diff(seq[order]) == 0) & (np.diff(frame[order]) == 1)
    if step.any():
        interval = float(np.median(np.diff(t[order])[step]))
        if abs(interval - cycle) > CYCLE_TIME_TOLERANCE * cycle:
            raise InputError(
                f"cycle_time: {cycle:g} s, but consecutive frames of {log.source} are {interval:g} s apart (column 't')"
            )
    return cycle


def clutter_counts(log: RadarLog) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Clutter detections per cycle and their positions.

    Cycles are the distinct ``(sequence, frame)`` pairs present in the log (a cycle with neither
    targets nor clutter cannot be represented and is not counted).

    Returns:
        ``counts (n_cycles,)`` number of clutter rows per cycle, and ``xy (m, 2)`` clutter
        positions in the sensor frame [m].
    """
    seq, frame = log.columns["sequence"], log.columns["frame"]
    cyc, inv = np.unique(np.stack([seq, frame], axis=1), axis=0, return_inverse=True)
    cl = log.is_clutter
    counts = np.bincount(inv.ravel()[cl], minlength=cyc.shape[0]).astype(np.int64)
    xy = np.stack([log.columns["meas_x"][cl], log.columns["meas_y"][cl]], axis=1)
    return counts, xy
