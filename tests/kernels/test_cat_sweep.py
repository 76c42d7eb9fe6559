"""The CAT grid kernel's row sweep (``kernels/cat_lanes.py``: the scan swept along each row, single
roots searched a vector of lanes at a time) against the points kernel, which scans every node of
each point, bit for bit, and against the per-cell scalar kernel (the GPU path's) to the lane
search's rounding, on the grids that are hard for it: cells far smaller than the bands around
each interval's lines, rows crossing the lines at every angle (lines parallel to the rows
included), float32 far from the origin, and the folds at large turn noise; and rows whose
centres are not sorted (the per-cell fallback)."""

import math

import numpy as np
import warp as wp
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.kernels import cat, cat_lanes, lanes
from bananagrid.models import _cat_heading as heading

from cat_lane_roots import lane_roots_agree


def _scalar_points(model, ctx, binding, x, y):
    """The scalar kernel (``cat.KERNELS.points``, the GPU path's) at the points, with the lane
    binding's parameters (less the node groups), in ``ctx``'s dtype."""
    out = ctx.zeros(x.size)
    params = cat.CAT.of(ctx.scalar_type)()
    for name in cat.CAT.fields:
        setattr(params, name, getattr(binding.params, name))
    wp.launch(cat.KERNELS.points, dim=x.size, device="cpu",
              inputs=[ctx.array(x.ravel()), ctx.array(y.ravel()), 0, params, out])
    return out.numpy().reshape(x.shape)


@st.composite
def _sweep_cases(draw):
    """An exact CAT over the domain (speeds 1-1000 m/s, times to 10 min, acceleration noise 0.1-20 %
    of the speed per second, turn noise 1e-3 to 2 rad over the time: folds, and lines at every
    angle to the rows) and a grid of 40-90 columns by 20-40 rows about its banana, from a tenth of
    its range (cells far smaller than the bands) to twice it, placed up to 1e6 m away."""
    v0, t = draw(st.floats(1.0, 1000.0)), draw(st.floats(1.0, 600.0))
    accel, turn = draw(st.floats(0.1, 20.0)), draw(st.floats(1e-3, 2.0))
    far = draw(st.sampled_from([0.0, 1e4, 1e6]))
    origin = (draw(st.floats(-1.0, 1.0)) * far, draw(st.floats(-1.0, 1.0)) * far)
    heading = draw(st.floats(-math.pi, math.pi))
    model = bg.CAT(v0=v0, t=t, sigma_a=accel * v0 / 100.0, sigma_omega=turn / t,
                   pose=bg.Pose(origin=origin, heading=heading))
    reach = draw(st.floats(0.1, 2.0)) * v0 * t
    # a window about a point of the banana (the fix, or v0 t ahead along the heading)
    ahead = draw(st.floats(0.0, 1.0)) * v0 * t
    cx, cy = origin[0] + ahead * math.sin(heading), origin[1] + ahead * math.cos(heading)
    nx, ny = draw(st.integers(40, 90)), draw(st.integers(20, 40))
    grid = bg.Grid.from_bounds(x=(cx - reach, cx + reach), y=(cy - reach, cy + reach), dx=2 * reach / nx,
                               dy=2 * reach / ny)
    return model, grid


@seed(20261127)
@settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=_sweep_cases())
def test_row_sweep_equals_the_per_cell_scan(case):
    """rasterise (the sweep) equals the points kernel (``pdf``: every node of each point scanned)
    at every cell centre bit for bit, in both dtypes: the sweep's bands hold every cell that the
    scan flags (or a bit would differ: a missed interval drops a root), and both search the same
    roots with the same lane search, each cell's roots summed in node order. The scalar per-cell
    kernel agrees to the lane search's rounding (``cat_lane_roots``)."""
    model, grid = case
    x, y = np.meshgrid(grid.x, grid.y)
    for dtype in (np.float64, np.float32):
        raster = bg.rasterise(model, grid, dtype=dtype, threads=1, min_mass=0.0)
        computed = np.dtype(raster.provenance["computed_in"]).type  # float32 far out: float64
        ctx = WarpContext(computed, "cpu", 1)
        binding = model.bind(ctx, None, grid=True)
        assert binding.kernels.grid.key == "cat_grid_lanes"
        points = model.pdf(x, y, dtype=computed).astype(dtype)
        assert np.array_equal(raster.values, points), int(np.sum(raster.values != points))
        scalar = _scalar_points(model, ctx, binding, x, y).astype(dtype)
        agree = lane_roots_agree(raster.values, scalar)
        assert np.all(agree), (int(np.sum(~agree)), np.abs(raster.values - scalar).max())


def test_the_sweep_finds_roots_on_most_cells_of_the_figure_1_frame():
    """A guard that the bit-for-bit test compares something: on the Figure 1 frame at 40 m most
    cells hold a root within 38 sigma_a (the sweep's work), and the map integrates to about 1
    (paper Figure 1's banana lies inside the frame; the midpoint rule at 40 m is good to 1e-3)."""
    model = bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=40.0)
    raster = bg.rasterise(model, grid, threads=1)
    assert np.count_nonzero(raster.values) > 0.5 * raster.values.size
    assert abs(raster.mass - 1.0) < 1e-3


