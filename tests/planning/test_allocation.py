"""Optimal search effort on one map (bg.allocate): against closed forms of search theory, an
independent solver of the Lagrange condition written here (Brent's method on the multiplier over
unsorted cells, each law's coverage in its own closed form), a brute-force search over effort
splits of tiny maps, the Kuhn-Tucker certificate of optimality, and sweeps over maps whose
densities span 1e-300 to 1 and efforts from a millionth to a million times the map's area."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st
from scipy import optimize, special, stats

import bananagrid as bg
from bananagrid.planning.detection import DetectionLaw


def probability_map(p, step=1.0):
    ny, nx = p.shape
    grid = bg.Grid(origin=(0.0, 0.0), dx=step, dy=step, nx=nx, ny=ny)
    return bg.Raster(values=np.asarray(p, dtype=float), grid=grid, mass=float(np.sum(p)), quantity="probability")


#: Each law's coverage where d b'(e) = lam, of ln(d / lam) >= 0, written here from the law's
#: formula (not the package's).
ORACLE_COVERAGE = {
    # b = 1 - exp(-e): b' = exp(-e) = lam / d
    "exponential": lambda log_ratio: log_ratio,
    # b = erf(sqrt(pi) e / 2): b' = exp(-pi e^2 / 4) = lam / d
    "inverse_cube": lambda log_ratio: np.sqrt(4.0 / math.pi * log_ratio),
}
ORACLE_POD = {"exponential": lambda e: 1.0 - np.exp(-e),
              "inverse_cube": lambda e: special.erf(math.sqrt(math.pi) / 2.0 * e)}


def oracle(p, areas, z, law):
    """(POS, effort per cell) from the Lagrange condition solved by Brent's method on ln lambda
    over the cells as given (no sorting, no cumulative sums), sums by math.fsum."""
    p, areas = np.ravel(p), np.broadcast_to(areas, np.shape(p)).ravel()
    d = np.where(p > 0, p / areas, 0.0)
    log_d = np.log(np.where(p > 0, p, 1.0)) - np.log(areas)

    def effort(log_lam):
        e = np.where(p > 0, ORACLE_COVERAGE[law](np.maximum(log_d - log_lam, 0.0)), 0.0)
        return e, math.fsum(areas * e)

    hi = float(log_d[p > 0].max())
    lo = hi - 1.0
    while effort(lo)[1] < z:
        lo -= 2.0 * (hi - lo)
    log_lam = optimize.brentq(lambda s: effort(s)[1] - z, lo, hi, xtol=1e-300, rtol=4 * np.finfo(float).eps)
    e = effort(log_lam)[0]
    return math.fsum(p * ORACLE_POD[law](e)), areas * e, d


def test_uniform_target_random_search_is_koopmans_formula():
    """A target uniform over a region of area A: POS = 1 - exp(-Z / A) (Koopman 1946, the
    random-search formula), the effort spread evenly."""
    p = np.full((40, 70), 1.0 / 2800)
    for z in (1e-3, 350.0, 2800.0, 1e5):
        plan = bg.allocate(probability_map(p, step=2.0), z)
        # 1e-12: a few roundings in sums over 2,800 equal cells
        assert plan.pos == pytest.approx(-math.expm1(-z / (2800 * 4.0)), rel=1e-12)
        assert np.ptp(plan.effort.values) <= 1e-12 * plan.effort.values.max()
        plan = bg.allocate(probability_map(p, step=2.0), z, law="inverse_cube")
        assert plan.pos == pytest.approx(special.erf(math.sqrt(math.pi) / 2 * z / 11200.0), rel=1e-12)


def test_circular_normal_target_approaches_stones_closed_form():
    """A circular normal target (sd s) under random search: the optimal POS is
    1 - (1 + H) exp(-H), H = sqrt(Z / (pi s^2)) (Stone 1975, Example 2.2.8). On cells the
    optimum spreads effort evenly within each cell, so it lies below the continuous one and
    approaches it at second order in the cell size."""
    s, z = 100.0, 2.0e5
    h_big = math.sqrt(z / (math.pi * s * s))
    want = 1.0 - (1.0 + h_big) * math.exp(-h_big)
    errors = []
    for step in (20.0, 10.0, 5.0):
        edges = np.arange(-800.0, 800.0 + step / 2, step)
        px = np.diff(stats.norm.cdf(edges, scale=s))
        plan = bg.allocate(probability_map(np.outer(px, px), step=step), z)
        errors.append(want - plan.pos)
    assert all(e > 0 for e in errors)  # cells can only lose against the continuous optimum
    # second order: halving the cell divides the loss by 4 (3.5 to 4.5 allows the next order)
    assert 3.5 < errors[0] / errors[1] < 4.5 and 3.5 < errors[1] / errors[2] < 4.5
    assert errors[2] < 1e-4


def test_polar_lattice_cells_use_their_sector_areas():
    """A circular normal on a polar lattice about its centre: the cell probabilities in closed
    form (exp(-r0^2 / 2 s^2) - exp(-r1^2 / 2 s^2)) db / 2 pi; the plan against the oracle with the
    lattice's exact sector areas."""
    s = 50.0
    lattice = bg.PolarLattice(ranges=(0.0, 400.0), range_step=5.0, bearings=(-math.pi, math.pi),
                              bearing_step=math.pi / 36)
    r = lattice.range_edges
    ring = -np.diff(np.exp(-0.5 * (r / s) ** 2))
    prob = np.outer(ring, np.diff(lattice.bearing_edges) / (2 * math.pi))
    polar = bg.PolarRaster(density=np.zeros_like(prob), probability=prob, lattice=lattice, mass=float(prob.sum()))
    plan = bg.allocate(polar, 3.0e4)
    want_pos, want_effort, _ = oracle(prob, lattice.cell_areas, 3.0e4, "exponential")
    # 1e-9: the bound; the two solvers differ by roundings of sums over 5,760 cells
    assert plan.pos == pytest.approx(want_pos, rel=1e-9)
    assert np.abs(plan.cell_effort.ravel() - want_effort).max() <= 1e-9 * 3.0e4
    assert plan.effort.shape == lattice.shape


