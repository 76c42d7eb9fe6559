"""Independent references for cell probabilities (tests/engine/test_cell_probabilities.py,
tests/engine/test_cell_kinks.py).

CAT: for each turn rate the line P(a) = pos(a, omega) is clipped to the cell in NumPy (the
cell's two slabs, not the kernel's walk), and Phi(z_out) - Phi(z_in) is integrated over omega by
SciPy's adaptive ``quad`` with the normal weight, between the turn rates whose lines pass the
cell's corners (where the share has kinks), to 1e-11 relative. Other models: SciPy
``dblquad`` of ``pdf`` over the cell, or over the cell in polar coordinates about a point.
A polar banana's cell of a polar lattice about any origin: exact in the banana's own range,
adaptive ``quad`` over its bearing (``banana_lattice_cell``).
"""

import math
import warnings

import numpy as np
from scipy import integrate, optimize
from scipy.special import ndtr

from bananagrid.models.cat import cat_position


def line_shares(model, omegas, cell):
    """Phi(z_out) - Phi(z_in) for the lines of turn rates ``omegas`` through the world cell
    ``(x0, x1, y0, y1)`` (eq. (1) of the polar-banana paper at a = 0 and a = sigma_a)."""
    omegas = np.atleast_1d(np.asarray(omegas, dtype=float))
    base = model.pose.to_world(cat_position(model.v0, model.t, np.zeros_like(omegas), omegas))
    unit = model.pose.to_world(cat_position(model.v0, model.t, np.full_like(omegas, model.sigma_a), omegas))
    d = unit - base
    lo, hi = np.full(len(omegas), -40.0), np.full(len(omegas), 40.0)
    x0, x1, y0, y1 = cell
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, a, b in ((0, x0, x1), (1, y0, y1)):
            start, step = base[:, axis], d[:, axis]
            za, zb = (a - start) / step, (b - start) / step
            flat = step == 0.0
            inside = (a <= start) & (start <= b)
            lo = np.where(flat, np.where(inside, lo, 40.0), np.maximum(lo, np.minimum(za, zb)))
            hi = np.where(flat, np.where(inside, hi, -40.0), np.minimum(hi, np.maximum(za, zb)))
    share = np.where(lo >= 0.0, ndtr(-lo) - ndtr(-hi), ndtr(hi) - ndtr(lo))
    return np.where(lo < hi, share, 0.0)


def _lines(model, omegas):
    omegas = np.atleast_1d(np.asarray(omegas, dtype=float))
    base = model.pose.to_world(cat_position(model.v0, model.t, np.zeros_like(omegas), omegas))
    unit = model.pose.to_world(cat_position(model.v0, model.t, np.full_like(omegas, model.sigma_a), omegas))
    return base, unit - base


def _corner_side(model, omegas, corner):
    """Which side of the line of each turn rate the corner lies on (the cross product)."""
    base, d = _lines(model, omegas)
    return d[:, 0] * (corner[1] - base[:, 1]) - d[:, 1] * (corner[0] - base[:, 0])


