"""Run a presence scene: its cell map, recorded to ``OUT/NAME.rrd`` (and ``OUT/NAME.npz``),
the two replaced together or not at all (:class:`~bananagrid.atomic.OutputSet`), with the
summary row, as :func:`bananagrid.scenes.run.run_scene` does for grids."""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path

import numpy as np

from ..atomic import OutputSet, OutputWriteError
from ..recording.core import log_scene_text, recording_id_for, write_recording
from ..recording.presence import log_cell_map, plane_eye, presence_blueprint
from ..results import CellMap
from ..validate import BananagridError, BananagridWarning
from ..version import __version__
from .presence import PresenceScene

__all__ = ["run_presence_scene"]


def run_presence_scene(scene: PresenceScene, out_dir: str | os.PathLike, *, npz: bool = False,
                       threads: int | None = None, progress=None, outputs: OutputSet | None = None) -> list[dict]:
    """Compute the scene's cell map, record it to ``OUT/NAME.rrd`` and optionally export it.

    Parameters
    ----------
    scene : PresenceScene
    out_dir : path-like
        Existing directory.
    npz : bool, default False
        Also write ``OUT/NAME.npz``: ``prob`` indexed ``[azimuth, elevation]`` by integer
        degrees (shape (360, 181); line: ``prob[azimuth]``, (361,)), NaN for directions not in
        the lattice; ``cells`` (the same in lattice order, ``(n_azimuth, n_elevation)``),
        ``error`` (error estimate per cell), ``azimuth_deg`` and ``elevation_deg`` (uint16
        direction of each lattice index), ``azimuth_edges_deg`` and ``elevation_edges_deg``
        (cell bounds), ``sizes`` (cell length, area or volume; inf at the horizon),
        ``clipped_sizes`` (within the room, when there is one), for the line ``x_edges`` (m),
        and ``provenance`` (a JSON string).
    threads : int, optional
        CPU threads (default: every core).
    progress : callable, optional
        ``progress(done, total, label)`` before (0, 1) and after (1, 1) the computation.
    outputs : OutputSet, optional
        The run's planned files (:func:`bananagrid.scenes.run.plan_outputs`); default: planned
        here, before computing.

    Returns
    -------
    list of dict
        One summary row: ``scene``, ``layer`` (``GEOMETRY/KIND``), ``t`` (0), ``cells``,
        ``mass`` (sum of p(C | S) over the cells), ``peak`` (largest cell probability) and
        ``seconds``.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise BananagridError(f"{out_dir}: output directory does not exist")
    rrd_path = out_dir / f"{scene.name}.rrd"
    npz_path = out_dir / f"{scene.name}.npz"
    if outputs is None:
        outputs = OutputSet()
        outputs.add(rrd_path, "recording")
        if npz:
            outputs.add(npz_path, ".npz arrays")
    lattice = scene.lattice
    label = f"{lattice.geometry}/{scene.kind} {' x '.join(map(str, lattice.shape))} cells"
    rows: list[dict] = []

    def build(rec) -> None:
        log_scene_text(rec, scene.text)
        if progress is not None:
            progress(0, 1, label)
        start = time.perf_counter()
        cm = scene.cell_map(threads=threads)
        seconds = time.perf_counter() - start
        regions = log_cell_map(rec, "presence", cm, scene.presence, scene.region, names=scene.component_names or None,
                               room_z=scene.room_z, far=scene.far, log10_floor=scene.log10_floor,
                               mass_levels=scene.mass_levels)
        where = f"{scene.name}: {lattice.geometry}/{scene.kind}"
        for message in _unreached(regions, where):
            warnings.warn(message, BananagridWarning, stacklevel=2)
        if npz:
            with outputs.stage(npz_path) as partial:
                try:
                    _write_npz(partial, scene, cm)
                except OSError as exc:  # a full disk, a file-size limit: one line naming the file
                    raise OutputWriteError(f"{npz_path}: cannot write the .npz arrays ({exc.strerror or exc})") from None
        rows.append({"scene": scene.name, "layer": f"{lattice.geometry}/{scene.kind}", "t": 0.0,
                     "cells": int(cm.prob.size), "mass": float(np.sum(cm.prob)), "peak": float(np.max(cm.prob)),
                     "peak_unit": "per cell", "regions": regions, "seconds": seconds})
        if progress is not None:
            progress(1, 1, label)

    with outputs:  # all or nothing: no recording without its arrays, the old pair kept on failure
        blueprint = presence_blueprint(eye=plane_eye(lattice, scene.region, scene.far))
        write_recording(rrd_path, build, recording_id=recording_id_for(scene.text), blueprint=blueprint,
                        stage=outputs.stage)
        outputs.commit()
    return rows


def _write_npz(path: Path, scene: PresenceScene, cm: CellMap) -> None:
    """The arrays of :func:`run_presence_scene` into ``path`` (the caller renames it)."""
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
