"""Bad input: one test per kind of bad parameter, each asserting its message."""

import math
import warnings

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.domains.grid import MAX_CELLS

from cases import FIG1

BAD_NUMBERS = [
    (0.0, "must be > 0"),
    (-1.0, "must be > 0"),
    (math.nan, "must be finite"),
    (math.inf, "must be finite"),
    ("3", "expected a real number"),
]


@pytest.mark.parametrize("model_cls", [bg.CAT, bg.PolarBanana])
@pytest.mark.parametrize("name", ["v0", "t", "sigma_a", "sigma_omega"])
@pytest.mark.parametrize("value, message", BAD_NUMBERS)
def test_model_parameter_rejected(model_cls, name, value, message):
    params = dict(FIG1, **{name: value})
    with pytest.raises(bg.BananagridError) as err:
        model_cls(**params)
    assert str(err.value).startswith(f"{name} = ")
    assert message in str(err.value)


def test_k_sigma_range():
    with pytest.raises(bg.BananagridError, match=r"k_sigma = 0.5: must be in \[1, 38\]"):
        bg.CAT(**FIG1, k_sigma=0.5)


def test_unknown_variant():
    with pytest.raises(bg.BananagridError, match="variant = 'smooth': must be one of rough, improved"):
        bg.PolarBanana(**FIG1, variant="smooth")


@pytest.mark.parametrize("model_cls", [bg.CAT, bg.PolarBanana])
@pytest.mark.parametrize(
    "value, message",
    [(-0.1, "must be >= 0"), (math.nan, "must be finite"), (math.inf, "must be finite"), ("0.1", "expected a real number")],
)
def test_sigma_heading_rejected(model_cls, value, message):
    with pytest.raises(bg.BananagridError) as err:
        model_cls(**FIG1, sigma_heading=value)
    assert str(err.value).startswith("sigma_heading = ")
    assert message in str(err.value)


@pytest.mark.parametrize("order", [0, 3, 2.5, True, "4"])
def test_heading_order_rejected(order):
    with pytest.raises(bg.BananagridError, match=r"heading_order = .*: must be 2 \(\(15\), \(16\)\) or 4"):
        bg.PolarBanana(**FIG1, sigma_heading=0.1, heading_order=order)


def test_pose_rejects_nan_origin_and_heading():
    with pytest.raises(bg.BananagridError, match=r"origin\[1\] = nan: must be finite"):
        bg.Pose(origin=(0.0, math.nan))
    with pytest.raises(bg.BananagridError, match="heading = inf: must be finite"):
        bg.Pose(heading=math.inf)
    with pytest.raises(bg.BananagridError, match="origin = 3.0: expected a pair"):
        bg.Pose(origin=3.0)


def test_improved_warns_where_p_sigma_turns_negative():
    # sigma_positive_limit = sigma_omega sqrt(t^2/12 + 6 v0^2 / sigma_a^2) = 0.1 * sqrt(1/12 + 24) < pi
    with pytest.warns(UserWarning, match="P_sigma .* not positive"):
        bg.PolarBanana(v0=10.0, t=1.0, sigma_a=5.0, sigma_omega=0.1)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(x=(0.0, 0.0), y=(0.0, 1.0), step=1.0), r"x = \(0.0, 0.0\): the upper bound must exceed the lower"),
        (dict(x=(0.0, 1.0), y=(5.0, 1.0), step=1.0), r"y = \(5.0, 1.0\): the upper bound must exceed the lower"),
        (dict(x=(0.0, 1.0), y=(0.0, 1.0), step=0.0), "step = 0.0: must be > 0"),
        (dict(x=(0.0, 1.0), y=(0.0, 1.0), step=-2.0), "step = -2.0: must be > 0"),
        (dict(x=(0.0, math.nan), y=(0.0, 1.0), step=1.0), r"x\[1\] = nan: must be finite"),
        (dict(x=(0.0, 1.0), y=(-math.inf, 1.0), step=1.0), r"y\[0\] = -inf: must be finite"),
        (dict(x=0.0, y=(0.0, 1.0), step=1.0), "x = 0.0: expected bounds"),
        (dict(x=(0.0, 1.0), y=(0.0, 1.0)), "step .* is required"),
    ],
)
def test_grid_bounds_rejected(kwargs, message):
    with pytest.raises(bg.BananagridError, match=message):
        bg.Grid.from_bounds(**kwargs)


