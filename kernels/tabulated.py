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
def table_density_local(
    x: Any,
    y: Any,
    log_table: wp.array2d(dtype=Any),
    table: wp.array2d(dtype=Any),
    geometry: wp.array(dtype=Any),
    mirror: int,
):
    """Interpolated density at a local point; ``geometry`` = (r0, dr, theta0, dtheta, floor)."""
    zero = type(x)(0.0)
    n_r = table.shape[0]
    n_theta = table.shape[1]
    r0 = geometry[0]
    dr = geometry[1]
    theta0 = geometry[2]
    dtheta = geometry[3]
    floor_value = geometry[4]
    r = wp.sqrt(x * x + y * y)
    u = (r - r0) / dr
    base = int(wp.floor(u))
    if mirror == 0:
        base = wp.clamp(base, 1, n_r - 3)  # one-sided stencils at the lattice's ends
    else:
        base = wp.min(base, n_r - 3)
    fr = u - type(x)(float(base))
    v = (atan2_fast(x, y) - theta0) / dtheta
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
            p = table[i, j]
            lin_sum += w * p
            log_sum += w * log_table[i, j]
            if b == 0 and a == 0:
                lowest = p
            else:
                lowest = wp.min(lowest, p)
    if lowest > floor_value:
        return wp.exp(log_sum)
    return wp.max(lin_sum, zero)


@wp.kernel
def table_grid(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    columns: int,
    log_table: wp.array2d(dtype=Any),
    table: wp.array2d(dtype=Any),
    geometry: wp.array(dtype=Any),
    mirror: int,
    pose: wp.array(dtype=Any),
    out: wp.array2d(dtype=Any),
):
    """Interpolated density at the cell centres of a band of rows, ``columns`` cells a thread."""
    i, block = wp.tid()
    row = row0 + i
    y_world = ys[row]
    j_end = wp.min((block + 1) * columns, xs.shape[0])
    for j in range(block * columns, j_end):
        x, y = world_to_local(xs[j], y_world, pose)
        out[row, j] = table_density_local(x, y, log_table, table, geometry, mirror)


@wp.kernel
def table_points(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    start: int,
    log_table: wp.array2d(dtype=Any),
    table: wp.array2d(dtype=Any),
    geometry: wp.array(dtype=Any),
    mirror: int,
    pose: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """Interpolated density at world points (xs[k], ys[k]) for k in a chunk from ``start``."""
    k = start + wp.tid()
    x, y = world_to_local(xs[k], ys[k], pose)
    out[k] = table_density_local(x, y, log_table, table, geometry, mirror)


def _register_overloads():
    for scalar in (wp.float32, wp.float64):
        vec = wp.array(dtype=scalar)
        mat = wp.array2d(dtype=scalar)
        common = {"xs": vec, "ys": vec, "log_table": mat, "table": mat, "geometry": vec, "pose": vec}
        wp.overload(table_grid, {**common, "out": mat})
        wp.overload(table_points, {**common, "out": vec})


_register_overloads()
