r"""Presence laws of Pessentheiner's report: where people are in a room (Sections 6-9, ERRATA).

* :class:`Region` — the target region S, a box: an x range (a line), x and y (a plane), x, y
  and z (a slab of heights, the frustum geometry).
* :class:`GaussianMixture` — ``sum_i w_i N(x; mu_i, Sigma_i)`` in 1, 2 or 3 dimensions with
  full covariances ((7.2), (8.2), (9.3)).
* :class:`UniformPresence` — ``1 / |S|`` on a region S (Sections 7.1, 8.1, 9.1).
* :func:`grid_probabilities` — a planar mixture on a :class:`~bananagrid.Grid`: the density at
  each cell centre and the exact probability of each rectangular cell (bivariate normal
  rectangle probabilities by Genz's BVNU in the kernel).

Cell probabilities on an angular lattice are in :mod:`bananagrid.angular`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr

from .grid import Grid
from .validate import BananagridError, finite

__all__ = [
    "Region", "GaussianMixture", "UniformPresence", "GridPresence", "grid_probabilities",
    "WEIGHT_SUM_TOL", "SYMMETRY_TOL",
]

#: |sum(weights) - 1| allowed (rounding of weights typed with a few digits is the user's job).
WEIGHT_SUM_TOL = 1e-9
#: |Sigma - Sigma^T| allowed, relative to the largest entry.
SYMMETRY_TOL = 1e-12

_AXES = ("x", "y", "z")


def _interval(name: str, value) -> tuple[float, float]:
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise BananagridError(f"{name} = {value!r}: expected a pair (low, high)") from None
    lo, hi = finite(f"{name}[0]", lo), finite(f"{name}[1]", hi)
    if not hi > lo:
        raise BananagridError(
            f"{name} = ({lo!r}, {hi!r}): the region is empty; the upper bound must exceed the lower"
        )
    return lo, hi


@dataclass(frozen=True)
class Region:
    """The target region S: a box with an x range, optionally a y range and a z range.

    Parameters
    ----------
    x : (float, float)
        ``(x0, x1)``, m, x0 < x1.
    y : (float, float), optional
        ``(y0, y1)``, m (a plane or a slab).
    z : (float, float), optional
        ``(z0, z1)``, m, heights in the array frame (z up, the floor at negative z); needs y.

    The dimension (1, 2 or 3) is the number of ranges given; |S| is its length, area or volume.
    """

    x: tuple[float, float]
    y: tuple[float, float] | None = None
    z: tuple[float, float] | None = None

    def __post_init__(self):
        object.__setattr__(self, "x", _interval("region x", self.x))
        if self.y is not None:
            object.__setattr__(self, "y", _interval("region y", self.y))
        if self.z is not None:
            if self.y is None:
                raise BananagridError(f"region z = {self.z!r} given without y: a slab needs x, y and z ranges")
            object.__setattr__(self, "z", _interval("region z", self.z))

    @property
    def dim(self) -> int:
        return 1 if self.y is None else (2 if self.z is None else 3)

    @property
    def bounds(self) -> np.ndarray:
        """``(dim, 2)`` array of (low, high) per axis."""
        return np.array([r for r in (self.x, self.y, self.z) if r is not None], dtype=float)

    @property
    def size(self) -> float:
        """|S|: length, area or volume, in m, m^2 or m^3."""
        b = self.bounds
        return float(np.prod(b[:, 1] - b[:, 0]))

    def contains(self, points) -> np.ndarray:
        """Whether each point (rows of an ``(n, dim)`` array) lies in the closed box."""
        p = np.atleast_2d(np.asarray(points, dtype=float))
        b = self.bounds
        return np.all((p >= b[:, 0]) & (p <= b[:, 1]), axis=1)

    def describe(self) -> dict:
        return {a: list(r) for a, r in zip(_AXES, (self.x, self.y, self.z)) if r is not None}


def _as_region(region) -> Region:
    if isinstance(region, Region):
        return region
    if isinstance(region, dict):
        try:
            return Region(**region)
        except TypeError:
            raise BananagridError(f"region = {region!r}: expected keys x, y, z") from None
    raise BananagridError(f"region = {region!r}: expected a bananagrid Region (or a dict with x, y, z)")


@dataclass(frozen=True, eq=False)
class GaussianMixture:
    r"""Gaussian mixture presence law, ``f(x) = sum_i w_i N(x; mu_i, Sigma_i)`` ((7.2), (8.2),
    (9.3)), in 1, 2 or 3 dimensions.

    Parameters
    ----------
    weights : array_like, shape (M,)
        w_i >= 0, summing to 1 (within ``WEIGHT_SUM_TOL``), at least one positive.
    means : array_like, shape (M, D) (or (M,) for D = 1)
        Component means, m; D is 1 (a line: x), 2 (a plane: x, y) or 3 (x, y, z; z up, the
        floor at negative z).
    covs : array_like, shape (M, D, D) (or (M,) variances for D = 1)
        Symmetric positive-definite covariances, m^2 (full matrices; the frustum lattice takes
        any, the paper's block-diagonal (x, y) | z included).

    Notes
    -----
    The paper factorises Sigma = A A^T by eigendecomposition (8.2.1); the kernels use the
    Cholesky factor L instead (any A with A A^T = Sigma whitens the same way).
    """

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray

    def __post_init__(self):
        w = _finite_array("weights", self.weights)
        if w.ndim != 1 or w.size == 0:
            raise BananagridError(f"weights: expected a non-empty 1-D array, got shape {w.shape}")
        m = _finite_array("means", self.means)
        if m.ndim == 1 and w.size == m.size:
            m = m[:, None]
        if m.ndim != 2 or m.shape[0] != w.size or m.shape[1] not in (1, 2, 3):
            raise BananagridError(
                f"means: expected shape (M, D) with M = {w.size} components and D in 1, 2, 3; got {m.shape}"
            )
        d = m.shape[1]
        c = _finite_array("covs", self.covs)
        if d == 1 and c.shape == (w.size,):
            c = c[:, None, None]
        if c.shape != (w.size, d, d):
            raise BananagridError(f"covs: expected shape ({w.size}, {d}, {d}) to match the means; got {c.shape}")
        if np.any(w < 0.0):
            i = int(np.argmin(w))
            raise BananagridError(f"weights[{i}] = {w[i]!r}: weights must be >= 0")
        total = float(w.sum())
        if abs(total - 1.0) > WEIGHT_SUM_TOL:
            raise BananagridError(
                f"weights = {w.tolist()!r}: they sum to {total!r}, not 1 (allowed error {WEIGHT_SUM_TOL:g}); "
                "divide them by their sum"
            )
        for i in range(w.size):
            ci = c[i]
            scale = float(np.max(np.abs(ci)))
            if np.max(np.abs(ci - ci.T)) > SYMMETRY_TOL * max(scale, 1e-300):
                raise BananagridError(f"covs[{i}] = {ci.tolist()!r}: a covariance must be symmetric")
            eig = np.linalg.eigvalsh(ci)
            if not eig[0] > 0.0 or eig[0] <= 1e-14 * eig[-1]:
                raise BananagridError(
                    f"covs[{i}] = {ci.tolist()!r}: not positive definite (eigenvalues {eig.tolist()!r}); "
                    "every covariance needs positive eigenvalues (condition number below 1e14)"
                )
        for name, value in (("weights", w), ("means", m), ("covs", c)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    # -- description ---------------------------------------------------------------------

    @property
    def dim(self) -> int:
        return self.means.shape[1]

    @property
    def n_components(self) -> int:
        return self.weights.size

    @property
    def block_diagonal(self) -> bool:
        """3-D only: whether every covariance is block diagonal in (x, y) | z (Section 9)."""
        return self.dim == 3 and bool(np.all(self.covs[:, :2, 2] == 0.0))

    def parameters(self) -> dict:
        return {
            "model": "GaussianMixture",
            "weights": self.weights.tolist(),
            "means": self.means.tolist(),
            "covs": self.covs.tolist(),
        }

    # -- law -------------------------------------------------------------------------------

    def pdf(self, points) -> np.ndarray:
        """Density at points, ``(n, D)`` (or ``(n,)`` for D = 1), per m^D (float64 NumPy)."""
        p = _points(points, self.dim)
        out = np.zeros(p.shape[0])
        for w, mu, cov in zip(self.weights, self.means, self.covs):
            chol = np.linalg.cholesky(cov)
            u = np.linalg.solve(chol, (p - mu).T)
            norm = w / ((2.0 * math.pi) ** (self.dim / 2) * np.prod(np.diag(chol)))
            out += norm * np.exp(-0.5 * np.sum(u * u, axis=0))
        return out

    def sample(self, n: int, rng=None) -> np.ndarray:
        """``(n, D)`` positions: a component by weight, then its normal."""
        rng = np.random.default_rng(rng)
        counts = rng.multinomial(int(n), self.weights)
        parts = [rng.multivariate_normal(mu, cov, size=k) for mu, cov, k in zip(self.means, self.covs, counts) if k]
        out = np.concatenate(parts) if parts else np.zeros((0, self.dim))
        return out[rng.permutation(out.shape[0])]

    def region_probability(self, region, *, dtype=np.float64, device: str = "cpu") -> float:
        r"""p(S): the mixture's probability of the box S (ERRATA, end of Section 9).

        1-D: differences of normal CDFs. 2-D: bivariate rectangle probabilities (Genz's BVNU in
        the kernel). 3-D block diagonal: rectangle times interval; otherwise
        ``int N(z) P(rect | z) dz`` by Gauss-Legendre over panels of at most half the z law's
        SD and of the depth change that moves the conditional mean by half its smallest SD.
        """
        region = _as_region(region)
        if region.dim != self.dim:
            raise BananagridError(
                f"region has {region.dim} axes but the mixture has {self.dim}: give x{', y' if self.dim > 1 else ''}"
                f"{', z' if self.dim > 2 else ''} ranges"
            )
        b = region.bounds
        if self.dim == 1:
            sd = np.sqrt(self.covs[:, 0, 0])
            lo, hi = (b[0, 0] - self.means[:, 0]) / sd, (b[0, 1] - self.means[:, 0]) / sd
            return float(np.sum(self.weights * _interval_probability(lo, hi)))
        if self.dim == 2:
            lims = _standard_rectangles(self.means, self.covs, b[0], b[1])
            return float(np.sum(self.weights * rectangle_probabilities(lims, dtype=dtype, device=device)))
        total = 0.0
        for w, mu, cov in zip(self.weights, self.means, self.covs):
            szz = cov[2, 2]
            sz = math.sqrt(szz)
            g = cov[:2, 2] / szz
            cond = cov[:2, :2] - np.outer(cov[:2, 2], cov[:2, 2]) / szz
            if not np.any(g):
                rect = rectangle_probabilities(_standard_rectangles(mu[None, :2], cov[None, :2, :2], b[0], b[1]),
                                               dtype=dtype, device=device)[0]
                total += w * rect * float(_interval_probability((b[2, 0] - mu[2]) / sz, (b[2, 1] - mu[2]) / sz))
                continue
            z0, z1 = max(b[2, 0], mu[2] - 40.0 * sz), min(b[2, 1], mu[2] + 40.0 * sz)
            if not z1 > z0:
                continue
            smin = math.sqrt(np.linalg.eigvalsh(cond)[0])
            step = 0.5 * min(sz, smin / float(np.max(np.abs(g))))
            panels = int(min(20000, max(1, math.ceil((z1 - z0) / step))))
            x, wts = np.polynomial.legendre.leggauss(12)
            edges = np.linspace(z0, z1, panels + 1)
            half = 0.5 * np.diff(edges)
            z = (0.5 * (edges[:-1] + edges[1:]))[:, None] + half[:, None] * x[None, :]
            wz = (half[:, None] * wts[None, :]).ravel()
            z = z.ravel()
            means = mu[:2][None, :] + np.outer(z - mu[2], g)
            covs = np.broadcast_to(cond, (z.size, 2, 2))
            rect = rectangle_probabilities(_standard_rectangles(means, covs, b[0], b[1]), dtype=dtype, device=device)
            gz = np.exp(-0.5 * ((z - mu[2]) / sz) ** 2) / (math.sqrt(2.0 * math.pi) * sz)
            total += w * float(np.sum(wz * gz * rect))
        return float(total)


def _finite_array(name: str, value) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise BananagridError(f"{name} = {value!r}: expected numbers") from None
    if not np.all(np.isfinite(a)):
        raise BananagridError(f"{name}: every entry must be finite (NaN or inf given)")
    return a


def _points(points, dim: int) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if dim == 1 and p.ndim <= 1:
        p = p.reshape(-1, 1)
    if p.ndim == 1 and p.size == dim:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != dim:
        raise BananagridError(f"points: expected shape (n, {dim}); got {np.shape(points)}")
    return p


def _interval_probability(lo, hi) -> np.ndarray:
    """Phi(hi) - Phi(lo), from the tail away from zero (no cancellation near one)."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    upper = lo >= 0.0
    return np.where(upper, ndtr(-lo) - ndtr(-hi), ndtr(hi) - ndtr(lo))


def _standard_rectangles(means, covs, xb, yb) -> np.ndarray:
    """Rows (x0, x1, y0, y1, r) of standardised rectangle limits for each (mean, cov)."""
    sx = np.sqrt(covs[:, 0, 0])
    sy = np.sqrt(covs[:, 1, 1])
    r = covs[:, 0, 1] / (sx * sy)
    return np.stack([(xb[0] - means[:, 0]) / sx, (xb[1] - means[:, 0]) / sx,
                     (yb[0] - means[:, 1]) / sy, (yb[1] - means[:, 1]) / sy, r], axis=1)


@dataclass(frozen=True)
class UniformPresence:
    """Uniform presence on a region S: density ``1 / |S|`` inside the box, 0 outside (Sections
    7.1, 8.1, 9.1 with C_Sigma = |S|).

    Parameters
    ----------
    region : Region
        The box; its dimension is the law's.
    """

    region: Region

    def __post_init__(self):
        object.__setattr__(self, "region", _as_region(self.region))

    @property
    def dim(self) -> int:
        return self.region.dim

    def parameters(self) -> dict:
        return {"model": "UniformPresence", "region": self.region.describe()}

    def pdf(self, points) -> np.ndarray:
        p = _points(points, self.dim)
        return np.where(self.region.contains(p), 1.0 / self.region.size, 0.0)

    def sample(self, n: int, rng=None) -> np.ndarray:
        rng = np.random.default_rng(rng)
        b = self.region.bounds
        return b[:, 0] + (b[:, 1] - b[:, 0]) * rng.random((int(n), self.dim))

    def region_probability(self, region, **_) -> float:
        """p(S') = |S' and S| / |S|."""
        other = _as_region(region)
        if other.dim != self.dim:
            raise BananagridError(f"region has {other.dim} axes but the law has {self.dim}")
        a, b = self.region.bounds, other.bounds
        overlap = np.clip(np.minimum(a[:, 1], b[:, 1]) - np.maximum(a[:, 0], b[:, 0]), 0.0, None)
        return float(np.prod(overlap) / self.region.size)


# --------------------------------------------------------------------------------------------
# Kernel plumbing
# --------------------------------------------------------------------------------------------


def _gk_rule() -> np.ndarray:
    """Rows: Gauss-Kronrod 15 nodes on [-1, 1], Kronrod weights, embedded Gauss-7 weights
    (QUADPACK qk15)."""
    xk = [0.991455371120812639206854697526329, 0.949107912342758524526189684047851,
          0.864864423359769072789712788640926, 0.741531185599394439863864773280788,
          0.586087235467691130294144845693013, 0.405845151377397166906606412076961,
          0.207784955007898467600689403773245, 0.0]
    wk = [0.022935322010529224963732008058970, 0.063092092629978553290700663189204,
          0.104790010322250183839876322541518, 0.140653259715525918745189590510238,
          0.169004726639267902826583426598550, 0.190350578064785409913256402421014,
          0.204432940075298892414161999234649, 0.209482141084727828012999174891714]
    wg = [0.129484966168869693270611432679082, 0.279705391489276667901467771423780,
          0.381830050505118944950369775488975, 0.417959183673469387755102040816327]
    x = np.array([-v for v in xk[:7]] + [0.0] + xk[6::-1])
    kw = np.array(wk[:7] + [wk[7]] + wk[6::-1])
    gw = np.zeros(15)
    gw[1::2] = wg[:3] + [wg[3]] + wg[2::-1]
    return np.stack([x, kw, gw])


def _gl8() -> np.ndarray:
    x, w = np.polynomial.legendre.leggauss(8)
    return np.stack([x, w])


def _bvn_rule() -> np.ndarray:
    """Rows (nodes, weights) of the 6-, 12- and 20-point Gauss-Legendre rules, zero-padded."""
    out = np.zeros((6, 20))
    for row, n in enumerate((6, 12, 20)):
        x, w = np.polynomial.legendre.leggauss(n)
        out[2 * row, :n], out[2 * row + 1, :n] = x, w
    return out


def rectangle_probabilities(lims, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
    """P(l0 < X < l1, l2 < Y < l3) for standard normals of correlation l4, per row of the
    ``(n, 5)`` array ``lims`` (Genz's BVNU in the kernel), computed in float64 for either
    ``dtype`` (the four orthant terms cancel on small rectangles) and returned in ``dtype``."""
    from .kernels import presence as kp
    from .raster import _check_device, _scalar

    lims = np.ascontiguousarray(lims, dtype=float)
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    if lims.shape[0] == 0:
        return np.zeros(0, dtype=np_dtype)
    lims = np.clip(lims, -1e30, 1e30)  # +-inf limits as far-out finite ones (Q underflows to 0)
    out = wp.zeros(lims.shape[0], dtype=scalar, device=device)
    wp.launch(kp.rectangles, dim=lims.shape[0], inputs=[
        wp.array(lims, dtype=wp.float64, device=device), wp.array(_bvn_rule(), dtype=wp.float64, device=device), out,
    ], device=device)
    wp.synchronize_device(device)
    return out.numpy()


@dataclass(frozen=True)
class GridPresence:
    """A planar Gaussian mixture on a :class:`~bananagrid.Grid`.

    Attributes
    ----------
    density : ndarray, shape (ny, nx)
        Density per m^2 at each cell centre (rows south to north).
    probability : ndarray, shape (ny, nx)
        Exact probability of each rectangular cell (bivariate normal rectangle probabilities).
    grid : Grid
    mass : float
        ``sum(probability)``: the mixture's probability of the grid's extent.
    provenance : dict
    """

    density: np.ndarray
    probability: np.ndarray
    grid: Grid
    mass: float
    provenance: dict = field(default_factory=dict)


def grid_probabilities(mixture: GaussianMixture, grid: Grid, *, dtype=np.float64, device: str = "cpu",
                       threads=None) -> GridPresence:
    r"""A 2-D mixture's density at the cell centres of ``grid`` and each cell's exact probability.

    .. math::

        P_{ij} = \sum_c w_c\, \Pr(x_j^- < X < x_j^+,\ y_i^- < Y < y_i^+ \mid c),

    each rectangle by inclusion and exclusion of four upper-orthant probabilities of Genz's
    BVNU (Drezner & Wesolowsky with Genz's double-precision changes; accurate to about 1e-15
    absolute), with each axis reflected so that the orthants are tail values. A 3-D mixture
    is taken by its (x, y) marginal.

    Parameters
    ----------
    mixture : GaussianMixture
        A 2-D or 3-D mixture.
    grid : Grid
    dtype : {np.float64, np.float32}
        dtype of the returned arrays. The four orthant terms cancel (a small cell is a tiny
        difference of nearly equal orthant probabilities), so the kernel computes every cell in
        float64 from float64 edges either way; float32 is that result rounded once (within
        2^-24 = 6e-8 relative of float64 down to float32's normal range, 1.2e-38; below it the
        absolute error is under 1e-45). It saves memory, not time.
    device : str
        ``"cpu"`` or ``"cuda"``.
    threads : int, optional
        CPU threads (bands of rows); default all cores.

    Raises
    ------
    BananagridError
        For a 1-D mixture, anything but a Grid, or a bad dtype, device or thread count.
    """
    from .kernels import presence as kp
    from .raster import _bands, _check_device, _check_threads, _run_bands, _scalar

    if not isinstance(mixture, GaussianMixture):
        raise BananagridError(f"mixture = {mixture!r}: expected a bananagrid GaussianMixture")
    if mixture.dim == 1:
        raise BananagridError("mixture: a 1-D (line) mixture has no density on a planar grid; give 2-D means")
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid.Grid")
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    threads = _check_threads(threads)
    start = time.perf_counter()
    rows = []
    for w, mu, cov in zip(mixture.weights, mixture.means[:, :2], mixture.covs[:, :2, :2]):
        chol = np.linalg.cholesky(cov)
        b = np.linalg.inv(chol)
        sx, sy = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
        rows.append([w, mu[0], mu[1], sx, sy, cov[0, 1] / (sx * sy), b[0, 0], b[1, 0], b[1, 1],
                     w / (2.0 * math.pi * chol[0, 0] * chol[1, 1])])
    # inputs are float64 for either dtype: float32 edges alone would cost ulp(x) / dx of a
    # cell's width, and the orthant differences cancel (see kernels.presence.grid_cells)
    comp = wp.array(np.array(rows, dtype=np.float64), dtype=wp.float64, device=device)
    x0, x1, y0, y1 = grid.extent
    xe = wp.array(x0 + grid.dx * np.arange(grid.nx + 1), dtype=wp.float64, device=device)
    ye = wp.array(y0 + grid.dy * np.arange(grid.ny + 1), dtype=wp.float64, device=device)
    rule = wp.array(_bvn_rule(), dtype=wp.float64, device=device)
    density = wp.zeros(grid.shape, dtype=scalar, device=device)
    prob = wp.zeros(grid.shape, dtype=scalar, device=device)
    wp.load_module(kp.grid_cells.module, device=device)

    def launch(r0, r1):
        wp.launch(kp.grid_cells, dim=r1 - r0, inputs=[xe, ye, r0, comp, len(rows), rule, density, prob], device=device)

    bands = _bands(grid.ny, threads, 4) if device == "cpu" else [(0, grid.ny)]
    _run_bands(launch, bands, threads if device == "cpu" else 1)
    wp.synchronize_device(device)
    p = prob.numpy()
    return GridPresence(
        density=density.numpy(), probability=p, grid=grid, mass=float(np.sum(p, dtype=np.float64)),
        provenance={**mixture.parameters(), "kernel": "presence.grid_cells", "dtype": np_dtype.name,
                    "device": device, "threads": threads, "seconds": time.perf_counter() - start},
    )
