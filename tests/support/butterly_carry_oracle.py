"""Independent float64 oracle of Butterly's carried density: the course integral with each
path's weight inside, by adaptive quadrature (scipy.integrate.quad) between breakpoints.

Nothing here mirrors the kernels: no eigen frame, no secular equation, no walk, no pack. For a
point x at the map's time t and a speed V (range r = V t), the path of course c (a bearing
clockwise from north, e(c) = (sin c, cos c)) is at X(s) = x - V (t - s) e(c) at time s, and

    P^w(x) = sum_i w_i int_0^{2 pi} N(x - r_i e(c); mean, cov) p(c) W_i(c) dc,
    W_i(c) = prod_k l_k(X_i(s_k; c))

with each evidence's likelihood l_k taken from its own NumPy ``likelihood`` (AreaSearch,
PositionReport, BearingReport) at its time. An area search over an interval (t0, t1) with
coverage C (``miss`` = exp(-C)) is taken as random search spread evenly over the interval: the
path's hazard is C times the fraction of the interval it spends inside the polygon, computed
exactly for a straight path as the length of the segment X([t0, t1]) inside the polygon over its
length (``segment_fraction_inside``), or, with ``rule``, by a composite Gauss-Legendre rule in
time (the pack's: what the kernels integrate over courses).

A definite-range track weighs a path 0 where its closest approach to the searcher is within
W / 2 (``definite_oracle.closest_approach``: dense sampling and ``minimize_scalar`` per leg),
else 1: constant between the courses where that switches (``definite_oracle.switch_courses``),
so it is taken once per piece, at the piece's middle course.

[0, 2 pi] is cut at every course where a path crosses an edge at a search's time (the circle of
radius V (t - s) about x against each edge), where a search interval's segment passes a vertex,
where a definite-range track's weight switches, and into sub-intervals no wider than a tenth of
the integrand's peak width sigma_min / r, and each piece is integrated by ``quad`` to a
relative 1e-12.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import integrate
from scipy.special import ive

from definite_oracle import closest_approach, straight_path, switch_courses


def _definite(ev) -> bool:
    return getattr(ev, "law", None) == "definite"


def definite_weight(model, evidence, x, r, c) -> float:
    """The definite-range tracks' weight of the path of course ``c`` (a float) through x with
    range r at the map's time: 0 if any comes within W / 2, else 1."""
    for ev in evidence:
        if _definite(ev):
            if closest_approach(ev.track, straight_path(x, r / model.t, model.t, c)) <= 0.5 * ev.sweep_width:
                return 0.0
    return 1.0


def _normal(dx, dy, cov):
    inv = np.linalg.inv(cov)
    q = inv[0, 0] * dx * dx + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy * dy
    return np.exp(-0.5 * q) / (2 * math.pi * math.sqrt(np.linalg.det(cov)))


