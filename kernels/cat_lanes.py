"""The CAT scan on the CPU: along grid rows (the grid kernel), and over nodes in lanes (points).

The grid kernel sweeps each row (:func:`cat_sweep_row`: only the cells where a node interval
can be flagged are tested, with the scan's own arithmetic); the points kernels test a group of
node intervals at once (:func:`cat_points_lanes`, :func:`cat_scan_lanes`). Each flagged interval
is taken as ``cat.cat_node_interval`` takes it, but that the single roots (a sign change that
``cat.cat_one_root`` settles: nearly all of them) are queued, across the cells of a row or the
points of a vector, and searched a vector of lanes at a time (``lanes.lane_cat_roots``: the
scalar search's steps and proofs, other roundings). Each cell's roots are added in node order,
so the grid and points kernels give the same density bit for bit, and the scalar kernel
(``kernels/cat.py``, the GPU path's) the same to the lane search's rounding
(``tests/kernels/test_cat_sweep.py``, ``tests/kernels/test_lanes.py``). The carried kernel scans
with :func:`cat_scan_lanes` and the scalar root search (its roots weigh the evidence along their
paths).

CPU only (see ``kernels/lanes.py``); the GPU path uses ``cat.KERNELS``.
"""

from typing import Any

import numpy as np
import warp as wp

