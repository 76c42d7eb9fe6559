"""The exact CAT density: constant, unknown acceleration and turn rate (Gade et al.; eq. (1) of
the polar-banana paper), with an optional normal error on the initial heading (Section 7)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import erfc

from ..domains.pose import Pose
from ..kernels import cat as kernels
from ..kernels import cat_cells
from ..protocol import CellPlan, Extent, KernelBinding, KernelContext, SceneKey, SceneSchema
from ..validate import BananagridError, positive
from ._cat_heading import clear_heading_tables, first_table_nodes, heading_table, ray_densities, table_binding
from .base import check_n, check_rng
from .motion import MOTION_KEYS, MotionModel, pose_arguments

__all__ = ["CAT", "cat_position", "scan_nodes", "clear_heading_tables", "NODE_SPACING"]

#: Turn-rate node spacing of the scan table, in units of omega t (radians). The kernel's bounds
#: find every root at any spacing; at this one they are tight enough that few node intervals
#: need splitting.
NODE_SPACING = 0.1
MIN_NODES = 64
#: The scan's domain: at most this many nodes (a 336 MB float64 table, and 0.17 s a cell), i.e.
#: k_sigma sigma_omega t up to 209,715 rad (over 4,000 turns at one SD with k_sigma = 8); a
#: wider scan is refused, not thinned, since the kernel's proof needs nodes NODE_SPACING apart.
MAX_NODES = 2**22

#: Work estimate of a cell where the density is not negligible, one core, float64
#: (:meth:`CAT.work_estimate`): its root refinements, plus each scan node's multiply-adds.
#: Measured 1.8-2.0 us at 81 nodes, 15-17 us at 481, 56-94 us at 4,801 and 0.68-0.80 ms at
#: 48,001, on grids of 10,000-22,000 cells framing the banana's 99 % (AMD Zen 4); rounded up.
SECONDS_PER_CELL = 2e-6
SECONDS_PER_NODE = 40e-9
#: And per cell interpolated in a heading table.
SECONDS_PER_TABLE_CELL = 0.5e-6


#: Exact-in-acceleration cell probabilities (:meth:`CAT.grid_cells`): turn-rate intervals
#: per crossing of the smallest cell side by the fastest-moving point of a line (so that an
#: interval's ribbon of lines is narrower than a cell), and at least per sigma_omega; the work
#: estimate per cell an interval's edge lines walk (a few normal intervals and corner tests;
#: measured 100-200 ns on the reference machine, AMD Zen 4, rounded up) and per interval.
CELL_SUBSTEPS = 8
CELL_SIGMA_STEPS = 16
#: Largest distance between an interval's lines and their linear interpolation, as a fraction
#: of the smaller of the cell and the acceleration's SD along a line (the scale over which a
#: cell's share of a line changes): the rule's remaining error, about 4.3 times this relative
#: to a cell's probability over the sweep (4.3e-5 at 1e-5, 4.3e-6 at 1e-6).
CELL_CURVE_TOL = 1e-6
SECONDS_PER_LINE_CELL = 400e-9
SECONDS_PER_LINE = 1e-6
#: Most turn-rate intervals of the cell probabilities (512 MiB of edges).
MAX_CELL_NODES = 2**26


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
    cell and the acceleration's SD along a line, sigma_a t^2 |(C, D)|, of their linear
    interpolation between its edges: h^2 |d^2 P / domega^2| / 8, with |d^2 P / domega^2| <=
    t^2 (v0 t / 6 + Z_MAX sigma_a t^2 / 12) (``line_speed``'s integrals, one power of s more)."""
    t = model.t
    span = 2.0 * model.k_sigma * model.sigma_omega
    grid_of_span = np.linspace(-0.5 * span, 0.5 * span, 4097)
    sd_along = model.sigma_a * float(np.min(np.hypot(*cat_position(0.0, t, 1.0, grid_of_span).T)))
    curvature = t * t * (model.v0 * t / 6.0 + cat_cells.Z_MAX * model.sigma_a * t * t / 12.0)
    step = min(cell / (CELL_SUBSTEPS * line_speed(model)), model.sigma_omega / CELL_SIGMA_STEPS,
               math.sqrt(8.0 * CELL_CURVE_TOL * min(cell, sd_along) / curvature))
    return np.linspace(-0.5 * span, 0.5 * span, max(1, math.ceil(span / step)) + 1)


