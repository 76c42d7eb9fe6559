"""Every key of every bundled scene, mutated by type and value: the parser (which also builds
each layer's model at each time) either accepts the scene or refuses it with one line that
names the key; never another exception. A derandomised property-based sweep, so CI is
deterministic, plus the exhaustive table of one mutation of each kind per key. The geographic
keys (origin, UTC time, CRS) are also set to the ends of their domains, and accepted mutated
scenes are run, geographic ones with every map file they can write."""

import math
import warnings
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bananagrid import BananagridError
from bananagrid.scenes.load import parse_scene
from bananagrid.scenes.run import run_scene
from geo_cases import check_geojson, check_geotiff, check_netcdf, moved_doc

SCENES = sorted((Path(__file__).resolve().parents[2] / "scenes").glob("*.toml"))
DOCS = {path.name: tomllib.loads(path.read_text()) for path in SCENES}

#: Values of every TOML type and the numeric extremes.
MUTATIONS = (
    "text", "", True, False, 0, -1, 1, 2**63 - 1, -(2**63), 0.0, -0.0, -1.0, 1e-308, 1e308, -1e308,
    math.nan, math.inf, -math.inf, [], [1.0], ["a"], [[1.0, 2.0]], [[[1.0]]], [True], {}, {"a": 1.0},
)


def leaves(table, prefix=()):
    """Paths of every value (array elements included) in a TOML document."""
    for key, value in table.items():
        path = (*prefix, key)
        yield path
        if isinstance(value, dict):
            yield from leaves(value, path)
        elif isinstance(value, list):
            for k, item in enumerate(value):
                yield (*path, k)
                if isinstance(item, list):
                    yield from ((*path, k, j) for j in range(len(item)))


PATHS = [(name, path) for name, doc in DOCS.items() for path in leaves(doc)]


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f'"{k}" = {toml_value(v)}' for k, v in value.items()) + "}"
    raise TypeError(type(value))


def toml_text(doc: dict) -> str:
    """A TOML document of nested tables (dotted headers) whose leaves are inline values."""
    lines = []

    def table(body: dict, header: tuple):
        scalars = {k: v for k, v in body.items() if not isinstance(v, dict)}
        if header:
            lines.append("[" + ".".join(f'"{h}"' for h in header) + "]")
        lines.extend(f'"{k}" = {toml_value(v)}' for k, v in scalars.items())
        for k, v in body.items():
            if isinstance(v, dict):
                table(v, (*header, k))

    table(doc, ())
    return "\n".join(lines) + "\n"


def mutated(name: str, path: tuple, value) -> str:
    doc = tomllib.loads(toml_text(DOCS[name]))  # a deep copy that round-trips
    *parents, last = path
    node = doc
    for key in parents:
        node = node[key]
    node[last] = value
    return toml_text(doc)


def test_the_writer_round_trips_every_scene():
    for name, doc in DOCS.items():
        assert tomllib.loads(toml_text(doc)) == doc, name


def check(name: str, path: tuple, value) -> None:
    text = mutated(name, path, value)
    try:
        with warnings.catch_warnings():
            # NumPy overflow on the way is a value that should have been refused at the edge
            warnings.simplefilter("error", RuntimeWarning)
            parse_scene(text, source=name)
    except BananagridError as exc:
        message = str(exc)
        assert "\n" not in message, message
        assert message.startswith(f"{name}: "), message
        # the message names the key (or, for an element or a table-valued key, a key above it;
        # for a key in degrees or knots, the parameter it sets)
        named = [str(p) for p in path if isinstance(p, str)]
        named += [p.removesuffix("_deg").removesuffix("_kn") for p in named]
        assert any(part in message for part in named), (path, value, message)


@settings(max_examples=600, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(PATHS), st.sampled_from(MUTATIONS))
def test_a_mutated_scene_is_accepted_or_refused_in_one_line(case, value):
    name, path = case
    check(name, path, value)


@pytest.mark.parametrize("value", ["text", True, [], {}, math.nan, -1.0, 1e308], ids=repr)
def test_every_key_with_one_bad_value(value):
    """Each kind of bad value at every key of every bundled scene (the sweep above mixes them)."""
    for name, path in PATHS:
        check(name, path, value)


#: Cells along the wider side of a grid scene's small-grid run.
SMALL_GRID_CELLS = 40


@settings(max_examples=20, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.sampled_from(PATHS), st.sampled_from(MUTATIONS))
def test_an_accepted_mutated_scene_runs_on_a_small_grid(tmp_path_factory, case, value):
    """A mutation the parser accepts must also run: on a grid of about 40 cells a side (an
    [array] scene on its own lattice), ending with the recording written or one-line refusal.
    (20 draws, about a minute; a 40-draw run found `sigma_heading_deg = 1e308` accepted and
    overflowing in the polar kernel's coefficients.)"""
    name, path = case
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the scenes' own warnings (a poor crossing) are fine here
            scene = parse_scene(mutated(name, path, value), source=name)
    except BananagridError:
        return
    if hasattr(scene, "grid"):
        x0, x1, y0, y1 = scene.grid.extent
        scene = scene.with_step(max(x1 - x0, y1 - y0) / SMALL_GRID_CELLS)
    run_with_exports(scene, tmp_path_factory.mktemp("run"))


