"""Recording a Butterly layer: what a reviewer needs beside the density.

Under the layer's entity (whose north-up transform :func:`bananagrid.recording.core.log_raster`
has set), in world metres:

- ``geometry/mean``: the start's mean (Points2D);
- ``geometry/ellipses``: the start's 1- and 2-sigma ellipses {x : (x - mean)^T cov^-1 (x - mean)
  = k^2} (LineStrips2D; they hold 39.3 % and 86.5 % of the start);
- ``geometry/rings``: the circles of radius r_i = V_i t about the mean, one per speed (for at most
  :data:`MAX_RINGS` speed nodes; else the smallest and largest), the rings the density follows;
- ``geometry/parameters``: sigma_min, sigma_max, the start's axes angle and r_max / sigma_min.

For an isotropic start (cov = s^2 I) the distance from the mean has Rice's law per speed
(Butterly's Appendix B, ERRATA), and ``range/`` compares the raster with it:
``range/raster`` and ``range/rice`` (BarCharts: the probability per metre in range bins about
the mean, from the raster's cells and from scipy.stats.rice) and ``range/summary``.

:mod:`bananagrid.recording.layers` finds this module by its ``MODEL`` as the Butterly layers' extras
(:func:`log_layer_extras`, :func:`layer_views`).
"""

from __future__ import annotations

import math

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy import stats

from ..models.butterly import Butterly
from ..results import Raster
from .core import entity_path, strict
from .labels import LabelBoard, log_placed, place_all

__all__ = [
    "log_layer_extras", "layer_views", "log_butterly_geometry", "range_comparison", "log_range_comparison",
    "is_isotropic", "start_ellipse", "MAX_RINGS",
]

#: The model class whose layers this module records (:data:`bananagrid.recording.layers.EXTRAS`).
MODEL = Butterly

#: Points per cell side over which a cell's mass is spread when binned by range.
SUB = 4
#: Speed nodes up to which every ring is drawn.
MAX_RINGS = 16
#: Points of each drawn ellipse and circle.
OUTLINE_POINTS = 181

MEAN_COLOUR = (255, 60, 60)
ELLIPSE_COLOURS = ((255, 60, 60), (255, 160, 60))
RING_COLOUR = (255, 255, 255, 120)
RANGE_COLOURS = {"raster": (60, 120, 255), "rice": (255, 60, 60)}


def start_ellipse(model: Butterly, k: float) -> np.ndarray:
    """The k-sigma ellipse of the start, (OUTLINE_POINTS, 2) world points, closed."""
    values, vectors = np.linalg.eigh(model.cov)
    angle = np.linspace(0.0, 2.0 * math.pi, OUTLINE_POINTS)
    unit = np.column_stack((np.cos(angle), np.sin(angle))) * (k * np.sqrt(values))
    return np.asarray(model.mean) + unit @ vectors.T


def _circle(centre, radius: float) -> np.ndarray:
    angle = np.linspace(0.0, 2.0 * math.pi, OUTLINE_POINTS)
    return np.asarray(centre) + radius * np.column_stack((np.sin(angle), np.cos(angle)))


def is_isotropic(model: Butterly) -> bool:
    """Whether the start covariance is s^2 I (to 1e-12 relative), where Rice's law holds."""
    c = model.cov
    return abs(c[0, 0] - c[1, 1]) <= 1e-12 * c[0, 0] and abs(c[0, 1]) <= 1e-12 * c[0, 0]


def layer_extent(model: Butterly) -> tuple[float, float, float, float]:
    """What the layer's map must hold beside its regions: the start's 2-sigma ellipse
    (x0, x1, y0, y1, m)."""
    points = start_ellipse(model, 2.0)
    return float(points[:, 0].min()), float(points[:, 0].max()), float(points[:, 1].min()), float(points[:, 1].max())


def log_butterly_geometry(rec: rr.RecordingStream, entity: str, model: Butterly, *,
                          board: LabelBoard | None = None) -> None:
    """Log the start's mean, 1- and 2-sigma ellipses, the speeds' rings and the scales under
    ``entity`` (``layers/NAME/geometry``).

    The texts stay on their primitives for hovering and are drawn as ``labels`` placed by the
    map's label ``board`` (:mod:`bananagrid.recording.labels`; a board of the start's own
    :func:`layer_extent` if none): the mean's first, then each ellipse and each ring on its
    line, none over another (a ring's label with no free spot is left off)."""
    entity = entity_path(entity)
    s1, s2, beta = model.axes
    ranges = np.unique(model.ranges)
    if ranges.size > MAX_RINGS:
        ranges = ranges[[0, -1]]
    board = LabelBoard(layer_extent(model)) if board is None else board
    ellipses = [start_ellipse(model, 1.0), start_ellipse(model, 2.0)]
    ellipse_texts = ["1 sigma (39.3 %)", "2 sigma (86.5 %)"]
    rings = [_circle(model.mean, float(r)) for r in ranges if r > 0.0]
    ring_texts = [f"r = {r:.0f} m" for r in ranges if r > 0.0]
    placed = place_all(board, [("start mean", model.mean), *((t, [e]) for t, e in zip(ellipse_texts, ellipses)),
                               *((t, [r]) for t, r in zip(ring_texts, rings))])
    with strict():
        rec.log(f"{entity}/mean", rr.Points2D([model.mean], colors=MEAN_COLOUR, radii=rr.Radius.ui_points(5.0),
                                              labels=["start mean"], show_labels=False))
        rec.log(
            f"{entity}/ellipses",
            rr.LineStrips2D(ellipses, colors=list(ELLIPSE_COLOURS), radii=rr.Radius.ui_points(1.5),
                            labels=ellipse_texts, show_labels=False),
        )
        if rings:
            rec.log(
                f"{entity}/rings",
                rr.LineStrips2D(rings, colors=RING_COLOUR, radii=rr.Radius.ui_points(0.7),
                                labels=ring_texts, show_labels=False),
            )
        log_placed(rec, entity, placed)
        rec.log(
            f"{entity}/parameters",
            rr.AnyValues(sigma_min=math.sqrt(s1), sigma_max=math.sqrt(s2), axis_angle_deg=math.degrees(beta),
                         r_max_over_sigma_min=float(model.ranges.max()) / math.sqrt(s1), t=model.t),
        )


