"""Butterly's density: a bivariate normal start moved by r_i along a random course (Butterly
(3.1), (2.5); the course law is uniform or, beyond the paper, von Mises as in (2.3)).

For one travelled range r the density at a world point u is

    P_r(u) = int_0^{2 pi} N(u - r e(c); mu, Sigma) p(c) dc,      e(c) = (sin c, cos c),

with c the course as a bearing clockwise from north and p(c) = exp(kappa cos(c - c0)) /
(2 pi I0(kappa)) (kappa = 0: Butterly's uniform 1 / (2 pi)).

Frame. With Sigma = S1 q1 q1^T + S2 q2 q2^T (S1 <= S2, q2 = q1 rotated +90 deg) and the angle
theta = pi/2 - c - beta (beta the angle of q1 from east), q_k . e(c) = (cos theta, sin theta), and
in the whitened coordinates z = (q1 . (u - mu) / sqrt(S1), q2 . (u - mu) / sqrt(S2)) the exponent
of the integrand is (Butterly (3.6) and Appendix A, ERRATA's w')

    E(theta) = -1/2 |z - (rho1 cos theta, rho2 sin theta)|^2 + kappa (cos(theta - theta0) - 1)
             = const + a cos theta + b sin theta - F cos 2 theta,

    rho_k = r / sqrt(S_k),  a = rho1 z1 + kappa cos theta0,  b = rho2 z2 + kappa sin theta0,
    F = (rho1^2 - rho2^2) / 4 >= 0.

Quadrature. The integrand exp(E) is periodic and entire, so the N-point periodic trapezoid rule
converges geometrically: with A = |(a, b)| + 4 F >= max |E''| its relative error is at most
4 pi exp(min_y(A sinh(y)^2 / 2 - N y)) / sqrt(2 pi / A) (Fourier coefficients bounded on the
strip |Im theta| < y), and :func:`node_count` takes N = sqrt(2 A (L + ln(1 + A) / 2)) + 12,
L = ln(1 / tol) + ln(4 pi), which the tests check against that bound for A up to 1e10. The
rule's nodes are anchored at the global maximum theta* of E (the root mu > 0 of the secular
equation a^2 / (mu + 4F)^2 + b^2 / mu^2 = 1, by Newton on 1/sqrt(h) - 1, which is concave), and
only the nodes where exp(E - E*) > ``stop`` are evaluated: the walk goes outward from theta* on
both sides until the integrand falls below ``stop`` (it decreases monotonically up to the next
minimum). E has a second local maximum exactly when (|a|^(2/3) + |b|^(2/3))^(3/2) < 4F (inside
the astroid, the evolute of the whitened ring); then it is the root of the same equation on
(-4F, 0) where h increases, and the nodes around it are walked too. Every term is
exp(E - E*) <= 1, so nothing overflows or underflows before the final exp(E*): the density is
exact in relative terms far into the tails (until it underflows itself).

Each node costs one exp and a dozen multiply-adds: cos and sin of the offset delta = k Delta are
advanced by the rotation recurrence in the form (cos delta - 1, sin delta) (error proportional to
delta, not 1; recomputed exactly every 64 steps), and E - E* is the quadratic form

    E(theta* + delta) - E* = u C1 + v C2 - (P11 u^2 + 2 P12 u v + P22 v^2) / 2,
    u = cos delta - 1,  v = sin delta,

whose coefficients come from the residual at theta* (no cancellation of large exponents).
"""

from typing import Any

import warp as wp

#: Layout of the parameter array: a head, then PER_SPEED values for each travelled range.
MEAN_X, MEAN_Y, Q1_X, Q1_Y, INV_SQRT_S1, INV_SQRT_S2, KAPPA, COS_THETA0, SIN_THETA0, LOG_TOL, STOP, NEWTON_TOL, LOG_STOP, LOG_TINY = range(14)
HEAD = 14
#: Per speed: rho1 = r / sqrt(S1), rho2 = r / sqrt(S2), F = (rho1^2 - rho2^2) / 4 and
#: log(weight / (4 pi^2 sqrt(S1 S2) ive(0, kappa))).
RHO1, RHO2, FOUR_F, LOG_COEF = range(4)
PER_SPEED = 4

