"""Exact-in-acceleration cell probabilities of the CAT model on a grid.

For a fixed turn rate omega the CAT position (eq. (1) of the polar-banana paper) is affine in
the acceleration: with u = omega t and z = a / sigma_a ~ N(0, 1),

    P(z) = v0 t (A(u), B(u)) + z sigma_a t^2 (C(u), D(u))    (local frame, see cat_basis),

a line in the plane along which z is standard normal. A cell that the line crosses between
z_in and z_out holds Phi(z_out) - Phi(z_in) of that turn rate's mass, exactly; the cell
probability is the integral of that over omega with the normal weight g(omega). The caustics,
where the density is infinite, are only where neighbouring lines touch: every line's share is
finite, so the cells there are exact in z like any other.

One kernel thread takes one interval of omega. Its lines are interpolated quadratically
through the interval's two edge lines and its exact middle line (a :class:`Ribbon`: the chord
between the edge lines plus s (1 - s) times a bend; at most half a cell wide); both edge lines
are clipped to the grid (Liang-Barsky) and walked through the cells they cross in order
(Amanatides-Woo), and each cell they own gets the ribbon's mass there (``ribbon_cell``): the
integral over omega, piecewise between the turn rates whose bent lines pass a corner of the
cell (``bent_corner_roots``), by Gauss-Legendre. The interpolation is third order in the
interval (``bananagrid.models.cat.cell_turn_edges``), so the walk's narrowness, not the
curvature of the lines, sets the number of intervals. A line's share is smooth between those passes, so the rule stays accurate
where a midpoint rule in omega is not: a line running along a cell side leaves the cell over a
tiny change of omega. Crossings are computed from the lines alone, not accumulated, so no step
drifts and the result does not depend on the bands. Always float64: a cell's share is a
difference of two normal tails. Work shared along the walk, the same bits as without it: a
Gauss node's line leaves one cell at the z it enters the next by, so its tail there is taken
from the cell before (``gauss_nodes``); the nodes' weights over the whole ribbon (every cell
no corner pass cuts) are computed once a ribbon; a corner that stays on one side of every line
of the ribbon by a margin needs no root (``bent_corner_roots``).

Earlier evidence (:class:`Earlier`): polygons at earlier times weigh each path by where it was
then, exactly in z along each line (``weighted_share``), with the kinks over omega as breaks of
the Gauss rule (``weighted_piece``); the rule and its error: ``bananagrid.models.cat_carried``.
Sub-pieces whose earlier points no polygon edge comes near take the plain terms times constant
factors, so the evidence costs only where it cuts, and without evidence the sums are the plain
rule's bit for bit. On a sub-piece that polygons cut, only the channels weighed by one of them
take the split rule; the others (the prior, the channels of other polygons) take the plain
terms times constant factors, so the prior channel is always the plain rule's terms, regrouped
(equal to float64 rounding). One pass fills several channels: channel c weighs by the polygons
of the bit mask ``masks[c]``.
"""


import warp as wp

from .common import cat_basis, local_to_world, normal_interval, normal_pdf, normal_sf
from .evidence import polygon_contains, polygon_edge

# No adjoints: nothing differentiates these kernels, and the backward kernels Warp would
# generate for every launch kernel are most of a module's code (the CAT module's CUDA build:
# see the note in kernels/__init__.py).
wp.set_module_options({"enable_backward": False})

#: Largest |z| walked: the normal mass beyond it, erfc(7.5 / sqrt 2) = 6.4e-14, is left out (a
#: tenth of the cells' absolute error floor, 1e-12: no cell there holds more than that; the
#: walk of |z| from 7.5 to 9 was a sixth of the cells it visited).
Z_MAX = 7.5
#: 3-point Gauss-Legendre on [-1, 1]: nodes 0, +-sqrt(3/5), weights 8/9 and 5/9 (module
#: constants: a literal inside a Warp function is a float32 constant).
GAUSS_NODE = 0.7745966692414834
GAUSS_CENTRE_WEIGHT = 8.0 / 9.0
GAUSS_SIDE_WEIGHT = 5.0 / 9.0
#: Largest move of z_in or z_out (standard deviations) over one Gauss sub-piece of a ribbon,
#: and the most sub-pieces between two corner passes (beyond, the move per sub-piece grows).
#: The 3-point rule's error goes as the sixth power of the move: 0.07 keeps a cell's share
#: within about 1e-12 of it where the ribbons are wide enough to reach the bound (between the
#: plain rule and the earlier evidence's split rule on Figure 1's 130 m cells, 0.25 left 1.3e-12
#: of the largest cell and 0.1 left 3e-12).
Z_PIECE = 0.07
MAX_PIECES = 64
#: Largest move (standard deviations) over one Gauss sub-piece of a crossing of an earlier line
#: with a polygon's edge inside a cell's window: it bounds a piece of constant weight, like z_in
#: and z_out, but in the whole-plane weighted mass of Figure 1 (60 m cells, 3 s and 5 s searches)
#: Z_PIECE left 1.7e-7 and this 1.5e-9 (the intervals' own error, 2.5e-9 before)
Z_CROSSING = 0.05
#: Newton steps refining a chord's corner pass on the bent lines through the interval's middle:
#: the chord's root is off by about the bend's sag over the ribbon's width (1e-4 of the interval
#: on Figure 1), one step leaves about its square, a kink that far from its break costs the
#: Gauss rule its square again (a second step cost 6 % of Figure 1's cells for nothing seen).
BENT_NEWTON = 1
#: Earlier evidence: most vertex passes and window events handled in one sub-piece (beyond,
#: the rest of the sub-piece takes one Gauss rule), and the halvings that place a window
#: event (to 2^-30 of the sub-piece: its kink then costs far below the rule's error).
MAX_EVENTS = 16
WINDOW_BISECTIONS = 30
#: Most polygons of the earlier evidence (a channel's polygons are the bits of an int).
MAX_POLYGONS = 30
VEC4 = wp.vec4d


