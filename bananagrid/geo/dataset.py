"""Results as CF-1.10 xarray Datasets, and CF NetCDF files.

:func:`raster_dataset` puts a scene's maps (its layers at its elapsed times, all on one grid)
into one :class:`xarray.Dataset` that follows the CF conventions 1.10, so that xarray, ncdump,
Panoply, QGIS and GDAL read it without help:

* ``x``, ``y``: the projected coordinates of the cell centres, m (``projection_x_coordinate``,
  ``projection_y_coordinate``; local metres about the origin when there is no frame), with
  ``x_bounds``, ``y_bounds`` holding the cell edges;
* with a :class:`~bananagrid.geo.frame.GeoFrame`: ``lat``, ``lon`` (y, x), the latitude and
  longitude of every cell centre, and ``crs``, the grid mapping (pyproj's CF attributes, and as
  ``crs_wkt`` and ``spatial_ref`` the WKT that GDAL 3.6 / PROJ 9.1 and later read:
  :attr:`GeoFrame.portable_wkt <bananagrid.geo.frame.GeoFrame.portable_wkt>`);
* ``time``: with a frame time, the UTC times (decoded to datetime64 in memory, written as
  ``seconds since`` the frame time), with the auxiliary coordinate ``elapsed`` (s since the
  fix); without one, the time dimension is ``elapsed`` itself (units ``s``: CF keeps a
  coordinate named ``time`` for ``seconds since`` a date). Any time of years 1 to 9999: held
  as datetime64[ns] within its range (1677 to 2262), as datetime64[us] beyond it; the calendar
  is CF's ``standard``, or ``proleptic_gregorian`` for a time before 1582-10-15 (where
  ``standard`` is Julian, and ISO 8601 is not);
* one variable per layer, named for the layer: the density per m^2 at each cell centre,
  dims (time, y, x), with ``LAYER_mass`` (the probability mass the grid captured before any
  normalisation, per time) and ``LAYER_normalised`` (a 0/1 flag per time); the provenance of
  each time as JSON in the attribute ``bananagrid_provenance``;
* where cell probabilities are given (a scene's ``output.cell_probabilities``):
  ``LAYER_probability``, dims as the layer's, the probability that the target is in each cell
  (the probability of containment, POC, of search planning: units ``1``, ``cell_methods =
  "area: sum"``, the layer named in ``bananagrid_cells_of``), as computed, to the bit.

Layers at different times: when every layer has the same elapsed times they share the
dimension ``time``; otherwise each layer has its own time dimension and coordinates,
``time_LAYER`` (and ``elapsed_LAYER``), so that no layer is padded with maps it does not have.
Both layouts are plain CF (a variable's time coordinate is the one on its own dimension).

:func:`polar_dataset` and :func:`cell_map_dataset` do the same, smaller, for a polar lattice and
an angular cell lattice; :func:`write_netcdf` writes any of them (netCDF4 engine, zlib
compression of the data variables) to a temporary name and renames it when complete, and
:func:`read_maps` reads a scene's maps back from such a file (``bananagrid plot FILE.nc``).

xarray, netCDF4 and pyproj are the ``geo`` extra, loaded when first used. Results are taken
duck-typed (this package sits below :mod:`bananagrid.results`, whose ``to_xarray`` methods call
these functions).
"""

from __future__ import annotations

import hashlib
import json
import os
from datetime import datetime, timezone
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..validate import BananagridError, checked_in_child, regular_file
from ..version import __version__
from .files import writing
from .frame import iso_utc
from .libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from .panels import check_cells, check_panels, frame_of, provenance_json, variable_name

__all__ = [
    "CONVENTIONS", "DENSITY_UNITS", "ELAPSED_LONG_NAME", "NETCDF_PURPOSE", "raster_dataset", "polar_dataset",
    "cell_map_dataset", "write_netcdf", "COVERAGE_VARIABLE", "time_units", "read_maps", "check_netcdf", "netcdf_digest", "DIGEST_ATTRIBUTE",
    "layer_variables",
]

CONVENTIONS = "CF-1.10"
#: Density per square metre (UDUNITS).
DENSITY_UNITS = "m-2"
ELAPSED_LONG_NAME = "elapsed time since the fix"
#: What the libraries of this module are needed for, in the message when one is missing.
NETCDF_PURPOSE = "NetCDF and xarray export"
#: zlib level of the data variables in a NetCDF file (4: most of level 9's gain, much faster).
ZLIB_LEVEL = 4
#: Names of the coordinates and grid mapping: a layer may not take one of them.
RESERVED_NAMES = frozenset({"x", "y", "x_bounds", "y_bounds", "lat", "lon", "crs", "time", "elapsed"})
CELL_UNITS = {"line": "m", "plane": "m2", "frustum": "m3"}
#: The first and last whole seconds datetime64[ns] holds (numpy: 1677-09-21T00:12:43.145 to
#: 2262-04-11T23:47:16.854, 2**63 ns either side of 1970).
NS_FIRST = datetime(1677, 9, 21, 0, 12, 44, tzinfo=timezone.utc)
NS_LAST = datetime(2262, 4, 11, 23, 47, 16, tzinfo=timezone.utc)
#: The first day of the Gregorian calendar; CF's "standard" calendar is Julian before it.
GREGORIAN_START = datetime(1582, 10, 15, tzinfo=timezone.utc)


