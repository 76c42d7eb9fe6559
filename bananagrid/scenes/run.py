"""Run a scene: rasterise every layer at every time, record it, and optionally export arrays.

One scene gives one recording ``OUT/NAME.rrd`` (and ``OUT/NAME.npz`` with ``npz=True``, and the
map files asked for). They are one :class:`~bananagrid.atomic.OutputSet`: every target is checked
before any computing (:func:`plan_outputs`), each is written under a temporary name, and they
are renamed into place together only when all are complete, so a failure leaves the previous
run's files as they were and no temporary behind.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
import warnings
import zipfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np


from ..analysis.bearing_validation import format_table, summary, validation_table
from ..analysis.coverage import coverage_warnings, level_warnings, peak_location
from ..atomic import OutputSet, OutputWriteError
from ..engine.grid_cells import probability_work
from ..engine.memory import check_memory
from ..engine.grid_kernel import GridExtent
from ..engine.rasterise import rasterise
from ..engine.warp_runtime import check_threads
from ..engine.work import check_work
from ..geo.dataset import raster_dataset, write_netcdf
from ..geo.areas import search_areas
from ..geo.geojson import write_geojson
from ..geo.geotiff import write_geotiff
from ..geo.libraries import require
from ..protocol import DensityModel
from ..recording.bearing import log_validation_table
from ..recording.geomap import log_map_areas, log_map_marks, map_view
from ..recording.core import (
    default_blueprint,
    focus_extent,
    log_cell_probabilities,
    log_raster,
    log_scene_text,
    recording_id_for,
    send_blueprint,
    set_elapsed,
    union_extent,
    write_recording,
)
from ..recording.layers import layer_views, log_layer_extras
from ..recording.radial import log_radial_curves, radial_groups, radial_views
from ..recording.summary import CELL_TAB, log_summary
from ..results import Raster
from ..validate import BananagridError, BananagridWarning
from ..version import __version__
from .load import Layer, Scene
from .presence import PresenceScene
from .run_presence import run_presence_scene

__all__ = ["run_scene", "compute", "array_key", "check_exports", "check_run_memory", "check_run_work", "export_paths", "write_exports",
           "plan_outputs", "RUN_ONLY_PROVENANCE"]

#: Provenance keys that describe the run rather than the result. They stay out of the
#: recording, so that running a scene twice gives equal recordings; the summary rows and the
#: .npz provenance keep them.
RUN_ONLY_PROVENANCE = ("seconds", "threads")

Progress = Callable[[int, int, str], None]


def run_scene(
    scene: Scene,
    out_dir: str | os.PathLike,
    *,
    npz: bool = False,
    netcdf: bool = False,
    geotiff: bool = False,
    geojson: bool = False,
    threads: int | None = None,
    progress: Progress | None = None,
    max_memory: float | None = None,
    max_seconds: float | None = None,
) -> list[dict]:
    """Rasterise, record and optionally export every layer of ``scene`` at every time.

    Parameters
    ----------
    scene : Scene
        A validated scene (see :func:`bananagrid.scenes.load_scene`).
    out_dir : path-like
        Existing directory; receives ``NAME.rrd`` and, with ``npz``, ``NAME.npz``.
    npz : bool, default False
        Also write the arrays: ``x``, ``y`` (cell centres, m), one ``LAYER__tT`` array of
        shape ``(ny, nx)`` per layer and time (density per m^2, normalised when the scene
        says so, rows south to north) and ``provenance`` (a JSON string).
    netcdf : bool, default False
        Also write ``NAME.nc``: CF-1.10 NetCDF of every layer and time (projected x, y; with
        ``[geo]`` also latitude, longitude, the CRS and UTC times), see
        :func:`bananagrid.geo.dataset.raster_dataset`.
    geotiff : bool, default False
        Also write ``NAME.tif``: one georeferenced float32 band per layer and time
        (:func:`bananagrid.geo.geotiff.write_geotiff`).
    geojson : bool, default False
        Also write ``NAME-areas.geojson``: the probability-mass regions at the scene's
        ``mass_levels`` as WGS84 polygons (:func:`bananagrid.geo.geojson.write_geojson`); needs
        ``[geo]``.
    threads : int, optional
        CPU threads per rasterisation (default: every core).
    progress : callable, optional
        ``progress(done, total, label)``, called before each layer and time with ``done``
        items finished so far, and after it (computed and logged) with ``done + 1``.
    max_memory : float, optional
        Bytes the run may take (default: the memory the system has available); a grid whose
        estimate (:func:`check_run_memory`) is larger is refused before any computing.
    max_seconds : float, optional
        Wall-clock seconds of computing the run may take (default one hour,
        :data:`bananagrid.engine.work.DEFAULT_MAX_SECONDS`; ``math.inf`` for no limit); a scene
        whose estimate (:func:`check_run_work`) is larger is refused before any computing.

    Returns
    -------
    list of dict
        One row per layer and time: ``scene``, ``layer``, ``t`` (s), ``cells``, ``mass``
        (raw captured mass: the sum of the cell probabilities with ``output.cell_probabilities``,
        else the densities' midpoint sum), ``mass_from`` (``"the cell probabilities"`` or ""),
        ``peak`` (largest recorded density, m^-2), ``peak_x``, ``peak_y`` (its cell centre, m),
        ``regions`` (the probability-mass regions at the scene's ``mass_levels``,
        :class:`~bananagrid.contours.MassRegion`) and ``seconds`` (rasterise, cell probabilities
        and normalise, wall clock).

    Raises
    ------
    BananagridError
        Before any computing: a bad option, too much memory or work, or a target that must not
        be replaced (:func:`plan_outputs`). After: a failure while computing or writing
        (:class:`~bananagrid.atomic.OutputWriteError` names the file), with the previous run's
        files kept as they were.

    Warns
    -----
    BananagridWarning
        For a layer whose grid captured less than the scene's ``min_mass`` (naming the edges
        where the mass leaks), probability-mass levels the grid cannot reach, and fixed
        contour levels outside the map's range. The scene's own warnings and these are listed
        in the recording's summary document.
    """
    check_exports(scene, netcdf=netcdf, geotiff=geotiff, geojson=geojson)
    check_run_memory(scene, exports=netcdf or geotiff or geojson, limit=max_memory)
    check_run_work(scene, threads=threads, limit=max_seconds)
    outputs = plan_outputs(scene, out_dir, npz=npz, netcdf=netcdf, geotiff=geotiff, geojson=geojson)
    if isinstance(scene, PresenceScene):  # an [array] scene: its own runner
        return run_presence_scene(scene, out_dir, npz=npz, threads=threads, progress=progress, outputs=outputs)
    out_dir = Path(out_dir)
    panels: list | None = [] if netcdf or geotiff or geojson else None
    rrd_path = out_dir / f"{scene.name}.rrd"
    npz_path = out_dir / f"{scene.name}.npz"
    archive = None
    rows: list[dict] = []
    found: list[str] = list(scene.warnings)
    frames: dict[str, list] = {}
    areas: dict[tuple[str, float], list] = {}  # a geographic scene's search areas, by (layer, t)
    marked: set[str] = set()  # layers whose landmarks are on the map (static, logged once)

    def build(rec) -> None:
        # Runs on this thread: set_elapsed is per thread.
        log_scene_text(rec, scene.text)
        jobs = scene.jobs()
        for k, (layer, t) in enumerate(jobs):
            label = f"{layer.name} t={t:g} s"
            if progress is not None:
                progress(k, len(jobs), label)
            model = layer.model(t)
            raster, seconds = compute(scene, layer, t, threads=threads, model=model, max_seconds=math.inf)
            cells = None
            if scene.cell_probabilities:  # the captured mass is then theirs, not the midpoint sum's
                cells, more = compute(scene, layer, t, threads=threads, model=model, max_seconds=math.inf,
                                      quantity="probability")
                seconds += more
                raster = replace(raster, mass=cells.mass,
                                 provenance={**raster.provenance, "mass_from": "the cell probabilities"})
            set_elapsed(rec, t)
            entity = f"layers/{layer.name}"
            if cells is not None:
                log_cell_probabilities(rec, f"{entity}/{CELL_IMAGE}", _recordable(cells), colormap=scene.colormap)
            regions = log_raster(
                rec, entity, _recordable(raster), levels=scene.levels, mass_levels=scene.mass_levels,
                colormap=scene.colormap,
            )
            frames.setdefault(entity, []).append(focus_extent(raster, regions))
            where = f"{scene.name}: layer {layer.name} at t = {t:g} s"
            for message in (coverage_warnings(raster, regions, where=where, threshold=scene.min_mass,
                                                 integrates_to_one=model.integrates_to_one)
                            + level_warnings(raster, scene.levels, where=where)):
                warnings.warn(message, BananagridWarning, stacklevel=2)
                found.append(message)
            log_layer_extras(
                rec, entity, layer.model_kind, model, raster,
                compute=lambda other: compute(scene, layer, t, threads=threads, model=other, max_seconds=math.inf)[0],
            )
            if scene.radial is not None and layer.name in scene.radial.layers:
                _log_radial(rec, scene, layer, t, threads)
            if scene.geo is not None:
                if layer.name not in marked:
                    log_map_marks(rec, layer.name, model, scene.geo)
                    marked.add(layer.name)
                areas[layer.name, t] = search_areas(raster, scene.mass_levels)
                log_map_areas(rec, layer.name, areas[layer.name, t], scene.geo)
            if archive is not None:
                archive.add(layer.name, t, raster, cells)
            if panels is not None:
                panels.append((layer.name, t, raster))
            rows.append(_row(scene, layer, t, raster, seconds, regions))
            if progress is not None:
                progress(k + 1, len(jobs), label)
        if scene.bearing_validation:
            records = validation_table()
            log_validation_table(rec, "validation", format_table(records), summary(records))
        log_summary(rec, scene.title, rows, found)
        # The maps open framed on what was found, so the blueprint comes last.
        send_blueprint(rec, _blueprint(scene, {e: union_extent(extents) for e, extents in frames.items()}))
        if archive is not None:
            archive.close()

    with outputs:  # all or nothing: the old files stay until every new one is complete
        with outputs.stage(npz_path) if npz else contextlib.nullcontext() as npz_partial:
            archive = _Archive(npz_path, npz_partial, scene) if npz else None
            try:
                write_recording(rrd_path, build, recording_id=_recording_id(scene), stage=outputs.stage)
            finally:
                if archive is not None:
                    archive.abandon()
        if panels is not None:
            write_exports(scene, out_dir, panels, netcdf=netcdf, geotiff=geotiff, geojson=geojson, areas=areas,
                          stage=outputs.stage)
        outputs.commit()
    return rows


def plan_outputs(scene: Scene | PresenceScene, out_dir: str | os.PathLike, *, npz: bool = False,
                 netcdf: bool = False, geotiff: bool = False, geojson: bool = False) -> OutputSet:
    """The files a run of ``scene`` writes in ``out_dir`` (``NAME.rrd``, and ``NAME.npz`` and the
    map files asked for), each checked now, before any computing: the directory must exist and
    take new files, and each target must be absent or a regular file (a directory, a link or
    anything else there is refused, naming it). Nothing is created.

    Raises
    ------
    BananagridError
        One line naming the directory or the target and what is there.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise BananagridError(f"{out_dir}: output directory does not exist")
    outputs = OutputSet()
    outputs.add(out_dir / f"{scene.name}.rrd", "recording")
    if npz:
        outputs.add(out_dir / f"{scene.name}.npz", NPZ)
    for option, path in export_paths(scene.name, out_dir, netcdf=netcdf, geotiff=geotiff, geojson=geojson).items():
        outputs.add(path, EXPORT_NAMES[option])
    return outputs


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
#: The cell probabilities' image under a layer's entity (named in the summary's note).
CELL_IMAGE = CELL_TAB


