"""The panels of a scene's map files: ``(layer, t, raster)`` triples on one grid, checked once.

A scene's maps are its layers at its elapsed times. The NetCDF and GeoTIFF writers take them as
a sequence of panels ``(layer_name, t, raster)``: ``layer_name`` a string, ``t`` the elapsed
time in seconds since the fix (t = 0) and ``raster`` a :class:`~bananagrid.Raster` (taken
duck-typed: ``values``, ``grid``, ``mass``, ``normalised``, ``provenance`` and ``frame``; this
package sits below :mod:`bananagrid.results`). :func:`check_panels` refuses what no file could
hold: no panels, panels on different grids or frames, a layer twice at one time, values that
do not fit the grid.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..validate import BananagridError, show

__all__ = ["Panel", "check_panels", "check_cells", "frame_of", "provenance_json", "variable_name", "PROBABILITY"]

#: A NetCDF (and CF) variable name: a letter, then letters, digits and underscores.
_CF_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


@dataclass(frozen=True)
class Panel:
    """One map of a scene: a layer's density at an elapsed time ``t`` (s)."""

    layer: str
    t: float
    raster: object


def _has(raster, name: str) -> bool:
    """Whether ``raster`` has attribute ``name``, without evaluating a property (a tiled raster's
    ``mass`` would compute the whole map)."""
    return name in getattr(raster, "__dict__", {}) or hasattr(type(raster), name)


def check_panels(panels: Sequence, what: str = "panels") -> list[Panel]:
    """The panels as :class:`Panel` objects, in the order given.

    Raises
    ------
    BananagridError
        No panels; an entry that is not ``(layer_name, t, raster)``; an empty layer name; a
        time that is not a finite number; a layer given twice at one time; rasters on different
        grids or different geographic frames; values whose shape is not the grid's.
    """
    if isinstance(panels, (str, bytes)) or not isinstance(panels, Sequence):
        raise BananagridError(f"{what} = {show(panels)}: expected a sequence of (layer_name, t, raster)")
    if len(panels) == 0:
        raise BananagridError(f"{what} is empty: give at least one (layer_name, t, raster)")
    checked, seen = [], set()
    for k, entry in enumerate(panels):
        if not (isinstance(entry, Sequence) and not isinstance(entry, (str, bytes)) and len(entry) == 3):
            raise BananagridError(f"{what}[{k}] = {show(entry)}: expected (layer_name, t, raster)")
        layer, t, raster = entry
        if not isinstance(layer, str) or not layer.strip():
            raise BananagridError(f"{what}[{k}]: layer name {show(layer)} must be a non-empty string")
        if isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)) or not math.isfinite(t):
            raise BananagridError(f"{what}[{k}] ({layer}): t = {show(t)} must be a finite number of seconds")
        if not all(_has(raster, a) for a in ("values", "grid", "mass", "provenance")):
            raise BananagridError(f"{what}[{k}] ({layer}): {type(raster).__name__} is not a Raster")
        if np.shape(raster.values) != raster.grid.shape:
            raise BananagridError(
                f"{what}[{k}] ({layer}): values of shape {np.shape(raster.values)} do not fit the grid's {raster.grid.shape}"
            )
        if (layer, float(t)) in seen:
            raise BananagridError(f"{what}[{k}]: layer {layer!r} is given twice at t = {float(t):g} s")
        seen.add((layer, float(t)))
        checked.append(Panel(layer, float(t), raster))
    first = checked[0].raster.grid
    for k, panel in enumerate(checked[1:], start=1):
        if panel.raster.grid != first:
            raise BananagridError(
                f"{what}[{k}] ({panel.layer}, t = {panel.t:g} s) is on a different grid "
                f"({panel.raster.grid.describe()}) than {what}[0] ({first.describe()}): one file holds one grid"
            )
    frame_of(checked, None, what)
    return checked


#: The ``quantity`` of a raster of cell probabilities (:func:`bananagrid.rasterise` with
#: ``quantity="probability"``): the probability that the target is in each cell.
PROBABILITY = "probability"


