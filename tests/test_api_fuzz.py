"""The Python API at the extremes: motion models and Butterly built from parameters anywhere
from 1e-300 to 1e300 are either refused with a BananagridError or give finite, non-negative
densities at points, finite samples, and a finite raster on a small grid about those samples;
geographic frames anywhere on the globe, at any time, in any CRS, are refused in one line or
give map files (NetCDF, GeoTIFF, GeoJSON) that are valid or refused in one line.
A derandomised property-based sweep (deterministic in CI); each example is bounded in work by
its small grid."""

import math
import warnings
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.geo.dataset import raster_dataset, write_netcdf
from bananagrid.geo.geojson import write_geojson
from bananagrid.geo.geotiff import write_geotiff
from geo_cases import check_geojson_geometry, check_geotiff, check_netcdf

EXTREMES = st.one_of(
    st.sampled_from([1e-300, 1e-30, 1e-6, 1e-3, 1.0, 1e3, 1e6, 1e30, 1e300]),
    st.floats(1e-9, 1e9),
)
SWEEP = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                 suppress_health_check=list(HealthCheck))


def exercise(build):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the models' own warnings (e.g. P_sigma's limit) are fine here
            model = build()
    except bg.BananagridError:
        return
    try:
        density = model.pdf([0.0, 1.0, -5.0, 100.0, 1e4], [0.0, 2.0, 3.0, -100.0, 1e4])
        assert np.all(np.isfinite(density)) and np.all(density >= 0.0), density
        pts = model.sample(50, np.random.default_rng(0))
        assert pts.shape == (50, 2) and np.all(np.isfinite(pts)), pts[:3]
        lo, hi = np.percentile(pts, 1, axis=0), np.percentile(pts, 99, axis=0)
        span = max(float(np.max(hi - lo)), 1e-6 * max(1.0, float(np.abs(lo).max())))
        grid = bg.Grid.from_bounds(x=(lo[0] - span, lo[0] + 2 * span), y=(lo[1] - span, lo[1] + 2 * span), step=span / 3)
        raster = bg.rasterise(model, grid)
        assert np.all(np.isfinite(raster.values)) and math.isfinite(raster.mass), raster.mass
    except bg.BananagridError:
        pass  # a clear refusal (e.g. a grid whose numbers overflow) is fine


@SWEEP
@given(EXTREMES, EXTREMES, EXTREMES, EXTREMES, st.sampled_from(["cat", "rough", "improved"]))
def test_motion_models_at_the_extremes(v0, t, sigma_a, sigma_omega, kind):
    def build():
        if kind == "cat":
            return bg.CAT(v0=v0, t=t, sigma_a=sigma_a, sigma_omega=sigma_omega)
        return bg.PolarBanana(v0=v0, t=t, sigma_a=sigma_a, sigma_omega=sigma_omega, variant=kind)

    exercise(build)


@SWEEP
@given(EXTREMES, EXTREMES, EXTREMES, st.floats(-0.999, 0.999))
def test_butterly_at_the_extremes(sd, speed, t, rho):
    def build():
        cov = [[sd * sd, 0.5 * rho * sd * sd], [0.5 * rho * sd * sd, 0.25 * sd * sd]]
        return bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=[speed], t=t)

    exercise(build)


@SWEEP
@given(EXTREMES, st.floats(-2.0, 2.0), st.floats(0.05, 3.0), EXTREMES, EXTREMES, st.booleans(),
       st.sampled_from(["exact", "linear"]))
def test_bearing_fixes_at_the_extremes(baseline, a, b, sigma_1, sigma_2, third, variant):
    """Two or three stations a baseline apart (1e-300 to 1e300 m), a contact anywhere in front
    of them, bearing SDs from 1e-300 to 1e300 rad (stations whose accuracies differ by up to
    1e600 found a singular covariance before its determinant was taken by Cauchy-Binet)."""
    def build():
        sensors = [[0.0, 0.0], [baseline, 0.0]] + ([[0.5 * baseline, -baseline]] if third else [])
        bearings = bg.bearing_to(np.array(sensors), np.array([a * baseline, b * baseline]))
        sigmas = [sigma_1, sigma_2] + ([sigma_1] if third else [])
        return bg.BearingFix(sensors=sensors, bearings=bearings, sigmas=sigmas, variant=variant)

    exercise(build)


