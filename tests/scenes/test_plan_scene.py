"""``[plan]`` in scenes: the run's plan is ``bg.allocate`` (and ``search_rectangles``,
``search_regions``) on the layer's cell probabilities, not normalised; the recording, ``inspect``
(text and JSON), the NetCDF variable and the plan's GeoJSON carry it, all or nothing with the
run's other files; bad keys are one line naming the key, exit 2 from the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.cli import main
from bananagrid.geo.dataset import read_maps
from bananagrid.recording.readback import open_recording, recording_rows
from bananagrid.recording.timeline import ELAPSED, UTC, elapsed_nanos, utc_nanos
from bananagrid.recording.inspect import format_inspection, inspect_recording
from bananagrid.recording.readback import read_depth_image
from bananagrid.scenes.load import parse_scene
from bananagrid.scenes.run import plan_outputs, run_scene

#: A vessel 10 and 15 minutes after its fix (as scenes/geo_ship.toml), on 150 m cells: 4,800
#: cells, so that the run takes about a second.
SCENE = """
[scene]
name = "plan_ship"
title = "Vessel west of Bergen: where to look"
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
PLAN = """
[plan]
effort_km2 = 8.0
sweep_width = 500.0
rectangles = 3
bands = 3
"""


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """The scene run once with every map file: its rows, its directory and its scene."""
    out = tmp_path_factory.mktemp("plan")
    scene = parse_scene(SCENE + PLAN, source="plan_ship.toml")
    rows = run_scene(scene, out, netcdf=True, geojson=True)
    return rows, out, scene


@pytest.fixture(scope="module")
def reference(planned):
    """The same plan by the Python API on the same map: what the scene must give."""
    _, _, scene = planned
    model = scene.layers[0].model(900.0)
    cells = bg.rasterise(model, scene.grid, quantity="probability")
    allocation = bg.allocate(cells, 8.0e6)
    return (cells, allocation, bg.search_rectangles(allocation, 3, sweep_width=500.0),
            bg.search_regions(allocation, 3, sweep_width=500.0))


def test_the_scene_plans_what_the_api_plans(planned, reference):
    rows, _, _ = planned
    cells, allocation, rectangles, bands = reference
    (row,) = [r for r in rows if "plan" in r]
    plan = row["plan"]
    assert (row["layer"], row["t"]) == ("cat", 900.0)  # the first layer at the last time, by default
    # 1e-12: the same kernels and the same solver on the same map; only the threads' order of
    # summing may differ
    assert plan["pos"] == pytest.approx(allocation.pos, abs=1e-12)
    assert plan["marginal_gain"] == pytest.approx(allocation.marginal_gain, rel=1e-12)
    assert plan["rectangles_pos"] == pytest.approx(rectangles.pos, abs=1e-12)
    assert plan["bands_pos"] == pytest.approx(bands.pos, abs=1e-12)
    assert plan["effort_m2"] == 8.0e6
    # the map is not normalised: the POS is of the whole target (normalising would move it by
    # the 4.5e-5 the grid misses)
    assert plan["map_mass"] == pytest.approx(cells.mass, abs=1e-12) and plan["map_mass"] < 1.0 - 1e-6
    normalised = bg.allocate(cells.normalise(), 8.0e6).pos
    assert abs(normalised - plan["pos"]) > 1e-7
    # the areas: never better than the ideal (Jensen), never more effort than given
    assert plan["rectangles_pos"] <= plan["pos"] + 1e-12 and plan["bands_pos"] <= plan["pos"] + 1e-12
    assert plan["rectangles_effort_m2"] <= 8.0e6 * (1 + 1e-12)
    assert plan["rectangles_probability"] == pytest.approx([r.probability for r in rectangles.rectangles], abs=1e-12)
    assert plan["bands_track_spacing_m"] == pytest.approx([r.track_spacing for r in bands.regions], rel=1e-12)


