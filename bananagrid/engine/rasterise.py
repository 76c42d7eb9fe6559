"""``rasterise``: the entry for every domain. It validates the call and hands it to the function
of its domain and quantity, each of which makes one kind of result:

* a grid's densities, :func:`bananagrid.engine.grid_density.density_raster` (a ``Raster``), or
  lazily in blocks, :func:`bananagrid.engine.tiles.rasterise_tiles` (a ``TiledRaster``);
* a grid's cell probabilities, :func:`bananagrid.engine.grid_cells.probability_raster`
  (a ``Raster`` of ``quantity == "probability"``);
* a polar lattice's densities and cells, :func:`bananagrid.engine.polar_cells.rasterise_lattice`
  (a ``PolarRaster``);
* an angular lattice's cells, the model's own cell plan (a ``CellMap``).
"""

from __future__ import annotations

import warnings

import numpy as np

from ..domains.angular_lattice import AngularLattice
from ..domains.grid import Grid
from ..domains.polar_lattice import PolarLattice
from ..protocol import DensityModel, PresenceModel
from ..results import CellMap, PolarRaster, Raster, TiledRaster
from ..validate import BananagridError, BananagridWarning
from .grid_density import density_raster
from .points import check_model
from .grid_cells import probability_raster
from .polar_cells import rasterise_lattice
from .warp_runtime import WarpContext
from .tiles import rasterise_tiles

__all__ = ["rasterise", "warn_uncovered", "QUANTITIES", "MIN_MASS"]

#: Captured mass below which :func:`rasterise` warns that the grid misses part of the target
#: (the scenes' default ``output.min_mass``).
MIN_MASS = 0.99


#: What :func:`rasterise` computes on a grid.
QUANTITIES = ("density", "probability")


def rasterise(model: DensityModel | PresenceModel, grid: Grid | PolarLattice | AngularLattice, *,
              quantity: str = "density", dtype=np.float64, device: str = "cpu", threads=None,
              max_seconds: float | None = None, chunks=None,
              region=None, min_mass: float = MIN_MASS) -> Raster | PolarRaster | TiledRaster | CellMap:
    """Density of ``model`` at the cell centres of ``grid`` or the probability of each cell, or
    both on a polar lattice, or the probability of each angular cell.

    With a :class:`~bananagrid.PolarLattice` the result is a :class:`~bananagrid.PolarRaster`:
    densities per (m, rad) at the cell centres and the probability integrated over each
    (range, bearing) cell (see :func:`bananagrid.engine.polar_cells.rasterise_lattice`).

    With an :class:`~bananagrid.AngularLattice` the result is a :class:`~bananagrid.CellMap`:
    the probability p(C | S) of each cell of an array's directions, conditioned on ``region``
    (S; None for the whole space), computed by the model's own cell plan
    (``model.cell_plan``, :class:`~bananagrid.protocol.PresenceModel`;
    :func:`bananagrid.cell_probabilities` for the presence laws).

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
        acceleration (``CAT.cell_plan``), caustic cells included; every other model by a
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
    chunks : int or (int, int), optional
        Rasterise the density lazily in blocks of ``(rows, columns)`` cells on Dask (the
        ``cluster`` extra) and return a :class:`~bananagrid.results.TiledRaster`: grids up to
        :data:`~bananagrid.domains.grid.MAX_TILED_CELLS` cells, each block bit-identical to this
        function's values there, blocks the model proves negligible left at 0 without computing
        (:func:`bananagrid.engine.tiles.rasterise_tiles`; ``threads`` does not apply: Dask runs
        the blocks in parallel).

    region : Region, optional
        An angular lattice's conditioning box S (the other domains take none).
    min_mass : float, default 0.99
        A probability density (``model.integrates_to_one``) whose grid or polar lattice
        captures less than this warns that the grid misses part of the target (0: never).

    Returns
    -------
    Raster
        Raw (not normalised) densities per m^2, with the captured mass and provenance
        (a PolarRaster for a PolarLattice, a CellMap for an AngularLattice).

    Warns
    -----
    BananagridWarning
        When the grid captures less than ``min_mass`` of a probability density (it misses
        part of the target: the grid is too small or misplaced, or a parameter's unit is
        wrong), and where the model's or the quadrature's own limits cost accuracy.
    """
    if quantity not in QUANTITIES:
        raise BananagridError(f"quantity = {quantity!r}: expected one of {', '.join(map(repr, QUANTITIES))}")
    if isinstance(min_mass, bool) or not isinstance(min_mass, (int, float)) or not 0.0 <= min_mass <= 1.0:
        raise BananagridError(f"min_mass = {min_mass!r}: must be a number in [0, 1] (0 switches the warning off)")
    if isinstance(grid, AngularLattice):
        return _angular_cells(model, grid, region, dtype=dtype, device=device, threads=threads, chunks=chunks)
    if region is not None:
        raise BananagridError(f"region = {region!r}: only an AngularLattice's cells are conditioned on a region")
    if not callable(getattr(model, "bind", None)) and callable(getattr(model, "cell_plan", None)):
        model.cell_plan(grid)  # a law with cells but no planar kernels (a presence law) says where they are
    if isinstance(grid, PolarLattice):
        return _covered(model, rasterise_lattice(model, grid, dtype=dtype, device=device, threads=threads,
                                                 max_seconds=max_seconds), min_mass)
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid.Grid")
    if chunks is not None:
        if quantity != "density":
            raise BananagridError(f"quantity = {quantity!r} with chunks: tiles compute densities only")
        return rasterise_tiles(model, grid, chunks, dtype=dtype, device=device, max_seconds=max_seconds)
    check_model(model)
    grid.check_in_memory()
    if quantity == "probability":
        raster = probability_raster(model, grid, dtype=dtype, device=device, threads=threads, max_seconds=max_seconds)
    else:
        raster = density_raster(model, grid, dtype=dtype, device=device, threads=threads, max_seconds=max_seconds)
    return _covered(model, raster, min_mass)


def _covered(model, result, min_mass: float):
    """``result``, after a warning if it captured less than ``min_mass`` of a probability density."""
    warn_uncovered(model, float(result.mass), "polar lattice" if isinstance(result, PolarRaster) else "grid",
                   min_mass, stacklevel=4)
    return result


def warn_uncovered(model, mass: float, where: str, min_mass: float, stacklevel: int = 3) -> None:
    """Warn if a ``where`` ("grid", "polar lattice") captured less than ``min_mass`` of a
    probability density's mass."""
    if getattr(model, "integrates_to_one", False) and mass < min_mass:
        warnings.warn(
            f"rasterise: the {where} captured {mass:.3g} of {type(model).__name__}'s probability (below "
            f"{min_mass:g}): it misses part of the target; move or enlarge it, or check the parameters' units "
            "(min_mass=0 switches this off)", BananagridWarning, stacklevel=stacklevel,
        )


def _angular_cells(model, lattice: AngularLattice, region, *, dtype, device, threads, chunks) -> CellMap:
    """The model's own cells of an angular lattice (its :meth:`cell_plan`: probabilities,
    whatever the ``quantity``, as a polar lattice gives both), or one line saying why not."""
    if chunks is not None:
        raise BananagridError("chunks: an AngularLattice's cells are not tiled; leave chunks out")
    if not callable(getattr(model, "cell_plan", None)):
        check_model(model)  # not a model at all
    plan = model.cell_plan(lattice, region)  # a density in the world plane refuses in one line
    cells, _ = plan.run(WarpContext(dtype, device, threads))
    return cells
