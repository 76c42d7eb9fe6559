"""Geographic scenes anywhere on the globe, at any time of the calendar, in any CRS pyproj takes:
either valid map files or one line naming the key and why.

* the bundled geographic scenes moved (rigidly, in their local plane) to origins at the poles,
  beside them, on the antimeridian and just either side of it, run with every geographic export
  through the command line; each file read back and checked: GeoJSON per RFC 7946 (polygons cut
  at the antimeridian, longitudes in [-180, 180], rings closed, exteriors counter-clockwise,
  every part valid, the ellipsoidal area that of the plane), NetCDF and GeoTIFF coordinates that
  step by the grid's step (never constant);
* search areas over the whole globe (a derandomised property-based sweep of origins, poles and
  the antimeridian included), each cell centre inside the GeoJSON polygons exactly when it lies
  inside the plane's; a polar cap closed along latitude +-90;
* UTC times from year 1 to 9999, across the datetime64[ns] limits, written and read back to the
  microsecond, or refused naming geo.time and the range;
* absurd CRSs (a false easting of 1e20 m, ridiculous scales, a projection whose domain does not
  hold the grid) refused naming geo.crs, the value and the measured error.
"""

from __future__ import annotations

import json
import math
import tomllib
import warnings
from datetime import datetime, timedelta, timezone
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import rasterio
import shapely
import shapely.geometry
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid import BananagridError, cli
from bananagrid.geo.areas import search_areas
from bananagrid.geo.dataset import raster_dataset, write_netcdf
from bananagrid.geo.frame import GeoFrame, iso_utc
from bananagrid.geo.geojson import area_features, write_geojson
from bananagrid.geo.geotiff import write_geotiff
from bananagrid.recording.readback import open_recording, recording_rows
from bananagrid.scenes.load import parse_scene
from geo_cases import (GEOD, check_area, check_geojson, check_geojson_geometry, check_geotiff, check_netcdf, moved_doc,
                       one_line_naming)
from test_scene_fuzz import toml_text

ROOT = Path(__file__).resolve().parents[2]
SCENES = {name: (ROOT / "scenes" / f"{name}.toml").read_text() for name in ("geo_ship", "geo_bearing")}
#: A step of about 40 cells along each scene's wider side: a quick run; the files' geometry does
#: not depend on it.
STEPS = {"geo_ship": 300.0, "geo_bearing": 250.0}

#: Origins over the globe: the poles exactly, 11 m and 1.1 km from them (the grids then hold the
#: pole), the antimeridian as +-180 and 1e-4 degrees (5 m at 60 N) either side of it, and both.
ORIGINS = [
    (90.0, 0.0), (-90.0, 180.0),
    (89.9999, 0.0), (-89.9999, -180.0),
    (60.45, 179.9999), (0.0, 180.0),
]
#: Every origin of the sweep, for the scenes' load (the runs, a few seconds each, take the
#: list above: the maps' files at other origins are swept on synthetic maps below).
EVERY_ORIGIN = ORIGINS + [(89.99, -179.9999), (-89.95, 45.0), (60.45, 180.0), (60.45, -180.0), (60.45, -179.9999),
                          (-45.0, -179.99),
                          (-0.0, -0.0), (45.0, 90.0)]


# --- the bundled scenes, moved --------------------------------------------------------------------

def moved(name: str, lat: float, lon: float) -> str:
    """The bundled scene ``name`` moved to the origin (lat, lon) (:func:`geo_cases.moved_doc`)."""
    return toml_text(moved_doc(tomllib.loads(SCENES[name]), lat, lon))


