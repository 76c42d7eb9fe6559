"""Presence laws on angular cells and grids (Pessentheiner, Sections 7-9; ERRATA).

Cell probabilities of a Gaussian mixture
----------------------------------------
On the depth d (the plane z = -d) a cell is the annular sector rho in [d tau0, d tau1],
phi in [phi0, phi1] with tau = tan(pi - theta) (ERRATA: rho = -h tan(theta)). One bivariate
normal component, whitened by the inverse Cholesky factor B (Sigma = L L^T, B = L^-1), is along
the ray u = (cos phi, sin phi)

    (rho u - mu)^T Sigma^-1 (rho u - mu) = a (rho - m)^2 + k,
    a = |B u|^2,  m = (B u . B mu) / a,  k = ((B mu) x (B u))^2 / a  (squared distance of the
    whitened mean from the whitened ray; no cancellation),

so the polar integral of the density over rho (area element rho d rho) is closed form
(:func:`ray_moment`), exact at the nadir (rho0 = 0) and out to the horizon (rho1 = inf). The
phi integral of the remaining smooth function is Gauss-Kronrod (7, 15) on panels no wider than
two angular length scales of the component, refined fourfold until |K15 - G7| meets the
tolerance (the G7 error is a conservative estimate of the K15 error). A frustum cell (depths d
in [h - dh, h + dh]) adds a Gauss-Kronrod integral over d of the z marginal times the
conditional (x, y) law given z = -d (a full 3x3 covariance: the conditional mean moves linearly
with z), the same closed form inside.

Cells cut by the region S are integrated piece by piece between host-computed breakpoints in phi
(corners of S, circles of the cell's radii meeting S's edges), so every piece is smooth; on a
piece the rho range is [max(rho0, rho_in(phi)), min(rho1, rho_out(phi))], the ray's chord of
the box (:func:`ray_box`).

Rectangle probabilities
-----------------------
:func:`bvn_upper` is Genz's BVNU (Drezner & Wesolowsky 1989 with Genz's double-precision
changes; TVPACK): P(X > h, Y > k) for standard normals of correlation r, by 6/12/20-point
Gauss-Legendre in the correlation (nodes passed in ``bvn_rule``). A grid cell is a difference
of four such orthant probabilities, which cancels.

Shared corners (:func:`grid_cells`). :func:`bvn_rectangle` reflects each axis of a cell that
lies on one side of the component's mean so that the four orthants it differences are tail
values: with s = sign(a) and t = sign(b) (+ at 0) of a corner's standardised edges, the
corner's term is its *tail orthant* V(a, b) = P(s X > |a|, t Y > |b|) = BVNU(|a|, |b|, s t r),
a function of the corner alone, whichever of its four cells asks. So a grid evaluates each
corner's V once per component (a tile walks its rows keeping the row of corners below) and a
cell on one side of the mean on both axes is

    P = V(n_x, n_y) - V(f_x, n_y) - V(n_x, f_y) + V(f_x, f_y)      (n: near the mean, f: far),

the very expression :func:`bvn_rectangle` evaluates, on the same float64 numbers: the edges are
standardised by the same operations, and the nodes that depend on r alone come from one
function, :func:`bvn_node`, whether :func:`bvn_upper` asks for them per call or
:func:`bvn_node_table` tabulates them per component; a reflected orthant's correlation is -r,
and sin and asin are odd, so its nodes are these negated, exactly. The shared value therefore
equals the per-cell value bit for bit, and so does its error.

The cells that hold a component's mean coordinate on an axis (a0 < 0 <= a1, or the same in y)
are not differences of their corners' tail orthants: those face opposite ways, and the
complement that joins them brings in the 1-D tail Q(|b|) of the whole strip: for a0 < 0 <= a1
and 0 <= b0 < b1, P = [Q(b0) - V(a0, b0) - V(a1, b0)] - [Q(b1) - V(a0, b1) - V(a1, b1)], terms
of the size of Q(b0), which at strong correlation exceeds the cell by orders of magnitude
(r = -0.99, x in [-0.1, 0.3], y in [5, 5.1]: Q(5) = 2.9e-7 against a cell near 1e-240). These
cells, at most one row and one column of cells a component, are :func:`bvn_rectangle`'s own.
So every cell of a grid is the per-cell form's value (its bound: ``RECTANGLE_ABS_ERROR`` of
``bananagrid.models.presence``; tested in tests/models/test_presence_grid_corners.py), for one
tail orthant a component per cell (plus one row of corners a tile) instead of four, each also
without its sin per node, asin and normal tails. The cells are float64 whatever the output
dtype (why: ``grid_probabilities``' ``dtype``); only the stored values round to it.

Precision: normal tails come from :func:`kernels.common.erfcx_pos` (Cephes' ndtr.c), so upper
tails keep their relative accuracy far out.
"""

from typing import Any

import warp as wp

from .common import INV_SQRT2, erfcx_pos, normal_cdf, normal_interval, normal_sf
from .generate import ARRAY, ARRAY2D, SCALAR, overload_each

SQRT_2PI = 2.5066282746310002
SQRT_HALF_PI = 1.2533141373155003


#: ray_moment integrates by 8-point Gauss-Legendre when (t1 - t0)(1 + max|t|) is below this:
#: there the closed form's terms would cancel; the rule's error is below 1e-13 relative.
RAY_GAUSS_SWITCH = 1.0

#: Rows of ``rule`` (Gauss-Kronrod 15 and its embedded Gauss 7): nodes, Kronrod weights, Gauss
#: weights (0 where the node is Kronrod only).
GK_NODES = 15

# No adjoints: nothing differentiates these kernels. And the loops over the GK_NODES nodes of a
# panel stay loops: unrolled (Warp unrolls constant loops up to ``max_unroll``, 16 by default),
# each held 15 inlined copies of the ray integrals with their own unrolled 8-point rules, and
# the module's CUDA build took minutes (see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False, "max_unroll": GK_NODES - 1})

