"""Butterly's model: a bivariate normal start, a random course and a speed law (Butterly 1975).

The target starts at X ~ N(mean, cov), picks a course c (a bearing clockwise from north, the
project's heading convention: unit vector e(c) = (sin c, cos c)) and a speed V independently,
and after t seconds is at U = X + V t e(c). Its density is (2.3), and with a discrete speed law
(2.5) with (3.1):

    p(u) = sum_i w_i P_i(u),   P_i(u) = int_0^{2 pi} N(u - r_i e(c); mean, cov) p(c) dc,   r_i = V_i t,

with p(c) = 1 / (2 pi) (Butterly's uniform course) or, beyond the paper, the von Mises law
exp(kappa cos(c - c0)) / (2 pi I0(kappa)) around a mean course c0 (kappa = 0 is Butterly).
Continuous speed laws (:class:`UniformSpeed`, :class:`NormalSpeed`, :class:`TabulatedSpeed`)
are integrated by a composite Gauss-Legendre rule whose nodes become the discrete speeds of (2.5)
(see :data:`SPEED_PANEL_SIGMAS`). The phi-integral is computed by the Warp kernel
``kernels/butterly.py`` (method in its docstring); :mod:`bananagrid.models._butterly_series`
holds the Bessel series (3.8) as a second method.

Evidence at earlier times is carried exactly through the paths: for the course c and speed V_i
the path through the map point x is at x - V_i (t - s) e(c) at time s, so the evidence is a
weight inside the course integral (:meth:`Butterly.bind_carried`, the engine's carried hook;
cell probabilities by :meth:`Butterly.carried_cell_plan`), and :meth:`Butterly.sample_paths`
draws whole paths of the generative story for Monte Carlo.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np
from scipy import special, stats

from ..domains.pose import Pose
from ..kernels import butterly as kernels
from ..kernels import evidence as evidence_kernels
from ..domains.grid import Grid
from ..domains.polar_lattice import PolarLattice
from ..engine.carried import evaluate_carried
from ..engine.rasterise import rasterise
from ..engine.quadrature import GAUSS_TOL, MAX_ORDER, gauss_error, unit_rule
from ..protocol import CellPlan, EvidencePack, Extent, KernelBinding, KernelContext, SceneKey, SceneSchema
from ..validate import BananagridError, BananagridWarning, covariance, finite, non_negative, point, positive, real_array, show
from ._butterly_series import series_density
from .base import RANGE_SDS, Model, check_n, check_rng
from .params import modelclass, param

__all__ = [
    "Butterly",
    "UniformSpeed",
    "NormalSpeed",
    "TabulatedSpeed",
    "covariance_axes",
    "SPEED_LAWS",
    "SPEED_PANEL_SIGMAS",
    "GAUSS_POINTS",
    "KERNEL_TOL",
    "CELL_FLOOR",
    "SPEED_FLOOR",
]

#: Continuous speed laws: width of a Gauss-Legendre panel in travelled range r = V t, in units
#: of the start's smallest SD sqrt(S1). P_r(u) varies with r on that scale (the ring's
#: profile), so the error of GAUSS_POINTS nodes per panel is fixed by this ratio: below 1e-11
#: relative against a rule 4x finer (measured 5e-12, the kernel's own rounding level) wherever
#: the density exceeds 1e-12 of its peak (tests/models/test_butterly.py, test_continuous_speed_*).
SPEED_PANEL_SIGMAS = 1.0
#: Gauss-Legendre nodes per panel.
GAUSS_POINTS = 8
#: A truncated normal speed law is integrated over mean +- NORMAL_SPAN sd (clipped at 0): the
#: mass beyond, erfc(10 / sqrt 2) = 1.5e-23, is far below the quadrature's own error.
NORMAL_SPAN = 10.0
#: More speed nodes than this warn: each costs a full course integral per cell.
MANY_SPEED_NODES = 2048
#: Hard limit on speed nodes.
MAX_SPEED_NODES = 200_000

#: Rasterising a grid, a cell is set to 0 where the kernel proves the density is below
#: CELL_FLOOR times its maximum (10x below the 1e-12 under which relative accuracy is not
#: promised), and a speed is left out of a cell's sum where its own bound is below SPEED_FLOOR
#: times the maximum over the number of speeds: together at most 1e-22 of the maximum, a
#: relative 1e-10 wherever the density exceeds 1e-12 of its maximum.
CELL_FLOOR = 1e-13
SPEED_FLOOR = 1e-22

#: Work estimate per cell, one core, float64 (:meth:`Butterly.work_estimate`): a cell's
#: share of the tile, plus a course integral per speed node. Measured on the reference machine
#: (AMD Zen 4): 0.15-0.45 us per cell for three speeds over whole rings (r / sigma_min 1 to
#: 1e6), up to 2.3 us on cells all within 6 sigma of a thin ring (r / sigma_min 1e3-1e5); 21 ns
#: per speed node with 624 nodes (a normal speed law: the tiles drop the negligible ones).
SECONDS_PER_CELL = 0.5e-6
SECONDS_PER_SPEED_NODE = 0.1e-6

#: Carried maps (:meth:`Butterly.bind_carried`): the course pieces' Gauss-Legendre panels, in
#: trapezoid spacings of the density's rule (0.81 of the integrand's narrowest width each), and
#: the narrowest panel smooth factors may ask for, as a fraction of one.
CARRIED_PANEL = 2.0
#: The reference rule: CARRIED_GAUSS_NODES-point Gauss-Legendre on CARRIED_PANEL spacings
#: (relative error below 1e-13 per panel for a normal profile); every order's panels are sized
#: to the same error bound (``_carried_rule``).
CARRIED_GAUSS_NODES = 8
CARRIED_NARROWEST = 1.0 / 16.0
#: A smooth factor's course spacing, as a fraction of its angular scale (its length scale over
#: the radius V (t - s)): the fraction the density's own spacing is of its narrowest width
#: (2 pi / sqrt(2 L), L = ln(1e12) + ln(4 pi): 0.81).
SMOOTH_SPACING = 0.8


#: Carried cell probabilities: points per evaluation (bounds the node arrays' memory), and the
#: work estimate per node and speed (measured: 2-60 us per point for three speeds on the
#: submarine case, Intel Xeon, float64, one core; the upper end near the searches' edges).
CELL_CHUNK = 2**18
CARRIED_SECONDS_PER_NODE = 10e-6


def _interval_searches(pack: EvidencePack) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pack's area searches over intervals, to be taken exactly: a Butterly path is straight,
    so the time it spends in the polygon over (t0, t1) is the length of its segment inside over
    its speed (no time rule). A factor qualifies when its nodes are all one polygon's with one
    rate and are exactly a composite Gauss-Legendre rule over some (t0, t1) (P equal panels of n
    nodes, the pack's rule for an interval: (t0, t1) recovered from the weights' sum and the
    first node for each n that divides the count, and every node checked); others keep their
    nodes.

    Returns (segments (S, 8): t0, t1, rate, orientation, the polygon's box x0, x1, y0, y1;
    ints (S, 3): factor, first edge, edge count; a mask of the pack's nodes they replace)."""
    kind, factor = pack.ints[:, 0], pack.ints[:, 1]
    rows, ints = [], []
    exact = np.zeros(pack.nodes, dtype=bool)
    for f in range(pack.factors):
        nodes = np.flatnonzero(factor == f)
        if nodes.size < 2 or np.any(kind[nodes] != evidence_kernels.KIND_POLYGON):
            continue
        first, count = int(pack.ints[nodes[0], 2]), int(pack.ints[nodes[0], 3])
        if np.any(pack.ints[nodes, 2] != first) or np.any(pack.data[nodes, 0] != pack.data[nodes[0], 0]):
            continue
        span = float(np.sum(pack.q[nodes]))
        times = np.sort(pack.time[nodes])
        found = None
        for n in range(1, 17):
            if nodes.size % n:
                continue
            panels = nodes.size // n
            x, _ = np.polynomial.legendre.leggauss(n)
            t0 = float(times[0]) - 0.5 * span / panels * (1.0 + x[0])
            edges = np.linspace(t0, t0 + span, panels + 1)
            expected = np.sort((0.5 * (edges[1:] + edges[:-1])[:, None] + 0.5 * np.diff(edges)[:, None] * x).ravel())
            if span > 0.0 and np.allclose(times, expected, rtol=0.0, atol=1e-9 * span):
                found = t0
                break
        if found is None:
            continue
        e = pack.edges[first:first + count]
        orient = 1.0 if np.sum(e[:, 0] * e[:, 3] - e[:, 2] * e[:, 1]) > 0.0 else -1.0
        rows.append((found, found + span, float(pack.data[nodes[0], 0]), orient, *pack.data[nodes[0], 1:5]))
        ints.append((f, first, count))
        exact[nodes] = True
    if not rows:
        return np.zeros((0, 8)), np.zeros((0, 3), dtype=np.int32), exact
    return np.asarray(rows, dtype=float), np.asarray(ints, dtype=np.int32), exact


