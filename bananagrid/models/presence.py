r"""Presence laws of Pessentheiner's report: where people are in a room (Sections 6-9, ERRATA).

* :class:`GaussianMixture` — ``sum_i w_i N(x; mu_i, Sigma_i)`` in 1, 2 or 3 dimensions with
  full covariances ((7.2), (8.2), (9.3)).
* :class:`UniformPresence` — ``1 / |S|`` on a region S (Sections 7.1, 8.1, 9.1).
* :func:`grid_probabilities` — a planar mixture on a :class:`~bananagrid.Grid`: the density at
  each cell centre and the exact probability of each rectangular cell (bivariate normal
  rectangle probabilities by Genz's BVNU in the kernel).

* :func:`cell_probabilities` — the presence probability of every cell of an
  :class:`~bananagrid.AngularLattice`, conditional on a region S (a
  :class:`~bananagrid.Region`).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from scipy.special import ndtr

from ..domains.angular_lattice import (
    AngularLattice, box_far, cell_breakpoints, cell_pieces, classify_cells, clipped_cells,
)
from ..domains.grid import Grid
from ..domains.region import Region, as_region
from ..engine.warp_runtime import WarpContext, check_threads
from ..kernels import presence as kp
from ..results import CellMap, GridPresence
from ..protocol import CellPlan, SceneKey, SceneSchema
from ..validate import MAX_CONDITION, BananagridError, covariance, positive, real_array, show, unknown_key
from .base import check_n, check_rng
from .params import modelclass, param, plain_parameters

__all__ = [
    "GaussianMixture", "UniformPresence", "cell_probabilities", "grid_probabilities", "rectangle_probabilities",
    "WEIGHT_SUM_TOL", "RTOL", "ATOL", "FLOAT32_RTOL", "MAX_PANELS", "RECTANGLE_ABS_ERROR", "clip_rounding",
    "AXES", "COMPONENT_KEYS", "COVARIANCE_KEYS", "SD_KEYS", "MAX_LENGTH", "MIN_LENGTH",
]

#: |sum(weights) - 1| allowed (rounding of weights typed with a few digits is the user's job).
WEIGHT_SUM_TOL = 1e-9
#: Default relative tolerance of each component's cell integral (|K15 - G7| <= RTOL |K15| + ATOL).
RTOL = 1e-7
#: The tolerance a float32 run uses at least: its cells agree with float64 to about 4e-5 relative
#: (tests/models/test_presence.py), the precision float32 gives; the 1e-6 guarantee is float64's.
FLOAT32_RTOL = 1e-5
#: Absolute tolerance of a component's cell integral, as a fraction of p(S) (the conditioning
#: mass): far below the 1e-9 cell mass that the 1e-6 relative guarantee covers.
ATOL = 1e-17
#: Most Gauss-Kronrod panels per piece and axis.
MAX_PANELS = 4096

def _finite_array(name: str, value) -> np.ndarray:
    a = real_array(name, value)
    if not np.all(np.isfinite(a)):
        raise BananagridError(f"{name}: every entry must be finite (NaN or inf given)")
    return a


_finite_array.domain = "finite"


def _mixture_weights(name: str, value) -> np.ndarray:
    """The weights of a mixture: a non-empty 1-D array, each >= 0, summing to 1."""
    w = _finite_array(name, value)
    if w.ndim != 1 or w.size == 0:
        raise BananagridError(f"{name}: expected a non-empty 1-D array, got shape {w.shape}")
    if np.any(w < 0.0):
        i = int(np.argmin(w))
        raise BananagridError(f"{name}[{i}] = {w[i]!r}: weights must be >= 0")
    total = float(w.sum())
    if abs(total - 1.0) > WEIGHT_SUM_TOL:
        raise BananagridError(
            f"{name} = {w.tolist()!r}: they sum to {total!r}, not 1 (allowed error {WEIGHT_SUM_TOL:g}); "
            "divide them by their sum"
        )
    return w


_mixture_weights.domain = f"each >= 0, summing to 1 (within {WEIGHT_SUM_TOL:g})"


def _listed(name: str):
    """``plain`` of an array parameter: ``{name: nested lists}``."""
    return lambda model, value: {name: value.tolist()}


#: Axes of a presence law by its dimension (the array frame: x, y horizontal, z up).
AXES = ("x", "y", "z")

#: The keys of a mixture component's table, ``[presence.components.NAME]`` of an ``[array]``
#: scene (``axes``: the law's, by its lattice's geometry; ``sd_x`` .. ``rho`` set the covariance).
COMPONENT_KEYS = (
    SceneKey("weight", default="required", allowed=f"in [0, 1]; the weights sum to 1 within {WEIGHT_SUM_TOL:g}"),
    SceneKey("mean", type="numbers", unit="m",
             allowed="one number per axis (the line: a number or `[x]`), each within +-1e150"),
)
COVARIANCE_KEYS = (
    SceneKey("cov", type="matrix", unit="m^2", default="instead of the SDs",
             allowed="D x D, symmetric positive definite, variances in [1e-300, 1e300]"),
)
SD_KEYS = (
    SceneKey("sd_x", unit="m", default="required unless `cov`", allowed="in [1e-150, 1e150]"),
    SceneKey("sd_y", unit="m", default="required unless `cov` (plane, frustum)", allowed="in [1e-150, 1e150]"),
    SceneKey("sd_z", unit="m", default="required unless `cov` (frustum)", allowed="in [1e-150, 1e150]"),
    SceneKey("rho", default="`0`", allowed="plane and frustum, with the SDs: the x-y correlation, in (-1, 1)"),
)


@modelclass(eq=False)
class GaussianMixture:
    r"""Gaussian mixture presence law, ``f(x) = sum_i w_i N(x; mu_i, Sigma_i)`` ((7.2), (8.2),
    (9.3)), in 1, 2 or 3 dimensions.

    Notes
    -----
    The paper factorises Sigma = A A^T by eigendecomposition (8.2.1); the kernels use the
    Cholesky factor L instead (any A with A A^T = Sigma whitens the same way).
    """

    weights: np.ndarray = param(
        py="array_like, shape (M,)", scene=COMPONENT_KEYS[:1], check=_mixture_weights, plain=_listed("weights"),
        doc="Component weights w_i; a scene gives one ``weight`` per ``[presence.components.NAME]`` table.")
    means: np.ndarray = param(
        py="array_like, shape (M, D) (or (M,) for D = 1)", unit="m", scene=COMPONENT_KEYS[1:], check=_finite_array,
        domain="finite, shape (M, D) with D in 1, 2, 3", plain=_listed("means"),
        doc="Component means; D is 1 (a line: x), 2 (a plane: x, y) or 3 (x, y, z; z up, the floor at "
            "negative z).")
    covs: np.ndarray = param(
        py="array_like, shape (M, D, D) (or (M,) variances for D = 1)", unit="m^2", scene=COVARIANCE_KEYS,
        also=SD_KEYS, check=_finite_array, plain=_listed("covs"),
        domain=f"each {covariance.domain}, condition number below {MAX_CONDITION:g} (in 3-D of its correlation "
               "matrix)",
        doc="Component covariances (full matrices; the frustum lattice takes any, the paper's block-diagonal "
            "(x, y) | z included).")

    #: Its registry name: ``presence.kind = "mixture"`` of an ``[array]`` scene.
    kind: ClassVar[str] = "mixture"
    #: Its scene keys: those of each ``[presence.components.NAME]`` table (:meth:`scene_table`
    #: turns their ``mean``, ``cov`` or SDs into these parameters).
    scene: ClassVar[SceneSchema] = SceneSchema(
        summary="a Gaussian mixture of heads in the room, one [presence.components.NAME] table a component",
    )
    #: Stated agreement of float32 cells with float64 (relative, cells holding 1e-9 of the mass):
    #: a float32 run uses the tolerance FLOAT32_RTOL and agrees to 4e-5 (tests/models/test_presence.py).
    float32_rtol: ClassVar[float] = 2e-4

    #: Peak bytes per sample of :meth:`sample`: 56 (2-D) and 80 (3-D) measured (tracemalloc,
    #: ``sample(10**6)``), rounded up.
    sample_bytes: ClassVar[float] = 128

    def __post_init__(self):
        """The rules between the parameters: the means' and covariances' shapes match the
        weights, and each covariance is one (:func:`bananagrid.validate.covariance`)."""
        w, m, c = self.weights, self.means, self.covs
        if m.ndim == 1 and w.size == m.size:
            m = m[:, None]
        if m.ndim != 2 or m.shape[0] != w.size or m.shape[1] not in (1, 2, 3):
            raise BananagridError(
                f"means: expected shape (M, D) with M = {w.size} components and D in 1, 2, 3; got {m.shape}"
            )
        d = m.shape[1]
        if d == 1 and c.shape == (w.size,):
            c = c[:, None, None]
        if c.shape != (w.size, d, d):
            raise BananagridError(f"covs: expected shape ({w.size}, {d}, {d}) to match the means; got {c.shape}")
        c = np.stack([covariance(f"covs[{i}]", c[i], dim=d) for i in range(w.size)])
        for name, value in (("weights", w), ("means", m), ("covs", c)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @classmethod
    def scene_table(cls, table: Mapping, *, path: str, lattice: AngularLattice, room: Region | None):
        """The parameters of a scene's presence table (``table``, whose ``kind`` names this law;
        ``path``: its key path) on ``lattice``: one ``[PATH.components.NAME]`` table a component, with
        ``weight``, ``mean`` and ``cov`` or the SDs (``sd_x``, ``sd_y``, ``rho``, ``sd_z``) on the
        law's axes.

        Returns
        -------
        params : dict
            ``weights``, ``means``, ``covs`` (lists, m and m^2).
        names : tuple of str
            The components' names, in the table's order.

        Raises
        ------
        BananagridError
            ``KEY.PATH = value: what is allowed`` for the first key that breaks a rule.
        """
        _check_keys(table, ("kind", "components"), path)
        components = table.get("components")
        if not isinstance(components, dict) or not components:
            raise BananagridError(f"{path}.components: a mixture needs at least one [{path}.components.NAME] table")
        axes = AXES[:_GEOMETRY_DIM[lattice.geometry]]
        names, weights, means, covs = [], [], [], []
        for name, body in components.items():
            where = f"{path}.components.{name}"
            if not isinstance(name, str) or not _NAME.fullmatch(name):
                raise BananagridError(f"{where} = {show(name)}: expected a component name of letters, digits, _ and -")
            if not isinstance(body, dict):
                raise BananagridError(f"{where} = {show(body)}: expected a table [{where}]")
            w, mu, cov = _component(body, where, axes, lattice.geometry)
            names.append(name)
            weights.append(w)
            means.append(mu)
            covs.append(cov)
        total = math.fsum(weights)
        if abs(total - 1.0) > WEIGHT_SUM_TOL:
            listed = ", ".join(f"{n} = {show(float(w))}" for n, w in zip(names, weights))
            raise BananagridError(
                f"{path}.components: the weights ({listed}) sum to {total!r}, not 1 "
                f"(allowed error {WEIGHT_SUM_TOL:g}); divide them by their sum"
            )
        return {"weights": weights, "means": means, "covs": covs}, tuple(names)

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
        """Plain-data parameters for provenance and recordings (the declared ``plain`` entries)."""
        return plain_parameters(self)

    # -- law -------------------------------------------------------------------------------

    def pdf(self, x, y=None, z=None, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
        """Density at points, per m^D, computed in float64 NumPy and returned in ``dtype``
        (``device`` is accepted for the protocol; the law needs no kernel).

        The protocol form gives coordinates, broadcast: ``pdf(x)`` (1-D), ``pdf(x, y)`` (2-D; for
        a 3-D mixture its (x, y) marginal, per m^2, the density the grid functions use) and
        ``pdf(x, y, z)`` (3-D), each returning the broadcast shape. As a convenience ``pdf(points)``
        takes one ``(n, D)`` array (``(n,)`` for D = 1) and returns ``(n,)``.
        """
        return _law_values(self, _coordinates(x, y, z, self.dim), self._density, dtype)

    def _density(self, p: np.ndarray) -> np.ndarray:
        """Density at points ``(n, d)`` of the law's first d axes (d = D, or 2 for the marginal)."""
        d = p.shape[1]
        out = np.zeros(p.shape[0])
        for w, mu, cov in zip(self.weights, self.means[:, :d], self.covs[:, :d, :d]):
            chol = np.linalg.cholesky(cov)
            with np.errstate(over="ignore", invalid="ignore"):
                diff = p - mu  # inf where a point and a mean near +-1.8e308 lie apart: no density there
                far = ~np.all(np.isfinite(diff), axis=1)
                u = np.linalg.solve(chol, np.where(far[:, None], 0.0, diff).T)
                q = np.sum(u * u, axis=0)
                # beyond ~1e154 SDs u * u overflows, and an overflowing forward substitution can
                # give inf - inf: either way the point is that far out, where exp gives 0
                q = np.where(np.isfinite(q), q, np.inf)
            norm = w / ((2.0 * math.pi) ** (d / 2) * np.prod(np.diag(chol)))
            out += np.where(far, 0.0, norm * np.exp(-0.5 * q))
        return out

    def sample(self, n: int, rng) -> np.ndarray:
        """``(n, D)`` positions: a component by weight, then its normal (``rng``: a NumPy
        Generator or an integer seed)."""
        n = check_n(n, self.sample_bytes)
        rng = check_rng(rng)
        counts = rng.multinomial(n, self.weights)
        parts = [rng.multivariate_normal(mu, cov, size=k) for mu, cov, k in zip(self.means, self.covs, counts) if k]
        out = np.concatenate(parts) if parts else np.zeros((0, self.dim))
        return out[rng.permutation(out.shape[0])]

    def cell_plan(self, domain, region=None) -> CellPlan:
        """The law's own cells of a domain: p(C | S) of every cell of an
        :class:`~bananagrid.AngularLattice` (:func:`cell_probabilities`), the plan
        :func:`bananagrid.rasterise` runs for such a lattice (:func:`lattice_cell_plan`)."""
        return lattice_cell_plan(self, domain, region)

    def region_probability(self, region, *, dtype=np.float64, device: str = "cpu") -> float:
        r"""p(S): the mixture's probability of the box S (ERRATA, end of Section 9).

        1-D: differences of normal CDFs. 2-D: bivariate rectangle probabilities (Genz's BVNU in
        the kernel). 3-D block diagonal: rectangle times interval; otherwise
        ``int N(z) P(rect | z) dz`` by Gauss-Legendre over panels of at most half the z law's
        SD and of the depth change that moves the conditional mean by half its smallest SD.
        """
        region = as_region(region)
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


