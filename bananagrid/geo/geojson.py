"""Search areas as GeoJSON (RFC 7946), for QGIS, Leaflet, geojson.io and chart plotters.

:func:`write_geojson` writes one ``FeatureCollection``, in WGS84 longitude and latitude
(degrees, as RFC 7946 requires; no ``crs`` member), with one ``Feature`` per layer, elapsed time
and probability level, in that order. Each feature's geometry is the level's search area
(:func:`bananagrid.geo.areas.search_areas`) carried from the grid's plane to the ellipsoid
vertex by vertex (pyproj), as a ``MultiPolygon``: exterior rings counter-clockwise, holes
clockwise (RFC 7946, section 3.1.6), coordinates rounded to 1e-7 degrees (about 1 cm; section
11.2) with validity kept (shapely ``set_precision``). A level the grid does not hold has a
``null`` geometry and ``reached: false``.

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

__all__ = ["COORDINATE_DECIMALS", "area_features", "write_geojson"]

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
        No frame (GeoJSON is longitude and latitude), bad panels or levels, or a failure while
        writing (nothing is left behind).
    """
    checked = check_panels(panels)
    frame = frame_of(checked, frame)
    if frame is None:
        raise BananagridError(
            "GeoJSON search areas are in longitude and latitude: the maps need a geographic frame "
            "(a scene's [geo] table, or frame=GeoFrame(...))"
        )
    levels = mass_levels(levels)
    known = dict(areas or {})
    features = []
    for panel in checked:
        found = known.get((panel.layer, panel.t))
        if found is None or [a.level for a in found] != list(levels):
            found = search_areas(panel.raster, levels)
        features += area_features(panel.layer, panel.t, found, frame)
    collection = {
        "type": "FeatureCollection",
        "bananagrid": {"version": __version__, "title": title, "frame": frame.describe(),
                       "quantity": "smallest areas holding each probability level of the target's position"},
        "features": features,
    }
    with writing(path, "GeoJSON file", stage=stage) as partial:
        partial.write_text(json.dumps(collection, allow_nan=False) + "\n", encoding="utf-8")
    return Path(path)


def _to_lonlat(geometry, frame, shapely):
    """A MultiPolygon in local metres as a valid, RFC 7946-oriented MultiPolygon of (lon, lat)."""
    def lonlat(xy: np.ndarray) -> np.ndarray:
        lat, lon = frame.geographic(xy[:, 0], xy[:, 1])
        return np.column_stack([lon, lat])

    moved = shapely.set_precision(shapely.transform(geometry, lonlat), 10.0 ** -COORDINATE_DECIMALS)
    # The nearest double to each 7-decimal value, so that the JSON prints 7 decimals, not 16.
    moved = shapely.transform(moved, lambda xy: np.round(xy, COORDINATE_DECIMALS))
    parts = [shapely.geometry.polygon.orient(p, sign=1.0) for p in shapely.get_parts(moved)
             if isinstance(p, shapely.Polygon) and not p.is_empty]
    return shapely.MultiPolygon(parts)


def _plain(value: float) -> float | None:
    """NaN (a level not reached) as JSON null."""
    return None if math.isnan(value) else float(value)