from .cat import (
    CAT, CAT_CARRIED, PRUNE_SIGMAS, SPLIT, cat_curvature, cat_flagged, cat_interval, cat_negligible,
    cat_node_interval, cat_node_values, cat_one_root, cat_scan_functions, cat_scan_noise, cat_split,
)
from .evidence import EVIDENCE
from .generate import Params, carried_points_kernel, density_kernels, overload_on_use
from .common import lanes32, lanes64, world_to_local
from .lanes import LANE_TURN_LIMIT, cat_scan_group, lane_cat_roots, lane_count, lane_slots, load_lanes, row_start

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
def cat_scan_lanes(x: Any, y: Any, p: Any, carry: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    """``cat.cat_scan`` with its test over nodes in lanes (``p.groups``: :func:`node_groups`)."""
    density = type(x)(0.0)
    r, noise_f, noise_g, chord_coef = cat_scan_noise(x, y, p.v0, p.t, p.eps)
    n = p.table.shape[0]
    width = lane_count(p.table[0])  # intervals per group: the dtype's lanes
    for g in range(p.groups.shape[1]):
        k = 1 + g * width  # the node that the group's first interval ends at
        flags = cat_scan_group(p.groups, g, x, y, chord_coef, noise_f, n - k)
        if flags != 0:
            for j in range(width):
                if ((flags >> j) & 1) != 0:
                    density += cat_node_interval(x, y, p, k + j, r, noise_f, noise_g, carry, lw, out)
    return density


cat_density_lanes, cat_carried_lanes = cat_scan_functions(cat_scan_lanes)


@wp.func
def cat_interval_kind(p: Any, k: int, x: Any, y: Any, r: Any, noise_f: Any, noise_g: Any, chord_coef: Any,
                      in_lanes: bool):
    """How the scan takes node interval [k - 1, k] at the local point (x, y): 0, nothing to add
    (not flagged, ``cat.cat_flagged``, or negligible, ``cat.cat_negligible``); 1, one root that
    ``cat.cat_node_interval`` would search directly (a sign change that ``cat.cat_one_root``
    settles), for ``lanes.lane_cat_roots`` (with ``in_lanes``); 2, the rest, for
    ``cat.cat_node_interval``. With the node values (lo, hi, F and dF/domega at each)."""
    lo, f_lo, g_lo = cat_node_values(p.table, k - 1, x, y)
    hi, f_hi, g_hi = cat_node_values(p.table, k, x, y)
    kind = int(0)
    if cat_flagged(f_lo, f_hi, hi - lo, chord_coef, noise_f) and not cat_negligible(
        p.table, k, x, y, type(x)(PRUNE_SIGMAS) * p.sigma_a
    ):
        kind = 2
        m3w2, curvature = cat_curvature(lo, hi, p.v0, p.t, r, noise_g)
        if in_lanes and (f_hi >= type(x)(0.0)) != (f_lo >= type(x)(0.0)) and cat_one_root(
            g_lo, g_hi, m3w2, curvature, noise_g
        ):
            kind = 1
    return kind, lo, hi, f_lo, g_lo, f_hi, g_hi


@wp.func
def cat_rest(p: Any, x: Any, y: Any, lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any, r: Any, noise_f: Any,
             noise_g: Any):
    """What ``cat.cat_node_interval`` adds for an interval of kind 2 (``cat_interval_kind``: not
    negligible, its node values known): ``cat.cat_interval``'s settled density, or ``cat.cat_split``'s."""
    part, settled = cat_interval(x, y, lo, hi, f_lo, g_lo, f_hi, g_hi, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, r,
                                 noise_f, noise_g, False, int(0), p.table[0], p.table[0])
    if settled:
        return part
    return cat_split(x, y, lo, hi, f_lo, g_lo, f_hi, g_hi, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, r, noise_f,
                     noise_g, int(0), p.table[0], p.table[0])


@wp.func
def lanes_hold(j: Any, count: int, slot: int):
    """Whether one of the first ``count`` queued roots belongs to ``slot``."""
    held = int(0)
    for m in range(count):
        if j[m] == slot:
            held = 1
    return held != 0


@wp.func
def in_lane_turns(p: Any, k: int):
    """Whether node interval [k - 1, k] is within the lanes' sine reduction (LANE_TURN_LIMIT)."""
    return wp.max(wp.abs(p.table[k - 1, 0]), wp.abs(p.table[k, 0])) * p.t < type(p.t)(LANE_TURN_LIMIT)


@wp.func
def points_roots(x: Any, y: Any, lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any, noise_g: Any, j: Any,
                 count: int, p: Any, density: Any):
    """``density`` with the single roots queued in the first ``count`` lanes added to the lanes
    j of their points (``lanes.lane_cat_roots``)."""
    found = lane_cat_roots(x, y, lo, hi, f_lo, g_lo, f_hi, g_hi, noise_g, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol,
                           count)
    out = density
    for m in range(count):
        out[j[m]] = out[j[m]] + found[m]
    return out


@wp.func
def cat_points_lanes(xs: Any, ys: Any, p: Any):
    """The density at a vector of world points (the points kernel's, and the grid kernel's on a
    row it cannot sweep): each point's nodes scanned in lanes (``cat_scan_lanes``' test), the
    single roots of all of them queued and searched a vector at a time (``lanes.lane_cat_roots``)
    and the rest by ``cat.cat_node_interval``, each point's roots added in node order from 0
    (a point's queued roots go in before its next interval of the rest): the grid kernel's row
    sweep's sum, to the bit."""
    width = lane_count(p.table[0])
    density = xs
    for m in range(width):
        density[m] = type(p.t)(0.0)
    q_x = xs
    q_y = xs
    q_lo = xs
    q_hi = xs
    q_f_lo = xs
    q_g_lo = xs
    q_f_hi = xs
    q_g_hi = xs
    q_noise = xs
    q_j = lane_slots(xs)
    queued = int(0)
    n = p.table.shape[0]
    for m in range(width):
        x, y = world_to_local(xs[m], ys[m], p.pose)
        r, noise_f, noise_g, chord_coef = cat_scan_noise(x, y, p.v0, p.t, p.eps)
        for g in range(p.groups.shape[1]):
            k0 = 1 + g * width  # the node that the group's first interval ends at
            flags = cat_scan_group(p.groups, g, x, y, chord_coef, noise_f, n - k0)
            if flags != 0:
                for i in range(width):
                    if ((flags >> i) & 1) != 0:
                        k = k0 + i
                        kind, lo, hi, f_lo, g_lo, f_hi, g_hi = cat_interval_kind(p, k, x, y, r, noise_f, noise_g,
                                                                                 chord_coef, in_lane_turns(p, k))
                        if kind == 1:
                            q_x[queued] = x
                            q_y[queued] = y
                            q_lo[queued] = lo
                            q_hi[queued] = hi
                            q_f_lo[queued] = f_lo
                            q_g_lo[queued] = g_lo
                            q_f_hi[queued] = f_hi
                            q_g_hi[queued] = g_hi
                            q_noise[queued] = noise_g
                            q_j[queued] = m
                            queued += 1
                            if queued == width:
                                density = points_roots(q_x, q_y, q_lo, q_hi, q_f_lo, q_g_lo, q_f_hi, q_g_hi, q_noise,
                                                       q_j, queued, p, density)
                                queued = 0
                        elif kind == 2:
                            if lanes_hold(q_j, queued, m):
                                density = points_roots(q_x, q_y, q_lo, q_hi, q_f_lo, q_g_lo, q_f_hi, q_g_hi, q_noise,
                                                       q_j, queued, p, density)
                                queued = 0
                            density[m] = density[m] + cat_rest(p, x, y, lo, hi, f_lo, g_lo, f_hi, g_hi, r, noise_f,
                                                               noise_g)
    if queued > 0:
        density = points_roots(q_x, q_y, q_lo, q_hi, q_f_lo, q_g_lo, q_f_hi, q_g_hi, q_noise, q_j, queued, p, density)
    return density


def GROUPS(scalar):
    """Field type: the node groups (:func:`node_groups`), vectors of the scalar's lanes."""
    return wp.array2d(dtype=lanes64 if scalar == wp.float64 else lanes32)


#: The scalar kernels' parameters and the node groups; likewise the carried kernel's.
CAT_LANES = Params("CatLaneParams", __name__, **CAT.fields, groups=GROUPS)
CAT_CARRIED_LANES = Params("CatCarriedLaneParams", __name__, **CAT_CARRIED.fields, groups=GROUPS)


# --- the grid kernel: the scan swept along a row -------------------------------------------------

#: Rounding allowance of the row sweep (:func:`cat_sweep_row`) on F at a cell, in units of the
#: dtype's epsilon times t^2 (|x| + |y| + |origin| + |local x| + |local y| + v0 t): more than
#: twice what the scan's F and local coordinates can be off by (see the proof there).
SWEEP_ULPS = 32.0


@wp.func
def sweep_first(xs: wp.array(dtype=Any), j0: int, j1: int, bound: wp.float64, strict: bool, x_first: wp.float64,
                x_last: wp.float64, per_x: wp.float64):
    """The first j in [j0, j1) with xs[j] >= bound (> bound with ``strict``), j1 if none, for xs
    non-decreasing there, from x_first = xs[j0] to x_last = xs[j1 - 1]: a guess from the row's
    mean spacing (per_x = (j1 - 1 - j0) / (x_last - x_first), 0 for one x), then a walk to it (a
    step or two on a uniform grid)."""
    if bound < x_first or (bound == x_first and not strict):
        return j0
    if bound > x_last or (bound == x_last and strict):
        return j1
    j = wp.clamp(j0 + int(per_x * (bound - x_first)), j0, j1 - 1)
    # xs[j - 1] < bound <= xs[j] (or <, <= with strict) at the answer
    while j > j0 and (wp.float64(xs[j - 1]) > bound or (wp.float64(xs[j - 1]) == bound and not strict)):
        j -= 1
    while j < j1 and (wp.float64(xs[j]) < bound or (wp.float64(xs[j]) == bound and strict)):
        j += 1
    return j


@wp.func
def sweep_half_line(alpha: wp.float64, beta: wp.float64, inv_beta: wp.float64, e: wp.float64):
    """The x with alpha + beta x <= e, as (lo, hi) (+-inf for an open end; lo > hi: none);
    inv_beta = 1 / beta."""
    inf = wp.float64(wp.inf)
    if beta > wp.float64(0.0):
        return -inf, (e - alpha) * inv_beta
    if beta < wp.float64(0.0):
        return (e - alpha) * inv_beta, inf
    if alpha <= e:
        return -inf, inf
    return inf, -inf


@wp.func
def sweep_span(xs: wp.array(dtype=Any), j0: int, j1: int, alpha1: wp.float64, beta1: wp.float64,
               inv_beta1: wp.float64, alpha2: wp.float64, beta2: wp.float64, inv_beta2: wp.float64, e: wp.float64,
               x_first: wp.float64, x_last: wp.float64, per_x: wp.float64):
    """The index range [begin, end) of the cells j in [j0, j1) (xs non-decreasing there, from
    x_first to x_last, ``sweep_first``'s per_x) where alpha1 + beta1 x <= e and
    alpha2 + beta2 x <= e ((j1, j1) if none); inv_beta = 1 / beta."""
    lo1, hi1 = sweep_half_line(alpha1, beta1, inv_beta1, e)
    lo2, hi2 = sweep_half_line(alpha2, beta2, inv_beta2, e)
    lo = wp.max(lo1, lo2)
    hi = wp.min(hi1, hi2)
    if lo <= hi:
        return (sweep_first(xs, j0, j1, lo, False, x_first, x_last, per_x),
                sweep_first(xs, j0, j1, hi, True, x_first, x_last, per_x))
    return j1, j1


@wp.func
def sweep_node(table: wp.array2d(dtype=Any), k: int, ox: wp.float64, cs: wp.float64, sn: wp.float64, dyo: wp.float64):
    """Node k's F and acceleration along the row (float64): F = hx ly - hy lx - c = alpha + beta x
    and a = ax lx + ay ly - a0 = acc_alpha + acc_beta x, as (alpha, beta, 1 / beta, acc_alpha,
    acc_beta, 1 / acc_beta), and |h| = |(hx, hy)| (each node's lines bound two intervals' spans:
    their reciprocals are taken once)."""
    tx = wp.float64(table[k, 1])
    ty = wp.float64(table[k, 2])
    beta = tx * sn - ty * cs
    ax = wp.float64(table[k, 7])
    ay = wp.float64(table[k, 8])
    acc_beta = ax * cs + ay * sn
    one = wp.float64(1.0)
    return (-ox * beta + dyo * (tx * cs + ty * sn) - wp.float64(table[k, 3]), beta, one / beta,
            -ox * acc_beta + dyo * (ay * cs - ax * sn) - wp.float64(table[k, 9]), acc_beta, one / acc_beta,
            wp.sqrt(tx * tx + ty * ty))


@wp.func
def sweep_roots(x: Any, y: Any, lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any, noise_g: Any, j: Any,
                count: int, row: int, p: Any, out: wp.array2d(dtype=Any)):
    """Add the single roots queued in the first ``count`` lanes (each in its node interval
    [lo, hi], at the cell j of the row) to out[row, j]: ``lanes.lane_cat_roots``."""
    found = lane_cat_roots(x, y, lo, hi, f_lo, g_lo, f_hi, g_hi, noise_g, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol,
                           count)
    for m in range(count):
        out[row, j[m]] = out[row, j[m]] + found[m]


@wp.func
def cat_sweep_row(xs: wp.array(dtype=Any), y: Any, row: int, j0: int, j1: int, p: Any, out: wp.array2d(dtype=Any)):
    """out[row, j0 .. j1 - 1] (zeroed: ``lanes.row_start``) += the density at (xs[j], y), xs
    non-decreasing there: the scan
    swept along the row, node interval by node interval, each cell's roots added in node order
    from 0 (:func:`cat_points_lanes`' sum, to the bit); the single roots queued across the row
    and searched a vector of lanes at a time (a cell's queued roots are added before its next
    interval that ``cat.cat_node_interval`` takes).

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
    alpha_prev, beta_prev, inv_prev, acc_alpha_prev, acc_beta_prev, acc_inv_prev, h_prev = sweep_node(
        p.table, 0, ox, cs, sn, dyo)
    x_first = wp.float64(xs[j0])
    x_last = wp.float64(xs[j1 - 1])
    per_x = wp.float64(0.0)
    if x_last > x_first:
        per_x = wp.float64(j1 - 1 - j0) / (x_last - x_first)
    # the acceleration's rounding allowance, over |h| (its coefficients are h / |h|^2, v0 h.f / |h|^2)
    acc_delta = delta / (t * t)
    cut = wp.float64(PRUNE_SIGMAS) * wp.float64(p.sigma_a) * wp.float64(1.000001)
    # the single roots, queued across the row and searched a vector of lanes at a time
    q_x = load_lanes(xs, j0)  # a vector of the dtype's lanes (its values overwritten)
    q_y = q_x
    q_lo = q_x
    q_hi = q_x
    q_f_lo = q_x
    q_g_lo = q_x
    q_f_hi = q_x
    q_g_hi = q_x
    q_noise = q_x
    q_j = lane_slots(q_x)
    width = lane_count(xs)
    queued = int(0)
    parts = int(2)
    for k in range(1, n):
        alpha, beta, inv_k, acc_alpha, acc_beta, acc_inv_k, h_k = sweep_node(p.table, k, ox, cs, sn, dyo)
        # the cells where both accelerations are beyond the cut on one side: skipped (pruned)
        beyond = cut + acc_delta / wp.min(h_prev, h_k)
        a_hi, b_hi = sweep_span(xs, j0, j1, -acc_alpha_prev, -acc_beta_prev, -acc_inv_prev, -acc_alpha, -acc_beta,
                                -acc_inv_k, -beyond, x_first, x_last, per_x)
        a_lo, b_lo = sweep_span(xs, j0, j1, acc_alpha_prev, acc_beta_prev, acc_inv_prev, acc_alpha, acc_beta,
                                acc_inv_k, -beyond, x_first, x_last, per_x)
        width_k = wp.float64(p.table[k, 0] - p.table[k - 1, 0])
        e = (chord_max * width_k * width_k + noise_max) * wp.float64(1.000001) + delta
        # the cells where F_(k-1) <= E and F_k >= -E, and where F_(k-1) >= -E and F_k <= E
        a1, b1 = sweep_span(xs, j0, j1, alpha_prev, beta_prev, inv_prev, -alpha, -beta, -inv_k, e, x_first, x_last,
                            per_x)
        a2, b2 = sweep_span(xs, j0, j1, -alpha_prev, -beta_prev, -inv_prev, alpha, beta, inv_k, e, x_first, x_last,
                            per_x)
        if a1 < b1 and a2 < b2 and a2 <= b1 and a1 <= b2:  # overlapping: one range
            a1 = wp.min(a1, a2)
            b1 = wp.max(b1, b2)
            a2 = j1
            b2 = j1
        in_lanes = in_lane_turns(p, k)
        for part in range(parts):  # a loop, not two copies of its body
            begin = a1
            end = b1
            if part == 1:
                begin = a2
                end = b2
            for j in range(begin, end):
                if (j >= a_hi and j < b_hi) or (j >= a_lo and j < b_lo):
                    continue
                lx, ly = world_to_local(xs[j], y, p.pose)
                r, noise_f, noise_g, chord_coef = cat_scan_noise(lx, ly, p.v0, p.t, p.eps)
                kind, lo, hi, f_lo, g_lo, f_hi, g_hi = cat_interval_kind(p, k, lx, ly, r, noise_f, noise_g, chord_coef,
                                                                         in_lanes)
                if kind == 1:
                    q_x[queued] = lx
                    q_y[queued] = ly
                    q_lo[queued] = lo
                    q_hi[queued] = hi
                    q_f_lo[queued] = f_lo
                    q_g_lo[queued] = g_lo
                    q_f_hi[queued] = f_hi
                    q_g_hi[queued] = g_hi
                    q_noise[queued] = noise_g
                    q_j[queued] = j
                    queued += 1
                    if queued == width:
                        sweep_roots(q_x, q_y, q_lo, q_hi, q_f_lo, q_g_lo, q_f_hi, q_g_hi, q_noise, q_j, queued, row, p,
                                    out)
                        queued = 0
                elif kind == 2:
                    # the cell's queued roots first: each cell's roots add in node order
                    if lanes_hold(q_j, queued, j):
                        sweep_roots(q_x, q_y, q_lo, q_hi, q_f_lo, q_g_lo, q_f_hi, q_g_hi, q_noise, q_j, queued, row, p,
                                    out)
                        queued = 0
                    out[row, j] = out[row, j] + cat_rest(p, lx, ly, lo, hi, f_lo, g_lo, f_hi, g_hi, r, noise_f,
                                                         noise_g)
        alpha_prev = alpha
        beta_prev = beta
        inv_prev = inv_k
        acc_alpha_prev = acc_alpha
        acc_beta_prev = acc_beta
        acc_inv_prev = acc_inv_k
        h_prev = h_k
    if queued > 0:
        sweep_roots(q_x, q_y, q_lo, q_hi, q_f_lo, q_g_lo, q_f_hi, q_g_hi, q_noise, q_j, queued, row, p, out)


@wp.func
def cat_row(xs: wp.array(dtype=Any), y: Any, out: wp.array2d(dtype=Any), row: int, j0: int, j1: int, p: Any):
    """The generated grid kernel's row by the sweep (:func:`cat_sweep_row`) where its centres are
    non-decreasing (a grid's always are): 1; else 0 (the row is left to the density, cell by cell)."""
    if row_start(xs, out, row, j0, j1) != 0:  # the row zeroed, its centres sorted
        cat_sweep_row(xs, y, row, j0, j1, p, out)
        return 1
    return 0


# the grid by the row sweep, the points one by one with the nodes in lanes
KERNELS = density_kernels(cat_points_lanes, CAT_LANES, "cat", lanes=True, row=cat_row)
CARRIED_POINTS = carried_points_kernel(cat_carried_lanes, CAT_CARRIED_LANES, EVIDENCE, "cat")


# --- rays from the fix: the row sweep along a bearing ---------------------------------------------


@wp.kernel
def cat_rays(radii: wp.array(dtype=Any), sines: wp.array(dtype=Any), cosines: wp.array(dtype=Any), k0: int, p: Any,
             out: wp.array2d(dtype=Any)):
    """out[k, j] = the density at the local point radii[j] (sines[k], cosines[k]) (radii
    non-decreasing), for k = k0 + the thread: a ray from the fix swept as a grid row
    (:func:`cat_sweep_row`) through the frame turned so that the world x axis lies along it
    (pose (0, 0, sines[k], cosines[k]): the local point is (r sin, r cos) to the bit, so each value
    is the points kernel's, ``pdf``'s). ``p``'s pose is not used. A polar lattice of the plain CAT
    costs O(nodes) a ray plus its roots, instead of the scan at every point (:func:`cat_row`, the
    grid's row). Unsorted radii leave the ray at zero (the caller sorts them)."""
    k = k0 + wp.tid()
    sine = sines[k]
    zero = type(sine)(0.0)
    q = p
    q.pose = wp.vector(zero, zero, sine, cosines[k])
    cat_row(radii, zero, out, k, 0, radii.shape[0], q)


for _scalar in (wp.float64, wp.float32):
    overload_on_use(cat_rays, _scalar, {"radii": wp.array(dtype=_scalar), "sines": wp.array(dtype=_scalar),
                                        "cosines": wp.array(dtype=_scalar), "p": CAT_LANES.of(_scalar),
                                        "out": wp.array2d(dtype=_scalar)})
