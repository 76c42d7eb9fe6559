"""The polar-banana approximations of the CAT density (Sections 2, 5 and 7 of the paper)."""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Sequence

import numpy as np
from scipy import stats
from scipy.special import erfc

from ..domains.pose import Pose
from ..engine.warp_runtime import WarpContext
from ..kernels import polar as kernels
from ..kernels import polar_lanes
from ..protocol import Extent, KernelBinding, KernelContext, SceneSchema
from ..validate import BananagridError, BananagridWarning
from .base import check_n, check_rng
from .motion import MotionModel, motion_param, pose_arguments
from .params import modelclass, param

__all__ = ["PolarBanana", "VARIANTS", "HEADING_ORDERS"]

VARIANTS = ("rough", "improved")
HEADING_ORDERS = (2, 4)


def _angles(name: str, values) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if not np.isfinite(values).all():
        raise BananagridError(f"{name}: angles must be finite")
    return values


# --- proved density bounds (PolarBanana.density_bound) ------------------------------------------
# Closed intervals are (lo, hi) tuples of float64. Each helper that stands for one kernel operation
# widens its exact range outward by one float32 rounding (2^-24 relative, doubled for the float64
# arithmetic of the endpoints, plus float32's smallest subnormal for an underflow): the float32 or
# float64 value the kernel computes from operands inside the argument intervals then lies inside.

#: float32's unit roundoff (float64's is finer, so what holds in float32 holds in float64).
_U = 2.0**-24
#: float32's smallest subnormal: the absolute error of an operation that underflows.
_TINY = 2.0**-149
#: Absolute error of the kernels' sinc derivatives (``common.sinc_derivatives``) at |x| <= 4 in
#: float32: about 10 u measured; 128 u assumed.
_SINC_SLACK = 128.0 * _U
#: Relative error of ``common.atan2_fast`` in float32: 2.5 u measured over 2e6 points (its result
#: is a rational function of |x| / |y| and pi / 2, pi sums of magnitude >= pi / 4); 16 u assumed.
_ATAN_SLACK = 16.0 * _U
#: Intermediates of the kernel stay below this magnitude (or no bound is given): far from
#: float32's overflow at 3.4e38, so every operation rounds by at most _U relative.
_NO_OVERFLOW = 1e36
#: Seconds of one core a cell or point assumed by :meth:`PolarBanana.work_estimate`, without and
#: with heading noise: about 20 and 10 times the measured cost (5.1 and 20.7 ns a cell, float64;
#: float32 3.5 and 30 ns; Figure 1's grid at 4 m, Intel Xeon AVX-512, one thread), room for a CPU
#: with half the lanes or none.
SECONDS_PER_CELL = 1.0e-7
SECONDS_PER_HEADING_CELL = 3.0e-7


def _rounded(lo: float, hi: float) -> tuple[float, float]:
    """[lo, hi] widened by one float32 rounding."""
    return lo - 2.0 * _U * abs(lo) - _TINY, hi + 2.0 * _U * abs(hi) + _TINY


def _f32(c: float) -> tuple[float, float]:
    """A float64 constant rounded to float32 (subnormal included)."""
    return _rounded(c, c)


def _add(a, b):
    return _rounded(a[0] + b[0], a[1] + b[1])


def _sub(a, b):
    return _rounded(a[0] - b[1], a[1] - b[0])


def _mul(a, b):
    p = (a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1])
    return _rounded(min(p), max(p))


def _scale(a, k: float):
    """``a`` times an exact constant ``k`` (a float literal of the kernel)."""
    return _rounded(min(a[0] * k, a[1] * k), max(a[0] * k, a[1] * k))


def _sq(a):
    """x * x for one x in ``a`` (not the product of two independent values of ``a``): >= 0."""
    lo, hi = a
    low = 0.0 if lo <= 0.0 <= hi else min(lo * lo, hi * hi)
    low, top = _rounded(low, max(lo * lo, hi * hi))
    return max(0.0, low), top


def _widen(a, slack: float):
    return a[0] - slack, a[1] + slack


def _sinc_derivatives(x: float, n: int) -> list[float]:
    """sinc(x) = sin(x) / x and its derivatives 1..n (n <= 5) in float64: the upward recurrence
    x s_k + k s_(k-1) = sin^(k)(x) for |x| >= 1.5, the series sum_j (-1)^j x^(2j) / (2j+1)!
    differentiated term by term below (as ``common.sinc_derivatives``; errors below 1e-14)."""
    if abs(x) >= 1.5:
        trig = (math.sin(x), math.cos(x), -math.sin(x), -math.cos(x))
        out = [trig[0] / x]
        for k in range(1, n + 1):
            out.append((trig[k % 4] - k * out[-1]) / x)
        return out
    out = [0.0] * (n + 1)
    a = 1.0  # (-1)^j / (2j+1)!
    for j in range(14):  # at |x| = 1.5 the 14th term is below 1e-22
        m = 2 * j
        falling = 1.0  # m (m-1) ... (m-k+1): d^k/dx^k x^m = falling x^(m-k)
        for k in range(min(n, m) + 1):
            out[k] += a * falling * x ** (m - k)
            falling *= m - k
        a = -a / ((m + 2) * (m + 3))
    return out


