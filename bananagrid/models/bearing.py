"""Bearing fixes: where two or more direction-finding stations' bearings cross (Walsh, 1968).

Each sensor at S_i reports a bearing b_i (radians clockwise from north) to the contact with an
independent normal error of standard deviation sigma_i. The fix is the crossing of the bearing
lines (two sensors) or the likelihood's global maximum (three or more, beyond Walsh: a
multistart search, chi^2 being multimodal where a station is near the contact); its
linearised covariance is J diag(sigma^2) J^T with J the Jacobian of the fix with respect to the
bearing errors (ERRATA), equivalently (G^T W G)^-1 with G the gradients of the bearings with
respect to position and W = diag(1 / sigma^2).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
from scipy import special

from ..domains.pose import Pose
from ..kernels import bearing as kernels
from ..kernels import bearing_lanes
from ..protocol import Extent, KernelBinding, KernelContext, SceneSchema
from ..validate import BananagridError, BananagridWarning, real_array
from .base import RANGE_SDS, Model, check_n, check_rng
from .containment import containment, containment_radius
from .params import modelclass, param

__all__ = ["BearingFix", "bearing_to", "crossings", "two_bearing_variances", "MIN_CROSSING_DEG", "MAP_VARIANTS"]

#: Crossing angles below this (degrees) are refused: the lines are nearly parallel, the fix
#: lies far out along them and Walsh's linearisation (assumption 7) does not hold.
MIN_CROSSING_DEG = 2.0

#: Crossing angles below this (degrees) are accepted with a warning.
POOR_CROSSING_DEG = 20.0

MAP_VARIANTS = ("exact", "linear")

#: Bearing errors beyond this many sigmas are outside the sampler's support (mass < 1e-22).
SAMPLE_SIGMAS = 10.0
#: The sampler gives up when fewer than this fraction of its proposals were kept after
#: SAMPLE_PATIENCE proposals: the other stations' bearings then disagree with the best pair's
#: crossing by several sigmas, and rejection would run for hours (the map itself is fine).
SAMPLE_MIN_ACCEPTANCE = 1e-4
SAMPLE_PATIENCE = 1_000_000

#: Gauss-Newton iterations polishing the fix of three or more sensors (quadratic convergence).
MAX_ITERATIONS = 50
#: The global search for the fix of three or more sensors starts, besides every pair's line
#: crossing, at points along each bearing ray at these ranges in units of the stations' spread
#: D (6 per decade from 1e-6 D, a contact almost on a station, to 1e4 D, far beyond the
#: farthest): chi^2 is multimodal (a station near the contact swings its bearing through every
#: value within a few of its SDs of the contact), and every basin of a minimum that fits each
#: bearing within a few SDs reaches a ray near the contact's range.
START_RANGES = 10.0 ** (np.arange(-36, 25) / 6.0)
#: A start that comes within this many D of a station is sliding into it (along its bearing,
#: where the station's own residual is 0 and the others' fall): not a minimum, dropped.
INTO_STATION = 1e-9
#: A station whose likelihood lump (see :meth:`BearingFix.station_lumps`) is below exp(-72) of
#: the fix's Laplace mass is left out of the normaliser.
LUMP_DEPTH = 72.0
#: Levenberg-Marquardt iterations of each start of the global search.
SEARCH_ITERATIONS = 300
#: A start that wanders beyond this many D from the stations' centre is heading for a minimum
#: at infinity (bearings that only meet there): it is dropped.
RUNAWAY = 1e7

#: float32's unit roundoff: :meth:`BearingFix.density_bound` allows for a float32 kernel in
#: every term (a float64 kernel rounds 2^29 times less), so one bound serves both dtypes.
UNIT_ROUNDOFF = 2.0**-24
#: Seconds of one core a cell assumed by :meth:`BearingFix.work_estimate`: a fixed part and one a
#: station, about 10 times the exact variant's measured cost (8.9, 25 and 90 ns a cell with 2, 8 and
#: 32 stations, float64; float32 about half; the linear variant 2.5-6 ns; 2000 x 2000 cells, Intel
#: Xeon AVX-512, one thread).
SECONDS_PER_CELL = 3.0e-8
SECONDS_PER_STATION_CELL = 3.0e-8
#: Error of the kernel's float32 ``atan2_fast``, in units of UNIT_ROUNDOFF * pi (measured at
#: most 1.4 over 2e6 points spread over 12 decades and every quadrant; 16 leaves 11x of room).
ATAN2_ROUNDOFFS = 16.0
#: Relative margin of the bound for the kernel's exp (a few ulps in float32), its rounding of
#: a float64 result to float32, and this bound's own float64 arithmetic.
BOUND_MARGIN = 1e-5
#: Added to every bound: an exp whose result underflows may come out as a few float32
#: subnormals (2^-149 each), however small its argument.
UNDERFLOW_SLACK = 4.0 * 2.0**-149


def bearing_to(sensor, point) -> np.ndarray:
    """Bearing (radians clockwise from north, in (-pi, pi]) from ``sensor`` to ``point``."""
    sensor = np.asarray(sensor, dtype=float)
    point = np.asarray(point, dtype=float)
    d = point - sensor
    return np.arctan2(d[..., 0], d[..., 1])


def crossings(sensors, b1, b2):
    r"""Exact crossings of the bearing lines from ``sensors[0]`` at ``b1`` and ``sensors[1]``
    at ``b2`` (arrays, radians clockwise from north).

    .. math::  s_1 = \frac{d \times u_2}{u_1 \times u_2},\quad
               s_2 = \frac{d \times u_1}{u_1 \times u_2},\quad F = S_1 + s_1 u_1,

    Returns
    -------
    fx, fy : ndarray
        The crossing F (NaN or inf where the lines are parallel).
    kept : ndarray of bool
        A fix exists: the lines cross (finite s) in front of both stations (s1 > 0, s2 > 0).
    """
    sensors = np.asarray(sensors, dtype=float)
    u1x, u1y = np.sin(b1), np.cos(b1)
    u2x, u2y = np.sin(b2), np.cos(b2)
    dx, dy = sensors[1] - sensors[0]
    den = u1x * u2y - u1y * u2x
    with np.errstate(divide="ignore", invalid="ignore"):
        s1 = (dx * u2y - dy * u2x) / den
        s2 = (dx * u1y - dy * u1x) / den
        fx = sensors[0, 0] + s1 * u1x
        fy = sensors[0, 1] + s1 * u1y
    kept = np.isfinite(s1) & np.isfinite(s2) & (s1 > 0.0) & (s2 > 0.0)
    return fx, fy, kept


def two_bearing_variances(sensor1, sensor2, bearing1, bearing2, sigma1, sigma2):
    """Fixes and principal variances of many two-bearing geometries at once (broadcast).

    For each geometry the fix F is the crossing of the two bearing lines and the linearised
    covariance is C = (G^T W G)^-1 with rows g_i = (dy_i, -dx_i) / r_i^2 (the gradients of the
    bearings at F) and W = diag(1 / sigma_i^2); with two rows det(G) = sin(beta_1 - beta_2) /
    (r_1 r_2), and C's eigenvalues (v1 >= v2) are Walsh's v_g.

    Parameters
    ----------
    sensor1, sensor2 : array_like, shape (..., 2)
    bearing1, bearing2 : array_like
        Radians clockwise from north.
    sigma1, sigma2 : array_like
        Bearing error SDs, radians, > 0.

    Returns
    -------
    fix : ndarray, shape (..., 2)
    v1, v2 : ndarray
        Principal variances, m^2. Geometries without a fix in front of both sensors (or with
        parallel lines) give NaN.
    """
    s1 = np.asarray(sensor1, dtype=float)
    s2 = np.asarray(sensor2, dtype=float)
    b1, b2, sd1, sd2 = (np.asarray(v, dtype=float) for v in (bearing1, bearing2, sigma1, sigma2))
    if not all(np.isfinite(v).all() for v in (s1, s2, b1, b2, sd1, sd2)):
        raise BananagridError("two_bearing_variances: every sensor, bearing and sigma must be finite")
    if np.any(sd1 <= 0) or np.any(sd2 <= 0):
        raise BananagridError("two_bearing_variances: sigmas must be > 0")
    u1 = np.stack((np.sin(b1), np.cos(b1)), axis=-1)
    u2 = np.stack((np.sin(b2), np.cos(b2)), axis=-1)
    d = s2 - s1
    den = u1[..., 0] * u2[..., 1] - u1[..., 1] * u2[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        along1 = (d[..., 0] * u2[..., 1] - d[..., 1] * u2[..., 0]) / den
        along2 = (d[..., 0] * u1[..., 1] - d[..., 1] * u1[..., 0]) / den
        fix = s1 + along1[..., None] * u1
        r1, r2 = fix - s1, fix - s2
        g1 = np.stack((r1[..., 1], -r1[..., 0]), axis=-1) / np.sum(r1 * r1, axis=-1)[..., None]
        g2 = np.stack((r2[..., 1], -r2[..., 0]), axis=-1) / np.sum(r2 * r2, axis=-1)[..., None]
        # information I = G^T W G; C = I^-1 has eigenvalues 1 / (eigenvalues of I)
        w1, w2 = 1.0 / sd1**2, 1.0 / sd2**2
        ixx = w1 * g1[..., 0] ** 2 + w2 * g2[..., 0] ** 2
        iyy = w1 * g1[..., 1] ** 2 + w2 * g2[..., 1] ** 2
        ixy = w1 * g1[..., 0] * g1[..., 1] + w2 * g2[..., 0] * g2[..., 1]
        half_trace = 0.5 * (ixx + iyy)
        root = np.sqrt(0.25 * (ixx - iyy) ** 2 + ixy**2)
        big, det = half_trace + root, ixx * iyy - ixy**2
        v1 = 1.0 / (det / big)  # 1 / smallest eigenvalue of I (det / largest, no cancellation)
        v2 = 1.0 / big
    bad = ~(np.isfinite(along1) & np.isfinite(along2) & (along1 > 0) & (along2 > 0))
    v1, v2 = np.where(bad, np.nan, v1), np.where(bad, np.nan, v2)
    return fix, v1, v2


def _wrap(angle):
    """Angle difference wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(angle, dtype=float)))


