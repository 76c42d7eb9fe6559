"""Bearing-fix geometry (Walsh): fix, linearised covariance, ellipse, and bad geometry."""

import math
import warnings

import numpy as np
import pytest

from bananagrid import BananagridError
from bananagrid.models.bearing import BearingFix, bearing_to

#: Two coastal stations 20 km apart and a contact about 30 km out (the bearing_coastal scene).
STATIONS = np.array([[0.0, 0.0], [20000.0, 0.0]])
CONTACT = np.array([8000.0, 30000.0])
SIGMAS = np.array([0.01, 0.02])


def make(sensors=STATIONS, target=CONTACT, sigmas=SIGMAS, noise=None):
    bearings = bearing_to(sensors, target)
    if noise is not None:
        bearings = bearings + noise
    return BearingFix(sensors, bearings, sigmas)


def crossing_by_hand(sensors, bearings):
    """Walsh's standardised formulas: sensor 1 at the origin, sensor 2 at (D, 0) after a
    rotation; X = D cot(a1) / (cot(a1) - cot(a2)), Y = D / (cot(a1) - cot(a2)), with a_i the
    angles from the baseline (mathematical convention)."""
    s1, s2 = sensors
    base = s2 - s1
    d = np.hypot(*base)
    rot = math.atan2(base[1], base[0])  # baseline angle from east
    # a bearing (clockwise from north) is the mathematical angle pi/2 - b; measure from baseline
    a1 = (math.pi / 2 - bearings[0]) - rot
    a2 = (math.pi / 2 - bearings[1]) - rot
    x = d / math.tan(a1) / (1 / math.tan(a1) - 1 / math.tan(a2))
    y = d / (1 / math.tan(a1) - 1 / math.tan(a2))
    c, s = math.cos(rot), math.sin(rot)
    return s1 + np.array([x * c - y * s, x * s + y * c])


@pytest.mark.parametrize("noise", [None, np.array([0.01, -0.02]), np.array([-0.03, 0.005])])
def test_two_sensor_fix_is_walsh_crossing(noise):
    fix = make(noise=noise)
    want = crossing_by_hand(STATIONS, fix.bearings)
    np.testing.assert_allclose(fix.fix, want, rtol=1e-12)


def test_covariance_is_jacobian_of_the_fix():
    """ERRATA: the covariance is J diag(s^2) J^T, J = d fix / d bearing errors; here J comes
    from central differences of Walsh's crossing formulas (step 1e-7 rad: truncation ~1e-14
    relative, rounding ~1e-9 relative for coordinates of 3e4 m)."""
    fix = make()
    h = 1e-7
    jac = np.zeros((2, 2))
    for i in range(2):
        step = np.zeros(2)
        step[i] = h
        jac[:, i] = (crossing_by_hand(STATIONS, fix.bearings + step) - crossing_by_hand(STATIONS, fix.bearings - step)) / (2 * h)
    want = jac @ np.diag(SIGMAS**2) @ jac.T
    np.testing.assert_allclose(fix.covariance, want, rtol=1e-6)


def test_covariance_matches_monte_carlo_for_small_errors():
    """Re-triangulating perturbed bearings: with sigma = 1e-4 rad the nonlinearity is ~1e-4 of
    the spread, so the sample covariance of 200,000 fixes matches the linearised one within its
    sampling error (~ sqrt(2 / n) = 0.3 % per variance; 1.5 % allows 5 sigma)."""
    small = SIGMAS / 100
    fix = make(sigmas=small)
    rng = np.random.default_rng(2)
    n = 200_000
    eps = rng.normal(size=(n, 2)) * small
    u1 = np.column_stack((np.sin(fix.bearings[0] + eps[:, 0]), np.cos(fix.bearings[0] + eps[:, 0])))
    u2 = np.column_stack((np.sin(fix.bearings[1] + eps[:, 1]), np.cos(fix.bearings[1] + eps[:, 1])))
    # S1 + s1 u1 = S2 + s2 u2  ->  s1 = cross(S2 - S1, u2) / cross(u1, u2)
    d = STATIONS[1] - STATIONS[0]
    s1 = (d[0] * u2[:, 1] - d[1] * u2[:, 0]) / (u1[:, 0] * u2[:, 1] - u1[:, 1] * u2[:, 0])
    pts = STATIONS[0] + s1[:, None] * u1
    np.testing.assert_allclose(np.cov(pts.T), fix.covariance, rtol=0.015, atol=0.015 * fix.covariance.max())


