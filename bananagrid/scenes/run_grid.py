"""The grid domain of a scene's run: each layer's raster at each time, recorded (density, contours,
the model's extras, radial curves, map marks), archived to the .npz and kept for the map files.

:func:`bananagrid.scenes.run.run_scene` drives it (:class:`GridRun`) as it drives the angular cells
of an ``[array]`` scene (:class:`bananagrid.scenes.run_cells.CellRun`).
"""

from __future__ import annotations

import contextlib
import json
import math
import time
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import rerun.blueprint as rrb

from ..analysis.coverage import coverage_warnings, level_warnings, peak_location
from ..atomic import OutputSet, OutputWriteError
from ..engine.grid_cells import probability_work
from ..engine.grid_kernel import GridExtent
from ..engine.memory import check_memory
from ..engine.rasterise import rasterise
from ..engine.warp_runtime import check_threads
from ..engine.work import check_work
from ..geo.areas import search_areas
from ..geo.libraries import require
from ..protocol import DensityModel
from ..recording.blueprint import ColourRange, map_panel_points
from ..recording.core import (
    default_blueprint,
    log_cell_probabilities,
    recording_id_for,
    send_blueprint,
    union_extent,
)
from ..recording.geomap import log_map_areas, log_map_marks, map_view
from ..recording.layers import layer_views, log_layer, log_scene_extras, log_shared_colours, scene_texts
from ..recording.evidence import evidence_view
from ..recording.plan import plan_view
from ..recording.timeline import ELAPSED, UTC, set_times
from ..recording.radial import log_radial_curves, radial_groups, radial_views
from ..recording.summary import CELL_TAB, log_summary
from ..results import Raster
from ..validate import BananagridError, BananagridWarning
from ..version import __version__
from .load import Layer, Scene
from .run_outputs import NPZ, RUN_ONLY_PROVENANCE, write_exports
from .run_evidence import (
    evidence_bytes_per_cell, evidence_paths, record_evidence_marks, record_posterior, scene_posterior,
    write_evidence_geojson,
)
from .run_plan import ScenePlan, plan_coverage, plan_label, plan_paths, plan_scene, record_plan, write_plan_geojson

__all__ = ["GridRun", "compute", "array_key", "check_exports", "check_run_memory", "check_run_work",
           "RUN_BYTES_PER_CELL", "EXPORT_BYTES_PER_MAP_CELL", "PROBABILITY_BYTES_PER_CELL", "PLAN_BYTES_PER_CELL",
           "CELL_IMAGE"]


