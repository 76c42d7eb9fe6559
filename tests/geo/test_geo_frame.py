"""The geographic frame: local metres against pyproj's geodesics, true and grid bearings,
UTC times, and the [geo] table of scenes with every bad key named.

The oracle is pyproj's ``Geod`` (Karney's geodesic algorithms on the WGS84 ellipsoid, accurate
to 15 nm), not the projection the frame uses.
"""

from __future__ import annotations

import importlib
import math
import warnings
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyproj
import pytest

from bananagrid import BananagridError
from bananagrid.geo import libraries
from bananagrid.geo.frame import GeoFrame, parse_utc
from bananagrid.scenes.load import load_scene, parse_scene
from geo_cases import FRAME_CRSS

SCENES = Path(__file__).resolve().parents[2] / "scenes"
GEOD = pyproj.Geod(ellps="WGS84")

# Origins: the Norwegian coast, the equator, the southern ocean, next to the antimeridian.
ORIGINS = [(60.45, 4.6), (0.0, -30.0), (-52.3, 170.1), (35.0, 179.95), (78.2, 15.6)]


def random_points(rng, n: int, half: float) -> tuple[np.ndarray, np.ndarray]:
    return rng.uniform(-half, half, n), rng.uniform(-half, half, n)


@pytest.mark.parametrize("lat, lon", ORIGINS)
def test_aeqd_distances_and_azimuths_from_the_origin_are_true(lat, lon):
    frame = GeoFrame(lat, lon)
    rng = np.random.default_rng(1)
    x, y = random_points(rng, 200, 80_000.0)
    plat, plon = frame.geographic(x, y)
    azimuth, _, distance = GEOD.inv(np.full_like(x, lon), np.full_like(y, lat), plon, plat)
    # azimuthal equidistant: the plane distance and direction from the centre are the
    # geodesic's, to the projection's round-off (PROJ's aeqd inverse is iterative, 1e-9 m)
    np.testing.assert_allclose(distance, np.hypot(x, y), rtol=1e-9, atol=1e-6)
    turn = np.remainder(np.radians(azimuth) - np.arctan2(x, y) + math.pi, 2 * math.pi) - math.pi
    assert np.max(np.abs(turn)) < 1e-9


@pytest.mark.parametrize("crs", ["aeqd", "utm"])
@pytest.mark.parametrize("lat, lon", ORIGINS)
def test_plane_distances_are_within_the_stated_scale_error(lat, lon, crs):
    """Between any two points of a grid, the plane distance differs from the geodesic one by
    no more than the scale error the frame states for that grid."""
    frame = GeoFrame(lat, lon, crs=crs)
    half = 150_000.0
    stated = frame.scale_error((-half, half), (-half, half))
    rng = np.random.default_rng(2)
    x1, y1 = random_points(rng, 300, half)
    x2, y2 = random_points(rng, 300, half)
    lat1, lon1 = frame.geographic(x1, y1)
    lat2, lon2 = frame.geographic(x2, y2)
    _, _, geodesic = GEOD.inv(lon1, lat1, lon2, lat2)
    ratio = np.hypot(x2 - x1, y2 - y1) / geodesic
    # the plane distance is the integral of the scale along the path: within [min k, max k]
    assert np.max(np.abs(ratio - 1.0)) <= stated + 1e-9
    if crs == "aeqd":
        # Snyder (25-2): k - 1 ~ rho^2 / (6 R^2) at the corner, rho = half * sqrt(2)
        assert stated == pytest.approx((half * math.sqrt(2)) ** 2 / (6 * 6_371_000.0**2), rel=0.02)
    else:
        assert stated >= 3.9e-4  # UTM's central scale 0.9996 at least


@pytest.mark.parametrize("lat, lon", ORIGINS)
def test_local_and_geographic_round_trip(lat, lon):
    frame = GeoFrame(lat, lon, crs="utm" if abs(lat) < 80 else "aeqd")
    rng = np.random.default_rng(3)
    x, y = random_points(rng, 100, 50_000.0)
    back = frame.local(*frame.geographic(x, y))
    np.testing.assert_allclose(back[0], x, atol=1e-6)  # 1 um: far below any cell
    np.testing.assert_allclose(back[1], y, atol=1e-6)


