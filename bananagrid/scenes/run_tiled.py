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
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..engine.tiles import rasterise_tiles
from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..geo.zarr_store import check_store_target, write_zarr
from ..results import TiledRaster
from ..validate import BananagridError
from .load import Scene

__all__ = ["run_scene_tiled", "tiled_maps", "check_tiled", "format_tiled_summary"]


def check_tiled(scene: Scene) -> Scene:
    """Refuse what cannot be tiled: an [array] scene (angular cells, not a grid), a scene that
    plans a search (a plan needs the cell probabilities of its whole map in memory), a scene
    with evidence (each posterior is normalised over its whole map)."""
    if not scene.gridded:
        raise BananagridError(f"{scene.source}: --zarr: an [array] scene's angular cells are not a grid; "
                              "run it without --zarr")
    if scene.plan is not None:
        raise BananagridError(f"{scene.source}: --zarr computes maps in tiles; a [plan] needs its map's cell "
                              "probabilities in memory: run it without --zarr (or drop [plan])")
    if scene.evidence:
        raise BananagridError(f"{scene.source}: --zarr computes maps in tiles; a posterior after [[evidence]] is "
                              "normalised over its whole map, in memory: run it without --zarr (or drop [[evidence]])")
    return scene


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
    (:func:`format_tiled_summary`), read back from the store. A ``path`` that is not absent, an
    empty directory or a store of ours is refused before any computing
    (:func:`~bananagrid.geo.zarr_store.check_store_target`)."""
    xr = require("xarray", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    check_tiled(scene)
    check_store_target(path)
    start = time.perf_counter()
    panels = tiled_maps(scene, chunks, max_seconds=max_seconds)
    cells = None
    if scene.cell_probabilities:  # each cell's probability beside its density, in the same tiles
        cells = {(layer, t): tiled for layer, t, tiled in tiled_maps(scene, chunks, max_seconds=max_seconds,
                                                                      quantity="probability")}
    write_zarr(path, panels, scene.geo, title=scene.title, source=scene.source, progress=progress, cells=cells)
    seconds = time.perf_counter() - start
    rows = []
    with xr.open_zarr(path) as stored:
        masses = {}
        for name, var in stored.data_vars.items():
            if "bananagrid_layer" in var.attrs:
                masses[var.attrs["bananagrid_layer"]] = stored[f"{name}_mass"].values
        seen: dict[str, int] = {}
        for layer, t, tiled in panels:
            k = seen.get(layer, 0)
            seen[layer] = k + 1
            rows.append({
                "scene": scene.name, "layer": layer, "t": float(t), "cells": scene.grid.nx * scene.grid.ny,
                "tiles": int(tiled.skipped.size), "skipped": int(tiled.skipped.sum()),
                "computed": int(tiled.provenance["cells_computed"]), "mass": float(masses[layer][k]),
            })
    for row in rows:
        row["seconds"] = seconds / len(rows)  # one pass computes every map: its time, shared
    return rows


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