def cat_position(v0, t, a, omega) -> np.ndarray:
    """Local CAT position of eq. (1) for arrays of accelerations and turn rates, shape (n, 2).

    Written with u = omega t as  v0 t (A, B) + a t^2 (C, D)  (see ``kernels.common.cat_basis``);
    C and D use their series below |u| = 1e-2, where the closed forms cancel.
    """
    u = np.asarray(omega, dtype=float) * t
    a = np.asarray(a, dtype=float)
    half = 0.5 * u
    A = np.sin(half) * np.sinc(half / np.pi)  # np.sinc is normalised: sinc(x/pi) = sin(x)/x
    B = np.sinc(u / np.pi)
    small = np.abs(u) < 1e-2
    us = np.where(small, 1.0, u)  # avoid 0/0 in the branch that is not used
    C = np.where(small, u / 3 - u**3 / 30 + u**5 / 840, (np.sin(us) - us * np.cos(us)) / us**2)
    D = np.where(small, 0.5 - u**2 / 8 + u**4 / 144, (np.cos(us) + us * np.sin(us) - 1) / us**2)
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


def _rotate(local: np.ndarray, theta0: np.ndarray) -> np.ndarray:
    """Turn local points by theta0 (radians, clockwise: a heading error to starboard)."""
    c, s = np.cos(theta0), np.sin(theta0)
    x, y = local[:, 0], local[:, 1]
    return np.column_stack((x * c + y * s, -x * s + y * c))


