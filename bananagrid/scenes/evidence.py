"""A scene's ``[[evidence]]``: searches that found nothing, reports and land, each validated once
here into a :mod:`bananagrid.evidence` object on the scene's clock.

Each table has a ``kind`` (:data:`EVIDENCE_KINDS`), its time on the scene's timeline (``t``: s since
the last fix, or in a geographic scene with a ``[geo] time`` an ISO 8601 UTC time; a pair for a
search over an interval) and its geometry inline (world metres, or ``*_latlon`` degrees in a
geographic scene) or from a GeoJSON ``file`` (relative to the scene file; longitude and latitude
in a geographic scene, local metres otherwise), as planners draw them in a GIS. The keys are
declared in :data:`EVIDENCE_TABLE` (``docs/scenes.md`` is generated from it). Every refusal is
one line ``evidence[k].KEY = value: what is allowed``.

A map at time t takes the evidence that began by then (``t0 <= t``): a scene's earlier maps
are not updated by later evidence, and evidence after the scene's last map is refused, as is a
search over an interval that holds a map's time inside it (the map would take it whole, effort
after its time included: split it there).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from ..evidence.reports import BearingReport, Exclusion, PositionReport
from ..evidence.searches import LAWS, AreaSearch, TrackSearch
from ..geo.frame import parse_utc
from ..geo.inputs import read_track
from ..models.bearing import BearingFix
from ..validate import BananagridError
from . import keys
from .keys import SceneKeyError, check_keys, show

__all__ = ["EvidenceSpec", "EVIDENCE_KINDS", "EVIDENCE_TABLE", "EVIDENCE_KEYS", "parse_evidence", "job_evidence"]

#: The kinds of ``[[evidence]]`` tables and the keys each takes (beside ``kind`` and ``name``).
EVIDENCE_KINDS = {
    "area_search": ("t", "polygon", "polygon_latlon", "file", "pod", "coverage"),
    "track_search": ("track", "track_latlon", "file", "sweep_width", "law"),
    "position_report": ("t", "position", "position_latlon", "sigma", "cov"),
    "bearing_report": ("t", "sensors", "sensors_latlon", "bearings", "bearings_deg", "sigmas", "sigmas_deg"),
    "exclusion": ("polygon", "polygon_latlon", "file"),
}
#: ``[[evidence]]`` keys, ``(key, kinds, type, unit, default, allowed)`` each; ``docs/scenes.md``
#: is generated from it (:mod:`bananagrid.scenes.docs`).
EVIDENCE_TABLE = (
    ("kind", "all", "string", "", "required", ", ".join(f'`"{k}"`' for k in EVIDENCE_KINDS)),
    ("name", "all", "string", "", "`E1`, `E2`, ... (its place in the file)",
     "letters, digits, `_` and `-`: the label in the recording, the summary and the files"),
    ("t", "area_search, position_report, bearing_report", "number, string or a pair", "s", "required",
     "s since the last fix, >= 0 and not after the scene's last time; in a geographic scene with a `[geo] time` "
     "also an ISO 8601 UTC time; an area search over an interval takes `[t0, t1]`"),
    ("polygon", "area_search, exclusion", "array of `[x, y]`", "m", "one of `polygon`, `polygon_latlon`, `file`",
     "a simple polygon, at least 3 vertices"),
    ("polygon_latlon", "area_search, exclusion", "array of `[lat, lon]`", "deg", "instead of `polygon`",
     "latitude in [-90, 90], longitude in [-180, 180]; needs `[geo]`"),
    ("file", "area_search, track_search, exclusion", "string", "", "instead of the inline geometry",
     "a GeoJSON file, relative to the scene: a Polygon (area search), Polygon or MultiPolygon (exclusion), in "
     "longitude and latitude in a geographic scene, local metres otherwise; a track: any track file "
     "`bg.read_track` reads (a GeoJSON LineString with `properties.times`, GPX, CSV, NMEA), needs `[geo]` with a time"),
    ("pod", "area_search", "number", "", "one of `pod`, `coverage`", "in [0, 1]: probability of detection inside"),
    ("coverage", "area_search", "number", "", "instead of `pod`",
     ">= 0: coverage factor C, POD = 1 - exp(-C) (random search)"),
    ("track", "track_search", "array of `[x, y, t]`", "m, s", "one of `track`, `track_latlon`, `file`",
     "at least 2 points, times strictly increasing (s, or ISO 8601 UTC in a geographic scene)"),
    ("track_latlon", "track_search", "array of `[lat, lon, t]`", "deg, s", "instead of `track`",
     "as `track`, positions in degrees; needs `[geo]`"),
    ("sweep_width", "track_search", "number", "m", "required", "finite and > 0"),
    ("law", "track_search", "string", "", '`"inverse_cube"`', ", ".join(f'`"{law}"`' for law in LAWS)),
    ("position", "position_report", "`[x, y]`", "m", "one of `position`, `position_latlon`", "finite"),
    ("position_latlon", "position_report", "`[lat, lon]`", "deg", "instead of `position`", "needs `[geo]`"),
    ("sigma", "position_report", "number", "m", "one of `sigma`, `cov`", "finite and > 0: circular error"),
    ("cov", "position_report", "2 x 2 array", "m^2", "instead of `sigma`", "symmetric positive definite"),
    ("sensors", "bearing_report", "array of `[x, y]`", "m", "one of `sensors`, `sensors_latlon`", "at least 2"),
    ("sensors_latlon", "bearing_report", "array of `[lat, lon]`", "deg", "instead of `sensors`", "needs `[geo]`"),
    ("bearings", "bearing_report", "array of numbers", "rad", "required (or `bearings_deg`)",
     "one per sensor, clockwise from north (true north in a geographic scene)"),
    ("bearings_deg", "bearing_report", "array of numbers", "deg", "instead of `bearings`", "as `bearings`, in degrees"),
    ("sigmas", "bearing_report", "array of numbers", "rad", "required (or `sigmas_deg`)", "one per sensor, > 0"),
    ("sigmas_deg", "bearing_report", "array of numbers", "deg", "instead of `sigmas`", "as `sigmas`, in degrees"),
)
EVIDENCE_KEYS = tuple(row[0] for row in EVIDENCE_TABLE)


@dataclass(frozen=True)
class EvidenceSpec:
    """One ``[[evidence]]`` table, validated.

    Attributes
    ----------
    index : int
        Its place in the file (``evidence[index]`` in messages).
    name : str
        Its label.
    kind : str
        A key of :data:`EVIDENCE_KINDS`.
    evidence : object
        The :mod:`bananagrid.evidence` object (world metres, s since the last fix).
    span : (float, float) or None
        When, s (None for land: at every time).
    shapes : tuple of ndarray
        Polygons to draw (world metres, (n, 2) each).
    track : ndarray or None
        A track search's ``(n, 3)`` points (x, y, t).
    points : ndarray or None
        A report's positions to draw (the reported position, the bearing stations).
    """

    index: int
    name: str
    kind: str
    evidence: object
    span: tuple | None
    shapes: tuple = ()
    track: np.ndarray | None = field(default=None, repr=False)
    points: np.ndarray | None = field(default=None, repr=False)

    @property
    def search(self) -> bool:
        """Whether it is a search (it has a POS)."""
        return self.kind in ("area_search", "track_search")


def parse_evidence(value, timeline, geo, directory: Path) -> tuple[EvidenceSpec, ...]:
    """``[[evidence]]``: a list of tables, each validated (:data:`EVIDENCE_TABLE`), on the scene's
    ``timeline`` (its times, s): evidence must not start after its last time."""
    if not isinstance(value, list) or not all(isinstance(item, dict) for item in value):
        raise SceneKeyError(f"evidence = {show(value)}: expected [[evidence]] tables")
    specs = []
    names: set[str] = set()
    for k, table in enumerate(value):
        spec = _one(k, table, timeline, geo, directory)
        if spec.name in names:
            raise SceneKeyError(f"evidence[{k}].name = {show(spec.name)}: another [[evidence]] has this name")
        names.add(spec.name)
        specs.append(spec)
    return tuple(specs)


def job_evidence(specs, t: float) -> list[EvidenceSpec]:
    """The evidence a map at ``t`` takes: that which began by then (land always)."""
    return [s for s in specs if s.span is None or s.span[0] <= t]


def _one(k: int, table: dict, timeline, geo, directory: Path) -> EvidenceSpec:
    path = f"evidence[{k}]"
    kind = table.get("kind")
    if not isinstance(kind, str) or kind not in EVIDENCE_KINDS:
        shown = "missing" if kind is None else f"= {show(kind)}"
        raise SceneKeyError(f"{path}.kind {shown}: must be one of {', '.join(map(show, EVIDENCE_KINDS))}")
    check_keys(table, ("kind", "name", *EVIDENCE_KINDS[kind]), path, note=f" (kind {show(kind)})")
    name = keys.name(table.get("name", f"E{k + 1}"), f"{path}.name")
    for key in table:
        if key.endswith("_latlon") and geo is None:
            raise SceneKeyError(f"{path}.{key} = {show(table[key])}: positions in latitude and longitude need a [geo] "
                                "table (its origin_latlon)")
    build = {"area_search": _area, "track_search": _track, "position_report": _position,
             "bearing_report": _bearings, "exclusion": _exclusion}[kind]
    spec = build(path, table, geo, directory)
    evidence, shapes, track, points, used = spec
    span = evidence.time_span
    key = used.get("track" if kind == "track_search" else "t", "t")
    last = max(timeline)
    if span is not None and span[1] > last:
        raise SceneKeyError(f"{path}.{key} = {show(table.get(key))}: ends at {span[1]:g} s, after the scene's last "
                            f"time {last:g} s; evidence must not be later than the maps it updates")
    inside = [t for t in timeline if span is not None and span[0] < t < span[1]]
    if inside:  # a map takes a search whole: part of it would be after the map's time
        raise SceneKeyError(f"{path}.{key} = {show(table.get(key))}: spans the map time {inside[0]:g} s of the "
                            "timeline, and a map takes a search whole; split it there (one table before, one after)")
    return EvidenceSpec(index=k, name=name, kind=kind, evidence=evidence, span=span, shapes=tuple(shapes),
                        track=track, points=points)


# --- the kinds --------------------------------------------------------------------------------


def _area(path, table, geo, directory):
    t = _time(path, table, geo, interval=True)
    where, polygon, frame = _polygon(path, table, geo, directory)
    _one_of(path, table, ("pod", "coverage"), "the probability of detection inside (pod) or the coverage factor")
    amount = {key: keys.number(table[key], f"{path}.{key}") for key in ("pod", "coverage") if key in table}
    search = _made(path, {"polygon": where}, lambda: AreaSearch(polygon, t, frame=frame, **amount))
    return search, [search.polygon], None, None, {"t": "t"}


def _track(path, table, geo, directory):
    where = _one_of(path, table, ("track", "track_latlon", "file"), "the searcher's timed track")
    if "sweep_width" not in table:
        raise SceneKeyError(f"{path}.sweep_width: missing; expected the sweep width W in m")
    width = keys.number(table["sweep_width"], f"{path}.sweep_width")
    law = table.get("law", "inverse_cube")
    if law not in LAWS:
        raise SceneKeyError(f"{path}.law = {show(law)}: must be one of {', '.join(map(show, LAWS))}")
    if where == "file":
        if geo is None or geo.time is None:
            raise SceneKeyError(f"{path}.file = {show(table['file'])}: a track file's positions and times are "
                                "longitude, latitude and UTC: it needs a [geo] table with a time")
        file = _file(path, table, directory)
        try:
            track = read_track(file)
        except BananagridError as exc:
            raise SceneKeyError(f"{path}.file = {show(table['file'])}: {exc}") from None
        search = _made(path, {"track": "file"}, lambda: TrackSearch.from_track(track, geo, width, law))
    else:
        points = _track_points(path, where, table[where], geo)
        search = _made(path, {"track": where}, lambda: TrackSearch(points, width, law))
    return search, [], np.array(search.track), None, {"track": where}


def _position(path, table, geo, directory):
    t = _time(path, table, geo)
    where = _one_of(path, table, ("position", "position_latlon"), "the reported position")
    position = _positions(path, where, table[where], geo, single=True)
    _one_of(path, table, ("sigma", "cov"), "the error's standard deviation (sigma, m) or covariance (cov, m^2)")
    error = ({"sigma": keys.number(table["sigma"], f"{path}.sigma")} if "sigma" in table
             else {"cov": keys.matrix(table["cov"], f"{path}.cov")})
    report = _made(path, {"position": where}, lambda: PositionReport(position, t, **error))
    return report, [], None, np.array([report.position]), {"t": "t"}


def _bearings(path, table, geo, directory):
    t = _time(path, table, geo)
    where = _one_of(path, table, ("sensors", "sensors_latlon"), "the stations' positions")
    sensors = _positions(path, where, table[where], geo)
    values = {}
    for name in ("bearings", "sigmas"):
        key = _one_of(path, table, (name, f"{name}_deg"), f"one {name[:-1]} per sensor")
        values[name] = [math.radians(v) if key.endswith("_deg") else v for v in keys.numbers(table[key], f"{path}.{key}")]
        values[f"{name}_key"] = key
    bearings = values["bearings"]
    if geo is not None:  # true bearings, turned into grid bearings at each station
        bearings = [geo.grid_bearing(b, *p) if math.isfinite(b) else b for b, p in zip(bearings, sensors)] \
            + bearings[len(sensors):]
    renamed = {"sensors": where, "bearings": values["bearings_key"], "sigmas": values["sigmas_key"]}
    fix = _made(path, renamed, lambda: BearingFix(sensors=sensors, bearings=bearings, sigmas=values["sigmas"]))
    report = _made(path, {}, lambda: BearingReport(fix, t))
    return report, [], None, np.array(fix.sensors), {"t": "t"}


def _exclusion(path, table, geo, directory):
    where, polygon, frame = _polygon(path, table, geo, directory)
    land = _made(path, {"polygon": where}, lambda: Exclusion(polygon, frame=frame))
    return land, [np.array(region.vertices) for region in land.regions], None, None, {}


# --- values -----------------------------------------------------------------------------------


def _one_of(path: str, table: dict, options: tuple, what: str) -> str:
    """The one key of ``options`` the table gives (refusing none, or several)."""
    given = [key for key in options if key in table]
    if not given:
        raise SceneKeyError(f"{path}.{options[0]}: missing; expected {what} (give one of {', '.join(options)})")
    if len(given) > 1:
        raise SceneKeyError(f"{path}: give one of {', '.join(options)}, not several ("
                            + ", ".join(f"{key} = {show(table[key])}" for key in given) + ")")
    return given[0]


def _time(path: str, table: dict, geo, *, interval: bool = False):
    """``t``: s since the last fix, or an ISO UTC time in a geographic scene with a time; a pair
    [t0, t1] where ``interval``."""
    if "t" not in table:
        raise SceneKeyError(f"{path}.t: missing; expected the time on the scene's timeline (s since the last fix"
                            + (", or [t0, t1]" if interval else "") + ")")
    value = table["t"]
    if isinstance(value, list):
        if not interval:
            raise SceneKeyError(f"{path}.t = {show(value)}: expected one time (only an area search takes [t0, t1])")
        if len(value) != 2:
            raise SceneKeyError(f"{path}.t = {show(value)}: expected a time or a pair [t0, t1]")
        t0, t1 = (_seconds(f"{path}.t[{j}]", v, geo) for j, v in enumerate(value))
        if t1 < t0:
            raise SceneKeyError(f"{path}.t = {show(value)}: the search ends before it starts; expected t0 <= t1")
        return (t0, t1)
    return _seconds(f"{path}.t", value, geo)


def _seconds(where: str, value, geo) -> float:
    """A time on the scene's clock, s: a number, or an ISO 8601 UTC time (a string or a TOML
    offset date-time) in a geographic scene with a time."""
    if isinstance(value, (str, datetime)):
        if geo is None or geo.time is None:
            raise SceneKeyError(f"{where} = {show(value)}: a UTC time needs a [geo] table with a time (t = 0); "
                                "give s since the last fix")
        try:
            seconds = (parse_utc(value, where) - geo.time).total_seconds()
        except BananagridError as exc:
            raise SceneKeyError(str(exc)) from None
        if seconds < 0.0:
            raise SceneKeyError(f"{where} = {show(value)}: before the last fix ({geo.time.isoformat()}); evidence "
                                "comes after it")
        return seconds
    seconds = keys.number(value, where)
    if not math.isfinite(seconds) or seconds < 0.0:
        raise SceneKeyError(f"{where} = {show(value)}: must be finite and >= 0 (s since the last fix)")
    return seconds


def _positions(path: str, where: str, value, geo, single: bool = False):
    """Positions in world metres: ``[x, y]`` pairs, or ``[lat, lon]`` under ``*_latlon``."""
    full = f"{path}.{where}"
    if where.endswith("_latlon"):
        points = [keys.pairs([value], full)[0]] if single else keys.pairs(value, full)
        out = []
        for k, (lat, lon) in enumerate(points):
            at = full if single else f"{full}[{k}]"
            if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
                raise SceneKeyError(f"{at} = {show([lat, lon])}: expected [latitude in [-90, 90], longitude in "
                                    "[-180, 180]] degrees")
            try:
                x, y = geo.local(lat, lon)
            except BananagridError as exc:
                raise SceneKeyError(f"{at} = {show([lat, lon])}: {exc}") from None
            out.append((float(x), float(y)))
        return out[0] if single else out
    return keys.pairs([value], full)[0] if single else keys.pairs(value, full)


def _polygon(path: str, table: dict, geo, directory: Path):
    """``(key, vertices or GeoJSON path, frame)``: inline metres, ``[lat, lon]`` vertices, or a
    GeoJSON file (longitude and latitude through the frame in a geographic scene)."""
    where = _one_of(path, table, ("polygon", "polygon_latlon", "file"), "the area (a polygon)")
    if where == "file":
        return where, str(_file(path, table, directory)), geo
    return where, _positions(path, where, table[where], geo), None


def _file(path: str, table: dict, directory: Path) -> Path:
    value = table["file"]
    if not isinstance(value, str) or not value.strip():
        raise SceneKeyError(f"{path}.file = {show(value)}: expected a file name (relative to the scene file)")
    file = directory / value
    if not file.is_file():
        raise SceneKeyError(f"{path}.file = {show(value)}: no such file ({file})")
    return file


def _track_points(path: str, where: str, value, geo) -> np.ndarray:
    """``[[x, y, t], ...]`` (or ``[[lat, lon, t], ...]``) as (n, 3) world metres and s."""
    full = f"{path}.{where}"
    if not isinstance(value, list) or len(value) < 2:
        raise SceneKeyError(f"{full} = {show(value)}: expected at least 2 points [x, y, t]"
                            if not where.endswith("_latlon") else
                            f"{full} = {show(value)}: expected at least 2 points [lat, lon, t]")
    rows = []
    for k, item in enumerate(value):
        if not isinstance(item, list) or len(item) != 3:
            shape = "[lat, lon, t]" if where.endswith("_latlon") else "[x, y, t] (m, m, s)"
            raise SceneKeyError(f"{full}[{k}] = {show(item)}: expected {shape}")
        a, b = (keys.number(v, f"{full}[{k}][{j}]") for j, v in enumerate(item[:2]))
        if where.endswith("_latlon"):
            a, b = _positions(path, where, [a, b], geo, single=True)
        elif not (math.isfinite(a) and math.isfinite(b)):
            raise SceneKeyError(f"{full}[{k}] = {show(item)}: positions must be finite")
        rows.append((a, b, _seconds(f"{full}[{k}][2]", item[2], geo)))
    return np.array(rows, dtype=float)


def _made(path: str, renamed: dict, build):
    """``build()``, its one-line refusal restated with the scene's keys (``renamed``: the
    constructor's arguments -> the keys that set them, replaced where the message names them
    before its first colon) under ``path``."""
    try:
        return build()
    except BananagridError as exc:
        head, sep, rest = str(exc).partition(": ")
        key = re.match(r"\w+", head)
        head = re.sub(r"\b\w+\b", lambda m: renamed.get(m.group(0), m.group(0)), head.split(" = ")[0]) \
            + head[len(head.split(" = ")[0]):]
        message = head + sep + rest
        if key and (key.group(0) in renamed or key.group(0) in _OWN_KEYS):
            raise SceneKeyError(f"{path}.{message}") from None
        raise SceneKeyError(f"{path}: {message}") from None


#: Arguments of the evidence constructors that are scene keys of the same name.
_OWN_KEYS = ("t", "pod", "coverage", "sigma", "cov", "sweep_width", "law", "track", "position", "sensors")
