"""The CAT scan on the CPU: along grid rows (the grid kernel), and over nodes in lanes (points).

The exact CAT kernel (``kernels/cat.py``) scans every cell's turn-rate nodes for intervals that
can hold a root: F = hx y - hy x - c at each node, and a cheap test on each interval (a sign
change, or an end within the chord bound of zero); each flagged interval is examined by
``cat.cat_node_interval``, in node order.

The grid kernel sweeps each row instead (:func:`cat_sweep_row`): along a row F at a node is
affine in x, so the cells an interval can be flagged at lie in at most two x-intervals, found
from the row's ends in O(nodes) a row; only those cells are tested, with the scan's own
arithmetic, and their roots are added in node order from 0. Single roots (the common case) are
searched ROOT_GROUP at a time (``cat.cat_root_group``: the scalar search's steps, interleaved).
The density is therefore the scalar kernel's, bit for bit (``tests/kernels/test_cat_sweep.py``
and ``tests/kernels/test_lanes.py`` check it). On the bench's Figure 1 grid (float64, one core,
Intel Xeon AVX-512) the per-cell scan took 0.17 s of the kernel's 0.54 s; the sweep and its
cells' tests take 0.02 s.

The points kernels run the per-cell test on a group of intervals at once
(``lanes.cat_scan_group``: F at the group's nodes and at their predecessors, from the table's
columns regrouped into vectors by :func:`node_groups`, with the scalar scan's arithmetic).

CPU only (see ``kernels/lanes.py``); the GPU path uses ``cat.KERNELS``.
"""

from typing import Any

import numpy as np
import warp as wp

from .cat import (
    CAT, CAT_CARRIED, PRUNE_SIGMAS, ROOT_GROUP, SPLIT, cat_curvature, cat_negligible, cat_node_interval, cat_one_root,
    cat_root_density, cat_root_group, cat_scan_noise,
)
from .evidence import EVIDENCE
from .generate import SCALARS, Params, carried_points_kernel, density_kernels, overload_on_use
from .common import LANES32, LANES64, lanes32, lanes64, world_to_local
from .lanes import cat_scan_group

# No adjoints: nothing differentiates these kernels (see ``polar_lanes``); the scan's split
# loops stay loops, as in ``cat`` (its module options say why).
wp.set_module_options({"enable_backward": False, "max_unroll": SPLIT - 1})

#: Rows of the node groups: omega, hx, hy, c at nodes 1 + L g .. L (g + 1), then the same at the
#: nodes before them.
GROUP_ROWS = 8


