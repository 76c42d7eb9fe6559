"""Polygons against rectangles and points, and the inverse-cube integral along a segment, each
against an independent oracle: shapely's exact polygon intersection areas and containment, and
SciPy's adaptive quadrature of 1 / r^3."""

from __future__ import annotations

import math

import numpy as np
import shapely
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st
from scipy import integrate

from bananagrid.evidence.geometry import Polygon, distance_to_track, segment_inverse_cube

SWEEP = settings(max_examples=40, deadline=None, database=None, suppress_health_check=list(HealthCheck))


def star_polygon(rng, centre=(0.0, 0.0), radius=100.0, n=None):
    """A simple polygon: vertices at increasing random angles about ``centre``, no two more than
    pi apart, random radii (a star about its centre is simple whatever the radii)."""
    n = n or int(rng.integers(4, 12))
    angles = 2.0 * math.pi * (np.arange(n) + rng.uniform(0.0, 0.8, n)) / n  # gaps below 1.8 (2 pi / n) <= pi
    radii = radius * rng.uniform(0.2, 1.0, n)
    return np.column_stack((centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)))


@seed(20261127)
@SWEEP
@given(st.integers(0, 2**32 - 1), st.sampled_from([1.0, 1e3, 1e6]), st.booleans())
def test_area_fraction_in_rectangles_matches_shapely(seed_value, offset, clockwise):
    """The fraction of random rectangles (large, small, thin, outside, holding the polygon)
    inside a random polygon, far from the origin too, equals shapely's exact intersection area
    to 1e-9 of the rectangle's area (rounding of the clamped trapezoids, coordinates taken
    relative to each rectangle: 1e-9 is far above it and far below any wrong sign or edge)."""
    rng = np.random.default_rng(seed_value)
    vertices = star_polygon(rng, centre=(offset, -offset))
    if clockwise:
        vertices = vertices[::-1]
    poly = Polygon(vertices)
    x0 = offset + rng.uniform(-150.0, 120.0, 200)
    y0 = -offset + rng.uniform(-150.0, 120.0, 200)
    w = rng.choice([0.01, 1.0, 30.0, 300.0], 200) * rng.uniform(0.5, 1.0, 200)
    h = rng.choice([0.01, 1.0, 30.0, 300.0], 200) * rng.uniform(0.5, 1.0, 200)
    got = poly.fraction(x0, x0 + w, y0, y0 + h)
    # shapely in each rectangle's own coordinates (its intersection at 1e6 m rounds to ~1e-9 of
    # a centimetre's rectangle; translated, it is exact to rounding of the given vertices)
    expected = np.array([shapely.clip_by_rect(shapely.Polygon(poly.vertices - (a, b)), 0.0, 0.0, (a + c) - a,
                                              (b + d) - b).area / (((a + c) - a) * ((b + d) - b))
                         for a, b, c, d in zip(x0, y0, w, h)])
    np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-9)


@seed(20261127)
@settings(SWEEP, max_examples=15)
@given(st.integers(0, 2**32 - 1))
def test_untouched_cells_are_wholly_inside_or_outside(seed_value):
    """A cell no polygon edge touches is wholly inside or wholly outside, and contains() of its
    centre says which (shapely's area, to 1e-12 of the cell); every touched cell is one whose
    boundary the polygon's boundary meets (shapely)."""
    rng = np.random.default_rng(seed_value)
    vertices = star_polygon(rng, radius=rng.uniform(5.0, 80.0))
    poly = Polygon(vertices)
    step = rng.uniform(6.0, 15.0)
    xe = -100.0 + step * np.arange(int(200 / step) + 1)
    ye = -100.0 + step * np.arange(int(200 / step) + 1)
    touched = poly.cells_touched(xe, ye)
    reference = shapely.Polygon(vertices)
    boundary = reference.boundary
    for i in range(len(ye) - 1):
        for j in range(len(xe) - 1):
            cell = shapely.box(xe[j], ye[i], xe[j + 1], ye[i + 1])
            assert touched[i, j] == cell.intersects(boundary), (i, j)
            if not touched[i, j]:
                inside = poly.contains(0.5 * (xe[j] + xe[j + 1]), 0.5 * (ye[i] + ye[i + 1]))
                assert math.isclose(reference.intersection(cell).area / cell.area, float(inside), abs_tol=1e-12)


