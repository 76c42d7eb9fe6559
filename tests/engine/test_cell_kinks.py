"""Cell probabilities over every kink and seam of every model, against independent oracles.

A Gauss rule is only as good as the smoothness of what it integrates. Each model's densities
have their own kinks: a polar banana's angle wraps from pi to -pi behind the start (the density
is continuous there, its slope across the ray is not), its origin (1 / r), the improved
variant's P_sigma = 0 edge (beyond it the density is 0; at it the range SD falls to 0, so the
ridge narrows to a point), and with heading noise the same edge as a jump; a bearing fix's
bearings wrap behind each station, and the station itself is a point about which the density
changes with the direction; a Butterly is smooth (a normal start convolved with a course and a
speed law); the CAT's folds are caustics, which its own rule takes exactly in the acceleration
(``tests/engine/test_cell_probabilities.py`` holds it to its stated 5e-5 at the folds).

Cells are placed across each: the oracles (``tests/support/cell_oracle.py``) are SciPy's adaptive
``quad`` in polar coordinates about the kink's point with the kinks and the corners' bearings
as breakpoints, exact in r for a polar banana's radial law written with ``math``, nested over
``model.pdf`` otherwise. Stated accuracy (docs/accuracy.md, cell probabilities): 1e-8 relative for the
engine's quadrature.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, assume, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.domains.pose import Pose

import cell_oracle

#: The stated accuracy of every cell rule but the CAT's (docs/accuracy.md): relative to the cell, plus an
#: absolute floor of 1e-14 for cells in a density's far tail (the rule's error there is an
#: absolute one, far below any cell a planner looks at; the same floor as
#: tests/engine/test_cell_probabilities.py).
RTOL = 1e-8
ATOL = 1e-14


def _check(model, grid, oracle, min_checked=1):
    got = bg.rasterise(model, grid, quantity="probability").values
    checked = 0
    for i, j, cell in cell_oracle.grid_cells(grid):
        want = oracle(cell)
        assert abs(got[i, j] - want) <= RTOL * want + ATOL, (cell, got[i, j], want, got[i, j] / want - 1)
        checked += want > 1e-6
    assert checked >= min_checked  # cells that hold mass, not only tails
    return checked


def _polar_oracle(model, seams):
    law = cell_oracle.polar_banana_law(model)
    return lambda cell: cell_oracle.polar_law_cell(law, model.pose.origin, cell, seams)


def _behind(model, distance):
    """The world point ``distance`` behind the start, on the seam."""
    h = model.pose.heading
    ox, oy = model.pose.origin
    return ox - distance * math.sin(h), oy - distance * math.cos(h)


# --- polar bananas: the seam behind the start, the origin, the P_sigma = 0 edge -----------------

#: Broad bananas whose mass reaches behind the start (sigma_phi = 1 and 2 rad, the range SD 1/10
#: and 1 of v0 t), posed at an arbitrary heading.
BROAD = {
    "rough-wide": dict(v0=10.0, t=100.0, sigma_a=0.02, sigma_omega=0.04, variant="rough"),
    "improved-wide": dict(v0=10.0, t=100.0, sigma_a=0.02, sigma_omega=0.02, variant="improved"),
    "rough-slow": dict(v0=1.0, t=100.0, sigma_a=0.02, sigma_omega=0.04, variant="rough"),
}


@pytest.mark.parametrize("name", BROAD)
def test_polar_cells_on_the_seam_behind_the_start(name):
    """Cells centred on the ray behind the start (the angle's wrap inside them), from the origin
    to far behind, against the oracle with the seam as a breakpoint (they were off by 7.6e-4
    relative when the seam was not a break of the rule)."""
    model = bg.PolarBanana(**BROAD[name], pose=Pose(origin=(300.0, -120.0), heading=0.7))
    v0t = model.v0 * model.t
    seams = model.seams()[:, 2]
    checked = 0
    for distance in (0.0, 0.05 * v0t, 0.3 * v0t):
        for side in (0.02 * v0t, 0.1 * v0t):
            checked += _check(model, cell_oracle.cells_around(_behind(model, distance), side), _polar_oracle(model, seams),
                              min_checked=0)
    assert checked >= 6  # cells that hold mass, not only tails


def _edge_point(model):
    law = cell_oracle.polar_banana_law(model)
    edge = model.sigma_positive_limit
    mu = law(model.pose.heading + edge)[1]
    ox, oy = model.pose.origin
    b = model.pose.heading + edge
    return edge, (ox + mu * math.sin(b), oy + mu * math.cos(b))


@pytest.mark.filterwarnings("ignore:P_sigma")
@pytest.mark.parametrize("params", [dict(v0=1.0, t=10.0, sigma_a=0.5, sigma_omega=0.3),
                                    dict(v0=1.0, t=10.0, sigma_a=0.3, sigma_omega=0.2)])
def test_improved_cells_at_the_p_sigma_edge(params):
    """Where P_sigma (11) reaches 0 within (-pi, pi) (sigma_a t beyond about 2 v0), the range SD
    falls to 0 on the edge ray and the density's ridge ends in a point of unbounded density:
    cells of 0.05 to 0.5 of the mean range about that point (a tensor rule was off by 8 % in the
    cell holding it, and by 1e-3 in those beside)."""
    model = bg.PolarBanana(**params, variant="improved", pose=Pose(origin=(-40.0, 25.0), heading=-2.2))
    edge, point = _edge_point(model)
    assert edge < math.pi
    seams = model.seams()[:, 2]
    assert len(seams) == 3
    scale = math.dist(point, model.pose.origin)
    for side in (0.05 * scale, 0.15 * scale, 0.5 * scale):
        _check(model, cell_oracle.cells_around(point, side), _polar_oracle(model, seams), min_checked=3)


def test_polar_cells_at_the_origin_with_the_seam():
    """The origin (density infinite like 1 / r) inside a cell, at a corner and on a side, with
    the seam behind the start through the cells."""
    model = bg.PolarBanana(**BROAD["rough-slow"], pose=Pose(origin=(0.0, 0.0), heading=0.0))
    seams = model.seams()[:, 2]
    oracle = _polar_oracle(model, seams)
    for origin in [(-15.0, -15.0), (-20.0, -20.0), (-20.0, -13.0)]:  # centred, corner, side
        grid = bg.Grid(origin=origin, dx=10.0, dy=10.0, nx=4, ny=4)
        _check(model, grid, oracle, min_checked=4)


@pytest.mark.filterwarnings("ignore:P_sigma")
@seed(20261127)  # a fixed seed, not derandomize (whose examples depend on the checkout's path)
@settings(max_examples=12, deadline=None, derandomize=False, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(variant=st.sampled_from(["rough", "improved"]),
       sigma_phi=st.floats(0.3, 2.5), range_sd=st.floats(0.02, 2.0), heading=st.floats(-math.pi, math.pi),
       where=st.sampled_from(["behind", "origin", "edge"]), side=st.floats(0.01, 0.5), offset=st.floats(-0.5, 0.5))
def test_polar_kinks_over_the_domain(variant, sigma_phi, range_sd, heading, where, side, offset):
    """Bearing SDs from 0.3 to 2.5 rad, range SDs from 0.02 to 2 of v0 t, any heading: 3 x 3
    cells of 0.01 to 0.5 v0 t on the seam behind the start, at the origin, or at the improved
    edge where it lies within (-pi, pi); the kink anywhere in the middle cell."""
    v0, t = 10.0, 100.0
    sigma_a = 2.0 * range_sd * v0 * t / t**2  # range SD sigma_a t^2 / 2
    model = bg.PolarBanana(v0=v0, t=t, sigma_a=sigma_a, sigma_omega=2.0 * sigma_phi / t, variant=variant,
                           pose=Pose(origin=(120.0, -70.0), heading=heading))
    v0t = v0 * t
    if where == "edge" and variant == "improved" and model.sigma_positive_limit < math.pi:
        _, point = _edge_point(model)
    elif where == "origin":
        point = model.pose.origin
    else:
        point = _behind(model, 0.2 * v0t)
    cell = side * v0t
    grid = cell_oracle.cells_around((point[0] + offset * cell, point[1] - 0.37 * offset * cell), cell)
    _check(model, grid, _polar_oracle(model, model.seams()[:, 2]), min_checked=0)


@pytest.mark.filterwarnings("ignore:P_sigma")
def test_polar_heading_cells_at_the_seam_and_the_edge():
    """With heading noise (order 2) the improved edge is a jump (SD[r | theta] stays positive to
    it): cells on it and behind the start, against nested ``quad`` of ``pdf`` about the origin
    with the seams as breakpoints."""
    model = bg.PolarBanana(v0=1.0, t=10.0, sigma_a=0.5, sigma_omega=0.3, variant="improved", sigma_heading=0.4)
    seams = model.seams()[:, 2]
    assert len(seams) == 3
    edge = seams[1]
    oracle = lambda cell: cell_oracle.pdf_polar_cell(model, (0.0, 0.0), cell, seams)  # noqa: E731
    mean, _ = model.conditional_moments([edge - 1e-3])
    point = (float(mean[0]) * math.sin(edge), float(mean[0]) * math.cos(edge))
    _check(model, cell_oracle.cells_around(point, 4.0, n=2), oracle)
    # beyond the edge the improved density is 0, behind the start too: the seam there on a rough one
    rough = bg.PolarBanana(v0=1.0, t=10.0, sigma_a=0.5, sigma_omega=0.3, variant="rough", sigma_heading=0.4)
    seams = rough.seams()[:, 2]
    _check(rough, cell_oracle.cells_around(_behind(rough, 8.0), 4.0, n=2),
           lambda cell: cell_oracle.pdf_polar_cell(rough, (0.0, 0.0), cell, seams))


def test_polar_lattice_cells_cut_at_the_seam():
    """A lattice whose bearings run from 0.1 rad past north all the way round: the cell holding
    the seam behind the start (bearing pi) is integrated on each side of it; against ``quad``
    of the same law in (r, b) with pi as a breakpoint."""
    model = bg.PolarBanana(**BROAD["rough-wide"])
    lattice = bg.PolarLattice(ranges=(0.0, 400.0), range_step=100.0, bearings=(0.1, 0.1 + 2.0 * math.pi),
                              bearing_step=2.0 * math.pi / 9)
    got = bg.rasterise(model, lattice).probability
    law = cell_oracle.polar_banana_law(model)
    from scipy import integrate
    from scipy.special import ndtr
    b_edges, r_edges = lattice.bearing_edges, lattice.range_edges
    j = int(np.flatnonzero((b_edges[:-1] < math.pi) & (math.pi < b_edges[1:]))[0])
    for i in range(lattice.n_range):
        def f(b):
            g, mu, sd = law(b)
            return g * (ndtr((r_edges[i + 1] - mu) / sd) - ndtr((r_edges[i] - mu) / sd))
        want = integrate.quad(f, b_edges[j], b_edges[j + 1], points=[math.pi], epsabs=0.0, epsrel=1e-12)[0]
        # the lattice's stated accuracy: 1e-9 absolute per cell (docs/accuracy.md, polar lattice)
        assert abs(got[i, j] - want) <= 1e-9, (i, got[i, j], want)
        assert abs(got[i, j] - want) <= RTOL * want + ATOL, (i, got[i, j], want)


# --- bearing fixes: the wrap behind a station, a station inside a cell ------------------------


def test_bearing_cells_at_a_station_and_behind_it():
    """A broad exact two-station fix (bearing SDs 0.5 and 0.6 rad, so the density reaches its
    stations): cells holding a station and straddling the ray behind it, against nested
    ``quad`` of ``pdf`` about the station: the exact fix declares its seams, the rays behind its
    stations (without them the cell holding the station was off by 24 %); the linear fix none."""
    assert bg.BearingFix(sensors=[(0.0, 0.0), (1000.0, 0.0)], bearings=[0.5, -0.4], sigmas=[0.5, 0.6],
                         variant="linear").seams().shape == (0, 3)
    model = bg.BearingFix(sensors=[(0.0, 0.0), (1000.0, 0.0)], bearings=[0.5, -0.4], sigmas=[0.5, 0.6])
    oracle = lambda cell: cell_oracle.pdf_polar_cell(model, (0.0, 0.0), cell, [0.5 - math.pi])  # noqa: E731
    _check(model, cell_oracle.cells_around((0.0, 0.0), 60.0, n=2), oracle)


# --- Butterly: smooth everywhere --------------------------------------------------------------


def test_butterly_cells_about_its_ring_and_start():
    """No kink: cells on the start's mean and across the ring, against ``dblquad`` of ``pdf``."""
    model = bg.Butterly(mean=(50.0, -20.0), cov=[[100.0**2, 3000.0], [3000.0, 80.0**2]], speeds=[0.0, 2.0],
                        weights=[0.3, 0.7], t=100.0)
    for point in [(50.0, -20.0), (250.0, -20.0)]:
        _check(model, cell_oracle.cells_around(point, 60.0, n=2), lambda cell: cell_oracle.pdf_cell(model, cell, eps=1e-15))


# --- seams of several points in one cell: crossing back rays, two stations in a cell ----------


def _station_geometry(rng, n, close):
    """A contact at the origin seen by ``n`` stations 1-3 km away (bearing SDs 0.8 to 2 rad, so
    the map reaches behind every station), one of them ``close`` (a fraction of a km) beside
    another when given."""
    angles = rng.uniform(0.0, 2.0 * math.pi, n)
    sensors = rng.uniform(1000.0, 3000.0, n)[:, None] * np.column_stack((np.sin(angles), np.cos(angles)))
    if close is not None:
        turn = rng.uniform(0.0, 2.0 * math.pi)
        sensors[1] = sensors[0] + close * 1000.0 * np.array([math.sin(turn), math.cos(turn)])
    sigmas = rng.uniform(0.8, 2.0, n)
    bearings = bg.bearing_to(sensors, np.zeros(2)) + sigmas * rng.normal(size=n) * 0.3
    return sensors, bearings, sigmas


def _back_ray_crossings(model):
    """Where two stations' seams (the rays behind them) cross."""
    seams = model.seams()
    out = []
    for i in range(len(seams)):
        for j in range(i + 1, len(seams)):
            (ax, ay, a), (bx, by, b) = seams[i], seams[j]
            ux, uy, vx, vy = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
            den = ux * vy - uy * vx
            qx, qy = bx - ax, by - ay
            s, t = (qx * vy - qy * vx) / den, (qx * uy - qy * ux) / den
            if s > 0.0 and t > 0.0:
                out.append((ax + s * ux, ay + s * uy))
    return out


@pytest.mark.filterwarnings("ignore:bearings cross at", "ignore:the fix lies behind")
@seed(20261127)  # a fixed seed, not derandomize (whose examples depend on the checkout's path)
@settings(max_examples=8, deadline=None, derandomize=False, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
          phases=[Phase.explicit, Phase.generate])  # each example is seconds of quad: no shrinking
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 4), where=st.sampled_from(["crossing", "stations"]),
       side=st.floats(40.0, 400.0), offset=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
       close=st.floats(0.1, 0.45))
