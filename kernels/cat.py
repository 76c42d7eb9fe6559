"""Exact CAT density (eq. (1) of the polar-banana paper) by root finding in the turn rate.

For a fixed turn rate omega the CAT position  p(a, omega) = v0 f(omega) + a h(omega)  is affine
in the acceleration a, with (u = omega t, basis in ``common.cat_basis``)

    f = t (A, B),   h = t^2 (C, D),   df/domega = t^2 (D, -C),   dh/domega = t^3 (C', D').

A point P is reached at omega iff  F(omega) = h x (P - v0 f) = 0  (2-D cross product), with
a = h . (P - v0 f) / |h|^2, and  dF/domega = h' x (P - v0 f) + v0 |h|^2 = -det d(x,y)/d(a,omega).
The density is  sum over roots of  g(a; sigma_a) g(omega; sigma_omega) / |dF/domega|.

F and dF/domega are affine in P with omega-only coefficients: each point scans a table of them
(``cat_table``, ``cat_scan``; on the CPU ``kernels/cat_lanes.py``), ``cat_interval`` proves which
node intervals hold roots, and ``cat_root_density`` finds each.
"""

from typing import Any

import warp as wp

from .common import (
    SERIES_SWITCH, cat_basis, horner10, local_to_world, series_c_over_u, series_d, series_dc, series_dd_over_u,
    sinc_of, world_to_local,
)
from .evidence import EVIDENCE, evidence_add, evidence_node, evidence_nodes, evidence_reset, evidence_time
from .generate import (
    ARRAY, ARRAY2D, SCALAR, SCALARS, VEC4, Params, carried_points_kernel, density_kernels, overload_on_use,
)

#: Table columns: omega; the coefficients of F = hx*y - hy*x - c and of
#: dF/domega = dhx*y - dhy*x - dc; and of the acceleration of the line through P,
#: a = ax*x + ay*y - a0 (exact at a root).
TABLE_COLUMNS = 10

#: Roots whose acceleration lies beyond this many sigma_a contribute g(a) < 1e-313 relative and
#: are skipped when both ends of their node interval are beyond it on the same side.
PRUNE_SIGMAS = 38.0

#: 1 / (2 pi)
INV_2PI = 0.15915494309189535

#: Iteration caps; each iteration at least halves the bracket, so float64 converges well before.
MAX_NEWTON = 100
MAX_FOLD_SEARCH = 100

#: A node interval whose roots the bounds cannot settle is split into SPLIT parts, and each of
#: those again (two levels: widths 1/8 and 1/64 of the node spacing).
SPLIT = 8

# No adjoints: nothing differentiates these kernels. And the split loops stay loops: unrolled
# (Warp unrolls constant loops up to ``max_unroll``, 16 by default), every kernel held
# 1 + 8 + 64 inlined copies of ``cat_interval`` with its root and fold searches, and NVRTC took
# minutes to build the module for a GPU (see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False, "max_unroll": SPLIT - 1})

#: 1/3, 7/12 and 1/12, for the scan's allowances (``cat_scan_noise``).
ONE_THIRD = 1.0 / 3.0
SEVEN_TWELFTHS = 7.0 / 12.0
ONE_TWELFTH = 1.0 / 12.0

#: Rounding allowance on computed values of F and dF/domega, in units of the dtype's epsilon
#: times the largest term they sum (their table coefficients carry a few ulps each).
ROUNDING_ULPS = 32.0


@wp.func
def series_ddc_over_u(z: Any):
    """C''(u) / u as a series in z = u^2: sum_{n>=2} (-1)^(n+1) 2n (2n-1) (2n-2) u^(2n-4) / (2n+1)!
    (``common.cat_basis``'s C' differentiated term by term)."""
    return horner10(z, type(z)(-0.2), type(z)(0.023809523809523808), type(z)(-0.000925925925925926), type(z)(1.8037518037518038e-05), type(z)(-2.119793786460453e-07), type(z)(1.6701405590294479e-09), type(z)(-9.44649637460095e-12), type(z)(4.024823016747272e-14), type(z)(-1.3387891687359624e-16), type(z)(3.574189237662752e-19))


@wp.func
def series_ddd(z: Any):
    """D''(u) as a series in z = u^2: sum_{n>=2} (-1)^(n+1) (2n-1) (2n-2) (2n-3) u^(2n-4) / (2n)!."""
    return horner10(z, type(z)(-0.25), type(z)(0.08333333333333333), type(z)(-0.005208333333333333), type(z)(0.0001388888888888889), type(z)(-2.066798941798942e-06), type(z)(1.968379944570421e-08), type(z)(-1.3047973117417563e-10), type(z)(6.372636443183181e-13), type(z)(-2.3897386661936928e-15), type(z)(7.099639531175557e-18))


@wp.func
def series_dddc(z: Any):
    """C'''(u) as a series in z = u^2: sum_{n>=2} (-1)^(n+1) 2n (2n-1) (2n-2) (2n-3) u^(2n-4) / (2n+1)!."""
    return horner10(z, type(z)(-0.2), type(z)(0.07142857142857142), type(z)(-0.004629629629629629), type(z)(0.00012626262626262626), type(z)(-1.907814407814408e-06), type(z)(1.8371546149323926e-08), type(z)(-1.2280445286981235e-10), type(z)(6.037234525120908e-13), type(z)(-2.275941586851136e-15), type(z)(6.7909595515592285e-18))


