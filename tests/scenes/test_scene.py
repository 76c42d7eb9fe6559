"""Scene files: valid scenes parse into the right grid and models; every bad key is named."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import bananagrid as bg
from bananagrid import CAT, BananagridError, PolarBanana
from bananagrid.contours import DEFAULT_MASS_LEVELS
from bananagrid.models.registry import installed_kinds
from bananagrid.scenes.load import Layer, load_scene, parse_scene

from cases import small_scene

#: The model kinds a scene may name, as its messages list them (from the registry).
KINDS_LISTED = ", ".join(f'"{kind}"' for kind in installed_kinds().on("grid"))  # the kinds a [layers] table takes

SCENES = Path(__file__).resolve().parents[2] / "scenes"

# A small valid scene; the error cases below edit one line of it each.
BASE = small_scene("demo", """\
[layers.exact]
model = "cat"

[layers.approx]
model = "polar"
variant = "rough"
""")


def edited(old: str, new: str, text: str = BASE) -> str:
    """``text`` with the one occurrence of ``old`` replaced by ``new``."""
    assert text.count(old) == 1, old
    return text.replace(old, new)


def error_of(text: str, source: str = "bad.toml") -> str:
    with pytest.raises(BananagridError) as info:
        parse_scene(text, source=source)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{source}: ")
    return message


# --- valid scenes -----------------------------------------------------------------------------


def test_base_scene_parses_with_defaults():
    scene = parse_scene(BASE)
    assert scene.name == "demo" and scene.title == "demo" and scene.description == ""
    assert scene.text == BASE and scene.source == "<string>"
    assert (scene.grid.nx, scene.grid.ny, scene.grid.dx) == (20, 20, 10.0)
    assert scene.grid.extent == (-100.0, 100.0, 0.0, 200.0)
    assert [layer.name for layer in scene.layers] == ["exact", "approx"]  # file order
    assert scene.times is None
    assert scene.levels == ()  # fixed-density contours only when asked for
    assert scene.mass_levels == DEFAULT_MASS_LEVELS and scene.min_mass == 0.99 and scene.warnings == ()
    assert (scene.normalise, scene.dtype, scene.colormap) == (True, "float64", "viridis")


def test_degrees_become_radians_and_layers_override_defaults():
    text = edited('variant = "rough"\n', 'variant = "rough"\nsigma_omega = 0.5\nheading_deg = 90\n'
                  "origin = [5.0, -7]\nv0 = 20\n")
    exact, approx = parse_scene(text).layers
    assert exact.params["sigma_omega"] == pytest.approx(math.radians(10.0), rel=1e-15)
    assert exact.params["v0"] == 10.0
    model = approx.model()
    assert isinstance(model, PolarBanana) and model.variant == "rough"
    assert (model.v0, model.sigma_omega) == (20.0, 0.5)
    assert model.pose.heading == pytest.approx(math.pi / 2, rel=1e-15)
    assert model.pose.origin == (5.0, -7.0)


def test_layer_model_at_another_time():
    layer = parse_scene(BASE).layers[0]
    assert isinstance(layer, Layer) and layer.kind == "cat"
    assert isinstance(layer.model(), CAT) and layer.model().t == 5.0
    assert layer.model(t=2.5).t == 2.5
    with pytest.raises(TypeError):
        layer.params["v0"] = 1.0  # params are read-only


def test_times_give_every_layer_every_time():
    text = edited('name = "demo"\n', 'name = "demo"\ntimes = [1, 2.5, 4]\n')
    scene = parse_scene(edited("t = 5.0\n", "", text))
    assert scene.times == (1.0, 2.5, 4.0)
    assert "t" not in scene.layers[0].params
    assert [(layer.name, t) for layer, t in scene.jobs()] == [
        ("exact", 1.0), ("approx", 1.0), ("exact", 2.5), ("approx", 2.5), ("exact", 4.0), ("approx", 4.0)
    ]
    with pytest.raises(BananagridError, match="no elapsed time t"):
        scene.layers[0].model()


def test_defaults_of_the_other_model_kind_are_ignored():
    text = edited("v0 = 10.0\n", 'v0 = 10.0\nk_sigma = 6\nvariant = "improved"\n')
    exact, approx = parse_scene(text).layers
    assert exact.params["k_sigma"] == 6.0 and "variant" not in exact.params
    assert approx.params["variant"] == "rough" and "k_sigma" not in approx.params


def test_output_table():
    text = BASE + '[output]\ncontour_levels = [1e-3, 1e-4]\nnormalise = false\ndtype = "float32"\ncolormap = "Turbo"\n'
    scene = parse_scene(text)
    assert scene.levels == (1e-3, 1e-4)
    assert (scene.normalise, scene.dtype, scene.colormap) == (False, "float32", "turbo")


def test_with_step_keeps_bounds():
    scene = parse_scene(BASE)
    coarse = scene.with_step(40.0)
    assert (coarse.grid.nx, coarse.grid.ny) == (5, 5)
    assert coarse.with_step(10.0).grid == scene.grid
    assert coarse.layers == scene.layers and coarse.text == scene.text
    with pytest.raises(BananagridError, match=r"step = -1.0: must be > 0"):
        scene.with_step(-1.0)


def test_rectangular_cells():
    scene = parse_scene(edited("step = 10.0\n", "dx = 10.0\ndy = 20.0\n"))
    assert (scene.grid.dx, scene.grid.dy, scene.grid.ny) == (10.0, 20.0, 10)


# the poor-crossing scene exists to show the optimistic-linearisation warning
@pytest.mark.filterwarnings("ignore:bearings cross at:UserWarning")
@pytest.mark.parametrize("path", sorted(SCENES.glob("*.toml")), ids=lambda p: p.name)
def test_bundled_scenes_load(path):
    scene = load_scene(path)
    assert scene.name == path.stem
    assert scene.source == str(path)
    for layer, t in scene.jobs():  # an [array] scene's one layer is its presence law

        layer.model(t)


def test_figure1_parameters():
    scene = load_scene(SCENES / "figure1.toml")
    assert [layer.name for layer in scene.layers] == ["cat", "rough", "improved"]
    model = scene.layers[0].model()
    assert (model.v0, model.t) == (280.0, 10.0)
    assert model.sigma_a == pytest.approx(5 / 3, rel=1e-15)
    assert model.sigma_omega == pytest.approx(math.pi / 54, rel=1e-15)
    assert (scene.grid.nx, scene.grid.ny, scene.grid.dx) == (1500, 900, 4.0)


# --- bad scenes: one case per kind of error, asserting the message -----------------------------

BAD = {
    "unknown top-level key": ("colour = 1\n" + BASE, ["colour: unknown key", "allowed: scene, grid"]),
    "unknown key in a layer": (
        edited('model = "cat"\n', 'model = "cat"\nsigma_omga = 1.0\n'),
        ["layers.exact.sigma_omga: unknown key", "sigma_omega_deg"],
    ),
    "key of the other model": (
        edited('variant = "rough"\n', 'variant = "rough"\nk_sigma = 6\n'),
        ['layers.approx.k_sigma: unknown key (model "polar")'],
    ),
    "unknown key in scene": (edited('name = "demo"\n', 'name = "demo"\nauthor = "me"\n'), ["scene.author: unknown key"]),
    "unknown key in grid": (edited("step = 10.0\n", "step = 10.0\nz = [0, 1]\n"), ["grid.z: unknown key"]),
    "unknown key in output": (BASE + "[output]\nlevels = [1e-6]\n", ["output.levels: unknown key", "contour_levels"]),
    "unknown key in defaults": (edited("v0 = 10.0\n", "v0 = 10.0\nspeed = 3\n"), ["defaults.speed: unknown key"]),
    "both sigma_omega forms": (
        edited('model = "cat"\n', 'model = "cat"\nsigma_omega = 0.1\nsigma_omega_deg = 5.0\n'),
        ["layers.exact: give sigma_omega (rad) or sigma_omega_deg (degrees), not both"],
    ),
    "both heading forms": (
        edited("v0 = 10.0\n", "v0 = 10.0\nheading = 0.1\nheading_deg = 5.0\n"),
        ["defaults: give heading (rad) or heading_deg (degrees), not both"],
    ),
    "negative parameter": (
        edited('model = "cat"\n', 'model = "cat"\nsigma_a = -1.0\n'),
        ["layers.exact.sigma_a = -1.0: must be > 0"],
    ),
    "zero parameter": (edited('variant = "rough"\n', 'variant = "rough"\nv0 = 0\n'), ["layers.approx.v0 = 0: must be > 0"]),
    "nan parameter": (edited('model = "cat"\n', 'model = "cat"\nt = nan\n'), ["layers.exact.t = nan: must be finite"]),
    "inf parameter in defaults": (
        edited("sigma_omega_deg = 10.0\n", "sigma_omega_deg = inf\n"),
        ["defaults.sigma_omega_deg = inf: must be finite"],
    ),
    "negative degrees": (
        edited("sigma_omega_deg = 10.0\n", "sigma_omega_deg = -10.0\n"),
        ["defaults.sigma_omega_deg = -10.0: must be > 0"],
    ),
    "string parameter": (edited("v0 = 10.0\n", 'v0 = "fast"\n'), ['defaults.v0 = "fast": expected a number']),
    "boolean parameter": (edited("v0 = 10.0\n", "v0 = true\n"), ["defaults.v0 = true: expected a number"]),
    "k_sigma out of range": (
        edited('model = "cat"\n', 'model = "cat"\nk_sigma = 40\n'),
        ["layers.exact.k_sigma = 40: must be in [1, 38]"],
    ),
    "unknown variant": (
        edited('variant = "rough"\n', 'variant = "smooth"\n'),
        ['layers.approx.variant = "smooth": must be one of "rough", "improved"'],
    ),
    "unknown variant in defaults": (
        edited("v0 = 10.0\n", 'v0 = 10.0\nvariant = "fine"\n'),
        ['defaults.variant = "fine": must be one of "exact", "improved", "linear", "rough"'],
    ),
    "non-finite heading": (
        edited('model = "cat"\n', 'model = "cat"\nheading_deg = nan\n'),
        ["layers.exact.heading_deg = nan: must be finite"],
    ),
    "bad origin": (
        edited('model = "cat"\n', 'model = "cat"\norigin = [1.0]\n'),
        ["layers.exact.origin = [1.0]: expected a pair of numbers"],
    ),
    "unknown model kind": (
        edited('model = "cat"\n', 'model = "ctrv"\n'),
        [f'layers.exact.model = "ctrv": must be one of {KINDS_LISTED}'],
    ),
    "missing model": (edited('model = "cat"\n', ""), [f'layers.exact.model missing: must be one of {KINDS_LISTED}']),
    "missing parameter": (
        edited("sigma_a = 1.0\n", ""),
        ["layers.exact: missing sigma_a: give each in [layers.exact] or [defaults]"],
    ),
    "t in a layer with scene.times": (
        edited('name = "demo"\n', 'name = "demo"\ntimes = [1, 2]\n', edited("t = 5.0\n", "", edited('model = "cat"\n', 'model = "cat"\nt = 3\n'))),
        ["layers.exact.t = 3: not allowed when scene.times is given"],
    ),
    "t in defaults with scene.times": (
        edited('name = "demo"\n', 'name = "demo"\ntimes = [1, 2]\n'),
        ["defaults.t = 5.0: not allowed when scene.times is given"],
    ),
    "times not increasing": (
        edited('name = "demo"\n', 'name = "demo"\ntimes = [1, 3, 3]\n', edited("t = 5.0\n", "")),
        ["scene.times = [1, 3, 3]: must be strictly increasing (3 then 3)"],
    ),
    "times decreasing": (
        edited('name = "demo"\n', 'name = "demo"\ntimes = [2.0, 1.0]\n', edited("t = 5.0\n", "")),
        ["scene.times = [2.0, 1.0]: must be strictly increasing"],
    ),
    "zero time": (
        edited('name = "demo"\n', 'name = "demo"\ntimes = [0, 1]\n', edited("t = 5.0\n", "")),
        ["scene.times[0] = 0: must be finite and > 0"],
    ),
    "empty times": (edited('name = "demo"\n', 'name = "demo"\ntimes = []\n'), ["scene.times = []: expected a non-empty list"]),
    "empty grid": (edited("x = [-100.0, 100.0]\n", "x = [50.0, 50.0]\n"), ["grid.x = (50.0, 50.0): the upper bound must exceed the lower"]),
    "reversed grid": (edited("y = [0.0, 200.0]\n", "y = [200.0, 0.0]\n"), ["grid.y = (200.0, 0.0)"]),
    "gigantic grid": (
        edited("x = [-100.0, 100.0]\n", "x = [-1e6, 1e6]\n", edited("y = [0.0, 200.0]\n", "y = [-1e6, 1e6]\n")),
        ["grid: grid of 200000 x 200000 = 40,000,000,000 cells would take 298.0 GiB as float64", "use a larger step"],
    ),
    "zero step": (edited("step = 10.0\n", "step = 0\n"), ["grid.step = 0.0: must be > 0"]),
    "missing step": (edited("step = 10.0\n", ""), ["grid: step (m) is required"]),
    "step and dx": (edited("step = 10.0\n", "step = 10.0\ndx = 5.0\n"), ["grid: give either step or both dx and dy"]),
    "non-finite bound": (edited("x = [-100.0, 100.0]\n", "x = [-inf, 100.0]\n"), ["grid.x[0] = -inf: must be finite"]),
    "missing grid": (BASE.replace("[grid]", "[grid_]"), ["grid_: unknown key"]),
    "missing scene name": (edited('name = "demo"\n', 'title = "x"\n'), ["scene.name: missing"]),
    "bad scene name": (edited('name = "demo"\n', 'name = "my demo"\n'), ['scene.name = "my demo": expected a name of letters, digits, _ and -']),
    "bad layer name": (edited("[layers.exact]", '[layers."a/b"]'), ['layers."a/b": a layer name must be letters, digits, _ and -']),
    "no layers": (BASE.split("[layers.exact]")[0], ["[layers]: missing table"]),
    "layer not a table": (
        edited('[layers.exact]\nmodel = "cat"\n', "[layers]\nexact = 1\n"),
        ["layers.exact = 1: expected a table [layers.exact]"],
    ),
    "bad level": (BASE + "[output]\ncontour_levels = [1e-6, -1]\n", ["output.contour_levels[1] = -1: must be finite and > 0"]),
    "bad dtype": (BASE + '[output]\ndtype = "float16"\n', ['output.dtype = "float16": must be one of "float64", "float32"']),
    "bad colormap": (BASE + '[output]\ncolormap = "jet"\n', ['output.colormap = "jet": must be one of', "viridis"]),
    "bad normalise": (BASE + '[output]\nnormalise = "yes"\n', ['output.normalise = "yes": expected true or false']),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_scene_is_named(case):
    text, expected = BAD[case]
    message = error_of(text)
    for part in expected:
        assert part in message, f"{part!r} not in {message!r}"


def test_toml_syntax_error_gives_line_and_column():
    message = error_of(edited("step = 10.0\n", "step = \n"))
    assert "bad.toml: invalid TOML:" in message
    assert "(at line 7, column 8)" in message


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere.toml"
    with pytest.raises(BananagridError, match=r"nowhere\.toml: no such scene file"):
        load_scene(path)


def test_directory_is_not_a_scene(tmp_path):
    with pytest.raises(BananagridError, match="is a directory"):
        load_scene(tmp_path)


def test_file_errors_name_the_file(tmp_path):
    path = tmp_path / "neg.toml"
    path.write_text(edited('model = "cat"\n', 'model = "cat"\nsigma_a = -1.0\n'))
    with pytest.raises(BananagridError) as info:
        load_scene(path)
    assert str(info.value) == f"{path}: layers.exact.sigma_a = -1.0: must be > 0"


# --- the schema document -----------------------------------------------------------------------

DOC = SCENES.parent / "docs" / "scenes.md"


def test_docs_name_every_key_and_the_example_parses():
    from bananagrid.scenes.load import GRID_KEYS, OUTPUT_KEYS, PARAMETER_KEYS, RADIAL_KEYS, SCENE_KEYS, TOP_KEYS

    doc = DOC.read_text()
    assert not [table for table in TOP_KEYS if f"`[{table}" not in doc and f"`[[{table}" not in doc]
    keys = {*SCENE_KEYS, *GRID_KEYS, *OUTPUT_KEYS, *RADIAL_KEYS, "model"}
    keys.update(option for kind in bg.MODEL_KINDS.values() for option in kind.scene.options)
    keys.update(k for kind in PARAMETER_KEYS.values() for k in kind)
    assert not [key for key in sorted(keys) if f"`{key}`" not in doc]
    example = doc.split("## Example")[1].split("```toml\n")[1].split("```")[0]
    scene = parse_scene(example, source="docs/scenes.md")
    assert [layer.name for layer in scene.layers] == ["west", "east"] and len(scene.jobs()) == 6


# --- heading noise and radial curves --------------------------------------------------------


def test_heading_keys_parse_into_models():
    text = edited('model = "cat"\n', 'model = "cat"\nsigma_heading_deg = 5.0\n')
    text = edited('variant = "rough"\n', 'variant = "rough"\nsigma_heading = 0.1\nheading_order = 4\n', text)
    scene = parse_scene(text)
    exact, approx = (layer.model() for layer in scene.layers)
    assert isinstance(exact, CAT) and exact.sigma_heading == pytest.approx(math.radians(5.0), rel=1e-15)
    assert isinstance(approx, PolarBanana) and approx.sigma_heading == 0.1 and approx.heading_order == 4


def test_bad_heading_keys_are_named():
    message = error_of(edited('model = "cat"\n', 'model = "cat"\nsigma_heading_deg = -2\n'))
    assert message == "bad.toml: layers.exact.sigma_heading_deg = -2: must be >= 0"
    message = error_of(edited('model = "cat"\n', 'model = "cat"\nheading_order = 4\n'))
    assert message.startswith('bad.toml: layers.exact.heading_order: unknown key (model "cat")')
    message = error_of(edited('variant = "rough"\n', 'variant = "rough"\nheading_order = 3\n'))
    assert message.startswith("bad.toml: layers.approx.heading_order = 3: must be 2")


def test_radial_table_parses():
    scene = parse_scene(BASE + '\n[radial]\nlayers = ["exact"]\ndensity_bearings_deg = [0.0, 30.0]\nmoments_max_deg = 60\n')
    spec = scene.radial
    assert spec.layers == ("exact",) and spec.density_bearings == (0.0, math.radians(30.0))
    assert spec.moments_max == math.radians(60.0) and spec.moments_step == math.radians(2.0)
    assert parse_scene(BASE).radial is None
    assert parse_scene(BASE + "\n[radial]\nmoments_max_deg = 10\n").radial.layers == ("exact", "approx")


@pytest.mark.parametrize("body, message", [
    ('layers = ["nope"]\nmoments_max_deg = 10', 'radial.layers[0] = "nope": not a cat or polar layer of this scene'),
    ("density_bearings_deg = [200.0]", "radial.density_bearings_deg[0] = 200.0: must be in (-180, 180] degrees"),
    ("moments_max_deg = -1", "radial.moments_max_deg = -1: must be in [0, 180] degrees"),
    ("moments_max_deg = 10\nmoments_step_deg = 0", "radial.moments_step_deg = 0: must be in (0, 90] degrees"),
    ("layers = []", "radial.layers = []: expected a non-empty list"),
    ("", "radial: give density_bearings_deg or moments_max_deg"),
    ("colour = 1", "radial.colour: unknown key"),
])
def test_bad_radial_keys_are_named(body, message):
    assert message in error_of(BASE + f"\n[radial]\n{body}\n")


# --- Butterly layers -------------------------------------------------------------------------

BUTTERLY = BASE + """
[layers.sub]
model = "butterly"
mean = [10.0, 50.0]
sigma_x = 40.0
sigma_y = 20.0
rho = 0.5
speeds_kn = [5.0, 10.0]
weights = [0.25, 0.75]
course_mean_deg = 90.0
course_kappa = 2.0
"""


def test_butterly_layer_parses_into_the_model():
    """Knots become m/s (1 kn = 1852 m / 3600 s), sigma_x, sigma_y and rho the covariance,
    degrees radians; the layer takes the defaults' t (5 s) and follows scene.times."""
    from bananagrid import Butterly

    layer = parse_scene(BUTTERLY).layers[2]
    model = layer.model()
    assert isinstance(model, Butterly) and model.t == 5.0
    np.testing.assert_allclose(model.speeds, [5.0 * 1852 / 3600, 10.0 * 1852 / 3600], rtol=1e-15)
    np.testing.assert_array_equal(model.cov, [[1600.0, 400.0], [400.0, 400.0]])
    assert model.mean == (10.0, 50.0) and model.weights.tolist() == [0.25, 0.75]
    assert model.course_mean == pytest.approx(math.pi / 2) and model.course_kappa == 2.0
    timed = parse_scene(edited('name = "demo"\n', 'name = "demo"\ntimes = [60, 120]\n', edited("t = 5.0\n", "", BUTTERLY)))
    assert [(layer.name, t) for layer, t in timed.jobs()][-1] == ("sub", 120.0)
    assert timed.layers[2].model(120.0).ranges[1] == pytest.approx(120.0 * 10.0 * 1852 / 3600)


