"""Search areas as GeoJSON (RFC 7946), for QGIS, Leaflet, geojson.io and chart plotters.

:func:`write_geojson` writes one ``FeatureCollection``, in WGS84 longitude and latitude
(degrees, as RFC 7946 requires; no ``crs`` member), with one ``Feature`` per layer, elapsed time
and probability level, in that order. Each feature's geometry is the level's search area
(:func:`bananagrid.geo.areas.search_areas`) carried from the grid's plane to the ellipsoid
vertex by vertex (pyproj), as a ``MultiPolygon``: exterior rings counter-clockwise, holes
clockwise (RFC 7946, section 3.1.6), coordinates rounded to 1e-7 degrees (about 1 cm; section
11.2) with validity kept (shapely ``set_precision``). A level the grid does not hold has a
``null`` geometry and ``reached: false``; an area that vanishes at that precision (a grid of
sub-centimetre cells) is refused, not written empty.

Anywhere on the globe:

* **the antimeridian**: an area that crosses it is cut there (RFC 7946, section 3.1.9), in the
  plane, along the meridian's trace, so that each part lies on one side, its vertices on the
  cut at exactly +180 or -180: a MultiPolygon whose longitudes all lie in [-180, 180];
* **the poles**: an area that holds a pole is cut also along that pole's meridian 0/180 (both
  halves, through the pole), and each part's corner at the pole is drawn along the pole's
  latitude between the meridians of its neighbours. Merged again at longitude 0, the area is one
  polygon spanning -180 to 180 whose exterior runs along the area's edge, up the antimeridian,
  along latitude 90 (or -90) and down again: the cap that RFC 7946 leaves to the writer
  (section 3.1.9 asks only that geometries not cross the antimeridian), the form Natural
  Earth's Antarctica takes and pyproj's geodesic area measures as the cap; it contains the
  pole in longitude and latitude, and shapely finds it valid. An area with the pole in a hole
  is cut the same way;
* an edge that turns more than 1 degree of longitude round a pole is divided, so that the
  straight edges in longitude and latitude follow the plane's outline.

The maps' origin itself cannot be a pole (true north has no direction there), but a grid about
an origin near one may hold it.

Properties of each feature:

================  =========================================================================
``layer``         the scene's layer
``t_s``           elapsed time since the fix, s
``time_utc``      the UTC time (ISO 8601), or null without a frame time
``level``         the probability asked for
``reached``       whether the grid holds that much
``probability``   the probability inside the polygons, recomputed from the cells
``resolution``    the bound on ``|probability - level|`` from the grid's cells
``area_km2``      area on the WGS84 ellipsoid (pyproj ``Geod.geometry_area_perimeter``), km^2
``area_km2_plane`` area in the scene's plane (the projection's), km^2
``cells``         cells of the region
``density_m2``    the boundary density, per m^2
================  =========================================================================

The collection's foreign member ``bananagrid`` names the version, the title and the frame.
The file is written to a temporary name and renamed when complete.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ..contours import DEFAULT_MASS_LEVELS, mass_levels
from ..validate import BananagridError
from ..version import __version__
from .areas import SHAPELY_PURPOSE, SearchArea, search_areas
from .files import writing
from .frame import iso_utc
from .libraries import require
from .panels import check_panels, frame_of

__all__ = ["COORDINATE_DECIMALS", "area_features", "write_geojson", "lonlat_panels", "panel_areas", "polygons_lonlat",
           "line_lonlat"]

#: Decimal places of the longitudes and latitudes: 1e-7 degrees is 1.1 cm of latitude.
COORDINATE_DECIMALS = 7


def area_features(layer: str, t: float, areas: Iterable[SearchArea], frame) -> list[dict]:
    """GeoJSON features (dicts) of one layer's search areas at elapsed time ``t``."""
    shapely = require("shapely", SHAPELY_PURPOSE)
    geod = require("pyproj").Geod(ellps="WGS84")
    utc = frame.utc(t)
    features = []
    for area in areas:
        geometry, area_km2 = None, None
        if area.reached and not area.geometry.is_empty:
            lonlat = _to_lonlat(area.geometry, frame, shapely)
            if lonlat.is_empty:
                raise BananagridError(
                    f"GeoJSON: the {area.level:g} search area of layer {layer} at t = {t:g} s "
                    f"({area.area:.3g} m2 in the plane) vanishes at the {10.0 ** -COORDINATE_DECIMALS:g} degree "
                    "precision of GeoJSON coordinates (about 1 cm): use a grid whose areas are larger (grid.step)"
                )
            geometry = shapely.geometry.mapping(lonlat)
            # Oriented counter-clockwise outside, clockwise holes: the signed area is the area.
            area_km2 = geod.geometry_area_perimeter(lonlat)[0] / 1e6
        features.append({
            "type": "Feature",
            "geometry": geometry,
            "properties": {
                "layer": layer,
                "t_s": t,
                "time_utc": None if utc is None else iso_utc(utc),
                "level": area.level,
                "reached": area.reached,
                "probability": _plain(area.probability),
                "resolution": _plain(area.resolution),
                "area_km2": area_km2,
                "area_km2_plane": area.area / 1e6,
                "cells": area.cells,
                "density_m2": _plain(area.density),
            },
        })
    return features