def node_groups(table: np.ndarray, lanes: int) -> np.ndarray:
    """The scan table's omega, hx, hy and c columns at nodes 1 .. n - 1 and at their predecessors
    0 .. n - 2, in groups of ``lanes`` (the last padded with its last node, which the count of
    live intervals then leaves out): shape (GROUP_ROWS, groups, lanes)."""
    n = table.shape[0]
    groups = -(-(n - 1) // lanes)
    out = np.empty((GROUP_ROWS, groups * lanes), dtype=table.dtype)
    for c in range(4):
        for row, nodes in ((c, table[1:, c]), (4 + c, table[:-1, c])):
            out[row, : n - 1] = nodes
            out[row, n - 1 :] = nodes[-1]
    return out.reshape(GROUP_ROWS, groups, lanes)


@wp.func
def group_width(groups: wp.array2d(dtype=lanes64)):
    """Intervals per group (8 float64 lanes)."""
    return LANES64


@wp.func
def group_width(groups: wp.array2d(dtype=lanes32)):  # noqa: F811
    return LANES32


@wp.func
def cat_density_lanes(
    x: Any,
    y: Any,
    table: wp.array2d(dtype=Any),
    groups: wp.array2d(dtype=Any),
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    tol: Any,
    eps: Any,
    carry: Any,
    lw: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
):
    """``cat.cat_density_local`` with its scan over nodes in lanes (``groups``: :func:`node_groups`);
    ``carry``, ``lw``, ``out`` as there (the integer 0 and any rows: no evidence)."""
    density = type(x)(0.0)
    r, noise_f, noise_g, chord_coef = cat_scan_noise(x, y, v0, t, eps)
    n = table.shape[0]
    width = group_width(groups)
    for g in range(groups.shape[1]):
        k = 1 + g * width  # the node that the group's first interval ends at
        flags = cat_scan_group(groups, g, x, y, chord_coef, noise_f, n - k)
        if flags != 0:
            for j in range(width):
                if ((flags >> j) & 1) != 0:
                    density += cat_node_interval(x, y, table, k + j, v0, t, sigma_a, sigma_omega, tol, r, noise_f,
                                                 noise_g, carry, lw, out)
    return density


@wp.func
def cat_density_world_lanes(x: Any, y: Any, p: Any):
    """Density per m^2 at the world point (x, y), the scan in lanes: the launch kernels' maths."""
    lx, ly = world_to_local(x, y, p.pose)
    return cat_density_lanes(lx, ly, p.table, p.groups, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, p.eps, int(0),
                             p.table[0], p.table[0])


#: The scalar kernels' parameters and the node groups (:func:`node_groups`).
CAT_LANES = Params("CatLaneParams", __name__, **CAT.fields,
                   groups=lambda scalar: wp.array2d(dtype=lanes64 if scalar == wp.float64 else lanes32))


# --- the grid kernel: the scan swept along a row -------------------------------------------------

#: Rounding allowance of the row sweep (:func:`cat_sweep_row`) on F at a cell, in units of the
#: dtype's epsilon times t^2 (|x| + |y| + |origin| + |local x| + |local y| + v0 t): more than
#: twice what the scan's F and local coordinates can be off by (see the proof there).
SWEEP_ULPS = 32.0


@wp.func
def sweep_first(xs: wp.array(dtype=Any), j0: int, j1: int, bound: wp.float64, strict: bool):
    """The first j in [j0, j1) with xs[j] >= bound (> bound with ``strict``), j1 if none, for xs
    non-decreasing there: a guess from the row's mean spacing, then a walk to it (a step or two on
    a uniform grid)."""
    x_first = wp.float64(xs[j0])
    x_last = wp.float64(xs[j1 - 1])
    if bound < x_first or (bound == x_first and not strict):
        return j0
    if bound > x_last or (bound == x_last and strict):
        return j1
    j = j0
    if x_last > x_first:
        j = j0 + int(wp.float64(j1 - 1 - j0) * (bound - x_first) / (x_last - x_first))
        j = wp.clamp(j, j0, j1 - 1)
    # xs[j - 1] < bound <= xs[j] (or <, <= with strict) at the answer
    while j > j0 and (wp.float64(xs[j - 1]) > bound or (wp.float64(xs[j - 1]) == bound and not strict)):
        j -= 1
    while j < j1 and (wp.float64(xs[j]) < bound or (wp.float64(xs[j]) == bound and strict)):
        j += 1
    return j


@wp.func
def sweep_half_line(alpha: wp.float64, beta: wp.float64, e: wp.float64):
    """The x with alpha + beta x <= e, as (lo, hi) (+-inf for an open end; lo > hi: none)."""
    inf = wp.float64(wp.inf)
    if beta > wp.float64(0.0):
        return -inf, (e - alpha) / beta
    if beta < wp.float64(0.0):
        return (e - alpha) / beta, inf
    if alpha <= e:
        return -inf, inf
    return inf, -inf


@wp.func
def sweep_band(alpha_prev: wp.float64, beta_prev: wp.float64, alpha: wp.float64, beta: wp.float64,
               e: wp.float64, sign: wp.float64):
    """The x with sign F_prev(x) <= e and sign F(x) >= -e (F = alpha + beta x): an interval (lo, hi)."""
    lo1, hi1 = sweep_half_line(sign * alpha_prev, sign * beta_prev, e)
    lo2, hi2 = sweep_half_line(-sign * alpha, -sign * beta, e)
    return wp.max(lo1, lo2), wp.min(hi1, hi2)


@wp.func
def sweep_acceleration(table: wp.array2d(dtype=Any), k: int, ox: wp.float64, cs: wp.float64, sn: wp.float64,
                       dyo: wp.float64):
    """The acceleration of node k's line along the row, a = ax lx + ay ly - a0 = alpha + beta x
    (float64): (beta, alpha)."""
    ax = wp.float64(table[k, 7])
    ay = wp.float64(table[k, 8])
    beta = ax * cs + ay * sn
    return beta, -ox * beta + dyo * (ay * cs - ax * sn) - wp.float64(table[k, 9])


@wp.func
def sweep_pruned(xs: wp.array(dtype=Any), j0: int, j1: int, alpha_prev: wp.float64, beta_prev: wp.float64,
                 alpha: wp.float64, beta: wp.float64, beyond: wp.float64):
    """Index ranges (two, as a vec4i of begin, end pairs) of the cells where both nodes'
    accelerations alpha + beta x are at least ``beyond`` on one side."""
    lo1, hi1 = sweep_half_line(-alpha_prev, -beta_prev, -beyond)
    lo2, hi2 = sweep_half_line(-alpha, -beta, -beyond)
    lo3, hi3 = sweep_half_line(alpha_prev, beta_prev, -beyond)
    lo4, hi4 = sweep_half_line(alpha, beta, -beyond)
    out = wp.vec4i(j1, j1, j1, j1)
    lo = wp.max(lo1, lo2)
    hi = wp.min(hi1, hi2)
    if lo <= hi:
        out[0] = sweep_first(xs, j0, j1, lo, False)
        out[1] = sweep_first(xs, j0, j1, hi, True)
    lo = wp.max(lo3, lo4)
    hi = wp.min(hi3, hi4)
    if lo <= hi:
        out[2] = sweep_first(xs, j0, j1, lo, False)
        out[3] = sweep_first(xs, j0, j1, hi, True)
    return out


@wp.func
def sweep_cells(xs: wp.array(dtype=Any), y: Any, row: int, j_begin: int, j_end: int, k: int, p: Any,
                skip: wp.vec4i, out: wp.array2d(dtype=Any)):
    """Add the roots of node interval [k - 1, k] to out[row, j] for j in [j_begin, j_end): at the
    cells that the scan's cheap test flags (``cat.cat_density_local``'s test, its arithmetic),
    what ``cat.cat_node_interval`` adds there. A single root (a sign change that
    ``cat.cat_one_root`` settles, the common case) joins a group of ROOT_GROUP searched side by
    side (``cat.cat_root_group``: the same bits as the scalar search); the rest, and the roots
    left over at the end, are settled one by one by the scalar functions. Cells in the index
    ranges [skip[0], skip[1]) and [skip[2], skip[3]) are skipped: proved pruned there (both
    nodes' accelerations beyond PRUNE_SIGMAS sigma_a on one side: ``cat.cat_negligible``, which
    adds nothing)."""
    zero = type(y)(0.0)
    q_x = wp.vector(zero, zero, zero, zero)
    q_y = q_x
    q_lo = q_x
    q_hi = q_x
    q_f_lo = q_x
    q_g_lo = q_x
    q_f_hi = q_x
    q_g_hi = q_x
    q_noise = q_x
    q_j = wp.vec4i(0, 0, 0, 0)
    queued = int(0)
    a_cut = type(y)(PRUNE_SIGMAS) * p.sigma_a
    for j in range(j_begin, j_end):
        if (j >= skip[0] and j < skip[1]) or (j >= skip[2] and j < skip[3]):
            continue
        lx, ly = world_to_local(xs[j], y, p.pose)
        r, noise_f, noise_g, chord_coef = cat_scan_noise(lx, ly, p.v0, p.t, p.eps)
        f_prev = p.table[k - 1, 1] * ly - p.table[k - 1, 2] * lx - p.table[k - 1, 3]
        f_k = p.table[k, 1] * ly - p.table[k, 2] * lx - p.table[k, 3]
        width = p.table[k, 0] - p.table[k - 1, 0]
        if (f_k >= zero) != (f_prev >= zero) or wp.min(wp.abs(f_prev), wp.abs(f_k)) <= (
            chord_coef * width * width + noise_f
        ):
            if not cat_negligible(p.table, k, lx, ly, a_cut):  # else cat_node_interval adds 0
                w_prev = p.table[k - 1, 0]
                w_k = p.table[k, 0]
                g_prev = p.table[k - 1, 4] * ly - p.table[k - 1, 5] * lx - p.table[k - 1, 6]
                g_k = p.table[k, 4] * ly - p.table[k, 5] * lx - p.table[k, 6]
                m3w2, curvature = cat_curvature(w_prev, w_k, p.v0, p.t, r, noise_g)
                if (f_k >= zero) != (f_prev >= zero) and cat_one_root(g_prev, g_k, m3w2, curvature, noise_g):
                    q_x[queued] = lx
                    q_y[queued] = ly
                    q_lo[queued] = w_prev
                    q_hi[queued] = w_k
                    q_f_lo[queued] = f_prev
                    q_g_lo[queued] = g_prev
                    q_f_hi[queued] = f_k
                    q_g_hi[queued] = g_k
                    q_noise[queued] = noise_g
                    q_j[queued] = j
                    queued += 1
                    if queued == ROOT_GROUP:
                        found = cat_root_group(q_x, q_y, q_lo, q_hi, q_f_lo, q_g_lo, q_f_hi, q_g_hi, q_noise, p.v0,
                                               p.t, p.sigma_a, p.sigma_omega, p.tol)
                        for m in range(ROOT_GROUP):
                            out[row, q_j[m]] = out[row, q_j[m]] + found[m]
                        queued = 0
                else:
                    out[row, j] = out[row, j] + cat_node_interval(
                        lx, ly, p.table, k, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, r, noise_f, noise_g, int(0),
                        p.table[0], p.table[0])
    for m in range(queued):
        out[row, q_j[m]] = out[row, q_j[m]] + cat_root_density(
            q_x[m], q_y[m], q_lo[m], q_hi[m], q_f_lo[m], q_g_lo[m], q_f_hi[m], q_g_hi[m], p.v0, p.t, p.sigma_a,
            p.sigma_omega, p.tol, q_noise[m], int(0), p.table[0], p.table[0])


@wp.func
def cat_sweep_row(xs: wp.array(dtype=Any), y: Any, row: int, j0: int, j1: int, p: Any, out: wp.array2d(dtype=Any)):
    """out[row, j0 .. j1 - 1] = the density at (xs[j], y), xs non-decreasing there: the scan
    swept along the row, node interval by node interval, each cell's roots added in node order
    from 0 (``cat.cat_density_local``'s sum, to the bit).

    Along the row the local point is affine in x, and so is F at a node:
    F_k(x) = alpha_k + beta_k x with beta_k = hx s - hy c and alpha_k = -ox beta_k +
    (y - oy) (hx c + hy s) - c_k (pose (ox, oy, c, s); F = hx ly - hy lx - c_k). The scan flags
    interval k at a cell where its computed F_(k-1), F_k change sign or the smaller |F| is
    within B = chord_coef width^2 + noise_f (``cat_scan_noise``). The computed F differs from
    F_k(x) by at most delta: the coefficients |hx|, |hy| <= t^2 / 2 times the local
    coordinates' rounding (a few ulps of |x| + |y| + |origin|), plus three roundings of terms
    at most t^2 / 2 (|lx| + |ly|) and |c_k| <= v0 t^3 / 2; SWEEP_ULPS eps t^2 (W + L + v0 t)
    with W, L the largest |x| + |y| + |origin| and |lx| + |ly| at the row's ends (both convex
    along it, so largest at an end) is more than twice that. B is largest at an end too (r and
    |lx| + |ly| convex), so with E = B_max (1 + 1e-6) + delta: a flagged cell has
    F_(k-1) <= E and F_k >= -E, or F_(k-1) >= -E and F_k <= E (a sign change puts the two
    values on either side of zero; an end within B of zero satisfies one of the two whatever
    the other's sign). Each is an intersection of two half-lines of x, an interval (its ends in
    float64: their rounding is far inside the allowance), and the cells in it are found by a
    search of the sorted xs. Only they are tested, with the scan's own arithmetic: the flagged
    set, and so every root and the sum, is the per-cell scan's. The row costs O(nodes) plus the
    cells near each interval's lines (a few a cell), instead of every node at every cell.

    Cells where both nodes' accelerations a = ax lx + ay ly - a0 (also affine in x) are beyond
    PRUNE_SIGMAS sigma_a on one side by more than their rounding allowance (the coefficients are
    h / |h|^2 and v0 h . f / |h|^2, so delta / (t^2 |h|)) are skipped without a test: the scan's
    ``cat.cat_negligible`` prunes them, and they add nothing.
    """
    zero = type(y)(0.0)
    for j in range(j0, j1):
        out[row, j] = zero
    if j1 <= j0:
        return
    n = p.table.shape[0]
    # the allowance E's parts at the row's ends
    lx0, ly0 = world_to_local(xs[j0], y, p.pose)
    lx1, ly1 = world_to_local(xs[j1 - 1], y, p.pose)
    r0, noise_f0, noise_g0, chord0 = cat_scan_noise(lx0, ly0, p.v0, p.t, p.eps)
    r1, noise_f1, noise_g1, chord1 = cat_scan_noise(lx1, ly1, p.v0, p.t, p.eps)
    chord_max = wp.float64(wp.max(chord0, chord1))
    noise_max = wp.float64(wp.max(noise_f0, noise_f1))
    ox = wp.float64(p.pose[0])
    oy = wp.float64(p.pose[1])
    cs = wp.float64(p.pose[2])
    sn = wp.float64(p.pose[3])
    yy = wp.float64(y)
    dyo = yy - oy
    t = wp.float64(p.t)
    far = wp.max(wp.abs(wp.float64(xs[j0])), wp.abs(wp.float64(xs[j1 - 1]))) + wp.abs(yy) + wp.abs(ox) + wp.abs(oy)
    local = wp.float64(wp.max(wp.abs(lx0) + wp.abs(ly0), wp.abs(lx1) + wp.abs(ly1)))
    delta = wp.float64(SWEEP_ULPS) * wp.float64(p.eps) * t * t * (far + local + wp.float64(p.v0) * t)
    tx = wp.float64(p.table[0, 1])
    ty = wp.float64(p.table[0, 2])
    beta_prev = tx * sn - ty * cs
    alpha_prev = -ox * beta_prev + dyo * (tx * cs + ty * sn) - wp.float64(p.table[0, 3])
    acc_beta_prev, acc_alpha_prev = sweep_acceleration(p.table, 0, ox, cs, sn, dyo)
    # the acceleration's rounding allowance, over |h| (its coefficients are h / |h|^2, v0 h.f / |h|^2)
    acc_delta = delta / (t * t)
    cut = wp.float64(PRUNE_SIGMAS) * wp.float64(p.sigma_a) * wp.float64(1.000001)
    h_prev = wp.sqrt(tx * tx + ty * ty)
    for k in range(1, n):
        tx = wp.float64(p.table[k, 1])
        ty = wp.float64(p.table[k, 2])
        beta = tx * sn - ty * cs
        alpha = -ox * beta + dyo * (tx * cs + ty * sn) - wp.float64(p.table[k, 3])
        acc_beta, acc_alpha = sweep_acceleration(p.table, k, ox, cs, sn, dyo)
        h_k = wp.sqrt(tx * tx + ty * ty)
        beyond = cut + acc_delta / wp.min(h_prev, h_k)
        skip = sweep_pruned(xs, j0, j1, acc_alpha_prev, acc_beta_prev, acc_alpha, acc_beta, beyond)
        width = wp.float64(p.table[k, 0] - p.table[k - 1, 0])
        e = (chord_max * width * width + noise_max) * wp.float64(1.000001) + delta
        lo1, hi1 = sweep_band(alpha_prev, beta_prev, alpha, beta, e, wp.float64(1.0))
        lo2, hi2 = sweep_band(alpha_prev, beta_prev, alpha, beta, e, wp.float64(-1.0))
        a1 = j1 + 0
        b1 = j1 + 0
        if lo1 <= hi1:
            a1 = sweep_first(xs, j0, j1, lo1, False)
            b1 = sweep_first(xs, j0, j1, hi1, True)
        a2 = j1 + 0
        b2 = j1 + 0
        if lo2 <= hi2:
            a2 = sweep_first(xs, j0, j1, lo2, False)
            b2 = sweep_first(xs, j0, j1, hi2, True)
        if a1 < b1 and a2 < b2 and a2 <= b1 and a1 <= b2:  # overlapping: one range
            sweep_cells(xs, y, row, wp.min(a1, a2), wp.max(b1, b2), k, p, skip, out)
        else:
            sweep_cells(xs, y, row, a1, b1, k, p, skip, out)
            sweep_cells(xs, y, row, a2, b2, k, p, skip, out)
        alpha_prev = alpha
        beta_prev = beta
        acc_alpha_prev = acc_alpha
        acc_beta_prev = acc_beta
        h_prev = h_k


def _cat_grid_lanes(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), row0: int, columns: int, p: Any,
                    out: wp.array2d(dtype=Any)):
    """The generated grid kernel's layout (``columns`` cells of a row per thread), each row by
    the sweep (:func:`cat_sweep_row`) where its centres are non-decreasing (a grid's always are),
    else cell by cell (:func:`cat_density_world_lanes`)."""
    i, block = wp.tid()
    row = row0 + i
    j0 = block * columns
    j1 = wp.min((block + 1) * columns, xs.shape[0])
    y = ys[row]
    unsorted = int(0)
    for j in range(j0 + 1, j1):
        if not (xs[j] >= xs[j - 1]):
            unsorted = 1
    if unsorted == 0:
        cat_sweep_row(xs, y, row, j0, j1, p, out)
    else:
        for j in range(j0, j1):
            out[row, j] = cat_density_world_lanes(xs[j], y, p)


