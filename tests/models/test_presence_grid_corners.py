"""A mixture's exact cell probabilities on a grid, with the corners shared between cells.

``grid_probabilities`` evaluates each corner's tail orthant once per component and lets its four
cells share it (cells holding a mean's coordinate stay per cell). Checked here over the class of
components (variances from 1e-3 to 1e3 cells, correlations from 0 to within 1e-6 of +-1, means
inside the grid and up to a thousand SDs outside, grids of one cell to 8 x 8):

* against an independent float64 oracle (SciPy ``quad`` of the normal density times the
  conditional interval probability, written from the law alone), to the documented 1e-9
  relative or 1e-15 absolute per cell;
* against the per-cell form (``rectangle_probabilities``: four orthants chosen per cell), bit for
  bit on the CPU, whatever the threads.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st
from scipy import integrate, special

import bananagrid as bg
import bananagrid.models.presence as presence

#: The sweeps' fixed seed (a derandomised sweep's examples depend on the checkout's path).
SWEEP_SEED = 20261127

#: The per-cell guarantee of grid_probabilities (docs/guide/presence.md): 1e-9 relative or 1e-15
#: absolute, whichever is larger.
REL, ABS = 1e-9, 1e-15

_GL_X, _GL_W = np.polynomial.legendre.leggauss(20)


def _normal_interval(u0: float, u1: float) -> float:
    """Phi(u1) - Phi(u0) for u0 <= u1 in float64: from the tail away from zero (no difference of
    two numbers near one); a short interval by 20-point Gauss-Legendre of the density itself,
    where the CDF difference would cancel (the density varies by at most e^0.5 over it, so the
    rule is exact to rounding)."""
    if (u1 - u0) * (1.0 + max(abs(u0), abs(u1))) < 0.5:
        mid, half = 0.5 * (u0 + u1), 0.5 * (u1 - u0)
        u = mid + half * _GL_X
        return float(half * np.sum(_GL_W * np.exp(-0.5 * u * u)) / math.sqrt(2.0 * math.pi))
    if u0 >= 0.0:
        return float(special.ndtr(-u0) - special.ndtr(-u1))
    if u1 <= 0.0:
        return float(special.ndtr(u1) - special.ndtr(u0))
    return float(1.0 - special.ndtr(u0) - special.ndtr(-u1))


def oracle_rectangle(x0, x1, y0, y1, mean, cov) -> float:
    """P(x0 < X < x1, y0 < Y < y1) for X, Y ~ N(mean, cov), independent of the kernels:

        P = int_{a0}^{a1} phi(u) [Phi((b1 - r u) / s) - Phi((b0 - r u) / s)] du,  s = sqrt(1 - r^2),

    over the standardised edges (Y given X = u is N(r u, s^2)), by ``scipy.integrate.quad`` to
    1e-13 relative or 1e-22 absolute, with the conditional mean's crossings of the y edges as
    break points. u is cut to +-40 (phi beyond is below 1e-347, zero in float64) and, for r != 0,
    to where the conditional mean lies within 12 s of [b0, b1] (beyond, the bracket is below
    Q(12) = 1.8e-33): both far below the 1e-15 the test allows."""
    sx, sy = math.sqrt(cov[0][0]), math.sqrt(cov[1][1])
    r = cov[0][1] / (sx * sy)
    a0, a1 = (x0 - mean[0]) / sx, (x1 - mean[0]) / sx
    b0, b1 = (y0 - mean[1]) / sy, (y1 - mean[1]) / sy
    s = math.sqrt((1.0 - r) * (1.0 + r))
    lo, hi = max(a0, -40.0), min(a1, 40.0)
    if r != 0.0:
        w0, w1 = sorted(((b0 - 12.0 * s) / r, (b1 + 12.0 * s) / r))
        lo, hi = max(lo, w0), min(hi, w1)
    if not hi > lo:
        return 0.0

    def integrand(u):
        return math.exp(-0.5 * u * u) / math.sqrt(2.0 * math.pi) * _normal_interval((b0 - r * u) / s, (b1 - r * u) / s)

    points = sorted(p for p in ((b0 / r, b1 / r) if r != 0.0 else ()) if lo < p < hi)
    value, _ = integrate.quad(integrand, lo, hi, points=points or None, epsabs=1e-22, epsrel=1e-13, limit=400)
    return value


def _edges(grid: bg.Grid):
    """The grid's cell edges as grid_probabilities forms them (origin + step * k)."""
    x0, _, y0, _ = grid.extent
    return x0 + grid.dx * np.arange(grid.nx + 1), y0 + grid.dy * np.arange(grid.ny + 1)


