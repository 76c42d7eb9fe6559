"""``bananagrid run SCENE --zarr OUT.zarr``: a scene's maps computed in tiles on Dask, into Zarr.

Every layer at every time is rasterised lazily in blocks (:func:`bananagrid.engine.tiles.rasterise_tiles`:
blocks the model proves negligible are never computed) and written block by block to one Zarr
store (:func:`bananagrid.geo.zarr_store.write_zarr`): the CF dataset of the NetCDF export, with
the grid, CRS, latitude and longitude of a geographic scene, times and provenance, whole or not
at all. The maps are the raw densities (a tiled map is not normalised: that would take a second
pass over it); each layer's captured mass is stored beside it (``LAYER_mass``), computed in the
same pass, so a reader divides by it to normalise. With ``output.cell_probabilities = true``
each cell's probability (POC) is stored beside its layer (``LAYER_probability``), computed in
the same tiles by the cell rules. No recording is written (a viewer cannot
hold such grids; ``bananagrid run`` without ``--zarr`` records a scene that fits in memory).

A scene with ``[[evidence]]`` stores each map's posterior beside it, as the NetCDF export of the
same scene does (:func:`~bananagrid.geo.dataset.raster_dataset`): ``LAYER_posterior`` (the
posterior cell probabilities, summing to one), ``LAYER_pod`` (each cell's cumulative POD),
``LAYER_pos`` (the searches' POS at each time), ``LAYER_search_pos`` (each search's own) and the
evidence's provenance (``bananagrid_evidence``). Each posterior is the in-memory run's
(:func:`~bananagrid.scenes.run_evidence.scene_posterior`: the layer's model on the scene's grid
after the evidence that began by the map's time) computed in blocks by
:func:`~bananagrid.evidence.tiled.posterior_tiles`. One pass over the blocks computes everything:
the priors' densities, each posterior's cells before its normaliser (P_c f_all) and POD map, and
every posterior's float64 sums; the normaliser, POS and each search's POS are global, so once the
pass is done the stored cells are divided by their sum in place (a read and a write of each
stored block, no cell rule run again) and the numbers written, before the store is put in place.
Evidence that contradicts a prior is refused then, in the in-memory run's words, and no store is
left. Refused still: an ``[array]`` scene and a ``[plan]`` (one line each).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..engine.cluster import worker_need
from ..engine.grid_cells import probability_work
from ..engine.warp_runtime import default_threads
from ..engine.work import check_work
from ..engine.tiles import rasterise_tiles
from ..evidence.tiled import TiledPosterior, posterior_tiles
from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..geo.dataset import layer_variables, raster_dataset
from ..geo.zarr_store import check_store_target, compute_with_progress, scale_stored, write_zarr
from ..recording.evidence import evidence_values
from ..results import TiledRaster
from ..validate import BananagridError
from .evidence import job_evidence
from .load import Layer, Scene
from .run_evidence import EVIDENCE_BYTES_PER_CELL, EVIDENCE_BYTES_PER_PIECE, ScenePosterior, scene_error, scene_named

__all__ = ["run_scene_tiled", "tiled_maps", "check_tiled", "format_tiled_summary", "TiledJob", "tiled_posteriors",
           "finish_posteriors", "posterior_worker_need"]


def check_tiled(scene: Scene) -> Scene:
    """Refuse what cannot be tiled: an [array] scene (angular cells, not a grid), a scene that
    plans a search (a plan needs the cell probabilities of its whole map in memory)."""
    if not scene.gridded:
        raise BananagridError(f"{scene.source}: --zarr: an [array] scene's angular cells are not a grid; "
                              "run it without --zarr")
    if scene.plan is not None:
        raise BananagridError(f"{scene.source}: --zarr computes maps in tiles; a [plan] needs its map's cell "
                              "probabilities in memory: run it without --zarr (or drop [plan])")
    return scene


@dataclass(frozen=True)
class TiledJob:
    """One map's posterior in a tiled run, lazily: the layer, the time, the scene's evidence it
    takes (that which began by ``t``) and its :class:`~bananagrid.evidence.tiled.TiledPosterior`."""

    layer: Layer
    t: float
    used: tuple
    tiles: TiledPosterior


def tiled_posteriors(scene: Scene, chunks, *, max_seconds: float | None = None) -> list[TiledJob]:
    """Each map's posterior after the scene's evidence, lazily (none without ``[[evidence]]``),
    checked now as the in-memory run checks it (``posterior_tiles`` runs every check of
    ``bg.posterior`` on one cell): what it refuses is one line naming the scene, the layer, the
    time and the scene's ``evidence[k]``. A posterior whose estimated computing exceeds
    ``max_seconds`` (default one hour) is refused too: its prior's cell rules on the blocks not
    skipped, over the machine's cores (what the in-memory run counts for it)."""
    if not scene.evidence:
        return []
    jobs = []
    cells = scene.grid.nx * scene.grid.ny
    for layer, t in scene.jobs():
        used = tuple(job_evidence(scene.evidence, t))
        model = layer.model(t)
        try:
            tiles = posterior_tiles(model, scene.grid, [s.evidence for s in used], chunks)
        except BananagridError as exc:
            raise scene_error(scene, layer, t, used, exc) from None
        _, rows, cols = tiles.channels.chunks
        computed = int(np.outer(rows, cols)[~tiles.skipped].sum())
        check_work(probability_work(model, scene.grid)[0] * computed / cells, default_threads(),
                   f"{scene.source}: the posterior of layers.{layer.name} at t = {t:g} s on {computed:,} cells in "
                   "tiles", limit=max_seconds, option="--max-seconds S")
        jobs.append(TiledJob(layer, float(t), used, tiles))
    return jobs


