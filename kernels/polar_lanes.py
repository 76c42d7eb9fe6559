"""The polar-banana kernels in CPU lanes: 8 float64 or 16 float32 cells at a time, end to end.

The same density as ``polar.polar_density_local``. Without heading noise (rough and improved
variants; the formulas are in ``kernels/polar.py``): r by a lane sqrt, phi by the lane atan2,
sinc(phi) = (x / r) / phi, cos(phi) = y / r, P_mu (8) and P_sigma (11) in lane arithmetic with
the host's coefficients, and one lane exp for both normal factors. With initial-heading noise
(order 2 or 4): the law's derivatives at theta_bar and the moments (15)-(16) by the generic
functions the scalar kernel runs too (``polar.polar_law_of``, ``polar.polar_heading_moments``),
with the lane sine and both branches of the sinc derivatives selected per lane. The scalar
kernel's branches are selects: 0 at r = 0 and where P_sigma (or the variance) is not positive.
Values agree with the scalar kernel to about 1e-14 relative in float64 where the density is well
conditioned (``tests/kernels/test_lanes.py`` sweeps the parameter domain).

CPU only (see ``kernels/lanes.py``); the GPU path uses ``polar.polar_grid``. The grid, points
and batch kernels share :func:`polar_world_lanes`, so that ``rasterise``, ``pdf`` and the batches
agree bit for bit.
"""

from typing import Any

import warp as wp

from .common import SINC_SERIES_SWITCH, sinc_derivatives_recurrence, sinc_derivatives_series
from .lanes import (
    lane_abs, lane_atan2, lane_cos, lane_count, lane_exp, lane_sin, lane_sinc_of, lane_sqrt, lane_where_not_negative,
    lane_where_positive, load_lanes, store_lanes,
)
from .polar import (
    INV_SIGMA_OMEGA_SQ, INV_SIGMA_PHI, INV_SIGMA_THETA, MEAN_SCC, MEAN_SINC, NORM, ROUGH, SD_CURVATURE, SD_SCALE,
    SD_T_TERM, SHRINK, THETA_NORM, overload_density_kernels, polar_heading_moments, polar_law_of,
)

ONE_THIRD = 1.0 / 3.0

# No adjoints: nothing differentiates these kernels, and without them the module builds in half
# the time. The lane functions are forced inline (``inline=True``): left to the compiler, a change
# as small as a compile flag made it call them out of line, passing every vector through memory
# (17.3 ms against 11.5 ms for the Figure 1 grid).
wp.set_module_options({"enable_backward": False})


@wp.func(inline=True)
def polar_plain_lanes(x: Any, y: Any, coef: wp.array(dtype=Any), variant: int):
    """Density per m^2 at a vector of local points without heading noise:
    g(phi; 0, sigma_phi) g(r; mu, sd) / r."""
    one = type(x)(1.0)
    r = lane_sqrt(wp.cw_mul(x, x) + wp.cw_mul(y, y))
    inv_r = wp.cw_div(one, r)
    phi = lane_atan2(x, y)
    sinc_phi = lane_sinc_of(phi, wp.cw_mul(x, inv_r))
    mu = sinc_phi * coef[MEAN_SINC]
    sd = type(x)(coef[SD_SCALE])
    if variant != ROUGH:
        phi2 = wp.cw_mul(phi, phi)
        scc = wp.cw_mul(wp.cw_mul(sinc_phi, type(x)(4.0)) - wp.cw_mul(y, inv_r), type(x)(ONE_THIRD))
        z2 = phi2 * (coef[INV_SIGMA_PHI] * coef[INV_SIGMA_PHI])
        mu = mu + wp.cw_mul((z2 - one) * coef[MEAN_SCC], scc)
        sd = wp.cw_mul((one + (type(x)(coef[SD_T_TERM]) - phi2 * coef[INV_SIGMA_OMEGA_SQ]) * coef[SD_CURVATURE])
                       * coef[SD_SCALE], scc)
    inv_sd = wp.cw_div(one, sd)
    z_phi = phi * coef[INV_SIGMA_PHI]
    z_r = wp.cw_mul(r - mu, inv_sd)
    e = lane_exp(wp.cw_mul(wp.cw_mul(z_phi, z_phi) + wp.cw_mul(z_r, z_r), type(x)(-0.5)))
    density = wp.cw_mul(wp.cw_mul(inv_sd, inv_r), e) * coef[NORM]
    return lane_where_positive(sd, lane_where_positive(r, density))


