"""Cell probabilities of any model on a polar lattice: a Gauss-Legendre rule sized from the
model's own length scales.

The sub-cells are no larger than the model's length scales (``model.polar_scales``, through
the model protocol), and a cell that a seam of the model's density crosses along a bearing of
the lattice (``model.seams``: a polar density's angle wrapping at +-pi behind its start, when
the seam starts at the lattice's origin or its line passes through it) is integrated on each
side of it. A seam whose line misses the origin crosses the cells along a curve r*(b) in (r,
b): the cells it crosses are integrated again with each bearing node's range interval split
at r*(b) and the bearings where it crosses the cells' arcs as breaks (:func:`_foreign_cells`),
as are the cells near a seam's start (a station, about which the density changes with the
direction) with sub-intervals of a quarter of their distance to it. A cell that holds a seam's
start or a 1 / r point off the origin is swept in polar coordinates about that point over the
annular sector (:func:`_point_cells`). About a point where the model has a closed radial law
(a polar banana posed elsewhere) the sweep is exact in range, and it takes the cells that
point's seams cross and every cell where the tensor rule about the lattice's origin is not to
be trusted: near the point, or where the law's SD or the arc over which its ridge moves by an
SD is narrower than the rule's length scale (behind the start, and at the improved
variant's P_sigma = 0 edge, where the ridge narrows to a point). Its bearing is cut where the
rays' clip by the cell changes (corners, tangents, the bounding lines' directions) and where
the ridge crosses the cell's edges, and its sub-intervals turn an end of the rays' clip near the
ridge by at most half an SD (a ray grazing a bounding line moves its crossing fast). Every node is evaluated by the model's own kernels
through :func:`bananagrid.engine.points.evaluate_points`.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from ..domains.polar_lattice import PolarLattice
from ..protocol import DensityModel
from ..results import PolarRaster
from ..validate import BananagridError, BananagridWarning
from .points import check_finite, check_model, evaluate_points
from .quadrature import (GAUSS_TOL, GRADE_SPLIT, MAX_ORDER, MAX_SUBINTERVALS, axis_plan, graded_rule, narrowing,
                         normal_shares, ray_circle_points, seam_ranges, split_segments, unit_rule)
from .warp_runtime import check_threads
from .work import check_work

__all__ = ["rasterise_lattice", "LatticeExtent", "GAUSS_TOL", "MAX_NODES"]

#: Most quadrature nodes over the whole lattice (about 30 s of CAT evaluations on two cores).
#: Beyond it the sub-intervals are coarsened and a warning says what accuracy is left.
MAX_NODES = 2**26

#: Bearings per piece at which a radial law's SD is sampled.
LAW_PROBES = 33

#: Points per evaluate_points call (bounds the memory of the node arrays: ~100 MB at 2**20).
NODE_CHUNK = 2**20



class LatticeExtent:
    """A whole polar lattice, seen from an origin: one range for every chunk of its nodes, so
    that a tabulated model (CAT with heading noise) builds its table once."""

    def __init__(self, lattice: PolarLattice):
        self.lattice = lattice

    def radii(self, origin) -> tuple[float, float]:
        offset = math.dist(origin, self.lattice.pose.origin)
        r_min, r_max = self.lattice.range_edges[0], self.lattice.range_edges[-1]
        return max(0.0, r_min - offset), r_max + offset


@dataclass(frozen=True)
class _Plan:
    radial: tuple[int, int]  # (m, n) for every row
    angular: list  # (m, n) per row
    error: float  # largest estimated error per sub-interval (radial + angular)
    scales: tuple[float, float]
    rule: str  # "model frame" or "cartesian"
    total_nodes: int


def _plan(model: DensityModel, lattice: PolarLattice) -> _Plan:
    """Sub-intervals and nodes per cell: sub-cells no larger than the model's length scales.

    With a motion model whose pose is the lattice's, the model's polar scales apply directly.
    Otherwise the Cartesian scale L (``model.feature_scale()``) bounds the radial sub-step and
    ``L / r1`` the angular one in a row whose outer edge is r1 (a cell's arc there is r1 db).
    """
    radial, angular = model.polar_scales(lattice.pose.origin)
    own_frame = model.pose is not None and model.pose.same_as(lattice.pose)
    dr, db = lattice.range_step, lattice.bearing_step
    outer = lattice.range_edges[1:]
    if own_frame:
        r_scale, b_scales = radial, np.full(lattice.n_range, angular)
    else:
        r_scale = model.feature_scale()
        b_scales = r_scale / outer
    cells_per_row = lattice.n_bearing
    cap = MAX_SUBINTERVALS
    while True:
        rm, rn, r_err = axis_plan(dr, r_scale, cap)
        rows = [axis_plan(db, s, cap) for s in b_scales]
        total = rm * rn * cells_per_row * sum(m * n for m, n, _ in rows)
        if total <= MAX_NODES or cap == 1:
            break
        cap = max(1, cap // 2)
    error = min(1.0, r_err + max(e for _, _, e in rows))
    if error > 10.0 * GAUSS_TOL:
        effect = (
            "leave the cell probabilities without an accuracy bound (sub-cells much wider than "
            "the model's length scales)"
            if error >= 0.01
            else f"limit the cell probabilities' accuracy to about {error:.2g} of the mass per sub-cell"
        )
        warnings.warn(
            f"polar lattice: the node caps ({MAX_SUBINTERVALS} sub-intervals per cell and axis, "
            f"{MAX_NODES:,} nodes in all; {cap} sub-intervals used) {effect} (target "
            f"{GAUSS_TOL:g}); use smaller cells or a smaller lattice",
            BananagridWarning, stacklevel=4,
        )
    return _Plan(
        radial=(rm, rn),
        angular=[(m, n) for m, n, _ in rows],
        error=error,
        scales=(r_scale, float(np.min(b_scales))),
        rule="model frame" if own_frame else "cartesian",
        total_nodes=int(total),
    )


# --------------------------------------------------------------------------------------------
# Rasterising
# --------------------------------------------------------------------------------------------


def _tasks(n_pieces: int, plan: _Plan):
    """Blocks ``(row, j0, j1, a0, a1)`` of at most NODE_CHUNK nodes: bearing pieces j0:j1 of
    ``row`` with radial nodes a0:a1."""
    rm, rn = plan.radial
    n_r_nodes = rm * rn
    nb = n_pieces
    for row, (m, n) in enumerate(plan.angular):
        k = m * n
        if n_r_nodes * k <= NODE_CHUNK:
            per = max(1, NODE_CHUNK // (n_r_nodes * k))
            for j0 in range(0, nb, per):
                yield row, j0, min(nb, j0 + per), 0, n_r_nodes
        else:
            per_a = max(1, NODE_CHUNK // k)
            for j in range(nb):
                for a0 in range(0, n_r_nodes, per_a):
                    yield row, j, j + 1, a0, min(n_r_nodes, a0 + per_a)


#: A seam whose line passes within this fraction of its start's distance of the lattice's
#: origin is taken as a ray of the lattice (a bearing cut) rather than a curve across it.
THROUGH_ORIGIN = 1e-13


def _split_seams(model: DensityModel, lattice: PolarLattice) -> tuple[list, np.ndarray]:
    """The model's seams (:meth:`~bananagrid.protocol.DensityModel.seams`) as the lattice sees
    them: ``(cuts, foreign)``. A seam on a line through the origin is along the lattice's
    bearings: ``cuts`` holds them (relative to the heading): its own bearing, and the opposite
    one where the origin lies ahead of its start. Every other seam crosses the cells along a
    curve: ``foreign``, rows (x, y, bearing), which :func:`_foreign_cells` integrates."""
    ox, oy = lattice.pose.origin
    cuts, foreign = [], []
    for x, y, bearing in np.asarray(model.seams(), dtype=float).reshape(-1, 3):
        qx, qy = x - ox, y - oy
        vx, vy = math.sin(bearing), math.cos(bearing)
        distance = math.hypot(qx, qy)
        if abs(qx * vy - qy * vx) <= THROUGH_ORIGIN * distance:
            cuts.append(bearing - lattice.pose.heading)
            if -(qx * vx + qy * vy) > 0.0:  # the origin is ahead of the start: the seam passes it
                cuts.append(bearing + math.pi - lattice.pose.heading)
        else:
            foreign.append((x, y, bearing))
    return cuts, np.array(foreign, dtype=np.float64).reshape(-1, 3)


def _bearing_pieces(model: DensityModel, lattice: PolarLattice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lo, hi, column)``: the bearing intervals the rule integrates, each cell's interval cut
    at the bearings of the model's seams that lie along the lattice's rays (from its origin or
    through it: a kink of the density there becomes a break of the rule, like a cell edge).
    Seams that cross the cells along curves are the business of :func:`_foreign_cells`."""
    edges = lattice.bearing_edges
    cuts, _ = _split_seams(model, lattice)
    lo, hi, column, seam = [], [], [], []
    two_pi = 2.0 * math.pi
    for j in range(lattice.n_bearing):
        a, b = float(edges[j]), float(edges[j + 1])
        at = {a + (c - a) % two_pi for c in cuts}
        inside = sorted(at - {a})
        breaks = [a] + [c for c in inside if c < b] + [b]
        on = at | {c - two_pi for c in at}
        for u, v in zip(breaks[:-1], breaks[1:]):
            lo.append(u), hi.append(v), column.append(j), seam.append((u in on, v in on))
    return np.array(lo), np.array(hi), np.array(column), seam


def _law_cells(model: DensityModel, lattice: PolarLattice, law) -> np.ndarray:
    """Cell probabilities exact in r for a density that is g(theta) N(r; mu, sd) / r about the
    lattice's origin (``model.polar_law``): per bearing piece, sum over bearing nodes of
    w g [Phi((r_(i+1) - mu) / sd) - Phi((r_i - mu) / sd)], every row at once. The nodes are
    :func:`~bananagrid.engine.quadrature.graded_rule`'s, their sub-intervals no wider than the
    model's angular scale nor than half the law's least SD on the piece over the lattice's
    outer range (where the ridge crosses a range edge, a share turns over sd / r), graded
    toward the seams (the improved variant's P_sigma = 0 edge)."""
    p_lo, p_hi, p_column, seam = _bearing_pieces(model, lattice)
    r_edges = lattice.range_edges
    far = max(float(r_edges[-1]), 1e-300)
    angular = model.polar_scales(lattice.pose.origin)[1]
    heading = lattice.pose.heading
    # one evaluation of the law for every piece's probes, one for every piece's nodes
    probes = np.linspace(p_lo, p_hi, LAW_PROBES, axis=1)
    _, _, sd_probes = law(heading + probes.ravel())
    rules = []
    for k, (a, b, graded) in enumerate(zip(p_lo, p_hi, seam)):
        sd = sd_probes[k * LAW_PROBES:(k + 1) * LAW_PROBES]
        live = sd[sd > 0.0]
        scale = min(angular, 0.5 * float(live.min()) / far) if live.size else angular
        narrow = narrowing(sd)  # graded only toward a seam where the SD falls (P_sigma = 0)
        rules.append(graded_rule(float(a), float(b), scale, (graded[0] and narrow[0], graded[1] and narrow[1])))
    g, mu, sd = law(heading + np.concatenate([nodes for nodes, _ in rules]))
    probability = np.zeros(lattice.shape)
    start = 0
    for (nodes, w), j in zip(rules, p_column):
        part = slice(start, start + nodes.size)
        start += nodes.size
        shares = normal_shares(g[None, part], mu[None, part], sd[None, part], r_edges[:-1, None], r_edges[1:, None])
        probability[:, j] += shares @ w
    return probability


def _groups(tasks):
    """Consecutive tasks gathered up to NODE_CHUNK nodes per evaluation."""
    group, size = [], 0
    for task in tasks:
        row, j0, j1, a0, a1, k = task
        nodes = (j1 - j0) * (a1 - a0) * k
        if group and size + nodes > NODE_CHUNK:
            yield group
            group, size = [], 0
        group.append(task)
        size += nodes
    if group:
        yield group


def _integrate(model: DensityModel, lattice: PolarLattice, plan: _Plan, *, dtype, device, threads) -> np.ndarray:
    """Cell probabilities: sum over nodes of w_r(r) r w_b p(O + r u(h + b)), float64, the
    bearing cut at the model's seams through the origin (:func:`_bearing_pieces`)."""
    r_edges = lattice.range_edges
    law = model.polar_law(lattice.pose.origin)
    if law is not None:
        probability = _law_cells(model, lattice, law)
    else:
        probability = _tensor_cells(model, lattice, plan, dtype=dtype, device=device, threads=threads)
    # the cells swept about a point are set there: the rule in the lattice's frame skips them
    choice = _point_choice(model, lattice, plan)
    _foreign_cells(model, lattice, plan, probability, set(choice[2]), dtype=dtype, device=device, threads=threads)
    _point_cells(model, lattice, probability, choice, dtype=dtype, device=device, threads=threads)
    return probability


def _tensor_cells(model: DensityModel, lattice: PolarLattice, plan: _Plan, *, dtype, device, threads) -> np.ndarray:
    """The tensor rule over every cell's bearing pieces (:func:`_integrate`)."""
    r_edges = lattice.range_edges
    p_lo, p_hi, p_column, _ = _bearing_pieces(model, lattice)
    r_nodes, r_weights = unit_rule(*plan.radial)
    b_rules = {mn: unit_rule(*mn) for mn in set(plan.angular)}
    heading = lattice.pose.heading
    ox, oy = lattice.pose.origin
    probability = np.zeros(lattice.shape)

    def expand():
        for row, j0, j1, a0, a1 in _tasks(len(p_lo), plan):
            yield row, j0, j1, a0, a1, len(b_rules[plan.angular[row]][0])

    extent = LatticeExtent(lattice)
    for group in _groups(expand()):
        xs, ys, parts = [], [], []
        for row, j0, j1, a0, a1, _ in group:
            r0, r1 = r_edges[row], r_edges[row + 1]
            r = r0 + (r1 - r0) * r_nodes[a0:a1]
            w_r = (r1 - r0) * r_weights[a0:a1] * r  # the polar area element r dr
            v, w_v = b_rules[plan.angular[row]]
            lo, hi = p_lo[j0:j1, None], p_hi[j0:j1, None]
            theta = heading + lo + (hi - lo) * v[None, :]  # (J, K)
            w_b = (hi - lo) * w_v[None, :]
            s, c = np.sin(theta), np.cos(theta)
            xs.append((ox + r[:, None, None] * s[None]).ravel())
            ys.append((oy + r[:, None, None] * c[None]).ravel())
            parts.append((row, j0, j1, w_r, w_b, r.size, theta.shape))
        values = evaluate_points(
            model, np.concatenate(xs), np.concatenate(ys), dtype=dtype, device=device, threads=threads,
            extent=extent,
        )
        start = 0
        for row, j0, j1, w_r, w_b, a, (J, K) in parts:
            block = values[start : start + a * J * K].reshape(a, J, K)
            start += a * J * K
            pieces = np.einsum("a,ajk,jk->j", w_r, block, w_b, dtype=np.float64)
            np.add.at(probability[row], p_column[j0:j1], pieces)  # in piece order: no thread dependence
    return probability


#: A crossed cell's sub-intervals are at most this fraction of its distance to a seam's start.
NEAR_FRACTION = 0.25


def _distance_to_cell(points, origin, heading, ranges, bearings) -> float:
    """A lower bound of the distance from the nearest of ``points`` to the annular sector
    ``ranges`` x ``bearings`` (0 for a point inside): the distance to the annulus, or to the
    nearer bounding ray where the point's bearing lies outside the sector's."""
    (r0, r1), (b0, b1) = ranges, bearings
    best = math.inf
    for px, py in points:
        dx, dy = px - origin[0], py - origin[1]
        r = math.hypot(dx, dy)
        radial = max(0.0, r0 - r, r - r1)
        rel = b0 + (math.atan2(dx, dy) - heading - b0) % (2.0 * math.pi)
        if rel <= b1:
            best = min(best, radial)
            continue
        # outside the sector's bearings: at least the distance to the nearer bounding ray
        gap = min(rel - b1, b0 + 2.0 * math.pi - rel)  # rel in (b1, b0 + 2 pi): both positive
        best = min(best, max(radial, r * math.sin(min(gap, 0.5 * math.pi))))
    return best


def _crossed_cells(lattice: PolarLattice, foreign: np.ndarray) -> set:
    """The cells ``(i, j)`` that a seam of ``foreign`` crosses or ends in: its curve in (r, b)
    enters and leaves a cell through its arcs (a crossing of a range edge's circle) or its
    radial sides (a crossing of a bearing edge's ray), or ends at its start inside."""
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    origin = lattice.pose.origin
    heading = lattice.pose.heading
    n_r, n_b = lattice.n_range, lattice.n_bearing
    out = set()

    def column(bearing):  # the lattice column of a world bearing, or None outside the lattice
        rel = b_edges[0] + (bearing - heading - b_edges[0]) % (2.0 * math.pi)
        j = int(np.searchsorted(b_edges, rel, side="right")) - 1
        return j if 0 <= j < n_b else (n_b - 1 if rel == b_edges[-1] else None)

    def row(r):
        i = int(np.searchsorted(r_edges, r, side="right")) - 1
        return i if 0 <= i < n_r else (n_r - 1 if r == r_edges[-1] else None)

    for seam in foreign:
        for e, radius in enumerate(r_edges):
            if radius <= 0.0:
                continue
            for px, py in ray_circle_points(seam, origin, float(radius)):
                j = column(math.atan2(px - origin[0], py - origin[1]))
                if j is not None:
                    out |= {(i, j) for i in (e - 1, e) if 0 <= i < n_r}
        ranges = seam_ranges(origin, heading + b_edges, seam[None, :])[:, 0]
        for e, r in enumerate(ranges):
            if np.isfinite(r):
                i = row(float(r))
                if i is not None:
                    out |= {(i, j) for j in (e - 1, e) if 0 <= j < n_b}
        qx, qy = seam[0] - origin[0], seam[1] - origin[1]
        i, j = row(math.hypot(qx, qy)), column(math.atan2(qx, qy))
        if i is not None and j is not None:
            out.add((i, j))
    return out


def _near_cells(lattice: PolarLattice, plan: _Plan, starts: np.ndarray) -> set:
    """The cells too near one of ``starts`` (seams' starts off the origin) for the tensor rule:
    about a start the density changes with the direction on the scale of the distance d, and an
    n-point Gauss rule on a sub-interval of width h at a distance d from such a point errs by
    about (h / 4d)^(2n) (the singularity bounds the Bernstein ellipse): the cells where that
    exceeds GAUSS_TOL, radially or along the arc at the row's outer edge."""
    out = set()
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    r0, r1 = r_edges[:-1], r_edges[1:]
    rm, rn = plan.radial
    m_b = np.array([m for m, _ in plan.angular], dtype=float)
    n_b = np.array([n for _, n in plan.angular], dtype=float)
    h_r, h_b = lattice.range_step / rm, r1 * lattice.bearing_step / m_b
    # the distance below which (h / 4d)^(2n) > GAUSS_TOL, per row: the larger of the two axes'
    sub = np.maximum(h_r / (4.0 * GAUSS_TOL ** (1.0 / (2.0 * rn))), h_b / (4.0 * GAUSS_TOL ** (1.0 / (2.0 * n_b))))
    ox, oy = lattice.pose.origin
    for px, py in starts:
        dx, dy = px - ox, py - oy
        r = math.hypot(dx, dy)
        radial = np.maximum(0.0, np.maximum(r0 - r, r - r1))
        rel = b_edges[0] + (math.atan2(dx, dy) - lattice.pose.heading - b_edges[0]) % (2.0 * math.pi)
        circular = lambda d: np.abs((d + math.pi) % (2.0 * math.pi) - math.pi)  # noqa: E731
        gap = np.where((b_edges[:-1] <= rel) & (rel <= b_edges[1:]), 0.0,
                       np.minimum(circular(rel - b_edges[:-1]), circular(rel - b_edges[1:])))
        across = r * np.sin(np.minimum(gap, 0.5 * math.pi))
        distance = np.maximum(radial[:, None], across[None, :])
        out |= set(map(tuple, np.argwhere(distance < sub[:, None]).tolist()))
    return out


def _foreign_cells(model: DensityModel, lattice: PolarLattice, plan: _Plan, probability: np.ndarray, skip: set, *,
                   dtype, device, threads) -> None:
    """Integrate again the cells that seams off the lattice's rays cross (``foreign`` of
    :func:`_split_seams`), and those near a seam's start off the origin, but not those of
    ``skip`` (swept about a point, :func:`_point_cells`), and set them in ``probability``.

    A seam that is a half-line from Q not through the origin O meets the ray from O at bearing
    b at one range r*(b) at most (:func:`~bananagrid.engine.quadrature.seam_ranges`): each
    bearing node's range interval is split there, so every radial piece is smooth. Between the
    bearings at which a seam crosses the cell's arcs (and Q's bearing), r*(b) stays inside or
    outside the cell, and each node's integral is smooth in b: those bearings are breaks. About
    Q the density changes with the direction on the scale of the distance: sub-intervals are at
    most NEAR_FRACTION of the cell's distance to the nearest start, and no wider than the
    tensor rule's, MAX_ORDER nodes each. A cell that holds a start, touches it or lies within
    TOUCH_FRACTION of its diameter of it is swept about it instead (``skip``)."""
    cuts, foreign = _split_seams(model, lattice)
    origin, heading = lattice.pose.origin, lattice.pose.heading
    ox, oy = origin
    seams = np.asarray(model.seams(), dtype=float).reshape(-1, 3)
    starts = np.unique(seams[:, :2], axis=0) if len(seams) else np.zeros((0, 2))
    starts = starts[np.hypot(starts[:, 0] - ox, starts[:, 1] - oy) > 0.0]
    if not len(starts) and not len(foreign):
        return
    cells = sorted((_crossed_cells(lattice, foreign) | _near_cells(lattice, plan, starts)) - skip)
    if not cells:
        return
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    db, dr = lattice.bearing_step, lattice.range_step
    extent = LatticeExtent(lattice)
    two_pi = 2.0 * math.pi
    totals = np.zeros(len(cells))
    batch = {"x": [], "y": [], "w": [], "owner": [], "size": 0}

    def flush():
        if not batch["size"]:
            return
        values = evaluate_points(model, np.concatenate(batch["x"]), np.concatenate(batch["y"]), dtype=dtype,
                                 device=device, threads=threads, extent=extent).astype(float)
        totals[:] += np.bincount(np.concatenate(batch["owner"]), weights=np.concatenate(batch["w"]) * values,
                                 minlength=len(cells))  # in node order: no thread dependence
        batch.update(x=[], y=[], w=[], owner=[], size=0)

    for n, (i, j) in enumerate(cells):
        r0, r1 = float(r_edges[i]), float(r_edges[i + 1])
        a, b = float(b_edges[j]), float(b_edges[j + 1])
        near = _distance_to_cell(starts, origin, heading, (r0, r1), (a, b)) if len(starts) else math.inf
        limit = NEAR_FRACTION * near if near > 0.0 else math.inf
        m_r, _, _ = axis_plan(dr, min(dr / plan.radial[0], limit), MAX_SUBINTERVALS)
        u_r, w_r = unit_rule(m_r, MAX_ORDER)
        at = list(cuts)
        for seam in foreign:
            at += [math.atan2(px - ox, py - oy) - heading
                   for radius in (r0, r1) if radius > 0.0 for px, py in ray_circle_points(seam, origin, radius)]
            at.append(math.atan2(seam[0] - ox, seam[1] - oy) - heading)
        edges = sorted({a, b} | {a + (c - a) % two_pi for c in at if a < a + (c - a) % two_pi < b})
        m, _ = plan.angular[i]
        rules = [graded_rule(lo, hi, min(db / m, limit / max(r1, 1e-300)), (False, False))
                 for lo, hi in zip(edges[:-1], edges[1:])]
        theta = np.concatenate([t for t, _ in rules])
        w_t = np.concatenate([w for _, w in rules])
        world = heading + theta
        lo, hi = split_segments(np.full(theta.size, r0), np.full(theta.size, r1), seam_ranges(origin, world, foreign))
        xs, ys, ws = _radial_nodes(origin, world, w_t, lo, hi, (u_r, w_r))
        if batch["size"] and batch["size"] + xs.size > NODE_CHUNK:
            flush()
        batch["x"].append(xs)
        batch["y"].append(ys)
        batch["w"].append(ws)
        batch["owner"].append(np.full(xs.size, n))
        batch["size"] += xs.size
    flush()
    rows, columns = np.array(cells).T
    probability[rows, columns] = totals


#: A point within this fraction of its distance inside a cell's circle is taken as on it (its
#: tangents at right angles to its radius are breaks of the sweep about it).
TANGENT_SLACK = 1e-12

#: Widest bearing sub-interval of a lattice cell swept about a point (radians).
SWEEP_ANGLE = 0.25


def _sector_segments(point, phi, ranges, bearings, origin, heading, foreign) -> tuple[np.ndarray, np.ndarray]:
    """The pieces ``(lo, hi)`` (shape (T, K), empty ones lo = hi) of the rays from ``point`` at
    bearings ``phi`` that lie in the annular sector ``ranges`` x ``bearings`` about ``origin``
    (bearings from ``heading``; each of r0, r1, b0, b1 a number or one per ray), split where a
    seam of ``foreign`` crosses them: a ray enters or leaves the sector where it crosses a
    range circle (a quadratic in its range) or a bounding ray, and a piece between two such
    events is in or out as its midpoint is."""
    (r0, r1), (b0, b1) = (np.broadcast_to(np.asarray(v, dtype=float), phi.shape) for v in ranges), \
        (np.broadcast_to(np.asarray(v, dtype=float), phi.shape) for v in bearings)
    wx, wy = np.sin(phi), np.cos(phi)
    dx, dy = point[0] - origin[0], point[1] - origin[1]
    along = dx * wx + dy * wy
    distance = math.hypot(dx, dy)
    far = distance + r1
    events = [np.zeros_like(phi), far]
    for radius in (r0, r1):
        disc = along * along + (radius - distance) * (radius + distance)
        root = np.sqrt(np.maximum(disc, 0.0))
        for s in (-along - root, -along + root):
            events.append(np.where((radius > 0.0) & (disc >= 0.0) & (s > 0.0), s, np.nan))
    # the bounding rays O + s u(heading + b), s >= 0: the ray meets one at r = (q x u) / (w x u)
    # with q = O - point (the formula of seam_ranges, one bounding ray per ray)
    for b in (b0, b1):
        ux, uy = np.sin(heading + b), np.cos(heading + b)
        den = wx * uy - wy * ux
        with np.errstate(divide="ignore", invalid="ignore"):
            r = (-dx * uy + dy * ux) / den
            s = (-dx * wy + dy * wx) / den
        events.append(np.where((den != 0.0) & (r > 0.0) & (s >= 0.0) & np.isfinite(r), r, np.nan))
    cuts = seam_ranges(point, phi, np.asarray(foreign, dtype=float).reshape(-1, 3))
    stacked = np.column_stack(events + [cuts])
    stacked = np.sort(np.where(np.isnan(stacked), far[:, None], np.minimum(stacked, far[:, None])), axis=1)
    lo, hi = stacked[:, :-1], stacked[:, 1:]
    mid = 0.5 * (lo + hi)
    mx, my = dx + mid * wx[:, None], dy + mid * wy[:, None]
    r = np.hypot(mx, my)
    rel = b0[:, None] + (np.arctan2(mx, my) - heading - b0[:, None]) % (2.0 * math.pi)
    inside = (r0[:, None] <= r) & (r <= r1[:, None]) & (rel <= b1[:, None]) & (hi > lo)
    return lo, np.where(inside, hi, lo)


def _near_end(end: float, width: float, side: float, points) -> bool:
    """Whether one of ``points`` lies at ``end`` of a piece ``width`` wide, or beyond it (on
    ``side``: -1 before a piece's start, +1 after its end) by less than ``width``."""
    return any(0.0 <= (p - end) * side < width for p in points)


def _sweep_breaks(point, own_bearings, cell, origin, heading):
    """``(edges, graded, seams, far)`` of a lattice cell swept about ``point``: the bearings
    about the point that cut the turn (unwrapped from the direction away from the lattice's
    origin, sorted, the whole turn's ends included), those of them to grade toward, the
    point's own seams among them, and the farthest range from the point the cell can reach.
    The cuts: the cell's corners, the tangents from the point to its arcs (graded: a ray's
    entry or exit moves like the square root of the turn there), the bearing of the lattice's
    origin, the bearings of the bounding rays' lines (graded: a ray's crossing with one runs
    off to infinity there) and the point's seams. Between two cuts a ray meets the cell or
    misses it all along."""
    (r0, r1), (b0, b1) = cell
    px, py = point
    dx, dy = px - origin[0], py - origin[1]
    distance = math.hypot(dx, dy)
    centre = math.atan2(origin[0] - px, origin[1] - py) if distance > 0.0 else 0.0
    breaks, graded = set(), set()
    for radius in (r0, r1):
        for bearing in (b0, b1):
            cx = origin[0] + radius * math.sin(heading + bearing)
            cy = origin[1] + radius * math.cos(heading + bearing)
            breaks.add(math.atan2(cx - px, cy - py))
        # tangents from the point to the circle; a point on it (to rounding) has them at right
        # angles to its radius: the rays on one side cross the disk, on the other they miss it
        if 0.0 < radius <= distance * (1.0 + TANGENT_SLACK):
            half = math.asin(min(1.0, radius / distance))
            graded |= {centre - half, centre + half}
    graded |= {heading + bearing + turn for bearing in (b0, b1) for turn in (0.0, math.pi)}
    breaks |= graded | {centre} | set(own_bearings)
    start = centre - math.pi
    unwrap = lambda b: start + (b - start) % (2.0 * math.pi)  # noqa: E731
    edges = sorted({start, start + 2.0 * math.pi} | {unwrap(b) for b in breaks})
    return edges, {unwrap(b) for b in graded}, {unwrap(b) for b in own_bearings}, distance + r1


def _piece_rules(pieces, law, sd_probes):
    """Nodes and weights of each swept piece ``(a, b, graded, seams, angular, far)``: sub-intervals
    no wider than ``angular`` nor, with a radial law, than half its least SD (``sd_probes``, a
    row of LAW_PROBES per piece, or None) over the farthest range (a share turns over sd /
    r there); graded toward an end where a singular bearing lies at it or beyond it by less
    than the piece's width (a corner's bearing a hair past a tangent's still bends the
    integrand next to the end): one step per halving, the integrand turning like a square
    root there; GRADE_SPLIT where the end is a seam toward which the law's SD narrows (the
    improved banana's P_sigma = 0 edge, where the ridge narrows to a point)."""
    rules = []
    for k, (a, b, graded, seams, angular, far, sharp) in enumerate(pieces):
        grade = [_near_end(a, b - a, -1.0, graded), _near_end(b, b - a, 1.0, graded)]
        split = [1, 1]
        scale = angular
        if sd_probes is not None:
            sd = sd_probes[k]
            live = sd[sd > 0.0]
            scale = min(angular, 0.5 * float(live.min()) / far) if live.size else angular
            narrow = narrowing(sd)
            ridge = [narrow[0] and _near_end(a, b - a, -1.0, seams), narrow[1] and _near_end(b, b - a, 1.0, seams)]
            grade = [grade[0] or ridge[0] or a in sharp, grade[1] or ridge[1] or b in sharp]
            split = [GRADE_SPLIT if ridge[0] else 1, GRADE_SPLIT if ridge[1] else 1]
        rules.append(graded_rule(a, b, scale, tuple(grade), split=tuple(split)))
    return rules


#: Bisections of the bearings at which a radial law's ridge crosses a cell's edges.
RIDGE_BISECTIONS = 60


def _ridge_crossings(point, law, pieces, cell_r, cell_b, origin, heading) -> list:
    """Per piece ``(a, b, ...)`` of a sweep about ``point``, the bearings inside it at which the
    law's ridge, the point at range mu(theta) on the ray, crosses one of its cell's circles or
    bounding rays' lines: there the ray's share steps over a turn of sd over the rate at which
    the ridge and the edge part, which no scale set in advance resolves (the edge's crossing
    runs off to infinity next to a ray along a bounding line; the improved banana's SD falls
    to 0 at its P_sigma = 0 edge). Sign changes over LAW_PROBES probes, refined by
    RIDGE_BISECTIONS bisections of all at once."""
    a = np.array([p[0] for p in pieces])
    b = np.array([p[1] for p in pieces])
    probes = np.linspace(a, b, LAW_PROBES, axis=1)
    dx, dy = point[0] - origin[0], point[1] - origin[1]
    u = [(np.sin(heading + cell_b[:, k]), np.cos(heading + cell_b[:, k])) for k in (0, 1)]

    def sides(theta, rows):
        """The ridge's signed distances from the piece's cell's circles and lines, (..., 4)."""
        _, mu, sd = law(theta.ravel())
        mu, sd = mu.reshape(theta.shape), sd.reshape(theta.shape)
        x, y = dx + mu * np.sin(theta), dy + mu * np.cos(theta)
        r = np.hypot(x, y)
        shape = (-1,) + (1,) * (theta.ndim - 1)
        out = [r - cell_r[rows, 0].reshape(shape), r - cell_r[rows, 1].reshape(shape)]
        out += [x * u[k][1][rows].reshape(shape) - y * u[k][0][rows].reshape(shape) for k in (0, 1)]
        return np.stack(out, axis=-1), sd

    rows = np.arange(len(pieces))
    f, sd = sides(probes, rows)
    live = sd > 0.0
    change = (np.sign(f[:, :-1]) * np.sign(f[:, 1:]) < 0.0) & (live[:, :-1] & live[:, 1:])[..., None]
    piece, k, edge = np.nonzero(change)
    out = [[] for _ in pieces]
    if not piece.size:
        return out
    lo, hi = probes[piece, k], probes[piece, k + 1]
    f_lo = f[piece, k, edge]
    for _ in range(RIDGE_BISECTIONS):
        mid = 0.5 * (lo + hi)
        f_mid = sides(mid, piece)[0][np.arange(mid.size), edge]
        left = np.sign(f_mid) == np.sign(f_lo)
        lo, hi = np.where(left, mid, lo), np.where(left, hi, mid)
        f_lo = np.where(left, f_mid, f_lo)
    for n, t in zip(piece.tolist(), (0.5 * (lo + hi)).tolist()):
        if pieces[n][0] < t < pieces[n][1]:
            out[n].append(t)
    return out


def _swept_lattice_cell(model, point, own_bearings, cell, lattice, foreign, feature):
    """Nodes ``(x, y, w)`` of a lattice cell swept in polar coordinates about ``point`` (a
    seam's start or a 1 / r point off the lattice's origin, which the cell holds), for a model
    without a radial law about it (:func:`_sweep_breaks`, :func:`_piece_rules`), each ray's
    pieces in the cell by a Gauss rule in range."""
    (r0, r1), (b0, b1) = cell
    origin, heading = lattice.pose.origin, lattice.pose.heading
    edges, graded, seams, far = _sweep_breaks(point, own_bearings, cell, origin, heading)
    radial, angular = model.polar_scales(point)
    # no wider than a quarter radian: the pieces span the whole turn about the point
    angular = min(angular, SWEEP_ANGLE, feature / max(far, 1e-300))
    pieces = [(a, b, graded, seams, angular, far, ()) for a, b in zip(edges[:-1], edges[1:]) if b > a]
    rules = _piece_rules(pieces, None, None)
    theta = np.concatenate([t for t, _ in rules])
    w_t = np.concatenate([w for _, w in rules])
    lo, hi = _sector_segments(point, theta, (r0, r1), (b0, b1), origin, heading, foreign)
    m_r, _, _ = axis_plan(math.hypot(r1 - r0, r1 * (b1 - b0)), min(radial, feature), MAX_SUBINTERVALS)
    return _radial_nodes(point, theta, w_t, lo, hi, unit_rule(m_r, MAX_ORDER))


def _swept_law_cells(model, point, own_bearings, law, cells, lattice, foreign, feature) -> np.ndarray:
    """Probabilities of lattice ``cells`` swept about ``point``, about which the density is
    g(theta) N(rho; mu, sd) / rho (``law``: a polar banana's start off the lattice's origin):
    per ray the pieces in the cell (:func:`_sector_segments`) are exact, sums of normal-CDF
    differences; over the bearing, Gauss rules between the cuts of :func:`_sweep_breaks` where
    the rays meet the cell (:func:`_piece_rules`). All cells at once: one evaluation of the
    law for the probes and at most NODE_CHUNK nodes per evaluation after."""
    origin, heading = lattice.pose.origin, lattice.pose.heading
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    angular = min(model.polar_scales(point)[1], SWEEP_ANGLE)
    pieces, owner = [], []
    for n, (i, j) in enumerate(cells):
        cell = ((float(r_edges[i]), float(r_edges[i + 1])), (float(b_edges[j]), float(b_edges[j + 1])))
        edges, graded, seams, far = _sweep_breaks(point, own_bearings, cell, origin, heading)
        scale = min(angular, feature / max(far, 1e-300))
        for a, b in zip(edges[:-1], edges[1:]):
            if b > a:
                pieces.append((a, b, graded, seams, scale, far, ()))
                owner.append(n)
    if not pieces:
        return np.zeros(len(cells))
    owner = np.array(owner)
    cell_r = np.array([(r_edges[i], r_edges[i + 1]) for i, _ in cells], dtype=float)[owner]
    cell_b = np.array([(b_edges[j], b_edges[j + 1]) for _, j in cells], dtype=float)[owner]
    # the pieces whose rays meet the cell (the same all along a piece: three probes for safety)
    a, b = np.array([p[0] for p in pieces]), np.array([p[1] for p in pieces])
    probe = (a[:, None] + (b - a)[:, None] * np.array([0.25, 0.5, 0.75])).ravel()
    lo, hi = _sector_segments(point, probe, (np.repeat(cell_r[:, 0], 3), np.repeat(cell_r[:, 1], 3)),
                              (np.repeat(cell_b[:, 0], 3), np.repeat(cell_b[:, 1], 3)), origin, heading, foreign)
    meets = (hi > lo).any(axis=1).reshape(-1, 3).any(axis=1)
    keep = np.flatnonzero(meets)
    pieces = [pieces[k] for k in keep]
    owner, cell_r, cell_b = owner[keep], cell_r[keep], cell_b[keep]
    totals = np.zeros(len(cells))
    if not pieces:
        return totals
    # split the pieces where the ridge crosses the cell's edges with its SD narrowed
    crossings = _ridge_crossings(point, law, pieces, cell_r, cell_b, origin, heading)
    split, index = [], []
    for k, (piece, at) in enumerate(zip(pieces, crossings)):
        a, b, graded, seams, scale, far, _ = piece
        cuts = sorted({a, b, *at})
        for u, v in zip(cuts[:-1], cuts[1:]):
            if v > u:
                split.append((u, v, graded, seams, scale, far, frozenset(at)))
                index.append(k)
    pieces, index = split, np.array(index)
    owner, cell_r, cell_b = owner[index], cell_r[index], cell_b[index]
    probes = np.linspace([p[0] for p in pieces], [p[1] for p in pieces], LAW_PROBES, axis=1)
    _, mu_probes, sd_probes = law(probes.ravel())
    speed = _end_speeds(point, probes, mu_probes, sd_probes, cell_r, cell_b, origin, heading, foreign)
    # an end of the rays' pieces may move faster than ``far`` per radian (a ray grazing a
    # bounding line or an arc): the share turns over sd over that speed
    pieces = [p[:5] + (max(p[5], v),) + p[6:] for p, v in zip(pieces, speed)]
    rules = _piece_rules(pieces, law, sd_probes.reshape(probes.shape))
    sizes = np.array([t.size for t, _ in rules])
    theta = np.concatenate([t for t, _ in rules])
    w_t = np.concatenate([w for _, w in rules])
    node_owner = np.repeat(owner, sizes)
    node_r, node_b = np.repeat(cell_r, sizes, axis=0), np.repeat(cell_b, sizes, axis=0)
    for c0 in range(0, theta.size, NODE_CHUNK):
        part = slice(c0, c0 + NODE_CHUNK)
        lo, hi = _sector_segments(point, theta[part], (node_r[part, 0], node_r[part, 1]),
                                  (node_b[part, 0], node_b[part, 1]), origin, heading, foreign)
        g, mu, sd = law(theta[part])
        shares = normal_shares(g[:, None], mu[:, None], sd[:, None], lo, hi).sum(axis=1)
        totals += np.bincount(node_owner[part], weights=w_t[part] * shares, minlength=len(cells))  # node order
    return totals


def _end_speeds(point, probes, mu, sd, cell_r, cell_b, origin, heading, foreign) -> np.ndarray:
    """Per piece (a row of ``probes``, LAW_PROBES bearings about ``point``), the fastest rate
    (m per radian) at which an end of the rays' pieces in its cell (:func:`_sector_segments`)
    moves while it lies within TAIL_SDS of the law's SD (``sd``) of its mean (``mu``, both
    flat, at the probes): there the ray's share turns over sd / rate, which bounds the
    bearing's sub-intervals like the law's SD over the farthest range does where the ends move
    no faster than that range (a ray that grazes a bounding line or an arc moves its crossing
    much faster). Finite differences between neighbouring probes of each end where the ray's
    piece is not empty at both."""
    n_pieces, k = probes.shape
    lo, hi = _sector_segments(point, probes.ravel(), (np.repeat(cell_r[:, 0], k), np.repeat(cell_r[:, 1], k)),
                              (np.repeat(cell_b[:, 0], k), np.repeat(cell_b[:, 1], k)), origin, heading, foreign)
    shape = (n_pieces, k, lo.shape[1])
    lo, hi = lo.reshape(shape), hi.reshape(shape)
    mu, sd = mu.reshape(n_pieces, k, 1), sd.reshape(n_pieces, k, 1)
    full = hi > lo
    step = np.maximum(np.diff(probes, axis=1), 1e-300)[..., None]
    both = full[:, 1:] & full[:, :-1] & (sd[:, 1:] > 0.0) & (sd[:, :-1] > 0.0)
    fastest = np.zeros(n_pieces)
    for end in (lo, hi):
        near = np.abs(end - mu) <= TAIL_SDS * np.maximum(sd, 0.0)
        rate = np.abs(np.diff(end, axis=1)) / step
        counted = both & (near[:, 1:] | near[:, :-1])
        fastest = np.maximum(fastest, np.max(np.where(counted, rate, 0.0), axis=(1, 2), initial=0.0))
    return fastest


def _radial_nodes(point, theta, w_t, lo, hi, rule):
    """Nodes ``(x, y, w)`` of the rays from ``point`` at bearings ``theta`` (weights ``w_t``) over
    their non-empty pieces [lo, hi] (shape (T, K)), each by the unit ``rule`` scaled, the
    area element r included: only the pieces that hold something are expanded."""
    u_r, w_r = rule
    t, _ = np.nonzero(hi > lo)
    a, b = lo[hi > lo], hi[hi > lo]
    r = a[:, None] + (b - a)[:, None] * u_r  # (P, R)
    w = ((w_t[t] * (b - a))[:, None] * w_r * r).ravel()  # the bearing's and range's weights, r dr
    return (point[0] + r * np.sin(theta[t])[:, None]).ravel(), (point[1] + r * np.cos(theta[t])[:, None]).ravel(), w


#: Cells nearer a polar law's point than this many of their diameters are swept about it.
NEAR_SWEEP = 2.0

#: Probes per cell of the law's SD over the bearings the cell spans about the point, and
#: samples per cell side of the cell's outline.
SPAN_PROBES = 17
OUTLINE_SAMPLES = 9

#: Range SDs beyond which a cell lies in the law's tail on every probed bearing.
TAIL_SDS = 12.0


def _law_untrusted_cells(lattice: PolarLattice, plan: _Plan, point, law) -> set:
    """The cells that the tensor rule about the lattice's origin cannot be trusted on for a
    density that is g N(rho; mu, sd) / rho about ``point`` (a polar banana's start off the
    origin), to be swept about the point: cells nearer it than NEAR_SWEEP of their diameters
    (1 / rho, and a density that changes with the direction there), and cells where one of
    the density's Cartesian length scales falls below the tensor rule's (``plan.scales[0]``):
    the law's range SD over the bearings the cell spans about the point (SPAN_PROBES probes;
    it falls behind the improved banana's start and to 0 at its P_sigma = 0 edge, where the
    ridge narrows to a point), or the arc over which the ridge moves by an SD at the cell's
    nearest range, rho sd / |mu'| (its bends are compressed like rho near the start), or the
    cell spans bearings where the law has no mass next to ones where it has; but not cells in
    the law's far tail on every bearing they span (beyond TAIL_SDS SDs of every probed mean)."""
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    origin, heading = lattice.pose.origin, lattice.pose.heading
    px, py = point
    n_r, n_b = lattice.n_range, lattice.n_bearing
    # each cell's outline, sampled: its arcs and its radial sides, shape (n_r, n_b, P)
    f = np.linspace(0.0, 1.0, OUTLINE_SAMPLES)
    r0, r1 = r_edges[:-1, None, None], r_edges[1:, None, None]
    a0, a1 = b_edges[None, :-1, None], b_edges[None, 1:, None]
    shape = (n_r, n_b, OUTLINE_SAMPLES)
    radius = np.concatenate([np.broadcast_to(r0, shape), np.broadcast_to(r1, shape),
                             np.broadcast_to(r0 + (r1 - r0) * f, shape), np.broadcast_to(r0 + (r1 - r0) * f, shape)],
                            axis=2)
    bearing = np.concatenate([np.broadcast_to(a0 + (a1 - a0) * f, shape), np.broadcast_to(a0 + (a1 - a0) * f, shape),
                              np.broadcast_to(a0, shape), np.broadcast_to(a1, shape)], axis=2)
    x = origin[0] + radius * np.sin(heading + bearing) - px
    y = origin[1] + radius * np.cos(heading + bearing) - py
    # bearings about the point, unwrapped about the direction to the cell's middle
    rm, bm = 0.5 * (r0 + r1), 0.5 * (a0 + a1)
    centre = np.arctan2(origin[0] + rm * np.sin(heading + bm) - px, origin[1] + rm * np.cos(heading + bm) - py)
    turn = (np.arctan2(x, y) - centre + math.pi) % (2.0 * math.pi) - math.pi
    lo, hi = turn.min(axis=2), turn.max(axis=2)
    pad = 0.125 * (hi - lo)  # the arcs between the samples bulge a little beyond them
    lo, hi = lo - pad, hi + pad
    far = np.hypot(x, y).max(axis=2) + lattice.range_step / OUTLINE_SAMPLES
    near = _cell_distances(lattice, point)
    around = near <= 0.0  # the cell holds the point (or reaches round it): every bearing
    lo, hi = np.where(around, -math.pi, lo), np.where(around, math.pi, hi)
    probes = centre[..., 0, None] + lo[..., None] + (hi - lo)[..., None] * np.linspace(0.0, 1.0, SPAN_PROBES)
    _, mu, sd = law(probes.ravel())
    mu, sd = mu.reshape(probes.shape), sd.reshape(probes.shape)
    live = sd > 0.0
    widest = np.max(np.where(live, sd, 0.0), axis=2)
    top = np.max(np.where(live, mu, -np.inf), axis=2) + TAIL_SDS * widest
    bottom = np.min(np.where(live, mu, np.inf), axis=2) - TAIL_SDS * widest
    tail = ~live.any(axis=2) | (near > top) | (far < bottom)
    # the density's Cartesian length scales over the cell: the range SD, and across the
    # bearings the turn that moves the ridge by an SD (sd / |mu'|) at the cell's nearest range
    step = ((hi - lo) / (SPAN_PROBES - 1))[..., None]
    slope = np.abs(np.gradient(mu, axis=2)) / np.maximum(step, 1e-300)
    least = np.min(np.where(live, sd, np.inf), axis=2)
    steepest = np.max(np.where(live[..., 1:] & live[..., :-1], np.maximum(slope[..., 1:], slope[..., :-1]), 0.0),
                      axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        across = np.where(steepest > 0.0, near * least / steepest, np.inf)
    narrow = (np.minimum(least, across) < plan.scales[0]) | (live.any(axis=2) & ~live.all(axis=2))
    untrusted = ((near < NEAR_SWEEP * _cell_diameters(lattice)[:, None]) | narrow) & ~tail
    return set(map(tuple, np.argwhere(untrusted).tolist()))


def _point_choice(model: DensityModel, lattice: PolarLattice, plan: _Plan) -> tuple[list, np.ndarray, dict]:
    """``(points, seams, chosen)``: the seams' starts and 1 / r points off the lattice's origin,
    the model's seams, and the cells to sweep about one of them, ``{(i, j): point index}``:
    the cell that holds a point, and for a point with a polar law (a polar banana's start) the
    cells its seams cross (:func:`_crossed_cells`) and those the tensor rule about the
    lattice's origin cannot be trusted on (:func:`_law_untrusted_cells`)."""
    origin = lattice.pose.origin
    seams = np.asarray(model.seams(), dtype=float).reshape(-1, 3)
    points = [tuple(map(float, p)) for p in np.asarray(model.singular_points(), dtype=float).reshape(-1, 2)]
    points += [tuple(map(float, p)) for p in seams[:, :2] if tuple(map(float, p)) not in points]
    points = [p for p in points if p != tuple(map(float, origin))]
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    chosen = {}
    for k, point in enumerate(points):
        own = seams[(seams[:, 0] == point[0]) & (seams[:, 1] == point[1])]
        law = model.polar_law(point)
        if law is not None:
            for cell in _crossed_cells(lattice, own) | _law_untrusted_cells(lattice, plan, point, law):
                chosen.setdefault(cell, k)
        # the cells beside the point too: on their edge (to rounding) or nearer than a
        # quarter of their diameter, where the rule in the lattice's frame would need
        # sub-intervals finer than its caps allow
        beside = _cell_distances(lattice, point) < TOUCH_FRACTION * _cell_diameters(lattice)[:, None]
        for cell in map(tuple, np.argwhere(beside).tolist()):
            chosen.setdefault(cell, k)
        dx, dy = point[0] - origin[0], point[1] - origin[1]
        r = math.hypot(dx, dy)
        rel = b_edges[0] + (math.atan2(dx, dy) - lattice.pose.heading - b_edges[0]) % (2.0 * math.pi)
        i = int(np.searchsorted(r_edges, r, side="right")) - 1
        j = int(np.searchsorted(b_edges, rel, side="right")) - 1
        if 0 <= i < lattice.n_range and 0 <= j < lattice.n_bearing:
            chosen[(i, j)] = k
    return points, seams, chosen


#: Cells nearer a seam's start or 1 / r point than this fraction of their diameter are swept
#: about it.
TOUCH_FRACTION = 0.25


def _cell_diameters(lattice: PolarLattice) -> np.ndarray:
    """Per row, the diagonal of a cell at its outer arc: hypot(dr, r1 db)."""
    return np.hypot(lattice.range_step, lattice.range_edges[1:] * lattice.bearing_step)


def _cell_distances(lattice: PolarLattice, point) -> np.ndarray:
    """A lower bound of the distance from ``point`` to every cell, shape (n_range, n_bearing):
    the gap to the cell's annulus, or the distance to the nearer bounding ray where the
    point's bearing lies outside the cell's (as :func:`_distance_to_cell`)."""
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    dx, dy = point[0] - lattice.pose.origin[0], point[1] - lattice.pose.origin[1]
    r = math.hypot(dx, dy)
    radial = np.maximum(0.0, np.maximum(r_edges[:-1] - r, r - r_edges[1:]))
    rel = b_edges[0] + (math.atan2(dx, dy) - lattice.pose.heading - b_edges[0]) % (2.0 * math.pi)
    circular = lambda d: np.abs((d + math.pi) % (2.0 * math.pi) - math.pi)  # noqa: E731
    gap = np.where((b_edges[:-1] <= rel) & (rel <= b_edges[1:]), 0.0,
                   np.minimum(circular(rel - b_edges[:-1]), circular(rel - b_edges[1:])))
    across = r * np.sin(np.minimum(gap, 0.5 * math.pi))
    return np.maximum(radial[:, None], across[None, :])


def _point_cells(model: DensityModel, lattice: PolarLattice, probability: np.ndarray, choice, *, dtype, device,
                 threads) -> None:
    """Integrate again, swept about their point, the cells of ``choice`` (:func:`_point_choice`),
    and set them in ``probability``: exact in range about a point with a polar law
    (:func:`_swept_law_cells`), else Gauss in range (:func:`_swept_lattice_cell`)."""
    points, seams, chosen = choice
    if not chosen:
        return
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    feature = float(model.feature_scale())
    extent = LatticeExtent(lattice)
    by_point = {}
    for cell, k in sorted(chosen.items()):
        by_point.setdefault(k, []).append(cell)
    for k, cells in sorted(by_point.items()):
        point = points[k]
        mine = (seams[:, 0] == point[0]) & (seams[:, 1] == point[1])
        own, foreign = seams[mine, 2], seams[~mine]
        law = model.polar_law(point)
        if law is not None:
            values = _swept_law_cells(model, point, own, law, cells, lattice, foreign, feature)
            for (i, j), value in zip(cells, values):
                probability[i, j] = value
            continue
        for i, j in cells:
            cell = ((float(r_edges[i]), float(r_edges[i + 1])), (float(b_edges[j]), float(b_edges[j + 1])))
            xs, ys, w = _swept_lattice_cell(model, point, own, cell, lattice, foreign, feature)
            total = 0.0
            for c0 in range(0, xs.size, NODE_CHUNK):
                values = evaluate_points(model, xs[c0:c0 + NODE_CHUNK], ys[c0:c0 + NODE_CHUNK], dtype=dtype,
                                         device=device, threads=threads, extent=extent)
                total += float(np.dot(w[c0:c0 + NODE_CHUNK], values.astype(float)))
            probability[i, j] = total


def rasterise_lattice(
    model: DensityModel, lattice: PolarLattice, *, dtype=np.float64, device: str = "cpu", threads=None,
    max_seconds: float | None = None,
) -> PolarRaster:
    r"""Densities at the cell centres and probabilities of the cells of a polar lattice.

    .. math::

        \mathrm{density}_{ij} = r_i\, p(x(r_i, b_j), y(r_i, b_j)),\qquad
        \mathrm{probability}_{ij} = \int_{r_i^-}^{r_i^+}\!\int_{b_j^-}^{b_j^+} p(x, y)\, r\, db\, dr,

    with ``(x, y) = O + r (sin(h + b), cos(h + b))`` and p the model's density per m^2.

    Where the model's density about the lattice's origin is g(theta) N(r; mu, sd) / r (a polar
    banana on a lattice at its start: ``model.polar_law``), each cell is exact in r and
    Gauss-Legendre in the bearing (:func:`_law_cells`), cut at the model's seams; such a banana
    on a lattice about another origin is integrated exact in its own range about its start,
    in the cells its seams cross and wherever the rule below is not to be trusted
    (:func:`_point_cells`). Otherwise the
    integral is a tensor Gauss-Legendre rule over sub-cells no larger than the model's
    length scales (``model.polar_scales``): per axis, m equal sub-intervals of at most the scale
    and the fewest nodes n (<= 8) whose remainder bound for a normal feature of that SD is below
    ``GAUSS_TOL`` = 1e-10 of its mass (:func:`gauss_error`). Where the density is as smooth as
    its scales say, each cell's probability is then within about 1e-9 of the model's total mass.
    Folds of a CAT banana (sigma_omega t beyond about 90 deg) have integrable infinite density
    and converge more slowly. Every node is evaluated by the model's own kernels through
    :func:`bananagrid.engine.points.evaluate_points`, at most ``NODE_CHUNK`` points at a time.

    Parameters
    ----------
    model : DensityModel
    lattice : PolarLattice
    dtype, device, threads, max_seconds
        As for :func:`bananagrid.rasterise`; probabilities are summed in float64. The work
        estimate counts the cell centres and the quadrature nodes.

    Returns
    -------
    PolarRaster
        Raw densities per (m, rad) and probabilities, with the captured mass and provenance.

    Warns
    -----
    UserWarning
        When ``MAX_NODES`` or ``MAX_SUBINTERVALS`` keeps the rule from meeting ``GAUSS_TOL``.
    """
    if not isinstance(lattice, PolarLattice):
        raise BananagridError(f"lattice = {lattice!r}: expected a bananagrid.PolarLattice")
    check_model(model, "polar lattices know the length scales of models that follow bananagrid.DensityModel only")
    threads = check_threads(threads)
    start = time.perf_counter()
    plan = _plan(model, lattice)
    if device == "cpu":
        points = lattice.n_range * lattice.n_bearing + plan.total_nodes
        check_work(model.work_estimate(points, LatticeExtent(lattice)), threads,
                   f"{type(model).__name__}: a polar lattice of {lattice.n_range} x {lattice.n_bearing} cells "
                   f"({plan.total_nodes:,} quadrature nodes)", limit=max_seconds, option="max_seconds=S")
    x, y = lattice.world_centres
    p = evaluate_points(model, x, y, dtype=dtype, device=device, threads=threads, extent=LatticeExtent(lattice))
    density = (lattice.range_centres[:, None] * p).astype(p.dtype, copy=False)
    check_finite(density, model)
    probability = _integrate(model, lattice, plan, dtype=dtype, device=device, threads=threads)
    check_finite(probability, model)
    seconds = time.perf_counter() - start
    (rm, rn), angular = plan.radial, [m * n for m, n in plan.angular]
    provenance = {
        **model.parameters(),
        "lattice": lattice.describe(),
        "dtype": np.dtype(dtype).name,
        "device": device,
        "threads": threads if device == "cpu" else 1,
        "seconds": seconds,
        "quadrature": ("exact in range (the model's radial law), Gauss-Legendre in bearing"
                       if model.polar_law(lattice.pose.origin) is not None else "tensor Gauss-Legendre over sub-cells"),
        "scale_rule": plan.rule,
        "length_scales": {"radial_m": plan.scales[0], "angular_rad": plan.scales[1]},
        "radial_nodes_per_cell": rm * rn,
        "bearing_nodes_per_cell": (min(angular), max(angular)),
        "total_nodes": plan.total_nodes,
        "accuracy": {
            "claim": "error bound per sub-cell for a normal feature as wide as the length scales, "
            "as a fraction of the model's mass",
            "target": GAUSS_TOL,
            "estimated": float(plan.error),
        },
    }
    return PolarRaster(
        density=density,
        probability=probability,
        lattice=lattice,
        mass=float(np.sum(probability)),
        normalised=False,
        provenance=provenance,
    )