class GridRun:
    """The outputs of a ``[grid]`` scene's run, one job (layer, time) at a time.

    Parameters
    ----------
    scene : Scene
    out_dir : Path
    outputs : OutputSet
        The run's planned files (:func:`bananagrid.scenes.run_outputs.plan_outputs`).
    npz, netcdf, geotiff, geojson, kml : bool
        The files asked for.
    threads : int or None
        CPU threads per rasterisation.
    """

    @staticmethod
    def check_exports(scene: Scene, **asked) -> None:
        """Before any computing: :func:`check_exports`."""
        check_exports(scene, **asked)

    @staticmethod
    def check_memory(scene: Scene, *, exports: bool = False, limit: float | None = None) -> float:
        """Before any computing: :func:`check_run_memory`."""
        return check_run_memory(scene, exports=exports, limit=limit)

    @staticmethod
    def check_work(scene: Scene, *, threads: int | None = None, limit: float | None = None) -> float:
        """Before any computing: :func:`check_run_work`."""
        return check_run_work(scene, threads=threads, limit=limit)

    def __init__(self, scene: Scene, out_dir: Path, outputs: OutputSet, *, npz: bool = False, netcdf: bool = False,
                 geotiff: bool = False, geojson: bool = False, kml: bool = False, threads: int | None = None):
        self.scene = scene
        self.out_dir = Path(out_dir)
        self.outputs = outputs
        self.npz_path = self.out_dir / f"{scene.name}.npz" if npz else None
        self.exports = dict(netcdf=netcdf, geotiff=geotiff, geojson=geojson, kml=kml)
        self.threads = threads
        self.panels: list | None = [] if any(self.exports.values()) else None
        self.found: list[str] = list(scene.warnings)
        self.frames: dict[str, list] = {}
        self.logged: dict[str, list] = {}  # what each layer's maps drew (frames, colour ranges)
        self.areas: dict[tuple[str, float], list] = {}  # a geographic scene's search areas, by (layer, t)
        self.cells: dict[tuple[str, float], Raster] = {}  # the cell probabilities kept for the map files
        self.marks: dict[str, dict] = {}  # each layer's landmarks (fix, stations), for the KML
        self.marked: set[str] = set()  # layers whose landmarks are on the map (static, logged once)
        self.archive = None
        self.plan: ScenePlan | None = None
        self.posteriors: list = []  # each map's posterior after the scene's evidence (ScenePosterior)

    def recording_id(self) -> str:
        """Depends on the scene text and the grid actually used (a step override changes it)."""
        return recording_id_for(self.scene.text + "\n" + json.dumps(self.scene.grid.describe(), sort_keys=True))

    def blueprint(self):
        """None: the maps open framed on what was found, so the blueprint is sent last (:meth:`finish`)."""
        return None

    def label(self, layer: Layer, t: float) -> str:
        return f"{layer.name} t={t:g} s"

    @contextlib.contextmanager
    def writing(self):
        """Around the recording: the .npz streamed into its staged file; after it, the map files."""
        scene = self.scene
        with self.outputs.stage(self.npz_path) if self.npz_path else contextlib.nullcontext() as partial:
            self.archive = _Archive(self.npz_path, partial, scene) if self.npz_path else None
            try:
                yield
            finally:
                if self.archive is not None:
                    self.archive.abandon()
        if self.panels is not None:
            plan = self.plan
            write_exports(scene, self.out_dir, self.panels, **self.exports, areas=self.areas, cells=self.cells,
                          marks=self.marks, stage=self.outputs.stage,
                          coverage=plan_coverage(scene, plan),
                          posteriors=self.posteriors)
            for path in plan_paths(scene, self.out_dir, geojson=self.exports["geojson"]):
                write_plan_geojson(path, scene, plan, stage=self.outputs.stage)
            for path in evidence_paths(scene, self.out_dir, geojson=self.exports["geojson"]):
                write_evidence_geojson(path, scene, self.posteriors, stage=self.outputs.stage)

    def extra_steps(self) -> list:
        """``(label, step)`` of the steps after the jobs: the scene's plan, if it has one
        (``step(rec, rows)`` computes and logs it, and gives its row the plan's numbers)."""
        return [] if self.scene.plan is None else [(plan_label(self.scene), self._plan_step)]

    def _plan_step(self, rec, rows: list[dict]) -> None:
        scene = self.scene
        # after evidence, the plan searches the posterior: where the target is given nothing found so far
        found = next((p.posterior for p in self.posteriors if (p.layer, p.t) == (scene.plan.layer, scene.plan.t)), None)
        self.plan = plan_scene(scene, threads=self.threads, posterior=found)
        record_plan(rec, scene, self.plan)
        for row in rows:
            if row["layer"] == scene.plan.layer and row["t"] == scene.plan.t:
                row["plan"] = self.plan.values

    def record(self, rec, layer: Layer, t: float) -> dict:
        """Compute one layer at ``t``, log it and keep it for the files; its summary row."""
        scene, threads = self.scene, self.threads
        model = layer.model(t)
        raster, seconds = compute(scene, layer, t, threads=threads, model=model, max_seconds=math.inf)
        cells = None
        if scene.cell_probabilities:  # the captured mass is then theirs, not the midpoint sum's
            cells, more = compute(scene, layer, t, threads=threads, model=model, max_seconds=math.inf,
                                  quantity="probability")
            seconds += more
            raster = replace(raster, mass=cells.mass,
                             provenance={**raster.provenance, "mass_from": "the cell probabilities"})
        set_times(rec, t, scene.geo)  # runs on the recording's thread: the times are per thread
        entity = f"layers/{layer.name}"
        if cells is not None:
            log_cell_probabilities(rec, f"{entity}/{CELL_IMAGE}", _recordable(cells), colormap=scene.colormap)
        logged = log_layer(
            rec, entity, layer.model_kind, model, _recordable(raster), levels=scene.levels,
            mass_levels=scene.mass_levels, colormap=scene.colormap,
            panel=_panel(scene),
            compute=lambda other: compute(scene, layer, t, threads=threads, model=other, max_seconds=math.inf)[0],
        )
        regions = logged.regions
        self.frames.setdefault(entity, []).append(logged.frame)
        self.logged.setdefault(entity, []).append(logged)
        where = f"{scene.name}: layer {layer.name} at t = {t:g} s"
        for message in (coverage_warnings(raster, regions, where=where, threshold=scene.min_mass,
                                          integrates_to_one=model.integrates_to_one)
                        + level_warnings(raster, scene.levels, where=where)):
            warnings.warn(message, BananagridWarning, stacklevel=2)
            self.found.append(message)
        if scene.radial is not None and layer.name in scene.radial.layers:
            _log_radial(rec, scene, layer, t, threads)
        if scene.geo is not None:
            self._log_map(rec, layer, t, model, raster)
        found = None
        if scene.evidence:
            if not self.posteriors:  # the evidence's geometry, once, each at its own time
                record_evidence_marks(rec, scene)
                set_times(rec, t, scene.geo)
            found = scene_posterior(scene, layer, t, model, threads=threads)
            record_posterior(rec, scene, found)
            self.posteriors.append(found)
        if self.archive is not None:
            self.archive.add(layer.name, t, raster, cells, found)
        if self.panels is not None:
            self.panels.append((layer.name, t, raster))
            if cells is not None:
                self.cells[layer.name, t] = cells
        row = _row(scene, layer, t, raster, seconds, regions)
        if found is not None:
            row["evidence"] = found.values
        return row

    def _log_map(self, rec, layer: Layer, t: float, model, raster: Raster) -> None:
        """A geographic scene's marks (once per layer) and search areas at ``t``."""
        scene = self.scene
        if layer.name not in self.marked:
            log_map_marks(rec, layer.name, model, scene.geo)
            self.marked.add(layer.name)
            self.marks[layer.name] = model.landmarks()
        self.areas[layer.name, t] = search_areas(raster, scene.mass_levels)
        log_map_areas(rec, layer.name, self.areas[layer.name, t], scene.geo)

    def finish(self, rec, rows: list[dict]) -> None:
        """The kinds' scene extras (e.g. the validation table), the summary and (last) the blueprint; the .npz completed."""
        scene = self.scene
        log_scene_extras(rec, scene.kinds.values(), scene.options)
        log_summary(rec, scene.title, rows, self.found)
        # The maps open framed on what was found, so the blueprint comes last.
        colours = log_shared_colours(rec, self.logged, _panel(scene))
        send_blueprint(rec, _blueprint(scene, {e: union_extent(extents) for e, extents in self.frames.items()},
                                       None if self.plan is None else self.plan.extent, colours=colours,
                                       mass_top=max((row["mass"] for row in rows), default=1.0)))
        if self.archive is not None:
            self.archive.close()


