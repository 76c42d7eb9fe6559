"""Searches that found nothing: an area searched with a probability of detection, and a
searcher's timed track with its lateral-range law.

Each search gives, for a target at a point (held there while the search lasts), the probability
of not detecting it, 1 - POD(point): the likelihood of "nothing found". Several searches are
independent looks: their (1 - POD) multiply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..domains.grid import Grid
from ..validate import BananagridError, finite, positive, real_array, timed_track
from .geometry import Polygon, distance_to_track, polygons_from, segment_inverse_cube

__all__ = ["AreaSearch", "TrackSearch", "RasterSearch", "LAWS", "lateral_range", "search_time"]

#: The lateral-range laws of :class:`TrackSearch`.
LAWS = ("inverse_cube", "definite")


def search_time(name: str, t) -> tuple[float, float]:
    """``t`` (a time, or a pair (t0, t1) with t0 <= t1), s since the last fix, as (t0, t1)."""
    if isinstance(t, (tuple, list, np.ndarray)):
        if len(t) != 2:
            raise BananagridError(f"{name} = {t!r}: expected a time (s) or a pair (t0, t1)")
        t0, t1 = finite(f"{name}[0]", t[0]), finite(f"{name}[1]", t[1])
    else:
        t0 = t1 = finite(name, t)
    if t0 < 0.0:
        raise BananagridError(f"{name} = {t!r}: times must be >= 0 (s since the last fix)")
    if t1 < t0:
        raise BananagridError(f"{name} = {t!r}: the search ends before it starts; expected t0 <= t1")
    return t0, t1


def lateral_range(x, sweep_width: float, law: str = "inverse_cube") -> np.ndarray:
    """POD of a stationary target at lateral distance ``x`` (m) from an infinite straight leg.

    ``"inverse_cube"``: p(x) = 1 - exp(-W^2 / (4 pi x^2)); ``"definite"``: p(x) = 1 for |x| <=
    W / 2, else 0. Both integrate over x to the sweep width W (see :class:`TrackSearch`).
    """
    x = np.abs(np.asarray(x, dtype=float))
    w = positive("sweep_width", sweep_width)
    if law == "definite":
        return np.where(x <= 0.5 * w, 1.0, 0.0)
    if law != "inverse_cube":
        raise BananagridError(f"law = {law!r}: expected one of {', '.join(map(repr, LAWS))}")
    with np.errstate(divide="ignore"):
        return -np.expm1(-w * w / (4.0 * math.pi * x * x))


@dataclass(frozen=True)
class AreaSearch:
    """An area searched at time ``t`` (or over ``t = (t0, t1)``) that found nothing. The
    likelihood of "nothing found" is 1 - POD inside the polygon (``miss``: exp(-C) from a
    coverage, exactly, however close POD is to 1) and 1 outside.

    Parameters
    ----------
    polygon : array_like (n, 2), GeoJSON dict, or path to a GeoJSON file
        The area's vertices (m, world frame), a simple polygon (a closing vertex is dropped), or
        a GeoJSON Polygon (or a Feature or FeatureCollection holding exactly one).
    t : float or (float, float)
        When it was searched, s since the last fix (the prior's clock).
    pod : float, optional
        Probability of detecting a target inside the area, in [0, 1].
    coverage : float, optional
        The coverage factor C >= 0 (effort / area); then POD = 1 - exp(-C), random search
        (Koopman 1946; Stone, *Theory of Optimal Search*, eq. (2.2.3)). Give ``pod`` or
        ``coverage``, not both.
    frame : GeoFrame, optional
        With a frame the polygon's coordinates are [longitude, latitude] degrees (GeoJSON's
        order), projected to the frame's local metres vertex by vertex.
    """

    polygon: np.ndarray
    t: tuple[float, float]
    pod: float | None = None
    coverage: float | None = None
    frame: object = None
    region: Polygon = field(init=False, repr=False, compare=False)
    miss: float = field(init=False, repr=False, compare=False)

    kind = "search"

    def __post_init__(self):
        shapes = polygons_from("polygon", self.polygon, self.frame)
        if len(shapes) != 1:
            raise BananagridError(f"polygon: the GeoJSON holds {len(shapes)} polygons; an area search is one "
                                  "(give one AreaSearch per area)")
        object.__setattr__(self, "polygon", shapes[0])
        object.__setattr__(self, "t", search_time("t", self.t))
        if (self.pod is None) == (self.coverage is None):
            raise BananagridError(f"pod = {self.pod!r}, coverage = {self.coverage!r}: give exactly one of them")
        if self.coverage is not None:
            c = finite("coverage", self.coverage)
            if c < 0.0:
                raise BananagridError(f"coverage = {c!r}: must be >= 0 (effort per unit area)")
            object.__setattr__(self, "coverage", c)
            object.__setattr__(self, "pod", float(-math.expm1(-c)))
            object.__setattr__(self, "miss", math.exp(-c))  # 1 - POD without its rounding
        else:
            p = finite("pod", self.pod)
            if not 0.0 <= p <= 1.0:
                raise BananagridError(f"pod = {p!r}: must be in [0, 1]")
            object.__setattr__(self, "pod", p)
            object.__setattr__(self, "miss", 1.0 - p)
        object.__setattr__(self, "region", Polygon(self.polygon))

    @property
    def time_span(self) -> tuple[float, float]:
        return self.t

    def likelihood(self, x, y) -> np.ndarray:
        """1 - POD at each point (broadcast ``x``, ``y``)."""
        return np.where(self.region.contains(x, y), self.miss, 1.0)

    def describe(self) -> dict:
        """Plain data for provenance."""
        return {"kind": "area_search", "t": list(self.t), "pod": self.pod, "coverage": self.coverage,
                "vertices": len(self.polygon), "area_m2": self.region.area}


@dataclass(frozen=True)
class TrackSearch:
    """A searcher's timed track that found nothing, with its sweep width and lateral-range law.

    Parameters
    ----------
    track : array_like, shape (n, 3)
        ``[(x, y, t), ...]``: positions (m, world frame) at times (s since the last fix,
        strictly increasing), at least 2; the searcher runs straight between them.
    sweep_width : float
        W > 0, m: the integral over lateral distance of the lateral-range curve.
    law : {"inverse_cube", "definite"}, default "inverse_cube"
        ``"inverse_cube"``: Koopman's detection rate of a sensor at height h looking down at a
        wake, gamma(r) = k h / r^3 per unit time (Koopman, *Search and Screening*, 1946 and
        1980, Section 3.4; Washburn, *Search and Detection*, Section 2.3). Along a straight leg
        flown at speed v past a stationary target at lateral distance x, the exposure is
        int gamma dt = (k h / v) int ds / (x^2 + s^2)^(3/2) = 2 k h / (v x^2), so the
        lateral-range curve is p(x) = 1 - exp(-2 k h / (v x^2)); its integral over x is the
        sweep width W = 2 sqrt(2 pi k h / v), so p(x) = 1 - exp(-W^2 / (4 pi x^2)). Written per
        metre of track, the exposure of a point at range r(s) from the searcher is
        (W^2 / (8 pi)) int ds / r(s)^3; each leg's integral is closed-form
        (:func:`~bananagrid.evidence.geometry.segment_inverse_cube`). ``"definite"``: the
        target is detected iff the track's closest approach is within W / 2 (the definite-range
        law, Koopman 1946): p(x) = 1 for |x| <= W / 2, else 0.

    Notes
    -----
    For a target path x(t) the POD is 1 - exp(-int gamma(|x(t) - s(t)|) dt) along the relative
    motion (inverse cube), or 1 where min over the track's span of |x(t) - s(t)| <= W / 2 and 0
    elsewhere (definite range: the closest approach of the relative path). A map at a time
    within the track's span takes the target stationary over the track's duration: the exposure
    of each point is the integral along the track's legs above (for a straight leg that is the
    lateral-range curve; tested), its closest approach the distance to the track. A map after
    the track carries either law along the model's paths (CAT, Butterly:
    :func:`~bananagrid.evidence.packing.pack` states the rules and their errors).
    """

    track: np.ndarray
    sweep_width: float
    law: str = "inverse_cube"

    kind = "search"

    def __post_init__(self):
        points = real_array("track", self.track, "a list of (x, y, t) points")
        if points.ndim != 2 or points.shape[1] != 3:
            raise BananagridError(f"track = {self.track!r}: expected a list of (x, y, t) points, got shape {points.shape}")
        times, positions = timed_track("track", points[:, 2], points[:, :2])
        if times[0] < 0.0:
            raise BananagridError(f"track.times[0] = {times[0]!r}: times must be >= 0 (s since the last fix)")
        same = np.flatnonzero(np.all(positions[1:] == positions[:-1], axis=1))
        if same.size:
            k = int(same[0]) + 1
            raise BananagridError(f"track.positions[{k}] = {positions[k].tolist()!r}: repeats the position before it "
                                  "(a searcher that waits in place sweeps no width)")
        track = np.column_stack((positions, times))
        track.setflags(write=False)
        object.__setattr__(self, "track", track)
        object.__setattr__(self, "sweep_width", positive("sweep_width", self.sweep_width))
        if self.law not in LAWS:
            raise BananagridError(f"law = {self.law!r}: expected one of {', '.join(map(repr, LAWS))}")

    @classmethod
    def from_track(cls, track, frame, sweep_width: float, law: str = "inverse_cube") -> "TrackSearch":
        """A search along a track read from a file (``bg.read_track``: longitude, latitude and
        UTC times), placed in ``frame``'s local metres and timed in seconds since the frame's
        time (the last fix's).

        Raises
        ------
        BananagridError
            A frame without a time, a track without longitude, latitude and times, or a point
            the frame cannot place; and what the constructor refuses.
        """
        if getattr(frame, "time", None) is None:
            raise BananagridError("frame: a GeoFrame with a time (the last fix's UTC time) is needed to time a track "
                                  "read from a file")
        try:
            lon, lat, times = np.asarray(track.lon, dtype=float), np.asarray(track.lat, dtype=float), track.times
        except AttributeError:
            raise BananagridError(f"track = {type(track).__name__}: expected a track read by bg.read_track "
                                  "(longitude, latitude, UTC times)") from None
        x, y = frame.local(lat, lon)
        seconds = [(when - frame.time).total_seconds() for when in times]
        return cls(np.column_stack((x, y, seconds)), sweep_width, law)

    @property
    def time_span(self) -> tuple[float, float]:
        return float(self.track[0, 2]), float(self.track[-1, 2])

    def exposure(self, x, y) -> np.ndarray:
        """The inverse-cube exposure (W^2 / (8 pi)) sum over legs of int ds / r^3 at each point."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        points = np.column_stack((x.ravel(), y.ravel()))
        total = np.zeros(len(points))
        for a, b in zip(self.track[:-1, :2], self.track[1:, :2]):
            total += segment_inverse_cube(points, a, b)
        return (self.sweep_width**2 / (8.0 * math.pi) * total).reshape(x.shape)

    def likelihood(self, x, y) -> np.ndarray:
        """1 - POD of a target held at each point while the searcher flies the track."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        if self.law == "definite":
            d = distance_to_track(np.column_stack((x.ravel(), y.ravel())), self.track[:, :2]).reshape(x.shape)
            return np.where(d <= 0.5 * self.sweep_width, 0.0, 1.0)
        return np.exp(-self.exposure(x, y))

    def describe(self) -> dict:
        """Plain data for provenance."""
        return {"kind": "track_search", "t": list(self.time_span), "sweep_width_m": self.sweep_width,
                "law": self.law, "points": len(self.track)}


@dataclass(frozen=True)
class RasterSearch:
    """A search given cell by cell on a grid, at time ``t`` (or over ``t = (t0, t1)``), that found
    nothing: a planner's effort of one period as a raster of POD values (or of coverage
    factors). A target in cell (i, j) is missed with probability 1 - ``pod[i, j]`` (exp(-C) from
    a coverage); outside the grid the search saw nothing (likelihood 1).

    Parameters
    ----------
    grid : Grid
        The raster's cells (``values[i, j]`` belongs to the cell centred at (x[j], y[i]), rows
        from south to north). A point on the edge between two cells belongs to the cell east of
        it (north of it); points on the grid's east or north edge are outside.
    t : float or (float, float)
        When, s since the last fix. Over an interval the coverage is spread uniformly over it:
        a target path is missed with probability exp(-int C(x(s)) ds / (t1 - t0)) (random
        search, Koopman), C = -log(1 - POD) where POD is given.
    pod : array_like (ny, nx), optional
        POD of each cell, in [0, 1].
    coverage : array_like (ny, nx), optional
        Coverage factor C >= 0 of each cell. Give ``pod`` or ``coverage``, not both.
    """

    grid: Grid
    t: tuple[float, float]
    pod: np.ndarray | None = None
    coverage: np.ndarray | None = None
    log_miss: np.ndarray = field(init=False, repr=False, compare=False)
    miss: np.ndarray = field(init=False, repr=False, compare=False)

    kind = "search"

    def __post_init__(self):
        if not isinstance(self.grid, Grid):
            raise BananagridError(f"grid = {self.grid!r}: expected a bananagrid Grid")
        object.__setattr__(self, "t", search_time("t", self.t))
        if (self.pod is None) == (self.coverage is None):
            raise BananagridError("pod, coverage: give exactly one of them (a raster of POD values or of coverage "
                                  "factors)")
        name = "pod" if self.pod is not None else "coverage"
        values = real_array(name, self.pod if self.pod is not None else self.coverage, "a raster of numbers")
        if values.shape != self.grid.shape:
            raise BananagridError(f"{name}: shape {values.shape}; expected the grid's (ny, nx) = {self.grid.shape}")
        if not np.isfinite(values).all():
            i, j = np.argwhere(~np.isfinite(values))[0]
            raise BananagridError(f"{name}[{i}, {j}] = {float(values[i, j])!r}: must be finite")
        if name == "pod":
            bad = (values < 0.0) | (values > 1.0)
            if bad.any():
                i, j = np.argwhere(bad)[0]
                raise BananagridError(f"pod[{i}, {j}] = {float(values[i, j])!r}: must be in [0, 1]")
            with np.errstate(divide="ignore"):
                log_miss = np.log1p(-values)
            miss = 1.0 - values
        else:
            bad = values < 0.0
            if bad.any():
                i, j = np.argwhere(bad)[0]
                raise BananagridError(f"coverage[{i}, {j}] = {float(values[i, j])!r}: must be >= 0 (effort per unit area)")
            log_miss = -values
            miss = np.exp(-values)
        values = values.copy()
        for a in (values, log_miss, miss):
            a.setflags(write=False)
        object.__setattr__(self, name, values)
        object.__setattr__(self, "log_miss", log_miss)
        object.__setattr__(self, "miss", miss)

    @property
    def time_span(self) -> tuple[float, float]:
        return self.t

    def cells(self, x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row, column and whether on the raster, for each point (broadcast ``x``, ``y``)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        g = self.grid
        fx = (x - g.origin[0]) / g.dx
        fy = (y - g.origin[1]) / g.dy
        on = (fx >= 0.0) & (fy >= 0.0) & (fx < g.nx) & (fy < g.ny)
        col = np.clip(np.floor(np.where(on, fx, 0.0)).astype(np.int64), 0, g.nx - 1)
        row = np.clip(np.floor(np.where(on, fy, 0.0)).astype(np.int64), 0, g.ny - 1)
        return row, col, on

    def likelihood(self, x, y) -> np.ndarray:
        """1 - POD of the cell holding each point (1 off the raster)."""
        row, col, on = self.cells(x, y)
        return np.where(on, self.miss[row, col], 1.0)

    def describe(self) -> dict:
        """Plain data for provenance."""
        values = self.pod if self.pod is not None else self.coverage
        return {"kind": "raster_search", "t": list(self.t), "grid": self.grid.describe(),
                "given": "pod" if self.pod is not None else "coverage", "largest": float(values.max())}
