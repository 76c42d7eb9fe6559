"""Areas a crew can fly: an allocation turned into k rectangles, each searched by parallel
sweeps.

An optimal allocation (:func:`~bananagrid.planning.allocation.allocate`) asks for a different
coverage in every cell; a crew flies a few rectangles at one track spacing each. This module
groups the cells that get effort into k clusters (Lloyd's k-means weighted by each cell's
effort, seeded deterministically), covers each cluster by its smallest rectangle in any
orientation (shapely's ``oriented_envelope`` of the cells' corners), then moves their sides
while that raises the probability of success (the envelopes hold thin tails; a smaller
rectangle searched harder finds more). Each rectangle is flown as whole parallel legs along its
long side, evenly spaced across it (track spacing S_j = w_j / n_j for a width w_j, coverage
W / S_j for a sweep width W, effort W n_j L_j): one leg each, then one leg at a time where it
adds the most probability of success per m^2, as long as the total stays within the
allocation's effort.

The probability of success of the rectangles is recomputed on the map, not taken from the ideal
allocation, so that a planner sees what the rectangles lose: searches of overlapping rectangles
are independent looks, POD = 1 - prod_j (1 - b(c_j)) where they overlap, and by inclusion and
exclusion over the rectangles' intersections

    POS = sum over non-empty sets J of rectangles of (-1)^(|J| + 1) prod_{j in J} b(c_j) M_J,

with M_J the probability inside the intersection of J, each cell's share of it its share of the
cell's area (the map's resolution: a cell's probability is not known finer than the cell).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geo.libraries import require
from ..results import Raster
from ..validate import BananagridError, positive, positive_int
from .allocation import Allocation, optimal_coverage
from .plan_files import PlanGeoJSON

#: Lloyd iterations of the k-means (it stops earlier when no cell changes cluster).
KMEANS_ITERATIONS = 100
#: The most rectangles a plan may have (inclusion and exclusion visits the sets of rectangles
#: that overlap; a crew flies a few).
MAX_RECTANGLES = 16


@dataclass(frozen=True)
class SearchRectangle:
    """One rectangle of a plan, searched by parallel sweeps.

    Attributes
    ----------
    corners : ndarray, shape (4, 2)
        Corners in the map's local metres (x east, y north), counter-clockwise.
    centre : tuple of float
        Its centre, m.
    length, width : float
        The long side (along the tracks) and the short side, m.
    orientation : float
        Bearing of the long side, rad clockwise from north, in [0, pi).
    legs : int
        Parallel legs flown along the long side.
    track_spacing : float
        Distance between legs, m (``width / legs``).
    coverage : float
        Sweep width over track spacing: the coverage flown.
    effort : float
        Effort flown, m^2: sweep width times the legs' length (``legs * length``).
    probability : float
        The probability that the target is inside (from the map's cells).
    pod : float
        b(coverage): the probability of detecting a target that is inside.
    track : ndarray, shape (2 legs, 2)
        Waypoints of the lawnmower track, local metres: each leg end to end, alternating.
    """

    corners: np.ndarray
    centre: tuple[float, float]
    length: float
    width: float
    orientation: float
    legs: int
    track_spacing: float
    coverage: float
    effort: float
    probability: float
    pod: float
    track: np.ndarray


@dataclass(frozen=True)
class SearchPlan(PlanGeoJSON):
    """Rectangles a crew can fly, with their probability of success on the map.

    Attributes
    ----------
    rectangles : tuple of SearchRectangle
    pos : float
        The rectangles' probability of success, recomputed on the map (overlaps as independent
        looks).
    ideal_pos : float
        The allocation's: what an ideal, cell-by-cell spread of the effort would find.
    effort : float
        Effort flown, m^2 (the allocation's, up to the rounding to whole legs).
    sweep_width : float
        W, m.
    law : str
        The detection law's name.
    frame : GeoFrame or None
        Where the map lies on the Earth (for GeoJSON in longitude and latitude).
    """

    rectangles: tuple
    pos: float
    ideal_pos: float
    effort: float
    sweep_width: float
    law: str
    frame: object = None

    def geojson_areas(self) -> list:
        """(polygon, tracks, properties) of each area, for :meth:`geojson`."""
        shapely = require("shapely")
        return [(shapely.Polygon(r.corners), [r.track],
                {"probability": r.probability, "pod": r.pod, "pos": r.probability * r.pod, "coverage": r.coverage,
                 "legs": r.legs, "track_spacing_m": r.track_spacing, "effort_m2": r.effort, "length_m": r.length,
                 "width_m": r.width, "orientation_deg": math.degrees(r.orientation)})
                for r in self.rectangles]


def search_rectangles(allocation: Allocation, k: int, sweep_width: float) -> SearchPlan:
    """Turn an allocation on a grid into ``k`` rectangles flown by parallel sweeps (see the
    module).

    Parameters
    ----------
    allocation : Allocation
        ``bg.allocate(cells, effort, law)`` on a grid map.
    k : int
        How many rectangles (1 to :data:`MAX_RECTANGLES`; fewer when fewer cells get effort).
    sweep_width : float
        W, m: the sensor's sweep width, which sets the track spacing W / coverage.

    Returns
    -------
    SearchPlan
        The rectangles, their tracks, and the probability of success recomputed on the map.
    """
    shapely = require("shapely")
    if not isinstance(allocation, Allocation):
        raise BananagridError(f"allocation = {type(allocation).__name__}: expected the result of bg.allocate")
    if not isinstance(allocation.effort, Raster):
        raise BananagridError("allocation: rectangles are planned on grid maps; this allocation is on a polar lattice")
    k = positive_int("k", k)
    if k > MAX_RECTANGLES:
        raise BananagridError(f"k = {k}: at most {MAX_RECTANGLES} rectangles")
    width = positive("sweep_width", sweep_width)
    grid, p = allocation.effort.grid, np.asarray(allocation.cells, dtype=np.float64)
    active = np.argwhere(allocation.cell_effort > 0.0)  # (row, column) of each cell with effort
    weights = allocation.cell_effort[active[:, 0], active[:, 1]]
    centres = np.column_stack([grid.x[active[:, 1]], grid.y[active[:, 0]]])
    labels = _kmeans(centres, weights, min(k, len(active)))
    boxes = []
    for label in range(labels.max() + 1):
        mine = centres[labels == label]
        if not len(mine):
            continue
        hx, hy = 0.5 * grid.dx, 0.5 * grid.dy
        corners = np.concatenate([mine + (sx * hx, sy * hy) for sx in (-1, 1) for sy in (-1, 1)])
        boxes.append(_rectangle(shapely.oriented_envelope(shapely.MultiPoint(corners)), shapely))
    fitted = _fitted(boxes, p, grid, allocation)
    legs = _legs(fitted, p, grid, allocation, width)
    rectangles = [_flown(_corners(r), _mass_inside(p, grid, shapely.Polygon(_corners(r)), shapely), n, width,
                         allocation.law) for r, n in zip(fitted, legs) if n > 0]
    pos = _pos_with_overlaps(p, grid, rectangles, shapely)
    return SearchPlan(rectangles=tuple(rectangles), pos=pos, ideal_pos=allocation.pos,
                      effort=float(sum(r.effort for r in rectangles)), sweep_width=width, law=allocation.law.name,
                      frame=allocation.effort.frame)


def _kmeans(points: np.ndarray, weights: np.ndarray, k: int) -> np.ndarray:
    """Cluster labels of ``points`` by Lloyd's k-means weighted by ``weights``, seeded by the
    heaviest point and then, one at a time, the point of largest weight times squared distance
    to its nearest seed (a deterministic k-means++)."""
    seeds = [int(np.argmax(weights))]
    nearest = np.sum((points - points[seeds[0]]) ** 2, axis=1)
    for _ in range(1, k):
        seeds.append(int(np.argmax(weights * nearest)))
        nearest = np.minimum(nearest, np.sum((points - points[seeds[-1]]) ** 2, axis=1))
    centres = points[seeds].copy()
    labels = np.full(len(points), -1)
    for _ in range(KMEANS_ITERATIONS):
        new = np.argmin(((points[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2), axis=1)
        if (new == labels).all():
            break
        labels = new
        for c in range(k):
            mine = labels == c
            if mine.any():
                centres[c] = np.average(points[mine], axis=0, weights=weights[mine])
    return labels


def _fitted(boxes: list, p: np.ndarray, grid, allocation: Allocation) -> list:
    """The rectangles with their sides moved, one at a time, while that raises the plan's
    POS: the envelopes of the clusters hold every cell with effort, thin tails included, and a
    smaller rectangle searched harder finds more. The search scores a trial with each cell's
    probability at its centre (fast; the plan's POS is recomputed exactly on the cells after),
    each rectangle searched evenly, the effort split optimally between them and overlaps as
    independent looks. Steps of 20 % down to 1.25 % of the side."""
    points = _PointMasses(p, grid)

    def score(rects):
        inside = points.inside(rects)
        masses = inside.astype(float) @ points.mass
        areas = np.array([4.0 * r[3] * r[4] for r in rects])
        coverage, _, _ = optimal_coverage(masses, areas, allocation.total_effort, allocation.law)
        return points.pos(inside, allocation.law.pod(coverage))

    best = [_frame(c) for c in boxes]
    best_pos = score(best)
    for step in (0.2, 0.1, 0.05, 0.025, 0.0125):
        improved = True
        while improved:
            improved = False
            for j in range(len(best)):
                for side in range(4):
                    for sign in (-1.0, 1.0):
                        moved = _moved(best[j], side, sign * step)
                        if moved is None:
                            continue
                        trial = best[:j] + [moved] + best[j + 1:]
                        pos = score(trial)
                        if pos > best_pos * (1.0 + 1e-12):
                            best, best_pos, improved = trial, pos, True
    return best


class _PointMasses:
    """The map's cells with probability as point masses at their centres (the fitting's fast
    score; the plan's POS is recomputed on the cells after)."""

    def __init__(self, p: np.ndarray, grid):
        rows, cols = np.nonzero(p > 0.0)
        self.xy, self.mass = np.column_stack([grid.x[cols], grid.y[rows]]), p[rows, cols]

    def inside(self, rects) -> np.ndarray:
        return np.stack([_contains(r, self.xy) for r in rects])  # (k, cells)

    def pos(self, inside: np.ndarray, pods: np.ndarray) -> float:
        """POS with rectangle j detecting with ``pods[j]``, overlaps as independent looks."""
        miss = np.prod(np.where(inside, 1.0 - np.asarray(pods)[:, None], 1.0), axis=0)
        return float(np.sum(self.mass * (1.0 - miss)))


def _legs(rects: list, p: np.ndarray, grid, allocation: Allocation, sweep_width: float) -> list[int]:
    """Whole legs per rectangle within the effort: one leg each (the rectangles holding least
    probability dropped, as 0 legs, while even that exceeds the effort), then one leg at a time
    where it adds the most POS per m^2 while the total stays within the effort (the gain of a
    further leg falls as legs are added: the law is concave)."""
    points = _PointMasses(p, grid)
    inside = points.inside(rects)
    # legs run along the long side (as _flown lays them): moving sides may have made the
    # rectangle's first axis the shorter one
    lengths = np.array([2.0 * max(r[3], r[4]) for r in rects])
    widths = np.array([2.0 * min(r[3], r[4]) for r in rects])
    cost = sweep_width * lengths  # m^2 of effort per leg
    legs = np.ones(len(rects), dtype=int)
    order = np.argsort(inside.astype(float) @ points.mass)  # least probability first
    for j in order:
        if legs @ cost <= allocation.total_effort:
            break
        legs[j] = 0

    def pods(n):
        return np.where(n > 0, allocation.law.pod(sweep_width * n / widths), 0.0)

    current = points.pos(inside, pods(legs))
    while True:
        best, best_rate = None, 0.0
        for j in np.flatnonzero(legs > 0):
            if legs @ cost + cost[j] > allocation.total_effort:
                continue
            trial = legs.copy()
            trial[j] += 1
            rate = (points.pos(inside, pods(trial)) - current) / cost[j]
            if rate > best_rate:
                best, best_rate = j, rate
        if best is None:
            return legs.tolist()
        legs[best] += 1
        current = points.pos(inside, pods(legs))


def _frame(corners: np.ndarray) -> tuple[float, float, float, float, float]:
    """A rectangle as (cx, cy, theta, half_length, half_width), theta the bearing of its long
    side in [0, pi)."""
    sides = np.roll(corners, -1, axis=0) - corners
    lengths = np.hypot(sides[:, 0], sides[:, 1])
    long_side = int(np.argmax(lengths[:2]))
    theta = math.atan2(sides[long_side][0], sides[long_side][1]) % math.pi
    cx, cy = corners.mean(axis=0)
    return (float(cx), float(cy), theta, 0.5 * float(lengths[long_side]), 0.5 * float(lengths[1 - long_side]))


def _axes(theta: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors along (bearing theta) and across (90 degrees clockwise of it)."""
    return np.array([math.sin(theta), math.cos(theta)]), np.array([math.cos(theta), -math.sin(theta)])


def _corners(r) -> np.ndarray:
    cx, cy, theta, hl, hw = r
    along, across = _axes(theta)
    c = np.array([cx, cy])
    corners = np.array([c - hl * along - hw * across, c + hl * along - hw * across,
                        c + hl * along + hw * across, c - hl * along + hw * across])
    # counter-clockwise (positive signed area)
    x, y = corners[:, 0], corners[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        corners = corners[::-1]
    return corners


def _contains(r, xy: np.ndarray) -> np.ndarray:
    cx, cy, theta, hl, hw = r
    along, across = _axes(theta)
    d = xy - (cx, cy)
    return (np.abs(d @ along) <= hl) & (np.abs(d @ across) <= hw)


def _moved(r, side: int, fraction: float):
    """The rectangle with one side (0, 1: the ends along it; 2, 3: the long sides) moved
    outwards by ``fraction`` of the rectangle's extent across that side (inwards when
    negative); None where it would vanish."""
    cx, cy, theta, hl, hw = r
    along, across = _axes(theta)
    half = hl if side < 2 else hw
    shift = fraction * half  # the side moves by 2 * half * fraction; the centre by half of it
    if half + shift <= 1e-9 * half:
        return None
    direction = (along, -along, across, -across)[side]
    cx, cy = np.array([cx, cy]) + shift * direction
    return (float(cx), float(cy), theta, hl + shift if side < 2 else hl, hw + shift if side >= 2 else hw)


def _rectangle(envelope, shapely) -> np.ndarray:
    """The four corners of an oriented envelope, counter-clockwise."""
    ring = shapely.geometry.polygon.orient(envelope, sign=1.0).exterior.coords
    return np.asarray(ring)[:4]


def _cell_boxes(grid, polygon, shapely):
    """The rows, columns and boxes of the grid cells that meet ``polygon``'s bounding box."""
    x0, y0, x1, y1 = polygon.bounds
    gx0, gy0 = grid.origin
    j0, j1 = max(0, int(math.floor((x0 - gx0) / grid.dx))), min(grid.nx, int(math.ceil((x1 - gx0) / grid.dx)))
    i0, i1 = max(0, int(math.floor((y0 - gy0) / grid.dy))), min(grid.ny, int(math.ceil((y1 - gy0) / grid.dy)))
    rows, cols = np.meshgrid(np.arange(i0, i1), np.arange(j0, j1), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    boxes = shapely.box(gx0 + cols * grid.dx, gy0 + rows * grid.dy, gx0 + (cols + 1) * grid.dx, gy0 + (rows + 1) * grid.dy)
    return rows, cols, boxes


def _mass_inside(p: np.ndarray, grid, polygon, shapely) -> float:
    """The map's probability inside ``polygon``: each cell's by its share of the cell's area."""
    if polygon.is_empty:
        return 0.0
    rows, cols, boxes = _cell_boxes(grid, polygon, shapely)
    share = shapely.area(shapely.intersection(boxes, polygon)) / grid.cell_area
    return float(np.sum(p[rows, cols] * share))


def _flown(corners: np.ndarray, mass: float, legs: int, sweep_width: float, law) -> SearchRectangle:
    """A rectangle flown as ``legs`` parallel legs along its long side, evenly spaced."""
    sides = np.roll(corners, -1, axis=0) - corners
    lengths = np.hypot(sides[:, 0], sides[:, 1])
    long_side = int(np.argmax(lengths[:2]))
    along, across = sides[long_side] / lengths[long_side], sides[1 - long_side] / lengths[1 - long_side]
    length, width = float(lengths[long_side]), float(lengths[1 - long_side])
    spacing = width / legs
    flown = sweep_width / spacing
    centre = corners.mean(axis=0)
    waypoints = []
    for leg in range(legs):
        offset = (leg + 0.5) * spacing - 0.5 * width
        ends = [-0.5 * length, 0.5 * length][:: 1 if leg % 2 == 0 else -1]
        waypoints += [centre + offset * across + e * along for e in ends]
    orientation = math.atan2(along[0], along[1]) % math.pi
    return SearchRectangle(corners=corners, centre=(float(centre[0]), float(centre[1])), length=length, width=width,
                           orientation=orientation, legs=legs, track_spacing=spacing, coverage=flown,
                           effort=sweep_width * legs * length, probability=mass,
                           pod=float(law.pod(np.array([flown]))[0]), track=np.array(waypoints))


def _pos_with_overlaps(p: np.ndarray, grid, rectangles, shapely) -> float:
    """POS of the rectangles on the map, overlaps as independent looks (inclusion and
    exclusion over the sets of rectangles that intersect; see the module)."""
    polygons = [shapely.Polygon(r.corners) for r in rectangles]
    total = 0.0

    def visit(start: int, region, product: float, size: int):
        nonlocal total
        for j in range(start, len(polygons)):
            piece = polygons[j] if region is None else shapely.intersection(region, polygons[j])
            if piece.is_empty or piece.area <= 0.0:
                continue
            term = product * rectangles[j].pod
            total += (1.0 if size % 2 == 0 else -1.0) * term * _mass_inside(p, grid, piece, shapely)
            visit(j + 1, piece, term, size + 1)

    visit(0, None, 1.0, 0)
    return float(total)
