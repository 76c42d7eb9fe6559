"""Inputs from the field: tracks, last fixes and bearings read from the files people have.

A track is a list of timed positions ``(lon, lat, utc)``; its last point is the last fix. The
formats, recognised by their content (``format=`` names one instead):

* **CSV** with a header naming the columns (case and spaces ignored): ``time`` (or ``utc``,
  ``timestamp``), ``lat`` (``latitude``), ``lon`` (``lng``, ``longitude``), and optionally the
  course over ground in degrees true (``course_deg``, ``cog_deg``, ``cog``) and the speed over
  ground in m/s (``speed_mps``, ``sog_mps``) or knots (``speed_kn``, ``sog_kn``, ``sog``); a
  plain ``speed`` is refused (its unit is unknown). Comma, semicolon or tab separated.
* **GPX** 1.0 / 1.1: every ``trkpt`` (else ``rtept``, else ``wpt``) with its ``time``; GPX 1.0's
  ``course`` (degrees) and ``speed`` (m/s) where given. GPX times are UTC by the standard.
* **NMEA 0183**: ``GGA`` and ``RMC`` positions of any talker (a GGA takes its date from the
  latest RMC; both of one epoch make one point, RMC's course and speed over ground with it;
  sentences without a fix, GGA quality 0 or RMC status V, are skipped), and AIS position
  reports ``!AIVDM``/``!AIVDO`` of types 1, 2, 3 (class A) and 18 (class B), 6-bit decoded here
  (ITU-R M.1371-5, Annex 8, Tables 48 and 70: thirty lines of bit fields, not worth a
  dependency). An AIS report carries only the second of the minute: its time comes from the
  receiver's, a tag block ``\\c:UNIX,...*hh\\`` or a trailing ``,UNIX`` field after the checksum,
  moved back to the report's second. Every checksum is verified; one that is missing or wrong
  is refused with its line number. Other sentences (GSV, VTG, ...) are skipped.
* **GeoJSON** (RFC 7946): a ``Point`` feature with a ``time`` property (one fix), a
  ``FeatureCollection`` of such points (a track, in file order), or a ``LineString`` feature
  with a list of times in ``properties.times`` (or ``coordTimes``, or
  ``coordinateProperties.times`` as togeojson writes); ``course_deg``, ``speed_mps`` or
  ``speed_kn`` properties of a point are its course and speed.

Bearings are CSV with the columns ``station_lat``, ``station_lon`` (or ``lat``, ``lon``),
``bearing_deg`` (true), ``sigma_deg``, ``time`` and optionally ``station`` (a name).

Everything is validated once, here: a file missing, unreadable, binary, not UTF-8, empty,
without times, with times that do not increase, a latitude outside [-90, 90] or a longitude
outside [-180, 180] is one :class:`~bananagrid.validate.BananagridError` line naming the file,
the line (a JSON path in GeoJSON) and what is allowed. Times need a zone (``Z`` or an offset),
but GPX's, which are UTC by the standard. Angles in the returned objects are radians, speeds m/s
(the Python API's units); positions stay degrees of latitude and longitude (WGS84).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import xml.parsers.expat
from dataclasses import dataclass, field
from datetime import date, datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from ..validate import BananagridError, regular_file, show
from .frame import parse_utc
from .libraries import require

__all__ = ["Track", "Fix", "Bearings", "read_track", "read_fix", "read_bearings", "FORMATS", "MAX_INPUT_BYTES",
           "KNOT", "PASS_MMSI", "nmea_checksum", "decode_ais"]

#: The formats a track or fix may be read from (``format=``; by default recognised by content).
FORMATS = ("csv", "gpx", "nmea", "geojson")
#: Largest file read (bytes): a track of a million points in any of the formats is far smaller.
MAX_INPUT_BYTES = 256 * 1024 * 1024
#: One knot in m/s (1852 m per hour).
KNOT = 1852.0 / 3600.0
#: How a message asks for one vessel of several (a scene says which key to give instead).
PASS_MMSI = "pass the mmsi of the vessel wanted"


@dataclass(frozen=True)
class Fix:
    """A last fix: where and when a target was last seen, and how it moved.

    Attributes
    ----------
    lat, lon : float
        Degrees (WGS84).
    time : datetime
        UTC (timezone-aware).
    course : float or None
        Course over ground, rad clockwise from true north, in [0, 2 pi); None where unknown.
    speed : float or None
        Speed over ground, m/s; None where unknown.
    source : str
        The file and line it came from, for messages.
    """

    lat: float
    lon: float
    time: datetime
    course: float | None = None
    speed: float | None = None
    source: str = ""


@dataclass(frozen=True, eq=False)  # arrays: compare their fields, not the objects
class Track:
    """Timed positions, times strictly increasing.

    Iterating gives ``(lon, lat, utc)`` tuples; ``len`` is the number of points.

    Attributes
    ----------
    lon, lat : numpy.ndarray
        Degrees (WGS84), shape ``(n,)``.
    times : tuple of datetime
        UTC, strictly increasing.
    course, speed : numpy.ndarray
        The file's own course over ground (rad, true) and speed over ground (m/s) at each
        point, NaN where it gives none.
    lines : tuple of int
        The line of the file each point came from (0 where a format has no lines).
    source : str
        The file it was read from.
    """

    lon: np.ndarray
    lat: np.ndarray
    times: tuple
    course: np.ndarray
    speed: np.ndarray
    lines: tuple = ()
    source: str = ""

    def __iter__(self):
        return iter(zip(self.lon.tolist(), self.lat.tolist(), self.times))

    def __len__(self) -> int:
        return len(self.times)

    @property
    def points(self) -> list[tuple[float, float, datetime]]:
        """``[(lon, lat, utc), ...]``."""
        return list(self)

    def last_fix(self) -> Fix:
        """The last point as a :class:`Fix`: its course and speed the file's own where it gives
        them, else those of the geodesic from the point before (its azimuth on arrival, its
        length over the time between them); None where neither is known (one point, or the
        last two at one place)."""
        k = len(self) - 1
        course = float(self.course[k]) if np.isfinite(self.course[k]) else None
        speed = float(self.speed[k]) if np.isfinite(self.speed[k]) else None
        if (course is None or speed is None) and k >= 1:
            geod = require("pyproj", "courses and speeds from a track").Geod(ellps="WGS84")
            _, back, metres = geod.inv(self.lon[k - 1], self.lat[k - 1], self.lon[k], self.lat[k])
            seconds = (self.times[k] - self.times[k - 1]).total_seconds()
            if speed is None:
                speed = float(metres) / seconds
            if course is None and metres > 0.0:
                course = math.radians((float(back) + 180.0) % 360.0) % (2.0 * math.pi)
        line = self.lines[k] if self.lines else 0
        where = f"{self.source}: line {line}" if line else self.source
        return Fix(lat=float(self.lat[k]), lon=float(self.lon[k]), time=self.times[k], course=course, speed=speed,
                   source=where)


@dataclass(frozen=True, eq=False)
class Bearings:
    """Bearings taken at stations.

    Attributes
    ----------
    lat, lon : numpy.ndarray
        The stations, degrees (WGS84), shape ``(n,)``.
    bearings : numpy.ndarray
        True bearings to the target, rad clockwise from true north, in [0, 2 pi).
    sigmas : numpy.ndarray
        Their standard deviations, rad, in (0, pi / 2).
    times : tuple of datetime
        UTC of each bearing.
    names : tuple of str
        Station names ("" where the file gives none).
    source : str
        The file.
    """

    lat: np.ndarray
    lon: np.ndarray
    bearings: np.ndarray
    sigmas: np.ndarray
    times: tuple
    names: tuple = ()
    source: str = field(default="")

    def __len__(self) -> int:
        return len(self.times)


# --- the public readers -------------------------------------------------------------------------


def read_track(path: str | os.PathLike, *, format: str | None = None, mmsi: int | None = None) -> Track:
    """The timed positions in the file at ``path``.

    Parameters
    ----------
    path : path-like
        A CSV, GPX, NMEA 0183 or GeoJSON file (see :mod:`bananagrid.geo.inputs`).
    format : {"csv", "gpx", "nmea", "geojson"}, optional
        The file's format (default: recognised from its first character: ``<`` GPX, ``{``
        GeoJSON, ``$``, ``!`` or ``\\`` NMEA, anything else CSV).
    mmsi : int, optional
        The vessel whose AIS reports make the track, in an NMEA file that holds several vessels
        (or AIS beside the receiver's own GGA/RMC positions).

    Returns
    -------
    Track
        At least one point; times strictly increasing.

    Raises
    ------
    BananagridError
        One line naming the file, the line (or JSON path) and what is allowed.
    """
    source = Path(path)
    text, raw = _read_text(source, xml=format in (None, "gpx"))
    kind = "gpx" if text is None else _format(source, text, format)
    if kind == "gpx":
        rows = _gpx_rows(source, raw)
    elif kind == "geojson":
        rows = _geojson_rows(source, text)
    elif kind == "nmea":
        rows = _nmea_rows(source, text, mmsi)
    else:
        rows = _csv_rows(source, text)
    if mmsi is not None and kind != "nmea":
        raise BananagridError(f"{source}: mmsi = {mmsi!r}: selects AIS reports of an NMEA file; this is {kind.upper()}")
    return _track(source, rows)


def read_fix(path: str | os.PathLike, *, format: str | None = None, mmsi: int | None = None) -> Fix:
    """The last fix of the track in the file at ``path`` (:func:`read_track`,
    :meth:`Track.last_fix`): its last point, time, and course and speed over ground (the
    file's own at that point where given, else from the last two points)."""
    return read_track(path, format=format, mmsi=mmsi).last_fix()


def read_bearings(path: str | os.PathLike) -> Bearings:
    """Bearings from a CSV file with the columns ``station_lat``, ``station_lon`` (or ``lat``,
    ``lon``), ``bearing_deg`` (true, in [0, 360)), ``sigma_deg`` (in (0, 90)), ``time`` (ISO
    8601 with a zone) and optionally ``station`` (a name).

    Raises
    ------
    BananagridError
        One line naming the file, the line and what is allowed.
    """
    source = Path(path)
    text, _ = _read_text(source)
    header, records = _csv_records(source, text)
    columns = _columns(source, header, {
        "lat": ("station_lat", "lat", "latitude"), "lon": ("station_lon", "lon", "lng", "longitude"),
        "bearing": ("bearing_deg",), "sigma": ("sigma_deg",), "time": _TIME_NAMES, "name": ("station", "name"),
    }, required=("lat", "lon", "bearing", "sigma", "time"), unitless={"bearing": ("bearing", "bearing_deg"), "sigma": ("sigma", "sigma_deg")})
    lat, lon, bearing, sigma, times, names = [], [], [], [], [], []
    for line, record in records:
        cell = _cells(source, line, record, header)
        la, lo = _position(source, line, cell(columns["lat"]), cell(columns["lon"]))
        b = _number(source, line, "bearing_deg", cell(columns["bearing"]))
        if not 0.0 <= b < 360.0:
            raise BananagridError(f"{source}: line {line}: bearing_deg = {show(b)}: must lie in [0, 360) degrees true")
        s = _number(source, line, "sigma_deg", cell(columns["sigma"]))
        if not 0.0 < s < 90.0:
            raise BananagridError(f"{source}: line {line}: sigma_deg = {show(s)}: must lie in (0, 90) degrees")
        lat.append(la)
        lon.append(lo)
        bearing.append(math.radians(b))
        sigma.append(math.radians(s))
        times.append(_utc(source, line, cell(columns["time"])))
        names.append(cell(columns["name"]).strip() if "name" in columns else "")
    if not times:
        raise BananagridError(f"{source}: no bearings (a header and no rows); expected one row per bearing")
    return Bearings(lat=np.array(lat), lon=np.array(lon), bearings=np.array(bearing), sigmas=np.array(sigma),
                    times=tuple(times), names=tuple(names), source=str(source))


# --- reading and recognising ----------------------------------------------------------------------


def _read_text(path: Path, xml: bool = False) -> tuple[str | None, bytes]:
    """The file's text (UTF-8, a byte-order mark dropped) and bytes, or one line saying why not;
    with ``xml``, an XML document in another encoding it declares gives None for the text (expat
    reads the bytes)."""
    path = regular_file(path, "a track or bearings file")
    size = path.stat().st_size
    if size > MAX_INPUT_BYTES:
        raise BananagridError(f"{path}: {size:,} bytes, more than the {MAX_INPUT_BYTES:,} a track file may have")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise BananagridError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if not raw.strip():
        raise BananagridError(f"{path}: empty; expected a track (CSV, GPX, NMEA 0183 or GeoJSON)")
    if b"\x00" in raw:
        line = raw[: raw.index(b"\x00")].count(b"\n") + 1
        raise BananagridError(f"{path}: line {line}: binary data (a NUL byte), not a text file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if xml and re.match(rb"\s*<\?xml[^>]*encoding=", raw):
            return None, raw
        line = raw[: exc.start].count(b"\n") + 1
        raise BananagridError(f"{path}: line {line}: not UTF-8 text (byte {exc.start}); save the file as UTF-8") from None
    return text, raw


def _format(path: Path, text: str, format: str | None) -> str:
    if format is not None:
        if format not in FORMATS:
            raise BananagridError(f"format = {show(format)}: must be one of {', '.join(map(show, FORMATS))}")
        return format
    first = text.lstrip()[:1]
    return {"<": "gpx", "{": "geojson", "$": "nmea", "!": "nmea", "\\": "nmea"}.get(first, "csv")


# --- what every format gives: rows, then one validated track ------------------------------------


@dataclass
class _Row:
    line: int  # 0 where the format has no lines (GeoJSON: ``where`` names the JSON path)
    lat: float
    lon: float
    time: datetime
    course: float = math.nan  # rad
    speed: float = math.nan  # m/s
    where: str = ""


def _at(path: Path, row: _Row) -> str:
    return f"{path}: {row.where}" if row.where else f"{path}: line {row.line}"


def _track(path: Path, rows: list[_Row]) -> Track:
    if not rows:
        raise BananagridError(f"{path}: no timed positions found; expected a track (CSV, GPX, NMEA 0183 or GeoJSON)")
    for k, row in enumerate(rows):
        _check_position(_at(path, row), row.lat, row.lon)
        if k and not row.time > rows[k - 1].time:
            before = rows[k - 1]
            earlier = f"line {before.line}" if not before.where else before.where
            raise BananagridError(
                f"{_at(path, row)}: time {_iso(row.time)} is not after {_iso(before.time)} ({earlier}); "
                "a track's times must strictly increase"
            )
        if not (math.isnan(row.speed) or (math.isfinite(row.speed) and row.speed >= 0.0)):
            raise BananagridError(f"{_at(path, row)}: speed {row.speed!r} m/s: must be finite and >= 0")
        if not (math.isnan(row.course) or math.isfinite(row.course)):
            raise BananagridError(f"{_at(path, row)}: course {row.course!r}: must be finite")
    return Track(
        lon=np.array([r.lon for r in rows]), lat=np.array([r.lat for r in rows]), times=tuple(r.time for r in rows),
        course=np.array([r.course % (2.0 * math.pi) if math.isfinite(r.course) else math.nan for r in rows]),
        speed=np.array([r.speed for r in rows]), lines=tuple(r.line for r in rows), source=str(path),
    )


def _check_position(where: str, lat: float, lon: float) -> None:
    if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
        raise BananagridError(f"{where}: latitude {lat!r}: must lie in [-90, 90] degrees")
    if not (math.isfinite(lon) and -180.0 <= lon <= 180.0):
        raise BananagridError(f"{where}: longitude {lon!r}: must lie in [-180, 180] degrees")


def _iso(when: datetime) -> str:
    return when.isoformat().replace("+00:00", "Z")


def _utc(path: Path, line: int, value: str, *, naive_utc: bool = False, where: str = "") -> datetime:
    """An ISO 8601 time as UTC; a naive one is refused unless ``naive_utc`` (GPX: UTC by the standard)."""
    at = where or f"line {line}"
    value = value.strip()
    if not value:
        raise BananagridError(f"{path}: {at}: no time; every position needs its UTC time (ISO 8601, e.g. "
                              "2026-11-24T05:40:00Z)")
    if naive_utc and re.fullmatch(r"[0-9T:.\- ]+", value):
        value += "Z"
    try:
        return parse_utc(value, "time")
    except BananagridError as exc:
        raise BananagridError(f"{path}: {at}: {exc}") from None


# --- CSV ----------------------------------------------------------------------------------------------

_TIME_NAMES = ("time", "utc", "timestamp", "datetime", "time_utc")


def _csv_records(path: Path, text: str) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """The header (lower case, stripped) and the non-blank records with their line numbers."""
    first = next(line for line in text.splitlines() if line.strip())
    delimiter = max((",", ";", "\t"), key=first.count)
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter, strict=True)
    header, records = None, []
    try:
        for record in reader:
            if not any(cell.strip() for cell in record):
                continue
            if header is None:
                header = [cell.strip().lower() for cell in record]
            else:
                records.append((reader.line_num, record))
    except csv.Error as exc:
        raise BananagridError(f"{path}: line {reader.line_num}: not CSV ({exc})") from None
    return header, records


def _columns(path: Path, header: list[str], names: dict, *, required, unitless=None) -> dict:
    """Column index of each wanted field (its first name found in ``header``)."""
    out = {}
    for key, choices in names.items():
        for choice in choices:
            if choice in header:
                out[key] = header.index(choice)
                break
    for key, (plain, named) in (unitless or {}).items():
        if key not in out and plain in header:
            raise BananagridError(f"{path}: line 1: column {show(plain)}: name its unit ({named})")
    missing = [names[key][0] for key in required if key not in out]
    if missing:
        raise BananagridError(
            f"{path}: line 1: no column {' or '.join(missing)} in the header ({', '.join(header)}); expected "
            + ", ".join(" or ".join(names[key]) for key in required)
        )
    return out


def _cells(path: Path, line: int, record: list[str], header: list[str]):
    if len(record) != len(header):
        raise BananagridError(f"{path}: line {line}: {len(record)} field{'' if len(record) == 1 else 's'}, the header "
                              f"has {len(header)}")
    return lambda k: record[k]


def _number(path: Path, line: int, name: str, value: str) -> float:
    try:
        number = float(value.strip())
    except ValueError:
        raise BananagridError(f"{path}: line {line}: {name} = {show(value.strip())}: expected a number") from None
    if not math.isfinite(number):
        raise BananagridError(f"{path}: line {line}: {name} = {show(value.strip())}: must be finite")
    return number


def _position(path: Path, line: int, lat: str, lon: str) -> tuple[float, float]:
    la, lo = _number(path, line, "latitude", lat), _number(path, line, "longitude", lon)
    _check_position(f"{path}: line {line}", la, lo)
    return la, lo


def _csv_rows(path: Path, text: str) -> list[_Row]:
    header, records = _csv_records(path, text)
    columns = _columns(path, header, {
        "time": _TIME_NAMES, "lat": ("lat", "latitude"), "lon": ("lon", "lng", "long", "longitude"),
        "course": ("course_deg", "cog_deg", "cog"), "speed_mps": ("speed_mps", "sog_mps"),
        "speed_kn": ("speed_kn", "sog_kn", "sog"),
    }, required=("time", "lat", "lon"), unitless={"speed_kn": ("speed", "speed_mps or speed_kn"), "course": ("course", "course_deg")})
    rows = []
    for line, record in records:
        cell = _cells(path, line, record, header)
        lat, lon = _position(path, line, cell(columns["lat"]), cell(columns["lon"]))
        row = _Row(line, lat, lon, _utc(path, line, cell(columns["time"])))
        if "course" in columns and cell(columns["course"]).strip():
            row.course = math.radians(_number(path, line, "course_deg", cell(columns["course"])))
        for key, scale in (("speed_mps", 1.0), ("speed_kn", KNOT)):
            if key in columns and cell(columns[key]).strip():
                row.speed = _number(path, line, key, cell(columns[key])) * scale
        rows.append(row)
    return rows


# --- GPX ----------------------------------------------------------------------------------------------


def _gpx_rows(path: Path, raw: bytes) -> list[_Row]:
    """Points of the GPX document: ``trkpt``, else ``rtept``, else ``wpt`` (expat gives the
    line of each; a DOCTYPE, and with it any entity expansion, is refused)."""
    parser = xml.parsers.expat.ParserCreate(namespace_separator=" ")
    points: dict[str, list[dict]] = {"trkpt": [], "rtept": [], "wpt": []}
    stack: list[str] = []
    current: dict | None = None
    text: list[str] = []

    def local(name: str) -> str:
        return name.rsplit(" ", 1)[-1]

    def start(name, attrs):
        nonlocal current
        tag = local(name)
        stack.append(tag)
        text.clear()
        if tag in points and current is None:
            current = {"tag": tag, "line": parser.CurrentLineNumber, "lat": attrs.get("lat"), "lon": attrs.get("lon")}

    def end(name):
        nonlocal current
        tag = stack.pop()
        if current is not None and tag in ("time", "course", "speed") and stack and stack[-1] == current["tag"]:
            current[tag] = "".join(text).strip()
        if current is not None and tag == current["tag"]:
            points[tag].append(current)
            current = None
        text.clear()

    def doctype(*_):
        raise BananagridError(f"{path}: line {parser.CurrentLineNumber}: a DOCTYPE in GPX is not read (entities)")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = text.append
    parser.StartDoctypeDeclHandler = doctype
    try:
        parser.Parse(raw, True)
    except xml.parsers.expat.ExpatError as exc:
        raise BananagridError(f"{path}: line {exc.lineno}: not well-formed XML ({xml.parsers.expat.ErrorString(exc.code)})") from None
    found = points["trkpt"] or points["rtept"] or points["wpt"]
    rows = []
    for p in found:
        line = p["line"]
        if p["lat"] is None or p["lon"] is None:
            raise BananagridError(f"{path}: line {line}: <{p['tag']}> without lat and lon attributes")
        lat, lon = _position(path, line, p["lat"], p["lon"])
        if "time" not in p:
            raise BananagridError(f"{path}: line {line}: <{p['tag']}> without <time>; every point needs its UTC time")
        row = _Row(line, lat, lon, _utc(path, line, p["time"], naive_utc=True))
        if p.get("course"):
            row.course = math.radians(_number(path, line, "course", p["course"]))
        if p.get("speed"):
            row.speed = _number(path, line, "speed", p["speed"])
        rows.append(row)
    return rows


# --- GeoJSON ------------------------------------------------------------------------------------------


def _geojson_rows(path: Path, text: str) -> list[_Row]:
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise BananagridError(f"{path}: line {exc.lineno}: not JSON ({exc.msg})") from None
    except RecursionError:
        raise BananagridError(f"{path}: not JSON this reader can hold (nested too deeply)") from None
    kind = doc.get("type") if isinstance(doc, dict) else None
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list):
            raise BananagridError(f"{path}: features: expected a list of Feature objects")
        lines = [f for f in features if isinstance(f, dict) and isinstance(f.get("geometry"), dict)
                 and f["geometry"].get("type") == "LineString"]
        if len(features) == 1 and lines:
            return _geojson_line(path, features[0], "features[0]")
        rows = []
        for k, feature in enumerate(features):
            rows += _geojson_point(path, feature, f"features[{k}]")
        return rows
    if kind == "Feature":
        geometry = doc.get("geometry")
        if isinstance(geometry, dict) and geometry.get("type") == "LineString":
            return _geojson_line(path, doc, "feature")
        return _geojson_point(path, doc, "feature")
    raise BananagridError(
        f"{path}: type = {show(kind) if isinstance(kind, str) else 'missing'}: expected a Feature (a Point with a "
        "time property, or a LineString with properties.times) or a FeatureCollection of timed Points"
    )


def _lonlat(path: Path, where: str, value) -> tuple[float, float]:
    if (not isinstance(value, list) or len(value) < 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value[:2])):
        raise BananagridError(f"{path}: {where} = {show(value)}: expected [longitude, latitude]")
    lon, lat = float(value[0]), float(value[1])
    _check_position(f"{path}: {where}", lat, lon)
    return lon, lat


