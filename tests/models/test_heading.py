"""Initial-heading noise (Section 7 of the polar-banana paper) and conditional radial laws.

Oracles, none sharing code with the kernels:
- P_mu, P_sigma and their derivatives: Chebyshev interpolants of ``oracles.polar_mu_sigma``
  (NumPy, eqs. (7), (8), (11)) differentiated by numpy.polynomial.
- The heading-convolved CAT density: ``oracles.cat_density`` (independent root finder) summed
  over a trapezoid rule in theta_0 with normal weights, a direct float64 sum (no FFT, no
  lattice, no interpolation).
- Monte Carlo from ``CAT.sample`` (which draws theta_0 too).
"""

import math

import numpy as np
import pytest
from numpy.polynomial import chebyshev
from scipy import stats

import bananagrid as bg
import oracles
from bananagrid.models import _cat_heading as heading
from bananagrid.models.bearing import BearingFix
from bananagrid.analysis.radial import radial_density, radial_moments

from cases import FIG1, FIG1_BOUNDS, FOLDING

ORACLE_ARGS = dict(v0=FIG1["v0"], t=FIG1["t"], sigma_a=FIG1["sigma_a"], sigma_w=FIG1["sigma_omega"])
SIGMA_0 = {"0": 0.0, "pi/30": math.pi / 30, "pi/15": math.pi / 15}


# ------------------------------------------------------------------ P_mu, P_sigma derivatives
@pytest.mark.parametrize("variant", ["improved", "rough"])
@pytest.mark.parametrize("phi", [0.0, 0.3, 1.2, 1.5, 1.8, 2.7, -0.9])
def test_law_derivatives_match_chebyshev(variant, phi):
    model = bg.PolarBanana(**FIG1, variant=variant)
    got = model.law_derivatives(np.array([phi]))[0]
    window = [phi - 0.25, phi + 0.25]
    mu = chebyshev.Chebyshev.interpolate(
        lambda p: oracles.polar_mu_sigma(p, variant=variant, **ORACLE_ARGS)[0], 40, domain=window
    )
    sd = chebyshev.Chebyshev.interpolate(
        lambda p: oracles.polar_mu_sigma(p, variant=variant, **ORACLE_ARGS)[1], 40, domain=window
    )
    want = [mu.deriv(k)(phi) if k else mu(phi) for k in range(5)] + [sd.deriv(k)(phi) if k else sd(phi) for k in range(3)]
    # Chebyshev differentiation amplifies rounding by about degree^(2k): measured errors of the
    # reference are below 2e-6 of v0 t for the fourth derivative, far less for lower ones.
    scale_mu = FIG1["v0"] * FIG1["t"]
    scale_sd = 0.5 * FIG1["sigma_a"] * FIG1["t"] ** 2
    for k in range(5):
        assert abs(got[k] - want[k]) <= 1e-5 * scale_mu, (k, got[k], want[k])
    for k in range(3):
        assert abs(got[5 + k] - want[5 + k]) <= 1e-7 * scale_sd, (k, got[5 + k], want[5 + k])


def test_sinc_derivatives_continuous_at_series_switch():
    """The kernel sums sinc's series below |phi| = 1.5 and recurs upward above it: the rough
    law, P_mu = v0 t sinc, shows both forms agree across the switch."""
    model = bg.PolarBanana(**FIG1, variant="rough")
    gap = 1e-12
    below = model.law_derivatives(np.array([1.5 - gap, -(1.5 - gap)]))[:, :5]
    above = model.law_derivatives(np.array([1.5 + gap, -(1.5 + gap)]))[:, :5]
    # derivative k moves by |P_mu^(k+1)| * 2e-12 < 1e-8 m across the gap; both forms are good to
    # ~1e-15 relative of v0 t = 2800 m there, so 1e-9 of v0 t is a real check
    assert np.max(np.abs(below - above)) < 1e-9 * FIG1["v0"] * FIG1["t"]


