"""CPU lane arithmetic: a Warp vector of 8 float64 or 16 float32 values, one AVX-512 register.

Warp compiles scalar kernel code to scalar instructions (``vmulsd``, a libm call per ``exp``).
Its vector types do compile to SIMD arithmetic, but Warp has no per-lane select, no
round-to-integer or bit-cast builtin and no vector sqrt, and helpers that loop over the lanes
for those left the polar kernel half scalar (62 Mcells/s on one core, against 116 with the
helpers below). The helpers are therefore ``wp.func_native`` snippets written with the
compiler's vector extension (``vector_size``), which give whole-register instructions
(``vblendmpd``, ``vsqrtpd``, ``vdivpd``; two ymm halves on a CPU without AVX-512), each declared
for ``lanes64`` and ``lanes32`` from one template (Warp overloads them by argument type). They
are C++ for the CPU only: a kernel that calls them lives in a module never launched on a GPU
(the models bind them on the CPU alone). :func:`load_lanes` and :func:`store_lanes` move a whole
vector in one unaligned load or store where it lies in a contiguous array (lane by lane they
cost a third of the float32 kernel's time).

Warp compiles without contracting a * b + c into one fused multiply-add; the exp and sine
snippets ask for it (``#pragma clang fp contract(fast)``): their Horner steps become FMAs, one
rounding fewer each. The atan2 snippet does not: its rounding is then the scalar
``common.atan2_fast``'s, step for step. The polar density's angle (:func:`_angle_steps`) fuses
only its polynomial's Horner steps, damped by w s: within 1 ulp of the scalar kernel's
``common.atan2_one_division`` (measured: 68 of 400,000 angles differ, by 1 ulp).

Division without the divider (AVX-512: a 512-bit ``vdivpd`` occupies it 16 cycles, ``vsqrtpd``
longer): reciprocals, reciprocal square roots and correctly rounded quotients from the 14-bit
estimates (:func:`_reciprocal_steps`, :func:`_rsqrt_steps`, :func:`_quotient_steps`), which is how
the polar density takes its angle's one quotient with the division's bits. The polar density
without heading noise is one snippet (:func:`lane_polar_plain`) and a grid row one native loop
over ``CHAINS`` registers of lanes a step (:func:`polar_plain_row`), which also sums the row.
Without AVX-512 these snippets divide and take the square root (the same values but in the last
ulp of 1 / x and 1 / sqrt(x), and a / b exactly).

The CAT's single roots are searched a vector of lanes at a time by one snippet
(:func:`lane_cat_roots`: the scalar ``cat.cat_root_density``'s steps and proofs, with this
module's sine, exp and reciprocals), out of line once per dtype.

Accuracy (``tests/kernels/test_lanes.py`` measures each over its reduced range and the whole domain
against long double references): :func:`lane_exp` within 3 ulp (float64) and 2 ulp
(float32), :func:`lane_atan2` within 2 ulp (Cephes' rational function, as the scalar
``common.atan2_fast``), :func:`lane_sin` and :func:`lane_cos` within 2 ulp away from their zeros
and one unit of 1 absolute on [-pi, pi]; :func:`lane_sqrt` is correctly rounded, and
:func:`lane_quotient` the division's bits; :func:`lane_reciprocal` within 1 ulp and
:func:`lane_rsqrt` within 1.5 ulp; the wrap and the selects are exact.
"""

import dataclasses
import math
import re
from dataclasses import dataclass
from fractions import Fraction

import warp as wp

# the lane types live with the arithmetic generic over them (common.each_mul, ...)
from .common import (  # noqa: F401
    ATAN_SERIES32, ATAN_SERIES64, HALF_PI, LANES32, LANES64, PI, QUARTER_PI, QUARTER_PI_LO, TAN_PI_8, atan2_fast,
    lanes32, lanes64, wrap_angle,
)


@dataclass(frozen=True)
class _Format:
    """What the templates need of a lane format."""

    scalar: str  # C type of a lane
    integer: str  # C integer type of the same width
    lanes: int
    suffix: str  # of a C literal of the scalar type
    mantissa: int  # stored mantissa bits
    bias: int  # exponent bias
    ln2_hi: float  # ln 2 rounded so that n ln2_hi is exact for every n of the domain
    ln2_lo: float  # ln 2 - ln2_hi
    exp_floor: float  # below this exp(x) is 0 in the format
    exp_ceiling: float  # above this (ln of the largest finite value) exp(x) is inf
    infinity: str  # C expression of +inf in the format
    taylor: int  # degree of exp(r)'s Taylor polynomial on |r| <= ln2 / 2
    sqrt: str  # C builtins
    floor: str
    pio2: tuple  # pi / 2 in parts, each times |n| <= 3 exact: the sine's Cody-Waite reduction
    sin_coefficients: tuple  # Cephes' sin(r) = r + r^3 S(r^2) and cos(r) = 1 - r^2 / 2 + r^4 C(r^2)
    cos_coefficients: tuple  # on |r| <= pi / 4, highest degree first
    rcp14: str  # AVX-512 builtins: 14-bit estimates of 1 / x and 1 / sqrt(x), and their all-lanes mask
    rsqrt14: str
    mask: str
    newton: int  # Newton steps from a 14-bit estimate to the format's precision (14 -> 28 -> 56 bits)

    def literal(self, value: float) -> str:
        return f"{value!r}{self.suffix}"

    @property
    def bytes(self) -> int:
        """Bytes of a vector: 64, one AVX-512 register."""
        return self.lanes * (8 if self.scalar == "double" else 4)


# float64: fdlibm's ln2_hi has 33 significant bits, |n| <= 1075 needs 11; Taylor degree 12
# leaves (ln2/2)^13 / 13! = 1.7e-16. float32: fdlibm expf's ln2_hi has 16 bits, |n| <= 150
# needs 8; degree 7 leaves (ln2/2)^8 / 8! = 5.3e-9 (eps = 6e-8).
F64 = _Format("double", "long long", LANES64, "", 52, 1023, 6.93147180369123816490e-01, 1.90821492927058770002e-10,
              -745.2, 709.782712893384, "__builtin_huge_val()", 12, "__builtin_sqrt",
              "__builtin_floor", (1.57079632673412561417e+00, 6.07710050630396597660e-11, 2.02226624879595063154e-21),
              (1.58962301576546568060e-10, -2.50507477628578072866e-8, 2.75573136213857245213e-6,
               -1.98412698295895385996e-4, 8.33333333332211858878e-3, -1.66666666666666307295e-1),
              (-1.13585365213876817300e-11, 2.08757008419747316778e-9, -2.75573141792967388112e-7,
               2.48015872888517045348e-5, -1.38888888888730564116e-3, 4.16666666666665929218e-2),
              "__builtin_ia32_rcp14pd512_mask", "__builtin_ia32_rsqrt14pd512_mask", "(unsigned char)-1", 2)
F32 = _Format("float", "int", LANES32, "f", 23, 127, 6.9314575195e-01, 1.4286067653e-06, -104.0, 88.72283905206835,
             "__builtin_huge_valf()", 7, "__builtin_sqrtf", "__builtin_floorf",
             (1.5703125, 4.837512969970703125e-4, 7.54978995489188216e-8),
             (-1.9515295891e-4, 8.3321608736e-3, -1.6666654611e-1),
             (2.443315711809948e-5, -1.388731625493765e-3, 4.166664568298827e-2),
             "__builtin_ia32_rcp14ps512_mask", "__builtin_ia32_rsqrt14ps512_mask", "(unsigned short)-1", 1)


#: Lets the compiler fuse a * b + c in one snippet (the pragma must open its block).
CONTRACT = "#pragma clang fp contract(fast)\n"


def _estimates(fmt: _Format) -> str:
    """C lambdas over a ``vt`` of one AVX-512 register or of several (``fmt.bytes`` a multiple of
    64: each register on its own, the instructions side by side): ``rcp_est(d)`` and
    ``rsqrt_est(d)``, the 14-bit estimates of 1 / d and 1 / sqrt(d), and ``scale(p, n)``,
    p 2^n for integral n in one rounding (``vscalefpd`` / ``ps``: gradual underflow included)."""
    parts = fmt.bytes // 64
    step = fmt.lanes // parts
    kind = "pd" if fmt.scalar == "double" else "ps"

    def per_register(template: str, args: tuple[str, ...]) -> str:
        if parts == 1:
            return f"vt zero = {{}}; return {template.format(*args)};"
        pieces = "".join(
            f"vh p{k} = " + template.format(*(
                f"__builtin_shufflevector({a}, {a}, {', '.join(map(str, range(k * step, (k + 1) * step)))})"
                for a in args)) + "; " for k in range(parts))
        # join the pieces pairwise: a shuffle takes two vectors of the same size
        names, width = [f"p{k}" for k in range(parts)], step
        text = ""
        level = 0
        while len(names) > 1:
            level += 1
            text += f"typedef {fmt.scalar} vh{level} __attribute__((vector_size({64 * 2 ** level}))); "
            joined = []
            for k in range(0, len(names), 2):
                name = f"j{level}_{k // 2}"
                text += (f"vh{level} {name} = __builtin_shufflevector({names[k]}, {names[k + 1]}, "
                         f"{', '.join(map(str, range(2 * width)))}); ")
                joined.append(name)
            names, width = joined, 2 * width
        return f"vh zero = {{}}; {pieces}{text}return {names[0]};"
    return ("#if defined(__AVX512F__)\n"
            f"typedef {fmt.scalar} vh __attribute__((vector_size(64)));\n"
            f"auto rcp_est = [](vt d) -> vt {{ {per_register(fmt.rcp14 + '({0}, zero, ' + fmt.mask + ')', ('d',))} }};\n"
            f"auto rsqrt_est = [](vt d) -> vt {{ {per_register(fmt.rsqrt14 + '({0}, zero, ' + fmt.mask + ')', ('d',))} }};\n"
            f"auto scale = [](vt p, vt n) -> vt {{ {per_register(f'__builtin_ia32_scalef{kind}512_mask' + '({0}, {1}, zero, ' + fmt.mask + ', 4)', ('p', 'n'))} }};\n"
            "#endif\n")