def check_run_memory(scene: Scene | PresenceScene, *, exports: bool = False, limit: float | None = None) -> float | None:
    """Refuse a grid scene whose run would need more memory than ``limit`` (default: what the
    system has available), before any computing; returns the estimate (None for an [array]
    scene). See :mod:`bananagrid.engine.memory`."""
    if isinstance(scene, PresenceScene):
        return None
    cells = scene.grid.nx * scene.grid.ny
    per_cell = (RUN_BYTES_PER_CELL + (EXPORT_BYTES_PER_MAP_CELL * len(scene.jobs()) if exports else 0)
                + (PROBABILITY_BYTES_PER_CELL if scene.cell_probabilities else 0))
    return check_memory(cells, per_cell, f"{scene.source}: a grid of {scene.grid.nx} x {scene.grid.ny} = {cells:,} cells",
                        limit=limit, option="--max-memory GB")


def check_run_work(scene: Scene | PresenceScene, *, threads: int | None = None,
                   limit: float | None = None) -> float | None:
    """Refuse a grid scene whose layers' estimated computing (the sum of each layer's
    ``work_estimate`` at each time, over ``threads``) exceeds ``limit`` wall-clock seconds
    (default one hour), before any computing; returns the estimate (None for an [array] scene,
    whose angular lattices are bounded in size). See :mod:`bananagrid.engine.work`."""
    if isinstance(scene, PresenceScene):
        return None
    cells, extent = scene.grid.nx * scene.grid.ny, GridExtent(scene.grid)
    jobs = scene.jobs()
    core_seconds = sum(layer.model(t).work_estimate(cells, extent) for layer, t in jobs)
    if scene.cell_probabilities:
        core_seconds += sum(probability_work(layer.model(t), scene.grid)[0] for layer, t in jobs)
    return check_work(core_seconds, check_threads(threads),
                      f"{scene.source}: {len(jobs)} layer map{'s' * (len(jobs) != 1)} of {cells:,} cells",
                      limit=limit, option="--max-seconds S")


