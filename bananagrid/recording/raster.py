"""A raster as one layer of a recording: images, contours, legend and info values.

Layout of one layer ``entity`` (all of it in world metres, x east, y north):

- ``entity``: a static ``Transform3D`` with scale ``(1, -1, 1)``. rerun's 2D views draw y
  downwards; this flip puts north at the top of the screen for everything below ``entity``.
- ``entity/density``: ``DepthImage`` (float32) of the density per square metre, stored with
  its rows north first (image row 0 is the top), and a ``Transform3D`` from pixels to world
  metres, so the centre of ``values[i, j]`` lands on ``(x[j], y[i])``.
- ``entity/log10_density``: the same in ``log10``, cells at or below ``10**floor`` set to the
  floor (:func:`log10_floor`: two decades below the lowest contour drawn).
- ``entity/contours/lines``: ``LineStrips2D`` of the probability-mass contours (the boundaries of
  the highest-density regions, :func:`bananagrid.contours.mass_regions`), one colour per level;
  ``entity/contours/labels``: ``Points2D``, one per level on its line, labelled
  ``"90 % · 0.960 km²"``.
- ``entity/density_contours/lines`` and ``/labels``: the same for fixed density levels, when
  given.
- ``entity/legend/colour_bar``, ``/ticks``, ``/scale``: a log10 colour bar east of the map's
  frame (:func:`focus_extent`) with a label per decade, and a scale bar below it.
- ``entity/info``: ``AnyValues`` with the flattened provenance, mass, peak, grid and regions
  (``regions.90.area`` ...).
- ``entity/mass``: ``Scalars`` with the captured mass, a time series over ``elapsed``.
"""

from __future__ import annotations

from collections.abc import Iterable

import rerun as rr

from ..contours import DEFAULT_MASS_LEVELS, MassRegion, contour_lines, focus_extent, format_level, mass_regions
from ..results import Raster
from ..validate import positive
from .entities import entity_path, strict
from .images import check_values, log10_floor, log_density, log_log10_density, log_north_up
from .info import flatten, raster_info
from .legend import log_legend
from .lines import LEVEL_COLOURS, MASS_COLOURS, log_lines

__all__ = ["log_raster"]


def log_raster(
    rec: rr.RecordingStream,
    entity: str,
    raster: Raster,
    *,
    levels: Iterable[float] = (),
    mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS,
    colormap: str = "viridis",
    log10_colormap: str = "turbo",
) -> list[MassRegion]:
    """Log one raster as a layer under ``entity`` at the current ``elapsed`` time.

    See the module docstring for the entities written. Call :func:`set_elapsed` first when a
    scene has several times.

    Parameters
    ----------
    rec : rerun.RecordingStream
        Where to log.
    entity : str
        Layer path, e.g. ``"cat"`` or ``"layers/cat"``.
    raster : Raster
        Density per square metre; values must be finite.
    levels : iterable of float
        Fixed contour levels, density per square metre, > 0 (none by default).
    mass_levels : iterable of float
        Probability-mass levels in (0, 1): the highest-density regions drawn as labelled
        contours (default 50, 90, 95 and 99 %).
    colormap, log10_colormap : str
        rerun colormap names for the density and the log10 density.

    Returns
    -------
    list of MassRegion
        The probability-mass regions drawn (see :func:`bananagrid.contours.mass_regions`).
    """
    entity = entity_path(entity)
    levels = tuple(positive(f"levels[{k}]", level) for k, level in enumerate(levels))
    check_values(raster)
    regions = mass_regions(raster, mass_levels)
    floor = log10_floor(levels, regions, raster.peak)
    with strict():
        log_north_up(rec, entity)
        log_density(rec, f"{entity}/density", raster, colormap)
        top = log_log10_density(rec, f"{entity}/log10_density", raster, floor, log10_colormap)
        reached = [r for r in regions if r.reached]
        placed = log_lines(
            rec, f"{entity}/contours", contour_lines(raster, [r.density for r in reached]),
            [format_level(r) for r in reached], MASS_COLOURS,
        )
        if levels:
            log_lines(
                rec, f"{entity}/density_contours", contour_lines(raster, levels),
                [f"{level:g} m^-2" for level in levels], LEVEL_COLOURS, avoid=placed,
            )
        log_legend(rec, f"{entity}/legend", focus_extent(raster, regions), floor, top, log10_colormap)
        info = raster_info(raster)
        info.update(flatten("regions", {f"{100 * r.probability:g}": r.describe() for r in regions}))
        rec.log(f"{entity}/info", rr.AnyValues(**info))
        rec.log(f"{entity}/mass", rr.Scalars(float(raster.mass)))
    return regions
