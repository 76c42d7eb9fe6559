"""Posteriors over grids too large for memory: the cells block by block on Dask, then one
reduction.

A posterior's cells are each their own: the prior's cell probability P_c and each combination's
cell mean f_c of the evidence's likelihood (:func:`~bananagrid.evidence.posterior.cell_means`;
the sub-cell rule, and the kernels' carried channels for evidence before the map's time) depend
on that cell alone. Only the normaliser is global. So :func:`posterior_tiles` makes each block
of ``chunks`` cells one Dask task that runs ``cell_means`` on the block's cells (the same rules,
on the block as a grid of its own), and the posterior is assembled from those arrays:

* the sums (one pass over the blocks, each summed in float64, then the blocks' sums):
  S_P = sum P_c, S_all = sum P_c f_all, S_others = sum P_c f_others, S_k = sum P_c f_(search k);
  normaliser = S_all / S_P, POS = 1 - S_all / S_others, each search's POS 1 - S_k / S_others,
  the formulas of :func:`~bananagrid.evidence.posterior.finish_cells`, with its refusal of a
  normaliser below :data:`~bananagrid.evidence.posterior.MIN_NORMALISER`;
* the posterior map, P_c f_all / S_all, block by block once S_all is known (a second pass: the
  normaliser is global);
* the POD map, 1 - f_searches: each cell's own, no sum.

:meth:`TiledPosterior.compute` gathers the cells into memory and finishes them with
``finish_cells``: the result is ``bg.posterior(prior, grid, evidence)`` to the rounding of the
prior's cell rules on a block's own grid (a block's cell edges are the grid's to an ulp).
:meth:`TiledPosterior.to_zarr` writes the prior's and the posterior's cell probabilities to a
Zarr store block by block, whole or not at all (:func:`bananagrid.geo.zarr_store.write_zarr`),
in one pass that computes the cells and the sums together (the stored posterior is divided by
its sum after it).
A model whose kernels depend on the grid's extent (the CAT with heading noise tabulates its
density over each grid) gives a block its own table: the tiled map then agrees with the whole
grid's within that table's interpolation error (1e-6 relative), not to rounding.

**Only the support costs** (``skip=True``): a block where the prior proves its density at most
its floor (:meth:`~bananagrid.protocol.DensityModel.density_bound` over the block's cells, at most
:meth:`~bananagrid.protocol.DensityModel.density_floor`, 1e-13 of the peak) runs no prior cell
rule: its prior cells are taken as 0 (each holds at most the floor times the cell's area), so its
posterior is 0, and its POD map is what ``cell_means`` gives cells without prior mass, the area
mean over each cell of the same-time searches' product (a search before the map's time reaches
such a cell along no path: factor 1). A block that no same-time search's polygon (or corridor)
reaches is a constant (POD 0) that holds no memory. The POD map is :attr:`TiledPosterior.pod`
(lazy; a store does not hold it: the dataset's layers are densities, and a POD is not one).
"""

from __future__ import annotations

import math
import uuid
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..domains.grid import Grid
from ..engine.rasterise import MIN_MASS
from ..engine.tiles import DEFAULT_CHUNK, check_chunks
from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..geo.dataset import raster_dataset
from ..geo.zarr_store import check_store_target, compute_with_progress, scale_stored, write_zarr
from ..results import TiledRaster
from ..validate import BananagridError, BananagridWarning
from ..domains.region import Region
from ..models.presence import UniformPresence
from .posterior import MIN_NORMALISER, SUBDIVISIONS, CellMeans, Posterior, cell_means, finish_cells
from .searches import AreaSearch, TrackSearch

__all__ = ["posterior_tiles", "TiledPosterior", "PosteriorMaps", "block_cells", "empty_block", "channel_names", "posterior_numbers",
           "check_normaliser", "block_grid"]


def channel_names(evidence) -> list:
    """The channels of a tiled posterior's cells, in order: ``"prior"`` (P_c), then the cell
    means f_c of ``"all"``, ``"searches"``, ``"others"`` and ``("search", k)`` for each search
    (k its index in ``evidence``), and ``"boundary"``: the block's boundary mass in its first
    cell (NaN where a smooth factor varies, so that it has none), 0 in the others (so that the
    blocks' sums are the sums of one array: no second collection, whose tasks Dask would
    compute again)."""
    return ["prior", "all", "searches", "others", *[("search", k) for k, e in enumerate(evidence) if e.kind == "search"],
            "boundary"]


