"""A scene's ``[plan]`` in its run: the layer's cell probabilities at the plan's time, the optimal
allocation of the effort, the rectangles and bands, recorded, summarised and written.

The map is the layer's cell probabilities on the scene's grid, *not* normalised whatever
``output.normalise`` says: the plan's POS is of the whole target distribution (what the grid
misses counts as not found), the same number as ``bg.allocate(bg.rasterise(model, grid,
quantity="probability"), effort, law)``. A scene with ``[[evidence]]`` plans on the layer's
posterior at the plan's time instead (``bg.allocate(bg.posterior(model, grid, evidence), ...)``):
where the target is given that nothing was found so far, its POS conditional on that.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..engine.rasterise import rasterise
from ..geo.files import writing
from ..planning.allocation import Allocation, allocate
from ..planning.plan_files import plan_collection
from ..planning.rectangles import SearchPlan, search_rectangles
from ..planning.regions import RegionPlan, search_regions
from ..recording.plan import log_plan, plan_extent, plan_values
from ..recording.timeline import set_times
from ..results import Raster
from .load import Scene

__all__ = ["ScenePlan", "plan_scene", "plan_map", "record_plan", "plan_label", "plan_paths", "write_plan_geojson",
           "PLAN_GEOJSON_SUFFIX"]

#: The plan's GeoJSON after the scene's name.
PLAN_GEOJSON_SUFFIX = "-plan.geojson"


@dataclass(frozen=True)
class ScenePlan:
    """A scene's plan, computed.

    Attributes
    ----------
    cells : Raster
        The map searched: the layer's cell probabilities at the plan's time (not normalised).
    allocation : Allocation
    rectangles : SearchPlan or None
    bands : RegionPlan or None
    values : dict
        The plan's numbers (:func:`bananagrid.recording.plan.plan_values`).
    seconds : float
        Wall-clock seconds of the map and the plan.
    """

    cells: Raster
    allocation: Allocation
    rectangles: SearchPlan | None
    bands: RegionPlan | None
    values: dict
    seconds: float

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """Where the plan's view opens (m)."""
        return plan_extent(self.allocation, self.rectangles, self.bands)


def plan_label(scene: Scene) -> str:
    """The progress line's label of the plan step."""
    spec = scene.plan
    return f"plan {spec.layer} t={spec.t:g} s ({spec.effort / 1e6:g} km^2)"


def plan_scene(scene: Scene, *, threads: int | None = None, posterior: Raster | None = None) -> ScenePlan:
    """Compute ``scene``'s plan (its ``[plan]``: :class:`~bananagrid.scenes.load.PlanSpec`);
    on ``posterior`` where given (a scene with evidence: the plan's layer's posterior at its
    time, ``bg.posterior``'s cell probabilities given that nothing was found), else on
    :func:`plan_map`."""
    spec = scene.plan
    start = time.perf_counter()
    cells = plan_map(scene, threads=threads) if posterior is None else posterior
    allocation = allocate(cells, spec.effort, law=spec.law)
    rectangles = search_rectangles(allocation, spec.rectangles, spec.sweep_width) if spec.rectangles else None
    bands = search_regions(allocation, spec.bands, spec.sweep_width) if spec.bands else None
    values = plan_values(allocation, rectangles, bands, layer=spec.layer, t=spec.t)
    return ScenePlan(cells=cells, allocation=allocation, rectangles=rectangles, bands=bands, values=values,
                     seconds=time.perf_counter() - start)


def plan_map(scene: Scene, *, threads: int | None = None) -> Raster:
    """The map a scene's plan searches: its layer's cell probabilities at its time on the
    scene's grid, at the scene's dtype, not normalised (the whole target's POS), with the
    scene's geographic frame."""
    spec = scene.plan
    layer = next(layer for layer in scene.layers if layer.name == spec.layer)
    cells = rasterise(layer.model(spec.t), scene.grid, quantity="probability", dtype=np.dtype(scene.dtype),
                      threads=threads, max_seconds=math.inf, min_mass=0.0)  # the run warns about its layers
    if scene.geo is not None:  # GeoJSON of the areas in longitude and latitude
        cells = replace(cells, frame=scene.geo, provenance={**cells.provenance, "geo": scene.geo.identity()})
    return cells


def record_plan(rec, scene: Scene, plan: ScenePlan) -> None:
    """Log ``plan`` at its time on the elapsed and (geographic scenes) UTC timelines
    (:func:`bananagrid.recording.plan.log_plan`)."""
    set_times(rec, scene.plan.t, scene.geo)  # both timelines: a geographic scene opens on utc
    log_plan(rec, plan.cells, plan.allocation, plan.rectangles, plan.bands, layer=scene.plan.layer, t=scene.plan.t)


def plan_paths(scene: Scene, out_dir: str | os.PathLike, *, geojson: bool = False) -> list[Path]:
    """The plan's files a run writes: ``NAME-plan.geojson`` when GeoJSON is asked for and the
    plan has areas (rectangles or bands)."""
    if not geojson or scene.plan is None or not scene.plan.areas:
        return []
    return [Path(out_dir) / f"{scene.name}{PLAN_GEOJSON_SUFFIX}"]


def write_plan_geojson(path: str | os.PathLike, scene: Scene, plan: ScenePlan, *, stage=None) -> Path:
    """The plan's areas and tracks (rectangles and bands, each feature's ``plan`` saying which)
    as one RFC 7946 FeatureCollection in WGS84 longitude and latitude; ``stage``: the run's
    :meth:`~bananagrid.atomic.OutputSet.stage` (all or nothing with its other files)."""
    areas = []
    for name, flown in (("rectangles", plan.rectangles), ("bands", plan.bands)):
        if flown is not None:
            areas += [(polygon, tracks, {"plan": name, **properties})
                      for polygon, tracks, properties in flown.geojson_areas()]
    summary = {key: value for key, value in plan.values.items() if not isinstance(value, list)}
    collection = plan_collection(areas, {"title": scene.title, **summary}, scene.geo)
    with writing(path, "GeoJSON file", stage=stage) as partial:
        partial.write_text(json.dumps(collection, allow_nan=False) + "\n", encoding="utf-8")
    return Path(path)
