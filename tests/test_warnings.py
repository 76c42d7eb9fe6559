"""The Python API speaks like the command line: the likely mistakes the CLI warns about (degrees
typed as radians, a heading beyond a turn, a grid that misses the target) warn in Python too,
every warning of the package is a ``bg.BananagridWarning`` (never a plain ``UserWarning``), and
``warnings.simplefilter("error", bg.BananagridWarning)`` turns each into an error. An ``[array]``
scene asked for grid exports is refused before any kernel is compiled or launched."""

from __future__ import annotations

import ast
import math
import warnings
from pathlib import Path

import pytest

import bananagrid as bg
from bananagrid.cli import main
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.scenes.examples import example_path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = [*sorted((ROOT / "bananagrid").rglob("*.py")), *sorted((ROOT / "kernels").rglob("*.py"))]


def _warn_calls(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            if (isinstance(func, ast.Attribute) and func.attr == "warn" and isinstance(func.value, ast.Name)
                    and func.value.id == "warnings") or (isinstance(func, ast.Name) and func.id == "warn"):
                yield node


def test_every_warning_of_the_package_is_a_bananagrid_warning():
    """Each ``warnings.warn`` call names the category BananagridWarning (second argument or
    ``category=``): a plain UserWarning could not be filtered as the project's."""
    plain, calls = [], 0
    for path in PACKAGE:
        if path.is_symlink() or "kernels" in path.parts and (ROOT / "bananagrid" / "kernels") in path.parents:
            continue  # bananagrid/kernels links to kernels/: read once
        for call in _warn_calls(ast.parse(path.read_text(), str(path))):
            calls += 1
            category = call.args[1] if len(call.args) > 1 else next(
                (k.value for k in call.keywords if k.arg == "category"), None)
            if not (isinstance(category, ast.Name) and category.id == "BananagridWarning"):
                plain.append(f"{path.relative_to(ROOT)}:{call.lineno}")
    assert calls >= 15  # the audit saw the calls there are (15 when it was written)
    assert plain == []


def _cat(**changes):
    return bg.CAT(**{"v0": 280.0, "t": 10.0, "sigma_a": 5 / 3, "sigma_omega": math.pi / 54, **changes})


def _bearings_in_turns():
    # a target at (500, 1000) seen from (0, 0) and (1000, 0); the first bearing a turn too far
    first, second = math.atan2(500.0, 1000.0), math.atan2(-500.0, 1000.0) % (2.0 * math.pi)
    return bg.BearingFix(sensors=[(0.0, 0.0), (1000.0, 0.0)], bearings=[first + 2.0 * math.pi, second],
                         sigmas=[0.01, 0.01])


def _grid_that_misses():
    # the banana lies 2.8 km up the y axis; this grid holds the origin only
    return bg.rasterise(_cat(), bg.Grid.from_bounds(x=(-100.0, 100.0), y=(-100.0, 100.0), step=10.0))


#: Each likely mistake, what Python does with it, and the words of its warning.
MISTAKES = {
    "turn rate in degrees": (lambda: _cat(sigma_omega=5.0),
                             r"CAT: sigma_omega = 5 rad/s turns more than a full turn in t = 10 s .*were degrees meant\?"),
    "heading in degrees": (lambda: bg.Pose(heading=90.0), r"Pose: heading = 90 rad is more than a full turn"),
    "heading error in degrees": (lambda: _cat(sigma_heading=10.0), r"CAT: sigma_heading = 10 rad is more than a full turn"),
    "bearing beyond a turn": (_bearings_in_turns, r"BearingFix: bearings = \[6.7468\d*, 5.8195\d*\] rad is more than a full turn"),
    "bearings that cross poorly": (
        lambda: bg.BearingFix(sensors=[(0.0, 0.0), (1000.0, 0.0)], sigmas=[0.01, 0.01],
                              bearings=[math.atan2(500.0, 5000.0), math.atan2(-500.0, 5000.0) % (2.0 * math.pi)]),
        r"bearings cross at 11.4 deg \(< 20.0 deg\): the linearised covariance and containment are optimistic"),
    "a grid that misses the target": (_grid_that_misses,
                                      r"rasterise: the grid captured .* of CAT's probability \(below 0.99\): it misses part"),
}


@pytest.mark.parametrize("name", list(MISTAKES))
def test_each_mistake_warns_in_python(name):
    make, words = MISTAKES[name]
    with pytest.warns(bg.BananagridWarning, match=words) as caught:
        make()
    ours = [w for w in caught if issubclass(w.category, bg.BananagridWarning)]
    assert len(ours) == 1, [str(w.message) for w in ours]  # said once
    assert ours[0].filename == __file__  # pointing at the caller's line, not the package's


@pytest.mark.parametrize("name", list(MISTAKES))
def test_each_mistake_is_an_error_when_asked(name):
    make, words = MISTAKES[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error", bg.BananagridWarning)
        with pytest.raises(bg.BananagridWarning, match=words):
            make()


def test_plausible_values_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error", bg.BananagridWarning)
        _cat(sigma_omega=0.5, sigma_heading=0.3)  # 0.5 rad/s over 10 s: 5 rad, less than a turn
        bg.Pose(heading=-2.0 * math.pi)  # a full turn exactly is a heading still
        bg.rasterise(_cat(), bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=50.0))  # the docs' grid
        bg.rasterise(_cat(), bg.Grid.from_bounds(x=(-100.0, 100.0), y=(-100.0, 100.0), step=10.0), min_mass=0.0)


@pytest.mark.parametrize("value", [1.5, -0.1, math.nan, True, "0.9"])
def test_bad_min_mass_before_computing(no_kernels, value):
    with pytest.raises(bg.BananagridError, match=r"min_mass = .*: must be a number in \[0, 1\]"):
        bg.rasterise(_cat(), bg.Grid.from_bounds(x=(-100.0, 100.0), y=(-100.0, 100.0), step=10.0), min_mass=value)


def test_a_scene_says_it_once_with_the_key():
    """A scene names the key and its _deg form; the model's own words are not repeated."""
    text = ('[scene]\nname = "s"\n[grid]\nx = [-100.0, 100.0]\ny = [-100.0, 100.0]\nstep = 10.0\n'
            '[layers.a]\nmodel = "cat"\nv0 = 5.0\nt = 10.0\nsigma_a = 1.0\nsigma_omega = 5.0\n')
    with pytest.warns(bg.BananagridWarning) as caught:
        scene = bg.parse_scene(text, source="s.toml")
        scene.layers[0].model()
    messages = [str(w.message) for w in caught if "degrees meant" in str(w.message)]
    assert messages == ["s.toml: layers.a.sigma_omega = 5.0 rad/s spreads over more than a full turn in t = 10 s "
                        "(2.86e+03 deg): were degrees meant? Give sigma_omega_deg for degrees/s"]


def test_presence_scene_step_warning_is_ours():
    scene = bg.load_scene(example_path("room_uniform"))
    with pytest.warns(bg.BananagridWarning, match="--step 5 does not apply to a presence scene"):
        scene.with_step(5.0)


# --- an [array] scene with grid exports: refused before any computing ---------------------------


@pytest.fixture
def no_kernels(monkeypatch):
    """Compiling or launching a kernel fails the test."""

    def refuse(*args, **kwargs):
        raise AssertionError("a kernel was compiled or launched before the refusal")

    monkeypatch.setattr(WarpContext, "launch", refuse)
    monkeypatch.setattr(WarpContext, "load", refuse)


@pytest.mark.parametrize("export", ["netcdf", "geotiff", "geojson"])
def test_array_scene_with_grid_exports_is_refused_before_computing(tmp_path, no_kernels, export):
    scene = bg.load_scene(example_path("room_uniform"))
    with pytest.raises(bg.BananagridError, match=rf"room_uniform.toml: --{export}: an \[array\] scene maps angular "
                                                 "cells, not a grid"):
        bg.run_scene(scene, tmp_path, **{export: True})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("option", [["--netcdf"], ["--geotiff"], ["--geojson"], ["--zarr", "X.zarr"]])
def test_cli_refuses_array_exports_in_one_line(tmp_path, capsys, no_kernels, option):
    out = tmp_path / "out"
    if option[0] == "--zarr":
        option = ["--zarr", str(tmp_path / "X.zarr")]
    assert main(["run", "--example", "room_uniform", "--out", str(out), *option]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bananagrid: error: ") and "not a grid" in err[0], err
    assert not out.exists() and not (tmp_path / "X.zarr").exists()
