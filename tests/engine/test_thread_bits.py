"""Every output is the same bits for any number of threads.

The engine splits rows into bands, one launch each, as many as the threads allow; a sum taken
band by band (the captured mass, a batch's per-hypothesis sums) would then depend on where the
bands begin. Each row (each hypothesis) is summed on its own and the rows' sums added exactly,
so values, masses and normalised values must be equal byte for byte between 1 and any number of
threads, for every registered model kind (the contract table of ``tests/models/test_contract.py``),
both dtypes and grids of 1 row, of prime row counts, and of more Butterly tiles than bands; the
presence laws (kinds of the array domain) on their angular lattices, whose cells are bands too.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine import grid_kernel
from bananagrid.engine.batch import rasterise_batch
from bananagrid.engine.warp_runtime import row_sums

from test_contract import ARRAY_CASES, GRID_CASES
from test_contract import CASES as EVERY_CASE

#: The grid kinds' cases (the array kinds' are swept on their lattices below).
CASES = {name: EVERY_CASE[name] for name in GRID_CASES}

THREADS = (2, 3, 5, 8)
#: Row counts: one row, primes (bands of unequal sizes for every thread count), and 257 rows
#: (9 Butterly tiles of 32 rows, so 1, 2 and 3 threads cut them into different bands).
ROWS = (1, 2, 7, 13, 31, 97, 257)
COLUMNS = (1, 3, 17, 64)
DTYPES = (np.float64, np.float32)
#: CAT with heading noise builds its table (about a second) in every call: fewer calls of it.
SLOW = {"cat-heading": {np.float64: (3, 8), np.float32: (5,)}}


@pytest.fixture(scope="module", autouse=True)
def bands_on_every_grid():
    """Grids this small run as one band on the calling thread (``grid_kernel.SERIAL_CELLS``):
    here they are cut into bands for every thread count, as a large grid is."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(grid_kernel, "SERIAL_CELLS", 0)
        yield