@wp.struct
class Frame:
    """The CAT's lines in grid coordinates (world - edge) / cell size: speed ``v0``, ``sigma_a``,
    pose (origin x, origin y, cos heading, sin heading), the grid's west and south edges and its
    cell sizes."""

    v0: wp.float64
    sigma_a: wp.float64
    pose: wp.vec4d
    x_edge: wp.float64
    y_edge: wp.float64
    dx: wp.float64
    dy: wp.float64


@wp.struct
class Ribbon:
    """The lines of the turn rates omega0 + s h, s in [0, 1], of interval ``k``: ``line + s
    step + s (1 - s) bend`` (a line: its point at z = 0 and its step per unit z,
    :func:`world_line`; the bend puts the exact middle line at s = 1/2), the SD of the
    turn rate's normal weight, and the factors of the Gauss nodes of the whole ribbon taken as
    one piece (:func:`node_scale` over s in [0, 1]: the same in every cell no corner pass cuts)."""

    line: wp.vec4d
    step: wp.vec4d
    omega0: wp.float64
    h: wp.float64
    sigma_omega: wp.float64
    k: int
    weights: wp.vec3d
    bend: wp.vec4d


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
def world_line(omega: wp.float64, t: wp.float64, f: Frame):
    """The line of turn rate ``omega`` at time t in grid coordinates: its point at z = 0 and its
    step per unit z (the local frame's point placed by the pose, ``local_to_world``)."""
    a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn = cat_basis(omega * t)
    wx, wy = local_to_world(f.v0 * t * a_fn, f.v0 * t * b_fn, f.pose)
    qx = f.sigma_a * t * t * c_fn
    qy = f.sigma_a * t * t * d_fn
    return wp.vec4d((wx - f.x_edge) / f.dx, (wy - f.y_edge) / f.dy, (qx * f.pose[2] + qy * f.pose[3]) / f.dx,
                    (-qx * f.pose[3] + qy * f.pose[2]) / f.dy)


@wp.func
def line_point(line: wp.vec4d, z: wp.float64):
    """The point of ``line`` at z."""
    return wp.vec2d(line[0] + z * line[2], line[1] + z * line[3])


@wp.func
def cell_clip(line: wp.vec4d, i: int, j: int):
    """[lo, hi] of z (within +-Z_MAX) where the line lies in cell (column i, row j)."""
    z_max = wp.float64(Z_MAX)
    lo, hi = line_interval(line[0], line[2], i, i + 1, -z_max, z_max)
    return line_interval(line[1], line[3], j, j + 1, lo, hi)


@wp.func
def ribbon_clip(r: Ribbon, s: wp.float64, i: int, j: int):
    """:func:`cell_clip` of the ribbon's (bent) line s: at s = 0 the edge line's bits."""
    return cell_clip(r.line + s * r.step + (s * (wp.float64(1.0) - s)) * r.bend, i, j)


@wp.func
def corner_roots(line: wp.vec4d, d: wp.vec4d, cx: wp.float64, cy: wp.float64, after: wp.float64, best: wp.float64):
    """The least s in (after, best) where the line ``line + s d`` passes the corner (cx, cy): a
    root of the quadratic cross(direction, corner - point) = 0; else best."""
    rx = cx - line[0]
    ry = cy - line[1]
    c0 = line[2] * ry - line[3] * rx
    c1 = d[2] * ry - line[2] * d[1] - d[3] * rx + line[3] * d[0]
    c2 = d[3] * d[0] - d[2] * d[1]
    zero = wp.float64(0.0)
    scale = wp.abs(c0) + wp.abs(c1) + wp.abs(c2)
    if scale == zero:
        return best
    # most corners stay on one side of every line of a narrow ribbon: on [0, 1], c(s) =
    # (1 - s) c(0) + s c(1) - c2 s (1 - s) is at least min(|c(0)|, |c(1)|) - |c2| / 4 from 0 when
    # c(0), c(1) share a sign; a margin of 1e-9 scale keeps every root the solver below would
    # compute outside [0, 1] too (rounding moves them by a few ulps of scale / |c'|, or by
    # sqrt(eps scale / |c2|) at a double root), so it would return best as well
    end = c0 + c1 + c2
    if (c0 > zero) == (end > zero) and wp.min(wp.abs(c0), wp.abs(end)) > wp.float64(0.25) * wp.abs(c2) + wp.float64(
            1.0e-9) * scale:
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
    q = wp.float64(-0.5) * (c1 + wp.sign(c1) * wp.sqrt(disc))  # no cancellation (Numerical Recipes 5.6; sign(0) = 1)
    r1 = q / c2
    if r1 > after and r1 < best:
        best = r1
    if q != zero:
        r2 = c0 / q
        if r2 > after and r2 < best:
            best = r2
    return best


@wp.func
def bent_cross(line: wp.vec4d, d: wp.vec4d, bend: wp.vec4d, cx: wp.float64, cy: wp.float64, s: wp.float64):
    """cross(direction, corner - point) of the bent line ``line + s d + s (1 - s) bend`` and its
    derivative in s."""
    one = wp.float64(1.0)
    l = line + s * d + (s * (one - s)) * bend
    dl = d + (one - wp.float64(2.0) * s) * bend
    f = l[2] * (cy - l[1]) - l[3] * (cx - l[0])
    fp = dl[2] * (cy - l[1]) - l[2] * dl[1] - dl[3] * (cx - l[0]) + l[3] * dl[0]
    return f, fp