def test_moving_a_scene_keeps_its_maps():
    """The helper's own check: geo_bearing moved to 0 N 0 E has its bearings still crossing at
    the same local point (the grid's centre region), to 1 m."""
    here = parse_scene(SCENES["geo_bearing"]).layers[0].params
    there = parse_scene(moved("geo_bearing", 0.0, 0.0)).layers[0].params
    np.testing.assert_allclose(there["sensors"], here["sensors"], atol=1e-6)  # the same local metres

    def crossing(params):
        s, b = np.asarray(params["sensors"]), np.asarray(params["bearings"])
        u = np.column_stack([np.sin(b), np.cos(b)])
        a = np.linalg.solve(np.column_stack([u[0], -u[1]]), s[1] - s[0])[0]
        return s[0] + a * u[0]

    # 1 m: the geodesic from a sensor 40 km away leaves its grid bearing by less than 1e-5 rad
    np.testing.assert_allclose(crossing(there), crossing(here), atol=1.0)


@pytest.mark.parametrize("name", sorted(SCENES))
@pytest.mark.parametrize("lat, lon", ORIGINS, ids=[f"{a!r},{o!r}" for a, o in ORIGINS])
def test_bundled_geo_scenes_over_the_globe_with_every_export(tmp_path, capsys, name, lat, lon):
    path = tmp_path / f"{name}.toml"
    path.write_text(moved(name, lat, lon))
    out = tmp_path / "out"
    out.mkdir()
    argv = ["run", str(path), "--out", str(out), "--step", str(STEPS[name]), "--quiet",
            "--netcdf", "--geotiff", "--geojson"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the scenes' own warnings (mass beyond the grid) are fine here
        code = cli.main(argv)
    err = capsys.readouterr().err
    if abs(lat) == 90.0:  # true north has no direction at a pole: refused, naming the key
        assert code == 2
        one_line_naming(err, "geo.origin_latlon")
        assert "is a pole" in err
        assert list(out.iterdir()) == []
        return
    assert code == 0, err
    scene = parse_scene(path.read_text()).with_step(STEPS[name])
    check_map_lines(out / f"{name}.rrd")
    check_geojson(out / f"{name}-areas.geojson")
    check_netcdf(out / f"{name}.nc", scene)
    check_geotiff(out / f"{name}.tif", scene)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_bundled_geo_scenes_load_at_every_origin(name):
    """At each origin of the sweep the moved scene loads (its CRS holds the grid to 1 mm, its
    scale error is within the bound) or, at a pole, is refused naming geo.origin_latlon."""
    for lat, lon in EVERY_ORIGIN:
        try:
            scene = parse_scene(moved(name, lat, lon), source=name)
        except BananagridError as exc:
            assert abs(lat) == 90.0, str(exc)
            one_line_naming(str(exc), "geo.origin_latlon")
            continue
        assert scene.geo.round_trip_error(*np.reshape(scene.grid.extent, (2, 2)))[0] < 1e-6  # see the test below
        assert scene.scale_error < 1e-3


def check_map_lines(rrd: Path) -> None:
    """The recording's map view (rerun's GeoLineStrings: search areas, bearing lines) draws no
    segment the long way round the Earth: each strip steps by less than 180 degrees of longitude."""
    reader, store = open_recording(rrd)
    strips = 0
    for entity, _, cells in recording_rows(reader, store):
        if entity.startswith("/map/") and "GeoLineStrings:line_strings" in cells:
            for strip in cells["GeoLineStrings:line_strings"][1].as_py() or []:
                lon = np.asarray(strip, dtype=float)[:, 1]
                assert np.all(np.abs(np.diff(lon)) <= 180.0), entity
                strips += 1
    assert strips > 0


# --- search areas over the whole globe ------------------------------------------------------------

LATITUDES = st.one_of(st.sampled_from([-90.0, -89.9999, -89.99, 0.0, 89.99, 89.9999, 90.0]), st.floats(-90.0, 90.0))
LONGITUDES = st.one_of(st.sampled_from([-180.0, -179.9999, 179.9999, 180.0]), st.floats(-180.0, 180.0))
STEP = 50.0
HALF = 1500.0


@settings(max_examples=30, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(LATITUDES, LONGITUDES, st.floats(-HALF / 2, HALF / 2), st.floats(-HALF / 2, HALF / 2), st.booleans(),
       st.sampled_from(["aeqd", "utm"]))
def test_search_areas_anywhere_on_the_globe(tmp_path_factory, lat, lon, cx, cy, ring, crs):
    """A blob, or a ring with a hole (a Butterly ring), about (cx, cy) on a 3 km grid about an
    origin anywhere: each level's GeoJSON geometry is valid RFC 7946, and holds a cell centre
    exactly when the plane's polygons do (the centres within 5 % of a cell of the outline, where
    a straight edge in longitude and latitude and one in the plane part, aside); where the
    plane's polygons hold a pole, the MultiPolygon is closed along that pole's latitude from
    -180 to 180. At a pole itself the frame is refused in one line."""
    try:
        frame = GeoFrame(lat, lon, crs=crs)
        x0, x1, y0, y1 = -HALF, HALF, -HALF, HALF
        frame.check_extent((x0, x1), (y0, y1))
    except BananagridError as exc:
        assert abs(lat) == 90.0 or crs == "utm", str(exc)  # a pole, or a UTM zone whose scale drifts
        assert "\n" not in str(exc)
        return
    grid = bg.Grid.from_bounds(x=(x0, x1), y=(y0, y1), step=STEP)
    speed = 8.0 if ring else 0.5
    model = bg.Butterly(mean=(cx, cy), cov=[[200.0**2, 0.0], [0.0, 150.0**2]], speeds=[speed], t=100.0)
    raster = bg.rasterise(model, grid)
    path = tmp_path_factory.mktemp("areas") / "a.geojson"
    areas = search_areas(raster)
    write_geojson(path, [("a", 100.0, raster)], frame)
    features = json.loads(path.read_text())["features"]
    xs, ys = np.meshgrid(raster.x, raster.y)
    poles = [(p, frame.project_points(np.array([p]), np.array([0.0]))) for p in (90.0, -90.0)]
    for feature, area in zip(features, areas):
        if not area.reached:
            continue
        shape = check_geojson_geometry(feature["geometry"])
        clear = shapely.distance(shapely.points(xs, ys), area.geometry.boundary) > 0.05 * STEP
        plat, plon = frame.geographic(xs[clear], ys[clear])
        inside_plane = shapely.contains_xy(area.geometry, xs[clear], ys[clear])
        assert np.array_equal(shapely.contains_xy(shape, plon, plat), inside_plane)
        for pole, (px, py) in poles:
            if np.isfinite(px[0]) and shapely.contains_xy(area.geometry, px[0], py[0]):
                assert shape.covers(shapely.LineString([(-180.0, pole), (180.0, pole)]))
        check_area(shape, feature["properties"]["area_km2"], area.area / 1e6)


def test_a_polar_cap_in_geojson():
    """A disc about the north pole 1.1 km from the origin: one polygon from -180 to 180 whose
    exterior runs east along the disc's edge, up the antimeridian, west along latitude 90 and
    down again, holding the pole (the representation RFC 7946 leaves to the writer, the one GIS
    tools read as a cap); its ellipsoidal area that of the disc."""
    frame = GeoFrame(89.99, 10.0)
    px, py = frame.project_points(np.array([90.0]), np.array([0.0]))
    grid = bg.Grid.from_bounds(x=(px[0] - 1000.0, px[0] + 1000.0), y=(py[0] - 1000.0, py[0] + 1000.0), step=20.0)
    raster = bg.rasterise(bg.Butterly(mean=(px[0], py[0]), cov=[[150.0**2, 0.0], [0.0, 150.0**2]], speeds=[0.1],
                                      t=1.0), grid)
    area = search_areas(raster, [0.9])[0]
    assert shapely.contains_xy(area.geometry, px[0], py[0])
    feature = area_features("a", 1.0, [area], frame)[0]
    shape = check_geojson_geometry(feature["geometry"])
    assert len(shape.geoms) == 1
    lon0, lat0, lon1, lat1 = shape.bounds
    assert (lon0, lon1, lat1) == (-180.0, 180.0, 90.0)
    assert shape.contains(shapely.Point(0.0, 89.9999))
    # the 90 % disc of a circular normal has the radius sigma sqrt(2 ln 10) = 321.9 m: every
    # vertex of the outline (off the pole and the cut along the antimeridian) lies that far
    # from it, to a cell (20 m) of the grid
    ring = np.asarray(feature["geometry"]["coordinates"][0][0])
    edge = ring[(ring[:, 1] < 90.0) & (np.abs(ring[:, 0]) < 180.0)]
    assert len(edge) > 100
    distance = GEOD.inv(edge[:, 0], edge[:, 1], np.zeros(len(edge)), np.full(len(edge), 90.0))[2]
    np.testing.assert_allclose(distance, 150.0 * math.sqrt(2.0 * math.log(10.0)), atol=20.0)
    assert feature["properties"]["area_km2"] == pytest.approx(area.area / 1e6, rel=1e-4)  # aeqd: 2e-9 at 1 km


# --- UTC times over the calendar ------------------------------------------------------------------

def small_raster():
    grid = bg.Grid.from_bounds(x=(-200.0, 200.0), y=(-200.0, 200.0), step=40.0)
    return bg.rasterise(bg.Butterly(mean=(0.0, 0.0), cov=[[60.0**2, 0.0], [0.0, 60.0**2]], speeds=[0.5], t=10.0),
                        grid)


#: Times of the frame and what becomes of geo_ship (times 300, 600, 900 s) there; None: accepted.
CALENDAR = [
    ("0001-01-01T00:00:00Z", None),
    ("0001-01-01T00:30:00+01:00", "outside the calendar"),
    ("1582-10-04T23:59:59Z", None),      # the last Julian day of the CF standard calendar
    ("1582-10-15T00:00:00Z", None),      # the first Gregorian day
    ("1677-09-21T00:12:43Z", None),      # a second before datetime64[ns] begins
    ("1677-09-21T00:12:44Z", None),
    ("2262-04-11T23:32:16Z", None),      # t = 900 s is the last second of datetime64[ns]
    ("2262-04-11T23:32:17Z", None),      # t = 900 s is past it
    ("9999-12-31T23:44:59Z", None),      # t = 900 s is the last second of the calendar
    ("9999-12-31T23:45:00Z", "t = 900 s after it falls outside the calendar"),
    ("9999-12-31T23:59:59.999999Z", "t = 300 s after it falls outside the calendar"),
    ("9999-12-31T23:30:00-01:00", "outside the calendar"),
]


@pytest.mark.parametrize("when, refusal", CALENDAR, ids=[c[0] for c in CALENDAR])
def test_utc_times_over_the_calendar(tmp_path, when, refusal):
    """Accepted at load, and the NetCDF's times read back by netCDF4 (cftime) equal to the
    microsecond the frame's UTC times; or refused naming geo.time and the allowed range."""
    text = SCENES["geo_ship"].replace('time = "2026-11-24T05:40:00Z"', f'time = "{when}"')
    try:
        scene = parse_scene(text, source="s.toml")
    except BananagridError as exc:
        assert refusal is not None, str(exc)
        message = str(exc)
        one_line_naming(message, "geo.time")
        assert refusal in message and "[0001-01-01T00:00:00Z, 9999-12-31T23:59:59.999999Z]" in message, message
        return
    assert refusal is None
    raster = small_raster()
    panels = [("cat", t, raster) for t in scene.times]
    path = write_netcdf(tmp_path / "t.nc", raster_dataset(panels, scene.geo))
    with netCDF4.Dataset(path) as nc:
        var = nc["time"]
        back = netCDF4.num2date(var[:], var.units, var.calendar, only_use_cftime_datetimes=True)
        expected = [scene.geo.utc(t) for t in scene.times]
        assert [b.isoformat() for b in back] == [e.replace(tzinfo=None).isoformat() for e in expected]
        gregorian = expected[0] >= datetime(1582, 10, 15, tzinfo=timezone.utc)  # CF "standard" is Julian before
        assert var.calendar == ("standard" if gregorian else "proleptic_gregorian")
    # the other files' UTC strings: ISO 8601 with four-digit years
    write_geotiff(tmp_path / "t.tif", panels, scene.geo)
    with rasterio.open(tmp_path / "t.tif") as tif:
        assert tif.tags(1)["utc"] == iso_utc(expected[0])
        datetime.fromisoformat(tif.tags(1)["utc"])  # parses back
    assert iso_utc(expected[0])[:4] == f"{expected[0].year:04d}"


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(st.datetimes(min_value=datetime(1, 1, 1), max_value=datetime(9999, 12, 31, 23, 59, 59, 999999),
                    timezones=st.sampled_from([timezone.utc, timezone(timedelta(hours=14)),
                                               timezone(timedelta(hours=-12))])),
       st.floats(1e-3, 1e9))
def test_any_time_and_elapsed_time_is_a_utc_time_or_one_line(when, t):
    """A frame time anywhere in the calendar, in any zone, and an elapsed time up to 30 years:
    the UTC time or the one-line refusal naming the range, never an OverflowError."""
    try:
        frame = GeoFrame(0.0, 0.0, time=when)
        utc = frame.utc(t)
    except BananagridError as exc:
        assert "[0001-01-01T00:00:00Z, 9999-12-31T23:59:59.999999Z]" in str(exc), str(exc)
        return
    assert utc - frame.time == timedelta(seconds=t)
    assert datetime.fromisoformat(iso_utc(utc)) == utc


# --- CRSs that do not hold the grid ---------------------------------------------------------------

#: (origin, crs, what the one-line refusal says beside the key and the value); geo_ship's grid.
#: The doubles near 1e20 lie 16384 m apart (near 1e19, 2048 m): a local point of the grid moves
#: to the nearest of them, x = -7000 m onto the origin's easting; the scale errors are PROJ's
#: (Tissot's indicatrix, pyproj get_factors) at the grid's worst point.
ABSURD = [
    ((60.45, 4.6), "+proj=tmerc +lon_0=4.6 +x_0=1e20 +datum=WGS84 +units=m", "its round trip over the grid x = [-7000, 5000] m, y = [-7500, 1500] m (local metres to latitude and longitude and back) is off by 7e+03 m"),
    ((60.45, 4.6), "+proj=tmerc +lon_0=4.6 +y_0=-1e19 +datum=WGS84 +units=m", "is off by 952 m"),
    ((60.45, 4.6), "+proj=tmerc +lon_0=4.6 +k=1e-20 +datum=WGS84 +units=m", "PROJ cannot transform with it"),
    ((60.45, 4.6), "+proj=tmerc +lon_0=4.6 +k=1000 +datum=WGS84 +units=m", "reaches 999 over it"),
    ((60.45, 4.6), "+proj=tmerc +lon_0=4.6 +k=1e-6 +datum=WGS84 +units=m", "is off by inf m"),
    ((30.0, 60.0), "EPSG:32631", "reaches 0.456 over it"),  # UTM 31 (3 E), 57 degrees off
    ((10.0, 80.0), "EPSG:32631", "its round trip at the origin (local metres to latitude and longitude and back) is off by 0.0834 m"),
    ((0.5, 95.0), "EPSG:32631", "the origin lat 0.5, lon 95 is outside it"),
    ((60.45, 4.6), "+proj=stere +lat_0=-90 +lat_ts=-71 +datum=WGS84 +units=m", "reaches 13.8 over it"),
    ((-60.45, 4.6), "EPSG:3413", "reaches 13.7 over it"),  # NSIDC north polar, south
]


@pytest.mark.parametrize("origin, crs, says", ABSURD, ids=[c[1] for c in ABSURD])
def test_absurd_crs_strings_are_refused_with_the_measured_error(origin, crs, says):
    text = SCENES["geo_ship"].replace("origin_latlon = [60.45, 4.60]", f"origin_latlon = [{origin[0]}, {origin[1]}]")
    text = text.replace('crs = "aeqd"', f'crs = "{crs}"')
    with pytest.raises(BananagridError) as info:
        parse_scene(text, source="s.toml")
    message = str(info.value)
    assert "\n" not in message
    assert f'geo.crs = "{crs}"' in message and says in message, message
    if "reaches" not in says:  # the round trip, PROJ, the origin: the CRS alone is at fault
        assert message.startswith(f's.toml: geo.crs = "{crs}": '), message
    else:  # the scale error: the grid and the CRS together (and the bound, geo.max_scale_error)
        assert message.startswith("s.toml: grid x = [") and "(geo.max_scale_error)" in message, message


def test_a_frame_whose_round_trip_fails_over_a_grid_writes_no_map_file(tmp_path):
    """Through the API a frame is checked at its origin only (a false easting of 1e20 m is
    exact there); each writer checks the round trip over its grid and refuses, where a NetCDF
    of constant coordinates and a GeoJSON of empty polygons were written."""
    frame = GeoFrame(60.45, 4.6, crs="+proj=tmerc +lon_0=4.6 +x_0=1e20 +datum=WGS84 +units=m")
    panels = [("a", 10.0, small_raster())]
    for write in (lambda: write_netcdf(tmp_path / "a.nc", raster_dataset(panels, frame)),
                  lambda: write_geotiff(tmp_path / "a.tif", panels, frame),
                  lambda: write_geojson(tmp_path / "a.geojson", panels, frame)):
        with pytest.raises(BananagridError, match=r'^crs = "\+proj=tmerc .*": its round trip over the grid .* is off by'):
            write()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("lat, lon, crs", [(60.45, 4.6, "aeqd"), (60.45, 4.6, "utm"), (-89.9999, 180.0, "aeqd"),
                                           (89.99, -179.9999, "utm"), (0.0, 180.0, "EPSG:3832")])
def test_good_projections_round_trip_to_a_micrometre(lat, lon, crs):
    """PROJ's forward and inverse of aeqd, UTM and Mercator agree to rounding (the bound is 1 mm;
    a micrometre leaves a margin of 1000)."""
    error, _, _ = GeoFrame(lat, lon, crs=crs).round_trip_error((-7000.0, 5000.0), (-7500.0, 1500.0))
    assert error < 1e-6


def test_a_scene_in_year_one_runs_with_every_export_and_inspects(tmp_path, capsys):
    """geo_bearing dated 0001-01-01 (before datetime64[ns], and before the Gregorian reform):
    every file written, the NetCDF's time read back by netCDF4 in its proleptic Gregorian
    calendar, and `inspect` naming the time with its four-digit year."""
    path = tmp_path / "geo_bearing.toml"
    path.write_text(SCENES["geo_bearing"].replace('time = "2026-11-24T06:10:00Z"', 'time = "0001-01-01T00:00:00Z"'))
    argv = ["run", str(path), "--out", str(tmp_path), "--step", "500", "--quiet", "--netcdf", "--geotiff", "--geojson"]
    assert cli.main(argv) == 0
    with netCDF4.Dataset(tmp_path / "geo_bearing.nc") as nc:
        var = nc["time"]
        (when,) = netCDF4.num2date(var[:], var.units, var.calendar, only_use_cftime_datetimes=True)
        assert (var.calendar, when.isoformat()) == ("proleptic_gregorian", "0001-01-01T00:00:00")
    features = json.loads((tmp_path / "geo_bearing-areas.geojson").read_text())["features"]
    assert {f["properties"]["time_utc"] for f in features} == {"0001-01-01T00:00:00Z"}
    capsys.readouterr()
    assert cli.main(["inspect", str(tmp_path / "geo_bearing.rrd")]) == 0
    assert "exact at t = 0 s (0001-01-01T00:00:00Z)" in capsys.readouterr().out
