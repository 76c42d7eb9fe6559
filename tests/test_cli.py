"""The command line end to end: scenes to recordings and arrays, one-line errors, no partial files."""

from __future__ import annotations

import json
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

import bananagrid
from bananagrid import rasterise
from bananagrid import cli
from bananagrid.cli import main
from bananagrid.models.registry import installed_kinds
from bananagrid.recording.inspect import inspect_recording, read_depth_image
from bananagrid.scenes.run import array_key, run_scene
from bananagrid.scenes.load import load_scene

from cases import small_scene

ROOT = Path(__file__).resolve().parent.parent
SCENES = sorted((ROOT / "scenes").glob("*.toml"))
RERUN = Path(sys.executable).parent / "rerun"

#: Coarse steps (m) for the end-to-end runs, so the whole file stays well under a minute.
QUICK_STEP = {
    "figure1": 40.0, "folding": 40.0, "sequence": 200.0,
    "bearing_coastal": 100.0, "bearing_poor_crossing": 400.0, "bearing_three_stations": 100.0,
    "figure8": 100.0, "ship_heading": 20.0,
    "submarine": 4000.0, "rice_isotropic": 20.0, "slow_contact": 200.0,
    "geo_ship": 200.0, "geo_bearing": 200.0, "fast_contact": 400.0,
    # about a CPU minute and a half at any step (its cell rule's sub-cells follow the start's SD)
    "submarine_barriers": 4000.0,
}
#: Presence scenes ([array]) have no grid: --step does not apply (it is ignored with a warning),
#: so they run at their own 1-degree lattices (about a second each) and get no --step here.
QUICK_STEP.update(room_mixture=None, room_uniform=None, room_frustum=None, line_section4=None)

SMALL = small_scene("small", """\
[layers.near]
model = "cat"
""")

# The second layer lies far outside the grid: it captures no mass, so normalising fails after
# the first layer has been computed and logged.
FAILS_MIDWAY = SMALL + """
[layers.far]
model = "polar"
origin = [1.0e6, 1.0e6]
"""


def write(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def error_line(capsys) -> str:
    """The single stderr line of a failed command (nothing else on stderr)."""
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("bananagrid: error: ")
    return err[0]


def rerun_cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([str(RERUN), *map(str, args)], capture_output=True, text=True, timeout=120)


# --- errors -----------------------------------------------------------------------------------


def test_bad_scene_exits_2_with_one_line(tmp_path, capsys):
    scene = write(tmp_path, SMALL.replace("sigma_a = 1.0", "sigma_a = -1.0"))
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out)]) == 2
    assert error_line(capsys) == f"bananagrid: error: {scene}: defaults.sigma_a = -1.0: must be > 0"
    assert not out.exists()  # scenes are checked before anything is created


