"""Public constructors and verbs at the extremes of float64 and of memory.

Parameters anywhere from the smallest subnormal (5e-324) through 1e-308 and 1 to 1e308 and the
largest float, of either sign; sample sizes up to 10**15. Each call either succeeds
with finite results or raises :class:`bananagrid.BananagridError` with one line that names the
argument: never OverflowError, MemoryError, ZeroDivisionError, a NumPy or thread-pool
ValueError, FloatingPointError or a RuntimeWarning (the sweeps turn RuntimeWarnings into
errors). Property-based sweeps on a fixed seed; each example is bounded in work (small lattices,
a few points, ten samples).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine import memory
from bananagrid.models.base import SAMPLE_BYTES

TINY = float(np.finfo(float).smallest_subnormal)  # 5e-324
HUGE = float(np.finfo(float).max)  # 1.8e308
#: Magnitudes at the edges of float64: subnormals, the smallest normal, and the largest values.
SPECIAL = [TINY, 1e-323, 1e-320, 1e-310, 2.2250738585072014e-308, 1e-308, 1e-300, 1e-30, 1e-6, 0.5, 1.0,
           3.0, 1e6, 1e30, 1e300, 1e307, 1e308, HUGE]
MAGNITUDES = st.one_of(st.sampled_from(SPECIAL),
                       st.floats(min_value=TINY, max_value=HUGE, allow_subnormal=True),
                       st.floats(min_value=1e-3, max_value=1e4))  # ordinary values, so that some calls succeed
SIGNED = st.one_of(MAGNITUDES, MAGNITUDES.map(lambda v: -v), st.just(0.0))
#: Sizes from 0 to 10**15 (memory checks) and small ones (that run).
SIZES = st.one_of(st.sampled_from([0, 1, 10, 10**9, 10**12, 10**13, 10**15]), st.integers(0, 10**15))

#: The sweeps' fixed seed: a derandomised test's examples derive from where its module was
#: imported from, so each checkout drew other examples; a fixed seed draws the same everywhere.
SWEEP_SEED = 20261127


def sweep(max_examples):
    """The sweeps' settings: ``max_examples`` examples drawn from SWEEP_SEED, no database."""
    def apply(test):
        return seed(SWEEP_SEED)(settings(max_examples=max_examples, deadline=None, derandomize=False, database=None,
                                         suppress_health_check=list(HealthCheck))(test))
    return apply


SWEEP = sweep(120)
#: For the sweeps that run kernels on each model (its pdf, samples): fewer, costlier examples.
MODEL_SWEEP = sweep(40)


