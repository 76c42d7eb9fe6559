"""``[[evidence]]`` in scenes: each map's posterior is ``bg.posterior`` of the layer's model on the
scene's grid with the evidence that began by its time; the recording, the printed summary,
``inspect`` (text and JSON), the .npz, NetCDF, GeoTIFFs and the evidence's GeoJSON carry it, all
or nothing with the run's other files; bad keys are one line naming the key, exit 2 from the CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from datetime import datetime, timedelta, timezone

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.cli import main
from bananagrid.recording.inspect import inspect_recording
from bananagrid.scenes.load import parse_scene
from bananagrid.scenes.run import plan_outputs, run_scene

#: A vessel 10 and 15 minutes after its fix west of Bergen (as scenes/geo_ship.toml) and a still
#: target, on 150 m cells: 4,800 cells, so that the run takes about a second.
SCENE = """
[scene]
name = "ev_ship"
title = "Vessel west of Bergen: after the searches"
times = [600.0, 900.0]

[geo]
origin_latlon = [60.45, 4.60]
time = "2026-11-24T05:40:00Z"

[grid]
x = [-7000.0, 5000.0]
y = [-7500.0, 1500.0]
step = 150.0

[layers.cat]
model = "cat"
v0 = 5.0
sigma_a = 0.002
sigma_omega_deg = 0.05
heading_deg = 200.0

[layers.still]
model = "butterly"
mean = [0.0, -2000.0]
sigma_x = 800.0
sigma_y = 800.0
speeds = [0.0]
"""
#: At the last map's time (900 s, 05:55 UTC): an area searched (degrees, its time in UTC), a
#: patrol's track flown up to then (degrees, one time in s and one in UTC), land from a GeoJSON
#: file, and a position report (metres).
EVIDENCE = """
[[evidence]]
kind = "area_search"
name = "box"
polygon_latlon = [[60.40, 4.56], [60.40, 4.60], [60.42, 4.60], [60.42, 4.56]]
t = "2026-11-24T05:55:00Z"
pod = 0.8

[[evidence]]
kind = "track_search"
name = "patrol"
track_latlon = [[60.39, 4.50, 800.0], [60.41, 4.66, "2026-11-24T05:55:00Z"]]
sweep_width = 600.0

[[evidence]]
kind = "exclusion"
name = "land"
file = "land.geojson"

