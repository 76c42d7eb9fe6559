"""CF NetCDF and xarray export: a scene's maps written by bananagrid.geo.dataset and read back
with xarray and, independently, with netCDF4; coordinates checked against pyproj transformers
built here (not the frame's), times against datetimes written out by hand, the CF checker on
the file where it can run offline, and the one-line errors of bad input (with nothing left
behind)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import netCDF4
import numpy as np
import pyproj
import pytest
import xarray as xr

import bananagrid as bg
from bananagrid import BananagridError, Raster
from bananagrid.domains.angular_lattice import AngularLattice
from bananagrid.domains.grid import Grid
from bananagrid.domains.polar_lattice import PolarLattice
from bananagrid.geo.dataset import raster_dataset, read_maps, write_netcdf
from bananagrid.geo.frame import GeoFrame
from bananagrid.results import CellMap, PolarRaster

ROOT = Path(__file__).resolve().parents[2]
LAT, LON, FIX_TIME = 60.39, 5.32, "2026-11-24T06:00:00Z"
GRID = Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=400.0)  # 15 x 9 cells
# The two CRSs of a frame: the default (false origin (0, 0)) and a UTM zone (a false origin of
# ~(0.3e6, 6.7e6) m, which catches a forgotten offset).
CRSS = {
    "aeqd": f"+proj=aeqd +lat_0={LAT!r} +lon_0={LON!r} +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs",
    "EPSG:32632": "EPSG:32632",
}


def raster(seed: int, dtype=np.float64, grid: Grid = GRID, t: float = 10.0) -> Raster:
    values = np.random.default_rng(seed).random(grid.shape).astype(dtype)
    return Raster(values=values, grid=grid, mass=0.5 + seed / 100.0, normalised=bool(seed % 2),
                  provenance={"model": "test", "t": t, "seed": seed, "dtype": np.dtype(dtype).name})


def cell_probabilities(seed: int, grid: Grid = GRID) -> Raster:
    """A raster of cell probabilities (sum 1), spread over many decades as far cells' are."""
    values = 10.0 ** np.random.default_rng(seed).uniform(-300.0, 0.0, grid.shape)
    return Raster(values=values / values.sum(), grid=grid, mass=0.9, normalised=True, quantity="probability",
                  provenance={"model": "test", "seed": seed, "quantity": "probability"})


def scene_panels(dtype=np.float64):
    """Two layers, each at 600 s and 1200 s (given out of order, to check the sorting)."""
    return [("cat", 1200.0, raster(2, dtype)), ("cat", 600.0, raster(1, dtype)),
            ("cat-course", 600.0, raster(3, dtype)), ("cat-course", 1200.0, raster(4, dtype))]


def expected_projected(crs_name: str):
    """Cell centres in the CRS, from a transformer built here: the false origin is where the
    fix (LAT, LON) lands, and local metres are offsets from it."""
    to_crs = pyproj.Transformer.from_crs("EPSG:4326", pyproj.CRS.from_user_input(CRSS[crs_name]), always_xy=True)
    e0, n0 = to_crs.transform(LON, LAT)
    return e0 + GRID.x, n0 + GRID.y


def expected_latlon(crs_name: str, e, n):
    to_geo = pyproj.Transformer.from_crs(pyproj.CRS.from_user_input(CRSS[crs_name]), "EPSG:4326", always_xy=True)
    ge, gn = np.meshgrid(e, n)
    lon, lat = to_geo.transform(ge, gn)
    return lat, lon


