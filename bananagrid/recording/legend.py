"""A map's legend: the log10 colour bar east of its frame and a scale bar below it."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr

__all__ = ["COLOUR_BAR_PIXELS", "format_length", "log_legend", "nice_length"]


#: Pixels along the log10 colour bar.
COLOUR_BAR_PIXELS = 256


def log_legend(rec: rr.RecordingStream, path: str, extent: tuple, floor: float, top: float, colormap: str) -> None:
    """A scale bar below ``extent`` (the map's frame, see :func:`focus_extent`) and a log10
    colour bar east of it, in world metres.

    The colour bar is a one-pixel-wide image of ``COLOUR_BAR_PIXELS`` values from ``floor``
    (south end) to ``top`` (north end) in the log10 image's colormap and range, with a label
    at each whole decade; the scale bar is the roundest length (1, 2 or 5 x 10^k m) no longer
    than a quarter of the grid's width.
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
    bar_x0, bar_w = x1 + 0.03 * width, 0.025 * width
    ramp = np.linspace(top, floor, COLOUR_BAR_PIXELS, dtype=np.float32)[:, None]  # row 0 is the top
    rec.log(
        f"{path}/colour_bar",
        rr.DepthImage(ramp, meter=1.0, colormap=colormap, depth_range=(floor, top)),
        rr.Transform3D(translation=(bar_x0, y1, 0.0), scale=(bar_w, -height / COLOUR_BAR_PIXELS, 1.0)),
    )
    decades = np.arange(math.ceil(floor), math.floor(top) + 1)
    ticks = [(bar_x0 + bar_w, y0 + (d - floor) / (top - floor) * height) for d in decades]
    rec.log(
        f"{path}/ticks",
        rr.Points2D(
            ticks + [(bar_x0, y1 + 0.04 * height)],
            labels=[f"1e{int(d)}" for d in decades] + ["log10 m^-2"],
            colors=[(255, 255, 255)] * (len(ticks) + 1), radii=rr.Radius.ui_points(1.0), show_labels=True,
        ),
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