def _snippet(fmt: _Format, names: str, body: str, contract: bool = False) -> str:
    """A native body over ``vt`` copies of the vector arguments ``names`` that leaves ``res``
    (``vt``: the lanes as a compiler vector; ``vi``: integers of the same width); ``L(value)``
    in ``body`` becomes a literal of the lane type; ``contract`` allows fused multiply-adds."""
    size = fmt.bytes
    head = ((CONTRACT if contract else "") +
            f"typedef {fmt.scalar} vt __attribute__((vector_size({size})));\n"
            f"typedef {fmt.integer} vi __attribute__((vector_size({size})));\n"
            "vt zero = {};\n")
    if "_est(" in body or "scale(" in body:  # the lambdas of _estimates
        head += _estimates(fmt)
    copies = "".join(f"vt v{n}; __builtin_memcpy(&v{n}, &{n}, {size});\n" for n in names.split())
    tail = f"\nwp::vec_t<{fmt.lanes}, {fmt.scalar}> out; __builtin_memcpy(&out, &res, {size});\nreturn out;\n"
    return head + copies + re.sub(r"L\(([^()]+)\)", lambda m: fmt.literal(float(m.group(1))), body) + tail


def _exp_steps(fmt: _Format, x: str, out: str, upper: bool = True, scalef: bool = False) -> str:
    """C statements leaving ``out`` = exp(``x``) (both ``vt``), in a block of their own: 0 below
    the format's floor (where libm's exp is 0 too), inf above its ceiling, NaN for NaN. Cody-Waite
    reduction x = n ln2 + r, |r| <= ln2 / 2, ln 2 split in two so that n ln2_hi is exact; n by the
    1.5 * 2^mantissa shifter (round to nearest in one add); exp(r) by its Taylor polynomial; 2^n
    as two factors 2^(n/2) built from their exponent bits, so that results below the smallest
    normal underflow gradually to subnormals as libm's do and n = 1024 (x near the ceiling) still
    has a factor (one factor 2^n would wrap its exponent). Without ``upper`` for an ``x`` known
    not positive (no test against the ceiling); with ``scalef`` (where :func:`_estimates`'
    lambdas are defined) p 2^n by one ``scale(p, n)`` on AVX-512: the two factors' bits (the
    first product is exact, each way rounds once), in one instruction instead of nine."""
    shifter = 1.5 * 2.0**fmt.mantissa
    floor, ceiling = f"L({fmt.exp_floor!r})", f"L({fmt.exp_ceiling!r})"
    horner = "".join(f"p = p * r + L({1.0 / math.factorial(k)!r});\n" for k in range(fmt.taylor - 2, -1, -1))
    clamp = (f"vt v = {x} < {floor} ? zero + {floor} : ({x} > {ceiling} ? zero + {ceiling} : {x});\n" if upper else
             f"vt v = {x} < {floor} ? zero + {floor} : {x};\n")
    return (
        f"vt {out};\n{{\n" + clamp +
        f"vt n = (v * L({1 / math.log(2)!r}) + L({shifter!r})) - L({shifter!r});\n"
        f"vt r = (v - n * L({fmt.ln2_hi!r})) - n * L({fmt.ln2_lo!r});\n"
        f"vt p = r * L({1.0 / math.factorial(fmt.taylor)!r}) + L({1.0 / math.factorial(fmt.taylor - 1)!r});\n"
        + horner
        + ("#if defined(__AVX512F__)\n" f"{out} = scale(p, n);\n" "#else\n" if scalef else "") +
        "vi whole = __builtin_convertvector(n, vi);\n"
        "vi half = whole >> 1;\n"
        f"{out} = (p * (vt)((half + {fmt.bias}) << {fmt.mantissa})) * (vt)((whole - half + {fmt.bias}) << {fmt.mantissa});\n"
        + ("#endif\n" if scalef else "") +
        f"{out} = {x} < {floor} ? zero : {out};\n"
        + (f"{out} = {x} > {ceiling} ? zero + {fmt.infinity} : {out};\n" if upper else "") + "}\n"
    )


#: atan2(x, y), the angle of (y, x) from the +y axis toward +x, lane by lane; the same steps as
#: ``common.atan2_fast``/``atan_unit`` (Cephes: z = min/max of |x|, |y|; above 0.66 atan(z) =
#: pi/4 + atan((z - 1) / (z + 1)); P(s) / Q(s) in s = w^2), every branch a select.
_ATAN2 = """vt ax = vx < 0 ? -vx : vx;
vt ay = vy < 0 ? -vy : vy;
vt big = ax > ay ? ax : ay;
vt z = big > 0 ? (ax > ay ? ay : ax) / big : zero;
vt w = z > L(0.66) ? (z - 1) / (z + 1) : z;
vt s = w * w;
vt p = s * L(-8.750608600031904122785e-1) + L(-1.615753718733365076637e1);
p = p * s + L(-7.500855792314704667340e1);
p = p * s + L(-1.228866684490136173410e2);
p = p * s + L(-6.485021904942025371773e1);
vt q = s + L(2.485846490142306297962e1);
q = q * s + L(1.650270098316988542046e2);
q = q * s + L(4.328810604912902668951e2);
q = q * s + L(4.853903996359136964868e2);
q = q * s + L(1.945506571482613964425e2);
vt a = w + w * (s * p / q);
a = z > L(0.66) ? L(0.7853981633974483) + (a + L(3.061616997868383e-17)) : a;
a = ax > ay ? L(1.5707963267948966) - a : a;
a = vy < 0 ? L(3.141592653589793) - a : a;
vt res = vx < 0 ? -a : a;"""

#: sin(phi) / phi from a known sin(phi) (unnormalised sinc; 1 - phi^2 / 6 below |phi| = 1e-4,
#: as ``common.sinc_of``).
_SINC_OF = """vt a = vphi < 0 ? -vphi : vphi;
vt res = a < L(1.0e-4) ? 1 - vphi * vphi / 6 : vsin_phi / vphi;"""

_WHERE_POSITIVE = "vt res = vc > 0 ? va : zero;"

_WHERE_NOT_NEGATIVE = "vt res = vc >= 0 ? va : vb;"

_ABS = "vt res = vx < 0 ? -vx : vx;"


def _horner(var: str, coefficients) -> str:
    """The polynomial with ``coefficients`` (highest degree first) in ``var``, nested."""
    text = f"L({coefficients[0]!r})"
    for c in coefficients[1:]:
        text = f"({text} * {var} + L({c!r}))"
    return text


def _sine(fmt: _Format, cosine: bool) -> str:
    """sin(x) or cos(x) for |x| <= 4 (enough for |x| <= pi): x = n pi/2 + r, |r| <= pi/4, by
    Cody-Waite with pi/2 in three parts (n by the shifter, as the exp); Cephes' polynomials of r;
    the quadrant n mod 4 picks +-sin r or +-cos r."""
    shifter = 1.5 * 2.0**fmt.mantissa
    p1, p2, p3 = (f"L({v!r})" for v in fmt.pio2)
    sin_poly, cos_poly = (_horner("z", c) for c in (fmt.sin_coefficients, fmt.cos_coefficients))
    pick = ("q == 0 ? c : (q == 1 ? -s : (q == 2 ? -c : s))" if cosine else
            "q == 0 ? s : (q == 1 ? c : (q == 2 ? -s : -c))")
    return _snippet(fmt, "x", contract=True, body=(
        f"vt n = (vx * L({2 / math.pi!r}) + L({shifter!r})) - L({shifter!r});\n"
        f"vt r = ((vx - n * {p1}) - n * {p2}) - n * {p3};\n"
        "vt z = r * r;\n"
        f"vt s = r + r * z * {sin_poly};\n"
        f"vt c = (1 - L(0.5) * z) + z * z * {cos_poly};\n"
        "vi q = __builtin_convertvector(n, vi) & 3;\n"
        f"vt res = {pick};"
    ))


