"""Cell-centred rectangular grids in world coordinates (x east, y north, metres)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..validate import BananagridError, pair, point, positive, positive_int

__all__ = ["Grid", "MAX_CELLS", "MAX_TILED_CELLS"]

#: Largest grid computed in memory (cells). 2**28 cells are 2 GiB per float64 map; a scene run
#: holds several such arrays at once (about 60 bytes per cell measured, so some 16 GB here), and
#: what a run will need is checked against the memory available before it starts
#: (:mod:`bananagrid.engine.memory`). Larger grids are rasterised in tiles (``chunks=``).
MAX_CELLS = 2**28

#: Largest grid at all (cells): 2**38, some 2.7e11 cells (a 500,000 x 500,000 basin), computed in
#: tiles on Dask workers and written to Zarr (:mod:`bananagrid.engine.tiles`).
MAX_TILED_CELLS = 2**38

#: Fewest float64 steps (ulps of the largest coordinate) across a cell: below, the cells' centres
#: and edges would collapse onto each other or be placed wrong by more than a thousandth of a
#: cell (1e-30 m cells about x = 1: every centre at the same x, every map 0 or garbage).
MIN_CELL_ULPS = 1024


@dataclass(frozen=True)
class Grid:
    """A cell-centred grid: ``values[i, j]`` belongs to the cell centred at ``(x[j], y[i])``.

    Rows run from south to north. Build one with :meth:`from_bounds` or directly from its
    south-west corner ``origin``, the cell sizes ``dx``, ``dy`` and the counts ``nx``, ``ny``.

    Parameters
    ----------
    origin : (float, float)
        World coordinates of the grid's south-west corner (the outer edge, not a centre), m.
    dx, dy : float
        Cell width (east) and height (north), m, > 0.
    nx, ny : int
        Number of columns and rows, >= 1, with ``nx * ny <= MAX_TILED_CELLS`` (``MAX_CELLS`` to compute it in memory).
    """

    origin: tuple[float, float]
    dx: float
    dy: float
    nx: int
    ny: int

    def __post_init__(self):
        object.__setattr__(self, "origin", point("origin", self.origin))
        object.__setattr__(self, "dx", positive("dx", self.dx))
        object.__setattr__(self, "dy", positive("dy", self.dy))
        object.__setattr__(self, "nx", positive_int("nx", self.nx))
        object.__setattr__(self, "ny", positive_int("ny", self.ny))
        cells = self.nx * self.ny
        if cells > MAX_TILED_CELLS:
            raise BananagridError(
                f"grid of {self.nx} x {self.ny} = {cells:,} cells would take {cells * 8 / 2**30:.1f} GiB as "
                f"float64; the limit is {MAX_TILED_CELLS:,} cells in tiles (chunks=) and {MAX_CELLS:,} "
                f"({MAX_CELLS * 8 / 2**30:.0f} GiB per float64 map) in memory: use a larger step or smaller bounds"
            )
        for name, start, extent in (("x", self.origin[0], self.nx * self.dx), ("y", self.origin[1], self.ny * self.dy)):
            if not (math.isfinite(extent) and math.isfinite(start + extent)):
                raise BananagridError(f"grid extent in {name} is not finite (origin {start!r}, {extent!r} m)")
        for name, step, start, extent in (("dx", self.dx, self.origin[0], self.nx * self.dx),
                                          ("dy", self.dy, self.origin[1], self.ny * self.dy)):
            ulp = math.ulp(max(abs(start), abs(start + extent)))
            if not step >= MIN_CELL_ULPS * ulp:
                raise BananagridError(
                    f"{name} = {step!r}: below float64's resolution at coordinates up to "
                    f"{max(abs(start), abs(start + extent)):.6g} m (cells need at least {MIN_CELL_ULPS} steps of "
                    f"{ulp:.3g} m, so {MIN_CELL_ULPS * ulp:.3g} m); use larger cells or an origin nearer 0"
                )
        area = self.dx * self.dy
        if not (math.isfinite(area) and area > 0.0):  # 1e308 squared overflows, 1e-308 squared underflows
            raise BananagridError(
                f"dx, dy = {self.dx!r}, {self.dy!r}: the cell area {area!r} m^2 is not a positive finite number"
            )

    @classmethod
    def many(cls, origins, dx, dy, nx: int, ny: int) -> list["Grid"]:
        """Grids of one shape: ``Grid(origin=origins[k], dx=dx[k], dy=dy[k], nx=nx, ny=ny)`` for
        each k, equal field for field, or the first one's error.

        Their checks are taken for every grid at once (a batch frames thousands, and each grid's
        own checks cost some 5 us): a grid that passes them all is made without running them
        again; any other (a non-finite or non-positive step, an extent that overflows, cells
        below the coordinates' resolution, where NumPy's ulp of the largest float, inf, is
        stricter than ``math.ulp``) is made by ``Grid(...)`` itself, which raises its error."""
        nx, ny = positive_int("nx", nx), positive_int("ny", ny)
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 2)
        steps = np.column_stack((np.asarray(dx, dtype=np.float64).ravel(), np.asarray(dy, dtype=np.float64).ravel()))
        with np.errstate(all="ignore"):
            ok = np.isfinite(origins).all(axis=1) & np.isfinite(steps).all(axis=1) & (steps > 0.0).all(axis=1)
            extents = steps * np.array([nx, ny], dtype=np.float64)
            ends = origins + extents
            ok &= (np.isfinite(extents) & np.isfinite(ends)).all(axis=1)
            ok &= (steps >= MIN_CELL_ULPS * np.spacing(np.maximum(np.abs(origins), np.abs(ends)))).all(axis=1)
            area = steps[:, 0] * steps[:, 1]
            ok &= np.isfinite(area) & (area > 0.0)
        ok &= nx * ny <= MAX_TILED_CELLS
        grids, make = [], object.__new__
        for x, y, u, v, checked in zip(*origins.T.tolist(), *steps.T.tolist(), ok.tolist()):
            if checked:
                grid = make(cls)  # the fields as __post_init__ leaves them: floats and ints
                grid.__dict__.update(origin=(x, y), dx=u, dy=v, nx=nx, ny=ny)
            else:
                grid = cls(origin=(x, y), dx=u, dy=v, nx=nx, ny=ny)
            grids.append(grid)
        return grids

    @classmethod
    def from_bounds(cls, x, y, step=None, *, dx=None, dy=None) -> "Grid":
        """Grid covering ``x = (x0, x1)`` and ``y = (y0, y1)`` with square cells of ``step``.

        The bounds are the outer cell edges. When the extent is not a whole number of steps the
        upper bound is moved out to the next whole cell, so the bounds are always covered.
        ``dx`` and ``dy`` may be given instead of ``step`` for rectangular cells.
        """
        if step is not None:
            if dx is not None or dy is not None:
                raise BananagridError("give either step or dx/dy, not both")
            dx = dy = step
        if dx is None or dy is None:
            raise BananagridError("step (or both dx and dy) is required")
        dx, dy = positive("dx" if step is None else "step", dx), positive(
            "dy" if step is None else "step", dy
        )
        counts = []
        for name, bounds, d in (("x", x, dx), ("y", y, dy)):
            lo, hi = pair(name, bounds, "bounds (low, high)")
            if not hi > lo:
                raise BananagridError(f"{name} = ({lo}, {hi}): the upper bound must exceed the lower")
            span = (hi - lo) / d
            if not math.isfinite(span):  # a span near 1e308, or a step near 1e-308
                raise BananagridError(f"{name} bounds ({lo}, {hi}) at step {d}: the number of cells overflows")
            # a whole number of steps up to rounding stays whole; anything else rounds up
            n = round(span) if abs(span - round(span)) <= 1e-9 * max(1.0, span) else math.ceil(span)
            if n > MAX_TILED_CELLS:
                count = f"{n:,}" if n < 1e15 else f"{float(n):.3g}"  # no 300-digit numbers
                gib = n * 8 / 2**30
                size = f"{gib:.1f}" if gib < 1e6 else f"{gib:.3g}"
                raise BananagridError(
                    f"{name} bounds ({lo}, {hi}) at step {d} give {count} cells in one axis, "
                    f"over {size} GiB as float64 for a single row; the limit is "
                    f"{MAX_TILED_CELLS:,} cells in all ({MAX_CELLS:,} in memory)"
                )
            counts.append((lo, max(n, 1)))
        (x0, nx), (y0, ny) = counts
        return cls(origin=(x0, y0), dx=dx, dy=dy, nx=nx, ny=ny)

    def check_in_memory(self) -> None:
        """Refuse a grid too large for one array (more than :data:`MAX_CELLS` cells): compute it
        in tiles instead (``chunks=``, ``bananagrid run --zarr``)."""
        cells = self.nx * self.ny
        if cells > MAX_CELLS:
            raise BananagridError(
                f"grid of {self.nx} x {self.ny} = {cells:,} cells would take {cells * 8 / 2**30:.1f} GiB as "
                f"float64; the limit in memory is {MAX_CELLS:,} cells ({MAX_CELLS * 8 / 2**30:.0f} GiB per float64 "
                "map): use a larger step or smaller bounds, or compute it in tiles (chunks=, or run --zarr)"
            )

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: the shape of a values array on this grid."""
        return (self.ny, self.nx)

    @property
    def cell_area(self) -> float:
        return self.dx * self.dy

    @property
    def x(self) -> np.ndarray:
        """Cell-centre x coordinates, shape ``(nx,)``."""
        return self.origin[0] + (np.arange(self.nx) + 0.5) * self.dx

    @property
    def y(self) -> np.ndarray:
        """Cell-centre y coordinates (south to north), shape ``(ny,)``."""
        return self.origin[1] + (np.arange(self.ny) + 0.5) * self.dy

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """Outer edges ``(x0, x1, y0, y1)``."""
        x0, y0 = self.origin
        return (x0, x0 + self.nx * self.dx, y0, y0 + self.ny * self.dy)

    def describe(self) -> dict:
        """Plain-data description for recordings and provenance."""
        return {"origin": list(self.origin), "dx": self.dx, "dy": self.dy, "nx": self.nx, "ny": self.ny}
