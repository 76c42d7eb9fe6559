"""The files of a scene's run, planned before any computing: ``NAME.rrd``, ``NAME.npz`` and the
map files (NetCDF, GeoTIFF, GeoJSON, KML), all one :class:`~bananagrid.atomic.OutputSet`."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from ..atomic import OutputSet
from ..geo.dataset import raster_dataset, write_netcdf
from ..geo.geojson import write_geojson
from ..geo.geotiff import POD, write_geotiff
from ..geo.kml import write_kml
from ..validate import BananagridError
from .run_evidence import evidence_paths
from .run_plan import plan_paths

__all__ = ["plan_outputs", "export_paths", "write_exports", "EXPORT_SUFFIXES", "EXPORT_NAMES", "EXPORT_OPTIONS", "NPZ",
           "RUN_ONLY_PROVENANCE", "PROBABILITY_GEOTIFF", "POSTERIOR_GEOTIFF", "POD_GEOTIFF"]

#: Provenance keys that describe the run rather than the result. They stay out of the
#: recording, so that running a scene twice gives equal recordings; the summary rows and the
#: .npz provenance keep them.
RUN_ONLY_PROVENANCE = ("seconds", "threads")


def plan_outputs(scene, out_dir: str | os.PathLike, *, npz: bool = False, netcdf: bool = False,
                 geotiff: bool = False, geojson: bool = False, kml: bool = False) -> OutputSet:
    """The files a run of ``scene`` writes in ``out_dir`` (``NAME.rrd``, and ``NAME.npz`` and the
    map files asked for), each checked now, before any computing: the directory must exist and
    take new files, and each target must be absent or a regular file (a directory, a link or
    anything else there is refused, naming it). Nothing is created.

    Raises
    ------
    BananagridError
        One line naming the directory or the target and what is there.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise BananagridError(f"{out_dir}: output directory does not exist")
    outputs = OutputSet()
    outputs.add(out_dir / f"{scene.name}.rrd", "recording")
    if npz:
        outputs.add(out_dir / f"{scene.name}.npz", NPZ)
    for option, path in export_paths(scene.name, out_dir, netcdf=netcdf, geotiff=geotiff, geojson=geojson, kml=kml,
                                     cell_probabilities=_cells(scene),
                                     evidence=bool(getattr(scene, "evidence", ()))).items():
        outputs.add(path, EXPORT_NAMES[option])
    for path in plan_paths(scene, out_dir, geojson=geojson):  # a [plan]'s areas and tracks
        outputs.add(path, EXPORT_NAMES["geojson"])
    for path in evidence_paths(scene, out_dir, geojson=geojson):  # the evidence and the posteriors' areas
        outputs.add(path, EXPORT_NAMES["geojson"])
    return outputs


#: The map options of ``bananagrid run`` (``--netcdf``, ...), in the order their files are written.
EXPORT_OPTIONS = ("netcdf", "geotiff", "geojson", "kml")
#: The GeoTIFF of the cell probabilities (float64, unit 1), beside the densities' GeoTIFF when a
#: scene asks for them (``output.cell_probabilities``): one quantity and one unit per file.
PROBABILITY_GEOTIFF = "geotiff_probability"
#: With a scene's evidence: the posterior cell probabilities (float64, unit 1) and the searches'
#: POD maps, a GeoTIFF each (band tags ``pos`` and ``search_pos``).
POSTERIOR_GEOTIFF = "geotiff_posterior"
POD_GEOTIFF = "geotiff_pod"
#: The map files' names after the scene's name, by option.
EXPORT_SUFFIXES = {"netcdf": ".nc", "geotiff": ".tif", PROBABILITY_GEOTIFF: "-probability.tif",
                   "geotiff_posterior": "-posterior.tif", "geotiff_pod": "-pod.tif",
                   "geojson": "-areas.geojson", "kml": ".kml"}
#: What each map file is called in messages (as its writer calls it).
EXPORT_NAMES = {"netcdf": "NetCDF file", "geotiff": "GeoTIFF", PROBABILITY_GEOTIFF: "GeoTIFF",
                "geotiff_posterior": "GeoTIFF", "geotiff_pod": "GeoTIFF",
                "geojson": "GeoJSON file", "kml": "KML file"}
#: What the .npz is called in messages.
NPZ = ".npz arrays"


