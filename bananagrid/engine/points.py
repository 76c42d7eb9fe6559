"""Densities at arbitrary world points, through a model's points kernel."""

from __future__ import annotations

import functools

import numpy as np

from ..protocol import DensityModel, KernelBinding
from ..validate import BananagridError
from .precision import working_dtype
from .warp_runtime import WarpContext

__all__ = ["evaluate_points", "launch_points", "PointsExtent", "check_model", "check_finite", "POINT_CHUNK"]

#: Points per launch in evaluate_points: at most POINT_CHUNK (so the pool gets several chunks),
#: at least MIN_POINT_CHUNK (a launch costs a few microseconds).
POINT_CHUNK = 65536
MIN_POINT_CHUNK = 4096


class PointsExtent:
    """The extent of a set of points: distances from an origin to the nearest and farthest."""

    def __init__(self, x: np.ndarray, y: np.ndarray):
        self.x, self.y = x, y

    def radii(self, origin) -> tuple[float, float]:
        with np.errstate(over="ignore"):  # points near 1.8e308 away: inf, farther than any support
            r = np.hypot(self.x - origin[0], self.y - origin[1])
        return float(r.min()), float(r.max())


def check_model(model: object, what: str = "not a bananagrid model") -> DensityModel:
    """``model`` if it follows :class:`~bananagrid.protocol.DensityModel`, else an error
    ``model = TYPE: WHAT``.

    The protocol's ``isinstance`` looks up each of its 25 members on the object (about 20 us);
    a class whose instance passed once is remembered (:func:`_follows_protocol`), so a tracker's
    every call pays a set lookup. Only a pass is remembered: an object that fails is checked,
    and refused, each time."""
    kind = type(model)
    if kind in _follows_protocol():
        return model
    if not isinstance(model, DensityModel):
        raise BananagridError(f"model = {kind.__name__}: {what}")
    _follows_protocol().add(kind)
    return model


@functools.cache
def _follows_protocol() -> set:
    """Classes an instance of which followed :class:`~bananagrid.protocol.DensityModel`. Every
    instance of such a class does: the protocol's members are methods and properties of the
    class or fields every instance of a model (a frozen dataclass) sets in ``__init__``."""
    return set()


def check_finite(values: np.ndarray, model: DensityModel) -> None:
    """Raise if a kernel produced NaN or inf (an internal error: every model is finite)."""
    if np.isfinite(values.sum()):  # one pass, no mask, in the common case
        return
    bad = ~np.isfinite(values)
    if bad.any():
        raise FloatingPointError(
            f"{type(model).__name__}: {int(bad.sum())} non-finite densities (first at index "
            f"{np.argwhere(bad)[0].tolist()}); please report this with the model parameters"
        )


def evaluate_points(model: DensityModel, x, y, *, dtype=np.float64, device: str = "cpu", threads=None,
                    extent=None) -> np.ndarray:
    """Density of ``model`` at world points; ``x`` and ``y`` broadcast together.

    ``extent`` (an :class:`~bananagrid.protocol.Extent`) says where the points of this call
    lie (default: these points). A caller evaluating many chunks of one region passes the
    region's extent, so that a model that tabulates itself (CAT with heading noise) reuses one
    table.
    """
    try:
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    except ValueError:
        raise BananagridError(
            f"x and y: shapes {np.shape(x)} and {np.shape(y)} do not broadcast"
        ) from None
    if not (np.isfinite(bx).all() and np.isfinite(by).all()):
        raise BananagridError("x, y: points must be finite (NaN or inf given)")
    ctx = WarpContext(dtype, device, threads)
    asked = ctx.dtype
    if bx.size == 0:
        return np.zeros(bx.shape, dtype=asked)
    check_model(model)
    extent = extent if extent is not None else PointsExtent(bx, by)
    if asked == np.float32:  # float64 computes in float64 wherever the points lie
        working = working_dtype(model, asked, extent.radii((0.0, 0.0))[1])
        if working != asked:
            ctx = WarpContext(working, device, threads)
    binding = model.bind(ctx, extent, grid=False)
    ctx.load(binding.kernels.points)
    return launch_points(ctx, binding, bx, by).astype(asked, copy=False)


def launch_points(ctx: WarpContext, binding: KernelBinding, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    """Run a bound points kernel over (bx, by) in chunks from the thread pool (one launch on a
    GPU); the result has bx's shape. The kernel's module must be loaded."""
    n = bx.size
    xs = ctx.host_array(bx.ravel())
    ys = ctx.host_array(by.ravel())
    if ctx.cpu:
        values = np.empty(n, dtype=ctx.dtype)  # the chunks cover every point
        out = ctx.shared(values)
    else:
        out = ctx.zeros(n)

    # at least one chunk per thread once there is enough work to share
    size = max(MIN_POINT_CHUNK, min(POINT_CHUNK, -(-n // ctx.threads)))
    chunks = [(a, min(n, a + size)) for a in range(0, n, size)] if ctx.cpu else [(0, n)]
    # a tracker's few points again and again, with a model's kept parameters: one launch replayed
    launch = ctx.launch_kept if len(chunks) == 1 else ctx.launch

    def launch_chunk(a, b):
        launch(binding.kernels.points, dim=b - a, inputs=[xs, ys, a, binding.params, out], fresh=(0, 1, 4))
    ctx.run_bands(launch_chunk, chunks)
    if ctx.cpu:  # a CPU launch has finished when it returns
        return values.reshape(bx.shape)
    return ctx.numpy(out).reshape(bx.shape)
