"""The padded lattice the interpolating kernel reads (``kernels/tabulated.py``'s ``pad_table``), and
the kernel at the seams the padding replaces (the bearing wrap at +-pi, the mirror through the fix)."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine.grid_kernel import grid_block
from bananagrid.engine.points import launch_points
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.kernels import tabulated
from bananagrid.protocol import KernelBinding
from bananagrid.models import _cat_heading as heading


@pytest.mark.parametrize("mirror", [False, True])
def test_pad_table_wraps_bearings_and_mirrors_row_one(mirror):
    rng = np.random.default_rng(5)
    values = rng.uniform(size=(7, 12))
    padded = tabulated.pad_table(values, mirror)
    n_theta = values.shape[1]
    assert padded.shape == (8, n_theta + tabulated.PAD_BEFORE + tabulated.PAD_AFTER)
    for c in range(padded.shape[1]):
        j = (c - tabulated.PAD_BEFORE) % n_theta
        assert np.array_equal(padded[1:, c], values[:, j])
        # lattice row -1: p(-r, theta) = p(r, theta + pi) where the lattice mirrors
        assert padded[0, c] == (values[1, (j + n_theta // 2) % n_theta] if mirror else values[0, j])


@pytest.mark.parametrize("mirror", [False, True])
def test_interpolation_is_periodic_and_exact_for_log_cubics(mirror):
    """log p cubic in r and constant in theta, read across the bearings' seam at +-pi (either side
    of it): the kernel reproduces the cubic to rounding; within a step of the fix of a mirrored
    lattice it interpolates row -1 = row 1 (the same |r|)."""
    n_r, n_theta = 10, 16
    r0 = 0.0 if mirror else 5.0
    radii = r0 + np.arange(n_r)
    logs = 0.1 * radii - 0.02 * radii**2 + 0.001 * radii**3
    table = heading.HeadingTable(np.repeat(np.exp(logs)[:, None], n_theta, axis=1), r0, 1.0, -math.pi,
                                 2.0 * math.pi / n_theta, mirror, 0.0, 0)
    r = np.linspace(r0 + 1.0, r0 + n_r - 3.0, 37)
    for eps in (0.0, 1e-12, -1e-12):
        theta = math.pi + eps
        got = heading.interpolate_table(table, r * math.sin(theta), r * math.cos(theta))
        want = np.exp(0.1 * r - 0.02 * r**2 + 0.001 * r**3)
        # the stencil reproduces cubics; the rest is rounding of a few terms of size ~1
        np.testing.assert_allclose(got, want, rtol=1e-13)
        if mirror:  # within a step of the fix: the cubic through rows 1, 0, 1, 2 at nodes -1 .. 2
            f = np.linspace(0.0, 0.9, 10)
            near = heading.interpolate_table(table, f * math.sin(theta), f * math.cos(theta))
            w = [-f * (f - 1) * (f - 2) / 6, (f + 1) * (f - 1) * (f - 2) / 2, -(f + 1) * f * (f - 2) / 2,
                 (f + 1) * f * (f - 1) / 6]
            np.testing.assert_allclose(near, np.exp(sum(wk * logs[k] for wk, k in zip(w, (1, 0, 1, 2)))),
                                       rtol=1e-13)


def _scalar_interpolation(table, x, y, dtype):
    """The scalar kernel (``tabulated.KERNELS.points``, the GPU path's) on the CPU."""
    ctx = WarpContext(dtype, "cpu", 1)
    values, logs, floor = table.kernel_arrays(ctx.dtype)
    params = ctx.struct(tabulated.TABLE, log_table=ctx.array(logs), table=ctx.array(values), r0=table.r0,
                        dr=table.dr, theta0=table.theta0, dtheta=table.dtheta, floor_value=floor,
                        mirror=int(table.mirror), pose=(0.0, 0.0, 1.0, 0.0))
    ctx.load(tabulated.KERNELS.points)
    return launch_points(ctx, KernelBinding(tabulated.KERNELS, params, {}), np.asarray(x, float), np.asarray(y, float))


@st.composite
def _tables(draw):
    """A lattice of a smooth log-density (a Gaussian ridge in r, periodic in theta, 6-40 ranges by
    8-64 bearings, from the fix or not) reaching from near 1 down past both floors (the linear
    branch), with rough noise of up to 3 in the log, and points over all of it (a row's margin at its
    ends, as the heading tables keep two)."""
    n_r, n_theta = draw(st.integers(6, 40)), 2 * draw(st.integers(4, 32))
    mirror = draw(st.booleans())
    dr = draw(st.floats(0.01, 100.0))
    r0 = 0.0 if mirror else dr * draw(st.floats(0.0, 50.0))
    depth = draw(st.sampled_from([5.0, 50.0, 800.0]))
    rng = np.random.default_rng(draw(st.integers(0, 1000)))
    radii = r0 + dr * np.arange(n_r)
    theta = -math.pi + 2.0 * math.pi * np.arange(n_theta) / n_theta
    z = (radii[:, None] - radii.mean()) / (dr * n_r / 4.0)
    logs = -depth * (z**2 + 0.5 * (1.0 - np.cos(theta[None, :] - rng.uniform(-3, 3))))
    logs += draw(st.sampled_from([0.0, 3.0])) * rng.uniform(-1.0, 1.0, logs.shape)
    table = heading.HeadingTable(np.exp(logs), r0, dr, -math.pi, 2.0 * math.pi / n_theta, mirror, 0.0, 0)
    r = rng.uniform(0.0 if mirror else r0 + dr, radii[-1] - dr, 300)  # where a table is queried
    phi = rng.uniform(-math.pi, math.pi, 300)
    return table, r * np.sin(phi), r * np.cos(phi)


@seed(20261129)
@settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=_tables())
def test_lanes_agree_with_the_scalar_kernel(case):
    """The CPU's lane kernels (``kernels/tabulated_lanes.py``, what ``interpolate_table`` runs) and the
    scalar kernel agree in both dtypes: in the log branch to a few ulps of the log sum (the lane exp's
    3 ulp, fused multiply-adds, the angle's ulps times its weights' slope), in the linear branch to
    a few ulps of the stencil's largest entry."""
    table, x, y = case
    for dtype in (np.float64, np.float32):
        eps = float(np.finfo(dtype).eps)
        lanes = heading.interpolate_table(table, x, y, dtype=dtype).astype(float)
        scalar = _scalar_interpolation(table, x, y, dtype).astype(float)
        top = float(table.values.max())
        big = np.abs(np.log(np.maximum(table.values, 1e-300))).max()
        # log branch: e^(L (1 + k eps)) - e^L ~ k eps |L| e^L, with |L| up to the table's largest
        # log, plus slope terms of the same order (64 ulps: a margin of ten over what was measured)
        tol = 64.0 * eps * (1.0 + big) * np.maximum(lanes, scalar) + 64.0 * eps * top
        bad = ~(np.abs(lanes - scalar) <= tol)
        assert not bad.any(), (dtype, lanes[bad], scalar[bad], tol[bad], x[bad], y[bad])