@pytest.mark.parametrize("crs_name", sorted(CRSS))
def test_a_scene_reads_back_with_xarray_and_netcdf4(tmp_path, crs_name):
    frame = GeoFrame(LAT, LON, time=FIX_TIME, crs=crs_name)
    panels = scene_panels()
    path = write_netcdf(tmp_path / "scene.nc", raster_dataset(panels, frame, title="Two layers", source="test"))
    assert path == tmp_path / "scene.nc" and sorted(os.listdir(tmp_path)) == ["scene.nc"]
    by_key = {(layer, t): r for layer, t, r in panels}
    e, n = expected_projected(crs_name)
    lat, lon = expected_latlon(crs_name, e, n)
    utc = [datetime(2026, 11, 24, 6, 10, tzinfo=timezone.utc), datetime(2026, 11, 24, 6, 20, tzinfo=timezone.utc)]

    with xr.open_dataset(path) as ds:
        for layer, var in (("cat", "cat"), ("cat-course", "cat_course")):
            stacked = np.stack([by_key[layer, 600.0].values, by_key[layer, 1200.0].values])
            assert ds[var].dims == ("time", "y", "x")
            assert ds[var].dtype == np.float64
            np.testing.assert_array_equal(ds[var].values, stacked)  # written as float64: exact
            np.testing.assert_array_equal(ds[f"{var}_mass"].values, [by_key[layer, t].mass for t in (600.0, 1200.0)])
            np.testing.assert_array_equal(ds[f"{var}_normalised"].values,
                                          [by_key[layer, t].normalised for t in (600.0, 1200.0)])
            assert ds[var].attrs["bananagrid_layer"] == layer and ds[var].attrs["units"] == "m-2"
            assert ds[var].attrs["grid_mapping"] == "crs"
            provenance = json.loads(ds[var].attrs["bananagrid_provenance"])
            assert [p["seed"] for p in provenance] == [by_key[layer, t].provenance["seed"] for t in (600.0, 1200.0)]
        # projected coordinates: one pyproj transformation of the same point on both sides; 1 um
        # allows for the order of the float64 additions (ulp of 6.7e6 m is 1e-9 m)
        np.testing.assert_allclose(ds.x.values, e, rtol=0, atol=1e-6)
        np.testing.assert_allclose(ds.y.values, n, rtol=0, atol=1e-6)
        np.testing.assert_allclose(ds.x_bounds.values[:, 1] - ds.x_bounds.values[:, 0], GRID.dx, rtol=1e-12)
        np.testing.assert_allclose(ds.x_bounds.values.mean(axis=1), ds.x.values, rtol=0, atol=1e-6)
        # the inverse projection of the same coordinates: 1e-9 degrees is 0.1 mm on the ground,
        # far above the transformation's float64 noise and far below any cell
        np.testing.assert_allclose(ds.lat.values, lat, rtol=0, atol=1e-9)
        np.testing.assert_allclose(ds.lon.values, lon, rtol=0, atol=1e-9)
        assert ds.time.dtype.kind == "M"
        assert list(ds.time.values) == [np.datetime64(u.replace(tzinfo=None), "ns") for u in utc]
        np.testing.assert_array_equal(ds.elapsed.values, [600.0, 1200.0])
        assert pyproj.CRS.from_wkt(ds.crs.attrs["crs_wkt"]).equals(pyproj.CRS.from_user_input(CRSS[crs_name]))
        assert ds.attrs["Conventions"] == "CF-1.10" and ds.attrs["title"] == "Two layers"
        assert ds.attrs["source"] == "test" and bg.__version__ in ds.attrs["history"]

    with netCDF4.Dataset(path) as nc:
        assert nc.Conventions == "CF-1.10"
        var = nc["cat_course"]
        assert var.dimensions == ("time", "y", "x") and var.dtype == np.float64
        np.testing.assert_array_equal(var[:].data, np.stack([by_key["cat-course", 600.0].values,
                                                            by_key["cat-course", 1200.0].values]))
        assert var.filters()["zlib"] is True
        assert var.units == "m-2" and var.grid_mapping == "crs"
        assert set(var.coordinates.split()) == {"elapsed", "lat", "lon"}
        for name, standard, units, axis in (("x", "projection_x_coordinate", "m", "X"),
                                            ("y", "projection_y_coordinate", "m", "Y")):
            v = nc[name]
            assert (v.standard_name, v.units, v.axis, v.bounds) == (standard, units, axis, f"{name}_bounds")
            assert "_FillValue" not in v.ncattrs()  # CF: coordinates have no missing values
        assert (nc["lat"].standard_name, nc["lat"].units) == ("latitude", "degrees_north")
        assert (nc["lon"].standard_name, nc["lon"].units) == ("longitude", "degrees_east")
        np.testing.assert_allclose(nc["lat"][:].data, lat, rtol=0, atol=1e-9)  # as above
        crs = nc["crs"]
        assert crs.grid_mapping_name == ("azimuthal_equidistant" if crs_name == "aeqd" else "transverse_mercator")
        assert pyproj.CRS.from_cf({k: crs.getncattr(k) for k in crs.ncattrs()}).equals(
            pyproj.CRS.from_user_input(CRSS[crs_name]))
        time = nc["time"]
        assert time.standard_name == "time" and time.units.startswith("seconds since 2026-11-24T06:00:00")
        decoded = netCDF4.num2date(time[:], time.units, time.calendar, only_use_cftime_datetimes=False,
                                   only_use_python_datetimes=True)
        assert [d.replace(tzinfo=timezone.utc) for d in decoded] == utc
        assert (nc["elapsed"].units, nc["elapsed"].long_name) == ("s", "elapsed time since the fix")


