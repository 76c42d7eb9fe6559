"""Vectorised NumPy float64 versions of the kernels' algorithms: the baseline of ``bananagrid bench``.

They compute the same densities as the Warp kernels (same root-finding scheme for CAT), so the
benchmark's ratio measures the kernels, not a change of algorithm. The tests do not use these:
they check the kernels against independent oracles of their own.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import integrate, special, stats

from ..models.butterly import CELL_FLOOR, KERNEL_TOL, SPEED_FLOOR
from ..models.cat import cat_position
from ..protocol import DensityModel

__all__ = [
    "cat_density", "polar_density", "bearing_density", "butterly_density", "presence_plane_cells",
    "presence_grid_cells", "presence_frustum_cells", "cat_cells", "density_cells",
]

_INV_SQRT_2PI = 0.3989422804014327


def _normal_pdf(x, mu, sigma):
    z = (x - mu) / sigma
    return _INV_SQRT_2PI / sigma * np.exp(-0.5 * z * z)


def _sinc(x):
    return np.sinc(x / np.pi)  # numpy's sinc is the normalised one


def _basis(u):
    """(A, B, C, D, C', D') of ``kernels.common.cat_basis``; 6-term series below |u| = 0.1."""
    u = np.asarray(u, dtype=float)
    small = np.abs(u) < 0.1
    us = np.where(small, 1.0, u)
    s, c = np.sin(us), np.cos(us)
    z = u * u
    a_fn = np.sin(0.5 * u) * _sinc(0.5 * u)
    b_fn = _sinc(u)
    c_fn = np.where(small, u * (1 / 3 - z / 30 + z**2 / 840 - z**3 / 45360 + z**4 / 3991680), (s - us * c) / us**2)
    d_fn = np.where(small, 0.5 - z / 8 + z**2 / 144 - z**3 / 5760 + z**4 / 403200, (c + us * s - 1) / us**2)
    dc_fn = np.where(small, 1 / 3 - z / 10 + z**2 / 168 - z**3 / 6480 + z**4 / 443520, (us**2 * s - 2 * s + 2 * us * c) / us**3)
    dd_fn = np.where(small, u * (-1 / 4 + z / 36 - z**2 / 960 + z**3 / 50400), (us**2 * c - 2 * c - 2 * us * s + 2) / us**3)
    return a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn


def _coefficients(omega, v0, t):
    a_fn, b_fn, c_fn, d_fn, dc_fn, dd_fn = _basis(omega * t)
    hx, hy = t * t * c_fn, t * t * d_fn
    dhx, dhy = t**3 * dc_fn, t**3 * dd_fn
    fx, fy = t * a_fn, t * b_fn
    h2 = hx * hx + hy * hy
    return dict(
        hx=hx, hy=hy, c=v0 * (hx * fy - hy * fx), dhx=dhx, dhy=dhy,
        dc=v0 * (dhx * fy - dhy * fx - h2), ax=hx / h2, ay=hy / h2, a0=v0 * (hx * fx + hy * fy) / h2,
    )


def _residual(x, y, omega, v0, t):
    k = _coefficients(omega, v0, t)
    f = k["hx"] * y - k["hy"] * x - k["c"]
    df = k["dhx"] * y - k["dhy"] * x - k["dc"]
    return f, df, k["ax"] * x + k["ay"] * y - k["a0"]


def _root_density(x, y, lo, hi, f_lo, v0, t, sigma_a, sigma_omega, iterations=60):
    """Vectorised bracketed Newton (bisection fallback) from the regula-falsi point."""
    a, b, fa = lo.copy(), hi.copy(), f_lo.copy()
    w = 0.5 * (a + b)
    for _ in range(iterations):
        f, df, acc = _residual(x, y, w, v0, t)
        same = (f > 0) == (fa > 0)
        a = np.where(same, w, a)
        fa = np.where(same, f, fa)
        b = np.where(same, b, w)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = w - f / df
        ok = (newton > a) & (newton < b)
        w_new = np.where(ok, newton, 0.5 * (a + b))
        done = np.abs(w_new - w) <= 1e-15 * (np.abs(w) + sigma_omega)
        w = w_new
        if done.all():
            break
    f, df, acc = _residual(x, y, w, v0, t)
    return _normal_pdf(acc, 0.0, sigma_a) * _normal_pdf(w, 0.0, sigma_omega) / np.abs(df)


def cat_density(x, y, v0, t, sigma_a, sigma_omega, omegas, *, prune_sigmas=38.0, chunk=200_000):
    """Exact CAT density at local points (x, y) by the kernels' scan-and-refine scheme in NumPy."""
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    table = _coefficients(np.asarray(omegas, dtype=float), v0, t)
    out = np.zeros(x.size)
    a_cut = prune_sigmas * sigma_a
    for start in range(0, x.size, chunk):
        xs, ys = x[start : start + chunk, None], y[start : start + chunk, None]
        f = table["hx"] * ys - table["hy"] * xs - table["c"]
        g = table["dhx"] * ys - table["dhy"] * xs - table["dc"]
        acc = table["ax"] * xs + table["ay"] * ys - table["a0"]
        negligible = ((acc[:, :-1] > a_cut) & (acc[:, 1:] > a_cut)) | ((acc[:, :-1] < -a_cut) & (acc[:, 1:] < -a_cut))
        crossing = ((f[:, 1:] >= 0) != (f[:, :-1] >= 0)) & ~negligible
        cell, k = np.nonzero(crossing)
        dens = _root_density(
            xs[cell, 0], ys[cell, 0], omegas[k], omegas[k + 1], f[cell, k], v0, t, sigma_a, sigma_omega
        )
        block = np.zeros(xs.shape[0])
        np.add.at(block, cell, dens)
        # intervals where |F| has an interior minimum: bisection on F' for it, then two roots
        fold = (f[:, :-1] * g[:, :-1] < 0) & (f[:, 1:] * g[:, 1:] > 0) & ~negligible
        cell, k = np.nonzero(fold)
        if cell.size:
            xf, yf = xs[cell, 0], ys[cell, 0]
            lo, hi, g_lo = omegas[k].copy(), omegas[k + 1].copy(), g[cell, k]
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                _, g_mid, _ = _residual(xf, yf, mid, v0, t)
                same = (g_mid > 0) == (g_lo > 0)
                lo, g_lo, hi = np.where(same, mid, lo), np.where(same, g_mid, g_lo), np.where(same, hi, mid)
            mid = 0.5 * (lo + hi)
            f_mid, _, _ = _residual(xf, yf, mid, v0, t)
            dips = (f_mid >= 0) != (f[cell, k + 1] >= 0)
            for left, right, f_left in ((omegas[k], mid, f[cell, k]), (mid, omegas[k + 1], f_mid)):
                d = _root_density(xf[dips], yf[dips], left[dips], right[dips], f_left[dips], v0, t, sigma_a, sigma_omega)
                np.add.at(block, cell[dips], d)
        out[start : start + chunk] = block
    return out