def segment_fraction_inside(p0, p1, vertices) -> np.ndarray:
    """Fraction of each segment p0 -> p1 ((n, 2) arrays) inside the polygon (even-odd rule):
    the parameters where it crosses the edges, sorted, and the midpoints of the pieces tested."""
    p0, p1 = np.atleast_2d(p0), np.atleast_2d(p1)
    v = np.asarray(vertices, dtype=float)
    a, b = v, np.roll(v, -1, axis=0)
    d = p1 - p0
    out = np.empty(len(p0))
    for k in range(len(p0)):
        e = b - a
        denom = d[k, 0] * e[:, 1] - d[k, 1] * e[:, 0]
        w = a - p0[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / denom
            u = (w[:, 0] * d[k, 1] - w[:, 1] * d[k, 0]) / denom
        cuts = np.sort(s[(denom != 0) & (s > 0) & (s < 1) & (u >= 0) & (u <= 1)])
        knots = np.concatenate(([0.0], cuts, [1.0]))
        mids = 0.5 * (knots[1:] + knots[:-1])
        px, py = p0[k, 0] + mids * d[k, 0], p0[k, 1] + mids * d[k, 1]
        out[k] = float(np.sum(np.diff(knots) * _contains(v, px, py)))
    return out


def _contains(v, px, py):
    a, b = v, np.roll(v, -1, axis=0)
    inside = np.zeros(np.shape(px), dtype=bool)
    for (ax, ay), (bx, by) in zip(a, b):
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = ax + (py - ay) * (bx - ax) / (by - ay)
        inside ^= ((ay > py) != (by > py)) & (px < cross)
    return inside


def _circle_courses(x, radius, vertices):
    """Courses c at which x - radius e(c) lies on an edge of the polygon."""
    out = []
    if radius <= 0:
        return out
    v = np.asarray(vertices, dtype=float)
    for a, b in zip(v, np.roll(v, -1, axis=0)):
        d, f = b - a, a - x
        qa, qb, qc = d @ d, 2 * f @ d, f @ f - radius * radius
        disc = qb * qb - 4 * qa * qc
        if disc < 0:
            continue
        for u in ((-qb - math.sqrt(disc)) / (2 * qa), (-qb + math.sqrt(disc)) / (2 * qa)):
            if 0 <= u <= 1:
                p = a + u * d
                e = (x - p) / radius
                out.append(math.atan2(e[0], e[1]) % (2 * math.pi))
    return out


def time_rule(t0: float, t1: float, panels: int, points: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre nodes and weights over [t0, t1] (``panels`` of ``points``)."""
    x, w = np.polynomial.legendre.leggauss(points)
    edges = np.linspace(t0, t1, panels + 1)
    half, mid = 0.5 * np.diff(edges), 0.5 * (edges[1:] + edges[:-1])
    return (mid[:, None] + half[:, None] * x).ravel(), (half[:, None] * w).ravel()


def weight(model, evidence, x, r, c, rule=None):
    """W(c) of the paths through x with range r at the map's time (array c). With ``rule`` =
    (panels, points) an area search over an interval takes the fraction of it spent inside by
    that Gauss-Legendre rule in time instead of exactly."""
    t = model.t
    e = np.stack((np.sin(c), np.cos(c)), axis=-1)
    w = np.ones(np.shape(c))
    for ev in evidence:
        if _definite(ev):
            w = w * np.vectorize(lambda u: definite_weight(model, [ev], x, r, float(u)))(c)
            continue
        t0, t1 = ev.time_span
        if t0 < t1 and rule is not None:
            nodes, q = time_rule(t0, t1, *rule)
            radius = r * (t - nodes) / t  # (N,)
            px = x[0] - radius * e[..., 0, None]
            py = x[1] - radius * e[..., 1, None]
            hazard = np.sum(q * ev.region.contains(px, py), axis=-1)
            w = w * np.exp(math.log(ev.miss) * hazard / (t1 - t0))
        elif t0 == t1:
            pos = x - (r * (t - t0) / t) * e
            w = w * ev.likelihood(pos[..., 0], pos[..., 1])
        else:  # an area search over (t0, t1): coverage spread evenly over the interval
            p0 = x - (r * (t - t0) / t) * e
            p1 = x - (r * (t - t1) / t) * e
            inside = segment_fraction_inside(p0.reshape(-1, 2), p1.reshape(-1, 2), ev.region.vertices)
            w = w * np.exp(math.log(ev.miss) * inside).reshape(np.shape(c)) if ev.miss > 0 else w * np.where(
                inside.reshape(np.shape(c)) > 0, 0.0, 1.0)
    return w


def breakpoints(model, evidence, x, r, rule=None):
    """Courses where W jumps or kinks for the range r."""
    t = model.t
    out = []
    for ev in evidence:
        if _definite(ev):
            out += switch_courses(ev.track, x, r / t, t, ev.sweep_width)
            continue
        region = getattr(ev, "region", None)
        if region is None:
            continue
        t0, t1 = ev.time_span
        times = {t0, t1} if rule is None or t0 == t1 else set(time_rule(t0, t1, *rule)[0].tolist())
        for s in times:
            out += _circle_courses(x, r * (t - s) / t, region.vertices)
        if t1 > t0 and rule is None:  # the segment passes a vertex
            for p in region.vertices:
                d = x - p
                dist = math.hypot(*d)
                if r * (t - t1) / t <= dist <= r * (t - t0) / t and dist > 0:
                    out.append(math.atan2(d[0], d[1]) % (2 * math.pi))
    return out


def carried_density(model, evidence, x, y, *, epsrel=1e-12, rule=None) -> np.ndarray:
    """The carried (unnormalised) density at points (x, y), float64 (``rule``: see :func:`weight`)."""
    x, y = np.atleast_1d(np.asarray(x, dtype=float)), np.atleast_1d(np.asarray(y, dtype=float))
    v, wv = model.speed_nodes
    cov = np.asarray(model.cov, dtype=float)
    mean = np.asarray(model.mean, dtype=float)
    kappa, c0 = model.course_kappa, model.course_mean
    inv = np.linalg.inv(cov)
    i00, i01, i11 = float(inv[0, 0]), float(inv[0, 1]), float(inv[1, 1])
    norm = 1.0 / (2 * math.pi * math.sqrt(np.linalg.det(cov)) * 2 * math.pi * ive(0, kappa))
    sigma_min = math.sqrt(np.linalg.eigvalsh(cov)[0])
    out = np.zeros(len(x))
    for k, (px, py) in enumerate(zip(x, y)):
        point = np.array([px, py])
        for speed, w_i in zip(v, wv):
            r = speed * model.t
            dx0, dy0 = px - mean[0], py - mean[1]

            def log_g(c):
                dx = dx0 - r * np.sin(c)
                dy = dy0 - r * np.cos(c)
                return -0.5 * (i00 * dx * dx + 2 * i01 * dx * dy + i11 * dy * dy) + kappa * (np.cos(c - c0) - 1.0)

            # the courses where the integrand is within e^-60 of its largest value (a fine scan,
            # 20 nodes per peak width sigma_min / r), cut into pieces of one peak width
            n_scan = max(2048, math.ceil(20 * 2 * math.pi * r / sigma_min))
            grid = 2 * math.pi * np.arange(n_scan + 1) / n_scan
            lg = log_g(grid)
            top = float(lg.max())
            keep = lg > top - 60.0
            keep = keep | np.roll(keep, 1) | np.roll(keep, -1)
            knots = set(grid[keep].tolist()[:: max(1, 20)] + [0.0, 2 * math.pi])
            knots.update(b for b in breakpoints(model, evidence, point, r, rule))
            knots = np.array(sorted(knots))

            others = [ev for ev in evidence if not _definite(ev)]

            def f(c):
                return math.exp(float(log_g(c)) - top) * float(weight(model, others, point, r, np.array(c), rule))

            total = 0.0
            for a, b in zip(knots[:-1], knots[1:]):
                mid = np.linspace(a, b, 5)
                if b - a > 1e-15 and (np.any(lg[np.searchsorted(grid, mid, side="right") - 1] > top - 60.0)
                                      or np.any(log_g(mid) > top - 60.0)):
                    # the definite tracks' weight is constant on the piece (their switches are knots)
                    if definite_weight(model, evidence, point, r, 0.5 * (a + b)) > 0.0:
                        total += integrate.quad(f, a, b, epsabs=0.0, epsrel=epsrel, limit=200)[0]
            out[k] += w_i * norm * math.exp(top) * total
    return out
