"""A scene's ``[[evidence]]`` in its run: each map's posterior (:func:`bananagrid.posterior` of the
layer's model on the scene's grid, with the evidence that began by the map's time), recorded,
summarised and written (NetCDF, GeoTIFF, the evidence's GeoJSON).

The posterior is the same call a user makes: ``bg.posterior(layer.model(t), scene.grid,
[evidence that began by t])``, cell probabilities in float64 whatever ``output.dtype`` says.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..evidence.posterior import posterior
from ..geo.areas import SHAPELY_PURPOSE, search_areas
from ..geo.files import writing
from ..geo.frame import iso_utc
from ..geo.geojson import area_features, line_lonlat, polygons_lonlat
from ..geo.libraries import require
from ..recording.evidence import evidence_values, log_evidence_marks, log_posterior
from ..recording.geomap import log_map_evidence
from ..recording.timeline import set_times
from ..validate import BananagridError
from .evidence import job_evidence
from .load import Layer, Scene

__all__ = ["ScenePosterior", "scene_posterior", "scene_named", "scene_error", "record_evidence_marks",
           "record_posterior", "evidence_paths", "write_evidence_geojson", "evidence_bytes_per_cell",
           "EVIDENCE_GEOJSON_SUFFIX", "EVIDENCE_BYTES_PER_CELL", "EVIDENCE_BYTES_PER_PIECE", "EVIDENCE_KEPT_BYTES_PER_CELL"]

#: The evidence's GeoJSON after the scene's name.
EVIDENCE_GEOJSON_SUFFIX = "-evidence.geojson"
#: Further bytes per cell of a run with evidence, while ``bg.posterior`` runs: a base and a
#: share per piece of evidence. Measured (tracemalloc, the growth of the peak from the Figure 1
#: CAT at 40 m cells to 10 m, 13,500 to 216,000 cells; Intel Xeon): 83 bytes per cell with one
#: area search, 204 with eight, 308 with an area search, an inverse-cube track, land and a
#: position report (a smooth factor varies on every cell); :func:`evidence_bytes_per_cell`
#: bounds each (160, 608, 352). Besides, a fixed 30 MB of sub-cell chunks.
EVIDENCE_BYTES_PER_CELL = 96
EVIDENCE_BYTES_PER_PIECE = 64
#: Further bytes per cell and map kept for the files and the recording's shared frames: the
#: posterior's float64 prior, posterior and POD arrays.
EVIDENCE_KEPT_BYTES_PER_CELL = 24


def evidence_bytes_per_cell(scene: Scene) -> int:
    """Bytes per cell a run with ``scene``'s evidence needs beyond a run without: computing one
    posterior (:data:`EVIDENCE_BYTES_PER_CELL` and :data:`EVIDENCE_BYTES_PER_PIECE` for each
    piece of evidence) and keeping each map's (:data:`EVIDENCE_KEPT_BYTES_PER_CELL`)."""
    if not scene.evidence:
        return 0
    return (EVIDENCE_BYTES_PER_CELL + EVIDENCE_BYTES_PER_PIECE * len(scene.evidence)
            + EVIDENCE_KEPT_BYTES_PER_CELL * len(scene.jobs()))


@dataclass(frozen=True)
class ScenePosterior:
    """One map's posterior in a scene's run.

    Attributes
    ----------
    layer : str
    t : float
    posterior : Posterior
        ``bg.posterior``'s result (cell probabilities on the scene's grid; with the scene's
        geographic frame).
    used : tuple of EvidenceSpec
        The evidence it took (that which began by ``t``).
    values : dict
        Its numbers (:func:`bananagrid.recording.evidence.evidence_values`).
    """

    layer: str
    t: float
    posterior: object
    used: tuple
    values: dict


def scene_posterior(scene: Scene, layer: Layer, t: float, model=None, *, threads: int | None = None) -> ScenePosterior:
    """The posterior of ``layer`` at ``t`` after the scene's evidence that began by then.

    Raises
    ------
    BananagridError
        What ``bg.posterior`` refuses (evidence the model cannot carry to ``t``, evidence that
        contradicts the prior), one line naming the scene, the layer, the time and the scene's
        ``evidence[k]``.
    """
    used = tuple(job_evidence(scene.evidence, t))
    model = layer.model(t) if model is None else model
    try:
        post = posterior(model, scene.grid, [s.evidence for s in used], threads=threads)
    except BananagridError as exc:
        raise scene_error(scene, layer, t, used, exc) from None
    post = scene_named(scene, used, post)
    values = evidence_values(post, used, scene.evidence, layer=layer.name, t=t)
    return ScenePosterior(layer=layer.name, t=float(t), posterior=post, used=used, values=values)


def scene_named(scene: Scene, used, post):
    """``post`` (a ``Posterior``, or a tiled posterior's maps) with the names of the scene's
    evidence it took (``evidence_names``, ``search_names``: the files name the searches by them)
    in its provenance, and in a geographic scene the scene's frame."""
    provenance = {**post.provenance, "evidence_names": [s.name for s in used],
                  "search_names": [s.name for s in used if s.search]}
    if scene.geo is not None:
        return replace(post, frame=scene.geo, provenance={**provenance, "geo": scene.geo.identity()})
    return replace(post, provenance=provenance)


