"""Search plans over several periods for a moving target (Brown 1980; Washburn).

A target moves along a path x(t) drawn from a motion model (a CAT or a Butterly prior); a search
spends effort E_k in period k, at the time t_k, with t_1 < ... < t_K. Spread over the grid's
cells as coverages e_k (m^2 swept per m^2), period k detects a target in cell c with probability
b(e_k(c)), independently of the other periods, so the probability of success of the plan is

    POS(e_1, ..., e_K) = 1 - E[ prod_k (1 - b(e_k(x(t_k)))) ],

the expectation over the target's paths (a path outside the grid at t_k is not searched then).

**Brown's forward-and-backward iteration.** Hold every period but k fixed. A path's chance of
escaping them is its weight w_k(path) = prod_{j != k} (1 - b(e_j(x(t_j)))): earlier periods
carried forward to t_k, later ones carried backward (a path is fixed by its parameters, so its
later positions are as exact as its earlier ones). With g_k(c) = E[w_k 1{x(t_k) in c}], the map
at t_k of the target that the other periods miss (unnormalised),

    POS = P(some other period detects it) + sum_c g_k(c) b(e_k(c)),

the first term free of e_k, so the best e_k given the others is the single-period optimum
(:func:`~bananagrid.planning.allocation.allocate`) on g_k with the effort E_k, and replacing
e_k by e_k' changes the POS by exactly sum_c g_k(c) (b(e_k'(c)) - b(e_k(c))). The iteration
sweeps k = 1..K, replacing each period's coverage by that optimum, and keeps the POS by these
increments from 0 (no search), on the grid's cells alone (no guess of what happens off the
grid is needed), until a sweep raises it by less than ``tol`` (Brown 1980, "Optimal search for
a moving target in discrete time and space", Oper. Res. 28(6); Washburn 1983, "Search for a
moving target: the FAB algorithm", Oper. Res. 31(4)). The plan's ``pos`` is then evaluated once
more from the final coverages, as the sum of each period's first detections.

**Never decreasing.** Each update maximises the POS over e_k with the others held, and the
coverage it replaces is one of the candidates, so the POS after the update is at least the POS
before it: the history is non-decreasing (an update whose optimum does not beat the coverage it
would replace, by rounding, keeps that coverage). For the exponential law the POS,
1 - E[exp(-sum_k e_k(x(t_k)))], is concave in (e_1, ..., e_K) (an expectation of concave
functions of linear ones), so the iteration converges to the optimum for the given efforts
(Brown 1980); for another concave law it reaches a plan that no single period's change improves.

**What the maps are.** The planner asks one function for "period k's map given the other
periods' POD rasters" (:class:`PeriodMaps`). :class:`SampledPaths` answers it from positions of
sample paths at the plan's times (the paths' cells, each path weighted by the others' 1 - POD):
the particle form of the iteration, exact for the sample, and the Monte Carlo oracle of the tests.
:class:`CarriedMaps` answers it through the model's kernels, on sub-cells of each cell with mass.

**Cost.** A sweep computes K carried maps, and the refined sub-cells (:data:`SUBDIVISIONS` per
side where the other periods' weight varies) are most of it. Where a cell's first look
(:data:`SCREEN` x SCREEN sub-cells) is fine against the model's smallest feature
(:data:`FIRST_LOOK_SCALE`), :func:`plan_periods` first iterates on first looks alone (a tenth of
the points) and then refines from that plan: the optimum is the same, and the refined sweeps
start near it. The history is then the refined sweeps' only (from the first look's plan's POS on
the refined maps), so it never decreases and ends at the plan's POS to the maps' accuracy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Protocol, Sequence

import numpy as np

from ..domains.grid import Grid
from ..engine.carried import carries, evaluate_carried
from ..engine.rasterise import rasterise
from ..evidence.packing import pack
from ..evidence.posterior import NO_PATHS
from ..evidence.searches import RasterSearch
from ..results import Raster
from ..validate import BananagridError, positive_int, show
from .allocation import Allocation, check_effort, optimal_coverage
from .detection import EXPONENTIAL, DetectionLaw, detection_law

__all__ = ["PeriodPlan", "PeriodMaps", "SampledPaths", "CarriedMaps", "iterate_periods", "plan_periods", "log_miss",
           "TOL", "MAX_ITERATIONS", "SUBDIVISIONS", "SKIP_MASS", "REFINE_MASS", "COARSE_TOL", "FIRST_LOOK_SCALE"]

#: Default convergence: a sweep over the periods that raises the total POS by less than this
#: stops the iteration (the POS is a probability; 1e-9 is far below any planning decision and
#: well above the rounding of sums over 10^6 cells, some 1e-13).
TOL = 1e-9
#: Default cap on sweeps over the periods (Brown's iteration converges linearly; the plans of
#: the tests and the bench converge in 3 to 30 sweeps).
MAX_ITERATIONS = 200
#: Sub-cells per side of the rule for a period's cell means of the other periods' weight, on
#: the cells where it varies (measured on the submarine's 1600 m cells: 4 errs by 2.4e-3 in the
#: POS, 8 by 2e-5, within the Monte Carlo sigma of 10^6 paths).
SUBDIVISIONS = 12
#: Sub-cells per side of the first look at every cell: where the weight is the same at all of
#: them, that is its mean.
SCREEN = 4
#: Relative spread of the weight over a cell's first look beyond which the cell is refined
#: (rounding of the weights' sums is some 1e-15).
VARIES = 1e-12
#: Mass of the least likely cells of a period's map left out of the carried rule (their weight
#: taken as 1): on the submarine's rings they are two thirds of the cells with mass.
SKIP_MASS = 1e-10
#: What the first look at the cells that are not refined may be off by in all (their prior mass
#: times the weight's spread over their sub-cells, summed): far below any planning decision.
REFINE_MASS = 1e-10
#: Sweeps on the first look alone stop when one raises the POS by less than this (or ``tol``
#: if larger); the iteration then goes on from that plan on the refined maps.
COARSE_TOL = 1e-6
#: The first sweeps are made on the first look alone where its sub-cells (a cell's side over
#: :data:`SCREEN`) are at most this fraction of the model's smallest feature: measured on the
#: submarine (start SD 430 m) at 400 m cells (sub-cells 0.23 of it), a first-look map's POS
#: is within 5e-5 of 16 x 16 sub-cells', so the refined sweeps start near their optimum; at
#: 3,200 m cells (1.9 of it) the first look's plan was no nearer than no plan.
FIRST_LOOK_SCALE = 0.25
#: Points per call of the carried kernels (bounds the arrays' memory: C channels x 8 bytes each).
CARRIED_POINTS = 2**20


class PeriodMaps(Protocol):
    """What the iteration asks for: period k's map given the other periods' searches.

    Calling it with the period ``k`` and ``misses`` (one array of the grid's shape per period,
    ln(1 - POD_j) of each cell: -e_j for random search, exactly; -inf where the POD is 1; or
    None for a period not searched) returns the unnormalised map g_k of cell probabilities at
    t_k of the target's paths, each weighted by prod_{j != k} (1 - POD_j at the path's cell at
    t_j) (a path off the grid at t_j is not searched then), an array of the grid's shape.
    """

    def __call__(self, k: int, misses: Sequence[np.ndarray | None]) -> np.ndarray: ...


@dataclass(frozen=True)
class PeriodPlan:
    """A search plan over several periods for a moving target.

    Attributes
    ----------
    times : tuple of float
        The periods' times t_1 < ... < t_K, s.
    efforts : tuple of float
        Effort E_k of each period, m^2 (sweep width times track length).
    allocations : tuple of Allocation
        Each period's coverage: the optimal allocation of E_k on the map at t_k of the target
        the other periods miss (its ``cells``, unnormalised). An allocation's own ``pos`` is
        the probability that period k finds a target the others miss.
    pos : float
        Total probability of success, that some period detects the target: the sum of
        ``period_pos``.
    period_pos : tuple of float
        Probability that the target is first detected in period k (missed by the earlier
        periods); they sum to ``pos``.
    history : tuple of float
        Total POS after each update of one period's coverage, in order (K per sweep), kept by
        the updates' increments: non-decreasing; its last value is ``pos`` to the maps' accuracy.
    sweeps : int
        Sweeps over the periods made.
    converged : bool
        Whether the last sweep raised the POS by less than ``tol`` (False: ``max_iterations``
        was reached first).
    tol : float
    law : DetectionLaw
    """

    times: tuple
    efforts: tuple
    allocations: tuple
    pos: float
    period_pos: tuple
    history: tuple
    sweeps: int
    converged: bool
    tol: float
    law: DetectionLaw
    provenance: dict = field(default_factory=dict, repr=False)

    @property
    def coverage(self) -> list:
        """Each period's coverage (effort per m^2): ``allocations[k].effort``."""
        return [a.effort for a in self.allocations]