def test_without_a_frame_the_coordinates_are_local_metres_and_time_elapsed_seconds(tmp_path):
    panels = scene_panels(np.float32)
    path = write_netcdf(tmp_path / "local.nc", raster_dataset(panels))
    with xr.open_dataset(path) as ds:
        np.testing.assert_array_equal(ds.x.values, GRID.x)  # no offset: the same float64 sums
        np.testing.assert_array_equal(ds.y.values, GRID.y)
        assert ds.cat.dtype == np.float32  # float32 stays float32
        np.testing.assert_array_equal(ds.cat.values[0], panels[1][2].values)
        assert {"lat", "lon", "crs"}.isdisjoint(ds.variables)
        assert "grid_mapping" not in ds.cat.attrs and "bananagrid_frame" not in ds.attrs
        # no date: the time dimension is "elapsed" (CF keeps "time" for "seconds since" a date)
        assert "time" not in ds.variables and ds.cat.dims == ("elapsed", "y", "x")
        assert ds.elapsed.dtype == np.float64
        np.testing.assert_array_equal(ds.elapsed.values, [600.0, 1200.0])
        assert (ds.elapsed.attrs["units"], ds.elapsed.attrs["long_name"]) == ("s", "elapsed time since the fix")
    with netCDF4.Dataset(path) as nc:
        assert "coordinates" not in nc["cat"].ncattrs()


def test_layers_at_different_times_have_their_own_time_dimensions(tmp_path):
    frame = GeoFrame(LAT, LON, time=FIX_TIME)
    panels = [("near", 300.0, raster(1)), ("far", 600.0, raster(2)), ("far", 900.0, raster(3))]
    path = write_netcdf(tmp_path / "times.nc", raster_dataset(panels, frame))
    with xr.open_dataset(path) as ds:
        assert ds.near.dims == ("time_near", "y", "x") and ds.far.dims == ("time_far", "y", "x")
        assert "time" not in ds.dims
        assert list(ds.time_far.values) == [np.datetime64("2026-11-24T06:10:00", "ns"),
                                            np.datetime64("2026-11-24T06:15:00", "ns")]
        np.testing.assert_array_equal(ds.elapsed_near.values, [300.0])
        np.testing.assert_array_equal(ds.far.values[1], panels[2][2].values)
        assert ds.far_mass.dims == ("time_far",)


def test_raster_to_xarray_takes_the_frame_and_time_from_the_raster():
    grid = Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=200.0)
    r = bg.rasterise(bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54), grid)
    frame = GeoFrame(LAT, LON, time=FIX_TIME)
    ds = replace(r, frame=frame).to_xarray()
    np.testing.assert_array_equal(ds.density.values[0], r.values)
    assert ds.time.values[0] == np.datetime64("2026-11-24T06:00:10", "ns")  # t = 10 s from the provenance
    assert ds.density_mass.values[0] == r.mass and json.loads(ds.density.attrs["bananagrid_provenance"])[0]["model"] == "CAT"
    assert "crs" in ds and ds.lat.shape == grid.shape
    local = r.to_xarray(name="banana", t=5.0)
    assert "lat" not in local and local.elapsed.values[0] == 5.0 and local.banana.dims == ("elapsed", "y", "x")


