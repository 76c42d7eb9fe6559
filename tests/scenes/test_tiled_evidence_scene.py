"""``bananagrid run SCENE --zarr`` on a scene with ``[[evidence]]``: each map's posterior computed
in the store's tiles (bananagrid.scenes.run_tiled, bananagrid.evidence.tiled.posterior_tiles)
holds what the NetCDF export of the same scene (in memory, ``bg.posterior``) holds: the same
variables and attributes, the posterior, POD map, POS and each search's POS equal within
:data:`TOL` (two scenes, and a sweep over blocks, search times, places, PODs and land); a
geographic scene's store has latitude and longitude; each posterior block is computed once; the printed summary gives the
POS lines of the in-memory run; what the in-memory run refuses is one line here too and leaves no
store; a store is written whole or not at all.

Tolerance: a block's cells run the same rules on the block as a grid of its own (cell edges the
whole grid's to an ulp: engine.tiles, within 1e-14 of the largest cell), blocks the prior proves
below 1e-13 of its peak are taken as 0, and the sums (normaliser, POS) run over the blocks in
another order than over the whole grid (n eps of a sum of n cells at worst: 5e-13 for the 4,800
cells here). 1e-12 of the largest cell (maps) and 1e-12 absolute (POS) hold all three with room
(measured: 2.4e-17 absolute on a posterior whose largest cell is 0.013, POS to 1.1e-16).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import dask
import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid import cli
from bananagrid.cli import main
from bananagrid.evidence import tiled
from bananagrid.geo.dataset import read_maps
from bananagrid.scenes import run_tiled
from bananagrid.scenes.run_evidence import scene_posterior
from bananagrid.scenes.run_tiled import run_scene_tiled
from test_evidence_scene import PLAIN, _write

#: Module docstring: the same rules on a block's own edges, skipped blocks, sums in another order.
TOL = 1e-12

SCENES = Path(__file__).resolve().parents[2] / "scenes"

#: Two layers at their own times (each its own time dimension) and a search between them, carried
#: to the later one: the earlier map took no search, the later one took it.
TWO_TIMES = PLAIN.replace("[layers.cat]", "[layers.early]").replace("t = 10.0\n", "t = 5.0\n") + """
[layers.late]
model = "cat"
v0 = 280.0
t = 10.0
sigma_a = 1.6666667
sigma_omega_deg = 3.3333

