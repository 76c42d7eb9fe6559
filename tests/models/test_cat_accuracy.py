"""Exact CAT kernel against the independent float64 oracle in ``oracles.py``.

The oracle shares no code with the kernel: it works in (alpha = a t / v0, s = omega t), scans
at 0.01 rad, and is itself checked against literal eq. (1) with scipy.optimize.brentq
(``oracles.self_check``). Requirement: at most 1e-6 relative inside the 1e-10 m^-2
contour.
"""

import numpy as np
import pytest

import bananagrid as bg
import oracles

from cases import FIG1, FOLDING

TOLERANCE = 1e-6
CASES = {
    # name: (parameters, grid bounds, step)
    "figure1": (FIG1, dict(x=(-3000.0, 3000.0), y=(-200.0, 3400.0)), 20.0),
    "folding": (FOLDING, dict(x=(-3200.0, 3200.0), y=(-2400.0, 3400.0)), 40.0),
}


def oracle(params, x, y):
    return oracles.cat_density(
        x, y, v0=params["v0"], t=params["t"], sigma_a=params["sigma_a"], sigma_w=params["sigma_omega"]
    )


@pytest.mark.parametrize("case", CASES)
def test_grid_matches_oracle(case):
    params, bounds, step = CASES[case]
    grid = bg.Grid.from_bounds(**bounds, step=step)
    got = bg.rasterise(bg.CAT(**params), grid).values
    xx, yy = np.meshgrid(grid.x, grid.y)
    want = oracle(params, xx, yy)
    inside = want >= 1e-10
    assert inside.sum() > 1000
    rel = np.abs(got[inside] / want[inside] - 1.0)
    assert rel.max() <= TOLERANCE, rel.max()
    # outside the contour the two agree in absolute terms too (no stray roots or missed mass)
    assert np.abs(got - want).max() <= TOLERANCE * 1e-10


@pytest.mark.parametrize("case", CASES)
def test_sampled_points_match_oracle(case):
    """Points drawn from the model itself, so they crowd where the mass is, folds included."""
    params, _, _ = CASES[case]
    model = bg.CAT(**params)
    pts = model.sample(3000, np.random.default_rng(7))
    want = oracle(params, pts[:, 0], pts[:, 1])
    got = model.pdf(pts[:, 0], pts[:, 1])
    inside = want >= 1e-10
    assert np.abs(got[inside] / want[inside] - 1.0).max() <= TOLERANCE


def test_turn_rate_zero_line_has_no_0_over_0():
    """x = 0 is reached with omega = 0 exactly, where the closed forms of eq. (1) are 0/0."""
    model = bg.CAT(**FIG1)
    y = np.linspace(2500.0, 3100.0, 61)
    for x in (0.0, 1e-9, -1e-6, 1e-3):
        got = model.pdf(np.full_like(y, x), y)
        want = oracle(FIG1, np.full_like(y, x), y)
        assert np.all(np.isfinite(got))
        inside = want >= 1e-10
        assert np.abs(got[inside] / want[inside] - 1.0).max() <= TOLERANCE


def test_folding_case_has_several_roots_somewhere():
    """Guard that the folding case really folds: the mass captured on a generous grid is
    (nearly) one only if every root of the overlapping sheets is summed."""
    grid = bg.Grid.from_bounds(x=(-3200.0, 3200.0), y=(-2400.0, 3400.0), step=20.0)
    raster = bg.rasterise(bg.CAT(**FOLDING), grid)
    # the omega tail beyond 8 sigma is 1.2e-15; the sheets reaching outside the frame hold
    # about 2e-6 (Monte Carlo, test_monte_carlo); midpoint error at 20 m is below 1e-6.
    assert abs(raster.mass - 1.0) < 1e-5
