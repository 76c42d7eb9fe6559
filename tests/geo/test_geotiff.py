"""GeoTIFF export: a scene's maps written by bananagrid.geo.geotiff and read back with rasterio:
the CRS, the transform (pixel corners and centres against the projected cell edges and centres
computed here with pyproj), the values flipped north up, band descriptions and tags, and the
one-line errors of bad input (with nothing left behind)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio

from bananagrid import BananagridError, Raster
from bananagrid.domains.grid import Grid
from bananagrid.geo import geotiff
from bananagrid.geo.frame import GeoFrame
from bananagrid.geo.geotiff import write_geotiff

# rasterio's writer multiplies affine transforms with `*`, which affine 2.4 deprecates (not ours)
pytestmark = pytest.mark.filterwarnings("ignore:Use `@` matmul:PendingDeprecationWarning")

LAT, LON, FIX_TIME = 60.39, 5.32, "2026-11-24T06:00:00Z"
GRID = Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=400.0)  # 15 x 9 cells
CRSS = {
    "aeqd": f"+proj=aeqd +lat_0={LAT!r} +lon_0={LON!r} +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs",
    "EPSG:32632": "EPSG:32632",
}


def raster(seed: int, grid: Grid = GRID) -> Raster:
    # values spread over many decades, as densities are (float32 keeps them to 2**-24 relative)
    values = 10.0 ** np.random.default_rng(seed).uniform(-30.0, -4.0, grid.shape)
    return Raster(values=values, grid=grid, mass=0.5 + seed / 100.0, provenance={"model": "test", "seed": seed})


def panels():
    return [("cat", 600.0, raster(1)), ("cat", 1200.0, raster(2)), ("cat-course", 600.0, raster(3))]


@pytest.mark.parametrize("crs_name", sorted(CRSS))
def test_a_scene_reads_back_with_rasterio(tmp_path, crs_name):
    frame = GeoFrame(LAT, LON, time=FIX_TIME, crs=crs_name)
    scene = panels()
    path = write_geotiff(tmp_path / "scene.tif", scene, frame, title="Two layers")
    assert path == tmp_path / "scene.tif" and os.listdir(tmp_path) == ["scene.tif"]
    crs = pyproj.CRS.from_user_input(CRSS[crs_name])
    e0, n0 = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(LON, LAT)
    with rasterio.open(path) as src:
        assert (src.count, src.height, src.width) == (3, GRID.ny, GRID.nx)
        assert src.dtypes == ("float32",) * 3 and src.nodata is None
        assert src.profile["compress"].lower() == "deflate"
        assert pyproj.CRS.from_wkt(src.crs.to_wkt()).equals(crs)
        # pixel (0, 0)'s outer corner is the grid's west and north edges; 1e-6 m allows for the
        # order of the float64 additions (ulp of 6.7e6 m is 1e-9 m)
        west, north = src.transform @ (0, 0)
        assert west == pytest.approx(e0 + GRID.origin[0], abs=1e-6)
        assert north == pytest.approx(n0 + GRID.origin[1] + GRID.ny * GRID.dy, abs=1e-6)
        for row, col in ((0, 0), (GRID.ny - 1, GRID.nx - 1), (2, 11)):
            x, y = src.xy(row, col)  # the pixel's centre
            assert x == pytest.approx(e0 + GRID.x[col], abs=1e-6)
            assert y == pytest.approx(n0 + GRID.y[GRID.ny - 1 - row], abs=1e-6)  # row 0 is the north
        for band, (layer, t, r) in enumerate(scene, start=1):
            np.testing.assert_array_equal(src.read(band), r.values[::-1].astype(np.float32))  # exact: the same cast
            assert src.descriptions[band - 1] == f"{layer} t={t:g} s"
            tags = src.tags(band)
            assert tags["layer"] == layer and float(tags["t"]) == t and float(tags["mass"]) == r.mass
            assert tags["unit"] == "m-2" and tags["model"] == "test"
        assert src.tags(2)["utc"] == "2026-11-24T06:20:00Z"
        assert src.units == ("m-2",) * 3
        assert src.tags()["title"] == "Two layers" and "bananagrid_version" in src.tags()


def test_without_a_frame_there_is_no_crs_and_the_coordinates_are_local_metres(tmp_path):
    path = write_geotiff(tmp_path / "local.tif", panels())
    with rasterio.open(path) as src:
        assert src.crs is None
        assert src.transform @ (0, 0) == (GRID.origin[0], GRID.origin[1] + GRID.ny * GRID.dy)
        assert "utc" not in src.tags(1)


def test_the_rasters_own_frame_is_used(tmp_path):
    frame = GeoFrame(LAT, LON, crs="EPSG:32632")
    scene = [(layer, t, Raster(r.values, r.grid, r.mass, provenance=r.provenance, frame=frame)) for layer, t, r in panels()]
    with rasterio.open(write_geotiff(tmp_path / "own.tif", scene)) as src:
        assert src.crs.to_epsg() == 32632


def test_empty_panels_and_different_grids_are_refused(tmp_path):
    with pytest.raises(BananagridError, match="^panels is empty"):
        write_geotiff(tmp_path / "a.tif", [])
    other = Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=200.0)
    with pytest.raises(BananagridError, match=r"^panels\[1\] \(b, t = 5 s\) is on a different grid"):
        write_geotiff(tmp_path / "a.tif", [("a", 5.0, raster(1)), ("b", 5.0, raster(2, other))])
    assert os.listdir(tmp_path) == []


def test_a_missing_directory_is_one_line_and_writes_nothing(tmp_path):
    with pytest.raises(BananagridError, match=r"^\S+/missing/a.tif: cannot write the GeoTIFF: directory \S+ does not exist$"):
        write_geotiff(tmp_path / "missing" / "a.tif", panels())
    assert os.listdir(tmp_path) == []


def test_a_failure_while_writing_leaves_nothing_behind(tmp_path, monkeypatch):
    calls = []

    def fail_on_the_second_band(*args):
        calls.append(args)
        if len(calls) == 2:
            raise KeyboardInterrupt  # an interrupt half way through the bands
        return {"layer": args[0]}

    monkeypatch.setattr(geotiff, "band_tags", fail_on_the_second_band)
    with pytest.raises(KeyboardInterrupt):
        write_geotiff(tmp_path / "a.tif", panels())
    assert len(calls) == 2 and os.listdir(tmp_path) == []


def cell_probabilities(seed: int) -> Raster:
    """Cell probabilities over 300 decades: float32 would round them and flush most to 0."""
    values = 10.0 ** np.random.default_rng(seed).uniform(-300.0, 0.0, GRID.shape)
    return Raster(values=values / values.sum(), grid=GRID, mass=0.9, normalised=True, quantity="probability",
                  provenance={"model": "test", "seed": seed})


def test_cell_probabilities_are_float64_bands_of_unit_one_to_the_bit(tmp_path):
    frame = GeoFrame(LAT, LON, time=FIX_TIME)
    given = [("cat", 600.0, cell_probabilities(1)), ("cat", 1200.0, cell_probabilities(2))]
    path = write_geotiff(tmp_path / "poc.tif", given, frame)
    with rasterio.open(path) as src:
        assert src.dtypes == ("float64", "float64") and src.units == ("1", "1") and src.nodata is None
        assert src.descriptions == ("cat t=600 s", "cat t=1200 s") and src.tags()["unit"] == "1"
        assert "probability of containment" in src.tags(1)["quantity"]
        for band, (_, _, r) in enumerate(given, start=1):
            np.testing.assert_array_equal(src.read(band)[::-1], r.values)  # north up in the file; exact


def test_densities_and_cell_probabilities_in_one_file_are_refused(tmp_path):
    with pytest.raises(BananagridError, match="^GeoTIFF: panels of quantities density, probability: one file holds one "
                                              r"quantity \(write the cell probabilities to a file of their own\)$"):
        write_geotiff(tmp_path / "mixed.tif", [("cat", 600.0, raster(1)), ("poc", 600.0, cell_probabilities(1))])
    assert not os.listdir(tmp_path)
