"""``[plan]`` over several periods in scenes: ``t`` and ``effort`` as lists make the run's plan
``bg.plan_periods`` on the layer's model (a CAT or a Butterly); the progress line says each
sweep's POS, and the summary, the recording (each period at its time), ``inspect`` (text and
JSON), the NetCDF variables and the plan's GeoJSON carry each period's allocation and POS and the
total; one effort and one time (or lists of one) keep the one-period plan; bad input is one line
naming the key."""

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
from bananagrid.recording.inspect import format_inspection, inspect_recording
from bananagrid.recording.readback import open_recording, recording_rows
from bananagrid.recording.timeline import ELAPSED
from bananagrid.scenes.load import SEVERAL_PERIODS, parse_scene
from bananagrid.scenes.run import run_scene

#: A vessel 10, 15 and 20 minutes after its fix (as scenes/geo_ship.toml) on 500 m cells (720
#: cells): the plan over three periods takes a few seconds.
SCENE = """
[scene]
name = "periods_ship"
title = "Vessel west of Bergen: three periods of search"
times = [600.0, 900.0, 1200.0]

[geo]
origin_latlon = [60.45, 4.60]
time = "2026-11-24T05:40:00Z"

[grid]
x = [-9000.0, 6000.0]
y = [-9000.0, 3000.0]
step = 500.0

[layers.cat]
model = "cat"
v0 = 5.0
sigma_a = 0.002
sigma_omega_deg = 0.05
heading_deg = 200.0

[layers.polar]
model = "polar"
v0 = 5.0
sigma_a = 0.002
sigma_omega_deg = 0.05
heading_deg = 200.0

[layers.fix]
model = "bearing_fix"
sensors = [[-8000.0, -8000.0], [5000.0, -8000.0]]
bearings_deg = [45.0, -45.0]
sigmas_deg = [5.0, 5.0]
"""
TIMES, EFFORTS = (600.0, 900.0, 1200.0), (3.0e6, 5.0e6, 5.0e6)
#: A sweep's gain below 1e-6 stops the iteration: 30 sweeps, some 3 s here (Brown's iteration
#: converges linearly: the default 1e-9 takes many more).
TOL = 1e-6
PLAN = f"""
[plan]
effort_km2 = [3.0, 5.0, 5.0]
t = [600.0, 900.0, 1200.0]
sweep_width = 500.0
rectangles = 2
bands = 2
tol = {TOL}
"""


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """The scene run once with the map files: its rows, its directory, its scene."""
    out = tmp_path_factory.mktemp("periods")
    scene = parse_scene(SCENE + PLAN, source="periods_ship.toml")
    rows = run_scene(scene, out, netcdf=True, geojson=True)
    return rows, out, scene


@pytest.fixture(scope="module")
def reference(planned):
    """The same plan by the Python API: what the scene must give."""
    _, _, scene = planned
    return bg.plan_periods(scene.layers[0].model(TIMES[0]), scene.grid, TIMES, EFFORTS, tol=TOL)


def test_the_scene_plans_what_plan_periods_plans(planned, reference):
    rows, _, _ = planned
    (row,) = [r for r in rows if "plan" in r]
    plan = row["plan"]
    assert (row["layer"], row["t"]) == ("cat", 1200.0)  # the row of the last period's time
    # 1e-12: the same kernels and iteration on the same maps; only the threads' order of summing may differ
    assert plan["pos"] == pytest.approx(reference.pos, abs=1e-12)
    assert plan["first_detection"] == pytest.approx(list(reference.period_pos), abs=1e-12)
    assert math.fsum(plan["first_detection"]) == pytest.approx(plan["pos"], abs=1e-12)
    assert plan["periods"] == 3 and plan["times_s"] == list(TIMES) and plan["efforts_m2"] == list(EFFORTS)
    assert plan["converged"] and plan["sweeps"] == reference.sweeps
    assert np.all(np.diff(plan["pos_by_sweep"]) >= -1e-13)  # never decreasing, to rounding
    for k, (period, allocation) in enumerate(zip(plan["period_plans"], reference.allocations)):
        assert (period["period"], period["t"], period["effort_m2"]) == (k + 1, TIMES[k], EFFORTS[k])
        assert period["pos"] == pytest.approx(allocation.pos, abs=1e-12)
        # each period's areas: never better than its ideal allocation (Jensen), never more effort
        assert period["rectangles_pos"] <= period["pos"] + 1e-12 and period["bands_pos"] <= period["pos"] + 1e-12
        assert period["rectangles_effort_m2"] <= EFFORTS[k] * (1 + 1e-12)
    # planning the periods together is never worse than the first period's own plan
    own = bg.allocate(bg.rasterise(planned[2].layers[0].model(TIMES[0]), planned[2].grid, quantity="probability"),
                      EFFORTS[0])
    assert plan["pos"] >= own.pos - 1e-12