@wp.func(inline=True)
def sinc_derivatives_lanes(x: Any, sin_x: Any, cos_x: Any):
    """``common.sinc_derivatives`` lane by lane: both of its branches, then a select per lane."""
    u0, u1, u2, u3, u4 = sinc_derivatives_recurrence(x, sin_x, cos_x)
    v0, v1, v2, v3, v4 = sinc_derivatives_series(x)
    upward = lane_abs(x) - type(x)(SINC_SERIES_SWITCH)  # >= 0 exactly where |x| >= the switch
    return (lane_where_not_negative(upward, u0, v0), lane_where_not_negative(upward, u1, v1),
            lane_where_not_negative(upward, u2, v2), lane_where_not_negative(upward, u3, v3),
            lane_where_not_negative(upward, u4, v4))


@wp.func(inline=True)
def polar_heading_lanes(x: Any, y: Any, coef: wp.array(dtype=Any), variant: int, order: int):
    """Density per m^2 at a vector of local points with initial-heading noise (``order`` 2 or 4):
    g(theta; 0, sigma_theta) g(r; E[r | theta], SD[r | theta]) / r, the law's derivatives at
    theta_bar by the scalar kernel's own generic functions (``polar.polar_law_of``,
    ``polar.polar_heading_moments``), sin and cos by the lane sine; 0 where P_sigma(theta_bar)
    or the variance is not positive, and at r = 0."""
    one = type(x)(1.0)
    r = lane_sqrt(wp.cw_mul(x, x) + wp.cw_mul(y, y))
    inv_r = wp.cw_div(one, r)
    theta = lane_atan2(x, y)
    bar = theta * coef[SHRINK]
    sin_bar = lane_sin(bar)
    cos_bar = lane_cos(bar)
    d0, d1, d2, d3, d4 = sinc_derivatives_lanes(bar, sin_bar, cos_bar)
    m0, m1, m2, m3, m4, s0, s1, s2 = polar_law_of(bar, d0, d1, d2, d3, d4, sin_bar, cos_bar, coef, variant)
    mean, var = polar_heading_moments(m0, m1, m2, m3, m4, s0, s1, s2, coef, order)
    sd = lane_where_positive(s0, lane_where_positive(var, lane_sqrt(var)))
    inv_sd = wp.cw_div(one, sd)
    z_theta = theta * coef[INV_SIGMA_THETA]
    z_r = wp.cw_mul(r - mean, inv_sd)
    e = lane_exp(wp.cw_mul(wp.cw_mul(z_theta, z_theta) + wp.cw_mul(z_r, z_r), type(x)(-0.5)))
    density = wp.cw_mul(wp.cw_mul(inv_sd, inv_r), e) * coef[THETA_NORM]
    return lane_where_positive(sd, lane_where_positive(r, density))


@wp.func(inline=True)
def polar_world_lanes(dx: Any, dy: Any, coef: wp.array(dtype=Any), variant: int, order: int,
                      pose: wp.array(dtype=Any)):
    """The density at a vector of world offsets from the pose origin (``common.world_to_local``'s
    rotation), one expression for the grid and the points kernels so that they agree bit for bit."""
    x = dx * pose[2] - dy * pose[3]
    y = dx * pose[3] + dy * pose[2]
    if order == 0:
        return polar_plain_lanes(x, y, coef, variant)
    return polar_heading_lanes(x, y, coef, variant, order)


