"""Grids as images: the density, its log10, cell probabilities and signed fields, each placed in
world metres with north up."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import rerun as rr

from ..contours import MassRegion
from ..results import Raster
from ..validate import BananagridError
from .entities import entity_path, strict

__all__ = ["LOG10_FLOOR_DECADES", "check_values", "colormaps", "image_from_values", "log10_floor", "log_cell_probabilities", "log_density", "log_log10_density", "log_north_up", "log_signed_image", "pixel_to_world", "values_from_image"]


#: How many decades below the lowest contour level the log10 image is floored.
LOG10_FLOOR_DECADES = 2.0


def log_north_up(rec: rr.RecordingStream, entity: str) -> None:
    """Make ``entity``'s subtree (world metres, y north) show north up in a 2D view."""
    rec.log(entity_path(entity), rr.Transform3D(scale=(1.0, -1.0, 1.0)), static=True)


def image_from_values(values: np.ndarray) -> np.ndarray:
    """Grid values (row 0 south) as a float32 image (row 0 north, the image's top row)."""
    return np.ascontiguousarray(np.flipud(values), dtype=np.float32)


def values_from_image(image: np.ndarray) -> np.ndarray:
    """Inverse of :func:`image_from_values`: image rows back to grid rows (row 0 south)."""
    return np.ascontiguousarray(np.flipud(image))


def check_values(raster: Raster) -> None:
    """Raise unless the values match the grid and are finite (a colour range needs both)."""
    values = np.asarray(raster.values)
    if values.shape != raster.grid.shape:
        raise BananagridError(
            f"raster values have shape {values.shape}, the grid needs {raster.grid.shape}"
        )
    if not np.all(np.isfinite(values)):
        raise BananagridError("raster values contain NaN or inf; cannot record them")


def log_density(rec: rr.RecordingStream, path: str, raster: Raster, colormap: str) -> None:
    """The density image with range ``(0, peak)`` and its pixel-to-world transform."""
    peak = raster.peak
    image = rr.DepthImage(
        image_from_values(raster.values),
        meter=1.0,
        colormap=colormap,
        depth_range=(0.0, peak if peak > 0.0 else 1.0),
    )
    rec.log(path, image, pixel_to_world(raster))


def log_log10_density(
    rec: rr.RecordingStream, path: str, raster: Raster, floor: float, colormap: str
) -> float:
    """``log10`` of the density, cells at or below ``10**floor`` shown at ``floor``, and the
    same transform as the density; returns the top of the colour range."""
    values = np.asarray(raster.values, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.where(values > 10.0**floor, np.log10(values), floor)
    top = float(logs.max())
    top = top if top > floor else floor + 1.0
    image = rr.DepthImage(image_from_values(logs), meter=1.0, colormap=colormap, depth_range=(floor, top))
    rec.log(path, image, pixel_to_world(raster))
    return top


def log_cell_probabilities(rec: rr.RecordingStream, path: str, cells: Raster, *, colormap: str = "viridis") -> None:
    """The probability of each cell (a :class:`Raster` of ``quantity == "probability"``) as an
    image with range ``(0, largest cell)``, placed in world metres like the layer's density."""
    if cells.quantity != "probability":
        raise BananagridError(f"cells.quantity = {cells.quantity!r}: expected cell probabilities")
    check_values(cells)
    with strict():
        log_density(rec, entity_path(path), cells, colormap)


def log_signed_image(rec: rr.RecordingStream, path: str, values: np.ndarray, like: Raster) -> None:
    """A signed field on ``like``'s grid (a difference, a relative error) as an image with a
    diverging colormap symmetric about zero, placed in world metres like ``like``'s density."""
    bound = float(np.max(np.abs(values))) or 1.0
    with strict():
        rec.log(
            entity_path(path),
            rr.DepthImage(image_from_values(values), meter=1.0, colormap="cyantoyellow", depth_range=(-bound, bound)),
            pixel_to_world(like),
        )


def colormaps() -> tuple[str, ...]:
    """The colormap names rerun knows, in lower case."""
    return tuple(c.name.lower() for c in rr.components.Colormap)


def log10_floor(levels: Sequence[float], regions: Sequence[MassRegion], peak: float) -> float:
    """Floor of the log10 image: ``LOG10_FLOOR_DECADES`` below the lowest contour drawn.

    The lowest contour is the outermost probability-mass region's boundary density or the
    lowest fixed level, whichever is lower; with neither, ``LOG10_FLOOR_DECADES`` below the
    peak's decade minus four. Zero cells (``log10 = -inf``) and anything below the floor are
    shown at the floor.
    """
    lowest = [r.density for r in regions if r.reached and r.density > 0.0] + list(levels)
    if lowest:
        return math.log10(min(lowest)) - LOG10_FLOOR_DECADES
    return (math.log10(peak) - 4.0 if peak > 0.0 else -12.0) - LOG10_FLOOR_DECADES


def pixel_to_world(raster: Raster) -> rr.Transform3D:
    """Pixels of :func:`image_from_values` to world metres.

    Image pixel ``(u, v)`` covers ``[u, u+1] x [v, v+1]`` and row ``v = 0`` is the northern
    row, so ``x = x0 + dx u`` and ``y = y1 - dy v``; the centre of ``values[i, j]``, pixel
    ``(j + 1/2, ny - i - 1/2)``, lands on ``(x[j], y[i])``.
    """
    x0, _, _, y1 = raster.grid.extent
    return rr.Transform3D(translation=(x0, y1, 0.0), scale=(raster.grid.dx, -raster.grid.dy, 1.0))
