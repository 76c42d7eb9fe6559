"""Pictures of rasters with matplotlib (the ``plot`` extra): a map a reviewer reads without a
viewer.

A map is log10 of the density in km (x east, y north, north up, equal aspect), framed on the
outermost probability-mass region (:func:`bananagrid.contours.focus_extent`), with a colour bar
in log10 m^-2 that starts ``FLOOR_DECADES`` below the lowest drawn region's boundary density (so
the tails show), the probability-mass contours (:func:`bananagrid.contours.mass_regions`) each
labelled once on its line with its area, and the geometry the raster's provenance names (as the
recordings draw it): a bearing fix's sensors, bearing lines with +-2 sigma wedges and the fix; a
motion model's start with its initial heading; a Butterly start's mean. Points off the frame
are named at the edge they lie beyond. Contour labels are placed when the figure is drawn,
where they overlap no other label or name; a key names the contour colours.

Given a chart (:mod:`bananagrid.geo.chart`, for a map on the Earth), the map carries latitude
and longitude lines labelled at its edges, the land filled lightly with its coast, a km scale
bar and the UTC time in its title instead of km axes (:func:`draw_chart`, :func:`plot_overview`).
Panels side by side share one colour range (:func:`shared_colour_range`).

matplotlib is loaded (with importlib) only when a picture is drawn, so the rest of the package
never needs it. Rasters are taken duck-typed (``values``, ``x``, ``y``, ``grid``, ``mass``,
``provenance``): this module sits below :mod:`bananagrid.results`, whose ``Raster.plot`` calls
it.
"""

from __future__ import annotations

import base64
import html
import importlib
import io
import math
import sys
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import timezone

import numpy as np

from .contours import (
    DEFAULT_MASS_LEVELS,
    contour_lines,
    focus_extent,
    format_area,
    format_level,
    label_positions,
    mass_levels as checked_levels,
    mass_regions,
)
from .validate import BananagridError, finite, show

__all__ = [
    "FLOOR_DECADES", "MASS_COLOURS", "WEDGE_SIGMAS", "MapGeometry", "MatplotlibMissing", "colour_range", "draw_chart",
    "figure_layout", "format_time", "legend_handles", "map_frame", "map_geometry", "plot_overview", "plot_raster", "png_bytes", "pyplot",
    "raster_html", "shared_colour_range", "utc_label",
]

#: The colour scale starts this many decades below the lowest probability-mass contour drawn.
FLOOR_DECADES = 2.0

#: Contour colours by level, innermost (50 %) first; they read on turbo's reds and blues alike.
MASS_COLOURS = ("white", "magenta", "dimgrey", "black")

#: Half-width of the drawn bearing wedges, in sigmas (as the recordings draw them).
WEDGE_SIGMAS = 2.0

#: Height of a map (inches) in a default figure, and the room around it for the colour bar,
#: tick labels and titles.
MAP_HEIGHT = 3.2
MAP_WIDTH_RANGE = (2.0, 5.5)
#: A map's frame is widened (or heightened) to an aspect, width over height, in this range.
FRAME_ASPECTS = (0.6, 3.0)
PANEL_MARGINS = (1.7, 1.1)
#: A figure of several maps puts up to this many in a row, within this width (inches).
MAX_COLUMNS = 3
MAX_FIGURE_WIDTH = 16.0
#: Room for a figure's title above its maps (inches).
TITLE_HEIGHT = 0.35

_MARKER_STYLES = {  # by the first word of a marker's label
    "sensor": {"marker": "^", "color": "white", "markersize": 9},
    "fix": {"marker": "X", "color": "white", "markersize": 9},
    "start": {"marker": "o", "color": "white", "markersize": 7},
}
_OTHER_MARKER = {"marker": "o", "color": "cyan", "markersize": 7}
_BEARING_COLOUR = "gold"
#: Other spots along its line that a contour label may take where its own is taken.
LABEL_CANDIDATES = 24
#: The land of a chart, filled lightly over the map, and its coast.
LAND_COLOUR = "#efe6cf"
#: The sea of an overview chart (no map under it).
SEA_COLOUR = "#dcebf5"
COAST_COLOUR = "0.2"


class MatplotlibMissing(BananagridError):
    """matplotlib (the ``plot`` extra) is not installed."""


def pyplot(*, headless: bool = False):
    """``matplotlib.pyplot``; with ``headless``, on the non-interactive Agg backend unless pyplot
    was imported already (files only, no window). A one-line error naming the extra when
    matplotlib is not installed."""
    try:
        matplotlib = importlib.import_module("matplotlib")  # optional: loaded on first use
    except ImportError:
        raise MatplotlibMissing(
            "pictures need matplotlib: pip install 'bananagrid[plot]' (or pip install matplotlib)"
        ) from None
    if headless and "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    return importlib.import_module("matplotlib.pyplot")