def time_units(frame) -> str:
    """The CF units of the time coordinate of a frame with a time: ``seconds since`` its UTC
    time in ISO 8601 (``2026-11-24T06:00:00Z``), which UDUNITS, cftime and pandas all read."""
    return f"seconds since {iso_utc(frame.time)}"


def raster_dataset(panels: Sequence, frame=None, *, title: str = "", source: str = "", cells=None, coverage=None,
                   posteriors=None):
    """A scene's maps as one CF-1.10 :class:`xarray.Dataset`.

    Parameters
    ----------
    panels : sequence of (str, float, Raster)
        ``(layer_name, t, raster)``: each layer's density at elapsed time ``t`` (s), all on one
        grid. A layer name that is not a NetCDF name (letters, digits, ``_``, starting with a
        letter) has its other characters replaced by ``_``; the name as given is kept in the
        variable's ``bananagrid_layer`` attribute.
    frame : GeoFrame, optional
        Where the grid lies on the Earth; default the rasters' own ``frame``. Without one the
        coordinates are local metres and there is no CRS, latitude, longitude or UTC time.
    title, source : str
        The global ``title`` and ``source`` attributes (``source`` defaults to
        ``"bananagrid VERSION"``).
    cells : mapping of (str, float) to Raster, optional
        Cell probabilities (rasters of ``quantity == "probability"``) by ``(layer_name, t)``, for
        every time of the layers that have them (:func:`~bananagrid.geo.panels.check_cells`):
        each such layer gets ``LAYER_probability`` beside its density.
    coverage : (str, float, Raster), optional
        ``(layer_name, t, effort)``: a search plan's coverage on the same grid (m^2 swept per
        m^2, ``bg.allocate(...).effort``), written as the variable :data:`COVERAGE_VARIABLE`; or
        a list of ``(layer_name, t, effort, attributes)``, a plan over several periods' coverage
        of each period, written as ``plan_coverage_1``, ``plan_coverage_2``, ... with the
        attributes (the period, its POS, the plan's).
    posteriors : mapping of (str, float) to Posterior, optional
        ``bg.posterior`` results by ``(layer_name, t)``, at every time of the layers that have
        them (as ``cells``): each such layer gets ``LAYER_posterior`` (the posterior cell
        probabilities, units 1) and ``LAYER_pod`` (the cumulative POD of each cell) beside its
        density, ``LAYER_pos`` (the searches' POS at each time) and ``LAYER_search_pos`` (each
        search's own POS, on the dimension ``search`` of the searches' names; NaN before a
        search began), with the evidence described in the attribute ``bananagrid_evidence``.

    Returns
    -------
    xarray.Dataset
        See the module's description for its variables.

    Raises
    ------
    BananagridError
        Bad panels (:func:`~bananagrid.geo.panels.check_panels`), a layer whose variable name
        clashes with a coordinate or another layer, a frame whose CRS's round trip over the
        grid is off by more than 1 mm (:meth:`GeoFrame.check_round_trip`; its coordinates would
        misplace the cells), a UTC time outside the calendar, or xarray or pyproj missing.
    """
    xr = require("xarray", NETCDF_PURPOSE)
    checked = check_panels(panels)
    probabilities = check_cells(cells, checked)
    found = check_cells(posteriors, checked, "posteriors")
    frame = frame_of(checked, frame)
    grid = checked[0].raster.grid
    layers: dict[str, list] = {}
    for panel in checked:
        layers.setdefault(panel.layer, []).append(panel)
    for series in layers.values():
        series.sort(key=lambda p: p.t)
    taken = set(RESERVED_NAMES)
    names = {}
    for layer in layers:
        names[layer] = variable_name(layer, taken)
        taken.add(names[layer])
    shared = len({tuple(p.t for p in series) for series in layers.values()}) == 1

    coords, data_vars = _grid_variables(grid, frame, _chunks(checked))
    for layer, series in layers.items():
        var = names[layer]
        derived = {"mass": f"{var}_mass", "normalised": f"{var}_normalised"}
        if (layer, series[0].t) in probabilities:
            derived["probability"] = f"{var}_probability"
        if (layer, series[0].t) in found:
            derived.update(posterior=f"{var}_posterior", pod=f"{var}_pod", pos=f"{var}_pos",
                           search_pos=f"{var}_search_pos")
        if not shared:
            derived.update(time=f"time_{var}", elapsed=f"elapsed_{var}")
        for name in derived.values():
            variable_name(name, taken)  # refuses a clash (derived names are valid NetCDF names)
            taken.add(name)
        tdim, elapsed = ("time", "elapsed") if shared else (derived["time"], derived["elapsed"])
        if frame is None or frame.time is None:  # CF: a "time" needs "seconds since" a date
            tdim = elapsed
        if tdim not in coords:
            coords.update(_time_variables(tdim, elapsed, [p.t for p in series], frame))
        data_vars[var] = _layer_variable(xr, layer, series, tdim, elapsed, frame)
        if "probability" in derived:
            data_vars[derived["probability"]] = _probability_variable(
                xr, layer, [probabilities[layer, p.t] for p in series], data_vars[var])
        if "posterior" in derived:
            data_vars.update(_posterior_variables(xr, layer, [found[layer, p.t] for p in series], data_vars[var],
                                                  derived, tdim, coords, _search_names(found.values())))
        data_vars[derived["mass"]] = xr.Variable(
            (tdim,), _stack([getattr(p.raster, "lazy_mass", None) if _lazy(p.raster.values) else float(p.raster.mass)
                             for p in series]),
            {"long_name": f"probability mass the grid captured before normalisation: layer {layer}", "units": "1"},
        )
        data_vars[derived["normalised"]] = xr.Variable(
            (tdim,), np.array([bool(getattr(p.raster, "normalised", False)) for p in series], dtype=np.int8),
            {"long_name": f"whether the density of layer {layer} was divided by its captured mass",
             "flag_values": np.array([0, 1], dtype=np.int8), "flag_meanings": "raw normalised"},
        )
    if isinstance(coverage, list):  # a plan over several periods: one variable per period
        for k, item in enumerate(coverage):
            data_vars[variable_name(f"{COVERAGE_VARIABLE}_{k + 1}", taken)] = _coverage_variable(xr, *item[:3], grid,
                                                                                                frame, *item[3:])
    elif coverage is not None:
        data_vars[variable_name(COVERAGE_VARIABLE, taken)] = _coverage_variable(xr, *coverage, grid, frame)
    attrs = _global_attrs(title, source, frame)
    attrs["bananagrid_grid"] = json.dumps(grid.describe())
    attrs["comment"] = (
        "Each layer variable holds the probability density of the target's position per square metre at the "
        "cell centres (not a cell probability: multiply by the cell area for that). "
        + ("Layers share the time dimension." if shared else "Each layer has its own time dimension (their times differ).")
    )
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def layer_variables(dataset) -> dict:
    """``{layer: variable name}`` of the layers' density variables of a dataset of
    :func:`raster_dataset` (or a file or store of it): those with a ``bananagrid_layer`` in
    units of density (a posterior's, POD's and POS's variables name their layer too)."""
    return {var.attrs["bananagrid_layer"]: name for name, var in dataset.data_vars.items()
            if "bananagrid_layer" in var.attrs and var.attrs.get("units") == DENSITY_UNITS}


