"""Presence scenes: the [array] schema, its errors, the recording and the .npz.

The probabilities themselves are checked against independent oracles in test_presence.py; here
the recorded and exported numbers are compared with ``cell_probabilities`` called directly on
the law, lattice and room that the scene file spells out (so a parser that swapped sd_x and
sd_y, or dropped rho, would fail), and the drawn geometry against the room and the covariances.
"""

from __future__ import annotations

import ast
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rerun.chunk import RrdReader

import bananagrid as bg
from bananagrid.cli import main
from bananagrid.models.params import modelclass
from bananagrid.models.registry import ModelKind
from bananagrid.protocol import SceneSchema
from bananagrid.recording.inspect import inspect_recording, read_depth_image
from bananagrid.recording.presence import cell_colours
from bananagrid.scenes.run import run_scene
from bananagrid.scenes.load import load_scene, parse_scene
import bananagrid.scenes.run_cells as run_cells

ROOT = Path(__file__).resolve().parents[2]
SCENES = {name: ROOT / "scenes" / f"{name}.toml" for name in ("room_mixture", "room_uniform", "room_frustum", "line_section4")}
RERUN = Path(sys.executable).parent / "rerun"
DEG = math.pi / 180.0

#: The room of the bundled scenes, in the array frame.
ROOM = bg.Region(x=(-3.0, 3.0), y=(-2.5, 2.5))
#: room_mixture.toml written out by hand: chair, sofa, door (door: rho 0.3 of sd 0.15 and 0.3).
MIXTURE = bg.GaussianMixture(
    weights=[0.5, 0.35, 0.15],
    means=[[-1.8, 1.5], [1.2, -1.8], [2.6, 1.9]],
    covs=[np.diag([0.0625, 0.0625]), np.diag([0.49, 0.04]), [[0.0225, 0.3 * 0.15 * 0.3], [0.3 * 0.15 * 0.3, 0.09]]],
)


def law(scene):
    """The scene's presence law: its one layer's model."""
    (layer,) = scene.layers
    return layer.model()


# --- the bundled scenes parse to what they say ----------------------------------------------------


def test_room_mixture_parses_to_its_law_lattice_and_room():
    scene = load_scene(SCENES["room_mixture"])
    assert not scene.gridded and scene.name == "room_mixture" and scene.layers[0].kind == "mixture"
    assert scene.layers[0].model_kind is bg.MODEL_KINDS["mixture"] and scene.layers[0].model_kind.domain == "array"
    assert scene.domain == bg.AngularLattice.integer_degrees("plane", h=1.8)
    assert scene.region == ROOM and scene.room_z == (-3.0, 0.0)
    assert scene.component_names == ("desk_chair", "sofa", "door")
    np.testing.assert_array_equal(law(scene).weights, MIXTURE.weights)
    np.testing.assert_array_equal(law(scene).means, MIXTURE.means)
    # sd^2 and rho sd_x sd_y in floating point: equal to the hand-written products to 1 ulp
    np.testing.assert_allclose(law(scene).covs, MIXTURE.covs, rtol=1e-15, atol=0)


def test_other_scenes_parse():
    uniform = load_scene(SCENES["room_uniform"])
    assert isinstance(law(uniform), bg.UniformPresence) and law(uniform).region == ROOM
    assert uniform.component_names == ()
    frustum = load_scene(SCENES["room_frustum"])
    assert frustum.domain == bg.AngularLattice.integer_degrees("frustum", h=1.55, dh=0.25)
    assert frustum.region == bg.Region(x=(-3.0, 3.0), y=(-2.5, 2.5), z=(-3.0, 0.0))
    assert law(frustum).dim == 3 and law(frustum).block_diagonal
    assert law(frustum).covs[2, 2, 2] == pytest.approx(0.08**2, rel=1e-15)
    line = load_scene(SCENES["line_section4"])
    assert line.domain == bg.AngularLattice("line", h=1.8, azimuth_step=DEG, azimuth_range=(math.pi, 2 * math.pi))
    assert line.domain.shape == (181,) and line.region == bg.Region(x=(-3.0, 3.0))
    np.testing.assert_array_equal(law(line).means[:, 0], [-1.8, 2.6])  # a number and [x] alike