def test_polar_raster_to_xarray_has_ranges_bearings_bounds_and_latlon(tmp_path):
    lattice = PolarLattice(ranges=(0.0, 1000.0), range_step=250.0, bearings=(-0.5, 0.5), bearing_step=0.25)
    rng = np.random.default_rng(7)
    polar = PolarRaster(density=rng.random(lattice.shape), probability=rng.random(lattice.shape), lattice=lattice,
                        mass=0.97, provenance={"model": "test"}, frame=GeoFrame(LAT, LON))
    path = write_netcdf(tmp_path / "polar.nc", polar.to_xarray())
    with xr.open_dataset(path) as ds:
        np.testing.assert_array_equal(ds.density.values, polar.density)
        np.testing.assert_array_equal(ds.probability.values, polar.probability)
        np.testing.assert_array_equal(ds.range.values, lattice.range_centres)
        np.testing.assert_array_equal(ds.range_bounds.values[:, 0], lattice.range_edges[:-1])
        np.testing.assert_array_equal(ds.bearing_bounds.values[:, 1], lattice.bearing_edges[1:])
        assert (ds.density.attrs["units"], ds.probability.attrs["units"]) == ("m-1 rad-1", "1")
        assert ds.attrs["mass"] == 0.97
        wx, wy = lattice.world_centres  # heading north: x = r sin b, y = r cos b
        to_geo = pyproj.Transformer.from_crs(pyproj.CRS.from_proj4(CRSS["aeqd"]), "EPSG:4326", always_xy=True)
        lon, lat = to_geo.transform(wx, wy)
        np.testing.assert_allclose(ds.lat.values, lat, rtol=0, atol=1e-9)  # 0.1 mm, as above
        np.testing.assert_allclose(ds.lon.values, lon, rtol=0, atol=1e-9)


@pytest.mark.parametrize("geometry", ["line", "plane"])
def test_cell_map_to_xarray_has_cells_with_bounds(tmp_path, geometry):
    if geometry == "line":
        lattice = AngularLattice(geometry="line", h=10.0, azimuth_step=math.pi / 8)
    else:
        lattice = AngularLattice(geometry="plane", h=10.0, azimuth_step=math.pi / 4, elevation_step=math.pi / 8)
    rng = np.random.default_rng(3)
    cells = CellMap(prob=rng.random(lattice.shape), lattice=lattice, error=np.full(lattice.shape, 1e-9),
                    region_probability=0.8, provenance={"model": "test"})
    path = write_netcdf(tmp_path / "cells.nc", cells.to_xarray())
    with xr.open_dataset(path) as ds:
        np.testing.assert_array_equal(ds.probability.values, cells.prob)
        np.testing.assert_array_equal(ds.azimuth.values, lattice.azimuths)
        np.testing.assert_array_equal(ds.azimuth_bounds.values[:, 0], lattice.azimuth_edges[:-1])
        np.testing.assert_array_equal(ds.cell_size.values, lattice.sizes)
        assert float(ds.region_probability) == 0.8 and ds.error.shape == lattice.shape
        assert ("elevation" in ds.dims) == (geometry != "line")


