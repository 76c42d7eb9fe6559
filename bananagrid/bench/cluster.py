"""``bananagrid bench --cluster``: tiles and hypothesis shards on a local Dask cluster.

Three measurements, each on a fresh ``LocalCluster`` (so that a worker's peak memory is its own
work's):

* **zarr**: a Butterly map on a ``side`` x ``side`` float32 grid at 1 m (65,536 x 65,536 = 16 GiB
  if dense) into a Zarr store, workers limited to ``memory_limit`` each: seconds, blocks and
  cells computed and skipped, the computed cells per second per core, and each worker's peak
  resident memory;
* **zarr-dense**: the same Butterly on ``DENSE_SIDE`` x ``DENSE_SIDE`` cells inside its ring, every
  block computed, against the in-memory rasterise of the same grid on one thread: a computed
  cell's cost into Zarr, for the cost model;
* **hypotheses**: ``hypotheses`` polar bananas on 64 x 64 framed grids (float32), sharded over
  the workers into a Zarr store, against the single-process batch on ``in_process`` of them on
  as many threads, per hypothesis.
"""

from __future__ import annotations

import math
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from ..domains.grid import Grid
from ..engine.batch import rasterise_batch
from ..engine.rasterise import rasterise
from ..engine.batch_shards import rasterise_batch_shards
from ..engine.cluster import dask_client
from ..engine.tiles import rasterise_tiles
from ..models.registry import MODEL_KINDS

__all__ = ["zarr_row", "dense_row", "hypotheses_row", "CLUSTER_SIDE", "DENSE_SIDE", "CLUSTER_CHUNK", "HYPOTHESES", "IN_PROCESS_HYPOTHESES"]

CLUSTER_SIDE = 65536
CLUSTER_CHUNK = 2048
HYPOTHESES = 1_000_000
IN_PROCESS_HYPOTHESES = 100_000
#: Side of the dense row's grid (every block computed; 1 GiB of float32).
DENSE_SIDE = 16384
#: The dense row's window (m): 320 m x 320 m on the ring of :data:`ZARR_MODEL`, so that no block
#: is skipped.
DENSE_WINDOW = dict(x=(440.0, 760.0), y=(-160.0, 160.0))
#: The Butterly of the zarr row (scene parameters): a 40 m x 20 m start, speeds 0.9, 1 and
#: 1.1 m/s for 10 min (a ring about 1.2 km across), centred on the grid: a small banana on a
#: basin-sized grid.
ZARR_MODEL = dict(mean=(0.0, 0.0), cov=[[1600.0, 300.0], [300.0, 400.0]], speeds=[0.9, 1.0, 1.1],
                  weights=[0.25, 0.5, 0.25], t=600.0)


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _tiles_to_zarr(model, grid: Grid, chunk: int, workers: int, memory_limit: str, directory) -> dict:
    """Rasterise ``model`` on ``grid`` in ``chunk`` x ``chunk`` float32 blocks into a Zarr store on a
    fresh local cluster (Warp warmed on every worker first); the store is removed afterwards."""
    work = Path(tempfile.mkdtemp(prefix="bananagrid-bench-", dir=directory))
    try:
        with dask_client(workers=workers, memory_limit=memory_limit) as client:
            client.run(lambda: rasterise_tiles(model, Grid.from_bounds(x=(0, 64), y=(0, 64), step=1.0), 64,
                                               dtype=np.float32).values.compute(scheduler="sync"))  # warm: Warp
            start = time.perf_counter()
            tiled = rasterise_tiles(model, grid, chunk, dtype=np.float32)
            planned = time.perf_counter() - start
            tiled.to_zarr(work / "map.zarr")
            seconds = time.perf_counter() - start
            peaks = sorted(client.run(_peak_rss_mib).values())
        stored = sum(p.stat().st_size for p in (work / "map.zarr").rglob("*") if p.is_file())
    finally:
        shutil.rmtree(work, ignore_errors=True)
    computed = int(tiled.provenance["cells_computed"])
    blocks, skipped = int(tiled.skipped.size), int(tiled.skipped.sum())
    cells = grid.nx * grid.ny
    return {
        "side": grid.nx, "chunk": chunk, "workers": workers, "memory_limit": memory_limit, "seconds": seconds,
        "plan_seconds": planned, "blocks": blocks, "blocks_skipped": skipped, "cells": cells,
        "cells_computed": computed, "cells_skipped": cells - computed, "store_mib": stored / 2**20,
        "worker_peak_rss_mib": peaks,
        "blocks_per_second_per_core": blocks / seconds / workers,
        "computed_cells_per_second_per_core": computed / seconds / workers,
    }


def _describe(row: dict) -> str:
    return (f"{row['seconds']:.1f} s ({row['plan_seconds']:.2f} s proving the bounds); "
            f"{row['blocks'] - row['blocks_skipped']:,} of {row['blocks']:,} blocks computed "
            f"({row['cells_computed']:,} cells), {row['blocks_skipped']:,} skipped ({row['cells_skipped']:,} cells); "
            f"store {row['store_mib']:.1f} MiB; worker peak RSS "
            + ", ".join(f"{p:.0f}" for p in row["worker_peak_rss_mib"]) + " MiB")


