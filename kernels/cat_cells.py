"""Exact-in-acceleration cell probabilities of the CAT model on a grid.

For a fixed turn rate omega the CAT position (eq. (1) of the polar-banana paper) is affine in
the acceleration: with u = omega t and z = a / sigma_a ~ N(0, 1),

    P(z) = v0 t (A(u), B(u)) + z sigma_a t^2 (C(u), D(u))    (local frame, see cat_basis),

a line in the plane along which z is standard normal. A cell that the line crosses between
z_in and z_out holds Phi(z_out) - Phi(z_in) of that turn rate's mass, exactly; the cell
probability is the integral of that over omega with the normal weight g(omega). The caustics,
where the density is infinite, are only where neighbouring lines touch: every line's share is
finite, so the cells there are exact in z like any other.

One kernel thread takes one interval of omega. Its lines are interpolated linearly between
the interval's two edge lines (a ribbon, narrower than a cell); both edge lines are clipped to
the grid (Liang-Barsky) and walked through the cells they cross in order (Amanatides-Woo), and
each cell they own gets the ribbon's mass there (``ribbon_cell``): the integral over omega,
piecewise between the turn rates whose lines pass a corner of the cell, by Gauss-Legendre. A
line's share is smooth between those passes, so the rule stays accurate where a midpoint rule
in omega is not: a line running along a cell side leaves the cell over a tiny change of omega.
Crossings are computed from the lines alone, not accumulated, so no step drifts and the
result does not depend on the bands. Always float64: a cell's share is a difference of two
normal tails.

Earlier evidence (:class:`Earlier`): a polygon at an earlier time s (an area searched then,
1 - POD inside; land, 0) weighs each path by where it was at s. For one omega the paths' points
at s form the line of omega at s, affine in the same z, so the polygon's edges cut the cell's
window [z_in, z_out] into pieces of constant weight, and the line's weighted share is the sum of
each piece's weight times its normal mass: exact in z (``weighted_share``). The earlier lines
are interpolated across the interval like the lines at t (``earlier_line``). Over omega the
share has kinks where an earlier line passes a polygon vertex and where a crossing enters or
leaves the window: breaks of the Gauss rule (``weighted_piece``). Sub-pieces whose earlier
points no polygon edge comes near take the plain terms times constant factors, so the evidence
costs only where it cuts, and without evidence the sums are the plain rule's bit for bit. On a
sub-piece that polygons cut, only the channels weighed by one of them take the split rule; the
others (the prior, the channels of other polygons) take the plain terms times constant factors,
so the prior channel is always the plain rule's terms, regrouped (equal to float64 rounding).
One pass fills several channels: channel c weighs by the polygons of the bit mask ``masks[c]``.
"""


import warp as wp

from .common import cat_basis, normal_interval, normal_pdf

# No adjoints: nothing differentiates these kernels, and the backward kernels Warp would
# generate for every launch kernel are most of a module's code (the CAT module's CUDA build:
# see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False})

#: Largest |z| walked: the normal mass beyond it, erfc(9 / sqrt 2) = 2.3e-19, is left out.
Z_MAX = 9.0
#: 3-point Gauss-Legendre on [-1, 1]: nodes 0, +-sqrt(3/5), weights 8/9 and 5/9 (module
#: constants: a literal inside a Warp function is a float32 constant).
GAUSS_NODE = 0.7745966692414834
GAUSS_CENTRE_WEIGHT = 8.0 / 9.0
GAUSS_SIDE_WEIGHT = 5.0 / 9.0
#: Largest move of z_in or z_out (standard deviations) over one Gauss sub-piece of a ribbon,
#: and the most sub-pieces between two corner passes (beyond, the move per sub-piece grows).
Z_PIECE = 0.25
MAX_PIECES = 64
#: Earlier evidence: most vertex passes and window events handled in one sub-piece (beyond,
#: the rest of the sub-piece takes one Gauss rule), and the halvings that place a window
#: event (to 2^-30 of the sub-piece: its kink then costs far below the rule's error).
MAX_EVENTS = 16
WINDOW_BISECTIONS = 30
#: Most polygons of the earlier evidence (a channel's polygons are the bits of an int).
MAX_POLYGONS = 30
VEC2 = wp.vec2d
VEC4 = wp.vec4d