# --- bad keys, one per kind, the whole message ----------------------------------------------------

BASE = """\
[scene]
name = "t"

[array]
geometry = "plane"
h = 1.8
azimuth_step_deg = 10
elevation_step_deg = 10

[room]
x = [-3.0, 3.0]
y = [-2.5, 2.5]

[presence]
kind = "mixture"

[presence.components.a]
weight = 0.6
mean = [1.0, 0.5]
sd_x = 0.3
sd_y = 0.2

[presence.components.b]
weight = 0.4
mean = [-1.0, -0.5]
cov = [[0.1, 0.02], [0.02, 0.2]]
"""

BAD = [
    ("top-level key", ("[room]", "[grid]\nstep = 1.0\n\n[room]"),
     "grid: unknown key (a presence scene, since it has [array]); allowed: scene, array, room, presence, output"),
    ("array key", ("h = 1.8", "h = 1.8\nheight = 2"),
     "array.height: unknown key; allowed: geometry, h, dh, azimuth_step_deg, elevation_step_deg, azimuth_range_deg, "
     "elevation_range_deg"),
    ("geometry", ('geometry = "plane"', 'geometry = "cone"'),
     'array.geometry = "cone": must be one of "line", "plane", "frustum"'),
    ("h", ("h = 1.8", "h = -1.8"), "array.h = -1.8: must be finite and > 0 (m below the array)"),
    ("dh missing", ('geometry = "plane"', 'geometry = "frustum"'),
     "array.dh: missing; the frustum's slab half-thickness, m (0 < dh < h)"),
    ("dh on a plane", ("h = 1.8", "h = 1.8\ndh = 0.2"),
     'array.dh = 0.2: only the frustum geometry has a slab (geometry = "plane")'),
    ("dh too large", ('geometry = "plane"\nh = 1.8', 'geometry = "frustum"\nh = 1.8\ndh = 2.0'),
     "array.dh = 2.0: must be in (0, h = 1.8) m"),
    ("fractional step", ("azimuth_step_deg = 10", "azimuth_step_deg = 0.5"),
     "array.azimuth_step_deg = 0.5: must be a whole number of degrees in [1, 180] (the paper's integer angles, Section 2)"),
    ("step that does not divide", ("elevation_step_deg = 10", "elevation_step_deg = 7"),
     "array.elevation_step_deg = 7: does not divide the elevation span 90 deg of array.elevation_range_deg = [90, 180]"),
    ("range outside the hemisphere", ("elevation_step_deg = 10", "elevation_step_deg = 10\nelevation_range_deg = [80, 180]"),
     "array.elevation_range_deg[0] = 80: must be a whole number of degrees in [90, 180] (the paper's integer angles, "
     "Section 2)"),
    ("elevation on a line", ('geometry = "plane"', 'geometry = "line"'),
     "array.elevation_step_deg = 10: the line geometry has azimuths only"),
    ("room axis missing", ("y = [-2.5, 2.5]\n", ""),
     "room.y: missing; the plane geometry needs x, y ranges [low, high] in m"),
    ("room range reversed", ("x = [-3.0, 3.0]", "x = [3.0, -3.0]"),
     "room.x = [3.0, -3.0]: the upper bound must exceed the lower"),
    ("room below the plane", ("y = [-2.5, 2.5]", "y = [-2.5, 2.5]\nz = [-1.5, 0.0]"),
     "room.z = [-1.5, 0.0]: the target plane z = -h = -1.8 m lies outside the room"),
    ("presence kind", ('kind = "mixture"', 'kind = "gaussian"'),
     'presence.kind = "gaussian": must be one of "mixture", "uniform"'),
    ("presence kind of a grid layer", ('kind = "mixture"', 'kind = "cat"'),
     'presence.kind = "cat": must be one of "mixture", "uniform"'),
    ("presence kind not a string", ('kind = "mixture"', 'kind = []'),
     'presence.kind = []: must be one of "mixture", "uniform"'),
    ("uniform with components", ('kind = "mixture"', 'kind = "uniform"'),
     'presence.components: a uniform law has no components (kind = "uniform")'),
    ("component key of another geometry", ("sd_y = 0.2", "sd_y = 0.2\nsd_z = 0.1"),
     'presence.components.a.sd_z: unknown key (geometry "plane": axes x, y); did you mean "sd_y"? allowed: weight, '
     'mean, cov, sd_x, sd_y, rho'),
    ("weight", ("weight = 0.6", "weight = 1.6"), "presence.components.a.weight = 1.6: must be in [0, 1]"),
    ("weights that do not sum to 1", ("weight = 0.6", "weight = 0.5"),
     "presence.components: the weights (a = 0.5, b = 0.4) sum to 0.9, not 1 (allowed error 1e-09); divide them by their sum"),
    ("mean", ("mean = [1.0, 0.5]", "mean = [1.0, 0.5, 0.0]"),
     "presence.components.a.mean = [1.0, 0.5, 0.0]: expected [x, y] in m (2 number(s))"),
    ("cov and sds", ("cov = [[0.1, 0.02], [0.02, 0.2]]", "cov = [[0.1, 0.02], [0.02, 0.2]]\nsd_x = 0.1"),
     "presence.components.b: give cov or sd_x, sd_y, rho, not both (sd_x given with cov)"),
    ("sd", ("sd_x = 0.3", "sd_x = 0.0"), "presence.components.a.sd_x = 0.0: must be > 0 (m)"),
    ("rho", ("sd_y = 0.2", "sd_y = 0.2\nrho = 1.0"),
     "presence.components.a.rho = 1.0: must be in (-1, 1) (the x-y correlation)"),
    ("covariance not positive definite", ("[[0.1, 0.02], [0.02, 0.2]]", "[[0.1, 0.5], [0.5, 0.2]]"),
     "presence.components.b.cov = [[0.1, 0.5], [0.5, 0.2]]: must be positive definite (eigenvalues -0.352494, "
     "0.652494; correlation 3.53553390593274; allowed: |rho| < 1 and a condition number below 1e+13)"),
    ("covariance not symmetric", ("[[0.1, 0.02], [0.02, 0.2]]", "[[0.1, 0.02], [0.03, 0.2]]"),
     "presence.components.b.cov = [[0.1, 0.02], [0.03, 0.2]]: must be symmetric "
     "(presence.components.b.cov[0][1] == presence.components.b.cov[1][0])"),
    ("SDs too elongated", ("sd_y = 0.2", "sd_y = 1e-8"),  # variances 0.09 and 1e-16: condition 9e14 > 1e13
     "presence.components.a.sd_x, sd_y, rho = [[0.09, 0.0], [0.0, 1.0000000000000001e-16]]: must be positive "
     "definite (eigenvalues 1e-16, 0.09; correlation 0; allowed: |rho| < 1 and a condition number below 1e+13)"),
    ("presence key", ('kind = "mixture"', 'kind = "mixture"\nlabel = "heads"'),
     "presence.label: unknown key; allowed: kind, components"),
    ("output key", ("[presence]", '[output]\ncolormap = "turbo"\n\n[presence]'),
     "output.colormap: unknown key; allowed: dtype, far, log10_floor, mass_levels"),
    ("log10 floor", ("[presence]", "[output]\nlog10_floor = 2\n\n[presence]"),
     "output.log10_floor = 2: must be in [-300, 0) (log10 of a probability)"),
]