def _geojson_point(path: Path, feature, where: str) -> list[_Row]:
    if not isinstance(feature, dict) or feature.get("type") != "Feature":
        raise BananagridError(f"{path}: {where}: expected a Feature")
    geometry = feature.get("geometry")
    if not isinstance(geometry, dict) or geometry.get("type") != "Point":
        kind = geometry.get("type") if isinstance(geometry, dict) else None
        raise BananagridError(f"{path}: {where}.geometry: {show(kind) if kind else 'none'}; expected a Point (a "
                              "collection of timed points) or one LineString with properties.times")
    properties = feature.get("properties") or {}
    if not isinstance(properties, dict):
        raise BananagridError(f"{path}: {where}.properties: expected an object")
    lon, lat = _lonlat(path, f"{where}.geometry.coordinates", geometry.get("coordinates"))
    time = properties.get("time")
    if not isinstance(time, str):
        raise BananagridError(f"{path}: {where}.properties.time = {show(time) if time is not None else 'missing'}: "
                              "expected an ISO 8601 UTC time such as \"2026-11-24T05:40:00Z\"")
    row = _Row(0, lat, lon, _utc(path, 0, time, where=f"{where}.properties.time"), where=where)
    for name, attr, scale in (("course_deg", "course", math.radians(1.0)), ("speed_mps", "speed", 1.0),
                              ("speed_kn", "speed", KNOT)):
        value = properties.get(name)
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise BananagridError(f"{path}: {where}.properties.{name} = {show(value)}: expected a finite number")
        setattr(row, attr, float(value) * scale)
    return [row]