def test_utm_frame_is_offset_by_the_origins_projected_position():
    frame = GeoFrame(60.45, 4.6, crs="utm")
    utm = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True)  # 4.6 E: zone 31
    e0, n0 = utm.transform(4.6, 60.45)
    assert frame.false_origin == pytest.approx((e0, n0), abs=1e-6)
    assert frame.crs.to_epsg() == 32631
    assert frame.local(60.45, 4.6) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert GeoFrame(-33.9, 18.4, crs="utm").crs.to_epsg() == 32734  # southern hemisphere, zone 34


@pytest.mark.parametrize("bearing_deg", [0.0, 45.0, 137.0, 200.0, 317.4])
@pytest.mark.parametrize("where", [(0.0, 0.0), (40_000.0, -30_000.0), (-60_000.0, 50_000.0)])
def test_grid_bearing_in_utm_is_the_true_bearing_less_the_meridian_convergence(bearing_deg, where):
    """UTM is conformal: every direction turns by the meridian convergence gamma (pyproj's
    ``get_factors``, computed from the projection's derivatives, not from a geodesic step)."""
    frame = GeoFrame(60.45, 4.6, crs="utm")
    lat, lon = frame.geographic(*where)
    gamma = pyproj.Proj(frame.crs).get_factors(float(lon), float(lat)).meridian_convergence
    grid = frame.grid_bearing(math.radians(bearing_deg), *where)
    expected = math.radians(bearing_deg - gamma)
    assert abs(math.remainder(grid - expected, 2 * math.pi)) < 1e-7  # 2e-5 deg: get_factors' finite differences


@pytest.mark.parametrize("where", [(35_000.0, -35_000.0), (17_000.0, 34_000.0), (-80_000.0, 10_000.0)])
def test_a_grid_bearing_points_along_the_geodesic(where):
    """In the azimuthal projection (not conformal) the grid direction of a true bearing is
    the direction of the geodesic's first 100 m in the plane, to its curvature there."""
    frame = GeoFrame(60.45, 4.4)
    lat, lon = frame.geographic(*where)
    for bearing_deg in (10.0, 100.0, 206.7, 317.4):
        lon2, lat2, _ = GEOD.fwd(float(lon), float(lat), bearing_deg, 100.0)
        x2, y2 = frame.local(lat2, lon2)
        chord = math.atan2(float(x2) - where[0], float(y2) - where[1])
        grid = frame.grid_bearing(math.radians(bearing_deg), *where)
        # a 100 m chord of a path curving by < 1e-6 rad/km turns < 1e-7 rad from its tangent
        assert abs(math.remainder(grid - chord, 2 * math.pi)) < 1e-7


def test_utc_times():
    frame = GeoFrame(60.0, 5.0, time="2026-11-24T07:00:00+01:00")
    assert frame.time == datetime(2026, 11, 24, 6, 0, tzinfo=timezone.utc)
    assert frame.utc(90.5) == datetime(2026, 11, 24, 6, 1, 30, 500000, tzinfo=timezone.utc)
    assert frame.describe()["time"] == "2026-11-24T06:00:00Z"
    assert GeoFrame(60.0, 5.0).utc(10.0) is None
    assert parse_utc(datetime(2026, 1, 1, tzinfo=timezone.utc)) == datetime(2026, 1, 1, tzinfo=timezone.utc)
    assert parse_utc("2026-01-01T00:00:00Z").tzinfo == timezone.utc


