r"""Validation table for Walsh's linearised two-bearing fix: where does it hold?

Walsh (1968) replaces the fix (X, Y) by its first-order expansion in the bearing errors
:math:`\ell_1, \ell_2` (his assumptions 7 and 8: a good crossing and sigma <= ~0.03 rad), so the
fix error is normal with covariance :math:`\Sigma = J\,\mathrm{diag}(\sigma_1^2, \sigma_2^2)\,J^T`
(ERRATA) and the containment probability is

.. math::  P(R) = P(v_1 t_1^2 + v_2 t_2^2 \le R^2),

:math:`v_1, v_2` the eigenvalues of :math:`\Sigma`.  This module measures, by Monte Carlo of the
exact (nonlinear) crossing, how often the true contact actually lies within the linearised
R50 and R95 of the fix, over a grid of crossing angles gamma and bearing errors sigma.

Standard geometry.  Stations at :math:`S_1 = (0, 0)` and :math:`S_2 = (D, 0)`; the contact
:math:`T = (D/2,\ h)` on the perpendicular bisector with

.. math::  h = \frac{D/2}{\tan(\gamma/2)},

so that the two true bearings :math:`b_1 = \operatorname{atan2}(D/2, h)`,
:math:`b_2 = -b_1` differ by exactly :math:`b_1 - b_2 = 2\arctan\frac{D/2}{h} = \gamma`: the
bearing lines cross at T at angle gamma.  Both sigmas are equal.

Exact crossing.  With :math:`u_i = (\sin(b_i + \ell_i), \cos(b_i + \ell_i))`,
:math:`d = S_2 - S_1` and :math:`a \times b = a_x b_y - a_y b_x`, the lines
:math:`S_1 + s_1 u_1` and :math:`S_2 + s_2 u_2` meet at

.. math::  s_1 = \frac{d \times u_2}{u_1 \times u_2},\qquad
           s_2 = \frac{d \times u_1}{u_1 \times u_2},\qquad F = S_1 + s_1 u_1 .

A draw is discarded (and counted) when :math:`u_1 \times u_2 = 0` or the result is not finite
(parallel lines: no crossing), or when :math:`s_1 \le 0` or :math:`s_2 \le 0` (the lines cross
behind a station: no fix, as :class:`~bananagrid.BearingFix` refuses).  The empirical
containment is conditional on a fix existing: :math:`\hat p = \#\{|F - T| \le R\} / n_{kept}`.

Statistics and verdict.  For nominal :math:`p_0 \in \{0.5, 0.95\}` the table gives
:math:`\hat p`, its binomial standard error :math:`\sqrt{\hat p(1 - \hat p)/n_{kept}}` and the
deviation :math:`z = (\hat p - p_0)/\sqrt{p_0(1 - p_0)/n_{kept}}` in standard errors under the
null hypothesis "the linearisation is right".  A cell **holds** when, for both p0,

.. math::  |\hat p - p_0| \le \max\big(3\sqrt{p_0(1 - p_0)/n_{kept}},\ 0.005\big),

else it **fails**.  Why this rule: the 3-SE term is a statistical test (under the null each
value falls outside it with probability 0.27 %, so a correct cell fails with probability at
most 0.54 % by the union bound); the 0.005 floor is a practical tolerance, because with
n = 200,000 the standard errors (0.0011 at 0.5, 0.0005 at 0.95) would otherwise flag
second-order effects of no practical consequence: an error of half a percentage point in a
containment probability is below what an operator reading R50 or R95 could act on.  At the
default n the floor decides (3 SE < 0.005 for both p0); for n below ~90,000 the 3-SE term
decides at 0.5, below ~17,000 at 0.95.

The same standard normal draws (``seed``) are reused in every cell (common random numbers):
each cell depends only on (gamma, sigma, n, baseline, seed), not on which other cells are in
the table, and neighbouring cells differ by geometry, not by sampling noise.
"""

from __future__ import annotations

import math
import warnings
from numbers import Integral, Real

import numpy as np

from ..models.bearing import MIN_CROSSING_DEG, BearingFix, bearing_to, crossings
from ..validate import BananagridError

