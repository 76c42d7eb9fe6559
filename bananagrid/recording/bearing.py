"""Recording a bearing fix: sensors, bearing lines with +-2 sigma wedges, the fix, its error
ellipse and R50 / R95 circles, the difference of the exact and linear maps, and the
linearisation validation table. Everything is in world metres under a layer entity, whose
north-up transform :func:`bananagrid.recording.core.log_raster` has set. The registry names this
module as the ``bearing_fix`` kind's recording extras (:func:`log_layer_extras`,
:func:`layer_views`)."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from ..analysis.bearing_validation import format_table, summary, validation_table
from ..models.bearing import BearingFix
from ..results import Raster
from .core import entity_path, log_signed_image, strict
from .labels import LabelBoard, log_placed, place_all

__all__ = [
    "log_layer_extras", "layer_views", "log_scene_extras", "scene_texts", "log_bearing_geometry", "log_difference", "log_validation_table",
    "WEDGE_SIGMAS",
]

#: The model class whose layers this module records (:data:`bananagrid.recording.layers.EXTRAS`).
MODEL = BearingFix

#: Half-width of the drawn bearing wedges, in sigmas.
WEDGE_SIGMAS = 2.0
#: Points of the drawn ellipse and circles.
OUTLINE_POINTS = 181

SENSOR_COLOUR = (255, 255, 255)
LINE_COLOUR = (255, 200, 0)
WEDGE_COLOUR = (255, 200, 0, 110)
FIX_COLOUR = (255, 60, 60)
ELLIPSE_COLOUR = (255, 60, 60)
CIRCLE_COLOURS = {"R50": (0, 220, 255), "R95": (255, 0, 255)}


def _ray(origin: np.ndarray, bearing: float, length: float) -> np.ndarray:
    return np.array([origin, origin + length * np.array([math.sin(bearing), math.cos(bearing)])])


def _circle(centre: np.ndarray, radius: float) -> np.ndarray:
    angle = np.linspace(0.0, 2.0 * math.pi, OUTLINE_POINTS)
    return centre + radius * np.column_stack((np.cos(angle), np.sin(angle)))


def _ellipse(fix: BearingFix, k: float) -> np.ndarray:
    """The k-sigma ellipse {P : (P - fix)^T C^-1 (P - fix) = k^2} as a closed polyline."""
    values, vectors = np.linalg.eigh(fix.covariance)
    angle = np.linspace(0.0, 2.0 * math.pi, OUTLINE_POINTS)
    unit = np.column_stack((np.cos(angle), np.sin(angle))) * (k * np.sqrt(values))
    return fix.fix + unit @ vectors.T


def layer_extent(fix: BearingFix, ellipse_k: float = 2.0) -> tuple[float, float, float, float]:
    """What the layer's map must hold beside its regions: the fix, its ``ellipse_k``-sigma
    ellipse and its R95 circle (x0, x1, y0, y1, m). The stations and the bearing lines reach
    beyond, often tens of kilometres: they are a zoom-out away."""
    r95 = float(fix.radius([0.95])[0])
    points = np.concatenate([_ellipse(fix, ellipse_k), _circle(fix.fix, r95)])
    return float(points[:, 0].min()), float(points[:, 0].max()), float(points[:, 1].min()), float(points[:, 1].max())


def log_bearing_geometry(rec: rr.RecordingStream, entity: str, fix: BearingFix, *, ellipse_k: float = 2.0,
                         board: LabelBoard | None = None) -> None:
    """Log the fix's geometry under ``entity``: ``sensors`` (points), ``bearings`` (lines to
    1.5 times the farthest sensor-fix range), ``wedges`` (+-WEDGE_SIGMAS sigma), ``fix``,
    ``ellipse`` (the ``ellipse_k``-sigma ellipse), ``circles`` (R50 and R95 about the fix).

    The texts (the fix, the ellipse, R50, R95, the stations) are kept on their primitives for
    hovering and drawn as ``labels`` placed by the map's label ``board``
    (:mod:`bananagrid.recording.labels`; a board of the fix's own :func:`layer_extent` if none):
    the fix's first, then R50, the ellipse and R95 on their lines, none over another."""
    entity = entity_path(entity)
    reach = 1.5 * float(np.max(np.hypot(*(fix.fix - fix.sensors).T)))
    r50, r95 = (float(r) for r in fix.radius([0.5, 0.95]))
    ellipse = fix.ellipse(ellipse_k)
    board = LabelBoard(layer_extent(fix, ellipse_k)) if board is None else board
    sensor_texts = [f"sensor {i}" for i in range(len(fix.sensors))]
    ellipse_text = f"{ellipse_k:g}-sigma ellipse ({ellipse['probability']:.3f})"
    circle_texts = [f"R50 = {r50:.0f} m", f"R95 = {r95:.0f} m"]
    placed = place_all(board, [("fix", fix.fix), (circle_texts[0], [_circle(fix.fix, r50)]),
                               (ellipse_text, [_ellipse(fix, ellipse_k)]), (circle_texts[1], [_circle(fix.fix, r95)])])
    # the stations are often far outside the map: their labels need only keep clear of each other
    placed += place_all(board, list(zip(sensor_texts, fix.sensors)), inside=False)
    with strict():
        rec.log(
            f"{entity}/sensors",
            rr.Points2D(fix.sensors, colors=SENSOR_COLOUR, radii=rr.Radius.ui_points(6.0),
                        labels=sensor_texts, show_labels=False),
        )
        rec.log(
            f"{entity}/bearings",
            rr.LineStrips2D([_ray(s, b, reach) for s, b in zip(fix.sensors, fix.bearings)],
                            colors=LINE_COLOUR, radii=rr.Radius.ui_points(1.0)),
        )
        wedges = [
            _ray(s, b + side * WEDGE_SIGMAS * sd, reach)
            for s, b, sd in zip(fix.sensors, fix.bearings, fix.sigmas) for side in (-1.0, 1.0)
        ]
        rec.log(f"{entity}/wedges", rr.LineStrips2D(wedges, colors=WEDGE_COLOUR, radii=rr.Radius.ui_points(0.7)))
        rec.log(f"{entity}/fix", rr.Points2D([fix.fix], colors=FIX_COLOUR, radii=rr.Radius.ui_points(5.0), labels=["fix"],
                                             show_labels=False))
        rec.log(
            f"{entity}/ellipse",
            rr.LineStrips2D([_ellipse(fix, ellipse_k)], colors=ELLIPSE_COLOUR, radii=rr.Radius.ui_points(1.5),
                            labels=[ellipse_text], show_labels=False),
        )
        rec.log(
            f"{entity}/circles",
            rr.LineStrips2D([_circle(fix.fix, r50), _circle(fix.fix, r95)],
                            colors=[CIRCLE_COLOURS["R50"], CIRCLE_COLOURS["R95"]], radii=rr.Radius.ui_points(1.5),
                            labels=circle_texts, show_labels=False),
        )
        log_placed(rec, entity, placed)
        rec.log(
            f"{entity}/containment",
            rr.AnyValues(r50=r50, r95=r95, fix_x=float(fix.fix[0]), fix_y=float(fix.fix[1]),
                         semi_major=float(ellipse["semi_major"]), semi_minor=float(ellipse["semi_minor"])),
        )


def log_difference(rec: rr.RecordingStream, path: str, exact: Raster, linear: Raster) -> None:
    """exact - linear (both as given, e.g. normalised), per m^2, as an image with a diverging
    colormap symmetric about zero, placed in world metres like the layer's density."""
    log_signed_image(rec, path, exact.values - linear.values, exact)


def log_validation_table(rec: rr.RecordingStream, entity: str, table_text: str, summary: str) -> None:
    """The linearisation validation table (``bearing_validation.format_table``) as markdown."""
    with strict():
        rec.log(
            entity_path(entity),
            rr.TextDocument(f"{summary}\n\n```\n{table_text}\n```", media_type=rr.MediaType.MARKDOWN),
            static=True,
        )


def log_layer_extras(rec: rr.RecordingStream, entity: str, fix: BearingFix, raster: Raster, *, compute,
                     board: LabelBoard | None = None) -> None:
    """Beside a bearing-fix layer: its geometry (``entity/geometry``, labelled on the map's
    ``board``) and, for the exact map, its difference to the linear one
    (``entity/difference_to_linear``; ``compute(model)`` rasterises the linear fix as the layer
    was)."""
    log_bearing_geometry(rec, f"{entity}/geometry", fix, board=board)
    if fix.variant == "exact":
        log_difference(rec, f"{entity}/difference_to_linear", raster, compute(fix.with_variant("linear")))


def layer_views(entity: str, fix: BearingFix) -> tuple[list[str], list]:
    """The exact map's difference image as one more tab of the layer; no further views."""
    return (["difference_to_linear"] if fix.variant == "exact" else []), []


#: The entity of the validation table (``output.bearing_validation``).
VALIDATION_ENTITY = "validation"


def log_scene_extras(rec: rr.RecordingStream, options) -> None:
    """With the scene's ``output.bearing_validation``: the linearisation validation table (Monte
    Carlo of the true two-bearing geometry over crossing angles and bearing errors; a few
    seconds) as the text entity ``validation``."""
    if options.get("bearing_validation"):
        records = validation_table()
        log_validation_table(rec, VALIDATION_ENTITY, format_table(records), summary(records))


def scene_texts(options) -> list[str]:
    """The text entities :func:`log_scene_extras` logs for ``options``."""
    return [VALIDATION_ENTITY] if options.get("bearing_validation") else []