@pytest.mark.parametrize("kwargs, message", [
    (dict(lat=91.0, lon=0.0), "lat = 91.0: must lie in [-90, 90] degrees"),
    (dict(lat=0.0, lon=-181.0), "lon = -181.0: must lie in [-180, 180] degrees"),
    (dict(lat=float("nan"), lon=0.0), "lat = nan: must lie in [-90, 90] degrees"),
    (dict(lat=90.0, lon=0.0), "lat = 90: a pole has no north for bearings"),
    (dict(lat="60", lon=0.0), 'lat = "60": expected a number of degrees'),
    (dict(lat=0.0, lon=0.0, crs="EPSG:4326"), 'crs = "EPSG:4326": WGS 84 is not a projected CRS'),
    (dict(lat=0.0, lon=0.0, crs="EPSG:2263"), 'crs = "EPSG:2263": NAD83 / New York Long Island (ftUS) has axes in US survey foot; expected metres'),
    (dict(lat=0.0, lon=0.0, crs="mercator please"), 'crs = "mercator please": not a CRS pyproj knows'),
    (dict(lat=0.0, lon=0.0, time="yesterday"), 'time = "yesterday": not an ISO 8601 time'),
    (dict(lat=0.0, lon=0.0, time="2026-11-24T06:00:00"), 'time = "2026-11-24T06:00:00": give the UTC offset'),
    (dict(lat=0.0, lon=0.0, time=1234), "time = 1234: expected an ISO 8601 UTC time"),
])
def test_bad_frames_are_one_line_errors(kwargs, message):
    with pytest.raises(BananagridError) as info:
        GeoFrame(**kwargs)
    assert str(info.value).startswith(message), str(info.value)


def test_points_outside_the_globe_are_refused():
    frame = GeoFrame(60.0, 5.0)
    with pytest.raises(BananagridError, match=r"latitude 95\.0: must lie in \[-90, 90\] degrees"):
        frame.local([60.0, 95.0], [5.0, 5.0])


# --- scenes -------------------------------------------------------------------------------------

GEO_SCENE = """\
[scene]
name = "g"

[geo]
origin_latlon = [60.45, 4.40]
time = "2026-11-24T06:10:00Z"

[grid]
x = [-5000.0, 5000.0]
y = [-5000.0, 5000.0]
step = 100.0

[defaults]
sensors_latlon = [[60.1279, 5.0086], [60.7517, 4.7131]]
bearings_deg = [317.4, 206.7]
sigmas_deg = [1.0, 1.5]

[layers.fix]
model = "bearing_fix"

[layers.ship]
model = "cat"
v0 = 5.0
t = 60.0
sigma_a = 0.01
sigma_omega_deg = 0.5
origin_latlon = [60.46, 4.41]
heading_deg = 30.0
"""


def test_a_geographic_scene_converts_positions_and_true_bearings():
    scene = parse_scene(GEO_SCENE)
    frame = scene.geo
    assert (frame.lat, frame.lon, frame.crs_name) == (60.45, 4.40, "aeqd")
    assert frame.time == datetime(2026, 11, 24, 6, 10, tzinfo=timezone.utc)
    fix, ship = scene.layers
    aeqd = pyproj.Transformer.from_crs("EPSG:4326", "+proj=aeqd +lat_0=60.45 +lon_0=4.4 +datum=WGS84", always_xy=True)
    for (x, y), (lat, lon) in zip(fix.params["sensors"], [(60.1279, 5.0086), (60.7517, 4.7131)]):
        assert (x, y) == pytest.approx(aeqd.transform(lon, lat), abs=1e-6)
    # each true bearing becomes the grid direction of its geodesic at its sensor
    for (x, y), true, grid in zip(fix.params["sensors"], (317.4, 206.7), fix.params["bearings"]):
        lat, lon = frame.geographic(x, y)
        lon2, lat2, _ = GEOD.fwd(float(lon), float(lat), true, 100.0)
        x2, y2 = frame.local(lat2, lon2)
        assert abs(math.remainder(grid - math.atan2(float(x2) - x, float(y2) - y), 2 * math.pi)) < 1e-7
    # Marstein lies 0.61 deg of longitude east of the origin at 60.1 N: grid north turns by
    # about 0.61 * sin(60.1 deg) = 0.53 deg there (the meridian convergence)
    assert math.degrees(fix.params["bearings"][0]) == pytest.approx(317.4 - 0.53, abs=0.01)
    assert ship.params["origin"] == pytest.approx(aeqd.transform(4.41, 60.46), abs=1e-6)
    assert ship.params["heading"] == pytest.approx(frame.grid_bearing(math.radians(30.0), *ship.params["origin"]))
    assert scene.scale_error < 1e-6