def posterior_numbers(prior_mass: float, q_sum: float, given: float, search_sums) -> dict:
    """A posterior's global numbers from its sums (module docstring; the formulas of
    :func:`~bananagrid.evidence.posterior.finish_cells`): ``prior_mass`` S_P, ``mass`` S_all,
    ``normaliser`` S_all / S_P, ``pos`` 1 - S_all / S_others and ``search_pos`` 1 - S_k /
    S_others (NaN where S_P or S_others is 0: no prior mass, no POS)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        normaliser = float(np.float64(q_sum) / prior_mass)
        pos = float(1.0 - np.float64(q_sum) / given)
        search_pos = [float(1.0 - np.float64(s) / given) for s in search_sums]
    return {"prior_mass": prior_mass, "mass": q_sum, "normaliser": normaliser, "pos": pos, "search_pos": search_pos}


def check_normaliser(numbers: dict) -> None:
    """:func:`~bananagrid.evidence.posterior.finish_cells`' refusals, in its words: no prior
    mass on the grid, or evidence that contradicts the prior (normaliser below
    :data:`~bananagrid.evidence.posterior.MIN_NORMALISER`)."""
    if not numbers["prior_mass"] > 0.0:
        raise BananagridError("grid: the prior holds no mass on it; the posterior needs the prior's support")
    if not numbers["normaliser"] >= MIN_NORMALISER:
        raise BananagridError(
            f"evidence: the probability of the evidence under the prior is {numbers['normaliser']:.3g}, below "
            f"{MIN_NORMALISER:g}; the evidence contradicts the prior (the searches would almost surely have found "
            "the target, or a report lies where the prior holds no mass); check the evidence's places and times")


def block_grid(grid: Grid, rows, cols) -> Grid:
    """Rows ``rows[0]:rows[1]`` and columns ``cols[0]:cols[1]`` of ``grid`` as a grid of their own."""
    return Grid(origin=(grid.origin[0] + cols[0] * grid.dx, grid.origin[1] + rows[0] * grid.dy), dx=grid.dx,
                dy=grid.dy, nx=cols[1] - cols[0], ny=rows[1] - rows[0])


def block_cells(prior, grid: Grid, evidence, subdivisions: int, rows, cols) -> np.ndarray:
    """One block's channels (:func:`channel_names`), shape ``(C, rows, columns)`` float64:
    ``cell_means`` on the block's cells, on one thread (Dask runs the blocks in parallel)."""
    parts = cell_means(prior, block_grid(grid, rows, cols), evidence, subdivisions=subdivisions, threads=1,
                       min_mass=0.0)
    names = channel_names(evidence)
    out = np.empty((len(names), rows[1] - rows[0], cols[1] - cols[0]))
    out[0] = parts.cells
    for c, key in enumerate(names[1:-1], start=1):
        out[c] = parts.means[key]
    out[-1] = 0.0
    out[-1, 0, 0] = math.nan if parts.boundary_mass is None else parts.boundary_mass
    return out


def empty_block(grid: Grid, searches, subdivisions: int, rows, cols, names) -> np.ndarray:
    """A skipped block's channels (module docstring): prior 0, the searches' mean for the POD map
    (the means of the other combinations weigh a prior of 0: left at 1), boundary mass 0."""
    shape = (len(names), rows[1] - rows[0], cols[1] - cols[0])
    block = block_grid(grid, rows, cols)
    x0, x1, y0, y1 = block.extent
    reach = [e for e in searches if _may_reach(e, (x0, x1, y0, y1))]
    constant = np.ones(len(names))
    constant[0] = constant[-1] = 0.0
    if not reach:  # POD 0 on every cell: one value per channel seen as the block
        return np.broadcast_to(constant[:, None, None], shape)
    # the rules of cell_means for cells without prior mass, under a law with no mass on the block
    nowhere = UniformPresence(Region(x=(x1 + 1.0, x1 + 2.0), y=(y1 + 1.0, y1 + 2.0)))
    parts = cell_means(nowhere, block, reach, subdivisions=subdivisions, threads=1, min_mass=0.0)
    out = np.repeat(constant[:, None, None], shape[1] * shape[2], axis=1).reshape(shape)
    out[names.index("searches")] = parts.means["searches"]
    return out


