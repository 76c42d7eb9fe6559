"""Tiled rasterising on Dask: a grid too large for one process, computed block by block.

:func:`rasterise_tiles` cuts a :class:`~bananagrid.Grid` into blocks of ``chunks = (rows,
columns)`` cells and returns a :class:`~bananagrid.results.TiledRaster` whose ``values`` are a
lazy ``dask.array``: each block is one task that runs the model's own grid kernel (the same
binding, built from the whole grid's extent and working dtype) on the block's cell centres, so
its values are bit-identical to those of :func:`bananagrid.rasterise` on the whole grid. The
tasks run wherever Dask runs them (its threads by default, a ``distributed`` cluster's worker
processes under a ``Client``); a worker process initialises Warp once and loads the kernels from
Warp's on-disk cache, and keeps the last few bindings it built (:func:`block_values`).

**Only the support costs.** Before any task runs, the model proves for every block an upper
bound of its density there (:meth:`~bananagrid.protocol.DensityModel.density_bound`); a block
whose bound is at most the floor (:meth:`~bananagrid.protocol.DensityModel.density_floor`, 1e-13
of the peak) is a block of zeros that runs no kernel (and that a Zarr store does not write).

Dask, distributed and Zarr are the ``cluster`` extra, loaded when first used.
"""

from __future__ import annotations

import math
import sys
import threading
import uuid
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..domains.grid import Grid
from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..protocol import DensityModel
from ..results import TiledRaster
from ..validate import BananagridError, show
from .cluster import minimum_memory_limit, worker_need
from .grid_cells import probability_raster, probability_work
from .grid_kernel import GridExtent, grid_block, grid_context
from .memory import format_bytes
from .points import check_finite, check_model
from .warp_runtime import WarpContext, default_threads
from .work import check_work

__all__ = ["rasterise_tiles", "TilePlan", "block_values", "check_chunks", "check_cluster_memory", "tile_bounds",
           "DEFAULT_CHUNK"]

#: Default side of a block, cells: 1024 x 1024 float32 is 4 MiB a block (8 MiB float64), a few
#: milliseconds of Dask's overhead against tenths of a second of a kernel.
DEFAULT_CHUNK = 1024

#: Bindings a process keeps (a worker computes many blocks of one grid in a row).
_KEPT_BINDINGS = 4
_bindings: OrderedDict = OrderedDict()
_bindings_lock = threading.Lock()


def check_chunks(chunks, grid: Grid, align: int = 1) -> tuple[int, int]:
    """``chunks`` (an int for both axes, or ``(rows, columns)``) as two ints >= 1, each a multiple
    of ``align`` (the kernel's tile side) where the grid has more than one block in that axis."""
    if isinstance(chunks, (int, np.integer)) and not isinstance(chunks, bool):
        chunks = (chunks, chunks)
    if not (isinstance(chunks, (tuple, list)) and len(chunks) == 2
            and all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) and c >= 1 for c in chunks)):
        raise BananagridError(f"chunks = {show(chunks)}: expected (rows, columns), two integers >= 1")
    out = []
    for name, c, n in (("rows", int(chunks[0]), grid.ny), ("columns", int(chunks[1]), grid.nx)):
        if c < n and c % align:
            raise BananagridError(
                f"chunks = {show(tuple(chunks))}: {name} {c} is not a multiple of {align}; this model's kernel "
                f"works in tiles of {align} x {align} cells, so blocks must start on them to equal the whole grid"
            )
        out.append(min(c, n))
    return out[0], out[1]


def check_cluster_memory(chunks: tuple[int, int], dtype, computed_in) -> None:
    """Refuse blocks of ``chunks`` cells that the workers of the current ``distributed`` client
    (if one is open) cannot compute within their memory limits (:func:`~bananagrid.engine.cluster.worker_need`):
    Dask would pause such a worker, or kill and restart it, block after block."""
    distributed = sys.modules.get("distributed")
    if distributed is None:  # no client can be open
        return
    try:
        client = distributed.default_client()
    except ValueError:
        return
    if client.asynchronous:  # its cached information has no workers; the caller awaits its own checks
        return
    limits = [w.get("memory_limit") or 0 for w in client.scheduler_info()["workers"].values()]
    limits = [limit for limit in limits if limit > 0]  # 0: no limit
    if not limits:
        return
    need = worker_need(chunks, dtype, computed_in)
    minimum = minimum_memory_limit(need)
    if min(limits) < minimum:
        raise BananagridError(
            f"chunks = {show(tuple(chunks))}: a worker needs about {format_bytes(need)} for a block of "
            f"{chunks[0]} x {chunks[1]} cells, so a memory limit of at least {format_bytes(minimum)}; this cluster's "
            f"workers have {format_bytes(min(limits))}: give them more memory or use smaller chunks"
        )