def test_bearing_cells_where_seams_of_several_stations_meet(seed, n, where, side, offset, close):
    """Random three- and four-station fixes: 3 x 3 cells of 40 to 400 m over the point where two
    stations' back rays cross (the seams of two points in one cell), or over two stations a
    tenth to a half of a cell apart (two seams' start points in one cell), against nested
    Cartesian ``quad`` with every seam's crossing and start as a breakpoint (only one point's
    seams were breaks of the rule before)."""
    rng = np.random.default_rng(seed)
    sensors, bearings, sigmas = _station_geometry(rng, n, close * side / 1000.0 if where == "stations" else None)
    try:
        model = bg.BearingFix(sensors=sensors, bearings=bearings, sigmas=sigmas)
    except bg.BananagridError:
        assume(False)
    if where == "crossing":
        crossings = [c for c in _back_ray_crossings(model) if math.hypot(*c) < 4000.0]  # where the map has mass
        assume(crossings)
        centre = crossings[0]
    else:
        centre = tuple(0.5 * (sensors[0] + sensors[1]))
    grid = cell_oracle.cells_around((centre[0] + offset[0] * side, centre[1] + offset[1] * side), side)
    density = cell_oracle.bearing_density(model)
    _check(model, grid, lambda cell: cell_oracle.seams_cell(density, cell, model.seams()))


