"""Fitted conditional corrections on top of a radar model: what ``diagnose radar`` adds for a found cause.

A :class:`CorrectedRadar` wraps a fitted base model (the KDE radar or its Gaussian baseline) and a
list of :class:`Term` objects, each a smooth function of one covariate column ``c`` (a log column the
world supplies, e.g. ``rel_vx``), optionally different per bin of the target's azimuth or range (an
interaction with the model's own state). Each term acts on one *part* of the output law:

* ``mean_x`` / ``mean_y``: an offset ``d(c)`` [m] added to the output's sensor-frame x / y;
* ``spread``: a log scale factor ``a(c)``: the output's deviation from the base model's mean output
  is multiplied by ``exp(a)`` (both axes);
* ``rate``: ``b(c)`` added to the logit of the detection probability.

With ``mu`` the base model's mean output and ``p`` its detection probability at the state, the
corrected model draws ``z = mu + exp(a) (z0 - mu) + d`` from a base draw ``z0``, and detects with
``p' = sigmoid(logit p + b)``; :meth:`CorrectedRadar.log_prob` is the exact density of that law
(change of variables: ``log p'(z) = log p'/p + log p0(z0) - 2 a``), so sampling and scoring are paired.
A detection the corrected law asks for where the base draw missed is redrawn from the base model
(up to :data:`MAX_REDRAWS` times; a row still missed then stays missed: the law is then slightly
under-detecting there).

Shape of a term: piecewise-linear in ``c`` through :data:`N_KNOTS` knots at quantiles of ``c`` in
the fit data (constant beyond the end knots; linear, step, U and saturating forms alike), times an
indicator of :data:`N_STATE_BINS` quantile bins of the state feature (``azimuth`` [rad] or ``range``
[m] of the closest corner) for an interaction; fitted by ridge regression (mean: the offsets;
spread: ``log`` of the squared offsets; rate: logistic with the base logit as offset).

Model file: kind :data:`KIND`, format :data:`FORMAT_VERSION`; the base model's own file is stored
inside it (``base_file``, the bytes of its pickle-free ``.npz``) and read by the base class's loader,
so its values are checked as usual; the terms' values are checked here. No pickle.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensor_envs.inputs import InputError
from sensor_envs.modelio import Constraint, InstanceOf, ModelFileError, Names, load_model_file, save_model_file
from sensor_envs.sensor_model import extra_state_names

__all__ = [
    "KIND",
    "FORMAT_VERSION",
    "PARTS",
    "STATE_FEATURES",
    "Term",
    "CorrectedRadar",
    "fit_term",
    "term_basis",
    "load_radar_file",
    "HEADER_SCHEMA",
]

KIND = "radar_corrected"
FORMAT_VERSION = 1
PARTS = ("mean_x", "mean_y", "spread", "rate")
"""Parts of the output law a term acts on."""
STATE_FEATURES = ("", "azimuth", "range")
"""State features a term may interact with (``""``: none, a main effect)."""
N_KNOTS = 6
N_STATE_BINS = 4
MAX_REDRAWS = 30
_LIMITS = {"mean_x": 100.0, "mean_y": 100.0, "spread": 5.0, "rate": 20.0}
"""Largest absolute coefficient a file may hold per part [m, log-scale, logit]."""
_RIDGE = 30.0
HEADER_SCHEMA: dict[str, list[Constraint]] = {
    "extra_state": [Names()],
    "free_previous": [InstanceOf(bool)],
    "terms": [InstanceOf(list)],  # each term's part, column, state and fill: checked by the loader
}
"""Declared fitted fields of a corrected radar file's header (:func:`sensor_envs.modelio.check_header`)."""


