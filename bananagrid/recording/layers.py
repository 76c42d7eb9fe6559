"""A layer's recording extras, found through the model registry: each kind may name a module
(:attr:`bananagrid.models.registry.ModelKind.recording`) that logs what a reviewer needs beside
the density (a fix's geometry, a start's rings) and adds views to the blueprint.

Such a module provides

* ``log_layer_extras(rec, entity, model, raster, *, compute)``: log under ``entity`` (the
  layer's entity); ``compute(model)`` rasterises another model on the layer's grid as the layer
  was rasterised (for difference maps);
* ``layer_views(entity, model) -> (extra_images, extra_views)``: image names under ``entity``
  shown as more tabs of the layer, and further blueprint views.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from types import ModuleType

import rerun as rr

from ..models.registry import ModelKind
from ..protocol import DensityModel
from ..results import Raster

__all__ = ["extras_module", "log_layer_extras", "layer_views"]


def extras_module(kind: ModelKind) -> ModuleType | None:
    """The module that records ``kind``'s extras, or None."""
    return None if kind.recording is None else importlib.import_module(kind.recording)


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