def test_base_scene_is_valid():
    scene = parse_scene(BASE, source="base.toml")
    assert scene.domain.shape == (36, 10) and scene.component_names == ("a", "b")


@pytest.mark.parametrize("case, edit, message", BAD, ids=[case for case, _, _ in BAD])
def test_bad_key_is_named(case, edit, message):
    old, new = edit
    assert BASE.count(old) >= 1, case
    text = BASE.replace(old, new, 1)
    with pytest.raises(bg.BananagridError) as info:
        parse_scene(text, source="bad.toml")
    assert str(info.value) == f"bad.toml: {message}"


def test_uniform_needs_a_room():
    text = BASE.split("[room]")[0] + '[presence]\nkind = "uniform"\n'
    with pytest.raises(bg.BananagridError, match=r'^bad.toml: \[room\]: missing table; a uniform law'):
        parse_scene(text, source="bad.toml")


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(a=st.floats(-4.0, 4.0), b=st.floats(-4.0, 4.0), c=st.floats(-20.0, 20.0), rho=st.floats(-1.0, 1.0),
       sds=st.booleans())
def test_a_component_covariance_is_the_laws_own(a, b, c, rho, sds):
    """The component table and the law check a covariance the same way: a table the scene
    accepts builds the law with that covariance, and one the law would refuse is refused naming
    the component's key (never by the fallback that names only ``presence``). Covariances of
    every elongation (variances 10^a, 10^b) and correlation, near-singular ones included (rho
    and c close to the ends), given as ``cov`` or as SDs."""
    sx, sy = 10.0 ** (a / 2), 10.0 ** (b / 2)
    if sds:
        body = f"sd_x = {sx!r}\nsd_y = {sy!r}\nrho = {rho!r}"
        key = "presence.components.b.sd_x, sd_y, rho"
    else:
        sxy = rho * sx * sy * (1.0 + 10.0 ** -abs(c))  # |correlation| a hair above |rho|: at and past 1
        body = f"cov = [[{sx * sx!r}, {sxy!r}], [{sxy!r}, {sy * sy!r}]]"
        key = "presence.components.b.cov"
    text = BASE.replace("cov = [[0.1, 0.02], [0.02, 0.2]]", body)
    try:
        scene = parse_scene(text, source="fuzz.toml")
    except bg.BananagridError as exc:
        message = str(exc)
        # a correlation of 1 or more is the only refusal this table can meet but the room's mass
        assert message.startswith((f"fuzz.toml: {key} = ", "fuzz.toml: presence.components.b.rho = ")), message
        return
    cov = law(scene).covs[1]
    assert cov[0, 1] == cov[1, 0]  # the law's own check made it exactly symmetric (it was written so)