#: Peak bytes per grid cell of a scene run (rasters, the recording's float32 images, contours
#: and regions): the growth of a process's peak resident set from a 10,000-cell run to a
#: 2-million-cell one (tests/engine/test_memory.py) measured 76.4 (rice_isotropic, Butterly), 75.2
#: (ship_heading), 74.4 (figure1), 68.4 (submarine), 64.3 (bearing_coastal); rounded up to a bound.
RUN_BYTES_PER_CELL = 96
#: Further bytes per cell for each map kept for --netcdf, --geotiff or --geojson (the float64
#: raster, and the file's copy while it is written).
EXPORT_BYTES_PER_MAP_CELL = 24
#: Further bytes per cell with ``output.cell_probabilities``: their float64 sums and raster, the
#: quadrature's per-cell plans, and the float32 image.
PROBABILITY_BYTES_PER_CELL = 64
#: Further bytes per cell with a ``[plan]``: computing the plan peaked at 80 (three bands) and
#: 104 (three rectangles and three bands) bytes per cell of Python allocations (tracemalloc, on
#: geo_ship's 172,800 cells: its map's cell probabilities, the allocation's arrays and sorted
#: copies), and its recorded images take 11 more (two float32 images and an RGB one); rounded up.
#: A plan over several periods takes it per period (each period's map, coverage, POD, ln(1 - POD)
#: and the prior's cells at its time: 40 bytes, below its allocation's and areas').
PLAN_BYTES_PER_CELL = 160
#: The cell probabilities' image under a layer's entity (named in the summary's note).
CELL_IMAGE = CELL_TAB


