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
from definite_oracle import sampled_approach
from evidence_cases import chi_square_p, grid_counts, lattice_counts

ALPHA = 1e-3
DRAWS = 10**6
#: Draws of the definite-range cases (their closest approach needs 401 path positions a draw).
DEFINITE_DRAWS = 250_000
GRID = bg.Grid.from_bounds(x=(-2400.0, 2400.0), y=(0.0, 3300.0), step=100.0)


def binomial_within(count: int, n: int, p: float, sigmas: float = 4.0) -> bool:
    return abs(count - n * p) <= sigmas * math.sqrt(n * p * (1.0 - p)) + 1e-9


def earlier_evidence(track: bool):
    """Two area searches (t = 4 s and 7 s) across the banana's earlier positions, bearings at
    6 s; with ``track`` an inverse-cube track flown across the paths' way from 2 s to 2.6 s,
    some 50 to 250 m ahead of them (its own POS about 0.3); with ``track = "definite"``,
    :data:`DEFINITE`."""
    fix = bg.BearingFix(sensors=[(-3000.0, 1200.0), (1500.0, -500.0)],
                        bearings=[math.atan2(3000.0, 600.0), math.atan2(-1500.0, 2200.0)], sigmas=[0.12, 0.1])
    evidence = [bg.AreaSearch([(-400.0, 900.0), (150.0, 950.0), (250.0, 1400.0), (-300.0, 1350.0)], t=4.0, pod=0.8),
                bg.AreaSearch([(-100.0, 1600.0), (900.0, 1500.0), (900.0, 2300.0), (0.0, 2200.0)], t=7.0, pod=0.6),
                bg.BearingReport(fix, t=6.0)]
    if track == "definite":
        evidence.append(DEFINITE)
    elif track:
        evidence.append(bg.TrackSearch([(-300.0, 780.0, 2.0), (300.0, 780.0, 2.6)], sweep_width=300.0))
    return evidence


#: A definite-range track (detected iff within 100 m) flown north beside the paths' way from
#: 1.5 s to 4.5 s, then north-west into it (its own POS 0.34, given the bearings).
DEFINITE = bg.TrackSearch([(150.0, 400.0, 1.5), (150.0, 1300.0, 4.5), (0.0, 1600.0, 5.0)], sweep_width=200.0,
                          law="definite")


def simulate(model, evidence, n, seed):
    """The draws' positions at the map's time (n, 2), and each evidence's factor on each draw
    (n, K), from the draw's path (``sample_paths``): a search's 1 - POD and a report's
    likelihood where the path was at their times (land: at the map's); a search over an
    interval, exp(int log(1 - POD(x(s))) ds / span), and a track's exp(-exposure), by the
    trapezoidal rule on fine times over their spans (a track: 121 times, 0.005 s apart, the
    searcher moving 5 m while the paths pass it at some 50 m or more; an interval: 41 times,
    its error at a crossing of an edge, like the pack's, of either sign); a definite-range
    track's factor is 0 where the smallest range sampled at 401 times over its span is within
    W / 2 (samples 9 ms apart, relative speeds below 700 m/s: the sampled range overestimates
    the true one by at most (700 x 0.009)^2 / (8 x 100) = 0.05 m)."""
    rng = np.random.default_rng(seed)
    times, slices = [model.t], []
    for e in evidence:
        span = (model.t, model.t) if e.time_span is None else e.time_span  # land: the map's time
        if isinstance(e, bg.TrackSearch):
            fine = np.linspace(*span, 401 if e.law == "definite" else 121)
        elif span[1] > span[0]:
            fine = np.linspace(*span, 41)
        else:
            fine = np.array([span[0]])
        slices.append((slice(len(times), len(times) + len(fine)), fine))
        times.extend(fine)
    factors = np.ones((n, len(evidence)))
    out = np.empty((n, 2))
    chunk = 20_000
    for start in range(0, n, chunk):
        m = min(chunk, n - start)
        paths = model.sample_paths(m, times, rng)
        out[start:start + m] = paths[:, 0]
        for k, (e, (where, fine)) in enumerate(zip(evidence, slices)):
            pts = paths[:, where]
            if isinstance(e, bg.TrackSearch) and e.law == "definite":
                factors[start:start + m, k] = sampled_approach(e.track, pts, fine) > 0.5 * e.sweep_width
            elif isinstance(e, bg.TrackSearch):
                sx = np.interp(fine, e.track[:, 2], e.track[:, 0])
                sy = np.interp(fine, e.track[:, 2], e.track[:, 1])
                speed = np.hypot(np.diff(e.track[:, 0]), np.diff(e.track[:, 1])) / np.diff(e.track[:, 2])
                v = speed[np.clip(np.searchsorted(e.track[:, 2], fine, side="right") - 1, 0, len(speed) - 1)]
                r = np.hypot(pts[..., 0] - sx, pts[..., 1] - sy)
                rate = e.sweep_width**2 * v / (8.0 * math.pi * r**3)
                factors[start:start + m, k] = np.exp(-np.trapezoid(rate, fine, axis=1))
            elif len(fine) > 1:
                with np.errstate(divide="ignore"):
                    log_miss = np.log(e.likelihood(pts[..., 0], pts[..., 1]))
                factors[start:start + m, k] = np.exp(np.trapezoid(log_miss, fine, axis=1) / (fine[-1] - fine[0]))
            else:
                factors[start:start + m, k] = e.likelihood(pts[:, 0, 0], pts[:, 0, 1])
    return out, factors


