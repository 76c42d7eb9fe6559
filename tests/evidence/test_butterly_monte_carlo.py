"""Monte Carlo of Butterly's carried map: 10^6 draws of the generative story
(``Butterly.sample_paths``: start, course, speed), each detected by two barrier searches over
intervals with its own POD (random search: 1 - exp(-C x the fraction of the interval its straight
path spends inside the barrier, clipped exactly) and kept with the probability of a bearing
report's likelihood; the survivors histogrammed at the map's time against the carried cell
probabilities (``Butterly.carried_cell_plan``, unnormalised: the expected count of a cell is
N times its mass). The prior is the submarine scene's (scenes/submarine.toml) at 2 h."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

import bananagrid as bg
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.evidence.packing import pack

KN = 1852.0 / 3600.0
T = 7200.0
N = 10**6
ALPHA = 1e-3


def submarine():
    sx, sy, rho = 2000.0, 500.0, 0.5  # scenes/submarine.toml
    return bg.Butterly(mean=(0.0, 0.0), cov=[[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]],
                       speeds=[5 * KN, 10 * KN, 15 * KN], weights=[0.2, 0.5, 0.3], t=T)


#: Two barriers an aircraft flew (x0, x1, y0, y1, t0, t1, coverage): a strip north of the fix
#: in the first half hour, one east of it in the second hour.
BARRIERS = [(-40e3, 40e3, 8e3, 16e3, 1200.0, 3000.0, 1.5), (20e3, 30e3, -50e3, 30e3, 3600.0, 5400.0, 1.0)]
#: A bearing pair taken at 1 h 40 min, pointing near (10 km, -20 km).
FIX = bg.BearingFix(sensors=[(-60e3, -10e3), (15e3, -80e3)], bearings=[math.atan2(70e3, -10e3), math.atan2(-5e3, 60e3)],
                    sigmas=[math.radians(8.0), math.radians(8.0)])
T_BEARING = 6000.0


def evidence():
    out = [bg.AreaSearch([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], t=(t0, t1), coverage=c)
           for x0, x1, y0, y1, t0, t1, c in BARRIERS]
    return out + [bg.BearingReport(FIX, t=T_BEARING)]


def fraction_inside(p0, p1, x0, x1, y0, y1):
    """Exact fraction of each segment p0 -> p1 inside the box (slab clipping)."""
    a, b = np.zeros(len(p0)), np.ones(len(p0))
    d = p1 - p0
    for k, (lo, hi) in enumerate(((x0, x1), (y0, y1))):
        with np.errstate(divide="ignore", invalid="ignore"):
            s1, s2 = (lo - p0[:, k]) / d[:, k], (hi - p0[:, k]) / d[:, k]
        flat = d[:, k] == 0.0
        inside = (p0[:, k] >= lo) & (p0[:, k] <= hi)
        s_lo = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(s1, s2))
        s_hi = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(s1, s2))
        a, b = np.maximum(a, s_lo), np.minimum(b, s_hi)
    return np.clip(b - a, 0.0, 1.0)


def survivors(model, rng):
    times = [t for (*_, t0, t1, _) in BARRIERS for t in (t0, t1)] + [T_BEARING, T]
    paths = model.sample_paths(N, times, rng)
    keep = np.ones(N, dtype=bool)
    for k, (x0, x1, y0, y1, t0, t1, c) in enumerate(BARRIERS):
        pod = -np.expm1(-c * fraction_inside(paths[:, 2 * k], paths[:, 2 * k + 1], x0, x1, y0, y1))
        keep &= rng.uniform(size=N) >= pod
    likelihood = bg.BearingReport(FIX, t=T_BEARING).likelihood(paths[:, -2, 0], paths[:, -2, 1])
    keep &= rng.uniform(size=N) < likelihood
    return paths[keep, -1]


def test_carried_cells_match_monte_carlo():
    """Chi-square over the cells with expected count >= 5 (alpha 1e-3) and region masses (the
    window, its quadrants about its centre, a disc) within 4 sigma, on the window where the
    survivors are (48 km square, 2 km cells; draws outside it are not counted: each cell's
    count is binomial with N and its mass either way). The cell rule at tol 1e-3 (2 Gauss nodes
    per sub-cell of sigma_min and axis: 2e-4 of a normal's mass per sub-cell and axis,
    engine.quadrature.gauss_error(2, 0.93)) and the pack's time rule (at most C 0.35 / 16 per
    barrier crossing in a path's log-weight, of either sign along the crossing times) are far
    below a cell's Poisson SD (>= 1 / sqrt(count) ~ 3 %)."""
    model = submarine()
    grid = bg.Grid.from_bounds(x=(-12e3, 36e3), y=(-48e3, 0.0), step=2000.0)
    pk = pack(evidence(), T)
    cells, _ = model.carried_cell_plan(grid, pk, tol=1e-3).run(WarpContext(np.float64, "cpu", None))
    mass = cells[pk.channel("all")]
    found = survivors(model, np.random.default_rng(20261127))
    counts, _, _ = np.histogram2d(found[:, 1], found[:, 0], bins=[grid.ny, grid.nx],
                                  range=[(grid.origin[1], grid.origin[1] + grid.ny * grid.dy),
                                         (grid.origin[0], grid.origin[0] + grid.nx * grid.dx)])
    expected = N * mass
    big = expected >= 5.0
    chi2 = float(np.sum((counts[big] - expected[big]) ** 2 / expected[big]))
    assert stats.chi2.sf(chi2, int(big.sum()) - 1) > ALPHA, (chi2, int(big.sum()))
    xc, yc = np.meshgrid(grid.x, grid.y)
    regions = [np.ones(mass.shape, bool), (xc > 12e3) & (yc > -24e3), (xc <= 12e3) & (yc > -24e3),
               (xc > 12e3) & (yc <= -24e3), np.hypot(xc - 10e3, yc + 20e3) < 10e3]
    for region in regions:
        p = float(mass[region].sum())
        seen = float(counts[region].sum()) / N
        assert abs(seen - p) <= 4.0 * math.sqrt(p * (1.0 - p) / N), (seen, p)