def check_run_memory(scene: Scene, *, exports: bool = False, limit: float | None = None) -> float:
    """Refuse a grid scene whose run would need more memory than ``limit`` (default: what the
    system has available), before any computing; returns the estimate. See
    :mod:`bananagrid.engine.memory`."""
    cells = scene.grid.nx * scene.grid.ny
    kept = len(scene.jobs()) * (2 if scene.cell_probabilities else 1)  # maps kept for the files: densities, cells
    per_cell = (RUN_BYTES_PER_CELL + (EXPORT_BYTES_PER_MAP_CELL * kept if exports else 0)
                + (PROBABILITY_BYTES_PER_CELL if scene.cell_probabilities else 0)
                + (PLAN_BYTES_PER_CELL * len(scene.plan.periods) if scene.plan is not None else 0)
                + evidence_bytes_per_cell(scene))
    return check_memory(cells, per_cell, f"{scene.source}: a grid of {scene.grid.nx} x {scene.grid.ny} = {cells:,} cells",
                        limit=limit, option="--max-memory GB")


def check_run_work(scene: Scene, *, threads: int | None = None, limit: float | None = None) -> float:
    """Refuse a grid scene whose layers' estimated computing (the sum of each layer's
    ``work_estimate`` at each time, over ``threads``) exceeds ``limit`` wall-clock seconds
    (default one hour), before any computing; returns the estimate. See
    :mod:`bananagrid.engine.work`."""
    cells, extent = scene.grid.nx * scene.grid.ny, GridExtent(scene.grid)
    jobs = scene.jobs()
    core_seconds = sum(layer.model(t).work_estimate(cells, extent) for layer, t in jobs)
    if scene.cell_probabilities:
        core_seconds += sum(probability_work(layer.model(t), scene.grid)[0] for layer, t in jobs)
    if scene.evidence:  # each map's posterior: its prior's cell probabilities first
        core_seconds += sum(probability_work(layer.model(t), scene.grid)[0] for layer, t in jobs)
    if scene.plan is not None:  # the plan's maps: the layer's cell probabilities at each period's time
        planned = next(layer for layer in scene.layers if layer.name == scene.plan.layer)
        # (a plan over several periods then sweeps over carried maps, a number of sweeps not
        # known before: the progress line says each)
        core_seconds += sum(probability_work(planned.model(t), scene.grid)[0] for t, _ in scene.plan.periods)
    return check_work(core_seconds, check_threads(threads),
                      f"{scene.source}: {len(jobs)} layer map{'s' * (len(jobs) != 1)} of {cells:,} cells",
                      limit=limit, option="--max-seconds S")


