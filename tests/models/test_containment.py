"""Containment probability of a two-bearing fix (Walsh 1968, "Evaluation of Probability").

P(R) = P(v1 t1^2 + v2 t2^2 <= R^2), t1, t2 independent standard normal.  Two methods in
bananagrid.containment (Robbins-Pitman series with Walsh's bounds, ERRATA-corrected; periodic
quadrature), checked against each other and against oracles written here: the ERRATA's
closed-form weights, scipy.stats.chi2 / nbinom, the Rayleigh law, scipy dblquad of the
bivariate normal density over the disc, extended-precision quadrature, mpmath reference
values, and Monte Carlo of the linear model.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy import integrate, special, stats

import bananagrid as bg
from bananagrid.models import containment as cm
from bananagrid.models.containment import (
    EXACT_RTOL,
    containment,
    containment_exact,
    containment_radius,
    containment_series,
    exact_nodes,
    robbins_pitman_weights,
    series_bounds,
)

EPS = np.finfo(float).eps

# The case table of the brief: V in {1, 1.5, 4, 25, 400}, x = R^2/v from 1e-3 to 50.  The
# minor variance is 1.7 (not 1) so that the scaling R^2/v is exercised; every other case puts
# the major axis first, so that the order of v1, v2 is exercised too.
V_TABLE = [1.0, 1.5, 4.0, 25.0, 400.0]
X_TABLE = [1e-3, 1e-2, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0]
VMIN = 1.7


def table():
    VV, XX = np.meshgrid(V_TABLE, X_TABLE, indexing="ij")
    V, x = VV.ravel(), XX.ravel()
    R = np.sqrt(x * VMIN)
    swap = np.arange(V.size) % 2 == 1
    v1 = np.where(swap, VMIN * V, VMIN)
    v2 = np.where(swap, VMIN, VMIN * V)
    return R, v1, v2, x, V


# mpmath 1.4.1 at 35 digits, tanh-sinh quadrature of the theta-integral
# P = x/(2 sqrt V) (1/pi) int_0^pi (1 - e^-w)/w dphi, w = x/(2V) + x(1 - 1/V)(1 + cos phi)/4,
# split at pi (1 - 2^-k), k < 40; cross-checked to all 20 digits shown on five of them
# ((5, 4), (1000, 400), (2e4, 1e4), (4e6, 1e6), (1e-3, 1e6)) with the independent form
# P = int_{-sqrt x}^{sqrt x} phi(t) erf(sqrt((x - t^2)/(2V))) dt.  Columns: x = R^2/v, V, P.
MPMATH_REFERENCE = [
    (0.001, 1e6, "4.9993750774919148738e-7"),
    (1.0, 1e4, "0.0044455912128768214837"),
    (5.0, 4.0, "0.6629749362758400532"),
    (20.0, 25.0, "0.61601009806820927028"),
    (30.0, 1.5, "0.99998574413677372883"),
    (50.0, 400.0, "0.27362925599475677333"),
    (1000.0, 25.0, "0.99999999974067098533"),
    (1000.0, 400.0, "0.88597250358768856604"),
    (1500.0, 400.0, "0.94711331770250789491"),
    (5000.0, 1e4, "0.52045592879312329835"),
    (2e4, 1e4, "0.84269041409461111387"),
    (1e5, 1e6, "0.24816916590530172528"),
    (4e6, 1e6, "0.95449970910813302071"),
]


# --------------------------------------------------------------------------------------------
# Robbins-Pitman weights
# --------------------------------------------------------------------------------------------


def test_weights_match_walsh_coefficients_and_errata_closed_form():
    V = np.array([1.0, 1.5, 4.0, 25.0, 400.0, 1e6])
    H = robbins_pitman_weights(V, 4)
    r = 1.0 - 1.0 / V
    # Walsh's printed expansion of [1 - (1 - 1/V) z]^(-1/2): 1, 1/2, 3/8, 5/16, 35/128.
    walsh = np.array([1.0, 1 / 2, 3 / 8, 5 / 16, 35 / 128])
    expected = walsh[None, :] * r[:, None] ** np.arange(5) / np.sqrt(V)[:, None]
    # 4 recursion steps of a few roundings each: 16 eps relative.
    np.testing.assert_allclose(H, expected, rtol=16 * EPS, atol=0)
    # ERRATA closed form binom(2w, w) / 4^w (1 - 1/V)^w V^(-1/2) for w up to 60.
    W = np.arange(61)
    H = robbins_pitman_weights(V, 60)
    closed = special.comb(2 * W, W) / 4.0**W * r[:, None] ** W / np.sqrt(V)[:, None]
    # 60 recursion steps: the relative error grows by a few eps a step.
    np.testing.assert_allclose(H, closed, rtol=300 * EPS, atol=0)
    # They are the negative-binomial(1/2, 1/V) probabilities (scipy's Boost pmf).
    np.testing.assert_allclose(H, stats.nbinom.pmf(W, 0.5, 1.0 / V[:, None]), rtol=300 * EPS, atol=1e-300)


def test_weights_sum_to_one():
    V = np.array([1.0, 1.5, 4.0, 25.0])
    H = robbins_pitman_weights(V, 3000)
    # The tail beyond 3000 is below (1 - 1/25)^3000 < 1e-50; the sum of 3001 positive terms
    # has a rounding error well below 1e-13.
    np.testing.assert_allclose(H.sum(axis=-1), 1.0, rtol=0, atol=1e-13)
    assert robbins_pitman_weights(1.0, 3).tolist() == [1.0, 0.0, 0.0, 0.0]
    assert robbins_pitman_weights([[4.0]], 2).shape == (1, 1, 3)


# --------------------------------------------------------------------------------------------
# Series vs exact, bounds
# --------------------------------------------------------------------------------------------


def test_series_matches_exact_on_case_table():
    R, v1, v2, x, V = table()
    exact = containment_exact(R, v1, v2)
    P, lower, upper, W = containment_series(R, v1, v2, tol=1e-12, return_bounds=True)
    # The brief's requirement.
    np.testing.assert_allclose(P, exact, rtol=0, atol=1e-10)
    # Sharper: the midpoint of bounds 1e-12 apart is within 5e-13 of P; the exact value is
    # good to ~1e-15 and the running sums round at ~W eps (W < 100 here).
    assert np.max(np.abs(P - exact)) <= 0.5e-12 + 1e-14
    assert np.all(upper - lower <= 1e-12)
    assert np.all(W[V == 1.0] == 0)  # H_0 = 1: the first term is the whole answer
    assert np.all((W >= 0) & (W < 100))


def test_series_tolerance_is_honoured():
    R, v1, v2, _, _ = table()
    exact = containment_exact(R, v1, v2)
    for tol in (1e-4, 1e-8, 1e-14):
        P, lower, upper, W = containment_series(R, v1, v2, tol=tol, return_bounds=True)
        # |midpoint - P| <= tol/2, plus rounding of the sums (< 1e-14 for W < 120 terms).
        assert np.max(np.abs(P - exact)) <= tol / 2 + 1e-14, tol
        assert np.all(upper - lower <= tol)


@pytest.mark.parametrize("W", range(31))
def test_bounds_bracket_exact_for_every_W(W):
    R, v1, v2, x, V = table()
    exact = containment_exact(R, v1, v2)
    lower, upper = series_bounds(R, v1, v2, W)
    # Walsh's inequality (ERRATA: C_{2w+2} on both sides) holds exactly; the computed bounds
    # carry the rounding of sums of at most 32 terms plus the exact value's 1e-15: 1e-14 slack.
    slack = 1e-14
    assert np.all(lower <= exact + slack), np.max(lower - exact)
    assert np.all(upper >= exact - slack), np.max(exact - upper)
    # Independent evaluation of the same bounds: the ERRATA's H_w in closed form and
    # scipy.stats.chi2.cdf for C_k (float64 rounding of <= 33 terms: 1e-14).
    w = np.arange(W + 1)
    H = special.comb(2 * w, w) / 4.0**w * (1.0 - 1.0 / V[:, None]) ** w / np.sqrt(V)[:, None]
    C = stats.chi2.cdf(x[:, None], 2 * w + 2)
    lo = np.sum(H * C, axis=1)
    up = lo + (1.0 - H.sum(axis=1)) * stats.chi2.cdf(x, 2 * W + 4)
    np.testing.assert_allclose(lower, lo, rtol=0, atol=1e-14)
    np.testing.assert_allclose(upper, up, rtol=0, atol=1e-14)


def test_bounds_tighten_with_W():
    R, v1, v2, _, _ = table()
    prev_lo, prev_up = series_bounds(R, v1, v2, 0)
    for W in range(1, 31):
        lo, up = series_bounds(R, v1, v2, W)
        # L_{W+1} - L_W = H C >= 0 and U_{W+1} - U_W = T_{W+1} (C_{2W+6} - C_{2W+4}) <= 0;
        # rounding 1e-15.
        assert np.all(lo >= prev_lo - 1e-15)
        assert np.all(up <= prev_up + 1e-15)
        prev_lo, prev_up = lo, up


def test_large_V_series_converges_slowly_and_caps():
    # V = 1e6: the weights decay like (1 - 1e-6)^w, so the series must run past the Poisson
    # bulk x/2.  x = 1e5 needs about 5e4 terms (from the Poisson lower tail on, where the
    # recursion starts), and still agrees with the quadrature.
    R, v1, v2 = math.sqrt(1e5), 1.0, 1e6
    P, lower, upper, W = containment_series(R, v1, v2, return_bounds=True)
    assert 5e4 < W < 5.3e4
    ref = float(MPMATH_REFERENCE[11][2])
    assert abs(P - ref) <= 0.5e-12 + 1e-14
    assert abs(containment_exact(R, v1, v2) - ref) <= 2 * EXACT_RTOL * ref + 4 * EPS * ref
    # x = 4e6 (R = 2 sigma_major) would need ~2e6 terms: a clear error, naming what to do.
    with pytest.raises(bg.BananagridError, match=r"max_terms = 100000: the Robbins-Pitman series did not reach tol = 1e-12 for 1 of 2 geometries .*V = 1e\+06.*method='exact'"):
        containment_series([R, 2000.0], v1, v2)
    with pytest.raises(bg.BananagridError, match="max_terms = 10: .* did not reach"):
        containment_series(1.0, 1.0, 1e6, max_terms=10)


def test_isotropic_and_zero_radius():
    v = 2.5
    R = np.array([0.0, 1e-5, 0.3, 1.0, 2.0, 5.0, 30.0])
    rayleigh = -np.expm1(-(R**2) / (2 * v))  # closed form (Rayleigh CDF), V = 1
    # One node is exact for V = 1: a few roundings of the expression.
    np.testing.assert_allclose(containment_exact(R, v, v), rayleigh, rtol=4 * EPS, atol=0)
    np.testing.assert_allclose(containment_series(R, v, v), rayleigh, rtol=4 * EPS, atol=0)
    np.testing.assert_allclose(containment_exact(R, v, v), stats.chi2.cdf(R**2 / v, 2), rtol=1e-14, atol=0)
    for method in ("exact", "series"):
        assert containment(0.0, 1.0, 7.0, method=method) == 0.0
    lo, up = series_bounds(0.0, 1.0, 7.0, 3)
    assert lo == 0.0 and up == 0.0


# --------------------------------------------------------------------------------------------
# Exact quadrature vs independent oracles
# --------------------------------------------------------------------------------------------


def disc_probability_dblquad(R, cov):
    """Integral of the N(0, cov) density over the disc of radius R, by scipy dblquad in
    polar coordinates (outer theta, inner r)."""
    inv = np.linalg.inv(cov)
    norm = 1.0 / (2 * math.pi * math.sqrt(np.linalg.det(cov)))

    def f(r, th):
        c, s = math.cos(th), math.sin(th)
        return norm * r * math.exp(-0.5 * r * r * (inv[0, 0] * c * c + 2 * inv[0, 1] * c * s + inv[1, 1] * s * s))

    return integrate.dblquad(f, 0.0, 2 * math.pi, 0.0, R, epsabs=1e-14, epsrel=1e-13)[0]


@pytest.mark.parametrize("V", [1.5, 4.0, 25.0])
@pytest.mark.parametrize("x", [0.1, 1.0, 5.0, 20.0])
def test_exact_matches_dblquad_of_rotated_density(V, x):
    # A full covariance with eigenvalues v1, v2 (rotated by 0.7 rad): the containment
    # probability depends on the eigenvalues only (Walsh, principal components; ERRATA).
    v1, v2 = 0.8, 0.8 * V
    c, s = math.cos(0.7), math.sin(0.7)
    Q = np.array([[c, -s], [s, c]])
    cov = Q @ np.diag([v1, v2]) @ Q.T
    R = math.sqrt(x * v1)
    oracle = disc_probability_dblquad(R, cov)
    # dblquad was asked for 1e-14 absolute; its estimate is an estimate, so allow 1e-12.
    assert abs(containment_exact(R, v1, v2) - oracle) <= 1e-12


@pytest.mark.parametrize("x, V, ref", MPMATH_REFERENCE)
def test_exact_and_series_match_mpmath(x, V, ref):
    ref = float(ref)
    v = 0.37
    R = math.sqrt(x * v)
    P = containment_exact(R, v, V * v)
    # Truncation <= EXACT_RTOL P by the node rule, rounding a few eps (observed <= 4e-16):
    # 1e-15 + 8 eps relative.
    assert abs(P - ref) <= (EXACT_RTOL + 8 * EPS) * ref
    if x <= 1e5:  # beyond, the series needs more than max_terms (see the large-V test)
        Ps = containment_series(R, v, V * v)
        assert abs(Ps - ref) <= 0.5e-12 + 1e-14


def test_exact_small_and_saturated():
    # Small R: P = x/(2 sqrt V) (1 - x (1 + 1/V)/8 + O(x^2)) (expansion of the mean of
    # (1 - e^-w)/w); relative error of the two-term form x^2/24 < 1e-21 at x = 1e-10.
    for V in (1.0, 3.0, 1e8):
        x = 1e-10
        expected = x / (2 * math.sqrt(V)) * (1 - x * (1 + 1 / V) / 8)
        assert containment_exact(math.sqrt(x), 1.0, V) == pytest.approx(expected, rel=4 * EPS, abs=0)
        # and just above the switch to quadrature, x = 3e-8 (relative error of the expansion
        # x^2 (...)/6 < 1e-15)
        x = 3e-8
        expected = x / (2 * math.sqrt(V)) * (1 - x * (1 + 1 / V) / 8)
        assert containment_exact(math.sqrt(x), 1.0, V) == pytest.approx(expected, rel=1e-15, abs=0)
    # Large R: 1 - P <= exp(-R^2/(2 max(v1, v2))) (isotropic with the larger variance).
    assert containment_exact(100.0, 1.0, 10.0) == 1.0
    assert containment_exact(1e150, 1e-100, 1e100) == 1.0


def longdouble_midpoint(x, V, N):
    """The module's midpoint rule with N nodes on [0, pi], in extended precision (an
    independent implementation: 1 + cos phi written as 2 sin^2 of the half-angle from pi)."""
    x = np.longdouble(x)
    V = np.longdouble(V)
    j = np.arange(N, dtype=np.longdouble)
    pi = np.arccos(np.longdouble(-1))
    c = 2 * np.sin((j + np.longdouble(0.5)) * (pi / (2 * N))) ** 2
    w = x / (2 * V) + x * (1 - 1 / V) / 4 * c
    return x / (2 * np.sqrt(V)) * np.mean(-np.expm1(-w) / w)


@pytest.mark.skipif(np.finfo(np.longdouble).eps > 1e-18, reason="needs an extended-precision long double")
def test_node_rule_doubling():
    # The node count is N = exact_nodes(x, V); with 2N nodes the truncation error is squared,
    # so |P_N - P_2N| is the error of P_N.  Both P_2N and P_N are computed here in extended
    # precision; the module's float64 value must agree with P_2N to truncation (<= 1e-15 P by
    # the rule) plus float64 rounding (a few eps): 1e-15 + 8 eps relative.  Cases: the table,
    # the mpmath cases, and random (V, x) with V up to 1e8.
    rng = np.random.default_rng(7)
    V = np.concatenate([np.repeat(V_TABLE, len(X_TABLE)), [c[1] for c in MPMATH_REFERENCE], 10 ** rng.uniform(0, 8, 60)])
    x = np.concatenate([np.tile(X_TABLE, len(V_TABLE)), [c[0] for c in MPMATH_REFERENCE], np.zeros(60)])
    x[-60:] = 10 ** rng.uniform(-6, np.log10(40 * V[-60:]))
    worst_trunc = worst_module = 0.0
    for xi, Vi in zip(x, V):
        if xi / (2 * Vi) > 40 or xi < 2e-8:  # closed forms, tested elsewhere
            continue
        N = int(exact_nodes(xi, Vi))
        if N > 20000:
            continue
        p_n, p_2n = longdouble_midpoint(xi, Vi, N), longdouble_midpoint(xi, Vi, 2 * N)
        trunc = float(abs(p_n - p_2n) / p_2n)
        module = float(abs(np.longdouble(containment_exact(math.sqrt(xi), 1.0, Vi)) - p_2n) / p_2n)
        worst_trunc, worst_module = max(worst_trunc, trunc), max(worst_module, module)
        assert trunc <= EXACT_RTOL, (xi, Vi, N, trunc)
        assert module <= EXACT_RTOL + 8 * EPS, (xi, Vi, N, module)
    print(f"node rule: worst truncation {worst_trunc:.2e}, worst module error {worst_module:.2e} (relative)")


def rigorous_bound(x, V, N, ys):
    """Trefethen-Weideman bound on the midpoint-rule error with M = 2N nodes on the period,
    minimised over the strip half-widths ys: (x/sqrt V) phi_1(m(y)) / (e^{2Ny} - 1),
    m(y) = x/(2V) - x(1 - 1/V)(cosh y - 1)/4 (the smallest Re w on Im phi = y)."""
    m = x[:, None] / (2 * V[:, None]) - x[:, None] * (1 - 1 / V[:, None]) * (np.cosh(ys)[None, :] - 1) / 4
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        phi1 = np.where(m == 0, 1.0, -np.expm1(-m) / m)
        B = (x / np.sqrt(V))[:, None] * phi1 / np.expm1(2 * N[:, None] * ys[None, :])
    return np.nanmin(B, axis=1)


def test_node_rule_against_rigorous_bound():
    # Dense grid: V from 1 + 1e-12 to 1e14, x from 2e-8 to 80 V (beyond, P == 1.0) or the
    # largest x the rule accepts.  The bound must be below EXACT_RTOL times a lower bound of P.
    ys = np.geomspace(1e-9, 80.0, 1500)
    Vs = np.concatenate([1 + np.geomspace(1e-12, 0.5, 12), np.geomspace(1.6, 1e14, 50)])
    worst = 0.0
    for V in Vs:
        xmax = min(80 * V, (cm.EXACT_MAX_NODES / 2.5) ** 2)
        x = np.geomspace(2e-8, xmax, 120)
        Vv = np.full_like(x, V)
        N = exact_nodes(x, Vv)
        bound = rigorous_bound(x, Vv, N, ys)
        p_lower = np.maximum(-np.expm1(-x / 2) / np.sqrt(V), -np.expm1(-x / (2 * V)))
        ratio = bound / (EXACT_RTOL * p_lower)
        worst = max(worst, ratio.max())
        assert np.all(ratio <= 1.0), (V, x[np.argmax(ratio)], ratio.max())
    print(f"node rule: worst bound / target = {worst:.3f}")


def test_exact_refuses_hopeless_geometries():
    with pytest.raises(bg.BananagridError, match=r"R\^2/v = 1e\+13 with V = 1e\+14: the exact quadrature would need 7.91e\+06 nodes \(> 4194304\); the ellipse is too elongated for R$"):
        containment_exact(math.sqrt(1e13), 1.0, 1e14)


# --------------------------------------------------------------------------------------------
# Monte Carlo
# --------------------------------------------------------------------------------------------

# Binomial tolerance: |p_hat - P| <= Z sqrt(P (1 - P) / n) + 1/n.  Z = 5.5 gives a two-sided
# false-alarm rate of 3.8e-8 per comparison (normal approximation; n P (1 - P) >= 1e4 here),
# under 1e-6 for the whole file.  The seed is fixed, so the test is deterministic anyway.
Z = 5.5
N_MC = 2_000_000


@pytest.mark.parametrize(
    "v1, v2, R",
    [(1.0, 1.0, 1.0), (1.0, 4.0, 1.5), (2.0, 50.0, 3.0), (0.3, 120.0, 12.0), (1.0, 400.0, 5.0), (9.0, 1.0, 2.0)],
)
def test_exact_matches_monte_carlo_of_linear_model(v1, v2, R):
    rng = np.random.default_rng(20240611)
    t = rng.standard_normal((2, N_MC))
    hit = v1 * t[0] ** 2 + v2 * t[1] ** 2 <= R * R
    p_hat = hit.mean()
    P = containment_exact(R, v1, v2)
    assert abs(p_hat - P) <= Z * math.sqrt(P * (1 - P) / N_MC) + 1 / N_MC, (p_hat, P)


def two_bearing_fix(D, A, B):
    """Walsh's fix (X, Y) from bearings a1 + l1, a2 + l2 at sensors (0, 0), (D, 0):
    Y = D / (cot a1' - cot a2'), X = Y cot a1'."""
    a1, a2 = math.atan2(B, A), math.atan2(B, A - D)

    def fix(l1, l2):
        c1, c2 = 1 / np.tan(a1 + l1), 1 / np.tan(a2 + l2)
        Y = D / (c1 - c2)
        return np.stack([Y * c1, Y])

    return fix


