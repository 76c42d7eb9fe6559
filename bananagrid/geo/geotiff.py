"""A scene's maps as one multi-band GeoTIFF, for QGIS, ArcGIS and GDAL.

:func:`write_geotiff` writes one float32 band per panel ``(layer, t, raster)``, in the order
given, all on the scene's one grid:

* north up: row 0 is the northernmost row of cells (a raster's rows run south to north, so they
  are flipped);
* the affine transform maps pixel corners to projected coordinates: pixel (0, 0)'s outer
  corner is the grid's west and north edges (``E0 + x0``, ``N0 + y0 + ny dy``), pixels are
  ``dx`` wide and ``dy`` high;
* the CRS is the frame's projected CRS (:attr:`~bananagrid.geo.frame.GeoFrame.portable_wkt`, as the
  NetCDF carries it); without a frame there is none, and the
  coordinates are local metres about the origin (a GIS shows the map, but cannot place it);
* no nodata value: every pixel holds a density (0 where the model puts none), and zero is a
  value, not a gap;
* each band's description is ``"LAYER t=T s"``; its tags name the layer, t (s), the UTC time
  (with a frame time), the captured mass, whether it was normalised, and the unit ``m-2``; the
  dataset's tags the bananagrid version, the title and the frame;
* DEFLATE compression with the floating-point predictor; written to a temporary name and renamed
  when complete.

Densities below float32's smallest subnormal (1.4e-45 m^-2) become 0 in the file.

Cell probabilities (panels whose rasters have ``quantity == "probability"``: a scene's
``output.cell_probabilities``) are written the same way to a file of their own, as float64
bands of unit ``1``: exactly the values computed (the .npz's, to the bit), which float32 would
round to 24 bits and flush below 1.4e-45; and a file of one quantity and one unit per band, so
that a GIS's band statistics, colour stretch and sums never mix densities with probabilities.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..validate import BananagridError
from ..version import __version__
from .files import writing
from .frame import iso_utc
from .libraries import require
from .panels import PROBABILITY, check_panels, frame_of

__all__ = ["GEOTIFF_PURPOSE", "band_description", "band_tags", "write_geotiff", "QUANTITIES", "POD"]

GEOTIFF_PURPOSE = "GeoTIFF export"
#: The quantity of a map of the searches' probability of detection (a scene's evidence).
POD = "pod"
#: Per quantity of the panels' rasters: the bands' data type, unit and what they hold.
QUANTITIES = {
    "density": ("float32", "m-2", "probability density of the target's position at the cell centre"),
    PROBABILITY: ("float64", "1", "probability that the target is in the cell (probability of containment, POC)"),
    POD: ("float64", "1", "cumulative probability that the searches would have detected a target in the cell (POD)"),
}


def band_description(layer: str, t: float) -> str:
    """A band's description: ``"LAYER t=T s"`` (``T`` as ``%g``)."""
    return f"{layer} t={t:g} s"


def band_tags(layer: str, t: float, raster, frame) -> dict:
    """A band's metadata: layer, t (s), captured mass, normalised (0 or 1), model, the unit of
    its values, and the UTC time (ISO 8601) where the frame has a time."""
    utc = None if frame is None else frame.utc(t)
    _, unit, quantity = QUANTITIES[_quantity(raster)]
    tags = {
        "layer": layer,
        "t": f"{t!r}",
        "mass": f"{float(raster.mass)!r}",
        "normalised": str(int(bool(getattr(raster, "normalised", False)))),
        "model": str(raster.provenance.get("model", "?")),
        "unit": unit,
        "quantity": quantity,
    }
    if utc is not None:
        tags["utc"] = iso_utc(utc)
    if getattr(raster, "pos", None) is not None:  # a posterior, or its POD map: what the searches would have found
        tags["pos"] = f"{float(raster.pos)!r}"
        tags["search_pos"] = json.dumps(dict(zip(raster.provenance.get("search_names", []),
                                                 map(float, raster.search_pos))))
    return tags