def test_missing_scene_file(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml"), "--out", str(tmp_path)]) == 2
    assert "nope.toml: no such scene file" in error_line(capsys)


def test_toml_syntax_error(tmp_path, capsys):
    scene = write(tmp_path, SMALL.replace("step = 10.0", "step = "))
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 2
    assert "invalid TOML: Invalid value (at line 7, column 8)" in error_line(capsys)


@pytest.mark.parametrize("npz", [False, True], ids=["rrd", "rrd+npz"])
def test_failure_midway_leaves_no_file(tmp_path, capsys, npz):
    scene = write(tmp_path, FAILS_MIDWAY)
    out = tmp_path / "out"
    argv = ["run", str(scene), "--out", str(out), *(["--npz"] if npz else [])]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "[1/2] small: near t=5 s ..." in err  # the first layer ran
    assert err.strip().splitlines()[-1] == (
        f"bananagrid: error: {scene}: layers.far at t = 5 s: the grid captured no mass, so it "
        "cannot be normalised; move or enlarge the grid, or set output.normalise = false"
    )
    assert sorted(p.name for p in out.iterdir()) == []  # no .rrd, .npz or .partial


def test_bad_options(tmp_path, capsys):
    scene = write(tmp_path, SMALL)
    assert main(["run", str(scene), "--out", str(tmp_path), "--step", "-5"]) == 2
    assert error_line(capsys) == "bananagrid: error: --step = -5.0: must be > 0"
    assert main(["run", str(scene), "--out", str(scene)]) == 2
    assert error_line(capsys) == f"bananagrid: error: --out {scene}: exists and is not a directory"
    assert main(["run", str(scene), "--out", str(tmp_path), "--threads", "0"]) == 2
    assert error_line(capsys) == "bananagrid: error: --threads = 0: must be >= 1"
    assert main(["run", str(scene), "--bogus"]) == 2  # argparse usage error
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err
    assert main(["inspect", str(tmp_path / "missing.rrd")]) == 2
    assert "missing.rrd: no such file" in error_line(capsys)


def test_duplicate_scene_names(tmp_path, capsys):
    a, b = write(tmp_path, SMALL, "a.toml"), write(tmp_path, SMALL, "b.toml")
    assert main(["run", str(a), str(b), "--out", str(tmp_path / "out")]) == 2
    assert 'scene.name = "small" is also the name of' in error_line(capsys)


def test_error_as_subprocess(tmp_path):
    scene = write(tmp_path, SMALL.replace('model = "cat"', 'model = "banana"'))
    result = subprocess.run(
        [sys.executable, "-m", "bananagrid", "run", str(scene), "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f'bananagrid: error: {scene}: layers.near.model = "banana": must be one of '
        + ", ".join(f'"{kind}"' for kind in installed_kinds().on("grid"))
    ]
    assert result.stdout == ""


def test_run_as_subprocess(tmp_path):
    scene = write(tmp_path, SMALL)
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-m", "bananagrid", "run", str(scene), "--out", str(out), "--npz"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert f"wrote {out / 'small.rrd'}" in result.stdout.splitlines()
    assert f"wrote {out / 'small.npz'}" in result.stdout.splitlines()
    assert sorted(p.name for p in out.iterdir()) == ["small.npz", "small.rrd"]


def test_model_warning_is_one_line(tmp_path, capsys):
    # P_sigma (11) turns negative beyond |phi| = 0.5 sqrt(25/12 + 6) = 1.42 rad < pi: the
    # improved approximation warns (once, although the model is built twice).
    text = SMALL.replace('model = "cat"', 'model = "polar"').replace("sigma_a = 1.0", "sigma_a = 10.0")
    text = text.replace("sigma_omega_deg = 10.0", "sigma_omega = 0.5")
    scene = write(tmp_path, text)
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("bananagrid:")]
    # (the 200 m x 200 m grid also misses most of this fast target: one coverage line per time)
    model = [line for line in warnings if "the grid captured" not in line]
    assert model == [
        "bananagrid: warning: P_sigma (11) is not positive for |phi| > 1.422 rad; the improved density is 0 there"
    ]


# --- help and delegation ----------------------------------------------------------------------


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["inspect", "--help"]])
def test_help_exits_0(argv, capsys):
    assert main(argv) == 0
    assert "usage: bananagrid" in capsys.readouterr().out


def test_help_as_subprocess(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "bananagrid", "run", "--help"], capture_output=True, text=True, timeout=60,
        cwd=tmp_path,
    )
    assert result.returncode == 0
    assert "--npz" in result.stdout and "--step" in result.stdout


def test_bench_is_delegated_with_its_arguments(monkeypatch):
    import bananagrid.cli

    calls = []
    fake = types.ModuleType("bananagrid.bench.runner")
    fake.main = lambda argv: calls.append(argv) or 7
    monkeypatch.setattr(bananagrid.cli, "bench", fake)
    assert main(["bench", "--help"]) == 7
    assert main(["bench", "--size", "64", "extra"]) == 7
    assert calls == [["--help"], ["--size", "64", "extra"]]


def test_bench_help(capsys):
    assert main(["bench", "--help"]) == 0


# --- scenes end to end ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def quick_runs(tmp_path_factory) -> dict[str, Path]:
    """Every bundled scene run once by the CLI at its coarse step: {scene name: out dir}."""
    runs = {}
    for path in SCENES:
        name = path.stem
        out = tmp_path_factory.mktemp(name)
        step = QUICK_STEP.get(name, 100.0)
        argv = ["run", str(path), "--out", str(out), *(["--step", str(step)] if step is not None else []), "--npz"]
        assert main(argv) == 0, name
        runs[name] = out
    return runs