def test_uniform_takes_no_keys_of_its_own():
    text = BASE.split("[presence]")[0] + '[presence]\nkind = "uniform"\nlabel = "heads"\n'
    with pytest.raises(bg.BananagridError) as info:
        parse_scene(text, source="bad.toml")
    assert str(info.value) == "bad.toml: presence.label: unknown key; allowed: kind"


def test_a_room_the_law_gives_no_mass_is_refused():
    """Every law's cells are conditioned on the room, so each must give it mass (a uniform law
    is the room's own and always does)."""
    text = BASE.replace("mean = [1.0, 0.5]", "mean = [100.0, 0.5]").replace("mean = [-1.0, -0.5]", "mean = [-100.0, 0.5]")
    with pytest.raises(bg.BananagridError) as info:
        parse_scene(text, source="bad.toml")
    assert str(info.value) == ("bad.toml: room = {x = [-3.0, 3.0], y = [-2.5, 2.5]}: the mixture law gives the room "
                               "no mass (p(S) = 0.0)")


@modelclass
class WholeRoom(bg.UniformPresence):
    """A presence law of the tests' own: uniform on the room, under a kind name the package never
    spells; its scene table is read by the hook it inherits."""

    kind = "whole_room"
    scene = SceneSchema(summary="presence uniform on the scene's [room], a kind of the tests")