#: Smallest node count of the periodic rule (covers small A, see node_count).
MIN_NODES = 12
#: Exact cos/sin of the walk's offset every this many steps (bounds the recurrence's drift).
REANCHOR = 64
#: Newton iterations of the secular equations (they converge in a handful).
MAX_NEWTON = 60
TWO_PI = 6.283185307179586
TWO_THIRDS = 2.0 / 3.0
#: Largest node count: above it the int arithmetic of the walk could overflow (A > 1e17).
MAX_NODES = 1000000000


@wp.func
def node_count(amplitude: Any, log_tol: Any):
    """N of the periodic trapezoid rule for exp(E) with max |E''| <= ``amplitude`` (= A):
    sqrt(2 A (L + ln(1 + A) / 2)) + 12 with L = ``log_tol`` = ln(1 / tol) + ln(4 pi)."""
    half = type(amplitude)(0.5)
    n = wp.sqrt(type(amplitude)(2.0) * amplitude * (log_tol + half * wp.log(type(amplitude)(1.0) + amplitude)))
    n = wp.min(n + type(amplitude)(MIN_NODES), type(amplitude)(MAX_NODES))
    return int(wp.ceil(n))


@wp.func
def global_peak(a: Any, b: Any, four_f: Any, eps: Any):
    """(cos theta*, sin theta*) of the global maximum of a cos + b sin - F cos 2 theta.

    On the unit circle (x, y) it maximises a x + b y - 2F x^2; the Lagrange condition gives
    x = a / (mu + 4F), y = b / mu with h(mu) = x^2 + y^2 = 1, and the global maximum is the
    root with mu > 0 (mu >= the largest eigenvalue of the objective's Hessian, 0). 1/sqrt(h) is
    concave and increasing there, so Newton from mu_L = max(|b|, |a| - 4F) (where h >= 1)
    climbs monotonically to the root.
    """
    zero = type(a)(0.0)
    one = type(a)(1.0)
    if four_f <= zero:
        m = wp.sqrt(a * a + b * b)
        if m > zero:
            return a / m, b / m
        return one, zero
    if b == zero:
        if wp.abs(a) >= four_f:
            return wp.sign(a), zero
        x = a / four_f
        return x, wp.sqrt(wp.max(zero, one - x * x))
    mu = wp.max(wp.abs(b), wp.abs(a) - four_f)
    for _ in range(MAX_NEWTON):
        p = mu + four_f
        ta = a / p
        tb = b / mu
        h = ta * ta + tb * tb
        s = one / wp.sqrt(h)
        slope = s * s * s * (ta * ta / p + tb * tb / mu)
        step = (one - s) / slope
        mu = mu + step
        if wp.abs(step) <= eps * mu:
            break
    x = a / (mu + four_f)
    y = b / mu
    n = wp.sqrt(x * x + y * y)
    return x / n, y / n


@wp.func
def second_peak(a: Any, b: Any, four_f: Any, eps: Any, depth: Any):
    """The other local maximum of a cos + b sin - F cos 2 theta, if any, unless it is lower than
    the global one by more than ``depth`` for sure: (found, cos, sin).

    On the half circle sign(y) = -sign(b) the objective a x + b y - 2F x^2 is at most
    a^2 / (8F), and the global maximum is at least a^2 / (8F) + |b| sqrt(1 - (a / 4F)^2) (the
    point x = a / 4F on the other half), so a second maximum is skipped when that gap exceeds
    ``depth``. It exists iff (|a|^(2/3) + |b|^(2/3))^(3/2) < 4F; its multiplier mu lies in (mu_min, 0),
    where h is convex and increasing (mu_min = -4F |b|^(2/3) / (|a|^(2/3) + |b|^(2/3)) is h's
    minimum), so Newton on h - 1 from the right (h >= 1 at max(-|b|, mu_min / 2)) descends
    monotonically to it.
    """
    zero = type(a)(0.0)
    one = type(a)(1.0)
    if four_f <= zero or wp.abs(a) >= four_f or wp.abs(b) >= four_f:
        return int(0), one, zero
    if b == zero:
        x = a / four_f
        return int(1), x, -wp.sqrt(wp.max(zero, one - x * x))
    ratio = a / four_f
    if wp.abs(b) * wp.sqrt(one - ratio * ratio) > depth:
        return int(0), one, zero
    ca = wp.pow(wp.abs(a), type(a)(TWO_THIRDS))
    cb = wp.pow(wp.abs(b), type(a)(TWO_THIRDS))
    sum_c = ca + cb
    if sum_c * wp.sqrt(sum_c) >= four_f:
        return int(0), one, zero
    mu_min = -four_f * cb / sum_c
    mu = wp.max(-wp.abs(b), type(a)(0.5) * mu_min)
    for _ in range(MAX_NEWTON):
        p = mu + four_f
        ta = a / p
        tb = b / mu
        f = ta * ta + tb * tb - one
        slope = type(a)(-2.0) * (ta * ta / p + tb * tb / mu)
        if slope <= zero:
            break
        step = f / slope
        mu = mu - step
        if wp.abs(step) <= eps * four_f:
            break
    x = a / (mu + four_f)
    y = b / mu
    n = wp.sqrt(x * x + y * y)
    return int(1), x / n, y / n


