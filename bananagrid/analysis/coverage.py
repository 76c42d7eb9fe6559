"""Did the grid catch the target? Captured mass, the edges where it leaks, and the warnings a
reviewer needs before trusting a normalised map."""

from __future__ import annotations

import numpy as np

from ..contours import MassRegion
from ..results import Raster
from ..validate import BananagridError, show

__all__ = ["DEFAULT_MIN_MASS", "MASS_EXCESS", "EDGES", "coverage_warnings", "leaking_edges", "level_warnings", "min_mass", "peak_location"]

#: Captured mass below which a layer is reported as missing part of the target.
DEFAULT_MIN_MASS = 0.99

#: Captured mass above 1 + this is reported: a probability cannot exceed 1, so the midpoint sum
#: of the centre densities overcounts, and the cells are too coarse for the density's peak or
#: curvature (a Butterly start of 5 SDs across 1 cell gives 1.033).
MASS_EXCESS = 1e-3

#: Grid edges, in the order they are reported.
EDGES = ("north", "east", "south", "west")

#: An edge leaks when its outermost cells hold at least this share of the largest edge's ...
LEAK_SHARE = 0.1
#: ... and at least this much probability.
LEAK_FLOOR = 1e-6


def min_mass(value, key: str = "min_mass") -> float:
    """Validate a captured-mass threshold: a number in [0, 1] (0 switches the warning off)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise BananagridError(f"{key} = {show(value)}: expected a number in [0, 1]")
    if not 0.0 <= float(value) <= 1.0:
        raise BananagridError(f"{key} = {show(value)}: must be in [0, 1] (0 switches the warning off)")
    return float(value)


def leaking_edges(raster: Raster) -> list[str]:
    """The grid edges across which probability leaves the grid, most first.

    Each edge's outermost row or column of cells holds some probability (values times the
    cell area). An edge counts when that is at least ``LEAK_FLOOR`` and at least ``LEAK_SHARE``
    of the largest edge's: a density still that high at the edge goes on beyond it, while a
    grid that misses mass with nothing at its edges is too coarse, not too small.
    """
    values = np.asarray(raster.values, dtype=np.float64)
    area = raster.grid.cell_area
    held = {
        "north": values[-1, :].sum() * area, "east": values[:, -1].sum() * area,
        "south": values[0, :].sum() * area, "west": values[:, 0].sum() * area,
    }
    largest = max(held.values())
    if not largest >= LEAK_FLOOR:
        return []
    return [edge for edge in sorted(EDGES, key=lambda e: (-held[e], EDGES.index(e)))
            if held[edge] >= max(LEAK_FLOOR, LEAK_SHARE * largest)]


def coverage_warnings(raster: Raster, regions: list[MassRegion], *, where: str, threshold: float = DEFAULT_MIN_MASS,
                      integrates_to_one: bool = True) -> list[str]:
    """A one-line warning (or none) about a layer's raster: mass the grid misses (and where it
    leaks, or that the cells are too coarse), a mass above ``1 + MASS_EXCESS`` (cells too coarse),
    and probability-mass levels it cannot reach.

    Parameters
    ----------
    raster : Raster
        The layer's raster; ``raster.mass`` is the raw captured mass even after normalising.
    regions : list of MassRegion
        Its probability-mass regions (for the levels that were not reached).
    where : str
        Names the layer and time in the messages, e.g. ``"figure1: layer cat at t = 10 s"``.
    threshold : float
        Captured mass below which the grid is said to miss the target (0: never).
    integrates_to_one : bool
        Whether the layer's density is a probability density (the model's
        ``integrates_to_one``); only then is a mass above ``1 + MASS_EXCESS`` reported.
    """
    parts = []
    if raster.mass < threshold:
        edges = leaking_edges(raster)
        normalised = ", then normalised to 1" if raster.normalised else ""
        if edges:
            advice = (f"it leaks across the {_listed(edges)} edge{'s' if len(edges) > 1 else ''}: "
                      "move or enlarge the grid, or check the parameters' units")
        else:
            advice = "nothing reaches the edges, so the cells are too coarse for the density: refine the grid"
        parts.append(f"the grid captured {raster.mass:.3g} of the probability (below {threshold:g}){normalised}; {advice}")
    elif integrates_to_one and raster.mass > 1.0 + MASS_EXCESS:
        normalised = ", then normalised to 1" if raster.normalised else ""
        parts.append(
            f"the cells' midpoint sum gives a mass of {raster.mass:.4g}, above 1 + {MASS_EXCESS:g}{normalised}: "
            "a probability cannot exceed 1, so the cells are too coarse for the density: refine the grid"
        )
    unreached = [r for r in regions if not r.reached]
    if unreached:
        parts.append(
            f"it holds {unreached[0].enclosed:.3g}, so the "
            f"{_listed([f'{100 * r.probability:g} %' for r in unreached])} probability-mass contour"
            f"{'s are' if len(unreached) > 1 else ' is'} not drawn"
        )
    return [f"{where}: {'; '.join(parts)}"] if parts else []


def _listed(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


def level_warnings(raster: Raster, levels, *, where: str) -> list[str]:
    """A warning for fixed contour levels outside the raster's range (they draw no line)."""
    values = np.asarray(raster.values, dtype=np.float64)
    if not values.size:
        return []
    low, high = float(values.min()), float(values.max())
    outside = [level for level in levels if not low < level < high]
    if not outside:
        return []
    shown = ", ".join(f"{level:g}" for level in outside)
    return [
        f"{where}: contour level{'s' if len(outside) > 1 else ''} {shown} m^-2 outside the map's range "
        f"[{low:.3g}, {high:.3g}] m^-2 draw{'' if len(outside) > 1 else 's'} no line"
    ]


def peak_location(raster: Raster) -> tuple[float, float]:
    """World coordinates ``(x, y)`` (m) of the cell centre with the highest density (the first
    in row-major order, south-west first, on ties)."""
    values = np.asarray(raster.values)
    i, j = np.unravel_index(int(np.argmax(values)), values.shape)
    return float(raster.x[j]), float(raster.y[i])
