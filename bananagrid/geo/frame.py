"""The geographic frame of a scene: local metres about a last fix on the Earth.

Every model works in a plane, x east and y north in metres. A geographic scene anchors that
plane on the WGS84 ellipsoid: its local origin (0, 0) is a latitude and longitude, and the plane
is a map projection of the ellipsoid about it:

* ``"aeqd"`` (the default): the azimuthal equidistant projection centred on the origin.
  Distances and azimuths *from the origin* are true; elsewhere the scale across the radius
  grows as ``(rho / R) / sin(rho / R)``, about ``1 + rho**2 / (6 R**2)`` at a distance ``rho``
  (4e-5 at 100 km, 4e-3 at 1,000 km) (Snyder, *Map Projections: A Working Manual*, 1987,
  eq. (25-2));
* ``"utm"``: the UTM zone of the origin (scale 0.9996 on the central meridian, about 1.0010 at
  its edges), or any projected CRS in metres that pyproj knows (``"EPSG:32632"``, a WKT or
  PROJ string); the local (0, 0) is the origin's projected position (:attr:`GeoFrame.false_origin`).

Grid north and true north differ away from the central meridian (the meridian convergence):
bearings a scene gives are true bearings (clockwise from true north) and are turned into grid
bearings where they are measured (:meth:`GeoFrame.grid_bearing`), exactly, from a geodesic step.
:meth:`GeoFrame.scale_error` states the projection's distortion over a grid, and a scene refuses
a grid where it exceeds the scene's bound.

Any CRS is refused unless it holds the grid: PROJ must transform with it, map the origin, and
take every point of the grid to latitude and longitude and back to within a millimetre
(:meth:`GeoFrame.check_round_trip`, at the grid's corners, edge midpoints and centre, both ways).
A false easting of 1e20 m (float64 cannot tell points 16 km apart there), a UTM zone far from
the origin or a polar projection of the other hemisphere fails that or the scale bound.

UTC times are those of ISO 8601 in Python's calendar, years 1 to 9999: a frame time, and every
elapsed time after it, outside it is refused in one line (:meth:`GeoFrame.check_elapsed`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from functools import cached_property

import numpy as np

from ..validate import BananagridError, show
from .libraries import require

__all__ = ["GeoFrame", "parse_utc", "iso_utc", "DEFAULT_MAX_SCALE_ERROR", "CRS_CHOICES", "WGS84", "FIRST_UTC", "LAST_UTC",
           "MAX_ROUND_TRIP_M"]

#: The largest relative scale error of the projection over a scene's grid, by default (0.1 %).
DEFAULT_MAX_SCALE_ERROR = 1e-3
#: The projections named by a word; anything else is handed to ``pyproj.CRS.from_user_input``.
CRS_CHOICES = ("aeqd", "utm")
#: Latitude and longitude on the WGS84 ellipsoid (degrees), as GeoJSON and GPS give them.
WGS84 = "EPSG:4326"
#: Half the Earth's circumference (m): no plane about a point reaches farther.
HALF_CIRCUMFERENCE_M = 2.0004e7
#: Points per side of the lattice on which the scale error over a grid is evaluated.
SCALE_LATTICE = 17
#: Length of the geodesic step that measures a bearing's grid direction, m: long enough that
#: float64 projected coordinates (~1e7 m, 2e-9 m apart) resolve it to 1e-9 rad, short enough
#: that the geodesic's curvature in the plane is below 1e-12 rad.
BEARING_STEP_M = 1.0


#: The first and the last instant an ISO 8601 time of Python's calendar (years 1 to 9999) holds.
FIRST_UTC = datetime.min.replace(tzinfo=timezone.utc)
LAST_UTC = datetime.max.replace(tzinfo=timezone.utc)
#: The largest error (m) of a CRS's round trip over a grid (local -> latitude and longitude ->
#: local, and back to latitude and longitude) that a frame accepts: a map file's coordinates
#: then place every cell where the model put it, to a millimetre.
MAX_ROUND_TRIP_M = 1e-3
#: How far from the origin (m) :attr:`GeoFrame.portable_wkt` checks that the WKT1 it writes maps
#: points as the frame's CRS does: beyond any grid a scale bound of 1e-3 lets an aeqd hold
#: (a radius of about 500 km), so a parameter WKT1 lost would show.
PORTABLE_CHECK_M = 1e6


def iso_utc(when: datetime) -> str:
    """A UTC time as ISO 8601 with ``Z``, the seconds' fraction only where there is one:
    ``2026-11-24T05:45:00Z``; years below 1000 with four digits (``0001-01-01T00:00:00Z``),
    which ``strftime`` drops on some platforms."""
    plain = when.astimezone(timezone.utc).replace(tzinfo=None)
    return plain.isoformat(timespec="microseconds" if plain.microsecond else "seconds") + "Z"


def parse_utc(value, key: str = "geo.time") -> datetime:
    """An ISO 8601 time with a UTC offset (a string, or a TOML offset date-time), as UTC.

    Raises
    ------
    BananagridError
        A value that does not parse, or a time without an offset (``Z`` or ``+hh:mm``): a local
        time of unknown zone would shift every map by hours.
    """
    if isinstance(value, datetime):
        when = value
    elif isinstance(value, str):
        try:
            when = datetime.fromisoformat(value.strip())
        except ValueError:
            raise BananagridError(
                f"{key} = {show(value)}: not an ISO 8601 time; write e.g. \"2026-11-24T06:00:00Z\""
            ) from None
    else:
        raise BananagridError(f"{key} = {show(value)}: expected an ISO 8601 UTC time such as \"2026-11-24T06:00:00Z\"")
    if when.tzinfo is None or when.utcoffset() is None:
        raise BananagridError(
            f"{key} = {show(value)}: give the UTC offset (\"Z\" for UTC, or e.g. \"+01:00\"); "
            "a time without one could be any zone"
        )
    try:
        return when.astimezone(timezone.utc)
    except OverflowError:  # e.g. 0001-01-01T00:00:00+01:00, an hour before the calendar starts
        raise BananagridError(
            f"{key} = {show(value)}: in UTC it falls outside the calendar; UTC times must lie in "
            f"[{iso_utc(FIRST_UTC)}, {iso_utc(LAST_UTC)}]"
        ) from None


@dataclass(frozen=True, init=False)
class GeoFrame:
    """Local metres (x east, y north) about an origin on the WGS84 ellipsoid.

    Parameters
    ----------
    lat, lon : float
        The origin (the local (0, 0), usually the last fix), degrees; latitude in (-90, 90)
        (a pole has no north), longitude in [-180, 180]. A grid about an origin near a pole
        may hold the pole.
    time : datetime or str, optional
        UTC time of elapsed t = 0 (an ISO 8601 string with its offset, or an aware datetime).
    crs : str, default "aeqd"
        ``"aeqd"``, ``"utm"`` or a projected CRS in metres that pyproj accepts, whose round trip
        at the origin is accurate to a millimetre (a grid's is checked by :meth:`check_extent`
        and by each map file's writer).

    Examples
    --------
    >>> frame = GeoFrame(60.39, 5.32, time="2026-11-24T06:00:00Z")
    >>> lat, lon = frame.geographic(0.0, 1000.0)   # 1 km north of the origin
    """

    lat: float
    lon: float
    time: datetime | None = None
    crs_name: str = "aeqd"

    def __init__(self, lat: float, lon: float, time=None, crs: str = "aeqd"):
        lat, lon = _degrees("lat", lat, 90.0), _degrees("lon", lon, 180.0)
        if abs(lat) == 90.0:
            raise BananagridError(f"lat = {lat:g}: a pole has no north for bearings; give a latitude in (-90, 90)")
        if not isinstance(crs, str) or not crs.strip():
            raise BananagridError(f"crs = {show(crs)}: expected \"aeqd\", \"utm\" or a projected CRS such as \"EPSG:32632\"")
        object.__setattr__(self, "lat", lat)
        object.__setattr__(self, "lon", lon)
        object.__setattr__(self, "time", None if time is None else parse_utc(time, "time"))
        object.__setattr__(self, "crs_name", crs.strip())
        # an unknown or unsuitable CRS is refused here, not at first use: one PROJ cannot
        # transform with, one that cannot place the origin, or one whose round trip there fails
        self.check_round_trip((0.0, 0.0), (0.0, 0.0))

    # --- the projection -----------------------------------------------------------------------

    @cached_property
    def crs(self):
        """The projected CRS of the local plane (a ``pyproj.CRS``)."""
        pyproj = require("pyproj")
        name = self.crs_name
        if name.lower() == "aeqd":
            plain = pyproj.CRS.from_proj4(
                f"+proj=aeqd +lat_0={self.lat!r} +lon_0={self.lon!r} +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs"
            ).to_json_dict()
            # A PROJ string makes a CRS named "unknown"; a GIS shows the name, so give it one.
            plain["name"] = f"Azimuthal equidistant about {_latlon_text(self.lat, self.lon)} (WGS 84)"
            plain["base_crs"]["name"] = "WGS 84"
            return pyproj.CRS.from_json_dict(plain)
        if name.lower() == "utm":
            zone = int((self.lon + 180.0) // 6.0) % 60 + 1
            return pyproj.CRS.from_epsg((32600 if self.lat >= 0.0 else 32700) + zone)
        try:
            crs = pyproj.CRS.from_user_input(name)
        except pyproj.exceptions.CRSError:
            raise BananagridError(
                f"crs = {show(name)}: not a CRS pyproj knows; give \"aeqd\", \"utm\", an EPSG code such as "
                "\"EPSG:32632\", a PROJ string or WKT"
            ) from None
        if not crs.is_projected:
            raise BananagridError(
                f"crs = {show(name)}: {crs.name} is not a projected CRS; the local plane needs one in metres "
                "(e.g. \"utm\" or \"EPSG:32632\")"
            )
        units = {axis.unit_name for axis in crs.axis_info}
        if units != {"metre"}:
            raise BananagridError(f"crs = {show(name)}: {crs.name} has axes in {', '.join(sorted(units))}; expected metres")
        return crs

    @property
    def wkt(self) -> str:
        """The projected CRS as WKT2 (2019), as this pyproj's PROJ writes it: exact, but it may
        name a method an older PROJ does not know (:attr:`portable_wkt` is what files carry)."""
        return self.crs.to_wkt()

    @cached_property
    def portable_wkt(self) -> str:
        """The projected CRS as the map files write it: GDAL's WKT1 (``WKT1_GDAL``), which the
        GDAL and PROJ of every current LTS distribution read, wherever it describes the same
        projection; else WKT2 (2015).

        The WKT2 a recent PROJ writes names each method by its newest EPSG code: PROJ 9.2 and
        later write the azimuthal equidistant as ``METHOD["Azimuthal Equidistant", ID["EPSG",
        1125]]``, which PROJ 9.1 (GDAL 3.6, Debian 12) does not know, so it has no inverse and
        ``gdalwarp`` fails. WKT1 names the projection by GDAL's stable name
        (``PROJECTION["Azimuthal_Equidistant"]``), read since GDAL 1 and PROJ 6; a CRS WKT1
        cannot describe is carried in it as PROJ's own string (``EXTENSION["PROJ4", ...]``).
        "The same projection" is checked, not assumed: pyproj must read the WKT1 back and map
        the origin and points 1,000 km about it to within :data:`MAX_ROUND_TRIP_M` of this
        frame's CRS.
        """
        pyproj = require("pyproj")
        wkt1 = self.crs.to_wkt("WKT1_GDAL")
        if wkt1 and self._same_projection(pyproj, wkt1):
            return wkt1
        return self.crs.to_wkt("WKT2_2015")

    def _same_projection(self, pyproj, wkt: str) -> bool:
        """Whether the CRS ``wkt`` maps the origin and points :data:`PORTABLE_CHECK_M` about it
        (where the projection holds them) as this frame's CRS does, to :data:`MAX_ROUND_TRIP_M`."""
        try:
            other = pyproj.Transformer.from_crs(WGS84, pyproj.CRS.from_wkt(wkt), always_xy=True)
        except pyproj.exceptions.ProjError:
            return False
        reach = np.array([0.0, PORTABLE_CHECK_M, -PORTABLE_CHECK_M])
        x, y = (v.ravel() for v in np.meshgrid(reach, reach))
        e, n = self.projected(x, y)
        with np.errstate(all="ignore"):
            lat, lon = self.geographic(x, y)
            e2, n2 = (np.asarray(v, dtype=float) for v in other.transform(lon, lat))
        held = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(e) & np.isfinite(n)
        return bool(held[0] and np.all(np.hypot(e2 - e, n2 - n)[held] <= MAX_ROUND_TRIP_M))

    @cached_property
    def _forward(self):
        return self._transformer(WGS84, self.crs)

    @cached_property
    def _inverse(self):
        return self._transformer(self.crs, WGS84)

    def _transformer(self, source, target):
        pyproj = require("pyproj")
        try:
            return pyproj.Transformer.from_crs(source, target, always_xy=True)
        except pyproj.exceptions.ProjError as exc:
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise BananagridError(f"crs = {show(self.crs_name)}: PROJ cannot transform with it ({reason})") from None

    @cached_property
    def false_origin(self) -> tuple[float, float]:
        """Projected coordinates (E, N) of the local (0, 0): (0, 0) for ``"aeqd"``."""
        e, n = self._forward.transform(self.lon, self.lat)
        if not (math.isfinite(e) and math.isfinite(n)):
            raise BananagridError(f"crs = {show(self.crs_name)}: the origin lat {self.lat:g}, lon {self.lon:g} is outside it")
        return (float(e), float(n))

    # --- coordinates --------------------------------------------------------------------------

    def projected(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Projected coordinates (E, N) of local points: ``x + E0``, ``y + N0``."""
        e0, n0 = self.false_origin
        return np.asarray(x, dtype=float) + e0, np.asarray(y, dtype=float) + n0

    def geographic(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Latitude and longitude (degrees) of local points (x east, y north, m)."""
        e, n = self.projected(x, y)
        lon, lat = self._inverse.transform(e, n)
        return np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)

    def local(self, lat, lon) -> tuple[np.ndarray, np.ndarray]:
        """Local x east, y north (m) of points given in degrees.

        Raises
        ------
        BananagridError
            A latitude outside [-90, 90] or a longitude outside [-180, 180], or a point the
            projection cannot map.
        """
        lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
        for name, values, limit in (("latitude", lat, 90.0), ("longitude", lon, 180.0)):
            bad = ~(np.abs(values) <= limit)
            if np.any(bad):
                raise BananagridError(f"{name} {float(values[bad].flat[0])!r}: must lie in [-{limit:g}, {limit:g}] degrees")
        e, n = self._forward.transform(lon, lat)
        e0, n0 = self.false_origin
        x, y = np.asarray(e, dtype=float) - e0, np.asarray(n, dtype=float) - n0
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise BananagridError(f"a point lies outside the projection {self.crs_name!r}")
        return x, y

    def grid_bearing(self, bearing: float, x: float, y: float) -> float:
        """The grid direction (rad, clockwise from grid north) of the true bearing ``bearing``
        (rad, clockwise from true north) measured at the local point (x, y).

        The direction of a geodesic step of :data:`BEARING_STEP_M` along the true bearing, in
        the plane: exact to 1e-9 rad in any projection, conformal or not. The difference
        ``grid - true`` is minus the meridian convergence (and, off a conformal projection,
        its angular distortion) at that point.
        """
        lat, lon = self.geographic(x, y)
        lon2, lat2, _ = require("pyproj").Geod(ellps="WGS84").fwd(float(lon), float(lat), math.degrees(bearing),
                                                                  BEARING_STEP_M)
        x2, y2 = self.local(lat2, lon2)
        turned = math.atan2(float(x2) - x, float(y2) - y)
        return bearing + math.remainder(turned - bearing, 2.0 * math.pi)

    def utc(self, t: float) -> datetime | None:
        """The UTC time of elapsed time ``t`` (s), or None without a frame time.

        Raises
        ------
        BananagridError
            A time past the end of the calendar (9999-12-31T23:59:59.999999Z) or before its
            start (:meth:`check_elapsed` says so at a scene's load).
        """
        if self.time is None:
            return None
        try:
            return self.time + timedelta(seconds=float(t))
        except (OverflowError, ValueError):
            raise BananagridError(self._calendar_message(float(t))) from None

    def check_elapsed(self, times) -> None:
        """Refuse elapsed times (s) whose UTC time falls outside the calendar, years 1 to 9999
        (:data:`FIRST_UTC`, :data:`LAST_UTC`); nothing to check without a frame time."""
        if self.time is None:
            return
        for t in times:
            self.utc(t)

    def _calendar_message(self, t: float) -> str:
        return (f"time = {show(iso_utc(self.time))}: t = {t:g} s after it falls outside the calendar; UTC times "
                f"must lie in [{iso_utc(FIRST_UTC)}, {iso_utc(LAST_UTC)}]: give a time that leaves room for every "
                "elapsed time")

    def project_points(self, lat, lon) -> tuple[np.ndarray, np.ndarray]:
        """Local x east, y north (m) of points in degrees, NaN where the projection cannot map
        one (:meth:`local` refuses such points instead)."""
        with np.errstate(invalid="ignore", over="ignore"):
            e, n = self._forward.transform(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float))
            e0, n0 = self.false_origin
            x, y = np.asarray(e, dtype=float) - e0, np.asarray(n, dtype=float) - n0
        bad = ~(np.isfinite(x) & np.isfinite(y))
        return np.where(bad, np.nan, x), np.where(bad, np.nan, y)

    # --- accuracy -----------------------------------------------------------------------------

    def round_trip_error(self, x_bounds, y_bounds) -> tuple[float, float, float]:
        """How far the projection's round trip moves a point of a rectangle of local metres:
        ``(error, x, y)``, the largest error (m) and the local point where it occurs.

        At the rectangle's corners, the midpoints of its edges and its centre, a local point
        ``P`` is taken to latitude and longitude ``G`` (inverse) and back to ``P'`` (forward),
        and ``P'`` to ``G'`` (inverse again); the error is the larger of ``|P' - P|`` in the
        plane and the geodesic distance from ``G`` to ``G'`` on the ellipsoid. A projection
        that cannot hold the rectangle (a point outside its domain, coordinates so large that
        float64 cannot tell the cells apart, a false easting of 1e20 m) has a large or
        infinite error.
        """
        x0, x1 = map(float, x_bounds)
        y0, y1 = map(float, y_bounds)
        gx, gy = np.meshgrid([x0, 0.5 * (x0 + x1), x1], [y0, 0.5 * (y0 + y1), y1])
        x, y = gx.ravel(), gy.ravel()
        with np.errstate(all="ignore"):
            e0, n0 = self.false_origin
            lon, lat = self._inverse.transform(x + e0, y + n0)
            e, n = self._forward.transform(lon, lat)
            x2, y2 = np.asarray(e, dtype=float) - e0, np.asarray(n, dtype=float) - n0
            lon2, lat2 = self._inverse.transform(x2 + e0, y2 + n0)
            lon, lat, lon2, lat2 = (np.asarray(v, dtype=float) for v in (lon, lat, lon2, lat2))
            plane = np.hypot(x2 - x, y2 - y)
        finite = (np.isfinite(plane) & np.isfinite(lon) & np.isfinite(lat) & np.isfinite(lon2) & np.isfinite(lat2)
                  & (np.abs(lat) <= 90.0) & (np.abs(lat2) <= 90.0))
        errors = np.full(x.shape, math.inf)
        if np.any(finite):
            ground = require("pyproj").Geod(ellps="WGS84").inv(lon[finite], lat[finite], lon2[finite], lat2[finite])[2]
            errors[finite] = np.maximum(plane[finite], np.asarray(ground, dtype=float))
        errors[~np.isfinite(errors)] = math.inf
        worst = int(np.argmax(errors))
        return float(errors[worst]), float(x[worst]), float(y[worst])

    def check_round_trip(self, x_bounds, y_bounds, limit: float = MAX_ROUND_TRIP_M) -> float:
        """:meth:`round_trip_error` over the rectangle, refused above ``limit`` (m, default
        :data:`MAX_ROUND_TRIP_M`); returns it."""
        self.false_origin  # noqa: B018 -- an origin outside the projection is its own message
        error, x, y = self.round_trip_error(x_bounds, y_bounds)
        if not error <= limit:
            origin = x_bounds[0] == x_bounds[1] and y_bounds[0] == y_bounds[1]
            where = "at the origin" if origin else (
                f"over the grid x = [{x_bounds[0]:g}, {x_bounds[1]:g}] m, y = [{y_bounds[0]:g}, {y_bounds[1]:g}] m")
            raise BananagridError(
                f"crs = {show(self.crs_name)}: its round trip {where} (local metres to latitude and longitude and "
                f"back) is off by {error:.3g} m at x = {x:g} m, y = {y:g} m, above {limit * 1e3:g} mm: the "
                f"projection does not hold the {'origin' if origin else 'grid'}; use a CRS whose domain holds it"
                + ("" if self.crs_name.lower() == "aeqd" else " (\"aeqd\" about the origin)")
            )
        return error

    def scale_error(self, x_bounds, y_bounds) -> float:
        """The largest relative scale error ``|k - 1|`` of the projection over a rectangle of
        local metres: a distance measured in the plane is within this fraction of the true
        geodesic distance.

        ``k`` runs over the principal scales (the semi-axes of Tissot's indicatrix, pyproj's
        ``get_factors``). They are evaluated on a 17 x 17 lattice that includes the corners
        (where azimuthal projections are worst), and the worst lattice point is then refined by
        a bounded search, which finds an extreme between lattice lines (UTM's least scale lies
        on its central meridian, wherever that crosses the grid).
        """
        x0, x1 = map(float, x_bounds)
        y0, y1 = map(float, y_bounds)
        if not max(abs(x0), abs(x1), abs(y0), abs(y1)) <= HALF_CIRCUMFERENCE_M:
            return math.inf  # the rectangle reaches round the Earth: no projection holds it
        gx, gy = np.meshgrid(np.linspace(x0, x1, SCALE_LATTICE), np.linspace(y0, y1, SCALE_LATTICE))
        errors = self._scale_errors(gx.ravel(), gy.ravel())
        if not np.all(np.isfinite(errors)):
            return math.inf
        worst = int(np.argmax(errors))
        start = np.array([gx.ravel()[worst], gy.ravel()[worst]])
        found = require("scipy.optimize").minimize(
            lambda p: -float(self._scale_errors(np.array([p[0]]), np.array([p[1]]))[0]), start,
            method="Nelder-Mead", bounds=[(x0, x1), (y0, y1)],
            options={"xatol": 1e-3 * max(x1 - x0, y1 - y0, 1.0), "fatol": 1e-12},
        )
        return float(max(errors[worst], -found.fun))

    def _scale_errors(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``max(|a - 1|, |b - 1|)`` of the principal scales a >= b at each local point."""
        lat, lon = self.geographic(x, y)
        factors = require("pyproj").Proj(self.crs).get_factors(np.atleast_1d(lon), np.atleast_1d(lat))
        a, b = np.asarray(factors.tissot_semimajor), np.asarray(factors.tissot_semiminor)
        return np.maximum(np.abs(a - 1.0), np.abs(b - 1.0))

    def check_extent(self, x_bounds, y_bounds, limit: float = DEFAULT_MAX_SCALE_ERROR, *,
                     key: str = "grid") -> float:
        """:meth:`scale_error` over the rectangle, refused above ``limit``; returns it. The
        projection's round trip over it is checked first (:meth:`check_round_trip`), unless the
        rectangle reaches round the Earth (then no projection holds it: the grid is at fault)."""
        if max(map(abs, (*x_bounds, *y_bounds))) <= HALF_CIRCUMFERENCE_M:
            self.check_round_trip(x_bounds, y_bounds)
        error = self.scale_error(x_bounds, y_bounds)
        if not error <= limit:
            raise BananagridError(
                f"{key} x = [{x_bounds[0]:g}, {x_bounds[1]:g}] m, y = [{y_bounds[0]:g}, {y_bounds[1]:g}] m: "
                f"the scale error of its projection, geo.crs = {show(self.crs_name)}, reaches {error:.3g} over it, "
                f"above the bound {limit:g} (geo.max_scale_error); use a smaller grid, a CRS suited to it, or a larger bound"
            )
        return error

    def identity(self) -> dict:
        """What rebuilds the frame (``GeoFrame.from_identity``): ``lat``, ``lon``, ``time``
        (ISO 8601 UTC or ""), ``crs`` (as given). Plain values, for provenance and recordings."""
        return {"lat": self.lat, "lon": self.lon, "time": self.describe()["time"] or "", "crs": self.crs_name}

    @classmethod
    def from_identity(cls, values: dict) -> "GeoFrame":
        """The frame :meth:`identity` describes."""
        return cls(values["lat"], values["lon"], time=values.get("time") or None, crs=values.get("crs", "aeqd"))

    def describe(self) -> dict:
        """The frame for provenance and file metadata."""
        return {
            "lat": self.lat, "lon": self.lon,
            "time": None if self.time is None else iso_utc(self.time),
            "crs_name": self.crs_name, "crs": self.crs.name, "false_origin": list(self.false_origin),
        }

    def __repr__(self) -> str:
        when = "" if self.time is None else f", time {self.describe()['time']}"
        return f"GeoFrame(lat {self.lat:.6f}, lon {self.lon:.6f}{when}, crs {self.crs_name})"


def _latlon_text(lat: float, lon: float) -> str:
    """``60.45 N 4.6 E``: degrees with hemispheres, as many decimals as given (up to 7)."""
    return (f"{_trimmed(abs(lat))} {'N' if lat >= 0 else 'S'} "
            f"{_trimmed(abs(lon))} {'E' if lon >= 0 else 'W'}")


def _trimmed(value: float) -> str:
    return f"{value:.7f}".rstrip("0").rstrip(".")


def _degrees(name: str, value, limit: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise BananagridError(f"{name} = {show(value)}: expected a number of degrees in [-{limit:g}, {limit:g}]")
    value = float(value)
    if not -limit <= value <= limit:
        raise BananagridError(f"{name} = {value!r}: must lie in [-{limit:g}, {limit:g}] degrees")
    return value
