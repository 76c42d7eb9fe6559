"""Posteriors over tiled grids (bananagrid.evidence.tiled): the blocks' cells finished together
equal ``bg.posterior`` on the whole grid (every block computed: ``skip=False``), the global
numbers from the blocks' sums equal its numbers, blocks where the prior is negligible cost no
prior rule and keep the searches' POD map, and a store is written whole or not at all.

Tolerance: a block's cells are computed on the block as a grid of its own, whose cell edges are
the whole grid's to an ulp (origin + k dx on each), so the prior's cell rules there agree to
rounding (engine.tiles: within 1e-14 of the largest cell); sums over the blocks run in another
order than over the whole grid (n cells: n eps of the sum at worst, 1e-13 for the grids here).
1e-12 of the largest cell (values) and 1e-12 absolute (POS, normaliser) hold both with room.
"""

from __future__ import annotations

import json
import math

import dask
import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.evidence import tiled
from bananagrid.evidence.tiled import posterior_tiles
from cases import FIG1
from evidence_cases import PRIORS, cutting_evidence

#: Module docstring: rounding of the cells' rules on a block's own edges, and of the sums.
TOL = 1e-12

#: Blocks that do not divide the grids (partial blocks at the north and east edges).
CHUNKS = (7, 11)


def _coarse(grid: bg.Grid, factor: int = 2) -> bg.Grid:
    """``grid`` at ``factor`` times its step (the table's grids at a test's cost)."""
    (x0, x1, y0, y1) = grid.extent
    return bg.Grid.from_bounds(x=(x0, x1), y=(y0, y1), step=grid.dx * factor)


def _evidence(name):
    prior, _, centre, scale = PRIORS[name]
    t = getattr(prior, "t", None)
    found = cutting_evidence(t, centre, scale)
    tt = 0.0 if t is None else t
    # a second area search (coverage), each search's own POS then differs from the total
    cx, cy = centre
    found.append(bg.AreaSearch([(cx, cy - scale), (cx + scale, cy - scale), (cx + scale, cy), (cx, cy)], t=tt,
                               coverage=0.8))
    found.append(bg.PositionReport((cx + 0.2 * scale, cy), t=tt, sigma=2.0 * scale))
    return found


def _assert_same(got, ref):
    peak = float(np.max(ref.values))
    assert np.max(np.abs(got.values - ref.values)) <= TOL * peak
    assert np.max(np.abs(got.prior - ref.prior)) <= TOL * float(np.max(ref.prior))
    assert np.max(np.abs(got.pod - ref.pod)) <= TOL
    assert got.pos == pytest.approx(ref.pos, abs=TOL) and got.normaliser == pytest.approx(ref.normaliser, abs=TOL)
    assert np.allclose(got.search_pos, ref.search_pos, rtol=0.0, atol=TOL)


@pytest.mark.parametrize("name", list(PRIORS))
def test_a_tiled_posterior_is_the_whole_grids(name):
    """Every prior of the evidence table (CAT, polar banana, Butterly, a mixture, a bearing fix)
    after an area search and a track that cut cells, land, a second search and a position
    report: the blocks' cells finished together, and the numbers from the blocks' sums alone,
    equal bg.posterior on the whole grid."""
    prior, grid, _, _ = PRIORS[name]
    grid = _coarse(grid)
    evidence = _evidence(name)
    ref = bg.posterior(prior, grid, evidence)
    tiles = posterior_tiles(prior, grid, evidence, chunks=CHUNKS, skip=False)
    assert tiles.channels.chunks[1][0] == CHUNKS[0] and tiles.channels.chunks[2][0] == CHUNKS[1]
    with dask.config.set(scheduler="threads"):
        got = tiles.compute()
        numbers = tiles.numbers()
    _assert_same(got, ref)
    assert numbers["pos"] == pytest.approx(ref.pos, abs=TOL)
    assert numbers["normaliser"] == pytest.approx(ref.normaliser, abs=TOL)
    assert np.allclose(numbers["search_pos"], ref.search_pos, rtol=0.0, atol=TOL)
    assert numbers["mass"] == pytest.approx(ref.mass, rel=TOL)
    bound = ref.provenance["posterior"]["boundary_mass"]
    assert (numbers["boundary_mass"] is None) == (bound is None)
    if bound is not None:  # a sum of the cells' own bounds
        assert numbers["boundary_mass"] == pytest.approx(bound, rel=TOL)


