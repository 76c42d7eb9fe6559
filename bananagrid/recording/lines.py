"""Contour lines and their labels, one colour per level, each label placed once on its line."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from ..contours import label_positions
from .labels import LabelBoard

__all__ = ["CONTOUR_DRAW_ORDER", "LEVEL_COLOURS", "MASS_COLOURS", "log_lines"]


#: Fixed-density contour colours (RGB), one per level in the order given, cycled. Light and
#: saturated so that they stand out on both viridis and turbo.
LEVEL_COLOURS = ((255, 255, 255), (255, 99, 71), (255, 200, 0), (0, 220, 255), (255, 0, 255))

#: Probability-mass contour colours, innermost (50 %) first. The inner regions lie in turbo's
#: red and yellow, the outer ones in its greens and blues: white and magenta show on the former,
#: dark grey and black on the latter.
MASS_COLOURS = ((255, 255, 255), (255, 0, 255), (70, 70, 70), (0, 0, 0))

#: Draw contours above the images in a 2D view.
CONTOUR_DRAW_ORDER = 30.0


def log_lines(
    rec: rr.RecordingStream, path: str, lines: dict[float, list[np.ndarray]], labels: Sequence[str],
    colours: Sequence[tuple[int, int, int]], *, avoid: Sequence[tuple[float, float]] = (),
    board: LabelBoard | None = None,
) -> list[tuple[float, float]]:
    """Contour lines under ``path/lines`` (one colour per level, unlabelled) and one label per
    level under ``path/labels``, placed on its line by the map's ``board``
    (:class:`~bananagrid.recording.labels.LabelBoard`: over no other label of the map, a level
    with no free spot left unlabelled), else apart from the others and from ``avoid``
    (:func:`bananagrid.contours.label_positions`); returns the label positions. Empty lists
    clear both at this time. rerun writes a label in its point's colour on a dark box, so the
    label points are white whatever the line's colour."""
    strips, strip_colours = [], []
    for k, pieces in enumerate(lines.values()):
        strips += pieces
        strip_colours += [colours[k % len(colours)]] * len(pieces)
    rec.log(
        f"{path}/lines",
        rr.LineStrips2D(strips, colors=strip_colours, radii=rr.Radius.ui_points(1.5), draw_order=CONTOUR_DRAW_ORDER),
    )
    text = dict(zip(lines, labels))
    if board is None:
        spots = label_positions(lines, avoid=avoid)
    else:
        spots = {}
        for level, pieces in lines.items():
            spot = board.place_on_line(text[level], pieces)
            if spot is not None:
                spots[level] = spot
    rec.log(
        f"{path}/labels",
        rr.Points2D(
            [spots[level] for level in spots], labels=[text[level] for level in spots],
            colors=[(255, 255, 255)] * len(spots), radii=rr.Radius.ui_points(2.5),
            show_labels=True, draw_order=CONTOUR_DRAW_ORDER + 1,
        ),
    )
    return list(spots.values())
