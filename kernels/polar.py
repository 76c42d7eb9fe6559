"""Polar-banana approximations of the CAT density (Sections 2 and 5 of the polar-banana paper).

    phi ~ N(0, sigma_phi),  sigma_phi = sigma_omega t / 2,   r | phi ~ N(mu(phi), sd(phi)),
    p(x, y) = g(phi; 0, sigma_phi) g(r; mu(phi), sd(phi)) / r,

with phi = atan2(x, y) (from the +y axis toward +x) and r = |(x, y)| in the model's local frame.
The rough variant has mu = v0 t sinc(phi), sd = sigma_a t^2 / 2; the improved variant has
mu = P_mu (8) and sd = P_sigma (11), with scc(phi) = (4 sinc(phi) - cos(phi)) / 3 (7):

    P_mu(phi)    = v0 t sinc(phi) + sigma_a^2 t^3 / (12 v0) ((phi / sigma_phi)^2 - 1) scc(phi)
    P_sigma(phi) = sigma_a t^2 / 2 (1 + sigma_a^2 / (6 v0^2) (t^2 / 12 - phi^2 / sigma_omega^2)) scc(phi)

The parameter-only factors are computed once per model on the host (:func:`coefficients`), so
a cell costs one sqrt, one atan2 and one exp.

Initial-heading noise (Section 7): theta = theta_0 + phi with theta_0 ~ N(0, sigma_0), so
theta ~ N(0, sigma_theta), sigma_theta^2 = sigma_0^2 + sigma_phi^2, and by (12)
phi | theta ~ N(theta_bar, sigma_bar) with theta_bar = theta sigma_phi^2 / sigma_theta^2 and
sigma_bar = sigma_0 sigma_phi / sigma_theta. The density is

    p(x, y) = g(theta; 0, sigma_theta) g(r; E[r | theta], SD[r | theta]) / r,

with every function at theta_bar ("order" 2: (15), (16); order 4 adds the terms given after
Figure 8; Pm_k is the k-th derivative of P_mu, Ps_k that of P_sigma):

    E[r | theta]    = P_mu + Pm_2 sigma_bar^2 / 2  [+ Pm_4 sigma_bar^4 / 8]
    SD[r | theta]^2 = P_sigma^2 + Pm_1^2 sigma_bar^2
                      [+ (Ps_1^2 + P_sigma Ps_2) sigma_bar^2 + (Pm_2^2 / 2 + Pm_1 Pm_3) sigma_bar^4]

The derivatives are analytic: Leibniz's rule over sinc, scc and the quadratic factors of (8)
and (11), with ``common.sinc_derivatives``.
"""

import math
from typing import Any

import warp as wp

from .common import atan2_fast, atan2_one_division, each_mul, lane0, scc_of, sinc_derivatives, sinc_of, world_to_local
from .generate import SCALAR, SCALARS, VEC4, Params, density_kernels, overload_on_use

# No adjoints: nothing differentiates these kernels, and the backward kernels Warp would
# generate for every launch kernel are most of a module's code (the CAT module's CUDA build:
# see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False})

ROUGH = 0
IMPROVED = 1

#: Heading orders: 0 without heading noise (the angle is phi), 2 for (15)-(16), 4 with the
#: fourth-order terms given after Figure 8.
HEADING_ORDERS = (0, 2, 4)

#: The coefficients (:func:`coefficients`), fields of the parameter struct; their indices in
#: the list for host code.
COEFFICIENTS = (
    "mean_sinc", "mean_scc", "inv_sigma_phi", "sd_scale", "sd_curvature", "sd_t_term", "inv_sigma_omega_sq", "norm",
    "inv_sigma_theta", "theta_norm", "shrink", "sigma_bar_sq",
)
(
    MEAN_SINC, MEAN_SCC, INV_SIGMA_PHI, SD_SCALE, SD_CURVATURE, SD_T_TERM, INV_SIGMA_OMEGA_SQ, NORM,
    INV_SIGMA_THETA, THETA_NORM, SHRINK, SIGMA_BAR_SQ,
) = range(len(COEFFICIENTS))


