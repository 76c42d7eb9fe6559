"""A model defined only in the tests: an isotropic normal N(mean, sigma^2 I).

It shows that a model plugs into bananagrid through the model protocol alone: its Warp kernels
are written here, its class derives from ``bananagrid.Model``, and a registry entry
(``ISOTROPIC``) gives it scene layers. Nothing in the package names it.
"""

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

import bananagrid as bg
from bananagrid.protocol import KernelBinding, SceneKey, SceneSchema
from bananagrid.validate import point, positive


@wp.func
def isotropic_density(x: Any, y: Any, params: wp.array(dtype=Any)):
    """params = (mean_x, mean_y, 1 / sigma^2, 1 / (2 pi sigma^2))."""
    dx = x - params[0]
    dy = y - params[1]
    return params[3] * wp.exp(type(x)(-0.5) * (dx * dx + dy * dy) * params[2])


@wp.kernel
def isotropic_grid(
    xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), row0: int, params: wp.array(dtype=Any),
    out: wp.array2d(dtype=Any),
):
    i, j = wp.tid()
    out[row0 + i, j] = isotropic_density(xs[j], ys[row0 + i], params)


@wp.kernel
def isotropic_points(
    xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), start: int, params: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    k = start + wp.tid()
    out[k] = isotropic_density(xs[k], ys[k], params)


for _scalar in (wp.float32, wp.float64):
    _vec = wp.array(dtype=_scalar)
    wp.overload(isotropic_grid, {"xs": _vec, "ys": _vec, "params": _vec, "out": wp.array2d(dtype=_scalar)})
    wp.overload(isotropic_points, {"xs": _vec, "ys": _vec, "params": _vec, "out": _vec})


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
        params = ctx.array(np.array([self.mean[0], self.mean[1], 1.0 / s2, 1.0 / (2.0 * math.pi * s2)]))
        return KernelBinding(isotropic_grid, isotropic_points, (params,), "isotropic.isotropic_grid")

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