def test_the_bearing_lines_of_the_bundled_scene_stay_straight_in_the_plane():
    """A bearing fix draws each bearing as a straight grid line from its station. The true line
    is the geodesic; over the grid it departs from the straight line by less than a metre,
    nothing beside the 660 m a 1 deg bearing error spans at 38 km."""
    scene = load_scene(SCENES / "geo_bearing.toml")
    frame, layer = scene.geo, scene.layers[0]
    for (x, y), true_deg, grid in zip(layer.params["sensors"], (317.4, 206.7), layer.params["bearings"]):
        lat, lon = frame.geographic(x, y)
        distances = np.linspace(0.0, 60_000.0, 61)
        lons, lats, _ = GEOD.fwd(np.full(61, float(lon)), np.full(61, float(lat)), np.full(61, true_deg), distances)
        px, py = frame.local(lats, lons)
        off_line = (px - x) * math.cos(grid) - (py - y) * math.sin(grid)
        assert np.max(np.abs(off_line)) < 1.0


def _geo_error(text: str) -> str:
    with pytest.raises(BananagridError) as info:
        parse_scene(text, source="g.toml")
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize("old, new, message", [
    ("origin_latlon = [60.45, 4.40]\n", "", "g.toml: geo.origin_latlon: missing; expected [latitude, longitude] in degrees"),
    ("origin_latlon = [60.45, 4.40]", "origin_latlon = [95.0, 4.40]", "g.toml: geo.origin_latlon = [95.0, 4.4]: expected [latitude in (-90, 90), longitude in [-180, 180]] degrees"),
    ("origin_latlon = [60.45, 4.40]", "origin_latlon = [60.45]", "g.toml: geo.origin_latlon = [60.45]: expected a pair of numbers"),
    ('time = "2026-11-24T06:10:00Z"', 'time = "tomorrow"', 'g.toml: geo.time = "tomorrow": not an ISO 8601 time'),
    ('time = "2026-11-24T06:10:00Z"', 'time = "2026-11-24T06:10:00"', 'g.toml: geo.time = "2026-11-24T06:10:00": give the UTC offset'),
    ('time = "2026-11-24T06:10:00Z"', 'crs = "EPSG:99999"', 'g.toml: geo.crs = "EPSG:99999": not a CRS pyproj knows'),
    ('time = "2026-11-24T06:10:00Z"', "crs = 32632", "g.toml: geo.crs = 32632: expected"),
    ('time = "2026-11-24T06:10:00Z"', "max_scale_error = 2.0", "g.toml: geo.max_scale_error = 2.0: must lie in (0, 1)"),
    ('time = "2026-11-24T06:10:00Z"', "zone = 32", "g.toml: geo.zone: unknown key; allowed: origin_latlon, time, crs, max_scale_error"),
    ("x = [-5000.0, 5000.0]", "x = [-1500000.0, 1500000.0]", "g.toml: grid x = [-1.5e+06, 1.5e+06] m, y = [-5000, 5000] m: the scale error of its projection, geo.crs = \"aeqd\", reaches 0.00925 over it, above the bound 0.001 (geo.max_scale_error)"),
    ("sensors_latlon = [[60.1279, 5.0086], [60.7517, 4.7131]]", "sensors_latlon = [[60.1279, 5.0086], [160.0, 4.7]]", "g.toml: defaults.sensors_latlon[1] = [160.0, 4.7]: expected [latitude in [-90, 90], longitude in [-180, 180]] degrees"),
    ("sensors_latlon = [[60.1279, 5.0086], [60.7517, 4.7131]]", "sensors_latlon = [[60.1279, 5.0086], [60.7517, 4.7131]]\nsensors = [[0.0, 0.0], [1.0, 1.0]]", "g.toml: defaults: give sensors (m) or sensors_latlon ([lat, lon] degrees), not both"),
])
def test_bad_geo_keys_name_the_key(old, new, message):
    assert GEO_SCENE.count(old) == 1
    assert _geo_error(GEO_SCENE.replace(old, new)).startswith(message)


