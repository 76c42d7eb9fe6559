"""Conditional radial laws along rays: E[r | theta], SD[r | theta] and p(r | theta).

For a model with a pose, theta is the bearing clockwise from the pose's heading (the papers'
phi, or theta with heading noise) and r the range from its origin. Along the ray the density
per (m, rad) is r p(x, y) (the polar Jacobian), so

    p(r | theta) = r p(r, theta) / M(theta),   M(theta) = integral of r p(r, theta) dr,
    E[r | theta] = integral of r p(r | theta) dr,  SD[r | theta]^2 = integral of (r - E)^2 p(r | theta) dr,

computed numerically for any model (this is how the polar-banana paper computes the curves of
Figures 2-5 and 8, footnote 2). The quadrature: a coarse scan of the ray over [0, r_max] finds
where r p exceeds ``SUPPORT_LEVEL`` of its largest value; there the trapezoid rule runs on
``FINE_PER_SCALE`` nodes per range scale of the model (for a smooth bump that vanishes at both
ends its error falls faster than any power of the step). Models take part through the model
protocol: ``radial_extent`` gives the range scale and the greatest range worth scanning,
``ray_values`` the density along the rays (a CAT with heading noise evaluates it exactly, by the
Fourier series of the convolved rows, not through its interpolated lattice).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..domains.pose import Pose
from ..engine.points import check_model
from ..protocol import DensityModel
from ..validate import BananagridError, show

__all__ = ["RadialMoments", "RadialDensity", "radial_moments", "radial_density", "ray_density"]

#: Where r p falls below this fraction of its largest value on the ray, the ray holds no mass
#: worth integrating (the dropped tails are below 1e-14 of the total).
SUPPORT_LEVEL = 1.0e-18
#: Trapezoid nodes per range scale (a lower bound on the range SD of the banana): for a normal
#: bump the trapezoid rule's error is about exp(-2 pi^2 (sd / h)^2), below 1e-300 at 6 nodes.
FINE_PER_SCALE = 6
COARSE_PER_SCALE = 2
MAX_NODES = 1 << 16

@dataclass(frozen=True)
class RadialMoments:
    """E[r | theta], SD[r | theta] and the ray mass M(theta) = integral of r p dr at each angle.

    ``mass`` is the marginal density of the bearing (per radian) when the model's density
    integrates to one."""

    angles: np.ndarray
    mean: np.ndarray
    sd: np.ndarray
    mass: np.ndarray


@dataclass(frozen=True)
class RadialDensity:
    """p(r | theta) at one angle: the exact conditional density (``density``, per metre) and
    the normal density with the same mean and SD (``normal``), at ranges ``r``."""

    angle: float
    r: np.ndarray
    density: np.ndarray
    normal: np.ndarray
    mean: float
    sd: float


def _pose(model: DensityModel, pose) -> Pose:
    check_model(model, "radial laws need a model that follows bananagrid.DensityModel")
    if pose is not None:
        if not isinstance(pose, Pose):
            raise BananagridError(f"pose = {pose!r}: expected a bananagrid.Pose")
        return pose
    own = model.pose
    if own is None:
        raise BananagridError(f"pose: {type(model).__name__} has no pose; pass pose=bananagrid.Pose(origin, heading)")
    return own


def ray_density(model: DensityModel, angle: float, r, *, pose: Pose | None = None, threads=None) -> np.ndarray:
    """r p(r, theta): the density per (m, rad) at ranges ``r`` along one bearing (not
    normalised; divide by :attr:`RadialMoments.mass` for p(r | theta))."""
    pose = _pose(model, pose)
    at = np.asarray(r, dtype=float)
    if at.ndim != 1 or not np.isfinite(at).all() or (at < 0).any():
        raise BananagridError("r: expected a 1-D array of finite ranges >= 0 (metres)")
    return at * model.ray_values(pose, at, np.array([float(angle)]), threads=threads)[:, 0]


def _check_angles(angles) -> np.ndarray:
    try:
        values = np.asarray(angles, dtype=float)
    except (TypeError, ValueError):
        raise BananagridError(f"angles = {angles!r}: expected real numbers (radians)") from None
    if values.ndim > 1 or not np.isfinite(values).all():
        raise BananagridError(f"angles = {angles!r}: expected a finite scalar or 1-D array (radians)")
    return values


def _nodes(lo: float, hi: float, n: int) -> np.ndarray:
    """``n`` equally spaced nodes from ``lo`` to ``hi``: ``numpy.linspace``'s, except for spans
    near float64's largest value, where linspace's ``k * step`` overflows; there each node is
    ``lo (1 - f) + hi f`` for ``f = k / (n - 1)``, which never passes ``hi``."""
    if hi - lo < np.finfo(float).max / 4:
        return np.linspace(lo, hi, n)
    f = np.arange(n) / (n - 1.0)
    return lo * (1.0 - f) + hi * f


def _profile(model: DensityModel, pose: Pose, angles: np.ndarray, r_max, threads):
    """Shared trapezoid nodes and the values r p(r, theta), shape (nodes, angles), over the
    union of the rays' supports."""
    scale, bound = model.radial_extent(pose)
    if r_max is not None:
        bound = float(r_max) if isinstance(r_max, (int, float)) else math.nan
        if not (math.isfinite(bound) and bound > 0.0):
            raise BananagridError(f"r_max = {r_max!r}: must be finite and > 0")
    coarse_n = int(min(MAX_NODES, max(256, math.ceil(bound / scale * COARSE_PER_SCALE))))
    coarse = _nodes(0.0, bound, coarse_n)
    q = coarse[:, None] * model.ray_values(pose, coarse, angles, threads=threads)
    peaks = q.max(axis=0)
    if not (peaks > 0.0).all():
        empty = float(angles[np.argmin(peaks > 0.0)])
        raise BananagridError(f"angle = {empty!r}: the model has no density along this ray within {bound:.6g} m")
    keep = np.nonzero((q >= SUPPORT_LEVEL * peaks).any(axis=1))[0]
    step = coarse[1] - coarse[0]
    lo = max(0.0, coarse[keep[0]] - 2 * step)
    hi = min(bound, coarse[keep[-1]] + 2 * step)
    n = int(min(MAX_NODES, max(512, math.ceil((hi - lo) / scale * FINE_PER_SCALE) + 1)))
    radii = _nodes(lo, hi, n)
    return radii, radii[:, None] * model.ray_values(pose, radii, angles, threads=threads)


