"""Where a model's local frame, or a lattice, sits in the world."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ..validate import BananagridWarning, finite, point, radian_doubt

__all__ = ["Pose"]


@dataclass(frozen=True)
class Pose:
    """Where a model's local frame sits in the world.

    Parameters
    ----------
    origin : (float, float)
        World position of the last fix (local origin), metres.
    heading : float
        Initial heading as a bearing in radians clockwise from north: the local +y axis.
    """

    origin: tuple[float, float] = (0.0, 0.0)
    heading: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "origin", point("origin", self.origin))
        object.__setattr__(self, "heading", finite("heading", self.heading))
        doubt = radian_doubt("Pose: heading", self.heading, "rad")
        if doubt is not None:  # a heading beyond a full turn is degrees typed as radians, most likely
            warnings.warn(doubt, BananagridWarning, stacklevel=3)

    def as_array(self) -> np.ndarray:
        """(ox, oy, cos heading, sin heading): the kernels' pose argument."""
        return np.array(
            [self.origin[0], self.origin[1], math.cos(self.heading), math.sin(self.heading)]
        )

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Map (n, 2) local points (x right of heading, y along it) to world (east, north)."""
        c, s = math.cos(self.heading), math.sin(self.heading)
        x, y = local[:, 0], local[:, 1]
        return np.column_stack((self.origin[0] + x * c + y * s, self.origin[1] - x * s + y * c))

    def same_as(self, other: "Pose") -> bool:
        """Whether ``other`` is this pose to rounding (origins within 1e-12 of their scale,
        headings within 1e-12 rad modulo 2 pi)."""
        scale = max(1.0, *map(abs, self.origin), *map(abs, other.origin))
        turn = (self.heading - other.heading + math.pi) % (2.0 * math.pi) - math.pi
        return math.dist(self.origin, other.origin) <= 1e-12 * scale and abs(turn) <= 1e-12
