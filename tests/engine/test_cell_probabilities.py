"""Cell probabilities on grids: ``bg.rasterise(model, grid, quantity="probability")``.

References (``tests/support/cell_oracle.py``): the CAT cells exact in the acceleration by NumPy line
clipping and SciPy's adaptive ``quad`` over the turn rate (not the kernel's walk or its rule);
the other models by SciPy ``dblquad`` of their density, in polar coordinates about a polar
density's origin; Monte Carlo from each model's own ``sample``; and the mass of a grid that holds
the whole support.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rerun.chunk import RrdReader
from scipy import integrate, stats

import bananagrid as bg
from bananagrid.domains.pose import Pose
from bananagrid.models.cat import cat_position
from bananagrid.scenes.load import parse_scene
from bananagrid.scenes.run import run_scene

import cell_oracle
import test_cat_caustics as caustics

#: The stated error of the CAT cells (``CAT.grid_cells``): relative to the cell's probability,
#: plus an absolute floor far below any cell a planner looks at. Each omega interval is a
#: ribbon of lines interpolated linearly between its edges and integrated between the corner
#: passes (so a line running along a cell side is no longer a jump, as it was for the midpoint
#: rule we had first: 1.2e-2 over this sweep, 1e-1 on thin bananas). What is left is the
#: interpolation, kept below CELL_CURVE_TOL = 1e-6 of the scale a share changes over: measured
#: 4.3e-6 over 100 draws of this sweep (4.3e-5 with the tolerance at 1e-5: it scales with it).
CAT_RTOL = 5e-5
CAT_ATOL = 1e-12
#: The engine's quadrature: Gauss-Legendre sized to 1e-10 of the mass per sub-cell; measured
#: below 1e-10 relative against dblquad (whose own tolerance is 1e-9 relative).
QUADRATURE_RTOL = 1e-8


# --- CAT: exact in the acceleration ----------------------------------------------------------


@pytest.mark.parametrize("name", caustics.FOLDS)
def test_cat_caustic_cells_against_the_oracle(name):
    """Cells of 1e-3 and 1e-2 v0 t centred 1e-3 v0 t from the folds (the caustic crosses them:
    their density is infinite on it) against the oracle, within the stated error."""
    params = caustics.FOLDS[name]
    model = bg.CAT(**params)
    v0t = params["v0"] * params["t"]
    checked = 0
    for fraction in (1e-3, 1e-2):
        for point in caustics.fold_points(params, n_folds=2, distances=(1e-3,))[::2]:
            grid = cell_oracle.cells_around(point, fraction * v0t)
            got = bg.rasterise(model, grid, quantity="probability").values
            for i, j, cell in cell_oracle.grid_cells(grid):
                want = cell_oracle.cat_cell(model, cell)
                assert abs(got[i, j] - want) <= CAT_RTOL * want + CAT_ATOL, (fraction, cell, got[i, j], want)
                checked += want > 1e-6
    assert checked >= 4


def test_cat_cells_against_monte_carlo():
    """Chi-square of 2e6 samples of the model's own ``sample`` binned on a 20 m grid against the
    cell probabilities (cells expecting at least 20 samples; false-alarm rate 1e-3)."""
    model = bg.CAT(**caustics.SHIP, pose=Pose(origin=(300.0, -200.0), heading=0.7))
    points = model.sample(2_000_000, np.random.default_rng(11))
    lo, hi = points.min(axis=0), points.max(axis=0)
    grid = bg.Grid.from_bounds((lo[0] - 40.0, hi[0] + 40.0), (lo[1] - 40.0, hi[1] + 40.0), 20.0)
    p = bg.rasterise(model, grid, quantity="probability").values
    x0, x1, y0, y1 = grid.extent
    counts, _, _ = np.histogram2d(points[:, 1], points[:, 0], bins=[grid.ny, grid.nx], range=[[y0, y1], [x0, x1]])
    expected = p * len(points)
    used = expected >= 20.0
    chi2 = float(np.sum((counts[used] - expected[used]) ** 2 / expected[used]))
    assert stats.chi2.sf(chi2, int(used.sum()) - 1) > 1e-3, (chi2, int(used.sum()))
    # the density's midpoint sum at these coarse cells is off by far more than the cells are
    density = bg.rasterise(model, grid).values * grid.cell_area
    bad = stats.chi2.sf(float(np.sum((counts[used] - density[used] * len(points)) ** 2 / (density[used] * len(points)))),
                        int(used.sum()) - 1)
    assert bad < 1e-6


def test_cat_cells_hold_the_whole_mass():
    """On a grid holding every walked line, the cells sum to 1 - truncated_mass: each interval's
    ribbon puts its whole normal mass (Gauss on g, to 1e-13) into the cells its edge lines own,
    and each line's share is Phi(7.5) - Phi(-7.5), 6.4e-14 short of 1 (inside the 1e-12)."""
    model = bg.CAT(**caustics.FOLDS["jet-150deg"])
    s = model.k_sigma * model.sigma_omega
    omegas = np.linspace(-s, s, 4001)
    ends = np.vstack([cat_position(model.v0, model.t, np.full_like(omegas, z * model.sigma_a), omegas)
                      for z in (-9.5, 0.0, 9.5)])
    lo, hi = ends.min(axis=0), ends.max(axis=0)
    grid = bg.Grid.from_bounds((lo[0] - 100.0, hi[0] + 100.0), (lo[1] - 100.0, hi[1] + 100.0), 40.0)
    r = bg.rasterise(model, grid, quantity="probability")
    assert r.quantity == "probability"
    assert r.mass == pytest.approx(float(np.sum(r.values)), rel=1e-15)
    # 1e-12: rounding of ~1e5 float64 terms per cell sum
    assert abs(r.mass - (1.0 - model.truncated_mass)) < 1e-12, r.mass
    # the midpoint sum of the densities at these 40 m cells misses the caustics' mass
    assert abs(bg.rasterise(model, grid).mass - 1.0) > 1e-5


