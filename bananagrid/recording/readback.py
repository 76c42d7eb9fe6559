"""Read a bananagrid recording's layers back as rasters (for pictures and checks without a
viewer).

Each layer ``layers/NAME`` holds, per elapsed time, its density image (rows north first) with a
``Transform3D`` from pixels to world metres (translation = the north-west corner, scale =
``(dx, -dy)``, see :func:`bananagrid.recording.core.log_raster`) and its ``info`` values; this
rebuilds the :class:`~bananagrid.domains.grid.Grid` from them and the values from the float32
image.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..contours import DEFAULT_MASS_LEVELS, format_area, mass_regions
from ..domains.grid import Grid
from ..results import Raster
from ..validate import BananagridError
from .core import ELAPSED, values_from_image
from .inspect import IMAGE_BUFFER, IMAGE_FORMAT, decode_image, open_recording, plain_cell, recording_rows

__all__ = ["RecordedRaster", "format_layers", "layer_summaries", "read_rasters"]


@dataclass(frozen=True)
class RecordedRaster:
    """One layer at one elapsed time, read back from a recording.

    Attributes
    ----------
    layer : str
        Layer name (``"cat"``).
    entity : str
        Its entity (``"layers/cat"``).
    t : float
        Elapsed time, s.
    raster : Raster
        float64 of the recorded float32 density, on the rebuilt grid; ``mass`` and
        ``normalised`` from the layer's info, provenance the info's ``provenance.*`` values.
    """

    layer: str
    entity: str
    t: float
    raster: Raster


def read_rasters(path: str | os.PathLike) -> list[RecordedRaster]:
    """Every density layer of a recording written by ``bananagrid run``, by time then layer.

    Raises
    ------
    BananagridError
        If the file is not a readable recording, or holds no density layer.
    """
    reader, store = open_recording(path)
    images, transforms, infos = {}, {}, {}
    for name, times, cells in recording_rows(reader, store):
        parts = name.strip("/").split("/")
        if len(parts) != 3 or parts[0] != "layers":
            continue
        key = (parts[1], times.get(ELAPSED, (None, 0))[1])
        if parts[2] == "density":
            if IMAGE_BUFFER in cells and IMAGE_FORMAT in cells:
                images[key] = decode_image(cells[IMAGE_BUFFER][1], cells[IMAGE_FORMAT][1])
            if "Transform3D:translation" in cells:
                transforms[key] = (plain_cell(cells["Transform3D:translation"][1]), plain_cell(cells["Transform3D:scale"][1]))
        elif parts[2] == "info":
            infos[key] = {component: plain_cell(value) for component, (_, value) in cells.items()}
    out = []
    for (layer, nanos), image in sorted(images.items(), key=lambda item: (item[0][1], item[0][0])):
        if (layer, nanos) not in transforms:
            raise BananagridError(f"{path}: layers/{layer}/density has no pixel-to-world transform")
        (x0, y1, _), (dx, dy, _) = transforms[(layer, nanos)]
        values = values_from_image(image).astype(np.float64)
        ny, nx = values.shape
        grid = Grid(origin=(float(x0), float(y1) + float(dy) * ny), dx=float(dx), dy=-float(dy), nx=nx, ny=ny)
        info = {k.removeprefix("AnyValues:"): v for k, v in infos.get((layer, nanos), {}).items()}
        provenance = {k.removeprefix("provenance."): v for k, v in info.items() if k.startswith("provenance.")}
        raster = Raster(values=values, grid=grid, mass=float(info.get("mass", np.nan)),
                        normalised=info.get("normalised") == "true", provenance=provenance)
        out.append(RecordedRaster(layer, f"layers/{layer}", nanos / 1e9, raster))
    if not out:
        raise BananagridError(f"{path}: no density layers (layers/NAME/density); is it a scene recording?")
    return out


def layer_summaries(path: str | os.PathLike, levels=DEFAULT_MASS_LEVELS) -> list[dict]:
    """Where the target is, per layer and time of a recording: ``layer``, ``t`` (s), ``mass``
    (captured, from the layer's info), ``peak`` (m^-2) and ``peak_x``, ``peak_y`` (its cell
    centre, m), and ``regions`` (:meth:`MassRegion.describe` of the probability-mass regions at
    ``levels``, from the recorded float32 image). Empty for a recording without density layers
    (an array scene's)."""
    try:
        recorded = read_rasters(path)
    except BananagridError as exc:
        if "no density layers" in str(exc):
            return []
        raise
    out = []
    for item in recorded:
        raster = item.raster
        i, j = np.unravel_index(int(np.argmax(raster.values)), raster.values.shape)
        out.append({
            "layer": item.layer, "t": item.t, "mass": raster.mass, "peak": raster.peak,
            "peak_x": float(raster.x[j]), "peak_y": float(raster.y[i]),
            "regions": [r.describe() for r in mass_regions(raster, levels)],
        })
    return out


def format_layers(layers: list[dict]) -> list[str]:
    """Report lines for :func:`layer_summaries`: one block per layer and time."""
    lines = []
    for item in layers:
        lines.append(f"  {item['layer']} at t = {item['t']:g} s: captured mass {item['mass']:.6f}, "
                     f"peak {item['peak']:.4g} m^-2 at (x, y) = ({item['peak_x']:.6g}, {item['peak_y']:.6g}) m")
        for r in item["regions"]:
            shown = (f"{format_area(r['area'])} ({r['area']:.6g} m^2), {r['cells']:,} cells, holds {r['enclosed']:.6f}"
                     if r["reached"] else f"not reached (the grid holds {r['enclosed']:.6f})")
            lines.append(f"    {100 * r['probability']:g} % region: {shown}")
    return lines
