"""Polar lattices: cells in (range, bearing) about a pose.

Oracles are independent of the kernels: the polar-banana densities (8), (11) written below with
``math`` for scipy.integrate.dblquad, ``oracles.cat_density`` (exact CAT, float64 NumPy)
integrated by scipy.integrate.cubature, scipy.stats' bivariate normal for a linearised bearing
fix, and the Cartesian grid's mass (``bg.rasterise(model, Grid).mass``).
"""

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import cubature, dblquad
from scipy.stats import multivariate_normal

import bananagrid as bg
import bananagrid.engine.polar_cells as lattice_module
import oracles
from bananagrid.models.bearing import BearingFix, bearing_to
from bananagrid.domains.grid import MAX_CELLS

from cases import FIG1

V0, T, SA, SW = FIG1["v0"], FIG1["t"], FIG1["sigma_a"], FIG1["sigma_omega"]

#: A posed model and a second pose for lattices that do not share it (arbitrary, non-trivial).
MODEL_POSE = bg.Pose(origin=(1200.0, -800.0), heading=0.7)
OTHER_POSE = bg.Pose(origin=(-500.0, 300.0), heading=-0.4)

#: Two stations 20 km apart and a contact about 31 km out (as in test_bearing).
STATIONS = np.array([[0.0, 0.0], [20000.0, 0.0]])
CONTACT = np.array([8000.0, 30000.0])


def bearing_fix():
    return BearingFix(STATIONS, bearing_to(STATIONS, CONTACT), [0.01, 0.02], variant="linear")


# ----------------------------------------------------------------------------------------------
# Independent densities (per m^2, world coordinates)
# ----------------------------------------------------------------------------------------------


def _to_local(pose, x, y):
    """World to the pose's local frame (x right of the heading, y along it), by hand."""
    dx, dy = x - pose.origin[0], y - pose.origin[1]
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    return dx * c - dy * s, dx * s + dy * c


def _polar_banana(variant, pose):
    """Scalar p0 ("rough") or p1 ("improved") of the polar-banana paper, eqs. (7), (8), (11):
    g(phi; 0, sigma_omega t / 2) g(r; mu, sd) / r, written with ``math`` so dblquad is fast."""
    s_phi = 0.5 * SW * T

    def density(x, y):
        xl, yl = _to_local(pose, x, y)
        phi, r = math.atan2(xl, yl), math.hypot(xl, yl)
        sinc = math.sin(phi) / phi if phi != 0.0 else 1.0
        if variant == "rough":
            mu, sd = V0 * T * sinc, 0.5 * SA * T * T
        else:
            scc = (4.0 * sinc - math.cos(phi)) / 3.0
            mu = V0 * T * sinc + SA**2 * T**3 / (12.0 * V0) * (phi**2 / s_phi**2 - 1.0) * scc
            sd = 0.5 * SA * T * T * (1.0 + SA**2 / (6.0 * V0**2) * (T * T / 12.0 - phi**2 / SW**2)) * scc
        if sd <= 0.0 or r == 0.0:
            return 0.0
        z = (r - mu) / sd
        return math.exp(-0.5 * (phi / s_phi) ** 2 - 0.5 * z * z) / (2.0 * math.pi * s_phi * sd * r)

    return density


def _bivariate_normal(fix):
    law = multivariate_normal(mean=fix.fix, cov=fix.covariance)
    return lambda x, y: float(law.pdf([x, y]))


def _dblquad(density, lattice_pose, r0, r1, b0, b1):
    """int_{r0}^{r1} int_{b0}^{b1} p(O + r u(h + b)) r db dr with the world map written out."""
    (ox, oy), h = lattice_pose.origin, lattice_pose.heading

    def integrand(b, r):
        return r * density(ox + r * math.sin(h + b), oy + r * math.cos(h + b))

    value, _ = dblquad(integrand, r0, r1, b0, b1, epsabs=1e-15, epsrel=1e-12)
    return value


def _cat_cubature(pose, lattice_pose, r0, r1, b0, b1):
    """The exact CAT density of ``oracles`` integrated over the cell by adaptive Gauss-Kronrod."""
    (ox, oy), h = lattice_pose.origin, lattice_pose.heading

    def integrand(points):
        r, b = points[:, 0], points[:, 1]
        xl, yl = _to_local(pose, ox + r * np.sin(h + b), oy + r * np.cos(h + b))
        return r * oracles.cat_density(xl, yl, V0, T, SA, SW)

    res = cubature(integrand, [r0, b0], [r1, b1], rtol=1e-11, atol=1e-15)
    assert res.status == "converged"
    return float(res.estimate)