def coefficients(
    v0: float, t: float, sigma_a: float, sigma_omega: float, sigma_heading: float = 0.0
) -> list[float]:
    """Host-side factors of P_mu (8), P_sigma (11), the heading law (12) and the normal
    constants, in float64."""
    sigma_phi = 0.5 * sigma_omega * t
    sigma_theta_sq = sigma_heading**2 + sigma_phi**2
    return [
        v0 * t,  # MEAN_SINC
        sigma_a**2 * t**3 / (12.0 * v0),  # MEAN_SCC
        1.0 / sigma_phi,  # INV_SIGMA_PHI
        0.5 * sigma_a * t * t,  # SD_SCALE
        sigma_a**2 / (6.0 * v0 * v0),  # SD_CURVATURE
        t * t / 12.0,  # SD_T_TERM
        1.0 / sigma_omega**2,  # INV_SIGMA_OMEGA_SQ
        1.0 / (2.0 * math.pi * sigma_phi),  # NORM: both normal constants but 1/sd
        1.0 / math.sqrt(sigma_theta_sq),  # INV_SIGMA_THETA
        1.0 / (2.0 * math.pi * math.sqrt(sigma_theta_sq)),  # THETA_NORM
        sigma_phi**2 / sigma_theta_sq,  # SHRINK: theta_bar = SHRINK theta
        (sigma_heading * sigma_phi) ** 2 / sigma_theta_sq,  # SIGMA_BAR_SQ
    ]


@wp.func
def polar_mean_sd(phi: Any, sinc_phi: Any, cos_phi: Any, p: Any):
    """Mean and SD of r given phi: the rough law, or P_mu (8) and P_sigma (11)."""
    one = type(phi)(1.0)
    if p.variant == ROUGH:
        return p.mean_sinc * sinc_phi, p.sd_scale
    scc_phi = scc_of(sinc_phi, cos_phi)
    z = phi * p.inv_sigma_phi
    mu = p.mean_sinc * sinc_phi + p.mean_scc * (z * z - one) * scc_phi
    sd = p.sd_scale * (one + p.sd_curvature * (p.sd_t_term - phi * phi * p.inv_sigma_omega_sq)) * scc_phi
    return mu, sd


@wp.func
def polar_law_of(
    phi: Any, d0: Any, d1: Any, d2: Any, d3: Any, d4: Any, sin_phi: Any, cos_phi: Any, p: Any,
):
    """P_mu and its first four derivatives, P_sigma and its first two, at phi, from sinc's
    derivatives d0..d4 and sin, cos at phi. Generic over a value and a vector of lanes.

    Improved: P_mu = A sinc + K q scc with q = (phi / sigma_phi)^2 - 1, and
    P_sigma = S w scc with w = 1 + c (T - phi^2 / sigma_omega^2). q and w are quadratics, so by
    Leibniz's rule  (q scc)^(n) = q scc^(n) + n q' scc^(n-1) + n (n-1) / 2 q'' scc^(n-2),  and
    scc^(n) = (4 sinc^(n) - cos^(n)) / 3 by (7). Rough: P_mu = A sinc, P_sigma = S (constant).
    """
    zero = type(phi)(0.0)
    two = type(lane0(phi))(2.0)
    three = type(lane0(phi))(3.0)
    four = type(lane0(phi))(4.0)
    a = p.mean_sinc
    if p.variant == ROUGH:
        return a * d0, a * d1, a * d2, a * d3, a * d4, type(phi)(p.sd_scale), zero, zero
    c0 = (four * d0 - cos_phi) / three
    c1 = (four * d1 + sin_phi) / three
    c2 = (four * d2 + cos_phi) / three
    c3 = (four * d3 - sin_phi) / three
    c4 = (four * d4 - cos_phi) / three
    inv_sp2 = p.inv_sigma_phi * p.inv_sigma_phi
    q = each_mul(phi, phi) * inv_sp2 - type(phi)(1.0)
    q1 = two * phi * inv_sp2
    q2 = two * inv_sp2
    k = p.mean_scc
    m0 = a * d0 + each_mul(k * q, c0)
    m1 = a * d1 + k * (each_mul(q, c1) + each_mul(q1, c0))
    m2 = a * d2 + k * (each_mul(q, c2) + each_mul(two * q1, c1) + q2 * c0)
    m3 = a * d3 + k * (each_mul(q, c3) + each_mul(three * q1, c2) + three * q2 * c1)
    m4 = a * d4 + k * (each_mul(q, c4) + each_mul(four * q1, c3) + type(lane0(phi))(6.0) * q2 * c2)
    curv = p.sd_curvature
    u = p.inv_sigma_omega_sq
    w = type(phi)(1.0) + curv * (type(phi)(p.sd_t_term) - each_mul(phi, phi) * u)
    w1 = -two * curv * u * phi
    w2 = -two * curv * u
    scale = p.sd_scale
    s0 = each_mul(scale * w, c0)
    s1 = scale * (each_mul(w, c1) + each_mul(w1, c0))
    s2 = scale * (each_mul(w, c2) + each_mul(two * w1, c1) + w2 * c0)
    return m0, m1, m2, m3, m4, s0, s1, s2


