"""``posterior``: the map of cell probabilities after evidence at the map's own time, and
after evidence at earlier times carried along the paths of a model that carries it.

For a prior with density p and cell probabilities P_c (the prior's own cell rule: exact for
CAT, Gaussian mixtures and uniform laws, Gauss-Legendre for the others), and a likelihood L
(the product of every evidence's factor), each cell's posterior mass is

    Q_c = int_c p L = P_c f_c,    f_c = int_c p L / int_c p,

and the posterior is Q_c / sum Q. Where every factor is constant on a cell (a grid cell wholly
inside or outside each polygon, away from a definite-range track's edge) f_c is that constant
and Q_c = P_c L exactly. Elsewhere f_c is the density-weighted mean of L over n x n equal
sub-cells: the sub-cell's exact area fraction inside each polygon (a grid's rectangles;
:meth:`~bananagrid.evidence.geometry.Polygon.fraction`), the factor at the sub-cell's centre for
the others, weighted by p at the centre (n / 2 x n / 2 sub-cells on a cell that only smooth
factors vary on: a position report, bearings, an inverse-cube track).

Error bound: whatever p does inside a cell, f_c lies between the least and greatest products
of the factors' bounds on the cell (a weighted mean of values between them), so a cell whose
only varying factors are polygons (1 - POD inside, 1 outside) or a definite-range corridor errs
by at most P_c (max L - min L); their sum is ``provenance["posterior"]["boundary_mass"]``, a
bound on the absolute error of the unnormalised posterior (None where a smooth factor varies).
For p and L smooth on the cell the rule is second order, O((h / n)^2) of the cell's mass:
measured, 8 sub-cells per side differ from 32 by under 1e-3 of the bound (5.2e-5 in all
against a bound of 0.087 for the Figure 1 CAT at 100 m cells; the tests hold it for a CAT, a
Butterly and a mixture).

On a polar lattice every cell with prior mass takes the rule on n x n sub-cells in (range,
bearing), each weighted by its exact area times p at its centre, every factor (polygons
included) at the centre: a polygon's edge is resolved to a sub-cell there (error O(1 / n) of
the mass of the cells it cuts), and no cell is taken as constant. A presence law (a Gaussian
mixture, a uniform law) has no polar cell rule: its cell probabilities there are the same
sub-cells' midpoint rule.

Evidence before the map's time
------------------------------
A model whose kernels carry evidence (:class:`~bananagrid.protocol.CarryingModel`: the CAT,
with and without heading noise) weighs each of its paths through a point by the earlier
evidence (:mod:`~bananagrid.evidence.packing`, ``kernels/evidence.py``), and returns at each
point the weighted densities of the combinations the posterior needs (channels: the prior, all
the earlier evidence, its searches, its reports, each search with the reports). Evidence at the
map's time (and land, always) multiplies them as above. Which rule serves which model:

* a carrying model on a grid: every cell with prior mass by the sub-cell rule on the carried
  channels, f_c = sum over n x n sub-cell midpoints of (channel x same-time factors) / sum of
  the prior channel, times the prior's own cell probability P_c (exact for the CAT). The
  carried weight varies on every cell (the earlier polygons' edges, carried to t, are curves
  through the map), so no cell is taken as constant and no bound is given
  (``boundary_mass`` is None). The rule is first order at those curves: measured on Figure 1's
  CAT with two earlier area searches and bearings (100 m cells), 8 sub-cells differ from 24
  by at most 3.0e-4 of a cell's probability (1.7 % of that cell's), 7.9e-4 summed over the
  grid, and POS by 2.7e-5; 4 sub-cells by 6.6e-4 (5.4 %) and 2.1e-3;
* a carrying model with its own rule for the carried cells (``carried_cell_plan(grid, pack)``:
  each channel's mass in each cell, e.g. the CAT's lines exact in the acceleration): each
  combination's cell mean is the same-time factors' mean (the rule above, without the earlier
  evidence) times the cell's carried share, channel / prior channel: exact where the same-time
  factors are constant on the cell (every cell, without same-time evidence);
* a carrying model on a polar lattice: the polar sub-cell rule above with the carried channels
  at the sub-cell centres;
* a model without paths (the polar banana) refuses earlier evidence in one line naming the CAT;
  the other models without carrying kernels refuse it in one line;
* cells without prior mass: the POD map there is that of the same-time searches alone (no
  path reaches them).
"""

from __future__ import annotations