@wp.func
def series_dddd_over_u(z: Any):
    """D'''(u) / u as a series in z = u^2: sum_{n>=3} (-1)^(n+1) (2n-1) (2n-2) (2n-3) (2n-4) u^(2n-6) / (2n)!."""
    return horner10(z, type(z)(0.16666666666666666), type(z)(-0.020833333333333332), type(z)(0.0008333333333333334), type(z)(-1.6534391534391536e-05), type(z)(1.9683799445704207e-07), type(z)(-1.5657567740901075e-09), type(z)(8.921691020456453e-12), type(z)(-3.8235818659099085e-14), type(z)(1.2779351156116003e-16), type(z)(-3.4252646860934706e-19))


@wp.func
def cat_basis_curved(u: Any):
    """``common.cat_basis`` (A, B, C, D, C', D' by the same formulas: the same bits) with each
    sine and cosine taken once, and the second and third derivatives C'', D'', C''', D''' (the
    closed forms below; their series below SERIES_SWITCH)."""
    one = type(u)(1.0)
    two = type(u)(2.0)
    half_u = u * type(u)(0.5)
    sin_half = wp.sin(half_u)
    s = wp.sin(u)
    a_fn = sin_half * sinc_of(half_u, sin_half)  # (1 - cos u) / u without cancellation
    b_fn = sinc_of(u, s)
    if wp.abs(u) < type(u)(SERIES_SWITCH):
        z = u * u
        return (a_fn, b_fn, u * series_c_over_u(z), series_d(z), series_dc(z), u * series_dd_over_u(z),
                u * series_ddc_over_u(z), series_ddd(z), series_dddc(z), u * series_dddd_over_u(z))
    c = wp.cos(u)
    u2 = u * u
    u3 = u2 * u
    u4 = u2 * u2
    six = type(u)(6.0)
    three = type(u)(3.0)
    c_fn = (s - u * c) / u2
    d_fn = (c + u * s - one) / u2
    dc_fn = (u2 * s - two * s + two * u * c) / u3
    dd_fn = (u2 * c - two * c - two * u * s + two) / u3
    ddc_fn = (u3 * c - three * u2 * s + six * s - six * u * c) / u4
    ddd_fn = (six * c + six * u * s - u3 * s - three * u2 * c - six) / u4
    u5 = u4 * u
    four = type(u)(4.0)
    twelve = type(u)(12.0)
    twenty_four = type(u)(24.0)
    dddc_fn = (twenty_four * u * c - u4 * s - four * u3 * c + twelve * u2 * s - twenty_four * s) / u5
    dddd_fn = (twenty_four - u4 * c - twenty_four * c - twenty_four * u * s + four * u3 * s + twelve * u2 * c) / u5
    return a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn, ddc_fn, ddd_fn, dddc_fn, dddd_fn


@wp.func
def cat_line_terms(a_fn: Any, b_fn: Any, c_fn: Any, d_fn: Any, dc_fn: Any, dd_fn: Any, v0: Any, t: Any):
    """From the basis at omega t: f = t (A, B), h = t^2 (C, D), h' = t^3 (C', D'), |h|^2, and the
    line's offsets c = v0 h x f, dc = v0 (h' x f - |h|^2) (d/domega (h x f) = h' x f + h x f',
    and h x f' = -|h|^2): what F, its derivatives and the acceleration share."""
    t2 = t * t
    fx = t * a_fn
    fy = t * b_fn
    hx = t2 * c_fn
    hy = t2 * d_fn
    dhx = t2 * t * dc_fn
    dhy = t2 * t * dd_fn
    h2 = hx * hx + hy * hy
    c = v0 * (hx * fy - hy * fx)
    dc = v0 * (dhx * fy - dhy * fx - h2)
    return fx, fy, hx, hy, dhx, dhy, h2, c, dc


