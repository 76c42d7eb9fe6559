"""CPU lanes: the lane exp, atan2, sqrt, sinc, reciprocal and reciprocal square root against long
double references over their whole ranges, the reciprocal-based quotient against the division's
bits, and the lane polar grid kernel against the scalar one across the parameter domain."""

import math
import warnings
from typing import Any

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.kernels import bearing, cat, polar
from bananagrid.kernels.common import TAN_PI_8, atan2_one_division
from bananagrid.kernels.lanes import (
    LANES32, LANES64, lane_atan2, lane_atan2_one_division, lane_cos, lane_exp, lane_quotient, lane_reciprocal,
    lane_rsqrt, lane_sin, lane_sinc_of, lane_sqrt, lanes32, lanes64,
)

from cat_lane_roots import lane_roots_agree

# np.longdouble is the x87 80-bit format here (64-bit mantissa, 11 bits beyond float64): a
# reference whose own error is ~1/2048 ulp of the float64 result.
assert np.finfo(np.longdouble).nmant >= 63

FORMATS = {np.float64: (lanes64, LANES64), np.float32: (lanes32, LANES32)}


@wp.kernel
def _unary(op: int, xs: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    k = wp.tid()
    if op == 0:
        out[k] = lane_exp(xs[k])
    elif op == 1:
        out[k] = lane_sqrt(xs[k])
    elif op == 2:
        out[k] = lane_sin(xs[k])
    elif op == 3:
        out[k] = lane_cos(xs[k])
    elif op == 4:
        out[k] = lane_reciprocal(xs[k])
    else:
        out[k] = lane_rsqrt(xs[k])


@wp.kernel
def _binary(op: int, xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    k = wp.tid()
    if op == 0:
        out[k] = lane_atan2(xs[k], ys[k])
    elif op == 3:
        out[k] = lane_atan2_one_division(xs[k], ys[k])
    elif op == 1:
        out[k] = lane_sinc_of(xs[k], ys[k])
    else:
        out[k] = lane_quotient(xs[k], ys[k])


for _lane_type, _ in FORMATS.values():
    wp.overload(_unary, {"xs": wp.array(dtype=_lane_type), "out": wp.array(dtype=_lane_type)})
    wp.overload(_binary, {"xs": wp.array(dtype=_lane_type), "ys": wp.array(dtype=_lane_type),
                          "out": wp.array(dtype=_lane_type)})


def _run(kernel, op, *args, dtype=np.float64):
    """``kernel`` (op) over the values ``args`` in lanes of ``dtype``."""
    lane_type, width = FORMATS[dtype]
    n = len(args[0])
    groups = -(-n // width)
    arrays = [wp.array(np.resize(np.asarray(a, dtype=dtype), groups * width).reshape(-1, width), dtype=lane_type,
                       device="cpu") for a in args]
    out = wp.zeros(groups, dtype=lane_type, device="cpu")
    wp.launch(kernel, dim=groups, inputs=[op, *arrays, out], device="cpu")
    return out.numpy().ravel()[:n]


def _ulps(got, reference, dtype=np.float64):
    """|got - reference| in units of the ``dtype`` spacing at the reference."""
    spacing = np.spacing(np.abs(reference.astype(dtype))).astype(np.longdouble)
    return (np.abs(got.astype(np.longdouble) - reference) / spacing).astype(float)


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


def test_exp_of_positive_arguments_and_overflow():
    # the bearing kernel's log density can be positive (a fix sharper than 1 / (2 pi) m^2)
    x = np.concatenate([np.random.default_rng(5).uniform(0, 709.78, 200_000), [1e-300, 1.0, 700.0, 709.78]])
    worst = _ulps(_run(_unary, 0, x), np.exp(x.astype(np.longdouble))).max()
    assert worst <= 3.0, worst  # the same reduction and polynomial as below 0 (measured 2.4)
    over = np.array([709.7828, 710.0, 1e5, np.inf])
    assert _run(_unary, 0, over).tolist() == [np.inf] * 4
    assert np.isnan(_run(_unary, 0, np.array([np.nan])))[0]
    x32 = np.random.default_rng(6).uniform(0, 88.72, 100_000).astype(np.float32)
    worst = _ulps(_run(_unary, 0, x32, dtype=np.float32), np.exp(x32.astype(np.longdouble)), np.float32).max()
    assert worst <= 2.0, worst
    assert _run(_unary, 0, np.array([88.73, 1e4], dtype=np.float32), dtype=np.float32).tolist() == [np.inf] * 2


def test_exp_underflows_gradually_like_libm():
    # below -708 the result is subnormal: within one subnormal step (4.9e-324) of NumPy's
    x = -np.concatenate([np.linspace(708.0, 745.1, 5000), [709.78, 744.44, 745.13]])
    got = _run(_unary, 0, x)
    assert np.all(np.abs(got - np.exp(x)) <= 2 * 4.9e-324 + 3 * np.spacing(np.exp(x)))
    assert np.all(got[x > -744.4] > 0)
    x = np.array([-745.21, -746.0, -1e5, -1e300, -np.inf])
    assert _run(_unary, 0, x).tolist() == [0.0] * len(x)  # where libm's exp is 0 as well


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_sin_and_cos_over_the_heading_range(dtype):
    # the heading kernels take them at theta_bar in [-pi, pi]: quadrant edges, zeros, tiny angles
    rng = np.random.default_rng(7)
    edges = np.array([0.0, 1e-300, 1e-8, math.pi / 4, math.pi / 2, 3 * math.pi / 4, math.pi, 2.0, 3.0])
    x = np.concatenate([rng.uniform(-math.pi, math.pi, 200_000), edges, -edges]).astype(dtype)
    xl = x.astype(np.longdouble)
    for op, reference in ((2, np.sin(xl)), (3, np.cos(xl))):
        got = _run(_unary, op, x, dtype=dtype)
        # within 2 units of the format's spacing at 1 (an absolute bound: the law takes sin and
        # cos in sums with terms of order 1), and within 2 ulp relative away from the zeros
        eps = np.finfo(dtype).eps
        assert np.max(np.abs(got - reference)) <= 2 * eps / 2, np.max(np.abs(got - reference)) / eps
        away = np.abs(reference) > 0.1
        worst = _ulps(got[away], reference[away], dtype).max()
        assert worst <= 2.0, worst


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


@wp.kernel
def _scalar_angle(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    k = wp.tid()
    out[k] = atan2_one_division(xs[k], ys[k])


for _scalar in (wp.float64, wp.float32):
    wp.overload(_scalar_angle, {"xs": wp.array(dtype=_scalar), "ys": wp.array(dtype=_scalar),
                                "out": wp.array(dtype=_scalar)})


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_one_division_atan2_within_3_ulp_everywhere(dtype):
    """The polar kernels' angle (``common.atan2_one_division``, scalar, and its lane steps) against
    long double over every direction and 10^+-(decades) radii, the reduction's switch lo = tan(pi/8) hi
    and its neighbours, the diagonals, axes and signed zeros; the lanes (fused multiply-adds in R)
    within 1 ulp of the scalar function."""
    rng = np.random.default_rng(13)
    decades = 200 if dtype == np.float64 else 15
    angle = rng.uniform(-math.pi, math.pi, 200_000)
    radius = 10.0 ** rng.uniform(-decades, decades, angle.size)
    x, y = radius * np.sin(angle), radius * np.cos(angle)
    switch = np.array([TAN_PI_8, np.nextafter(TAN_PI_8, 0.0), np.nextafter(TAN_PI_8, 1.0), 0.5, 1.0, 0.0, 1e-30])
    ones = np.ones(switch.size)
    sx = np.concatenate([switch, -switch, ones, -ones, [0.0, -0.0, 0.0, -0.0, 1.0, -1.0, 0.0]])
    sy = np.concatenate([ones, -ones, switch, -switch, [1.0, 1.0, -1.0, -1.0, 0.0, 0.0, 0.0]])
    x, y = np.concatenate([x, sx]).astype(dtype), np.concatenate([y, sy]).astype(dtype)
    scalar_type = wp.float64 if dtype == np.float64 else wp.float32
    out = wp.zeros(x.size, dtype=scalar_type, device="cpu")
    wp.launch(_scalar_angle, dim=x.size, device="cpu", inputs=[wp.array(x, dtype=scalar_type, device="cpu"),
                                                               wp.array(y, dtype=scalar_type, device="cpu"), out])
    scalar = out.numpy()
    lanes = _run(_binary, 3, x, y, dtype=dtype)
    # a negative zero x counts as +0: atan2(-0, -1) = +pi
    reference = np.arctan2(np.where(x == 0, 0.0, x).astype(np.longdouble), y.astype(np.longdouble))
    nonzero = reference != 0
    for got in (scalar, lanes):
        worst = _ulps(got[nonzero], reference[nonzero], dtype).max()
        # measured 2.44 ulp (float64) and 2.81 (float32), both just above the switch, where
        # lo - hi and lo + hi round and pi / 4 + atan(w) cancels a little
        assert worst <= 3.0, worst
        assert np.all(got[~nonzero] == 0.0)
        assert got[-7:].tolist() == [0.0, 0.0, dtype(math.pi), dtype(math.pi), dtype(math.pi / 2),
                                     dtype(-math.pi / 2), 0.0]
    assert _ulps(lanes, scalar.astype(np.longdouble), dtype).max() <= 1.0  # R's roundings, damped by w s


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_one_division_atan2_of_subnormal_pairs(dtype):
    """Points a subnormal distance from the origin (a cell centre a few ulps from a pose at 0):
    the lane steps scale the pair by a power of two before the quotient (a subnormal divisor's
    reciprocal estimate is inf), so the angle is as accurate as anywhere (3 ulp: the test above),
    never NaN. (The scalar float32 function loses bits there: measured 10 ulp from the lanes.)"""
    rng = np.random.default_rng(14)
    tiny = float(np.finfo(dtype).tiny)
    angle = rng.uniform(-math.pi, math.pi, 20_000)
    radius = tiny * 2.0 ** rng.uniform(-20.0, 1.0, angle.size)  # below the least normal, and a little above
    x, y = (radius * np.sin(angle)).astype(dtype), (radius * np.cos(angle)).astype(dtype)
    keep = (x != 0) & (y != 0)
    x, y = x[keep], y[keep]
    scalar_type = wp.float64 if dtype == np.float64 else wp.float32
    out = wp.zeros(x.size, dtype=scalar_type, device="cpu")
    wp.launch(_scalar_angle, dim=x.size, device="cpu", inputs=[wp.array(x, dtype=scalar_type, device="cpu"),
                                                               wp.array(y, dtype=scalar_type, device="cpu"), out])
    lanes = _run(_binary, 3, x, y, dtype=dtype)
    reference = np.arctan2(x.astype(np.longdouble), y.astype(np.longdouble))
    assert np.isfinite(lanes).all()
    assert _ulps(lanes, reference, dtype).max() <= 3.0
    assert np.isfinite(out.numpy()).all()


def test_sinc_of_matches_the_series_and_the_quotient():
    phi = np.concatenate([np.geomspace(1e-12, 3.1, 50_000), -np.geomspace(1e-12, 3.1, 1000), [0.0]])
    got = _run(_binary, 1, phi, np.sin(phi))
    p = phi.astype(np.longdouble)
    reference = np.where(p == 0, 1, np.sin(p) / np.where(p == 0, 1, p))
    assert np.max(np.abs(got - reference.astype(float))) <= 3e-16  # 1 - phi^2/6 below 1e-4: phi^4/120 < 1e-18


def test_float32_exp_atan2_sqrt_and_sinc():
    rng = np.random.default_rng(4)
    x = -np.concatenate([rng.uniform(0, 87.3, 200_000), rng.uniform(0, math.log(2) / 2, 100_000), [0.0, 1e-30]])
    x = x.astype(np.float32)
    worst = _ulps(_run(_unary, 0, x, dtype=np.float32), np.exp(x.astype(np.longdouble)), np.float32).max()
    assert worst <= 2.0, worst  # measured 1.2 ulp: degree 7 (tail 5.3e-9 = 0.09 ulp) and 9 roundings
    tiny = -np.array([87.4, 95.0, 103.0, 103.9, 104.1, 200.0], dtype=np.float32)  # subnormal, then 0
    assert np.all(np.abs(_run(_unary, 0, tiny, dtype=np.float32) - np.exp(tiny)) <= 2 * 1.5e-45)
    angle = rng.uniform(-math.pi, math.pi, 200_000)
    radius = 10.0 ** rng.uniform(-15, 15, angle.size)
    ax, ay = (radius * np.sin(angle)).astype(np.float32), (radius * np.cos(angle)).astype(np.float32)
    reference = np.arctan2(ax.astype(np.longdouble), ay.astype(np.longdouble))
    worst = _ulps(_run(_binary, 0, ax, ay, dtype=np.float32), reference, np.float32).max()
    assert worst <= 2.0, worst  # measured 1.6 ulp
    r = rng.uniform(0, 1e6, 10_000).astype(np.float32)
    assert np.array_equal(_run(_unary, 1, r, dtype=np.float32), np.sqrt(r))
    phi = np.geomspace(1e-8, 3.1, 10_000).astype(np.float32)
    got = _run(_binary, 1, phi, np.sin(phi), dtype=np.float32)
    assert np.max(np.abs(got - np.sin(phi.astype(float)) / phi)) <= 2e-7  # float32 sin and / (each <= 6e-8)


def _spread(rng, n, dtype, decades):
    """n positive values of ``dtype`` spread over ``decades`` decades each side of 1, with
    significands uniform on [1, 2)."""
    return (rng.uniform(1.0, 2.0, n) * 10.0 ** rng.uniform(-decades, decades, n)).astype(dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_quotient_is_the_division_bit_for_bit(dtype):
    # Markstein's correction on the reciprocal: the division's bits (the float64 polar kernel
    # takes the scalar atan2's three quotients this way); significands next to powers of two
    # and all ones (the reciprocal step's exception) included
    rng = np.random.default_rng(11)
    decades = 100 if dtype == np.float64 else 15
    a, b = _spread(rng, 200_000, dtype, decades), _spread(rng, 200_000, dtype, decades)
    a[: a.size // 2] *= -1
    edges = np.array([1.0, 2.0, 3.0, 0.66, 1.66, 10.0], dtype=dtype)
    ones = np.nextafter(edges * 2, dtype(0))  # significands 1.11...1 and neighbours of powers of two
    b = np.concatenate([b, edges, ones, np.nextafter(edges, dtype(4)), ones * 3, ones / 7])
    a = np.concatenate([a, np.resize(_spread(rng, 64, dtype, 3), b.size - a.size)])
    b[::5] = a[::5] + dtype(1)  # the reduction's (z - 1) / (z + 1) shape
    got = _run(_binary, 2, a, b, dtype=dtype)
    assert np.array_equal(got, a / b), int(np.sum(got != a / b))
    assert _run(_binary, 2, np.zeros(3, dtype), np.array([1.0, 3.0, 1e-30], dtype), dtype=dtype).tolist() == [0.0] * 3


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_reciprocal_and_reciprocal_square_root_within_1_ulp(dtype):
    rng = np.random.default_rng(12)
    decades = 300 if dtype == np.float64 else 37
    x = np.concatenate([_spread(rng, 200_000, dtype, decades), np.array([1.0, 2.0, 0.5, 3.0], dtype)])
    xl = x.astype(np.longdouble)
    worst = _ulps(_run(_unary, 4, x, dtype=dtype), 1 / xl, dtype).max()
    assert worst <= 1.0, worst  # Newton's last step from within 2^-28: rounding only (measured below 0.51)
    assert np.array_equal(_run(_unary, 4, -x, dtype=dtype), -_run(_unary, 4, x, dtype=dtype))
    worst = _ulps(_run(_unary, 5, x, dtype=dtype), 1 / np.sqrt(xl), dtype).max()
    assert worst <= 1.5, worst  # (x y) y and y / 2 rounded before the last step (measured below 1.1)
    special = np.array([0.0, np.inf], dtype=dtype)
    assert _run(_unary, 4, special, dtype=dtype).tolist() == [np.inf, 0.0]  # as the division gives
    assert _run(_unary, 5, special, dtype=dtype).tolist() == [np.inf, 0.0]


def _scalar_kernel(model, x, y, dtype=np.float64, inputs=None):
    """The density by the scalar kernel (``polar.KERNELS.points``, which the GPU and heading-noise
    paths run) in ``dtype``, launched here directly (``model.pdf`` itself takes the lane kernel);
    with ``inputs=np.float32`` the coordinates, pose and coefficients are first rounded to
    float32 (what a float32 kernel is given), then computed in ``dtype``."""
    inputs = inputs or dtype
    scalar = wp.float64 if dtype == np.float64 else wp.float32

    def device_array(values):
        rounded = np.ascontiguousarray(values, dtype=inputs).ravel().astype(dtype)
        return wp.array(rounded, dtype=scalar, device="cpu")

    def rounded(values):
        return np.asarray(values, dtype=inputs).astype(dtype)

    coef = polar.coefficients(model.v0, model.t, model.sigma_a, model.sigma_omega, model.sigma_heading)
    params = polar.POLAR.of(scalar)()
    for name, value in zip(polar.COEFFICIENTS, rounded(coef)):
        setattr(params, name, value)
    params.pose = wp.types.vector(4, scalar)(*rounded(model.pose.as_array()))
    params.variant = polar.ROUGH if model.variant == "rough" else polar.IMPROVED
    params.order = model.kernel_order
    xs, ys = device_array(x), device_array(y)
    out = wp.zeros(xs.shape[0], dtype=scalar, device="cpu")
    wp.launch(polar.KERNELS.points, dim=xs.shape[0], device="cpu", inputs=[xs, ys, 0, params, out])
    return out.numpy().reshape(np.shape(x))


@st.composite
def _swept_cases(draw):
    """A polar banana and a 157 x 157 grid about its pose origin, over the domain: speeds 0.5-2000
    m/s, times to 10 min, acceleration noise 1e-3 to 20 % of the speed per second, turn noise
    1e-4 to 1 rad over the time, any heading and place, grids from inside the banana to three
    times its range (the origin, r = 0, is on some of them)."""
    v0, t = draw(st.floats(0.5, 2000.0)), draw(st.floats(0.5, 600.0))
    accel, turn = draw(st.floats(1e-3, 20.0)), draw(st.floats(1e-4, 1.0))
    heading, variant = draw(st.floats(-math.pi, math.pi)), draw(st.sampled_from(["rough", "improved"]))
    origin = draw(st.tuples(st.floats(-1e5, 1e5), st.floats(-1e5, 1e5)))
    reach = draw(st.floats(0.3, 3.0)) * v0 * t
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the improved variant warns where P_sigma can be <= 0
        model = bg.PolarBanana(v0=v0, t=t, sigma_a=accel * v0 / 100.0, sigma_omega=turn / t, variant=variant,
                               pose=bg.Pose(origin=origin, heading=heading))
    grid = bg.Grid.from_bounds(x=(origin[0] - reach, origin[0] + reach), y=(origin[1] - reach, origin[1] + reach),
                               step=2 * reach / 157)
    return model, grid


def _centres(grid):
    return np.meshgrid(grid.origin[0] + grid.dx * (np.arange(grid.nx) + 0.5),
                       grid.origin[1] + grid.dy * (np.arange(grid.ny) + 0.5))


@settings(max_examples=300, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=_swept_cases())
def test_lane_grid_matches_the_scalar_kernel_across_the_domain(case):
    """rasterise (the lane kernel on the CPU in float64) against the scalar kernel at the same
    cell centres over the swept domain. Compared relatively where the density is at least 1e-10 of the peak and a normal
    float64 with headroom (>= 1e-290: a subnormal carries fewer bits than its neighbours)."""
    model, grid = case
    origin, heading = model.pose.origin, model.pose.heading
    lanes = bg.rasterise(model, grid, threads=1)
    assert lanes.provenance["kernel"] == "polar_lanes.polar_grid_lanes"
    x, y = _centres(grid)
    scalar = _scalar_kernel(model, x, y)
    assert np.array_equal(model.pdf(x, y), lanes.values)  # the points take the same lanes
    peak = scalar.max()
    inside = scalar >= max(1e-10 * peak, 1e-290)
    rel = np.abs(lanes.values[inside] - scalar[inside]) / scalar[inside]
    kappa = _condition(model, x[inside] - origin[0], y[inside] - origin[1], heading)
    # 1e-13 where the formula is well conditioned; where P_sigma nears its zero (scc(phi) -> 0)
    # the density itself is ill conditioned and each kernel's own error grows like eps kappa
    # (both measured against mpmath at 1e-13 - 2e-13 there); 300 random cases reached 0.4 eps kappa
    assert np.all(rel <= 1e-13 + 16 * EPS * kappa), (rel.max(), (rel / (EPS * kappa)).max())
    # elsewhere: absolute, and a few subnormal steps (4.9e-324 each) where values underflow
    assert np.all(np.abs(lanes.values[~inside] - scalar[~inside]) <= 1e-13 * peak + 1e-300)


EPS = np.finfo(np.float64).eps
EPS32 = np.finfo(np.float32).eps


def _condition(model, dx, dy, heading):
    """A first-order bound on how much rounding the density's inputs and terms by one unit
    (relative) moves log(density), from (8) and (11) (or the rough law) evaluated here in float64:

        kappa = 1 + (1 + |z_phi|)^2 / sigma_phi
                + [ |z_r| (r + |A sinc| + |K| (z^2 + 1) m) + (1 + z_r^2) |S| (|w| m + |scc| (1 + |c T| + |c phi^2 U|)) ] / |sd|

    with A = v0 t, K = sigma_a^2 t^3 / (12 v0), S = sigma_a t^2 / 2, c = sigma_a^2 / (6 v0^2),
    T = t^2 / 12, U = 1 / sigma_omega^2, w = 1 + c (T - phi^2 U), m = (4 |sinc| + |cos|) / 3 (the
    size of the terms that cancel in scc) and z = phi / sigma_phi. phi is rounded absolutely (the
    rotation to the local frame cancels), every other quantity relative to the terms it sums."""
    c, s = math.cos(heading), math.sin(heading)
    x, y = dx * c - dy * s, dx * s + dy * c  # world offset to the local frame (as Pose.to_world inverts)
    r, phi = np.hypot(x, y), np.arctan2(x, y)
    v0, t, sigma_a, sigma_omega = model.v0, model.t, model.sigma_a, model.sigma_omega
    sigma_phi = sigma_omega * t / 2
    z = phi / sigma_phi
    sinc = np.where(phi == 0, 1.0, np.sin(phi) / np.where(phi == 0, 1.0, phi))
    big_a, big_s = v0 * t, sigma_a * t**2 / 2
    if model.variant == "improved":
        k, curv = sigma_a**2 * t**3 / (12 * v0), sigma_a**2 / (6 * v0**2)
        scc, m = (4 * sinc - np.cos(phi)) / 3, (4 * np.abs(sinc) + np.abs(np.cos(phi))) / 3
        w = 1 + curv * (t**2 / 12 - phi**2 / sigma_omega**2)
        mu, sd = big_a * sinc + k * (z**2 - 1) * scc, big_s * w * scc
        mu_terms = r + np.abs(big_a * sinc) + abs(k) * (z**2 + 1) * m
        sd_terms = big_s * (np.abs(w) * m + np.abs(scc) * (1 + curv * t**2 / 12 + curv * phi**2 / sigma_omega**2))
    else:
        mu, sd = big_a * sinc, np.full_like(phi, big_s)
        mu_terms, sd_terms = r + np.abs(mu), np.full_like(phi, big_s)
    z_r = (r - mu) / sd
    return 1 + (1 + np.abs(z)) ** 2 / sigma_phi + (np.abs(z_r) * mu_terms + (1 + z_r**2) * sd_terms) / np.abs(sd)


@settings(max_examples=150, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=_swept_cases())
def test_float32_lanes_within_the_rounding_of_float32(case):
    """The float32 lane grid against the scalar kernel in float64 on the float32-rounded inputs
    (the error of float32 arithmetic alone; the inputs' own rounding is the same for every
    float32 kernel): within 64 eps32 kappa where the density is at least 1e-6 of the peak (300
    random cases reached 18 eps32 kappa, as did the scalar float32 kernel), and below 4e-6 of the
    peak elsewhere."""
    model, grid = case
    origin, heading = model.pose.origin, model.pose.heading
    try:
        lanes = bg.rasterise(model, grid, dtype=np.float32, threads=1)
    except bg.BananagridError as exc:
        # a cell centre within ~1e-80 m of the origin: 1/r takes the density past float32's range,
        # which rasterise refuses (an error, not inf); float64 shows that it does exceed it
        assert "exceed float32's range" in str(exc)
        assert bg.rasterise(model, grid, threads=1).values.max() > np.finfo(np.float32).max
        assume(False)
    assert lanes.provenance["kernel"] == "polar_lanes.polar_grid_lanes" and lanes.values.dtype == np.float32
    # grids that float32 cannot resolve (cells far smaller than the coordinates' float32 spacing,
    # a cell centre within rounding of the pose origin) are computed in float64: not this test's
    assume(lanes.provenance["computed_in"] == "float32")
    x, y = _centres(grid)
    reference = _scalar_kernel(model, x, y, np.float64, inputs=np.float32)
    peak = reference.max()
    assume(peak >= 1e-20)  # a map whose peak nears float32's underflow (1e-38) is no float32 map
    # the 1/r singularity: a centre within 1e-15 m of the pose origin squares to 0 in float32
    f32 = np.float32
    near_origin = np.hypot(x.astype(f32) - f32(origin[0]), y.astype(f32) - f32(origin[1]), dtype=float) < 1e-15
    inside = (reference >= 1e-6 * peak) & ~near_origin
    rel = np.abs(lanes.values[inside] - reference[inside]) / reference[inside]
    kappa = _condition(model, x[inside] - origin[0], y[inside] - origin[1], heading)
    assert np.all(rel <= 64 * EPS32 * kappa), (rel / (EPS32 * kappa)).max()
    outside = ~inside & ~near_origin
    assert np.abs(lanes.values[outside] - reference[outside]).max(initial=0.0) <= 4e-6 * peak


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("variant", ["rough", "improved"])
def test_lane_grid_at_the_origin_and_past_the_improved_domain(variant, dtype):
    # a grid centred on the origin (r = 0 at a cell centre) and reaching angles where the improved
    # P_sigma is negative: 0 in both kernels there
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = bg.PolarBanana(v0=10.0, t=60.0, sigma_a=2.0, sigma_omega=0.05, variant=variant)
    grid = bg.Grid(origin=(-400.5, -400.5), dx=1.0, dy=1.0, nx=801, ny=801)
    lanes = bg.rasterise(model, grid, threads=2, dtype=dtype)
    x, y = _centres(grid)
    scalar = _scalar_kernel(model, x, y, dtype)
    assert np.array_equal(model.pdf(x, y, dtype=dtype), lanes.values)  # the points take the same lanes
    assert lanes.values[400, 400] == 0.0 and scalar[400, 400] == 0.0
    assert np.array_equal(lanes.values == 0.0, scalar == 0.0)
    inside = scalar >= 1e-10 * scalar.max()
    rel = np.max(np.abs(lanes.values[inside] - scalar[inside]) / scalar[inside])
    assert rel <= (1e-13 if dtype == np.float64 else 1e-4), rel  # float32: FLOAT32_BOUND's scale


def _scalar_bearing(model, x, y, dtype):
    """The bearing density by the scalar kernel (``bearing.KERNELS.points``, the GPU path's),
    launched here directly in ``dtype`` (``model.pdf`` takes the lane kernel on the CPU)."""
    scalar = wp.float64 if dtype == np.float64 else wp.float32
    xs = wp.array(np.ravel(x).astype(dtype), dtype=scalar, device="cpu")
    ys = wp.array(np.ravel(y).astype(dtype), dtype=scalar, device="cpu")
    out = wp.zeros(xs.shape[0], dtype=scalar, device="cpu")
    params = model.bind(WarpContext(dtype, "cpu", 1), None).params  # the struct the lane kernels take
    wp.launch(bearing.KERNELS.points, dim=xs.shape[0], device="cpu", inputs=[xs, ys, 0, params, out])
    return out.numpy().reshape(np.shape(x))


@st.composite
def _bearing_cases(draw):
    """A fix from 2-4 stations 1-50 km from a contact, bearing SDs 1e-4 to 0.2 rad (the observed
    bearings off the true ones by up to 2 SDs), either variant, and a 131 x 127 grid from inside
    the fix's ellipse to 10 times its size."""
    n = draw(st.integers(2, 4))
    target = np.array([draw(st.floats(-1e4, 1e4)), draw(st.floats(-1e4, 1e4))])
    angles = sorted(draw(st.lists(st.floats(0.0, 2 * math.pi), min_size=n, max_size=n)))
    assume(min(np.diff(angles + [angles[0] + 2 * math.pi])) > 0.2)  # stations not in line with the contact
    ranges = [draw(st.floats(1e3, 5e4)) for _ in range(n)]
    sensors = np.array([target + r * np.array([math.sin(a), math.cos(a)]) for a, r in zip(angles, ranges)])
    sigmas = np.array([draw(st.floats(1e-4, 0.2)) for _ in range(n)])
    offsets = np.array([draw(st.floats(-2.0, 2.0)) for _ in range(n)])
    bearings = bg.bearing_to(sensors, target) + offsets * sigmas
    variant = draw(st.sampled_from(["exact", "linear"]))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = bg.BearingFix(sensors=sensors, bearings=bearings, sigmas=sigmas, variant=variant)
    except bg.BananagridError:
        assume(False)  # lines that cross behind a station: no fix to map
    half = draw(st.floats(0.3, 10.0)) * 4.0 * math.sqrt(max(np.linalg.eigvalsh(model.covariance)))
    fx, fy = model.fix
    grid = bg.Grid.from_bounds(x=(fx - half, fx + half), y=(fy - half, fy + half), dx=2 * half / 131, dy=2 * half / 127)
    return model, grid


@settings(max_examples=200, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(case=_bearing_cases())
def test_bearing_lanes_match_the_scalar_kernel_across_the_domain(case):
    """The lane kernels compute the log density with the scalar kernel's roundings, step for step
    (the lane atan2 is ``atan2_fast``'s steps, the wrap the same expression); only the exp
    differs: the lane exp within 3 ulp, libm's within 1, so 4 ulp of relative difference where
    the density is a normal number, a few subnormal steps below. Both dtypes, as rasterise
    computes them."""
    model, grid = case
    x, y = _centres(grid)
    for dtype in (np.float64, np.float32):
        lanes = bg.rasterise(model, grid, dtype=dtype, threads=1)
        assert lanes.provenance["kernel"] == "bearing_lanes.bearing_grid_lanes"
        computed = np.dtype(lanes.provenance["computed_in"]).type
        assert np.array_equal(model.pdf(x, y, dtype=dtype), lanes.values)  # the points take the same lanes
        scalar = _scalar_bearing(model, x, y, computed).astype(dtype)
        eps, tiny = np.finfo(computed).eps, np.finfo(computed).tiny
        normal = scalar >= tiny
        rel = np.abs(lanes.values[normal].astype(float) - scalar[normal]) / scalar[normal]
        assert np.all(rel <= 4 * eps), rel.max() / eps
        assert np.all(np.abs(lanes.values[~normal].astype(float) - scalar[~normal]) <= 4 * tiny * eps)


def _heading_condition(model, dx, dy):
    """``_condition`` with initial-heading noise: how much rounding each input and term by one unit
    moves log(density) to first order, from (15)-(16) at theta_bar (the law's derivatives and
    the moments by the model's scalar kernel):

        kappa = 1 + (1 + |z_theta|)^2 / sigma_theta + [ |z_r| M + (1 + z_r^2) V / (2 SD) ] / SD

    with M = r + |A sinc| + |K| (z^2 + 1) m + |Pm_2| sb2 / 2 + |Pm_4| sb2^2 / 8 (the mean's terms;
    improved only for the K term) and V = 2 |Ps| S_terms + Pm_1^2 sb2 + (Ps_1^2 + |Ps Ps_2|) sb2
    + (Pm_2^2 / 2 + |Pm_1 Pm_3|) sb2^2 (the variance's), S_terms as in ``_condition``."""
    c, s = math.cos(model.pose.heading), math.sin(model.pose.heading)
    x, y = dx * c - dy * s, dx * s + dy * c
    r, theta = np.hypot(x, y), np.arctan2(x, y)
    bar = theta * model.sigma_phi**2 / model.sigma_theta**2
    sb2 = model.sigma_bar**2
    m0, m1, m2, m3, m4, s0, s1, s2 = np.moveaxis(model.law_derivatives(bar), -1, 0)
    mean, sd = model.conditional_moments(theta)
    v0, t, sigma_a, sigma_omega = model.v0, model.t, model.sigma_a, model.sigma_omega
    sinc = np.where(bar == 0, 1.0, np.sin(bar) / np.where(bar == 0, 1.0, bar))
    big_a, big_s = v0 * t, sigma_a * t**2 / 2
    mean_terms = r + np.abs(big_a * sinc) + np.abs(m2) * sb2 / 2 + np.abs(m4) * sb2**2 / 8
    s_terms = np.full_like(bar, big_s)
    if model.variant == "improved":
        z = bar / model.sigma_phi
        k, curv = sigma_a**2 * t**3 / (12 * v0), sigma_a**2 / (6 * v0**2)
        scc, m = (4 * sinc - np.cos(bar)) / 3, (4 * np.abs(sinc) + np.abs(np.cos(bar))) / 3
        w = 1 + curv * (t**2 / 12 - bar**2 / sigma_omega**2)
        mean_terms = mean_terms + abs(k) * (z**2 + 1) * m
        s_terms = big_s * (np.abs(w) * m + np.abs(scc) * (1 + curv * t**2 / 12 + curv * bar**2 / sigma_omega**2))
    var_terms = (2 * np.abs(s0) * s_terms + m1**2 * sb2 + (s1**2 + np.abs(s0 * s2)) * sb2
                 + (m2**2 / 2 + np.abs(m1 * m3)) * sb2**2)
    z_r = (r - mean) / sd
    z_theta = theta / model.sigma_theta
    return (1 + (1 + np.abs(z_theta)) ** 2 / model.sigma_theta
            + (np.abs(z_r) * mean_terms + (1 + z_r**2) * var_terms / (2 * sd)) / sd)


@st.composite
def _heading_cases(draw):
    """A polar banana with initial-heading noise (sigma_0 from 1e-4 to 0.6 rad, order 2 or 4) over
    the swept domain of ``_swept_cases``."""
    model, grid = draw(_swept_cases())
    sigma_heading, order = draw(st.floats(1e-4, 0.6)), draw(st.sampled_from([2, 4]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = bg.PolarBanana(v0=model.v0, t=model.t, sigma_a=model.sigma_a, sigma_omega=model.sigma_omega,
                               variant=model.variant, sigma_heading=sigma_heading, heading_order=order, pose=model.pose)
    return model, grid


@settings(max_examples=200, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=_heading_cases())
def test_heading_lanes_match_the_scalar_kernel_across_the_domain(case):
    """With heading noise the lane kernel computes (15)-(16) with the scalar kernel's own generic
    functions; only sin, cos (lane sine against libm) and exp differ, by a few ulp each, and
    the final product's order. Compared relatively inside 1e-10 of the peak."""
    model, grid = case
    lanes = bg.rasterise(model, grid, threads=1)
    assert lanes.provenance["kernel"] == "polar_lanes.polar_grid_lanes"
    x, y = _centres(grid)
    assert np.array_equal(model.pdf(x, y), lanes.values)  # the points take the same lanes
    scalar = _scalar_kernel(model, x, y)
    peak = scalar.max()
    inside = scalar >= max(1e-10 * peak, 1e-290)
    rel = np.abs(lanes.values[inside] - scalar[inside]) / scalar[inside]
    kappa = _heading_condition(model, x[inside] - model.pose.origin[0], y[inside] - model.pose.origin[1])
    # 1e-13 where well conditioned, and 16 eps kappa where (r - E[r | theta]) / SD cancels: the
    # lane sine and libm's differ by an ulp, which kappa's terms carry (the sweep reached
    # 0.5 eps kappa: up to 1e-12 relative where sigma_a / v0 is 0.005)
    assert np.all(rel <= 1e-13 + 16 * EPS * kappa), (rel / (EPS * kappa)).max()
    assert np.all(np.abs(lanes.values[~inside] - scalar[~inside]) <= 1e-13 * peak + 1e-300)


@settings(max_examples=100, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=_heading_cases())
def test_float32_heading_lanes_within_the_rounding_of_float32(case):
    """As the float32 sweep without heading noise: the float32 lane grid against the scalar
    kernel in float64 on the float32-rounded inputs, within 64 eps32 kappa where the density is
    at least 1e-6 of the peak (100 cases reached 3.8 eps32 kappa)."""
    model, grid = case
    try:
        lanes = bg.rasterise(model, grid, dtype=np.float32, threads=1)
    except bg.BananagridError as exc:  # the 1/r singularity past float32's range, as above
        assert "exceed float32's range" in str(exc)
        assume(False)
    assume(lanes.provenance["computed_in"] == "float32")
    x, y = _centres(grid)
    reference = _scalar_kernel(model, x, y, np.float64, inputs=np.float32)
    peak = reference.max()
    assume(peak >= 1e-20)
    origin = model.pose.origin
    f32 = np.float32
    near_origin = np.hypot(x.astype(f32) - f32(origin[0]), y.astype(f32) - f32(origin[1]), dtype=float) < 1e-15
    inside = (reference >= 1e-6 * peak) & ~near_origin
    rel = np.abs(lanes.values[inside] - reference[inside]) / reference[inside]
    kappa = _heading_condition(model, x[inside] - origin[0], y[inside] - origin[1])
    assert np.all(rel <= 64 * EPS32 * kappa), (rel / (EPS32 * kappa)).max()
    outside = ~inside & ~near_origin
    assert np.abs(lanes.values[outside] - reference[outside]).max(initial=0.0) <= 4e-6 * peak


@st.composite
def _cat_cases(draw):
    """An exact CAT (speeds 1-1000 m/s, times to 10 min, acceleration noise 0.1-20 % of the speed
    per second, turn noise 1e-3 to 1 rad over the time, heading and place anywhere) and a
    41 x 37 grid from inside its banana to twice its range: folds at the larger turn noises."""
    v0, t = draw(st.floats(1.0, 1000.0)), draw(st.floats(1.0, 600.0))
    accel, turn = draw(st.floats(0.1, 20.0)), draw(st.floats(1e-3, 1.0))
    origin = draw(st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4)))
    model = bg.CAT(v0=v0, t=t, sigma_a=accel * v0 / 100.0, sigma_omega=turn / t,
                   pose=bg.Pose(origin=origin, heading=draw(st.floats(-math.pi, math.pi))))
    reach = draw(st.floats(0.3, 2.0)) * v0 * t
    grid = bg.Grid.from_bounds(x=(origin[0] - reach, origin[0] + reach), y=(origin[1] - reach, origin[1] + reach),
                               dx=2 * reach / 41, dy=2 * reach / 37)
    return model, grid


@settings(max_examples=60, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=_cat_cases())
def test_cat_lane_scan_equals_the_scalar_scan(case):
    """The lane scan computes F with the scalar scan's arithmetic and examines the flagged
    intervals with the scalar kernel's own functions, in node order, but for the single roots,
    which the lanes search (``lanes.lane_cat_roots``): rasterise (grid kernel) and pdf (points
    kernel) give the same density to the bit, in both dtypes, and the scalar kernel the same to
    the lane search's rounding (``cat_lane_roots``)."""
    model, grid = case
    x, y = _centres(grid)
    for dtype in (np.float64, np.float32):
        lanes = bg.rasterise(model, grid, dtype=dtype, threads=2)
        computed = np.dtype(lanes.provenance["computed_in"]).type  # float32 far out: float64 (precision)
        ctx = WarpContext(computed, "cpu", 1)
        binding = model.bind(ctx, None, grid=True)
        assert binding.kernel_name == "cat_lanes.cat_grid_lanes"
        out = ctx.zeros(x.size)
        params = cat.CAT.of(ctx.scalar_type)()  # the lane binding's parameters but the node groups
        for name in cat.CAT.fields:
            setattr(params, name, getattr(binding.params, name))
        wp.launch(cat.KERNELS.points, dim=x.size, device="cpu", inputs=[
            ctx.array(x.ravel()), ctx.array(y.ravel()), 0, params, out])
        scalar = out.numpy().reshape(x.shape)
        agree = lane_roots_agree(lanes.values, scalar.astype(dtype))
        assert np.all(agree), (int(np.sum(~agree)), np.abs(lanes.values - scalar).max())
        assert np.array_equal(model.pdf(x, y, dtype=computed).astype(dtype), lanes.values)
        assume(np.any(scalar > 0))  # 60 cases where the grid catches the banana (equal zeros say less)
