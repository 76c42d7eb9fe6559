"""CAT.density_bound: a proved bound of what the grid kernels compute over a rectangle.

Checked against the kernels themselves: ``bananagrid.rasterise`` on a grid whose cell centres
cover the closed rectangle (its edges and corners included), in float64 and float32. Where the
bound is 0.0 the raster must be exact zeros. Rectangles are drawn where the proof is tight
(along the scan's lines at accelerations around PRUNE_SIGMAS = 38 sigma_a, where the kernel's
pruning starts), far away, around the last fix and over the whole banana.
"""

import math

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.models import _cat_heading as heading
from bananagrid.models.cat import cat_position

from cases import FIG1

#: Cells per side of the checking grid (its centres include the rectangle's edges).
CHECK_CELLS = 40


def raster_over(model, x0, x1, y0, y1, dtype, n=CHECK_CELLS):
    """The raster whose (n + 1)^2 cell centres run from corner to corner of the rectangle."""
    dx, dy = (x1 - x0) / n, (y1 - y0) / n
    grid = bg.Grid(origin=(x0 - 0.5 * dx, y0 - 0.5 * dy), dx=dx, dy=dy, nx=n + 1, ny=n + 1)
    return bg.rasterise(model, grid, dtype=dtype)


def check_bound(model, rect):
    """Assert the bound holds in both dtypes (and gives exact zeros where it is 0); return
    (bound, dtypes the kernel computed in)."""
    bound = model.density_bound(*rect)
    assert bound >= 0.0
    computed = set()
    for dtype in (np.float64, np.float32):
        raster = raster_over(model, *rect, dtype)
        computed.add(raster.provenance["computed_in"])
        values = raster.values
        assert np.all(np.isfinite(values))
        top = float(values.max())
        assert top <= bound, (model, rect, dtype, top, bound)
        if bound == 0.0:
            assert np.all(values == 0.0), (model, rect, dtype, top)
    return bound, computed


def random_cat(rng, *, heading_sd=0.0, origin_scale=100.0):
    """A CAT over a wide parameter range (sigma_omega t <= 5 keeps the scan short)."""
    t = 10 ** rng.uniform(0.0, 2.0)
    sigma_omega = min(10 ** rng.uniform(-3.0, -0.5), 5.0 / t)
    pose = bg.Pose(origin=tuple(rng.uniform(-origin_scale, origin_scale, 2)), heading=rng.uniform(-4.0, 4.0))
    return bg.CAT(v0=10 ** rng.uniform(0.0, 3.0), t=t, sigma_a=10 ** rng.uniform(-1.5, 0.5),
                  sigma_omega=sigma_omega, k_sigma=rng.choice([4.0, 8.0, 8.0, 12.0]),
                  sigma_heading=heading_sd, pose=pose)


def rectangle_about(rng, centre, size):
    """A rectangle of sides up to ``size`` placed randomly over ``centre``."""
    lo = centre - size * rng.uniform(0.0, 1.0, 2)
    return (lo[0], lo[0] + size * rng.uniform(0.1, 1.0), lo[1], lo[1] + size * rng.uniform(0.1, 1.0))


def along_line(rng, model, sigmas):
    """A world point on the scan's line at a turn rate within the scan, acceleration +-sigmas
    sigma_a from the kernel's pruning limit's neighbourhood."""
    omega = rng.uniform(-1.0, 1.0) * model.k_sigma * model.sigma_omega
    a = rng.choice([-1.0, 1.0]) * sigmas * model.sigma_a
    return model.pose.to_world(cat_position(model.v0, model.t, a, omega))[0]


@pytest.mark.parametrize("seed", range(4))
def test_bound_holds_near_the_pruning_limit(seed):
    """Rectangles along the scan's lines at |a| in [20, 45] sigma_a, small to large: the bound
    holds in both dtypes, and its zeros are the kernel's (the 38 sigma_a pruning and the F test
    both give exact zeros there)."""
    rng = np.random.default_rng(1000 + seed)
    zeros = 0
    computed = set()
    for _ in range(6):
        model = random_cat(rng)
        sd_length = model.sigma_a * model.t**2
        for _ in range(2):
            centre = along_line(rng, model, rng.uniform(20.0, 45.0))
            rect = rectangle_about(rng, centre, sd_length * 10 ** rng.uniform(-3.0, 0.5))
            bound, dtypes = check_bound(model, rect)
            zeros += bound == 0.0
            computed |= dtypes
    assert zeros >= 1  # the zero branch was exercised
    assert "float32" in computed  # and the float32 kernel