[[evidence]]
kind = "area_search"
name = "box"
polygon = [[-900.0, 1600.0], [900.0, 1600.0], [900.0, 2600.0], [-900.0, 2600.0]]
t = 8.0
pod = 0.5
"""

#: The scenes exported both ways: ``(path maker, --step, chunks)``. ``ev_ship``: geographic (UTC
#: times, lat/lon), a CAT and a still Butterly (blocks of 32 x 32 for its kernel's tiles, partial
#: ones at the north and east edges), an area search, a track, land and a report at the second
#: time, land alone at the first. ``fast_contact`` (the bundled scene at 400 m cells): a box searched
#: at 5 min carried through the CAT's paths to 10 min and a patrol's track, blocks of 16 x 24 that do
#: not divide the grid, blocks far from the banana skipped.
CASES = {
    "ev_ship": (lambda where: _write(where), None, (32, 32)),
    "fast_contact": (lambda where: SCENES / "fast_contact.toml", 400.0, (16, 24)),
    "two_times": (lambda where: _write(where, TWO_TIMES, "two.toml"), None, (8, 8)),
}


@pytest.fixture(scope="module", params=list(CASES))
def exported(request, tmp_path_factory):
    """The scene exported to NetCDF by the in-memory run (the CLI) and to Zarr in tiles (the
    synchronous scheduler): ``netcdf`` and ``zarr`` (the two datasets), ``scene``, ``rows`` (the
    tiled run's summary), ``path`` (the NetCDF file), ``chunks`` and ``calls`` (the blocks whose
    posterior cells the tiled run computed)."""
    where = tmp_path_factory.mktemp(request.param)
    make, step, chunks = CASES[request.param]
    path = make(where)
    argv = ["run", str(path), "--out", str(where), "--netcdf", "--quiet"]
    assert main(argv + (["--step", str(step)] if step else [])) == 0
    scene = bg.load_scene(path, tiled=True)
    if step:
        scene = scene.with_step(step, tiled=True)
    store = where / "tiled.zarr"
    real, calls = tiled.block_cells, []
    with pytest.MonkeyPatch.context() as patch, dask.config.set(scheduler="synchronous"):
        patch.setattr(tiled, "block_cells", lambda *args: calls.append(args[4:6]) or real(*args))
        rows = run_scene_tiled(scene, store, chunks)
    with xr.open_dataset(where / f"{scene.name}.nc") as netcdf, xr.open_zarr(store) as zarr:
        yield SimpleNamespace(netcdf=netcdf.load(), zarr=zarr.load(), scene=scene, rows=rows,
                              path=where / f"{scene.name}.nc", chunks=chunks, calls=calls)


def _index(scene, layer: str, t: float) -> int:
    """Where a layer's map at ``t`` lies on its variables' time dimension (by time)."""
    return sorted(time for other, time in scene.jobs() if other.name == layer).index(t)


def _evidence(var) -> list:
    return json.loads(var.attrs["bananagrid_evidence"])


def test_the_store_holds_the_netcdfs_posteriors(exported):
    netcdf, zarr, scene = exported.netcdf, exported.zarr, exported.scene
    layers = [layer.name for layer in scene.layers]
    derived = ("posterior", "pod", "pos", "search_pos")
    assert set(netcdf.data_vars) == set(zarr.data_vars)  # the same variables, nothing left out
    assert {f"{layer}_{d}" for layer in layers for d in derived} <= set(zarr.data_vars)
    assert set(netcdf.coords) == set(zarr.coords)
    assert list(zarr["search"].values) == list(netcdf["search"].values) == [s.name for s in scene.evidence if s.search]
    for layer in layers:
        for d in derived:
            got, want = zarr[f"{layer}_{d}"], netcdf[f"{layer}_{d}"]
            assert got.dims == want.dims, (layer, d)
            # the same attributes; the evidence's provenance holds the global numbers, compared below
            assert {k: v for k, v in got.attrs.items() if k != "bananagrid_evidence"} == \
                   {k: v for k, v in want.attrs.items() if k != "bananagrid_evidence"}, (layer, d)
        post, pod = zarr[f"{layer}_posterior"].values, netcdf[f"{layer}_posterior"].values
        assert np.max(np.abs(post - pod)) <= TOL * np.max(pod)
        np.testing.assert_allclose(post.sum(axis=(1, 2)), 1.0, rtol=0, atol=TOL)  # cell probabilities
        assert np.max(np.abs(zarr[f"{layer}_pod"].values - netcdf[f"{layer}_pod"].values)) <= TOL
        np.testing.assert_allclose(zarr[f"{layer}_pos"].values, netcdf[f"{layer}_pos"].values, rtol=0, atol=TOL)
        got, want = zarr[f"{layer}_search_pos"].values, netcdf[f"{layer}_search_pos"].values
        assert np.array_equal(np.isnan(got), np.isnan(want))  # NaN before a search began
        np.testing.assert_allclose(got[~np.isnan(got)], want[~np.isnan(want)], rtol=0, atol=TOL)
        for a, b in zip(_evidence(zarr[f"{layer}_posterior"]), _evidence(netcdf[f"{layer}_posterior"])):
            assert a.keys() == b.keys() and a["evidence"] == b["evidence"] and a["subdivisions"] == b["subdivisions"]
            for key in ("pos", "normaliser", "prior_mass"):
                assert a[key] == pytest.approx(b[key], abs=TOL), key
            assert a["search_pos"] == pytest.approx(b["search_pos"], abs=TOL)
            assert (a["boundary_mass"] is None) == (b["boundary_mass"] is None)
        # the prior as the tiled export writes it: raw densities, the captured mass beside them
        assert not zarr[f"{layer}_normalised"].values.any() and netcdf[f"{layer}_normalised"].values.all()
        raw = zarr[layer].values / zarr[f"{layer}_mass"].values[:, None, None]
        assert np.max(np.abs(raw - netcdf[layer].values)) <= TOL * np.max(netcdf[layer].values)


def test_the_coordinates_are_the_netcdfs(exported):
    """A geographic scene's store has the NetCDF's latitude, longitude, CRS and UTC times."""
    netcdf, zarr, scene = exported.netcdf, exported.zarr, exported.scene
    for name in netcdf.coords:  # x, y, the times, the searches; lat and lon of a geographic scene
        assert np.array_equal(zarr[name].values, netcdf[name].values), name
    assert ("lat" in zarr.coords) == ("lon" in zarr.coords) == (scene.geo is not None)
    if scene.geo is not None:
        assert zarr["crs"].attrs["crs_wkt"] == netcdf["crs"].attrs["crs_wkt"]
        assert zarr[f"{scene.layers[0].name}_posterior"].attrs["grid_mapping"] == "crs"


def test_the_netcdfs_maps_read_back_are_its_layers(exported):
    """``read_maps`` (``bananagrid plot FILE.nc``) of a file with posteriors: each layer's map at
    each time, and not the posterior's, POD's or POS's variables (which name their layer too)."""
    netcdf, scene, path = exported.netcdf, exported.scene, exported.path
    _, maps = read_maps(path)
    assert sorted((m["layer"], m["t"]) for m in maps) == sorted((layer.name, t) for layer, t in scene.jobs())
    for m in maps:
        np.testing.assert_array_equal(m["values"], netcdf[m["layer"]].values[_index(scene, m["layer"], m["t"])])


