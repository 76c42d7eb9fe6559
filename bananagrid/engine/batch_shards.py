"""Many hypotheses across Dask workers: the batch kernels on shards of hypotheses.

:func:`rasterise_batch_shards` and :func:`pdf_batch_shards` cut the hypotheses into shards of
``shard`` consecutive hypotheses; each shard is one Dask task that runs
:func:`~bananagrid.engine.batch.rasterise_batch` (or ``pdf_batch``) on its hypotheses in the
worker, on one thread. The frames are computed once, for every hypothesis together, exactly as
the single-process batch computes them, so each hypothesis gets the same grid and the same
values bit for bit. The result is lazy: gather it (``compute``) or write it to Zarr
(:meth:`~bananagrid.results.ShardedBatch.to_zarr`) without holding it whole.
"""

from __future__ import annotations

import pickle
from collections.abc import Sequence

import numpy as np

from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..protocol import BatchModel
from ..results import ShardedBatch
from ..validate import BananagridError, positive_int
from .batch import FRAME_SDS, batch_models, frame_bounds, grids_in, pdf_batch, rasterise_batch
from .warp_runtime import WarpContext

__all__ = ["rasterise_batch_shards", "pdf_batch_shards", "DEFAULT_SHARD"]

#: Hypotheses per task: 4096 on 64 x 64 grids is 128 MiB of float64, about a second of one core.
DEFAULT_SHARD = 4096


def _shards(n: int, shard) -> list[tuple[int, int]]:
    shard = positive_int("shard", shard)
    return [(a, min(a + shard, n)) for a in range(0, n, shard)]


def _packed(models: list) -> bytes:
    """A shard's hypotheses as one pickle: Dask would otherwise walk every model (it unpacks
    dataclasses in a task's arguments, looking for collections), minutes for a million."""
    return pickle.dumps(models, protocol=pickle.HIGHEST_PROTOCOL)


def _grid_shard(packed: bytes, bounds: np.ndarray, shape: tuple[int, int], dtype: str, device: str) -> np.ndarray:
    models = pickle.loads(packed)
    return rasterise_batch(models, grids_in(bounds, shape), dtype=dtype, device=device, threads=1).values


def _points_shard(packed: bytes, x: np.ndarray, y: np.ndarray, dtype: str, device: str) -> np.ndarray:
    return pdf_batch(pickle.loads(packed), x, y, dtype=dtype, device=device, threads=1)


def rasterise_batch_shards(models: Sequence[BatchModel], *, shape=(64, 64), shard: int = DEFAULT_SHARD,
                           sds: float = FRAME_SDS, dtype=np.float64, device: str = "cpu") -> ShardedBatch:
    """Every hypothesis on its own framed grid (as :func:`~bananagrid.engine.batch.rasterise_batch`
    with ``grids=None``), lazily, ``shard`` hypotheses per Dask task.

    Returns
    -------
    ShardedBatch
        ``values``: a ``dask.array`` ``(H, ny, nx)`` in blocks of ``shard`` hypotheses, equal bit
        for bit to the single-process batch; ``bounds``: each hypothesis' frame ``(H, 4)``.
    """
    da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    dask = require("dask", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    models = batch_models(models)
    ny, nx = positive_int("shape[0]", shape[0]), positive_int("shape[1]", shape[1])
    dtype = WarpContext(dtype, device, 1).dtype
    bounds = frame_bounds(models, sds)
    blocks = []
    for a, b in _shards(len(models), shard):
        task = dask.delayed(_grid_shard, pure=False)(_packed(models[a:b]), bounds[a:b], (ny, nx), dtype.name, device)
        blocks.append(da.from_delayed(task, shape=(b - a, ny, nx), dtype=dtype))
    return ShardedBatch(values=da.concatenate(blocks, axis=0), bounds=bounds, shape=(ny, nx))


def pdf_batch_shards(models: Sequence[BatchModel], x, y, *, shard: int = DEFAULT_SHARD, dtype=np.float64,
                     device: str = "cpu"):
    """The density of every point under every hypothesis (as
    :func:`~bananagrid.engine.batch.pdf_batch`), lazily: a ``dask.array`` ``(H, N)`` in blocks of
    ``shard`` hypotheses, equal bit for bit to the single-process result."""
    da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    dask = require("dask", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    models = batch_models(models)
    try:
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    except ValueError:
        raise BananagridError(f"x and y: shapes {np.shape(x)} and {np.shape(y)} do not broadcast") from None
    if not (np.isfinite(bx).all() and np.isfinite(by).all()):
        raise BananagridError("x, y: points must be finite (NaN or inf given)")
    dtype = WarpContext(dtype, device, 1).dtype
    bx, by = bx.ravel(), by.ravel()
    px, py = dask.delayed(bx, pure=True), dask.delayed(by, pure=True)  # sent once, not per shard
    blocks = []
    for a, b in _shards(len(models), shard):
        task = dask.delayed(_points_shard, pure=False)(_packed(models[a:b]), px, py, dtype.name, device)
        blocks.append(da.from_delayed(task, shape=(b - a, bx.size), dtype=dtype))
    return da.concatenate(blocks, axis=0)  # pure=False: tokenising a million models would cost seconds