def _may_reach(search, box) -> bool:
    """Whether ``search`` may detect anywhere in ``box``: an area search's polygon or a definite
    track's corridor whose bounding box meets it (others, smooth everywhere: True)."""
    x0, x1, y0, y1 = box
    if isinstance(search, AreaSearch):
        (a, b), (c, d) = search.polygon.min(axis=0), search.polygon.max(axis=0)
    elif isinstance(search, TrackSearch) and search.law == "definite":
        w = 0.5 * search.sweep_width
        (a, b), (c, d) = search.track[:, :2].min(axis=0) - w, search.track[:, :2].max(axis=0) + w
    else:
        return True
    return not (c < x0 or a > x1 or d < y0 or b > y1)




def _edges(n: int, chunk: int) -> list[tuple[int, int]]:
    return [(a, min(a + chunk, n)) for a in range(0, n, chunk)]


@dataclass(frozen=True)
class TiledPosterior:
    """A posterior on a grid, lazily, in blocks computed by Dask (:func:`posterior_tiles`).

    Attributes
    ----------
    channels : dask.array.Array, shape (C, ny, nx), float64
        Each cell's prior probability and cell means (:func:`channel_names`), in blocks of
        ``(C, *chunks)``.
    grid : Grid
    chunks : (int, int)
    evidence : list
    prior : model
    subdivisions : int
    provenance : dict
        The prior's, with the chunks and the blocks.
    frame : GeoFrame or None
    min_mass : float
        The whole grid's capture below which :meth:`numbers` and :meth:`compute` warn.
    skipped : ndarray of bool (blocks in y, blocks in x)
        Blocks where the prior was proved negligible (taken as 0; module docstring).
    """

    channels: object
    grid: Grid
    chunks: tuple
    evidence: list
    prior: object
    subdivisions: int
    provenance: dict = field(default_factory=dict)
    frame: object = None
    min_mass: float = MIN_MASS
    skipped: np.ndarray | None = None

    @property
    def names(self) -> list:
        return channel_names(self.evidence)

    def _channel(self, key):
        return self.channels[self.names.index(key)]

    @property
    def pod(self):
        """The cumulative POD map, 1 - f_searches: lazy, each cell's own."""
        return 1.0 - self._channel("searches")

    @property
    def unnormalised(self):
        """P_c f_all, each cell's posterior mass before the normaliser: lazy."""
        return self._channel("prior") * self._channel("all")

    def lazy_sums(self):
        """S_P, S_all, S_others, each search's S_k (module docstring) and the boundary mass,
        lazily: each computed block summed in float64, then the blocks' sums (a skipped block's
        prior is 0: no task)."""
        da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
        keys = ["all", "others", *[key for key in self.names if isinstance(key, tuple)]]
        index = [self.names.index(key) for key in keys]
        skipped = self.skipped if self.skipped is not None else np.zeros(self.channels.numblocks[1:], dtype=bool)
        per_block = []
        for i, j in zip(*np.nonzero(~skipped)):
            block = self.channels.blocks[0, i, j]
            prior = block[0]
            per_block.append(da.stack([prior.sum(dtype=np.float64)]
                                      + [(prior * block[c]).sum(dtype=np.float64) for c in index]
                                      + [block[-1].sum(dtype=np.float64)]))
        if not per_block:
            return [da.zeros((), dtype=np.float64)] * (2 + len(keys))
        total = da.stack(per_block).sum(axis=0)
        return [total[k] for k in range(2 + len(keys))]

    def numbers(self, *, progress: bool = False) -> dict:
        """The posterior's global numbers, from one pass over the blocks: ``prior_mass`` (S_P),
        ``mass`` (S_all), ``normaliser``, ``pos``, ``search_pos`` and ``boundary_mass``.

        Raises
        ------
        BananagridError
            The prior holds no mass on the grid, or the evidence contradicts it (normaliser
            below :data:`~bananagrid.evidence.posterior.MIN_NORMALISER`), as ``bg.posterior``.
        """
        return self.finish_sums(compute_with_progress(*self.lazy_sums(), progress=progress))

    def finish_sums(self, sums) -> dict:
        """:meth:`numbers` from the computed :meth:`lazy_sums` (several posteriors' sums computed
        in one pass, then each finished; raises as :meth:`numbers`)."""
        *sums, bound = (float(v) for v in sums)
        prior_mass, q_sum, given, *search_sums = sums
        self._covered(prior_mass)
        found = posterior_numbers(prior_mass, q_sum, given, search_sums)
        check_normaliser(found)
        return {**found, "boundary_mass": None if math.isnan(bound) else bound}

    def maps(self, numbers: dict | None = None, *, progress: bool = False) -> "PosteriorMaps":
        """The posterior's maps, lazy, with its global numbers (:meth:`numbers`, computed here
        unless given): what ``bg.posterior``'s :class:`~bananagrid.evidence.posterior.Posterior`
        holds, its maps as Dask arrays and its provenance's ``posterior`` entry with the same
        keys, so that :func:`~bananagrid.geo.dataset.raster_dataset` and
        :func:`~bananagrid.geo.zarr_store.write_zarr` take it as they take a ``Posterior``."""
        numbers = self.numbers(progress=progress) if numbers is None else numbers
        info = {"pos": numbers["pos"], "search_pos": list(numbers["search_pos"]), "normaliser": numbers["normaliser"],
                "prior_mass": numbers["prior_mass"], "boundary_mass": numbers["boundary_mass"],
                "subdivisions": self.subdivisions, "evidence": [e.describe() for e in self.evidence]}
        return PosteriorMaps(values=self.unnormalised / numbers["mass"], pod=self.pod, prior=self._channel("prior"),
                             grid=self.grid, pos=numbers["pos"], search_pos=tuple(numbers["search_pos"]),
                             normaliser=numbers["normaliser"], prior_mass=numbers["prior_mass"], mass=numbers["mass"],
                             provenance={**self.provenance, "posterior": info}, frame=self.frame)

    def _covered(self, prior_mass: float) -> None:
        """The whole grid's warning of ``bg.posterior`` (its prior's ``rasterise``) where it
        captures less than ``min_mass`` of a probability density (the blocks' own are off)."""
        if getattr(self.prior, "integrates_to_one", False) and prior_mass < self.min_mass:
            warnings.warn(
                f"posterior_tiles: the grid captured {prior_mass:.3g} of {type(self.prior).__name__}'s probability "
                f"(below {self.min_mass:g}): it misses part of the target; move or enlarge it, or check the "
                "parameters' units (min_mass=0 switches this off)", BananagridWarning, stacklevel=3)

    def compute(self) -> Posterior:
        """The whole posterior in memory (at most :data:`~bananagrid.domains.grid.MAX_CELLS`
        cells): the blocks' cells gathered and finished by ``finish_cells``, as ``bg.posterior``
        finishes the whole grid's."""
        self.grid.check_in_memory()
        channels = np.asarray(compute_with_progress(self.channels)[0])
        bound = float(np.sum(channels[-1]))
        bound = None if math.isnan(bound) else bound
        self._covered(float(np.sum(channels[0])))
        means = {key: channels[c] for c, key in enumerate(self.names) if 0 < c < len(self.names) - 1}
        return finish_cells(CellMeans(self.grid, self.frame, channels[0], means,
                                      list(self.evidence), dict(self.provenance), bound, self.subdivisions))

    def to_zarr(self, path, *, t: float | None = None, title: str = "", progress: bool = False):
        """Write the layers ``prior`` and ``posterior`` to the Zarr store ``path``, block by block,
        whole or not at all (:func:`bananagrid.geo.zarr_store.write_zarr`): each cell's
        probability as ``LAYER_probability`` (the posterior's summing to one) and, as the
        layer's density, that probability over the cell's area (the cell's mean density); the
        global numbers (:meth:`numbers`) in the provenance. One pass over the blocks computes
        the cells and the sums together; then the stored posterior is divided by its sum in place
        (the normaliser is global), before the store is put in place. Returns the path.

        Raises
        ------
        BananagridError
            As :func:`~bananagrid.geo.zarr_store.write_zarr`, and as :meth:`numbers` (evidence
            that contradicts the prior: no store is left).
        """
        final = check_store_target(path)  # before any computing
        t = float(getattr(self.prior, "t", 0.0) or 0.0) if t is None else t
        skipped = self.skipped if self.skipped is not None else np.zeros(self.channels.numblocks[1:], dtype=bool)
        area = self.grid.cell_area

        def layers(posterior, info):
            def layer(values, quantity, what):
                return TiledRaster(values=values, grid=self.grid, chunks=self.chunks, skipped=skipped,
                                   floor=-math.inf, provenance=dict(info, quantity=quantity, values=what),
                                   frame=self.frame, quantity=quantity)

            cells = {"prior": self._channel("prior"), "posterior": posterior}
            panels = [(name, t, layer(values / area, "density", "cell probability / cell area: the cell's mean "
                                      "density")) for name, values in cells.items()]
            return panels, {(name, t): layer(values, "probability", "cell probability") for name, values in cells.items()}

        def finish(group, sums) -> None:
            numbers = self.finish_sums(sums)
            info = {**self.provenance, "posterior": dict(numbers, subdivisions=self.subdivisions,
                                                          evidence=[e.describe() for e in self.evidence])}
            for name in ("posterior", "posterior_probability"):
                scale_stored(group, name, [numbers["mass"]], progress=progress)
            group["posterior_mass"][...] = group["posterior_mass"][...] / numbers["mass"]
            panels, cells = layers(self.unnormalised / numbers["mass"], info)
            complete = raster_dataset(panels, self.frame, title=title, cells=cells)  # nothing in it is computed
            for name, var in complete.data_vars.items():
                if "bananagrid_provenance" in var.attrs:
                    group[name].attrs["bananagrid_provenance"] = var.attrs["bananagrid_provenance"]

        # the posterior's cells before the normaliser, with the sums, in the store's one pass
        panels, cells = layers(self.unnormalised, dict(self.provenance))
        return write_zarr(final, panels, self.frame, title=title, progress=progress, cells=cells,
                          extra=self.lazy_sums(), finish=finish)

    def pending_maps(self) -> "PosteriorMaps":
        """The maps as one pass writes them before its sums are known: ``values`` the cells'
        posterior mass P_c f_all before the normaliser (to be divided by the sum S_all, which
        :meth:`maps` holds as ``mass``, once the pass has computed :meth:`lazy_sums`), the POD
        map as :meth:`maps`; the global numbers NaN, the provenance's ``posterior`` entry empty.
        Its blocks are computed once when the maps and the sums are computed together."""
        searches = sum(1 for key in self.names if isinstance(key, tuple))
        return PosteriorMaps(values=self.unnormalised, pod=self.pod, prior=self._channel("prior"), grid=self.grid,
                             pos=math.nan, search_pos=(math.nan,) * searches, normaliser=math.nan,
                             prior_mass=math.nan, mass=math.nan, provenance={**self.provenance, "posterior": {}},
                             frame=self.frame, normalised=False)

    def __repr__(self) -> str:
        g = self.grid
        blocks = len(self.channels.chunks[1]) * len(self.channels.chunks[2])
        skipped = 0 if self.skipped is None else int(self.skipped.sum())
        return (f"TiledPosterior({g.nx} x {g.ny} cells in {blocks} blocks of {self.chunks[0]} x {self.chunks[1]}, "
                f"{skipped} skipped, {len(self.evidence)} evidence, model {type(self.prior).__name__})")