def test_bearing_fix_monte_carlo_uses_covariance_eigenvalues():
    # Linearised fix error J l, l ~ N(0, diag(s1^2, s2^2)); v1, v2 are the eigenvalues of
    # J diag(s1^2, s2^2) J^T (ERRATA).  J by central differences of Walsh's exact fix
    # (step 1e-6 rad: truncation 1e-12 relative, far below the Monte Carlo error).
    D, A, B, s1, s2 = 10e3, 3e3, 8e3, 0.01, 0.02
    fix = two_bearing_fix(D, A, B)
    h = 1e-6
    J = np.stack([(fix(h, 0.0) - fix(-h, 0.0)) / (2 * h), (fix(0.0, h) - fix(0.0, -h)) / (2 * h)], axis=1)
    np.testing.assert_allclose(fix(0.0, 0.0), [A, B], rtol=1e-12)
    v1, v2 = np.linalg.eigvalsh(J @ np.diag([s1**2, s2**2]) @ J.T)
    rng = np.random.default_rng(5)
    l = rng.standard_normal((2, N_MC)) * np.array([[s1], [s2]])
    err = J @ l
    for R in (50.0, 150.0, 300.0):
        p_hat = np.mean(np.hypot(err[0], err[1]) <= R)
        P = containment(R, v1, v2)
        assert abs(p_hat - P) <= Z * math.sqrt(P * (1 - P) / N_MC) + 1 / N_MC, (R, p_hat, P)