def cat_cell(model, cell, scan=20001):
    """The CAT probability of a world cell, exact in the acceleration, adaptive in omega.

    A line's share of the cell is smooth in omega except where the line passes a corner of the
    cell (its entry or exit edge changes there): those turn rates are found as sign changes of
    the corner's side of the line on a ``scan``-point grid, refined by ``brentq`` (or its zeros
    on the grid), and given to ``quad`` as breakpoints, so that every piece it integrates is
    smooth. Only the stretches of omega whose lines cross the cell (widened by one scan step)
    are integrated.
    """
    s = model.sigma_omega
    x0, x1, y0, y1 = cell
    f = lambda w: float(line_shares(model, w, cell)[0]) * math.exp(-0.5 * (w / s) ** 2) / (s * math.sqrt(2 * math.pi))  # noqa: E731
    omegas = np.linspace(-model.k_sigma * s, model.k_sigma * s, scan)
    breaks = []
    for corner in ((x0, y0), (x1, y0), (x1, y1), (x0, y1)):
        side = _corner_side(model, omegas, corner)
        # a pass exactly at a scan node is no sign change of a step but a break all the same
        # (omega = 0 through a corner on the pose's axis: a line along a cell side jumps there)
        breaks += [float(w) for w in omegas[side == 0.0]]
        for k in np.flatnonzero(np.sign(side[:-1]) * np.sign(side[1:]) < 0):
            g = lambda w: float(_corner_side(model, w, corner)[0])  # noqa: E731
            breaks.append(optimize.brentq(g, omegas[k], omegas[k + 1], xtol=1e-15 * s, rtol=1e-15))
    hit = line_shares(model, omegas, cell) > 0.0
    total = 0.0
    k = 0
    while k < scan:
        if not hit[k]:
            k += 1
            continue
        start = k
        while k < scan and hit[k]:
            k += 1
        lo, hi = omegas[max(start - 1, 0)], omegas[min(k, scan - 1)]
        inner = sorted(b for b in breaks if lo < b < hi)
        with warnings.catch_warnings():  # quad's roundoff note: its estimate is at 1e-15 absolute
            warnings.simplefilter("ignore", integrate.IntegrationWarning)
            value, _ = integrate.quad(f, lo, hi, points=inner or None, epsabs=1e-15, epsrel=1e-11,
                                      limit=max(200, 4 * len(inner)))
        total += value
    return total


def pdf_cell(model, cell, eps=1e-12):
    """``dblquad`` of the model's density over a world cell."""
    x0, x1, y0, y1 = cell
    f = lambda y, x: float(model.pdf(np.array([x]), np.array([y]))[0])  # noqa: E731
    value, _ = integrate.dblquad(f, x0, x1, y0, y1, epsabs=eps, epsrel=1e-9)
    return value


# --- swept cells: polar coordinates about a point, the kinks as breakpoints --------------------


def ray_segment(point, cell, theta):
    """``(r_in, r_out)`` of the ray from ``point`` at bearing ``theta`` (clockwise from north)
    inside the world cell ``(x0, x1, y0, y1)`` (equal where it misses)."""
    x0, x1, y0, y1 = cell
    lo, hi = 0.0, math.inf
    for start, step, a, b in ((point[0], math.sin(theta), x0, x1), (point[1], math.cos(theta), y0, y1)):
        if abs(step) < 1e-300:
            if not a <= start <= b:
                return 0.0, 0.0
            continue
        ra, rb = sorted(((a - start) / step, (b - start) / step))
        lo, hi = max(lo, ra), min(hi, rb)
    return lo, max(lo, hi)


def bearing_span(point, cell, seams=()):
    """The bearings ``[t0, t1]`` the cell subtends about ``point`` (the whole circle where it holds
    the point) and the breakpoints inside: the corners' bearings and ``seams``, unwrapped."""
    x0, x1, y0, y1 = cell
    px, py = point
    corners = [math.atan2(cx - px, cy - py) for cx, cy in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]
    if x0 <= px <= x1 and y0 <= py <= y1:
        t0 = corners[0]
        t1 = t0 + 2.0 * math.pi
        unwrap = lambda b: t0 + (b - t0) % (2.0 * math.pi)  # noqa: E731
    else:
        centre = math.atan2(0.5 * (x0 + x1) - px, 0.5 * (y0 + y1) - py)
        unwrap = lambda b: centre + (b - centre + math.pi) % (2.0 * math.pi) - math.pi  # noqa: E731
        rel = [unwrap(c) for c in corners]
        t0, t1 = min(rel), max(rel)
    inner = sorted({unwrap(b) for b in (*corners, *seams)} - {t0, t1})
    return t0, t1, [b for b in inner if t0 < b < t1]