def zarr_row(*, side: int = CLUSTER_SIDE, chunk: int = CLUSTER_CHUNK, workers: int = 2,
             memory_limit: str = "4GiB", directory: str | None = None, log=print) -> dict:
    """Rasterise the Butterly of :data:`ZARR_MODEL` on ``side`` x ``side`` cells of 1 m into Zarr
    on a fresh local cluster: a small support on a huge grid (the store is removed afterwards)."""
    model = MODEL_KINDS["butterly"].build(ZARR_MODEL)
    half = side / 2.0
    row = _tiles_to_zarr(model, Grid.from_bounds(x=(-half, half), y=(-half, half), step=1.0), chunk, workers,
                         memory_limit, directory)
    log(f"zarr: {side:,} x {side:,} float32 Butterly (ring 1.2 km across) in {chunk} x {chunk} blocks on {workers} "
        f"workers ({memory_limit} each): " + _describe(row))
    return row


def dense_row(*, side: int = DENSE_SIDE, chunk: int = CLUSTER_CHUNK, workers: int = 2, memory_limit: str = "4GiB",
              directory: str | None = None, log=print) -> dict:
    """The same Butterly on ``side`` x ``side`` cells of :data:`DENSE_WINDOW` (every block computed)
    into Zarr on a fresh local cluster, against the in-memory rasterise of the same grid on one
    thread: what a computed cell costs end to end (kernel, compression, writing)."""
    model = MODEL_KINDS["butterly"].build(ZARR_MODEL)
    grid = Grid.from_bounds(**DENSE_WINDOW, step=(DENSE_WINDOW["x"][1] - DENSE_WINDOW["x"][0]) / side)
    row = _tiles_to_zarr(model, grid, chunk, workers, memory_limit, directory)
    rasterise(model, Grid.from_bounds(x=(0, 64), y=(0, 64), step=1.0), dtype=np.float32, threads=1)  # warm
    start = time.perf_counter()
    rasterise(model, grid, dtype=np.float32, threads=1)
    row["in_memory_seconds"] = time.perf_counter() - start
    row["in_memory_cells_per_second"] = row["cells"] / row["in_memory_seconds"]
    log(f"zarr-dense: {side:,} x {side:,} float32 cells inside the same ring in {chunk} x {chunk} blocks on {workers} "
        f"workers: " + _describe(row) + f"; {row['computed_cells_per_second_per_core'] / 1e6:.1f} M computed cells/s "
        f"per core into Zarr, against {row['in_memory_cells_per_second'] / 1e6:.1f} M/s for the in-memory rasterise "
        f"on one thread ({row['in_memory_seconds']:.1f} s)")
    return row


def _hypotheses(n: int, seed: int = 0) -> list:
    """``n`` polar bananas (Figure 1's noise) at speeds 100-300 m/s, anywhere in a 100 km square,
    any heading."""
    rng = np.random.default_rng(seed)
    v = rng.uniform(100.0, 300.0, n)
    x, y = rng.uniform(-5e4, 5e4, n), rng.uniform(-5e4, 5e4, n)
    h = rng.uniform(-math.pi, math.pi, n)
    polar = MODEL_KINDS["polar"]
    return [polar.build(dict(v0=float(v[k]), t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54,
                             origin=(float(x[k]), float(y[k])), heading=float(h[k]))) for k in range(n)]


def hypotheses_row(*, hypotheses: int = HYPOTHESES, in_process: int = IN_PROCESS_HYPOTHESES, workers: int = 2,
                   memory_limit: str = "4GiB", directory: str | None = None, log=print) -> dict:
    """``hypotheses`` polar bananas on 64 x 64 grids, float32, sharded over ``workers`` into Zarr,
    against the single-process batch of ``in_process`` of them on ``workers`` threads."""
    start = time.perf_counter()
    models = _hypotheses(hypotheses)
    built = time.perf_counter() - start
    start = time.perf_counter()
    rasterise_batch(models[:in_process], dtype=np.float32, threads=workers)
    local = time.perf_counter() - start
    work = Path(tempfile.mkdtemp(prefix="bananagrid-bench-", dir=directory))
    try:
        with dask_client(workers=workers, memory_limit=memory_limit) as client:
            client.run(lambda: rasterise_batch(models[:8], dtype=np.float32, threads=1))  # warm: Warp
            start = time.perf_counter()
            rasterise_batch_shards(models, dtype=np.float32).to_zarr(work / "batch.zarr")
            sharded = time.perf_counter() - start
            peaks = sorted(client.run(_peak_rss_mib).values())
        stored = sum(p.stat().st_size for p in (work / "batch.zarr").rglob("*") if p.is_file())
    finally:
        shutil.rmtree(work, ignore_errors=True)
    row = {
        "hypotheses": hypotheses, "in_process": in_process, "workers": workers, "build_seconds": built,
        "sharded_seconds": sharded, "in_process_seconds": local,
        "sharded_per_second": hypotheses / sharded, "in_process_per_second": in_process / local,
        "store_gib": stored / 2**30, "worker_peak_rss_mib": peaks,
    }
    log(f"hypotheses: {hypotheses:,} polar bananas on 64 x 64 grids (float32) sharded over {workers} workers into "
        f"Zarr ({stored / 2**30:.1f} GiB): {sharded:.1f} s, {hypotheses / sharded:,.0f} per s; the single-process "
        f"batch of {in_process:,} on {workers} threads (in memory): {local:.1f} s, {in_process / local:,.0f} per s "
        f"(models built in {built:.1f} s); worker peak RSS " + ", ".join(f"{p:.0f}" for p in peaks) + " MiB")
    return row
