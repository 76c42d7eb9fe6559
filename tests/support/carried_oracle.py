"""Independent references for the CAT cell probabilities with earlier evidence inside
(tests/models/test_cat_carried_cells.py).

A path is fixed by (a, omega): its position at any time s is eq. (1) of the polar-banana paper
(``cat_position``, NumPy). For one turn rate the paths at the map's time t form a line in
z = a / sigma_a; the cell keeps [z_in, z_out] of it (the slabs of the cell, as
``cell_oracle.line_shares``). The same paths at an earlier time s form the line of omega at s;
each polygon edge is met where a 2 x 2 linear system says (``numpy.linalg.solve``), the window
is cut at those z, and each piece is weighted by the factors of the polygons that hold its
midpoint's earlier position (``Polygon.contains``, the even-odd rule of the evidence layer):
exact in z, with no ribbons, no walk and no sweep of the kernel. The integral over omega is
SciPy's adaptive ``quad`` with the normal weight, to 1e-10 relative, its breakpoints the turn
rates where the piece structure changes: where a line passes a cell corner or an earlier line a
polygon vertex (sign changes of the point's side of the line on a scan, ``brentq``, as
``cell_oracle.cat_cell`` finds the corners), and where a crossing enters or leaves the window
(changes of the count of crossings in it on a scan, bisected to 1e-15 of sigma_omega).
"""

import functools
import math
import warnings

import numpy as np
from scipy import integrate, optimize
from scipy.special import ndtr

from bananagrid.evidence.geometry import Polygon
from bananagrid.models.cat import cat_position
from cell_oracle import line_shares


@functools.lru_cache(maxsize=1 << 16)
def _line(model, omega, s):
    """World point at z = 0 and step per unit z of the line of ``omega`` at time ``s``, eq. (1)
    written with ``math``: u = omega s, local (x, y) = v0 s (A, B) + a s^2 (C, D) with A = (1 -
    cos u) / u = 2 sin^2(u / 2) / u, B = sin u / u, C = (sin u - u cos u) / u^2, D = (cos u + u
    sin u - 1) / u^2 (Taylor series below |u| = 1e-2), turned by the pose (x east of the
    heading, y along it). Cached: one turn rate's window, crossings and pieces read the same."""
    u = omega * s
    if abs(u) < 1e-2:
        a_, b_ = u / 2.0 - u**3 / 24.0 + u**5 / 720.0, 1.0 - u * u / 6.0 + u**4 / 120.0
        c_, d_ = u / 3.0 - u**3 / 30.0 + u**5 / 840.0, 0.5 - u * u / 8.0 + u**4 / 144.0
    else:
        a_, b_ = 2.0 * math.sin(0.5 * u) ** 2 / u, math.sin(u) / u
        c_, d_ = (math.sin(u) - u * math.cos(u)) / u**2, (math.cos(u) + u * math.sin(u) - 1.0) / u**2
    px, py = model.v0 * s * a_, model.v0 * s * b_
    qx, qy = model.sigma_a * s * s * c_, model.sigma_a * s * s * d_
    (ox, oy), h = model.pose.origin, model.pose.heading
    ch, sh = math.cos(h), math.sin(h)
    return (ox + px * ch + py * sh, oy - px * sh + py * ch), (qx * ch + qy * sh, -qx * sh + qy * ch)


def _key(vertices):
    return tuple((float(x), float(y)) for x, y in vertices)


@functools.lru_cache(maxsize=256)
def _polygon(vertices):
    return Polygon(np.asarray(vertices, dtype=float))


def _share(lo, hi):
    return float(ndtr(-lo) - ndtr(-hi)) if lo >= 0.0 else float(ndtr(hi) - ndtr(lo))


def window(model, omega, cell, z_max=9.0):
    """[z_in, z_out] of the line of ``omega`` at the map's time in the world cell (or None)."""
    base, step = _line(model, float(omega), float(model.t))
    lo, hi = -z_max, z_max
    for axis, (a, b) in enumerate(((cell[0], cell[1]), (cell[2], cell[3]))):
        if step[axis] == 0.0:
            if not a <= base[axis] < b:
                return None
            continue
        za, zb = (a - base[axis]) / step[axis], (b - base[axis]) / step[axis]
        lo, hi = max(lo, min(za, zb)), min(hi, max(za, zb))
    return (lo, hi) if lo < hi else None


