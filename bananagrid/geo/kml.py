"""Search areas and landmarks as KML 2.2, for Google Earth, chart plotters and GIS tools.

:func:`write_kml` writes one KML document (OGC 07-147r2, namespace
``http://www.opengis.net/kml/2.2``) in WGS84 longitude and latitude:

* a folder per layer, in it a folder per elapsed time (with its UTC time as a ``TimeStamp``
  where the frame has one, so that Google Earth's time slider steps through them), and in it a
  placemark per probability level the grid reaches: the level's search area as a
  ``MultiGeometry`` of ``Polygon`` elements, exactly the polygons of the GeoJSON export
  (:func:`bananagrid.geo.geojson.area_features`: cut at the antimeridian and round a pole,
  exterior rings counter-clockwise, holes clockwise, coordinates to 1e-7 degrees), with the
  probability they hold, its bound and the area in the description and as ``ExtendedData``;
* one shared style per level (outline and a translucent fill, the inner levels drawn warmer and
  on top), so that a plotter shows the 50 % area over the 99 % one;
* a folder ``LAYER landmarks`` per layer: its last fix and stations as point placemarks and its
  bearing lines as line strings (what the model's ``landmarks()`` gives, in local metres).

Plain XML (the standard library's ElementTree) rather than a KML library: the document uses six
element types, and the geometry, already cut for the antimeridian and the poles, is the GeoJSON
writer's. The file is written to a temporary name and renamed when complete.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ..contours import DEFAULT_MASS_LEVELS
from ..version import __version__
from .files import writing
from .geojson import COORDINATE_DECIMALS, area_features, lonlat_panels, panel_areas

__all__ = ["KML_NAMESPACE", "write_kml", "level_style", "STYLE_COLOURS"]

KML_NAMESPACE = "http://www.opengis.net/kml/2.2"
#: Outline colours of the levels, innermost first, as KML's ``aabbggrr`` without the alpha:
#: red, orange, yellow, then blues (the recording's contour colours run the same way).
STYLE_COLOURS = ("2020e0", "2080f0", "20d0f0", "f0a030", "c06020", "803010")
#: Opacity of a search area's fill (hex alpha): translucent, so the chart shows through.
FILL_ALPHA = "40"
#: Vertices of a bearing line in the plane, each carried to the ellipsoid (as the map view draws it).
LINE_POINTS = 65


def level_style(level: float) -> str:
    """The id of a level's style: ``p50``, ``p99_5``."""
    return "p" + f"{level * 100.0:g}".replace(".", "_")


def write_kml(path: str | os.PathLike, panels: Sequence, frame=None,
              levels: Iterable[float] = DEFAULT_MASS_LEVELS, *, title: str = "",
              areas: Mapping | None = None, marks: Mapping | None = None, stage=None) -> Path:
    """Write the search areas of a scene's maps, and its landmarks, as one KML file.

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
        The document's name.
    areas : mapping of (layer, t) to list of SearchArea, optional
        Search areas already found (at ``levels``); the others are found here.
    marks : mapping of str to dict, optional
        Per layer, its model's ``landmarks()``: ``"fix"`` (x, y), ``"stations"`` (n, 2) and
        ``"bearings"`` (pairs of points), local metres.
    stage : callable, optional
        Default: written to a temporary name and renamed when complete; a run passes its
        :meth:`bananagrid.atomic.OutputSet.stage`.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    BananagridError
        No frame (KML is longitude and latitude), bad panels or levels, a frame whose CRS's
        round trip over the grid is off by more than 1 mm, a search area smaller than the
        coordinates' precision, or a failure while writing (nothing is left behind).
    """
    checked, frame, levels = lonlat_panels("KML", panels, frame, levels)
    ET.register_namespace("", KML_NAMESPACE)
    kml = ET.Element(_tag("kml"))
    document = _child(kml, "Document")
    _text(document, "name", title or "bananagrid search areas")
    _text(document, "description", f"Smallest areas holding each probability of the target's position; "
                                   f"bananagrid {__version__}. {_frame_text(frame)}")
    for k, level in enumerate(levels):
        _style(document, level, STYLE_COLOURS[k % len(STYLE_COLOURS)], len(levels) - k)
    _point_style(document, "fix", "ff2020e0")
    _point_style(document, "station", "ffe0a020")
    layers: dict[str, list] = {}
    for panel in checked:
        layers.setdefault(panel.layer, []).append(panel)
    for layer, series in layers.items():
        folder = _child(document, "Folder")
        _text(folder, "name", layer)
        if marks and layer in marks:
            _landmarks(folder, layer, marks[layer], frame)
        for panel in sorted(series, key=lambda p: p.t):
            _time_folder(folder, panel, area_features(panel.layer, panel.t, panel_areas(panel, areas, levels), frame))
    ET.indent(kml)
    with writing(path, "KML file", stage=stage) as partial:
        ET.ElementTree(kml).write(partial, encoding="utf-8", xml_declaration=True)
    return Path(path)


def _tag(name: str) -> str:
    return f"{{{KML_NAMESPACE}}}{name}"


def _child(parent, tag: str, **attrs):
    return ET.SubElement(parent, _tag(tag), attrs)


def _text(parent, tag: str, text: str):
    element = _child(parent, tag)
    element.text = text
    return element