def test_every_scene_has_a_quick_step():
    assert {p.stem for p in SCENES} <= set(QUICK_STEP)


# the poor-crossing scene exists to show the optimistic-linearisation warning
@pytest.mark.filterwarnings("ignore:bearings cross at:UserWarning")
@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_scene_runs_end_to_end(path, quick_runs):
    scene = load_scene(path)
    rrd = quick_runs[scene.name] / f"{scene.name}.rrd"
    verify = rerun_cli("rrd", "verify", rrd)
    assert verify.returncode == 0, verify.stderr
    info = inspect_recording(rrd)
    assert info["blueprint"]
    assert "/scene" in info["entities"]
    if not scene.gridded:  # one cell map, no grid layers (see test_presence_scene.py)
        for part in ("plane/cells", "plane/room", "table", "log10_table", "summary"):
            assert f"/presence/{part}" in info["entities"], part
        assert sorted(p.name for p in quick_runs[scene.name].iterdir()) == [f"{scene.name}.npz", f"{scene.name}.rrd"]
        return
    for layer in scene.layers:
        for part in ("density", "log10_density", "contours/lines", "contours/labels", "legend/colour_bar", "info", "mass"):
            assert f"/layers/{layer.name}/{part}" in info["entities"]
        masses = info["entities"][f"/layers/{layer.name}/mass"]["scalars"]
        assert len(masses) == len(scene.times or (1,))
    times = scene.times or sorted({t for _, t in scene.jobs()})
    # and a scene's evidence, each drawn from its own time on (land at every time)
    times = sorted({*times, *(e.span[0] for e in scene.evidence if e.span is not None)})
    assert info["timelines"]["elapsed"]["values"] == pytest.approx(list(times))
    assert sorted(p.name for p in quick_runs[scene.name].iterdir()) == [f"{scene.name}.npz", f"{scene.name}.rrd"]


def test_summary_and_progress(tmp_path, capsys):
    scene = write(tmp_path, SMALL.replace("t = 5.0", "t = 5.0\norigin = [0, 20]"))
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    assert "[1/1] small: near t=5 s ..." in captured.err
    lines = captured.out.splitlines()
    header = next(k for k, line in enumerate(lines) if line.startswith("scene"))
    assert lines[header].split("  ")[:2] == ["scene", "layer"]
    for column in ("t [s]", "cells", "captured mass", "peak", "50 % area", "99 % area", "seconds"):
        assert column in lines[header]
    assert "m^-2" in lines[header + 2]  # the peak carries its unit
    row = lines[header + 2].split()
    assert row[:4] == ["small", "near", "5", "400"]
    assert f"wrote {tmp_path / 'out' / 'small.rrd'}" in lines
    assert main(["run", str(scene), "--out", str(tmp_path / "quiet"), "--quiet"]) == 0
    assert "[1/1]" not in capsys.readouterr().err


def test_same_scene_twice_gives_equal_recordings(tmp_path, quick_runs):
    out = tmp_path / "again"
    scene = ROOT / "scenes" / "figure1.toml"
    argv = ["run", str(scene), "--out", str(out), "--step", str(QUICK_STEP["figure1"]), "--quiet"]
    assert main(argv) == 0
    compare = rerun_cli("rrd", "compare", quick_runs["figure1"] / "figure1.rrd", out / "figure1.rrd")
    assert compare.returncode == 0, compare.stdout + compare.stderr


