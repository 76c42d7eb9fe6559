"""A model's densities at the cell centres of a grid: one band of rows per launch on the
context's threads, the captured mass summed row by row (exactly in any thread count), float32
narrowed from float64 where float32 coordinates do not resolve the model
(:mod:`bananagrid.engine.precision`)."""

from __future__ import annotations

import math
import time

import numpy as np

from ..domains.grid import Grid
from ..protocol import DensityModel
from ..results import Raster
from ..validate import BananagridError
from .grid_kernel import grid_block, grid_context
from .memory import RASTERISE_BYTES_PER_CELL, check_memory
from .points import check_finite
from .work import check_work

__all__ = ["density_raster", "narrow"]

#: The kernels' dtypes' names (NumPy's ``dtype.name`` costs about 3 us a call).
_NAMES = {np.dtype(np.float32): "float32", np.dtype(np.float64): "float64"}


def density_raster(model: DensityModel, grid: Grid, *, dtype=np.float64, device: str = "cpu", threads=None,
                   max_seconds: float | None = None) -> Raster:
    """Raw (not normalised) densities per m^2 of ``model`` at the cell centres of ``grid``, with the
    captured mass and provenance (see :func:`bananagrid.rasterise`), after the memory and work the
    grid needs are checked."""
    asked, ctx, extent = grid_context(model, grid, dtype, device, threads)
    if ctx.cpu:  # an allocation the machine cannot give would abort the process without a word
        what = f"rasterise on a grid of {grid.nx} x {grid.ny} = {grid.nx * grid.ny:,} cells"
        check_memory(grid.nx * grid.ny, RASTERISE_BYTES_PER_CELL, what)
        check_work(model.work_estimate(grid.nx * grid.ny, extent), ctx.launch_threads,
                   f"{type(model).__name__}: {what}", limit=max_seconds, option="max_seconds=S")
    start = time.perf_counter()
    binding = model.bind(ctx, extent, grid=True)
    values, total = grid_block(ctx, binding, grid, with_sum=True)
    seconds = time.perf_counter() - start
    if not math.isfinite(total):
        check_finite(values, model)
    if asked != ctx.dtype:  # float32 asked, computed in float64 (engine.precision)
        values = narrow(values, asked, total, model)
    mass = total * grid.cell_area
    provenance = {
        **model.parameters(),
        "kernel": binding.kernel_name,
        "dtype": _NAMES[asked],
        "computed_in": _NAMES[ctx.dtype],
        "device": ctx.device,
        "threads": ctx.launch_threads,
        "seconds": seconds,
        **binding.notes,
    }
    return Raster(values=values, grid=grid, mass=mass, normalised=False, provenance=provenance)


def narrow(values: np.ndarray, dtype: np.dtype, total: float, model: DensityModel) -> np.ndarray:
    """``values`` cast to ``dtype``; an error, not inf, where a density exceeds its range
    (checked only when their sum ``total`` does)."""
    if total <= np.finfo(dtype).max:
        return values.astype(dtype)
    with np.errstate(over="ignore"):
        cast = values.astype(dtype)
    if not np.isfinite(cast).all():
        raise BananagridError(
            f"{type(model).__name__}: densities up to {float(values.max()):.3g} per m^2 exceed {dtype.name}'s range "
            f"({float(np.finfo(dtype).max):.3g}); rasterise with dtype=np.float64"
        )
    return cast