def check_cells(cells, panels: Sequence[Panel], what: str = "cells") -> dict[tuple[str, float], object]:
    """The cell probabilities of the panels' maps: ``{(layer, t): raster}``, checked once.

    Parameters
    ----------
    cells : mapping of (str, float) to Raster, or None
        For some layers, their cell probabilities (rasters of ``quantity == "probability"``) at
        every time those layers have a panel, on the panels' grid.
    panels : list of Panel
        The checked panels (:func:`check_panels`).

    Raises
    ------
    BananagridError
        A key that names no panel, a raster that is not one of cell probabilities or lies on
        another grid, or a layer whose probabilities are given at some of its times only (a
        file would have to pad the others).
    """
    if cells is None:
        return {}
    if not hasattr(cells, "items"):
        raise BananagridError(f"{what} = {show(cells)}: expected a mapping of (layer_name, t) to a Raster of cell "
                              "probabilities")
    times: dict[str, set[float]] = {}
    for panel in panels:
        times.setdefault(panel.layer, set()).add(panel.t)
    checked = {}
    for key, raster in cells.items():
        if not (isinstance(key, tuple) and len(key) == 2 and key[0] in times and isinstance(key[1], (int, float))
                and float(key[1]) in times[key[0]]):
            raise BananagridError(f"{what}: key {show(key)} names no map (layer_name, t) of the panels")
        layer, t = key[0], float(key[1])
        if getattr(raster, "quantity", None) != PROBABILITY or not _has(raster, "values") or not _has(raster, "grid"):
            raise BananagridError(f"{what}[{layer!r}, {t:g}]: expected a Raster of cell probabilities "
                                  f"(quantity {PROBABILITY!r}), got {type(raster).__name__}"
                                  f" of quantity {show(getattr(raster, 'quantity', None))}")
        if raster.grid != panels[0].raster.grid or np.shape(raster.values) != raster.grid.shape:
            raise BananagridError(f"{what}[{layer!r}, {t:g}]: not on the panels' grid ({panels[0].raster.grid.describe()})")
        checked[layer, t] = raster
    for layer in {layer for layer, _ in checked}:
        missing = sorted(times[layer] - {t for other, t in checked if other == layer})
        if missing:
            raise BananagridError(f"{what}: layer {layer!r} has cell probabilities at some of its times but not at "
                                  f"t = {', '.join(f'{t:g}' for t in missing)} s; give them at every time or at none")
    return checked


def frame_of(panels: Sequence[Panel], frame, what: str = "panels"):
    """The geographic frame of the panels: ``frame`` if given, else the rasters' common
    ``frame`` (None when they have none).

    Raises
    ------
    BananagridError
        Rasters with different frames and no ``frame`` given to choose.
    """
    if frame is not None:
        return frame
    frames = [getattr(p.raster, "frame", None) for p in panels]
    if any(f != frames[0] for f in frames[1:]):
        raise BananagridError(f"{what}: the rasters lie in different geographic frames; pass frame= to choose one")
    return frames[0]


def variable_name(layer: str, taken: set[str]) -> str:
    """A NetCDF variable name for ``layer``: the name itself when it is one (a letter, then
    letters, digits and underscores), else each other character replaced by ``_`` (and ``L_``
    in front of a leading non-letter).

    Raises
    ------
    BananagridError
        A name that is already ``taken`` (a coordinate's, or another layer's after replacing).
    """
    name = layer if _CF_NAME.fullmatch(layer) else re.sub(r"[^A-Za-z0-9_]", "_", layer)
    if not name[:1].isalpha():
        name = "L_" + name
    if name in taken:
        raise BananagridError(
            f"layer {layer!r}: its variable name {name!r} is already used in the file (by a coordinate or "
            "another layer); rename the layer"
        )
    return name


def provenance_json(provenance) -> str:
    """A provenance dict as one line of JSON (NumPy numbers as numbers, anything else as text)."""
    return json.dumps(provenance, default=_plain, sort_keys=False, allow_nan=True)


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
