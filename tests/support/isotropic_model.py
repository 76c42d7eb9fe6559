"""A model defined only in the tests: an isotropic normal N(mean, sigma^2 I).

It shows that a model plugs into bananagrid through the model protocol alone: its maths is a
``@wp.func`` density over a typed parameter struct, written here, from which the package's
generator makes its grid and points kernels (no launch code); its class derives from
``bananagrid.Model``, and a registry entry (``ISOTROPIC``) gives it scene layers. Nothing in the
package names it.
"""

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

import bananagrid as bg
from bananagrid.kernels.generate import SCALAR, Params, density_kernels
from bananagrid.protocol import KernelBinding, SceneKey, SceneSchema
from bananagrid.validate import point, positive


@wp.func
def isotropic_density(x: Any, y: Any, p: Any):
    """Density per m^2 at the world point (x, y): its maths, all that it writes of kernels."""
    dx = x - p.mean_x
    dy = y - p.mean_y
    return p.norm * wp.exp(type(x)(-0.5) * (dx * dx + dy * dy) * p.inv_var)


#: Its parameters: the mean, 1 / sigma^2 and 1 / (2 pi sigma^2); its kernels, generated.
PARAMS = Params("IsotropicParams", __name__, mean_x=SCALAR, mean_y=SCALAR, inv_var=SCALAR, norm=SCALAR)
KERNELS = density_kernels(isotropic_density, PARAMS, "isotropic")


@dataclass(frozen=True)
class IsotropicNormal(bg.Model):
    """N(mean, sigma^2 I) in the world plane."""

    mean: tuple = (0.0, 0.0)
    sigma: float = 1.0

    kind = "isotropic"
    # one rounding of exp's argument: |z|^2 / 2 <= 14 where the density exceeds 1e-6 of its peak,
    # so float32 errs by about 14 * 6e-8 = 1e-6; 1e-5 allows for the exp itself
    float32_rtol = 1e-5
    scene = SceneSchema(
        keys=(SceneKey("mean", type="pair", unit="m"), SceneKey("sigma", unit="m", allowed="finite, > 0")),
        required=("mean", "sigma"),
        timed=False,
        build=lambda params: IsotropicNormal(**params),
        summary="an isotropic normal (a model of the tests)",
    )

    def __post_init__(self):
        object.__setattr__(self, "mean", point("mean", self.mean))
        object.__setattr__(self, "sigma", positive("sigma", self.sigma))

    def bind(self, ctx, extent, *, grid=False):
        s2 = self.sigma * self.sigma
        return KernelBinding(KERNELS, ctx.struct(PARAMS, mean_x=self.mean[0], mean_y=self.mean[1], inv_var=1.0 / s2,
                                                 norm=1.0 / (2.0 * math.pi * s2)))

    def sample(self, n, rng):
        return rng.normal(self.mean, self.sigma, (n, 2))

    def polar_scales(self, origin=(0.0, 0.0)):
        distance = math.dist(origin, self.mean)
        return self.sigma, (self.sigma / distance if distance > 0.0 else 2.0 * math.pi)

    def feature_scale(self):
        return self.sigma

    def radial_extent(self, pose):
        return self.sigma, math.dist(pose.origin, self.mean) + 12.0 * self.sigma


#: Its registry entry: with ``bg.MODEL_KINDS.with_kinds(ISOTROPIC)`` scenes may use it.
ISOTROPIC = bg.ModelKind("isotropic", IsotropicNormal)