def finish_posteriors(scene: Scene, jobs: list[TiledJob], sums=None, *, progress: bool = False) -> list[ScenePosterior]:
    """Each map's :class:`~bananagrid.scenes.run_evidence.ScenePosterior` holding its lazy maps
    (:meth:`~bananagrid.evidence.tiled.TiledPosterior.maps`), named as the in-memory run names
    them, from the posteriors' sums: ``sums`` the computed
    :meth:`~bananagrid.evidence.tiled.TiledPosterior.lazy_sums` of every job in turn, or None to
    compute them here in one pass over their blocks.

    Raises
    ------
    BananagridError
        Evidence that contradicts a map's prior, or a grid where the prior holds no mass: one
        line naming the scene, the layer and the time, as the in-memory run.
    """
    if not jobs:
        return []
    if sums is None:
        sums = compute_with_progress(*[s for job in jobs for s in job.tiles.lazy_sums()], progress=progress)
    computed = iter(sums)
    found = []
    for job in jobs:
        mine = [next(computed) for _ in job.tiles.lazy_sums()]
        try:
            numbers = job.tiles.finish_sums(mine)
        except BananagridError as exc:
            raise scene_error(scene, job.layer, job.t, job.used, exc) from None
        post = scene_named(scene, job.used, job.tiles.maps(numbers))
        # evidence_values sums the prior's cells for its prior mass: here the blocks' sum, known
        summed = SimpleNamespace(pos=post.pos, normaliser=post.normaliser, search_pos=post.search_pos,
                                 prior=post.prior_mass)
        values = evidence_values(summed, job.used, scene.evidence, layer=job.layer.name, t=job.t)
        found.append(ScenePosterior(layer=job.layer.name, t=job.t, posterior=post, used=job.used, values=values))
    return found


def posterior_worker_need(job: TiledJob) -> int:
    """Bytes a worker needs for one block of ``job``'s posterior: a prior's block
    (:func:`~bananagrid.engine.cluster.worker_need`), the block's channels twice (computed, then
    handed on) and the in-memory run's measured bytes per cell of ``bg.posterior``
    (:data:`~bananagrid.scenes.run_evidence.EVIDENCE_BYTES_PER_CELL` and a share per piece)."""
    rows, cols = job.tiles.chunks
    cells = rows * cols
    channels = len(job.tiles.names)
    return (worker_need((rows, cols)) + cells * 2 * 8 * channels
            + cells * (EVIDENCE_BYTES_PER_CELL + EVIDENCE_BYTES_PER_PIECE * len(job.used)))


def tiled_maps(scene: Scene, chunks, *, max_seconds: float | None = None,
               quantity: str = "density") -> list[tuple[str, float, TiledRaster]]:
    """The scene's panels ``(layer, t, TiledRaster)`` of densities (or cell probabilities),
    lazily (nothing computed yet)."""
    panels = []
    for layer, t in scene.jobs():
        tiled = rasterise_tiles(layer.model(t), scene.grid, chunks, dtype=np.dtype(scene.dtype), max_seconds=max_seconds,
                                quantity=quantity)
        if scene.geo is not None:  # the frame travels in the provenance too: readers rebuild it
            tiled = replace(tiled, frame=scene.geo, provenance={**tiled.provenance, "geo": scene.geo.identity()})
        panels.append((layer.name, t, tiled))
    return panels


