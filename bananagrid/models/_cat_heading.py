"""Exact CAT density with initial-heading noise (Section 7 of the polar-banana paper).

A heading error theta_0 ~ N(0, sigma_0) turns the whole CAT trajectory about the last fix, so at
range r and bearing theta (local frame, clockwise from the nominal heading)

    p(r, theta) = integral of p_0(r, theta - theta_0) g(theta_0; 0, sigma_0) d theta_0,        (*)

with p_0 the CAT density without heading noise. A rotation by theta_0 + 2 pi is the same
rotation, so (*) is the periodic convolution of p_0(r, .) with the wrapped normal law, whose
Fourier coefficients are exp(-k^2 sigma_0^2 / 2).

How it is computed, and why the error is controlled:

1. p_0 is evaluated by the exact CAT kernel on a polar lattice: ranges r_i = r0 + i dr and
   n_theta bearings over the full circle. The spacings come from the banana's own scales
   (:func:`natural_scales`): ``RESOLUTION`` nodes per range SD and ``BEARING_RESOLUTION`` per
   angular width of the banana on a circle. Each bearing's ray is swept as a grid row
   (:func:`plain_lattice`: ``pdf``'s values to the bit), and p_0 is symmetric about
   the heading, so each pair of mirrored bearings is swept once.
2. Each lattice row is convolved with the wrapped normal by FFT (the lattice's rows, even about
   their first bearing, by the cosine transform of their half). With the row resolved (its
   Fourier coefficients negligible at the Nyquist frequency) this is (*) to rounding: the
   error is a few ulps of the row's largest value: relative to the value, 1e-6 holds down to
   about 1e-10 of the peak (7e-7 measured there on Figure 1), and grows as the value falls
   below that.
3. Cells and points interpolate the convolved lattice (``kernels/tabulated.py``: cubic Lagrange in
   r and theta applied to log p, exact for a locally Gaussian density; on the CPU in lanes,
   ``kernels/tabulated_lanes.py``).
4. The interpolation error is measured on every table: ``CHECK_ROWS`` extra rows at half-steps
   in range, convolved exactly at bearings half-way between the lattice's, are compared with
   the interpolated values wherever the density exceeds ``CHECK_LEVEL`` of its peak. If the
   largest relative difference exceeds ``TARGET_ERROR`` the spacings are refined by the factor
   the stencils' h^4 error law asks for (at most ``MAX_REFINEMENTS`` times); the estimate is
   reported as ``heading_error_estimate``.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.fft

from ..domains.pose import Pose
from ..engine.points import evaluate_points, launch_points
from ..engine.warp_runtime import WarpContext
from ..kernels import cat_lanes, tabulated, tabulated_lanes
from ..protocol import KernelBinding, KernelContext
from ..validate import BananagridError, BananagridWarning
from .motion import MotionModel, natural_scales

__all__ = [
    "HeadingTable", "heading_table", "build_heading_table", "convolved_rows", "plain_lattice", "ray_densities",
    "convolve_heading", "convolve_even_heading", "table_binding", "clear_heading_tables", "interpolate_table", "RESOLUTION", "BEARING_RESOLUTION",
    "first_table_nodes", "table_spacing_limits", "interpolation_bound",
    "TARGET_ERROR", "CHECK_LEVEL", "heading_nodes", "HEADING_SDS", "HEADING_NODES_PER_SCALE",
]

#: Lattice nodes per natural scale: per range SD, and per angular width of the banana on a
#: circle. The bearing needs more: where the heading blur merges the banana's two crossings of a
#: circle, the convolved profile departs from a log-quadratic (measured on Figure 1 at
#: sigma_0 = pi/15: 5e-6 error at 8 nodes per width, 8e-7 at 13).
RESOLUTION = 8
BEARING_RESOLUTION = 14
#: Bearing nodes per angular width for the exact ray values (:func:`ray_densities`).
RAY_RESOLUTION = 6
#: Largest relative interpolation error accepted before the spacings are refined.
TARGET_ERROR = 1.0e-6
#: The error check covers the points where the density is at least this fraction of its peak.
CHECK_LEVEL = 1.0e-8
CHECK_ROWS = 16
MAX_REFINEMENTS = 2
#: A refinement scales the resolution by 1.1 (error / target)^(1/4), at most 2.
REFINE_MARGIN = 1.1
#: Lattice size beyond which no refinement is tried (64 MiB per float64 table) and beyond which
#: an unrefined table is refused.
MAX_LATTICE_NODES = 1 << 23
#: Tables at or below this value are treated as underflowed: interpolated linearly, not in log.
FLOOR = {np.dtype(np.float64): 1.0e-290, np.dtype(np.float32): 1.0e-30}
#: Over a stencil's offsets (fr, ft) in [0, 1]^2 the tensor cubic Lagrange weights sum to 1, their
#: absolute values to at most 1.25^2 = 1.5625 (the Lebesgue constant, at fr = ft = 1/2) and their
#: negative parts to at most 2 (1/8)(9/8) = 0.28125; these allow offsets 0.05 outside [0, 1]
#: (a float32 range rounded past a stencil's end), where the values are lower still.
STENCIL_LEBESGUE = 1.6
STENCIL_NEGATIVE = 0.3
#: Absolute rounding a stencil's sums may gain in the subnormal range (32 terms of a float32 ulp).
SUBNORMAL_SLACK = 1e-43


@dataclass(frozen=True)
class HeadingTable:
    """The heading-convolved CAT density on a polar lattice of the model's local frame.

    Attributes
    ----------
    values : ndarray (n_r, n_theta)
        Density per m^2 at r0 + i dr, theta0 + j dtheta (float64).
    r0, dr, theta0, dtheta : float
        Lattice geometry; n_theta dtheta = 2 pi.
    mirror : bool
        Whether the lattice starts at the origin (rows below it are reflected through it).
    error_estimate : float
        Largest relative interpolation error found by the check rows (see module notes).
    refinements : int
        How many times the spacings were refined to meet ``TARGET_ERROR``.
    """

    values: np.ndarray
    r0: float
    dr: float
    theta0: float
    dtheta: float
    mirror: bool
    error_estimate: float
    refinements: int
    #: The kernel's arrays per dtype (:meth:`kernel_arrays`), made once.
    _kernel_arrays: dict = field(default_factory=dict, repr=False, compare=False)

    def kernel_arrays(self, dtype) -> tuple[np.ndarray, np.ndarray, float]:
        """The padded lattice (``kernels/tabulated.py``'s ``pad_table``) in ``dtype``, its log
        (entries at or below the dtype's ``FLOOR`` are never used in log) and that floor: made
        once per dtype (the check rows and every grid of a remembered table share them)."""
        dtype = np.dtype(dtype)
        arrays = self._kernel_arrays.get(dtype)
        if arrays is None:
            values = tabulated.pad_table(self.values, self.mirror).astype(dtype)
            floor = FLOOR[dtype]
            with np.errstate(divide="ignore"):
                logs = np.log(np.maximum(values, floor))
            arrays = self._kernel_arrays.setdefault(dtype, (values, logs, floor))
        return arrays

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape

    def notes(self) -> dict:
        """Provenance entries describing the table."""
        return {
            "heading_lattice": f"{self.shape[0]} ranges x {self.shape[1]} bearings",
            "heading_dr": self.dr,
            "heading_dtheta": self.dtheta,
            "heading_error_estimate": self.error_estimate,
        }


def convolve_heading(values: np.ndarray, sigma_heading: float) -> np.ndarray:
    """Periodic convolution of each row (a full circle of bearings) with the wrapped normal
    N(0, sigma_heading): Fourier coefficient k is multiplied by exp(-k^2 sigma^2 / 2)."""
    n = values.shape[-1]
    k = np.arange(n // 2 + 1)
    spectrum = np.fft.rfft(values, axis=-1) * np.exp(-0.5 * (k * sigma_heading) ** 2)
    out = np.fft.irfft(spectrum, n=n, axis=-1)
    # rounding leaves values of a few ulps of the row maximum, of either sign, where p is ~0
    return np.maximum(out, 0.0)


def convolve_even_heading(half: np.ndarray, sigma_heading: float) -> np.ndarray:
    """:func:`convolve_heading` of rows that are even about their first bearing, given by their
    first n / 2 + 1 bearings (n even; shape (..., n / 2 + 1)), and so returned: the Fourier
    coefficients of an even row are its type-I cosine transform (real, half the length)."""
    k = np.arange(half.shape[-1])
    spectrum = scipy.fft.dct(half, type=1, axis=-1) * np.exp(-0.5 * (k * sigma_heading) ** 2)
    out = scipy.fft.idct(spectrum, type=1, axis=-1)
    # rounding leaves values of a few ulps of the row maximum, of either sign, where p is ~0
    return np.maximum(out, 0.0)


def _base_model(model: MotionModel) -> MotionModel:
    """The same CAT without heading noise, in its own local frame."""
    return replace(model, sigma_heading=0.0, pose=Pose())


def convolved_rows(model: MotionModel, radii, theta_start: float, n_theta: int, *, threads=None) -> np.ndarray:
    """(*) at ranges ``radii`` and bearings theta_start + 2 pi j / n_theta (j < n_theta), exact
    to rounding when n_theta resolves the rows (float64, shape (len(radii), n_theta))."""
    theta = theta_start + 2.0 * math.pi * np.arange(n_theta) / n_theta
    partner = _mirror_bearings(theta_start, n_theta)
    if partner is None:
        p0 = plain_lattice(model, radii, theta, threads=threads)
    elif partner[0] == 0 and n_theta % 2 == 0:
        # bearing 0 its own mirror (the lattice's -pi): each row is even about it, bearings
        # 0 .. n_theta / 2 hold all of it, and so does its convolution (the wrapped normal is even)
        half = np.ascontiguousarray(plain_lattice(model, radii, theta[: n_theta // 2 + 1], threads=threads))
        j = np.arange(n_theta)
        return convolve_even_heading(half, model.sigma_heading)[:, np.minimum(j, n_theta - j)]
    else:
        # p_0 is symmetric about the nominal heading (the turn rate's law is symmetric, and
        # omega -> -omega mirrors each path: p_0(r, -theta) = p_0(r, theta)): each pair of
        # mirrored bearings is evaluated once, at the one of the pair listed first
        j = np.arange(n_theta)
        first = np.minimum(j, partner)
        own = np.unique(first)
        p0 = plain_lattice(model, radii, theta[own], threads=threads, rays=True)[np.searchsorted(own, first)].T
    return convolve_heading(p0, model.sigma_heading)


def _mirror_bearings(theta_start: float, n_theta: int) -> np.ndarray | None:
    """For bearings theta_j = theta_start + 2 pi j / n_theta, the index of -theta_j's bearing
    (mod 2 pi) for each j where every bearing has one (theta_start an integer multiple of
    pi / n_theta, as the lattice's -pi and the check rows' half-steps), else None."""
    s = -theta_start * n_theta / math.pi  # -theta_j = theta_m (mod 2 pi) for m = s - j (mod n_theta)
    if not abs(s - round(s)) <= 1e-9 * max(1.0, abs(s)):
        return None
    return (int(round(s)) - np.arange(n_theta)) % n_theta


#: Ray bands per thread of :func:`plain_lattice`: the rays through the banana cost far more than
#: the others.
RAY_BANDS_PER_THREAD = 16


def plain_lattice(model: MotionModel, radii, theta, *, threads=None, rays: bool = False) -> np.ndarray:
    """p_0, the CAT density without heading noise (float64), at the local points
    (r sin theta, r cos theta) for r in ``radii`` and each bearing ``theta``:
    shape (len(radii), len(theta)) (with ``rays``: its transpose, a ray a row). Each bearing's ray is swept as a grid row
    (``kernels/cat_lanes.py``'s ``cat_rays``): ``pdf``'s values, to the bit, at a
    fraction of its cost (O(nodes) a ray plus the roots, instead of the scan at every point)."""
    radii = np.ascontiguousarray(radii, dtype=np.float64)
    theta = np.asarray(theta, dtype=np.float64)
    if radii.size == 0 or not np.isfinite(radii).all():
        # the points kernel refuses non-finite points (and has none to evaluate): always the rays
        # otherwise, also for the check rows' few ranges, so that a run builds one CAT kernel
        x = radii[:, None] * np.sin(theta)[None, :]
        y = radii[:, None] * np.cos(theta)[None, :]
        values = evaluate_points(_base_model(model), x, y, dtype=np.float64, threads=threads)
        return values.T if rays else values
    if np.any(np.diff(radii) < 0.0):  # the sweep takes a ray's points in order
        order = np.argsort(radii, kind="stable")
        values = np.empty((theta.size, radii.size))
        values[:, order] = plain_lattice(model, radii[order], theta, threads=threads, rays=True)
        return values if rays else values.T
    ctx = WarpContext(np.float64, "cpu", threads)
    binding = _base_model(model).bind(ctx, None, grid=True)
    sines = ctx.host_array(np.sin(theta))
    cosines = ctx.host_array(np.cos(theta))
    lattice = np.empty((theta.size, radii.size))  # a ray a row
    out = ctx.shared(lattice)
    xs = ctx.host_array(radii)
    ctx.load(cat_lanes.cat_rays)

    def launch_band(a, b):
        ctx.launch(cat_lanes.cat_rays, dim=b - a, inputs=[xs, sines, cosines, a, binding.params, out])
    ctx.run_bands(launch_band, ctx.bands(theta.size, RAY_BANDS_PER_THREAD))
    return lattice if rays else lattice.T


def _even(n: float) -> int:
    n = int(math.ceil(n))
    return n + (n % 2)


def heading_table(model: MotionModel, r_lo: float, r_hi: float, *, threads=None) -> HeadingTable:
    """:func:`build_heading_table`, remembered for the last few (model, range) pairs: a caller
    that evaluates one region in chunks (a polar lattice) builds the table once. The
    thread count does not change the table."""
    return _remembered_table(model, float(r_lo), float(r_hi), threads)


def clear_heading_tables() -> None:
    """Forget the remembered tables (e.g. to time building them)."""
    _remembered_table.cache_clear()


@functools.lru_cache(maxsize=2)
def _remembered_table(model: MotionModel, r_lo: float, r_hi: float, threads) -> HeadingTable:
    return build_heading_table(model, r_lo, r_hi, threads=threads)


def build_heading_table(model: MotionModel, r_lo: float, r_hi: float, *, threads=None) -> HeadingTable:
    """The convolved lattice covering ranges [r_lo, r_hi] of the model's local frame, with its
    interpolation error checked. While the estimate exceeds ``TARGET_ERROR`` the spacings are
    refined by the factor the cubic stencils' h^4 error law asks for (with a 10% margin, at most
    2 a step), as long as the finer lattice stays within ``MAX_LATTICE_NODES`` and the factor
    needed in all stays within 2^MAX_REFINEMENTS; else a warning gives the estimate."""
    radial, angular = natural_scales(model)
    scale = 1.0
    table = None
    for refinement in range(MAX_REFINEMENTS + 1):
        dr = radial / (RESOLUTION * scale)
        n_theta = max(16, _even(2.0 * math.pi * BEARING_RESOLUTION * scale / angular))
        if table is not None and _rows(r_lo, r_hi, dr) * n_theta > MAX_LATTICE_NODES:
            break
        table = _build(model, r_lo, r_hi, dr, n_theta, refinement, threads)
        if table.error_estimate <= TARGET_ERROR:
            return table
        needed = REFINE_MARGIN * (table.error_estimate / TARGET_ERROR) ** 0.25
        if scale * needed > 2.0**MAX_REFINEMENTS:
            break  # beyond what the refinements allowed can reach (the density is not smooth)
        scale *= min(2.0, needed)
    warnings.warn(
        f"CAT with sigma_heading = {model.sigma_heading:.6g}: the heading lattice's interpolation "
        f"error estimate is {table.error_estimate:.2g} (target {TARGET_ERROR:g}) where the density "
        f"exceeds {CHECK_LEVEL:g} of its peak; sharp features such as the folds of a banana that "
        "turns over itself are not resolved better within the lattice size limit",
        BananagridWarning, stacklevel=6,
    )
    return table


def first_table_nodes(model: MotionModel, r_lo: float, r_hi: float) -> int:
    """Lattice nodes of the first table :func:`build_heading_table` evaluates for ranges
    [r_lo, r_hi] (for the work estimate; a refinement, where the error estimate asks for it,
    evaluates up to 4 and 16 times as many, within ``MAX_LATTICE_NODES``)."""
    radial, angular = natural_scales(model)
    return _rows(r_lo, r_hi, radial / RESOLUTION) * max(16, _even(2.0 * math.pi * BEARING_RESOLUTION / angular))


def table_spacing_limits(model: MotionModel) -> tuple[float, int]:
    """The largest range spacing and the most bearings of any table :func:`build_heading_table`
    builds for ``model``, over any extent: its refinements only shrink dr = radial /
    (RESOLUTION scale) and grow n_theta, with scale in [1, 2^MAX_REFINEMENTS]."""
    radial, angular = natural_scales(model)
    most = _even(2.0 * math.pi * BEARING_RESOLUTION * 2.0**MAX_REFINEMENTS / angular)
    return radial / RESOLUTION, max(16, most)


def interpolation_bound(value_bound: float) -> float:
    """A bound of what ``kernels/tabulated.py`` (and its CPU lanes, ``kernels/tabulated_lanes.py``:
    the same weights, sums and selects, with fused multiply-adds and an exp within 3 ulp) returns,
    in float32 or float64, from a stencil
    whose 16 table entries (float64, before the cast to the kernel's dtype) are at most
    ``value_bound`` (0 from entries all 0: the linear branch sums zeros).

    Linear branch (an entry at or below the floor): at most STENCIL_LEBESGUE max p. Log branch
    (every entry above the floor f): with weights w summing to 1 and logs L in (log f, log P],
    sum w L <= log P + STENCIL_NEGATIVE (log P - log f), so the value is at most
    P (P / f)^STENCIL_NEGATIVE; that branch needs P > f. A 0.1 % allowance covers the float32
    rounding of the entries, their logs and the weighted sum.
    """
    p = float(value_bound)
    if p == 0.0:
        return 0.0
    if not p < 1e38:  # float32 entries would overflow; nothing useful to prove either
        return math.inf
    # the cast to float32 rounds up by an ulp, or to twice a value in its subnormal range
    p = max(p * (1.0 + 1e-6), 2.0 * p if p < float(np.finfo(np.float32).tiny) else 0.0)
    bound = STENCIL_LEBESGUE * p
    for floor in FLOOR.values():
        if p > floor:
            bound = max(bound, p * (p / floor) ** STENCIL_NEGATIVE)
    # subnormal sums round by up to half the smallest float32 subnormal (1.4e-45) a term
    return bound * 1.001 + SUBNORMAL_SLACK


def _rows(r_lo: float, r_hi: float, dr: float) -> int:
    """Lattice rows for ranges [r_lo, r_hi] at spacing dr, two rows of margin each side."""
    start = r_lo - 2.0 * dr
    r0 = 0.0 if start < 2.0 * dr else start
    rows = (r_hi + 2.0 * dr - r0) / dr  # inf for points near 1e300 and a tiny banana: capped, then refused
    return max(4, int(math.ceil(min(rows, 2.0**62))) + 1)


def _build(model: MotionModel, r_lo, r_hi, dr, n_theta, refinement, threads) -> HeadingTable:
    # two rows of margin each side keep every query inside a centred stencil; a lattice that
    # would start within two rows of the origin starts at it and mirrors through it
    start = r_lo - 2.0 * dr
    mirror = start < 2.0 * dr
    r0 = 0.0 if mirror else start
    n_r = _rows(r_lo, r_hi, dr)
    if n_r * n_theta > MAX_LATTICE_NODES:
        raise BananagridError(
            f"sigma_heading = {model.sigma_heading!r}: the heading lattice would need {n_r} ranges x "
            f"{n_theta} bearings (more than {MAX_LATTICE_NODES} nodes) to resolve this banana over "
            f"ranges {r_lo:.6g}..{r_hi:.6g} m; use a smaller region"
        )
    dtheta = 2.0 * math.pi / n_theta
    theta0 = -math.pi
    radii = r0 + dr * np.arange(n_r)
    values = convolved_rows(model, radii, theta0, n_theta, threads=threads)
    draft = HeadingTable(values, r0, dr, theta0, dtheta, bool(mirror), math.nan, refinement)
    return replace(draft, error_estimate=_check(model, draft, threads))


def _check(model: MotionModel, table: HeadingTable, threads) -> float:
    """Largest relative interpolation error at half-step ranges and bearings, where the
    density is at least CHECK_LEVEL of the table's peak (0 when no such check point exists)."""
    n_r = table.shape[0]
    peak = float(table.values.max())
    if not peak > 0.0:
        return 0.0
    row_peak = table.values.max(axis=1)
    # intervals [i, i + 1] whose stencil rows i - 1 .. i + 2 all exist (or are mirrored)
    first = 0 if table.mirror else 1
    candidates = [i for i in range(first, n_r - 2) if max(row_peak[i], row_peak[i + 1]) >= CHECK_LEVEL * peak]
    if not candidates:
        return 0.0
    picks = np.unique(np.linspace(0, len(candidates) - 1, min(CHECK_ROWS, len(candidates))).round().astype(int))
    radii = table.r0 + table.dr * (np.array([candidates[k] for k in picks]) + 0.5)
    n_theta = table.shape[1]
    theta_start = table.theta0 + 0.5 * table.dtheta
    exact = convolved_rows(model, radii, theta_start, n_theta, threads=threads)
    theta = theta_start + table.dtheta * np.arange(n_theta)
    x = radii[:, None] * np.sin(theta)[None, :]
    y = radii[:, None] * np.cos(theta)[None, :]
    approx = interpolate_table(table, x, y, dtype=np.float64, threads=threads)
    mask = exact >= CHECK_LEVEL * peak
    if not mask.any():
        return 0.0
    return float(np.max(np.abs(approx[mask] / exact[mask] - 1.0)))


def ray_densities(model: MotionModel, radii, angles, *, threads=None) -> np.ndarray:
    """(*) at every (radius, angle) pair of the model's local frame, exact to rounding: each
    range's row is convolved in Fourier space and its trigonometric series summed at the
    angles (no lattice interpolation). Shape (len(radii), len(angles)), float64."""
    radii = np.asarray(radii, dtype=float)
    angles = np.asarray(angles, dtype=float)
    _, angular = natural_scales(model)
    # no interpolation here, only the FFT: a row sampled at RAY_RESOLUTION nodes per angular
    # width w has negligible spectrum at the Nyquist frequency pi / dtheta = 6 pi / w (a normal
    # profile of SD w has exp(-(6 pi)^2 / 2) ~ 1e-77 there)
    n_theta = max(16, _even(2.0 * math.pi * RAY_RESOLUTION / angular))
    theta = -math.pi + 2.0 * math.pi * np.arange(n_theta) / n_theta
    p0 = plain_lattice(model, radii, theta, threads=threads)
    k = np.arange(n_theta // 2 + 1)
    spectrum = np.fft.rfft(p0, axis=-1) * np.exp(-0.5 * (k * model.sigma_heading) ** 2)
    # p(theta) = (1/n) sum_k c_k e^{i k (theta - theta_start)} over k in [-n/2, n/2): the real
    # series has weight 2 on 0 < k < n/2 (the Nyquist term is negligible on a resolved row)
    weights = np.full(k.size, 2.0)
    weights[0] = 1.0
    weights[-1] = 1.0
    phase = np.exp(1j * np.outer(k, angles + math.pi))  # (k, angles)
    values = np.real((spectrum * weights) @ phase) / n_theta
    return np.maximum(values, 0.0)


def table_binding(ctx: KernelContext, table: HeadingTable, pose, notes: dict) -> KernelBinding:
    """The interpolating kernels (``kernels/tabulated.py``) over ``table``, placed by ``pose``
    (origin x, origin y, cos heading, sin heading): log-cubic stencils where the table is above
    its floor."""
    values, logs, floor = table.kernel_arrays(ctx.dtype)
    params = ctx.struct(tabulated.TABLE, log_table=ctx.array(logs), table=ctx.array(values), r0=table.r0, dr=table.dr,
                        theta0=table.theta0, dtheta=table.dtheta, floor_value=floor, mirror=int(table.mirror), pose=pose)
    # on the CPU the lane kernels (``kernels/tabulated_lanes.py``)
    return KernelBinding(tabulated_lanes.KERNELS if ctx.device == "cpu" else tabulated.KERNELS, params, notes)


def interpolate_table(table: HeadingTable, x, y, *, dtype=np.float64, device: str = "cpu", threads=None) -> np.ndarray:
    """Interpolate ``table`` at points (x, y) of its own local frame."""
    ctx = WarpContext(dtype, device, threads)
    bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    binding = table_binding(ctx, table, (0.0, 0.0, 1.0, 0.0), {})
    ctx.load(binding.kernels.points)
    return launch_points(ctx, binding, bx, by)


#: Carried evidence with heading noise: the trapezoidal rule in theta_0 over +-HEADING_SDS
#: sigma_0 (the normal tail beyond, 2.6e-12, is left out), HEADING_NODES_PER_SCALE nodes per the
#: smaller of sigma_0 and the banana's angular width (``natural_scales``).
HEADING_SDS = 7.0
HEADING_NODES_PER_SCALE = 6.0


def heading_nodes(model: MotionModel) -> tuple[np.ndarray, np.ndarray]:
    """Heading errors theta_0 and weights of the carried density with heading noise,

        p_w(x) = int g(theta_0; 0, sigma_0) sum over roots of the path turned by theta_0 of
                 w(path) g(a) g(omega) / |det J| d theta_0,

    by the trapezoidal rule (``HEADING_SDS``, ``HEADING_NODES_PER_SCALE``): the evidence is
    fixed in the world, so the heading no longer enters as a convolution along the bearing and
    each node is a CAT scan of the turned path. The trapezoidal rule converges geometrically on
    the smooth integrand of a point whose evidence weight is smooth in theta_0 (reports, bearings,
    the inverse-cube track); where a path's position at a search's time crosses a polygon's edge
    as theta_0 turns, the weight jumps, and the rule is first order there: at a point its error
    is at most one node's share of the integrand times the jump (measured up to 1.4e-2 of the
    prior density for a search with POD 0.8; tests/models/test_cat_carried.py), and it averages
    out over a cell's sub-cells (the posterior's Monte Carlo test). Without heading noise: one
    node, theta_0 = 0, weight 1."""
    if model.sigma_heading <= 0.0:
        return np.zeros(1), np.ones(1)
    _, angular = natural_scales(model)
    step = min(model.sigma_heading, angular) / HEADING_NODES_PER_SCALE
    half = HEADING_SDS * model.sigma_heading
    n = int(math.ceil(half / step))
    theta = np.linspace(-half, half, 2 * n + 1)
    h = theta[1] - theta[0]
    weights = h * np.exp(-0.5 * (theta / model.sigma_heading) ** 2) / (model.sigma_heading * math.sqrt(2.0 * math.pi))
    return theta, weights