#: Layout of a 2-D (conditional) component row (bananagrid.models.presence._component_rows).
(C_LOGW, C_NORM, C_B11, C_B21, C_B22, C_V1, C_V2, C_MX, C_MY, C_SMIN, C_SMAX, C_VG1, C_VG2, C_MZ, C_SZ) = range(15)
COMPONENT_COLUMNS = 15


@wp.func
def mills_terms(t: Any):
    """For t >= 0: R(t) = Q(t) / phi(t) = sqrt(pi / 2) erfcx(t / sqrt 2) (Mills' ratio) and
    1 - t R(t) (in (0, 1]; it tends to 1 / t^2, so it keeps about 16 - 2 log10(t) digits)."""
    r = type(t)(SQRT_HALF_PI) * erfcx_pos(t * type(t)(INV_SQRT2))
    return r, type(t)(1.0) - t * r


@wp.func
def ray_moment(r0: Any, r1: Any, infinite: int, m: Any, s: Any, gl: wp.array2d(dtype=Any)):
    """J such that  int_{r0}^{r1} rho exp(-(rho - m)^2 / (2 s^2)) d rho = s^2 J,  0 <= r0 < r1
    (r1 = infinity when ``infinite``).

    With t = (rho - m) / s:  J = int_{t0}^{t1} (m / s + t) exp(-t^2 / 2) dt.
    * t0 >= 0: J = A(t0) - A(t1), A(t) = exp(-t^2/2) (rho R(t) / s + 1 - t R(t)), both terms
      >= 0 (R: Mills' ratio), so the upper tail keeps relative accuracy.
    * otherwise: J = (m / s) sqrt(2 pi) (Phi(t1) - Phi(t0)) + exp(-t0^2 / 2) - exp(-t1^2 / 2).
    * a short interval, (t1 - t0)(1 + max|t|) < RAY_GAUSS_SWITCH, where the terms above would
      cancel: 8-point Gauss-Legendre on the integrand itself (``gl``: nodes, weights).
    """
    zero = type(s)(0.0)
    half = type(s)(0.5)
    inv = type(s)(1.0) / s
    c = m * inv
    t0 = (r0 - m) * inv
    if infinite == 0:
        t1 = (r1 - m) * inv
        dt = (r1 - r0) * inv
        if dt * (type(s)(1.0) + wp.max(wp.abs(t0), wp.abs(t1))) < type(s)(RAY_GAUSS_SWITCH):
            mid = half * (t0 + t1)
            acc = zero
            for i in range(8):
                t = mid + half * dt * gl[0, i]
                acc += gl[1, i] * (c + t) * wp.exp(-half * t * t)
            return half * dt * acc
    if t0 >= zero:
        ra, ga = mills_terms(t0)
        a0 = wp.exp(-half * t0 * t0) * (r0 * inv * ra + ga)
        a1 = zero
        if infinite == 0:
            t1 = (r1 - m) * inv
            rb, gb = mills_terms(t1)
            a1 = wp.exp(-half * t1 * t1) * (r1 * inv * rb + gb)
        return a0 - a1
    e1 = zero
    q = zero
    if infinite == 0:
        t1 = (r1 - m) * inv
        e1 = wp.exp(-half * t1 * t1)
        if t1 <= zero:
            return c * type(s)(SQRT_2PI) * (normal_sf(-t1) - normal_sf(-t0)) + wp.exp(-half * t0 * t0) - e1
        q = normal_sf(t1)
    return c * type(s)(SQRT_2PI) * (type(s)(1.0) - normal_sf(-t0) - q) + wp.exp(-half * t0 * t0) - e1


@wp.func
def slab(lo: Any, hi: Any, c: Any, b0: Any, b1: Any):
    """[lo, hi] cut to where rho c lies in [b0, b1] (hi = -1 when c = 0 and 0 is outside)."""
    if c > type(c)(0.0):
        lo = wp.max(lo, b0 / c)
        hi = wp.min(hi, b1 / c)
    elif c < type(c)(0.0):
        lo = wp.max(lo, b1 / c)
        hi = wp.min(hi, b0 / c)
    elif b0 > type(c)(0.0) or b1 < type(c)(0.0):
        hi = type(c)(-1.0)
    return lo, hi


@wp.func
def ray_box(c: Any, s: Any, box: wp.array(dtype=Any)):
    """The chord [rho_in, rho_out] of the ray rho (c, s), rho >= 0, in the box
    [box0, box1] x [box2, box3] (rho_in > rho_out when the ray misses it)."""
    lo, hi = slab(type(c)(0.0), type(c)(1.0e30), c, box[0], box[1])
    return slab(lo, hi, s, box[2], box[3])


@wp.func
def ray_mass(
    c: Any, s: Any, lo: Any, hi: Any, infinite: int, comp: wp.array2d(dtype=Any), i: int,
    shift: Any, gl: wp.array2d(dtype=Any),
):
    """Mass per radian of component row i along the ray (c, s) between rho = lo and hi:
    norm exp(-k / 2) s^2 J (see the module notes). ``shift`` = z - mu_z moves the whitened mean
    by shift * (B g) (conditional law given z; 0 for a planar component)."""
    w1 = comp[i, C_B11] * c
    w2 = comp[i, C_B21] * c + comp[i, C_B22] * s
    v1 = comp[i, C_V1] + shift * comp[i, C_VG1]
    v2 = comp[i, C_V2] + shift * comp[i, C_VG2]
    a = w1 * w1 + w2 * w2
    cross = v1 * w2 - v2 * w1
    k = cross * cross / a
    if k > type(c)(1400.0):  # exp(-700): below every float64 tolerance
        return type(c)(0.0)
    m = (w1 * v1 + w2 * v2) / a
    sd = type(c)(1.0) / wp.sqrt(a)
    return comp[i, C_NORM] * wp.exp(type(c)(-0.5) * k) * sd * sd * ray_moment(lo, hi, infinite, m, sd, gl)


