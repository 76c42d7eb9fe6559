"""Polar-banana approximations (Sections 2 and 5) against the scipy.stats oracle in ``oracles``."""

import math

import numpy as np
import pytest
from scipy import stats as _stats

import bananagrid as bg
import oracles

from cases import FIG1, FIG1_BOUNDS

ORACLE_ARGS = dict(v0=FIG1["v0"], t=FIG1["t"], sigma_a=FIG1["sigma_a"], sigma_w=FIG1["sigma_omega"])


def test_p_mu_and_p_sigma_match_eqs_8_and_11():
    model = bg.PolarBanana(**FIG1)
    phi = np.linspace(-math.pi, math.pi, 2001)
    mu, sd = oracles.polar_mu_sigma(phi, variant="improved", **ORACLE_ARGS)
    # same closed forms evaluated in another order: agreement to a few ulps of v0 t = 2800 m
    np.testing.assert_allclose(model.p_mu(phi), mu, rtol=1e-13, atol=1e-10)
    np.testing.assert_allclose(model.p_sigma(phi), sd, rtol=1e-13, atol=1e-10)


def test_p_mu_at_zero_and_known_values():
    """At phi = 0, eq. (8) gives v0 t - sigma_a^2 t^3 / (12 v0) (sinc = scc = 1) and eq. (11)
    gives sigma_a t^2 / 2 (1 + sigma_a^2 t^2 / (72 v0^2))."""
    model = bg.PolarBanana(**FIG1)
    v0, t, sa = FIG1["v0"], FIG1["t"], FIG1["sigma_a"]
    assert model.p_mu(0.0) == pytest.approx(v0 * t - sa**2 * t**3 / (12 * v0), rel=1e-15)
    assert model.p_sigma(0.0) == pytest.approx(sa * t**2 / 2 * (1 + sa**2 * t**2 / (72 * v0**2)), rel=1e-15)


@pytest.mark.parametrize("variant", ["rough", "improved"])
def test_density_matches_oracle(variant):
    grid = bg.Grid.from_bounds(**FIG1_BOUNDS, step=10.0)
    got = bg.rasterise(bg.PolarBanana(**FIG1, variant=variant), grid).values
    xx, yy = np.meshgrid(grid.x, grid.y)
    want = oracles.polar_density(xx, yy, variant=variant, **ORACLE_ARGS)
    inside = want >= 1e-12
    # exp of an argument up to ~60 amplifies its rounding (1e-16 relative) to ~1e-14
    np.testing.assert_allclose(got[inside], want[inside], rtol=1e-12)
    assert np.abs(got - want).max() < 1e-12 * want.max()


def test_improved_density_is_zero_where_p_sigma_is_not_positive():
    with pytest.warns(UserWarning):
        model = bg.PolarBanana(v0=10.0, t=1.0, sigma_a=5.0, sigma_omega=0.1)
    limit = model.sigma_positive_limit
    phi = np.array([0.5 * limit, 1.5 * limit])
    r = 9.0
    dens = model.pdf(r * np.sin(phi), r * np.cos(phi))
    assert dens[0] > 0 and dens[1] == 0.0
    # the sampler never draws there
    pts = model.sample(20000, np.random.default_rng(1))
    assert np.all(np.abs(np.arctan2(pts[:, 0], pts[:, 1])) <= limit)


def test_sample_support_and_moments():
    model = bg.PolarBanana(**FIG1, variant="rough")
    pts = model.sample(200_000, np.random.default_rng(11))
    phi = np.arctan2(pts[:, 0], pts[:, 1])
    # phi ~ N(0, sigma_omega t / 2) (its tail beyond pi is 1e-27): SD within 4 standard errors
    sigma_phi = FIG1["sigma_omega"] * FIG1["t"] / 2
    assert abs(phi.std() / sigma_phi - 1) < 4 / math.sqrt(2 * len(phi))


def test_sample_with_a_turn_far_beyond_a_full_circle():
    """sigma_omega t = 1e4 rad: rejecting |phi| > pi would keep 2.5e-4 of the draws (and
    1e-12 of them at sigma_omega t = 1e12, for ever); the angle is drawn from its law truncated
    to [-pi, pi] instead, here uniform on it to within 1e-7."""
    model = bg.PolarBanana(v0=1.0, t=1e4, sigma_a=1e-3, sigma_omega=1.0)
    pts = model.sample(20_000, np.random.default_rng(3))
    bearing = np.arctan2(pts[:, 0], pts[:, 1])
    assert np.all(np.isfinite(pts)) and np.all(np.abs(bearing) <= np.pi)
    assert _stats.kstest(bearing, _stats.uniform(loc=-np.pi, scale=2 * np.pi).cdf).pvalue > 1e-3
