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
    (see :func:`containment_exact`).

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

from .validate import BananagridError

__all__ = [
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

#: Poisson mean y = x/2 above which the series starts its Poisson recursion near the lower
#: tail of Poisson(y) instead of at exp(-y) (which underflows past y = 708).
_Y_SKIP = 600.0

#: Elements x nodes per block of the quadrature (a few 512 KiB temporaries: cache sized).
_BLOCK = 1 << 16

#: Elements per block of the series recursion.
_SERIES_BLOCK = 1 << 14


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
    s = np.sqrt(ratio)
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
    """exp(-y) y^k / k! for k >= 380, |k - y| < 0.4 y, to ~1e-15 relative (Loader 2000:
    log pmf = -stirlerr(k) - bd0(k, y) - log(2 pi k)/2, bd0 by its series in v = (k-y)/(k+y))."""
    kk = k * k
    stirlerr = (1 / 12 - (1 / 360 - (1 / 1260 - 1 / (1680 * kk)) / kk) / kk) / k
    v = (k - y) / (k + y)
    bd0 = (k - y) * v
    ej = 2.0 * k * v
    v2 = v * v
    for j in range(1, 25):  # |v| < 0.25 -> v^48 < 1e-28
        ej = ej * v2
        bd0 = bd0 + ej / (2 * j + 1)
    return np.exp(-stirlerr - bd0) / np.sqrt(2.0 * math.pi * k)


class _SeriesFailed(Exception):
    def __init__(self, index: np.ndarray, gap: np.ndarray):
        self.index, self.gap = index, gap


def _series_block(x, s, r, ratio, tol, max_terms, W_fixed):
    """Bounds (L_W, U_W) and W for flat arrays; W adaptive (smallest with U - L <= tol) or
    W_fixed.  State at index w: H = H_w, T = 1 - sum_{j<=w} H_j, C = C_{2w+2}(x),
    p = exp(-y) y^w / w! (y = x/2), L = sum_{j<=w} H_j C_{2j+2}(x).  The step uses
    p_{w+1} = p_w y/(w+1), C_{2w+4} = C_{2w+2} - p_{w+1} (the even-dof chi-square CDF is a
    Poisson upper tail: C_{2w+2}(x) = 1 - exp(-y) sum_{j<=w} y^j/j!),
    H_{w+1} = H_w (w + 1/2)/(w + 1) (1 - 1/V)."""
    n = x.size
    lower = np.empty(n)
    upper = np.empty(n)
    Wout = np.empty(n, dtype=np.int64)
    y = 0.5 * x
    # Where exp(-y) would underflow and the series must run past the bulk of Poisson(y), start
    # at w0 = ceil(y - 9 sqrt(y)): P(Poisson(y) < w0) < exp(-81/2) = 2.6e-18, so every
    # C_{2w+2}(x) with w < w0 is 1 to that accuracy and sum_{w<w0} H_w C_{2w+2} = 1 - T_{w0-1}.
    skip = y > _Y_SKIP
    w0 = np.zeros(n)
    if skip.any():
        w0[skip] = np.ceil(y[skip] - 9.0 * np.sqrt(y[skip]))
        if W_fixed is None:
            # the gap at w < w0 is T_w C_{2w+4} >= T_{w0-1}(1 - 3e-18): skip only past W's
            # that cannot stop; T_{w0-1} = P(NegBin(1/2, 1/V) >= w0) = I_{1-1/V}(w0, 1/2).
            skip[skip] = special.betainc(w0[skip], 0.5, r[skip]) > tol
        else:
            skip &= w0 <= W_fixed
    failed = []
    for sel, start in ((~skip, None), (skip, w0)):
        idx = np.flatnonzero(sel)
        if idx.size == 0:
            continue
        ys, rs = y[idx], r[idx]
        if start is None:
            w = 0
            H = s[idx].copy()
            T = rs / (1.0 + H)  # 1 - V^(-1/2) without cancellation
            p = np.exp(-ys)
            C = -np.expm1(-ys)
            L = H * C
        else:
            w = start[idx]
            H = stats.nbinom.pmf(w, 0.5, ratio[idx])
            T = special.betainc(w + 1.0, 0.5, rs)
            p = _poisson_pmf(w, ys)
            C = special.gammainc(w + 1.0, ys)
            L = special.betainc(0.5, w, ratio[idx]) + H * C
        pos = idx
        Cref, Tref = C.copy(), T.copy()
        while True:
            pn = p * ys
            pn *= 1.0 / (w + 1.0)
            Cn = C - pn
            # C and T are tails computed by subtraction: their absolute error grows by about
            # eps per step, which would stall the gap T C_{2W+4} near 1e-13 after thousands of
            # steps.  Each time one has fallen 16-fold since its last exact value, take it
            # afresh from the regularised incomplete gamma / beta function (a few times per
            # element): the relative error stays below 16 eps per step since then.
            low = Cn < Cref * (1 / 16)
            if low.any():
                wl = w if np.ndim(w) == 0 else w[low]
                Cn[low] = special.gammainc(wl + 2.0, ys[low])
                Cref[low] = Cn[low]
            np.maximum(Cn, 0.0, out=Cn)
            gap = T * Cn
            if W_fixed is None:
                done = gap <= tol
                last = np.asarray(w) >= max_terms - 1
            else:
                done = np.broadcast_to(np.asarray(w) >= W_fixed, gap.shape)
                last = False
            if done.any() or np.any(last):
                d = np.flatnonzero(done)
                lower[pos[d]] = L[d]
                upper[pos[d]] = L[d] + gap[d]
                Wout[pos[d]] = w if np.ndim(w) == 0 else w[d]
                if np.any(last):
                    bad = np.flatnonzero(~done & last)
                    if bad.size:
                        failed.append((pos[bad], gap[bad]))
                    keep = np.flatnonzero(~done & ~last)
                else:
                    keep = np.flatnonzero(~done)
                if keep.size == 0:
                    break
                pos, ys, rs, Cref, Tref = pos[keep], ys[keep], rs[keep], Cref[keep], Tref[keep]
                H, T, C, L, p, Cn, pn = H[keep], T[keep], C[keep], L[keep], p[keep], Cn[keep], pn[keep]
                if np.ndim(w):
                    w = w[keep]
            # advance to w + 1
            H *= rs
            H *= (w + 0.5) / (w + 1.0)
            T -= H
            low = T < Tref * (1 / 16)
            if low.any():  # T_{w+1} = P(NegBin(1/2, 1/V) > w + 1) = I_{1-1/V}(w + 2, 1/2)
                wl = w if np.ndim(w) == 0 else w[low]
                T[low] = special.betainc(wl + 2.0, 0.5, rs[low])
                Tref[low] = T[low]
            np.maximum(T, 0.0, out=T)
            L += H * Cn
            C, p = Cn, pn
            w = w + 1
    if failed:
        raise _SeriesFailed(np.concatenate([f[0] for f in failed]), np.concatenate([f[1] for f in failed]))
    return lower, upper, Wout


def _series_flat(R, v1, v2, tol, max_terms, W_fixed, threads):
    x, s, r, ratio = _reduced(R, v1, v2)
    n = x.size
    lower, upper = np.empty(n), np.empty(n)
    W = np.empty(n, dtype=np.int64)
    failures = []

    def task(a, b):
        def run():
            try:
                lo, up, w = _series_block(x[a:b], s[a:b], r[a:b], ratio[a:b], tol, max_terms, W_fixed)
            except _SeriesFailed as exc:
                failures.append((exc.index + a, exc.gap))
                return
            lower[a:b], upper[a:b], W[a:b] = lo, up, w

        return run

    _run([task(a, min(a + _SERIES_BLOCK, n)) for a in range(0, n, _SERIES_BLOCK)], threads)
    if failures:
        index = np.sort(np.concatenate([f[0] for f in failures]))
        i = int(index[0])
        V = max(v1[i], v2[i]) / min(v1[i], v2[i])
        raise BananagridError(
            f"max_terms = {max_terms}: the Robbins-Pitman series did not reach tol = {tol!r} "
            f"for {index.size} of {n} geometries (first: R = {float(R[i])!r}, "
            f"v1 = {float(v1[i])!r}, v2 = {float(v2[i])!r}, V = {V:.6g}, R^2/v = {x[i]:.6g}); "
            f"it needs about "
            f"min(V ln(1/tol), R^2/(2v) + 6 sqrt(R^2/v)) terms: raise max_terms or tol, "
            f"or use method='exact'"
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
    special-function call.  Where :math:`e^{-x/2}` underflows (x/2 > 600) and the series has to
    run past the bulk of Poisson(x/2), the recursion starts at
    :math:`w_0 = \lceil x/2 - 9\sqrt{x/2} \rceil` from accurate values (regularised incomplete
    gamma and beta functions, negative-binomial pmf, Loader's Poisson pmf).

    Cost.  The gap :math:`U_W - L_W \le \min(1 - \sum_{w \le W} H_w,\ C_{2W+4}(x))`; the first
    factor decays like :math:`(1 - 1/V)^W` and the second once W passes the Poisson bulk
    x/2.  So about :math:`\min(V \ln(1/{\rm tol}),\ x/2 + 6\sqrt{x})` terms are needed: few
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
        Absolute width of the bounds at which to stop, in (0, 0.1].  Below about 1e-14 the
        rounding of the running sums may keep it from being reached.
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
    (:math:`\max((1 - e^{-x/2})/\sqrt V,\ 1 - e^{-x/(2V)})`) with at least 2.5 % to spare;
    ``tests/test_containment.py`` re-checks this and checks N against 2N nodes.
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
    if cancel_free:  # P >= 1/4: 1 - exp(-w) to eps absolute is eps/P <= 4 eps relative
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
    V = 1.0 / (s * s)
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
            f"{int(N[i])} nodes (> {EXACT_MAX_NODES}); the geometry is too elongated"
        )
    # Round N up to a ladder (4.4 % steps above 32) so that few groups share a node set.
    big = N > 32
    N[big] = np.ceil(32.0 * np.exp2(np.ceil(16.0 * np.log2(N[big] / 32.0)) / 16.0))
    plb = np.maximum(-np.expm1(-0.5 * xr) * sr, -np.expm1(-qr))
    key = N.astype(np.int64) * 2 + (plb >= 0.25)
    order = np.argsort(key, kind="stable")
    keys, starts = np.unique(key[order], return_index=True)
    bounds = list(starts) + [rest.size]
    zr = xr * (0.25 * (1.0 - sr * sr))
    pref = 0.5 * xr * sr
    tasks = []
    for k, a, b in zip(keys, bounds[:-1], bounds[1:]):
        Nk, cancel_free = int(k) // 2, bool(k % 2)
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
    s = np.sqrt(vmin / vmax)
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
        cur = np.sqrt(lo * hi)
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