@wp.func
def sector_distance(mx: Any, my: Any, r0: Any, r1: Any, infinite: int, p0: Any, p1: Any):
    """Euclidean distance from (mx, my) to the annular sector r in [r0, r1], phi in [p0, p1]
    (a lower bound when p1 - p0 >= pi: then only the radial distance is used)."""
    zero = type(mx)(0.0)
    rr = wp.sqrt(mx * mx + my * my)
    radial = wp.max(zero, r0 - rr)
    if infinite == 0:
        radial = wp.max(radial, rr - r1)
    if p1 - p0 >= type(mx)(3.141592653589793):
        return radial
    psi = wp.atan2(my, mx)
    two_pi = type(mx)(6.283185307179586)
    rel = psi - p0 - two_pi * wp.floor((psi - p0) / two_pi)  # in [0, 2 pi)
    if rel <= p1 - p0:
        return radial
    best = type(mx)(1.0e30)
    for e in range(2):
        ang = p0
        if e == 1:
            ang = p1
        ce = wp.cos(ang)
        se = wp.sin(ang)
        proj = mx * ce + my * se
        lim = r1
        if infinite != 0:
            lim = type(mx)(1.0e30)
        proj = wp.min(wp.max(proj, r0), lim)
        dx = mx - proj * ce
        dy = my - proj * se
        best = wp.min(best, wp.sqrt(dx * dx + dy * dy))
    return best


@wp.func
def panel_count(width: Any, scale: Any, max_panels: int):
    """Panels of at most two length scales over ``width`` (at least 1, at most max_panels)."""
    if scale <= type(width)(0.0):
        return max_panels
    q = width / (type(width)(2.0) * scale)
    if q >= type(width)(max_panels):
        return max_panels
    return wp.max(1, int(wp.ceil(q)))


@wp.func
def depth_piece(
    da: Any, db: Any, panels: int, c: Any, s: Any, t0: Any, t1: Any, infinite: int,
    chord_lo: Any, chord_hi: Any, comp: wp.array2d(dtype=Any), i: int,
    rule: wp.array2d(dtype=Any), gl: wp.array2d(dtype=Any),
):
    """(K15, G7) over depth d in [da, db] of  g(-d; mu_z, sigma_z) x (conditional ray mass
    with rho in [max(d t0, chord_lo), min(d t1, chord_hi)])."""
    zero = type(da)(0.0)
    half_w = type(da)(0.5) * (db - da) / type(da)(float(panels))
    k_sum = zero
    g_sum = zero
    for p in range(panels):
        centre = da + (type(da)(2.0) * type(da)(float(p)) + type(da)(1.0)) * half_w
        for j in range(GK_NODES):
            d = centre + half_w * rule[0, j]
            lo = wp.max(d * t0, chord_lo)
            hi = chord_hi
            inf = infinite
            if infinite == 0:
                hi = wp.min(d * t1, chord_hi)
            elif chord_hi < type(da)(1.0e299):
                inf = 0
            v = zero
            if inf != 0 or hi > lo:
                z = -d
                u = (z - comp[i, C_MZ]) / comp[i, C_SZ]
                gz = type(da)(0.3989422804014327) / comp[i, C_SZ] * wp.exp(type(da)(-0.5) * u * u)
                v = gz * ray_mass(c, s, lo, hi, inf, comp, i, z - comp[i, C_MZ], gl)
            k_sum += rule[1, j] * v
            g_sum += rule[2, j] * v
    return k_sum * half_w, g_sum * half_w


@wp.func
def depth_integral(
    d0: Any, d1: Any, d_panels: int, c: Any, s: Any, t0: Any, t1: Any, infinite: int,
    chord_lo: Any, chord_hi: Any, comp: wp.array2d(dtype=Any), i: int,
    rule: wp.array2d(dtype=Any), gl: wp.array2d(dtype=Any),
):
    """(K, G) over d in [d0, d1], split where the rho range changes its active bound
    (d t0 or d t1 crossing the chord ends: up to four kinks)."""
    zero = type(d0)(0.0)
    k_tot = zero
    g_tot = zero
    cur = d0
    while cur < d1:
        nxt = d1
        for e in range(4):
            num = chord_lo
            if e >= 2:
                num = chord_hi
            den = t0
            if e == 1 or e == 3:
                den = t1
            if den > zero and (e < 2 or chord_hi < type(d0)(1.0e299)):
                if e % 2 == 0 or infinite == 0:
                    cand = num / den
                    if cand > cur and cand < nxt:
                        nxt = cand
        n = wp.max(1, int(wp.ceil(type(d0)(float(d_panels)) * (nxt - cur) / (d1 - d0))))
        kk, gg = depth_piece(cur, nxt, n, c, s, t0, t1, infinite, chord_lo, chord_hi, comp, i, rule, gl)
        k_tot += kk
        g_tot += gg
        cur = nxt
    return k_tot, g_tot