def range_comparison(raster: Raster, model: Butterly) -> dict:
    """Probability per metre of the distance R from the start mean in bins, from the raster
    (its cells' mass binned by the distance of their centres) and from Rice's law (the exact
    mass of each bin, sum_i w_i [F(R1) - F(R0)], F the scipy.stats.rice CDF with b = r_i / s
    and scale s), over the largest disc about the mean inside the grid. Bins are the larger
    of 2 cells and s / 5 wide. Each cell's mass is spread evenly over SUB x SUB points in it
    before binning (the density is known at the centre only), which leaves an error of about
    the density's change across a cell (the midpoint rule's) and of the binning of those
    points near the bin edges: a few 1e-3 of the peak at cells of s / 20 (tests/scenes/test_scene.py).

    Returns
    -------
    dict
        ``R`` (bin centres, m), ``width`` (m), ``raster`` and ``rice`` (per m), and
        ``max_abs_difference`` and ``max_rice`` (per m).
    """
    if not is_isotropic(model):
        raise ValueError("Rice's law needs an isotropic start covariance")
    grid = raster.grid
    s = math.sqrt(model.cov[0, 0])
    mx, my = model.mean
    reach = min(mx - (grid.x[0] - 0.5 * grid.dx), (grid.x[-1] + 0.5 * grid.dx) - mx,
                my - (grid.y[0] - 0.5 * grid.dy), (grid.y[-1] + 0.5 * grid.dy) - my)
    width = max(2.0 * max(grid.dx, grid.dy), s / 5.0)
    n_bins = int(reach // width)
    if n_bins < 1:
        return {"R": np.zeros(0), "width": width, "raster": np.zeros(0), "rice": np.zeros(0),
                "max_abs_difference": 0.0, "max_rice": 0.0}
    edges = width * np.arange(n_bins + 1)
    # each cell's mass split evenly over SUB x SUB points inside it, binned by their distance
    offsets = (np.arange(SUB) + 0.5) / SUB - 0.5
    mass = np.zeros(n_bins)
    cell_mass = raster.values * (grid.cell_area / SUB**2)
    for oy in offsets:
        for ox in offsets:
            distance = np.hypot(*np.meshgrid(grid.x + ox * grid.dx - mx, grid.y + oy * grid.dy - my))
            mass += np.histogram(distance, bins=edges, weights=cell_mass)[0]
    speeds, weights = model.speed_nodes
    cdf = sum(w * stats.rice.cdf(edges, r / s, scale=s) for r, w in zip(speeds * model.t, weights))
    rice = np.diff(cdf) / width
    got = mass / width
    return {"R": 0.5 * (edges[1:] + edges[:-1]), "width": width, "raster": got, "rice": rice,
            "max_abs_difference": float(np.max(np.abs(got - rice))), "max_rice": float(np.max(rice))}


def log_range_comparison(rec: rr.RecordingStream, entity: str, raster: Raster, model: Butterly) -> dict:
    """Log :func:`range_comparison` under ``entity`` (``layers/NAME/range``); returns it."""
    result = range_comparison(raster, model)
    root = entity_path(entity)
    widths = np.full(result["R"].size, result["width"])
    with strict():
        for name in ("raster", "rice"):
            rec.log(f"{root}/{name}", rr.BarChart(result[name], abscissa=result["R"], widths=widths, color=RANGE_COLOURS[name]))
        rec.log(
            f"{root}/summary",
            rr.AnyValues(max_abs_difference_per_m=result["max_abs_difference"], max_rice_per_m=result["max_rice"],
                         relative_to_peak=result["max_abs_difference"] / result["max_rice"] if result["max_rice"] > 0 else 0.0,
                         bin_width_m=result["width"]),
        )
    return result


def log_layer_extras(rec: rr.RecordingStream, entity: str, model: Butterly, raster: Raster, *, compute,
                     board: LabelBoard | None = None) -> None:
    """Beside a Butterly layer: the start's geometry (``entity/geometry``, labelled on the map's
    ``board``) and, for an isotropic start, the raster's range law beside Rice's
    (``entity/range``)."""
    log_butterly_geometry(rec, f"{entity}/geometry", model, board=board)
    if is_isotropic(model):
        log_range_comparison(rec, f"{entity}/range", raster, model)


def layer_views(entity: str, model: Butterly) -> tuple[list[str], list]:
    """For an isotropic start, a bar-chart view of the range laws."""
    if not is_isotropic(model):
        return [], []
    name = entity.rsplit("/", 1)[-1]
    return [], [rrb.BarChartView(origin=f"/{entity}/range", name=f"{name}: range vs Rice")]