def test_gigantic_grid_states_memory():
    with pytest.raises(bg.BananagridError) as err:
        bg.Grid.from_bounds(x=(0.0, 1e6), y=(0.0, 1e6), step=1.0)
    message = str(err.value)
    assert "1000000 x 1000000" in message and "7450.6 GiB" in message and f"{MAX_CELLS:,}" in message


def test_explicit_grid_rejects_bad_counts():
    with pytest.raises(bg.BananagridError, match="nx = 0: must be >= 1"):
        bg.Grid(origin=(0.0, 0.0), dx=1.0, dy=1.0, nx=0, ny=3)
    with pytest.raises(bg.BananagridError, match="ny = 2.5: expected an integer"):
        bg.Grid(origin=(0.0, 0.0), dx=1.0, dy=1.0, nx=2, ny=2.5)


def test_grid_cell_centres_and_rounding():
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=4.0)
    assert grid.shape == (900, 1500)
    assert grid.x[0] == -2998.0 and grid.x[-1] == 2998.0
    assert grid.y[0] == -198.0 and grid.y[-1] == 3398.0
    # a non-whole extent is covered by moving the upper edge out to the next whole cell
    grid = bg.Grid.from_bounds(x=(0.0, 10.5), y=(0.0, 1.0), step=1.0)
    assert grid.nx == 11 and grid.extent[1] == 11.0


def test_rasterise_rejects_bad_dtype_device_threads():
    model = bg.CAT(**FIG1)
    grid = bg.Grid.from_bounds(x=(0.0, 10.0), y=(0.0, 10.0), step=5.0)
    with pytest.raises(bg.BananagridError, match="dtype = .*int32.*: must be float32 or float64"):
        bg.rasterise(model, grid, dtype=np.int32)
    with pytest.raises(bg.BananagridError, match="device = 'tpu': not available here"):
        bg.rasterise(model, grid, device="tpu")
    with pytest.raises(bg.BananagridError, match="threads = 0: expected an integer >= 1"):
        bg.rasterise(model, grid, threads=0)
    with pytest.raises(bg.BananagridError, match="grid = .*: expected a bananagrid.Grid"):
        bg.rasterise(model, "grid")


def test_pdf_rejects_nan_points_and_bad_shapes():
    model = bg.PolarBanana(**FIG1)
    with pytest.raises(bg.BananagridError, match="points must be finite"):
        model.pdf([0.0, math.nan], [1.0, 2.0])
    with pytest.raises(bg.BananagridError, match="do not broadcast"):
        model.pdf(np.zeros(3), np.zeros(4))


def test_sample_rejects_bad_n_and_rng():
    model = bg.CAT(**FIG1)
    with pytest.raises(bg.BananagridError, match="n = -1: expected a non-negative integer"):
        model.sample(-1, np.random.default_rng(0))
    with pytest.raises(bg.BananagridError, match="rng = 'x': expected a numpy.random.Generator"):
        model.sample(3, "x")


def test_single_axis_overflow_states_memory():
    with pytest.raises(bg.BananagridError, match=r"x bounds \(0.0, 1000000000000.0\) at step 1.0 give 1,000,000,000,000 cells in one axis, over 7450.6 GiB as float64"):
        bg.Grid.from_bounds(x=(0.0, 1e12), y=(0.0, 1.0), step=1.0)


def test_normalise_without_mass_is_a_clear_error():
    grid = bg.Grid.from_bounds(x=(1e6, 1e6 + 10.0), y=(0.0, 10.0), step=5.0)
    raster = bg.rasterise(bg.PolarBanana(**FIG1), grid)
    assert raster.mass == 0.0
    with pytest.raises(bg.BananagridError, match="cannot normalise a raster that captured no mass"):
        raster.normalise()