@wp.func
def bent_refine(line: wp.vec4d, d: wp.vec4d, bend: wp.vec4d, cx: wp.float64, cy: wp.float64, r: wp.float64,
                slope: wp.float64, margin: wp.float64, after: wp.float64, best: wp.float64):
    """``best`` lowered to the root of the bent line's corner function near the chord's root r
    (Newton's method from r, BENT_NEWTON steps) where it lies in (after, best). The bent
    function is within ``margin`` of the chord's, whose slope at r is ``slope``: a root further
    than twice margin / |slope| outside (after, best) stays outside, untouched."""
    reach = wp.float64(2.0) * margin / wp.max(wp.abs(slope), wp.float64(1.0e-300))
    if r <= after - reach or r >= best + reach:
        return best
    for _ in range(BENT_NEWTON):
        f, fp = bent_cross(line, d, bend, cx, cy, r)
        if fp != wp.float64(0.0):
            r = r - f / fp
    if r > after and r < best:
        best = r
    return best


@wp.func
def bent_corner_roots(line: wp.vec4d, d: wp.vec4d, bend: wp.vec4d, cx: wp.float64, cy: wp.float64,
                      after: wp.float64, best: wp.float64):
    """:func:`corner_roots` of the bent lines ``line + s d + s (1 - s) bend``: the least s in
    (after, best) where one passes the corner (cx, cy), else best. The corner function is the
    chord's quadratic plus s (1 - s) times terms bounded over [0, 1] (``bent_margin``): the
    early out holds where the chord's margin exceeds them; else each root of the chord's
    quadratic (or, without real roots, its vertex) that may move into (after, best) is refined
    on the bent line by Newton's method (BENT_NEWTON steps)."""
    zero = wp.float64(0.0)
    rx = cx - line[0]
    ry = cy - line[1]
    c0 = line[2] * ry - line[3] * rx
    c1 = d[2] * ry - line[2] * d[1] - d[3] * rx + line[3] * d[0]
    c2 = d[3] * d[0] - d[2] * d[1]
    scale = wp.abs(c0) + wp.abs(c1) + wp.abs(c2)
    if scale == zero:
        return best
    # |q(s)| and |corner - p(s)| per axis over [0, 1] (linear in s: their ends), and the bent
    # terms s (1 - s) (bq x (c - p) - q x bp) - s^2 (1 - s)^2 bq x bp at most a quarter of them
    qx = wp.max(wp.abs(line[2]), wp.abs(line[2] + d[2]))
    qy = wp.max(wp.abs(line[3]), wp.abs(line[3] + d[3]))
    px = wp.max(wp.abs(rx), wp.abs(rx - d[0]))
    py = wp.max(wp.abs(ry), wp.abs(ry - d[1]))
    margin = wp.float64(0.25) * (wp.abs(bend[2]) * py + wp.abs(bend[3]) * px + qx * wp.abs(bend[1]) + qy * wp.abs(
        bend[0])) + wp.float64(0.0625) * (wp.abs(bend[2] * bend[1]) + wp.abs(bend[3] * bend[0]))
    end = c0 + c1 + c2
    if (c0 > zero) == (end > zero) and wp.min(wp.abs(c0), wp.abs(end)) > wp.float64(0.25) * wp.abs(
            c2) + margin + wp.float64(1.0e-9) * scale:
        return best
    if wp.abs(c2) <= wp.float64(1.0e-14) * scale:  # the chord's is linear: one root
        if c1 != zero:
            best = bent_refine(line, d, bend, cx, cy, -c0 / c1, c1, margin, after, best)
        return best
    disc = c1 * c1 - wp.float64(4.0) * c2 * c0
    if disc < zero:  # the chord misses the corner: the bent line's roots, if any, near its vertex
        return bent_refine(line, d, bend, cx, cy, -c1 / (wp.float64(2.0) * c2), zero, margin, after, best)
    q = wp.float64(-0.5) * (c1 + wp.sign(c1) * wp.sqrt(disc))
    r1 = q / c2
    best = bent_refine(line, d, bend, cx, cy, r1, c1 + wp.float64(2.0) * c2 * r1, margin, after, best)
    if q != zero:
        r2 = c0 / q
        best = bent_refine(line, d, bend, cx, cy, r2, c1 + wp.float64(2.0) * c2 * r2, margin, after, best)
    return best


@wp.struct
class Earlier:
    """Evidence at earlier times whose weight is constant inside polygons (an area search at a
    time, land), in the grid coordinates of the walk, and the output channels.

    Polygon p has the edges ``edges[starts[p]:starts[p + 1]]`` (x0, y0, x1, y1; the even-odd
    rule of ``kernels/evidence.py``'s ``polygon_contains``) and bounding box ``boxes[p]`` (x0,
    x1, y0, y1); a path inside it at its time gets the factor ``miss[p]`` (1 - POD, or 0 for
    land), outside 1. ``lines[p, 2 k]`` is the line at polygon p's time of the turn rate
    ``edges[k]`` of the walk (:func:`world_line`), ``lines[p, 2 k + 1]`` that of the middle of
    interval k. Channel c weights each path by the product of
    the factors of the polygons in the bit mask ``masks[c]`` (0: the prior)."""

    lines: wp.array2d(dtype=wp.vec4d)
    starts: wp.array(dtype=int)
    edges: wp.array2d(dtype=wp.float64)
    boxes: wp.array(dtype=wp.vec4d)
    miss: wp.array(dtype=wp.float64)
    masks: wp.array(dtype=int)
    count: int
    channels: int


@wp.func
def earlier_bend(ev: Earlier, p: int, k: int):
    """Polygon p's bend across interval k: 4 (middle line - mean of the edge lines)."""
    a = ev.lines[p, 2 * k]
    return wp.float64(4.0) * (ev.lines[p, 2 * k + 1] - a - wp.float64(0.5) * (ev.lines[p, 2 * k + 2] - a))