[[evidence]]
kind = "position_report"
position = [-1500.0, -4000.0]
t = 900.0
sigma = 1500.0
"""
LAND = {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [
    [[4.50, 60.38], [4.55, 60.38], [4.55, 60.41], [4.50, 60.41], [4.50, 60.38]]]}}


def _write(directory, text=SCENE + EVIDENCE, name="ev_ship.toml"):
    (directory / "land.geojson").write_text(json.dumps(LAND))
    path = directory / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    """The scene run once through the CLI with every file: its directory and its scene."""
    where = tmp_path_factory.mktemp("evidence")
    path = _write(where)
    out = where / "out"
    assert main(["run", str(path), "--out", str(out), "--npz", "--netcdf", "--geotiff", "--geojson", "--quiet"]) == 0
    return out, bg.load_scene(path)


@pytest.fixture(scope="module")
def direct(ran):
    """The posteriors by the Python API, the evidence built here (not by the scene's parser)."""
    _, scene = ran
    frame = scene.geo
    box = bg.AreaSearch([[4.56, 60.40], [4.60, 60.40], [4.60, 60.42], [4.56, 60.42]], t=900.0, pod=0.8, frame=frame)
    x, y = frame.local(np.array([60.39, 60.41]), np.array([4.50, 4.66]))
    patrol = bg.TrackSearch(np.column_stack((x, y, [800.0, 900.0])), sweep_width=600.0)
    land = bg.Exclusion(LAND, frame=frame)
    report = bg.PositionReport((-1500.0, -4000.0), t=900.0, sigma=1500.0)
    out = {}
    for layer in scene.layers:
        out[layer.name, 600.0] = bg.posterior(layer.model(600.0), scene.grid, [land])  # the rest began later
        out[layer.name, 900.0] = bg.posterior(layer.model(900.0), scene.grid, [box, patrol, land, report])
    return out


def test_the_files_hold_the_posteriors_bg_posterior_gives(ran, direct):
    """.npz, NetCDF and GeoTIFFs: the posterior and POD maps, POS and each search's POS, equal
    to ``bg.posterior`` called directly."""
    import rasterio
    import xarray as xr

    out, _ = ran
    # 1e-12: the same kernels and rule on the same grid; only the threads' order of summing may differ
    tol = 1e-12
    with np.load(out / "ev_ship.npz", allow_pickle=False) as arrays:
        provenance = json.loads(str(arrays["provenance"]))["arrays"]
        for (layer, t), post in direct.items():
            key = f"{layer}__t{t:g}"
            np.testing.assert_allclose(arrays[f"{key}__posterior"], post.values, rtol=0, atol=tol)
            np.testing.assert_allclose(arrays[f"{key}__pod"], post.pod, rtol=0, atol=tol)
            assert provenance[f"{key}__posterior"]["pos"] == pytest.approx(post.pos, abs=tol)
    with xr.open_dataset(out / "ev_ship.nc") as dataset:
        assert list(dataset["search"].values) == ["box", "patrol"]
        for layer in ("cat", "still"):
            assert dataset[f"{layer}_posterior"].dims == dataset[layer].dims
            assert dataset[f"{layer}_posterior"].attrs["units"] == "1"
            for k, t in enumerate((600.0, 900.0)):
                post = direct[layer, t]
                np.testing.assert_allclose(dataset[f"{layer}_posterior"].values[k], post.values, rtol=0, atol=tol)
                np.testing.assert_allclose(dataset[f"{layer}_pod"].values[k], post.pod, rtol=0, atol=tol)
                assert float(dataset[f"{layer}_pos"].values[k]) == pytest.approx(post.pos, abs=tol)
            # each search's own POS; none before it began
            assert np.all(np.isnan(dataset[f"{layer}_search_pos"].values[0]))
            np.testing.assert_allclose(dataset[f"{layer}_search_pos"].values[1], direct[layer, 900.0].search_pos,
                                       rtol=0, atol=tol)
    for name, field in (("posterior", "values"), ("pod", "pod")):
        with rasterio.open(out / f"ev_ship-{name}.tif") as tif:
            assert tif.count == 4 and tif.dtypes[0] == "float64"
            for band, key in enumerate([("cat", 600.0), ("still", 600.0), ("cat", 900.0), ("still", 900.0)], start=1):
                post = direct[key]
                np.testing.assert_array_equal(tif.read(band)[::-1], getattr(post, field))  # float64: the bits
                tags = tif.tags(band)
                assert float(tags["pos"]) == pytest.approx(post.pos, abs=tol)
            assert json.loads(tif.tags(3)["search_pos"]) == pytest.approx(
                dict(zip(["box", "patrol"], direct["cat", 900.0].search_pos)), abs=tol)


def test_the_recording_verifies_and_the_evidence_geojson(ran, direct):
    out, _ = ran
    verify = subprocess.run([str(Path(sys.executable).parent / "rerun"), "rrd", "verify", str(out / "ev_ship.rrd")],
                            capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    collection = json.loads((out / "ev_ship-evidence.geojson").read_text())
    features = collection["features"]
    evidence = {f["properties"]["evidence"]: f for f in features if "evidence" in f["properties"]}
    assert {name: f["geometry"]["type"] for name, f in evidence.items()} == {
        "box": "MultiPolygon", "patrol": "MultiLineString", "land": "MultiPolygon", "E4": "MultiPoint"}
    assert evidence["box"]["properties"]["time_utc"] == ["2026-11-24T05:55:00Z"] * 2
    assert evidence["patrol"]["properties"]["t_s"] == [800.0, 900.0]
    pos = {(p["layer"], p["t_s"]): p["pos"] for p in evidence["box"]["properties"]["pos"]}
    assert pos["cat", 900.0] == pytest.approx(direct["cat", 900.0].search_pos[0], abs=1e-12)
    # the box's corners in WGS84, as written (to the 1e-7 degrees of the file)
    ring = np.array(evidence["box"]["geometry"]["coordinates"][0][0])
    assert {(round(a, 6), round(b, 6)) for a, b in ring} == {(4.56, 60.40), (4.60, 60.40), (4.60, 60.42), (4.56, 60.42)}
    areas = [f for f in features if f["properties"].get("map") == "posterior"]
    assert sorted({(f["properties"]["layer"], f["properties"]["t_s"]) for f in areas}) == sorted(direct)
    # each area holds its level of the posterior to the grid's resolution (bananagrid.geo.areas)
    for f in areas:
        p = f["properties"]
        assert p["reached"] and abs(p["probability"] - p["level"]) <= p["resolution"]


def test_the_recording_inspect_and_the_summary_carry_the_posteriors(ran, direct, capsys):
    out, scene = ran
    info = inspect_recording(out / "ev_ship.rrd")
    entities = info["entities"]
    ny, nx = scene.grid.shape
    for layer in ("cat", "still"):
        for image in ("prior", "posterior", "pod"):
            assert entities[f"/evidence/{layer}/{image}"]["image_shapes"] == [(ny, nx)]
        # POS over time: one scalar per map time, 0 before any search began
        pos = [row["values"] for row in entities[f"/evidence/{layer}/pos"]["scalars"]]
        assert pos == pytest.approx([0.0, direct[layer, 900.0].pos], abs=1e-12)
    for name in ("box", "patrol", "land", "E4"):
        assert f"/evidence/marks/{name}" in entities
    assert entities["/evidence/marks/land"]["static_rows"] == 1  # land holds at every time
    assert main(["inspect", "--json", str(out / "ev_ship.rrd")]) == 0
    (report,) = json.loads(capsys.readouterr().out)
    by_key = {(item["layer"], item["t"]): item for item in report["evidence"]}
    assert sorted(by_key) == sorted(direct)
    for key, post in direct.items():
        item = by_key[key]
        assert item["pos"] == pytest.approx(post.pos, abs=1e-12)
        assert item["normaliser"] == pytest.approx(post.normaliser, rel=1e-12)
    assert by_key["cat", 900.0]["evidence"] == ["box", "patrol", "land", "E4"]
    assert by_key["cat", 900.0]["search_pos"] == pytest.approx(dict(zip(["box", "patrol"],
                                                                        direct["cat", 900.0].search_pos)), abs=1e-12)
    assert by_key["cat", 600.0]["search_pos"] == {} and by_key["cat", 600.0]["evidence"] == ["land"]
    assert main(["inspect", str(out / "ev_ship.rrd")]) == 0
    text = capsys.readouterr().out
    assert "after the evidence (the recorded posteriors)" in text
    assert f"POS                    {direct['cat', 900.0].pos:.6f}" in text


def test_the_printed_summary_and_the_files_named(tmp_path, capsys):
    path = _write(tmp_path)
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--geojson", "--geotiff"]) == 0
    captured = capsys.readouterr()
    assert "ev_ship: posterior of cat at t = 900 s after box, patrol, land, E4: POS " in captured.out
    assert "ev_ship: posterior of cat at t = 600 s after land: POS 0.0000" in captured.out
    for name in ("ev_ship-evidence.geojson", "ev_ship-posterior.tif", "ev_ship-pod.tif"):
        assert f"wrote {tmp_path / 'o' / name}" in captured.out


def test_a_plan_after_evidence_searches_the_posterior(tmp_path, direct):
    """A scene's [plan] after evidence allocates its effort on the layer's posterior at the
    plan's time: where the target is given that nothing was found so far."""
    _write(tmp_path, SCENE + EVIDENCE + "[plan]\neffort_km2 = 8.0\nsweep_width = 500.0\nbands = 2\n")
    rows = run_scene(bg.load_scene(tmp_path / "ev_ship.toml"), tmp_path)
    (row,) = [r for r in rows if "plan" in r]
    want = bg.allocate(direct["cat", 900.0], 8.0e6)
    # 1e-12: the same solver on the same posterior (equal to the direct call's to 1e-12, above)
    assert row["plan"]["pos"] == pytest.approx(want.pos, abs=1e-12)
    assert row["plan"]["map_mass"] == pytest.approx(1.0, abs=1e-12)  # the posterior, normalised over the grid
    assert row["plan"]["bands_pos"] == pytest.approx(bg.search_regions(want, 2, sweep_width=500.0).pos, abs=1e-12)


def test_the_evidence_files_are_planned_with_the_run(tmp_path):
    """Checked before any computing like the run's other files: a directory where the evidence's
    GeoJSON would go is refused, and nothing is written."""
    _write(tmp_path)
    scene = bg.load_scene(tmp_path / "ev_ship.toml")
    out = tmp_path / "o"
    out.mkdir()
    assert out / "ev_ship-evidence.geojson" in plan_outputs(scene, out, geojson=True)._targets
    (out / "ev_ship-evidence.geojson").mkdir()
    with pytest.raises(bg.BananagridError, match="ev_ship-evidence.geojson"):
        run_scene(scene, out, geojson=True)
    assert sorted(p.name for p in out.iterdir()) == ["ev_ship-evidence.geojson"]


def test_a_bearing_report_in_a_geographic_scene_takes_true_bearings():
    """Bearings given true are turned into grid bearings at each station, as a bearing fix
    layer's are: the scene's report has the likelihood of the fix built with grid bearings."""
    text = SCENE + """
[[evidence]]
kind = "bearing_report"
sensors_latlon = [[60.50, 4.40], [60.48, 4.80]]
bearings_deg = [150.0, 220.0]
sigmas_deg = [2.0, 3.0]
t = 900.0
"""
    scene = parse_scene(text, source="s")
    (spec,) = scene.evidence
    frame = scene.geo
    x, y = frame.local(np.array([60.50, 60.48]), np.array([4.40, 4.80]))
    sensors = np.column_stack((x, y))
    grid_bearings = [frame.grid_bearing(math.radians(b), *s) for b, s in zip((150.0, 220.0), sensors)]
    fix = bg.BearingFix(sensors=sensors, bearings=grid_bearings, sigmas=[math.radians(2.0), math.radians(3.0)])
    want = bg.BearingReport(fix, t=900.0)
    points = np.array([[-1500.0, -4000.0], [0.0, -2000.0], [3000.0, -6000.0]])
    np.testing.assert_allclose(spec.evidence.likelihood(points[:, 0], points[:, 1]),
                               want.likelihood(points[:, 0], points[:, 1]), rtol=1e-12, atol=0)
    # the grid bearings differ from the true ones (the meridians converge): the test can fail
    assert abs(grid_bearings[0] - math.radians(150.0)) > 1e-4


#: One layer, without times (its own t): the timeline ends at 10 s.
PLAIN = """
[scene]
name = "e"
[grid]
x = [-3000.0, 3000.0]
y = [-200.0, 3400.0]
step = 200.0
[layers.cat]
model = "cat"
v0 = 280.0
t = 10.0
sigma_a = 1.6666667
sigma_omega_deg = 3.3333
"""

BAD = [
    ('kind = "area"', 'evidence[0].kind = "area": must be one of "area_search", "track_search"'),
    ("t = 5.0", "evidence[0].kind missing: must be one of"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\npod = 0.5', "evidence[0].t: missing"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 5.0', "evidence[0].pod: missing"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 5.0\npod = 1.5',
     "evidence[0].pod = 1.5: must be in [0, 1]"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 5.0\npod = -0.1',
     "evidence[0].pod = -0.1: must be in [0, 1]"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 5.0\ncoverage = -1',
     "evidence[0].coverage = -1.0: must be >= 0"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 5.0\npod = 0.5\ncoverage = 1',
     "evidence[0]: give one of pod, coverage, not several (pod = 0.5, coverage = 1)"),
    ('kind = "area_search"\npolygon = [[0, 0], [10, 10], [10, 0], [0, 10]]\nt = 5.0\npod = 0.5',
     "evidence[0].polygon: edges 0-1 and 2-3 cross"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0]]\nt = 5.0\npod = 0.5',
     "evidence[0].polygon: 2 distinct vertices given, a polygon needs at least 3"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 11.0\npod = 0.5',
     "evidence[0].t = 11.0: ends at 11 s, after the scene's last time 10 s"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = [2.0, 12.0]\npod = 0.5',
     "evidence[0].t = [2.0, 12.0]: ends at 12 s, after the scene's last time 10 s"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = [8.0, 2.0]\npod = 0.5',
     "evidence[0].t = [8.0, 2.0]: the search ends before it starts"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = -1.0\npod = 0.5',
     "evidence[0].t = -1.0: must be finite and >= 0"),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = "2026-11-24T05:55:00Z"\npod = 0.5',
     'evidence[0].t = "2026-11-24T05:55:00Z": a UTC time needs a [geo] table with a time'),
    ('kind = "area_search"\npolygon_latlon = [[60, 4], [60, 5], [61, 4]]\nt = 5.0\npod = 0.5',
     "evidence[0].polygon_latlon = [[60, 4], [60, 5], [61, 4]]: positions in latitude and longitude need a [geo]"),
    ('kind = "area_search"\nfile = "nowhere.geojson"\nt = 5.0\npod = 0.5',
     'evidence[0].file = "nowhere.geojson": no such file'),
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 5.0\npod = 0.5\nsweep_width = 3',
     'evidence[0].sweep_width: unknown key'),
    ('kind = "track_search"\ntrack = [[0, 0, 1.0], [100, 0, 1.0]]\nsweep_width = 50',
     "evidence[0].track.times[1] = 1.0"),
    ('kind = "track_search"\ntrack = [[0, 0, 1.0], [100, 0, 2.0]]\nsweep_width = 0',
     "evidence[0].sweep_width = 0"),
    ('kind = "track_search"\ntrack = [[0, 0, 1.0], [100, 0, 2.0]]\nsweep_width = -5.0',
     "evidence[0].sweep_width = -5.0"),
    ('kind = "track_search"\ntrack = [[0, 0, 1.0], [100, 0, 2.0]]', "evidence[0].sweep_width: missing"),
    ('kind = "track_search"\ntrack = [[0, 0, 1.0], [100, 0, 2.0]]\nsweep_width = 50\nlaw = "linear"',
     'evidence[0].law = "linear": must be one of "inverse_cube", "definite"'),
    ('kind = "track_search"\ntrack = [[0, 0, 1.0]]\nsweep_width = 50', "evidence[0].track = [[0, 0, 1.0]]: expected at least 2"),
    ('kind = "track_search"\ntrack = [[0, 0], [1, 1]]\nsweep_width = 50', "evidence[0].track[0] = [0, 0]: expected [x, y, t]"),
    ('kind = "track_search"\ntrack = [[0, 0, 1.0], [100, 0, 20.0]]\nsweep_width = 50',
     "evidence[0].track = [[0, 0, 1.0], [100, 0, 20.0]]: ends at 20 s, after the scene's last time 10 s"),
    ('kind = "track_search"\nfile = "t.gpx"\nsweep_width = 50', "evidence[0].file = \"t.gpx\": a track file's positions"),
    ('kind = "position_report"\nposition = [0, 0]\nt = 5.0\nsigma = 0', "evidence[0].sigma = 0"),
    ('kind = "position_report"\nposition = [0, 0]\nt = 5.0', "evidence[0].sigma: missing"),
    ('kind = "position_report"\nposition = [0, 0]\nt = [1.0, 2.0]\nsigma = 5',
     "evidence[0].t = [1.0, 2.0]: expected one time (only an area search takes [t0, t1])"),
    ('kind = "position_report"\nposition = [0, 0]\nt = 5.0\ncov = [[1, 2], [2, 1]]', "evidence[0].cov"),
    ('kind = "bearing_report"\nsensors = [[0, 0], [1000, 0]]\nbearings_deg = [10, 20]\nsigmas_deg = [1]\nt = 5.0',
     "evidence[0].sensors, bearings_deg, sigmas_deg: lengths 2, 2, 1 must match"),
    ('kind = "bearing_report"\nsensors = [[0, 0], [1000, 0]]\nbearings_deg = [10, 20]\nt = 5.0',
     "evidence[0].sigmas: missing"),
    ('kind = "exclusion"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = 5.0', "evidence[0].t: unknown key"),
    ('kind = "exclusion"\nname = "a b"\npolygon = [[0, 0], [1, 0], [0, 1]]',
     'evidence[0].name = "a b": expected a name of letters, digits, _ and -'),
]