@SWEEP
@given(EXTREMES, EXTREMES, st.floats(-0.99, 0.99), st.sampled_from([1.0, -1.0]), EXTREMES)
def test_gaussian_mixtures_at_the_extremes(sd_x, sd_y, rho, side, offset):
    """A two-component plane mixture with spreads from 1e-300 to 1e300 m, one component
    ``offset`` away: refused, or finite non-negative densities, finite samples, and cell
    probabilities on a small grid about them that are finite, >= 0 and sum to at most 1."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sx, sy = np.float64(sd_x), np.float64(sd_y)  # squares overflow to inf, not OverflowError
            cov = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
            mixture = bg.GaussianMixture(weights=[0.5, 0.5], means=[[0.0, 0.0], [side * offset, offset]], covs=[cov] * 2)
    except bg.BananagridError:
        return
    density = mixture.pdf(np.array([[0.0, 0.0], [1.0, 2.0], [side * offset, offset]]))
    assert np.all(np.isfinite(density)) and np.all(density >= 0.0), density
    pts = mixture.sample(50, np.random.default_rng(0))
    assert pts.shape == (50, 2) and np.all(np.isfinite(pts))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = max(float(np.max(hi - lo)), 1e-6 * max(1.0, float(np.abs(lo).max())))
    try:
        grid = bg.Grid.from_bounds(x=(lo[0] - span, lo[0] + 2 * span), y=(lo[1] - span, lo[1] + 2 * span), step=span / 3)
        cells = bg.grid_probabilities(mixture, grid)
    except bg.BananagridError:
        return
    assert np.all(np.isfinite(cells.probability)) and np.all(cells.probability >= 0.0)
    assert np.all(np.isfinite(cells.density)) and cells.mass <= 1.0 + 1e-12


@SWEEP
@given(st.sampled_from(["line", "plane", "frustum"]), EXTREMES, EXTREMES, st.floats(-1.0, 1.0), EXTREMES,
       st.floats(0.05, 0.95))
def test_uniform_presence_cells_at_the_extremes(geometry, size, height, shift, reach, thickness):
    """A uniform room from 1e-300 to 1e300 m on a side, shifted by up to its size, under an
    array at a height from 1e-300 to 1e300 m: refused, or finite densities and samples, and cell
    probabilities that are finite, >= 0 and sum to at most 1 (the room's share seen by the cells)."""
    dim = {"line": 1, "plane": 2, "frustum": 3}[geometry]
    axes = {"x": (shift * size - size, shift * size + size), "y": (-size, reach), "z": (-2.0 * height, -0.5 * height)}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            room = bg.UniformPresence(bg.Region(**{k: axes[k] for k in "xyz"[:dim]}))
            kwargs = {"dh": thickness * height} if geometry == "frustum" else {}
            lattice = bg.AngularLattice(geometry, h=height, azimuth_step=math.pi / 8,
                                        elevation_step=None if geometry == "line" else math.pi / 16, **kwargs)
            cells = bg.cell_probabilities(room, lattice)
    except bg.BananagridError:
        return
    pts = room.sample(20, np.random.default_rng(0))
    assert np.all(np.isfinite(pts)) and np.all(np.isfinite(room.pdf(pts)))
    assert np.all(np.isfinite(cells.prob)) and np.all(cells.prob >= 0.0), cells.prob
    assert float(np.sum(cells.prob)) <= 1.0 + 1e-12


LATITUDES = st.one_of(st.sampled_from([-90.0, -89.9999, 0.0, 89.9999, 90.0, 90.0000001, math.nan, math.inf]),
                      st.floats(-90.0, 90.0))
LONGITUDES = st.one_of(st.sampled_from([-180.0, -179.9999, 179.9999, 180.0, 180.0000001, -math.inf]),
                       st.floats(-180.0, 180.0))
TIMES = st.one_of(
    st.none(),
    st.sampled_from(["0001-01-01T00:00:00Z", "0001-01-01T00:00:00+01:00", "2262-04-11T23:47:16Z",
                     "9999-12-31T23:59:59Z", "1677-09-21T00:12:43Z", "not a time"]),
    st.datetimes(min_value=datetime(1, 1, 1), max_value=datetime(9999, 12, 31),
                 timezones=st.sampled_from([timezone.utc, timezone(timedelta(hours=-12))])),
)
CRSS = st.sampled_from(["aeqd", "utm", "EPSG:32601", "EPSG:3413", "EPSG:3031", "EPSG:4326", "+proj=merc +datum=WGS84",
                        "+proj=tmerc +x_0=1e20 +datum=WGS84", "+proj=tmerc +k=1e-20 +datum=WGS84",
                        "+proj=tmerc +k=1000 +datum=WGS84", "+proj=stere +lat_0=-90 +datum=WGS84", ""])


@settings(max_examples=30, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(LATITUDES, LONGITUDES, TIMES, CRSS, st.sampled_from([1.0, 1e3, 1e5, 3e6]), st.floats(1e-3, 1e9))
def test_geographic_frames_and_map_files_at_the_extremes(tmp_path_factory, lat, lon, time, crs, half, t):
    """A frame at an origin anywhere (the poles, the antimeridian, beyond them, NaN), at a time
    anywhere in the calendar, in a CRS that holds the grid or not; a blob on a grid 1 m to 6,000 km
    wide about the origin, at elapsed time t (up to 30 years): each map file is written and valid
    (NetCDF and GeoTIFF coordinates stepping by the grid's step, GeoJSON per RFC 7946) or refused
    in one line with nothing left behind."""
    try:
        frame = bg.GeoFrame(lat, lon, time=time, crs=crs)
    except bg.BananagridError as exc:
        assert "\n" not in str(exc), str(exc)
        return
    grid = bg.Grid.from_bounds(x=(-half, half), y=(-half, half), step=half / 8)
    raster = bg.rasterise(bg.Butterly(mean=(0.0, 0.0), cov=[[(half / 4) ** 2, 0.0], [0.0, (half / 5) ** 2]],
                                      speeds=[0.0], t=1.0), grid)
    panels = [("a", t, raster)]
    scene = SimpleNamespace(grid=grid, geo=frame, jobs=lambda: [(None, t)])
    out = tmp_path_factory.mktemp("geo")
    writers = {
        "a.nc": (lambda path: write_netcdf(path, raster_dataset(panels, frame)), lambda path: check_netcdf(path, scene)),
        "a.tif": (lambda path: write_geotiff(path, panels, frame), lambda path: check_geotiff(path, scene)),
        "a.geojson": (lambda path: write_geojson(path, panels, frame), check_features),
    }
    for name, (write, check) in writers.items():
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", RuntimeWarning)  # an overflow on the way is a value not refused
                write(out / name)
        except bg.BananagridError as exc:
            assert "\n" not in str(exc), str(exc)
            assert not (out / name).exists()
            continue
        check(out / name)


def check_features(path) -> None:
    import json

    for feature in json.loads(path.read_text())["features"]:
        if feature["properties"]["reached"]:
            check_geojson_geometry(feature["geometry"])