def scene_error(scene: Scene, layer: Layer, t: float, used, exc: BananagridError) -> BananagridError:
    """``bg.posterior``'s refusal ``exc`` of a map's evidence ``used`` in the scene's words: one
    line naming the scene, the layer, the time and the scene's ``evidence[k]`` (the call's
    ``evidence[k]`` is the scene's ``evidence[used[k].index]``)."""
    message = re.sub(r"evidence\[(\d+)\]", lambda m: f"evidence[{used[int(m.group(1))].index}]"
                     if int(m.group(1)) < len(used) else m.group(0), str(exc))
    return BananagridError(f"{scene.source}: layers.{layer.name} at t = {t:g} s: {message}")


def record_evidence_marks(rec, scene: Scene) -> None:
    """The evidence's geometry, each at its time on the elapsed (and UTC) timelines; in a
    geographic scene on each layer's map too."""
    def at(seconds: float) -> None:
        set_times(rec, seconds, scene.geo)

    log_evidence_marks(rec, scene.evidence, at, scene.grid.extent)
    if scene.geo is not None:
        log_map_evidence(rec, [layer.name for layer in scene.layers], scene.evidence, scene.geo, at)


def record_posterior(rec, scene: Scene, found: ScenePosterior) -> None:
    """A map's prior, posterior, POD and POS at the recording's current time."""
    log_posterior(rec, found.layer, found.posterior, found.values, scene.evidence, colormap=scene.colormap)


def evidence_paths(scene: Scene, out_dir: str | os.PathLike, *, geojson: bool = False) -> list[Path]:
    """The evidence's files a run writes: ``NAME-evidence.geojson`` when GeoJSON is asked for
    and the scene has evidence."""
    if not geojson or not scene.evidence:
        return []
    return [Path(out_dir) / f"{scene.name}{EVIDENCE_GEOJSON_SUFFIX}"]


def write_evidence_geojson(path: str | os.PathLike, scene: Scene, posteriors: list, *, stage=None) -> Path:
    """The evidence (searched areas and tracks, reports, land: each feature's ``evidence`` its
    name, ``kind``, times, POD and each map's POS of it) and each posterior's probability-mass
    areas (``map`` = ``"posterior"``), as one RFC 7946 FeatureCollection in WGS84 longitude and
    latitude; ``stage``: the run's :meth:`~bananagrid.atomic.OutputSet.stage`."""
    shapely = require("shapely", SHAPELY_PURPOSE)
    frame = scene.geo
    features = []
    for spec in scene.evidence:
        props = {"evidence": spec.name, "kind": spec.kind, "t_s": None if spec.span is None else list(spec.span),
                 "time_utc": None if spec.span is None or frame.time is None
                 else [iso_utc(frame.utc(s)) for s in spec.span]}
        e = spec.evidence
        if spec.kind == "area_search":
            props.update(pod=e.pod, coverage=e.coverage)
        if spec.kind == "track_search":
            props.update(sweep_width_m=e.sweep_width, law=e.law)
        if spec.search:
            props["pos"] = [{"layer": p.layer, "t_s": p.t, "pos": p.values["search_pos"][
                p.values["searches"].index(spec.name)]} for p in posteriors if spec.name in p.values["evidence"]]
        if spec.shapes:
            geometry = shapely.geometry.mapping(polygons_lonlat(shapely.geometry.MultiPolygon(
                [shapely.geometry.Polygon(s) for s in spec.shapes]), frame))
        elif spec.track is not None:
            geometry = {"type": "MultiLineString", "coordinates": line_lonlat(spec.track[:, :2], frame)}
            props["times_s"] = spec.track[:, 2].tolist()
        else:
            lat, lon = frame.geographic(spec.points[:, 0], spec.points[:, 1])
            geometry = {"type": "MultiPoint", "coordinates": [[round(float(a), 7), round(float(b), 7)]
                                                              for a, b in zip(np.atleast_1d(lon), np.atleast_1d(lat))]}
        features.append({"type": "Feature", "geometry": geometry, "properties": props})
    for found in posteriors:
        post = found.posterior
        density = replace(post, values=np.asarray(post.values) / (post.grid.dx * post.grid.dy), quantity="density")
        for feature in area_features(found.layer, found.t, search_areas(density, scene.mass_levels), frame):
            feature["properties"].update(map="posterior", pos=found.values["pos"])
            features.append(feature)
    collection = {"type": "FeatureCollection",
                  "bananagrid": {"title": scene.title, "frame": frame.describe(),
                                 "quantity": "the evidence (searches that found nothing, reports, land) and the "
                                             "posterior's smallest areas holding each probability level"},
                  "features": features}
    with writing(path, "GeoJSON file", stage=stage) as partial:
        partial.write_text(json.dumps(collection, allow_nan=False) + "\n", encoding="utf-8")
    return Path(path)