import inspect
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..domains.grid import Grid
from ..domains.polar_lattice import PolarLattice
from ..engine.carried import carries, evaluate_carried
from ..engine.rasterise import MIN_MASS, rasterise, warn_uncovered
from ..engine.warp_runtime import WarpContext
from ..models.presence import grid_probabilities
from ..results import PolarRaster, Raster
from ..validate import BananagridError, positive_int
from .geometry import distance_to_track
from .packing import pack as pack_evidence
from .reports import BearingReport, Exclusion, PositionReport
from .searches import AreaSearch, RasterSearch, TrackSearch

__all__ = ["posterior", "cell_means", "finish_cells", "CellMeans", "Posterior", "PolarPosterior", "MIN_NORMALISER",
           "SUBDIVISIONS", "EVIDENCE_TYPES"]

#: Below this the evidence contradicts the prior: the searches would have found the target almost
#: surely, or a report lies where the prior holds no mass (the map would be rounding noise).
MIN_NORMALISER = 1e-12
#: Sub-cells per side of a cell on which a factor varies.
SUBDIVISIONS = 8
#: Sub-cell centres per evaluation of the prior's density (bounds the arrays' memory).
POINT_CHUNK = 2**18
#: Registry kinds whose map is an approximation without a path per parameter: earlier evidence
#: cannot be carried to the map's time through them, with the exact model to use instead.
NO_PATHS = {"polar": "bg.CAT (exact, a path per (a, omega))"}
EVIDENCE_TYPES = (AreaSearch, TrackSearch, RasterSearch, PositionReport, BearingReport, Exclusion)


@dataclass(frozen=True, repr=False)
class Posterior(Raster):
    """A posterior map on a grid: a :class:`~bananagrid.Raster` of cell probabilities (POC,
    ``quantity == "probability"``, summing to one over the grid; ``mass`` is the unnormalised
    sum of P_c f_c), with what the searches would have found.

    Attributes
    ----------
    pos : float
        Probability that the searches together would have detected the target, under the prior
        restricted to the grid and given the other evidence (land, reports): 1 - sum_c P_c f_c /
        sum_c P_c g_c, g_c the cell mean of the other evidence's product (with searches alone,
        1 - normaliser, and sum_c P_c POD_c / sum_c P_c).
    search_pos : tuple of float
        Each search's own POS (given the other evidence, not the other searches), in the order
        of the evidence's searches.
    pod : ndarray, shape (ny, nx)
        The cumulative POD of each cell: 1 - the density-weighted mean over the cell of the
        product of every search's 1 - POD (for earlier searches, of the paths that end in the
        cell: the probability that a target now in the cell would have been detected).
    normaliser : float
        sum_c P_c f_c / sum_c P_c: the probability of the evidence under the prior (for searches
        alone, 1 - pos), with reports' likelihoods scaled to a peak of at most one.
    prior : ndarray, shape (ny, nx)
        The prior's cell probabilities P_c.
    """

    pos: float = math.nan
    search_pos: tuple = ()
    pod: np.ndarray | None = field(default=None, repr=False)
    normaliser: float = math.nan
    prior: np.ndarray | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        """The map's line (never the values) and what the searches would have found."""
        return f"Posterior({super().__repr__()}, POS {self.pos:.6g}, normaliser {self.normaliser:.6g})"


@dataclass(frozen=True, repr=False)
class PolarPosterior(PolarRaster):
    """A posterior on a polar lattice: ``probability`` holds the posterior cell probabilities
    (summing to one), ``density`` the prior's density at the cell centres times the cells'
    f_c / normaliser; attributes as :class:`Posterior`."""

    pos: float = math.nan
    search_pos: tuple = ()
    pod: np.ndarray | None = field(default=None, repr=False)
    normaliser: float = math.nan
    prior: np.ndarray | None = field(default=None, repr=False)