__all__ = ["validation_table", "format_table", "summary", "standard_geometry", "crossings", "verdict"]

#: Nominal probabilities of the two radii checked (R50, R95).
PROBABILITIES = (0.5, 0.95)

#: Verdict rule: |p_hat - p0| <= max(Z_LIMIT * SE0, ABS_FLOOR).
Z_LIMIT = 3.0
ABS_FLOOR = 0.005

DEFAULT_GAMMAS_DEG = (20.0, 40.0, 60.0, 90.0, 120.0, 140.0, 160.0)
DEFAULT_SIGMAS = (0.005, 0.01, 0.02, 0.03, 0.05)
MIN_N = 1000


# --------------------------------------------------------------------------------------------
# Arguments
# --------------------------------------------------------------------------------------------


def _reals(name: str, values) -> list[float]:
    try:
        items = list(values)
    except TypeError:
        raise BananagridError(f"{name} = {values!r}: expected a sequence of numbers") from None
    if not items:
        raise BananagridError(f"{name} = {values!r}: must not be empty")
    out = []
    for i, v in enumerate(items):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, Real):
            raise BananagridError(f"{name}[{i}] = {v!r}: expected a real number")
        out.append(float(v))
    return out


def _gammas(values) -> list[float]:
    gammas = _reals("gammas_deg", values)
    for i, g in enumerate(gammas):
        if not (math.isfinite(g) and 0.0 < g < 180.0):
            raise BananagridError(f"gammas_deg[{i}] = {g!r}: must be in (0, 180) deg, exclusive")
        # BearingFix refuses lines crossing at under MIN_CROSSING_DEG (either side of 90 deg):
        # say so now rather than after part of the table has run.
        if not (MIN_CROSSING_DEG <= g <= 180.0 - MIN_CROSSING_DEG):
            raise BananagridError(
                f"gammas_deg[{i}] = {g!r}: must be in [{MIN_CROSSING_DEG:g}, "
                f"{180.0 - MIN_CROSSING_DEG:g}] deg: BearingFix refuses nearly parallel lines"
            )
    return gammas


def _sigmas(values) -> list[float]:
    sigmas = _reals("sigmas", values)
    for i, s in enumerate(sigmas):
        if not (math.isfinite(s) and s > 0.0):
            raise BananagridError(f"sigmas[{i}] = {s!r}: must be finite and > 0 (radians)")
    return sigmas


def _integer(name: str, value, minimum: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Integral):
        raise BananagridError(f"{name} = {value!r}: expected an integer >= {minimum}")
    if value < minimum:
        raise BananagridError(f"{name} = {value!r}: must be an integer >= {minimum}")
    return int(value)


def _baseline(value) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise BananagridError(f"baseline = {value!r}: expected a real number (metres)")
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise BananagridError(f"baseline = {v!r}: must be finite and > 0 (metres)")
    return v


# --------------------------------------------------------------------------------------------
# Geometry and Monte Carlo
# --------------------------------------------------------------------------------------------


def standard_geometry(gamma_deg: float, baseline: float = 20_000.0):
    r"""Stations and true contact whose bearing lines cross at ``gamma_deg``.

    .. math::  S_1 = (0, 0),\quad S_2 = (D, 0),\quad T = \Big(\frac D2,\ \frac{D/2}{\tan(\gamma/2)}\Big).

    Returns
    -------
    sensors : ndarray, shape (2, 2)
    target : ndarray, shape (2,)
    bearings : ndarray, shape (2,)
        True bearings from each station to T (radians clockwise from north);
        ``bearings[0] - bearings[1] == gamma``.
    """
    half = 0.5 * baseline
    sensors = np.array([[0.0, 0.0], [baseline, 0.0]])
    target = np.array([half, half / math.tan(0.5 * math.radians(gamma_deg))])
    return sensors, target, bearing_to(sensors, target)


def _linearised_radii(sensors, bearings, sigma):
    """R50, R95 of Walsh's linearised law, linearised at the true bearings."""
    with warnings.catch_warnings():
        # under 20 deg BearingFix warns that the linearisation is optimistic: this table is
        # the measurement of exactly that, so the warning adds nothing here.
        warnings.filterwarnings("ignore", message="bearings cross at", category=UserWarning)
        fix = BearingFix(sensors, bearings, [sigma, sigma])
    return np.asarray(fix.radius(list(PROBABILITIES)), dtype=float)