@wp.func
def polar_law_derivatives(phi: Any, p: Any):
    """P_mu and its first four derivatives, P_sigma and its first two, at phi
    (:func:`polar_law_of`)."""
    d0, d1, d2, d3, d4 = sinc_derivatives(phi)
    sin_phi = type(phi)(0.0)
    cos_phi = type(phi)(0.0)
    if p.variant != ROUGH:
        cos_phi = wp.cos(phi)
        sin_phi = wp.sin(phi)
    return polar_law_of(phi, d0, d1, d2, d3, d4, sin_phi, cos_phi, p)


@wp.func
def polar_heading_moments(
    m0: Any, m1: Any, m2: Any, m3: Any, m4: Any, s0: Any, s1: Any, s2: Any, p: Any
):
    """E[r | theta] and Var[r | theta] from the law's derivatives at theta_bar: (15) and (16)
    at order 2, with the fourth-order terms at order 4. Generic over a value and a vector of
    lanes."""
    sb2 = p.sigma_bar_sq
    half = type(lane0(m0))(0.5)
    mean = m0 + half * m2 * sb2
    var = each_mul(s0, s0) + each_mul(m1, m1) * sb2
    if p.order == 4:
        mean = mean + type(lane0(m0))(0.125) * m4 * sb2 * sb2
        var = var + (each_mul(s1, s1) + each_mul(s0, s2)) * sb2 + (half * each_mul(m2, m2) + each_mul(m1, m3)) * sb2 * sb2
    return mean, var


@wp.func
def polar_heading_mean_sd(theta: Any, p: Any):
    """E[r | theta] and SD[r | theta] with initial-heading noise (:func:`polar_heading_moments`).
    SD is 0 where P_sigma(theta_bar) <= 0 (outside the approximation's domain, as without
    heading noise) or the variance is not positive."""
    zero = type(theta)(0.0)
    m0, m1, m2, m3, m4, s0, s1, s2 = polar_law_derivatives(theta * p.shrink, p)
    mean, var = polar_heading_moments(m0, m1, m2, m3, m4, s0, s1, s2, p)
    if s0 <= zero or var <= zero:
        return mean, zero
    return mean, wp.sqrt(var)