def refused_or(call, names):
    """``call()``, or None when it raises a one-line BananagridError naming one of ``names``;
    RuntimeWarnings (NumPy's overflow, invalid values, division by zero) raise and fail the test;
    BananagridWarnings are allowed."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        warnings.simplefilter("ignore", bg.BananagridWarning)
        try:
            return call()
        except bg.BananagridError as exc:
            message = str(exc)
            assert "\n" not in message, message
            assert any(name in message for name in names), (names, message)
            return None


def finite(*arrays):
    for a in arrays:
        assert np.all(np.isfinite(np.asarray(a, dtype=float))), a


# -- domains ---------------------------------------------------------------------------------


@SWEEP
@given(SIGNED, SIGNED, MAGNITUDES, MAGNITUDES, st.integers(1, 4), st.integers(1, 4))
def test_grids_at_the_extremes(x0, y0, dx, dy, nx, ny):
    grid = refused_or(lambda: bg.Grid(origin=(x0, y0), dx=dx, dy=dy, nx=nx, ny=ny), ["origin", "dx", "dy", "grid"])
    if grid is not None:
        finite(grid.x, grid.y, grid.extent, grid.cell_area)
        assert grid.cell_area > 0.0
        cells_apart(grid)


def cells_apart(grid):
    """Every cell centre of ``grid`` in order and where float64 puts it, to 4e-3 of a cell: cells
    smaller than float64 resolves at their coordinates are refused, not collapsed (a cell spans at
    least MIN_CELL_ULPS = 1024 ulps; a centre origin + (k + 1/2) d and its offset from the origin
    take three roundings of at most one ulp each, 3 / 1024 < 4e-3)."""
    for values, start, step, n in ((grid.x, grid.origin[0], grid.dx, grid.nx), (grid.y, grid.origin[1], grid.dy, grid.ny)):
        exact = (np.arange(n) + 0.5) * step  # offsets from the origin; subtracted exactly below
        assert np.all(np.diff(values) > 0.0)
        assert np.all(np.abs((values - start) - exact) <= 4e-3 * step), (values, start, step)


@SWEEP
@given(SIGNED, MAGNITUDES, SIGNED, MAGNITUDES, MAGNITUDES)
def test_grids_from_bounds_at_the_extremes(x0, width, y0, height, step):
    grid = refused_or(lambda: bg.Grid.from_bounds(x=(x0, x0 + width), y=(y0, y0 + height), step=step),
                      ["x", "y", "step", "grid", "dx", "dy"])
    if grid is not None and grid.nx * grid.ny <= 10**6:
        finite(grid.x, grid.y, grid.extent)
        cells_apart(grid)


@SWEEP
@given(SIGNED, st.floats(1.0, 2.0**40), st.integers(1, 6))
def test_grids_finer_than_float64_resolves_are_refused(start, cells_per_ulp, n):
    """Cells of a few ulps of their coordinates (1e-154 m cells at 1e-30, 1e-17 m at 1, 1e-11 m
    at 1e6: every centre the same float, maps of 0): refused naming dx, or resolved."""
    step = math.ulp(abs(start) + 1e-300) * cells_per_ulp
    grid = refused_or(lambda: bg.Grid(origin=(start, 0.0), dx=step, dy=1.0, nx=n, ny=1), ["dx", "origin", "grid"])
    if grid is not None:
        cells_apart(grid)


@SWEEP
@given(MAGNITUDES, MAGNITUDES, MAGNITUDES, st.floats(1e-3, 2 * math.pi), MAGNITUDES)
def test_polar_lattices_at_the_extremes(r_min, span, range_step, bearing_span, bearing_step):
    lattice = refused_or(
        lambda: bg.PolarLattice(ranges=(r_min, r_min + span), range_step=range_step, bearings=(0.0, bearing_span),
                                bearing_step=bearing_step),
        ["ranges", "range_step", "bearings", "bearing_step", "polar lattice"])
    if lattice is not None:
        assert 1 <= lattice.n_range * lattice.n_bearing <= 2**31
        if lattice.n_range * lattice.n_bearing <= 10**5:
            finite(lattice.range_edges, lattice.bearing_edges, lattice.cell_areas)


@SWEEP
@given(st.sampled_from(["line", "plane", "frustum"]), MAGNITUDES, st.floats(0.0, 1.0), MAGNITUDES, MAGNITUDES)
def test_angular_lattices_at_the_extremes(geometry, h, thickness, azimuth_step, elevation_step):
    """Steps down to 5e-324 (a count that overflows, or too many cells) and depths to 1e308."""
    def build():
        kwargs = {"dh": thickness * h} if geometry == "frustum" else {}
        if geometry != "line":
            kwargs["elevation_step"] = elevation_step
        return bg.AngularLattice(geometry, h=h, azimuth_step=azimuth_step, **kwargs)

    lattice = refused_or(build, ["azimuth_step", "elevation_step", "h", "dh", "lattice"])
    if lattice is not None:
        assert math.prod(lattice.shape) <= 2**31
        if math.prod(lattice.shape) <= 10**5:
            finite(lattice.azimuths)


@MODEL_SWEEP
@given(st.sampled_from(["line", "plane", "frustum"]), MAGNITUDES, MAGNITUDES, SIGNED, MAGNITUDES, MAGNITUDES)
def test_cell_probabilities_at_the_extremes(geometry, h, dh, shift, size, depth):
    """A uniform room and a mixture under lattices with depths and slab thicknesses at the extremes
    (a frustum of dh = 1e-308 once ended in a thread pool's "max_workers must be greater than 0")."""
    dim = {"line": 1, "plane": 2, "frustum": 3}[geometry]
    axes = {"x": (shift - size, shift + size), "y": (-size, size), "z": (-depth - size, -depth)}

    def build():
        room = bg.UniformPresence(bg.Region(**{k: axes[k] for k in "xyz"[:dim]}))
        kwargs = {"dh": dh} if geometry == "frustum" else {}
        lattice = bg.AngularLattice(geometry, h=h, azimuth_step=math.pi / 4,
                                    elevation_step=None if geometry == "line" else math.pi / 8, **kwargs)
        return bg.cell_probabilities(room, lattice)

    cells = refused_or(build, ["h", "dh", "region", "x", "y", "z", "cell", "lattice", "room"])
    if cells is not None:
        finite(cells.prob)
        assert np.all(cells.prob >= 0.0) and float(np.sum(cells.prob)) <= 1.0 + 1e-12


@SWEEP
@given(SIGNED, MAGNITUDES, SIGNED, MAGNITUDES, SIGNED, MAGNITUDES)
def test_regions_and_poses_at_the_extremes(x0, wx, y0, wy, origin, heading):
    region = refused_or(lambda: bg.Region(x=(x0, x0 + wx), y=(y0, y0 + wy)), ["x", "y", "region"])
    if region is not None:
        finite(region.bounds, region.size)
        assert region.size > 0.0
    pose = refused_or(lambda: bg.Pose(origin=(origin, -origin), heading=heading), ["origin", "heading"])
    if pose is not None:
        finite(pose.to_world(np.array([[1.0, 2.0]])))


# -- models ----------------------------------------------------------------------------------

#: Points to 1e300 m (a point farther than float64 can measure from a model's origin, near
#: 1.8e308 on both axes, is not swept: see docs/accuracy.md).
POINTS_X = [0.0, 1.0, -5.0, 1e4, 1e300, -1e300]
POINTS_Y = [0.0, 2.0, 3.0, -1e4, -1e300, 1e300]


def exercise(build, names):
    """Build a model; if it builds, its densities at ordinary and extreme points and ten samples
    are finite (densities >= 0)."""
    model = refused_or(build, names)
    if model is None:
        return
    density = refused_or(lambda: model.pdf(POINTS_X, POINTS_Y), ["x", "y", "points"])
    if density is not None:
        finite(density)
        assert np.all(density >= 0.0)
    samples = refused_or(lambda: model.sample(10, np.random.default_rng(0)), ["n", "sample"])
    if samples is not None:
        assert samples.shape == (10, 2)
        finite(samples)


MOTION = ["v0", "t", "sigma_a", "sigma_omega", "sigma_heading", "sigma"]


@MODEL_SWEEP
@given(MAGNITUDES, MAGNITUDES, MAGNITUDES, MAGNITUDES, st.one_of(st.just(0.0), MAGNITUDES),
       st.sampled_from(["cat", "rough", "improved"]))
def test_motion_models_at_the_extremes(v0, t, sigma_a, sigma_omega, sigma_heading, kind):
    def build():
        if kind == "cat":
            return bg.CAT(v0=v0, t=t, sigma_a=sigma_a, sigma_omega=sigma_omega, sigma_heading=sigma_heading)
        return bg.PolarBanana(v0=v0, t=t, sigma_a=sigma_a, sigma_omega=sigma_omega, variant=kind,
                              sigma_heading=sigma_heading)

    exercise(build, MOTION)


SPEEDS = ["speeds", "v_min", "v_max", "mean", "sd", "density", "t"]


@MODEL_SWEEP
@given(st.sampled_from(["uniform", "normal", "table", "list"]), MAGNITUDES, MAGNITUDES, st.floats(1.0, 1e4),
       st.floats(1.0, 1e6))
def test_butterly_speed_laws_at_the_extremes(law, low, width, t, sd):
    """Speed laws reaching from 5e-324 up to 1.8e308 m/s (a uniform law to 1e308 once ended in
    OverflowError in its quadrature): continuous laws, tables and lists of speeds (ordinary
    times and spreads: Butterly's own numerics at the extremes are swept in test_api_fuzz)."""
    def speeds():
        if law == "uniform":
            return bg.UniformSpeed(low, low + width)
        if law == "normal":
            return bg.NormalSpeed(mean=low, sd=width)
        if law == "table":
            return bg.TabulatedSpeed([low, low + width], [1.0, 0.5])
        return [low, low + width]

    exercise(lambda: bg.Butterly(mean=(0.0, 0.0), cov=[[sd * 1.0, 0.0], [0.0, sd]], speeds=speeds(), t=t),
             SPEEDS + ["cov", "mean", "weights"])


@MODEL_SWEEP
@given(MAGNITUDES, SIGNED, MAGNITUDES, MAGNITUDES)
def test_bearing_fixes_at_the_extremes(baseline, offset, sigma_1, sigma_2):
    def build():
        sensors = [[0.0, 0.0], [baseline, 0.0]]
        # Python floats: the target's own coordinates may reach inf at these sizes, silently
        target = (0.5 * baseline + offset, baseline)
        bearings = [math.atan2(target[0] - s[0], target[1] - s[1]) for s in sensors]
        return bg.BearingFix(sensors=sensors, bearings=bearings, sigmas=[sigma_1, sigma_2])

    exercise(build, ["sensors", "bearings", "sigmas"])


#: Points as far as float64 reaches, each way, and a few ordinary ones.
FAR_POINTS = [0.0, 1.0, -1e4, 1e154, -1e160, 1e300, -1e300, 1e308, HUGE, -HUGE]


#: Bearing SDs and baselines: extreme ones, and ordinary ones so that most fixes build.
BEARING_SIGMAS = st.one_of(st.floats(1e-6, 0.3), MAGNITUDES)
BASELINES = st.one_of(st.floats(1.0, 1e6), MAGNITUDES)


@sweep(80)
@given(SIGNED, SIGNED, BASELINES, st.floats(0.05, 1.5), BEARING_SIGMAS, BEARING_SIGMAS,
       st.sampled_from(["exact", "linear"]))
def test_bearing_maps_anywhere_at_points_anywhere(ox, oy, baseline, angle, sigma_1, sigma_2, variant):
    """Both bearing maps of a fix placed anywhere in float64 (stations up to 1.8e308 from the
    world origin, baselines from 5e-324 up), at points anywhere (offsets from the fix beyond
    1.8e308, where they overflow): finite, non-negative and at most the map's peak
    exp(log_norm) (the likelihood is at most 1); the linear map's quadratic form once made
    inf - inf = NaN beyond 1e154 m from its fix. Or the fix refused by name."""
    def build():
        sensors = [[ox, oy], [ox + baseline, oy]]
        target = [ox + 0.5 * baseline, oy + 0.5 * baseline / math.tan(0.5 * angle)]
        bearings = [math.atan2(target[0] - sx, target[1] - sy) for sx, sy in sensors]
        return bg.BearingFix(sensors=sensors, bearings=bearings, sigmas=[sigma_1, sigma_2], variant=variant)

    model = refused_or(build, ["sensors", "bearings", "sigmas"])
    if model is None:
        return
    fx, fy = model.fix
    x = np.array([fx] + [a for a in FAR_POINTS for _ in FAR_POINTS])
    y = np.array([fy] + [b for _ in FAR_POINTS for b in FAR_POINTS])
    peak = math.exp(model.kernel_parameters()["log_norm"])
    for dtype in (np.float64, np.float32):
        values = refused_or(lambda: model.pdf(x, y, dtype=dtype), ["x", "y", "points"])
        finite(values)
        # the lane exp is within 3 ulp (tests/kernels/test_lanes.py): 1e-6 covers float32's too
        assert np.all(values >= 0.0) and np.all(values <= peak * (1.0 + 1e-6)), (values.max(), peak)


# -- sample sizes ----------------------------------------------------------------------------

POSE = bg.Pose(origin=(150.0, -80.0), heading=0.4)
#: One model of every class that samples.
SAMPLERS = {
    "cat": bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, pose=POSE),
    "polar": bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, pose=POSE),
    "butterly": bg.Butterly(mean=(300.0, 900.0), cov=[[900.0, 200.0], [200.0, 400.0]],
                            speeds=bg.NormalSpeed(mean=4.0, sd=0.5), t=120.0),
    "bearing": bg.BearingFix(sensors=[(-2000.0, 0.0), (2500.0, 300.0)], bearings=[0.6, -0.5], sigmas=[0.02, 0.03]),
    "mixture": bg.GaussianMixture(weights=[0.5, 0.5], means=[[0.0, 0.0], [1.0, 1.0]], covs=[np.eye(2)] * 2),
    "uniform": bg.UniformPresence(bg.Region(x=(0.0, 1.0), y=(0.0, 2.0), z=(-3.0, -1.0))),
}