def _monte_carlo(sensors, target, bearings, sigma, z, radii):
    """Re-triangulate ``bearings + sigma z`` exactly; return (number within each radius,
    number kept, number discarded)."""
    fx, fy, kept = crossings(sensors, bearings[0] + sigma * z[:, 0], bearings[1] + sigma * z[:, 1])
    ex = fx[kept] - target[0]
    ey = fy[kept] - target[1]
    dist2 = ex * ex + ey * ey
    inside = [int(np.count_nonzero(dist2 <= r * r)) for r in radii]
    n_kept = int(np.count_nonzero(kept))
    return inside, n_kept, z.shape[0] - n_kept


def verdict(p_hat: float, p0: float, n: int) -> bool:
    r"""True when :math:`|\hat p - p_0| \le \max(3\sqrt{p_0(1 - p_0)/n},\ 0.005)`."""
    return abs(p_hat - p0) <= max(Z_LIMIT * math.sqrt(p0 * (1.0 - p0) / n), ABS_FLOOR)


def validation_table(
    gammas_deg=DEFAULT_GAMMAS_DEG,
    sigmas=DEFAULT_SIGMAS,
    n: int = 200_000,
    baseline: float = 20_000.0,
    seed: int = 0,
) -> list[dict]:
    r"""Empirical containment of Walsh's linearised R50 / R95 under the exact geometry.

    For each (gamma, sigma), in the order gammas outer, sigmas inner: build
    :func:`standard_geometry`, compute R50, R95 from ``BearingFix(sensors, true bearings,
    (sigma, sigma)).radius([0.5, 0.95])`` (Walsh: linearised at the true bearings), draw
    :math:`\ell_i = \sigma z_i`, re-triangulate exactly, and count the fixes within R of the
    true contact (module docstring for the formulas, the discard rule and the verdict).

    Parameters
    ----------
    gammas_deg : sequence of float
        Crossing angles, degrees, in (0, 180) exclusive; BearingFix further needs
        [2, 178] (``MIN_CROSSING_DEG``).
    sigmas : sequence of float
        Bearing-error standard deviations (both stations), radians, finite and > 0.
    n : int
        Draws per cell, integer >= 1000.
    baseline : float
        Distance D between the stations, metres, finite and > 0.
    seed : int
        Seed of the standard normal draws (shared by every cell), integer >= 0.

    Returns
    -------
    list of dict
        One record per cell with keys ``gamma_deg``, ``sigma``, ``r50_m``, ``r95_m``,
        ``p50``, ``se50``, ``z50``, ``p95``, ``se95``, ``z95`` (empirical containment, its
        binomial standard error, deviation in null standard errors), ``discarded`` (fraction
        of draws without a fix) and ``verdict`` (``"holds"`` or ``"fails"``). Values are plain
        Python floats and strings.
    """
    gammas = _gammas(gammas_deg)
    sigma_list = _sigmas(sigmas)
    n = _integer("n", n, MIN_N)
    baseline = _baseline(baseline)
    seed = _integer("seed", seed, 0)

    z = np.random.default_rng(seed).standard_normal((n, 2))
    records = []
    for gamma in gammas:
        sensors, target, bearings = standard_geometry(gamma, baseline)
        for sigma in sigma_list:
            radii = _linearised_radii(sensors, bearings, sigma)
            inside, n_kept, n_bad = _monte_carlo(sensors, target, bearings, sigma, z, radii)
            rec = {"gamma_deg": float(gamma), "sigma": float(sigma),
                   "r50_m": float(radii[0]), "r95_m": float(radii[1])}
            ok = n_kept > 0
            for key, p0, k in zip(("50", "95"), PROBABILITIES, inside):
                if n_kept == 0:  # every line pair failed to cross: nothing to measure
                    rec.update({f"p{key}": math.nan, f"se{key}": math.nan, f"z{key}": math.nan})
                    continue
                p_hat = k / n_kept
                rec[f"p{key}"] = float(p_hat)
                rec[f"se{key}"] = math.sqrt(p_hat * (1.0 - p_hat) / n_kept)
                rec[f"z{key}"] = (p_hat - p0) / math.sqrt(p0 * (1.0 - p0) / n_kept)
                ok = ok and verdict(p_hat, p0, n_kept)
            rec["discarded"] = n_bad / n
            rec["verdict"] = "holds" if ok else "fails"
            records.append(rec)
    return records


