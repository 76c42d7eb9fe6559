"""A density tabulated on a polar lattice, interpolated at grid cells and points.

The lattice holds a density at r_i = r0 + i dr (i = 0 .. n_r - 1) and theta_j = theta0 + j dtheta
(j = 0 .. n_theta - 1, periodic: n_theta dtheta = 2 pi), with theta = atan2(x, y) in the model's
local frame. A point is interpolated by the tensor product of 4-point (cubic) Lagrange stencils
in r and theta, applied to log p so that a locally Gaussian density is reproduced almost exactly
and relative accuracy holds far into the tails; where a stencil touches a value at or below
``floor`` (underflowed tails) the linear values are interpolated instead, clamped at zero.

When the lattice starts at the origin (``mirror`` = 1, n_theta even), stencil rows below it are
reflected through the origin: p(-r, theta) = p(r, theta + pi).
"""

from typing import Any

import warp as wp

from .common import atan2_fast, world_to_local
from .generate import ARRAY2D, SCALAR, VEC4, Params, density_kernels

# No adjoints: nothing differentiates these kernels, and the backward kernels Warp would
# generate for every launch kernel are most of a module's code (the CAT module's CUDA build:
# see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False})


@wp.func
def lagrange4(f: Any):
    """Weights of the cubic Lagrange interpolant through nodes -1, 0, 1, 2 at offset f."""
    one = type(f)(1.0)
    two = type(f)(2.0)
    sixth = one / type(f)(6.0)
    w0 = -f * (f - one) * (f - two) * sixth
    w1 = (f + one) * (f - one) * (f - two) * type(f)(0.5)
    w2 = -(f + one) * f * (f - two) * type(f)(0.5)
    w3 = (f + one) * f * (f - one) * sixth
    return w0, w1, w2, w3


@wp.func
def row_weight(k: int, w0: Any, w1: Any, w2: Any, w3: Any):
    """The k-th of four stencil weights."""
    w = w0
    if k == 1:
        w = w1
    elif k == 2:
        w = w2
    elif k == 3:
        w = w3
    return w


@wp.func
def table_density_local(x: Any, y: Any, p: Any):
    """Interpolated density at a local point."""
    zero = type(x)(0.0)
    n_r = p.table.shape[0]
    n_theta = p.table.shape[1]
    r = wp.sqrt(x * x + y * y)
    u = (r - p.r0) / p.dr
    base = int(wp.floor(u))
    if p.mirror == 0:
        base = wp.clamp(base, 1, n_r - 3)  # one-sided stencils at the lattice's ends
    else:
        base = wp.min(base, n_r - 3)
    fr = u - type(x)(float(base))
    v = (atan2_fast(x, y) - p.theta0) / p.dtheta
    col = int(wp.floor(v))
    ft = v - type(x)(float(col))
    wr0, wr1, wr2, wr3 = lagrange4(fr)
    wt0, wt1, wt2, wt3 = lagrange4(ft)
    log_sum = zero
    lin_sum = zero
    lowest = type(x)(1.0)
    half_turn = n_theta / 2
    for a in range(4):
        i = base - 1 + a
        shift = int(0)
        if i < 0:
            i = -i
            shift = half_turn
        wr = row_weight(a, wr0, wr1, wr2, wr3)
        for b in range(4):
            j = (col - 1 + b + shift) % n_theta
            if j < 0:
                j = j + n_theta
            w = wr * row_weight(b, wt0, wt1, wt2, wt3)
            value = p.table[i, j]
            lin_sum += w * value
            log_sum += w * p.log_table[i, j]
            if b == 0 and a == 0:
                lowest = value
            else:
                lowest = wp.min(lowest, value)
    if lowest > p.floor_value:
        return wp.exp(log_sum)
    return wp.max(lin_sum, zero)


@wp.func
def table_density(x: Any, y: Any, p: Any):
    """Interpolated density per m^2 at the world point (x, y): the launch kernels' maths."""
    lx, ly = world_to_local(x, y, p.pose)
    return table_density_local(lx, ly, p)


#: The parameters: log p and p on the lattice, its geometry, ``mirror``, the pose.
TABLE = Params("TableParams", __name__, log_table=ARRAY2D, table=ARRAY2D, r0=SCALAR, dr=SCALAR, theta0=SCALAR,
               dtheta=SCALAR, floor_value=SCALAR, mirror=int, pose=VEC4)
KERNELS = density_kernels(table_density, TABLE, "table", bands_per_thread=1)
