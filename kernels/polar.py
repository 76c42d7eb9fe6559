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
"""

import math
from typing import Any

import warp as wp

from .common import atan2_fast, scc_of, sinc_of, world_to_local

ROUGH = 0
IMPROVED = 1

#: Layout of the coefficient array (see :func:`coefficients`).
MEAN_SINC, MEAN_SCC, INV_SIGMA_PHI, SD_SCALE, SD_CURVATURE, SD_T_TERM, INV_SIGMA_OMEGA_SQ, NORM = range(8)


def coefficients(v0: float, t: float, sigma_a: float, sigma_omega: float) -> list[float]:
    """Host-side factors of P_mu (8), P_sigma (11) and the normal constants, in float64."""
    sigma_phi = 0.5 * sigma_omega * t
    return [
        v0 * t,  # MEAN_SINC
        sigma_a**2 * t**3 / (12.0 * v0),  # MEAN_SCC
        1.0 / sigma_phi,  # INV_SIGMA_PHI
        0.5 * sigma_a * t * t,  # SD_SCALE
        sigma_a**2 / (6.0 * v0 * v0),  # SD_CURVATURE
        t * t / 12.0,  # SD_T_TERM
        1.0 / sigma_omega**2,  # INV_SIGMA_OMEGA_SQ
        1.0 / (2.0 * math.pi * sigma_phi),  # NORM: both normal constants but 1/sd
    ]


@wp.func
def polar_mean_sd(phi: Any, sinc_phi: Any, cos_phi: Any, coef: wp.array(dtype=Any), variant: int):
    """Mean and SD of r given phi: the rough law, or P_mu (8) and P_sigma (11)."""
    one = type(phi)(1.0)
    if variant == ROUGH:
        return coef[MEAN_SINC] * sinc_phi, coef[SD_SCALE]
    scc_phi = scc_of(sinc_phi, cos_phi)
    z = phi * coef[INV_SIGMA_PHI]
    mu = coef[MEAN_SINC] * sinc_phi + coef[MEAN_SCC] * (z * z - one) * scc_phi
    sd = coef[SD_SCALE] * (one + coef[SD_CURVATURE] * (coef[SD_T_TERM] - phi * phi * coef[INV_SIGMA_OMEGA_SQ])) * scc_phi
    return mu, sd


@wp.func
def polar_density_local(x: Any, y: Any, coef: wp.array(dtype=Any), variant: int):
    """Density per m^2 at a local point: g(phi; 0, sigma_phi) g(r; mu, sd) / r.

    sin(phi) = x / r and cos(phi) = y / r, and the two normal factors share one exp. Zero where
    the improved P_sigma is not positive (outside the approximation's domain; the model warns
    when that can happen) and at r = 0.
    """
    zero = type(x)(0.0)
    r = wp.sqrt(x * x + y * y)
    if r == zero:
        return zero  # the 1/r Jacobian is singular at the origin
    inv_r = type(x)(1.0) / r
    phi = atan2_fast(x, y)
    mu, sd = polar_mean_sd(phi, sinc_of(phi, x * inv_r), y * inv_r, coef, variant)
    if sd <= zero:
        return zero
    inv_sd = type(x)(1.0) / sd
    z_phi = phi * coef[INV_SIGMA_PHI]
    z_r = (r - mu) * inv_sd
    return coef[NORM] * inv_sd * inv_r * wp.exp(type(x)(-0.5) * (z_phi * z_phi + z_r * z_r))


@wp.kernel
def polar_grid(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    columns: int,
    coef: wp.array(dtype=Any),
    variant: int,
    pose: wp.array(dtype=Any),
    out: wp.array2d(dtype=Any),
):
    """Density at the cell centres of a band of rows, ``columns`` cells per thread.

    On the CPU a thread takes a whole row (Warp's 2-D thread index costs an integer division
    per thread, as much as a third of a cell); on a GPU one cell (``columns = 1``).
    """
    i, block = wp.tid()
    row = row0 + i
    y_world = ys[row]
    j_end = wp.min((block + 1) * columns, xs.shape[0])
    for j in range(block * columns, j_end):
        x, y = world_to_local(xs[j], y_world, pose)
        out[row, j] = polar_density_local(x, y, coef, variant)


@wp.kernel
def polar_points(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    start: int,
    coef: wp.array(dtype=Any),
    variant: int,
    pose: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """Density at arbitrary world points (xs[k], ys[k]) for k in a chunk starting at ``start``."""
    k = start + wp.tid()
    x, y = world_to_local(xs[k], ys[k], pose)
    out[k] = polar_density_local(x, y, coef, variant)


@wp.kernel
def polar_moments(
    phis: wp.array(dtype=Any),
    coef: wp.array(dtype=Any),
    variant: int,
    mean: wp.array(dtype=Any),
    sd: wp.array(dtype=Any),
):
    """Mean and SD of r given phi (P_mu (8) and P_sigma (11) for the improved variant)."""
    k = wp.tid()
    phi = phis[k]
    m, s = polar_mean_sd(phi, sinc_of(phi, wp.sin(phi)), wp.cos(phi), coef, variant)
    mean[k] = m
    sd[k] = s


def _register_overloads():
    for scalar in (wp.float32, wp.float64):
        vec = wp.array(dtype=scalar)
        common = {"xs": vec, "ys": vec, "coef": vec, "pose": vec}
        wp.overload(polar_grid, {**common, "out": wp.array2d(dtype=scalar)})
        wp.overload(polar_points, {**common, "out": vec})
        wp.overload(polar_moments, {"phis": vec, "coef": vec, "mean": vec, "sd": vec})


_register_overloads()