def _points(points, dim: int) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if dim == 1 and p.ndim <= 1:
        p = p.reshape(-1, 1)
    if p.ndim == 1 and p.size == dim:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != dim:
        raise BananagridError(f"points: expected shape (n, {dim}); got {np.shape(points)}")
    return p


def _coordinates(x, y, z, dim: int):
    """``(points (n, d), shape of the result)`` from a pdf call: the coordinates ``x``, ``y``,
    ``z`` broadcast (d of them), or the convenience form ``pdf(points)``."""
    if y is None and z is None:
        if dim == 1:  # pdf(x): the protocol form and the points form agree
            x = np.asarray(x, dtype=float)
            if x.ndim == 2 and x.shape[1] == 1:
                x = x[:, 0]
            return x.reshape(-1, 1), x.shape
        p = _points(x, dim)
        return p, (p.shape[0],)
    if y is None:
        raise BananagridError("pdf: z given without y; call pdf(x, y, z)")
    if dim == 1:
        raise BananagridError(f"pdf: a 1-D (line) law takes x only; got y{' and z' if z is not None else ''}")
    if z is not None and dim == 2:
        raise BananagridError("pdf: a 2-D (plane) law takes x and y; got z")
    axes = [x, y] if z is None else [x, y, z]
    try:
        arrays = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in axes))
    except ValueError:
        raise BananagridError(f"pdf: x, y{', z' if z is not None else ''} do not broadcast "
                              f"(shapes {', '.join(str(np.shape(a)) for a in axes)})") from None
    return np.stack([a.ravel() for a in arrays], axis=1), arrays[0].shape