def posterior(prior, grid, evidence=(), *, subdivisions: int = SUBDIVISIONS, threads=None):
    """The posterior cell probabilities of ``prior`` on ``grid`` after ``evidence``, at the
    prior's own time.

    Parameters
    ----------
    prior : model
        A CAT, PolarBanana, Butterly, BearingFix, GaussianMixture (2-D) or UniformPresence
        (2-D), or any model of the protocol with cell probabilities. A model with a time ``t``
        is the target's position law at ``t``; one without (the presence laws, a bearing fix) is
        a stationary target's, at every time.
    grid : Grid or PolarLattice
    evidence : sequence
        :class:`AreaSearch`, :class:`TrackSearch`, :class:`RasterSearch`,
        :class:`PositionReport`, :class:`BearingReport`, :class:`Exclusion`. A search or report
        whose time span holds the prior's ``t`` is evidence at the map's time; the target is
        taken to stay where it is while a search lasts. Evidence that ends before ``t`` is
        carried along the paths of a model that carries it (the CAT; module docstring) and
        refused for the others; later evidence always.
    subdivisions : int, default 8
        Sub-cells per side of a cell that a polygon or a definite-range corridor cuts (half as
        many where only smooth factors vary; module docstring).
    threads : int, optional
        CPU threads of the prior's cell probabilities.

    Returns
    -------
    Posterior or PolarPosterior

    Raises
    ------
    BananagridError
        Evidence of the wrong type, at a time the map cannot take, or contradicting the prior
        (normaliser below :data:`MIN_NORMALISER`).
    """
    n = positive_int("subdivisions", subdivisions)
    evidence, earlier = _checked_evidence(prior, evidence)
    carried = _Carried(prior, evidence, earlier, threads) if earlier else None
    if isinstance(grid, PolarLattice):
        return _polar_posterior(prior, grid, evidence, n, threads, carried)
    return finish_cells(_grid_cell_means(prior, grid, evidence, n, threads, carried))


@dataclass(frozen=True)
class CellMeans:
    """The cell-by-cell half of a posterior on a grid (:func:`cell_means`): every array is the
    cells' own (a cell's values depend on that cell alone), so a grid's blocks give the whole
    grid's cells; :func:`finish_cells` is the reduction (the normaliser, POS, the map).

    Attributes
    ----------
    grid : Grid
    frame : GeoFrame or None
    cells : ndarray (ny, nx)
        The prior's cell probabilities P_c.
    means : dict
        f_c of each combination of the evidence (``"all"``, ``"searches"``, ``"others"``,
        ``("search", k)`` for the k-th evidence, a search): the density-weighted cell mean of
        its likelihood.
    evidence : list
    provenance : dict
        The prior's.
    boundary_mass : float or None
        The bound of the module docstring over these cells (None where a smooth factor varies).
    subdivisions : int
    """

    grid: Grid
    frame: object
    cells: np.ndarray
    means: dict
    evidence: list
    provenance: dict
    boundary_mass: float | None
    subdivisions: int


def cell_means(prior, grid, evidence=(), *, subdivisions: int = SUBDIVISIONS, threads=None,
               min_mass: float = MIN_MASS) -> CellMeans:
    """The cells' half of :func:`posterior` on a :class:`Grid` (arguments as there, checked the
    same way), before any sum over the grid: ``posterior(prior, grid, evidence)`` is
    ``finish_cells(cell_means(prior, grid, evidence))``. ``min_mass``: as for
    :func:`~bananagrid.rasterise` (0 for a block of a larger grid, which the whole grid's
    capture concerns, not the block's)."""
    n = positive_int("subdivisions", subdivisions)
    evidence, earlier = _checked_evidence(prior, evidence)
    carried = _Carried(prior, evidence, earlier, threads) if earlier else None
    return _grid_cell_means(prior, grid, evidence, n, threads, carried, min_mass)


def finish_cells(parts: CellMeans) -> Posterior:
    """The posterior of :func:`cell_means`' cells: the normaliser, POS, each search's POS, the
    POD map and the cells' posterior probabilities (raises where the evidence contradicts the
    prior, as :func:`posterior`)."""
    return _finish(Posterior, dict(grid=parts.grid, frame=parts.frame), parts.cells, parts.means, parts.evidence,
                   parts.provenance, parts.boundary_mass, parts.subdivisions)


