"""Contour lines and captured mass of a rasterised density, in world metres."""

from __future__ import annotations

from collections.abc import Iterable

import contourpy
import numpy as np

from ..results import Raster
from ..validate import finite

__all__ = ["contour_lines", "mass_inside", "DEFAULT_LEVELS"]

#: Contour levels (density per square metre) drawn and tabulated by default.
DEFAULT_LEVELS = (1e-6, 1e-7, 1e-8, 1e-9, 1e-10)


def contour_lines(raster: Raster, levels: Iterable[float]) -> dict[float, list[np.ndarray]]:
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
    if min(raster.values.shape) < 2:
        # Marching squares needs at least one 2 x 2 quad of centres.
        return {level: [] for level in levels}
    generator = _generator(raster)
    return {level: _pieces(generator, level) for level in levels}


def mass_inside(raster: Raster, level: float) -> float:
    """Probability mass in the cells whose density is at least ``level``.

    ``sum(values[values >= level]) * dx * dy`` (midpoint rule), the mass inside the
    ``level`` contour as the grid resolves it.
    """
    level = finite("level", level)
    values = np.asarray(raster.values, dtype=np.float64)
    return float(values[values >= level].sum() * raster.grid.cell_area)


def _generator(raster: Raster) -> contourpy.ContourGenerator:
    """A contourpy generator over the raster's cell centres, in world metres."""
    return contourpy.contour_generator(
        raster.x,
        raster.y,
        np.asarray(raster.values, dtype=np.float64),
        line_type=contourpy.LineType.Separate,
    )


def _pieces(generator: contourpy.ContourGenerator, level: float) -> list[np.ndarray]:
    """The line pieces at one level as contiguous float64 ``(n, 2)`` arrays."""
    return [np.ascontiguousarray(line, dtype=np.float64) for line in generator.lines(level)]