def test_recordings_do_not_depend_on_timing(tmp_path):
    """Two runs at full size at once (so that their logging takes seconds and interleaves
    differently): equal under rerun rrd compare. rerun's default batcher cut chunks on a 200 ms
    clock tick, and these two scenes then differed in chunk order and count."""
    scenes = [str(ROOT / "scenes" / f"{name}.toml") for name in ("figure1", "ship_heading")]
    runs = [subprocess.Popen([sys.executable, "-m", "bananagrid", "run", *scenes, "--out", str(tmp_path / d), "--quiet"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for d in ("a", "b")]
    for run in runs:
        out, err = run.communicate(timeout=600)
        assert run.returncode == 0, err
    for name in ("figure1", "ship_heading"):
        compare = rerun_cli("rrd", "compare", tmp_path / "a" / f"{name}.rrd", tmp_path / "b" / f"{name}.rrd")
        assert compare.returncode == 0, compare.stdout + compare.stderr


@pytest.mark.parametrize("name", ["figure1", "sequence"])
def test_npz_holds_the_rasters(name, quick_runs):
    scene = load_scene(ROOT / "scenes" / f"{name}.toml").with_step(QUICK_STEP[name])
    rrd, npz = (quick_runs[name] / f"{name}.{ext}" for ext in ("rrd", "npz"))
    with np.load(npz, allow_pickle=False) as arrays:
        provenance = json.loads(str(arrays["provenance"]))
        np.testing.assert_array_equal(arrays["x"], scene.grid.x)
        np.testing.assert_array_equal(arrays["y"], scene.grid.y)
        expected_keys = {array_key(layer.name, t) for layer, t in scene.jobs()}
        assert set(arrays.files) == expected_keys | {"x", "y", "provenance"}
        assert set(provenance["arrays"]) == expected_keys
        for layer, t in scene.jobs():
            raster = rasterise(layer.model(t), scene.grid)
            if scene.normalise:
                raster = raster.normalise()
            key = array_key(layer.name, t)
            np.testing.assert_array_equal(arrays[key], raster.values)
            assert provenance["arrays"][key]["mass"] == raster.mass
            # The recording holds the same values in float32.
            image = read_depth_image(rrd, f"layers/{layer.name}/density", elapsed=t)
            np.testing.assert_allclose(image, raster.values.astype(np.float32), rtol=0, atol=0)
    assert provenance["scene"] == name and provenance["normalised"] == scene.normalise
    assert provenance["grid"] == scene.grid.describe()


def test_inspect_prints_entities(quick_runs, capsys):
    rrd = quick_runs["figure1"] / "figure1.rrd"
    assert main(["inspect", str(rrd)]) == 0
    out = capsys.readouterr().out
    for layer in ("cat", "rough", "improved"):
        assert f"/layers/{layer}/density" in out
    assert "elapsed  duration" in out


def test_run_scene_returns_rows(tmp_path):
    scene = load_scene(write(tmp_path, SMALL))
    calls = []
    rows = run_scene(scene, tmp_path, progress=lambda *a: calls.append(a))
    assert calls == [(0, 1, "near t=5 s"), (1, 1, "near t=5 s")]
    (row,) = rows
    assert (row["scene"], row["layer"], row["t"], row["cells"]) == ("small", "near", 5.0, 400)
    assert 0.0 < row["mass"] <= 1.0 + 1e-9 and row["peak"] > 0.0 and row["seconds"] >= 0.0
    with pytest.raises(bananagrid.BananagridError, match="output directory does not exist"):
        run_scene(scene, tmp_path / "missing")


def test_butterly_recordings_have_geometry_and_rice(quick_runs):
    """Every Butterly layer logs its start geometry at every time; the isotropic scene also
    logs its range law beside Rice's, which agree to 2 % of the peak at the quick 20 m cells
    (bananagrid.record_butterly: the error of binning cells of s / 5 is about 1e-2 there)."""
    for name, layers in (("submarine", ["submarine"]), ("rice_isotropic", ["rice"]), ("slow_contact", ["drift", "start"])):
        scene = load_scene(ROOT / "scenes" / f"{name}.toml")
        entities = inspect_recording(quick_runs[name] / f"{name}.rrd")["entities"]
        for layer in layers:
            for part in ("mean", "ellipses", "parameters"):
                rows = entities[f"/layers/{layer}/geometry/{part}"]
                assert rows["temporal_rows"] == len(scene.times or (1,)), (name, layer, part)
    entities = inspect_recording(quick_runs["rice_isotropic"] / "rice_isotropic.rrd")["entities"]
    assert "/layers/rice/range/raster" in entities and "/layers/rice/range/rice" in entities
    summary = entities["/layers/rice/range/summary"]["values"][-1]["values"]
    assert 0 < summary["relative_to_peak"] < 0.02


def test_bearing_recording_has_geometry_difference_and_validation(quick_runs):
    path = quick_runs["bearing_coastal"] / "bearing_coastal.rrd"
    entities = inspect_recording(path)["entities"]
    for part in ("sensors", "bearings", "wedges", "fix", "ellipse", "circles", "containment"):
        assert f"/layers/exact/geometry/{part}" in entities, part
    assert "/validation" in entities
    exact = read_depth_image(path, "layers/exact/density")
    linear = read_depth_image(path, "layers/linear/density")
    difference = read_depth_image(path, "layers/exact/difference_to_linear")
    # recorded as float32 from float64 values: compare at float32 resolution of the peak
    np.testing.assert_allclose(difference, exact - linear, rtol=0, atol=4 * np.finfo(np.float32).eps * exact.max())


def test_examples_lists_every_bundled_scene_with_its_title(capsys):
    import tomllib

    assert cli.main(["examples"]) == 0
    lines = capsys.readouterr().out.splitlines()
    scenes = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))
    assert [line.split()[0] for line in lines] == [p.stem for p in scenes]
    for line, path in zip(lines, scenes):
        assert line.endswith(tomllib.loads(path.read_text())["scene"]["title"])
    assert cli.main(["examples", "--show", "figure1"]) == 0
    assert capsys.readouterr().out == (scenes[[p.stem for p in scenes].index("figure1")]).read_text()