# --- polar lattices about any origin: seams that cross the cells along curves ------------------


def _lattice_model(kind, rng):
    """A broad two-station exact fix (bearing SDs 1 to 2 rad: mass behind both stations), a broad
    rough or improved polar banana, or an improved one whose P_sigma = 0 edge lies inside
    (-pi, pi) (its ridge narrowing to a point), posed at an arbitrary heading; and the length
    its seams are worth following (m)."""
    if kind == "bearing":
        return bg.BearingFix(sensors=[(0.0, 0.0), (300.0, 0.0)], bearings=[0.5, -0.4],
                             sigmas=rng.uniform(1.0, 2.0, 2)), 1000.0
    pose = Pose(origin=(300.0, -120.0), heading=float(rng.uniform(-math.pi, math.pi)))
    if kind == "improved-edge":
        return bg.PolarBanana(v0=1.0, t=10.0, sigma_a=0.5, sigma_omega=0.3, variant="improved", pose=pose), 30.0
    return bg.PolarBanana(**BROAD["improved-wide" if kind == "improved" else "rough-wide"], pose=pose), 1000.0


def _lattice_about(origin, centre, side, heading=0.3):
    """A 3 x 3 polar lattice about ``origin`` whose middle cell (``side`` m in range and arc)
    is centred on ``centre``."""
    r_c = math.dist(centre, origin)
    b_c = math.atan2(centre[0] - origin[0], centre[1] - origin[1]) - heading
    db = side / r_c
    return bg.PolarLattice(ranges=(r_c - 1.5 * side, r_c + 1.5 * side), range_step=side,
                           bearings=(b_c - 1.5 * db, b_c + 1.5 * db), bearing_step=db,
                           pose=Pose(origin=origin, heading=heading))


