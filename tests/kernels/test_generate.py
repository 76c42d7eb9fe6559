"""The launch-kernel generator: a family writes a density over a typed struct, and gets grid,
points and batch kernels (scalar and in CPU lanes) that the engine launches.

A family of the tests' own (a normal bump) is generated here with no launch code and run through
the engine's own layouts (row bands, point chunks, batch bands) for every shape, chunking and
dtype the sweep draws: every cell and point written once, grids equal to points bit for bit, and
values against a NumPy oracle."""

import importlib
from typing import Any

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine import batch as engine_batch
from bananagrid.engine.grid_kernel import grid_block
from bananagrid.engine.points import launch_points
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.kernels import cat
from bananagrid.kernels.common import each_mul
from bananagrid.kernels.generate import SCALAR, SCALARS, VEC4, Params, density_kernels
from bananagrid.kernels.lanes import each_exp, lane_count, lane_exp, load_lanes, store_lanes
from bananagrid.protocol import KernelBinding


@wp.func
def bump(x: Any, y: Any, p: Any):
    dx = x - p.centre[0]
    dy = y - p.centre[1]
    return p.scale * wp.exp((dx * dx + dy * dy) * p.minus_half_inv_var)


@wp.func
def bump_lanes(x: Any, y: Any, p: Any):
    dx = x - type(x)(p.centre[0])
    dy = y - type(x)(p.centre[1])
    return lane_exp((wp.cw_mul(dx, dx) + wp.cw_mul(dy, dy)) * p.minus_half_inv_var) * p.scale


@wp.func
def bump_generic(x: Any, y: Any, p: Any):
    """The bump written once, at a point or lane by lane at a vector of points."""
    dx = x - type(x)(p.centre[0])
    dy = y - type(x)(p.centre[1])
    return each_exp((each_mul(dx, dx) + each_mul(dy, dy)) * p.minus_half_inv_var) * p.scale


@wp.func
def bump_row(xs: wp.array(dtype=Any), y: Any, out: wp.array2d(dtype=Any), row: int, j0: int, j1: int, p: Any):
    """A family's own row: the rows at or north of the centre in a loop of its own (1), the others
    left to the generated loop (0)."""
    if y < p.centre[1]:
        return 0
    j = j0
    while j < j1:
        x = load_lanes(xs, j)
        store_lanes(out[row], j, bump_lanes(x, type(x)(y), p), j1 - j)
        j += lane_count(xs)
    return 1


@wp.func
def bump_row_mark(xs: wp.array(dtype=Any), y: Any, out: wp.array2d(dtype=Any), row: int, j0: int, j1: int,
                  p: Any):
    """Marks the rows at or north of the centre with -1 instead of the density: shows which rows
    the generated grid kernel left to the family's row."""
    if y < p.centre[1]:
        return 0
    for j in range(j0, j1):
        out[row, j] = type(y)(-1.0)
    return 1


BUMP = Params("BumpParams", __name__, centre=VEC4, minus_half_inv_var=SCALAR, scale=SCALAR)
SCALAR_KERNELS = density_kernels(bump, BUMP, "bump", batch=True, bands_per_thread=3)
LANE_KERNELS = density_kernels(bump_lanes, BUMP, "bump", lanes=True, batch=True)
FAMILIES = {"scalar": SCALAR_KERNELS, "lanes": LANE_KERNELS}
#: The generic bump's scalar and lane kernels and the two rows' families, each in a module of its
#: own (``module``): one build per dtype each, not a rebuild of this module's families
_ONCE = {"generic": {}, "generic_lanes": {"lanes": True}, "row": {"lanes": True, "row": bump_row},
         "mark": {"lanes": True, "row": bump_row_mark}}
for _family in _ONCE:
    wp.set_module_options({"enable_backward": False}, module=f"{__name__}_{_family}")
ONCE = {family: density_kernels(bump_lanes if "row" in options else bump_generic, BUMP, "bump",
                                module=f"{__name__}_{family}", **options) for family, options in _ONCE.items()}