@wp.func
def normal_pair(z_angle: Any, r: Any, inv_r: Any, mean: Any, sd: Any, norm: Any):
    """norm / sd / r exp(-(z_angle^2 + ((r - mean) / sd)^2) / 2): the angle's and r's normal
    factors under one exp, with the 1/r Jacobian; 0 where sd is not positive."""
    if sd <= type(r)(0.0):
        return type(r)(0.0)
    inv_sd = type(r)(1.0) / sd
    z_r = (r - mean) * inv_sd
    return norm * inv_sd * inv_r * wp.exp(type(r)(-0.5) * (z_angle * z_angle + z_r * z_r))


@wp.func
def polar_density_local(x: Any, y: Any, p: Any):
    """Density per m^2 at a local point: g(phi; 0, sigma_phi) g(r; mu, sd) / r.

    sin(phi) = x / r and cos(phi) = y / r. Zero where the improved P_sigma is not positive
    (outside the approximation's domain; the model warns when that can happen) and at r = 0.
    With heading noise (``order`` 2 or 4) the angle is theta ~ N(0, sigma_theta) and r | theta
    follows (15)-(16).
    """
    zero = type(x)(0.0)
    r = wp.sqrt(x * x + y * y)
    if r == zero:
        return zero  # the 1/r Jacobian is singular at the origin
    inv_r = type(x)(1.0) / r
    if p.order != 0:
        theta = atan2_fast(x, y)
        mean_t, sd_t = polar_heading_mean_sd(theta, p)
        return normal_pair(theta * p.inv_sigma_theta, r, inv_r, mean_t, sd_t, p.theta_norm)
    phi = atan2_one_division(x, y)  # one division: the lane kernel's steps
    mu, sd = polar_mean_sd(phi, sinc_of(phi, x * inv_r), y * inv_r, p)
    return normal_pair(phi * p.inv_sigma_phi, r, inv_r, mu, sd, p.norm)


@wp.func
def polar_density(x: Any, y: Any, p: Any):
    """Density per m^2 at the world point (x, y): the launch kernels' maths."""
    lx, ly = world_to_local(x, y, p.pose)
    return polar_density_local(lx, ly, p)


@wp.kernel
def polar_moments(phis: wp.array(dtype=Any), p: Any, mean: wp.array(dtype=Any), sd: wp.array(dtype=Any)):
    """Mean and SD of r given the angle: at order 0 given phi (P_mu (8) and P_sigma (11) for
    the improved variant), at order 2 or 4 given theta with heading noise ((15), (16))."""
    k = wp.tid()
    phi = phis[k]
    m = phi
    s = phi
    if p.order == 0:
        m, s = polar_mean_sd(phi, sinc_of(phi, wp.sin(phi)), wp.cos(phi), p)
    else:
        m, s = polar_heading_mean_sd(phi, p)
    mean[k] = m
    sd[k] = s


@wp.kernel
def polar_derivatives(phis: wp.array(dtype=Any), p: Any, out: wp.array(dtype=Any)):
    """P_mu and its derivatives 1-4, P_sigma and its derivatives 1-2, at each phi (a vector of 8)."""
    k = wp.tid()
    m0, m1, m2, m3, m4, s0, s1, s2 = polar_law_derivatives(phis[k], p)
    out[k] = wp.vector(m0, m1, m2, m3, m4, s0, s1, s2)


#: The parameters: the coefficients (:func:`coefficients`, in their order), the pose, the
#: variant and the heading order.
POLAR = Params("PolarParams", __name__, **dict.fromkeys(COEFFICIENTS, SCALAR), pose=VEC4, variant=int, order=int)
KERNELS = density_kernels(polar_density, POLAR, "polar", batch=True, bands_per_thread=1)
for _scalar in SCALARS:
    _vec = wp.array(dtype=_scalar)
    overload_on_use(polar_moments, _scalar, {"phis": _vec, "p": POLAR.of(_scalar), "mean": _vec, "sd": _vec})
    overload_on_use(polar_derivatives, _scalar,
                    {"phis": _vec, "p": POLAR.of(_scalar), "out": wp.array(dtype=wp.types.vector(8, _scalar))})
