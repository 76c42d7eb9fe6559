"""Charts of geographic maps: the graticule lies where PROJ puts its latitudes and longitudes
(checked with a projection built here from its definition, not the frame's), its labels name
the lines at the edges they cross, and the land comes from the bundled Natural Earth file,
offline, with land and sea where the world has them."""

from __future__ import annotations

import math
import re
import socket
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pyproj
import pytest
from hypothesis import HealthCheck, Phase, given, seed, settings, strategies as st
from matplotlib.path import Path as MplPath

from bananagrid import BananagridError
from bananagrid.geo.chart import LAND_FILE, MIN_LINES, SPACINGS_DEG, chart, format_angle, graticule_spacing, load_land
from bananagrid.geo.frame import GeoFrame


def independent_inverse(lat0: float, lon0: float, crs: str):
    """Local metres to (lat, lon), from the projection's definition: aeqd about the origin, or
    the origin's northern or southern UTM zone (zone from the longitude, as UTM defines it)."""
    if crs == "aeqd":
        definition = f"+proj=aeqd +lat_0={lat0!r} +lon_0={lon0!r} +datum=WGS84 +units=m"
    else:
        zone = int((lon0 + 180.0) // 6.0) % 60 + 1
        definition = f"EPSG:{(32600 if lat0 >= 0 else 32700) + zone}"
    forward = pyproj.Transformer.from_crs("EPSG:4326", definition, always_xy=True)
    inverse = pyproj.Transformer.from_crs(definition, "EPSG:4326", always_xy=True)
    e0, n0 = forward.transform(lon0, lat0)

    def to_latlon(x, y):
        lon, lat = inverse.transform(np.asarray(x) + e0, np.asarray(y) + n0)
        return np.asarray(lat), np.asarray(lon)

    return to_latlon


def angle_of(label: str) -> float:
    """The signed degrees a graticule label names (``60°27′N``, ``4°36′30″E``, ``0°``)."""
    match = re.fullmatch(r"(\d+)°(?:(\d\d)′)?(?:(\d\d)″)?([NSEW]?)", label)
    assert match, label
    degrees, minutes, seconds, side = match.groups()
    value = int(degrees) + int(minutes or 0) / 60.0 + int(seconds or 0) / 3600.0
    return -value if side in ("S", "W") else value


def longitude_gap(a, b):
    return np.abs((np.asarray(a) - b + 180.0) % 360.0 - 180.0)


# a fixed seed, not derandomize: a derandomised test's examples depend on the checkout's path
@seed(20261128)
@settings(max_examples=25, deadline=None, derandomize=False, database=None,
          suppress_health_check=[HealthCheck.too_slow], phases=[Phase.explicit, Phase.generate])
@given(lat=st.floats(-80.0, 80.0), lon=st.floats(-180.0, 180.0), crs=st.sampled_from(["aeqd", "utm"]),
       width=st.floats(500.0, 400_000.0), aspect=st.floats(0.4, 3.0), dx=st.floats(-1.0, 1.0),
       dy=st.floats(-1.0, 1.0))
def test_graticule_lies_where_proj_puts_it(lat, lon, crs, width, aspect, dx, dy):
    """Every line's points inside the map have its latitude or longitude (1e-9 deg: float64
    round trips of PROJ are good to ~1e-12 deg, the lines are computed points, not fitted);
    every label sits where its line crosses the edge (1e-6 deg: the crossing is found to 1 mm,
    under 1e-8 deg of latitude); each kind has MIN_LINES lines or more, and fewer than the
    next spacing up would give (the spacings step by at most 2.5)."""
    if crs == "utm":  # the map's centre well inside the origin's zone, as a scene's would be
        central = (int((lon + 180.0) // 6.0) % 60) * 6.0 - 177.0
        lon = central + float(np.clip(lon - central, -2.5, 2.5))
        width = min(width, 150_000.0)
    frame = GeoFrame(lat, lon, crs=crs)
    height = width / aspect
    x0, y0 = dx * width, dy * height
    extent = (x0 - width / 2, x0 + width / 2, y0 - height / 2, y0 + height / 2)
    drawn = chart(frame, extent, land=False)
    to_latlon = independent_inverse(lat, lon, crs)
    for line in drawn.lines:
        x, y = line.xy[:, 0], line.xy[:, 1]
        inside = np.isfinite(x) & (x >= extent[0]) & (x <= extent[1]) & (y >= extent[2]) & (y <= extent[3])
        assert inside.sum() >= 1, (line.kind, line.value)  # a line is kept only if it crosses the map
        got_lat, got_lon = to_latlon(x[inside], y[inside])
        if line.kind == "lat":
            assert np.max(np.abs(got_lat - line.value)) < 1e-9
        else:
            assert np.max(longitude_gap(got_lon, line.value)) < 1e-9
        assert angle_of(line.label) == pytest.approx(((line.value + 180.0) % 360.0 - 180.0) if line.kind == "lon"
                                                     else line.value, abs=1e-9) or abs(line.value) == 180.0
    for tick in drawn.ticks:
        x, y = (extent[0], tick.position) if tick.edge == "left" else (tick.position, extent[2])
        got_lat, got_lon = to_latlon(x, y)
        if tick.kind == "lat":
            assert abs(float(got_lat) - tick.value) < 1e-6
        else:
            assert float(longitude_gap(got_lon, tick.value)) < 1e-6
        assert any(line.kind == tick.kind and line.value == tick.value for line in drawn.lines)
    lat_step, lon_step = drawn.spacing
    for kind, step in (("lat", lat_step), ("lon", lon_step)):
        count = sum(line.kind == kind for line in drawn.lines)
        if step != SPACINGS_DEG[-1]:
            assert count >= MIN_LINES, (kind, step, count)
        assert count <= math.floor(2.5 * MIN_LINES) + 1, (kind, step, count)


def test_labels_name_every_meridian_and_parallel_crossing_the_edges():
    """geo_ship's chart: parallels every minute labelled on the left, meridians every two
    minutes on the bottom, the origin's meridian (4°36'E) at x = 0 (aeqd: it is straight)."""
    frame = GeoFrame(60.45, 4.60, time="2026-11-24T05:40:00Z")
    drawn = chart(frame, (-7000.0, 5000.0, -7500.0, 1500.0), land=False)
    assert drawn.spacing == (1 / 60, 2 / 60)
    left = [t.label for t in drawn.ticks if t.edge == "left"]
    bottom = {t.label: t.position for t in drawn.ticks if t.edge == "bottom"}
    assert left == ["60°23′N", "60°24′N", "60°25′N", "60°26′N", "60°27′N"]
    assert list(bottom) == ["4°30′E", "4°32′E", "4°34′E", "4°36′E", "4°38′E", "4°40′E"]
    assert bottom["4°36′E"] == pytest.approx(0.0, abs=1e-3)  # to the edge tolerance, 1 mm


@pytest.mark.parametrize("value, kind, spacing, text", [
    (60.45, "lat", 1 / 60, "60°27′N"),
    (-33.5, "lat", 0.5, "33°30′S"),
    (4.6, "lon", 2 / 60, "4°36′E"),
    (-70.25, "lon", 15 / 3600, "70°15′00″W"),
    (0.0, "lat", 1.0, "0°"),
    (0.0, "lon", 1 / 60, "0°00′"),
    (180.0, "lon", 5.0, "180°"),
    (190.0, "lon", 10.0, "170°W"),  # unwrapped across the antimeridian
    (12.0, "lon", 2.0, "12°E"),
])
def test_angle_labels(value, kind, spacing, text):
    assert format_angle(value, kind, spacing) == text


@pytest.mark.parametrize("span, spacing", [(100.0, 30.0), (10.0, 2.0), (0.07, 1 / 60), (0.18, 1 / 60 * 2 * 1.0),
                                           (1e-4, 1 / 3600)])
def test_spacing_is_the_largest_giving_enough_lines(span, spacing):
    assert graticule_spacing(span) == pytest.approx(spacing)


@pytest.fixture
def offline(monkeypatch):
    """Every socket refuses: anything that tries the network fails loudly."""
    def refuse(*args, **kwargs):
        raise AssertionError("a chart tried to use the network")

    monkeypatch.setattr(socket, "socket", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    monkeypatch.setattr(socket, "getaddrinfo", refuse)


def inside_land(drawn, x: float, y: float) -> bool:
    """Whether the local point lies on the chart's land: inside an exterior ring and no hole."""
    for rings in drawn.land:
        if MplPath(rings[0]).contains_point((x, y)) and not any(MplPath(h).contains_point((x, y)) for h in rings[1:]):
            return True
    return False


# land and sea where the world has them (city centres inland of their coasts; open sea far
# from any island); each within a few hundred km of the chart's centre
PLACES = [
    # chart centre (lat, lon, crs), extent half-size m, point (lat, lon), land?
    ((60.40, 5.00, "aeqd"), 60_000.0, (60.3913, 5.3221), True),     # Bergen
    ((60.40, 5.00, "aeqd"), 60_000.0, (60.45, 4.40), False),        # the sea west of Oygarden
    ((40.0, -4.0, "utm"), 200_000.0, (40.4168, -3.7038), True),     # Madrid
    ((0.0, 0.0, "aeqd"), 100_000.0, (0.5, -0.5), False),            # the Gulf of Guinea (not 0, 0: NE has
    # a tiny "Null Island" there)
    ((-34.0, 18.6, "aeqd"), 80_000.0, (-33.9249, 18.4241), True),   # Cape Town
    ((-34.0, 18.6, "aeqd"), 80_000.0, (-34.3, 18.0), False),        # the Atlantic off the Cape
    ((67.0, 180.0, "aeqd"), 150_000.0, (67.0, 179.5), True),        # Chukotka, west of 180
    ((67.0, 180.0, "aeqd"), 150_000.0, (67.0, -179.5), True),       # Chukotka, east of 180
    ((-16.8, 179.9, "aeqd"), 150_000.0, (-17.5, -179.0), False),    # the Koro Sea, Fiji, east of 180
    ((89.9, 10.0, "aeqd"), 50_000.0, (89.95, 100.0), False),        # the Arctic Ocean at the pole
    ((-89.9, 0.0, "aeqd"), 50_000.0, (-89.95, 45.0), True),         # the Antarctic plateau at the pole
]


@pytest.mark.parametrize("centre, half, point, land", PLACES)
def test_land_is_drawn_from_the_bundled_data_offline(offline, centre, half, point, land):
    frame = GeoFrame(centre[0], centre[1], crs=centre[2])
    drawn = chart(frame, (-half, half, -half, half))
    x, y = frame.local(*point)
    assert inside_land(drawn, float(x), float(y)) is land
    assert "Natural Earth" in drawn.source


def test_the_bundled_land_is_natural_earth_10m():
    """The file holds Natural Earth's land (its stated source) at the stated simplification:
    the continents' areas within a few per cent of their known land areas."""
    polygons, source = load_land()
    assert source.startswith("Natural Earth 1:10m physical land polygons") and "public domain" in source
    assert len(polygons) > 5000  # NE 10m land has thousands of islands (6837 polygons here)
    geod = pyproj.Geod(ellps="WGS84")
    total = sum(abs(geod.geometry_area_perimeter(p)[0]) for p in polygons)
    # the Earth's land area is 148.9 million km^2 (CIA World Factbook); Natural Earth's land at
    # 1:10m, without lakes cut out, simplified to 0.002 deg, within 3 % of it
    assert total / 1e6 == pytest.approx(148.9e6, rel=0.03)


def test_a_bad_extent_is_one_line():
    frame = GeoFrame(10.0, 10.0)
    with pytest.raises(BananagridError, match=r"chart extent = .*: expected finite x0 < x1") as info:
        chart(frame, (0.0, 0.0, 0.0, 1.0))
    assert "\n" not in str(info.value)


def test_the_land_file_ships_as_package_data():
    """The wheel carries the file (pyproject's package-data names it) and git tracks it (the
    repository ignores *.npz elsewhere)."""
    root = Path(__file__).resolve().parents[2]
    config = tomllib.loads((root / "pyproject.toml").read_text())
    globs = config["tool"]["setuptools"]["package-data"]["bananagrid.geo"]
    assert [p.name for g in globs for p in (root / "bananagrid" / "geo").glob(g)] == [LAND_FILE]
    ignored = subprocess.run(["git", "check-ignore", "-q", f"bananagrid/geo/data/{LAND_FILE}"], cwd=root)
    assert ignored.returncode == 1  # 1: not ignored (0 would be ignored)
