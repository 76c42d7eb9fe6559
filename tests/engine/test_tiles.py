"""Tiled rasterising on Dask, Zarr stores, sharded batches and faults (bananagrid.engine.tiles,
bananagrid.engine.batch_shards, bananagrid.geo.zarr_store, ``bananagrid run --zarr``).

Every equality here is exact (``np.array_equal``): a block runs the same kernel with the same
binding on the same coordinates as the whole grid, so nothing but a bug can change a bit. The
cluster tests run on a 2-process ``distributed.LocalCluster`` on this machine.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from pathlib import Path

import dask
import numpy as np
import pytest
import xarray as xr

import bananagrid as bg
from bananagrid.cli import main
from bananagrid.engine import tiles
from bananagrid.engine.cluster import check_memory_limit, dask_client
from bananagrid.engine.grid_kernel import GridExtent
from bananagrid.engine.tiles import check_chunks, rasterise_tiles, tile_bounds
from bananagrid.engine.warp_runtime import default_threads
from bananagrid.geo.dataset import raster_dataset
from bananagrid.geo.zarr_store import write_zarr
from bananagrid.scenes.examples import example_path
from bananagrid.scenes.run_tiled import tiled_maps

distributed = pytest.importorskip("distributed")

POSE = bg.Pose(origin=(150.0, -80.0), heading=0.4)

#: One model of every kind and variant the grid kernels have (CAT exact and tabulated with heading
#: noise, both polar variants and heading noise, Butterly with a continuous speed law, both
#: bearing variants).
MODELS = {
    "cat": bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, pose=POSE),
    "cat_heading": bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, sigma_heading=0.1, pose=POSE),
    "polar_rough": bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, variant="rough", pose=POSE),
    "polar_improved": bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, pose=POSE),
    "polar_heading": bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, sigma_heading=0.1,
                                    pose=POSE),
    "butterly": bg.Butterly(mean=(300.0, 900.0), cov=[[900.0, 200.0], [200.0, 400.0]],
                            speeds=bg.NormalSpeed(mean=4.0, sd=0.5), t=120.0),
    "bearing_exact": bg.BearingFix(sensors=[(-2000.0, 0.0), (2500.0, 300.0)], bearings=[0.6, -0.5],
                                   sigmas=[0.02, 0.03], variant="exact"),
    "bearing_linear": bg.BearingFix(sensors=[(-2000.0, 0.0), (2500.0, 300.0)], bearings=[0.6, -0.5],
                                    sigmas=[0.02, 0.03], variant="linear"),
}
#: A grid whose sides are not multiples of the blocks (partial blocks at the north and east edges).
GRID = bg.Grid.from_bounds(x=(-4000.0, 4100.0), y=(-3000.0, 5000.0), step=25.0)
CHUNKS = (64, 96)  # multiples of 32: Butterly's tiles


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2, memory_limit="2GiB") as c:
        yield c


def _in_memory(name, dtype=np.float64):
    return bg.rasterise(MODELS[name], GRID, dtype=dtype).values


def _as_tiled(tiled, reference):
    """``reference`` (the whole grid in memory) with the tiled raster's skipped blocks at 0,
    after checking that it is at most the floor there."""
    skipped = np.kron(tiled.skipped, np.ones(tiled.chunks, dtype=bool))[:tiled.grid.ny, :tiled.grid.nx]
    assert reference[skipped].max(initial=0.0) <= tiled.floor
    return np.where(skipped, 0.0, reference).astype(reference.dtype)


def _blocks(grid, chunks):
    for i, r0 in enumerate(range(0, grid.ny, chunks[0])):
        for j, c0 in enumerate(range(0, grid.nx, chunks[1])):
            yield i, j, (r0, min(r0 + chunks[0], grid.ny)), (c0, min(c0 + chunks[1], grid.nx))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_block_equals_the_in_memory_grid_on_a_cluster(client, name):
    model = MODELS[name]
    reference = _in_memory(name)
    tiled = bg.rasterise(model, GRID, chunks=CHUNKS)
    assert isinstance(tiled, bg.TiledRaster)
    assert tiled.values.chunks[0][0] == CHUNKS[0] and tiled.values.chunks[1][0] == CHUNKS[1]
    values = tiled.values.compute()  # on the cluster's worker processes
    floor = model.density_floor()
    for i, j, rows, cols in _blocks(GRID, CHUNKS):
        block = values[rows[0]:rows[1], cols[0]:cols[1]]
        whole = reference[rows[0]:rows[1], cols[0]:cols[1]]
        bound = model.density_bound(*tile_bounds(GRID, rows, cols))
        # the skipped blocks are exactly those whose proved bound is at most the floor ...
        assert tiled.skipped[i, j] == (bound <= floor), (i, j, bound, floor)
        if tiled.skipped[i, j]:
            # ... where the whole grid is indeed at most the floor, and the block is zeros
            assert not block.any() and whole.max() <= floor, (i, j, whole.max(), floor)
        else:
            assert np.array_equal(block, whole), (name, i, j, np.abs(block - whole).max())
        assert np.all(whole <= bound), (name, i, j)  # the bound holds on the cell centres


@pytest.mark.parametrize("name", ["cat", "polar_improved", "butterly", "bearing_exact"])
def test_float32_blocks_equal_the_in_memory_float32_grid(name):
    tiled = bg.rasterise(MODELS[name], GRID, chunks=CHUNKS, dtype=np.float32)
    values = tiled.values.compute(scheduler="threads")
    assert values.dtype == np.float32
    reference = _in_memory(name, np.float32)
    computed = np.kron(~tiled.skipped, np.ones(CHUNKS, dtype=bool))[:GRID.ny, :GRID.nx]
    assert np.array_equal(values[computed], reference[computed])
    assert reference[~computed].max(initial=0.0) <= MODELS[name].density_floor()


def test_skipped_blocks_run_no_kernel(monkeypatch):
    calls = []
    real = tiles.block_values
    monkeypatch.setattr(tiles, "block_values", lambda plan, rows, cols: calls.append((rows, cols)) or real(plan, rows, cols))
    tiled = rasterise_tiles(MODELS["butterly"], GRID, CHUNKS)
    tiled.values.compute(scheduler="synchronous")
    assert 0 < tiled.skipped.sum() < tiled.skipped.size
    assert len(calls) == tiled.skipped.size - tiled.skipped.sum()
    assert tiled.provenance["cells_computed"] == sum((r[1] - r[0]) * (c[1] - c[0]) for r, c in calls)


def test_a_huge_grid_with_a_small_banana_costs_the_banana(tmp_path):
    # 16,384 x 16,384 cells (268 M, 1 GiB as float32) at 1 m, the Butterly ring 480 m across:
    # only the blocks the ring can reach are computed and only they are written
    model = bg.Butterly(mean=(0.0, 0.0), cov=[[100.0, 0.0], [0.0, 100.0]], speeds=[4.0], weights=[1.0], t=60.0)
    grid = bg.Grid.from_bounds(x=(-8192.0, 8192.0), y=(-8192.0, 8192.0), step=1.0)
    tiled = bg.rasterise(model, grid, chunks=1024, dtype=np.float32)
    assert tiled.skipped.size == 256
    computed = tiled.skipped.size - int(tiled.skipped.sum())
    assert computed == 4  # the ring (radius 240 m, 11 SDs of the start beyond it) lies in the 4 central blocks
    assert tiled.cells_skipped == 252 * 1024 * 1024
    store = tiled.to_zarr(tmp_path / "huge.zarr")
    written = [p for p in (store / "density" / "c").rglob("*") if p.is_file()]
    assert len(written) == computed
    with xr.open_zarr(store) as ds:
        assert ds.density.shape == (1, 16384, 16384)
        centre = ds.density[0, 7168:9216, 7168:9216].values
        corner = ds.density[0, :1024, :1024].values
    reference = bg.rasterise(model, bg.Grid(origin=(-1024.0, -1024.0), dx=1.0, dy=1.0, nx=2048, ny=2048),
                             dtype=np.float32).values
    assert np.array_equal(centre, reference)
    assert not corner.any()
    assert float(ds.density_mass.values[0]) == pytest.approx(1.0, abs=1e-5)  # float32 sum of 4 M cells


def test_chunks_are_checked():
    with pytest.raises(bg.BananagridError, match=r"chunks = \(0, 64\): expected \(rows, columns\), two integers >= 1"):
        bg.rasterise(MODELS["cat"], GRID, chunks=(0, 64))
    with pytest.raises(bg.BananagridError, match=r'chunks = "big": expected'):
        bg.rasterise(MODELS["cat"], GRID, chunks="big")
    with pytest.raises(bg.BananagridError, match=r"columns 100 is not a multiple of 32; this model's kernel works in tiles of 32 x 32"):
        bg.rasterise(MODELS["butterly"], GRID, chunks=(64, 100))
    assert check_chunks(10_000, GRID) == (GRID.ny, GRID.nx)  # one block: any size
    with pytest.raises(bg.BananagridError, match="tiles compute densities only"):
        bg.rasterise(MODELS["cat"], GRID, chunks=64, quantity="probability")


def test_narrow_blocks_of_a_cat_are_estimated_per_block_row():
    """The CAT's row sweep costs per launch row: blocks 8 columns wide sweep every row once per
    block (measured 0.71 s against 0.12 s for whole rows on a 200 x 200 framing grid, sigma_omega t
    10 rad, Intel Xeon AVX-512), so the estimate that refuses tiles counts the blocks' rows: a limit
    between the whole rows' estimate and the narrow blocks' refuses the narrow blocks before any
    block is computed and lets the whole rows through."""
    model, grid = MODELS["cat"], bg.Grid.from_bounds(x=(-2000.0, 2000.0), y=(-1000.0, 3000.0), step=20.0)
    whole = model.work_estimate(grid.nx * grid.ny, GridExtent(grid))
    narrow = model.work_estimate(grid.nx * grid.ny, GridExtent(grid, row_cells=8))
    assert narrow > 1.5 * whole  # 25 sweeps of each row where there was one
    limit = (whole + narrow) / 2 / default_threads()
    with pytest.raises(bg.BananagridError, match=r"CAT: 40,000 cells in tiles would take about .* max_seconds=S"):
        rasterise_tiles(model, grid, chunks=(grid.ny, 8), skip=False, max_seconds=limit)
    rasterise_tiles(model, grid, chunks=(grid.ny, grid.nx), skip=False, max_seconds=limit)  # lazy: nothing runs


def test_a_grid_over_the_in_memory_limit_is_refused_in_memory_but_tiles():
    grid = bg.Grid.from_bounds(x=(0.0, 32768.0), y=(0.0, 16384.0), step=1.0)  # 2**29 cells
    with pytest.raises(bg.BananagridError, match=r"limit in memory is 268,435,456 cells .* compute it in tiles"):
        bg.rasterise(MODELS["butterly"], grid)
    assert bg.rasterise(MODELS["butterly"], grid, chunks=4096).values.shape == (16384, 32768)


def test_zarr_round_trip_of_a_geographic_scene(tmp_path):
    scene = bg.load_scene(example_path("geo_ship")).with_step(200.0)
    panels = tiled_maps(scene, 64)
    store = write_zarr(tmp_path / "ship.zarr", panels, scene.geo, title=scene.title)
    in_memory = [(layer, t, tiled.compute()) for layer, t, tiled in panels]
    expected = raster_dataset(in_memory, scene.geo, title=scene.title)
    with xr.open_zarr(store) as got:
        assert set(expected.data_vars) <= set(got.data_vars) | set(got.coords)
        for name in expected.data_vars:
            if name.endswith("_mass"):
                np.testing.assert_allclose(got[name].values, expected[name].values, rtol=1e-12)  # summed in another order
            else:
                assert np.array_equal(got[name].values, expected[name].values), name
        for name in ("x", "y", "lat", "lon"):
            assert np.array_equal(got[name].values, expected[name].values), name
        assert got["crs"].attrs["crs_wkt"] == expected["crs"].attrs["crs_wkt"]
        assert got.attrs["bananagrid_grid"] == expected.attrs["bananagrid_grid"]
        layer = next(v for v in got.data_vars.values() if "bananagrid_layer" in v.attrs)
        assert '"tiles_skipped"' in layer.attrs["bananagrid_provenance"]
        assert layer.attrs["units"] == "m-2" and layer.attrs["grid_mapping"] == "crs"
    assert not list(tmp_path.glob(".*partial*"))


def test_a_failed_write_leaves_no_store_and_keeps_the_old_one(tmp_path, monkeypatch):
    store = tmp_path / "maps.zarr"
    tiled = bg.rasterise(MODELS["polar_improved"], GRID, chunks=CHUNKS)
    tiled.to_zarr(store)
    before = sorted(str(p.relative_to(store)) for p in store.rglob("*"))
    calls = []

    def failing(plan, rows, cols):
        calls.append(rows)
        if len(calls) > 3:
            raise OSError(28, "No space left on device")
        return np.ones((rows[1] - rows[0], cols[1] - cols[0]))

    monkeypatch.setattr(tiles, "block_values", failing)
    again = bg.rasterise(MODELS["cat"], GRID, chunks=CHUNKS)
    with dask.config.set(scheduler="threads"), pytest.raises(
            bg.BananagridError, match=r"maps.zarr: cannot write the Zarr store \(OSError: .*No space left on device"):
        again.to_zarr(store)
    assert sorted(str(p.relative_to(store)) for p in store.rglob("*")) == before
    assert [p.name for p in tmp_path.iterdir()] == ["maps.zarr"]


def _kill_workers_when_written(client, store_parent: Path, count: int, every: bool):
    """Kill one worker process (or every one) once ``count`` chunks of the store are on disk."""
    pids = client.run(os.getpid)

    def watch():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            partial = [p for p in store_parent.glob(".*partial") if p.is_dir()]
            if partial and sum(1 for p in partial[0].rglob("c/*/*/*") if p.is_file()) >= count:
                for pid in (pids.values() if every else list(pids.values())[:1]):
                    os.kill(pid, signal.SIGKILL)
                return
            time.sleep(0.01)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


def test_a_worker_killed_mid_run_does_not_change_the_store(client, tmp_path):
    model = MODELS["cat"]
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=8.0)
    reference = bg.rasterise(model, grid).values
    tiled = bg.rasterise(model, grid, chunks=32)
    watcher = _kill_workers_when_written(client, tmp_path, 20, every=False)
    store = tiled.to_zarr(tmp_path / "killed.zarr")
    watcher.join(5)
    assert not watcher.is_alive()
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it
    with xr.open_zarr(store) as ds:
        assert np.array_equal(ds.density.values[0], _as_tiled(tiled, reference))


def test_a_run_that_cannot_recover_leaves_no_store(tmp_path):
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with dask_client(workers=2, memory_limit="2GiB") as c:
            grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=8.0)
            tiled = bg.rasterise(MODELS["cat"], grid, chunks=32)
            watcher = _kill_workers_when_written(c, tmp_path, 10, every=True)
            with pytest.raises(bg.BananagridError, match=r"lost.zarr: cannot write the Zarr store \(KilledWorker"):
                tiled.to_zarr(tmp_path / "lost.zarr")
            watcher.join(5)
    assert list(tmp_path.iterdir()) == []


def test_sharded_batches_equal_the_single_process_batch(client):
    rng = np.random.default_rng(7)
    models = [bg.PolarBanana(v0=float(v), t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54,
                             pose=bg.Pose(origin=(float(x), float(y)), heading=float(h)))
              for v, x, y, h in zip(rng.uniform(100, 300, 700), rng.uniform(-1e4, 1e4, 700), rng.uniform(-1e4, 1e4, 700),
                                    rng.uniform(-math.pi, math.pi, 700))]
    reference = bg.rasterise_batch(models)
    sharded = bg.rasterise_batch_shards(models, shard=128)
    assert len(sharded.values.chunks[0]) == 6
    got = sharded.compute()
    assert np.array_equal(got.values, reference.values)
    assert np.array_equal(got.mass, reference.mass)
    assert got.grids == tuple(reference.grids)
    x, y = rng.uniform(-1e4, 1e4, 300), rng.uniform(-1e4, 1e4, 300)
    assert np.array_equal(bg.pdf_batch_shards(models, x, y, shard=100).compute(), bg.pdf_batch(models, x, y))


def test_a_sharded_batch_gathers_to_zarr(tmp_path):
    models = [bg.PolarBanana(v0=200.0 + k, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54) for k in range(50)]
    reference = bg.rasterise_batch(models, dtype=np.float32)
    store = bg.rasterise_batch_shards(models, shard=16, dtype=np.float32).to_zarr(tmp_path / "batch.zarr")
    with xr.open_zarr(store) as ds:
        assert np.array_equal(ds.density.values, reference.values)
        assert np.array_equal(ds.mass.values, reference.mass)
        assert np.array_equal(ds.bounds.values, np.array([[g.extent[0], g.extent[1], g.extent[2], g.extent[3]]
                                                          for g in reference.grids]))


def test_memory_limits_and_workers_are_checked():
    assert check_memory_limit("4GiB") == 4 * 2**30
    with pytest.raises(bg.BananagridError, match=r'memory_limit = "lots": expected a positive size of memory per worker'):
        check_memory_limit("lots")
    with pytest.raises(bg.BananagridError, match=r"workers = 0: expected an integer >= 1"):
        with dask_client(workers=0):
            pass
    with pytest.raises(bg.BananagridError, match="give workers and memory_limit only for a local cluster"):
        with dask_client(workers=2, scheduler="tcp://127.0.0.1:1"):
            pass


def test_an_unreachable_scheduler_is_one_line(capsys, tmp_path):
    code = main(["run", "--example", "slow_contact", "--zarr", str(tmp_path / "s.zarr"), "--scheduler",
                 "tcp://127.0.0.1:9", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("bananagrid: error: --scheduler = tcp://127.0.0.1:9: connection refused") and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["--zarr", "X.zarr", "--example", "figure1", "--example", "figure8"], "--zarr X.zarr: writes one scene's store; 2 scenes given"),
    (["--zarr", "X.zarr", "--example", "figure1", "--netcdf"], "--zarr cannot be combined with --netcdf"),
    (["--zarr", "X.zarr", "--example", "figure1", "--threads", "2"], "--threads does not apply to --zarr"),
    (["--example", "figure1", "--workers", "2"], "--workers: only with --zarr"),
    (["--zarr", "X.zarr", "--example", "submarine", "--chunks", "100"], "chunks = (100, 100): rows 100 is not a multiple of 32"),
    (["--zarr", "X.zarr", "--example", "room_uniform"], "an [array] scene's angular cells are not a grid"),
])
def test_run_zarr_options_are_checked(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", *argv, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_run_zarr_writes_the_scene_and_prints_its_tiles(capsys, tmp_path):
    store = tmp_path / "figure1.zarr"
    assert main(["run", "--example", "figure1", "--step", "16", "--zarr", str(store), "--chunks", "64",
                 "--workers", "2", "--memory-limit", "1GiB", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "cells computed" in out and f"wrote {store}" in out
    scene = bg.load_scene(example_path("figure1")).with_step(16.0)
    with xr.open_zarr(store) as ds:
        for layer, t in scene.jobs():
            model = layer.model(t)
            reference = bg.rasterise(model, scene.grid).values
            tiled = bg.rasterise(model, scene.grid, chunks=64)
            assert np.array_equal(ds[layer.name].sel(elapsed=t).values, _as_tiled(tiled, reference)), layer.name


def test_run_zarr_on_an_existing_cluster_by_address(client, capsys, tmp_path):
    store = tmp_path / "submarine.zarr"
    address = client.scheduler.address
    assert main(["run", "--example", "submarine", "--step", "2000", "--zarr", str(store), "--scheduler", address]) == 0
    captured = capsys.readouterr()
    assert f"tiles on {address}" in captured.err  # where it ran, on stderr with the progress
    assert f"wrote {store}" in captured.out
    scene = bg.load_scene(example_path("submarine")).with_step(2000.0)
    with xr.open_zarr(store) as ds:
        layer, t = scene.jobs()[0]
        model = layer.model(t)
        expected = _as_tiled(bg.rasterise(model, scene.grid, chunks=1024), bg.rasterise(model, scene.grid).values)
        assert np.array_equal(ds[layer.name].sel(elapsed=t).values, expected)


@pytest.mark.parametrize("kind", ["polar", "cat", "butterly", "bearing"])
def test_cell_probabilities_in_tiles_are_the_whole_grids(kind):
    """``quantity="probability"`` in blocks equals ``rasterise(..., quantity="probability")`` on
    the whole grid to rounding (each cell's rule is its own; the sums run in another order on a
    block): within 1e-13 of the largest cell (measured at most 8e-15), skipped blocks included."""
    fig1 = dict(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)
    model = {"polar": lambda: bg.PolarBanana(**fig1, variant="improved"), "cat": lambda: bg.CAT(**fig1),
             "butterly": lambda: bg.Butterly(mean=(0.0, 1500.0), cov=[[4e4, 0.0], [0.0, 9e4]], speeds=[5.0, 8.0],
                                             weights=[0.5, 0.5], t=100.0),
             "bearing": lambda: bg.BearingFix(sensors=[(-2000.0, 0.0), (2000.0, 0.0)], bearings=[0.6, -0.6],
                                              sigmas=[0.02, 0.02])}[kind]()
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=50.0)
    whole = bg.rasterise(model, grid, quantity="probability").values
    tiled = rasterise_tiles(model, grid, chunks=(32, 64), quantity="probability")
    assert tiled.quantity == "probability" and tiled.provenance["quantity"] == "probability"
    np.testing.assert_allclose(tiled.values.compute(), whole, rtol=0, atol=1e-13 * whole.max())
    with pytest.raises(bg.BananagridError, match='quantity = "mass"'):
        rasterise_tiles(model, grid, chunks=32, quantity="mass")