def test_butterly_cov_and_continuous_speed_laws_parse():
    from bananagrid.models.butterly import NormalSpeed, TabulatedSpeed, UniformSpeed

    start = 'mean = [10.0, 50.0]\nsigma_x = 40.0\nsigma_y = 20.0\nrho = 0.5\n'
    cases = {
        'cov = [[1600.0, 400.0], [400.0, 400.0]]\n': None,
        'speed_law = "uniform"\nspeed_min_kn = 4\nspeed_max = 6.0\n': UniformSpeed(4 * 1852 / 3600, 6.0),
        'speed_law = "normal"\nspeed_mean = 5.0\nspeed_sd_kn = 1.0\n': NormalSpeed(5.0, 1852 / 3600),
        'speed_law = "table"\nspeeds = [1.0, 2.0, 4.0]\nspeed_density = [0.0, 1.0, 0.5]\n': "table",
    }
    for body, law in cases.items():
        text = BUTTERLY.replace("speeds_kn = [5.0, 10.0]\nweights = [0.25, 0.75]\n", body if law else "speeds = [1.0]\n")
        if law is None:
            text = text.replace(start, "mean = [10.0, 50.0]\n" + body)
        model = parse_scene(text).layers[2].model()
        np.testing.assert_array_equal(model.cov, [[1600.0, 400.0], [400.0, 400.0]])
        if law == "table":
            assert isinstance(model.speeds, TabulatedSpeed) and model.speeds.speeds.tolist() == [1.0, 2.0, 4.0]
        elif law is not None:
            assert model.speeds == law