def _phi_piece(frustum: bool):
    """The Gauss-Kronrod sums over phi in [pa, pb] on ``panels`` panels of the plane's ray mass
    (rho in [r0, r1]) or (``frustum``) of the frustum's depth integral (rho in [d t0, d t1], d in
    [depth_lo, depth_hi] on ``d_panels``), each ray clipped to ``box`` where ``cut``: one body,
    the geometry's node compiled in (``wp.static``). Returns (k_tot, g_tot) with the piece's (K15,
    G7) added: the plane's piece summed first, the frustum's nodes added one by one."""

    def piece(
        k_tot: Any, g_tot: Any, pa: Any, pb: Any, panels: int, r0: Any, r1: Any, t0: Any, t1: Any, infinite: int,
        cut: int, box: wp.array(dtype=Any), comp: wp.array2d(dtype=Any), i: int, depth_lo: Any, depth_hi: Any,
        d_panels: int, rule: wp.array2d(dtype=Any), gl: wp.array2d(dtype=Any),
    ):
        zero = type(pa)(0.0)
        half_w = type(pa)(0.5) * (pb - pa) / type(pa)(float(panels))
        k_sum = zero
        g_sum = zero
        for p in range(panels):
            centre = pa + (type(pa)(2.0) * type(pa)(float(p)) + type(pa)(1.0)) * half_w
            for j in range(GK_NODES):
                phi = centre + half_w * rule[0, j]
                c = wp.cos(phi)
                s = wp.sin(phi)
                if wp.static(frustum):
                    chord_lo = zero
                    chord_hi = type(pa)(1.0e30)
                    if cut != 0:
                        chord_lo, chord_hi = ray_box(c, s, box)
                    if chord_hi > chord_lo:
                        kd, gd = depth_integral(depth_lo, depth_hi, d_panels, c, s, t0, t1, infinite, chord_lo,
                                                chord_hi, comp, i, rule, gl)
                        k_tot += half_w * rule[1, j] * kd
                        g_tot += half_w * rule[2, j] * gd
                else:
                    lo = r0
                    hi = r1
                    inf = infinite
                    if cut != 0:
                        bi, bo = ray_box(c, s, box)
                        lo = wp.max(lo, bi)
                        if inf != 0 or bo < hi:
                            hi = bo
                            inf = 0
                    v = zero
                    if inf != 0 or hi > lo:
                        v = ray_mass(c, s, lo, hi, inf, comp, i, zero, gl)
                    k_sum += rule[1, j] * v
                    g_sum += rule[2, j] * v
        if wp.static(frustum):
            return k_tot, g_tot
        return k_tot + k_sum * half_w, g_tot + g_sum * half_w

    return wp.func(piece, name=f"phi_piece_{'frustum' if frustum else 'plane'}")


def _cells_kernel(name: str, frustum: bool):
    """The cell kernel of the plane or (``frustum``) of the frustum: one body, the frustum's depth
    panels (``wp.static``) and depth integral (:func:`_phi_piece`) compiled in only for it."""
    phi_piece = _phi_piece(frustum)

    def cells(
        piece_start: wp.array(dtype=wp.int32),
        piece_a: wp.array(dtype=Any),
        piece_b: wp.array(dtype=Any),
        cut: wp.array(dtype=wp.int32),
        phi_lo: wp.array(dtype=Any),
        phi_hi: wp.array(dtype=Any),
        lo: wp.array(dtype=Any),
        hi: wp.array(dtype=Any),
        depth_lo: Any,
        depth_hi: Any,
        box: wp.array(dtype=Any),
        box_far: Any,
        comp: wp.array2d(dtype=Any),
        n_comp: int,
        rule: wp.array2d(dtype=Any),
        gl: wp.array2d(dtype=Any),
        rtol: Any,
        log_atol: Any,
        max_panels: int,
        start: int,
        prob: wp.array(dtype=Any),
        err: wp.array(dtype=Any),
        evals: wp.array(dtype=wp.int32),
    ):
        """Probability of cells ``start + tid``: phi in [phi_lo, phi_hi] split into the pieces
        piece_start[c] .. piece_start[c+1] (clipped to ``box`` where ``cut``); on the plane rho
        in [lo, hi], on the frustum depth d in [depth_lo, depth_hi] and rho in [d lo, d hi] (hi < 0:
        unbounded, the horizon). Writes the Kronrod sum over components, its error estimate sum
        |K - G| (tensor Gauss-Kronrod in (phi, d) on the frustum) and the panels used."""
        cell = start + wp.tid()
        zero = lo[cell] * type(rtol)(0.0)
        t0 = lo[cell]
        t1 = hi[cell]
        infinite = int(0)
        if t1 < zero:
            infinite = 1
        clip = cut[cell]
        p0 = phi_lo[cell]
        p1 = phi_hi[cell]
        total = zero
        error = zero
        used = int(0)
        # the cell's radii (on the frustum, its slab's: nearest and farthest)
        r0 = t0
        r1 = t1
        if wp.static(frustum):
            r0 = depth_lo * t0
            r1 = depth_hi * t1
        reach = type(rtol)(1.0e30)
        if infinite == 0:
            reach = r1
        if clip != 0:
            reach = wp.min(reach, box_far)
        for i in range(n_comp):
            # whole-cell skip: the component's mass beyond Euclidean distance D is below
            # exp(-(D / sigma_max)^2 / 2) (the Mahalanobis distance is at least D / sigma_max;
            # on the frustum that of the (x, y) marginal)
            dist = sector_distance(comp[i, C_MX], comp[i, C_MY], r0, r1, infinite, p0, p1) / comp[i, C_SMAX]
            if comp[i, C_LOGW] - type(rtol)(0.5) * dist * dist < log_atol:
                continue
            mu = wp.sqrt(comp[i, C_MX] * comp[i, C_MX] + comp[i, C_MY] * comp[i, C_MY])
            rel = wp.min(reach, mu + type(rtol)(9.0) * comp[i, C_SMAX])
            scale = type(rtol)(1.0e30)
            if rel > zero:
                scale = comp[i, C_SMIN] / rel
            d_scale = zero
            if wp.static(frustum):
                # depth scale: the z law's SD; the depth change that moves the whitened
                # conditional mean by one (1 / |B g|); the one that moves the outer arc (rate
                # tau_hi, capped by the reach) by the smallest conditional SD
                d_scale = comp[i, C_SZ]
                bg = wp.sqrt(comp[i, C_VG1] * comp[i, C_VG1] + comp[i, C_VG2] * comp[i, C_VG2])
                if bg > zero:
                    d_scale = wp.min(d_scale, type(rtol)(1.0) / bg)
                arc_rate = rel / depth_lo
                if infinite == 0:
                    arc_rate = wp.min(arc_rate, t1)
                if arc_rate > zero:
                    d_scale = wp.min(d_scale, comp[i, C_SMIN] / arc_rate)
            atol = wp.exp(log_atol)
            mult = int(1)
            while True:
                k_tot = zero
                g_tot = zero
                n_used = int(0)
                d_panels = int(1)
                if wp.static(frustum):
                    d_panels = wp.min(max_panels, panel_count(depth_hi - depth_lo, d_scale, max_panels) * mult)
                for q in range(piece_start[cell], piece_start[cell + 1]):
                    pa = piece_a[q]
                    pb = piece_b[q]
                    panels = wp.min(max_panels, panel_count(pb - pa, scale, max_panels) * mult)
                    k_tot, g_tot = phi_piece(k_tot, g_tot, pa, pb, panels, r0, r1, t0, t1, infinite, clip, box, comp, i,
                                             depth_lo, depth_hi, d_panels, rule, gl)
                    n_used += panels * d_panels
                e = wp.abs(k_tot - g_tot)
                if e <= rtol * wp.abs(k_tot) + atol or mult >= max_panels:
                    total += k_tot
                    error += e
                    used += n_used
                    break
                mult = mult * 4
        prob[cell] = total
        err[cell] = error
        evals[cell] = used

    kernel = wp.kernel(cells, name=name)
    overload_each(kernel, piece_a=ARRAY, piece_b=ARRAY, phi_lo=ARRAY, phi_hi=ARRAY, lo=ARRAY, hi=ARRAY,
                  depth_lo=SCALAR, depth_hi=SCALAR, box=ARRAY, box_far=SCALAR, comp=ARRAY2D, rule=ARRAY2D,
                  gl=ARRAY2D, rtol=SCALAR, log_atol=SCALAR, prob=ARRAY, err=ARRAY)
    return kernel


