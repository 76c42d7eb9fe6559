r"""Angular cell lattices of a ceiling array, and the geometry of their cells on the target.

A planar array at the origin (z up) samples directions on a lattice of azimuths phi (from +x
toward +y) and elevations theta (from +z; theta = pi is the nadir, pi/2 the horizon). A target
at depth h below the array (the plane z = -h, Pessentheiner Sections 4, 5, 9) sees each
direction's cell as

* ``"line"`` (Section 4): a segment of the line y = -h in the (x, y) plane; the azimuth phi in
  [pi, 2 pi] is the only angle and x = -h cot(phi) (4.9);
* ``"plane"`` (Section 5): the annular sector rho in [h tan(pi - theta_p), h tan(pi - theta_m)],
  phi in [phi_m, phi_p] of the plane z = -h (ERRATA: rho = -h tan(theta));
* ``"frustum"`` (Section 9): the slab of such sectors for depths d in [h - dh, h + dh].

Directions follow (2.1): azimuths a0, a0 + step, ... (a full turn half open: 0 <= phi < 360 deg),
elevations t0, ..., t1 inclusive; a direction's cell spans +- step / 2 about it ((4.6), (5.10):
phi_m = phi - dphi/2, phi_p = phi + dphi/2), clipped to the hemisphere theta in [pi/2, pi] (for
the line phi in [pi, 2 pi]). So the nadir direction's cells are thin sectors of the disc about
the nadir and the horizon direction's cells reach to infinity. :meth:`AngularLattice.integer_degrees`
gives the paper's 360 x 91 lattice (32,760 cells) with uint16 degree indices.

The probability of each cell under a presence law is computed in
:mod:`bananagrid.models.presence`; this module holds the cells and their clipping to a box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..validate import BananagridError, finite, pair, positive, step_ratio
from .grid import MAX_CELLS
from .region import Region

__all__ = [
    "AngularLattice", "GEOMETRIES", "box_far", "classify_cells", "cell_breakpoints", "cell_pieces",
    "clipped_measure", "clipped_cells",
]

GEOMETRIES = ("line", "plane", "frustum")
#: Slack for angles given in floating point (pi/2, pi, a step that divides a range).
ANGLE_TOL = 1e-9
_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi
#: Depths h a lattice may have, m: h^3 (a frustum's volumes) and 1/h^3 stay far inside float64.
MIN_DEPTH, MAX_DEPTH = 1e-100, 1e100


def _pair(name: str, value) -> tuple[float, float]:
    return pair(name, value, "a pair (first, last)")


def _steps(name: str, step: float, span: float) -> int:
    ratio = step_ratio(name, step, span, MAX_CELLS, " rad")
    n = round(ratio)
    if abs(ratio - n) > ANGLE_TOL * max(1.0, ratio):
        best = max(1, n)
        raise BananagridError(
            f"{name} = {step!r} rad does not divide the range's span {span!r} rad ({ratio:.6g} steps); "
            f"the nearest step that does is {span / best!r}"
        )
    return int(n)


@dataclass(frozen=True)
class AngularLattice:
    r"""Direction cells of a ceiling array and the regions they cut on the target.

    Parameters
    ----------
    geometry : {"line", "plane", "frustum"}
    h : float
        Depth of the target below the array, m, > 0 (the plane z = -h).
    dh : float, default 0
        Frustum only: half-thickness of the slab of depths [h - dh, h + dh], 0 < dh < h.
    azimuth_step : float
        Azimuth spacing, rad, > 0; must divide the azimuth range's span.
    elevation_step : float
        Plane and frustum: elevation spacing, rad, > 0; must divide the elevation span.
    azimuth_range : (float, float), optional
        Plane and frustum: ``(a0, a1)``, the directions a0, a0 + step, ..., a1 - step (a1
        excluded, a span of at most 2 pi; default (0, 2 pi)). Line: the directions a0, ..., a1
        inclusive within [pi, 2 pi] (default (pi, 2 pi)).
    elevation_range : (float, float), optional
        ``(t0, t1)``, directions t0, ..., t1 inclusive, pi/2 <= t0 <= t1 <= pi (default
        (pi/2, pi)). Only directions below the horizon meet the target: a direction's cell is
        clipped to [pi/2, pi], and a cell with nothing in (pi/2, pi] is refused.

    Notes
    -----
    Cell sizes (ERRATA for (5.10) and Section 9):

    * line (4.16): ``h (cot phi_m - cot phi_p)``;
    * plane: ``(dphi h^2 / 2)(tan^2 theta_m - tan^2 theta_p)``;
    * frustum: ``dphi ((h + dh)^3 - (h - dh)^3) / 6 (tan^2 theta_m - tan^2 theta_p)``;

    infinite for the horizon's cells. The slant range of a direction is r(h, theta) =
    -h / cos(theta) (5.9).
    """

    geometry: str
    h: float
    azimuth_step: float
    elevation_step: float | None = None
    azimuth_range: tuple[float, float] | None = None
    elevation_range: tuple[float, float] | None = None
    dh: float = 0.0

    def __post_init__(self):
        if self.geometry not in GEOMETRIES:
            raise BananagridError(f"geometry = {self.geometry!r}: expected one of {', '.join(GEOMETRIES)}")
        h = finite("h", self.h)
        if h <= 0.0:
            raise BananagridError(f"h = {h!r}: must be > 0 (the target lies at z = -h, below the array)")
        if not MIN_DEPTH <= h <= MAX_DEPTH:
            raise BananagridError(
                f"h = {h!r}: must be within [{MIN_DEPTH:g}, {MAX_DEPTH:g}] m (cell areas and volumes, h^2 and h^3 "
                "times the directions' tangents, must stay normal float64 numbers)"
            )
        dh = finite("dh", self.dh)
        if self.geometry == "frustum":
            if not 0.0 < dh < h:
                raise BananagridError(
                    f"dh = {dh!r}: a frustum needs 0 < dh < h = {h!r} (depths h - dh to h + dh, all below the array)"
                )
            if not h - dh < h + dh:  # dh below half a unit in the last place of h
                raise BananagridError(
                    f"dh = {dh!r}: the slab h - dh to h + dh has no thickness at h = {h!r} in float64; "
                    f"use dh of at least {h * 2.0**-52:.3g} m or the plane geometry"
                )
        elif dh != 0.0:
            raise BananagridError(f"dh = {dh!r}: only the frustum geometry has a slab thickness; use dh = 0")
        da = positive("azimuth_step", self.azimuth_step)
        if self.geometry == "line":
            if self.elevation_step is not None or self.elevation_range is not None:
                raise BananagridError("elevation_step / elevation_range: the line geometry has azimuths only")
            a0, a1 = _pair("azimuth_range", self.azimuth_range if self.azimuth_range is not None else (math.pi, _TWO_PI))
            if not (math.pi - ANGLE_TOL <= a0 <= a1 <= _TWO_PI + ANGLE_TOL):
                raise BananagridError(
                    f"azimuth_range = ({a0!r}, {a1!r}): line directions must lie in [pi, 2 pi] "
                    "(below the array axis), first <= last"
                )
            if a1 - a0 < ANGLE_TOL and (a0 <= math.pi + ANGLE_TOL or a0 >= _TWO_PI - ANGLE_TOL):
                raise BananagridError(f"azimuth_range = ({a0!r}, {a1!r}): the only direction is horizontal")
            _steps("azimuth_step", da, a1 - a0)
            object.__setattr__(self, "azimuth_range", (a0, a1))
        else:
            a0, a1 = _pair("azimuth_range", self.azimuth_range if self.azimuth_range is not None else (0.0, _TWO_PI))
            span = a1 - a0
            if not 0.0 < span <= _TWO_PI * (1.0 + 1e-12):
                raise BananagridError(
                    f"azimuth_range = ({a0!r}, {a1!r}): the span must be in (0, 2 pi] (each direction once)"
                )
            _steps("azimuth_step", da, span)
            if self.elevation_step is None:
                raise BananagridError(f"elevation_step: required for the {self.geometry} geometry")
            de = positive("elevation_step", self.elevation_step)
            t0, t1 = _pair("elevation_range", self.elevation_range if self.elevation_range is not None else (_HALF_PI, math.pi))
            for name, t in (("elevation_range[0]", t0), ("elevation_range[1]", t1)):
                if not _HALF_PI - ANGLE_TOL <= t <= math.pi + ANGLE_TOL:
                    raise BananagridError(
                        f"{name} = {t!r}: theta outside (pi/2, pi]; elevations are measured from +z, "
                        "pi the nadir, pi/2 the horizon (only directions below the horizon meet the target)"
                    )
            if t1 < t0:
                raise BananagridError(f"elevation_range = ({t0!r}, {t1!r}): first must be <= last")
            if t1 <= _HALF_PI + ANGLE_TOL and t0 <= _HALF_PI + ANGLE_TOL and t1 - t0 < ANGLE_TOL:
                raise BananagridError(f"elevation_range = ({t0!r}, {t1!r}): the horizon alone never meets the target")
            if t1 > t0:
                _steps("elevation_step", de, t1 - t0)
            object.__setattr__(self, "azimuth_range", (a0, a1))
            object.__setattr__(self, "elevation_range", (min(max(t0, _HALF_PI), math.pi), min(max(t1, _HALF_PI), math.pi)))
            object.__setattr__(self, "elevation_step", de)
        object.__setattr__(self, "h", h)
        object.__setattr__(self, "dh", dh)
        object.__setattr__(self, "azimuth_step", da)
        cells = math.prod(self.shape)
        if cells > MAX_CELLS:
            raise BananagridError(
                f"angular lattice of {' x '.join(map(str, self.shape))} = {cells:,} cells: more than the {MAX_CELLS:,} a "
                "lattice may have; use a larger azimuth_step or elevation_step"
            )

    @classmethod
    def integer_degrees(cls, geometry: str = "plane", h: float = 1.0, dh: float = 0.0) -> "AngularLattice":
        """The paper's lattice (2.1): azimuths 0..359 deg and elevations 90..180 deg in 1-deg
        steps (32,760 cells), or azimuths 180..360 deg for the line."""
        deg = math.pi / 180.0
        if geometry == "line":
            return cls(geometry, h=h, azimuth_step=deg)
        return cls(geometry, h=h, dh=dh, azimuth_step=deg, elevation_step=deg)

    # -- directions and edges --------------------------------------------------------------

    @property
    def n_azimuth(self) -> int:
        a0, a1 = self.azimuth_range
        n = round((a1 - a0) / self.azimuth_step)
        return n + 1 if self.geometry == "line" else n

    @property
    def n_elevation(self) -> int:
        if self.geometry == "line":
            return 0
        t0, t1 = self.elevation_range
        return round((t1 - t0) / self.elevation_step) + 1

    @property
    def shape(self) -> tuple[int, ...]:
        """``(n_azimuth, n_elevation)`` (line: ``(n_azimuth,)``)."""
        return (self.n_azimuth,) if self.geometry == "line" else (self.n_azimuth, self.n_elevation)

    @property
    def azimuths(self) -> np.ndarray:
        """Direction azimuths, rad."""
        return self.azimuth_range[0] + self.azimuth_step * np.arange(self.n_azimuth)

    @property
    def elevations(self) -> np.ndarray:
        """Direction elevations, rad from +z."""
        return self.elevation_range[0] + self.elevation_step * np.arange(self.n_elevation)

    @property
    def azimuth_edges(self) -> np.ndarray:
        """Cell bounds in azimuth, ``(n_azimuth + 1,)``: phi +- step / 2 (line: clipped to
        [pi, 2 pi])."""
        e = self.azimuth_range[0] + self.azimuth_step * (np.arange(self.n_azimuth + 1) - 0.5)
        if self.geometry == "line":
            e = np.clip(e, math.pi, _TWO_PI)
        return e

    @property
    def elevation_edges(self) -> np.ndarray:
        """Cell bounds in elevation, ``(n_elevation + 1,)``: theta +- step / 2 clipped to
        [pi/2, pi]."""
        e = self.elevation_range[0] + self.elevation_step * (np.arange(self.n_elevation + 1) - 0.5)
        return np.clip(e, _HALF_PI, math.pi)

    @property
    def tau_edges(self) -> np.ndarray:
        """tan(pi - theta) at the elevation edges (inf at the horizon, 0 at the nadir): a depth d
        meets an edge at the radius d tau."""
        e = self.elevation_edges
        with np.errstate(divide="ignore"):
            t = np.tan(math.pi - e)
        return np.where(e <= _HALF_PI + 1e-15, np.inf, t)

    @property
    def depths(self) -> tuple[float, float]:
        return (self.h - self.dh, self.h + self.dh)

    def slant_ranges(self) -> np.ndarray:
        """r(h, theta) = -h / cos(theta) (5.9) of each direction (line: -h / sin(phi))."""
        with np.errstate(divide="ignore"):
            if self.geometry == "line":
                s = np.sin(self.azimuths)
                return np.where(np.abs(s) < 1e-15, np.inf, -self.h / s)
            c = np.cos(self.elevations)
            return np.where(np.abs(c) < 1e-15, np.inf, -self.h / c)

    # -- cells -----------------------------------------------------------------------------

    def line_edges(self) -> np.ndarray:
        """Line cells' x bounds, ``(n_azimuth + 1,)``: x = -h cot(phi) (4.9), -inf / +inf at
        phi = pi / 2 pi."""
        e = self.azimuth_edges
        with np.errstate(divide="ignore"):
            x = -self.h * np.cos(e) / np.sin(e)
        x = np.where(e <= math.pi + 1e-15, -np.inf, x)
        return np.where(e >= _TWO_PI - 1e-15, np.inf, x)

    def radii(self, depth: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Inner and outer radius of each elevation ring at ``depth`` (default h), ``(n_elevation,)``
        each: [d tan(pi - theta_p), d tan(pi - theta_m)]."""
        d = self.h if depth is None else depth
        t = self.tau_edges
        return d * t[1:], d * t[:-1]

    @property
    def sizes(self) -> np.ndarray:
        """Length (m), area (m^2) or volume (m^3) of each cell ((4.16); ERRATA for (5.10), 9.1);
        inf for the horizon's cells."""
        if self.geometry == "line":
            x = self.line_edges()
            return np.diff(x)
        dphi = np.diff(self.azimuth_edges)
        t = self.tau_edges
        with np.errstate(invalid="ignore"):
            ring = (t[:-1] - t[1:]) * (t[:-1] + t[1:])  # tan^2 theta_m - tan^2 theta_p
        ring = np.where(np.isinf(t[:-1]), np.inf, ring)
        if self.geometry == "plane":
            return 0.5 * self.h**2 * dphi[:, None] * ring[None, :]
        d0, d1 = self.depths
        return (d1**3 - d0**3) / 6.0 * dphi[:, None] * ring[None, :]

    @property
    def centroids(self) -> np.ndarray:
        """Centroid of each cell in world coordinates: line ``(n, 2)`` (x, -h); plane and
        frustum ``(n_az, n_el, 3)``. NaN for the horizon's unbounded cells."""
        if self.geometry == "line":
            x = self.line_edges()
            with np.errstate(invalid="ignore"):
                mid = 0.5 * (x[:-1] + x[1:])
            mid = np.where(np.isfinite(x[:-1]) & np.isfinite(x[1:]), mid, np.nan)
            return np.stack([mid, np.full_like(mid, -self.h)], axis=1)
        phi = self.azimuth_edges
        dphi = np.diff(phi)
        mid = 0.5 * (phi[:-1] + phi[1:])
        half = 0.5 * dphi
        sinc = np.where(half > 0, np.sin(half) / np.where(half > 0, half, 1.0), 1.0)
        t = self.tau_edges
        t0, t1 = t[1:], t[:-1]
        with np.errstate(invalid="ignore", divide="ignore"):
            # radial centroid of an annular sector of radii (a, b): 2/3 (b^3 - a^3)/(b^2 - a^2) sinc
            ratio = (2.0 / 3.0) * (t1**2 + t1 * t0 + t0**2) / (t1 + t0)
        ratio = np.where(np.isfinite(t1), ratio, np.nan)
        if self.geometry == "plane":
            rbar, zbar = self.h * ratio, -self.h
        else:
            d0, d1 = self.depths
            # int rho^2 d rho dd / int rho d rho dd over rho in [d t0, d t1], d in [d0, d1]
            rbar = ratio * ((d1**4 - d0**4) / 4.0) / ((d1**3 - d0**3) / 3.0)
            zbar = -((d1**4 - d0**4) / 4.0) / ((d1**3 - d0**3) / 3.0)
        r = rbar[None, :] * sinc[:, None]
        out = np.empty(self.shape + (3,))
        out[..., 0] = r * np.cos(mid)[:, None]
        out[..., 1] = r * np.sin(mid)[:, None]
        out[..., 2] = np.where(np.isfinite(r), zbar, np.nan)
        return out

    def cell_polygons(self, n_arc: int = 8, far: float | None = None) -> np.ndarray:
        """Each cell's outline on the target plane z = -h in world coordinates.

        Plane and frustum: ``(n_az, n_el, 2 n_arc, 3)``, the inner arc from phi_m to phi_p then
        the outer arc back, ``n_arc`` points each; line: ``(n_az, 2, 2)`` segment ends (x, -h).
        The horizon's unbounded cells are cut at the radius ``far`` (default 100 h)."""
        far = 100.0 * self.h if far is None else positive("far", far)
        if self.geometry == "line":
            x = np.clip(self.line_edges(), -far, far)
            ends = np.stack([x[:-1], x[1:]], axis=1)
            return np.stack([ends, np.full_like(ends, -self.h)], axis=2)
        n_arc = max(2, int(n_arc))
        inner, outer = self.radii()
        outer = np.minimum(outer, far)
        phi = self.azimuth_edges
        s = np.linspace(0.0, 1.0, n_arc)
        ang = phi[:-1, None] + np.diff(phi)[:, None] * s[None, :]  # (n_az, n_arc)
        ring = np.concatenate([np.broadcast_to(inner[None, :, None], (1, inner.size, n_arc)),
                               np.broadcast_to(outer[None, :, None], (1, outer.size, n_arc))], axis=2)
        angles = np.concatenate([ang, ang[:, ::-1]], axis=1)[:, None, :]
        out = np.empty((self.n_azimuth, self.n_elevation, 2 * n_arc, 3))
        out[..., 0] = ring * np.cos(angles)
        out[..., 1] = ring * np.sin(angles)
        out[..., 2] = -self.h
        return out

    def describe(self) -> dict:
        return {
            "geometry": self.geometry, "h": self.h, "dh": self.dh,
            "azimuth_step": self.azimuth_step, "azimuth_range": list(self.azimuth_range),
            "elevation_step": self.elevation_step,
            "elevation_range": None if self.elevation_range is None else list(self.elevation_range),
            "shape": list(self.shape),
        }


