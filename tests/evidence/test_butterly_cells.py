"""Butterly's carried cell probabilities (``Butterly.carried_cell_plan``): the prior channel is
the prior's own cell rule, and every channel converges under refinement (on a window where the
searches and the report cut the rings)."""

from __future__ import annotations

from unittest import mock

import numpy as np
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.engine.carried import evaluate_carried
from bananagrid.evidence.packing import pack
from bananagrid.models.butterly import SPEED_FLOOR

MODEL = bg.Butterly(mean=(100.0, -50.0), cov=[[300.0**2, 0.5 * 300 * 150], [0.5 * 300 * 150, 150.0**2]],
                    speeds=[3.0, 6.0], weights=[0.4, 0.6], t=1000.0)
EVIDENCE = [bg.AreaSearch([(-2000, 1000), (3000, 1000), (3000, 2500), (-2000, 2500)], t=400.0, pod=0.8),
            bg.AreaSearch([(0, -4000), (2500, -4000), (1000, 0)], t=(500.0, 800.0), coverage=1.0),
            bg.PositionReport((1500.0, 1500.0), t=500.0, sigma=1500.0)]
#: Where a polygon's weight is carried the density has kinks (a course's circle tangent to an
#: edge, or through a vertex): the Gauss rule is second order on a cell that holds one. Measured
#: on the polar case below: 1.0e-6 of the channel's mass per cell at most between the lattice
#: and its 2 x 2 refinement; held to 1e-5.
KINKS = 1e-5
GRID = bg.Grid.from_bounds(x=(0.0, 4000.0), y=(-1000.0, 3000.0), step=500.0)


def cells(grid, tol=1e-10):
    pk = pack(EVIDENCE, MODEL.t)
    out, notes = MODEL.carried_cell_plan(grid, pk, tol=tol).run(WarpContext(np.float64, "cpu", None))
    return pk, out, notes


def test_prior_channel_is_the_prior_cell_rule():
    """Channel "prior" against ``rasterise(quantity="probability")`` (the engine's rule at the
    same target): the same sub-cells of at most sigma_min; within 1e-9 of the total mass (each
    rule's error bound, 1e-10 per sub-cell and axis, times a few)."""
    pk, out, _ = cells(GRID)
    prior = bg.rasterise(MODEL, GRID, quantity="probability", min_mass=0).values
    np.testing.assert_allclose(out[pk.channel("prior")], prior, rtol=0.0, atol=1e-9)


def test_refinement():
    """Every channel against the same rule on cells halved in each direction (summed 2 x 2):
    the carried density has kinks where a course's circle touches a polygon's edge, where the
    rule is second order; measured 3e-17 of the window's mass per cell at most here, held to
    KINKS (measured 1e-6 on the polar case's sectors)."""
    pk, out, _ = cells(GRID)
    fine_grid = bg.Grid.from_bounds(x=(0.0, 4000.0), y=(-1000.0, 3000.0), step=250.0)
    _, fine, _ = cells(fine_grid)
    fine = fine.reshape(fine.shape[0], GRID.ny, 2, GRID.nx, 2).sum(axis=(2, 4))
    for c in range(out.shape[0]):
        np.testing.assert_allclose(out[c], fine[c], rtol=0.0, atol=KINKS * out[c].sum())
    # evidence lowers the mass, and no cell gains
    assert np.all(out[pk.channel("all")] <= out[pk.channel("prior")] * (1 + 1e-12))
    assert out[pk.channel("all")].sum() < 0.9 * out[pk.channel("prior")].sum()


def test_polar_lattice():
    """On a polar lattice about a sensor: the prior channel against ``rasterise`` on the lattice
    (the engine's polar cell rule, its own target 1e-10 per sub-cell) to 1e-9 of the mass, and
    every channel against the lattice with halved ranges and bearings (summed 2 x 2): the
    channels without a polygon to 1e-12 of their mass, those with one to KINKS (the sectors
    here hold the kinks of the north search's curves)."""
    pose = bg.Pose(origin=(-1000.0, -2000.0), heading=0.3)
    lattice = bg.PolarLattice(ranges=(2000.0, 6000.0), range_step=500.0, bearings=(0.0, 0.8), bearing_step=0.1,
                              pose=pose)
    fine = bg.PolarLattice(ranges=(2000.0, 6000.0), range_step=250.0, bearings=(0.0, 0.8), bearing_step=0.05,
                           pose=pose)
    pk = pack(EVIDENCE, MODEL.t)
    ctx = WarpContext(np.float64, "cpu", None)
    out, _ = MODEL.carried_cell_plan(lattice, pk).run(ctx)
    refined, _ = MODEL.carried_cell_plan(fine, pk).run(ctx)
    refined = refined.reshape(refined.shape[0], lattice.n_range, 2, lattice.n_bearing, 2).sum(axis=(2, 4))
    prior = bg.rasterise(MODEL, lattice, min_mass=0).probability
    np.testing.assert_allclose(out[pk.channel("prior")], prior, rtol=0.0, atol=1e-9 * prior.sum())
    for c, name in enumerate(pk.channel_names):
        smooth = name in ("prior", "others")  # no polygon: the weight is smooth
        np.testing.assert_allclose(out[c], refined[c], rtol=0.0, atol=(1e-12 if smooth else KINKS) * out[c].sum())


