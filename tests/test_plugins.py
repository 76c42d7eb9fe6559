"""Models from other packages: a model registered by an entry point of the group
``bananagrid.models`` runs from scenes and the command line, and a broken registration is one
line naming its entry point.

``tests/plugins`` is such a package, installed by being on the path: ``bananagrid_cv`` (a
constant-velocity target, N(mean + v t, cov + q t I)) with its distribution's metadata
(``bananagrid_cv-0.1.dist-info``: METADATA and entry_points.txt), which ``importlib.metadata``
finds on ``sys.path``. It is put on the path of the processes that use it only, so that no other
test sees it.
"""

import os
import re
import subprocess
import sys
import warnings
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import bananagrid as bg
from bananagrid.models.registry import ENTRY_POINT_GROUP, MODEL_KINDS, installed_kinds, kinds_from_entry_points
from bananagrid.scenes.load import parse_scene

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = Path(__file__).resolve().parent / "plugins"

MEAN, COV, VELOCITY, Q, T = (0.0, 0.0), [[40000.0, 10000.0], [10000.0, 22500.0]], (8.0, 4.0), 50.0, 120.0

SCENE = f"""
[scene]
name = "cv"

[grid]
x = [-1000.0, 3000.0]
y = [-1500.0, 2500.0]
step = 50.0

[output]
normalise = false

[layers.target]
model = "cv"
mean = [{MEAN[0]}, {MEAN[1]}]
cov = {COV}
velocity = [{VELOCITY[0]}, {VELOCITY[1]}]
q = {Q}
t = {T}
"""