@wp.func
def line_interval(start: wp.float64, step: wp.float64, i0: int, i1: int, lo: wp.float64, hi: wp.float64):
    """Narrow [lo, hi] of z to where start + z step lies in [i0, i1] (one axis of the clip;
    the same expression as :func:`next_crossing`, so a band's edge is crossed at the same z)."""
    if step == wp.float64(0.0):  # parallel: inside for i0 <= start < i1, the cell first_cell picks
        if start < wp.float64(float(i0)) or start >= wp.float64(float(i1)):
            return wp.float64(1.0), wp.float64(0.0)  # parallel and outside: empty
        return lo, hi
    z0 = (wp.float64(float(i0)) - start) / step
    z1 = (wp.float64(float(i1)) - start) / step
    return wp.max(lo, wp.min(z0, z1)), wp.min(hi, wp.max(z0, z1))


@wp.func
def first_cell(g: wp.float64, step: wp.float64, i0: int, i1: int):
    """Index in [i0, i1) of the cell a line enters at grid coordinate g moving by ``step`` per
    unit z (a line starting on an edge and moving down belongs to the cell below it)."""
    i = int(wp.floor(g))
    if step < wp.float64(0.0) and wp.float64(float(i)) == g:
        i = i - 1
    return wp.clamp(i, i0, i1 - 1)


@wp.func
def next_crossing(g0: wp.float64, step: wp.float64, i: int):
    """z where the line leaves cell i along one axis (infinite for a line parallel to it)."""
    if step > wp.float64(0.0):
        return (wp.float64(float(i + 1)) - g0) / step
    if step < wp.float64(0.0):
        return (wp.float64(float(i)) - g0) / step
    return wp.float64(1.0e300)


@wp.func
def world_line(omega: wp.float64, v0: wp.float64, t: wp.float64, sigma_a: wp.float64, pose: wp.array(dtype=wp.float64),
               x_edge: wp.float64, y_edge: wp.float64, dx: wp.float64, dy: wp.float64):
    """The line of turn rate ``omega`` in grid coordinates (world - edge) / cell size: its point
    at z = 0 and its step per unit z (world X = ox + x cos h + y sin h, Y = oy - x sin h + y cos h)."""
    u = omega * t
    a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn = cat_basis(u)
    px = v0 * t * a_fn
    py = v0 * t * b_fn
    qx = sigma_a * t * t * c_fn
    qy = sigma_a * t * t * d_fn
    ch = pose[2]
    sh = pose[3]
    gx = (pose[0] + px * ch + py * sh - x_edge) / dx
    gy = (pose[1] - px * sh + py * ch - y_edge) / dy
    return gx, gy, (qx * ch + qy * sh) / dx, (-qx * sh + qy * ch) / dy


@wp.func
def cell_clip(gx: wp.float64, gy: wp.float64, sx: wp.float64, sy: wp.float64, i: int, j: int):
    """[lo, hi] of z (within +-Z_MAX) where the line lies in cell (column i, row j)."""
    z_max = wp.float64(Z_MAX)
    lo, hi = line_interval(gx, sx, i, i + 1, -z_max, z_max)
    return line_interval(gy, sy, j, j + 1, lo, hi)


@wp.func
def corner_roots(gx: wp.float64, gy: wp.float64, sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64,
                 dsx: wp.float64, dsy: wp.float64, cx: wp.float64, cy: wp.float64, after: wp.float64, best: wp.float64):
    """The least s in (after, best) where the line (g + s dg, direction s_ + s ds) passes the
    corner (cx, cy): a root of the quadratic cross(direction, corner - point) = 0; else best."""
    rx = cx - gx
    ry = cy - gy
    c0 = sx * ry - sy * rx
    c1 = dsx * ry - sx * dgy - dsy * rx + sy * dgx
    c2 = dsy * dgx - dsx * dgy
    zero = wp.float64(0.0)
    scale = wp.abs(c0) + wp.abs(c1) + wp.abs(c2)
    if scale == zero:
        return best
    if wp.abs(c2) <= wp.float64(1.0e-14) * scale:  # linear: one root
        if c1 != zero:
            r = -c0 / c1
            if r > after and r < best:
                best = r
        return best
    disc = c1 * c1 - wp.float64(4.0) * c2 * c0
    if disc < zero:
        return best
    q = wp.float64(-0.5) * (c1 + wp.sign(c1) * wp.sqrt(disc))  # no cancellation (Numerical Recipes 5.6)
    if c1 == zero:
        q = wp.float64(-0.5) * wp.sqrt(disc)
    r1 = q / c2
    if r1 > after and r1 < best:
        best = r1
    if q != zero:
        r2 = c0 / q
        if r2 > after and r2 < best:
            best = r2
    return best


