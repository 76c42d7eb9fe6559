"""Run a scene: compute every layer at every time on the scene's domain, record it, and
optionally export arrays.

One scene gives one recording ``OUT/NAME.rrd`` (and ``OUT/NAME.npz`` with ``npz=True``, and the
map files asked for). They are one :class:`~bananagrid.atomic.OutputSet`: every target is checked
before any computing (:func:`plan_outputs`), each is written under a temporary name, and they
are renamed into place together only when all are complete, so a failure leaves the previous
run's files as they were and no temporary behind.

:func:`run_scene` is the one runner: the checks, the planned files, the recording, the jobs
(layer, time) with their progress and summary rows. What a job computes and how it is recorded
belongs to the scene's domain: :class:`~bananagrid.scenes.run_grid.GridRun` for a grid's
rasters, :class:`~bananagrid.scenes.run_cells.CellRun` for an array's angular cells
(:data:`DOMAIN_RUNS`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from ..domains.angular_lattice import AngularLattice
from ..domains.grid import Grid
from ..recording.core import log_scene_text, write_recording
from .load import Scene
from .run_cells import CellRun
from .run_grid import (
    CELL_IMAGE, EXPORT_BYTES_PER_MAP_CELL, PROBABILITY_BYTES_PER_CELL, RUN_BYTES_PER_CELL, GridRun, array_key, compute,
)
from .run_outputs import (
    EXPORT_NAMES, EXPORT_SUFFIXES, NPZ, RUN_ONLY_PROVENANCE, export_paths, plan_outputs, write_exports,
)

__all__ = ["run_scene", "compute", "array_key", "check_exports", "check_run_memory", "check_run_work", "export_paths",
           "write_exports", "plan_outputs", "domain_run", "DOMAIN_RUNS", "RUN_ONLY_PROVENANCE", "RUN_BYTES_PER_CELL",
           "EXPORT_BYTES_PER_MAP_CELL", "PROBABILITY_BYTES_PER_CELL", "CELL_IMAGE", "EXPORT_NAMES",
           "EXPORT_SUFFIXES", "NPZ"]

Progress = Callable[[int, int, str], None]

#: How a scene's jobs are computed and recorded, by the type of its domain.
DOMAIN_RUNS = {Grid: GridRun, AngularLattice: CellRun}


def domain_run(scene: Scene) -> type:
    """The run class of ``scene``'s domain (:data:`DOMAIN_RUNS`)."""
    return DOMAIN_RUNS[type(scene.domain)]