def check_exports(scene: Scene | PresenceScene, *, netcdf: bool = False, geotiff: bool = False,
                  geojson: bool = False) -> None:
    """Refuse, before any computing, a map file the scene cannot give or whose library is
    missing: an [array] scene maps angular cells, not a grid; GeoJSON search areas are in
    latitude and longitude, so they need a geographic scene (``[geo]``)."""
    asked = [option for option, wanted in (("--netcdf", netcdf), ("--geotiff", geotiff), ("--geojson", geojson))
             if wanted]
    if asked and isinstance(scene, PresenceScene):
        raise BananagridError(f"{scene.source}: {', '.join(asked)}: an [array] scene maps angular cells, "
                              "not a grid; its cell tables are in the .rrd and .npz")
    for wanted, libraries in ((netcdf, ("xarray", "netCDF4")), (geotiff, ("rasterio",)), (geojson, ("shapely", "pyproj"))):
        for library in libraries if wanted else ():
            require(library, "map files (--netcdf, --geotiff, --geojson)")
    if geojson and scene.geo is None:
        raise BananagridError(
            f"{scene.source}: --geojson: search areas are written in latitude and longitude, and this scene "
            "has no [geo] table (geo.origin_latlon); --netcdf and --geotiff work in local metres"
        )


#: The map files' names after the scene's name, by option.
EXPORT_SUFFIXES = {"netcdf": ".nc", "geotiff": ".tif", "geojson": "-areas.geojson"}
#: What each map file is called in messages (as its writer calls it).
EXPORT_NAMES = {"netcdf": "NetCDF file", "geotiff": "GeoTIFF", "geojson": "GeoJSON file"}
#: What the .npz is called in messages.
NPZ = ".npz arrays"