# --------------------------------------------------------------------------------------------
# Radius
# --------------------------------------------------------------------------------------------


def test_radius_inverts_containment():
    R, v1, v2, x, V = table()
    P = containment_exact(R, v1, v2)
    # Near P = 1 the radius is ill-conditioned: a rounding of P (1e-16) moves R by
    # 1e-16 / (R dP/dR) relative, 1.4e-7 at V = 1, x = 50 (1 - P = 1.4e-11).  Keep P < 0.9999
    # (R dP/dR > 1e-3 there: R to better than 1e-13); 47 of the 50 table cases.
    keep = P < 0.9999
    assert keep.sum() == 47
    R, v1, v2, P = R[keep], v1[keep], v2[keep], P[keep]
    R_back = containment_radius(P, v1, v2)
    # Newton stops at a step below 1e-13 R or |P - p| <= 4 eps p: R to ~1e-15; 1e-10 is the
    # brief's requirement.
    np.testing.assert_allclose(R_back, R, rtol=1e-10, atol=0)
    assert np.max(np.abs(R_back - R) / R) <= 1e-13
    p = np.array([0.0, 1e-9, 0.01, 0.25, 0.5, 0.9, 0.95, 0.99, 0.999])
    for V in V_TABLE + [1e4, 1e6]:
        Rp = containment_radius(p, 2.0, 2.0 * V)
        assert Rp[0] == 0.0 and np.all(np.diff(Rp) > 0)
        # containment(radius(p)) == p: P is computed to ~1e-15 relative, and Newton stops
        # within 4 eps of p or after a step of 1e-13 R (error ~ its square): 1e-14 relative.
        np.testing.assert_allclose(containment_exact(Rp, 2.0, 2.0 * V), p, rtol=1e-14, atol=0)


