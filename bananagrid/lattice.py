"""Polar lattices: cells in (range, bearing) about a pose, and the models' probabilities on them.

A tracker that gates on range and bearing wants the probability of each (range, bearing) cell,
not a density sampled on a Cartesian grid. :class:`PolarLattice` describes such cells about a
pose; :func:`rasterise_lattice` (reached through :func:`bananagrid.rasterise`) gives, for any
model, the density per (m, rad) at each cell centre and the probability integrated over each
cell by Gauss-Legendre quadrature, with the sub-cell size chosen from the model's length scales.

Coordinates
-----------
A lattice's pose has a world origin O and a heading h (a bearing clockwise from north). The
point at range r and bearing b (radians clockwise from the heading) is

    (x, y) = O + r (sin(h + b), cos(h + b)),

so for a motion model with the same pose, b is the paper's phi = atan2(x_local, y_local). The
area element is r dr db, hence a density per (m, rad) is r p(x, y) with p the model's density
per m^2.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from .grid import MAX_CELLS
from .models import Pose
from .validate import BananagridError, finite, positive

__all__ = ["PolarLattice", "PolarRaster", "rasterise_lattice", "GAUSS_TOL", "MAX_NODES"]

#: Relative slack for "the step divides the span": span / step within this of a whole number.
DIVIDES_RTOL = 1e-9

#: Target Gauss-Legendre error per sub-interval and axis, for a normal feature whose SD equals
#: the length scale, as a fraction of that feature's mass (see :func:`_gauss_error`).
GAUSS_TOL = 1e-10

#: Most Gauss-Legendre nodes per sub-interval.
MAX_ORDER = 8

#: Most sub-intervals per cell and axis (so at most MAX_SUBINTERVALS * MAX_ORDER nodes per axis).
MAX_SUBINTERVALS = 256

#: Most quadrature nodes over the whole lattice (about 30 s of CAT evaluations on two cores).
#: Beyond it the sub-intervals are coarsened and a warning says what accuracy is left.
MAX_NODES = 2**26

#: Points per evaluate_points call (bounds the memory of the node arrays: ~100 MB at 2**20).
NODE_CHUNK = 2**20

_TWO_PI = 2.0 * math.pi


def _pair(name: str, value) -> tuple[float, float]:
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise BananagridError(f"{name} = {value!r}: expected a pair (low, high)") from None
    return finite(f"{name}[0]", lo), finite(f"{name}[1]", hi)


def _count(name: str, step: float, span: float, span_text: str, unit: str) -> int:
    """Number of steps in ``span``; raise unless ``step`` divides it (within DIVIDES_RTOL)."""
    ratio = span / step
    n = round(ratio)
    if n < 1 or abs(ratio - n) > DIVIDES_RTOL * max(1.0, ratio):
        best = max(1, n)
        raise BananagridError(
            f"{name} = {step!r}: does not divide the {span_text} {span!r} {unit} "
            f"({ratio:.6g} steps); the nearest step that divides it is {span / best!r} "
            f"({best} cell{'s' if best > 1 else ''})"
        )
    return int(n)


@dataclass(frozen=True)
class PolarLattice:
    r"""Cells in (range, bearing) about a pose: ``values[i, j]`` belongs to the annular sector
    ``range_edges[i] <= r <= range_edges[i + 1]``, ``bearing_edges[j] <= b <= bearing_edges[j + 1]``.

    Rows run outward in range, columns clockwise in bearing. A cell's centre is the midpoint of
    its range and bearing intervals.

    Parameters
    ----------
    ranges : (float, float)
        ``(r_min, r_max)``: range interval in metres from the pose origin, 0 <= r_min < r_max.
    range_step : float
        Radial cell size dr, m, > 0; must divide ``r_max - r_min`` (within 1e-9 relative).
    bearings : (float, float)
        ``(b_min, b_max)``: bearing interval in radians clockwise from the pose heading,
        b_min < b_max, span at most 2 pi (a full circle covers every direction once).
    bearing_step : float
        Angular cell size db, rad, > 0; must divide ``b_max - b_min``.
    pose : Pose, default origin (0, 0), heading north
        The lattice's origin and the direction of bearing 0.

    Notes
    -----
    The cell ``[r0, r1] x [b0, b1]`` has the area ``(r1^2 - r0^2) / 2 (b1 - b0)`` m^2 (exact);
    the lattice has at most ``MAX_CELLS`` cells.
    """

    ranges: tuple[float, float]
    range_step: float
    bearings: tuple[float, float]
    bearing_step: float
    pose: Pose = field(default_factory=Pose)

    def __post_init__(self):
        r_min, r_max = _pair("ranges", self.ranges)
        b_min, b_max = _pair("bearings", self.bearings)
        dr = positive("range_step", self.range_step)
        db = positive("bearing_step", self.bearing_step)
        if r_min < 0.0:
            raise BananagridError(
                f"ranges = ({r_min!r}, {r_max!r}): the range starts below zero (ranges[0] = {r_min!r}); "
                "ranges are distances from the pose origin, >= 0 m"
            )
        if not r_max > r_min:
            raise BananagridError(f"ranges = ({r_min!r}, {r_max!r}): the upper bound must exceed the lower")
        if not b_max > b_min:
            raise BananagridError(f"bearings = ({b_min!r}, {b_max!r}): the upper bound must exceed the lower")
        b_span = b_max - b_min
        if b_span > _TWO_PI * (1.0 + 1e-12):
            raise BananagridError(
                f"bearings = ({b_min!r}, {b_max!r}): the span {b_span!r} rad exceeds 2 pi "
                f"({_TWO_PI!r}); a lattice covers each direction at most once"
            )
        if not isinstance(self.pose, Pose):
            raise BananagridError(f"pose = {self.pose!r}: expected a bananagrid.Pose")
        n_range = _count("range_step", dr, r_max - r_min, "range span", "m")
        n_bearing = _count("bearing_step", db, b_span, "bearing span", "rad")
        cells = n_range * n_bearing
        if cells > MAX_CELLS:
            raise BananagridError(
                f"polar lattice of {n_range} x {n_bearing} = {cells:,} cells would take "
                f"{cells * 8 / 2**30:.1f} GiB as float64; the limit is {MAX_CELLS:,} cells: use a "
                "larger range_step or bearing_step, or smaller ranges or bearings"
            )
        object.__setattr__(self, "ranges", (r_min, r_max))
        object.__setattr__(self, "bearings", (b_min, b_max))
        object.__setattr__(self, "range_step", dr)
        object.__setattr__(self, "bearing_step", db)

    # -- shape and coordinates -------------------------------------------------------------

    @property
    def n_range(self) -> int:
        return round((self.ranges[1] - self.ranges[0]) / self.range_step)

    @property
    def n_bearing(self) -> int:
        return round((self.bearings[1] - self.bearings[0]) / self.bearing_step)

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_range, n_bearing)``: the shape of a values array on this lattice."""
        return (self.n_range, self.n_bearing)

    @property
    def range_edges(self) -> np.ndarray:
        """Range cell edges, m, shape ``(n_range + 1,)``; the last is exactly ``r_max``."""
        return np.linspace(self.ranges[0], self.ranges[1], self.n_range + 1)

    @property
    def range_centres(self) -> np.ndarray:
        """Range cell centres (midpoints), m, shape ``(n_range,)``."""
        e = self.range_edges
        return 0.5 * (e[:-1] + e[1:])

    @property
    def bearing_edges(self) -> np.ndarray:
        """Bearing cell edges, rad clockwise from the pose heading, shape ``(n_bearing + 1,)``."""
        return np.linspace(self.bearings[0], self.bearings[1], self.n_bearing + 1)

    @property
    def bearing_centres(self) -> np.ndarray:
        """Bearing cell centres (midpoints), rad clockwise from the pose heading, ``(n_bearing,)``."""
        e = self.bearing_edges
        return 0.5 * (e[:-1] + e[1:])

    @property
    def cell_areas(self) -> np.ndarray:
        """Exact annular-sector areas ``(r1^2 - r0^2) / 2 * (b1 - b0)``, m^2, ``(n_range, n_bearing)``."""
        r, b = self.range_edges, self.bearing_edges
        ring = 0.5 * (r[1:] - r[:-1]) * (r[1:] + r[:-1])  # (r1^2 - r0^2) / 2 without cancellation
        return ring[:, None] * np.diff(b)[None, :]

    @property
    def area(self) -> float:
        """Total area covered, m^2: ``(r_max^2 - r_min^2) / 2 * (b_max - b_min)``."""
        (r0, r1), (b0, b1) = self.ranges, self.bearings
        return 0.5 * (r1 - r0) * (r1 + r0) * (b1 - b0)

    def to_world(self, r, b) -> tuple[np.ndarray, np.ndarray]:
        """World (x east, y north) of range ``r`` and bearing ``b`` (broadcast):
        ``O + r (sin(h + b), cos(h + b))``."""
        theta = self.pose.heading + np.asarray(b, dtype=float)
        r = np.asarray(r, dtype=float)
        return self.pose.origin[0] + r * np.sin(theta), self.pose.origin[1] + r * np.cos(theta)

    @property
    def world_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates ``(x, y)`` of the cell centres, each ``(n_range, n_bearing)``."""
        return self.to_world(self.range_centres[:, None], self.bearing_centres[None, :])

    def describe(self) -> dict:
        """Plain-data description for recordings and provenance."""
        return {
            "ranges": list(self.ranges),
            "range_step": self.range_step,
            "bearings": list(self.bearings),
            "bearing_step": self.bearing_step,
            "origin": list(self.pose.origin),
            "heading": self.pose.heading,
            "n_range": self.n_range,
            "n_bearing": self.n_bearing,
        }


@dataclass(frozen=True)
class PolarRaster:
    """A model on a :class:`PolarLattice`: densities at the cell centres and cell probabilities.

    Attributes
    ----------
    density : ndarray, shape (n_range, n_bearing)
        Density per (m, rad) at each cell centre, ``r p(x, y)`` with p the model's density per
        m^2 (kernel dtype). ``sum(density) * dr * db`` is the midpoint-rule mass.
    probability : ndarray, shape (n_range, n_bearing), float64
        Probability of each cell: the integral of p over the cell, ``int int p r dr db``
        (Gauss-Legendre, accuracy in ``provenance["accuracy"]``).
    lattice : PolarLattice
    mass : float
        ``sum(probability)`` before any normalisation: the mass the lattice captures.
    normalised : bool
        Whether ``density`` and ``probability`` were divided by ``mass``.
    provenance : dict
        Model parameters, lattice, dtype, device, threads, seconds, nodes and the accuracy claim.
    """

    density: np.ndarray
    probability: np.ndarray
    lattice: PolarLattice
    mass: float
    normalised: bool = False
    provenance: dict = field(default_factory=dict)

    @property
    def ranges(self) -> np.ndarray:
        """Range cell centres, m."""
        return self.lattice.range_centres

    @property
    def bearings(self) -> np.ndarray:
        """Bearing cell centres, rad clockwise from the lattice's heading."""
        return self.lattice.bearing_centres

    def normalise(self) -> "PolarRaster":
        """Return a copy whose probabilities sum to one; ``mass`` keeps the raw captured mass."""
        if not self.mass > 0.0:
            raise BananagridError(
                f"cannot normalise a polar raster that captured no mass (mass = {self.mass!r}): "
                "the lattice misses the model's support"
            )
        if self.normalised:
            return self
        return replace(
            self,
            density=self.density / np.asarray(self.mass, dtype=self.density.dtype),
            probability=self.probability / self.mass,
            normalised=True,
        )


