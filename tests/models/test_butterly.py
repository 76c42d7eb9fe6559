"""Butterly's model (normal start, random course, speed law): kernel accuracy against an
independent float64 oracle, Rice's law, Monte Carlo, mass, speed laws, von Mises course, the
Bessel series (3.8) and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special, stats

import bananagrid as bg
from bananagrid import BananagridError
from bananagrid.models.butterly import GAUSS_POINTS, NormalSpeed, TabulatedSpeed, UniformSpeed, _gauss_panels
from bananagrid.models._butterly_series import series_density
from butterly_oracle import butterly_density as oracle

#: Start SDs (m) of the case table: 100 m east, 250 m north, correlated by rho.
SX, SY = 100.0, 250.0
MEAN = (300.0, -200.0)
RHOS = (-0.99, 0.0, 0.6, 0.999)
RATIOS = (0.0, 0.1, 1.0, 10.0, 100.0, 1000.0, 1e4)

#: The accuracy target: relative error 1e-9 in float64.
RTOL = 1e-9


def covariance(rho, sx=SX, sy=SY):
    return [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]


def axes(cov):
    s1, s2 = np.linalg.eigvalsh(np.asarray(cov))
    return math.sqrt(s1), math.sqrt(s2)


def case_points(mean, r, sigma_min, sigma_max):
    """Near the ring (on it and 1.5 sigma_min outside), inside it, and in the far tails."""
    mean = np.asarray(mean)
    courses = np.linspace(0.1, 2 * math.pi + 0.1, 8, endpoint=False)
    e = np.column_stack((np.sin(courses), np.cos(courses)))
    ring = mean + r * e
    ring_out = mean + (r + 1.5 * sigma_min) * e
    inside = np.vstack((mean, mean + 0.5 * r * e[::2]))
    tails = np.vstack((mean + (r + 12 * sigma_max) * e[::2], mean + (r + 30 * sigma_min) * e[1::4]))
    return np.vstack((ring, ring_out, inside, tails))


CASES = [(rho, ratio) for rho in RHOS for ratio in RATIOS]


@pytest.mark.parametrize("rho, ratio", CASES, ids=[f"rho{rho}-r{ratio:g}" for rho, ratio in CASES])
def test_kernel_matches_oracle(rho, ratio):
    """Relative error <= 1e-9 wherever the density is a normal float64 (> 1e-300), which covers
    the target region (density > 1e-12 of its maximum) and the far tails. Rounding bound: the
    exponent's inputs carry an absolute error ~ eps r / sigma_min, times |residual| <= ~40 in the
    tails, so about 1e-10 at r / sigma_min = 1e4 (measured: 8e-11 there, <= 1e-12 below 1e3).
    The oracle's own convergence (n / 2 vs n nodes) is checked to 1e-11."""
    cov = covariance(rho)
    sigma_min, sigma_max = axes(cov)
    r = ratio * sigma_min
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=[r / 20.0], t=20.0)
    pts = case_points(MEAN, r, sigma_min, sigma_max)
    got = model.pdf(pts[:, 0], pts[:, 1])
    want, self_check = oracle(pts[:, 0], pts[:, 1], MEAN, cov, [r], [1.0])
    normal = want > 1e-300
    assert normal[:16].all()  # the ring points are never in the underflow range
    assert np.max(self_check[normal]) < 1e-11
    rel = np.abs(got[normal] / want[normal] - 1.0)
    assert rel.max() <= RTOL, f"max relative error {rel.max():.2e} at point {np.argmax(rel)}"
    assert np.all(got[~normal] <= 1e-290)  # underflow in the oracle: the kernel is tiny too


@pytest.mark.parametrize("kappa", [0.3, 8.0, 2000.0])
def test_von_mises_course_matches_oracle(kappa):
    """Three speeds, a correlated start and a von Mises course, against the oracle (1e-9 as
    above; the course law adds kappa (cos - 1) <= 0 to the exponent, no new rounding)."""
    cov = covariance(0.6)
    sigma_min, sigma_max = axes(cov)
    speeds, weights, t = [1.0, 4.0, 9.0], [0.25, 0.5, 0.25], 100.0
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=speeds, weights=weights, t=t, course_kappa=kappa, course_mean=2.0)
    pts = np.vstack([case_points(MEAN, v * t, sigma_min, sigma_max) for v in speeds])
    got = model.pdf(pts[:, 0], pts[:, 1])
    want, self_check = oracle(pts[:, 0], pts[:, 1], MEAN, cov, [v * t for v in speeds], weights, kappa=kappa, course_mean=2.0)
    normal = want > 1e-300
    assert np.max(self_check[normal]) < 1e-11
    assert np.max(np.abs(got[normal] / want[normal] - 1.0)) <= RTOL