def _geojson_line(path: Path, feature: dict, where: str) -> list[_Row]:
    coordinates = feature["geometry"].get("coordinates")
    if not isinstance(coordinates, list) or not coordinates:
        raise BananagridError(f"{path}: {where}.geometry.coordinates: expected a list of [longitude, latitude]")
    properties = feature.get("properties") or {}
    times, named = None, ""
    if isinstance(properties, dict):
        for name in ("times", "coordTimes"):
            if name in properties:
                times, named = properties[name], f"{where}.properties.{name}"
                break
        nested = properties.get("coordinateProperties")
        if times is None and isinstance(nested, dict) and "times" in nested:
            times, named = nested["times"], f"{where}.properties.coordinateProperties.times"
    if times is None:
        raise BananagridError(f"{path}: {where}.properties.times: missing; a LineString track needs one UTC time per "
                              "point (properties.times, coordTimes or coordinateProperties.times)")
    if not isinstance(times, list) or len(times) != len(coordinates):
        count = len(times) if isinstance(times, list) else "no"
        raise BananagridError(f"{path}: {named}: {count} times for {len(coordinates)} points; give one per point")
    rows = []
    for k, (point, time) in enumerate(zip(coordinates, times)):
        lon, lat = _lonlat(path, f"{where}.geometry.coordinates[{k}]", point)
        if not isinstance(time, str):
            raise BananagridError(f"{path}: {named}[{k}] = {show(time)}: expected an ISO 8601 UTC time")
        rows.append(_Row(0, lat, lon, _utc(path, 0, time, where=f"{named}[{k}]"), where=f"{named}[{k}]"))
    return rows