def _circular_distance(angle):
    """|angle| wrapped to [0, pi] (float64; its rounding is far below the bound's slack)."""
    return np.abs(np.remainder(np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) - np.pi)


def _least_bearing_gaps(sensors, bearings, x0, x1, y0, y1) -> np.ndarray:
    """min over the closed rectangle [x0, x1] x [y0, y1] of the circular distance between the
    bearing from each sensor to the point and that sensor's observed bearing, shape (n,): exact.

    A sensor inside the rectangle (or on its edge) sees every bearing: 0. From a sensor outside,
    the rectangle (convex) fills an arc of bearings narrower than pi that holds the bearing of
    its centre theta_c and is spanned by its corners: relative to theta_c the corners' bearings
    lie in (-pi, pi) without wrap-around, their least A and greatest B bound the arc, and the
    distance from b to the arc is 0 inside it, else the nearer of its ends.
    """
    sx, sy = sensors[:, 0], sensors[:, 1]
    corner_x = np.array([x0, x1, x0, x1])
    corner_y = np.array([y0, y0, y1, y1])
    centre = np.arctan2(0.5 * (x0 + x1) - sx, 0.5 * (y0 + y1) - sy)
    corners = np.arctan2(corner_x[None, :] - sx[:, None], corner_y[None, :] - sy[:, None])
    relative = np.remainder(corners - centre[:, None] + np.pi, 2.0 * np.pi) - np.pi
    low, high = relative.min(axis=1), relative.max(axis=1)
    seen = np.remainder(bearings - centre + np.pi, 2.0 * np.pi) - np.pi
    gap = np.minimum(_circular_distance(seen - low), _circular_distance(seen - high))
    inside = (x0 <= sx) & (sx <= x1) & (y0 <= sy) & (sy <= y1)
    return np.where(inside | ((low <= seen) & (seen <= high)), 0.0, gap)


def _box_quadratic_min(a, b, c, x0, x1, y0, y1) -> float:
    """A lower bound, exact but for float64 rounding, of q(x, y) = a x^2 + 2 b x y + c y^2 over
    the box [x0, x1] x [y0, y1], for any symmetric (a, b; b, c), definite or not.

    An interior minimum of q is a critical point, a null vector of the form: the origin (where
    q = 0), or a line through it along which q = 0 and which reaches the boundary at that value;
    an indefinite form's only critical point is a saddle. So the minimum is the least of the
    boundary's and, where the box holds the origin, 0. On each edge q is a quadratic in one
    variable t, least at an end or at its vertex t* = -b s / (coefficient of t^2), clamped to the
    edge. Each candidate's value is lowered by 1e-14 of the sum of its terms' magnitudes, more
    than the rounding of the vertex and of the sum.
    """
    best = 0.0 if (x0 <= 0.0 <= x1 and y0 <= 0.0 <= y1) else math.inf
    # edges x = s (t = y, coefficient c) and y = s (t = x, coefficient a)
    for fixed_coef, free_coef, fixed_values, (lo, hi) in ((a, c, (x0, x1), (y0, y1)), (c, a, (y0, y1), (x0, x1))):
        for s in fixed_values:
            candidates = [lo, hi]
            if free_coef > 0.0:
                candidates.append(min(hi, max(lo, -b * s / free_coef)))
            for t in candidates:
                terms = (fixed_coef * s * s, 2.0 * b * s * t, free_coef * t * t)
                best = min(best, sum(terms) - 1e-14 * sum(abs(v) for v in terms))
    return best


def _misfit(sensors, bearings, inv_sigma, points):
    """Bearing residuals z_i = wrap(beta_i(P) - b_i) / sigma_i at each point, shape (m, n), and
    their gradients dz_i / dP = (dy, -dx) / (r^2 sigma_i), shape (m, n, 2) (inf on a station)."""
    d = points[:, None, :] - sensors[None, :, :]
    r2 = d[..., 0] ** 2 + d[..., 1] ** 2
    z = (np.remainder(np.arctan2(d[..., 0], d[..., 1]) - bearings + np.pi, 2.0 * np.pi) - np.pi) * inv_sigma
    with np.errstate(divide="ignore", invalid="ignore"):
        jac = np.stack((d[..., 1], -d[..., 0]), axis=-1) * (inv_sigma / r2)[..., None]
    return z, jac