def _evidence_boxes(pack: EvidencePack, segments: np.ndarray, segment_ints: np.ndarray):
    """Where and when each factor of the pack can weigh a path: a list of (s0, s1, x0, x1, y0,
    y1), the factor's value 0 (its weight 1) for a path outside the box at every time in
    [s0, s1]; None where a factor is not bounded so (reports, bearings and tracks weigh every
    path). A polygon's box at its nodes' times (an area search over an interval taken exactly:
    its whole (t0, t1)); a raster's extent at its nodes' times."""
    kind, factor = pack.ints[:, 0], pack.ints[:, 1]
    exact = {int(f): k for k, f in enumerate(segment_ints[:, 0])}
    boxes = []
    for f in range(pack.factors):
        nodes = np.flatnonzero(factor == f)
        if f in exact:
            row = segments[exact[f]]
            boxes.append((row[0], row[1], *row[4:8]))
            continue
        if nodes.size == 0:
            continue
        if np.all(kind[nodes] == evidence_kernels.KIND_POLYGON):
            d = pack.data[nodes]
            box = (d[:, 1].min(), d[:, 2].max(), d[:, 3].min(), d[:, 4].max())
        elif np.all(kind[nodes] == evidence_kernels.KIND_RASTER):
            d, nx = pack.data[nodes], pack.ints[nodes, 3]
            box = (d[:, 0].min(), (d[:, 0] + d[:, 2] * nx).max(), d[:, 1].min(), (d[:, 1] + d[:, 3] * d[:, 4]).max())
        else:
            return None
        boxes.append((pack.time[nodes].min(), pack.time[nodes].max(), *box))
    return boxes


@functools.lru_cache(maxsize=4)
def _carried_rule(tol: float) -> np.ndarray:
    """The carried kernels' course rule array (layout in kernels/butterly.py): Gauss-Legendre
    rules of each order, each order's widest panel (in spacings) integrated within the error
    bound of the CARRIED_GAUSS_NODES-point rule on CARRIED_PANEL spacings for a normal profile
    (:func:`~bananagrid.engine.quadrature.gauss_error`), and the smooth factors' spacings. A
    spacing is at most 2 pi / sqrt(2 L) of the integrand's narrowest width (L = ln(1 / tol) +
    ln(4 pi), the density's node count)."""
    k = kernels
    rule = np.zeros(k.RULE_SIZE)
    width = 2.0 * math.pi / math.sqrt(2.0 * (math.log(1.0 / tol) + math.log(4.0 * math.pi)))
    target = gauss_error(CARRIED_GAUSS_NODES, CARRIED_PANEL * width)
    q = np.linspace(1e-3, 4.0 * CARRIED_PANEL * max(k.ORDERS) / CARRIED_GAUSS_NODES, 8000)
    for i, n in enumerate(k.ORDERS):
        x, w = np.polynomial.legendre.leggauss(n)
        rule[k.RULE_AT[n]:k.RULE_AT[n] + 2 * n] = np.concatenate((x, w))
        ok = q[[gauss_error(n, v * width) <= target for v in q]]
        limit = float(ok.max()) if ok.size else 0.0
        if n == CARRIED_GAUSS_NODES:
            limit = CARRIED_PANEL  # the reference rule's own panel
        rule[[k.ORDER_N + i, k.ORDER_AT + i, k.ORDER_LIMIT + i]] = n, k.RULE_AT[n], limit
    rule[[k.NARROWEST, k.SPACING]] = CARRIED_NARROWEST, SMOOTH_SPACING
    rule.setflags(write=False)
    return rule


def _axis_rule(width: float, scale: float, tol: float) -> tuple[int, int, float]:
    """(m, n, error): m equal sub-intervals of at most ``scale`` with the fewest Gauss-Legendre
    nodes n <= MAX_ORDER whose error bound for a normal feature of SD ``scale`` is <= ``tol``."""
    m = max(1, math.ceil(width / scale * (1.0 - 1e-12)))
    q = width / (m * scale)
    for n in range(1, MAX_ORDER + 1):
        err = gauss_error(n, q)
        if err <= tol:
            return m, n, err
    return m, MAX_ORDER, err


#: Relative tolerance of the kernel's trapezoid rule (its node count, see kernels/butterly.py),
#: the relative size below which the walk drops a node, and Newton's tolerance, per precision.
KERNEL_TOL = {np.dtype(np.float64): (1e-12, 1e-15, 1e-8), np.dtype(np.float32): (1e-7, 1e-8, 1e-4)}


def covariance_axes(cov: np.ndarray) -> tuple[float, float, float]:
    """Eigen-decomposition of a 2x2 covariance: (S1, S2, beta) with S1 <= S2 its eigenvalues
    (Butterly's S_u, S_v of (3.7), per ERRATA) and beta the angle from east of S1's eigenvector
    (Butterly's beta of (3.3)). S1 = det / S2 avoids cancellation for elongated covariances,
    and det = sxx syy - sxy^2 is computed exactly (in rationals, then rounded once): in
    float64 its products' roundings are eps sxx syy, a relative eps / (1 - rho^2) of det (1e-8
    at a correlation 1 - 1e-8), which moved the density by as much. The entries are scaled by a
    power of two (exactly) so that det neither under- nor overflows at any scale of units."""
    sxx, sxy, syy = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    exponent = math.frexp(max(abs(sxx), abs(syy), abs(sxy)))[1]
    sxx, sxy, syy = (math.ldexp(v, -exponent) for v in (sxx, sxy, syy))
    half_trace = 0.5 * (sxx + syy)
    root = math.hypot(0.5 * (sxx - syy), sxy)
    s2 = half_trace + root
    s1 = float(Fraction(sxx) * Fraction(syy) - Fraction(sxy) ** 2) / s2
    # the eigenvector of S1: (sxy, s1 - sxx) or (s1 - syy, sxy), whichever is longer
    v1 = (sxy, s1 - sxx)
    v2 = (s1 - syy, sxy)
    vx, vy = v1 if math.hypot(*v1) >= math.hypot(*v2) else v2
    s1, s2 = math.ldexp(s1, exponent), math.ldexp(s2, exponent)
    if vx == 0.0 and vy == 0.0:  # isotropic: any axis
        return s1, s2, 0.0
    return s1, s2, math.atan2(vy, vx)


# ---------------------------------------------------------------------------------------------
# Speed laws
# ---------------------------------------------------------------------------------------------


