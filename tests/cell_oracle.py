"""Independent references for cell probabilities (tests/test_cell_probabilities.py).

CAT: for each turn rate the line P(a) = pos(a, omega) is clipped to the cell in NumPy (the
cell's two slabs, not the kernel's walk), and Phi(z_out) - Phi(z_in) is integrated over omega by
SciPy's adaptive ``quad`` with the normal weight, between the turn rates whose lines pass the
cell's corners (where the share has kinks), to 1e-11 relative. Other models: SciPy
``dblquad`` of ``pdf`` over the cell, or over the cell in polar coordinates about a point.
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
    the corner's side of the line on a ``scan``-point grid, refined by ``brentq``, and given to
    ``quad`` as breakpoints, so that every piece it integrates is smooth. Only the stretches of
    omega whose lines cross the cell (widened by one scan step) are integrated.
    """
    s = model.sigma_omega
    x0, x1, y0, y1 = cell
    f = lambda w: float(line_shares(model, w, cell)[0]) * math.exp(-0.5 * (w / s) ** 2) / (s * math.sqrt(2 * math.pi))  # noqa: E731
    omegas = np.linspace(-model.k_sigma * s, model.k_sigma * s, scan)
    breaks = []
    for corner in ((x0, y0), (x1, y0), (x1, y1), (x0, y1)):
        side = _corner_side(model, omegas, corner)
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