def _check_mass(radii: np.ndarray, q: np.ndarray, named: tuple) -> None:
    """Refuse rays none of which holds mass that float64 resolves (a range scanned far below
    the model's scale: the integral underflows to 0, and mean and SD would be 0 / 0)."""
    if not np.any(np.trapezoid(q, radii, axis=0) > 0.0):
        name, value = named
        raise BananagridError(f"{name} = {show(value)}: the density along these rays holds no mass that float64 "
                              "resolves (the integral underflows to 0), so they have no mean or SD")


def _moments(radii: np.ndarray, q: np.ndarray):
    """Ray mass, mean and SD of each column of q (trapezoid rule on the shared nodes)."""
    r = radii[:, None]
    mass = np.trapezoid(q, radii, axis=0)
    mean = np.trapezoid(r * q, radii, axis=0) / mass
    var = np.trapezoid((r - mean) ** 2 * q, radii, axis=0) / mass
    return mass, mean, np.sqrt(var)


def radial_moments(model: DensityModel, angles, *, pose: Pose | None = None, r_max=None, threads=None) -> RadialMoments:
    """E[r | theta] and SD[r | theta] from the model's density along rays (numerical).

    Parameters
    ----------
    model : DensityModel
    angles : float or 1-D array
        Bearings theta (radians) clockwise from the pose's heading.
    pose : Pose, optional
        Origin and zero bearing of the rays; by default the model's own pose (required for
        models without one, such as a bearing fix).
    r_max : float, optional
        Greatest range scanned (default: v0 t + 12 sigma_a t^2 / 2 for motion models).
    threads : int, optional
        CPU threads for the kernels.

    Returns
    -------
    RadialMoments
        Arrays shaped like ``angles``: mean, SD and the ray mass integral of r p(r, theta) dr.
    """
    pose = _pose(model, pose)
    values = _check_angles(angles)
    radii, q = _profile(model, pose, np.atleast_1d(values), r_max, threads)
    _check_mass(radii, q, ("r_max", r_max) if r_max is not None else ("angles", angles))
    mass, mean, sd = _moments(radii, q)
    shape = values.shape
    return RadialMoments(values, mean.reshape(shape), sd.reshape(shape), mass.reshape(shape))


def radial_density(model: DensityModel, angle, r=None, *, pose: Pose | None = None, r_max=None, threads=None) -> RadialDensity:
    """p(r | theta) at one bearing: exact (numerical, normalised along the ray) and the normal
    density with the same mean and SD (the comparison of Figure 2).

    ``r``: ranges at which to report it (default: the quadrature nodes over the ray's support).
    """
    pose = _pose(model, pose)
    angle = _check_angles(angle)
    if angle.ndim != 0:
        raise BananagridError(f"angle = {angle!r}: expected one angle (radians)")
    radii, q = _profile(model, pose, np.atleast_1d(angle), r_max, threads)
    _check_mass(radii, q, ("r_max", r_max) if r_max is not None else ("angle", float(angle)))
    mass, mean, sd = (float(v[0]) for v in _moments(radii, q))
    if not sd > 0.0:  # the ray's spread underflows (a range scanned far below the model's scale)
        name, value = ("r_max", r_max) if r_max is not None else ("angle", float(angle))
        raise BananagridError(f"{name} = {value!r}: the density along this ray has no spread that float64 "
                              "resolves (SD 0), so p(r | theta) has no normal to compare with")
    q = q[:, 0]
    if r is None:
        at, density = radii, q / mass
    else:
        at = np.asarray(r, dtype=float)
        density = ray_density(model, float(angle), at, pose=pose, threads=threads) / mass
    normal = np.exp(-0.5 * ((at - mean) / sd) ** 2) / (sd * math.sqrt(2.0 * math.pi))
    return RadialDensity(float(angle), at, density, normal, mean, sd)