def _sqrt(fmt: _Format) -> str:
    """sqrt lane by lane: a loop the compiler turns into one ``vsqrtpd`` / ``vsqrtps``."""
    return _snippet(fmt, "x", f"vt res;\nfor (int k = 0; k < {fmt.lanes}; ++k) res[k] = {fmt.sqrt}(vx[k]);")


def _reciprocal_steps(fmt: _Format, d: str, out: str, guard: bool = True) -> str:
    """C statements leaving ``out`` = 1 / ``d`` (both ``vt``). With AVX-512: the 14-bit estimate
    (``vrcp14pd`` / ``vrcp14ps``, a fraction of a division's cost: a 512-bit division occupies the
    divider 16 cycles) refined by Newton steps e = 1 - d x, x + x e (one for float32, two for
    float64: 14 -> 28 -> 56 bits), each step two fused multiply-adds; where a step gives NaN (d
    zero or infinite) the estimate stands (inf or 0, as the division gives); without ``guard``
    (where ``d`` is known finite and nonzero, or the result is selected away there) the NaN
    stays. Elsewhere: the division."""
    keep = f" {out} = next == next ? next : {out};" if guard else f" {out} = next;"
    steps = "".join(f"{{ vt e = 1 - {d} * {out}; vt next = {out} + {out} * e;{keep} }}\n" for _ in range(fmt.newton))
    return (f"vt {out};\n#if defined(__AVX512F__)\n{out} = rcp_est({d});\n{steps}"
            f"#else\n{out} = 1 / {d};\n#endif\n")


def _rsqrt_steps(fmt: _Format, x: str, out: str, guard: bool = True) -> str:
    """C statements leaving ``out`` = 1 / sqrt(``x``). With AVX-512: the 14-bit estimate
    (``vrsqrt14pd`` / ``ps``) and Newton steps e = 1 - (x y) y, y + (y / 2) e (as many as the
    reciprocal's; ``guard`` as :func:`_reciprocal_steps`'s: where a step gives NaN, x zero or
    infinite, the estimate stands, inf or 0). Elsewhere: a division by the correctly rounded square
    root. x y is then sqrt(x) to within about 1 ulp, without the ``vsqrtpd``/``vdivpd`` pair."""
    keep = f" {out} = next == next ? next : {out};" if guard else f" {out} = next;"
    steps = "".join(f"{{ vt e = 1 - ({x} * {out}) * {out}; vt next = {out} + ({out} * L(0.5)) * e;{keep} }}\n"
                    for _ in range(fmt.newton))
    return (f"vt {out};\n#if defined(__AVX512F__)\n{out} = rsqrt_est({x});\n{steps}"
            f"#else\nfor (int k = 0; k < {fmt.lanes}; ++k) {out}[k] = 1 / {fmt.sqrt}({x}[k]);\n#endif\n")


def _quotient_steps(fmt: _Format, a: str, b: str, out: str) -> str:
    """C statements leaving ``out`` = a / b correctly rounded (the division's bits) without the
    divider (a 512-bit ``vdivpd`` occupies it 16 cycles; these are 10 instructions on the FMA
    ports): the estimate y of 1 / b by ``newton`` + 1 Newton steps becomes RN(1 / b), the
    quotient q = RN(a y) is within 1 ulp, and Markstein's correction RN(q + (a - q b) y), the
    remainder exact by a fused multiply-add, is RN(a / b) (Markstein, IBM J. Res. Dev. 34 (1990);
    Cornea, Harrison and Tang, Scientific Computing on Itanium-based Systems (2002), th. 8.10).
    The one exception of the reciprocal step, a divisor whose significand is all ones, has odds
    of 2^-52. For b finite, nonzero and normal (the callers' divisors); explicit fused
    multiply-adds, so that the block's contraction setting does not matter. Without AVX-512:
    the division."""
    fma = "__builtin_elementwise_fma"
    steps = "".join(f"{{ vt e = {fma}(-{b}, inv_b, zero + 1); inv_b = {fma}(inv_b, e, inv_b); }}\n"
                    for _ in range(fmt.newton + 1))
    return (f"vt {out};\n#if defined(__AVX512F__)\n{{\nvt inv_b = rcp_est({b});\n{steps}"
            f"vt quo = {a} * inv_b;\n{out} = {fma}({fma}(-quo, {b}, {a}), inv_b, quo);\n}}\n"
            f"#else\n{out} = {a} / {b};\n#endif\n")


def _angle_steps(fmt: _Format, x: str, y: str, out: str) -> str:
    """C statements leaving ``out`` = atan2(``x``, ``y``) by ``common.atan2_one_division``'s steps:
    one quotient (:func:`_quotient_steps`: the division's bits), numerator and denominator selected
    first, then atan(w) = w + w s R(s), R of each precision's own degree (9 in float64, 3 in
    float32: ``common.atan_series``), every branch a select. Its Horner steps are fused
    multiply-adds (the scalar function rounds each product): their roundings are damped by w s,
    so that phi stays within 1 ulp of the scalar kernel's and is its bits at all but 1 in 6,000
    angles. The last step, w + w (s R), is not fused: phi feeds P_sigma, ill conditioned near its
    zero, and a fused one changed phi by an ulp at many more cells, moving the density 3.1e-13
    from the scalar kernel's there (``tests/kernels/test_lanes.py`` allows 1e-13)."""
    series = ATAN_SERIES64 if fmt.scalar == "double" else ATAN_SERIES32
    # the least normal number, and 2^(mantissa bits + 2): a subnormal times it is normal
    tiny, up = (2.0**-1022, 2.0**54) if fmt.scalar == "double" else (2.0**-126, 2.0**25)
    fma = "__builtin_elementwise_fma"
    horner = f"vt p = {fma}(s, zero + L({series[-1]!r}), zero + L({series[-2]!r}));\n" + "".join(
        f"p = {fma}(p, s, zero + L({c!r}));\n" for c in series[-3::-1])
    return (
        f"vt {out};\n{{\n#pragma clang fp contract(off)\nvt ux = {x}; vt uy = {y};\n"
        "vt ax = ux < 0 ? -ux : ux;\n"
        "vt ay = uy < 0 ? -uy : uy;\n"
        "vt lo = ax > ay ? ay : ax;\n"
        "vt hi = ax > ay ? ax : ay;\n"
        # subnormal pairs scaled by a power of two (exact): the reciprocal estimate of a subnormal
        # divisor is inf, and the quotient of the scaled pair is the same
        f"vt up = hi < L({tiny!r}) ? zero + L({up!r}) : zero + 1;\n"
        "lo = lo * up;\n"
        "hi = hi * up;\n"
        f"auto reduced = lo > L({TAN_PI_8!r}) * hi;\n"
        "vt num = reduced ? lo - hi : lo;\n"
        "vt den = reduced ? lo + hi : hi;\n"
        "den = hi > 0 ? den : zero + 1;\n"  # x = y = 0: num = 0, w = 0
        + _quotient_steps(fmt, "num", "den", "w") +
        "vt s = w * w;\n" + horner +
        "vt a = w + w * (s * p);\n"
        f"a = reduced ? L({QUARTER_PI!r}) + (a + L({QUARTER_PI_LO!r})) : a;\n"
        f"a = ax > ay ? L({HALF_PI!r}) - a : a;\n"
        f"a = uy < 0 ? L({PI!r}) - a : a;\n"
        f"{out} = ux < 0 ? -a : a;\n}}\n"
    )