plane_cells = _cells_kernel("plane_cells", frustum=False)
frustum_cells = _cells_kernel("frustum_cells", frustum=True)


# --------------------------------------------------------------------------------------------
# Dense grids: density at centres and exact rectangle probabilities
# --------------------------------------------------------------------------------------------

#: Layout of a grid component row: weight, mean x, mean y, sd x, sd y, correlation, and the
#: whitening (B11, B21, B22) and density normaliser w / (2 pi det L).
(G_W, G_MX, G_MY, G_SX, G_SY, G_R, G_B11, G_B21, G_B22, G_NORM) = range(10)

#: Standardised edges are clamped to +-EDGE_CLAMP: beyond 38.5 SDs every normal tail is 0 in
#: float64, so no probability changes, and squares and products of edges stay finite.
EDGE_CLAMP = 1.0e30

#: Layout of a component's slab of ``bvn_nodes`` (shape (6, 20)): rows 0-4 per Gauss-Legendre
#: node (:func:`bvn_node`'s values), row 5 the component's scalars (BVN_KIND, BVN_N, BVN_ASR:
#: asin r, BVN_ASS: 1 - r^2, BVN_A: its square root).
(BVN_SN, BVN_W, BVN_RS, BVN_RS1, BVN_RS2) = range(5)
(BVN_KIND, BVN_N, BVN_ASR, BVN_ASS, BVN_A) = range(5)
BVN_SCALARS = 5
#: Columns of ``bvn_nodes``: the most Gauss-Legendre nodes of :func:`bvn_upper`'s rules.
BVN_NODES = 20
#: BVN_KIND: the correlation is 0 (product of tails), |r| < 0.925 (Drezner-Wesolowsky in
#: asin r), |r| >= 0.925 (Genz's expansion about r = +-1).
(BVN_PRODUCT, BVN_ASIN, BVN_NEAR_ONE) = range(3)


@wp.func
def bvn_rule_of(r: Any):
    """Genz's rule for correlation r: its nodes' row in ``bvn_rule`` and their count (6 points
    below |r| = 0.3, 12 below 0.75, 20 above)."""
    if wp.abs(r) < type(r)(0.3):
        return 0, 6
    if wp.abs(r) < type(r)(0.75):
        return 2, 12
    return 4, 20


@wp.func
def bvn_node(kind: int, asr: Any, half: Any, row: int, i: int, bvn_rule: wp.array2d(dtype=Any)):
    """Node i of :func:`bvn_upper`'s rule for a correlation r of ``kind`` (asr = asin r, half =
    sqrt(1 - r^2) / 2), the numbers that depend on r alone: (sin(asr (x_i + 1) / 2), w_i, 0, 0,
    0) of Drezner-Wesolowsky's rule, or Genz's (x^2, half w_i, sqrt(1 - x^2), 1 - that, 2 (1 +
    that)) with x = half (x_i + 1) near |r| = 1."""
    one = type(asr)(1.0)
    if kind == BVN_ASIN:
        zero = type(asr)(0.0)
        return wp.sin(type(asr)(0.5) * asr * (bvn_rule[row, i] + one)), bvn_rule[row + 1, i], zero, zero, zero
    xs = half * (bvn_rule[row, i] + one)
    xs = xs * xs
    rs = wp.sqrt(one - xs)
    return xs, half * bvn_rule[row + 1, i], rs, one - rs, type(asr)(2.0) * (one + rs)


@wp.func
def asin_term(sn: Any, w: Any, hk: Any, hs: Any):
    """A node's term of Drezner-Wesolowsky's integral in asin r (sn, w: :func:`bvn_node`)."""
    return w * wp.exp((sn * hk - hs) / (type(sn)(1.0) - sn * sn))