def test_the_recording_holds_the_plan(planned, reference):
    _, out, scene = planned
    _, allocation, rectangles, bands = reference
    path = out / "plan_ship.rrd"
    info = inspect_recording(path)
    entities = info["entities"]
    ny, nx = scene.grid.shape
    for image in ("/plan/coverage", "/plan/probability"):
        assert entities[image]["image_shapes"] == [(ny, nx)]
    assert "Image" in entities["/plan/overlay"]["archetypes"]
    # the coverage as recorded (float32) is the allocation's
    recorded = read_depth_image(path, "plan/coverage", 900.0)
    np.testing.assert_allclose(recorded, allocation.effort.values.astype(np.float32), rtol=0, atol=0)
    assert "LineStrips2D" in entities["/plan/rectangles"]["archetypes"]
    assert "LineStrips2D" in entities["/plan/bands/tracks"]["archetypes"]
    assert "BarChart" in entities["/plan/pos_curve/ideal"]["archetypes"]
    assert "BarChart" in entities["/plan/pos_curve/this_plan"]["archetypes"]
    labels = entities["/plan/rectangles/labels"]
    assert labels["temporal_rows"] == 1 and "Points2D" in labels["archetypes"]
    # inspect: the plan's numbers, for scripts and for people
    plan = info["plan"]
    assert plan["pos"] == pytest.approx(allocation.pos, abs=1e-12)
    assert plan["rectangles"]["pos"] == pytest.approx(rectangles.pos, abs=1e-12)
    assert len(plan["rectangles"]["areas"]) == len(rectangles.rectangles)
    assert [a["pod"] for a in plan["bands"]["areas"]] == pytest.approx([r.pod for r in bands.regions], abs=1e-12)
    text = format_inspection(info)
    assert "where to look next" in text and f"ideal POS              {allocation.pos:.6f}" in text
    assert f"rectangles POS         {rectangles.pos:.6f}" in text


def test_inspect_json_and_the_printed_summary_carry_the_plan(planned, tmp_path, capsys):
    _, out, _ = planned
    assert main(["inspect", "--json", str(out / "plan_ship.rrd")]) == 0
    (info,) = json.loads(capsys.readouterr().out)
    assert set(info["plan"]) >= {"pos", "effort_m2", "marginal_gain", "rectangles", "bands"}
    scene = tmp_path / "plan_ship.toml"
    scene.write_text(SCENE + PLAN.replace("bands = 3", "bands = 0"))
    assert main(["run", str(scene), "--out", str(tmp_path), "--geojson"]) == 0
    captured = capsys.readouterr()
    assert "plan on layer cat at t = 900 s: 8 km^2 of effort (exponential), ideal POS" in captured.out
    assert "3 rectangles: POS" in captured.out and "bands:" not in captured.out
    assert f"wrote {tmp_path / 'plan_ship-plan.geojson'}" in captured.out
    assert "plan cat t=900 s (8 km^2)" in captured.err  # its own progress line


def test_netcdf_carries_the_coverage(planned, reference):
    import xarray as xr
    _, out, _ = planned
    _, allocation, _, _ = reference
    with xr.open_dataset(out / "plan_ship.nc") as dataset:
        coverage = dataset["plan_coverage"]
        assert coverage.dims == ("y", "x")
        assert coverage.attrs["units"] == "m2 m-2"
        assert coverage.attrs["long_name"].startswith("search effort per unit area of the plan")
        assert coverage.attrs["grid_mapping"] == "crs"
        np.testing.assert_array_equal(coverage.values, allocation.effort.values)
    # the file's readers (bananagrid plot, notebooks) still find the layers' maps, and only them
    _, maps = read_maps(out / "plan_ship.nc")
    assert sorted({(m["layer"], m["t"]) for m in maps}) == [("cat", 600.0), ("cat", 900.0), ("still", 600.0),
                                                              ("still", 900.0)]