# --------------------------------------------------------------------------------------------
# Clipping geometry (host, vectorised over cells)
# --------------------------------------------------------------------------------------------


def box_far(b) -> float:
    return float(np.max(np.hypot(b[0][[0, 1, 0, 1]], b[1][[0, 0, 1, 1]])))


def classify_cells(phi0, phi1, r_in, r_out, b):
    """0 outside, 1 inside, 2 cut: the cells' (x, y) bounding boxes against the box ``b``
    (rows x, y). r_out may be inf."""
    far = box_far(b) * 2.0 + 1.0
    ro = np.minimum(r_out, far)
    angles = [phi0, phi1]
    for k in range(-1, 9):
        ax = k * _HALF_PI
        rel = (ax - phi0) % _TWO_PI
        angles.append(np.where(rel <= phi1 - phi0, phi0 + rel, phi0))
    xs, ys = [], []
    for a in angles:
        for r in (r_in, ro):
            xs.append(r * np.cos(a))
            ys.append(r * np.sin(a))
    xs, ys = np.array(xs), np.array(ys)
    lo_x, hi_x, lo_y, hi_y = xs.min(0), xs.max(0), ys.min(0), ys.max(0)
    inside = (lo_x >= b[0, 0]) & (hi_x <= b[0, 1]) & (lo_y >= b[1, 0]) & (hi_y <= b[1, 1]) & np.isfinite(r_out)
    outside = (hi_x < b[0, 0]) | (lo_x > b[0, 1]) | (hi_y < b[1, 0]) | (lo_y > b[1, 1])
    return np.where(outside, 0, np.where(inside, 1, 2))


