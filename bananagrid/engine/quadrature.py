"""Composite Gauss-Legendre rules sized from a model's length scales (shared by polar lattices
and grid cells)."""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.special import ndtr

__all__ = ["GAUSS_TOL", "MAX_ORDER", "MAX_SUBINTERVALS", "gauss_error", "axis_plan", "unit_rule", "graded_rule",
           "seam_ranges", "split_segments", "ray_box_points", "ray_circle_points",
           "normal_shares"]

_TWO_PI = 2.0 * math.pi

#: Target Gauss-Legendre error per sub-interval and axis, for a normal feature whose SD equals
#: the length scale, as a fraction of that feature's mass (see :func:`gauss_error`).
GAUSS_TOL = 1e-10

#: Most Gauss-Legendre nodes per sub-interval.
MAX_ORDER = 8

#: Most sub-intervals per cell and axis (so at most MAX_SUBINTERVALS * MAX_ORDER nodes per axis).
MAX_SUBINTERVALS = 256


#: Halvings of a swept cell's bearing pieces toward a seam (to 1e-12 of the piece).
GRADE_LEVELS = 40


GRADE_SPLIT = 16


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
    x, w = _legendre(n)  # cached: a lattice asks for it once per cell
    nodes = (np.arange(m)[:, None] + 0.5 * (x[None, :] + 1.0)) / m
    return nodes.ravel(), np.tile(0.5 * w / m, m)


@functools.cache
def _legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.polynomial.legendre.leggauss(n)


def narrowing(sd: np.ndarray) -> tuple[bool, bool]:
    """Whether a law's SD, sampled along a piece from end to end, falls toward either end below
    a quarter of its largest (or to 0): the ends to grade (:func:`graded_rule`)."""
    top = float(np.max(sd, initial=0.0))
    return bool(sd[0] < 0.25 * top), bool(sd[-1] < 0.25 * top)


def graded_rule(a: float, b: float, scale: float, graded: tuple[bool, bool], extra=frozenset(),
                split: tuple[int, int] = (GRADE_SPLIT, GRADE_SPLIT)):
    """Gauss-Legendre nodes and weights on [a, b]: sub-intervals no wider than ``scale``, and
    toward an end that is a seam, also geometrically graded ones (GRADE_LEVELS halvings, each
    in ``split`` equal steps at that end), so that features narrowing in proportion to the
    distance from the seam (the improved polar banana's range SD P_sigma as it falls to 0)
    stay resolved; one step per halving is enough for an end where the integrand only turns
    like a square root (a ray's tangency to an arc). ``extra`` adds breakpoints. MAX_ORDER
    nodes per sub-interval."""
    m = max(1, min(MAX_SUBINTERVALS, math.ceil((b - a) / scale * (1.0 - 1e-12))))
    points = set((a + (b - a) * np.arange(m + 1) / m).tolist()) | set(extra)
    # ``split`` equal steps within each halving: a feature at a distance d from the seam and
    # as narrow as a small multiple of d sees steps of d / (2 split)
    def fractions(k):
        return (0.5 ** np.arange(1, GRADE_LEVELS + 1)[:, None] * (1.0 + np.arange(k) / k)).ravel()
    if graded[0]:
        points |= set((a + (b - a) * fractions(split[0])).tolist())
    if graded[1]:
        points |= set((b - (b - a) * fractions(split[1])).tolist())
    edges = np.array(sorted(points))
    x, w = _legendre(MAX_ORDER)
    half = 0.5 * np.diff(edges)[:, None]
    nodes = (edges[:-1, None] + half * (x[None, :] + 1.0)).ravel()
    return nodes, (half * w[None, :]).ravel()


def normal_shares(g, mu, sd, r_in, r_out) -> np.ndarray:
    """g times the normal mass N(mu, sd) between r_in and r_out (broadcast; 0 where sd <= 0 or
    r_out <= r_in), from the upper tails where both z are positive (no cancellation of values
    near 1)."""
    live = sd > 0.0
    sd = np.where(live, sd, 1.0)
    z_in, z_out = (r_in - mu) / sd, (r_out - mu) / sd
    share = np.where(z_in > 0.0, ndtr(-z_in) - ndtr(-z_out), ndtr(z_out) - ndtr(z_in))
    return np.where(live & (r_out > r_in), g * share, 0.0)