def test_unsorted_centres_take_the_per_cell_scan():
    """A row whose centres are not sorted (the grid kernel launched on reversed and shuffled
    columns) is computed cell by cell (the points kernel's density), and equals ``pdf`` there
    bit for bit and the scalar kernel to the lane search's rounding."""
    model = bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 20)
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=100.0)
    rng = np.random.default_rng(7)
    xs = rng.permutation(grid.x)
    ctx = WarpContext(np.float64, "cpu", 1)
    binding = model.bind(ctx, None, grid=True)
    out = ctx.zeros((grid.ny, grid.nx))
    ctx.load(binding.kernels.grid)
    wp.launch(binding.kernels.grid, dim=(grid.ny, 1), device="cpu",
              inputs=[ctx.array(xs), ctx.array(grid.y), 0, grid.nx, binding.params, out])
    x, y = np.meshgrid(xs, grid.y)
    scalar = _scalar_points(model, ctx, binding, x, y)
    assert np.count_nonzero(scalar) > 0
    assert np.array_equal(out.numpy(), model.pdf(x, y))
    assert np.all(lane_roots_agree(out.numpy(), scalar))
    assert binding.kernels.grid is cat_lanes.KERNELS.grid  # the row sweep's generated grid kernel


@st.composite
def _ray_cases(draw):
    """A plain CAT over the sweep's domain (as :func:`_sweep_cases`) and a polar lattice of its
    local frame: 1-80 ranges from the fix (0 included or not) to twice v0 t, in order or shuffled
    (the lattice sorts them), spaced from a hundredth of the range to all of it, and 12-40 bearings
    anywhere on the circle, the nominal heading and its reverse among them."""
    v0, t = draw(st.floats(1.0, 1000.0)), draw(st.floats(1.0, 600.0))
    accel, turn = draw(st.floats(0.1, 20.0)), draw(st.floats(1e-3, 2.0))
    model = bg.CAT(v0=v0, t=t, sigma_a=accel * v0 / 100.0, sigma_omega=turn / t)
    n_r = draw(st.integers(1, 80))
    start = draw(st.sampled_from([0.0, draw(st.floats(0.0, 1.5))])) * v0 * t
    step = draw(st.floats(0.01, 1.0)) * v0 * t / n_r
    radii = start + step * np.arange(n_r)
    if draw(st.booleans()):
        radii = np.random.default_rng(draw(st.integers(0, 100))).permutation(radii)
    n_theta = draw(st.integers(12, 40))
    theta = np.concatenate([[0.0, math.pi], np.random.default_rng(draw(st.integers(0, 100))).uniform(
        -math.pi, math.pi, n_theta - 2)])
    return model, radii, theta


@seed(20261128)
@settings(max_examples=30, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=_ray_cases())
def test_rays_equal_the_per_point_scan_bit_for_bit(case):
    """``cat_lanes.cat_rays`` (each bearing's ray swept as a grid row, what the heading table is
    built from: ``models/_cat_heading.plain_lattice``) equals ``pdf`` (the CPU points kernel) bit
    for bit at every lattice point (r sin theta, r cos theta): the turned frame gives the same local
    points, and the sweep the scan's roots, searched in the same lanes; and the scalar per-point
    kernel to the lane search's rounding."""
    model, radii, theta = case
    got = heading.plain_lattice(model, radii, theta, threads=2)
    ctx = WarpContext(np.float64, "cpu", 1)
    binding = model.bind(ctx, None, grid=True)
    x = radii[:, None] * np.sin(theta)[None, :]
    y = radii[:, None] * np.cos(theta)[None, :]
    assert np.array_equal(got, model.pdf(x, y)), int(np.sum(got != model.pdf(x, y)))
    assert np.all(lane_roots_agree(got, _scalar_points(model, ctx, binding, x, y)))


def test_rays_of_the_figure_1_lattice_find_the_banana():
    """A guard that the bit-for-bit test compares something: on the Figure 1 banana's heading
    lattice most points of the rays through it hold roots; and a ray of one range, or of a few as
    the heading tables' check rows, gives the long rays' values."""
    model = bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)
    radii = np.linspace(0.0, 3400.0, 32)
    theta = np.linspace(-math.pi, math.pi, 64, endpoint=False)
    rays = heading.plain_lattice(model, radii, theta, threads=1)
    assert np.count_nonzero(rays) > 0.3 * rays.size
    for few in (radii[5:6], radii[3:19:4]):
        assert np.array_equal(heading.plain_lattice(model, few, theta, threads=1), rays[np.isin(radii, few)])


def test_turns_beyond_the_lanes_reduction_take_the_scalar_search():
    """Node intervals at |omega t| beyond ``lanes.LANE_TURN_LIMIT`` (where the lanes' sine
    reduction would round) are searched by the scalar functions, in the sweep and at points
    alike: a CAT scanning 3,000 turns each way (k_sigma sigma_omega t = 2e4 rad) about its pose,
    where every interval's roots lie; the grid equals ``pdf`` bit for bit and the scalar kernel
    to the lane search's rounding."""
    model = bg.CAT(v0=10.0, t=100.0, sigma_a=0.5, sigma_omega=25.0)
    assert model.k_sigma * model.sigma_omega * model.t > 1.5 * lanes.LANE_TURN_LIMIT
    grid = bg.Grid.from_bounds(x=(-2.0, 2.0), y=(-2.0, 2.0), step=1.0)
    x, y = np.meshgrid(grid.x, grid.y)
    raster = bg.rasterise(model, grid, threads=1, min_mass=0.0)
    ctx = WarpContext(np.float64, "cpu", 1)
    binding = model.bind(ctx, None, grid=True)
    scalar = _scalar_points(model, ctx, binding, x, y)
    assert np.count_nonzero(scalar) == scalar.size
    assert np.array_equal(raster.values, model.pdf(x, y))
    assert np.all(lane_roots_agree(raster.values, scalar))
