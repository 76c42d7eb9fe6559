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


@wp.func
def ribbon_cell(gx: wp.float64, gy: wp.float64, sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64,
                dsx: wp.float64, dsy: wp.float64, i: int, j: int, omega0: wp.float64, h: wp.float64,
                sigma_omega: wp.float64):
    """The mass of the turn rates omega0 + s h, s in [0, 1], in cell (i, j): the integral over s
    of g(omega) h [Phi(z_out(s)) - Phi(z_in(s))], the line of each s interpolated linearly
    between the interval's edge lines (point g + s dg, step s_ + s ds).

    A line's share of the cell is smooth in s except where the line passes a corner of the cell
    (its entry or exit side changes there, or it starts or stops crossing): those s are the
    roots of four quadratics. Between them the sides crossed are fixed and z_in, z_out move
    monotonically; the stretch is cut into sub-pieces over which they move by at most Z_PIECE
    and each takes 3-point Gauss-Legendre (exact to fifth order). This is what keeps the rule
    accurate where a line runs along a cell side: its share falls from a whole crossing to
    nothing between the passes of that side's two corners."""
    fi = wp.float64(float(i))
    fj = wp.float64(float(j))
    one = wp.float64(1.0)
    node = wp.float64(GAUSS_NODE)
    total = wp.float64(0.0)
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
        for p in range(pieces):
            mid = s0 + (wp.float64(2.0) * wp.float64(float(p)) + one) * half
            for k in range(3):
                s = mid + wp.float64(float(k - 1)) * node * half
                lo, hi = cell_clip(gx + s * dgx, gy + s * dgy, sx + s * dsx, sy + s * dsy, i, j)
                if lo < hi:
                    w = wp.float64(GAUSS_CENTRE_WEIGHT)
                    if k != 1:
                        w = wp.float64(GAUSS_SIDE_WEIGHT)
                    total += w * half * normal_pdf(omega0 + s * h, wp.float64(0.0), sigma_omega) * h * normal_interval(lo, hi)
        if s1 >= one:
            break
        s0 = s1
    return total


@wp.func
def walk_edge(gx: wp.float64, gy: wp.float64, sx: wp.float64, sy: wp.float64, dgx: wp.float64, dgy: wp.float64,
              dsx: wp.float64, dsy: wp.float64, edge: wp.float64, row0: int, row1: int, nx: int,
              omega0: wp.float64, h: wp.float64, sigma_omega: wp.float64, out: wp.array2d(dtype=wp.float64)):
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
            out[j, i] += ribbon_cell(gx, gy, sx, sy, dgx, dgy, dsx, dsy, i, j, omega0, h, sigma_omega)
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
    out: wp.array2d(dtype=wp.float64),
):
    """Add the mass of turn-rate interval ``tid`` (``edges[tid]`` to ``edges[tid + 1]``) to every
    cell of rows ``row0:row1`` of ``out[ny, nx]`` (rows south to north; ``x_edge``, ``y_edge``
    the grid's west and south edges). A cell gets the same terms in the same order whatever the
    bands: its crossings are computed from the lines alone."""
    k = wp.tid()
    omega0 = edges[k]
    h = edges[k + 1] - omega0
    gx, gy, sx, sy = world_line(omega0, v0, t, sigma_a, pose, x_edge, y_edge, dx, dy)
    gx1, gy1, sx1, sy1 = world_line(omega0 + h, v0, t, sigma_a, pose, x_edge, y_edge, dx, dy)
    dgx = gx1 - gx
    dgy = gy1 - gy
    dsx = sx1 - sx
    dsy = sy1 - sy
    walk_edge(gx, gy, sx, sy, dgx, dgy, dsx, dsy, wp.float64(0.0), row0, row1, nx, omega0, h, sigma_omega, out)
    walk_edge(gx, gy, sx, sy, dgx, dgy, dsx, dsy, wp.float64(1.0), row0, row1, nx, omega0, h, sigma_omega, out)