def test_cep_of_isotropic_case_is_closed_form():
    for v in (1e-4, 1.0, 3.0, 2.5e7):
        # CEP = R50 = sqrt(2 v ln 2) (Rayleigh median); a few roundings.
        assert containment_radius(0.5, v, v) == pytest.approx(math.sqrt(2 * v * math.log(2)), rel=4 * EPS)
    # R90, R95 of the Rayleigh law: sqrt(-2 v ln(1 - p)).
    np.testing.assert_allclose(containment_radius([0.9, 0.95], 2.0, 2.0), np.sqrt(-4 * np.log([0.1, 0.05])), rtol=4 * EPS)


def test_cep_elongated_matches_monte_carlo_median():
    rng = np.random.default_rng(11)
    v1, v2 = 1.0, 30.0
    t = rng.standard_normal((2, N_MC))
    r = np.sqrt(v1 * t[0] ** 2 + v2 * t[1] ** 2)
    cep = containment_radius(0.5, v1, v2)
    # The empirical probability inside the CEP is binomial(N_MC, 1/2): tolerance as above.
    assert abs(np.mean(r <= cep) - 0.5) <= Z * math.sqrt(0.25 / N_MC)


# --------------------------------------------------------------------------------------------
# Vectorisation and timing
# --------------------------------------------------------------------------------------------