# --- NMEA 0183 and AIS ----------------------------------------------------------------------------


def nmea_checksum(body: str) -> str:
    """The NMEA 0183 checksum of a sentence's body (between ``$``/``!`` and ``*``): the XOR of
    its characters, as two upper-case hex digits."""
    value = 0
    for char in body:
        value ^= ord(char)
    return f"{value:02X}"


_SENTENCE = re.compile(r"(?:\\(?P<tag>[^\\]*)\\)?(?P<start>[$!])(?P<body>[^*]*)(?:\*(?P<sum>[0-9A-Fa-f]{2}))?(?P<rest>.*)")


def _nmea_rows(path: Path, text: str, mmsi: int | None) -> list[_Row]:
    gnss: list[_Row] = []
    ais: dict[int, list[_Row]] = {}
    day: date | None = None
    dated: datetime | None = None  # the time of the RMC that gave ``day``
    for line, sentence in enumerate(text.splitlines(), start=1):
        sentence = sentence.strip()
        if not sentence:
            continue
        match = _SENTENCE.fullmatch(sentence)
        if match is None:
            raise BananagridError(f"{path}: line {line}: not an NMEA 0183 sentence (expected $... or !... with a "
                                  "*hh checksum)")
        body, given = match["body"], match["sum"]
        if given is None:
            raise BananagridError(f"{path}: line {line}: no checksum (*hh); a sentence without one cannot be trusted")
        if given.upper() != nmea_checksum(body):
            raise BananagridError(f"{path}: line {line}: checksum *{given} does not match the sentence "
                                  f"(*{nmea_checksum(body)}); the line is damaged")
        received = _tag_time(path, line, match["tag"]) if match["tag"] is not None else None
        fields = body.split(",")
        kind = fields[0][-3:]  # the talker (GP, GN, AI, BS, ...) before it is anyone's
        if match["start"] == "!" and kind in ("VDM", "VDO"):
            trailing = match["rest"].lstrip(",").strip()
            if received is None and trailing:
                received = _unix(path, line, trailing, "a trailing receive time")
            report = _ais_row(path, line, fields, received)
            if report is not None:
                rows = ais.setdefault(report[0], [])
                same = rows and (rows[-1].time, rows[-1].lat, rows[-1].lon) == (report[1].time, report[1].lat, report[1].lon)
                if not same:  # one report heard twice (two receivers, two channels) is one point
                    rows.append(report[1])
            continue
        if match["start"] != "$" or kind not in ("GGA", "RMC"):
            continue  # GSV, VTG, GSA, ...: no position
        if kind == "RMC":
            row, day = _rmc(path, line, fields)
            dated = row.time if row is not None else datetime(day.year, day.month, day.day, tzinfo=timezone.utc)
        else:
            row = _gga(path, line, fields, day)
            if row is not None and dated is not None and row.time < dated - timedelta(hours=12):
                row.time += timedelta(days=1)  # past midnight since the RMC that gave the date
        if row is None:
            continue
        if gnss and gnss[-1].time == row.time:  # GGA and RMC of one epoch: one point, RMC's motion
            last = gnss[-1]
            last.course = row.course if math.isnan(last.course) else last.course
            last.speed = row.speed if math.isnan(last.speed) else last.speed
            continue
        gnss.append(row)
    if mmsi is not None:
        if mmsi not in ais:
            held = ", ".join(map(str, sorted(ais))) or "none"
            raise BananagridError(f"{path}: mmsi = {mmsi!r}: no AIS position report of it (vessels: {held})")
        return ais[mmsi]
    if ais and gnss:
        raise BananagridError(f"{path}: holds the receiver's own GGA/RMC positions and AIS reports of "
                              f"{', '.join(map(str, sorted(ais)[:5]))}; {PASS_MMSI}")
    if len(ais) > 1:
        raise BananagridError(f"{path}: AIS reports of {len(ais)} vessels ({', '.join(map(str, sorted(ais)[:5]))}"
                              f"{', ...' if len(ais) > 5 else ''}); {PASS_MMSI}")
    return next(iter(ais.values())) if ais else gnss