def _search_names(posts) -> list[str]:
    """The searches of every posterior, each once, in the order they are first taken: the
    dimension ``search`` (layers at different times may have taken different searches)."""
    searches: list[str] = []
    for p in posts:
        for name in p.provenance.get("search_names", []):
            if name not in searches:
                searches.append(name)
    return searches


def _posterior_variables(xr, layer: str, posts: list, density, names: dict, tdim: str, coords: dict,
                         searches: list[str]) -> dict:
    """A layer's posterior, POD, POS and each search's POS beside its density variable
    ``density`` (the same dimensions, coordinates and grid mapping), the values as computed;
    ``searches``: the dimension ``search`` (:func:`_search_names` of every layer's posteriors)."""
    common = {"units": "1", "bananagrid_layer": layer}
    if "grid_mapping" in density.attrs:
        common["grid_mapping"] = density.attrs["grid_mapping"]
    encoding = {k: v for k, v in density.encoding.items() if k == "coordinates"}
    evidence = [p.provenance.get("posterior", {}) for p in posts]
    table = np.full((len(posts), len(searches)), np.nan)
    for i, p in enumerate(posts):
        for name, pos in zip(p.provenance.get("search_names", []), p.search_pos):
            table[i, searches.index(name)] = pos
    if "search" not in coords:
        coords["search"] = xr.Variable(("search",), np.array(searches, dtype=object),
                                       {"long_name": "name of the search (the scene's [[evidence]] name)"})
    return {
        names["posterior"]: xr.Variable(density.dims, _stack([p.values for p in posts]), {
            **common, "long_name": f"probability that the target is in the cell after the evidence (posterior POC): "
                                   f"layer {layer}", "cell_methods": "area: sum",
            "bananagrid_evidence": json.dumps(evidence, default=str)}, encoding=encoding),
        names["pod"]: xr.Variable(density.dims, _stack([p.pod for p in posts]), {
            **common, "long_name": f"cumulative probability that the searches would have detected a target in the "
                                   f"cell (POD): layer {layer}", "cell_methods": "area: mean"}, encoding=encoding),
        names["pos"]: xr.Variable((tdim,), np.array([p.pos for p in posts]), {
            **common, "long_name": f"probability that the searches together would have found the target (POS): "
                                   f"layer {layer}"}),
        names["search_pos"]: xr.Variable((tdim, "search"), table, {
            **common, "long_name": f"each search's own probability of success (POS), NaN before it began: "
                                   f"layer {layer}"}),
    }