def polar_law_cell(law, point, cell, seams=(), eps=1e-11):
    """The probability of a world cell under a density that is, in polar coordinates about
    ``point``, g(theta) N(r; mu(theta), sd(theta)) / r (a polar banana about its origin):
    ``law(theta) -> (g, mu, sd)`` (sd <= 0: no mass at that bearing). Exact in r (normal CDFs
    at the ray's entry and exit), SciPy's adaptive ``quad`` over the bearing with the corners'
    bearings and ``seams`` as breakpoints."""
    t0, t1, breaks = bearing_span(point, cell, seams)

    def f(theta):
        g, mu, sd = law(theta)
        if not sd > 0.0 or g == 0.0:
            return 0.0
        r_in, r_out = ray_segment(point, cell, theta)
        if r_out <= r_in:
            return 0.0
        z_in, z_out = (r_in - mu) / sd, (r_out - mu) / sd
        share = ndtr(-z_in) - ndtr(-z_out) if z_in > 0.0 else ndtr(z_out) - ndtr(z_in)
        return g * share

    with warnings.catch_warnings():  # roundoff notes where the integrand is 1e-300
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        value, _ = integrate.quad(f, t0, t1, points=breaks or None, epsabs=0.0, epsrel=eps, limit=500)
    return value


def polar_banana_law(model):
    """``law(theta)`` of :func:`polar_law_cell` for a rough or improved PolarBanana without
    heading noise, eqs. (7), (8), (11) of the polar-banana paper written with ``math``: phi is
    the bearing from the heading wrapped to (-pi, pi], g its normal density N(0, sigma_omega t / 2)."""
    v0, t, sa, sw = model.v0, model.t, model.sigma_a, model.sigma_omega
    s_phi = 0.5 * sw * t
    heading = model.pose.heading

    def law(theta):
        phi = (theta - heading + math.pi) % (2.0 * math.pi) - math.pi
        if phi == -math.pi:
            phi = math.pi
        sinc = math.sin(phi) / phi if phi != 0.0 else 1.0
        if model.variant == "rough":
            mu, sd = v0 * t * sinc, 0.5 * sa * t * t
        else:
            scc = (4.0 * sinc - math.cos(phi)) / 3.0
            mu = v0 * t * sinc + sa**2 * t**3 / (12.0 * v0) * (phi**2 / s_phi**2 - 1.0) * scc
            sd = 0.5 * sa * t * t * (1.0 + sa**2 / (6.0 * v0**2) * (t * t / 12.0 - phi**2 / sw**2)) * scc
        g = math.exp(-0.5 * (phi / s_phi) ** 2) / (math.sqrt(2.0 * math.pi) * s_phi)
        return g, mu, sd

    return law


def pdf_polar_cell(model, point, cell, seams=(), eps=1e-10):
    """The probability of a world cell by nested adaptive ``quad`` of ``model.pdf`` in polar
    coordinates about ``point`` (r p r dr dtheta), the corners' bearings and ``seams`` as
    breakpoints of the outer integral: for densities without a closed radial law."""
    t0, t1, breaks = bearing_span(point, cell, seams)
    px, py = point

    def inner(theta):
        r_in, r_out = ray_segment(point, cell, theta)
        if r_out <= r_in:
            return 0.0
        s, c = math.sin(theta), math.cos(theta)
        f = lambda r: float(model.pdf(np.array([px + r * s]), np.array([py + r * c]))[0]) * r  # noqa: E731
        return integrate.quad(f, r_in, r_out, epsabs=0.0, epsrel=eps, limit=200)[0]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        value, _ = integrate.quad(inner, t0, t1, points=breaks or None, epsabs=0.0, epsrel=eps, limit=200)
    return value


# --- cells of a grid ----------------------------------------------------------------------------


def grid_cells(grid):
    """``(i, j, (x0, x1, y0, y1))`` of every cell of ``grid``, rows south to north."""
    x0, _, y0, _ = grid.extent
    for i in range(grid.ny):
        for j in range(grid.nx):
            yield i, j, (x0 + grid.dx * j, x0 + grid.dx * (j + 1), y0 + grid.dy * i, y0 + grid.dy * (i + 1))


