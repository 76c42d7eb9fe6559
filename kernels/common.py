"""Shared device math: generic over float32 and float64 (``Any`` scalars).

Warp has no log1p, hypot, Bessel or normal-pdf builtins, and its closed forms lose digits near
zero, so the small-argument series live here once and every kernel calls them.

Precision trap: a module-level Python float used in a kernel is a float32 constant in
arithmetic, so ``type(x)(A * B)`` is rounded to float32 before the cast. Cast single constants
only (``type(x)(A)``), and precompute products in Python as their own constant.
"""

from typing import Any

import warp as wp

#: 1 / sqrt(2 pi)
INV_SQRT_2PI = 0.3989422804014327
ONE_THIRD = 1.0 / 3.0

#: Below this |u| the CAT basis functions switch from closed forms to their Taylor series. At
#: |u| = 1 the series' 10th term is below 1e-19 relative, and the closed forms' cancellation
#: (sin u - u cos u ~ u^3 / 3) costs at most one digit above it.
SERIES_SWITCH = 1.0



@wp.func
def sinc_of(x: Any, sin_x: Any):
    """Unnormalised sinc, sin(x) / x, from a known sin(x); sinc(0) = 1 (ERRATA: not numpy's
    normalised sinc). Taking sin(x) as an argument lets a caller that knows it skip a sine."""
    if wp.abs(x) < type(x)(1.0e-4):
        return type(x)(1.0) - x * x / type(x)(6.0)
    return sin_x / x


@wp.func
def sinc(x: Any):
    """Unnormalised sinc, sin(x) / x."""
    return sinc_of(x, wp.sin(x))


#: Below this |x| :func:`sinc_derivatives` sums the Taylor series; above it the upward
#: recurrence loses at most 4! / x^4 < 5 ulps (the series' 15th term is below 1e-18 there).
SINC_SERIES_SWITCH = 1.5
SINC_SERIES_TERMS = 15


#: A vector of cells: 8 float64 or 16 float32 lanes, one 512-bit register (``kernels/lanes.py``).
#: Half as many (256 bits, one AVX2 register) measured slower on every lane kernel on AVX-512
#: (docs/speed.md); on an AVX2 machine a 512-bit vector compiles to two registers.
LANES64 = 8
LANES32 = 16
lanes64 = wp.types.vector(LANES64, wp.float64)
lanes32 = wp.types.vector(LANES32, wp.float32)


# --- arithmetic generic over one value and a vector of lanes -------------------------------------
# Warp's * and / between two vectors are not lane by lane. These are, and between scalars they
# are the plain operators: one function body then serves the scalar kernels and the lane
# kernels with the same roundings. ``lane0`` gives a value of the scalar type, whose type makes
# constants (``type(lane0(x))(2.0) * v`` scales a vector; ``type(v)(1.0)`` fills one).

for _scalar in (wp.float64, wp.float32):

    @wp.func
    def each_mul(a: _scalar, b: _scalar):
        """a * b, lane by lane for vectors."""
        return a * b

    @wp.func
    def each_div(a: _scalar, b: _scalar):
        """a / b, lane by lane for vectors."""
        return a / b

    @wp.func
    def lane0(x: _scalar):
        """x itself, or a vector's first lane: a value of the scalar type."""
        return x


for _lanes in (lanes64, lanes32):

    @wp.func
    def each_mul(a: _lanes, b: _lanes):  # noqa: F811
        return wp.cw_mul(a, b)

    @wp.func
    def each_div(a: _lanes, b: _lanes):  # noqa: F811
        return wp.cw_div(a, b)

    @wp.func
    def lane0(x: _lanes):  # noqa: F811
        return x[0]