def check_exports(scene: Scene, *, netcdf: bool = False, geotiff: bool = False, geojson: bool = False,
                  kml: bool = False) -> None:
    """Refuse, before any computing, a map file the scene cannot give or whose library is
    missing: GeoJSON and KML search areas are in latitude and longitude, so they need a
    geographic scene (``[geo]``)."""
    for wanted, libraries in ((netcdf, ("xarray", "netCDF4")), (geotiff, ("rasterio",)),
                              (geojson or kml, ("shapely", "pyproj"))):
        for library in libraries if wanted else ():
            require(library, "map files (--netcdf, --geotiff, --geojson, --kml)")
    if kml and scene.geo is None:
        raise BananagridError(
            f"{scene.source}: --kml: search areas are written in latitude and longitude, and this scene "
            "has no [geo] table (geo.origin_latlon); --netcdf and --geotiff work in local metres"
        )
    if scene.plan is not None and scene.plan.areas:
        require("shapely", "a [plan]'s rectangles and bands")
    if geojson and scene.geo is None:
        raise BananagridError(
            f"{scene.source}: --geojson: search areas are written in latitude and longitude, and this scene "
            "has no [geo] table (geo.origin_latlon); --netcdf and --geotiff work in local metres"
        )


def compute(scene: Scene, layer: Layer, t: float, *, threads: int | None = None,
            model: DensityModel | None = None, max_seconds: float | None = None,
            quantity: str = "density") -> tuple[Raster, float]:
    """One layer at elapsed time ``t``: the raster (normalised if the scene says so) and seconds.
    ``model``: the layer's model at ``t`` if already built, or another model rasterised as the
    layer is (e.g. for a difference map); ``max_seconds`` and ``quantity`` as for
    :func:`bananagrid.rasterise`."""
    start = time.perf_counter()
    model = layer.model(t) if model is None else model
    raster = rasterise(model, scene.grid, quantity=quantity, dtype=np.dtype(scene.dtype), threads=threads,
                       max_seconds=max_seconds, min_mass=0.0)  # the run warns itself, naming the edges
    if scene.normalise:
        if not raster.mass > 0.0:
            raise BananagridError(
                f"{scene.source}: layers.{layer.name} at t = {t:g} s: the grid captured no mass, "
                "so it cannot be normalised; move or enlarge the grid, or set output.normalise = false"
            )
        raster = raster.normalise()
    if scene.geo is not None:  # the frame travels in the provenance too: readers rebuild it
        raster = replace(raster, frame=scene.geo, provenance={**raster.provenance, "geo": scene.geo.identity()})
    return raster, time.perf_counter() - start


def _panel(scene: Scene) -> tuple[float, float]:
    """The size of each map's panel in the default layout (its labels are placed for it)."""
    return map_panel_points(len(scene.layers) + (scene.geo is not None))


def _blueprint(scene: Scene, frames: dict, plan_frame: tuple | None = None, *,
               colours: ColourRange | None = None, mass_top: float = 1.0):
    """The default layout, with each kind's extra images and views (from the registry's
    recording modules), the radial curves and the validation table if any; a scene's plan
    is a panel after the maps (opened on ``plan_frame``), its geographic map a tab behind it."""
    views, images = [], []
    if scene.radial is not None:
        groups = radial_groups(scene.radial.density_bearings, scene.radial.moments_max)
        for name in scene.radial.layers:
            views += radial_views(f"radial/{name}", groups)
    t0 = scene.jobs()[0][1] if scene.times else None
    models = [(layer.name, layer.model(t0)) for layer in scene.layers]
    for layer, (_, model) in zip(scene.layers, models):
        more_images, more_views = layer_views(f"layers/{layer.name}", layer.model_kind, model)
        if scene.cell_probabilities:
            images.append(f"layers/{layer.name}/{CELL_IMAGE}")
        images += more_images
        views += more_views
    return default_blueprint(
        [f"layers/{layer.name}" for layer in scene.layers],
        summary_entity="summary",
        extra_images=images,
        text_entities=scene_texts(scene.kinds.values(), scene.options),
        extra_views=views,
        several_times=scene.times is not None and len(scene.times) > 1,
        frames=frames,
        map_view=_with_plan(None if scene.geo is None else map_view(scene.geo, scene.grid.extent, models), scene,
                            plan_frame, list(frames.values())),
        colours=colours,
        mass_top=mass_top,
        timeline=UTC if scene.geo is not None and scene.geo.time is not None else ELAPSED,
        follow=bool(scene.evidence),
    )


