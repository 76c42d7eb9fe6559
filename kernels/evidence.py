"""Evidence weights of one target path, for every model whose kernels carry earlier evidence:
the one shared implementation (CAT roots, Butterly course nodes and the CAT cell rule call it).

A path is fixed by the map point and the parameters a model's kernel already sums or
integrates over (CAT: a root (a, omega); Butterly: a course node and speed). Evidence at
earlier times is a weight on that path. The evidence arrives packed
(``bananagrid.evidence.packing.pack``) as *time nodes*: node j has a time s_j, the factor k_j
(one per piece of evidence) it belongs to, a quadrature weight q_j, a kind and its data. The
factor's log-weight is

    lw_k = sum over its nodes j of q_j c_j(x_j),   x_j the path's world position at s_j,

with c_j (``KIND_*``):

* ``KIND_POLYGON``: ``data[0]`` inside the polygon (``edges[off : off + count]``, even-odd
  rule, bounding box ``data[1:5]`` = x0, x1, y0, y1), else 0: log(1 - POD) (a search at one
  time, q = 1) or -C / (t1 - t0) (coverage C spread over an interval, Gauss-Legendre nodes).
* ``KIND_RASTER``: the value of the raster cell holding x_j (``raster[off + i nx + j]``; row i
  from ``data[1]`` = y0 north by ``data[3]`` = dy, column j from ``data[0]`` = x0 east by
  ``data[2]`` = dx, ``ints`` count = nx, ``data[4]`` = ny), 0 outside the raster; the values are
  log(1 - POD) (one time) or -C / (t1 - t0) (an interval, Gauss-Legendre nodes).
* ``KIND_NORMAL``: -d^T P d / 2, d = x_j - (data[0], data[1]), P = [[data[2], data[3]],
  [data[3], data[4]]]: a position report with a normal error (q = 1).
* ``KIND_BEARING``: -(wrap(beta - data[2]) data[3])^2 / 2, beta the bearing (clockwise from
  north) from the sensor (data[0], data[1]) to x_j, data[3] = 1 / sigma: one bearing of a
  :class:`~bananagrid.BearingReport` (one node per sensor, same factor, q = 1).
* ``KIND_INVERSE_CUBE``: -gamma(r), r = |x_j - (data[0], data[1])| the range to the searcher at
  s_j, gamma(r) = data[2] / r^3 with data[2] = W^2 v / (8 pi), v the leg's speed: Koopman's
  inverse-cube detection rate (``bananagrid.evidence.searches.TrackSearch`` states it and its
  sources), Gauss-Legendre nodes q_j over the leg's time span; r = 0 gives -inf (detected).
* ``KIND_DEFINITE``: a definite-range track (detected iff the closest approach of the path to
  the searcher over the track's span is at most h = W / 2). The track's nodes form a *chain*:
  chord ends s_0 < s_1 < ... (each leg cut into chords), node j holding the searcher's position
  Q_j at s_j (``data[0:2]``), Q_{j-1} at the chord's start (``data[2:4]``) and h (``data[4]``);
  ``ints`` offset: the scratch slots (``lw[offset : offset + 2]``, beyond the factors) that keep
  the path's position at the chain's previous node; ``ints`` count: bit ``DEFINITE_START`` on
  the chain's first node, bit ``DEFINITE_LEG`` on every node at a track point (a leg's end).
  Over a chord the searcher moves straight at constant speed and the path is taken so too
  (the chord from its position at s_{j-1} to that at s_j), so the relative position
  D = X - Q is linear in time and the chord's closest approach is the distance from the origin
  to the segment D_{j-1} D_j, closed form (:func:`segment_distance`). c_j = -inf (the weight 0)
  where it is at most h, else 0 (the chain's first node: |D_0| <= h); exact for a path
  straight over each chord (the error of others: ``packing``).

The path's weight for a *channel* c is exp(sum over factors k in c of lw_k); the pack lists the
channels as a 0/1 mask ``channels[c, k]`` (e.g. the prior: no factor; all evidence; the
searches; the reports; each search with the reports). A model's kernel returns, per map point,
each channel's weighted density: sum over paths of density(path) x weight_c(path).

How a model's kernel uses it (one path; ``lw`` a scratch row of the factors and, beyond them,
the definite-range chains' slots (``EvidencePack.scratch``), ``out`` the point's row of
channels, zeroed by the launch kernel; the nodes must be visited in order, as below)::

    evidence_reset(ev, lw)
    for j in range(evidence_nodes(ev)):
        s = evidence_time(ev, j)
        # the model's own path at s, world metres (positions may be reused while s repeats:
        # the pack sorts its nodes by time)
        px, py = ...
        evidence_node(ev, j, px, py, lw)
    evidence_add(ev, lw, density_of_path, out)

Every function is generic over float32 and float64 (the :class:`Evidence` struct of the
kernel's scalar, ``EVIDENCE.of(scalar)``). The engine builds the struct from a pack
(``bananagrid.engine.carried.evidence_struct``).
"""

