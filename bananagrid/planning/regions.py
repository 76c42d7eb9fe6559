"""Probability-mass regions a crew can search: an allocation's coverage in k bands.

The optimal coverage of a map (:func:`~bananagrid.planning.allocation.allocate`) grows with the
cell's density, so cells with similar coverage form nested bands about the densest part of the
map: the highest-density regions. This module cuts the cells that get effort into k bands by
their coverage (equal steps from the largest coverage down to 0: band 0 the densest), searches
each band evenly at one track spacing, and spreads the effort over the bands by the Lagrange
condition (each band one cell of that problem: its probability m_j and area A_j). The track
spacing of band j is S_j = W / c_j for a sweep width W and coverage c_j; its tracks are
parallel lines at that spacing along the band's long axis (the principal axis of its cells),
clipped to the band. As the bands are unions of whole cells, the probability of success
sum_j m_j b(c_j) is exact on the map (no share of a cell is guessed); it lies below the ideal
allocation's (even coverage over a band is one allocation of the same effort).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geo.libraries import require
from ..results import Raster
from ..validate import BananagridError, positive, positive_int
from .allocation import Allocation, optimal_coverage
from .plan_files import PlanGeoJSON

#: The most bands of a plan.
MAX_BANDS = 16


@dataclass(frozen=True)
class SearchRegion:
    """One band of cells, searched evenly.

    Attributes
    ----------
    polygon : shapely (Multi)Polygon
        The band's cells merged, local metres.
    cells : ndarray of bool
        Which of the map's cells are in it.
    area : float
        m^2.
    probability : float
        The probability that the target is in it (the sum of its cells').
    coverage : float
        Sweep width over track spacing.
    track_spacing : float
        m (inf for a band that gets no effort).
    effort : float
        m^2 (coverage times area).
    pod : float
        b(coverage).
    tracks : tuple of ndarray
        Parallel sweep legs clipped to the band, each an (n, 2) polyline in local metres.
    """

    polygon: object
    cells: np.ndarray
    area: float
    probability: float
    coverage: float
    track_spacing: float
    effort: float
    pod: float
    tracks: tuple


@dataclass(frozen=True)
class RegionPlan(PlanGeoJSON):
    """Bands of a map searched at one track spacing each, with their exact probability of
    success (``pos``) beside the ideal allocation's (``ideal_pos``)."""

    regions: tuple
    pos: float
    ideal_pos: float
    effort: float
    sweep_width: float
    law: str
    frame: object = None

    def geojson_areas(self) -> list:
        """(polygon, tracks, properties) of each area, for :meth:`geojson`."""
        return [(r.polygon, r.tracks,
                {"probability": r.probability, "pod": r.pod, "pos": r.probability * r.pod, "coverage": r.coverage,
                 "track_spacing_m": r.track_spacing, "effort_m2": r.effort, "area_m2": r.area})
                for r in self.regions if r.coverage > 0]


def search_regions(allocation: Allocation, k: int, sweep_width: float) -> RegionPlan:
    """Cut an allocation on a grid into ``k`` bands of cells by coverage, each searched evenly
    by parallel sweeps (see the module).

    Parameters
    ----------
    allocation : Allocation
        ``bg.allocate(cells, effort, law)`` on a grid map.
    k : int
        Bands, 1 to :data:`MAX_BANDS`.
    sweep_width : float
        W, m.
    """
    shapely = require("shapely")
    if not isinstance(allocation, Allocation) or not isinstance(allocation.effort, Raster):
        raise BananagridError("allocation: expected bg.allocate's result on a grid map")
    k = positive_int("k", k)
    if k > MAX_BANDS:
        raise BananagridError(f"k = {k}: at most {MAX_BANDS} bands")
    width = positive("sweep_width", sweep_width)
    grid, coverage = allocation.effort.grid, allocation.effort.values
    p = np.asarray(allocation.cells, dtype=np.float64)
    top = float(coverage.max())
    # band j holds coverages in (top (k - j - 1) / k, top (k - j) / k]: band 0 the densest
    band = np.where(coverage > 0, np.minimum(k - 1, np.floor((top - coverage) / top * k)).astype(int), -1)
    members = [band == j for j in range(k) if (band == j).any()]
    masses = np.array([p[m].sum() for m in members])
    areas = np.array([m.sum() * grid.cell_area for m in members])
    planned, _, _ = optimal_coverage(masses, areas, allocation.total_effort, allocation.law)
    regions = []
    for cells, mass, area, c in zip(members, masses, areas, planned):
        polygon = _cells_polygon(grid, cells, shapely)
        spacing = width / c if c > 0 else math.inf
        tracks = _sweeps(grid, cells, polygon, spacing, shapely) if c > 0 else ()
        regions.append(SearchRegion(polygon=polygon, cells=cells, area=float(area), probability=float(mass),
                                    coverage=float(c), track_spacing=spacing, effort=float(c * area),
                                    pod=float(allocation.law.pod(np.array([c]))[0]), tracks=tracks))
    pos = float(sum(r.probability * r.pod for r in regions))
    return RegionPlan(regions=tuple(regions), pos=pos, ideal_pos=allocation.pos,
                      effort=float(sum(r.effort for r in regions)), sweep_width=width, law=allocation.law.name,
                      frame=allocation.effort.frame)


def _cells_polygon(grid, cells: np.ndarray, shapely):
    """The union of the marked cells' squares (shapely's coverage union: they only touch)."""
    rows, cols = np.nonzero(cells)
    x0, y0 = grid.origin
    boxes = shapely.box(x0 + cols * grid.dx, y0 + rows * grid.dy, x0 + (cols + 1) * grid.dx, y0 + (rows + 1) * grid.dy)
    return shapely.coverage_union_all(boxes)


def _sweeps(grid, cells: np.ndarray, polygon, spacing: float, shapely) -> tuple:
    """Parallel legs at ``spacing`` along the band's principal axis, clipped to it."""
    rows, cols = np.nonzero(cells)
    xy = np.column_stack([grid.x[cols], grid.y[rows]])
    centre = xy.mean(axis=0)
    spread = np.cov((xy - centre).T) if len(xy) > 2 else np.eye(2)
    _, vectors = np.linalg.eigh(spread)
    along, across = vectors[:, 1], vectors[:, 0]
    reach = float(np.hypot(*(np.asarray(polygon.bounds[2:]) - polygon.bounds[:2]))) + spacing
    offsets = np.arange(-reach, reach + spacing / 2, spacing) + spacing / 2
    lines = shapely.MultiLineString([[centre + o * across - reach * along, centre + o * across + reach * along]
                                     for o in offsets])
    clipped = shapely.intersection(lines, polygon)
    return tuple(np.asarray(part.coords) for part in shapely.get_parts(clipped)
                 if isinstance(part, shapely.LineString) and not part.is_empty)