#: The NetCDF variable of a search plan's coverage (:func:`raster_dataset`'s ``coverage``).
COVERAGE_VARIABLE = "plan_coverage"


def _coverage_variable(xr, layer: str, t: float, effort, grid, frame, extra: dict | None = None):
    """A plan's coverage on the layers' grid, (y, x), m^2 swept per m^2 (``extra``: further
    attributes, a period's of a plan over several)."""
    if effort.grid.shape != grid.shape or not (np.array_equal(effort.grid.x, grid.x) and np.array_equal(effort.grid.y, grid.y)):
        raise BananagridError("coverage: the plan's grid differs from the layers' grid")
    attrs = {"long_name": f"search effort per unit area of the plan (coverage): layer {layer} at t = {t:g} s",
             "units": "m2 m-2", "cell_methods": "area: mean", "bananagrid_layer": layer, "bananagrid_t": float(t),
             "bananagrid_provenance": provenance_json(effort.provenance), **(extra or {})}
    encoding = {}
    if frame is not None:
        attrs["grid_mapping"] = "crs"
        encoding["coordinates"] = "lat lon"
    return xr.Variable(("y", "x"), np.asarray(effort.values, dtype=np.float64), attrs, encoding=encoding)


def _lazy(values) -> bool:
    """Whether ``values`` are a lazy Dask array (a tiled raster's)."""
    return hasattr(values, "__dask_graph__")


def _stack(items: list):
    """The items stacked on a new first axis: a lazy Dask array if any is lazy (NumPy hands
    ``np.stack`` of Dask arrays to Dask), else a NumPy array."""
    if any(_lazy(item) for item in items):
        return np.stack(items)
    return np.stack([np.asarray(item) for item in items])


def _chunks(panels) -> tuple | None:
    """The block shape of the first lazy panel's values, or None when all are in memory."""
    for panel in panels:
        if _lazy(panel.raster.values):
            return tuple(int(c[0]) for c in panel.raster.values.chunks)
    return None


def _grid_variables(grid, frame, chunks: tuple | None = None) -> tuple[dict, dict]:
    """The coordinates and grid mapping; with ``chunks`` (tiled maps) the latitude and
    longitude are lazy Dask arrays in those blocks, so that no array of the grid's size is held."""
    xr = require("xarray", NETCDF_PURPOSE)
    if frame is not None:  # coordinates that place every cell where the model put it, to a millimetre
        x0, x1, y0, y1 = grid.extent
        frame.check_round_trip((x0, x1), (y0, y1))
    e0, n0 = (0.0, 0.0) if frame is None else frame.false_origin
    x_edges = e0 + grid.origin[0] + grid.dx * np.arange(grid.nx + 1)
    y_edges = n0 + grid.origin[1] + grid.dy * np.arange(grid.ny + 1)
    where = "easting" if frame is not None else "x east of the local origin"
    coords = {
        "x": xr.Variable(("x",), e0 + grid.x, {
            "standard_name": "projection_x_coordinate", "long_name": f"{where} of the cell centre",
            "units": "m", "axis": "X", "bounds": "x_bounds"}),
        "y": xr.Variable(("y",), n0 + grid.y, {
            "standard_name": "projection_y_coordinate",
            "long_name": ("northing" if frame is not None else "y north of the local origin") + " of the cell centre",
            "units": "m", "axis": "Y", "bounds": "y_bounds"}),
    }
    data_vars = {
        "x_bounds": xr.Variable(("x", "nv"), np.stack([x_edges[:-1], x_edges[1:]], axis=1)),
        "y_bounds": xr.Variable(("y", "nv"), np.stack([y_edges[:-1], y_edges[1:]], axis=1)),
    }
    if frame is not None:
        if chunks is None:
            coords.update(_lat_lon(xr, ("y", "x"), frame, *np.meshgrid(grid.x, grid.y)))
        else:
            coords.update(_lazy_lat_lon(xr, frame, grid, chunks))
        data_vars["crs"] = xr.Variable((), np.int32(0), _crs_attrs(frame))
    return coords, data_vars


def _lat_lon(xr, dims: tuple, frame, x, y) -> dict:
    """CF ``lat`` and ``lon`` auxiliary coordinates on ``dims`` of the local points (x, y)
    (with ``frame`` None, ``x`` and ``y`` are the latitudes and longitudes already)."""
    lat, lon = (x, y) if frame is None else frame.geographic(x, y)
    return {
        "lat": xr.Variable(dims, lat, {
            "standard_name": "latitude", "long_name": "latitude of the cell centre (WGS84)", "units": "degrees_north"}),
        "lon": xr.Variable(dims, lon, {
            "standard_name": "longitude", "long_name": "longitude of the cell centre (WGS84)", "units": "degrees_east"}),
    }