@wp.struct
class Earlier:
    """Evidence at earlier times whose weight is constant inside polygons (an area search at a
    time, land), in the grid coordinates of the walk, and the output channels.

    Polygon p has vertices ``verts[starts[p]:starts[p + 1]]`` and bounding box ``boxes[p]``
    (x0, x1, y0, y1); a path inside it at its time gets the factor ``miss[p]`` (1 - POD, or 0
    for land), outside 1. ``lines[p, k]`` is the line at polygon p's time of the turn rate
    ``edges[k]`` (point at z = 0 and step per unit z, :func:`world_line`). Channel c weights
    each path by the product of the factors of the polygons in the bit mask ``masks[c]``
    (0: the prior)."""

    lines: wp.array2d(dtype=wp.vec4d)
    starts: wp.array(dtype=int)
    verts: wp.array(dtype=wp.vec2d)
    boxes: wp.array(dtype=wp.vec4d)
    miss: wp.array(dtype=wp.float64)
    masks: wp.array(dtype=int)
    count: int
    channels: int


@wp.func
def earlier_line(ev: Earlier, p: int, k: int, s: wp.float64):
    """Polygon p's line at s in [0, 1] across turn-rate interval k: linear between the
    interval's edge lines, like the ribbon of lines at the map's time."""
    a = ev.lines[p, k]
    b = ev.lines[p, k + 1]
    return a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]), a[3] + s * (b[3] - a[3])


@wp.func
def point_in_polygon(ev: Earlier, p: int, x: wp.float64, y: wp.float64):
    """1 if (x, y) is inside polygon p (even-odd rule, as ``Polygon.contains``), else 0."""
    inside = int(0)
    v0 = ev.starts[p]
    v1 = ev.starts[p + 1]
    for v in range(v0, v1):
        a = ev.verts[v]
        w = v + 1
        if w == v1:
            w = v0
        b = ev.verts[w]
        if (a[1] > y) != (b[1] > y):
            if x < a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1]):
                inside = 1 - inside
    return inside


@wp.func
def edge_crossing(px: wp.float64, py: wp.float64, qx: wp.float64, qy: wp.float64, a: wp.vec2d, b: wp.vec2d):
    """Whether the line p + z q crosses the edge a-b, and at which z. The ends are sorted by
    the sign of cross(q, v - p) > 0 (the even-odd rule's half-open convention), so a line
    through a vertex crosses exactly one of its two edges, or both or neither where it only
    touches the polygon there: the parity of the crossings below any z is the inside test."""
    ca = qx * (a[1] - py) - qy * (a[0] - px)
    cb = qx * (b[1] - py) - qy * (b[0] - px)
    zero = wp.float64(0.0)
    if (ca > zero) == (cb > zero):
        return False, zero
    # p + z q = a + tau (b - a): z = cross(a - p, b - a) / cross(q, b - a), cross(q, b - a) = cb - ca
    return True, ((a[0] - px) * (b[1] - a[1]) - (a[1] - py) * (b[0] - a[0])) / (cb - ca)


@wp.func
def polygon_state(ev: Earlier, p: int, k: int, s: wp.float64, lo: wp.float64, hi: wp.float64):
    """For polygon p's line at s: 1 if its point at z = lo is inside (the parity of the
    crossings at or below lo), and how many crossings lie in (lo, hi)."""
    px, py, qx, qy = earlier_line(ev, p, k, s)
    if qx == wp.float64(0.0) and qy == wp.float64(0.0):  # the time of the last fix: one point
        return point_in_polygon(ev, p, px, py), 0
    inside = int(0)
    inner = int(0)
    v0 = ev.starts[p]
    v1 = ev.starts[p + 1]
    for v in range(v0, v1):
        w = v + 1
        if w == v1:
            w = v0
        hit, z = edge_crossing(px, py, qx, qy, ev.verts[v], ev.verts[w])
        if hit:
            if z <= lo:
                inside = 1 - inside
            elif z < hi:
                inner += 1
    return inside, inner


@wp.func
def mask_weight(ev: Earlier, mask: int):
    """The weight of a path inside the polygons of the bit mask ``mask``: the product of their
    factors (1 - POD, 0 on land)."""
    w = wp.float64(1.0)
    for p in range(ev.count):
        if (mask >> p) & 1 == 1:
            w = w * ev.miss[p]
    return w


@wp.func
def add_channels(ev: Earlier, inside: int, value: wp.float64, i: int, j: int, out: wp.array3d(dtype=wp.float64)):
    """Add ``value`` times each channel's weight of a path inside the polygons of the bit mask
    ``inside`` to cell (i, j) of every channel."""
    for c in range(ev.channels):
        out[c, j, i] += mask_weight(ev, ev.masks[c] & inside) * value


@wp.func
def add_cut_channels(ev: Earlier, cut: int, inside: int, value: wp.float64, i: int, j: int,
                     out: wp.array3d(dtype=wp.float64)):
    """:func:`add_channels` for the channels whose mask meets ``cut`` only (the others take the
    plain rule's terms for the sub-piece, :func:`add_uncut_channels`)."""
    for c in range(ev.channels):
        if ev.masks[c] & cut != 0:
            out[c, j, i] += mask_weight(ev, ev.masks[c] & inside) * value


