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
rule's nodes are anchored at the global maximum theta* of E (:func:`global_peak`), and only the
nodes where exp(E - E*) > ``stop`` are evaluated: the walk goes outward from theta* on both
sides until the integrand falls below ``stop`` (it decreases monotonically up to the next
minimum). Where E has a second local maximum (:func:`second_peak`: inside the astroid, the
evolute of the whitened ring) the nodes around it are walked too. Every term is exp(E - E*) <= 1,
so nothing overflows or underflows before the final exp(E*): the density is exact in relative
terms far into the tails (until it underflows itself).

Each node costs one exp and a dozen multiply-adds: cos and sin of the offset delta = k Delta are
advanced by the rotation recurrence in the form (cos delta - 1, sin delta) (error proportional to
delta, not 1; recomputed exactly every 64 steps), and E - E* is the quadratic form

    E(theta* + delta) - E* = u C1 + v C2 - (P11 u^2 + 2 P12 u v + P22 v^2) / 2,
    u = cos delta - 1,  v = sin delta,

whose coefficients come from the residual at theta* (no cancellation of large exponents).

Grids: ``butterly_grid`` computes the same rule faster, skipping what its bounds prove
negligible (:func:`log_bound`) and summing tiles of cells as a matrix product (:func:`tile_speed`).