def test_a_presence_kind_of_ones_own_is_parsed_and_run_through_its_hooks(tmp_path):
    """The parser and the runner name no kind: a law registered beside the package's runs from
    its scene, reading its table through its class's ``scene_table``, to the same cells as the
    uniform law it extends."""
    kinds = bg.MODEL_KINDS.with_kinds(ModelKind("whole_room", WholeRoom, domain="array"))
    text = BASE.split("[presence]")[0] + '[presence]\nkind = "whole_room"\n'
    scene = parse_scene(text, source="own.toml", kinds=kinds)
    assert type(law(scene)) is WholeRoom and law(scene).region == scene.region == ROOM
    with pytest.raises(bg.BananagridError, match=r'^own.toml: presence.components: a uniform law has no components '
                                                 r'\(kind = "whole_room"\)$'):
        parse_scene(BASE.replace('kind = "mixture"', 'kind = "whole_room"'), source="own.toml", kinds=kinds)
    (row,) = run_scene(scene, tmp_path, npz=True)
    assert row["layer"] == "plane/whole_room"
    with np.load(tmp_path / "t.npz") as z:
        own = z["cells"]
    uniform = bg.cell_probabilities(bg.UniformPresence(ROOM), scene.domain)
    np.testing.assert_array_equal(own, uniform.prob)


def test_the_scene_layer_names_no_kind():
    """Scenes branch on a kind's hooks, never on its name: no string of the scenes package (its
    docstrings aside) is a registered kind's name."""
    found = []
    for path in sorted((ROOT / "bananagrid" / "scenes").rglob("*.py")):
        tree = ast.parse(path.read_text())
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)}
        found += [f"{path.name}:{node.lineno} {node.value!r}" for node in ast.walk(tree)
                  if isinstance(node, ast.Constant) and node.value in set(bg.MODEL_KINDS) and id(node) not in docstrings]
    assert found == []


def test_frustum_room_must_meet_the_slab():
    text = BASE.replace('geometry = "plane"\nh = 1.8', 'geometry = "frustum"\nh = 1.8\ndh = 0.2')
    text = text.replace("y = [-2.5, 2.5]", "y = [-2.5, 2.5]\nz = [-1.5, 0.0]")
    with pytest.raises(bg.BananagridError) as info:
        parse_scene(text, source="bad.toml")
    assert str(info.value) == ("bad.toml: room.z = [-1.5, 0.0]: misses the slab z in [-2, -1.6] "
                               "(depths h - dh to h + dh below the array)")


# --- the recording --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def mixture_run(tmp_path_factory):
    """room_mixture.toml run once with --npz: (out dir, the scene, its cell map computed directly)."""
    out = tmp_path_factory.mktemp("room_mixture")
    scene = load_scene(SCENES["room_mixture"])
    rows = run_scene(scene, out, npz=True)
    direct = bg.cell_probabilities(MIXTURE, bg.AngularLattice.integer_degrees("plane", h=1.8), ROOM)
    return out, scene, direct, rows


def _cell(path: Path, entity: str, component: str):
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            if component in batch.schema.names:
                return batch.column(component)[0].as_py()
    raise AssertionError(f"{component} not logged at {entity}")


def test_summary_row(mixture_run):
    _, _, direct, rows = mixture_run
    (row,) = rows
    assert (row["scene"], row["layer"], row["t"], row["cells"]) == ("room_mixture", "plane/mixture", 0.0, 32760)
    assert row["mass"] == pytest.approx(1.0, abs=1e-12)  # the lattice covers the room: sum p(C | S) = 1
    assert row["peak"] == float(direct.prob.max())