def bearing_geometries(n, rng):
    """(R, v1, v2) for n random two-bearing fixes: sensors 10 km apart, targets in
    [-20, 30] x [2, 40] km, bearing sd 0.005-0.03 rad; R uniform in [0, 2] sigma_major."""
    D = 10e3
    A, B = rng.uniform(-20e3, 30e3, n), rng.uniform(2e3, 40e3, n)
    s1, s2 = rng.uniform(0.005, 0.03, n), rng.uniform(0.005, 0.03, n)
    a1, a2 = np.arctan2(B, A), np.arctan2(B, A - D)
    g = np.sin(a2 - a1)
    # Moving bearing i by d moves the fix along the other bearing line by r_i d / sin(a2 - a1).
    J = np.empty((n, 2, 2))
    J[:, :, 0] = (np.hypot(A, B) / g)[:, None] * np.stack([np.cos(a2), np.sin(a2)], 1)
    J[:, :, 1] = (np.hypot(A - D, B) / g)[:, None] * np.stack([np.cos(a1), np.sin(a1)], 1)
    cov = np.einsum("nij,nj,nkj->nik", J, np.stack([s1**2, s2**2], 1), J)
    ev = np.linalg.eigvalsh(cov)
    v1, v2 = ev[:, 0], ev[:, 1]
    R = rng.uniform(0, 2, n) * np.sqrt(v2)
    return R, v1, v2