@seed(20261130)
@settings(max_examples=15, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=_tables(), nx=st.integers(1, 70), pose=st.tuples(st.floats(-50.0, 50.0), st.floats(-50.0, 50.0),
                                                             st.floats(-math.pi, math.pi)))
def test_grid_rows_are_the_points_kernels_bits(case, nx, pose):
    """The grid kernel's rows (``lanes.tabulated_row``: two registers of lanes a step, a partial
    vector at a row's end) give the points kernel's bits at every cell centre, in both dtypes,
    under any pose."""
    table, _, _ = case
    reach = table.r0 + table.dr * (table.shape[0] - 2)
    ox, oy, heading_ = pose
    grid = bg.Grid.from_bounds(x=(ox - reach, ox + reach), y=(oy - reach, oy + reach), dx=2 * reach / nx,
                               dy=2 * reach / 7)
    placed = (ox, oy, math.cos(heading_), math.sin(heading_))
    for dtype in (np.float64, np.float32):
        ctx = WarpContext(dtype, "cpu", 2)
        binding = heading.table_binding(ctx, table, placed, {})
        values = grid_block(ctx, binding, grid)
        x, y = np.meshgrid(grid.x, grid.y)
        ctx.load(binding.kernels.points)
        points = launch_points(ctx, binding, x, y)
        assert np.array_equal(values, points), int(np.sum(values != points))