@pytest.mark.parametrize("name", list(SAMPLERS))
@SWEEP
@given(n=SIZES)
def test_sample_sizes_that_do_not_fit_are_refused_with_the_bytes(name, n, monkeypatch):
    """Up to 10**15 samples: refused, naming n and the bytes, when they would not fit in the
    memory available (held at 64 MB here, so that no example allocates more), else drawn."""
    available = 64 * 10**6
    monkeypatch.setattr(memory, "available_bytes", lambda: available)
    model = SAMPLERS[name]
    bytes_per_sample = getattr(model, "sample_bytes", SAMPLE_BYTES)
    if n * bytes_per_sample > available:
        with pytest.raises(bg.BananagridError) as raised:
            model.sample(n, np.random.default_rng(0))
        message = str(raised.value)
        assert message.startswith(f"n = {n:,}: sample(n) would take about "
                                  f"{memory.format_bytes(n * bytes_per_sample)}") and "64 MB available" in message
    elif n <= 1000:  # a size that fits and is quick: drawn
        assert len(model.sample(n, np.random.default_rng(0))) == n


@pytest.mark.parametrize("name", list(SAMPLERS))
@pytest.mark.parametrize("n", [-1, 1.5, "10", True, None])
def test_sample_sizes_that_are_not_counts_are_refused(name, n):
    with pytest.raises(bg.BananagridError, match=r"^n = .*: expected a non-negative integer"):
        SAMPLERS[name].sample(n, np.random.default_rng(0))


