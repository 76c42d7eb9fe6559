"""Target regions: boxes in the array frame (a line, a plane or a slab of heights)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..validate import BananagridError, pair

__all__ = ["Region", "as_region"]

_AXES = ("x", "y", "z")


def _interval(name: str, value) -> tuple[float, float]:
    lo, hi = pair(name, value)
    if not hi > lo:
        raise BananagridError(
            f"{name} = ({lo!r}, {hi!r}): the region is empty; the upper bound must exceed the lower"
        )
    return lo, hi


@dataclass(frozen=True)
class Region:
    """The target region S: a box with an x range, optionally a y range and a z range.

    The dimension (1, 2 or 3) is the number of ranges given; |S| is its length, area or volume.

    Parameters
    ----------
    x : (float, float)
        ``(x0, x1)``, m, x0 < x1.
    y : (float, float), optional
        ``(y0, y1)``, m (a plane or a slab).
    z : (float, float), optional
        ``(z0, z1)``, m, heights in the array frame (z up, the floor at negative z); needs y.
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
        self._check_size()

    def _check_size(self) -> None:
        """|S| divides every uniform density and conditions every probability: it must be a
        normal float64 number, in [1e-300, 1e300]."""
        ranges = [r for r in (self.x, self.y, self.z) if r is not None]
        # log10 of each width (> 0, subnormal widths too); halved first where hi - lo overflows
        exponent = sum(math.log10(hi - lo) if hi - lo < math.inf else math.log10(0.5 * hi - 0.5 * lo) + math.log10(2.0)
                       for lo, hi in ranges)
        if not (-300.0 <= exponent <= 300.0 and all(hi - lo < math.inf for lo, hi in ranges)):
            unit = ("m", "m^2", "m^3")[len(ranges) - 1]
            measure = ("length", "area", "volume")[len(ranges) - 1]
            raise BananagridError(
                f"region = {self.describe()}: its {measure} is about 1e{exponent:+.0f} {unit}, outside "
                f"[1e-300, 1e300] {unit}; use units that keep it a normal number"
            )

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

    def intersect(self, other: "Region") -> "Region":
        """The box common to this region and ``other`` (of the same dimension)."""
        lo = np.maximum(self.bounds[:, 0], other.bounds[:, 0])
        hi = np.minimum(self.bounds[:, 1], other.bounds[:, 1])
        if np.any(hi <= lo):
            raise BananagridError(f"region {other.describe()} does not overlap the uniform law's region {self.describe()}: empty")
        return Region(*[(float(l), float(h)) for l, h in zip(lo, hi)])


def as_region(region) -> Region:
    """``region`` as a :class:`Region` (a dict with keys x, y, z is accepted too)."""
    if isinstance(region, Region):
        return region
    if isinstance(region, dict):
        try:
            return Region(**region)
        except TypeError:
            raise BananagridError(f"region = {region!r}: expected keys x, y, z") from None
    raise BananagridError(f"region = {region!r}: expected a bananagrid Region (or a dict with x, y, z)")
