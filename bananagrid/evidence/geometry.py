"""Plane geometry of evidence: polygons against grid cells and sub-cells, tracks against points,
and polygons read from vertices or GeoJSON (longitude and latitude through a frame).

Everything here is float64 NumPy, exact but for rounding where it says so: the area of a
polygon inside a rectangle (the clipped trapezoid rule below), which cells an edge touches
(Liang-Barsky clipping, closed rectangles), which points a polygon holds (even-odd rule), and the
integral of 1 / r^3 along a segment (the inverse-cube law's exposure), in a form without the
cancellation of its textbook antiderivative.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from ..validate import BananagridError, polygon

__all__ = ["Polygon", "polygons_from", "segment_inverse_cube", "distance_to_track"]


class Polygon:
    """A validated simple polygon (vertices ``(n, 2)``, from :func:`bananagrid.validate.polygon`),
    held counter-clockwise, with its area and bounding box."""

    def __init__(self, vertices: np.ndarray):
        v = np.asarray(vertices, dtype=np.float64)
        local = v - v[0]
        signed = 0.5 * math.fsum(local[:, 0] * np.roll(local[:, 1], -1) - np.roll(local[:, 0], -1) * local[:, 1])
        self.vertices = v if signed > 0.0 else v[::-1].copy()
        self.vertices.setflags(write=False)
        self.area = abs(signed)
        self.bounds = (float(v[:, 0].min()), float(v[:, 0].max()), float(v[:, 1].min()), float(v[:, 1].max()))

    @property
    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Start and end points of every edge, each ``(n, 2)``."""
        return self.vertices, np.roll(self.vertices, -1, axis=0)

    def contains(self, x, y) -> np.ndarray:
        """Whether each point (broadcast ``x``, ``y``) is inside (even-odd rule; a point on the
        boundary may fall either way, a set of zero area)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        inside = np.zeros(x.shape, dtype=bool)
        x0, x1, y0, y1 = self.bounds
        near = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)  # outside the box: outside
        px, py = x[near], y[near]
        hit = np.zeros(px.shape, dtype=bool)
        a, b = self.edges
        for (ax, ay), (bx, by) in zip(a, b):
            straddles = (ay > py) != (by > py)
            with np.errstate(divide="ignore", invalid="ignore"):
                cross_x = ax + (py - ay) * (bx - ax) / (by - ay)
            hit ^= straddles & (px < cross_x)
        inside[near] = hit
        return inside

    def contains_grid(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """:meth:`contains` at the points (x[j], y[i]) of a grid, ``(len(y), len(x))``, row by
        row: the crossings of a row's line with the edges, sorted, and each point's count of
        crossings east of it (odd: inside). O(rows x edges + points) instead of O(points x edges)."""
        a, b = self.edges
        inside = np.zeros((len(y), len(x)), dtype=bool)
        for i, yi in enumerate(y):
            straddles = (a[:, 1] > yi) != (b[:, 1] > yi)
            if not straddles.any():
                continue
            pa, pb = a[straddles], b[straddles]
            cross = np.sort(pa[:, 0] + (yi - pa[:, 1]) * (pb[:, 0] - pa[:, 0]) / (pb[:, 1] - pa[:, 1]))
            east = len(cross) - np.searchsorted(cross, x, side="right")  # crossings with x < cross
            inside[i] = east % 2 == 1
        return inside

    def fraction(self, x0, x1, y0, y1) -> np.ndarray:
        """Fraction of each rectangle ``[x0, x1] x [y0, y1]`` (broadcast arrays) inside the polygon.

        For a counter-clockwise polygon the area inside a rectangle is, on each vertical line
        x in [x0, x1], the length of the line's part inside both: the sum over the polygon's edges
        of -int c(y_edge(x)) dx, with c(y) = clamp(y, y0, y1) - y0 (the lower edges of the
        polygon run east, the upper ones west). c of a linear function integrates in closed form
        (:func:`_mean_clamped`). Exact but for rounding: coordinates are taken relative to each
        rectangle's corner, so the rounding is of the rectangle's size, not of the world's.
        """
        x0, x1, y0, y1 = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x0, x1, y0, y1)))
        shape = x0.shape
        x0, x1, y0, y1 = (v.ravel() for v in (x0, x1, y0, y1))
        # rectangles sorted by their west edge: an edge reaches only those whose west edge lies
        # within the widest rectangle's width west of the edge's east end (a band, by bisection)
        order = np.argsort(x0, kind="stable")
        x0, x1, y0, y1 = x0[order], x1[order], y0[order], y1[order]
        width, height = x1 - x0, y1 - y0
        widest = float(width.max()) if width.size else 0.0
        area = np.zeros(x0.shape)
        a, b = self.edges
        for (ax, ay), (bx, by) in zip(a, b):
            if ax == bx:
                continue  # a vertical edge encloses no area between vertical lines
            lo_edge, hi_edge = min(ax, bx), max(ax, bx)
            band = slice(int(np.searchsorted(x0, lo_edge - widest, side="left")),
                         int(np.searchsorted(x0, hi_edge, side="right")))
            bx0, by0, bw, bh = x0[band], y0[band], width[band], height[band]
            # the edge in each rectangle's own coordinates (origin at its south-west corner)
            pax, pay, pbx, pby = ax - bx0, ay - by0, bx - bx0, by - by0
            lo = np.clip(np.minimum(pax, pbx), 0.0, bw)
            hi = np.clip(np.maximum(pax, pbx), 0.0, bw)
            slope = (pby - pay) / (pbx - pax)
            ya = pay + slope * (lo - pax)
            yb = pay + slope * (hi - pax)
            area[band] -= math.copysign(1.0, bx - ax) * (hi - lo) * _mean_clamped(ya, yb, bh)
        out = np.empty(x0.shape)
        out[order] = np.clip(area / (width * height), 0.0, 1.0)
        return out.reshape(shape)

    def cells_touched(self, x_edges: np.ndarray, y_edges: np.ndarray) -> np.ndarray:
        """Mask ``(ny, nx)`` of the cells of a grid (cell edges ``x_edges`` (nx + 1,), ``y_edges``
        (ny + 1,)) that a polygon edge touches or crosses (closed cells: an edge along a cell's
        side touches both neighbours). Every other cell is wholly inside or wholly outside."""
        nx, ny = len(x_edges) - 1, len(y_edges) - 1
        touched = np.zeros((ny, nx), dtype=bool)
        a, b = self.edges
        for p, q in zip(a, b):
            # candidate cells: those of the edge's bounding box, one more on each side for rounding
            j0 = max(int(np.searchsorted(x_edges, min(p[0], q[0]), side="right")) - 2, 0)
            j1 = min(int(np.searchsorted(x_edges, max(p[0], q[0]), side="left")) + 1, nx)
            i0 = max(int(np.searchsorted(y_edges, min(p[1], q[1]), side="right")) - 2, 0)
            i1 = min(int(np.searchsorted(y_edges, max(p[1], q[1]), side="left")) + 1, ny)
            if j0 >= j1 or i0 >= i1:
                continue
            cx0, cx1 = x_edges[j0:j1][None, :], x_edges[j0 + 1:j1 + 1][None, :]
            cy0, cy1 = y_edges[i0:i1][:, None], y_edges[i0 + 1:i1 + 1][:, None]
            touched[i0:i1, j0:j1] |= _segment_meets_box(p, q, cx0, cx1, cy0, cy1)
        return touched


def _rings(name: str, value) -> list:
    """The polygons' outer rings of a GeoJSON object (a dict, or a path to a file)."""
    if isinstance(value, (str, os.PathLike)):
        path = Path(value)
        try:
            value = json.loads(path.read_text(encoding="utf-8"))
        except OSError as error:
            raise BananagridError(f"{name} = {str(path)!r}: cannot read it ({error.strerror or error})") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise BananagridError(f"{name} = {str(path)!r}: not a GeoJSON file ({error})") from None
    if not isinstance(value, dict):
        raise BananagridError(f"{name}: a GeoJSON {type(value).__name__}; expected a GeoJSON object")
    kind = value.get("type")
    if kind == "FeatureCollection":
        return [ring for feature in value.get("features", []) for ring in _rings(name, feature)]
    if kind == "Feature":
        return _rings(name, value.get("geometry") or {})
    if kind in ("Polygon", "MultiPolygon"):
        polygons = [value.get("coordinates")] if kind == "Polygon" else value.get("coordinates") or []
        rings = []
        for rings_of_one in polygons:
            if not isinstance(rings_of_one, list) or not rings_of_one:
                raise BananagridError(f"{name}: a {kind} without coordinates")
            if len(rings_of_one) > 1:
                raise BananagridError(f"{name}: a polygon with {len(rings_of_one) - 1} hole(s); "
                                      "give the land as polygons without holes")
            rings.append(rings_of_one[0])
        return rings
    raise BananagridError(f"{name}: GeoJSON type {kind!r}; expected a Polygon, MultiPolygon, Feature or "
                          "FeatureCollection of them")