@dataclass
class Term:
    """One fitted correction term.

    Attributes:
        part: one of :data:`PARTS`.
        column: the covariate's column name (a log column the world must supply).
        knots: ``(K,)`` increasing knot positions in the column's units.
        state: ``""`` or the state feature it interacts with (:data:`STATE_FEATURES`).
        edges: ``(S - 1,)`` increasing bin edges of the state feature (empty for a main effect).
        coef: ``(S, K)`` the term's value at each knot per state bin [m, log scale or logit].
        fill: value taken for a missing (NaN) covariate (the fit data's median).
    """

    part: str
    column: str
    knots: NDArray[np.float64]
    state: str
    edges: NDArray[np.float64]
    coef: NDArray[np.float64]
    fill: float

    @property
    def label(self) -> str:
        """e.g. ``mean_y(speed x azimuth)``."""
        return f"{self.part}({self.column}{' x ' + self.state if self.state else ''})"

    def value(self, c: NDArray, corners: NDArray) -> NDArray[np.float64]:
        """``(n,)`` the term at covariate values ``c (n,)`` and closest corners ``(n, 2)`` [m]."""
        return np.asarray(term_basis(c, corners, self) @ self.coef.ravel(), dtype=np.float64)


def _state_feature(name: str, corners: NDArray) -> NDArray[np.float64]:
    """Azimuth [rad] or range [m] of the closest corners ``(n, 2)``."""
    if name == "azimuth":
        return np.arctan2(corners[:, 1], corners[:, 0])
    return np.hypot(corners[:, 0], corners[:, 1])


def _hats(c: NDArray, knots: NDArray) -> NDArray[np.float64]:
    """``(n, K)`` piecewise-linear interpolation weights of ``c`` at ``knots`` (rows sum to 1)."""
    k = knots.size
    if k == 1:
        return np.ones((c.size, 1))
    x = np.clip(c, knots[0], knots[-1])
    j = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, k - 2)
    t = (x - knots[j]) / np.maximum(knots[j + 1] - knots[j], 1e-300)
    out = np.zeros((c.size, k))
    rows = np.arange(c.size)
    out[rows, j] = 1.0 - t
    out[rows, j + 1] += t
    return out


def term_basis(c: NDArray, corners: NDArray, term: Term) -> NDArray[np.float64]:
    """``(n, S * K)`` design of a term: knot weights of ``c`` within the state bin of each row."""
    c = np.asarray(c, dtype=np.float64).ravel()
    c = np.where(np.isfinite(c), c, term.fill)
    h = _hats(c, term.knots)
    s = term.edges.size + 1
    if s == 1:
        return h
    b = np.searchsorted(term.edges, _state_feature(term.state, np.atleast_2d(corners)), side="right")
    out = np.zeros((c.size, s, term.knots.size))
    out[np.arange(c.size), b] = h
    return out.reshape(c.size, -1)


def _new_term(part: str, column: str, c: NDArray, corners: NDArray, state: str) -> Term:
    """An unfitted term with knots at quantiles of ``c`` and state-bin edges at quantiles of the state."""
    f = c[np.isfinite(c)]
    if f.size == 0:
        raise InputError(f"column {column!r}: no finite value to fit a correction on")
    knots = np.unique(np.quantile(f, np.linspace(0.05, 0.95, N_KNOTS)))
    edges = np.zeros(0)
    if state:
        edges = np.unique(np.quantile(_state_feature(state, corners), np.linspace(0, 1, N_STATE_BINS + 1)[1:-1]))
    coef = np.zeros((edges.size + 1, knots.size))
    return Term(part, column, knots, state, edges, coef, float(np.median(f)))


def _ridge(x: NDArray, y: NDArray, ridge: float) -> NDArray[np.float64]:
    """Ridge coefficients of ``y ~ x`` (no intercept: the knot weights sum to 1)."""
    a = x.T @ x + ridge * np.eye(x.shape[1])
    return np.asarray(np.linalg.solve(a, x.T @ y), dtype=np.float64)