def test_sample_memory_figures_cover_the_measured_peaks():
    """The bytes per sample each class declares are at least its measured peak (tracemalloc over
    sample(200,000), which NumPy's allocations report to), so the refusal is never too late."""
    import tracemalloc

    for name, model in SAMPLERS.items():
        model.sample(10, np.random.default_rng(0))
        tracemalloc.start()
        try:
            model.sample(200_000, np.random.default_rng(1))
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak / 200_000 <= getattr(model, "sample_bytes", SAMPLE_BYTES), (name, peak / 200_000)


# -- radial laws and batches -----------------------------------------------------------------

CAT = SAMPLERS["cat"]


@MODEL_SWEEP
@given(SIGNED, st.one_of(MAGNITUDES, MAGNITUDES.map(lambda v: -v)), st.integers(1, 4),
       st.one_of(st.none(), MAGNITUDES))
def test_radial_laws_at_the_extremes(start, step, count, r_max):
    """Angles a subnormal step apart (5e-324), anywhere up to 1.8e308 rad, ranges to 1.8e308 m."""
    angles = start + step * np.arange(count) if math.isfinite(start + step * count) else [start]
    moments = refused_or(lambda: bg.radial_moments(CAT, angles, r_max=r_max), ["angles", "angle", "r_max"])
    if moments is not None:
        finite(moments.mean, moments.sd, moments.mass)
        assert np.all(moments.sd >= 0.0) and np.all(moments.mass >= 0.0)
    law = refused_or(lambda: bg.radial_density(CAT, float(start), r_max=r_max), ["angle", "r_max"])
    if law is not None:
        finite(law.density, law.normal, law.mean, law.sd)