NOT_NUMBERS = [
    ("speeds", lambda v: bg.Butterly(mean=(0.0, 0.0), cov=[[1.0, 0.0], [0.0, 1.0]], speeds=v, t=1.0), ["1"]),
    ("speeds", lambda v: bg.Butterly(mean=(0.0, 0.0), cov=[[1.0, 0.0], [0.0, 1.0]], speeds=v, t=1.0), [True]),
    ("cov", lambda v: bg.Butterly(mean=(0.0, 0.0), cov=v, speeds=[1.0], t=1.0), [["1", 0.0], [0.0, 1.0]]),
    ("bearings", lambda v: bg.BearingFix([[0.0, 0.0], [1000.0, 0.0]], v, [0.01, 0.01]), ["0.1", 0.2]),
    ("sigmas", lambda v: bg.BearingFix([[0.0, 0.0], [1000.0, 0.0]], [0.1, -0.2], v), [True, 0.01]),
    ("weights", lambda v: bg.GaussianMixture(weights=v, means=[[0.0, 0.0]], covs=[[[1.0, 0.0], [0.0, 1.0]]]), [True]),
    ("means", lambda v: bg.GaussianMixture(weights=[1.0], means=v, covs=[[[1.0, 0.0], [0.0, 1.0]]]), [["0", 0.0]]),
]


@pytest.mark.parametrize("name, build, value", NOT_NUMBERS, ids=[f"{n}-{v!r}" for n, _, v in NOT_NUMBERS])
def test_strings_and_booleans_are_not_numbers(name, build, value):
    """NumPy turns "1" and True into 1.0; the parameters refuse them, naming the argument."""
    with pytest.raises(bg.BananagridError, match=rf"^{name} = .*: expected"):
        build(value)


@pytest.mark.parametrize("bounds, step, message", [
    (dict(x=(0.0, 1.0), y=(0.0, 1.0)), 1e-308, r"x bounds \(0.0, 1.0\) at step 1e-308 give 1e\+308 cells in one axis, over 7.45e\+299 GiB"),
    (dict(x=(0.0, 10.0), y=(0.0, 1.0)), 1e-308, r"x bounds \(0.0, 10.0\) at step 1e-308: the number of cells overflows"),
    (dict(x=(-1e308, 1e308), y=(0.0, 1.0)), 1.0, r"x bounds .* the number of cells overflows"),
    (dict(x=(0.0, 1.0), y=(0.0, 1.0)), 1e308, r"dx, dy = 1e\+308, 1e\+308: the cell area inf m\^2"),
    (dict(x=(1.7e308, 1.75e308), y=(0.0, 1.0)), 1e307, r"grid extent in x is not finite"),
])
def test_grids_whose_numbers_overflow_are_refused(bounds, step, message):
    """Extreme steps and bounds: a message, not an OverflowError or a NaN mass later."""
    with pytest.raises(bg.BananagridError, match=message):
        bg.Grid.from_bounds(**bounds, step=step)


@pytest.mark.parametrize("kwargs, match", [
    (dict(sigmas=[1e-308, 0.01]), r"sigmas\[0\] = 1e-308: must be in \[1e-10, 1e\+150\] rad"),
    (dict(sigmas=[0.01, 1e308]), r"sigmas\[1\] = 1e\+308: must be in"),
    (dict(sensors=[[0.0, 0.0], [1e308, 0.0]]), r"sensors\[1\]\[0\] = 1e\+308: must be within \+-1e\+150 m"),
])
def test_bearing_values_whose_squares_overflow_are_refused(kwargs, match):
    """1 / sigma^2 and squared ranges overflowed with a NumPy RuntimeWarning and went on."""
    args = dict(sensors=[[0.0, 0.0], [10_000.0, 0.0]], bearings=[0.3, -0.3], sigmas=[0.01, 0.01]) | kwargs
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(bg.BananagridError, match=match):
            bg.BearingFix(**args)