def run_with_exports(scene, out: Path) -> None:
    """Run ``scene`` into ``out`` (a geographic scene with every map file: NetCDF, GeoTIFF,
    GeoJSON): the files written and valid, or a one-line refusal with nothing left behind."""
    geographic = getattr(scene, "geo", None) is not None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_scene(scene, out, netcdf=geographic, geotiff=geographic, geojson=geographic)
    except BananagridError as exc:
        assert "\n" not in str(exc), str(exc)
        assert list(out.iterdir()) == []  # nothing half-written
        return
    assert (out / f"{scene.name}.rrd").stat().st_size > 0
    if geographic:
        check_geojson(out / f"{scene.name}-areas.geojson")
        check_netcdf(out / f"{scene.name}.nc", scene)
        check_geotiff(out / f"{scene.name}.tif", scene)


#: The geographic keys of the bundled geographic scenes, with values at the ends of their
#: domains: origins at and beside the poles and the antimeridian (the scene's other positions
#: moved with the origin), UTC times at the ends of the calendar and of datetime64[ns], and CRSs
#: that hold the grid or do not (a false easting of 1e20 m, absurd scales, a UTM zone and polar
#: stereographic projections far from it, a geographic CRS).
GEO_VALUES = {
    "origin_latlon": [(90.0, None), (-90.0, None), (89.9999, None), (-89.9999, None), (0.0, None),
                      (None, 180.0), (None, -180.0), (None, 179.9999), (None, -179.9999), (None, 180.0000001),
                      (math.nan, None), (None, math.inf)],
    "time": ["0001-01-01T00:00:00Z", "0001-01-01T00:00:00+01:00", "1582-10-04T12:00:00Z", "1677-09-21T00:12:43Z",
             "2262-04-11T23:47:16Z", "9999-12-31T23:00:00Z", "9999-12-31T23:59:59Z", "10000-01-01T00:00:00Z"],
    "crs": ["utm", "aeqd", "EPSG:32601", "EPSG:3413", "EPSG:3031", "EPSG:4326", "+proj=merc +datum=WGS84",
            "+proj=tmerc +x_0=1e20 +datum=WGS84", "+proj=tmerc +k=1e-20 +datum=WGS84",
            "+proj=tmerc +k=1000 +datum=WGS84", "+proj=stere +lat_0=-90 +datum=WGS84"],
}
GEO_CASES = [(name, key, value) for name, doc in DOCS.items() if "geo" in doc
             for key, values in GEO_VALUES.items() for value in values]


def geo_mutated(name: str, key: str, value) -> str:
    """The scene with ``geo.KEY`` set to ``value``; an origin (lat or lon, the other kept) moves
    the scene's other positions with it where it is a finite place that is not a pole."""
    doc = DOCS[name]
    if key != "origin_latlon":
        return mutated(name, ("geo", key), value)
    lat, lon = (v if v is not None else old for v, old in zip(value, doc["geo"]["origin_latlon"]))
    if math.isfinite(lat) and math.isfinite(lon) and abs(lat) < 90.0 and abs(lon) <= 180.0:
        return toml_text(moved_doc(doc, lat, lon))
    return mutated(name, ("geo", key), [lat, lon])


def check_geo(name: str, key: str, value) -> object:
    """Parse the mutated scene: the Scene, or None after a one-line refusal naming ``geo.KEY``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            return parse_scene(geo_mutated(name, key, value), source=name)
    except BananagridError as exc:
        message = str(exc)
        assert "\n" not in message, message
        # a CRS whose scale error over the grid is above geo.max_scale_error: the grid and the
        # projection (named by its value) are refused together
        scale = key == "crs" and message.startswith(f"{name}: grid x = ") and f'geo.crs = "{value}", reaches' in message
        assert message.startswith(f"{name}: geo.{key}") or scale, message
        return None


@pytest.mark.parametrize("name, key, value", GEO_CASES, ids=[f"{n}-{k}-{v}" for n, k, v in GEO_CASES])
def test_every_geographic_key_at_the_ends_of_its_domain(name, key, value):
    """Each geographic key of each geographic scene at each of its extreme values: accepted, or
    refused in one line that starts with the key (a pole, a time outside the calendar, a CRS
    whose round trip over the grid is off by more than a millimetre)."""
    check_geo(name, key, value)


@settings(max_examples=6, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.sampled_from([case for case in GEO_CASES if case[1] != "time"]))
def test_a_mutated_geographic_scene_runs_with_every_export(tmp_path_factory, case):
    """A geographic key mutated (an origin at a pole or the antimeridian, a CRS), the scene run on
    a small grid with --netcdf --geotiff --geojson: valid files (GeoJSON per RFC 7946, NetCDF and
    GeoTIFF coordinates stepping by the grid's step) or a one-line refusal. (The times are run
    through the NetCDF writer in test_geo_globe.py.)"""
    scene = check_geo(*case)
    if scene is None:
        return
    x0, x1, y0, y1 = scene.grid.extent
    run_with_exports(scene.with_step(max(x1 - x0, y1 - y0) / SMALL_GRID_CELLS), tmp_path_factory.mktemp("geo"))