def test_the_recording_holds_each_period_at_its_time_and_the_totals(planned, reference):
    _, out, _ = planned
    reader, store = open_recording(out / "periods_ship.rrd")
    times = sorted(t[ELAPSED][1] for name, t, _ in recording_rows(reader, store) if name == "/plan/coverage")
    assert times == [int(t * 1e9) for t in TIMES]
    info = inspect_recording(out / "periods_ship.rrd")
    plan = info["plan"]
    assert plan["pos"] == pytest.approx(reference.pos, abs=1e-12) and plan["periods"] == 3
    assert plan["first_detection"] == pytest.approx(list(reference.period_pos), abs=1e-12)
    assert [p["t"] for p in plan["period_plans"]] == list(TIMES)
    assert [p["pos"] for p in plan["period_plans"]] == pytest.approx([a.pos for a in reference.allocations], abs=1e-12)
    assert all(len(p["rectangles"]["areas"]) >= 1 for p in plan["period_plans"])
    json.dumps(info, allow_nan=False)  # what --json writes
    text = format_inspection(info)
    assert "recorded plan over 3 periods" in text and f"total POS {reference.pos:.6f}" in text
    assert "period 3: first detection" in text
    assert "/plan/periods/pos_by_sweep" in info["entities"]


def test_netcdf_and_geojson_carry_each_period(planned, reference):
    _, out, _ = planned
    import xarray as xr
    with xr.open_dataset(out / "periods_ship.nc") as dataset:
        for k, allocation in enumerate(reference.allocations):
            variable = dataset[f"plan_coverage_{k + 1}"]
            assert variable.dims == ("y", "x") and variable.attrs["units"] == "m2 m-2"
            assert variable.attrs["bananagrid_period"] == k + 1 and variable.attrs["bananagrid_t"] == TIMES[k]
            # 1e-12: the run's plan and the API's, summed in another threads' order at most
            assert variable.attrs["bananagrid_plan_pos"] == pytest.approx(reference.pos, abs=1e-12)
            np.testing.assert_allclose(variable.values, allocation.effort.values, rtol=1e-9, atol=1e-12)
    # the file's readers still find the layers' maps, and only them
    _, maps = read_maps(out / "periods_ship.nc")
    assert {m["layer"] for m in maps} == {"cat", "polar", "fix"}
    collection = json.loads((out / "periods_ship-plan.geojson").read_text())
    periods = {f["properties"]["period"] for f in collection["features"] if f["properties"]["kind"] == "area"}
    assert periods == {1, 2, 3}
    assert collection["bananagrid"]["pos"] == pytest.approx(reference.pos, abs=1e-12)