def test_a_line_on_a_cell_side_is_counted_once():
    """The omega = 0 line runs exactly along the cell side x = 0: the ribbons on either side of
    it still reach their cells (it once lost 5.7e-4 of the mass, a line on a side counting as
    inside both cells but walked through one)."""
    model = bg.CAT(**caustics.SHIP)
    grid = bg.Grid.from_bounds((-4800.0, 4800.0), (-4800.0, 4800.0), 4800.0)
    assert abs(bg.rasterise(model, grid, quantity="probability").mass - (1.0 - model.truncated_mass)) < 1e-12


def test_cat_cells_do_not_depend_on_threads_or_bands():
    model = bg.CAT(**caustics.SHIP, pose=Pose(origin=(10.0, 20.0), heading=-2.0))
    grid = bg.Grid.from_bounds((-1000.0, 200.0), (-400.0, 700.0), 10.0)
    one = bg.rasterise(model, grid, quantity="probability", threads=1).values
    for threads in (2, 3, 7):
        assert np.array_equal(bg.rasterise(model, grid, quantity="probability", threads=threads).values, one)


def test_float32_cells_are_the_float64_sums_rounded():
    """The lines are always walked in float64 (a share is a difference of normal tails)."""
    model = bg.CAT(**caustics.SHIP)
    grid = bg.Grid.from_bounds((-300.0, 300.0), (500.0, 1000.0), 10.0)
    p64 = bg.rasterise(model, grid, quantity="probability").values
    p32 = bg.rasterise(model, grid, quantity="probability", dtype=np.float32).values
    assert p32.dtype == np.float32
    assert np.array_equal(p32, p64.astype(np.float32))


# --- the whole CAT domain ----------------------------------------------------------------------

log_uniform = caustics.log_uniform


@st.composite
def cat_cases(draw):
    params, pose, seed = draw(caustics.settings_and_points())
    return params, pose, seed, draw(log_uniform(1e-3, 3e-2))


