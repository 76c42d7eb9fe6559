"""A map's legend: the log10 colour bar east of its frame and a scale bar below it."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

from .labels import LabelBoard

__all__ = ["COLOUR_BAR_PIXELS", "SHARED_TITLE", "format_length", "log_legend", "log_shared_colour_bar", "nice_length"]

#: The title of a colour bar shared by every map of a scene (:func:`log_shared_colour_bar`).
SHARED_TITLE = "log10 m^-2 · all maps"


#: Pixels along the log10 colour bar.
COLOUR_BAR_PIXELS = 256
#: The colour bar draws above the maps' images (rerun's default for images is -10) and below
#: the contours.
COLOUR_BAR_DRAW_ORDER = 20.0


def log_legend(rec: rr.RecordingStream, path: str, extent: tuple, floor: float, top: float, colormap: str,
               board: LabelBoard | None = None) -> None:
    """A scale bar below ``extent`` (the map's frame, see :func:`focus_extent`) and a log10
    colour bar east of it, in world metres.

    The colour bar is a one-pixel-wide image of ``COLOUR_BAR_PIXELS`` values from ``floor``
    (south end) to ``top`` (north end) in the log10 image's colormap and range, with a label
    at each whole decade; the scale bar is the roundest length (1, 2 or 5 x 10^k m) no longer
    than a quarter of the grid's width. With the map's label ``board``, the legend's labels are
    held there first (the map's own labels keep clear of them), and a decade whose label would
    overlap another's is left unlabelled (a short bar with many decades).
    """
    x0, x1, y0, y1 = extent
    width, height = x1 - x0, y1 - y0
    length = nice_length(width / 4.0)
    below = y0 - 0.05 * height
    rec.log(
        f"{path}/scale",
        rr.LineStrips2D(
            [[(x0, below), (x0 + length, below)]], colors=[(255, 255, 255)], radii=rr.Radius.ui_points(2.0),
            labels=[format_length(length)], show_labels=True,
        ),
    )
    if board is not None:
        board.reserve((x0 + 0.5 * length, below), format_length(length))
    _colour_bar(rec, path, extent, floor, top, colormap, board, "log10 m^-2")


def log_shared_colour_bar(rec: rr.RecordingStream, path: str, extent: tuple, floor: float, top: float, colormap: str,
                          panel: tuple[float, float]) -> None:
    """A colour bar east of ``extent`` for the range (``floor``, ``top``) that every map of a scene
    shares (:class:`~bananagrid.recording.blueprint.ColourRange`), static, titled
    :data:`SHARED_TITLE`: drawn as :func:`log_legend` draws a map's own, where a map's view
    shows it instead of its own (the labels of the map keep clear of the legend's place)."""
    _colour_bar(rec, path, extent, floor, top, colormap, LabelBoard(extent, panel), SHARED_TITLE, static=True)


def _colour_bar(rec, path: str, extent: tuple, floor: float, top: float, colormap: str, board, title_text: str,
                *, static: bool = False) -> None:
    """The colour bar east of ``extent``, its decade labels (thinned on ``board``) and its title."""
    x0, x1, y0, y1 = extent
    width, height = x1 - x0, y1 - y0
    bar_x0, bar_w = x1 + 0.03 * width, 0.025 * width
    ramp = np.linspace(top, floor, COLOUR_BAR_PIXELS, dtype=np.float32)[:, None]  # row 0 is the top
    rec.log(
        f"{path}/colour_bar",
        # above the map's image, which may reach under the legend (the frame is inside the grid)
        rr.DepthImage(ramp, meter=1.0, colormap=colormap, depth_range=(floor, top), draw_order=COLOUR_BAR_DRAW_ORDER),
        rr.Transform3D(translation=(bar_x0, y1, 0.0), scale=(bar_w, -height / COLOUR_BAR_PIXELS, 1.0)),
        static=static,
    )
    decades = np.arange(math.ceil(floor), math.floor(top) + 1)
    ticks = [(bar_x0 + bar_w, y0 + (d - floor) / (top - floor) * height) for d in decades]
    texts = [f"1e{int(d)}" for d in decades]
    title = (bar_x0, y1 + 0.04 * height)
    if board is not None:
        # the longer of the two titles: a shared bar may be shown here instead (same place)
        board.reserve(title, max(title_text, SHARED_TITLE, key=len))
        kept = [k for k, (tick, text) in enumerate(zip(ticks, texts))
                if board.place(text, np.array([tick]), inside=False) is not None]
        ticks, texts = [ticks[k] for k in kept], [texts[k] for k in kept]
    rec.log(
        f"{path}/ticks",
        rr.Points2D(
            ticks + [title],
            labels=texts + [title_text],
            colors=[(255, 255, 255)] * (len(ticks) + 1), radii=rr.Radius.ui_points(1.0), show_labels=True,
        ),
        static=static,
    )


def nice_length(limit: float) -> float:
    """The largest 1, 2 or 5 x 10^k not above ``limit`` (> 0)."""
    exponent = math.floor(math.log10(limit))
    for mantissa in (5.0, 2.0, 1.0):
        if mantissa * 10.0**exponent <= limit:
            return mantissa * 10.0**exponent
    return 10.0**exponent


def format_length(metres: float) -> str:
    """``500 m``, ``2 km``, ``0.5 m``."""
    if metres >= 1000.0:
        return f"{metres / 1000.0:g} km"
    return f"{metres:g} m"