def iterate_periods(period_maps: PeriodMaps, grid: Grid, efforts: Sequence[float], law="exponential", *,
                    tol: float = TOL, max_iterations: int = MAX_ITERATIONS, times: Sequence[float] | None = None,
                    provenance: dict | None = None, start: Sequence[np.ndarray] | None = None,
                    progress=None) -> PeriodPlan:
    """Brown's forward-and-backward iteration on any source of the periods' maps.

    Parameters
    ----------
    period_maps : PeriodMaps
        Period k's map given the other periods' POD rasters (:class:`SampledPaths`, or the
        model's exact carried maps in :func:`plan_periods`).
    grid : Grid
        The grid of the maps.
    efforts : sequence of float
        E_k > 0 per period, m^2.
    law : str or DetectionLaw, default "exponential"
    tol : float, default :data:`TOL`
        Stop when a sweep over the periods raises the total POS by less than ``tol``.
    max_iterations : int, default :data:`MAX_ITERATIONS`
        Most sweeps.
    times : sequence of float, optional
        The periods' times, for the plan's record (default 0, 1, ...).
    start : sequence of arrays, optional
        Coverages to start from (one per period, effort per m^2 on the grid), e.g. a plan made
        on cheaper maps: the history then starts from their POS on ``period_maps`` (the sum of
        their first detections) instead of 0 (no search).
    progress : callable, optional
        Called after each sweep with ``(sweeps, pos)``: the POS so far (a progress line).

    Returns
    -------
    PeriodPlan
    """
    law, tol, max_iterations = _settings(law, tol, max_iterations)
    efforts = tuple(check_effort(f"efforts[{k}]", z) for k, z in enumerate(efforts))
    if not efforts:
        raise BananagridError("efforts = []: expected one effort per period, at least one period")
    n_periods = len(efforts)
    pods: list[np.ndarray | None] = [None] * n_periods
    misses: list[np.ndarray | None] = [None] * n_periods
    coverage: list[np.ndarray | None] = [None] * n_periods
    maps: list[np.ndarray | None] = [None] * n_periods
    history: list[float] = []
    pos = 0.0
    if start is not None:
        if len(start) != n_periods:
            raise BananagridError(f"start: {len(start)} coverages for {n_periods} periods; expected one per period")
        for k, held in enumerate(start):
            coverage[k] = np.asarray(getattr(held, "values", held), dtype=np.float64)
            pods[k] = np.asarray(law.pod(coverage[k]), dtype=np.float64)
            misses[k] = log_miss(law, coverage[k])
        pos = math.fsum(_first_detections(period_maps, misses, pods))
    sweep_pos = [pos]
    converged = False
    sweeps = 0
    while sweeps < max_iterations and not converged:
        for k in range(n_periods):
            cells = period_maps(k, misses)
            cells = np.asarray(cells, dtype=np.float64)
            if np.any(cells > 0.0):
                new, _, gain = optimal_coverage(cells, grid.cell_area, efforts[k], law)
            else:  # nothing left to find on the grid at t_k: the effort buys nothing there
                new, gain = np.zeros(cells.shape), 0.0
            held = 0.0
            if coverage[k] is not None:
                # the coverage held is a candidate too: an optimum that rounding puts below it
                # would lower the POS, so keep the coverage held
                held = float(np.sum(cells * pods[k]))
                if held >= gain:
                    new, gain = coverage[k], held
            coverage[k], maps[k] = new, cells
            pods[k] = np.asarray(law.pod(new), dtype=np.float64)
            misses[k] = log_miss(law, new)
            pos += gain - held
            history.append(pos)
        sweeps += 1
        sweep_pos.append(history[-1])
        # from a start, its POS is the baseline: one sweep that gains less than tol has converged
        converged = (sweeps > 1 or start is not None) and sweep_pos[-1] - sweep_pos[-2] < tol
        if progress is not None:
            progress(sweeps, history[-1])
    # first detections: period k's map weighted by the earlier periods only; the last period's
    # is the map of its last update (every other period is earlier, and none changed since)
    period_pos = _first_detections(period_maps, misses, pods, last=maps[-1])
    times = tuple(float(t) for t in times) if times is not None else tuple(float(k) for k in range(n_periods))
    allocations = tuple(_allocation(grid, maps[k], coverage[k], pods[k], efforts[k], law, times[k])
                        for k in range(n_periods))
    # the plan's POS from one set of maps (the increments of the history agree with it to the
    # maps' accuracy; exactly, but for rounding, on sample paths)
    total = math.fsum(period_pos)
    info = {"law": law.name, "tol": tol, "sweeps": sweeps, "converged": converged, "pos": total,
            "pos_by_increments": history[-1], "period_pos": list(period_pos), "times_s": list(times),
            "efforts_m2": list(efforts), **(provenance or {})}
    return PeriodPlan(times=times, efforts=efforts, allocations=allocations, pos=total,
                      period_pos=tuple(period_pos), history=tuple(history), sweeps=sweeps, converged=converged,
                      tol=tol, law=law, provenance={"period_plan": info})


