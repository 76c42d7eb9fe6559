"""A scene's ``[plan]`` in its run: the layer's cell probabilities at the plan's time, the optimal
allocation of the effort, the rectangles and bands, recorded, summarised and written.

The map is the layer's cell probabilities on the scene's grid, *not* normalised whatever
``output.normalise`` says: the plan's POS is of the whole target distribution (what the grid
misses counts as not found), the same number as ``bg.allocate(bg.rasterise(model, grid,
quantity="probability"), effort, law)``. A scene with ``[[evidence]]`` plans on the layer's
posterior at the plan's time instead (``bg.allocate(bg.posterior(model, grid, evidence), ...)``):
where the target is given that nothing was found so far, its POS conditional on that.

With several periods (``[plan]`` ``t`` and ``effort`` as lists) the plan is
``bg.plan_periods(model, grid, times, efforts, law)`` on the layer's model (a CAT or a Butterly):
each period's allocation on its map at its time of the target the other periods miss, the total
POS and each period's first detections; each period's rectangles and bands come from its own
allocation. The run says each sweep's POS on its progress line (:data:`sweep_notice`).
"""

from __future__ import annotations

import contextvars
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
from ..planning.periods import PeriodPlan, plan_periods
from ..planning.plan_files import plan_collection
from ..planning.rectangles import SearchPlan, search_rectangles
from ..planning.regions import RegionPlan, search_regions
from ..recording.plan import log_plan, log_plan_periods, periods_values, plan_extent, plan_values
from ..recording.timeline import set_times
from ..results import Raster
from .load import Scene

__all__ = ["ScenePlan", "plan_scene", "plan_map", "record_plan", "plan_label", "plan_paths", "write_plan_geojson",
           "PLAN_GEOJSON_SUFFIX", "sweep_notice", "plan_coverage"]

#: Where a plan over several periods says each sweep's POS: a callable taking one short text
#: (the CLI's progress line sets it), or None to say nothing.
sweep_notice: contextvars.ContextVar = contextvars.ContextVar("sweep_notice", default=None)

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
        The plan's numbers (:func:`bananagrid.recording.plan.plan_values`; with several periods
        :func:`bananagrid.recording.plan.periods_values`, the totals and each period's).
    seconds : float
        Wall-clock seconds of the map and the plan.
    periods : tuple of ScenePlan
        Several periods: each period's map (of the target the other periods miss), allocation,
        areas and numbers; the fields above are then the first period's. Empty for one period.
    period_plan : PeriodPlan or None
        Several periods: :func:`bananagrid.plan_periods`'s plan.
    """

    cells: Raster
    allocation: Allocation
    rectangles: SearchPlan | None
    bands: RegionPlan | None
    values: dict
    seconds: float
    periods: tuple = ()
    period_plan: PeriodPlan | None = None

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """Where the plan's view opens (m): every period's cells with effort and areas."""
        boxes = [plan_extent(p.allocation, p.rectangles, p.bands) for p in self.periods or (self,)]
        return (min(b[0] for b in boxes), max(b[1] for b in boxes), min(b[2] for b in boxes), max(b[3] for b in boxes))


def plan_label(scene: Scene) -> str:
    """The progress line's label of the plan step."""
    spec = scene.plan
    if spec.several:
        return (f"plan {spec.layer} {len(spec.times)} periods t={', '.join(f'{t:g}' for t in spec.times)} s "
                f"({' + '.join(f'{z / 1e6:g}' for z in spec.efforts)} km^2)")
    return f"plan {spec.layer} t={spec.t:g} s ({spec.effort / 1e6:g} km^2)"


def plan_scene(scene: Scene, *, threads: int | None = None, posterior: Raster | None = None) -> ScenePlan:
    """Compute ``scene``'s plan (its ``[plan]``: :class:`~bananagrid.scenes.load.PlanSpec`);
    on ``posterior`` where given (a scene with evidence: the plan's layer's posterior at its
    time, ``bg.posterior``'s cell probabilities given that nothing was found), else on
    :func:`plan_map`."""
    spec = scene.plan
    if spec.several:
        return _plan_periods(scene, threads=threads)
    start = time.perf_counter()
    cells = plan_map(scene, threads=threads) if posterior is None else posterior
    allocation = allocate(cells, spec.effort, law=spec.law)
    rectangles = search_rectangles(allocation, spec.rectangles, spec.sweep_width) if spec.rectangles else None
    bands = search_regions(allocation, spec.bands, spec.sweep_width) if spec.bands else None
    values = plan_values(allocation, rectangles, bands, layer=spec.layer, t=spec.t)
    return ScenePlan(cells=cells, allocation=allocation, rectangles=rectangles, bands=bands, values=values,
                     seconds=time.perf_counter() - start)


