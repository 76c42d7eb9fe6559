"""Exact CAT density (eq. (1) of the polar-banana paper) by root finding in the turn rate.

For a fixed turn rate omega the CAT position  p(a, omega) = v0 f(omega) + a h(omega)  is affine
in the acceleration a, with (u = omega t, basis in ``common.cat_basis``)

    f = t (A, B),   h = t^2 (C, D),   df/domega = t^2 (D, -C),   dh/domega = t^3 (C', D').

A point P is reached at omega iff  F(omega) = h x (P - v0 f) = 0  (2-D cross product), with
a = h . (P - v0 f) / |h|^2, and  dF/domega = h' x (P - v0 f) + v0 |h|^2 = -det d(x,y)/d(a,omega).
The density is  sum over roots of  g(a; sigma_a) g(omega; sigma_omega) / |dF/domega|.

F and dF/domega are affine in P with omega-only coefficients, so a table of those coefficients
at N nodes (``cat_table``) lets each cell scan for sign changes with a few multiply-adds per
node. A sign change is refined by safeguarded Newton; a node interval without a sign change in
which |F| has a local minimum (F dF changes sign from - to +) is searched for the minimum, which
finds the root pairs where the banana folds over itself.
"""

from typing import Any

import warp as wp

from .common import cat_basis, normal_pdf, world_to_local

#: Table columns: omega; the coefficients of F = hx*y - hy*x - c and of
#: dF/domega = dhx*y - dhy*x - dc; and of the acceleration of the line through P,
#: a = ax*x + ay*y - a0 (exact at a root).
TABLE_COLUMNS = 10

#: Roots whose acceleration lies beyond this many sigma_a contribute g(a) < 1e-313 relative and
#: are skipped when both ends of their node interval are beyond it on the same side.
PRUNE_SIGMAS = 38.0

#: Iteration caps; each iteration at least halves the bracket, so float64 converges well before.
MAX_NEWTON = 100
MAX_FOLD_SEARCH = 100

#: An interval is searched for a root pair when the Hermite interpolant of F comes within this
#: fraction of its larger end value of zero. The interpolant's error is O(width^4): on the
#: 0.1-rad node intervals (of omega t) about 2e-7 of F's scale, so 1e-2 leaves a wide margin.
FOLD_MARGIN = 1.0e-2


@wp.func
def cat_coefficients(omega: Any, v0: Any, t: Any):
    """The omega-only coefficients of everything a point needs, from one basis evaluation:
    F = hx y - hy x - c, dF/domega = dhx y - dhy x - dc, and the acceleration of the line
    through P, a = h . (P - v0 f) / |h|^2 = ax x + ay y - a0 (exact at a root)."""
    u = omega * t
    a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn = cat_basis(u)
    t2 = t * t
    fx = t * a_fn
    fy = t * b_fn
    hx = t2 * c_fn
    hy = t2 * d_fn
    dhx = t2 * t * dc_fn
    dhy = t2 * t * dd_fn
    h2 = hx * hx + hy * hy
    # d/domega (h x f) = h' x f + h x f', and h x f' = -|h|^2
    c = v0 * (hx * fy - hy * fx)
    dc = v0 * (dhx * fy - dhy * fx - h2)
    return hx, hy, c, dhx, dhy, dc, hx / h2, hy / h2, v0 * (hx * fx + hy * fy) / h2


@wp.func
def cat_eval(x: Any, y: Any, omega: Any, v0: Any, t: Any):
    """F(omega), dF/domega and the acceleration a of the line through P, at a local point."""
    hx, hy, c, dhx, dhy, dc, ax, ay, a0 = cat_coefficients(omega, v0, t)
    return hx * y - hy * x - c, dhx * y - dhy * x - dc, ax * x + ay * y - a0


@wp.func
def hermite_cubic(f0: Any, g0: Any, f1: Any, g1: Any, width: Any):
    """Coefficients (m0, q, p) of the cubic Hermite interpolant of F on an interval,
    H(s) = f0 + s (m0 + s (q + s p)) for s in [0, 1], from end values f and slopes g."""
    m0 = g0 * width
    m1 = g1 * width
    p = type(f0)(2.0) * (f0 - f1) + m0 + m1
    q = type(f0)(3.0) * (f1 - f0) - type(f0)(2.0) * m0 - m1
    return m0, q, p


@wp.func
def hermite_root(f0: Any, g0: Any, f1: Any, g1: Any, width: Any):
    """Root in [0, 1] of the Hermite interpolant (f0, f1 of opposite sign): a Newton start for F
    good to O(width^4)."""
    m0, q, p = hermite_cubic(f0, g0, f1, g1, width)
    zero = type(f0)(0.0)
    lo = zero
    hi = type(f0)(1.0)
    s = f0 / (f0 - f1)
    for _it in range(6):
        h = f0 + s * (m0 + s * (q + s * p))
        if (h >= zero) == (f0 >= zero):
            lo = s
        else:
            hi = s
        dh = m0 + s * (type(f0)(2.0) * q + type(f0)(3.0) * s * p)
        s_new = (lo + hi) * type(f0)(0.5)
        if dh != zero:
            s_newton = s - h / dh
            if s_newton > lo and s_newton < hi:
                s_new = s_newton
        s = s_new
    return s