#: A ship's sonar patrol with the definite-range law (detection range 2 km): north of the fix
#: westward to eastward in the first 75 min, then south (x, y, t).
PATROL = bg.TrackSearch([(-20e3, 10e3, 1800.0), (20e3, 10e3, 4500.0), (20e3, -15e3, 6300.0)], sweep_width=4000.0,
                        law="definite")


def test_definite_track_cells_match_monte_carlo():
    """The patrol alone: 2 x 10^5 draws of the generative story (``sample_paths`` at the track's
    first and last times; a Butterly path is straight, so its position at 300 times per leg
    lies on that segment), each detected iff its smallest sampled range to the searcher is
    within W / 2 (the samples 6-9 s apart, relative speeds below 25 m/s: the sampled range
    overestimates the true one by at most (25 x 9)^2 / (8 x 2000) = 3.2 m, a band of paths
    3 m wide along a corridor 4 km wide, far inside the tolerances). The survivors histogrammed
    at 2 h against the carried cells (channel ``all``): chi-square (alpha 1e-3) and the
    regions within 4 sigma, as above, and POS (1 - the carried mass over the window's prior
    mass, on the window) within 4 sigma of the detected share."""
    from definite_oracle import sampled_approach

    n = 200_000
    model = submarine()
    grid = bg.Grid.from_bounds(x=(-36e3, 36e3), y=(-36e3, 36e3), step=3000.0)
    pk = pack([PATROL], T)
    cells, _ = model.carried_cell_plan(grid, pk, tol=1e-3).run(WarpContext(np.float64, "cpu", None))
    mass = cells[pk.channel("all")]
    prior = cells[pk.channel("prior")]
    rng = np.random.default_rng(20261127)
    track = PATROL.track
    ends = model.sample_paths(n, [track[0, 2], track[-1, 2], T], rng)
    times = np.concatenate([np.linspace(ta, tb, 301)[:-1] for ta, tb in zip(track[:-1, 2], track[1:, 2])]
                           + [track[-1:, 2]])
    detected = np.zeros(n, dtype=bool)
    for a in range(0, n, 20_000):
        u = (times - track[0, 2]) / (track[-1, 2] - track[0, 2])
        p0, p1 = ends[a:a + 20_000, 0], ends[a:a + 20_000, 1]
        positions = p0[:, None, :] + u[None, :, None] * (p1 - p0)[:, None, :]
        detected[a:a + 20_000] = sampled_approach(track, positions, times) <= 0.5 * PATROL.sweep_width
    found = ends[~detected, 2]
    counts, _, _ = np.histogram2d(found[:, 1], found[:, 0], bins=[grid.ny, grid.nx],
                                  range=[(grid.origin[1], grid.origin[1] + grid.ny * grid.dy),
                                         (grid.origin[0], grid.origin[0] + grid.nx * grid.dx)])
    expected = n * mass
    big = expected >= 5.0
    chi2 = float(np.sum((counts[big] - expected[big]) ** 2 / expected[big]))
    assert stats.chi2.sf(chi2, int(big.sum()) - 1) > ALPHA, (chi2, int(big.sum()))
    xc, yc = np.meshgrid(grid.x, grid.y)
    regions = [np.ones(mass.shape, bool), (xc > 0) & (yc > 0), (xc <= 0) & (yc > 0), (xc > 0) & (yc <= 0),
               np.hypot(xc - 10e3, yc - 5e3) < 10e3]
    for region in regions:
        p = float(mass[region].sum())
        seen = float(counts[region].sum()) / n
        assert abs(seen - p) <= 4.0 * math.sqrt(p * (1.0 - p) / n), (seen, p)
    inside = (ends[:, 2, 0] >= grid.origin[0]) & (ends[:, 2, 0] < grid.origin[0] + grid.nx * grid.dx) & (
        ends[:, 2, 1] >= grid.origin[1]) & (ends[:, 2, 1] < grid.origin[1] + grid.ny * grid.dy)
    pos = 1.0 - float(mass.sum()) / float(prior.sum())
    m = int(inside.sum())
    assert 0.1 < pos < 0.9
    assert abs(float(detected[inside].mean()) - pos) <= 4.0 * math.sqrt(pos * (1.0 - pos) / m)
