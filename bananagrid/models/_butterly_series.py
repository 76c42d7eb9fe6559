"""Butterly's Bessel series (3.8), corrected per ERRATA, as a second method (NumPy/SciPy).

In the start covariance's eigen frame (S1 <= S2 its eigenvalues, Butterly's S_u, S_v), with
whitened coordinates z = (u' / sqrt(S1), v' / sqrt(S2)) and rho_k = r / sqrt(S_k), the exponent of
the course integral is -q' + a cos theta + b sin theta - F cos 2 theta (Appendix A) with

    q' = |z|^2 / 2 + (rho1^2 + rho2^2) / 4 (+ kappa for a von Mises course),
    a = rho1 z1 (+ kappa cos theta0),  b = rho2 z2 (+ kappa sin theta0),  F = (rho1^2 - rho2^2) / 4,
    w' = |(a, b)| = r sqrt((u'/S1)^2 + (v'/S2)^2)  (ERRATA's correction of Appendix A),
    gamma' = atan2(b, a).

Expanding exp(-F cos 2 theta) = sum_k (-1)^k I_k(F) e^(2 i k theta) and integrating term by
term gives (3.8):

    P(u) = (2 pi)^-1 (S1 S2)^-1/2 exp(-q') sum_{k>=0} (-1)^k eps_k I_k(F) I_2k(w') cos(2 k gamma'),

eps_0 = 1, eps_k = 2. Written with exponentially scaled Bessel functions (scipy.special.ive),
I_k(F) I_2k(w') = ive(k, F) ive(2k, w') exp(F + w'), so nothing overflows: the series is
exp(F + w' - q') times an alternating sum of terms of size <= 1.

Where it works, and where it fails
----------------------------------
The sum equals exp(g* - F - w') times a number of order one, g* = max_theta (a cos theta +
b sin theta - F cos 2 theta) <= F + w'. Its terms are of order one, so rounding leaves an
absolute error of about K eps in the sum and a relative error of about

    K eps exp(F + w' - g*),   i.e.  log10(e) (F + w' - g*) digits lost  (``lost_digits``).

No digit is lost for an isotropic start (F = 0: the sum is ive(0, w'), Rice's law), nor along
the major axis where both peaks of the integrand coincide (g* = F + w'). Off it the loss grows
like F = (r^2 / 4)(1/S1 - 1/S2): at r / sigma_min = 10 and a 3:1 elongation the points on the
minor axis lose 2F / ln 10 = 19 digits (all of them), and far out in the tails in that direction
the loss grows further. K, the number of terms, grows like sqrt(F) and sqrt(w'), so large
r / sigma also makes the series slow. The kernel's quadrature has neither problem.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from ..protocol import DensityModel

__all__ = ["series_density", "series_terms"]


def series_terms(big_f, w, *, digits: float = 40.0, max_terms: int = 20000) -> int:
    """Terms needed: ive(k, F) ~ exp(-k^2 / 2F) and ive(2k, w) ~ exp(-2 k^2 / w), so the terms
    fall below exp(-digits) past min(sqrt(2 F digits), sqrt(w digits / 2)), plus a margin."""
    big_f = float(np.max(big_f, initial=0.0))
    w = float(np.max(w, initial=0.0))
    k = min(math.sqrt(2.0 * big_f * digits), math.sqrt(0.5 * w * digits)) + 30.0
    return int(min(max_terms, math.ceil(k)))


def _max_exponent(a, b, big_f, n_scan: int = 256) -> np.ndarray:
    """g* = max_theta (a cos theta + b sin theta - F cos 2 theta): a scan, then Newton steps."""
    theta = 2.0 * math.pi * np.arange(n_scan) / n_scan
    g = a[:, None] * np.cos(theta) + b[:, None] * np.sin(theta) - big_f[:, None] * np.cos(2 * theta)
    t = theta[np.argmax(g, axis=1)]
    for _ in range(8):
        d1 = -a * np.sin(t) + b * np.cos(t) + 2 * big_f * np.sin(2 * t)
        d2 = -a * np.cos(t) - b * np.sin(t) + 4 * big_f * np.cos(2 * t)
        step = np.where(d2 < 0, -d1 / np.where(d2 < 0, d2, -1.0), 0.0)
        t = t + np.clip(step, -0.5 / math.sqrt(n_scan), 0.5 / math.sqrt(n_scan))
    value = a * np.cos(t) + b * np.sin(t) - big_f * np.cos(2 * t)
    return np.maximum(value, g.max(axis=1))


def series_density(model: DensityModel, x, y, *, max_terms: int = 20000):
    """Density per m^2 of a :class:`~bananagrid.Butterly` by the Bessel series (3.8).

    Returns
    -------
    density : ndarray
        The series summed in float64 with ive (see the module docstring).
    lost_digits : ndarray
        log10(e) (F + w' - g*) for the worst speed at each point: the decimal digits that
        cancellation costs there (the result keeps about 15.6 - lost_digits - log10(K)).
    """
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    shape = x.shape
    x, y = x.ravel(), y.ravel()
    s1, s2, beta = model.axes
    c, s = math.cos(beta), math.sin(beta)
    dx, dy = x - model.mean[0], y - model.mean[1]
    z1 = (dx * c + dy * s) / math.sqrt(s1)  # Butterly's u' / sqrt(S_u), (3.2)
    z2 = (dy * c - dx * s) / math.sqrt(s2)  # v' / sqrt(S_v)
    kappa = model.course_kappa
    theta0 = 0.5 * math.pi - beta - model.course_mean
    speeds, weights = model.speed_nodes
    density = np.zeros(x.size)
    lost = np.zeros(x.size)
    for r, weight in zip(speeds * model.t, weights):
        rho1, rho2 = r / math.sqrt(s1), r / math.sqrt(s2)
        big_f = 0.25 * (rho1 - rho2) * (rho1 + rho2)
        a = rho1 * z1 + kappa * math.cos(theta0)
        b = rho2 * z2 + kappa * math.sin(theta0)
        w = np.hypot(a, b)
        gamma = np.arctan2(b, a)
        q = 0.5 * (z1 * z1 + z2 * z2) + 0.25 * (rho1 * rho1 + rho2 * rho2) + kappa
        n_terms = series_terms(big_f, w, max_terms=max_terms)
        total = special.ive(0, big_f) * special.ive(0, w)
        for k in range(1, n_terms):
            total = total + (-1) ** k * 2.0 * special.ive(k, big_f) * special.ive(2 * k, w) * np.cos(2 * k * gamma)
        coef = weight / (2.0 * math.pi * (math.sqrt(s1) * math.sqrt(s2)) * special.ive(0, kappa))
        # log of an exact 0 sum is -inf (gives 0); where cancellation leaves garbage it may overflow
        with np.errstate(under="ignore", divide="ignore", over="ignore"):
            density += coef * np.sign(total) * np.exp(big_f + w - q + np.log(np.abs(total)))
        g_star = _max_exponent(a, b, np.full_like(a, big_f))
        lost = np.maximum(lost, (big_f + w - g_star) / math.log(10.0))
    return density.reshape(shape), lost.reshape(shape)
