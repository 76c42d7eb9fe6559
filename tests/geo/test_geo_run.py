"""A geographic scene end to end, as a user runs it: `bananagrid run --netcdf --geotiff
--geojson` on a bundled scene, each file read back with the field's own readers (xarray,
netCDF4, rasterio, json + shapely) and checked against the recording and pyproj; `inspect` and
`plot` on what it wrote; the one-line refusals."""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
import shapely
import shapely.geometry
import xarray as xr

from bananagrid import cli
from bananagrid.recording.inspect import layer_summaries
from bananagrid.recording.geomap import VIEW_PIXELS, map_zoom
from bananagrid.recording.readback import open_recording, read_rasters, recording_rows
from bananagrid.scenes.load import load_scene
from bananagrid.scenes.pictures import read_picture

ROOT = Path(__file__).resolve().parents[2]
SHIP = ROOT / "scenes" / "geo_ship.toml"
STEP = 200.0  # m: 60 x 45 cells, a quick run; the files do not depend on the step


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("geo")
    argv = ["run", str(SHIP), "--out", str(out), "--step", str(STEP), "--quiet", "--netcdf", "--geotiff", "--geojson"]
    assert cli.main(argv) == 0
    return out


def test_run_writes_every_file_asked_for(written):
    assert sorted(p.name for p in written.iterdir()) == [
        "geo_ship-areas.geojson", "geo_ship.nc", "geo_ship.rrd", "geo_ship.tif"]


def test_the_netcdf_holds_the_recordings_maps_with_latlon_and_utc_times(written):
    recorded = {(r.layer, r.t): r.raster for r in read_rasters(written / "geo_ship.rrd")}
    aeqd = pyproj.Transformer.from_crs("+proj=aeqd +lat_0=60.45 +lon_0=4.6 +datum=WGS84", "EPSG:4326", always_xy=True)
    with xr.open_dataset(written / "geo_ship.nc") as ds:
        assert list(ds.time.values) == [np.datetime64(f"2026-11-24T05:{m}:00", "ns") for m in (45, 50, 55)]
        np.testing.assert_array_equal(ds.elapsed.values, [300.0, 600.0, 900.0])
        lon, lat = aeqd.transform(*np.meshgrid(ds.x.values, ds.y.values))
        np.testing.assert_allclose(ds.lat.values, lat, atol=1e-9)  # 0.1 mm: the same PROJ inverse
        np.testing.assert_allclose(ds.lon.values, lon, atol=1e-9)
        for (layer, t), raster in recorded.items():
            values = ds[layer].sel(time=np.datetime64("2026-11-24T05:40:00", "ns") + np.timedelta64(int(t), "s")).values
            # the recording stores float32: the file's float64 agrees to float32 rounding
            np.testing.assert_allclose(values, raster.values, rtol=2**-23, atol=1e-30)


def test_the_geotiff_is_georeferenced_in_the_scenes_projection(written):
    scene = load_scene(SHIP).with_step(STEP)
    with rasterio.open(written / "geo_ship.tif") as tif:
        assert tif.count == 2 * 3 and tif.dtypes[0] == "float32"
        assert pyproj.CRS.from_wkt(tif.crs.to_wkt()).equals(scene.geo.crs)
        x0, x1, y0, y1 = scene.grid.extent
        assert (tif.bounds.left, tif.bounds.bottom, tif.bounds.right, tif.bounds.top) == pytest.approx((x0, y0, x1, y1))
        assert tif.descriptions[0] == "cat t=300 s"


def test_the_geojson_search_areas_hold_their_levels(written):
    collection = json.loads((written / "geo_ship-areas.geojson").read_text())
    assert collection["type"] == "FeatureCollection"
    levels = sorted({f["properties"]["level"] for f in collection["features"]})
    assert levels == [0.5, 0.9, 0.95, 0.99]  # the scene's output.mass_levels (the default)
    for feature in collection["features"]:
        shape = shapely.geometry.shape(feature["geometry"])
        assert shape.is_valid and not shape.is_empty
        lon0, lat0, lon1, lat1 = shape.bounds
        assert 60.35 < lat0 < lat1 < 60.47 and 4.45 < lon0 < lon1 < 4.70  # west of Bergen, south of the fix


def test_inspect_says_where_the_target_is_in_latitude_and_longitude(written, capsys):
    summaries = layer_summaries(written / "geo_ship.rrd")
    first = summaries[0]
    assert first["utc"] == "2026-11-24T05:45:00Z" and first["crs"] == "aeqd"
    geod = pyproj.Geod(ellps="WGS84")
    # the peak's place: its distance and azimuth from the fix are the cell centre's (aeqd)
    azimuth, _, distance = geod.inv(4.6, 60.45, first["peak_lon"], first["peak_lat"])
    assert distance == pytest.approx(math.hypot(first["peak_x"], first["peak_y"]), rel=1e-9)
    assert math.radians(azimuth) % (2 * math.pi) == pytest.approx(math.atan2(first["peak_x"], first["peak_y"]) % (2 * math.pi), abs=1e-9)
    assert cli.main(["inspect", str(written / "geo_ship.rrd")]) == 0
    text = capsys.readouterr().out
    assert "cat at t = 300 s (2026-11-24T05:45:00Z)" in text
    # degrees to a tenth of the 200 m cell: 4 decimals (11 m of latitude)
    assert f"{first['peak_lat']:.4f} N {first['peak_lon']:.4f} E" in text