# -------------------------------------------------------- PolarBanana with heading noise
def heading_moments_oracle(theta, sigma_0, order, variant="improved"):
    """(15), (16) and the fourth-order terms, from Chebyshev derivatives of the NumPy laws."""
    sigma_phi = 0.5 * FIG1["sigma_omega"] * FIG1["t"]
    s_theta2 = sigma_0**2 + sigma_phi**2
    tb = theta * sigma_phi**2 / s_theta2
    sb2 = (sigma_0 * sigma_phi) ** 2 / s_theta2
    window = [tb - 0.25, tb + 0.25]
    mu = chebyshev.Chebyshev.interpolate(lambda p: oracles.polar_mu_sigma(p, variant=variant, **ORACLE_ARGS)[0], 40, domain=window)
    sd = chebyshev.Chebyshev.interpolate(lambda p: oracles.polar_mu_sigma(p, variant=variant, **ORACLE_ARGS)[1], 40, domain=window)
    m = [mu(tb)] + [mu.deriv(k)(tb) for k in range(1, 5)]
    s = [sd(tb)] + [sd.deriv(k)(tb) for k in range(1, 3)]
    mean = m[0] + 0.5 * m[2] * sb2
    var = s[0] ** 2 + m[1] ** 2 * sb2
    if order == 4:
        mean += m[4] * sb2**2 / 8
        var += (s[1] ** 2 + s[0] * s[2]) * sb2 + (0.5 * m[2] ** 2 + m[1] * m[3]) * sb2**2
    return mean, math.sqrt(var), math.sqrt(s_theta2)


@pytest.mark.parametrize("order", [2, 4])
@pytest.mark.parametrize("sigma_0", [math.pi / 30, math.pi / 15])
def test_polar_heading_density_matches_formula(order, sigma_0):
    model = bg.PolarBanana(**FIG1, sigma_heading=sigma_0, heading_order=order)
    rng = np.random.default_rng(7)
    pts = model.sample(200, rng)
    got = model.pdf(pts[:, 0], pts[:, 1])
    want = []
    for x, y in pts:
        theta, r = math.atan2(x, y), math.hypot(x, y)
        mean, sd, s_theta = heading_moments_oracle(theta, sigma_0, order)
        want.append(stats.norm.pdf(theta, 0.0, s_theta) * stats.norm.pdf(r, mean, sd) / r)
    # the reference derivatives carry ~1e-9 relative error into the mean and SD (see above);
    # the density's relative error is |r - mean| / sd^2 times that: 1e-7 covers 8 SDs
    assert np.max(np.abs(got / np.array(want) - 1.0)) < 1e-7


def test_polar_heading_zero_is_the_foundation():
    """sigma_0 = 0 is the foundation's kernel path bit for bit; sigma_0 -> 0 converges to it."""
    grid = bg.Grid.from_bounds(**FIG1_BOUNDS, step=40.0)
    plain = bg.rasterise(bg.PolarBanana(**FIG1), grid).values
    assert np.array_equal(bg.rasterise(bg.PolarBanana(**FIG1, sigma_heading=0.0, heading_order=4), grid).values, plain)
    tiny = bg.rasterise(bg.PolarBanana(**FIG1, sigma_heading=1e-9), grid).values
    inside = plain >= 1e-10
    # sigma_bar = 1e-9 rad moves theta_bar by 1e-18 relative and the SD by (P_mu' sigma_bar)^2
    # / (2 P_sigma^2) < 1e-15: what is left is rounding
    assert np.max(np.abs(tiny[inside] / plain[inside] - 1.0)) < 1e-12


def test_polar_heading_sampling_matches_density():
    """PolarBanana.sample with heading noise draws from the kernel's own density (chi-square)."""
    model = bg.PolarBanana(**FIG1, sigma_heading=math.pi / 15, heading_order=4)
    assert chi_square_p_value(model, FIG1_BOUNDS) > 1e-3


