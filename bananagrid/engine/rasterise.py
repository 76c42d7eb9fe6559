"""``rasterise``: a model's density on a grid (or its cells on a polar lattice)."""

from __future__ import annotations

import math
import time

import numpy as np

from ..domains.grid import Grid
from ..domains.polar_lattice import PolarLattice
from ..protocol import DensityModel
from ..results import PolarRaster, Raster
from ..validate import BananagridError
from .memory import RASTERISE_BYTES_PER_CELL, check_memory
from .points import check_finite, check_model
from .precision import working_dtype
from .work import check_work
from .grid_cells import probability_raster
from .polar_cells import rasterise_lattice
from .warp_runtime import WarpContext

__all__ = ["rasterise", "GridExtent", "QUANTITIES"]


class GridExtent:
    """The cell centres of a grid, seen from an origin."""

    def __init__(self, grid: Grid):
        self.grid = grid

    def radii(self, origin) -> tuple[float, float]:
        """Least and greatest distance from ``origin`` to the grid's cell centres."""
        ox, oy = origin
        x0, x1 = self.grid.x[0] - ox, self.grid.x[-1] - ox
        y0, y1 = self.grid.y[0] - oy, self.grid.y[-1] - oy
        near_x = 0.0 if x0 <= 0.0 <= x1 else min(abs(x0), abs(x1))
        near_y = 0.0 if y0 <= 0.0 <= y1 else min(abs(y0), abs(y1))
        far_x, far_y = max(abs(x0), abs(x1)), max(abs(y0), abs(y1))
        return math.hypot(near_x, near_y), math.hypot(far_x, far_y)


#: What :func:`rasterise` computes on a grid.
QUANTITIES = ("density", "probability")