@pytest.mark.parametrize("body, message", BAD, ids=[b.replace("\n", " ")[:60] for b, _ in BAD])
def test_bad_evidence_keys_are_one_line(body, message):
    with pytest.raises(bg.BananagridError) as raised:
        parse_scene(PLAIN + "[[evidence]]\n" + body + "\n", source="s.toml")
    text = str(raised.value)
    assert "\n" not in text and text.startswith("s.toml: ") and message in text


@pytest.mark.parametrize("body, message", [
    ('kind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\nt = [500.0, 700.0]\npod = 0.5',
     "evidence[0].t = [500.0, 700.0]: spans the map time 600 s of the timeline"),
    ('kind = "track_search"\ntrack = [[0, 0, 550.0], [100, 0, 650.0], [200, 0, 660.0]]\nsweep_width = 50',
     "evidence[0].track = [[0, 0, 550.0], [100, 0, 650.0], [200, 0, 660.0]]: spans the map time 600 s"),
])
def test_a_search_across_a_map_time_is_refused(body, message):
    """A map takes a search whole: one that goes on past a map's time is split by the planner."""
    with pytest.raises(bg.BananagridError) as raised:
        parse_scene(SCENE + "[[evidence]]\n" + body + "\n", source="s")
    assert message in str(raised.value) and "\n" not in str(raised.value)
    # ending at the map's time, or starting at it, is taken
    parse_scene(SCENE + '[[evidence]]\nkind = "area_search"\npolygon = [[0, 0], [1, 0], [0, 1]]\npod = 0.5\n'
                "t = [500.0, 600.0]\n", source="s")