def test_three_sensors_weighted_least_squares():
    sensors = np.vstack((STATIONS, [[10000.0, -5000.0]]))
    exact = make(sensors=sensors, sigmas=[0.01, 0.02, 0.01])
    np.testing.assert_allclose(exact.fix, CONTACT, rtol=1e-12)  # noise-free: the true point
    noisy = make(sensors=sensors, sigmas=[0.01, 0.02, 0.01], noise=np.array([0.001, -0.002, 0.0005]))
    # the WLS point makes the weighted bearing residuals orthogonal to their gradients
    d = noisy.fix - sensors
    r2 = (d**2).sum(axis=1)
    g = np.column_stack((d[:, 1], -d[:, 0])) / r2[:, None]
    resid = np.angle(np.exp(1j * (np.arctan2(d[:, 0], d[:, 1]) - noisy.bearings)))
    assert np.abs(g.T @ (resid / noisy.sigmas**2)).max() < 1e-12 * np.abs(g).max() / noisy.sigmas.min() ** 2
    # a third sensor can only shrink the linearised error
    assert np.trace(exact.covariance) < np.trace(make().covariance)


def test_ellipse_axes_are_the_covariance_eigen():
    fix = make()
    e = fix.ellipse(2.0)
    v1, v2 = fix.principal_variances
    assert e["semi_major"] == pytest.approx(2 * math.sqrt(v1), rel=1e-12)
    assert e["semi_minor"] == pytest.approx(2 * math.sqrt(v2), rel=1e-12)
    assert e["probability"] == pytest.approx(1 - math.exp(-2.0), rel=1e-15)
    axis = np.array([math.sin(e["bearing"]), math.cos(e["bearing"])])
    assert axis @ fix.covariance @ axis == pytest.approx(v1, rel=1e-12)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(sigmas=[0.01, 0.0]), r"sigmas\[1\] = 0.0: must be > 0"),
        (dict(sigmas=[-0.01, 0.02]), r"sigmas\[0\] = -0.01: must be > 0"),
        (dict(sigmas=[0.01, math.nan]), "sigmas = .*: every value must be finite"),
        (dict(sigmas=[0.01]), "lengths 2, 2, 1 must match"),
        (dict(sensors=[[0.0, 0.0]], bearings=[0.1], sigmas=[0.01]), "sensors: 1 given, a fix needs at least 2"),
        (dict(sensors=[[0.0, 0.0], [0.0, 0.0]]), "sensors 0 and 1 coincide"),
        (dict(sensors=[0.0, 1.0]), r"sensors: shape \(2,\), expected an \(n, 2\) array"),
        (dict(bearings=[0.3, 0.3 + 1e-3]), "the lines cross at .* deg, below 2.0 deg: nearly parallel"),
        (dict(bearings=[math.pi + 0.26, -0.5]), r"bearings\[0\] = .*: the fix .* lies behind sensor 0"),
        (dict(bearings=["north", 0.1]), "bearings = .*: expected an \\(n,\\) array of numbers"),
    ],
)
def test_bad_input(kwargs, message):
    args = dict(sensors=STATIONS, bearings=bearing_to(STATIONS, CONTACT), sigmas=SIGMAS)
    args.update(kwargs)
    with pytest.raises(BananagridError, match=message):
        BearingFix(**args)


def test_poor_crossing_warns():
    far = np.array([10000.0, 150000.0])  # about 7.6 deg crossing
    with pytest.warns(UserWarning, match="bearings cross at .* deg .* optimistic"):
        make(target=far)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        make()  # 26 deg crossing: no warning


# --- presence maps ---------------------------------------------------------------------------

import bananagrid as bg  # noqa: E402
from scipy import stats  # noqa: E402

