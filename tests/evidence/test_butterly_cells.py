"""Butterly's carried cell probabilities (``Butterly.carried_cell_plan``): the prior channel is
the prior's own cell rule, and every channel converges under refinement (on a window where the
searches and the report cut the rings)."""

from __future__ import annotations

import numpy as np

import bananagrid as bg
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.evidence.packing import pack

MODEL = bg.Butterly(mean=(100.0, -50.0), cov=[[300.0**2, 0.5 * 300 * 150], [0.5 * 300 * 150, 150.0**2]],
                    speeds=[3.0, 6.0], weights=[0.4, 0.6], t=1000.0)
EVIDENCE = [bg.AreaSearch([(-2000, 1000), (3000, 1000), (3000, 2500), (-2000, 2500)], t=400.0, pod=0.8),
            bg.AreaSearch([(0, -4000), (2500, -4000), (1000, 0)], t=(500.0, 800.0), coverage=1.0),
            bg.PositionReport((1500.0, 1500.0), t=500.0, sigma=1500.0)]
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
    rule is not at its smooth-case bound; measured 3e-17 of the window's mass per cell at most
    (the kinks' share of a sub-cell of sigma_min is small), held to 1e-12."""
    pk, out, _ = cells(GRID)
    fine_grid = bg.Grid.from_bounds(x=(0.0, 4000.0), y=(-1000.0, 3000.0), step=250.0)
    _, fine, _ = cells(fine_grid)
    fine = fine.reshape(fine.shape[0], GRID.ny, 2, GRID.nx, 2).sum(axis=(2, 4))
    for c in range(out.shape[0]):
        np.testing.assert_allclose(out[c], fine[c], rtol=0.0, atol=1e-12 * out[c].sum())
    # evidence lowers the mass, and no cell gains
    assert np.all(out[pk.channel("all")] <= out[pk.channel("prior")] * (1 + 1e-12))
    assert out[pk.channel("all")].sum() < 0.9 * out[pk.channel("prior")].sum()