def best_of(k, fn):
    best = math.inf
    for _ in range(k):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def test_million_geometries_vectorised_and_timed(capsys):
    rng = np.random.default_rng(2024)
    n = 1_000_000
    R, v1, v2 = bearing_geometries(n, rng)
    t_exact, P = best_of(2, lambda: containment_exact(R, v1, v2))
    t_series, Ps = best_of(1, lambda: containment_series(R, v1, v2, max_terms=10**6))
    pick = rng.choice(n, 25, replace=False)
    loop = np.array([containment_exact(R[i], v1[i], v2[i]) for i in pick])
    # Same arithmetic per element whatever the batch (rows of the same node set, summed
    # row by row): identical numbers.
    np.testing.assert_array_equal(P[pick], loop)
    loop_s = np.array([containment_series(R[i], v1[i], v2[i], max_terms=10**6) for i in pick])
    # A lone element runs the along-the-terms path: same terms, other rounding (1e-13).
    np.testing.assert_allclose(Ps[pick], loop_s, rtol=0, atol=1e-13)
    np.testing.assert_allclose(Ps, P, rtol=0, atol=1e-10)
    x = R**2 / np.minimum(v1, v2)
    V = np.maximum(v1, v2) / np.minimum(v1, v2)
    with capsys.disabled():
        print(
            f"\n10^6 two-bearing geometries (V median {np.median(V):.0f}, max {V.max():.0f}; "
            f"R^2/v median {np.median(x):.0f}, max {x.max():.0f}): exact {t_exact:.2f} s, "
            f"series (tol 1e-12) {t_series:.2f} s, max |series - exact| {np.max(np.abs(Ps - P)):.1e}"
        )