@pytest.mark.parametrize("frame", ["dated", "undated", "none"])
def test_the_cf_compliance_checker_passes_every_check(tmp_path, frame):
    """The IOOS compliance checker (its CF 1.10 suite; cf-units' wheels bundle UDUNITS-2, and
    the standard-name table ships with it, so it runs offline) passes every check: errors and
    warnings alike, on files with and without a geographic frame and its time."""
    frames = {"dated": GeoFrame(LAT, LON, time=FIX_TIME), "undated": GeoFrame(LAT, LON), "none": None}
    panels = scene_panels() + [("other", 60.0, raster(9))]  # two time dimensions
    cells = {("cat", 600.0): cell_probabilities(1), ("cat", 1200.0): cell_probabilities(2),
             ("other", 60.0): cell_probabilities(3)}  # with the cell probabilities of two layers
    path = write_netcdf(tmp_path / "scene.nc", raster_dataset(panels, frames[frame], title="checked", cells=cells))
    run = subprocess.run([str(Path(sys.executable).parent / "compliance-checker"), "--test=cf:1.10", str(path)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and "All tests passed!" in run.stdout, run.stdout + run.stderr


@pytest.mark.parametrize("crs_name", sorted(CRSS))
def test_cell_probabilities_sit_beside_their_layer_to_the_bit(tmp_path, crs_name):
    """A layer's cell probabilities (POC) are LAYER_probability: its dimensions, coordinates
    and grid mapping, units 1, the values exactly as given (float64, however small)."""
    panels = scene_panels()
    cells = {("cat-course", 600.0): cell_probabilities(5), ("cat-course", 1200.0): cell_probabilities(6)}
    frame = GeoFrame(LAT, LON, time=FIX_TIME, crs=crs_name)
    path = write_netcdf(tmp_path / "scene.nc", raster_dataset(panels, frame, cells=cells))
    with netCDF4.Dataset(path) as nc:
        assert "cat_probability" not in nc.variables  # only the layer given them
        var = nc["cat_course_probability"]
        assert var.dimensions == nc["cat_course"].dimensions == ("time", "y", "x") and var.dtype == np.float64
        np.testing.assert_array_equal(var[:].data, np.stack([cells["cat-course", t].values for t in (600.0, 1200.0)]))
        assert (var.units, var.cell_methods, var.bananagrid_cells_of, var.grid_mapping) == (
            "1", "area: sum", "cat-course", "crs")
        assert "probability of containment" in var.long_name and set(var.coordinates.split()) == {"elapsed", "lat", "lon"}
        assert [p["seed"] for p in json.loads(var.bananagrid_provenance)] == [5, 6]
    title, maps = read_maps(path)  # the plot reader takes the densities only
    assert sorted({m["layer"] for m in maps}) == ["cat", "cat-course"]


@pytest.mark.parametrize("cells, message", [
    ({("nope", 600.0): None}, r"^cells: key \('nope', 600.0\) names no map \(layer_name, t\) of the panels$"),
    ({("cat", 600.0): raster(1)}, r"^cells\['cat', 600\]: expected a Raster of cell probabilities \(quantity "
                                  r"'probability'\), got Raster of quantity \"density\"$"),
    ({("cat", 600.0): cell_probabilities(1)}, r"^cells: layer 'cat' has cell probabilities at some of its times but "
                                              r"not at t = 1200 s; give them at every time or at none$"),
    ({("cat", 600.0): cell_probabilities(1, Grid.from_bounds(x=(0.0, 400.0), y=(0.0, 400.0), step=100.0)),
      ("cat", 1200.0): cell_probabilities(2)}, r"^cells\['cat', 600\]: not on the panels' grid"),
    ([1, 2], r"^cells = \[1, 2\]: expected a mapping of \(layer_name, t\) to a Raster of cell probabilities$"),
])
def test_bad_cell_probabilities_are_refused_in_one_line(cells, message):
    with pytest.raises(BananagridError, match=message):
        raster_dataset(scene_panels(), cells=cells)


# --- bad input --------------------------------------------------------------------------------


def test_empty_panels_are_refused():
    with pytest.raises(BananagridError, match="^panels is empty: give at least one"):
        raster_dataset([])


def test_panels_on_different_grids_are_refused(tmp_path):
    other = Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=200.0)
    with pytest.raises(BananagridError, match=r"^panels\[1\] \(b, t = 5 s\) is on a different grid .*one file holds one grid$"):
        raster_dataset([("a", 5.0, raster(1)), ("b", 5.0, raster(2, grid=other))])


@pytest.mark.parametrize("panels, message", [
    ([("a", 5.0)], r"^panels\[0\] = .*: expected \(layer_name, t, raster\)$"),
    ([("", 5.0, None)], r'^panels\[0\]: layer name "" must be a non-empty string$'),
    ([("a", float("nan"), None)], r"^panels\[0\] \(a\): t = nan must be a finite number of seconds$"),
    ([("a", 5.0, np.zeros((9, 15)))], r"^panels\[0\] \(a\): ndarray is not a Raster$"),
    ("abc", r'^panels = "abc": expected a sequence'),
])
def test_malformed_panels_are_refused(panels, message):
    with pytest.raises(BananagridError, match=message):
        raster_dataset(panels)


def test_a_layer_twice_at_one_time_and_a_name_clash_are_refused():
    with pytest.raises(BananagridError, match=r"^panels\[1\]: layer 'a' is given twice at t = 5 s$"):
        raster_dataset([("a", 5.0, raster(1)), ("a", 5.0, raster(2))])
    with pytest.raises(BananagridError, match=r"^layer 'lat': its variable name 'lat' is already used"):
        raster_dataset([("lat", 5.0, raster(1))])
    with pytest.raises(BananagridError, match=r"^layer 'a-b': its variable name 'a_b' is already used"):
        raster_dataset([("a_b", 5.0, raster(1)), ("a-b", 5.0, raster(2))])


def test_a_missing_directory_is_one_line_and_writes_nothing(tmp_path):
    ds = raster_dataset(scene_panels())
    with pytest.raises(BananagridError, match=r"^\S+missing/scene.nc: cannot write the NetCDF file: directory \S+ does not exist$"):
        write_netcdf(tmp_path / "missing" / "scene.nc", ds)
    assert os.listdir(tmp_path) == []


def test_a_failure_while_writing_leaves_nothing_behind(tmp_path, monkeypatch):
    def fail_half_way(self, path, **kwargs):
        Path(path).write_bytes(b"CDF\x01 half a file")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", fail_half_way)
    (tmp_path / "scene.nc").write_bytes(b"the previous file")
    with pytest.raises(BananagridError, match=r"^\S+scene.nc: cannot write the NetCDF file \(No space left on device\)$"):
        write_netcdf(tmp_path / "scene.nc", raster_dataset(scene_panels()))
    assert os.listdir(tmp_path) == ["scene.nc"]  # no temporary file
    assert (tmp_path / "scene.nc").read_bytes() == b"the previous file"  # and the old file untouched


def test_import_bananagrid_loads_no_geo_library():
    code = "import sys, bananagrid; print(sorted(m for m in ('xarray', 'netCDF4', 'rasterio', 'pyproj') if m in sys.modules))"
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")  # affine's `*` inside rasterio
def test_gdal_places_a_layer_as_qgis_will(tmp_path):
    """QGIS opens NetCDF through GDAL: GDAL must find the CRS and the cell centres (its own
    reading of x, y and the grid mapping, independent of xarray)."""
    rasterio = pytest.importorskip("rasterio")
    frame = GeoFrame(LAT, LON, time=FIX_TIME, crs="EPSG:32632")
    panels = scene_panels()
    path = write_netcdf(tmp_path / "scene.nc", raster_dataset(panels, frame))
    e, n = expected_projected("EPSG:32632")
    with rasterio.open(f'NETCDF:"{path}":cat') as src:
        assert src.crs.to_epsg() == 32632 and (src.count, src.height, src.width) == (2, GRID.ny, GRID.nx)
        x, y = src.xy(0, 0)  # GDAL's row 0 is the north
        assert x == pytest.approx(e[0], abs=1e-6) and y == pytest.approx(n[-1], abs=1e-6)  # 1 um, as above
        np.testing.assert_array_equal(src.read(1), panels[1][2].values[::-1])  # t = 600 s, north up


def test_a_frame_without_a_time_gives_latlon_and_elapsed_seconds(tmp_path):
    path = write_netcdf(tmp_path / "notime.nc", raster_dataset(scene_panels(), GeoFrame(LAT, LON)))
    with netCDF4.Dataset(path) as nc:
        assert nc["elapsed"].units == "s" and "standard_name" not in nc["elapsed"].ncattrs()
        assert "time" not in nc.variables and nc["cat"].dimensions == ("elapsed", "y", "x")
        assert nc["cat"].coordinates == "lat lon" and nc["cat"].grid_mapping == "crs"
        np.testing.assert_array_equal(nc["elapsed"][:].data, [600.0, 1200.0])