def _gauss_panels(lo: float, hi: float, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre nodes and weights on [lo, hi] with panels no wider than ``width``."""
    if hi <= lo:
        return np.array([lo]), np.array([0.0])
    n_panels = max(1, math.ceil((hi - lo) / width - 1e-9))
    if n_panels * GAUSS_POINTS > MAX_SPEED_NODES:
        raise BananagridError(
            f"speeds: the speed law spans {(hi - lo):.4g} m of travel, {n_panels} panels of "
            f"{width:.4g} m ({n_panels * GAUSS_POINTS} nodes, limit {MAX_SPEED_NODES}); "
            "narrow the law or use a discrete one"
        )
    x, w = np.polynomial.legendre.leggauss(GAUSS_POINTS)
    edges = np.linspace(lo, hi, n_panels + 1)
    half = 0.5 * np.diff(edges)
    mid = 0.5 * (edges[1:] + edges[:-1])
    return (mid[:, None] + half[:, None] * x).ravel(), (half[:, None] * w).ravel()


@dataclass(frozen=True)
class UniformSpeed:
    """Speed uniform on [v_min, v_max], m/s (0 <= v_min < v_max)."""

    v_min: float
    v_max: float

    def __post_init__(self):
        lo = non_negative("speeds.v_min", self.v_min)
        hi = non_negative("speeds.v_max", self.v_max)
        if hi <= lo:
            raise BananagridError(f"speeds.v_max = {hi!r}: must be > v_min = {lo!r}")
        if not hi < MAX_SPEED:  # the quadrature's panels and the ranges v t stay finite
            raise BananagridError(f"speeds.v_max = {hi!r}: must be below {MAX_SPEED:g} m/s")
        if not hi - lo >= MIN_SPEED_WIDTH:  # its density 1 / (v_max - v_min) stays finite
            raise BananagridError(f"speeds.v_max = {hi!r}: the law's width {hi - lo!r} m/s is below "
                                  f"{MIN_SPEED_WIDTH:g} m/s; give one speed as speeds = [v]")
        object.__setattr__(self, "v_min", lo)
        object.__setattr__(self, "v_max", hi)

    def nodes(self, t: float, panel: float) -> tuple[np.ndarray, np.ndarray]:
        """Speeds and weights of the composite Gauss-Legendre rule (panels <= ``panel`` m of r)."""
        v, w = _gauss_panels(self.v_min, self.v_max, panel / t if t > 0 else math.inf)
        return v, w / (self.v_max - self.v_min)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(self.v_min, self.v_max, n)

    def pdf(self, v) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        return np.where((v >= self.v_min) & (v <= self.v_max), 1.0 / (self.v_max - self.v_min), 0.0)


#: Fastest speed a continuous speed law may reach, m/s: its quadrature panels and the ranges
#: v t stay normal float64 numbers.
MAX_SPEED = 1e100
#: Narrowest continuous speed law, m/s (width of a uniform law or table, SD of a normal one):
#: its density and quadrature weights stay finite.
MIN_SPEED_WIDTH = 1e-100
#: Smallest SD of a normal speed law relative to its mean: the law's quadrature spans 20 SDs,
#: which must hold many float64 steps of the mean (2.2e-16 of it).
MIN_RELATIVE_SD = 1e-9


@dataclass(frozen=True)
class NormalSpeed:
    """Speed N(mean, sd) truncated at zero (renormalised over v >= 0), m/s."""

    mean: float
    sd: float

    def __post_init__(self):
        object.__setattr__(self, "mean", finite("speeds.mean", self.mean))
        object.__setattr__(self, "sd", positive("speeds.sd", self.sd))
        if self.mean + NORMAL_SPAN * self.sd <= 0.0:
            raise BananagridError(
                f"speeds.mean = {self.mean!r}: with sd = {self.sd!r} the law has no mass above 0 m/s"
            )
        # the quadrature's nodes reach mean + NORMAL_SPAN sd: they must stay finite
        if not abs(self.mean) < MAX_SPEED:
            raise BananagridError(f"speeds.mean = {self.mean!r}: must be below {MAX_SPEED:g} m/s")
        if not self.sd >= MIN_RELATIVE_SD * abs(self.mean):  # else the quadrature's nodes coincide
            raise BananagridError(
                f"speeds.sd = {self.sd!r}: below {MIN_RELATIVE_SD:g} of the mean {self.mean!r} the law is one "
                "speed; give it as speeds = [mean]"
            )
        if not self.sd >= MIN_SPEED_WIDTH:  # its density 1 / sd stays finite
            raise BananagridError(f"speeds.sd = {self.sd!r}: must be at least {MIN_SPEED_WIDTH:g} m/s; "
                                  "give one speed as speeds = [mean]")
        if not abs(self.mean) + NORMAL_SPAN * self.sd < MAX_SPEED:
            raise BananagridError(
                f"speeds.sd = {self.sd!r}: with mean = {self.mean!r} the law reaches "
                f"{abs(self.mean) + NORMAL_SPAN * self.sd!r} m/s (at most {MAX_SPEED:g})"
            )

    @property
    def _law(self):
        return stats.truncnorm(-self.mean / self.sd, np.inf, loc=self.mean, scale=self.sd)

    def nodes(self, t: float, panel: float) -> tuple[np.ndarray, np.ndarray]:
        lo = max(0.0, self.mean - NORMAL_SPAN * self.sd)
        hi = self.mean + NORMAL_SPAN * self.sd
        width = min(panel / t if t > 0 else math.inf, self.sd)
        v, w = _gauss_panels(lo, hi, width)
        return v, w * self._law.pdf(v)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self._law.rvs(size=n, random_state=rng)

    def pdf(self, v) -> np.ndarray:
        return self._law.pdf(np.asarray(v, dtype=float))


@dataclass(frozen=True, eq=False)
class TabulatedSpeed:
    """A user's speed table: density values at increasing speeds, joined linearly, zero outside
    [speeds[0], speeds[-1]] and normalised to one.

    Parameters
    ----------
    speeds : array_like, shape (m,)
        Increasing speeds, m/s, >= 0, m >= 2.
    density : array_like, shape (m,)
        Non-negative (relative) density at those speeds, not all zero.
    """

    speeds: np.ndarray
    density: np.ndarray

    def __post_init__(self):
        v = _vector("speeds.speeds", self.speeds)
        f = _vector("speeds.density", self.density)
        if v.size < 2 or v.size != f.size:
            raise BananagridError(
                f"speeds: a table needs at least 2 speeds and as many densities (got {v.size} and {f.size})"
            )
        if v[0] < 0 or np.any(np.diff(v) <= 0):
            raise BananagridError(f"speeds.speeds = {v.tolist()!r}: must be >= 0 and strictly increasing")
        if not v[-1] < MAX_SPEED:  # the quadrature's panels and the ranges v t stay finite
            raise BananagridError(f"speeds.speeds = {v.tolist()!r}: must be below {MAX_SPEED:g} m/s")
        if not v[-1] - v[0] >= MIN_SPEED_WIDTH:  # the normalised density stays finite
            raise BananagridError(f"speeds.speeds = {v.tolist()!r}: the table spans less than {MIN_SPEED_WIDTH:g} m/s; "
                                  "give one speed as speeds = [v]")
        if np.any(f < 0) or not np.any(f > 0):
            raise BananagridError(f"speeds.density = {f.tolist()!r}: must be >= 0 and not all zero")
        mass = float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(v)))
        f = f / mass
        for name, value in (("speeds", v), ("density", f)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def nodes(self, t: float, panel: float) -> tuple[np.ndarray, np.ndarray]:
        vs, ws = [], []
        for lo, hi in zip(self.speeds[:-1], self.speeds[1:]):  # exact on each linear piece
            v, w = _gauss_panels(float(lo), float(hi), panel / t if t > 0 else math.inf)
            vs.append(v)
            ws.append(w * self.pdf(v))
        return np.concatenate(vs), np.concatenate(ws)

    def pdf(self, v) -> np.ndarray:
        return np.interp(np.asarray(v, dtype=float), self.speeds, self.density, left=0.0, right=0.0)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Inverse CDF: a piece by its mass, then the root of its quadratic CDF."""
        v, f = self.speeds, self.density
        h = np.diff(v)
        mass = 0.5 * (f[1:] + f[:-1]) * h
        piece = rng.choice(len(h), size=n, p=mass / mass.sum())
        m = rng.uniform(0.0, 1.0, n) * mass[piece]
        f0, f1, hp = f[piece], f[piece + 1], h[piece]
        # f0 s + (f1 - f0) s^2 / (2 h) = m, in the form without cancellation
        s = 2.0 * m / (f0 + np.sqrt(np.maximum(f0 * f0 + 2.0 * (f1 - f0) * m / hp, 0.0)))
        return v[piece] + np.minimum(s, hp)


SpeedLaw = UniformSpeed | NormalSpeed | TabulatedSpeed


def _vector(name: str, value) -> np.ndarray:
    array = real_array(name, value, "a list of numbers")
    if array.ndim != 1 or array.size == 0:
        raise BananagridError(f"{name} = {value!r}: expected a non-empty list of numbers")
    if not np.isfinite(array).all():
        raise BananagridError(f"{name} = {value!r}: every value must be finite (NaN or inf given)")
    return array


#: Travelled ranges below this many of the start's smallest SD are taken as 0 (see
#: :meth:`Butterly.kernel_parameters`).
NEGLIGIBLE_RHO = 1e-100


# ---------------------------------------------------------------------------------------------
# Scene layers (model = "butterly")
# ---------------------------------------------------------------------------------------------

#: Speed laws of a scene layer (``speed_law``) and the keys each takes besides the common ones.
SPEED_LAWS = {
    "discrete": ("speeds", "weights"),
    "uniform": ("speed_min", "speed_max"),
    "normal": ("speed_mean", "speed_sd"),
    "table": ("speeds", "speed_density"),
}


def scene_arguments(params: Mapping) -> dict:
    """Keyword arguments of :class:`~bananagrid.Butterly` from a Butterly layer's parameters.

    ``params`` holds, in SI units: ``mean``; ``cov`` or ``sigma_x``, ``sigma_y`` (m) and
    optionally ``rho`` (correlation, default 0); ``t``; ``speed_law`` (default
    ``"discrete"``) with ``speeds`` and ``weights``, ``speed_min`` and ``speed_max``
    (uniform), ``speed_mean`` and ``speed_sd`` (normal, truncated at 0) or ``speeds`` and
    ``speed_density`` (table); optionally ``course_kappa`` and ``course_mean``.

    Raises
    ------
    BananagridError
        ``NAME = value: rule`` for a value out of its domain (sigma_x, sigma_y, rho here; the
        rest from the model and its speed laws).
    """
    if "cov" in params:
        cov = params["cov"]
    else:
        sx, sy = params["sigma_x"], params["sigma_y"]
        rho = params.get("rho", 0.0)
        for name, value in (("sigma_x", sx), ("sigma_y", sy)):
            if not (math.isfinite(value) and value > 0.0):
                raise BananagridError(f"{name} = {value!r}: must be finite and > 0 (m, 1 sigma)")
            if not 1e-150 < value < 1e150:  # its square, the variance, must be a normal float64
                raise BananagridError(f"{name} = {value!r}: its square (the variance) overflows or vanishes in float64")
        if not (math.isfinite(rho) and -1.0 < rho < 1.0):
            raise BananagridError(f"rho = {rho!r}: must be in (-1, 1) (the start's correlation)")
        cov = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
        try:  # named by the keys given (sigmas of very different size make it singular in float64)
            covariance("cov", cov)
        except BananagridError as exc:
            rule = str(exc).split(": ", 1)[1]
            raise BananagridError(f"sigma_x = {sx!r}: with sigma_y = {sy!r} and rho = {rho!r}, the start's covariance "
                                  f"[[sx^2, rho sx sy], [rho sx sy, sy^2]] {rule}") from None
    law = params.get("speed_law", "discrete")
    weights = None
    if law == "discrete":
        speeds, weights = params["speeds"], params.get("weights")
    elif law == "uniform":
        speeds = UniformSpeed(params["speed_min"], params["speed_max"])
    elif law == "normal":
        speeds = NormalSpeed(params["speed_mean"], params["speed_sd"])
    else:
        speeds = TabulatedSpeed(params["speeds"], params["speed_density"])
    return dict(
        mean=params["mean"], cov=cov, speeds=speeds, weights=weights, t=params["t"],
        course_kappa=params.get("course_kappa", 0.0), course_mean=params.get("course_mean", 0.0),
    )


def _scene_missing(given: Mapping, path: str) -> list[str]:
    """The start covariance and speed-law keys a Butterly layer lacks (as 'missing' items);
    keys that contradict each other or the speed law are errors."""
    missing = []
    sigmas = [k for k in ("sigma_x", "sigma_y", "rho") if k in given]
    if "cov" in given and sigmas:
        raise BananagridError(
            f"{path}: give cov or sigma_x, sigma_y (and rho), not both "
            f"(cov from {given['cov'][0]}, {sigmas[0]} from {given[sigmas[0]][0]})"
        )
    if "cov" not in given:
        if sigmas:
            missing += [k for k in ("sigma_x", "sigma_y") if k not in given]
        else:
            missing.append("cov (or sigma_x and sigma_y)")
    law = given.get("speed_law", (None, None, "discrete"))[2]
    needed = SPEED_LAWS[law]
    missing += [k for k in needed if k not in given and not (law == "discrete" and k == "weights")]
    for key in (k for ks in SPEED_LAWS.values() for k in ks):
        if key in given and key not in needed:
            where, written, _ = given[key]
            laws = [name for name, keys in SPEED_LAWS.items() if key in keys]
            raise BananagridError(
                f"{where} = {show(written)}: only with speed_law = "
                + " or ".join(map(show, laws)) + f" (this layer's is {show(law)})"
            )
    return missing


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------


def _speed_entries(model: "Butterly", speeds) -> dict:
    """The speeds' entries in ``parameters()``: the discrete speeds and their weights, or the
    continuous law and its number of quadrature nodes."""
    v, w = model.speed_nodes
    if isinstance(speeds, np.ndarray):
        return {"speeds": v.tolist(), "weights": w.tolist()}
    return {"speed_law": repr(speeds), "speed_nodes": int(v.size)}


#: Scene keys that set the start's covariance from standard deviations instead of ``cov``.
SIGMA_KEYS = (
    SceneKey("sigma_x", unit="m", default="instead of `cov`", allowed="finite, > 0: the start's 1-sigma error east"),
    SceneKey("sigma_y", unit="m", default="instead of `cov`", allowed="finite, > 0: the start's 1-sigma error north"),
    SceneKey("rho", default="`0`", allowed="in (-1, 1): their correlation (with `sigma_x`, `sigma_y` only)"),
)
#: Scene keys that set the speeds: the law, and the keys of each law (:data:`SPEED_LAWS`).
SPEED_KEYS = (
    SceneKey("speed_law", type="choice", default='`"discrete"`', choices=tuple(SPEED_LAWS),
             allowed='`"discrete"` (`speeds`, `weights`), `"uniform"` (`speed_min`, `speed_max`), `"normal"` '
                     '(`speed_mean`, `speed_sd`, truncated at 0 and renormalised), `"table"` (`speeds`, '
                     '`speed_density`, joined linearly)'),
    SceneKey("speeds", type="numbers", unit="m/s", alias="kn",
             default='required for `"discrete"` and `"table"` (or `speeds_kn`)',
             allowed='finite, >= 0 (`"table"`: at least 2, strictly increasing)'),
    SceneKey("speed_min", unit="m/s", alias="kn", default='required for `"uniform"` (or `speed_min_kn`)',
             allowed="finite, 0 <= `speed_min` < `speed_max`"),
    SceneKey("speed_max", unit="m/s", alias="kn", default='required for `"uniform"` (or `speed_max_kn`)',
             allowed="finite, > `speed_min`"),
    SceneKey("speed_mean", unit="m/s", alias="kn", default='required for `"normal"` (or `speed_mean_kn`)',
             allowed="|mean| < 1e100; some of the law's mass above 0"),
    SceneKey("speed_sd", unit="m/s", alias="kn", default='required for `"normal"` (or `speed_sd_kn`)',
             allowed=">= 1e-9 |mean|, with |mean| + 10 sd < 1e100"),
    SceneKey("speed_density", type="numbers", unit="(relative)", default='required for `"table"`',
             allowed="one per speed, >= 0, not all 0; normalised over the table"),
)


@modelclass(eq=False, kw_only=True)
class Butterly(Model):
    """Normal start, random course, speed law (Butterly (2.5), (3.1); (2.3) for von Mises).

    Notes
    -----
    Density (per m^2) at u: sum_i w_i int N(u - V_i t e(c); mean, cov) p(c) dc, e(c) =
    (sin c, cos c). ``rasterise`` and :meth:`pdf` compute it with a relative error below 1e-9
    (float64) for any r / sigma_min: :meth:`pdf` far into the tails (until it underflows),
    ``rasterise`` wherever the density exceeds 1e-12 of its maximum; a grid's cells that the
    kernel proves below CELL_FLOOR = 1e-13 of the maximum are set to 0 (provenance
    ``zero_below``, per m^2). ``speed_nodes`` holds the discrete
    (V_i, w_i) the kernel integrates: the speeds given, or a continuous law's quadrature nodes.
    """

    mean: tuple[float, float] = param(
        type="pair", unit="m", py="(float, float)", check=point, domain="finite: the start's mean (x east, y north)",
        plain=lambda model, mean: {"mean_x": mean[0], "mean_y": mean[1]},
        doc="Mean of the start position (x east, y north).")
    cov: np.ndarray = param(
        type="matrix", unit="m^2", py="array_like, 2x2", also=SIGMA_KEYS, check=covariance,
        default_doc="required unless `sigma_x`, `sigma_y`",
        plain=lambda model, cov: {"cov_xx": float(cov[0, 0]), "cov_xy": float(cov[0, 1]), "cov_yy": float(cov[1, 1])},
        doc="Covariance of the start: symmetric positive definite (any correlation |rho| < 1, any elongation); "
            "a scene may give ``sigma_x``, ``sigma_y`` and ``rho`` instead.")
    t: float = param(
        unit="s", default_doc="required, unless `scene.times`", domain="finite, >= 0; refused with `scene.times`",
        doc="Elapsed time.")
    speeds: object = param(
        py="list of float, or UniformSpeed, NormalSpeed, TabulatedSpeed", scene=SPEED_KEYS, plain=_speed_entries,
        domain="discrete speeds finite, >= 0", doc="Discrete speeds V_i >= 0 (m/s) of (2.5), or a continuous speed law.")
    weights: object = param(
        None, type="numbers", py="list of float, optional", plain=lambda model, weights: {},
        default_doc="required for more than one discrete speed", domain="one per speed, >= 0, summing to 1 (within 1e-9)",
        doc="Probabilities p_i of the discrete speeds. Required for more than one discrete speed; must be left "
            "out for a continuous law.")
    course_kappa: float = param(
        0.0, domain="finite, >= 0: concentration of a von Mises course law; 0 is Butterly's uniform course",
        doc="Concentration of the von Mises course law.")
    course_mean: float = param(
        0.0, unit="rad", alias="deg", default_doc="`0` (north)", bearing_at="mean",
        domain="finite; the von Mises law's mean course, clockwise from north (true north in a geographic scene; "
               "used when `course_kappa` > 0)",
        doc="Mean course c0, clockwise from north (used when course_kappa > 0).")
    _nodes: tuple = field(init=False, repr=False)

    kind = "butterly"
    #: float32 agreement with float64 where the density exceeds 1e-6 of its peak, beyond the
    #: density's change over the point's float32 rounding (``DensityModel.float32_rtol``).
    float32_rtol = 1e-4
    scene = SceneSchema(
        timed=True,
        build=lambda params: Butterly(**scene_arguments(params)),
        missing=_scene_missing,
        message_keys={
            "speeds.v_min": "speed_min", "speeds.v_max": "speed_max", "speeds.mean": "speed_mean",
            "speeds.sd": "speed_sd", "speeds.speeds": "speeds", "speeds.density": "speed_density",
        },
        summary="a normal start moved by a speed law on a uniform or von Mises course (Butterly)",
    )

    def __post_init__(self):
        self.cov.setflags(write=False)  # mean and cov: their declared checks have run
        t = finite("t", self.t)
        if t < 0:
            raise BananagridError(f"t = {t!r}: must be >= 0 (elapsed time, s)")
        object.__setattr__(self, "t", t)
        kappa = finite("course_kappa", self.course_kappa)
        if kappa < 0:
            raise BananagridError(f"course_kappa = {kappa!r}: must be >= 0 (0 is the uniform course)")
        object.__setattr__(self, "course_kappa", kappa)
        object.__setattr__(self, "course_mean", finite("course_mean", self.course_mean))
        if isinstance(self.speeds, (UniformSpeed, NormalSpeed, TabulatedSpeed)):
            if self.weights is not None:
                raise BananagridError(
                    f"weights = {self.weights!r}: a continuous speed law ({type(self.speeds).__name__}) takes no weights"
                )
            v, w = self.speeds.nodes(self.t, SPEED_PANEL_SIGMAS * math.sqrt(self.axes[0]))
            w = w / w.sum()
        else:
            v = _vector("speeds", self.speeds)
            bad = np.flatnonzero(v < 0)
            if bad.size:
                raise BananagridError(f"speeds[{bad[0]}] = {float(v[bad[0]])!r}: must be >= 0 (m/s)")
            if self.weights is None:
                if v.size > 1:
                    raise BananagridError(f"weights: required for {v.size} speeds (probabilities summing to 1)")
                w = np.ones(1)
            else:
                w = _vector("weights", self.weights)
                if w.size != v.size:
                    raise BananagridError(f"weights: {w.size} given for {v.size} speeds; lengths must match")
                bad = np.flatnonzero(w < 0)
                if bad.size:
                    raise BananagridError(f"weights[{bad[0]}] = {float(w[bad[0]])!r}: must be >= 0")
                total = float(w.sum())
                if abs(total - 1.0) > 1e-9:
                    raise BananagridError(f"weights = {w.tolist()!r}: must sum to 1 (they sum to {total!r})")
                w = w / total
            v.setflags(write=False)
            object.__setattr__(self, "speeds", v)
            if self.weights is not None:
                frozen = w.copy()
                frozen.setflags(write=False)
                object.__setattr__(self, "weights", frozen)
        if v.size > MANY_SPEED_NODES:
            warnings.warn(
                f"Butterly: {v.size} speed nodes; each costs a course integral per cell", BananagridWarning, stacklevel=4
            )
        v = np.ascontiguousarray(v, dtype=float)
        w = np.ascontiguousarray(w, dtype=float)
        reach = float(v.max()) * t
        if not reach < 1e150:  # the ranges r = v t, and their squares, must be normal float64 numbers
            fastest = {UniformSpeed: "speed_max", NormalSpeed: "speed_mean and speed_sd"}.get(type(self.speeds), "speeds")
            raise BananagridError(
                f"t = {t!r}: with speeds up to {float(v.max())!r} m/s (from {fastest}) the range v t = {reach!r} m "
                "overflows (at most 1e150 m)"
            )
        v.setflags(write=False)
        w.setflags(write=False)
        object.__setattr__(self, "_nodes", (v, w))

    # -- derived quantities ----------------------------------------------------------------------

    @property
    def axes(self) -> tuple[float, float, float]:
        """(S1, S2, beta): the start covariance's eigenvalues (S1 <= S2) and the angle from east
        of S1's axis (Butterly's S_u, S_v, beta of (3.3), (3.7))."""
        return covariance_axes(self.cov)

    @property
    def sigma_min(self) -> float:
        """Smallest SD of the start, sqrt(S1), m."""
        return math.sqrt(self.axes[0])

    @property
    def speed_nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """(V_i, w_i): the discrete speed law the kernel integrates (copies)."""
        return self._nodes[0].copy(), self._nodes[1].copy()

    @property
    def ranges(self) -> np.ndarray:
        """Travelled ranges r_i = V_i t, m."""
        return self._nodes[0] * self.t

    @property
    def n_speed_nodes(self) -> int:
        return int(self._nodes[0].size)

    def kernel_parameters(self, dtype=np.float64, *, floors: bool = False) -> np.ndarray:
        """The kernel's parameter array (layout in ``kernels/butterly.py``).

        With ``floors`` (rasterising a grid) the grid kernel may skip work where its bound
        shows the density is negligible: a cell whose bound is below CELL_FLOOR times a lower
        bound of the density's maximum (:meth:`peak_lower_bound`) is set to 0, and a speed whose
        bound at a cell is below SPEED_FLOOR times that maximum over the number of speeds is
        left out of the cell's sum. Without ``floors`` (and for ``pdf``) only contributions
        that would underflow to 0 are skipped.
        """
        k = kernels
        tol, stop, newton = KERNEL_TOL[np.dtype(dtype)]
        s1, s2, beta = self.axes
        theta0 = 0.5 * math.pi - beta - self.course_mean  # the course mean in the eigen frame
        kappa = self.course_kappa
        log_norm = -math.log(4.0 * math.pi**2 * (math.sqrt(s1) * math.sqrt(s2))) - math.log(special.ive(0, kappa))
        head = np.zeros(k.HEAD)
        head[[k.MEAN_X, k.MEAN_Y]] = self.mean
        head[[k.Q1_X, k.Q1_Y]] = math.cos(beta), math.sin(beta)
        head[[k.INV_SQRT_S1, k.INV_SQRT_S2]] = 1.0 / math.sqrt(s1), 1.0 / math.sqrt(s2)
        head[[k.KAPPA, k.COS_THETA0, k.SIN_THETA0]] = kappa, math.cos(theta0), math.sin(theta0)
        head[k.LOG_TOL] = math.log(1.0 / tol) + math.log(4.0 * math.pi)
        head[k.STOP] = stop
        head[k.NEWTON_TOL] = newton
        head[k.LOG_STOP] = -math.log(stop)
        tiny = np.finfo(dtype).smallest_subnormal
        head[k.LOG_TINY] = math.log(tiny) - math.log(2.0 * math.pi) - 1.0
        # below tiny / e the sum of a speed's terms rounds to 0 anyway
        head[k.LOG_POINT_FLOOR] = math.log(tiny) - 1.0
        head[k.LOG_CELL_FLOOR] = -math.inf
        head[k.LOG_SPEED_FLOOR] = head[k.LOG_POINT_FLOOR]
        # a tile drops the nodes below stop / TILE_NODES of the largest at every cell
        head[k.TILE_DROP] = -math.log(stop) + math.log(k.TILE_NODES)
        # the range of logs of normal numbers, less a margin for the rounding of exp and log
        info = np.finfo(dtype)
        head[k.LOG_HUGE], head[k.LOG_SMALL] = math.log(info.max) - 1.0, math.log(info.tiny) + 1.0
        if floors:
            log_peak = math.log(self.peak_lower_bound())
            head[k.LOG_CELL_FLOOR] = math.log(CELL_FLOOR) + log_peak
            head[k.LOG_SPEED_FLOOR] = max(
                head[k.LOG_POINT_FLOOR], math.log(SPEED_FLOOR / self.n_speed_nodes) + log_peak
            )
        r = self.ranges
        rho1, rho2 = r / math.sqrt(s1), r / math.sqrt(s2)
        # a ring under 1e-100 SDs moves no density a float64 can hold (by exp(38.6 rho) - 1 at
        # most: beyond 38.6 SDs the density underflows), and its squares would underflow in
        # the kernel's secular equation (densities 0 off the mean at rho ~ 1e-154): the start
        rho1, rho2 = np.where(rho1 < NEGLIGIBLE_RHO, 0.0, rho1), np.where(rho1 < NEGLIGIBLE_RHO, 0.0, rho2)
        with np.errstate(divide="ignore"):
            log_w = np.log(self._nodes[1])
        per = np.zeros((r.size, k.PER_SPEED))
        per[:, k.RHO1], per[:, k.RHO2] = rho1, rho2
        per[:, k.FOUR_F] = (rho1 - rho2) * (rho1 + rho2)  # 4F = rho1^2 - rho2^2 without cancellation
        per[:, k.LOG_COEF] = np.where(np.isfinite(log_w), log_w + log_norm, -1e300)
        per[:, k.LOG_BOUND] = np.where(
            np.isfinite(log_w), log_w - math.log(2.0 * math.pi * (math.sqrt(s1) * math.sqrt(s2))), -1e300
        )
        return np.concatenate((head, per.ravel())).astype(dtype)

    def peak_lower_bound(self) -> float:
        """A lower bound of the density's maximum (per m^2): the largest of its values at the
        start mean and at 64 courses on the ring of each of (up to 64, evenly chosen) speeds,
        computed once by the float64 kernel."""
        cached = self.__dict__.get("_peak_lower_bound")
        if cached is not None:
            return cached
        r = self.ranges
        pick = np.unique(np.linspace(0, r.size - 1, min(r.size, 64)).round().astype(int))
        c = 2.0 * math.pi * np.arange(64) / 64 + self.course_mean
        x = np.concatenate(([self.mean[0]], (self.mean[0] + r[pick, None] * np.sin(c)).ravel()))
        y = np.concatenate(([self.mean[1]], (self.mean[1] + r[pick, None] * np.cos(c)).ravel()))
        peak = float(np.max(self.pdf(x, y)))
        if not peak > 0.0:  # every candidate underflowed: no floor
            peak = float(np.finfo(float).smallest_subnormal)
        self.__dict__["_peak_lower_bound"] = peak
        return peak

    # -- densities ---------------------------------------------------------------------------------

    def bind(self, ctx: KernelContext, extent: Extent, *, grid: bool = False) -> KernelBinding:
        """The course-integral kernels (``kernels/butterly.py``); on a grid, with the cell and
        speed floors (:meth:`kernel_parameters`), 32 x 32 tiles and per-band scratch."""
        params = ctx.struct(kernels.BUTTERLY, params=ctx.array(self.kernel_parameters(ctx.dtype, floors=grid)),
                            n_speeds=self.n_speed_nodes)
        notes = {"speed_nodes": self.n_speed_nodes}
        if grid:
            notes["zero_below"] = CELL_FLOOR * self.peak_lower_bound()
        return KernelBinding(kernels.KERNELS, params, notes)

    def bind_carried(self, ctx: KernelContext, extent: Extent, pack: EvidencePack) -> KernelBinding:
        """The carried points kernel (:class:`~bananagrid.protocol.CarryingModel`): each course
        node's path weighted by the packed evidence, inside the course integral.

        For the course c and speed V_i the path through the map point x is at x - V_i (t - s)
        e(c) at time s, so the weight needs no integral over the start. Rule
        (``kernels/butterly.py``, the carried section): the arcs of courses where the speed's
        integrand exceeds 1e-15 of its peak (the density's own walk) are cut at every course
        whose path crosses a polygon's edge at a polygon node's time (the circle of radius V_i
        (t - s) about x against each edge: the polygons' weights are constant between), and
        each piece is integrated by Gauss-Legendre within the error bound of the
        CARRIED_GAUSS_NODES-point rule on CARRIED_PANEL trapezoid spacings (about 1.6 of the
        integrand's narrowest width 1 / sqrt(A): relative error below 1e-13 per panel for a
        normal profile, ``engine.quadrature.gauss_error(8, 1.6)``): the fewest equal panels no
        wider than the 16-point rule's limit (6.7 spacings), each by the lowest order (2 to 16)
        whose limit covers it (``_carried_rule``). Smooth factors (reports, bearings,
        inverse-cube tracks, rasters) are evaluated at every node, on panels narrowed to their
        angular scale (the factor's length scale over V_i (t - s)), down to
        CARRIED_NARROWEST of a panel; an arc that no polygon cuts takes the density's own
        trapezoid rule (the weight at its nodes, spacing narrowed likewise). An area search over
        an interval (t0, t1) is exact: the path over it is a straight segment, whose length
        inside the polygon over its speed is the time spent inside (coverage C spread evenly:
        log-weight -C x that fraction of the interval); its breaks are the courses where an end
        of the segment crosses an edge or the segment passes a vertex (the pack's time nodes
        for it are recognised and replaced, :func:`_interval_searches`). A definite-range
        track weighs a path 0 where its closest approach (exact per leg: both move straight)
        is within W / 2: its breaks are the courses where that switches, found by a march that
        cannot step over one and bisected (``kernels/butterly.py``, ``definite_breaks``); its
        chords (for curved paths) are left out. ``t`` of the pack must be the model's.

        As on a grid (:meth:`kernel_parameters` with ``floors``), a point whose prior bound is
        below CELL_FLOOR = 1e-13 of the density's maximum is 0 in every channel (weights are at
        most one) and a speed below SPEED_FLOOR of it is left out: inside and beyond the rings,
        where the course integrand is spread over the whole circle, every search's crossings
        would cut it into hundreds of pieces for a density of 1e-100.
        """
        if not math.isclose(pack.t, self.t, rel_tol=1e-12, abs_tol=0.0):
            raise BananagridError(f"t = {pack.t!r}: the evidence was packed for a map at t = {pack.t!r}, "
                                  f"the model's t is {self.t!r}")
        rule = _carried_rule(KERNEL_TOL[np.dtype(ctx.dtype)][0])
        segments, segment_ints, exact = _interval_searches(pack)
        kind = pack.ints[:, 0]
        polygon = np.flatnonzero((kind == evidence_kernels.KIND_POLYGON) & ~exact).astype(np.int32)
        # a definite-range track's chords are for curved paths: a straight one takes its legs alone
        chord = (kind == evidence_kernels.KIND_DEFINITE) & ((pack.ints[:, 3] & evidence_kernels.DEFINITE_LEG) == 0)
        smooth = np.flatnonzero((kind != evidence_kernels.KIND_POLYGON) & ~chord).astype(np.int32)
        params = ctx.struct(kernels.BUTTERLY_CARRIED, params=ctx.array(self.kernel_parameters(ctx.dtype, floors=True)),
                            n_speeds=self.n_speed_nodes, rule=ctx.array(rule), t=ctx.scalar(self.t),
                            polygon_nodes=ctx.array(polygon, dtype=np.int32),
                            smooth_nodes=ctx.array(smooth, dtype=np.int32), segments=ctx.array(segments),
                            segment_ints=ctx.array(segment_ints, dtype=np.int32))
        return KernelBinding(kernels.CARRIED_KERNELS, params,
                             {"speed_nodes": self.n_speed_nodes, "carried": "course pieces between polygon crossings"})

    def weighted_cells(self, pack: EvidencePack, x_edges, y_edges) -> np.ndarray:
        """Which cells of a grid (``x_edges``, ``y_edges``) a path may cross with a weight below 1
        (shape (ny, nx)): False where every path through the cell is proved to keep the weight 1
        in every channel, but for courses whose prior contribution is below the carried kernel's
        speed floor (:meth:`bind_carried`: SPEED_FLOOR of the density's maximum over the number
        of speeds, per speed).

        The path through x with start X is at X + (s / t)(x - X) at time s (straight), so with
        x in the cell and X within rho_i of the mean (beyond, speed i's weighted start density is
        below its floor: rho_i = sqrt(2 S2 (log bound_i - log floor)), S2 the start's largest
        variance) it lies, over a factor's [s0, s1], in a box whose sides are affine in s: the
        cell is weighted where that box meets the factor's (:func:`_evidence_boxes`), the
        cell is within rho_i of the ring r_i = V_i t about the mean (else speed i is below its
        floor there), and the annulus r_i (t - s) / t, s in [s0, s1], about the cell meets the
        factor's box (the path at s is that far from x), all for some speed. Every
        cell is weighted where a factor is not bounded by a box (reports, bearings, tracks)."""
        x_edges, y_edges = np.asarray(x_edges, dtype=float), np.asarray(y_edges, dtype=float)
        shape = (y_edges.size - 1, x_edges.size - 1)
        segments, segment_ints, _ = _interval_searches(pack)
        boxes = _evidence_boxes(pack, segments, segment_ints)
        if boxes is None or self.t <= 0.0:
            return np.ones(shape, dtype=bool)
        k = kernels
        params = self.kernel_parameters(np.float64, floors=True)
        floor = params[k.LOG_SPEED_FLOOR]
        log_bound = params[k.HEAD + k.LOG_BOUND::k.PER_SPEED]
        s2 = self.axes[1]
        mx, my = (float(v) for v in self.mean)
        scale = float(np.abs(x_edges).max() + np.abs(y_edges).max() + abs(mx) + abs(my))
        weighted = np.zeros(shape, dtype=bool)
        xlo, xhi = x_edges[None, :-1], x_edges[None, 1:]
        ylo, yhi = y_edges[:-1, None], y_edges[1:, None]
        half = 0.5 * float(np.max(np.hypot(np.diff(x_edges)[None, :], np.diff(y_edges)[:, None])))
        xc, yc = 0.5 * (xlo + xhi), 0.5 * (ylo + yhi)
        distance = np.hypot(xc - mx, yc - my)  # from the mean to the cell's centre
        for lb, r in zip(log_bound, self.ranges):
            if not lb > floor:
                continue
            rho = math.sqrt(2.0 * s2 * (lb - floor))
            rho = rho + 1e-9 * (rho + scale)  # margin for the rounding of positions and bounds
            # the start within rho of the mean and r from a point of the cell: else the speed
            # is below its floor there
            ring = np.abs(distance - r) <= rho + half * (1.0 + 1e-9)
            if not ring.any():
                continue
            for s0, s1, bx0, bx1, by0, by1 in boxes:
                a0, a1 = min(max(s0 / self.t, 0.0), 1.0), min(max(s1 / self.t, 0.0), 1.0)
                reach_x = np.ones(xlo.shape, dtype=bool)
                reach_y = np.ones(ylo.shape, dtype=bool)
                lo_x = np.minimum(a0 * xlo + (1 - a0) * (mx - rho), a1 * xlo + (1 - a1) * (mx - rho))
                hi_x = np.maximum(a0 * xhi + (1 - a0) * (mx + rho), a1 * xhi + (1 - a1) * (mx + rho))
                reach_x = (lo_x <= bx1) & (hi_x >= bx0)
                lo_y = np.minimum(a0 * ylo + (1 - a0) * (my - rho), a1 * ylo + (1 - a1) * (my - rho))
                hi_y = np.maximum(a0 * yhi + (1 - a0) * (my + rho), a1 * yhi + (1 - a1) * (my + rho))
                reach_y = (lo_y <= by1) & (hi_y >= by0)
                # and on the circle of radius r (t - s) / t about the point (an annulus about the
                # cell's centre, widened by its half diagonal) at a time in [s0, s1]
                near = np.hypot(np.maximum(np.maximum(bx0 - xc, 0.0), xc - bx1),
                                np.maximum(np.maximum(by0 - yc, 0.0), yc - by1))
                far = np.hypot(np.maximum(np.abs(bx0 - xc), np.abs(xc - bx1)),
                               np.maximum(np.abs(by0 - yc), np.abs(yc - by1)))
                annulus = (near <= r * (1.0 - a0) + half * (1.0 + 1e-9)) & (far >= r * (1.0 - a1) - half * (1.0 + 1e-9))
                weighted |= reach_y & reach_x & ring & annulus
        return weighted

    def carried_cell_plan(self, domain, pack: EvidencePack, *, tol: float = GAUSS_TOL,
                          prior_cells=None) -> CellPlan | None:
        """Each channel's carried probability of every cell of a grid
        (:class:`~bananagrid.protocol.CarryingModel`), unnormalised: shape (C, ny, nx).

        Rule: the prior's (the engine's tensor Gauss-Legendre rule on sub-cells no wider than
        sigma_min, :func:`~bananagrid.engine.quadrature.gauss_error` at most ``tol`` per
        sub-cell and axis for a normal feature of SD sigma_min) applied to the carried density
        (:meth:`bind_carried`) at the nodes. Cells whose prior mass is proved below CELL_FLOOR of
        the density's maximum times their area (:meth:`density_bounds`) are 0: weights are at most
        one. Error: where the weight is smooth over a cell, the rule's (``tol`` per sub-cell and
        axis). The carried density is continuous in x for a polygon at an earlier time but has a
        kink where a course's circle touches an edge (the set of courses that reach the polygon
        changes in length like sqrt of the distance), and jumps for a polygon at the map's own
        time: there the rule's error is that of a Gauss rule on a kink or a step, O(h^2) or
        O(h) of the sub-cell's mass (measured against cells halved in each direction: 1e-6 of
        the channel's mass per cell at most on polar sectors holding a point-time search's
        kinks, tests/evidence/test_butterly_cells.py). Cells that no path with a weight below 1
        crosses (:meth:`weighted_cells`) take the prior's cell probability in every channel:
        ``prior_cells`` (the engine's rule, ``rasterise(model, grid, quantity="probability")``,
        the same tensor rule as above; computed here when not given). On a
        :class:`~bananagrid.PolarLattice` the same rule in (range, bearing); None on other
        domains (the posterior's sub-cell rule on the carried densities).
        """
        if isinstance(domain, PolarLattice):
            return self._carried_polar_plan(domain, pack, float(tol))
        if not isinstance(domain, Grid):
            return None
        tol = float(tol)
        scale = self.sigma_min
        (mx, nx_, _), (my, ny_, _) = (_axis_rule(domain.dx, scale, tol), _axis_rule(domain.dy, scale, tol))
        ux, wx = unit_rule(mx, nx_)
        uy, wy = unit_rule(my, ny_)
        x_edges = domain.origin[0] + domain.dx * np.arange(domain.nx + 1)
        y_edges = domain.origin[1] + domain.dy * np.arange(domain.ny + 1)
        bound = self.density_bounds(x_edges[None, :-1], x_edges[None, 1:], y_edges[:-1, None], y_edges[1:, None])
        mass = bound >= CELL_FLOOR * self.peak_lower_bound()
        plain = mass & ~self.weighted_cells(pack, x_edges, y_edges)
        keep = np.argwhere(mass & ~plain)
        if prior_cells is not None:
            prior_cells = np.asarray(prior_cells, dtype=float)
            if prior_cells.shape != domain.shape:
                raise BananagridError(f"prior_cells: shape {prior_cells.shape}; expected the grid's {domain.shape}")
        per_cell = len(ux) * len(uy)
        method = (f"carried density by tensor Gauss-Legendre: {mx} x {my} sub-cells of {nx_} x {ny_} nodes per cell "
                  f"(sub-cells <= sigma_min = {scale:.6g} m)")

        def run(ctx):
            cells = np.zeros((pack.channels.shape[0], domain.ny, domain.nx))
            weights = np.outer(wy, wx).ravel() * (domain.dx * domain.dy)
            chunk = max(1, CELL_CHUNK // per_cell)
            for c0 in range(0, len(keep), chunk):
                block = keep[c0:c0 + chunk]
                xs = x_edges[block[:, 1], None] + domain.dx * ux[None, :]
                ys = y_edges[block[:, 0], None] + domain.dy * uy[None, :]
                px = np.broadcast_to(xs[:, None, :], (len(block), len(uy), len(ux))).ravel()
                py = np.broadcast_to(ys[:, :, None], (len(block), len(uy), len(ux))).ravel()
                values = evaluate_carried(self, px, py, pack, dtype=ctx.dtype, device=ctx.device, threads=ctx.threads)
                cells[:, block[:, 0], block[:, 1]] = values.reshape(-1, len(block), per_cell).astype(float) @ weights
            if plain.any():
                own = prior_cells
                if own is None:
                    own = np.asarray(rasterise(self, domain, quantity="probability", threads=ctx.threads,
                                               min_mass=0.0).values, dtype=float)
                cells[:, plain] = own[plain]
            return cells, {"cell_method": method, "cells_computed": int(len(keep)), "cells_unweighted": int(plain.sum()),
                           "accuracy": {"claim": "per sub-cell and axis for a normal feature as wide as sigma_min, "
                                                 "where the weight is smooth on the cell", "target": tol}}

        seconds = float(len(keep) * per_cell) * CARRIED_SECONDS_PER_NODE * self.n_speed_nodes
        seconds += float(plain.sum()) * per_cell * SECONDS_PER_CELL
        return CellPlan(seconds=seconds, run=run, method=method)

    def _carried_polar_plan(self, lattice: PolarLattice, pack: EvidencePack, tol: float) -> CellPlan:
        """:meth:`carried_cell_plan` on a polar lattice: each cell by the tensor Gauss-Legendre
        rule in (range, bearing) with the area element r, sub-intervals no longer than sigma_min
        radially and, as arcs at the cell's outer range, along the bearing (``tol`` as on a
        grid); cells whose prior bound (on a box holding the sector) is negligible are 0."""
        scale = self.sigma_min
        re, be = lattice.range_edges, lattice.bearing_edges
        nr, nb = lattice.shape
        db = float(np.max(np.diff(be)))
        # a box holding each sector: 17 points along each arc, widened by the arc's largest
        # distance from its chords between them (r (1 - cos(db / 32)))
        u = np.linspace(0.0, 1.0, 17)
        r_grid = np.stack((np.broadcast_to(re[:-1, None, None], (nr, nb, 17)), np.broadcast_to(re[1:, None, None],
                                                                                                (nr, nb, 17))))
        b_grid = be[None, None, :-1, None] + np.diff(be)[None, None, :, None] * u
        x, y = lattice.to_world(r_grid, b_grid)
        pad = re[1:, None] * (1.0 - math.cos(db / 32.0))
        bound = self.density_bounds(x.min(axis=(0, 3)) - pad, x.max(axis=(0, 3)) + pad, y.min(axis=(0, 3)) - pad,
                                    y.max(axis=(0, 3)) + pad)
        keep = bound >= CELL_FLOOR * self.peak_lower_bound()
        rows = np.flatnonzero(keep.any(axis=1))
        plans = {}
        nodes = 0
        for i in rows:
            mr, nr_, _ = _axis_rule(re[i + 1] - re[i], scale, tol)
            mb, nb_, _ = _axis_rule(re[i + 1] * db, scale, tol)
            plans[i] = (unit_rule(mr, nr_), unit_rule(mb, nb_))
            nodes += int(keep[i].sum()) * mr * nr_ * mb * nb_
        method = ("carried density by tensor Gauss-Legendre in (range, bearing), sub-intervals <= sigma_min = "
                  f"{scale:.6g} m (as arcs at the outer range)")

        def run(ctx):
            cells = np.zeros((pack.channels.shape[0], nr, nb))
            for i, ((ur, wr), (ub, wb)) in plans.items():
                cols = np.flatnonzero(keep[i])
                r = re[i] + (re[i + 1] - re[i]) * ur  # (kr,)
                b = be[cols, None] + np.diff(be)[cols, None] * ub[None, :]  # (cols, kb)
                x, y = lattice.to_world(r[None, :, None], b[:, None, :])  # (cols, kr, kb)
                values = evaluate_carried(self, x, y, pack, dtype=ctx.dtype, device=ctx.device, threads=ctx.threads)
                w = (wr * r * (re[i + 1] - re[i]))[:, None] * wb[None, :]  # (kr, kb) without db
                cells[:, i, cols] = np.einsum("cnrb,rb->cn", values.astype(float), w) * np.diff(be)[cols]
            return cells, {"cell_method": method, "cells_computed": int(keep.sum()),
                           "accuracy": {"claim": "per sub-cell and axis for a normal feature as wide as sigma_min, "
                                                 "where the weight is smooth on the cell", "target": tol}}

        return CellPlan(seconds=float(nodes) * CARRIED_SECONDS_PER_NODE * self.n_speed_nodes, run=run, method=method)

    def density_bounds(self, x0, x1, y0, y1) -> np.ndarray:
        """:meth:`density_bound` on arrays of rectangles (broadcast)."""
        x0, x1, y0, y1 = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x0, x1, y0, y1)))
        mx, my = self.mean
        pad = 2.0 ** -22 * (np.maximum(np.abs(x0), np.abs(x1)) + np.maximum(np.abs(y0), np.abs(y1)) + abs(mx) + abs(my))
        x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
        near = np.hypot(np.maximum(np.maximum(x0 - mx, 0.0), mx - x1), np.maximum(np.maximum(y0 - my, 0.0), my - y1))
        far = np.hypot(np.maximum(np.abs(x0 - mx), np.abs(x1 - mx)), np.maximum(np.abs(y0 - my), np.abs(y1 - my)))
        s1, s2, _ = self.axes
        total = np.zeros(near.shape)
        for r, w in zip(self.ranges, self._nodes[1]):
            d = np.maximum(np.maximum(near - r, r - far), 0.0)
            total += w * np.exp(-0.5 * d * d / s2)
        return 2.0 * total / (2.0 * math.pi * math.sqrt(s1) * math.sqrt(s2))

    def density_bound(self, x0: float, x1: float, y0: float, y1: float) -> float:
        """A proved upper bound of the density on the rectangle [x0, x1] x [y0, y1].

        The density is sum_i w_i E_c[N(p - r_i u(c); mean, cov)] over the speed nodes (ranges
        r_i = V_i t, weights w_i, the course law c), so it is at most sum_i w_i max_c N(...). A
        normal is at most exp(-d^2 / (2 S2)) / (2 pi sqrt(S1 S2)) at Euclidean distance d from its
        mean (S2 the larger eigenvalue), and the smallest distance from a point p of the rectangle
        to a point of the circle of radius r_i about the mean is d_i = max(near - r_i, r_i - far,
        0), with near and far the least and greatest distances from the mean to the rectangle (the
        rectangle is connected, so every distance between them is taken). The rectangle is widened
        by the rounding of float32 coordinates and the bound doubled for the kernels' own error
        (float32_rtol and the series' tolerance are far below 1).
        """
        mx, my = self.mean
        pad = 2.0 ** -22 * (max(abs(x0), abs(x1)) + max(abs(y0), abs(y1)) + abs(mx) + abs(my))
        x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
        near = math.hypot(max(x0 - mx, 0.0, mx - x1), max(y0 - my, 0.0, my - y1))
        far = math.hypot(max(abs(x0 - mx), abs(x1 - mx)), max(abs(y0 - my), abs(y1 - my)))
        r = self.ranges
        d = np.maximum(np.maximum(near - r, r - far), 0.0)
        s1, s2, _ = self.axes
        w = self._nodes[1]
        total = float(np.sum(w * np.exp(-0.5 * d * d / s2)))
        return 2.0 * total / (2.0 * math.pi * math.sqrt(s1) * math.sqrt(s2))

    # -- scales (polar lattices and rays) ----------------------------------------------------------

    def polar_scales(self, origin=(0.0, 0.0)) -> tuple[float, float]:
        """sigma_min, the start's smallest SD (the ring's narrowest profile and, for r << sigma,
        the normal's), and that divided by the distance from ``origin`` to the start mean
        (2 pi at the mean; a lattice then gives a row at range R the scale sigma_min / R)."""
        radial = self.sigma_min
        distance = math.hypot(*(np.asarray(self.mean) - np.asarray(origin, dtype=float)))
        return radial, (radial / distance if distance > 0.0 else 2.0 * math.pi)

    def feature_scale(self) -> float:
        """sigma_min, the start's smallest SD."""
        return self.sigma_min

    def radial_extent(self, pose: Pose) -> tuple[float, float]:
        """sigma_min, and the distance from ``pose`` to the start mean plus the longest travel
        plus 12 of the start's largest SDs."""
        s_min, s_max, _ = self.axes
        distance = math.dist(pose.origin, tuple(self.mean))
        return math.sqrt(s_min), distance + float(np.max(self.ranges)) + RANGE_SDS * math.sqrt(s_max)

    def series_pdf(self, x, y, *, lost_digits: bool = False, max_terms: int = 20000):
        """Density by the Bessel series (3.8) (NumPy/SciPy; see :mod:`bananagrid.models._butterly_series`).

        With ``lost_digits=True`` returns ``(density, lost_digits)``: log10(e) (F + w' - g*), the
        decimal digits the alternating series loses to cancellation at each point.
        """
        density, lost = series_density(self, x, y, max_terms=max_terms)
        return (density, lost) if lost_digits else density

    def range_pdf(self, R, *, origin=None, rtol: float = 1e-11) -> np.ndarray:
        """Density of the distance R = |U - origin| (per m), by default from the start's mean.

        Given the course, U - origin ~ N(mean - origin + r e(c), cov), whose distance from 0 has
        the Beckmann law (Butterly's Appendix B, per ERRATA)

            p_B(R; m, cov) = R int_0^{2 pi} N(R e(psi); m, cov) dpsi = 2 pi R P_R(m),

        P_R the single-speed density (3.1) of a start N(0, cov) moved by R, at the point m: so the
        kernel evaluates it. Then p(R) = sum_i w_i int p(c) p_B(R; mean - origin + r_i e(c), cov)
        dc, a periodic integral in c done by the trapezoid rule, doubled until two successive
        rules agree to ``rtol``. For an isotropic cov = s^2 I and origin = mean, p_B does not
        depend on c and p(R) = sum_i w_i Rice(R / s; r_i / s) / s.
        """
        R = np.asarray(R, dtype=float)
        if not np.isfinite(R).all():
            raise BananagridError("R: ranges must be finite (NaN or inf given)")
        if origin is None:
            offset = np.zeros(2)
        else:
            offset = np.asarray(self.mean) - np.asarray(point("origin", origin))
        out = np.zeros(R.shape)
        flat = out.reshape(-1)
        radii, weights = self.ranges, self._nodes[1]
        for k, rk in enumerate(R.reshape(-1)):
            if rk <= 0.0:
                continue
            inner = Butterly(mean=(0.0, 0.0), cov=self.cov, speeds=[rk], t=1.0)
            flat[k] = rk * 2.0 * math.pi * self._course_average(inner, offset, radii, weights, rtol)
        return out

    def _course_average(self, inner: "Butterly", offset, radii, weights, rtol) -> float:
        """sum_i w_i int p(c) inner.pdf(offset + r_i e(c)) dc by the doubling trapezoid rule."""
        n = 64
        previous = None
        while True:
            c = 2.0 * math.pi * np.arange(n) / n
            pc = self.course_pdf(c)
            px = offset[0] + radii[:, None] * np.sin(c)
            py = offset[1] + radii[:, None] * np.cos(c)
            values = inner.pdf(px, py)
            estimate = float(np.sum(weights[:, None] * values * pc) * 2.0 * math.pi / n)
            if previous is not None and abs(estimate - previous) <= rtol * abs(estimate):
                return estimate
            if n >= 2**22:
                warnings.warn(f"range_pdf: course integral not converged to {rtol:g} with {n} nodes",
                              BananagridWarning, stacklevel=3)
                return estimate
            previous = estimate
            n *= 2

    def course_pdf(self, c) -> np.ndarray:
        """Density of the course c (radians clockwise from north): 1 / (2 pi), or von Mises."""
        c = np.asarray(c, dtype=float)
        k = self.course_kappa
        return np.exp(k * (np.cos(c - self.course_mean) - 1.0)) / (2.0 * math.pi * special.ive(0, k))

    def landmarks(self) -> dict[str, np.ndarray]:
        """The start's mean, as ``"fix"``."""
        return {"fix": np.reshape(np.asarray(self.mean, dtype=np.float64), (1, 2))}

    # -- sampling ----------------------------------------------------------------------------------

    def work_estimate(self, cells: int, extent: Extent) -> float:
        """Seconds of one core: ``cells (SECONDS_PER_CELL + speed nodes SECONDS_PER_SPEED_NODE)``."""
        return float(cells) * (SECONDS_PER_CELL + self.n_speed_nodes * SECONDS_PER_SPEED_NODE)

    def sample(self, n: int, rng) -> np.ndarray:
        """Draw ``n`` world positions: start ~ N(mean, cov), speed from its law, course from its
        law, then U = X + V t (sin c, cos c). Continuous speed laws are sampled exactly (not
        through their quadrature nodes)."""
        n, rng = check_n(n), check_rng(rng)
        start, v, c = self._draw(n, rng)
        r = v * self.t
        return start + np.column_stack((r * np.sin(c), r * np.cos(c)))

    def sample_paths(self, n: int, times, rng) -> np.ndarray:
        """Positions of ``n`` draws of the generative story at each of ``times``.

        Each draw is a start X ~ N(mean, cov), a speed V and a course c (drawn as :meth:`sample`
        draws them, in the same order: with the same generator state, ``sample_paths(n, [t],
        rng)[:, 0]`` is ``sample(n, rng)``), and its position at time s is X + V s (sin c, cos c).

        Parameters
        ----------
        n : int
            Number of draws.
        times : array_like, shape (m,)
            Times s >= 0, s since the last fix (the model's clock), finite; any order.
        rng : numpy.random.Generator or int

        Returns
        -------
        ndarray, shape (n, m, 2)
            World positions (x, y), m.
        """
        times = _vector("times", times)
        bad = np.flatnonzero(times < 0)
        if bad.size:
            raise BananagridError(f"times[{bad[0]}] = {float(times[bad[0]])!r}: must be >= 0 (s since the last fix)")
        n, rng = check_n(n, self.sample_bytes * times.size), check_rng(rng)
        start, v, c = self._draw(n, rng)
        e = np.column_stack((np.sin(c), np.cos(c)))
        return start[:, None, :] + (v[:, None] * times[None, :])[:, :, None] * e[:, None, :]

    def _draw(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(start (n, 2), speed (n,), course (n,)) of ``n`` draws of the generative story."""
        start = rng.multivariate_normal(self.mean, self.cov, size=n, method="cholesky")
        if isinstance(self.speeds, np.ndarray):
            v = self._nodes[0][rng.choice(self._nodes[0].size, size=n, p=self._nodes[1])]
        else:
            v = self.speeds.sample(n, rng)
        if self.course_kappa > 0:
            c = rng.vonmises(self.course_mean, self.course_kappa, n)
        else:
            c = rng.uniform(0.0, 2.0 * math.pi, n)
        return start, v, c
