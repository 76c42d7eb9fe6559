"""The engine's hook for evidence carried along a model's paths: densities at points weighted
by earlier evidence, one channel per combination of the evidence (the pack's channels).

A model that carries (:class:`~bananagrid.protocol.CarryingModel`) returns from
``bind_carried(ctx, extent, pack)`` a :class:`~bananagrid.protocol.KernelBinding` whose
``kernels.points`` has the carried signature ``(xs, ys, start, p, ev, lw, out)``; the engine
builds the pack's struct (:func:`evidence_struct`), the scratch and the output, and launches it
in chunks from the thread pool as it does a plain points kernel.
"""

from __future__ import annotations

import numpy as np

from ..kernels import evidence as evidence_kernels
from ..protocol import EvidencePack
from ..validate import BananagridError
from .points import PointsExtent, check_model
from .precision import working_dtype
from .warp_runtime import WarpContext

__all__ = ["evaluate_carried", "evidence_struct", "weigh_paths", "carries", "CARRIED_CHUNK"]

#: Points per launch (the scratch and output rows of a chunk stay in cache).
CARRIED_CHUNK = 8192


def carries(model) -> bool:
    """Whether ``model``'s kernels carry earlier evidence (it has ``bind_carried``)."""
    return callable(getattr(model, "bind_carried", None))


def evidence_struct(ctx, pack: EvidencePack):
    """The pack as the kernels' :data:`~bananagrid.kernels.evidence.EVIDENCE` struct in ``ctx``'s
    dtype on its device."""
    i32 = np.int32
    return ctx.struct(
        evidence_kernels.EVIDENCE, time=ctx.array(pack.time), q=ctx.array(pack.q), data=ctx.array(pack.data),
        ints=ctx.array(np.ascontiguousarray(pack.ints, dtype=i32), dtype=i32), edges=ctx.array(pack.edges),
        raster=ctx.array(pack.raster), channels=ctx.array(np.ascontiguousarray(pack.channels, dtype=i32), dtype=i32),
    )


def evaluate_carried(model, x, y, pack: EvidencePack, *, dtype=np.float64, device: str = "cpu", threads=None,
                     extent=None) -> np.ndarray:
    """Each channel of ``pack`` of ``model``'s density at world points, weighted by the
    evidence along the paths through each point: shape ``(C, *broadcast shape)``, per m^2
    (float32 asked: computed in float64 where float32 coordinates cannot resolve the model,
    as :func:`~bananagrid.engine.points.evaluate_points` does).

    Raises
    ------
    BananagridError
        A model that does not carry evidence, points that are not finite or do not broadcast.
    """
    if not carries(model):
        raise BananagridError(f"model = {type(model).__name__}: its kernels do not carry evidence along its paths")
    check_model(model)
    try:
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    except ValueError:
        raise BananagridError(f"x and y: shapes {np.shape(x)} and {np.shape(y)} do not broadcast") from None
    if not (np.isfinite(bx).all() and np.isfinite(by).all()):
        raise BananagridError("x, y: points must be finite (NaN or inf given)")
    ctx = WarpContext(dtype, device, threads)
    asked = ctx.dtype
    channels = pack.channels.shape[0]
    if bx.size == 0:
        return np.zeros((channels, *bx.shape), dtype=asked)
    extent = extent if extent is not None else PointsExtent(bx, by)
    if asked == np.float32:  # as evaluate_points: float64 where float32 coordinates cannot resolve the model
        working = working_dtype(model, asked, extent.radii((0.0, 0.0))[1])
        if working != asked:
            ctx = WarpContext(working, device, threads)
    binding = model.bind_carried(ctx, extent, pack)
    ev = evidence_struct(ctx, pack)
    kernel = binding.kernels.points
    ctx.load(kernel)
    n = bx.size
    xs, ys = ctx.host_array(bx.ravel()), ctx.host_array(by.ravel())
    lw = ctx.empty((n, pack.scratch))
    out = ctx.zeros((n, channels))

    def launch_chunk(a, b):
        ctx.launch(kernel, dim=b - a, inputs=[xs, ys, a, binding.params, ev, lw, out])

    size = max(1, min(CARRIED_CHUNK, -(-n // ctx.threads)))
    chunks = [(a, min(n, a + size)) for a in range(0, n, size)] if ctx.cpu else [(0, n)]
    ctx.run_bands(launch_chunk, chunks)
    values = ctx.numpy(out)
    return np.ascontiguousarray(values.T, dtype=asked).reshape(channels, *bx.shape)


def weigh_paths(pack: EvidencePack, positions, density, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
    """The channels of given paths through the shared helpers: ``positions`` (n, N, 2) world
    positions of n paths at the pack's N node times, ``density`` (n,) each path's density;
    returns (n, C) density x weight_c (the kernels' own weights, for paths a caller computes on
    the host and for the tests)."""
    ctx = WarpContext(dtype, device, 1)
    positions = np.ascontiguousarray(positions, dtype=ctx.dtype)
    n = positions.shape[0]
    if positions.shape != (n, pack.nodes, 2):
        raise BananagridError(f"positions: shape {positions.shape}; expected (n, {pack.nodes}, 2)")
    out = ctx.zeros((n, pack.channels.shape[0]))
    if n == 0:
        return ctx.numpy(out)
    ctx.load(evidence_kernels.evidence_paths)
    ctx.launch(evidence_kernels.evidence_paths, dim=n, inputs=[
        evidence_struct(ctx, pack), ctx.wp.array(positions, dtype=ctx.scalar_type, ndim=3, device=ctx.device),
        ctx.array(np.asarray(density)), ctx.zeros((n, pack.scratch)), out])
    return ctx.numpy(out)