def test_the_plans_geojson(planned, reference):
    _, out, _ = planned
    _, allocation, rectangles, bands = reference
    collection = json.loads((out / "plan_ship-plan.geojson").read_text())
    assert collection["bananagrid"]["pos"] == pytest.approx(allocation.pos, abs=1e-12)
    features = collection["features"]
    areas = [f for f in features if f["properties"]["kind"] == "area"]
    tracks = [f for f in features if f["properties"]["kind"] == "track"]
    flown = [r for r in bands.regions if r.coverage > 0]
    assert [f["properties"]["plan"] for f in areas] == ["rectangles"] * len(rectangles.rectangles) + ["bands"] * len(flown)
    assert len(tracks) == len(areas)
    # in WGS84 longitude and latitude, about the fix (60.45 N, 4.60 E; the grid spans 12 x 9 km)
    for feature in areas:
        ring = np.array(feature["geometry"]["coordinates"][0] if feature["geometry"]["type"] == "Polygon"
                        else feature["geometry"]["coordinates"][0][0])
        assert np.all(np.abs(ring[:, 0] - 4.60) < 0.15) and np.all(np.abs(ring[:, 1] - 60.45) < 0.1)


def test_the_plans_geojson_is_planned_with_the_run(tmp_path):
    """Checked before any computing like the run's other files: a directory where the plan's
    GeoJSON would go is refused, and nothing is written."""
    scene = parse_scene(SCENE + PLAN, source="plan_ship.toml")
    assert tmp_path / "plan_ship-plan.geojson" in plan_outputs(scene, tmp_path, geojson=True)._targets
    (tmp_path / "plan_ship-plan.geojson").mkdir()
    with pytest.raises(bg.BananagridError, match="plan_ship-plan.geojson"):
        run_scene(scene, tmp_path, geojson=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan_ship-plan.geojson"]


def test_a_plan_on_another_layer_and_time(tmp_path):
    scene = parse_scene(SCENE + PLAN.replace("rectangles = 3", "rectangles = 0").replace("bands = 3", "bands = 0")
                        + 'layer = "still"\nt = 600\nlaw = "definite"\n', source="x")
    rows = run_scene(scene, tmp_path)
    (row,) = [r for r in rows if "plan" in r]
    assert (row["layer"], row["t"]) == ("still", 600.0)
    cells = bg.rasterise(scene.layers[1].model(600.0), scene.grid, quantity="probability")
    # 1e-12: as above
    assert row["plan"]["pos"] == pytest.approx(bg.allocate(cells, 8.0e6, law="definite").pos, abs=1e-12)
    assert "rectangles_pos" not in row["plan"] and "bands_pos" not in row["plan"]
    # logged at its own time on both timelines (the last job's utc time was 900 s): a geographic
    # recording opens on utc, where a plan at another time would otherwise be out of place
    reader, store = open_recording(tmp_path / "plan_ship.rrd")
    times = {(times.get(ELAPSED, (None, None))[1], times.get(UTC, (None, None))[1])
             for name, times, _ in recording_rows(reader, store) if name == "/plan/coverage"}
    assert times == {(elapsed_nanos(600.0), utc_nanos(scene.geo.utc(600.0)))}


BAD = [
    ("effort = 0", "plan.effort = 0: must be finite and > 0"),
    ("effort = -5.0", "plan.effort = -5.0: must be finite and > 0"),
    ("effort = inf", "plan.effort = inf: must be finite and > 0"),
    ("effort = nan", "plan.effort = nan: must be finite and > 0"),
    ("effort_km2 = 1e305", "plan.effort_km2 = 1e+305: too large"),
    ('effort = "8 km2"', "plan.effort = \"8 km2\": expected a number"),
    ("effort = 1e6\neffort_km2 = 1", "plan: give effort (m^2) or effort_km2 (km^2), not both"),
    ("sweep_width = 500.0", "plan.effort: missing"),
    ("effort = 1e6\nsweep_width = 0\nrectangles = 1", "plan.sweep_width = 0: must be finite and > 0"),
    ("effort = 1e6\nsweep_width = -inf\nbands = 1", "plan.sweep_width = -inf: must be finite and > 0"),
    ("effort = 1e6\nrectangles = 2", "plan.sweep_width: missing"),
    ('effort = 1e6\nlaw = "koopman"', 'plan.law = "koopman": must be one of "exponential", "inverse_cube", "definite"'),
    ("effort = 1e6\nlaw = 3", "plan.law = 3: must be one of"),
    ("effort = 1e6\nsweep_width = 1\nrectangles = 17", "plan.rectangles = 17: expected an integer from 0 (none) to 16"),
    ("effort = 1e6\nsweep_width = 1\nrectangles = -1", "plan.rectangles = -1: expected an integer"),
    ("effort = 1e6\nsweep_width = 1\nbands = 2.5", "plan.bands = 2.5: expected an integer from 0 (none) to 16"),
    ("effort = 1e6\nsweep_width = 1\nbands = true", "plan.bands = true: expected an integer"),
    ("effort = 1e6\nt = 700", "plan.t = 700: not a time of the scene's timeline (scene.times: 600, 900 s)"),
    ('effort = 1e6\nlayer = "boat"', 'plan.layer = "boat": not a layer of this scene (those are: "cat", "still")'),
    ("effort = [1e6, 2e6]", "plan.t: missing; 2 efforts (plan.effort) need a list of as many increasing times"),
    ("effort_km2 = [1, 2]", "plan.t: missing; 2 efforts (plan.effort_km2) need a list"),
    ("effort = 1e6\nt = [600, 900]", "plan.effort = 1000000.0: 2 times (plan.t) need a list of as many efforts"),
    ("effort = 1e6\nsweep_widht = 5", 'plan.sweep_widht: unknown key; did you mean "sweep_width"?'),
]


@pytest.mark.parametrize("body, message", BAD, ids=[b.split("\n")[-1] for b, _ in BAD])
def test_bad_plan_keys_are_one_line(body, message):
    with pytest.raises(bg.BananagridError) as raised:
        parse_scene(SCENE + "[plan]\n" + body + "\n", source="s.toml")
    text = str(raised.value)
    assert "\n" not in text and text.startswith("s.toml: ") and message in text


@pytest.mark.parametrize("body, message", [BAD[0], BAD[11], BAD[17], BAD[18], BAD[19]])
def test_bad_plan_keys_exit_2_from_the_cli(tmp_path, capsys, body, message):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE + "[plan]\n" + body + "\n")
    assert main(["run", str(scene), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert not list(tmp_path.glob("s*.rrd"))


@seed(20261127)
@settings(max_examples=60, deadline=None, database=None)
@given(effort=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**63), 2**63 - 1)),
       km2=st.booleans())