def test_von_mises_with_kappa_to_zero_is_uniform():
    """p(c) = exp(kappa (cos(c - c0) - 1)) / (2 pi ive(0, kappa)) = (1 + kappa cos(c - c0) + O(kappa^2))
    / (2 pi), a factor within [exp(-2 kappa), 1] / ive(0, kappa), so the density moves by at most
    kappa (1 + O(kappa)) relative everywhere: 2 kappa allows the O(kappa^2)."""
    cov = covariance(0.6)
    kwargs = dict(mean=MEAN, cov=cov, speeds=[3.0, 7.0], weights=[0.5, 0.5], t=60.0)
    pts = case_points(MEAN, 420.0, *axes(cov))
    uniform = bg.Butterly(**kwargs).pdf(pts[:, 0], pts[:, 1])
    normal = uniform > 1e-300
    for kappa in (1e-6, 1e-9):
        near = bg.Butterly(**kwargs, course_kappa=kappa, course_mean=1.0).pdf(pts[:, 0], pts[:, 1])
        assert np.max(np.abs(near[normal] / uniform[normal] - 1.0)) <= 2 * kappa
    exact = bg.Butterly(**kwargs, course_kappa=0.0, course_mean=1.0).pdf(pts[:, 0], pts[:, 1])
    np.testing.assert_array_equal(exact, uniform)


def test_isotropic_range_is_rice():
    """Isotropic start s^2 I: |U - mean| given speed r_i is Rice(b = r_i / s, scale s) (ERRATA,
    Appendix B), so range_pdf is the weighted sum of scipy.stats.rice densities. 1e-10: the
    kernel's 1e-12 plus the course average's doubling tolerance (1e-11)."""
    s = 150.0
    speeds, weights, t = [0.0, 2.0, 30.0], [0.2, 0.5, 0.3], 50.0
    model = bg.Butterly(mean=(40.0, 70.0), cov=[[s * s, 0.0], [0.0, s * s]], speeds=speeds, weights=weights, t=t)
    R = np.array([1.0, 50.0, 100.0, 300.0, 800.0, 1400.0, 1500.0, 1650.0, 2500.0, 3500.0])
    want = sum(w * stats.rice.pdf(R, v * t / s, scale=s) for v, w in zip(speeds, weights))
    got = model.range_pdf(R)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=0)


def test_range_pdf_of_correlated_start_integrates_to_one():
    """The Beckmann mixture of a correlated start integrates to 1 over R (Gauss-Legendre on
    [0, r_max + 12 sigma_max] in panels of sigma_min / 2, 8 nodes each: the density varies on
    the scale sigma_min, so the rule's error is far below 1e-8)."""
    cov = covariance(0.6)
    sigma_min, sigma_max = axes(cov)
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=[1.0, 3.0], weights=[0.4, 0.6], t=100.0)
    R, w = _gauss_panels(0.0, 300.0 + 12 * sigma_max, sigma_min / 2)
    assert np.sum(w * model.range_pdf(R)) == pytest.approx(1.0, abs=1e-8)


def test_range_pdf_of_elongated_start_matches_oracle():
    """rho = 0.999 (axes 270 m and 4.2 m), range from a point that is not the mean: p(R) =
    R int p(origin + R e(psi)) dpsi with p from the independent oracle and the psi-integral by
    a 2048-node trapezoid rule (the integrand's narrowest feature, sigma_min / R >= 0.0084 rad,
    spans 2.7 node spacings at R = 500 m: checked against 1024 nodes to 1e-12). 1e-9 as for
    the kernel."""
    cov = covariance(0.999)
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=[5.0], t=100.0)
    origin = (MEAN[0] + 40.0, MEAN[1] - 30.0)
    R = np.array([300.0, 480.0, 500.0])
    got = model.range_pdf(R, origin=origin)
    for n in (1024, 2048):
        psi = 2 * math.pi * np.arange(n) / n
        want = []
        for rk in R:
            dens, _ = oracle(origin[0] + rk * np.sin(psi), origin[1] + rk * np.cos(psi), MEAN, cov, [500.0], [1.0])
            want.append(rk * dens.sum() * 2 * math.pi / n)
        if n == 1024:
            coarse = np.array(want)
    want = np.array(want)
    np.testing.assert_allclose(coarse, want, rtol=1e-12)
    np.testing.assert_allclose(got, want, rtol=1e-9)