def _span(lo: float, hi: float) -> tuple[float, float]:
    """Midpoint c and a radius h >= |x - c| for every x of [lo, hi] (float64 rounding included)."""
    c = 0.5 * (lo + hi)
    return c, max(hi - c, c - lo) + 1e-15 * (abs(lo) + abs(hi))


def _sinc_enclosure(lo: float, hi: float, n: int) -> list[tuple[float, float]]:
    """Intervals holding sinc^(k)(x), k = 0..n, for every x of [lo, hi].

    sinc(x) = int_0^1 cos(x t) dt, so sinc^(k)(x) = int_0^1 t^k cos^(k)(x t) dt and
    |sinc^(k)| <= 1 / (k + 1) everywhere. By Taylor's theorem about the midpoint c, with h the
    half-width, sinc^(k)(x) is within min(h / (k + 2), |sinc^(k+1)(c)| h + h^2 / (2 (k + 3)))
    of sinc^(k)(c).
    """
    c, h = _span(lo, hi)
    d = _sinc_derivatives(c, n + 1)
    out = []
    for k in range(n + 1):
        top = 1.0 / (k + 1)
        w = min(h / (k + 2), abs(d[k + 1]) * h + 0.5 * h * h / (k + 3)) + 1e-14
        out.append((max(-top, d[k] - w), min(top, d[k] + w)))
    return out