def _tag_time(path: Path, line: int, tag: str) -> float | None:
    """The ``c:`` (UNIX seconds) of an NMEA 4 tag block ``c:1700000000,s:r01*hh``, its checksum verified."""
    content, _, given = tag.partition("*")
    if given and given.upper() != nmea_checksum(content):
        raise BananagridError(f"{path}: line {line}: tag block checksum *{given} does not match "
                              f"(*{nmea_checksum(content)}); the line is damaged")
    for item in content.split(","):
        if item.startswith("c:"):
            return _unix(path, line, item[2:], "the tag block's c: time")
    return None


def _unix(path: Path, line: int, value: str, what: str) -> float:
    try:
        seconds = float(value)
    except ValueError:
        raise BananagridError(f"{path}: line {line}: {what} {show(value)}: expected UNIX seconds") from None
    if seconds > 1e11:  # milliseconds, as some receivers write
        seconds /= 1000.0
    if not (math.isfinite(seconds) and 0.0 <= seconds < 253402300800.0):  # before year 10000
        raise BananagridError(f"{path}: line {line}: {what} {show(value)}: outside the calendar")
    return seconds


def _nmea_latlon(path: Path, line: int, lat: str, ns: str, lon: str, ew: str) -> tuple[float, float]:
    """``ddmm.mmmm,N,dddmm.mmmm,E`` as signed degrees."""
    try:
        la = int(lat[:2]) + float(lat[2:]) / 60.0
        lo = int(lon[:3]) + float(lon[3:]) / 60.0
    except ValueError:
        raise BananagridError(f"{path}: line {line}: position {show(f'{lat},{ns},{lon},{ew}')}: expected "
                              "ddmm.mm,N|S,dddmm.mm,E|W") from None
    if ns not in ("N", "S") or ew not in ("E", "W"):
        raise BananagridError(f"{path}: line {line}: hemispheres {show(ns)}, {show(ew)}: expected N or S, E or W")
    if not (float(lat[2:]) < 60.0 and float(lon[3:]) < 60.0):
        raise BananagridError(f"{path}: line {line}: minutes of {show(lat)} or {show(lon)}: must be below 60")
    la, lo = (-la if ns == "S" else la), (-lo if ew == "W" else lo)
    _check_position(f"{path}: line {line}", la, lo)
    return la, lo