@dataclass(frozen=True)
class CAT(MotionModel):
    """Constant, unknown acceleration and turn rate (Gade et al.; eq. (1) of the polar-banana paper).

    From the origin, heading +y at speed ``v0``, the target moves for ``t`` seconds with constant
    acceleration a ~ N(0, sigma_a) and turn rate omega ~ N(0, sigma_omega). Its density at (x, y)
    is the sum over every (a, omega) reaching (x, y) of g(a) g(omega) / |det d(x,y)/d(a,omega)|.

    Parameters
    ----------
    v0 : float
        Initial speed, m/s, > 0.
    t : float
        Elapsed time, s, > 0.
    sigma_a : float
        Standard deviation of the acceleration, m/s^2, > 0.
    sigma_omega : float
        Standard deviation of the turn rate, rad/s, > 0.
    k_sigma : float, default 8
        Turn rates are searched within +-k_sigma * sigma_omega; the mass beyond,
        erfc(k_sigma / sqrt 2) (1.2e-15 at 8), is reported as ``truncated_mass`` and excluded.
    sigma_heading : float, default 0
        Standard deviation sigma_0 (radians, >= 0) of a normal error theta_0 on the initial
        heading (Section 7 of the polar-banana paper). The density is then the exact CAT density
        convolved over the rotation by theta_0 about the origin:
        p(r, theta) = integral of p_0(r, theta - theta_0) g(theta_0; 0, sigma_0) d theta_0, computed
        on a polar lattice (exact wrapped-normal convolution by FFT along the bearing, then
        interpolation; see :mod:`bananagrid.models._cat_heading`). 0 gives the plain kernel exactly.
    pose : Pose, default origin (0, 0), heading north
        Places the local frame in the world.

    Notes
    -----
    For a fixed turn rate omega the position is affine in the acceleration a, so a point P is
    reached at omega iff F(omega) = h(omega) x (P - v0 f(omega)) = 0, and dF/domega = -det J
    there. Each cell scans a table of F's coefficients at :func:`scan_nodes`, refines each sign
    change by Newton from the cubic Hermite root, and finds the root pairs where the banana
    folds over itself wherever proved bounds on F's derivatives cannot exclude them; see
    ``kernels/cat.py`` (``cat_interval``).
    """

    v0: float
    t: float
    sigma_a: float
    sigma_omega: float
    k_sigma: float = 8.0
    sigma_heading: float = 0.0
    pose: Pose = field(default_factory=Pose)

    kind = "cat"
    #: float32 agreement with float64 where the density exceeds 1e-6 of its peak, beyond the
    #: density's change over the point's float32 rounding (``DensityModel.float32_rtol``).
    float32_rtol = 2e-4
    scene = SceneSchema(
        keys=(
            MOTION_KEYS["v0"], MOTION_KEYS["t"], MOTION_KEYS["sigma_a"], MOTION_KEYS["sigma_omega"],
            SceneKey("k_sigma", default="`8`", allowed="in [1, 38]: turn rates beyond +-k_sigma sigma_omega are left out"),
            MOTION_KEYS["sigma_heading"], MOTION_KEYS["origin"], MOTION_KEYS["heading"],
        ),
        required=("v0", "sigma_a", "sigma_omega"),
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
        pose = ctx.array(self.pose.as_array())
        if self.sigma_heading > 0.0:
            table = heading_table(self, *extent.radii(self.pose.origin), threads=ctx.threads)
            return table_binding(ctx, table, pose, {
                "k_sigma": self.k_sigma, "truncated_mass": self.truncated_mass, **table.notes(),
            })
        omegas = scan_nodes(self)
        table = ctx.zeros((len(omegas), kernels.TABLE_COLUMNS))
        ctx.launch(kernels.cat_table, dim=len(omegas),
                   inputs=[ctx.array(omegas), ctx.scalar(self.v0), ctx.scalar(self.t), table])
        # Newton stops when its step is below a few ulps of the searched range.
        tol = 8.0 * np.finfo(ctx.dtype).eps * self.k_sigma * self.sigma_omega
        params = (
            table, ctx.scalar(self.v0), ctx.scalar(self.t), ctx.scalar(self.sigma_a),
            ctx.scalar(self.sigma_omega), pose, ctx.scalar(tol), ctx.scalar(np.finfo(ctx.dtype).eps),
        )
        notes = {"scan_nodes": len(omegas), "k_sigma": self.k_sigma, "truncated_mass": self.truncated_mass}
        return KernelBinding(kernels.cat_grid, kernels.cat_points, params, "cat.cat_grid", notes)

    def work_estimate(self, cells: int, extent: Extent) -> float:
        """Seconds of one core: ``cells (SECONDS_PER_CELL + nodes SECONDS_PER_NODE)`` for the
        scan; with heading noise the heading table's nodes (:func:`first_table_nodes`, the
        lattice before any refinement) cost that each, and the grid's cells
        ``SECONDS_PER_TABLE_CELL``."""
        per_point = SECONDS_PER_CELL + scan_node_count(self.k_sigma, self.sigma_omega, self.t) * SECONDS_PER_NODE
        if self.sigma_heading > 0.0:
            nodes = first_table_nodes(self, *extent.radii(self.pose.origin))
            return nodes * per_point + float(cells) * SECONDS_PER_TABLE_CELL
        return float(cells) * per_point

    def grid_cells(self, grid) -> CellPlan | None:
        r"""Cell probabilities exact in the acceleration (without heading noise; with it, None:
        the engine integrates the convolved density).

        For each turn rate the reachable points form a line along which z = a / sigma_a is
        standard normal (``kernels/cat_cells.py``), so a cell crossed between z_in and z_out
        holds Phi(z_out) - Phi(z_in) of it, exactly, caustic cells included:

        .. math:: P_{ij} = \int g(\omega)\, [\Phi(z_{out}(\omega)) - \Phi(z_{in}(\omega))]\, d\omega.

        Over each of equal omega intervals (:func:`cell_turn_edges`) the lines are interpolated
        linearly between its edge lines (a ribbon narrower than a cell), and the integral over
        omega is taken piecewise between the turn rates whose lines pass a corner of the cell
        (where the share has kinks, and where a line running along a side starts or stops
        crossing), by 3-point Gauss-Legendre with the normal weight. The cells of a grid holding
        all the mass sum to 1 - truncated_mass (|a| <= 9 sigma_a, 2.3e-19 left out) within the
        Gauss rule's error on g, below 1e-12. The remaining error, the ribbons' linear
        interpolation, is second order in the interval, which is kept short enough for it
        (``CELL_CURVE_TOL``): stated as 5e-5 of a cell's probability plus 1e-12, tested over
        the whole parameter domain and at the folds (measured at most 4.3e-6,
        tests/test_cell_probabilities.py).
        """
        if self.sigma_heading > 0.0:
            return None
        edges = cell_turn_edges(self, min(grid.dx, grid.dy))
        intervals = len(edges) - 1
        if intervals > MAX_CELL_NODES:
            raise BananagridError(
                f"{grid.nx} x {grid.ny} cells of {grid.dx:g} x {grid.dy:g} m: the CAT cell probabilities "
                f"need {intervals:,} turn-rate intervals (more than {MAX_CELL_NODES:,}) at cells this small "
                f"for sigma_omega t = {self.sigma_omega * self.t:.3g} rad; use larger cells"
            )
        walked = 2.0 * min(grid.nx + grid.ny, 2.0 * cat_cells.Z_MAX * self.sigma_a * self.t**2
                           * math.sqrt(2.0) / min(grid.dx, grid.dy) + 2.0)
        seconds = intervals * (SECONDS_PER_LINE + walked * SECONDS_PER_LINE_CELL)

        def run(ctx: KernelContext):
            out = ctx.zeros(grid.shape, dtype=np.float64)
            x0, _, y0, _ = grid.extent
            f64 = np.float64
            head = [ctx.array(edges, dtype=f64), f64(self.sigma_omega)]
            scalars = [f64(self.v0), f64(self.t), f64(self.sigma_a)]
            pose = ctx.array(self.pose.as_array(), dtype=f64)
            ctx.load(cat_cells.cat_cells)

            def launch(r0, r1):
                ctx.launch(cat_cells.cat_cells, dim=intervals, inputs=[
                    *head, r0, r1, *scalars, pose, f64(x0), f64(y0), f64(grid.dx), f64(grid.dy), grid.nx, out,
                ])

            ctx.run_bands(launch, ctx.bands(grid.ny, 4))
            notes = {
                "cell_method": "exact in the acceleration, Gauss-Legendre between corner passes over the turn rate",
                "turn_rate_intervals": intervals,
                "truncated_mass": self.truncated_mass,
            }
            return ctx.numpy(out), notes

        return CellPlan(seconds=seconds, run=run, method="CAT lines exact in the acceleration")

    def sample(self, n: int, rng) -> np.ndarray:
        """Draw ``n`` world positions: a and omega from their normal laws, then eq. (1), turned
        by a heading error theta_0 ~ N(0, sigma_heading) when there is one.

        The turn rate is not truncated here (the truncated mass is below 1e-15 by default).
        """
        n, rng = check_n(n), check_rng(rng)
        a = rng.normal(0.0, self.sigma_a, n)
        omega = rng.normal(0.0, self.sigma_omega, n)
        local = cat_position(self.v0, self.t, a, omega)
        if self.sigma_heading > 0.0:
            local = _rotate(local, rng.normal(0.0, self.sigma_heading, n))
        return self.pose.to_world(local)

    def ray_values(self, pose: Pose, radii: np.ndarray, angles: np.ndarray, *, threads=None) -> np.ndarray:
        """p(r, theta) along rays; from the model's own pose with heading noise, exactly by the
        Fourier series of the heading-convolved rows (no table interpolation)."""
        if self.sigma_heading > 0.0 and pose == self.pose:
            return ray_densities(self, radii, angles, threads=threads)
        return super().ray_values(pose, radii, angles, threads=threads)