def _cli(*args, path=PLUGINS, cwd=ROOT):
    """``python -m bananagrid ARGS`` in a fresh process whose path holds ``path`` (a directory
    of installed distributions) and the checkout (the working directory)."""
    env = {**os.environ, "PYTHONPATH": str(path)}
    return subprocess.run([sys.executable, "-m", "bananagrid", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def test_the_plugin_is_its_model_file_its_kernel_file_and_its_registration():
    files = {p.relative_to(PLUGINS).as_posix() for p in PLUGINS.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    assert files == {
        "bananagrid_cv/model.py", "bananagrid_cv/kernels.py",
        "bananagrid_cv-0.1.dist-info/METADATA", "bananagrid_cv-0.1.dist-info/entry_points.txt",
    }
    # and nothing of the package names it
    named = [p for p in (ROOT / "bananagrid").rglob("*.py") if "bananagrid_cv" in p.read_text() or "ConstantVelocity" in p.read_text()]
    assert named == []
    # the plugin is not installed for the other tests: the default kinds do not hold it
    assert "cv" not in installed_kinds()


def test_bananagrid_run_runs_a_scene_of_an_entry_point_model(tmp_path):
    scene = tmp_path / "cv.toml"
    scene.write_text(SCENE)
    run = _cli("run", scene, "--out", tmp_path, "--npz", "--quiet")
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "cv.rrd").is_file()
    with np.load(tmp_path / "cv.npz") as arrays:
        x, y, values = arrays["x"], arrays["y"], arrays[[k for k in arrays.files if k.startswith("target__")][0]]
    # the closed form: N(mean + v t, cov + q t I), by SciPy
    law = stats.multivariate_normal(np.add(MEAN, np.multiply(VELOCITY, T)), np.add(COV, Q * T * np.eye(2)))
    expected = law.pdf(np.stack(np.meshgrid(x, y), axis=-1))
    # float64 kernel: the exponent (<= 80 on this grid) carries a few ulps, which exp turns into
    # a relative 80 * 1e-15; 1e-11 leaves room
    np.testing.assert_allclose(values, expected, rtol=1e-11, atol=0.0)
    # the recording reads back with the layer's density
    info = _cli("inspect", tmp_path / "cv.rrd")
    assert info.returncode == 0, info.stderr
    assert "/layers/target/density" in info.stdout


def test_an_entry_point_model_runs_through_the_model_protocol_in_process(monkeypatch):
    """Found on the path like any installed distribution: its kind loads, its scene parses and
    its pdf matches its own samples' law."""
    monkeypatch.syspath_prepend(str(PLUGINS))
    installed_kinds.cache_clear()
    try:
        kinds = installed_kinds()
        assert list(kinds)[:len(MODEL_KINDS)] == list(MODEL_KINDS) and "cv" in kinds
        scene = parse_scene(SCENE, source="cv.toml")
        model = scene.layers[0].model()
        mu, cov = model.law
        points = model.sample(200, np.random.default_rng(5))
        # the kernels against SciPy at the model's own samples (float64: as above)
        np.testing.assert_allclose(model.pdf(points[:, 0], points[:, 1]), stats.multivariate_normal(mu, cov).pdf(points),
                                   rtol=1e-11)
        assert model.parameters()["velocity_x"] == VELOCITY[0]
        with pytest.raises(bg.BananagridError, match=r"^cv.toml: layers.target.q = -1.0: must be >= 0$"):
            parse_scene(SCENE.replace(f"q = {Q}", "q = -1.0"), source="cv.toml")
    finally:
        installed_kinds.cache_clear()


class NoScene:
    kind = "sc"


def _entry(name: str, value: str) -> metadata.EntryPoint:
    return metadata.EntryPoint(name=name, value=value, group=ENTRY_POINT_GROUP)


#: Broken registrations: (entry point name, value, what its one line says after naming it).
BROKEN = {
    "import error": ("ghost", "bananagrid_no_such_package.model:Ghost",
                     r"cannot be loaded: ModuleNotFoundError: No module named 'bananagrid_no_such_package'"),
    "not a class": ("pi", "math:pi", r"not a model class or ModelKind but float 3.14"),
    "class without a scene": ("sc", "test_plugins:NoScene", r"not a model class: model kind 'sc': NoScene.scene is not a SceneSchema$"),
    "class without kind": ("fraction", "fractions:Fraction", r"not a model class: Fraction has no kind \(its scene name\)$"),
    "name is not its kind": ("normal", "isotropic_model:IsotropicNormal",
                             r"its model's kind is 'isotropic'; the entry point must be named so"),
    "duplicate kind": ("cat", "bananagrid.models.cat:CAT", r"model kind 'cat' is already registered by this package; left out"),
}


@pytest.mark.parametrize("case", BROKEN)
def test_a_broken_registration_is_one_line_naming_its_entry_point(case):
    name, value, reason = BROKEN[case]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        kinds = kinds_from_entry_points(MODEL_KINDS, [_entry(name, value)])
    (warning,) = caught
    message = str(warning.message)
    assert warning.category is bg.BananagridWarning and "\n" not in message
    assert message.startswith(f"entry point {name} = {value!r} ({ENTRY_POINT_GROUP})")
    assert re.search(reason, message), message
    assert list(kinds) == list(MODEL_KINDS) and kinds["cat"] is MODEL_KINDS["cat"]  # the others unchanged
    if case != "duplicate kind":  # a scene that asks for it gets the same line as its error
        text = SCENE.replace('model = "cv"', f'model = "{name}"')
        with pytest.raises(bg.BananagridError) as error:
            parse_scene(text, source="s.toml", kinds=kinds)
        assert str(error.value) == f's.toml: layers.target.model = "{name}": {message}'


def test_a_second_registration_of_a_kind_is_left_out():
    entries = [_entry("isotropic", "isotropic_model:IsotropicNormal"), _entry("isotropic", "isotropic_model:IsotropicNormal")]
    with pytest.warns(bg.BananagridWarning, match=r"model kind 'isotropic' is already registered by entry point isotropic"):
        kinds = kinds_from_entry_points(MODEL_KINDS, entries)
    assert list(kinds) == [*MODEL_KINDS, "isotropic"]


def test_the_command_line_says_a_broken_plugin_in_one_line(tmp_path):
    """A distribution whose entry point names a module it lacks: the run of a scene that uses it
    ends with one warning line and one error line, exit code 2, no traceback and no file."""
    info = tmp_path / "site" / "bananagrid_ghost-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: bananagrid-ghost\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[bananagrid.models]\ncv = bananagrid_ghost.model:Ghost\n")
    scene = tmp_path / "cv.toml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    run = _cli("run", scene, "--out", out, path=tmp_path / "site")
    assert run.returncode == 2
    lines = run.stderr.splitlines()
    origin = "entry point cv = 'bananagrid_ghost.model:Ghost' (bananagrid.models, distribution bananagrid-ghost 1.0)"
    reason = "cannot be loaded: ModuleNotFoundError: No module named 'bananagrid_ghost'"
    assert lines == [f"bananagrid: warning: {origin}: {reason}",
                     f'bananagrid: error: {scene}: layers.target.model = "cv": {origin}: {reason}'], run.stderr
    assert not out.exists() or not any(out.iterdir())
