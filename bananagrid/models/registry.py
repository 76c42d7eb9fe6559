"""The registry of model kinds: the scene name of each model class, and where its recording
extras live. Scene parsing, the runner, recordings, ``bench`` and ``docs/scenes.md`` derive
from it; adding a model is its model module, its kernel module and one line here."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from ..protocol import DensityModel, SceneSchema
from .bearing import BearingFix
from .butterly import Butterly
from .cat import CAT
from .polar import PolarBanana
from .presence import GaussianMixture, UniformPresence

__all__ = ["ModelKind", "Registry", "MODEL_KINDS", "DOMAINS"]

#: Where a kind's model is computed in a scene: ``"grid"``, a planar density of a ``[layers]``
#: table on the scene's ``[grid]`` (also on polar lattices); ``"array"``, a presence law of the
#: ``[presence]`` table on the angular cells of the scene's ``[array]`` (conditioned on its
#: ``[room]``).
DOMAINS = ("grid", "array")


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
    recording : str or None
        Dotted name of the module that logs the kind's extras beside each layer (its geometry,
        comparisons); ``None`` for none. It provides ``log_layer_extras(rec, entity, model,
        raster, *, compute)`` and ``layer_views(entity, model) -> (extra image names, extra
        views)`` (see :mod:`bananagrid.recording.layers`).
    domain : str
        One of :data:`DOMAINS`: where scenes compute the kind (a ``"grid"`` kind's class is a
        :class:`~bananagrid.protocol.DensityModel`, an ``"array"`` kind's a
        :class:`~bananagrid.protocol.PresenceModel`).
    """

    name: str
    cls: type
    recording: str | None = None
    domain: str = "grid"

    def __post_init__(self):
        if self.domain not in DOMAINS:
            raise ValueError(f"model kind {self.name!r}: domain {self.domain!r} not in {DOMAINS}")
        if getattr(self.cls, "kind", None) != self.name:
            raise ValueError(f"model kind {self.name!r}: {self.cls.__name__}.kind is {getattr(self.cls, 'kind', None)!r}")
        if not isinstance(getattr(self.cls, "scene", None), SceneSchema):
            raise ValueError(f"model kind {self.name!r}: {self.cls.__name__}.scene is not a SceneSchema")

    @property
    def scene(self) -> SceneSchema:
        return self.cls.scene

    def build(self, params: Mapping) -> DensityModel:
        """The model from scene parameters in SI units."""
        return self.cls.scene.build(params)


class Registry(Mapping):
    """An immutable mapping of scene names to :class:`ModelKind` (in registration order).

    :meth:`with_kinds` gives a new registry with more kinds, e.g. a model of your own for
    :func:`bananagrid.scenes.parse_scene`.
    """

    def __init__(self, kinds=()):
        self._kinds = {}
        for kind in kinds:
            if kind.name in self._kinds:
                raise ValueError(f"model kind {kind.name!r} registered twice")
            self._kinds[kind.name] = kind

    def __getitem__(self, name: str) -> ModelKind:
        return self._kinds[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._kinds)

    def __len__(self) -> int:
        return len(self._kinds)

    def __repr__(self) -> str:
        return f"Registry({', '.join(self._kinds)})"

    def __hash__(self) -> int:  # immutable: usable as a default value and a cache key
        return hash(tuple(self._kinds.values()))

    def with_kinds(self, *kinds: ModelKind) -> "Registry":
        """This registry with ``kinds`` added after its own."""
        return Registry([*self._kinds.values(), *kinds])

    def on(self, domain: str) -> "Registry":
        """The kinds computed on ``domain`` (one of :data:`DOMAINS`), in registration order."""
        return Registry([kind for kind in self._kinds.values() if kind.domain == domain])


#: The model kinds of scene files.
MODEL_KINDS = Registry([
    ModelKind("cat", CAT),
    ModelKind("polar", PolarBanana),
    ModelKind("bearing_fix", BearingFix, recording="bananagrid.recording.bearing"),
    ModelKind("butterly", Butterly, recording="bananagrid.recording.butterly"),
    ModelKind("mixture", GaussianMixture, domain="array"),
    ModelKind("uniform", UniformPresence, domain="array"),
])