def test_recording_holds_the_table_mesh_room_and_ellipses(mixture_run):
    out, scene, direct, _ = mixture_run
    path = out / "room_mixture.rrd"
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    info = inspect_recording(path)
    assert info["blueprint"]
    entities = info["entities"]
    assert entities["/presence/plane/cells"]["archetypes"] == ["Mesh3D"]
    for part in ("plane/room", "plane/components"):
        assert entities[f"/presence/{part}"]["archetypes"] == ["LineStrips3D"]
    assert "/scene" in entities and "/presence/plane/array" in entities
    # The table: the kernel is deterministic per cell (no reduction across threads), so the
    # recorded float32 table is exactly the float32 of the direct computation.
    table = np.flipud(read_depth_image(path, "presence/table"))  # undo the reader's row flip
    assert table.shape == (91, 360)
    np.testing.assert_array_equal(table.T, direct.prob.astype(np.float32))
    logs = np.flipud(read_depth_image(path, "presence/log10_table"))
    expected = np.log10(np.maximum(direct.prob, 1e-12)).astype(np.float32)
    # log10 in float64 then rounded to float32 both ways: identical
    np.testing.assert_array_equal(logs.T, expected)
    values = entities["/presence/summary"]["values"][-1]["values"]
    assert values["total"] == float(direct.prob.sum())
    assert values["region_probability"] == MIXTURE.region_probability(ROOM)
    assert values["largest_error"] == float(direct.error.max())
    assert "provenance.seconds" not in values and "provenance.threads" not in values


def _triangle_areas(pos, tri):
    a, b, c = (pos[tri[:, k]].astype(np.float64) for k in range(3))
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def test_mesh_tiles_the_room_on_the_target_plane(mixture_run):
    out, _, direct, _ = mixture_run
    path = out / "room_mixture.rrd"
    pos = np.array(_cell(path, "/presence/plane/cells", "Mesh3D:vertex_positions"), dtype=np.float32)
    tri = np.array(_cell(path, "/presence/plane/cells", "Mesh3D:triangle_indices"), dtype=np.int64)
    colours = np.array(_cell(path, "/presence/plane/cells", "Mesh3D:vertex_colors"), dtype=np.uint32)
    assert np.all(pos[:, 2] == np.float32(-1.8))
    # clipped to the walls (float32 of coordinates below 3 m: 2.4e-7 m)
    assert np.all(np.abs(pos[:, 0]) <= 3.0 + 1e-6) and np.all(np.abs(pos[:, 1]) <= 2.5 + 1e-6)
    # Adjacent rings share their chords, so the pieces tile the room exactly: the triangles'
    # area is the room's 30 m^2 up to float32 vertex rounding (about 1e-7 relative per vertex).
    assert _triangle_areas(pos, tri).sum() == pytest.approx(30.0, rel=1e-5)
    # The brightest vertex colour is the largest cell's (RGBA packed as 0xRRGGBBAA).
    rgb, _ = cell_colours(direct.prob)
    i, j = np.unravel_index(np.argmax(direct.prob), direct.prob.shape)
    r, g, b = (int(v) for v in rgb[i, j])
    assert (r << 24 | g << 16 | b << 8 | 255) in set(colours.tolist())


def test_ellipses_are_the_components_sigma_contours(mixture_run):
    out, scene, _, _ = mixture_run
    path = out / "room_mixture.rrd"
    strips = _cell(path, "/presence/plane/components", "LineStrips3D:strips")
    labels = _cell(path, "/presence/plane/components", "LineStrips3D:labels")
    names = scene.component_names
    assert labels == [f"{n} {k} sigma" for n in names for k in (1, 2, 3)]
    for c, (mu, cov) in enumerate(zip(MIXTURE.means, MIXTURE.covs)):
        inv = np.linalg.inv(cov)
        for k in (1, 2, 3):
            p = np.array(strips[3 * c + k - 1], dtype=np.float64)
            d = p[:, :2] - mu
            # Mahalanobis radius k; float32 points of a few metres: 1e-6 relative
            assert np.sqrt(np.einsum("ni,ij,nj->n", d, inv, d)) == pytest.approx(k, rel=1e-5)
            assert np.all(p[:, 2] == np.float32(-1.8))
    room = _cell(path, "/presence/plane/room", "LineStrips3D:strips")
    corners = {tuple(v) for strip in room for v in strip}
    assert corners == {(x, y, z) for x in (-3.0, 3.0) for y in (-2.5, 2.5) for z in (-3.0, 0.0)}