def run_scene(
    scene: Scene,
    out_dir: str | os.PathLike,
    *,
    npz: bool = False,
    netcdf: bool = False,
    geotiff: bool = False,
    geojson: bool = False,
    kml: bool = False,
    threads: int | None = None,
    progress: Progress | None = None,
    max_memory: float | None = None,
    max_seconds: float | None = None,
) -> list[dict]:
    """Compute, record and optionally export every layer of ``scene`` at every time.

    Parameters
    ----------
    scene : Scene
        A validated scene (see :func:`bananagrid.scenes.load_scene`): a ``[grid]`` scene's
        layers are rasterised on its grid, an ``[array]`` scene's presence law gives the
        probabilities of its lattice's cells.
    out_dir : path-like
        Existing directory; receives ``NAME.rrd`` and, with ``npz``, ``NAME.npz``.
    npz : bool, default False
        Also write the arrays. A grid scene: ``x``, ``y`` (cell centres, m), one ``LAYER__tT``
        array of shape ``(ny, nx)`` per layer and time (density per m^2, normalised when the
        scene says so, rows south to north) and ``provenance`` (a JSON string). An array scene:
        the cell tables of :class:`~bananagrid.scenes.run_cells.CellRun`.
    netcdf : bool, default False
        Also write ``NAME.nc``: CF-1.10 NetCDF of every layer and time (projected x, y; with
        ``[geo]`` also latitude, longitude, the CRS and UTC times), see
        :func:`bananagrid.geo.dataset.raster_dataset`. Grid scenes only.
    geotiff : bool, default False
        Also write ``NAME.tif``: one georeferenced float32 band per layer and time
        (:func:`bananagrid.geo.geotiff.write_geotiff`). Grid scenes only.
    geojson : bool, default False
        Also write ``NAME-areas.geojson``: the probability-mass regions at the scene's
        ``mass_levels`` as WGS84 polygons (:func:`bananagrid.geo.geojson.write_geojson`); needs
        ``[geo]``.
    kml : bool, default False
        Also write ``NAME.kml``: the same search areas and the layers' landmarks (fix, stations,
        bearings) for Google Earth and chart plotters (:func:`bananagrid.geo.kml.write_kml`);
        needs ``[geo]``.
    threads : int, optional
        CPU threads per rasterisation (default: every core).
    progress : callable, optional
        ``progress(done, total, label)``, called before each layer and time with ``done``
        items finished so far, and after it (computed and logged) with ``done + 1``; then so
        for the steps after the maps (a grid scene's ``[plan]``: ``"plan LAYER t=T s (Z km^2)"``).
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
        One row per layer and time: ``scene``, ``layer``, ``t`` (s), ``cells``, ``mass``,
        ``peak``, ``regions`` (the probability-mass regions at the scene's ``mass_levels``,
        :class:`~bananagrid.contours.MassRegion`) and ``seconds``. A grid layer's ``mass`` is
        the raw captured mass (the sum of the cell probabilities with
        ``output.cell_probabilities``, else the densities' midpoint sum; ``mass_from`` says
        which), its ``peak`` the largest recorded density (m^-2) at ``peak_x``, ``peak_y``; an
        array's layer (``GEOMETRY/KIND``) gives the sum of p(C | S) and the largest cell
        probability (``peak_unit``: ``"per cell"``). With a ``[plan]``, the row of its layer
        and time has ``plan``: the plan's numbers (:func:`bananagrid.recording.plan.plan_values`).

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
        where the mass leaks), probability-mass levels the grid or the cells cannot reach, and
        fixed contour levels outside the map's range. A grid scene's own warnings and these are
        listed in the recording's summary document.
    """
    asked = dict(netcdf=netcdf, geotiff=geotiff, geojson=geojson, kml=kml)
    kind = domain_run(scene)
    kind.check_exports(scene, **asked)
    kind.check_memory(scene, exports=any(asked.values()), limit=max_memory)
    kind.check_work(scene, threads=threads, limit=max_seconds)
    outputs = plan_outputs(scene, out_dir, npz=npz, **asked)
    run = kind(scene, Path(out_dir), outputs, npz=npz, threads=threads, **asked)
    rows: list[dict] = []

    def build(rec) -> None:
        # Runs on this thread: set_elapsed is per thread.
        log_scene_text(rec, scene.text)
        jobs = scene.jobs()
        extra = run.extra_steps()  # after the maps, e.g. a scene's plan
        total = len(jobs) + len(extra)
        for k, (layer, t) in enumerate(jobs):
            label = run.label(layer, t)
            if progress is not None:
                progress(k, total, label)
            rows.append(run.record(rec, layer, t))
            if progress is not None:
                progress(k + 1, total, label)
        for k, (label, step) in enumerate(extra, start=len(jobs)):
            if progress is not None:
                progress(k, total, label)
            step(rec, rows)
            if progress is not None:
                progress(k + 1, total, label)
        run.finish(rec, rows)

    with outputs:  # all or nothing: the old files stay until every new one is complete
        with run.writing():
            write_recording(Path(out_dir) / f"{scene.name}.rrd", build, recording_id=run.recording_id(),
                            blueprint=run.blueprint(), stage=outputs.stage)
        outputs.commit()
    return rows


def check_exports(scene: Scene, *, netcdf: bool = False, geotiff: bool = False, geojson: bool = False,
                  kml: bool = False) -> None:
    """Refuse, before any computing, a map file the scene cannot give or whose library is
    missing: an [array] scene maps angular cells, not a grid; GeoJSON search areas are in
    latitude and longitude, so they need a geographic scene (``[geo]``)."""
    domain_run(scene).check_exports(scene, netcdf=netcdf, geotiff=geotiff, geojson=geojson, kml=kml)


def check_run_memory(scene: Scene, *, exports: bool = False, limit: float | None = None) -> float | None:
    """Refuse a grid scene whose run would need more memory than ``limit`` (default: what the
    system has available), before any computing; returns the estimate (None for an [array]
    scene). See :func:`bananagrid.scenes.run_grid.check_run_memory`."""
    return domain_run(scene).check_memory(scene, exports=exports, limit=limit)


def check_run_work(scene: Scene, *, threads: int | None = None, limit: float | None = None) -> float | None:
    """Refuse a grid scene whose estimated computing exceeds ``limit`` wall-clock seconds
    (default one hour), before any computing; returns the estimate (None for an [array] scene,
    whose angular lattices are bounded in size). See
    :func:`bananagrid.scenes.run_grid.check_run_work`."""
    return domain_run(scene).check_work(scene, threads=threads, limit=limit)