def _cell_about(model_pose, lattice_pose, phi, dr, db):
    """A cell of size (dr, db) centred, as seen from ``lattice_pose``, on the polar-banana ridge
    point at bearing ``phi`` of the model (range v0 t sinc(phi) from the model's origin)."""
    reach = V0 * T * (math.sin(phi) / phi if phi else 1.0)
    wx = model_pose.origin[0] + reach * math.sin(model_pose.heading + phi)
    wy = model_pose.origin[1] + reach * math.cos(model_pose.heading + phi)
    dx, dy = wx - lattice_pose.origin[0], wy - lattice_pose.origin[1]
    r = math.hypot(dx, dy)
    b = (math.atan2(dx, dy) - lattice_pose.heading + math.pi) % (2 * math.pi) - math.pi
    return r - dr / 2, r + dr / 2, b - db / 2, b + db / 2


def _single_cell(pose, r0, r1, b0, b1):
    return bg.PolarLattice(ranges=(r0, r1), range_step=r1 - r0, bearings=(b0, b1), bearing_step=b1 - b0, pose=pose)


# ----------------------------------------------------------------------------------------------
# Cell probabilities against independent integrals
# ----------------------------------------------------------------------------------------------

IDENTITY = bg.Pose()

#: (name, model factory, lattice pose, cell (r0, r1, b0, b1), oracle). The core cell sits on the
#: ridge at phi = 0 (a small share of the mass, about 1e-3), the flank cell at phi = 0.6 rad (two
#: bearing SDs out), the coarse cell covers almost the whole banana in one cell.
CELL_CASES = [
    ("improved core", lambda: bg.PolarBanana(**FIG1), IDENTITY, (2780.0, 2800.0, -0.005, 0.005), "polar:improved"),
    ("improved flank", lambda: bg.PolarBanana(**FIG1), IDENTITY, (2600.0, 2640.0, 0.55, 0.6), "polar:improved"),
    ("improved coarse", lambda: bg.PolarBanana(**FIG1), IDENTITY, (1500.0, 3500.0, -1.0, 1.0), "polar:improved"),
    ("rough flank", lambda: bg.PolarBanana(**FIG1, variant="rough"), IDENTITY, (2600.0, 2650.0, 0.55, 0.6), "polar:rough"),
    (
        "posed, same pose, core",
        lambda: bg.PolarBanana(**FIG1, pose=MODEL_POSE), MODEL_POSE, (2770.0, 2810.0, -0.02, 0.02), "polar:improved",
    ),
    (
        "posed, other pose, core",
        lambda: bg.PolarBanana(**FIG1, pose=MODEL_POSE), OTHER_POSE,
        _cell_about(MODEL_POSE, OTHER_POSE, 0.0, 40.0, 0.01), "polar:improved",
    ),
    (
        "posed, other pose, coarse flank",
        lambda: bg.PolarBanana(**FIG1, pose=MODEL_POSE), OTHER_POSE,
        _cell_about(MODEL_POSE, OTHER_POSE, -0.5, 600.0, 0.2), "polar:improved",
    ),
    ("CAT core", lambda: bg.CAT(**FIG1), IDENTITY, (2780.0, 2800.0, -0.005, 0.005), "cat"),
    ("CAT flank, posed", lambda: bg.CAT(**FIG1, pose=MODEL_POSE), MODEL_POSE, (2600.0, 2640.0, 0.55, 0.6), "cat"),
    (
        "bearing fix about a station",
        bearing_fix, bg.Pose(origin=tuple(STATIONS[0])), (30900.0, 31200.0, 0.255, 0.265), "normal",
    ),
]


def _oracle(kind, model, pose, cell):
    if kind.startswith("polar:"):
        return _dblquad(_polar_banana(kind.split(":")[1], model.pose), pose, *cell)
    if kind == "cat":
        return _cat_cubature(model.pose, pose, *cell)
    return _dblquad(_bivariate_normal(model), pose, *cell)