def tile_bounds(grid: Grid, rows: tuple[int, int], cols: tuple[int, int]) -> tuple[float, float, float, float]:
    """``(x0, x1, y0, y1)``: the rectangle of the cell centres of rows ``rows[0]:rows[1]`` and
    columns ``cols[0]:cols[1]`` (the points the kernel evaluates)."""
    x = grid.origin[0] + (np.array([cols[0], cols[1] - 1]) + 0.5) * grid.dx
    y = grid.origin[1] + (np.array([rows[0], rows[1] - 1]) + 0.5) * grid.dy
    return float(x[0]), float(x[1]), float(y[0]), float(y[1])


def _edges(n: int, chunk: int) -> list[tuple[int, int]]:
    return [(a, min(a + chunk, n)) for a in range(0, n, chunk)]


@dataclass(frozen=True)
class TilePlan:
    """What every block of one tiled rasterise shares (sent once to each worker).

    Attributes
    ----------
    model : DensityModel
    grid : Grid
    dtype, computed_in : str
        The values' dtype, and the kernels' (the whole grid's working dtype).
    device : str
    chunks : (int, int)
        Block shape, cells.
    skipped : ndarray of bool, (blocks in y, blocks in x)
        Blocks whose proved bound is at most the floor: zeros, no kernel.
    token : str
        Names the plan in a worker's cache of bindings.
    quantity : {"density", "probability"}
        The densities at the cell centres, or each cell's probability (the cell rules of
        ``rasterise(..., quantity="probability")`` on the block's cells).
    """

    model: DensityModel
    grid: Grid
    dtype: str
    computed_in: str
    device: str
    chunks: tuple[int, int]
    skipped: np.ndarray
    token: str
    quantity: str = "density"

    def block(self, i: int, j: int) -> np.ndarray:
        """Block ``(i, j)``'s values: zeros if skipped, else the grid kernel's."""
        (r0, r1), (c0, c1) = _edges(self.grid.ny, self.chunks[0])[i], _edges(self.grid.nx, self.chunks[1])[j]
        if self.skipped[i, j]:  # one zero seen as the block: no memory, nothing to fill or page in
            return np.broadcast_to(np.zeros((), dtype=self.dtype), (r1 - r0, c1 - c0))
        return block_values(self, (r0, r1), (c0, c1))


def block_values(plan: TilePlan, rows: tuple[int, int], cols: tuple[int, int]) -> np.ndarray:
    """The grid kernel over rows ``rows[0]:rows[1]`` and columns ``cols[0]:cols[1]`` of the
    plan's grid, on one thread (Dask runs the blocks in parallel), with this process's binding
    of the plan (built on first use: Warp initialised once, kernels from its cache); for cell
    probabilities, the cell rules on the block's cells (each cell's rule is its own: a block's
    cells are the whole grid's to rounding, measured within 1e-14 of the largest cell for the
    polar banana, CAT, Butterly and a bearing fix; not to the bit: sums run in another order)."""
    if plan.quantity == "probability":
        g = plan.grid
        block_grid = Grid(origin=(g.origin[0] + cols[0] * g.dx, g.origin[1] + rows[0] * g.dy), dx=g.dx, dy=g.dy,
                          nx=cols[1] - cols[0], ny=rows[1] - rows[0])
        values = probability_raster(plan.model, block_grid, dtype=plan.computed_in, device=plan.device, threads=1).values
        return values.astype(plan.dtype, copy=False)
    with _bindings_lock:
        kept = _bindings.get(plan.token)
        if kept is not None:
            _bindings.move_to_end(plan.token)
    if kept is None:
        ctx = WarpContext(plan.computed_in, plan.device, 1)
        _, _, extent = grid_context(plan.model, plan.grid, plan.computed_in, plan.device, 1)
        kept = (ctx, plan.model.bind(ctx, extent, grid=True))
        with _bindings_lock:
            _bindings[plan.token] = kept
            while len(_bindings) > _KEPT_BINDINGS:
                _bindings.popitem(last=False)
    ctx, binding = kept
    values = grid_block(ctx, binding, plan.grid, rows, cols)
    check_finite(values, plan.model)
    return values.astype(plan.dtype, copy=False)


def _block_task(plan: TilePlan, block_info=None) -> np.ndarray:
    i, j = block_info[None]["chunk-location"]
    return plan.block(i, j)