def _robust(r: NDArray) -> NDArray[np.float64]:
    """``r`` clipped at 5 robust standard deviations (heavy tails must not steer a least-squares fit)."""
    med = np.median(r)
    s = 1.4826 * np.median(np.abs(r - med)) + 1e-12
    return np.asarray(np.clip(r, med - 5 * s, med + 5 * s), dtype=np.float64)


def fit_term(
    part: str,
    column: str,
    c: NDArray,
    corners: NDArray,
    z: NDArray,
    mu: NDArray,
    p_miss: NDArray,
    state: str = "",
    ridge: float = _RIDGE,
) -> Term:
    """Fit one term on out-of-sample base-model quantities.

    Args:
        part: one of :data:`PARTS`.
        column: the covariate's name.
        c: ``(n,)`` covariate values.
        corners: ``(n, 2)`` closest corners [m].
        z: ``(n, 2)`` outputs [m] (NaN rows = missed).
        mu: ``(n, 2)`` the base model's mean output at each row [m] (not fitted on these rows).
        p_miss: ``(n,)`` the base model's miss probability at each row.
        state: ``""`` or a state feature (:data:`STATE_FEATURES`).
        ridge: ridge penalty in pseudo-readings per knot value.

    Returns:
        The fitted :class:`Term`.
    """
    if part not in PARTS:
        raise InputError(f"part: expected one of {PARTS}, got {part!r}")
    if state not in STATE_FEATURES:
        raise InputError(f"state: expected one of {STATE_FEATURES}, got {state!r}")
    c = np.asarray(c, dtype=np.float64)
    term = _new_term(part, column, c, corners, state)
    x = term_basis(c, corners, term)
    det = np.isfinite(z[:, 0])
    if part != "rate":  # offsets need the base mean (NaN where a KDE query found no weighted detection)
        det &= np.isfinite(mu).all(axis=1)
    if part in ("mean_x", "mean_y"):
        k = 0 if part == "mean_x" else 1
        coef = _ridge(x[det], _robust(z[det, k] - mu[det, k]), ridge)
    elif part == "spread":
        r = z[det] - mu[det]
        v = np.mean(_robust_sq(r), axis=0) + 1e-12
        u = np.log(np.sum(r**2 / v, axis=1) + 1e-6)
        coef = 0.5 * _ridge(x[det], u - u.mean(), ridge)
        a = x[det] @ coef
        coef -= 0.5 * np.log(np.mean(np.exp(2 * a)))  # the base's average spread is kept
    else:
        coef = _logistic_offset(x, det.astype(np.float64), 1.0 - p_miss, ridge)
    term.coef = np.clip(coef, -_LIMITS[part], _LIMITS[part]).reshape(term.coef.shape)
    return term


def _robust_sq(r: NDArray) -> NDArray[np.float64]:
    """Squared offsets ``(n, 2)`` of the central readings (each axis clipped at 5 robust sd)."""
    return np.stack([_robust(r[:, k]) ** 2 for k in range(r.shape[1])], axis=1)


def _logistic_offset(x: NDArray, y: NDArray, p0: NDArray, ridge: float, steps: int = 12) -> NDArray[np.float64]:
    """Coefficients of ``logit p = logit p0 + x c`` by ridge-regularised Newton steps (``y`` in {0, 1})."""
    p0 = np.clip(p0, 1e-6, 1 - 1e-6)
    off = np.log(p0) - np.log1p(-p0)
    c = np.zeros(x.shape[1])
    for _ in range(steps):  # Newton iterations (a few dozen coefficients)
        p = 1.0 / (1.0 + np.exp(-(off + x @ c)))
        g = x.T @ (y - p) - ridge * c
        h = (x * (p * (1 - p))[:, None]).T @ x + ridge * np.eye(x.shape[1])
        c = c + np.linalg.solve(h, g)
    return c