@settings(max_examples=25, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(cat_cases())
def test_cat_cells_over_the_domain(case):
    """Parameters across the whole domain (sigma_omega t from 1e-6 to 250 deg, accelerations
    1e-3 to 1 of v0 / t, posed models), 3 x 3 cells of 1e-3 ... 3e-2 v0 t about a drawn sample
    and about a fold: within the stated error of the oracle."""
    params, pose, seed, fraction = case
    model = bg.CAT(**params, pose=pose)
    v0t = params["v0"] * params["t"]
    rng = np.random.default_rng(seed)
    centres = [model.sample(1, rng)[0]]
    folds = caustics.fold_points(params, n_folds=1, distances=(fraction,))
    if len(folds):
        centres.append(pose.to_world(folds[:1])[0])
    for centre in centres:
        grid = cell_oracle.cells_around(centre, fraction * v0t)
        got = bg.rasterise(model, grid, quantity="probability").values
        for i, j, cell in cell_oracle.grid_cells(grid):
            want = cell_oracle.cat_cell(model, cell)
            assert abs(got[i, j] - want) <= CAT_RTOL * want + CAT_ATOL, (params, pose, cell, got[i, j], want)


# --- every other model: the engine's quadrature ----------------------------------------------


def _butterly():
    return bg.Butterly(mean=(50.0, -20.0), cov=np.array([[100.0**2, 0.3 * 100 * 200], [0.3 * 100 * 200, 200.0**2]]),
                       speeds=[1.0, 2.0, 3.0], weights=[0.3, 0.3, 0.4], t=100.0)


def test_butterly_on_a_coarse_grid_never_exceeds_one():
    """Cells of 5 start SDs: the densities' midpoint sum is far from 1 (it was 1.033 on such a
    grid), the cells sum to the mass inside the grid, here all of it."""
    model = _butterly()
    grid = bg.Grid.from_bounds((-3000.0, 3000.0), (-3000.0, 3000.0), 500.0)
    r = bg.rasterise(model, grid, quantity="probability")
    assert abs(r.mass - 1.0) < 1e-12  # every sub-cell to 1e-10 of the mass; the whole support inside
    assert abs(bg.rasterise(model, grid).mass - 1.0) > 1e-3
    for i, j, cell in list(cell_oracle.grid_cells(grid))[::7]:
        want = cell_oracle.pdf_cell(model, cell, eps=1e-15)
        assert abs(r.values[i, j] - want) <= QUADRATURE_RTOL * want + 1e-14, (cell, r.values[i, j], want)


def _polar_dblquad(model, cell, origin):
    """dblquad of the density over a world cell in polar coordinates about ``origin`` (the
    1/r of a polar density cancels against r dr): over the cell's bearing range, for each
    bearing the radii inside the cell."""
    x0, x1, y0, y1 = cell
    ox, oy = origin
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]

    def inside(theta):
        return cell_oracle.ray_segment((ox, oy), cell, theta)

    thetas = [math.atan2(cx - ox, cy - oy) for cx, cy in corners]
    contains = x0 <= ox <= x1 and y0 <= oy <= y1
    t0, t1 = (-math.pi, math.pi) if contains else (min(thetas), max(thetas))
    if not contains and t1 - t0 > math.pi:  # the cell straddles south: unwrap
        thetas = [t % (2 * math.pi) for t in thetas]
        t0, t1 = min(thetas), max(thetas)

    def f(r, theta):
        x, y = ox + r * math.sin(theta), oy + r * math.cos(theta)
        return float(model.pdf(np.array([x]), np.array([y]))[0]) * r

    value, _ = integrate.dblquad(f, t0, t1, lambda th: inside(th)[0], lambda th: inside(th)[1],
                                 epsabs=1e-15, epsrel=1e-10)
    return value