@wp.func
def anchor_exponent(z1: Any, z2: Any, rho1: Any, rho2: Any, kappa: Any, c0: Any, s0: Any, x: Any, y: Any):
    """E at theta* = atan2(y, x) (without the constant) and the coefficients (C1, C2, P11, P12,
    P22) of E(theta* + delta) - E* in u = cos delta - 1, v = sin delta."""
    r1 = z1 - rho1 * x  # residual zeta* = z - (rho1 cos, rho2 sin)
    r2 = z2 - rho2 * y
    ax = rho1 * x  # d zeta / du = -(ax, ay), d zeta / dv = -(bx, by)
    ay = rho2 * y
    bx = -rho1 * y
    by = rho2 * x
    cos_rel = x * c0 + y * s0  # cos(theta* - theta0)
    sin_rel = y * c0 - x * s0
    e_star = type(z1)(-0.5) * (r1 * r1 + r2 * r2) + kappa * (cos_rel - type(z1)(1.0))
    c1 = r1 * ax + r2 * ay + kappa * cos_rel
    c2 = r1 * bx + r2 * by - kappa * sin_rel
    return e_star, c1, c2, ax * ax + ay * ay, ax * bx + ay * by, bx * bx + by * by


@wp.func
def walk(
    c1: Any, c2: Any, p11: Any, p12: Any, p22: Any, delta: Any, stop: Any,
    lim_plus: int, lim_minus: int, lim_total: int,
):
    """Sum of exp(E(theta* + k delta) - E*) over k = 0, +-1, +-2, ... outward on both sides until
    a term is below ``stop`` or a side reaches its limit (offsets +1..lim_plus, -1..-lim_minus,
    at most lim_total besides the anchor). Returns (sum, nodes taken on the + side, on the - side).
    """
    one = type(c1)(1.0)
    half = type(c1)(0.5)
    total = one
    alpha = type(c1)(-2.0) * wp.sin(half * delta) * wp.sin(half * delta)  # cos(delta) - 1
    beta = wp.sin(delta)
    u = type(c1)(0.0)
    v = type(c1)(0.0)
    plus = int(1)
    minus = int(1)
    if lim_plus <= 0:
        plus = int(0)
    if lim_minus <= 0:
        minus = int(0)
    p = int(0)
    m = int(0)
    k = int(0)
    while plus + minus > 0:
        k = k + 1
        if k % REANCHOR == 0:
            sk = wp.sin(half * type(c1)(k) * delta)
            u = type(c1)(-2.0) * sk * sk
            v = wp.sin(type(c1)(k) * delta)
        else:
            u_next = u + alpha * (one + u) - beta * v
            v = v + alpha * v + beta * (one + u)
            u = u_next
        even = u * (c1 - half * p11 * u) - half * p22 * v * v
        odd = v * (c2 - p12 * u)
        if plus == 1:
            if k > lim_plus or p + m >= lim_total:
                plus = int(0)
            else:
                term = wp.exp(even + odd)
                total = total + term
                p = k
                if term < stop:
                    plus = int(0)
        if minus == 1:
            if k > lim_minus or p + m >= lim_total:
                minus = int(0)
            else:
                term = wp.exp(even - odd)
                total = total + term
                m = k
                if term < stop:
                    minus = int(0)
    return total, p, m