def _chi2(sensors, bearings, inv_sigma, points) -> np.ndarray:
    """chi^2(P) = sum_i z_i^2 at each point, shape (m,)."""
    z = (np.remainder(np.arctan2(points[:, None, 0] - sensors[None, :, 0], points[:, None, 1] - sensors[None, :, 1])
                      - bearings + np.pi, 2.0 * np.pi) - np.pi) * inv_sigma
    return np.einsum("mn,mn->m", z, z)


def _global_minimum(sensors, bearings, sigmas):
    """The global minimum of chi^2(P) = sum_i (wrap(beta_i(P) - b_i) / sigma_i)^2 over the plane
    less the stations (the bearings' likelihood's highest maximum), or None if every start runs
    off to infinity or into a station.

    chi^2 has no value at a station (the bearing from it is undefined); approached along the
    station's bearing it tends to the others' misfit there, which may be lower than at any
    point off the stations (the other bearings point at the station): that supremum of the
    likelihood is no maximum and has no linearisation, so starts that slide into a station are
    dropped, and :meth:`BearingFix.station_lumps` accounts for its mass instead.

    chi^2 is multimodal: near a station its bearing swings through every value, so each station
    within a few of its cross-range SDs of the contact adds basins, and the least-squares point
    of the lines can sit in a basin whose chi^2 is a hundred times the contact's. So the search
    starts everywhere a minimum can hide: at each pair's line crossing (ahead of or behind the
    stations), at the lines' least-squares point, and along each bearing ray at ``START_RANGES``
    (log-spaced, in units of the stations' spread D), and refines every start at once by
    Levenberg-Marquardt (a step is kept only if chi^2 falls, so no start climbs out of its
    basin). The work is done about the stations' centre in units of D (a power of two, exact),
    so any scale of units gives the same starts; the caller polishes the best point in metres.
    """
    centre = sensors.mean(axis=0)
    spread = float(np.max(np.hypot(*(sensors - centre).T)))
    scale = math.ldexp(1.0, -math.frexp(spread)[1])  # 1 / D rounded to a power of two
    s = (sensors - centre) * scale
    inv_sigma = 1.0 / sigmas
    u = np.column_stack((np.sin(bearings), np.cos(bearings)))
    n = len(s)
    starts = [(s[:, None, :] + START_RANGES[None, :, None] * u[:, None, :]).reshape(-1, 2)]
    i, j = np.triu_indices(n, k=1)
    den = u[i, 0] * u[j, 1] - u[i, 1] * u[j, 0]
    dx, dy = (s[j] - s[i]).T
    with np.errstate(divide="ignore", invalid="ignore"):
        along = (dx * u[j, 1] - dy * u[j, 0]) / den
    starts.append((s[i] + along[:, None] * u[i])[np.isfinite(along)])
    a = np.column_stack((u[:, 1], -u[:, 0]))
    starts.append(np.linalg.lstsq(a, u[:, 1] * s[:, 0] - u[:, 0] * s[:, 1], rcond=None)[0][None, :])
    points = np.concatenate(starts)
    points = points[np.isfinite(points).all(axis=1) & (np.hypot(*points.T) < RUNAWAY)]
    chi2 = _chi2(s, bearings, inv_sigma, points)
    chi2[~np.isfinite(chi2)] = np.inf
    damping = np.full(len(points), 1e-3)
    active = np.isfinite(chi2)
    eye = np.eye(2)
    for _ in range(SEARCH_ITERATIONS):
        k = np.flatnonzero(active)
        if k.size == 0:
            break
        z, jac = _misfit(s, bearings, inv_sigma, points[k])
        h = np.einsum("mni,mnj->mij", jac, jac)
        grad = np.einsum("mni,mn->mi", jac, z)
        # Marquardt's damping scales the diagonal; the trace term keeps a singular h solvable
        lhs = h + damping[k, None, None] * (h * eye + 1e-12 * np.trace(h, axis1=1, axis2=2)[:, None, None] * eye)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            ok = np.isfinite(lhs).all(axis=(1, 2)) & np.isfinite(grad).all(axis=1)
            det = lhs[:, 0, 0] * lhs[:, 1, 1] - lhs[:, 0, 1] * lhs[:, 1, 0]
            step = np.column_stack((lhs[:, 0, 1] * grad[:, 1] - lhs[:, 1, 1] * grad[:, 0],
                                    lhs[:, 1, 0] * grad[:, 0] - lhs[:, 0, 0] * grad[:, 1])) / det[:, None]
            trial = points[k] + step
            ok &= np.isfinite(trial).all(axis=1)
            value = np.full(k.size, np.inf)
            value[ok] = _chi2(s, bearings, inv_sigma, trial[ok])
        better = value < chi2[k]
        points[k[better]] = trial[better]
        chi2[k[better]] = value[better]
        damping[k] = np.where(better, damping[k] * 0.2, damping[k] * 10.0)
        near = np.hypot(points[k, None, 0] - s[None, :, 0], points[k, None, 1] - s[None, :, 1]).min(axis=1)
        small = np.hypot(*step.T) <= 1e-10 * near
        away = (np.hypot(*points[k].T) >= RUNAWAY) | (near <= INTO_STATION)
        chi2[k[away]] = np.inf
        # done: a tiny step taken, no step that lowers chi^2 however short, or gone to infinity
        active[k[(better & small) | (damping[k] > 1e16) | away | ~np.isfinite(chi2[k])]] = False
    best = int(np.argmin(chi2))
    if not np.isfinite(chi2[best]):
        return None
    return points[best] / scale + centre


def _as_array(name: str, value, shape_text: str, ndim: int) -> np.ndarray:
    array = real_array(name, value, f"{shape_text} of numbers")  # a copy: frozen below, not the caller's
    if array.ndim != ndim or (ndim == 2 and array.shape[1] != 2):
        raise BananagridError(f"{name}: shape {array.shape}, expected {shape_text}")
    if not np.isfinite(array).all():
        raise BananagridError(f"{name} = {value!r}: every value must be finite")
    return array


#: Bearing SDs (rad): float64 bearings and the fix computed from them carry rounding of about
#: 1e-15 rad, which an SD below 1e-10 rad would count as misfit ((1e-15 / sigma)^2 in chi2_min);
#: the upper bound keeps 1 / sigma^2 a normal float64 number.
MIN_SIGMA, MAX_SIGMA = 1e-10, 1e150
#: Sensor coordinates (m) stay within this, so that squared ranges are normal float64 numbers.
MAX_POSITION = 1e150
#: Range of a station's cross-range SD at the fix, r sigma (m), so that the information matrix's
#: determinant, ~ (r sigma)^-4, stays a normal float64 number.
MIN_CROSS_SD, MAX_CROSS_SD = 1e-75, 1e75


def _sensor_entries(model, sensors) -> dict:
    return {k: float(v) for i, s in enumerate(sensors) for k, v in ((f"sensor{i}_x", s[0]), (f"sensor{i}_y", s[1]))}


