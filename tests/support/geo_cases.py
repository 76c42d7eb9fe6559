"""Shared checks of geographic map files and scenes moved over the globe (for the globe sweep
and the fuzzers): GeoJSON per RFC 7946, NetCDF and GeoTIFF coordinates that are not degenerate,
and a bundled scene moved rigidly to another origin."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
import shapely
import shapely.geometry
import xarray as xr

from bananagrid.geo.frame import GeoFrame
from bananagrid.scenes.load import parse_scene

GEOD = pyproj.Geod(ellps="WGS84")

#: CRSs a user may give (geo.crs: an EPSG code, a PROJ string) with an origin each holds: the
#: projection methods of the field (polar stereographic, Lambert conformal and equal-area, the
#: oblique stereographic of the Dutch grid, Web Mercator, a transverse Mercator by the antimeridian).
FRAME_CRSS = [
    ("EPSG:32632", 60.39, 5.32),
    ("EPSG:3413", 75.0, -40.0),
    ("EPSG:3031", -75.0, 100.0),
    ("EPSG:3035", 52.0, 10.0),
    ("EPSG:28992", 52.1, 5.4),
    ("EPSG:3857", 60.0, 5.0),
    ("+proj=lcc +lat_1=33 +lat_2=45 +lat_0=39 +lon_0=-96 +datum=WGS84 +units=m", 39.5, -95.0),
    ("+proj=tmerc +lat_0=0 +lon_0=179 +k=0.9996 +x_0=500000 +y_0=10000000 +datum=WGS84 +units=m", -17.0, 178.8),
    ("aeqd", 60.45, 4.6),
    ("aeqd", -54.0, -67.0),
    ("utm", -33.9, 18.4),
]


def toml_text(doc: dict) -> str:
    from test_scene_fuzz import toml_text as text  # the fuzzers' writer (imported late: it imports this module)

    return text(doc)


def signed_area(ring: np.ndarray) -> float:
    """Shoelace area of a closed ring in (lon, lat): positive when counter-clockwise."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def check_geojson_geometry(geometry: dict) -> object:
    """RFC 7946 section 3.1.6 and 3.1.9: a MultiPolygon of closed rings of >= 4 positions, the
    exterior counter-clockwise and holes clockwise, longitudes in [-180, 180] (a polygon that
    crosses the antimeridian is cut there into parts), latitudes in [-90, 90], each part valid;
    returns the shapely MultiPolygon."""
    assert geometry["type"] == "MultiPolygon"
    assert geometry["coordinates"], "a reached level with no polygon"
    for polygon in geometry["coordinates"]:
        for k, ring in enumerate(polygon):
            ring = np.asarray(ring, dtype=float)
            assert len(ring) >= 4 and np.array_equal(ring[0], ring[-1])
            assert np.all(np.abs(ring[:, 0]) <= 180.0) and np.all(np.abs(ring[:, 1]) <= 90.0)
            assert (signed_area(ring) > 0.0) == (k == 0), (k, signed_area(ring))
        part = shapely.geometry.shape({"type": "Polygon", "coordinates": polygon})
        assert part.is_valid and not part.is_empty
    shape = shapely.geometry.shape(geometry)
    assert shape.is_valid
    return shape


def check_geojson(path: Path) -> None:
    collection = json.loads(path.read_text())
    assert collection["type"] == "FeatureCollection" and collection["features"]
    for feature in collection["features"]:
        props = feature["properties"]
        if not props["reached"]:
            assert feature["geometry"] is None
            continue
        check_area(check_geojson_geometry(feature["geometry"]), props["area_km2"], props["area_km2_plane"])


def check_area(shape, area_km2: float, plane_km2: float) -> None:
    """The ellipsoid's area (pyproj's geodesic polygon) against the plane's: a part cut or
    closed the wrong way round the globe would be off by a hemisphere. They differ by the
    projection's scale error over the grid (at most geo.max_scale_error = 1e-3, twice that in
    area, 2.5e-3 with a margin) and by the rounding of the vertices to 1e-7 degrees, which moves
    each by at most 0.8 cm (half of 1.1 cm of latitude, diagonally): the perimeter times that."""
    perimeter = GEOD.geometry_area_perimeter(shape)[1]
    assert area_km2 == pytest.approx(plane_km2, rel=2.5e-3, abs=perimeter * 0.008 / 1e6)