@wp.func
def add_uncut_channels(ev: Earlier, cut: int, inside: int, value: wp.float64, i: int, j: int,
                       out: wp.array3d(dtype=wp.float64)):
    """:func:`add_channels` for the channels whose mask misses ``cut`` only: their weight is
    constant over a sub-piece that only ``cut``'s polygons cut (the prior's is 1)."""
    for c in range(ev.channels):
        if ev.masks[c] & cut == 0:
            out[c, j, i] += mask_weight(ev, ev.masks[c] & inside) * value


@wp.func
def weighted_share(ev: Earlier, active: int, base: int, k: int, s: wp.float64, lo: wp.float64, hi: wp.float64,
                   scale: wp.float64, i: int, j: int, out: wp.array3d(dtype=wp.float64)):
    """Add ``scale`` times the weighted normal mass of the line's piece [lo, hi] of z (in the
    cell) to every channel whose mask meets ``active`` (the others: :func:`ribbon_cell`): the earlier lines' crossings with the polygons (``active``'s bits;
    of the others, ``base``'s hold the whole window, the rest miss it) cut [lo, hi] into pieces
    of constant weight, each adding its weight times Phi(z_hi) - Phi(z_lo), exactly. The pieces
    are taken in order by finding the least crossing above the last (no sort, no buffer)."""
    inside = base
    inner = int(0)
    for p in range(ev.count):
        if (active >> p) & 1 == 1:
            flag, n = polygon_state(ev, p, k, s, lo, hi)
            inside = inside | (flag << p)
            inner += n
    z = lo
    for _ in range(inner + 1):
        z_next = hi
        toggle = int(0)
        if inner > 0:
            for p in range(ev.count):
                if (active >> p) & 1 == 1:
                    px, py, qx, qy = earlier_line(ev, p, k, s)
                    if qx != wp.float64(0.0) or qy != wp.float64(0.0):
                        v0 = ev.starts[p]
                        v1 = ev.starts[p + 1]
                        for v in range(v0, v1):
                            w = v + 1
                            if w == v1:
                                w = v0
                            hit, zc = edge_crossing(px, py, qx, qy, ev.verts[v], ev.verts[w])
                            if hit and zc > z and zc <= z_next:
                                if zc < z_next:
                                    z_next = zc
                                    toggle = int(0)
                                toggle = toggle ^ (1 << p)
        add_cut_channels(ev, active, inside, scale * normal_interval(z, z_next), i, j, out)
        if z_next >= hi:
            break
        inside = inside ^ toggle
        z = z_next


@wp.func
def patch_box(ev: Earlier, p: int, k: int, s0: wp.float64, s1: wp.float64, z0: wp.float64, z1: wp.float64):
    """The box (x_lo, x_hi, y_lo, y_hi) of the four corners of polygon p's earlier points of the
    lines s in [s0, s1], z in [z0, z1] (a bilinear patch lies inside their hull)."""
    ax, ay, aqx, aqy = earlier_line(ev, p, k, s0)
    bx, by, bqx, bqy = earlier_line(ev, p, k, s1)
    x_lo = wp.min(wp.min(ax + z0 * aqx, ax + z1 * aqx), wp.min(bx + z0 * bqx, bx + z1 * bqx))
    x_hi = wp.max(wp.max(ax + z0 * aqx, ax + z1 * aqx), wp.max(bx + z0 * bqx, bx + z1 * bqx))
    y_lo = wp.min(wp.min(ay + z0 * aqy, ay + z1 * aqy), wp.min(by + z0 * bqy, by + z1 * bqy))
    y_hi = wp.max(wp.max(ay + z0 * aqy, ay + z1 * aqy), wp.max(by + z0 * bqy, by + z1 * bqy))
    return x_lo, x_hi, y_lo, y_hi


@wp.func
def patch_active(ev: Earlier, k: int, s0: wp.float64, s1: wp.float64, z0: wp.float64, z1: wp.float64):
    """Bit mask of the polygons whose bounding box meets that of the earlier points of the
    lines s in [s0, s1], z in [z0, z1] (a bilinear patch, inside the hull of its four
    corners); a polygon whose box it misses is outside for all of them."""
    active = int(0)
    for p in range(ev.count):
        x_lo, x_hi, y_lo, y_hi = patch_box(ev, p, k, s0, s1, z0, z1)
        box = ev.boxes[p]
        if x_hi >= box[0] and x_lo <= box[1] and y_hi >= box[2] and y_lo <= box[3]:
            active = active | (1 << p)
    return active