def crossings(model, omega, s, vertices):
    """z of the crossings of the line of ``omega`` at time ``s`` with the polygon's edges: the
    2 x 2 system base + z step = a + tau (b - a) by Cramer's rule, kept for tau in [0, 1]."""
    (px, py), (qx, qy) = _line(model, float(omega), float(s))
    out = []
    n = len(vertices)
    for k in range(n):
        (ax, ay), (bx, by) = vertices[k], vertices[(k + 1) % n]
        ex, ey = ax - bx, ay - by  # the matrix [[qx, ex], [qy, ey]] of (z, tau)
        det = qx * ey - qy * ex
        if abs(det) < 1e-300:
            continue
        rx, ry = ax - px, ay - py
        z, tau = (rx * ey - ry * ex) / det, (qx * ry - qy * rx) / det
        if 0.0 <= tau <= 1.0:
            out.append(z)
    return out


def pieces(model, omega, cell, polygons):
    """``[(z_lo, z_hi, weights per polygon inside), ...]`` of the window of ``omega``."""
    win = window(model, omega, cell)
    if win is None:
        return []
    lo, hi = win
    cuts = {lo, hi}
    for vertices, s, _ in polygons:
        cuts.update(z for z in crossings(model, omega, s, vertices) if lo < z < hi)
    cuts = sorted(cuts)
    out = []
    for z0, z1 in zip(cuts[:-1], cuts[1:]):
        mid = 0.5 * (z0 + z1)
        inside = []
        for vertices, s, _ in polygons:
            (px, py), (qx, qy) = _line(model, float(omega), float(s))
            inside.append(bool(_polygon(_key(vertices)).contains(px + mid * qx, py + mid * qy)))
        out.append((z0, z1, inside))
    return out


def weighted_share(model, omega, cell, polygons, mask):
    """Sum over the window's pieces of the product of the factors of ``mask``'s polygons that
    hold the piece, times its normal mass."""
    total = 0.0
    for z0, z1, inside in pieces(model, omega, cell, polygons):
        w = 1.0
        for p, (_, _, miss) in enumerate(polygons):
            if (mask >> p) & 1 and inside[p]:
                w *= miss
        total += w * _share(z0, z1)
    return total


def _window_count(model, omega, cell, polygons):
    """How many crossings of the earlier lines lie in the window (-1: no window)."""
    win = window(model, omega, cell)
    if win is None:
        return -1
    lo, hi = win
    return sum(sum(lo < z < hi for z in crossings(model, omega, s, vertices)) for vertices, s, _ in polygons)


def _lines(model, omegas, time):
    """Points at z = 0 and steps per unit z of the lines of ``omegas`` at ``time``, (n, 2) each."""
    base = model.pose.to_world(cat_position(model.v0, time, np.zeros_like(omegas), omegas))
    return base, model.pose.to_world(cat_position(model.v0, time, np.full_like(omegas, model.sigma_a), omegas)) - base