def rasterise_tiles(model: DensityModel, grid: Grid, chunks=DEFAULT_CHUNK, *, dtype=np.float64, device: str = "cpu",
                    skip: bool = True, max_seconds: float | None = None, quantity: str = "density") -> TiledRaster:
    """The density of ``model`` at the cell centres of ``grid`` (or each cell's probability),
    lazily, in blocks of ``chunks``.

    Parameters
    ----------
    model : DensityModel
    grid : Grid
        Up to :data:`~bananagrid.domains.grid.MAX_TILED_CELLS` cells.
    chunks : int or (int, int), default 1024
        Block shape ``(rows, columns)`` (an int for both). For a kernel that works in tiles
        (Butterly: 32 x 32), a multiple of the tile side.
    dtype, device
        As for :func:`bananagrid.rasterise`; the kernels run in the whole grid's working dtype.
    skip : bool, default True
        Leave at 0, without computing, the blocks where the model proves its density at most
        its floor (``model.density_floor()``). False computes every block.
    max_seconds : float, optional
        Limit on the estimated computing of the blocks that are not skipped, wall-clock seconds
        on this machine's cores (default one hour; checked before anything runs).
    quantity : {"density", "probability"}, default "density"
        ``"probability"``: each cell's probability by the cell rules of ``bananagrid.rasterise(
        model, grid, quantity="probability")``, in float64 sums; a skipped block is 0 where the
        cells hold at most the floor times the cell's area.

    Returns
    -------
    TiledRaster
        ``values``: a ``dask.array`` of shape ``(ny, nx)`` in blocks of ``chunks``, equal block
        for block to ``bananagrid.rasterise(model, grid).values`` (bit for bit where computed;
        skipped blocks are 0 where the whole grid has values at most the floor).
    """
    da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    dask = require("dask", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid.Grid")
    check_model(model)
    if quantity not in ("density", "probability"):
        raise BananagridError(f"quantity = {show(quantity)}: expected 'density' or 'probability'")
    asked, ctx, extent = grid_context(model, grid, dtype, device, 1)
    binding = model.bind(ctx, extent, grid=True)  # the provenance, and the kernel's tile side
    cy, cx = check_chunks(chunks, grid, max(1, binding.kernels.tile_rows))
    row_edges, col_edges = _edges(grid.ny, cy), _edges(grid.nx, cx)
    floor = model.density_floor() if skip else -math.inf
    skipped = np.zeros((len(row_edges), len(col_edges)), dtype=bool)
    if skip:
        for i, rows in enumerate(row_edges):
            for j, cols in enumerate(col_edges):
                skipped[i, j] = model.density_bound(*tile_bounds(grid, rows, cols)) <= floor
    sizes_y = np.diff([r[0] for r in row_edges] + [grid.ny])
    sizes_x = np.diff([c[0] for c in col_edges] + [grid.nx])
    computed = int(np.sum(np.outer(sizes_y, sizes_x)[~skipped]))
    if ctx.cpu:
        core_seconds = (probability_work(model, grid)[0] * computed / (grid.nx * grid.ny) if quantity == "probability"
                        else model.work_estimate(computed, GridExtent(grid, row_cells=cx)))
        check_work(core_seconds, default_threads(), f"{type(model).__name__}: {computed:,} cells in tiles",
                   limit=max_seconds, option="max_seconds=S")
    check_cluster_memory((cy, cx), asked, ctx.dtype)
    plan = TilePlan(model, grid, asked.name, ctx.dtype.name, ctx.device, (cy, cx), skipped, uuid.uuid4().hex, quantity)
    values = da.map_blocks(
        _block_task, dask.delayed(plan, pure=True), chunks=(tuple(sizes_y), tuple(sizes_x)), dtype=asked,
        meta=np.empty((0, 0), dtype=asked), name=f"bananagrid-{type(model).__name__.lower()}-{plan.token[:8]}",
    )
    if quantity == "probability" and skip:
        floor *= grid.cell_area  # a cell holds at most the bound times its area
    provenance = {
        **model.parameters(),
        "quantity": quantity,
        "kernel": binding.kernel_name,
        "dtype": asked.name,
        "computed_in": ctx.dtype.name,
        "device": ctx.device,
        "chunks": [cy, cx],
        "tiles": int(skipped.size),
        "tiles_skipped": int(skipped.sum()),
        "cells_computed": computed,
        "zero_at_or_below": floor if skip else None,
        **binding.notes,
    }
    return TiledRaster(values=values, grid=grid, chunks=(cy, cx), skipped=skipped, floor=floor, provenance=provenance,
                       quantity=quantity)