@wp.func
def earlier_line(ev: Earlier, p: int, k: int, s: wp.float64):
    """Polygon p's line at s in [0, 1] across turn-rate interval k: quadratic through the
    interval's edge lines (``lines[p, 2 k]``, ``lines[p, 2 k + 2]``) and its middle line
    (``lines[p, 2 k + 1]``), like the ribbon of lines at the map's time."""
    a = ev.lines[p, 2 * k]
    return a + s * (ev.lines[p, 2 * k + 2] - a) + (s * (wp.float64(1.0) - s)) * earlier_bend(ev, p, k)


@wp.func
def holds(ev: Earlier, p: int, point: wp.vec2d):
    """1 if polygon p holds ``point``, else 0."""
    return int(polygon_contains(ev.edges, ev.starts[p], ev.starts[p + 1] - ev.starts[p], point[0], point[1]))


@wp.func
def edge_crossing(line: wp.vec4d, edges: wp.array2d(dtype=wp.float64), e: int):
    """Whether the line p + z q crosses edge e (a-b), and at which z. The ends are sorted by
    the sign of cross(q, v - p) > 0 (the even-odd rule's half-open convention), so a line
    through a vertex crosses exactly one of its two edges, or both or neither where it only
    touches the polygon there: the parity of the crossings below any z is the inside test."""
    ax, ay, bx, by = polygon_edge(edges, e)
    ca = line[2] * (ay - line[1]) - line[3] * (ax - line[0])
    cb = line[2] * (by - line[1]) - line[3] * (bx - line[0])
    zero = wp.float64(0.0)
    if (ca > zero) == (cb > zero):
        return False, zero
    # p + z q = a + tau (b - a): z = cross(a - p, b - a) / cross(q, b - a), cross(q, b - a) = cb - ca
    return True, ((ax - line[0]) * (by - ay) - (ay - line[1]) * (bx - ax)) / (cb - ca)


@wp.func
def edge_line_z(line: wp.vec4d, edges: wp.array2d(dtype=wp.float64), e: int):
    """The z where the line p + z q meets the line through edge e (a-b) (:func:`edge_crossing`'s
    formula without its test; 0 where they are parallel)."""
    ax, ay, bx, by = polygon_edge(edges, e)
    den = line[2] * (by - ay) - line[3] * (bx - ax)
    if den == wp.float64(0.0):
        return wp.float64(0.0)
    return ((ax - line[0]) * (by - ay) - (ay - line[1]) * (bx - ax)) / den


@wp.func
def polygon_crossings(ev: Earlier, p: int, line: wp.vec4d, lo: wp.float64, hi: wp.float64):
    """The crossings of ``line`` with polygon p's edges: the parity of those at or below lo (1:
    the point at lo is inside), how many lie in (lo, hi), the least in (lo, hi] (hi if none) and
    the parity of those there (none for a line of one point: its step is 0)."""
    below = int(0)
    inner = int(0)
    first = hi
    toggle = int(0)
    for e in range(ev.starts[p], ev.starts[p + 1]):
        hit, z = edge_crossing(line, ev.edges, e)
        if hit:
            if z <= lo:
                below = 1 - below
            elif z < hi:
                inner += 1
            if z > lo and z <= first:
                if z < first:
                    first = z
                    toggle = int(0)
                toggle = 1 - toggle
    return below, inner, first, toggle


@wp.func
def window_state(ev: Earlier, active: int, r: Ribbon, s: wp.float64, i: int, j: int):
    """The window [lo, hi] of z of the ribbon's line s in cell (i, j) and, for the earlier lines
    of s and the polygons of ``active``, the bit mask of those holding the point at z = lo and
    the number of crossings in (lo, hi): -1 where the window is empty (the number changes where
    a crossing enters or leaves the window, a kink of the weighted share in s)."""
    lo, hi = ribbon_clip(r, s, i, j)
    inside = int(0)
    inner = int(0)
    if lo >= hi:
        return lo, hi, inside, -1
    for p in range(ev.count):
        if (active >> p) & 1 == 1:
            line = earlier_line(ev, p, r.k, s)
            if line[2] == wp.float64(0.0) and line[3] == wp.float64(0.0):  # the time of the last fix: one point
                inside = inside | (holds(ev, p, wp.vec2d(line[0], line[1])) << p)
            else:
                below, n, _first, _toggle = polygon_crossings(ev, p, line, lo, hi)
                inside = inside | (below << p)
                inner += n
    return lo, hi, inside, inner


@wp.func
def add_channels(ev: Earlier, cut: int, meets: bool, inside: int, value: wp.float64, i: int, j: int,
                 out: wp.array3d(dtype=wp.float64)):
    """Add ``value`` times each channel's weight of a path inside the polygons of the bit mask
    ``inside`` (the product of the factors of the channel's polygons among them) to cell (i, j)
    of the channels whose mask meets ``cut`` (``meets``) or misses it (not ``meets``: with
    ``cut`` 0, every channel)."""
    for c in range(ev.channels):
        if (ev.masks[c] & cut != 0) == meets:
            w = wp.float64(1.0)
            for p in range(ev.count):
                if ((ev.masks[c] & inside) >> p) & 1 == 1:
                    w = w * ev.miss[p]
            out[c, j, i] += w * value