def _with_plan(geographic, scene: Scene, plan_frame: tuple | None, layer_frames: list | None = None):
    """The panel after the layers' maps: the evidence's (prior and posterior side by side,
    :func:`~bananagrid.recording.evidence.evidence_view`), the plan's
    (:func:`~bananagrid.recording.plan.plan_view`) and the geographic map, as tabs in that
    order (each where the scene has it)."""
    panels = []
    if scene.evidence:
        panels.append(evidence_view([layer.name for layer in scene.layers], _evidence_frame(scene, layer_frames)))
    if scene.plan is not None:
        panels.append(plan_view(plan_frame, rectangles=scene.plan.rectangles > 0, bands=scene.plan.bands > 0,
                                periods=scene.plan.several))
    if geographic is not None:
        panels.append(geographic)
    if len(panels) < 2:
        return panels[0] if panels else None
    return rrb.Tabs(*panels, name=" and ".join(("evidence", "plan", "map")[k] for k, wanted in enumerate(
        (bool(scene.evidence), scene.plan is not None, geographic is not None)) if wanted))


def _evidence_frame(scene: Scene, layer_frames: list | None = None,
                    margin: float = 0.1) -> tuple[float, float, float, float] | None:
    """Where the evidence's views open: the layers' maps' frames (else the grid), widened to
    hold the evidence's shapes and tracks (within the grid: land or a track may reach far beyond)."""
    x0, x1, y0, y1 = union_extent(layer_frames) if layer_frames else scene.grid.extent
    gx0, gx1, gy0, gy1 = scene.grid.extent
    xs, ys = [x0, x1], [y0, y1]
    for spec in scene.evidence:
        for shape in (*spec.shapes, *(() if spec.track is None else (spec.track[:, :2],))):
            xs += [max(gx0, float(shape[:, 0].min())), min(gx1, float(shape[:, 0].max()))]
            ys += [max(gy0, float(shape[:, 1].min())), min(gy1, float(shape[:, 1].max()))]
    pad = margin * max(max(xs) - min(xs), max(ys) - min(ys))
    return (min(xs) - pad, max(xs) + pad, min(ys) - pad, max(ys) + pad)


def _log_radial(rec, scene: Scene, layer: Layer, t: float, threads) -> None:
    """The conditional radial curves (Figures 2-5 and 8) of a motion layer at time ``t``."""
    spec = scene.radial
    log_radial_curves(
        rec, f"radial/{layer.name}", layer.model(t), density_bearings=spec.density_bearings,
        moments_max=spec.moments_max, moments_step=spec.moments_step, threads=threads,
    )


def array_key(layer: str, t: float, quantity: str = "density") -> str:
    """Name of a layer's array at time ``t`` in the .npz: ``LAYER__tT`` (``T`` shortest form) for
    the density, ``LAYER__tT__probability`` for the cell probabilities."""
    key = f"{layer}__t{np.format_float_positional(float(t), trim='-')}"
    return key if quantity == "density" else f"{key}__{quantity}"


def _recordable(raster: Raster) -> Raster:
    """The raster without run-dependent provenance (timings, threads)."""
    kept = {k: v for k, v in raster.provenance.items() if k not in RUN_ONLY_PROVENANCE}
    return replace(raster, provenance=kept)