def _law_values(law, located, density, dtype) -> np.ndarray:
    """``density(points)`` reshaped to the call's shape and cast to ``dtype``."""
    points, shape = located
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise BananagridError(f"dtype = {dtype}: expected float32 or float64")
    return density(points).reshape(shape).astype(dtype, copy=False)


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


@modelclass
class UniformPresence:
    """Uniform presence on a region S: density ``1 / |S|`` inside the box, 0 outside (Sections
    7.1, 8.1, 9.1 with C_Sigma = |S|)."""

    region: Region = param(
        py="Region", unit="m", scene=(), check=lambda name, value: as_region(value),
        domain="a bananagrid Region (or a mapping of its axes' ranges), not empty",
        plain=lambda model, region: {"region": region.describe()},
        doc="The box; its dimension is the law's. A scene gives no key for it: the law is uniform on the "
            "scene's ``[room]``.")

    #: Its registry name: ``presence.kind = "uniform"`` of an ``[array]`` scene.
    kind: ClassVar[str] = "uniform"
    #: Its scene keys: none of its own; the region is the scene's ``[room]`` (:meth:`scene_table`).
    scene: ClassVar[SceneSchema] = SceneSchema(summary="presence uniform on the scene's [room]")
    #: Stated agreement of float32 with float64: exact geometry, computed in float64 either way.
    float32_rtol: ClassVar[float] = 0.0

    #: Peak bytes per sample of :meth:`sample`: 48 measured (3-D; tracemalloc, ``sample(10**6)``), rounded up.
    sample_bytes: ClassVar[float] = 64

    @classmethod
    def scene_table(cls, table: Mapping, *, path: str, lattice: AngularLattice, room: Region | None):
        """The parameters of a scene's presence table (``table``, whose ``kind`` names this law), as
        :meth:`GaussianMixture.scene_table`: the law has no keys of its own and is uniform on
        the scene's room (``room``, required), with no components."""
        if "components" in table:
            raise BananagridError(f"{path}.components: a uniform law has no components (kind = \"{cls.kind}\")")
        _check_keys(table, ("kind",), path)
        if room is None:
            raise BananagridError(f"[room]: missing table; a uniform law ({path}.kind = \"{cls.kind}\") is uniform "
                                  "on the room")
        return {"region": room}, ()

    @property
    def dim(self) -> int:
        return self.region.dim

    def parameters(self) -> dict:
        """Plain-data parameters for provenance and recordings (the declared ``plain`` entries)."""
        return plain_parameters(self)

    def pdf(self, x, y=None, z=None, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
        """``1 / |S|`` inside the box, 0 outside, per m^D; called as :meth:`GaussianMixture.pdf`
        (``pdf(x, y)`` of a 3-D law: its (x, y) marginal, ``z_extent / |S|`` over the floor plan)."""
        return _law_values(self, _coordinates(x, y, z, self.dim), self._density, dtype)

    def _density(self, p: np.ndarray) -> np.ndarray:
        d = p.shape[1]
        b = self.region.bounds[:d]
        inside = np.all((p >= b[:, 0]) & (p <= b[:, 1]), axis=1)
        size = self.region.size if d == self.dim else float(np.prod(b[:, 1] - b[:, 0]))
        return np.where(inside, 1.0 / size, 0.0)

    def sample(self, n: int, rng) -> np.ndarray:
        """``(n, D)`` positions uniform in the box (``rng``: a NumPy Generator or an integer seed)."""
        n = check_n(n, self.sample_bytes)
        rng = check_rng(rng)
        b = self.region.bounds
        return b[:, 0] + (b[:, 1] - b[:, 0]) * rng.random((n, self.dim))

    def cell_plan(self, domain, region=None) -> CellPlan:
        """Its cells of an :class:`~bananagrid.AngularLattice` (:func:`cell_probabilities`), as
        :meth:`GaussianMixture.cell_plan`."""
        return lattice_cell_plan(self, domain, region)

    def region_probability(self, region, **_) -> float:
        """p(S') = |S' and S| / |S|."""
        other = as_region(region)
        if other.dim != self.dim:
            raise BananagridError(f"region has {other.dim} axes but the law has {self.dim}")
        a, b = self.region.bounds, other.bounds
        overlap = np.clip(np.minimum(a[:, 1], b[:, 1]) - np.maximum(a[:, 0], b[:, 0]), 0.0, None)
        return float(np.prod(overlap) / self.region.size)


# --------------------------------------------------------------------------------------------
# Scene tables (the keys of a presence law in an [array] scene)
# --------------------------------------------------------------------------------------------

#: The law's dimension on each lattice geometry.
_GEOMETRY_DIM = {"line": 1, "plane": 2, "frustum": 3}
#: Names of components: they become entity names of the recording.
_NAME = re.compile(r"[A-Za-z0-9_-]+")
#: Positions and spreads of a room, in metres, stay within these magnitudes, so that their
#: squares and ratios (standardised room bounds) are normal float64 numbers.
MAX_LENGTH = 1e150
MIN_LENGTH = 1e-150


def _check_keys(table: Mapping, allowed, path: str, note: str = "") -> None:
    """Refuse keys outside ``allowed``, naming the key path."""
    for key in table:
        if key not in allowed:
            raise BananagridError(unknown_key(f"{path}.{key}", key, allowed, note))


def _number(value, path: str) -> float:
    """A TOML integer or float as float (booleans and strings are refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BananagridError(f"{path} = {show(value)}: expected a number")
    return float(value)


def _finite(value, path: str) -> float:
    number = _number(value, path)
    if not math.isfinite(number):
        raise BananagridError(f"{path} = {show(value)}: must be finite")
    return number


def _length(value, path: str) -> float:
    """A position in metres: finite, |value| <= MAX_LENGTH."""
    number = _finite(value, path)
    if not abs(number) <= MAX_LENGTH:
        raise BananagridError(f"{path} = {show(value)}: must be within +-{MAX_LENGTH:g} m")
    return number


def _component(body: Mapping, path: str, axes, geometry: str):
    """One component table: (weight, mean (D,), cov (D, D)), checked key by key."""
    d = len(axes)
    allowed = [key.name for key in (*COMPONENT_KEYS, *COVARIANCE_KEYS)]
    allowed += [key.name for key in SD_KEYS if key.name[3:] in axes or (key.name == "rho" and d > 1)]
    _check_keys(body, allowed, path, note=f" (geometry {show(geometry)}: axes {', '.join(axes)})")
    if "weight" not in body:
        raise BananagridError(f"{path}.weight: missing; a number in [0, 1]")
    w = _number(body["weight"], f"{path}.weight")
    if not (math.isfinite(w) and 0.0 <= w <= 1.0):
        raise BananagridError(f"{path}.weight = {show(body['weight'])}: must be in [0, 1]")
    if "mean" not in body:
        raise BananagridError(f"{path}.mean: missing; [{', '.join(axes)}] in m")
    value = body["mean"]
    if d == 1 and not isinstance(value, list):
        value = [value]
    if not isinstance(value, list) or len(value) != d:
        raise BananagridError(f"{path}.mean = {show(body['mean'])}: expected [{', '.join(axes)}] in m ({d} number(s))")
    mean = [_length(v, f"{path}.mean[{k}]") for k, v in enumerate(value)]
    sd_keys = [k for k in body if k.startswith("sd_") or k == "rho"]
    if "cov" in body:
        if sd_keys:
            raise BananagridError(f"{path}: give cov or {', '.join(f'sd_{a}' for a in axes)}{', rho' if d > 1 else ''}, "
                                  f"not both ({', '.join(sd_keys)} given with cov)")
        value = body["cov"]
        rows = value if isinstance(value, list) else None
        if rows is None or len(rows) != d or any(not isinstance(r, list) or len(r) != d for r in rows):
            raise BananagridError(f"{path}.cov = {show(value)}: expected a {d} x {d} list of lists in m^2")
        cov = [[_finite(v, f"{path}.cov[{i}][{j}]") for j, v in enumerate(r)] for i, r in enumerate(rows)]
        for i in range(d):
            if not MIN_LENGTH**2 <= cov[i][i] <= MAX_LENGTH**2:
                raise BananagridError(f"{path}.cov[{i}][{i}] = {show(rows[i][i])}: a variance must be in "
                                      f"[{MIN_LENGTH**2:g}, {MAX_LENGTH**2:g}] m^2")
        covariance(f"{path}.cov", cov, dim=d)  # the model's own check, named by the key
        return w, mean, cov
    missing = [f"sd_{a}" for a in axes if f"sd_{a}" not in body]
    if missing:
        raise BananagridError(f"{path}: missing {', '.join(missing)}; give cov ({d} x {d}, m^2) or the SDs "
                              f"{', '.join(f'sd_{a}' for a in axes)} (m){' and rho' if d > 1 else ''}")
    sds = []
    for a in axes:
        sd = _finite(body[f"sd_{a}"], f"{path}.sd_{a}")
        if not sd > 0.0:
            raise BananagridError(f"{path}.sd_{a} = {show(body[f'sd_{a}'])}: must be > 0 (m)")
        if not MIN_LENGTH <= sd <= MAX_LENGTH:
            raise BananagridError(f"{path}.sd_{a} = {show(body[f'sd_{a}'])}: must be in [{MIN_LENGTH:g}, {MAX_LENGTH:g}] m")
        sds.append(sd)
    cov = np.diag(np.square(sds))
    if d > 1:
        rho = _finite(body.get("rho", 0.0), f"{path}.rho")
        if not -1.0 < rho < 1.0:
            raise BananagridError(f"{path}.rho = {show(body['rho'])}: must be in (-1, 1) (the x-y correlation)")
        cov[0, 1] = cov[1, 0] = rho * sds[0] * sds[1]
    covariance(f"{path}.{', '.join(f'sd_{a}' for a in axes)}{', rho' if d > 1 else ''}", cov, dim=d)
    return w, mean, cov.tolist()


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


#: Side of a GPU thread's tile of grid cells (:func:`grid_probabilities`).
_GPU_TILE = 8


def _grid_tiles(grid: Grid, bands, side: int | None = None) -> list[tuple[int, int, int, int, int, int]]:
    """Launches of :func:`bananagrid.kernels.presence.grid_cells`: ``(row0, row1, tile_rows,
    tile_cols, slot0, threads)`` each. On the CPU (``bands``) a band is one tile as wide as the
    grid (one extra row of corners a band); on a GPU (``side``) one launch of ``side`` x ``side``
    tiles, (side + 1)^2 corners for side^2 cells, one thread each."""
    if side is None:
        return [(r0, r1, r1 - r0, grid.nx, k, 1) for k, (r0, r1) in enumerate(bands)]
    width = min(side, grid.nx)
    return [(0, grid.ny, side, width, 0, -(-grid.ny // side) * -(-grid.nx // width))]


#: Absolute error bound of one rectangle probability by inclusion and exclusion of four BVNU
#: orthant values: each is accurate to about 1e-15 absolute (Genz, "Numerical computation of
#: rectangular bivariate and trivariate normal and t probabilities", Stat. Comput. 14 (2004)),
#: and the three subtractions add at most 4 ulps of 1: |p_hat - p| <= 4e-15 + 1e-15 < 1e-14.
#: A mixture's weights sum to 1, so its cells' error is bounded the same way.
RECTANGLE_ABS_ERROR = 1e-14


def clip_rounding(prob: np.ndarray, what: str) -> np.ndarray:
    """Probabilities with the negative rounding of the orthant differences set to 0.

    A true probability is >= 0 and the computed one is within ``RECTANGLE_ABS_ERROR`` of it, so
    a value in [-RECTANGLE_ABS_ERROR, 0) is rounding and 0 is closer to the truth; anything lower
    cannot come from rounding and is an internal error, never silently clipped.

    Raises
    ------
    BananagridError
        A value below ``-RECTANGLE_ABS_ERROR`` (or NaN).
    """
    low = float(np.min(prob)) if prob.size else 0.0
    if not low >= -RECTANGLE_ABS_ERROR:
        raise BananagridError(
            f"{what}: a cell probability of {low!r}, below -{RECTANGLE_ABS_ERROR:g}, which rounding cannot "
            "explain: an internal error, please report it with the parameters"
        )
    return np.maximum(prob, 0.0)


def rectangle_probabilities(lims, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
    """P(l0 < X < l1, l2 < Y < l3) for standard normals of correlation l4, per row of the
    ``(n, 5)`` array ``lims`` (Genz's BVNU in the kernel), computed in float64 for either
    ``dtype`` (the four orthant terms cancel on small rectangles) and returned in ``dtype``."""
    lims = np.ascontiguousarray(lims, dtype=float)
    ctx = WarpContext(dtype, device)
    if lims.shape[0] == 0:
        return np.zeros(0, dtype=ctx.dtype)
    lims = np.clip(lims, -1e30, 1e30)  # +-inf limits as far-out finite ones (Q underflows to 0)
    out = ctx.zeros(lims.shape[0])
    ctx.launch(kp.rectangles, dim=lims.shape[0], inputs=[
        ctx.array(lims, dtype=np.float64), ctx.array(_bvn_rule(), dtype=np.float64), out,
    ])
    return clip_rounding(ctx.numpy(out), "rectangle probabilities")


def grid_probabilities(mixture: GaussianMixture, grid: Grid, *, dtype=np.float64, device: str = "cpu",
                       threads=None) -> GridPresence:
    r"""A 2-D mixture's density at the cell centres of ``grid`` and each cell's exact probability.

    .. math::

        P_{ij} = \sum_c w_c\, \Pr(x_j^- < X < x_j^+,\ y_i^- < Y < y_i^+ \mid c),

    each rectangle by inclusion and exclusion of four upper-orthant probabilities of Genz's
    BVNU (Drezner & Wesolowsky with Genz's double-precision changes; accurate to about 1e-15
    absolute), with each axis reflected so that the orthants are tail values. A 3-D mixture
    is taken by its (x, y) marginal.

    Neighbouring cells share their corners: a corner's tail orthant (the quadrant facing away
    from the component's mean) is evaluated once per component and serves its four cells, and
    the cells holding a mean's coordinate on an axis keep orthants of their own (see
    :mod:`bananagrid.kernels.presence`). Each cell is the per-cell form's value bit for bit,
    within 1e-9 relative or 1e-15 absolute (tested against an independent oracle), at about one
    bivariate normal evaluation a component and cell instead of four.

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
        absolute error is under 1e-45). It saves memory, not time. Cells whose orthant
        differences round below 0 (by at most ``RECTANGLE_ABS_ERROR``, see
        :func:`clip_rounding`) are 0.
    device : str
        ``"cpu"`` or ``"cuda"``.
    threads : int, optional
        CPU threads (bands of rows); default all cores.

    Raises
    ------
    BananagridError
        For a 1-D mixture, anything but a Grid, or a bad dtype, device or thread count.
    """
    if not isinstance(mixture, GaussianMixture):
        raise BananagridError(f"mixture = {mixture!r}: expected a bananagrid GaussianMixture")
    if mixture.dim == 1:
        raise BananagridError("mixture: a 1-D (line) mixture has no density on a planar grid; give 2-D means")
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid.Grid")
    ctx = WarpContext(dtype, device, threads)
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
    f64 = np.float64
    comp = ctx.array(np.array(rows, dtype=f64), dtype=f64)
    n_comp = len(rows)
    x0, x1, y0, y1 = grid.extent
    xe = ctx.array(x0 + grid.dx * np.arange(grid.nx + 1), dtype=f64)
    ye = ctx.array(y0 + grid.dy * np.arange(grid.ny + 1), dtype=f64)
    rule = ctx.array(_bvn_rule(), dtype=f64)
    density = ctx.zeros(grid.shape)
    prob = ctx.zeros(grid.shape)
    ctx.load(kp.grid_cells)
    # what every corner of a component shares: the correlation's Gauss-Legendre nodes, and each
    # column edge standardised with its normal tail
    nodes = ctx.zeros((n_comp, kp.BVN_SCALARS + 1, kp.BVN_NODES), dtype=f64)
    ctx.launch(kp.bvn_node_table, dim=(n_comp, kp.BVN_NODES), inputs=[comp, rule, nodes])
    col_std = ctx.empty((n_comp, grid.nx + 1), dtype=f64)
    col_tail = ctx.empty((n_comp, grid.nx + 1), dtype=f64)
    ctx.launch(kp.grid_edge_tails, dim=(n_comp, grid.nx + 1), inputs=[xe, comp, col_std, col_tail])
    tiles = _grid_tiles(grid, ctx.bands(grid.ny, 4)) if ctx.cpu else _grid_tiles(grid, None, _GPU_TILE)
    width = tiles[0][3]
    slots = sum(tile[5] for tile in tiles)
    below = ctx.empty((slots, n_comp, width + 1), dtype=f64)
    acc = ctx.empty((slots, width), dtype=f64)
    by_start = {tile[0]: tile for tile in tiles}

    def launch(r0, r1):
        _, row1, tile_rows, tile_cols, slot0, dim = by_start[r0]
        ctx.launch(kp.grid_cells, dim=dim, inputs=[xe, ye, r0, row1, tile_rows, tile_cols, slot0, comp, n_comp, rule,
                                                   nodes, col_std, col_tail, below, acc, density, prob])

    ctx.run_bands(launch, [tile[:2] for tile in tiles])
    p = clip_rounding(ctx.numpy(prob), "grid_probabilities")
    return GridPresence(
        density=density.numpy(), probability=p, grid=grid, mass=float(np.sum(p, dtype=np.float64)),
        provenance={**mixture.parameters(), "kernel": "presence.grid_cells", "dtype": ctx.dtype.name,
                    "device": ctx.device, "threads": ctx.threads, "seconds": time.perf_counter() - start},
    )


# --------------------------------------------------------------------------------------------
# Cell probabilities
# --------------------------------------------------------------------------------------------


def _component_rows(mixture: GaussianMixture) -> np.ndarray:
    """Kernel rows (kernels/presence.py C_* layout) of each component's (conditional) (x, y) law."""
    rows = np.zeros((mixture.n_components, kp.COMPONENT_COLUMNS))
    for i, (w, mu, cov) in enumerate(zip(mixture.weights, mixture.means, mixture.covs)):
        row = rows[i]
        row[kp.C_LOGW] = math.log(w) if w > 0 else -1e300
        cond = cov[:2, :2]
        g = np.zeros(2)
        if mixture.dim == 3:
            szz = cov[2, 2]
            g = cov[:2, 2] / szz
            cond = cov[:2, :2] - np.outer(cov[:2, 2], cov[:2, 2]) / szz
            row[kp.C_MZ], row[kp.C_SZ] = mu[2], math.sqrt(szz)
        else:
            row[kp.C_SZ] = 1.0
        chol = np.linalg.cholesky(cond)
        binv = np.linalg.inv(chol)
        row[kp.C_NORM] = w / (2.0 * math.pi * chol[0, 0] * chol[1, 1])
        row[kp.C_B11], row[kp.C_B21], row[kp.C_B22] = binv[0, 0], binv[1, 0], binv[1, 1]
        row[kp.C_V1], row[kp.C_V2] = binv @ mu[:2]
        row[kp.C_VG1], row[kp.C_VG2] = binv @ g
        row[kp.C_MX], row[kp.C_MY] = mu[:2]
        row[kp.C_SMIN] = math.sqrt(np.linalg.eigvalsh(cond)[0])
        row[kp.C_SMAX] = math.sqrt(np.linalg.eigvalsh(cov[:2, :2])[-1])
    return rows