@wp.func
def cat_eval_curved(x: Any, y: Any, omega: Any, v0: Any, t: Any):
    """F, dF/domega, d^2F/domega^2 and d^3F/domega^3 at a local point, and the acceleration
    a = h . (P - v0 f) / |h|^2 of the line through it with da/domega and d^2a/domega^2 (for
    ``cat_root_value``).

    With h'' = t^4 (C'', D''), h''' = t^5 (C''', D'''), f' = t^2 (D, -C) = (hy, -hx):
    h' x f' = -h . h' and h'' x f' = -h . h'', so with Q = P - v0 f

        d^2F/domega^2 = h'' x Q - v0 (h' x f' - 2 h . h') = h'' x Q + 3 v0 h . h',
        d^3F/domega^3 = h''' x Q + 3 v0 |h'|^2 + 4 v0 h . h''.
    """
    u = omega * t
    a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn, ddc_fn, ddd_fn, dddc_fn, dddd_fn = cat_basis_curved(u)
    fx, fy, hx, hy, dhx, dhy, h2, c, dc = cat_line_terms(a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn, v0, t)
    t2 = t * t
    ddhx = t2 * t2 * ddc_fn
    ddhy = t2 * t2 * ddd_fn
    ddc = v0 * (ddhx * fy - ddhy * fx) - type(x)(3.0) * v0 * (hx * dhx + hy * dhy)
    t4 = t2 * t2
    dddhx = t4 * t * dddc_fn
    dddhy = t4 * t * dddd_fn
    hh1 = hx * dhx + hy * dhy  # h . h'
    hh2 = hx * ddhx + hy * ddhy  # h . h''
    h1h1 = dhx * dhx + dhy * dhy  # |h'|^2
    qx = x - v0 * fx
    qy = y - v0 * fy
    dddf = (dddhx * qy - dddhy * qx) + v0 * (type(x)(3.0) * h1h1 + type(x)(4.0) * hh2)
    # a = N / D with N = h . Q, D = |h|^2: N' = h' . Q (h . f' = 0), N'' = h'' . Q - v0 h' . f',
    # f' = (hy, -hx), D' = 2 h . h', D'' = 2 (|h'|^2 + h . h'')
    inv_h2 = type(x)(1.0) / h2  # one division for the three
    acc = (hx * qx + hy * qy) * inv_h2
    dacc = (dhx * qx + dhy * qy - type(x)(2.0) * acc * hh1) * inv_h2
    n2 = ddhx * qx + ddhy * qy - v0 * (dhx * hy - dhy * hx)
    ddacc = (n2 - type(x)(4.0) * dacc * hh1 - type(x)(2.0) * acc * (h1h1 + hh2)) * inv_h2
    return hx * y - hy * x - c, dhx * y - dhy * x - dc, ddhx * y - ddhy * x - ddc, dddf, acc, dacc, ddacc


@wp.func
def cat_eval(x: Any, y: Any, omega: Any, v0: Any, t: Any):
    """F(omega) and dF/domega at a local point (``cat_eval_curved``'s)."""
    f, df, ddf, dddf, acc, dacc, ddacc = cat_eval_curved(x, y, omega, v0, t)
    return f, df


@wp.func
def hermite_root(f0: Any, g0: Any, f1: Any, g1: Any, width: Any):
    """A Newton start for the root in [0, 1] of F (f0, f1 of opposite sign), good to O(width^4)
    where F is monotone: the inverse cubic Hermite interpolant, s as a cubic in
    tau = (F - f0) / (f1 - f0) with s(0) = 0, s(1) = 1 and slopes ds/dtau = (f1 - f0) / (g width)
    at the ends, at F = 0 (tau = the chord's root): no iteration, no chain of divisions. A start
    outside [0, 1] (F not monotone: a slope near zero or of the wrong sign) is clamped: a start
    needs no guarantee (``cat_root_density`` keeps its own bracket)."""
    zero = type(f0)(0.0)
    one = type(f0)(1.0)
    two = type(f0)(2.0)
    three = type(f0)(3.0)
    span = f1 - f0
    tau = -f0 / span
    d0 = span / (g0 * width)
    d1 = span / (g1 * width)
    tau2 = tau * tau
    tau3 = tau2 * tau
    s = (tau3 - two * tau2 + tau) * d0 + (three * tau2 - two * tau3) + (tau3 - tau2) * d1
    # NaN (a zero slope) or out of range: the chord's root, or the end
    s = wp.where(s >= zero and s <= one, s, wp.where(s > one, one, wp.where(s < zero, zero, tau)))
    return s


@wp.func
def hermite_minimum(f0: Any, g0: Any, f1: Any, g1: Any, width: Any):
    """The smallest value on [0, 1] of the cubic Hermite interpolant of F on an interval of that
    width, H(s) = f0 + s (m0 + s (q + s p)), from its end values f and slopes g (signed: its ends
    and its interior stationary points, where 3 p s^2 + 2 q s + m0 = 0)."""
    m0 = g0 * width
    m1 = g1 * width
    p = type(f0)(2.0) * (f0 - f1) + m0 + m1
    q = type(f0)(3.0) * (f1 - f0) - type(f0)(2.0) * m0 - m1
    zero = type(f0)(0.0)
    one = type(f0)(1.0)
    lowest = wp.min(f0, f1)
    disc = q * q - type(f0)(3.0) * p * m0
    if p != zero and disc >= zero:
        root = wp.sqrt(disc)
        for sgn in range(2):
            s = (-q + (type(f0)(2.0 * float(sgn)) - one) * root) / (type(f0)(3.0) * p)
            if s > zero and s < one:
                lowest = wp.min(lowest, f0 + s * (m0 + s * (q + s * p)))
    elif p == zero and q != zero:
        s = -m0 / (type(f0)(2.0) * q)
        if s > zero and s < one:
            lowest = wp.min(lowest, f0 + s * (m0 + s * q))
    return lowest


#: A root's path under evidence (``cat_carry_root``): the pack's struct, the pose that places the
#: path in the world (the model's, turned by a heading node), and the weight of that heading node.
CAT_CARRY = Params("CatCarry", __name__, ev=lambda scalar: EVIDENCE.of(scalar), pose=VEC4, scale=SCALAR)


@wp.func
def cat_path_position(a: Any, omega: Any, v0: Any, s: Any):
    """Local position at time s of the CAT path with acceleration a and turn rate omega, eq. (1)
    with u = omega s: v0 s (A, B) + a s^2 (C, D) (``common.cat_basis``)."""
    a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn = cat_basis(omega * s)
    s2 = s * s
    return v0 * s * a_fn + a * s2 * c_fn, v0 * s * b_fn + a * s2 * d_fn


