"""The exact CAT density: constant, unknown acceleration and turn rate (Gade et al.; eq. (1) of
the polar-banana paper), with an optional normal error on the initial heading (Section 7)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erfc

from ..domains.grid import Grid
from ..domains.pose import Pose
from ..engine.grid_kernel import GridExtent
from ..engine.warp_runtime import WarpContext
from ..kernels import cat as kernels
from ..kernels import cat_lanes
from ..kernels.common import LANES32, LANES64
from ..kernels import cat_cells
from . import cat_carried
from ..protocol import CellPlan, EvidencePack, Extent, KernelBinding, KernelContext, SceneSchema
from ..validate import BananagridError, positive
from ._cat_heading import (
    clear_heading_tables, first_table_nodes, heading_nodes, heading_table, interpolation_bound, ray_densities,
    table_binding, table_spacing_limits,
)
from .base import check_n, check_rng
from .motion import MotionModel, motion_param, pose_arguments
from .params import modelclass, param

__all__ = ["CAT", "cat_position", "scan_nodes", "scan_table", "scan_bounds", "clear_heading_tables", "NODE_SPACING"]

#: Turn-rate node spacing of the scan table, in units of omega t (radians). The kernel's bounds
#: find every root at any spacing; at this one they are tight enough that few node intervals
#: need splitting.
NODE_SPACING = 0.1
MIN_NODES = 64
#: The scan's domain: at most this many nodes (a 336 MB float64 table, and 0.17 s a cell), i.e.
#: k_sigma sigma_omega t up to 209,715 rad (over 4,000 turns at one SD with k_sigma = 8); a
#: wider scan is refused, not thinned, since the kernel's proof needs nodes NODE_SPACING apart.
MAX_NODES = 2**22

#: Work estimate (:meth:`CAT.work_estimate`), seconds of one core, float64 or float32, about twice
#: the upper envelope of the process CPU time measured on Intel Xeon AVX-512, one and two threads,
#: sigma_omega t 0.1 to 25,000 rad, sigma_a 0.001 to 50, grids framing the banana, within a few
#: metres of the pose and 10 to 30 times wider (the margin: a CPU up to 2x slower still finishes
#: within the estimate; the calibration table is in :meth:`CAT.work_estimate`). A point
#: (the points kernel, a polar lattice's or a cell quadrature's node): SECONDS_PER_CELL, and
#: SECONDS_PER_NODE for each scan node (far from the pose: 15 ns a node measured at 480,001 nodes).
SECONDS_PER_CELL = 2e-6
SECONDS_PER_NODE = 40e-9
#: The row sweep of a grid (``kernels/cat_lanes.py``): each row scans every node
#: (SECONDS_PER_ROW_NODE: 90-160 ns measured, the table streamed from memory), and each cell
#: costs SECONDS_PER_SWEPT_CELL plus SECONDS_PER_CROSSING for each half-turn of the lines'
#: direction the scan covers (:func:`scan_half_turns`): every node's line (infinite in the
#: acceleration) crosses every row, and the cells near each crossing are tested (20-63 ns
#: measured per cell and half-turn).
SECONDS_PER_ROW_NODE = 330e-9
SECONDS_PER_SWEPT_CELL = 300e-9
SECONDS_PER_CROSSING = 130e-9
#: Near the pose the scan's cheap test flags most node intervals, and each costs its search: at
#: distance r about min(nodes, FLAG_REACH (v0 t + FLAG_ACCELERATION sigma_a t^2) / (r
#: NODE_SPACING)) of them (the nodes of |omega t| up to a reach over r, where the paths that
#: turn fast curl: :func:`flagged_nodes`), SECONDS_PER_FLAGGED_NODE each, times sqrt(nodes /
#: FLAGGED_NODES) up to 5x and nodes / STREAMED_NODES beyond (the table out of cache, more roots
#: to split: :func:`flagged_seconds`). Measured per node within a metre of the pose: on grids 7
#: ns at 1,601 nodes, 28 at 16,001, 46-55 at 160,001, 44 at 480,001; at points 83 at 480,001,
#: 390 at 4,000,001. The reach: the mean cost over +-10, 30 and 100 m about the pose at
#: sigma_a 0.05 and 2, 16,001 to 480,001 nodes (as flagged nodes at 45 ns).
FLAG_REACH = 100.0
FLAG_ACCELERATION = 0.3
#: The reach grows with the turn-rate spread (measured flagged work +-100 m about the pose: 900
#: of 1,601 nodes at sigma_omega t = 10 rad, 4,700 of 16,001 at 100, 16,000 of 160,001 at 1,000;
#: within 1 m at 0.1 and 1 rad, 0.12 and 0.29 us a cell, next to nothing flagged): as
#: sqrt(sigma_omega t / FLAG_TURN), linearly below FLAG_FEW_TURNS rad.
FLAG_TURN = 1000.0
FLAG_FEW_TURNS = 10.0
SECONDS_PER_FLAGGED_NODE = 20e-9
FLAGGED_NODES = 1601
STREAMED_NODES = 480001
#: A point's flagged intervals cost this much more than a grid cell's (83 against 44 ns a node
#: at 480,001 nodes: the points kernel searches each root alone, the sweep in groups).
POINT_FLAGGED_FACTOR = 1.5
#: And per cell interpolated in a heading table.
SECONDS_PER_TABLE_CELL = 0.5e-6


#: Density bounds (:meth:`CAT.density_bound`). Rounding allowance, in ulps of the kernel's
#: dtype, on a computed acceleration (of (|P| + v0 t) / |h|) and a computed F (of
#: |h| (|P| + v0 t)): table coefficients computed on another device, the scan's multiply-adds.
BOUND_ULPS = 64.0
#: Most roots one node interval of the scan contributes: ``cat_split``'s SPLIT x SPLIT parts,
#: two roots each.
ROOTS_PER_INTERVAL = 2 * kernels.SPLIT**2
#: A region whose bound exceeds the density floor is split into 2 x 2 parts and bounded again,
#: at most this many times (and only while the gain so far could reach the floor): each node's
#: F and a range over a smaller part less, so more intervals are proved skipped or far.
BOUND_REFINEMENTS = 3
#: With heading noise, the circle of ranges a rectangle's stencils read is covered by this many
#: sectors first, then refined as above.
HEADING_BOUND_SECTORS = 32
HEADING_BOUND_REFINEMENTS = 4
#: The finite bound's Lipschitz argument runs on this many pieces of each node interval; their
#: ends' line coefficients are cached up to this many values (5 arrays of 8 bytes a value).
BOUND_SUBSTEPS = 8
BOUND_PIECES_CACHED = 1 << 18
#: Parts times scan nodes bounded per refinement level at most (the level's memory and time).
BOUND_WORK = 1 << 21
#: Rectangles reaching beyond this (metres from the world origin) get the whole plane's bound.
FARTHEST_BOUNDED = 1e100
#: Distance allowance on float32 local coordinates, in ulps of |x| + |y| + |origin| (the
#: world coordinates and the pose rounded to float32, then the rotation).
COORDINATE_ULPS = 8.0


#: Exact-in-acceleration cell probabilities (:meth:`CAT.cell_plan`): turn-rate intervals
#: per crossing of the smallest cell side by the fastest-moving point of a line (so that an
#: interval's ribbon of lines is narrower than a cell: half a cell at most), and at least per
#: sigma_omega; the work estimate per cell an interval's edge lines walk (a few normal
#: intervals and corner tests; measured 100-200 ns on the reference machine, AMD Zen 4, rounded
#: up) and per interval. With the ribbon bent through its exact middle line the walk's
#: narrowness sets the count, not the interpolation (Figure 1 at 4 m: 7,486 intervals; 29,943 at
#: 8 a crossing, 39,315 when a linear ribbon's second-order error set it).
CELL_SUBSTEPS = 2
CELL_SIGMA_STEPS = 16
#: Largest distance between an interval's lines and their quadratic interpolation through its
#: edge and middle lines, as a fraction of the smaller of the cell and the acceleration's SD
#: along a line (the scale over which a cell's share of a line changes): the rule's
#: interpolation error, third order in the interval (the linear ribbon's, second order, was held
#: to the same tolerance with 5x the intervals on Figure 1).
CELL_CURVE_TOL = 1e-6
SECONDS_PER_LINE_CELL = 400e-9
SECONDS_PER_LINE = 1e-6
#: Most turn-rate intervals of the cell probabilities (512 MiB of edges).
MAX_CELL_NODES = 2**26
#: Work of the cell probabilities with earlier polygons, as a multiple of the plain rule's: an
#: allowance for the work check, twice the cost measured on the Figure 1 grid with two searches
#: (1.5x; the weighted terms cost only in the cells the polygons' edges reach).
CARRIED_WORK_FACTOR = 3.0


def scan_half_turns(model: "CAT") -> float:
    """Half-turns of the direction of the lines of reachable points, h(omega) = t^2 (C, D), over
    the scan (at least 1): it turns like omega t, over 2 k_sigma sigma_omega t, and each line
    (infinite in the acceleration) crosses a grid row once for each."""
    return max(1.0, 2.0 * model.k_sigma * model.sigma_omega * model.t / math.pi)


def flagged_nodes(model: "CAT", nodes: int, grid: Grid | None, r_near: float) -> float:
    """Node intervals the scan's test flags (for the work estimate), min(nodes, K / r) at distance
    r from the pose, K = FLAG_REACH s (v0 t + FLAG_ACCELERATION sigma_a t^2) / NODE_SPACING, s =
    sqrt(sigma_omega t / FLAG_TURN) (linear in sigma_omega t below FLAG_FEW_TURNS): at a
    point at least ``r_near`` from it (``grid`` None), or on average over ``grid``'s cell centres.
    Over a grid, the sum of that decreasing function of r is bounded by its integral over the
    disc of the grid's area about the pose (the largest for such a function), in cells' areas:
    nodes pi (R + 2 d)^2 within R + 2 d (R = K / nodes, d half a cell's diagonal; the cells
    nearest the pose included), and 4 pi K (R_eq + 2 d) beyond (a centre at r holds K / r,
    at most twice the mean of K / r over its cell there); and K / ``r_near`` (the centres' least
    distance from the pose) bounds every centre."""
    t = model.t
    turn = model.sigma_omega * t
    # the reach grows with the turns the paths may make: as sqrt(turn / FLAG_TURN), linearly below FLAG_FEW_TURNS
    spread = math.sqrt(turn / FLAG_TURN) if turn >= FLAG_FEW_TURNS else turn / math.sqrt(FLAG_FEW_TURNS * FLAG_TURN)
    k = FLAG_REACH * spread * (model.v0 * t + FLAG_ACCELERATION * model.sigma_a * t * t) / NODE_SPACING
    if grid is None:
        return float(nodes) if r_near * nodes <= k else k / r_near
    area, cells = grid.dx * grid.dy, grid.nx * grid.ny
    d = 0.5 * math.hypot(grid.dx, grid.dy)
    r_eq = math.sqrt(cells * area / math.pi)
    total = (nodes * math.pi * (k / nodes + 2.0 * d) ** 2 + 4.0 * math.pi * k * (r_eq + 2.0 * d)) / area
    # every centre is at least r_near from the pose: K / r_near bounds them all
    return min(float(nodes), total / cells, k / r_near if r_near > 0.0 else math.inf)


def flagged_seconds(nodes: int) -> float:
    """Seconds of one flagged node interval in a scan of ``nodes`` nodes."""
    growth = min(5.0, math.sqrt(max(1.0, nodes / FLAGGED_NODES))) * max(1.0, nodes / STREAMED_NODES)
    return SECONDS_PER_FLAGGED_NODE * growth


def point_seconds(model: "CAT", r_near: float) -> float:
    """Seconds of one point at least ``r_near`` from the pose (the points kernel): the scan, and
    the flagged intervals' search near the pose."""
    nodes = scan_node_count(model.k_sigma, model.sigma_omega, model.t)
    return (SECONDS_PER_CELL + nodes * SECONDS_PER_NODE
            + flagged_nodes(model, nodes, None, r_near) * POINT_FLAGGED_FACTOR * flagged_seconds(nodes))