@MODEL_SWEEP
@given(st.one_of(st.sampled_from([0.0, TINY, 1e-308, 1e308, HUGE, 1.0]), MAGNITUDES))
def test_radial_scales_of_extreme_models(scale):
    """Motion models whose length scales are subnormal or huge: the rays' nodes stay countable."""
    def moments():
        model = bg.PolarBanana(v0=scale, t=1.0, sigma_a=scale, sigma_omega=0.1)
        return bg.radial_moments(model, [0.0, 0.1])

    result = refused_or(moments, MOTION + ["angles", "angle", "r_max"])
    if result is not None:
        finite(result.mean, result.sd, result.mass)


# -- mixtures: means and points anywhere in float64 ------------------------------------------


@SWEEP
@given(SIGNED, SIGNED, SIGNED, SIGNED, MAGNITUDES, st.floats(-0.99, 0.99))
def test_mixture_densities_with_means_and_points_anywhere(mx, my, px, py, scale, rho):
    """A mixture's ``pdf`` with means and points anywhere in float64 (as far as +-1.8e308 apart,
    where their difference overflows): finite and non-negative, 0 where a point lies farther
    than float64 reaches, and the normal's peak at the mean; or the covariance refused by name."""
    def call():
        cov = [[scale * scale, rho * scale * scale], [rho * scale * scale, scale * scale]]
        mixture = bg.GaussianMixture(weights=[0.5, 0.5], means=[[mx, my], [0.0, 0.0]], covs=[cov, [[1.0, 0.0], [0.0, 1.0]]])
        points = np.array([[px, py], [mx, my], [-mx, -my]])
        values = mixture.pdf(points)
        finite(values)
        assert np.all(values >= 0.0)
        if math.isfinite(mx - px) and math.isfinite(my - py) and max(abs(mx - px), abs(my - py)) > 1e200:
            assert values[0] <= 0.5 / (2.0 * math.pi)  # only the unit component can hold it
        return values

    refused_or(call, ["covs", "means", "weights"])


