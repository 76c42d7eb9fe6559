"""The grid kernel of a model over a whole grid or a block of one: one context, one binding."""

from __future__ import annotations

import functools
import math

import numpy as np

from ..domains.grid import Grid
from ..protocol import DensityModel
from .precision import working_dtype
from .warp_runtime import WarpContext, row_sums

__all__ = ["GridExtent", "grid_context", "grid_block", "SERIAL_CELLS"]

#: Blocks of at most this many cells run as one band on the calling thread: handing bands to
#: the pool's threads and waiting for them costs more than the kernel saves there (a
#: 100 x 100 polar map took 0.34 ms on one thread, 0.62 ms on two; ``bananagrid bench
#: --small``). The values are the same bits either way (each row alone, summed by row).
SERIAL_CELLS = 1 << 15

#: Small blocks whose cell-centre arrays are kept (at most 2 * SERIAL_CELLS values each).
CENTRES_KEPT = 32


class GridExtent:
    """The cell centres of a grid, seen from an origin.

    ``row_cells`` is how many cells of a row one launch covers: the whole row (``grid.nx``), or
    a block's columns when the grid is computed in blocks (a row sweep's cost is per launch row).
    """

    def __init__(self, grid: Grid, row_cells: int | None = None):
        self.grid = grid
        self.row_cells = grid.nx if row_cells is None else max(1, min(int(row_cells), grid.nx))

    def radii(self, origin) -> tuple[float, float]:
        """Least and greatest distance from ``origin`` to the grid's cell centres."""
        ox, oy = origin
        g = self.grid
        # the first and last of Grid.x and Grid.y, by their arithmetic (the same floats), not all of them
        x0, x1 = (g.origin[0] + 0.5 * g.dx) - ox, (g.origin[0] + (g.nx - 0.5) * g.dx) - ox
        y0, y1 = (g.origin[1] + 0.5 * g.dy) - oy, (g.origin[1] + (g.ny - 0.5) * g.dy) - oy
        near_x = 0.0 if x0 <= 0.0 <= x1 else min(abs(x0), abs(x1))
        near_y = 0.0 if y0 <= 0.0 <= y1 else min(abs(y0), abs(y1))
        far_x, far_y = max(abs(x0), abs(x1)), max(abs(y0), abs(y1))
        return math.hypot(near_x, near_y), math.hypot(far_x, far_y)


def grid_context(model: DensityModel, grid: Grid, dtype=np.float64, device: str = "cpu", threads=None):
    """``(asked dtype, context, extent)`` of a rasterise of ``model`` on ``grid``: the kernels run in
    the working dtype of the whole grid (:func:`~bananagrid.engine.precision.working_dtype`), so
    that a tile of it computes exactly what the whole grid computes there."""
    ctx = WarpContext(dtype, device, threads)
    asked, extent = ctx.dtype, GridExtent(grid)
    if asked != np.float32:  # float64 computes in float64 wherever the grid lies
        return asked, ctx, extent
    working = working_dtype(model, asked, extent.radii((0.0, 0.0))[1])
    if working != asked:
        ctx = WarpContext(working, device, threads)
    return asked, ctx, extent


def _make_centres(ctx: WarpContext, grid: Grid, rows, cols):
    """Device arrays of the cell centres of columns ``cols`` and rows ``rows`` of ``grid``."""
    return ctx.host_array(grid.x[cols[0]:cols[1]]), ctx.host_array(grid.y[rows[0]:rows[1]])


@functools.lru_cache(maxsize=CENTRES_KEPT)
def _centres(grid: Grid, rows, cols, dtype, device):
    """:func:`_make_centres`, kept for the last CENTRES_KEPT small blocks (a grid is frozen and
    the kernels only read them; making them cost about 15 us a call)."""
    return _make_centres(WarpContext(dtype, device), grid, rows, cols)