@pytest.mark.parametrize("name, make_model, pose, cell, oracle", CELL_CASES, ids=[c[0] for c in CELL_CASES])
def test_cell_probability_matches_independent_integral(name, make_model, pose, cell, oracle):
    model = make_model()
    got = bg.rasterise(model, _single_cell(pose, *cell))
    assert got.probability.shape == (1, 1)
    want = _oracle(oracle, model, pose, cell)
    assert want > 1e-4  # every case holds real mass
    # Tolerance: the rule's claim (rasterise_lattice), within about 1e-9 of the total mass (1)
    # per cell. The references are far tighter: dblquad is asked for 1e-12 relative, cubature
    # for 1e-11, and the CAT kernel's roots are refined to a few ulps. Measured: 1e-15 to 1e-11
    # absolute (the largest, 1.2e-11, for the bearing fix, whose cell is 1.04 x 1.1 of its
    # minor SD: the rule's own error, gone at GAUSS_TOL = 1e-14). GAUSS_TOL = 1e-5 fails here.
    assert abs(got.probability[0, 0] - want) <= 1e-9


# ----------------------------------------------------------------------------------------------
# Densities at the centres
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "model, pose",
    [
        (bg.CAT(**FIG1), IDENTITY),
        (bg.PolarBanana(**FIG1, pose=MODEL_POSE), MODEL_POSE),
        (bg.PolarBanana(**FIG1, pose=MODEL_POSE), OTHER_POSE),
    ],
    ids=["cat", "posed-same", "posed-other"],
)
def test_density_is_range_times_pdf_at_centres(model, pose):
    lattice = bg.PolarLattice(ranges=(2000.0, 3500.0), range_step=50.0, bearings=(-1.0, 1.0), bearing_step=0.05, pose=pose)
    got = bg.rasterise(model, lattice)
    assert got.density.shape == lattice.shape == (30, 40)
    x, y = lattice.world_centres
    # the world map written out independently: O + r (sin(h + b), cos(h + b)), same float ops
    rr, bb = np.meshgrid(lattice.range_centres, lattice.bearing_centres, indexing="ij")
    np.testing.assert_allclose(x, pose.origin[0] + rr * np.sin(pose.heading + bb), rtol=0, atol=1e-9)
    np.testing.assert_allclose(y, pose.origin[1] + rr * np.cos(pose.heading + bb), rtol=0, atol=1e-9)
    # exactly r * pdf: the same kernel at the same points, one float64 product
    np.testing.assert_array_equal(got.density, lattice.range_centres[:, None] * model.pdf(x, y))


def test_centres_edges_and_areas():
    lattice = bg.PolarLattice(ranges=(100.0, 400.0), range_step=100.0, bearings=(-0.3, 0.3), bearing_step=0.2)
    np.testing.assert_allclose(lattice.range_edges, [100.0, 200.0, 300.0, 400.0])
    np.testing.assert_allclose(lattice.range_centres, [150.0, 250.0, 350.0])
    np.testing.assert_allclose(lattice.bearing_edges, [-0.3, -0.1, 0.1, 0.3], atol=1e-15)
    np.testing.assert_allclose(lattice.bearing_centres, [-0.2, 0.0, 0.2], atol=1e-15)
    # (r1^2 - r0^2) / 2 db: 15000 * 0.2, 25000 * 0.2, 35000 * 0.2 m^2
    np.testing.assert_allclose(lattice.cell_areas, np.repeat([[3000.0], [5000.0], [7000.0]], 3, axis=1), rtol=1e-14)
    assert lattice.cell_areas.sum() == pytest.approx(lattice.area, rel=1e-14)
    assert lattice.describe()["n_range"] == 3 and lattice.describe()["n_bearing"] == 3
    # bearing 0 is the heading; +pi/2 is to starboard: heading east puts bearing pi/2 south
    east = bg.PolarLattice(ranges=(0.0, 2.0), range_step=2.0, bearings=(0.0, 1.0), bearing_step=1.0,
                           pose=bg.Pose(origin=(10.0, 20.0), heading=math.pi / 2))
    x, y = east.to_world(1.0, math.pi / 2)
    assert (x, y) == pytest.approx((10.0, 19.0), abs=1e-12)


# ----------------------------------------------------------------------------------------------
# The lattice's probabilities sum to the Cartesian grid's mass
# ----------------------------------------------------------------------------------------------

_FULL = dict(bearings=(-math.pi, math.pi), bearing_step=2 * math.pi / 180)