def test_run_example_is_the_same_as_running_the_file(tmp_path):
    root = Path(__file__).resolve().parents[1]
    assert cli.main(["run", "--example", "folding", "--step", "100", "--out", str(tmp_path / "a"), "--quiet"]) == 0
    assert cli.main(["run", str(root / "scenes" / "folding.toml"), "--step", "100", "--out", str(tmp_path / "b"), "--quiet"]) == 0
    # recordings depend on the scene text and grid only: rerun finds them equal
    compare = rerun_cli("rrd", "compare", tmp_path / "a" / "folding.rrd", tmp_path / "b" / "folding.rrd")
    assert compare.returncode == 0, compare.stdout + compare.stderr


def test_unknown_example_and_no_scene_are_one_line_errors(capsys):
    assert cli.main(["run", "--example", "figure9"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith('bananagrid: error: --example "figure9": not a bundled scene; choose one of ') and "figure1" in err
    assert "\n" not in err
    assert cli.main(["run"]) == 2
    assert "give at least one SCENE.toml or --example NAME" in capsys.readouterr().err
    assert cli.main(["examples", "--show", "figure9"]) == 2  # the message names the option given
    assert capsys.readouterr().err.startswith('bananagrid: error: --show "figure9": not a bundled scene; choose one of ')


def test_compare_example_is_the_same_as_comparing_the_file(tmp_path, capsys):
    options = ["--reference", "cat", "--model", "improved", "--step", "100"]
    assert cli.main(["compare", "--example", "folding", *options, "--out", str(tmp_path / "a")]) == 0
    by_name = capsys.readouterr().out
    assert cli.main(["compare", str(ROOT / "scenes" / "folding.toml"), *options, "--out", str(tmp_path / "b")]) == 0
    by_path = capsys.readouterr().out
    assert by_name.replace(str(tmp_path / "a"), "OUT") == by_path.replace(str(tmp_path / "b"), "OUT")
    # the same recording: what inspect reads back is equal (not `rerun rrd compare`, for which
    # the NaN of an empty contour's largest error never equals itself)
    name = "folding-improved-vs-cat.rrd"
    assert cli.main(["inspect", "--json", str(tmp_path / "a" / name), str(tmp_path / "b" / name)]) == 0
    a, b = json.loads(capsys.readouterr().out)
    assert {**a, "path": None} == {**b, "path": None}
    # one scene: a file or a name, exactly one of them
    assert cli.main(["compare", *options]) == 2
    assert "give SCENE.toml or --example NAME" in capsys.readouterr().err
    assert cli.main(["compare", str(ROOT / "scenes" / "folding.toml"), "--example", "folding", *options]) == 2
    assert "give one of them, not both" in capsys.readouterr().err
    assert cli.main(["compare", "--example", "folding9", *options]) == 2
    assert '--example "folding9": not a bundled scene' in capsys.readouterr().err