def test_monte_carlo_correlated_start_three_speeds():
    """200,000 draws of sample() binned at 100 m against the rasterised density integrated on
    10 m sub-cells (midpoint rule: error ~ (h^2 / 24) |p''| / p ~ 1e-4, below the >= 5e-3
    statistical error of the fullest bins); Pearson's chi-square over bins expecting >= 5."""
    model = bg.Butterly(mean=(100.0, -50.0), cov=covariance(0.6), speeds=[2.0, 5.0, 8.0], weights=[0.2, 0.5, 0.3], t=100.0)
    half, bin_size, sub = 2200.0, 100.0, 10
    grid = bg.Grid.from_bounds(x=(100 - half, 100 + half), y=(-50 - half, -50 + half), step=bin_size / sub)
    probs = bg.rasterise(model, grid).values * grid.cell_area
    ny, nx = grid.ny // sub, grid.nx // sub
    probs = probs.reshape(ny, sub, nx, sub).sum(axis=(1, 3))
    pts = model.sample(200_000, np.random.default_rng(20260101))
    counts, _, _ = np.histogram2d(pts[:, 1], pts[:, 0], bins=(ny, nx), range=((-50 - half, -50 + half), (100 - half, 100 + half)))
    expected = probs * len(pts)
    big = expected >= 5
    obs = np.append(counts[big], len(pts) - counts[big].sum())
    exp = np.append(expected[big], len(pts) - expected[big].sum())
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    p_value = stats.chi2.sf(chi2, df=len(obs) - 1)
    assert p_value > 1e-3, f"chi2 = {chi2:.1f} on {len(obs) - 1} dof, p = {p_value:.2e}"


def test_mass_is_conserved_on_a_grid():
    """The midpoint rule over the whole plane is spectrally accurate for a smooth density that
    decays to 0 (error ~ exp(-2 pi^2 sigma_min^2 / h^2) = e^-79 at h = sigma_min / 2), and the
    frame r_max + 9 sigma_max misses < 1e-17: the captured mass is 1 to rounding (1e-11 allows
    the kernel's relative error summed over the grid)."""
    cov = covariance(-0.8, 60.0, 90.0)
    sigma_min, sigma_max = axes(cov)
    model = bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=[1.0, 4.0, 6.0], weights=[0.3, 0.3, 0.4], t=100.0)
    half = 600.0 + 9 * sigma_max
    grid = bg.Grid.from_bounds(x=(-half, half), y=(-half, half), step=sigma_min / 2)
    assert bg.rasterise(model, grid).mass == pytest.approx(1.0, abs=1e-11)


def test_rasterise_and_pdf_agree():
    """The grid kernel (tiles, skipped cells) and the points kernel (each point walking from its
    peak) compute the same rule to rounding: 1e-11 relative wherever the density exceeds 1e-12
    of its peak (each is within 1e-12 of the exact integral; the tile's factors add about 30
    roundings and drop nodes below 1e-15 / 2048 of the largest). Cells set to 0 are exactly
    those the bound proves below 1e-13 of the peak: there the points kernel is below that too."""
    model = bg.Butterly(mean=(5.0, 5.0), cov=covariance(0.3, 20.0, 30.0), speeds=[1.0], t=100.0)
    grid = bg.Grid.from_bounds(x=(-400.0, 400.0), y=(-350.0, 370.0), step=4.0)
    raster = bg.rasterise(model, grid)
    xx, yy = np.meshgrid(grid.x, grid.y)
    points = model.pdf(xx, yy)
    peak = model.peak_lower_bound()
    assert points.max() >= peak >= 0.5 * points.max()  # a lower bound, and a useful one
    keep = points > 1e-12 * points.max()
    np.testing.assert_allclose(raster.values[keep], points[keep], rtol=1e-11)
    zero = raster.values == 0.0
    assert zero.any() and np.all(points[zero] < 1e-13 * peak)
    assert raster.provenance["kernel"] == "butterly.butterly_grid"
    assert raster.provenance["zero_below"] == pytest.approx(1e-13 * peak)


GRID_CASES = [(0.6, 0.5), (0.6, 3.0), (-0.99, 10.0), (0.0, 10.0), (0.999, 30.0), (0.6, 100.0), (0.6, 400.0)]