# ---------------------------------------------------------------- CAT with heading noise
def cat_heading_oracle(x, y, sigma_0, params=FIG1, n=801):
    """Trapezoid rule over theta_0 in [-8 sigma_0, 8 sigma_0] of p_0(R(-theta_0) P) g(theta_0).

    The integrand is smooth and negligible at both ends (the normal mass beyond 8 sigma is
    1.2e-15), so the trapezoid rule converges faster than any power of the step; n = 801 puts
    >= 16 nodes across the narrowest angular feature of the Figure 1 banana (0.05 rad)."""
    theta0 = np.linspace(-8 * sigma_0, 8 * sigma_0, n)
    weights = stats.norm.pdf(theta0, 0.0, sigma_0) * (theta0[1] - theta0[0])
    weights[[0, -1]] *= 0.5
    c, s = np.cos(theta0), np.sin(theta0)
    # the point seen in the frame of a trajectory turned by theta_0: rotate it by -theta_0
    xl = np.outer(x, c) - np.outer(y, s)
    yl = np.outer(x, s) + np.outer(y, c)
    p0 = oracles.cat_density(
        xl, yl, v0=params["v0"], t=params["t"], sigma_a=params["sigma_a"], sigma_w=params["sigma_omega"]
    )
    return p0 @ weights


@pytest.mark.parametrize("sigma_0", [math.pi / 30, math.pi / 15])
def test_cat_heading_matches_oracle(sigma_0):
    pose = bg.Pose(origin=(500.0, -200.0), heading=math.radians(-35.0))
    model = bg.CAT(**FIG1, sigma_heading=sigma_0, pose=pose)
    # points where the mass is, and in the tails: samples of a twice-as-wide banana
    wide = bg.CAT(**dict(FIG1, sigma_a=2 * FIG1["sigma_a"]), sigma_heading=2 * sigma_0, pose=pose)
    pts = wide.sample(120, np.random.default_rng(3))
    got = model.pdf(pts[:, 0], pts[:, 1])
    local = np.linalg.solve(
        np.array([[math.cos(pose.heading), math.sin(pose.heading)], [-math.sin(pose.heading), math.cos(pose.heading)]]),
        (pts - np.array(pose.origin)).T,
    )
    want = cat_heading_oracle(local[0], local[1], sigma_0)
    inside = want >= 1e-10  # the paper's outermost contour
    assert inside.sum() >= 80
    rel = np.abs(got[inside] / want[inside] - 1.0)
    # the table's checked interpolation error target is 1e-6 (heading.TARGET_ERROR); the oracle's
    # root finder is good to 1e-12 (test_cat_accuracy); 1e-6 is the claim we make
    assert rel.max() <= heading.TARGET_ERROR, rel.max()
    # beyond the contour the two agree in absolute terms (no stray mass in the tails)
    assert np.max(np.abs(got - want)[~inside], initial=0.0) <= heading.TARGET_ERROR * 1e-10


def test_cat_heading_grid_matches_points_and_estimate():
    """The raster (a table over the grid's ranges) and pdf (a table over the points' ranges)
    agree within the error estimates they report."""
    model = bg.CAT(**FIG1, sigma_heading=math.pi / 30)
    grid = bg.Grid.from_bounds(**FIG1_BOUNDS, step=40.0)
    raster = bg.rasterise(model, grid)
    assert 0.0 < raster.provenance["heading_error_estimate"] <= heading.TARGET_ERROR
    xx, yy = np.meshgrid(grid.x, grid.y)
    inside = raster.values >= 1e-10
    points = model.pdf(xx[inside], yy[inside])
    assert np.max(np.abs(points / raster.values[inside] - 1.0)) <= 2 * heading.TARGET_ERROR
    # the whole banana is on the grid: the captured mass is one to the midpoint rule's error
    # (h^2 / 24 |p''| / p ~ 40^2 / 24 / 83^2 ~ 1e-2 locally, cancelling over the bump)
    assert abs(raster.mass - 1.0) < 1e-3


