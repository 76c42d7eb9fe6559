"""Independent float64 oracles for presence cells (Pessentheiner; ERRATA): SciPy adaptive
quadrature over a cell written from the geometry alone (no kernel code, no closed forms of the
package), and Monte Carlo binning of samples into cells.

Coordinates: azimuth phi from +x, elevation theta from +z; on the plane z = -d a direction
(phi, theta) meets rho = d tan(pi - theta) (ERRATA), the line y = -h at x = -h cot(phi).
"""

import math

import numpy as np
from scipy import integrate
from scipy.stats import multivariate_normal, norm


def mixture_pdf(weights, means, covs):
    """Scalar density of a Gaussian mixture via scipy.stats (not the package's pdf)."""
    laws = [(w, multivariate_normal(mean=m, cov=c)) for w, m, c in zip(weights, means, covs)]

    def pdf(*x):
        return sum(w * law.pdf(x) for w, law in laws)

    return pdf


def chord(phi, box):
    """Range of rho >= 0 for which rho (cos phi, sin phi) lies in box = ((x0, x1), (y0, y1))."""
    lo, hi = 0.0, math.inf
    for comp, (e0, e1) in ((math.cos(phi), box[0]), (math.sin(phi), box[1])):
        if comp == 0.0:
            if e0 > 0.0 or e1 < 0.0:
                return 0.0, 0.0
            continue
        a, b = sorted((e0 / comp, e1 / comp))
        lo, hi = max(lo, a), min(hi, b)
    return lo, max(lo, hi)


def radius(d, theta):
    """rho = d tan(pi - theta); inf at the horizon."""
    return math.inf if theta <= math.pi / 2 + 1e-15 else d * math.tan(math.pi - theta)


def plane_cell(pdf, d, phi0, phi1, theta0, theta1, box=None):
    """int_{phi0}^{phi1} int rho pdf(rho cos phi, rho sin phi) d rho d phi over the sector
    rho in [radius(d, theta1), radius(d, theta0)] (clipped to ``box``), by scipy dblquad."""
    r0, r1 = radius(d, theta1), radius(d, theta0)

    def lims(phi):
        if box is None:
            return r0, r1
        a, b = chord(phi, box)
        lo, hi = max(r0, a), min(r1, b)
        return lo, max(lo, hi)

    value, _ = integrate.dblquad(
        lambda r, p: r * pdf(r * math.cos(p), r * math.sin(p)), phi0, phi1,
        lambda p: lims(p)[0], lambda p: lims(p)[1], epsabs=1e-17, epsrel=1e-11,
    )
    return value


def frustum_cell(pdf, d0, d1, phi0, phi1, theta0, theta1, box=None):
    """Integral of pdf(x, y, z) over the frustum cell (depths d in [d0, d1], z = -d), clipped
    to ``box`` in (x, y), by scipy tplquad in (phi, d, rho)."""

    def lims(p, d):
        lo, hi = radius(d, theta1), radius(d, theta0)
        if box is not None:
            a, b = chord(p, box)
            lo, hi = max(lo, a), min(hi, b)
        return lo, max(lo, hi)

    value, _ = integrate.tplquad(
        lambda r, d, p: r * pdf(r * math.cos(p), r * math.sin(p), -d), phi0, phi1, d0, d1,
        lambda p, d: lims(p, d)[0], lambda p, d: lims(p, d)[1], epsabs=1e-16, epsrel=1e-9,
    )
    return value


def line_segment(weights, means, sds, x0, x1):
    """int_{x0}^{x1} sum_i w_i N(x; mu_i, sd_i) dx by scipy quad (infinite bounds allowed)."""
    total = 0.0
    for w, m, s in zip(weights, means, sds):
        total += w * integrate.quad(lambda x: norm.pdf(x, m, s), x0, x1, epsabs=1e-17, epsrel=1e-12, limit=200)[0]
    return total


def bin_samples(points, azimuth_edges, elevation_edges, depths):
    """Counts of samples (n, 2 or 3) per (azimuth, elevation) cell: a 2-D sample lies on the
    plane at depth depths[0]; a 3-D one has depth -z and is kept when within ``depths``. The
    azimuth edges cover a full turn; returns counts (n_az, n_el)."""
    pts = np.asarray(points, dtype=float)
    if pts.shape[1] == 2:
        d = np.full(pts.shape[0], depths[0])
    else:
        d = -pts[:, 2]
    keep = (d >= depths[0]) & (d <= depths[1])
    x, y, d = pts[keep, 0], pts[keep, 1], d[keep]
    phi = np.arctan2(y, x)
    a0 = azimuth_edges[0]
    step = azimuth_edges[1] - azimuth_edges[0]
    ia = np.floor(((phi - a0) % (2 * math.pi)) / step).astype(int) % (len(azimuth_edges) - 1)
    theta = math.pi - np.arctan2(np.hypot(x, y), d)
    ie = np.searchsorted(elevation_edges, theta, side="right") - 1
    ie = np.clip(ie, 0, len(elevation_edges) - 2)
    counts = np.zeros((len(azimuth_edges) - 1, len(elevation_edges) - 1))
    np.add.at(counts, (ia, ie), 1.0)
    return counts