@seed(20261127)
@settings(max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(rng_seed=st.integers(0, 2**32 - 1), law=st.sampled_from(["exponential", "inverse_cube"]),
       spread=st.floats(0.0, 300.0), relative_effort=st.floats(-6.0, 6.0), zeros=st.floats(0.0, 0.9),
       polar=st.booleans())
def test_allocation_equals_an_independent_solver(rng_seed, law, spread, relative_effort, zeros, polar):
    """Maps of 3,000 cells whose probabilities span up to 10^-spread (to 1e-300), some cells
    empty, equal or unequal cell areas, efforts 1e-6 to 1e6 times the map's area: POS to 1e-9
    relative and each cell's effort to 1e-9 of the total, against :func:`oracle`; and the
    Kuhn-Tucker certificate: every cell with effort has the marginal gain lambda, every cell
    without has d b'(0) <= lambda."""
    rng = np.random.default_rng(rng_seed)
    p = 10.0 ** (-spread * rng.random((50, 60)))
    p[rng.random(p.shape) < zeros] = 0.0
    p[0, 0] = max(p[0, 0], 1e-3)  # never an empty map
    p /= p.sum()
    areas = 10.0 ** rng.uniform(-1, 3, p.shape) if polar else 4.0
    z = float(np.sum(np.broadcast_to(areas, p.shape))) * 10.0 ** relative_effort
    plan = bg.allocate(_map_with_areas(p, areas), z, law=law)
    want_pos, want_effort, d = oracle(p, areas, z, law)
    assert plan.pos == pytest.approx(want_pos, rel=1e-9)
    assert np.abs(plan.cell_effort.ravel() - want_effort).max() <= 1e-9 * z
    # 1e-12 relative: the effort adds up (a few roundings in a pairwise sum of 3,000 terms)
    assert math.fsum(plan.cell_effort.ravel()) == pytest.approx(z, rel=1e-12)
    coverage = (plan.cell_effort / np.broadcast_to(areas, p.shape)).ravel()
    gain = d * bg.detection_law(law).dpod(coverage)
    active = coverage > 0
    # 1e-9: the gains are equal up to the roundings of ln and exp of the coverage (e <= 1e3 here)
    assert np.allclose(gain[active], plan.marginal_gain, rtol=1e-9, atol=0)
    assert (d[~active] <= plan.marginal_gain * (1 + 1e-12)).all()


def _map_with_areas(p, areas):
    """A Raster on a unit grid when the areas are one number, else a stand-in PolarRaster whose
    lattice reports the given areas (the allocation reads only its cell areas)."""
    if np.ndim(areas) == 0:
        return probability_map(p, step=math.sqrt(areas))

    class Lattice:
        cell_areas = areas
        shape = p.shape

    return bg.PolarRaster(density=np.zeros_like(p), probability=p, lattice=Lattice(), mass=float(p.sum()))


def test_no_split_of_effort_beats_the_plan_on_tiny_maps():
    """Brute force: on three cells, every split of the effort on a 1/400 lattice of the simplex
    gives at most the plan's POS, and the best of them is within the lattice's resolution."""
    rng = np.random.default_rng(7)
    for law in ("exponential", "inverse_cube", "definite"):
        for _ in range(5):
            p = rng.dirichlet(np.ones(3)) * rng.uniform(0.3, 1.0)
            areas = rng.uniform(1.0, 10.0, 3)
            z = float(areas.sum() * rng.uniform(0.05, 3.0))
            plan = bg.allocate(_map_with_areas(p.reshape(1, 3), areas.reshape(1, 3)), z, law=law)
            i, j = np.meshgrid(np.arange(401), np.arange(401), indexing="ij")
            keep = i + j <= 400
            split = np.stack([i[keep], j[keep], 400 - i[keep] - j[keep]], axis=1) / 400.0 * z
            pod = bg.detection_law(law).pod(split / areas)
            brute = (pod * p).sum(axis=1)
            assert brute.max() <= plan.pos * (1 + 1e-12)
            # within the resolution: moving z / 400 between cells costs at most that effort times
            # the largest marginal gain, max d b'(0)
            assert plan.pos - brute.max() <= 2 * z / 400 * (p / areas).max()


def test_definite_range_fills_the_densest_cells_first():
    p = np.array([[0.1, 0.4, 0.2, 0.3]])
    plan = bg.allocate(probability_map(p, step=1.0), 2.5, law="definite")
    # cells 0.4 and 0.3 whole, half of 0.2: POS 0.4 + 0.3 + 0.1
    assert plan.pos == pytest.approx(0.8, rel=1e-15)
    np.testing.assert_allclose(plan.effort.values, [[0.0, 1.0, 0.5, 1.0]])
    assert plan.marginal_gain == pytest.approx(0.2)
    plan = bg.allocate(probability_map(p, step=1.0), 10.0, law="definite")
    assert plan.pos == pytest.approx(1.0) and plan.marginal_gain == 0.0  # more effort than cells


def test_the_pos_curve_is_the_optimum_at_each_effort_and_concave():
    rng = np.random.default_rng(3)
    p = rng.random((30, 30)) ** 4
    p /= p.sum()
    cells = probability_map(p, step=10.0)
    efforts = np.linspace(0.0, 4.0e5, 41)
    for law in ("exponential", "inverse_cube", "definite"):
        plan = bg.allocate(cells, 1.0e5, law=law)
        curve = plan.pos_curve(efforts)
        assert curve[0] == 0.0
        assert curve[10] == pytest.approx(plan.pos, rel=1e-12)
        assert (np.diff(curve) >= -1e-15).all()  # more effort never finds less
        # concave: the POS a further step buys never grows (1e-12: roundings)
        assert (np.diff(curve, 2) <= 1e-12).all()
        # the marginal gain is the curve's slope at the plan's effort (central difference of
        # step 1 m^2 against a curvature of at most gain / effort: 1e-6 relative)
        slope = (plan.pos_curve([1.0e5 + 1.0])[0] - plan.pos_curve([1.0e5 - 1.0])[0]) / 2.0
        if law != "definite":
            assert slope == pytest.approx(plan.marginal_gain, rel=1e-6)


def test_a_law_of_ones_own_gives_the_same_plan():
    """An exponential law given as a user's DetectionLaw (no inverse: solved by bisection)
    equals the closed form."""
    law = DetectionLaw("mine", pod=lambda e: 1.0 - np.exp(-e), dpod=lambda e: np.exp(-e))
    rng = np.random.default_rng(5)
    p = rng.random((20, 25))
    p /= p.sum()
    cells = probability_map(p, step=3.0)
    mine, ours = bg.allocate(cells, 2000.0, law=law), bg.allocate(cells, 2000.0)
    assert mine.pos == pytest.approx(ours.pos, rel=1e-12)
    assert np.abs(mine.cell_effort - ours.cell_effort).max() <= 1e-9 * 2000.0


@pytest.mark.parametrize("cells, effort, law, words", [
    ("density", 10.0, "exponential", "quantity=\"probability\""),
    ("nan", 10.0, "exponential", "not finite"),
    ("negative", 10.0, "exponential", "negative"),
    ("empty", 10.0, "exponential", "no probability"),
    ("over one", 10.0, "exponential", "sum to"),
    ("ok", 0.0, "exponential", "effort = 0.0"),
    ("ok", -1.0, "exponential", "effort = -1.0"),
    ("ok", math.inf, "exponential", "effort = inf"),
    ("ok", "lots", "exponential", 'effort = "lots"'),
    ("ok", 10.0, "gaussian", "law = 'gaussian'"),
    ("list", 10.0, "exponential", "expected a Raster"),
])
def test_bad_input_is_one_line_naming_it(cells, effort, law, words):
    p = np.full((4, 5), 0.05)
    maps = {"ok": probability_map(p), "density": bg.Raster(values=p, grid=probability_map(p).grid, mass=1.0),
            "nan": probability_map(np.where(p > 0, np.nan, p)), "negative": probability_map(p - 0.06),
            "empty": probability_map(0 * p), "over one": probability_map(2 * p), "list": p.tolist()}
    with pytest.raises(bg.BananagridError) as error:
        bg.allocate(maps[cells], effort, law=law)
    assert words in str(error.value) and "\n" not in str(error.value)


def test_laws_that_are_not_concave_are_refused():
    with pytest.raises(bg.BananagridError, match="not concave"):
        # b = 1 - exp(-e - e^2): b' = (1 + 2 e) exp(-e - e^2) rises from 1 to 1.075 at e = 0.1
        DetectionLaw("rising", pod=lambda e: -np.expm1(-e - e**2), dpod=lambda e: (1 + 2 * e) * np.exp(-e - e**2))
    with pytest.raises(bg.BananagridError, match="pod.0. must be 0"):
        DetectionLaw("offset", pod=lambda e: 0.5 + 0 * e, dpod=lambda e: np.exp(-e))
