"""Reports of where the target was, and where it cannot be: a position report with a normal
error, the bearings of a :class:`~bananagrid.BearingFix`, and land (an exclusion).

Each is a likelihood factor of the target's position, scaled so that its largest value is at
most one (a constant factor cancels in the posterior; at most one keeps the normaliser a
probability-like number that a contradiction drives towards zero).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..models.bearing import bearing_to
from ..validate import BananagridError, covariance, point, positive
from .geometry import Polygon, polygons_from
from .searches import search_time

__all__ = ["PositionReport", "BearingReport", "Exclusion"]


@dataclass(frozen=True)
class PositionReport:
    """A report of the target's position at time ``t`` with a normal error. The likelihood is
    exp(-d^T C^-1 d / 2), d the point minus the report (the normal density without its
    constant).

    Parameters
    ----------
    position : (float, float)
        Reported (x, y), m (world frame).
    t : float
        When, s since the last fix.
    sigma : float, optional
        Standard deviation of a circular error, m (give ``sigma`` or ``cov``).
    cov : array_like, shape (2, 2), optional
        Covariance of the error, m^2.
    """

    position: tuple[float, float]
    t: float
    sigma: float | None = None
    cov: np.ndarray | None = None
    precision: np.ndarray = field(init=False, repr=False, compare=False)

    kind = "report"

    def __post_init__(self):
        object.__setattr__(self, "position", point("position", self.position))
        object.__setattr__(self, "t", search_time("t", self.t)[0])
        if (self.sigma is None) == (self.cov is None):
            raise BananagridError(f"sigma = {self.sigma!r}, cov = {self.cov!r}: give exactly one of them")
        if self.sigma is not None:
            s = positive("sigma", self.sigma)
            object.__setattr__(self, "sigma", s)
            cov = covariance("sigma", [[s * s, 0.0], [0.0, s * s]])
        else:
            cov = covariance("cov", self.cov)
        cov.setflags(write=False)
        object.__setattr__(self, "cov", cov)
        object.__setattr__(self, "precision", np.linalg.inv(cov))

    @property
    def time_span(self) -> tuple[float, float]:
        return self.t, self.t

    def likelihood(self, x, y) -> np.ndarray:
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        dx, dy = x - self.position[0], y - self.position[1]
        p = self.precision
        return np.exp(-0.5 * (p[0, 0] * dx * dx + 2.0 * p[0, 1] * dx * dy + p[1, 1] * dy * dy))

    def describe(self) -> dict:
        return {"kind": "position_report", "t": [self.t, self.t], "position": list(self.position),
                "cov": self.cov.tolist()}


@dataclass(frozen=True)
class BearingReport:
    """The bearings of a fix taken at time ``t``: the likelihood of the exact variant of
    :class:`~bananagrid.BearingFix` without its flat prior and normaliser,

        L(P) = exp(-chi^2(P) / 2),  chi^2(P) = sum_i (wrap(beta_i(P) - b_i) / sigma_i)^2,

    beta_i(P) the bearing from sensor i to P (Walsh's bearings-only likelihood; the fix's exact
    presence map is L divided by its Laplace normaliser).

    Parameters
    ----------
    fix : BearingFix
        Sensors, bearings and their sigmas (either variant: the likelihood is the exact one).
    t : float
        When the bearings were taken, s since the last fix.
    """

    fix: object
    t: float

    kind = "report"

    def __post_init__(self):
        if getattr(self.fix, "kind", None) != "bearing_fix":
            raise BananagridError(f"fix = {self.fix!r}: expected a bananagrid BearingFix")
        object.__setattr__(self, "t", search_time("t", self.t)[0])

    @property
    def time_span(self) -> tuple[float, float]:
        return self.t, self.t

    def likelihood(self, x, y) -> np.ndarray:
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        points = np.column_stack((x.ravel(), y.ravel()))
        chi2 = np.zeros(len(points))
        for sensor, b, s in zip(self.fix.sensors, self.fix.bearings, self.fix.sigmas):
            z = (np.remainder(bearing_to(sensor, points) - b + math.pi, 2.0 * math.pi) - math.pi) / s
            chi2 += z * z
        return np.exp(-0.5 * chi2).reshape(x.shape)

    def describe(self) -> dict:
        return {"kind": "bearings", "t": [self.t, self.t], "sensors": self.fix.sensors.tolist(),
                "bearings": self.fix.bearings.tolist(), "sigmas": self.fix.sigmas.tolist()}


@dataclass(frozen=True)
class Exclusion:
    """A region the target cannot be in (land): likelihood 0 inside, 1 outside, at every time.

    Parameters
    ----------
    polygon : array_like (n, 2), GeoJSON dict, or path to a GeoJSON file
        The region's vertices (m, world frame), or a GeoJSON Polygon, MultiPolygon, Feature or
        FeatureCollection (every outer ring a simple polygon; holes are refused). Several
        polygons exclude their union.
    frame : GeoFrame, optional
        With a frame the coordinates are [longitude, latitude] in degrees (GeoJSON's order,
        RFC 7946), projected to the frame's local metres vertex by vertex (edges straight in
        the local metres); without one they are local metres.
    """

    polygon: object
    frame: object = None
    regions: tuple = field(init=False, repr=False, compare=False)

    kind = "exclusion"
    pod = 1.0
    miss = 0.0

    def __post_init__(self):
        vertices = polygons_from("polygon", self.polygon, self.frame)
        object.__setattr__(self, "regions", tuple(Polygon(v) for v in vertices))

    @property
    def time_span(self) -> None:
        return None  # land holds at every time

    def likelihood(self, x, y) -> np.ndarray:
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        inside = np.zeros(x.shape, dtype=bool)
        for region in self.regions:
            inside |= region.contains(x, y)
        return np.where(inside, 0.0, 1.0)

    def describe(self) -> dict:
        return {"kind": "exclusion", "polygons": len(self.regions), "area_m2": sum(r.area for r in self.regions)}