def line_speed(model: "CAT") -> float:
    """A bound on |dP/domega| (m per rad/s) over the walked lines |a| <= Z_MAX sigma_a:
    dP/domega = t (v0 t (D, -C) + a t^2 (C', D')), with |(C, D)| <= 1/2 and |(C', D')| <= 1/6
    (C + iD and its derivative are integrals of (1 - s) e^(ius) and i s (1 - s) e^(ius) over
    s in [0, 1])."""
    t = model.t
    return t * (0.5 * model.v0 * t + cat_cells.Z_MAX * model.sigma_a * t * t / 6.0)


def cell_turn_edges(model: "CAT", cell: float) -> np.ndarray:
    """Edges of the turn-rate intervals of the cell probabilities on cells of smallest side
    ``cell``: equal intervals of +-k_sigma sigma_omega, at most sigma_omega / CELL_SIGMA_STEPS
    long, short enough that no point of a walked line moves more than cell / CELL_SUBSTEPS
    across one, and that the lines inside one stay within CELL_CURVE_TOL of the smaller of the
    cell and the acceleration's SD along a line, sigma_a t^2 |(C, D)|, of their quadratic
    interpolation through its edge and middle lines: h^3 |d^3 P / domega^3| sqrt(3) / 216 (the
    cubic remainder, |s (s - 1/2) (s - 1)| <= sqrt(3) / 36 on [0, 1], over 3!), with
    |d^3 P / domega^3| <= t^3 (v0 t / 12 + Z_MAX sigma_a t^2 / 20) (``line_speed``'s integrals,
    two powers of s more)."""
    t = model.t
    span = 2.0 * model.k_sigma * model.sigma_omega
    grid_of_span = np.linspace(-0.5 * span, 0.5 * span, 4097)
    sd_along = model.sigma_a * float(np.min(np.hypot(*cat_position(0.0, t, 1.0, grid_of_span).T)))
    third = t ** 3 * (model.v0 * t / 12.0 + cat_cells.Z_MAX * model.sigma_a * t * t / 20.0)
    step = min(cell / (CELL_SUBSTEPS * line_speed(model)), model.sigma_omega / CELL_SIGMA_STEPS,
               (72.0 * math.sqrt(3.0) * CELL_CURVE_TOL * min(cell, sd_along) / third) ** (1.0 / 3.0))
    return np.linspace(-0.5 * span, 0.5 * span, max(1, math.ceil(span / step)) + 1)


