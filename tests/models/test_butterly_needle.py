"""Butterly with a needle start: correlations from 0.9 to within 1e-8 of 1, r / sigma_min up to
1e4, against the long-double oracle with an exact Cholesky factor (``butterly_oracle``).

Near the cusps of the astroid on the whitened major axis (a -> +-4F, b -> 0) the course
integrand has two mirror-image peaks a hair apart; the kernel's Newton for the second stopped
on a tolerance scaled by F instead of by its own multiplier (|mu| ~ |b| << F), anchored its walk
far from the peak, and lost it: half the density. And the start's smallest eigenvalue, from a
float64 determinant, was a relative eps / (1 - rho^2) off (1e-8 at rho = 1 - 1e-8).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import bananagrid as bg
from butterly_oracle import needle_density

#: The docs' accuracy statement: relative error 1e-9 wherever the density is a normal
#: float64 number.
RTOL = 1e-9
TINY = np.finfo(float).tiny


def frame(cov):
    """(sigma_min, sigma_max, q1, q2): the start's SDs and unit axes (q1 the narrow one), by
    numpy's eigh (only to place the test points; the oracle does not use it)."""
    values, vectors = np.linalg.eigh(np.asarray(cov, dtype=float))
    return math.sqrt(values[0]), math.sqrt(values[1]), vectors[:, 0], vectors[:, 1]


def cusp_points(mean, cov, r, rng):
    """Points whose course integrand has two close peaks: in whitened coordinates z with
    a = rho1 z1 = +-4F (1 - eps), b = rho2 z2 tiny (rho_k = r / sigma_k, 4F = rho1^2 - rho2^2),
    eps from 1e-1 (peaks 0.9 rad apart) to 1e-3; and points on and near the ring."""
    s_min, s_max, q1, q2 = frame(cov)
    rho1, rho2 = r / s_min, r / s_max
    four_f = (rho1 - rho2) * (rho1 + rho2)
    out = []
    for eps in (1e-1, 1e-2, 1e-3):
        for b in (0.0, 1e-6, 1e-2, 1.0):
            side = rng.choice([-1.0, 1.0])
            z1, z2 = side * four_f * (1.0 - eps) / rho1, rng.choice([-1.0, 1.0]) * b / max(rho2, 1e-300)
            out.append(np.asarray(mean) + z1 * s_min * q1 + z2 * s_max * q2)
    courses = rng.uniform(0.0, 2 * math.pi, 4)
    ring = np.column_stack((np.sin(courses), np.cos(courses)))
    out.extend(np.asarray(mean) + (r + rng.normal(size=4)[:, None] * 2 * s_min) * ring)
    return np.array(out)


@st.composite
def needles(draw):
    """A start N(mean, R(phi) [[sx^2, rho sx sy], [rho sx sy, sy^2]] R(phi)^T) with rho = +-(1 -
    m 10^-k), k = 1..8, m in [1, 9.9] (or an exact value within 1e-8 of +-1), 1-2 speeds with
    r / sigma_min from 0.1 to 1e4."""
    k = draw(st.integers(1, 8))
    rho = draw(st.one_of(
        st.floats(1.0, 9.9).map(lambda m: 1.0 - m * 10.0**-k),
        st.sampled_from([0.99999999, 1.0 - 2.0**-27, 0.999999995, 0.9999]),
    )) * draw(st.sampled_from([1.0, -1.0]))
    sx = 10.0 ** draw(st.floats(0.0, 4.0))
    sy = sx * 10.0 ** draw(st.floats(-1.0, 1.0))
    phi = draw(st.floats(0.0, math.pi))
    c, s = math.cos(phi), math.sin(phi)
    rot = np.array([[c, -s], [s, c]])
    cov = rot @ np.array([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]) @ rot.T
    cov = 0.5 * (cov + cov.T)
    mean = (draw(st.floats(-1e4, 1e4)), draw(st.floats(-1e4, 1e4)))
    s_min = frame(cov)[0]
    ratios = [10.0 ** draw(st.floats(-1.0, 4.0)) for _ in range(draw(st.integers(1, 2)))]
    weights = np.array([draw(st.floats(0.1, 1.0)) for _ in ratios])
    return mean, cov, [q * s_min for q in ratios], list(weights / weights.sum()), draw(st.integers(0, 2**32 - 1))


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=needles())
def test_needle_starts_hold_the_readme_accuracy(case):
    """pdf at the cusp points (where the second peak was lost), on and near each speed's ring:
    relative error <= 1e-9 wherever the density is a normal float64 number (the oracle's own
    convergence, n / 2 against n courses, below 1e-11)."""
    mean, cov, ranges, weights, seed = case
    model = bg.Butterly(mean=mean, cov=cov, speeds=ranges, weights=weights, t=1.0)
    rng = np.random.default_rng(seed)
    pts = np.vstack([cusp_points(mean, cov, r, rng) for r in ranges])
    got = model.pdf(pts[:, 0], pts[:, 1])
    want, self_check = needle_density(pts[:, 0], pts[:, 1], mean, cov, ranges, weights)
    normal = want >= TINY
    assert np.max(self_check[normal], initial=0.0) < 1e-11
    rel = np.abs(got[normal] / want[normal] - 1.0)
    assert rel.max(initial=0.0) <= RTOL, (rel.max(), pts[normal][np.argmax(rel)])
    assert np.all(got[~normal] < 1e-290)


@pytest.mark.parametrize("ratio", [100.0, 3000.0])
def test_needle_grid_cells_near_a_cusp(ratio):
    """The same in rasterise's own paths, tiles (rules up to 2048 nodes, r / sigma_min = 100)
    and each cell walking from its peak beyond (3000): a grid about a cusp of a start at
    rho = 1 - 1e-8, against the oracle at 60 cells where the density is above 1e-12 of its peak
    (the docs' grid statement)."""
    sx, sy, rho = 100.0, 250.0, 1.0 - 1e-8
    cov = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
    s_min, s_max, q1, q2 = frame(cov)
    r = ratio * s_min
    model = bg.Butterly(mean=(0.0, 0.0), cov=cov, speeds=[r], t=1.0)
    rho1, rho2 = r / s_min, r / s_max
    centre = (rho1 - rho2) * (rho1 + rho2) * 0.99 / rho1 * s_min * q1 + 1e-3 / rho2 * s_max * q2
    half = 4.0 * s_min
    grid = bg.Grid.from_bounds(x=(centre[0] - half, centre[0] + half), y=(centre[1] - half, centre[1] + half), step=half / 20)
    values = bg.rasterise(model, grid).values
    pick = np.random.default_rng(3).choice(values.size, 60, replace=False)
    rows, cols = np.unravel_index(pick, values.shape)
    want, self_check = needle_density(grid.x[cols], grid.y[rows], (0.0, 0.0), cov, [r], [1.0])
    keep = want > 1e-12 * model.peak_lower_bound()
    assert keep.sum() > 30 and np.max(self_check[keep]) < 1e-11
    assert np.max(np.abs(values[rows, cols][keep] / want[keep] - 1.0)) <= RTOL