def write_geojson(path: str | os.PathLike, panels: Sequence, frame=None,
                  levels: Iterable[float] = DEFAULT_MASS_LEVELS, *, title: str = "",
                  areas: Mapping | None = None, stage=None) -> Path:
    """Write the search areas of a scene's maps as one GeoJSON file (see the module).

    Parameters
    ----------
    path : path-like
        The file to write; its directory must exist.
    panels : sequence of (str, float, Raster)
        ``(layer_name, t, raster)``, all on one grid.
    frame : GeoFrame, optional
        Where the grid lies on the Earth; default the rasters' own ``frame``.
    levels : iterable of float
        Probabilities in (0, 1); default 0.5, 0.9, 0.95, 0.99.
    title : str
        The scene's title, in the collection's ``bananagrid`` member.
    areas : mapping of (layer, t) to list of SearchArea, optional
        Search areas already found (at ``levels``) for some panels; the others are found here.
    stage : callable, optional
        Default: written to a temporary name and renamed when complete; a run passes its
        :meth:`bananagrid.atomic.OutputSet.stage` to rename it with its other files.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    BananagridError
        No frame (GeoJSON is longitude and latitude), a frame whose CRS's round trip over the
        grid is off by more than 1 mm (:meth:`GeoFrame.check_round_trip`), bad panels or levels,
        a search area smaller than the coordinates' precision, or a failure while writing
        (nothing is left behind).
    """
    checked, frame, levels = lonlat_panels("GeoJSON", panels, frame, levels)
    features = []
    for panel in checked:
        features += area_features(panel.layer, panel.t, panel_areas(panel, areas, levels), frame)
    collection = {
        "type": "FeatureCollection",
        "bananagrid": {"version": __version__, "title": title, "frame": frame.describe(),
                       "quantity": "smallest areas holding each probability level of the target's position"},
        "features": features,
    }
    with writing(path, "GeoJSON file", stage=stage) as partial:
        partial.write_text(json.dumps(collection, allow_nan=False) + "\n", encoding="utf-8")
    return Path(path)


def lonlat_panels(what: str, panels: Sequence, frame, levels) -> tuple[list, object, tuple]:
    """What a writer of search areas in longitude and latitude (GeoJSON, KML) checks first: the
    panels (:func:`~bananagrid.geo.panels.check_panels`), their frame (refused without one), the
    levels, and the frame's round trip over the grid (polygons placed where the model put them,
    to a millimetre). ``what`` names the file kind in the refusal."""
    checked = check_panels(panels)
    frame = frame_of(checked, frame)
    if frame is None:
        raise BananagridError(
            f"{what} search areas are in longitude and latitude: the maps need a geographic frame "
            "(a scene's [geo] table, or frame=GeoFrame(...))"
        )
    levels = mass_levels(levels)
    x0, x1, y0, y1 = checked[0].raster.grid.extent
    frame.check_round_trip((x0, x1), (y0, y1))
    return checked, frame, levels


def panel_areas(panel, areas: Mapping | None, levels) -> list[SearchArea]:
    """A panel's search areas at ``levels``: those in ``areas`` (by ``(layer, t)``) if found at
    these levels already, else found here."""
    found = (areas or {}).get((panel.layer, panel.t))
    if found is None or [a.level for a in found] != list(levels):
        found = search_areas(panel.raster, levels)
    return found