def cells_around(point, cell, n=3):
    """A grid of n x n cells of side ``cell`` centred on ``point`` (the middle one holds it)."""
    import bananagrid as bg

    return bg.Grid(origin=(point[0] - 0.5 * n * cell, point[1] - 0.5 * n * cell), dx=cell, dy=cell, nx=n, ny=n)


# --- cells crossed by several seams: Cartesian, every crossing a breakpoint ---------------------


def bearing_density(model):
    """The exact bearing map's density at a point, written with ``math`` (kernels/bearing.py's
    module docstring): exp(log_norm - sum_i wrap(beta_i - b_i)^2 / (2 sigma_i^2)), log_norm the
    model's normaliser (this oracle checks the cell rule, not the normaliser)."""
    log_norm = float(model.kernel_parameters()["log_norm"])
    stations = [(float(x), float(y), float(b), float(s)) for (x, y), b, s in
                zip(model.sensors, model.bearings, model.sigmas)]

    def density(x, y):
        total = log_norm
        for sx, sy, b, s in stations:
            z = (math.atan2(x - sx, y - sy) - b + math.pi) % (2.0 * math.pi) - math.pi
            total -= 0.5 * (z / s) ** 2
        return math.exp(total)

    return density


def _ray_hits_line(seam, axis, value):
    """The parameter s >= 0 at which the half-line ``seam`` = (x, y, bearing) reaches the line
    x = value (axis 0) or y = value (axis 1), or None."""
    qx, qy, b = seam
    start, step = ((qx, math.sin(b)), (qy, math.cos(b)))[axis]
    if step == 0.0:
        return None
    s = (value - start) / step
    return s if s >= 0.0 else None


def seams_cell(density, cell, seams, eps=1e-11):
    """The probability of a world cell by nested adaptive ``quad`` in Cartesian coordinates (x
    outside, y inside) of ``density(x, y)``, every kink a breakpoint: of the inner integral,
    the y at which each seam crosses the vertical line and each seam's start's y; of the
    outer, each start's x and the x at which a seam crosses the cell's bottom or top or
    another seam (between those the inner breakpoints move smoothly and keep their order)."""
    x0, x1, y0, y1 = cell
    seams = [tuple(float(v) for v in s) for s in np.asarray(seams, dtype=float).reshape(-1, 3)]
    starts_y = sorted({qy for _, qy, _ in seams if y0 < qy < y1})

    def inner(x):
        points = set(starts_y)
        for seam in seams:
            s = _ray_hits_line(seam, 0, x)
            if s is not None:
                y = seam[1] + s * math.cos(seam[2])
                if y0 < y < y1:
                    points.add(y)
        return integrate.quad(lambda y: density(x, y), y0, y1, points=sorted(points) or None, epsabs=0.0,
                              epsrel=eps, limit=400)[0]

    outer = {qx for qx, _, _ in seams}
    for seam in seams:
        for value in (y0, y1):
            s = _ray_hits_line(seam, 1, value)
            if s is not None:
                outer.add(seam[0] + s * math.sin(seam[2]))
    for i, (ax, ay, a) in enumerate(seams):  # pairwise crossings of the half-lines
        for bx, by, b in seams[i + 1:]:
            ux, uy, vx, vy = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
            den = ux * vy - uy * vx
            if den == 0.0:
                continue
            qx, qy = bx - ax, by - ay
            s, t = (qx * vy - qy * vx) / den, (qx * uy - qy * ux) / den
            if s >= 0.0 and t >= 0.0:
                outer.add(ax + s * ux)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        return integrate.quad(inner, x0, x1, points=sorted(v for v in outer if x0 < v < x1) or None, epsabs=0.0,
                              epsrel=eps, limit=400)[0]