@pytest.mark.parametrize("rho, ratio", GRID_CASES, ids=[f"rho{rho}-r{ratio:g}" for rho, ratio in GRID_CASES])
def test_grid_kernel_matches_oracle(rho, ratio):
    """rasterise (its own path: tiles for rules up to 2048 nodes, the walk beyond,
    cells skipped by the bound) against the independent oracle at 160 cells of a 300 x 240 grid
    framed about the ring +- 8 sigma_max: 1e-9 relative where the density exceeds 1e-12 of its
    peak, and a skipped cell (0) only where the oracle is below 1e-13 of the peak."""
    cov = covariance(rho)
    sigma_min, sigma_max = axes(cov)
    r = ratio * sigma_min
    speeds, weights, t = [0.6 * r / 50.0, r / 50.0], [0.4, 0.6], 50.0
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=speeds, weights=weights, t=t)
    half = r + 8 * sigma_max
    grid = bg.Grid.from_bounds(x=(MEAN[0] - half, MEAN[0] + half), y=(MEAN[1] - half, MEAN[1] + half), dx=2 * half / 300, dy=2 * half / 240)
    values = bg.rasterise(model, grid).values
    rng = np.random.default_rng(7)
    live = np.argwhere(values > 0)
    dead = np.argwhere(values == 0)
    pick = np.vstack((live[rng.choice(len(live), 120, replace=False)], dead[rng.choice(len(dead), min(40, len(dead)), replace=False)]))
    x, y = grid.x[pick[:, 1]], grid.y[pick[:, 0]]
    want, self_check = oracle(x, y, MEAN, cov, [v * t for v in speeds], weights)
    got = values[pick[:, 0], pick[:, 1]]
    peak = model.peak_lower_bound()
    keep = want > 1e-12 * peak
    assert np.max(self_check[keep]) < 1e-11
    assert np.max(np.abs(got[keep] / want[keep] - 1.0)) <= RTOL
    assert np.all(want[got == 0] < 1e-13 * peak)


def test_grid_kernel_window_on_a_wide_ring():
    """Tiles with rules of about 1,800 nodes (r / sigma_min = 150, rho = 0.9): a window of
    fine cells (sigma_min / 20) across the ring, against the oracle at 150 cells, 1e-9."""
    cov = covariance(0.9)
    sigma_min, sigma_max = axes(cov)
    r = 150.0 * sigma_min
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=[r / 100.0], t=100.0)
    cx, cy = MEAN[0] + r * math.sin(0.7), MEAN[1] + r * math.cos(0.7)
    half = 4.0 * sigma_max
    step = sigma_min / 20.0
    grid = bg.Grid.from_bounds(x=(cx - half, cx + half), y=(cy - half, cy + half), step=step)
    values = bg.rasterise(model, grid).values
    rng = np.random.default_rng(11)
    live = np.argwhere(values > 0)
    pick = live[rng.choice(len(live), 150, replace=False)]
    x, y = grid.x[pick[:, 1]], grid.y[pick[:, 0]]
    want, self_check = oracle(x, y, MEAN, cov, [r], [1.0])
    got = values[pick[:, 0], pick[:, 1]]
    keep = want > 1e-12 * model.peak_lower_bound()
    assert keep.sum() > 100 and np.max(self_check[keep]) < 1e-11
    assert np.max(np.abs(got[keep] / want[keep] - 1.0)) <= RTOL


def test_float32_kernel():
    """float32 keeps ~1e-7 per operation; the exponent's inputs of size r / sigma ~ 10 lose
    a digit: 1e-4 relative near the ring is a loose but meaningful check of the float32 path."""
    model = bg.Butterly(mean=MEAN, cov=covariance(0.6), speeds=[10.0], t=60.0)
    pts = case_points(MEAN, 600.0, *axes(model.cov))[:21]
    got = model.pdf(pts[:, 0], pts[:, 1], dtype=np.float32)
    want = model.pdf(pts[:, 0], pts[:, 1])
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-4)
    # the grid kernel's float32 path (a tile's factors: about 30 more roundings, 2e-6)
    grid = bg.Grid.from_bounds(x=(-800.0, 1400.0), y=(-1000.0, 1200.0), step=10.0)
    got = bg.rasterise(model, grid, dtype=np.float32).values
    want = bg.rasterise(model, grid).values
    keep = want > 1e-6 * want.max()
    np.testing.assert_allclose(got[keep], want[keep], rtol=1e-4)


def _points_check(model, grid, threads=1, rtol=1e-11):
    """rasterise against pdf (each point on its own) at 1e-11 relative above 1e-12 of the peak
    (both within 1e-12 of the integral); cells set to 0 are below 1e-13 of the peak."""
    values = bg.rasterise(model, grid, threads=threads).values
    xx, yy = np.meshgrid(grid.x, grid.y)
    points = model.pdf(xx, yy)
    keep = points > 1e-12 * points.max()
    np.testing.assert_allclose(values[keep], points[keep], rtol=rtol)
    assert np.all(points[values == 0] < 1e-13 * model.peak_lower_bound())
    return values