def test_the_summary_rows_carry_the_stores_pos(exported):
    zarr, scene, rows = exported.zarr, exported.scene, exported.rows
    for row in rows:
        k = _index(scene, row["layer"], row["t"])
        found = row["evidence"]
        assert (found["layer"], found["t"]) == (row["layer"], row["t"])
        assert found["pos"] == float(zarr[f"{row['layer']}_pos"].values[k])
        assert found["searches"] == [s.name for s in scene.evidence if s.search]


def test_the_cli_prints_the_in_memory_runs_pos_lines(tmp_path, capsys):
    """``run --zarr`` on a local cluster of worker processes: the posteriors' lines of the summary
    are the in-memory run's, word for word (POS to 4 digits, the probability of the evidence to 4
    significant digits: the two agree to 1e-12)."""
    path = SCENES / "fast_contact.toml"
    assert main(["run", str(path), "--out", str(tmp_path), "--step", "400", "--quiet"]) == 0
    memory = [line for line in capsys.readouterr().out.splitlines() if ": posterior of " in line]
    store = tmp_path / "fast_contact.zarr"
    assert main(["run", str(path), "--zarr", str(store), "--step", "400", "--chunks", "16", "--workers", "1",
                 "--memory-limit", "2GiB", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert [line for line in out.splitlines() if ": posterior of " in line] == memory and len(memory) == 2
    assert "cells computed" in out and f"wrote {store}" in out


#: The Figure 1 CAT (PLAIN: 30 x 18 cells of 200 m) at 4 and 10 s.
SWEPT = PLAIN.replace("[scene]\n", "[scene]\ntimes = [4.0, 10.0]\n").replace("t = 10.0\n", "")


@seed(20261127)
@settings(max_examples=6, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(rows=st.integers(5, 30), cols=st.integers(5, 45), t=st.floats(0.5, 10.0), pod=st.floats(0.05, 1.0),
       corner=st.tuples(st.floats(-2500.0, 1500.0), st.floats(0.0, 2500.0)), land=st.booleans())
def test_any_blocks_and_times_give_the_in_memory_posteriors(rows, cols, t, pod, corner, land, tmp_path_factory):
    """Any blocks (partial ones at the edges), a search at any time (before a map's time: carried
    through the CAT's paths; after it: not taken by that map), anywhere, of any POD, with land or
    not: the store's posterior, POD map, POS and each search's POS are the in-memory run's
    (``scene_posterior``, what the NetCDF holds) within TOL."""
    x, y = corner
    text = SWEPT + (f'[[evidence]]\nkind = "area_search"\nname = "box"\npolygon = [[{x}, {y}], [{x + 1200}, {y}], '
                    f'[{x + 1200}, {y + 900}], [{x}, {y + 900}]]\nt = {t!r}\npod = {pod!r}\n')
    if land:
        text += '[[evidence]]\nkind = "exclusion"\npolygon = [[-3000, -200], [-1000, -200], [-3000, 1500]]\n'
    scene = bg.parse_scene(text, source="s", tiled=True)
    store = tmp_path_factory.mktemp("swept") / "s.zarr"
    with dask.config.set(scheduler="synchronous"):
        run_scene_tiled(scene, store, (rows, cols))
    with xr.open_zarr(store) as zarr:
        for k, (layer, t_map) in enumerate(scene.jobs()):
            want = scene_posterior(scene, layer, t_map).posterior
            post = zarr["cat_posterior"].values[k]
            assert np.max(np.abs(post - want.values)) <= TOL * np.max(want.values)
            assert np.max(np.abs(zarr["cat_pod"].values[k] - want.pod)) <= TOL
            assert float(zarr["cat_pos"].values[k]) == pytest.approx(want.pos, abs=TOL)
            got = zarr["cat_search_pos"].values[k]
            if t <= t_map:  # the box began by the map's time
                assert got == pytest.approx(list(want.search_pos), abs=TOL)
            else:
                assert np.isnan(got).all() and want.search_pos == ()


# --- what the in-memory run refuses, and whole or nothing ----------------------------------------

POLAR_EARLIER = PLAIN.replace('model = "cat"', 'model = "polar"\nvariant = "improved"') + (
    '[[evidence]]\nkind = "area_search"\npolygon = [[0, 0], [100, 0], [0, 100]]\nt = 4.0\npod = 0.5\n')
#: A search of POD 1 over the whole grid at the map's time: the searches would have found it.
EVERYWHERE = PLAIN + ('[[evidence]]\nkind = "area_search"\nname = "all"\n'
                      'polygon = [[-4000, -1000], [4000, -1000], [4000, 4000], [-4000, 4000]]\nt = 10.0\npod = 1.0\n')


@pytest.mark.parametrize("text, message", [
    (POLAR_EARLIER, "layers.cat at t = 10 s: evidence[0].t = 4.0: earlier than the map's time"),
    (EVERYWHERE, "layers.cat at t = 10 s: evidence: the probability of the evidence under the prior is 0"),
])
def test_what_the_in_memory_run_refuses_is_one_line_and_no_store(text, message, tmp_path, capsys, monkeypatch):
    """The in-memory run's line, word for word: a refusal of the evidence before any block runs
    (the polar banana cannot carry earlier evidence), and evidence that contradicts the prior,
    found once the pass has summed the posterior (the tiles on Dask's synchronous scheduler here:
    the cluster's own path is the test above)."""
    monkeypatch.setattr(cli, "dask_client", lambda **kwargs: dask.config.set(scheduler="synchronous"))
    scene = tmp_path / "s.toml"
    scene.write_text(text)
    assert main(["run", str(scene), "--out", str(tmp_path), "--quiet"]) == 2
    memory = capsys.readouterr().err.splitlines()[-1]  # after the coarse grid's warning
    assert main(["run", str(scene), "--zarr", str(tmp_path / "s.zarr"), "--workers", "1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert err == memory + "\n"  # the in-memory run's line
    assert not (tmp_path / "s.zarr").exists()


def test_each_posterior_block_is_computed_once(exported):
    """One pass computes the maps and the sums of the posteriors (the normaliser is applied to the
    stored cells after it): each block of each map's posterior runs its cell rules once (two
    passes, sums then maps, cost twice the in-memory run: measured 96 s against 48 s of CPU), and
    a block the prior proves negligible not at all."""
    jobs = run_tiled.tiled_posteriors(exported.scene, exported.chunks)
    assert len(exported.calls) == sum(int((~job.tiles.skipped).sum()) for job in jobs) > 0


@pytest.mark.parametrize("when", ["block", "finish"])
def test_a_failure_leaves_no_store(when, tmp_path, monkeypatch):
    """A posterior's block fails in the store's pass (a full disk, a worker lost), or dividing the
    stored cells by their sums fails after it: one line naming the store, and no store (nor a
    temporary one) left."""
    scene = bg.parse_scene(PLAIN + '[[evidence]]\nkind = "area_search"\npolygon = [[-600, 2400], [600, 2400], '
                           '[600, 3200], [-600, 3200]]\nt = 10.0\npod = 0.5\n', source="s")

    def full(*args, **kwargs):
        raise OSError("No space left on device")

    monkeypatch.setattr(tiled if when == "block" else run_tiled, "block_cells" if when == "block" else "scale_stored",
                        full)
    with dask.config.set(scheduler="synchronous"), pytest.raises(bg.BananagridError) as caught:
        run_scene_tiled(scene, tmp_path / "s.zarr", 8)
    assert str(caught.value) == f"{tmp_path / 's.zarr'}: cannot write the Zarr store (OSError: No space left on device)"
    assert list(tmp_path.iterdir()) == []


def test_a_posteriors_block_needs_more_memory_than_the_maps(tmp_path, capsys, monkeypatch):
    """A worker's memory limit that holds a block of the map (720 x 1024 cells: 0.52 GB, 0.66 GB
    over Dask's pause fraction) but not one of the posterior (its channels and cell rules: 0.70 GB,
    0.88 GB) is refused before any worker starts, naming the limit; the map alone goes on to
    start its cluster (stopped here)."""
    def started(**kwargs):
        raise bg.BananagridError("the cluster starts")

    monkeypatch.setattr(cli, "dask_client", started)
    evidence = '[[evidence]]\nkind = "area_search"\npolygon = [[0, 0], [100, 0], [0, 100]]\nt = 10.0\npod = 0.5\n'
    for name, text, message in (("map", PLAIN, "bananagrid: error: the cluster starts"),
                                ("posterior", PLAIN + evidence, "bananagrid: error: --memory-limit")):
        (tmp_path / f"{name}.toml").write_text(text)
        assert main(["run", str(tmp_path / f"{name}.toml"), "--zarr", str(tmp_path / f"{name}.zarr"), "--step", "5",
                     "--chunks", "1024", "--memory-limit", "800MB", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(message) and err.count("\n") == 1, err
    assert list(tmp_path.glob("*.zarr")) == []


def test_a_posterior_over_the_time_allowed_is_refused_before_any_cluster(tmp_path, capsys, monkeypatch):
    """``--max-seconds`` counts each posterior too (its prior's cell rules on the blocks computed,
    as the in-memory run counts it: estimated 0.11 s on the 2 threads set here for the CAT on 180 x
    300 cells; its map's densities 0.035 s; both estimates, not timings, so the limit of 0.07 s
    between them holds on any machine): the map alone goes on (to a scheduler that does not answer
    here), the scene with evidence is refused in one line naming the layer, the time and the
    option."""
    monkeypatch.setattr(run_tiled, "default_threads", lambda: 2)
    evidence = '[[evidence]]\nkind = "area_search"\npolygon = [[0, 0], [100, 0], [0, 100]]\nt = 10.0\npod = 0.5\n'
    for name, text, message in (
            ("map", PLAIN, "--scheduler = tcp://127.0.0.1:9: connection refused"),
            ("posterior", PLAIN + evidence, "the posterior of layers.cat at t = 10 s on 54,000 cells in tiles would "
                                            "take about")):
        (tmp_path / f"{name}.toml").write_text(text)
        assert main(["run", str(tmp_path / f"{name}.toml"), "--zarr", str(tmp_path / f"{name}.zarr"), "--step", "20",
                     "--max-seconds", "0.07", "--scheduler", "tcp://127.0.0.1:9", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
    assert "--max-seconds S to allow more" in err and list(tmp_path.glob("*.zarr")) == []