@pytest.mark.filterwarnings("ignore:P_sigma")
def test_the_exact_lattice_oracle_against_sampling_and_nested_quad():
    """``cell_oracle.banana_lattice_cell`` (exact in the banana's own range) is checked two
    independent ways: against nested ``quad`` in the lattice's (b, r) on a rough banana's
    ridge away from its start, where that one converges (both adaptive to 1e-11 or better:
    agreement to 1e-10 relative), and against the fraction of 2 million samples of
    ``model.sample`` in each cell (times the plane mass, ``cell_oracle.banana_mass``) where the
    nested one does not converge: cells about the improved banana's P_sigma = 0 edge, where
    the ridge narrows to a point, and about its start (within 5 binomial SDs; a wrong clip of
    the rays would be off by a share of the cell)."""
    rough = bg.PolarBanana(**BROAD["rough-wide"], pose=Pose(origin=(300.0, -120.0), heading=0.7))
    ridge = (300.0 + 900.0 * math.sin(1.0), -120.0 + 900.0 * math.cos(1.0))
    lattice = _lattice_about((-400.0, 500.0), ridge, 120.0)
    density = cell_oracle.polar_banana_density(rough)
    for i in range(3):
        for j in range(3):
            rr, bb = lattice.range_edges[i:i + 2], lattice.bearing_edges[j:j + 2]
            exact = cell_oracle.banana_lattice_cell(rough, lattice.pose.origin, lattice.pose.heading, rr, bb)
            nested = cell_oracle.lattice_cell(density, lattice.pose.origin, lattice.pose.heading, rr, bb, rough.seams())
            assert exact > 1e-4 and abs(exact - nested) <= 1e-10 * exact, ((i, j), exact, nested)
    edge = bg.PolarBanana(v0=1.0, t=10.0, sigma_a=0.5, sigma_omega=0.3, variant="improved",
                          pose=Pose(origin=(300.0, -120.0), heading=-0.4))
    _, point = _edge_point(edge)
    mass = cell_oracle.banana_mass(edge)
    rng = np.random.default_rng(5)
    samples = np.concatenate([edge.sample(500_000, rng) for _ in range(4)])
    n = len(samples)
    for lattice in (_lattice_about((310.0, -95.0), point, 1.5), _lattice_about((290.0, -100.0), edge.pose.origin, 3.0)):
        (ox, oy), h = lattice.pose.origin, lattice.pose.heading
        r = np.hypot(samples[:, 0] - ox, samples[:, 1] - oy)
        b = lattice.bearing_edges[0] + (np.arctan2(samples[:, 0] - ox, samples[:, 1] - oy) - h
                                        - lattice.bearing_edges[0]) % (2.0 * math.pi)
        i = np.searchsorted(lattice.range_edges, r) - 1
        j = np.searchsorted(lattice.bearing_edges, b) - 1
        inside = (i >= 0) & (i < 3) & (j >= 0) & (j < 3)
        counts = np.zeros((3, 3))
        np.add.at(counts, (i[inside], j[inside]), 1.0)
        held = 0
        for i in range(3):
            for j in range(3):
                exact = cell_oracle.banana_lattice_cell(edge, (ox, oy), h, lattice.range_edges[i:i + 2],
                                                        lattice.bearing_edges[j:j + 2])
                share = exact / mass
                assert abs(counts[i, j] / n - share) <= 5.0 * math.sqrt(share * (1.0 - share) / n) + 1.0 / n, \
                    ((i, j), counts[i, j] / n, share)
                held += share > 1e-3
        assert held >= 3  # cells that hold mass, not only tails