#: Correlations: Genz's three Gauss-Legendre rules (|r| < 0.3, < 0.75, < 0.925), his expansion
#: about +-1 (at and beyond 0.925, up to 1e-6 from it), r = 0 (a product) and the rule borders.
CORRELATIONS = st.one_of(
    st.sampled_from([0.0, 1e-12, -1e-12, 0.3, -0.3, 0.75, -0.75, 0.925, -0.925, 0.999999, -0.999999]),
    st.floats(-0.999999, 0.999999),
)


@st.composite
def component_and_grid(draw):
    """One component and a grid about it: SDs from 1e-3 to 1e3 cells on each axis, any
    correlation, the grid's centre from the mean by up to 8 SDs on each axis (3 in 4) or by 50
    to 1000 (a mean far outside), 1 to 8 cells a side."""
    nx, ny = draw(st.integers(1, 8)), draw(st.integers(1, 8))
    dx, dy = 10.0 ** draw(st.floats(-1.0, 1.0)), 10.0 ** draw(st.floats(-1.0, 1.0))
    sx = dx * 10.0 ** draw(st.floats(-3.0, 3.0))
    sy = dy * 10.0 ** draw(st.floats(-3.0, 3.0))
    r = draw(CORRELATIONS)
    far = st.one_of(st.floats(50.0, 1000.0), st.floats(-1000.0, -50.0))
    offsets = st.one_of(st.floats(-3.0, 3.0), st.floats(-8.0, 8.0), st.floats(-3.0, 3.0), far)  # 3 in 4 near
    mean = (draw(st.floats(-5.0, 5.0)), draw(st.floats(-5.0, 5.0)))
    centre = (mean[0] + draw(offsets) * sx, mean[1] + draw(offsets) * sy)
    grid = bg.Grid(origin=(centre[0] - 0.5 * nx * dx, centre[1] - 0.5 * ny * dy), dx=dx, dy=dy, nx=nx, ny=ny)
    cov = [[sx * sx, r * sx * sy], [r * sx * sy, sy * sy]]
    return mean, cov, grid


