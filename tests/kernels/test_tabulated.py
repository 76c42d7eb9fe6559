"""The padded lattice the interpolating kernel reads (``kernels/tabulated.py``'s ``pad_table``), and
the kernel at the seams the padding replaces (the bearing wrap at +-pi, the mirror through the fix)."""

import math

import numpy as np
import pytest

from bananagrid.kernels import tabulated
from bananagrid.models import _cat_heading as heading


@pytest.mark.parametrize("mirror", [False, True])
def test_pad_table_wraps_bearings_and_mirrors_row_one(mirror):
    rng = np.random.default_rng(5)
    values = rng.uniform(size=(7, 12))
    padded = tabulated.pad_table(values, mirror)
    n_theta = values.shape[1]
    assert padded.shape == (8, n_theta + tabulated.PAD_BEFORE + tabulated.PAD_AFTER)
    for c in range(padded.shape[1]):
        j = (c - tabulated.PAD_BEFORE) % n_theta
        assert np.array_equal(padded[1:, c], values[:, j])
        # lattice row -1: p(-r, theta) = p(r, theta + pi) where the lattice mirrors
        assert padded[0, c] == (values[1, (j + n_theta // 2) % n_theta] if mirror else values[0, j])


@pytest.mark.parametrize("mirror", [False, True])
def test_interpolation_is_periodic_and_exact_for_log_cubics(mirror):
    """log p cubic in r and constant in theta, read across the bearings' seam at +-pi (either side
    of it): the kernel reproduces the cubic to rounding; within a step of the fix of a mirrored
    lattice it interpolates row -1 = row 1 (the same |r|)."""
    n_r, n_theta = 10, 16
    r0 = 0.0 if mirror else 5.0
    radii = r0 + np.arange(n_r)
    logs = 0.1 * radii - 0.02 * radii**2 + 0.001 * radii**3
    table = heading.HeadingTable(np.repeat(np.exp(logs)[:, None], n_theta, axis=1), r0, 1.0, -math.pi,
                                 2.0 * math.pi / n_theta, mirror, 0.0, 0)
    r = np.linspace(r0 + 1.0, r0 + n_r - 3.0, 37)
    for eps in (0.0, 1e-12, -1e-12):
        theta = math.pi + eps
        got = heading.interpolate_table(table, r * math.sin(theta), r * math.cos(theta))
        want = np.exp(0.1 * r - 0.02 * r**2 + 0.001 * r**3)
        # the stencil reproduces cubics; the rest is rounding of a few terms of size ~1
        np.testing.assert_allclose(got, want, rtol=1e-13)
        if mirror:  # within a step of the fix: the cubic through rows 1, 0, 1, 2 at nodes -1 .. 2
            f = np.linspace(0.0, 0.9, 10)
            near = heading.interpolate_table(table, f * math.sin(theta), f * math.cos(theta))
            w = [-f * (f - 1) * (f - 2) / 6, (f + 1) * (f - 1) * (f - 2) / 2, -(f + 1) * f * (f - 2) / 2,
                 (f + 1) * f * (f - 1) / 6]
            np.testing.assert_allclose(near, np.exp(sum(wk * logs[k] for wk, k in zip(w, (1, 0, 1, 2)))),
                                       rtol=1e-13)
