"""Evidence at times before a map's, packed into the flat arrays the kernels read
(:class:`~bananagrid.protocol.EvidencePack`; each column: ``bananagrid/kernels/evidence.py``).

Each piece of evidence is one *factor*; each factor is a list of *time nodes* at which the
model's kernel places the target's path and adds the node's contribution to the factor's
log-weight:

* an :class:`~bananagrid.AreaSearch` at one time: one node, log(1 - POD) inside the polygon;
  over an interval (t0, t1): the coverage C (-log(1 - POD) when POD is given) spread uniformly
  over it, -C / (t1 - t0) inside, integrated by composite Gauss-Legendre (``AREA_PANELS``
  panels of ``PANEL_NODES`` nodes). The path's fraction of the interval inside the polygon is an
  integral of a step function: its error is at most the largest node weight per crossing of the
  polygon's edge, 0.35 / AREA_PANELS of the interval (the 4-node rule's largest weight is
  0.652 of a half panel), a bound on the error of C x fraction of C x 0.35 / AREA_PANELS per
  crossing;
* a :class:`RasterSearch`: as an area search, cell by cell;
* a :class:`~bananagrid.TrackSearch` with the inverse-cube law: on each leg the detection rate
  gamma = W^2 v / (8 pi r^3), v the leg's speed, r the range from the searcher (at its position
  at that time, straight between track points) to the path (``TrackSearch`` states the law and
  its sources), integrated over the leg's time by composite Gauss-Legendre with panels in which
  the searcher moves at most W / 4 (the range's scale where detection is neither sure nor
  negligible), ``PANEL_NODES`` nodes each. Measured: the exposure's absolute error is below
  5e-5 (2.3e-5 at most over 300 random paths) for paths whose closest approach to the
  searcher exceeds W / 4, at target speeds up to a third of the searcher's
  (tests/kernels/test_evidence.py); it grows closer in (3e-3 at W / 8, where the path is
  missed with probability exp(-4 / pi) or less);
* a :class:`~bananagrid.TrackSearch` with the definite-range law (the path is detected iff its
  closest approach to the searcher over the track's span is at most W / 2: its weight is 0 or
  1): a chain of nodes at the ends of *chords*, each leg cut into the fewest equal chords of at
  most t / ``definite_chords`` seconds (t the map's time), each node holding the searcher's
  positions at its chord's ends; the kernel takes the closest approach of each chord in closed
  form with the path straight over the chord, and keeps the path's previous position in two
  scratch slots (``EvidencePack.slots``). Exact for a path straight at constant speed over each
  chord (Butterly: its kernel takes the legs alone, and cuts its course integral where the
  weight switches); a path whose acceleration is at most M deviates from its chords by at most
  M dt^2 / 8 (dt <= t / ``definite_chords``), and only a path whose true closest approach is
  within that of W / 2 can be misjudged (a CAT path: M = sqrt(a^2 + v^2 omega^2), v = v0 + a s
  its speed; at Figure 1's 4-sigma corner, M ~ 80 m/s^2 at t = 10 s, 6e-2 m with 128 chords).
  The weight is a step, so the carried density jumps across the map points whose paths graze
  the corridor: the CAT's roots are discrete and its density is exact at each point
  (tests/models/test_cat_carried.py), and its cells take the posterior's sub-cell rule on the
  carried density, first order at those curves: measured on Figure 1's CAT with two earlier
  area searches, bearings and a definite track (100 m cells), 8 sub-cells differ from 24 by
  at most 4.0e-4 of a cell's probability (1.7 % of that cell's), 1.7e-3 summed over the grid,
  POS by 1.1e-5 and the track's own POS by 2.6e-4; 4 sub-cells by 8.7e-4 (3.7 %) and 3.3e-3.
  Butterly's course integral is cut where the weight switches (``kernels/butterly.py``,
  ``definite_breaks``), so its density is exact to the course rule's 1e-12;
* a :class:`~bananagrid.PositionReport`: one node, the normal log-likelihood;
* a :class:`~bananagrid.BearingReport`: one node per bearing, same time and factor.

Refused, one line each naming ``evidence[K]``: evidence after the map's time, land (an
:class:`~bananagrid.Exclusion` holds at every time: the posterior applies it at the map's own
time), and more nodes than ``MAX_NODES``.

The channels (``EvidencePack.channel_names``): ``prior`` (no factor: the model's own density),
``all``, ``searches``, ``others`` (the reports) and ``search:K`` for each search K (that search
with the reports): what POS, each search's POS and the POD map need.
"""