def _window_counts(model, omegas, cell, polygons):
    """:func:`_window_count` for an array of turn rates, the same formulas in NumPy."""
    base, step = _lines(model, omegas, model.t)
    lo, hi = np.full(len(omegas), -9.0), np.full(len(omegas), 9.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, (a, b) in enumerate(((cell[0], cell[1]), (cell[2], cell[3]))):
            flat = step[:, axis] == 0.0
            za, zb = (a - base[:, axis]) / step[:, axis], (b - base[:, axis]) / step[:, axis]
            inside = (a <= base[:, axis]) & (base[:, axis] < b)
            lo = np.where(flat, np.where(inside, lo, np.inf), np.maximum(lo, np.minimum(za, zb)))
            hi = np.where(flat, np.where(inside, hi, -np.inf), np.minimum(hi, np.maximum(za, zb)))
        count = np.zeros(len(omegas), dtype=int)
        for vertices, s, _ in polygons:
            (px, py), (qx, qy) = (v.T for v in _lines(model, omegas, s))
            n = len(vertices)
            for k in range(n):
                (ax, ay), (bx, by) = vertices[k], vertices[(k + 1) % n]
                ex, ey = ax - bx, ay - by
                det = qx * ey - qy * ex
                rx, ry = ax - px, ay - py
                z, tau = (rx * ey - ry * ex) / det, (qx * ry - qy * rx) / det
                count += (np.abs(det) >= 1e-300) & (tau >= 0.0) & (tau <= 1.0) & (lo < z) & (z < hi)
    return np.where(lo < hi, count, -1)


def _passes(model, omegas, time, point, near):
    """Turn rates where the line at ``time`` passes ``point`` (the sign of the point's side of
    the line changes on the scan ``omegas``; ``brentq`` to 1e-15 of sigma_omega, or the side is
    exactly 0 at a scan node), in the scan's steps where ``near`` (a mask of the scan) holds at
    either end."""
    def side(w):
        w = np.atleast_1d(np.asarray(w, dtype=float))
        base = model.pose.to_world(cat_position(model.v0, time, np.zeros_like(w), w))
        d = model.pose.to_world(cat_position(model.v0, time, np.full_like(w, model.sigma_a), w)) - base
        return d[:, 0] * (point[1] - base[:, 1]) - d[:, 1] * (point[0] - base[:, 0])

    values = side(omegas)
    # a pass exactly at a scan node (a line through a corner or vertex there: the straight line
    # omega = 0 along a cell side x = 0 of a grid on the pose's axes) is no sign change of a
    # step, but a break all the same: there a line along a side leaves the window empty on one
    # side and full on the other, a jump that quad alone resolves only to ~1e-10 absolute
    out = [float(w) for w in omegas[(values == 0.0) & near]]
    for k in np.flatnonzero((np.sign(values[:-1]) * np.sign(values[1:]) < 0) & (near[:-1] | near[1:])):
        out.append(optimize.brentq(lambda w: float(side(w)[0]), omegas[k], omegas[k + 1],
                                   xtol=1e-15 * model.sigma_omega, rtol=1e-15))
    return out


def carried_cell(model, cell, polygons, mask, scan=201):
    """The probability of the world cell ``(x0, x1, y0, y1)`` weighted by the factors of
    ``mask``'s polygons, ``polygons`` a list of ``(vertices, time, miss)``. Breakpoints of
    ``quad``: the turn rates where the line at t passes a corner of the cell and an earlier
    line a polygon vertex (sign changes of the side on 20001 turn rates over +-k_sigma
    sigma_omega, ``brentq``), and, over each stretch whose lines reach the cell
    (``cell_oracle.line_shares``, widened by a step), where the count of earlier crossings in
    the window changes (a ``scan``, bisected)."""
    sw = model.sigma_omega
    g = lambda w: math.exp(-0.5 * (w / sw) ** 2) / (sw * math.sqrt(2.0 * math.pi))  # noqa: E731
    f = lambda w: weighted_share(model, w, cell, polygons, mask) * g(w)  # noqa: E731
    coarse = np.linspace(-model.k_sigma * sw, model.k_sigma * sw, 20001)
    x0, x1, y0, y1 = cell
    hit = line_shares(model, coarse, cell) > 0.0
    near = hit | np.roll(hit, 1) | np.roll(hit, -1)
    breaks = []
    for corner in ((x0, y0), (x1, y0), (x1, y1), (x0, y1)):
        breaks += _passes(model, coarse, model.t, corner, near)
    for vertices, s, _ in polygons:
        for vertex in vertices:
            breaks += _passes(model, coarse, s, vertex, near)
    total = []
    k = 0
    while k < len(coarse):
        if not hit[k]:
            k += 1
            continue
        start = k
        while k < len(coarse) and hit[k]:
            k += 1
        lo, hi = coarse[max(start - 1, 0)], coarse[min(k, len(coarse) - 1)]
        omegas = np.linspace(lo, hi, scan)
        counts = _window_counts(model, omegas, cell, polygons)
        edges = [lo, hi] + [b for b in breaks if lo < b < hi]
        for q in range(scan - 1):
            if counts[q] != counts[q + 1] and counts[q] >= 0 and counts[q + 1] >= 0:
                a, b = omegas[q], omegas[q + 1]
                while True:
                    m = 0.5 * (a + b)
                    if not a < m < b or b - a < 1e-15 * sw:
                        break
                    if _window_count(model, m, cell, polygons) == counts[q]:
                        a = m
                    else:
                        b = m
                edges.append(0.5 * (a + b))
        edges = sorted(edges)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", integrate.IntegrationWarning)
            for a, b in zip(edges[:-1], edges[1:]):
                if b > a:
                    total.append(integrate.quad(f, a, b, epsabs=1e-16, epsrel=1e-10, limit=200)[0])
    return math.fsum(total)


def carried_mass(model, polygons, mask):
    """The whole plane's weighted mass: the integral over omega of the weighted normal mass of
    the whole line (|z| <= 9), pieces cut at every crossing."""
    sw = model.sigma_omega

    def f(w):
        cuts = {-9.0, 9.0}
        for vertices, s, _ in polygons:
            cuts.update(z for z in crossings(model, w, s, vertices) if -9.0 < z < 9.0)
        cuts = sorted(cuts)
        total = 0.0
        for z0, z1 in zip(cuts[:-1], cuts[1:]):
            mid = 0.5 * (z0 + z1)
            wgt = 1.0
            for p, (vertices, s, miss) in enumerate(polygons):
                (px, py), (qx, qy) = _line(model, float(w), float(s))
                if (mask >> p) & 1 and _polygon(_key(vertices)).contains(px + mid * qx, py + mid * qy):
                    wgt *= miss
            total += wgt * _share(z0, z1)
        return total * math.exp(-0.5 * (w / sw) ** 2) / (sw * math.sqrt(2.0 * math.pi))

    span = model.k_sigma * sw
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        return integrate.quad(f, -span, span, epsabs=1e-14, epsrel=1e-10, limit=2000)[0]