def _lazy_lat_lon(xr, frame, grid, chunks: tuple) -> dict:
    """:func:`_lat_lon` of every cell centre as Dask arrays in blocks of ``chunks``."""
    da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    x, y = da.meshgrid(da.from_array(grid.x, chunks=chunks[1]), da.from_array(grid.y, chunks=chunks[0]))
    lat = da.map_blocks(_latitudes, x, y, frame, dtype=np.float64)
    lon = da.map_blocks(_longitudes, x, y, frame, dtype=np.float64)
    return _lat_lon(xr, ("y", "x"), None, lat, lon)


def _latitudes(x, y, frame) -> np.ndarray:
    return frame.geographic(x, y)[0]


def _longitudes(x, y, frame) -> np.ndarray:
    return frame.geographic(x, y)[1]


def _crs_attrs(frame) -> dict:
    attrs = {}
    for key, value in frame.crs.to_cf().items():
        if isinstance(value, (str, int, float, np.number)):
            attrs[key] = value
        elif isinstance(value, (list, tuple)) and value and all(isinstance(v, (int, float)) for v in value):
            attrs[key] = np.asarray(value, dtype=float)
    # WKT that the GDAL and PROJ of current LTS distributions read (GeoFrame.portable_wkt): the
    # WKT2 of a newer PROJ may name a method they do not know, and gdalwarp then fails
    attrs["crs_wkt"] = frame.portable_wkt
    attrs["spatial_ref"] = frame.portable_wkt  # the name GDAL (and so QGIS) reads first
    attrs["long_name"] = f"coordinate reference system of x and y ({frame.crs_name})"
    return attrs


def _time_variables(tdim: str, elapsed: str, times: list[float], frame) -> dict:
    xr = require("xarray", NETCDF_PURPOSE)
    seconds = np.asarray(times, dtype=float)
    elapsed_attrs = {"long_name": ELAPSED_LONG_NAME, "units": "s"}
    if frame is None or frame.time is None:
        return {tdim: xr.Variable((tdim,), seconds, elapsed_attrs)}
    instants = [frame.utc(t) for t in seconds]  # refuses a time outside the calendar, years 1 to 9999
    # datetime64[ns] holds 1677-09-21 to 2262-04-11 and wraps round silently beyond: other
    # times are held to the microsecond (as Python's datetime holds them)
    unit, per_second = ("ns", 1e9) if all(NS_FIRST <= u <= NS_LAST for u in instants) else ("us", 1e6)
    start = np.datetime64(frame.time.replace(tzinfo=None), unit)
    utc = start + np.round(seconds * per_second).astype(f"timedelta64[{unit}]")
    # ISO 8601 counts days in the proleptic Gregorian calendar; CF's "standard" calendar is
    # Julian before 1582-10-15, so a time before that date is written with the calendar it is in
    calendar = "standard" if min(instants) >= GREGORIAN_START else "proleptic_gregorian"
    time = xr.Variable((tdim,), utc, {"standard_name": "time", "long_name": "UTC time", "axis": "T"},
                       encoding={"units": time_units(frame), "calendar": calendar, "dtype": "float64"})
    return {tdim: time, elapsed: xr.Variable((tdim,), seconds, elapsed_attrs)}


def _layer_variable(xr, layer: str, series: list, tdim: str, elapsed: str, frame):
    values = _stack([p.raster.values for p in series])
    models = sorted({str(p.raster.provenance.get("model", "?")) for p in series})
    attrs = {
        "long_name": f"probability density of the target's position at the cell centre: layer {layer}",
        "units": DENSITY_UNITS,
        "cell_methods": "area: point",
        "bananagrid_layer": layer,
        "model": ", ".join(models),
        "bananagrid_provenance": "[" + ", ".join(provenance_json(p.raster.provenance) for p in series) + "]",
    }
    coordinates = [elapsed] if frame is not None and frame.time is not None else []
    encoding = {}
    if frame is not None:
        attrs["grid_mapping"] = "crs"
        coordinates += ["lat", "lon"]
    if coordinates:
        encoding["coordinates"] = " ".join(coordinates)
    return xr.Variable((tdim, "y", "x"), values, attrs, encoding=encoding)


def _probability_variable(xr, layer: str, cells: list, density):
    """A layer's cell probabilities (probability of containment, POC) beside its density
    variable ``density``: the same dimensions, coordinates and grid mapping, the values as
    computed (so that they equal the .npz's to the bit)."""
    attrs = {
        "long_name": (f"probability that the target is in the cell (probability of containment, POC): layer {layer}; "
                      "the density integrated over the cell, not sampled at its centre"),
        "units": "1",
        "cell_methods": "area: sum",
        "bananagrid_cells_of": layer,
        "bananagrid_provenance": "[" + ", ".join(provenance_json(c.provenance) for c in cells) + "]",
    }
    if "grid_mapping" in density.attrs:
        attrs["grid_mapping"] = density.attrs["grid_mapping"]
    encoding = {k: v for k, v in density.encoding.items() if k == "coordinates"}
    return xr.Variable(density.dims, _stack([c.values for c in cells]), attrs, encoding=encoding)