@seed(20261127)
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(x0=st.floats(-9000.0, 6000.0), y0=st.one_of(st.floats(-9000.0, -5000.0), st.floats(3000.0, 6000.0)),
       side=st.floats(300.0, 3000.0),
       t0=st.floats(0.0, 900.0), span=st.floats(0.0, 300.0), report=st.booleans())
def test_unweighted_cells_keep_the_prior(x0, y0, side, t0, span, report):
    """``weighted_cells``' claim, swept over search boxes and times (one time or an interval):
    boxes north or south of the rings' middle (some cells out of reach), at 9 points of every
    cell it calls unweighted (with prior mass), every channel of the
    carried kernel equals the prior channel within the speeds' floor (n_speeds x SPEED_FLOOR /
    n_speeds of the density's maximum: the mass its bound leaves out, as the kernel's own
    speed floor does). A report weighs every path: then every cell is weighted."""
    t1 = min(t0 + span, MODEL.t)
    evidence = [bg.AreaSearch([(x0, y0), (x0 + side, y0), (x0 + side, y0 + side), (x0, y0 + side)],
                              t=t0 if t1 == t0 else (t0, t1), pod=0.9)]
    if report:
        evidence.append(bg.PositionReport((x0, y0), t=t0, sigma=500.0))
    pk = pack(evidence, MODEL.t)
    grid = bg.Grid.from_bounds(x=(-8000.0, 8000.0), y=(-8000.0, 8000.0), step=800.0)
    xe = grid.origin[0] + grid.dx * np.arange(grid.nx + 1)
    ye = grid.origin[1] + grid.dy * np.arange(grid.ny + 1)
    weighted = MODEL.weighted_cells(pk, xe, ye)
    if report:
        assert weighted.all()
        return
    rows, cols = np.nonzero(~weighted)
    u = np.array([0.01, 0.5, 0.99])
    px = (xe[cols, None, None] + grid.dx * u[None, None, :]) + 0.0 * u[None, :, None]
    py = (ye[rows, None, None] + grid.dy * u[None, :, None]) + 0.0 * u[None, None, :]
    values = evaluate_carried(MODEL, px.ravel(), py.ravel(), pk)
    floor = SPEED_FLOOR * MODEL.peak_lower_bound()
    assert np.max(np.abs(values - values[pk.channel("prior")]), initial=0.0) <= floor
    # the claim is not empty: some cells beyond the box's reach (the rings span +-6 km)
    assert (~weighted).sum() > 0


def test_unweighted_cells_in_the_plan():
    """The plan with cells proved unweighted (their every channel the prior's cells, given or
    computed by ``rasterise``) against the plan that carries every cell: within 1e-9 of the
    mass (the two prior cell rules' agreement, test_prior_channel_is_the_prior_cell_rule), and
    the posterior built on either agrees to the same; most of this grid is unweighted."""
    evidence = [bg.AreaSearch([(2000, 2000), (3000, 2000), (3000, 3000), (2000, 3000)], t=(300.0, 400.0), pod=0.9)]
    grid = bg.Grid.from_bounds(x=(-7000.0, 7000.0), y=(-7000.0, 7000.0), step=700.0)
    pk = pack(evidence, MODEL.t)
    ctx = WarpContext(np.float64, "cpu", None)
    fast, notes = MODEL.carried_cell_plan(grid, pk).run(ctx)
    given_prior = bg.rasterise(MODEL, grid, quantity="probability", min_mass=0).values
    fast_given, _ = MODEL.carried_cell_plan(grid, pk, prior_cells=given_prior).run(ctx)
    np.testing.assert_array_equal(fast, fast_given)
    with mock.patch.object(bg.Butterly, "weighted_cells", lambda self, p, x, y: np.ones((y.size - 1, x.size - 1), bool)):
        slow, slow_notes = MODEL.carried_cell_plan(grid, pk).run(ctx)
        slow_post = bg.posterior(MODEL, grid, evidence)
    assert notes["cells_unweighted"] > notes["cells_computed"] > 0
    assert slow_notes["cells_unweighted"] == 0
    for c in range(fast.shape[0]):
        np.testing.assert_allclose(fast[c], slow[c], rtol=0.0, atol=1e-9 * slow[c].sum())
    post = bg.posterior(MODEL, grid, evidence)
    np.testing.assert_allclose(post.values, slow_post.values, rtol=0.0, atol=1e-9)
    assert abs(post.pos - slow_post.pos) <= 1e-9
