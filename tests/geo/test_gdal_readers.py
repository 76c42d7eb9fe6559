"""The map files as GDAL reads them: ``gdalinfo`` and ``gdalwarp -t_srs EPSG:4326`` of the
system's GDAL (Debian 12's 3.6.2 with PROJ 9.1 on CI: .ci/run installs gdal-bin) on the NetCDF
and GeoTIFF files of every CRS a scene's frame can take, and of every bundled geographic
scene's run (and a local one's), each warped map's peak where the project says it is, to a cell.

Where the tools are absent the tests skip, saying so; nothing here needs them to import."""

from __future__ import annotations

import math
import tempfile
import tomllib
from pathlib import Path

import hypothesis
import hypothesis.strategies as st
import numpy as np
import pytest
import rasterio
from hypothesis import settings

from bananagrid import Raster, cli
from bananagrid.domains.grid import Grid
from bananagrid.geo.dataset import raster_dataset, write_netcdf
from bananagrid.geo.frame import GeoFrame
from bananagrid.geo.geotiff import write_geotiff
from bananagrid.scenes.load import load_scene
from geo_cases import FRAME_CRSS
from gdal_tools import check_warped_peaks, gdalinfo, layer_sources, needs_gdal, to_lonlat, warp_to_wgs84

pytestmark = [needs_gdal, pytest.mark.filterwarnings("ignore:Use `@` matmul:PendingDeprecationWarning")]

ROOT = Path(__file__).resolve().parents[2]
GRID = Grid.from_bounds(x=(-9000.0, 6000.0), y=(-4000.0, 8000.0), step=500.0)  # 30 x 24 cells


def gaussian(frame_seed: int) -> Raster:
    """A map whose one peak lies off the grid's centre, at a cell chosen by the seed."""
    rng = np.random.default_rng(frame_seed)
    x0, y0 = rng.uniform(-7000.0, 4000.0), rng.uniform(-2000.0, 6000.0)
    gx, gy = np.meshgrid(GRID.x, GRID.y)
    values = np.exp(-((gx - x0) ** 2 + (gy - y0) ** 2) / (2.0 * 1500.0**2)) / (2.0 * math.pi * 1500.0**2)
    return Raster(values=values, grid=GRID, mass=float(values.sum() * GRID.cell_area), provenance={"model": "test"})


def check_frame(tmp_path: Path, frame: GeoFrame, seed: int) -> None:
    """GDAL reads the NetCDF and the GeoTIFF of one map in ``frame`` (a CRS, the grid) and warps
    both to longitude and latitude with the peak in its cell."""
    first, second = gaussian(seed), gaussian(seed + 1)
    panels = [("map", 0.0, first), ("map", 60.0, second)]
    nc = write_netcdf(tmp_path / "map.nc", raster_dataset(panels, frame))
    tif = write_geotiff(tmp_path / "map.tif", panels, frame)
    for source in (f'NETCDF:"{nc}":map', tif):
        info = gdalinfo(source)
        assert info["size"] == [GRID.nx, GRID.ny] and info["coordinateSystem"]["wkt"]
        check_warped_peaks(warp_to_wgs84(source, tmp_path / "warped.tif", GRID, frame), [first.values, second.values], GRID, frame)


@pytest.mark.parametrize("crs, lat, lon", FRAME_CRSS)
def test_gdal_reads_and_warps_the_files_of_each_kind_of_crs(tmp_path, crs, lat, lon):
    check_frame(tmp_path, GeoFrame(lat, lon, crs=crs), seed=int(abs(lat * 10)))


@pytest.mark.parametrize("crs, lat, lon", FRAME_CRSS)
def test_gdals_proj_maps_the_files_crs_as_the_frame_does(crs, lat, lon):
    """GDAL's PROJ (9.1 on Debian 12), given the WKT the files carry, takes projected points to
    the latitudes and longitudes pyproj's PROJ gives the frame, to 1e-9 degrees (0.1 mm): at the
    grid's corners and 300 km away, where an approximate azimuthal equidistant (EPSG's
    "Modified", as GDAL names the WKT1 method) would be metres off."""
    frame = GeoFrame(lat, lon, crs=crs)
    x = np.array([GRID.extent[0], GRID.extent[1], 3e5, -2e5])
    y = np.array([GRID.extent[2], GRID.extent[3], -1e5, 3e5])
    plat, plon = frame.geographic(x, y)
    held = np.isfinite(plat) & np.isfinite(plon)
    e, n = frame.projected(x[held], y[held])
    got = to_lonlat(frame.portable_wkt, e, n)
    np.testing.assert_allclose(got[:, 0], plon[held], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got[:, 1], plat[held], rtol=0, atol=1e-9)


