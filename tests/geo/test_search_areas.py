"""Search areas (bananagrid.geo.areas) and their GeoJSON (bananagrid.geo.geojson).

What is claimed and checked here:

* the polygons hold exactly the region's cell centres (every cell at or above the boundary
  density, no other), for smooth maps and for random noise with ties and plateaus;
* the probability they enclose, recomputed from the cells, is within ``resolution`` of the level
  (the stated bound), ``resolution`` shrinks in proportion to the step, and the model's own
  samples fall inside at the level's rate;
* holes are kept (a Butterly ring);
* the GeoJSON is RFC 7946: WGS84 longitude/latitude, counter-clockwise exteriors, clockwise
  holes, 7 decimals, geodesic areas that agree with the plane's to the projection's scale error.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pyproj
import pytest
import shapely
import shapely.geometry
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bananagrid import CAT, BananagridError, Butterly, GeoFrame, Grid, Pose, Raster, rasterise
from bananagrid.contours import mass_regions
from bananagrid.geo.areas import search_areas
from bananagrid.geo.geojson import write_geojson

LEVELS = (0.5, 0.9, 0.95, 0.99)


def ship(t: float = 600.0) -> CAT:
    return CAT(v0=5.0, t=t, sigma_a=0.002, sigma_omega=math.radians(0.05),
               pose=Pose(heading=math.radians(200.0)))


def ring() -> Butterly:
    """A start known to 200 m, 5 m/s on any course for 600 s: a ring 3 km across with a hole."""
    return Butterly(mean=(0.0, 0.0), cov=np.diag([200.0**2, 200.0**2]), speeds=[5.0], t=600.0)


def raster_of(model, step: float) -> Raster:
    """The model on one grid for both cases (one GeoJSON file holds maps of one grid)."""
    grid = Grid.from_bounds((-5000.0, 4600.0), (-6600.0, 4600.0), step)
    return rasterise(model, grid, dtype=np.float64).normalise()


def centres_inside(raster: Raster, geometry) -> np.ndarray:
    xs, ys = np.meshgrid(raster.x, raster.y)
    return shapely.contains_xy(geometry, xs, ys)


CASES = {
    "ship": lambda step: raster_of(ship(), step),
    "ring": lambda step: raster_of(ring(), step),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_polygons_hold_exactly_the_regions_cells_and_their_level(case):
    raster = CASES[case](40.0)
    regions = mass_regions(raster, LEVELS)
    for area, region in zip(search_areas(raster, LEVELS), regions):
        assert area.reached and area.geometry.is_valid
        np.testing.assert_array_equal(centres_inside(raster, area.geometry), raster.values >= region.density)
        assert area.cells == region.cells and area.enclosed == region.enclosed
        # the stated bound (the module's argument): cut cells plus the cells at the boundary density
        assert abs(area.probability - area.level) <= area.resolution
        assert 0.0 < area.resolution < 0.2


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_resolution_shrinks_with_the_step(case):
    coarse, fine = (search_areas(CASES[case](step), [0.9])[0] for step in (80.0, 40.0))
    # in proportion to the step (perimeter / step cells of mass c step^2): halving it halves the
    # bound, to within the boundary's staircase (allow 0.6)
    assert fine.resolution < 0.6 * coarse.resolution
    assert fine.area == pytest.approx(coarse.area, rel=0.02)


def test_the_models_own_samples_fall_inside_at_each_level():
    rng = np.random.default_rng(20261125)
    for case, model in (("ship", ship()), ("ring", ring())):
        raster = CASES[case](25.0)
        points = model.sample(200_000, rng)
        for area in search_areas(raster, LEVELS):
            share = float(np.mean(shapely.contains_xy(area.geometry, points[:, 0], points[:, 1])))
            sd = math.sqrt(area.level * (1.0 - area.level) / len(points))
            # the cells' bound, plus 5 binomial SDs of the Monte Carlo share
            assert abs(share - area.level) <= area.resolution + 5.0 * sd, (case, area.level, share)


def test_a_ring_keeps_its_hole():
    raster = CASES["ring"](40.0)
    area = search_areas(raster, [0.5])[0]
    (polygon,) = area.geometry.geoms
    assert len(polygon.interiors) == 1
    assert not shapely.contains_xy(area.geometry, 0.0, 0.0)  # the start is in the hole
    assert shapely.contains_xy(area.geometry, 0.0, 3000.0)   # 5 m/s x 600 s north of it is inside


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    shape=st.tuples(st.integers(2, 24), st.integers(2, 24)),
    seed=st.integers(0, 2**32 - 1),
    plateau=st.booleans(),
    levels=st.lists(st.floats(0.01, 0.99), min_size=1, max_size=4),
)
def test_any_map_gets_polygons_around_exactly_its_regions_cells(shape, seed, plateau, levels):
    """Noise, zeros, ties and plateaus: marching squares between a level strictly between the
    boundary density and the next lower value still puts exactly the region's centres inside."""
    rng = np.random.default_rng(seed)
    ny, nx = shape
    values = rng.random((ny, nx)) * (rng.random((ny, nx)) < 0.7)
    if plateau:
        values = np.round(values * 3.0) / 3.0  # few distinct values: ties everywhere
    grid = Grid((0.0, 0.0), 10.0, 7.0, nx, ny)
    if not values.any():
        values[0, 0] = 1.0
    raster = Raster(values / (values.sum() * grid.cell_area), grid, mass=1.0, normalised=True)
    for area, region in zip(search_areas(raster, levels), mass_regions(raster, levels)):
        np.testing.assert_array_equal(centres_inside(raster, area.geometry), raster.values >= region.density)
        assert abs(area.probability - area.level) <= area.resolution + 1e-12  # sums of ~600 terms