@wp.func
def weighted_share(ev: Earlier, active: int, base: int, r: Ribbon, s: wp.float64, scale: wp.float64, i: int, j: int,
                   out: wp.array3d(dtype=wp.float64)):
    """Add ``scale`` times the weighted normal mass of the ribbon's line s in cell (i, j) (its
    window [lo, hi] of z, not empty) to every channel whose mask meets ``active`` (the others:
    :func:`ribbon_cell`): the earlier lines' crossings with the polygons (``active``'s bits; of
    the others, ``base``'s hold the whole window, the rest miss it) cut [lo, hi] into pieces of
    constant weight, each adding its weight times Phi(z_hi) - Phi(z_lo), exactly. The pieces are
    taken in order by finding the least crossing above the last (no sort, no buffer)."""
    lo, hi, inside, inner = window_state(ev, active, r, s, i, j)
    inside = inside | base
    z = lo
    for _ in range(inner + 1):
        z_next = hi
        toggle = int(0)
        if inner > 0:
            for p in range(ev.count):
                if (active >> p) & 1 == 1:
                    _below, _n, first, flip = polygon_crossings(ev, p, earlier_line(ev, p, r.k, s), z, z_next)
                    if first < z_next:
                        z_next = first
                        toggle = flip << p
                    else:
                        toggle = toggle ^ (flip << p)
        add_channels(ev, active, True, inside, scale * normal_interval(z, z_next), i, j, out)
        if z_next >= hi:
            break
        inside = inside ^ toggle
        z = z_next


@wp.func
def patch_meets(ev: Earlier, p: int, k: int, s0: wp.float64, s1: wp.float64, z0: wp.float64, z1: wp.float64):
    """The box (corners lo, hi) of the four corners of polygon p's earlier points of the lines
    s in [s0, s1], z in [z0, z1] (a bilinear patch lies inside their hull), widened by the bend's
    sag between s0 and s1 ((s1 - s0)^2 / 4 of it), and whether it meets the polygon's box (if
    not, the polygon holds none of them)."""
    a = earlier_line(ev, p, k, s0)
    b = earlier_line(ev, p, k, s1)
    a0 = line_point(a, z0)
    a1 = line_point(a, z1)
    b0 = line_point(b, z0)
    b1 = line_point(b, z1)
    bend = earlier_bend(ev, p, k)
    reach = wp.max(wp.abs(z0), wp.abs(z1))
    sag = wp.float64(0.25) * (s1 - s0) * (s1 - s0)
    pad = wp.vec2d(sag * (wp.abs(bend[0]) + reach * wp.abs(bend[2])), sag * (wp.abs(bend[1]) + reach * wp.abs(bend[3])))
    lo = wp.min(wp.min(a0, a1), wp.min(b0, b1)) - pad
    hi = wp.max(wp.max(a0, a1), wp.max(b0, b1)) + pad
    box = ev.boxes[p]
    return hi[0] >= box[0] and lo[0] <= box[1] and hi[1] >= box[2] and lo[1] <= box[3], lo, hi


@wp.func
def patch_state(ev: Earlier, near: int, k: int, s0: wp.float64, s1: wp.float64, z0: wp.float64, z1: wp.float64):
    """Sort the polygons of ``near`` against the earlier points of the lines s in [s0, s1], z in
    [z0, z1] (inside the box of the patch's four corners, :func:`patch_meets`): those an edge's
    box meets (``cut``: the weight may change across the patch), and of the others, those that
    hold the patch (``inside``: no edge comes near it, so one corner tells)."""
    cut = int(0)
    inside = int(0)
    for p in range(ev.count):
        if (near >> p) & 1 == 1:
            meets, lo, hi = patch_meets(ev, p, k, s0, s1, z0, z1)
            if meets:
                hit = bool(False)
                for e in range(ev.starts[p], ev.starts[p + 1]):
                    ax, ay, bx, by = polygon_edge(ev.edges, e)
                    if wp.max(ax, bx) >= lo[0] and wp.min(ax, bx) <= hi[0] and wp.max(ay, by) >= lo[1] and wp.min(
                            ay, by) <= hi[1]:
                        hit = True
                if hit:
                    cut = cut | (1 << p)
                else:
                    inside = inside | (holds(ev, p, line_point(earlier_line(ev, p, k, s0), z0)) << p)
    return cut, inside


@wp.func
def node_s(n: int, mid: wp.float64, half: wp.float64):
    """s of node n (0, 1, 2) of 3-point Gauss-Legendre over [mid - half, mid + half]."""
    return mid + wp.float64(float(n - 1)) * wp.float64(GAUSS_NODE) * half


@wp.func
def node_scale(r: Ribbon, n: int, s: wp.float64, half: wp.float64):
    """The factor of node n at s of a rule of half-width ``half``: weight x half x g(omega) h."""
    w = wp.float64(GAUSS_CENTRE_WEIGHT)
    if n != 1:
        w = wp.float64(GAUSS_SIDE_WEIGHT)
    return w * half * normal_pdf(r.omega0 + s * r.h, wp.float64(0.0), r.sigma_omega) * r.h


@wp.func
def gauss_node(r: Ribbon, n: int, mid: wp.float64, half: wp.float64, i: int, j: int):
    """Node n (0, 1, 2) of 3-point Gauss-Legendre over s in [mid - half, mid + half]: its s, the
    line's window [lo, hi] of z in cell (i, j) and, where it is not empty, the node's factor
    (:func:`node_scale`; the ribbon's own for the whole of [0, 1], computed once)."""
    s = node_s(n, mid, half)
    lo, hi = ribbon_clip(r, s, i, j)
    scale = wp.float64(0.0)
    if lo < hi:
        if mid == wp.float64(0.5) and half == wp.float64(0.5):
            scale = r.weights[n]
        else:
            scale = node_scale(r, n, s, half)
    return s, lo, hi, scale


@wp.func
def normal_tail(z: wp.float64):
    """Q(|z|): the normal tail on the side of z away from 0 (``normal_sf``'s upper branch)."""
    return normal_sf(wp.abs(z))