def _polar_plain_steps(fmt: _Format, x: str, y: str, out: str) -> str:
    """C statements leaving ``out`` = the polar-banana density without heading noise
    (``polar.polar_density_local``'s maths) at the world points (``x``, ``y``), in a block of their
    own; the parameters are the scalars of ``lane_polar_plain``'s signature. One snippet, so that
    all of it is whole-register vector code with fused multiply-adds and its constants kept in
    registers across the row (the same formulas as Warp code compiled to half-register pieces,
    every multiply and add apart, and took twice as long). The world point to the model's frame; r
    and 1 / r from one reciprocal square root (:func:`_rsqrt_steps`); phi by
    :func:`_angle_steps`; sinc(phi) = (x / r) / phi by a reciprocal (1 - phi^2 / 6 below
    |phi| = 1e-4); with ``improved``: scc, the mean's correction (8) and P_sigma (11); 1 / sd by a
    reciprocal (once per call for the rough variant's constant sd); one exp for both normal
    factors. 0 at r = 0 and where sd is not positive."""
    third = f"L({1 / 3!r})"
    return (
        f"vt {out};\n{{\n"
        f"vt dx = {x} - ox;\n"
        f"vt dy = {y} - oy;\n"
        "vt lx = dx * c - dy * s;\n"
        "vt ly = dx * s + dy * c;\n"
        "vt r2 = lx * lx + ly * ly;\n"
        + _rsqrt_steps(fmt, "r2", "inv_r", guard=False) +  # r = NaN at r2 = 0: selected away below
        "vt r = r2 * inv_r;\n"
        + _angle_steps(fmt, "lx", "ly", "phi") +  # the scalar kernel's phi within 1 ulp
        "vt aphi = phi < 0 ? -phi : phi;\n"
        "vt phi_or_1 = aphi < L(1.0e-4) ? zero + 1 : phi;\n"
        + _reciprocal_steps(fmt, "phi_or_1", "inv_phi", guard=False) +  # |phi_or_1| >= 1e-4
        f"vt sinc = aphi < L(1.0e-4) ? 1 - (phi * phi) * L({1 / 6!r}) : (lx * inv_r) * inv_phi;\n"
        "vt mu = sinc * mean_sinc;\n"
        "vt inv_sd;\n"
        "vt sd = zero + sd_scale;\n"
        "if (improved) {\n"
        "  vt phi2 = phi * phi;\n"
        f"  vt scc = (sinc * 4 - ly * inv_r) * {third};\n"
        "  vt z2 = phi2 * (inv_sigma_phi * inv_sigma_phi);\n"
        "  mu = mu + ((z2 - 1) * mean_scc) * scc;\n"
        "  sd = ((1 + (sd_t_term - phi2 * inv_sigma_omega_sq) * sd_curvature) * sd_scale) * scc;\n"
        + "  " + _reciprocal_steps(fmt, "sd", "inv", guard=False).replace("\n", "\n  ").rstrip() + "\n"
        "  inv_sd = inv;\n"
        "} else {\n"
        "  inv_sd = zero + 1 / sd_scale;\n"
        "}\n"
        "vt z_phi = phi * inv_sigma_phi;\n"
        "vt z_r = (r - mu) * inv_sd;\n"
        "vt q = (z_phi * z_phi + z_r * z_r) * L(-0.5);\n"
        + _exp_steps(fmt, "q", "e", upper=False, scalef=True) +  # q <= 0
        "vt density = ((inv_sd * inv_r) * e) * norm;\n"
        f"{out} = sd > 0 ? (r > 0 ? density : zero) : zero;\n}}\n"
    )


#: Registers of lanes per step of ``polar_plain_row``: independent chains the core overlaps.
#: Figure 1 grid, float64, one core (Intel Xeon AVX-512): 1 register 10.0 ms a launch, 2: 8.98
#: ms a rasterise, 4: 6.75 ms, 8: 6.67 ms and float32 5.17 -> 6.39 ms (spills).
CHAINS = 4


def _wide_block(fmt: _Format, chains: int) -> tuple[_Format, str]:
    """The format of ``chains`` registers of ``fmt``'s lanes side by side, and the opening of a
    row loop's block over them: the vector types, a zero and the reciprocal estimates."""
    wide = dataclasses.replace(fmt, lanes=chains * fmt.lanes)
    return wide, ("{\n"
                  f"typedef {fmt.scalar} vt __attribute__((vector_size({wide.bytes})));\n"
                  f"typedef {fmt.integer} vi __attribute__((vector_size({wide.bytes})));\n"
                  "vt zero = {};\n" + _estimates(wide))


def _polar_plain_row(fmt: _Format) -> str:
    """out[row, j0 .. j1 - 1] = the density without heading noise at (xs[j], y): the grid
    kernel's row in one loop, with AVX-512 ``CHAINS`` registers of lanes a step (a ``vt`` of
    ``CHAINS * lanes``: every operation is that many instructions side by side, independent
    chains that the core overlaps; a chain one register wide left the core waiting on each
    step's latency, 7.4 ns a float64 cell), elsewhere one vector of ``lanes`` (two ymm halves
    already, and 16 registers would spill four). Lane by lane the same operations as
    :func:`lane_polar_plain`, so the same bits as the points kernel's; whole vectors loaded and
    stored where they lie in contiguous rows, else lane by lane (the index clamped to the last
    element, as ``load_lanes``). Returns the row's sum in float64: each lane position's values
    added in order as they are computed (while in registers: a pass over the grid after the
    kernel cost 12 % of a Figure 1 rasterise), then the positions in order, so that a row's sum
    depends on the row alone."""
    def loop(chains: int) -> str:
        wide, head = _wide_block(fmt, chains)
        size, n = wide.bytes, wide.lanes
        body = (
            head +
            f"typedef double vd __attribute__((vector_size({8 * n})));\n"
            "vd acc = {};\n"
            "vt vy = zero + y;\n"
            f"for (int j = j0; j < j1; j += {n}) {{\n"
            f"bool whole = contiguous && j + {n} <= j1;\n"
            "vt vx;\n"
            f"if (whole) {{ __builtin_memcpy(&vx, wp::address(xs, j), {size}); }}\n"
            f"else {{ for (int k = 0; k < {n}; ++k) {{ vx[k] = wp::index(xs, j + k < last ? j + k : last); }} }}\n"
            + _polar_plain_steps(wide, "vx", "vy", "res") +
            f"if (whole) {{ __builtin_memcpy(wp::address(out, row, j), &res, {size}); }}\n"
            f"else {{ for (int k = 0; k < {n}; ++k) {{ if (j + k < j1) {{ *wp::address(out, row, j + k) = res[k]; }} "
            "else { res[k] = 0; } } }\n"
            "acc += __builtin_convertvector(res, vd);\n"
            "}\n"
            f"double total = 0.0;\nfor (int k = 0; k < {n}; ++k) {{ total += acc[k]; }}\nreturn total;\n"
            "}\n"
        )
        return re.sub(r"L\(([^()]+)\)", lambda m: fmt.literal(float(m.group(1))), body)
    return (CONTRACT + "int last = xs.shape[0] - 1;\n"
            f"bool contiguous = xs.strides[0] == sizeof({fmt.scalar}) && out.strides[1] == sizeof({fmt.scalar});\n"
            f"#if defined(__AVX512F__)\n{loop(CHAINS)}#else\n{loop(1)}#endif\n")


def _wrap_angle(fmt: _Format) -> str:
    """d wrapped to [-pi, pi], d - 2 pi floor((d + pi) / (2 pi)) with the scalar
    ``bearing.wrap_angle``'s roundings; the floor loop becomes one ``vrndscalepd``."""
    two_pi, pi = "L(6.283185307179586)", "L(3.141592653589793)"
    return _snippet(fmt, "d", (
        f"vt q = (vd + {pi}) / {two_pi};\n"
        f"vt res;\nfor (int k = 0; k < {fmt.lanes}; ++k) res[k] = {fmt.floor}(q[k]);\n"
        f"res = vd - {two_pi} * res;"
    ))


def _scan_group(fmt: _Format) -> str:
    """The CAT scan's cheap test on one group of node intervals (``cat_lanes.node_groups``), as
    ``cat.cat_scan`` computes it: F = hx y - hy x - c at the group's nodes and at their
    predecessors, the chord bound (chord (w - w_prev)) (w - w_prev) + noise; bit k set where F
    changes sign over interval k or the smaller |F| at its ends is within the bound (of the
    first ``count`` intervals). One snippet, so that all of it is vector code."""
    size = fmt.bytes
    rows = "".join(f"vt r{i}; __builtin_memcpy(&r{i}, &wp::index(groups, {i}, g), {size});\n" for i in range(8))
    return (
        f"typedef {fmt.scalar} vt __attribute__((vector_size({size})));\n" + rows +
        "vt f = (r1 * y - r2 * x) - r3;\n"
        "vt f_prev = (r5 * y - r6 * x) - r7;\n"
        "vt spacing = r0 - r4;\n"
        "vt bound = (spacing * chord) * spacing + noise;\n"
        f"typedef {fmt.integer} vi __attribute__((vector_size({size})));\n"
        "vt a = f_prev < 0 ? -f_prev : f_prev;\n"
        "vt b = f < 0 ? -f : f;\n"
        "vi hit = ((f >= 0) != (f_prev >= 0)) | ((a < b ? a : b) <= bound);\n"
        f"int n = count < {fmt.lanes} ? count : {fmt.lanes};\n"
        "int flags = 0;\n"
        f"for (int k = 0; k < {fmt.lanes}; ++k) flags |= (hit[k] != 0) << k;\n"
        "return flags & ((1 << n) - 1);\n"
    )