#: The lattice's stated accuracy in every cell (docs/accuracy.md, polar lattice): 1e-9 of the mass.
LATTICE_ATOL = 1e-9


#: Examples per kind of model and placement of the origin (16 pairs): 3 here (48 in all, about
#: 60 s on two cores); the sweep reported in docs/accuracy.md ran 8 each.
ANY_ORIGIN_EXAMPLES = 3


@pytest.mark.filterwarnings("ignore:P_sigma")
@pytest.mark.parametrize("kind", ["bearing", "rough", "improved", "improved-edge"])
@pytest.mark.parametrize("where", ["anywhere", "on the seam", "behind the start", "holding the start"])
# a fixed seed, not derandomize: hypothesis derives a derandomised test's seed from where the
# module was imported from, so each checkout drew other examples (and found other edges)
@seed(20261127)
@settings(max_examples=ANY_ORIGIN_EXAMPLES, deadline=None, derandomize=False, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
          phases=[Phase.explicit, Phase.generate])
@given(seed=st.integers(0, 2**32 - 1), along=st.floats(0.1, 0.5), size=st.floats(0.15, 0.4),
       away=st.floats(2.5, 20.0), offset=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)))
def test_polar_lattice_cells_over_seams_from_any_origin(kind, where, seed, along, size, away, offset):
    """Polar lattices whose origin is anywhere (2.5 to 20 cells from the cells), on a seam
    between its start and the cells, or on its line behind the start: 3 x 3 cells of 0.15 to
    0.4 of their distance from the seam's start, placed over the seam 0.1 to 0.5 of the
    model's reach from it (a station's back ray, a polar banana's wrap behind the start or its
    P_sigma = 0 edge, where the ridge narrows to a point), or cells around the start itself (a
    station, a polar banana's 1 / r origin). Against, for a polar banana, an integral exact in
    its own range about its start (``cell_oracle.banana_lattice_cell``: adaptive ``quad`` over
    its bearing with every change of the ray's clip and every crossing of the ridge as a
    breakpoint), for a bearing fix nested ``quad`` in the lattice's (b, r) with the seams'
    crossings and the nearest approach to each station as breakpoints. A seam that misses the
    origin is a curve in (r, b): only seams from the origin were cut before (4e-4 to 8e-2
    relative off); then a banana's cells near its start, behind it and at its edge, held to
    1e-7, were off by up to 2.6e-7 (a tensor rule about the lattice's origin where the ridge's
    bends are compressed near the start or its SD narrows), swept cells by up to 4.2e-8 (a
    corner's bearing a hair past a tangent's, a ray along a cell's side, the ridge crossing a
    cell's edge as a sharp step), and with the start or a station on a cell's edge (offsets of
    +-0.5) by 2.4e-4 and 1e-7 (no tangent break for a point on a circle; the neighbouring
    cells not swept). Every kind and placement is drawn ANY_ORIGIN_EXAMPLES times."""
    rng = np.random.default_rng(seed)
    model, reach = _lattice_model(kind, rng)
    seams = model.seams()
    # the edge banana has no mass behind its start: its edges' seams
    qx, qy, beta = seams[int(rng.integers(1, 3)) if kind == "improved-edge" else int(rng.integers(len(seams)))]
    v = np.array([math.sin(beta), math.cos(beta)])
    distance = along * reach
    side = size * distance
    centre = np.array([qx, qy]) + (0.0 if where == "holding the start" else distance) * v
    away = away * side
    if where in ("anywhere", "holding the start"):
        turn = rng.uniform(0.0, 2.0 * math.pi)
        origin = centre + away * np.array([math.sin(turn), math.cos(turn)])
    elif where == "on the seam":
        origin = np.array([qx, qy]) + rng.uniform(0.0, distance - 2.5 * side) * v
    else:
        origin = np.array([qx, qy]) - away * v
    heading = float(rng.uniform(-math.pi, math.pi))
    r_c = float(np.hypot(*(centre - origin)))
    b_c = math.atan2(*(centre - origin)) - heading
    db = side / r_c
    r_c, b_c = r_c + offset[0] * side, b_c + offset[1] * db
    lattice = bg.PolarLattice(ranges=(r_c - 1.5 * side, r_c + 1.5 * side), range_step=side,
                              bearings=(b_c - 1.5 * db, b_c + 1.5 * db), bearing_step=db,
                              pose=Pose(origin=tuple(origin), heading=heading))
    got = bg.rasterise(model, lattice).probability
    if kind == "bearing":
        density = cell_oracle.bearing_density(model)
        oracle = lambda rr, bb: cell_oracle.lattice_cell(density, tuple(origin), heading, rr, bb, seams)  # noqa: E731
    else:
        oracle = lambda rr, bb: cell_oracle.banana_lattice_cell(model, tuple(origin), heading, rr, bb)  # noqa: E731
    crossed = _crossed_by_seams(lattice, seams)
    assert crossed  # the seam runs through the cells
    checked = 0
    for i in range(lattice.n_range):
        for j in range(lattice.n_bearing):
            want = oracle(lattice.range_edges[i:i + 2], lattice.bearing_edges[j:j + 2])
            assert abs(got[i, j] - want) <= LATTICE_ATOL, ((i, j), got[i, j], want)
            if (i, j) in crossed:
                assert abs(got[i, j] - want) <= RTOL * want + ATOL, ((i, j), got[i, j], want)
                checked += RTOL * want > ATOL
    # an example whose crossed cells hold only tails (below ATOL / RTOL) tests the absolute bound
    # alone: it is not counted, so that every counted example holds a crossed cell to its bound
    assume(checked >= 1)