def test_polar_cells_at_the_origin():
    """A broad polar banana (the range SD half the range): the cells at and around its origin,
    where the density is infinite like 1/r, against dblquad in polar coordinates."""
    model = bg.PolarBanana(v0=1.0, t=100.0, sigma_a=0.01, sigma_omega=0.01, variant="rough",
                           pose=Pose(origin=(3.0, -4.0)))
    grid = bg.Grid.from_bounds((-37.0, 43.0), (-44.0, 36.0), 10.0)
    r = bg.rasterise(model, grid, quantity="probability")
    assert "swept in polar coordinates" in r.provenance["cell_method"]
    x0, _, y0, _ = grid.extent
    i0, j0 = int((-4.0 - y0) // grid.dy), int((3.0 - x0) // grid.dx)
    for i, j in [(i0, j0), (i0 + 1, j0), (i0, j0 + 1), (i0 + 1, j0 - 1), (i0 + 3, j0 + 2)]:
        cell = (x0 + grid.dx * j, x0 + grid.dx * (j + 1), y0 + grid.dy * i, y0 + grid.dy * (i + 1))
        want = _polar_dblquad(model, cell, (3.0, -4.0))
        assert want > 1e-6
        assert abs(r.values[i, j] - want) <= QUADRATURE_RTOL * want, (cell, r.values[i, j], want)


@pytest.mark.parametrize("kind", ["polar-rough", "bearing", "cat-heading"])
def test_other_models_against_monte_carlo(kind):
    """Chi-square of 1e6 samples from the model's own ``sample`` on 60 x about 60 cells framing
    all but 0.1 % of them (the cells normalised over the grid, like the counts in it)."""
    if kind == "polar-rough":
        model = bg.PolarBanana(v0=8.0, t=60.0, sigma_a=0.05, sigma_omega=math.radians(1.0), variant="rough")
    elif kind == "cat-heading":
        model = bg.CAT(v0=8.0, t=60.0, sigma_a=0.05, sigma_omega=math.radians(0.5), sigma_heading=math.radians(5.0))
    else:
        model = bg.BearingFix(sensors=[(-2000.0, 0.0), (0.0, -2500.0)], bearings=[math.radians(60.0), math.radians(10.0)],
                              sigmas=[0.01, 0.015])
    points = model.sample(1_000_000, np.random.default_rng(5))
    lo, hi = np.percentile(points, 0.05, axis=0), np.percentile(points, 99.95, axis=0)
    grid = bg.Grid.from_bounds((lo[0], hi[0]), (lo[1], hi[1]), max(hi - lo) / 60.0)
    p = bg.rasterise(model, grid, quantity="probability").values
    x0, x1, y0, y1 = grid.extent
    counts, _, _ = np.histogram2d(points[:, 1], points[:, 0], bins=[grid.ny, grid.nx], range=[[y0, y1], [x0, x1]])
    expected = p / p.sum() * counts.sum()
    used = expected >= 20.0
    chi2 = float(np.sum((counts[used] - expected[used]) ** 2 / expected[used]))
    assert stats.chi2.sf(chi2, int(used.sum()) - 1) > 1e-3, (chi2, int(used.sum()))


# --- the interface ---------------------------------------------------------------------------


def test_quantity_is_checked():
    with pytest.raises(bg.BananagridError, match=r"quantity = 'mass': expected one of 'density', 'probability'"):
        bg.rasterise(bg.CAT(**caustics.SHIP), bg.Grid.from_bounds((0, 10), (0, 10), 1.0), quantity="mass")


def test_the_work_check_sees_the_lines():
    model = bg.CAT(**caustics.FOLDS["jet-200deg"])
    grid = bg.Grid.from_bounds((-3000.0, 3000.0), (-3000.0, 3000.0), 0.5)
    with pytest.raises(bg.BananagridError, match=r"cell probabilities on a grid .* \(CAT lines exact in the acceleration\) would take about"):
        bg.rasterise(model, grid, quantity="probability", max_seconds=1.0)


# --- scenes -----------------------------------------------------------------------------------

SCENE = """
[scene]
name = "cells"
[grid]
x = [-2600.0, 2600.0]
y = [-1400.0, 3400.0]
step = 100.0
[defaults]
v0 = 8.0
t = 120.0
sigma_a = 0.05
sigma_omega_deg = 0.3
[layers.cat]
model = "cat"
[layers.polar]
model = "polar"
variant = "rough"
[output]
cell_probabilities = true
"""


def test_a_scene_records_and_archives_its_cell_probabilities(tmp_path):
    """``[output] cell_probabilities = true``: each layer's cells as the image
    layers/NAME/cell_probability in the recording, LAYER__tT__probability in the .npz (normalised
    over the grid, as the scene normalises its maps), and the captured mass is their sum before
    normalising (the midpoint sum of the densities on these 100 m cells is not)."""
    scene = parse_scene(SCENE)
    rows = run_scene(scene, tmp_path, npz=True, threads=1)
    arrays = np.load(tmp_path / "cells.npz")
    for row in rows:
        cells = arrays[f"{row['layer']}__t120__probability"]
        assert row["mass_from"] == "the cell probabilities"
        assert float(np.sum(cells, dtype=np.float64)) == pytest.approx(1.0, rel=1e-6)  # float32 archive
        model = scene.layers[[layer.name for layer in scene.layers].index(row["layer"])].model(120.0)
        assert row["mass"] == pytest.approx(bg.rasterise(model, scene.grid, quantity="probability").mass, rel=1e-12)
        assert abs(bg.rasterise(model, scene.grid).mass - row["mass"]) > 1e-4
    logged = {chunk.entity_path for chunk in RrdReader(tmp_path / "cells.rrd").stream()}
    assert {"/layers/cat/cell_probability", "/layers/polar/cell_probability"} <= logged
