r"""Containment probability of a two-bearing fix: P(true position within R of the fix).

Walsh (1968), "Probability of locating a submarine within a stated distance on the basis of two
directional sensors", reduces the linearised fix error to two independent normal components
along the principal axes of the fix covariance J diag(s1^2, s2^2) J^T (ERRATA: v1, v2 are its
eigenvalues).  The containment probability is then

.. math::  P(R) = P(v_1 t_1^2 + v_2 t_2^2 \le R^2) = P(t_1^2 + V t_2^2 \le x),
           \quad v = \min(v_1, v_2),\ V = \max(v_1, v_2) / v \ge 1,\ x = R^2 / v,

with t1, t2 independent standard normal (Walsh, section "Evaluation of Probability").

Two independent evaluations are offered.

``containment_series``
    The Robbins-Pitman chi-square mixture used by Walsh (his ref. 2),
    :math:`P = \sum_{w \ge 0} H_w C_{2w+2}(x)` with
    :math:`H_w = \binom{2w}{w} 4^{-w} (1 - 1/V)^w V^{-1/2}` (ERRATA) and the bounds
    :math:`L_W = \sum_{w \le W} H_w C_{2w+2}(x) \le P \le L_W + (1 - \sum_{w \le W} H_w)
    C_{2W+4}(x) = U_W` (ERRATA: :math:`C_{2w+2}` on both sides; the OCR prints
    :math:`C_{w+2}`).  It stops, element by element, at the smallest W with
    :math:`U_W - L_W \le` ``tol`` and returns :math:`(L_W + U_W)/2`.

``containment_exact``
    A quadrature of the same probability that shares no algebra with the series:
    with :math:`a(\theta) = \cos^2\theta / v_1 + \sin^2\theta / v_2`,

    .. math::  P = \frac{1}{2\pi\sqrt{v_1 v_2}} \int_0^{2\pi}
               \frac{1 - e^{-R^2 a(\theta)/2}}{a(\theta)}\, d\theta
             = \frac{x}{2\sqrt V}\,\frac{1}{2\pi}\int_0^{2\pi} \varphi_1(w(\phi))\, d\phi,

    :math:`\varphi_1(w) = (1 - e^{-w})/w`, :math:`w(\phi) = q + z (1 + \cos\phi)`,
    :math:`q = x / (2V)`, :math:`z = x (1 - 1/V) / 4` (substituting :math:`\phi = 2\theta`).
    The integrand is an entire, even, 2 pi-periodic function of phi, so the midpoint rule
    converges geometrically; the node count is chosen per element from a rigorous bound
    (see :func:`exact_nodes`).

:func:`containment_radius` inverts P (R50 is the CEP) by safeguarded Newton with the exact
derivative :math:`dP/dR = R/(2\pi\sqrt{v_1 v_2}) \int_0^{2\pi} e^{-R^2 a(\theta)/2} d\theta
= R/\sqrt{v_1 v_2}\; e^{-x/(2V)}\, \mathrm{i0e}(z)` (the theta integral of
:math:`e^{-s(\alpha + \beta\cos 2\theta)}` is :math:`2\pi e^{-s\alpha} I_0(s\beta)`).

Every public function validates its arguments once and raises
:class:`bananagrid.BananagridError` naming the argument, the offending value and the allowed
domain; R, v1, v2 (and p) broadcast together like NumPy arrays.  Scalars in give NumPy
float64 scalars out.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from numbers import Integral

import numpy as np
from scipy import special, stats

from ..validate import BananagridError

__all__ = [
    "EXACT_RTOL",
    "EXACT_MAX_NODES",
    "exact_nodes",
    "robbins_pitman_weights",
    "series_bounds",
    "containment_series",
    "containment_exact",
    "containment",
    "containment_radius",
]

#: Relative truncation error targeted by the exact quadrature (the rounding floor is a few
#: times 1e-16, see :func:`containment_exact`).
EXACT_RTOL = 1e-15

#: Largest node count (on [0, pi]) the exact quadrature will use for one element.
EXACT_MAX_NODES = 1 << 22

#: Beyond q = x / (2V) = R^2 / (2 max(v1, v2)) = 40, 1 - P <= exp(-q) < 4.3e-18: P == 1.0.
_Q_SATURATE = 40.0

#: Below x = R^2 / v = 2e-8, P = x/(2 sqrt V) (1 - x (1 + 1/V)/8) with relative error
#: < x^2/24 < 2e-17 (two terms of the mean of phi_1(w) = 1 - w/2 + w^2/6 - ...).
_X_TINY = 2e-8

#: Poisson mean y = x/2 above which the series may start its Poisson recursion near the
#: lower tail of Poisson(y), at w0 = ceil(y - 9 sqrt(y)) >= 40, instead of at exp(-y) (which
#: underflows past y = 708); below it the special-function start costs more than it saves.
_Y_SKIP = 150.0

#: Elements x nodes per block of the quadrature (a few 512 KiB temporaries: bounded memory).
_BLOCK = 1 << 16

#: Elements per block of the series recursion.
_SERIES_BLOCK = 1 << 16


# --------------------------------------------------------------------------------------------
# Validation (once per public call)
# --------------------------------------------------------------------------------------------


def _real_array(name: str, value) -> np.ndarray:
    if isinstance(value, (str, bytes)):
        raise BananagridError(f"{name} = {value!r}: expected a real number or an array of them")
    try:
        a = np.asarray(value)
    except Exception:  # ragged lists and the like
        raise BananagridError(f"{name} = {value!r}: expected a real number or an array of them") from None
    if a.dtype == np.bool_ or a.dtype.kind not in "iuf":
        raise BananagridError(f"{name} = {value!r}: expected a real number or an array of them")
    return a.astype(np.float64, copy=False)


def _require(name: str, a: np.ndarray, ok: np.ndarray, domain: str) -> None:
    """Raise naming the first element of ``a`` where ``ok`` is False."""
    if ok.all():
        return
    i = int(np.flatnonzero(~ok.ravel())[0])
    label = name if a.ndim == 0 else f"{name}[{', '.join(map(str, np.unravel_index(i, a.shape)))}]"
    raise BananagridError(f"{label} = {float(a.ravel()[i])!r}: must be {domain}")


def _variances(v1, v2) -> tuple[np.ndarray, np.ndarray]:
    out = []
    for name, value in (("v1", v1), ("v2", v2)):
        a = _real_array(name, value)
        with np.errstate(invalid="ignore"):
            _require(name, a, np.isfinite(a) & (a > 0.0), "finite and > 0")
        out.append(a)
    return out[0], out[1]


def _radius(R) -> np.ndarray:
    a = _real_array("R", R)
    with np.errstate(invalid="ignore"):
        _require("R", a, np.isfinite(a) & (a >= 0.0), "finite and >= 0")
    return a


def _broadcast(names: tuple[str, ...], arrays: tuple[np.ndarray, ...]) -> list[np.ndarray]:
    try:
        return list(np.broadcast_arrays(*arrays))
    except ValueError:
        shapes = ", ".join(f"{n} shape {a.shape}" for n, a in zip(names, arrays))
        raise BananagridError(f"{', '.join(names)}: {shapes} do not broadcast together") from None


def _tol(tol) -> float:
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.integer, np.floating)):
        raise BananagridError(f"tol = {tol!r}: expected a real number in (0, 0.1]")
    t = float(tol)
    if not (0.0 < t <= 0.1):
        raise BananagridError(f"tol = {t!r}: must be in (0, 0.1]")
    return t


def _count(name: str, value, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise BananagridError(f"{name} = {value!r}: expected an integer >= {minimum}")
    v = int(value)
    if v < minimum:
        raise BananagridError(f"{name} = {v}: must be an integer >= {minimum}")
    return v


def _threads(threads) -> int:
    if threads is None:
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # pragma: no cover - non-Linux
            return max(1, os.cpu_count() or 1)
    return _count("threads", threads, 1)


def _geometry(R, v1, v2):
    """Validated, broadcast (shape, x, V-derived quantities) as flat float64 arrays."""
    R = _radius(R)
    v1, v2 = _variances(v1, v2)
    R, v1, v2 = _broadcast(("R", "v1", "v2"), (R, v1, v2))
    return R.shape, R.ravel(), v1.ravel(), v2.ravel()


def _reduced(R, v1, v2):
    """x = R^2/v, s = V^(-1/2) = sqrt(v/vmax), r = 1 - 1/V = (vmax - v)/vmax (exact-ish)."""
    vmin = np.minimum(v1, v2)
    vmax = np.maximum(v1, v2)
    with np.errstate(over="ignore"):
        x = (R / vmin) * R if R.size else R.copy()
        x = np.where(np.isfinite(x), x, np.inf)
    ratio = vmin / vmax
    s = np.sqrt(vmin) / np.sqrt(vmax)  # no underflow for extreme V
    r = (vmax - vmin) / vmax
    return x, s, r, ratio


def _shaped(flat: np.ndarray, shape: tuple[int, ...]):
    return flat.reshape(shape)[()]


def _run(tasks, threads: int) -> None:
    if threads == 1 or len(tasks) <= 1:
        for task in tasks:
            task()
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for future in [pool.submit(task) for task in tasks]:
            future.result()


# --------------------------------------------------------------------------------------------
# Robbins-Pitman series
# --------------------------------------------------------------------------------------------


def robbins_pitman_weights(V, W):
    r"""Robbins-Pitman mixture weights :math:`H_0, \dots, H_W` of :math:`t_1^2 + V t_2^2`.

    .. math::  H_w = \binom{2w}{w} 4^{-w} (1 - 1/V)^w V^{-1/2}

    (ERRATA, walsh section; Walsh's coefficients of
    :math:`V^{-1/2}[1 - (1 - 1/V) z]^{-1/2} = \sum_w H_w z^w`), computed by the recursion
    :math:`H_0 = V^{-1/2}`, :math:`H_{w+1} = H_w \frac{2w+1}{2w+2} (1 - 1/V)` (no factorials,
    no overflow; terms past the float64 range underflow to 0).  They are the negative-binomial
    probabilities with shape 1/2 and success probability 1/V, so :math:`\sum_w H_w = 1`.

    Parameters
    ----------
    V : array_like
        Variance ratio max(v1, v2) / min(v1, v2), finite and >= 1.
    W : int
        Last index, >= 0.

    Returns
    -------
    ndarray, shape ``np.shape(V) + (W + 1,)``
    """
    Va = _real_array("V", V)
    with np.errstate(invalid="ignore"):
        _require("V", Va, np.isfinite(Va) & (Va >= 1.0), "finite and >= 1")
    W = _count("W", W, 0)
    H = np.empty(Va.shape + (W + 1,))
    H[..., 0] = 1.0 / np.sqrt(Va)
    r = (Va - 1.0) / Va
    for w in range(W):
        H[..., w + 1] = H[..., w] * ((2 * w + 1) / (2 * w + 2)) * r
    return H


def _poisson_pmf(k: np.ndarray, y: np.ndarray) -> np.ndarray:
    """exp(-y) y^k / k! (k >= 0 integral, y > 0) without overflow or cancellation.

    Loader (2000), "Fast and accurate computation of binomial probabilities": for k >= 16,
    log pmf = -stirlerr(k) - bd0(k, y) - log(2 pi k)/2 with bd0 = k log(k/y) + y - k taken from
    its series in v = (k - y)/(k + y) where |v| < 1/4 (where it is small and would cancel)
    and stirlerr(k) = log k! - (k + 1/2) log k + k - log(2 pi)/2 from five Stirling terms
    (error < 1e-18); below 16 the direct form.  Relative error ~1e-15 where the pmf matters.
    """
    k = np.asarray(k, dtype=float)
    y = np.asarray(y, dtype=float)
    k, y = np.broadcast_arrays(k, y)
    out = np.empty(k.shape)
    small = k < 16
    if small.any():
        ks, ysm = k[small], y[small]
        out[small] = np.exp(special.xlogy(ks, ysm) - ysm - special.gammaln(ks + 1.0))
    big = ~small
    if big.any():
        kb, yb = k[big], y[big]
        kk = kb * kb
        stirlerr = (1 / 12 - (1 / 360 - (1 / 1260 - (1 / 1680 - 1 / (1188 * kk)) / kk) / kk) / kk) / kb
        v = (kb - yb) / (kb + yb)
        near = np.abs(v) < 0.25
        with np.errstate(divide="ignore", invalid="ignore"):
            bd0 = kb * np.log(kb / yb) + yb - kb
        vn = v[near]
        series = (kb[near] - yb[near]) * vn
        ej = 2.0 * kb[near] * vn
        v2 = vn * vn
        for j in range(1, 25):  # v^2 < 1/16: the 24th term is below 1e-28 of the first
            ej = ej * v2
            series = series + ej / (2 * j + 1)
        bd0[near] = series
        out[big] = np.exp(-stirlerr - bd0) / np.sqrt(2.0 * math.pi * kb)
    return out


#: Steps between exact re-evaluations of every running quantity of the series recursion.
_RESYNC = 1024
#: Active elements at or below which a block finishes its elements one by one, vectorised
#: along the terms instead of across elements.
_TAIL = 16


def _exact_state(w, y, r, ratio):
    """H_w, T_w = 1 - sum_{j<=w} H_j, C_{2w+2}(x), p_w from special functions (w array)."""
    H = stats.nbinom.pmf(w, 0.5, ratio)  # H_w = NegBin(1/2, 1/V) pmf (ERRATA's H_w)
    T = special.betainc(w + 1.0, 0.5, r)  # P(NegBin > w) = I_{1-1/V}(w + 1, 1/2)
    C = special.gammainc(w + 1.0, y)  # C_{2w+2}(2y) = P(Gamma(w + 1) <= y)
    p = _poisson_pmf(w, y)
    return H, T, C, p


def _series_start(y, s, r, ratio, tol, W_fixed):
    """Initial state (w, H, T, C, p, L) of every element."""
    w = np.zeros(y.size)
    H = s.copy()  # H_0 = V^(-1/2)
    T = r / (1.0 + s)  # 1 - V^(-1/2) without cancellation near V = 1
    p = np.exp(-y)
    C = -np.expm1(-y)
    L = H * C
    # Where exp(-y) underflows and the series has to run past the bulk of Poisson(y), start at
    # w0 = ceil(y - 9 sqrt(y)): P(Poisson(y) < w0) < exp(-81/2) = 2.6e-18 (Chernoff), so every
    # C_{2w+2}(x) with w < w0 is 1 to that accuracy and sum_{w<w0} H_w C_{2w+2} = 1 - T_{w0-1}.
    skip = np.flatnonzero(y > _Y_SKIP)
    if skip.size:
        w0 = np.ceil(y[skip] - 9.0 * np.sqrt(y[skip]))
        if W_fixed is None:
            # The gap at w < w0 is T_w C_{2w+4} >= T_{w0-1} (1 - 3e-18): skip only past W's
            # that cannot stop.  T_{w0-1} = I_{1-1/V}(w0, 1/2).
            ok = special.betainc(w0, 0.5, r[skip]) > tol
        else:
            ok = w0 <= W_fixed
        i, w0 = skip[ok], w0[ok]
        if i.size:
            w[i] = w0
            H[i], T[i], C[i], p[i] = _exact_state(w0, y[i], r[i], ratio[i])
            L[i] = special.betainc(0.5, w0, ratio[i]) + H[i] * C[i]  # NegBin cdf at w0 - 1
    return w, H, T, C, p, L


def _series_tail(y, r, ratio, w, L, tol, last, fixed):
    """One element from state (w, L) on, vectorised along blocks of terms m = w+1 .. w+K.

    In a block, p_m and H_m are running products from exact values at the block start, and the
    tails are summed from exact values at its end, all terms positive:
    C_{2m+2} = C_{2(w+K)+2} + sum_{m<i<=w+K} p_i, T_m = T_{w+K} + sum_{m<i<=w+K} H_i.
    Returns (lower, upper, W), or None if ``last`` is reached with the gap above tol.
    """
    def exact(m):
        return (float(a[0]) for a in _exact_state(np.array([m]), np.array([y]), np.array([r]), np.array([ratio])))

    H, T, _, p = exact(w)
    K = 32
    while True:
        K = int(min(K, last - w + 1))
        i = w + 1.0 + np.arange(K)
        fp = y / i
        fp[0] *= p
        pi = np.cumprod(fp)  # p_{w+1..w+K}
        fh = r * (i - 0.5) / i
        fh[0] *= H
        Hi = np.cumprod(fh)  # H_{w+1..w+K}
        wK = w + K
        H, Tend, Cend, p = exact(wK)
        Ci = Cend + np.concatenate((np.cumsum(pi[:0:-1])[::-1], [0.0]))
        Ti = Tend + np.concatenate((np.cumsum(Hi[:0:-1])[::-1], [0.0]))
        Li = L + np.cumsum(Hi * Ci)
        gap = np.concatenate(([T], Ti[:-1])) * Ci  # gap at m = w .. w+K-1: T_m C_{2m+4}
        Lm = np.concatenate(([L], Li[:-1]))
        if fixed:
            hit = [K - 1] if wK - 1 >= last else []
        else:
            hit = np.flatnonzero(gap <= tol)
        if len(hit):
            j = int(hit[0])
            return Lm[j], Lm[j] + gap[j], int(w) + j
        if wK - 1 >= last:
            return None
        w, L, T = wK, Li[-1], Tend
        K = min(2 * K, 1024)


def _series_block(y, s, r, ratio, tol, max_terms, W_fixed):
    """Bounds (L_W, U_W) and W for flat arrays; W adaptive (the smallest with U - L <= tol) or
    W_fixed.  State at index w: H = H_w, T = 1 - sum_{j<=w} H_j, C = C_{2w+2}(x),
    p = exp(-y) y^w / w! (y = x/2), L = sum_{j<=w} H_j C_{2j+2}(x).  A step uses
    p_{w+1} = p_w y/(w+1), C_{2w+4} = C_{2w+2} - p_{w+1} (the even-dof chi-square CDF is a
    Poisson upper tail: C_{2w+2}(x) = 1 - exp(-y) sum_{j<=w} y^j/j!),
    H_{w+1} = H_w (w + 1/2)/(w + 1) (1 - 1/V).  Returns (lower, upper, W, failed positions)."""
    n = y.size
    lower, upper = np.empty(n), np.empty(n)
    Wout = np.empty(n, dtype=np.int64)
    failed = []
    fixed = W_fixed is not None
    last = W_fixed if fixed else max_terms - 1
    w, H, T, C, p, L = _series_start(y, s, r, ratio, tol, W_fixed)
    pos = np.arange(n)
    ys, rs, qs = y, r, ratio
    beyond = w > last  # the smallest admissible W is past max_terms - 1 already
    if beyond.any():
        failed.extend(pos[beyond])
        keep = ~beyond
        pos, ys, rs, qs, w, H, T, C, p, L = (a[keep] for a in (pos, ys, rs, qs, w, H, T, C, p, L))
    if w.size and np.all(w == w[0]):
        w = float(w[0])  # a common index: scalar arithmetic
    Cref, Tref = C * (1 / 16), T * (1 / 16)
    step = 0
    while pos.size:
        if pos.size <= _TAIL:
            for k in range(pos.size):
                wk = w if np.ndim(w) == 0 else w[k]
                res = _series_tail(ys[k], rs[k], qs[k], wk, L[k], tol, last, fixed)
                if res is None:
                    failed.append(pos[k])
                else:
                    lower[pos[k]], upper[pos[k]], Wout[pos[k]] = res
            break
        step += 1
        if step % _RESYNC == 0:
            wa = np.broadcast_to(w, ys.shape).astype(float)
            H, T, C, p = _exact_state(wa, ys, rs, qs)
            Cref, Tref = C * (1 / 16), T * (1 / 16)
        inv = 1.0 / (w + 1.0)
        pn = p * ys
        pn *= inv
        Cn = C - pn
        # C and T are tails computed by subtraction: their absolute error grows by about eps a
        # step, which would stall the gap T C_{2W+4} near 1e-13 after thousands of steps.
        # Each time one has fallen 16-fold since its last exact value it is taken afresh from
        # the regularised incomplete gamma / beta function (a few times per element).
        low = Cn < Cref
        if low.any():
            wl = w + 2.0 if np.ndim(w) == 0 else w[low] + 2.0
            Cn[low] = special.gammainc(wl, ys[low])
            Cref[low] = Cn[low] * (1 / 16)
        # (a negative Cn from rounding is below Cref > 0, so it has just been recomputed)
        gap = T * Cn
        if fixed:
            done = np.broadcast_to(np.asarray(w) >= W_fixed, gap.shape)
            at_last = done
        else:
            done = gap <= tol
            at_last = w >= last if np.ndim(w) == 0 else w >= last
        if done.any() or np.any(at_last):
            d = np.flatnonzero(done)
            lower[pos[d]] = L[d]
            upper[pos[d]] = L[d] + gap[d]
            Wout[pos[d]] = w if np.ndim(w) == 0 else w[d]
            bad = at_last & ~done
            if np.any(bad):
                failed.extend(pos[np.broadcast_to(bad, done.shape)])
            keep = np.flatnonzero(~(done | at_last))
            pos, ys, rs, qs, Cref, Tref = pos[keep], ys[keep], rs[keep], qs[keep], Cref[keep], Tref[keep]
            H, T, C, L, p, Cn, pn = H[keep], T[keep], C[keep], L[keep], p[keep], Cn[keep], pn[keep]
            inv = inv if np.ndim(w) == 0 else inv[keep]
            if np.ndim(w):
                w = w[keep]
            if not pos.size:
                break
        # advance to w + 1
        H *= rs * ((w + 0.5) * inv)
        T -= H
        low = T < Tref
        if low.any():  # T_{w+1} = P(NegBin(1/2, 1/V) > w + 1) = I_{1-1/V}(w + 2, 1/2)
            wl = w + 2.0 if np.ndim(w) == 0 else w[low] + 2.0
            T[low] = special.betainc(wl, 0.5, rs[low])
            Tref[low] = T[low] * (1 / 16)
        L += H * Cn
        C, p = Cn, pn
        w = w + 1.0
    return lower, upper, Wout, np.asarray(failed, dtype=np.int64)


def _series_flat(R, v1, v2, tol, max_terms, W_fixed, threads):
    x, s, r, ratio = _reduced(R, v1, v2)
    y = 0.5 * x
    n = x.size
    lower, upper = np.empty(n), np.empty(n)
    W = np.empty(n, dtype=np.int64)
    # Blocks of elements with similar expected W (about min(V ln(1/tol), y + 7 sqrt(y))),
    # so that a block's loop is not kept running by a few long ones.
    with np.errstate(divide="ignore"):
        V = 1.0 / ratio
    est = np.minimum(V * math.log(1.0 / tol), y + 7.0 * np.sqrt(y) + 2.0)
    order = np.argsort(np.floor(8.0 * np.log2(est + 1.0)).astype(np.int16), kind="stable")
    failures = []

    def task(sel):
        def run():
            lo, up, w, bad = _series_block(y[sel], s[sel], r[sel], ratio[sel], tol, max_terms, W_fixed)
            lower[sel], upper[sel], W[sel] = lo, up, w
            if bad.size:
                failures.append(sel[bad])

        return run

    _run([task(order[a : a + _SERIES_BLOCK]) for a in range(0, n, _SERIES_BLOCK)], threads)
    np.minimum(upper, 1.0, out=upper)  # P <= 1: still a bound, and rounding cannot pass 1
    if failures:
        index = np.sort(np.concatenate(failures))
        i = int(index[0])
        Vi = max(v1[i], v2[i]) / min(v1[i], v2[i])
        raise BananagridError(
            f"max_terms = {max_terms}: the Robbins-Pitman series did not reach tol = {tol!r} "
            f"for {index.size} of {n} geometries (first: R = {float(R[i])!r}, "
            f"v1 = {float(v1[i])!r}, v2 = {float(v2[i])!r}, V = {Vi:.6g}, R^2/v = {x[i]:.6g}); "
            f"it needs about min(V ln(1/tol), R^2/(2v) + 5 sqrt(R^2/v)) terms: raise max_terms "
            f"or tol, or use method='exact'"
        )
    return lower, upper, W


def series_bounds(R, v1, v2, W, *, threads=None):
    r"""Walsh's lower and upper bounds on P(R) after the terms w = 0..W (ERRATA-corrected).

    .. math::  L_W = \sum_{w=0}^{W} H_w C_{2w+2}(x) \;\le\; P \;\le\;
               L_W + \Big[1 - \sum_{w=0}^{W} H_w\Big] C_{2W+4}(x) = U_W,
               \qquad x = R^2 / \min(v_1, v_2)

    (Walsh, final inequality of "Evaluation of Probability"; the OCR's :math:`C_{w+2}` is
    :math:`C_{2w+2}`, ERRATA).  The upper bound holds because :math:`C_{2w+2}(x)` decreases
    in w.

    Parameters
    ----------
    R : array_like
        Radius, finite and >= 0.
    v1, v2 : array_like
        Principal variances of the fix error, finite and > 0; broadcast with R.
    W : int
        Last term, >= 0.
    threads : int, optional
        Worker threads (default: every core this process may use).

    Returns
    -------
    lower, upper : ndarray or float64
    """
    shape, R, v1, v2 = _geometry(R, v1, v2)
    W = _count("W", W, 0)
    lower, upper, _ = _series_flat(R, v1, v2, 0.1, W + 1, W, _threads(threads))
    return _shaped(lower, shape), _shaped(upper, shape)


def containment_series(R, v1, v2, tol=1e-12, max_terms=100000, return_bounds=False, *, threads=None):
    r"""P(v1 t1^2 + v2 t2^2 <= R^2) by the Robbins-Pitman series, to ``tol`` (absolute).

    .. math::  P = \sum_{w=0}^{\infty} H_w C_{2w+2}(x), \qquad x = R^2/v,

    with :math:`H_w` of :func:`robbins_pitman_weights` and the even-dof chi-square CDF
    :math:`C_{2w+2}(x) = 1 - e^{-x/2} \sum_{j=0}^{w} (x/2)^j / j!` (Walsh, "Evaluation of
    Probability"; ERRATA for H_w and the bounds).  For each element the sum runs to the
    smallest W whose bounds :math:`L_W \le P \le U_W` (:func:`series_bounds`) satisfy
    :math:`U_W - L_W \le` ``tol``, and the midpoint :math:`(L_W + U_W)/2` is returned, so
    :math:`|P_{\rm returned} - P| \le` ``tol``/2 plus rounding (a few 1e-16 times W).

    The Poisson terms :math:`p_{w+1} = p_w\,(x/2)/(w+1)` and
    :math:`C_{2w+4} = C_{2w+2} - p_{w+1}` (starting from :math:`C_2 = -\mathrm{expm1}(-x/2)`)
    and :math:`H_{w+1} = H_w (2w+1)/(2w+2)\,(1 - 1/V)` are updated in place; no per-term
    special-function call in the loop.  Where x/2 > 150 and the series has to run past the
    bulk of Poisson(x/2), the recursion starts at :math:`w_0 = \lceil x/2 - 9\sqrt{x/2} \rceil`
    (all earlier :math:`C_{2w+2}(x)` are 1 to 3e-18, and their terms sum to
    :math:`\sum_{w<w_0} H_w`) from accurate values: regularised incomplete gamma and beta
    functions, the negative-binomial pmf and Loader's Poisson pmf (this also avoids the
    underflow of :math:`e^{-x/2}` past x/2 = 708).  The running tails C and
    :math:`1 - \sum H` are recomputed from those functions whenever they have fallen 16-fold
    and every 1024 terms, so rounding stays near 1e-16 W at worst; an element still running
    when 16 or fewer are left in its block is finished alone, vectorised along the terms.

    Cost.  The gap :math:`U_W - L_W \le \min(1 - \sum_{w \le W} H_w,\ C_{2W+4}(x))`; the first
    factor decays like :math:`(1 - 1/V)^W` and the second once W passes the Poisson bulk
    x/2.  So about :math:`\min(V \ln(1/{\rm tol}),\ x/2 + 5\sqrt{x})` terms are needed: few
    for V near 1 or small R, but for large V (say 1e6) and R comparable to the long axis
    (x ~ V) it takes of order x/2 terms, i.e. ~5e5 at R = sigma_major; past ``max_terms`` a
    :class:`BananagridError` says so (use :func:`containment_exact` there).

    Parameters
    ----------
    R : array_like
        Radius, finite and >= 0.
    v1, v2 : array_like
        Principal variances (eigenvalues of the fix covariance), finite and > 0; R, v1 and v2
        broadcast together.
    tol : float
        Absolute width of the bounds at which to stop, in (0, 0.1].  Any value is reached
        (the tails are recomputed, not left to cancel); below about 1e-15 the returned value is
        limited by rounding, not by tol.
    max_terms : int
        Most terms per element (W + 1), >= 1.
    return_bounds : bool
        Also return the bounds and the W used.
    threads : int, optional
        Worker threads over blocks of elements (default: every core this process may use).

    Returns
    -------
    P : ndarray or float64
        Midpoint estimate.
    lower, upper : ndarray or float64
        Only with ``return_bounds``: :math:`L_W`, :math:`U_W`.
    W : ndarray of int64 or int64
        Only with ``return_bounds``: last term used.
    """
    shape, R, v1, v2 = _geometry(R, v1, v2)
    tol = _tol(tol)
    max_terms = _count("max_terms", max_terms, 1)
    if not isinstance(return_bounds, (bool, np.bool_)):
        raise BananagridError(f"return_bounds = {return_bounds!r}: expected True or False")
    lower, upper, W = _series_flat(R, v1, v2, tol, max_terms, None, _threads(threads))
    P = 0.5 * (lower + upper)
    if return_bounds:
        return _shaped(P, shape), _shaped(lower, shape), _shaped(upper, shape), _shaped(W, shape)
    return _shaped(P, shape)


# --------------------------------------------------------------------------------------------
# Exact quadrature
# --------------------------------------------------------------------------------------------


def exact_nodes(x, V):
    r"""Node count N on [0, pi] of the midpoint rule used by :func:`containment_exact`.

    .. math::  N = \max\Big(1,\ \min\Big(\big\lceil 2.5\sqrt{x} + 5 \big\rceil,\
               \Big\lceil \frac{25 + \ln(V)/4}{y_0} \Big\rceil\Big)\Big),\qquad
               y_0 = \ln\frac{\sqrt V + 1}{\sqrt V - 1} = 2\,\mathrm{artanh}(V^{-1/2}).

    Justification.  With M = 2N equispaced nodes on a period, the error of the periodic
    trapezoid (or midpoint) rule for a function analytic and bounded by B in the strip
    :math:`|\mathrm{Im}\,\phi| < y` is at most :math:`4\pi B/(e^{My} - 1)` (Trefethen and
    Weideman, SIAM Review 56 (2014), Thm 3.2).  On :math:`\mathrm{Im}\,\phi = \pm y`,
    :math:`|\varphi_1(w)| \le \varphi_1(\mathrm{Re}\,w)` and
    :math:`\mathrm{Re}\,w \ge m(y) = q - z(\cosh y - 1)`, so

    .. math::  |P_N - P| \le \frac{x}{\sqrt V}\,\frac{\varphi_1(m(y))}{e^{2Ny} - 1}
               \quad\text{for every } y > 0.

    For :math:`y < y_0` (where a vanishes: the pole of 1/a) :math:`m > 0` and the bound is
    x-independent, which gives the V-only term (the pole-limited rate, about
    :math:`\sqrt V/2` per unit of y); for larger y and x << V the optimum is Gaussian,
    :math:`e^{-(2N)^2/(x)}`-like, which gives the :math:`\sqrt x` term.  The two constants were
    fitted so that, on a dense grid of V in [1, 1e14] and x in [2e-8, 80 V], the bound
    minimised over y is below ``EXACT_RTOL`` times a lower bound of P
    (:math:`\max((1 - e^{-x/2})/\sqrt V,\ 1 - e^{-x/(2V)})`), with N at least 2.6 % above
    the count that the bound requires (14 % for V <= 1e6); ``tests/models/test_containment.py``
    re-checks the bound on such a grid and compares N with 2N nodes in extended precision
    (observed truncation below 1e-18 relative).
    """
    x = np.asarray(x, dtype=float)
    V = np.asarray(V, dtype=float)
    with np.errstate(divide="ignore"):
        y0 = 2.0 * np.arctanh(1.0 / np.sqrt(V))
        pole = np.ceil((25.0 + 0.25 * np.log(V)) / y0)
    gauss = np.ceil(2.5 * np.sqrt(x) + 5.0)
    return np.maximum(1.0, np.minimum(gauss, pole))


def _quadrature_block(q, z, pref, N, cancel_free, out, where):
    """out[where] = pref * mean_j phi_1(q + z (1 + cos phi_j)), phi_j = pi (j + 1/2)/N."""
    # 1 + cos(phi_j) = 2 sin^2((pi - phi_j)/2), and {pi - phi_j} = {phi_j}: every c_j has a
    # small relative error (1 + cos of a rounded phi near pi would not: its error grows like
    # eps / (pi - phi), 1e-14 relative in P for x ~ 1e4).
    c = 2.0 * np.sin((np.arange(N) + 0.5) * (0.5 * math.pi / N)) ** 2
    negw = np.multiply.outer(-z, c)
    negw -= q[:, None]  # -w
    if cancel_free:  # P >= 1/4: 1 - exp(-w) good to eps absolute is eps/P <= 4 eps relative
        e = np.exp(negw)
        e -= 1.0
    else:
        e = np.expm1(negw)
    e /= negw  # (1 - exp(-w)) / w
    out[where] = pref * e.sum(axis=1) * (1.0 / N)


def _exact_flat(x, s, threads=1):
    """P for flat arrays x = R^2/v >= 0 and s = V^(-1/2) in (0, 1]."""
    n = x.size
    P = np.empty(n)
    with np.errstate(divide="ignore", over="ignore"):
        V = 1.0 / (s * s)  # inf past V = 1e308: then only sqrt(x) limits the node count
    q = x * (0.5 * s * s)  # x / (2V)
    sat = q > _Q_SATURATE
    tiny = x < _X_TINY
    P[sat] = 1.0
    xt = x[tiny]
    P[tiny] = (0.5 * s[tiny]) * xt * (1.0 - xt * (1.0 + s[tiny] ** 2) / 8.0)
    rest = np.flatnonzero(~sat & ~tiny)
    if rest.size == 0:
        return P
    xr, sr, qr, Vr = x[rest], s[rest], q[rest], V[rest]
    N = exact_nodes(xr, Vr)
    if np.any(N > EXACT_MAX_NODES):
        i = int(np.flatnonzero(N > EXACT_MAX_NODES)[0])
        raise BananagridError(
            f"R^2/v = {xr[i]:.6g} with V = {Vr[i]:.6g}: the exact quadrature would need "
            f"{N[i]:.3g} nodes (> {EXACT_MAX_NODES}); the ellipse is too elongated for R"
        )
    # Round N up to a ladder (exact to 32, then 4.4 % steps) so that few groups share a node
    # set; group by (rung, cancellation-free) with a radix sort of a small integer key.
    rung = np.where(N > 32, 32.0 + np.ceil(16.0 * np.log2(np.maximum(N, 32.0) / 32.0)), N)
    plb = np.maximum(-np.expm1(-0.5 * xr) * sr, -np.expm1(-qr))
    key = (2 * rung + (plb >= 0.25)).astype(np.int16)
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    starts = np.concatenate(([0], np.flatnonzero(sorted_key[1:] != sorted_key[:-1]) + 1))
    bounds = list(starts) + [rest.size]
    keys = sorted_key[starts]
    zr = xr * (0.25 * (1.0 - sr * sr))
    pref = 0.5 * xr * sr
    tasks = []
    for k, a, b in zip(keys, bounds[:-1], bounds[1:]):
        rk, cancel_free = int(k) // 2, bool(k % 2)
        Nk = rk if rk <= 32 else int(math.ceil(32.0 * 2.0 ** ((rk - 32) / 16.0)))
        rows = max(1, _BLOCK // Nk)
        for c0 in range(a, b, rows):
            sel = order[c0 : min(c0 + rows, b)]
            tasks.append(
                lambda sel=sel, Nk=Nk, cf=cancel_free: _quadrature_block(
                    qr[sel], zr[sel], pref[sel], Nk, cf, P, rest[sel]
                )
            )
    _run(tasks, threads)
    return P


def containment_exact(R, v1, v2, *, threads=None):
    r"""P(v1 t1^2 + v2 t2^2 <= R^2) by a periodic quadrature accurate to ~1e-15 relative.

    .. math::  P = \frac{1}{2\pi\sqrt{v_1 v_2}}\int_0^{2\pi}
               \frac{1 - e^{-R^2 a(\theta)/2}}{a(\theta)}\,d\theta
             = \frac{x}{2\sqrt V}\,\frac1N\sum_{j=0}^{N-1} \varphi_1\big(q + z(1 + \cos\phi_j)\big)
               + E_N,

    :math:`a(\theta) = \cos^2\theta/v_1 + \sin^2\theta/v_2`, :math:`\phi_j = \pi(j + 1/2)/N`,
    :math:`\varphi_1(w) = (1 - e^{-w})/w`, :math:`x = R^2/v`, :math:`q = x/(2V)`,
    :math:`z = x(1 - 1/V)/4`.  The first form is the disc integral of the bivariate normal
    density in polar coordinates (the radial integral done in closed form); the second
    substitutes :math:`\phi = 2\theta` and uses the evenness of the integrand (the midpoint rule
    with N nodes on [0, pi] is the rule with 2N nodes on the period).

    The integrand is entire in phi (the pole of 1/a cancels), so the rule converges
    geometrically; N is chosen per element by :func:`exact_nodes` so that the truncation error
    is below ``EXACT_RTOL`` = 1e-15 times P.  All terms are positive and summed pairwise;
    :math:`1 - e^{-w}` is ``-expm1(-w)`` where P may be below 1/4, so small probabilities keep
    their relative accuracy (rounding: a few 1e-16 relative).  For V = 1 one node is exact
    (:math:`P = 1 - e^{-R^2/(2v)}`, the Rayleigh law); R = 0 gives 0; for x < 2e-8 the
    two-term expansion :math:`P = x/(2\sqrt V)\,(1 - x(1 + 1/V)/8)` is used; for
    :math:`R^2/(2\max(v_1, v_2)) > 40`, :math:`1 - P < 4.3\times10^{-18}` and P = 1.0.

    Cost: N is about :math:`2.5\sqrt{x} + 5`, at most :math:`\approx 12.5\sqrt V` for
    very elongated ellipses; work is split in cache-sized blocks (bounded memory) over
    ``threads`` workers.  Geometries needing more than ``EXACT_MAX_NODES`` nodes (x above
    about 2.8e12 with V above about 1e11) are refused.

    Parameters
    ----------
    R : array_like
        Radius, finite and >= 0.
    v1, v2 : array_like
        Principal variances, finite and > 0; R, v1, v2 broadcast together.
    threads : int, optional
        Worker threads (default: every core this process may use).

    Returns
    -------
    ndarray or float64
    """
    shape, R, v1, v2 = _geometry(R, v1, v2)
    threads = _threads(threads)
    x, s, _, _ = _reduced(R, v1, v2)
    return _shaped(_exact_flat(x, s, threads), shape)


def containment(R, v1, v2, method="exact", tol=1e-12, *, threads=None):
    """Containment probability P(v1 t1^2 + v2 t2^2 <= R^2): dispatch to
    :func:`containment_exact` (``method="exact"``, default; ``tol`` is not used) or
    :func:`containment_series` (``method="series"``, absolute tolerance ``tol``)."""
    if method == "exact":
        _tol(tol)
        return containment_exact(R, v1, v2, threads=threads)
    if method == "series":
        return containment_series(R, v1, v2, tol=tol, threads=threads)
    raise BananagridError(f"method = {method!r}: must be one of exact, series")


# --------------------------------------------------------------------------------------------
# Radius for a given probability
# --------------------------------------------------------------------------------------------


def containment_radius(p, v1, v2, *, threads=None):
    r"""The radius R with P(v1 t1^2 + v2 t2^2 <= R^2) = p (R50 = CEP, R90, R95, ...).

    Safeguarded Newton on :math:`\rho = R/\sqrt v` with the exact derivative

    .. math::  \frac{dP}{dR} = \frac{R}{2\pi\sqrt{v_1 v_2}}\int_0^{2\pi}
               e^{-R^2 a(\theta)/2}\,d\theta = \frac{R}{\sqrt{v_1 v_2}}\;
               e^{-x/(2V)}\,\mathrm{i0e}\Big(\frac{x(1 - 1/V)}{4}\Big),

    P from :func:`containment_exact`, inside the bracket given by
    :math:`1 - e^{-x/(2V)} \le P \le 1 - e^{-x/2}` and
    :math:`(1 - e^{-x/2})/\sqrt V \le P \le x/(2\sqrt V)` (narrower and narrower as Newton's
    iterates fall on either side; a step leaving the bracket is replaced by bisection).  It
    stops when the Newton step is below 1e-13 R (the error after that step is far smaller) or
    |P - p| <= 4 eps p.  The result is accurate to about 1e-15 relative where
    :math:`R\,dP/dR` is not small, i.e. except for p very close to 1, where the conditioning
    :math:`\delta R / R \approx 1e{-16} / (R\, dP/dR)` is the limit.  For V = 1 the
    closed form :math:`R = \sqrt{-2 v \ln(1 - p)}` is returned; p = 0 gives R = 0.

    Parameters
    ----------
    p : array_like
        Probability in [0, 1).
    v1, v2 : array_like
        Principal variances, finite and > 0; p, v1, v2 broadcast together.
    threads : int, optional
        Worker threads for the quadrature.

    Returns
    -------
    ndarray or float64
    """
    pa = _real_array("p", p)
    with np.errstate(invalid="ignore"):
        _require("p", pa, (pa >= 0.0) & (pa < 1.0), "in [0, 1)")
    v1, v2 = _variances(v1, v2)
    pa, v1, v2 = _broadcast(("p", "v1", "v2"), (pa, v1, v2))
    threads = _threads(threads)
    shape = pa.shape
    pf, v1, v2 = pa.ravel(), v1.ravel(), v2.ravel()
    vmin = np.minimum(v1, v2)
    vmax = np.maximum(v1, v2)
    s = np.sqrt(vmin) / np.sqrt(vmax)  # V^(-1/2), as in the quadrature
    rsq = (vmax - vmin) / vmax  # 1 - 1/V
    rho = np.zeros(pf.size)
    L1 = -np.log1p(-pf)  # -ln(1 - p)
    lo = np.maximum(np.sqrt(2.0 * L1), np.sqrt(2.0 * pf / s))
    with np.errstate(invalid="ignore", divide="ignore"):
        hi2 = np.where(pf / s < 1.0, np.sqrt(-2.0 * np.log1p(-pf / s)), np.inf)
    hi = np.minimum(np.sqrt(2.0 * L1) / s, hi2)
    iso = (rsq == 0.0) | (pf == 0.0)
    rho[iso] = np.sqrt(2.0 * L1[iso])
    act = np.flatnonzero(~iso)
    if act.size:
        lo, hi = np.minimum(lo[act], hi[act]), np.maximum(lo[act], hi[act])
        # Start from Patnaik's two-moment approximation t1^2 + V t2^2 ~ c chi2(nu),
        # c = (1 + V^2)/(1 + V), nu = (1 + V)^2/(1 + V^2) (a few % off), kept in the bracket.
        Va = 1.0 / (s[act] * s[act])
        nu = (1.0 + Va) ** 2 / (1.0 + Va * Va)
        guess = np.sqrt((1.0 + Va * Va) / (1.0 + Va) * special.gammaincinv(0.5 * nu, pf[act]) * 2.0)
        cur = np.where((guess > lo) & (guess < hi), guess, np.sqrt(lo * hi))
        pt, sa, ra = pf[act], s[act], rsq[act]
        for _ in range(200):
            x = cur * cur
            P = _exact_flat(x, sa, threads)
            dP = cur * sa * np.exp(-0.5 * x * sa * sa) * special.i0e(0.25 * x * ra)
            f = P - pt
            below = f < 0
            lo = np.where(below, np.maximum(lo, cur), lo)
            hi = np.where(below, hi, np.minimum(hi, cur))
            with np.errstate(divide="ignore", invalid="ignore"):
                new = cur - f / dP
            bad = ~((new > lo) & (new < hi))
            new = np.where(bad, 0.5 * (lo + hi), new)
            done = (np.abs(new - cur) <= 1e-13 * cur) & ~bad
            exact_hit = np.abs(f) <= 4 * np.finfo(float).eps * pt
            collapsed = hi - lo <= 4 * np.finfo(float).eps * hi
            fin = done | exact_hit | collapsed
            res = np.where(done, new, cur)
            rho[act[fin]] = res[fin]
            keep = ~fin
            if not keep.any():
                break
            act, cur, lo, hi = act[keep], new[keep], lo[keep], hi[keep]
            pt, sa, ra = pt[keep], sa[keep], ra[keep]
        else:  # pragma: no cover - the bracket halves at worst every other step
            raise BananagridError("containment_radius: Newton iteration did not converge")
    return _shaped(rho * np.sqrt(vmin), shape)