def test_contains_matches_shapely():
    rng = np.random.default_rng(3)
    vertices = star_polygon(rng, n=9)
    points = rng.uniform(-110.0, 110.0, (5000, 2))
    expected = shapely.contains_xy(shapely.Polygon(vertices), points[:, 0], points[:, 1])
    np.testing.assert_array_equal(Polygon(vertices).contains(points[:, 0], points[:, 1]), expected)


@seed(20261127)
@SWEEP
@given(st.integers(0, 2**32 - 1), st.sampled_from([1e-6, 1e-3, 1.0, 100.0, 1e4]))
def test_inverse_cube_integral_along_a_segment_matches_quadrature(seed_value, lateral):
    """int ds / r^3 along a segment, at points abreast, beyond either end and nearly on the line
    (lateral distances 1e-6 to 1e4 m from the line), equals SciPy's quad of the integrand in
    the segment's own coordinate to 1e-9 relative (quad's own tolerance is set to 1e-12; the
    closed form has no cancellation, which the near-line points check), plus the rounding of the
    test points' own coordinates, which moves a lateral distance of 1e-6 m by 1e-13 m."""
    rng = np.random.default_rng(seed_value)
    a = rng.uniform(-1e3, 1e3, 2)
    b = a + rng.uniform(-2e3, 2e3, 2)
    length = float(np.hypot(*(b - a)))
    u = (b - a) / length
    normal = np.array([-u[1], u[0]])
    along = rng.uniform(-0.5 * length, 1.5 * length, 20)
    along = along[np.abs(along) > 1e-3 * length]  # not at an end (the integrand's pole) for the oracle
    points = a + along[:, None] * u + lateral * normal
    got = segment_inverse_cube(points, a, b)
    for p, s, value in zip(points, along, got):
        # q = s + x sinh(u): ds / r^3 = du / (x^2 cosh^2 u), smooth however small x is
        lo, hi = math.asinh((0.0 - s) / lateral), math.asinh((length - s) / lateral)
        expected = integrate.quad(lambda v: 1.0 / (lateral * math.cosh(v)) ** 2, lo, hi,
                                  epsabs=0.0, epsrel=1e-12, limit=500, points=[0.0] if lo < 0.0 < hi else None)[0]
        # the point's coordinates round by eps |p|, which moves a lateral distance x by that much
        # and the integral (~ 1 / x^2) by twice that relative
        rounding = 2.0 * 4.0 * np.finfo(float).eps * float(np.max(np.abs(p))) / lateral
        assert math.isclose(value, expected, rel_tol=1e-9 + rounding), (p, value, expected)


def test_inverse_cube_on_the_line():
    """On the segment the integral is infinite; on its line beyond an end, (1/s1^2 - 1/s2^2) / 2."""
    a, b = np.array([0.0, 0.0]), np.array([10.0, 0.0])
    got = segment_inverse_cube(np.array([[5.0, 0.0], [0.0, 0.0], [-2.0, 0.0], [14.0, 0.0]]), a, b)
    assert np.isinf(got[0]) and np.isinf(got[1])
    assert math.isclose(got[2], 0.5 * (1 / 4 - 1 / 144), rel_tol=1e-15)
    assert math.isclose(got[3], 0.5 * (1 / 16 - 1 / 196), rel_tol=1e-15)


def test_distance_to_track():
    track = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    points = np.array([[5.0, 3.0], [-4.0, 3.0], [13.0, 5.0], [12.0, 14.0]])
    np.testing.assert_allclose(distance_to_track(points, track), [3.0, 5.0, 3.0, math.hypot(2.0, 4.0)], rtol=1e-15)


def test_contains_on_a_grid_is_contains_at_its_points():
    """The row-by-row scan gives the point test's answer at every grid point (even-odd rule, the
    same crossing arithmetic), for polygons of few and many vertices."""
    rng = np.random.default_rng(5)
    for n in (4, 9, 400):
        poly = Polygon(star_polygon(rng, n=n))
        x, y = np.linspace(-120.0, 120.0, 181), np.linspace(-110.0, 115.0, 157)
        np.testing.assert_array_equal(poly.contains_grid(x, y), poly.contains(x[None, :], y[:, None]))