@wp.func
def cat_carry_root(carry: int, a: Any, omega: Any, v0: Any, density: Any, lw: wp.array(dtype=Any),
                   out: wp.array(dtype=Any)):
    """No evidence (the plain kernels, whose ``carry`` is the integer 0): nothing to add."""
    return


@wp.func
def cat_carry_root(carry: Any, a: Any, omega: Any, v0: Any, density: Any, lw: wp.array(dtype=Any),  # noqa: F811
                   out: wp.array(dtype=Any)):
    """Add the path (a, omega)'s density times its evidence weights (``kernels/evidence.py``) to
    ``out``, scaled by the heading node's weight; positions at the pack's node times (reused
    while a time repeats: the nodes are sorted)."""
    ev = carry.ev
    evidence_reset(ev, lw)
    zero = type(a)(0.0)
    px = zero
    py = zero
    s_prev = zero
    for j in range(evidence_nodes(ev)):
        s = evidence_time(ev, j)
        if j == 0 or s != s_prev:
            lx, ly = cat_path_position(a, omega, v0, s)
            px, py = local_to_world(lx, ly, carry.pose)
            s_prev = s
        evidence_node(ev, j, px, py, lw)
    evidence_add(ev, lw, carry.scale * density, out)


@wp.func
def cat_root_step(w: Any, a: Any, b: Any, fa: Any, f: Any, df: Any, ddf: Any, tol: Any, m3: Any):
    """One step of ``cat_root_density``'s search from w (F, dF/domega, d^2F/domega^2 there):
    the bracket [a, b] (F(a) = fa) narrowed by w, the next omega, and whether to stop at w.

    Halley's step, the Newton step n over 1 - L with L = n F'' / (2 F') (cubic convergence:
    from the Hermite start one step leaves w within tol of the root), where |L| <= 1/2 (then
    it lies within 2/3 to 2 Newton steps: near a fold, where F' vanishes, Halley's step shrinks
    to -2 F' / F'' whatever F is, and would crawl) and it stays inside the bracket; else
    Newton's, inside the bracket; else bisection. The search stops where F = 0, where the
    Newton step is at most tol (whether or not it stays inside: one that rounds to nothing
    leaves w on the bracket's end), where the step taken or the bracket is at most tol; or at
    the Halley point, where a bound on the third derivative (``m3``) proves it within
    tol of the root (the common case: one evaluation a root). Selects rather than branches: the
    bracket's side and the step's kind are coin tosses from root to root, and a mispredicted
    branch cost more than the step.
    """
    zero = type(w)(0.0)
    same = (f > zero) == (fa > zero)
    a = wp.where(same, w, a)
    fa = wp.where(same, f, fa)
    b = wp.where(same, b, w)
    slope = df != zero
    inv_df = type(w)(1.0) / df  # two divisions a step, not five: each is a long latency
    step_newton = f * inv_df
    bend = step_newton * ddf * (type(w)(0.5) * inv_df)
    w_newton = w - step_newton
    w_halley = w - step_newton / (type(w)(1.0) - bend)
    halley_in = slope and wp.abs(bend) <= type(w)(0.5) and w_halley > a and w_halley < b
    newton_in = slope and w_newton > a and w_newton < b
    w_new = wp.where(halley_in, w_halley, wp.where(newton_in, w_newton, (a + b) * type(w)(0.5)))
    stop = (f == zero or (slope and wp.abs(step_newton) <= tol) or wp.abs(w_new - w) <= tol
            or (b - a) <= tol)
    # The Halley point proved within tol of the root, without evaluating F there: with
    # e = w_halley - w, q(e) = F + e F' + e^2 F'' / 2 differs from F(w + e) by at most
    # m3 |e|^3 / 6 (m3 >= |d^3F/domega^3|), and |q'| >= |F'| - |F''| 2|e| =: d > 0 on
    # |e'| <= 2|e|. So with rho = (|q(e)| + m3 (2|e|)^3 / 6) / d <= |e|, F at w_halley -+ rho
    # has opposite signs (q moves by at least rho d from q(e) there, more than |q(e)| and the
    # remainder together): a root lies within rho of w_halley, the bracket's own if that span
    # is inside the bracket.
    e = w_halley - w
    q = f + e * (df + type(w)(0.5) * e * ddf)
    two_e = type(w)(2.0) * wp.abs(e)
    d = wp.abs(df) - wp.abs(ddf) * two_e
    # rho d, and rho <= min(|e|, tol, the bracket's room) tested as rho d <= that times d (d > 0)
    rho_d = wp.abs(q) + m3 * two_e * two_e * two_e * type(w)(0.16666666666666666)
    room = wp.min(wp.min(wp.abs(e), tol), wp.min(w_halley - a, b - w_halley))
    proved = halley_in and not stop and d > zero and rho_d < room * d
    return a, b, fa, w_new, stop or proved, proved


@wp.func
def cat_root_start(lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any):
    """``cat_root_density``'s first omega: the Hermite start (``hermite_root``)."""
    return lo + (hi - lo) * hermite_root(f_lo, g_lo, f_hi, g_hi, hi - lo)