def _global_attrs(title: str, source: str, frame) -> dict:
    attrs = {
        "Conventions": CONVENTIONS,
        "title": str(title),
        "source": str(source) or f"bananagrid {__version__}",
        "history": f"created by bananagrid {__version__}",
        "institution": f"bananagrid {__version__}",
        "bananagrid_version": __version__,
    }
    if frame is not None:
        attrs["bananagrid_frame"] = json.dumps(frame.describe())
    return attrs


def polar_dataset(polar, frame=None, *, title: str = "", source: str = ""):
    """A :class:`~bananagrid.PolarRaster` as a CF-style :class:`xarray.Dataset`.

    Dimensions ``range`` (m, outward) and ``bearing`` (rad, clockwise from the lattice's
    heading), with ``range_bounds`` and ``bearing_bounds`` holding the cell edges; variables
    ``density`` (per m per rad at the cell centre) and ``probability`` (of each cell); ``x``,
    ``y`` (range, bearing) the cell centres in local metres (projected when there is a frame),
    and with a frame ``lat``, ``lon`` of the cell centres. The captured mass, the normalised
    flag, the lattice and the provenance are attributes. ``frame`` defaults to the raster's.
    """
    xr = require("xarray", NETCDF_PURPOSE)
    frame = getattr(polar, "frame", None) if frame is None else frame
    lattice = polar.lattice
    r_edges, b_edges = lattice.range_edges, lattice.bearing_edges
    wx, wy = lattice.world_centres
    px, py = (wx, wy) if frame is None else frame.projected(wx, wy)
    coords = {
        "range": xr.Variable(("range",), lattice.range_centres, {
            "long_name": "range from the lattice origin", "units": "m", "bounds": "range_bounds"}),
        "bearing": xr.Variable(("bearing",), lattice.bearing_centres, {
            "long_name": "bearing clockwise from the lattice heading", "units": "rad", "bounds": "bearing_bounds"}),
        "x": xr.Variable(("range", "bearing"), px, {
            "long_name": ("easting" if frame is not None else "x east of the local origin") + " of the cell centre",
            "units": "m"}),
        "y": xr.Variable(("range", "bearing"), py, {
            "long_name": ("northing" if frame is not None else "y north of the local origin") + " of the cell centre",
            "units": "m"}),
    }
    coordinates = "x y"
    if frame is not None:
        coords.update(_lat_lon(xr, ("range", "bearing"), frame, wx, wy))
        coordinates += " lat lon"
    data_vars = {
        "density": xr.Variable(("range", "bearing"), np.asarray(polar.density), {
            "long_name": "probability density of the target per unit range and bearing at the cell centre",
            "units": "m-1 rad-1"}, encoding={"coordinates": coordinates}),
        "probability": xr.Variable(("range", "bearing"), np.asarray(polar.probability), {
            "long_name": "probability of the cell", "units": "1"}, encoding={"coordinates": coordinates}),
        "range_bounds": xr.Variable(("range", "nv"), np.stack([r_edges[:-1], r_edges[1:]], axis=1)),
        "bearing_bounds": xr.Variable(("bearing", "nv"), np.stack([b_edges[:-1], b_edges[1:]], axis=1)),
    }
    attrs = _global_attrs(title, source, frame)
    attrs.update(mass=float(polar.mass), normalised=np.int8(bool(polar.normalised)),
                 bananagrid_lattice=json.dumps(lattice.describe()),
                 bananagrid_provenance=provenance_json(polar.provenance),
                 model=str(polar.provenance.get("model", "?")))
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def cell_map_dataset(cell_map, frame=None, *, title: str = "", source: str = ""):
    """A :class:`~bananagrid.CellMap` as a CF-style :class:`xarray.Dataset`.

    Dimensions ``azimuth`` and (plane, frustum) ``elevation`` (rad, the direction cell centres;
    elevation from +z, pi/2 the horizon, pi the nadir), with ``azimuth_bounds`` and
    ``elevation_bounds`` holding the cell edges; variables ``probability`` (presence
    probability of each cell given the region), ``error`` (its estimated absolute error, where
    known), ``cell_size`` (m, m2 or m3; inf for a horizon cell) and the scalar
    ``region_probability``. The lattice, the frame and the provenance are attributes.
    """
    xr = require("xarray", NETCDF_PURPOSE)
    frame = getattr(cell_map, "frame", None) if frame is None else frame
    lattice = cell_map.lattice
    dims = ("azimuth",) if lattice.geometry == "line" else ("azimuth", "elevation")
    a_edges = lattice.azimuth_edges
    coords = {"azimuth": xr.Variable(("azimuth",), lattice.azimuths, {
        "long_name": "azimuth of the direction cell", "units": "rad", "bounds": "azimuth_bounds"})}
    data_vars = {"azimuth_bounds": xr.Variable(("azimuth", "nv"), np.stack([a_edges[:-1], a_edges[1:]], axis=1))}
    if lattice.geometry != "line":
        e_edges = lattice.elevation_edges
        coords["elevation"] = xr.Variable(("elevation",), lattice.elevations, {
            "long_name": "elevation of the direction cell from +z (pi/2 the horizon, pi the nadir)",
            "units": "rad", "bounds": "elevation_bounds"})
        data_vars["elevation_bounds"] = xr.Variable(("elevation", "nv"), np.stack([e_edges[:-1], e_edges[1:]], axis=1))
    size = cell_map.clipped_sizes if cell_map.clipped_sizes is not None else lattice.sizes
    data_vars["probability"] = xr.Variable(dims, np.asarray(cell_map.prob), {
        "long_name": "presence probability of the cell given the region", "units": "1"})
    if cell_map.error is not None:
        data_vars["error"] = xr.Variable(dims, np.asarray(cell_map.error), {
            "long_name": "estimated absolute error of the cell probability", "units": "1"})
    data_vars["cell_size"] = xr.Variable(dims, np.asarray(size, dtype=float), {
        "long_name": "length, area or volume of the cell" + (" within the region" if cell_map.clipped_sizes is not None else ""),
        "units": CELL_UNITS[lattice.geometry]})
    data_vars["region_probability"] = xr.Variable((), float(cell_map.region_probability), {
        "long_name": "probability of the conditioning region (1 without one)", "units": "1"})
    attrs = _global_attrs(title, source, frame)
    attrs.update(bananagrid_lattice=json.dumps(lattice.describe()),
                 bananagrid_provenance=provenance_json(cell_map.provenance),
                 model=str(cell_map.provenance.get("model", "?")))
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def write_netcdf(path: str | os.PathLike, dataset, *, stage=None) -> Path:
    """Write ``dataset`` as NetCDF-4 (netCDF4 engine, zlib level :data:`ZLIB_LEVEL` on the data
    variables) to ``path``, whole or not at all: to a temporary name beside it, renamed when
    complete (``stage``: a run's :meth:`bananagrid.atomic.OutputSet.stage`, renamed with its
    other files).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    BananagridError
        A missing directory, a failure while writing (nothing is left behind), or xarray or
        netCDF4 missing.
    """
    xr = require("xarray", NETCDF_PURPOSE)
    require("netCDF4", NETCDF_PURPOSE)
    if not isinstance(dataset, xr.Dataset):
        raise BananagridError(f"dataset: expected an xarray.Dataset, got {type(dataset).__name__}")
    # no fill value: every cell holds a number (CF forbids missing values in coordinates); the
    # variables' own encodings (the time's units) are kept, since this argument replaces them
    encoding = {
        name: {**{k: v for k, v in var.encoding.items() if k in ("units", "calendar", "dtype")}, "_FillValue": None}
        for name, var in dataset.variables.items()
    }
    for name, var in dataset.data_vars.items():
        if var.ndim >= 1 and not name.endswith("_bounds"):
            encoding[name].update(zlib=True, complevel=ZLIB_LEVEL)
    final = Path(path)
    netcdf4 = require("netCDF4", NETCDF_PURPOSE)
    with writing(final, "NetCDF file", (RuntimeError,), stage=stage) as partial:
        dataset.to_netcdf(partial, engine="netcdf4", format="NETCDF4", encoding=encoding)
        with netcdf4.Dataset(partial, "a") as nc:  # the digest of what the file holds, as read back
            nc.setncattr(DIGEST_ATTRIBUTE, netcdf_digest(nc))
    return final


