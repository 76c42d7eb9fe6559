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

from ..domains.grid import Grid
from ..results import Raster
from ..validate import BananagridError
from .core import ELAPSED, values_from_image
from .inspect import _BUFFER, _FORMAT, _decode_image, _open, _plain, _rows

__all__ = ["RecordedRaster", "read_rasters"]


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
    reader, store = _open(path)
    images, transforms, infos = {}, {}, {}
    for name, times, cells in _rows(reader, store):
        parts = name.strip("/").split("/")
        if len(parts) != 3 or parts[0] != "layers":
            continue
        key = (parts[1], times.get(ELAPSED, (None, 0))[1])
        if parts[2] == "density":
            if _BUFFER in cells and _FORMAT in cells:
                images[key] = _decode_image(cells[_BUFFER][1], cells[_FORMAT][1])
            if "Transform3D:translation" in cells:
                transforms[key] = (_plain(cells["Transform3D:translation"][1]), _plain(cells["Transform3D:scale"][1]))
        elif parts[2] == "info":
            infos[key] = {component: _plain(value) for component, (_, value) in cells.items()}
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
