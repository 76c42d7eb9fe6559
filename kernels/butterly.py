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

Grids. ``butterly_grid`` (a whole row per thread on the CPU) computes the same rule faster:

* Skipping. exp(E) <= exp(-d^2 / 2) with d a lower bound of the whitened distance to the ring
  (:func:`log_bound`, no exp), so each speed's term is bounded before any work. A cell whose
  bound (all speeds) is below LOG_CELL_FLOOR is set to 0, and a speed whose bound is below
  LOG_SPEED_FLOOR is left out of a cell; the host sets them from a lower bound of the density's
  maximum M (1e-13 M, and 1e-22 M over the number of speeds: a relative 1e-10 at most wherever
  the density exceeds 1e-12 M). ``butterly_points`` skips only what would underflow.
* Row recurrence (:func:`row_runs`, rules of up to RECURRENCE_NODES nodes, i.e. r / sigma_min
  up to a few tens): along a row z moves by a constant dz, so each node's term is carried
  from cell to cell by one multiplication (a Gaussian recurrence: T_k g_k^m, times
  H^(m (m - 1) / 2) per cell) instead of an exp, restarted exactly every run of up to
  RUN_CELLS cells (fewer where cells are coarse), and only the nodes that can reach ``stop``
  of the largest term within the run are carried.
* Otherwise each cell walks from its peak as above, Newton starting from the root of the
  neighbouring cell (the speeds are the outer loop).