def _first_detections(period_maps: PeriodMaps, misses: list, pods: list, last: np.ndarray | None = None) -> list:
    """P(the target is first detected in period k) for each k: the sum of period k's map given
    the earlier periods' searches times its POD (``last``: the last period's map, if known)."""
    n_periods = len(misses)
    out = []
    for k in range(n_periods):
        if k == n_periods - 1 and last is not None:
            earlier = last
        else:
            earlier = period_maps(k, [misses[j] if j < k else None for j in range(n_periods)])
        out.append(float(np.sum(np.asarray(earlier, dtype=np.float64) * pods[k])))
    return out


def _settings(law, tol, max_iterations) -> tuple[DetectionLaw, float, int]:
    law = detection_law(law)
    try:
        tol = float(tol)
    except (TypeError, ValueError):
        raise BananagridError(f"tol = {show(tol)}: expected a positive finite change of POS") from None
    if not (math.isfinite(tol) and tol > 0.0):
        raise BananagridError(f"tol = {tol!r}: expected a positive finite change of POS")
    return law, tol, positive_int("max_iterations", max_iterations)


def log_miss(law: DetectionLaw, coverage: np.ndarray) -> np.ndarray:
    """ln(1 - b(e)) of each cell's coverage: -e for random search (exact at any coverage), else
    log1p(-b(e)) (-inf where b rounds to 1)."""
    coverage = np.asarray(coverage, dtype=np.float64)
    if law is EXPONENTIAL:
        return -coverage
    with np.errstate(divide="ignore"):
        return np.log1p(-np.asarray(law.pod(coverage), dtype=np.float64))