@wp.func
def tail_interval(lo: wp.float64, hi: wp.float64, q_lo: wp.float64, q_hi: wp.float64):
    """Phi(hi) - Phi(lo) for lo <= hi from q_lo = Q(|lo|) and q_hi = Q(|hi|): ``normal_interval``'s
    three cases with the same operations, so the same bits."""
    if lo >= wp.float64(0.0):
        return q_lo - q_hi
    if hi <= wp.float64(0.0):
        return q_hi - q_lo
    return wp.float64(1.0) - q_lo - q_hi


@wp.func
def gauss_nodes(r: Ribbon, i: int, j: int, mid: wp.float64, half: wp.float64, total: wp.float64, tz: wp.vec3d,
                tq: wp.vec3d):
    """``total`` plus the terms of the lines' shares of cell (i, j) (:func:`gauss_node`). ``tz``,
    ``tq``: each node's last exit z and its tail Q(|z|); where node n enters at that z (its line
    leaves one cell into the next of the walk) the tail is taken, not computed again. Returns
    the new total and the updated tails."""
    for n in range(3):
        s, lo, hi, scale = gauss_node(r, n, mid, half, i, j)
        if lo < hi:
            q_lo = tq[n]
            if lo != tz[n]:
                q_lo = normal_tail(lo)
            q_hi = normal_tail(hi)
            tz[n] = hi
            tq[n] = q_hi
            total += scale * tail_interval(lo, hi, q_lo, q_hi)
    return total, tz, tq


@wp.func
def weighted_gauss(ev: Earlier, active: int, base: int, r: Ribbon, a: wp.float64, b: wp.float64, i: int, j: int,
                   out: wp.array3d(dtype=wp.float64)):
    """:func:`gauss_nodes` over s in [a, b] of the weighted shares (``weighted_share``)."""
    half = wp.float64(0.5) * (b - a)
    for n in range(3):
        s, lo, hi, scale = gauss_node(r, n, a + half, half, i, j)
        if lo < hi:
            weighted_share(ev, active, base, r, s, scale, i, j, out)


@wp.func
def crossing_parts(ev: Earlier, active: int, r: Ribbon, a: wp.float64, b: wp.float64, i: int, j: int):
    """Parts of [a, b] short enough that no crossing of an earlier line with an active
    polygon's edge, where it meets the cell's windows at a or b, moves by more than Z_CROSSING
    SDs over one (a crossing bounds a piece of constant weight, like z_in and z_out)."""
    lo_a, hi_a = ribbon_clip(r, a, i, j)
    lo_b, hi_b = ribbon_clip(r, b, i, j)
    z_lo = wp.min(lo_a, lo_b)
    z_hi = wp.max(hi_a, hi_b)
    moved = wp.float64(0.0)
    for p in range(ev.count):
        if (active >> p) & 1 == 1:
            line_a = earlier_line(ev, p, r.k, a)
            line_b = earlier_line(ev, p, r.k, b)
            for e in range(ev.starts[p], ev.starts[p + 1]):
                hit_a, za = edge_crossing(line_a, ev.edges, e)
                hit_b, zb = edge_crossing(line_b, ev.edges, e)
                if hit_a or hit_b:
                    # where the edge's line meets the earlier lines at both ends (a part's end
                    # may be a vertex pass, where the crossing moves onto the next edge)
                    za = edge_line_z(line_a, ev.edges, e)
                    zb = edge_line_z(line_b, ev.edges, e)
                    if wp.max(za, zb) >= z_lo and wp.min(za, zb) <= z_hi:
                        moved = wp.max(moved, wp.abs(zb - za))
    return wp.clamp(int(wp.ceil(moved / wp.float64(Z_CROSSING))), 1, MAX_PIECES)


@wp.func
def window_events(ev: Earlier, active: int, base: int, r: Ribbon, s0: wp.float64, s1: wp.float64, i: int, j: int,
                  out: wp.array3d(dtype=wp.float64)):
    """:func:`weighted_gauss` over [s0, s1] (no vertex pass inside) cut where the window's
    crossing count or the polygons holding its lower end change (a crossing entering as
    another leaves keeps the count; found by bisection, WINDOW_BISECTIONS halvings)."""
    _lo, _hi, held_left, left = window_state(ev, active, r, s0, i, j)
    for _e in range(MAX_EVENTS):
        _lo, _hi, held_right, right = window_state(ev, active, r, s1, i, j)
        if right == left and held_right == held_left:
            break
        lo_s = s0
        hi_s = s1
        for _b in range(WINDOW_BISECTIONS):
            m = wp.float64(0.5) * (lo_s + hi_s)
            _lo, _hi, held_middle, middle = window_state(ev, active, r, m, i, j)
            if middle == left and held_middle == held_left:
                lo_s = m
            else:
                hi_s = m
        weighted_gauss(ev, active, base, r, s0, hi_s, i, j, out)
        s0 = hi_s
        _lo, _hi, held_left, left = window_state(ev, active, r, s0, i, j)
    weighted_gauss(ev, active, base, r, s0, s1, i, j, out)