def test_cat_heading_to_zero_recovers_the_foundation():
    grid = bg.Grid.from_bounds(**FIG1_BOUNDS, step=40.0)
    plain = bg.rasterise(bg.CAT(**FIG1), grid).values
    assert np.array_equal(bg.rasterise(bg.CAT(**FIG1, sigma_heading=0.0), grid).values, plain)
    tiny = bg.rasterise(bg.CAT(**FIG1, sigma_heading=1e-7), grid)
    inside = plain >= 1e-10
    # a 1e-7 rad blur changes p by (sigma_0 / angular width)^2 / 2 ~ 1e-12; what is left is the
    # lattice's interpolation error, which its own estimate bounds
    bound = 2 * max(tiny.provenance["heading_error_estimate"], 1e-9)
    assert np.max(np.abs(tiny.values[inside] / plain[inside] - 1.0)) <= bound


def test_cat_heading_sampling_matches_density():
    model = bg.CAT(**FIG1, sigma_heading=math.pi / 15, pose=bg.Pose(origin=(100.0, 0.0), heading=0.3))
    assert chi_square_p_value(model, dict(x=(-2500.0, 3500.0), y=(-1200.0, 3600.0))) > 1e-3


def test_folding_heading_warns_with_its_estimate():
    """Where the banana folds over itself the lattice cannot meet the target: it says so."""
    model = bg.CAT(**FOLDING, sigma_heading=math.pi / 30)
    # a box about (646 m, -151 m): where the checks found the fold's largest error, 1e-3
    grid = bg.Grid.from_bounds(x=(500.0, 800.0), y=(-300.0, 0.0), step=50.0)
    with pytest.warns(UserWarning, match="interpolation error estimate is"):
        raster = bg.rasterise(model, grid)
    assert raster.provenance["heading_error_estimate"] > heading.TARGET_ERROR


def chi_square_p_value(model, bounds, n=200_000, bin_size=200.0, sub=20):
    """Pearson's test of binned samples against bin probabilities from the kernel (midpoint rule
    on sub-cells of 10 m: relative error ~ (10 m)^2 / 24 / (83 m)^2 = 6e-4, below the 1/sqrt(N)
    >= 2e-3 noise of the fullest bins)."""
    fine = bg.Grid.from_bounds(**bounds, step=bin_size / sub)
    values = bg.rasterise(model, fine).values
    ny, nx = values.shape[0] // sub, values.shape[1] // sub
    probs = values[: ny * sub, : nx * sub].reshape(ny, sub, nx, sub).sum(axis=(1, 3)) * fine.cell_area
    pts = model.sample(n, np.random.default_rng(20261121))
    x0, y0 = fine.origin
    counts, _, _ = np.histogram2d(pts[:, 1], pts[:, 0], bins=(ny, nx), range=((y0, y0 + ny * bin_size), (x0, x0 + nx * bin_size)))
    expected = probs * n
    big = expected >= 5
    obs = np.append(counts[big], n - counts[big].sum())
    exp = np.append(expected[big], n - expected[big].sum())
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    return stats.chi2.sf(chi2, df=len(obs) - 1)


# ------------------------------------------------------ the paper's Figures 2 and 8
@pytest.fixture(scope="module")
def figure8():
    """Exact (numerical) E[r | theta], SD[r | theta] at theta = pi/4 for each sigma_0, and the
    closed forms (15)-(16) (order 2) and with the fourth-order terms (order 4)."""
    theta = math.pi / 4
    rows = {}
    for name, s0 in SIGMA_0.items():
        exact = radial_moments(bg.CAT(**FIG1, sigma_heading=s0), theta)
        polar = bg.PolarBanana(**FIG1, sigma_heading=s0)
        closed = {order: polar.conditional_moments(np.array([theta]), order=order) for order in (2, 4)}
        rows[name] = (float(exact.mean), float(exact.sd), {k: (float(m[0]), float(s[0])) for k, (m, s) in closed.items()})
    return rows


@pytest.mark.parametrize("name", SIGMA_0)
def test_figure8_moments_within_a_metre(figure8, name):
    """Section 7: (15) and (16) deviate from the numerically computed moments 'well below 1 m'
    in all three cases. Measured: mean -0.16, -0.10, -0.11 m; SD -0.07, +0.01, -0.69 m."""
    mean, sd, closed = figure8[name]
    m2, s2 = closed[2]
    assert abs(m2 - mean) < 1.0 and abs(s2 - sd) < 1.0