from __future__ import annotations

import math

import numpy as np

from ..kernels import evidence as ek
from ..protocol import EvidencePack
from ..validate import BananagridError, finite, positive_int
from .reports import BearingReport, Exclusion, PositionReport
from .searches import AreaSearch, RasterSearch, TrackSearch

__all__ = ["pack", "AREA_PANELS", "PANEL_NODES", "MAX_NODES", "CARRIED_TYPES", "DEFINITE_CHORDS"]

#: Gauss-Legendre nodes per panel of an interval.
PANEL_NODES = 4
#: Panels of an area (or raster) search over an interval.
AREA_PANELS = 16
#: Most time nodes in a pack (each costs a path position and a contribution per path).
MAX_NODES = 4096
#: Chords of a definite-range track per map time: a chord lasts at most t / DEFINITE_CHORDS.
DEFINITE_CHORDS = 128
#: What a pack carries.
CARRIED_TYPES = (AreaSearch, RasterSearch, TrackSearch, PositionReport, BearingReport)


def _gauss_legendre(t0: float, t1: float, panels: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre nodes and weights over [t0, t1]: ``panels`` equal panels of
    PANEL_NODES nodes."""
    x, w = np.polynomial.legendre.leggauss(PANEL_NODES)
    edges = np.linspace(t0, t1, panels + 1)
    half = 0.5 * np.diff(edges)
    mid = 0.5 * (edges[1:] + edges[:-1])
    return (mid[:, None] + half[:, None] * x[None, :]).ravel(), (half[:, None] * w[None, :]).ravel()


class _Builder:
    def __init__(self):
        self.time, self.q, self.data, self.ints = [], [], [], []
        self.edges, self.raster = [], []
        self.slots = 0

    def node(self, t, q, kind, factor, data=(), offset=0, count=0):
        row = np.zeros(ek.DATA_COLUMNS)
        row[: len(data)] = data
        self.time.append(float(t))
        self.q.append(float(q))
        self.data.append(row)
        self.ints.append((kind, factor, offset, count))

    def polygon(self, vertices) -> tuple[int, int, tuple]:
        v = np.asarray(vertices, dtype=float)
        offset = len(self.edges)
        self.edges.extend(np.column_stack((v, np.roll(v, -1, axis=0))))
        box = (v[:, 0].min(), v[:, 0].max(), v[:, 1].min(), v[:, 1].max())
        return offset, len(v), box

    def add_raster(self, values) -> int:
        offset = len(self.raster)
        self.raster.extend(np.asarray(values, dtype=float).ravel())
        return offset


def pack(evidence, t_map: float, *, keys=None, area_panels: int = AREA_PANELS,
         definite_chords: int = DEFINITE_CHORDS) -> EvidencePack:
    """The evidence at times before ``t_map`` (s since the last fix) as a pack.

    Parameters
    ----------
    evidence : sequence
        :class:`AreaSearch`, :class:`RasterSearch`, :class:`TrackSearch` (either law),
        :class:`PositionReport`, :class:`BearingReport`, each ending at or before ``t_map``.
    t_map : float
        The map's time.
    keys : sequence of str, optional
        How errors and channels name each evidence (default ``evidence[K]``, K its index).
    area_panels : int, default AREA_PANELS
        Gauss-Legendre panels of an area or raster search over an interval (its error per
        crossing of an edge: C x 0.35 / area_panels in the exponent; the cost: PANEL_NODES
        nodes a panel, each a position and a look-up per path).
    definite_chords : int, default DEFINITE_CHORDS
        A definite-range track's chords last at most t_map / definite_chords (a path of
        acceleration M is misjudged only where its closest approach is within M dt^2 / 8 of
        W / 2; module docstring).

    Returns
    -------
    EvidencePack

    Raises
    ------
    BananagridError
        Evidence of another type, after ``t_map``, land, or more than :data:`MAX_NODES` nodes
        in all; the message names the evidence's key.
    """
    t_map = finite("t", t_map)
    area_panels = positive_int("area_panels", area_panels)
    definite_chords = positive_int("definite_chords", definite_chords)
    try:
        evidence = list(evidence)
    except TypeError:
        raise BananagridError(f"evidence = {evidence!r}: expected a list of bananagrid evidence") from None
    keys = [f"evidence[{k}]" for k in range(len(evidence))] if keys is None else [str(k) for k in keys]
    if len(keys) != len(evidence):
        raise BananagridError(f"keys: {len(keys)} names for {len(evidence)} pieces of evidence")
    b = _Builder()
    kinds = []
    for factor, (key, e) in enumerate(zip(keys, evidence)):
        if isinstance(e, Exclusion):
            raise BananagridError(f"{key}: land holds at every time; it is applied at the map's own time, not carried")
        if not isinstance(e, CARRIED_TYPES):
            raise BananagridError(f"{key} = {e!r}: expected one of "
                                  f"{', '.join('bg.' + c.__name__ for c in CARRIED_TYPES)}")
        t0, t1 = e.time_span
        if t1 > t_map:
            raise BananagridError(f"{key}.t = {t1!r}: after the map's time t = {t_map!r}; only evidence up to the "
                                  "map's time can be carried to it")
        kinds.append(e.kind)
        if isinstance(e, AreaSearch):
            offset, count, box = b.polygon(e.region.vertices)
            if t0 == t1:
                b.node(t0, 1.0, ek.KIND_POLYGON, factor, (_log_miss(e.miss), *box), offset, count)
            else:
                rate = -_coverage(e.miss) / (t1 - t0)
                for s, q in zip(*_gauss_legendre(t0, t1, area_panels)):
                    b.node(s, q, ek.KIND_POLYGON, factor, (rate, *box), offset, count)
        elif isinstance(e, RasterSearch):
            g = e.grid
            if t0 == t1:
                offset = b.add_raster(e.log_miss)
                b.node(t0, 1.0, ek.KIND_RASTER, factor, (g.origin[0], g.origin[1], g.dx, g.dy, g.ny), offset, g.nx)
            else:
                with np.errstate(invalid="ignore"):
                    offset = b.add_raster(e.log_miss / (t1 - t0))  # -C / (t1 - t0); -inf where POD = 1
                for s, q in zip(*_gauss_legendre(t0, t1, area_panels)):
                    b.node(s, q, ek.KIND_RASTER, factor, (g.origin[0], g.origin[1], g.dx, g.dy, g.ny), offset, g.nx)
        elif isinstance(e, TrackSearch):
            if e.law == "definite":
                _definite_chain(b, e, factor, len(keys), t_map / definite_chords)
                if len(b.time) > MAX_NODES:
                    raise BananagridError(
                        f"{key}: the definite-range track needs {len(b.time)} time nodes with the evidence before it "
                        f"(chords of at most t / {definite_chords} s), above {MAX_NODES}; pass fewer definite_chords")
                continue
            w = e.sweep_width
            for (ax, ay, ta), (bx, by, tb) in zip(e.track[:-1], e.track[1:]):
                length = math.hypot(bx - ax, by - ay)
                coef = w * w * (length / (tb - ta)) / (8.0 * math.pi)
                panels = max(2, math.ceil(length / (0.25 * w)))
                if panels * PANEL_NODES > MAX_NODES:
                    raise BananagridError(
                        f"{key}.sweep_width = {w!r}: a leg of {length:.6g} m needs {panels * PANEL_NODES} time nodes "
                        f"(panels of W / 4), above {MAX_NODES}; split the track or widen the sweep")
                for s, q in zip(*_gauss_legendre(ta, tb, panels)):
                    f = (s - ta) / (tb - ta)
                    b.node(s, q, ek.KIND_INVERSE_CUBE, factor, (ax + f * (bx - ax), ay + f * (by - ay), coef))
        elif isinstance(e, PositionReport):
            p = e.precision
            b.node(e.t, 1.0, ek.KIND_NORMAL, factor, (*e.position, p[0, 0], p[0, 1], p[1, 1]))
        else:  # BearingReport
            for sensor, bearing, sigma in zip(e.fix.sensors, e.fix.bearings, e.fix.sigmas):
                b.node(e.t, 1.0, ek.KIND_BEARING, factor, (sensor[0], sensor[1], bearing, 1.0 / sigma))
        if len(b.time) > MAX_NODES:
            raise BananagridError(f"{key}: the evidence needs {len(b.time)} time nodes in all, above {MAX_NODES}")
    return _finish(b, t_map, keys, kinds)


def _definite_chain(b: _Builder, e: TrackSearch, factor: int, n_factors: int, longest: float) -> None:
    """A definite-range track's chain (``kernels/evidence.py``, ``KIND_DEFINITE``): a node at
    the first track point, then one at the end of each chord, each leg cut into the fewest
    equal chords of at most ``longest`` seconds; its two scratch slots after the factors'."""
    slot = n_factors + b.slots
    b.slots += 2
    h = 0.5 * e.sweep_width
    x0, y0, t0 = (float(v) for v in e.track[0])
    b.node(t0, 1.0, ek.KIND_DEFINITE, factor, (x0, y0, x0, y0, h), slot, ek.DEFINITE_START | ek.DEFINITE_LEG)
    for (ax, ay, ta), (bx, by, tb) in zip(e.track[:-1], e.track[1:]):
        n = max(1, math.ceil((tb - ta) / longest * (1.0 - 1e-12)))
        for i in range(1, n + 1):
            f0, f1 = (i - 1) / n, i / n
            s = tb if i == n else ta + f1 * (tb - ta)
            b.node(s, 1.0, ek.KIND_DEFINITE, factor,
                   (ax + f1 * (bx - ax), ay + f1 * (by - ay), ax + f0 * (bx - ax), ay + f0 * (by - ay), h), slot,
                   ek.DEFINITE_LEG if i == n else 0)


