"""The angular-cell domain of a scene's run: an ``[array]`` scene's presence law on its lattice,
recorded (:func:`bananagrid.recording.presence.log_cell_map`) and exported to the .npz.

:func:`bananagrid.scenes.run.run_scene` drives it (:class:`CellRun`) as it drives the grid
layers (:class:`bananagrid.scenes.run_grid.GridRun`): the same checks, planned files, progress,
jobs and summary rows.
"""

from __future__ import annotations

import contextlib
import json
import time
import warnings
from pathlib import Path

import numpy as np

from ..atomic import OutputSet, OutputWriteError
from ..engine.rasterise import rasterise
from ..recording.core import recording_id_for
from ..recording.presence import log_cell_map, plane_eye, presence_blueprint
from ..results import CellMap
from ..validate import BananagridError, BananagridWarning
from ..version import __version__
from .load import Layer, Scene
from .run_outputs import NPZ

__all__ = ["CellRun"]


class CellRun:
    """The outputs of an ``[array]`` scene's run: its one layer, the presence law, as a cell map
    recorded to ``OUT/NAME.rrd`` and, with ``npz``, exported to ``OUT/NAME.npz``.

    The .npz holds ``prob`` indexed ``[azimuth, elevation]`` by integer degrees (shape
    (360, 181); line: ``prob[azimuth]``, (361,)), NaN for directions not in the lattice;
    ``cells`` (the same in lattice order, ``(n_azimuth, n_elevation)``), ``error`` (error
    estimate per cell), ``azimuth_deg`` and ``elevation_deg`` (uint16 direction of each lattice
    index), ``azimuth_edges_deg`` and ``elevation_edges_deg`` (cell bounds), ``sizes`` (cell
    length, area or volume; inf at the horizon), ``clipped_sizes`` (within the room, when there
    is one), for the line ``x_edges`` (m), and ``provenance`` (a JSON string).

    Parameters are those of :class:`~bananagrid.scenes.run_grid.GridRun`; the map files are
    refused before (:meth:`check_exports`).
    """

    @staticmethod
    def check_exports(scene: Scene, *, netcdf: bool = False, geotiff: bool = False, geojson: bool = False,
                      kml: bool = False) -> None:
        """Refuse map files: angular cells are not a grid."""
        asked = [option for option, wanted in (("--netcdf", netcdf), ("--geotiff", geotiff), ("--geojson", geojson),
                                               ("--kml", kml)) if wanted]
        if asked:
            raise BananagridError(f"{scene.source}: {', '.join(asked)}: an [array] scene maps angular cells, "
                                  "not a grid; its cell tables are in the .rrd and .npz")

    @staticmethod
    def check_memory(scene: Scene, *, exports: bool = False, limit: float | None = None) -> None:
        """None: an angular lattice is bounded in size (integer degrees: at most 360 x 181 cells)."""
        return None

    @staticmethod
    def check_work(scene: Scene, *, threads: int | None = None, limit: float | None = None) -> None:
        """None: as :meth:`check_memory`."""
        return None

    def __init__(self, scene: Scene, out_dir: Path, outputs: OutputSet, *, npz: bool = False, netcdf: bool = False,
                 geotiff: bool = False, geojson: bool = False, kml: bool = False, threads: int | None = None):
        self.scene = scene
        self.outputs = outputs
        self.npz_path = Path(out_dir) / f"{scene.name}.npz" if npz else None
        self.threads = threads

    def recording_id(self) -> str:
        """Depends on the scene text (the lattice is the scene's own)."""
        return recording_id_for(self.scene.text)

    def blueprint(self):
        """The cell map's layout, sent before anything is logged: the eye above the room."""
        scene = self.scene
        return presence_blueprint(eye=plane_eye(scene.domain, scene.region, scene.far))

    def extra_steps(self) -> list:
        """No steps after the cell map (an array scene has no ``[plan]``)."""
        return []

    def label(self, layer: Layer, t: float) -> str:
        lattice = self.scene.domain
        return f"{lattice.geometry}/{layer.kind} {' x '.join(map(str, lattice.shape))} cells"

    def writing(self):
        """Nothing around the recording: the .npz is written whole in :meth:`record`."""
        return contextlib.nullcontext()

    def record(self, rec, layer: Layer, t: float) -> dict:
        """The law's cell map, logged and exported; its summary row."""
        scene = self.scene
        lattice = scene.domain
        start = time.perf_counter()
        model = layer.model(t)
        cm = rasterise(model, lattice, region=scene.region, dtype=np.dtype(scene.dtype), threads=self.threads)
        seconds = time.perf_counter() - start
        regions = log_cell_map(rec, layer.name, cm, model, scene.region, names=scene.component_names or None,
                               room_z=scene.room_z, far=scene.far, log10_floor=scene.log10_floor,
                               mass_levels=scene.mass_levels)
        where = f"{scene.name}: {lattice.geometry}/{layer.kind}"
        for message in _unreached(regions, where):
            warnings.warn(message, BananagridWarning, stacklevel=2)
        if self.npz_path is not None:
            with self.outputs.stage(self.npz_path) as partial:
                try:
                    _write_npz(partial, scene, cm)
                except OSError as exc:  # a full disk, a file-size limit: one line naming the file
                    raise OutputWriteError(f"{self.npz_path}: cannot write the {NPZ} ({exc.strerror or exc})") from None
        return {"scene": scene.name, "layer": f"{lattice.geometry}/{layer.kind}", "t": float(t),
                "cells": int(cm.prob.size), "mass": float(np.sum(cm.prob)), "peak": float(np.max(cm.prob)),
                "peak_unit": "per cell", "regions": regions, "seconds": seconds}

    def finish(self, rec, rows: list[dict]) -> None:
        """Nothing more: the cell map's summary is under its own entity."""


def _write_npz(path: Path, scene: Scene, cm: CellMap) -> None:
    """The arrays of :class:`CellRun` into ``path`` (the caller renames it)."""
    lat = cm.lattice
    idx = cm.degree_indices()
    arrays = {
        "prob": cm.degree_table(), "cells": cm.prob, "error": cm.error, "azimuth_deg": idx[0],
        "azimuth_edges_deg": np.degrees(lat.azimuth_edges), "sizes": lat.sizes,
    }
    if lat.geometry == "line":
        arrays["x_edges"] = lat.line_edges()
    else:
        arrays["elevation_deg"] = idx[1]
        arrays["elevation_edges_deg"] = np.degrees(lat.elevation_edges)
    if cm.clipped_sizes is not None:
        arrays["clipped_sizes"] = cm.clipped_sizes
    provenance = {
        "bananagrid": __version__, "scene": scene.name, "title": scene.title, "source": scene.source,
        "quantity": "p(C | S): presence probability of each cell conditioned on the room S",
        "total": float(np.sum(cm.prob)), "region_probability": cm.region_probability,
        "region": None if cm.region is None else cm.region.describe(), "components": list(scene.component_names),
        "provenance": cm.provenance, "text": scene.text,
    }
    arrays["provenance"] = np.array(json.dumps(provenance, default=str))
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def _unreached(regions, where: str) -> list[str]:
    """A warning for probability-mass levels above the cells' total (they are not outlined)."""
    missing = [r for r in regions if not r.reached]
    if not missing:
        return []
    shown = ", ".join(f"{100 * r.probability:g} %" for r in missing)
    return [f"{where}: the cells hold {missing[0].enclosed:.3g} of the probability, so the {shown} "
            "probability-mass outlines are not drawn (set output.mass_levels below it)"]