def grid_block(ctx: WarpContext, binding, grid: Grid, rows: tuple[int, int] | None = None,
               cols: tuple[int, int] | None = None, *, with_sum: bool = False):
    """The grid kernel of ``binding`` at the cell centres of rows ``rows[0]:rows[1]`` and
    columns ``cols[0]:cols[1]`` of ``grid`` (default all), in the context's dtype.

    With ``with_sum``, returns ``(values, total)``: ``total`` the float64 sum of the values,
    the same bits for any number of threads: each row is summed on its own (by the kernel as it
    computes the row where the family's grid kernel does, ``DensityKernels.row_sums``; else by
    :func:`~bananagrid.engine.warp_runtime.row_sums`, on the CPU by the thread that computed its
    band, right after the launch, in parallel and while the band is in that core's cache: one
    serial pass over the grid after the kernel held the 1 -> 2 thread speedup of the fastest
    kernels to 1.5x), and the rows' sums are added exactly (``math.fsum``), so neither the
    bands' boundaries nor their order can change a bit of it.

    Each cell's value depends on its coordinates only, except for kernels that work in tiles of
    ``binding.kernels.tile_rows`` cells (Butterly): their bands start on multiples of the tile
    side and they take the grid's steps, so that a block whose corner lies on such a multiple
    computes the same tiles as the whole grid.
    """
    rows = (0, grid.ny) if rows is None else (int(rows[0]), int(rows[1]))
    cols = (0, grid.nx) if cols is None else (int(cols[0]), int(cols[1]))
    ny, nx = rows[1] - rows[0], cols[1] - cols[0]
    family = binding.kernels
    ctx.load(family.grid)
    if ny * nx <= SERIAL_CELLS:  # a tracker's grid again and again: its centres' arrays are kept
        xs, ys = _centres(grid, rows, cols, ctx.dtype, ctx.device)
    else:
        xs, ys = _make_centres(ctx, grid, rows, cols)
    if ctx.cpu:
        values = np.empty((ny, nx), dtype=ctx.dtype)  # every cell is written by the kernel
        out = ctx.shared(values)
    else:
        out = ctx.zeros((ny, nx))
    # a kernel that sums each row as it computes it (``DensityKernels.row_sums``, CPU kernels): its
    # sums, instead of a pass over the grid after the launch
    summed = ctx.cpu and family.row_sums
    kernel_sums = np.empty(ny) if summed else None
    outputs = [out, ctx.shared(kernel_sums, dtype=np.float64)] if summed else [out]

    # whole rows per thread on the CPU, one cell per thread on a GPU
    columns = nx if ctx.cpu else 1
    serial = ctx.cpu and ny * nx <= SERIAL_CELLS
    if serial:
        bands = [(0, ny)]  # one launch on this thread; a band from row 0 is aligned to any tile
    else:
        bands = ctx.bands(ny, family.bands_per_thread, align=max(1, family.tile_rows))
    if family.scratch_width:  # one work row per band: a band's rows run one after another
        scratch = ctx.empty((len(bands), family.scratch_width))
        quads = ctx.empty((len(bands), family.quad_width), dtype=ctx.vector(4))
        band_of = {r0: k for k, (r0, _) in enumerate(bands)}
    tile = (family.tile_rows if ctx.cpu else 1) if family.tile_rows else None
    sums = np.empty(ny) if with_sum else None

    def launch_band(r0, r1):
        if tile is None:
            dim, head = (r1 - r0, -(-nx // columns)), [xs, ys, r0, columns]
        else:
            dim = (-(-(r1 - r0) // tile), -(-nx // columns))
            head = [xs, ys, r0, r1, tile, columns, ctx.scalar(grid.dx), ctx.scalar(grid.dy)]
        extra = [scratch, quads, band_of[r0]] if family.scratch_width else []
        # a small grid again and again (kept centres, a model's kept parameters): replayed, with
        # the outputs and any work rows (made for each call) packed afresh
        fresh = [-k for k in range(1, len(outputs) + 1)]
        if family.scratch_width:
            fresh += [len(head) + 1, len(head) + 2]
        (ctx.launch_kept if serial else ctx.launch)(family.grid, dim=dim,
                                                    inputs=[*head, binding.params, *extra, *outputs], fresh=fresh)
        if with_sum and ctx.cpu and not summed:  # a CPU launch has finished when it returns
            sums[r0:r1] = row_sums(values[r0:r1])

    ctx.run_bands(launch_band, bands)
    ctx.synchronize()
    if not ctx.cpu:
        values = out.numpy()
    if not with_sum:
        return values
    if summed:
        sums = kernel_sums
    elif not ctx.cpu:
        sums = row_sums(values)
    return values, math.fsum(sums.tolist())  # Python floats: fsum converts NumPy's one by one