@dataclass(frozen=True)
class PosteriorMaps:
    """A tiled posterior's maps, lazy, with its global numbers (:meth:`TiledPosterior.maps`):
    the attributes of :class:`~bananagrid.evidence.posterior.Posterior`, the maps Dask arrays in
    the posterior's blocks.

    Attributes
    ----------
    values : dask.array.Array (ny, nx)
        Posterior cell probabilities (POC), summing to one over the grid.
    pod : dask.array.Array (ny, nx)
        The cumulative POD of each cell.
    prior : dask.array.Array (ny, nx)
        The prior's cell probabilities P_c.
    grid : Grid
    pos, search_pos, normaliser
        As :class:`~bananagrid.evidence.posterior.Posterior`'s.
    prior_mass : float
        The sum of the prior's cells (S_P).
    mass : float
        The sum of the unnormalised posterior cells (S_all).
    provenance : dict
        The prior's, with the blocks, and ``posterior``: the keys ``bg.posterior`` writes there.
    frame : GeoFrame or None
    """

    values: object
    pod: object
    prior: object
    grid: Grid
    pos: float
    search_pos: tuple
    normaliser: float
    prior_mass: float
    mass: float
    provenance: dict = field(default_factory=dict)
    frame: object = None
    quantity: str = "probability"
    normalised: bool = True

    def __repr__(self) -> str:
        g = self.grid
        return f"PosteriorMaps({g.nx} x {g.ny} cells, lazy, POS {self.pos:.6g}, normaliser {self.normaliser:.6g})"