def test_bad_maps_are_refused():
    grid = Grid((0.0, 0.0), 10.0, 10.0, 4, 3)
    values = np.ones((3, 4)) / (12 * 100.0)
    with pytest.raises(BananagridError, match="negative densities"):
        search_areas(Raster(values - 1.0, grid, mass=1.0))
    with pytest.raises(BananagridError, match="NaN or inf"):
        search_areas(Raster(np.where(values > 0, np.nan, 0.0), grid, mass=1.0))
    with pytest.raises(BananagridError, match=r"mass_levels\[0\] = 1.5"):
        search_areas(Raster(values, grid, mass=1.0), [1.5])
    line = Grid((0.0, 0.0), 10.0, 10.0, 5, 1)
    with pytest.raises(BananagridError, match="at least 2 cells along each side"):
        search_areas(Raster(np.ones((1, 5)), line, mass=1.0))


def test_a_level_the_grid_does_not_hold_is_not_reached():
    raster = rasterise(ship(), Grid.from_bounds((-3000.0, 0.0), (-6000.0, 0.0), 50.0))  # misses the west
    held = raster.mass
    assert 0.5 < held < 0.99
    areas = search_areas(raster, [0.5, 0.99])
    assert areas[0].reached and not areas[1].reached and areas[1].geometry.is_empty


# --- GeoJSON -------------------------------------------------------------------------------------

FRAME = GeoFrame(60.45, 4.60, time="2026-11-24T05:40:00Z")


@pytest.fixture(scope="module")
def collection(tmp_path_factory):
    path = tmp_path_factory.mktemp("areas") / "areas.geojson"
    panels = [("ship", 600.0, CASES["ship"](40.0)), ("ring", 600.0, CASES["ring"](40.0))]
    write_geojson(path, panels, FRAME, LEVELS, title="test")
    return json.loads(path.read_text()), panels


def test_the_geojson_is_wgs84_with_one_feature_per_layer_time_and_level(collection):
    data, panels = collection
    assert data["type"] == "FeatureCollection" and "crs" not in data
    assert [(f["properties"]["layer"], f["properties"]["level"]) for f in data["features"]] == [
        (layer, level) for layer, _, _ in panels for level in LEVELS]
    to_local = pyproj.Transformer.from_crs("EPSG:4326", "+proj=aeqd +lat_0=60.45 +lon_0=4.6 +datum=WGS84", always_xy=True)
    for feature, (layer, t, raster) in zip(data["features"], [p for p in panels for _ in LEVELS]):
        props = feature["properties"]
        assert props["time_utc"] == "2026-11-24T05:50:00Z" and props["t_s"] == 600.0
        area = search_areas(raster, [props["level"]])[0]
        assert props["probability"] == area.probability and props["cells"] == area.cells
        shape = shapely.geometry.shape(feature["geometry"])
        assert shape.is_valid
        # back in the plane (independent PROJ pipeline), the polygons are the plane's to 1e-7 deg
        # rounding (1.1 cm north, 0.6 cm east at 60 N): symmetric difference below perimeter x 2 cm
        back = shapely.transform(shape, lambda ll: np.column_stack(to_local.transform(ll[:, 0], ll[:, 1])))
        assert back.symmetric_difference(area.geometry).area < area.geometry.length * 0.02


def test_the_rings_are_oriented_and_rounded_as_rfc_7946_says(collection):
    data, _ = collection
    holes = 0
    for feature in data["features"]:
        for polygon in feature["geometry"]["coordinates"]:
            exterior, *interiors = polygon
            assert shapely.LinearRing(exterior).is_ccw
            assert all(not shapely.LinearRing(hole).is_ccw for hole in interiors)
            holes += len(interiors)
            for lon, lat in exterior:
                assert round(lon, 7) == lon and round(lat, 7) == lat
    assert holes >= 1  # the ring's


def test_geodesic_areas_agree_with_the_planes_to_the_projections_scale_error(collection):
    data, _ = collection
    for feature in data["features"]:
        props = feature["properties"]
        # aeqd within 5 km of its centre: scale error ~ rho^2 / (6 R^2) < 1e-7 per axis;
        # rounding to 1e-7 deg moves the area by < perimeter x 1 cm (relative < 1e-5 here)
        assert props["area_km2"] == pytest.approx(props["area_km2_plane"], rel=2e-5)
        shape = shapely.geometry.shape(feature["geometry"])
        independent = abs(pyproj.Geod(ellps="WGS84").geometry_area_perimeter(shape)[0]) / 1e6
        assert props["area_km2"] == pytest.approx(independent, rel=1e-12)


def test_an_unreached_level_has_a_null_geometry(tmp_path):
    raster = rasterise(ship(), Grid.from_bounds((-3000.0, 0.0), (-6000.0, 0.0), 50.0))
    path = write_geojson(tmp_path / "a.geojson", [("ship", 600.0, raster)], FRAME, [0.5, 0.99])
    features = json.loads(path.read_text())["features"]
    assert features[1]["geometry"] is None and features[1]["properties"]["reached"] is False
    assert features[1]["properties"]["probability"] is None


def test_geojson_without_a_frame_or_a_directory_is_refused_and_leaves_nothing(tmp_path):
    raster = CASES["ship"](80.0)
    with pytest.raises(BananagridError, match="need a geographic frame"):
        write_geojson(tmp_path / "a.geojson", [("ship", 600.0, raster)])
    with pytest.raises(BananagridError, match="does not exist"):
        write_geojson(tmp_path / "no" / "a.geojson", [("ship", 600.0, raster)], FRAME)
    assert list(tmp_path.iterdir()) == []