Carried evidence (the section at the end, ``CARRIED_KERNELS``; the rule and its error in
``bananagrid.models.butterly.Butterly.bind_carried``): evidence at earlier times weighs each
course's path inside the same integral, through the shared helpers of ``kernels/evidence.py``,
at points only (a tile's matrix product has no place for a weight per node and cell).
"""

from typing import Any

import warp as wp

from . import evidence as ek
from .generate import ARRAY, ARRAY2D, SCALAR, SCALARS, Params, carried_points_kernel, density_kernels, overload_on_use

# No adjoints: nothing differentiates these kernels, and the backward kernels Warp would
# generate for every launch kernel are most of a module's code (the CAT module's CUDA build:
# see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False})

#: Layout of the parameter array: a head, then PER_SPEED values for each travelled range.
(
    MEAN_X, MEAN_Y, Q1_X, Q1_Y, INV_SQRT_S1, INV_SQRT_S2, KAPPA, COS_THETA0, SIN_THETA0, LOG_TOL, STOP,
    NEWTON_TOL, LOG_STOP, LOG_TINY, LOG_CELL_FLOOR, LOG_SPEED_FLOOR, LOG_POINT_FLOOR, LOG_HUGE, LOG_SMALL,
    TILE_DROP,
) = range(20)
HEAD = 20
#: Per speed: rho1 = r / sqrt(S1), rho2 = r / sqrt(S2), 4F = rho1^2 - rho2^2,
#: log(weight / (4 pi^2 sqrt(S1 S2) ive(0, kappa))) and log(weight / (2 pi sqrt(S1 S2))), the
#: log of the peak of the weighted start density (see :func:`log_bound`).
RHO1, RHO2, FOUR_F, LOG_COEF, LOG_BOUND = range(5)
PER_SPEED = 5

#: Smallest node count of the periodic rule (covers small A, see node_count).
MIN_NODES = 12
#: Exact cos/sin of the walk's offset every this many steps (bounds the rotation's drift).
REANCHOR = 64
#: Newton iterations of the secular equations (they converge in a handful).
MAX_NEWTON = 60
TWO_PI = 6.283185307179586
PI = 3.141592653589793
#: Side of the grid kernel's tiles (cells); a CPU thread takes a strip of TILE rows.
TILE = 32
#: vec4 per node and axis in a tile's factor tables.
QUADS = TILE // 4
#: Largest rule the tile product takes; larger ones (r / sigma_min beyond a few hundred) walk.
TILE_NODES = 2048
#: Smallest block of cells worth a tile (a GPU thread's single cell walks).
MIN_TILE_CELLS = 16
#: Scalar scratch per band: the nodes' exponents and slopes (TILE_NODES each), cos and sin of
#: the first 16 node angles, and the strip's cross factor (TILE x TILE).
NODE_E = 0
NODE_X = TILE_NODES
NODE_Y = 2 * TILE_NODES
NODE_TRIG = 3 * TILE_NODES
CROSS = 3 * TILE_NODES + 32
SCRATCH = CROSS + TILE * TILE
#: vec4 scratch per band: the kept nodes' column factors A, then their row factors B.
QUAD_A = 0
QUAD_B = TILE_NODES * QUADS
QUAD_SCRATCH = 2 * TILE_NODES * QUADS
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
    monotonically to it. Newton stops at a step below ``eps`` of |mu| (relative: near the
    astroid's cusps on the a axis, |b| << F, the two maxima are mirror images a hair apart with
    |mu| ~ |b|, and a step tolerance on the scale of F stopped at the start, far from the
    peak, which was then lost: half the density). Where b^2 underflows, the peak is b = 0's.
    """
    zero = type(a)(0.0)
    one = type(a)(1.0)
    if four_f <= zero or wp.abs(a) >= four_f or wp.abs(b) >= four_f:
        return int(0), one, zero
    bb = b * b
    if bb == zero:  # b = 0 (or b^2 underflows: the same peak to far below a node's spacing)
        x = a / four_f
        y = -wp.sqrt(wp.max(zero, one - x * x))
        if b >= zero:  # on the half circle opposite to the global maximum's (+ for b = 0)
            return int(1), x, y
        return int(1), x, -y
    ratio = a / four_f
    if wp.abs(b) * wp.sqrt(one - ratio * ratio) > depth:
        return int(0), one, zero
    ca = wp.cbrt(a * a)  # |a|^(2/3)
    cb = wp.cbrt(bb)
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
        if wp.abs(step) <= eps * wp.abs(mu):
            break
    x = a / (mu + four_f)
    y = b / mu
    n = wp.sqrt(x * x + y * y)
    return int(1), x / n, y / n


@wp.func
def anchor_exponent(z1: Any, z2: Any, params: wp.array(dtype=Any), base: int, x: Any, y: Any):
    """E at theta* = atan2(y, x) (without the constant) and the coefficients (C1, C2, P11, P12,
    P22) of E(theta* + delta) - E* in u = cos delta - 1, v = sin delta."""
    rho1 = params[base + RHO1]
    rho2 = params[base + RHO2]
    kappa = params[KAPPA]
    c0 = params[COS_THETA0]
    s0 = params[SIN_THETA0]
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
def walk_side(going: int, k: int, lim: int, full: bool, exponent: Any, total: Any, stop: Any, last: int):
    """One side's node k of :func:`walk` (offsets up to ``lim``; none where the walk is ``full``):
    (still going, the sum, its last node)."""
    if going == 0 or k > lim or full:
        return int(0), total, last
    term = wp.exp(exponent)
    if term < stop:
        return int(0), total + term, k
    return int(1), total + term, k


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
        plus, total, p = walk_side(plus, k, lim_plus, p + m >= lim_total, even + odd, total, stop, p)
        minus, total, m = walk_side(minus, k, lim_minus, p + m >= lim_total, even - odd, total, stop, m)
    return total, p, m


@wp.func
def rule_terms(z1: Any, z2: Any, params: wp.array(dtype=Any), base: int):
    """(a, b, A = |(a, b)| + 4F) of one speed at the whitened point z."""
    a = params[base + RHO1] * z1 + params[KAPPA] * params[COS_THETA0]
    b = params[base + RHO2] * z2 + params[KAPPA] * params[SIN_THETA0]
    return a, b, wp.sqrt(a * a + b * b) + params[base + FOUR_F]


@wp.func
def peak_rule(z1: Any, z2: Any, params: wp.array(dtype=Any), base: int, mu_start: Any):
    """One speed's periodic rule at the whitened point z, anchored at its global peak: (a, b, N,
    Delta, cos theta*, sin theta*, mu, then E* and the coefficients of :func:`anchor_exponent`)."""
    a, b, amplitude = rule_terms(z1, z2, params, base)
    n = node_count(amplitude, params[LOG_TOL])
    x, y, mu = global_peak(a, b, params[base + FOUR_F], params[NEWTON_TOL], mu_start)
    e1, c1, c2, p11, p12, p22 = anchor_exponent(z1, z2, params, base, x, y)
    return a, b, n, type(z1)(TWO_PI) / type(z1)(n), x, y, mu, e1, c1, c2, p11, p12, p22


@wp.func
def second_walk(
    z1: Any, z2: Any, params: wp.array(dtype=Any), base: int, a: Any, b: Any, n: int, delta: Any, x: Any, y: Any,
    e1: Any, p1: int, m1: int,
):
    """The walk about the second local maximum (:func:`second_peak`) where it matters, from the
    node of the same periodic rule nearest to it, over the nodes the first walk (p1, m1 nodes on
    its sides from the peak (x, y), E* = e1) left: (exp(E2 - E*), its sum, its node j2, its
    nodes on each side); (0, 0, 0, 0, 0) where there is no such walk."""
    zero = type(z1)(0.0)
    found, x2, y2 = second_peak(a, b, params[base + FOUR_F], params[NEWTON_TOL], params[LOG_STOP])
    if found == 1 and p1 + m1 + 1 < n:
        offset = wp.atan2(x * y2 - y * x2, x * x2 + y * y2)
        j2 = int(wp.round(offset / delta))
        if j2 < 0:
            j2 = j2 + n
        if j2 > p1 and j2 < n - m1:
            angle = type(z1)(j2) * delta
            cj = wp.cos(angle)
            sj = wp.sin(angle)
            e2, d1, d2, q11, q12, q22 = anchor_exponent(z1, z2, params, base, x * cj - y * sj, y * cj + x * sj)
            scale = wp.exp(e2 - e1)
            if scale >= params[STOP]:
                lim_plus = n - m1 - 1 - j2
                lim_minus = j2 - p1 - 1
                extra, p2, m2 = walk(d1, d2, q11, q12, q22, delta, params[STOP], lim_plus, lim_minus,
                                     lim_plus + lim_minus)
                return scale, extra, j2, p2, m2
    return zero, zero, int(0), int(0), int(0)


@wp.func
def speed_density(z1: Any, z2: Any, params: wp.array(dtype=Any), base: int, mu_start: Any):
    """(w_i P_{r_i}(u), mu) for the speed whose constants start at ``params[base]``; ``mu_start``
    and ``mu`` are the secular equation's multiplier at the previous and this point (see
    :func:`global_peak`; 0 for a cold start)."""
    zero = type(z1)(0.0)
    a, b, n, delta, x, y, mu, e1, c1, c2, p11, p12, p22 = peak_rule(z1, z2, params, base, mu_start)
    if params[base + LOG_COEF] + e1 < params[LOG_TINY]:
        return zero, mu  # below the smallest positive number even if all N terms were 1 (Delta N = 2 pi)
    total, p1, m1 = walk(c1, c2, p11, p12, p22, delta, params[STOP], n - 1, n - 1, n - 1)
    scale, extra, j2, p2, m2 = second_walk(z1, z2, params, base, a, b, n, delta, x, y, e1, p1, m1)
    if scale > zero:
        total = total + scale * extra
    if total <= zero:
        return zero, mu
    return delta * total * wp.exp(params[base + LOG_COEF] + e1), mu


@wp.func
def ring_distance(z1: Any, z2: Any, z_norm: Any, params: wp.array(dtype=Any), base: int):
    """A lower bound d of the whitened distance from z to the ring, the ellipse (rho1 cos,
    rho2 sin) (rho1 >= rho2), that is 1-Lipschitz in z. The ring lies in the annulus
    rho2 <= |p| <= rho1, and g(z) = |(z1 / rho1, z2 / rho2)| is 1 on it with Lipschitz constant
    1 / rho2, so d = max(|z| - rho1, rho2 - |z|, rho2 |g(z) - 1|, 0) (d = |z| for r = 0): a
    maximum of 1-Lipschitz functions."""
    zero = type(z1)(0.0)
    rho1 = params[base + RHO1]
    rho2 = params[base + RHO2]
    d = wp.max(zero, wp.max(z_norm - rho1, rho2 - z_norm))
    if rho2 > zero:
        g1 = z1 / rho1
        g2 = z2 / rho2
        d = wp.max(d, rho2 * wp.abs(wp.sqrt(g1 * g1 + g2 * g2) - type(z1)(1.0)))
    return d


@wp.func
def log_bound(z1: Any, z2: Any, z_norm: Any, params: wp.array(dtype=Any), base: int):
    """An upper bound of log(w_i P_{r_i}(u)) that costs no exp: LOG_BOUND - d^2 / 2.

    exp(E(theta)) <= exp(-|z - ring(theta)|^2 / 2) exp(kappa (cos - 1)), so P_r <= (peak of
    the start density) exp(-d^2 / 2) with d (:func:`ring_distance`) a lower bound of the
    whitened distance from z to the ring.
    """
    d = ring_distance(z1, z2, z_norm, params, base)
    return params[base + LOG_BOUND] - type(z1)(0.5) * d * d


@wp.func
def whiten(x: Any, y: Any, params: wp.array(dtype=Any)):
    """The whitened coordinates (z1, z2) of the world point (x, y), and |z|."""
    dx = x - params[MEAN_X]
    dy = y - params[MEAN_Y]
    q1x = params[Q1_X]
    q1y = params[Q1_Y]
    z1 = (dx * q1x + dy * q1y) * params[INV_SQRT_S1]
    z2 = (dy * q1x - dx * q1y) * params[INV_SQRT_S2]
    return z1, z2, wp.sqrt(z1 * z1 + z2 * z2)


@wp.func
def butterly_density(x: Any, y: Any, params: wp.array(dtype=Any), n_speeds: int):
    """Density per m^2 at the world point (x, y): sum over speeds of w_i P_{r_i}(x, y), each
    from a cold start, a speed skipped only where its bound is below LOG_POINT_FLOOR (its value
    would underflow to 0)."""
    z1, z2, z_norm = whiten(x, y, params)
    total = type(x)(0.0)
    floor = params[LOG_POINT_FLOOR]
    for i in range(n_speeds):
        base = HEAD + PER_SPEED * i
        if log_bound(z1, z2, z_norm, params, base) >= floor:
            value, mu = speed_density(z1, z2, params, base, type(x)(0.0))
            total = total + value
    return total


@wp.func
def geometric_quads(quads: wp.array2d(dtype=Any), band: int, at: int, start: Any, slope: Any):
    """quads[band, at + q] = exp(start + m slope) for m = 4q .. 4q + 3, q < QUADS: two exps, then
    products (at most 10 roundings: the factor's relative error stays below 10 eps)."""
    g = wp.exp(slope)
    g2 = g * g
    first = wp.exp(start)
    lanes = wp.vector(first, first * g, first * g2, first * g2 * g)
    g4 = g2 * g2
    for q in range(QUADS):
        quads[band, at + q] = lanes
        lanes = lanes * g4


@wp.func
def add_row(
    out: wp.array2d(dtype=Any), row: int, col: int, cols: int, low: Any, high: Any,
    scratch: wp.array2d(dtype=Any), band: int, at: int, scale: Any, log_scale: Any, safe: int,
):
    """Add scale C(m) (low, high)[m] to the 8 cells col .. col + 7 of a row (those before
    ``cols`` and not marked skipped); C(m) = scratch[band, at + m] is the cross factor."""
    zero = type(scale)(0.0)
    for lane in range(8):
        if lane < cols and out[row, col + lane] >= zero:
            value = zero
            if lane < 4:
                value = low[lane]
            else:
                value = high[lane - 4]
            value = value * scratch[band, at + lane]
            if safe == 1:
                out[row, col + lane] = out[row, col + lane] + scale * value
            elif value > zero:  # exp(log_scale) alone under- or overflows: combine in logs
                out[row, col + lane] = out[row, col + lane] + scale * wp.exp(log_scale + wp.log(value))


@wp.func
def tile_speed(
    z1: Any, z2: Any, dzx1: Any, dzx2: Any, dzy1: Any, dzy2: Any, reach: Any, row: int, rows: int,
    col: int, cols: int, params: wp.array(dtype=Any), base: int, scratch: wp.array2d(dtype=Any),
    quads: wp.array2d(dtype=Any), band: int, out: wp.array2d(dtype=Any),
):
    """Add w_i P_{r_i} to the cells of one tile by the full periodic rule as a product of
    factors; 1 if done, 0 if the tile must be walked cell by cell instead (nothing added).

    The tile is TILE x TILE cells (the real ones: ``rows`` x ``cols`` from (row, col)) about the
    whitened centre z = (z1, z2); a cell is z + (m - h) dzx + (r - h) dzy, h = (TILE - 1) / 2,
    within ``reach`` = h (|dzx| + |dzy|) of z.
    With w_k = z - rho_k (rho_k the ring's node k) each node's exponent splits exactly into

        E_k(r, m) = e_k + (m - h) X_k + (r - h) Y_k - |(m - h) dzx + (r - h) dzy|^2 / 2,
        e_k = kappa (cos(theta_k - theta0) - 1) - |w_k|^2 / 2,  X_k = -w_k . dzx,  Y_k = -w_k . dzy,

    so the rule's sum is C(r, m) sum_k A_k(m) B_k(r) (a matrix product) with A_k(m) =
    exp(e_k - ref + (m - h) X_k), B_k(r) = exp((r - h) Y_k) and the node-free cross factor C
    (precomputed for the strip). ref = max_k e_k is taken out. A node is dropped when it stays
    below exp(-TILE_DROP) = stop / TILE_NODES of the largest node at every cell: E_k - E_ref is
    linear in (m, r), so its largest value on the tile is e_k - ref + h (|X_k - X_ref| +
    |Y_k - Y_ref|) (exact, no bound). The tile is refused (walked instead) where the rule needs
    more than TILE_NODES nodes, or where a factor could overflow or an underflowing one could
    matter (coarse cells far out).
    """
    zero = type(z1)(0.0)
    one = type(z1)(1.0)
    half = type(z1)(0.5)
    h = type(z1)(0.5 * float(TILE - 1))
    rho1 = params[base + RHO1]
    rho2 = params[base + RHO2]
    kappa = params[KAPPA]
    c0 = params[COS_THETA0]
    s0 = params[SIN_THETA0]
    # the rule for the largest amplitude on the tile (|(a, b)| is convex in z: at a corner)
    amp = zero
    for corner in range(4):
        sx = type(z1)(1 - 2 * (corner % 2))  # +-1
        sy = type(z1)(1 - 2 * (corner // 2))
        corner_a, corner_b, corner_amp = rule_terms(z1 + h * (sx * dzx1 + sy * dzy1), z2 + h * (sx * dzx2 + sy * dzy2),
                                                    params, base)
        amp = wp.max(amp, corner_amp)
    n = node_count(amp, params[LOG_TOL])
    n = (n + 15) // 16 * 16
    if n > TILE_NODES:
        return int(0)
    delta = type(z1)(TWO_PI) / type(z1)(n)
    # the nodes' exponents at the centre and their slopes; cos and sin of k delta = 16 b delta +
    # j delta by one rotation (a few roundings) from those of 16 b delta and of j delta
    angle = zero
    for j in range(16):
        scratch[band, NODE_TRIG + j] = wp.cos(angle)
        scratch[band, NODE_TRIG + 16 + j] = wp.sin(angle)
        angle = angle + delta
    ref = type(z1)(-1.0e30)
    x_ref = zero
    y_ref = zero
    for b in range(n // 16):
        angle = type(z1)(16 * b) * delta
        cb = wp.cos(angle)
        sb = wp.sin(angle)
        for j in range(16):
            cj = scratch[band, NODE_TRIG + j]
            sj = scratch[band, NODE_TRIG + 16 + j]
            ck = cb * cj - sb * sj
            sk = sb * cj + cb * sj
            w1 = z1 - rho1 * ck
            w2 = z2 - rho2 * sk
            e = kappa * (ck * c0 + sk * s0 - one) - half * (w1 * w1 + w2 * w2)
            x = -(w1 * dzx1 + w2 * dzx2)
            y = -(w1 * dzy1 + w2 * dzy2)
            k = 16 * b + j
            scratch[band, NODE_E + k] = e
            scratch[band, NODE_X + k] = x
            scratch[band, NODE_Y + k] = y
            if e > ref:
                ref = e
                x_ref = x
                y_ref = y
    # every cell's largest term is at least exp(-low) of ref (E_ref(r, m) - ref >= -low)
    low = h * (wp.abs(x_ref) + wp.abs(y_ref)) + half * reach * reach
    drop = params[TILE_DROP]
    kept = int(0)
    top = zero  # the largest exponent of a kept A, and of a kept B
    top_b = zero
    for k in range(n):
        e = scratch[band, NODE_E + k] - ref
        x = scratch[band, NODE_X + k]
        y = scratch[band, NODE_Y + k]
        if e + h * (wp.abs(x - x_ref) + wp.abs(y - y_ref)) >= -drop:
            top = wp.max(top, e + h * wp.abs(x))
            top_b = wp.max(top_b, h * wp.abs(y))
            geometric_quads(quads, band, QUAD_A + kept * QUADS, e - h * x, x)
            geometric_quads(quads, band, QUAD_B + kept * QUADS, -h * y, y)
            kept = kept + 1
    # The products and sums must not overflow (every factor is at most exp(top), exp(top_b)),
    # and a factor that underflows must leave only a negligible term: at most tiny exp(top_b)
    # (or exp(top)), below exp(-drop) of the cell's largest term (>= exp(-low)).
    log_kept = wp.log(type(z1)(kept))
    if top + top_b + log_kept >= params[LOG_HUGE] or wp.max(top, top_b) + low + drop >= -params[LOG_SMALL]:
        return int(0)
    # a cell's sum lies in [exp(-low), kept exp(top + top_b)]: exp(log_scale) times it is a
    # normal number unless log_scale is extreme (tails far out): then each cell combines logs
    log_scale = params[base + LOG_COEF] + ref
    safe_scale = int(0)
    if log_scale + top + top_b + log_kept < params[LOG_HUGE] and log_scale - low > params[LOG_SMALL]:
        safe_scale = int(1)
    scale = delta
    if safe_scale == 1:
        scale = wp.exp(log_scale) * delta
    # the product, 4 rows x 8 columns at a time (two 4 x 4 sums of outer products B_k A_k^T: row
    # i of ``sum_lo`` the columns m .. m + 3 of row rb + i; one node's A and B per step)
    for rb in range(0, rows, 4):
        for q in range(0, (cols + 3) // 4, 2):
            sum_lo = wp.matrix(shape=(4, 4), dtype=type(zero))
            sum_hi = wp.matrix(shape=(4, 4), dtype=type(zero))
            for k in range(kept):
                bk = quads[band, QUAD_B + k * QUADS + rb // 4]
                sum_lo = sum_lo + wp.outer(bk, quads[band, QUAD_A + k * QUADS + q])
                sum_hi = sum_hi + wp.outer(bk, quads[band, QUAD_A + k * QUADS + q + 1])
            m = 4 * q
            for i in range(wp.min(4, rows - rb)):
                add_row(out, row + rb + i, col + m, cols - m, sum_lo[i], sum_hi[i], scratch, band,
                        CROSS + (rb + i) * TILE + m, scale, log_scale, safe_scale)
    return int(1)


@wp.func
def walk_cells(
    xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), r_begin: int, r_end: int, c_begin: int, c_end: int,
    params: wp.array(dtype=Any), base: int, out: wp.array2d(dtype=Any),
):
    """Add w_i P_{r_i} to the unskipped cells of a block, each walking from its peak (Newton
    from the neighbouring cell's root), a speed left out where its bound is below the floor."""
    zero = type(params[0])(0.0)
    for row in range(r_begin, r_end):
        y = ys[row]
        mu = zero
        for j in range(c_begin, c_end):
            if out[row, j] >= zero:
                z1, z2, z_norm = whiten(xs[j], y, params)
                if log_bound(z1, z2, z_norm, params, base) >= params[LOG_SPEED_FLOOR]:
                    value, mu_next = speed_density(z1, z2, params, base, mu)
                    mu = mu_next
                    out[row, j] = out[row, j] + value


@wp.func
def mark_cells(
    xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), r_begin: int, r_end: int, c_begin: int, c_end: int,
    params: wp.array(dtype=Any), n_speeds: int, out: wp.array2d(dtype=Any),
):
    """out = 0 at the cells of a block to compute, -1 at those to skip: where the sum of the
    speeds' bounds (n times the largest) is below LOG_CELL_FLOOR."""
    zero = type(params[0])(0.0)
    cell_floor = params[LOG_CELL_FLOOR] - wp.log(type(params[0])(n_speeds))
    for row in range(r_begin, r_end):
        y = ys[row]
        for j in range(c_begin, c_end):
            z1, z2, z_norm = whiten(xs[j], y, params)
            mark = type(y)(-1.0)
            for s in range(n_speeds):
                if log_bound(z1, z2, z_norm, params, HEAD + PER_SPEED * s) >= cell_floor:
                    mark = zero
                    break
            out[row, j] = mark


@wp.func
def fill_cells(r_begin: int, r_end: int, c_begin: int, c_end: int, value: Any, skipped_only: int, out: wp.array2d(dtype=Any)):
    """out = ``value`` on a block (only where it is marked skipped, < 0, with ``skipped_only``)."""
    for row in range(r_begin, r_end):
        for j in range(c_begin, c_end):
            if skipped_only == 0 or out[row, j] < value:
                out[row, j] = value


@wp.kernel
def butterly_grid(
    xs: wp.array(dtype=Any),
    ys: wp.array(dtype=Any),
    row0: int,
    row_end: int,
    rows: int,
    columns: int,
    step_x: Any,
    step_y: Any,
    p: Any,
    scratch: wp.array2d(dtype=Any),
    quads: wp.array2d(dtype=Any),
    band: int,
    out: wp.array2d(dtype=Any),
):
    """Density at the cell centres of a block of ``rows`` x ``columns`` cells per thread (a strip
    of TILE rows of the band [row0, row_end) on the CPU, one cell on a GPU); ``scratch[band]`` and
    ``quads[band]`` are this band's work space (a band's threads run one after another on the
    CPU; a GPU's one-cell blocks never use it).

    Skipping (no exp): a cell is set to 0 where the sum of the speeds' bounds
    (:func:`log_bound`; n times the largest) is below LOG_CELL_FLOOR, and a speed is left out
    where its bound is below LOG_SPEED_FLOOR (the floors: ``Butterly.kernel_parameters``). A
    strip is cut into TILE x TILE tiles. The bound's distance is 1-Lipschitz, so on a tile it is
    within the half-diagonal ``reach`` of its value at the centre: a tile is skipped whole,
    computed whole, or (near the floor's contour) marked cell by cell. For each speed whose
    bound on the tile reaches LOG_SPEED_FLOOR, :func:`tile_speed` adds the speed's term, or,
    where it refuses the tile (rules over TILE_NODES nodes, coarse cells), :func:`walk_cells`
    does each cell from its peak. Blocks too small for a tile (a GPU's cells) are marked and
    walked cell by cell. ``out`` holds -1 for skipped cells until the end.
    """
    params = p.params
    n_speeds = p.n_speeds
    i, block = wp.tid()
    r_begin = row0 + i * rows
    r_end = wp.min(r_begin + rows, row_end)
    j_begin = block * columns
    j_end = wp.min(j_begin + columns, xs.shape[0])
    zero = type(params[0])(0.0)
    half = type(params[0])(0.5)
    if (r_end - r_begin) * (j_end - j_begin) < MIN_TILE_CELLS:
        mark_cells(xs, ys, r_begin, r_end, j_begin, j_end, params, n_speeds, out)
        for s in range(n_speeds):
            walk_cells(xs, ys, r_begin, r_end, j_begin, j_end, params, HEAD + PER_SPEED * s, out)
        fill_cells(r_begin, r_end, j_begin, j_end, zero, 1, out)
        return
    cell_floor = params[LOG_CELL_FLOOR] - wp.log(type(params[0])(n_speeds))
    speed_floor = params[LOG_SPEED_FLOOR]
    # the whitened steps of a column and a row (the grid is uniform) from the grid's own steps
    # (``step_x``, ``step_y``): the difference of neighbouring coordinates would carry their rounding
    # (1e-5 of a step in float32), and steps taken from the ends of ``xs`` would differ between a
    # block and the whole grid
    q1x = params[Q1_X]
    q1y = params[Q1_Y]
    dzx1 = step_x * q1x * params[INV_SQRT_S1]
    dzx2 = -step_x * q1y * params[INV_SQRT_S2]
    dzy1 = step_y * q1y * params[INV_SQRT_S1]
    dzy2 = step_y * q1x * params[INV_SQRT_S2]
    h = type(params[0])(0.5 * float(TILE - 1))
    # the cross factor C(r, m) = exp(-|(m - h) dzx + (r - h) dzy|^2 / 2) of every tile
    for r in range(TILE):
        for m in range(TILE):
            fm = type(params[0])(m) - h
            fr = type(params[0])(r) - h
            c1 = fm * dzx1 + fr * dzy1
            c2 = fm * dzx2 + fr * dzy2
            scratch[band, CROSS + r * TILE + m] = wp.exp(-half * (c1 * c1 + c2 * c2))
    reach = h * (wp.sqrt(dzx1 * dzx1 + dzx2 * dzx2) + wp.sqrt(dzy1 * dzy1 + dzy2 * dzy2))
    for c_begin in range(j_begin, j_end, TILE):
        c_end = wp.min(c_begin + TILE, j_end)
        zo1, zo2, zo_norm = whiten(xs[c_begin], ys[r_begin], params)
        z1 = zo1 + h * (dzx1 + dzy1)
        z2 = zo2 + h * (dzx2 + dzy2)
        z_norm = wp.sqrt(z1 * z1 + z2 * z2)
        state = int(0)  # 0: every cell skipped, 1: every cell computed, 2: some of each
        for s in range(n_speeds):
            base = HEAD + PER_SPEED * s
            d = ring_distance(z1, z2, z_norm, params, base)
            far = d + reach
            near = wp.max(d - reach, zero)
            if params[base + LOG_BOUND] - half * far * far >= cell_floor:
                state = int(1)
                break
            if params[base + LOG_BOUND] - half * near * near >= cell_floor:
                state = int(2)
        if state == 2:
            mark_cells(xs, ys, r_begin, r_end, c_begin, c_end, params, n_speeds, out)
        else:
            fill_cells(r_begin, r_end, c_begin, c_end, zero, 0, out)
        if state != 0:
            for s in range(n_speeds):
                base = HEAD + PER_SPEED * s
                # the speed's bound on the tile: its distance less the half-diagonal
                d = wp.max(ring_distance(z1, z2, z_norm, params, base) - reach, zero)
                if params[base + LOG_BOUND] - half * d * d >= speed_floor:
                    done = tile_speed(
                        z1, z2, dzx1, dzx2, dzy1, dzy2, reach, r_begin, r_end - r_begin, c_begin, c_end - c_begin,
                        params, base, scratch, quads, band, out,
                    )
                    if done == 0:
                        walk_cells(xs, ys, r_begin, r_end, c_begin, c_end, params, base, out)
        if state == 2:
            fill_cells(r_begin, r_end, c_begin, c_end, zero, 1, out)


@wp.func
def butterly_world(x: Any, y: Any, p: Any):
    """Density per m^2 at the world point (x, y) (:func:`butterly_density`): the points kernels'
    maths."""
    return butterly_density(x, y, p.params, p.n_speeds)


#: The parameters: the array laid out as HEAD and PER_SPEED say, and the speeds' count.
BUTTERLY = Params("ButterlyParams", __name__, params=ARRAY, n_speeds=int)
for _scalar in SCALARS:
    overload_on_use(butterly_grid, _scalar, {
        "xs": wp.array(dtype=_scalar), "ys": wp.array(dtype=_scalar), "step_x": _scalar, "step_y": _scalar,
        "p": BUTTERLY.of(_scalar), "scratch": wp.array2d(dtype=_scalar),
        "quads": wp.array2d(dtype=wp.types.vector(4, _scalar)), "out": wp.array2d(dtype=_scalar)})
KERNELS = density_kernels(butterly_world, BUTTERLY, "butterly", grid=butterly_grid, tile_rows=TILE,
                          scratch_width=SCRATCH, quad_width=QUAD_SCRATCH)




# ---------------------------------------------------------------------------------------------
# Carried evidence: the course integral with each path's weight inside
# ---------------------------------------------------------------------------------------------
#
# For the course c (theta = pi/2 - c - beta in the eigen frame) and the speed of range r = V t,
# the path through the map point x is at X(s) = x - r (t - s) / t e(c) at time s: on the
# circle of radius R(s) = r (t - s) / t about x. Evidence at s weighs the course by W(theta)
# (``kernels/evidence.py``), and the speed's carried density is
#
#     w_i P_i^W(x) = w_i coef int exp(E(theta)) W(theta) dtheta,
#
# integrated by pieces between the courses where W is not smooth (``carried_arc``): the rule,
# its pieces' breaks and its error are ``bananagrid.models.butterly.Butterly.bind_carried``'s.

#: Gauss-Legendre orders of the course pieces, lowest first (:func:`panel_rule`); the rule array
#: (``models.butterly._carried_rule``) holds each order's nodes on [-1, 1] and weights from
#: RULE_AT[n], then the constants below.
ORDERS = (2, 3, 4, 6, 8, 12, 16)
N_ORDERS = 7
RULE_AT = {2: 0, 3: 4, 4: 10, 6: 18, 8: 30, 12: 46, 16: 70}
#: After the rules: each order's n, where its nodes start, and its limit (in spacings); then
#: the narrowest spacing for smooth factors (a fraction of the density's) and a smooth factor's
#: spacing as a fraction of its angular scale.
ORDER_N = 102
ORDER_AT = ORDER_N + N_ORDERS
ORDER_LIMIT = ORDER_AT + N_ORDERS
NARROWEST = ORDER_LIMIT + N_ORDERS
SPACING = NARROWEST + 1
RULE_SIZE = SPACING + 1
#: Course breaks held at once: a window of the smallest, and the next window after them.
BREAKS = 32
#: Polygon nodes whose circle can meet their polygon, listed per point and speed, with their
#: contributions kept across the pieces of an arc (a break changes one node's); more than this
#: many: every polygon node is visited at every piece.
ACTIVE = 128
#: Definite-range tracks' course breaks (:func:`definite_breaks`): the march's least step and the
#: bisection's tolerance, as fractions of the arc; its most steps per arc and track; bisections
#: per break; the share of the Lipschitz step taken (rounding of the margins).
DEFINITE_MIN_STEP = 1.0e-6
DEFINITE_TOL = 1.0e-13
DEFINITE_STEPS = 20000
DEFINITE_BISECTIONS = 64
DEFINITE_SAFE = 0.999


@wp.func
def circle_edge_crossings(cx: Any, cy: Any, radius: Any, ax: Any, ay: Any, bx: Any, by: Any):
    """Where the circle of ``radius`` about (cx, cy) crosses the segment from (ax, ay) to
    (bx, by): (count, u1, u2), 0 <= u < 1 the crossings' fractions along the segment (a tangent
    point counts once). |A - C + u D|^2 = R^2 is a quadratic in u, solved in the form without
    cancellation (q = -(b + sign(b) sqrt(disc)), roots q / a and c / q)."""
    zero = type(cx)(0.0)
    one = type(cx)(1.0)
    dx = bx - ax
    dy = by - ay
    fx = ax - cx
    fy = ay - cy
    a2 = dx * dx + dy * dy
    b2 = fx * dx + fy * dy
    c2 = (fx - radius) * (fx + radius) + fy * fy
    disc = b2 * b2 - a2 * c2
    count = int(0)
    u1 = zero
    u2 = zero
    if a2 <= zero or disc < zero or radius <= zero:
        return count, u1, u2
    root = wp.sqrt(disc)
    q = -(b2 + root)
    if b2 < zero:
        q = root - b2
    r1 = q / a2
    if r1 >= zero and r1 < one:
        u1 = r1
        count = 1
    if q != zero:
        r2 = c2 / q
        if r2 >= zero and r2 < one and (count == 0 or r2 != r1):
            if count == 0:
                u1 = r2
            else:
                u2 = r2
            count = count + 1
    return count, u1, u2


@wp.func
def insert_break(buf: Any, who: Any, count: int, value: Any, node: int):
    """Insert ``value`` (made by the active node ``node``) into the sorted ``buf[:count]``
    (``who`` alongside), keeping the BREAKS smallest: (buf, who, count)."""
    if count == BREAKS:
        if value >= buf[BREAKS - 1]:
            return buf, who, count
        count = count - 1
    k = count
    while k > 0 and buf[k - 1] > value:
        buf[k] = buf[k - 1]
        who[k] = who[k - 1]
        k = k - 1
    buf[k] = value
    who[k] = wp.int32(node)
    return buf, who, count + 1


@wp.func
def path_radius(r: Any, t: Any, s: Any):
    """R(s) = r (t - s) / t: the distance from the map point to the path at time s."""
    if t <= type(r)(0.0):
        return type(r)(0.0)
    return r * ((t - s) / t)


@wp.func
def insert_course(buf: Any, who: Any, count: int, ex: Any, ey: Any, sx: Any, sy: Any, lo: Any, hi: Any, node: int):
    """Insert into the window (:func:`insert_break`, made by ``node``) the course offset from the
    peak's direction (sx, sy) to the direction (ex, ey), wrapped into (lo, hi) if it can be."""
    d = wp.atan2(sx * ey - sy * ex, sx * ex + sy * ey)
    for wrap in range(3):
        dd = d + type(ex)(float(wrap - 1)) * type(ex)(TWO_PI)
        if dd > lo and dd < hi:
            buf, who, count = insert_break(buf, who, count, dd, node)
    return buf, who, count


@wp.func
def node_radius(ev: Any, j: int, r: Any, t: Any):
    """R(s_j): the path's distance from the map point at node j's time."""
    return path_radius(r, t, ek.evidence_time(ev, j))


@wp.func
def box_distances(x: Any, y: Any, x0: Any, x1: Any, y0: Any, y1: Any):
    """The squared least and greatest distances from (x, y) to the box [x0, x1] x [y0, y1]."""
    zero = type(x)(0.0)
    near_x = wp.max(wp.max(x0 - x, zero), x - x1)
    near_y = wp.max(wp.max(y0 - y, zero), y - y1)
    far_x = wp.max(wp.abs(x0 - x), wp.abs(x - x1))
    far_y = wp.max(wp.abs(y0 - y), wp.abs(y - y1))
    return near_x * near_x + near_y * near_y, far_x * far_x + far_y * far_y


@wp.func
def circle_meets_box(ev: Any, j: int, x: Any, y: Any, radius: Any):
    """Whether the circle of ``radius`` about (x, y) meets polygon node j's bounding box (else
    the node's path points are all outside its polygon, and none crosses an edge)."""
    near2, far2 = box_distances(x, y, ev.data[j, 1], ev.data[j, 2], ev.data[j, 3], ev.data[j, 4])
    r2 = radius * radius
    return radius > type(x)(0.0) and near2 <= r2 and far2 >= r2


@wp.func
def active_polygons(ev: Any, p: Any, x: Any, y: Any, r: Any):
    """The polygon nodes whose circle meets their box for the range r: (list, count), count -1
    when more than ACTIVE (then every polygon node is taken)."""
    active = wp.vector(length=ACTIVE, dtype=wp.int32)
    count = int(0)
    for k in range(p.polygon_nodes.shape[0]):
        j = p.polygon_nodes[k]
        if count >= 0 and circle_meets_box(ev, j, x, y, node_radius(ev, j, r, p.t)):
            if count == ACTIVE:
                count = -1
            else:
                active[count] = wp.int32(j)
                count = count + 1
    return active, count


@wp.func
def circle_breaks(edges: Any, first: int, n_edges: int, x: Any, y: Any, radius: Any, sx: Any, sy: Any, lo: Any,
                  hi: Any, buf: Any, who: Any, count: int, node: int):
    """Insert into the window (:func:`insert_break`, made by ``node``) the course offsets in
    (lo, hi), from the peak's direction (sx, sy), where the circle of ``radius`` about (x, y)
    crosses the edges ``edges[first:first + n_edges]``: (buf, who, count)."""
    for e in range(first, first + n_edges):
        ax = edges[e, 0]
        ay = edges[e, 1]
        bx = edges[e, 2]
        by = edges[e, 3]
        hits, u1, u2 = circle_edge_crossings(x, y, radius, ax, ay, bx, by)
        for h in range(hits):
            u = u1
            if h == 1:
                u = u2
            ex = (x - (ax + u * (bx - ax))) / radius
            ey = (y - (ay + u * (by - ay))) / radius
            buf, who, count = insert_course(buf, who, count, ex, ey, sx, sy, lo, hi, node)
    return buf, who, count


@wp.func
def polygon_node(p: Any, active: Any, count: int, k: int):
    """The k-th polygon node to visit: from the active list, or every polygon node (count -1)."""
    if count < 0:
        return p.polygon_nodes[k]
    return int(active[k])


@wp.func
def visits(p: Any, count: int):
    """How many polygon nodes to visit."""
    if count < 0:
        return p.polygon_nodes.shape[0]
    return count


@wp.func
def window_breaks(x: Any, y: Any, r: Any, p: Any, active: Any, n_active: int, sx: Any, sy: Any, lo: Any, hi: Any,
                  ev: Any):
    """The smallest BREAKS offsets in (lo, hi) (from the peak's direction (sx, sy)) of the
    courses whose path crosses a polygon's edge at a polygon node's time, those of the searches
    over intervals (:func:`segment_breaks`) and of the definite-range tracks
    (:func:`definite_breaks`): (buf, who, count),
    who[b] the visit index k (:func:`polygon_node`) of the node that makes break b."""
    buf = wp.vector(length=BREAKS, dtype=type(x))
    who = wp.vector(length=BREAKS, dtype=wp.int32)
    count = int(0)
    for k in range(visits(p, n_active)):
        j = polygon_node(p, active, n_active, k)
        radius = node_radius(ev, j, r, p.t)
        if circle_meets_box(ev, j, x, y, radius):
            buf, who, count = circle_breaks(ev.edges, ev.ints[j, 2], ev.ints[j, 3], x, y, radius, sx, sy, lo, hi,
                                            buf, who, count, k)
    if p.smooth_nodes.shape[0] == 0:  # no definite-range track (the window is not copied again)
        return segment_breaks(x, y, r, p, ev, sx, sy, lo, hi, buf, who, count)
    buf, who, count = segment_breaks(x, y, r, p, ev, sx, sy, lo, hi, buf, who, count)
    return definite_breaks(x, y, r, p, ev, sx, sy, lo, hi, buf, who, count)


@wp.func
def smooth_spacing(x: Any, y: Any, r: Any, p: Any, delta: Any, ev: Any):
    """The course spacing (radians) that resolves the smooth factors as ``delta`` resolves the
    density: at most ``delta``, at most SMOOTH_SPACING times each smooth node's length scale over
    its radius R(s_j) (``delta`` is that fraction of the density's narrowest width), at least
    ``rule[NARROWEST]`` of ``delta``. Length scales: a report's smallest SD (>= 1 / sqrt(trace
    P)); a bearing's sigma times the least distance from the sensor to the circle; an
    inverse-cube rate's quarter distance from the searcher to the circle; a raster's cell."""
    zero = type(x)(0.0)
    out = delta
    for k in range(p.smooth_nodes.shape[0]):
        j = p.smooth_nodes[k]
        kind = ev.ints[j, 0]
        radius = node_radius(ev, j, r, p.t)
        if radius > zero and kind != ek.KIND_DEFINITE:  # a definite track's weight is cut, not resolved
            scale = zero
            if kind == ek.KIND_NORMAL:
                scale = type(x)(1.0) / wp.sqrt(ev.data[j, 2] + ev.data[j, 4])
            elif kind == ek.KIND_RASTER:
                scale = wp.min(ev.data[j, 2], ev.data[j, 3])
            else:
                dx = x - ev.data[j, 0]
                dy = y - ev.data[j, 1]
                gap = wp.abs(wp.sqrt(dx * dx + dy * dy) - radius)
                if kind == ek.KIND_BEARING:
                    scale = gap / ev.data[j, 3]
                else:
                    scale = type(x)(0.25) * gap
            out = wp.min(out, p.rule[SPACING] * scale / radius)
    return wp.max(out, delta * p.rule[NARROWEST])


@wp.func
def smooth_trapezoid(
    x: Any, y: Any, r: Any, cx: Any, cy: Any, q1x: Any, q1y: Any, c1: Any, c2: Any, p11: Any, p12: Any, p22: Any,
    lo: Any, hi: Any, h: Any, log_scale: Any, p: Any, ev: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any),
):
    """Add to each channel the trapezoid rule of spacing h (nodes theta* + k h) over (lo, hi)
    of exp(E + log_scale) times the path's weight, the polygons' log-weights already in ``lw``
    (constant on the arc): for an arc without polygon breaks, where the integrand falls below
    ``stop`` of its peak at both ends (or spans the circle), and the weight is smooth and
    periodic in the course."""
    k0 = int(wp.ceil(lo / h))
    k1 = int(wp.floor(hi / h))
    if hi - lo >= type(x)(TWO_PI) * (type(x)(1.0) - type(x)(1.0e-12)):
        k1 = k0 + int(wp.round((hi - lo) / h)) - 1  # the whole circle: each node once
    for k in range(k0, k1 + 1):
        e, ex, ey = course_node(cx, cy, q1x, q1y, c1, c2, p11, p12, p22, type(x)(k) * h)
        add_smooth(ev, p, x, y, ex, ey, r, lw)
        ek.evidence_add(ev, lw, h * wp.exp(e + log_scale), out)


@wp.func
def course_node(cx: Any, cy: Any, q1x: Any, q1y: Any, c1: Any, c2: Any, p11: Any, p12: Any, p22: Any, d: Any):
    """At theta = theta* + d: (E - E*, e(c) in the world)."""
    half = type(d)(0.5)
    sd = wp.sin(half * d)
    u = type(d)(-2.0) * sd * sd  # cos d - 1 without cancellation
    v = wp.sin(d)
    cd = type(d)(1.0) + u
    e = u * (c1 - half * p11 * u) - half * p22 * v * v + v * (c2 - p12 * u)
    ct = cx * cd - cy * v  # cos and sin of theta
    st = cy * cd + cx * v
    return e, ct * q1x - st * q1y, ct * q1y + st * q1x


@wp.func
def polygon_contribution(ev: Any, p: Any, active: Any, n_active: int, k: int, x: Any, y: Any, ex: Any, ey: Any,
                         r: Any):
    """q_j c_j of the k-th polygon node to visit for the path through (x, y) with direction e
    (``kernels/evidence.py``'s contribution: the polygon's value inside, else 0)."""
    j = polygon_node(p, active, n_active, k)
    radius = node_radius(ev, j, r, p.t)
    c = ek.evidence_contribution(ev, j, x - radius * ex, y - radius * ey)
    if c == type(x)(0.0):
        return c
    return ev.q[j] * c


@wp.func
def polygon_weights(ev: Any, p: Any, active: Any, n_active: int, cached: Any, lw: wp.array(dtype=Any)):
    """The factors' log-weights from the polygon nodes' contributions ``cached`` (one per
    visited node; the smooth factors' are zeroed, set at each node later)."""
    ek.evidence_reset(ev, lw)
    for k in range(visits(p, n_active)):
        if cached[k] != type(cached[k])(0.0):
            f = ev.ints[polygon_node(p, active, n_active, k), 1]
            lw[f] = lw[f] + cached[k]


@wp.func
def edge_crossing(edges: wp.array2d(dtype=Any), e: int, ax: Any, ay: Any, dx: Any, dy: Any):
    """Whether the segment from (ax, ay) along (dx, dy) crosses edge e (at 0 < u < 1 along the
    segment, 0 <= v < 1 along the edge): (crosses, u, cross(d, edge))."""
    zero = type(ax)(0.0)
    one = type(ax)(1.0)
    px = edges[e, 0]
    py = edges[e, 1]
    qx = edges[e, 2] - px
    qy = edges[e, 3] - py
    denom = dx * qy - dy * qx
    if denom != zero:
        wx = px - ax
        wy = py - ay
        u = (wx * qy - wy * qx) / denom
        v = (wx * dy - wy * dx) / denom
        return u > zero and u < one and v >= zero and v < one, u, denom
    return False, zero, denom


@wp.func
def inside_length(ev: Any, first: int, count: int, orient: Any, ax: Any, ay: Any, bx: Any, by: Any):
    """The fraction of the segment from (ax, ay) to (bx, by) inside the polygon of edges
    [first, first + count) (``orient`` +1 counter-clockwise, -1 clockwise): the winding number
    (0 or 1 in a simple polygon) at the start plus, at each crossing u of an edge, its change
    +-1 (entering where the segment crosses the edge from its outer side) times the rest of the
    segment 1 - u. No sorting: the sum of the steps' tails is the integral of the indicator."""
    zero = type(ax)(0.0)
    one = type(ax)(1.0)
    total = zero
    if ek.polygon_contains(ev.edges, first, count, ax, ay):
        total = one
    dx = bx - ax
    dy = by - ay
    for e in range(first, first + count):
        crosses, u, denom = edge_crossing(ev.edges, e, ax, ay, dx, dy)
        if crosses:
            step = orient
            if denom > zero:
                step = -orient  # crossing the edge from its left (inner) side: leaving
            total = total + step * (one - u)
    return wp.min(wp.max(total, zero), one)


@wp.func
def segment_reaches(p: Any, k: int, x: Any, y: Any, r: Any):
    """Whether the annulus R(t1) <= |P - x| <= R(t0) swept by search k's path segments (any
    course) meets the search polygon's box: else the segment is never inside."""
    r_far = path_radius(r, p.t, p.segments[k, 0])
    r_near = path_radius(r, p.t, p.segments[k, 1])
    near2, far2 = box_distances(x, y, p.segments[k, 4], p.segments[k, 5], p.segments[k, 6], p.segments[k, 7])
    return near2 <= r_far * r_far and far2 >= r_near * r_near


@wp.func
def reaching_segments(p: Any, x: Any, y: Any, r: Any, sx: Any, sy: Any, lo: Any, hi: Any):
    """How many searches over intervals a path of a course in theta* + (lo, hi) can be inside:
    the sector of the annulus R(t1) <= |P - x| <= R(t0) in those directions (from the peak's
    direction (sx, sy)) lies in the box of its four corners widened by R(t0) (1 - cos((hi - lo)
    / 2)) (the arc's bulge); it must meet the polygon's box (an arc of pi or more: the annulus's
    test, :func:`segment_reaches`)."""
    count = int(0)
    zero = type(x)(0.0)
    half = type(x)(0.5)
    cl = wp.cos(lo)
    sl = wp.sin(lo)
    ch = wp.cos(hi)
    sh = wp.sin(hi)
    # e(theta* + d) = the peak's direction turned by d
    lx = sx * cl - sy * sl
    ly = sx * sl + sy * cl
    hx = sx * ch - sy * sh
    hy = sx * sh + sy * ch
    wide = hi - lo >= type(x)(PI)
    bulge = type(x)(1.0) - wp.cos(half * (hi - lo))
    for k in range(p.segments.shape[0]):
        if segment_reaches(p, k, x, y, r):
            if wide:
                count = count + 1
            else:
                r0 = path_radius(r, p.t, p.segments[k, 0])
                r1 = path_radius(r, p.t, p.segments[k, 1])
                x0 = wp.min(wp.min(x - r0 * lx, x - r1 * lx), wp.min(x - r0 * hx, x - r1 * hx)) - r0 * bulge
                x1 = wp.max(wp.max(x - r0 * lx, x - r1 * lx), wp.max(x - r0 * hx, x - r1 * hx)) + r0 * bulge
                y0 = wp.min(wp.min(y - r0 * ly, y - r1 * ly), wp.min(y - r0 * hy, y - r1 * hy)) - r0 * bulge
                y1 = wp.max(wp.max(y - r0 * ly, y - r1 * ly), wp.max(y - r0 * hy, y - r1 * hy)) + r0 * bulge
                if x1 >= p.segments[k, 4] and x0 <= p.segments[k, 5] and y1 >= p.segments[k, 6] and y0 <= p.segments[k, 7]:
                    count = count + 1
    return count


@wp.func
def add_segments(ev: Any, p: Any, x: Any, y: Any, ex: Any, ey: Any, r: Any, lw: wp.array(dtype=Any)):
    """Set the log-weights of the area searches over intervals taken exactly: the path's
    straight segment over (t0, t1) spends the fraction f of the interval inside the polygon,
    and the factor's log-weight is rate (t1 - t0) f (rate = -C / (t1 - t0), the pack's)."""
    zero = type(x)(0.0)
    for k in range(p.segments.shape[0]):
        f = p.segment_ints[k, 0]
        r0 = path_radius(r, p.t, p.segments[k, 0])
        r1 = path_radius(r, p.t, p.segments[k, 1])
        first = p.segment_ints[k, 1]
        count = p.segment_ints[k, 2]
        frac = zero
        if not segment_reaches(p, k, x, y, r):
            frac = zero
        elif r0 > r1:
            frac = inside_length(ev, first, count, p.segments[k, 3], x - r0 * ex, y - r0 * ey, x - r1 * ex, y - r1 * ey)
        elif ek.polygon_contains(ev.edges, first, count, x - r0 * ex, y - r0 * ey):
            frac = type(x)(1.0)
        value = zero
        if frac > zero:
            value = p.segments[k, 2] * (p.segments[k, 1] - p.segments[k, 0]) * frac
        lw[f] = value


@wp.func
def segments_cross(ev: Any, p: Any, x: Any, y: Any, ex: Any, ey: Any, r: Any):
    """Whether the path of direction e through (x, y) crosses an edge of a search over an
    interval's polygon inside its segment (the crossings :func:`inside_length` counts). Between
    two courses that are breaks (:func:`segment_breaks`: an end of the segment on an edge, or
    the segment through a vertex) the set of edges a segment crosses does not change, so where
    it crosses none at one course of a piece its fraction inside (0 or 1) is constant on the
    piece."""
    for k in range(p.segments.shape[0]):
        if segment_reaches(p, k, x, y, r):
            r0 = path_radius(r, p.t, p.segments[k, 0])
            r1 = path_radius(r, p.t, p.segments[k, 1])
            ax = x - r0 * ex
            ay = y - r0 * ey
            dx = (r0 - r1) * ex
            dy = (r0 - r1) * ey
            first = p.segment_ints[k, 1]
            for e in range(first, first + p.segment_ints[k, 2]):
                crosses, u, denom = edge_crossing(ev.edges, e, ax, ay, dx, dy)
                if crosses:
                    return True
    return False


@wp.func
def segment_breaks(x: Any, y: Any, r: Any, p: Any, ev: Any, sx: Any, sy: Any, lo: Any, hi: Any, buf: Any, who: Any,
                   count: int):
    """Add to the window the courses where a search-over-an-interval's weight is not smooth:
    where an end of the path's segment crosses an edge (the circles R(t0), R(t1)) and where the
    segment passes a vertex (its direction from x, at a distance between R(t1) and R(t0))."""
    zero = type(x)(0.0)
    for k in range(p.segments.shape[0]):
        first = p.segment_ints[k, 1]
        n_edges = p.segment_ints[k, 2]
        r_far = path_radius(r, p.t, p.segments[k, 0])
        r_near = path_radius(r, p.t, p.segments[k, 1])
        if not segment_reaches(p, k, x, y, r):
            n_edges = 0  # never inside: no break
        for end in range(2):
            radius = r_far
            if end == 1:
                radius = r_near
            if radius > zero:
                buf, who, count = circle_breaks(ev.edges, first, n_edges, x, y, radius, sx, sy, lo, hi, buf, who,
                                                count, -1)
        for e in range(first, first + n_edges):
            vx = x - ev.edges[e, 0]
            vy = y - ev.edges[e, 1]
            dist = wp.sqrt(vx * vx + vy * vy)
            if dist > zero and dist >= r_near and dist <= r_far:
                buf, who, count = insert_course(buf, who, count, vx / dist, vy / dist, sx, sy, lo, hi, -1)
    return buf, who, count


@wp.func
def track_margin(ev: Any, p: Any, x: Any, y: Any, ex: Any, ey: Any, r: Any, k0: int):
    """The closest approach less h = W / 2 of the path through (x, y) with direction e to the
    definite-range track whose chain starts at smooth node k0, exact per leg (its nodes at track
    points, ``DEFINITE_LEG``; ``kernels/evidence.py``'s ``KIND_DEFINITE`` with the legs as
    chords, the chords between ignored). At most 0: detected."""
    j0 = p.smooth_nodes[k0]
    f = ev.ints[j0, 1]
    h = ev.data[j0, 4]
    margin = type(x)(0.0)
    prev_x = type(x)(0.0)
    prev_y = type(x)(0.0)
    for k in range(k0, p.smooth_nodes.shape[0]):
        j = p.smooth_nodes[k]
        if ev.ints[j, 0] == ek.KIND_DEFINITE and ev.ints[j, 1] == f and (ev.ints[j, 3] & ek.DEFINITE_LEG) != 0:
            radius = node_radius(ev, j, r, p.t)
            dx = x - radius * ex - ev.data[j, 0]
            dy = y - radius * ey - ev.data[j, 1]
            if k == k0:
                margin = wp.sqrt(dx * dx + dy * dy) - h
            else:
                margin = wp.min(margin, ek.segment_distance(prev_x, prev_y, dx, dy) - h)
            prev_x = dx
            prev_y = dy
    return margin


@wp.func
def definite_reaches(ev: Any, p: Any, x: Any, y: Any, r: Any, k0: int):
    """Whether a path through (x, y) of any course can come within h of the definite-range
    track whose chain starts at smooth node k0: its paths over the track's span lie in the
    annulus R(s_last) <= |P - x| <= R(s_0) about x, the searcher in the box of its track
    points; else every course's margin is positive (no break, weight 1)."""
    j0 = p.smooth_nodes[k0]
    f = ev.ints[j0, 1]
    h = ev.data[j0, 4]
    x0 = ev.data[j0, 0]
    x1 = x0
    y0 = ev.data[j0, 1]
    y1 = y0
    j_last = j0
    for k in range(k0, p.smooth_nodes.shape[0]):
        j = p.smooth_nodes[k]
        if ev.ints[j, 0] == ek.KIND_DEFINITE and ev.ints[j, 1] == f and (ev.ints[j, 3] & ek.DEFINITE_LEG) != 0:
            x0 = wp.min(x0, ev.data[j, 0])
            x1 = wp.max(x1, ev.data[j, 0])
            y0 = wp.min(y0, ev.data[j, 1])
            y1 = wp.max(y1, ev.data[j, 1])
            j_last = j
    near2, far2 = box_distances(x, y, x0, x1, y0, y1)
    return wp.sqrt(near2) <= node_radius(ev, j0, r, p.t) + h and wp.sqrt(far2) >= node_radius(ev, j_last, r, p.t) - h


@wp.func
def add_definite(ev: Any, p: Any, x: Any, y: Any, ex: Any, ey: Any, r: Any, lw: wp.array(dtype=Any)):
    """Set each definite-range track's log-weight for the path of direction e: -inf where it
    comes within h of the searcher (:func:`track_margin`), else 0."""
    for k in range(p.smooth_nodes.shape[0]):
        j = p.smooth_nodes[k]
        if ev.ints[j, 0] == ek.KIND_DEFINITE and (ev.ints[j, 3] & ek.DEFINITE_START) != 0:
            value = type(x)(0.0)
            if track_margin(ev, p, x, y, ex, ey, r, k) <= type(x)(0.0):
                value = -type(x)(wp.inf)
            lw[ev.ints[j, 1]] = value


@wp.func
def turned(sx: Any, sy: Any, d: Any):
    """The peak's direction (sx, sy) turned by the course offset d: e(theta* + d)."""
    c = wp.cos(d)
    s = wp.sin(d)
    return sx * c - sy * s, sx * s + sy * c


@wp.func
def definite_breaks(x: Any, y: Any, r: Any, p: Any, ev: Any, sx: Any, sy: Any, lo: Any, hi: Any, buf: Any, who: Any,
                    count: int):
    """Add to the window the course offsets in (lo, hi) where a definite-range track's weight
    switches (its margin, :func:`track_margin`, changes sign), found by a march that cannot
    step over one: the margin is Lipschitz in the course with constant L = R(s_0), the radius
    at the track's first time (a course change dd moves the path at s by R(s) dd), so from an
    offset where it is m there is no sign change within |m| / L. The march steps by that (at
    least DEFINITE_MIN_STEP of the arc (lo, hi) and four roundings of the offset, at most
    DEFINITE_STEPS steps) and bisects each
    step across which the sign changes to DEFINITE_TOL of the arc. What it can miss: a set of
    courses narrower than the least step where the margin changes sign twice (a sliver of
    grazing paths), its integral at most the least step times the integrand's peak (the arc
    spans a normal-like integrand to 1e-15 of its peak, +-8.3 SD, so the least step is 17e-6
    SD: under 7e-6 of the arc's integral per sliver in float64)."""
    zero = type(x)(0.0)
    half = type(x)(0.5)
    width = hi - lo
    # the least step also moves the offset by a few of its roundings (float32: 1.2e-7 of it)
    eps = type(x)(2.2e-16)
    if type(x)(1.0) + type(x)(1.0e-10) == type(x)(1.0):
        eps = type(x)(1.2e-7)
    least = wp.max(width * type(x)(DEFINITE_MIN_STEP), type(x)(4.0) * eps * (wp.abs(lo) + wp.abs(hi)))
    tol = width * type(x)(DEFINITE_TOL)
    for k0 in range(p.smooth_nodes.shape[0]):
        j0 = p.smooth_nodes[k0]
        if ev.ints[j0, 0] == ek.KIND_DEFINITE and (ev.ints[j0, 3] & ek.DEFINITE_START) != 0:
            lip = node_radius(ev, j0, r, p.t)
            if lip > zero and width > zero and definite_reaches(ev, p, x, y, r, k0):
                d = lo
                ex, ey = turned(sx, sy, d)
                m = track_margin(ev, p, x, y, ex, ey, r, k0)
                steps = int(0)
                while d < hi and steps < DEFINITE_STEPS:
                    steps = steps + 1
                    d2 = wp.min(d + wp.max(type(x)(DEFINITE_SAFE) * wp.abs(m) / lip, least), hi)
                    ex, ey = turned(sx, sy, d2)
                    m2 = track_margin(ev, p, x, y, ex, ey, r, k0)
                    if (m2 <= zero) != (m <= zero):
                        a = d
                        b = d2
                        for _it in range(DEFINITE_BISECTIONS):
                            if b - a > tol:
                                c = half * (a + b)
                                if c > a and c < b:
                                    cx, cy = turned(sx, sy, c)
                                    if (track_margin(ev, p, x, y, cx, cy, r, k0) <= zero) == (m <= zero):
                                        a = c
                                    else:
                                        b = c
                        c = half * (a + b)
                        if c > lo and c < hi:
                            buf, who, count = insert_break(buf, who, count, c, -1)
                    d = d2
                    m = m2
    return buf, who, count


@wp.func
def add_smooth(ev: Any, p: Any, x: Any, y: Any, ex: Any, ey: Any, r: Any, lw: wp.array(dtype=Any)):
    """Set the smooth factors' log-weights for the path through (x, y) with direction e (their
    factors zeroed first; the polygons' are left as they are), the searches over intervals'
    included (:func:`add_segments`), and the definite-range tracks' (:func:`add_definite`:
    their legs, not the pack's chords)."""
    for k in range(p.smooth_nodes.shape[0]):
        lw[ev.ints[p.smooth_nodes[k], 1]] = type(x)(0.0)
    definite = int(0)
    for k in range(p.smooth_nodes.shape[0]):
        j = p.smooth_nodes[k]
        if ev.ints[j, 0] == ek.KIND_DEFINITE:
            definite = 1
        else:
            radius = node_radius(ev, j, r, p.t)
            ek.evidence_node(ev, j, x - radius * ex, y - radius * ey, lw)
    if definite == 1:
        add_definite(ev, p, x, y, ex, ey, r, lw)
    add_segments(ev, p, x, y, ex, ey, r, lw)


@wp.func
def panel_rule(a: Any, b: Any, spacing: Any, rule: Any):
    """The pieces' rule on (a, b): the fewest equal panels no wider than the highest order's
    limit (in units of ``spacing``), each by the lowest order whose limit covers it:
    (panels m, panel width h, order, offset of its nodes and weights in ``rule``)."""
    width = (b - a) / spacing
    m = int(wp.ceil(width / rule[ORDER_LIMIT + N_ORDERS - 1]))
    if m < 1:
        m = 1
    h = (b - a) / type(a)(m)
    level = int(N_ORDERS - 1)
    for i in range(N_ORDERS - 1):
        if level == N_ORDERS - 1 and width <= type(a)(m) * rule[ORDER_LIMIT + i]:
            level = i
    return m, h, int(rule[ORDER_N + level]), int(rule[ORDER_AT + level])


@wp.func
def gauss_piece(
    a: Any, b: Any, spacing: Any, cx: Any, cy: Any, q1x: Any, q1y: Any, c1: Any, c2: Any, p11: Any, p12: Any,
    p22: Any, log_scale: Any, rule: Any, weighted: int, x: Any, y: Any, r: Any, p: Any, ev: Any,
    lw: wp.array(dtype=Any), out: wp.array(dtype=Any), others: Any,
):
    """The integral of exp(E + log_scale) over theta* + (a, b) by the pieces' rule
    (:func:`panel_rule`), and ``others`` plus it; with ``weighted`` each node's term times the
    path's weight there (the polygons' log-weights already in ``lw``) is added to each channel
    instead, and the integral returned is 0."""
    half = type(a)(0.5)
    m, h, order, at = panel_rule(a, b, spacing, rule)
    total = type(a)(0.0)
    for k in range(m):
        mid = a + (type(a)(k) + half) * h
        for g in range(order):
            e, ex, ey = course_node(cx, cy, q1x, q1y, c1, c2, p11, p12, p22, mid + half * h * rule[at + g])
            term = half * h * rule[at + order + g] * wp.exp(e + log_scale)
            others = others + term
            if weighted == 0:
                total = total + term
            else:
                add_smooth(ev, p, x, y, ex, ey, r, lw)
                ek.evidence_add(ev, lw, term, out)
    return total, others


@wp.func
def course_polygon_weights(ev: Any, p: Any, active: Any, n_active: int, x: Any, y: Any, r: Any, ex: Any, ey: Any,
                           lw: wp.array(dtype=Any)):
    """The factors' log-weights from every polygon node to visit for the path through (x, y)
    with direction e (the smooth factors' zeroed)."""
    ek.evidence_reset(ev, lw)
    for k in range(visits(p, n_active)):
        j = polygon_node(p, active, n_active, k)
        radius = node_radius(ev, j, r, p.t)
        ek.evidence_node(ev, j, x - radius * ex, y - radius * ey, lw)


@wp.func
def segments_constant(ev: Any, p: Any, x: Any, y: Any, ex: Any, ey: Any, r: Any, lw: wp.array(dtype=Any)):
    """Where searches over intervals are the only smooth factors: whether their weights are
    constant about the path of direction e (no segment crosses an edge, :func:`segments_cross`),
    and then their log-weights set."""
    if segments_cross(ev, p, x, y, ex, ey, r):
        return False
    add_segments(ev, p, x, y, ex, ey, r, lw)
    return True


@wp.func
def carried_arc(
    x: Any, y: Any, r: Any, cx: Any, cy: Any, q1x: Any, q1y: Any, c1: Any, c2: Any, p11: Any, p12: Any,
    p22: Any, lo: Any, hi: Any, spacing: Any, log_scale: Any, trapezoid: Any, p: Any, active: Any, n_active: int,
    ev: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any),
):
    """Add to each channel the integral over theta* + (lo, hi) of exp(E + log_scale) times the
    path's weight: pieces between the polygons' course breaks (a window of BREAKS at a time), each
    by :func:`gauss_piece` in ``spacing``. Without smooth factors the weight is constant on a piece:
    one weight per piece, and an arc without breaks takes the density's own trapezoid sum over it
    (``trapezoid``, relative to exp(E*)) times its weight. With breaks, the piece holding the peak's
    course, where its weight is constant, takes the trapezoid sum less the other pieces' integrals
    (where that is at least half the sum, so the trapezoid's error, 1e-12 of the arc, stays within
    2e-12 of the piece's; else its own rule): the arc's widest piece costs no nodes."""
    zero = type(x)(0.0)
    half = type(x)(0.5)
    rule = p.rule
    sx = cx * q1x - cy * q1y  # the peak's direction e(c*) in the world
    sy = cx * q1y + cy * q1x
    reach = reaching_segments(p, x, y, r, sx, sy, lo, hi)
    smooth = p.smooth_nodes.shape[0] + reach
    cached = wp.vector(length=ACTIVE, dtype=type(x))
    # the peak's piece (theta* inside it), where its weight is constant, is not integrated by
    # its own rule: its integral is the arc's trapezoid sum less the other pieces' (below)
    use_base = p.smooth_nodes.shape[0] == 0 and ev.channels.shape[1] <= ek.EXP_FACTORS and lo < zero and hi > zero
    base_lw = wp.vector(length=ek.EXP_FACTORS, dtype=type(x))
    have_base = int(0)
    base_a = zero
    base_b = zero
    others = zero  # the other pieces' integrals of exp(E + log_scale) (no weight)
    a = lo
    while a < hi:
        buf, who, count = window_breaks(x, y, r, p, active, n_active, sx, sy, a, hi, ev)
        if count == 0 and a == lo:
            # no break: the polygons' weight is constant on the arc
            e_mid, mx, my = course_node(cx, cy, q1x, q1y, c1, c2, p11, p12, p22, half * (lo + hi))
            course_polygon_weights(ev, p, active, n_active, x, y, r, mx, my, lw)
            constant = smooth == 0
            if not constant and p.smooth_nodes.shape[0] == 0:
                # only searches over intervals weigh the arc: their weights at the middle course
                constant = segments_constant(ev, p, x, y, mx, my, r, lw)
            if constant:
                ek.evidence_add(ev, lw, trapezoid * wp.exp(log_scale), out)
            else:
                smooth_trapezoid(x, y, r, cx, cy, q1x, q1y, c1, c2, p11, p12, p22, lo, hi, spacing, log_scale, p, ev,
                                 lw, out)
            return
        end = hi
        if count == BREAKS:
            end = buf[BREAKS - 1]
        fresh = int(1)  # every contribution to evaluate (a window's first piece: breaks beyond the
        # last window may have been dropped at its edge)
        applied = int(0)  # breaks of this window whose node is evaluated
        for piece in range(count + 1):
            b = end
            if piece < count:
                b = buf[piece]
            if b > a:
                e_mid, mx, my = course_node(cx, cy, q1x, q1y, c1, c2, p11, p12, p22, half * (a + b))
                if n_active < 0:
                    course_polygon_weights(ev, p, active, n_active, x, y, r, mx, my, lw)
                else:
                    if fresh == 1:
                        for k in range(n_active):
                            cached[k] = polygon_contribution(ev, p, active, n_active, k, x, y, mx, my, r)
                        polygon_weights(ev, p, active, n_active, cached, lw)
                    else:
                        # only the nodes whose crossings lie between the last piece and this
                        # one change: their factors' log-weights move by the difference (all
                        # of them again where a contribution is infinite: POD = 1)
                        rebuild = int(0)
                        for q in range(applied, piece):
                            k = int(who[q])
                            if k < 0:  # a search over an interval's break: its weight is per node
                                continue
                            new = polygon_contribution(ev, p, active, n_active, k, x, y, mx, my, r)
                            if wp.isfinite(new) and wp.isfinite(cached[k]):
                                f = ev.ints[polygon_node(p, active, n_active, k), 1]
                                lw[f] = lw[f] + (new - cached[k])
                            else:
                                rebuild = 1
                            cached[k] = new
                        if rebuild == 1:
                            polygon_weights(ev, p, active, n_active, cached, lw)
                fresh = int(0)
                applied = piece
                piece_smooth = smooth
                if smooth > 0 and p.smooth_nodes.shape[0] == 0:
                    # only searches over intervals: the piece's weight may be constant
                    if segments_constant(ev, p, x, y, mx, my, r, lw):
                        piece_smooth = 0
                if use_base and piece_smooth == 0 and a <= zero and b > zero:
                    for f in range(ev.channels.shape[1]):
                        base_lw[f] = lw[f]
                    have_base = 1
                    base_a = a
                    base_b = b
                    a = b
                    continue
                total, others = gauss_piece(a, b, spacing, cx, cy, q1x, q1y, c1, c2, p11, p12, p22, log_scale, rule,
                                            piece_smooth, x, y, r, p, ev, lw, out, others)
                if piece_smooth == 0:
                    ek.evidence_add(ev, lw, total, out)
                a = b
        if count < BREAKS:
            a = hi
        else:
            a = end
    if have_base == 1:
        whole = trapezoid * wp.exp(log_scale)
        base = whole - others
        if base < half * whole:
            # the peak's piece holds under half the arc: its own rule (the difference's
            # cancellation would cost more than the trapezoid's 1e-12 of the arc)
            base, unused = gauss_piece(base_a, base_b, spacing, cx, cy, q1x, q1y, c1, c2, p11, p12, p22, log_scale,
                                       rule, 0, x, y, r, p, ev, lw, out, zero)
        for f in range(ev.channels.shape[1]):
            lw[f] = base_lw[f]
        ek.evidence_add(ev, lw, base, out)


@wp.func
def carried_speed(
    x: Any, y: Any, z1: Any, z2: Any, p: Any, base: int, ev: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any),
):
    """Add the speed's carried density w_i P_i^W at (x, y) (whitened z) to each channel: the
    arcs of the density's walk (:func:`speed_density`: the peak's, and the second peak's where
    it matters), each by :func:`carried_arc`."""
    params = p.params
    zero = type(z1)(0.0)
    pi = type(z1)(PI)
    q1x = params[Q1_X]
    q1y = params[Q1_Y]
    r = params[base + RHO1] / params[INV_SQRT_S1]
    a, b, n, delta, cx, cy, mu, e1, c1, c2, p11, p12, p22 = peak_rule(z1, z2, params, base, zero)
    spacing = delta
    if p.smooth_nodes.shape[0] > 0:
        spacing = smooth_spacing(x, y, r, p, delta, ev)
        spacing = delta / type(z1)(float(int(wp.ceil(delta / spacing))))  # delta a multiple of it
    log_scale = params[base + LOG_COEF] + e1
    if log_scale < params[LOG_TINY]:
        return
    active, n_active = active_polygons(ev, p, x, y, r)
    trapezoid, p1, m1 = walk(c1, c2, p11, p12, p22, delta, params[STOP], n - 1, n - 1, n - 1)
    lo = -type(z1)(m1) * delta
    hi = type(z1)(p1) * delta
    if p1 + m1 + 1 >= n:
        lo = -pi
        hi = pi
    carried_arc(x, y, r, cx, cy, q1x, q1y, c1, c2, p11, p12, p22, lo, hi, spacing, log_scale, delta * trapezoid, p,
                active, n_active, ev, lw, out)
    scale, extra, j2, p2, m2 = second_walk(z1, z2, params, base, a, b, n, delta, cx, cy, e1, p1, m1)
    if scale > zero:
        carried_arc(x, y, r, cx, cy, q1x, q1y, c1, c2, p11, p12, p22, type(z1)(j2 - m2) * delta,
                    type(z1)(j2 + p2) * delta, spacing, log_scale, delta * scale * extra, p, active, n_active, ev,
                    lw, out)


@wp.func
def butterly_carried(x: Any, y: Any, p: Any, ev: Any, lw: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    """Add the carried density per m^2 at the world point (x, y) to each channel of ``out``: the
    sum over speeds of :func:`carried_speed`, a speed skipped where its bound is below
    LOG_SPEED_FLOOR (and the point where every speed's is below LOG_CELL_FLOOR): weights are at
    most one, so the prior's bound bounds every channel."""
    params = p.params
    z1, z2, z_norm = whiten(x, y, params)
    cell_floor = params[LOG_CELL_FLOOR] - wp.log(type(x)(float(p.n_speeds)))
    keep = int(0)
    for i in range(p.n_speeds):
        if log_bound(z1, z2, z_norm, params, HEAD + PER_SPEED * i) >= cell_floor:
            keep = 1
    if keep == 0:
        return
    for i in range(p.n_speeds):
        base = HEAD + PER_SPEED * i
        if log_bound(z1, z2, z_norm, params, base) >= params[LOG_SPEED_FLOOR]:
            carried_speed(x, y, z1, z2, p, base, ev, lw, out)


#: The carried kernels' parameters: the density's array and speed count, the course rule
#: (RULE_SIZE values), the map's time t, the pack's polygon nodes and other (smooth) nodes, and
#: the area searches over intervals taken exactly (``segments`` rows t0, t1, rate, orientation,
#: then the polygon's box x0, x1, y0, y1;
#: ``segment_ints`` rows factor, first edge, edge count, in the pack's edges).
BUTTERLY_CARRIED = Params("ButterlyCarriedParams", __name__, params=ARRAY, n_speeds=int, rule=ARRAY, t=SCALAR,
                          polygon_nodes=wp.array(dtype=wp.int32), smooth_nodes=wp.array(dtype=wp.int32),
                          segments=ARRAY2D, segment_ints=wp.array2d(dtype=wp.int32))
CARRIED_KERNELS = carried_points_kernel(butterly_carried, BUTTERLY_CARRIED, ek.EVIDENCE, "butterly")