@hypothesis.seed(35)
@settings(max_examples=10, deadline=None, database=None)
@hypothesis.given(lat=st.floats(-80.0, 80.0), lon=st.floats(-179.0, 179.0), crs=st.sampled_from(["aeqd", "utm"]),
                  seed=st.integers(0, 1000))
def test_gdal_warps_the_local_frame_anywhere_on_the_globe(lat, lon, crs, seed):
    # longitudes within 1 degree of the antimeridian are left to the table (a grid across it
    # warps to a map 360 degrees wide); latitudes beyond 80 to the polar CRSs of the table
    with tempfile.TemporaryDirectory() as tmp:
        check_frame(Path(tmp), GeoFrame(lat, lon, crs=crs), seed)


def geographic_scenes() -> list[str]:
    """The bundled scenes with a [geo] table."""
    return sorted(p.stem for p in (ROOT / "scenes").glob("*.toml") if "geo" in tomllib.loads(p.read_text()))


#: A quick step per scene (m): tens of cells a side; the files do not depend on it.
STEPS = {"geo_ship": 200.0, "geo_bearing": 250.0, "rice_isotropic": 100.0}
LOCAL_SCENE = "rice_isotropic"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """Every geographic bundled scene, and a local one, run with --netcdf --geotiff --npz."""
    out = {}
    for name in [*geographic_scenes(), LOCAL_SCENE]:
        out[name] = tmp_path_factory.mktemp(name)
        argv = ["run", "--example", name, "--out", str(out[name]), "--step", str(STEPS.get(name, 250.0)), "--quiet",
                "--netcdf", "--geotiff", "--npz"]
        assert cli.main(argv) == 0
    return out


def test_every_geographic_bundled_scene_is_run_here():
    assert geographic_scenes() and set(geographic_scenes()) <= set(STEPS)


@pytest.mark.parametrize("name", geographic_scenes())
def test_gdal_reads_and_warps_every_map_of_a_geographic_scene(runs, tmp_path, name):
    out = runs[name]
    scene = load_scene(ROOT / "scenes" / f"{name}.toml").with_step(STEPS[name])
    arrays = np.load(out / f"{name}.npz")
    info = gdalinfo(out / f"{name}.nc")  # the file itself: its subdatasets
    sources = layer_sources(info)
    assert len(sources) == len(scene.layers)
    for source in sources:
        variable = source.rsplit(":", 1)[1]
        layer = next(l.name for l in scene.layers if l.name.replace("-", "_") == variable)
        times = sorted(t for l, t in scene.jobs() if l.name == layer)  # the NetCDF's bands: the layer's times in order
        maps = [arrays[f"{layer}__t{np.format_float_positional(t, trim='-')}"] for t in times]
        assert gdalinfo(source)["coordinateSystem"]["wkt"]
        check_warped_peaks(warp_to_wgs84(source, tmp_path / f"{variable}.tif", scene.grid, scene.geo), maps, scene.grid, scene.geo)
    with rasterio.open(out / f"{name}.tif") as tif:
        bands = [d.rsplit(" t=", 1) for d in tif.descriptions]
    maps = [arrays[f"{layer}__t{t.removesuffix(' s')}"] for layer, t in bands]
    assert gdalinfo(out / f"{name}.tif")["coordinateSystem"]["wkt"]
    check_warped_peaks(warp_to_wgs84(out / f"{name}.tif", tmp_path / "tif.tif", scene.grid, scene.geo), maps, scene.grid, scene.geo)


def test_gdal_reads_a_local_scenes_files_in_local_metres(runs):
    out = runs[LOCAL_SCENE]
    grid = load_scene(ROOT / "scenes" / f"{LOCAL_SCENE}.toml").with_step(STEPS[LOCAL_SCENE]).grid
    sources = layer_sources(gdalinfo(out / f"{LOCAL_SCENE}.nc"))
    assert sources
    for source in [*sources, out / f"{LOCAL_SCENE}.tif"]:
        info = gdalinfo(source)
        assert info["size"] == [grid.nx, grid.ny] and "coordinateSystem" not in info or not info["coordinateSystem"].get("wkt")
        # GDAL's geotransform: the west edge, the cell width, 0; the north edge, 0, minus the height
        west, dx, _, north, _, dy = info["geoTransform"]
        x0, x1, y0, y1 = grid.extent
        assert (west, dx, north, dy) == pytest.approx((x0, grid.dx, y1, -grid.dy), abs=1e-9 * max(abs(x0), abs(y1)))
