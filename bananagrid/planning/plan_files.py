"""A plan's areas and tracks as GeoJSON (RFC 7946, WGS84 longitude and latitude), written to a
temporary name and renamed when complete."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..geo.files import writing
from ..geo.geojson import line_lonlat, polygons_lonlat
from ..geo.libraries import require
from ..validate import BananagridError
from ..version import __version__


def plan_collection(areas, summary: dict, frame) -> dict:
    """A FeatureCollection of ``areas``: (polygon in local metres, list of track polylines in
    local metres, properties), each as an area feature and a track feature; ``summary`` goes in
    the collection's ``bananagrid`` member with the version and the frame."""
    if frame is None:
        raise BananagridError("GeoJSON is in longitude and latitude: the map needs a geographic frame "
                              "(a scene's [geo] table, or Raster.frame)")
    shapely = require("shapely")
    features = []
    for index, (polygon, tracks, properties) in enumerate(areas):
        lonlat = polygons_lonlat(polygon, frame)
        features.append({"type": "Feature", "geometry": shapely.geometry.mapping(lonlat),
                         "properties": {"kind": "area", "area": index, **properties}})
        lines = [part for track in tracks for part in line_lonlat(np.asarray(track), frame)]
        features.append({"type": "Feature", "geometry": {"type": "MultiLineString", "coordinates": lines},
                         "properties": {"kind": "track", "area": index,
                                        "track_spacing_m": properties.get("track_spacing_m")}})
    return {"type": "FeatureCollection",
            "bananagrid": {"version": __version__, **summary, "frame": frame.describe()},
            "features": features}


def write_collection(path: str | os.PathLike, collection: dict) -> Path:
    """Write a FeatureCollection as JSON to ``path`` (temporary name, renamed when complete)."""
    with writing(path, "GeoJSON file") as partial:
        partial.write_text(json.dumps(collection, allow_nan=False) + "\n", encoding="utf-8")
    return Path(path)


class PlanGeoJSON:
    """What a plan (rectangles or bands) shares: its GeoJSON. A plan has ``pos``, ``ideal_pos``,
    ``effort``, ``sweep_width``, ``law`` and ``frame``, and lists its areas with
    ``geojson_areas()``: (polygon, tracks, properties) each."""

    def geojson(self) -> dict:
        """The plan's areas (Polygons) and sweep legs (MultiLineStrings) as an RFC 7946
        FeatureCollection in WGS84 longitude and latitude; needs a geographic map."""
        summary = {"pos": self.pos, "ideal_pos": self.ideal_pos, "effort_m2": self.effort,
                   "sweep_width_m": self.sweep_width, "law": self.law}
        return plan_collection(self.geojson_areas(), summary, self.frame)

    def write_geojson(self, path: str | os.PathLike) -> Path:
        """Write :meth:`geojson` to ``path`` (a temporary name, renamed when complete)."""
        return write_collection(path, self.geojson())