def rasterise(model: DensityModel, grid: Grid | PolarLattice, *, quantity: str = "density", dtype=np.float64,
              device: str = "cpu", threads=None, max_seconds: float | None = None) -> Raster | PolarRaster:
    """Density of ``model`` at the cell centres of ``grid`` or the probability of each cell, or
    both on a polar lattice.

    With a :class:`~bananagrid.PolarLattice` the result is a :class:`~bananagrid.PolarRaster`:
    densities per (m, rad) at the cell centres and the probability integrated over each
    (range, bearing) cell (see :func:`bananagrid.engine.polar_cells.rasterise_lattice`).

    Parameters
    ----------
    model : DensityModel
        Any model that follows :class:`bananagrid.protocol.DensityModel` (every kind of
        ``bananagrid.MODEL_KINDS``, or one of your own).
    grid : Grid or PolarLattice
    quantity : {"density", "probability"}, default "density"
        On a grid: ``"density"``, the density per m^2 at each cell centre; ``"probability"``,
        the probability that the target is in each cell (a :class:`Raster` of ``quantity ==
        "probability"`` whose values sum to its ``mass``, the probability inside the grid, never
        above 1 but by rounding). CAT (without heading noise) computes them exactly in the
        acceleration (``CAT.grid_cells``), caustic cells included; every other model by a
        Gauss-Legendre rule over sub-cells no larger than its length scale, in polar coordinates
        about a polar density's origin (:mod:`bananagrid.engine.grid_cells`). A polar lattice
        always gives both.
    dtype : float32 or float64, default float64
        Precision of ``values``, and of the kernel where float32 coordinates resolve the model
        (:func:`bananagrid.engine.precision.working_dtype`: elsewhere, far from the world
        origin, float32 is computed in float64 and rounded; ``provenance["computed_in"]``
        says which); cell probabilities are summed in float64 and returned in ``dtype``.
    device : str, default "cpu"
        Warp device; "cuda" where present runs the same kernel source.
    threads : int, optional
        CPU worker threads (default: every core). Rows are split into bands, each a launch; a
        Warp CPU launch uses one core and releases the GIL, so bands run in parallel. Results do
        not depend on the number of threads.
    max_seconds : float, optional
        Wall-clock seconds of estimated computing allowed (default
        :data:`bananagrid.engine.work.DEFAULT_MAX_SECONDS`, one hour; ``math.inf`` for no
        limit). The model's estimate (``work_estimate``) is checked before any launch on the CPU.

    Returns
    -------
    Raster
        Raw (not normalised) densities per m^2, with the captured mass and provenance
        (a PolarRaster for a PolarLattice).
    """
    if quantity not in QUANTITIES:
        raise BananagridError(f"quantity = {quantity!r}: expected one of {', '.join(map(repr, QUANTITIES))}")
    if isinstance(grid, PolarLattice):
        return rasterise_lattice(model, grid, dtype=dtype, device=device, threads=threads, max_seconds=max_seconds)
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid.Grid")
    check_model(model)
    if quantity == "probability":
        return probability_raster(model, grid, dtype=dtype, device=device, threads=threads, max_seconds=max_seconds)
    asked = WarpContext(dtype, device, threads).dtype
    extent = GridExtent(grid)
    ctx = WarpContext(working_dtype(model, asked, extent.radii((0.0, 0.0))[1]), device, threads)
    if ctx.cpu:  # an allocation the machine cannot give would abort the process without a word
        what = f"rasterise on a grid of {grid.nx} x {grid.ny} = {grid.nx * grid.ny:,} cells"
        check_memory(grid.nx * grid.ny, RASTERISE_BYTES_PER_CELL, what)
        check_work(model.work_estimate(grid.nx * grid.ny, extent), ctx.launch_threads,
                   f"{type(model).__name__}: {what}", limit=max_seconds, option="max_seconds=S")
    start = time.perf_counter()
    binding = model.bind(ctx, extent, grid=True)
    ctx.load(binding.grid_kernel)
    xs = ctx.array(grid.x)
    ys = ctx.array(grid.y)
    if ctx.cpu:
        values = np.empty(grid.shape, dtype=ctx.dtype)  # every cell is written by the kernel
        out = ctx.shared(values)
    else:
        out = ctx.zeros(grid.shape)

    # row-looping kernels take whole rows per thread on the CPU, one cell per thread on a GPU
    columns = (grid.nx if ctx.cpu else 1) if binding.row_loop else None
    bands = ctx.bands(grid.ny, binding.bands_per_thread)
    scratch, quads = None, None
    if binding.scratch_width:  # one work row per band: a band's rows run one after another
        scratch = ctx.empty((len(bands), binding.scratch_width))
        band_of = {r0: k for k, (r0, _) in enumerate(bands)}
    if binding.quad_width:
        quads = ctx.empty((len(bands), binding.quad_width), dtype=ctx.vector(4))
    rows = (binding.tile_rows if ctx.cpu else 1) if binding.tile_rows else None

    def launch_band(r0, r1):
        if columns is None:
            dim, head = (r1 - r0, grid.nx), [xs, ys, r0]
        elif rows is None:
            dim, head = (r1 - r0, -(-grid.nx // columns)), [xs, ys, r0, columns]
        else:
            dim, head = (-(-(r1 - r0) // rows), -(-grid.nx // columns)), [xs, ys, r0, r1, rows, columns]
        extra = [] if scratch is None else [scratch] + ([] if quads is None else [quads]) + [band_of[r0]]
        ctx.launch(binding.grid_kernel, dim=dim, inputs=[*head, *binding.params, *extra, out])

    ctx.run_bands(launch_band, bands)
    ctx.synchronize()
    if not ctx.cpu:
        values = out.numpy()
    seconds = time.perf_counter() - start
    check_finite(values, model)
    values = values.astype(asked, copy=False)
    mass = float(np.sum(values, dtype=np.float64) * grid.cell_area)
    provenance = {
        **model.parameters(),
        "kernel": binding.kernel_name,
        "dtype": asked.name,
        "computed_in": ctx.dtype.name,
        "device": ctx.device,
        "threads": ctx.launch_threads,
        "seconds": seconds,
        **binding.notes,
    }
    return Raster(values=values, grid=grid, mass=mass, normalised=False, provenance=provenance)