def _plan_periods(scene: Scene, *, threads: int | None = None) -> ScenePlan:
    """A plan over several periods (:func:`bananagrid.plan_periods` on the layer's model), each
    period's map, allocation and areas on the scene's grid (in its geographic frame)."""
    spec = scene.plan
    layer = next(layer for layer in scene.layers if layer.name == spec.layer)
    start = time.perf_counter()
    say = sweep_notice.get()

    def progress(sweep: int, pos: float, stage: str) -> None:
        if say is not None:
            say(f"sweep {sweep}: POS {pos:.6f} ({stage})")

    plan = plan_periods(layer.model(spec.times[0]), scene.grid, spec.times, spec.efforts, spec.law, tol=spec.tol,
                        threads=threads, progress=progress)
    periods = []
    for k, (t, allocation) in enumerate(zip(plan.times, plan.allocations)):
        effort = allocation.effort
        cells = Raster(values=np.asarray(allocation.cells, dtype=np.float64), grid=scene.grid,
                       mass=float(np.sum(allocation.cells)), quantity="probability",
                       provenance={"period_plan": {"period": k + 1, "t": t, "map": "the target the other periods miss"}})
        if scene.geo is not None:  # GeoJSON of the areas in longitude and latitude
            geo = {"geo": scene.geo.identity()}
            cells = replace(cells, frame=scene.geo, provenance={**cells.provenance, **geo})
            allocation = replace(allocation, effort=replace(effort, frame=scene.geo,
                                                            provenance={**effort.provenance, **geo}))
        rectangles = search_rectangles(allocation, spec.rectangles, spec.sweep_width) if spec.rectangles else None
        bands = search_regions(allocation, spec.bands, spec.sweep_width) if spec.bands else None
        values = plan_values(allocation, rectangles, bands, layer=spec.layer, t=t)
        values.update(period=k + 1, periods=len(plan.times), first_detection=float(plan.period_pos[k]),
                      plan_pos=float(plan.pos))
        periods.append(ScenePlan(cells=cells, allocation=allocation, rectangles=rectangles, bands=bands,
                                 values=values, seconds=0.0))
    first = periods[0]
    return ScenePlan(cells=first.cells, allocation=first.allocation, rectangles=first.rectangles, bands=first.bands,
                     values=periods_values(plan, [p.values for p in periods], layer=spec.layer),
                     seconds=time.perf_counter() - start, periods=tuple(periods), period_plan=plan)


def plan_coverage(scene: Scene, plan: ScenePlan | None):
    """The plan's coverage for the NetCDF file: ``(layer, t, effort raster)``, or with several
    periods a list of ``(layer, t, effort raster, attributes)``, one per period; None without
    a plan."""
    if plan is None:
        return None
    if not plan.periods:
        return (scene.plan.layer, scene.plan.t, plan.allocation.effort)
    return [(scene.plan.layer, p.values["t"], p.allocation.effort,
             {"bananagrid_period": p.values["period"], "bananagrid_first_detection": p.values["first_detection"],
              "bananagrid_period_pos": p.values["pos"], "bananagrid_plan_pos": p.values["plan_pos"]})
            for p in plan.periods]


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
    if plan.periods:  # each period at its time, then the plan's totals
        for period in plan.periods:
            set_times(rec, period.values["t"], scene.geo)
            log_plan(rec, period.cells, period.allocation, period.rectangles, period.bands, layer=scene.plan.layer,
                     t=period.values["t"], extra=period.values)
        log_plan_periods(rec, plan.period_plan, plan.values)
        return
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
    for k, period in enumerate(plan.periods or (plan,)):
        for name, flown in (("rectangles", period.rectangles), ("bands", period.bands)):
            if flown is not None:
                where = {"period": k + 1, "t": period.values["t"]} if plan.periods else {}
                areas += [(polygon, tracks, {"plan": name, **where, **properties})
                          for polygon, tracks, properties in flown.geojson_areas()]
    summary = {key: value for key, value in plan.values.items() if not isinstance(value, (list, dict))}
    collection = plan_collection(areas, {"title": scene.title, **summary}, scene.geo)
    with writing(path, "GeoJSON file", stage=stage) as partial:
        partial.write_text(json.dumps(collection, allow_nan=False) + "\n", encoding="utf-8")
    return Path(path)