@wp.func
def hermite_dips_to_zero(f0: Any, g0: Any, f1: Any, g1: Any, width: Any):
    """Whether the Hermite interpolant of F (same sign at both ends) comes within FOLD_MARGIN of
    zero, relative to the larger end value.

    F is smooth on the scale of a node interval (the interpolant's error is O(width^4)), so an
    interval whose interpolant stays far from zero cannot hold a root pair; only the rest pay
    for the exact search.
    """
    m0, q, p = hermite_cubic(f0, g0, f1, g1, width)
    zero = type(f0)(0.0)
    lowest = wp.min(wp.abs(f0), wp.abs(f1))
    # stationary points: 3 p s^2 + 2 q s + m0 = 0
    disc = q * q - type(f0)(3.0) * p * m0
    if p != zero and disc >= zero:
        root = wp.sqrt(disc)
        for sgn in range(2):
            s = (-q + (type(f0)(2.0 * float(sgn)) - type(f0)(1.0)) * root) / (type(f0)(3.0) * p)
            if s > zero and s < type(f0)(1.0):
                lowest = wp.min(lowest, wp.abs(f0 + s * (m0 + s * (q + s * p))))
    elif p == zero and q != zero:
        s = -m0 / (type(f0)(2.0) * q)
        if s > zero and s < type(f0)(1.0):
            lowest = wp.min(lowest, wp.abs(f0 + s * (m0 + s * q)))
    return lowest <= type(f0)(FOLD_MARGIN) * wp.max(wp.abs(f0), wp.abs(f1))


@wp.func
def cat_root_density(
    x: Any, y: Any, lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any,
    v0: Any, t: Any, sigma_a: Any, sigma_omega: Any, tol: Any,
):
    """g(a) g(omega) / |det J| at the root of F in [lo, hi] (F(lo), F(hi) of opposite sign).

    Newton from the Hermite estimate, kept inside the bracket (bisection when it leaves it);
    the density is taken from the last evaluation, whose omega is within ``tol`` of the root.
    """
    zero = type(x)(0.0)
    a = lo
    b = hi
    fa = f_lo
    w = lo + (hi - lo) * hermite_root(f_lo, g_lo, f_hi, g_hi, hi - lo)
    f, df, acc = cat_eval(x, y, w, v0, t)
    for _it in range(MAX_NEWTON):
        if f == zero:
            break
        if (f > zero) == (fa > zero):
            a = w
            fa = f
        else:
            b = w
        w_new = (a + b) * type(a)(0.5)
        if df != zero:
            w_newton = w - f / df
            if w_newton > a and w_newton < b:
                w_new = w_newton
        if wp.abs(w_new - w) <= tol or (b - a) <= tol:
            break
        w = w_new
        f, df, acc = cat_eval(x, y, w, v0, t)
    return normal_pdf(acc, zero, sigma_a) * normal_pdf(w, zero, sigma_omega) / wp.abs(df)


@wp.func
def cat_fold_minimum(x: Any, y: Any, lo: Any, hi: Any, g_lo: Any, g_hi: Any, v0: Any, t: Any, tol: Any):
    """Where dF/domega = 0 in [lo, hi], given that it changes sign there (Illinois method).
    Returns omega and F, dF/domega there."""
    zero = type(x)(0.0)
    a = lo
    b = hi
    ga = g_lo
    gb = g_hi
    side = int(0)
    m = b - gb * (b - a) / (gb - ga)
    f_m, g_m, acc = cat_eval(x, y, m, v0, t)
    for _it in range(MAX_FOLD_SEARCH):
        if g_m == zero:
            break
        if (g_m > zero) == (ga > zero):
            a = m
            ga = g_m
            if side == -1:
                gb = gb * type(x)(0.5)
            side = -1
        else:
            b = m
            gb = g_m
            if side == 1:
                ga = ga * type(x)(0.5)
            side = 1
        if (b - a) <= tol:
            break
        m = b - gb * (b - a) / (gb - ga)
        if not (m > a and m < b):
            m = (a + b) * type(x)(0.5)
        f_m, g_m, acc = cat_eval(x, y, m, v0, t)
    return m, f_m, g_m


