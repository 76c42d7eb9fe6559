"""Independent float64 oracle for Butterly's density (3.1), (2.5) with a uniform or von Mises
course.

Nothing here imports or mirrors ``bananagrid`` or its kernels: no eigen-frame, no secular
equation, no walk. For each point and travelled range r it sums, over a uniform grid of N
courses c_j = 2 pi j / N (c a bearing clockwise from north, e(c) = (sin c, cos c)),

    log N(u - r e(c_j); mean, cov) + log p(c_j)

with the bivariate normal's log-density written through the Cholesky factor of cov (never its
inverse), then combines the terms by scipy.special.logsumexp: the periodic trapezoid rule with
N a power of two, far finer than the integrand's peak (width about sigma_min / r), applied in
log space so that nothing underflows in the far tails. Each call also returns the rule's own
convergence: the relative change from N / 2 to N nodes (a periodic trapezoid rule converges
geometrically, so a tiny change means both are converged).
"""

from __future__ import annotations

import math
from decimal import Decimal, localcontext
from fractions import Fraction
from functools import lru_cache

import numpy as np
from scipy.special import ive, logsumexp


def oracle_nodes(r_over_sigma: float, kappa: float = 0.0) -> int:
    """A power of two above 32 nodes per peak width sigma_min / r (and per 1 / sqrt(kappa))."""
    need = 512 + 32.0 * r_over_sigma + 32.0 * math.sqrt(kappa)
    return 2 ** math.ceil(math.log2(need))


def _log_normal(dx, dy, cov):
    """log N((dx, dy); 0, cov) by the Cholesky factor L (cov = L L^T): -|L^-1 d|^2 / 2 - log(2 pi det L)."""
    l11 = math.sqrt(cov[0][0])
    l21 = cov[0][1] / l11
    l22 = math.sqrt(cov[1][1] - l21 * l21)
    w1 = dx / l11
    w2 = (dy - l21 * w1) / l22
    return -0.5 * (w1 * w1 + w2 * w2) - math.log(2.0 * math.pi * l11 * l22)


def _log_course(c, kappa, course_mean):
    """log of exp(kappa cos(c - c0)) / (2 pi I0(kappa)), written with ive (no overflow)."""
    return kappa * (np.cos(c - course_mean) - 1.0) - math.log(2.0 * math.pi * ive(0, kappa))


def log_density(x, y, mean, cov, ranges, weights, *, kappa=0.0, course_mean=0.0, n):
    """log p(x, y) for points x, y (1-d arrays) with the n-node rule."""
    c = 2.0 * math.pi * np.arange(n) / n
    sc, cc = np.sin(c), np.cos(c)
    log_pc = _log_course(c, kappa, course_mean)
    out = np.empty(len(x))
    for k, (px, py) in enumerate(zip(x, y)):
        terms = []
        for r, w in zip(ranges, weights):
            if w <= 0:
                continue
            lg = _log_normal(px - mean[0] - r * sc, py - mean[1] - r * cc, cov) + log_pc
            terms.append(math.log(w) + logsumexp(lg) + math.log(2.0 * math.pi / n))
        out[k] = logsumexp(terms)
    return out


