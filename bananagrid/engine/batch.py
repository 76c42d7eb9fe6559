"""Many hypotheses at once (a tracker's gating and association step).

:func:`rasterise_batch` rasterises thousands of hypotheses of one model kind, each on its own
small grid framed about it, in one kernel over (hypothesis, row); :func:`pdf_batch` scores every
point against every hypothesis. A model kind takes part through two class methods of the model
protocol's batch capability (:class:`~bananagrid.protocol.BatchModel`): ``frame_bounds`` (the
world box holding each hypothesis) and ``batch_binding`` (its batch kernels). They run the same
device function as :func:`bananagrid.rasterise` and ``pdf``, so their values are bit-identical
to one hypothesis at a time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..domains.grid import Grid
from ..protocol import BatchModel
from ..results import BatchRaster
from ..validate import BananagridError, positive, positive_int
from .memory import check_memory
from .warp_runtime import WarpContext, row_sums

__all__ = ["frame", "batch_grids", "frame_bounds", "grids_in", "batch_models", "rasterise_batch", "pdf_batch", "FRAME_SDS"]

#: A framed grid holds each hypothesis to this many SDs in range and bearing.
FRAME_SDS = 4.0


def batch_grids(models: Sequence[BatchModel], grids=None, shape=(64, 64), *, sds: float = FRAME_SDS) -> tuple[Grid, ...]:
    """One grid per hypothesis, all of one shape: ``grids`` checked (one-line errors naming
    ``grids[k]``), or by default :func:`frame` of the hypotheses at ``shape`` and ``sds``."""
    if grids is None:
        return tuple(frame(models, shape, sds=sds))
    grids = tuple(grids)
    if len(grids) != len(models):
        raise BananagridError(f"grids: {len(grids)} grids for {len(models)} hypotheses")
    for k, g in enumerate(grids):
        if not isinstance(g, Grid):
            raise BananagridError(f"grids[{k}] = {g!r}: expected a bananagrid.Grid")
        if g.shape != grids[0].shape:
            raise BananagridError(f"grids[{k}]: shape {g.shape}, but grids[0] has {grids[0].shape}; one shape for all")
    return grids


def frame(models: Sequence[BatchModel], shape=(64, 64), *, sds: float = FRAME_SDS) -> list[Grid]:
    """Grids of ``shape`` = (ny, nx) cells framing each hypothesis: the world box that holds it
    to ``sds`` standard deviations (the model kind's ``frame_bounds``, vectorised over the
    hypotheses), cut into ``shape`` cells."""
    models = batch_models(models)
    return grids_in(frame_bounds(models, sds), _shape(shape))


def frame_bounds(models: Sequence[BatchModel], sds: float = FRAME_SDS) -> np.ndarray:
    """The world boxes ``(x0, x1, y0, y1)`` of :func:`frame`, shape ``(H, 4)``."""
    return type(models[0]).frame_bounds(models, positive("sds", sds))


def grids_in(bounds: np.ndarray, shape: tuple[int, int]) -> list[Grid]:
    """Grids of ``shape`` = (ny, nx) cells over each box ``(x0, x1, y0, y1)`` of ``bounds``:
    each ``Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / nx, dy=(y1 - y0) / ny)``.

    ``from_bounds``'s checks and cell counts are taken for every box at once: when every box
    passes them, with counts that come out as ``shape`` (the span over the step within
    ``from_bounds``'s 1e-9 of a whole number), the grids are those ``from_bounds`` returns,
    ``Grid(origin=(x0, y0), dx, dy, nx, ny)``, made together by :meth:`Grid.many` (framing a
    thousand hypotheses cost more than rasterising them); otherwise each box is made in turn,
    a plain one as that ``Grid`` and any other by ``from_bounds`` itself and its error."""
    ny, nx = shape
    boxes = np.asarray(bounds, dtype=np.float64).reshape(-1, 4)
    x0, x1, y0, y1 = boxes.T
    with np.errstate(all="ignore"):
        dx, dy = (x1 - x0) / nx, (y1 - y0) / ny
        plain = np.isfinite(boxes).all(axis=1) & (x1 > x0) & (y1 > y0)
        for span, step, n in ((x1 - x0, dx, nx), (y1 - y0, dy, ny)):
            count = span / step
            plain &= np.isfinite(step) & (step > 0.0) & np.isfinite(count)
            plain &= (np.round(count) == n) & (np.abs(count - n) <= 1e-9 * np.maximum(1.0, count))
    if plain.all():
        return Grid.many(np.column_stack((x0, y0)), dx, dy, nx, ny)
    return [
        Grid(origin=(a, c), dx=u, dy=v, nx=nx, ny=ny) if ok
        else Grid.from_bounds(x=(a, b), y=(c, d), dx=u, dy=v)
        for a, b, c, d, u, v, ok in zip(x0.tolist(), x1.tolist(), y0.tolist(), y1.tolist(), dx.tolist(),
                                        dy.tolist(), plain.tolist())
    ]


def _shape(shape) -> tuple[int, int]:
    return positive_int("shape[0]", shape[0]), positive_int("shape[1]", shape[1])


def batch_models(models: Sequence[BatchModel]) -> list[BatchModel]:
    """The hypotheses as a list, all of one model kind that has batch kernels."""
    models = list(models)
    if not models:
        raise BananagridError("models: expected at least one hypothesis")
    kind = type(models[0])
    if not isinstance(models[0], BatchModel):
        raise BananagridError(f"models[0] = {kind.__name__}: this model has no batch kernels")
    for k, m in enumerate(models):
        if type(m) is not kind:
            raise BananagridError(f"models[{k}] = {type(m).__name__}: batches take {kind.__name__} hypotheses, "
                                  "like models[0]")
    return models


def rasterise_batch(models: Sequence[BatchModel], grids: Sequence[Grid] | None = None, *, shape=(64, 64),
                    dtype=np.float64, device: str = "cpu", threads=None) -> BatchRaster:
    """Rasterise every hypothesis on its own grid in one launch.

    ``grids``: one per hypothesis, all of one shape; by default :func:`frame` of the
    hypotheses at ``shape``.
    """
    models = batch_models(models)
    grids = batch_grids(models, grids, shape)
    ny, nx = grids[0].shape
    _check_memory(len(models), ny * nx, 0, dtype)
    # every grid's cell centres at once, with Grid.x's and Grid.y's arithmetic (the same values)
    origins = np.array([g.origin for g in grids])
    steps = np.array([(g.dx, g.dy) for g in grids])
    xs = origins[:, :1] + (np.arange(nx) + 0.5) * steps[:, :1]
    ys = origins[:, 1:] + (np.arange(ny) + 0.5) * steps[:, 1:]
    values, sums = _launch("grid", models, xs, ys, (len(models), ny, nx), ny, dtype=dtype, device=device,
                           threads=threads)
    return BatchRaster(values, grids, sums * np.array([g.cell_area for g in grids]))


def pdf_batch(models: Sequence[BatchModel], x, y, *, dtype=np.float64, device: str = "cpu", threads=None) -> np.ndarray:
    """Density of every world point (x, y broadcast to N points) under every hypothesis: (H, N)."""
    models = batch_models(models)
    try:
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    except ValueError:
        raise BananagridError(f"x and y: shapes {np.shape(x)} and {np.shape(y)} do not broadcast") from None
    _check_memory(len(models), bx.size, bx.size, dtype)  # before anything the size of the points is made
    if not (np.isfinite(bx).all() and np.isfinite(by).all()):
        raise BananagridError("x, y: points must be finite (NaN or inf given)")
    return _launch("points", models, bx.ravel(), by.ravel(), (len(models), bx.size), None,
                   dtype=dtype, device=device, threads=threads)[0]


def _check_memory(hypotheses: int, cells: int, points: int, dtype) -> None:
    """Refuse a batch whose values alone (hypotheses x cells of ``dtype``) and, for points, their
    float64 coordinates (the points as given and as the kernel's arrays: 32 bytes a point) would
    not fit in the memory available: a lower bound of what the batch holds, so a refusal is
    certain, with the bytes (:func:`bananagrid.engine.memory.check_memory`)."""
    try:
        itemsize = np.dtype(dtype).itemsize
    except TypeError:
        return  # not a dtype: WarpContext says so, naming it
    check_memory(hypotheses * cells, itemsize, f"a batch of {hypotheses:,} hypotheses x {cells:,} cells",
                 base=32.0 * points)


def _launch(which: str, models: list[BatchModel], x, y, out_shape, rows, *, dtype, device,
            threads) -> tuple[np.ndarray, np.ndarray]:
    """Run the kind's batch kernel (``which``: "grid" over (hypothesis, row) with ``rows`` rows,
    or "points") over bands of hypotheses: each launch covers hypotheses h0 .. h0 + b - a.
    Returns the values and each hypothesis's float64 sum of them.

    On the CPU the kernels write every value into a NumPy array they share (zeroing 328 MB for
    10,000 64 x 64 float64 grids first took 0.17 s, on one thread), and each band's sums are
    taken by the thread that computed it, right after its launch: each hypothesis's sum alone
    (:func:`~bananagrid.engine.warp_runtime.row_sums`), the same bits for any banding."""
    ctx = WarpContext(dtype, device, threads)
    binding = type(models[0]).batch_binding(ctx, models)
    kernel = binding.kernels.batch_grid if which == "grid" else binding.kernels.batch_points
    ctx.load(kernel)
    x_arr = ctx.array(x)
    y_arr = ctx.array(y)
    if ctx.cpu:
        values = np.empty(out_shape, dtype=ctx.dtype)  # every value is written by the kernel
        out = ctx.shared(values)
    else:
        out = ctx.zeros(out_shape)
    sums = np.empty(len(models))

    def launch_band(a, b):
        dim = b - a if rows is None else (b - a, rows)
        ctx.launch(kernel, dim=dim, inputs=[x_arr, y_arr, a, binding.params, out])
        if ctx.cpu:  # a CPU launch has finished when it returns
            sums[a:b] = row_sums(values[a:b].reshape(b - a, -1))

    ctx.run_bands(launch_band, ctx.bands(len(models), 4))
    if not ctx.cpu:
        values = ctx.numpy(out)
        sums = row_sums(values.reshape(len(models), -1))
    return values, sums