def _ray_meets(origin, theta, seam):
    """The range at which the ray from ``origin`` at bearing ``theta`` meets the half-line
    ``seam`` = (x, y, bearing), or None."""
    ux, uy = math.sin(theta), math.cos(theta)
    vx, vy = math.sin(seam[2]), math.cos(seam[2])
    den = ux * vy - uy * vx
    if den == 0.0:
        return None
    qx, qy = seam[0] - origin[0], seam[1] - origin[1]
    r, s = (qx * vy - qy * vx) / den, (qx * uy - qy * ux) / den
    return r if r > 0.0 and s >= 0.0 else None


def lattice_cell(density, origin, heading, ranges, bearings, seams, eps=1e-11):
    """The probability of a polar lattice cell (``ranges`` = (r0, r1), ``bearings`` = (b0, b1)
    clockwise from ``heading`` about ``origin``) by nested adaptive ``quad`` of
    ``density(x, y) r`` in (b, r): the inner integral's breakpoints are the ranges at which each
    seam crosses the ray, the outer's the bearings at which a seam crosses the arcs r0 and r1
    (a quadratic in the seam's own parameter), its start's bearing, and a seam's own bearing
    and its opposite (a seam along a ray of the lattice); the inner ones also the ray's nearest
    approach to each start."""
    (r0, r1), (b0, b1) = ranges, bearings
    ox, oy = origin
    seams = [tuple(float(v) for v in s) for s in np.asarray(seams, dtype=float).reshape(-1, 3)]
    outer = set()
    for qx, qy, beta in seams:
        dx, dy = qx - ox, qy - oy
        vx, vy = math.sin(beta), math.cos(beta)
        outer |= {math.atan2(dx, dy), beta, beta + math.pi}
        b = dx * vx + dy * vy
        for radius in (r0, r1):
            disc = b * b - (dx * dx + dy * dy - radius * radius)
            if disc >= 0.0:
                for s in (-b - math.sqrt(disc), -b + math.sqrt(disc)):
                    if s >= 0.0:
                        outer.add(math.atan2(dx + s * vx, dy + s * vy))
    outer = sorted({b0 + (t - heading - b0) % (2.0 * math.pi) for t in outer} - {b0, b1})
    outer = [t for t in outer if b0 < t < b1]

    def inner(b):
        theta = heading + b
        s, c = math.sin(theta), math.cos(theta)
        # and the ray's nearest approach to each start (the peak of a 1 / r there, or where the
        # direction from a station turns fastest)
        near = [(qx - ox) * s + (qy - oy) * c for qx, qy, _ in seams]
        points = sorted({r for r in (*(_ray_meets(origin, theta, seam) for seam in seams), *near)
                         if r is not None and r0 < r < r1})
        return integrate.quad(lambda r: density(ox + r * s, oy + r * c) * r, r0, r1, points=points or None,
                              epsabs=0.0, epsrel=eps, limit=400)[0]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        return integrate.quad(inner, b0, b1, points=outer or None, epsabs=0.0, epsrel=eps, limit=400)[0]


def polar_banana_density(model):
    """A rough or improved PolarBanana's density at a world point from :func:`polar_banana_law`:
    g(theta) N(rho; mu, sd) / rho in polar coordinates (rho, theta) about its start."""
    law = polar_banana_law(model)
    ox, oy = model.pose.origin

    def density(x, y):
        rho = math.hypot(x - ox, y - oy)
        g, mu, sd = law(math.atan2(x - ox, y - oy))
        if not sd > 0.0 or rho == 0.0:
            return 0.0
        return g * math.exp(-0.5 * ((rho - mu) / sd) ** 2) / (math.sqrt(2.0 * math.pi) * sd * rho)

    return density


# --- a polar banana's cells on a lattice about another origin: exact in its own range ----------


def _sector_inside(rel_x, rel_y, ranges, bearings, heading):
    """Whether the point (rel_x, rel_y) from a lattice's origin lies in its annular sector."""
    (r0, r1), (b0, b1) = ranges, bearings
    r = math.hypot(rel_x, rel_y)
    rel = b0 + (math.atan2(rel_x, rel_y) - heading - b0) % (2.0 * math.pi)
    return r0 <= r <= r1 and rel <= b1


