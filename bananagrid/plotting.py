"""Pictures of rasters with matplotlib (the ``plot`` extra): a map a reviewer reads without a
viewer.

The map is log10 of the density in km (x east, y north, north up, equal aspect), a colour bar in
log10 m^-2 floored two decades below the 99 % region's boundary, the probability-mass contours
(:func:`bananagrid.contours.mass_regions`) each labelled once on its line with its area, and
optional markers (a fix, bearing stations). matplotlib is loaded (with importlib, like the
registry's recording modules) only when a picture is drawn, so the rest of the package never
needs it.

Rasters are taken duck-typed (``values``, ``x``, ``y``, ``grid``, ``mass``, ``provenance``): this
module sits below :mod:`bananagrid.results`, whose ``Raster.plot`` calls it.
"""

from __future__ import annotations

import base64
import html
import importlib
import io
import math
from collections.abc import Iterable, Sequence

import numpy as np

from .contours import (
    DEFAULT_MASS_LEVELS,
    contour_lines,
    focus_extent,
    format_area,
    format_level,
    label_positions,
    mass_regions,
)
from .validate import BananagridError

__all__ = ["FLOOR_DECADES", "MASS_COLOURS", "plot_raster", "png_bytes", "raster_html", "pyplot"]

#: The colour scale starts this many decades below the lowest contour drawn.
FLOOR_DECADES = 2.0

#: Contour colours, innermost (50 %) first; they read on turbo's reds and blues alike.
MASS_COLOURS = ("white", "magenta", "dimgrey", "black")


def pyplot():
    """``matplotlib.pyplot`` with a non-interactive backend when none is chosen; a one-line
    error naming the extra when matplotlib is not installed."""
    try:
        matplotlib = importlib.import_module("matplotlib")  # optional: loaded on first use
    except ImportError:
        raise BananagridError(
            "pictures need matplotlib: pip install 'bananagrid[plot]' (or pip install matplotlib)"
        ) from None
    if not matplotlib.get_backend() or matplotlib.get_backend().lower().startswith("qt"):
        matplotlib.use("Agg")
    return importlib.import_module("matplotlib.pyplot")