@dataclass(frozen=True)
class MapGeometry:
    """What a raster's provenance says to draw over its map, in world metres.

    Attributes
    ----------
    markers : tuple of (x, y, label)
        ``"sensor K"`` (a bearing fix's stations), ``"fix"``, ``"start"`` (a motion model's
        origin) or ``"start mean"`` (a Butterly start).
    bearings : tuple of ((x, y), bearing, sigma)
        Each sensor's bearing (rad, clockwise from north) and its SD (rad).
    heading : (x, y, bearing) or None
        A motion model's initial heading (rad, clockwise from north) at its start.
    """

    markers: tuple = ()
    bearings: tuple = ()
    heading: tuple | None = None


def map_geometry(provenance: Mapping | None) -> MapGeometry:
    """The points and lines a raster's provenance names (see :class:`MapGeometry`).

    Reads the keys the models write: ``sensorK_x``, ``sensorK_y``, ``bearingK``, ``sigmaK``,
    ``fix_x``, ``fix_y`` (a bearing fix); ``origin_x``, ``origin_y``, ``heading`` (CAT and
    polar bananas); ``mean_x``, ``mean_y`` (Butterly). Anything else is ignored.
    """
    given = dict(provenance or {})

    def number(key: str) -> float | None:
        value = given.get(key)
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
        return float(value) if ok and math.isfinite(value) else None

    markers, bearings, heading = [], [], None
    k = 0
    while number(f"sensor{k}_x") is not None and number(f"sensor{k}_y") is not None:
        x, y = number(f"sensor{k}_x"), number(f"sensor{k}_y")
        markers.append((x, y, f"sensor {k}"))
        if number(f"bearing{k}") is not None:
            bearings.append(((x, y), number(f"bearing{k}"), number(f"sigma{k}") or 0.0))
        k += 1
    if number("fix_x") is not None and number("fix_y") is not None:
        markers.append((number("fix_x"), number("fix_y"), "fix"))
    if number("origin_x") is not None and number("origin_y") is not None:
        markers.append((number("origin_x"), number("origin_y"), "start"))
        if number("heading") is not None:
            heading = (number("origin_x"), number("origin_y"), number("heading"))
    elif number("mean_x") is not None and number("mean_y") is not None:
        markers.append((number("mean_x"), number("mean_y"), "start mean"))
    return MapGeometry(tuple(markers), tuple(bearings), heading)


def format_time(t: float) -> str:
    """An elapsed time for a title: ``10 s``, ``600 s (10 min)``, ``28800 s (8 h)``."""
    text = f"{t:g} s"
    if abs(t) >= 3600.0:
        return f"{text} ({t / 3600.0:.3g} h)"
    if abs(t) >= 120.0:
        return f"{text} ({t / 60.0:.3g} min)"
    return text


def map_frame(raster, mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS) -> tuple[float, float, float, float]:
    """Where :func:`plot_raster` frames ``raster``: its outermost reached probability-mass
    region, padded (:func:`bananagrid.contours.focus_extent`), widened or heightened about its
    centre to an aspect (width over height) within ``FRAME_ASPECTS`` as far as the grid reaches;
    ``(x0, x1, y0, y1)``, m."""
    return _framed(raster, [r for r in mass_regions(raster, mass_levels) if r.reached])


def _framed(raster, reached) -> tuple[float, float, float, float]:
    x0, x1, y0, y1 = focus_extent(raster, reached)
    gx0, gx1, gy0, gy1 = raster.grid.extent
    low, high = FRAME_ASPECTS
    width, height = x1 - x0, y1 - y0
    if width < low * height:
        x0, x1 = _widened(x0, x1, low * height, gx0, gx1)
    elif width > high * height:
        y0, y1 = _widened(y0, y1, width / high, gy0, gy1)
    return float(x0), float(x1), float(y0), float(y1)


def _widened(a: float, b: float, size: float, low: float, high: float) -> tuple[float, float]:
    """The interval [a, b] grown about its centre to ``size``, shifted and cut to [low, high]."""
    centre = (a + b) / 2
    a, b = centre - size / 2, centre + size / 2
    if a < low:
        a, b = low, min(high, b + (low - a))
    if b > high:
        a, b = max(low, a - (b - high)), high
    return a, b