@wp.func
def cat_root_value(w: Any, e: Any, df: Any, ddf: Any, dddf: Any, acc: Any, dacc: Any, ddacc: Any, sigma_a: Any,
                   sigma_omega: Any, noise_g: Any):
    """g(a) g(omega) / max(|dF/domega|, noise_g) at the root omega = w + e, from the values at the
    search's last evaluation w (e = 0: the search stopped there; else ``cat_root_step``'s proved
    Halley point): dF/domega and a carried to w + e by their Taylor polynomials of degree two,
    whose remainders are O(e^3), e within a step of the Hermite start (a first-degree carry left
    a bias of the order of e^2 F''' / F', 1e-14 relative: measurable in a map's total mass). One
    exponential. Returns the density, the acceleration and omega."""
    half = type(w)(0.5)
    slope = df + e * (ddf + half * e * dddf)
    a = acc + e * (dacc + half * e * ddacc)
    omega = w + e
    za = a / sigma_a
    zw = omega / sigma_omega
    density = (type(w)(INV_2PI) / (sigma_a * sigma_omega) * wp.exp(type(w)(-0.5) * (za * za + zw * zw))
               / wp.max(wp.abs(slope), noise_g))
    return density, a, omega


@wp.func
def cat_third_bound(x: Any, y: Any, v0: Any, t: Any):
    """M3 >= |d^3F/domega^3| at the local point (``cat_interval``'s bound, M3 w^2 / w^2):
    t^5 (r / 5 + v0 t / 20), r = |P|, rounded up by 1 %."""
    r = wp.sqrt(x * x + y * y)
    t2 = t * t
    return t2 * t2 * t * (r * type(x)(0.2) + v0 * t * type(x)(0.05)) * type(x)(1.01)


@wp.func
def cat_root_density(
    x: Any, y: Any, lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any,
    v0: Any, t: Any, sigma_a: Any, sigma_omega: Any, tol: Any, noise_g: Any,
    carry: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any),
):
    """g(a) g(omega) / |det J| at the root of F in [lo, hi] (F(lo), F(hi) of opposite sign);
    ``cat_carry_root`` adds the root's path, weighted by the evidence, to ``out`` (a no-op for
    the plain kernels, whose ``carry`` is the integer 0).

    The search (``cat_root_step``) starts at the Hermite estimate (``cat_root_start``); the
    density is taken at an omega within ``tol`` of the root (``cat_root_value``). |det J| = |dF/domega| is taken as at least ``noise_g``, its rounding allowance: on a fold
    caustic the density is infinite, and a point whose coordinates round onto it (in float32,
    within ~1e-7 v0 t) gets the largest value its arithmetic can resolve, never inf.
    On the CPU, ``lanes.lane_cat_roots`` takes the same steps for a vector of single roots.
    """
    a = lo
    b = hi
    fa = f_lo
    m3 = cat_third_bound(x, y, v0, t)
    e = type(x)(0.0)
    w = cat_root_start(lo, hi, f_lo, g_lo, f_hi, g_hi)
    f, df, ddf, dddf, acc, dacc, ddacc = cat_eval_curved(x, y, w, v0, t)
    for _it in range(MAX_NEWTON):
        a, b, fa, w_new, stop, proved = cat_root_step(w, a, b, fa, f, df, ddf, tol, m3)
        if stop:
            if proved:
                e = w_new - w
            break
        w = w_new
        f, df, ddf, dddf, acc, dacc, ddacc = cat_eval_curved(x, y, w, v0, t)
    density, a_root, omega = cat_root_value(w, e, df, ddf, dddf, acc, dacc, ddacc, sigma_a, sigma_omega, noise_g)
    cat_carry_root(carry, a_root, omega, v0, density, lw, out)
    return density


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
    f_m, g_m = cat_eval(x, y, m, v0, t)
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
        f_m, g_m = cat_eval(x, y, m, v0, t)
    return m, f_m, g_m


@wp.func
def cat_negligible(table: wp.array2d(dtype=Any), k: int, x: Any, y: Any, a_cut: Any):
    """Whether the accelerations at nodes k-1 and k are both beyond +-a_cut on the same side."""
    a_prev = table[k - 1, 7] * x + table[k - 1, 8] * y - table[k - 1, 9]
    a_k = table[k, 7] * x + table[k, 8] * y - table[k, 9]
    return (a_prev > a_cut and a_k > a_cut) or (a_prev < -a_cut and a_k < -a_cut)


@wp.func
def cat_curvature(lo: Any, hi: Any, v0: Any, t: Any, r: Any, noise_g: Any):
    """``cat_interval``'s M3 w^2 on [lo, hi] and the curvature margin M3 w^2 + 2 noise_g."""
    du = (hi - lo) * t
    du2 = du * du
    t2 = t * t
    m3w2 = t2 * t * (r * type(r)(0.2) + v0 * t * type(r)(0.05)) * du2  # M3 w^2
    return m3w2, m3w2 + type(r)(2.0) * noise_g