@seed(20261127)
@settings(max_examples=8, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(rows=st.integers(1, 40), cols=st.integers(1, 40), shift=st.floats(-0.45, 0.45), pod=st.floats(0.05, 1.0),
       corner=st.tuples(st.floats(-0.9, 0.5), st.floats(-0.9, 0.5)))
def test_any_blocks_give_the_whole_grids_posterior(rows, cols, shift, pod, corner):
    """Blocks of any shape (one cell to the whole grid), a grid shifted by a fraction of a cell,
    a search of any POD (1 included: cells the search empties) placed anywhere over the CAT."""
    prior, grid, (cx, cy), scale = PRIORS["cat"]
    (x0, x1, y0, y1), step = grid.extent, 4 * grid.dx
    grid = bg.Grid.from_bounds(x=(x0 + shift * step, x1 + shift * step), y=(y0, y1), step=step)
    u, v = corner
    box = [(cx + u * scale, cy + v * scale), (cx + (u + 0.8) * scale, cy + v * scale),
           (cx + (u + 0.8) * scale, cy + (v + 0.6) * scale), (cx + u * scale, cy + (v + 0.6) * scale)]
    evidence = [bg.AreaSearch(box, t=prior.t, pod=pod)]
    ref = bg.posterior(prior, grid, evidence)
    with dask.config.set(scheduler="threads"):
        got = posterior_tiles(prior, grid, evidence, chunks=(rows, cols), skip=False).compute()
    _assert_same(got, ref)


def test_the_store_holds_the_posterior_whole_or_not_at_all(tmp_path, monkeypatch):
    """to_zarr writes the prior's and the posterior's cell probabilities (and their cell-mean
    densities) with the numbers in the provenance; a block that fails leaves no store and an
    older store at the path as it was."""
    prior, grid, _, _ = PRIORS["butterly"]
    grid, evidence = _coarse(grid), _evidence("butterly")
    ref = bg.posterior(prior, grid, evidence)
    path = tmp_path / "post.zarr"
    with dask.config.set(scheduler="threads"):
        posterior_tiles(prior, grid, evidence, chunks=(16, 16), skip=False).to_zarr(path)
    with xr.open_zarr(path) as store:
        assert np.max(np.abs(store["posterior_probability"].values[0] - ref.values)) <= TOL * ref.values.max()
        assert np.max(np.abs(store["prior_probability"].values[0] - ref.prior)) <= TOL * ref.prior.max()
        assert np.allclose(store["posterior"].values[0] * grid.cell_area, store["posterior_probability"].values[0],
                           rtol=1e-15, atol=0.0)
        assert '"pos": ' in store["posterior"].attrs["bananagrid_provenance"]
        before = sorted(p.relative_to(path) for p in path.rglob("*"))
    real = tiled.block_cells

    def failing(prior, grid, evidence, n, rows, cols):
        if rows[0] > 0 and cols[0] > 0:
            raise RuntimeError("disk full")
        return real(prior, grid, evidence, n, rows, cols)

    monkeypatch.setattr(tiled, "block_cells", failing)
    with dask.config.set(scheduler="threads"), pytest.raises(bg.BananagridError, match="disk full"):
        posterior_tiles(prior, grid, [evidence[0]], chunks=(16, 16)).to_zarr(path)
    assert sorted(p.relative_to(path) for p in path.rglob("*")) == before  # the older store, untouched
    assert [p.name for p in tmp_path.iterdir()] == ["post.zarr"]  # no temporary store left
    with xr.open_zarr(path) as store:
        assert np.max(np.abs(store["posterior_probability"].values[0] - ref.values)) <= TOL * ref.values.max()


def test_contradicting_evidence_is_refused_as_by_the_whole_grid(tmp_path):
    """A search that would surely have found the target: the same one-line refusal from the
    blocks' sums as from bg.posterior, and from to_zarr (its one pass done), with no store left."""
    prior, grid, _, _ = PRIORS["cat"]
    grid = _coarse(grid)
    (x0, x1, y0, y1) = grid.extent
    everywhere = bg.AreaSearch([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], t=prior.t, pod=1.0)
    with pytest.raises(bg.BananagridError) as whole:
        bg.posterior(prior, grid, [everywhere])
    tiles = posterior_tiles(prior, grid, [everywhere], chunks=CHUNKS)
    with dask.config.set(scheduler="threads"), pytest.raises(bg.BananagridError) as blocks:
        tiles.numbers()
    assert str(blocks.value) == str(whole.value)
    with dask.config.set(scheduler="threads"), pytest.raises(bg.BananagridError) as stored:
        tiles.to_zarr(tmp_path / "post.zarr")
    assert str(stored.value) == str(whole.value) and list(tmp_path.iterdir()) == []


def test_the_store_is_written_in_one_pass(tmp_path, monkeypatch):
    """to_zarr computes each block's cells once (the sums in the same pass; the stored posterior
    divided by its sum after it): the store's posterior sums to one, its captured mass is 1 and
    its provenance holds numbers() (the same sums, in another pass)."""
    prior, grid, _, _ = PRIORS["cat"]
    grid, evidence = _coarse(grid), _evidence("cat")
    real, calls = tiled.block_cells, []
    monkeypatch.setattr(tiled, "block_cells", lambda *args: calls.append(args[4:6]) or real(*args))
    tiles = posterior_tiles(prior, grid, evidence, chunks=CHUNKS)
    with dask.config.set(scheduler="threads"):
        tiles.to_zarr(tmp_path / "post.zarr")
        assert len(calls) == int((~tiles.skipped).sum()) > 0
        numbers = tiles.numbers()
    with xr.open_zarr(tmp_path / "post.zarr") as store:
        assert float(store["posterior_probability"].values.sum()) == pytest.approx(1.0, abs=TOL)
        assert float(store["posterior_mass"].values[0]) == pytest.approx(1.0, abs=TOL)
        stored = json.loads(store["posterior"].attrs["bananagrid_provenance"])[0]["posterior"]
    assert stored["pos"] == numbers["pos"] and stored["normaliser"] == numbers["normaliser"]  # the same sums


@pytest.mark.parametrize("what, call, message", [
    ("chunks", lambda p, g: posterior_tiles(p, g, [], chunks=(0, 4)),
     "chunks = (0, 4): expected (rows, columns), two integers >= 1"),
    ("grid", lambda p, g: posterior_tiles(p, "grid", []), "grid = 'grid': expected a bananagrid.Grid"),
    ("evidence", lambda p, g: posterior_tiles(p, g, [3.0]), "evidence[0] = 3.0: expected one of"),
    ("later", lambda p, g: posterior_tiles(p, g, [bg.PositionReport((0.0, 0.0), t=11.0, sigma=1.0)]),
     "evidence[0].t = 11.0: after the map's time t = 10.0"),
    ("subdivisions", lambda p, g: posterior_tiles(p, g, [], subdivisions=0), "subdivisions"),
])
def test_bad_arguments_are_refused_before_any_block_runs(what, call, message, monkeypatch):
    monkeypatch.setattr(tiled, "block_cells", lambda *a: pytest.fail("a block ran"))
    prior, grid, _, _ = PRIORS["cat"]
    with pytest.raises(bg.BananagridError) as err:
        call(prior, _coarse(grid))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_blocks_run_in_worker_processes():
    """The blocks' tasks travel to other processes (the prior, the grid and the evidence pickled,
    Warp initialised there): the same posterior as on the whole grid in this one."""
    prior, grid, _, _ = PRIORS["butterly"]
    grid, evidence = _coarse(grid, 3), _evidence("butterly")
    ref = bg.posterior(prior, grid, evidence)
    with dask.config.set(scheduler="processes", num_workers=2):
        got = posterior_tiles(prior, grid, evidence, chunks=(12, 12), skip=False).compute()
    _assert_same(got, ref)


def test_the_whole_grid_warns_once_where_it_misses_the_target():
    """A grid over part of the target: one warning of the whole grid's capture when the sums are
    computed (none from the blocks, each of which misses most of it)."""
    prior, grid, _, _ = PRIORS["cat"]
    (x0, x1, y0, y1) = grid.extent
    half = bg.Grid.from_bounds(x=(x0, 0.5 * (x0 + x1)), y=(y0, y1), step=4 * grid.dx)
    tiles = posterior_tiles(prior, half, [], chunks=(5, 5))
    with dask.config.set(scheduler="threads"), pytest.warns(bg.BananagridWarning) as caught:
        tiles.numbers()
    assert len(caught) == 1 and "posterior_tiles: the grid captured 0.5" in str(caught[0].message)


#: A CAT with heading noise tabulates its density over each grid's extent (a block's own table,
#: not the whole grid's), to a relative interpolation error of at most
#: models._cat_heading.TARGET_ERROR (1e-6) each: the two maps agree within twice that.
HEADING_TOL = 2e-6


@pytest.mark.parametrize("heading, step, chunks, tol", [(0.0, 200.0, CHUNKS, TOL), (0.1, 600.0, (3, 4), HEADING_TOL)])
def test_evidence_carried_from_earlier_times_tiles_too(heading, step, chunks, tol):
    """A CAT (with and without heading noise) after two area searches at 4 s and 7 s, bearings at
    6 s (carried along the paths in the kernels) and a search at the map's time: the blocks'
    cells (each block's own carried channels) finished together equal bg.posterior."""
    from test_carried_posterior import earlier_evidence

    prior = bg.CAT(**FIG1, sigma_heading=heading)
    grid = bg.Grid.from_bounds(x=(-2400.0, 2400.0), y=(0.0, 3300.0), step=step)
    evidence = [*earlier_evidence(track=False),
                bg.AreaSearch([(-600.0, 2400.0), (600.0, 2400.0), (600.0, 3200.0), (-600.0, 3200.0)], t=10.0, pod=0.5)]
    ref = bg.posterior(prior, grid, evidence)
    assert "carried" in ref.provenance
    with dask.config.set(scheduler="threads"):
        tiles = posterior_tiles(prior, grid, evidence, chunks=chunks, skip=False)
        got = tiles.compute()
        numbers = tiles.numbers()
    peak = float(np.max(ref.values))
    assert np.max(np.abs(got.values - ref.values)) <= tol * peak
    assert np.max(np.abs(got.pod - ref.pod)) <= tol
    for value, expected in ((got.pos, ref.pos), (numbers["pos"], ref.pos), (numbers["normaliser"], ref.normaliser)):
        assert value == pytest.approx(expected, abs=tol)
    assert np.allclose(numbers["search_pos"], ref.search_pos, rtol=0.0, atol=tol)


def test_blocks_where_the_prior_is_negligible_are_skipped_but_keep_the_pod_map():
    """The CAT on a grid four times its frame, a search at the map's time over the banana's tip
    and one far out where the prior is negligible: the far blocks run no prior rule (prior 0,
    map 0); the map and the numbers equal bg.posterior's (the skipped cells hold at most the
    floor times a cell's area: 1e-13 of the peak cell at most, within TOL); the POD map on the
    skipped blocks is the search's exact area share of each cell (shapely's intersection, an
    independent oracle), elsewhere bg.posterior's."""
    import shapely

    prior = PRIORS["cat"][0]
    grid = bg.Grid.from_bounds(x=(-12000.0, 12000.0), y=(-6000.0, 12000.0), step=300.0)
    tip = [(-600.0, 2400.0), (600.0, 2450.0), (650.0, 3300.0), (-550.0, 3200.0)]
    far = [(-9000.0, 7000.0), (-4100.0, 7400.0), (-4400.0, 10100.0), (-8800.0, 9800.0)]
    evidence = [bg.AreaSearch(tip, t=prior.t, pod=0.7), bg.AreaSearch(far, t=prior.t, pod=0.6)]
    ref = bg.posterior(prior, grid, evidence, )
    calls = []
    real = tiled.block_cells
    tiles_mod_block = lambda *a: calls.append(a[4:6]) or real(*a)  # noqa: E731
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tiled, "block_cells", tiles_mod_block)
        tiles = posterior_tiles(prior, grid, evidence, chunks=(10, 10))
        with dask.config.set(scheduler="threads"):
            got = tiles.compute()
            numbers = tiles.numbers()
    assert 0 < tiles.skipped.sum() < tiles.skipped.size and len(calls) == 2 * int((~tiles.skipped).sum())
    peak = float(np.max(ref.values))
    assert np.max(np.abs(got.values - ref.values)) <= TOL * peak
    assert numbers["pos"] == pytest.approx(ref.pos, abs=TOL)
    assert np.allclose(numbers["search_pos"], ref.search_pos, rtol=0.0, atol=TOL)
    skipped = np.kron(tiles.skipped, np.ones((10, 10), dtype=bool))[:grid.ny, :grid.nx]
    assert np.all(got.prior[skipped] == 0.0) and ref.prior[skipped].max() <= TOL * ref.prior.max()
    assert np.max(np.abs(got.pod - ref.pod)[~skipped]) <= TOL
    far_polygon = shapely.Polygon(far)
    xe, ye = grid.origin[0] + grid.dx * np.arange(grid.nx + 1), grid.origin[1] + grid.dy * np.arange(grid.ny + 1)
    i, j = np.nonzero(skipped)
    share = np.array([far_polygon.intersection(shapely.box(xe[b], ye[a], xe[b + 1], ye[a + 1])).area
                      for a, b in zip(i, j)]) / grid.cell_area
    # the exact share's rounding: 1e-12 of a cell (shapely and the package's clip sum differently)
    assert np.max(np.abs(got.pod[i, j] - 0.6 * share)) <= 1e-12
    assert share.max() == 1.0 and 0.0 < share[share < 1.0].max()  # whole and cut cells among them
