"""Where a map's labels go: one placement rule for every text drawn on a map.

rerun draws a point's label centred just below the point, at a fixed size in screen points,
and a line's label at the mean of its vertices: the labels of circles and ellipses about one
point (a fix, its error ellipse, R50 and R95; a start mean and its sigma ellipses) all land on
that point, one over the other. So no map lets rerun choose: every label is a point of a
:class:`LabelBoard`, which places the labels of one map (one layer at one time) in turn, each at
the first of its candidate anchors whose text box

- overlaps no box already placed (screen-relative: the boxes are sized in screen points and
  turned into metres by the map's frame, see :func:`metres_per_point`), and
- lies inside the map's frame (labels of the legend, east of and below the frame, excepted);

the screen is the map's panel in the default layout of a 1600 x 1000 point viewer window (the
size the screenshots are taken at), with :data:`PANEL_SLACK` to spare;

a label with no such anchor is dropped from the map (its line keeps the text: hovering it
shows it) and listed in :attr:`LabelBoard.dropped`. Candidates are points along the label's own
line (a contour, a circle, an ellipse) ordered farthest from the labels placed so far, or for a
point the point itself and then offsets in eight directions, with a leader line back to it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from ..contours import points_along, polyline_length

__all__ = [
    "LabelBoard", "PANEL_POINTS", "PANEL_SLACK", "TEXT_HEIGHT_POINTS", "CHAR_POINTS", "BOX_PADDING_POINTS", "LABEL_GAP_POINTS",
    "metres_per_point", "text_box", "boxes_overlap", "line_candidates", "point_candidates", "leader",
    "log_placed", "place_all", "LABEL_DRAW_ORDER",
]

#: A map panel's size in screen points (width, height) when nothing better is known: one map of
#: three in a row of the default layout in a 1600 x 1000 point window
#: (:func:`bananagrid.recording.blueprint.map_panel_points` gives each layout's).
PANEL_POINTS = (366.0, 330.0)
#: The frame is taken this much larger on screen than the panel fits it: room for a viewer
#: window a little smaller than the reference one, and for the panel's own margins.
PANEL_SLACK = 1.15
#: Height of a label's box (rerun's 12-point text and its dark box), in points.
TEXT_HEIGHT_POINTS = 18.0
#: Mean advance of one character of rerun's label font, in points (measured on the viewer's
#: screenshots: "99 % · 9.34 km²", 15 characters, is a box 105 points wide and 17.5 high).
CHAR_POINTS = 6.5
#: Padding of the box beyond its text, left and right together, in points.
BOX_PADDING_POINTS = 8.0
#: rerun draws a point's label this far below the point, in points.
LABEL_GAP_POINTS = 3.0
#: Points tried along a line for its label.
LINE_CANDIDATES = 48
#: Directions tried for a point label moved off its point: east, west, north, south and between.
_DIRECTIONS = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (1, -1), (-1, -1))


def metres_per_point(frame: tuple[float, float, float, float],
                     panel_points: tuple[float, float] = PANEL_POINTS) -> float:
    """Metres per screen point of a map showing ``frame`` (x0, x1, y0, y1) in a panel of
    ``panel_points`` (width, height): the viewer fits the frame into the panel whole, so the
    tighter of the two sides sets the scale (times :data:`PANEL_SLACK`)."""
    x0, x1, y0, y1 = frame
    width, height = panel_points
    return PANEL_SLACK * max((x1 - x0) / width, (y1 - y0) / height, 1e-300)


def text_box(anchor: Sequence[float], text: str, scale: float, *, y_down: bool = False) -> tuple[float, float, float, float]:
    """The box (x0, x1, y0, y1 in metres, north up) that rerun fills with ``text`` labelling a point
    at ``anchor``, on a map of ``scale`` metres per point: centred on it across, from the point
    down the screen (``y_down``: in a view whose y grows down the screen, an image's rows)."""
    width = (CHAR_POINTS * len(text) + BOX_PADDING_POINTS) * scale
    x, y = float(anchor[0]), float(anchor[1])
    below, above = (LABEL_GAP_POINTS + TEXT_HEIGHT_POINTS) * scale, LABEL_GAP_POINTS * scale
    if y_down:
        return x - 0.5 * width, x + 0.5 * width, y - above, y + below
    return x - 0.5 * width, x + 0.5 * width, y - below, y + above


def boxes_overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two boxes (x0, x1, y0, y1) share more than an edge."""
    return a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]


def _inside(box, frame) -> bool:
    return box[0] >= frame[0] and box[1] <= frame[1] and box[2] >= frame[2] and box[3] <= frame[3]


def line_candidates(pieces: Sequence[np.ndarray], n: int = LINE_CANDIDATES) -> np.ndarray:
    """``n`` points evenly spaced along each piece of a line (longest piece first), (m, 2)."""
    pieces = sorted((np.asarray(p, dtype=float)[:, :2] for p in pieces if len(p) >= 2), key=polyline_length, reverse=True)
    if not pieces:
        return np.empty((0, 2))
    return np.concatenate([points_along(p, n) for p in pieces])


def point_candidates(point: Sequence[float], text: str, scale: float) -> np.ndarray:
    """The point itself, then the point moved in eight directions just clear of it by one and two
    label boxes (east-west by a box's width, north-south by its height)."""
    x, y = float(point[0]), float(point[1])
    width = (CHAR_POINTS * len(text) + BOX_PADDING_POINTS) * scale
    height = (TEXT_HEIGHT_POINTS + 2.0 * LABEL_GAP_POINTS) * scale
    out = [(x, y)]
    for k in (1.0, 2.0):
        for dx, dy in _DIRECTIONS:
            out.append((x + k * dx * (0.5 * width + 4.0 * scale), y + k * dy * height))
    return np.array(out)


@dataclass
class LabelBoard:
    """The labels of one map: placed in turn, none over another, inside ``frame``.

    Parameters
    ----------
    frame : (x0, x1, y0, y1)
        The map's frame in metres (what its view opens on, before the legend's margins).
    panel_points : (float, float)
        The map's panel (width, height) in screen points (:data:`PANEL_POINTS`).
    y_down : bool
        The view's y axis grows down the screen (an image in pixel coordinates), not north.
    """

    frame: tuple[float, float, float, float]
    panel_points: tuple[float, float] = PANEL_POINTS
    y_down: bool = False
    boxes: list[tuple[float, float, float, float]] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)

    @property
    def scale(self) -> float:
        """Metres per screen point (:func:`metres_per_point`)."""
        return metres_per_point(self.frame, self.panel_points)

    def reserve(self, anchor: Sequence[float], text: str) -> None:
        """Hold the box of a label drawn at ``anchor`` whatever the others (the legend's)."""
        self.boxes.append(text_box(anchor, text, self.scale, y_down=self.y_down))
        self.texts.append(text)

    def free(self, anchor: Sequence[float], text: str, *, inside: bool = True) -> bool:
        """Whether ``text`` at ``anchor`` would overlap no placed label (and lie in the frame)."""
        box = text_box(anchor, text, self.scale, y_down=self.y_down)
        if inside and not _inside(box, self.frame):
            return False
        return not any(boxes_overlap(box, other) for other in self.boxes)

    def place(self, text: str, candidates: np.ndarray, *, inside: bool = True) -> tuple[float, float] | None:
        """The first of ``candidates`` ((n, 2), in preference order) where ``text`` is
        :meth:`free`, held from now on; None (and ``text`` in :attr:`dropped`) when none is."""
        for anchor in np.asarray(candidates, dtype=float).reshape(-1, 2):
            if self.free(anchor, text, inside=inside):
                self.reserve(anchor, text)
                return float(anchor[0]), float(anchor[1])
        self.dropped.append(text)
        return None

    def place_on_line(self, text: str, pieces: Sequence[np.ndarray]) -> tuple[float, float] | None:
        """A label on its line: of the points along it, the farthest from the labels placed so
        far comes first (ties: the northernmost), so that nested lines get labels on different
        sides."""
        points = line_candidates(pieces)
        if len(points) == 0:
            return None
        if self.boxes:
            centres = np.array([(0.5 * (b[0] + b[1]), 0.5 * (b[2] + b[3])) for b in self.boxes])
            # screen distance in label heights and widths: text lines are wider than tall
            unit_x = (CHAR_POINTS * 12 + BOX_PADDING_POINTS) * self.scale
            unit_y = TEXT_HEIGHT_POINTS * self.scale
            gaps = np.min(np.hypot((points[:, None, 0] - centres[None, :, 0]) / unit_x,
                                   (points[:, None, 1] - centres[None, :, 1]) / unit_y), axis=1)
        else:
            gaps = np.zeros(len(points))
        order = np.lexsort((points[:, 1] if self.y_down else -points[:, 1], -np.round(gaps, 9)))
        return self.place(text, points[order])

    def place_at_point(self, text: str, point: Sequence[float]) -> tuple[float, float] | None:
        """A point's label: under the point if free, else moved just off it (draw a leader)."""
        return self.place(text, point_candidates(point, text, self.scale))

    def extent(self) -> tuple[float, float, float, float] | None:
        """The smallest extent holding every box placed or reserved (None for none)."""
        if not self.boxes:
            return None
        b = np.array(self.boxes)
        return float(b[:, 0].min()), float(b[:, 1].max()), float(b[:, 2].min()), float(b[:, 3].max())


def leader(point: Sequence[float], anchor: Sequence[float]) -> np.ndarray | None:
    """A line from ``point`` to a label moved off it to ``anchor`` (None where it was not moved)."""
    if math.hypot(anchor[0] - point[0], anchor[1] - point[1]) == 0.0:
        return None
    return np.array([point[:2], anchor[:2]], dtype=float)


#: Labels and leaders draw above the images and the contours.
LABEL_DRAW_ORDER = 40.0


def log_placed(rec, path: str, placed: Sequence[tuple[str, tuple[float, float], Sequence[float] | None]], *,
               three_d_z: float | None = None) -> None:
    """Log placed labels under ``path/labels`` (white points carrying the text, shown) and, for
    each moved off its point, a leader back to it under ``path/leaders``. ``placed`` holds
    ``(text, anchor, point)`` (``point`` None for a label on a line); ``three_d_z``: log them
    in 3D at that height instead (the target plane of an array's cells)."""
    anchors = [anchor for _, anchor, _ in placed]
    texts = [text for text, _, _ in placed]
    leaders = [line for _, anchor, point in placed if point is not None
               for line in [leader(point, anchor)] if line is not None]
    white = [(255, 255, 255)] * len(anchors)
    if three_d_z is None:
        rec.log(f"{path}/labels", rr.Points2D(anchors, labels=texts, colors=white, radii=rr.Radius.ui_points(1.5),
                                              show_labels=True, draw_order=LABEL_DRAW_ORDER))
        rec.log(f"{path}/leaders", rr.LineStrips2D(leaders, colors=(255, 255, 255), radii=rr.Radius.ui_points(0.7),
                                                   draw_order=LABEL_DRAW_ORDER))
    else:
        def lift(xy):
            return [(float(x), float(y), three_d_z) for x, y in np.reshape(xy, (-1, 2))]

        rec.log(f"{path}/labels", rr.Points3D(lift(anchors), labels=texts, colors=white,
                                              radii=rr.Radius.ui_points(1.5), show_labels=True))
        rec.log(f"{path}/leaders", rr.LineStrips3D([lift(line) for line in leaders], colors=(255, 255, 255),
                                                   radii=rr.Radius.ui_points(0.7)))


def place_all(board: LabelBoard, items: Sequence[tuple[str, object]], *, inside: bool = True
              ) -> list[tuple[str, tuple[float, float], Sequence[float] | None]]:
    """Place ``items`` in turn on ``board``: ``(text, point)`` for a point's label (an (x, y)),
    ``(text, pieces)`` for a line's (a list of (n, 2) arrays); the placed ones as
    :func:`log_placed` takes them."""
    out = []
    for text, where in items:
        if isinstance(where, list):
            anchor = board.place_on_line(text, where)
            point = None
        else:
            point = tuple(float(v) for v in np.ravel(where)[:2])
            anchor = board.place(text, point_candidates(point, text, board.scale), inside=inside)
        if anchor is not None:
            out.append((text, anchor, point))
    return out