def export_paths(name: str, out_dir: Path, *, netcdf: bool = False, geotiff: bool = False,
                 geojson: bool = False, kml: bool = False, cell_probabilities: bool = False,
                 evidence: bool = False) -> dict[str, Path]:
    """``{option: path}`` of the map files asked for, for scene ``name`` in ``out_dir``; with
    ``cell_probabilities`` and ``geotiff``, also the cell probabilities' GeoTIFF
    (:data:`PROBABILITY_GEOTIFF`); with ``evidence`` and ``geotiff``, the posteriors' and the
    POD maps' GeoTIFFs (:data:`POSTERIOR_GEOTIFF`, :data:`POD_GEOTIFF`)."""
    wanted = {"netcdf": netcdf, "geotiff": geotiff, PROBABILITY_GEOTIFF: geotiff and cell_probabilities,
              POSTERIOR_GEOTIFF: geotiff and evidence, POD_GEOTIFF: geotiff and evidence,
              "geojson": geojson, "kml": kml}
    return {option: Path(out_dir) / f"{name}{suffix}" for option, suffix in EXPORT_SUFFIXES.items() if wanted[option]}


def write_exports(scene, out_dir: Path, panels: list, *, netcdf: bool = False, geotiff: bool = False,
                  geojson: bool = False, kml: bool = False, areas: dict | None = None, cells: dict | None = None,
                  marks: dict | None = None, stage=None, coverage=None, posteriors=()) -> list[Path]:
    """The map files of a scene's ``panels`` (``(layer, t, raster)``), written together or not at
    all (``stage``: a run's :meth:`~bananagrid.atomic.OutputSet.stage`, whose commit puts them in
    place with its other files; default: put in place here when all are complete). Returns their
    paths. ``areas``: the panels' search areas by ``(layer, t)`` where already found; ``cells``:
    the cell probabilities by ``(layer, t)`` (a scene's ``output.cell_probabilities``), into the
    NetCDF and a GeoTIFF of their own; ``marks``: each layer's model's ``landmarks()``, for the KML;
    ``coverage``: a plan's ``(layer, t, effort raster)``, a variable of the NetCDF file;
    ``posteriors``: each map's :class:`~bananagrid.scenes.run_evidence.ScenePosterior` (a
    scene's evidence), into the NetCDF and GeoTIFFs of their own."""
    cells = cells or {}
    found = {(p.layer, p.t): p.posterior for p in posteriors}
    paths = export_paths(scene.name, out_dir, netcdf=netcdf, geotiff=geotiff, geojson=geojson, kml=kml,
                         cell_probabilities=bool(cells), evidence=bool(found))
    with OutputSet() as own:
        if stage is None:
            for option, path in paths.items():
                own.add(path, EXPORT_NAMES[option])
            stage = own.stage
        if netcdf:
            dataset = raster_dataset(panels, scene.geo, title=scene.title, source=scene.source, cells=cells,
                                     coverage=coverage, posteriors=found or None)
            write_netcdf(paths["netcdf"], dataset, stage=stage)
        if geotiff:
            write_geotiff(paths["geotiff"], panels, scene.geo, title=scene.title, stage=stage)
            if cells:
                write_geotiff(paths[PROBABILITY_GEOTIFF], [(layer, t, cells[layer, t]) for layer, t, _ in panels],
                              scene.geo, title=scene.title, stage=stage)
            if found:
                write_geotiff(paths[POSTERIOR_GEOTIFF], [(layer, t, found[layer, t]) for layer, t, _ in panels],
                              scene.geo, title=scene.title, stage=stage)
                write_geotiff(paths[POD_GEOTIFF], [(layer, t, replace(found[layer, t], values=found[layer, t].pod,
                                                                      quantity=POD)) for layer, t, _ in panels],
                              scene.geo, title=scene.title, stage=stage)
        if geojson:
            write_geojson(paths["geojson"], panels, scene.geo, scene.mass_levels, title=scene.title, areas=areas,
                          stage=stage)
        if kml:
            write_kml(paths["kml"], panels, scene.geo, scene.mass_levels, title=scene.title, areas=areas, marks=marks,
                      stage=stage)
        own.commit()
    return list(paths.values())


def _cells(scene) -> bool:
    """Whether a scene's run computes cell probabilities (a grid scene's ``output.cell_probabilities``)."""
    return bool(getattr(scene, "cell_probabilities", False))