"""

from typing import Any

import warp as wp

#: Layout of the parameter array: a head, then PER_SPEED values for each travelled range.
(
    MEAN_X, MEAN_Y, Q1_X, Q1_Y, INV_SQRT_S1, INV_SQRT_S2, KAPPA, COS_THETA0, SIN_THETA0, LOG_TOL, STOP,
    NEWTON_TOL, LOG_STOP, LOG_TINY, LOG_CELL_FLOOR, LOG_SPEED_FLOOR, LOG_POINT_FLOOR, RUN_CELLS, RUN_SPREAD,
    RUN_SAFE, RUN_DROP,
) = range(21)
HEAD = 21
#: Per speed: rho1 = r / sqrt(S1), rho2 = r / sqrt(S2), 4F = rho1^2 - rho2^2,
#: log(weight / (4 pi^2 sqrt(S1 S2) ive(0, kappa))) and log(weight / (2 pi sqrt(S1 S2))), the
#: log of the peak of the weighted start density (see :func:`log_bound`).
RHO1, RHO2, FOUR_F, LOG_COEF, LOG_BOUND = range(5)
PER_SPEED = 5

#: Smallest node count of the periodic rule (covers small A, see node_count).
MIN_NODES = 12
#: Exact cos/sin of the walk's offset every this many steps (bounds the recurrence's drift).
REANCHOR = 64
#: Newton iterations of the secular equations (they converge in a handful).
MAX_NEWTON = 60
TWO_PI = 6.283185307179586
#: The grid kernel's row recurrence (:func:`row_runs`) is used for rule sizes up to this; larger
#: ones (r / sigma_min beyond a few hundred) walk from the peak.
RECURRENCE_NODES = 512
#: Scratch values per band of rows: rho1 cos, rho2 sin and the course term at each node, and
#: the recurrence's T and g (4 slots of padding each).
SCRATCH = 5 * RECURRENCE_NODES + 8
#: Shortest run of cells worth a restart of the recurrence (2N exps); shorter runs walk.
MIN_RUN = 4
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
def global_peak(a: Any, b: Any, four_f: Any, eps: Any, mu_start: Any):
    """(cos theta*, sin theta*, mu) of the global maximum of a cos + b sin - F cos 2 theta.

    On the unit circle (x, y) it maximises a x + b y - 2F x^2; the Lagrange condition gives
    x = a / (mu + 4F), y = b / mu with h(mu) = x^2 + y^2 = 1, and the global maximum is the
    root with mu > 0 (mu >= the largest eigenvalue of the objective's Hessian, 0). 1/sqrt(h) is
    concave and increasing there, so Newton from mu_L = max(|b|, |a| - 4F) (where h >= 1)
    climbs monotonically to the root. A start ``mu_start`` above mu_L (the root of the
    neighbouring cell) is used as is: from above the root one Newton step lands at or below it
    (concavity: the tangent lies above the curve), and clamping at mu_L keeps it in the
    concave range, from where the climb is monotone again. ``mu`` is returned for the next
    cell (0 where there is no Newton: F = 0 or b = 0).
    """
    zero = type(a)(0.0)
    one = type(a)(1.0)
    if four_f <= zero:
        m = wp.sqrt(a * a + b * b)
        if m > zero:
            return a / m, b / m, zero
        return one, zero, zero
    if b == zero:
        if wp.abs(a) >= four_f:
            return wp.sign(a), zero, zero
        x = a / four_f
        return x, wp.sqrt(wp.max(zero, one - x * x)), zero
    mu_low = wp.max(wp.abs(b), wp.abs(a) - four_f)
    mu = wp.max(mu_low, mu_start)
    for _ in range(MAX_NEWTON):
        p = mu + four_f
        ta = a / p
        tb = b / mu
        h = ta * ta + tb * tb
        s = one / wp.sqrt(h)
        slope = s * s * s * (ta * ta / p + tb * tb / mu)
        mu_next = wp.max(mu + (one - s) / slope, mu_low)
        step = mu_next - mu
        mu = mu_next
        if wp.abs(step) <= eps * mu:
            break
    x = a / (mu + four_f)
    y = b / mu
    n = wp.sqrt(x * x + y * y)
    return x / n, y / n, mu


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
    ca = wp.cbrt(a * a)  # |a|^(2/3)
    cb = wp.cbrt(b * b)
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
    anchor = int(REANCHOR)
    while plus + minus > 0:
        k = k + 1
        anchor = anchor - 1
        if anchor == 0:
            anchor = int(REANCHOR)
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
def speed_density(z1: Any, z2: Any, params: wp.array(dtype=Any), base: int, mu_start: Any):
    """(w_i P_{r_i}(u), mu) for the speed whose constants start at ``params[base]``; ``mu_start``
    and ``mu`` are the secular equation's multiplier at the previous and this point (see
    :func:`global_peak`; 0 for a cold start)."""
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
    x, y, mu = global_peak(a, b, four_f, params[NEWTON_TOL], mu_start)
    e1, c1, c2, p11, p12, p22 = anchor_exponent(z1, z2, rho1, rho2, kappa, c0, s0, x, y)
    if params[base + LOG_COEF] + e1 < params[LOG_TINY]:
        return zero, mu  # below the smallest positive number even if all N terms were 1 (Delta N = 2 pi)
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
        return zero, mu
    return delta * total * wp.exp(params[base + LOG_COEF] + e1), mu


@wp.func
def log_bound(z1: Any, z2: Any, z_norm: Any, params: wp.array(dtype=Any), base: int):
    """An upper bound of log(w_i P_{r_i}(u)) that costs no exp: LOG_BOUND - d^2 / 2.

    exp(E(theta)) <= exp(-|z - ring(theta)|^2 / 2) exp(kappa (cos - 1)), so P_r <= (peak of
    the start density) exp(-d^2 / 2) with d any lower bound of the whitened distance from z
    to the ring, the ellipse (rho1 cos, rho2 sin) (rho1 >= rho2). It lies in the annulus
    rho2 <= |p| <= rho1, and g(z) = |(z1 / rho1, z2 / rho2)| is 1 on it with Lipschitz
    constant 1 / rho2, so d >= max(|z| - rho1, rho2 - |z|, rho2 |g(z) - 1|, 0) (d = |z| for r = 0).
    """
    zero = type(z1)(0.0)
    rho1 = params[base + RHO1]
    rho2 = params[base + RHO2]
    d = wp.max(zero, wp.max(z_norm - rho1, rho2 - z_norm))
    if rho2 > zero:
        g1 = z1 / rho1
        g2 = z2 / rho2
        d = wp.max(d, rho2 * wp.abs(wp.sqrt(g1 * g1 + g2 * g2) - type(z1)(1.0)))
    return params[base + LOG_BOUND] - type(z1)(0.5) * d * d


@wp.func
def whiten(x: Any, y: Any, params: wp.array(dtype=Any)):
    """The whitened coordinates (z1, z2) of the world point (x, y)."""
    dx = x - params[MEAN_X]
    dy = y - params[MEAN_Y]
    q1x = params[Q1_X]
    q1y = params[Q1_Y]
    return (dx * q1x + dy * q1y) * params[INV_SQRT_S1], (dy * q1x - dx * q1y) * params[INV_SQRT_S2]


@wp.func
def butterly_density(x: Any, y: Any, params: wp.array(dtype=Any), n_speeds: int):
    """Density per m^2 at the world point (x, y): sum over speeds of w_i P_{r_i}(x, y), each
    from a cold start, a speed skipped only where its bound is below LOG_POINT_FLOOR (its value
    would underflow to 0)."""
    z1, z2 = whiten(x, y, params)
    z_norm = wp.sqrt(z1 * z1 + z2 * z2)
    total = type(x)(0.0)
    floor = params[LOG_POINT_FLOOR]
    for i in range(n_speeds):
        base = HEAD + PER_SPEED * i
        if log_bound(z1, z2, z_norm, params, base) >= floor:
            value, mu = speed_density(z1, z2, params, base, type(x)(0.0))
            total = total + value
    return total


@wp.func
def rule_size(z1: Any, z2: Any, params: wp.array(dtype=Any), base: int):
    """The amplitude A = |(a, b)| + 4F at the whitened point z for one speed."""
    a = params[base + RHO1] * z1 + params[KAPPA] * params[COS_THETA0]
    b = params[base + RHO2] * z2 + params[KAPPA] * params[SIN_THETA0]
    return wp.sqrt(a * a + b * b) + params[base + FOUR_F]


@wp.func
def live_cell(xs: wp.array(dtype=Any), y: Any, row: int, j: int, params: wp.array(dtype=Any), base: int,
              out: wp.array2d(dtype=Any)):
    """1 where cell j of the row is computed and this speed's bound reaches LOG_SPEED_FLOOR."""
    if out[row, j] < type(y)(0.0):
        return int(0)
    z1, z2 = whiten(xs[j], y, params)
    if log_bound(z1, z2, wp.sqrt(z1 * z1 + z2 * z2), params, base) >= params[LOG_SPEED_FLOOR]:
        return int(1)
    return int(0)