MAP_GRID = bg.Grid.from_bounds(x=(0.0, 16000.0), y=(20000.0, 40000.0), step=40.0)


def test_linear_map_is_the_normal_of_the_fix():
    fix = make(noise=np.array([0.004, -0.01])).with_variant("linear")
    got = bg.rasterise(fix, MAP_GRID).values
    xx, yy = np.meshgrid(MAP_GRID.x, MAP_GRID.y)
    want = stats.multivariate_normal(fix.fix, fix.covariance).pdf(np.dstack((xx, yy)))
    # exp of arguments up to ~700 amplifies rounding to ~1e-13 relative
    np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-300)


def test_exact_map_is_the_likelihood_product():
    """Independent oracle: numpy's arctan2 bearings, wrapped residuals, scipy's normal log-pdf,
    divided by the linearised normaliser 2 pi sqrt(det C)."""
    fix = make(noise=np.array([0.004, -0.01]))
    got = bg.rasterise(fix, MAP_GRID).values
    xx, yy = np.meshgrid(MAP_GRID.x, MAP_GRID.y)
    log_l = np.zeros_like(xx)
    for (sx, sy), b, s in zip(fix.sensors, fix.bearings, fix.sigmas):
        resid = np.angle(np.exp(1j * (np.arctan2(xx - sx, yy - sy) - b)))
        log_l += stats.norm.logpdf(resid, scale=s) + math.log(math.sqrt(2 * math.pi) * s)
    want = np.exp(log_l) / (2 * math.pi * math.sqrt(np.linalg.det(fix.covariance)))
    np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-300)


def test_exact_map_departs_from_the_ellipse_in_proportion_to_sigma():
    """Walsh's linearisation drops second-order terms, so the total-variation distance between
    the exact and the linear map grows like sigma (measured: 3.8e-4, 3.8e-3, 3.9e-2, 8.0e-2 at
    0.01, 0.1, 1 and 2 times sigma = (0.01, 0.02) rad); the check allows 20 % around linear."""
    distances = []
    scales = (0.01, 0.1, 1.0, 2.0)
    for scale in scales:
        fix = make(sigmas=SIGMAS * scale)
        c = fix.covariance
        half = 6 * math.sqrt(max(c[0, 0], c[1, 1]))
        grid = bg.Grid.from_bounds(
            x=(fix.fix[0] - half, fix.fix[0] + half), y=(fix.fix[1] - half, fix.fix[1] + half), dx=half / 100, dy=half / 100
        )
        exact = bg.rasterise(fix, grid).normalise().values
        linear = bg.rasterise(fix.with_variant("linear"), grid).normalise().values
        distances.append(0.5 * np.abs(exact - linear).sum() * grid.cell_area)
    per_sigma = np.array(distances) / np.array(scales)
    assert per_sigma.max() / per_sigma.min() < 1.2, distances
    assert distances[0] < 1e-3


def test_map_variant_is_validated():
    with pytest.raises(BananagridError, match="variant = 'smooth': must be one of exact, linear"):
        BearingFix(STATIONS, bearing_to(STATIONS, CONTACT), SIGMAS, variant="smooth")


# --- containment -------------------------------------------------------------------------------


def test_containment_of_a_fix_matches_its_linear_map():
    """P(|P - fix| <= R) from the principal variances equals the linear map's mass in the disc
    (midpoint rule on 20 m cells inside a 6-sigma frame: error ~1e-4 at the disc's edge)."""
    fix = make().with_variant("linear")
    r50, r95 = fix.radius([0.5, 0.95])
    assert fix.containment(r50) == pytest.approx(0.5, abs=1e-12)
    assert fix.containment(r95, method="series") == pytest.approx(0.95, abs=1e-11)
    c = fix.covariance
    half = 6 * math.sqrt(max(c[0, 0], c[1, 1]))
    grid = bg.Grid.from_bounds(x=(fix.fix[0] - half, fix.fix[0] + half), y=(fix.fix[1] - half, fix.fix[1] + half), step=20.0)
    values = bg.rasterise(fix, grid).values
    xx, yy = np.meshgrid(grid.x, grid.y)
    inside = np.hypot(xx - fix.fix[0], yy - fix.fix[1]) <= r50
    assert values[inside].sum() * grid.cell_area == pytest.approx(0.5, abs=2e-3)