#: Variances at the bottom of float64: subnormal, the smallest normals, and just above, where a
#: normal's peak density 1 / (2 pi sqrt(det)) crosses float64's largest value (near 1e-308).
TINY_VARIANCES = st.one_of(
    st.sampled_from([TINY, 1e-323, 1e-320, 1e-315, 1e-310, 2.2250738585072014e-308, 1e-308, 1.7e-308,
                     1e-307, 1e-300, 1e-290]),
    st.floats(TINY, 1e-290, allow_subnormal=True))


@MODEL_SWEEP
@given(TINY_VARIANCES, st.one_of(st.just(1.0), st.floats(1e-13, 1.0)), st.floats(-0.999, 0.999),
       st.one_of(st.just(0.0), SIGNED))
def test_mixture_covariances_near_the_smallest_floats(variance, ratio, rho, shift):
    """A mixture component whose covariance is tiny but positive definite (variances from 5e-324
    to 1e-290, aspect ratios to 1e13, correlations to 0.999), its mean anywhere: refused in one
    line naming ``covs``, or densities that are finite (at the mean, a few SDs off and far away)
    and cell probabilities on a grid of its own scale that are the unit-variance mixture's (a
    rectangle's probability is invariant under scaling both), to 1e-9 relative plus 1e-14
    (docs/accuracy.md, presence cells: Genz's BVNU is accurate to about 1e-15 absolute)."""
    vx, vy = variance, variance * ratio

    def mixture(scale_x, scale_y, mean):
        c = rho * math.sqrt(scale_x) * math.sqrt(scale_y)
        return bg.GaussianMixture(weights=[1.0], means=[mean], covs=[[[scale_x, c], [c, scale_y]]])

    tiny = refused_or(lambda: mixture(vx, vy, (shift, -shift)), ["covs"])
    if tiny is None:
        return
    sx, sy = math.sqrt(vx), math.sqrt(vy)
    density = tiny.pdf(np.array([[shift, -shift], [shift + 2.0 * sx, -shift - sy], [0.0, 1.0]]))
    finite(density)
    assert np.all(density >= 0.0) and density[0] > 0.0
    # the same law in units of its SDs: the grid's cells are the unit grid's scaled
    unit = mixture(1.0, 1.0, (0.0, 0.0))
    n = 6
    small = refused_or(lambda: bg.Grid(origin=(shift - 3.0 * sx, -shift - 3.0 * sy), dx=sx, dy=sy, nx=n, ny=n),
                       ["origin", "dx", "dy", "grid"])
    k = np.arange(n + 1)
    # the unit grid's edges, to 1e-12 (moving the cells' probabilities by far less than the
    # tolerance), unless a mean far from 0 rounds the tiny steps away: nothing to compare then
    if small is None or not (np.allclose((small.origin[0] + sx * k - shift) / sx, k - 3.0, rtol=0.0, atol=1e-12)
                             and np.allclose((small.origin[1] + sy * k + shift) / sy, k - 3.0, rtol=0.0, atol=1e-12)):
        return
    cells = refused_or(lambda: bg.grid_probabilities(tiny, small), ["grid", "mixture", "covs"])
    if cells is None:
        return
    finite(cells.probability, cells.density)
    want = bg.grid_probabilities(unit, bg.Grid(origin=(-3.0, -3.0), dx=1.0, dy=1.0, nx=n, ny=n)).probability
    np.testing.assert_allclose(cells.probability, want, rtol=1e-9, atol=1e-14)


#: Elapsed times at the bottom of float64, and ordinary ones.
TINY_TIMES = st.one_of(st.sampled_from([TINY, 1e-320, 1e-310, 2.2250738585072014e-308, 1e-300, 1e-200, 1e-30]),
                       st.floats(TINY, 1e-290, allow_subnormal=True), st.floats(1e-3, 1e4))