def _frame_text(frame) -> str:
    described = frame.describe()
    when = f", t = 0 at {described['time']}" if described["time"] else ""
    return f"Local origin (the last fix) {frame.lat:g}, {frame.lon:g} (WGS84){when}."


def _style(document, level: float, colour: str, order: int) -> None:
    style = _child(document, "Style", id=level_style(level))
    line = _child(style, "LineStyle")
    _text(line, "color", "ff" + colour)
    _text(line, "width", f"{1.0 + 0.5 * order:g}")
    poly = _child(style, "PolyStyle")
    _text(poly, "color", FILL_ALPHA + colour)


def _point_style(document, name: str, colour: str) -> None:
    style = _child(document, "Style", id=name)
    icon = _child(style, "IconStyle")
    _text(icon, "color", colour)
    _text(_child(icon, "Icon"), "href", "http://maps.google.com/mapfiles/kml/shapes/placemark_circle.png")


def _time_folder(parent, panel, features: list[dict]) -> None:
    folder = _child(parent, "Folder")
    utc = features[0]["properties"]["time_utc"] if features else None
    _text(folder, "name", f"{panel.layer} t = {panel.t:g} s" + (f" ({utc})" if utc else ""))
    missing = [f"{f['properties']['level']:g}" for f in features if f["geometry"] is None]
    if missing:  # levels the grid does not reach: said, not drawn (KML's order: description, then time)
        _text(folder, "description", f"The grid holds less than {', '.join(missing)}: no area at "
                                     f"{'that level' if len(missing) == 1 else 'those levels'}.")
    if utc:
        _text(_child(folder, "TimeStamp"), "when", utc)
    for feature in features:
        props = feature["properties"]
        if feature["geometry"] is None:
            continue
        placemark = _child(folder, "Placemark")
        _text(placemark, "name", f"{100.0 * props['level']:g} %")
        _text(placemark, "description",
              f"Smallest area holding {100.0 * props['level']:g} % of the target's probability (layer "
              f"{props['layer']}, t = {props['t_s']:g} s): it holds {props['probability']:.6f} "
              f"(within {props['resolution']:.2g} of the level at this grid's cells), {props['area_km2']:.6g} km2.")
        if utc:
            _text(_child(placemark, "TimeStamp"), "when", utc)
        _text(placemark, "styleUrl", "#" + level_style(props["level"]))
        data = _child(placemark, "ExtendedData")
        for key in ("layer", "t_s", "time_utc", "level", "probability", "resolution", "area_km2", "cells"):
            if props[key] is not None:
                _text(_child(data, "Data", name=key), "value", str(props[key]))
        geometry = _child(placemark, "MultiGeometry")
        for polygon in feature["geometry"]["coordinates"]:
            _polygon(geometry, polygon)


def _polygon(parent, rings: list) -> None:
    polygon = _child(parent, "Polygon")
    _text(polygon, "tessellate", "1")  # edges follow the ground, not a chord through it
    for k, ring in enumerate(rings):
        boundary = _child(polygon, "outerBoundaryIs" if k == 0 else "innerBoundaryIs")
        _text(_child(boundary, "LinearRing"), "coordinates", _coordinates(ring))


def _coordinates(points) -> str:
    """``lon,lat`` tuples separated by spaces: the GeoJSON's numbers, printed as they are (the
    shortest repr of each, 7 decimals at most)."""
    return " ".join(f"{float(lon)!r},{float(lat)!r}" for lon, lat in points)


def _lonlat(frame, xy) -> np.ndarray:
    xy = np.reshape(np.asarray(xy, dtype=float), (-1, 2))
    lat, lon = frame.geographic(xy[:, 0], xy[:, 1])
    return np.round(np.column_stack([lon, lat]), COORDINATE_DECIMALS)


def _landmarks(parent, layer: str, found: Mapping, frame) -> None:
    folder = _child(parent, "Folder")
    _text(folder, "name", f"{layer} landmarks")
    for key, label, style in (("fix", "last fix", "fix"), ("stations", "station", "station")):
        if key not in found:
            continue
        points = _lonlat(frame, found[key])
        for k, (lon, lat) in enumerate(points):
            placemark = _child(folder, "Placemark")
            name = label if len(points) == 1 else f"{label} {k + 1}"
            _text(placemark, "name", name)
            _text(placemark, "description", f"{name}: {lat:.7f}, {lon:.7f} (WGS84 latitude, longitude)")
            _text(placemark, "styleUrl", "#" + style)
            _text(_child(placemark, "Point"), "coordinates", _coordinates([(lon, lat)]))
    along = np.linspace(0.0, 1.0, LINE_POINTS)[:, None]
    for k, (start, end) in enumerate(found.get("bearings", ())):
        start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
        points = _lonlat(frame, start + along * (end - start))
        placemark = _child(folder, "Placemark")
        _text(placemark, "name", f"bearing {k + 1}")
        style = _child(placemark, "Style")
        line = _child(style, "LineStyle")
        _text(line, "color", "ffe0a020")
        _text(line, "width", "1.5")
        string = _child(placemark, "LineString")
        _text(string, "tessellate", "1")
        _text(string, "coordinates", _coordinates(points))