DTYPES = {np.float64: "float64", np.float32: "float32"}


def _params(ctx, centre, sigma):
    return ctx.struct(BUMP, centre=(*centre, 0.0, 0.0), minus_half_inv_var=-0.5 / sigma**2,
                      scale=1.0 / (2.0 * np.pi * sigma**2))


def _oracle(x, y, centre, sigma):
    """The bump in float64 NumPy."""
    return np.exp(-0.5 * ((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / sigma**2) / (2.0 * np.pi * sigma**2)


class _Batch:
    """Hypotheses of the bump for the engine's batch path (its BatchModel capability)."""

    def __init__(self, centre, sigma, family):
        self.centre, self.sigma, self.family = centre, sigma, family

    @classmethod
    def frame_bounds(cls, models, sds):
        return np.array([(m.centre[0] - sds * m.sigma, m.centre[0] + sds * m.sigma, m.centre[1] - sds * m.sigma,
                          m.centre[1] + sds * m.sigma) for m in models])

    @classmethod
    def batch_binding(cls, ctx, models):
        centres = np.array([(*m.centre, 0.0, 0.0) for m in models])
        sigmas = np.array([m.sigma for m in models])
        params = ctx.structs(BUMP, len(models), centre=centres, minus_half_inv_var=-0.5 / sigmas**2,
                             scale=1.0 / (2.0 * np.pi * sigmas**2))
        return KernelBinding(models[0].family, params)


def test_generated_kernels_join_the_density_module_under_the_family_names():
    assert SCALAR_KERNELS.grid.module is bump.module and LANE_KERNELS.points.module is bump_lanes.module
    assert SCALAR_KERNELS.name == f"{bump.module.name.rsplit('.', 1)[-1]}.bump_grid"
    assert [k.key for k in (LANE_KERNELS.grid, LANE_KERNELS.points, LANE_KERNELS.batch_grid,
                            LANE_KERNELS.batch_points)] == ["bump_grid_lanes", "bump_points_lanes",
                                                            "bump_batch_grid_lanes", "bump_batch_points_lanes"]
    assert {BUMP.of(s).vars["scale"].type for s in SCALARS} == set(SCALARS)


def test_overloads_are_registered_on_first_use_for_that_dtype_only():
    """A module is built with the overloads registered in it, so none is registered before a
    context loads the kernel; loading one registers its dtype's overload (and the grid's with the
    points', launched side by side), taking that type's struct, and nothing else."""
    family = density_kernels(bump, BUMP, "bump_on_use", batch=True)
    kernels = (family.grid, family.points, family.batch_grid, family.batch_points)
    assert [len(k.overloads) for k in kernels] == [0, 0, 0, 0]
    for done, scalar in enumerate(SCALARS, start=1):
        ctx = WarpContext({wp.float32: np.float32, wp.float64: np.float64}[scalar], "cpu", 1)
        ctx.load(family.points)
        assert [len(k.overloads) for k in kernels] == [done, done, 0, 0]
        for kernel in (family.grid, family.points):
            structs = {a.label: a.type for a in list(kernel.overloads.values())[-1].adj.args}
            assert structs["p"] is BUMP.of(scalar)
        ctx.load(family.points)  # once
        assert len(family.points.overloads) == done
    WarpContext(np.float64, "cpu", 1).load(family.batch_points)
    assert [len(k.overloads) for k in kernels] == [2, 2, 0, 1]


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(nx=st.integers(1, 41), ny=st.integers(1, 9), n_points=st.integers(1, 70), threads=st.integers(1, 3),
       dtype=st.sampled_from(list(DTYPES)), family=st.sampled_from(list(FAMILIES)),
       centre=st.tuples(st.floats(-50.0, 50.0), st.floats(-50.0, 50.0)), sigma=st.floats(2.0, 40.0))
def test_generated_grid_and_points_cover_every_cell_and_agree(nx, ny, n_points, threads, dtype, family, centre,
                                                              sigma):
    """Every shape (row lengths that are not a multiple of the lane count, one-cell rows), band
    and chunk count: the grid kernel and the points kernel at the same cell centres give the same
    bits (one density function), and both the oracle's values."""
    ctx = WarpContext(dtype, "cpu", threads)
    binding = KernelBinding(FAMILIES[family], _params(ctx, centre, sigma))
    grid = bg.Grid(origin=(-60.0, -45.0), dx=120.0 / nx, dy=90.0 / ny, nx=nx, ny=ny)
    values = grid_block(ctx, binding, grid)
    x, y = np.meshgrid(grid.x, grid.y)
    ctx.load(binding.kernels.points)
    assert np.array_equal(launch_points(ctx, binding, x, y), values)
    rng = np.random.default_rng(n_points)
    px, py = rng.uniform(-60.0, 60.0, n_points), rng.uniform(-45.0, 45.0, n_points)
    points = launch_points(ctx, binding, px, py)
    # float64: exp's argument carries a few roundings of its size (<= 2e3 here) and exp's own;
    # float32: the same at eps32, and the inputs' float32 rounding moves the argument by
    # |arg| eps32 more; the lane exp is within 3 ulp of libm's (tests/kernels/test_lanes.py)
    eps = np.finfo(dtype).eps
    for got, gx, gy in ((values, x, y), (points, px, py)):
        reference = _oracle(gx.astype(dtype).astype(float), gy.astype(dtype).astype(float), centre, sigma)
        arg = 0.5 * ((gx - centre[0]) ** 2 + (gy - centre[1]) ** 2) / sigma**2
        normal = reference > np.finfo(dtype).tiny * 1e3
        rel = np.abs(got[normal] - reference[normal]) / reference[normal]
        assert np.all(rel <= 16 * eps * (1.0 + arg[normal])), (rel / (eps * (1.0 + arg[normal]))).max()
        assert np.all(np.abs(got[~normal]) <= 1e3 * np.finfo(dtype).tiny)


@pytest.mark.parametrize("dtype", list(DTYPES))
def test_lane_kernels_agree_with_the_scalar_kernels(dtype):
    """The two densities of one family, generated alike: the same cells within the lane exp's
    3 ulp of libm's (exp's argument is computed in the same order, lane by lane)."""
    grid = bg.Grid(origin=(-60.0, -45.0), dx=0.7, dy=0.9, nx=171, ny=100)
    out = {}
    for family, kernels in {**FAMILIES, **ONCE}.items():
        if family == "mark":
            continue
        ctx = WarpContext(dtype, "cpu", 2)
        out[family] = grid_block(ctx, KernelBinding(kernels, _params(ctx, (3.0, -4.0), 11.0)), grid)
    normal = out["scalar"] > np.finfo(dtype).tiny
    rel = np.abs(out["lanes"][normal].astype(float) - out["scalar"][normal]) / out["scalar"][normal]
    assert rel.max() <= 4 * np.finfo(dtype).eps, rel.max()


@pytest.mark.parametrize("dtype", list(DTYPES))
def test_a_density_written_once_gives_the_bits_of_its_scalar_and_lane_twins(dtype):
    """A density generic over a value and a vector of lanes (``each_mul``, ``each_exp``) generates
    scalar kernels with the scalar density's bits and lane kernels (in the module named for them)
    with the lane density's; a family's own row (``row``) gives the generated loop's bits."""
    assert ONCE["generic_lanes"].points.module.name == f"{__name__}_generic_lanes" != bump_generic.module.name
    assert ONCE["generic_lanes"].name == "test_generate_generic_lanes.bump_grid_lanes"
    grid = bg.Grid(origin=(-60.0, -45.0), dx=0.7, dy=0.9, nx=171, ny=100)
    rng = np.random.default_rng(4)
    px, py = rng.uniform(-60.0, 60.0, 333), rng.uniform(-45.0, 45.0, 333)
    out = {}
    for family, kernels in {**FAMILIES, **ONCE}.items():
        if family == "mark":
            continue
        ctx = WarpContext(dtype, "cpu", 2)
        binding = KernelBinding(kernels, _params(ctx, (3.0, -4.0), 11.0))
        ctx.load(kernels.points)
        out[family] = grid_block(ctx, binding, grid), launch_points(ctx, binding, px, py)
    for twin, family in (("scalar", "generic"), ("lanes", "generic_lanes"), ("lanes", "row")):
        for a, b in zip(out[twin], out[family]):
            assert np.array_equal(a, b), (twin, family)
    assert not np.array_equal(out["scalar"][0], out["lanes"][0])  # the two exps differ: the check can fail


@pytest.mark.parametrize("dtype", list(DTYPES))
def test_a_family_row_fills_the_rows_it_takes_and_leaves_the_others(dtype):
    """The generated grid kernel calls the family's row on every row of every band, and fills a
    row with the density exactly where the row returned 0."""
    grid = bg.Grid(origin=(-60.0, -45.0), dx=0.7, dy=0.9, nx=37, ny=100)
    ctx = WarpContext(dtype, "cpu", 2)
    marked = grid_block(ctx, KernelBinding(ONCE["mark"], _params(ctx, (3.0, -4.0), 11.0)), grid)
    plain = grid_block(ctx, KernelBinding(LANE_KERNELS, _params(ctx, (3.0, -4.0), 11.0)), grid)
    north = grid.y.astype(dtype) >= dtype(-4.0)
    assert 0 < north.sum() < grid.ny
    assert np.all(marked[north] == -1.0)
    assert np.array_equal(marked[~north], plain[~north])


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.parametrize("dtype", list(DTYPES))
def test_generated_batches_equal_one_hypothesis_at_a_time(family, dtype):
    """The batch kernels, through the engine's batch path, give every hypothesis the bits of its
    own grid and points kernels (one density function over its own struct)."""
    rng = np.random.default_rng(3)
    models = [_Batch((float(rng.uniform(-20, 20)), float(rng.uniform(-20, 20))), float(rng.uniform(3, 30)),
                     FAMILIES[family]) for _ in range(11)]
    grids = engine_batch.grids_in(np.array([(-40.0 - k, 40.0 + k, -30.0, 30.0 + 2 * k) for k in range(11)]), (13, 19))
    px, py = rng.uniform(-40, 40, 37), rng.uniform(-30, 30, 37)
    values = engine_batch.rasterise_batch(models, grids, dtype=dtype, threads=2).values
    points = engine_batch.pdf_batch(models, px, py, dtype=dtype, threads=2)
    for k, (model, grid) in enumerate(zip(models, grids)):
        ctx = WarpContext(dtype, "cpu", 1)
        binding = KernelBinding(FAMILIES[family], _params(ctx, model.centre, model.sigma))
        assert np.array_equal(values[k], grid_block(ctx, binding, grid))
        ctx.load(binding.kernels.points)
        assert np.array_equal(points[k], launch_points(ctx, binding, px, py))


@pytest.mark.parametrize("family", ["polar", "polar_lanes", "bearing", "bearing_lanes", "cat", "cat_lanes", "tabulated",
                                    "tabulated_lanes",
                                    "butterly"])
def test_every_family_builds_one_module_without_adjoints(family):
    """The package's families: every kernel of a family (generated or its own) lives in the family's
    module, one build, under the module's options (no adjoint kernels; the CAT scan's loops not
    unrolled)."""
    module = importlib.import_module(f"bananagrid.kernels.{family}")
    kernels = module.KERNELS
    built = [k for k in (kernels.grid, kernels.points, kernels.batch_grid, kernels.batch_points) if k is not None]
    assert {k.module.name for k in built} == {module.__name__}
    assert built[0].module.options["enable_backward"] is False
    if family.startswith("cat"):
        assert built[0].module.options["max_unroll"] == cat.SPLIT - 1