def test_every_effort_is_taken_in_si_or_refused_naming_the_key(effort, km2):
    """Any number under effort or effort_km2: a positive finite effort in m^2 (km^2 times 1e6),
    or one line naming the key."""
    key = "effort_km2" if km2 else "effort"
    value = repr(effort) if isinstance(effort, int) else ("nan" if math.isnan(effort) else repr(effort))
    value = {"inf": "inf", "-inf": "-inf"}.get(value, value)
    text = SCENE + f"[plan]\n{key} = {value}\n"
    try:
        scene = parse_scene(text, source="s")
    except bg.BananagridError as exc:
        assert f"s: plan.{key} = " in str(exc) and "\n" not in str(exc)
        assert not (math.isfinite(effort) and effort > 0 and math.isfinite(effort * (1e6 if km2 else 1.0)))
        return
    want = float(effort) * (1e6 if km2 else 1.0)
    assert scene.plan.effort == want and math.isfinite(want) and want > 0


def test_a_tiled_run_refuses_a_plan(tmp_path, capsys):
    """Tiles compute densities; a plan is never silently left out of a --zarr run."""
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE + PLAN)
    assert main(["run", str(scene), "--zarr", str(tmp_path / "s.zarr")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a [plan] needs its map's cell probabilities" in err
    assert not (tmp_path / "s.zarr").exists()