def _row(scene: Scene, layer: Layer, t: float, raster: Raster, seconds: float, regions: list) -> dict:
    """A summary row of one computed layer."""
    x, y = peak_location(raster)
    return {
        "scene": scene.name, "layer": layer.name, "t": float(t), "cells": scene.grid.nx * scene.grid.ny,
        "mass": raster.mass, "peak": raster.peak, "peak_x": x, "peak_y": y, "regions": regions,
        "seconds": seconds, "mass_from": raster.provenance.get("mass_from", ""),
    }


class _Archive:
    """The .npz export, streamed into its temporary file ``partial`` (the run's output set
    renames it with the other files).

    Arrays are added one at a time (no need to hold every raster), in numpy's .npz layout: a
    zip of ``KEY.npy`` members, deflated, readable with :func:`numpy.load` without pickle. A
    failure of the file system is one line naming ``path``
    (:class:`~bananagrid.atomic.OutputWriteError`).
    """

    def __init__(self, path: Path, partial: Path, scene: Scene):
        self.path = path
        self.partial = partial
        self.scene = scene
        self.entries: dict[str, dict] = {}
        with self._failing():
            self.zip = zipfile.ZipFile(self.partial, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1)
        try:
            self._write("x", scene.grid.x)
            self._write("y", scene.grid.y)
        except BaseException:
            self.abandon()
            raise

    def add(self, layer: str, t: float, raster: Raster, cells: Raster | None = None, found=None) -> None:
        """Store ``raster.values`` (and the cell probabilities ``cells``, if computed; and with
        evidence the posterior and its POD map, ``found``: a
        :class:`~bananagrid.scenes.run_evidence.ScenePosterior`) under :func:`array_key` and
        note their provenance."""
        if found is not None:
            post = found.posterior
            for quantity, values in (("posterior", post.values), ("pod", post.pod)):
                key = array_key(layer, t, quantity)
                self._write(key, np.asarray(values))
                self.entries[key] = {"layer": layer, "t": float(t), "quantity": quantity, **found.values,
                                     "provenance": post.provenance}
        for item in (raster, cells):
            if item is None:
                continue
            key = array_key(layer, t, item.quantity)
            self._write(key, item.values)
            self.entries[key] = {
                "layer": layer, "t": float(t), "quantity": item.quantity, "mass": item.mass, "peak": item.peak,
                "normalised": item.normalised, "provenance": item.provenance,
            }

    def close(self) -> None:
        """Write the provenance and finish the zip (still under the temporary name)."""
        self._write("provenance", np.array(json.dumps(self._provenance(), default=str)))
        with self._failing():
            self.zip.close()

    def abandon(self) -> None:
        """Let go of the file after a failure (or after :meth:`close`: then nothing to do);
        the output set removes it. Never raises: the failure already on its way is the one
        to report."""
        try:
            self.zip.close()
        except (OSError, ValueError):  # the write that failed failed again; or a member left open
            if self.zip.fp is not None:
                self.zip.fp.close()

    def _write(self, key: str, array: np.ndarray) -> None:
        with self._failing(), self.zip.open(f"{key}.npy", "w", force_zip64=True) as member:
            np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)

    @contextlib.contextmanager
    def _failing(self):
        """An error of the file system (a full disk, a file-size limit) as one line naming the file."""
        try:
            yield
        except OSError as exc:
            raise OutputWriteError(f"{self.path}: cannot write the {NPZ} ({exc.strerror or exc})") from None

    def _provenance(self) -> dict:
        scene = self.scene
        return {
            "bananagrid": __version__,
            "scene": scene.name,
            "title": scene.title,
            "source": scene.source,
            "grid": scene.grid.describe(),
            "geo": None if scene.geo is None else scene.geo.describe(),
            "dtype": scene.dtype,
            "quantity": "density per m^2 at the cell centres (x[j], y[i]); rows south to north"
                        + ("; arrays named __probability: the probability of each cell" if scene.cell_probabilities else ""),
            "normalised": scene.normalise,
            "arrays": self.entries,
            "text": scene.text,
        }
