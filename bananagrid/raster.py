"""Rasterised results and the one place that launches kernels."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .grid import Grid

__all__ = ["Raster"]


@dataclass(frozen=True)
class Raster:
    """A model's density sampled at the cell centres of a grid.

    Attributes
    ----------
    values : ndarray, shape (ny, nx)
        Density per square metre at each cell centre (``quantity == "density"``); rows south
        to north. After :meth:`normalise` the values are scaled so that they sum to one over the
        grid (times the cell area).
    grid : Grid
        The grid the values belong to.
    mass : float
        Probability mass captured by the grid before any normalisation: ``sum(values) * dx * dy``
        of the raw density (midpoint rule). A value well below one says the grid misses mass.
    normalised : bool
        Whether ``values`` were divided by ``mass``.
    provenance : dict
        Model name and parameters, kernel, dtype, device, threads, seconds, truncation.
    """

    values: np.ndarray
    grid: Grid
    mass: float
    normalised: bool = False
    quantity: str = "density"
    provenance: dict = field(default_factory=dict)

    @property
    def x(self) -> np.ndarray:
        return self.grid.x

    @property
    def y(self) -> np.ndarray:
        return self.grid.y

    @property
    def peak(self) -> float:
        return float(np.max(self.values))

    def normalise(self) -> "Raster":
        """Return a copy whose values integrate to one over the grid; ``mass`` keeps the raw mass."""
        if not self.mass > 0.0:
            raise ValueError("cannot normalise a raster that captured no mass")
        if self.normalised:
            return self
        return replace(self, values=self.values / self.mass, normalised=True)