def test_grid_kernel_paths_agree_with_points():
    """Every path of the grid kernel against the points kernel: partial tiles (sides not
    multiples of 32) on 1 and 2 threads (other strips, other tile centres: equal to rounding),
    a grid too small for a tile (each cell marked and walked, as on a GPU), and coarse cells
    (3 sigma_min: a tile's cross factor would span exp(-4000), so tiles are refused and walked)."""
    model = bg.Butterly(mean=(30.0, -10.0), cov=covariance(0.7, 40.0, 90.0), speeds=[2.0, 5.0], weights=[0.3, 0.7], t=100.0)
    fine = bg.Grid.from_bounds(x=(-900.0, 950.0), y=(-800.0, 760.0), dx=1850.0 / 77, dy=1560.0 / 45)
    one = _points_check(model, fine, threads=1)
    two = _points_check(model, fine, threads=2)
    np.testing.assert_allclose(two, one, rtol=1e-12, atol=0.0)
    tiny = bg.Grid.from_bounds(x=(-300.0, 300.0), y=(-200.0, 200.0), dx=200.0, dy=80.0)
    assert tiny.shape[0] * tiny.shape[1] < 16  # below MIN_TILE_CELLS
    _points_check(model, tiny)
    sigma_min = axes(model.cov)[0]
    coarse = bg.Grid.from_bounds(x=(-2000.0, 2000.0), y=(-2000.0, 2000.0), step=3.0 * sigma_min)
    _points_check(model, coarse)


def test_grid_kernel_extreme_scale():
    """Lengths in units 1e154 times smaller: the density is 1e308 times larger, exp of a tile's
    log scale (about +697) times its sum could overflow, so each cell combines logs (a test
    that fails if that branch adds nothing); the raster is the unscaled one times 1e308 to
    1e-11 (float64 rounding of the scaled inputs: ~1e-14)."""
    unit = 1e-154
    cov = np.asarray(covariance(0.5, 70.0, 120.0))
    base = bg.Butterly(mean=(10.0, 20.0), cov=cov, speeds=[4.0, 8.0], weights=[0.5, 0.5], t=100.0)
    small = bg.Butterly(mean=(10.0 * unit, 20.0 * unit), cov=cov * unit**2, speeds=[4.0 * unit, 8.0 * unit],
                        weights=[0.5, 0.5], t=100.0)
    grid = bg.Grid.from_bounds(x=(-1400.0, 1400.0), y=(-1300.0, 1300.0), step=10.0)
    grid_small = bg.Grid.from_bounds(x=(-1400.0 * unit, 1400.0 * unit), y=(-1300.0 * unit, 1300.0 * unit), step=10.0 * unit)
    want = bg.rasterise(base, grid).values
    got = bg.rasterise(small, grid_small).values * (unit * unit)
    assert np.isfinite(got).all() and want.max() > 0
    keep = want > 1e-12 * want.max()
    np.testing.assert_allclose(got[keep], want[keep], rtol=1e-11)


# --- continuous speed laws --------------------------------------------------------------------

CONTINUOUS = {
    "uniform": UniformSpeed(2.0, 7.0),
    "normal": NormalSpeed(4.0, 1.5),
    "normal-truncated": NormalSpeed(0.5, 2.0),
    "table": TabulatedSpeed([1.0, 3.0, 4.0, 8.0], [0.0, 2.0, 1.0, 0.5]),
}


def _fine_discrete(law, n=4000):
    """The law's density on a fine midpoint grid over its support, as a discrete law."""
    lo, hi = {
        "UniformSpeed": lambda: (law.v_min, law.v_max),
        "NormalSpeed": lambda: (max(0.0, law.mean - 10 * law.sd), law.mean + 10 * law.sd),
        "TabulatedSpeed": lambda: (law.speeds[0], law.speeds[-1]),
    }[type(law).__name__]()
    edges = np.linspace(lo, hi, n + 1)
    v = 0.5 * (edges[1:] + edges[:-1])
    w = law.pdf(v) * np.diff(edges)
    return v, w / w.sum()


@pytest.mark.parametrize("name", list(CONTINUOUS))
def test_continuous_speed_law_matches_fine_discrete(name):
    """Against a 4,000-node midpoint rule of the speed density (an independent discretisation;
    its error is O(h^2): (h t)^2 / 24 |d^2 P / dr^2| / P ~ (0.15 m)^2 / 24 / (35 m)^2 x (|zeta|^2 + 1)
    ~ 1e-6 near the ring, and O(h) ~ 1e-5 relative in a table's kink cells): 3e-5 relative
    where the density exceeds 1e-6 of its peak."""
    law = CONTINUOUS[name]
    cov = covariance(0.5, 40.0, 60.0)
    model = bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=law, t=100.0)
    v, w = _fine_discrete(law)
    with pytest.warns(UserWarning, match="4000 speed nodes"):
        fine = bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=v, weights=w, t=100.0)
    x = np.linspace(-1100.0, 1100.0, 25)
    xx, yy = np.meshgrid(x, x[::2] + 7.0)
    got = model.pdf(xx, yy)
    want = fine.pdf(xx, yy)
    keep = want > 1e-6 * want.max()
    np.testing.assert_allclose(got[keep], want[keep], rtol=3e-5)