def write_geotiff(path: str | os.PathLike, panels: Sequence, frame=None, *, title: str = "", stage=None) -> Path:
    """Write a scene's maps as one multi-band GeoTIFF (see the module's description): float32
    densities, or float64 cell probabilities.

    Parameters
    ----------
    path : path-like
        The file to write; its directory must exist.
    panels : sequence of (str, float, Raster)
        ``(layer_name, t, raster)``, one band each, all on one grid.
    frame : GeoFrame, optional
        Where the grid lies on the Earth; default the rasters' own ``frame``. Without one the
        file has no CRS.
    title : str
        The scene's title, a dataset tag.
    stage : callable, optional
        Default: written to a temporary name and renamed when complete; a run passes its
        :meth:`bananagrid.atomic.OutputSet.stage` to rename it with its other files.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    BananagridError
        Bad panels (:func:`~bananagrid.geo.panels.check_panels`), panels of densities and cell
        probabilities together, a frame whose CRS's round trip over the grid is off by more than
        1 mm (:meth:`GeoFrame.check_round_trip`), a missing directory, a failure while writing
        (nothing is left behind), or rasterio missing.
    """
    rasterio = require("rasterio", GEOTIFF_PURPOSE)
    transform_of = require("rasterio.transform", GEOTIFF_PURPOSE).from_origin
    checked = check_panels(panels)
    frame = frame_of(checked, frame)
    grid = checked[0].raster.grid
    quantities = {_quantity(p.raster) for p in checked}
    if len(quantities) != 1:
        raise BananagridError(f"GeoTIFF: panels of quantities {', '.join(sorted(quantities))}: one file holds one "
                              "quantity (write the cell probabilities to a file of their own)")
    dtype, unit, _ = QUANTITIES[quantities.pop()]
    if frame is not None:  # a transform that places every pixel where the model put it, to a millimetre
        x0, x1, y0, y1 = grid.extent
        frame.check_round_trip((x0, x1), (y0, y1))
    e0, n0 = (0.0, 0.0) if frame is None else frame.false_origin
    west, north = e0 + grid.origin[0], n0 + grid.origin[1] + grid.ny * grid.dy
    profile = {
        "driver": "GTiff", "width": grid.nx, "height": grid.ny, "count": len(checked), "dtype": dtype,
        "crs": None if frame is None else rasterio.crs.CRS.from_wkt(frame.portable_wkt),
        "transform": transform_of(west, north, grid.dx, grid.dy),
        "nodata": None, "compress": "deflate", "predictor": 3,
    }
    if grid.nx >= 256 and grid.ny >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    tags = {"bananagrid_version": __version__, "title": str(title), "unit": unit,
            "rows": "north to south (row 0 is the north edge)"}
    if frame is not None:
        tags["bananagrid_frame"] = json.dumps(frame.describe())
    final = Path(path)
    with writing(final, "GeoTIFF", (rasterio.errors.RasterioError,), stage=stage) as partial:
        with rasterio.open(partial, "w", **profile) as dst:
            dst.update_tags(**tags)
            for band, panel in enumerate(checked, start=1):
                dst.write(np.asarray(panel.raster.values, dtype=dtype)[::-1], band)
                dst.set_band_description(band, band_description(panel.layer, panel.t))
                dst.set_band_unit(band, unit)
                dst.update_tags(band, **band_tags(panel.layer, panel.t, panel.raster, frame))
    return final


def _quantity(raster) -> str:
    """The raster's quantity (a raster without one holds densities), refused unless a GeoTIFF takes it."""
    quantity = getattr(raster, "quantity", "density")
    if quantity not in QUANTITIES:
        raise BananagridError(f"GeoTIFF: a raster of quantity {quantity!r}; expected one of {', '.join(QUANTITIES)}")
    return quantity