def cat_position(v0, t, a, omega) -> np.ndarray:
    """Local CAT position of eq. (1) for arrays of accelerations and turn rates, shape (n, 2).

    Written with u = omega t as  v0 t (A, B) + a t^2 (C, D)  (see ``kernels.common.cat_basis``);
    A = 2 sin^2(u / 2) / u without cancellation; below |u| = 1e-2 every function is its series
    (three terms: the next is below 1e-16 of the first), where C's and D's closed forms cancel.
    """
    u = np.atleast_1d(np.asarray(omega, dtype=float) * t)  # at least 1-D: the series fill in place
    a = np.atleast_1d(np.asarray(a, dtype=float))
    u, a = np.broadcast_arrays(u, a)
    small = np.abs(u) < 1e-2
    us = np.where(small, 1.0, u)  # no 0/0 in the closed forms that the series replace
    inv = 1.0 / us
    sin_u, cos_u = np.sin(us), np.cos(us)
    sin_half = np.sin(0.5 * us)
    A = 2.0 * sin_half * sin_half * inv  # (1 - cos u) / u
    B = sin_u * inv
    C = (sin_u - us * cos_u) * inv * inv
    D = (cos_u + us * sin_u - 1.0) * inv * inv
    if small.any():
        v = u[small]
        v2 = v * v
        A[small] = v * (0.5 - v2 / 24 + v2 * v2 / 720)
        B[small] = 1.0 - v2 / 6 + v2 * v2 / 120
        C[small] = v / 3 - v * v2 / 30 + v * v2 * v2 / 840
        D[small] = 0.5 - v2 / 8 + v2 * v2 / 144
    return np.column_stack((v0 * t * A + a * t * t * C, v0 * t * B + a * t * t * D))


def scan_node_count(k_sigma: float, sigma_omega: float, t: float) -> int:
    """Nodes of the CAT scan over +-k_sigma sigma_omega, at most ``NODE_SPACING`` apart in omega t
    (at least ``MIN_NODES``); may exceed ``MAX_NODES``, which the model refuses."""
    span = 2.0 * k_sigma * sigma_omega * t  # in omega t
    return int(max(MIN_NODES, math.ceil(span / NODE_SPACING) + 1))


def scan_nodes(model: "CAT") -> np.ndarray:
    """Turn-rate nodes of the CAT scan: uniform over +-k_sigma sigma_omega, ``NODE_SPACING``
    apart in omega t (at least ``MIN_NODES``)."""
    half = model.k_sigma * model.sigma_omega
    return np.linspace(-half, half, scan_node_count(model.k_sigma, model.sigma_omega, model.t))


def scan_table(model: "CAT", ctx: KernelContext, omegas: np.ndarray | None = None):
    """The scan's table (``kernels.cat_table``) at :func:`scan_nodes` (or at ``omegas``), in
    ``ctx``'s dtype on its device: the one :meth:`CAT.bind` gives the grid and points kernels."""
    omegas = scan_nodes(model) if omegas is None else omegas
    table = ctx.zeros((len(omegas), kernels.TABLE_COLUMNS))
    ctx.launch(kernels.cat_table, dim=len(omegas),
               inputs=[ctx.array(omegas), ctx.scalar(model.v0), ctx.scalar(model.t), table])
    return table


def host_table(model: "CAT", dtype, omegas: np.ndarray | None = None) -> np.ndarray:
    """:func:`scan_table` computed on the CPU, as a float64 NumPy array."""
    ctx = WarpContext(dtype, "cpu", 1)
    return ctx.numpy(scan_table(model, ctx, omegas)).astype(np.float64)


@dataclass(frozen=True)
class ScanBoundTable:
    """What :func:`scan_bounds` needs of one dtype's scan table (as float64 arrays).

    Attributes
    ----------
    eps : float
        The dtype's machine epsilon.
    omega : ndarray (n,)
        The nodes as the kernel holds them.
    f, a : ndarray (3, n)
        F = hx y - hy x - c: (hx, hy, c); the line's acceleration a = ax x + ay y - a0: (ax, ay, a0).
    h : ndarray (n,)
        |h(omega)| at the float64 nodes, in float64.
    """

    eps: float
    omega: np.ndarray
    f: np.ndarray
    a: np.ndarray
    h: np.ndarray


@dataclass(frozen=True)
class BoundData:
    """What :meth:`CAT.density_bound` computes once per model.

    Attributes
    ----------
    tables : tuple of ScanBoundTable
        The scan tables of the dtypes the kernels may run in.
    nodes : ndarray (n,)
        The float64 scan nodes.
    pieces : tuple of ndarray (n - 1, BOUND_SUBSTEPS + 1), or None
        omega, ax, ay, a0 and |h| (float64) at the ends of each node interval's pieces; None
        beyond BOUND_PIECES_CACHED values (the bound then uses whole intervals only).
    """

    tables: tuple
    nodes: np.ndarray
    pieces: tuple | None


def bound_data(model: "CAT", dtypes) -> BoundData:
    """:class:`BoundData` for the scan tables of ``dtypes``, all from the kernels' own
    ``cat_table`` (float64 |h| and piece coefficients: its series below |u| = 1 keep them
    accurate to a few ulps, where closed forms would cancel)."""
    nodes = scan_nodes(model)
    h = np.hypot(*host_table(model, np.float64)[:, 1:3].T)
    tables = []
    for dtype in dtypes:
        values = host_table(model, dtype)
        tables.append(ScanBoundTable(float(np.finfo(dtype).eps), values[:, 0].copy(), values[:, 1:4].T.copy(),
                                     values[:, 7:10].T.copy(), h))
    pieces = None
    if (len(nodes) - 1) * (BOUND_SUBSTEPS + 1) <= BOUND_PIECES_CACHED:
        ends = np.linspace(0.0, 1.0, BOUND_SUBSTEPS + 1)
        omega = nodes[:-1, None] + np.diff(nodes)[:, None] * ends
        values = host_table(model, np.float64, omega.ravel()).reshape(*omega.shape, -1)
        pieces = (omega, values[..., 7], values[..., 8], values[..., 9], np.hypot(values[..., 1], values[..., 2]))
    return BoundData(tuple(tables), nodes, pieces)