@pytest.mark.parametrize("name", list(CONTINUOUS))
def test_continuous_speed_quadrature_error_is_as_stated(name):
    """SPEED_PANEL_SIGMAS: the composite Gauss-Legendre rule agrees with one on panels 4x
    narrower to 1e-11 relative (the stated error) wherever the density exceeds 1e-12 of its
    peak (measured 5e-12, at the level of the kernel's own rounding at those points)."""
    law = CONTINUOUS[name]
    cov = covariance(0.5, 40.0, 60.0)
    model = bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=law, t=100.0)
    v, w = law.nodes(100.0, 0.25 * model.sigma_min)
    finer = bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=v, weights=w / w.sum(), t=100.0)
    x = np.linspace(-1300.0, 1300.0, 27)
    xx, yy = np.meshgrid(x, x + 3.0)
    got, want = model.pdf(xx, yy), finer.pdf(xx, yy)
    keep = want > 1e-12 * want.max()
    np.testing.assert_allclose(got[keep], want[keep], rtol=1e-11)
    assert model.n_speed_nodes % GAUSS_POINTS == 0


@pytest.mark.parametrize("name", list(CONTINUOUS))
def test_continuous_speed_sampling(name):
    """sample() draws speeds from the law itself: Kolmogorov-Smirnov against the law's CDF
    (numerical integral of its pdf), 50,000 draws, p > 1e-3."""
    law = CONTINUOUS[name]
    draws = law.sample(50_000, np.random.default_rng(11))
    v, w = _fine_discrete(law, 200_000)
    cdf = lambda s: np.interp(s, v, np.cumsum(w))
    assert stats.kstest(draws, cdf).pvalue > 1e-3


# --- the Bessel series (3.8) ------------------------------------------------------------------

SERIES_CASES = [(0.0, 1.0, 0.0), (0.6, 1.0, 0.0), (0.6, 3.0, 0.0), (0.6, 10.0, 0.0), (0.999, 1.0, 0.0), (0.999, 10.0, 0.0), (0.6, 3.0, 4.0)]


@pytest.mark.parametrize("rho, ratio, kappa", SERIES_CASES)
def test_series_matches_kernel_where_it_converges(rho, ratio, kappa):
    """Where the series loses at most 4 digits to cancellation (lost_digits <= 4) it agrees with
    the kernel to 1e-10: 10^(4 - 15.6) times ~K terms' rounding (measured <= 1e-12). Where it
    loses more than 17 digits (all of them) it is not even the right order of magnitude."""
    cov = covariance(rho)
    sigma_min, sigma_max = axes(cov)
    r = ratio * sigma_min
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=[r], t=1.0, course_kappa=kappa, course_mean=0.3)
    rng = np.random.default_rng(3)
    pts = np.vstack((model.sample(200, rng), np.asarray(MEAN) + rng.uniform(-1, 1, (100, 2)) * (r + 8 * sigma_max)))
    series, lost = series_density(model, pts[:, 0], pts[:, 1])
    kernel = model.pdf(pts[:, 0], pts[:, 1])
    good = (lost <= 4.0) & (kernel > 1e-300)
    assert good.sum() >= 10
    np.testing.assert_allclose(series[good], kernel[good], rtol=1e-10)
    hopeless = (lost > 17.0) & (kernel > 1e-300)
    if hopeless.any():
        assert np.all(np.abs(series[hopeless] / kernel[hopeless] - 1.0) > 0.01)


def test_series_loses_nothing_for_an_isotropic_start():
    """F = 0: the sum is ive(0, w') (Rice), no cancellation even at r / sigma = 1000 and 40 sigma out."""
    s = 100.0
    model = bg.Butterly(mean=(0.0, 0.0), cov=[[s * s, 0.0], [0.0, s * s]], speeds=[1e5], t=1.0)
    R = np.array([0.0, 5e4, 9.9e4, 1e5, 1.01e5, 1.04e5])
    series, lost = series_density(model, R * 0.6, R * 0.8)
    kernel = model.pdf(R * 0.6, R * 0.8)
    assert np.all(lost < 1e-6)
    ok = kernel > 1e-300
    np.testing.assert_allclose(series[ok], kernel[ok], rtol=1e-12)


# --- the kernel's node count ------------------------------------------------------------------