@wp.func
def cat_negligible(table: wp.array2d(dtype=Any), k: int, x: Any, y: Any, a_cut: Any):
    """Whether the accelerations at nodes k-1 and k are both beyond +-a_cut on the same side."""
    a_prev = table[k - 1, 7] * x + table[k - 1, 8] * y - table[k - 1, 9]
    a_k = table[k, 7] * x + table[k, 8] * y - table[k, 9]
    return (a_prev > a_cut and a_k > a_cut) or (a_prev < -a_cut and a_k < -a_cut)


@wp.func
def cat_density_local(
    x: Any,
    y: Any,
    table: wp.array2d(dtype=Any),
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    tol: Any,
):
    """Exact CAT density at a point of the local frame: scan the table, refine every root."""
    zero = type(x)(0.0)
    density = zero
    a_cut = type(x)(PRUNE_SIGMAS) * sigma_a
    n = table.shape[0]
    w_prev = table[0, 0]
    f_prev = table[0, 1] * y - table[0, 2] * x - table[0, 3]
    g_prev = table[0, 4] * y - table[0, 5] * x - table[0, 6]
    for k in range(1, n):
        w_k = table[k, 0]
        f_k = table[k, 1] * y - table[k, 2] * x - table[k, 3]
        g_k = table[k, 4] * y - table[k, 5] * x - table[k, 6]
        if (f_k >= zero) != (f_prev >= zero):
            if not cat_negligible(table, k, x, y, a_cut):
                density += cat_root_density(
                    x, y, w_prev, w_k, f_prev, g_prev, f_k, g_k, v0, t, sigma_a, sigma_omega, tol
                )
        elif f_prev * g_prev < zero and f_k * g_k > zero:
            # |F| falls then rises inside the interval; if its minimum comes near zero it may
            # dip through it: a fold of the banana, two roots close together.
            if hermite_dips_to_zero(f_prev, g_prev, f_k, g_k, w_k - w_prev) and not cat_negligible(
                table, k, x, y, a_cut
            ):
                w_min, f_min, g_min = cat_fold_minimum(x, y, w_prev, w_k, g_prev, g_k, v0, t, tol)
                if (f_min >= zero) != (f_k >= zero):
                    density += cat_root_density(
                        x, y, w_prev, w_min, f_prev, g_prev, f_min, g_min, v0, t, sigma_a, sigma_omega, tol
                    )
                    density += cat_root_density(
                        x, y, w_min, w_k, f_min, g_min, f_k, g_k, v0, t, sigma_a, sigma_omega, tol
                    )
        w_prev = w_k
        f_prev = f_k
        g_prev = g_k
    return density


@wp.kernel
def cat_table(
    omegas: wp.array(dtype=Any), v0: Any, t: Any, table: wp.array2d(dtype=Any)
):
    """Fill the scan table: one row per turn-rate node."""
    k = wp.tid()
    w = omegas[k]
    hx, hy, c, dhx, dhy, dc, ax, ay, a0 = cat_coefficients(w, v0, t)
    table[k, 7] = ax
    table[k, 8] = ay
    table[k, 9] = a0
    table[k, 0] = w
    table[k, 1] = hx
    table[k, 2] = hy
    table[k, 3] = c
    table[k, 4] = dhx
    table[k, 5] = dhy
    table[k, 6] = dc


@wp.kernel
def cat_grid(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    table: wp.array2d(dtype=Any),
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    pose: wp.array(dtype=Any),
    tol: Any,
    out: wp.array2d(dtype=Any),
):
    """Density at the cell centres (xs[j], ys[row0 + i]) of a band of rows."""
    i, j = wp.tid()
    row = row0 + i
    x, y = world_to_local(xs[j], ys[row], pose)
    out[row, j] = cat_density_local(x, y, table, v0, t, sigma_a, sigma_omega, tol)


@wp.kernel
def cat_points(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    start: int,
    table: wp.array2d(dtype=Any),
    v0: Any,
    t: Any,
    sigma_a: Any,
    sigma_omega: Any,
    pose: wp.array(dtype=Any),
    tol: Any,
    out: wp.array(dtype=Any),
):
    """Density at arbitrary world points (xs[k], ys[k]) for k in a chunk starting at ``start``."""
    k = start + wp.tid()
    x, y = world_to_local(xs[k], ys[k], pose)
    out[k] = cat_density_local(x, y, table, v0, t, sigma_a, sigma_omega, tol)


def _register_overloads():
    for scalar in (wp.float32, wp.float64):
        vec = wp.array(dtype=scalar)
        mat = wp.array2d(dtype=scalar)
        wp.overload(cat_table, {"omegas": vec, "v0": scalar, "t": scalar, "table": mat})
        common = {
            "xs": vec, "ys": vec, "table": mat, "v0": scalar, "t": scalar,
            "sigma_a": scalar, "sigma_omega": scalar, "pose": vec, "tol": scalar,
        }
        wp.overload(cat_grid, {**common, "out": mat})
        wp.overload(cat_points, {**common, "out": vec})


_register_overloads()