def test_plot_draws_the_netcdf_as_it_draws_the_recording(written, tmp_path):
    from_nc, from_rrd = read_picture(written / "geo_ship.nc", t=600.0), read_picture(written / "geo_ship.rrd", t=600.0)
    # the recording lists its layers by name, the file in the scene's order
    by_name = sorted(from_nc.panels, key=lambda p: p.layer)
    assert [(p.layer, p.t) for p in by_name] == [(p.layer, p.t) for p in from_rrd.panels]
    for a, b in zip(by_name, from_rrd.panels):
        assert a.raster.grid == b.raster.grid and a.raster.frame == b.raster.frame
        np.testing.assert_allclose(a.raster.values, b.raster.values, rtol=2**-23, atol=1e-30)
    assert cli.main(["plot", str(written / "geo_ship.nc"), "-o", str(tmp_path / "nc.png"), "--dpi", "30"]) == 0
    assert (tmp_path / "nc.png").stat().st_size > 0


def test_map_files_a_scene_cannot_give_are_refused_before_computing(tmp_path, capsys):
    local = ROOT / "scenes" / "folding.toml"
    assert cli.main(["run", str(local), "--out", str(tmp_path), "--geojson"]) == 2
    assert "--geojson: search areas are written in latitude and longitude, and this scene has no [geo] table" in capsys.readouterr().err
    room = ROOT / "scenes" / "room_mixture.toml"
    assert cli.main(["run", str(room), "--out", str(tmp_path), "--netcdf"]) == 2
    assert "--netcdf: an [array] scene maps angular cells, not a grid" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_local_scene_gets_netcdf_and_geotiff_in_local_metres(tmp_path):
    local = ROOT / "scenes" / "folding.toml"
    assert cli.main(["run", str(local), "--out", str(tmp_path), "--step", "100", "--quiet", "--netcdf", "--geotiff"]) == 0
    with xr.open_dataset(tmp_path / "folding.nc") as ds:
        assert "lat" not in ds and "crs" not in ds and ds.cat.dims == ("elapsed", "y", "x")
    with rasterio.open(tmp_path / "folding.tif") as tif:
        assert tif.crs is None


def test_utc_times_follow_the_scene(written):
    scene = load_scene(SHIP)
    assert scene.geo.utc(900.0) == datetime(2026, 11, 24, 5, 55, tzinfo=timezone.utc)


# --- the map view ---------------------------------------------------------------------------


def _map_rows(rrd: Path) -> dict:
    """``{(entity, elapsed s or None): {component: python value}}`` of the ``/map`` entities."""
    reader, store = open_recording(rrd)
    rows = {}
    for entity, times, cells in recording_rows(reader, store):
        if entity.startswith("/map/"):
            t = times["elapsed"][1] / 1e9 if "elapsed" in times else None
            rows[entity, t] = {name: value.as_py() for name, (_, value) in cells.items()}
    return rows


def test_the_recording_puts_the_fix_and_the_search_areas_on_a_map(written):
    rows = _map_rows(written / "geo_ship.rrd")
    for layer in ("cat", "butterly"):
        (fix,) = rows[f"/map/{layer}/fix", None]["GeoPoints:positions"]
        assert fix == pytest.approx([60.45, 4.60], abs=1e-9)  # the fix (the Butterly start's mean)
    collection = json.loads((written / "geo_ship-areas.geojson").read_text())
    for feature in collection["features"]:
        props = feature["properties"]
        rings = rows[f"/map/{props['layer']}/areas/p{props['level'] * 100:g}", props["t_s"]]["GeoLineStrings:line_strings"]
        drawn = shapely.MultiLineString([[(lon, lat) for lat, lon in ring] for ring in rings])
        filed = shapely.MultiLineString([ring for polygon in feature["geometry"]["coordinates"] for ring in polygon])
        # the same rings (the file's rounded to 1e-7 deg and oriented as RFC 7946 says)
        assert len(drawn.geoms) == len(filed.geoms)
        assert drawn.hausdorff_distance(filed) < 1e-7


def test_bearing_lines_on_the_map_leave_each_station_on_its_true_bearing(tmp_path):
    scene = ROOT / "scenes" / "geo_bearing.toml"
    assert cli.main(["run", str(scene), "--out", str(tmp_path), "--step", "250", "--quiet"]) == 0
    rows = _map_rows(tmp_path / "geo_bearing.rrd")
    stations = rows["/map/exact/stations", None]["GeoPoints:positions"]
    np.testing.assert_allclose(stations, [[60.1279, 5.0086], [60.7517, 4.7131]], atol=1e-9)
    lines = rows["/map/exact/bearings", None]["GeoLineStrings:line_strings"]
    geod = pyproj.Geod(ellps="WGS84")
    for line, true_bearing in zip(lines, (317.4, 206.7)):  # the scene's bearings, deg true
        (lat0, lon0), (lat1, lon1) = line[0], line[1]
        azimuth, _, _ = geod.inv(lon0, lat0, lon1, lat1)
        # a straight line in the plane, turned by the meridian convergence at the station: its
        # first 1/32 (about 1.5 km) leaves on the true bearing to the plane's curvature there
        assert azimuth % 360.0 == pytest.approx(true_bearing, abs=2e-3)


def test_the_map_view_opens_on_the_grid_and_the_marks():
    frame = load_scene(SHIP).geo
    zoom = map_zoom(frame, (-7000.0, 5000.0, -7500.0, 1500.0))
    # Web Mercator: 40,075,016.686 m cos(lat) / (256 * 2^zoom) per pixel; the wider side of the
    # grid (12 km) then spans VIEW_PIXELS at the grid's centre latitude
    lat, _ = frame.geographic(-1000.0, -3000.0)
    metres_per_pixel = 40_075_016.686 * math.cos(math.radians(float(lat))) / (256.0 * 2.0**zoom)
    assert 12_000.0 / metres_per_pixel == pytest.approx(VIEW_PIXELS, rel=1e-6)
