"""KML export: search areas and landmarks written by bananagrid.geo.kml, read back by a second
reader (GDAL's LIBKML driver through ``ogr2ogr`` where GDAL is installed, and always a plain XML
parse of the KML 2.2 elements), their polygons the GeoJSON export's to 1e-7 degrees, over the
globe and across the antimeridian; and the one-line refusals."""

from __future__ import annotations

import json
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import hypothesis
import hypothesis.strategies as st
import numpy as np
import pytest
import shapely.geometry
import shapely.wkt
from hypothesis import settings

from bananagrid import BananagridError, Raster, cli
from bananagrid.domains.grid import Grid
from bananagrid.geo.frame import GeoFrame
from bananagrid.geo.geojson import write_geojson
from bananagrid.geo.kml import KML_NAMESPACE, write_kml
from gdal_tools import gdal, needs_gdal

NS = {"k": KML_NAMESPACE}
GRID = Grid.from_bounds(x=(-6000.0, 6000.0), y=(-5000.0, 7000.0), step=250.0)  # 48 x 48 cells
LEVELS = (0.5, 0.9, 0.99)
#: 1e-7 degrees: the GeoJSON's precision (its coordinates are rounded to 7 decimals, about 1 cm);
#: the KML carries the same numbers, so any difference is a misplaced vertex.
DEGREES = 1e-7


def ring_map(seed: int) -> Raster:
    """A density with a hole (a ring about an off-centre point) and a second peak: polygons with
    holes and several parts."""
    rng = np.random.default_rng(seed)
    cx, cy = rng.uniform(-2000.0, 2000.0, 2)
    gx, gy = np.meshgrid(GRID.x, GRID.y)
    r = np.hypot(gx - cx, gy - cy)
    values = np.exp(-0.5 * ((r - 2500.0) / 600.0) ** 2) + 0.7 * np.exp(-0.5 * (np.hypot(gx + 4500.0, gy - 5000.0) / 500.0) ** 2)
    values /= values.sum() * GRID.cell_area
    return Raster(values=values, grid=GRID, mass=1.0, normalised=True, provenance={"model": "test"})


def write_both(folder: Path, frame: GeoFrame, seed: int) -> tuple[Path, Path]:
    panels = [("ring", 60.0, ring_map(seed)), ("ring", 120.0, ring_map(seed + 1))]
    marks = {"ring": {"fix": np.array([0.0, 0.0]), "stations": np.array([[1000.0, -2000.0], [-3000.0, 500.0]]),
                      "bearings": [(np.array([1000.0, -2000.0]), np.array([0.0, 3000.0]))]}}
    geojson = write_geojson(folder / "areas.geojson", panels, frame, LEVELS, title="rings")
    kml = write_kml(folder / "areas.kml", panels, frame, LEVELS, title="rings", marks=marks)
    return geojson, kml


def geojson_areas(path: Path) -> dict:
    """``{(layer, t, level): [polygon, ...]}``, each polygon a list of rings of (lon, lat)."""
    found = {}
    for feature in json.loads(path.read_text())["features"]:
        props = feature["properties"]
        if feature["geometry"] is not None:
            found[props["layer"], float(props["t_s"]), float(props["level"])] = feature["geometry"]["coordinates"]
    return found


def kml_areas(path: Path) -> dict:
    """The same from the KML, by a plain parse of its Placemark, ExtendedData and Polygon elements."""
    found = {}
    for placemark in ET.parse(path).getroot().iter(f"{{{KML_NAMESPACE}}}Placemark"):
        data = {d.get("name"): d.find("k:value", NS).text for d in placemark.iterfind("k:ExtendedData/k:Data", NS)}
        if "level" not in data:
            continue  # a landmark
        polygons = []
        for polygon in placemark.iterfind("k:MultiGeometry/k:Polygon", NS):
            rings = [polygon.find("k:outerBoundaryIs/k:LinearRing/k:coordinates", NS)]
            rings += polygon.findall("k:innerBoundaryIs/k:LinearRing/k:coordinates", NS)
            polygons.append([[[float(v) for v in pair.split(",")] for pair in ring.text.split()] for ring in rings])
        found[data["layer"], float(data["t_s"]), float(data["level"])] = polygons
    return found