def _check_presence(presence, lattice: AngularLattice):
    need = {"line": 1, "plane": 2, "frustum": 3}[lattice.geometry]
    if not isinstance(presence, (GaussianMixture, UniformPresence)):
        raise BananagridError(f"presence = {presence!r}: expected a GaussianMixture or a UniformPresence")
    if presence.dim != need:
        raise BananagridError(
            f"presence has {presence.dim} dimension(s) but a {lattice.geometry} lattice needs {need} "
            f"({'x' if need == 1 else 'x, y' if need == 2 else 'x, y, z'})"
        )


def lattice_cell_plan(law, domain, region=None) -> CellPlan:
    """A presence law's :class:`~bananagrid.protocol.CellPlan` on ``domain``: the cells of an
    :class:`~bananagrid.AngularLattice` conditioned on ``region`` (:func:`cell_probabilities` in
    the run's dtype, device and threads; no time estimate, the lattice's size bounds it), or one
    line saying where the law's cells are."""
    if not isinstance(domain, AngularLattice):
        raise BananagridError(
            f"{type(law).__name__}: a presence law's cells are those of an AngularLattice (rasterise(law, "
            "lattice, region=room)); a 2-D mixture's grid cells: bananagrid.grid_probabilities(law, grid)"
        )

    def run(ctx):
        return cell_probabilities(law, domain, region, dtype=ctx.dtype, device=ctx.device, threads=ctx.threads), {}

    return CellPlan(seconds=None, run=run, method="the law's cells of an angular lattice (cell_probabilities)")