def _clock(path: Path, line: int, value: str) -> timedelta:
    match = re.fullmatch(r"(\d\d)(\d\d)(\d\d(?:\.\d+)?)", value)
    if match is None or int(match[1]) > 23 or int(match[2]) > 59 or float(match[3]) >= 61.0:
        raise BananagridError(f"{path}: line {line}: time {show(value)}: expected hhmmss.ss (UTC)")
    return timedelta(hours=int(match[1]), minutes=int(match[2]), seconds=float(match[3]))


def _rmc(path: Path, line: int, f: list[str]) -> tuple[_Row | None, date | None]:
    """``$xxRMC,hhmmss.ss,A,lat,N,lon,E,sog_kn,cog_deg,ddmmyy,...``; None for status V (no fix)."""
    if len(f) < 10:
        raise BananagridError(f"{path}: line {line}: RMC with {len(f) - 1} fields; expected at least 9")
    match = re.fullmatch(r"(\d\d)(\d\d)(\d\d)", f[9])
    if match is None:
        raise BananagridError(f"{path}: line {line}: RMC date {show(f[9])}: expected ddmmyy")
    try:
        day = date(2000 + int(match[3]) if int(match[3]) < 80 else 1900 + int(match[3]), int(match[2]), int(match[1]))
    except ValueError:
        raise BananagridError(f"{path}: line {line}: RMC date {show(f[9])}: not a date") from None
    if f[2] != "A" or not f[3]:
        return None, day
    lat, lon = _nmea_latlon(path, line, f[3], f[4], f[5], f[6])
    when = datetime(day.year, day.month, day.day, tzinfo=timezone.utc) + _clock(path, line, f[1])
    row = _Row(line, lat, lon, when)
    if f[7]:
        row.speed = _number(path, line, "RMC speed (kn)", f[7]) * KNOT
    if f[8]:
        row.course = math.radians(_number(path, line, "RMC course (deg)", f[8]))
    return row, day


