"""A constant-velocity target, a model of another package: it starts at N(mean, cov) and moves
at a known velocity, its position spreading by a diffusion q, so that after t seconds it is at
N(mean + velocity t, cov + q t I). Registered by the entry point ``cv`` of the group
``bananagrid.models`` (its distribution's ``entry_points.txt``)."""

import math

import numpy as np

from bananagrid.models.base import Model, check_n, check_rng
from bananagrid.models.params import modelclass, param
from bananagrid.protocol import KernelBinding, SceneSchema
from bananagrid.validate import covariance, non_negative, point

from . import kernels


@modelclass(eq=False)
class ConstantVelocity(Model):
    """A target moving at a known velocity from a normal start: N(mean + velocity t, cov + q t I)."""

    mean: tuple = param(type="pair", unit="m", py="(float, float)", check=point,
                        plain=lambda model, m: {"mean_x": m[0], "mean_y": m[1]}, doc="Mean of the start.")
    cov: np.ndarray = param(type="matrix", unit="m^2", py="array_like, 2x2", check=covariance,
                            doc="Covariance of the start.",
                            plain=lambda model, c: {"cov_xx": c[0, 0], "cov_xy": c[0, 1], "cov_yy": c[1, 1]})
    velocity: tuple = param(type="pair", unit="m/s", py="(float, float)", check=point,
                            plain=lambda model, v: {"velocity_x": v[0], "velocity_y": v[1]}, doc="The velocity.")
    t: float = param(unit="s", check=non_negative, doc="Elapsed time.")
    q: float = param(0.0, unit="m^2/s", check=non_negative, doc="Growth of each position variance per second.")

    kind = "cv"
    # the exponent's rounding: q/2 <= 14 where the density exceeds 1e-6 of its peak, a few
    # float32 ulps (6e-8) of it, and of exp: 1e-5 with room
    float32_rtol = 1e-5
    scene = SceneSchema(timed=True, summary="a constant-velocity target from a normal start")

    @property
    def law(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance of the position at t."""
        mu = np.add(self.mean, np.multiply(self.velocity, self.t))
        return mu, self.cov + self.q * self.t * np.eye(2)

    def bind(self, ctx, extent, *, grid=False):
        mu, s = self.law
        inverse = np.linalg.inv(s)
        norm = 1.0 / (2.0 * math.pi * math.sqrt(np.linalg.det(s)))
        return KernelBinding(kernels.KERNELS, ctx.struct(kernels.PARAMS, mean_x=mu[0], mean_y=mu[1], a=inverse[0, 0],
                                                          b=inverse[0, 1], c=inverse[1, 1], norm=norm))

    def sample(self, n, rng):
        n, rng = check_n(n), check_rng(rng)
        mu, s = self.law
        return rng.multivariate_normal(mu, s, n)

    def _sds(self) -> tuple[float, float]:
        values = np.linalg.eigvalsh(self.law[1])
        return math.sqrt(values[0]), math.sqrt(values[1])

    def polar_scales(self, origin=(0.0, 0.0)):
        narrow = self._sds()[0]
        distance = math.dist(origin, self.law[0])
        return narrow, (narrow / distance if distance > 0.0 else 2.0 * math.pi)

    def feature_scale(self):
        return self._sds()[0]

    def radial_extent(self, pose):
        narrow, wide = self._sds()
        return narrow, math.dist(pose.origin, self.law[0]) + 12.0 * wide
