"""Cell probabilities of any model on a polar lattice: a Gauss-Legendre rule sized from the
model's own length scales.

The sub-cells are no larger than the model's length scales (``model.polar_scales``, through
the model protocol), and a cell that a seam of the model's density crosses along a bearing of
the lattice (``model.seams``: a polar density's angle wrapping at +-pi behind its start) is
integrated on each side of it; every node is evaluated by the model's own kernels through
:func:`bananagrid.engine.points.evaluate_points`.
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
from ..validate import BananagridError
from .points import check_finite, check_model, evaluate_points
from .quadrature import GAUSS_TOL, MAX_SUBINTERVALS, axis_plan, graded_rule, narrowing, normal_shares, unit_rule
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
            stacklevel=4,
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


def _bearing_pieces(model: DensityModel, lattice: PolarLattice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lo, hi, column)``: the bearing intervals the rule integrates, each cell's interval cut
    at the bearings of the model's seams (:meth:`~bananagrid.protocol.DensityModel.seams`) that
    start at the lattice's origin and pass through it (a kink of the density there becomes a
    break of the rule, like a cell edge). Seams from other points cross the lattice's cells
    along curves and are not cut."""
    edges = lattice.bearing_edges
    origin = np.asarray(lattice.pose.origin, dtype=float)
    cuts = []
    for x, y, bearing in np.asarray(model.seams(), dtype=float).reshape(-1, 3):
        if np.array_equal(np.array([x, y]), origin):
            cuts.append(bearing - lattice.pose.heading)
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
        return _law_cells(model, lattice, law)
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
    Gauss-Legendre in the bearing (:func:`_law_cells`), cut at the model's seams. Otherwise the
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