from typing import Any

import warp as wp

from .common import wrap_angle
from .generate import ARRAY, ARRAY2D, SCALARS, Params, overload_on_use

wp.set_module_options({"enable_backward": False})

#: Node kinds (``ints[j, 0]``).
KIND_POLYGON = 0
KIND_RASTER = 1
KIND_NORMAL = 2
KIND_BEARING = 3
KIND_INVERSE_CUBE = 4
KIND_DEFINITE = 5
#: Bits of a definite-range node's ``ints`` count: the chain's first node; a node at a track point.
DEFINITE_START = 1
DEFINITE_LEG = 2
#: Most factors whose weights :func:`evidence_add` takes as one exp each (more: one per channel).
EXP_FACTORS = 16
#: Columns of ``data`` and of ``ints`` (kind, factor, offset, count).
DATA_COLUMNS = 6
INT_COLUMNS = 4

#: The packed evidence: node times, quadrature weights, data and ints per node; polygon edges
#: (x0, y0, x1, y1); raster values; the channel mask (channels x factors).
EVIDENCE = Params(
    "Evidence", __name__, time=ARRAY, q=ARRAY, data=ARRAY2D, ints=wp.array2d(dtype=wp.int32), edges=ARRAY2D,
    raster=ARRAY, channels=wp.array2d(dtype=wp.int32),
)


@wp.func
def evidence_nodes(ev: Any):
    """Number of time nodes."""
    return ev.time.shape[0]


@wp.func
def evidence_time(ev: Any, j: int):
    """Time s_j of node j (s since the last fix)."""
    return ev.time[j]


@wp.func
def evidence_reset(ev: Any, lw: wp.array(dtype=Any)):
    """Zero the factors' log-weights of one path (the scratch slots beyond them, a
    definite-range chain's previous position, are written before they are read)."""
    for k in range(ev.channels.shape[1]):
        lw[k] = type(lw[k])(0.0)


@wp.func
def polygon_edge(edges: wp.array2d(dtype=Any), e: int):
    """The ends (ax, ay, bx, by) of edge e of a polygon's edge rows (x0, y0, x1, y1)."""
    return edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]


@wp.func
def polygon_contains(edges: wp.array2d(dtype=Any), offset: int, count: int, px: Any, py: Any):
    """Whether (px, py) is inside the polygon ``edges[offset : offset + count]`` (even-odd rule,
    as ``bananagrid.evidence.geometry.Polygon.contains``)."""
    inside = bool(False)
    for e in range(offset, offset + count):
        ax, ay, bx, by = polygon_edge(edges, e)
        if (ay > py) != (by > py):
            cross = ax + (py - ay) * (bx - ax) / (by - ay)
            if px < cross:
                inside = not inside
    return inside


@wp.func
def evidence_contribution(ev: Any, j: int, px: Any, py: Any):
    """c_j at the world point (px, py) (module docstring), before the quadrature weight."""
    kind = ev.ints[j, 0]
    zero = type(px)(0.0)
    half = type(px)(0.5)
    dx = px - ev.data[j, 0]  # from the report's mean, the sensor, the searcher
    dy = py - ev.data[j, 1]
    if kind == KIND_POLYGON:
        if px < ev.data[j, 1] or px > ev.data[j, 2] or py < ev.data[j, 3] or py > ev.data[j, 4]:
            return zero
        if polygon_contains(ev.edges, ev.ints[j, 2], ev.ints[j, 3], px, py):
            return ev.data[j, 0]
        return zero
    if kind == KIND_RASTER:
        fx = (px - ev.data[j, 0]) / ev.data[j, 2]
        fy = (py - ev.data[j, 1]) / ev.data[j, 3]
        nx = ev.ints[j, 3]
        if fx < zero or fy < zero or fx >= type(px)(float(nx)) or fy >= ev.data[j, 4]:
            return zero
        col = wp.min(int(fx), nx - 1)
        row = wp.min(int(fy), int(ev.data[j, 4]) - 1)
        return ev.raster[ev.ints[j, 2] + row * nx + col]
    if kind == KIND_NORMAL:
        return -half * (ev.data[j, 2] * dx * dx + type(px)(2.0) * ev.data[j, 3] * dx * dy + ev.data[j, 4] * dy * dy)
    if kind == KIND_BEARING:
        beta = wp.atan2(dx, dy)
        z = wrap_angle(beta - ev.data[j, 2]) * ev.data[j, 3]
        return -half * z * z
    if kind == KIND_INVERSE_CUBE:
        r2 = dx * dx + dy * dy
        return -ev.data[j, 2] / (r2 * wp.sqrt(r2))
    return zero