@wp.func
def speed_density(z1: Any, z2: Any, params: wp.array(dtype=Any), base: int):
    """w_i P_{r_i}(u) for the speed whose constants start at ``params[base]``."""
    zero = type(z1)(0.0)
    rho1 = params[base + RHO1]
    rho2 = params[base + RHO2]
    four_f = params[base + FOUR_F]
    kappa = params[KAPPA]
    c0 = params[COS_THETA0]
    s0 = params[SIN_THETA0]
    stop = params[STOP]
    a = rho1 * z1 + kappa * c0
    b = rho2 * z2 + kappa * s0
    n = node_count(wp.sqrt(a * a + b * b) + four_f, params[LOG_TOL])
    delta = type(z1)(TWO_PI) / type(z1)(n)
    x, y = global_peak(a, b, four_f, params[NEWTON_TOL])
    e1, c1, c2, p11, p12, p22 = anchor_exponent(z1, z2, rho1, rho2, kappa, c0, s0, x, y)
    if params[base + LOG_COEF] + e1 < params[LOG_TINY]:
        return zero  # below the smallest positive number even if all N terms were 1 (Delta N = 2 pi)
    total, p1, m1 = walk(c1, c2, p11, p12, p22, delta, stop, n - 1, n - 1, n - 1)
    found, x2, y2 = second_peak(a, b, four_f, params[NEWTON_TOL], params[LOG_STOP])
    if found == 1 and p1 + m1 + 1 < n:
        # the node of the same periodic rule nearest to the second maximum
        offset = wp.atan2(x * y2 - y * x2, x * x2 + y * y2)
        j2 = int(wp.round(offset / delta))
        if j2 < 0:
            j2 = j2 + n
        if j2 > p1 and j2 < n - m1:
            angle = type(z1)(j2) * delta
            cj = wp.cos(angle)
            sj = wp.sin(angle)
            xa = x * cj - y * sj
            ya = y * cj + x * sj
            e2, d1, d2, q11, q12, q22 = anchor_exponent(z1, z2, rho1, rho2, kappa, c0, s0, xa, ya)
            scale = wp.exp(e2 - e1)
            if scale >= stop:
                lim_plus = n - m1 - 1 - j2
                lim_minus = j2 - p1 - 1
                extra, p2, m2 = walk(d1, d2, q11, q12, q22, delta, stop, lim_plus, lim_minus, lim_plus + lim_minus)
                total = total + scale * extra
    if total <= zero:
        return zero
    return delta * total * wp.exp(params[base + LOG_COEF] + e1)


@wp.func
def butterly_density(x: Any, y: Any, params: wp.array(dtype=Any), n_speeds: int):
    """Density per m^2 at the world point (x, y): sum over speeds of w_i P_{r_i}(x, y)."""
    dx = x - params[MEAN_X]
    dy = y - params[MEAN_Y]
    q1x = params[Q1_X]
    q1y = params[Q1_Y]
    z1 = (dx * q1x + dy * q1y) * params[INV_SQRT_S1]
    z2 = (dy * q1x - dx * q1y) * params[INV_SQRT_S2]
    total = type(x)(0.0)
    for i in range(n_speeds):
        total = total + speed_density(z1, z2, params, HEAD + PER_SPEED * i)
    return total


@wp.kernel
def butterly_grid(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    columns: int,
    params: wp.array(dtype=Any),
    n_speeds: int,
    out: wp.array2d(dtype=Any),
):
    """Density at the cell centres of a band of rows, ``columns`` cells per thread (a whole row
    on the CPU, one cell on a GPU)."""
    i, block = wp.tid()
    row = row0 + i
    y = ys[row]
    j_end = wp.min((block + 1) * columns, xs.shape[0])
    for j in range(block * columns, j_end):
        out[row, j] = butterly_density(xs[j], y, params, n_speeds)


@wp.kernel
def butterly_points(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    start: int,
    params: wp.array(dtype=Any),
    n_speeds: int,
    out: wp.array(dtype=Any),
):
    """Density at arbitrary world points (xs[k], ys[k]) for k in a chunk starting at ``start``."""
    k = start + wp.tid()
    out[k] = butterly_density(xs[k], ys[k], params, n_speeds)


def _register_overloads():
    for scalar in (wp.float32, wp.float64):
        vec = wp.array(dtype=scalar)
        common = {"xs": vec, "ys": vec, "params": vec}
        wp.overload(butterly_grid, {**common, "out": wp.array2d(dtype=scalar)})
        wp.overload(butterly_points, {**common, "out": vec})


_register_overloads()
