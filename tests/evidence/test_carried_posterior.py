"""Posteriors of a CAT prior with evidence at earlier times, carried along the paths in the
kernels, against an independent simulation of the model's own generative story: 10^6 draws of
``CAT.sample_paths`` (a, omega and the heading error of ``sample``), each path detected by every
search with its POD where the path was at the search's time (the inverse-cube track's exposure
by a fine trapezoidal rule along the path, not the pack's nodes), kept with the bearings'
likelihood, and the undetected ones histogrammed at the map's time: Pearson's chi-square at
alpha 1e-3 over the cells, region masses and POS within 4 binomial SDs. And the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

import bananagrid as bg
from cases import FIG1
from evidence_cases import chi_square_p, grid_counts

ALPHA = 1e-3
DRAWS = 10**6
GRID = bg.Grid.from_bounds(x=(-2400.0, 2400.0), y=(0.0, 3300.0), step=100.0)


def binomial_within(count: int, n: int, p: float, sigmas: float = 4.0) -> bool:
    return abs(count - n * p) <= sigmas * math.sqrt(n * p * (1.0 - p)) + 1e-9


def earlier_evidence(track: bool):
    """Two area searches (t = 4 s and 7 s) across the banana's earlier positions, bearings at
    6 s; with ``track`` an inverse-cube track flown across the paths' way from 2 s to 2.6 s,
    some 50 to 250 m ahead of them (its own POS about 0.3)."""
    fix = bg.BearingFix(sensors=[(-3000.0, 1200.0), (1500.0, -500.0)],
                        bearings=[math.atan2(3000.0, 600.0), math.atan2(-1500.0, 2200.0)], sigmas=[0.12, 0.1])
    evidence = [bg.AreaSearch([(-400.0, 900.0), (150.0, 950.0), (250.0, 1400.0), (-300.0, 1350.0)], t=4.0, pod=0.8),
                bg.AreaSearch([(-100.0, 1600.0), (900.0, 1500.0), (900.0, 2300.0), (0.0, 2200.0)], t=7.0, pod=0.6),
                bg.BearingReport(fix, t=6.0)]
    if track:
        evidence.append(bg.TrackSearch([(-300.0, 780.0, 2.0), (300.0, 780.0, 2.6)], sweep_width=300.0))
    return evidence


def simulate(model, evidence, n, seed):
    """(the undetected draws' positions at the map's time, all draws' positions there): each
    draw kept with probability the product of its searches' 1 - POD and the bearings'
    likelihood where its path was at their times; a track's exposure by the trapezoidal rule on
    121 times over its span (0.005 s apart: the searcher moves 5 m, the paths pass it at
    some 50 m or more)."""
    rng = np.random.default_rng(seed)
    point_times = sorted({e.time_span[0] for e in evidence if not isinstance(e, bg.TrackSearch)})
    fine = []
    for e in evidence:
        if isinstance(e, bg.TrackSearch):
            fine = np.linspace(e.time_span[0], e.time_span[1], 121)
    all_times = np.concatenate([[model.t], point_times, fine])
    keep = np.ones(n)
    out = np.empty((n, 2))
    chunk = 20_000
    for start in range(0, n, chunk):
        m = min(chunk, n - start)
        paths = model.sample_paths(m, all_times, rng)
        out[start:start + m] = paths[:, 0]
        w = np.ones(m)
        for e in evidence:
            if isinstance(e, bg.TrackSearch):
                pts = paths[:, 1 + len(point_times):]
                sx = np.interp(fine, e.track[:, 2], e.track[:, 0])
                sy = np.interp(fine, e.track[:, 2], e.track[:, 1])
                speed = np.hypot(np.diff(e.track[:, 0]), np.diff(e.track[:, 1])) / np.diff(e.track[:, 2])
                v = speed[np.clip(np.searchsorted(e.track[:, 2], fine, side="right") - 1, 0, len(speed) - 1)]
                r = np.hypot(pts[..., 0] - sx, pts[..., 1] - sy)
                rate = e.sweep_width**2 * v / (8.0 * math.pi * r**3)
                w = w * np.exp(-np.trapezoid(rate, fine, axis=1))
            else:
                p = paths[:, 1 + point_times.index(e.time_span[0])]
                w = w * e.likelihood(p[:, 0], p[:, 1])
        keep[start:start + m] = w
    kept = rng.uniform(size=n) < keep
    return out[kept], out


CASES = {
    "cat_searches_bearings": (bg.CAT(**FIG1), False),
    "cat_heading_searches_bearings": (bg.CAT(**FIG1, sigma_heading=0.04), False),
    "cat_track": (bg.CAT(**FIG1), True),
}


@pytest.mark.parametrize("name", list(CASES))
def test_carried_posterior_matches_simulation_of_the_paths(name):
    """Chi-square over the cells at alpha 1e-3; the normaliser (kept / drawn on the grid), the
    mass of the cells east of x = 0 and of the cells within 300 m of the second search's
    polygon's centre line at the map's time, and each search's POS within 4 binomial SDs."""
    model, track = CASES[name]
    evidence = earlier_evidence(track)
    post = bg.posterior(model, GRID, evidence, subdivisions=6)
    kept, drawn = simulate(model, evidence, DRAWS, seed=20261127)
    counts = grid_counts(kept, GRID)
    x0, x1, y0, y1 = GRID.extent
    on_grid = ((drawn[:, 0] >= x0) & (drawn[:, 0] < x1) & (drawn[:, 1] >= y0) & (drawn[:, 1] < y1)).sum()
    assert chi_square_p(counts, post.values) > ALPHA
    assert binomial_within(int(counts.sum()), int(on_grid), post.normaliser)
    east = GRID.x[None, :] > 0.0
    east = np.broadcast_to(east, GRID.shape)
    assert binomial_within(int(counts[east].sum()), int(counts.sum()), float(post.values[east].sum()))
    assert 0.0 < post.pos < 1.0
    assert post.provenance["carried"]["evidence"]