def _to_lonlat(geometry, frame, shapely):
    """A MultiPolygon in local metres as a valid, RFC 7946-oriented MultiPolygon of (lon, lat),
    cut at the antimeridian and, where it holds a pole, along the pole's meridians (see the
    module's description)."""
    poles = _poles(frame)
    pieces = []
    for polygon in shapely.get_parts(geometry):
        rings = [_ring_lonlat(frame, np.asarray(r.coords), ()) for r in (polygon.exterior, *polygon.interiors)]
        if _continuous(rings) and not any(shapely.contains_xy(polygon, px, py) for px, py, _ in poles):
            pieces.append(shapely.Polygon(rings[0], rings[1:]))  # the plain case: nothing to cut
            continue
        try:
            cut, antimeridian = _cut(polygon, frame, poles, shapely)
            for piece in cut:
                pieces += _piece_lonlat(piece, frame, poles, antimeridian, shapely)
        except shapely.errors.GEOSException as exc:  # a safety net: GEOS refusing the cut
            raise BananagridError(f"GeoJSON: a search area could not be cut at the antimeridian or a pole ({exc})") from None
    if not pieces:
        return shapely.MultiPolygon()
    merged = shapely.union_all(pieces) if len(pieces) > 1 else pieces[0]
    if not merged.is_valid:
        merged = shapely.make_valid(merged)
    moved = shapely.set_precision(merged, 10.0 ** -COORDINATE_DECIMALS)
    # The nearest double to each 7-decimal value, so that the JSON prints 7 decimals, not 16.
    moved = shapely.transform(moved, lambda xy: np.round(xy, COORDINATE_DECIMALS))
    parts = [shapely.geometry.polygon.orient(p, sign=1.0) for p in shapely.get_parts(moved)
             if isinstance(p, shapely.Polygon) and not p.is_empty]
    return shapely.MultiPolygon(parts)


#: The largest change of longitude (degrees) between two vertices of an outline that is not a
#: crossing of the antimeridian: vertices lie a cell apart, far less than a quarter turn
#: except within a few cells of a pole, whose outlines are cut in the plane in any case.
LONGITUDE_JUMP = 90.0
#: The largest turn of longitude (degrees) along one edge of a polygon in longitude and
#: latitude: an edge is straight there (RFC 7946, section 3.1.1) but straight in the plane,
#: so an edge that turns further round a pole is divided; a 1 degree arc lies within 4e-5 of
#: its radius from the chord the plane draws.
MAX_EDGE_TURN = 1.0
#: Vertices of each meridian that cuts an outline in the plane: over a trace a few times the
#: outline's size, chords whose sagitta is far below a millimetre.
MERIDIAN_VERTICES = 2049
#: How near (m) a vertex must lie to a cutting meridian, or to a pole, to count as on it: the
#: cut's vertices lie on it to rounding (1e-9 m at 1e7 m of projected coordinates); the cells
#: are at least centimetres wide.
ON_CUT_M = 1e-6


def _ring_lonlat(frame, xy: np.ndarray, poles) -> np.ndarray:
    """A ring (local metres, closed) in (lon, lat), divided as :func:`_dense` divides it."""
    return _lonlat(frame, _dense(frame, xy, poles))


def _dense(frame, xy: np.ndarray, poles) -> np.ndarray:
    """A ring's vertices (local metres, closed) with each edge that turns more than
    :data:`MAX_EDGE_TURN` degrees of longitude divided in the plane (edges to a pole, along a
    meridian, are not)."""
    lon = _lonlat(frame, xy)[:, 0]
    turn = np.abs(np.remainder(np.diff(lon) + 180.0, 360.0) - 180.0)
    at_pole = np.zeros(len(xy), dtype=bool)
    for px, py, _ in poles:
        at_pole |= np.hypot(xy[:, 0] - px, xy[:, 1] - py) <= ON_CUT_M
    divide = np.maximum(np.ceil(turn / MAX_EDGE_TURN), 1).astype(int)
    divide[at_pole[:-1] | at_pole[1:]] = 1
    if np.all(divide == 1):
        return xy
    dense = [xy[:1]]
    for k, parts in enumerate(divide):
        f = np.arange(1, parts + 1)[:, None] / parts
        dense.append(xy[k] + f * (xy[k + 1] - xy[k]))
    return np.concatenate(dense)


