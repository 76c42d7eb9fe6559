"""Many hypotheses after the same evidence (a tracker's association step with searches, bearings
and reports): each hypothesis's posterior on its own grid, and the probability of the evidence
under each, which reweighs the hypotheses.

:func:`posterior_batch` takes H priors (any kinds; each on its own grid, or framed about it as
:func:`bananagrid.engine.batch.frame` frames a batch kind's hypotheses) and one list of evidence,
and returns a :class:`BatchPosterior`: for every hypothesis the cells of
:func:`~bananagrid.evidence.posterior.cell_means` (the same rules as ``bg.posterior``, so each
hypothesis's map, POS and normaliser are ``bg.posterior``'s to rounding) reduced with
:func:`~bananagrid.evidence.tiled.posterior_numbers`, hypotheses in parallel on a thread pool.

A hypothesis the evidence rules out (its normaliser below
:data:`~bananagrid.evidence.posterior.MIN_NORMALISER`: the searches would almost surely have
found it, or a report lies where it holds no mass) does not stop the batch: it is flagged in
``ruled_out``, its normaliser kept (what reweighs it to nothing) and its map left at 0 rather
than rounding noise. :func:`posterior_batch_shards` runs shards of hypotheses as Dask tasks.
"""

from __future__ import annotations

import pickle
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..domains.grid import Grid
from ..engine.batch import FRAME_SDS, batch_grids
from ..engine.warp_runtime import default_threads
from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..validate import BananagridError, positive_int
from .posterior import MIN_NORMALISER, SUBDIVISIONS, cell_means
from .tiled import posterior_numbers

__all__ = ["posterior_batch", "posterior_batch_shards", "BatchPosterior", "DEFAULT_SHARD"]

#: Hypotheses per Dask task of :func:`posterior_batch_shards`.
DEFAULT_SHARD = 256


@dataclass(frozen=True)
class BatchPosterior:
    """H posteriors after the same evidence, each on its own grid of one shape.

    Attributes
    ----------
    values : ndarray (H, ny, nx)
        Each hypothesis's posterior cell probabilities (summing to one; 0 where ruled out).
    prior : ndarray (H, ny, nx)
        Its prior cell probabilities P_c.
    pod : ndarray (H, ny, nx)
        Its cumulative POD map.
    normaliser : ndarray (H,)
        The probability of the evidence under each hypothesis (restricted to its grid): the
        factor that reweighs it (with its prior mass ``prior_mass``).
    prior_mass : ndarray (H,)
    pos : ndarray (H,)
        Each hypothesis's POS (NaN where the other evidence leaves it no mass).
    search_pos : ndarray (H, S)
        Each search's own POS, S the searches in the evidence's order.
    ruled_out : ndarray of bool (H,)
        Hypotheses whose normaliser is below MIN_NORMALISER (or that hold no mass on their grid).
    grids : tuple of Grid
    """

    values: np.ndarray
    prior: np.ndarray
    pod: np.ndarray
    normaliser: np.ndarray
    prior_mass: np.ndarray
    pos: np.ndarray
    search_pos: np.ndarray
    ruled_out: np.ndarray
    grids: tuple

    def __repr__(self) -> str:
        h, ny, nx = self.values.shape
        return f"BatchPosterior({h:,} hypotheses on {ny} x {nx} grids, {int(self.ruled_out.sum())} ruled out)"


def _one(model, grid: Grid, evidence, n: int) -> tuple:
    """One hypothesis: its cells (``cell_means``, one thread) and the reduction."""
    parts = cell_means(model, grid, evidence, subdivisions=n, threads=1, min_mass=0.0)
    cells = parts.cells
    q = cells * parts.means["all"]  # as finish_cells forms it
    searches = [key for key in parts.means if isinstance(key, tuple)]
    numbers = posterior_numbers(float(np.sum(cells)), float(np.sum(q)), float(np.sum(cells * parts.means["others"])),
                                [float(np.sum(cells * parts.means[key])) for key in searches])
    out = not (numbers["prior_mass"] > 0.0 and numbers["normaliser"] >= MIN_NORMALISER)
    values = np.zeros_like(q) if out else q / numbers["mass"]
    return values, cells, 1.0 - parts.means["searches"], numbers, out


