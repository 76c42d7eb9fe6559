"""Composite Gauss-Legendre rules sized from a model's length scales (shared by polar lattices
and grid cells)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["GAUSS_TOL", "MAX_ORDER", "MAX_SUBINTERVALS", "gauss_error", "axis_plan", "unit_rule"]

_TWO_PI = 2.0 * math.pi

#: Target Gauss-Legendre error per sub-interval and axis, for a normal feature whose SD equals
#: the length scale, as a fraction of that feature's mass (see :func:`gauss_error`).
GAUSS_TOL = 1e-10

#: Most Gauss-Legendre nodes per sub-interval.
MAX_ORDER = 8

#: Most sub-intervals per cell and axis (so at most MAX_SUBINTERVALS * MAX_ORDER nodes per axis).
MAX_SUBINTERVALS = 256


def error_constant(n: int) -> float:
    """Gauss-Legendre remainder on [-1, 1]: E = K_n f^(2n)(xi), K_n = 2^(2n+1) (n!)^4 /
    ((2n + 1) ((2n)!)^3)."""
    return 2.0 ** (2 * n + 1) * math.factorial(n) ** 4 / ((2 * n + 1) * float(math.factorial(2 * n)) ** 3)


def gauss_error(n: int, q: float) -> float:
    r"""Error bound of the n-point Gauss-Legendre rule on an interval of width ``q sigma`` for a
    normal density of SD sigma (as a fraction of its unit mass).

    .. math:: E \le K_n (q/2)^{2n+1} \max|\mathrm{He}_{2n}(z)\,\varphi(z)|
              = K_n (q/2)^{2n+1} (2n-1)!! / \sqrt{2\pi}

    (the maximum is at z = 0). With q = 1: 2.8e-4 (n = 2), 2.4e-8 (4), 7.8e-13 (6).
    """
    double_factorial = math.prod(range(1, 2 * n, 2))
    return error_constant(n) * (0.5 * q) ** (2 * n + 1) * double_factorial / math.sqrt(_TWO_PI)


def axis_plan(width: float, scale: float, cap: int) -> tuple[int, int, float]:
    """``(m, n, error)``: m equal sub-intervals of at most ``scale`` (no more than ``cap``) with
    the fewest nodes n <= MAX_ORDER whose :func:`gauss_error` meets GAUSS_TOL."""
    m = max(1, min(cap, math.ceil(width / scale * (1.0 - 1e-12))))
    q = width / (m * scale)
    for n in range(1, MAX_ORDER + 1):
        err = gauss_error(n, q)
        if err <= GAUSS_TOL:
            return m, n, err
    return m, MAX_ORDER, min(err, 1.0)  # beyond q ~ 2 the bound says nothing: at most the mass


def unit_rule(m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre rule on [0, 1]: m sub-intervals of n nodes; (nodes, weights)."""
    x, w = np.polynomial.legendre.leggauss(n)
    nodes = (np.arange(m)[:, None] + 0.5 * (x[None, :] + 1.0)) / m
    return nodes.ravel(), np.tile(0.5 * w / m, m)