@wp.func
def sinc_derivatives_recurrence(x: Any, sin_x: Any, cos_x: Any):
    """sinc and its first four derivatives at x by the upward recurrence (for |x| >=
    SINC_SERIES_SWITCH): differentiating x sinc(x) = sin(x) n times gives
    x s_n + n s_(n-1) = sin^(n)(x). Generic over a value and a vector of lanes."""
    inv = each_div(type(x)(1.0), x)
    s0 = each_mul(sin_x, inv)
    s1 = each_mul(cos_x - s0, inv)
    s2 = each_mul(-sin_x - type(lane0(x))(2.0) * s1, inv)
    s3 = each_mul(-cos_x - type(lane0(x))(3.0) * s2, inv)
    s4 = each_mul(sin_x - type(lane0(x))(4.0) * s3, inv)
    return s0, s1, s2, s3, s4


@wp.func
def sinc_derivatives_series(x: Any):
    """sinc and its first four derivatives at x by the series sinc = sum_k (-1)^k x^(2k) /
    (2k+1)! differentiated term by term (for |x| < SINC_SERIES_SWITCH: no 0/0, no cancellation
    at x = 0). Generic over a value and a vector of lanes."""
    one = type(lane0(x))(1.0)
    two = type(lane0(x))(2.0)
    three = type(lane0(x))(3.0)
    z = each_mul(x, x)
    s0 = type(x)(0.0)
    s1 = type(x)(0.0)
    s2 = type(x)(0.0)
    s3 = type(x)(0.0)
    s4 = type(x)(0.0)
    a = one  # (-1)^k / (2k+1)!
    p0 = type(x)(1.0)  # z^k
    p1 = type(x)(0.0)  # z^(k-1)
    p2 = type(x)(0.0)  # z^(k-2)
    for k in range(SINC_SERIES_TERMS):
        m = two * type(lane0(x))(float(k))  # the power 2k of x
        s0 = s0 + a * p0
        s1 = s1 + each_mul(a * m * x, p1)
        s2 = s2 + a * m * (m - one) * p1
        s3 = s3 + each_mul(a * m * (m - one) * (m - two) * x, p2)
        s4 = s4 + a * m * (m - one) * (m - two) * (m - three) * p2
        p2 = p1
        p1 = p0
        p0 = each_mul(p0, z)
        a = -a / ((m + two) * (m + three))
    return s0, s1, s2, s3, s4


@wp.func
def sinc_derivatives(x: Any):
    """sinc and its first four derivatives at x (unnormalised sinc, sin(x) / x): the upward
    recurrence for |x| >= SINC_SERIES_SWITCH, the series below it (the lane kernels compute
    both and select)."""
    if wp.abs(x) >= type(x)(SINC_SERIES_SWITCH):
        return sinc_derivatives_recurrence(x, wp.sin(x), wp.cos(x))
    return sinc_derivatives_series(x)


@wp.func
def scc_of(sinc_x: Any, cos_x: Any):
    """scc(x) = (4 sinc(x) - cos(x)) / 3, eq. (7) of the polar-banana paper, from sinc and cos."""
    return (type(sinc_x)(4.0) * sinc_x - cos_x) * type(sinc_x)(ONE_THIRD)


#: Cephes' atan rational approximation P(z^2) / Q(z^2) on |z| <= 0.66 (Q monic), accurate to
#: 2.3e-16 relative for atan2 over 2e6 random points (tests/models/test_consistency.py checks it).
ATAN_MOREBITS = 6.123233995736765886130e-17
HALF_PI = 1.5707963267948966
QUARTER_PI = 0.7853981633974483
PI = 3.141592653589793