@pytest.mark.parametrize("mean, sd", [(9.2e18, 0.8), (5.0, 1e-308)])
def test_a_normal_speed_law_narrower_than_its_quadrature_is_refused(mean, sd):
    """Nodes 20 SDs wide around 9.2e18 m/s coincide in float64 (the weights summed to 0)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(bg.BananagridError, match=r"speeds\.sd = .*: below 1e-09 of the mean .* the law is one speed"):
            bg.NormalSpeed(mean, sd)


@pytest.mark.parametrize("model", [bg.CAT, bg.PolarBanana])
def test_a_heading_sd_whose_square_overflows_is_refused(model):
    """sigma_heading_deg = 1e308 was accepted and overflowed in the polar coefficients (12)."""
    with pytest.raises(bg.BananagridError, match=r"sigma_heading = 1\.7\d*e\+306: must be at most 1e\+150 rad"):
        model(v0=8.0, t=60.0, sigma_a=0.02, sigma_omega=0.01, sigma_heading=math.radians(1e308))


# --- the shared checks of bananagrid.validate: covariances, polygons, timed tracks ------------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from bananagrid.validate import MAX_CONDITION, covariance, polygon, timed_track  # noqa: E402

FUZZ = settings(max_examples=200, deadline=None, derandomize=True, database=None)


@FUZZ
@given(small=st.floats(-100.0, 100.0), ratio=st.floats(0.0, 16.0), angle=st.floats(0.0, math.pi))
def test_every_well_conditioned_covariance_is_taken_as_given(small, ratio, angle):
    """R diag(s1, s2) R^T with s1 = 10^small and s2 = s1 10^ratio: taken as given where the
    condition number 10^ratio is below MAX_CONDITION (1e13) by a factor 10, refused with its
    eigenvalues where it is above by 10 (between, the construction's own rounding decides)."""
    s1, s2 = 10.0**small, 10.0 ** (small + ratio)
    c, s = math.cos(angle), math.sin(angle)
    rotation = np.array([[c, -s], [s, c]])
    cov = rotation @ np.diag([s1, s2]) @ rotation.T
    cov[1, 0] = cov[0, 1]  # symmetric as written in a scene
    if 10.0**ratio < MAX_CONDITION / 10:
        out = covariance("cov", cov.tolist())
        assert out.dtype == np.float64 and np.array_equal(out, cov)
    elif 10.0**ratio > MAX_CONDITION * 10:
        with pytest.raises(bg.BananagridError, match=r"^cov = .*: must be positive definite \((variances|eigenvalues)"):
            covariance("cov", cov)


BAD_COVARIANCES = {
    "shape": ([[1.0, 0.0, 0.0]], r"^cov = \[\[1.0, 0.0, 0.0\]\]: expected a 2x2 array \[\[sxx, sxy\], \[sxy, syy\]\], got shape \(1, 3\)$"),
    "text": ([[1.0, "0"], [0.0, 1.0]], r"^cov = .*: expected a 2x2 array of numbers$"),
    "nan": ([[1.0, math.nan], [math.nan, 1.0]], r"^cov = .*: every entry must be finite \(NaN or inf given\)$"),
    "asymmetric": ([[1.0, 0.5], [0.4, 1.0]], r"^cov = .*: must be symmetric \(cov\[0\]\[1\] == cov\[1\]\[0\]\)$"),
    "negative variance": ([[-1.0, 0.0], [0.0, 1.0]], r"^cov = .*: must be positive definite \(variances > 0\)$"),
    "correlation 1": ([[4.0, 6.0], [6.0, 9.0]], r"^cov = .*: must be positive definite \(eigenvalues 0, 13; "
                                                  r"correlation 1; allowed: \|rho\| < 1 and a condition number below 1e\+13\)$"),
}


@pytest.mark.parametrize("case", BAD_COVARIANCES)
def test_a_bad_covariance_is_named(case):
    value, message = BAD_COVARIANCES[case]
    with pytest.raises(bg.BananagridError, match=message):
        covariance("cov", value)


def test_a_covariance_of_three_axes():
    good = np.array([[4.0, 1.0, 0.0], [1.0, 9.0, 0.0], [0.0, 0.0, 1e6]])  # units of different size on z
    assert np.array_equal(covariance("covs[0]", good, dim=3), good)
    with pytest.raises(bg.BananagridError, match=r"^covs\[0\] = .*: must be symmetric \(covs\[0\]\[0\]\[2\]|"
                                                 r"^covs\[0\] = .*: must be symmetric \(covs\[0\]\[0\]\[2\] == "):
        covariance("covs[0]", good + np.diag([0.0, 0.0, 0.0]) + np.array([[0, 0, 1.0], [0, 0, 0], [0, 0, 0]]), dim=3)
    singular = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(bg.BananagridError, match=r"condition number below 1e\+13"):
        covariance("covs[0]", singular, dim=3)


@FUZZ
@given(n=st.integers(3, 24), radius=st.floats(1e-3, 1e9), turn=st.floats(0.0, 2 * math.pi),
       centre=st.tuples(st.floats(-1e9, 1e9), st.floats(-1e9, 1e9)), closed=st.booleans(), jitter=st.randoms())
def test_every_convex_polygon_is_taken_and_a_swap_of_two_vertices_is_not(n, radius, turn, centre, closed, jitter):
    """Vertices on a circle at increasing angles (spread at random) make a convex polygon; swapping
    two neighbours of a polygon of 4 or more makes two of its edges cross."""
    angles = turn + np.sort(np.array([jitter.uniform(0.1, 1.0) for _ in range(n)]).cumsum())
    angles = turn + (angles - turn) * (2 * math.pi * 0.95 / (angles[-1] - turn))  # within one turn
    ring = np.column_stack((centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)))
    if radius < 1e-6 * max(map(abs, centre)):  # a polygon lost in the rounding of its offset
        return
    given_ring = np.vstack((ring, ring[:1])) if closed else ring
    assert np.array_equal(polygon("area", given_ring.tolist()), ring)
    if n >= 4:
        k = jitter.randrange(n)
        swapped = ring.copy()
        swapped[[k, (k + 1) % n]] = swapped[[(k + 1) % n, k]]
        with pytest.raises(bg.BananagridError, match=r"^area: edges \d+-\d+ and \d+-\d+ cross; the polygon must not cross itself$"):
            polygon("area", swapped)