def posterior_tiles(prior, grid: Grid, evidence=(), chunks=DEFAULT_CHUNK, *, subdivisions: int = SUBDIVISIONS,
                    min_mass: float = MIN_MASS, skip: bool = True) -> TiledPosterior:
    """The posterior of ``prior`` on ``grid`` after ``evidence`` (as :func:`bananagrid.posterior`),
    lazily, in blocks of ``chunks`` cells on Dask (the ``cluster`` extra).

    Parameters
    ----------
    prior, evidence, subdivisions
        As for :func:`bananagrid.posterior`, checked the same way before anything runs.
    grid : Grid
    chunks : int or (int, int), default 1024
        Block shape ``(rows, columns)``: any (each cell's rule is its own).
    min_mass : float, default 0.99
        As for :func:`bananagrid.rasterise`, of the whole grid (warned when the sums are
        computed).
    skip : bool, default True
        Take the prior as 0 on the blocks where it proves its density at most its floor, with
        no prior cell rule run there (module docstring); False computes every block.

    Returns
    -------
    TiledPosterior
    """
    da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    dask = require("dask", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid.Grid")
    cy, cx = check_chunks(chunks, grid)
    # every check of bg.posterior, now, on the grid's first cell (cheap: one cell's rules)
    if isinstance(min_mass, bool) or not isinstance(min_mass, (int, float)) or not 0.0 <= min_mass <= 1.0:
        raise BananagridError(f"min_mass = {min_mass!r}: must be a number in [0, 1] (0 switches the warning off)")
    first = cell_means(prior, block_grid(grid, (0, 1), (0, 1)), evidence, subdivisions=subdivisions, threads=1,
                       min_mass=0.0)
    evidence, n = first.evidence, first.subdivisions
    names = channel_names(evidence)
    token = uuid.uuid4().hex[:8]
    rows_of, cols_of = _edges(grid.ny, cy), _edges(grid.nx, cx)
    floor = prior.density_floor() if skip and callable(getattr(prior, "density_floor", None)) else -math.inf
    skipped = np.zeros((len(rows_of), len(cols_of)), dtype=bool)
    t_map = getattr(prior, "t", None)
    same = [e for e in evidence if e.kind == "search"
            and (t_map is None or e.time_span is None or e.time_span[1] >= t_map)]
    blocks = []
    for i, rows in enumerate(rows_of):
        line = []
        for j, cols in enumerate(cols_of):
            if floor > -math.inf:  # over the block's whole cells, edges included
                x0, x1, y0, y1 = block_grid(grid, rows, cols).extent
                skipped[i, j] = prior.density_bound(x0, x1, y0, y1) <= floor
            name = f"bananagrid-posterior-{token}-{rows[0]}-{cols[0]}"
            if skipped[i, j]:
                task = dask.delayed(empty_block, pure=True)(grid, same, n, rows, cols, names, dask_key_name=name)
            else:
                task = dask.delayed(block_cells, pure=True)(prior, grid, evidence, n, rows, cols, dask_key_name=name)
            shape = (len(names), rows[1] - rows[0], cols[1] - cols[0])
            line.append(da.from_delayed(task, shape=shape, dtype=np.float64))
        blocks.append(line)
    channels = da.block(blocks)
    provenance = {**first.provenance, "chunks": [cy, cx], "tiles": int(skipped.size),
                  "tiles_skipped": int(skipped.sum()), "zero_at_or_below": floor * grid.cell_area if skip else None}
    return TiledPosterior(channels=channels, grid=grid, chunks=(cy, cx),
                          skipped=skipped,
                          evidence=list(evidence), prior=prior, subdivisions=n, provenance=provenance,
                          frame=first.frame, min_mass=float(min_mass))
