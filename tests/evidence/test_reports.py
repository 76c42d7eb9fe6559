"""Reports and land: the bearings' likelihood is the exact BearingFix map without its
normaliser, a position report is the normal density without its constant, land from a GeoJSON
dict or file is the same as from its vertices; bad input in one line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

import bananagrid as bg

FIX = bg.BearingFix(sensors=[(-2000.0, 0.0), (2000.0, 0.0), (0.0, -1500.0)],
                    bearings=[math.atan2(2000.0, 1500.0), math.atan2(-2000.0, 1500.0), 0.02],
                    sigmas=[0.03, 0.02, 0.05])


def test_bearing_likelihood_is_the_exact_fix_without_its_normaliser():
    """L(P) / pdf(P) of the exact variant is one constant (the Laplace normaliser) wherever the
    pdf is above 1e-200 of its peak (the kernel's float64 exp; 1e-12 relative)."""
    report = bg.BearingReport(FIX, t=0.0)
    rng = np.random.default_rng(1)
    points = FIX.fix + rng.normal(0.0, 200.0, (2000, 2))
    density = FIX.pdf(points[:, 0], points[:, 1])
    likelihood = report.likelihood(points[:, 0], points[:, 1])
    ok = density > 1e-200 * density.max()
    ratio = likelihood[ok] / density[ok]
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-12)
    assert likelihood.max() <= 1.0


def test_position_report_is_the_normal_density_without_its_constant():
    cov = [[300.0**2, 2e4], [2e4, 150.0**2]]
    report = bg.PositionReport((100.0, 200.0), t=5.0, cov=cov)
    rng = np.random.default_rng(2)
    points = rng.normal(0.0, 500.0, (1000, 2))
    expected = stats.multivariate_normal((100.0, 200.0), cov).pdf(points) * 2.0 * math.pi * math.sqrt(np.linalg.det(cov))
    np.testing.assert_allclose(report.likelihood(points[:, 0], points[:, 1]), expected, rtol=1e-12)
    circular = bg.PositionReport((0.0, 0.0), t=5.0, sigma=10.0)
    assert math.isclose(float(circular.likelihood(10.0, 0.0)), math.exp(-0.5), rel_tol=1e-15)


LAND = [(0.0, 0.0), (100.0, 0.0), (100.0, 50.0), (0.0, 80.0)]
ISLAND = [(300.0, 300.0), (350.0, 300.0), (320.0, 360.0)]


def test_land_from_geojson_is_land_from_vertices(tmp_path):
    collection = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [LAND + [LAND[0]]]}},
        {"type": "Feature", "properties": {}, "geometry": {"type": "MultiPolygon", "coordinates": [[ISLAND]]}},
    ]}
    path = tmp_path / "land.geojson"
    path.write_text(json.dumps(collection))
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-50.0, 400.0, (2, 5000))
    expected = bg.Exclusion(LAND).likelihood(x, y) * bg.Exclusion(ISLAND).likelihood(x, y)
    for given in (collection, path, str(path)):
        np.testing.assert_array_equal(bg.Exclusion(given).likelihood(x, y), expected)
    assert (expected == 0.0).any() and (expected == 1.0).any()


BAD = [
    ("sigma 0", lambda: bg.PositionReport((0, 0), t=0.0, sigma=0.0), r"sigma = 0\.0: must be > 0"),
    ("sigma and cov", lambda: bg.PositionReport((0, 0), t=0.0, sigma=1.0, cov=[[1, 0], [0, 1]]), r"give exactly one"),
    ("cov not positive", lambda: bg.PositionReport((0, 0), t=0.0, cov=[[1.0, 2.0], [2.0, 1.0]]),
     r"cov = .*must be positive definite"),
    ("position NaN", lambda: bg.PositionReport((0, math.nan), t=0.0, sigma=1.0), r"position\[1\] = nan: must be finite"),
    ("report time NaN", lambda: bg.PositionReport((0, 0), t=math.nan, sigma=1.0), r"t = nan: must be finite"),
    ("not a fix", lambda: bg.BearingReport([(0, 0), (1, 0)], t=0.0), r"fix = .*expected a bananagrid BearingFix"),
    ("bearing time < 0", lambda: bg.BearingReport(FIX, t=-2.0), r"t = -2\.0: times must be >= 0"),
    ("land crossing", lambda: bg.Exclusion([(0, 0), (10, 10), (10, 0), (0, 10)]), r"polygon: edges .* cross"),
    ("land with a hole", lambda: bg.Exclusion({"type": "Polygon", "coordinates": [LAND, ISLAND]}),
     r"polygon: a polygon with 1 hole"),
    ("land of points", lambda: bg.Exclusion({"type": "Point", "coordinates": [0, 0]}), r"GeoJSON type 'Point'"),
    ("land file missing", lambda: bg.Exclusion("/nonexistent/land.geojson"), r"polygon = '/nonexistent/land\.geojson': cannot read"),
    ("land empty", lambda: bg.Exclusion({"type": "FeatureCollection", "features": []}), r"holds no polygon"),
]


@pytest.mark.parametrize("what, build, message", BAD, ids=[b[0] for b in BAD])
def test_bad_report_is_one_line_naming_the_argument(what, build, message):
    with pytest.raises(bg.BananagridError, match=message) as caught:
        build()
    assert "\n" not in str(caught.value)


def test_land_file_not_geojson(tmp_path):
    path = tmp_path / "land.geojson"
    path.write_text("not json")
    with pytest.raises(bg.BananagridError, match=r"not a GeoJSON file"):
        bg.Exclusion(path)


def test_geojson_in_longitude_and_latitude_through_a_frame():
    """With a GeoFrame a GeoJSON's [lon, lat] vertices are the frame's local metres of them
    (frame.local, vertex by vertex), for land and for an area search."""
    frame = bg.GeoFrame(lat=59.9, lon=10.7)
    lonlat = [(10.70, 59.90), (10.72, 59.90), (10.72, 59.91), (10.70, 59.915)]
    x, y = frame.local([p[1] for p in lonlat], [p[0] for p in lonlat])
    local = np.column_stack((x, y))
    feature = {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [lonlat]}}
    land = bg.Exclusion(feature, frame=frame)
    np.testing.assert_array_equal(land.regions[0].vertices, bg.Exclusion(local).regions[0].vertices)
    search = bg.AreaSearch(feature, t=0.0, pod=0.5, frame=frame)
    np.testing.assert_array_equal(search.polygon, bg.AreaSearch(local, t=0.0, pod=0.5).polygon)
    assert 500.0 < search.region.area / 1e3 < 2.5e3  # about 1.1 km x 1.3 km, in m^2 / 1000


def test_geojson_refusals(tmp_path):
    two = {"type": "MultiPolygon", "coordinates": [[LAND], [ISLAND]]}
    with pytest.raises(bg.BananagridError, match=r"^polygon: the GeoJSON holds 2 polygons; an area search is one"):
        bg.AreaSearch(two, t=0.0, pod=0.5)
    path = tmp_path / "list.geojson"
    path.write_text("[1, 2]")
    with pytest.raises(bg.BananagridError, match=r"^polygon: a GeoJSON list; expected a GeoJSON object"):
        bg.Exclusion(path)
    with pytest.raises(bg.BananagridError, match=r"latitude 95\.0: must lie in"):
        bg.Exclusion([(10.0, 59.0), (10.1, 95.0), (10.2, 59.0)], frame=bg.GeoFrame(lat=59.9, lon=10.7))