#: Evidence at the map's own time beside the earlier: an area search and land.
NOW = [bg.AreaSearch([(-700.0, 2300.0), (0.0, 2250.0), (100.0, 2900.0), (-600.0, 3000.0)], t=FIG1["t"], pod=0.5),
       bg.Exclusion([(300.0, 2900.0), (1500.0, 2700.0), (1500.0, 3300.0), (300.0, 3300.0)])]

#: Searches over periods (a planner's): an area searched from 3 s to 5 s (coverage 1.2 spread
#: over it) and a raster of PODs searched from 5.5 s to 6.5 s.
PERIODS = [bg.AreaSearch([(-300.0, 700.0), (100.0, 700.0), (100.0, 1500.0), (-300.0, 1500.0)], t=(3.0, 5.0),
                         coverage=1.2),
           bg.RasterSearch(bg.Grid.from_bounds(x=(-400.0, 400.0), y=(1400.0, 2000.0), step=200.0), t=(5.5, 6.5),
                           pod=[[0.9, 0.3, 0.6, 0.1], [0.2, 0.8, 0.4, 0.7], [0.5, 0.1, 0.95, 0.3]])]

CASES = {
    "cat_searches_bearings": (bg.CAT(**FIG1), False),
    "cat_earlier_and_now": (bg.CAT(**FIG1), None),
    "cat_periods": (bg.CAT(**FIG1), "periods"),
    "cat_heading_searches_bearings": (bg.CAT(**FIG1, sigma_heading=0.04), False),
    "cat_track": (bg.CAT(**FIG1), True),
    "cat_definite": (bg.CAT(**FIG1), "definite"),
    "cat_heading_definite": (bg.CAT(**FIG1, sigma_heading=0.04), "definite"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_carried_posterior_matches_simulation_of_the_paths(name):
    """Chi-square over the cells at alpha 1e-3; the normaliser (kept / drawn on the grid), the
    mass of the cells east of x = 0, POS and each search's own POS (given the bearings) within 4
    binomial SDs; the POD map against the detected share of each busy cell's draws."""
    model, track = CASES[name]
    evidence = {None: [*earlier_evidence(False), *NOW], "periods": PERIODS}.get(track) or earlier_evidence(track)
    post = bg.posterior(model, GRID, evidence, subdivisions=6)
    draws = DEFINITE_DRAWS if track == "definite" else DRAWS
    positions, factors = simulate(model, evidence, draws, seed=20261127)
    rng = np.random.default_rng(7)
    # each draw detected by each search with its POD, kept by the reports with their likelihood
    searches = [k for k, e in enumerate(evidence) if e.kind == "search"]
    reports = [k for k, e in enumerate(evidence) if e.kind != "search"]  # land too
    found = rng.uniform(size=(draws, len(searches))) >= factors[:, searches]
    reported = np.all(rng.uniform(size=(draws, len(reports))) < factors[:, reports], axis=1)
    x0, x1, y0, y1 = GRID.extent
    on_grid = (positions[:, 0] >= x0) & (positions[:, 0] < x1) & (positions[:, 1] >= y0) & (positions[:, 1] < y1)
    kept = on_grid & reported & ~found.any(axis=1)
    counts = grid_counts(positions[kept], GRID)
    assert chi_square_p(counts, post.values) > ALPHA
    assert binomial_within(int(kept.sum()), int(on_grid.sum()), post.normaliser)
    east = np.broadcast_to(GRID.x[None, :] > 0.0, GRID.shape)
    assert binomial_within(int(counts[east].sum()), int(counts.sum()), float(post.values[east].sum()))
    # POS given the reports: of the draws the reports keep, those some search (each search) finds
    given = on_grid & reported
    assert binomial_within(int((given & found.any(axis=1)).sum()), int(given.sum()), post.pos)
    for j in range(len(searches)):
        assert binomial_within(int((given & found[:, j]).sum()), int(given.sum()), post.search_pos[j])
    assert post.provenance["carried"]["evidence"] == [f"evidence[{k}]" for k, e in enumerate(evidence)
                                                      if e.time_span is not None and e.time_span[1] < model.t]
    # the cumulative POD map: of the draws that end in a cell, the share some search finds (cells
    # with 3000 draws or more; 4 binomial SDs, plus the sub-cell rule's stated 1.7 % of a cell)
    ix = np.floor((positions[on_grid, 0] - x0) / GRID.dx).astype(int)
    iy = np.floor((positions[on_grid, 1] - y0) / GRID.dy).astype(int)
    drawn = np.zeros(GRID.shape)
    hit = np.zeros(GRID.shape)
    np.add.at(drawn, (iy, ix), 1.0)
    np.add.at(hit, (iy, ix), found[on_grid].any(axis=1).astype(float))
    busy = drawn >= 3000
    assert busy.sum() > 20
    share = hit[busy] / drawn[busy]
    sd = np.sqrt(post.pod[busy] * (1.0 - post.pod[busy]) / drawn[busy])
    assert np.all(np.abs(share - post.pod[busy]) <= 4.0 * sd + 0.017 * post.pod[busy] + 1e-12)


def test_polar_lattice_carried_posterior_matches_simulation():
    """On a polar lattice about the last fix (the carried channels at the polar sub-cells'
    centres), with the earlier searches and bearings and an area search at the map's time:
    chi-square over the cells at alpha 1e-3, the normaliser within 4 binomial SDs."""
    model = bg.CAT(**FIG1)
    lattice = bg.PolarLattice(ranges=(0.0, 3400.0), range_step=100.0, bearings=(-math.pi / 2, math.pi / 2),
                              bearing_step=math.pi / 90)
    now = bg.AreaSearch([(-600.0, 2400.0), (100.0, 2300.0), (200.0, 3000.0), (-500.0, 3100.0)], t=model.t, pod=0.5)
    evidence = [*earlier_evidence(False), now]
    post = bg.posterior(model, lattice, evidence, subdivisions=6)
    positions, factors = simulate(model, evidence, DRAWS, seed=11)
    kept = np.random.default_rng(12).uniform(size=DRAWS) < factors.prod(axis=1)
    counts = lattice_counts(positions[kept], lattice)
    assert chi_square_p(counts, post.probability) > ALPHA
    r = np.hypot(positions[:, 0], positions[:, 1])
    b = np.arctan2(positions[:, 0], positions[:, 1])
    on = (r < 3400.0) & (np.abs(b) < math.pi / 2)
    assert binomial_within(int((kept & on).sum()), int(on.sum()), post.normaliser)


class _OwnCells(bg.CAT):
    """A CAT whose carried cells are its own: each channel's density at the cell centre times the
    cell's area (a stand-in for an exact rule, to show the posterior takes it)."""

    def carried_cell_plan(self, grid, pack):
        from bananagrid.engine.carried import evaluate_carried
        from bananagrid.protocol import CellPlan

        def run(ctx):
            xx, yy = np.meshgrid(grid.x, grid.y)
            return evaluate_carried(self, xx, yy, pack) * grid.cell_area, {"own": True}

        return CellPlan(seconds=1.0, run=run, method="centre times area")


def test_a_models_own_carried_cells_take_over():
    """With ``carried_cell_plan`` the posterior's cells are the prior's cells times each cell's
    carried share (channel / prior channel of the plan), times the same-time factors' means:
    here against that formula from the channels at the cell centres, to 1e-12."""
    from bananagrid.engine.carried import evaluate_carried

    model = _OwnCells(**FIG1)
    evidence = earlier_evidence(False)
    post = bg.posterior(model, GRID, evidence)
    assert post.provenance["carried"]["cell_rule"] == "centre times area" and post.provenance["carried"]["own"]
    xx, yy = np.meshgrid(GRID.x, GRID.y)
    p = bg.evidence.packing.pack(evidence, model.t)
    channels = evaluate_carried(model, xx, yy, p)
    share = np.where(channels[0] > 0, channels[p.channel("all")] / np.where(channels[0] > 0, channels[0], 1.0), 1.0)
    q = post.prior * share
    np.testing.assert_allclose(post.values, q / q.sum(), rtol=1e-12, atol=1e-300)
