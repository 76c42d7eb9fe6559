"""Search areas: a probability-mass region of a raster as polygons, and what they enclose.

A search planner is handed the smallest areas that hold 50, 90, 95 or 99 % of the probability.
The region for a level ``q`` is the set of cells of :func:`bananagrid.contours.mass_regions`:
every cell whose density is at least the boundary density ``c_q``. :func:`search_areas` draws
it as polygons in the grid's plane (metres):

* the outline is the iso-density line at ``c_q`` (contourpy's filled contours, marching squares
  between cell centres), traced so that the polygons contain exactly the region's cell centres,
  none of the others (see ``OUTLINE_GAP``); holes (a Butterly ring, a bearing fix's far side)
  are kept;
* shapely makes the result valid (``make_valid``) and measures it.

What the polygons enclose is recomputed from the cells: each cell's probability
``p_ij = values[i, j] dx dy`` counts with the share of the cell's square that lies inside the
polygons, ``probability = sum p_ij |cell_ij ∩ polygons| / (dx dy)``. That differs from the
level ``q`` for two reasons, both bounded by the grid:

1. the region's cells hold ``enclosed >= q``; the excess is less than the mass of the cells at
   the boundary density ``c_q`` (the last one counted, and any tied with it);
2. the outline crosses cells, each only partly inside: counting them by their share instead of
   by their centre moves the sum by less than their mass.

So ``|probability - q| <= resolution``, the mass of the cells the outline passes through plus
that of the cells at ``c_q``: the grid's resolution in probability. For a smooth density it
shrinks with the cell size (the outline crosses about ``perimeter / step`` cells of mass
``c_q step**2`` each, so in proportion to the step). :class:`SearchArea` reports it per area.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import contourpy
import numpy as np

from ..contours import DEFAULT_MASS_LEVELS, mass_regions
from ..validate import BananagridError
from .libraries import require

__all__ = ["SearchArea", "search_areas"]

SHAPELY_PURPOSE = "search areas (polygons)"


@dataclass(frozen=True)
class SearchArea:
    """The smallest area holding a probability, as polygons in the grid's plane.

    Attributes
    ----------
    level : float
        The probability asked for, in (0, 1).
    reached : bool
        Whether the grid holds that much probability; if not, ``geometry`` is empty and the
        numbers describe nothing (NaN, 0).
    density : float
        The boundary density of the region, m^-2 (:class:`bananagrid.contours.MassRegion`).
    cells : int
        Cells of the region (cell centres inside the polygons).
    enclosed : float
        Probability of the region's cells, ``sum p_ij`` over them (>= ``level``).
    probability : float
        Probability inside the polygons, recomputed from the cells with each cell counted by the
        share of its square inside (see the module's description).
    resolution : float
        Probability of the cells the outline passes through plus that of the cells at the
        boundary density: ``|probability - level| <= resolution`` (the grid's resolution in
        probability).
    area : float
        Area of the polygons in the plane, m^2.
    geometry : shapely.MultiPolygon
        The polygons, in the grid's x (east) and y (north) metres.
    """

    level: float
    reached: bool
    density: float
    cells: int
    enclosed: float
    probability: float
    resolution: float
    area: float
    geometry: object


def search_areas(raster, levels: Iterable[float] = DEFAULT_MASS_LEVELS) -> list[SearchArea]:
    """The probability-mass regions of ``raster`` at ``levels`` as polygons (see the module).

    Parameters
    ----------
    raster : Raster
        A density per m^2 on a grid (``values``, ``x``, ``y``, ``grid``); finite, >= 0.
    levels : iterable of float
        Probabilities in (0, 1); default 0.5, 0.9, 0.95, 0.99.

    Returns
    -------
    list of SearchArea
        One per level, in increasing probability.

    Raises
    ------
    BananagridError
        Values that are NaN, inf or negative; a grid with fewer than 2 cells along a side
        (no outline can be traced); a level outside (0, 1).
    """
    shapely = require("shapely", SHAPELY_PURPOSE)
    values = np.asarray(raster.values, dtype=np.float64)
    if values.size and np.any(values < 0.0):
        raise BananagridError("raster values contain negative densities: no search area is defined")
    regions = mass_regions(raster, levels)  # validates levels and finiteness
    if min(values.shape) < 2:
        raise BananagridError(
            f"a grid of {values.shape[1]} x {values.shape[0]} cells: search areas need at least 2 cells along each side"
        )
    cells = _Cells(raster, values, shapely)
    areas = []
    for region in regions:
        if not region.reached:
            empty = shapely.MultiPolygon()
            areas.append(SearchArea(region.probability, False, math.nan, 0, region.enclosed, math.nan, math.nan,
                                    0.0, empty))
            continue
        member = values >= region.density
        geometry = _polygons(raster, values, member, region.density, shapely)
        probability, cut, inside = cells.enclosed(geometry, member)
        tied = float(np.count_nonzero(values == region.density)) * region.density * float(raster.grid.cell_area)
        areas.append(SearchArea(
            level=region.probability, reached=True, density=region.density, cells=inside, enclosed=region.enclosed,
            probability=probability, resolution=cut + tied, area=float(geometry.area), geometry=geometry,
        ))
    return areas


#: The outline is traced at ``c (1 - OUTLINE_GAP / 2)`` through a map whose cells outside the
#: region are lowered to at most ``c (1 - OUTLINE_GAP)``: every centre then lies a clear
#: ``OUTLINE_GAP / 2`` of ``c`` from the level, so marching squares puts each one strictly on its
#: side even where a symmetric map has two densities one rounding apart at ``c``. The outline
#: moves only where a cell lies within 0.1 % of ``c``, by a thousandth of the cell there.
OUTLINE_GAP = 1e-3


def _polygons(raster, values: np.ndarray, member: np.ndarray, density: float, shapely):
    """The region ``member`` (the cells at or above ``density``) as one valid shapely
    MultiPolygon of the outline between its centres and the others (holes kept)."""
    field = np.where(member, values, np.minimum(values, density * (1.0 - OUTLINE_GAP)))
    # A ring of zeros on the grid's outer edges: the outline passes between an edge cell's centre
    # and the edge, so that the centre is inside and the polygons stay on the grid.
    field = np.pad(field, 1, constant_values=0.0)
    x, y = np.asarray(raster.x, dtype=np.float64), np.asarray(raster.y, dtype=np.float64)
    x0, x1, y0, y1 = raster.grid.extent
    x = np.concatenate([[x0], x, [x1]])
    y = np.concatenate([[y0], y, [y1]])
    generator = contourpy.contour_generator(x, y, field, fill_type=contourpy.FillType.OuterOffset)
    top = float(field.max())
    points, offsets = generator.filled(density * (1.0 - 0.5 * OUTLINE_GAP), top + abs(top) + 1.0)
    polygons = []
    for pts, offs in zip(points, offsets):
        rings = [pts[offs[k]:offs[k + 1]] for k in range(len(offs) - 1)]
        polygons.append(shapely.Polygon(rings[0], rings[1:]))
    geometry = shapely.make_valid(shapely.MultiPolygon(polygons)) if polygons else shapely.MultiPolygon()
    parts = [g for g in shapely.get_parts(geometry) if isinstance(g, shapely.Polygon) and not g.is_empty]
    # make_valid may return a collection with stray lines or points of no area: keep the areas.
    return shapely.MultiPolygon(parts) if parts else shapely.MultiPolygon()


#: Cells per side of the tiles that cut the polygons into small pieces before the cells' squares
#: are intersected with them: one intersection with the whole outline per square would cost
#: its length (seconds for a 1000 x 1000 grid), one per tile costs far less.
TILE = 16


class _Cells:
    """The grid's cells as points and squares, for what a geometry encloses of them."""

    def __init__(self, raster, values: np.ndarray, shapely):
        self.shapely = shapely
        grid = raster.grid
        self.dx, self.dy = float(grid.dx), float(grid.dy)
        self.values = values
        xs, ys = np.meshgrid(np.asarray(raster.x, dtype=np.float64), np.asarray(raster.y, dtype=np.float64))
        self.x, self.y = xs, ys
        self.p = values * float(grid.cell_area)

    def crossed(self, member: np.ndarray) -> np.ndarray:
        """The cells whose square the outline around ``member`` may enter: marching squares draws in a
        quad of four centres only where they lie on both sides of the level, and a cell's square
        is a quarter of each of the four quads about its centre, so the cells with a 3 x 3
        neighbourhood on both sides; and the cells on the grid's edge with their centre inside,
        where the polygons stop at the outermost centres."""
        above = np.pad(member, 1, constant_values=False)
        rows, cols = self.values.shape
        any_above = np.zeros((rows, cols), dtype=bool)
        any_below = np.zeros((rows, cols), dtype=bool)
        for di in range(3):
            for dj in range(3):
                window = above[di:di + rows, dj:dj + cols]
                any_above |= window
                any_below |= ~window
        return any_above & any_below

    def enclosed(self, geometry, member: np.ndarray) -> tuple[float, float, int]:
        """``(probability, cut_mass, cells)``: the probability inside ``geometry`` with each cell
        counted by the share of its square inside, the mass of the cells whose square its outline
        cuts (a share strictly between 0 and 1), and the number of cell centres inside."""
        shapely = self.shapely
        if geometry.is_empty:
            return 0.0, 0.0, 0
        shapely.prepare(geometry)
        inside = shapely.contains_xy(geometry, self.x, self.y)
        near = self.crossed(member)
        rows, cols = np.nonzero(near)
        x, y = self.x[near], self.y[near]
        squares = shapely.box(x - self.dx / 2, y - self.dy / 2, x + self.dx / 2, y + self.dy / 2)
        tiles, which = np.unique(np.column_stack([rows // TILE, cols // TILE]), axis=0, return_inverse=True)
        x0 = self.x[0, 0] - self.dx / 2 + tiles[:, 1] * TILE * self.dx
        y0 = self.y[0, 0] - self.dy / 2 + tiles[:, 0] * TILE * self.dy
        # A hair larger than the tile, so that no square on its edge loses a sliver to rounding.
        pad = 1e-6 * min(self.dx, self.dy)
        pieces = shapely.intersection(
            shapely.box(x0 - pad, y0 - pad, x0 + TILE * self.dx + pad, y0 + TILE * self.dy + pad), geometry)
        share = shapely.area(shapely.intersection(squares, pieces[which.ravel()])) / (self.dx * self.dy)
        probability = float(self.p[inside & ~near].sum() + np.sum(self.p[near] * share))
        # Only a square the outline cuts (0 < share < 1) counts differently by share than by centre.
        cut = (share > 0.0) & (share < 1.0)
        return probability, float(self.p[near][cut].sum()), int(inside.sum())