@wp.func
def atan_unit(z: Any):
    """atan(z) for 0 <= z <= 1 (Cephes atan: above 0.66, atan(z) = pi/4 + atan((z-1)/(z+1)))."""
    one = type(z)(1.0)
    w = z
    offset = type(z)(0.0)
    if z > type(z)(0.66):
        w = (z - one) / (z + one)
        offset = type(z)(QUARTER_PI)
    s = w * w
    p = (((type(z)(-8.750608600031904122785e-1) * s + type(z)(-1.615753718733365076637e1)) * s
          + type(z)(-7.500855792314704667340e1)) * s + type(z)(-1.228866684490136173410e2)) * s + type(z)(-6.485021904942025371773e1)
    q = ((((s + type(z)(2.485846490142306297962e1)) * s + type(z)(1.650270098316988542046e2)) * s
          + type(z)(4.328810604912902668951e2)) * s + type(z)(4.853903996359136964868e2)) * s + type(z)(1.945506571482613964425e2)
    r = w + w * (s * p / q)
    if offset > type(z)(0.0):
        r = offset + (r + type(z)(0.5) * type(z)(ATAN_MOREBITS))
    return r


@wp.func
def atan2_fast(x: Any, y: Any):
    """atan2(x, y) (the angle of (y, x)) by one rational function: a third of libm's cost on the
    CPU, to 2 ulp. Gives 0 for x = y = 0."""
    ax = wp.abs(x)
    ay = wp.abs(y)
    a = type(x)(0.0)
    if ax <= ay:
        if ay > type(x)(0.0):
            a = atan_unit(ax / ay)
    else:
        a = type(x)(HALF_PI) - atan_unit(ay / ax)
    if y < type(x)(0.0):
        a = type(x)(PI) - a
    if x < type(x)(0.0):
        a = -a
    return a


#: atan(w) = w + w s R(s), s = w^2, for |w| <= tan(pi / 8): R's coefficients (lowest degree first),
#: a least-squares fit weighted by s (the weight of R's error in atan's) on 4,000 Chebyshev nodes,
#: refined against a long double reference. Degree 9 for float64: 3.8e-17 relative (0.35 ulp) at
#: worst on 400,000 points; degree 3 for float32: 2.1e-8 (0.36 ulp of float32).
TAN_PI_8 = 0.41421356237309503
ATAN_SERIES64 = (
    -0.3333333333333001, 0.1999999999906214, -0.14285714193374047, 0.1111110658589315, -0.09090781005954882,
    0.07690050372609125, -0.06640978875289538, 0.05691852889194422, -0.04357256748209664, 0.021238839921933202,
)
ATAN_SERIES32 = (-0.33332937955856323, 0.1997736096382141, -0.13874448835849762, 0.08044466376304626)  # float32 values
(ATAN_R0, ATAN_R1, ATAN_R2, ATAN_R3, ATAN_R4, ATAN_R5, ATAN_R6, ATAN_R7, ATAN_R8, ATAN_R9) = ATAN_SERIES64
(ATAN32_R0, ATAN32_R1, ATAN32_R2, ATAN32_R3) = ATAN_SERIES32
#: pi / 4 - QUARTER_PI (QUARTER_PI rounded to float64)
QUARTER_PI_LO = 3.061616997868383e-17


@wp.func
def atan_series(s: wp.float64):
    """R(s) of :data:`ATAN_SERIES64` by Horner's rule (float64: degree 9)."""
    p = wp.float64(ATAN_R9) * s + wp.float64(ATAN_R8)
    p = p * s + wp.float64(ATAN_R7)
    p = p * s + wp.float64(ATAN_R6)
    p = p * s + wp.float64(ATAN_R5)
    p = p * s + wp.float64(ATAN_R4)
    p = p * s + wp.float64(ATAN_R3)
    p = p * s + wp.float64(ATAN_R2)
    p = p * s + wp.float64(ATAN_R1)
    return p * s + wp.float64(ATAN_R0)


@wp.func
def atan_series(s: wp.float32):  # noqa: F811
    """R(s) of :data:`ATAN_SERIES32` by Horner's rule (float32: degree 3)."""
    p = wp.float32(ATAN32_R3) * s + wp.float32(ATAN32_R2)
    p = p * s + wp.float32(ATAN32_R1)
    return p * s + wp.float32(ATAN32_R0)


