"""The polar-banana approximations of the CAT density (Sections 2, 5 and 7 of the paper)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.special import erfc

from ..domains.pose import Pose
from ..engine.warp_runtime import WarpContext
from ..kernels import polar as kernels
from ..protocol import Extent, KernelBinding, KernelContext, SceneKey, SceneSchema
from ..validate import BananagridError
from .base import check_n, check_rng
from .motion import MOTION_KEYS, MotionModel, pose_arguments

__all__ = ["PolarBanana", "VARIANTS", "HEADING_ORDERS"]

VARIANTS = ("rough", "improved")
HEADING_ORDERS = (2, 4)


def _angles(name: str, values) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if not np.isfinite(values).all():
        raise BananagridError(f"{name}: angles must be finite")
    return values


@dataclass(frozen=True)
class PolarBanana(MotionModel):
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
    #: float32 agreement with float64 where the density exceeds 1e-6 of its peak, beyond the
    #: density's change over the point's float32 rounding (``DensityModel.float32_rtol``).
    float32_rtol = 6e-5
    scene = SceneSchema(
        keys=(
            MOTION_KEYS["v0"], MOTION_KEYS["t"], MOTION_KEYS["sigma_a"], MOTION_KEYS["sigma_omega"],
            SceneKey("variant", type="choice", default='`"improved"`', choices=VARIANTS,
                     allowed='`"rough"` (Section 2), `"improved"` (P_mu (8), P_sigma (11))'),
            MOTION_KEYS["sigma_heading"],
            SceneKey("heading_order", default="`2`",
                     allowed="`2`: (15), (16); `4`: with the fourth-order terms after Figure 8 "
                             "(only used when `sigma_heading` > 0)"),
            MOTION_KEYS["origin"], MOTION_KEYS["heading"],
        ),
        required=("v0", "sigma_a", "sigma_omega"),
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

    def singular_points(self) -> np.ndarray:
        """The origin of the pose: the plane density g(phi) g(r) / r is infinite there like 1 / r
        wherever g(r = 0) is not negligible (cell probabilities integrate about it in polar
        coordinates, :mod:`bananagrid.engine.grid_cells`)."""
        return np.reshape(np.asarray(self.pose.origin, dtype=np.float64), (1, 2))

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
        out = ctx.zeros((phi.size, 8))
        if phi.size:
            ctx.launch(kernels.polar_derivatives, dim=phi.size,
                       inputs=[ctx.array(phi.ravel()), self._coefficients(ctx), self._law(), out])
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
        n, rng = check_n(n), check_rng(rng)
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

    # --- kernels ------------------------------------------------------------------------------

    def _coefficients(self, ctx: KernelContext):
        """The kernels' coefficient array: P_mu (8), P_sigma (11) and heading-law factors."""
        return ctx.array(kernels.coefficients(self.v0, self.t, self.sigma_a, self.sigma_omega, self.sigma_heading))

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
            ctx.launch(kernels.polar_moments, dim=phi.size, inputs=[
                ctx.array(phi.ravel()), self._coefficients(ctx), self._law(variant), int(order), mean, sd,
            ])
        return ctx.numpy(mean).reshape(phi.shape), ctx.numpy(sd).reshape(phi.shape)

    def bind(self, ctx: KernelContext, extent: Extent, *, grid: bool = False) -> KernelBinding:
        """The closed-form kernels (``kernels/polar.py``): one row per CPU thread."""
        params = (self._coefficients(ctx), self._law(), self.kernel_order, ctx.array(self.pose.as_array()))
        notes = {"variant": self.variant, "truncated_mass": self.truncated_mass}
        if self.sigma_heading > 0.0:
            notes["heading_order"] = self.heading_order
        return KernelBinding(
            kernels.polar_grid, kernels.polar_points, params, "polar.polar_grid", notes, row_loop=True,
            bands_per_thread=1,
        )

    # --- batches (bananagrid.engine.batch) ----------------------------------------------------

    @classmethod
    def frame_bounds(cls, models: Sequence[PolarBanana], sds: float) -> np.ndarray:
        """World boxes ``(x0, x1, y0, y1)`` of each hypothesis, vectorised over them: the
        bounding box of bearings within +-min(pi, sds sigma_theta) and ranges within
        v0 t sinc(theta) -+ sds s, with s = sigma_a t^2 / 2 + 0.44 v0 t sigma_bar a bound on the
        SD of r given the bearing (P_sigma <= sigma_a t^2 / 2 (1 + sigma_a^2 t^2 / (72 v0^2)),
        |P_mu - v0 t sinc| << s, and the heading blur adds |P_mu'| sigma_bar with
        |sinc'| <= 0.44), and the origin."""
        v0t = np.array([m.v0 * m.t for m in models])[:, None]
        spread = np.array([0.5 * m.sigma_a * m.t**2 * (1 + (m.sigma_a * m.t / m.v0) ** 2 / 72) for m in models])[:, None]
        spread = spread + 0.44 * v0t * np.array([m.sigma_bar for m in models])[:, None]
        top = np.minimum(math.pi, sds * np.array([m.sigma_theta for m in models]))[:, None]
        b = top * np.linspace(-1.0, 1.0, 129)[None, :]
        mean = v0t * np.sinc(b / math.pi)
        r = np.concatenate([np.maximum(0.0, mean - sds * spread), mean + sds * spread, np.zeros_like(mean[:, :1])], axis=1)
        b = np.concatenate([b, b, np.zeros_like(b[:, :1])], axis=1)
        lx, ly = r * np.sin(b), r * np.cos(b)
        heading = np.array([m.pose.heading for m in models])[:, None]
        origin = np.array([m.pose.origin for m in models])
        c, s = np.cos(heading), np.sin(heading)
        wx = origin[:, :1] + lx * c + ly * s
        wy = origin[:, 1:] - lx * s + ly * c
        return np.column_stack((wx.min(axis=1), wx.max(axis=1), wy.min(axis=1), wy.max(axis=1)))

    @classmethod
    def batch_binding(cls, ctx: KernelContext, models: Sequence[PolarBanana]) -> KernelBinding:
        """Per-hypothesis coefficient rows, variants, heading orders and poses for the batch
        kernels, which run the same device function as the grid kernel."""
        coefs = np.array([
            kernels.coefficients(m.v0, m.t, m.sigma_a, m.sigma_omega, m.sigma_heading) for m in models
        ])
        variants = np.array([m._law() for m in models], dtype=np.int32)
        orders = np.array([m.kernel_order for m in models], dtype=np.int32)
        poses = np.array([m.pose.as_array() for m in models])
        params = (ctx.array(coefs), ctx.array(variants, dtype=np.int32), ctx.array(orders, dtype=np.int32),
                  ctx.array(poses))
        return KernelBinding(kernels.polar_batch_grid, kernels.polar_batch_points, params, "polar.polar_batch_grid")