def polar_density(x, y, v0, t, sigma_a, sigma_omega, variant="improved", xp=np):
    """Polar-banana density at local points: g(phi) g(r; mean, sd) / r, eqs. (8), (11).

    ``xp`` is the array library: NumPy (the baseline) or ``jax.numpy`` (the JAX peer of
    :mod:`bananagrid.bench.peers`, traced under ``jax.jit``); the formula is written once for both.
    """
    r = xp.hypot(x, y)
    phi = xp.arctan2(x, y)
    sinc = xp.sinc(phi / np.pi)  # the library's sinc is the normalised one
    sigma_phi = 0.5 * sigma_omega * t
    if variant == "rough":
        mean = v0 * t * sinc
        sd = xp.full_like(r, 0.5 * sigma_a * t * t)
    else:
        scc = (4 * sinc - xp.cos(phi)) / 3
        ratio = phi / sigma_phi
        mean = v0 * t * sinc + sigma_a**2 * t**3 / (12 * v0) * (ratio**2 - 1) * scc
        sd = 0.5 * sigma_a * t * t * (1 + sigma_a**2 / (6 * v0**2) * (t**2 / 12 - phi**2 / sigma_omega**2)) * scc
    z_phi, z_r = phi / sigma_phi, (r - mean) / sd
    with np.errstate(divide="ignore", invalid="ignore"):
        dens = _INV_SQRT_2PI**2 / (sigma_phi * sd * r) * xp.exp(-0.5 * (z_phi * z_phi + z_r * z_r))
    return xp.where((r > 0) & (sd > 0), dens, 0.0)


