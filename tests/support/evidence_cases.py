"""Priors, grids and evidence shared by the evidence tests, and the Monte Carlo oracle: the
model's own samples at the map's time, each kept with probability L(point) (a search's
"nothing found": 1 - POD), histogrammed on the grid."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

import bananagrid as bg
from cases import FIG1, FIG1_BOUNDS

#: Each prior with a grid that holds nearly all of its mass, and where its mass lies (a centre
#: and a length, m) for evidence that cuts it.
PRIORS = {
    "cat": (bg.CAT(**FIG1), bg.Grid.from_bounds(**FIG1_BOUNDS, step=100.0), (0.0, 2700.0), 700.0),
    "polar": (bg.PolarBanana(**FIG1, variant="improved"), bg.Grid.from_bounds(**FIG1_BOUNDS, step=100.0),
              (0.0, 2700.0), 700.0),
    "butterly": (bg.Butterly(mean=(0.0, 1500.0), cov=[[250.0**2, 0.0], [0.0, 150.0**2]], speeds=[3.0, 5.0],
                             weights=[0.5, 0.5], t=400.0),
                 bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-1600.0, 4600.0), step=100.0), (800.0, 2600.0), 900.0),
    "mixture": (bg.GaussianMixture(weights=[0.6, 0.4], means=[[0.0, 1200.0], [900.0, 2200.0]],
                                   covs=[[[4e5, 1e5], [1e5, 2e5]], [[2e5, 0.0], [0.0, 3e5]]]),
                bg.Grid.from_bounds(x=(-3000.0, 3400.0), y=(-1600.0, 5000.0), step=100.0), (300.0, 1600.0), 900.0),
    "bearing_fix": (bg.BearingFix(sensors=[(-2000.0, 0.0), (2000.0, 0.0)],
                                  bearings=[math.atan2(2000.0, 1500.0), math.atan2(-2000.0, 1500.0)],
                                  sigmas=[0.03, 0.03]),
                    bg.Grid.from_bounds(x=(-1500.0, 1500.0), y=(500.0, 2600.0), step=50.0), (100.0, 1450.0), 250.0),
}


def cutting_evidence(t: float | None, centre, scale: float) -> list:
    """An area search (POD 0.7) over a tilted quadrilateral, a track across it (inverse cube),
    and land on one side: polygons whose edges cut many cells, about ``centre`` at the length
    ``scale``, at the map's time ``t`` (0 for a law without one)."""
    t = 0.0 if t is None else t
    cx, cy = centre

    def at(points):
        return [(cx + scale * u, cy + scale * v) for u, v in points]

    area = at([(-0.7, -0.6), (0.6, -0.7), (0.9, 0.5), (-0.5, 0.3)])
    (x0, y0), (x1, y1) = at([(-3.0, 0.6), (3.0, 0.9)])
    land = at([(-3.0, 1.1), (-0.9, 1.2), (-1.2, 3.5), (-3.0, 3.5)])
    return [bg.AreaSearch(area, t=t, pod=0.7),
            bg.TrackSearch([(x0, y0, max(t - 60.0, 0.0)), (x1, y1, t + 60.0)], sweep_width=0.3 * scale),
            bg.Exclusion(land)]


def undetected(model, evidence, n: int, seed: int):
    """(the draws of ``model.sample`` that the evidence leaves, all draws): each draw is kept
    with probability L(draw), the product of the evidence's factors there (a search's 1 - POD)."""
    rng = np.random.default_rng(seed)
    points = model.sample(n, rng)
    keep = np.ones(len(points))
    for e in evidence:
        keep = keep * e.likelihood(points[:, 0], points[:, 1])
    return points[rng.uniform(size=len(points)) < keep], points


def grid_counts(points: np.ndarray, grid: bg.Grid) -> np.ndarray:
    """Draws per cell of ``grid``, (ny, nx)."""
    x_edges = grid.origin[0] + grid.dx * np.arange(grid.nx + 1)
    y_edges = grid.origin[1] + grid.dy * np.arange(grid.ny + 1)
    counts, _, _ = np.histogram2d(points[:, 1], points[:, 0], bins=[y_edges, x_edges])
    return counts


def lattice_counts(points: np.ndarray, lattice: bg.PolarLattice) -> np.ndarray:
    """Draws per cell of a polar lattice about the origin, heading north, (n_range, n_bearing)."""
    r = np.hypot(points[:, 0], points[:, 1])
    b = np.arctan2(points[:, 0], points[:, 1])
    counts, _, _ = np.histogram2d(r, b, bins=[lattice.range_edges, lattice.bearing_edges])
    return counts


def chi_square_p(counts: np.ndarray, probabilities: np.ndarray) -> float:
    """p-value of Pearson's chi-square over the cells with an expected count of 5 or more (the
    rest pooled into one bin, so that the counts and the expectations have the same total)."""
    expected = probabilities * counts.sum()
    ok = expected >= 5.0
    observed = np.append(counts[ok], counts[~ok].sum())
    expect = np.append(expected[ok], expected[~ok].sum())
    if expect[-1] < 5.0:  # too little left over to be a bin of its own
        observed, expect = observed[:-1], expect[:-1]
        observed = observed * expect.sum() / observed.sum()
    statistic = float(np.sum((observed - expect) ** 2 / expect))
    return float(stats.chi2.sf(statistic, len(expect) - 1))