def cell_breakpoints(phi0, phi1, radii, b):
    """Sorted phi breakpoints strictly inside each cell's (phi0, phi1): the box's corner
    directions and where circles of the given radii (list of arrays) cross the box's edge lines.
    Returns a list of arrays (one per cell)."""
    cands = []
    for cx in b[0]:
        for cy in b[1]:
            cands.append(np.full_like(phi0, math.atan2(cy, cx)))
    for r in radii:
        with np.errstate(invalid="ignore", divide="ignore"):
            for xe in b[0]:
                c = np.arccos(np.clip(xe / r, -1.0, 1.0))
                ok = np.isfinite(r) & (np.abs(xe) < r)
                cands += [np.where(ok, c, np.nan), np.where(ok, -c, np.nan)]
            for ye in b[1]:
                s = np.arcsin(np.clip(ye / r, -1.0, 1.0))
                ok = np.isfinite(r) & (np.abs(ye) < r)
                cands += [np.where(ok, s, np.nan), np.where(ok, math.pi - s, np.nan)]
    c = np.stack(cands, axis=1)
    rel = (c - phi0[:, None]) % _TWO_PI
    width = (phi1 - phi0)[:, None]
    keep = (rel > 1e-13 * np.maximum(1.0, width)) & (rel < width * (1.0 - 1e-13))
    val = np.where(keep, phi0[:, None] + rel, np.inf)
    val.sort(axis=1)
    return val


