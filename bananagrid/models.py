"""Motion models as frozen, validated parameter objects.

A model holds its parameters and its pose (origin of its local frame in the world, heading as a
bearing clockwise from north); it knows how to draw samples of its own generative story. Its
densities are computed by the kernels through :mod:`bananagrid.raster`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.special import erfc

from .validate import BananagridError, finite, non_negative, point, positive

__all__ = ["Pose", "CAT", "PolarBanana", "Model", "VARIANTS", "HEADING_ORDERS", "cat_position"]


@dataclass(frozen=True)
class Pose:
    """Where a model's local frame sits in the world.

    Parameters
    ----------
    origin : (float, float)
        World position of the last fix (local origin), metres.
    heading : float
        Initial heading as a bearing in radians clockwise from north: the local +y axis.
    """

    origin: tuple[float, float] = (0.0, 0.0)
    heading: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "origin", point("origin", self.origin))
        object.__setattr__(self, "heading", finite("heading", self.heading))

    def as_array(self) -> np.ndarray:
        """(ox, oy, cos heading, sin heading): the kernels' pose argument."""
        return np.array(
            [self.origin[0], self.origin[1], math.cos(self.heading), math.sin(self.heading)]
        )

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Map (n, 2) local points (x right of heading, y along it) to world (east, north)."""
        c, s = math.cos(self.heading), math.sin(self.heading)
        x, y = local[:, 0], local[:, 1]
        return np.column_stack((self.origin[0] + x * c + y * s, self.origin[1] - x * s + y * c))


def _check_rng(rng) -> np.random.Generator:
    if rng is None:
        raise BananagridError("rng: pass a numpy.random.Generator (e.g. numpy.random.default_rng(seed))")
    if isinstance(rng, (int, np.integer)):
        return np.random.default_rng(int(rng))
    if not isinstance(rng, np.random.Generator):
        raise BananagridError(f"rng = {rng!r}: expected a numpy.random.Generator or an integer seed")
    return rng


def _check_n(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise BananagridError(f"n = {n!r}: expected a non-negative integer")
    return int(n)


def _validate_motion(model) -> None:
    """The parameters every motion model shares: v0, t, sigma_a, sigma_omega > 0,
    sigma_heading >= 0 and a Pose."""
    for name in ("v0", "t", "sigma_a", "sigma_omega"):
        object.__setattr__(model, name, positive(name, getattr(model, name)))
    object.__setattr__(model, "sigma_heading", non_negative("sigma_heading", model.sigma_heading))
    if not isinstance(model.pose, Pose):
        raise BananagridError(f"pose = {model.pose!r}: expected a bananagrid.Pose")


def _heading_errors(model, n: int, rng: np.random.Generator) -> np.ndarray:
    """Initial-heading errors theta_0 ~ N(0, sigma_heading) (zeros without heading noise)."""
    if model.sigma_heading == 0.0:
        return np.zeros(n)
    return rng.normal(0.0, model.sigma_heading, n)


def _rotate(local: np.ndarray, theta0: np.ndarray) -> np.ndarray:
    """Turn local points by theta0 (radians, clockwise: a heading error to starboard)."""
    c, s = np.cos(theta0), np.sin(theta0)
    x, y = local[:, 0], local[:, 1]
    return np.column_stack((x * c + y * s, -x * s + y * c))


def cat_position(v0, t, a, omega) -> np.ndarray:
    """Local CAT position of eq. (1) for arrays of accelerations and turn rates, shape (n, 2).

    Written with u = omega t as  v0 t (A, B) + a t^2 (C, D)  (see ``kernels.common.cat_basis``);
    C and D use their series below |u| = 1e-2, where the closed forms cancel.
    """
    u = np.asarray(omega, dtype=float) * t
    a = np.asarray(a, dtype=float)
    half = 0.5 * u
    A = np.sin(half) * np.sinc(half / np.pi)  # np.sinc is normalised: sinc(x/pi) = sin(x)/x
    B = np.sinc(u / np.pi)
    small = np.abs(u) < 1e-2
    us = np.where(small, 1.0, u)  # avoid 0/0 in the branch that is not used
    C = np.where(small, u / 3 - u**3 / 30 + u**5 / 840, (np.sin(us) - us * np.cos(us)) / us**2)
    D = np.where(small, 0.5 - u**2 / 8 + u**4 / 144, (np.cos(us) + us * np.sin(us) - 1) / us**2)
    return np.column_stack((v0 * t * A + a * t * t * C, v0 * t * B + a * t * t * D))


@dataclass(frozen=True)
class CAT:
    """Constant, unknown acceleration and turn rate (Gade et al.; eq. (1) of the polar-banana paper).

    From the origin, heading +y at speed ``v0``, the target moves for ``t`` seconds with constant
    acceleration a ~ N(0, sigma_a) and turn rate omega ~ N(0, sigma_omega). Its density at (x, y)
    is the sum over every (a, omega) reaching (x, y) of g(a) g(omega) / |det d(x,y)/d(a,omega)|.

    Parameters
    ----------
    v0 : float
        Initial speed, m/s, > 0.
    t : float
        Elapsed time, s, > 0.
    sigma_a : float
        Standard deviation of the acceleration, m/s^2, > 0.
    sigma_omega : float
        Standard deviation of the turn rate, rad/s, > 0.
    k_sigma : float, default 8
        Turn rates are searched within +-k_sigma * sigma_omega; the mass beyond,
        erfc(k_sigma / sqrt 2) (1.2e-15 at 8), is reported as ``truncated_mass`` and excluded.
    sigma_heading : float, default 0
        Standard deviation sigma_0 (radians, >= 0) of a normal error theta_0 on the initial
        heading (Section 7 of the polar-banana paper). The density is then the exact CAT density
        convolved over the rotation by theta_0 about the origin:
        p(r, theta) = integral of p_0(r, theta - theta_0) g(theta_0; 0, sigma_0) d theta_0, computed
        on a polar lattice (exact wrapped-normal convolution by FFT along the bearing, then
        interpolation; see :mod:`bananagrid.heading`). 0 gives the foundation's kernel exactly.
    pose : Pose, default origin (0, 0), heading north
        Places the local frame in the world.
    """

    v0: float
    t: float
    sigma_a: float
    sigma_omega: float
    k_sigma: float = 8.0
    sigma_heading: float = 0.0
    pose: Pose = field(default_factory=Pose)

    kind = "cat"

    def __post_init__(self):
        _validate_motion(self)
        k = positive("k_sigma", self.k_sigma)
        if not 1.0 <= k <= 38.0:
            raise BananagridError(f"k_sigma = {k!r}: must be in [1, 38] (beyond 38 the normal tail underflows)")
        object.__setattr__(self, "k_sigma", k)

    @property
    def truncated_mass(self) -> float:
        """Probability of |omega| > k_sigma sigma_omega, left out of the density."""
        return float(erfc(self.k_sigma / math.sqrt(2.0)))

    def parameters(self) -> dict:
        """Plain-data parameters for provenance and recordings."""
        return _parameters(self)

    def sample(self, n: int, rng) -> np.ndarray:
        """Draw ``n`` world positions: a and omega from their normal laws, then eq. (1), turned
        by a heading error theta_0 ~ N(0, sigma_heading) when there is one.

        The turn rate is not truncated here (the truncated mass is below 1e-15 by default).
        """
        n, rng = _check_n(n), _check_rng(rng)
        a = rng.normal(0.0, self.sigma_a, n)
        omega = rng.normal(0.0, self.sigma_omega, n)
        local = cat_position(self.v0, self.t, a, omega)
        if self.sigma_heading > 0.0:
            local = _rotate(local, _heading_errors(self, n, rng))
        return self.pose.to_world(local)

    def pdf(self, x, y, *, dtype=np.float64, device="cpu"):
        """Density per m^2 at world points (broadcast x, y), through the same kernels as rasterise."""
        from .raster import evaluate_points

        return evaluate_points(self, x, y, dtype=dtype, device=device)


VARIANTS = ("rough", "improved")
HEADING_ORDERS = (2, 4)


@dataclass(frozen=True)
class PolarBanana:
    """Polar approximation of the CAT density (Sections 2 and 5 of the polar-banana paper).

    phi ~ N(0, sigma_omega t / 2) is the bearing from the initial heading, r | phi normal with
    mean and SD ``v0 t sinc(phi)`` and ``sigma_a t^2 / 2`` (``variant="rough"``) or P_mu (8) and
    P_sigma (11) (``variant="improved"``); the density in the plane is
    g(phi) g(r; mean, sd) / r.

    Parameters
    ----------
    v0, t, sigma_a, sigma_omega : float
        As for :class:`CAT`, all > 0.
    variant : {"rough", "improved"}, default "improved"
    sigma_heading : float, default 0
        Standard deviation sigma_0 (radians, >= 0) of a normal error on the initial heading
        (Section 7). The bearing is then theta ~ N(0, sigma_theta), sigma_theta^2 = sigma_0^2 +
        sigma_phi^2, and r | theta is normal with the mean (15) and SD (16) built from the
        variant's P_mu and P_sigma at theta_bar = theta sigma_phi^2 / sigma_theta^2.
    heading_order : {2, 4}, default 2
        2: (15) and (16) as printed; 4: with (1/8) P_mu^(4) sigma_bar^4 in the mean and the
        fourth-order variance terms given after Figure 8. Only used when sigma_heading > 0.
    pose : Pose

    Notes
    -----
    P_sigma (11) turns negative where phi^2 > sigma_omega^2 (t^2 / 12 + 6 v0^2 / sigma_a^2); the
    improved density is set to 0 there and a warning is issued when that angle is below pi.
    Samples are drawn from the law restricted to |phi| <= pi and r > 0, the support of the
    plane density. Where P_mu(phi) comes near 0 (phi near +-pi when sigma_omega t is large) the
    density keeps the 1/r of the polar Jacobian: integrable, but cell-centre samples near the
    origin grow as the grid is refined.
    """

    v0: float
    t: float
    sigma_a: float
    sigma_omega: float
    variant: str = "improved"
    sigma_heading: float = 0.0
    heading_order: int = 2
    pose: Pose = field(default_factory=Pose)

    kind = "polar"

    def __post_init__(self):
        _validate_motion(self)
        if self.variant not in VARIANTS:
            raise BananagridError(f"variant = {self.variant!r}: must be one of {', '.join(VARIANTS)}")
        if isinstance(self.heading_order, bool) or self.heading_order not in HEADING_ORDERS:
            raise BananagridError(
                f"heading_order = {self.heading_order!r}: must be 2 ((15), (16)) or 4 (with the "
                "fourth-order terms after Figure 8)"
            )
        object.__setattr__(self, "heading_order", int(self.heading_order))
        if self.variant == "improved" and self.sigma_positive_limit < math.pi:
            warnings.warn(
                f"P_sigma (11) is not positive for |phi| > {self.sigma_positive_limit:.4g} rad; "
                "the improved density is 0 there",
                stacklevel=3,
            )

    @property
    def sigma_phi(self) -> float:
        """SD of the bearing phi, sigma_omega t / 2."""
        return 0.5 * self.sigma_omega * self.t

    @property
    def sigma_positive_limit(self) -> float:
        """|phi| beyond which P_sigma (11) is not positive."""
        return self.sigma_omega * math.sqrt(self.t**2 / 12 + 6 * self.v0**2 / self.sigma_a**2)

    @property
    def sigma_theta(self) -> float:
        """SD of the bearing theta = theta_0 + phi: sqrt(sigma_heading^2 + sigma_phi^2)."""
        return math.hypot(self.sigma_heading, self.sigma_phi)

    @property
    def sigma_bar(self) -> float:
        """SD of phi given theta, (12): sigma_0 sigma_phi / sigma_theta (0 without heading noise)."""
        return self.sigma_heading * self.sigma_phi / self.sigma_theta

    @property
    def kernel_order(self) -> int:
        """The kernels' heading order: 0 without heading noise, else ``heading_order``."""
        return self.heading_order if self.sigma_heading > 0.0 else 0

    @property
    def truncated_mass(self) -> float:
        """Mass of the bearing (phi, or theta with heading noise) beyond +-pi, outside the plane
        density."""
        return float(erfc(math.pi / (self.sigma_theta * math.sqrt(2.0))))

    def parameters(self) -> dict:
        return _parameters(self)

    def radial_law(self, phi) -> tuple[np.ndarray, np.ndarray]:
        """Mean and SD of r | phi for this variant, float64 arrays (through the kernel)."""
        from .raster import evaluate_polar_moments

        return evaluate_polar_moments(self, phi)

    def p_mu(self, phi, *, dtype=np.float64, device="cpu") -> np.ndarray:
        """P_mu(phi), eq. (8): the improved approximation's mean of r given phi (kernel)."""
        from .raster import evaluate_polar_moments

        return evaluate_polar_moments(self, phi, variant="improved", dtype=dtype, device=device)[0]

    def p_sigma(self, phi, *, dtype=np.float64, device="cpu") -> np.ndarray:
        """P_sigma(phi), eq. (11): the improved approximation's SD of r given phi (kernel)."""
        from .raster import evaluate_polar_moments

        return evaluate_polar_moments(self, phi, variant="improved", dtype=dtype, device=device)[1]

    def law_derivatives(self, phi, *, dtype=np.float64, device="cpu") -> np.ndarray:
        """The variant's mean law with its derivatives 1-4 and its SD law with derivatives 1-2,
        at phi: array (..., 8) in that order (for "improved": P_mu (8) and P_sigma (11)),
        analytic, through the kernel that (15)-(16) use."""
        from .raster import evaluate_polar_derivatives

        return evaluate_polar_derivatives(self, phi, dtype=dtype, device=device)

    def conditional_moments(self, theta, *, order=None, dtype=np.float64, device="cpu"):
        """Closed-form E[r | theta] and SD[r | theta] of this model (kernel).

        Without heading noise they are the variant's law at phi = theta (P_mu (8), P_sigma
        (11) for "improved"); with it, (15) and (16) (``order`` 2) or with the fourth-order
        terms (``order`` 4), by default the model's ``heading_order``. SD is 0 outside the
        approximation's domain (P_sigma(theta_bar) <= 0).
        """
        from .raster import evaluate_polar_moments

        if order is None:
            order = self.kernel_order
        elif isinstance(order, bool) or order not in HEADING_ORDERS:
            raise BananagridError(f"order = {order!r}: must be 2 or 4")
        elif self.sigma_heading == 0.0:
            order = 0  # sigma_bar = 0: (15) and (16) reduce to P_mu and P_sigma
        return evaluate_polar_moments(self, theta, order=order, dtype=dtype, device=device)

    def sample(self, n: int, rng) -> np.ndarray:
        """Draw ``n`` world positions: phi, then r given phi (rejecting |phi| > pi, r <= 0).

        With heading noise the bearing is theta = theta_0 + phi, theta_0 ~ N(0, sigma_heading),
        and r | theta follows the model's own law, (15)-(16): samples of the density the kernels
        compute (rejecting |theta| > pi and r <= 0), not of the exact generative story, which
        ``CAT(sigma_heading=...)`` samples.
        """
        n, rng = _check_n(n), _check_rng(rng)
        out = np.empty((0, 2))
        while len(out) < n:
            m = max(2 * (n - len(out)), 16)
            angle = rng.normal(0.0, self.sigma_theta, m)
            mean, sd = self.conditional_moments(angle) if self.sigma_heading > 0.0 else self.radial_law(angle)
            ok = (np.abs(angle) <= np.pi) & (sd > 0)
            r = rng.normal(mean[ok], sd[ok])
            keep = r > 0
            local = np.column_stack((r[keep] * np.sin(angle[ok][keep]), r[keep] * np.cos(angle[ok][keep])))
            out = np.vstack((out, local))
        return self.pose.to_world(out[:n])

    def pdf(self, x, y, *, dtype=np.float64, device="cpu"):
        """Density per m^2 at world points (broadcast x, y), through the same kernels as rasterise."""
        from .raster import evaluate_points

        return evaluate_points(self, x, y, dtype=dtype, device=device)


Model = CAT | PolarBanana


def _parameters(model) -> dict:
    out = {"model": type(model).__name__}
    for f in fields(model):
        value = getattr(model, f.name)
        if isinstance(value, Pose):
            out["origin_x"], out["origin_y"] = value.origin
            out["heading"] = value.heading
        else:
            out[f.name] = value
    return out
