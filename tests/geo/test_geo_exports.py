"""A geographic scene that asks for its cell probabilities, run as a user runs it
(``bananagrid run --npz --netcdf --geotiff --geojson --kml``): the cell probabilities (POC) in
the NetCDF, their own GeoTIFF and a Zarr store agree with the .npz to the bit, GDAL reads and
warps them, and the KML holds the GeoJSON's search areas and the fix."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import rasterio
import xarray as xr

from bananagrid import Raster, cli
from bananagrid.geo.kml import KML_NAMESPACE
from bananagrid.geo.zarr_store import write_zarr
from bananagrid.scenes.load import parse_scene
from bananagrid.scenes.run_grid import EXPORT_BYTES_PER_MAP_CELL, check_run_memory
from gdal_tools import check_warped_peaks, gdalinfo, needs_gdal, warp_to_wgs84
from test_kml import assert_same_areas, geojson_areas, kml_areas

pytestmark = pytest.mark.filterwarnings("ignore:Use `@` matmul:PendingDeprecationWarning")

SCENE = """
[scene]
name = "poc"
title = "A vessel west of Bergen, with the probability of each cell"
times = [120.0, 240.0]

[geo]
origin_latlon = [60.45, 4.60]
time = "2026-11-24T06:00:00Z"

[grid]
x = [-2600.0, 2600.0]
y = [-1400.0, 3400.0]
step = 100.0

[layers.cat]
model = "cat"
v0 = 8.0
sigma_a = 0.05
sigma_omega_deg = 0.3
heading_deg = 20.0

