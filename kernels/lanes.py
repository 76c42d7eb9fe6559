"""CPU lane arithmetic: eight float64 values per Warp vector, one AVX-512 register.

Warp compiles scalar kernel code to scalar instructions (``vmulsd``, a libm call per ``exp``).
Its vector types do compile to SIMD arithmetic, but Warp has no per-lane select, no
round-to-integer or bit-cast builtin and no vector sqrt, and helpers that loop over the lanes
for those left the polar kernel half scalar (62 Mcells/s on one core, against 116 with the
helpers below). The helpers are therefore ``wp.func_native`` snippets written with the
compiler's vector extension (``vector_size``), which give whole-register instructions
(``vblendmpd``, ``vsqrtpd``, ``vdivpd``; two ymm halves on a CPU without AVX-512). They are C++ for the CPU only: a kernel that calls
them lives in a module never launched on a GPU (the models bind them on the CPU alone).

Accuracy (``tests/test_lanes.py`` measures each over its reduced range and the whole domain
against long double references): :func:`lane_exp_neg` within 3 ulp, :func:`lane_atan2`
within 2 ulp (Cephes' rational function, as the scalar ``common.atan2_fast``).
"""

import warp as wp

#: Lanes per vector: 8 float64 = 512 bits.
LANES = 8
lanes64 = wp.types.vector(LANES, wp.float64)

_PROLOGUE = "typedef double d8 __attribute__((vector_size(64)));\n"
_EPILOGUE = "\nwp::vec_t<8, double> out; __builtin_memcpy(&out, &res, 64);\nreturn out;\n"


def _snippet(names: str, body: str) -> str:
    """A native body over ``d8`` copies of the vector arguments ``names`` that leaves ``res``."""
    copies = "".join(f"d8 v{n}; __builtin_memcpy(&v{n}, &{n}, 64);\n" for n in names.split())
    return _PROLOGUE + copies + body + _EPILOGUE


#: exp(x) for x <= 0 (0 below -745.2, where libm's exp is 0 too): Cody-Waite reduction
#: x = n ln2 + r, |r| <= ln2 / 2, with ln2 split in fdlibm's ln2_hi (33 bits, so n ln2_hi is
#: exact) and ln2_lo; n by the 1.5 * 2^52 shifter (round to nearest in one add); exp(r) by its
#: degree-12 Taylor polynomial (truncation below (ln2/2)^13 / 13! = 1.7e-16); 2^n as two
#: factors 2^(n/2) built from their exponent bits, so that results below 2^-1022 underflow
#: gradually to subnormals as libm's do (one factor 2^n would wrap its exponent there).
_EXP_NEG = _snippet("x", """
d8 zero = {};
d8 v = vx < -745.2 ? zero - 745.2 : vx;
const double shifter = 6755399441055744.0;
d8 n = (v * 1.4426950408889634 + shifter) - shifter;
d8 r = (v - n * 0.6931471803691238) - n * 1.9082149292705877e-10;
d8 p = r * 2.08767569878680989792e-09 + 2.50521083854417187751e-08;
p = p * r + 2.75573192239858906526e-07;
p = p * r + 2.75573192239858906526e-06;
p = p * r + 2.48015873015873015873e-05;
p = p * r + 1.98412698412698412698e-04;
p = p * r + 1.38888888888888888889e-03;
p = p * r + 8.33333333333333333333e-03;
p = p * r + 4.16666666666666666667e-02;
p = p * r + 1.66666666666666666667e-01;
p = p * r + 0.5;
p = p * r + 1.0;
p = p * r + 1.0;
typedef long long l8 __attribute__((vector_size(64)));
l8 whole = __builtin_convertvector(n, l8);
l8 half = whole >> 1;
d8 res = (p * (d8)((half + 1023) << 52)) * (d8)((whole - half + 1023) << 52);
res = vx < -745.2 ? zero : res;""")


@wp.func_native(_EXP_NEG)
def lane_exp_neg(x: lanes64) -> lanes64: ...


#: atan2(x, y), the angle of (y, x) from the +y axis toward +x, lane by lane; the same steps as
#: ``common.atan2_fast``/``atan_unit`` (Cephes: z = min/max of |x|, |y|; above 0.66 atan(z) =
#: pi/4 + atan((z - 1) / (z + 1)); P(s) / Q(s) in s = w^2), every branch a select.
_ATAN2 = _snippet("x y", """
d8 zero = {};
d8 ax = vx < 0.0 ? -vx : vx;
d8 ay = vy < 0.0 ? -vy : vy;
d8 big = ax > ay ? ax : ay;
d8 z = big > 0.0 ? (ax > ay ? ay : ax) / big : zero;
d8 w = z > 0.66 ? (z - 1.0) / (z + 1.0) : z;
d8 s = w * w;
d8 p = s * -8.750608600031904122785e-1 - 1.615753718733365076637e1;
p = p * s - 7.500855792314704667340e1;
p = p * s - 1.228866684490136173410e2;
p = p * s - 6.485021904942025371773e1;
d8 q = s + 2.485846490142306297962e1;
q = q * s + 1.650270098316988542046e2;
q = q * s + 4.328810604912902668951e2;
q = q * s + 4.853903996359136964868e2;
q = q * s + 1.945506571482613964425e2;
d8 a = w + w * (s * p / q);
a = z > 0.66 ? 0.7853981633974483 + (a + 3.0616169978683830e-17) : a;
a = ax > ay ? 1.5707963267948966 - a : a;
a = vy < 0.0 ? 3.141592653589793 - a : a;
d8 res = vx < 0.0 ? -a : a;""")


@wp.func_native(_ATAN2)
def lane_atan2(x: lanes64, y: lanes64) -> lanes64: ...


_SQRT = _snippet("x", "d8 res;\nfor (int k = 0; k < 8; ++k) res[k] = __builtin_sqrt(vx[k]);")


@wp.func_native(_SQRT)
def lane_sqrt(x: lanes64) -> lanes64: ...


#: sin(phi) / phi from a known sin(phi) (unnormalised sinc; 1 - phi^2 / 6 below |phi| = 1e-4,
#: as ``common.sinc_of``).
_SINC_OF = _snippet("phi sin_phi", """
d8 a = vphi < 0.0 ? -vphi : vphi;
d8 res = a < 1.0e-4 ? 1.0 - vphi * vphi / 6.0 : vsin_phi / vphi;""")


@wp.func_native(_SINC_OF)
def lane_sinc_of(phi: lanes64, sin_phi: lanes64) -> lanes64: ...


_WHERE_POSITIVE = _snippet("c a", "d8 zero = {};\nd8 res = vc > 0.0 ? va : zero;")


@wp.func_native(_WHERE_POSITIVE)
def lane_where_positive(c: lanes64, a: lanes64) -> lanes64: ...


@wp.func
def splat(value: wp.float64):
    """Every lane ``value``."""
    return lanes64(value)


@wp.func
def load_lanes(values: wp.array(dtype=wp.float64), start: int):
    """values[start .. start + 7], the index clamped to the last element past the end."""
    last = values.shape[0] - 1
    return lanes64(
        values[wp.min(start, last)], values[wp.min(start + 1, last)], values[wp.min(start + 2, last)],
        values[wp.min(start + 3, last)], values[wp.min(start + 4, last)], values[wp.min(start + 5, last)],
        values[wp.min(start + 6, last)], values[wp.min(start + 7, last)],
    )