def test_latlon_positions_need_a_geo_table():
    text = GEO_SCENE.replace('[geo]\norigin_latlon = [60.45, 4.40]\ntime = "2026-11-24T06:10:00Z"\n', "")
    assert _geo_error(text).startswith(
        "g.toml: defaults.sensors_latlon = [[60.1279, 5.0086], [60.7517, 4.7131]]: positions in latitude and "
        "longitude need a [geo] table")


def test_a_utm_scene_turns_the_heading_by_the_convergence_at_the_origin():
    text = GEO_SCENE.replace('time = "2026-11-24T06:10:00Z"', 'crs = "utm"')
    ship = parse_scene(text).layers[1]
    frame = parse_scene(text).geo
    lat, lon = frame.geographic(*ship.params["origin"])
    gamma = pyproj.Proj(frame.crs).get_factors(float(lon), float(lat)).meridian_convergence
    assert math.degrees(ship.params["heading"]) == pytest.approx(30.0 - gamma, abs=1e-5)


def test_a_grid_reaching_round_the_earth_has_no_finite_scale_error():
    """Bounds beyond half the circumference (a step of 9.2e18 m) made the refinement run on
    garbage with NumPy warnings; now the scale error is inf at once and the grid is refused."""
    frame = GeoFrame(60.45, 4.6)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert frame.scale_error((-9.2e18, 9.2e18), (-1.0, 1.0)) == math.inf
        with pytest.raises(BananagridError, match=r"scale error of its projection, geo.crs = \"aeqd\", reaches inf"):
            frame.check_extent((-3e7, 0.0), (0.0, 1.0))


def test_a_geographic_scene_without_the_geo_extra_says_how_to_install_it(monkeypatch):
    """Without pyproj (a plain `pip install .`) a [geo] scene is refused in one line naming the
    table and the extra, not as if a key were wrong."""
    real = importlib.import_module

    def without_pyproj(name, *args, **kwargs):
        if name.split(".")[0] == "pyproj":
            raise ImportError(name)
        return real(name, *args, **kwargs)

    monkeypatch.setattr(libraries.importlib, "import_module", without_pyproj)
    with pytest.raises(BananagridError) as info:
        load_scene(SCENES / "geo_ship.toml")
    assert str(info.value).endswith(
        "geo_ship.toml: [geo]: geographic scenes and map files need pyproj: pip install 'bananagrid[geo]' "
        "(or pip install pyproj)")


@pytest.mark.parametrize("crs, lat, lon", FRAME_CRSS)
def test_map_files_carry_gdal_wkt1_that_maps_points_as_the_frame_does(crs, lat, lon):
    """The WKT a map file carries is GDAL's WKT1 (what PROJ 9.1 reads: the WKT2 of PROJ 9.5
    names the azimuthal equidistant by EPSG method 1125, which PROJ 9.1 does not know), and
    read back by pyproj it is the frame's projection: points within 100 km of the origin map to
    the same projected coordinates as the frame's own CRS, to a micrometre (float64 noise of
    1e7 m coordinates is 1e-9 m; a lost or misread parameter moves points by metres or more)."""
    frame = GeoFrame(lat, lon, crs=crs)
    wkt = frame.portable_wkt
    assert wkt.startswith("PROJCS[") and "1125" not in wkt
    if crs == "aeqd":
        assert 'PROJECTION["Azimuthal_Equidistant"]' in wkt
    to_file = pyproj.Transformer.from_crs("EPSG:4326", pyproj.CRS.from_wkt(wkt), always_xy=True)
    x, y = (v.ravel() for v in np.meshgrid(np.linspace(-1e5, 1e5, 5), np.linspace(-1e5, 1e5, 5)))
    plat, plon = frame.geographic(x, y)
    e, n = to_file.transform(plon, plat)
    e0, n0 = frame.projected(*frame.local(plat, plon))  # the frame's own forward projection
    np.testing.assert_allclose(e, e0, rtol=0, atol=1e-6)
    np.testing.assert_allclose(n, n0, rtol=0, atol=1e-6)