def assert_same_areas(kml: dict, geojson: dict) -> None:
    assert kml.keys() == geojson.keys() and kml
    for key, polygons in geojson.items():
        assert len(kml[key]) == len(polygons), key
        for got, expected in zip(kml[key], polygons):
            assert len(got) == len(expected)
            for ring, ring0 in zip(got, expected):
                np.testing.assert_allclose(np.asarray(ring), np.asarray(ring0), rtol=0, atol=DEGREES)


def crosses_antimeridian(areas: dict) -> bool:
    """Whether some area has parts on both sides of the antimeridian (cut there)."""
    for polygons in areas.values():
        lons = [p[0][0][0] for p in polygons]
        if any(v > 170.0 for v in lons) and any(v < -170.0 for v in lons):
            return True
    return False


@hypothesis.seed(2207)
@settings(max_examples=8, deadline=None, database=None)
@hypothesis.given(lat=st.floats(-80.0, 80.0),
                  lon=st.one_of(st.floats(-180.0, 180.0), st.floats(179.95, 180.0), st.floats(-180.0, -179.95)),
                  seed=st.integers(0, 1000))
def test_kml_polygons_are_the_geojsons_anywhere_on_the_globe(lat, lon, seed):
    with tempfile.TemporaryDirectory() as tmp:
        geojson, kml = write_both(Path(tmp), GeoFrame(lat, lon, time="2026-11-24T06:00:00Z"), seed)
        assert_same_areas(kml_areas(kml), geojson_areas(geojson))


def ogr_features(listing: str) -> list[tuple[dict, dict | None]]:
    """The features of ``ogrinfo -al`` output: their fields (``  NAME (TYPE) = VALUE``) and their
    geometry (the WKT line, as GeoJSON-like coordinates through shapely)."""
    features = []
    for block in listing.split("OGRFeature(")[1:]:
        props, geometry = {}, None
        for line in block.splitlines()[1:]:
            text = line.strip()
            if " = " in text and " (" in text.split(" = ", 1)[0]:
                key, value = text.split(" = ", 1)
                props[key.rsplit(" (", 1)[0]] = value
            elif text.split(" ", 1)[0] in ("POINT", "LINESTRING", "POLYGON", "MULTIPOLYGON"):
                geometry = shapely.geometry.mapping(shapely.wkt.loads(text))
        features.append((props, geometry))
    return features


#: Origins whose areas cross the antimeridian, lie by a pole, or neither.
ORIGINS = [(-17.0, 179.99), (65.0, -179.99), (60.45, 4.6), (-84.5, 30.0)]


@pytest.mark.parametrize("lat, lon", ORIGINS)
def test_kml_polygons_across_the_antimeridian_and_by_a_pole_are_the_geojsons(tmp_path, lat, lon):
    geojson, kml = write_both(tmp_path, GeoFrame(lat, lon), 3)
    expected = geojson_areas(geojson)
    assert_same_areas(kml_areas(kml), expected)
    assert crosses_antimeridian(expected) == (abs(lon) > 179.0)


@needs_gdal
@pytest.mark.parametrize("lat, lon", ORIGINS)
def test_gdal_reads_the_kml_as_the_geojson(tmp_path, lat, lon):
    """GDAL's KML reader (ogr2ogr, LIBKML driver: a layer per folder) finds every placemark and
    the polygons of the GeoJSON, to 1e-7 degrees; an area across the antimeridian included."""
    geojson, kml = write_both(tmp_path, GeoFrame(lat, lon, time="2026-11-24T06:00:00Z"), 3)
    read, marks = {}, []
    for props, geometry in ogr_features(gdal("ogrinfo", "-ro", "-al", "-q", kml).stdout):
        if "level" in props:
            polygons = geometry["coordinates"] if geometry["type"] == "MultiPolygon" else [geometry["coordinates"]]
            read[props["layer"], float(props["t_s"]), float(props["level"])] = polygons
        elif geometry is not None and geometry["type"] == "Point":
            marks.append((props["Name"], list(geometry["coordinates"])))
    expected = geojson_areas(geojson)
    assert_same_areas(read, expected)
    if lon > 179.0 or lon < -179.0:
        assert crosses_antimeridian(expected)
    assert ("last fix", [pytest.approx(lon, abs=DEGREES), pytest.approx(lat, abs=DEGREES)]) in marks  # 7 decimals
    assert sorted(name for name, _ in marks) == ["last fix", "station 1", "station 2"]