def cell_probabilities(presence, lattice: AngularLattice, region=None, *, dtype=np.float64, device: str = "cpu",
                       threads=None, rtol: float = RTOL) -> CellMap:
    r"""Presence probability of every cell: ``p(C | S) = p(C and S) / p(S)`` (Sections 7-9, ERRATA).

    * Line, Gaussian mixture (7.2 as in ERRATA): exact, ``sum_i w_i (Phi(u_p) - Phi(u_m))`` at
      x = -h cot(phi) of the cell's azimuth bounds, clipped to S.
    * Plane and frustum, Gaussian mixture: the kernels of :mod:`bananagrid.kernels.presence`
      (closed-form radial integral, adaptive Gauss-Kronrod in phi and depth); each component's
      integral over a cell meets ``|K15 - G7| <= rtol |K15| + ATOL p(S)``, giving a relative error
      below 1e-6 for every cell holding at least 1e-9 of the mass at the default ``rtol``.
    * Uniform presence: clipped length, area or volume over |S| (exact geometry).

    Parameters
    ----------
    presence : GaussianMixture or UniformPresence
        Of dimension 1 (line), 2 (plane) or 3 (frustum).
    lattice : AngularLattice
    region : Region, optional
        S: cells are clipped to it and the probabilities conditioned on it. A uniform law is
        conditioned on its own region (intersected with ``region`` if given).
    dtype, device, threads
        Kernel precision (float64 for the stated accuracy), Warp device, CPU threads.
    rtol : float
        Relative tolerance per component and cell (default 1e-7).
    """
    if not isinstance(lattice, AngularLattice):
        raise BananagridError(f"lattice = {lattice!r}: expected a bananagrid AngularLattice")
    _check_presence(presence, lattice)
    rtol = positive("rtol", rtol)
    if np.dtype(dtype) == np.float32:
        rtol = max(rtol, FLOAT32_RTOL)  # float32 cannot resolve K15 - G7 below ~1e-7 of K15
    threads = check_threads(threads)
    start = time.perf_counter()
    if region is not None:
        region = as_region(region)
        if region.dim != presence.dim:
            raise BananagridError(f"region has {region.dim} axes; a {lattice.geometry} lattice needs {presence.dim}")
    if isinstance(presence, UniformPresence):
        box = presence.region if region is None else presence.region.intersect(region)
        prob, clipped, err = clipped_cells(lattice, box)
        return CellMap(prob=prob, lattice=lattice, region=box, region_probability=1.0, error=err,
                       clipped_sizes=clipped, provenance={**presence.parameters(), "lattice": lattice.describe(),
                                                          "method": "exact clipped geometry",
                                                          "seconds": time.perf_counter() - start})
    p_s = 1.0 if region is None else presence.region_probability(region, device=device)
    if region is not None and not p_s > 0.0:
        raise BananagridError(f"region {region.describe()}: the mixture gives it no mass (p(S) = {p_s!r})")
    if lattice.geometry == "line":
        prob = _line_mixture(presence, lattice, region) / p_s
        err = np.zeros_like(prob)
        clipped = clipped_cells(lattice, region)[1] if region is not None else None
        prov = {"method": "differences of normal CDFs (7.2)"}
    else:
        prob, err, prov = _mixture_cells(presence, lattice, region, p_s, dtype=dtype, device=device,
                                         threads=threads, rtol=rtol)
        clipped = clipped_cells(lattice, region)[1] if region is not None else None
    return CellMap(prob=prob, lattice=lattice, region=region, region_probability=p_s, error=err,
                   clipped_sizes=clipped, provenance={**presence.parameters(), "lattice": lattice.describe(),
                                                      **prov, "seconds": time.perf_counter() - start})