def test_exact_map_of_three_sensors_is_normalised_by_its_misfit():
    """With three inconsistent bearings the likelihood peaks below one (exp(-chi2_min / 2)); the
    map divides by that, so it still integrates to about one (within the 2 % that the nonlinear
    shape moves, as for two sensors)."""
    sensors = np.vstack((STATIONS, [[35000.0, 12000.0]]))
    fix = make(sensors=sensors, sigmas=[0.01, 0.02, 0.01], noise=np.array([0.003, -0.01, 0.004]))
    assert fix.chi2_min > 0.1
    c = fix.covariance
    half = 7 * math.sqrt(max(c[0, 0], c[1, 1]))
    grid = bg.Grid.from_bounds(x=(fix.fix[0] - half, fix.fix[0] + half), y=(fix.fix[1] - half, fix.fix[1] + half), dx=half / 150, dy=half / 150)
    assert bg.rasterise(fix, grid).mass == pytest.approx(1.0, abs=0.02)


# --- sampling ----------------------------------------------------------------------------------

from scipy import stats as _stats  # noqa: E402

#: False-alarm rate of each chi-square test (fixed seeds: deterministic outcome).
ALPHA = 1e-3


def _chi2_against_map(fix, pts):
    """Pearson's chi-square of points binned at 400 m against the grid-normalised exact map
    integrated on 20 m sub-cells, over bins expecting >= 5 (the rest pooled): (chi2, dof, the
    fraction of points inside the frame)."""
    bin_size, sub = 400.0, 20
    grid = bg.Grid.from_bounds(x=(0.0, 16000.0), y=(22000.0, 38000.0), step=bin_size / sub)
    probs = bg.rasterise(fix, grid).normalise().values
    ny, nx = grid.ny // sub, grid.nx // sub
    probs = probs.reshape(ny, sub, nx, sub).sum(axis=(1, 3)) * grid.cell_area
    counts, _, _ = np.histogram2d(pts[:, 1], pts[:, 0], bins=(ny, nx), range=((22000.0, 38000.0), (0.0, 16000.0)))
    expected = probs * counts.sum()
    big = expected >= 5
    obs = np.append(counts[big], counts[~big].sum())
    exp = np.append(expected[big], expected[~big].sum())
    return float(np.sum((obs - exp) ** 2 / exp)), len(obs) - 1, counts.sum() / len(pts)


@pytest.mark.parametrize("three", [False, True], ids=["two-sensors", "three-sensors"])
def test_exact_map_matches_its_samples(three):
    """300,000 draws against the exact map. The midpoint rule's error on 20 m sub-cells is
    ~ (h^2/24) |f''|/f with the fix's minor SD ~300 m: 2e-4, below the >= 4e-3 statistical
    error of the fullest bins."""
    if three:
        sensors = np.vstack((STATIONS, [[35000.0, 12000.0]]))
        fix = make(sensors=sensors, sigmas=[0.01, 0.02, 0.01], noise=np.array([0.004, -0.01, 0.003]))
    else:
        fix = make(noise=np.array([0.004, -0.01]))
    chi2, dof, inside = _chi2_against_map(fix, fix.sample(300_000, np.random.default_rng(20261121)))
    assert inside > 0.99  # the frame holds the fix region
    p_value = _stats.chi2.sf(chi2, df=dof)
    assert p_value > ALPHA, f"chi2 = {chi2:.1f} on {dof} dof, p = {p_value:.2e}"


def test_re_triangulation_alone_would_fail_the_same_test():
    """Power check: the raw re-triangulated fixes (no Jacobian correction) are rejected."""
    fix = make(noise=np.array([0.004, -0.01]))
    eps = np.random.default_rng(5).normal(size=(300_000, 2)) * fix.sigmas
    pts, ok = fix._crossings(0, 1, fix.bearings[0] + eps[:, 0], fix.bearings[1] + eps[:, 1])
    chi2, dof, _ = _chi2_against_map(fix, pts[ok])
    assert _stats.chi2.sf(chi2, df=dof) < ALPHA