@wp.func
def patch_state(ev: Earlier, near: int, k: int, s0: wp.float64, s1: wp.float64, z0: wp.float64, z1: wp.float64):
    """Sort the polygons of ``near`` against the earlier points of the lines s in [s0, s1], z in
    [z0, z1] (inside the box of the patch's four corners, as :func:`patch_active`): those an
    edge's box meets (``cut``: the weight may change across the patch), and of the others, those
    that hold the patch (``inside``: no edge comes near it, so one corner tells)."""
    cut = int(0)
    inside = int(0)
    for p in range(ev.count):
        if (near >> p) & 1 == 1:
            x_lo, x_hi, y_lo, y_hi = patch_box(ev, p, k, s0, s1, z0, z1)
            box = ev.boxes[p]
            if x_hi >= box[0] and x_lo <= box[1] and y_hi >= box[2] and y_lo <= box[3]:
                hit = bool(False)
                v0 = ev.starts[p]
                v1 = ev.starts[p + 1]
                for v in range(v0, v1):
                    w = v + 1
                    if w == v1:
                        w = v0
                    a = ev.verts[v]
                    b = ev.verts[w]
                    if (wp.max(a[0], b[0]) >= x_lo and wp.min(a[0], b[0]) <= x_hi and wp.max(a[1], b[1]) >= y_lo
                            and wp.min(a[1], b[1]) <= y_hi):
                        hit = True
                if hit:
                    cut = cut | (1 << p)
                else:
                    ax, ay, aqx, aqy = earlier_line(ev, p, k, s0)
                    inside = inside | (point_in_polygon(ev, p, ax + z0 * aqx, ay + z0 * aqy) << p)
    return cut, inside


@wp.func
def window_signature(ev: Earlier, active: int, k: int, s: wp.float64, gx: wp.float64, gy: wp.float64,
                     sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64, dsx: wp.float64,
                     dsy: wp.float64, i: int, j: int):
    """The number of crossings of the earlier lines with the polygons inside the cell's window
    [z_in, z_out] of the line s (-1 where it misses the cell): it changes where a crossing
    enters or leaves the window, a kink of the weighted share in s."""
    lo, hi = cell_clip(gx + s * dgx, gy + s * dgy, sx + s * dsx, sy + s * dsy, i, j)
    if lo >= hi:
        return -1
    inner = int(0)
    for p in range(ev.count):
        if (active >> p) & 1 == 1:
            flag, n = polygon_state(ev, p, k, s, lo, hi)
            inner += n
    return inner


@wp.func
def weighted_gauss(ev: Earlier, active: int, base: int, k: int, a: wp.float64, b: wp.float64, gx: wp.float64, gy: wp.float64,
                   sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64, dsx: wp.float64,
                   dsy: wp.float64, i: int, j: int, omega0: wp.float64, h: wp.float64, sigma_omega: wp.float64,
                   out: wp.array3d(dtype=wp.float64)):
    """3-point Gauss-Legendre over s in [a, b] of the weighted shares (``weighted_share``)."""
    half = wp.float64(0.5) * (b - a)
    mid = a + half
    for n in range(3):
        s = mid + wp.float64(float(n - 1)) * wp.float64(GAUSS_NODE) * half
        lo, hi = cell_clip(gx + s * dgx, gy + s * dgy, sx + s * dsx, sy + s * dsy, i, j)
        if lo < hi:
            w = wp.float64(GAUSS_CENTRE_WEIGHT)
            if n != 1:
                w = wp.float64(GAUSS_SIDE_WEIGHT)
            scale = w * half * normal_pdf(omega0 + s * h, wp.float64(0.0), sigma_omega) * h
            weighted_share(ev, active, base, k, s, lo, hi, scale, i, j, out)