def _same(a, b) -> bool:
    """Equal byte for byte (NaN-safe, -0.0 distinct from 0.0)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _grid(case, ny, nx):
    (x0, x1), (y0, y1) = case.bounds["x"], case.bounds["y"]
    return bg.Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / nx, dy=(y1 - y0) / ny)


@pytest.mark.parametrize("name", [name for name in CASES if name not in SLOW])
@settings(max_examples=6, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(ny=st.sampled_from(ROWS), nx=st.sampled_from(COLUMNS), dtype=st.sampled_from(DTYPES),
       threads=st.sampled_from(THREADS))
def test_densities_masses_and_normalised_values(name, ny, nx, dtype, threads):
    case = CASES[name]
    model, grid = case.model(), _grid(case, ny, nx)
    one = bg.rasterise(model, grid, dtype=dtype, threads=1)
    many = bg.rasterise(model, grid, dtype=dtype, threads=threads)
    assert _same(many.values, one.values), (name, grid.shape, threads)
    assert _same(many.mass, one.mass), (name, grid.shape, threads, many.mass, one.mass)
    if one.mass > 0.0:
        assert _same(many.normalise().values, one.normalise().values)


@pytest.mark.parametrize("name", CASES)
def test_every_kind_on_a_prime_grid_for_every_thread_count(name):
    """The table's whole sweep on one grid of 97 x 53 cells (97 rows: bands of unequal sizes),
    both dtypes: nothing left to the draws above."""
    case = CASES[name]
    model, grid = case.model(), _grid(case, 97, 53)
    for dtype in DTYPES:
        one = bg.rasterise(model, grid, dtype=dtype, threads=1)
        for threads in SLOW.get(name, {}).get(dtype, THREADS):
            many = bg.rasterise(model, grid, dtype=dtype, threads=threads)
            assert _same(many.values, one.values) and _same(many.mass, one.mass), (name, dtype, threads)


def test_butterly_tiles_do_not_follow_the_bands():
    """A Butterly on 1031 rows (33 tiles of 32 rows) of 7 columns: 1 thread cuts 16 bands, 2
    threads 32, 3 and more 33; the tiles are the grid's, never the bands', so every value is the
    same bits."""
    case = CASES["butterly"]
    model = case.model()
    grid = bg.Grid.from_bounds(x=(-400.0, 400.0), y=(-2500.0, 2500.0), dx=800.0 / 7, dy=5000.0 / 1031)
    for dtype in DTYPES:
        one = bg.rasterise(model, grid, dtype=dtype, threads=1)
        assert one.mass > 0.1
        for threads in (2, 3, 8):
            many = bg.rasterise(model, grid, dtype=dtype, threads=threads)
            assert _same(many.values, one.values) and _same(many.mass, one.mass), (dtype, threads)


@pytest.mark.parametrize("name", ["polar-rough", "polar-heading", "bearing_fix", "butterly", "isotropic"])
def test_cell_probabilities(name):
    """Cell probabilities on a grid by the engine's quadrature, whose nodes are evaluated in
    chunks sized by the thread count (the CAT's own rule: tests/engine/test_cell_probabilities.py)."""
    case = CASES[name]
    model, grid = case.model(), _grid(case, 7, 5)
    for dtype in DTYPES:
        one = bg.rasterise(model, grid, quantity="probability", dtype=dtype, threads=1)
        for threads in (2, 5):
            many = bg.rasterise(model, grid, quantity="probability", dtype=dtype, threads=threads)
            assert _same(many.values, one.values) and _same(many.mass, one.mass), (name, dtype, threads)


@pytest.mark.parametrize("name", ["polar-rough", "isotropic"])
def test_polar_lattices(name):
    case = CASES[name]
    model, lattice = case.model(), bg.PolarLattice(**case.lattice)
    for dtype in DTYPES:
        one = bg.rasterise(model, lattice, dtype=dtype, threads=1)
        for threads in (2, 5):
            many = bg.rasterise(model, lattice, dtype=dtype, threads=threads)
            assert _same(many.density, one.density) and _same(many.probability, one.probability)
            assert _same(many.mass, one.mass)
            assert _same(many.normalise().probability, one.normalise().probability)


def test_batch_sums():
    """A batch's per-hypothesis sums (its masses) and values: 37 hypotheses in bands of 4 per
    thread."""
    rng = np.random.default_rng(3)
    models = [bg.PolarBanana(v0=float(v), t=10.0, sigma_a=1.5, sigma_omega=0.05, variant="improved",
                             pose=bg.Pose(origin=(float(x), 0.0), heading=float(h)))
              for v, x, h in zip(rng.uniform(50, 300, 37), rng.uniform(-1e3, 1e3, 37), rng.uniform(-3, 3, 37))]
    for dtype in DTYPES:
        one = rasterise_batch(models, shape=(13, 29), dtype=dtype, threads=1)
        for threads in THREADS:
            many = rasterise_batch(models, shape=(13, 29), dtype=dtype, threads=threads)
            assert _same(many.values, one.values) and _same(many.mass, one.mass), (dtype, threads)


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(ny=st.integers(1, 40), nx=st.sampled_from([1, 2, 7, 128, 129, 8191, 8193, 20000]),
       dtype=st.sampled_from(DTYPES), cut=st.integers(0, 40), seed=st.integers(0, 2**16))
def test_row_sums_of_a_band_are_those_of_the_whole(ny, nx, dtype, cut, seed):
    """The property the sums rest on: a row's sum does not depend on the rows sliced with it
    (rows longer than NumPy's 8192-element cast buffer included), and equals the row's own."""
    rng = np.random.default_rng(seed)
    values = (rng.random((ny, nx)) * 10.0 ** rng.uniform(-30, 30, (ny, nx))).astype(dtype)
    whole = row_sums(values)
    a = min(cut, ny - 1)
    assert _same(np.concatenate([row_sums(values[:a]), row_sums(values[a:])]), whole)
    k = a
    assert _same(row_sums(values[k:k + 1]), np.array([np.sum(values[k], dtype=np.float64)]))
    assert whole.dtype == np.float64 and whole.shape == (ny,)
    # the mass is their exact sum: the order of the rows cannot matter
    assert math.fsum(whole[::-1]) == math.fsum(whole)


@pytest.mark.parametrize("name", ARRAY_CASES)
def test_angular_cells(name):
    """A presence law's cells on its angular lattice, conditioned on its room: the kernels' cell
    bands (and the uniform law's exact geometry) give the same bits for any thread count."""
    case = EVERY_CASE[name]
    model, lattice, region = case.model(), case.angular, case.region
    for dtype in DTYPES:
        one = bg.rasterise(model, lattice, region=region, dtype=dtype, threads=1)
        for threads in (2, 5):
            many = bg.rasterise(model, lattice, region=region, dtype=dtype, threads=threads)
            assert _same(many.prob, one.prob) and _same(many.error, one.error), (name, dtype, threads)


@pytest.mark.parametrize("name", CASES)
def test_small_grids_on_one_thread_are_the_bits_of_the_bands(name):
    """A grid of at most ``SERIAL_CELLS`` cells runs as one band on the calling thread: the
    same values and mass as the same grid cut into bands on 3 threads, both dtypes."""
    case = CASES[name]
    grid = _grid(case, 31, 17)
    for dtype in DTYPES:
        model = case.model()
        banded = bg.rasterise(model, grid, dtype=dtype, threads=3)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(grid_kernel, "SERIAL_CELLS", 31 * 17)
            serial = bg.rasterise(model, grid, dtype=dtype, threads=3)
        assert _same(serial.values, banded.values), (name, dtype)
        assert _same(serial.mass, banded.mass), (name, dtype)