@MODEL_SWEEP
@given(st.one_of(TINY_VARIANCES, st.floats(1e-6, 1e6)), st.one_of(st.just(1.0), st.floats(1e-6, 1.0)),
       st.floats(-0.999, 0.999), TINY_TIMES, st.floats(0.1, 10.0))
def test_butterly_at_tiny_times_and_covariances(variance, ratio, rho, t, speed):
    """Butterly with start covariances from 5e-324 up and elapsed times from 5e-324 up: refused
    in one line naming ``cov`` or ``t``, or densities that are finite and are the same law's in
    units of its SD (the density scales as 1 / variance: the model with covariance cov / v and
    time t / sqrt(v) at the points divided by sqrt(v), where that one is ordinary), to the
    docs/accuracy.md's 1e-9 relative (plus 1e-9 of the peak, for points in the tails)."""
    c = rho * math.sqrt(variance) * math.sqrt(variance * ratio)

    def build(v, cc, time):
        return bg.Butterly(mean=(0.0, 0.0), cov=[[v, cc], [cc, v * ratio]], speeds=[speed], t=time)

    model = refused_or(lambda: build(variance, c, t), ["cov", "t", "speeds"])
    if model is None:
        return
    s = math.sqrt(variance)
    ring = speed * (t / s)  # the ring's radius in SDs
    unit_points = np.array([[0.0, 0.0], [1.0, 0.5], [ring, 0.0], [0.0, -ring], [-2.0, 1.0]])
    values = refused_or(lambda: model.pdf(unit_points[:, 0] * s, unit_points[:, 1] * s), ["x", "y", "points"])
    finite(values)
    assert np.all(values >= 0.0)
    if ring <= 1.0:  # the mean is within an SD of the ring: near the peak, not 0
        assert values[0] > 0.0
    if not (1e-3 <= t / s <= 1e6 or t / s <= 1e-12):
        return  # no ordinary twin to compare with
    unit = build(1.0, c / variance, max(t / s, 1e-12))  # below 1e-12 SDs the ring is a point either way
    want = unit.pdf(unit_points[:, 0], unit_points[:, 1])
    np.testing.assert_allclose(values * variance, want, rtol=1e-9, atol=1e-9 * want.max())


@pytest.mark.parametrize("name", ["cat", "cat-heading", "rough", "improved", "butterly", "bearing", "bearing-linear"])
def test_densities_at_points_as_far_as_float64_reaches(name):
    """Every model's ``pdf`` at points up to +-1.8e308 from its origin (where distances
    overflow): finite, no RuntimeWarning, 0 that far out (the exact bearing map excepted: its
    flat prior keeps a little density along the bearings however far); or (the
    heading-convolved CAT) one line naming the parameter whose table cannot reach that far."""
    fig1 = dict(v0=280.0, t=10.0, sigma_a=5.0 / 3.0, sigma_omega=math.pi / 54.0)
    model = {
        "cat": lambda: bg.CAT(**fig1),
        "cat-heading": lambda: bg.CAT(**fig1, sigma_heading=0.1),
        "rough": lambda: bg.PolarBanana(**fig1, variant="rough"),
        "improved": lambda: bg.PolarBanana(**fig1, variant="improved"),
        "butterly": lambda: bg.Butterly(mean=(0.0, 0.0), cov=[[1e4, 0.0], [0.0, 1e4]], speeds=[1.0], t=600.0),
        "bearing": lambda: bg.BearingFix(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909],
                                         sigmas=[0.01, 0.02]),
        "bearing-linear": lambda: bg.BearingFix(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909],
                                                sigmas=[0.01, 0.02], variant="linear"),
    }[name]()
    far = [HUGE, -HUGE, 1e300, -1e300, 1e308]
    x = np.array([a for a in far for _ in far])
    y = np.array([b for _ in far for b in far])
    # the heading-convolved CAT tabulates its law over the points' ranges: that far, a table
    # it cannot hold, refused by name
    values = refused_or(lambda: model.pdf(x, y), ["sigma_heading"] if name == "cat-heading" else [])
    if values is not None:
        finite(values)
        assert np.all(values >= 0.0), values
        if name != "bearing":
            assert np.all(values == 0.0), values