def _line_mixture(mixture: GaussianMixture, lattice: AngularLattice, region) -> np.ndarray:
    x = lattice.line_edges()
    if region is not None:
        x = np.clip(x, region.x[0], region.x[1])
    prob = np.zeros(x.size - 1)
    for w, mu, cov in zip(mixture.weights, mixture.means[:, 0], mixture.covs[:, 0, 0]):
        sd = math.sqrt(cov)
        u = (x - mu) / sd
        prob += w * _interval_probability(u[:-1], u[1:])
    return prob


def _mixture_cells(mixture, lattice, region, p_s, *, dtype, device, threads, rtol):
    ctx = WarpContext(dtype, device, threads)
    na, ne = lattice.shape
    phi = lattice.azimuth_edges
    phi0 = np.repeat(phi[:-1], ne)
    phi1 = np.repeat(phi[1:], ne)
    tau = lattice.tau_edges
    tau0 = np.tile(tau[1:], na)
    tau1 = np.tile(tau[:-1], na)
    frustum = lattice.geometry == "frustum"
    depths = lattice.depths if frustum else (lattice.h, lattice.h)
    if region is not None:
        b = region.bounds
        if frustum:
            depths = (max(depths[0], -b[2, 1]), min(depths[1], -b[2, 0]))
        box = b[:2].ravel()
        far = box_far(b)
        status = np.zeros(phi0.size, dtype=int)
        if depths[1] > depths[0] or not frustum:
            status = classify_cells(phi0, phi1, depths[0] * tau0, depths[1] * tau1, b)
        radii = [depths[0] * tau0, depths[0] * tau1, depths[1] * tau0, depths[1] * tau1]
        bps = cell_breakpoints(phi0, phi1, radii, b)
    else:
        box = np.array([-1.0, 1.0, -1.0, 1.0])
        far = 1e300
        status = np.ones(phi0.size, dtype=int)
        bps = None
    start, pa, pb = cell_pieces(phi0, phi1, status, bps)
    cut = (status == 2).astype(np.int32)
    n = phi0.size

    arr = ctx.array
    scalar = ctx.scalar
    tau1_k = np.where(np.isinf(tau1), -1.0, tau1)
    comp = arr(_component_rows(mixture))
    prob = ctx.zeros(n)
    err = ctx.zeros(n)
    evals = ctx.zeros(n, dtype=np.int32)
    log_atol = math.log(ATOL * p_s)
    common_tail = [arr(box), scalar(far), comp, mixture.n_components, arr(_gk_rule()), arr(_gl8()),
                   scalar(rtol), scalar(log_atol), MAX_PANELS]
    head = [arr(start, dtype=np.int32), arr(pa), arr(pb), arr(cut, dtype=np.int32), arr(phi0), arr(phi1)]
    kernel = kp.frustum_cells if frustum else kp.plane_cells
    # the plane's radii in float64 here (h tau rounded once to the dtype); the frustum's depths scale tau in the kernel
    lo, hi = (tau0, tau1_k) if frustum else (lattice.h * tau0, np.where(np.isinf(tau1), -1.0, lattice.h * tau1_k))
    geo = [arr(lo), arr(hi), scalar(depths[0]), scalar(depths[1])]
    ctx.load(kernel)
    bands = [] if frustum and not depths[1] > depths[0] else ctx.bands(n, 16)

    def launch(c0, c1):
        ctx.launch(kernel, dim=c1 - c0, inputs=[*head, *geo, *common_tail, c0, prob, err, evals])

    if bands:  # none where the region misses the slab: every cell's probability is 0
        ctx.run_bands(launch, bands)
    raw = ctx.numpy(prob).astype(np.float64)
    out = (raw / p_s).reshape(na, ne)
    error = (err.numpy().astype(np.float64) / p_s).reshape(na, ne)
    nodes = int(evals.numpy().astype(np.int64).sum())
    prov = {
        "method": "closed-form radial integral, adaptive Gauss-Kronrod (7, 15) in phi"
                  + (" and depth" if frustum else ""),
        "kernel": f"presence.{'frustum' if frustum else 'plane'}_cells", "dtype": ctx.dtype.name,
        "device": ctx.device, "threads": ctx.threads, "rtol": rtol, "atol": ATOL * p_s,
        "panels": nodes, "cells_cut": int(np.sum(status == 2)), "cells_outside": int(np.sum(status == 0)),
    }
    return out, error, prov
