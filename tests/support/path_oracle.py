"""Sample paths of the motion models, written here from the models' generative stories (not
the package's position code): positions of each path at several times, shape (n, len(times), 2).

* CAT (Gade et al.; eq. (1) of the polar-banana paper): from the origin, heading north at v0,
  constant acceleration a ~ N(0, sigma_a) and turn rate omega ~ N(0, sigma_omega); heading at s
  is omega s (clockwise from north), speed v0 + a s, so the position at t is
  int_0^t (v0 + a s) (sin(omega s), cos(omega s)) ds, here by 24-point Gauss-Legendre (the
  integrand is a polynomial times sin / cos of degree omega t <= a few radians: the rule's error
  is below 1e-15 of v0 t there). A heading error theta_0 ~ N(0, sigma_heading) turns the
  whole path clockwise about the origin. Default pose only (origin 0, heading north).
* Butterly (3.1), (2.5): start ~ N(mean, cov), speed V from the discrete law, course c uniform
  (von Mises with course_kappa > 0); the position at s is start + V s (sin c, cos c).
"""

from __future__ import annotations

import numpy as np

_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)


def cat_paths(n, times, rng, *, v0, sigma_a, sigma_omega, sigma_heading=0.0):
    a = rng.normal(0.0, sigma_a, n)
    omega = rng.normal(0.0, sigma_omega, n)
    theta0 = rng.normal(0.0, sigma_heading, n) if sigma_heading > 0 else np.zeros(n)
    out = np.empty((n, len(times), 2))
    for k, t in enumerate(times):
        s = 0.5 * t * (_GL_X + 1.0)  # nodes on [0, t]
        w = 0.5 * t * _GL_W
        speed = v0 + a[:, None] * s[None, :]
        heading = omega[:, None] * s[None, :] + theta0[:, None]
        out[:, k, 0] = np.sum(w * speed * np.sin(heading), axis=1)
        out[:, k, 1] = np.sum(w * speed * np.cos(heading), axis=1)
    return out


def butterly_paths(n, times, rng, *, mean, cov, speeds, weights, course_kappa=0.0, course_mean=0.0):
    start = rng.multivariate_normal(mean, cov, size=n)
    v = np.asarray(speeds, dtype=float)[rng.choice(len(speeds), size=n, p=weights)]
    if course_kappa > 0:
        c = rng.vonmises(course_mean, course_kappa, n)
    else:
        c = rng.uniform(0.0, 2.0 * np.pi, n)
    e = np.column_stack((np.sin(c), np.cos(c)))
    return start[:, None, :] + v[:, None, None] * np.asarray(times, dtype=float)[None, :, None] * e[:, None, :]


def detection_probability(paths, grid, pods):
    """Each path's probability of being detected by some period: 1 - prod_k (1 - POD_k at the
    path's cell at t_k), POD 0 off the grid (cells found here by their edges, not the package's
    lookup)."""
    x_edges = grid.origin[0] + grid.dx * np.arange(grid.nx + 1)
    y_edges = grid.origin[1] + grid.dy * np.arange(grid.ny + 1)
    escape = np.ones(paths.shape[0])
    for k, pod in enumerate(pods):
        j = np.searchsorted(x_edges, paths[:, k, 0], side="right") - 1
        i = np.searchsorted(y_edges, paths[:, k, 1], side="right") - 1
        on = (j >= 0) & (j < grid.nx) & (i >= 0) & (i < grid.ny)
        escape[on] *= 1.0 - np.asarray(pod)[i[on], j[on]]
    return 1.0 - escape
