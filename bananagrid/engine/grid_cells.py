"""Cell probabilities on a grid: the probability that the target is in each cell.

A model may compute them its own way (``model.cell_plan``, a
:class:`~bananagrid.protocol.CellPlan`: the CAT's lines, exact in the acceleration). Otherwise
the density is integrated over each cell by a tensor Gauss-Legendre rule whose sub-cells are no
larger than the model's length scale (``model.feature_scale``), the rule the polar lattices use
(:mod:`bananagrid.engine.quadrature`). A Gauss rule is only as good as the smoothness of what it
integrates, so two kinds of cells are swept in polar coordinates about a point P instead:

* about a point where the density is infinite like 1 / r (``model.singular_points``: the origin
  of a polar density) or where a seam starts (the density changes with the direction there:
  a bearing station), the cells within FAN_CELLS diagonals of it: the area element r dr
  cancels the 1 / r, and the direction is a coordinate;
* cells that a seam crosses (``model.seams``: a ray from P along which the density has a kink
  or a jump, such as a polar density's angle wrapping at +-pi behind the start), or that hold
  its P: in polar coordinates about P the seam is a line of constant bearing, a break of the
  rule like the bearings of the cell's corners.

A cell is swept about the point it holds, else about the point whose seam or fan reached it
first. Every other seam that crosses it (another station's, crossing the first's) is a curve
about that point: each ray's segment is split where it crosses one, and the bearings at which
one enters, leaves or ends in the cell are breaks. A cell holding two or more points, or much
larger than its distance to a point it does not hold, is first cut into leaves
(:func:`_leaves`), each swept about the point it holds.

A swept cell is, for each bearing theta between its smallest and largest as seen from P (the
whole circle where the cell holds P), the segment [r_in(theta), r_out(theta)] of the ray that
lies in the cell; r_in and r_out are smooth between the bearings of the corners, so the
bearing is integrated by Gauss-Legendre between those and the seams' bearings, sub-intervals
no wider than the model's angular scale about P (and no longer, as arcs, than its feature
scale), and each segment by Gauss-Legendre sub-intervals no longer than its radial scale.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np

from ..domains.grid import Grid
from ..protocol import DensityModel
from ..results import Raster
from ..validate import BananagridError, BananagridWarning
from .memory import check_memory
from .points import check_finite, evaluate_points
from .quadrature import (GAUSS_TOL, MAX_ORDER, MAX_SUBINTERVALS, axis_plan, graded_rule, narrowing, normal_shares,
                         ray_box_points, seam_ranges, split_segments, unit_rule)
from .warp_runtime import WarpContext
from .work import check_work

__all__ = ["probability_raster", "probability_work", "MAX_NODES", "FAN_CELLS"]

#: Most quadrature nodes of the tensor rule over a grid (about 10 s of polar-banana evaluations
#: on two cores); beyond it the sub-cells are coarsened and a warning says so.
MAX_NODES = 2**28
#: Points per evaluation (bounds the node arrays' memory, ~100 MB).
NODE_CHUNK = 2**20
#: Cells within this many of their diagonals of a singular point are swept about it.
FAN_CELLS = 1.0
#: Sub-cells near a singular point are at most this fraction of their distance from it.
SINGULAR_FRACTION = 0.25
#: Steps along each side of a swept cell (in tan of the bearing from its normal).
SIDE_STEPS = 8
#: Bearings per piece at which a swept cell samples the radial law's SD.
LAW_PROBES = 33
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
    plan = model.cell_plan(grid)
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
    # every term is a positive weight times a density or a normal mass: a negative cell could
    # only be a model's own rule rounding below zero by a few ulps of its largest term
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
    """Per cell: the length scale its sub-cells must resolve, and the point it is swept about
    (an index into :func:`_seams_by_point`; -1 for the tensor rule): within FAN_CELLS diagonals
    of a singular point, or crossed by a seam."""
    scale = np.full(grid.shape, float(model.feature_scale()))
    sweep = np.full(grid.shape, -1, dtype=np.int64)
    diagonal = math.hypot(grid.dx, grid.dy)
    x0, _, y0, _ = grid.extent
    xl = x0 + grid.dx * np.arange(grid.nx)
    yl = y0 + grid.dy * np.arange(grid.ny)
    for k, ((sx, sy), bearings, _) in enumerate(_seams_by_point(model)):
        gap_x = np.maximum(0.0, np.maximum(xl - sx, sx - (xl + grid.dx)))
        gap_y = np.maximum(0.0, np.maximum(yl - sy, sy - (yl + grid.dy)))
        distance = np.hypot(gap_y[:, None], gap_x[None, :])
        # about a 1 / r point or a seam's start (where the density changes with the direction:
        # a bearing station) the angular features narrow in proportion to the distance, and the
        # 1 / r's Taylor series about a node converges within it: cells within FAN_CELLS
        # diagonals are swept about the point, and sub-cells beyond are at most a quarter of
        # the distance (Gauss's error then falls like 8^-2n)
        angular = min(model.polar_scales((sx, sy))[1], SINGULAR_FRACTION)
        sweep[(sweep < 0) & (distance <= FAN_CELLS * diagonal)] = k
        scale = np.minimum(scale, np.maximum(distance, diagonal) * angular)
        for bearing in bearings:
            sweep[(sweep < 0) & _crossed(grid, (sx, sy), bearing)] = k
        law = model.polar_law((sx, sy))
        if law is not None:
            sweep[(sweep < 0) & _narrow(grid, (sx, sy), law, float(model.feature_scale()))] = k
    # a cell that holds a point is swept about it (the singular points first), whichever other
    # point's seam crosses it: the other seams are then split along each ray (_sweep_nodes)
    for k, ((sx, sy), _, _) in reversed(list(enumerate(_seams_by_point(model)))):
        holds = ((xl <= sx) & (sx <= xl + grid.dx))[None, :] & ((yl <= sy) & (sy <= yl + grid.dy))[:, None]
        sweep[holds] = k
    return scale, sweep


#: Bearings at which a radial law is sampled to find where its range SD is narrower than the
#: tensor rule's length scale.
LAW_SAMPLES = 8192


def _narrow(grid: Grid, point, law, scale: float) -> np.ndarray:
    """Cells whose bearings about ``point`` reach where the radial law's SD is below ``scale``
    (the tensor rule's sub-cells would not resolve it: the improved polar banana's P_sigma
    falling to 0, or to a third of its peak behind the start) while its angular density is
    above 1e-16 of its peak (below, a cell holds under 1e-16 of the mass): a boolean mask."""
    theta = np.linspace(-math.pi, math.pi, LAW_SAMPLES + 1)
    g, _, sd = law(theta)
    bad = (sd < scale) & (g > 1e-16 * float(np.max(g)))
    if not bad.any():
        return np.zeros(grid.shape, dtype=bool)
    bad = bad | np.roll(bad, 1) | np.roll(bad, -1)  # a sample's neighbours: SD between samples
    count = np.concatenate([[0], np.cumsum(bad)])  # bad samples before index i: count[i]
    x0, _, y0, _ = grid.extent
    xe = x0 + grid.dx * np.arange(grid.nx + 1) - point[0]
    ye = y0 + grid.dy * np.arange(grid.ny + 1) - point[1]
    corners = [np.arctan2(xe[None, a:grid.nx + a], ye[b:grid.ny + b, None]) for a in (0, 1) for b in (0, 1)]
    centre = np.arctan2(0.5 * (xe[None, :-1] + xe[None, 1:]), 0.5 * (ye[:-1, None] + ye[1:, None]))
    rel = [(c - centre + math.pi) % (2.0 * math.pi) - math.pi for c in corners]
    lo = centre + np.minimum.reduce(rel)
    hi = centre + np.maximum.reduce(rel)
    step = 2.0 * math.pi / LAW_SAMPLES
    i0 = np.floor((lo + math.pi) / step).astype(np.int64)
    i1 = np.ceil((hi + math.pi) / step).astype(np.int64)
    n = LAW_SAMPLES + 1

    def hits(a, b):  # bad samples in [a, b] of indices that may run past either end (wrap)
        a_w, b_w = a % (n - 1), b % (n - 1)
        plain = count[np.minimum(b_w, n - 1) + 1] - count[a_w]
        wrapped = (count[n] - count[a_w]) + count[b_w + 1]
        return np.where(a_w <= b_w, plain, wrapped) > 0

    holds = ((xe[None, :-1] <= 0.0) & (0.0 <= xe[None, 1:])) & ((ye[:-1, None] <= 0.0) & (0.0 <= ye[1:, None]))
    return hits(i0, i1) | holds & bad.any()


class _QuadraturePlan:
    """The tensor rule's plans by octave of the cells' scales, and the swept cells."""

    def __init__(self, model: DensityModel, grid: Grid):
        scale, sweep = _cell_scales(model, grid)
        self.fan = sweep >= 0
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
        ij = np.argwhere(self.fan)
        self.fan_cells = np.column_stack([ij, sweep[self.fan]]) if len(ij) else np.zeros((0, 3), dtype=np.int64)
        self.fan_nodes = self._swept_nodes(model, grid)
        self.error = max((px[2] + py[2] for px, py in self.plans.values()), default=0.0)

    def _swept_nodes(self, model, grid) -> int:
        """At most this many nodes in the swept cells: the bearings each subtends about its point
        (the whole circle within a diagonal of it) in angular scales, with a break per corner and
        seam, times the diagonal in radial scales, MAX_ORDER nodes each way."""
        if not len(self.fan_cells):
            return 0
        points = _seams_by_point(model)
        diagonal = math.hypot(grid.dx, grid.dy)
        x0, _, y0, _ = grid.extent
        feature = float(model.feature_scale())
        total = 0
        for k, ((px, py), bearings, _) in enumerate(points):
            cells = self.fan_cells[self.fan_cells[:, 2] == k]
            if not len(cells):
                continue
            radial, angular = model.polar_scales((px, py))
            radial = min(radial, feature)
            cx = x0 + grid.dx * (cells[:, 1] + 0.5) - px
            cy = y0 + grid.dy * (cells[:, 0] + 0.5) - py
            distance = np.hypot(cx, cy)
            span = np.where(distance <= diagonal, 2.0 * math.pi, np.minimum(2.0 * math.pi, 2.0 * diagonal / np.maximum(distance, 1e-300)))
            far = distance + diagonal
            # the seams of other points that cross each cell: two breaks each, a split of each ray
            others = [(x, y, b) for q, ((x, y), seam_bearings, _) in enumerate(points) if q != k
                      for b in seam_bearings]
            crossing = np.zeros(len(cells))
            for seam in others:
                for n, (i, j) in enumerate(cells[:, :2]):
                    box = (x0 + grid.dx * j, x0 + grid.dx * (j + 1), y0 + grid.dy * i, y0 + grid.dy * (i + 1))
                    crossing[n] += bool(ray_box_points(seam, box))
            pieces = 4 + len(bearings) + 2 * crossing
            per_angle = np.minimum(MAX_SUBINTERVALS, np.ceil(span / np.minimum(angular, feature / far)) + pieces)
            per_range = min(MAX_SUBINTERVALS, math.ceil(diagonal / radial))
            total += int(np.sum(per_angle * (1 + crossing))) * per_range * MAX_ORDER**2
        return total


def probability_work(model: DensityModel, grid: Grid) -> tuple[float, str]:
    """Estimated seconds of one CPU core for the cell probabilities of ``grid``, and the
    method: the model's own plan, or the engine's quadrature (its nodes at the model's cost)."""
    plan = model.cell_plan(grid)
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
            BananagridWarning, stacklevel=4,
        )
    probability = np.zeros(grid.shape)
    extent = _GridBox(grid)
    for key, ((mx, nx, _), (my, ny, _)) in q.plans.items():
        cells = np.argwhere((q.octave == key) & ~q.fan)
        _tensor_cells(model, grid, ctx, cells, unit_rule(mx, nx), unit_rule(my, ny), probability, extent)
    _swept_cells(model, grid, ctx, q.fan_cells, probability, extent)
    notes = {
        "cell_method": "tensor Gauss-Legendre over sub-cells"
                       + (", swept in polar coordinates about singular points and seams" if len(q.fan_cells) else ""),
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


def _seams_by_point(model: DensityModel) -> list[tuple[tuple[float, float], list[float], bool]]:
    """The points that cells are swept about: ``(P, seam bearings from P, singular)``, the
    singular points first (their cells take their polar rule even when a seam of another point
    crosses them)."""
    points = []
    for sx, sy in np.asarray(model.singular_points(), dtype=float).reshape(-1, 2):
        points.append(((float(sx), float(sy)), [], True))
    for x, y, bearing in np.asarray(model.seams(), dtype=float).reshape(-1, 3):
        for p, bearings, _ in points:
            if p == (float(x), float(y)):
                bearings.append(float(bearing))
                break
        else:
            points.append(((float(x), float(y)), [float(bearing)], False))
    return points


def _crossed(grid: Grid, point, bearing: float) -> np.ndarray:
    """Cells whose interior the ray from ``point`` at ``bearing`` passes through, or that hold
    ``point`` (closed cells): a boolean mask of the grid's shape."""
    px, py = point
    ux, uy = math.sin(bearing), math.cos(bearing)
    x0, _, y0, _ = grid.extent
    xl = x0 + grid.dx * np.arange(grid.nx)
    yl = y0 + grid.dy * np.arange(grid.ny)
    lo = np.zeros(grid.shape)
    hi = np.full(grid.shape, np.inf)
    for start, step, edges, width, axis in ((px, ux, xl, grid.dx, 1), (py, uy, yl, grid.dy, 0)):
        shape = (1, -1) if axis == 1 else (-1, 1)
        a, b = edges.reshape(shape), (edges + width).reshape(shape)
        if step == 0.0:  # parallel to this axis: inside the slab or nowhere
            inside = (a < start) & (start < b)
            hi = np.where(inside, hi, -np.inf)
            continue
        ta, tb = (a - start) / step, (b - start) / step
        lo = np.maximum(lo, np.minimum(ta, tb))
        hi = np.minimum(hi, np.maximum(ta, tb))
    crossed = hi > lo  # a segment of positive length inside the open cell
    holds = ((xl <= px) & (px <= xl + grid.dx))[None, :] & ((yl <= py) & (py <= yl + grid.dy))[:, None]
    return crossed | holds


def _bearing(dx, dy):
    """Bearing clockwise from north of the vector (dx, dy)."""
    return np.arctan2(dx, dy)


def _segment(point, corners_lo, corners_hi, theta):
    """``(r_in, r_out)`` of the rays from ``point`` at bearings ``theta`` in the box
    ``corners_lo`` = (x0, y0), ``corners_hi`` = (x1, y1) (r_in = r_out where a ray misses it)."""
    lo = np.zeros_like(theta)
    hi = np.full_like(theta, np.inf)
    for start, step, a, b in ((point[0], np.sin(theta), corners_lo[0], corners_hi[0]),
                              (point[1], np.cos(theta), corners_lo[1], corners_hi[1])):
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (a - start) / step, (b - start) / step
        flat = step == 0.0
        lo = np.where(flat, lo, np.maximum(lo, np.minimum(ta, tb)))
        hi = np.where(flat, np.where((a <= start) & (start <= b), hi, lo), np.minimum(hi, np.maximum(ta, tb)))
    return lo, np.maximum(lo, hi)


def _bearing_pieces(point, seam_bearings, box, breaks_at=()):
    """The bearings a cell subtends about ``point``, cut at the corners' and the seams'
    bearings and at ``breaks_at`` (bearings of other breaks: where another point's seam enters,
    leaves or ends in the cell): ``(pieces, far)``, pieces ``(a, b, seam_at_a, seam_at_b)``
    (unwrapped bearings), far the greatest distance from the point to the cell."""
    x0, x1, y0, y1 = box
    px, py = point
    cx, cy = np.array([x0, x1, x1, x0]), np.array([y0, y0, y1, y1])
    corner_bearings = _bearing(cx - px, cy - py)
    far = float(np.max(np.hypot(cx - px, cy - py)))
    two_pi = 2.0 * math.pi
    if x0 <= px <= x1 and y0 <= py <= y1:
        base = float(corner_bearings[0])
        span = (base, base + two_pi)
        unwrap = lambda b: base + (b - base) % two_pi  # noqa: E731
    else:
        centre = math.atan2(0.5 * (x0 + x1) - px, 0.5 * (y0 + y1) - py)
        unwrap = lambda b: centre + (b - centre + math.pi) % two_pi - math.pi  # noqa: E731
        rel = [unwrap(float(b)) for b in corner_bearings]  # within pi/2 of the centre's
        span = (min(rel), max(rel))
    seams = {unwrap(float(b)) for b in seam_bearings}
    if x0 <= px <= x1 and y0 <= py <= y1:
        seams |= {s + two_pi for s in seams if abs(s - span[0]) < 1e-15}
    breaks = {span[0], span[1]} | {u for u in (*map(unwrap, map(float, corner_bearings)), *seams,
                                               *map(unwrap, map(float, breaks_at)))
                                    if span[0] < u < span[1]}
    breaks = sorted(breaks)
    pieces = [(a, b, a in seams, b in seams) for a, b in zip(breaks[:-1], breaks[1:]) if b > a]
    return pieces, far, _side_steps(point, box)


def _side_steps(point, box):
    """``(normal bearing, distance)`` of the lines of the cell's sides not through ``point``: a
    ray's distance to a side at bearing theta is d / cos(theta - normal), steep where the ray
    grazes it; equal steps in tan(theta - normal) (along the side) keep it smooth."""
    x0, x1, y0, y1 = box
    px, py = point
    sides = []
    for normal, d in ((math.pi / 2, x1 - px), (-math.pi / 2, px - x0), (0.0, y1 - py), (math.pi, py - y0)):
        if d > 0.0:
            sides.append((normal, d))
    return sides


def _along_sides(a: float, b: float, sides) -> set:
    """SIDE_STEPS equal steps in tan(theta - normal) over [a, b] for each side facing it."""
    points = set()
    for normal, _ in sides:
        lo = (a - normal + math.pi) % (2.0 * math.pi) - math.pi
        hi = lo + (b - a)
        if -0.5 * math.pi < lo and hi < 0.5 * math.pi:
            u = np.linspace(math.tan(lo), math.tan(hi), SIDE_STEPS + 1)
            points |= set((a + (np.arctan(u) - lo)).tolist())
    return {p for p in points if a < p < b}


def _sweep_nodes(point, seam_bearings, box, radial: float, angular: float, feature: float,
                 foreign=np.zeros((0, 3)), limit: float = math.inf):
    """Nodes ``(x, y, w)`` of the swept rule over the cell ``box`` = (x0, x1, y0, y1) about
    ``point``: sum(w p(x, y)) is the cell's probability.

    ``foreign`` are the seams of other points that cross the cell (rows (x, y, bearing)): in
    polar coordinates about ``point`` each is a curve, so every ray's segment is split where it
    crosses one (:func:`~bananagrid.engine.quadrature.seam_ranges`), and the bearings at which
    one enters, leaves or ends in the cell are breaks: between them each piece of a ray is
    smooth and its integral smooth in the bearing. ``limit`` bounds the sub-intervals' lengths
    (radial, and as arcs): a quarter of the distance to another point about which the density
    changes with the direction."""
    x0, x1, y0, y1 = box
    px, py = point
    foreign = np.asarray(foreign, dtype=float).reshape(-1, 3)
    crossings = [_bearing(qx - px, qy - py) for seam in foreign for qx, qy in ray_box_points(seam, box)]
    pieces, far, sides = _bearing_pieces(point, seam_bearings, box, crossings)
    angular = min(angular, min(feature, limit) / max(far, 1e-300))
    # MAX_ORDER nodes whatever the plan's error bound asks: the swept cells are few, and the
    # bound is one of a whole normal feature, where a cell in its tail wants relative accuracy
    m_r, _, _ = axis_plan(math.hypot(x1 - x0, y1 - y0), min(radial, limit), MAX_SUBINTERVALS)
    u_r, w_r = unit_rule(m_r, MAX_ORDER)
    xs, ys, ws = [], [], []
    for a, b, seam_a, seam_b in pieces:
        theta, w_t = graded_rule(a, b, angular, (seam_a, seam_b), _along_sides(a, b, sides))
        r_in, r_out = _segment(point, (x0, y0), (x1, y1), theta)
        lo, hi = split_segments(r_in, r_out, seam_ranges(point, theta, foreign))  # (T, F + 1)
        r = lo[:, :, None] + (hi - lo)[:, :, None] * u_r  # (T, F + 1, R)
        w = (w_t[:, None] * (hi - lo))[:, :, None] * w_r * r  # dtheta, dr and the area element r
        keep = np.broadcast_to((hi > lo)[:, :, None], r.shape)  # empty pieces hold no nodes
        xs.append((px + r * np.sin(theta)[:, None, None])[keep])
        ys.append((py + r * np.cos(theta)[:, None, None])[keep])
        ws.append(w[keep])
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(ws)


def _law_nodes(point, seam_bearings, box, angular: float, law):
    """Bearing nodes ``(theta, w, r_in, r_out)`` of the swept rule over the cell ``box`` for a
    density with a closed radial law about ``point``: the cell's probability is
    sum(w g(theta) [Phi((r_out - mu) / sd) - Phi((r_in - mu) / sd)]).

    A ray's share changes where the law's mean crosses the cell's sides, over a turn of about
    sd / r: each piece's sub-intervals are no wider than half the least sd (sampled at
    LAW_PROBES bearings of the piece) over the cell's farthest distance."""
    pieces, far, sides = _bearing_pieces(point, seam_bearings, box)
    x0, x1, y0, y1 = box
    out = []
    for a, b, seam_a, seam_b in pieces:
        _, _, sd = law(np.linspace(a, b, LAW_PROBES))
        live = sd[sd > 0.0]
        scale = min(angular, 0.5 * float(live.min()) / far) if live.size else angular
        narrow = narrowing(sd)  # graded only toward a seam where the SD falls (P_sigma = 0)
        theta, w_t = graded_rule(a, b, scale, (seam_a and narrow[0], seam_b and narrow[1]), _along_sides(a, b, sides))
        r_in, r_out = _segment(point, (x0, y0), (x1, y1), theta)
        out.append((theta, w_t, r_in, r_out))
    return tuple(np.concatenate(parts) for parts in zip(*out))


def _swept_cells(model, grid, ctx, cells, probability, extent) -> None:
    """Set each of ``cells`` (``(i, j, k)``: row, column, index into ``_seams_by_point``) to its
    swept rule's integral: exact in r where the model has a closed radial law about the point
    (``model.polar_law``), else Gauss-Legendre in r over the model's densities. Nodes are
    evaluated NODE_CHUNK at a time and summed per cell in node order (the same sums for any
    number of threads)."""
    if not len(cells):
        return
    points = _seams_by_point(model)
    feature = float(model.feature_scale())
    x0, _, y0, _ = grid.extent
    used = sorted(set(int(c[2]) for c in cells))
    scales = {k: model.polar_scales(points[k][0]) for k in used}
    laws = {k: model.polar_law(points[k][0]) for k in used}
    totals = np.zeros(len(cells))
    batch = {"parts": [], "size": 0, "law": None}

    def flush():
        parts = batch["parts"]
        if not parts:
            return
        owner = np.concatenate([np.full(p[0].size, n) for n, p in parts])
        if batch["law"] is None:
            xs, ys, ws = (np.concatenate([p[i] for _, p in parts]) for i in range(3))
            values = evaluate_points(model, xs, ys, dtype=ctx.dtype, device=ctx.device, threads=ctx.threads,
                                     extent=extent).astype(float)
            terms = ws * values
        else:
            theta, w, r_in, r_out = (np.concatenate([p[i] for _, p in parts]) for i in range(4))
            terms = w * normal_shares(*batch["law"](theta), r_in, r_out)
        totals[:] += np.bincount(owner, weights=terms, minlength=len(cells))
        batch.update(parts=[], size=0)

    for k in used:
        point, bearings, singular = points[k]
        radial, angular = scales[k]
        law = laws[k]
        batch["law"] = law
        for n in np.flatnonzero(cells[:, 2] == k):
            i, j = int(cells[n, 0]), int(cells[n, 1])
            box = (x0 + grid.dx * j, x0 + grid.dx * (j + 1), y0 + grid.dy * i, y0 + grid.dy * (i + 1))
            if law is None:
                parts = []
                for leaf, held, limit in _leaves(box, [p for p, _, _ in points]):
                    m = k if held is None else held
                    (mx, my), own, m_singular = points[m]
                    m_radial, m_angular = scales.get(m) or scales.setdefault(m, model.polar_scales((mx, my)))
                    foreign = [(x, y, b) for q, (p, seam_bearings, _) in enumerate(points) if q != m
                               for x, y, b in [(*p, b) for b in seam_bearings]
                               if ray_box_points((x, y, b), leaf)]
                    parts.append(_sweep_nodes((mx, my), own, leaf, m_radial if m_singular else min(m_radial, feature),
                                              m_angular, feature, foreign, limit))
                part = tuple(np.concatenate(v) for v in zip(*parts))
            else:
                part = _law_nodes(point, bearings, box, angular, law)
            if batch["size"] and batch["size"] + part[0].size > NODE_CHUNK:
                flush()
            batch["parts"].append((n, part))
            batch["size"] += part[0].size
        flush()
    probability[cells[:, 0], cells[:, 1]] = totals


#: Most halvings of a swept cell toward the points it holds or is near (its leaves, each
#: holding at most one point and no larger than twice its distance to any other).
MAX_SPLIT_DEPTH = 40
#: A leaf's sub-intervals are at most this fraction of its distance to another point, about
#: which the density changes with the direction on that scale.
NEAR_FRACTION = 0.25


def _holds(box, point) -> bool:
    x0, x1, y0, y1 = box
    return x0 <= point[0] <= x1 and y0 <= point[1] <= y1


def _leaves(box, points, depth: int = 0) -> list:
    """The cell ``box`` as leaves ``(box, held, limit)``: each holds at most one of ``points``
    (``held``, its index, or None) and is no larger than twice its distance to the others, or
    ``limit`` (NEAR_FRACTION of that distance) bounds its rule's sub-intervals. A box holding
    two points is cut between them (across the coordinate in which they are farther apart); a
    box larger than twice its distance to a point it does not hold is quartered."""
    x0, x1, y0, y1 = box
    held = [k for k, p in enumerate(points) if _holds(box, p)]
    if len(held) >= 2 and depth < MAX_SPLIT_DEPTH:
        p, q = points[held[0]], points[held[1]]
        if abs(p[0] - q[0]) >= abs(p[1] - q[1]):
            cut = 0.5 * (p[0] + q[0])
            halves = [(x0, cut, y0, y1), (cut, x1, y0, y1)]
        else:
            cut = 0.5 * (p[1] + q[1])
            halves = [(x0, x1, y0, cut), (x0, x1, cut, y1)]
        return [leaf for half in halves for leaf in _leaves(half, points, depth + 1)]
    others = [math.hypot(max(0.0, x0 - px, px - x1), max(0.0, y0 - py, py - y1))
              for k, (px, py) in enumerate(points) if k not in held]
    near = min(others, default=math.inf)
    if math.hypot(x1 - x0, y1 - y0) > 2.0 * near and depth < MAX_SPLIT_DEPTH:
        xm, ym = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        quarters = [(x0, xm, y0, ym), (xm, x1, y0, ym), (x0, xm, ym, y1), (xm, x1, ym, y1)]
        return [leaf for quarter in quarters for leaf in _leaves(quarter, points, depth + 1)]
    return [(box, held[0] if held else None, NEAR_FRACTION * near if near > 0.0 else math.inf)]