def test_broadcasting_and_scalars():
    P = containment_exact(np.array([[0.5], [1.0], [2.0]]), 1.0, np.array([1.0, 4.0]))
    assert P.shape == (3, 2)
    assert P[2, 1] == containment_exact(2.0, 1.0, 4.0)
    s = containment(1.0, 2.0, 3.0)
    assert isinstance(s, float) and np.ndim(s) == 0
    # symmetric in v1, v2
    assert containment_exact(1.3, 2.0, 7.0) == containment_exact(1.3, 7.0, 2.0)
    assert containment_series(1.3, 2.0, 7.0) == containment_series(1.3, 7.0, 2.0)
    lo, up = series_bounds([0.5, 1.0], 1.0, 2.0, 3)
    assert lo.shape == up.shape == (2,)
    assert containment_radius([[0.5, 0.9]], [1.0], 2.0).shape == (1, 2)
    assert containment([], 1.0, 2.0).shape == (0,)
    assert containment_series([], 1.0, 2.0).shape == (0,)
    assert containment_radius([], 1.0, 2.0).shape == (0,)
    assert containment(1.0, 2.0, 3.0, method="series") == pytest.approx(s, abs=1e-12)
    # threads do not change the numbers
    R, v1, v2 = bearing_geometries(200_000, np.random.default_rng(3))
    np.testing.assert_array_equal(containment_exact(R, v1, v2, threads=1), containment_exact(R, v1, v2, threads=2))


# --------------------------------------------------------------------------------------------
# Bad input: one test per kind, message asserted
# --------------------------------------------------------------------------------------------

FUNCS = {
    "exact": lambda R, v1, v2: containment_exact(R, v1, v2),
    "series": lambda R, v1, v2: containment_series(R, v1, v2),
    "bounds": lambda R, v1, v2: series_bounds(R, v1, v2, 2),
    "dispatch": lambda R, v1, v2: containment(R, v1, v2, method="series"),
}


@pytest.mark.parametrize("func", FUNCS)
@pytest.mark.parametrize("name", ["v1", "v2"])
@pytest.mark.parametrize(
    "value, shown", [(0.0, "0.0"), (-1.0, "-1.0"), (math.nan, "nan"), (math.inf, "inf")]
)
def test_bad_variance(func, name, value, shown):
    args = {"R": 1.0, "v1": 1.0, "v2": 2.0, name: value}
    with pytest.raises(bg.BananagridError, match=rf"^{name} = {shown}: must be finite and > 0$"):
        FUNCS[func](**args)


