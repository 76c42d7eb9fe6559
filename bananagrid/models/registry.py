"""The registry of model kinds: the scene name of each model class. Scene parsing, the runner,
recordings, ``bench`` and ``docs/scenes.md`` derive from it; adding a model is its model module,
its kernel module and one line here, or, for a model in another package, one entry point.

Models from other packages register through the entry point group ``bananagrid.models`` (as
xarray's backends do through ``xarray.backends``), in their distribution's metadata::

    [project.entry-points."bananagrid.models"]
    cv = "mypackage.model:Drift"

The entry point's name is the scene kind; its object is the model class (its ``kind`` equal to
that name) or a :class:`ModelKind`. :func:`installed_kinds` loads them on first use, never at
import, and scenes and the command line use it by default.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from importlib import metadata
from types import MappingProxyType
from typing import Any

from ..protocol import DensityModel, SceneSchema
from ..validate import BananagridError, BananagridWarning
from .bearing import BearingFix
from .butterly import Butterly
from .cat import CAT
from .polar import PolarBanana
from .presence import GaussianMixture, UniformPresence

__all__ = [
    "ModelKind", "Registry", "MODEL_KINDS", "DOMAINS", "ENTRY_POINT_GROUP", "installed_kinds", "kinds_from_entry_points",
]

#: Where a kind's model is computed in a scene: ``"grid"``, a planar density of a ``[layers]``
#: table on the scene's ``[grid]`` (also on polar lattices); ``"array"``, a presence law of the
#: ``[presence]`` table on the angular cells of the scene's ``[array]`` (conditioned on its
#: ``[room]``).
DOMAINS = ("grid", "array")

#: The entry point group through which other packages register model kinds.
ENTRY_POINT_GROUP = "bananagrid.models"


@dataclass(frozen=True)
class ModelKind:
    """One model kind of the scene files.

    Attributes
    ----------
    name : str
        The ``model`` value of a scene layer.
    cls : type
        The model class (a :class:`~bananagrid.protocol.DensityModel`); its ``scene``
        attribute says which keys a layer takes.
    recording : object, optional
        For a model of another package: the object (a module) that logs the kind's extras beside
        each layer, with ``log_layer_extras(rec, entity, model, raster, *, compute)`` and
        ``layer_views(entity, model) -> (extra image names, extra views)`` (see
        :mod:`bananagrid.recording.layers`, which holds the package's own). None for none.
    domain : str
        One of :data:`DOMAINS`: where scenes compute the kind (a ``"grid"`` kind's class is a
        :class:`~bananagrid.protocol.DensityModel`, an ``"array"`` kind's a
        :class:`~bananagrid.protocol.PresenceModel`).
    """

    name: str
    cls: type
    recording: Any = None
    domain: str = "grid"

    def __post_init__(self):
        if not isinstance(self.cls, type):
            raise ValueError(f"model kind {self.name!r}: {self.cls!r} is not a class")
        if self.domain not in DOMAINS:
            raise ValueError(f"model kind {self.name!r}: domain {self.domain!r} not in {DOMAINS}")
        if getattr(self.cls, "kind", None) != self.name:
            raise ValueError(f"model kind {self.name!r}: {self.cls.__name__}.kind is {getattr(self.cls, 'kind', None)!r}")
        if not isinstance(getattr(self.cls, "scene", None), SceneSchema):
            raise ValueError(f"model kind {self.name!r}: {self.cls.__name__}.scene is not a SceneSchema")
        if isinstance(self.recording, str):
            raise ValueError(f"model kind {self.name!r}: recording must be the module itself, not its name")

    @property
    def scene(self) -> SceneSchema:
        return self.cls.scene

    def build(self, params: Mapping) -> DensityModel:
        """The model from scene parameters in SI units."""
        return self.cls.scene.build(params)


class Registry(Mapping):
    """An immutable mapping of scene names to :class:`ModelKind` (in registration order).

    :meth:`with_kinds` gives a new registry with more kinds, e.g. a model of your own for
    :func:`bananagrid.scenes.parse_scene`. ``broken`` maps the names of kinds whose
    registration failed (an entry point that does not load) to the one-line reason, which a
    scene naming one of them reports.
    """

    def __init__(self, kinds=(), broken: Mapping[str, str] | None = None):
        self._kinds = {}
        for kind in kinds:
            if kind.name in self._kinds:
                raise ValueError(f"model kind {kind.name!r} registered twice")
            self._kinds[kind.name] = kind
        self.broken = MappingProxyType(dict(broken or {}))

    def __getitem__(self, name: str) -> ModelKind:
        return self._kinds[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._kinds)

    def __len__(self) -> int:
        return len(self._kinds)

    def __repr__(self) -> str:
        return f"Registry({', '.join(self._kinds)})"

    def __hash__(self) -> int:  # immutable: usable as a default value and a cache key
        return hash((tuple(self._kinds.values()), tuple(self.broken.items())))

    def __eq__(self, other) -> bool:
        if not isinstance(other, Registry):
            return NotImplemented
        return list(self._kinds.values()) == list(other._kinds.values()) and self.broken == other.broken

    def with_kinds(self, *kinds: ModelKind, broken: Mapping[str, str] | None = None) -> "Registry":
        """This registry with ``kinds`` added after its own (and ``broken`` to its broken ones)."""
        return Registry([*self._kinds.values(), *kinds], {**self.broken, **(broken or {})})

    def on(self, domain: str) -> "Registry":
        """The kinds computed on ``domain`` (one of :data:`DOMAINS`), in registration order."""
        return Registry([kind for kind in self._kinds.values() if kind.domain == domain], self.broken)


#: The model kinds of this package.
MODEL_KINDS = Registry([
    ModelKind("cat", CAT),
    ModelKind("polar", PolarBanana),
    ModelKind("bearing_fix", BearingFix),
    ModelKind("butterly", Butterly),
    ModelKind("mixture", GaussianMixture, domain="array"),
    ModelKind("uniform", UniformPresence, domain="array"),
])


def _origin(entry: metadata.EntryPoint) -> str:
    """``entry point NAME = VALUE (group, distribution)`` for messages."""
    dist = getattr(entry, "dist", None)
    source = f", distribution {dist.name} {dist.version}" if dist is not None else ""
    return f"entry point {entry.name} = {entry.value!r} ({ENTRY_POINT_GROUP}{source})"


def _kind_of(entry: metadata.EntryPoint) -> ModelKind:
    """The :class:`ModelKind` an entry point names, or raise :class:`BananagridError` with one
    line naming the entry point and what is wrong."""
    try:
        target = entry.load()
    except Exception as exc:  # noqa: BLE001 - any failure of another package's import is its own
        reason = str(exc).splitlines()[0] if str(exc) else ""
        raise BananagridError(f"{_origin(entry)}: cannot be loaded: {type(exc).__name__}: {reason}".rstrip(": "))
    if isinstance(target, ModelKind):
        kind = target
    elif isinstance(target, type):
        if not isinstance(getattr(target, "kind", None), str):
            raise BananagridError(f"{_origin(entry)}: not a model class: {target.__name__} has no kind (its scene name)")
        try:
            kind = ModelKind(getattr(target, "kind", None), target)
        except ValueError as exc:
            raise BananagridError(f"{_origin(entry)}: not a model class: {exc}") from None
    else:
        raise BananagridError(f"{_origin(entry)}: not a model class or ModelKind but {type(target).__name__} {target!r}")
    if kind.name != entry.name:
        raise BananagridError(f"{_origin(entry)}: its model's kind is {kind.name!r}; the entry point must be named so")
    missing = [name for name in ("bind", "sample", "pdf", "parameters") if not callable(getattr(kind.cls, name, None))]
    if missing:
        raise BananagridError(f"{_origin(entry)}: not a model class: {kind.cls.__name__} lacks {', '.join(missing)}")
    return kind


def kinds_from_entry_points(base: Registry, entries: Iterable[metadata.EntryPoint]) -> Registry:
    """``base`` with the kinds that ``entries`` register. An entry point that cannot be
    loaded, is not a model, or names a kind already registered is left out with a
    :class:`~bananagrid.BananagridWarning` of one line naming it; a scene that asks for its kind
    gets the same line as its error (:attr:`Registry.broken`)."""
    kinds: dict[str, ModelKind] = {}
    origins: dict[str, str] = {}
    broken: dict[str, str] = {}
    for entry in entries:
        if entry.name in base or entry.name in kinds:
            first = "this package" if entry.name in base else origins[entry.name]
            message = f"{_origin(entry)}: model kind {entry.name!r} is already registered by {first}; left out"
            warnings.warn(message, BananagridWarning, stacklevel=2)
            continue
        try:
            kinds[entry.name] = _kind_of(entry)
            origins[entry.name] = _origin(entry)
        except BananagridError as exc:
            warnings.warn(str(exc), BananagridWarning, stacklevel=2)
            broken[entry.name] = str(exc)
    return base.with_kinds(*kinds.values(), broken=broken)


@functools.cache
def installed_kinds() -> Registry:
    """:data:`MODEL_KINDS` and the kinds installed packages register through the entry point
    group ``bananagrid.models``, loaded once, on first use (see :func:`kinds_from_entry_points`)."""
    return kinds_from_entry_points(MODEL_KINDS, metadata.entry_points(group=ENTRY_POINT_GROUP))