@wp.func
def genz_start(h: Any, kk: Any, hk: Any, ass: Any, a: Any):
    """Genz's expansion about |r| = 1 without its Gauss-Legendre part, for h, kk (k signed with r)
    and hk = h kk, ass = 1 - r^2, a = sqrt(ass); with the (bs, c, d) its nodes' terms take."""
    one = type(h)(1.0)
    bvn = type(h)(0.0)
    bs = (h - kk) * (h - kk)
    c = (type(h)(4.0) - hk) * type(h)(0.125)
    d = (type(h)(12.0) - hk) * type(h)(0.0625)
    asr = type(h)(-0.5) * (bs / ass + hk)
    if asr > type(h)(-100.0):
        bvn = a * wp.exp(asr) * (one - c * (bs - ass) * (one - d * bs / type(h)(5.0)) / type(h)(3.0)
                                 + c * d * ass * ass / type(h)(5.0))
    if -hk < type(h)(100.0):
        b = wp.sqrt(bs)
        bvn -= (wp.exp(type(h)(-0.5) * hk) * type(h)(SQRT_2PI) * normal_cdf(-b / a) * b
                * (one - c * bs * (one - d * bs / type(h)(5.0)) / type(h)(3.0)))
    return bvn, bs, c, d


@wp.func
def genz_add(bvn: Any, xs: Any, w: Any, rs: Any, rs1: Any, rs2: Any, bs: Any, hk: Any, c: Any, d: Any):
    """``bvn`` plus a node's term of Genz's expansion (xs, w, rs, rs1, rs2: :func:`bvn_node`)."""
    one = type(bvn)(1.0)
    asr = type(bvn)(-0.5) * (bs / xs + hk)
    if asr > type(bvn)(-100.0):
        return bvn + w * wp.exp(asr) * (wp.exp(-hk * rs1 / rs2) / rs - (one + c * xs * (one + d * xs)))
    return bvn


@wp.func
def bvn_upper(h: Any, k: Any, r: Any, bvn_rule: wp.array2d(dtype=Any)):
    """P(X > h, Y > k) for standard normals of correlation r (Genz's BVNU, TVPACK).

    ``bvn_rule`` rows (0, 1), (2, 3), (4, 5): nodes and weights of the 6-, 12- and 20-point
    Gauss-Legendre rules on [-1, 1] (zero-padded to 20 columns)."""
    zero = type(h)(0.0)
    one = type(h)(1.0)
    two_pi = type(h)(6.283185307179586)
    row, n = bvn_rule_of(r)
    hk = h * k
    bvn = zero
    if wp.abs(r) < type(h)(0.925):
        if wp.abs(r) > zero:
            hs = type(h)(0.5) * (h * h + k * k)
            asr = wp.asin(r)
            for i in range(n):
                sn, w, _rs, _rs1, _rs2 = bvn_node(BVN_ASIN, asr, zero, row, i, bvn_rule)
                bvn += asin_term(sn, w, hk, hs)
            bvn = bvn * asr / (type(h)(2.0) * two_pi)
        return bvn + normal_sf(h) * normal_sf(k)
    kk = k
    if r < zero:
        kk = -k
        hk = -hk
    if wp.abs(r) < one:
        ass = (one - r) * (one + r)
        a = wp.sqrt(ass)
        bvn, bs, c, d = genz_start(h, kk, hk, ass, a)
        half = type(h)(0.5) * a
        for i in range(n):
            xs, w, rs, rs1, rs2 = bvn_node(BVN_NEAR_ONE, zero, half, row, i, bvn_rule)
            bvn = genz_add(bvn, xs, w, rs, rs1, rs2, bs, hk, c, d)
        bvn = -bvn / two_pi
    if r > zero:
        return bvn + normal_sf(wp.max(h, kk))
    bvn = -bvn
    if kk > h:
        bvn += normal_interval(h, kk)
    return bvn


@wp.func
def bvn_rectangle(x0: Any, x1: Any, y0: Any, y1: Any, r: Any, bvn_rule: wp.array2d(dtype=Any)):
    """P(x0 < X < x1, y0 < Y < y1) for standard normals of correlation r, by inclusion and
    exclusion of upper orthants, after reflecting each axis so that the rectangle lies on the
    far side of its centre's sign (the orthant values are then tail values: small, with
    relative accuracy)."""
    rr = r
    a0 = x0
    a1 = x1
    b0 = y0
    b1 = y1
    if a0 + a1 < type(x0)(0.0):
        a0 = -x1
        a1 = -x0
        rr = -rr
    if b0 + b1 < type(x0)(0.0):
        b0 = -y1
        b1 = -y0
        rr = -rr
    return (bvn_upper(a0, b0, rr, bvn_rule) - bvn_upper(a1, b0, rr, bvn_rule)
            - bvn_upper(a0, b1, rr, bvn_rule) + bvn_upper(a1, b1, rr, bvn_rule))