@wp.func
def atan2_one_division(x: Any, y: Any):
    """atan2(x, y) (the angle of (y, x) from the +y axis toward +x) with one division: with
    lo, hi = min, max of |x|, |y|, the quotient lo / hi, or (lo - hi) / (lo + hi) above
    lo = tan(pi / 8) hi (atan(lo / hi) = pi / 4 + atan of it), numerator and denominator selected
    first; then atan(w) = w + w s R(s) for |w| <= tan(pi / 8), R of each precision's own degree
    (:func:`atan_series`). Within 3 ulp in both precisions (``tests/kernels/test_lanes.py``: the
    reduced quotient's roundings, then pi / 4 + atan(w) cancels a bit); 0 for x = y = 0. The polar
    lane kernel takes the same steps (``lanes._angle_steps``), operation for operation, so that phi
    is the same bits."""
    zero = type(x)(0.0)
    ax = wp.abs(x)
    ay = wp.abs(y)
    lo = wp.min(ax, ay)
    hi = wp.max(ax, ay)
    num = lo
    den = hi
    reduced = lo > type(x)(TAN_PI_8) * hi
    if reduced:
        num = lo - hi
        den = lo + hi
    w = zero
    if hi > zero:
        w = num / den
    s = w * w
    a = w + w * (s * atan_series(s))
    if reduced:
        a = type(x)(QUARTER_PI) + (a + type(x)(QUARTER_PI_LO))
    if ax > ay:
        a = type(x)(HALF_PI) - a
    if y < zero:
        a = type(x)(PI) - a
    if x < zero:
        a = -a
    return a


@wp.func
def wrap_angle(d: Any):
    """Angle difference wrapped to [-pi, pi]."""
    two_pi = type(d)(2.0) * type(d)(PI)
    return d - two_pi * wp.floor((d + type(d)(PI)) / two_pi)


@wp.func
def normal_pdf(x: Any, mu: Any, sigma: Any):
    """g(x; mu, sigma) = exp(-((x - mu) / sigma)^2 / 2) / (sigma sqrt(2 pi))."""
    z = (x - mu) / sigma
    return type(x)(INV_SQRT_2PI) / sigma * wp.exp(type(x)(-0.5) * z * z)


@wp.func
def horner10(z: Any, c0: Any, c1: Any, c2: Any, c3: Any, c4: Any, c5: Any, c6: Any, c7: Any, c8: Any, c9: Any):
    """c0 + c1 z + ... + c9 z^9 by Horner's rule."""
    return c0 + z * (c1 + z * (c2 + z * (c3 + z * (c4 + z * (c5 + z * (c6 + z * (c7 + z * (c8 + z * c9))))))))


@wp.func
def series_c_over_u(z: Any):
    """C(u) / u as a series in z = u^2."""
    return horner10(z, type(z)(0.3333333333333333), type(z)(-0.03333333333333333), type(z)(0.0011904761904761906), type(z)(-2.2045855379188714e-05), type(z)(2.505210838544172e-07), type(z)(-1.9270852604185937e-09), type(z)(1.0706029224547743e-11), type(z)(-4.498331606952833e-14), type(z)(1.4797143443923793e-16), type(z)(-3.9145882126782523e-19))


@wp.func
def series_d(z: Any):
    """D(u) as a series in z = u^2."""
    return horner10(z, type(z)(0.5), type(z)(-0.125), type(z)(0.006944444444444444), type(z)(-0.00017361111111111112), type(z)(2.48015873015873e-06), type(z)(-2.296443268665491e-08), type(z)(1.4911969277048643e-10), type(z)(-7.169215998581078e-13), type(z)(2.6552651846596585e-15), type(z)(-7.809603484293113e-18))


@wp.func
def series_dc(z: Any):
    """C'(u) as a series in z = u^2."""
    return horner10(z, type(z)(0.3333333333333333), type(z)(-0.1), type(z)(0.005952380952380952), type(z)(-0.00015432098765432098), type(z)(2.2546897546897547e-06), type(z)(-2.1197937864604532e-08), type(z)(1.3917837991912066e-10), type(z)(-6.74749741042925e-13), type(z)(2.515514385467045e-15), type(z)(-7.437717604088679e-18))