def _tabulated_steps(fmt: _Format, x: str, y: str, out: str) -> str:
    """C statements leaving ``out`` = ``tabulated.table_density`` at the world points (``x``, ``y``),
    in a block of their own; the parameters are the scalars and arrays of ``lane_tabulated``'s
    signature. The world point to the model's frame (``common.world_to_local``'s arithmetic); r by
    the square root; the bearing by :func:`_angle_steps` (within 3 ulp, one division); the
    stencils' rows and columns clamped as the scalar kernel's (a NaN's to the first); the cubic
    Lagrange weights by ``tabulated.lagrange4``'s formulas; the 16 entries of each lane's stencil
    from the padded lattice (``tabulated.pad_table``: no remainder, no branch; with AVX-512 one
    gather instruction per entry and register), weighted in the scalar kernel's order; exp of the
    log sum where every entry is above the floor, else the linear sum clamped at zero. ``fmt``
    may be one register or two (:func:`_tabulated_row`'s chains)."""
    parts = fmt.bytes // 64
    assert parts in (1, 2, 4), "the gathers join one, two or four registers"
    double = fmt.scalar == "double"
    gather_builtin = "__builtin_ia32_gatherdiv8df" if double else "__builtin_ia32_gathersiv16sf"
    step = fmt.lanes // parts

    def gather(data: str, name: str) -> str:
        if parts == 1:
            native = f"{name} = {gather_builtin}(zero, {data}, at, {fmt.mask}, {8 if double else 4});\n"
        else:  # a gather per register, the pieces joined pairwise
            size = 8 if double else 4
            native = "{ " + "".join(
                f"gv g{k} = {gather_builtin}(gzero, {data}, (gi)__builtin_shufflevector(at, at, "
                f"{', '.join(map(str, range(k * step, (k + 1) * step)))}), {fmt.mask}, {size}); "
                for k in range(parts))
            names, width = [f"g{k}" for k in range(parts)], step
            while len(names) > 1:
                joined = [f"{names[k]}{names[k + 1]}" for k in range(0, len(names), 2)]
                native += "".join(f"auto {joined[k // 2]} = __builtin_shufflevector({names[k]}, {names[k + 1]}, "
                                  f"{', '.join(map(str, range(2 * width)))}); " for k in range(0, len(names), 2))
                names, width = joined, 2 * width
            native += f"{name} = {names[0]}; }}\n"
        return (f"vt {name};\n#if defined(__AVX512F__)\n{native}"
                f"#else\nfor (int k = 0; k < {fmt.lanes}; ++k) {name}[k] = {data}[at[k]];\n#endif\n")
    stencil = "".join(
        f"{{ vt w = wr{a} * wt{b}; vi at = off + ({a} * row + {b} * col);\n"
        + gather("tdata", "tv") + gather("ldata", "lv") +
        "lin = lin + w * tv; lsum = lsum + w * lv; lowest = tv < lowest ? tv : lowest; }\n"
        for a in range(4) for b in range(4))
    weights = "".join(
        f"vt {name}0 = -(f * (f - 1) * (f - 2)) * sixth;\n"
        f"vt {name}1 = (f + 1) * (f - 1) * (f - 2) * L(0.5);\n"
        f"vt {name}2 = -((f + 1) * f * (f - 2)) * L(0.5);\n"
        f"vt {name}3 = (f + 1) * f * (f - 1) * sixth;\n".replace("f", f) for name, f in (("wr", "fr"), ("wt", "ft")))
    return (
        f"vt {out};\n{{\n"
        + (f"typedef {fmt.scalar} gv __attribute__((vector_size(64)));\n"
           f"typedef {fmt.integer} gi __attribute__((vector_size(64)));\n"
           "gv gzero = {};\n" if parts > 1 else "") +
        f"vt dx = {x} - ox;\n"
        f"vt dy = {y} - oy;\n"
        "vt lx = dx * c - dy * s;\n"
        "vt ly = dx * s + dy * c;\n"
        "vt r2 = lx * lx + ly * ly;\n"
        f"vt r; for (int k = 0; k < {fmt.lanes}; ++k) r[k] = {fmt.sqrt}(r2[k]);\n"
        "vt u = (r - r0) / dr;\n"
        f"vt base; for (int k = 0; k < {fmt.lanes}; ++k) base[k] = {fmt.floor}(u[k]);\n"
        f"vt lo = zero + ({fmt.scalar})(mirror != 0 ? 0 : 1);\n"
        f"vt hi = zero + ({fmt.scalar})(table.shape[0] - 1 - 3);\n"
        "base = base >= lo ? base : lo;\n"  # a NaN to the first row
        "base = base <= hi ? base : hi;\n"
        "vt fr = u - base;\n"
        + _angle_steps(fmt, "lx", "ly", "angle") +
        "vt v = (angle - theta0) / dtheta;\n"
        f"vt column; for (int k = 0; k < {fmt.lanes}; ++k) column[k] = {fmt.floor}(v[k]);\n"
        "column = column >= -1 ? column : zero - 1;\n"
        f"vt last = zero + ({fmt.scalar})(table.shape[1] - 5);\n"  # n_theta: the padded columns less 2 + 3
        "column = column <= last ? column : last;\n"
        "vt ft = v - column;\n"
        "vt sixth = zero + L(1.0) / L(6.0);\n"
        + weights +
        f"const {fmt.scalar}* tdata = &wp::index(table, 0, 0);\n"
        f"const {fmt.scalar}* ldata = &wp::index(log_table, 0, 0);\n"
        f"{fmt.integer} row = ({fmt.integer})(table.strides[0] / sizeof({fmt.scalar}));\n"
        f"{fmt.integer} col = ({fmt.integer})(table.strides[1] / sizeof({fmt.scalar}));\n"
        # padded row of lattice row base - 1 is base; padded column of column - 1 is column + 1
        "vi off = __builtin_convertvector(base, vi) * row + (__builtin_convertvector(column, vi) + 1) * col;\n"
        "vt lin = zero; vt lsum = zero; vt lowest = zero + " + fmt.infinity + ";\n"
        + stencil
        + _exp_steps(fmt, "lsum", "e", upper=True)
        + "lin = lin > 0 ? lin : zero;\n"
        f"{out} = lowest > floor_value ? e : lin;\n}}\n"
    )


#: Registers of lanes per step of ``tabulated_row``, float64 and float32: independent chains that
#: the core overlaps (the bearing's and the exp's steps are long chains of dependent operations;
#: float64 four registers measured no faster than two, float32 two slower than one: spills).
TABLE_CHAINS = {"double": 2, "float": 1}


def _tabulated_row(fmt: _Format) -> str:
    """out[row, j0 .. j1 - 1] = ``tabulated.table_density`` at (xs[j], y): the grid kernel's row in
    one loop, with AVX-512 ``TABLE_CHAINS`` registers of lanes a step (as :func:`_polar_plain_row`;
    two float32 registers spilled), elsewhere one; lane by lane the operations of ``lane_tabulated`` (:func:`_tabulated_steps`), so
    the points kernel's bits."""
    def loop(chains: int) -> str:
        wide, head = _wide_block(fmt, chains)
        size, n = wide.bytes, wide.lanes
        body = (
            head +
            "vt vy = zero + y;\n"
            f"for (int j = j0; j < j1; j += {n}) {{\n"
            f"bool whole = contiguous && j + {n} <= j1;\n"
            "vt vx;\n"
            f"if (whole) {{ __builtin_memcpy(&vx, wp::address(xs, j), {size}); }}\n"
            f"else {{ for (int k = 0; k < {n}; ++k) {{ vx[k] = wp::index(xs, j + k < last_x ? j + k : last_x); }} }}\n"
            + _tabulated_steps(wide, "vx", "vy", "res") +
            f"if (whole) {{ __builtin_memcpy(wp::address(out, row, j), &res, {size}); }}\n"
            f"else {{ for (int k = 0; k < {n} && j + k < j1; ++k) {{ *wp::address(out, row, j + k) = res[k]; }} }}\n"
            "}\n}\n"
        )
        return re.sub(r"L\(([^()]+)\)", lambda m: fmt.literal(float(m.group(1))), body)
    return (CONTRACT + "int last_x = xs.shape[0] - 1;\n"
            f"bool contiguous = xs.strides[0] == sizeof({fmt.scalar}) && out.strides[1] == sizeof({fmt.scalar});\n"
            f"#if defined(__AVX512F__)\n{loop(TABLE_CHAINS[fmt.scalar])}#else\n{loop(1)}#endif\n")


def _cat_series():
    """The Taylor series of the CAT basis below ``common.SERIES_SWITCH`` in z = u^2, lowest
    degree first, ten terms each, from their terms' formulas (``common.series_c_over_u`` ..
    ``cat.series_dddd_over_u``): C / u, D, dC/du, (dD/du) / u, (d^2C/du^2) / u, d^2D/du^2,
    d^3C/du^3 and (d^3D/du^3) / u."""

    def series(first, odd, term, count=10):
        # sum_n (-1)^(n+1) term(n) u^(2n - 2 first) / (2n+1)! (odd) or / (2n)!
        return tuple(float(Fraction((-1) ** (n + 1) * term(n), math.factorial(2 * n + 1 if odd else 2 * n)))
                     for n in range(first, first + count))

    return (series(1, True, lambda n: 2 * n), series(1, False, lambda n: 2 * n - 1),
            series(1, True, lambda n: 2 * n * (2 * n - 1)),
            series(2, False, lambda n: (2 * n - 1) * (2 * n - 2), 9) + (0.0,),
            series(2, True, lambda n: 2 * n * (2 * n - 1) * (2 * n - 2)),
            series(2, False, lambda n: (2 * n - 1) * (2 * n - 2) * (2 * n - 3)),
            series(2, True, lambda n: 2 * n * (2 * n - 1) * (2 * n - 2) * (2 * n - 3)),
            series(3, False, lambda n: (2 * n - 1) * (2 * n - 2) * (2 * n - 3) * (2 * n - 4)))