def test_figure8_fourth_order_terms(figure8):
    """Section 7: at sigma_0 = pi/15 the SD error 'about 70 cm' falls to 'only 5 cm' with the
    fourth-order terms. Measured: 0.69 m and 0.044 m."""
    _, sd, closed = figure8["pi/15"]
    assert 0.5 < abs(closed[2][1] - sd) < 0.9
    assert abs(closed[4][1] - sd) < 0.08
    # and in the middle case the terms are 'insignificant' (they move the SD by under 5 mm)
    _, sd_mid, closed_mid = figure8["pi/30"]
    assert abs(closed_mid[4][1] - closed_mid[2][1]) < 5e-3


def test_figure2_normality():
    """Section 4.1: at phi = 0.4 pi, r | phi is close to the normal law with its own mean and SD
    between 1800 and 2400 m; the paper says within a quarter of a percent. Measured: 0.12% up to
    2350 m, 0.25% at 2388 m and 0.29% at 2400 m (3.5 SD above the mean): the claim holds to
    2385 m, not quite to 2400 m."""
    r = np.linspace(1800.0, 2400.0, 121)
    law = radial_density(bg.CAT(**FIG1), 0.4 * math.pi, r)
    dev = np.abs(law.density / law.normal - 1.0)
    assert dev[r <= 2385.0].max() < 0.0025
    assert dev.max() < 0.003


def test_radial_moments_of_polar_banana_are_its_closed_forms():
    """Numerical moments along rays of the polar density itself equal P_mu and P_sigma, up to the
    truncation of r > 0 (8 SDs away here) and the trapezoid rule's error."""
    model = bg.PolarBanana(**FIG1)
    angles = np.array([-0.6, 0.0, 0.3, 0.9])
    got = radial_moments(model, angles)
    mean, sd = model.conditional_moments(angles)
    assert np.allclose(got.mean, mean, rtol=1e-10)
    assert np.allclose(got.sd, sd, rtol=1e-8)
    # the ray mass is the bearing's density g(theta; 0, sigma_phi)
    assert np.allclose(got.mass, stats.norm.pdf(angles, 0.0, model.sigma_phi), rtol=1e-10)


def test_radial_moments_need_a_pose_for_a_bearing_fix():
    fix = BearingFix(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909], sigmas=[0.01, 0.02])
    with pytest.raises(bg.BananagridError, match="pose: BearingFix has no pose"):
        radial_moments(fix, 0.0)
    got = radial_moments(fix, [0.2641], pose=bg.Pose(origin=(0.0, 0.0)))
    assert 20000.0 < float(got.mean[0]) < 40000.0


def test_radial_bad_input():
    model = bg.CAT(**FIG1)
    with pytest.raises(bg.BananagridError, match="angles = .*: expected a finite"):
        radial_moments(model, [0.0, math.nan])
    with pytest.raises(bg.BananagridError, match="r_max = -1.0: must be finite and > 0"):
        radial_moments(model, 0.0, r_max=-1.0)
    fix = BearingFix(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909], sigmas=[0.01, 0.02])
    with pytest.raises(bg.BananagridError, match="no density along this ray"):
        radial_moments(fix, math.pi, pose=bg.Pose(origin=(0.0, 0.0)), r_max=1000.0)


def test_radial_moments_of_an_isotropic_butterly_are_rice():
    """About the start of an isotropic Butterly with one speed, r | theta is Rice(V t / sigma,
    scale sigma) for every theta (Appendix B): an independent check of the ray quadrature."""
    sigma, travel = 200.0, 1000.0
    model = bg.Butterly(mean=(500.0, -300.0), cov=[[sigma**2, 0.0], [0.0, sigma**2]], speeds=[5.0], t=travel / 5.0)
    got = radial_moments(model, [0.0, 1.0, -2.5], pose=bg.Pose(origin=(500.0, -300.0)))
    law = stats.rice(travel / sigma, scale=sigma)
    # the kernel is good to 1e-9 relative and the trapezoid rule's error is far below that
    assert np.allclose(got.mean, law.mean(), rtol=1e-8) and np.allclose(got.sd, law.std(), rtol=1e-7)