@wp.func
def cat_one_root(g_lo: Any, g_hi: Any, m3w2: Any, curvature: Any, noise_g: Any):
    """Whether a sign change of F holds exactly one root (``cat_interval`` (iii)): F' keeps its
    sign (its ends beyond its chord's deviation M3 w^2 / 8) or F'' does."""
    zero = type(g_lo)(0.0)
    monotone = (g_lo > zero) == (g_hi > zero) and wp.min(wp.abs(g_lo), wp.abs(g_hi)) > (
        type(g_lo)(0.125) * m3w2 + noise_g
    )
    return monotone or wp.abs(g_hi - g_lo) > curvature


@wp.func
def cat_interval(
    x: Any, y: Any, lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any,
    v0: Any, t: Any, sigma_a: Any, sigma_omega: Any, tol: Any, r: Any, noise_f: Any, noise_g: Any,
    last: bool, carry: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any),
):
    """The density of the roots of F in [lo, hi] (F, dF/domega given at both ends), and whether
    the bounds below settled them (``last``: settle them anyway, by the fold search).

    Bounds. With tau the time since the fix and e(theta) a unit vector, f = int_0^t e(omega tau)
    dtau and h = int_0^t tau e(omega tau) dtau, so F = h x P - v0 h x f with
    h x f = int int tau1 sin(omega (tau1 - tau2)) dtau1 dtau2 (up to sign). Differentiating under
    the integrals, |d^n h / domega^n| <= t^(n+2) / (n+2) and |d^n (h x f) / domega^n| <=
    t^(n+3) int_0^1 int_0^1 u |u - v|^n du dv = t^(n+3) (1/12, 1/20, 1/30 for n = 2, 3, 4), so
    with r = |P| and u = omega t, on an interval of width du in u (w = du / t in omega):

        M2 w^2 = t^2 (r / 4 + v0 t / 12) du^2,    M3 w^2 = t^3 (r / 5 + v0 t / 20) du^2,
        M4 w^4 = t^2 (r / 6 + v0 t / 30) du^4,    M_n >= max |d^n F / domega^n| on it.

    Proof that no root is missed. (i) Same sign at both ends: F differs from its chord by at most
    M2 w^2 / 8 and from its cubic Hermite interpolant H by at most M4 w^4 / 384
    (F - H = F^(4)(xi) / 4! (s - lo)^2 (s - hi)^2); if either bound keeps F off zero there is no
    root. (ii) Else, if |g_hi - g_lo| > M3 w^2, F'' keeps one sign on the interval (the mean
    value theorem puts F'' = (g_hi - g_lo) / w somewhere in it, and F'' moves by at most M3 w):
    F is convex or concave, so it has at most two roots, both around the one minimum of |F|,
    which exists inside only if |F| falls at lo and rises at hi; ``cat_fold_minimum`` finds it
    (F' is monotone) and the two roots, if F changes sign there, are bracketed on either side.
    (iii) A sign change holds exactly one root if F' keeps its sign (F' differs from its chord by
    at most M3 w^2 / 8) or F'' does (as in (ii)). (iv) Otherwise the interval is undecided and is
    split (``cat_split``). Values of F and F' carry rounding ``noise_f``, ``noise_g``, added to
    every margin. An interval still undecided at 1/64 of the node spacing has F, F' and F'' all
    near zero together (a cusp of the caustic, where three roots meet): there the fold search of
    (ii) runs without the guarantee. The scan's nodes are never more than 0.1 apart in omega t
    (``bananagrid.models.cat.NODE_SPACING``), so the bounds always get the chance to settle.
    """
    zero = type(x)(0.0)
    du = (hi - lo) * t
    du2 = du * du
    t2 = t * t
    m3w2, curvature = cat_curvature(lo, hi, v0, t, r, noise_g)
    if (f_hi >= zero) != (f_lo >= zero):
        if cat_one_root(g_lo, g_hi, m3w2, curvature, noise_g) or last:
            density = cat_root_density(
                x, y, lo, hi, f_lo, g_lo, f_hi, g_hi, v0, t, sigma_a, sigma_omega, tol, noise_g, carry, lw, out
            )
            return density, True
        return zero, False
    chord = t2 * (r * type(x)(0.25) + v0 * t / type(x)(12.0)) * du2 * type(x)(0.125) + noise_f
    if wp.min(wp.abs(f_lo), wp.abs(f_hi)) > chord:
        return zero, True
    sign = type(x)(1.0)
    if f_lo < zero:
        sign = type(x)(-1.0)
    hermite = t2 * (r / type(x)(6.0) + v0 * t / type(x)(30.0)) * du2 * du2 / type(x)(384.0)
    if hermite_minimum(sign * f_lo, sign * g_lo, sign * f_hi, sign * g_hi, hi - lo) > (
        hermite + noise_f + type(x)(0.3) * (hi - lo) * noise_g
    ):
        return zero, True
    if not (wp.abs(g_hi - g_lo) > curvature or last):
        return zero, False
    density = zero
    if f_lo * g_lo < zero and f_hi * g_hi > zero:  # |F| falls, then rises: its minimum is inside
        w_min, f_min, g_min = cat_fold_minimum(x, y, lo, hi, g_lo, g_hi, v0, t, tol)
        if (f_min >= zero) != (f_hi >= zero):
            density = cat_root_density(
                x, y, lo, w_min, f_lo, g_lo, f_min, g_min, v0, t, sigma_a, sigma_omega, tol, noise_g, carry, lw, out
            ) + cat_root_density(
                x, y, w_min, hi, f_min, g_min, f_hi, g_hi, v0, t, sigma_a, sigma_omega, tol, noise_g, carry, lw, out
            )
    return density, True