#: (name, model, lattice, grid bounds). Each lattice and grid holds the whole density (beyond
#: 1e-12), so both are the model's total mass. The grid's midpoint rule is spectrally accurate
#: for a smooth density that vanishes at its edges: its error is about exp(-2 pi^2 (s / h)^2)
#: for the narrowest feature s (83 m radial SD of the banana, 288 m for the fix) at step h =
#: 10 or 50 m, far below 1e-15.
MASS_CASES = [
    (
        "CAT figure 1", bg.CAT(**FIG1),
        bg.PolarLattice(ranges=(0.0, 3500.0), range_step=50.0, **_FULL),
        dict(x=(-3500.0, 3500.0), y=(-3500.0, 3500.0), step=10.0),
    ),
    (
        "PolarBanana improved", bg.PolarBanana(**FIG1),
        bg.PolarLattice(ranges=(0.0, 3500.0), range_step=25.0, **_FULL),
        dict(x=(-3500.0, 3500.0), y=(-3500.0, 3500.0), step=10.0),
    ),
    (
        "CAT posed, lattice on the same pose", bg.CAT(**FIG1, pose=MODEL_POSE),
        bg.PolarLattice(ranges=(0.0, 3500.0), range_step=50.0, bearings=(-2.5, 2.5), bearing_step=0.025, pose=MODEL_POSE),
        dict(x=(-2300.0, 4700.0), y=(-4300.0, 2700.0), step=10.0),
    ),
    (
        "PolarBanana posed, lattice on another pose", bg.PolarBanana(**FIG1, pose=MODEL_POSE),
        bg.PolarLattice(ranges=(0.0, 6000.0), range_step=50.0, **_FULL, pose=OTHER_POSE),
        dict(x=(-2300.0, 4700.0), y=(-4300.0, 2700.0), step=10.0),
    ),
    (
        "PolarBanana, lattice facing back: the banana straddles bearing +-pi", bg.PolarBanana(**FIG1),
        bg.PolarLattice(ranges=(0.0, 3500.0), range_step=25.0, **_FULL, pose=bg.Pose(heading=math.pi)),
        dict(x=(-3500.0, 3500.0), y=(-3500.0, 3500.0), step=10.0),
    ),
    (
        "BearingFix linear, lattice about a station", bearing_fix(),
        bg.PolarLattice(ranges=(20000.0, 42000.0), range_step=500.0, bearings=(0.0, 0.5), bearing_step=0.01,
                        pose=bg.Pose(origin=tuple(STATIONS[0]))),
        dict(x=(-4000.0, 20000.0), y=(18000.0, 43000.0), step=50.0),
    ),
]


@pytest.mark.parametrize("name, model, lattice, bounds", MASS_CASES, ids=[c[0] for c in MASS_CASES])
def test_probabilities_sum_to_grid_mass(name, model, lattice, bounds):
    polar = bg.rasterise(model, lattice)
    grid_mass = bg.rasterise(model, bg.Grid.from_bounds(**bounds)).mass
    assert polar.mass == pytest.approx(np.sum(polar.probability), rel=1e-15)
    assert grid_mass > 0.999  # both hold the whole (approximation's) density
    # Tolerance 1e-9: the lattice rule's claim is about 1e-9 of the mass per cell, and a
    # composite Gauss rule over a density's whole support does far better (its errors cancel
    # between sub-cells like the grid's midpoint rule); measured differences are below 1e-15.
    # The grid side adds nothing measurable (see MASS_CASES).
    assert polar.mass == pytest.approx(grid_mass, abs=1e-9)


# ----------------------------------------------------------------------------------------------
# A full circle of bearings wraps
# ----------------------------------------------------------------------------------------------


def test_full_circle_wraps():
    model = bg.PolarBanana(**FIG1)
    step = 2 * math.pi / 72
    base = bg.rasterise(model, bg.PolarLattice(ranges=(2000.0, 3400.0), range_step=100.0, bearings=(-math.pi, math.pi),
                                               bearing_step=step))
    # starting the circle 10 cells further clockwise gives the same cells, rolled by 10 columns
    for b0, shift in ((-math.pi + 10 * step, 10), (0.0, 36), (math.pi / 2, 54)):
        lattice = bg.PolarLattice(ranges=(2000.0, 3400.0), range_step=100.0, bearings=(b0, b0 + 2 * math.pi),
                                  bearing_step=step)
        got = bg.rasterise(model, lattice)
        # the nodes differ from the base lattice's only by the rounding of b0 + j step (1e-15
        # rad at most), which moves a probability by at most its derivative times that
        np.testing.assert_allclose(got.probability, np.roll(base.probability, -shift, axis=1), rtol=1e-9, atol=1e-18)
        assert got.mass == pytest.approx(base.mass, rel=1e-12)