@wp.func
def series_dd_over_u(z: Any):
    """D'(u) / u as a series in z = u^2."""
    return horner10(z, type(z)(-0.25), type(z)(0.027777777777777776), type(z)(-0.0010416666666666667), type(z)(1.984126984126984e-05), type(z)(-2.296443268665491e-07), type(z)(1.789436313245837e-09), type(z)(-1.0036902398013508e-11), type(z)(4.2484242954554536e-14), type(z)(-1.4057286271727604e-16), type(z)(0.0))


@wp.func
def cat_basis(u: Any):
    """The CAT position's dimensionless basis at u = omega t, eq. (1) of the polar-banana paper.

    With x, y as in eq. (1),  (x, y) = v0 t (A, B) + a t^2 (C, D)  where

        A = (1 - cos u) / u,          B = sin(u) / u,
        C = (sin u - u cos u) / u^2,  D = (cos u + u sin u - 1) / u^2,

    and dA/du = D, dB/du = -C. Returns (A, B, C, D, dC/du, dD/du); below SERIES_SWITCH the
    Taylor series are summed (no 0/0 at omega = 0, no cancellation):

        C  = sum_{n>=1} (-1)^(n+1) 2n u^(2n-1) / (2n+1)!
        D  = sum_{n>=1} (-1)^(n+1) (2n-1) u^(2n-2) / (2n)!
        C' = sum_{n>=1} (-1)^(n+1) 2n (2n-1) u^(2n-2) / (2n+1)!
        D' = sum_{n>=2} (-1)^(n+1) (2n-1) (2n-2) u^(2n-3) / (2n)!
    """
    one = type(u)(1.0)
    two = type(u)(2.0)
    half_u = u * type(u)(0.5)
    a_fn = wp.sin(half_u) * sinc(half_u)  # (1 - cos u) / u without cancellation
    b_fn = sinc(u)
    if wp.abs(u) < type(u)(SERIES_SWITCH):
        z = u * u
        return a_fn, b_fn, u * series_c_over_u(z), series_d(z), series_dc(z), u * series_dd_over_u(z)
    s = wp.sin(u)
    c = wp.cos(u)
    u2 = u * u
    u3 = u2 * u
    c_fn = (s - u * c) / u2
    d_fn = (c + u * s - one) / u2
    dc_fn = (u2 * s - two * s + two * u * c) / u3
    dd_fn = (u2 * c - two * c - two * u * s + two) / u3
    return a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn


@wp.func
def world_to_local(x: Any, y: Any, pose: Any):
    """World (east, north) to a model's local frame (+y along the heading, a bearing from
    north); ``pose`` = (origin x, origin y, cos heading, sin heading), an array or a vector."""
    dx = x - pose[0]
    dy = y - pose[1]
    return dx * pose[2] - dy * pose[3], dx * pose[3] + dy * pose[2]


@wp.func
def local_to_world(x: Any, y: Any, pose: Any):
    """A model's local frame to world (east, north): the inverse of :func:`world_to_local`."""
    return pose[0] + x * pose[2] + y * pose[3], pose[1] - x * pose[3] + y * pose[2]


# --- normal tails ----------------------------------------------------------------------------

#: 1 / sqrt(2)
INV_SQRT2 = 0.7071067811865476
#: Below this the exp(-x^2) (1 - erf) form of erfcx is used (Cephes: erf by T/U there).
ERFCX_SMALL = 1.0
#: Cephes switches from the (P, Q) to the (R, S) rational function of erfcx here.
ERFCX_LARGE = 8.0