@wp.func
def row_runs(
    xs: wp.array(dtype=Any), y: Any, row: int, j_begin: int, j_end: int, params: wp.array(dtype=Any),
    base: int, n: int, scratch: wp.array2d(dtype=Any), band: int, out: wp.array2d(dtype=Any),
):
    """Add w_i P_{r_i} to the live cells j_begin..j_end-1 of a row by the full periodic rule,
    its terms carried from cell to cell by a Gaussian recurrence instead of exps.

    Along a row the whitened point moves by a constant dz per cell, so each node's exponent
    E_k(j) = -|z(j) - rho_k|^2 / 2 + kappa (cos(theta_k - theta0) - 1) is quadratic in j:

        T_k(j + 1) = T_k(j) G_k(j),   G_k(j + 1) = G_k(j) H,   H = exp(-|dz|^2),

    with T_k = exp(E_k - ref) and G_k = exp(E_k(j + 1) - E_k(j)). The row is cut into runs of
    at most RUN_CELLS cells over which no exponent moves by more than RUN_SPREAD (|E_k(j + m) -
    E_k(j)| <= m |dz| (|z| + rho1) + m^2 |dz|^2), restarted exactly (2N exps) at each run's
    first cell with ref = max_k E_k there: nothing overflows, and a term that underflows at the
    restart stays below exp(RUN_SPREAD - 708) while the largest stays above exp(-RUN_SPREAD).
    Each step multiplies rounding errors of about m eps into T (m^2 eps / 2 over a run: 9e-13 at
    128 cells in float64). Only the nodes that can reach stop / N of the largest term somewhere in
    the run are carried (the truncation of :func:`walk`); the run's sum is that of the carried
    T_k g_k^m times H^(m (m - 1) / 2). ``n`` (a multiple of 32, or of 4 below 128) is the rule for the
    largest amplitude on the row's live span (|(a, b)| is convex along the row, so at one of
    its ends); a run whose own amplitude needs at most n / 2, n / 4 or n / 8 nodes takes every
    2nd, 4th or 8th node, the rule of that size (never fewer nodes than node_count asks for).
    Runs shorter than MIN_RUN (coarse cells far out) walk from the peak instead
    (:func:`speed_density`), and runs with no live cell are skipped.
    """
    zero = type(y)(0.0)
    one = type(y)(1.0)
    half = type(y)(0.5)
    rho1 = params[base + RHO1]
    rho2 = params[base + RHO2]
    kappa = params[KAPPA]
    c0 = params[COS_THETA0]
    s0 = params[SIN_THETA0]
    log_coef = params[base + LOG_COEF]
    log_tol = params[LOG_TOL]
    spread = params[RUN_SPREAD]
    run_cells = int(params[RUN_CELLS])
    delta = type(y)(TWO_PI) / type(y)(n)
    offset_c = RECURRENCE_NODES
    offset_k = 2 * RECURRENCE_NODES
    offset_t = 3 * RECURRENCE_NODES
    offset_g = 4 * RECURRENCE_NODES + 4
    for k in range(n):
        angle = type(y)(k) * delta
        ck = wp.cos(angle)
        sk = wp.sin(angle)
        scratch[band, k] = rho1 * ck
        scratch[band, offset_c + k] = rho2 * sk
        scratch[band, offset_k + k] = kappa * (ck * c0 + sk * s0 - one)
    z1_next, z2_next = whiten(xs[j_begin + 1], y, params)
    z1_first, z2_first = whiten(xs[j_begin], y, params)
    dz1 = z1_next - z1_first
    dz2 = z2_next - z2_first
    dz_sq = dz1 * dz1 + dz2 * dz2
    dz_norm = wp.sqrt(dz_sq)
    h = wp.exp(-dz_sq)
    mu = type(y)(0.0)
    j = int(j_begin)
    while j < j_end:
        z1, z2 = whiten(xs[j], y, params)
        z_norm = wp.sqrt(z1 * z1 + z2 * z2)
        # longest run with L |dz| (|z| + rho1) + L^2 |dz|^2 <= spread
        reach = dz_norm * (z_norm + rho1)
        length = run_cells
        if dz_sq > zero:
            root = type(y)(2.0) * spread / (reach + wp.sqrt(reach * reach + type(y)(4.0) * dz_sq * spread))
            if root < type(y)(run_cells):
                length = int(root)
        length = wp.max(1, wp.min(length, j_end - j))
        live = int(0)
        for m in range(length):
            if live_cell(xs, y, row, j + m, params, base, out) == 1:
                live = int(1)
                break
        if live == 1 and length < MIN_RUN:
            for m in range(length):
                if live_cell(xs, y, row, j + m, params, base, out) == 1:
                    zm1, zm2 = whiten(xs[j + m], y, params)
                    value, mu_next = speed_density(zm1, zm2, params, base, mu)
                    mu = mu_next
                    out[row, j + m] = out[row, j + m] + value
        elif live == 1:
            # this run's own rule: every stride-th node of the row's
            ze1, ze2 = whiten(xs[j + length - 1], y, params)
            need = node_count(wp.max(rule_size(z1, z2, params, base), rule_size(ze1, ze2, params, base)), log_tol)
            stride = int(1)
            if n % 32 == 0:
                while stride < 8 and need * stride * 2 <= n:
                    stride = stride * 2
            ref = type(y)(-1.0e30)
            d_ref = zero
            for k in range(0, n, stride):
                r1 = z1 - scratch[band, k]
                r2 = z2 - scratch[band, offset_c + k]
                e = scratch[band, offset_k + k] - half * (r1 * r1 + r2 * r2)
                if e > ref:
                    ref = e
                    d_ref = -(r1 * dz1 + r2 * dz2) - half * dz_sq
            # Keep the nodes that can matter anywhere in the run. Over m <= L cells a node's
            # exponent rises by at most L max(D_k, 0) (E_k(j + m) - E_k(j) = m D_k - m (m - 1)
            # |dz|^2 / 2), and the largest term falls by at most L max(-D_ref, 0) + L^2 |dz|^2 / 2,
            # so a dropped node stays below stop / N of the largest term at every cell of the run.
            span = type(y)(length)
            allowance = params[RUN_DROP] + span * wp.max(-d_ref, zero) + half * span * span * dz_sq
            kept = int(0)
            for k in range(0, n, stride):
                r1 = z1 - scratch[band, k]
                r2 = z2 - scratch[band, offset_c + k]
                e = scratch[band, offset_k + k] - half * (r1 * r1 + r2 * r2) - ref
                d = -(r1 * dz1 + r2 * dz2) - half * dz_sq
                if e + span * wp.max(d, zero) + allowance >= zero:
                    scratch[band, offset_t + kept] = wp.exp(e)
                    scratch[band, offset_g + kept] = wp.exp(d)
                    kept = kept + 1
            while kept % 4 != 0:  # pad to whole groups of four with zero terms
                scratch[band, offset_t + kept] = zero
                scratch[band, offset_g + kept] = one
                kept = kept + 1
            log_scale = log_coef + ref
            safe = wp.abs(log_scale) < params[RUN_SAFE]
            weight = delta * type(y)(stride)
            scale = wp.exp(wp.min(log_scale, params[RUN_SAFE])) * weight
            quad = one  # H^(m (m - 1) / 2)
            power = one  # H^m
            for m in range(length):
                # T_k(j + m) = T_k(j) g_k^m H^(m (m - 1) / 2): carry T g^m, four independent sums
                s_a = type(y)(0.0)
                s_b = type(y)(0.0)
                s_c = type(y)(0.0)
                s_d = type(y)(0.0)
                for c in range(0, kept, 4):
                    ka = offset_t + c
                    ta = scratch[band, ka]
                    tb = scratch[band, ka + 1]
                    tc = scratch[band, ka + 2]
                    td = scratch[band, ka + 3]
                    s_a = s_a + ta
                    s_b = s_b + tb
                    s_c = s_c + tc
                    s_d = s_d + td
                    kg = offset_g + c
                    ga = scratch[band, kg]  # all loads before the stores (same array: no reordering)
                    gb = scratch[band, kg + 1]
                    gc = scratch[band, kg + 2]
                    gd = scratch[band, kg + 3]
                    scratch[band, ka] = ta * ga
                    scratch[band, ka + 1] = tb * gb
                    scratch[band, ka + 2] = tc * gc
                    scratch[band, ka + 3] = td * gd
                total = ((s_a + s_b) + (s_c + s_d)) * quad
                quad = quad * power
                power = power * h
                if out[row, j + m] >= zero:  # (inside the span a cell below the speed floor costs nothing extra)
                    if safe:
                        out[row, j + m] = out[row, j + m] + scale * total
                    else:  # exp(ref) alone under- or overflows: combine in logs
                        out[row, j + m] = out[row, j + m] + weight * wp.exp(log_scale + wp.log(total))
        j = j + length


