"""A density tabulated on a polar lattice, interpolated at grid cells and points.

The lattice holds a density at r_i = r0 + i dr (i = 0 .. n_r - 1) and theta_j = theta0 + j dtheta
(j = 0 .. n_theta - 1, periodic: n_theta dtheta = 2 pi), with theta = atan2(x, y) in the model's
local frame. A point is interpolated by the tensor product of 4-point (cubic) Lagrange stencils
in r and theta, applied to log p so that a locally Gaussian density is reproduced almost exactly
and relative accuracy holds far into the tails; where a stencil touches a value at or below
``floor`` (underflowed tails) the linear values are interpolated instead, clamped at zero.

When the lattice starts at the origin (``mirror`` = 1, n_theta even), stencil rows below it are
reflected through the origin: p(-r, theta) = p(r, theta + pi).

The kernel reads a padded copy of the lattice (:func:`pad_table`): a row -1 before it (row 1 turned
by half a turn where it mirrors) and the bearings wrapped by ``PAD_BEFORE`` columns before and
``PAD_AFTER`` after, so that a stencil's 16 entries are read without a remainder or a branch each
(the integer remainder was most of a cell's cost).
"""

from typing import Any

import numpy as np
import warp as wp

from .common import atan2_one_division, world_to_local
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


#: Wrapped bearing columns of the padded table before and after the lattice's (:func:`pad_table`):
#: a stencil at column col in [-1, n_theta] reads columns col - 1 .. col + 2.
PAD_BEFORE = 2
PAD_AFTER = 3


def pad_table(values: np.ndarray, mirror: bool) -> np.ndarray:
    """The lattice ``values`` (n_r, n_theta) as the kernel reads it, shape (n_r + 1, n_theta +
    PAD_BEFORE + PAD_AFTER): row 0 is lattice row -1 (row 1 turned by n_theta / 2 bearings where
    the lattice mirrors through the origin; else row 0, which no stencil reads), and padded column
    c holds bearing (c - PAD_BEFORE) mod n_theta."""
    n_r, n_theta = values.shape
    out = np.empty((n_r + 1, n_theta + PAD_BEFORE + PAD_AFTER), dtype=values.dtype)
    out[1:, PAD_BEFORE:PAD_BEFORE + n_theta] = values
    if mirror:
        half = n_theta // 2
        out[0, PAD_BEFORE:PAD_BEFORE + n_theta - half] = values[1, half:]
        out[0, PAD_BEFORE + n_theta - half:PAD_BEFORE + n_theta] = values[1, :half]
    else:
        out[0, PAD_BEFORE:PAD_BEFORE + n_theta] = values[0]
    # the wrapped columns (PAD_BEFORE, PAD_AFTER <= n_theta)
    out[:, :PAD_BEFORE] = out[:, n_theta:n_theta + PAD_BEFORE]
    out[:, PAD_BEFORE + n_theta:] = out[:, PAD_BEFORE:PAD_BEFORE + PAD_AFTER]
    return out


@wp.func
def table_density_local(x: Any, y: Any, p: Any):
    """Interpolated density at a local point (``p.table``, ``p.log_table``: :func:`pad_table`'s)."""
    zero = type(x)(0.0)
    n_r = p.table.shape[0] - 1
    n_theta = p.table.shape[1] - (PAD_BEFORE + PAD_AFTER)
    r = wp.sqrt(x * x + y * y)
    u = (r - p.r0) / p.dr
    base = int(wp.floor(u))
    # one-sided stencils at the lattice's ends (a lattice from the origin reads row -1, mirrored);
    # the clamps also keep a NaN's stencil inside the table
    base = wp.clamp(base, 1 - p.mirror, n_r - 3)
    fr = u - type(x)(float(base))
    v = (atan2_one_division(x, y) - p.theta0) / p.dtheta
    col = wp.clamp(int(wp.floor(v)), -1, n_theta)  # v in [0, n_theta] up to rounding
    ft = v - type(x)(float(col))
    wr0, wr1, wr2, wr3 = lagrange4(fr)
    wt0, wt1, wt2, wt3 = lagrange4(ft)
    wr = wp.vector(wr0, wr1, wr2, wr3)
    wt = wp.vector(wt0, wt1, wt2, wt3)
    log_sum = zero
    lin_sum = zero
    # padded row of lattice row base - 1 + a is base + a; padded column of col - 1 + b is
    # col - 1 + b + PAD_BEFORE
    i0 = base
    j0 = col + (PAD_BEFORE - 1)
    lowest = p.table[i0, j0]
    for a in range(4):
        for b in range(4):
            w = wr[a] * wt[b]
            value = p.table[i0 + a, j0 + b]
            lin_sum += w * value
            log_sum += w * p.log_table[i0 + a, j0 + b]
            lowest = wp.min(lowest, value)
    if lowest > p.floor_value:
        return wp.exp(log_sum)
    return wp.max(lin_sum, zero)


@wp.func
def table_density(x: Any, y: Any, p: Any):
    """Interpolated density per m^2 at the world point (x, y): the launch kernels' maths."""
    lx, ly = world_to_local(x, y, p.pose)
    return table_density_local(lx, ly, p)


#: The parameters: log p and p on the padded lattice (:func:`pad_table`), its geometry, ``mirror``, the pose.
TABLE = Params("TableParams", __name__, log_table=ARRAY2D, table=ARRAY2D, r0=SCALAR, dr=SCALAR, theta0=SCALAR,
               dtheta=SCALAR, floor_value=SCALAR, mirror=int, pose=VEC4)
KERNELS = density_kernels(table_density, TABLE, "table", bands_per_thread=1)