def test_each_time_is_stamped_and_each_level_styled(tmp_path):
    _, kml = write_both(tmp_path, GeoFrame(60.45, 4.6, time="2026-11-24T06:00:00Z"), 1)
    root = ET.parse(kml).getroot()
    assert root.tag == f"{{{KML_NAMESPACE}}}kml"
    styles = {s.get("id") for s in root.iterfind("k:Document/k:Style", NS)}
    assert {"p50", "p90", "p99", "fix", "station"} <= styles
    stamps = [f.find("k:TimeStamp/k:when", NS).text for f in root.iterfind("k:Document/k:Folder/k:Folder", NS)
              if f.find("k:TimeStamp", NS) is not None]
    assert stamps == ["2026-11-24T06:01:00Z", "2026-11-24T06:02:00Z"]
    urls = [p.find("k:styleUrl", NS).text for p in root.iter(f"{{{KML_NAMESPACE}}}Placemark")
            if p.find("k:MultiGeometry", NS) is not None]
    assert sorted(set(urls)) == ["#p50", "#p90", "#p99"]


def test_kml_needs_a_geographic_frame_and_writes_nothing_without(tmp_path):
    local = Raster(values=np.ones(GRID.shape), grid=GRID, mass=1.0, provenance={})
    with pytest.raises(BananagridError, match=r"^KML search areas are in longitude and latitude: the maps need a "
                                              r"geographic frame \(a scene's \[geo\] table, or frame=GeoFrame\(...\)\)$"):
        write_kml(tmp_path / "x.kml", [("a", 0.0, local)])
    assert not os.listdir(tmp_path)


def test_a_failure_while_writing_leaves_nothing_behind(tmp_path, monkeypatch):
    def failing(self, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ET.ElementTree, "write", failing)
    with pytest.raises(BananagridError, match=r"^.*x\.kml: cannot write the KML file \(No space left on device\)$"):
        write_kml(tmp_path / "x.kml", [("a", 0.0, ring_map(1))], GeoFrame(60.0, 5.0), LEVELS)
    assert not os.listdir(tmp_path)


def test_run_refuses_kml_of_a_local_scene_before_computing(tmp_path, capsys):
    """A scene without [geo] asking for --kml: one line on stderr, exit 2, nothing written."""
    out = tmp_path / "out"
    assert cli.main(["run", "--example", "figure1", "--out", str(out), "--kml", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.endswith(
        "figure1.toml: --kml: search areas are written in latitude and longitude, and this scene has no [geo] "
        "table (geo.origin_latlon); --netcdf and --geotiff work in local metres")
    assert not out.exists() or not any(out.iterdir())


def test_a_level_the_grid_does_not_reach_is_said_not_drawn(tmp_path):
    """A map holding 0.6 of the probability (the rest off the grid): its 50 % area is drawn,
    its 90 % area is not, and the time's folder says so (as the GeoJSON's null geometry does)."""
    partial = ring_map(4)
    partial = Raster(values=0.6 * partial.values, grid=GRID, mass=0.6, provenance={"model": "test"})
    path = write_kml(tmp_path / "partial.kml", [("ring", 60.0, partial)], GeoFrame(60.45, 4.6), (0.5, 0.9))
    root = ET.parse(path).getroot()
    names = [p.find("k:name", NS).text for p in root.iter(f"{{{KML_NAMESPACE}}}Placemark")]
    assert names == ["50 %"]
    (folder,) = root.iterfind("k:Document/k:Folder/k:Folder", NS)
    assert folder.find("k:description", NS).text == "The grid holds less than 0.9: no area at that level."