def polygons_from(name: str, value, frame=None) -> list[np.ndarray]:
    """Validated vertex arrays (read-only, local metres) of ``value``: vertices ``(n, 2)``, a
    GeoJSON dict, or a path to a GeoJSON file. With ``frame`` (a GeoFrame) the coordinates
    are [longitude, latitude] degrees, projected by ``frame.local`` vertex by vertex."""
    if isinstance(value, (dict, str, os.PathLike)):
        rings = _rings(name, value)
        if not rings:
            raise BananagridError(f"{name}: the GeoJSON holds no polygon")
        names = [f"{name}[{k}]" for k in range(len(rings))] if len(rings) > 1 else [name]
    else:
        rings, names = [value], [name]
    out = []
    for label, ring in zip(names, rings):
        if frame is not None:
            lonlat = polygon(label, ring)  # finite, simple in degrees first: then each vertex projects
            x, y = frame.local(lonlat[:, 1], lonlat[:, 0])
            ring = np.column_stack((x, y))
        vertices = polygon(label, ring)
        vertices.setflags(write=False)
        out.append(vertices)
    return out


def _mean_clamped(ya, yb, height):
    """Mean over a segment of c(y) = clamp(y, 0, height), y running linearly from ``ya`` to ``yb``.

    With ya <= yb (the mean is symmetric), the fractions of the segment below 0 and below
    ``height`` are t1 = (0 - ya) / (yb - ya) and t2 = (height - ya) / (yb - ya), clipped to
    [0, 1]; the mean is (t2 - t1) times the middle piece's mean, (max(ya, 0) + min(yb, height))
    / 2, plus (1 - t2) height: sums of non-negative terms, without the cancellation of the
    antiderivative's difference quotient.
    """
    lo, hi = np.minimum(ya, yb), np.maximum(ya, yb)
    span = hi - lo
    flat = span == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.clip(-lo / span, 0.0, 1.0)
        t2 = np.clip((height - lo) / span, 0.0, 1.0)
    middle = 0.5 * (np.clip(lo, 0.0, height) + np.clip(hi, 0.0, height))
    mean = (t2 - t1) * middle + (1.0 - t2) * height
    return np.where(flat, np.clip(lo, 0.0, height), mean)