def cell_pieces(phi0, phi1, status, bps):
    """CSR pieces per cell: (start (n + 1,), a, b). Outside cells get none; cut cells are split
    at their breakpoints; others are one piece."""
    n = phi0.size
    counts = np.where(status == 0, 0, 1 + (np.isfinite(bps).sum(axis=1) if bps is not None else 0))
    counts = np.where(status == 1, 1, counts)
    start = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(counts, out=start[1:])
    a = np.empty(start[-1])
    bb = np.empty(start[-1])
    split = (status == 2) & (bps is not None)
    whole = (counts > 0) & ~split  # one piece, the cell itself: every cell at once
    a[start[:-1][whole]] = phi0[whole]
    bb[start[:-1][whole]] = phi1[whole]
    for i in np.nonzero(split)[0]:  # the cells a region cuts, one by one (a 360 x 91 lattice's
        inner = bps[i][np.isfinite(bps[i])]  # 32,760 cells took 0.06 s in this loop)
        pts = np.concatenate([[phi0[i]], inner, [phi1[i]]])
        a[start[i]:start[i + 1]] = pts[:-1]
        bb[start[i]:start[i + 1]] = pts[1:]
    return start, a, bb


def _chord(phi, b):
    """Ray-box chord [rho_in, rho_out] along directions phi (rho_in > rho_out: a miss)."""
    c, s = np.cos(phi), np.sin(phi)
    lo = np.zeros_like(phi)
    hi = np.full_like(phi, np.inf)
    for comp, (e0, e1) in ((c, b[0]), (s, b[1])):
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = e0 / comp, e1 / comp
        near, far = np.minimum(t0, t1), np.maximum(t0, t1)
        zero = comp == 0.0
        miss = zero & ((e0 > 0.0) | (e1 < 0.0))
        lo = np.where(zero, lo, np.maximum(lo, near))
        hi = np.where(zero, np.where(miss, -1.0, hi), np.minimum(hi, far))
    return lo, hi