def test_bad_variance_in_array_names_the_element():
    with pytest.raises(bg.BananagridError, match=r"^v2\[1, 0\] = -3.0: must be finite and > 0$"):
        containment_exact(1.0, 1.0, [[1.0], [-3.0]])
    with pytest.raises(bg.BananagridError, match=r"^v1\[2\] = nan: must be finite and > 0$"):
        containment_radius(0.5, [1.0, 2.0, math.nan], 1.0)


@pytest.mark.parametrize("func", FUNCS)
@pytest.mark.parametrize("value, shown", [(-0.5, "-0.5"), (math.nan, "nan"), (-math.inf, "-inf")])
def test_bad_radius(func, value, shown):
    with pytest.raises(bg.BananagridError, match=rf"^R = {shown}: must be finite and >= 0$"):
        FUNCS[func](value, 1.0, 2.0)
    with pytest.raises(bg.BananagridError, match=rf"^R\[1\] = {shown}: must be finite and >= 0$"):
        FUNCS[func]([1.0, value], 1.0, 2.0)


@pytest.mark.parametrize("value, shown", [(-0.1, "-0.1"), (1.0, "1.0"), (1.5, "1.5"), (math.nan, "nan")])
def test_bad_probability(value, shown):
    with pytest.raises(bg.BananagridError, match=rf"^p = {shown}: must be in \[0, 1\)$"):
        containment_radius(value, 1.0, 2.0)


def test_mismatched_shapes():
    with pytest.raises(bg.BananagridError, match=r"^R, v1, v2: R shape \(3,\), v1 shape \(2,\), v2 shape \(\) do not broadcast together$"):
        containment_exact([1.0, 2.0, 3.0], [1.0, 2.0], 1.0)
    with pytest.raises(bg.BananagridError, match=r"^R, v1, v2: .* do not broadcast together$"):
        containment_series([1.0, 2.0, 3.0], 1.0, [1.0, 2.0])
    with pytest.raises(bg.BananagridError, match=r"^p, v1, v2: p shape \(2,\), v1 shape \(3,\), v2 shape \(\) do not broadcast together$"):
        containment_radius([0.1, 0.2], [1.0, 2.0, 3.0], 1.0)


def test_not_numbers():
    with pytest.raises(bg.BananagridError, match=r"^R = '1': expected a real number or an array of them$"):
        containment_exact("1", 1.0, 2.0)
    with pytest.raises(bg.BananagridError, match=r"^v1 = True: expected a real number or an array of them$"):
        containment_exact(1.0, True, 2.0)
    with pytest.raises(bg.BananagridError, match=r"^p = \(1\+2j\): expected a real number or an array of them$"):
        containment_radius(1 + 2j, 1.0, 2.0)


@pytest.mark.parametrize("tol, message", [(0.0, "tol = 0.0: must be in (0, 0.1]"), (0.2, "tol = 0.2: must be in (0, 0.1]"), (math.nan, "tol = nan: must be in (0, 0.1]"), ("1e-9", "tol = '1e-9': expected a real number in (0, 0.1]")])
def test_bad_tol(tol, message):
    with pytest.raises(bg.BananagridError) as err:
        containment_series(1.0, 1.0, 2.0, tol=tol)
    assert str(err.value) == message
    with pytest.raises(bg.BananagridError) as err:
        containment(1.0, 1.0, 2.0, tol=tol)
    assert str(err.value) == message


def test_bad_counts_and_method():
    with pytest.raises(bg.BananagridError, match=r"^max_terms = 0: must be an integer >= 1$"):
        containment_series(1.0, 1.0, 2.0, max_terms=0)
    with pytest.raises(bg.BananagridError, match=r"^max_terms = 10.5: expected an integer >= 1$"):
        containment_series(1.0, 1.0, 2.0, max_terms=10.5)
    with pytest.raises(bg.BananagridError, match=r"^W = -1: must be an integer >= 0$"):
        series_bounds(1.0, 1.0, 2.0, -1)
    with pytest.raises(bg.BananagridError, match=r"^W = -1: must be an integer >= 0$"):
        robbins_pitman_weights(2.0, -1)
    with pytest.raises(bg.BananagridError, match=r"^V = 0.5: must be finite and >= 1$"):
        robbins_pitman_weights(0.5, 3)
    with pytest.raises(bg.BananagridError, match=r"^method = 'quad': must be one of exact, series$"):
        containment(1.0, 1.0, 2.0, method="quad")
    with pytest.raises(bg.BananagridError, match=r"^threads = 0: must be an integer >= 1$"):
        containment_exact(1.0, 1.0, 2.0, threads=0)
    with pytest.raises(bg.BananagridError, match=r"^return_bounds = 'yes': expected True or False$"):
        containment_series(1.0, 1.0, 2.0, return_bounds="yes")