def _lonlat(frame, xy: np.ndarray) -> np.ndarray:
    lat, lon = frame.geographic(xy[:, 0], xy[:, 1])
    return np.column_stack([lon, lat])


def _continuous(lonlats: list) -> bool:
    """Whether no ring's longitude jumps (the antimeridian crossed)."""
    return all(np.all(np.abs(np.diff(ring[:, 0])) <= LONGITUDE_JUMP) for ring in lonlats)


def _poles(frame) -> list[tuple[float, float, float]]:
    """``(x, y, latitude)`` of each pole the projection maps to a point of the plane."""
    poles = []
    for lat in (90.0, -90.0):
        x, y = frame.project_points(np.array([lat]), np.array([0.0]))
        if np.isfinite(x[0]) and np.isfinite(y[0]):
            poles.append((float(x[0]), float(y[0]), lat))
    return poles


def _cut(polygon, frame, poles, shapely) -> tuple[list, object]:
    """``polygon`` (local metres) cut along the antimeridian and, where a pole lies near, along
    that pole's whole meridian 0/180 through it: pieces whose longitudes run without a jump,
    none with a pole inside (a pole lies at most on a piece's corner). Returns the pieces and
    the antimeridian's trace in the plane (None where it does not come near)."""
    x0, y0, x1, y1 = polygon.bounds
    span = max(x1 - x0, y1 - y0)
    box = shapely.box(x0 - span, y0 - span, x1 + span, y1 + span)
    edge = np.asarray(box.exterior.segmentize(span / 16.0).coords)
    lat = frame.geographic(edge[:, 0], edge[:, 1])[0]
    lat = lat[np.isfinite(lat)]
    if not lat.size:  # the box lies outside the projection: nothing to cut it by
        return [polygon], None
    low, high = float(np.min(lat)), float(np.max(lat))
    near = [(px, py, plat) for px, py, plat in poles if shapely.contains_xy(box, px, py)]
    if near:  # one line: the antimeridian from the far side to the pole, then the meridian 0 away
        px, py, plat = near[0]
        far = max(low - 0.5 * (high - low) - 1e-6, -90.0) if plat > 0 else min(high + 0.5 * (high - low) + 1e-6, 90.0)
        lats = np.linspace(far, plat, MERIDIAN_VERTICES)[:-1]
        ax, ay = frame.project_points(lats, np.full(lats.shape, 180.0))
        bx, by = frame.project_points(lats[::-1], np.zeros(lats.shape))
        x, y = np.concatenate([ax, [px], bx]), np.concatenate([ay, [py], by])
        anti = len(ax) + 1  # the antimeridian's vertices, the pole included
    else:
        margin = 0.5 * (high - low) + 1e-6
        lats = np.linspace(max(low - margin, -90.0), min(high + margin, 90.0), MERIDIAN_VERTICES)
        x, y = frame.project_points(lats, np.full(lats.shape, 180.0))
        anti = len(x)
    line = np.column_stack([x, y])
    keep = np.all(np.isfinite(line), axis=1)
    antimeridian = line[:anti][keep[:anti]]
    antimeridian = shapely.LineString(antimeridian) if len(antimeridian) >= 2 else None
    if np.count_nonzero(keep) < 2:
        return [polygon], antimeridian
    cutter = shapely.intersection(shapely.LineString(line[keep]), box)
    if cutter.is_empty:
        return [polygon], antimeridian
    pieces = shapely.get_parts(require("shapely.ops", SHAPELY_PURPOSE).split(polygon, cutter))
    return [p for p in pieces if isinstance(p, shapely.Polygon) and not p.is_empty], antimeridian