@wp.kernel
def bvn_node_table(
    comp: wp.array2d(dtype=wp.float64),
    bvn_rule: wp.array2d(dtype=wp.float64),
    nodes: wp.array3d(dtype=wp.float64),
):
    """Node ``i`` of component ``c``'s correlation (launched on (components, BVN_NODES)):
    :func:`bvn_node` and the scalars, the numbers :func:`tail_orthant` reads instead of
    recomputing them per corner (the module notes)."""
    c, i = wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    r = comp[c, G_R]
    row, n = bvn_rule_of(r)
    kind = BVN_NEAR_ONE
    if r == zero:
        kind = BVN_PRODUCT
    elif wp.abs(r) < wp.float64(0.925):
        kind = BVN_ASIN
    ass = (one - r) * (one + r)
    a = wp.sqrt(wp.max(ass, zero))
    if i == 0:
        nodes[c, BVN_SCALARS, BVN_KIND] = wp.float64(float(kind))
        nodes[c, BVN_SCALARS, BVN_N] = wp.float64(float(n))
        nodes[c, BVN_SCALARS, BVN_ASR] = wp.asin(r)
        nodes[c, BVN_SCALARS, BVN_ASS] = ass
        nodes[c, BVN_SCALARS, BVN_A] = a
    if i < n and kind != BVN_PRODUCT:
        sn, w, rs, rs1, rs2 = bvn_node(kind, wp.asin(r), wp.float64(0.5) * a, row, i, bvn_rule)
        nodes[c, BVN_SN, i] = sn
        nodes[c, BVN_W, i] = w
        nodes[c, BVN_RS, i] = rs
        nodes[c, BVN_RS1, i] = rs1
        nodes[c, BVN_RS2, i] = rs2


@wp.func
def tail_orthant(a: Any, qa: Any, b: Any, qb: Any, c: int, nodes: wp.array3d(dtype=Any)):
    """The tail orthant V(a, b) of the corner (a, b) of component c's standardised edges (the
    module notes), given qa = Q(|a|) and qb = Q(|b|): :func:`bvn_upper` (|a|, |b|, s t r) with
    the correlation's nodes read from ``nodes`` (:func:`bvn_node_table`), the same operations on
    the same numbers."""
    zero = type(a)(0.0)
    one = type(a)(1.0)
    two_pi = type(a)(6.283185307179586)
    kind = int(nodes[c, BVN_SCALARS, BVN_KIND])
    if kind == BVN_PRODUCT:
        return zero + qa * qb
    h = wp.abs(a)
    k = wp.abs(b)
    sign = one
    if (a < zero and b >= zero) or (a >= zero and b < zero):
        sign = -one
    n = int(nodes[c, BVN_SCALARS, BVN_N])
    hk = h * k
    bvn = zero
    if kind == BVN_ASIN:
        hs = type(a)(0.5) * (h * h + k * k)
        for i in range(n):
            bvn += asin_term(sign * nodes[c, BVN_SN, i], nodes[c, BVN_W, i], hk, hs)
        bvn = bvn * (sign * nodes[c, BVN_SCALARS, BVN_ASR]) / (type(a)(2.0) * two_pi)
        return bvn + qa * qb
    # the orthant's correlation s t r: its sign decides Genz's form near |r| = 1
    if nodes[c, BVN_SCALARS, BVN_ASR] < zero:
        sign = -sign
    kk = k
    if sign < zero:
        kk = -k
        hk = -hk
    ass = nodes[c, BVN_SCALARS, BVN_ASS]
    if ass > zero:
        bvn, bs, cc, d = genz_start(h, kk, hk, ass, nodes[c, BVN_SCALARS, BVN_A])
        for i in range(n):
            bvn = genz_add(bvn, nodes[c, BVN_SN, i], nodes[c, BVN_W, i], nodes[c, BVN_RS, i], nodes[c, BVN_RS1, i],
                           nodes[c, BVN_RS2, i], bs, hk, cc, d)
        bvn = -bvn / two_pi
    if sign > zero:
        if h >= kk:
            return bvn + qa
        return bvn + qb
    return -bvn


@wp.func
def standardised(x: Any, mean: Any, sd: Any):
    """(x - mean) / sd, clamped to +-EDGE_CLAMP."""
    return wp.clamp((x - mean) / sd, type(x)(-EDGE_CLAMP), type(x)(EDGE_CLAMP))


@wp.kernel
def grid_edge_tails(
    edges: wp.array(dtype=wp.float64),
    comp: wp.array2d(dtype=wp.float64),
    std: wp.array2d(dtype=wp.float64),
    tail: wp.array2d(dtype=wp.float64),
):
    """Component c's standardised column edge j and its tail Q(|edge|) (launched on
    (components, edges))."""
    c, j = wp.tid()
    a = standardised(edges[j], comp[c, G_MX], comp[c, G_SX])
    std[c, j] = a
    tail[c, j] = normal_sf(wp.abs(a))