@wp.func
def segment_distance(ax: Any, ay: Any, bx: Any, by: Any):
    """Distance from the origin to the segment from (ax, ay) to (bx, by): the closest approach
    of a relative position linear in time from a to b (the foot of the perpendicular,
    u = -a.(b - a) / |b - a|^2, clamped to [0, 1]; an end where the segment is a point)."""
    dx = bx - ax
    dy = by - ay
    zero = type(ax)(0.0)
    one = type(ax)(1.0)
    d2 = dx * dx + dy * dy
    u = zero
    if d2 > zero:
        u = wp.min(wp.max(-(ax * dx + ay * dy) / d2, zero), one)
    cx = ax + u * dx
    cy = ay + u * dy
    return wp.sqrt(cx * cx + cy * cy)


@wp.func
def definite_node(ev: Any, j: int, px: Any, py: Any, lw: wp.array(dtype=Any)):
    """A definite-range chain's node j: the factor's log-weight to -inf where the chord ending
    at s_j comes within h of the searcher (the chain's first node: where the range at s_j is at
    most h); the path's position kept in the slots for the next chord."""
    slot = ev.ints[j, 2]
    dx = px - ev.data[j, 0]
    dy = py - ev.data[j, 1]
    margin = type(px)(0.0)  # closest approach less h
    if (ev.ints[j, 3] & DEFINITE_START) != 0:
        margin = wp.sqrt(dx * dx + dy * dy) - ev.data[j, 4]
    else:
        margin = segment_distance(lw[slot] - ev.data[j, 2], lw[slot + 1] - ev.data[j, 3], dx, dy) - ev.data[j, 4]
    if margin <= type(px)(0.0):
        k = ev.ints[j, 1]
        lw[k] = -type(px)(wp.inf)
    lw[slot] = px
    lw[slot + 1] = py


@wp.func
def evidence_node(ev: Any, j: int, px: Any, py: Any, lw: wp.array(dtype=Any)):
    """Add node j's contribution q_j c_j(x_j) to its factor's log-weight, the path at the world
    point (px, py) at s_j. A zero contribution adds nothing (q_j is never multiplied by an
    infinite rate there). A definite-range node reads and writes its chain's scratch slots
    (:func:`definite_node`)."""
    if ev.ints[j, 0] == KIND_DEFINITE:
        definite_node(ev, j, px, py, lw)
        return
    c = evidence_contribution(ev, j, px, py)
    if c != type(px)(0.0):
        k = ev.ints[j, 1]
        lw[k] = lw[k] + ev.q[j] * c


@wp.func
def evidence_add(ev: Any, lw: wp.array(dtype=Any), density: Any, out: wp.array(dtype=Any)):
    """Add the path's density times its weight in each channel to ``out`` (one row per point).

    One exp per factor, not per channel (the channels share factors: prior, all, searches,
    others and each search with the others): channel c's weight is the product of its
    factors' exp(lw_k), equal to exp of their sum but for a few roundings (the products'
    relative error is below (factors + 1) eps, far inside every rule's). A factor whose
    log-weight is 0 (the path missed it) costs no exp. More than EXP_FACTORS factors: one exp
    per channel of the channel's sum."""
    n_factors = ev.channels.shape[1]
    if n_factors > EXP_FACTORS:
        for c in range(ev.channels.shape[0]):
            total = type(lw[0])(0.0)
            for k in range(n_factors):
                if ev.channels[c, k] != 0:
                    total += lw[k]
            out[c] = out[c] + density * wp.exp(total)
        return
    zero = type(density)(0.0)
    one = type(density)(1.0)
    w = wp.vector(length=EXP_FACTORS, dtype=type(density))
    for k in range(n_factors):
        w[k] = one
        if lw[k] != zero:
            w[k] = wp.exp(lw[k])
    for c in range(ev.channels.shape[0]):
        v = density
        for k in range(n_factors):
            if ev.channels[c, k] != 0:
                v = v * w[k]
        out[c] = out[c] + v


@wp.kernel
def evidence_paths(ev: Any, positions: wp.array3d(dtype=Any), density: wp.array(dtype=Any),
                   lw: wp.array2d(dtype=Any), out: wp.array2d(dtype=Any)):
    """Weights of given paths (``positions[i, j]``: path i's world position at node j, with
    ``density[i]``): each path's channel values in ``out[i]``. Used to check the helpers and to
    weigh paths a model computes on the host."""
    i = wp.tid()
    evidence_reset(ev, lw[i])
    for j in range(ev.time.shape[0]):
        evidence_node(ev, j, positions[i, j, 0], positions[i, j, 1], lw[i])
    for c in range(ev.channels.shape[0]):
        out[i, c] = type(density[i])(0.0)
    evidence_add(ev, lw[i], density[i], out[i])


for _scalar in SCALARS:
    overload_on_use(evidence_paths, _scalar, {
        "ev": EVIDENCE.of(_scalar), "positions": wp.array3d(dtype=_scalar), "density": wp.array(dtype=_scalar),
        "lw": wp.array2d(dtype=_scalar), "out": wp.array2d(dtype=_scalar)})
