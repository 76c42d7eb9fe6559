"""Polar-banana approximations of the CAT density (Sections 2 and 5 of the polar-banana paper).

    phi ~ N(0, sigma_omega t / 2),   r | phi ~ N(mu(phi), sd(phi)),
    p(x, y) = g(phi; 0, sigma_omega t / 2) g(r; mu(phi), sd(phi)) / r,

with phi = atan2(x, y) (from the +y axis toward +x) and r = |(x, y)| in the model's local frame.
The rough variant has mu = v0 t sinc(phi), sd = sigma_a t^2 / 2; the improved variant has
mu = P_mu (8) and sd = P_sigma (11).
"""

from typing import Any

import warp as wp

from .common import world_to_local_x, world_to_local_y

ROUGH = 0

#: 1 / (2 pi): the two normal factors' constants together.
INV_2PI = 0.15915494309189535
IMPROVED = 1


@wp.func
def sinc_of(phi: Any, sin_phi: Any):
    """sinc(phi) from a known sin(phi): no second sine on the hot path."""
    if wp.abs(phi) < type(phi)(1.0e-4):
        return type(phi)(1.0) - phi * phi / type(phi)(6.0)
    return sin_phi / phi


@wp.func
def polar_p_mu(phi: Any, sinc_phi: Any, cos_phi: Any, v0: Any, t: Any, sigma_a: Any, sigma_omega: Any):
    """P_mu(phi) = v0 t sinc(phi) + sigma_a^2 t^3 / (12 v0) (phi^2 / (sigma_omega t / 2)^2 - 1) scc(phi), eq. (8),
    with scc(phi) = (4 sinc(phi) - cos(phi)) / 3, eq. (7)."""
    ratio = phi / (sigma_omega * t * type(phi)(0.5))
    scc_phi = (type(phi)(4.0) * sinc_phi - cos_phi) / type(phi)(3.0)
    return v0 * t * sinc_phi + sigma_a * sigma_a * t * t * t / (type(phi)(12.0) * v0) * (
        ratio * ratio - type(phi)(1.0)
    ) * scc_phi


@wp.func
def polar_p_sigma(phi: Any, sinc_phi: Any, cos_phi: Any, v0: Any, t: Any, sigma_a: Any, sigma_omega: Any):
    """P_sigma(phi) = sigma_a t^2 / 2 (1 + sigma_a^2 / (6 v0^2) (t^2 / 12 - phi^2 / sigma_omega^2)) scc(phi), eq. (11)."""
    correction = type(phi)(1.0) + sigma_a * sigma_a / (type(phi)(6.0) * v0 * v0) * (
        t * t / type(phi)(12.0) - phi * phi / (sigma_omega * sigma_omega)
    )
    scc_phi = (type(phi)(4.0) * sinc_phi - cos_phi) / type(phi)(3.0)
    return sigma_a * t * t * type(phi)(0.5) * correction * scc_phi


@wp.func
def polar_density_local(
    x: Any, y: Any, v0: Any, t: Any, sigma_a: Any, sigma_omega: Any, variant: int
):
    """Density per m^2 at a local point: g(phi; 0, sigma_phi) g(r; mu, sd) / r.

    sin(phi) = x / r and cos(phi) = y / r, so the only transcendental calls are atan2 and one
    exp (the two normal factors share it). Zero where the improved P_sigma is not positive
    (outside the approximation's domain; the model warns when that can happen) and at r = 0.
    """
    zero = type(x)(0.0)
    r = wp.sqrt(x * x + y * y)
    if r == zero:
        return zero  # the 1/r Jacobian is singular at the origin; g(r) there is negligible
    phi = wp.atan2(x, y)
    sinc_phi = sinc_of(phi, x / r)
    cos_phi = y / r
    if variant == ROUGH:
        mu = v0 * t * sinc_phi
        sd = sigma_a * t * t * type(x)(0.5)
    else:
        mu = polar_p_mu(phi, sinc_phi, cos_phi, v0, t, sigma_a, sigma_omega)
        sd = polar_p_sigma(phi, sinc_phi, cos_phi, v0, t, sigma_a, sigma_omega)
    if sd <= zero:
        return zero
    sigma_phi = sigma_omega * t * type(x)(0.5)
    z_phi = phi / sigma_phi
    z_r = (r - mu) / sd
    norm = type(x)(INV_2PI) / (sigma_phi * sd * r)
    return norm * wp.exp(type(x)(-0.5) * (z_phi * z_phi + z_r * z_r))


@wp.kernel
def polar_grid(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    variant: int,
    pose: wp.array(dtype=Any),
    out: wp.array2d(dtype=Any),
):
    """Density at the cell centres (xs[j], ys[row0 + i]) of a band of rows."""
    i, j = wp.tid()
    row = row0 + i
    x = world_to_local_x(xs[j], ys[row], pose[0], pose[1], pose[2], pose[3])
    y = world_to_local_y(xs[j], ys[row], pose[0], pose[1], pose[2], pose[3])
    out[row, j] = polar_density_local(x, y, v0, t, sigma_a, sigma_omega, variant)


@wp.kernel
def polar_points(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    start: int,
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    variant: int,
    pose: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """Density at arbitrary world points (xs[k], ys[k]) for k in a chunk starting at ``start``."""
    k = start + wp.tid()
    x = world_to_local_x(xs[k], ys[k], pose[0], pose[1], pose[2], pose[3])
    y = world_to_local_y(xs[k], ys[k], pose[0], pose[1], pose[2], pose[3])
    out[k] = polar_density_local(x, y, v0, t, sigma_a, sigma_omega, variant)


@wp.kernel
def polar_moments(
    phis: wp.array(dtype=Any),
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    p_mu: wp.array(dtype=Any),
    p_sigma: wp.array(dtype=Any),
):
    """P_mu (8) and P_sigma (11) at the given angles."""
    k = wp.tid()
    phi = phis[k]
    sinc_phi = sinc_of(phi, wp.sin(phi))
    p_mu[k] = polar_p_mu(phi, sinc_phi, wp.cos(phi), v0, t, sigma_a, sigma_omega)
    p_sigma[k] = polar_p_sigma(phi, sinc_phi, wp.cos(phi), v0, t, sigma_a, sigma_omega)


def _register_overloads():
    for scalar in (wp.float32, wp.float64):
        vec = wp.array(dtype=scalar)
        mat = wp.array2d(dtype=scalar)
        common = {
            "xs": vec, "ys": vec, "v0": scalar, "t": scalar, "sigma_a": scalar,
            "sigma_omega": scalar, "pose": vec,
        }
        wp.overload(polar_grid, {**common, "out": mat})
        wp.overload(polar_points, {**common, "out": vec})
        wp.overload(
            polar_moments,
            {"phis": vec, "v0": scalar, "t": scalar, "sigma_a": scalar, "sigma_omega": scalar,
             "p_mu": vec, "p_sigma": vec},
        )


_register_overloads()