def test_two_pieces_of_evidence_of_one_name_are_refused():
    body = '[[evidence]]\nkind = "exclusion"\nname = "a"\npolygon = [[0, 0], [1, 0], [0, 1]]\n'
    with pytest.raises(bg.BananagridError, match=r'evidence\[1\].name = "a": another \[\[evidence\]\] has this name'):
        parse_scene(PLAIN + body + body, source="s")


@pytest.mark.parametrize("body, message", [BAD[4], BAD[10], BAD[19]])
def test_bad_evidence_exits_2_from_the_cli(tmp_path, capsys, body, message):
    scene = tmp_path / "s.toml"
    scene.write_text(PLAIN + "[[evidence]]\n" + body + "\n")
    assert main(["run", str(scene), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert not list(tmp_path.glob("*.rrd"))


def test_earlier_evidence_the_model_cannot_carry_is_one_line_and_leaves_nothing(tmp_path, capsys):
    """A polar banana has no path per parameter: evidence before its map's time is refused by
    ``bg.posterior`` in one line that names the scene's evidence, the layer and the time."""
    text = PLAIN.replace('model = "cat"', 'model = "polar"\nvariant = "improved"') + (
        '[[evidence]]\nkind = "exclusion"\npolygon = [[0, 0], [1, 0], [0, 1]]\n'
        '[[evidence]]\nkind = "area_search"\npolygon = [[0, 0], [100, 0], [0, 100]]\nt = 4.0\npod = 0.5\n')
    scene = tmp_path / "s.toml"
    scene.write_text(text)
    assert main(["run", str(scene), "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    (error,) = [line for line in err.splitlines() if line.startswith("bananagrid: error")]
    assert "Traceback" not in err and err.endswith(error + "\n")
    assert "layers.cat at t = 10 s: evidence[1].t = 4.0: earlier than the map's time" in error and "bg.CAT" in error
    assert not list(tmp_path.glob("*.rrd"))


@seed(20261127)
@settings(max_examples=60, deadline=None, database=None)
@given(t=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 100)),
       t1=st.one_of(st.none(), st.floats(min_value=-5.0, max_value=20.0)), utc=st.booleans())
def test_every_time_is_on_the_timeline_or_refused_naming_the_key(t, t1, utc):
    """Any time (and interval) of an area search, in s or as UTC in a geographic scene: taken in
    s since the fix when it lies in [0, the last time], else one line naming ``evidence[0].t``."""
    last = 900.0
    fix = datetime(2026, 11, 24, 5, 40, tzinfo=timezone.utc)  # the scene's [geo] time

    def written(value) -> tuple[str, float]:
        """The value as the scene writes it, and the seconds it means (a UTC text to its microsecond)."""
        if utc and isinstance(value, float) and math.isfinite(value) and abs(value) < 1e7:
            text = (fix + timedelta(seconds=value)).isoformat()
            return f'"{text}"', (datetime.fromisoformat(text) - fix).total_seconds()
        if isinstance(value, int):
            return repr(value), float(value)
        return {"nan": "nan", "inf": "inf", "-inf": "-inf"}.get(repr(value), repr(value)), value

    (a, s0), (b, s1) = written(t), written(t if t1 is None else t1)
    value = a if t1 is None else f"[{a}, {b}]"
    text = SCENE + ('[[evidence]]\nkind = "area_search"\npolygon = [[0, 0], [100, 0], [0, 100]]\npod = 0.5\n'
                    f"t = {value}\n")
    ok = (all(math.isfinite(v) and v >= 0.0 for v in (s0, s1)) and s0 <= s1 <= last
          and not any(s0 < t_map < s1 for t_map in (600.0, 900.0)))
    try:
        scene = parse_scene(text, source="s")
    except bg.BananagridError as exc:
        assert str(exc).startswith("s: evidence[0].t") and "\n" not in str(exc)
        assert not ok
        return
    assert ok and scene.evidence[0].span == (s0, s1)


# --- the bundled story scenes: earlier evidence carried through the model's paths ----------------

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def test_fast_contact_carries_the_box_and_the_patrol_as_bg_posterior_does(tmp_path):
    """scenes/fast_contact.toml at 400 m cells: each map is ``bg.posterior`` with the evidence
    built here (the box at 5 min carried to 10 min, the patrol's track), and the box's POS is the
    same whichever map it is carried to: a property of the paths, not of the map's time."""
    scene = bg.load_scene(SCENES / "fast_contact.toml").with_step(400.0)
    rows = run_scene(scene, tmp_path, npz=True)
    model = bg.CAT(v0=20.0, t=600.0, sigma_a=0.005, sigma_omega=math.radians(0.05), pose=bg.Pose(origin=(0.0, 0.0), heading=math.radians(45.0)))
    box = bg.AreaSearch([[3300.0, 4500.0], [4500.0, 3300.0], [5500.0, 4300.0], [4300.0, 5500.0]], t=300.0, pod=0.7)
    patrol = bg.TrackSearch([[11000.0, 3000.0, 330.0], [3000.0, 11000.0, 570.0]], sweep_width=1500.0)
    late = bg.posterior(model, scene.grid, [box, patrol])
    early = bg.posterior(bg.CAT(v0=20.0, t=300.0, sigma_a=0.005, sigma_omega=math.radians(0.05),
                                pose=bg.Pose(origin=(0.0, 0.0), heading=math.radians(45.0))), scene.grid, [box])
    with np.load(tmp_path / "fast_contact.npz", allow_pickle=False) as arrays:
        # 1e-12: the same kernels on the same grid; only the threads' order of summing may differ
        np.testing.assert_allclose(arrays["contact__t600__posterior"], late.values, rtol=0, atol=1e-12)
        np.testing.assert_allclose(arrays["contact__t300__posterior"], early.values, rtol=0, atol=1e-12)
    by_t = {row["t"]: row["evidence"] for row in rows}
    assert by_t[600.0]["search_pos"] == pytest.approx(list(late.search_pos), abs=1e-12)
    assert by_t[600.0]["pos"] == pytest.approx(late.pos, abs=1e-12)
    assert math.isnan(by_t[300.0]["search_pos"][1])  # the patrol began after 5 min
    # the box's POS at 5 min (its own time: prior x likelihood) and carried to 10 min: two
    # discretisations of one probability, measured apart by 2.8e-4 at 400 m cells, 1.1e-4 at
    # 200 m and 4.4e-5 at 100 m (both tend to 0.49512)
    assert abs(by_t[300.0]["search_pos"][0] - by_t[600.0]["search_pos"][0]) < 1e-3
    # the story: the searches found nothing where the contact most likely was
    assert by_t[600.0]["pos"] > 0.5 and by_t[300.0]["pos"] > 0.4


def test_an_earlier_definite_range_track_is_carried_in_a_scene(tmp_path):
    """fast_contact with the patrol's law definite (detected iff within 750 m): the scene runs,
    and its 10 min map is ``bg.posterior`` with that track carried along the CAT's paths."""
    text = (SCENES / "fast_contact.toml").read_text().replace("sweep_width = 1500.0",
                                                              'sweep_width = 1500.0\nlaw = "definite"')
    assert 'law = "definite"' in text
    (tmp_path / "fast_contact.toml").write_text(text)
    scene = bg.load_scene(tmp_path / "fast_contact.toml").with_step(400.0)
    rows = run_scene(scene, tmp_path, npz=True)
    model = bg.CAT(v0=20.0, t=600.0, sigma_a=0.005, sigma_omega=math.radians(0.05),
                   pose=bg.Pose(origin=(0.0, 0.0), heading=math.radians(45.0)))
    box = bg.AreaSearch([[3300.0, 4500.0], [4500.0, 3300.0], [5500.0, 4300.0], [4300.0, 5500.0]], t=300.0, pod=0.7)
    patrol = bg.TrackSearch([[11000.0, 3000.0, 330.0], [3000.0, 11000.0, 570.0]], sweep_width=1500.0, law="definite")
    late = bg.posterior(model, scene.grid, [box, patrol])
    with np.load(tmp_path / "fast_contact.npz", allow_pickle=False) as arrays:
        # 1e-12: the same kernels on the same grid; only the threads' order of summing may differ
        np.testing.assert_allclose(arrays["contact__t600__posterior"], late.values, rtol=0, atol=1e-12)
    by_t = {row["t"]: row["evidence"] for row in rows}
    assert by_t[600.0]["search_pos"] == pytest.approx(list(late.search_pos), abs=1e-12)
    assert 0.05 < late.search_pos[1] < 0.95  # the patrol's own POS: it meets some of the paths