[output]
cell_probabilities = true
"""
TIMES = (120.0, 240.0)


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("poc")
    (out / "poc.toml").write_text(SCENE)
    argv = ["run", str(out / "poc.toml"), "--out", str(out), "--quiet", "--npz", "--netcdf", "--geotiff", "--geojson",
            "--kml"]
    assert cli.main(argv) == 0
    return out


def npz_cells(out: Path) -> list[np.ndarray]:
    arrays = np.load(out / "poc.npz")
    return [arrays[f"cat__t{t:g}__probability"] for t in TIMES]


def test_run_writes_the_cell_probabilities_geotiff_and_the_kml(written):
    assert sorted(p.name for p in written.iterdir() if p.suffix != ".toml") == [
        "poc-areas.geojson", "poc-probability.tif", "poc.kml", "poc.nc", "poc.npz", "poc.rrd", "poc.tif"]


def test_the_netcdf_holds_the_cell_probabilities_of_the_npz_to_the_bit(written):
    expected = npz_cells(written)
    with netCDF4.Dataset(written / "poc.nc") as nc:
        var = nc["cat_probability"]
        assert var.units == "1" and var.dimensions == ("time", "y", "x") and var.dtype == expected[0].dtype
        np.testing.assert_array_equal(var[:].data, np.stack(expected))
    with xr.open_dataset(written / "poc.nc") as ds:
        np.testing.assert_array_equal(ds["cat_probability"].values, np.stack(expected))
        # the density variable and its captured mass: the cells' sum before normalising
        assert ds["cat"].attrs["units"] == "m-2" and np.all(ds["cat_mass"].values > 0.0)


def test_the_cell_probabilities_geotiff_holds_the_npz_to_the_bit(written):
    expected = npz_cells(written)
    with rasterio.open(written / "poc-probability.tif") as src, rasterio.open(written / "poc.tif") as densities:
        assert src.count == 2 and src.dtypes == ("float64", "float64") and src.units == ("1", "1")
        assert src.descriptions == densities.descriptions == ("cat t=120 s", "cat t=240 s")
        assert src.transform == densities.transform and src.crs == densities.crs
        for band, values in enumerate(expected, start=1):
            np.testing.assert_array_equal(src.read(band)[::-1], values)  # row 0 is the north


def test_a_zarr_store_holds_the_cell_probabilities_to_the_bit(written, tmp_path):
    """write_zarr takes the cell probabilities as the NetCDF does (the store here is written from
    the maps in memory)."""
    scene = parse_scene(SCENE)
    arrays = np.load(written / "poc.npz")
    panels = [("cat", t, Raster(values=arrays[f"cat__t{t:g}"], grid=scene.grid, mass=1.0, frame=scene.geo))
              for t in TIMES]
    cells = {("cat", t): Raster(values=v, grid=scene.grid, mass=1.0, quantity="probability", frame=scene.geo)
             for t, v in zip(TIMES, npz_cells(written))}
    store = write_zarr(tmp_path / "poc.zarr", panels, scene.geo, cells=cells)
    with xr.open_zarr(store) as ds:
        np.testing.assert_array_equal(ds["cat_probability"].values, np.stack(npz_cells(written)))
        assert ds["cat_probability"].attrs["units"] == "1"


def test_run_zarr_computes_the_cell_probabilities_in_tiles(written, tmp_path):
    """``run --zarr`` on the scene: each cell's probability beside its density, computed in the
    store's tiles by the same cell rules as the .npz's, and like the store's densities not
    normalised (the .npz's are: divided by the captured mass, 0.87 at 240 s). Normalised, equal
    to rounding, not to the bit (the rules' sums run in another order on a block): within 1e-14
    of the largest cell (the rules' own accuracy is 1e-8 relative)."""
    (tmp_path / "poc.toml").write_text(SCENE)
    store = tmp_path / "poc.zarr"
    assert cli.main(["run", str(tmp_path / "poc.toml"), "--zarr", str(store), "--chunks", "16", "--quiet"]) == 0
    expected = np.stack(npz_cells(written))
    with xr.open_zarr(store) as ds:
        got = ds["cat_probability"].values
        assert ds["cat_probability"].attrs["units"] == "1"
    mass = got.sum(axis=(1, 2), keepdims=True)
    assert np.all(mass <= 1.0 + 1e-12) and mass.min() < 0.9  # raw: the grid misses some at 240 s
    np.testing.assert_allclose(got / mass, expected, rtol=0, atol=1e-14 * expected.max())


@needs_gdal
def test_gdal_reads_and_warps_the_cell_probabilities(written, tmp_path):
    scene = parse_scene(SCENE)
    expected = npz_cells(written)
    for source in (f'NETCDF:"{written / "poc.nc"}":cat_probability', written / "poc-probability.tif"):
        assert gdalinfo(source)["coordinateSystem"]["wkt"]
        check_warped_peaks(warp_to_wgs84(source, tmp_path / "warped.tif", scene.grid, scene.geo), expected,
                           scene.grid, scene.geo)


def test_the_kml_holds_the_geojsons_areas_and_the_fix(written):
    assert_same_areas(kml_areas(written / "poc.kml"), geojson_areas(written / "poc-areas.geojson"))
    ns = {"k": KML_NAMESPACE}
    fixes = [p.find("k:Point/k:coordinates", ns).text for p in ET.parse(written / "poc.kml").getroot().iter(
        f"{{{KML_NAMESPACE}}}Placemark") if p.find("k:name", ns).text == "last fix"]
    assert fixes == ["4.6,60.45"]
    levels = {f["properties"]["level"] for f in json.loads((written / "poc-areas.geojson").read_text())["features"]}
    assert levels == {0.5, 0.9, 0.95, 0.99}


def test_the_memory_estimate_counts_the_cell_probabilities_kept_for_the_files():
    """A map kept for the files costs EXPORT_BYTES_PER_MAP_CELL per cell, and its cell
    probabilities as much again."""
    scene = parse_scene(SCENE)
    kept = check_run_memory(scene, exports=True, limit=1e12) - check_run_memory(scene, limit=1e12)
    assert kept == pytest.approx(scene.grid.nx * scene.grid.ny * EXPORT_BYTES_PER_MAP_CELL * 2 * len(scene.jobs()))
