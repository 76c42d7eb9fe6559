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

and, for a kind whose schema adds ``[output]`` switches
(:attr:`bananagrid.protocol.SceneSchema.options`),

* ``log_scene_extras(rec, options)``: log what the switches set in ``options`` ask for, once per
  scene;
* ``scene_texts(options) -> list of str``: the text entities it logs (the blueprint shows them).
"""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType

import rerun as rr

from ..models.registry import ModelKind
from ..protocol import DensityModel
from ..results import Raster
from . import bearing, butterly

__all__ = ["extras_module", "log_layer_extras", "layer_views", "log_scene_extras", "scene_texts", "EXTRAS"]

#: This package's extras modules by the model class each records.
EXTRAS = {module.MODEL: module for module in (bearing, butterly)}


def extras_module(kind: ModelKind) -> ModuleType | None:
    """The module that records ``kind``'s extras (its own, or this package's for the class), or None."""
    return kind.recording if kind.recording is not None else EXTRAS.get(kind.cls)


def log_layer_extras(rec: rr.RecordingStream, entity: str, kind: ModelKind, model: DensityModel, raster: Raster, *,
                     compute: Callable[[DensityModel], Raster]) -> None:
    """Log ``kind``'s extras for one layer (nothing for a kind without a recording module)."""
    module = extras_module(kind)
    if module is not None:
        module.log_layer_extras(rec, entity, model, raster, compute=compute)


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
