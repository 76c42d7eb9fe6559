"""Presence maps from bearings (Walsh's two-bearing fix and its n-sensor extension).

exact:  p(P) proportional to prod_i exp(-wrap(beta_i(P) - b_i)^2 / (2 sigma_i^2)), beta_i(P) the
        bearing from sensor i to P (clockwise from north), b_i the observed bearing: the
        bearings' likelihood under a flat prior. Its normaliser has no closed form; the kernel
        divides by the Laplace approximation L(fix) 2 pi sqrt(det C) at the likelihood's global
        maximum (L(fix) = 1 for two sensors, exp(-chi2_min / 2) for more), plus the lumps of
        likelihood at stations the other bearings point at (``BearingFix.station_lumps``), so
        the grid's captured mass shows how far the true shape departs from the ellipse, and
        normalising over the grid gives the posterior.
linear: p(P) = N(P; fix, C), C the linearised covariance of the fix. Its quadratic form
        (P - F)^T C^-1 (P - F) is taken as the sum of two squares,
        p_xx (dx + (p_xy / p_xx) dy)^2 + (det C^-1 / p_xx) dy^2, on the halved offsets
        dx = x / 2 - F_x / 2, dy = y / 2 - F_y / 2 (then times 4, exactly): no term is negative
        and no offset overflows, so q is +inf, never inf - inf, at points as far from the fix as
        float64 reaches, and the density 0 there.
"""

from typing import Any

import warp as wp

from .common import each_mul
from .generate import ARRAY_VEC4, SCALAR, Params, density_kernels
from .lanes import each_atan2, each_exp, each_wrap_angle

# No adjoints: nothing differentiates these kernels, and the backward kernels Warp would
# generate for every launch kernel are most of a module's code (the CAT module's CUDA build:
# see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False})

EXACT = 0
LINEAR = 1

@wp.func(inline=True)
def bearing_density(x: Any, y: Any, p: Any):
    """Density per m^2 at the world point (x, y), exp(log p) (see the module docstring): the
    launch kernels' maths, at a point or lane by lane at a vector of them (``bearing_lanes``)."""
    half = type(p.log_norm)(0.5)
    if p.variant == LINEAR:
        dx = x * half - type(x)(p.fix_x * half)
        dy = y * half - type(x)(p.fix_y * half)
        u = dx + dy * p.p_ratio
        q = each_mul(u * p.p_xx, u) + each_mul(dy * p.det_ratio, dy)  # a quarter of the form
        return each_exp(type(x)(p.log_norm) - q * type(p.log_norm)(2.0))
    total = type(x)(p.log_norm)
    for i in range(p.sensors.shape[0]):
        s = p.sensors[i]
        beta = each_atan2(x - type(x)(s[0]), y - type(x)(s[1]))
        z = each_wrap_angle(beta - type(x)(s[2])) * s[3]
        total = total - each_mul(z * half, z)
    return each_exp(total)


#: The parameters: the normaliser log_norm, the fix and the linear map's form as a sum of squares
#: (p = C^-1: p_xx, p_ratio = p_xy / p_xx, det_ratio = det(p) / p_xx), each sensor's
#: (x, y, bearing, 1 / sigma), the variant.
BEARING = Params("BearingParams", __name__, log_norm=SCALAR, fix_x=SCALAR, fix_y=SCALAR, p_xx=SCALAR, p_ratio=SCALAR,
                 det_ratio=SCALAR, sensors=ARRAY_VEC4, variant=int)
KERNELS = density_kernels(bearing_density, BEARING, "bearing")
