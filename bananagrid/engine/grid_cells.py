"""Cell probabilities on a grid: the probability that the target is in each cell.

A model may compute them its own way (``model.grid_cells``, a
:class:`~bananagrid.protocol.CellPlan`: the CAT's lines, exact in the acceleration). Otherwise
the density is integrated over each cell by a tensor Gauss-Legendre rule whose sub-cells are no
larger than the model's length scale (``model.feature_scale``), the rule the polar lattices use
(:mod:`bananagrid.engine.quadrature`). About a point where the density is infinite like 1 / r
(``model.singular_points``: the origin of a polar density) the cells are integrated in polar
coordinates about it: a cell is the signed sum of the four triangles that join the point to its
edges, each mapped from the unit square by the Duffy transform

    X(u, v) = S + u (P1 - S) + u v (P2 - P1),   dX = u (P1 - S) x (P2 - P1) du dv,

whose factor u cancels the 1 / r; nearer cells see the angular features of the density narrowed
in proportion to their distance, and their sub-cells shrink with it.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np

from ..domains.grid import Grid
from ..protocol import DensityModel
from ..results import Raster
from ..validate import BananagridError
from .memory import check_memory
from .points import check_finite, evaluate_points
from .quadrature import GAUSS_TOL, MAX_SUBINTERVALS, axis_plan, unit_rule
from .warp_runtime import WarpContext
from .work import check_work

__all__ = ["probability_raster", "probability_work", "MAX_NODES", "FAN_ORDER", "FAN_CELLS"]

#: Most quadrature nodes of the tensor rule over a grid (about 10 s of polar-banana evaluations
#: on two cores); beyond it the sub-cells are coarsened and a warning says so.
MAX_NODES = 2**28
#: Points per evaluation (bounds the node arrays' memory, ~100 MB).
NODE_CHUNK = 2**20
#: Gauss-Legendre nodes per sub-interval of the Duffy rule, and its most sub-intervals per axis.
FAN_ORDER = 8
FAN_MAX_SUBINTERVALS = 64
#: Cells within this many of their diagonals of a singular point take the Duffy rule.
FAN_CELLS = 1.0
#: Bytes per cell while the probabilities are computed: the float64 result, a model's own
#: buffer of the same size, and the cells' scales and plans.
PROBABILITY_BYTES_PER_CELL = 40


def probability_raster(model: DensityModel, grid: Grid, *, dtype=np.float64, device: str = "cpu", threads=None,
                       max_seconds: float | None = None) -> Raster:
    """The probability of every cell of ``grid`` (see :func:`bananagrid.rasterise` with
    ``quantity="probability"``), float64 sums returned in ``dtype``."""
    ctx = WarpContext(dtype, device, threads)
    n_cells = grid.nx * grid.ny
    what = f"{type(model).__name__}: cell probabilities on a grid of {grid.nx} x {grid.ny} = {n_cells:,} cells"
    start = time.perf_counter()
    plan = model.grid_cells(grid)
    if ctx.cpu:
        check_memory(n_cells, PROBABILITY_BYTES_PER_CELL, what)
    if plan is not None:
        if ctx.cpu:
            check_work(plan.seconds, ctx.launch_threads, f"{what} ({plan.method})", limit=max_seconds,
                       option="max_seconds=S")
        probability, notes = plan.run(ctx)
    else:
        probability, notes = _quadrature(model, grid, ctx, what, max_seconds)
    check_finite(probability, model)
    # every term is a positive weight times a density or a normal mass, except the Duffy rule's
    # signed triangles, whose sum may round below zero by a few ulps of the cell's largest term
    floor = -1e-12 * float(np.max(np.abs(probability), initial=0.0))
    if np.any(probability < floor):
        raise FloatingPointError(f"{what}: negative cell probabilities; please report this with the model")
    probability = np.maximum(probability, 0.0)
    mass = float(np.sum(probability))
    provenance = {
        **model.parameters(),
        "quantity": "probability",
        "dtype": ctx.dtype.name,
        "device": ctx.device,
        "threads": ctx.launch_threads,
        "seconds": time.perf_counter() - start,
        **notes,
    }
    return Raster(values=probability.astype(ctx.dtype, copy=False), grid=grid, mass=mass, quantity="probability",
                  provenance=provenance)


# --------------------------------------------------------------------------------------------
# The engine's quadrature
# --------------------------------------------------------------------------------------------


def _cell_scales(model: DensityModel, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Per cell: the length scale its sub-cells must resolve, and whether it takes the Duffy
    rule (within FAN_CELLS diagonals of a singular point)."""
    scale = np.full(grid.shape, float(model.feature_scale()))
    fan = np.zeros(grid.shape, dtype=bool)
    diagonal = math.hypot(grid.dx, grid.dy)
    x0, _, y0, _ = grid.extent
    xl = x0 + grid.dx * np.arange(grid.nx)
    yl = y0 + grid.dy * np.arange(grid.ny)
    for sx, sy in np.asarray(model.singular_points(), dtype=float).reshape(-1, 2):
        gap_x = np.maximum(0.0, np.maximum(xl - sx, sx - (xl + grid.dx)))
        gap_y = np.maximum(0.0, np.maximum(yl - sy, sy - (yl + grid.dy)))
        distance = np.hypot(gap_y[:, None], gap_x[None, :])
        angular = model.polar_scales((sx, sy))[1]
        fan |= distance <= FAN_CELLS * diagonal
        scale = np.minimum(scale, np.maximum(distance, diagonal) * angular)
    return scale, fan