@pytest.mark.filterwarnings("ignore:P_sigma")
def test_swept_cell_whose_ray_grazes_a_bounding_line_past_the_ridge():
    """The example a clean clone's sweep drew (its seed before the sweep's was fixed): an edge
    banana's lattice about an origin behind its start, whose crossed cell (2, 1) the sweep
    about the start put 2.8e-7 below the integral exact in range. On a bearing piece 2.4e-3
    rad wide the rays nearly run along the cell's bounding line, whose crossing moves 2,000 m
    per radian, 30 times the farthest range that sized the piece's sub-intervals, past the
    ridge 0.4 m wide: one 8-node rule for a normal CDF's whole turn. Held to RTOL now."""
    test_polar_lattice_cells_over_seams_from_any_origin.hypothesis.inner_test(
        kind="improved-edge", where="behind the start", seed=8388609, along=0.30474826258707755,
        size=0.39723011863556235, away=6.777203431868179, offset=(2.220446049250313e-16, 0.46088326310533656))

@pytest.mark.filterwarnings("ignore:P_sigma")
@pytest.mark.parametrize("kind", ["rough", "improved", "improved-edge"])
def test_banana_lattices_about_another_origin_in_every_cell(kind):
    """A 5 x 6 lattice about an origin 0.8 of the banana's reach from its start, over the start,
    the ground behind it and (for the edge banana) its P_sigma = 0 edge: the cells the rule
    leaves to the tensor rule about the lattice's origin and those it sweeps about the start
    alike, every one against the integral exact in the banana's range, to the lattice's 1e-9
    absolute (1e-8 relative where a seam crosses: docs/accuracy.md). Before, the rough banana's cell
    beside its start was 9.7e-9 off, the improved one's 1.2e-4 relative in a crossed cell and
    the edge banana's 2.5e-7 beside its edge (cells left to the tensor rule or swept without
    every break)."""
    model, reach = _lattice_model(kind, np.random.default_rng(3))
    start = np.array(model.pose.origin)
    h = model.pose.heading + 2.4  # from beside and behind the start
    origin = start + 0.8 * reach * np.array([math.sin(h), math.cos(h)])
    towards = math.atan2(*(start - origin))
    lattice = bg.PolarLattice(ranges=(0.3 * reach, 1.4 * reach), range_step=0.22 * reach,
                              bearings=(towards - 0.6, towards + 0.6), bearing_step=0.2, pose=Pose(origin=tuple(origin)))
    got = bg.rasterise(model, lattice).probability
    crossed = _crossed_by_seams(lattice, model.seams())
    held = 0
    for i in range(lattice.n_range):
        for j in range(lattice.n_bearing):
            want = cell_oracle.banana_lattice_cell(model, tuple(origin), 0.0, lattice.range_edges[i:i + 2],
                                                   lattice.bearing_edges[j:j + 2])
            assert abs(got[i, j] - want) <= LATTICE_ATOL, ((i, j), got[i, j], want)
            if (i, j) in crossed:
                assert abs(got[i, j] - want) <= RTOL * want + ATOL, ((i, j), got[i, j], want)
            held += want > 1e-4
    assert held >= 8  # cells that hold mass, not only tails


def _crossed_by_seams(lattice, seams, samples=20001):
    """The cells (i, j) of a polar lattice that points along the seams fall in (each seam
    sampled at ``samples`` points out to twice the lattice's outer range beyond its start)."""
    ox, oy = lattice.pose.origin
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    out = set()
    for qx, qy, beta in seams:
        s = np.linspace(0.0, 2.0 * (r_edges[-1] + math.hypot(qx - ox, qy - oy)), samples)
        x, y = qx + s * math.sin(beta) - ox, qy + s * math.cos(beta) - oy
        r = np.hypot(x, y)
        b = b_edges[0] + (np.arctan2(x, y) - lattice.pose.heading - b_edges[0]) % (2.0 * math.pi)
        i = np.searchsorted(r_edges, r) - 1
        j = np.searchsorted(b_edges, b) - 1
        inside = (i >= 0) & (i < lattice.n_range) & (j >= 0) & (j < lattice.n_bearing)
        out |= set(zip(i[inside].tolist(), j[inside].tolist()))
    return out

