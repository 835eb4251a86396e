"""One contract for every fitted sensor model: :class:`SensorModel`, a scikit-learn estimator with a file.

A fitted sensor model (``KDERadarModel``, ``GaussianRadar``, ``LidarLWLR``) is a subclass that declares:

* ``KIND``: the ``kind`` string of its model files; ``FORMAT_VERSION``: the one format it writes;
* ``_parameter_constraints``: one declarative table of its hyperparameters, checked by ``fit``
  (:meth:`SensorModel._check_params`) and by ``load`` (the file's ``params``) alike;
* ``_HEADER_SCHEMA``: the declared fitted fields of its files' header besides ``kind``, ``format_version``,
  ``params`` and ``card`` (:func:`sensor_envs.modelio.check_header`: an undeclared or malformed field is a
  ``ModelFileError``), checked by ``load`` before the upgrades;
* ``CAPABILITIES``: what callers may ask of it (e.g. ``"new_track"``: ``sample_cycle`` takes the new-track
  flags; ``"extra_state"``: queries take ``extra``), read by :func:`has_capability` instead of probing
  signatures or attributes;
* ``_UPGRADES``: ``{v: step}``, each step turning the ``(header, arrays)`` of a format-``v`` file into those of
  format ``v + 1`` in place. :meth:`SensorModel.load` reads any supported version through these steps and
  then ONE reader of the current format (``_from_file``); :meth:`SensorModel.save` writes the current
  format only (``_to_file``), so ``load`` + ``save`` upgrades a file (``sensor-envs upgrade-model``).

Shared semantics: ``random_state`` (where a fit draws at random) is a seed (default 0), a ``numpy`` Generator or
``None`` (fresh entropy), read once per ``fit`` through ``np.random.default_rng``; ``verbose`` shows progress bars;
neither is saved in the file. The model card is the model's: ``card_`` (a JSON-able dict) is filled by
``fit``, restored by ``load``, extended by callers (:meth:`SensorModel.update_card`) and written by ``save``.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from numpy.typing import NDArray
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_is_fitted

from sensor_envs.modelio import (
    Constraint,
    ModelFileError,
    check_header,
    check_model_arrays,
    params_from_header,
    read_header_and_arrays,
    save_model_file,
    validate_params,
)

__all__ = [
    "SensorModel",
    "has_capability",
    "extra_state_names",
    "CAPABILITIES",
    "upgrade_model_file",
    "set_param_defaults",
    "NOT_SAVED",
]

CAPABILITIES = ("new_track", "extra_state", "prev_output", "log_prob", "clutter", "output_frame", "bin_probabilities")
"""Capabilities a sensor model may declare: ``new_track`` (``sample_cycle``/``log_prob`` take the per-target
new-track flags), ``extra_state`` (queries take ``extra`` values of ``extra_state_``), ``prev_output`` (the state
holds the previous output ``z_{t-1}``), ``log_prob`` (scores outcomes), ``clutter`` (draws clutter),
``output_frame`` (``to_output_frame``: offsets on the axes its kernels act on), ``bin_probabilities`` (exact
probabilities of output bins, for chi-square checks of its samples)."""
NOT_SAVED = ("random_state", "verbose")
"""Hyperparameters of a run, never written to a model file (a loaded model gets their defaults)."""

Header = dict[str, Any]
Arrays = dict[str, NDArray[Any]]
Upgrade = Callable[[Path, Header, Arrays], None]
S = TypeVar("S", bound="SensorModel")


def has_capability(model: object, capability: str) -> bool:
    """Whether ``model`` declares ``capability`` (its class's ``CAPABILITIES``; undeclared: none).

    Raises:
        ValueError: for a name outside :data:`CAPABILITIES` (a typo would otherwise read as "no").
    """
    if capability not in CAPABILITIES:
        raise ValueError(f"capability: expected one of {CAPABILITIES}, got {capability!r}")
    return capability in getattr(type(model), "CAPABILITIES", frozenset())


def extra_state_names(model: object) -> tuple[str, ...]:
    """The extra state variables of a fitted ``model`` (``extra_state_``) if it declares ``"extra_state"``, else ``()``.

    What callers pass as ``extra`` columns; read from the declaration, not by probing for the attribute.
    """
    return tuple(model.extra_state_) if has_capability(model, "extra_state") else ()  # type: ignore[attr-defined]


class SensorModel(BaseEstimator):
    """Base of the fitted sensor models: parameter table, fitted check, card, versioned file with upgrades.

    Subclasses set the class attributes below and implement ``fit``, ``_to_file`` and ``_from_file``.

    Attributes:
        card_: the model card entries (JSON-able dict) stored in the file's header ``card``: what the model
            was fitted on and how (set by ``fit`` and :meth:`update_card`, restored by :meth:`load`).

    Examples:
        >>> from sensor_envs import GaussianRadar, KDERadarModel, LidarLWLR, SensorModel
        >>> all(issubclass(c, SensorModel) for c in (GaussianRadar, KDERadarModel, LidarLWLR))
        True
        >>> KDERadarModel.KIND, KDERadarModel.FORMAT_VERSION, "clutter" in KDERadarModel.CAPABILITIES
        ('radar_kde', 8, True)
    """

    KIND: ClassVar[str] = ""
    """``kind`` of the model files."""
    FORMAT_VERSION: ClassVar[int] = 1
    """The format :meth:`save` writes (older ones load through ``_UPGRADES``)."""
    CAPABILITIES: ClassVar[frozenset[str]] = frozenset()
    """What callers may ask of the model (names from :data:`CAPABILITIES`)."""
    _parameter_constraints: ClassVar[dict[str, list[Constraint]]] = {}
    """One declarative check of every hyperparameter, used by ``fit`` and :meth:`load`."""
    _FITTED: ClassVar[str] = ""
    """An attribute every fitted or loaded model has (the fitted check)."""
    _SCHEMA: ClassVar[dict[str, tuple[str, int | None, bool]]] = {}
    """Arrays every supported version holds: ``name -> (dtype kinds, ndim, finite)``, checked before upgrades."""
    _HEADER_SCHEMA: ClassVar[dict[str, list[Constraint]] | None] = None
    """Header fields any supported version may hold besides ``kind``, ``format_version``, ``params``, ``card``:
    ``name -> accepted forms`` (:func:`~sensor_envs.modelio.check_header`), checked before upgrades; ``None``:
    not checked."""
    _UPGRADES: ClassVar[dict[int, Upgrade]] = {}
    """``{v: step}``: ``step(path, header, arrays)`` turns format ``v`` into ``v + 1`` in place."""
    _PARAM_DEFAULTS: ClassVar[dict[str, Any]] = {}
    """Hyperparameters a current-format file may lack, read with these values."""
    _hyperparameter_constraints: ClassVar[dict[str, list[Constraint]]] = {}
    """Alias of ``_parameter_constraints`` (its name before the contract)."""
    _file: Path | None = None
    """The file :meth:`load` read the model from (``None``: fitted in memory); files beside it are found from it."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._hyperparameter_constraints = cls._parameter_constraints  # the table's name before the contract

    # ------------------------------------------------------------------------------- parameters
    def _check_params(self) -> None:
        """Check every hyperparameter against the class's table (``InputError`` naming the bad one)."""
        validate_params(self.get_params(), self._parameter_constraints)
        self._check_params_relations(None)

    def _check_params_relations(self, source: str | os.PathLike[str] | None) -> None:
        """Checks the table cannot express (relations between values); raise naming the parameter.

        ``source`` is the model file for values read by :meth:`load` (then raise ``ModelFileError``).
        """

    def _check_fitted(self) -> None:
        """Raise sklearn's ``NotFittedError`` unless the model is fitted or loaded."""
        msg = "This %(name)s is not fitted yet; call fit(log) or %(name)s.load(path) first"
        check_is_fitted(self, self._FITTED, msg=msg)

    @staticmethod
    def _deprecated_progress(progress: bool | None, verbose: Any) -> Any:
        """``verbose``, or the deprecated ``progress`` flag it replaces (with a ``FutureWarning``).

        ``verbose`` is handed on as given (``fit`` checks it is a flag): ``bool(verbose)`` here would turn
        ``nan`` into ``True`` and an array into a ``ValueError`` inside the constructor.
        """
        if progress is None:
            return verbose
        warnings.warn("'progress' is deprecated; use the 'verbose' hyperparameter", FutureWarning, stacklevel=3)
        return bool(progress)

    def baseline(self) -> Any:
        """The simple baseline this model is judged against, fitted with it on the same data, ready to simulate.

        One way for every sensor: the learned lidar returns its
        :class:`~sensor_envs.lidar.gaussian.GaussianLidar` (whose keyword arguments its card keeps, as
        ``gaussian_baseline``), the KDE radar its :class:`~sensor_envs.radar.gaussian.GaussianRadar` (a model file
        of its own, beside the file the KDE was loaded from: :func:`~sensor_envs.radar.gaussian.baseline_file`).
        ``None`` when the model keeps none: a baseline itself, a KDE fitted in memory or without the file beside it,
        a lidar whose card lacks the entry.
        """
        return None

    # ------------------------------------------------------------------------------------ card
    def update_card(self: S, entries: Mapping[str, Any] | None = None, **more: Any) -> S:
        """Add entries to the model card ``card_`` (written by :meth:`save`); returns self."""
        self.card_ = {**getattr(self, "card_", {}), **dict(entries or {}), **more}
        return self

    # ----------------------------------------------------------------------------------- files
    def _to_file(self) -> tuple[Header, Arrays]:
        """The current format's header (without ``kind``, ``format_version``) and arrays.

        A ``card`` entry in the header holds card fields the model keeps as fitted attributes; :meth:`save` adds
        :attr:`card_` to it.
        """
        raise NotImplementedError

    @classmethod
    def _from_file(cls: type[S], path: Path, header: Header, arrays: Arrays) -> S:
        """A model from a current-format file's header and arrays (value checks included)."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike[str], card: Mapping[str, Any] | None = None) -> Path:
        """Write the model to a pickle-free ``.npz`` file in the current format; returns the path written.

        The header's ``card`` is :attr:`card_` (plus ``card``, entries added for this file only). Written to
        a temporary sibling and renamed.

        Raises:
            NotFittedError: when the model is neither fitted nor loaded.
            OutputError: when ``path`` does not end in ``.npz``.
        """
        self._check_fitted()
        header, arrays = self._to_file()
        header["card"] = {**header.get("card", {}), **getattr(self, "card_", {}), **dict(card or {})}
        return save_model_file(path, self.KIND, self.FORMAT_VERSION, header, arrays)

    @classmethod
    def read_current(cls, path: str | os.PathLike[str]) -> tuple[Header, Arrays]:
        """A model file's header and arrays, checked and upgraded to the current format.

        Raises:
            ModelFileError: naming the file and the field (wrong kind, an unsupported version, an undeclared or
                malformed header field, a malformed array).
        """
        header, arrays = read_header_and_arrays(path)  # checks that path is a path (not, e.g., True)
        path = Path(path)
        if header.get("kind") != cls.KIND:
            raise ModelFileError(f"{path}: field 'kind' is {header.get('kind')!r}, expected {cls.KIND!r}")
        supported = (*sorted(cls._UPGRADES), cls.FORMAT_VERSION)
        version = header.get("format_version")
        if isinstance(version, bool) or not isinstance(version, int) or version not in supported:
            raise ModelFileError(
                f"{path}: field 'format_version' is {version!r}; this version of sensor_envs reads {list(supported)}"
            )
        for key in ("params", "card"):
            if key in header and not isinstance(header[key], dict):
                raise ModelFileError(f"{path}: field '__header__' entry {key!r} must be a JSON object")
        if "params" not in header:
            raise ModelFileError(f"{path}: field '__header__' lacks 'params'")
        if cls._HEADER_SCHEMA is not None:
            check_header(path, header, cls._HEADER_SCHEMA)
        check_model_arrays(path, arrays, cls._SCHEMA)
        for v in range(version, cls.FORMAT_VERSION):  # one step per format version
            cls._UPGRADES[v](path, header, arrays)
            header["format_version"] = v + 1
        return header, arrays

    @classmethod
    def load(cls: type[S], path: str | os.PathLike[str]) -> S:
        """Read a model file of any supported format (no pickle; upgraded, then value-checked).

        Raises:
            ModelFileError: naming the file and the field at fault.
        """
        header, arrays = cls.read_current(path)
        model = cls._from_file(Path(path), header, arrays)
        model.card_ = dict(header.get("card", {}))
        model._file = Path(path)
        return model

    @classmethod
    def _params_from(cls, path: Path, header: Header, not_saved: tuple[str, ...] = ()) -> dict[str, Any]:
        """The file's hyperparameters checked against the table (``_PARAM_DEFAULTS`` fill absent ones)."""
        params = params_from_header(
            path, header, cls._parameter_constraints, dict(cls._PARAM_DEFAULTS), (*NOT_SAVED, *not_saved)
        )
        return params

    @classmethod
    def _saved_params(cls, model: SensorModel, skip: tuple[str, ...] = ()) -> dict[str, Any]:
        """``get_params()`` as the header stores them: tuples as lists, run-time ones left out."""
        return {
            k: ([*v] if isinstance(v, tuple) else v)
            for k, v in model.get_params().items()
            if k not in (*NOT_SAVED, *skip)
        }


def set_param_defaults(header: Header, **defaults: Any) -> None:
    """An upgrade step's helper: hyperparameters an older format lacks, read as ``defaults`` (kept if present)."""
    params = header["params"]
    for k, v in defaults.items():
        params.setdefault(k, v)


def upgrade_model_file(
    src: str | os.PathLike[str], out: str | os.PathLike[str], classes: tuple[type[SensorModel], ...]
) -> tuple[SensorModel, int, int]:
    """Read ``src`` (any supported format of any of ``classes``) and write it to ``out`` in the current format.

    Returns:
        ``(model, old version, new version)``.

    Raises:
        ModelFileError: when ``src`` is no model file of ``classes`` (naming the file and the field).
    """
    header, _ = read_header_and_arrays(src)
    kind = header.get("kind")
    match = [c for c in classes if c.KIND == kind]
    if not match:
        raise ModelFileError(f"{src}: field 'kind' is {kind!r}, expected one of {[c.KIND for c in classes]}")
    old = header.get("format_version")
    model = match[0].load(src)
    model.save(out)
    return model, int(old) if isinstance(old, int) else -1, model.FORMAT_VERSION