@wp.func
def erfcx_pos(x: Any):
    """exp(x^2) erfc(x) for x >= 0 (Cephes ndtr.c): x < 1 via erf = x T(x^2) / U(x^2);
    1 <= x < 8: P(x) / Q(x); x >= 8: R(x) / S(x) (Q, S, U monic)."""
    one = type(x)(1.0)
    if x < type(x)(ERFCX_SMALL):
        z = x * x
        t = (((type(x)(9.60497373987051638749e0) * z + type(x)(9.00260197203842689217e1)) * z
              + type(x)(2.23200534594684319226e3)) * z + type(x)(7.00332514112805075473e3)) * z + type(x)(5.55923013010394962768e4)
        u = ((((z + type(x)(3.35617141647503099647e1)) * z + type(x)(5.21357949780152679795e2)) * z
              + type(x)(4.59432382970980127987e3)) * z + type(x)(2.26290000613890934246e4)) * z + type(x)(4.92673942608635921086e4)
        return wp.exp(z) * (one - x * t / u)
    if x < type(x)(ERFCX_LARGE):
        p = (((((((type(x)(2.46196981473530512524e-10) * x + type(x)(5.64189564831068821977e-1)) * x
                  + type(x)(7.46321056442269912687e0)) * x + type(x)(4.86371970985681366614e1)) * x
                + type(x)(1.96520832956077098242e2)) * x + type(x)(5.26445194995477358631e2)) * x
              + type(x)(9.34528527171957607540e2)) * x + type(x)(1.02755188689515710272e3)) * x + type(x)(5.57535335369399327526e2)
        q = (((((((x + type(x)(1.32281951154744992508e1)) * x + type(x)(8.67072140885989742329e1)) * x
                 + type(x)(3.54937778887819891062e2)) * x + type(x)(9.75708501743205489753e2)) * x
               + type(x)(1.82390916687909736289e3)) * x + type(x)(2.24633760818710981792e3)) * x
             + type(x)(1.65666309194161350182e3)) * x + type(x)(5.57535340817727675546e2)
        return p / q
    r = ((((type(x)(5.64189583547755073984e-1) * x + type(x)(1.27536670759978104416e0)) * x
           + type(x)(5.01905042251180477414e0)) * x + type(x)(6.16021097993053585195e0)) * x
         + type(x)(7.40974269950448939160e0)) * x + type(x)(2.97886665372100240670e0)
    s = (((((x + type(x)(2.26052863220117276590e0)) * x + type(x)(9.39603524938001434673e0)) * x
           + type(x)(1.20489539808096656605e1)) * x + type(x)(1.70814450747565897222e1)) * x
         + type(x)(9.60896809063285878198e0)) * x + type(x)(3.36907645100081516050e0)
    return r / s


@wp.func
def normal_sf(t: Any):
    """Q(t) = P(Z > t) for a standard normal, with relative accuracy in the upper tail:
    Q(t) = erfcx(t / sqrt 2) exp(-t^2 / 2) / 2 for t >= 0, 1 - Q(-t) below."""
    if t >= type(t)(0.0):
        return type(t)(0.5) * erfcx_pos(t * type(t)(INV_SQRT2)) * wp.exp(type(t)(-0.5) * t * t)
    u = -t
    return type(t)(1.0) - type(t)(0.5) * erfcx_pos(u * type(t)(INV_SQRT2)) * wp.exp(type(t)(-0.5) * u * u)


@wp.func
def normal_cdf(t: Any):
    """Phi(t) = Q(-t)."""
    return normal_sf(-t)


@wp.func
def normal_interval(t0: Any, t1: Any):
    """Phi(t1) - Phi(t0) for t0 <= t1, from the tail on the side away from zero (no
    cancellation of two numbers near one)."""
    if t0 >= type(t0)(0.0):
        return normal_sf(t0) - normal_sf(t1)
    if t1 <= type(t0)(0.0):
        return normal_sf(-t1) - normal_sf(-t0)
    return type(t0)(1.0) - normal_sf(-t0) - normal_sf(t1)