@modelclass(eq=False)
class BearingFix(Model):
    """A position fix from two or more bearings with independent normal errors.

    Raises
    ------
    BananagridError
        For bad shapes or values, coincident sensors, bearing lines that cross behind a sensor
        or cross at less than ``MIN_CROSSING_DEG``. A crossing under ``POOR_CROSSING_DEG``
        warns: the linearised covariance is then optimistic (see the validation table).
    """

    sensors: np.ndarray = param(
        type="pairs", unit="m", py="array_like, shape (n, 2)", plain=_sensor_entries,
        domain="at least 2, within +-1e150, no two coincident",
        doc="Sensor positions (x east, y north).")
    bearings: np.ndarray = param(
        type="numbers", unit="rad", alias="deg", bearing_at="sensors", py="array_like, shape (n,)",
        plain=lambda model, bearings: {f"bearing{i}": float(b) for i, b in enumerate(bearings)},
        domain="one per sensor, finite, clockwise from north (true north in a geographic scene)",
        doc="Observed bearings to the contact, clockwise from north.")
    sigmas: np.ndarray = param(
        type="numbers", unit="rad", alias="deg", py="array_like, shape (n,)",
        plain=lambda model, sigmas: {f"sigma{i}": float(sd) for i, sd in enumerate(sigmas)},
        domain="one per sensor, in [1e-10, 1e150]",
        doc="Standard deviations of the bearing errors.")
    variant: str = param(
        "exact", type="choice", choices=MAP_VARIANTS, py='{"exact", "linear"}',
        domain='`"exact"` (the likelihood under a flat prior), `"linear"` (the linearised normal)',
        doc="The presence map that ``rasterise`` and ``pdf`` compute: the bearings' likelihood under a flat "
            "prior (the true, non-elliptical shape; divided by the linearised normaliser, so it integrates to "
            "about one and normalising over a grid gives the posterior), or the normal law of the linearised "
            "fix, N(fix, covariance).")

    kind = "bearing_fix"
    #: float32 agreement with float64 where the density exceeds 1e-6 of its peak.
    float32_rtol = 1e-4
    scene = SceneSchema(
        summary="the presence map of a fix from two or more bearings (Walsh)",
        options={"bearing_validation": "the entity `validation`, a table of where Walsh's linearisation holds"},
    )

    def __post_init__(self):
        if self.variant not in MAP_VARIANTS:
            raise BananagridError(f"variant = {self.variant!r}: must be one of {', '.join(MAP_VARIANTS)}")
        sensors = _as_array("sensors", self.sensors, "an (n, 2) array", 2)
        bearings = _as_array("bearings", self.bearings, "an (n,) array", 1)
        sigmas = _as_array("sigmas", self.sigmas, "an (n,) array", 1)
        n = len(sensors)
        if n < 2:
            raise BananagridError(f"sensors: {n} given, a fix needs at least 2")
        if len(bearings) != n or len(sigmas) != n:
            raise BananagridError(
                f"sensors, bearings, sigmas: lengths {n}, {len(bearings)}, {len(sigmas)} must match"
            )
        bad = np.flatnonzero(sigmas <= 0)
        if bad.size:
            raise BananagridError(f"sigmas[{bad[0]}] = {float(sigmas[bad[0]])!r}: must be > 0")
        # weights 1 / sigma^2 and squared ranges must stay normal float64 numbers
        bad = np.flatnonzero(~((sigmas >= MIN_SIGMA) & (sigmas <= MAX_SIGMA)))
        if bad.size:
            raise BananagridError(f"sigmas[{bad[0]}] = {float(sigmas[bad[0]])!r}: must be in [{MIN_SIGMA:g}, {MAX_SIGMA:g}] rad")
        far = np.argwhere(~(np.abs(sensors) <= MAX_POSITION))
        if far.size:
            i, k = far[0]
            raise BananagridError(f"sensors[{i}][{k}] = {float(sensors[i, k])!r}: must be within +-{MAX_POSITION:g} m")
        for i in range(n):
            for j in range(i + 1, n):
                if np.hypot(*(sensors[i] - sensors[j])) <= 1e-9 * max(1.0, np.abs(sensors).max()):
                    raise BananagridError(f"sensors {i} and {j} coincide at {tuple(sensors[i])}: no baseline")
        for name, value in (("sensors", sensors), ("bearings", bearings), ("sigmas", sigmas)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        self._check_crossing()
        fix, interior, at_station = self._solve()
        object.__setattr__(self, "_fix", fix)
        object.__setattr__(self, "_interior", interior)
        object.__setattr__(self, "_at_station", at_station)
        self._check_in_front()
        self._check_scales()

    # -- geometry ------------------------------------------------------------------------------

    @property
    def directions(self) -> np.ndarray:
        """Unit vectors of the observed bearings, shape (n, 2)."""
        return np.column_stack((np.sin(self.bearings), np.cos(self.bearings)))

    @property
    def fix(self) -> np.ndarray:
        """The fix (x, y), metres: where the likelihood is highest. The crossing (2 sensors) or
        the global maximum of the likelihood off the stations (the global minimum of chi^2); or,
        where the other bearings point at a station and the likelihood rises higher towards it
        along its bearing (:attr:`at_station`), the mean point of that lump on the bearing."""
        return self._fix.copy()

    @property
    def at_station(self) -> int | None:
        """The station whose lump of likelihood (:meth:`station_lumps`) the fix stands for, or
        None where the fix is a maximum of the likelihood off the stations."""
        return self._at_station

    def _check_crossing(self) -> None:
        # the best-crossing pair decides whether any fix is possible
        i, j = self._best_pair()
        angle = math.degrees(math.asin(min(1.0, abs(math.sin(self.bearings[i] - self.bearings[j])))))
        if angle < MIN_CROSSING_DEG:
            raise BananagridError(
                f"bearings: the lines cross at {angle:.3g} deg, below {MIN_CROSSING_DEG} deg: "
                "nearly parallel, no usable fix"
            )
        if angle < POOR_CROSSING_DEG:
            warnings.warn(
                f"bearings cross at {angle:.3g} deg (< {POOR_CROSSING_DEG} deg): the linearised "
                "covariance and containment are optimistic", BananagridWarning, stacklevel=5,
            )

    def _solve(self) -> tuple[np.ndarray, np.ndarray | None, int | None]:
        """(fix, the likelihood's best maximum off the stations or None, the station whose lump
        is the fix or None).

        Two sensors: the crossing of the lines (chi^2 = 0 there). More: the global minimum of
        chi^2 off the stations (:func:`_global_minimum`), polished by Gauss-Newton in world
        metres; but where the likelihood rises higher towards a station (the limit c_k of a
        lump, :meth:`station_lumps`, is below that minimum), or no such minimum exists, the
        fix is the highest lump's mean point, S_k + s_k u_k, on station k's bearing.
        """
        u = self.directions
        if len(u) == 2:
            # each line: cross(u_i, P - S_i) = 0, i.e. u_y P_x - u_x P_y = u_y S_x - u_x S_y
            a = np.column_stack((u[:, 1], -u[:, 0]))
            rhs = u[:, 1] * self.sensors[:, 0] - u[:, 0] * self.sensors[:, 1]
            point = np.linalg.lstsq(a, rhs, rcond=None)[0]
            return point, point, None  # chi^2 = 0 there: no station's limit is lower
        point = _global_minimum(self.sensors, self.bearings, self.sigmas)
        if point is not None:
            point = self._polish(point)
        highest = min(self.station_lumps(), key=lambda lump: lump[1], default=None)
        if highest is not None:
            k, limit, _, mean_range = highest
            least = math.inf
            if point is not None:
                least = _chi2(self.sensors, self.bearings, 1.0 / self.sigmas, point[None, :])[0]
            if limit < least:
                return self.sensors[k] + mean_range * u[k], point, k
        if point is None:
            raise BananagridError(
                f"bearings: the lines of the {len(u)} sensors do not meet near one point (the "
                "bearings' misfit falls without end away from the stations): check the bearings, "
                "sensors and their order"
            )
        return point, point, None

    def _polish(self, point) -> np.ndarray:
        """Gauss-Newton from the search's point to full precision in world coordinates (the
        search works about the stations' centre); a step is kept only if chi^2 does not grow
        and it is a polish, under 1e-6 of the distance to the nearest station (where chi^2 only
        falls towards infinity, a full step would run off along the valley)."""
        weights = 1.0 / self.sigmas**2
        best = _chi2(self.sensors, self.bearings, 1.0 / self.sigmas, point[None, :])[0]
        for _ in range(MAX_ITERATIONS):
            residual = _wrap(bearing_to(self.sensors, point) - self.bearings)
            g = self._bearing_gradients(point)
            try:
                step = np.linalg.solve(g.T @ (weights[:, None] * g), -(g.T @ (weights * residual)))
            except np.linalg.LinAlgError:
                break
            trial = point + step
            value = _chi2(self.sensors, self.bearings, 1.0 / self.sigmas, trial[None, :])[0]
            near = np.hypot(*(point - self.sensors).T).min()
            if not (np.isfinite(step).all() and value <= best and np.hypot(*step) <= 1e-6 * near):
                break
            point, best = trial, value
            if np.hypot(*step) <= 1e-15 * max(np.abs(point).max(), np.hypot(*(point - self.sensors).T).min()):
                break
        return point

    def _check_scales(self) -> None:
        """Each station's cross-range SD at the fix, r_i sigma_i, between MIN_CROSS_SD and
        MAX_CROSS_SD metres: the information matrix's determinant is a sum of products of four
        of their inverses, which must stay a normal float64 number."""
        cross = np.hypot(*(self._fix - self.sensors).T) * self.sigmas
        bad = np.flatnonzero(~((cross >= MIN_CROSS_SD) & (cross <= MAX_CROSS_SD)))
        if bad.size:
            i = bad[0]
            raise BananagridError(
                f"sigmas[{i}] = {float(self.sigmas[i])!r}: at the fix's range "
                f"{float(np.hypot(*(self._fix - self.sensors[i]))):.6g} m the cross-range SD is {float(cross[i]):.3g} m; "
                f"it must be between {MIN_CROSS_SD:g} and {MAX_CROSS_SD:g} m (use units that keep it there)"
            )

    def _check_in_front(self) -> None:
        """Two sensors whose lines cross behind one have no fix: refused. With more, the fix is
        the likelihood's maximum, which may lie behind a station whose bearing is off by more
        than 90 deg there: a warning names it."""
        along = np.einsum("ij,ij->i", self._fix - self.sensors, self.directions)
        behind = np.flatnonzero(along <= 0)
        if behind.size:
            i = behind[0]
            text = (f"bearings[{i}] = {float(self.bearings[i])!r}: the fix {tuple(np.round(self._fix, 3))} lies "
                    f"behind sensor {i}")
            if len(self.sensors) == 2:
                raise BananagridError(text + " (the lines cross on the far side of the station)")
            warnings.warn(text + " (its bearing is off by more than 90 deg at the likelihood's maximum): "
                          "check it", BananagridWarning, stacklevel=5)

    def _bearing_gradients(self, point) -> np.ndarray:
        """d bearing_i / d(x, y) at ``point``: (dy, -dx) / r^2, shape (n, 2)."""
        d = np.asarray(point, dtype=float) - self.sensors
        r2 = np.einsum("ij,ij->i", d, d)
        return np.column_stack((d[:, 1], -d[:, 0])) / r2[:, None]

    # -- linearised error --------------------------------------------------------------------

    @property
    def chi2_min(self) -> float:
        """sum_i (wrap(beta_i(fix) - b_i) / sigma_i)^2: 0 for two sensors (the lines cross at the
        fix), for more the weighted misfit at the fix (the least over the plane off the
        stations, unless the fix is a station's lump, :attr:`at_station`)."""
        if len(self.sensors) == 2 and self._at_station is None:
            return 0.0  # exactly: the fix is the lines' crossing (computed, it leaves rounding)
        residual = _wrap(bearing_to(self.sensors, self._fix) - self.bearings) / self.sigmas
        return float(np.sum(residual**2))

    def station_lumps(self) -> list[tuple[int, float, float, float]]:
        r"""The stations at which the likelihood has a supremum of its own: (k, c_k, log m_k,
        s_k) for each station k that the likelihood rises towards along its own bearing.

        Close to station k its bearing is undefined, and approached along that bearing chi^2
        tends to the other stations' misfit there, c_k = sum_{i != k} z_i(S_k)^2. Where that
        misfit falls towards the station (slope a_k > 0 of chi^2 along the ray at s = 0+), the
        likelihood has a lump at the station that no point off the stations reaches, nor any
        linearisation; in polar coordinates (s, phi) about the station, chi^2 ~ c_k + a_k s +
        b_k s^2 / 2 + (phi / sigma_k)^2 (b_k the Gauss-Newton curvature along the ray), so its
        mass is

        .. math::  m_k = e^{-c_k / 2} \sqrt{2 \pi} \sigma_k \int_0^\infty s\,
                   e^{-(a_k s + b_k s^2 / 2) / 2} ds

        and s_k is its mean range from the station. The exact map's normaliser adds the lumps
        within exp(-``LUMP_DEPTH``) of the largest mass, so that the map stays finite and its
        mass near one where the other bearings point at a station (a contact next to it).
        """
        out = []
        n = len(self.sensors)
        for k in range(n):
            others = np.arange(n) != k
            d = self.sensors[k] - self.sensors[others]
            sigmas = self.sigmas[others]
            r2 = np.einsum("ij,ij->i", d, d)
            z = _wrap(np.arctan2(d[:, 0], d[:, 1]) - self.bearings[others]) / sigmas
            slope = (d[:, 1] * self.directions[k, 0] - d[:, 0] * self.directions[k, 1]) / (r2 * sigmas)
            a, b = 2.0 * float(np.dot(z, slope)), 2.0 * float(np.dot(slope, slope))
            if not a > 0.0:
                continue
            # with t = alpha s: I_m = int_0^inf t^m exp(-t - g t^2) dt, alpha = a / 2, g = b / a^2;
            # I_0 = sqrt(pi) x erfcx(x) (x = 1 / (2 sqrt g)), and integrating by parts
            # I_0 + 2 g I_1 = 1, I_1 + 2 g I_2 = I_0; their Taylor series where those cancel
            alpha, g = 0.5 * a, b / (a * a)
            if g < 1e-3:
                i1 = 1.0 - g * (6.0 - g * (60.0 - 840.0 * g))
                i2 = 2.0 - g * (24.0 - g * (360.0 - 6720.0 * g))
            else:
                x = 0.5 / math.sqrt(g)
                i0 = math.sqrt(math.pi) * x * float(special.erfcx(x))
                i1 = (1.0 - i0) / (2.0 * g)
                i2 = (i0 - i1) / (2.0 * g)
            c = float(np.dot(z, z))
            log_mass = -0.5 * c + math.log(math.sqrt(2.0 * math.pi) * self.sigmas[k] * i1) - 2.0 * math.log(alpha)
            out.append((k, c, log_mass, i2 / (alpha * i1)))
        return out

    def _log_mass(self) -> float:
        """log of the exact map's normaliser: the Laplace mass of the likelihood at its best
        maximum off the stations, L(P) 2 pi sqrt(det C(P)), and the stations' lumps
        (:meth:`station_lumps`), those below exp(-LUMP_DEPTH) of the largest left out."""
        terms = [log_lump for _, _, log_lump, _ in self.station_lumps()]
        if self._interior is not None:
            _, det = self._information(self._interior)
            chi2 = _chi2(self.sensors, self.bearings, 1.0 / self.sigmas, self._interior[None, :])[0]
            terms.append(-0.5 * (chi2 if len(self.sensors) > 2 else 0.0) + math.log(2.0 * math.pi) - 0.5 * math.log(det))
        top = max(terms)
        return float(np.logaddexp.reduce([t for t in terms if t > top - LUMP_DEPTH]))

    def _information(self, point=None) -> tuple[np.ndarray, float]:
        """The fix's information matrix I = G^T W G = sum_i w_i g_i g_i^T (w_i = 1 / sigma_i^2,
        g_i the bearing gradients) and its determinant by the Cauchy-Binet formula,
        det I = sum_{i<j} w_i w_j (g_i x g_j)^2: a sum of non-negative terms, so it keeps full
        relative precision where a_11 a_22 - a_12^2 would cancel (stations whose accuracies
        differ by many orders of magnitude)."""
        g = self._bearing_gradients(self._fix if point is None else point)
        w = 1.0 / self.sigmas**2
        info = g.T @ (g * w[:, None])
        cross = g[:, None, 0] * g[None, :, 1] - g[:, None, 1] * g[None, :, 0]
        pairs = np.triu(np.outer(w, w) * cross**2, k=1)
        return info, float(pairs.sum())

    @property
    def covariance(self) -> np.ndarray:
        """Linearised covariance of the fix, (G^T W G)^-1 = J diag(sigma^2) J^T, m^2: the
        information matrix's adjugate over its Cauchy-Binet determinant."""
        info, det = self._information()
        return np.array([[info[1, 1], -info[0, 1]], [-info[0, 1], info[0, 0]]]) / det

    def _information_eigen(self) -> tuple[float, float, float]:
        """The information matrix's eigenvalues (largest, smallest) and the angle from +x of the
        largest's eigenvector, in closed form: the largest is half the trace plus a root of
        squares (no cancellation), the smallest the Cauchy-Binet determinant over it. An
        eigensolver on the covariance loses its smaller eigenvalue (it even came out negative)
        where the stations' cross-range SDs differ by 1e30."""
        info, det = self._information()
        a, b, c = float(info[0, 0]), float(info[0, 1]), float(info[1, 1])
        big = 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)
        return big, det / big, 0.5 * math.atan2(2.0 * b, a - c)

    @property
    def principal_variances(self) -> tuple[float, float]:
        """(v1, v2): the covariance's eigenvalues, largest first (Walsh's v_g), m^2: the
        inverses of the information matrix's."""
        big, small, _ = self._information_eigen()
        return 1.0 / small, 1.0 / big

    def ellipse(self, k: float = 1.0) -> dict:
        """The k-sigma error ellipse: semi-axes (m) and the major axis' bearing (radians from
        north). It holds probability 1 - exp(-k^2 / 2) of the linearised law."""
        if not (isinstance(k, (int, float)) and math.isfinite(k) and k > 0):
            raise BananagridError(f"k = {k!r}: must be a finite number > 0")
        v1, v2 = self.principal_variances
        # the major axis is perpendicular to the information's largest eigenvector (angle
        # phi from +x): at phi + pi / 2 from +x, a bearing of -phi from north
        phi = self._information_eigen()[2]
        return {
            "centre": self.fix,
            "semi_major": k * math.sqrt(v1),
            "semi_minor": k * math.sqrt(v2),
            "bearing": (-phi) % math.pi,
            "probability": 1.0 - math.exp(-0.5 * k * k),
        }

    def containment(self, R, method: str = "exact", tol: float = 1e-12):
        """Probability that the contact lies within ``R`` (m, broadcast) of the fix under the
        linearised law: P(v1 t1^2 + v2 t2^2 <= R^2), Walsh's "Evaluation of Probability"
        (Robbins-Pitman series corrected per ERRATA, or the exact quadrature)."""
        v1, v2 = self.principal_variances
        return containment(R, v1, v2, method=method, tol=tol)

    def radius(self, p):
        """Radius (m) holding probability ``p`` (broadcast): R50 is the CEP; R90, R95."""
        v1, v2 = self.principal_variances
        return containment_radius(p, v1, v2)

    # -- maps ---------------------------------------------------------------------------------

    def with_variant(self, variant: str) -> "BearingFix":
        """The same fix with the other presence map."""
        return replace(self, variant=variant)

    def kernel_parameters(self) -> dict:
        """The bearing kernels' parameters (``kernels/bearing.py``'s ``BEARING`` struct, float64):
        log_norm, fix_x, fix_y, p_xx, p_ratio, det_ratio, and ``sensors`` (one row (x, y,
        bearing, 1 / sigma) each)."""
        precision, det = self._information()  # the precision is the information matrix itself
        log_norm = 0.5 * math.log(det) - math.log(2.0 * math.pi)  # -log(2 pi sqrt(det C))
        if self.variant == "exact":
            # Laplace normaliser of the likelihood: L(fix) 2 pi sqrt(det C) (with three or more
            # bearings they do not all pass through the fix, L(fix) = exp(-chi2_min / 2) < 1),
            # plus the lumps at stations the other bearings point at
            log_norm = -self._log_mass()
        # the linear form as p_xx (dx + k dy)^2 + m dy^2 (k = p_xy / p_xx, m = det p / p_xx, the
        # Cauchy-Binet determinant): two non-negative squares, finite or +inf however far the point
        p_xx = float(precision[0, 0])
        fix_x, fix_y = (float(v) for v in self._fix)
        return {"log_norm": log_norm, "fix_x": fix_x, "fix_y": fix_y, "p_xx": p_xx,
                "p_ratio": float(precision[0, 1]) / p_xx, "det_ratio": det / p_xx,
                "sensors": np.column_stack((self.sensors, self.bearings, 1.0 / self.sigmas))}

    def parameters(self) -> dict:
        """Plain-data parameters for provenance and recordings: the declared ones and the fix."""
        fix_x, fix_y = (float(v) for v in self._fix)
        return {**super().parameters(), "fix_x": fix_x, "fix_y": fix_y}

    def bind(self, ctx: KernelContext, extent: Extent, *, grid: bool = False) -> KernelBinding:
        """The bearing kernels (``kernels/bearing.py``) of ``variant``; on the CPU their lane twins."""
        return self.bind_once(ctx, lambda: self._binding(ctx))

    def _binding(self, ctx: KernelContext) -> KernelBinding:
        fields = self.kernel_parameters()
        sensors = ctx.array(fields.pop("sensors"), dtype=ctx.vector(4))
        params = ctx.struct(kernels.BEARING, **fields, sensors=sensors,
                            variant=kernels.EXACT if self.variant == "exact" else kernels.LINEAR)
        # on the CPU a vector of cells or points at a time (kernels/bearing_lanes.py)
        return KernelBinding(bearing_lanes.KERNELS if ctx.device == "cpu" else kernels.KERNELS, params,
                             {"variant": self.variant})

    def _bound_terms(self) -> dict:
        """What :meth:`density_bound` needs of the kernel's parameters, computed once per model:
        each taken as the kernel may see it, from the float64 array or its float32 rounding."""
        cached = self.__dict__.get("_density_bound_terms")
        if cached is not None:
            return cached
        fields = self.kernel_parameters()
        precision, _ = self._information()
        log_norm, inv_sigma = fields["log_norm"], fields["sensors"][:, 3]
        bearings = self.bearings
        n = len(self.sensors)
        terms = {
            "log_norm": float(max(log_norm, float(np.float32(log_norm)))),
            # the kernel's log-density: n + 1 terms summed, each z^2 from two rounded products
            "log_roundoffs": (2 * n + 8) * UNIT_ROUNDOFF,
            "inv_sigma": np.minimum(inv_sigma, inv_sigma.astype(np.float32).astype(np.float64)),
            # an upper bound of the kernel's error in wrap(beta - b): atan2_fast, the bearing's
            # float32 rounding, the subtraction, and k 2 pi in wrap_angle (|k| <= |b| / 2 pi + 2)
            "angle_slack": (UNIT_ROUNDOFF * (ATAN2_ROUNDOFFS * math.pi + 8.0 * (2.0 * math.pi + np.abs(bearings)))
                            + np.abs(bearings.astype(np.float32).astype(np.float64) - bearings)),
            # sensors and the fix, whose float32 rounding moves the point the kernel sees
            "scale": float(max(np.abs(self.sensors).max(), np.abs(self._fix).max())),
            # the linear map's C^-1 (the kernel holds it as p_xx, p_xy / p_xx, det / p_xx)
            "precision": (float(precision[0, 0]), float(precision[0, 1]), float(precision[1, 1])),
        }
        self.__dict__["_density_bound_terms"] = terms  # a frozen dataclass: its __dict__ caches
        return terms

    def work_estimate(self, cells: int, extent) -> float:
        """``SECONDS_PER_CELL`` plus ``SECONDS_PER_STATION_CELL`` for each station, a cell: the
        density sums a term per bearing (:meth:`bananagrid.protocol.DensityModel.work_estimate`)."""
        return float(cells) * (SECONDS_PER_CELL + SECONDS_PER_STATION_CELL * len(self.sensors))

    def density_bound(self, x0: float, x1: float, y0: float, y1: float) -> float:
        r"""A proved upper bound of the density the grid kernel computes, in float32 or float64,
        anywhere in the closed rectangle [x0, x1] x [y0, y1] (world metres)
        (:meth:`bananagrid.protocol.DensityModel.density_bound`).

        The kernel (``kernels/bearing.py``) computes exp(log_norm - q / 2) with

        .. math::  q_{exact} = \sum_i z_i^2,\quad z_i = \mathrm{wrap}(\beta_i(P) - b_i) / \sigma_i,
                   \qquad q_{linear} = (P - F)^T C^{-1} (P - F).

        Rounding first: the offsets P - S_i (or P - F) the kernel forms from float32 coordinates
        are the exact offsets of a point within 4 u (max(|x|, |y|) + max(|S_i|, |F|)) of P in each
        coordinate, u = 2^-24, so the rectangle is widened by that; every other rounding
        (atan2_fast, wrap_angle, the sums, the parameters' float32 values) is bounded in u and
        taken off q or added to log_norm. float64 kernels round less, so the bound holds for both.

        exact: each z_i^2 is at least ((g_i - eps_i)_+ / sigma_i)^2, g_i the least circular
        distance from b_i to the bearings of the widened rectangle seen from sensor i (exact: an
        arc spanned by the corners, or every bearing if the sensor is inside), eps_i the bearing
        rounding; the sum of these minima bounds the minimum of the sum. A sensor inside the
        rectangle contributes nothing, and the bound stays finite (at most the peak, exp(log_norm)).

        linear: the kernel computes q = 4 [p_xx u^2 + m (dy/2)^2], u = dx/2 + k dy/2, from k =
        p_xy / p_xx and m = det / p_xx rounded to the kernel's dtype. With p_xx k^2 <= p_yy and
        2 |u k dy/2| <= u^2 + (k dy/2)^2, the parameters' rounding and the seven of q take at most
        18.5 u (p_xx dx^2 + p_yy dy^2) off it (as 2 |p_xy dx dy| <= p_xx dx^2 + p_yy dy^2, q
        itself is at most twice that), within 2 gamma (p_xx dx^2 + p_yy dy^2), gamma = 16 u; so q
        is at least the form with p_xx, p_yy scaled by (1 - 2 gamma), minimised exactly over the
        widened box about the fix.

        The result, times 1 + ``BOUND_MARGIN`` plus ``UNDERFLOW_SLACK``, is never 0 (the kernel
        computes no exact zeros but by underflow); ``math.inf`` only if the bound would overflow.
        A rectangle with an infinite side gets the bound over the whole plane.

        Raises
        ------
        BananagridError
            For a NaN bound or x1 < x0 or y1 < y0.
        """
        x0, x1, y0, y1 = (float(v) for v in (x0, x1, y0, y1))
        if not (x0 <= x1 and y0 <= y1):
            raise BananagridError(f"density_bound: rectangle [{x0}, {x1}] x [{y0}, {y1}] must have x0 <= x1, y0 <= y1")
        terms = self._bound_terms()
        finite = all(math.isfinite(v) for v in (x0, x1, y0, y1))
        if finite:
            reach = max(abs(x0), abs(x1), abs(y0), abs(y1))
            widen = 4.0 * UNIT_ROUNDOFF * (reach + terms["scale"]) + 1e-30
            x0, x1, y0, y1 = x0 - widen, x1 + widen, y0 - widen, y1 + widen
        log_norm = terms["log_norm"]
        rounding = terms["log_roundoffs"]
        if self.variant == "exact":
            if finite:
                gaps = _least_bearing_gaps(self.sensors, self.bearings, x0, x1, y0, y1)
                z = np.maximum(gaps - terms["angle_slack"], 0.0) * terms["inv_sigma"]
                q = float(np.dot(z, z))
            else:
                q = 0.0
        else:
            p_xx, p_xy, p_yy = terms["precision"]
            shrink = 1.0 - 2.0 * 16.0 * UNIT_ROUNDOFF  # gamma = 16 u >= 18.5 u / 2 (see above)
            if finite:
                fx, fy = self._fix
                q = _box_quadratic_min(p_xx * shrink, p_xy, p_yy * shrink, x0 - fx, x1 - fx, y0 - fy, y1 - fy)
            else:
                definite = (p_xx * shrink) * (p_yy * shrink) >= p_xy * p_xy
                q = 0.0 if definite else -math.inf
        # q enters scaled by 1 -+ rounding, whichever is the smaller -q / 2
        log_bound = log_norm + rounding * abs(log_norm) - 0.5 * q * (1.0 - math.copysign(rounding, q))
        if not log_bound < 700.0:
            return math.inf
        return math.exp(log_bound) * (1.0 + BOUND_MARGIN) + UNDERFLOW_SLACK

    # -- scales (polar lattices and rays) ------------------------------------------------------

    def polar_scales(self, origin=(0.0, 0.0)) -> tuple[float, float]:
        """``sqrt(v2)`` with v2 the smallest principal variance of the fix, and that divided by
        the distance from ``origin`` to the fix (2 pi at the fix)."""
        radial = math.sqrt(self.principal_variances[1])
        distance = math.hypot(*(self.fix - np.asarray(origin, dtype=float)))
        return radial, (radial / distance if distance > 0.0 else 2.0 * math.pi)

    def feature_scale(self) -> float:
        """``sqrt(v2)``: the fix's narrowest SD."""
        return math.sqrt(self.principal_variances[1])

    def radial_extent(self, pose: Pose) -> tuple[float, float]:
        """The narrowest SD, and the distance from ``pose`` to the fix plus 12 of the widest."""
        large, small = self.principal_variances
        distance = math.dist(pose.origin, tuple(self.fix))
        return math.sqrt(small), distance + RANGE_SDS * math.sqrt(large)

    def seams(self) -> np.ndarray:
        """For the exact map, the ray behind each station (:meth:`bananagrid.protocol.DensityModel.seams`):
        there its bearing error wraps from pi to -pi (the factor's slope jumps across it), and at
        the station the factor changes with the direction only. The linear map is a normal law:
        none."""
        if self.variant != "exact":
            return np.zeros((0, 3))
        return np.array([(x, y, float(_wrap(b + math.pi))) for (x, y), b in zip(self.sensors, self.bearings)],
                        dtype=np.float64)

    # -- sampling -----------------------------------------------------------------------------

    def _best_pair(self) -> tuple[int, int]:
        """The two sensors whose bearings cross closest to a right angle."""
        n = len(self.bearings)
        pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
        return max(pairs, key=lambda ij: abs(math.sin(self.bearings[ij[0]] - self.bearings[ij[1]])))

    def _crossings(self, i: int, j: int, b_i, b_j) -> tuple[np.ndarray, np.ndarray]:
        """Crossings of sensor i's and j's lines at bearings b_i, b_j (arrays), shape (m, 2),
        and whether each lies in front of both sensors."""
        fx, fy, kept = crossings(self.sensors[[i, j]], b_i, b_j)
        return np.column_stack((fx, fy)), kept

    def _pair_jacobian(self, i: int, j: int, points: np.ndarray) -> np.ndarray:
        """|det d(beta_i, beta_j) / d(x, y)| = |sin(beta_i - beta_j)| / (r_i r_j)."""
        di = points - self.sensors[i]
        dj = points - self.sensors[j]
        cross = di[:, 0] * dj[:, 1] - di[:, 1] * dj[:, 0]
        return np.abs(cross) / (np.einsum("ij,ij->i", di, di) * np.einsum("ij,ij->i", dj, dj))

    @property
    def integrates_to_one(self) -> bool:
        """Only the linear map is a probability density; the exact likelihood, divided by the
        linearised normaliser, integrates to about one."""
        return self.variant == "linear"

    def landmarks(self) -> dict[str, np.ndarray]:
        """The fix, the stations, and each bearing line from its station to 1.5 times the
        farthest station's range from the fix (as the recording draws them)."""
        reach = 1.5 * float(np.max(np.hypot(*(self.fix - self.sensors).T)))
        ends = self.sensors + reach * np.column_stack((np.sin(self.bearings), np.cos(self.bearings)))
        return {"fix": np.reshape(np.asarray(self.fix, dtype=np.float64), (1, 2)),
                "stations": np.asarray(self.sensors, dtype=np.float64),
                "bearings": np.stack([self.sensors, ends], axis=1).astype(np.float64)}

    def sample(self, n: int, rng) -> np.ndarray:
        """Draw ``n`` positions from the exact presence map (the bearings' likelihood under a
        flat prior), restricted to bearing errors within ``SAMPLE_SIGMAS`` sigmas.

        Perturbing two bearings and re-triangulating (Walsh's generative story) draws from
        L_ij(P) |det d(beta_i, beta_j)/dP|, not from L(P): each draw is kept with probability
        J_min / J(P) times the likelihood factors of the other sensors, J = |sin(beta_i - beta_j)|
        / (r_i r_j) and J_min its minimum over the corners of the SAMPLE_SIGMAS bearing box (J
        is smallest there: farthest out, narrowest crossing). Rejection makes the draws exact.
        """
        n, rng = check_n(n), check_rng(rng)
        i, j = self._best_pair()
        box = SAMPLE_SIGMAS * np.array([self.sigmas[i], self.sigmas[j]])
        corners_i = self.bearings[i] + np.array([-1, -1, 1, 1]) * box[0]
        corners_j = self.bearings[j] + np.array([-1, 1, -1, 1]) * box[1]
        corner_points, corner_ok = self._crossings(i, j, corners_i, corners_j)
        if not corner_ok.all():
            raise BananagridError(
                f"bearings: within {SAMPLE_SIGMAS:g} sigma the lines of sensors {i} and {j} can cross "
                "behind a station or not at all; the fix is too poor to sample"
            )
        j_min = self._pair_jacobian(i, j, corner_points).min()
        others = [k for k in range(len(self.bearings)) if k not in (i, j)]
        out = np.empty((0, 2))
        proposed = 0
        while len(out) < n:
            if proposed >= SAMPLE_PATIENCE and len(out) < SAMPLE_MIN_ACCEPTANCE * proposed:
                raise BananagridError(
                    f"bearings: the bearings of sensors {others} disagree with the crossing of sensors {i} "
                    f"and {j} (kept {len(out)} of {proposed:,} draws); the fix cannot be sampled by "
                    "re-triangulation: check the bearings and their sigmas"
                )
            m = max(4 * (n - len(out)), 64)
            proposed += m
            eps = rng.normal(size=(m, 2))
            eps = eps[np.all(np.abs(eps) <= SAMPLE_SIGMAS, axis=1)]
            points, ok = self._crossings(
                i, j, self.bearings[i] + eps[:, 0] * self.sigmas[i], self.bearings[j] + eps[:, 1] * self.sigmas[j]
            )
            points = points[ok]
            accept = j_min / self._pair_jacobian(i, j, points)
            for k in others:
                z = _wrap(bearing_to(self.sensors[k], points) - self.bearings[k]) / self.sigmas[k]
                accept = accept * np.exp(-0.5 * z * z)
            out = np.vstack((out, points[rng.uniform(size=len(points)) < accept]))
        return out[:n]
