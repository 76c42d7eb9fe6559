"""Independent float64 oracles for the CAT ("constant acceleration and turn rate") banana
distribution of Langholm & Totland and for its two polar approximations.

Nothing here imports or mirrors the project's implementation (``bananagrid`` / ``kernels``);
it is built from the paper's equation (1), eqs. (8), (11) and the ERRATA only.

Exact CAT density -- method
---------------------------
Write s = omega*t (turn angle, s ~ N(0, sigma_w t)) and alpha = a t / v0
(alpha ~ N(0, sigma_a t / v0)).  Equation (1) becomes, in units of v0*t,

    xi = (x, y) / (v0 t) = A(s) + alpha * B(s),
    A(s) = int_0^1 (sin su, cos su) du = (I0s, I0c),
    B(s) = int_0^1 u (sin su, cos su) du = (I1s, I1c),

with the moment integrals  Imc(s) = int_0^1 u^m cos(su) du,  Ims(s) = int_0^1 u^m sin(su) du
(this is eq. (1) integrated along the path: heading s*u, speed v0 + a t u).  They are entire
functions of s; for |s| <= 1 they are evaluated from their Taylor series (no 0/0 at omega = 0),
for |s| > 1 from closed forms.  Their derivatives are again moments:
A'(s) = (I1c, -I1s), B'(s) = (I2c, -I2s).

For fixed s the reachable points form a line in alpha, so (x, y) is reached at turn s iff the
cross product
    f(s) = (xi - A(s)) x B(s) = xi_x I1c - xi_y I1s - (I0s I1c - I0c I1s)
vanishes; then alpha = (xi - A).B / |B|^2  (|B(s)| > 0 for all real s).  The roots of f in
|s| <= K sigma_w t are bracketed by a dense scan (step <= 0.01 rad) that also detects pairs of
roots hidden inside one scan step (|f| has an interior minimum whose sign differs: the fold
caustic), then refined by a bracket-safeguarded Newton iteration to |ds| <= 1e-13 (1+|s|).

The density is  sum_roots g(alpha; sigma_a t/v0) g(s; sigma_w t) / |det d xi / d(alpha, s)| / (v0 t)^2
with det = B x (A' + alpha B') = -|B|^2 - alpha (I1s I2s + I1c I2c).  The series, closed forms,
derivatives and Jacobian are checked against Gauss-Legendre quadrature, complex-step and
central finite differences of the *literal* eq. (1) in ``self_check()``; the vectorised density
is checked against a slow per-point scipy.brentq reference built on literal eq. (1) in (a, w).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import norm

__all__ = [
    "cat_density",
    "cat_density_slow",
    "cat_position",
    "polar_density",
    "table_stats",
    "goodness",
    "self_check",
]

# ----------------------------------------------------------------------------------------
# moment integrals I_m^c(s) = int_0^1 u^m cos(su) du,  I_m^s(s) = int_0^1 u^m sin(su) du
# ----------------------------------------------------------------------------------------
_SERIES_CUT = 1.0
_NTERMS = 16  # |s| <= 1: last term ~ 1/(32)! -- far below eps


def _series_coeffs(m: int, kind: str) -> np.ndarray:
    """Coefficients c_k of sum_k c_k (s^2)^k (times s for 'sin')."""
    c = []
    for k in range(_NTERMS):
        if kind == "c":
            c.append((-1) ** k / (math.factorial(2 * k) * (2 * k + m + 1)))
        else:
            c.append((-1) ** k / (math.factorial(2 * k + 1) * (2 * k + m + 2)))
    return np.array(c)


_COEF = {(m, kd): _series_coeffs(m, kd) for m in (0, 1, 2) for kd in ("c", "s")}


def _horner(coef, z):
    acc = np.zeros_like(z) + coef[-1]
    for c in coef[-2::-1]:
        acc = acc * z + c
    return acc


def _moments_series(s):
    z = s * s
    return {
        (m, kd): (_horner(_COEF[(m, kd)], z) * (s if kd == "s" else 1.0))
        for m in (0, 1, 2)
        for kd in ("c", "s")
    }


def _moments_closed(s):
    sn, cs = np.sin(s), np.cos(s)
    s2, s3 = s * s, s * s * s
    sh = np.sin(0.5 * s)
    return {
        (0, "s"): 2.0 * sh * sh / s,                       # (1 - cos s)/s
        (0, "c"): sn / s,
        (1, "s"): (sn - s * cs) / s2,
        (1, "c"): (cs + s * sn - 1.0) / s2,
        (2, "c"): (s2 * sn + 2.0 * s * cs - 2.0 * sn) / s3,
        (2, "s"): (-s2 * cs + 2.0 * s * sn + 2.0 * cs - 2.0) / s3,
    }


def _moments(s):
    """All six moments, float64 or complex (complex used only for complex-step checks)."""
    s = np.asarray(s)
    small = np.abs(s) <= _SERIES_CUT
    if np.all(small):
        return _moments_series(s)
    if not np.any(small):
        return _moments_closed(s)
    out = {}
    ser = _moments_series(s[small])
    clo = _moments_closed(s[~small])
    for key in ser:
        arr = np.empty(s.shape, dtype=np.result_type(s, float))
        arr[small] = ser[key]
        arr[~small] = clo[key]
        out[key] = arr
    return out


def _moments_gl(s, n=64):
    """Gauss-Legendre reference for the moments (self-check only)."""
    u, wq = np.polynomial.legendre.leggauss(n)
    u = 0.5 * (u + 1.0)
    wq = 0.5 * wq
    s = np.asarray(s, dtype=float)[..., None]
    out = {}
    for m in (0, 1, 2):
        out[(m, "c")] = np.sum(wq * u**m * np.cos(s * u), axis=-1)
        out[(m, "s")] = np.sum(wq * u**m * np.sin(s * u), axis=-1)
    return out


def _f_fp(xi_x, xi_y, s):
    """Cross product f(s) = (xi - A) x B and its derivative d f / d s."""
    M = _moments(s)
    i0s, i0c, i1s, i1c, i2s, i2c = (M[(0, "s")], M[(0, "c")], M[(1, "s")], M[(1, "c")],
                                    M[(2, "s")], M[(2, "c")])
    f = xi_x * i1c - xi_y * i1s - (i0s * i1c - i0c * i1s)
    fp = -(i1s * i1s + i1c * i1c) - xi_x * i2s - xi_y * i2c + (i0s * i2s + i0c * i2c)
    return f, fp


def _alpha_det(xi_x, xi_y, s):
    M = _moments(s)
    i0s, i0c, i1s, i1c, i2s, i2c = (M[(0, "s")], M[(0, "c")], M[(1, "s")], M[(1, "c")],
                                    M[(2, "s")], M[(2, "c")])
    b2 = i1s * i1s + i1c * i1c
    alpha = ((xi_x - i0s) * i1s + (xi_y - i0c) * i1c) / b2
    det = -b2 - alpha * (i1s * i2s + i1c * i2c)
    return alpha, det


def cat_position(a, w, v0, t):
    """Literal eq. (1) (used for Monte Carlo and the slow reference; w must be nonzero)."""
    a = np.asarray(a, dtype=float)
    w = np.asarray(w, dtype=float)
    wt = w * t
    c, sn = np.cos(wt), np.sin(wt)
    x = v0 / w * (1.0 - c) + a / w**2 * (sn - wt * c)
    y = v0 / w * sn + a / w**2 * (c + wt * sn - 1.0)
    return x, y


# ----------------------------------------------------------------------------------------
# vectorised exact CAT density
# ----------------------------------------------------------------------------------------
def _refine(xi_x, xi_y, lo, hi, flo, fhi, max_iter=200):
    """Bracket-safeguarded Newton on f; brackets [lo, hi] with sign(flo) != sign(fhi)."""
    lo = lo.copy(); hi = hi.copy(); flo = flo.copy()
    # start from the secant (regula falsi) point
    s = lo - flo * (hi - lo) / (fhi - flo)
    bad = ~np.isfinite(s) | (s <= lo) | (s >= hi)
    s[bad] = 0.5 * (lo[bad] + hi[bad])
    active = np.arange(lo.size)
    for _ in range(max_iter):
        if active.size == 0:
            break
        sa = s[active]
        f, fp = _f_fp(xi_x[active], xi_y[active], sa)
        same = np.signbit(f) == np.signbit(flo[active])
        l = np.where(same, sa, lo[active])
        h = np.where(same, hi[active], sa)
        fl = np.where(same, f, flo[active])
        lo[active], hi[active], flo[active] = l, h, fl
        with np.errstate(divide="ignore", invalid="ignore"):
            snew = sa - f / fp
        ok = np.isfinite(snew) & (snew > l) & (snew < h)
        snew = np.where(ok, snew, 0.5 * (l + h))
        step = np.abs(snew - sa)
        s[active] = snew
        tol = 1e-13 * (1.0 + np.abs(snew))
        done = (step <= tol) | (f == 0.0) | ((h - l) <= tol)
        s[active[f == 0.0]] = sa[f == 0.0]
        active = active[~done]
    return s


def _scan_grid(k, sig_s, step):
    smax = k * sig_s
    n = max(401, int(math.ceil(2.0 * smax / step)) + 1)
    # shift by an irrational fraction of a step so that s = 0 is not a scan node
    h = 2.0 * smax / (n - 1)
    grid = -smax + h * np.arange(n)
    grid[1:-1] += h * (math.sqrt(2.0) - 1.0) * 0.1
    return grid


def cat_density(x, y, v0, t, sigma_a, sigma_w, k=8.0, *, scan_step=0.01, chunk=6000,
                return_nroots=False, weight=None):
    """Exact CAT density p(x, y) [m^-2] (float64), summing over all roots with |w| <= k sigma_w.

    x, y broadcast together; any shape.  Correct across folds (several roots) and at w = 0.
    ``weight(index, a, w)``, if given, multiplies each root's term: the flat indices of the
    points, and each root's acceleration and turn rate (arrays): a weight on the path.
    """
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    shape = x.shape
    X = x.ravel() / (v0 * t)
    Y = y.ravel() / (v0 * t)
    sig_s = sigma_w * t
    sig_al = sigma_a * t / v0
    grid = _scan_grid(k, sig_s, scan_step)
    M = _moments(grid)
    g1c, g1s = M[(1, "c")], M[(1, "s")]
    g0 = M[(0, "s")] * g1c - M[(0, "c")] * g1s
    gp0 = -(g1s * g1s + g1c * g1c) + (M[(0, "s")] * M[(2, "s")] + M[(0, "c")] * M[(2, "c")])
    g2s, g2c = M[(2, "s")], M[(2, "c")]

    out = np.zeros(X.size)
    nroots = np.zeros(X.size, dtype=np.int32)
    norm_const = 1.0 / (2.0 * math.pi * sig_s * sig_al * (v0 * t) ** 2)
    for i0 in range(0, X.size, chunk):
        xs = X[i0:i0 + chunk]
        ys = Y[i0:i0 + chunk]
        F = xs[:, None] * g1c
        F -= ys[:, None] * g1s
        F -= g0
        pos = F > 0.0
        chg = pos[:, 1:] != pos[:, :-1]
        pi_, ji = np.nonzero(chg)
        lo = grid[ji]; hi = grid[ji + 1]
        flo = F[pi_, ji]; fhi = F[pi_, ji + 1]
        # hidden root pairs: |f| decreasing at left node, increasing at right node, no sign change
        FP = -(xs[:, None] * g2s)
        FP -= ys[:, None] * g2c
        FP += gp0
        toward = (F * FP)
        cand = (~chg) & (toward[:, :-1] < 0.0) & (toward[:, 1:] > 0.0)
        del FP, toward
        ci, cj = np.nonzero(cand)
        if ci.size:
            a_ = grid[cj].copy(); b_ = grid[cj + 1].copy()
            xa, ya = xs[ci], ys[ci]
            _, fpa = _f_fp(xa, ya, a_)
            for _ in range(60):  # bisection on f' for the extremum
                m_ = 0.5 * (a_ + b_)
                _, fpm = _f_fp(xa, ya, m_)
                same = np.signbit(fpm) == np.signbit(fpa)
                a_ = np.where(same, m_, a_)
                fpa = np.where(same, fpm, fpa)
                b_ = np.where(same, b_, m_)
            sm = 0.5 * (a_ + b_)
            fm, _ = _f_fp(xa, ya, sm)
            fl = F[ci, cj]
            split = (np.signbit(fm) != np.signbit(fl)) & (fm != 0.0)
            ci, cj, sm, fm = ci[split], cj[split], sm[split], fm[split]
            if ci.size:
                pi_ = np.concatenate([pi_, ci, ci])
                lo = np.concatenate([lo, grid[cj], sm])
                hi = np.concatenate([hi, sm, grid[cj + 1]])
                flo = np.concatenate([flo, F[ci, cj], fm])
                fhi = np.concatenate([fhi, fm, F[ci, cj + 1]])
        del F, pos, chg, cand
        if pi_.size == 0:
            continue
        xr, yr = xs[pi_], ys[pi_]
        s = _refine(xr, yr, lo, hi, flo, fhi)
        alpha, det = _alpha_det(xr, yr, s)
        dens = norm_const * np.exp(-0.5 * ((s / sig_s) ** 2 + (alpha / sig_al) ** 2)) / np.abs(det)
        if weight is not None:
            dens = dens * weight(i0 + pi_, alpha * v0 / t, s / t)
        out[i0:i0 + chunk] = np.bincount(pi_, weights=dens, minlength=xs.size)
        nroots[i0:i0 + chunk] = np.bincount(pi_, minlength=xs.size)
    if return_nroots:
        return out.reshape(shape), nroots.reshape(shape)
    return out.reshape(shape)


def cat_density_slow(x, y, v0, t, sigma_a, sigma_w, k=8.0, nscan=40001):
    """Slow scalar reference: literal eq. (1) in (a, w), scipy.optimize.brentq per root,
    Jacobian d(x, y)/d(a, w) by complex step.  For cross-checking only."""
    from scipy.optimize import brentq

    def UV(w):
        wt = w * t
        if abs(wt) < 0.05:  # Taylor series of eq. (1)'s bracketed terms (no 0/0)
            ks = range(1, 10)
            U = (v0 * t * sum((-1) ** (k + 1) * wt ** (2 * k - 1) / math.factorial(2 * k) for k in ks),
                 v0 * t * sum((-1) ** k * wt ** (2 * k) / math.factorial(2 * k + 1) for k in range(9)))
            V = (t * t * sum((-1) ** (k + 1) * 2 * k * wt ** (2 * k - 1) / math.factorial(2 * k + 1) for k in ks),
                 t * t * sum((-1) ** (k + 1) * (2 * k - 1) * wt ** (2 * k - 2) / math.factorial(2 * k) for k in ks))
            return U, V
        c, sn = np.cos(wt), np.sin(wt)
        U = (v0 / w * (1 - c), v0 / w * sn)
        V = ((sn - wt * c) / w**2, (c + wt * sn - 1) / w**2)
        return U, V

    def cross(w):
        U, V = UV(w)
        return (x - U[0]) * V[1] - (y - U[1]) * V[0]

    wmax = k * sigma_w
    ws = np.linspace(-wmax, wmax, nscan) + 1e-7 * wmax * math.pi  # avoid w = 0 exactly
    cr = np.array([cross(w) for w in ws])
    total = 0.0
    nroot = 0
    for j in np.nonzero(np.signbit(cr[1:]) != np.signbit(cr[:-1]))[0]:
        w = brentq(cross, ws[j], ws[j + 1], xtol=1e-15, rtol=4 * np.finfo(float).eps, maxiter=500)
        U, V = UV(w)
        a = ((x - U[0]) * V[0] + (y - U[1]) * V[1]) / (V[0] ** 2 + V[1] ** 2)
        if abs(w * t) > 1e-3:   # complex step on literal eq. (1)
            h = 1e-20 * abs(w)
            xc, yc = _pos_c(a, w + 1j * h, v0, t)
            dxdw, dydw = xc.imag / h, yc.imag / h
        else:                   # central differences of the series form (cancellation-free)
            h = 1e-6 / t
            Up, Vp = UV(w + h)
            Um, Vm = UV(w - h)
            dxdw = (Up[0] + a * Vp[0] - Um[0] - a * Vm[0]) / (2 * h)
            dydw = (Up[1] + a * Vp[1] - Um[1] - a * Vm[1]) / (2 * h)
        det = V[0] * dydw - V[1] * dxdw  # d(x,y)/da = V(w)
        total += norm.pdf(a, 0, sigma_a) * norm.pdf(w, 0, sigma_w) / abs(det)
        nroot += 1
    return total, nroot


def _pos_c(a, w, v0, t):
    wt = w * t
    c, sn = np.cos(wt), np.sin(wt)
    return (v0 / w * (1 - c) + a / w**2 * (sn - wt * c),
            v0 / w * sn + a / w**2 * (c + wt * sn - 1))


# ----------------------------------------------------------------------------------------
# polar approximations (Sections 2 and 5)
# ----------------------------------------------------------------------------------------
def _sinc(p):
    return np.sinc(p / np.pi)  # unnormalised sin(p)/p (np.sinc is normalised)


def polar_mu_sigma(phi, v0, t, sigma_a, sigma_w, variant):
    phi = np.asarray(phi, dtype=float)
    sc = _sinc(phi)
    if variant == "rough":
        return v0 * t * sc, np.full_like(phi, 0.5 * sigma_a * t * t)
    if variant == "improved":
        scc = (4.0 * sc - np.cos(phi)) / 3.0                                   # eq. (7)
        mu = v0 * t * sc + sigma_a**2 * t**3 / (12.0 * v0) * (
            phi**2 / (0.5 * sigma_w * t) ** 2 - 1.0) * scc                      # eq. (8)
        sd = 0.5 * sigma_a * t * t * (1.0 + sigma_a**2 / (6.0 * v0**2) * (
            t * t / 12.0 - phi**2 / sigma_w**2)) * scc                          # eq. (11)
        return mu, sd
    raise ValueError(f"unknown variant {variant!r}")


def polar_density(x, y, v0, t, sigma_a, sigma_w, variant):
    """p0 ('rough') or p1 ('improved') in Cartesian coordinates [m^-2]:
    g(phi; 0, sigma_w t / 2) g(r; mu(phi), sd(phi)) / r, phi = atan2(x, y) (from +y toward +x).
    Where eq. (11) gives sd <= 0 (far outside the paper's range) scipy returns nan."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    phi = np.arctan2(x, y)
    r = np.hypot(x, y)
    mu, sd = polar_mu_sigma(phi, v0, t, sigma_a, sigma_w, variant)
    return norm.pdf(phi, loc=0.0, scale=0.5 * sigma_w * t) * norm.pdf(r, loc=mu, scale=sd) / r


# ----------------------------------------------------------------------------------------
# table statistics and the Section 6.1 goodness measure
# ----------------------------------------------------------------------------------------
def table_stats(exact, approx, cell_area, levels, normalise=True):
    """For each level L: (mass inside {exact >= L}, max |approx/exact - 1| inside).

    normalise=True divides by the grid total sum(exact)*cell_area (the default: the
    paper's "proportion of the probability mass"; on the Figure 1 grid the grid total is
    1 - 3e-7, so both choices agree to the printed digits).  Returns a list of dicts.
    """
    exact = np.asarray(exact, dtype=float).ravel()
    approx = np.asarray(approx, dtype=float).ravel()
    total = exact.sum() * cell_area if normalise else 1.0
    rows = []
    for L in levels:
        m = exact >= L
        mass = exact[m].sum() * cell_area / total
        err = np.max(np.abs(approx[m] / exact[m] - 1.0)) if m.any() else np.nan
        rows.append({"level": L, "mass": mass, "max_rel_err": err, "ncells": int(m.sum())})
    return rows


def goodness(exact, approx, cell_area, threshold=0.05, normalise=True):
    """Mass inside the largest exact-density contour within which |approx/exact - 1| stays
    below ``threshold``: cells sorted by exact density (descending); the first cell whose
    relative error exceeds the threshold fixes the contour level; the mass of all cells with
    density strictly above that level is returned (normalised by the grid total by default).
    Returns 1.0 (or the grid mass) if no cell exceeds the threshold."""
    exact = np.asarray(exact, dtype=float).ravel()
    approx = np.asarray(approx, dtype=float).ravel()
    order = np.argsort(-exact, kind="stable")
    e = exact[order]
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(approx[order] / e - 1.0)
    bad = ~(err <= threshold)  # nan (0/0) counts as a failure
    total = exact.sum() * cell_area if normalise else 1.0
    if not bad.any():
        return exact.sum() * cell_area / total
    level = e[np.argmax(bad)]
    return exact[exact > level].sum() * cell_area / total


# ----------------------------------------------------------------------------------------
# self checks of the building blocks
# ----------------------------------------------------------------------------------------
def self_check(verbose=True):
    """Check series/closed forms against Gauss-Legendre, derivatives against complex step and
    finite differences, the Jacobian against literal eq. (1), and the vectorised density against
    the slow brentq reference, including a folded (sigma_w t = 120 deg) case.  Returns a dict
    of maximal discrepancies; raises AssertionError on failure."""
    res = {}
    s = np.concatenate([np.linspace(-17, 17, 3401), np.array([0.0, 1e-12, -1e-8, 0.999999, 1.000001])])
    Mv, Mg = _moments(s), _moments_gl(s)
    res["moments_vs_gauss_legendre"] = max(np.max(np.abs(Mv[kk] - Mg[kk])) for kk in Mv)
    # derivative identities A' = (I1c, -I1s), B' = (I2c, -I2s): complex step on the moments
    h = 1e-30
    Mc = _moments(s + 1j * h)
    d = [np.max(np.abs(Mc[(0, "s")].imag / h - Mv[(1, "c")])),
         np.max(np.abs(Mc[(0, "c")].imag / h + Mv[(1, "s")])),
         np.max(np.abs(Mc[(1, "s")].imag / h - Mv[(2, "c")])),
         np.max(np.abs(Mc[(1, "c")].imag / h + Mv[(2, "s")]))]
    res["moment_derivs_vs_complex_step"] = max(d)
    # Jacobian vs central finite differences of literal eq. (1) in (a, w)
    rng = np.random.default_rng(1)
    v0, t = 280.0, 10.0
    a = rng.normal(0, 3, 200)
    w = rng.normal(0, 0.2, 200)
    xi_x, xi_y = cat_position(a, w, v0, t)
    X, Y = xi_x / (v0 * t), xi_y / (v0 * t)
    s_ = w * t
    al, det = _alpha_det(X, Y, s_)
    res["alpha_recovery_rel"] = np.max(np.abs(al - a * t / v0)) / np.max(np.abs(a * t / v0))
    hh = 1e-6
    xp, yp = cat_position(a, w + hh, v0, t)
    xm, ym = cat_position(a, w - hh, v0, t)
    dxdw, dydw = (xp - xm) / (2 * hh), (yp - ym) / (2 * hh)
    xp, yp = cat_position(a + hh, w, v0, t)
    xm, ym = cat_position(a - hh, w, v0, t)
    dxda, dyda = (xp - xm) / (2 * hh), (yp - ym) / (2 * hh)
    det_fd = dxda * dydw - dyda * dxdw            # d(x,y)/d(a,w)
    det_an = det * (v0 * t) ** 2 * (t / v0) * t  # d xi/d(alpha,s) -> d(x,y)/d(a,w)
    res["jacobian_vs_fd_rel"] = np.max(np.abs(det_an / det_fd - 1))
    # f' at the root equals det
    f, fp = _f_fp(X, Y, s_)
    res["f_at_true_root"] = np.max(np.abs(f))
    res["fprime_vs_det"] = np.max(np.abs(fp - det))
    # vectorised density vs slow reference (Figure 1 and a folded case)
    worst = 0.0
    for sw, pts in [(math.pi / 54, [(0.0, 2790.0), (900.0, 2500.0), (-1500.0, 2100.0),
                                    (1e-9, 2800.0), (2400.0, 1200.0), (-300.0, 2600.0)]),
                    (2 * math.pi / 3 / 10, [(0.0, 2000.0), (1500.0, 800.0), (-2000.0, -500.0),
                                            (500.0, -1500.0), (2500.0, 300.0), (-100.0, 100.0)])]:
        xs = np.array([p[0] for p in pts]); ys = np.array([p[1] for p in pts])
        fast, nr = cat_density(xs, ys, v0, t, 5 / 3, sw, return_nroots=True)
        for i, (px, py) in enumerate(pts):
            ref, nref = cat_density_slow(px, py, v0, t, 5 / 3, sw)
            assert np.isfinite(ref) and np.isfinite(fast[i])
            if ref > 1e-300:
                worst = max(worst, abs(fast[i] / ref - 1))
            assert nr[i] == nref, (px, py, nr[i], nref)
    res["density_vs_slow_reference_rel"] = worst
    if verbose:
        for kk, v in res.items():
            print(f"  {kk:34s} {v:.3e}")
    assert res["moments_vs_gauss_legendre"] < 1e-14
    assert res["moment_derivs_vs_complex_step"] < 1e-14
    assert res["jacobian_vs_fd_rel"] < 1e-6
    assert res["fprime_vs_det"] < 1e-12
    assert res["density_vs_slow_reference_rel"] < 1e-8
    return res