# --------------------------------------------------------------------------------------------
# Length scales and the quadrature plan
# --------------------------------------------------------------------------------------------


def _motion_scales(model) -> tuple[float, float]:
    # SD of r given phi is sigma_a t^2 / 2 scc(phi) (11); half of sigma_a t^2 / 2 keeps scc >= 1/2
    # (|phi| <= 2.4 rad) covered. The ridge r = P_mu(phi) moves by at most v0 t per radian
    # (|d sinc / d phi| < 0.44), so a radial scale L needs an angular one L / (v0 t).
    radial = 0.25 * model.sigma_a * model.t**2
    angular = min(0.5 * model.sigma_omega * model.t, radial / (model.v0 * model.t))
    return radial, angular


def _length_scales(model, origin=(0.0, 0.0)) -> tuple[float, float]:
    """Smallest widths of a model's density features in polar coordinates: ``(radial_m,
    angular_rad)``.

    * CAT and PolarBanana, about their own pose: the radial scale is half the range SD at phi =
      0, ``sigma_a t^2 / 4``; the angular scale is ``min(sigma_omega t / 2, radial / (v0 t))``
      (the bearing SD, or the turn that moves the ridge ``r = P_mu(phi)`` by the radial scale).
      Heading noise (``sigma_heading``) only smooths and is ignored.
    * BearingFix, about ``origin``: ``sqrt(v2)`` with v2 the smallest principal variance of the
      fix, and that divided by the distance from ``origin`` to the fix.
    * Butterly, about ``origin``: sigma_min, the start's smallest SD (the ring's narrowest
      profile and, for r << sigma, the normal's), and that divided by the distance from
      ``origin`` to the start mean (2 pi at the mean; the Cartesian rule then gives a row at
      range R the angular scale sigma_min / R, see :func:`_plan`).

    Raises
    ------
    BananagridError
        For a model whose scales are not known.
    """
    from .bearing import BearingFix
    from .butterly import Butterly
    from .models import CAT, PolarBanana

    if isinstance(model, (CAT, PolarBanana)):
        return _motion_scales(model)
    if isinstance(model, (BearingFix, Butterly)):
        if isinstance(model, BearingFix):
            radial, centre = math.sqrt(model.principal_variances[1]), model.fix
        else:
            radial, centre = model.sigma_min, np.asarray(model.mean)
        distance = math.hypot(*(centre - np.asarray(origin, dtype=float)))
        return radial, (radial / distance if distance > 0.0 else _TWO_PI)
    raise BananagridError(
        f"model = {type(model).__name__}: polar lattices know the length scales of CAT, "
        "PolarBanana, BearingFix and Butterly only"
    )