def butterly_density(x, y, mean, cov, ranges, weights, *, kappa=0.0, course_mean=0.0, n=None):
    """(density, self_check): p(x, y) per m^2 at points (x, y) and the relative change of the
    result from n / 2 to n course nodes (n defaults to oracle_nodes of the largest r / sigma_min)."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    y = np.atleast_1d(np.asarray(y, dtype=float))
    if n is None:
        sigma_min = math.sqrt(np.linalg.eigvalsh(np.asarray(cov, dtype=float))[0])
        n = oracle_nodes(max(ranges) / sigma_min, kappa)
    fine = log_density(x, y, mean, cov, ranges, weights, kappa=kappa, course_mean=course_mean, n=n)
    coarse = log_density(x, y, mean, cov, ranges, weights, kappa=kappa, course_mean=course_mean, n=n // 2)
    return np.exp(fine), np.abs(np.expm1(coarse - fine))


# ---------------------------------------------------------------------------------------------
# Needles: a start correlated to within 1e-8 of 1 (extended precision, exact Cholesky)
# ---------------------------------------------------------------------------------------------

#: pi to long double precision (numpy's pi is a float64).
_PI = np.longdouble("3.141592653589793238462643383279502884")


def _long(value: Fraction) -> np.longdouble:
    """A rational rounded to long double (through a 40-digit decimal string)."""
    with localcontext() as context:
        context.prec = 40
        text = str(Decimal(value.numerator) / Decimal(value.denominator))
    return np.longdouble(text)


def exact_cholesky(cov):
    """(l11, l21, l22) of cov = L L^T in long double for the float64 entries as given, with
    l22^2 = det / cov[0][0] from the determinant in exact rationals: float64 loses a relative
    eps / (1 - rho^2) of l22^2 to cancellation (1e-8 at rho = 1 - 1e-8), long double on
    cov11 - l21^2 still 1e-11."""
    a, b, c = (Fraction(float(v)) for v in (cov[0][0], cov[0][1], cov[1][1]))
    l11 = np.sqrt(_long(a))
    return l11, _long(b) / l11, np.sqrt(_long((a * c - b * b) / a))


@lru_cache(maxsize=8)
def _courses(n: int):
    """sin and cos of the n courses 2 pi j / n in long double."""
    c = 2 * _PI * np.arange(n, dtype=np.longdouble) / n
    return np.sin(c), np.cos(c)


def needle_density(x, y, mean, cov, ranges, weights, *, n=None):
    """(density, self_check) as :func:`butterly_density` for a uniform course, with every
    exponent in long double (64-bit significand) from :func:`exact_cholesky`: the whitened
    offset L^-1 (u - mean - r e(c)) cancels to O(1) from terms of |u - mean| / sigma_min (up to
    1e5 for a needle), which float64 would leave wrong by 1e-11 absolute; long double by 1e-14.
    The exponents less their maximum are then summed in float64 (the periodic trapezoid rule)."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    y = np.atleast_1d(np.asarray(y, dtype=float))
    l11, l21, l22 = exact_cholesky(cov)
    if n is None:
        sigma_min = math.sqrt(np.linalg.eigvalsh(np.asarray(cov, dtype=float))[0])
        n = oracle_nodes(max(ranges) / sigma_min)
    sc, cc = _courses(n)
    v1 = sc / l11  # L^-1 e(c), e(c) = (sin c, cos c)
    v2 = (cc - l21 * v1) / l22
    log_det = float(np.log(2 * _PI * l11 * l22))
    out = np.empty((2, len(x)))
    for k, (px, py) in enumerate(zip(x, y)):
        w1 = (np.longdouble(px) - np.longdouble(mean[0])) / l11
        w2 = ((np.longdouble(py) - np.longdouble(mean[1])) - l21 * w1) / l22
        for row, step in enumerate((1, 2)):
            logs = []
            for r, w in zip(ranges, weights):
                if w <= 0:
                    continue
                # the nodes within e^-200 of the largest by a float64 pass (its error in the
                # exponent is below 1e-3), then those in long double
                a1, a2 = v1[::step], v2[::step]
                e64 = -0.5 * ((float(w1) - r * a1.astype(float)) ** 2 + (float(w2) - r * a2.astype(float)) ** 2)
                keep = e64 >= e64.max() - 200.0
                r = np.longdouble(r)
                d1 = w1 - r * a1[keep]
                d2 = w2 - r * a2[keep]
                e = -0.5 * (d1 * d1 + d2 * d2)
                top = e.max()
                total = math.fsum(np.exp((e - top).astype(float)))
                logs.append(float(top) + math.log(total * w * step / n))
            out[row, k] = logsumexp(logs) - log_det
    return np.exp(out[0]), np.abs(np.expm1(out[1] - out[0]))