@wp.func
def weighted_piece(ev: Earlier, active: int, base: int, k: int, a: wp.float64, b: wp.float64, gx: wp.float64, gy: wp.float64,
                   sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64, dsx: wp.float64,
                   dsy: wp.float64, i: int, j: int, omega0: wp.float64, h: wp.float64, sigma_omega: wp.float64,
                   out: wp.array3d(dtype=wp.float64)):
    """The weighted mass of the lines s in [a, b] (one Gauss sub-piece of the ribbon) in cell
    (i, j), into every channel whose mask meets ``active``. Split first where an earlier line passes a vertex of an
    active polygon (its crossings appear or vanish there: roots of the quadratics of
    ``corner_roots``), then where a crossing enters or leaves the cell's window of z (the
    window's crossing count changes; found by bisection, WINDOW_BISECTIONS halvings), so that
    Gauss-Legendre integrates a smooth function on every part."""
    s0 = a
    for event in range(MAX_EVENTS):
        s1 = b
        for p in range(ev.count):
            if (active >> p) & 1 == 1 and event < MAX_EVENTS - 1:  # the last round takes the rest whole
                l0 = ev.lines[p, k]
                l1 = ev.lines[p, k + 1]
                for v in range(ev.starts[p], ev.starts[p + 1]):
                    vert = ev.verts[v]
                    s1 = corner_roots(l0[0], l0[1], l0[2], l0[3], l1[0] - l0[0], l1[1] - l0[1], l1[2] - l0[2],
                                      l1[3] - l0[3], vert[0], vert[1], s0, s1)
        # [s0, s1]: no vertex pass inside; cut where the window's crossing count changes
        left = window_signature(ev, active, k, s0, gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j)
        for _e in range(MAX_EVENTS):
            right = window_signature(ev, active, k, s1, gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j)
            if right == left:
                break
            lo_s = s0
            hi_s = s1
            for _b in range(WINDOW_BISECTIONS):
                m = wp.float64(0.5) * (lo_s + hi_s)
                if window_signature(ev, active, k, m, gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j) == left:
                    lo_s = m
                else:
                    hi_s = m
            weighted_gauss(ev, active, base, k, s0, hi_s, gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h,
                           sigma_omega, out)
            s0 = hi_s
            left = window_signature(ev, active, k, s0, gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j)
        weighted_gauss(ev, active, base, k, s0, s1, gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h, sigma_omega, out)
        if s1 >= b:
            break
        s0 = s1


@wp.func
def gauss_nodes(gx: wp.float64, gy: wp.float64, sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64,
                dsx: wp.float64, dsy: wp.float64, i: int, j: int, omega0: wp.float64, h: wp.float64,
                sigma_omega: wp.float64, mid: wp.float64, half: wp.float64, total: wp.float64):
    """``total`` plus, node by node, the 3-point Gauss-Legendre terms of the lines' shares of
    cell (i, j) over s in [mid - half, mid + half] (the plain rule's sub-piece)."""
    for n in range(3):
        s = mid + wp.float64(float(n - 1)) * wp.float64(GAUSS_NODE) * half
        lo, hi = cell_clip(gx + s * dgx, gy + s * dgy, sx + s * dsx, sy + s * dsy, i, j)
        if lo < hi:
            w = wp.float64(GAUSS_CENTRE_WEIGHT)
            if n != 1:
                w = wp.float64(GAUSS_SIDE_WEIGHT)
            total += w * half * normal_pdf(omega0 + s * h, wp.float64(0.0), sigma_omega) * h * normal_interval(lo, hi)
    return total