def _piece_lonlat(piece, frame, poles, antimeridian, shapely) -> list:
    """A cut piece (local metres) as polygons of (lon, lat): a vertex on the antimeridian takes
    the piece's side (+180 or -180), and a vertex at a pole becomes two, at the pole on the
    meridians of its neighbours (an edge along latitude 90 or -90: the way a polar cap closes
    in longitude and latitude)."""
    inside = np.asarray(piece.representative_point().coords)[0]
    side = 1.0 if float(frame.geographic(inside[0:1], inside[1:2])[1][0]) >= 0.0 else -1.0
    rings = []
    for ring in [piece.exterior, *piece.interiors]:
        xy = _dense(frame, np.asarray(ring.coords), poles)[:-1]
        lonlat = _lonlat(frame, xy)
        pole = np.zeros(len(xy), dtype=bool)
        for px, py, plat in poles:
            at = np.hypot(xy[:, 0] - px, xy[:, 1] - py) <= ON_CUT_M
            lonlat[at, 1] = plat
            pole |= at
        if antimeridian is not None:
            on = shapely.distance(shapely.points(xy), antimeridian) <= ON_CUT_M
            lonlat[on & ~pole, 0] = side * 180.0
        # a vertex within the coordinates' precision of the antimeridian, on the cut's far side of
        # the meridian's true trace (the cut follows it by chords): this piece's side of it
        astray = (np.abs(lonlat[:, 0]) > 180.0 - 10.0 ** -COORDINATE_DECIMALS) & (np.sign(lonlat[:, 0]) != side)
        lonlat[astray & ~pole, 0] = side * 180.0
        points = []
        n = len(xy)
        for k in range(n):
            if not pole[k]:
                points.append(lonlat[k])
                continue
            before, after = lonlat[(k - 1) % n], lonlat[(k + 1) % n]
            points.append((before[0], lonlat[k, 1]))
            points.append((after[0], lonlat[k, 1]))
        points = np.asarray(points, dtype=float)
        # the cut's vertices between two others on the antimeridian add nothing to the
        # straight edge along it (the meridian's trace was cut by a few thousand chords)
        edge = points[:, 0] == side * 180.0
        points = points[~(edge & np.roll(edge, 1) & np.roll(edge, -1))]
        rings.append(points)
    if len(rings[0]) < 3:
        return []
    polygon = shapely.Polygon(rings[0], [r for r in rings[1:] if len(r) >= 3])
    if not polygon.is_valid:
        polygon = shapely.make_valid(polygon)
    return [p for p in shapely.get_parts(polygon) if isinstance(p, shapely.Polygon) and not p.is_empty]


def _plain(value: float) -> float | None:
    """NaN (a level not reached) as JSON null."""
    return None if math.isnan(value) else float(value)


def polygons_lonlat(geometry, frame):
    """A (Multi)Polygon in the frame's local metres as an RFC 7946 MultiPolygon of (lon, lat):
    cut at the antimeridian and about the poles as the search areas are (see the module)."""
    shapely = require("shapely", SHAPELY_PURPOSE)
    return _to_lonlat(geometry, frame, shapely)


def line_lonlat(xy, frame) -> list[list[list[float]]]:
    """A polyline in the frame's local metres as the parts of an RFC 7946 MultiLineString in
    (lon, lat): edges that turn more than :data:`MAX_EDGE_TURN` degrees of longitude divided,
    and the line cut where it crosses the antimeridian (each part's end on +-180)."""
    xy = np.asarray(xy, dtype=float)
    lon = _lonlat(frame, xy)[:, 0]
    turn = np.abs(np.remainder(np.diff(lon) + 180.0, 360.0) - 180.0)
    dense = [xy[:1]]
    for k, parts in enumerate(np.maximum(np.ceil(turn / MAX_EDGE_TURN), 1).astype(int)):
        dense.append(xy[k] + (np.arange(1, parts + 1)[:, None] / parts) * (xy[k + 1] - xy[k]))
    lonlat = _lonlat(frame, np.concatenate(dense))
    parts, part = [], [lonlat[0]]
    for a, b in zip(lonlat[:-1], lonlat[1:]):
        if abs(b[0] - a[0]) > 180.0:  # crossing the antimeridian: end this part on it
            east = 180.0 if a[0] > 0 else -180.0
            b_shift = b[0] + (360.0 if a[0] > 0 else -360.0)
            f = (east - a[0]) / (b_shift - a[0])
            lat = a[1] + f * (b[1] - a[1])
            part.append(np.array([east, lat]))
            parts.append(part)
            part = [np.array([-east, lat])]
        part.append(b)
    parts.append(part)
    return [[[round(float(lon), COORDINATE_DECIMALS), round(float(lat), COORDINATE_DECIMALS)] for lon, lat in p]
            for p in parts if len(p) > 1]