class CorrectedRadar:
    """A radar model with fitted conditional corrections (implements ``RadarSensor``).

    Args:
        base: a fitted :class:`~sensor_envs.radar.kde.KDERadarModel` or
            :class:`~sensor_envs.radar.gaussian.GaussianRadar`.
        terms: the fitted :class:`Term` objects.
        free_previous: the base model was fitted on outputs freed of the mean terms' offsets, and
            conditions on a previous output freed the same way: the offset at the current covariate
            values is taken off ``z_{t-1}`` before the base model sees it (a slow covariate's offset is
            then carried by the term, not by the base model's ``z_{t-1}``).

    The extra state (``extra_state_``) is the base model's, then every term column the base does not
    name; ``extra`` arguments are ``(n, E)`` in that order. Other attributes (``cycle_time_``,
    ``sample_clutter``, ...) are the base model's.
    """

    CAPABILITIES = frozenset({"new_track", "extra_state", "prev_output", "log_prob", "clutter"})
    """What callers may ask (:func:`sensor_envs.sensor_model.has_capability`): the base model's queries
    are passed on (a Gaussian base accepts and ignores ``z_{t-1}`` and the new-track flags)."""

    def __init__(self, base: Any, terms: list[Term], free_previous: bool = False) -> None:
        self.base = base
        self.terms = list(terms)
        self.free_previous = bool(free_previous)
        self.card_: dict[str, Any] = {}
        base_names = extra_state_names(base)
        own = tuple(dict.fromkeys(t.column for t in self.terms if t.column not in base_names))
        self.extra_state_ = (*base_names, *own)
        self._n_base = len(base_names)

    def __getattr__(self, name: str) -> Any:
        if name in ("base", "terms", "free_previous", "card_", "_last_mean", "__setstate__", "__getstate__"):
            raise AttributeError(name)
        return getattr(self.base, name)

    @property
    def state_variables(self) -> tuple[str, ...]:
        """The base model's state names, then the correction columns."""
        return (*self.base.state_variables, *self.extra_state_[self._n_base :])

    # -- the corrected law --------------------------------------------------------------------------

    def _split(self, extra: NDArray | None, n: int) -> tuple[NDArray | None, dict[str, NDArray]]:
        """The base model's ``extra`` and the term columns' values from ``extra (n, E)``."""
        e = len(self.extra_state_)
        if e == 0:
            return None, {}
        if extra is None:
            raise InputError(f"extra: this model's state includes {list(self.extra_state_)}; pass their values")
        x = np.asarray(extra, dtype=np.float64)
        if x.size != n * e:
            raise InputError(f"extra: expected ({n}, {e}) values of {list(self.extra_state_)}, got shape {x.shape}")
        x = x.reshape(n, e)
        cols = {name: x[:, i] for i, name in enumerate(self.extra_state_)}
        return (x[:, : self._n_base] if self._n_base else None), cols

    def _parts(self, cols: dict[str, NDArray], corners: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Offset ``(n, 2)`` [m], log scale ``(n,)`` and logit shift ``(n,)`` of the corrections."""
        n = corners.shape[0]
        shift, log_s, logit = np.zeros((n, 2)), np.zeros(n), np.zeros(n)
        for t in self.terms:
            v = t.value(cols[t.column], corners)
            if t.part == "mean_x":
                shift[:, 0] += v
            elif t.part == "mean_y":
                shift[:, 1] += v
            elif t.part == "spread":
                log_s += v
            else:
                logit += v
        return shift, log_s, logit

    def _base_mean(self, st: NDArray, bex: NDArray | None, new_track: NDArray | None) -> tuple[NDArray, NDArray]:
        """The base model's ``mean_output`` at ``st`` (the last result is kept).

        A batch is often scored, sampled and scored again at the same states, and a KDE query costs a
        neighbour search; the key is the bytes of the arguments, compared exactly. A missing mean
        (NaN: a KDE query whose detected neighbours all have zero weight) is taken as 0 (the corner),
        for sampling and scoring alike.
        """
        parts = [np.ascontiguousarray(st, dtype=np.float64).tobytes()]
        parts += [b"" if a is None else np.ascontiguousarray(a).tobytes() for a in (bex, new_track)]
        key = tuple(parts)
        last = self.__dict__.get("_last_mean")
        if last is not None and last[0] == key:
            return last[1], last[2]
        mu, p_miss = self.base.mean_output(st, extra=bex, new_track=new_track)
        # a KDE query whose detected neighbours all have zero weight has no mean: scale about the corner
        mu, p_miss = np.nan_to_num(np.asarray(mu, dtype=np.float64)), np.asarray(p_miss, dtype=np.float64)
        self.__dict__["_last_mean"] = (key, mu, p_miss)
        return mu, p_miss

    def _freed_state(self, st: NDArray, shift: NDArray) -> NDArray[np.float64]:
        """States with the previous output freed of the offsets (``free_previous``), else ``st`` itself."""
        if not self.free_previous or st.shape[1] < 4:
            return st
        return np.concatenate([st[:, :2], st[:, 2:4] - shift, st[:, 4:]], axis=1)

    @staticmethod
    def _p_detect(p_miss: NDArray, logit: NDArray) -> tuple[NDArray, NDArray]:
        """Base and corrected detection probabilities ``(n,)`` each."""
        p0 = np.clip(1.0 - p_miss, 1e-9, 1 - 1e-9)
        return p0, 1.0 / (1.0 + np.exp(-(np.log(p0) - np.log1p(-p0) + logit)))

    def mean_output(
        self, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> tuple[NDArray, NDArray]:
        """Expected output given a detection ``(n, 2)`` [m] and ``P(miss)`` ``(n,)`` (arguments as :meth:`log_prob`)."""
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        bex, cols = self._split(extra, st.shape[0])
        shift, _, logit = self._parts(cols, st[:, :2])
        st = self._freed_state(st, shift)
        mu, p_miss = self._base_mean(st, bex, new_track)
        _, p1 = self._p_detect(p_miss, logit)
        return mu + shift, 1.0 - p1

    def log_prob(
        self, z: NDArray, state: NDArray, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> NDArray[np.float64]:
        """Log-probability ``(n,)`` of outputs ``z (n, 2)`` [m] (NaN row = miss) under the corrected law.

        Arguments as the base model's ``log_prob``; ``extra (n, E)`` in the order of ``extra_state_``.
        """
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        bex, cols = self._split(extra, st.shape[0])
        shift, log_s, logit = self._parts(cols, st[:, :2])
        st = self._freed_state(st, shift)
        mu, p_miss = self._base_mean(st, bex, new_track)
        p0, p1 = self._p_detect(p_miss, logit)
        z0 = mu + (z - shift - mu) * np.exp(-log_s)[:, None]
        lp0 = self.base.log_prob(z0, st, extra=bex, new_track=new_track)
        miss = np.isnan(z[:, 0])
        return np.where(miss, np.log1p(-p1), lp0 - np.log(p0) + np.log(p1) - 2.0 * log_s)

    def sample_cycle(
        self,
        corners: NDArray,
        prev_z: NDArray | None,
        rng: np.random.Generator,
        extra: NDArray | None = None,
        new_track: NDArray | None = None,
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """``RadarSensor.sample_cycle`` of the corrected law (arguments as the base model's)."""
        corners = np.atleast_2d(np.asarray(corners, dtype=np.float64))
        n = corners.shape[0]
        if n == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
        bex, cols = self._split(extra, n)
        prev = None if prev_z is None else np.asarray(prev_z, dtype=np.float64).reshape(n, 2)
        shift, log_s, logit = self._parts(cols, corners)
        if prev is not None and self.free_previous:
            prev = prev - shift
        st = corners if prev is None else np.column_stack([corners, prev])
        mu, p_miss = self._base_mean(st, bex, new_track)
        p0, p1 = self._p_detect(p_miss, logit)
        z, src = self._base_draw(corners, prev, rng, bex, new_track, np.arange(n))
        det = np.isfinite(z[:, 0])
        u = rng.random(n)
        keep = det & (u < np.minimum(p1 / p0, 1.0))  # thinned where the corrected rate is lower
        want = ~det & (u < np.clip((p1 - p0) / (1.0 - p0), 0.0, 1.0))  # added where it is higher
        z = np.where(keep[:, None], z, np.nan)
        todo = np.flatnonzero(want)
        for _ in range(MAX_REDRAWS if todo.size else 0):  # rejection: base draws until detected
            zr, sr = self._base_draw(corners, prev, rng, bex, new_track, todo)
            ok = np.isfinite(zr[:, 0])
            z[todo[ok]], src[todo[ok]] = zr[ok], sr[ok]
            todo = todo[~ok]
            if todo.size == 0:
                break
        z = mu + (z - mu) * np.exp(log_s)[:, None] + shift
        return z, src

    def _base_draw(
        self,
        corners: NDArray,
        prev: NDArray | None,
        rng: np.random.Generator,
        bex: NDArray | None,
        new_track: NDArray | None,
        rows: NDArray,
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Base-model draws ``z (k, 2)``, ``source (k,)`` at ``rows`` (a fresh copy of the arrays)."""
        kw: dict[str, Any] = {}
        if bex is not None:
            kw["extra"] = bex[rows]
        if new_track is not None:
            kw["new_track"] = np.asarray(new_track)[rows]
        z, src = self.base.sample_cycle(corners[rows], None if prev is None else prev[rows], rng, **kw)
        return np.array(z, dtype=np.float64).reshape(-1, 2), np.array(src, dtype=np.int64).reshape(-1)

    def sample(
        self, state: NDArray, rng: np.random.Generator, extra: NDArray | None = None, new_track: NDArray | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Sample for ``(n, 2)`` or ``(n, 4)`` states (corner, previous output) [m]; see :meth:`sample_cycle`."""
        st = np.atleast_2d(np.asarray(state, dtype=np.float64))
        prev = st[:, 2:4] if st.shape[1] >= 4 else None
        return self.sample_cycle(st[:, :2], prev, rng, extra=extra, new_track=new_track)

    # -- file -------------------------------------------------------------------------------------

    def save(self, path: str | os.PathLike[str], card: dict[str, Any] | None = None) -> Path:
        """Save to a pickle-free model file (the base model's file inside, see the module docstring)."""
        with tempfile.TemporaryDirectory() as tmp:
            base_path = self.base.save(Path(tmp) / "base.npz")
            blob = np.frombuffer(Path(base_path).read_bytes(), dtype=np.uint8)
        header = {
            "params": {},
            "card": card or {},
            "extra_state": list(self.extra_state_),
            "free_previous": self.free_previous,
            "terms": [{"part": t.part, "column": t.column, "state": t.state, "fill": t.fill} for t in self.terms],
        }
        arrays: dict[str, NDArray[Any]] = {"base_file": blob}
        for i, t in enumerate(self.terms):
            arrays[f"term{i}_knots"], arrays[f"term{i}_edges"], arrays[f"term{i}_coef"] = t.knots, t.edges, t.coef
        return save_model_file(path, KIND, FORMAT_VERSION, header, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> CorrectedRadar:
        """Load a file written by :meth:`save`: the base model by its own loader, the terms checked here."""
        header, a = load_model_file(path, KIND, (FORMAT_VERSION,), {"base_file": ("u", 1, True)}, HEADER_SCHEMA)
        base = _load_base(path, a["base_file"])
        specs = header.get("terms")
        if not isinstance(specs, list) or not specs:
            raise ModelFileError(f"{path}: field 'terms' must be a non-empty list")
        terms = [_load_term(path, i, s, a) for i, s in enumerate(specs)]
        free = header.get("free_previous")
        if not isinstance(free, bool):
            raise ModelFileError(f"{path}: field 'free_previous' must be true or false")
        model = cls(base, terms, free_previous=free)
        if list(model.extra_state_) != header.get("extra_state"):
            raise ModelFileError(f"{path}: field 'extra_state' does not match the base model's and the terms' columns")
        model.card_ = header.get("card", {})
        return model


def _load_base(path: str | os.PathLike[str], blob: NDArray) -> Any:
    """The base model from the bytes of its file (KDE or Gaussian, by the kind in its own header)."""
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "base.npz"
        p.write_bytes(np.asarray(blob, dtype=np.uint8).tobytes())
        try:
            try:
                return KDERadarModel.load(p)
            except ModelFileError as exc:
                if "field 'kind'" not in str(exc):
                    raise
            return GaussianRadar.load(p)
        except ModelFileError as exc:
            raise ModelFileError(str(exc).replace(str(p), f"{path} (field 'base_file')")) from None


def _load_term(path: str | os.PathLike[str], i: int, spec: Any, a: dict[str, NDArray]) -> Term:
    """Term ``i`` of a file, its values checked (``ModelFileError`` naming the field)."""
    field = f"terms[{i}]"
    if not isinstance(spec, dict) or spec.get("part") not in PARTS or spec.get("state") not in STATE_FEATURES:
        raise ModelFileError(f"{path}: field '{field}' must give a part in {PARTS} and a state in {STATE_FEATURES}")
    if not isinstance(spec.get("column"), str) or not spec["column"]:
        raise ModelFileError(f"{path}: field '{field}.column' must be a column name")
    fill = spec.get("fill")
    if isinstance(fill, bool) or not isinstance(fill, (int, float)) or not np.isfinite(fill):
        raise ModelFileError(f"{path}: field '{field}.fill' must be a finite number")
    arr = {}
    for key in ("knots", "edges", "coef"):
        name = f"term{i}_{key}"
        if name not in a:
            raise ModelFileError(f"{path}: field '{name}' is missing")
        x = np.asarray(a[name])
        if x.dtype.kind != "f" or not np.isfinite(x).all():
            raise ModelFileError(f"{path}: field '{name}' must hold finite floats")
        arr[key] = x.astype(np.float64)
    knots, edges, coef = arr["knots"], arr["edges"], arr["coef"]
    if knots.ndim != 1 or knots.size < 1 or np.any(np.diff(knots) <= 0):
        raise ModelFileError(f"{path}: field 'term{i}_knots' must be increasing, one or more values")
    if edges.ndim != 1 or np.any(np.diff(edges) <= 0) or (edges.size > 0) != bool(spec["state"]):
        raise ModelFileError(f"{path}: field 'term{i}_edges' must be increasing, empty exactly for a main effect")
    if coef.shape != (edges.size + 1, knots.size):
        raise ModelFileError(
            f"{path}: field 'term{i}_coef' has shape {coef.shape}, expected {(edges.size + 1, knots.size)}"
        )
    if np.abs(coef).max() > _LIMITS[spec["part"]]:
        raise ModelFileError(f"{path}: field 'term{i}_coef' exceeds {_LIMITS[spec['part']]} in absolute value")
    return Term(spec["part"], spec["column"], knots, spec["state"], edges, coef, float(fill))


def load_radar_file(path: str | os.PathLike[str]) -> tuple[str, Any]:
    """``(kind, model)`` of any radar model file: ``"kde"``, ``"gaussian"`` or ``"corrected"``, by its header."""
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel

    for kind, loader in (("kde", KDERadarModel.load), ("corrected", CorrectedRadar.load)):
        try:
            return kind, loader(path)
        except ModelFileError as exc:
            if "field 'kind'" not in str(exc):
                raise
    return "gaussian", GaussianRadar.load(path)