def figure_layout(frames: Sequence[tuple[float, float, float, float]]) -> tuple[int, int, tuple[float, float]]:
    """Rows, columns and size (width, height in inches) of a figure of maps framed on
    ``frames``: each map at most ``MAP_HEIGHT`` tall and ``MAP_WIDTH_RANGE[1]`` wide at the widest
    frame's aspect (at least ``MAP_WIDTH_RANGE[0]`` wide), plus ``PANEL_MARGINS`` for its colour
    bar, labels and title; as many maps per row (up to ``MAX_COLUMNS``) as fit in
    ``MAX_FIGURE_WIDTH``."""
    aspect = max([(x1 - x0) / (y1 - y0) for x0, x1, y0, y1 in frames if y1 > y0 and x1 > x0] or [1.0])
    low, high = MAP_WIDTH_RANGE
    width = min(max(MAP_HEIGHT * aspect, low), high)
    height = min(MAP_HEIGHT, width / aspect)
    panel = (width + PANEL_MARGINS[0], height + PANEL_MARGINS[1])
    count = max(len(frames), 1)
    columns = max(1, min(MAX_COLUMNS, count, int(MAX_FIGURE_WIDTH // panel[0])))
    rows = -(-count // columns)
    return rows, columns, (round(columns * panel[0], 2), round(rows * panel[1] + TITLE_HEIGHT, 2))


def plot_raster(
    raster,
    ax=None,
    *,
    mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS,
    title: str | None = None,
    t: float | None = None,
    markers: Sequence[tuple[float, float, str]] = (),
    geometry: bool = True,
    colorbar: bool = True,
    legend: bool = True,
    clim: tuple[float, float] | None = None,
    extent: tuple[float, float, float, float] | None = None,
    chart=None,
):
    """Draw ``raster`` on ``ax`` (a new figure's axes by default) and return the axes.

    Parameters
    ----------
    raster : Raster
        Density per m^2 on a grid (finite, >= 0).
    ax : matplotlib Axes, optional
        Where to draw; a new figure sized to the map when omitted.
    mass_levels : iterable of float
        Probability-mass levels in (0, 1) whose contours are drawn and labelled
        (``"50 % · 0.294 km²"``: the level and the region's area).
    title : str, optional
        Default: the model (and variant) from the provenance and the elapsed time.
    t : float, optional
        Elapsed time, s, for the default title (default: the provenance's ``t``).
    markers : sequence of (x, y, label)
        More points to mark, in metres; a label starting with ``sensor``, ``fix`` or ``start``
        is drawn like those of the geometry.
    geometry : bool
        Whether to draw what the provenance names (:func:`map_geometry`): sensors, bearing lines
        with +-``WEDGE_SIGMAS`` sigma wedges, the fix, a start and its heading.
    colorbar : bool
        Whether to add the log10 colour bar (beside the map, as tall as it).
    legend : bool
        Whether to add the key to the contour colours (:func:`legend_handles`) in the map.
    clim : (float, float), optional
        The colour range, log10 m^-2 (default: :func:`colour_range` of this raster); panels
        side by side share one.
    extent : (x0, x1, y0, y1), optional
        The frame, m (default: :func:`map_frame`); an animation holds one for every time.
    chart : callable, optional
        For a map on the Earth: called with the frame ``(x0, x1, y0, y1)`` (m), it returns what
        :func:`draw_chart` draws (a :class:`bananagrid.geo.chart.Chart`: graticule, land). The
        axes then carry latitude and longitude labels and a km scale bar instead of km axes.

    Returns
    -------
    matplotlib Axes
        The map is its first image (log10 density, clim from the floor to the peak); each
        contour piece a ``Line2D`` with ``gid`` ``"mass-contour-<probability>"``; one label
        ``Text`` per level with ``gid`` ``"mass-label-<probability>"`` (levels whose regions
        coincide on a coarse grid share one line and one label, ``"95, 99 % · 400 m²"``);
        markers ``Line2D`` with ``gid`` ``"marker-<label>"``; bearing lines ``"bearing-K"`` and
        their wedges ``"bearing-K-wedge"``; with a chart, graticule lines ``"graticule-lat-<deg>"``
        and ``"graticule-lon-<deg>"`` (km), the land a ``PathPatch`` ``"land"`` and its edge.

    Raises
    ------
    BananagridError
        On a bad argument (one line naming it), or when matplotlib is not installed.
    """
    levels = checked_levels(mass_levels, key="mass_levels")
    extra = _checked_markers(markers)
    if title is not None and not isinstance(title, str):
        raise BananagridError(f"title = {show(title)}: expected a string or None")
    if t is not None:
        t = finite("t", t)
    values = _checked_values(raster)
    plt = pyplot()
    if ax is None:
        frame = map_frame(raster, levels)
        _, _, size = figure_layout([frame])
        _, ax = plt.subplots(figsize=size, layout="constrained")
    elif not (hasattr(ax, "imshow") and hasattr(ax, "figure")):
        raise BananagridError(f"ax = {type(ax).__name__}: expected matplotlib Axes or None")

    regions = mass_regions(raster, levels)
    reached = [r for r in regions if r.reached]
    floor, top = colour_range(raster, levels, regions) if clim is None else _checked_clim(clim)
    with np.errstate(divide="ignore"):
        logs = np.where(values > 10.0**floor, np.log10(np.where(values > 0.0, values, 1.0)), floor)
    x0, x1, y0, y1 = raster.grid.extent
    image = ax.imshow(logs, origin="lower", extent=(x0 / 1e3, x1 / 1e3, y0 / 1e3, y1 / 1e3),
                      cmap="turbo", vmin=floor, vmax=top, interpolation="nearest")

    frame = _framed(raster, reached) if extent is None else _checked_extent(extent)
    fx0, fx1, fy0, fy1 = frame
    drawn = chart(frame) if chart is not None else None
    if drawn is not None:
        draw_chart(ax, drawn)
    colours = {level: MASS_COLOURS[k % len(MASS_COLOURS)] for k, level in enumerate(levels)}
    lines = contour_lines(raster, [r.density for r in reached])  # one entry per distinct density
    sharing: dict[float, list] = {}  # regions by boundary density (coarse grids can tie levels)
    for region in reached:
        sharing.setdefault(region.density, []).append(region)
    for density, group in sharing.items():
        for piece in lines[density]:
            ax.plot(piece[:, 0] / 1e3, piece[:, 1] / 1e3, color=colours[group[0].probability], linewidth=1.2,
                    gid=f"mass-contour-{group[0].probability:g}")
    shown = map_geometry(getattr(raster, "provenance", None)) if geometry else MapGeometry()
    points = list(shown.markers) + extra
    inside = [(x, y) for x, y, _ in points if fx0 <= x <= fx1 and fy0 <= y <= fy1]
    visible = _within(lines, frame)
    spots = label_positions(visible, avoid=inside)  # labels away from the marked points
    labels = []
    for density, group in sharing.items():
        if density in spots:
            x, y = spots[density]
            along = np.concatenate([p for p in visible[density]]) if visible[density] else np.empty((0, 2))
            others = along[np.linspace(0, len(along) - 1, min(len(along), LABEL_CANDIDATES)).astype(int)] / 1e3
            text = format_level(group[0]) if len(group) == 1 else \
                f"{', '.join(f'{100 * r.probability:g}' for r in group)} % · {format_area(group[0].area)}"
            label = ax.text(x / 1e3, y / 1e3, text, fontsize=7.5, ha="center", va="center", zorder=5,
                            gid=f"mass-label-{group[0].probability:g}",
                            bbox={"boxstyle": "round,pad=0.2", "facecolor": "white", "alpha": 0.85, "linewidth": 0})
            labels.append((label, [(x / 1e3, y / 1e3)] + [tuple(p) for p in others]))
    _keep_apart(ax, labels)

    notes = _draw_bearings(ax, shown, frame)
    notes += _draw_markers(ax, points, frame, shown.heading, getattr(drawn, "place", None))

    ax.set_xlim(fx0 / 1e3, fx1 / 1e3)
    ax.set_ylim(fy0 / 1e3, fy1 / 1e3)
    ax.set_aspect("equal")
    axis = ["x east [km]"] if drawn is None else []
    ax.set_xlabel("\n".join([*axis, *_wrapped(notes, _label_width(ax))]))
    ax.set_ylabel("y north [km]" if drawn is None else "")
    if drawn is not None:
        _chart_axes(ax, drawn, frame)
    ax.set_title(title if title is not None else _default_title(raster, t), fontsize=10)
    if legend:
        ax.legend(handles=legend_handles(levels), loc="best", fontsize=7, framealpha=0.85, title="probability mass",
                  title_fontsize=7)
    if colorbar:
        inches = max(ax.figure.get_figwidth() * ax.get_position().width, 0.5)
        # an inset follows the map's box (equal aspect); 0.15 in wide, 0.12 in from the map
        bar = ax.inset_axes([1.0 + 0.12 / inches, 0.0, 0.15 / inches, 1.0])
        ax.figure.colorbar(image, cax=bar, label="log10 density [m⁻²]")
    return ax


def colour_range(raster, mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS, regions=None) -> tuple[float, float]:
    """The colour range of ``raster``'s map, log10 m^-2: from ``FLOOR_DECADES`` below the
    lowest reached probability-mass region's boundary density (four decades below the peak
    when none is reached) to the peak (at least a decade above the floor)."""
    values = _checked_values(raster)
    if regions is None:
        regions = mass_regions(raster, checked_levels(mass_levels, key="mass_levels"))
    reached = [r for r in regions if r.reached]
    lowest = min((r.density for r in reached), default=float(values.max()) * 1e-4)
    floor = math.log10(lowest) - FLOOR_DECADES if lowest > 0.0 else -12.0
    peak = float(values.max())
    top = math.log10(peak) if peak > 10.0**floor else floor
    return float(floor), float(max(top, floor + 1.0))


def shared_colour_range(ranges: Iterable[tuple[float, float]]) -> tuple[float, float]:
    """One colour range that holds every one of ``ranges`` (panels side by side, the frames of
    an animation): the lowest floor to the highest top."""
    ranges = list(ranges)
    if not ranges:
        raise BananagridError("shared_colour_range: no ranges given")
    return min(r[0] for r in ranges), max(r[1] for r in ranges)


def legend_handles(mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS) -> list:
    """The key to the contour colours: one line per probability-mass level, in its colour
    (outlined, so that the white one shows on a white key), labelled ``"50 % region"``."""
    levels = checked_levels(mass_levels, key="mass_levels")
    pyplot()
    lines = importlib.import_module("matplotlib.lines")
    patheffects = importlib.import_module("matplotlib.patheffects")
    outline = [patheffects.withStroke(linewidth=3.2, foreground="0.25")]
    return [lines.Line2D([], [], color=MASS_COLOURS[k % len(MASS_COLOURS)], linewidth=1.8, path_effects=outline,
                         label=f"{100 * level:g} % region", gid=f"legend-{level:g}")
            for k, level in enumerate(levels)]


def draw_chart(ax, chart, *, graticule_colour: str = "white") -> None:
    """Draw a chart (:class:`bananagrid.geo.chart.Chart`, duck-typed: ``land`` rings and
    graticule ``lines`` in local metres) on ``ax`` in km: the land filled lightly over the map
    with its coast as a dark line, and the graticule as thin lines (light over a map)."""
    path_module = importlib.import_module("matplotlib.path")
    patches = importlib.import_module("matplotlib.patches")
    vertices, codes = [], []
    for polygon in chart.land:
        for ring in polygon:
            vertices.append(np.asarray(ring, dtype=float) / 1e3)
            codes.append([path_module.Path.MOVETO] + [path_module.Path.LINETO] * (len(ring) - 1))
    if vertices:
        path = path_module.Path(np.concatenate(vertices), np.concatenate(codes))
        ax.add_patch(patches.PathPatch(path, facecolor=LAND_COLOUR, alpha=0.8, edgecolor="none", zorder=1.5,
                                       gid="land"))
        ax.add_patch(patches.PathPatch(path, facecolor="none", edgecolor=COAST_COLOUR, linewidth=0.8, zorder=1.6,
                                       gid="coast"))
    for line in chart.lines:
        xy = np.asarray(line.xy, dtype=float) / 1e3
        ax.plot(xy[:, 0], xy[:, 1], color=graticule_colour, alpha=0.55, linewidth=0.6, zorder=1.8,
                gid=f"graticule-{line.kind}-{line.value:.10g}")


def plot_overview(ax, geometry: MapGeometry, boxes: Sequence[tuple[float, float, float, float]], extent, chart,
                  *, title: str = "where the maps lie") -> None:
    """An overview chart on ``ax``: the land and graticule of ``chart`` over ``extent``
    (m), the frame of each map (``boxes``, m) as a red rectangle (``gid`` ``"overview-frame-K"``),
    and ``geometry``'s points with their names (``"marker-<label>"``), bearing lines and wedges:
    where the stations or the start that a map's frame leaves out lie."""
    x0, x1, y0, y1 = _checked_extent(extent)
    pyplot()
    patches = importlib.import_module("matplotlib.patches")
    ax.set_facecolor(SEA_COLOUR)
    draw_chart(ax, chart, graticule_colour="0.35")
    for k, (bx0, bx1, by0, by1) in enumerate(boxes):
        ax.add_patch(patches.Rectangle((bx0 / 1e3, by0 / 1e3), (bx1 - bx0) / 1e3, (by1 - by0) / 1e3, fill=False,
                                       edgecolor="crimson", linewidth=1.3, zorder=6, gid=f"overview-frame-{k}"))
    _draw_bearings(ax, geometry, (x0, x1, y0, y1))
    notes = _draw_markers(ax, geometry.markers, (x0, x1, y0, y1), geometry.heading, getattr(chart, "place", None))
    ax.set_xlim(x0 / 1e3, x1 / 1e3)
    ax.set_ylim(y0 / 1e3, y1 / 1e3)
    ax.set_aspect("equal")
    _chart_axes(ax, chart, (x0, x1, y0, y1))
    ax.set_xlabel("\n".join(_wrapped(notes, _label_width(ax))))
    ax.set_title(title, fontsize=10)
    ax.set_gid("overview")


def png_bytes(raster, *, dpi: int = 80, **kwargs) -> bytes:
    """A PNG of :func:`plot_raster` on a new figure (for notebooks' ``_repr_png_``); keywords as
    for :func:`plot_raster`."""
    plt = pyplot()
    ax = plot_raster(raster, **kwargs)
    buffer = io.BytesIO()
    try:
        ax.figure.savefig(buffer, format="png", dpi=dpi)
    finally:
        plt.close(ax.figure)
    return buffer.getvalue()


def raster_html(raster) -> str:
    """A small HTML summary (grid, mass, peak, the probability-mass regions) and the picture
    as an embedded PNG when matplotlib is installed (else a line saying how to get it)."""
    grid = raster.grid
    x0, x1, y0, y1 = grid.extent
    rows = [
        ("grid", f"{grid.nx} x {grid.ny} cells of {grid.dx:g} x {grid.dy:g} m; x {x0:g} .. {x1:g} m, "
                 f"y {y0:g} .. {y1:g} m"),
        ("captured mass", f"{raster.mass:.6f}" + (" (normalised)" if getattr(raster, "normalised", False) else "")),
        ("peak", f"{float(np.max(raster.values)):.4g} m⁻²"),
    ]
    rows += [(f"{100 * r.probability:g} % region",
              f"{format_area(r.area)}, holds {r.enclosed:.4f}, boundary {r.density:.3g} m⁻²" if r.reached
              else "not reached on this grid")
             for r in mass_regions(raster)]
    table = "".join(f"<tr><th style='text-align:left'>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                    for k, v in rows)
    try:
        picture = base64.b64encode(png_bytes(raster)).decode("ascii")
        image = f"<img src='data:image/png;base64,{picture}'/>"
    except MatplotlibMissing as exc:  # the table alone, saying why
        image = f"<p>{html.escape(str(exc))}</p>"
    return f"<div><table>{table}</table>{image}</div>"


# --- helpers ----------------------------------------------------------------------------------


def _checked_values(raster) -> np.ndarray:
    values = np.asarray(getattr(raster, "values", None), dtype=np.float64)
    if values.ndim != 2 or min(values.shape) < 1 or not np.all(np.isfinite(values)):
        raise BananagridError(f"raster values of shape {values.shape}: a map needs a finite 2-D array")
    if np.any(values < 0.0):
        raise BananagridError("raster values hold negative numbers: a map of log10 density needs values >= 0")
    return values


def _checked_clim(clim) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in clim)
    except (TypeError, ValueError):
        raise BananagridError(f"clim = {show(clim)}: expected (low, high), log10 m^-2") from None
    if not (math.isfinite(low) and math.isfinite(high) and high > low):
        raise BananagridError(f"clim = {show(clim)}: expected finite low < high")
    return low, high


def _checked_extent(extent) -> tuple[float, float, float, float]:
    try:
        x0, x1, y0, y1 = (float(v) for v in extent)
    except (TypeError, ValueError):
        raise BananagridError(f"extent = {show(extent)}: expected (x0, x1, y0, y1) in metres") from None
    if not (all(map(math.isfinite, (x0, x1, y0, y1))) and x1 > x0 and y1 > y0):
        raise BananagridError(f"extent = {show(extent)}: expected finite x0 < x1 and y0 < y1")
    return x0, x1, y0, y1


def _chart_axes(ax, chart, frame) -> None:
    """Latitude labels on the left edge, longitude labels on the bottom edge (where the
    graticule crosses them) and a km scale bar, in place of km axes."""
    ticks = {"bottom": [], "left": []}
    for tick in chart.ticks:
        ticks[tick.edge].append((tick.position / 1e3, tick.label))
    ax.set_xticks([p for p, _ in ticks["bottom"]], [label for _, label in ticks["bottom"]], fontsize=7)
    ax.set_yticks([p for p, _ in ticks["left"]], [label for _, label in ticks["left"]], fontsize=7)
    if len(ticks["bottom"]) > 3:  # long labels side by side would touch
        ax.tick_params(axis="x", labelrotation=30)
    x0, x1, _, _ = frame
    length = _round_length(0.25 * (x1 - x0))
    anchored = importlib.import_module("mpl_toolkits.axes_grid1.anchored_artists")
    bar = anchored.AnchoredSizeBar(ax.transData, length / 1e3, _length_text(length), "lower left", pad=0.4,
                                   color="black", frameon=True, size_vertical=0, fontproperties={"size": 7})
    bar.patch.set_alpha(0.75)
    bar.set_gid("scale-bar")
    bar.set_zorder(8)
    ax.add_artist(bar)


def _keep_apart(ax, labels) -> None:
    """At every draw, once the layout is final, put each contour label at the first of its
    spots (``(text, [(x, y) km, ...])``: the chosen one, then others along its line) where it
    overlaps no label placed before it nor a marker's name; where none is free (tiny regions in
    a wide frame, an animation's first frames) the label is left out and the key names the
    colour. Done by an artist drawn just before the labels."""
    artist = importlib.import_module("matplotlib.artist")
    texts = [label for label, _ in labels]

    class KeepApart(artist.Artist):
        def draw(self, renderer):
            names = [t for t in ax.texts if t not in texts and t.get_text() and t.get_visible()]
            placed = [_padded(t.get_window_extent(renderer)) for t in names]
            for label, spots in labels:
                label.set_visible(True)  # a hidden text has no extent
                for spot in spots:
                    label.set_position(spot)
                    box = _padded(label.get_window_extent(renderer))
                    if not any(box.overlaps(other) for other in placed):
                        placed.append(box)
                        break
                else:
                    label.set_position(spots[0])
                    label.set_visible(False)

    guard = KeepApart()
    guard.set_zorder(4.99)  # before the labels (5): their visibility is set for this draw
    guard.set_gid("mass-label-guard")
    ax.add_artist(guard)


def _padded(box, pixels: float = 3.0):
    """A window extent grown by a few pixels on each side (a label's box has padding)."""
    return box.expanded(1.0, 1.0).from_extents(box.x0 - pixels, box.y0 - pixels, box.x1 + pixels, box.y1 + pixels)


def _round_length(limit: float) -> float:
    """The largest 1, 2 or 5 times a power of ten (m) not above ``limit``."""
    power = 10.0 ** math.floor(math.log10(limit))
    return max(m * power for m in (1.0, 2.0, 5.0) if m * power <= limit)


def _length_text(metres: float) -> str:
    return f"{metres / 1e3:g} km" if metres >= 1e3 else f"{metres:g} m"


def _checked_markers(markers) -> list[tuple[float, float, str]]:
    try:
        given = list(markers)
    except TypeError:
        raise BananagridError(f"markers = {show(markers)}: expected a list of (x, y, label)") from None
    checked = []
    for k, marker in enumerate(given):
        try:
            x, y, label = marker
        except (TypeError, ValueError):
            raise BananagridError(f"markers[{k}] = {show(marker)}: expected (x, y, label), x and y in metres") from None
        if not isinstance(label, str):
            raise BananagridError(f"markers[{k}] label = {show(label)}: expected a string")
        checked.append((finite(f"markers[{k}] x", x), finite(f"markers[{k}] y", y), label))
    return checked


def _within(lines: Mapping[float, list[np.ndarray]], frame, margin: tuple[float, float] = (0.14, 0.07)):
    """The contour pieces cut to the frame less a margin (a label's half width and height), so
    that labels land on a visible stretch of their line and inside the frame."""
    x0, x1, y0, y1 = frame
    mx, my = margin[0] * (x1 - x0), margin[1] * (y1 - y0)
    cut = {}
    for level, pieces in lines.items():
        kept = []
        for piece in pieces:
            inside = (piece[:, 0] > x0 + mx) & (piece[:, 0] < x1 - mx) & (piece[:, 1] > y0 + my) & (piece[:, 1] < y1 - my)
            # contiguous runs of inside points
            edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
            kept += [piece[a:b] for a, b in zip(edges[::2], edges[1::2]) if b - a >= 2]
        cut[level] = kept if kept else pieces  # nothing inside the margin: anywhere on the line
    return cut


def _frame_diagonal(frame) -> float:
    x0, x1, y0, y1 = frame
    return math.hypot(x1 - x0, y1 - y0)


def _draw_bearings(ax, geometry: MapGeometry, frame) -> list[str]:
    """Each sensor's bearing line (solid) and its +-WEDGE_SIGMAS sigma wedge (dashed) from the
    sensor to beyond the fix (or the frame's centre); the key to them for the notes."""
    if not geometry.bearings:
        return []
    fix = next(((x, y) for x, y, label in geometry.markers if label == "fix"), None)
    x0, x1, y0, y1 = frame
    centre = np.array(fix if fix is not None else ((x0 + x1) / 2, (y0 + y1) / 2))
    reach = 1.5 * max(float(np.hypot(*(centre - np.array(s)))) for s, _, _ in geometry.bearings) + _frame_diagonal(frame)
    for k, (sensor, bearing, sigma) in enumerate(geometry.bearings):
        s = np.array(sensor)
        for side in (0.0, -1.0, 1.0):
            if side and not sigma > 0.0:
                continue
            b = bearing + side * WEDGE_SIGMAS * sigma
            end = s + reach * np.array([math.sin(b), math.cos(b)])
            ax.plot([s[0] / 1e3, end[0] / 1e3], [s[1] / 1e3, end[1] / 1e3], "--" if side else "-",
                    color=_BEARING_COLOUR, linewidth=0.7 if side else 1.0, zorder=3,
                    gid=f"bearing-{k}-wedge" if side else f"bearing-{k}")
    return [f"bearings (gold), ±{WEDGE_SIGMAS:g}σ dashed"]


def _draw_markers(ax, markers, frame, heading, place=None) -> list[str]:
    """Markers inside the frame as labelled points (a start with an arrow along its heading);
    those beyond it as notes naming them, where they are (km, or latitude and longitude by
    ``place(x, y)`` on a chart) and which way."""
    patheffects = importlib.import_module("matplotlib.patheffects")  # present: pyplot() has been called
    outline = [patheffects.withStroke(linewidth=2.5, foreground="black")]
    x0, x1, y0, y1 = frame
    if heading is not None:
        hx, hy, bearing = heading
        if x0 <= hx <= x1 and y0 <= hy <= y1:
            length = 0.12 * _frame_diagonal(frame)
            tip = (hx + length * math.sin(bearing), hy + length * math.cos(bearing))
            ax.annotate("", xy=(tip[0] / 1e3, tip[1] / 1e3), xytext=(hx / 1e3, hy / 1e3), zorder=6,
                        arrowprops={"arrowstyle": "-|>", "color": "white", "linewidth": 1.5,
                                    "path_effects": outline})
    beyond = []
    for x, y, label in markers:
        if x0 <= x <= x1 and y0 <= y <= y1:
            style = _MARKER_STYLES.get(label.split(" ")[0], _OTHER_MARKER)
            ax.plot([x / 1e3], [y / 1e3], linestyle="none", markeredgecolor="black", zorder=7,
                    gid=f"marker-{label}", **style)
            ax.annotate(label, (x / 1e3, y / 1e3), textcoords="offset points", xytext=(6, 6), fontsize=8,
                        color="white", path_effects=outline, zorder=7)
        else:
            way = _ARROWS[round(math.atan2(y - (y0 + y1) / 2, x - (x0 + x1) / 2) / (math.pi / 4)) % 8]
            beyond.append(f"{way} {label} ({_km(x)}, {_km(y)})" if place is None else f"{way} {label} {place(x, y)}")
    if not beyond:
        return []
    return [f"beyond the frame{' (km)' if place is None else ''}: {', '.join(beyond)}"]


#: Which way a point beyond the frame lies, by the eighth of a turn counter-clockwise from east.
_ARROWS = ("→", "↗", "↑", "↖", "←", "↙", "↓", "↘")


def _km(metres: float) -> str:
    return f"{metres / 1e3:.3g}"


def _label_width(ax) -> int:
    """How many characters of the x label fit under the map and its colour bar (about)."""
    inches = ax.figure.get_figwidth() * ax.get_position().width
    return max(24, int(inches / 0.075))


def _wrapped(notes: Sequence[str], width: int) -> list[str]:
    """Notes for the x label, wrapped to lines of about ``width`` characters."""
    lines = []
    for note in notes:
        lines += textwrap.wrap(note, width) or [note]
    return lines


def _default_title(raster, t: float | None) -> str:
    provenance = getattr(raster, "provenance", {}) or {}
    model = str(provenance.get("model", "raster"))
    variant = provenance.get("variant")
    if isinstance(variant, str):
        model = f"{model} ({variant})"
    if t is None:
        given = provenance.get("t")
        t = float(given) if isinstance(given, (int, float)) and not isinstance(given, bool) else None
    if t is None:
        return model
    when = utc_label(getattr(raster, "frame", None), t)
    return f"{model}, t = {format_time(t)}" + ("" if when is None else f"\n{when}")


def utc_label(frame, t: float) -> str | None:
    """``2026-11-24 05:55:00 UTC``: the UTC time at elapsed time ``t`` (s) of a geographic
    frame with a time (duck-typed: ``frame.utc(t)`` returns a datetime or None), else None."""
    utc = getattr(frame, "utc", None)
    when = utc(t) if callable(utc) else None
    if when is None:
        return None
    text = when.astimezone(timezone.utc).replace(tzinfo=None).isoformat(sep=" ", timespec="seconds")
    return f"{text} UTC"