def _cartesian_scale(model, radial: float, angular: float) -> float:
    """Smallest feature width in metres: the radial scale, or the angular scale at the range
    where the model's mass lies (v0 t for motion models; the fix's distance for BearingFix,
    whose angular scale is radial / distance, so this is the radial scale; likewise the start
    mean's for Butterly)."""
    from .bearing import BearingFix
    from .butterly import Butterly

    if isinstance(model, (BearingFix, Butterly)):
        return radial
    return min(radial, angular * model.v0 * model.t)


def _same_pose(a: Pose, b: Pose) -> bool:
    scale = max(1.0, *map(abs, a.origin), *map(abs, b.origin))
    turn = (a.heading - b.heading + math.pi) % _TWO_PI - math.pi
    return math.dist(a.origin, b.origin) <= 1e-12 * scale and abs(turn) <= 1e-12


def _error_constant(n: int) -> float:
    """Gauss-Legendre remainder on [-1, 1]: E = K_n f^(2n)(xi), K_n = 2^(2n+1) (n!)^4 /
    ((2n + 1) ((2n)!)^3)."""
    return 2.0 ** (2 * n + 1) * math.factorial(n) ** 4 / ((2 * n + 1) * float(math.factorial(2 * n)) ** 3)


def _gauss_error(n: int, q: float) -> float:
    r"""Error bound of the n-point Gauss-Legendre rule on an interval of width ``q sigma`` for a
    normal density of SD sigma (as a fraction of its unit mass).

    .. math:: E \le K_n (q/2)^{2n+1} \max|\mathrm{He}_{2n}(z)\,\varphi(z)|
              = K_n (q/2)^{2n+1} (2n-1)!! / \sqrt{2\pi}

    (the maximum is at z = 0). With q = 1: 2.8e-4 (n = 2), 2.4e-8 (4), 7.8e-13 (6).
    """
    double_factorial = math.prod(range(1, 2 * n, 2))
    return _error_constant(n) * (0.5 * q) ** (2 * n + 1) * double_factorial / math.sqrt(_TWO_PI)


