"""CPU lanes: the lane exp, atan2, sqrt and sinc against long double references over their
whole ranges, and the lane polar grid kernel against the scalar one across the parameter domain."""

import math
import warnings

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.kernels import polar
from bananagrid.kernels.lanes import LANES, lane_atan2, lane_exp_neg, lane_sinc_of, lane_sqrt, lanes64

# np.longdouble is the x87 80-bit format here (64-bit mantissa, 11 bits beyond float64): a
# reference whose own error is ~1/2048 ulp of the float64 result.
assert np.finfo(np.longdouble).nmant >= 63


@wp.kernel
def _unary(op: int, xs: wp.array(dtype=lanes64), out: wp.array(dtype=lanes64)):
    k = wp.tid()
    if op == 0:
        out[k] = lane_exp_neg(xs[k])
    elif op == 1:
        out[k] = lane_sqrt(xs[k])


@wp.kernel
def _binary(op: int, xs: wp.array(dtype=lanes64), ys: wp.array(dtype=lanes64), out: wp.array(dtype=lanes64)):
    k = wp.tid()
    if op == 0:
        out[k] = lane_atan2(xs[k], ys[k])
    else:
        out[k] = lane_sinc_of(xs[k], ys[k])


def _lanes(values):
    padded = np.resize(np.asarray(values, dtype=np.float64), -(-len(values) // LANES) * LANES)
    return wp.array(padded.reshape(-1, LANES), dtype=lanes64, device="cpu")


def _run(kernel, op, *args):
    n = len(args[0])
    out = wp.zeros(-(-n // LANES), dtype=lanes64, device="cpu")
    wp.launch(kernel, dim=out.shape[0], inputs=[op, *[_lanes(a) for a in args], out], device="cpu")
    return out.numpy().ravel()[:n]


def _ulps(got, reference):
    """|got - reference| in units of the float64 spacing at the reference."""
    ref64 = reference.astype(np.float64)
    return (np.abs(got.astype(np.longdouble) - reference) / np.spacing(np.abs(ref64)).astype(np.longdouble)).astype(float)


def test_exp_within_3_ulp_over_the_reduced_range_and_the_whole_domain():
    rng = np.random.default_rng(1)
    reduced = rng.uniform(-math.log(2) / 2, math.log(2) / 2, 200_000)
    whole = -np.concatenate([rng.uniform(0, 708, 200_000), np.geomspace(1e-300, 708, 20_000)])
    edges = -np.array([0.0, 5e-324, 1e-17, math.log(2) / 2, math.log(2), 1.0, 700.0, 707.99, 708.0])
    x = np.concatenate([reduced[reduced <= 0], whole, edges])
    got = _run(_unary, 0, x)
    worst = _ulps(got, np.exp(x.astype(np.longdouble))).max()
    assert worst <= 3.0, worst  # measured 2.4 ulp: the Taylor tail (1.7e-16) and 13 roundings
    assert got[x == 0.0].tolist() == [1.0] * int((x == 0.0).sum())


def test_exp_underflows_gradually_like_libm():
    # below -708 the result is subnormal: within one subnormal step (4.9e-324) of NumPy's
    x = -np.concatenate([np.linspace(708.0, 745.1, 5000), [709.78, 744.44, 745.13]])
    got = _run(_unary, 0, x)
    assert np.all(np.abs(got - np.exp(x)) <= 2 * 4.9e-324 + 3 * np.spacing(np.exp(x)))
    assert np.all(got[x > -744.4] > 0)
    x = np.array([-745.21, -746.0, -1e5, -1e300, -np.inf])
    assert _run(_unary, 0, x).tolist() == [0.0] * len(x)  # where libm's exp is 0 as well


def test_sqrt_is_correctly_rounded():
    x = np.concatenate([np.random.default_rng(2).uniform(0, 1e8, 100_000), [0.0, 1e-300, 2.0, 1e300]])
    assert np.array_equal(_run(_unary, 1, x), np.sqrt(x))


def test_atan2_within_2_ulp_everywhere():
    rng = np.random.default_rng(3)
    angle = rng.uniform(-math.pi, math.pi, 200_000)
    radius = 10.0 ** rng.uniform(-200, 200, angle.size)
    x, y = radius * np.sin(angle), radius * np.cos(angle)
    # the reduction's switch (z = 0.66), the diagonals, the axes and signed zeros
    z = np.array([0.0, 1e-300, 0.5, 0.66, np.nextafter(0.66, 1.0), 0.9, 1.0])
    sx = np.concatenate([z, -z, np.ones(7), -np.ones(7), [0.0, -0.0, 0.0, -0.0, 1.0, -1.0]])
    sy = np.concatenate([np.ones(7), -np.ones(7), z, -z, [1.0, 1.0, -1.0, -1.0, 0.0, 0.0]])
    x, y = np.concatenate([x, sx]), np.concatenate([y, sy])
    got = _run(_binary, 0, x, y)
    # a negative zero x counts as +0 (as in the scalar atan2_fast): atan2(-0, -1) = +pi
    reference = np.arctan2(np.where(x == 0, 0.0, x).astype(np.longdouble), y.astype(np.longdouble))
    nonzero = reference != 0
    worst = _ulps(got[nonzero], reference[nonzero]).max()
    assert worst <= 2.0, worst  # measured 1.6 ulp (Cephes' atan: 2.3e-16 relative, then pi - a)
    assert np.all(got[~nonzero] == 0.0)
    assert got[-6:].tolist() == [0.0, 0.0, math.pi, math.pi, math.pi / 2, -math.pi / 2]


def test_sinc_of_matches_the_series_and_the_quotient():
    phi = np.concatenate([np.geomspace(1e-12, 3.1, 50_000), -np.geomspace(1e-12, 3.1, 1000), [0.0]])
    got = _run(_binary, 1, phi, np.sin(phi))
    p = phi.astype(np.longdouble)
    reference = np.where(p == 0, 1, np.sin(p) / np.where(p == 0, 1, p))
    assert np.max(np.abs(got - reference.astype(float))) <= 3e-16  # 1 - phi^2/6 below 1e-4: phi^4/120 < 1e-18


def _scalar_kernel(model, x, y):
    """The density by the scalar kernel (``polar.polar_points``, which the GPU and float32 paths
    run), launched here directly: ``model.pdf`` itself takes the lane kernel in float64."""
    coef = polar.coefficients(model.v0, model.t, model.sigma_a, model.sigma_omega)
    law = polar.ROUGH if model.variant == "rough" else polar.IMPROVED
    xs, ys = (wp.array(np.ascontiguousarray(a, dtype=np.float64).ravel(), dtype=wp.float64, device="cpu") for a in (x, y))
    out = wp.zeros(xs.shape[0], dtype=wp.float64, device="cpu")
    wp.launch(polar.polar_points, dim=xs.shape[0], device="cpu", inputs=[
        xs, ys, 0, wp.array(np.array(coef), dtype=wp.float64, device="cpu"), law, 0,
        wp.array(model.pose.as_array(), dtype=wp.float64, device="cpu"), out])
    return out.numpy().reshape(np.shape(x))


def _centres(grid):
    return np.meshgrid(grid.origin[0] + grid.dx * (np.arange(grid.nx) + 0.5),
                       grid.origin[1] + grid.dy * (np.arange(grid.ny) + 0.5))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    v0=st.floats(0.5, 2000.0), t=st.floats(0.5, 600.0), accel=st.floats(1e-3, 20.0),
    turn=st.floats(1e-4, 1.0), heading=st.floats(-math.pi, math.pi), variant=st.sampled_from(["rough", "improved"]),
    origin=st.tuples(st.floats(-1e5, 1e5), st.floats(-1e5, 1e5)), span=st.floats(0.3, 3.0),
)
def test_lane_grid_matches_the_scalar_kernel_across_the_domain(v0, t, accel, turn, heading, variant, origin, span):
    """rasterise (the lane kernel on the CPU in float64) against pdf (the scalar points
    kernel) at the same cell centres, over speeds, times, noise ratios from 1e-4 to 40, any
    heading and place, and grids from inside the banana to three times its range (the origin,
    r = 0, is on some of them)."""
    sigma_a = accel * v0 / 100.0
    sigma_omega = turn / t
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the improved variant warns where P_sigma can be <= 0
        model = bg.PolarBanana(v0=v0, t=t, sigma_a=sigma_a, sigma_omega=sigma_omega, variant=variant,
                               pose=bg.Pose(origin=origin, heading=heading))
    reach = span * v0 * t
    grid = bg.Grid.from_bounds(x=(origin[0] - reach, origin[0] + reach), y=(origin[1] - reach, origin[1] + reach),
                               step=2 * reach / 157)
    lanes = bg.rasterise(model, grid, threads=1)
    assert lanes.provenance["kernel"] == "polar_lanes.polar_grid_lanes"
    x, y = _centres(grid)
    scalar = _scalar_kernel(model, x, y)
    assert np.array_equal(model.pdf(x, y), lanes.values)  # the points take the same lanes
    peak = scalar.max()
    inside = scalar >= 1e-10 * peak
    if peak > 0:
        rel = np.abs(lanes.values[inside] - scalar[inside]) / scalar[inside]
        kappa = _condition(model, x[inside] - origin[0], y[inside] - origin[1], heading)
        # 1e-13 where the formula is well conditioned; where P_sigma nears its zero (scc(phi) -> 0)
        # the density itself is ill conditioned and each kernel's own error grows like eps kappa
        # (both measured against mpmath at 1e-13 - 2e-13 there); 300 random cases reached 13.7 eps kappa
        assert np.all(rel <= 1e-13 + 64 * EPS * kappa), (rel.max(), (rel / (EPS * kappa)).max())
    assert np.all(np.abs(lanes.values[~inside] - scalar[~inside]) <= 1e-13 * max(peak, 1e-300))


EPS = np.finfo(np.float64).eps


def _condition(model, dx, dy, heading):
    """How much a relative rounding of the inputs of the density's exponent is amplified:
    (1 + |z_r|) (r + |mu|) / |sd| + z_phi^2, with mu, sd of (8), (11) (or the rough law) at
    the cell's phi, computed here in float64 from the paper's formulas."""
    c, s = math.cos(heading), math.sin(heading)
    x, y = dx * c - dy * s, dx * s + dy * c  # world offset to the local frame (as Pose.to_world inverts)
    r, phi = np.hypot(x, y), np.arctan2(x, y)
    sigma_phi = model.sigma_omega * model.t / 2
    sinc = np.where(phi == 0, 1.0, np.sin(phi) / np.where(phi == 0, 1.0, phi))
    mu, sd = model.v0 * model.t * sinc, np.full_like(phi, model.sigma_a * model.t**2 / 2)
    if model.variant == "improved":
        scc = (4 * sinc - np.cos(phi)) / 3
        mu = mu + model.sigma_a**2 * model.t**3 / (12 * model.v0) * ((phi / sigma_phi) ** 2 - 1) * scc
        sd = sd * (1 + model.sigma_a**2 / (6 * model.v0**2) * (model.t**2 / 12 - phi**2 / model.sigma_omega**2)) * scc
    z_r = (r - mu) / sd
    return (1 + np.abs(z_r)) * (r + np.abs(mu)) / np.abs(sd) + (phi / sigma_phi) ** 2


@pytest.mark.parametrize("variant", ["rough", "improved"])
def test_lane_grid_at_the_origin_and_past_the_improved_domain(variant):
    # a grid centred on the origin (r = 0 at a cell centre) and reaching angles where the improved
    # P_sigma is negative: 0 in both kernels there
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = bg.PolarBanana(v0=10.0, t=60.0, sigma_a=2.0, sigma_omega=0.05, variant=variant)
    grid = bg.Grid(origin=(-400.5, -400.5), dx=1.0, dy=1.0, nx=801, ny=801)
    lanes = bg.rasterise(model, grid, threads=2)
    x, y = _centres(grid)
    scalar = _scalar_kernel(model, x, y)
    assert np.array_equal(model.pdf(x, y), lanes.values)  # the points take the same lanes
    assert lanes.values[400, 400] == 0.0 and scalar[400, 400] == 0.0
    assert np.array_equal(lanes.values == 0.0, scalar == 0.0)
    inside = scalar >= 1e-10 * scalar.max()
    assert np.max(np.abs(lanes.values[inside] - scalar[inside]) / scalar[inside]) <= 1e-13