# --- the .npz -------------------------------------------------------------------------------------


def test_npz_round_trips(mixture_run):
    out, scene, direct, _ = mixture_run
    with np.load(out / "room_mixture.npz", allow_pickle=False) as arrays:
        prob = arrays["prob"]
        assert prob.shape == (360, 181)
        # indexed by integer degrees: azimuth 34, elevation 144 is lattice cell (34, 54)
        assert prob[34, 144] == direct.prob[34, 54]
        np.testing.assert_array_equal(prob[:, 90:], direct.prob)
        assert np.isnan(prob[:, :90]).all()  # above the horizon: not in the lattice
        np.testing.assert_array_equal(arrays["cells"], direct.prob)
        np.testing.assert_array_equal(arrays["error"], direct.error)
        np.testing.assert_array_equal(arrays["azimuth_deg"], np.arange(360, dtype=np.uint16))
        np.testing.assert_array_equal(arrays["elevation_deg"], np.arange(90, 181, dtype=np.uint16))
        assert arrays["azimuth_deg"].dtype == np.uint16
        # cell bounds +- half a degree, clipped to [90, 180] in elevation (to 1e-12 deg from radians)
        np.testing.assert_allclose(arrays["azimuth_edges_deg"], np.arange(361) - 0.5, rtol=0, atol=1e-12)
        np.testing.assert_allclose(arrays["elevation_edges_deg"], np.clip(np.arange(90, 182) - 0.5, 90, 180),
                                   rtol=0, atol=1e-12)
        np.testing.assert_array_equal(arrays["clipped_sizes"], direct.clipped_sizes)
        provenance = json.loads(str(arrays["provenance"]))
    assert provenance["scene"] == "room_mixture" and provenance["text"] == scene.text
    assert provenance["total"] == float(direct.prob.sum())
    assert provenance["components"] == ["desk_chair", "sofa", "door"]
    assert sorted(p.name for p in out.iterdir()) == ["room_mixture.npz", "room_mixture.rrd"]


def test_line_scene_records_segments_and_exports_by_degree(tmp_path):
    scene = load_scene(SCENES["line_section4"])
    run_scene(scene, tmp_path, npz=True)
    direct = bg.cell_probabilities(law(scene), scene.domain, bg.Region(x=(-3.0, 3.0)))
    table = np.flipud(read_depth_image(tmp_path / "line_section4.rrd", "presence/table"))
    np.testing.assert_array_equal(table, direct.prob[None, :].astype(np.float32))
    strips = _cell(tmp_path / "line_section4.rrd", "/presence/plane/cells", "LineStrips3D:strips")
    # the segments tile the room's width
    assert sum(s[1][0] - s[0][0] for s in strips) == pytest.approx(6.0, rel=1e-6)
    with np.load(tmp_path / "line_section4.npz", allow_pickle=False) as arrays:
        assert arrays["prob"].shape == (361,)
        np.testing.assert_array_equal(arrays["prob"][180:], direct.prob)
        np.testing.assert_array_equal(arrays["x_edges"], scene.domain.line_edges())
        assert "elevation_deg" not in arrays.files


# --- the command line -----------------------------------------------------------------------------


def test_cli_runs_a_presence_scene_and_ignores_step(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(SCENES["line_section4"]), "--out", str(out), "--step", "40"]) == 0
    captured = capsys.readouterr()
    assert f"bananagrid: warning: {SCENES['line_section4']}: --step 40 does not apply to a presence scene" in captured.err
    assert "[1/1] line_section4: line/mixture 181 cells ..." in captured.err
    row = next(line for line in captured.out.splitlines() if line.startswith("line_section4"))
    assert row.split()[:4] == ["line_section4", "line/mixture", "0", "181"]
    assert f"wrote {out / 'line_section4.rrd'}" in captured.out