#: The global attribute holding :func:`netcdf_digest` of everything else in the file.
DIGEST_ATTRIBUTE = "bananagrid_digest"

#: What netCDF4 and HDF5 raise on a damaged or foreign file (HDF errors are RuntimeError; a
#: damaged size can ask for an impossible array).
_READ_ERRORS = (OSError, RuntimeError, ValueError, KeyError, IndexError, TypeError, AttributeError, MemoryError,
                OverflowError)


def netcdf_digest(nc) -> str:
    """BLAKE2b hex digest of an open :class:`netCDF4.Dataset`: every group's attributes
    (but :data:`DIGEST_ATTRIBUTE`), dimensions and variables (name, type, dimensions,
    attributes and the values as stored, without scaling or masking), in name order.

    HDF5 keeps no checksum of the values or the attributes (without its Fletcher-32 filter), so
    a flipped digit in ``bananagrid_grid`` or in a map would read back as another number; a
    file whose digest does not match is damaged. (Measured before the digest, on a 100 x 100
    map file: random damages also ended in tracebacks, ``RuntimeError: NetCDF: HDF error``,
    and one zeroed block made netCDF4 loop for ever on opening.)"""
    hasher = hashlib.blake2b(digest_size=16)

    def feed(value) -> None:
        array = np.asarray(value)
        if array.dtype == object or array.dtype.kind in "US":
            hasher.update(f"{type(value).__name__}:{value!r};".encode())
        else:
            hasher.update(f"{array.dtype.str}{array.shape};".encode())
            hasher.update(np.ascontiguousarray(array).tobytes())

    def group(g) -> None:
        for name in sorted(g.ncattrs()):
            if name != DIGEST_ATTRIBUTE:
                hasher.update(f"attr {name};".encode())
                feed(g.getncattr(name))
        for name, dim in sorted(g.dimensions.items()):
            hasher.update(f"dim {name} {len(dim)} {dim.isunlimited()};".encode())
        for name, var in sorted(g.variables.items()):
            var.set_auto_maskandscale(False)
            hasher.update(f"var {name} {var.dtype} {var.dimensions};".encode())
            for attr in sorted(var.ncattrs()):
                hasher.update(f"attr {attr};".encode())
                feed(var.getncattr(attr))
            feed(var[...])
        for name, child in sorted(g.groups.items()):
            hasher.update(f"group {name};".encode())
            group(child)

    group(nc)
    return hasher.hexdigest()