SWEEP = settings(max_examples=60, deadline=None, derandomize=False, database=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def _mixture_or_none(means, covs, weights):
    try:
        return bg.GaussianMixture(weights=weights, means=means, covs=covs)
    except bg.BananagridError:  # a covariance past the condition limit: refused at the edge
        return None


@seed(SWEEP_SEED)
@SWEEP
@given(component_and_grid(), component_and_grid(), st.floats(0.0, 1.0))
def test_grid_cells_match_an_independent_oracle(first, second, weight):
    """Two components (weights w, 1 - w; the second's means and covariance on the first's
    grid): every cell within 1e-9 relative or 1e-15 absolute of the oracle."""
    (m1, c1, grid), (m2, c2, _) = first, second
    mixture = _mixture_or_none([m1, m2], [c1, c2], [weight, 1.0 - weight])
    if mixture is None:
        return
    got = bg.grid_probabilities(mixture, grid).probability
    xe, ye = _edges(grid)
    for i in range(grid.ny):
        for j in range(grid.nx):
            want = sum(w * oracle_rectangle(xe[j], xe[j + 1], ye[i], ye[i + 1], m, c)
                       for w, m, c in zip(mixture.weights, mixture.means, mixture.covs) if w > 0.0)
            assert abs(got[i, j] - want) <= max(REL * want, ABS), (i, j, got[i, j], want)


def _per_cell(mixture, grid, monkeypatch) -> np.ndarray:
    """The per-cell form: each cell's four orthants chosen by the cell (bvn_rectangle through
    ``rectangle_probabilities``), summed over the components in the kernel's order, then the
    rounding clip once, as grid_probabilities does (the per-component clip is lifted)."""
    xe, ye = _edges(grid)
    x0, y0 = np.meshgrid(xe[:-1], ye[:-1])
    x1, y1 = np.meshgrid(xe[1:], ye[1:])
    total = np.zeros(x0.shape)
    monkeypatch.setattr(presence, "clip_rounding", lambda p, what: p)
    for w, m, c in zip(mixture.weights, mixture.means, mixture.covs):
        sx, sy = math.sqrt(c[0, 0]), math.sqrt(c[1, 1])
        lims = np.stack([(x0 - m[0]) / sx, (x1 - m[0]) / sx, (y0 - m[1]) / sy, (y1 - m[1]) / sy,
                         np.full(x0.shape, c[0, 1] / (sx * sy))], axis=-1).reshape(-1, 5)
        total = total + w * presence.rectangle_probabilities(lims).reshape(x0.shape)
    monkeypatch.undo()
    return np.maximum(total, 0.0)


@seed(SWEEP_SEED)
@settings(max_examples=40, deadline=None, derandomize=False, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(component_and_grid(), component_and_grid(), st.floats(0.0, 1.0), st.integers(1, 5), st.integers(1, 5))
def test_shared_corners_are_the_per_cell_form_bit_for_bit(monkeypatch, first, second, weight, wide, tall):
    """The shared corners change no bit: every cell equals the per-cell form's, on one thread
    and on two (other bands, so other tiles' extra rows of corners), on grids up to 40 x 40."""
    (m1, c1, grid), (m2, c2, _) = first, second
    mixture = _mixture_or_none([m1, m2], [c1, c2], [weight, 1.0 - weight])
    if mixture is None:
        return
    grid = bg.Grid(origin=grid.origin, dx=grid.dx, dy=grid.dy, nx=grid.nx * wide, ny=grid.ny * tall)
    want = _per_cell(mixture, grid, monkeypatch)
    for threads in (1, 2):
        got = bg.grid_probabilities(mixture, grid, threads=threads).probability
        bad = got != want
        assert not bad.any(), (threads, np.argwhere(bad)[:3], got[bad][:3], want[bad][:3])


@pytest.mark.parametrize("side", [1, 3, 8])
def test_gpu_tiles_are_the_per_cell_form_bit_for_bit(monkeypatch, side):
    """The GPU's layout (one launch of small square tiles, each thread its own row of corners
    below) run on the CPU: tiles of 1, 3 and 8 cells a side, partial tiles at the grid's
    edges, bit for bit the per-cell form (as the bands are)."""
    mixture = bg.GaussianMixture(weights=[0.6, 0.4], means=[[0.3, -0.2], [-1.1, 0.9]],
                                 covs=[[[0.4, 0.3], [0.3, 0.5]], [[0.2, -0.19], [-0.19, 0.2]]])
    grid = bg.Grid(origin=(-2.0, -1.5), dx=0.21, dy=0.17, nx=19, ny=17)
    want = _per_cell(mixture, grid, monkeypatch)
    tiles = presence._grid_tiles
    monkeypatch.setattr(presence, "_grid_tiles", lambda grid, bands, _=None: tiles(grid, None, side))
    assert np.array_equal(bg.grid_probabilities(mixture, grid).probability, want)


def test_bench_grid_is_the_per_cell_form_bit_for_bit(monkeypatch):
    """The bench's 8-component mixture (bananagrid bench's presence-grid row) on its room at
    256 x 256 cells, and the room of test_presence with a rho = 0.98 desk: bit for bit."""
    rng = np.random.default_rng(20261121)  # the bench row's seed
    sd = rng.uniform(0.1, 0.6, (8, 2))
    rho = rng.uniform(-0.8, 0.8, 8)
    covs = [[[a * a, r * a * b], [r * a * b, b * b]] for (a, b), r in zip(sd, rho)]
    bench = bg.GaussianMixture(weights=np.full(8, 1 / 8), means=rng.uniform(-2.5, 2.5, (8, 2)), covs=covs)
    room = bg.GaussianMixture(
        weights=[0.35, 0.25, 0.25, 0.15], means=[[1.2, 0.8], [-1.5, 1.0], [0.4, -1.3], [2.5, -2.0]],
        covs=[[[0.09, 0.0], [0.0, 0.09]], [[0.5, 0.49], [0.49, 0.5]], [[0.2, 0.05], [0.05, 0.1]],
              [[0.02, 0.0], [0.0, 0.3]]])
    grid = bg.Grid.from_bounds(x=(-3.0, 3.0), y=(-2.5, 2.5), dx=6.0 / 256, dy=5.0 / 256)
    for mixture in (bench, room):
        got = bg.grid_probabilities(mixture, grid)
        assert np.array_equal(got.probability, _per_cell(mixture, grid, monkeypatch))
        assert got.provenance["kernel"] == "presence.grid_cells"


@pytest.mark.parametrize("r", [0.0, 0.5, -0.95])
def test_one_cell_and_one_row_grids(r):
    """Grids of one cell, one row and one column (a tile of one row of corners above another,
    or one column) against the oracle; the single cell holding the mean takes the per-cell form."""
    cov = [[0.5, r * math.sqrt(0.5) * 0.3], [r * math.sqrt(0.5) * 0.3, 0.09]]
    mixture = bg.GaussianMixture([1.0], [[0.1, -0.2]], [cov])
    for nx, ny in [(1, 1), (7, 1), (1, 7)]:
        grid = bg.Grid(origin=(-0.9, -0.7), dx=0.4, dy=0.3, nx=nx, ny=ny)
        got = bg.grid_probabilities(mixture, grid, threads=2).probability
        xe, ye = _edges(grid)
        for i in range(ny):
            for j in range(nx):
                want = oracle_rectangle(xe[j], xe[j + 1], ye[i], ye[i + 1], [0.1, -0.2], cov)
                assert abs(got[i, j] - want) <= max(REL * want, ABS), (nx, ny, i, j, got[i, j], want)