def _required_nodes(amplitude, tol):
    """Smallest N with 4 pi exp(min_y (A sinh(y)^2 / 2 - N y)) / (1 - e^-Ny) / J(A) <= tol,
    J(A) = max(2 pi exp(-A pi^2 / 6), sqrt(2 pi / A) erf(pi sqrt(A / 2))) <= int exp(E - E*):
    the strip bound on the periodic trapezoid rule (see kernels/butterly.py)."""
    y = np.geomspace(1e-7, 30.0, 20000)
    log_j = max(math.log(2 * math.pi) - amplitude * math.pi**2 / 6,
                0.5 * math.log(2 * math.pi / amplitude) + math.log(special.erf(math.pi * math.sqrt(amplitude / 2))))

    def log_bound(n):
        return np.min(amplitude * np.sinh(y) ** 2 / 2 - n * y - np.log(-np.expm1(-n * y))) + math.log(4 * math.pi) - log_j

    lo, hi = 1, 8
    while log_bound(hi) > math.log(tol):
        hi *= 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if log_bound(mid) > math.log(tol) else (lo, mid)
    return hi


def test_node_count_meets_the_trapezoid_bound():
    """The device's node_count (through a kernel) is at least the strip bound's N for A from
    1e-6 to 1e9, at the float64 tolerance the model uses (1e-12)."""
    import warp as wp

    from bananagrid.kernels import butterly as kb
    from bananagrid.engine.warp_runtime import warp as _warp

    _warp()

    @wp.kernel
    def counts(amps: wp.array(dtype=wp.float64), log_tol: wp.float64, out: wp.array(dtype=wp.int32)):
        i = wp.tid()
        out[i] = kb.node_count(amps[i], log_tol)

    amps = np.geomspace(1e-6, 1e9, 61)
    out = wp.zeros(len(amps), dtype=wp.int32)
    tol = 1e-12
    wp.launch(counts, dim=len(amps), inputs=[wp.array(amps, dtype=wp.float64), math.log(1 / tol) + math.log(4 * math.pi), out])
    got = out.numpy()
    need = np.array([_required_nodes(a, tol) for a in amps])
    assert np.all(got >= need), list(zip(amps[got < need], got[got < need], need[got < need]))


# --- bad input --------------------------------------------------------------------------------

GOOD = dict(mean=(0.0, 0.0), cov=[[4.0, 1.0], [1.0, 9.0]], speeds=[1.0, 2.0], weights=[0.5, 0.5], t=10.0)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(cov=[[4.0, 1.0], [1.5, 9.0]]), r"cov = .*: must be symmetric"),
        (dict(cov=[[4.0, 6.0], [6.0, 9.0]]), r"cov = .*: must be positive definite .*allowed: \|rho\| < 1"),
        (dict(cov=[[-4.0, 0.0], [0.0, 9.0]]), r"cov = .*: must be positive definite \(variances > 0\)"),
        (dict(cov=[[4.0, 1.0, 0.0], [1.0, 9.0, 0.0]]), r"cov = .*: expected a 2x2 array"),
        (dict(cov=[[4.0, math.nan], [math.nan, 9.0]]), r"cov = .*: every entry must be finite"),
        (dict(mean=(math.nan, 0.0)), r"mean\[0\] = nan: must be finite"),
        (dict(speeds=[1.0, -2.0]), r"speeds\[1\] = -2.0: must be >= 0"),
        (dict(speeds=[1.0, math.nan]), r"speeds = .*: every value must be finite"),
        (dict(weights=[0.5, 0.6]), r"weights = \[0.5, 0.6\]: must sum to 1 \(they sum to 1.1"),
        (dict(weights=[1.5, -0.5]), r"weights\[1\] = -0.5: must be >= 0"),
        (dict(weights=[0.5, math.nan]), r"weights = .*: every value must be finite"),
        (dict(weights=[1.0]), r"weights: 1 given for 2 speeds"),
        (dict(weights=None), r"weights: required for 2 speeds"),
        (dict(t=-1.0), r"t = -1.0: must be >= 0"),
        (dict(t=math.nan), r"t = nan: must be finite"),
        (dict(course_kappa=-0.1), r"course_kappa = -0.1: must be >= 0"),
        (dict(course_mean=math.inf), r"course_mean = inf: must be finite"),
        (dict(speeds=UniformSpeed(1.0, 2.0)), r"weights = .*: a continuous speed law \(UniformSpeed\) takes no weights"),
    ],
)
def test_bad_input(change, message):
    with pytest.raises(BananagridError, match=message):
        bg.Butterly(**{**GOOD, **change})


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: UniformSpeed(3.0, 2.0), r"speeds.v_max = 2.0: must be > v_min = 3.0"),
        (lambda: UniformSpeed(-1.0, 2.0), r"speeds.v_min = -1.0: must be >= 0"),
        (lambda: NormalSpeed(3.0, 0.0), r"speeds.sd = 0.0: must be > 0"),
        (lambda: NormalSpeed(math.nan, 1.0), r"speeds.mean = nan: must be finite"),
        (lambda: NormalSpeed(-50.0, 1.0), r"speeds.mean = -50.0: .* no mass above 0"),
        (lambda: TabulatedSpeed([1.0, 1.0], [1.0, 1.0]), r"speeds.speeds = .*: must be >= 0 and strictly increasing"),
        (lambda: TabulatedSpeed([1.0, 2.0], [0.0, -1.0]), r"speeds.density = .*: must be >= 0 and not all zero"),
        (lambda: TabulatedSpeed([1.0, 2.0, 3.0], [1.0, 1.0]), r"speeds: a table needs at least 2 speeds and as many densities"),
    ],
)
def test_bad_speed_law(make, message):
    with pytest.raises(BananagridError, match=message):
        make()