def test_the_cli_says_each_sweep_and_the_plan(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE + PLAN.replace("rectangles = 2", "rectangles = 0").replace("bands = 2", "bands = 0"))
    assert main(["run", str(scene), "--out", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    assert "sweep 1: POS " in captured.err and "(refined)" in captured.err
    assert "plan cat 3 periods t=600, 900, 1200 s (3 + 5 + 5 km^2)" in captured.err
    assert "plan over 3 periods on layer cat: total POS" in captured.out and "period 3:" in captured.out


def test_one_period_in_lists_is_the_one_period_plan():
    """Lists of one effort and one time are the one-period plan, exactly."""
    one = parse_scene(SCENE + "[plan]\neffort = 2e6\nt = 900\n", source="s").plan
    listed = parse_scene(SCENE + "[plan]\neffort = [2e6]\nt = [900]\n", source="s").plan
    assert one == listed and not listed.several and listed.periods == ((900.0, 2e6),)


BAD = [
    ("effort = [1e6, 2e6]", "plan.t: missing; 2 efforts (plan.effort) need a list of as many increasing times"),
    ("effort = [1e6, 2e6]\nt = 900", "plan.t = 900: 2 efforts (plan.effort) need a list"),
    ("effort = 1e6\nt = [600, 900]", "plan.effort = 1000000.0: 2 times (plan.t) need a list of as many efforts"),
    ("effort = [1e6, 2e6]\nt = [600, 900, 1200]", "plan.t: 3 times for 2 efforts (plan.effort)"),
    ("effort_km2 = [1, 2]\nt = [900, 600]", "plan.t[1] = 600: not after plan.t[0] = 900; the periods' times must"),
    ("effort_km2 = [1, 2]\nt = [600, 600]", "plan.t[1] = 600: not after plan.t[0] = 600"),
    ("effort_km2 = [1, 2]\nt = [600, 700]", "plan.t[1] = 700: not a time of the scene's timeline (scene.times: 600, "
                                            "900, 1200 s)"),
    ("effort_km2 = [1, 0]\nt = [600, 900]", "plan.effort_km2[1] = 0: must be finite and > 0 (km^2)"),
    ('effort = [1e6, "x"]\nt = [600, 900]', 'plan.effort[1] = "x": expected a number'),
    ('effort = [1e6, 1e6]\nt = [600, "x"]', 'plan.t[1] = "x": expected a number'),
    ('effort = [1e6, 1e6]\nt = [600, 900]\nlayer = "polar"', 'plan.layer = "polar": a polar layer, an approximation '
                                                             'with no path per parameter'),
    ('effort = [1e6, 1e6]\nt = [600, 900]\nlayer = "polar"', "use bg.CAT (exact, a path per (a, omega))"),
    ('effort = [1e6, 1e6]\nt = [600, 900]\nlayer = "fix"', 'plan.layer = "fix": a bearing_fix layer; plans over '
                                                           'several periods need a motion model'),
    ("effort = [1e6, 1e6]\nt = [600, 900]\ntol = 0", "plan.tol = 0: must be finite and > 0"),
    ("effort = [1e6, 1e6]\nt = [600, 900]\ntol = nan", "plan.tol = nan: must be finite and > 0"),
    ("effort = 1e6\ntol = 1e-6", "plan.tol = 1e-06: only for a plan over several periods"),
]


@pytest.mark.parametrize("body, message", BAD, ids=[b.replace("\n", " ") for b, _ in BAD])
def test_bad_period_keys_are_one_line(body, message):
    with pytest.raises(bg.BananagridError) as raised:
        parse_scene(SCENE + "[plan]\n" + body + "\n", source="s.toml")
    text = str(raised.value)
    assert "\n" not in text and text.startswith("s.toml: ") and message in text


def test_several_periods_after_evidence_are_refused(tmp_path, capsys):
    evidence = ('\n[[evidence]]\nkind = "area_search"\npolygon = [[-1000.0, -1000.0], [1000.0, -1000.0], '
                '[1000.0, 1000.0], [-1000.0, 1000.0]]\nt = 600.0\npod = 0.5\n')
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE + "[plan]\neffort = [1e6, 1e6]\nt = [900, 1200]\n" + evidence)
    assert main(["run", str(scene), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"plan.t = [900.0, 1200.0]: {SEVERAL_PERIODS}" in err and "Traceback" not in err
    assert not list(tmp_path.glob("s*.rrd"))


@seed(20261127)
@settings(max_examples=80, deadline=None, database=None)
@given(times=st.lists(st.sampled_from([0.0, 300.0, 600.0, 900.0, 1200.0, 1500.0]), min_size=1, max_size=5))
def test_any_list_of_times_is_a_plan_over_them_or_one_line(times):
    """Any list of times (one effort each): the periods in that order when they increase and
    lie on the timeline, else one line naming the first bad item."""
    text = SCENE + f"[plan]\neffort = {[1e6] * len(times)}\nt = {times}\n"
    try:
        plan = parse_scene(text, source="s").plan
    except bg.BananagridError as exc:
        message = str(exc)
        assert "\n" not in message and message.startswith("s: plan.t[")
        on = all(t in TIMES for t in times)
        assert not (on and all(b > a for a, b in zip(times, times[1:])))
        return
    assert all(t in TIMES for t in times) and all(b > a for a, b in zip(times, times[1:]))
    assert plan.periods == tuple((t, 1e6) for t in times)
    assert plan.several == (len(times) > 1)