@wp.kernel
def grid_cells(
    x_edges: wp.array(dtype=Any),
    y_edges: wp.array(dtype=Any),
    row0: int,
    row1: int,
    tile_rows: int,
    tile_cols: int,
    slot0: int,
    comp: wp.array2d(dtype=Any),
    n_comp: int,
    bvn_rule: wp.array2d(dtype=Any),
    nodes: wp.array3d(dtype=Any),
    col_std: wp.array2d(dtype=Any),
    col_tail: wp.array2d(dtype=Any),
    below: wp.array3d(dtype=Any),
    acc: wp.array2d(dtype=Any),
    density: wp.array2d(dtype=Any),
    prob: wp.array2d(dtype=Any),
):
    """A tile of cells, ``tile_rows`` x ``tile_cols`` from row ``row0`` (tiles numbered across
    first; rows stop at ``row1``): the mixture's density at each cell centre and the exact
    probability of each rectangle [x_edges[j], x_edges[j+1]] x [y_edges[i], y_edges[i+1]],

        P_ij = sum_c w_c [V(n_x, n_y) - V(f_x, n_y) - V(n_x, f_y) + V(f_x, f_y)]

    with shared corners (the module notes): the tile walks its rows from south to north,
    evaluates each corner's tail orthant once per component and keeps the row of corners below in
    ``below[slot]`` (``slot0 + tid``; ``acc[slot]`` collects a row of cells over the components);
    a cell holding the component's mean coordinate on an axis is :func:`bvn_rectangle`'s.

    ``col_std`` holds component c's standardised column edges (clamped), ``col_tail`` their
    Q(|a|); every input and scratch array is float64 in every overload and only the stores
    convert to the dtype of ``density`` and ``prob``."""
    t = wp.tid()
    nx = x_edges.shape[0] - 1
    n_tiles_x = (nx + tile_cols - 1) // tile_cols
    tile_y = t // n_tiles_x
    j0 = (t - tile_y * n_tiles_x) * tile_cols
    j1 = wp.min(nx, j0 + tile_cols)
    i0 = row0 + tile_y * tile_rows
    i1 = wp.min(row1, i0 + tile_rows)
    slot = slot0 + t
    y_first = y_edges[i0]
    zero = type(y_first)(0.0)
    for c in range(n_comp):
        b = standardised(y_edges[i0], comp[c, G_MY], comp[c, G_SY])
        qb = normal_sf(wp.abs(b))
        for j in range(j0, j1 + 1):
            below[slot, c, j - j0] = tail_orthant(col_std[c, j], col_tail[c, j], b, qb, c, nodes)
    for i in range(i0 + 1, i1 + 1):
        for j in range(j0, j1):
            acc[slot, j - j0] = zero
        for c in range(n_comp):
            w = comp[c, G_W]
            r = comp[c, G_R]
            b0 = standardised(y_edges[i - 1], comp[c, G_MY], comp[c, G_SY])
            b1 = standardised(y_edges[i], comp[c, G_MY], comp[c, G_SY])
            qb = normal_sf(wp.abs(b1))
            row_holds_mean = b0 < zero and b1 >= zero
            left = tail_orthant(col_std[c, j0], col_tail[c, j0], b1, qb, c, nodes)
            below_left = below[slot, c, 0]
            below[slot, c, 0] = left
            for j in range(j0 + 1, j1 + 1):
                a0 = col_std[c, j - 1]
                a1 = col_std[c, j]
                v = tail_orthant(a1, col_tail[c, j], b1, qb, c, nodes)
                below_right = below[slot, c, j - j0]
                cell = zero
                if row_holds_mean or (a0 < zero and a1 >= zero):
                    cell = bvn_rectangle(a0, a1, b0, b1, r, bvn_rule)
                else:
                    # near and far corners on each axis, in bvn_rectangle's order
                    nn = below_left
                    fn = below_right
                    nf = left
                    ff = v
                    if a0 < zero:
                        nn = below_right
                        fn = below_left
                        nf = v
                        ff = left
                    if b0 < zero:
                        tn = nn
                        tf = fn
                        nn = nf
                        fn = ff
                        nf = tn
                        ff = tf
                    cell = nn - fn - nf + ff
                acc[slot, j - 1 - j0] += w * cell
                below[slot, c, j - j0] = v
                below_left = below_right
                left = v
        yc = type(zero)(0.5) * (y_edges[i - 1] + y_edges[i])
        for j in range(j0, j1):
            xc = type(zero)(0.5) * (x_edges[j] + x_edges[j + 1])
            dens = zero
            for c in range(n_comp):
                dx = xc - comp[c, G_MX]
                dy = yc - comp[c, G_MY]
                u1 = comp[c, G_B11] * dx
                u2 = comp[c, G_B21] * dx + comp[c, G_B22] * dy
                dens += comp[c, G_NORM] * wp.exp(type(zero)(-0.5) * (u1 * u1 + u2 * u2))
            density[i - 1, j] = density.dtype(dens)
            prob[i - 1, j] = prob.dtype(acc[slot, j - j0])


@wp.kernel
def rectangles(
    lims: wp.array2d(dtype=Any),
    bvn_rule: wp.array2d(dtype=Any),
    out: wp.array(dtype=Any),
):
    """P(l0 < X < l1, l2 < Y < l3) for standard normals of correlation l4, per row of ``lims``
    (float64 in every overload, as in :func:`grid_cells`; only the store takes ``out``'s dtype)."""
    k = wp.tid()
    out[k] = out.dtype(bvn_rectangle(lims[k, 0], lims[k, 1], lims[k, 2], lims[k, 3], lims[k, 4], bvn_rule))


@wp.kernel
def special_functions(
    xs: wp.array(dtype=Any),
    gl: wp.array2d(dtype=Any),
    out: wp.array2d(dtype=Any),
):
    """The device helpers at xs (for tests): erfcx(|x|), Q(x), Phi(x) - Phi(x - 1), Mills'
    1 - x R(x) for |x|, and J of ray_moment on [0, 1] (m = x, s = 1), on [|x|, inf)."""
    k = wp.tid()
    x = xs[k]
    ax = wp.abs(x)
    out[k, 0] = erfcx_pos(ax)
    out[k, 1] = normal_sf(x)
    out[k, 2] = normal_interval(x - type(x)(1.0), x)
    r, g = mills_terms(ax)
    out[k, 3] = g
    out[k, 4] = ray_moment(type(x)(0.0), type(x)(1.0), 0, x, type(x)(1.0), gl)
    out[k, 5] = ray_moment(ax, type(x)(0.0), 1, type(x)(0.0), type(x)(1.0), gl)


# registered when a run in that dtype loads the kernel (generate.use_overload); the grid's and
# the rectangles' geometry and arithmetic are float64 in both (cancellation, see grid_cells)
F64, F64_2D, F64_3D = wp.array(dtype=wp.float64), wp.array2d(dtype=wp.float64), wp.array3d(dtype=wp.float64)
overload_each(grid_cells, x_edges=F64, y_edges=F64, comp=F64_2D, bvn_rule=F64_2D, nodes=F64_3D, col_std=F64_2D,
              col_tail=F64_2D, below=F64_3D, acc=F64_2D, density=ARRAY2D, prob=ARRAY2D)
overload_each(rectangles, lims=F64_2D, bvn_rule=F64_2D, out=ARRAY)
overload_each(special_functions, xs=ARRAY, gl=ARRAY2D, out=ARRAY2D)