def _trig_enclosure(lo: float, hi: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """Intervals holding cos(x) and sin(x) for every x of [lo, hi] (Taylor about the midpoint,
    |cos''|, |sin''| <= 1)."""
    c, h = _span(lo, hi)
    cc, sc = math.cos(c), math.sin(c)
    wc = min(h, abs(sc) * h + 0.5 * h * h) + 1e-15
    ws = min(h, abs(cc) * h + 0.5 * h * h) + 1e-15
    return (max(-1.0, cc - wc), min(1.0, cc + wc)), (max(-1.0, sc - ws), min(1.0, sc + ws))


#: Bearings at which :meth:`PolarBanana.frame_bounds` samples each curve, and hypotheses per block.
FRAME_BEARINGS, FRAME_BLOCK = 129, 128


def _wrap(angle: float) -> float:
    """``angle`` modulo 2 pi in [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@modelclass
class PolarBanana(MotionModel):
    """Polar approximation of the CAT density (Sections 2 and 5 of the polar-banana paper).

    phi ~ N(0, sigma_omega t / 2) is the bearing from the initial heading, r | phi normal with
    mean and SD ``v0 t sinc(phi)`` and ``sigma_a t^2 / 2`` (``variant="rough"``) or P_mu (8) and
    P_sigma (11) (``variant="improved"``); the density in the plane is
    g(phi) g(r; mean, sd) / r.

    Notes
    -----
    P_sigma (11) turns negative where phi^2 > sigma_omega^2 (t^2 / 12 + 6 v0^2 / sigma_a^2); the
    improved density is set to 0 there and a warning is issued when that angle is below pi.
    Samples are drawn from the law restricted to |phi| <= pi and r > 0, the support of the
    plane density. Where P_mu(phi) comes near 0 (phi near +-pi when sigma_omega t is large) the
    density keeps the 1/r of the polar Jacobian: integrable, but cell-centre samples near the
    origin grow as the grid is refined.
    """

    v0: float = motion_param("v0")
    t: float = motion_param("t")
    sigma_a: float = motion_param("sigma_a")
    sigma_omega: float = motion_param("sigma_omega")
    variant: str = param(
        "improved", type="choice", choices=VARIANTS, py='{"rough", "improved"}',
        domain='`"rough"` (Section 2), `"improved"` (P_mu (8), P_sigma (11))',
        doc="Which approximation: the rough normal range law of Section 2, or P_mu (8) and P_sigma (11).")
    sigma_heading: float = motion_param(
        "sigma_heading",
        doc="Standard deviation sigma_0 of a normal error on the initial heading (Section 7). The bearing is "
            "then theta ~ N(0, sigma_theta), sigma_theta^2 = sigma_0^2 + sigma_phi^2, and r | theta is normal "
            "with the mean (15) and SD (16) built from the variant's P_mu and P_sigma at theta_bar = theta "
            "sigma_phi^2 / sigma_theta^2.")
    heading_order: int = param(
        2, py="{2, 4}",
        domain="`2`: (15), (16); `4`: with the fourth-order terms after Figure 8 (only used when "
               "`sigma_heading` > 0)",
        doc="2: (15) and (16) as printed; 4: with (1/8) P_mu^(4) sigma_bar^4 in the mean and the fourth-order "
            "variance terms given after Figure 8. Only used when sigma_heading > 0.")
    pose: Pose = motion_param("pose")

    kind = "polar"
    #: Peak bytes per sample of :meth:`sample` (its rejection loop): 132 measured (tracemalloc,
    #: ``sample(10**6)``, with and without heading noise), rounded up.
    sample_bytes = 192
    #: float32 agreement with float64 where the density exceeds 1e-6 of its peak, beyond the
    #: density's change over the point's float32 rounding (``DensityModel.float32_rtol``).
    float32_rtol = 6e-5
    scene = SceneSchema(
        timed=True,
        build=lambda params: PolarBanana(**pose_arguments(params)),
        radial_curves=True,
        summary="the polar approximations of the CAT density (Sections 2, 5 and 7 of the polar-banana paper)",
    )

    def __post_init__(self):
        self._validate_motion()
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
                BananagridWarning, stacklevel=4,
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

    def singular_points(self) -> np.ndarray:
        """The origin of the pose: the plane density g(phi) g(r) / r is infinite there like 1 / r
        wherever g(r = 0) is not negligible (cell probabilities integrate about it in polar
        coordinates, :mod:`bananagrid.engine.grid_cells`)."""
        return np.reshape(np.asarray(self.pose.origin, dtype=np.float64), (1, 2))

    def seams(self) -> np.ndarray:
        """Rays from the origin of the pose (:meth:`bananagrid.protocol.DensityModel.seams`):
        behind the start, where the angle (phi, or theta with heading noise) wraps from pi to
        -pi (the density is continuous there, its slope across the ray is not); for the
        improved variant, where P_sigma (11) reaches 0 inside (-pi, pi) (beyond it the density
        is 0: a jump with heading noise, the ridge's limit without), |phi| =
        :attr:`sigma_positive_limit`, |theta| = that over theta_bar / theta."""
        x, y = self.pose.origin
        h = self.pose.heading
        rays = [(x, y, _wrap(h + math.pi))]
        if self.variant == "improved":
            edge = self.sigma_positive_limit
            if self.kernel_order:
                edge *= (self.sigma_theta / self.sigma_phi) ** 2  # theta_bar = theta sigma_phi^2 / sigma_theta^2
            if edge < math.pi:
                rays += [(x, y, _wrap(h + edge)), (x, y, _wrap(h - edge))]
        return np.array(rays, dtype=np.float64)

    def polar_law(self, origin):
        """About the origin of the pose, the density is g(angle) N(r; mean, sd) / r
        (:meth:`bananagrid.protocol.DensityModel.polar_law`): the angle phi (theta with heading
        noise) is the bearing from the heading wrapped to (-pi, pi], g its normal density
        (SD sigma_phi, or sigma_theta), mean and sd the kernel's law of r given it
        (:meth:`conditional_moments`); None about any other point."""
        if tuple(float(c) for c in origin) != tuple(float(c) for c in self.pose.origin):
            return None
        sd_angle = self.sigma_theta
        heading = self.pose.heading

        def law(theta):
            theta = np.asarray(theta, dtype=np.float64)
            angle = np.pi - (np.pi - (theta - heading)) % (2.0 * np.pi)  # in (-pi, pi]
            g = np.exp(-0.5 * (angle / sd_angle) ** 2) / (math.sqrt(2.0 * math.pi) * sd_angle)
            mean, sd = self.conditional_moments(angle)
            return g, mean, sd

        return law

    def radial_law(self, phi) -> tuple[np.ndarray, np.ndarray]:
        """Mean and SD of r | phi for this variant, float64 arrays (through the kernel)."""
        return self._moments(phi)

    def p_mu(self, phi, *, dtype=np.float64, device="cpu") -> np.ndarray:
        """P_mu(phi), eq. (8): the improved approximation's mean of r given phi (kernel)."""
        return self._moments(phi, variant="improved", dtype=dtype, device=device)[0]

    def p_sigma(self, phi, *, dtype=np.float64, device="cpu") -> np.ndarray:
        """P_sigma(phi), eq. (11): the improved approximation's SD of r given phi (kernel)."""
        return self._moments(phi, variant="improved", dtype=dtype, device=device)[1]

    def law_derivatives(self, phi, *, dtype=np.float64, device="cpu") -> np.ndarray:
        """The variant's mean law with its derivatives 1-4 and its SD law with derivatives 1-2,
        at phi: array (..., 8) in that order (for "improved": P_mu (8) and P_sigma (11)),
        analytic, through the kernel that (15)-(16) use."""
        phi = _angles("phi", phi)
        ctx = WarpContext(dtype, device)
        out = ctx.zeros(phi.size, dtype=ctx.vector(8))
        if phi.size:
            ctx.launch(kernels.polar_derivatives, dim=phi.size, inputs=[ctx.array(phi.ravel()), self._params(ctx), out])
        return ctx.numpy(out).reshape(phi.shape + (8,))

    def conditional_moments(self, theta, *, order=None, dtype=np.float64, device="cpu"):
        """Closed-form E[r | theta] and SD[r | theta] of this model (kernel).

        Without heading noise they are the variant's law at phi = theta (P_mu (8), P_sigma
        (11) for "improved"); with it, (15) and (16) (``order`` 2) or with the fourth-order
        terms (``order`` 4), by default the model's ``heading_order``. SD is 0 outside the
        approximation's domain (P_sigma(theta_bar) <= 0).
        """
        if order is None:
            order = self.kernel_order
        elif isinstance(order, bool) or order not in HEADING_ORDERS:
            raise BananagridError(f"order = {order!r}: must be 2 or 4")
        elif self.sigma_heading == 0.0:
            order = 0  # sigma_bar = 0: (15) and (16) reduce to P_mu and P_sigma
        return self._moments(theta, order=order, dtype=dtype, device=device)

    def sample(self, n: int, rng) -> np.ndarray:
        """Draw ``n`` world positions: phi, then r given phi (rejecting |phi| > pi, r <= 0).

        With heading noise the bearing is theta = theta_0 + phi, theta_0 ~ N(0, sigma_heading),
        and r | theta follows the model's own law, (15)-(16): samples of the density the kernels
        compute (rejecting |theta| > pi and r <= 0), not of the exact generative story, which
        ``CAT(sigma_heading=...)`` samples.
        """
        n, rng = check_n(n, self.sample_bytes), check_rng(rng)
        out = np.empty((0, 2))
        sd_angle = self.sigma_theta
        # rejecting |angle| > pi keeps erf(pi / (sd sqrt 2)) of the draws: below 1e-3 (sd above
        # about 2500 rad) rejection would run for ever, so the angle comes from its law truncated
        # to [-pi, pi] directly (the same law; other draws than the rejection loop's)
        truncated = math.erf(math.pi / (sd_angle * math.sqrt(2.0))) < 1e-3
        while len(out) < n:
            m = max(2 * (n - len(out)), 16)
            if truncated:
                angle = stats.truncnorm.rvs(-math.pi / sd_angle, math.pi / sd_angle, scale=sd_angle, size=m,
                                            random_state=rng)
            else:
                angle = rng.normal(0.0, sd_angle, m)
            mean, sd = self.conditional_moments(angle) if self.sigma_heading > 0.0 else self.radial_law(angle)
            ok = (np.abs(angle) <= np.pi) & (sd > 0)
            r = rng.normal(mean[ok], sd[ok])
            keep = r > 0
            local = np.column_stack((r[keep] * np.sin(angle[ok][keep]), r[keep] * np.cos(angle[ok][keep])))
            out = np.vstack((out, local))
        return self.pose.to_world(out[:n])

    # --- proved bounds (tiled rasterising) -------------------------------------------------------

    def work_estimate(self, cells: int, extent) -> float:
        """``SECONDS_PER_CELL`` a cell (``SECONDS_PER_HEADING_CELL`` with heading noise): the
        density is closed-form, its cost per cell the same everywhere
        (:meth:`bananagrid.protocol.DensityModel.work_estimate`)."""
        return float(cells) * (SECONDS_PER_HEADING_CELL if self.sigma_heading > 0.0 else SECONDS_PER_CELL)

    def density_bound(self, x0: float, x1: float, y0: float, y1: float) -> float:
        """A proved upper bound of the density the grid kernel computes, in float32 or float64,
        at any point of the world rectangle ``[x0, x1] x [y0, y1]``
        (:meth:`bananagrid.protocol.DensityModel.density_bound`).

        The kernel computes  NORM / (sd r) exp(-(z_phi^2 + z_r^2) / 2),  z_phi = phi / sigma_phi,
        z_r = (r - mu) / sd,  with mu, sd the rough law or P_mu (8), P_sigma (11) at phi; with
        heading noise the angle's SD is sigma_theta and mu, sd are E[r | theta], SD[r | theta]
        of (15)-(16) (order 2, or 4 with the terms after Figure 8) at theta_bar (12). Over the
        rectangle (u = 2^-24, float32's unit roundoff; float64 rounds less):

        1. r lies in [r_lo, r_hi], the distances of the rectangle's nearest and farthest points
           from the pose origin, and phi in the arc its corners span seen from there (in two
           pieces where it crosses +-pi); both are widened for the float32 rounding of the
           kernel's local point (8 u of the coordinates' sizes), of its sqrt and of its atan2.
        2. mu and sd are enclosed by interval arithmetic that follows the kernel's operations
           one by one, each widened by a float32 rounding, from enclosures of sinc, its
           derivatives, cos and sin over the arc: Taylor's theorem about the arc's midpoint
           with |sinc^(k)| <= 1 / (k + 1) (sinc(x) = int_0^1 cos(x t) dt) and |cos''| <= 1,
           plus the kernels' own errors.
        3. With phi_min the least |phi| of the arc, d the distance from [r_lo, r_hi] to the
           interval of mu and sd in [sd_lo, sd_hi] (sd_lo > 0), the density is at most

               NORM (1 + 16 u) / (s r_lo) exp(-(1 - 16 u) (phi_min^2 / sigma_phi^2 + d^2 / s^2) / 2)

           with s = d sqrt(1 - 16 u) clamped to [sd_lo, sd_hi] (where (1 / s) exp(-c d^2 / s^2)
           is largest), plus the float32 subnormals an underflowing exp or product rounds to.

        Returns
        -------
        float
            The bound; ``0.0`` where the kernel provably computes exact zeros: its SD not
            positive (the improved variant beyond ``sigma_positive_limit``) or its exp below
            e^-760 (0 in float32 and float64) over the whole rectangle; ``math.inf`` where the
            rectangle comes within rounding of the pose origin (the density grows like 1 / r
            there), where the SD may come arbitrarily near 0 (the edge of the improved
            variant's domain), for non-finite corners, and for parameters whose float32
            intermediates could overflow.
        """
        consts = self._bound_constants()
        box = (float(x0), float(x1), float(y0), float(y1))
        if consts is None or not all(map(math.isfinite, box)):
            return math.inf
        x0, x1 = sorted(box[:2])
        y0, y1 = sorted(box[2:])
        ox, oy = self.pose.origin
        ex0, ex1, ey0, ey1 = x0 - ox, x1 - ox, y0 - oy, y1 - oy
        wide_x, wide_y = max(abs(ex0), abs(ex1)), max(abs(ey0), abs(ey1))
        near = math.hypot(max(ex0, 0.0, -ex1), max(ey0, 0.0, -ey1))
        far = math.hypot(wide_x, wide_y)
        # the kernel's local point is within delta of the exact one: float32 world coordinates and
        # origin (u of each), their difference, the rounded cos and sin of the heading, the rotation
        delta = 8.0 * _U * (max(abs(x0), abs(x1)) + max(abs(y0), abs(y1)) + abs(ox) + abs(oy) + wide_x + wide_y)
        if not near > max(2.0 * delta, 1e-18):
            return math.inf  # at the origin the density grows like 1 / r (float32 x^2 underflows)
        r_lo = (near - delta) * (1.0 - 4.0 * _U)  # and the kernel's sqrt(x^2 + y^2) rounds
        r_hi = (far + delta) * (1.0 + 4.0 * _U)
        # a convex set that misses the origin subtends less than pi: the arc of bearings about
        # its centre's bearing runs between two of its corners
        centre = math.atan2(0.5 * (ex0 + ex1), 0.5 * (ey0 + ey1))
        offsets = [_wrap(math.atan2(ex, ey) - centre) for ex in (ex0, ex1) for ey in (ey0, ey1)]
        slack = math.asin(delta / near) + 1e-15 + 4e-16 * abs(self.pose.heading)
        mid = _wrap(centre - self.pose.heading)  # phi = world bearing - heading
        lo, hi = mid + min(offsets) - slack, mid + max(offsets) + slack
        if lo < -math.pi:  # atan2 gives angles in [-pi, pi]: an arc across +-pi is two
            arcs = ((lo + 2.0 * math.pi, math.pi), (-math.pi, hi))
        elif hi > math.pi:
            arcs = ((lo, math.pi), (-math.pi, hi - 2.0 * math.pi))
        else:
            arcs = ((lo, hi),)
        return max(self._arc_bound(consts, a, b, r_lo, r_hi) for a, b in arcs)

    def _bound_constants(self):
        """``(coefficients, their float32 intervals)`` of the kernels, computed once; None where
        the kernel's intermediates could come near float32's overflow (no bound is proved)."""
        if "_density_bound_constants" in self.__dict__:
            return self.__dict__["_density_bound_constants"]
        coef = kernels.coefficients(self.v0, self.t, self.sigma_a, self.sigma_omega, self.sigma_heading)
        a, k, isp, scale, curv, t_term, iso, _, ist, _, _, sb2 = coef
        top = 1.01 * math.pi  # |phi| and |theta_bar| (<= |theta|) the kernel can see
        inv2 = isp * isp
        if self.variant == "rough":
            mean_top, sd_top = a, scale
        else:  # |sinc^(k)| <= 1 and |scc^(k)| <= 5 / 3 in P_mu (8), P_sigma (11) and derivatives
            mean_top = a + k * (top * top * inv2 + 1.0 + 8.0 * top * inv2 + 12.0 * inv2) * 5.0 / 3.0
            sd_top = scale * (1.0 + curv * (t_term + top * top * iso) + 6.0 * curv * iso * top) * 5.0 / 3.0
        var_top = sd_top * sd_top * (1.0 + 2.0 * sb2) + mean_top * mean_top * (sb2 + sb2 * sb2)
        biggest = max(mean_top * mean_top, sd_top * sd_top, var_top, top * top * inv2, top * ist * top * ist,
                      *map(abs, coef))
        consts = (coef, [_f32(c) for c in coef]) if 4.0 * biggest < _NO_OVERFLOW else None
        self.__dict__["_density_bound_constants"] = consts  # a frozen dataclass: its __dict__ caches
        return consts

    def _arc_bound(self, consts, a: float, b: float, r_lo: float, r_hi: float) -> float:
        """The bound of :meth:`density_bound` where the exact bearing of the kernel's local
        point lies in [a, b] (within [-pi, pi]) and its computed range in [r_lo, r_hi]."""
        coef, c32 = consts
        phi = (a - _ATAN_SLACK * abs(a), b + _ATAN_SLACK * abs(b))  # the kernel's atan2
        if self.kernel_order == 0:
            mean, sd = self._law_enclosure(c32, a, b, phi)
            norm, inv_sigma = coef[kernels.NORM], coef[kernels.INV_SIGMA_PHI]
        else:
            mean, var, s0 = self._heading_enclosure(c32, phi)
            if s0[1] <= 0.0 or var[1] <= 0.0:
                return 0.0  # the kernel's SD is 0 there, and its density 0
            sd = (math.sqrt(max(var[0], 0.0)) * (1.0 - _U), math.sqrt(var[1]) * (1.0 + _U))
            norm, inv_sigma = coef[kernels.THETA_NORM], coef[kernels.INV_SIGMA_THETA]
        if sd[1] <= 0.0:
            return 0.0  # the kernel returns 0 where its SD is not positive
        factor = norm * (1.0 + 16.0 * _U)  # NORM, 1 / sd, 1 / r, exp and three products round
        if not (sd[0] > 1e-30 and factor / sd[0] < _NO_OVERFLOW):
            return math.inf  # 1 / sd unbounded, or NORM / sd near float32's overflow
        most = factor / (sd[0] * r_lo)  # the largest NORM / (sd r)
        if not most < _NO_OVERFLOW:
            return math.inf
        phi_min = 0.0 if phi[0] <= 0.0 <= phi[1] else min(abs(phi[0]), abs(phi[1]))
        z_phi = phi_min * inv_sigma
        gap = max(r_lo - mean[1], mean[0] - r_hi, 0.0)
        shrink = 1.0 - 16.0 * _U  # the rounding of z_phi^2 + z_r^2
        s = min(max(gap * math.sqrt(shrink), sd[0]), sd[1])
        z_r = gap / s
        bound = factor / (s * r_lo) * math.exp(-0.5 * shrink * (z_phi * z_phi + z_r * z_r))
        z_r = gap / sd[1]
        least = 0.5 * shrink * (z_phi * z_phi + z_r * z_r)  # the kernel's exponent is at least this
        # an exp that underflows is exact to 2 subnormals, the product it enters to one (libm's
        # exp is 0 beyond its underflow threshold: 104 in float32, 746 in float64); a float64
        # value rounded to float32 to one more
        if least < 110.0:
            bound += 4.0 * _TINY * (most + 1.0)
        elif least < 760.0:
            bound += 2.0**-1072 * (most + 1.0)
        if bound > 2.0**-152:
            bound = bound * (1.0 + _U) + _TINY
        return bound

    def _law_enclosure(self, c32, a: float, b: float, phi):
        """Intervals of the kernel's mean and SD of r (``polar_mean_sd``: the rough law, or P_mu
        (8) and P_sigma (11)) where the exact bearing lies in [a, b] and the computed one in
        ``phi``. The kernel's sinc is sin / phi with sin = x / r (within 40 u of sinc), its cos
        y / r (8 u)."""
        sinc = _widen(_sinc_enclosure(a, b, 0)[0], 40.0 * _U)
        if self.variant == "rough":
            return _mul(c32[kernels.MEAN_SINC], sinc), c32[kernels.SD_SCALE]
        cos = _widen(_trig_enclosure(a, b)[0], 8.0 * _U)
        one = (1.0, 1.0)
        scc = _mul(_sub(_scale(sinc, 4.0), cos), _f32(1.0 / 3.0))  # (7), as common.scc_of
        z = _mul(phi, c32[kernels.INV_SIGMA_PHI])
        mean = _add(_mul(c32[kernels.MEAN_SINC], sinc), _mul(_mul(c32[kernels.MEAN_SCC], _sub(_sq(z), one)), scc))
        width = _sub(c32[kernels.SD_T_TERM], _mul(_sq(phi), c32[kernels.INV_SIGMA_OMEGA_SQ]))
        sd = _mul(_mul(c32[kernels.SD_SCALE], _add(one, _mul(c32[kernels.SD_CURVATURE], width))), scc)
        return mean, sd

    def _heading_enclosure(self, c32, phi):
        """Intervals of the kernel's E[r | theta] and Var[r | theta] ((15), (16), order 4's terms)
        and of P_sigma(theta_bar) where the computed angle lies in ``phi``
        (``polar_law_derivatives`` and ``polar_heading_mean_sd``, operation by operation)."""
        x = _mul(phi, c32[kernels.SHRINK])  # theta_bar (12)
        d = [_widen(iv, _SINC_SLACK) for iv in _sinc_enclosure(x[0], x[1], 4)]
        a = c32[kernels.MEAN_SINC]
        zero, one = (0.0, 0.0), (1.0, 1.0)
        if self.variant == "rough":
            m0, m1, m2, m3, m4 = (_mul(a, dk) for dk in d)
            s0, s1, s2 = c32[kernels.SD_SCALE], zero, zero
        else:
            cos, sin = (_widen(iv, 4.0 * _U) for iv in _trig_enclosure(x[0], x[1]))
            c0 = _scale(_sub(_scale(d[0], 4.0), cos), 1.0 / 3.0)  # scc and its derivatives (7)
            c1 = _scale(_add(_scale(d[1], 4.0), sin), 1.0 / 3.0)
            c2 = _scale(_add(_scale(d[2], 4.0), cos), 1.0 / 3.0)
            c3 = _scale(_sub(_scale(d[3], 4.0), sin), 1.0 / 3.0)
            c4 = _scale(_sub(_scale(d[4], 4.0), cos), 1.0 / 3.0)
            inv_sp2 = _sq(c32[kernels.INV_SIGMA_PHI])
            q = _sub(_mul(_sq(x), inv_sp2), one)
            q1 = _mul(_scale(x, 2.0), inv_sp2)
            q2 = _scale(inv_sp2, 2.0)
            k = c32[kernels.MEAN_SCC]
            m0 = _add(_mul(a, d[0]), _mul(_mul(k, q), c0))
            m1 = _add(_mul(a, d[1]), _mul(k, _add(_mul(q, c1), _mul(q1, c0))))
            m2 = _add(_mul(a, d[2]), _mul(k, _add(_add(_mul(q, c2), _mul(_scale(q1, 2.0), c1)), _mul(q2, c0))))
            m3 = _add(_mul(a, d[3]), _mul(k, _add(_add(_mul(q, c3), _mul(_scale(q1, 3.0), c2)),
                                                  _mul(_scale(q2, 3.0), c1))))
            m4 = _add(_mul(a, d[4]), _mul(k, _add(_add(_mul(q, c4), _mul(_scale(q1, 4.0), c3)),
                                                  _mul(_scale(q2, 6.0), c2))))
            curv, u = c32[kernels.SD_CURVATURE], c32[kernels.INV_SIGMA_OMEGA_SQ]
            w = _add(one, _mul(curv, _sub(c32[kernels.SD_T_TERM], _mul(_sq(x), u))))
            w2 = _mul(_scale(curv, -2.0), u)
            w1 = _mul(w2, x)
            scale = c32[kernels.SD_SCALE]
            s0 = _mul(_mul(scale, w), c0)
            s1 = _mul(scale, _add(_mul(w, c1), _mul(w1, c0)))
            s2 = _mul(scale, _add(_add(_mul(w, c2), _mul(_scale(w1, 2.0), c1)), _mul(w2, c0)))
        sb2 = c32[kernels.SIGMA_BAR_SQ]
        mean = _add(m0, _mul(_scale(m2, 0.5), sb2))
        var = _add(_sq(s0), _mul(_sq(m1), sb2))
        if self.kernel_order == 4:
            mean = _add(mean, _mul(_mul(_scale(m4, 0.125), sb2), sb2))
            fourth = _add(_scale(_sq(m2), 0.5), _mul(m1, m3))
            var = _add(_add(var, _mul(_add(_sq(s1), _mul(s0, s2)), sb2)), _mul(_mul(fourth, sb2), sb2))
        return mean, var, s0

    # --- kernels ------------------------------------------------------------------------------

    def _params(self, ctx: KernelContext, variant: str | None = None, order: int | None = None):
        """The kernels' parameter struct: the coefficients of P_mu (8), P_sigma (11) and the
        heading law, the pose, ``variant`` and the heading ``order`` (default: the model's)."""
        coef = kernels.coefficients(self.v0, self.t, self.sigma_a, self.sigma_omega, self.sigma_heading)
        return ctx.struct(kernels.POLAR, **dict(zip(kernels.COEFFICIENTS, coef)), pose=self.pose.as_array(),
                          variant=self._law(variant), order=self.kernel_order if order is None else int(order))

    def _law(self, variant: str | None = None) -> int:
        """The kernels' code of ``variant`` (default: the model's)."""
        return kernels.ROUGH if (variant or self.variant) == "rough" else kernels.IMPROVED

    def _moments(self, phi, *, variant=None, order=0, dtype=np.float64, device: str = "cpu"):
        """Mean and SD of r given the angle: at ``order`` 0 given phi, the model's variant's law
        or ``variant``'s; at ``order`` 2 or 4 given theta with the heading noise, (15)-(16)."""
        phi = _angles("phi", phi)
        ctx = WarpContext(dtype, device)
        mean = ctx.zeros(phi.size)
        sd = ctx.zeros(phi.size)
        if phi.size:
            ctx.launch(kernels.polar_moments, dim=phi.size,
                       inputs=[ctx.array(phi.ravel()), self._params(ctx, variant, order), mean, sd])
        return ctx.numpy(mean).reshape(phi.shape), ctx.numpy(sd).reshape(phi.shape)

    def bind(self, ctx: KernelContext, extent: Extent, *, grid: bool = False) -> KernelBinding:
        """The closed-form kernels (``kernels/polar.py``): one row per CPU thread; on the CPU a vector
        of cells or points at a time (``kernels/polar_lanes.py``)."""
        return self.bind_once(ctx, lambda: self._binding(ctx))

    def _binding(self, ctx: KernelContext) -> KernelBinding:
        notes = {"variant": self.variant, "truncated_mass": self.truncated_mass}
        if self.sigma_heading > 0.0:
            notes["heading_order"] = self.heading_order
        family = polar_lanes.KERNELS if ctx.device == "cpu" else kernels.KERNELS
        return KernelBinding(family, self._params(ctx), notes)

    # --- batches (bananagrid.engine.batch) ----------------------------------------------------

    @classmethod
    def frame_bounds(cls, models: Sequence[PolarBanana], sds: float) -> np.ndarray:
        """World boxes ``(x0, x1, y0, y1)`` of each hypothesis, vectorised over them: the
        bounding box of bearings within +-min(pi, sds sigma_theta) and ranges within
        v0 t sinc(theta) -+ sds s, with s = sigma_a t^2 / 2 + 0.44 v0 t sigma_bar a bound on the
        SD of r given the bearing (P_sigma <= sigma_a t^2 / 2 (1 + sigma_a^2 t^2 / (72 v0^2)),
        |P_mu - v0 t sinc| << s, and the heading blur adds |P_mu'| sigma_bar with
        |sinc'| <= 0.44), and the origin.

        The inner curve's point at each bearing lies between the origin and the outer curve's,
        so the box of the origin and the outer curve holds all three. That curve is sampled at
        FRAME_BEARINGS bearings b_k = k delta (k = -K .. K), in blocks of FRAME_BLOCK hypotheses
        (their arrays stay in cache). Sines and cosines cost more than all the rest (5 ns each
        here): exp(i k delta) is built from exp(i 2^j delta) by products (at most log2 K + 1 of
        them, so within about 10 ulps). r(b) is even in b, so the points of +-b_k are
        (+-r sin b_k, r cos b_k), and at heading h their offsets east,
        r (cos b_k sin h +- sin b_k cos h), are least and greatest at
        r (cos b_k sin h -+ sin b_k |cos h|) (north: r (cos b_k cos h -+ sin b_k |sin h|)), as
        r sin b_k >= 0: each side of the box is the extreme of one sum over the bearings. As
        rounding is monotone, the least ``x0 + d`` over the points is ``x0 +`` the least ``d``
        (framing a thousand hypotheses cost more than rasterising them on 16 x 16 grids)."""
        n_models = len(models)
        cols = np.fromiter(itertools.chain.from_iterable(
            (m.v0, m.t, m.sigma_a, m.sigma_omega, m.sigma_heading, m.pose.heading, *m.pose.origin) for m in models),
            dtype=np.float64, count=8 * n_models).reshape(n_models, 8)
        v0, t, sigma_a, sigma_omega, sigma_heading, heading, ox, oy = (cols[:, k:k + 1] for k in range(8))
        sigma_phi = 0.5 * sigma_omega * t
        sigma_theta = np.hypot(sigma_heading, sigma_phi)
        v0t = v0 * t
        spread = 0.5 * sigma_a * t**2 * (1 + (sigma_a * t / v0) ** 2 / 72)
        reach = sds * (spread + 0.44 * v0t * (sigma_heading * sigma_phi / sigma_theta))  # sds SDs of r | bearing
        half = FRAME_BEARINGS // 2
        delta = np.minimum(math.pi, sds * sigma_theta) / half
        cos_h, sin_h = np.cos(heading), np.sin(heading)
        steps = np.exp(1j * delta * 2.0 ** np.arange(half.bit_length()))  # exp(i 2^j delta)
        inverse_k = 1.0 / np.arange(1, half + 1)
        box = np.empty((n_models, 4))  # least and greatest offset east, then north
        for a in range(0, n_models, FRAME_BLOCK):
            z = slice(a, a + FRAME_BLOCK)
            rot = np.empty((len(steps[z]), half + 1), dtype=complex)  # exp(i k delta), k = 0 .. half
            rot[:, 0] = 1.0
            done, j = 1, 0
            while done <= half:
                n = min(done, half + 1 - done)
                np.multiply(rot[:, :n], steps[z, j:j + 1], out=rot[:, done:done + n])
                done, j = done + n, j + 1
            cos_b, sin_b = np.ascontiguousarray(rot.real), np.ascontiguousarray(rot.imag)
            mean = np.empty(cos_b.shape)
            mean[:, 0] = 1.0  # sin(b) / b at b = 0
            np.multiply(sin_b[:, 1:], inverse_k / delta[z], out=mean[:, 1:])
            mean *= v0t[z]
            mean += reach[z]  # the outer curve
            lx, ly = mean * sin_b, mean * cos_b
            for side, (across, along) in enumerate(((ly * sin_h[z], lx * np.abs(cos_h[z])),
                                                     (ly * cos_h[z], lx * np.abs(sin_h[z])))):
                box[z, 2 * side] = (across - along).min(axis=1)
                box[z, 2 * side + 1] = (across + along).max(axis=1)
        box[:, ::2] = np.minimum(box[:, ::2], 0.0)  # the origin, r = 0
        box[:, 1::2] = np.maximum(box[:, 1::2], 0.0)
        return box + np.column_stack((ox, ox, oy, oy))

    @classmethod
    def batch_binding(cls, ctx: KernelContext, models: Sequence[PolarBanana]) -> KernelBinding:
        """Per-hypothesis coefficient rows, variants, heading orders and poses for the batch
        kernels, which run the same device function as the grid kernel."""
        coefs = np.array([
            kernels.coefficients(m.v0, m.t, m.sigma_a, m.sigma_omega, m.sigma_heading) for m in models
        ])
        params = ctx.structs(kernels.POLAR, len(models), **dict(zip(kernels.COEFFICIENTS, coefs.T)),
                             pose=np.array([m.pose.as_array() for m in models]),
                             variant=[m._law() for m in models], order=[m.kernel_order for m in models])
        # the grids of bind(), row for row
        return KernelBinding(polar_lanes.KERNELS if ctx.device == "cpu" else kernels.KERNELS, params)