#: The root search's step cap, ``cat.MAX_NEWTON`` (this module is below ``cat``'s).
CAT_MAX_NEWTON = 100

#: Largest |u| = |omega t| that :func:`lane_cat_roots` takes (n <= 6367 quarter turns in its
#: reductions, of u / 2 and in float32 of u): the Cody-Waite reduction's first two products
#: n pi/2 are exact for |n| < 2^22 in float64 and 2^13 in float32 (the parts hold 31 and 32, 8
#: and 11 bits); the callers search roots of wider turns by the scalar functions.
LANE_TURN_LIMIT = 1.0e4


def _cat_roots(fmt: _Format) -> str:
    """The single roots of F in each lane's [lo, hi] (F(lo), F(hi) of opposite sign) for the
    first ``count`` lanes: ``cat.cat_root_density``'s search and density (without evidence) as
    vector code, every branch a select, the lanes stepping until all have stopped.

    The scalar functions' steps: the Hermite start (``cat.hermite_root``); F, its derivatives
    and the acceleration (``cat.cat_eval_curved``) from the basis of ``cat.cat_basis_curved``
    (the series below |u| = 1 and the closed forms above, each computed where a lane needs it
    and selected), with sin and cos of u / 2 from one Cody-Waite reduction (pi / 2 in three
    parts; |u| below LANE_TURN_LIMIT) and Cephes' polynomials (those of :func:`lane_sin`), sin u
    and cos u from the half angle's (2 sin cos, (cos - sin)(cos + sin)) in float64 and by their
    own reduction in float32, and the closed forms' 1 / u^k as powers of one reciprocal;
    Halley's step with Newton's and bisection as fallbacks, the bracket, and the proof that ends
    a search at the Halley point (``cat.cat_root_step``); the density by the
    Taylor carry and one exp (``cat.cat_root_value``). Fused multiply-adds allowed. The values
    differ from the scalar search's in the last bits (the sine, exp and reciprocals are not
    libm's); the roots are the same roots of the same brackets."""
    c_over_u, d, dc, dd_over_u, ddc_over_u, ddd, dddc, dddd_over_u = (tuple(reversed(c)) for c in _cat_series())
    shifter = 1.5 * 2.0**fmt.mantissa
    p1, p2, p3 = (f"L({v!r})" for v in fmt.pio2)
    sin_poly, cos_poly = (_horner("r2", c) for c in (fmt.sin_coefficients, fmt.cos_coefficients))
    n = fmt.lanes
    inputs = "x y lo hi f_lo g_lo f_hi g_hi noise_g"
    pad = "".join(f"v{name} = live ? v{name} : zero + v{name}[0];\n" for name in inputs.split())
    index = "{" + ", ".join(str(k) for k in range(n)) + "}"
    sixth = f"L({1 / 6!r})"
    body = (
        # lanes past count: a copy of the first (finite values), never live
        f"vi lane = {index};\nvi live = lane < count;\n" + pad +
        "vt tt = zero + t; vt vv = zero + v0; vt tl = zero + tol;\n"
        "vt t2 = tt * tt;\nvt t4 = t2 * t2;\n"
        # cat_third_bound
        "vt rad = __builtin_elementwise_sqrt(vx * vx + vy * vy);\n"
        "vt m3 = t4 * tt * (rad * L(0.2) + vv * tt * L(0.05)) * L(1.01);\n"
        # hermite_root
        "vt width = vhi - vlo;\n"
        "vt span = vf_hi - vf_lo;\n"
        "vt gw_lo = vg_lo * width;\nvt gw_hi = vg_hi * width;\n"
        + _reciprocal_steps(fmt, "span", "inv_span") + _reciprocal_steps(fmt, "gw_lo", "inv_lo")
        + _reciprocal_steps(fmt, "gw_hi", "inv_hi") +
        "vt tau = -vf_lo * inv_span;\n"
        "vt d0 = span * inv_lo;\n"
        "vt d1 = span * inv_hi;\n"
        "vt tau2 = tau * tau;\nvt tau3 = tau2 * tau;\n"
        "vt st = (tau3 - 2 * tau2 + tau) * d0 + (3 * tau2 - 2 * tau3) + (tau3 - tau2) * d1;\n"
        "st = ((st >= 0) & (st <= 1)) ? st : (st > 1 ? zero + 1 : (st < 0 ? zero : tau));\n"
        "vt w = vlo + width * st;\n"
        "vt a = vlo; vt b = vhi; vt fa = vf_lo; vt e = zero;\n"
        "vt f = zero; vt df = zero; vt ddf = zero; vt dddf = zero; vt acc = zero; vt dacc = zero; vt ddacc = zero;\n"
        # cat_eval_curved at om, kept in the lanes of keep
        "auto eval = [&](vt om, vi keep) {\n"
        "  vt u = om * tt;\n"
        "  vt hu = u * L(0.5);\n"
        f"  vt nq = (hu * L({2 / math.pi!r}) + L({shifter!r})) - L({shifter!r});\n"
        f"  vt rr = ((hu - nq * {p1}) - nq * {p2}) - nq * {p3};\n"
        "  vt r2 = rr * rr;\n"
        f"  vt sr = rr + rr * r2 * {sin_poly};\n"
        f"  vt cr = (1 - L(0.5) * r2) + r2 * r2 * {cos_poly};\n"
        "  vi q = __builtin_convertvector(nq, vi) & 3;\n"
        "  vt sh = q == 0 ? sr : (q == 1 ? cr : (q == 2 ? -sr : -cr));\n"
        "  vt ch = q == 0 ? cr : (q == 1 ? -sr : (q == 2 ? -cr : sr));\n"
        + (
            # float32: sin u and cos u by their own reduction, to within 2 ulp (the half angle's
            # products add two roundings, which beside a fold float32 cannot spare)
            f"  vt nu = (u * L({2 / math.pi!r}) + L({shifter!r})) - L({shifter!r});\n"
            f"  vt ru = ((u - nu * {p1}) - nu * {p2}) - nu * {p3};\n"
            "  vt ru2 = ru * ru;\n"
            f"  vt su = ru + ru * ru2 * {sin_poly.replace('r2', 'ru2')};\n"
            f"  vt cu = (1 - L(0.5) * ru2) + ru2 * ru2 * {cos_poly.replace('r2', 'ru2')};\n"
            "  vi qu = __builtin_convertvector(nu, vi) & 3;\n"
            "  vt s = qu == 0 ? su : (qu == 1 ? cu : (qu == 2 ? -su : -cu));\n"
            "  vt c = qu == 0 ? cu : (qu == 1 ? -su : (qu == 2 ? -cu : su));\n"
            if fmt.scalar == "float" else
            "  vt s = 2 * sh * ch;\n"
            "  vt c = (ch - sh) * (ch + sh);\n"
        ) +
        "  vt au = u < 0 ? -u : u;\n"
        "  vt u_or_1 = au < L(1.0e-4) ? zero + 1 : u;\n"
        + _reciprocal_steps(fmt, "u_or_1", "iu", guard=False) +
        # sinc_of's small arguments: |u / 2| < 1e-4 and |u| < 1e-4
        f"  vt a_fn = au < L(2.0e-4) ? sh * (1 - hu * hu * {sixth}) : 2 * sh * sh * iu;\n"
        f"  vt b_fn = au < L(1.0e-4) ? 1 - u * u * {sixth} : s * iu;\n"
        "  vt z = u * u;\n"
        # the series where some lane is below the switch, the closed forms where some is above
        # (the lanes hold neighbouring cells' roots, most often on one side)
        "  vi closed = au >= L(1.0);\n"
        "  int n_closed = (int)-__builtin_reduce_add(closed);\n"
        "  vt c_fn = zero, d_fn = zero, dc_fn = zero, dd_fn = zero, ddc_fn = zero, ddd_fn = zero, dddc_fn = zero,"
        " dddd_fn = zero;\n"
        f"  if (n_closed < {n}) {{\n"
        f"    c_fn = u * {_horner('z', c_over_u)};\n"
        f"    d_fn = {_horner('z', d)};\n"
        f"    dc_fn = {_horner('z', dc)};\n"
        f"    dd_fn = u * {_horner('z', dd_over_u)};\n"
        f"    ddc_fn = u * {_horner('z', ddc_over_u)};\n"
        f"    ddd_fn = {_horner('z', ddd)};\n"
        f"    dddc_fn = {_horner('z', dddc)};\n"
        f"    dddd_fn = u * {_horner('z', dddd_over_u)};\n"
        "  }\n"
        "  if (n_closed > 0) {\n"
        "    vt i2 = iu * iu; vt i3 = i2 * iu; vt i4 = i2 * i2; vt i5 = i4 * iu;\n"
        "    vt u2 = z; vt u3 = u2 * u; vt u4 = u2 * u2;\n"
        "    c_fn = closed ? (s - u * c) * i2 : c_fn;\n"
        "    d_fn = closed ? (c + u * s - 1) * i2 : d_fn;\n"
        "    dc_fn = closed ? (u2 * s - 2 * s + 2 * u * c) * i3 : dc_fn;\n"
        "    dd_fn = closed ? (u2 * c - 2 * c - 2 * u * s + 2) * i3 : dd_fn;\n"
        "    ddc_fn = closed ? (u3 * c - 3 * u2 * s + 6 * s - 6 * u * c) * i4 : ddc_fn;\n"
        "    ddd_fn = closed ? (6 * c + 6 * u * s - u3 * s - 3 * u2 * c - 6) * i4 : ddd_fn;\n"
        "    dddc_fn = closed ? (24 * u * c - u4 * s - 4 * u3 * c + 12 * u2 * s - 24 * s) * i5 : dddc_fn;\n"
        "    dddd_fn = closed ? (24 - u4 * c - 24 * c - 24 * u * s + 4 * u3 * s + 12 * u2 * c) * i5 : dddd_fn;\n"
        "  }\n"
        # cat_line_terms and cat_eval_curved's derivatives
        "  vt fx = tt * a_fn; vt fy = tt * b_fn;\n"
        "  vt hx = t2 * c_fn; vt hy = t2 * d_fn;\n"
        "  vt dhx = t2 * tt * dc_fn; vt dhy = t2 * tt * dd_fn;\n"
        "  vt h2 = hx * hx + hy * hy;\n"
        "  vt cc = vv * (hx * fy - hy * fx);\n"
        "  vt dcc = vv * (dhx * fy - dhy * fx - h2);\n"
        "  vt ddhx = t4 * ddc_fn; vt ddhy = t4 * ddd_fn;\n"
        "  vt hh1 = hx * dhx + hy * dhy;\n"
        "  vt ddcc = vv * (ddhx * fy - ddhy * fx) - 3 * vv * hh1;\n"
        "  vt dddhx = t4 * tt * dddc_fn; vt dddhy = t4 * tt * dddd_fn;\n"
        "  vt hh2 = hx * ddhx + hy * ddhy;\n"
        "  vt h1h1 = dhx * dhx + dhy * dhy;\n"
        "  vt qx = vx - vv * fx; vt qy = vy - vv * fy;\n"
        + _reciprocal_steps(fmt, "h2", "inv_h2") +
        "  vt acc_n = (hx * qx + hy * qy) * inv_h2;\n"
        "  vt dacc_n = (dhx * qx + dhy * qy - 2 * acc_n * hh1) * inv_h2;\n"
        "  vt n2 = ddhx * qx + ddhy * qy - vv * (dhx * hy - dhy * hx);\n"
        "  f = keep ? hx * vy - hy * vx - cc : f;\n"
        "  df = keep ? dhx * vy - dhy * vx - dcc : df;\n"
        "  ddf = keep ? ddhx * vy - ddhy * vx - ddcc : ddf;\n"
        "  dddf = keep ? (dddhx * qy - dddhy * qx) + vv * (3 * h1h1 + 4 * hh2) : dddf;\n"
        "  acc = keep ? acc_n : acc;\n"
        "  dacc = keep ? dacc_n : dacc;\n"
        "  ddacc = keep ? (n2 - 4 * dacc_n * hh1 - 2 * acc_n * (h1h1 + hh2)) * inv_h2 : ddacc;\n"
        "};\n"
        # cat_root_step, MAX_NEWTON steps at most, until every lane has stopped (one evaluation
        # site: the snippet's size is its build time)
        "for (int it = 0; it <= MAX_NEWTON; ++it) {\n"
        "  eval(w, live);\n"
        "  if (it == MAX_NEWTON) break;\n"
        "  vi same = (f > 0) == (fa > 0);\n"
        "  a = (live & same) ? w : a;\n"
        "  fa = (live & same) ? f : fa;\n"
        "  b = (live & ~same) ? w : b;\n"
        "  vi slope = df != 0;\n"
        + _reciprocal_steps(fmt, "df", "inv_df") +
        "  vt step = f * inv_df;\n"
        "  vt bend = step * ddf * (L(0.5) * inv_df);\n"
        "  vt w_newton = w - step;\n"
        "  vt one_less = 1 - bend;\n"
        + _reciprocal_steps(fmt, "one_less", "inv_less") +
        "  vt w_halley = w - step * inv_less;\n"
        "  vt abend = bend < 0 ? -bend : bend;\n"
        "  vi halley_in = slope & (abend <= L(0.5)) & (w_halley > a) & (w_halley < b);\n"
        "  vi newton_in = slope & (w_newton > a) & (w_newton < b);\n"
        "  vt w_new = halley_in ? w_halley : (newton_in ? w_newton : (a + b) * L(0.5));\n"
        "  vt astep = step < 0 ? -step : step;\n"
        "  vt moved = w_new - w;\n"
        "  moved = moved < 0 ? -moved : moved;\n"
        "  vi stop = (f == 0) | (slope & (astep <= tl)) | (moved <= tl) | ((b - a) <= tl);\n"
        "  vt eh = w_halley - w;\n"
        "  vt q = f + eh * (df + L(0.5) * eh * ddf);\n"
        "  vt aeh = eh < 0 ? -eh : eh;\n"
        "  vt two_e = 2 * aeh;\n"
        "  vt adf = df < 0 ? -df : df;\n"
        "  vt addf = ddf < 0 ? -ddf : ddf;\n"
        "  vt aq = q < 0 ? -q : q;\n"
        "  vt dd = adf - addf * two_e;\n"
        f"  vt rho_d = aq + m3 * two_e * two_e * two_e * {sixth};\n"
        "  vt room = aeh < tl ? aeh : tl;\n"
        "  vt left = w_halley - a;\n"
        "  vt right = b - w_halley;\n"
        "  vt inner = left < right ? left : right;\n"
        "  room = room < inner ? room : inner;\n"
        "  vi proved = halley_in & ~stop & (dd > 0) & (rho_d < room * dd);\n"
        "  e = (live & proved) ? w_new - w : e;\n"
        "  live = live & ~(stop | proved);\n"
        "  w = live ? w_new : w;\n"
        "  if (!__builtin_reduce_or(live)) break;\n"
        "}\n"
        # cat_root_value
        "vt slope_r = df + e * (ddf + L(0.5) * e * dddf);\n"
        "vt acc_r = acc + e * (dacc + L(0.5) * e * ddacc);\n"
        "vt za = acc_r * (1 / sigma_a);\n"
        "vt zw = (w + e) * (1 / sigma_omega);\n"
        "vt arg = L(-0.5) * (za * za + zw * zw);\n"
        + _exp_steps(fmt, "arg", "g", upper=False, scalef=True) +
        "vt aslope = slope_r < 0 ? -slope_r : slope_r;\n"
        "aslope = aslope > vnoise_g ? aslope : vnoise_g;\n"
        + _reciprocal_steps(fmt, "aslope", "inv_slope") +
        f"vt res = (g * (L({1 / (2 * math.pi)!r}) / (sigma_a * sigma_omega))) * inv_slope;"
    )
    # one out-of-line body, however many call sites inline the snippet (each copy cost seconds of
    # build time)
    body = "vt res = [&]() __attribute__((noinline)) -> vt {\n" + body + "\nreturn res;\n}();"
    return _snippet(fmt, inputs, body.replace("MAX_NEWTON", str(CAT_MAX_NEWTON)), contract=True)