@wp.func
def weighted_piece(ev: Earlier, active: int, base: int, r: Ribbon, a: wp.float64, b: wp.float64, i: int, j: int,
                   out: wp.array3d(dtype=wp.float64)):
    """The weighted mass of the lines s in [a, b] (one Gauss sub-piece of the ribbon) in cell
    (i, j), into every channel whose mask meets ``active``. Split first where an earlier line
    passes a vertex of an active polygon (its crossings appear or vanish there: roots of the
    functions of ``bent_corner_roots``), then where a crossing enters or leaves the cell's window
    of z (:func:`window_events`, on the parts of :func:`crossing_parts`: a crossing that moved
    further could enter and leave the window unseen by a part's ends), so that Gauss-Legendre
    integrates a smooth function on every part."""
    s0 = a
    for event in range(MAX_EVENTS):
        s1 = b
        for p in range(ev.count):
            if (active >> p) & 1 == 1 and event < MAX_EVENTS - 1:  # the last round takes the rest whole
                l0 = ev.lines[p, 2 * r.k]
                d = ev.lines[p, 2 * r.k + 2] - l0
                bend = earlier_bend(ev, p, r.k)
                for e in range(ev.starts[p], ev.starts[p + 1]):
                    s1 = bent_corner_roots(l0, d, bend, ev.edges[e, 0], ev.edges[e, 1], s0, s1)
        # [s0, s1]: no vertex pass inside; cut where the window's crossing count changes
        parts = crossing_parts(ev, active, r, s0, s1, i, j)
        width = (s1 - s0) / wp.float64(float(parts))
        for part in range(parts):
            end = s1
            if part < parts - 1:
                end = s0 + wp.float64(float(part + 1)) * width
            window_events(ev, active, base, r, s0 + wp.float64(float(part)) * width, end, i, j, out)
        if s1 >= b:
            break
        s0 = s1


@wp.func
def ribbon_cell(r: Ribbon, i: int, j: int, ev: Earlier, near: int, out: wp.array3d(dtype=wp.float64), tz: wp.vec3d,
                tq: wp.vec3d, edge_lo: wp.float64, edge_hi: wp.float64):
    """Add the ribbon's mass in cell (i, j) to every channel of ``out``: the integral over s of
    g(omega) h [Phi(z_out(s)) - Phi(z_in(s))], weighted by the earlier evidence ``ev``.

    Between the s where a line passes a corner of the cell (``bent_corner_roots``) the sides
    crossed are fixed and z_in, z_out move monotonically (the chord's do; the bend, a small
    fraction of the ribbon's width, moves them by as little): the stretch is cut into
    sub-pieces over which they move by at most Z_PIECE, each taking 3-point Gauss-Legendre.

    Earlier evidence (``near``: the polygons the interval's earlier lines reach at all): a
    sub-piece whose earlier points (a hull, z_in and z_out being monotone) miss every polygon's
    box takes the plain terms; where no edge's box meets them either, the polygons that hold
    them give constant factors (:func:`patch_state`); otherwise :func:`weighted_piece` for the
    channels a cutting polygon weighs, the plain terms times constant factors for the others.

    ``edge_lo``, ``edge_hi``: the window of the line s = 0 in the cell (the walk's ``cell_clip``,
    the same bits as :func:`ribbon_clip` at s = 0); ``tz``, ``tq``: the nodes' last tails
    (:func:`gauss_nodes`), returned updated."""
    fi = wp.float64(float(i))
    fj = wp.float64(float(j))
    one = wp.float64(1.0)
    total = wp.float64(0.0)
    held = int(0)  # the polygons holding the sub-pieces summed in held_total
    held_total = wp.float64(0.0)
    s0 = wp.float64(0.0)
    for _ in range(9):  # at most 8 corner passes in (0, 1)
        s1 = bent_corner_roots(r.line, r.step, r.bend, fi, fj, s0, one)
        s1 = bent_corner_roots(r.line, r.step, r.bend, fi + one, fj, s0, s1)
        s1 = bent_corner_roots(r.line, r.step, r.bend, fi + one, fj + one, s0, s1)
        s1 = bent_corner_roots(r.line, r.step, r.bend, fi, fj + one, s0, s1)
        # sub-pieces short enough that neither z_in nor z_out moves by more than Z_PIECE SDs
        lo0 = edge_lo
        hi0 = edge_hi
        if s0 > wp.float64(0.0):
            lo0, hi0 = ribbon_clip(r, s0, i, j)
        lo1, hi1 = ribbon_clip(r, s1, i, j)
        moved = wp.max(wp.abs(lo1 - lo0), wp.abs(hi1 - hi0))
        pieces = wp.clamp(int(wp.ceil(moved / wp.float64(Z_PIECE))), 1, MAX_PIECES)
        half = wp.float64(0.5) * (s1 - s0) / wp.float64(float(pieces))
        # the polygons that the whole stretch's earlier points meet an edge of, and those that
        # hold them all (z_in, z_out are monotone over the stretch: its ends give the hull)
        stretch_cut = int(0)
        stretch_inside = int(0)
        if near != 0 and (lo0 < hi0 or lo1 < hi1):
            stretch_cut, stretch_inside = patch_state(ev, near, r.k, s0, s1, wp.min(lo0, lo1), wp.max(hi0, hi1))
        for p in range(pieces):
            mid = s0 + (wp.float64(2.0) * wp.float64(float(p)) + one) * half
            cut = int(0)
            inside = stretch_inside
            if stretch_cut != 0:
                a = mid - half
                b = mid + half
                lo_a, hi_a = ribbon_clip(r, a, i, j)
                lo_b, hi_b = ribbon_clip(r, b, i, j)
                if lo_a < hi_a or lo_b < hi_b:
                    # not ``held``: that names the mask of the pending held_total, still to be added
                    cut, holding = patch_state(ev, stretch_cut, r.k, a, b, wp.min(lo_a, lo_b), wp.max(hi_a, hi_b))
                    inside = inside | holding
                if cut != 0:
                    weighted_piece(ev, cut, inside, r, a, b, i, j, out)
                    # the channels no cut polygon weighs (the prior): the plain rule's terms,
                    # not weighted_piece's finer split (its own quadrature, 1e-12 apart)
                    plain, tz, tq = gauss_nodes(r, i, j, mid, half, wp.float64(0.0), tz, tq)
                    add_channels(ev, cut, False, inside, plain, i, j, out)
            if cut == 0 and inside == 0:
                total, tz, tq = gauss_nodes(r, i, j, mid, half, total, tz, tq)
            elif cut == 0:  # inside some polygons throughout: their constant factors
                if inside != held:
                    if held != 0:
                        add_channels(ev, 0, False, held, held_total, i, j, out)
                    held = inside
                    held_total = wp.float64(0.0)
                held_total, tz, tq = gauss_nodes(r, i, j, mid, half, held_total, tz, tq)
        if s1 >= one:
            break
        s0 = s1
    if held != 0:
        add_channels(ev, 0, False, held, held_total, i, j, out)
    for c in range(ev.channels):  # outside every polygon: weight 1 in every channel
        out[c, j, i] += total
    return tz, tq