class _QuadraturePlan:
    """The tensor rule's plans by octave of the cells' scales, and the Duffy rule's cells."""

    def __init__(self, model: DensityModel, grid: Grid):
        scale, self.fan = _cell_scales(model, grid)
        # sub-cells by quarter octaves of the scale: a cell takes the plan of the largest power
        # of 2^(1/4) of the feature scale not above its own (never coarser than its scale asks)
        self.base = float(model.feature_scale())
        self.octave = np.floor(4.0 * np.log2(np.maximum(scale, 1e-300) / self.base) + 1e-9)
        cap = MAX_SUBINTERVALS
        keys, counts = np.unique(self.octave[~self.fan], return_counts=True)
        while True:
            self.plans = {}
            for key in keys:
                s = self.base * 2.0 ** (key / 4.0)
                self.plans[key] = (axis_plan(grid.dx, s, cap), axis_plan(grid.dy, s, cap))
            self.total = sum(int(n) * px[0] * px[1] * py[0] * py[1]
                             for n, (px, py) in zip(counts, self.plans.values()))
            if self.total <= MAX_NODES or cap == 1:
                break
            cap = max(1, cap // 2)
        self.cap = cap
        self.fan_cells = np.argwhere(self.fan)
        # at most: four triangles of FAN_MAX_SUBINTERVALS^2 sub-cells of FAN_ORDER^2 nodes each
        self.fan_nodes = 4 * len(self.fan_cells) * (FAN_ORDER * FAN_MAX_SUBINTERVALS) ** 2
        self.error = max((px[2] + py[2] for px, py in self.plans.values()), default=0.0)


def probability_work(model: DensityModel, grid: Grid) -> tuple[float, str]:
    """Estimated seconds of one CPU core for the cell probabilities of ``grid``, and the
    method: the model's own plan, or the engine's quadrature (its nodes at the model's cost)."""
    plan = model.grid_cells(grid)
    if plan is not None:
        return plan.seconds, plan.method
    q = _QuadraturePlan(model, grid)
    nodes = q.total + q.fan_nodes
    return model.work_estimate(nodes, _GridBox(grid)), f"{nodes:,} quadrature nodes at most"


def _quadrature(model: DensityModel, grid: Grid, ctx, what: str, max_seconds) -> tuple[np.ndarray, dict]:
    q = _QuadraturePlan(model, grid)
    nodes = q.total + q.fan_nodes
    if ctx.cpu:
        check_work(model.work_estimate(nodes, _GridBox(grid)), ctx.launch_threads,
                   f"{what} ({nodes:,} quadrature nodes at most)", limit=max_seconds, option="max_seconds=S")
    if q.error > 10.0 * GAUSS_TOL:
        warnings.warn(
            f"grid cell probabilities: the node cap ({MAX_NODES:,} nodes, {q.cap} sub-intervals per cell and "
            f"axis) limits their accuracy to about {min(q.error, 1.0):.2g} of the mass per sub-cell (target "
            f"{GAUSS_TOL:g}); use larger cells or a smaller grid",
            stacklevel=4,
        )
    probability = np.zeros(grid.shape)
    extent = _GridBox(grid)
    for key, ((mx, nx, _), (my, ny, _)) in q.plans.items():
        cells = np.argwhere((q.octave == key) & ~q.fan)
        _tensor_cells(model, grid, ctx, cells, unit_rule(mx, nx), unit_rule(my, ny), probability, extent)
    for point in np.asarray(model.singular_points(), dtype=float).reshape(-1, 2):
        _fan_cells(model, grid, ctx, q.fan_cells, tuple(point), probability, extent)
    notes = {
        "cell_method": "tensor Gauss-Legendre over sub-cells"
                       + (", Duffy about singular points" if len(q.fan_cells) else ""),
        "length_scale_m": q.base,
        "quadrature_nodes": int(q.total),
        "accuracy": {"claim": "error bound per sub-cell for a normal feature as wide as the length scale, "
                              "as a fraction of the model's mass", "target": GAUSS_TOL, "estimated": float(q.error)},
    }
    return probability, notes


class _GridBox:
    """The whole grid (cell edges included), seen from an origin (an Extent)."""

    def __init__(self, grid: Grid):
        self.grid = grid

    def radii(self, origin) -> tuple[float, float]:
        x0, x1, y0, y1 = self.grid.extent
        ox, oy = origin
        near_x = 0.0 if x0 <= ox <= x1 else min(abs(x0 - ox), abs(x1 - ox))
        near_y = 0.0 if y0 <= oy <= y1 else min(abs(y0 - oy), abs(y1 - oy))
        return math.hypot(near_x, near_y), math.hypot(max(abs(x0 - ox), abs(x1 - ox)), max(abs(y0 - oy), abs(y1 - oy)))


def _tensor_cells(model, grid, ctx, cells, rule_x, rule_y, probability, extent) -> None:
    """Add the tensor rule's integral over each of ``cells`` (rows of (i, j)) to ``probability``."""
    (ux, wx), (uy, wy) = rule_x, rule_y
    per_cell = len(ux) * len(uy)
    chunk = max(1, NODE_CHUNK // per_cell)
    x0, _, y0, _ = grid.extent
    weights = np.outer(wy, wx).ravel() * (grid.dx * grid.dy)
    for c0 in range(0, len(cells), chunk):
        block = cells[c0 : c0 + chunk]
        xs = x0 + grid.dx * (block[:, 1, None] + ux[None, :])  # (C, kx)
        ys = y0 + grid.dy * (block[:, 0, None] + uy[None, :])  # (C, ky)
        px = np.broadcast_to(xs[:, None, :], (len(block), len(uy), len(ux)))
        py = np.broadcast_to(ys[:, :, None], (len(block), len(uy), len(ux)))
        values = evaluate_points(model, px.ravel(), py.ravel(), dtype=ctx.dtype, device=ctx.device,
                                 threads=ctx.threads, extent=extent)
        probability[block[:, 0], block[:, 1]] += values.reshape(len(block), per_cell).astype(float) @ weights


def _fan_cells(model, grid, ctx, cells, point, probability, extent) -> None:
    """Add the Duffy rule's integral over each of ``cells`` about the singular ``point``: the
    signed triangles (S, P1, P2) over the cell's edges taken anticlockwise."""
    sx, sy = point
    radial, angular = model.polar_scales(point)
    x0, _, y0, _ = grid.extent
    for i, j in cells:
        xa, ya = x0 + grid.dx * j, y0 + grid.dy * i
        corners = [(xa, ya), (xa + grid.dx, ya), (xa + grid.dx, ya + grid.dy), (xa, ya + grid.dy)]
        total = 0.0
        for (p1x, p1y), (p2x, p2y) in zip(corners, corners[1:] + corners[:1]):
            ax_, ay_ = p1x - sx, p1y - sy
            ex, ey = p2x - p1x, p2y - p1y
            jac = ax_ * ey - ay_ * ex  # (P1 - S) x (P2 - P1): twice the signed area
            if jac == 0.0:
                continue
            reach = max(math.hypot(ax_, ay_), math.hypot(ax_ + ex, ay_ + ey))
            turn = abs(math.atan2(jac, ax_ * (ax_ + ex) + ay_ * (ay_ + ey)))
            mu = max(1, min(FAN_MAX_SUBINTERVALS, math.ceil(reach / radial)))
            mv = max(1, min(FAN_MAX_SUBINTERVALS, math.ceil(2.0 * turn / angular)))
            u, wu = unit_rule(mu, FAN_ORDER)
            v, wv = unit_rule(mv, FAN_ORDER)
            px = sx + u[:, None] * (ax_ + v[None, :] * ex)
            py = sy + u[:, None] * (ay_ + v[None, :] * ey)
            values = evaluate_points(model, px.ravel(), py.ravel(), dtype=ctx.dtype, device=ctx.device,
                                     threads=ctx.threads, extent=extent).reshape(px.shape).astype(float)
            total += jac * float(np.einsum("u,uv,v->", wu * u, values, wv))
        probability[i, j] = total