def _row_start(fmt: _Format) -> str:
    """out[row, j0 .. j1 - 1] = 0, and 1 where xs[j0 .. j1 - 1] is non-decreasing (no NaN), else
    0: two plain loops over contiguous memory, which the compiler turns into vector code (the
    same loops in Warp code index the arrays element by element: 5 ms of a 60 ms CAT grid)."""
    return (
        "int ok = 1;\n"
        f"if (xs.strides[0] == sizeof({fmt.scalar})) {{\n"
        f"  const {fmt.scalar}* x = wp::address(xs, 0);\n"
        "  for (int j = j0 + 1; j < j1; ++j) ok &= x[j] >= x[j - 1];\n"
        "} else {\n"
        "  for (int j = j0 + 1; j < j1; ++j) ok &= wp::index(xs, j) >= wp::index(xs, j - 1);\n"
        "}\n"
        f"if (j1 > j0 && out.strides[1] == sizeof({fmt.scalar})) {{\n"
        f"  {fmt.scalar}* o = wp::address(out, row, 0);\n"
        "  for (int j = j0; j < j1; ++j) o[j] = 0;\n"
        "} else {\n"
        "  for (int j = j0; j < j1; ++j) *wp::address(out, row, j) = 0;\n"
        "}\n"
        "return ok;\n"
    )