@wp.func
def walk_edge(r: Ribbon, edge: wp.float64, row0: int, row1: int, nx: int, ev: Earlier, near: int,
              out: wp.array3d(dtype=wp.float64)):
    """Walk the ribbon's edge line s = ``edge`` (0 or 1) through the band's cells in order
    (Amanatides-Woo) and add the ribbon's mass to each cell it owns: a cell belongs to the walk
    of s = 0 if that line crosses it over a positive length, else to the walk of s = 1. The
    ribbon is narrower than a cell (the steps are cell / CELL_SUBSTEPS), so every cell it
    touches is crossed by one of its edge lines; the bent lines stay between the edge lines
    except where the band between them is narrower than the bend (a line's contact with a
    caustic), by at most the bend's sag: a cell reached only there is part of the rule's error
    (``bananagrid.models.cat.CAT.cell_plan``)."""
    line = r.line + edge * r.step
    z_max = wp.float64(Z_MAX)
    lo, hi = line_interval(line[0], line[2], 0, nx, -z_max, z_max)
    lo, hi = line_interval(line[1], line[3], row0, row1, lo, hi)
    if lo >= hi or (line[2] == wp.float64(0.0) and line[3] == wp.float64(0.0)):
        return
    i = first_cell(line[0] + lo * line[2], line[2], 0, nx)
    j = first_cell(line[1] + lo * line[3], line[3], row0, row1)
    z = lo
    step_i = int(wp.sign(line[2]))  # 1 for a step of 0
    step_j = int(wp.sign(line[3]))
    tz = wp.vec3d(wp.float64(1.0e300))  # no exit yet (|z| <= Z_MAX)
    tq = wp.vec3d(wp.float64(0.0))
    for _ in range(nx + row1 - row0 + 2):  # a line crosses at most nx + rows cells of the band
        zi = next_crossing(line[0], line[2], i)
        zj = next_crossing(line[1], line[3], j)
        z_next = wp.max(z, wp.min(hi, wp.min(zi, zj)))
        a_lo, a_hi = cell_clip(r.line, i, j)
        if (a_lo < a_hi) == (edge == wp.float64(0.0)):
            tz, tq = ribbon_cell(r, i, j, ev, near, out, tz, tq, a_lo, a_hi)
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
def earlier_lines(edges: wp.array(dtype=wp.float64), times: wp.array(dtype=wp.float64), f: Frame,
                  lines: wp.array2d(dtype=wp.vec4d)):
    """``lines[p, 2 k]``: the line of turn rate ``edges[k]`` at time ``times[p]``
    (:func:`world_line`); ``lines[p, 2 k + 1]``: that of the middle of interval k (the bits of
    the ribbon's middle turn rate)."""
    p, m = wp.tid()
    k = m // 2
    omega = edges[k]
    if m % 2 == 1:
        omega = omega + wp.float64(0.5) * (edges[k + 1] - omega)
    lines[p, m] = world_line(omega, times[p], f)


@wp.kernel
def cat_cells(edges: wp.array(dtype=wp.float64), sigma_omega: wp.float64, t: wp.float64, f: Frame, row0: int,
              row1: int, nx: int, ev: Earlier, out: wp.array3d(dtype=wp.float64)):
    """Add the mass of turn-rate interval ``tid`` (``edges[tid]`` to ``edges[tid + 1]``) at time
    t to every cell of rows ``row0:row1`` of each channel of ``out[channels, ny, nx]`` (rows
    south to north), weighted by the earlier evidence ``ev`` (none: ``ev.count == 0``, one
    channel). A cell gets the same terms in the same order whatever the bands: its crossings
    are computed from the lines alone."""
    k = wp.tid()
    r = Ribbon()
    r.omega0 = edges[k]
    r.h = edges[k + 1] - r.omega0
    r.line = world_line(r.omega0, t, f)
    r.step = world_line(r.omega0 + r.h, t, f) - r.line
    r.bend = wp.float64(4.0) * (world_line(r.omega0 + wp.float64(0.5) * r.h, t, f) - r.line - wp.float64(0.5) * r.step)
    r.sigma_omega = sigma_omega
    r.k = k
    half = wp.float64(0.5)
    r.weights = wp.vec3d(node_scale(r, 0, node_s(0, half, half), half), node_scale(r, 1, node_s(1, half, half), half),
                         node_scale(r, 2, node_s(2, half, half), half))
    # the polygons that cut or hold the interval's earlier points (|z| <= Z_MAX); the others
    # miss every one of them
    cut, inside = patch_state(ev, (1 << ev.count) - 1, k, wp.float64(0.0), wp.float64(1.0), wp.float64(-Z_MAX),
                              wp.float64(Z_MAX))
    near = cut | inside
    walk_edge(r, wp.float64(0.0), row0, row1, nx, ev, near, out)
    walk_edge(r, wp.float64(1.0), row0, row1, nx, ev, near, out)