def sector_ray_pieces(start, theta, origin, heading, ranges, bearings):
    """The range intervals ``[(lo, hi), ...]`` of the ray from ``start`` at bearing ``theta``
    that lie in the annular sector ``ranges`` x ``bearings`` (clockwise from ``heading``) about
    ``origin``. Written with ``math`` from the geometry alone: the ray (d + rho w from the
    origin, d = start - origin) meets a circle of radius R where rho^2 + 2 rho (d.w) + |d|^2 -
    R^2 = 0 and the line of a bounding ray u where (d + rho w) x u = 0; between consecutive
    events it is in or out of the sector as its midpoint is."""
    (r0, r1), (b0, b1) = ranges, bearings
    dx, dy = start[0] - origin[0], start[1] - origin[1]
    wx, wy = math.sin(theta), math.cos(theta)
    along = dx * wx + dy * wy
    d2 = dx * dx + dy * dy
    far = 2.0 * (math.sqrt(d2) + r1) + 1.0
    events = {0.0, far}
    for radius in (r0, r1):
        disc = along * along - d2 + radius * radius
        if disc >= 0.0:
            for rho in (-along - math.sqrt(disc), -along + math.sqrt(disc)):
                if 0.0 < rho < far:
                    events.add(rho)
    for b in (b0, b1):
        ux, uy = math.sin(heading + b), math.cos(heading + b)
        den = wx * uy - wy * ux
        if den != 0.0:
            rho = -(dx * uy - dy * ux) / den
            if 0.0 < rho < far:
                events.add(rho)
    events = sorted(events)
    pieces = []
    for lo, hi in zip(events[:-1], events[1:]):
        mid = 0.5 * (lo + hi)
        if hi > lo and _sector_inside(dx + mid * wx, dy + mid * wy, ranges, bearings, heading):
            if pieces and pieces[-1][1] == lo:
                pieces[-1] = (pieces[-1][0], hi)
            else:
                pieces.append((lo, hi))
    return pieces


def _normal_share(mu, sd, lo, hi):
    """N(mu, sd)'s mass on [lo, hi], from the upper tails where both ends lie above the mean."""
    z_in, z_out = (lo - mu) / sd, (hi - mu) / sd
    return float(ndtr(-z_in) - ndtr(-z_out)) if z_in > 0.0 else float(ndtr(z_out) - ndtr(z_in))


def _sign_changes(f, a, b, scan):
    """Roots of ``f`` on [a, b] (None where it is not defined): sign changes on a
    ``scan``-point grid refined by ``brentq``."""
    xs = np.linspace(a, b, scan)
    values = [f(x) for x in xs]
    roots = []
    for k in range(scan - 1):
        u, v = values[k], values[k + 1]
        if u is None or v is None:
            continue
        if u == 0.0:
            roots.append(float(xs[k]))
        elif u * v < 0.0:
            roots.append(optimize.brentq(f, xs[k], xs[k + 1], xtol=1e-15, rtol=1e-15))
    return roots


def sector_clip_breaks(point, origin, heading, ranges, bearings) -> set:
    """Directions from ``point`` at which its rays' clip by the lattice cell (``ranges`` x
    ``bearings`` clockwise from ``heading`` about ``origin``) changes: towards the cell's
    corners and the lattice's origin, tangent to the cell's two circles, and along the bounding
    rays' lines (there a ray's crossing with one runs off to infinity)."""
    (px, py), (ox, oy) = (float(c) for c in point), (float(c) for c in origin)
    (r0, r1), (b0, b1) = ranges, bearings
    dx, dy = px - ox, py - oy
    distance = math.hypot(dx, dy)
    breaks = set()
    for radius in (r0, r1):
        for b in (b0, b1):
            breaks.add(math.atan2(ox + radius * math.sin(heading + b) - px, oy + radius * math.cos(heading + b) - py))
    if distance > 0.0:
        towards = math.atan2(-dx, -dy)
        breaks.add(towards)
        for radius in (r0, r1):
            if 0.0 < radius <= distance * (1.0 + 1e-12):  # on the circle: at right angles
                half = math.asin(min(1.0, radius / distance))
                breaks |= {towards - half, towards + half}
    breaks |= {heading + b + turn for b in (b0, b1) for turn in (0.0, math.pi)}
    return breaks


