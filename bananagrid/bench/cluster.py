"""``bananagrid bench --cluster``: tiles and hypothesis shards on a local Dask cluster.

Two measurements, each on a fresh ``LocalCluster`` (so that a worker's peak memory is its own
work's):

* **zarr**: a Butterly map on a ``side`` x ``side`` float32 grid at 1 m (65,536 x 65,536 = 16 GiB
  if dense) into a Zarr store, workers limited to ``memory_limit`` each: seconds, blocks and
  cells computed and skipped, the computed cells per second per core, and each worker's peak
  resident memory;
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
from ..engine.batch_shards import rasterise_batch_shards
from ..engine.cluster import dask_client
from ..engine.tiles import rasterise_tiles
from ..models.registry import MODEL_KINDS

__all__ = ["zarr_row", "hypotheses_row", "CLUSTER_SIDE", "CLUSTER_CHUNK", "HYPOTHESES", "IN_PROCESS_HYPOTHESES"]

CLUSTER_SIDE = 65536
CLUSTER_CHUNK = 2048
HYPOTHESES = 1_000_000
IN_PROCESS_HYPOTHESES = 100_000
#: The Butterly of the zarr row (scene parameters): a 40 m x 20 m start, speeds 0.9, 1 and
#: 1.1 m/s for 10 min (a ring about 1.2 km across), centred on the grid: a small banana on a
#: basin-sized grid.
ZARR_MODEL = dict(mean=(0.0, 0.0), cov=[[1600.0, 300.0], [300.0, 400.0]], speeds=[0.9, 1.0, 1.1],
                  weights=[0.25, 0.5, 0.25], t=600.0)


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def zarr_row(*, side: int = CLUSTER_SIDE, chunk: int = CLUSTER_CHUNK, workers: int = 2,
             memory_limit: str = "4GiB", directory: str | None = None, log=print) -> dict:
    """Rasterise the Butterly of :data:`ZARR_MODEL` on ``side`` x ``side`` cells of 1 m into Zarr
    on a fresh local cluster; the store is removed afterwards."""
    model = MODEL_KINDS["butterly"].build(ZARR_MODEL)
    half = side / 2.0
    grid = Grid.from_bounds(x=(-half, half), y=(-half, half), step=1.0)
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
    blocks = int(tiled.skipped.size)
    skipped = int(tiled.skipped.sum())
    row = {
        "side": side, "chunk": chunk, "workers": workers, "memory_limit": memory_limit, "seconds": seconds,
        "plan_seconds": planned, "blocks": blocks, "blocks_skipped": skipped, "cells": side * side,
        "cells_computed": computed, "cells_skipped": side * side - computed, "store_mib": stored / 2**20,
        "worker_peak_rss_mib": peaks,
        "blocks_per_second_per_core": blocks / seconds / workers,
        "computed_cells_per_second_per_core": computed / seconds / workers,
    }
    log(f"zarr: {side:,} x {side:,} float32 Butterly (ring 1.2 km across) in {chunk} x {chunk} blocks on {workers} workers "
        f"({memory_limit} each): {seconds:.1f} s ({planned:.2f} s proving the bounds); {blocks - skipped:,} of "
        f"{blocks:,} blocks computed ({computed:,} cells), {skipped:,} skipped ({side * side - computed:,} cells); "
        f"store {stored / 2**20:.1f} MiB; worker peak RSS " + ", ".join(f"{p:.0f}" for p in peaks) + " MiB")
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