def plot_raster(
    raster,
    ax=None,
    *,
    mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS,
    title: str | None = None,
    markers: Sequence[tuple[float, float, str]] = (),
    colorbar: bool = True,
):
    """Draw ``raster`` on ``ax`` (a new figure's axes by default) and return the axes.

    Parameters
    ----------
    raster : Raster
        Density per m^2 on a grid.
    ax : matplotlib Axes, optional
        Where to draw.
    mass_levels : iterable of float
        Probability-mass levels in (0, 1) whose contours are drawn and labelled.
    title : str, optional
        Default: the model's name and elapsed time from the provenance.
    markers : sequence of (x, y, label)
        Points to mark, in metres (a fix, stations).
    colorbar : bool
        Whether to add the log10 colour bar.

    Returns
    -------
    matplotlib Axes
        With the map as its first image, one ``Line2D`` per contour piece (``gid`` =
        ``"mass-contour-<probability>"``) and one label ``Text`` per level.
    """
    plt = pyplot()
    values = np.asarray(raster.values, dtype=np.float64)
    if values.ndim != 2 or not np.all(np.isfinite(values)):
        raise BananagridError("raster values must be a finite 2-D array to be drawn")
    if ax is None:
        _, ax = plt.subplots(figsize=(7.0, 5.0), layout="constrained")
    regions = [r for r in mass_regions(raster, mass_levels) if r.reached]
    lowest = min((r.density for r in regions), default=float(values.max()) * 1e-4)
    floor = math.log10(lowest) - FLOOR_DECADES if lowest > 0.0 else -12.0
    with np.errstate(divide="ignore"):
        logs = np.where(values > 10.0**floor, np.log10(np.where(values > 0.0, values, 1.0)), floor)
    top = max(float(logs.max()), floor + 1.0)
    x0, x1, y0, y1 = raster.grid.extent
    image = ax.imshow(logs, origin="lower", extent=(x0 / 1e3, x1 / 1e3, y0 / 1e3, y1 / 1e3),
                      cmap="turbo", vmin=floor, vmax=top, interpolation="nearest")
    lines = contour_lines(raster, [r.density for r in regions])
    for k, (region, pieces) in enumerate(zip(regions, lines.values())):
        for piece in pieces:
            ax.plot(piece[:, 0] / 1e3, piece[:, 1] / 1e3, color=MASS_COLOURS[k % len(MASS_COLOURS)],
                    linewidth=1.2, gid=f"mass-contour-{region.probability:g}")
    spots = label_positions(lines)
    for region, level in zip(regions, lines):
        if level in spots:
            x, y = spots[level]
            ax.text(x / 1e3, y / 1e3, format_level(region), fontsize=8, ha="center", va="center",
                    bbox={"boxstyle": "round,pad=0.2", "facecolor": "white", "alpha": 0.8, "linewidth": 0})
    for x, y, label in markers:  # (off the frame when far away, e.g. distant stations)
        ax.plot([x / 1e3], [y / 1e3], marker="^", color="white", markeredgecolor="black", markersize=8)
        ax.annotate(label, (x / 1e3, y / 1e3), textcoords="offset points", xytext=(5, 5), fontsize=8, color="white")
    # framed on the outermost region (padded), like the recordings' default view
    fx0, fx1, fy0, fy1 = focus_extent(raster, regions)
    ax.set_xlim(fx0 / 1e3, fx1 / 1e3)
    ax.set_ylim(fy0 / 1e3, fy1 / 1e3)
    ax.set_aspect("equal")
    ax.set_xlabel("x east [km]")
    ax.set_ylabel("y north [km]")
    ax.set_title(title if title is not None else _default_title(raster), fontsize=10)
    if colorbar:
        ax.figure.colorbar(image, ax=ax, label="log10 density [m⁻²]", shrink=0.85)
    return ax


def png_bytes(raster, *, dpi: int = 80, **kwargs) -> bytes:
    """A PNG of :func:`plot_raster` on a new figure (for notebooks' ``_repr_png_``)."""
    plt = pyplot()
    ax = plot_raster(raster, **kwargs)
    buffer = io.BytesIO()
    ax.figure.savefig(buffer, format="png", dpi=dpi)
    plt.close(ax.figure)
    return buffer.getvalue()


def raster_html(raster) -> str:
    """A small HTML summary (grid, mass, peak, the probability-mass regions) and the picture
    as an embedded PNG when matplotlib is installed."""
    grid = raster.grid
    rows = [
        ("grid", f"{grid.nx} x {grid.ny} cells of {grid.dx:g} x {grid.dy:g} m, x {grid.extent[0]:g} .. {grid.extent[1]:g} m, "
                 f"y {grid.extent[2]:g} .. {grid.extent[3]:g} m"),
        ("captured mass", f"{raster.mass:.6f}" + (" (normalised)" if getattr(raster, "normalised", False) else "")),
        ("peak", f"{float(np.max(raster.values)):.4g} m⁻²"),
    ]
    rows += [(f"{100 * r.probability:g} % region", f"{format_area(r.area)}, holds {r.enclosed:.4f}" if r.reached else "not reached")
             for r in mass_regions(raster)]
    table = "".join(f"<tr><th style='text-align:left'>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows)
    try:
        picture = base64.b64encode(png_bytes(raster)).decode("ascii")
        image = f"<img src='data:image/png;base64,{picture}'/>"
    except BananagridError as exc:  # no matplotlib: the table alone, saying why
        image = f"<p>{html.escape(str(exc))}</p>"
    return f"<div><table>{table}</table>{image}</div>"


def _default_title(raster) -> str:
    provenance = getattr(raster, "provenance", {}) or {}
    model = provenance.get("model", "raster")
    t = (provenance.get("parameters") or {}).get("t", provenance.get("t"))
    return f"{model}, t = {t:g} s" if isinstance(t, (int, float)) else str(model)
