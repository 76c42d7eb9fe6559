"""Every key of every bundled scene, mutated by type and value: the parser (which also builds
each layer's model at each time) either accepts the scene or refuses it with one line that
names the key; never another exception. A derandomised property-based sweep, so CI is
deterministic, plus the exhaustive table of one mutation of each kind per key."""

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

SCENES = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))
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
    out = tmp_path_factory.mktemp("run")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_scene(scene, out)
    except BananagridError as exc:
        assert "\n" not in str(exc), str(exc)
        assert list(out.iterdir()) == []  # nothing half-written
        return
    assert (out / f"{scene.name}.rrd").stat().st_size > 0
