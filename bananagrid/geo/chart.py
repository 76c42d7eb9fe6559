"""A chart's furniture for a map in a geographic frame: graticule lines and their labels, and
the land, all in the frame's local metres (x east, y north).

* **Graticule.** Lines of constant latitude (parallels) and longitude (meridians) at a spacing
  chosen from the map's extent (:func:`graticule_spacing`: a round number of degrees, minutes or
  seconds giving at least :data:`MIN_LINES` lines across the map), each projected point by point
  with the frame's projection (pyproj), so a line lies where pyproj puts its latitude or
  longitude. Meridians are labelled where they cross the bottom edge, parallels where they cross
  the left edge; each crossing is found by root finding on the edge (to :data:`EDGE_TOLERANCE_M`).
* **Land.** Natural Earth's 1:10 million land polygons (public domain), simplified to about
  220 m, bundled with the package (``bananagrid/geo/data/land.npz``, made by
  ``docs/make_coastline.py``): read from the package's files, never downloaded. The polygons
  that reach the map are clipped in latitude and longitude to a box around it (across the
  antimeridian too), densified and projected into local metres.

Nothing here draws: :func:`bananagrid.plotting.plot_raster` draws a :class:`Chart` it is given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources

import numpy as np

from ..validate import BananagridError
from .frame import GeoFrame
from .libraries import require

__all__ = ["Chart", "GraticuleLine", "Tick", "LAND_FILE", "LAND_SOURCE", "MIN_LINES", "SPACINGS_DEG", "chart",
           "format_angle", "graticule_spacing", "land_polygons", "load_land"]

#: The bundled land polygons, in this package's folder ``data/``.
LAND_FILE = "land.npz"
#: Where the bundled land comes from (also stored in the file itself).
LAND_SOURCE = "Natural Earth 1:10m land (public domain)"
#: Graticule spacings to choose from, degrees: round degrees, minutes and seconds.
SPACINGS_DEG = tuple(sorted(
    [30.0, 20.0, 10.0, 5.0, 2.0, 1.0] + [m / 60.0 for m in (30, 20, 15, 10, 5, 2, 1)]
    + [s / 3600.0 for s in (30, 20, 15, 10, 5, 2, 1)], reverse=True))
#: A map shows at least this many lines of each kind (where the finest spacing allows).
MIN_LINES = 3
#: Points per graticule line and per edge of the map when it is sampled.
SAMPLES = 241
#: A label's crossing of the map's edge is found to this, m.
EDGE_TOLERANCE_M = 1e-3
#: The land is clipped to the map's latitude and longitude box grown by this fraction of it.
CLIP_MARGIN = 0.25
#: Clipped land is densified to this fraction of the box before projecting, so that straight
#: edges in degrees stay close to their curved images.
DENSIFY_FRACTION = 0.02


@dataclass(frozen=True)
class GraticuleLine:
    """A parallel (``kind == "lat"``) or a meridian (``"lon"``) at ``value`` degrees, labelled
    ``label``, as ``xy`` (n, 2) local metres (NaN where the projection cannot map a point)."""

    kind: str
    value: float
    label: str
    xy: np.ndarray


@dataclass(frozen=True)
class Tick:
    """Where a graticule line crosses an edge of the map: ``edge`` ``"bottom"`` (a meridian, at
    x = ``position`` m) or ``"left"`` (a parallel, at y = ``position`` m)."""

    edge: str
    position: float
    kind: str
    value: float
    label: str


@dataclass(frozen=True)
class Chart:
    """What a chart of the local rectangle ``extent`` ``(x0, x1, y0, y1)`` (m) shows.

    Attributes
    ----------
    lines : tuple of GraticuleLine
        The parallels and meridians that cross the map.
    ticks : tuple of Tick
        Their labelled crossings of the bottom and left edges.
    land : tuple of tuple of ndarray
        Land polygons reaching the map, each its rings (exterior first, then holes) as (n, 2)
        local metres.
    spacing : (float, float)
        The parallels' and the meridians' spacing, degrees.
    frame : GeoFrame or None
        The frame it was computed in (:meth:`place` names points in it).
    source : str
        Where the land comes from.
    """

    extent: tuple
    lines: tuple
    ticks: tuple
    land: tuple
    spacing: tuple
    frame: GeoFrame | None = None
    source: str = LAND_SOURCE

    def place(self, x: float, y: float) -> str:
        """A local point (m) as latitude and longitude in degrees and decimal minutes, as a
        chart gives a position: ``60°07.7′N 5°00.5′E``."""
        lat, lon = self.frame.geographic(x, y)
        return f"{_minutes(float(lat), 'NS')} {_minutes(float(lon), 'EW')}"


def graticule_spacing(span: float) -> float:
    """The largest of :data:`SPACINGS_DEG` that puts at least :data:`MIN_LINES` lines across
    ``span`` degrees (the finest when none does)."""
    for spacing in SPACINGS_DEG:
        if span / spacing >= MIN_LINES:
            return spacing
    return SPACINGS_DEG[-1]


def format_angle(value: float, kind: str, spacing: float) -> str:
    """A latitude (``kind == "lat"``) or longitude (``"lon"``) as a chart labels it: degrees,
    minutes where ``spacing`` is under a degree, seconds where it is under a minute, and the
    hemisphere: ``60°27′N``, ``4°36′E``, ``0°``."""
    if kind == "lon":
        value = (value + 180.0) % 360.0 - 180.0
        if math.isclose(value, -180.0, abs_tol=1e-9):
            value = 180.0
    total = round(abs(value) * 3600.0)
    degrees, rest = divmod(total, 3600)
    minutes, seconds = divmod(rest, 60)
    text = f"{degrees}°"
    if spacing < 1.0 - 1e-12:
        text += f"{minutes:02d}′"
        if spacing < 1.0 / 60.0 - 1e-12:
            text += f"{seconds:02d}″"
    if total == 0 or (kind == "lon" and total == 180 * 3600):  # the equator, the prime and 180th meridians
        return text
    hemisphere = ("N" if value > 0 else "S") if kind == "lat" else ("E" if value > 0 else "W")
    return text + hemisphere


def chart(frame: GeoFrame, extent, *, land: bool = True) -> Chart:
    """The graticule and land of the local rectangle ``extent`` ``(x0, x1, y0, y1)`` (m) of
    ``frame``.

    Raises
    ------
    BananagridError
        An empty or non-finite extent.
    """
    x0, x1, y0, y1 = (float(v) for v in extent)
    if not (all(map(math.isfinite, (x0, x1, y0, y1))) and x1 > x0 and y1 > y0):
        raise BananagridError(f"chart extent = {extent!r}: expected finite x0 < x1, y0 < y1 in metres")
    lat_range, lon_range = _box(frame, (x0, x1, y0, y1))
    lat_step = graticule_spacing(lat_range[1] - lat_range[0])
    lon_step = graticule_spacing(lon_range[1] - lon_range[0])
    lines, ticks = [], []
    for kind, (low, high), step, (other_low, other_high) in (
            ("lat", lat_range, lat_step, lon_range), ("lon", lon_range, lon_step, lat_range)):
        for k in range(math.ceil(low / step - 1e-9), math.floor(high / step + 1e-9) + 1):
            value = k * step
            if kind == "lat" and abs(value) > 90.0:
                continue
            label = format_angle(value, kind, step)
            along = np.linspace(other_low, other_high, SAMPLES)
            lat, lon = (np.full_like(along, value), along) if kind == "lat" else (along, np.full_like(along, value))
            x, y = frame.project_points(np.clip(lat, -90.0, 90.0), _wrapped(lon))
            if not np.any((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)):
                continue  # it clips a corner between samples, or misses the map: nothing to see
            lines.append(GraticuleLine(kind, float(value), label, np.column_stack([x, y])))
            ticks += [Tick("left" if kind == "lat" else "bottom", p, kind, float(value), label)
                      for p in _crossings(frame, (x0, x1, y0, y1), kind, value)]
    polygons = land_polygons(frame, lat_range, lon_range) if land else ()
    return Chart((x0, x1, y0, y1), tuple(lines), tuple(ticks), polygons, (lat_step, lon_step), frame)


def load_land():
    """The bundled land polygons: a NumPy array of shapely Polygons in longitude and latitude
    (degrees), and the text naming their source."""
    shapely = require("shapely", "charts of geographic scenes")
    with resources.files(__package__).joinpath("data", LAND_FILE).open("rb") as stream:
        with np.load(stream, allow_pickle=False) as stored:
            steps, rings, polygons = stored["steps"], stored["ring_offsets"], stored["polygon_offsets"]
            quantum, source = float(stored["quantum"]), str(stored["source"])
    coords = np.cumsum(steps.astype(np.int64), axis=0) * quantum
    return shapely.from_ragged_array(shapely.GeometryType.POLYGON, coords, (rings, polygons)), source


def land_polygons(frame: GeoFrame, lat_range, lon_range) -> tuple:
    """The bundled land within the latitude and longitude box (grown by :data:`CLIP_MARGIN`;
    longitudes may run past +-180), clipped, densified and projected: each polygon its rings
    (exterior first) as (n, 2) local metres."""
    shapely = require("shapely", "charts of geographic scenes")
    polygons, _ = load_land()
    (la0, la1), (lo0, lo1) = lat_range, lon_range
    grow_lat, grow_lon = CLIP_MARGIN * max(la1 - la0, 1e-3), CLIP_MARGIN * max(lo1 - lo0, 1e-3)
    la0, la1 = max(la0 - grow_lat, -90.0), min(la1 + grow_lat, 90.0)
    lo0, lo1 = (-180.0, 180.0) if lo1 - lo0 + 2 * grow_lon >= 360.0 else (lo0 - grow_lon, lo1 + grow_lon)
    bounds = shapely.bounds(polygons)
    densify = DENSIFY_FRACTION * min(la1 - la0, lo1 - lo0)
    found = []
    for shift in (-360.0, 0.0, 360.0):  # the box in the data's [-180, 180]: a box past 180 wraps
        a, b = lo0 - shift, lo1 - shift
        if b < -180.0 or a > 180.0:
            continue
        near = (bounds[:, 2] >= a) & (bounds[:, 0] <= b) & (bounds[:, 3] >= la0) & (bounds[:, 1] <= la1)
        for piece in shapely.clip_by_rect(polygons[near], a, la0, b, la1):
            for part in shapely.get_parts(shapely.segmentize(piece, densify)):
                if part.is_empty or part.geom_type != "Polygon":
                    continue
                rings = [np.asarray(part.exterior.coords)] + [np.asarray(r.coords) for r in part.interiors]
                projected = []
                for ring in rings:
                    x, y = frame.project_points(ring[:, 1], _wrapped(ring[:, 0]))
                    keep = np.isfinite(x) & np.isfinite(y)
                    if keep.sum() >= 3:
                        projected.append(np.column_stack([x[keep], y[keep]]))
                if projected:
                    found.append(tuple(projected))
    return tuple(found)


# --- helpers ----------------------------------------------------------------------------------


def _minutes(value: float, sides: str) -> str:
    """``60°07.7′N``: degrees and minutes to a tenth (about 185 m of latitude)."""
    tenths = round(abs(value) * 600.0)
    degrees, rest = divmod(tenths, 600)
    side = sides[0] if value >= 0.0 else sides[1]
    return f"{degrees}°{rest / 10.0:04.1f}′{side}"


def _wrapped(lon):
    """Longitudes to [-180, 180)."""
    return (np.asarray(lon, dtype=float) + 180.0) % 360.0 - 180.0


def _box(frame: GeoFrame, extent) -> tuple[tuple[float, float], tuple[float, float]]:
    """The latitude and longitude ranges (degrees) of the rectangle, from its boundary walked
    once round; longitudes unwrapped (they may run past +-180 across the antimeridian), and
    every longitude where a pole lies inside."""
    x0, x1, y0, y1 = extent
    side = np.linspace(0.0, 1.0, SAMPLES)[:-1]
    xs = np.concatenate([x0 + (x1 - x0) * side, np.full_like(side, x1), x1 - (x1 - x0) * side, np.full_like(side, x0)])
    ys = np.concatenate([np.full_like(side, y0), y0 + (y1 - y0) * side, np.full_like(side, y1), y1 - (y1 - y0) * side])
    lat, lon = frame.geographic(xs, ys)
    lon = np.degrees(np.unwrap(np.radians(np.append(lon, lon[0]))))
    lat_range = [float(np.min(lat)), float(np.max(lat))]
    lon_range = (float(np.min(lon[:-1])), float(np.max(lon[:-1])))
    for pole in (90.0, -90.0):
        px, py = frame.project_points(pole, 0.0)
        if np.isfinite(px) and x0 <= float(px) <= x1 and y0 <= float(py) <= y1:
            lat_range = [min(lat_range[0], pole), max(lat_range[1], pole)]
            lon_range = (-180.0, 180.0)
    if abs(lon[-1] - lon[0]) > 180.0:  # the boundary winds round a pole
        lon_range = (-180.0, 180.0)
    return (lat_range[0], lat_range[1]), lon_range


def _crossings(frame: GeoFrame, extent, kind: str, value: float) -> list[float]:
    """Where the parallel (left edge, y) or meridian (bottom edge, x) at ``value`` crosses the
    map's edge, m: sign changes of the sampled edge refined by Brent's method."""
    brentq = require("scipy.optimize", "charts of geographic scenes").brentq
    x0, x1, y0, y1 = extent

    def offset(s):
        edge = np.full_like(s, x0 if kind == "lat" else y0)
        lat, lon = frame.geographic(*((edge, s) if kind == "lat" else (s, edge)))
        lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
        return lat - value if kind == "lat" else (lon - value + 180.0) % 360.0 - 180.0

    low, high = (y0, y1) if kind == "lat" else (x0, x1)
    s = np.linspace(low, high, SAMPLES)
    f = offset(s)
    found = [float(u) for u in s[f == 0.0]]
    for k in np.flatnonzero((f[:-1] * f[1:] < 0.0) & (np.abs(f[:-1] - f[1:]) < 90.0)):  # not the +-180 seam
        found.append(float(brentq(lambda u: float(offset(np.array([u]))[0]), s[k], s[k + 1], xtol=EDGE_TOLERANCE_M)))
    return sorted(found)
