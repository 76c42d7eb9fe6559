"""A geographic scene on a map: rerun's map view, with what a reviewer places on a chart.

For a scene with a ``[geo]`` table the recording also holds, under ``map/LAYER``, in latitude
and longitude (WGS84, rerun's ``GeoPoints`` and ``GeoLineStrings``):

- ``fix``: where the layer starts, static: a motion model's last fix, a Butterly start's
  mean, a bearing fix's estimated position;
- ``stations``, ``bearings``: a bearing fix's stations and their bearing lines (to 1.5 times
  the farthest station's range, as on the layer's own map), static;
- ``areas/pNN``: the search area holding NN % of the probability
  (:func:`bananagrid.geo.areas.search_areas` at the scene's probability-mass levels), every ring
  of its polygons (holes too), one colour per level, on the ``elapsed`` timeline; hovering a
  ring names its level. A level the grid does not hold logs no rings.

:func:`map_view` is the blueprint's map panel: one tab per layer, each a map view zoomed to
hold the grid and the layer's landmarks, over OpenStreetMap tiles (the viewer fetches them;
offline it shows the primitives on a blank map). Every line is drawn through the plane's points
carried to the ellipsoid one by one (a bearing line every 1/32 of its length), so it lies where
the layer's own map puts it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .core import entity_path, strict

__all__ = ["log_map_evidence", "EVIDENCE_COLOURS", "MAP_ENTITY", "AREA_COLOURS", "log_map_marks", "log_map_areas", "map_view", "map_zoom", "level_entity"]

MAP_ENTITY = "map"
#: One colour per probability level, innermost first (readable over OpenStreetMap's pale land
#: and blue sea): red, orange, purple, dark blue; further levels repeat them.
AREA_COLOURS = ((220, 20, 60), (255, 140, 0), (148, 0, 211), (0, 0, 139))
FIX_COLOUR = (220, 20, 60)
#: Blue: seen on OpenStreetMap's land and on the viewer's dark blank map (offline).
STATION_COLOUR = (30, 144, 255)
BEARING_COLOUR = (255, 140, 0)
#: Points along each drawn bearing line.
LINE_POINTS = 33
#: Ground metres per pixel at zoom 0 on the equator (Web Mercator, 256-pixel tiles).
METRES_PER_PIXEL_Z0 = 156_543.034
#: The map view opens with the grid and the landmarks about this many points across (a panel of
#: the default layout is about 300 points high).
VIEW_PIXELS = 300.0


def _lat_lon(frame, xy: np.ndarray) -> np.ndarray:
    """(n, 2) local x, y (m) as (n, 2) latitude, longitude (deg)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    lat, lon = frame.geographic(xy[:, 0], xy[:, 1])
    return np.column_stack([lat, lon])


def _strips(lat_lon: np.ndarray) -> list[np.ndarray]:
    """A line in (lat, lon) split where it crosses the antimeridian (a step of more than 180
    degrees of longitude), so that the map draws no segment the long way round the Earth."""
    jumps = np.flatnonzero(np.abs(np.diff(lat_lon[:, 1])) > 180.0) + 1
    return [part for part in np.split(lat_lon, jumps) if len(part) >= 2]


def log_map_marks(rec: rr.RecordingStream, name: str, model, frame) -> None:
    """Log where layer ``name``'s model is anchored (its ``landmarks()``: the fix, a bearing
    fix's stations and lines), static."""
    entity = f"{MAP_ENTITY}/{entity_path(name)}"
    found = model.landmarks()
    with strict():
        if "stations" in found:
            rec.log(f"{entity}/stations", rr.GeoPoints(lat_lon=_lat_lon(frame, found["stations"]),
                                                       colors=STATION_COLOUR, radii=rr.Radius.ui_points(7.0)),
                    static=True)
        if "bearings" in found:
            # straight in the plane: drawn through LINE_POINTS of it, each carried to the ellipsoid
            along = np.linspace(0.0, 1.0, LINE_POINTS)[:, None]
            lines = [strip for start, end in found["bearings"]
                     for strip in _strips(_lat_lon(frame, start + along * (end - start)))]
            rec.log(f"{entity}/bearings", rr.GeoLineStrings(lat_lon=lines, colors=BEARING_COLOUR,
                                                            radii=rr.Radius.ui_points(1.5)), static=True)
        if "fix" in found:
            rec.log(f"{entity}/fix", rr.GeoPoints(lat_lon=_lat_lon(frame, found["fix"]), colors=FIX_COLOUR,
                                                  radii=rr.Radius.ui_points(6.0)), static=True)