def _gga(path: Path, line: int, f: list[str], day: date | None) -> _Row | None:
    """``$xxGGA,hhmmss.ss,lat,N,lon,E,quality,...``; None for quality 0 (no fix)."""
    if len(f) < 7:
        raise BananagridError(f"{path}: line {line}: GGA with {len(f) - 1} fields; expected at least 6")
    if f[6] in ("", "0") or not f[2]:
        return None
    if day is None:
        raise BananagridError(f"{path}: line {line}: a GGA carries no date and no RMC came before it; "
                              "record RMC sentences too (they carry the date)")
    lat, lon = _nmea_latlon(path, line, f[2], f[3], f[4], f[5])
    when = datetime(day.year, day.month, day.day, tzinfo=timezone.utc) + _clock(path, line, f[1])
    return _Row(line, lat, lon, when)


def decode_ais(payload: str, fill: int = 0) -> dict | None:
    """The position report in a 6-bit AIS payload (types 1, 2, 3 and 18; ITU-R M.1371-5,
    Annex 8): ``{"type", "mmsi", "lat", "lon", "speed" (knots), "course" (degrees), "second"}``,
    a field None where the report says it is not available; None for any other type.

    Raises
    ------
    ValueError
        A character outside the 6-bit alphabet or a payload too short for its type.
    """
    bits = 0
    for char in payload:
        value = ord(char) - 48
        if value > 40:
            value -= 8
        if not 0 <= value < 64 or 39 < ord(char) - 48 < 48:
            raise ValueError(f"character {char!r} is not in the AIS 6-bit alphabet")
        bits = (bits << 6) | value
    length = 6 * len(payload) - fill
    bits >>= fill

    def field(start: int, width: int, signed: bool = False) -> int:
        if start + width > length:
            raise ValueError(f"{length} bits, too short for its type")
        value = (bits >> (length - start - width)) & ((1 << width) - 1)
        return value - (1 << width) if signed and value >> (width - 1) else value

    kind = field(0, 6)
    if kind in (1, 2, 3):
        sog, lon, lat, cog, second = field(50, 10), field(61, 28, True), field(89, 27, True), field(116, 12), field(137, 6)
    elif kind == 18:
        sog, lon, lat, cog, second = field(46, 10), field(57, 28, True), field(85, 27, True), field(112, 12), field(133, 6)
    else:
        return None
    return {
        "type": kind, "mmsi": field(8, 30),
        "lon": None if lon == 181 * 600000 else lon / 600000.0,  # 1/10000 minute; 181 deg: not available
        "lat": None if lat == 91 * 600000 else lat / 600000.0,
        "speed": None if sog == 1023 else sog / 10.0,  # 0.1 knot; 1023: not available
        "course": None if cog == 3600 else cog / 10.0,  # 0.1 degree; 3600: not available
        "second": second if second < 60 else None,  # 60-63: not available, manual, dead reckoning, inoperative
    }