def banana_lattice_cell(model, origin, heading, ranges, bearings, eps=1e-12, scan=4001):
    """The probability of a polar lattice cell (``ranges`` = (r0, r1), ``bearings`` = (b0, b1)
    clockwise from ``heading`` about ``origin``, any origin) under a rough or improved
    PolarBanana without heading noise, exact in the banana's own range.

    In polar coordinates (rho, theta) about the banana's start S the density is g N(rho; mu,
    sd) / rho (:func:`polar_banana_law`) and the area element rho drho dtheta: along each ray
    from S the mass inside the cell is a sum of normal-CDF differences over the ray's pieces
    inside it (:func:`sector_ray_pieces`, closed form). SciPy's adaptive ``quad`` integrates that
    over theta in (h - pi, h + pi], every theta at which the pieces' structure changes a
    breakpoint: the bearings from S of the cell's corners and of the lattice's origin, the
    tangents from S to the cell's two circles, the directions of its bounding rays' lines
    (there a ray's crossing with one runs off to infinity), the seams (the wrap at h +- pi,
    the P_sigma = 0 edge at h +- its limit), and where the ridge S + mu(theta) w(theta)
    crosses the cell's circles and bounding lines (there a share steps over a turn of sd
    over the rate at which ridge and edge part: a sharp feature where the ridge narrows or
    runs along an edge)."""
    law = polar_banana_law(model)
    sx, sy = (float(c) for c in model.pose.origin)
    h = float(model.pose.heading)
    (r0, r1), (b0, b1) = (float(v) for v in ranges), (float(v) for v in bearings)
    ranges, bearings = (r0, r1), (b0, b1)
    ox, oy = (float(c) for c in origin)
    lo_t, hi_t = h - math.pi, h + math.pi
    unwrap = lambda t: lo_t + (t - lo_t) % (2.0 * math.pi)  # noqa: E731
    dx, dy = sx - ox, sy - oy
    breaks = sector_clip_breaks((sx, sy), (ox, oy), heading, ranges, bearings)
    if model.variant == "improved" and model.sigma_positive_limit < math.pi:
        breaks |= {h - model.sigma_positive_limit, h + model.sigma_positive_limit}

    def ridge(theta):
        _, mu, _ = law(theta)
        return dx + mu * math.sin(theta), dy + mu * math.cos(theta)

    def live(theta):
        return law(theta)[2] > 0.0

    crossing = [lambda t, R=R: math.hypot(*ridge(t)) - R for R in (r0, r1)]
    for b in (b0, b1):
        ux, uy = math.sin(heading + b), math.cos(heading + b)
        crossing.append(lambda t, ux=ux, uy=uy: (lambda p: p[0] * uy - p[1] * ux)(ridge(t)))
    for f in crossing:
        breaks |= set(_sign_changes(lambda t, f=f: f(t) if live(t) else None, lo_t, hi_t, scan))
    points = sorted({unwrap(t) for t in breaks} - {lo_t})
    edges = [lo_t] + [t for t in points if lo_t < t < hi_t] + [hi_t]

    def f(theta):
        g, mu, sd = law(theta)
        if not sd > 0.0 or g == 0.0:
            return 0.0
        return g * math.fsum(_normal_share(mu, sd, lo, hi)
                             for lo, hi in sector_ray_pieces((sx, sy), theta, (ox, oy), heading, ranges, bearings))

    parts = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        for a, b in zip(edges[:-1], edges[1:]):
            if b > a:
                parts.append(integrate.quad(f, a, b, epsabs=1e-18, epsrel=eps, limit=1000)[0])
    return math.fsum(parts)