@wp.func
def ribbon_cell(gx: wp.float64, gy: wp.float64, sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64,
                dsx: wp.float64, dsy: wp.float64, i: int, j: int, omega0: wp.float64, h: wp.float64,
                sigma_omega: wp.float64, k: int, ev: Earlier, near: int, out: wp.array3d(dtype=wp.float64)):
    """Add the mass of the turn rates omega0 + s h, s in [0, 1], in cell (i, j) to every
    channel of ``out``: the integral over s of g(omega) h [Phi(z_out(s)) - Phi(z_in(s))], the
    line of each s interpolated linearly between the interval's edge lines (point g + s dg,
    step s_ + s ds), weighted by the earlier evidence ``ev``.

    A line's share of the cell is smooth in s except where the line passes a corner of the cell
    (its entry or exit side changes there, or it starts or stops crossing): those s are the
    roots of four quadratics. Between them the sides crossed are fixed and z_in, z_out move
    monotonically; the stretch is cut into sub-pieces over which they move by at most Z_PIECE
    and each takes 3-point Gauss-Legendre (exact to fifth order). This is what keeps the rule
    accurate where a line runs along a cell side: its share falls from a whole crossing to
    nothing between the passes of that side's two corners.

    Earlier evidence: on a sub-piece whose earlier points (s in the sub-piece, z in its window,
    a hull since z_in and z_out are monotone there) miss the box of every polygon of ``near``
    (those the interval's earlier lines reach at all) the weight is 1 and the sums are the
    plain rule's, term for term (without evidence the result is the plain rule's bit for bit).
    Where no edge's box meets it either, the polygons that hold it give constant factors
    (:func:`patch_state`). Otherwise :func:`weighted_piece`, for the channels whose mask meets a
    polygon that cuts the sub-piece; the others (the prior) take the plain terms times their
    constant factors, so the prior channel is the plain rule's sums, regrouped."""
    fi = wp.float64(float(i))
    fj = wp.float64(float(j))
    one = wp.float64(1.0)
    total = wp.float64(0.0)
    held = int(0)  # the polygons holding the sub-pieces summed in held_total
    held_total = wp.float64(0.0)
    s0 = wp.float64(0.0)
    for _ in range(9):  # at most 8 corner passes in (0, 1)
        s1 = corner_roots(gx, gy, sx, sy, dgx, dgy, dsx, dsy, fi, fj, s0, one)
        s1 = corner_roots(gx, gy, sx, sy, dgx, dgy, dsx, dsy, fi + one, fj, s0, s1)
        s1 = corner_roots(gx, gy, sx, sy, dgx, dgy, dsx, dsy, fi + one, fj + one, s0, s1)
        s1 = corner_roots(gx, gy, sx, sy, dgx, dgy, dsx, dsy, fi, fj + one, s0, s1)
        # between two passes the sides crossed are fixed and z_in, z_out move monotonically:
        # sub-pieces short enough that neither moves by more than Z_PIECE standard deviations
        lo0, hi0 = cell_clip(gx + s0 * dgx, gy + s0 * dgy, sx + s0 * dsx, sy + s0 * dsy, i, j)
        lo1, hi1 = cell_clip(gx + s1 * dgx, gy + s1 * dgy, sx + s1 * dsx, sy + s1 * dsy, i, j)
        moved = wp.max(wp.abs(lo1 - lo0), wp.abs(hi1 - hi0))
        pieces = wp.clamp(int(wp.ceil(moved / wp.float64(Z_PIECE))), 1, MAX_PIECES)
        half = wp.float64(0.5) * (s1 - s0) / wp.float64(float(pieces))
        # the polygons that the whole stretch's earlier points meet an edge of, and those that
        # hold them all (z_in, z_out are monotone over the stretch: its ends give the hull)
        stretch_cut = int(0)
        stretch_inside = int(0)
        if near != 0 and (lo0 < hi0 or lo1 < hi1):
            stretch_cut, stretch_inside = patch_state(ev, near, k, s0, s1, wp.min(lo0, lo1), wp.max(hi0, hi1))
        for p in range(pieces):
            mid = s0 + (wp.float64(2.0) * wp.float64(float(p)) + one) * half
            cut = int(0)
            inside = stretch_inside
            if stretch_cut != 0:
                a = mid - half
                b = mid + half
                lo_a, hi_a = cell_clip(gx + a * dgx, gy + a * dgy, sx + a * dsx, sy + a * dsy, i, j)
                lo_b, hi_b = cell_clip(gx + b * dgx, gy + b * dgy, sx + b * dsx, sy + b * dsy, i, j)
                if lo_a < hi_a or lo_b < hi_b:
                    # not ``held``: that names the mask of the pending held_total, still to be added
                    cut, holds = patch_state(ev, stretch_cut, k, a, b, wp.min(lo_a, lo_b), wp.max(hi_a, hi_b))
                    inside = inside | holds
                if cut != 0:
                    weighted_piece(ev, cut, inside, k, a, b, gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h,
                                   sigma_omega, out)
                    # the channels no cut polygon weighs (the prior): the plain rule's terms,
                    # not weighted_piece's finer split (its own quadrature, 1e-12 apart)
                    plain = gauss_nodes(gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h, sigma_omega, mid, half,
                                        wp.float64(0.0))
                    add_uncut_channels(ev, cut, inside, plain, i, j, out)
            if cut == 0 and inside == 0:
                total = gauss_nodes(gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h, sigma_omega, mid, half, total)
            elif cut == 0:  # inside some polygons throughout: their constant factors
                if inside != held:
                    if held != 0:
                        add_channels(ev, held, held_total, i, j, out)
                    held = inside
                    held_total = wp.float64(0.0)
                held_total = gauss_nodes(gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h, sigma_omega, mid, half,
                                         held_total)
        if s1 >= one:
            break
        s0 = s1
    if held != 0:
        add_channels(ev, held, held_total, i, j, out)
    for c in range(ev.channels):  # outside every polygon: weight 1 in every channel
        out[c, j, i] += total