def run_scene_tiled(scene: Scene, path: Path, chunks, *, progress: bool = False,
                    max_seconds: float | None = None) -> list[dict]:
    """Compute ``scene`` in tiles into the Zarr store ``path``; returns one summary row per map
    (:func:`format_tiled_summary`), read back from the store; with ``[[evidence]]`` each row's
    ``evidence`` holds its posterior's numbers
    (:func:`~bananagrid.recording.evidence.evidence_values`, as the in-memory run's rows). A
    ``path`` that is not absent, an empty directory or a store of ours is refused before any
    computing (:func:`~bananagrid.geo.zarr_store.check_store_target`)."""
    xr = require("xarray", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    check_tiled(scene)
    check_store_target(path)
    start = time.perf_counter()
    panels = tiled_maps(scene, chunks, max_seconds=max_seconds)
    cells = None
    if scene.cell_probabilities:  # each cell's probability beside its density, in the same tiles
        cells = {(layer, t): tiled for layer, t, tiled in tiled_maps(scene, chunks, max_seconds=max_seconds,
                                                                      quantity="probability")}
    # one pass computes every block: the priors' densities, each posterior's cells before its
    # normaliser with its POD map, and the posteriors' sums; then finish() divides the stored cells
    # by their sums (the normaliser is global) and writes the numbers, before the store is in place
    jobs = tiled_posteriors(scene, chunks, max_seconds=max_seconds)
    lazy = [s for job in jobs for s in job.tiles.lazy_sums()]
    found: list[ScenePosterior] = []

    def finish(group, sums) -> None:
        found.extend(finish_posteriors(scene, jobs, sums))
        _store_numbers(group, scene, panels, cells, found, progress)

    pending = {(job.layer.name, job.t): scene_named(scene, job.used, job.tiles.pending_maps()) for job in jobs}
    write_zarr(path, panels, scene.geo, title=scene.title, source=scene.source, progress=progress, cells=cells,
               posteriors=pending or None, extra=lazy, finish=finish if jobs else None)
    seconds = time.perf_counter() - start
    evidence = {(p.layer, p.t): p.values for p in found}
    rows = []
    with xr.open_zarr(path) as stored:
        masses = {layer: stored[f"{name}_mass"].values for layer, name in layer_variables(stored).items()}
        seen: dict[str, int] = {}
        for layer, t, tiled in panels:
            k = seen.get(layer, 0)
            seen[layer] = k + 1
            rows.append({
                "scene": scene.name, "layer": layer, "t": float(t), "cells": scene.grid.nx * scene.grid.ny,
                "tiles": int(tiled.skipped.size), "skipped": int(tiled.skipped.sum()),
                "computed": int(tiled.provenance["cells_computed"]), "mass": float(masses[layer][k]),
            })
            if (layer, t) in evidence:  # the posterior's numbers, as the in-memory run's summary rows
                rows[-1]["evidence"] = evidence[layer, t]
    for row in rows:
        row["seconds"] = seconds / len(rows)  # one pass computes every map: its time, shared
    return rows


def _store_numbers(group, scene: Scene, panels, cells, found: list[ScenePosterior], progress: bool) -> None:
    """The posteriors' numbers into the temporary store ``group`` once its pass has summed them:
    each ``LAYER_posterior`` divided by its sums (cell probabilities), and ``LAYER_pos``,
    ``LAYER_search_pos`` and the evidence's provenance as
    :func:`~bananagrid.geo.dataset.raster_dataset` puts them in the NetCDF (built again here with
    the numbers known; nothing in it is computed)."""
    finished = {(p.layer, p.t): p.posterior for p in found}
    complete = raster_dataset(panels, scene.geo, title=scene.title, source=scene.source, cells=cells,
                              posteriors=finished)
    for layer, var in layer_variables(complete).items():
        if f"{var}_posterior" not in complete:
            continue
        masses = [finished[key].mass for key in sorted((key for key in finished if key[0] == layer), key=lambda k: k[1])]
        scale_stored(group, f"{var}_posterior", masses, progress=progress)
        for name in (f"{var}_pos", f"{var}_search_pos"):
            group[name][...] = complete[name].values
        group[f"{var}_posterior"].attrs["bananagrid_evidence"] = complete[f"{var}_posterior"].attrs["bananagrid_evidence"]


def format_tiled_summary(rows: list[dict]) -> str:
    """The rows of :func:`run_scene_tiled` as an aligned text table."""
    header = ["scene", "layer", "t [s]", "cells", "tiles", "skipped", "cells computed", "captured mass"]
    body = [[r["scene"], r["layer"], f"{r['t']:g}", f"{r['cells']:,}", f"{r['tiles']:,}", f"{r['skipped']:,}",
             f"{r['computed']:,}", f"{r['mass']:.6f}"] for r in rows]
    widths = [max(len(c) for c in column) for column in zip(header, *body)]

    def line(cells):
        return "  ".join(c.ljust(w) if k < 2 else c.rjust(w) for k, (c, w) in enumerate(zip(cells, widths))).rstrip()

    total = sum(r["seconds"] for r in rows)
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, body),
                      f"{total:.2f} s in all (raw densities: divide by the captured mass to normalise)"])