# --------------------------------------------------------------------------------------------
# Reporting
# --------------------------------------------------------------------------------------------

_COLUMNS = (
    # header, width, format of the value
    ("gamma", 6, "{gamma_deg:6.1f}"),
    ("sigma", 6, "{sigma:6.3f}"),
    ("R50 m", 9, "{r50_m:9.1f}"),
    ("R95 m", 9, "{r95_m:9.1f}"),
    ("P(R50)", 7, "{p50:7.4f}"),
    ("se", 6, "{se50:6.4f}"),
    ("z50", 7, "{z50:+7.1f}"),
    ("P(R95)", 7, "{p95:7.4f}"),
    ("se", 6, "{se95:6.4f}"),
    ("z95", 7, "{z95:+7.1f}"),
    ("discard", 8, "{discarded:8.2e}"),
    ("verdict", 7, "{verdict:>7}"),
)


def format_table(records) -> str:
    """Fixed-width text table: a header line, a rule, then one line per record.

    Columns: gamma (deg), sigma (rad), linearised R50 and R95 (m), empirical containment at
    each with its binomial standard error and deviation z in standard errors, the discarded
    fraction and the verdict.
    """
    header = " ".join(f"{h:>{w}}" for h, w, _ in _COLUMNS)
    lines = [header, "-" * len(header)]
    for rec in records:
        lines.append(" ".join(fmt.format(**rec) for _, _, fmt in _COLUMNS))
    return "\n".join(lines)


def _cells(records) -> str:
    return ", ".join(f"{r['gamma_deg']:g} deg / {r['sigma']:g} rad" for r in records)


def summary(records) -> str:
    """One paragraph: in how many cells the linearisation holds, per sigma the crossing angles
    where it holds, the failing cells and the worst one, and the largest discarded fraction."""
    records = list(records)
    if not records:
        return "No cells."
    held = [r for r in records if r["verdict"] == "holds"]
    failed = [r for r in records if r["verdict"] != "holds"]
    parts = [
        f"Walsh's linearised R50/R95 hold (both empirical containments within "
        f"max({Z_LIMIT:g} SE, {ABS_FLOOR:g}) of 0.5 and 0.95) in {len(held)} of {len(records)} cells."
    ]
    per_sigma = []
    for sigma in dict.fromkeys(r["sigma"] for r in records):
        ok = [f"{r['gamma_deg']:g}" for r in records if r["sigma"] == sigma and r["verdict"] == "holds"]
        per_sigma.append(f"sigma {sigma:g} rad: {', '.join(ok) if ok else 'none'}")
    parts.append("Crossing angles (deg) where it holds, by sigma: " + "; ".join(per_sigma) + ".")
    if failed:
        def worst_dev(r):
            return max(abs(r["p50"] - 0.5), abs(r["p95"] - 0.95)) if r["p50"] == r["p50"] else math.inf

        worst = max(failed, key=worst_dev)
        parts.append(
            f"It fails at {_cells(failed)}; worst at gamma {worst['gamma_deg']:g} deg, sigma "
            f"{worst['sigma']:g} rad, where the contact is within R50 {worst['p50']:.4f} and within "
            f"R95 {worst['p95']:.4f} of the time (z = {worst['z50']:+.1f}, {worst['z95']:+.1f})."
        )
    else:
        parts.append("It fails nowhere in the table.")
    top = max(records, key=lambda r: r["discarded"])
    parts.append(
        f"At most {top['discarded']:.2e} of the draws had no fix (lines parallel or crossing "
        f"behind a station; gamma {top['gamma_deg']:g} deg, sigma {top['sigma']:g} rad)."
    )
    return " ".join(parts)