def check_netcdf(path: Path, scene) -> None:
    """Coordinates that step by the grid's step (not a constant 1e20), finite latitudes and
    longitudes in range, the UTC times of the scene's elapsed times."""
    with xr.open_dataset(path) as ds:
        for axis, step in (("x", scene.grid.dx), ("y", scene.grid.dy)):
            # projected coordinates up to 2e7 m: float64 rounding 4e-9 m, far below 1e-6 of a step
            np.testing.assert_allclose(np.diff(ds[axis].values), step, rtol=1e-6)
        lat, lon = ds.lat.values, ds.lon.values
        assert np.all(np.isfinite(lat)) and np.all(np.abs(lat) <= 90.0)
        assert np.all(np.isfinite(lon)) and np.all(np.abs(lon) <= 180.0)
        expected_lat, expected_lon = scene.geo.geographic(*np.meshgrid(scene.grid.x, scene.grid.y))
        np.testing.assert_array_equal(lat, expected_lat)
        np.testing.assert_array_equal(lon, expected_lon)
    if scene.geo.time is not None:  # seconds since the frame's time, whatever the calendar's range
        with xr.open_dataset(path, decode_times=False) as ds:
            assert ds.time.attrs["units"].startswith("seconds since ")
            # to the microsecond: beyond datetime64[ns]'s years the times are held in microseconds
            np.testing.assert_allclose(np.sort(ds.time.values), sorted({float(t) for _, t in scene.jobs()}), rtol=0,
                                       atol=1e-6)


def check_geotiff(path: Path, scene) -> None:
    with rasterio.open(path) as tif:
        transform = tif.transform
        assert (transform.a, transform.e) == (scene.grid.dx, -scene.grid.dy)
        x0, x1, y0, y1 = scene.grid.extent
        e0, n0 = scene.geo.false_origin
        assert (tif.bounds.left, tif.bounds.bottom) == pytest.approx((e0 + x0, n0 + y0), abs=1e-6)
        # the file's CRS places the grid's corners where the frame does, to a millimetre (a CRS
        # read back from GeoKeys may spell the same projection otherwise: lat_ts = lat_0 written out)
        back = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(tif.crs.to_wkt()), "EPSG:4326", always_xy=True)
        x, y = np.array([x0, x1, x0, x1]), np.array([y0, y0, y1, y1])
        lon, lat = back.transform(e0 + x, n0 + y)
        want_lat, want_lon = scene.geo.geographic(x, y)
        assert np.all(GEOD.inv(lon, lat, want_lon, want_lat)[2] <= 1e-3)
        assert np.all(np.isfinite(tif.read()))


def one_line_naming(message: str, key: str) -> None:
    assert "\n" not in message.strip() and "Traceback" not in message, message
    assert key in message, message


def moved_doc(doc: dict, lat: float, lon: float) -> dict:
    """A geographic scene (its parsed TOML) with its origin at (lat, lon), its other positions
    moved with it (the same local metres in the new origin's plane) and its true bearings
    recomputed from each sensor to where the original bearings cross (geodesic azimuths), so
    that the maps hold the same mass wherever the scene lies. At a pole only the origin moves
    (the scene is refused there)."""
    doc = copy.deepcopy(doc)
    original = parse_scene(toml_text(doc))
    doc["geo"]["origin_latlon"] = [lat, lon]
    if abs(lat) == 90.0:
        return doc
    old, new = original.geo, GeoFrame(lat, lon)

    def move(point):
        x, y = old.local(*point)
        nlat, nlon = new.geographic(x, y)
        return [float(nlat), float(nlon)]

    for table in (doc.get("defaults", {}), *doc["layers"].values()):
        for key, value in table.items():
            if key.endswith("_latlon"):
                table[key] = [move(p) for p in value] if isinstance(value[0], list) else move(value)
        if "bearings_deg" in table:
            layer = original.layers[0]
            sensors, bearings = np.asarray(layer.params["sensors"]), np.asarray(layer.params["bearings"])
            # the grid bearings' lines cross at the contact: s0 + a u0 = s1 + b u1
            u = np.column_stack([np.sin(bearings), np.cos(bearings)])
            a = np.linalg.solve(np.column_stack([u[0], -u[1]]), sensors[1] - sensors[0])[0]
            clat, clon = new.geographic(*(sensors[0] + a * u[0]))
            table["bearings_deg"] = [
                float(GEOD.inv(slon, slat, float(clon), float(clat))[0] % 360.0) for slat, slon in table["sensors_latlon"]]
    return doc