BAD_POLYGONS = {
    "two vertices": ([[0.0, 0.0], [1.0, 0.0]], r"^area: 2 distinct vertices given, a polygon needs at least 3$"),
    "not pairs": ([[0.0, 0.0, 0.0]], r"^area = \[\[0.0, 0.0, 0.0\]\]: expected a list of \[x, y\] vertices, got shape \(1, 3\)$"),
    "infinite": ([[0.0, 0.0], [1.0, math.inf], [1.0, 1.0]], r"^area\[1\] = \[1.0, inf\]: must be finite$"),
    "repeated": ([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0]], r"^area\[2\] = \[1.0, 0.0\]: repeats the vertex before it$"),
    "on a line": ([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]], r"^area = .*: encloses no area \(its vertices lie on a line\)$"),
    "bow tie": ([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]], r"^area: edges 0-1 and 2-3 cross"),
    "touching": ([[0.0, 0.0], [2.0, 0.0], [1.0, 0.0], [1.0, 1.0]], r"^area: edges 0-1 and 2-3 cross"),
}


@pytest.mark.parametrize("case", BAD_POLYGONS)
def test_a_bad_polygon_is_named(case):
    value, message = BAD_POLYGONS[case]
    with pytest.raises(bg.BananagridError, match=message):
        polygon("area", value)


@FUZZ
@given(steps=st.lists(st.floats(1e-6, 1e6), min_size=1, max_size=30), start=st.floats(-1e9, 1e9), seed=st.integers(0, 99))
def test_every_increasing_track_is_taken_and_a_step_back_is_named(steps, start, seed):
    times = start + np.cumsum([0.0, *steps])
    if not np.all(np.diff(times) > 0):  # steps lost to the rounding of a large start
        return
    positions = np.random.default_rng(seed).normal(0.0, 1e4, (len(times), 2))
    t, p = timed_track("track", times.tolist(), positions.tolist())
    assert np.array_equal(t, times) and np.array_equal(p, positions)
    k = 1 + seed % len(steps)
    back = times.copy()
    back[k] = back[k - 1]
    with pytest.raises(bg.BananagridError, match=rf"^track.times\[{k}\] = .*: must be later than the time before it"):
        timed_track("track", back, positions)


BAD_TRACKS = {
    "one point": ([0.0], [[0.0, 0.0]], r"^track: 1 point given, a track needs at least 2$"),
    "lengths": ([0.0, 1.0], [[0.0, 0.0]], r"^track: 2 times and 1 positions; give one position per time$"),
    "nan time": ([0.0, math.nan], [[0.0, 0.0], [1.0, 1.0]], r"^track.times\[1\] = nan: must be finite$"),
    "positions shape": ([0.0, 1.0], [0.0, 1.0], r"^track.positions = \[0.0, 1.0\]: expected a list of \[x, y\] positions \(m\)$"),
    "text": (["0", 1.0], [[0.0, 0.0], [1.0, 1.0]], r"^track.times = \['0', 1.0\]: expected a list of times \(s\)$"),
}


@pytest.mark.parametrize("case", BAD_TRACKS)
def test_a_bad_track_is_named(case):
    times, positions, message = BAD_TRACKS[case]
    with pytest.raises(bg.BananagridError, match=message):
        timed_track("track", times, positions)