@wp.kernel
def butterly_grid(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    columns: int,
    params: wp.array(dtype=Any),
    n_speeds: int,
    scratch: wp.array2d(dtype=Any),
    band: int,
    out: wp.array2d(dtype=Any),
):
    """Density at the cell centres of a band of rows, ``columns`` cells per thread (a whole row
    on the CPU, one cell on a GPU); ``scratch[band]`` is this band's work space (a whole row's
    thread uses it, so a band's rows run one after another, as on the CPU).

    A cell is set to 0 without computing anything where the sum of the speeds' bounds
    (:func:`log_bound`; n times the largest) is below LOG_CELL_FLOOR, and a speed is skipped at
    a cell where its own bound is below LOG_SPEED_FLOOR (the floors are set on the host from a
    lower bound of the density's maximum; see ``Butterly.kernel_parameters``). The speeds are
    the outer loop: a row of at least 2 * MIN_RUN cells whose rule has at most RECURRENCE_NODES
    nodes goes through :func:`row_runs`, and otherwise each cell walks from its peak, Newton
    starting from the neighbouring cell's root. ``out`` holds -1 for skipped cells until the
    last pass.
    """
    i, block = wp.tid()
    row = row0 + i
    y = ys[row]
    zero = type(y)(0.0)
    j_begin = block * columns
    j_end = wp.min((block + 1) * columns, xs.shape[0])
    cell_floor = params[LOG_CELL_FLOOR] - wp.log(type(y)(n_speeds))
    speed_floor = params[LOG_SPEED_FLOOR]
    for j in range(j_begin, j_end):
        z1, z2 = whiten(xs[j], y, params)
        z_norm = wp.sqrt(z1 * z1 + z2 * z2)
        mark = type(y)(-1.0)
        for s in range(n_speeds):
            if log_bound(z1, z2, z_norm, params, HEAD + PER_SPEED * s) >= cell_floor:
                mark = zero
                break
        out[row, j] = mark
    for s in range(n_speeds):
        base = HEAD + PER_SPEED * s
        # the live span of the row for this speed: scan in from both ends
        first = int(j_begin)
        while first < j_end and live_cell(xs, y, row, first, params, base, out) == 0:
            first = first + 1
        last = int(j_end - 1)
        while last > first and live_cell(xs, y, row, last, params, base, out) == 0:
            last = last - 1
        n = int(MAX_NODES)
        if last - first + 1 >= 2 * MIN_RUN:
            za1, za2 = whiten(xs[first], y, params)
            zb1, zb2 = whiten(xs[last], y, params)
            amp = wp.max(rule_size(za1, za2, params, base), rule_size(zb1, zb2, params, base))
            n = node_count(amp, params[LOG_TOL])
            if n < 128:
                n = (n + 3) // 4 * 4
            else:
                n = (n + 31) // 32 * 32
        if first == j_end:
            n = int(0)  # nothing to add on this row
        elif n <= RECURRENCE_NODES:
            row_runs(xs, y, row, first, last + 1, params, base, n, scratch, band, out)
        else:
            mu = type(y)(0.0)
            for j in range(j_begin, j_end):
                if out[row, j] >= zero:
                    z1, z2 = whiten(xs[j], y, params)
                    z_norm = wp.sqrt(z1 * z1 + z2 * z2)
                    if log_bound(z1, z2, z_norm, params, base) >= speed_floor:
                        value, mu_next = speed_density(z1, z2, params, base, mu)
                        mu = mu_next
                        out[row, j] = out[row, j] + value
    for j in range(j_begin, j_end):
        if out[row, j] < zero:
            out[row, j] = zero


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
        wp.overload(butterly_grid, {**common, "scratch": wp.array2d(dtype=scalar), "out": wp.array2d(dtype=scalar)})
        wp.overload(butterly_points, {**common, "out": vec})


_register_overloads()
