"""The bearing-fix kernels in CPU lanes: 8 float64 or 16 float32 cells at a time.

The same log density as ``bearing.bearing_log_density`` (the exact variant's sum over sensors
of -wrap(beta_i - b_i)^2 / (2 sigma_i^2) with the lane atan2, or the linear variant's
quadratic form, two squares of halved offsets), in the scalar kernel's order of operations, then one lane exp. The scalar
kernel, one cell at a time, ran at 0.7x NumPy's speed on one core (NumPy's arctan2 and exp are
SIMD loops); here every step is one vector of cells.

CPU only (see ``kernels/lanes.py``); the GPU path uses ``bearing.KERNELS``. The grid and
points kernels are generated from :func:`bearing_world_lanes`, so that ``rasterise`` and ``pdf``
agree bit for bit.
"""

from typing import Any

import warp as wp

from .bearing import BEARING, HEAD, LINEAR, PER_SENSOR
from .generate import density_kernels
from .lanes import lane_atan2, lane_exp, lane_wrap_angle

# No adjoints: nothing differentiates these kernels (see ``polar_lanes``).
wp.set_module_options({"enable_backward": False})


@wp.func(inline=True)
def bearing_density_lanes(x: Any, y: Any, params: wp.array(dtype=Any), n_sensors: int, variant: int):
    """exp(log p) at a vector of world points (see ``bearing.bearing_log_density``)."""
    half = type(x)(0.5)
    if variant == LINEAR:
        s_half = type(params[0])(0.5)
        dx = x * s_half - type(x)(params[1] * s_half)
        dy = y * s_half - type(x)(params[2] * s_half)
        u = dx + dy * params[4]
        q = wp.cw_mul(u * params[3], u) + wp.cw_mul(dy * params[5], dy)  # a quarter of the form
        return lane_exp(type(x)(params[0]) - q * type(params[0])(2.0))
    total = type(x)(params[0])
    for i in range(n_sensors):
        base = HEAD + PER_SENSOR * i
        beta = lane_atan2(x - type(x)(params[base]), y - type(x)(params[base + 1]))
        z = lane_wrap_angle(beta - type(x)(params[base + 2])) * params[base + 3]
        total = total - wp.cw_mul(wp.cw_mul(half, z), z)
    return lane_exp(total)


@wp.func(inline=True)
def bearing_world_lanes(x: Any, y: Any, p: Any):
    """The density at a vector of world points: the launch kernels' maths."""
    return bearing_density_lanes(x, y, p.params, p.n_sensors, p.variant)


KERNELS = density_kernels(bearing_world_lanes, BEARING, "bearing", lanes=True, bands_per_thread=4)
