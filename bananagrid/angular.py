r"""Angular cell lattices of a ceiling array and the presence probability of each cell.

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
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .presence import (
    GaussianMixture, Region, UniformPresence, _as_region, _gk_rule, _gl8, _interval_probability,
)
from .validate import BananagridError, finite, positive

__all__ = ["AngularLattice", "CellMap", "cell_probabilities", "RTOL", "ATOL", "MAX_PANELS"]

GEOMETRIES = ("line", "plane", "frustum")
#: Slack for angles given in floating point (pi/2, pi, a step that divides a range).
ANGLE_TOL = 1e-9
#: Default relative tolerance of each component's cell integral (|K15 - G7| <= RTOL |K15| + ATOL).
RTOL = 1e-7
#: The tolerance a float32 run uses at least: its cells agree with float64 to about 4e-5 relative
#: (tests/test_presence.py), the precision float32 gives; the 1e-6 guarantee is float64's.
FLOAT32_RTOL = 1e-5
#: Absolute tolerance of a component's cell integral, as a fraction of p(S) (the conditioning
#: mass): far below the 1e-9 cell mass that the 1e-6 relative guarantee covers.
ATOL = 1e-17
#: Most Gauss-Kronrod panels per piece and axis.
MAX_PANELS = 4096

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


def _pair(name, value):
    try:
        lo, hi = value
    except (TypeError, ValueError):
        raise BananagridError(f"{name} = {value!r}: expected a pair (first, last)") from None
    return finite(f"{name}[0]", lo), finite(f"{name}[1]", hi)


def _steps(name: str, step: float, span: float) -> int:
    ratio = span / step
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
        dh = finite("dh", self.dh)
        if self.geometry == "frustum":
            if not 0.0 < dh < h:
                raise BananagridError(
                    f"dh = {dh!r}: a frustum needs 0 < dh < h = {h!r} (depths h - dh to h + dh, all below the array)"
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


@dataclass(frozen=True)
class CellMap:
    """Presence probability of each cell of an :class:`AngularLattice`.

    Attributes
    ----------
    prob : ndarray
        p(C | S) per cell, indexed [azimuth, elevation] (line: [azimuth]), float64.
    lattice : AngularLattice
    region : Region or None
        The conditioning region S (cells clipped to it), if any.
    region_probability : float
        p(S) (1 without a region).
    error : ndarray
        Estimated absolute error of each probability (0 for exact ones): the sum over components
        of |K15 - G7| divided by p(S), a conservative estimate of the Kronrod rule's error.
    clipped_sizes : ndarray or None
        Length, area or volume of each cell within S, if a region is given.
    provenance : dict
    """

    prob: np.ndarray
    lattice: AngularLattice
    region: Region | None = None
    region_probability: float = 1.0
    error: np.ndarray | None = None
    clipped_sizes: np.ndarray | None = None
    provenance: dict = field(default_factory=dict)

    @property
    def azimuth_edges(self) -> np.ndarray:
        return self.lattice.azimuth_edges

    @property
    def elevation_edges(self) -> np.ndarray:
        return self.lattice.elevation_edges

    @property
    def sizes(self) -> np.ndarray:
        return self.lattice.sizes

    @property
    def centroids(self) -> np.ndarray:
        return self.lattice.centroids

    def cell_polygons(self, n_arc: int = 8, far: float | None = None) -> np.ndarray:
        """Outlines on the target plane in world coordinates (see AngularLattice.cell_polygons)."""
        return self.lattice.cell_polygons(n_arc=n_arc, far=far)

    def clutter_mask(self, threshold: float) -> np.ndarray:
        """True where a cell's presence probability is below ``threshold`` (detections there are
        treated as clutter, Section 11)."""
        t = finite("threshold", threshold)
        if not 0.0 <= t <= 1.0:
            raise BananagridError(f"threshold = {t!r}: a probability threshold must be in [0, 1]")
        return self.prob < t

    def degree_indices(self) -> tuple[np.ndarray, ...]:
        """The directions as integer degrees, uint16 (the paper's 16-bit angles, Section 2)."""
        out = []
        axes = [("azimuth", self.lattice.azimuths)]
        if self.lattice.geometry != "line":  # a line has azimuths only (no elevations to read)
            axes.append(("elevation", self.lattice.elevations))
        for name, values in axes:
            deg = np.degrees(values)
            rounded = np.round(deg)
            if np.max(np.abs(deg - rounded), initial=0.0) > 1e-6:
                raise BananagridError(f"{name}s are not whole degrees: the lattice has no integer-degree index")
            out.append((rounded % 360 if name == "azimuth" and self.lattice.geometry != "line" else rounded).astype(np.uint16))
        return tuple(out)

    def degree_table(self) -> np.ndarray:
        """The probabilities in an array indexed by integer degrees: ``table[az_deg, el_deg]``
        of shape (360, 181) (line: ``table[az_deg]``, 361), NaN for directions not in the lattice."""
        idx = self.degree_indices()
        if self.lattice.geometry == "line":
            table = np.full(361, np.nan)
            table[idx[0]] = self.prob
            return table
        table = np.full((360, 181), np.nan)
        table[np.ix_(idx[0], idx[1])] = self.prob
        return table

    def world_map(self, x, y) -> np.ndarray:
        """The presence map on the target plane z = -h in world coordinates: at each point
        (x, y) (broadcast), the probability of the cell holding it divided by the cell's size
        (clipped to S where a region is given); 0 outside the lattice (and S). Plane and frustum
        (for the frustum: per m^3, the cell through the point at depth h)."""
        if self.lattice.geometry == "line":
            raise BananagridError("world_map: a line lattice has no plane map; use prob and lattice.line_edges()")
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        lat = self.lattice
        phi = np.arctan2(by, bx)
        a0 = lat.azimuth_edges[0]
        rel = (phi - a0) % _TWO_PI
        ia = np.floor(rel / lat.azimuth_step).astype(int)
        theta = math.pi - np.arctan2(np.hypot(bx, by), lat.h)
        ie = np.searchsorted(lat.elevation_edges, theta, side="right") - 1
        ie = np.where(theta == lat.elevation_edges[-1], lat.n_elevation - 1, ie)
        ok = (ia >= 0) & (ia < lat.n_azimuth) & (ie >= 0) & (ie < lat.n_elevation)
        size = self.clipped_sizes if self.clipped_sizes is not None else lat.sizes
        with np.errstate(divide="ignore", invalid="ignore"):
            dens = np.where(size > 0, self.prob / size, 0.0)
        out = np.zeros(bx.shape)
        out[ok] = dens[ia[ok], ie[ok]]
        if self.region is not None:
            b = self.region.bounds
            out[(bx < b[0, 0]) | (bx > b[0, 1]) | (by < b[1, 0]) | (by > b[1, 1])] = 0.0
        return out


# --------------------------------------------------------------------------------------------
# Clipping geometry (host, vectorised over cells)
# --------------------------------------------------------------------------------------------


def _box_far(b) -> float:
    return float(np.max(np.hypot(b[0][[0, 1, 0, 1]], b[1][[0, 0, 1, 1]])))


def _classify(phi0, phi1, r_in, r_out, b):
    """0 outside, 1 inside, 2 cut: the cells' (x, y) bounding boxes against the box ``b``
    (rows x, y). r_out may be inf."""
    far = _box_far(b) * 2.0 + 1.0
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


def _breakpoints(phi0, phi1, radii, b):
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


def _pieces(phi0, phi1, status, bps):
    """CSR pieces per cell: (start (n + 1,), a, b). Outside cells get none; cut cells are split
    at their breakpoints; others are one piece."""
    n = phi0.size
    counts = np.where(status == 0, 0, 1 + (np.isfinite(bps).sum(axis=1) if bps is not None else 0))
    counts = np.where(status == 1, 1, counts)
    start = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(counts, out=start[1:])
    a = np.empty(start[-1])
    bb = np.empty(start[-1])
    for i in np.nonzero(counts)[0]:
        if status[i] == 2 and bps is not None:
            inner = bps[i][np.isfinite(bps[i])]
            pts = np.concatenate([[phi0[i]], inner, [phi1[i]]])
        else:
            pts = np.array([phi0[i], phi1[i]])
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


def _clipped_measure(phi0, phi1, status, bps, tau0, tau1, depths, b, geometry, n_gauss=24):
    """Area (plane) or volume (frustum) of each cell within the box, by Gauss-Legendre in phi
    on pieces where the integrand is analytic, with the exact integral over (rho, depth) at each
    node: G(phi) = int_d int_rho rho d rho dd over the polygon {d in depths, d tau0 <= rho <=
    d tau1, rho_in(phi) <= rho <= rho_out(phi)}, piecewise quadratic in d (Simpson is exact on
    each piece between the kinks d = rho_in / tau, rho_out / tau). Returns (values, the change
    from n_gauss / 2 nodes as an error estimate)."""
    start, pa, pb = _pieces(phi0, phi1, status, bps)
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


# --------------------------------------------------------------------------------------------
# Cell probabilities
# --------------------------------------------------------------------------------------------


def _component_rows(mixture: GaussianMixture) -> np.ndarray:
    """Kernel rows (kernels.presence C_* layout) of each component's (conditional) (x, y) law."""
    from .kernels import presence as kp

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
        row[kp.C_GX], row[kp.C_GY] = g
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
    from .raster import _check_threads

    if not isinstance(lattice, AngularLattice):
        raise BananagridError(f"lattice = {lattice!r}: expected a bananagrid AngularLattice")
    _check_presence(presence, lattice)
    rtol = positive("rtol", rtol)
    if np.dtype(dtype) == np.float32:
        rtol = max(rtol, FLOAT32_RTOL)  # float32 cannot resolve K15 - G7 below ~1e-7 of K15
    threads = _check_threads(threads)
    start = time.perf_counter()
    if region is not None:
        region = _as_region(region)
        if region.dim != presence.dim:
            raise BananagridError(f"region has {region.dim} axes; a {lattice.geometry} lattice needs {presence.dim}")
    if isinstance(presence, UniformPresence):
        box = presence.region if region is None else _intersect(presence.region, region)
        prob, clipped, err = _uniform(lattice, box)
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
        clipped = _uniform(lattice, region)[1] if region is not None else None
        prov = {"method": "differences of normal CDFs (7.2)"}
    else:
        prob, err, prov = _mixture_cells(presence, lattice, region, p_s, dtype=dtype, device=device,
                                         threads=threads, rtol=rtol)
        clipped = _uniform(lattice, region)[1] if region is not None else None
    return CellMap(prob=prob, lattice=lattice, region=region, region_probability=p_s, error=err,
                   clipped_sizes=clipped, provenance={**presence.parameters(), "lattice": lattice.describe(),
                                                      **prov, "seconds": time.perf_counter() - start})


def _intersect(a: Region, b: Region) -> Region:
    lo = np.maximum(a.bounds[:, 0], b.bounds[:, 0])
    hi = np.minimum(a.bounds[:, 1], b.bounds[:, 1])
    if np.any(hi <= lo):
        raise BananagridError(f"region {b.describe()} does not overlap the uniform law's region {a.describe()}: empty")
    return Region(*[(float(l), float(h)) for l, h in zip(lo, hi)])


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


def _uniform(lattice: AngularLattice, box: Region):
    """(prob, clipped sizes, error estimate) for uniform presence on ``box``."""
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
    status = _classify(phi0, phi1, depths[0] * tau0, depths[1] * tau1, b)
    bps = _breakpoints(phi0, phi1, radii, b)
    meas, err = _clipped_measure(phi0, phi1, status, bps, tau0, tau1, depths, b, lattice.geometry)
    size = box.size
    return (meas / size).reshape(na, ne), meas.reshape(na, ne), (err / size).reshape(na, ne)


def _mixture_cells(mixture, lattice, region, p_s, *, dtype, device, threads, rtol):
    from .kernels import presence as kp
    from .raster import _bands, _check_device, _run_bands, _scalar

    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
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
        box_far = _box_far(b)
        status = np.zeros(phi0.size, dtype=int)
        if depths[1] > depths[0] or not frustum:
            status = _classify(phi0, phi1, depths[0] * tau0, depths[1] * tau1, b)
        radii = [depths[0] * tau0, depths[0] * tau1, depths[1] * tau0, depths[1] * tau1]
        bps = _breakpoints(phi0, phi1, radii, b)
    else:
        box = np.array([-1.0, 1.0, -1.0, 1.0])
        box_far = 1e300
        status = np.ones(phi0.size, dtype=int)
        bps = None
    start, pa, pb = _pieces(phi0, phi1, status, bps)
    cut = (status == 2).astype(np.int32)
    n = phi0.size

    def arr(a):
        return wp.array(np.ascontiguousarray(a, dtype=np_dtype), dtype=scalar, device=device)

    tau1_k = np.where(np.isinf(tau1), -1.0, tau1)
    comp = wp.array(_component_rows(mixture).astype(np_dtype), dtype=scalar, device=device)
    prob = wp.zeros(n, dtype=scalar, device=device)
    err = wp.zeros(n, dtype=scalar, device=device)
    evals = wp.zeros(n, dtype=wp.int32, device=device)
    log_atol = math.log(ATOL * p_s)
    common_tail = [arr(box), scalar(box_far), comp, mixture.n_components, arr(_gk_rule()), arr(_gl8()),
                   scalar(rtol), scalar(log_atol), MAX_PANELS]
    head = [wp.array(start, dtype=wp.int32, device=device), arr(pa), arr(pb),
            wp.array(cut, dtype=wp.int32, device=device), arr(phi0), arr(phi1)]
    if frustum:
        kernel = kp.frustum_cells
        geo = [arr(tau0), arr(np.where(np.isinf(tau1), -1.0, tau1)), scalar(depths[0]), scalar(depths[1])]
    else:
        kernel = kp.plane_cells
        rho_hi = np.where(np.isinf(tau1), -1.0, lattice.h * tau1_k)
        geo = [arr(lattice.h * tau0), arr(rho_hi)]
    wp.load_module(kernel.module, device=device)
    if frustum and not depths[1] > depths[0]:
        bands = []
    else:
        bands = _bands(n, threads, 16) if device == "cpu" else [(0, n)]

    def launch(c0, c1):
        wp.launch(kernel, dim=c1 - c0, inputs=[*head, *geo, *common_tail, c0, prob, err, evals], device=device)

    _run_bands(launch, bands, threads if device == "cpu" else 1)
    wp.synchronize_device(device)
    raw = prob.numpy().astype(np.float64)
    out = (raw / p_s).reshape(na, ne)
    error = (err.numpy().astype(np.float64) / p_s).reshape(na, ne)
    nodes = int(evals.numpy().astype(np.int64).sum())
    prov = {
        "method": "closed-form radial integral, adaptive Gauss-Kronrod (7, 15) in phi"
                  + (" and depth" if frustum else ""),
        "kernel": f"presence.{'frustum' if frustum else 'plane'}_cells", "dtype": np.dtype(np_dtype).name,
        "device": device, "threads": threads, "rtol": rtol, "atol": ATOL * p_s,
        "panels": nodes, "cells_cut": int(np.sum(status == 2)), "cells_outside": int(np.sum(status == 0)),
    }
    return out, error, prov