def export_paths(name: str, out_dir: Path, *, netcdf: bool = False, geotiff: bool = False,
                 geojson: bool = False) -> dict[str, Path]:
    """``{option: path}`` of the map files asked for, for scene ``name`` in ``out_dir``."""
    wanted = {"netcdf": netcdf, "geotiff": geotiff, "geojson": geojson}
    return {option: Path(out_dir) / f"{name}{suffix}" for option, suffix in EXPORT_SUFFIXES.items() if wanted[option]}


def write_exports(scene: Scene, out_dir: Path, panels: list, *, netcdf: bool = False, geotiff: bool = False,
                  geojson: bool = False, areas: dict | None = None, stage=None) -> list[Path]:
    """The map files of a scene's ``panels`` (``(layer, t, raster)``), written together or not at
    all (``stage``: a run's :meth:`~bananagrid.atomic.OutputSet.stage`, whose commit puts them in
    place with its other files; default: put in place here when all are complete). Returns their
    paths. ``areas``: the panels' search areas by ``(layer, t)`` where already found."""
    paths = export_paths(scene.name, out_dir, netcdf=netcdf, geotiff=geotiff, geojson=geojson)
    with OutputSet() as own:
        if stage is None:
            for option, path in paths.items():
                own.add(path, EXPORT_NAMES[option])
            stage = own.stage
        if netcdf:
            dataset = raster_dataset(panels, scene.geo, title=scene.title, source=scene.source)
            write_netcdf(paths["netcdf"], dataset, stage=stage)
        if geotiff:
            write_geotiff(paths["geotiff"], panels, scene.geo, title=scene.title, stage=stage)
        if geojson:
            write_geojson(paths["geojson"], panels, scene.geo, scene.mass_levels, title=scene.title, areas=areas,
                          stage=stage)
        own.commit()
    return list(paths.values())


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
                       max_seconds=max_seconds)
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


def _blueprint(scene: Scene, frames: dict):
    """The default layout, with each kind's extra images and views (from the registry's
    recording modules), the radial curves and the validation table if any."""
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
        text_entities=["validation"] if scene.bearing_validation else [],
        extra_views=views,
        several_times=scene.times is not None and len(scene.times) > 1,
        frames=frames,
        map_view=None if scene.geo is None else map_view(scene.geo, scene.grid.extent, models),
    )


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


def _recording_id(scene: Scene) -> str:
    """Depends on the scene text and the grid actually used (a step override changes it)."""
    return recording_id_for(scene.text + "\n" + json.dumps(scene.grid.describe(), sort_keys=True))


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

    def add(self, layer: str, t: float, raster: Raster, cells: Raster | None = None) -> None:
        """Store ``raster.values`` (and the cell probabilities ``cells``, if computed) under
        :func:`array_key` and note their provenance."""
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