BAD_BUTTERLY = {
    "rho out of range": (("rho = 0.5", "rho = 1.0"), "layers.sub.rho = 1.0: must be in (-1, 1)"),
    "negative sigma": (("sigma_x = 40.0", "sigma_x = -40.0"), "layers.sub.sigma_x = -40.0: must be finite and > 0"),
    # sigmas of very different size: the covariance they give is singular in float64, named by them
    "sigmas too far apart": (("sigma_x = 40.0", "sigma_x = 4.0e18"),
                             ("layers.sub.sigma_x = 4e+18: with sigma_y = 20.0 and rho = 0.5, the start's covariance [[sx^2, rho sx sy], "
                              "[rho sx sy, sy^2]] must be positive definite")),
    "negative speed in knots": (("speeds_kn = [5.0, 10.0]", "speeds_kn = [5.0, -10.0]"), "layers.sub.speeds_kn[1] = -10.0: must be >= 0"),
    "weights not summing to 1": (("weights = [0.25, 0.75]", "weights = [0.25, 0.5]"), "layers.sub.weights = [0.25, 0.5]: must sum to 1"),
    "weights missing": (("weights = [0.25, 0.75]\n", ""), "layers.sub: weights: required for 2 speeds"),
    "speeds missing": (("speeds_kn = [5.0, 10.0]\n", ""), "layers.sub: missing speeds (or speeds_kn): give each in [layers.sub] or [defaults]"),
    "no start covariance": (("sigma_x = 40.0\nsigma_y = 20.0\nrho = 0.5\n", ""), "layers.sub: missing cov (or sigma_x and sigma_y)"),
    "sigma_y missing": (("sigma_y = 20.0\n", ""), "layers.sub: missing sigma_y"),
    "cov and sigmas": (("rho = 0.5", "rho = 0.5\ncov = [[1.0, 0.0], [0.0, 1.0]]"), "layers.sub: give cov or sigma_x, sigma_y (and rho), not both"),
    "cov not symmetric": (("sigma_x = 40.0\nsigma_y = 20.0\nrho = 0.5\n", "cov = [[4.0, 1.0], [2.0, 9.0]]\n"), "layers.sub.cov = [[4.0, 1.0], [2.0, 9.0]]: must be symmetric"),
    "cov not positive definite": (("sigma_x = 40.0\nsigma_y = 20.0\nrho = 0.5\n", "cov = [[4.0, 6.0], [6.0, 9.0]]\n"), "layers.sub.cov = [[4.0, 6.0], [6.0, 9.0]]: must be positive definite"),
    "cov not 2 x 2": (("sigma_x = 40.0\nsigma_y = 20.0\nrho = 0.5\n", "cov = [1.0, 2.0]\n"), "layers.sub.cov = [1.0, 2.0]: expected a 2 x 2 array"),
    "bad mean": (("mean = [10.0, 50.0]", "mean = [10.0]"), "layers.sub.mean = [10.0]: expected a pair of numbers"),
    "speeds and knots": (("speeds_kn = [5.0, 10.0]", "speeds_kn = [5.0, 10.0]\nspeeds = [1.0, 2.0]"), "layers.sub: give speeds (m/s) or speeds_kn (knots), not both"),
    "unknown speed law": (("rho = 0.5", 'rho = 0.5\nspeed_law = "gamma"'), 'layers.sub.speed_law = "gamma": must be one of "discrete", "uniform", "normal", "table"'),
    "key of another speed law": (("rho = 0.5", "rho = 0.5\nspeed_sd = 1.0"), 'layers.sub.speed_sd = 1.0: only with speed_law = "normal" (this layer\'s is "discrete")'),
    "uniform law upside down": (
        ("speeds_kn = [5.0, 10.0]\nweights = [0.25, 0.75]", 'speed_law = "uniform"\nspeed_min = 6.0\nspeed_max = 2.0'),
        "layers.sub.speed_max = 2.0: must be > v_min = 6.0",
    ),
    "negative kappa": (("course_kappa = 2.0", "course_kappa = -2.0"), "layers.sub.course_kappa = -2.0: must be >= 0"),
    "both course forms": (("course_kappa = 2.0", "course_kappa = 2.0\ncourse_mean = 1.0"), "layers.sub: give course_mean (rad) or course_mean_deg (degrees), not both"),
    "negative time": (("rho = 0.5", "rho = 0.5\nt = -1.0"), "layers.sub.t = -1.0: must be >= 0"),
    "motion key": (("rho = 0.5", "rho = 0.5\nheading = 1.0"), 'layers.sub.heading: unknown key (model "butterly")'),
}