def clipped_measure(phi0, phi1, status, bps, tau0, tau1, depths, b, geometry, n_gauss=24):
    """Area (plane) or volume (frustum) of each cell within the box, by Gauss-Legendre in phi
    on pieces where the integrand is analytic, with the exact integral over (rho, depth) at each
    node: G(phi) = int_d int_rho rho d rho dd over the polygon {d in depths, d tau0 <= rho <=
    d tau1, rho_in(phi) <= rho <= rho_out(phi)}, piecewise quadratic in d (Simpson is exact on
    each piece between the kinks d = rho_in / tau, rho_out / tau). Returns (values, the change
    from n_gauss / 2 nodes as an error estimate)."""
    start, pa, pb = cell_pieces(phi0, phi1, status, bps)
    owner = np.repeat(np.arange(phi0.size), np.diff(start))
    out = []
    for n in (n_gauss // 2, n_gauss):
        x, w = np.polynomial.legendre.leggauss(n)
        half = 0.5 * (pb - pa)
        phi = (0.5 * (pa + pb))[:, None] + half[:, None] * x[None, :]
        lo_c, hi_c = _chord(phi, b)
        t0 = tau0[owner][:, None]
        t1 = tau1[owner][:, None]
        if geometry == "plane":
            d = depths[0]
            lo = np.maximum(d * t0, lo_c)
            hi = np.minimum(d * t1, hi_c)
            g = np.where(hi > lo, 0.5 * (hi - lo) * (hi + lo), 0.0)
        else:
            d0, d1 = depths
            with np.errstate(divide="ignore", invalid="ignore"):
                kinks = [lo_c / t0, lo_c / t1, hi_c / t0, hi_c / t1]
            ks = np.stack([np.full_like(phi, d0)] + [np.clip(np.nan_to_num(k, nan=d0, posinf=d1, neginf=d0), d0, d1)
                                                      for k in kinks] + [np.full_like(phi, d1)], axis=-1)
            ks.sort(axis=-1)
            g = np.zeros_like(phi)
            for j in range(ks.shape[-1] - 1):
                da, db = ks[..., j], ks[..., j + 1]
                for dd, wt in ((da, 1.0), (0.5 * (da + db), 4.0), (db, 1.0)):
                    lo = np.maximum(dd * t0, lo_c)
                    hi = np.minimum(np.where(np.isinf(t1), np.inf, dd * t1), hi_c)
                    g += wt * (db - da) / 6.0 * np.where(hi > lo, 0.5 * (hi - lo) * (hi + lo), 0.0)
        piece = half * (g @ w)
        out.append(np.bincount(owner, weights=piece, minlength=phi0.size))
    return out[1], np.abs(out[1] - out[0])


def clipped_cells(lattice: AngularLattice, box: Region):
    """Each cell of ``lattice`` clipped to the box ``box``: ``(fraction, size, error)``, the
    clipped length, area or volume over |box| (the cell probabilities of a uniform law on the
    box), the clipped size itself and an error estimate of the fraction (0 where exact)."""
    if lattice.geometry == "line":
        x = np.clip(lattice.line_edges(), box.x[0], box.x[1])
        length = np.diff(x)
        return length / box.size, length, np.zeros_like(length)
    b = box.bounds
    phi = lattice.azimuth_edges
    na, ne = lattice.shape
    phi0 = np.repeat(phi[:-1], ne)
    phi1 = np.repeat(phi[1:], ne)
    tau = lattice.tau_edges
    tau0 = np.tile(tau[1:], na)
    tau1 = np.tile(tau[:-1], na)
    if lattice.geometry == "plane":
        depths = (lattice.h, lattice.h)
    else:
        depths = lattice.depths
        if box.z is not None:
            depths = (max(depths[0], -box.z[1]), min(depths[1], -box.z[0]))
    if not depths[1] >= depths[0]:
        raise BananagridError(f"region {box.describe()}: its z range misses the slab of depths {lattice.depths}")
    radii = [depths[0] * tau0, depths[0] * tau1, depths[1] * tau0, depths[1] * tau1]
    status = classify_cells(phi0, phi1, depths[0] * tau0, depths[1] * tau1, b)
    bps = cell_breakpoints(phi0, phi1, radii, b)
    meas, err = clipped_measure(phi0, phi1, status, bps, tau0, tau1, depths, b, lattice.geometry)
    size = box.size
    return (meas / size).reshape(na, ne), meas.reshape(na, ne), (err / size).reshape(na, ne)