@pytest.mark.parametrize("seed", range(3))
def test_bound_holds_anywhere(seed):
    """Rectangles far away in any direction, around the last fix, over the banana, and tiny
    ones: the bound holds (often 0 far away, never below the raster)."""
    rng = np.random.default_rng(2000 + seed)
    zeros = 0
    for _ in range(5):
        model = random_cat(rng)
        reach = model.v0 * model.t + 40.0 * model.sigma_a * model.t**2
        origin = np.asarray(model.pose.origin)
        bearing = rng.uniform(0.0, 2.0 * math.pi)
        far = origin + reach * 10 ** rng.uniform(0.0, 1.5) * np.array([math.sin(bearing), math.cos(bearing)])
        rects = [
            rectangle_about(rng, far, reach * 10 ** rng.uniform(-2.0, 0.0)),
            rectangle_about(rng, origin, reach * 10 ** rng.uniform(-3.0, 0.0)),  # the last fix
            rectangle_about(rng, model.sample(1, rng)[0], 2.5 * reach),  # the banana
            rectangle_about(rng, along_line(rng, model, 38.0), 1e-6 * reach),  # at the pruning limit
        ]
        for rect in rects:
            bound, _ = check_bound(model, rect)
            zeros += bound == 0.0
    assert zeros >= 1


def test_bound_holds_far_from_the_world_origin():
    """A pose at UTM-like coordinates: float32 world coordinates round by metres there, which
    the bound allows for (the engine may compute in float64; the bound covers both)."""
    model = bg.CAT(**FIG1, pose=bg.Pose(origin=(512_345.6, 6_234_567.8), heading=0.7))
    rng = np.random.default_rng(7)
    for sigmas in (30.0, 38.0, 40.0, 45.0):
        check_bound(model, rectangle_about(rng, along_line(rng, model, sigmas), 200.0))


@pytest.mark.filterwarnings("ignore:CAT with sigma_heading")  # lattice accuracy: not what is tested
@pytest.mark.parametrize("seed", range(2))
def test_bound_holds_with_heading_noise(seed):
    """With heading noise the kernel interpolates a table built for the grid's extent; the
    bound (which never sees that table) holds for it: 0 beyond the ranges where the base
    kernel is 0 at every bearing, finite or huge elsewhere."""
    rng = np.random.default_rng(3000 + seed)
    zeros = 0
    for _ in range(3):
        model = bg.CAT(v0=10 ** rng.uniform(1.0, 2.5), t=10 ** rng.uniform(0.5, 1.2),
                       sigma_a=10 ** rng.uniform(-0.5, 0.3), sigma_omega=10 ** rng.uniform(-2.0, -1.3),
                       sigma_heading=10 ** rng.uniform(-1.7, -1.0),
                       pose=bg.Pose(origin=tuple(rng.uniform(-100.0, 100.0, 2)), heading=rng.uniform(-4.0, 4.0)))
        reach = model.v0 * model.t
        sd_length = model.sigma_a * model.t**2
        origin = np.asarray(model.pose.origin)
        for scale in (rng.uniform(1.0, 1.5), rng.uniform(2.0, 6.0)):
            bearing = rng.uniform(0.0, 2.0 * math.pi)
            centre = origin + (reach + scale * 20.0 * sd_length) * np.array([math.sin(bearing), math.cos(bearing)])
            bound, _ = check_bound(model, rectangle_about(rng, centre, sd_length * 10 ** rng.uniform(-1.0, 0.5)))
            zeros += bound == 0.0
        check_bound(model, rectangle_about(rng, origin, 0.1 * reach))  # a mirrored lattice
    assert zeros >= 1