def _checked(models, evidence, grids, shape, sds, subdivisions) -> tuple:
    """The hypotheses, the evidence (checked as ``bg.posterior`` checks it, once per kind and
    time of hypothesis, before any computing: one line naming the hypothesis), their grids and
    the subdivisions."""
    models = list(models)
    if not models:
        raise BananagridError("models: expected at least one hypothesis")
    n = positive_int("subdivisions", subdivisions)
    grids = batch_grids(models, grids, shape, sds=sds)
    seen, checked = set(), None
    for k, (model, grid) in enumerate(zip(models, grids)):
        key = (type(model), getattr(model, "t", None))
        if key in seen:
            continue
        seen.add(key)
        try:  # on one cell of the hypothesis's grid: cheap
            checked = cell_means(model, Grid(origin=grid.origin, dx=grid.dx, dy=grid.dy, nx=1, ny=1), evidence,
                                 subdivisions=n, threads=1, min_mass=0.0).evidence
        except BananagridError as exc:
            raise BananagridError(f"models[{k}]: {exc}") from None
    return models, checked, grids, n


def posterior_batch(models: Sequence, evidence=(), grids: Sequence[Grid] | None = None, *, shape=(64, 64),
                    sds: float = FRAME_SDS, subdivisions: int = SUBDIVISIONS, threads=None) -> BatchPosterior:
    """Every hypothesis's posterior after ``evidence`` on its own grid.

    Parameters
    ----------
    models : sequence of models
        The hypotheses (priors as for :func:`bananagrid.posterior`).
    evidence : sequence
        As for :func:`bananagrid.posterior`, the same for every hypothesis (checked once, against
        each hypothesis's time).
    grids : sequence of Grid, optional
        One per hypothesis, all of one shape; by default each framed about its hypothesis at
        ``shape`` (``sds`` standard deviations; a kind with batch kernels,
        :func:`bananagrid.engine.batch.frame`).
    subdivisions : int, default 8
    threads : int, optional
        Hypotheses computed at once (default: every core).

    Returns
    -------
    BatchPosterior
    """
    models, evidence, grids, n = _checked(models, evidence, grids, shape, sds, subdivisions)
    workers = default_threads() if threads is None else positive_int("threads", threads)
    with ThreadPoolExecutor(max_workers=min(workers, len(models))) as pool:
        found = list(pool.map(lambda pair: _one(pair[0], pair[1], evidence, n), zip(models, grids)))
    return _assembled(found, grids)


def _assembled(found: list, grids: tuple) -> BatchPosterior:
    values, prior, pod, numbers, out = zip(*found)
    return BatchPosterior(
        values=np.stack(values), prior=np.stack(prior), pod=np.stack(pod),
        normaliser=np.array([f["normaliser"] for f in numbers]), prior_mass=np.array([f["prior_mass"] for f in numbers]),
        pos=np.array([f["pos"] for f in numbers]),
        search_pos=np.array([f["search_pos"] for f in numbers]).reshape(len(numbers), -1),
        ruled_out=np.array(out, dtype=bool), grids=tuple(grids))


def _shard(packed: bytes, n: int) -> BatchPosterior:
    models, grids, evidence = pickle.loads(packed)
    return _assembled([_one(m, g, evidence, n) for m, g in zip(models, grids)], grids)


def posterior_batch_shards(models: Sequence, evidence=(), grids: Sequence[Grid] | None = None, *, shape=(64, 64),
                           sds: float = FRAME_SDS, subdivisions: int = SUBDIVISIONS, shard: int = DEFAULT_SHARD):
    """:func:`posterior_batch` with ``shard`` hypotheses per Dask task (the hypotheses, their
    grids and the evidence pickled once per shard), gathered: the same :class:`BatchPosterior`,
    each hypothesis computed as in the single process."""
    dask = require("dask", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    shard = positive_int("shard", shard)
    models, evidence, grids, n = _checked(models, evidence, grids, shape, sds, subdivisions)
    tasks = [dask.delayed(_shard, pure=False)(pickle.dumps((models[a:a + shard], grids[a:a + shard], evidence),
                                                           protocol=pickle.HIGHEST_PROTOCOL), n)
             for a in range(0, len(models), shard)]
    parts = dask.compute(*tasks)
    return BatchPosterior(
        values=np.concatenate([p.values for p in parts]), prior=np.concatenate([p.prior for p in parts]),
        pod=np.concatenate([p.pod for p in parts]), normaliser=np.concatenate([p.normaliser for p in parts]),
        prior_mass=np.concatenate([p.prior_mass for p in parts]), pos=np.concatenate([p.pos for p in parts]),
        search_pos=np.concatenate([p.search_pos for p in parts]),
        ruled_out=np.concatenate([p.ruled_out for p in parts]), grids=tuple(grids))