def bearing_density(x, y, fix) -> np.ndarray:
    """Exact bearing-fix presence density (``kernels/bearing.py``) of a BearingFix in NumPy."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    params = fix.kernel_parameters()
    log_p = np.full(np.broadcast(x, y).shape, params["log_norm"])
    for sx, sy, b, inv_sigma in params["sensors"]:
        resid = np.arctan2(x - sx, y - sy) - b
        resid -= 2 * np.pi * np.floor((resid + np.pi) / (2 * np.pi))
        log_p -= 0.5 * (resid * inv_sigma) ** 2
    return np.exp(log_p)


def presence_plane_cells(mixture, lattice, cells) -> np.ndarray:
    """SciPy baseline of the plane cell probabilities (no region): for each (azimuth, elevation)
    index in ``cells``, ``scipy.integrate.dblquad`` of rho f(rho cos phi, rho sin phi) over the
    cell's sector (rho to infinity at the horizon), f the mixture's density written in NumPy
    per point, relative tolerance 1e-7 (the kernel's is 1e-7 of each component's integral)."""

    weights = np.asarray(mixture.weights, dtype=float)
    means = np.asarray(mixture.means, dtype=float)
    inverses = np.array([np.linalg.inv(c) for c in mixture.covs])
    norms = weights / (2.0 * math.pi * np.sqrt([np.linalg.det(c) for c in mixture.covs]))

    def density(x, y):
        d = np.array([x, y]) - means
        q = np.einsum("ki,kij,kj->k", d, inverses, d)
        return float(np.sum(norms * np.exp(-0.5 * q)))

    az = lattice.azimuth_edges
    inner, outer = lattice.radii()
    out = np.empty(len(cells))
    for k, (a, e) in enumerate(cells):
        r0, r1 = float(inner[e]), float(outer[e])
        if math.isinf(r1):
            value = integrate.quad(
                lambda p: integrate.quad(lambda r: r * density(r * math.cos(p), r * math.sin(p)), r0, np.inf,
                                         epsrel=1e-7, epsabs=0.0)[0],
                az[a], az[a + 1], epsrel=1e-7, epsabs=0.0,
            )[0]
        else:
            value = integrate.dblquad(
                lambda r, p: r * density(r * math.cos(p), r * math.sin(p)), az[a], az[a + 1], r0, r1,
                epsrel=1e-7, epsabs=0.0,
            )[0]
        out[k] = value
    return out


def presence_grid_cells(mixture, grid, cells) -> np.ndarray:
    """SciPy baseline of rectangle probabilities: for each (row, column) in ``cells``,
    ``scipy.stats.multivariate_normal.cdf`` at the four corners per component (inclusion and
    exclusion), summed over the mixture."""
    out = np.zeros(len(cells))
    laws = [stats.multivariate_normal(mean=m[:2], cov=np.asarray(c)[:2, :2]) for m, c in zip(mixture.means, mixture.covs)]
    x0, y0 = grid.origin
    for k, (i, j) in enumerate(cells):
        xa, xb = x0 + j * grid.dx, x0 + (j + 1) * grid.dx
        ya, yb = y0 + i * grid.dy, y0 + (i + 1) * grid.dy
        corners = np.array([[xb, yb], [xa, yb], [xb, ya], [xa, ya]])
        for w, law in zip(mixture.weights, laws):
            c = law.cdf(corners)
            out[k] += w * (c[0] - c[1] - c[2] + c[3])
    return out


def presence_frustum_cells(mixture, lattice, cells) -> np.ndarray:
    """SciPy baseline of frustum cells (no region): ``scipy.integrate.tplquad`` of the mixture's
    3-D density over depth, azimuth and radius (the cell's slab of sectors), relative tolerance
    1e-7; the horizon's unbounded cells are integrated to 50 m (beyond it the density of a
    room-scale mixture underflows)."""

    weights = np.asarray(mixture.weights, dtype=float)
    means = np.asarray(mixture.means, dtype=float)
    inverses = np.array([np.linalg.inv(c) for c in mixture.covs])
    norms = weights / np.sqrt((2.0 * math.pi) ** 3 * np.array([np.linalg.det(c) for c in mixture.covs]))

    def density(x, y, z):
        d = np.array([x, y, z]) - means
        q = np.einsum("ki,kij,kj->k", d, inverses, d)
        return float(np.sum(norms * np.exp(-0.5 * q)))

    az = lattice.azimuth_edges
    tau = np.minimum(lattice.tau_edges, 50.0 / (lattice.h - lattice.dh))
    depths = (lattice.h - lattice.dh, lattice.h + lattice.dh)
    out = np.empty(len(cells))
    for k, (a, e) in enumerate(cells):
        t0, t1 = float(tau[e + 1]), float(tau[e])
        out[k] = integrate.tplquad(
            lambda r, p, d: r * density(r * math.cos(p), r * math.sin(p), -d),
            depths[0], depths[1], az[a], az[a + 1], lambda d, p: d * t0, lambda d, p: d * t1, epsrel=1e-7,
        )[0]
    return out


def butterly_density(model: DensityModel, x, y, *, floors: bool = False, chunk: int = 4096) -> np.ndarray:
    """The density of a ``"butterly"`` model in vectorised NumPy float64.

    For every speed, the periodic trapezoid rule on the full circle with the kernel's node
    count N (:func:`bananagrid.kernels.butterly.node_count`, per point), in log space (each
    point's largest term subtracted before exp); with ``floors`` the same cells and speeds are
    skipped as by the grid kernel (``kernel_parameters`` of the model), with the same bounds.
    Points are grouped by N (rounded up to a multiple of 8) and done ``chunk`` at a time, so
    the (points x nodes) work arrays stay in cache. It lacks the kernel's per-point walk from
    the peak (which stops where the terms fall below 1e-15 of it): an early exit per point
    does not vectorise, so NumPy pays N nodes per point and speed where the kernel pays the
    peak's width (about 20-45 nodes).
    """
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    shape = x.shape
    x, y = x.ravel(), y.ravel()
    s1, s2, beta = model.axes
    q1x, q1y = math.cos(beta), math.sin(beta)
    kappa = model.course_kappa
    theta0 = 0.5 * math.pi - beta - model.course_mean
    tol = KERNEL_TOL[np.dtype(np.float64)][0]
    log_tol = math.log(1.0 / tol) + math.log(4.0 * math.pi)
    log_norm = -math.log(4.0 * math.pi**2 * (math.sqrt(s1) * math.sqrt(s2))) - math.log(special.ive(0, kappa))
    log_peak_coef = -math.log(2.0 * math.pi * (math.sqrt(s1) * math.sqrt(s2)))
    tiny = np.finfo(float).smallest_subnormal
    speed_floor, cell_floor = math.log(tiny) - 1.0, -math.inf
    ranges, weights = model.ranges, model.speed_nodes[1]
    if floors:
        log_peak = math.log(model.peak_lower_bound())
        cell_floor = math.log(CELL_FLOOR) + log_peak
        speed_floor = max(speed_floor, math.log(SPEED_FLOOR / ranges.size) + log_peak)
    dx, dy = x - model.mean[0], y - model.mean[1]
    z1 = (dx * q1x + dy * q1y) / math.sqrt(s1)
    z2 = (dy * q1x - dx * q1y) / math.sqrt(s2)
    z_norm = np.hypot(z1, z2)

    def log_bound(rho1, rho2, w):  # kernels/butterly.py log_bound
        d = np.maximum(0.0, np.maximum(z_norm - rho1, rho2 - z_norm))
        if rho2 > 0.0:
            d = np.maximum(d, rho2 * np.abs(np.hypot(z1 / rho1, z2 / rho2) - 1.0))
        return math.log(w) + log_peak_coef - 0.5 * d * d if w > 0 else np.full(d.shape, -np.inf)

    out = np.zeros(x.size)
    rhos = [(r / math.sqrt(s1), r / math.sqrt(s2)) for r in ranges]
    if floors:
        top = np.full(x.size, -np.inf)
        for (rho1, rho2), w in zip(rhos, weights):
            np.maximum(top, log_bound(rho1, rho2, w), out=top)
        live = top >= cell_floor - math.log(ranges.size)
    else:
        live = np.ones(x.size, dtype=bool)
    for (rho1, rho2), w in zip(rhos, weights):
        keep = np.flatnonzero(live & (log_bound(rho1, rho2, w) >= speed_floor))
        if keep.size == 0:
            continue
        a = rho1 * z1[keep] + kappa * math.cos(theta0)
        b = rho2 * z2[keep] + kappa * math.sin(theta0)
        amp = np.hypot(a, b) + (rho1 - rho2) * (rho1 + rho2)
        n = np.ceil(np.sqrt(2.0 * amp * (log_tol + 0.5 * np.log1p(amp))) + 12.0).astype(np.int64)
        n = (n + 7) // 8 * 8
        order = np.argsort(n, kind="stable")
        keep, n = keep[order], n[order]
        bounds = np.flatnonzero(np.diff(n)) + 1
        for lo, hi in zip(np.concatenate(([0], bounds)), np.concatenate((bounds, [n.size]))):
            nodes = int(n[lo])
            theta = 2.0 * math.pi * np.arange(nodes) / nodes
            ct, st = rho1 * np.cos(theta), rho2 * np.sin(theta)
            course = kappa * (np.cos(theta - theta0) - 1.0) if kappa > 0 else None
            for c0 in range(lo, hi, chunk):
                idx = keep[c0:min(hi, c0 + chunk)]
                e = z1[idx, None] - ct
                e *= e
                t2 = z2[idx, None] - st
                t2 *= t2
                e += t2
                e *= -0.5
                if course is not None:
                    e += course
                peak = e.max(axis=1)
                e -= peak[:, None]
                np.exp(e, out=e)
                out[idx] += w * np.exp(log_norm + peak) * e.sum(axis=1) * (2.0 * math.pi / nodes)
    return out.reshape(shape)


def cat_cells(model: DensityModel, cells, edges: np.ndarray) -> np.ndarray:
    """CAT cell probabilities exact in the acceleration, by the midpoint rule over the turn-rate
    intervals ``edges`` (``CAT.cell_plan`` integrates each interval between corner passes),
    vectorised over the lines per cell: each line's clip to the cell (two slabs) and its normal
    mass Phi(z_out) - Phi(z_in), weighted by its interval's normal mass. ``cells`` are world
    boxes ``(x0, x1, y0, y1)``. NumPy clips every line against every cell; the kernel walks
    each line only through the cells it crosses."""
    omegas = 0.5 * (edges[:-1] + edges[1:])
    weights = np.diff(special.ndtr(edges / model.sigma_omega))
    base = model.pose.to_world(cat_position(model.v0, model.t, np.zeros_like(omegas), omegas))
    step = model.pose.to_world(cat_position(model.v0, model.t, np.full_like(omegas, model.sigma_a), omegas)) - base
    out = np.empty(len(cells))
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, (x0, x1, y0, y1) in enumerate(cells):
            lo, hi = np.full(len(omegas), -9.0), np.full(len(omegas), 9.0)
            for axis, a, b in ((0, x0, x1), (1, y0, y1)):
                za, zb = (a - base[:, axis]) / step[:, axis], (b - base[:, axis]) / step[:, axis]
                inside = (a <= base[:, axis]) & (base[:, axis] <= b)
                flat = step[:, axis] == 0.0
                lo = np.where(flat, np.where(inside, lo, 9.0), np.maximum(lo, np.minimum(za, zb)))
                hi = np.where(flat, np.where(inside, hi, -9.0), np.minimum(hi, np.maximum(za, zb)))
            share = np.where(lo >= 0.0, special.ndtr(-lo) - special.ndtr(-hi), special.ndtr(hi) - special.ndtr(lo))
            out[k] = float(np.sum(weights * np.where(lo < hi, share, 0.0)))
    return out


def density_cells(density, cells, epsrel: float = 1e-9) -> np.ndarray:
    """Cell probabilities by SciPy's ``dblquad`` of a vectorised density (one point per call):
    what a user without cell probabilities would write. ``cells`` are ``(x0, x1, y0, y1)``."""
    return np.array([
        integrate.dblquad(lambda y, x: float(density(np.array([x]), np.array([y]))[0]), x0, x1, y0, y1,
                          epsabs=0.0, epsrel=epsrel)[0]
        for x0, x1, y0, y1 in cells
    ])