def _ais_row(path: Path, line: int, f: list[str], received: float | None) -> tuple[int, _Row] | None:
    """``!xxVDM,count,number,id,channel,payload,fill``: a one-part position report as
    ``(mmsi, row)``; None for other types, other parts, and reports without a position."""
    if len(f) < 7:
        raise BananagridError(f"{path}: line {line}: AIS sentence with {len(f) - 1} fields; expected 6")
    if f[1] != "1":
        return None  # a multi-part message: no position report is one
    try:
        report = decode_ais(f[5], int(f[6] or 0))
    except ValueError as exc:
        raise BananagridError(f"{path}: line {line}: AIS payload: {exc}") from None
    if report is None or report["lat"] is None or report["lon"] is None:
        return None
    if received is None:
        raise BananagridError(
            f"{path}: line {line}: an AIS report carries only the second of the minute; the file needs the receive "
            "time, in a tag block (\\c:UNIX*hh\\) or a trailing ,UNIX field after the checksum"
        )
    moment = math.floor(received)
    if report["second"] is not None:  # the report's own second, at or before its reception
        moment -= (int(moment) % 60 - report["second"]) % 60
    when = datetime(1970, 1, 1, tzinfo=timezone.utc) + timedelta(seconds=moment)
    row = _Row(line, report["lat"], report["lon"], when)
    _check_position(f"{path}: line {line}", row.lat, row.lon)
    if report["speed"] is not None:
        row.speed = report["speed"] * KNOT
    if report["course"] is not None:
        row.course = math.radians(report["course"])
    return report["mmsi"], row