@wp.func
def cat_part_end(x: Any, y: Any, lo: Any, hi: Any, f_hi: Any, g_hi: Any, i: int, v0: Any, t: Any):
    """The right end of part ``i`` of SPLIT equal parts of [lo, hi], with F and dF/domega there."""
    if i == SPLIT - 1:
        return hi, f_hi, g_hi
    b = lo + (hi - lo) * type(x)(float(i + 1) / float(SPLIT))
    f_b, g_b = cat_eval(x, y, b, v0, t)
    return b, f_b, g_b


@wp.func
def cat_split(
    x: Any, y: Any, lo: Any, hi: Any, f_lo: Any, g_lo: Any, f_hi: Any, g_hi: Any,
    v0: Any, t: Any, sigma_a: Any, sigma_omega: Any, tol: Any, r: Any, noise_f: Any, noise_g: Any,
    carry: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any),
):
    """The roots of an interval ``cat_interval`` left undecided: split it into SPLIT parts, and
    each part it still cannot settle into SPLIT more (the last level settles them)."""
    density = type(x)(0.0)
    a = lo
    f_a = f_lo
    g_a = g_lo
    for i in range(SPLIT):
        b, f_b, g_b = cat_part_end(x, y, lo, hi, f_hi, g_hi, i, v0, t)
        part, settled = cat_interval(
            x, y, a, b, f_a, g_a, f_b, g_b, v0, t, sigma_a, sigma_omega, tol, r, noise_f, noise_g, False, carry, lw, out
        )
        if settled:
            density += part
        else:
            c = a
            f_c = f_a
            g_c = g_a
            for j in range(SPLIT):
                e, f_e, g_e = cat_part_end(x, y, a, b, f_b, g_b, j, v0, t)
                piece, done = cat_interval(
                    x, y, c, e, f_c, g_c, f_e, g_e, v0, t, sigma_a, sigma_omega, tol, r, noise_f, noise_g, True,
                    carry, lw, out,
                )
                density += piece
                c = e
                f_c = f_e
                g_c = g_e
        a = b
        f_a = f_b
        g_a = g_b
    return density


@wp.func
def cat_scan_noise(x: Any, y: Any, v0: Any, t: Any, eps: Any):
    """The scan's rounding allowances on F and dF/domega at (x, y), and the chord bound's
    coefficient (M2 / 8 per squared node spacing, ``cat_interval``)."""
    r = wp.sqrt(x * x + y * y)
    t2 = t * t
    noise_f = type(x)(ROUNDING_ULPS) * eps * t2 * type(x)(0.5) * (wp.abs(x) + wp.abs(y) + v0 * t)
    # products by the constants, not quotients: the scan takes these at every point it tests
    noise_g = type(x)(ROUNDING_ULPS) * eps * t2 * t * (
        (wp.abs(x) + wp.abs(y)) * type(x)(ONE_THIRD) + v0 * t * type(x)(SEVEN_TWELFTHS)
    )
    chord_coef = t2 * t2 * (r * type(x)(0.25) + v0 * t * type(x)(ONE_TWELFTH)) * type(x)(0.125)
    return r, noise_f, noise_g, chord_coef


@wp.func
def cat_node_f(table: wp.array2d(dtype=Any), k: int, x: Any, y: Any):
    """F = hx y - hy x - c at node k at the local point (x, y), from the scan table."""
    return table[k, 1] * y - table[k, 2] * x - table[k, 3]


@wp.func
def cat_node_values(table: wp.array2d(dtype=Any), k: int, x: Any, y: Any):
    """omega, F (``cat_node_f``) and dF/domega = dhx y - dhy x - dc at node k."""
    return table[k, 0], cat_node_f(table, k, x, y), table[k, 4] * y - table[k, 5] * x - table[k, 6]


@wp.func
def cat_flagged(f_prev: Any, f_k: Any, width: Any, chord_coef: Any, noise_f: Any):
    """The scan's cheap test of a node interval (F at its ends, its width): a sign change, or an
    end within the chord bound M2 w^2 / 8 of zero (``cat_interval``); the rest hold no root."""
    return (f_k >= type(f_k)(0.0)) != (f_prev >= type(f_k)(0.0)) or wp.min(wp.abs(f_prev), wp.abs(f_k)) <= (
        chord_coef * width * width + noise_f
    )