def scan_bounds(model: "CAT", data: BoundData, parts: np.ndarray, target: float = 0.0) -> np.ndarray:
    r"""Bounds of the density ``cat_scan`` computes with any of ``data``'s tables over
    each of the local-frame rectangles ``parts`` (rows cx, cy, e1x, e1y, e2x, e2y, delta: the
    points c + s e1 + q e2, |s|, |q| <= 1, each coordinate moved by up to delta by rounding):
    0 where it computes exact zeros, else a finite bound (made tighter, at some cost, only
    where that may bring it to ``target`` or below).

    Exact zeros. The scan adds nothing on a node interval [w_(k-1), w_k] unless both (i) F has
    a sign change or an end within the chord threshold (``chord_coef`` width^2 + noise_f) of
    zero, and (ii) ``cat_negligible`` fails: the nodes' accelerations a_k = ax x + ay y - a0
    are not both beyond +-a_cut = PRUNE_SIGMAS sigma_a on one side. At a node F and a are
    affine in P, so over a rectangle their range is exactly the centre's value +- |L . e1|
    +- |L . e2|; widened by the coordinates' rounding and BOUND_ULPS of their scales, and
    with the thresholds at their largest over the rectangle, "F is beyond the threshold on one
    side at both ends" or "a is beyond a_cut on one side at both ends" proves the interval
    skipped at every point of the rectangle.

    Finite bound. An interval not skipped adds at most ROOTS_PER_INTERVAL roots, each
    g(a(w); sigma_a) g(w; sigma_omega) / max(|dF/domega|, noise_g) at some w of the interval
    (Newton stays in its bracket), noise_g >= ROUNDING_ULPS eps t^3 (7/12) v0 t. With
    Q = P - v0 f = alpha h/|h| + beta h_perp/|h| and h . df/domega = 0,

    .. math:: \frac{da}{d\omega} = \frac{h' \cdot Q}{|h|^2} - \frac{2 (h \cdot Q)(h \cdot h')}{|h|^4}
              = \frac{\beta h'_\perp - \alpha h'_\parallel}{|h|^2},
              \qquad \left|\frac{da}{d\omega}\right| \le \frac{|Q|\, |h'|}{|h|^2},

    |Q| <= |P| + v0 t, |h'| = t^3 |(C', D')| <= t^3 min(1/3, (u^2 + 2|u| + 4) / |u|^3) (the
    smaller |u| of the piece), and |h| at least its smaller end value less |h'| times half the
    piece. On a piece of the interval |a(w)| is then at least the mean of its ends' minima
    (exact ranges, as above) less that slope times half the piece, a Lipschitz bound that holds
    where a changes sign too, and |w| at least the piece's nearest end to 0; the interval's
    bound is the largest over its pieces. The pieces are the whole interval (the table's own
    nodes) first, then, where that bound exceeds ``target`` and the nodes' own values do not
    already (no piece can do better than the node nearer the rectangle), BOUND_SUBSTEPS pieces
    (``data.pieces``: the kernels' float64 coefficients, within the nodes' rounding of the
    dtype's interval).
    """
    parts = np.asarray(parts, dtype=np.float64)
    out = np.zeros(len(parts))
    chunk = max(1, BOUND_WORK // len(data.nodes))
    for start in range(0, len(parts), chunk):
        block = parts[start:start + chunk]
        out[start:start + chunk] = np.max(
            [_scan_bounds(model, data, table, block, target) for table in data.tables], axis=0)
    return out


def _affine_ranges(parts: tuple, lx, ly, l0, margin):
    """Range (lo, hi) of lx x + ly y - l0 over each rectangle of ``parts`` (broadcast), widened
    by the coordinates' rounding and ``margin``."""
    cx, cy, e1x, e1y, e2x, e2y, delta = parts
    mid = cx * lx + cy * ly - l0
    half = (np.abs(e1x * lx + e1y * ly) + np.abs(e2x * lx + e2y * ly) + delta * (np.abs(lx) + np.abs(ly))
            + margin)
    return mid - half, mid + half


def _least_accelerations(parts: tuple, ax, ay, a0, h, eps: float, scale) -> np.ndarray:
    """The least |a| over each rectangle on each line (broadcast), less the rounding of a."""
    a_lo, a_hi = _affine_ranges(parts, ax, ay, a0, BOUND_ULPS * eps * scale / h)
    return np.maximum(0.0, np.maximum(a_lo, -a_hi))


def _piece_exponents(model: "CAT", eps: float, scale, end_min, omega, h) -> np.ndarray:
    """The largest exponent -(a_min / sigma_a)^2 / 2 - (w_min / sigma_omega)^2 / 2 over the pieces
    between consecutive columns of ``omega`` (rows: live intervals), from the least |a| at the
    pieces' ends ``end_min`` and |h| there (see :func:`scan_bounds`)."""
    t = model.t
    t3 = t * t * t
    lo, hi = omega[:, :-1], omega[:, 1:]
    # w rounded (and u = w t in float32) stays within widen of [lo, hi], and so do the turn
    # rates the table's rows hold (its nodes rounded, u rounded): a w lies within span / 2 of
    # one and within span of both together
    widen = 8.0 * eps * (np.abs(lo) + np.abs(hi))
    span = hi - lo + 4.0 * widen
    straddle = (lo - widen <= 0.0) & (hi + widen >= 0.0)
    w_min = np.where(straddle, 0.0, np.minimum(np.abs(lo), np.abs(hi)) - widen)
    u = t * w_min
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        turn = np.where(u > 3.0, np.minimum(1.0 / 3.0, (u * u + 2.0 * u + 4.0) / u**3), 1.0 / 3.0)
    h_lo = np.minimum(h[:, :-1], h[:, 1:]) * (1.0 - 1e-12) - t3 * turn * 0.5 * span  # |h| rounded by ulps
    positive_h = h_lo > 0.0
    h_safe = np.where(positive_h, h_lo, 1.0)
    slope = t3 * turn * scale / (h_safe * h_safe)
    a_min = 0.5 * (end_min[:, :-1] + end_min[:, 1:] - slope * span) - BOUND_ULPS * eps * scale / h_safe
    a_min = np.where(positive_h, np.maximum(a_min, 0.0), 0.0)
    exponent = -0.5 * (a_min / model.sigma_a) ** 2 - 0.5 * (w_min / model.sigma_omega) ** 2
    return exponent.max(axis=1)


def _scan_bounds(model: "CAT", data: BoundData, table: ScanBoundTable, parts: np.ndarray, target: float) -> np.ndarray:
    """:func:`scan_bounds` of one chunk of parts with one table."""
    eps, v0, t = table.eps, model.v0, model.t
    t2 = t * t
    reach = v0 * t
    columns = tuple(parts[:, i, None] for i in range(7))
    cx, cy, e1x, e1y, e2x, e2y, delta = columns
    r = np.hypot(cx, cy) + np.hypot(e1x, e1y) + np.hypot(e2x, e2y) + math.sqrt(2.0) * delta  # largest |P|
    scale = r + reach  # bounds |P - v0 f|
    # the nodes' accelerations and F over each part (F = hx y - hy x - c)
    a_lo, a_hi = _affine_ranges(columns, *table.a, BOUND_ULPS * eps * scale / table.h)
    hx, hy, c = table.f
    f_lo, f_hi = _affine_ranges(columns, -hy, hx, c, BOUND_ULPS * eps * scale * table.h)
    width = np.diff(table.omega)
    # the kernel's thresholds at their largest over the part (|x| + |y| <= sqrt(2) r)
    chord = t2 * t2 * (0.25 * r + reach / 12.0) * 0.125 * width * width
    noise_f = kernels.ROUNDING_ULPS * eps * t2 * 0.5 * (math.sqrt(2.0) * r + reach)
    threshold = (chord + noise_f) * (1.0 + 16.0 * eps)
    no_root = ((f_lo[:, :-1] > threshold) & (f_lo[:, 1:] > threshold)) | (
        (f_hi[:, :-1] < -threshold) & (f_hi[:, 1:] < -threshold))
    a_cut = kernels.PRUNE_SIGMAS * model.sigma_a * (1.0 + 4.0 * eps)
    pruned = ((a_lo[:, :-1] > a_cut) & (a_lo[:, 1:] > a_cut)) | ((a_hi[:, :-1] < -a_cut) & (a_hi[:, 1:] < -a_cut))
    part, k = np.nonzero(~(no_root | pruned))
    m = len(parts)
    if len(part) == 0:
        return np.zeros(m)
    noise_g = kernels.ROUNDING_ULPS * eps * t2 * t * reach * (7.0 / 12.0) * (1.0 - 1e-3)
    log_peak = math.log(ROOTS_PER_INTERVAL / (2.0 * math.pi * model.sigma_a * model.sigma_omega * noise_g))
    live = tuple(column[part] for column in columns)
    scale = scale[part]
    # the whole interval as one piece, on the table's nodes
    ends = np.column_stack((k, k + 1))
    node_min = np.maximum(0.0, np.maximum(a_lo, -a_hi))[part[:, None], ends]
    exponent = _piece_exponents(model, eps, scale, node_min, table.omega[ends], table.h[ends])
    bound = np.bincount(part, weights=np.exp(log_peak + exponent), minlength=m)
    # BOUND_SUBSTEPS pieces where they may bring a part to target: not where the nodes alone,
    # the largest any piece bound can reach, leave it above
    w_far = np.maximum(np.abs(table.omega[k]), np.abs(table.omega[k + 1]))
    best_case = log_peak - 0.5 * (node_min.min(axis=1) / model.sigma_a) ** 2 - 0.5 * (w_far / model.sigma_omega) ** 2
    hopeful = (bound > target) & (np.bincount(part, weights=np.exp(best_case), minlength=m) <= target)
    pick = hopeful[part]
    if data.pieces is not None and pick.any():
        omega, ax, ay, a0, h = (v[k[pick]] for v in data.pieces)
        chosen = tuple(column[pick] for column in live)
        end_min = _least_accelerations(chosen, ax, ay, a0, h, eps, scale[pick])
        exponent_fine = _piece_exponents(model, eps, scale[pick], end_min, omega, h)
        fine = np.bincount(part[pick], weights=np.exp(log_peak + exponent_fine), minlength=m)
        bound = np.where(hopeful, np.minimum(bound, fine), bound)
    bound *= 1.001
    # not proved exact: never 0 (the kernel's exp may round up to a subnormal)
    return np.where(np.bincount(part, minlength=m) > 0, np.maximum(bound, np.finfo(np.float64).smallest_subnormal), 0.0)


def plane_bound(model: "CAT", data: BoundData) -> float:
    """:func:`scan_bounds` over the whole plane: every node interval live, with a = 0."""
    bound = 0.0
    for table in data.tables:
        eps, t = table.eps, model.t
        lo, hi = table.omega[:-1], table.omega[1:]
        widen = 8.0 * eps * (np.abs(lo) + np.abs(hi))
        straddle = (lo - widen <= 0.0) & (hi + widen >= 0.0)
        w_min = np.where(straddle, 0.0, np.minimum(np.abs(lo), np.abs(hi)) - widen)
        noise_g = kernels.ROUNDING_ULPS * eps * t**4 * model.v0 * (7.0 / 12.0) * (1.0 - 1e-3)
        peak = ROOTS_PER_INTERVAL / (2.0 * math.pi * model.sigma_a * model.sigma_omega * noise_g)
        bound = max(bound, float(np.sum(peak * np.exp(-0.5 * (w_min / model.sigma_omega) ** 2))) * 1.001)
    return bound


def refined_bound(model: "CAT", data: BoundData, parts: np.ndarray, target: float, refinements: int) -> float:
    """The largest of :func:`scan_bounds` over ``parts``, the parts above ``target`` split into
    2 x 2 and bounded again up to ``refinements`` times (any level's largest is a bound: its
    parts cover the region). Refining stops where it cannot reach ``target``: when even the
    last level's gain, repeated at every level left, would leave the bound above it."""
    best = math.inf
    settled = 0.0  # the largest bound of the parts no longer split
    for level in range(refinements + 1):
        bounds = scan_bounds(model, data, parts, target)
        largest = max(settled, float(bounds.max()))
        gain = best / largest if largest > 0.0 else math.inf
        best = min(best, largest)
        hot = bounds > target
        if (best <= target or level == refinements or 4 * int(hot.sum()) * len(data.nodes) > BOUND_WORK
                or (level > 0 and min(gain, 1e30) ** (refinements - level) * target < best)):
            break
        settled = max(settled, float(bounds[~hot].max(initial=0.0)))
        parts = split_parts(parts[hot])
    return best


def split_parts(parts: np.ndarray) -> np.ndarray:
    """Each rectangle (cx, cy, e1x, e1y, e2x, e2y, delta) as its four quarters."""
    out = []
    for s1 in (-0.5, 0.5):
        for s2 in (-0.5, 0.5):
            q = parts.copy()
            q[:, 0] += s1 * parts[:, 2] + s2 * parts[:, 4]
            q[:, 1] += s1 * parts[:, 3] + s2 * parts[:, 5]
            q[:, 2:6] *= 0.5
            out.append(q)
    return np.concatenate(out)


def annulus_parts(inner: float, outer: float, sectors: int, delta: float) -> np.ndarray:
    """Rectangles covering the ranges [inner, outer] about the origin: each sector of
    2 pi / sectors in its bounding box (along its middle bearing from inner cos(half) to
    outer, across it +-outer sin(half))."""
    half = math.pi / sectors
    bearing = (np.arange(sectors) + 0.5) * 2.0 * half
    ux, uy = np.sin(bearing), np.cos(bearing)  # bearings clockwise from the local +y
    near, far = inner * math.cos(half), outer
    mid, radial, across = 0.5 * (near + far), 0.5 * (far - near), far * math.sin(half)
    return np.column_stack((mid * ux, mid * uy, radial * ux, radial * uy, across * uy, -across * ux,
                            np.full(sectors, delta)))


def _row_target(floor: float, n_theta: int) -> float:
    """The largest base-density bound B of a table row with interpolation_bound(n_theta B) <=
    floor (bisection in log B; a target for the refinement only, not part of any proof)."""
    lo, hi = -745.0, math.log(max(floor, 1e-300))
    if interpolation_bound(n_theta * math.exp(lo)) > floor:
        return 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if interpolation_bound(n_theta * math.exp(mid)) <= floor:
            lo = mid
        else:
            hi = mid
    return math.exp(lo)


def _rotate(local: np.ndarray, theta0: np.ndarray) -> np.ndarray:
    """Turn local points by theta0 (radians, clockwise: a heading error to starboard)."""
    c, s = np.cos(theta0), np.sin(theta0)
    x, y = local[:, 0], local[:, 1]
    return np.column_stack((x * c + y * s, -x * s + y * c))


def grid_cell_plan(model: "CAT", grid: Grid, polygons: cat_carried.EarlierPolygons | None = None) -> CellPlan:
    """The exact-in-acceleration cell plan of :meth:`CAT.cell_plan` on ``grid`` (no heading
    noise); with ``polygons`` (:class:`~bananagrid.models.cat_carried.EarlierPolygons`: area
    searches and land at earlier times) its ``run`` returns the channels ``(channels, ny, nx)``,
    each path weighted by the factors of the channel's polygons (:mod:`.cat_carried`)."""
    if model.sigma_heading > 0.0:
        raise BananagridError("sigma_heading > 0: the CAT cell rule exact in the acceleration is for the model "
                              "without heading noise")
    if polygons is not None and polygons.count and float(np.max(polygons.times)) > model.t:
        raise BananagridError(f"evidence times {polygons.times.tolist()!r}: after the map's t = {model.t!r} s; "
                              "only earlier evidence is carried")
    edges = cell_turn_edges(model, min(grid.dx, grid.dy))
    intervals = len(edges) - 1
    if intervals > MAX_CELL_NODES:
        raise BananagridError(
            f"{grid.nx} x {grid.ny} cells of {grid.dx:g} x {grid.dy:g} m: the CAT cell probabilities "
            f"need {intervals:,} turn-rate intervals (more than {MAX_CELL_NODES:,}) at cells this small "
            f"for sigma_omega t = {model.sigma_omega * model.t:.3g} rad; use larger cells"
        )
    walked = 2.0 * min(grid.nx + grid.ny, 2.0 * cat_cells.Z_MAX * model.sigma_a * model.t**2
                       * math.sqrt(2.0) / min(grid.dx, grid.dy) + 2.0)
    seconds = intervals * (SECONDS_PER_LINE + walked * SECONDS_PER_LINE_CELL)
    if polygons is not None and polygons.count:
        seconds *= CARRIED_WORK_FACTOR

    def run(ctx: KernelContext):
        notes = {
            "cell_method": cat_carried.CELL_METHOD,
            "turn_rate_intervals": intervals,
            "truncated_mass": model.truncated_mass,
        }
        channels = cat_carried.grid_cell_channels(ctx, model, grid, edges, polygons)
        return (channels[0] if polygons is None else channels), notes

    return CellPlan(seconds=seconds, run=run, method="CAT lines exact in the acceleration")


@modelclass
class CAT(MotionModel):
    """Constant, unknown acceleration and turn rate (Gade et al.; eq. (1) of the polar-banana paper).

    From the origin, heading +y at speed ``v0``, the target moves for ``t`` seconds with constant
    acceleration a ~ N(0, sigma_a) and turn rate omega ~ N(0, sigma_omega). Its density at (x, y)
    is the sum over every (a, omega) reaching (x, y) of g(a) g(omega) / |det d(x,y)/d(a,omega)|.

    Notes
    -----
    For a fixed turn rate omega the position is affine in the acceleration a, so a point P is
    reached at omega iff F(omega) = h(omega) x (P - v0 f(omega)) = 0, and dF/domega = -det J
    there. Each cell scans a table of F's coefficients at :func:`scan_nodes` (on the CPU a grid
    row is swept at once), refines each sign change by Halley's method from the inverse cubic
    Hermite start, and finds the root pairs where the banana
    folds over itself wherever proved bounds on F's derivatives cannot exclude them; see
    ``kernels/cat.py`` (``cat_interval``).
    """

    v0: float = motion_param("v0")
    t: float = motion_param("t")
    sigma_a: float = motion_param("sigma_a")
    sigma_omega: float = motion_param("sigma_omega")
    k_sigma: float = param(
        8.0, domain="in [1, 38]: turn rates beyond +-k_sigma sigma_omega are left out",
        doc="Turn rates are searched within +-k_sigma * sigma_omega; the mass beyond, erfc(k_sigma / sqrt 2) "
            "(1.2e-15 at 8), is reported as ``truncated_mass`` and excluded.")
    sigma_heading: float = motion_param(
        "sigma_heading",
        doc="Standard deviation sigma_0 of a normal error theta_0 on the initial heading (Section 7 of the "
            "polar-banana paper). The density is then the exact CAT density convolved over the rotation by "
            "theta_0 about the origin: p(r, theta) = integral of p_0(r, theta - theta_0) g(theta_0; 0, sigma_0) "
            "d theta_0, computed on a polar lattice (exact wrapped-normal convolution by FFT along the bearing, "
            "then interpolation; see :mod:`bananagrid.models._cat_heading`). 0 gives the plain kernel exactly.")
    pose: Pose = motion_param("pose")

    kind = "cat"
    #: Peak bytes per sample of :meth:`sample`: 105 measured (tracemalloc, ``sample(10**6)``), rounded up.
    sample_bytes = 160
    #: float32 agreement with float64 where the density exceeds 1e-6 of its peak, beyond the
    #: density's change over the point's float32 rounding (``DensityModel.float32_rtol``).
    float32_rtol = 2e-4
    scene = SceneSchema(
        timed=True,
        build=lambda params: CAT(**pose_arguments(params)),
        radial_curves=True,
        summary="the exact CAT density (eq. (1) of the polar-banana paper), with heading noise convolved",
    )

    def __post_init__(self):
        self._validate_motion()
        k = positive("k_sigma", self.k_sigma)
        if not 1.0 <= k <= 38.0:
            raise BananagridError(f"k_sigma = {k!r}: must be in [1, 38] (beyond 38 the normal tail underflows)")
        object.__setattr__(self, "k_sigma", k)
        nodes = scan_node_count(k, self.sigma_omega, self.t)
        if nodes > MAX_NODES:
            turn = self.sigma_omega * self.t
            raise BananagridError(
                f"sigma_omega = {self.sigma_omega!r} rad/s: over t = {self.t!r} s the turn-rate SD is "
                f"sigma_omega t = {turn:.3g} rad ({turn / (2 * math.pi):.3g} turns); the exact scan over "
                f"+-{k:g} SDs needs {nodes:.3g} nodes, above {MAX_NODES:,} (k_sigma sigma_omega t <= "
                f"{(MAX_NODES - 1) * NODE_SPACING / 2:,.0f} rad): a heading that uncertain is uniform, "
                "use a smaller t or sigma_omega"
            )

    @property
    def truncated_mass(self) -> float:
        """Probability of |omega| > k_sigma sigma_omega, left out of the density."""
        return float(erfc(self.k_sigma / math.sqrt(2.0)))

    def bind(self, ctx: KernelContext, extent: Extent, *, grid: bool = False) -> KernelBinding:
        """The scan kernels (``kernels/cat.py``) with their turn-rate table; with heading noise,
        the interpolating kernels over a heading table covering ``extent``."""
        pose = self.pose.as_array()
        if self.sigma_heading > 0.0:
            table = heading_table(self, *extent.radii(self.pose.origin), threads=ctx.threads)
            return table_binding(ctx, table, pose, {
                "k_sigma": self.k_sigma, "truncated_mass": self.truncated_mass, **table.notes(),
            })
        return self._scan_binding(ctx, (kernels.KERNELS, kernels.CAT), (cat_lanes.KERNELS, cat_lanes.CAT_LANES), {})

    def _scan_binding(self, ctx: KernelContext, scalar: tuple, lanes: tuple, notes: dict, **fields) -> KernelBinding:
        """The scan's binding: ``scalar``'s (kernels, parameter struct) pair, on the CPU ``lanes``'s
        (the scan over nodes in lanes, ``kernels/cat_lanes.py``, with the table's node groups),
        with the turn-rate table, Newton's tolerance and ``fields``; ``notes`` added to the scan's."""
        table = scan_table(self, ctx)
        eps = np.finfo(ctx.dtype).eps
        # Newton stops when its step is below a few ulps of the searched range.
        params = dict(table=table, v0=self.v0, t=self.t, sigma_a=self.sigma_a, sigma_omega=self.sigma_omega,
                      pose=self.pose.as_array(), tol=8.0 * eps * self.k_sigma * self.sigma_omega, eps=eps, **fields)
        notes = {"scan_nodes": table.shape[0], "k_sigma": self.k_sigma, "truncated_mass": self.truncated_mass, **notes}
        if ctx.device == "cpu":
            width = LANES64 if ctx.dtype == np.float64 else LANES32
            params["groups"] = ctx.array(cat_lanes.node_groups(table.numpy(), width), dtype=ctx.vector(width))
            scalar = lanes
        return KernelBinding(scalar[0], ctx.struct(scalar[1], **params), notes)

    def bind_carried(self, ctx: KernelContext, extent: Extent, pack: EvidencePack) -> KernelBinding:
        """The carried points kernel (``kernels/cat.py``'s ``cat_carried``; the scan in lanes on
        the CPU): each root (a, omega) of a point is a path, placed at the pack's node times by
        eq. (1) with the same pose, and weighted by the evidence there
        (:class:`~bananagrid.protocol.CarryingModel`). With heading noise the heading error
        theta_0 turns the path: a sum over the nodes of :func:`heading_nodes` of the turned
        model's weighted roots (not the heading table: the evidence is fixed in the world)."""
        pose = self.pose.as_array()
        thetas, weights = heading_nodes(self)
        heading = self.pose.heading + thetas
        poses = np.column_stack([np.full(len(thetas), pose[0]), np.full(len(thetas), pose[1]), np.cos(heading),
                                 np.sin(heading)])
        return self._scan_binding(
            ctx, (kernels.CARRIED_POINTS, kernels.CAT_CARRIED), (cat_lanes.CARRIED_POINTS, cat_lanes.CAT_CARRIED_LANES),
            {"heading_nodes": len(thetas), "evidence_nodes": pack.nodes},
            carry=ctx.struct(kernels.CAT_CARRY, pose=pose, scale=1.0), poses=ctx.array(poses, dtype=ctx.vector(4)),
            weights=ctx.array(weights))

    def work_estimate(self, cells: int, extent: Extent) -> float:
        """Seconds of one core. On a grid (:class:`~bananagrid.engine.grid_kernel.GridExtent`;
        ``cells`` its rows' cells, or a share of them, swept ``extent.row_cells`` a launch row),
        the row sweep: rows x nodes ``SECONDS_PER_ROW_NODE``, and each cell
        ``SECONDS_PER_SWEPT_CELL``, half-turns
        (:func:`scan_half_turns`) x ``SECONDS_PER_CROSSING`` and, near the pose
        the flagged intervals' search (:func:`flagged_nodes` x :func:`flagged_seconds`). At points (any
        other extent: the points kernel, a polar lattice's or a quadrature's nodes):
        :func:`point_seconds` each, at the extent's least distance from the pose. With heading
        noise the heading table's nodes (:func:`first_table_nodes`, the lattice before any
        refinement) cost a point each, and the grid's cells ``SECONDS_PER_TABLE_CELL``.

        Calibration: process CPU time of ``rasterise`` on rows spread evenly over the grid
        (scaled to all its rows), or of the points kernel at sampled points, against this
        estimate; Intel Xeon AVX-512, one thread, float64 (float32 and two threads alike), load
        7-9 on 2 cores; v0 10 m/s, t 100 s; "framing": a square about the sample's 99.9 %.

        ======================  =======  ==========================  ========  ========
        sigma_omega t (rad)     nodes    grid or points              measured  estimate
        ======================  =======  ==========================  ========  ========
        0.1, sigma_a 0.05       64       framing, 200^2              0.0096 s  0.025 s
        10, sigma_a 2           1,601    framing, 200^2              0.15 s    0.47 s
        100, sigma_a 0.05       16,001   framing, 200^2              0.62 s    6.9 s
        100, sigma_a 0.05       16,001   +-1 m about the pose, 100^2 4.7 s     11 s
        1,000, sigma_a 2        160,001  framing, 800^2              222 s     693 s
        3,000, sigma_a 2        480,001  framing, 200^2              54 s      161 s
        3,000, sigma_a 0.05     480,001  +-1 m about the pose, 100^2 212 s     516 s
        25,000 (v0 8, sa 0.05)  4e6      +-1 km, 2000^2              9.9 h     35 h
        3,000, sigma_a 0.05     480,001  a point near the pose       40 ms     91 ms
        25,000 (v0 8, sa 0.05)  4e6      a point near the pose       1.6 s     5.2 s
        ======================  =======  ==========================  ========  ========

        Over 107 cases (sigma_omega t 0.1 to 25,000 rad, sigma_a 0.001 to 50, grids 50^2 to
        2000^2 framing the banana, about the pose and 10-30 times wider, points near and far) the
        estimate is 2.0 to 30 times the measured time (median 5.2; the old per-cell constants
        were 16-50 times it on grids, and half of it near the pose at 480,001 nodes). The widest
        ratios: grids much wider than the banana and points at small scans (64-161 nodes, well
        under a microsecond a point). Since then single roots are searched in CPU lanes: framing
        grids of small scans take about half the table's time (the bench's Figure 1 row: the
        estimate about 24 times it), grids about the pose and large scans about the same (5 of
        the table's cases remeasured under load: ratios 2.3 to 13.5).
        """
        r_near = extent.radii(self.pose.origin)[0]
        if self.sigma_heading > 0.0:
            nodes = first_table_nodes(self, *extent.radii(self.pose.origin))
            return nodes * point_seconds(self, r_near) + float(cells) * SECONDS_PER_TABLE_CELL
        if not isinstance(extent, GridExtent):
            return float(cells) * point_seconds(self, r_near)
        grid = extent.grid
        nodes = scan_node_count(self.k_sigma, self.sigma_omega, self.t)
        rows = float(cells) / extent.row_cells  # a block narrower than the grid sweeps its rows again
        per_cell = (SECONDS_PER_SWEPT_CELL + scan_half_turns(self) * SECONDS_PER_CROSSING
                    + flagged_nodes(self, nodes, grid, r_near) * flagged_seconds(nodes))
        return rows * nodes * SECONDS_PER_ROW_NODE + float(cells) * per_cell

    def cell_plan(self, domain, region=None) -> CellPlan | None:
        r"""A grid's cell probabilities exact in the acceleration (without heading noise; with
        it, and on other domains, :meth:`Model.cell_plan`: the engine integrates the density).

        For each turn rate the reachable points form a line along which z = a / sigma_a is
        standard normal (``kernels/cat_cells.py``), so a cell crossed between z_in and z_out
        holds Phi(z_out) - Phi(z_in) of it, exactly, caustic cells included:

        .. math:: P_{ij} = \int g(\omega)\, [\Phi(z_{out}(\omega)) - \Phi(z_{in}(\omega))]\, d\omega.

        Over each of equal omega intervals (:func:`cell_turn_edges`) the lines are interpolated
        quadratically through its two edge lines and its exact middle line (a ribbon at most
        half a cell wide), and the integral over omega is taken piecewise between the turn rates
        where these lines pass a corner of the cell (where the share has kinks, and where a line
        running along a side starts or stops crossing; the chord's quadratic roots refined on the
        bent lines), by 3-point Gauss-Legendre with the normal weight on pieces over which z_in
        and z_out move by at most 0.07 SD. The cells of a grid holding all the mass sum to 1 -
        truncated_mass (|a| <= 7.5 sigma_a, 6.4e-14 left out) within the Gauss rule's error on g,
        below 1e-12. The remaining error is the interpolation, third order in the interval,
        which is kept short enough for it (``CELL_CURVE_TOL``; on most grids the walk's
        narrowness sets the interval, far inside it), and the cells a bent line reaches outside
        the band between the edge lines the walk follows (only where the band is narrower than
        the bend, h^2 |d^2 P / domega^2| / 8: at a line's contact with a caustic): stated as
        5e-5 of a cell's probability plus 1e-12, tested over the whole parameter domain and at
        the folds (measured at most 2.4e-7 over 100 draws of the sweep with 0.1 SD pieces, where
        the linear ribbon at 5x the intervals left 7.2e-6; tests/engine/test_cell_probabilities.py).
        """
        if self.sigma_heading > 0.0 or not isinstance(domain, Grid):
            return super().cell_plan(domain, region)
        return grid_cell_plan(self, domain)

    def carried_cell_plan(self, domain, pack: EvidencePack) -> CellPlan | None:
        """The channels' cell masses with the pack's earlier evidence inside, exact in the
        acceleration (:mod:`bananagrid.models.cat_carried`; the hook of
        :class:`~bananagrid.protocol.CarryingModel`): ``run`` returns float64 ``(C, ny, nx)``,
        channel c's unnormalised weighted probability of each cell. For searches at one time
        each on a grid, without heading noise; None otherwise (the sub-cell rule on
        :meth:`bind_carried`'s densities serves)."""
        if self.sigma_heading > 0.0 or not isinstance(domain, Grid):
            return None
        polygons = cat_carried.polygons_of_pack(pack)
        if polygons is None:
            return None
        return grid_cell_plan(self, domain, polygons)

    def density_bound(self, x0: float, x1: float, y0: float, y1: float) -> float:
        """A proved bound of the density the grid kernel computes, in float32 or float64, at any
        point of the world rectangle [x0, x1] x [y0, y1]; 0.0 where it computes exact zeros
        (:meth:`bananagrid.protocol.DensityModel.density_bound`). A side at infinity (or beyond
        FARTHEST_BOUNDED) gets the whole plane's bound, :func:`plane_bound`.

        Without heading noise: :func:`scan_bounds` on the rectangle in the local frame, against
        the float64 and float32 scan tables (computed once by the kernels' own ``cat_table`` and
        cached on the model), refined into quarters while above :meth:`density_floor`. A node
        interval adds nothing where F keeps its sign beyond the kernel's chord threshold or the
        acceleration is beyond PRUNE_SIGMAS sigma_a on one side at both nodes: exact zeros beyond
        the fan of lines and beyond 38 sigma_a along them. Elsewhere the bound is finite, and
        below the floor where every line needs some 12 to 20 sigma_a.

        With heading noise the kernel interpolates a table built for the extent given to
        ``bind`` (one holding every queried point, so the stencils are centred: the kernel
        extrapolates beyond its rows, it does not return 0 there), not at hand here. Any such
        table's stencil reads rows within 2 dr of the point's range, dr <= dr_max
        (:func:`table_spacing_limits`). A row is the float64 base kernel on a full circle,
        convolved by FFT: exactly 0 where the base kernel is 0 at every bearing, else at most
        n_theta times its largest value (|irfft(G rfft(p))_j| <= sum |p| as |G| <= 1). So the
        base kernel is bounded over the ranges [near - 2.5 dr_max, far + 2.5 dr_max] (half a row
        and ``delta`` for the float32 row index) by sectors of that annulus, and
        :func:`interpolation_bound` carries the bound through the log-cubic stencils. The bound
        is useful only at ranges where no bearing holds the banana (a row through the banana
        has FFT rounding of the banana's peak at every bearing; nothing proves less there).
        """
        x0, x1, y0, y1 = (float(v) for v in (x0, x1, y0, y1))
        if not (x0 <= x1 and y0 <= y1):
            raise BananagridError(f"density_bound: rectangle [{x0}, {x1}] x [{y0}, {y1}] must have x0 <= x1, y0 <= y1")
        ox, oy = self.pose.origin
        # float32 world coordinates and pose, and the rotation, move a local point by this much
        # (the float64 kernels' rounding is far smaller)
        world = max(abs(x0), abs(x1)) + max(abs(y0), abs(y1)) + abs(ox) + abs(oy)
        delta = COORDINATE_ULPS * float(np.finfo(np.float32).eps) * world
        data = self.__dict__.get("_bound_data")
        if data is None:
            # the heading table is built from the float64 kernel alone
            dtypes = (np.float64,) if self.sigma_heading > 0.0 else (np.float64, np.float32)
            data = self.__dict__["_bound_data"] = bound_data(self, dtypes)  # a frozen dataclass: __dict__ caches
        if not world < FARTHEST_BOUNDED:  # an infinite side, or squares that would overflow
            whole = plane_bound(self, data)
            return interpolation_bound(table_spacing_limits(self)[1] * whole) if self.sigma_heading > 0.0 else whole
        floor = self.density_floor()
        if self.sigma_heading > 0.0:
            dr, n_theta = table_spacing_limits(self)
            near_x = 0.0 if x0 <= ox <= x1 else min(abs(x0 - ox), abs(x1 - ox))
            near_y = 0.0 if y0 <= oy <= y1 else min(abs(y0 - oy), abs(y1 - oy))
            near = math.hypot(near_x, near_y) - delta
            far = math.hypot(max(abs(x0 - ox), abs(x1 - ox)), max(abs(y0 - oy), abs(y1 - oy))) + delta
            # 2 dr of stencil, half a row more for the rounding of the row index
            inner, outer = max(0.0, near - 2.5 * dr), far + 2.5 * dr
            # the lattice's float64 points, in the base model's own frame
            parts = annulus_parts(inner, outer, HEADING_BOUND_SECTORS, 4.0 * float(np.finfo(np.float64).eps) * outer)
            row = refined_bound(self, data, parts, _row_target(floor, n_theta), HEADING_BOUND_REFINEMENTS)
            return 0.0 if row == 0.0 else interpolation_bound(n_theta * row)
        c, s = math.cos(self.pose.heading), math.sin(self.pose.heading)
        dx, dy = 0.5 * (x0 + x1) - ox, 0.5 * (y0 + y1) - oy
        hx, hy = 0.5 * (x1 - x0), 0.5 * (y1 - y0)
        # world_to_local: (dx c - dy s, dx s + dy c)
        part = np.array([[dx * c - dy * s, dx * s + dy * c, hx * c, hx * s, -hy * s, hy * c, delta]])
        return refined_bound(self, data, part, floor, BOUND_REFINEMENTS)

    def sample(self, n: int, rng) -> np.ndarray:
        """Draw ``n`` world positions: a and omega from their normal laws, then eq. (1), turned
        by a heading error theta_0 ~ N(0, sigma_heading) when there is one.

        The turn rate is not truncated here (the truncated mass is below 1e-15 by default).
        """
        n, rng = check_n(n, self.sample_bytes), check_rng(rng)
        a = rng.normal(0.0, self.sigma_a, n)
        omega = rng.normal(0.0, self.sigma_omega, n)
        local = cat_position(self.v0, self.t, a, omega)
        if self.sigma_heading > 0.0:
            local = _rotate(local, rng.normal(0.0, self.sigma_heading, n))
        return self.pose.to_world(local)

    def sample_paths(self, n: int, times, rng) -> np.ndarray:
        """World positions of ``n`` draws at each of ``times`` (s since the last fix), shape
        ``(n, len(times), 2)``: the generative story of :meth:`sample` (a, omega and the heading
        error drawn once per draw, in that order), each draw's path placed at every time by
        eq. (1); ``sample_paths(n, [t], rng)[:, 0]`` equals ``sample(n, rng)`` for the same seed.

        Raises
        ------
        BananagridError
            Times that are not finite or negative; ``n`` or ``rng`` as :meth:`sample`.
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if times.ndim != 1 or times.size == 0 or not np.isfinite(times).all() or (times < 0.0).any():
            raise BananagridError(f"times = {times.tolist()!r}: expected finite times >= 0 (s since the last fix)")
        n, rng = check_n(n, self.sample_bytes + 16.0 * len(times)), check_rng(rng)  # + the positions
        a = rng.normal(0.0, self.sigma_a, n)
        omega = rng.normal(0.0, self.sigma_omega, n)
        theta0 = rng.normal(0.0, self.sigma_heading, n) if self.sigma_heading > 0.0 else None
        out = np.empty((n, len(times), 2))
        for k, s in enumerate(times):
            local = cat_position(self.v0, s, a, omega)
            out[:, k] = self.pose.to_world(local if theta0 is None else _rotate(local, theta0))
        return out

    def ray_values(self, pose: Pose, radii: np.ndarray, angles: np.ndarray, *, threads=None) -> np.ndarray:
        """p(r, theta) along rays; from the model's own pose with heading noise, exactly by the
        Fourier series of the heading-convolved rows (no table interpolation)."""
        if self.sigma_heading > 0.0 and pose == self.pose:
            return ray_densities(self, radii, angles, threads=threads)
        return super().ray_values(pose, radii, angles, threads=threads)
