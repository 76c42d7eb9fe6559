"""A layer's recording extras: a model kind may have a module that logs what a reviewer needs
beside the density (a fix's geometry, a start's rings) and adds views to the blueprint. This
package's own are imported here (:data:`EXTRAS`, keyed by the model class each names as
``MODEL``), so that the layers contract sees every such import; a kind of another package gives
its module as :attr:`bananagrid.models.registry.ModelKind.recording`.

Such a module provides

* ``log_layer_extras(rec, entity, model, raster, *, compute)``: log under ``entity`` (the
  layer's entity); ``compute(model)`` rasterises another model on the layer's grid as the layer
  was rasterised (for difference maps);
* ``layer_views(entity, model) -> (extra_images, extra_views)``: image names under ``entity``
  shown as more tabs of the layer, and further blueprint views;

and may provide

* ``layer_extent(model) -> (x0, x1, y0, y1)``: what its geometry needs the map to hold beyond
  the probability regions (a fix's R95 circle): the map's frame grows to hold it;
* a ``board`` keyword of ``log_layer_extras``: the map's
  :class:`~bananagrid.recording.labels.LabelBoard`, on which it places its labels, so that
  they keep clear of the contours' and the legend's (:func:`log_layer` passes it);

and, for a kind whose schema adds ``[output]`` switches
(:attr:`bananagrid.protocol.SceneSchema.options`),

* ``log_scene_extras(rec, options)``: log what the switches set in ``options`` ask for, once per
  scene;
* ``scene_texts(options) -> list of str``: the text entities it logs (the blueprint shows them).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable
from types import ModuleType

import rerun as rr

from ..models.registry import ModelKind
from ..protocol import DensityModel
from ..contours import DEFAULT_MASS_LEVELS
from ..results import Raster
from . import bearing, butterly
from .blueprint import ColourRange, union_extent
from .labels import PANEL_POINTS, LabelBoard
from .legend import log_shared_colour_bar
from .raster import LOG10_COLORMAP, LoggedRaster, log_raster_layer

__all__ = ["extras_module", "log_layer", "log_shared_colours", "SHARED_LEGEND", "log_layer_extras", "layer_views", "log_scene_extras", "scene_texts", "EXTRAS"]

#: This package's extras modules by the model class each records.
EXTRAS = {module.MODEL: module for module in (bearing, butterly)}


def extras_module(kind: ModelKind) -> ModuleType | None:
    """The module that records ``kind``'s extras (its own, or this package's for the class), or None."""
    return kind.recording if kind.recording is not None else EXTRAS.get(kind.cls)


def log_layer(rec: rr.RecordingStream, entity: str, kind: ModelKind, model: DensityModel, raster: Raster, *,
              compute: Callable[[DensityModel], Raster], levels: Iterable[float] = (),
              mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS, colormap: str = "viridis",
              panel: tuple[float, float] = PANEL_POINTS) -> LoggedRaster:
    """One layer of a scene: the raster (:func:`~bananagrid.recording.raster.log_raster_layer`)
    framed to hold the kind's geometry too (its module's ``layer_extent``), then the kind's
    extras, whose labels go on the same map's label board as the contours' and the legend's
    (placed for a map ``panel`` of (width, height) points,
    :func:`~bananagrid.recording.blueprint.map_panel_points`)."""
    module = extras_module(kind)
    extent = getattr(module, "layer_extent", None)
    logged = log_raster_layer(rec, entity, raster, levels=levels, mass_levels=mass_levels, colormap=colormap,
                              include=None if extent is None else extent(model), panel=panel)
    log_layer_extras(rec, entity, kind, model, raster, compute=compute, board=logged.board)
    return logged


#: Under a layer's entity: the colour bar its maps show when every map shares one range.
SHARED_LEGEND = "shared_legend"


def log_shared_colours(rec: rr.RecordingStream, logged: dict[str, list[LoggedRaster]],
                       panel: tuple[float, float] = PANEL_POINTS) -> ColourRange | None:
    """With two layers or more, one colour range for every map (:meth:`ColourRange.shared` of
    each map's, over every layer and time, since a blueprint's range holds at every time) and,
    under each layer, a colour bar of it (static, :data:`SHARED_LEGEND`, east of the layer's
    frames' union: where its views open) that its log10 view shows instead of its own; the
    range, for :func:`~bananagrid.recording.blueprint.default_blueprint` (None for one layer)."""
    if len(logged) < 2:
        return None
    shared = ColourRange.shared([(m.floor, m.top, m.peak) for maps in logged.values() for m in maps])
    for entity, maps in logged.items():
        log_shared_colour_bar(rec, f"{entity}/{SHARED_LEGEND}", union_extent([m.frame for m in maps]), *shared.log10,
                              LOG10_COLORMAP, panel)
    return shared


def log_layer_extras(rec: rr.RecordingStream, entity: str, kind: ModelKind, model: DensityModel, raster: Raster, *,
                     compute: Callable[[DensityModel], Raster], board: LabelBoard | None = None) -> None:
    """Log ``kind``'s extras for one layer (nothing for a kind without a recording module); a
    module that takes a ``board`` places its labels on ``board`` (the layer's map's)."""
    module = extras_module(kind)
    if module is not None:
        takes_board = board is not None and "board" in inspect.signature(module.log_layer_extras).parameters
        more = {"board": board} if takes_board else {}
        module.log_layer_extras(rec, entity, model, raster, compute=compute, **more)


def layer_views(entity: str, kind: ModelKind, model: DensityModel) -> tuple[list[str], list]:
    """``kind``'s extra image tabs (as entity paths) and blueprint views for one layer."""
    module = extras_module(kind)
    if module is None:
        return [], []
    images, views = module.layer_views(entity, model)
    return [f"{entity}/{image}" for image in images], list(views)


def _switched(kinds) -> list[ModuleType]:
    """The extras modules of ``kinds`` that act on scene switches."""
    modules = [extras_module(kind) for kind in kinds if kind.scene.options]
    return [module for module in modules if module is not None]


def log_scene_extras(rec: rr.RecordingStream, kinds, options) -> None:
    """Log what the ``[output]`` switches ``options`` of ``kinds`` (ModelKinds) ask for."""
    for module in _switched(kinds):
        module.log_scene_extras(rec, options)


def scene_texts(kinds, options) -> list[str]:
    """The text entities :func:`log_scene_extras` logs, for the blueprint."""
    return [text for module in _switched(kinds) for text in module.scene_texts(options)]