def test_same_presence_scene_twice_gives_equal_recordings(tmp_path):
    for name in ("a", "b"):
        assert main(["run", str(SCENES["line_section4"]), "--out", str(tmp_path / name), "--quiet"]) == 0
    compare = subprocess.run([str(RERUN), "rrd", "compare", str(tmp_path / "a" / "line_section4.rrd"),
                              str(tmp_path / "b" / "line_section4.rrd")], capture_output=True, text=True, timeout=120)
    assert compare.returncode == 0, compare.stdout + compare.stderr


def test_bad_presence_scene_is_one_line_exit_2(tmp_path, capsys):
    scene = tmp_path / "bad.toml"
    scene.write_text(BASE.replace("sd_x = 0.3", "sd_x = -0.3"))
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"bananagrid: error: {scene}: presence.components.a.sd_x = -0.3: must be > 0 (m)"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("layers, message", [
    (("presence", "presence"), "{scene}: a presence scene ([array]) has no grid layers; only `bananagrid run` takes it"),
    (("a", "b"), "--reference a: no such layer in {scene} (layers: presence)"),
])
def test_compare_refuses_a_presence_scene_in_one_line(tmp_path, capsys, layers, message):
    argv = ["compare", str(SCENES["line_section4"]), "--reference", layers[0], "--model", layers[1],
            "--out", str(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["bananagrid: error: " + message.format(scene=SCENES["line_section4"])]


def test_failure_leaves_no_file(tmp_path, capsys, monkeypatch):
    def fail(*args, **kwargs):
        raise bg.BananagridError("drawing failed")

    monkeypatch.setattr(run_cells, "log_cell_map", fail)
    out = tmp_path / "out"
    assert main(["run", str(SCENES["line_section4"]), "--out", str(out), "--npz"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == "bananagrid: error: drawing failed"
    assert sorted(p.name for p in out.iterdir()) == []  # no .rrd, .npz or .partial


def test_failure_while_exporting_leaves_no_file(tmp_path, capsys, monkeypatch):
    def half_written(path, scene, cm):
        path.write_bytes(b"PK half an archive")
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(run_cells, "_write_npz", half_written)
    out = tmp_path / "out"
    assert main(["run", str(SCENES["line_section4"]), "--out", str(out), "--npz", "--quiet"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"bananagrid: error: {out / 'line_section4.npz'}: cannot write the .npz arrays (No space left on device)")
    assert sorted(p.name for p in out.iterdir()) == []


# --- one registry, a domain per kind ----------------------------------------------------------------

GRID_SCENE = """\
[scene]
name = "g"

[grid]
x = [0.0, 10.0]
y = [0.0, 10.0]
step = 1.0

[layers.a]
model = "mixture"
"""


def test_a_presence_kind_is_no_grid_layer():
    """The registry holds the presence laws as kinds of the array domain: [presence] takes them,
    a grid scene's layers do not (and name the grid kinds)."""
    assert [name for name, kind in bg.MODEL_KINDS.items() if kind.domain == "array"] == ["mixture", "uniform"]
    with pytest.raises(bg.BananagridError) as info:
        parse_scene(GRID_SCENE, source="g.toml")
    assert str(info.value) == 'g.toml: layers.a.model = "mixture": must be one of "cat", "polar", "bearing_fix", "butterly"'


@pytest.mark.parametrize("name", sorted(SCENES))
def test_an_array_scene_runs_its_layer_through_rasterise(name):
    """The one runner's array job is ``rasterise`` of the scene's layer on its lattice, conditioned
    on its room: the same cells as the law's own ``cell_probabilities``, bit for bit."""
    scene = load_scene(SCENES[name])
    ((layer, t),) = scene.jobs()
    cells = bg.rasterise(layer.model(t), scene.domain, region=scene.region)
    np.testing.assert_array_equal(cells.prob, bg.cell_probabilities(law(scene), scene.domain, scene.region).prob)