def check_netcdf(path: str | os.PathLike) -> Path:
    """Raise unless ``path`` is a regular file that netCDF4 reads whole and whose
    :data:`DIGEST_ATTRIBUTE` matches its contents (:func:`write_netcdf` writes it).

    A file without the attribute is refused too: it is damaged there, or written by a
    bananagrid before digests (its scene, run again with ``--netcdf``, writes it anew); reading
    it anyway could give a wrong number without a word.

    Raises
    ------
    BananagridError
        One line naming the file and what is wrong with it.
    """
    path = regular_file(path, "a NetCDF file")
    require("netCDF4", NETCDF_PURPOSE)
    checked_in_child(path, _check_digest)  # HDF5 can loop for ever on a damaged B-tree
    return path


def _check_digest(path: Path) -> None:
    netcdf4 = require("netCDF4", NETCDF_PURPOSE)
    try:
        with netcdf4.Dataset(path, "r") as nc:
            stored = nc.getncattr(DIGEST_ATTRIBUTE) if DIGEST_ATTRIBUTE in nc.ncattrs() else None
            found = netcdf_digest(nc)
    except _READ_ERRORS as exc:
        first = (str(exc).splitlines() or [""])[0]
        raise BananagridError(f"{path}: not a NetCDF file, or damaged ({type(exc).__name__}: {first})") from None
    if stored is None:
        raise BananagridError(
            f"{path}: no {DIGEST_ATTRIBUTE} attribute: damaged, or not written by this bananagrid "
            "(run its scene again with --netcdf)"
        )
    if stored != found:
        raise BananagridError(f"{path}: damaged (its contents do not match its {DIGEST_ATTRIBUTE})")


def read_maps(path: str | os.PathLike) -> tuple[str, list[dict]]:
    """The maps of a NetCDF file :func:`write_netcdf` wrote from :func:`raster_dataset`.

    Returns
    -------
    (str, list of dict)
        The file's title, and per layer and time: ``layer`` (the name as given), ``t``
        (elapsed s), ``values`` (float64, rows south to north), ``grid`` (the float64
        description: ``origin``, ``dx``, ``dy``, ``nx``, ``ny``), ``mass``, ``normalised``,
        ``provenance`` and ``frame`` (the frame's identity, or None).

    Raises
    ------
    BananagridError
        A file that does not open, is damaged (:func:`check_netcdf`), or holds no bananagrid
        layer variables.
    """
    xr = require("xarray", NETCDF_PURPOSE)
    path = check_netcdf(path)
    try:
        ds = xr.open_dataset(path, engine="netcdf4", decode_times=False)
    except _READ_ERRORS as exc:
        raise BananagridError(f"{path}: not a NetCDF file ({type(exc).__name__}: {exc})") from None
    with ds:
        try:
            grid = json.loads(ds.attrs["bananagrid_grid"])
            described = json.loads(ds.attrs["bananagrid_frame"]) if "bananagrid_frame" in ds.attrs else None
        except (KeyError, ValueError) as exc:
            raise BananagridError(f"{path}: not a map file written by bananagrid (no {exc} attribute)") from None
        frame = None if described is None else {
            "lat": described["lat"], "lon": described["lon"], "time": described.get("time"), "crs": described["crs_name"],
        }
        maps = []
        for name in layer_variables(ds).values():
            var = ds[name]
            if var.dims[1:] != ("y", "x"):
                continue
            tdim = var.dims[0]
            elapsed = ds[tdim] if tdim.startswith("elapsed") else ds[tdim.replace("time", "elapsed", 1)]
            provenance = json.loads(var.attrs.get("bananagrid_provenance", "[]"))
            masses, flags = ds[f"{name}_mass"].values, ds[f"{name}_normalised"].values
            for k, t in enumerate(np.asarray(elapsed.values, dtype=float)):
                maps.append({
                    "layer": var.attrs["bananagrid_layer"], "t": float(t),
                    "values": np.asarray(var.values[k], dtype=np.float64), "grid": grid,
                    "mass": float(masses[k]), "normalised": bool(flags[k]),
                    "provenance": provenance[k] if k < len(provenance) else {}, "frame": frame,
                })
        if not maps:
            raise BananagridError(f"{path}: holds no bananagrid layer variables")
        return str(ds.attrs.get("title", "")), maps