@wp.func
def cat_node_interval(x: Any, y: Any, p: Any, k: int, r: Any, noise_f: Any, noise_g: Any, carry: Any,
                      lw: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    """The density of the roots in the node interval [k - 1, k] that a scan flagged
    (``cat_flagged``; 0 where both ends' accelerations are beyond PRUNE_SIGMAS on one side):
    settled by ``cat_interval``, or split by ``cat_split``. ``p``: the parameters (``CAT``)."""
    if cat_negligible(p.table, k, x, y, type(x)(PRUNE_SIGMAS) * p.sigma_a):
        return type(x)(0.0)
    w_prev, f_prev, g_prev = cat_node_values(p.table, k - 1, x, y)
    w_k, f_k, g_k = cat_node_values(p.table, k, x, y)
    part, settled = cat_interval(x, y, w_prev, w_k, f_prev, g_prev, f_k, g_k, p.v0, p.t, p.sigma_a, p.sigma_omega,
                                 p.tol, r, noise_f, noise_g, False, carry, lw, out)
    if settled:
        return part
    return cat_split(x, y, w_prev, w_k, f_prev, g_prev, f_k, g_k, p.v0, p.t, p.sigma_a, p.sigma_omega, p.tol, r,
                     noise_f, noise_g, carry, lw, out)


@wp.func
def cat_scan(x: Any, y: Any, p: Any, carry: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    """Exact CAT density at a point of the local frame: scan the table node by node, refine every
    root of each flagged interval (``cat_node_interval``), each root's path weighted into ``out``
    by ``cat_carry_root`` where ``carry`` is evidence (the integer 0 and any rows: none)."""
    density = type(x)(0.0)
    r, noise_f, noise_g, chord_coef = cat_scan_noise(x, y, p.v0, p.t, p.eps)
    w_prev = p.table[0, 0]
    f_prev = cat_node_f(p.table, 0, x, y)
    for k in range(1, p.table.shape[0]):
        w_k = p.table[k, 0]
        f_k = cat_node_f(p.table, k, x, y)
        if cat_flagged(f_prev, f_k, w_k - w_prev, chord_coef, noise_f):
            density += cat_node_interval(x, y, p, k, r, noise_f, noise_g, carry, lw, out)
        w_prev = w_k
        f_prev = f_k
    return density


def cat_scan_functions(scan):
    """The density and carried ``@wp.func``s of a scan (``cat_scan``, or the lanes' in
    ``kernels/cat_lanes.py``), in the scan's module: ``density(x, y, p)`` per m^2 at the world
    point (x, y), the launch kernels' maths; ``carried(x, y, p, ev, lw, out)`` each channel of it
    weighted by the evidence along each root's path (``bananagrid.protocol.CarryingModel``),
    summed over the heading nodes ``p.poses`` (the model's pose turned by theta_0; one node of
    weight 1 without heading noise) with weights ``p.weights``."""

    def density(x: Any, y: Any, p: Any):
        lx, ly = world_to_local(x, y, p.pose)
        # no evidence: the integer 0 selects the no-op ``cat_carry_root``; a table row stands in
        # for the unused scratch and channel rows
        return scan(lx, ly, p, int(0), p.table[0], p.table[0])

    def carried(x: Any, y: Any, p: Any, ev: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any)):
        carry = p.carry
        carry.ev = ev
        for i in range(p.weights.shape[0]):
            carry.pose = p.poses[i]
            carry.scale = p.weights[i]
            lx, ly = world_to_local(x, y, carry.pose)
            scan(lx, ly, p, carry, lw, out)

    return (wp.func(density, name=f"{scan.key}_density", module=scan.module),
            wp.func(carried, name=f"{scan.key}_carried", module=scan.module))


@wp.kernel
def cat_table(omegas: wp.array(dtype=Any), v0: Any, t: Any, table: wp.array2d(dtype=Any)):
    """Fill the scan table: one row per turn-rate node (columns: ``TABLE_COLUMNS``)."""
    k = wp.tid()
    w = omegas[k]
    a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn, ddc_fn, ddd_fn, dddc_fn, dddd_fn = cat_basis_curved(w * t)
    fx, fy, hx, hy, dhx, dhy, h2, c, dc = cat_line_terms(a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn, v0, t)
    # the acceleration of the line through P: a = h . (P - v0 f) / |h|^2 = ax x + ay y - a0
    row = wp.vector(w, hx, hy, c, dhx, dhy, dc, hx / h2, hy / h2, v0 * (hx * fx + hy * fy) / h2)
    for column in range(TABLE_COLUMNS):
        table[k, column] = row[column]


for _scalar in SCALARS:
    overload_on_use(cat_table, _scalar, {"omegas": wp.array(dtype=_scalar), "v0": _scalar, "t": _scalar,
                                         "table": wp.array2d(dtype=_scalar)})

#: The parameters: the scan table (``cat_table``), the model's, its pose, Newton's tolerance,
#: the dtype's machine epsilon (for the rounding allowances).
CAT = Params("CatParams", __name__, table=ARRAY2D, v0=SCALAR, t=SCALAR, sigma_a=SCALAR, sigma_omega=SCALAR, pose=VEC4,
             tol=SCALAR, eps=SCALAR)
#: The carried kernel's parameters: the scan's, the carry struct (its ``ev`` set by the kernel)
#: and the heading nodes (poses and weights).
CAT_CARRIED = Params("CatCarriedParams", __name__, **CAT.fields, carry=lambda scalar: CAT_CARRY.of(scalar),
                     poses=lambda scalar: wp.array(dtype=wp.types.vector(4, scalar)), weights=ARRAY)
cat_density, cat_carried = cat_scan_functions(cat_scan)
KERNELS = density_kernels(cat_density, CAT, "cat")
CARRIED_POINTS = carried_points_kernel(cat_carried, CAT_CARRIED, EVIDENCE, "cat")