def _grid_cell_means(prior, grid, evidence, n, threads, carried=None, min_mass=MIN_MASS) -> CellMeans:
    earlier = set() if carried is None else carried.earlier
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid Grid or PolarLattice")
    # a model whose carried cells' prior channel is its plain cell rule (the CAT's): one run gives
    # both; a model that takes the prior's cells instead (for the cells no weighted path reaches:
    # Butterly's) gets them first
    plan = None
    if carried is not None and not carried.takes_prior_cells:
        plan = carried.cell_plan(grid, None)
    if plan is not None:
        cells, provenance, frame, channel_cells, plan_notes = _carried_prior(prior, grid, plan, carried, threads,
                                                                             min_mass)
    else:
        cells, provenance, frame = _grid_prior(prior, grid, threads, min_mass)
        if carried is not None:
            plan = carried.cell_plan(grid, cells)
            if plan is not None:
                channel_cells, plan_notes = plan.run(WarpContext(np.float64, "cpu", threads))
                channel_cells = np.asarray(channel_cells, dtype=float)
    ny, nx = grid.shape
    x_edges = grid.origin[0] + grid.dx * np.arange(nx + 1)
    y_edges = grid.origin[1] + grid.dy * np.arange(ny + 1)
    factors = [_CarriedFactor(grid.shape) if k in earlier else _GridFactor(e, grid, x_edges, y_edges)
               for k, e in enumerate(evidence)]
    varying = np.zeros((ny, nx), dtype=bool)
    for factor in factors:
        varying |= factor.varying
    combos = _combos(evidence)
    # each combination's cell means (f_c of its product); the cells no factor varies on first
    means = {key: _product([factors[k].constant for k in members], (ny, nx)) for key, members in combos.items()}
    # cells with prior mass by the sub-cell rule: n x n where a polygon or a corridor cuts them,
    # half that where only smooth factors vary (a quarter of the density evaluations); cells
    # without prior mass (their posterior is 0 whatever the rule) by the cell itself, for the POD map
    cut = np.zeros((ny, nx), dtype=bool)
    for factor in factors:
        if factor.indicator:
            cut |= factor.varying
    groups = ((varying & cut & (cells > 0.0), n, True), (varying & ~cut & (cells > 0.0), max(1, n // 2), True),
              (varying & ~(cells > 0.0), 1, False))
    if carried is not None:
        # the carried weight varies on every cell with prior mass: each by the sub-cell rule on
        # the carried density's channels (module docstring); cells without mass as before.
        # With the model's own carried cells, the same-time factors' means as without evidence
        # before t, times each cell's carried share below
        if plan is None:
            groups = ((cells > 0.0, n, True), (varying & ~(cells > 0.0), 1, False))
    for mask, subdivide, weighted in groups:
        rows, cols = np.nonzero(mask)
        if rows.size:
            found = _varying_means(prior, factors, combos, x_edges, y_edges, rows, cols, subdivide, weighted,
                                   carried if weighted and plan is None else None)
            for key in combos:
                means[key][rows, cols] = found[key]
    bound = None if carried is not None else _boundary_mass(factors, cells, varying)
    if carried is not None:
        notes = carried.notes(n)
        if plan is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                share = channel_cells / channel_cells[carried.prior_channel]
            share = np.where(channel_cells[carried.prior_channel] > 0.0, share, 1.0)
            for key in combos:
                means[key] = means[key] * share[carried.index(key)]
            notes = {**notes, "cell_rule": plan.method, **plan_notes}
        provenance = {**provenance, "carried": notes}
    return CellMeans(grid, frame, cells, means, evidence, provenance, bound, n)


class _Carried:
    """The evidence before the prior's time, packed, and which of the pack's channels serves
    each combination of :func:`_combos` (the same-time factors multiply it)."""

    def __init__(self, prior, evidence, earlier, threads):
        keys = [f"evidence[{k}]" for k in earlier]
        self.pack = pack_evidence([evidence[k] for k in earlier], prior.t, keys=keys)
        self.prior, self.threads, self.earlier = prior, threads, set(earlier)
        self.channel = {"all": "all", "searches": "searches", "others": "others"}
        for k, e in enumerate(evidence):
            if e.kind == "search":
                self.channel[("search", k)] = f"search:evidence[{k}]" if k in earlier else "others"
        self.prior_channel = self.pack.channel("prior")

    def channels(self, x, y) -> np.ndarray:
        """Every channel at the points (x, y): shape (C, *x.shape)."""
        return evaluate_carried(self.prior, x, y, self.pack, threads=self.threads)

    def index(self, key) -> int:
        return self.pack.channel(self.channel[key])

    def cell_plan(self, grid, cells):
        """The model's own rule for the carried channels' cell masses (``carried_cell_plan``),
        or None; ``cells`` (the prior's cell probabilities) passed on where the model takes
        them (``prior_cells``: for the cells no weighted path crosses)."""
        own = getattr(self.prior, "carried_cell_plan", None)
        if not callable(own):
            return None
        if self.takes_prior_cells:
            return own(grid, self.pack, prior_cells=cells)
        return own(grid, self.pack)

    @property
    def takes_prior_cells(self) -> bool:
        """Whether the model's ``carried_cell_plan`` takes the prior's cells (``prior_cells``)."""
        own = getattr(self.prior, "carried_cell_plan", None)
        return callable(own) and "prior_cells" in inspect.signature(own).parameters

    def notes(self, n) -> dict:
        return {"evidence": list(self.pack.factor_keys), "time_nodes": self.pack.nodes,
                "cell_rule": f"carried density's channels at the midpoints of {n} x {n} sub-cells"}


class _CarriedFactor:
    """A factor carried by the kernels: 1 in the same-time products."""

    def __init__(self, shape):
        self.constant = np.ones(shape)
        self.varying = np.zeros(shape, dtype=bool)
        self.regions, self.low, self.indicator = None, 1.0, True


def _combos(evidence) -> dict:
    """The products whose cell means the posterior needs, as lists of evidence indices: all of
    them, the searches (the POD map), the rest (reports, land: what POS is conditioned on),
    and each search with the rest (its own POS)."""
    searches = [k for k, e in enumerate(evidence) if e.kind == "search"]
    others = [k for k, e in enumerate(evidence) if e.kind != "search"]
    combos = {"all": list(range(len(evidence))), "searches": searches, "others": others}
    combos.update({("search", k): [k, *others] for k in searches})
    return combos


def _product(arrays, shape):
    out = np.ones(shape)
    for a in arrays:
        out = out * a
    return out


def _finish(cls, where, cells, means, evidence, provenance, bound, n):
    mass = float(np.sum(cells))
    if not mass > 0.0:
        raise BananagridError("grid: the prior holds no mass on it; the posterior needs the prior's support")
    q = cells * means["all"]
    q_sum = float(np.sum(q))
    normaliser = q_sum / mass
    if not normaliser >= MIN_NORMALISER:
        raise BananagridError(
            f"evidence: the probability of the evidence under the prior is {normaliser:.3g}, below "
            f"{MIN_NORMALISER:g}; the evidence contradicts the prior (the searches would almost surely have found "
            "the target, or a report lies where the prior holds no mass); check the evidence's places and times")
    # POS given the other evidence (land, reports): 1 - P(no search finds it, others) / P(others)
    given = float(np.sum(cells * means["others"]))
    pos = 1.0 - q_sum / given
    searches = [key[1] for key in means if isinstance(key, tuple)]
    search_pos = tuple(1.0 - float(np.sum(cells * means[("search", k)])) / given for k in searches)
    pod = 1.0 - means["searches"]
    info = {"pos": pos, "search_pos": list(search_pos), "normaliser": normaliser, "prior_mass": mass,
            "boundary_mass": bound, "subdivisions": n, "evidence": [e.describe() for e in evidence]}
    provenance = {**provenance, "posterior": info}
    common = dict(pos=pos, search_pos=search_pos, pod=pod, normaliser=normaliser, prior=cells,
                  provenance=provenance, normalised=True, mass=q_sum)
    if cls is Posterior:
        return Posterior(values=q / q_sum, quantity="probability", **where, **common)
    return PolarPosterior(probability=q / q_sum, **where, **common)


def _checked_evidence(prior, evidence) -> list:
    if isinstance(evidence, EVIDENCE_TYPES):
        evidence = [evidence]
    try:
        evidence = list(evidence)
    except TypeError:
        raise BananagridError(f"evidence = {evidence!r}: expected a list of bananagrid evidence") from None
    t_map = getattr(prior, "t", None)
    earlier = []
    for k, e in enumerate(evidence):
        if not isinstance(e, EVIDENCE_TYPES):
            raise BananagridError(f"evidence[{k}] = {e!r}: expected one of "
                                  f"{', '.join('bg.' + c.__name__ for c in EVIDENCE_TYPES)}")
        span = e.time_span
        if span is None or t_map is None:
            continue  # land holds at every time; a stationary target's law at every time
        t0, t1 = span
        if t0 > t_map:
            raise BananagridError(f"evidence[{k}].t = {t0!r}: after the map's time t = {t_map!r}; evidence must not "
                                  "be later than the map it updates")
        if t1 < t_map:
            kind = getattr(prior, "kind", None)
            if carries(prior):
                earlier.append(k)
                continue
            if kind in NO_PATHS:
                raise BananagridError(
                    f"evidence[{k}].t = {t1!r}: earlier than the map's time t = {t_map!r}; {type(prior).__name__} is "
                    "an approximation with no path per parameter, so earlier evidence cannot be carried to t: use "
                    f"{NO_PATHS[kind]} or give evidence at t")
            raise BananagridError(
                f"evidence[{k}].t = {t1!r}: earlier than the map's time t = {t_map!r}; carrying earlier evidence "
                f"through {type(prior).__name__}'s paths is not yet available: give evidence at t")
    return evidence, earlier


def _carried_prior(prior, grid: Grid, plan, carried, threads, min_mass=MIN_MASS):
    """The carried channels' cell masses by the model's own rule (one run), and the prior's cell
    probabilities as their prior channel (the same rule, unweighted: the prior is not computed
    twice), with the provenance :func:`_grid_prior` gives, and the plan's notes (for the carried
    provenance too)."""
    ctx = WarpContext(np.float64, "cpu", threads)
    start = time.perf_counter()
    channel_cells, notes = plan.run(ctx)
    # every term is a positive weight times a normal mass (rounding may leave a few ulps below 0)
    channel_cells = np.maximum(np.asarray(channel_cells, dtype=float), 0.0)
    cells = channel_cells[carried.prior_channel]
    warn_uncovered(prior, float(np.sum(cells)), "grid", min_mass, stacklevel=5)
    provenance = {**prior.parameters(), "quantity": "probability", "dtype": "float64", "device": "cpu",
                  "threads": ctx.launch_threads, "seconds": time.perf_counter() - start, **notes}
    return cells, provenance, None, channel_cells, notes


def _grid_prior(prior, grid: Grid, threads, min_mass=MIN_MASS):
    """The prior's cell probabilities on ``grid``, its provenance and frame."""
    kind = getattr(prior, "kind", None)
    if not callable(getattr(prior, "bind", None)) and kind == "mixture":  # a presence law: its exact rectangles
        presence = grid_probabilities(prior, grid, threads=threads)
        return np.asarray(presence.probability, dtype=float), dict(presence.provenance), None
    if not callable(getattr(prior, "bind", None)) and kind == "uniform":
        return _uniform_cells(prior, grid), {"model": type(prior).__name__, **prior.parameters()}, None
    raster = rasterise(prior, grid, quantity="probability", threads=threads, min_mass=min_mass)
    return np.asarray(raster.values, dtype=float), dict(raster.provenance), raster.frame


def _uniform_cells(law, grid: Grid) -> np.ndarray:
    """Exact cell probabilities of a law uniform on a box: overlap area / box area."""
    if law.dim != 2:
        raise BananagridError(f"prior: a {law.dim}-D uniform law; a map on a grid needs a 2-D one")
    (bx0, bx1), (by0, by1) = law.region.bounds[0], law.region.bounds[1]
    xe = grid.origin[0] + grid.dx * np.arange(grid.nx + 1)
    ye = grid.origin[1] + grid.dy * np.arange(grid.ny + 1)
    wx = np.clip(np.minimum(xe[1:], bx1) - np.maximum(xe[:-1], bx0), 0.0, None)
    wy = np.clip(np.minimum(ye[1:], by1) - np.maximum(ye[:-1], by0), 0.0, None)
    return np.outer(wy, wx) / ((bx1 - bx0) * (by1 - by0))


class _GridFactor:
    """One evidence's factor on a grid: its value on the cells where it is constant, which
    cells it varies on, its mean over sub-cells, and its bounds on a varying cell."""

    def __init__(self, e, grid: Grid, x_edges, y_edges):
        self.e = e
        shape = grid.shape
        if isinstance(e, (AreaSearch, Exclusion)):
            regions = [e.region] if isinstance(e, AreaSearch) else list(e.regions)
            self.regions, self.low = regions, e.miss
            self.constant = np.ones(shape)
            self.varying = np.zeros(shape, dtype=bool)
            for region in regions:
                touched = region.cells_touched(x_edges, y_edges)
                inside = region.contains_grid(grid.x, grid.y) & ~touched
                # a touched cell whose exact fraction is 0 or 1 (an edge along its side) is not cut
                i, j = np.nonzero(touched)
                share = region.fraction(x_edges[j], x_edges[j + 1], y_edges[i], y_edges[i + 1])
                whole = (share == 0.0) | (share == 1.0)
                touched[i[whole], j[whole]] = False
                inside[i[whole], j[whole]] = share[whole] == 1.0
                self.constant = np.where(inside, self.constant * self.low, self.constant)
                self.varying |= touched
            self.indicator = True
        elif isinstance(e, TrackSearch) and e.law == "definite":
            # the corridor's edge is within half a diagonal of a cell centre it crosses
            half_diagonal = 0.5 * math.hypot(grid.dx, grid.dy)
            xc, yc = np.meshgrid(grid.x, grid.y)
            dist = distance_to_track(np.column_stack((xc.ravel(), yc.ravel())), e.track[:, :2]).reshape(shape)
            w2 = 0.5 * e.sweep_width
            self.varying = np.abs(dist - w2) <= half_diagonal * (1.0 + 1e-9)
            self.constant = np.where(dist < w2, 0.0, 1.0)
            self.regions, self.low, self.indicator = None, 0.0, True
        else:
            self.varying = np.ones(shape, dtype=bool)
            self.constant = np.ones(shape)
            self.regions, self.low, self.indicator = None, 0.0, False

    def sub_means(self, x0, x1, y0, y1) -> np.ndarray:
        """The factor's mean over each sub-rectangle: exact for polygons, the centre's value else."""
        if self.regions is not None:
            out = np.ones(x0.shape)
            for region in self.regions:
                out = out * (1.0 - (1.0 - self.low) * region.fraction(x0, x1, y0, y1))
            return out
        return self.e.likelihood(0.5 * (x0 + x1), 0.5 * (y0 + y1))


def _varying_means(prior, factors, combos, x_edges, y_edges, rows, cols, n, weighted: bool, carried=None) -> dict:
    """Means over each cell (``rows``, ``cols``) on n x n sub-cells of each combination's
    product of factors (:func:`_combos`): weighted by the prior's density at the sub-cell
    centres (``weighted``), else by area (cells without prior mass, for the POD map). A factor
    is evaluated on the sub-cells of the cells it varies on; elsewhere it is its constant.
    With ``carried`` (a :class:`_Carried`) the combination's carried channel at the sub-cell
    centres weighs its same-time product, over the sum of the prior channel there."""
    k_cells = rows.size
    dx = x_edges[1] - x_edges[0]
    dy = y_edges[1] - y_edges[0]
    u = np.arange(n)
    out = {key: np.empty(k_cells) for key in combos}
    per_chunk = max(1, POINT_CHUNK // (n * n))
    for start in range(0, k_cells, per_chunk):
        sl = slice(start, min(start + per_chunk, k_cells))
        r, c = rows[sl], cols[sl]
        # sub-cell edges from the cell's own edges (the last sub-cell ends on the cell's edge)
        sx = x_edges[c][:, None] + dx * u[None, :] / n
        sx1 = np.where(u[None, :] == n - 1, x_edges[c + 1][:, None], x_edges[c][:, None] + dx * (u[None, :] + 1) / n)
        sy = y_edges[r][:, None] + dy * u[None, :] / n
        sy1 = np.where(u[None, :] == n - 1, y_edges[r + 1][:, None], y_edges[r][:, None] + dy * (u[None, :] + 1) / n)
        shape = (len(r), n * n)
        x0 = np.broadcast_to(sx[:, None, :], (len(r), n, n)).reshape(shape)
        x1 = np.broadcast_to(sx1[:, None, :], (len(r), n, n)).reshape(shape)
        y0 = np.broadcast_to(sy[:, :, None], (len(r), n, n)).reshape(shape)
        y1 = np.broadcast_to(sy1[:, :, None], (len(r), n, n)).reshape(shape)
        channels = None
        if carried is not None:
            channels = carried.channels(0.5 * (x0 + x1), 0.5 * (y0 + y1))
            weights, bad = _checked_weights(channels[carried.prior_channel])
        else:
            weights = _weights(prior, 0.5 * (x0 + x1), 0.5 * (y0 + y1)) if weighted else np.ones(shape)
        values = []
        for f in factors:
            m = np.repeat(f.constant[r, c][:, None], n * n, axis=1)
            here = f.varying[r, c]
            if here.any():
                m[here] = f.sub_means(x0[here], x1[here], y0[here], y1[here])
            values.append(m)
        for key, members in combos.items():
            same = _product([values[k] for k in members], shape)
            if channels is None:
                out[key][sl] = _weighted(weights, same)
            else:
                # a row with no positive prior channel (mass between the centres): the same-time
                # factors' area mean, the carried weight taken as 1 there
                part = np.where(bad[:, None], same, channels[carried.index(key)] * same)
                out[key][sl] = np.sum(part, axis=1) / np.sum(weights, axis=1)
    return out


def _weights(prior, x, y) -> np.ndarray:
    """The prior's density at sub-cell centres, rows of cells; a row with no finite positive
    weight (a cell whose mass sits between the centres, or on an infinite caustic) gets equal
    weights, so that its mean is the plain area mean."""
    w = np.asarray(prior.pdf(x.ravel(), y.ravel()), dtype=float).reshape(x.shape)
    return _checked_weights(w)[0]


def _checked_weights(w):
    """``w`` with each row that has no finite positive weight set to ones, and those rows."""
    bad = ~np.isfinite(w).all(axis=1) | ~(np.sum(np.where(np.isfinite(w), w, 0.0), axis=1) > 0.0)
    return np.where(bad[:, None], 1.0, w), bad


def _weighted(weights, values) -> np.ndarray:
    return np.sum(weights * values, axis=1) / np.sum(weights, axis=1)


def _boundary_mass(factors, cells, varying) -> float | None:
    """sum over varying cells of P_c (prod of the factors' highs - prod of their lows) when
    every varying factor is an indicator (polygons, definite corridors), else None (no bound
    without bounds of the smooth factors on each cell)."""
    if not all(f.indicator for f in factors if f.varying.any()):
        return None
    high = np.ones(cells.shape)
    low = np.ones(cells.shape)
    for f in factors:
        high = high * np.where(f.varying, 1.0, f.constant)
        low = low * np.where(f.varying, f.low, f.constant)
    return float(np.sum(np.where(varying, cells * (high - low), 0.0)))


def _polar_posterior(prior, lattice: PolarLattice, evidence, n, threads, carried=None):
    """On a polar lattice: every cell by the rule of n x n sub-cells in (range, bearing), each
    weighted by its exact area times the density at its centre, each factor at the centre
    (with ``carried``: each combination's carried channel at the centre, the same-time
    factors' product, over the prior channel's sum)."""
    presence = not callable(getattr(prior, "bind", None)) and getattr(prior, "kind", None) in ("mixture", "uniform")
    if presence:  # a presence law has no polar kernels: its cells by the sub-cell rule below
        xc, yc = lattice.world_centres
        raster = PolarRaster(density=np.asarray(prior.pdf(xc.ravel(), yc.ravel()), dtype=float).reshape(xc.shape)
                             * lattice.range_centres[:, None], probability=np.zeros(lattice.shape), lattice=lattice,
                             mass=0.0, provenance={"model": type(prior).__name__, **prior.parameters(),
                                                   "cell_method": f"midpoint rule on {n} x {n} sub-cells"})
        cells = np.ones(lattice.shape)  # every cell weighted by the density below
    else:
        raster = rasterise(prior, lattice, threads=threads)
        cells = np.asarray(raster.probability, dtype=float)
    re, be = lattice.range_edges, lattice.bearing_edges
    # sub-cell edges along each axis
    sub_r = np.concatenate([np.linspace(re[i], re[i + 1], n + 1)[:-1] for i in range(len(re) - 1)] + [re[-1:]])
    sub_b = np.concatenate([np.linspace(be[j], be[j + 1], n + 1)[:-1] for j in range(len(be) - 1)] + [be[-1:]])
    rc, bc = 0.5 * (sub_r[1:] + sub_r[:-1]), 0.5 * (sub_b[1:] + sub_b[:-1])
    ring = 0.5 * (sub_r[1:] - sub_r[:-1]) * (sub_r[1:] + sub_r[:-1])
    area = ring[:, None] * np.diff(sub_b)[None, :]
    x, y = lattice.to_world(rc[:, None], bc[None, :])
    nr, nb = lattice.shape
    # the density where the prior has mass (elsewhere the posterior is 0: area weights, for the POD map)
    has_mass = np.repeat(np.repeat(cells > 0.0, n, axis=0), n, axis=1)
    w = np.zeros(x.shape)
    channels = None
    if carried is not None:
        channels = np.zeros((carried.pack.channels.shape[0], *x.shape))
        channels[:, has_mass] = carried.channels(x[has_mass], y[has_mass])
        channels = np.where(np.isfinite(channels), channels, 0.0) * area
        w[has_mass] = channels[carried.prior_channel][has_mass] / area[has_mass]
    else:
        w[has_mass] = np.asarray(prior.pdf(x[has_mass], y[has_mass]), dtype=float)
    w = np.where(np.isfinite(w), w, 0.0) * area

    def cell_sum(a):
        return a.reshape(nr, n, nb, n).sum(axis=(1, 3))

    w_cell = cell_sum(w)
    if presence:
        cells = w_cell  # the midpoint rule's cell probabilities: O((h / n)^2) of each cell's mass
    empty = ~(w_cell > 0.0)
    empty_sub = np.repeat(np.repeat(empty, n, axis=0), n, axis=1)
    w = np.where(empty_sub, area, w)  # no weight: the area mean
    w_cell = cell_sum(w)
    earlier = set() if carried is None else carried.earlier
    values = [np.ones(x.shape) if k in earlier else e.likelihood(x, y) for k, e in enumerate(evidence)]
    means = {}
    for key, members in _combos(evidence).items():
        weighted = w if channels is None else np.where(empty_sub, w, channels[carried.index(key)])
        means[key] = cell_sum(weighted * _product([values[k] for k in members], x.shape)) / w_cell
    where = dict(lattice=lattice, frame=raster.frame, density=raster.density)
    provenance = dict(raster.provenance)
    if carried is not None:
        provenance["carried"] = carried.notes(n)
    result = _finish(PolarPosterior, where, cells, means, evidence, provenance, None, n)
    return replace(result, density=np.asarray(raster.density, dtype=float) * means["all"] / result.normaliser)