def _axis_plan(width: float, scale: float, cap: int) -> tuple[int, int, float]:
    """``(m, n, error)``: m equal sub-intervals of at most ``scale`` (no more than ``cap``) with
    the fewest nodes n <= MAX_ORDER whose :func:`_gauss_error` meets GAUSS_TOL."""
    m = max(1, min(cap, math.ceil(width / scale * (1.0 - 1e-12))))
    q = width / (m * scale)
    for n in range(1, MAX_ORDER + 1):
        err = _gauss_error(n, q)
        if err <= GAUSS_TOL:
            return m, n, err
    return m, MAX_ORDER, min(err, 1.0)  # beyond q ~ 2 the bound says nothing: at most the mass


def _unit_rule(m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre rule on [0, 1]: m sub-intervals of n nodes; (nodes, weights)."""
    x, w = np.polynomial.legendre.leggauss(n)
    nodes = (np.arange(m)[:, None] + 0.5 * (x[None, :] + 1.0)) / m
    return nodes.ravel(), np.tile(0.5 * w / m, m)


@dataclass(frozen=True)
class _Plan:
    radial: tuple[int, int]  # (m, n) for every row
    angular: list  # (m, n) per row
    error: float  # largest estimated error per sub-interval (radial + angular)
    scales: tuple[float, float]
    rule: str  # "model frame" or "cartesian"
    total_nodes: int


def _plan(model, lattice: PolarLattice) -> _Plan:
    """Sub-intervals and nodes per cell: sub-cells no larger than the model's length scales.

    With a motion model whose pose is the lattice's, the model's polar scales apply directly.
    Otherwise the Cartesian scale L (:func:`_cartesian_scale`) bounds the radial sub-step and
    ``L / r1`` the angular one in a row whose outer edge is r1 (a cell's arc there is r1 db).
    """
    radial, angular = _length_scales(model, lattice.pose.origin)
    own_frame = hasattr(model, "pose") and _same_pose(model.pose, lattice.pose)
    dr, db = lattice.range_step, lattice.bearing_step
    outer = lattice.range_edges[1:]
    if own_frame:
        r_scale, b_scales = radial, np.full(lattice.n_range, angular)
    else:
        r_scale = _cartesian_scale(model, radial, angular)
        b_scales = r_scale / outer
    cells_per_row = lattice.n_bearing
    cap = MAX_SUBINTERVALS
    while True:
        rm, rn, r_err = _axis_plan(dr, r_scale, cap)
        rows = [_axis_plan(db, s, cap) for s in b_scales]
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


def _tasks(lattice: PolarLattice, plan: _Plan):
    """Blocks ``(row, j0, j1, a0, a1)`` of at most NODE_CHUNK nodes: bearing cells j0:j1 of
    ``row`` with radial nodes a0:a1."""
    rm, rn = plan.radial
    n_r_nodes = rm * rn
    nb = lattice.n_bearing
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


def _model_radii(model, lattice: PolarLattice) -> tuple[float, float]:
    """Distances from the model's origin that cover the whole lattice: one range for every
    chunk, so that a tabulated model (CAT with heading noise) builds its table once."""
    pose = getattr(model, "pose", None)
    offset = math.dist(pose.origin, lattice.pose.origin) if pose is not None else 0.0
    r_min, r_max = lattice.range_edges[0], lattice.range_edges[-1]
    return max(0.0, r_min - offset), r_max + offset


def _integrate(model, lattice: PolarLattice, plan: _Plan, *, dtype, device, threads) -> np.ndarray:
    """Cell probabilities: sum over nodes of w_r(r) r w_b p(O + r u(h + b)), float64."""
    from .raster import evaluate_points

    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    r_nodes, r_weights = _unit_rule(*plan.radial)
    b_rules = {mn: _unit_rule(*mn) for mn in set(plan.angular)}
    heading = lattice.pose.heading
    ox, oy = lattice.pose.origin
    probability = np.zeros(lattice.shape)

    def expand():
        for row, j0, j1, a0, a1 in _tasks(lattice, plan):
            yield row, j0, j1, a0, a1, len(b_rules[plan.angular[row]][0])

    radii = _model_radii(model, lattice)
    for group in _groups(expand()):
        xs, ys, parts = [], [], []
        for row, j0, j1, a0, a1, _ in group:
            r0, r1 = r_edges[row], r_edges[row + 1]
            r = r0 + (r1 - r0) * r_nodes[a0:a1]
            w_r = (r1 - r0) * r_weights[a0:a1] * r  # the polar area element r dr
            v, w_v = b_rules[plan.angular[row]]
            lo, hi = b_edges[j0:j1, None], b_edges[j0 + 1 : j1 + 1, None]
            theta = heading + lo + (hi - lo) * v[None, :]  # (J, K)
            w_b = (hi - lo) * w_v[None, :]
            s, c = np.sin(theta), np.cos(theta)
            xs.append((ox + r[:, None, None] * s[None]).ravel())
            ys.append((oy + r[:, None, None] * c[None]).ravel())
            parts.append((row, j0, j1, w_r, w_b, r.size, theta.shape))
        values = evaluate_points(
            model, np.concatenate(xs), np.concatenate(ys), dtype=dtype, device=device, threads=threads,
            radii=radii,
        )
        start = 0
        for row, j0, j1, w_r, w_b, a, (J, K) in parts:
            block = values[start : start + a * J * K].reshape(a, J, K)
            start += a * J * K
            probability[row, j0:j1] += np.einsum("a,ajk,jk->j", w_r, block, w_b, dtype=np.float64)
    return probability


def rasterise_lattice(
    model, lattice: PolarLattice, *, dtype=np.float64, device: str = "cpu", threads=None
) -> PolarRaster:
    r"""Densities at the cell centres and probabilities of the cells of a polar lattice.

    .. math::

        \mathrm{density}_{ij} = r_i\, p(x(r_i, b_j), y(r_i, b_j)),\qquad
        \mathrm{probability}_{ij} = \int_{r_i^-}^{r_i^+}\!\int_{b_j^-}^{b_j^+} p(x, y)\, r\, db\, dr,

    with ``(x, y) = O + r (sin(h + b), cos(h + b))`` and p the model's density per m^2.

    The integral is a tensor Gauss-Legendre rule over sub-cells no larger than the model's
    length scales (:func:`_length_scales`): per axis, m equal sub-intervals of at most the scale
    and the fewest nodes n (<= 8) whose remainder bound for a normal feature of that SD is below
    ``GAUSS_TOL`` = 1e-10 of its mass (:func:`_gauss_error`). Where the density is as smooth as
    its scales say, each cell's probability is then within about 1e-9 of the model's total mass.
    Folds of a CAT banana (sigma_omega t beyond about 90 deg) have integrable infinite density
    and converge more slowly. Every node is evaluated by the model's own kernels through
    :func:`bananagrid.raster.evaluate_points`, at most ``NODE_CHUNK`` points at a time.

    Parameters
    ----------
    model : CAT, PolarBanana, BearingFix or Butterly
    lattice : PolarLattice
    dtype, device, threads
        As for :func:`bananagrid.rasterise`; probabilities are summed in float64.

    Returns
    -------
    PolarRaster
        Raw densities per (m, rad) and probabilities, with the captured mass and provenance.

    Warns
    -----
    UserWarning
        When ``MAX_NODES`` or ``MAX_SUBINTERVALS`` keeps the rule from meeting ``GAUSS_TOL``.
    """
    from .raster import _check_finite, _check_threads, evaluate_points

    if not isinstance(lattice, PolarLattice):
        raise BananagridError(f"lattice = {lattice!r}: expected a bananagrid.PolarLattice")
    threads = _check_threads(threads)
    start = time.perf_counter()
    plan = _plan(model, lattice)
    x, y = lattice.world_centres
    radii = _model_radii(model, lattice)
    p = evaluate_points(model, x, y, dtype=dtype, device=device, threads=threads, radii=radii)
    density = (lattice.range_centres[:, None] * p).astype(p.dtype, copy=False)
    _check_finite(density, model)
    probability = _integrate(model, lattice, plan, dtype=dtype, device=device, threads=threads)
    _check_finite(probability, model)
    seconds = time.perf_counter() - start
    (rm, rn), angular = plan.radial, [m * n for m, n in plan.angular]
    provenance = {
        **model.parameters(),
        "lattice": lattice.describe(),
        "dtype": np.dtype(dtype).name,
        "device": device,
        "threads": threads if device == "cpu" else 1,
        "seconds": seconds,
        "quadrature": "tensor Gauss-Legendre over sub-cells",
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