@wp.func
def walk_edge(gx: wp.float64, gy: wp.float64, sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64,
              dsx: wp.float64, dsy: wp.float64, edge: wp.float64, row0: int, row1: int, nx: int,
              omega0: wp.float64, h: wp.float64, sigma_omega: wp.float64, k: int, ev: Earlier, near: int,
              out: wp.array3d(dtype=wp.float64)):
    """Walk the interval's edge line s = ``edge`` (0 or 1) through the band's cells in order
    (Amanatides-Woo) and add the ribbon's mass to each cell it owns: a cell belongs to the walk
    of s = 0 if that line crosses it over a positive length, else to the walk of s = 1. The
    ribbon is narrower than a cell (the steps are cell / CELL_SUBSTEPS), so every cell it
    touches is crossed by one of its edge lines."""
    ex = gx + edge * dgx
    ey = gy + edge * dgy
    ux = sx + edge * dsx
    uy = sy + edge * dsy
    z_max = wp.float64(Z_MAX)
    lo, hi = line_interval(ex, ux, 0, nx, -z_max, z_max)
    lo, hi = line_interval(ey, uy, row0, row1, lo, hi)
    if lo >= hi or (ux == wp.float64(0.0) and uy == wp.float64(0.0)):
        return
    i = first_cell(ex + lo * ux, ux, 0, nx)
    j = first_cell(ey + lo * uy, uy, row0, row1)
    z = lo
    step_i = 1
    if ux < wp.float64(0.0):
        step_i = -1
    step_j = 1
    if uy < wp.float64(0.0):
        step_j = -1
    for _ in range(nx + row1 - row0 + 2):  # a line crosses at most nx + rows cells of the band
        zi = next_crossing(ex, ux, i)
        zj = next_crossing(ey, uy, j)
        z_next = wp.max(z, wp.min(hi, wp.min(zi, zj)))
        a_lo, a_hi = cell_clip(gx, gy, sx, sy, i, j)
        if (a_lo < a_hi) == (edge == wp.float64(0.0)):
            ribbon_cell(gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h, sigma_omega, k, ev, near, out)
        z = z_next
        if z >= hi:
            return
        if zi <= zj:
            i += step_i
        if zj <= zi:
            j += step_j
        if i < 0 or i >= nx or j < row0 or j >= row1:
            return


@wp.kernel
def earlier_lines(
    edges: wp.array(dtype=wp.float64),
    times: wp.array(dtype=wp.float64),
    v0: wp.float64,
    sigma_a: wp.float64,
    pose: wp.array(dtype=wp.float64),
    x_edge: wp.float64,
    y_edge: wp.float64,
    dx: wp.float64,
    dy: wp.float64,
    lines: wp.array2d(dtype=wp.vec4d),
):
    """``lines[p, k]``: the line of turn rate ``edges[k]`` at time ``times[p]`` in grid
    coordinates (:func:`world_line`)."""
    p, k = wp.tid()
    gx, gy, sx, sy = world_line(edges[k], v0, times[p], sigma_a, pose, x_edge, y_edge, dx, dy)
    lines[p, k] = wp.vec4d(gx, gy, sx, sy)


@wp.kernel
def cat_cells(
    edges: wp.array(dtype=wp.float64),
    sigma_omega: wp.float64,
    row0: int,
    row1: int,
    v0: wp.float64,
    t: wp.float64,
    sigma_a: wp.float64,
    pose: wp.array(dtype=wp.float64),
    x_edge: wp.float64,
    y_edge: wp.float64,
    dx: wp.float64,
    dy: wp.float64,
    nx: int,
    ev: Earlier,
    out: wp.array3d(dtype=wp.float64),
):
    """Add the mass of turn-rate interval ``tid`` (``edges[tid]`` to ``edges[tid + 1]``) to every
    cell of rows ``row0:row1`` of each channel of ``out[channels, ny, nx]`` (rows south to
    north; ``x_edge``, ``y_edge`` the grid's west and south edges), weighted by the earlier
    evidence ``ev`` (none: ``ev.count == 0``, one channel). A cell gets the same terms in the
    same order whatever the bands: its crossings are computed from the lines alone."""
    k = wp.tid()
    omega0 = edges[k]
    h = edges[k + 1] - omega0
    gx, gy, sx, sy = world_line(omega0, v0, t, sigma_a, pose, x_edge, y_edge, dx, dy)
    gx1, gy1, sx1, sy1 = world_line(omega0 + h, v0, t, sigma_a, pose, x_edge, y_edge, dx, dy)
    dgx = gx1 - gx
    dgy = gy1 - gy
    dsx = sx1 - sx
    dsy = sy1 - sy
    # the polygons that the interval's earlier lines reach at all (|z| <= Z_MAX)
    near = patch_active(ev, k, wp.float64(0.0), wp.float64(1.0), wp.float64(-Z_MAX), wp.float64(Z_MAX))
    walk_edge(gx, gy, sx, sy, dgx, dgy, dsx, dsy, wp.float64(0.0), row0, row1, nx, omega0, h, sigma_omega, k, ev, near,
              out)
    walk_edge(gx, gy, sx, sy, dgx, dgy, dsx, dsy, wp.float64(1.0), row0, row1, nx, omega0, h, sigma_omega, k, ev, near,
              out)