# ----------------------------------------------------------------------------------------------
# Result object, precision, threads, caps
# ----------------------------------------------------------------------------------------------


def test_normalise_keeps_raw_mass_and_provenance():
    lattice = bg.PolarLattice(ranges=(2500.0, 3000.0), range_step=50.0, bearings=(-0.5, 0.5), bearing_step=0.05)
    raw = bg.rasterise(bg.PolarBanana(**FIG1), lattice)
    assert isinstance(raw, bg.PolarRaster) and not raw.normalised
    assert 0.5 < raw.mass < 0.99  # a partial lattice: it misses the flanks
    norm = raw.normalise()
    assert norm.normalised and norm.mass == raw.mass
    assert norm.probability.sum() == pytest.approx(1.0, rel=1e-14)
    np.testing.assert_allclose(norm.density, raw.density / raw.mass, rtol=1e-15)
    assert norm.normalise() is norm
    prov = raw.provenance
    assert prov["model"] == "PolarBanana" and prov["dtype"] == "float64" and prov["device"] == "cpu"
    assert prov["lattice"] == lattice.describe()
    assert prov["scale_rule"] == "model frame"
    assert prov["radial_nodes_per_cell"] >= 1 and prov["total_nodes"] > lattice.n_range * lattice.n_bearing
    assert prov["accuracy"]["estimated"] <= prov["accuracy"]["target"] * 2
    np.testing.assert_array_equal(raw.ranges, lattice.range_centres)


def test_float32_and_threads():
    lattice = bg.PolarLattice(ranges=(2500.0, 3000.0), range_step=50.0, bearings=(-0.5, 0.5), bearing_step=0.05)
    model = bg.CAT(**FIG1)
    ref = bg.rasterise(model, lattice, threads=2)
    one = bg.rasterise(model, lattice, threads=1)
    np.testing.assert_array_equal(one.probability, ref.probability)  # chunks, not threads, fix the sums
    single = bg.rasterise(model, lattice, dtype=np.float32)
    assert single.density.dtype == np.float32 and single.probability.dtype == np.float64
    # float32 kernels: about 1e-6 relative per density near the ridge (the CAT suite's bound)
    np.testing.assert_allclose(single.probability, ref.probability, rtol=1e-4, atol=1e-9)


def test_cap_warns_when_it_limits_accuracy(monkeypatch):
    # one 2 km x 2 rad cell needs ~50 radial and ~130 angular sub-intervals; allow 2
    monkeypatch.setattr(lattice_module, "MAX_SUBINTERVALS", 2)
    lattice = bg.PolarLattice(ranges=(1500.0, 3500.0), range_step=2000.0, bearings=(-1.0, 1.0), bearing_step=2.0)
    with pytest.warns(UserWarning, match=r"node caps \(2 sub-intervals .* without an accuracy bound"):
        capped = bg.rasterise(bg.PolarBanana(**FIG1), lattice)
    assert capped.provenance["accuracy"]["estimated"] == 1.0  # the bound is void; the result is
    # 2 x 8 nodes per axis on the whole banana: 0.986 against dblquad's 0.99941
    assert capped.probability[0, 0] == pytest.approx(0.99941, abs=0.02)
    monkeypatch.setattr(lattice_module, "MAX_SUBINTERVALS", 4)
    monkeypatch.setattr(lattice_module, "MAX_NODES", 500)  # 4 x 8 nodes per axis > 500: halves to 2
    with pytest.warns(UserWarning, match=r"500 nodes in all; 2 sub-intervals used"):
        bg.rasterise(bg.PolarBanana(**FIG1), lattice)