def _allocation(grid: Grid, cells, coverage, pod, effort, law, t) -> Allocation:
    area = grid.cell_area
    raster = Raster(values=coverage, grid=grid, mass=float(np.sum(coverage * area)), quantity="effort",
                    provenance={"allocation": {"law": law.name, "effort_m2": effort, "t": t}})
    return Allocation(effort=raster, cell_effort=coverage * area, pod=pod, pos=float(np.sum(cells * pod)),
                      marginal_gain=_marginal_gain(cells, coverage, area, law), total_effort=effort, law=law,
                      cells=cells, areas=np.asarray(area))


def _marginal_gain(cells, coverage, area, law) -> float:
    """lambda = d_c b'(e_c) on the cells with effort (equal on all of them at the optimum)."""
    active = coverage > 0.0
    if not active.any():
        return 0.0
    return float(np.max(cells[active] / area * law.dpod(coverage[active])))


class SampledPaths:
    """Period maps from sample paths: the target's positions at the plan's times.

    Parameters
    ----------
    positions : array_like, shape (n, K, 2)
        World positions (x east, y north, m) of n paths at the K periods' times, equally
        likely (draws of the model's generative story, or particles of a drift model).
    grid : Grid

    Notes
    -----
    g_k(c) = (1 / n) sum over the paths in cell c at t_k of prod_{j != k} (1 - POD_j(cell of the
    path at t_j)): the iteration on the sample is exact for it (its POS is the sample mean of
    each path's detection probability).
    """

    def __init__(self, positions, grid: Grid):
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 3 or p.shape[2] != 2 or p.shape[0] < 1:
            raise BananagridError(f"positions: shape {p.shape}; expected (n, K, 2) world positions of n >= 1 paths")
        if not np.isfinite(p).all():
            raise BananagridError("positions: not all finite")
        self.grid, self.n, self.periods = grid, p.shape[0], p.shape[1]
        col = np.floor((p[..., 0] - grid.origin[0]) / grid.dx)
        row = np.floor((p[..., 1] - grid.origin[1]) / grid.dy)
        on = (col >= 0) & (col < grid.nx) & (row >= 0) & (row < grid.ny)
        #: flat cell index of each path at each period, -1 off the grid
        self.cells = np.where(on, row * grid.nx + col, -1).astype(np.int64)

    def weights(self, misses: Sequence[np.ndarray | None], skip: int | None = None) -> np.ndarray:
        """Each path's probability (times 1 / n) of escaping the periods' searches (all but
        ``skip``), from their ln(1 - POD) rasters."""
        lw = np.zeros(self.n)
        for j, miss in enumerate(misses):
            if j == skip or miss is None:
                continue
            idx = self.cells[:, j]
            on = idx >= 0
            lw[on] += np.ravel(miss)[idx[on]]
        return np.exp(lw) / self.n

    def __call__(self, k: int, misses: Sequence[np.ndarray | None]) -> np.ndarray:
        """Period k's map of the paths the other periods miss (cell probabilities, unnormalised)."""
        if len(misses) != self.periods:
            raise BananagridError(f"misses: {len(misses)} periods; the paths have positions at {self.periods}")
        w = self.weights(misses, skip=k)
        idx = self.cells[:, k]
        on = idx >= 0
        return np.bincount(idx[on], weights=w[on], minlength=self.grid.nx * self.grid.ny).reshape(self.grid.shape)

    def pos(self, misses: Sequence[np.ndarray | None]) -> float:
        """The sample's POS of a plan with these ln(1 - POD) rasters: 1 - mean escape probability."""
        return 1.0 - float(np.sum(self.weights(misses)))