def _load(fmt: _Format) -> str:
    """values[start ..] as one vector: one unaligned vector load where the whole vector lies in a
    contiguous array, else lane by lane with the index clamped to the last element."""
    return (
        f"wp::vec_t<{fmt.lanes}, {fmt.scalar}> out;\n"
        f"if (start + {fmt.lanes} <= values.shape[0] && values.strides[0] == sizeof({fmt.scalar})) {{\n"
        f"  __builtin_memcpy(&out, wp::address(values, start), sizeof(out));\n"
        "} else {\n"
        "  int last = values.shape[0] - 1;\n"
        f"  for (int k = 0; k < {fmt.lanes}; ++k) {{ out[k] = wp::index(values, start + k < last ? start + k : last); }}\n"
        "}\n"
        "return out;\n"
    )


def _store(fmt: _Format) -> str:
    """out[start .. start + min(count, lanes) - 1] = the first lanes: one unaligned vector store
    where all of them go and the array is contiguous, else lane by lane."""
    return (
        f"int n = count < {fmt.lanes} ? count : {fmt.lanes};\n"
        f"if (n == {fmt.lanes} && out.strides[0] == sizeof({fmt.scalar})) {{\n"
        "  __builtin_memcpy(wp::address(out, start), &values, sizeof(values));\n"
        "} else {\n"
        "  for (int k = 0; k < n; ++k) { *wp::address(out, start + k) = values[k]; }\n"
        "}\n"
    )


# --- the lane functions, from the templates, for float64 (8 lanes) and float32 (16): Warp overloads
# each name by its argument types, so that one generic kernel calls either

for _fmt, _v, _s in ((F64, lanes64, wp.float64), (F32, lanes32, wp.float32)):

    @wp.func_native(_snippet(_fmt, "x", _exp_steps(_fmt, "vx", "res"), contract=True))
    def lane_exp(x: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "x y", _ATAN2))
    def lane_atan2(x: _v, y: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "x y", _angle_steps(_fmt, "vx", "vy", "res")))
    def lane_atan2_one_division(x: _v, y: _v) -> _v:
        """atan2(x, y) by ``common.atan2_one_division``'s steps (:func:`_angle_steps`), as the
        polar kernel takes phi."""
        ...

    @wp.func_native(_sqrt(_fmt))
    def lane_sqrt(x: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "phi sin_phi", _SINC_OF))
    def lane_sinc_of(phi: _v, sin_phi: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "x", _reciprocal_steps(_fmt, "vx", "res"), contract=True))
    def lane_reciprocal(x: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "a b", _quotient_steps(_fmt, "va", "vb", "res")))
    def lane_quotient(a: _v, b: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "x", _rsqrt_steps(_fmt, "vx", "res"), contract=True))
    def lane_rsqrt(x: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "c a", _WHERE_POSITIVE))
    def lane_where_positive(c: _v, a: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "x y", _polar_plain_steps(_fmt, "vx", "vy", "res"), contract=True))
    def lane_polar_plain(x: _v, y: _v, ox: _s, oy: _s, c: _s, s: _s, mean_sinc: _s, mean_scc: _s, sd_scale: _s,
                         sd_t_term: _s, sd_curvature: _s, inv_sigma_phi: _s, inv_sigma_omega_sq: _s, norm: _s,
                         improved: int) -> _v:
        """The polar-banana density without heading noise at the world points (x, y) (``_polar_plain_steps``)."""
        ...

    @wp.func_native(_polar_plain_row(_fmt))
    def polar_plain_row(xs: wp.array(dtype=_s), y: _s, out: wp.array2d(dtype=_s), row: int, j0: int, j1: int, ox: _s,
                        oy: _s, c: _s, s: _s, mean_sinc: _s, mean_scc: _s, sd_scale: _s, sd_t_term: _s,
                        sd_curvature: _s, inv_sigma_phi: _s, inv_sigma_omega_sq: _s, norm: _s,
                        improved: int) -> wp.float64:
        """out[row, j0 .. j1 - 1] = the density without heading noise at (xs[j], y); returns their
        float64 sum (``_polar_plain_row``)."""
        ...

    @wp.func_native(_wrap_angle(_fmt))
    def lane_wrap_angle(d: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "c a b", _WHERE_NOT_NEGATIVE))
    def lane_where_not_negative(c: _v, a: _v, b: _v) -> _v: ...

    @wp.func_native(_snippet(_fmt, "x", _ABS))
    def lane_abs(x: _v) -> _v: ...

    @wp.func_native(_sine(_fmt, cosine=False))
    def lane_sin(x: _v) -> _v: ...

    @wp.func_native(_sine(_fmt, cosine=True))
    def lane_cos(x: _v) -> _v: ...

    @wp.func_native(_scan_group(_fmt))
    def cat_scan_group(groups: wp.array2d(dtype=_v), g: int, x: _s, y: _s, chord: _s, noise: _s, count: int) -> int: ...

    @wp.func_native(_snippet(_fmt, "x y", _tabulated_steps(_fmt, "vx", "vy", "res"), contract=True))
    def lane_tabulated(x: _v, y: _v, log_table: wp.array2d(dtype=_s), table: wp.array2d(dtype=_s), r0: _s, dr: _s,
                       theta0: _s, dtheta: _s, floor_value: _s, mirror: int, ox: _s, oy: _s, c: _s, s: _s) -> _v:
        """The interpolated density of a padded polar lattice at the world points (x, y) (``_tabulated_steps``)."""
        ...

    @wp.func_native(_tabulated_row(_fmt))
    def tabulated_row(xs: wp.array(dtype=_s), y: _s, out: wp.array2d(dtype=_s), row: int, j0: int, j1: int,
                      log_table: wp.array2d(dtype=_s), table: wp.array2d(dtype=_s), r0: _s, dr: _s, theta0: _s,
                      dtheta: _s, floor_value: _s, mirror: int, ox: _s, oy: _s, c: _s, s: _s):
        """out[row, j0 .. j1 - 1] = the interpolated density at (xs[j], y) (``_tabulated_row``)."""
        ...

    @wp.func_native(f"return {_fmt.lanes};\n")
    def lane_count(values: wp.array(dtype=_s)) -> int:
        """Lanes in the vectors :func:`load_lanes` makes of ``values`` (8 float64, 16 float32)."""
        ...

    @wp.func_native(_load(_fmt))
    def load_lanes(values: wp.array(dtype=_s), start: int) -> _v:
        """values[start .. start + lanes - 1], the index clamped to the last element past the end."""
        ...

    @wp.func_native(_store(_fmt))
    def store_lanes(out: wp.array(dtype=_s), start: int, values: _v, count: int):
        """out[start + k] = values[k] for k < min(count, lanes)."""
        ...


# --- the CAT's root search, a vector of lanes a call (two registers a call, interleaved, measured
# no faster in float64 and 25 % slower in float32: Figure 1 grid, one core, Intel Xeon AVX-512)

for _fmt, _v, _s in ((F64, lanes64, wp.float64), (F32, lanes32, wp.float32)):

    @wp.func_native(_cat_roots(_fmt))
    def lane_cat_roots(x: _v, y: _v, lo: _v, hi: _v, f_lo: _v, g_lo: _v, f_hi: _v, g_hi: _v, noise_g: _v, v0: _s, t: _s,
                       sigma_a: _s, sigma_omega: _s, tol: _s, count: int) -> _v:
        """The density of the single root of F in each of the first ``count`` lanes' [lo, hi]
        (``_cat_roots``)."""
        ...

    @wp.func_native(_row_start(_fmt))
    def row_start(xs: wp.array(dtype=_s), out: wp.array2d(dtype=_s), row: int, j0: int, j1: int) -> int:
        """Zero out[row, j0 .. j1 - 1]; 1 where xs[j0 .. j1 - 1] is non-decreasing, else 0
        (``_row_start``)."""
        ...

    @wp.func_native(f"return wp::vec_t<{_fmt.lanes}, wp::int32>();\n")
    def lane_slots(x: _v) -> wp.types.vector(_fmt.lanes, wp.int32):
        """An integer for each lane of ``x`` (zeros)."""
        ...


# --- one name for a value and for lanes (as ``common.each_mul``), so that one generic body serves the
# scalar kernels (the GPU path's) and the lane kernels: the scalar function, or its lane snippet

for _s, _v in ((wp.float64, lanes64), (wp.float32, lanes32)):

    @wp.func(inline=True)
    def each_exp(x: _s):
        """exp(x): ``wp.exp``, or :func:`lane_exp` on lanes."""
        return wp.exp(x)

    @wp.func(inline=True)
    def each_exp(x: _v):  # noqa: F811
        return lane_exp(x)

    @wp.func(inline=True)
    def each_atan2(x: _s, y: _s):
        """atan2(x, y): ``common.atan2_fast``, or :func:`lane_atan2` (its steps) on lanes."""
        return atan2_fast(x, y)

    @wp.func(inline=True)
    def each_atan2(x: _v, y: _v):  # noqa: F811
        return lane_atan2(x, y)

    @wp.func(inline=True)
    def each_wrap_angle(d: _s):
        """d wrapped to [-pi, pi]: ``common.wrap_angle``, or :func:`lane_wrap_angle` on lanes."""
        return wrap_angle(d)

    @wp.func(inline=True)
    def each_wrap_angle(d: _v):  # noqa: F811
        return lane_wrap_angle(d)
