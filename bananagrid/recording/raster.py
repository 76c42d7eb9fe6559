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
from dataclasses import dataclass

import rerun as rr

from ..contours import DEFAULT_MASS_LEVELS, MassRegion, contour_lines, focus_extent, format_level, mass_regions
from ..results import Raster
from ..validate import positive
from .entities import entity_path, strict
from .images import check_values, log10_floor, log_density, log_log10_density, log_north_up
from .info import flatten, raster_info
from .labels import PANEL_POINTS, LabelBoard
from .legend import log_legend
from .lines import LEVEL_COLOURS, MASS_COLOURS, log_lines

#: The log10 density's colormap: its dark ends keep the tails and the peak apart.
LOG10_COLORMAP = "turbo"

__all__ = ["LOG10_COLORMAP", "LoggedRaster", "log_raster", "log_raster_layer", "grow_extent"]


@dataclass
class LoggedRaster:
    """What :func:`log_raster_layer` drew: the regions, the map's frame (the extent its view
    must hold, before the legend's margins), the log10 colour range and the map's label board
    (for labels drawn on the map after it, e.g. a layer's geometry)."""

    regions: list[MassRegion]
    frame: tuple[float, float, float, float]
    floor: float
    top: float
    peak: float
    board: LabelBoard


def grow_extent(extent: tuple[float, float, float, float], other: tuple[float, float, float, float] | None,
                margin: float = 0.0) -> tuple[float, float, float, float]:
    """The smallest extent holding ``extent`` and ``other`` (padded by ``margin`` of its own
    size on each side); ``extent`` when ``other`` is None."""
    if other is None:
        return extent
    x0, x1, y0, y1 = other
    pad_x, pad_y = margin * (x1 - x0), margin * (y1 - y0)
    return (min(extent[0], x0 - pad_x), max(extent[1], x1 + pad_x),
            min(extent[2], y0 - pad_y), max(extent[3], y1 + pad_y))


def log_raster(
    rec: rr.RecordingStream,
    entity: str,
    raster: Raster,
    *,
    levels: Iterable[float] = (),
    mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS,
    colormap: str = "viridis",
    log10_colormap: str = LOG10_COLORMAP,
) -> list[MassRegion]:
    """Log one raster as a layer under ``entity`` at the current ``elapsed`` time; the
    probability-mass regions drawn (:func:`log_raster_layer` tells more)."""
    return log_raster_layer(rec, entity, raster, levels=levels, mass_levels=mass_levels, colormap=colormap,
                            log10_colormap=log10_colormap).regions


#: The map's frame reaches this share of a layer's geometry (:func:`log_raster_layer`'s
#: ``include``) beyond it, so that a circle is not drawn on the frame's edge.
INCLUDE_MARGIN = 0.05


def log_raster_layer(
    rec: rr.RecordingStream,
    entity: str,
    raster: Raster,
    *,
    levels: Iterable[float] = (),
    mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS,
    colormap: str = "viridis",
    log10_colormap: str = LOG10_COLORMAP,
    include: tuple[float, float, float, float] | None = None,
    panel: tuple[float, float] = PANEL_POINTS,
) -> LoggedRaster:
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
    frame = grow_extent(focus_extent(raster, regions), include, INCLUDE_MARGIN)
    board = LabelBoard(frame, panel)
    with strict():
        log_north_up(rec, entity)
        log_density(rec, f"{entity}/density", raster, colormap)
        top = log_log10_density(rec, f"{entity}/log10_density", raster, floor, log10_colormap)
        # the legend's labels first: the map's labels keep clear of them
        log_legend(rec, f"{entity}/legend", frame, floor, top, log10_colormap, board=board)
        reached = [r for r in regions if r.reached]
        log_lines(
            rec, f"{entity}/contours", contour_lines(raster, [r.density for r in reached]),
            [format_level(r) for r in reached], MASS_COLOURS, board=board,
        )
        if levels:
            log_lines(
                rec, f"{entity}/density_contours", contour_lines(raster, levels),
                [f"{level:g} m^-2" for level in levels], LEVEL_COLOURS, board=board,
            )
        info = raster_info(raster)
        info.update(flatten("regions", {f"{100 * r.probability:g}": r.describe() for r in regions}))
        rec.log(f"{entity}/info", rr.AnyValues(**info))
        rec.log(f"{entity}/mass", rr.Scalars(float(raster.mass)))
    return LoggedRaster(regions, frame, floor, top, float(raster.peak), board)