def seam_ranges(origin, theta, seams) -> np.ndarray:
    """Ranges along the rays from ``origin`` at bearings ``theta`` (shape (T,), clockwise from
    north) at which each of ``seams`` (rows (x, y, bearing), shape (F, 3): half-lines) crosses
    them: shape (T, F), NaN where a ray and a seam do not meet (parallel, or the crossing
    behind the ray's origin or the seam's start).

    O + r u(theta) = Q + s v(beta) gives r = (q x v) / (u x v) and s = (q x u) / (u x v), with
    q = Q - O and a x b = a_x b_y - a_y b_x: a seam that does not pass through the origin is a
    curve in polar coordinates about it, and a rule that splits each ray's range at r makes the
    kink along it a break.
    """
    theta = np.asarray(theta, dtype=float)
    seams = np.asarray(seams, dtype=float).reshape(-1, 3)
    ux, uy = np.sin(theta)[:, None], np.cos(theta)[:, None]
    qx, qy = (seams[:, 0] - origin[0])[None, :], (seams[:, 1] - origin[1])[None, :]
    vx, vy = np.sin(seams[:, 2])[None, :], np.cos(seams[:, 2])[None, :]
    den = ux * vy - uy * vx
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (qx * vy - qy * vx) / den
        s = (qx * uy - qy * ux) / den
    return np.where((den != 0.0) & (r > 0.0) & (s >= 0.0) & np.isfinite(r), r, np.nan)


def split_segments(r_in, r_out, cuts) -> tuple[np.ndarray, np.ndarray]:
    """The segments [r_in, r_out] (shape (T,)) cut at ``cuts`` (shape (T, F), NaN for none):
    ``(lo, hi)`` of shape (T, F + 1), the pieces in order (empty ones have lo = hi)."""
    r_in = np.asarray(r_in, dtype=float)
    r_out = np.asarray(r_out, dtype=float)
    cuts = np.clip(np.where(np.isnan(cuts), r_in[:, None], cuts), r_in[:, None], r_out[:, None])
    edges = np.sort(np.concatenate([r_in[:, None], cuts, r_out[:, None]], axis=1), axis=1)
    return edges[:, :-1], edges[:, 1:]


def ray_box_points(seam, box) -> list[tuple[float, float]]:
    """Where the half-line ``seam`` = (x, y, bearing) meets the sides of ``box`` = (x0, x1, y0,
    y1), and its start if the box holds it: the points at which it enters, leaves or ends in
    the box."""
    qx, qy, beta = (float(v) for v in seam)
    vx, vy = math.sin(beta), math.cos(beta)
    x0, x1, y0, y1 = box
    out = []
    if x0 <= qx <= x1 and y0 <= qy <= y1:
        out.append((qx, qy))
    for start, step, other_start, other_step, lines, lo, hi, axis in (
            (qx, vx, qy, vy, (x0, x1), y0, y1, 0), (qy, vy, qx, vx, (y0, y1), x0, x1, 1)):
        if step == 0.0:
            continue
        for line in lines:
            s = (line - start) / step
            if s < 0.0:
                continue
            other = other_start + s * other_step
            if lo <= other <= hi:
                out.append((line, other) if axis == 0 else (other, line))
    return out


def ray_circle_points(seam, centre, radius: float) -> list[tuple[float, float]]:
    """Where the half-line ``seam`` = (x, y, bearing) crosses the circle of ``radius`` about
    ``centre``: 0, 1 or 2 points."""
    qx, qy = float(seam[0]) - centre[0], float(seam[1]) - centre[1]
    vx, vy = math.sin(float(seam[2])), math.cos(float(seam[2]))
    along = qx * vx + qy * vy
    # s^2 + 2 s along + |q|^2 - R^2 = 0; the discriminant as (R - d)(R + d) + along^2 loses less
    d = math.hypot(qx, qy)
    disc = along * along + (radius - d) * (radius + d)
    if disc < 0.0:
        return []
    root = math.sqrt(disc)
    return [(centre[0] + qx + s * vx, centre[1] + qy + s * vy) for s in {-along - root, -along + root} if s >= 0.0]