def _segment_meets_box(p, q, x0, x1, y0, y1) -> np.ndarray:
    """Whether the segment p-q meets each closed box (broadcast bounds): Liang-Barsky clipping."""
    dx, dy = q[0] - p[0], q[1] - p[1]
    t0 = np.zeros(np.broadcast(x0, x1, y0, y1).shape)
    t1 = np.ones_like(t0)
    ok = np.ones(t0.shape, dtype=bool)
    for direction, low, high, start in ((dx, x0, x1, p[0]), (dy, y0, y1, p[1])):
        if direction == 0.0:
            ok &= (low <= start) & (start <= high)
            continue
        ta, tb = (low - start) / direction, (high - start) / direction
        t0 = np.maximum(t0, np.minimum(ta, tb))
        t1 = np.minimum(t1, np.maximum(ta, tb))
    return ok & (t0 <= t1)


def segment_inverse_cube(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """int ds / r^3 along the segment a-b for each point (``points`` (m, 2)): inf on the segment.

    With the point at lateral distance x from the segment's line and the segment's ends at
    signed positions s1 < s2 along it, the integral is [s / (x^2 R)] from s1 to s2, R =
    sqrt(x^2 + s^2). Where s1 and s2 have the same sign the difference cancels when x << |s|;
    written as (s2^2 - s1^2) / (R1 R2 (s2 R1 + s1 R2)) (multiply out) it does not, and it holds
    at x = 0 too (a point on the line beyond an end: (1 / s1^2 - 1 / s2^2) / 2).
    """
    d = b - a
    length = math.hypot(d[0], d[1])
    u = d / length
    rel = points - a
    s1 = -(rel[:, 0] * u[0] + rel[:, 1] * u[1])  # the segment runs from s1 to s2 = s1 + length
    s2 = s1 + length
    x = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
    x2 = x * x
    r1, r2 = np.sqrt(x2 + s1 * s1), np.sqrt(x2 + s2 * s2)
    with np.errstate(divide="ignore", invalid="ignore"):
        opposite = s2 / (x2 * r2) - s1 / (x2 * r1)  # s1 < 0 < s2: two terms of one sign
        # both ends on one side: |s| of each, in the cancellation-free form
        n1, n2 = np.minimum(np.abs(s1), np.abs(s2)), np.maximum(np.abs(s1), np.abs(s2))
        m1, m2 = np.sqrt(x2 + n1 * n1), np.sqrt(x2 + n2 * n2)
        same = (n2 - n1) * (n2 + n1) / (m1 * m2 * (n2 * m1 + n1 * m2))
    out = np.where((s1 < 0.0) & (s2 > 0.0), opposite, same)
    return np.where(np.isnan(out), np.inf, out)  # 0 / 0: the point is an end of the segment


def distance_to_track(points: np.ndarray, track: np.ndarray) -> np.ndarray:
    """Least distance from each point (``(m, 2)``) to the polyline ``track`` (``(n, 2)``)."""
    best = np.full(len(points), np.inf)
    for a, b in zip(track[:-1], track[1:]):
        d = b - a
        dd = float(d @ d)
        rel = points - a
        t = np.clip((rel @ d) / dd, 0.0, 1.0) if dd > 0.0 else np.zeros(len(points))
        gap = rel - t[:, None] * d
        best = np.minimum(best, np.hypot(gap[:, 0], gap[:, 1]))
    return best