def test_interpolation_bound_holds_for_rough_tables():
    """The stencil bound (log-cubic overshoot and the linear branch) against the interpolating
    kernel itself, on tables of random logs from P down to far below either floor, some entries
    0: the worst a table can be, not a smooth one."""
    rng = np.random.default_rng(11)
    n_r, n_theta = 12, 16
    for top in (1e-300, 1e-200, 1e-40, 1e-20, 1e-5, 1.0):
        for depth in (3.0, 30.0, 300.0, 700.0):  # how far below P the logs reach
            logs = rng.uniform(max(math.log(top) - depth, -740.0), math.log(top), (n_r, n_theta))
            values = np.exp(logs)
            values[rng.uniform(size=values.shape) < 0.05] = 0.0
            values[0, :] = top  # the largest entry present
            table = heading.HeadingTable(values, 10.0, 1.0, -math.pi, 2.0 * math.pi / n_theta,
                                         False, 0.0, 0)
            r = rng.uniform(13.0, 19.0, 4000)
            theta = rng.uniform(-math.pi, math.pi, 4000)
            for dtype in (np.float64, np.float32):
                got = heading.interpolate_table(table, r * np.sin(theta), r * np.cos(theta), dtype=dtype)
                assert float(np.max(got)) <= heading.interpolation_bound(top), (top, depth, dtype)
    zero = heading.HeadingTable(np.zeros((8, 16)), 0.0, 1.0, -math.pi, 2.0 * math.pi / 16, True, 0.0, 0)
    assert heading.interpolation_bound(0.0) == 0.0
    assert np.all(heading.interpolate_table(zero, [0.3, 2.0], [1.0, -3.0]) == 0.0)


def test_figure1_far_tiles_are_left_out():
    """Figure 1 (v0 t = 2.8 km, sigma_a t^2 / 2 = 83 m along the track): a 2 km tile whose near
    edge is 1.7 km beyond the banana's nose (the straight line needs a = 20 sigma_a there) gets
    a finite bound below the density floor; one from 4.2 km beyond (more than the 38 sigma_a
    = 3.2 km of the kernel's pruning) gets 0.0 and the kernel gives exact zeros; and one
    holding the banana gets a bound above its peak."""
    model = bg.CAT(**FIG1)
    floor = model.density_floor()
    near = (-1000.0, 1000.0, 4500.0, 6500.0)
    bound, _ = check_bound(model, near)
    assert 0.0 < bound <= floor
    assert check_bound(model, (-1000.0, 1000.0, 7000.0, 9000.0))[0] == 0.0
    assert check_bound(model, (-7000.0, -5000.0, -3000.0, -1000.0))[0] == 0.0
    assert model.density_bound(-3000.0, 3000.0, -200.0, 3400.0) >= model.peak_lower_bound()


def test_figure1_with_heading_noise_far_tiles_are_left_out():
    """Figure 1 with sigma_heading = pi/30: the heading table's rows are whole circles, so a
    tile is left out when the circles of ranges its stencils read (its own, +-2 rows) are far
    from the banana at every bearing: 5 km from the fix (2.2 km past the nose) in any
    direction; 9 km out the base kernel is 0 on all of them, and so is the table."""
    model = bg.CAT(**FIG1, sigma_heading=math.pi / 30.0)
    floor = model.density_floor()
    for rect in ((-1000.0, 1000.0, 5000.0, 7000.0), (5000.0, 7000.0, -1000.0, 1000.0),
                 (-1000.0, 1000.0, -7000.0, -5000.0)):
        assert model.density_bound(*rect) <= floor
    assert check_bound(model, (9000.0, 10000.0, -500.0, 500.0))[0] == 0.0
    assert model.density_bound(-1000.0, 1000.0, 2000.0, 4000.0) > floor  # the banana's own ranges


@pytest.mark.filterwarnings("ignore:CAT with sigma_heading")  # lattice accuracy at single points
def test_points_the_whole_plane_and_bad_rectangles():
    """A point is a rectangle (its bound holds at it); a side at infinity gets the whole plane's
    bound, above every other; reversed or NaN bounds are refused."""
    for sigma_heading in (0.0, 0.05):
        model = bg.CAT(**FIG1, sigma_heading=sigma_heading)
        whole = model.density_bound(-math.inf, math.inf, -math.inf, math.inf)
        assert model.peak_lower_bound() <= whole < math.inf
        assert model.density_bound(0.0, math.inf, 0.0, 1.0) == whole
        for point in ((0.0, 2800.0), (0.0, 0.0), (0.0, 9000.0)):
            bound = model.density_bound(point[0], point[0], point[1], point[1])
            assert bound <= whole
            for dtype in (np.float64, np.float32):
                assert float(model.pdf(*point, dtype=dtype)) <= bound
        for rect in ((1.0, 0.0, 0.0, 1.0), (0.0, 1.0, 0.0, math.nan)):
            with pytest.raises(bg.BananagridError):
                model.density_bound(*rect)