@pytest.mark.parametrize("case", list(BAD_BUTTERLY), ids=list(BAD_BUTTERLY))
def test_bad_butterly_keys_are_named(case):
    (old, new), expected = BAD_BUTTERLY[case]
    message = error_of(edited(old, new, BUTTERLY))
    assert expected in message, message


def test_butterly_t_with_scene_times_is_refused():
    text = edited('name = "demo"\n', 'name = "demo"\ntimes = [1, 2]\n', edited("t = 5.0\n", "", edited("rho = 0.5", "rho = 0.5\nt = 3", BUTTERLY)))
    assert "layers.sub.t = 3: not allowed when scene.times is given" in error_of(text)


def test_butterly_is_not_a_radial_layer():
    message = error_of(BUTTERLY + '\n[radial]\nlayers = ["sub"]\nmoments_max_deg = 10\n')
    assert 'radial.layers[0] = "sub": not a cat or polar layer of this scene' in message


# --- extremes that used to end in tracebacks ----------------------------------------------------

def test_deeply_nested_arrays_are_invalid_toml():
    """tomllib parses nested arrays recursively: a RecursionError became a one-line error."""
    message = error_of('[scene]\nname = "deep"\n[grid]\nx = ' + "[" * 3000 + "]" * 3000 + "\n")
    assert message == "bad.toml: invalid TOML: arrays or tables nested too deeply"


@pytest.mark.parametrize("old, new, key", [
    ("t = 5.0\n", "t = 1e10\n", "defaults.t = 10000000000.0"),
    ('name = "demo"\n', 'name = "demo"\ntimes = [1.0, 1e10]\n', "scene.times[1] = 10000000000.0"),
])
def test_elapsed_times_beyond_the_timeline_are_refused(old, new, key):
    """A recording's elapsed timeline counts nanoseconds in 64 bits (9.2e9 s); beyond, the
    recording's time conversion overflowed after all the computing."""
    text = edited(old, new)
    if "times" in new:
        text = text.replace("\nt = ", "\n# t = ")  # scene.times replaces defaults.t
    message = error_of(text)
    assert f"{key}: must be below 9.22e+09 s" in message, message