GRID = wp.kernel(_cat_grid_lanes, name="cat_grid_lanes", module=cat_density_world_lanes.module)
for _scalar in SCALARS:
    _vec = wp.array(dtype=_scalar)
    overload_on_use(GRID, _scalar, {"xs": _vec, "ys": _vec, "p": CAT_LANES.of(_scalar),
                                    "out": wp.array2d(dtype=_scalar)})
# the grid by the row sweep, the points one by one with the nodes in lanes
KERNELS = density_kernels(cat_density_world_lanes, CAT_LANES, "cat", suffix="_lanes", grid=GRID)



@wp.func
def cat_carried_lanes(x: Any, y: Any, p: Any, ev: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    """``cat.cat_carried`` with the scan over nodes in lanes."""
    carry = p.carry
    carry.ev = ev
    for i in range(p.weights.shape[0]):
        carry.pose = p.poses[i]
        carry.scale = p.weights[i]
        lx, ly = world_to_local(x, y, carry.pose)
        cat_density_lanes(lx, ly, p.table, p.groups, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, p.eps, carry, lw,
                          out)


#: The carried kernel's parameters with the node groups.
CAT_CARRIED_LANES = Params("CatCarriedLaneParams", __name__, **CAT_CARRIED.fields,
                           groups=lambda scalar: wp.array2d(dtype=lanes64 if scalar == wp.float64 else lanes32))
CARRIED_POINTS = carried_points_kernel(cat_carried_lanes, CAT_CARRIED_LANES, EVIDENCE, "cat")