def test_no_warning_within_caps():
    lattice = bg.PolarLattice(ranges=(1500.0, 3500.0), range_step=2000.0, bearings=(-1.0, 1.0), bearing_step=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bg.rasterise(bg.PolarBanana(**FIG1), lattice)


# ----------------------------------------------------------------------------------------------
# Bad input: one test per kind, each asserting the argument and value in the message
# ----------------------------------------------------------------------------------------------

GOOD = dict(ranges=(0.0, 100.0), range_step=10.0, bearings=(-1.0, 1.0), bearing_step=0.5)


@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(ranges=(-1.0, 100.0)), r"ranges = \(-1.0, 100.0\): the range starts below zero \(ranges\[0\] = -1.0\)"),
        (dict(range_step=0.0), r"range_step = 0.0: must be > 0"),
        (dict(range_step=-10.0), r"range_step = -10.0: must be > 0"),
        (dict(bearing_step=0.0), r"bearing_step = 0.0: must be > 0"),
        (dict(bearing_step=-0.5), r"bearing_step = -0.5: must be > 0"),
        (dict(ranges=(100.0, 100.0)), r"ranges = \(100.0, 100.0\): the upper bound must exceed the lower"),
        (dict(bearings=(1.0, -1.0)), r"bearings = \(1.0, -1.0\): the upper bound must exceed the lower"),
        (dict(bearings=(-4.0, 4.0), bearing_step=1.0), r"bearings = \(-4.0, 4.0\): the span 8.0 rad exceeds 2 pi"),
        (dict(ranges=(0.0, math.nan)), r"ranges\[1\] = nan: must be finite"),
        (dict(bearings=(-math.inf, 1.0)), r"bearings\[0\] = -inf: must be finite"),
        (dict(ranges=5.0), r"ranges = 5.0: expected a pair \(low, high\)"),
        (dict(range_step="10"), r"range_step = '10': expected a real number"),
        (dict(pose=(0.0, 0.0)), r"pose = \(0.0, 0.0\): expected a bananagrid.Pose"),
    ],
    ids=[
        "range-below-zero", "range-step-zero", "range-step-negative", "bearing-step-zero", "bearing-step-negative",
        "empty-ranges", "reversed-bearings", "span-over-2pi", "nan-range", "inf-bearing", "ranges-not-pair",
        "step-not-number", "pose-not-pose",
    ],
)
def test_bad_lattice_rejected(changes, message):
    with pytest.raises(bg.BananagridError, match=message):
        bg.PolarLattice(**{**GOOD, **changes})


def test_step_must_divide_span_and_nearest_is_suggested():
    with pytest.raises(
        bg.BananagridError,
        match=r"range_step = 7.0: does not divide the range span 100.0 m \(14.2857 steps\); the nearest step "
        r"that divides it is 7.142857142857143 \(14 cells\)",
    ):
        bg.PolarLattice(**{**GOOD, "range_step": 7.0})
    with pytest.raises(bg.BananagridError, match=r"bearing_step = 0.3: does not divide the bearing span 2.0 rad .* "
                       r"nearest step that divides it is 0.2857142857142857 \(7 cells\)"):
        bg.PolarLattice(**{**GOOD, "bearing_step": 0.3})
    # within 1e-9 relative counts as dividing: 2 pi / 360 does not divide 2 pi exactly in floats
    assert bg.PolarLattice(**{**GOOD, **_FULL}).n_bearing == 180


def test_too_many_cells():
    with pytest.raises(bg.BananagridError, match=rf"polar lattice of .* cells .* the limit is {MAX_CELLS:,} cells"):
        bg.PolarLattice(ranges=(0.0, 1e6), range_step=1e-2, bearings=(-1.0, 1.0), bearing_step=1e-2)


def test_unknown_model_and_non_lattice():
    lattice = bg.PolarLattice(**GOOD)
    with pytest.raises(bg.BananagridError, match="model = str: polar lattices know the length scales of"):
        bg.rasterise("banana", lattice)
    with pytest.raises(bg.BananagridError, match="lattice = 'grid': expected a bananagrid.PolarLattice"):
        lattice_module.rasterise_lattice(bg.CAT(**FIG1), "grid")


def test_heading_cat_lattice_sums_to_grid_mass():
    """A CAT with heading noise on a polar lattice: one table serves every chunk, and the cell
    probabilities sum to the Cartesian grid's mass (both hold the whole banana; the grid's
    midpoint rule and the table's 1e-6 interpolation error bound the difference)."""
    from bananagrid.models import _cat_heading as heading

    model = bg.CAT(**FIG1, sigma_heading=math.pi / 30)
    lattice = bg.PolarLattice(ranges=(0.0, 4000.0), range_step=100.0, bearings=(-math.pi, math.pi),
                              bearing_step=math.radians(2.0))
    heading._remembered_table.cache_clear()
    polar = bg.rasterise(model, lattice)
    assert heading._remembered_table.cache_info().misses == 1
    grid = bg.rasterise(model, bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-600.0, 3600.0), step=10.0))
    assert abs(polar.mass - 1.0) < 1e-5 and abs(polar.mass - grid.mass) < 1e-5
