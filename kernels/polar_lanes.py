"""The polar-banana kernels in CPU lanes: 8 float64 or 16 float32 cells at a time, end to end.

The density of ``polar.polar_density_local``. Without heading noise: one native snippet
(``lanes.lane_polar_plain``; a grid row in ``lanes.polar_plain_row``), its steps stated in
``kernels/lanes.py`` (no division instruction on a CPU with AVX-512; phi by the scalar kernel's
atan2 steps, ``common.atan2_one_division``, within 1 ulp: fused multiply-adds in its
polynomial). With initial-heading noise (order 2 or 4): the law's derivatives at theta_bar and
the moments (15)-(16) by the generic functions the scalar kernel runs too
(``polar.polar_law_of``, ``polar.polar_heading_moments``), with the lane sine and both branches of
the sinc derivatives selected per lane. The scalar kernel's branches are selects: 0 at r = 0 and
where P_sigma (or the variance) is not positive. Values agree with the scalar kernel to about
1e-14 relative in float64 where the density is well conditioned (``tests/kernels/test_lanes.py``
sweeps the parameter domain).

CPU only (see ``kernels/lanes.py``); the GPU path uses ``polar.KERNELS``. Every kernel is
generated from :func:`polar_density_lanes`, the grid kernel with :func:`polar_row_lanes` (a row
without heading noise by ``lanes.polar_plain_row``, the same operations lane by lane), so that
``rasterise``, ``pdf`` and the batches agree bit for bit.
"""

from typing import Any

import warp as wp

from .common import SINC_SERIES_SWITCH, sinc_derivatives_recurrence, sinc_derivatives_series
from .generate import density_kernels
from .lanes import (
    lane_abs, lane_atan2, lane_cos, lane_exp, lane_polar_plain, lane_sin, lane_sqrt, lane_where_not_negative,
    lane_where_positive, polar_plain_row,
)
from .polar import POLAR, ROUGH, polar_heading_moments, polar_law_of


# No adjoints: nothing differentiates these kernels, and without them the module builds in half
# the time. The lane functions are forced inline (``inline=True``): left to the compiler, a change
# as small as a compile flag made it call them out of line, passing every vector through memory
# (17.3 ms against 11.5 ms for the Figure 1 grid).
wp.set_module_options({"enable_backward": False})


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
def polar_heading_lanes(x: Any, y: Any, p: Any):
    """Density per m^2 at a vector of local points with initial-heading noise (``order`` 2 or 4):
    g(theta; 0, sigma_theta) g(r; E[r | theta], SD[r | theta]) / r, the law's derivatives at
    theta_bar by the scalar kernel's own generic functions (``polar.polar_law_of``,
    ``polar.polar_heading_moments``), sin and cos by the lane sine; 0 where P_sigma(theta_bar)
    or the variance is not positive, and at r = 0."""
    one = type(x)(1.0)
    r = lane_sqrt(wp.cw_mul(x, x) + wp.cw_mul(y, y))
    inv_r = wp.cw_div(one, r)
    theta = lane_atan2(x, y)
    bar = theta * p.shrink
    sin_bar = lane_sin(bar)
    cos_bar = lane_cos(bar)
    d0, d1, d2, d3, d4 = sinc_derivatives_lanes(bar, sin_bar, cos_bar)
    m0, m1, m2, m3, m4, s0, s1, s2 = polar_law_of(bar, d0, d1, d2, d3, d4, sin_bar, cos_bar, p)
    mean, var = polar_heading_moments(m0, m1, m2, m3, m4, s0, s1, s2, p)
    sd = lane_where_positive(s0, lane_where_positive(var, lane_sqrt(var)))
    inv_sd = wp.cw_div(one, sd)
    z_theta = theta * p.inv_sigma_theta
    z_r = wp.cw_mul(r - mean, inv_sd)
    e = lane_exp(wp.cw_mul(wp.cw_mul(z_theta, z_theta) + wp.cw_mul(z_r, z_r), type(x)(-0.5)))
    density = wp.cw_mul(wp.cw_mul(inv_sd, inv_r), e) * p.theta_norm
    return lane_where_positive(sd, lane_where_positive(r, density))


@wp.func(inline=True)
def polar_density_lanes(x: Any, y: Any, p: Any):
    """The density at a vector of world points (``common.world_to_local``'s arithmetic, lane by
    lane): the launch kernels' maths."""
    dx = x - type(x)(p.pose[0])
    dy = y - type(x)(p.pose[1])
    lx = dx * p.pose[2] - dy * p.pose[3]
    ly = dx * p.pose[3] + dy * p.pose[2]
    if p.order == 0:
        return lane_polar_plain(x, y, p.pose[0], p.pose[1], p.pose[2], p.pose[3], p.mean_sinc, p.mean_scc,
                                p.sd_scale, p.sd_t_term, p.sd_curvature, p.inv_sigma_phi, p.inv_sigma_omega_sq,
                                p.norm, wp.where(p.variant != ROUGH, 1, 0))
    return polar_heading_lanes(lx, ly, p)


@wp.func(inline=True)
def polar_row_lanes(xs: wp.array(dtype=Any), y: Any, out: wp.array2d(dtype=Any), row: int, j0: int, j1: int, p: Any,
                    sums: wp.array(dtype=wp.float64)):
    """The generated grid kernel's row without heading noise, in one native loop
    (``lanes.polar_plain_row``: ``lanes.CHAINS`` registers of lanes a step, the same bits as
    :func:`polar_density_lanes`), its float64 sum in ``sums[row]``: 1; with heading noise 0 (the
    row and its sum are left to the generated kernel)."""
    if p.order == 0:
        sums[row] = polar_plain_row(xs, y, out, row, j0, j1, p.pose[0], p.pose[1], p.pose[2], p.pose[3],
                                    p.mean_sinc, p.mean_scc, p.sd_scale, p.sd_t_term, p.sd_curvature, p.inv_sigma_phi,
                                    p.inv_sigma_omega_sq, p.norm, wp.where(p.variant != ROUGH, 1, 0))
        return 1
    return 0


KERNELS = density_kernels(polar_density_lanes, POLAR, "polar", lanes=True, batch=True, bands_per_thread=1,
                          row=polar_row_lanes, row_sums=True)