@wp.func(inline=True)
def polar_row_lanes(
    xs: wp.array(dtype=Any),
    y_world: Any,
    j0: int,
    j1: int,
    coef: wp.array(dtype=Any),
    variant: int,
    order: int,
    pose: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """out[j] for j0 <= j < j1: the density at (xs[j], y_world), a vector of cells at a time."""
    dy = y_world - pose[1]
    width = lane_count(xs)
    j = j0
    while j < j1:
        dx = load_lanes(xs, j)
        values = polar_world_lanes(dx - type(dx)(pose[0]), type(dx)(dy), coef, variant, order, pose)
        store_lanes(out, j, values, j1 - j)
        j += width


@wp.func(inline=True)
def polar_point_lanes(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    k: int,
    coef: wp.array(dtype=Any),
    variant: int,
    order: int,
    pose: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """out[k ..]: the density at the vector of points from (xs[k], ys[k]) (as many as remain)."""
    dx = load_lanes(xs, k)
    values = polar_world_lanes(dx - type(dx)(pose[0]), load_lanes(ys, k) - type(dx)(pose[1]), coef, variant, order,
                               pose)
    store_lanes(out, k, values, xs.shape[0] - k)


@wp.kernel
def polar_grid_lanes(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    columns: int,
    coef: wp.array(dtype=Any),
    variant: int,
    order: int,
    pose: wp.array(dtype=Any),
    out: wp.array2d(dtype=Any),
):
    """Density at the cell centres of a band of rows, ``columns`` cells per thread, a vector at a
    time (the arguments of ``polar.polar_grid``)."""
    i, block = wp.tid()
    row = row0 + i
    polar_row_lanes(xs, ys[row], block * columns, wp.min((block + 1) * columns, xs.shape[0]), coef, variant, order,
                    pose, out[row])


@wp.kernel
def polar_points_lanes(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    start: int,
    coef: wp.array(dtype=Any),
    variant: int,
    order: int,
    pose: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """``polar.polar_points`` in lanes: the thread of every lane-count-th point (counted from the
    first of all, so that a group is computed once even where it straddles two launches'
    chunks) fills it and the next ones; the others return."""
    k = start + wp.tid()
    if k % lane_count(xs) == 0:
        polar_point_lanes(xs, ys, k, coef, variant, order, pose, out)


@wp.kernel
def polar_batch_grid_lanes(
    xs: wp.array2d(dtype=Any),
    ys: wp.array2d(dtype=Any),
    h0: int,
    coefs: wp.array2d(dtype=Any),
    variants: wp.array(dtype=wp.int32),
    orders: wp.array(dtype=wp.int32),
    poses: wp.array2d(dtype=Any),
    out: wp.array3d(dtype=Any),
):
    """``polar.polar_batch_grid`` in lanes: thread (h, i) fills row i of hypothesis h0 + h."""
    hh, i = wp.tid()
    h = h0 + hh
    polar_row_lanes(xs[h], ys[h, i], 0, xs.shape[1], coefs[h], int(variants[h]), int(orders[h]), poses[h], out[h, i])


@wp.kernel
def polar_batch_points_lanes(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    h0: int,
    coefs: wp.array2d(dtype=Any),
    variants: wp.array(dtype=wp.int32),
    orders: wp.array(dtype=wp.int32),
    poses: wp.array2d(dtype=Any),
    out: wp.array2d(dtype=Any),
):
    """``polar.polar_batch_points`` in lanes: thread h fills out[h0 + h, :], a vector of points
    at a time."""
    h = h0 + wp.tid()
    order = int(orders[h])
    variant = int(variants[h])
    k = int(0)
    while k < xs.shape[0]:
        polar_point_lanes(xs, ys, k, coefs[h], variant, order, poses[h], out[h])
        k += lane_count(xs)


overload_density_kernels(polar_grid_lanes, polar_points_lanes, polar_batch_grid_lanes, polar_batch_points_lanes)