class CarriedMaps:
    """Period maps from the model's own kernels: the map at t_k of the paths the other periods'
    searches miss, each period's coverage a :class:`~bananagrid.RasterSearch` at its time, carried
    along the paths through each point by the kernels (earlier periods forward, later ones
    backward: a path is fixed by its parameters, so its position at a later time is as exact as
    at an earlier one).

    Parameters
    ----------
    prior : CAT or Butterly
    grid : Grid
    times : sequence of float
        The periods' times (increasing).
    subdivisions : int
        Sub-cells per side of the rule for the weight's cell means.
    threads : int, optional

    Notes
    -----
    Cell c's mass at t_k is g_k(c) = P_c f_c: P_c the prior's cell probability at t_k (the
    model's own cell rule) and f_c the density-weighted mean over the cell of the paths' weight
    prod_{j != k} (1 - POD_j(x(t_j))), on sub-cell centres (the posterior's rule,
    :mod:`bananagrid.evidence.posterior`): :data:`SCREEN` x SCREEN on every cell, n x n where
    the weight differs between those. The weight of the paths through a point jumps where their
    position at t_j crosses a cell edge of period j's raster, so f_c is first order in the
    sub-cell size there. Measured against 10^6 paths of the submarine (3 periods, 1600 m cells):
    the first detections of the later periods err by 2e-3 with 4 x 4 sub-cells and agree within
    the Monte Carlo sigma (1.3e-4) with 8 x 8. On its own 400 m cells (the 3 h and 4 h maps given
    the other periods' single-period plans), sum_c g_c POD_c against 16 x 16: 4.8e-5 and 9.7e-6
    off with 4 x 4, 2.2e-6 and 3.8e-6 with 8 x 8, 8.8e-7 and 2.0e-6 with 12 x 12 (first order
    from 8 on), at 8, 21, 37 and 61 s of CPU per map.
    """

    def __init__(self, prior, grid: Grid, times, *, subdivisions: int = SUBDIVISIONS, threads=None):
        self.grid, self.times, self.threads = grid, tuple(times), threads
        self.models = [_at_time(prior, t, k) for k, t in enumerate(self.times)]
        self.n = positive_int("subdivisions", subdivisions)
        self.prior = [np.asarray(rasterise(m, grid, quantity="probability", threads=threads).values, dtype=np.float64)
                      for m in self.models]
        self.off_grid = [max(0.0, 1.0 - math.fsum(p.ravel())) for p in self.prior]
        self.floor = [_mass_floor(p, SKIP_MASS) for p in self.prior]
        #: the first look alone (SCREEN x SCREEN sub-cells on every cell): the cheap maps of the
        #: first sweeps (:func:`plan_periods`)
        self.coarse = False

    def __call__(self, k: int, misses: Sequence[np.ndarray | None]) -> np.ndarray:
        """Period k's map of the paths the other periods miss (cell probabilities, unnormalised)."""
        evidence = [_raster_search(self.grid, self.times[j], miss) for j, miss in enumerate(misses)
                    if j != k and miss is not None]
        cells = self.prior[k]
        if not evidence:
            return cells
        # packed at the last period's time (every search is at or before it), then placed at
        # t_k: the kernels place each node at its own time along the path, before t_k or after
        carried = replace(pack(evidence, max(self.times)), t=self.times[k])
        mean = self._cell_means(k, carried)
        return cells * mean

    def _cell_means(self, k: int, carried) -> np.ndarray:
        """f_c on the cells that hold all but :data:`SKIP_MASS` of the prior at t_k; 1 on the
        rest (as if the other periods had not searched them: their g is off by at most their
        mass, SKIP_MASS in all). First on SCREEN x SCREEN sub-cells; then, unless ``coarse``,
        again on n x n where the weight is not the same at all of them, but for the cells whose
        prior mass times the weight's spread there sums to at most :data:`REFINE_MASS` (what
        the first look can be off by on them)."""
        rows, cols = np.nonzero(self.prior[k] >= self.floor[k])
        out = np.ones(self.grid.shape)
        first = min(SCREEN, self.n)
        mean, spread = self._means(k, carried, rows, cols, first)
        out[rows, cols] = mean
        if self.n > first and not self.coarse:
            refine = _refined(self.prior[k][rows, cols] * spread, REFINE_MASS)
            if refine.any():
                rows, cols = rows[refine], cols[refine]
                out[rows, cols] = self._means(k, carried, rows, cols, self.n)[0]
        return out

    def _means(self, k: int, carried, rows, cols, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The density-weighted mean weight of each cell on n x n sub-cell centres, and the
        weight's spread between them (0 where it is the same at all of them, to :data:`VARIES`)."""
        grid = self.grid
        u = (np.arange(n) + 0.5) / n
        all_, prior_ = carried.channel("all"), carried.channel("prior")
        mean, spread = np.ones(rows.size), np.zeros(rows.size)
        per_chunk = max(1, CARRIED_POINTS // (n * n))
        for start in range(0, rows.size, per_chunk):
            sl = slice(start, start + per_chunk)
            r, c = rows[sl], cols[sl]
            x = grid.origin[0] + grid.dx * (c[:, None, None] + u[None, None, :])
            y = grid.origin[1] + grid.dy * (r[:, None, None] + u[None, :, None])
            x, y = np.broadcast_arrays(x, y)
            values = evaluate_carried(self.models[k], x.reshape(len(r), -1), y.reshape(len(r), -1), carried,
                                      threads=self.threads)
            weighted, density = values[all_], values[prior_]
            w_sum, d_sum = weighted.sum(axis=1), density.sum(axis=1)
            # a cell whose density vanishes at every sub-cell centre (its mass between them):
            # the weight's mean is unknown there; 1 (as if unsearched) errs by at most its mass
            mean[sl] = np.where(d_sum > 0.0, w_sum / np.where(d_sum > 0.0, d_sum, 1.0), 1.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                w = np.where(density > 0.0, weighted / density, np.nan)
            top = np.nanmax(w, axis=1, initial=-np.inf)
            width = top - np.nanmin(w, axis=1, initial=np.inf)
            spread[sl] = np.where(width > VARIES * np.nanmax(w, axis=1, initial=0.0), width, 0.0)
        return mean, spread


def _refined(error: np.ndarray, budget: float) -> np.ndarray:
    """Which cells to refine: every cell with a positive ``error`` but the smallest ones, whose
    errors sum to at most ``budget``."""
    order = np.argsort(error, kind="stable")
    skipped = int(np.searchsorted(np.cumsum(error[order]), budget, side="right"))
    refine = error > 0.0
    refine[order[:skipped]] = False
    return refine


def _mass_floor(cells: np.ndarray, skip: float) -> float:
    """The least cell probability kept when the smallest cells holding at most ``skip`` of the
    mass in all are left out (the smallest positive probability when none can be)."""
    p = np.sort(cells[cells > 0.0], axis=None)
    if p.size == 0:
        return math.inf
    dropped = int(np.searchsorted(np.cumsum(p), skip, side="right"))
    return float(p[min(dropped, p.size - 1)])


def _raster_search(grid: Grid, t: float, miss: np.ndarray) -> RasterSearch:
    if np.isfinite(miss).all():
        return RasterSearch(grid=grid, t=t, coverage=-miss)
    return RasterSearch(grid=grid, t=t, pod=-np.expm1(miss))


def _at_time(prior, t: float, k: int):
    """The prior's model at time t (its position law then)."""
    try:
        return replace(prior, t=t)
    except BananagridError as err:
        raise BananagridError(f"times[{k}] = {t!r}: {type(prior).__name__} refuses it as its time ({err})") from None


def plan_periods(prior, grid: Grid, times, efforts, law="exponential", *, tol: float = TOL,
                 max_iterations: int = MAX_ITERATIONS, subdivisions: int = SUBDIVISIONS, threads=None,
                 progress=None, first_look: bool | None = None) -> PeriodPlan:
    """A search plan over several periods for a moving target: effort E_k at time t_k spread to
    maximise the probability that some period detects the target (Brown's iteration, module
    docstring), each period's map computed by the model's kernels given the other periods'
    searches.

    Parameters
    ----------
    prior : CAT or Butterly
        The target's motion model; its own ``t`` is replaced by each period's time.
    grid : Grid
        Where the periods search: a path off the grid at t_k is not searched then (the prior's
        mass off the grid at each t_k is ``provenance["period_plan"]["off_grid"]``).
    times : sequence of float
        t_1 < ... < t_K, s since the last fix (each a time the model accepts).
    efforts : sequence of float
        E_k > 0 per period, m^2 (sweep width times track length).
    law : str or DetectionLaw, default "exponential"
        The detection law of every period (the iteration reaches the global optimum for the
        exponential law; for another, a plan no single period's change improves).
    tol : float, default :data:`TOL`
        Stop when a sweep over the periods raises the total POS by less than ``tol``.
    max_iterations : int, default :data:`MAX_ITERATIONS`
        Most sweeps over the periods.
    subdivisions : int, default 12
        Sub-cells per side for the weight's cell means where it varies (:class:`CarriedMaps`).
    threads : int, optional
        CPU threads of the kernels.
    progress : callable, optional
        Called after each sweep with ``(sweep, pos, stage)``: the sweeps so far, the POS so far
        and ``"first look"`` (the first sweeps, on :data:`SCREEN` x SCREEN sub-cells of every
        cell) or ``"refined"`` (on the plan's own maps, from the first look's plan).
    first_look : bool, optional
        Whether to make the first sweeps on the first look alone, and the refined ones from
        their plan (default: where the first look's sub-cells are at most
        :data:`FIRST_LOOK_SCALE` of the model's smallest feature, ``prior.feature_scale()``).

    Returns
    -------
    PeriodPlan
        Its ``history`` holds the refined sweeps' updates (from the first look's plan's POS on
        the refined maps), its ``sweeps`` both kinds (``provenance["period_plan"]
        ["first_look_sweeps"]`` of them the first look's).

    Raises
    ------
    BananagridError
        One line naming the argument: a prior without paths (the polar banana: use bg.CAT) or
        whose kernels do not carry evidence, times not finite or not increasing, efforts not
        positive and finite or not one per time, a grid that is not a Grid.
    """
    kind = getattr(prior, "kind", None)
    if kind in NO_PATHS:
        raise BananagridError(f"prior = {type(prior).__name__}: an approximation with no path per parameter, so "
                              f"the periods' searches cannot be carried between their times; use {NO_PATHS[kind]}")
    if not carries(prior) or not hasattr(prior, "t"):
        raise BananagridError(f"prior = {type(prior).__name__}: plans over periods need a motion model whose kernels "
                              "carry evidence along its paths (bg.CAT, bg.Butterly)")
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid Grid")
    times = _times(times)
    try:
        efforts = list(efforts)
    except TypeError:
        raise BananagridError(f"efforts = {show(efforts)}: expected one effort (m^2) per period") from None
    if len(efforts) != len(times):
        raise BananagridError(f"efforts: {len(efforts)} values for {len(times)} times; expected one effort (m^2) "
                              "per period")
    for k, z in enumerate(efforts):
        check_effort(f"efforts[{k}]", z)
    _settings(law, tol, max_iterations)
    maps = CarriedMaps(prior, grid, times, subdivisions=subdivisions, threads=threads)
    start, first_sweeps = None, 0
    if first_look is None:
        first_look = max(grid.dx, grid.dy) / SCREEN <= FIRST_LOOK_SCALE * float(prior.feature_scale())
    if first_look and len(times) > 1 and maps.n > SCREEN:
        # first sweeps on the first look alone (a tenth of the refined maps' points), to the
        # plan those maps give; the refined sweeps then start from it (the optimum is the same
        # whatever the start: the POS is concave in the coverages for random search)
        maps.coarse = True
        first = iterate_periods(maps, grid, efforts, law, tol=max(tol, COARSE_TOL), max_iterations=max_iterations,
                                times=times, progress=None if progress is None else
                                (lambda sweep, pos: progress(sweep, pos, "first look")))
        maps.coarse = False
        start, first_sweeps = first.coverage, first.sweeps
    plan = iterate_periods(maps, grid, efforts, law, tol=tol, max_iterations=max_iterations, times=times, start=start,
                           progress=None if progress is None else
                           (lambda sweep, pos: progress(first_sweeps + sweep, pos, "refined")),
                           provenance={"model": type(prior).__name__, "off_grid": list(maps.off_grid),
                                       "subdivisions": maps.n, "first_look_sweeps": first_sweeps})
    info = plan.provenance["period_plan"]
    return replace(plan, sweeps=first_sweeps + plan.sweeps,
                   provenance={"period_plan": {**info, "sweeps": first_sweeps + plan.sweeps}})


def _times(times) -> tuple:
    try:
        values = [float(t) for t in times]
    except (TypeError, ValueError):
        raise BananagridError(f"times = {show(times)}: expected an increasing list of times (s)") from None
    if not values:
        raise BananagridError("times = []: expected at least one period's time (s)")
    for k, t in enumerate(values):
        if not math.isfinite(t):
            raise BananagridError(f"times[{k}] = {t!r}: expected a finite time (s)")
        if k and not t > values[k - 1]:
            raise BananagridError(f"times[{k}] = {t!r}: not after times[{k - 1}] = {values[k - 1]!r}; the periods' "
                                  "times must increase")
    return tuple(values)
