"""CAT cell probabilities with earlier evidence inside: each path weighted by what it met at
earlier times, exact in the acceleration along each line of constant turn rate.

For a fixed turn rate omega the CAT position at ANY time s is affine in z = a / sigma_a (eq. (1)
of the polar-banana paper), so as z runs along the line of omega at the map's time t, the same
paths' positions at an earlier time s run along the line of omega at s. A polygon at s (an area
searched at that time, with 1 - POD inside; land, 0 inside) is crossed by that earlier line at
a few z: between the crossings the weight is constant, and a cell that the line at t crosses
between z_in and z_out holds, of that turn rate,

    sum over the pieces of [z_in, z_out] cut at the crossings of  w_piece (Phi(z_hi) - Phi(z_lo)),

exactly (``kernels/cat_cells.py``, ``weighted_share``). Over omega the rule is the plain one's
(:meth:`bananagrid.models.cat.CAT.cell_plan`): Gauss-Legendre between the turn rates where the
line at t passes a corner of the cell, with these breaks added where the share has kinks: the
turn rates where an earlier line passes a polygon vertex, and where a crossing enters or leaves
the cell's window [z_in, z_out].

Several polygons combine as independent looks (the product of their factors), and one pass
gives several channels, each the map weighted by a chosen subset of the polygons (bit masks):
the prior (no polygon), each search alone, all of them.

Error: as the plain rule's, 5e-5 of a cell's probability plus 1e-12 (tested against an
independent oracle over the CAT domain, folds included, and at the cells the polygons cut
hardest): the pieces in z are exact and every kink in omega is a break (the vertex passes of
the earlier lines refined on their bent interpolation, like the corner passes at t); the
crossings of the earlier lines with the polygons' edges move by at most Z_CROSSING SDs over a
Gauss part (so none enters and leaves a cell's window unseen); what remains is the quadratic
interpolation of the lines through each turn-rate interval's edges and middle, third order in
the interval, at t and at the earlier times alike (at an earlier time, in SDs along the line,
below the tolerance held at t: the lines' third derivative in omega grows as the time's fourth
and fifth powers, the SD along them as its square). Without polygons the result is the plain rule's bit
for bit; with them, the prior channel (and each channel over the parts of the
turn-rate range its own polygons do not cut) takes the plain rule's terms, regrouped: the prior
channel is the plain rule's cells to float64 rounding, polygons on or along the earlier lines
included.

Searches at one time (and land at one time) only: a search over an interval, a raster, a track
or a report is a factor that varies smoothly along the line, not taken here
(:func:`polygons_of_pack` returns None for such a pack, and the posterior takes the density's
sub-cell rule).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..domains.grid import Grid
from ..kernels import cat_cells
from ..kernels import evidence as evidence_kernels
from ..protocol import EvidencePack, KernelContext
from ..validate import BananagridError

__all__ = ["EarlierPolygons", "grid_cell_channels", "polygons_of_pack", "CELL_METHOD"]

#: Provenance line of the rule.
CELL_METHOD = "exact in the acceleration, Gauss-Legendre between corner passes over the turn rate"


@dataclass(frozen=True)
class EarlierPolygons:
    """Polygons at earlier times, each a factor on the paths that are inside it then, and the
    channels to weight by them.

    Parameters
    ----------
    vertices : sequence of array_like (n_p, 2)
        Each polygon's vertices, world metres (a simple polygon, validated by its evidence).
    times : sequence of float
        Each polygon's time, s since the last fix, in [0, the map's t].
    miss : sequence of float
        Each polygon's factor inside it, in [0, 1]: 1 - POD of a search, 0 for land.
    masks : sequence of int
        Each channel's polygons as bits (bit p: polygon p); 0 is the prior.
    """

    vertices: tuple
    times: np.ndarray
    miss: np.ndarray
    masks: tuple = (0,)
    count: int = field(init=False)

    def __post_init__(self):
        vertices = tuple(np.asarray(v, dtype=np.float64) for v in self.vertices)
        count = len(vertices)
        if count > cat_cells.MAX_POLYGONS:
            raise BananagridError(f"evidence: {count} polygons at earlier times; the CAT cell rule takes at most "
                                  f"{cat_cells.MAX_POLYGONS}")
        for p, v in enumerate(vertices):
            if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3 or not np.all(np.isfinite(v)):
                raise BananagridError(f"polygons[{p}]: expected (n >= 3, 2) finite vertices, got shape {v.shape}")
        times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        miss = np.asarray(self.miss, dtype=np.float64).reshape(-1)
        if len(times) != count or len(miss) != count:
            raise BananagridError(f"polygons: {count} polygons, {len(times)} times and {len(miss)} factors; "
                                  "expected one of each per polygon")
        if np.any(~np.isfinite(times)) or np.any(times < 0.0):
            raise BananagridError(f"times = {times.tolist()!r}: must be finite and >= 0 (s since the last fix)")
        if np.any(~(miss >= 0.0)) or np.any(miss > 1.0):
            raise BananagridError(f"miss = {miss.tolist()!r}: each factor must be in [0, 1]")
        masks = tuple(int(m) for m in self.masks)
        if not masks or any(m < 0 or m >= 1 << count for m in masks):
            raise BananagridError(f"masks = {masks!r}: each channel is a bit mask of the {count} polygons")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "miss", miss)
        object.__setattr__(self, "masks", masks)
        object.__setattr__(self, "count", count)


def _frame(model, grid: Grid):
    """The kernels' :class:`kernels.cat_cells.Frame` of ``model``'s lines on ``grid``."""
    f = cat_cells.Frame()
    f.v0, f.sigma_a, f.pose = model.v0, model.sigma_a, cat_cells.VEC4(*model.pose.as_array())
    f.x_edge, _, f.y_edge, _ = grid.extent
    f.dx, f.dy = grid.dx, grid.dy
    return f


def _earlier(ctx: KernelContext, frame, grid: Grid, edges: np.ndarray, polygons: EarlierPolygons | None):
    """The kernels' :class:`kernels.cat_cells.Earlier` for ``polygons`` on ``grid`` (grid
    coordinates: (world - edge) / cell size), with the earlier lines at every interval edge."""
    ev = cat_cells.Earlier()
    count = 0 if polygons is None else polygons.count
    x0, _, y0, _ = grid.extent
    local = [(v - (x0, y0)) / np.array([grid.dx, grid.dy]) for v in polygons.vertices] if count else []
    ev.starts = ctx.array(np.concatenate(([0], np.cumsum([len(v) for v in local]))).astype(np.int32), dtype=np.int32)
    ev.edges = ctx.array(np.concatenate([np.hstack((v, np.roll(v, -1, axis=0))) for v in local]) if count
                         else np.zeros((0, 4)), dtype=np.float64)
    ev.boxes = ctx.array(np.array([(v[:, 0].min(), v[:, 0].max(), v[:, 1].min(), v[:, 1].max()) for v in local])
                         if count else np.zeros((0, 4)), dtype=cat_cells.VEC4)
    ev.miss = ctx.array(polygons.miss if count else np.zeros(0), dtype=np.float64)
    ev.masks = ctx.array(np.asarray((0,) if polygons is None else polygons.masks, dtype=np.int32), dtype=np.int32)
    ev.count = count
    ev.channels = 1 if polygons is None else len(polygons.masks)
    ev.lines = ctx.zeros((count, 2 * len(edges) - 1 if count else 0), dtype=cat_cells.VEC4)
    if count:
        ctx.load(cat_cells.earlier_lines)
        ctx.launch(cat_cells.earlier_lines, dim=(count, 2 * len(edges) - 1), inputs=[
            ctx.array(edges, dtype=np.float64), ctx.array(polygons.times, dtype=np.float64), frame, ev.lines])
    return ev


def grid_cell_channels(ctx: KernelContext, model, grid: Grid, edges: np.ndarray,
                       polygons: EarlierPolygons | None = None) -> np.ndarray:
    """The CAT cell probabilities of ``grid`` over the turn-rate intervals ``edges``
    (:func:`bananagrid.models.cat.cell_turn_edges`), float64 ``(channels, ny, nx)``: one
    channel (the plain cell probabilities) without ``polygons``, else one per mask, each cell
    the integral over its paths of the product of the factors of the mask's polygons (channels
    with the same mask are computed once)."""
    unique = None
    if polygons is not None:
        masks = list(dict.fromkeys(polygons.masks))
        unique = EarlierPolygons(vertices=polygons.vertices, times=polygons.times, miss=polygons.miss,
                                 masks=tuple(masks))
    frame = _frame(model, grid)
    ev = _earlier(ctx, frame, grid, edges, unique)
    out = ctx.zeros((ev.channels, grid.ny, grid.nx), dtype=np.float64)
    head = [ctx.array(edges, dtype=np.float64), np.float64(model.sigma_omega), np.float64(model.t), frame]
    ctx.load(cat_cells.cat_cells)

    def launch(r0, r1):
        ctx.launch(cat_cells.cat_cells, dim=len(edges) - 1, inputs=[*head, r0, r1, grid.nx, ev, out])

    # a band walks every interval's lines again: four a thread balance the threads' work, one
    # thread takes one band
    ctx.run_bands(launch, ctx.bands(grid.ny, 4 if ctx.threads > 1 else 1))
    values = ctx.numpy(out)
    if unique is None:
        return values
    return values[[masks.index(m) for m in polygons.masks]]


def polygons_of_pack(pack: EvidencePack) -> EarlierPolygons | None:
    """The pack's factors as :class:`EarlierPolygons` where each is a search at one time (one
    polygon node, ``q`` = 1: log(1 - POD) inside), with the pack's channels as bit masks of
    them; None where any factor is another kind (an interval, a raster, a track, a report: the
    caller takes the density's sub-cell rule then)."""
    factors = pack.factors if pack.nodes else 0
    if factors > cat_cells.MAX_POLYGONS:
        return None
    node_of = {}
    for j in range(pack.nodes):
        kind, factor, _, _ = (int(v) for v in pack.ints[j])
        if kind != evidence_kernels.KIND_POLYGON or pack.q[j] != 1.0 or factor in node_of:
            return None
        node_of[factor] = j
    if sorted(node_of) != list(range(factors)):
        return None
    vertices, times, miss = [], [], []
    for k in range(factors):
        j = node_of[k]
        _, _, offset, count = (int(v) for v in pack.ints[j])
        vertices.append(pack.edges[offset:offset + count, :2])
        times.append(float(pack.time[j]))
        miss.append(math.exp(float(pack.data[j, 0])))  # log(1 - POD); exp(-inf) = 0: land or POD 1
    masks = tuple(int(sum(1 << k for k in range(factors) if row[k])) for row in np.asarray(pack.channels))
    return EarlierPolygons(vertices=vertices, times=times, miss=miss, masks=masks)
