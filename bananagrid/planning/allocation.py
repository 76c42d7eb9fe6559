"""Optimal search effort on one map of cell probabilities.

A planner has a map of cell probabilities p_i (a prior or a posterior: the probability that the
target is in cell i, of area A_i) and an amount of search effort Z (m^2 of swept area: sweep
width times track length). Spending z_i of it in cell i, spread evenly, detects a target there
with probability b(z_i / A_i) (a :class:`~bananagrid.planning.detection.DetectionLaw`). The
probability of success is

    POS(z) = sum_i p_i b(z_i / A_i),    sum_i z_i = Z,  z_i >= 0,

and for b increasing and concave its maximum is given by the Lagrange (Kuhn-Tucker) condition
(Stone, *Theory of Optimal Search*, 1975, Theorem 2.1.2 and eq. (2.2.6)): with d_i = p_i / A_i
the cell's density, every cell that gets effort has the same marginal gain

    d_i b'(e_i) = lambda,    e_i = z_i / A_i,

and a cell gets none where d_i b'(0) <= lambda. For random search (b = 1 - exp(-e)) this is
e_i = max(0, ln(d_i / lambda)), and with the cells sorted by density the multiplier has a closed
form on each set of active cells, ln lambda = (sum_active A_i ln d_i - Z) / sum_active A_i; for
other laws lambda is found by Brent's method on its logarithm, to the last bit. lambda is the
marginal gain: d POS / d Z at the optimum (probability per m^2 of further effort).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from ..domains.grid import Grid
from ..results import PolarRaster, Raster
from ..validate import BananagridError, show
from .detection import DEFINITE, DetectionLaw, detection_law

#: How far the cell probabilities may sum above one before the map is refused as not a
#: probability map (the exact cell rules are held to 1e-8 relative per cell, so a normalised map
#: may sum to 1 + 1e-12 or so; 1e-9 leaves room for that and refuses a density sum).
SUM_SLACK = 1e-9


@dataclass(frozen=True)
class Allocation:
    """Search effort spread over a map's cells to maximise the probability of success.

    Attributes
    ----------
    effort : Raster or ndarray
        Effort per square metre of each cell, the coverage e_i = z_i / A_i (m^2 swept per m^2):
        a :class:`Raster` with ``quantity == "effort"`` on the map's grid, or an array of the
        polar lattice's shape.
    cell_effort : ndarray
        Effort z_i spent in each cell, m^2 (sums to ``total_effort``).
    pod : ndarray
        Probability of detecting the target in each cell if it is there, b(e_i).
    pos : float
        Probability of success, sum_i p_i b(e_i): the probability that the search finds the
        target (of the whole target distribution: cells outside the map count as not found).
    marginal_gain : float
        The Lagrange multiplier lambda: the probability of success one more m^2 of effort buys
        at the optimum (0 when the effort exceeds what the law can use, ``"definite"`` only).
    total_effort : float
        Z, m^2.
    law : DetectionLaw
    cells : ndarray
        The map's cell probabilities p_i (float64), for :meth:`pos_curve`.
    areas : ndarray
        The cells' areas A_i, m^2.
    """

    effort: object
    cell_effort: np.ndarray
    pod: np.ndarray
    pos: float
    marginal_gain: float
    total_effort: float
    law: DetectionLaw
    cells: np.ndarray = field(repr=False)
    areas: np.ndarray = field(repr=False)

    def pos_curve(self, efforts) -> np.ndarray:
        """The optimal probability of success for each total effort in ``efforts`` (m^2): the
        curve a planner reads to decide how much to send (increasing and concave in Z)."""
        efforts = np.atleast_1d(np.asarray(efforts, dtype=float))
        if not (np.isfinite(efforts).all() and (efforts >= 0.0).all()):
            raise BananagridError(f"efforts = {show(efforts)}: expected finite efforts >= 0 (m^2)")
        plan = _SortedMap(self.cells.ravel(), np.broadcast_to(self.areas, self.cells.shape).ravel(), self.law)
        return np.array([plan.solve(z)[2] if z > 0.0 else 0.0 for z in efforts])


def allocate(cells, effort: float, law="exponential") -> Allocation:
    """Spread ``effort`` (m^2 of swept area) over a map of cell probabilities to maximise the
    probability of success.

    Parameters
    ----------
    cells : Raster or PolarRaster
        Cell probabilities: ``bg.rasterise(model, grid, quantity="probability")`` (a prior or a
        posterior) or a polar lattice's ``PolarRaster`` (its ``probability``). A density map is
        refused: its values are not probabilities.
    effort : float
        Total effort Z > 0, m^2 (sweep width times track length).
    law : {"exponential", "inverse_cube", "definite"} or DetectionLaw, default "exponential"
        The detection law b(e) of the coverage (:mod:`bananagrid.planning.detection`).

    Returns
    -------
    Allocation
        The effort per m^2 of each cell, the probability of success and the marginal gain.

    Notes
    -----
    The optimum satisfies d_i b'(e_i) = lambda on every cell with effort, d_i b'(0) <= lambda
    elsewhere (Stone 1975, Theorem 2.1.2); for random search e_i = max(0, ln(d_i / lambda)) with
    ln lambda = (sum A_i ln d_i - Z) / sum A_i over the active cells (Stone eq. (2.2.6)). The
    definite-range law fills the densest cells to coverage 1 first (its b' is flat).
    """
    law = detection_law(law)
    if not law.strictly_concave and law is not DEFINITE:
        raise BananagridError(f"law {law.name!r}: only the provided 'definite' law may be not strictly concave")
    z = check_effort("effort", effort)
    p, areas, shape, grid = _cells_and_areas(cells)
    plan = _SortedMap(p.ravel(), np.broadcast_to(areas, shape).ravel(), law)
    coverage, lam, pos = plan.solve(z)
    coverage = coverage.reshape(shape)
    flat_areas = np.broadcast_to(areas, shape)
    effort_map = coverage if grid is None else Raster(
        values=coverage, grid=grid, mass=float(np.sum(coverage * flat_areas)), quantity="effort",
        provenance={"allocation": {"law": law.name, "effort_m2": z, "pos": pos, "marginal_gain": lam}},
        frame=getattr(cells, "frame", None))
    return Allocation(effort=effort_map, cell_effort=coverage * flat_areas, pod=np.asarray(law.pod(coverage)),
                      pos=pos, marginal_gain=lam, total_effort=z, law=law, cells=p, areas=np.asarray(areas))


def optimal_coverage(p: np.ndarray, areas, z: float, law: DetectionLaw) -> tuple[np.ndarray, float, float]:
    """The optimal coverage of cells of probabilities ``p`` and areas ``areas`` under ``law``
    for effort ``z`` (unchecked): (coverage per cell, the multiplier lambda, POS)."""
    p = np.asarray(p, dtype=np.float64)
    coverage, lam, pos = _SortedMap(p.ravel(), np.broadcast_to(areas, p.shape).ravel(), law).solve(z)
    return coverage.reshape(p.shape), lam, pos


def check_effort(name: str, value) -> float:
    """``value`` as an effort in m^2 (sweep width times track length): a positive finite number,
    or a one-line error naming ``name`` (one period's, or each of a plan's periods')."""
    try:
        z = float(value)
    except (TypeError, ValueError):
        raise BananagridError(f"{name} = {show(value)}: expected a positive finite effort in m^2 "
                              "(sweep width times track length)") from None
    if not (math.isfinite(z) and z > 0.0):
        raise BananagridError(f"{name} = {z!r}: expected a positive finite effort in m^2 "
                              "(sweep width times track length)")
    return z


def _cells_and_areas(cells) -> tuple[np.ndarray, np.ndarray | float, tuple, Grid | None]:
    """The map's cell probabilities (float64), the cells' areas, the shape and the grid (None
    for a polar lattice); refuses what is not a map of probabilities."""
    if isinstance(cells, Raster):
        if cells.quantity != "probability":
            raise BananagridError(
                f"cells: a map of {cells.quantity} values, not cell probabilities; make one with "
                "bg.rasterise(model, grid, quantity=\"probability\")")
        p, areas, grid = np.asarray(cells.values, dtype=np.float64), cells.grid.cell_area, cells.grid
    elif isinstance(cells, PolarRaster):
        p, areas, grid = np.asarray(cells.probability, dtype=np.float64), cells.lattice.cell_areas, None
    else:
        raise BananagridError(f"cells = {type(cells).__name__}: expected a Raster of cell probabilities "
                              "(bg.rasterise(model, grid, quantity=\"probability\")) or a PolarRaster")
    if not np.isfinite(p).all():
        raise BananagridError(f"cells: {int((~np.isfinite(p)).sum())} cell probabilities are not finite")
    if (p < 0.0).any():
        raise BananagridError(f"cells: {int((p < 0.0).sum())} cell probabilities are negative "
                              f"(the lowest {p.min()!r})")
    total = float(np.sum(p))
    if not total > 0.0:
        raise BananagridError("cells: the map holds no probability (every cell is 0): nothing to search for")
    if total > 1.0 + SUM_SLACK:
        raise BananagridError(f"cells: the cell probabilities sum to {total!r}, more than 1: not a "
                              "probability map")
    return p, areas, p.shape, grid


class _SortedMap:
    """The cells with probability, sorted by density (densest first), for one law."""

    def __init__(self, p: np.ndarray, areas: np.ndarray, law: DetectionLaw):
        self.n, self.law = p.size, law
        self.index = np.flatnonzero(p > 0.0)
        # log densities (no underflow of p / A for tiny p and large cells), densest first
        log_density = np.log(p[self.index]) - np.log(areas[self.index])
        order = np.argsort(-log_density)  # ties in any order: tied cells get the same coverage
        self.index, self.log_density = self.index[order], log_density[order]
        self.p, self.areas = p[self.index], areas[self.index]

    def solve(self, z: float) -> tuple[np.ndarray, float, float]:
        """Coverage per cell (all n cells), the multiplier lambda and the POS for effort z."""
        if self.law is DEFINITE:
            active, lam = self._definite(z)
        elif self.law.name == "exponential" and self.law.inverse_dpod is not None:
            active, lam = self._exponential(z)
        else:
            active, lam = self._general(z)
        coverage = np.zeros(self.n)
        coverage[self.index[:active.size]] = active
        pos = float(np.sum(self.p[:active.size] * self.law.pod(active)))
        return coverage, lam, pos

    def _exponential(self, z: float) -> tuple[np.ndarray, float]:
        # relative to the densest cell, so the sums do not cancel at large |ln d|
        shifted = self.log_density - self.log_density[0]
        s_area = np.cumsum(self.areas)
        s_area_log = np.cumsum(self.areas * shifted)
        # effort that makes cell k (0-based) the first with none: sum_{i<k} A_i (L_i - L_k)
        threshold = s_area_log - shifted * s_area
        k = int(np.searchsorted(threshold, z, side="left"))  # cells 0..k-1 active (k >= 1)
        a = self.areas[:k]
        log_lam = (float(np.sum(a * shifted[:k])) - z) / float(np.sum(a))
        coverage = np.maximum(shifted[:k] - log_lam, 0.0)
        return coverage, math.exp(log_lam + self.log_density[0])

    def _general(self, z: float) -> tuple[np.ndarray, float]:
        law, c0 = self.law, self.law.initial_slope
        log_c0 = math.log(c0)
        shifted = self.log_density - self.log_density[0]

        def spent(log_lam: float, k: int) -> float:
            """Effort at the multiplier lambda = b'(0) d_0 exp(log_lam) (d_0 the densest cell's
            density), over the cells before k: cell i's coverage has ln b'(e) = ln(lambda / d_i)."""
            return float(np.sum(self.areas[:k] * law.coverage_at_log_slope(log_lam - shifted[:k] + log_c0)))

        # T(m) = effort when cell m is the first without any (lambda = d_m b'(0)), nondecreasing
        # in m: the active cells are 0..K-1 with K - 1 the largest m where T(m) < z
        lo, hi = 0, self.index.size - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if spent(shifted[mid], mid) < z:
                lo = mid
            else:
                hi = mid - 1
        k = lo + 1
        upper = shifted[k - 1]
        lower = shifted[k] if k < self.index.size else upper - 1.0
        while k == self.index.size and spent(lower, k) < z:  # all cells active: widen downwards
            lower = upper - 2.0 * (upper - lower)
            if not math.isfinite(lower):  # a law whose b' reaches 0 at a finite coverage
                raise BananagridError(f"effort = {z!r} m^2: more than law {law.name!r} can use on this map")
        log_lam = optimize.brentq(lambda s: spent(s, k) - z, lower, upper, xtol=1e-300, rtol=4.0 * np.finfo(float).eps,
                                  maxiter=500)
        coverage = law.coverage_at_log_slope(log_lam - shifted[:k] + log_c0)
        return coverage, c0 * math.exp(log_lam + self.log_density[0])

    def _definite(self, z: float) -> tuple[np.ndarray, float]:
        # b' = 1 below coverage 1: fill the densest cells whole, the next one in part
        filled = np.cumsum(self.areas)
        k = int(np.searchsorted(filled, z, side="right"))  # cells 0..k-1 filled whole
        if k >= self.index.size:  # more effort than the cells with probability: the rest is not used
            return np.ones(self.index.size), 0.0
        coverage = np.ones(k + 1)
        coverage[k] = (z - (filled[k - 1] if k else 0.0)) / self.areas[k]
        return coverage, math.exp(self.log_density[k])