def banana_mass(model, eps=1e-13):
    """The plane mass of a rough or improved PolarBanana without heading noise: the integral
    of g(theta) Phi(mu / sd) over theta in (h - pi, h + pi] (rho > 0 only), the P_sigma = 0
    edge a breakpoint."""
    law = polar_banana_law(model)
    h = float(model.pose.heading)
    points = []
    if model.variant == "improved" and model.sigma_positive_limit < math.pi:
        points = [h - model.sigma_positive_limit, h + model.sigma_positive_limit]

    def f(theta):
        g, mu, sd = law(theta)
        return g * float(ndtr(mu / sd)) if sd > 0.0 else 0.0

    return integrate.quad(f, h - math.pi, h + math.pi, points=points or None, epsabs=0.0, epsrel=eps, limit=500)[0]


def point_lattice_cell(density, point, origin, heading, ranges, bearings, seams, eps=1e-11):
    """The probability of a polar lattice cell (as for :func:`banana_lattice_cell`) by nested
    adaptive ``quad`` of ``density(x, y) rho`` in polar coordinates (theta, rho) about
    ``point`` (a station inside or beside the cell, about which the density changes with
    the direction only), the ray's pieces in the cell from :func:`sector_ray_pieces`. The
    inner integral's breakpoints: the ranges at which each seam crosses the ray and the
    ray's nearest approach to each seam's start; the outer's: the bearings from the point of
    the cell's corners, of the lattice's origin, of every seam's start and of a seam's
    crossings with the cell's circles, the tangents to the circles, the directions of the
    bounding rays' lines and of every seam (and their opposites)."""
    (r0, r1), (b0, b1) = (float(v) for v in ranges), (float(v) for v in bearings)
    ranges, bearings = (r0, r1), (b0, b1)
    px, py = (float(c) for c in point)
    ox, oy = (float(c) for c in origin)
    seams = [tuple(float(v) for v in s) for s in np.asarray(seams, dtype=float).reshape(-1, 3)]
    breaks = sector_clip_breaks((px, py), (ox, oy), heading, ranges, bearings)
    for qx, qy, beta in seams:
        breaks |= {beta, beta + math.pi}
        if (qx, qy) != (px, py):
            breaks.add(math.atan2(qx - px, qy - py))
        vx, vy = math.sin(beta), math.cos(beta)
        along = (qx - ox) * vx + (qy - oy) * vy
        d2 = (qx - ox) ** 2 + (qy - oy) ** 2
        for radius in (r0, r1):
            disc = along * along - d2 + radius * radius
            if disc >= 0.0:
                for s in (-along - math.sqrt(disc), -along + math.sqrt(disc)):
                    if s >= 0.0 and (qx + s * vx, qy + s * vy) != (px, py):
                        breaks.add(math.atan2(qx + s * vx - px, qy + s * vy - py))
    lo_t = -math.pi
    points = sorted({lo_t + (t - lo_t) % (2.0 * math.pi) for t in breaks} - {lo_t})
    edges = [lo_t] + [t for t in points if lo_t < t < math.pi] + [math.pi]

    def inner(theta):
        s, c = math.sin(theta), math.cos(theta)
        total = 0.0
        for lo, hi in sector_ray_pieces((px, py), theta, (ox, oy), heading, ranges, bearings):
            near = [(qx - px) * s + (qy - py) * c for qx, qy, _ in seams]
            cuts = sorted({r for r in (*(_ray_meets((px, py), theta, seam) for seam in seams), *near)
                           if r is not None and lo < r < hi})
            total += integrate.quad(lambda r: density(px + r * s, py + r * c) * r, lo, hi, points=cuts or None,
                                    epsabs=0.0, epsrel=eps, limit=400)[0]
        return total

    parts = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        for a, b in zip(edges[:-1], edges[1:]):
            if b > a:
                parts.append(integrate.quad(inner, a, b, epsabs=0.0, epsrel=eps, limit=400)[0])
    return math.fsum(parts)
