"""Independent float64 oracle of a definite-range track's detection: the closest approach of a
target path to the searcher over the track's span, by dense time sampling and SciPy's bounded
``minimize_scalar`` per leg, with no chords, no closed form and nothing of the pack.

The searcher runs straight between its track points (``np.interp`` of the track's x and y in
time); the path is any function of time (a Butterly straight path, a CAT path from
``cat_position``). On each leg the range is sampled at ``SAMPLES`` times, and the smallest
sample's neighbourhood (one sample either side) is refined by ``minimize_scalar`` (bounded, to
1e-12 of the leg's duration): the range is smooth on a leg, and within a sample spacing of its
minimum it is unimodal for the paths here (their curvature turns them through much less than a
radian over a spacing).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

#: Range samples per leg before the refinement.
SAMPLES = 257


def searcher_at(track: np.ndarray, s):
    """The searcher's position at times ``s`` (straight between the track's points)."""
    return np.stack((np.interp(s, track[:, 2], track[:, 0]), np.interp(s, track[:, 2], track[:, 1])), axis=-1)


def closest_approach(track: np.ndarray, path) -> float:
    """min over the track's span of |path(s) - searcher(s)|; ``path(s)`` returns (len(s), 2)."""
    best = math.inf
    for (ta, tb) in zip(track[:-1, 2], track[1:, 2]):
        s = np.linspace(ta, tb, SAMPLES)
        d = np.hypot(*(np.asarray(path(s)) - searcher_at(track, s)).T)
        i = int(np.argmin(d))
        lo, hi = s[max(i - 1, 0)], s[min(i + 1, SAMPLES - 1)]

        def rng(u):
            u = np.array([u])
            return float(np.hypot(*(np.asarray(path(u)) - searcher_at(track, u))[0]))

        res = optimize.minimize_scalar(rng, bounds=(lo, hi), method="bounded",
                                       options={"xatol": 1e-12 * (tb - ta)})
        best = min(best, float(d[i]), float(res.fun), rng(lo), rng(hi))
    return best


def sampled_approach(track: np.ndarray, positions: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Closest approach of many paths from their positions (n, len(times), 2) at fine
    ``times`` (the Monte Carlo's: the smallest sampled range, an overestimate by at most
    (relative speed x spacing)^2 / (8 x range))."""
    q = searcher_at(track, times)
    return np.hypot(positions[..., 0] - q[:, 0], positions[..., 1] - q[:, 1]).min(axis=1)


def straight_path(x, radius_rate, t, c):
    """Butterly's path through the map point ``x`` at ``t`` with course ``c`` and speed
    ``radius_rate``: x - V (t - s) e(c), e(c) = (sin c, cos c)."""
    e = np.array([math.sin(c), math.cos(c)])
    return lambda s: np.asarray(x)[None, :] - (radius_rate * (t - np.asarray(s, dtype=float)))[:, None] * e[None, :]


def switch_courses(track: np.ndarray, x, speed: float, t: float, sweep_width: float, n_scan: int = 0) -> list:
    """Courses in [0, 2 pi) where the straight path of ``speed`` through ``x`` at ``t`` switches
    between detected and missed: sign changes of (closest approach - W / 2) on a scan of
    ``n_scan`` courses (default: 16 per angle (W / 2) / R, R the path's largest distance from x
    over the track) of the sampled ranges, then of :func:`closest_approach` about each, refined
    by ``brentq`` to 1e-14."""
    h = 0.5 * sweep_width
    r_max = speed * (t - track[0, 2])
    if r_max <= 0.0:
        return []
    n_scan = n_scan or max(4096, math.ceil(16 * 2 * math.pi * r_max / h))
    c = 2 * math.pi * np.arange(n_scan + 1) / n_scan
    times = np.concatenate([np.linspace(ta, tb, 65) for ta, tb in zip(track[:-1, 2], track[1:, 2])])
    e = np.stack((np.sin(c), np.cos(c)), axis=-1)
    pos = np.asarray(x)[None, None, :] - (speed * (t - times))[None, :, None] * e[:, None, :]
    g = sampled_approach(track, pos, times) - h

    def exact(u):
        return closest_approach(track, straight_path(x, speed, t, u)) - h

    # the sampled ranges overestimate (by up to a few metres here), so a sign change of the
    # exact margin may sit a scan step or two from the sampled one: the exact margin on the
    # scan's courses about each sampled change, then brentq across its own changes
    near = set()
    for i in np.flatnonzero(np.sign(g[:-1]) != np.sign(g[1:])):
        near.update(range(max(i - 3, 0), min(i + 5, n_scan + 1)))
    near = sorted(near)
    values = {i: exact(c[i]) for i in near}
    out = []
    for i in near:
        if i + 1 in values and np.sign(values[i]) != np.sign(values[i + 1]):
            out.append(optimize.brentq(exact, c[i], c[i + 1], xtol=1e-14, rtol=1e-15))
    return out