def test_sample_validates_its_arguments():
    with pytest.raises(BananagridError, match="n = -2: expected a non-negative integer"):
        make().sample(-2, np.random.default_rng(0))


def test_sample_refuses_bearings_that_disagree():
    """A third bearing 5.4 sigma off the first two's crossing: its likelihood factor keeps about
    5e-7 of the re-triangulated draws, so rejection would run for hours; the sampler stops after
    SAMPLE_PATIENCE proposals with a message instead (the map itself is fine)."""
    fix = BearingFix([[0.0, 0.0], [20000.0, 0.0], [10000.0, -5000.0]], [0.2641, -0.3909, 0.05], [0.01, 0.02, 0.02])
    with pytest.raises(BananagridError, match=r"bearings of sensors \[2\] disagree with the crossing of sensors 0 and 1"):
        fix.sample(100, np.random.default_rng(0))
    assert np.isfinite(fix.pdf([8700.0], [30950.0])).all()


def test_many_geometries_at_once_match_one_at_a_time():
    from bananagrid.models.bearing import two_bearing_variances

    rng = np.random.default_rng(8)
    n = 50
    s2 = np.column_stack((rng.uniform(5000, 40000, n), rng.uniform(-3000, 3000, n)))
    targets = np.column_stack((rng.uniform(-10000, 30000, n), rng.uniform(10000, 60000, n)))
    b1 = bearing_to(np.zeros(2), targets)
    b2 = bearing_to(s2, targets)
    sd1, sd2 = rng.uniform(0.005, 0.05, n), rng.uniform(0.005, 0.05, n)
    fix, v1, v2 = two_bearing_variances(np.zeros(2), s2, b1, b2, sd1, sd2)
    for k in range(n):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            one = BearingFix([[0.0, 0.0], s2[k]], [b1[k], b2[k]], [sd1[k], sd2[k]])
        np.testing.assert_allclose(fix[k], one.fix, rtol=1e-10)
        np.testing.assert_allclose((v1[k], v2[k]), one.principal_variances, rtol=1e-9)
    # a geometry whose lines cross behind a station has no fix
    _, bad1, _ = two_bearing_variances([0.0, 0.0], [20000.0, 0.0], math.pi + 0.3, -0.5, 0.01, 0.01)
    assert np.isnan(bad1)


def test_inputs_are_copied_not_frozen():
    bearings = bearing_to(STATIONS, CONTACT)
    fix = BearingFix(STATIONS, bearings, SIGMAS)
    bearings[0] = 0.0  # the caller's array stays writable and the fix does not change
    assert fix.bearings[0] != 0.0 and not fix.bearings.flags.writeable


@pytest.mark.parametrize("sigmas", [(1e-10, 1.0), (1.0, 1e-10), (0.01, 0.02)])
def test_the_covariance_holds_when_the_stations_accuracies_differ_by_ten_orders(sigmas):
    """With two stations the fix is the crossing, so C = G^-1 diag(sigma^2) G^-T (G the bearing
    gradients, well conditioned whatever the sigmas): an independent route to the covariance.
    Inverting G^T W G instead lost every digit at a sigma ratio of 1e10 (its determinant cancels)."""
    sensors = np.array([[0.0, 0.0], [20_000.0, 0.0]])
    target = np.array([6_000.0, 15_000.0])
    fix = bg.BearingFix(sensors=sensors, bearings=bg.bearing_to(sensors, target), sigmas=list(sigmas))
    d = target - sensors
    g = np.column_stack((d[:, 1], -d[:, 0])) / np.einsum("ij,ij->i", d, d)[:, None]
    g_inv = np.linalg.inv(g)
    expected = g_inv @ np.diag(np.square(sigmas)) @ g_inv.T
    np.testing.assert_allclose(fix.covariance, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())
    assert np.isfinite(fix.pdf(target[0], target[1])).all()
