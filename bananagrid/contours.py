"""Contours of a rasterised density in world metres: fixed-density lines, probability-mass
(highest-density) regions and where to put one label per level.

This module sits below :mod:`bananagrid.results` (it needs only a raster's ``values``, ``x``,
``y`` and ``grid.cell_area``), so results, plots, recordings and ``inspect`` share one
definition of a probability-mass region.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import contourpy
import numpy as np

from .validate import BananagridError, finite, show

__all__ = [
    "DEFAULT_LEVELS",
    "DEFAULT_MASS_LEVELS",
    "MassRegion",
    "cell_regions",
    "contour_lines",
    "focus_extent",
    "format_area",
    "format_level",
    "label_positions",
    "mass_inside",
    "points_along",
    "polyline_length",
    "mass_levels",
    "mass_regions",
]

#: Fixed contour levels (density per square metre), used where a scene asks for densities and
#: by the paper comparisons (Figure 7's levels).
DEFAULT_LEVELS = (1e-6, 1e-7, 1e-8, 1e-9, 1e-10)

#: Probability-mass levels drawn and tabulated by default: the smallest regions that hold 50,
#: 90, 95 and 99 % of the probability.
DEFAULT_MASS_LEVELS = (0.5, 0.9, 0.95, 0.99)


def contour_lines(raster, levels: Iterable[float]) -> dict[float, list[np.ndarray]]:
    """Iso-density lines of ``raster`` at each of ``levels``.

    Lines are traced by marching squares (contourpy, linear interpolation between cell
    centres) on the cell-centre lattice ``(raster.x, raster.y)``, so they lie in world metres
    and never reach beyond the outermost cell centres.

    Parameters
    ----------
    raster : Raster
        Density on a grid; ``values[i, j]`` belongs to ``(x[j], y[i])``.
    levels : iterable of float
        Density levels, per square metre (finite).

    Returns
    -------
    dict of float to list of ndarray
        For each level (as ``float``, in the order given), the line pieces as ``(n, 2)``
        float64 arrays of ``(x, y)``. A closed piece repeats its first point at the end.
        A level the raster never crosses maps to an empty list.
    """
    levels = [finite(f"levels[{k}]", level) for k, level in enumerate(levels)]
    if min(np.shape(raster.values)) < 2:
        # Marching squares needs at least one 2 x 2 quad of centres.
        return {level: [] for level in levels}
    generator = contourpy.contour_generator(
        raster.x, raster.y, np.asarray(raster.values, dtype=np.float64), line_type=contourpy.LineType.Separate,
    )
    return {
        level: [np.ascontiguousarray(line, dtype=np.float64) for line in generator.lines(level)]
        for level in levels
    }


def mass_inside(raster, level: float) -> float:
    """Probability mass in the cells whose density is at least ``level``.

    ``sum(values[values >= level]) * dx * dy`` (midpoint rule), the mass inside the
    ``level`` contour as the grid resolves it.
    """
    level = finite("level", level)
    values = np.asarray(raster.values, dtype=np.float64)
    return float(values[values >= level].sum() * raster.grid.cell_area)


@dataclass(frozen=True)
class MassRegion:
    """The smallest set of cells holding a given probability: a highest-density region.

    Attributes
    ----------
    probability : float
        The level asked for, in (0, 1).
    reached : bool
        Whether the grid holds that much probability at all. If not, ``density`` is NaN and
        ``cells``, ``area`` and ``enclosed`` describe every cell with a positive density.
    density : float
        The region's boundary density (m^-2): the region is every cell at or above it, and its
        contour is the iso-density line at this level.
    enclosed : float
        Probability in the region, ``sum(values[values >= density]) * dx * dy`` (>= probability).
    cells : int
        Number of cells in the region.
    area : float
        ``cells * dx * dy``, square metres.
    """

    probability: float
    reached: bool
    density: float
    enclosed: float
    cells: int
    area: float

    def describe(self) -> dict:
        """A plain dict (for JSON and recordings); NaN (no density, no common area) as None."""
        def plain(value: float) -> float | None:
            return None if math.isnan(value) else value

        return {
            "probability": self.probability, "reached": self.reached, "density": plain(self.density),
            "enclosed": self.enclosed, "cells": self.cells, "area": plain(self.area),
        }


def mass_levels(levels: Iterable[float], *, key: str = "mass_levels") -> tuple[float, ...]:
    """Validate probability-mass levels: each finite in (0, 1), returned sorted and unique."""
    try:
        values = list(levels)
    except TypeError:
        raise BananagridError(f"{key} = {show(levels)}: expected a list of probabilities in (0, 1)") from None
    checked = []
    for k, level in enumerate(values):
        if isinstance(level, (bool, np.bool_)) or not isinstance(level, (int, float, np.integer, np.floating)):
            raise BananagridError(f"{key}[{k}] = {show(level)}: expected a probability in (0, 1)")
        if not 0.0 < float(level) < 1.0:
            raise BananagridError(f"{key}[{k}] = {show(level)}: a probability-mass level must lie in (0, 1)")
        checked.append(float(level))
    return tuple(sorted(set(checked)))


def mass_regions(raster, levels: Iterable[float] = DEFAULT_MASS_LEVELS) -> list[MassRegion]:
    """Highest-density regions of ``raster`` holding each probability in ``levels``.

    With ``p_ij = values[i, j] * dx * dy`` the cell probabilities (midpoint rule), the region
    for level ``q`` is ``{cells with values >= c_q}``, where ``c_q`` is the largest density such
    that those cells hold at least ``q``: sort the cells by density, descending, and stop where
    the running sum first reaches ``q``. Cells tied at ``c_q`` are all inside, so ``enclosed >= q``
    always. The probabilities are the raster's own (after :meth:`Raster.normalise` they sum to
    one over the grid); a level above the grid's total is returned with ``reached = False``.

    Parameters
    ----------
    raster : Raster
        Density per square metre on a grid; values finite and >= 0.
    levels : iterable of float
        Probabilities in (0, 1).

    Returns
    -------
    list of MassRegion
        One per level, in increasing probability.
    """
    values = np.asarray(raster.values, dtype=np.float64)
    if values.size and not np.all(np.isfinite(values)):
        raise BananagridError("raster values contain NaN or inf: no probability-mass region is defined")
    return _regions(values.ravel(), float(raster.grid.cell_area), mass_levels(levels))


def cell_regions(prob, levels: Iterable[float] = DEFAULT_MASS_LEVELS) -> list[MassRegion]:
    """Highest-probability sets of cells holding each probability in ``levels``.

    As :func:`mass_regions`, for probabilities per cell (an array's angular cells): the region
    for ``q`` is every cell whose probability is at least the largest ``c_q`` such that those
    cells hold ``q``. ``area`` is NaN (cells of a lattice differ in size); ``density`` is the
    boundary cell probability.
    """
    prob = np.asarray(prob, dtype=np.float64)
    if prob.size and not np.all(np.isfinite(prob)):
        raise BananagridError("cell probabilities contain NaN or inf: no probability-mass region is defined")
    regions = _regions(prob.ravel(), 1.0, mass_levels(levels))
    return [MassRegion(r.probability, r.reached, r.density, r.enclosed, r.cells, math.nan) for r in regions]


def _regions(values: np.ndarray, weight: float, levels: tuple[float, ...]) -> list[MassRegion]:
    """The regions of :func:`mass_regions` for flat ``values`` whose probabilities are
    ``values * weight``; ``area = cells * weight``."""
    ordered = np.sort(values[values > 0.0])[::-1]
    cumulative = np.cumsum(ordered) * weight
    total = float(cumulative[-1]) if cumulative.size else 0.0
    regions = []
    for level in levels:
        if total < level:
            regions.append(MassRegion(level, False, math.nan, total, int(ordered.size), ordered.size * weight))
            continue
        k = int(np.searchsorted(cumulative, level, side="left"))
        density = float(ordered[k])
        inside = int(np.searchsorted(-ordered, -density, side="right"))  # ties at the boundary
        regions.append(MassRegion(level, True, density, float(cumulative[inside - 1]), inside, inside * weight))
    return regions


#: A map's frame reaches this share of its outermost region's size beyond that region.
FOCUS_PADDING = 0.15


def focus_extent(raster, regions: Sequence[MassRegion]) -> tuple[float, float, float, float]:
    """Where a map should be framed: the outermost probability-mass region's cells, padded by
    ``FOCUS_PADDING`` of its size on each side and clipped to the grid; the whole grid when no
    region is reached. ``(x0, x1, y0, y1)``, m."""
    reached = [r for r in regions if r.reached]
    grid = raster.grid
    if not reached:
        return grid.extent
    inside = np.asarray(raster.values) >= reached[-1].density
    rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
    x0, x1 = raster.x[cols[0]] - grid.dx / 2, raster.x[cols[-1]] + grid.dx / 2
    y0, y1 = raster.y[rows[0]] - grid.dy / 2, raster.y[rows[-1]] + grid.dy / 2
    pad_x, pad_y = FOCUS_PADDING * (x1 - x0), FOCUS_PADDING * (y1 - y0)
    gx0, gx1, gy0, gy1 = grid.extent
    return (float(max(gx0, x0 - pad_x)), float(min(gx1, x1 + pad_x)),
            float(max(gy0, y0 - pad_y)), float(min(gy1, y1 + pad_y)))


#: Width over height of a typical label ("90 % · 0.96 km²"), for the gaps between labels.
LABEL_ASPECT = 4.0


def label_positions(
    lines: Mapping[float, Sequence[np.ndarray]], *, candidates: int = 48, avoid: Sequence[tuple[float, float]] = (),
) -> dict[float, tuple[float, float]]:
    """One point on each level's lines where its label goes, spread apart.

    Levels are placed in the order given. Each takes, among ``candidates`` points evenly spaced
    along the arc length of its longest piece, the one farthest from every label placed so far
    (ties: the northernmost), so nested contours get labels on different sides instead of a
    pile at one spot. Distances count east-west gaps ``LABEL_ASPECT`` times less than
    north-south ones, since a label is a line of text. The result is deterministic.

    Parameters
    ----------
    lines : mapping of level to list of (n, 2) arrays
        As returned by :func:`contour_lines`.
    candidates : int
        Points tried per level.
    avoid : sequence of (x, y)
        Labels already placed (e.g. another set of contours'), kept away from like the others.

    Returns
    -------
    dict of float to (x, y)
        Only levels with at least one piece.
    """
    placed: dict[float, tuple[float, float]] = {}
    fixed = [tuple(map(float, point)) for point in avoid]
    for level, pieces in lines.items():
        pieces = [p for p in pieces if len(p) >= 2]
        if not pieces:
            continue
        longest = max(pieces, key=polyline_length)
        points = points_along(longest, candidates)
        if placed or fixed:
            others = np.array(fixed + list(placed.values()))
            # Labels are text lines, several times wider than tall: east-west gaps count less.
            gaps = np.min(np.hypot((points[:, None, 0] - others[None, :, 0]) / LABEL_ASPECT,
                                   points[:, None, 1] - others[None, :, 1]), axis=1)
        else:
            gaps = np.zeros(len(points))
        order = np.lexsort((-points[:, 1], -gaps))  # largest gap first, then northernmost
        best = points[order[0]]
        placed[level] = (float(best[0]), float(best[1]))
    return placed


def polyline_length(piece: np.ndarray) -> float:
    """Length of a polyline ``(n, 2)``."""
    return float(np.sum(np.hypot(*np.diff(piece, axis=0).T)))


def points_along(piece: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced by arc length along a polyline (the ends included)."""
    steps = np.hypot(*np.diff(piece, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    if s[-1] == 0.0:
        return piece[:1].copy()
    targets = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(targets, s, piece[:, 0]), np.interp(targets, s, piece[:, 1])])


def format_area(square_metres: float) -> str:
    """An area for a label: ``0.293 km²`` from 0.01 km² up, else ``2,930 m²`` (3 significant digits)."""
    if not math.isfinite(square_metres):
        return "n/a"
    if square_metres >= 1e4:
        return f"{_sig3(square_metres / 1e6)} km²"
    return f"{_sig3(square_metres)} m²"


def format_level(region: MassRegion) -> str:
    """A probability-mass contour's label: ``90 % · 0.96 km²``."""
    return f"{region.probability * 100:g} % · {format_area(region.area)}"


def _sig3(value: float) -> str:
    """Three significant digits, thousands separated, no exponent below 1e15."""
    if value == 0.0:
        return "0"
    digits = 2 - int(math.floor(math.log10(abs(value))))
    return f"{round(value, digits):,.{max(digits, 0)}f}"
