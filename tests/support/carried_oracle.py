"""Independent references for the CAT cell probabilities with earlier evidence inside
(tests/models/test_cat_carried.py).

A path is fixed by (a, omega): its position at any time s is eq. (1) of the polar-banana paper
(``cat_position``, NumPy). For one turn rate the paths at the map's time t form a line in
z = a / sigma_a; the cell keeps [z_in, z_out] of it (the slabs of the cell, as
``cell_oracle.line_shares``). The same paths at an earlier time s form the line of omega at s;
each polygon edge is met where a 2 x 2 linear system says (``numpy.linalg.solve``), the window
is cut at those z, and each piece is weighted by the factors of the polygons that hold its
midpoint's earlier position (``Polygon.contains``, the even-odd rule of the evidence layer):
exact in z, with no ribbons, no walk and no sweep of the kernel. The integral over omega is
SciPy's adaptive ``quad`` with the normal weight, to 1e-11 relative, its breakpoints the turn
rates where the piece structure changes (a line passes a cell corner, an earlier line a polygon
vertex, a crossing enters or leaves the window): found as changes of an integer signature on a
scan of omega, refined by bisection to 1e-15 of sigma_omega.
"""

import math
import warnings

import numpy as np
from scipy import integrate
from scipy.special import ndtr

from bananagrid.evidence.geometry import Polygon
from bananagrid.models.cat import cat_position


def _line(model, omega, s):
    """World point at z = 0 and step per unit z of the line of ``omega`` at time ``s``."""
    w = np.array([omega, omega])
    pts = model.pose.to_world(cat_position(model.v0, s, np.array([0.0, model.sigma_a]), w))
    return pts[0], pts[1] - pts[0]


def _share(lo, hi):
    return float(ndtr(-lo) - ndtr(-hi)) if lo >= 0.0 else float(ndtr(hi) - ndtr(lo))


def window(model, omega, cell, z_max=9.0):
    """[z_in, z_out] of the line of ``omega`` at the map's time in the world cell (or None)."""
    base, step = _line(model, omega, model.t)
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
    """z of the crossings of the line of ``omega`` at time ``s`` with the polygon's edges."""
    base, step = _line(model, omega, s)
    out = []
    v = np.asarray(vertices, dtype=float)
    for a, b in zip(v, np.roll(v, -1, axis=0)):
        m = np.array([[step[0], a[0] - b[0]], [step[1], a[1] - b[1]]])
        if abs(np.linalg.det(m)) < 1e-300:
            continue
        z, tau = np.linalg.solve(m, a - base)
        if 0.0 <= tau <= 1.0:
            out.append(float(z))
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
            base, step = _line(model, omega, s)
            p = base + mid * step
            inside.append(bool(Polygon(np.asarray(vertices, dtype=float)).contains(p[0], p[1])))
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


def _signature(model, omega, cell, polygons):
    win = window(model, omega, cell)
    if win is None:
        return (-1,)
    lo, hi = win
    sig = []
    for vertices, s, _ in polygons:
        z = crossings(model, omega, s, vertices)
        sig.append(sum(lo < c < hi for c in z))
        sig.append(len(z))
    # which sides of the cell the line enters and leaves by
    base, step = _line(model, omega, model.t)
    sides = []
    for z in (lo, hi):
        p = base + z * step
        sides.append(int(np.argmin([abs(p[0] - cell[0]), abs(p[0] - cell[1]), abs(p[1] - cell[2]),
                                    abs(p[1] - cell[3]), 1e-9 * abs(abs(z) - 9.0)])))
    return tuple(sig + sides)


def carried_cell(model, cell, polygons, mask, scan=4001):
    """The probability of the world cell ``(x0, x1, y0, y1)`` weighted by the factors of
    ``mask``'s polygons, ``polygons`` a list of ``(vertices, time, miss)``."""
    sw = model.sigma_omega
    g = lambda w: math.exp(-0.5 * (w / sw) ** 2) / (sw * math.sqrt(2.0 * math.pi))  # noqa: E731
    f = lambda w: weighted_share(model, w, cell, polygons, mask) * g(w)  # noqa: E731
    omegas = np.linspace(-model.k_sigma * sw, model.k_sigma * sw, scan)
    sigs = [_signature(model, w, cell, polygons) for w in omegas]
    breaks = []
    for k in range(scan - 1):
        if sigs[k] != sigs[k + 1]:
            a, b = omegas[k], omegas[k + 1]
            left = sigs[k]
            while b - a > 1e-15 * sw:
                m = 0.5 * (a + b)
                if _signature(model, m, cell, polygons) == left:
                    a = m
                else:
                    b = m
            breaks.append(0.5 * (a + b))
    live = [k for k in range(scan) if sigs[k] != (-1,)]
    if not live:
        return 0.0
    lo, hi = omegas[max(live[0] - 1, 0)], omegas[min(live[-1] + 1, scan - 1)]
    edges = [lo] + sorted(b for b in breaks if lo < b < hi) + [hi]
    total = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        for a, b in zip(edges[:-1], edges[1:]):
            if b > a:
                total.append(integrate.quad(f, a, b, epsabs=1e-16, epsrel=1e-11, limit=200)[0])
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
                base, step = _line(model, w, s)
                q = base + mid * step
                if (mask >> p) & 1 and Polygon(np.asarray(vertices, dtype=float)).contains(q[0], q[1]):
                    wgt *= miss
            total += wgt * _share(z0, z1)
        return total * math.exp(-0.5 * (w / sw) ** 2) / (sw * math.sqrt(2.0 * math.pi))

    span = model.k_sigma * sw
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        return integrate.quad(f, -span, span, epsabs=1e-14, epsrel=1e-10, limit=2000)[0]