def test_model_is_frozen_and_copies_its_inputs():
    speeds = np.array([1.0, 2.0])
    model = bg.Butterly(**{**GOOD, "speeds": speeds})
    speeds[0] = 5.0
    assert model.speeds[0] == 1.0 and not model.speeds.flags.writeable
    with pytest.raises(AttributeError):
        model.t = 3.0
    assert bg.Butterly(mean=(0, 0), cov=[[1, 0], [0, 1]], speeds=[2.0], t=1).speed_nodes[1].tolist() == [1.0]


# --- polar outputs ----------------------------------------------------------------------------


def test_polar_lattice_rows_match_range_pdf():
    """p(R, theta) = R p(u, v) (Butterly (2.6)) on a full-circle polar lattice about the start
    mean: each row's probabilities summed over bearing are the range law's mass in that range
    bin, int range_pdf dR (the Beckmann mixture, Gauss-Legendre on panels of sigma_min, 8
    nodes: error far below 1e-15). The lattice's cell rule is within ~1e-9 of the total mass
    per cell (GAUSS_TOL, bananagrid.lattice) and range_pdf within 1e-11 relative, so 1e-9 per
    row is the stated bound (measured: 7e-13)."""
    cov = covariance(0.6)
    model = bg.Butterly(mean=MEAN, cov=cov, speeds=[2.0, 5.0], weights=[0.4, 0.6], t=100.0)
    lattice = bg.PolarLattice(
        ranges=(0.0, 2400.0), range_step=200.0, bearings=(0.0, 2 * math.pi), bearing_step=2 * math.pi / 24,
        pose=bg.Pose(origin=MEAN),
    )
    polar = bg.rasterise(model, lattice)
    rows = polar.probability.sum(axis=1)
    want = []
    for r0, r1 in zip(lattice.range_edges[:-1], lattice.range_edges[1:]):
        R, w = _gauss_panels(r0, r1, model.sigma_min)
        want.append(np.sum(w * model.range_pdf(R)))
    np.testing.assert_allclose(rows, want, rtol=0, atol=1e-9)
    assert rows.sum() == pytest.approx(1.0, abs=1e-9)  # 2400 m = r_max + 7.6 sigma_max: the rest is < 1e-12
    # the density per (m, rad) at the cell centres is R p(u, v)
    r, b = np.meshgrid(polar.ranges, polar.bearings, indexing="ij")
    x, y = MEAN[0] + r * np.sin(b), MEAN[1] + r * np.cos(b)
    np.testing.assert_allclose(polar.density, r * model.pdf(x, y), rtol=1e-12)


def test_numpy_twin_computes_the_same_raster():
    """bananagrid.butterly.numpy_density (the bench's baseline) is the same rule: with floors it
    zeroes the same cells as the grid kernel and agrees with it to 1e-11 relative elsewhere
    above 1e-12 of the peak (both within 1e-12 of the integral; the tiles add <= 1e-12)."""
    from bananagrid.bench.baselines import butterly_density as numpy_density

    cov = covariance(-0.4, 60.0, 110.0)
    model = bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=[0.5, 3.0, 6.0], weights=[0.2, 0.5, 0.3], t=100.0,
                        course_kappa=1.5, course_mean=0.4)
    grid = bg.Grid.from_bounds(x=(-1400.0, 1400.0), y=(-1300.0, 1300.0), step=20.0)
    kernel = bg.rasterise(model, grid).values
    xx, yy = np.meshgrid(grid.x, grid.y)
    twin = numpy_density(model, xx, yy, floors=True)
    np.testing.assert_array_equal(twin == 0, kernel == 0)
    keep = kernel > 1e-12 * kernel.max()
    np.testing.assert_allclose(twin[keep], kernel[keep], rtol=1e-11)
    exact = numpy_density(model, xx[::10], yy[::10])  # no floors: every cell
    assert np.all(exact > 0) and np.all(exact[kernel[::10] == 0] < 1e-13 * model.peak_lower_bound())