def _log_miss(miss: float) -> float:
    return math.log(miss) if miss > 0.0 else -math.inf


def _coverage(miss: float) -> float:
    return -math.log(miss) if miss > 0.0 else math.inf


def _finish(b: _Builder, t_map: float, keys, kinds) -> EvidencePack:
    n_factors = len(keys)
    order = np.argsort(np.asarray(b.time, dtype=float), kind="stable")
    arrays = {
        "time": np.asarray(b.time, dtype=float).reshape(-1)[order],
        "q": np.asarray(b.q, dtype=float).reshape(-1)[order],
        "data": np.asarray(b.data, dtype=float).reshape(-1, ek.DATA_COLUMNS)[order],
        "ints": np.asarray(b.ints, dtype=np.int32).reshape(-1, ek.INT_COLUMNS)[order],
        "edges": np.asarray(b.edges, dtype=float).reshape(-1, 4) if b.edges else np.zeros((1, 4)),
        "raster": np.asarray(b.raster, dtype=float) if b.raster else np.zeros(1),
    }
    searches = [k for k in range(n_factors) if kinds[k] == "search"]
    others = [k for k in range(n_factors) if kinds[k] != "search"]
    names = ["prior", "all", "searches", "others"] + [f"search:{keys[k]}" for k in searches]
    members = [[], list(range(n_factors)), searches, others] + [[k, *others] for k in searches]
    channels = np.zeros((len(names), max(n_factors, 1)), dtype=np.int32)
    for c, m in enumerate(members):
        channels[c, m] = 1
    arrays["channels"] = channels if n_factors else channels[:, :0].copy()
    for a in arrays.values():
        a.setflags(write=False)
    return EvidencePack(t=t_map, channel_names=tuple(names), factor_keys=tuple(keys),
                        factor_kinds=tuple("search" if k == "search" else "report" for k in kinds), slots=b.slots,
                        **arrays)