#: The evidence on the map: searches orange, reports cyan, land grey (as in the evidence's panel).
EVIDENCE_COLOURS = {"search": (255, 140, 0), "report": (0, 220, 255), "exclusion": (160, 160, 160)}


def log_map_evidence(rec: rr.RecordingStream, names: Sequence[str], specs: Sequence, frame, set_time) -> None:
    """A scene's evidence (:class:`bananagrid.scenes.evidence.EvidenceSpec`: areas, tracks,
    reported positions and stations) on each layer's map (``map/NAME/evidence/EVIDENCE``), each
    at its own time (``set_time(seconds)``), land static; edges straight in the plane are drawn
    through :data:`LINE_POINTS` points of it."""
    along = np.linspace(0.0, 1.0, LINE_POINTS)[:, None]
    with strict():
        for spec in specs:
            static = spec.span is None
            if not static:
                set_time(spec.span[0])
            colour = EVIDENCE_COLOURS[getattr(spec.evidence, "kind", "search")]
            lines = []
            for ring in (*(np.vstack([s, s[:1]]) for s in spec.shapes),
                         *(() if spec.track is None else (spec.track[:, :2],))):
                dense = np.concatenate([a + along * (b - a) for a, b in zip(ring[:-1], ring[1:])])
                lines += _strips(_lat_lon(frame, dense))
            for name in names:
                entity = f"{MAP_ENTITY}/{entity_path(name)}/evidence/{entity_path(spec.name)}"
                if lines:
                    rec.log(entity, rr.GeoLineStrings(lat_lon=lines, colors=colour, radii=rr.Radius.ui_points(2.0)),
                            static=static)
                if spec.points is not None:
                    rec.log(entity, rr.GeoPoints(lat_lon=_lat_lon(frame, spec.points), colors=colour,
                                                 radii=rr.Radius.ui_points(6.0)), static=static)


def level_entity(level: float) -> str:
    """The entity of a level's search area: ``p50``, ``p99_5``."""
    return "p" + f"{level * 100.0:g}".replace(".", "_")


def log_map_areas(rec: rr.RecordingStream, name: str, areas: Sequence, frame) -> None:
    """Log layer ``name``'s search areas (:class:`bananagrid.geo.areas.SearchArea`, in the
    plane) as rings in latitude and longitude at the current time, one entity per level."""
    with strict():
        for k, area in enumerate(areas):
            rings = [] if not area.reached else [
                strip for polygon in area.geometry.geoms for ring in (polygon.exterior, *polygon.interiors)
                for strip in _strips(_lat_lon(frame, np.asarray(ring.coords)))
            ]
            rec.log(f"{MAP_ENTITY}/{entity_path(name)}/areas/{level_entity(area.level)}",
                    rr.GeoLineStrings(lat_lon=rings, colors=AREA_COLOURS[k % len(AREA_COLOURS)],
                                      radii=rr.Radius.ui_points(2.0)))


def map_zoom(frame, extent: tuple[float, float, float, float]) -> float:
    """The web-map zoom level at which ``extent`` (x0, x1, y0, y1 in local metres) is about
    ``VIEW_PIXELS`` wide: ``log2(156543 cos(lat) VIEW_PIXELS / width)``, at its centre."""
    x0, x1, y0, y1 = extent
    lat, _ = frame.geographic(0.5 * (x0 + x1), 0.5 * (y0 + y1))
    width = max(x1 - x0, y1 - y0, 1.0)
    return float(np.clip(math.log2(METRES_PER_PIXEL_Z0 * math.cos(math.radians(float(lat))) * VIEW_PIXELS / width),
                         1.0, 19.0))


def map_view(frame, extent: tuple[float, float, float, float], layers: Sequence[tuple[str, object]]) -> rrb.Tabs:
    """The map panel: one tab per ``(name, model)`` layer, a map view of ``map/NAME`` zoomed to
    hold ``extent`` (the grid, local metres) and the layer's landmarks, over OpenStreetMap."""
    views = []
    for name, model in layers:
        marks = model.landmarks()
        points = np.concatenate([np.reshape(v, (-1, 2)) for v in marks.values()] or [np.empty((0, 2))])
        x0, x1, y0, y1 = extent
        if len(points):
            x0, x1 = min(x0, points[:, 0].min()), max(x1, points[:, 0].max())
            y0, y1 = min(y0, points[:, 1].min()), max(y1, points[:, 1].max())
        views.append(rrb.MapView(origin=f"/{MAP_ENTITY}/{entity_path(name)}", name=f"map · {name}",
                                 zoom=map_zoom(frame, (x0, x1, y0, y1)), background=rrb.MapProvider.OpenStreetMap))
    return rrb.Tabs(*views, name="map")
