"""Polar lattices: cells in (range, bearing) about a pose.

A tracker that gates on range and bearing wants the probability of each (range, bearing) cell,
not a density sampled on a Cartesian grid. :class:`PolarLattice` describes such cells about a
pose; :func:`bananagrid.rasterise` gives, for any model, the density per (m, rad) at each cell
centre and the probability integrated over each cell (see :mod:`bananagrid.engine.polar_cells`).

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
from dataclasses import dataclass, field

import numpy as np

from ..validate import BananagridError, pair, positive, step_ratio
from .grid import MAX_CELLS
from .pose import Pose

__all__ = ["PolarLattice", "DIVIDES_RTOL"]

#: Relative slack for "the step divides the span": span / step within this of a whole number.
DIVIDES_RTOL = 1e-9

_TWO_PI = 2.0 * math.pi


def _count(name: str, step: float, span: float, span_text: str, unit: str) -> int:
    """Number of steps in ``span``; raise unless ``step`` divides it (within DIVIDES_RTOL)."""
    ratio = step_ratio(name, step, span, MAX_CELLS, f" {unit}")
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
        r_min, r_max = pair("ranges", self.ranges)
        b_min, b_max = pair("bearings", self.bearings)
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
        total = 0.5 * (r_max - r_min) * (r_max + r_min) * b_span
        if not math.isfinite(total):  # ranges near 1e154 and beyond: r^2 overflows
            raise BananagridError(
                f"ranges = ({r_min!r}, {r_max!r}): the lattice's area {total!r} m^2 is not a finite number; "
                "use ranges below 1e150 m"
            )
        n_range = _count("range_step", dr, r_max - r_min, "range span", "m")
        n_bearing = _count("bearing_step", db, b_span, "bearing span", "rad")
        smallest = 0.5 * dr * (2.0 * r_min + dr) * db  # the innermost ring's cells
        if not smallest > 0.0:  # subnormal steps: the area underflows to 0
            raise BananagridError(
                f"range_step, bearing_step = {dr!r}, {db!r}: the innermost cells' area {smallest!r} m^2 "
                "underflows; use larger steps"
            )
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
