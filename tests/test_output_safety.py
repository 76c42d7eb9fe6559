"""Data that must never be lost: every path `bananagrid run` writes (.rrd, .npz, .nc, .tif,
-areas.geojson, --zarr) with someone else's things already there, and a failure injected at
every step of writing.

Whatever is at a target and is not a regular file (a directory, a link, a pipe; for --zarr a
file, a link or a directory that is not empty and not a store of ours) is refused before any
computing, in one line naming it, exit 2, with everything on disk byte-identical. A run that
fails after computing (a writer raising, a rename refused, a file-size limit) keeps the previous
run's files whole, leaves no temporary, and says so in one line naming the file; a run that
succeeds replaces the whole set.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import resource
import shutil
import signal
import stat
import subprocess
import sys
from pathlib import Path

import dask
import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid import atomic, cli
from bananagrid.atomic import OutputSet, check_target
from bananagrid.geo.zarr_store import check_store_target, is_bananagrid_store, write_zarr
from bananagrid.scenes import run_cells, run_grid

ROOT = Path(__file__).resolve().parents[1]
#: pytest shows PendingDeprecationWarnings that a user's run does not (rasterio's use of affine, inside
#: the GeoTIFF writer): they are not ours to print, and the tests count stderr's lines.
pytestmark = pytest.mark.filterwarnings("ignore:Use `@` matmul:PendingDeprecationWarning")

#: One CAT layer at one time on 32 x 32 cells of 100 m, with [geo] so that every map file can be
#: asked for: a run takes well under a second once the kernels are compiled.
TINY = """\
[scene]
name = "tiny"
times = [300.0]

[geo]
origin_latlon = [60.45, 4.60]
time = "2026-11-24T05:40:00Z"
crs = "aeqd"

[grid]
x = [-2400.0, 800.0]
y = [-2600.0, 600.0]
step = 100.0

[layers.cat]
model = "cat"
v0 = 5.0
sigma_a = 0.002
sigma_omega_deg = 0.05
heading_deg = 200.0
"""

#: Every file a `run` of the scene writes, by the option that asks for it (the .rrd always).
FILES = {"rrd": "tiny.rrd", "npz": "tiny.npz", "netcdf": "tiny.nc", "geotiff": "tiny.tif",
         "geojson": "tiny-areas.geojson", "kml": "tiny.kml"}
EVERY_FILE = ["--npz", "--netcdf", "--geotiff", "--geojson", "--kml"]
#: What each writer calls its file (the error's wording).
WHAT = {"rrd": "recording", "npz": ".npz arrays", "netcdf": "NetCDF file", "geotiff": "GeoTIFF",
        "geojson": "GeoJSON file", "kml": "KML file"}


# --- what may be at a target ---------------------------------------------------------------------

def _dir_with_file(path: Path, home: Path) -> None:
    path.mkdir()
    (path / "notes.txt").write_text("a user's notes\n")


def _empty_dir(path: Path, home: Path) -> None:
    path.mkdir()


def _unwritable_dir(path: Path, home: Path) -> None:
    path.mkdir()
    (path / "data.bin").write_bytes(b"\x00\x01user")
    path.chmod(0o555)


def _link_to_file(path: Path, home: Path) -> None:
    (home / "precious.txt").write_text("do not follow me\n")
    path.symlink_to(home / "precious.txt")


def _link_to_dir(path: Path, home: Path) -> None:
    (home / "folder").mkdir(exist_ok=True)
    (home / "folder" / "inside.txt").write_text("mine\n")
    path.symlink_to(home / "folder")


def _dangling_link(path: Path, home: Path) -> None:
    path.symlink_to(home / "nowhere")


def _fifo(path: Path, home: Path) -> None:
    os.mkfifo(path)


def _user_file(path: Path, home: Path) -> None:
    path.write_bytes(b"a user's own bytes\n")


#: Things that are not a regular file: refused at a file target.
NOT_A_FILE = {
    "a directory holding a user's file": _dir_with_file,
    "an empty directory": _empty_dir,
    "an unwritable directory": _unwritable_dir,
    "a link to a user's file": _link_to_file,
    "a link to a user's directory": _link_to_dir,
    "a dangling link": _dangling_link,
    "a named pipe": _fifo,
}


def snapshot(*roots: Path) -> dict:
    """Every entry under ``roots``: its kind and mode, a file's bytes, a link's target (links
    not followed, pipes not opened)."""
    seen = {}
    for root in roots:
        for top, dirs, files in os.walk(root, followlinks=False):
            for name in dirs + files:
                path = Path(top) / name
                info = path.lstat()
                if stat.S_ISLNK(info.st_mode):
                    seen[str(path)] = ("link", os.readlink(path))
                elif stat.S_ISREG(info.st_mode):
                    seen[str(path)] = ("file", info.st_mode, path.read_bytes())
                else:
                    seen[str(path)] = ("other", info.st_mode)
    return seen


def temporaries(root: Path) -> list[str]:
    """Temporary names of ours left anywhere under ``root``."""
    return [str(p) for p in root.rglob("*") if p.name.endswith((".partial", ".old")) or ".partial" in p.name]


@pytest.fixture
def tiny(tmp_path) -> Path:
    path = tmp_path / "scenes" / "tiny.toml"
    path.parent.mkdir()
    path.write_text(TINY)
    return path


@pytest.fixture
def no_computing(monkeypatch):
    """Fail the test if any map is rasterised or any cluster started."""
    def never(*args, **kwargs):
        raise AssertionError("computed before the targets were checked")

    for runner in (run_grid, run_cells):  # the one runner's domain steps: grid layers, angular cells
        monkeypatch.setattr(runner, "rasterise", never)
    monkeypatch.setattr(cli, "dask_client", never)
    monkeypatch.setattr(cli, "run_scene_tiled", never)


@pytest.fixture(autouse=True)
def _writable_again(tmp_path):
    """An unwritable directory made by a test is made writable again, so that it can be removed."""
    yield
    for path in tmp_path.rglob("*"):
        if path.is_dir() and not path.is_symlink():
            path.chmod(0o755)


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bananagrid: error: "), err
    return lines[0]


# --- refused before computing ----------------------------------------------------------------------

@pytest.mark.parametrize("occupant", list(NOT_A_FILE))
@pytest.mark.parametrize("option", list(FILES))
def test_a_file_target_that_is_not_a_regular_file_is_refused_before_computing(
        option, occupant, tiny, tmp_path, no_computing, capsys):
    out, home = tmp_path / "out", tmp_path / "home"
    out.mkdir(), home.mkdir()
    (out / "notes.txt").write_text("a user's file beside the outputs\n")
    target = out / FILES[option]
    NOT_A_FILE[occupant](target, home)
    before = snapshot(tmp_path)
    assert cli.main(["run", str(tiny), "--out", str(out), *EVERY_FILE, "--quiet"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"{target}: cannot write the {WHAT[option]}" in line, line
    assert snapshot(tmp_path) == before
    assert temporaries(tmp_path) == []


def _store(path: Path) -> Path:
    """A small store of ours at ``path`` (Dask's threads: no cluster)."""
    tiled = bg.rasterise(bg.CAT(v0=5.0, t=300.0, sigma_a=0.002, sigma_omega=1e-3),
                         bg.Grid.from_bounds(x=(-400.0, 400.0), y=(0.0, 1600.0), step=100.0), chunks=8)
    with dask.config.set(scheduler="threads"):
        return tiled.to_zarr(path)


@pytest.fixture(scope="module")
def template_store(tmp_path_factory) -> Path:
    return _store(tmp_path_factory.mktemp("store") / "ours.zarr")


def _store_with_a_users_file(path: Path, home: Path, template: Path) -> None:
    shutil.copytree(template, path)
    (path / "README.txt").write_text("my notes about this run\n")


def _store_with_a_users_file_inside_an_array(path: Path, home: Path, template: Path) -> None:
    shutil.copytree(template, path)
    (path / "density" / "keep.csv").write_text("1,2,3\n")


def _foreign_store(path: Path, home: Path, template: Path) -> None:
    """A Zarr store someone else wrote (no bananagrid attribute)."""
    shutil.copytree(template, path)
    meta = (path / "zarr.json").read_text()
    (path / "zarr.json").write_text(meta.replace('"bananagrid_version"', '"their_version"'))


#: Things a store must not replace (the file occupants take the template as a third argument).
NOT_A_STORE = {
    **{k: v for k, v in NOT_A_FILE.items() if k != "an empty directory"},
    "a user's file": _user_file,
    "a store of ours holding a user's file": _store_with_a_users_file,
    "a store of ours with a user's file in an array": _store_with_a_users_file_inside_an_array,
    "someone else's Zarr store": _foreign_store,
}


def _place(occupant: str, path: Path, home: Path, template: Path) -> None:
    make = NOT_A_STORE[occupant]
    if make in (_store_with_a_users_file, _store_with_a_users_file_inside_an_array, _foreign_store):
        make(path, home, template)
    else:
        make(path, home)


@pytest.mark.parametrize("via", ["cli", "api"])
@pytest.mark.parametrize("occupant", list(NOT_A_STORE))
def test_a_zarr_target_that_is_not_ours_is_refused_before_computing(
        occupant, via, tmp_path, template_store, no_computing, capsys, monkeypatch):
    home = tmp_path / "home"
    home.mkdir()
    target = tmp_path / "maps.zarr"
    _place(occupant, target, home, template_store)
    before = snapshot(tmp_path)
    if via == "cli":
        assert cli.main(["run", "--example", "figure1", "--zarr", str(target), "--quiet"]) == 2
        line = one_error_line(capsys.readouterr().err)
    else:
        tiled = bg.rasterise(bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=0.058),
                             bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=100.0), chunks=32)
        monkeypatch.setattr(dask, "compute", lambda *a, **k: pytest.fail("computed before the target was checked"))
        with pytest.raises(bg.BananagridError) as caught:
            tiled.to_zarr(target)
        line = str(caught.value)
        assert "\n" not in line
    assert f"{target}: cannot write the Zarr store" in line, line
    assert snapshot(tmp_path) == before
    assert temporaries(tmp_path) == []


#: The other commands' outputs: (argv, the target's name in OUT, what the error calls it).
OTHER_COMMANDS = {
    "compare": (["compare", "{tiny}", "--reference", "cat", "--model", "cat", "--out", "{out}"], "tiny-cat-vs-cat.rrd",
                "recording"),
    "sweep recording": (["sweep", "--n", "2", "--out", "{out}"], "sweep.rrd", "recording"),
    "sweep arrays": (["sweep", "--n", "2", "--out", "{out}"], "sweep.npz", ".npz arrays"),
    "plot": (["plot", "{tiny}", "-o", "{out}/map.png"], "map.png", "PNG"),
}


@pytest.mark.parametrize("occupant", ["a directory holding a user's file", "a link to a user's file", "a named pipe"])
@pytest.mark.parametrize("command", list(OTHER_COMMANDS))
def test_the_other_commands_refuse_such_targets_before_computing(command, occupant, tiny, tmp_path, monkeypatch,
                                                                  capsys):
    for name in ("compute", "sweep", "read_picture"):
        monkeypatch.setattr(cli, name, lambda *a, **k: pytest.fail("computed before the target was checked"))
    argv, name, what = OTHER_COMMANDS[command]
    out, home = tmp_path / "out", tmp_path / "home"
    out.mkdir(), home.mkdir()
    NOT_A_FILE[occupant](out / name, home)
    before = snapshot(tmp_path)
    assert cli.main([a.format(tiny=tiny, out=out) for a in argv]) == 2
    assert f"{out / name}: cannot write the {what}" in one_error_line(capsys.readouterr().err)
    assert snapshot(tmp_path) == before


def test_the_reported_case_a_users_directory_at_zarr_is_kept(tmp_path, no_computing, capsys):
    """`mkdir d; echo keep > d/notes.txt; bananagrid run scenes/geo_ship.toml --zarr d`."""
    d = tmp_path / "d"
    d.mkdir()
    (d / "notes.txt").write_text("keep\n")
    assert cli.main(["run", str(ROOT / "scenes" / "geo_ship.toml"), "--zarr", str(d)]) == 2
    assert one_error_line(capsys.readouterr().err) == (
        f"bananagrid: error: {d}: cannot write the Zarr store: the directory is not empty and is not a "
        "Zarr store written by bananagrid; remove it or write elsewhere")
    assert [p.name for p in d.iterdir()] == ["notes.txt"] and (d / "notes.txt").read_text() == "keep\n"


def test_unwritable_parents_are_refused_before_computing(tiny, tmp_path, no_computing, capsys):
    """/proc is a directory nobody (root included) may create files in."""
    for argv in (["run", str(tiny), "--out", "/proc", *EVERY_FILE], ["run", str(tiny), "--zarr", "/proc/x.zarr"]):
        assert cli.main([*argv, "--quiet"]) == 2
        assert one_error_line(capsys.readouterr().err).startswith("bananagrid: error: /proc"), argv


@pytest.mark.parametrize("argv", [
    ["run", "{tiny}", "--out", ""],
    ["run", "{tiny}", "--zarr", ""],
    ["compare", "{tiny}", "--reference", "cat", "--model", "cat", "--out", ""],
    ["sweep", "--n", "2", "--out", ""],
])
def test_an_empty_path_option_is_refused(argv, tiny, tmp_path, monkeypatch, no_computing, capsys):
    """An empty path would be the current directory: refused, naming the option."""
    monkeypatch.setattr(cli, "compute", lambda *a, **k: pytest.fail("computed"))
    monkeypatch.setattr(cli, "sweep", lambda *a, **k: pytest.fail("computed"))
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    option = argv[-2]
    assert cli.main([a.format(tiny=tiny) for a in argv]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith(f"bananagrid: error: {option} ") and "an empty path" in line, line
    assert list(cwd.iterdir()) == []


#: At each target: nothing, a user's regular file (replaced by a run), or something refused.
OCCUPANTS = st.sampled_from([None, "a user's file", *NOT_A_FILE])


@settings(derandomize=True, max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(at=st.fixed_dictionaries({option: OCCUPANTS for option in FILES}),
       extra=st.lists(st.sampled_from(["notes.txt", ".hidden", "tiny.rrd.bak", "tiny.zarr"]), unique=True))
def test_any_mix_of_occupants_is_refused_whole_if_one_is_not_a_file(at, extra, tiny, tmp_path_factory,
                                                                       no_computing, capsys):
    """Random things at the five targets, and a user's files beside them: if any target holds
    something other than a regular file, the run is refused (naming the first such target in
    the order the run writes them) and nothing changes."""
    bad = [option for option in FILES if at[option] not in (None, "a user's file")]  # in the run's order
    if not bad:  # a run would compute: the success case is tested below, once
        return
    root = tmp_path_factory.mktemp("mix")
    out, home = root / "out", root / "home"
    out.mkdir(), home.mkdir()
    for name in extra:
        (out / name).write_bytes(name.encode())
    for option, occupant in at.items():
        if occupant == "a user's file":
            _user_file(out / FILES[option], home)
        elif occupant is not None:
            NOT_A_FILE[occupant](out / FILES[option], home)
    before = snapshot(root)
    assert cli.main(["run", str(tiny), "--out", str(out), *EVERY_FILE, "--quiet"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"{out / FILES[bad[0]]}: cannot write the {WHAT[bad[0]]}" in line, line
    assert snapshot(root) == before
    for path in out.iterdir():  # so that pytest can remove it
        if path.is_dir() and not path.is_symlink():
            path.chmod(0o755)


# --- failures after computing: the previous set kept whole ---------------------------------------

@pytest.fixture(scope="module")
def previous(tmp_path_factory) -> Path:
    """A directory holding a previous run's complete set (100 m cells) and a user's file."""
    root = tmp_path_factory.mktemp("previous")
    scene = root / "tiny.toml"
    scene.write_text(TINY)
    out = root / "out"
    assert cli.main(["run", str(scene), "--out", str(out), *EVERY_FILE, "--quiet"]) == 0
    (out / "notes.txt").write_text("a user's file beside the outputs\n")
    assert sorted(p.name for p in out.iterdir()) == sorted([*FILES.values(), "notes.txt"])
    return out


@pytest.fixture
def out(previous, tmp_path) -> Path:
    copy = tmp_path / "out"
    shutil.copytree(previous, copy)
    return copy


def _fail_when_staged(monkeypatch, name: str) -> None:
    """The writer of ``name`` writes its whole temporary file, then the file system refuses
    (ENOSPC), as a full disk does at the last block."""
    real = OutputSet.stage

    @contextlib.contextmanager
    def stage(self, final):
        with real(self, final) as partial:
            yield partial
            if Path(final).name == name:
                assert partial.exists() and partial.stat().st_size > 0  # the writer had written it
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(OutputSet, "stage", stage)


def _fail_npz_midway(monkeypatch) -> None:
    """The .npz's third array (the map, after x and y) fails after some of its bytes (EFBIG)."""
    real, calls = np.lib.format.write_array, []

    def write_array(fp, array, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            fp.write(b"\x93NUMPY half an array")
            raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))
        return real(fp, array, *args, **kwargs)

    monkeypatch.setattr(np.lib.format, "write_array", write_array)


def _fail_rename(monkeypatch, k: int) -> None:
    """The k-th rename of a complete temporary file into place is refused (EIO)."""
    real, calls = os.replace, []

    def replace(src, dst, *args, **kwargs):
        if str(src).endswith(".partial"):
            calls.append(dst)
            if len(calls) == k:
                raise OSError(errno.EIO, os.strerror(errno.EIO), str(src))
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(atomic.os, "replace", replace)


#: Each step of writing, and the file whose name its one line must carry.
STEPS = {
    **{f"{option} writer": (lambda mp, name=name: _fail_when_staged(mp, name), name) for option, name in FILES.items()
       if option != "npz"},
    "npz writer, midway": (_fail_npz_midway, FILES["npz"]),
    **{f"rename {k} of {len(FILES)}": (lambda mp, k=k: _fail_rename(mp, k), name) for k, name in enumerate(FILES.values(), 1)},
}


@pytest.mark.parametrize("step", list(STEPS))
def test_a_failure_at_any_step_keeps_the_previous_set_whole(step, out, tiny, monkeypatch, capsys):
    inject, name = STEPS[step]
    before = snapshot(out)
    inject(monkeypatch)
    assert cli.main(["run", str(tiny), "--out", str(out), "--step", "80", *EVERY_FILE, "--quiet"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert re.match(rf"bananagrid: error: {re.escape(str(out / name))}: cannot (write|put) the ", line), line
    assert snapshot(out) == before  # every old file byte-identical, the user's too, nothing added
    assert temporaries(out) == []


def test_the_reported_case_a_directory_at_the_geojson_path(out, tiny, no_computing, capsys):
    """The GeoJSON path a directory: refused before computing, the earlier run's files kept."""
    (out / FILES["geojson"]).unlink()
    (out / FILES["geojson"]).mkdir()
    before = snapshot(out)
    assert cli.main(["run", str(tiny), "--out", str(out), *EVERY_FILE, "--quiet"]) == 2
    assert "it is a directory" in one_error_line(capsys.readouterr().err)
    assert snapshot(out) == before


def test_a_run_that_succeeds_replaces_the_whole_set(out, tiny, capsys):
    before = snapshot(out)
    assert cli.main(["run", str(tiny), "--out", str(out), "--step", "80", *EVERY_FILE, "--quiet"]) == 0
    after = snapshot(out)
    assert sorted(after) == sorted(before) and temporaries(out) == []
    changed = {Path(p).name for p in after if after[p] != before[p]}
    assert changed == set(FILES.values())  # every output new, the user's file as it was
    with np.load(out / FILES["npz"]) as arrays:
        assert arrays["x"].size == 40  # 3200 m at 80 m: the new run's grid
    with xr.open_dataset(out / FILES["netcdf"]) as ds:
        assert ds.x.size == 40


def test_a_regular_file_of_a_user_at_a_target_is_replaced(tiny, tmp_path, capsys):
    """A regular file is what a run may replace (the previous run's output, or a stale copy)."""
    out = tmp_path / "out"
    out.mkdir()
    (out / FILES["rrd"]).write_text("old")
    assert cli.main(["run", str(tiny), "--out", str(out), "--quiet"]) == 0
    assert (out / FILES["rrd"]).read_bytes()[:4] == b"RRF2"  # rerun's file magic
    assert sorted(p.name for p in out.iterdir()) == [FILES["rrd"]]


# --- the output set on its own ------------------------------------------------------------------------

def test_an_output_set_commits_together_and_rolls_back(tmp_path, monkeypatch):
    a, b, c = (tmp_path / name for name in ("a.txt", "b.txt", "c.txt"))
    a.write_text("old a")
    b.write_text("old b")
    _fail_rename(monkeypatch, 3)
    with OutputSet() as outputs:
        for path in (a, b, c):
            outputs.add(path, "file")
            with outputs.stage(path) as tmp:
                tmp.write_text(f"new {path.name}")
        with pytest.raises(bg.BananagridError, match=rf"^{re.escape(str(c))}: cannot put the file in place"):
            outputs.commit()
    assert (a.read_text(), b.read_text(), c.exists()) == ("old a", "old b", False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]
    monkeypatch.undo()
    with OutputSet() as outputs:
        for path in (a, b, c):
            outputs.add(path, "file")
            with outputs.stage(path) as tmp:
                tmp.write_text(f"new {path.name}")
        outputs.commit()
    assert [p.read_text() for p in (a, b, c)] == ["new a.txt", "new b.txt", "new c.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt", "c.txt"]


def test_check_target_names_what_is_there(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    for occupant, make in NOT_A_FILE.items():
        target = tmp_path / "t.rrd"
        make(target, home)
        with pytest.raises(bg.BananagridError, match=rf"^{re.escape(str(target))}: cannot write the recording: "):
            check_target(target, "recording")
        if target.is_dir() and not target.is_symlink():
            target.chmod(0o755)
            shutil.rmtree(target)
        else:
            target.unlink()
    check_target(tmp_path / "absent.rrd", "recording")
    (tmp_path / "mine.rrd").write_text("x")
    check_target(tmp_path / "mine.rrd", "recording")


# --- Zarr stores: ours replaced whole -------------------------------------------------------------------

def test_our_store_and_an_empty_directory_are_replaced_whole(tmp_path, template_store):
    store = tmp_path / "maps.zarr"
    shutil.copytree(template_store, store)
    assert is_bananagrid_store(store)
    (store / "density" / "c" / "stale").mkdir(parents=True)  # a chunk the new store does not have
    tiled = bg.rasterise(bg.CAT(v0=5.0, t=300.0, sigma_a=0.002, sigma_omega=1e-3),
                         bg.Grid.from_bounds(x=(-200.0, 200.0), y=(0.0, 800.0), step=100.0), chunks=8)
    with dask.config.set(scheduler="threads"):
        tiled.to_zarr(store, name="other")
    with xr.open_zarr(store) as ds:
        names = list(ds.data_vars)
        assert "other" in names and not any(n.startswith("density") for n in names) and ds.x.size == 4
    assert not (store / "density").exists() and temporaries(tmp_path) == []
    empty = tmp_path / "empty.zarr"
    empty.mkdir()
    check_store_target(empty)
    with dask.config.set(scheduler="threads"):
        tiled.to_zarr(empty)
    assert is_bananagrid_store(empty)


def test_a_failed_store_write_keeps_our_old_store(tmp_path, template_store, monkeypatch):
    store = tmp_path / "maps.zarr"
    shutil.copytree(template_store, store)
    before = snapshot(tmp_path)
    stage = OutputSet.stage

    @contextlib.contextmanager
    def failing(self, final):
        with stage(self, final) as partial:
            yield partial
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(OutputSet, "stage", failing)
    tiled = bg.rasterise(bg.CAT(v0=5.0, t=300.0, sigma_a=0.002, sigma_omega=1e-3),
                         bg.Grid.from_bounds(x=(-200.0, 200.0), y=(0.0, 800.0), step=100.0), chunks=8)
    with dask.config.set(scheduler="threads"), pytest.raises(
            bg.BananagridError, match=rf"^{re.escape(str(store))}: cannot write the Zarr store \(OSError: .*No space"):
        write_zarr(store, [("density", 300.0, tiled)])
    assert snapshot(tmp_path) == before and temporaries(tmp_path) == []


# --- a file-size limit (a full disk without a mount), in a child process ---------------------------

def _limit_file_size(limit: int):
    def limit_in_child():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails (EFBIG) instead of killing
    return limit_in_child


def _cli(*args, limit: int, timeout: int = 300):
    return subprocess.run([sys.executable, "-m", "bananagrid", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, preexec_fn=_limit_file_size(limit))


def test_a_file_size_limit_keeps_the_previous_set_and_says_one_line(out, tiny):
    """4 kB: under every file of the set (the .npz is 9.7 kB, the recording 170 kB). Whichever
    write fails first (rerun's or the .npz's, they run at once), one line names its file; rerun's
    own log lines about it are held back; the previous set and the user's file are untouched."""
    before = snapshot(out)
    run = _cli("run", tiny, "--out", out, "--step", "80", *EVERY_FILE, "--quiet", limit=4096)
    assert run.returncode == 2, run.stderr
    line = one_error_line(run.stderr)
    assert re.fullmatch(rf"bananagrid: error: {re.escape(str(out))}/tiny\.(rrd|npz): cannot write the "
                        r"(recording|\.npz arrays).*File too large.*", line), line
    assert snapshot(out) == before and temporaries(out) == []


def test_a_file_size_limit_on_a_cluster_keeps_the_old_store_and_says_one_line(tmp_path, template_store, tiny):
    """The store's blocks are written by Dask's worker processes, which fail (EFBIG) and log a
    traceback: held back with rerun's lines; the one line names the store; our old store stays."""
    store = tmp_path / "tiny.zarr"
    shutil.copytree(template_store, store)
    before = snapshot(tmp_path)
    # 25 m cells: one block of 128 x 128 float64 (128 kB raw) is larger than 40 kB, the metadata smaller
    run = _cli("run", tiny, "--step", "25", "--zarr", store, "--chunks", "128", "--workers", "1", "--quiet",
               limit=40_000)
    assert run.returncode == 2, run.stderr
    line = one_error_line(run.stderr)
    assert line.startswith(f"bananagrid: error: {store}: cannot write the Zarr store") and "File too large" in line
    assert snapshot(tmp_path) == before and temporaries(tmp_path) == []


def test_the_sweeps_two_files_are_replaced_together(tmp_path, monkeypatch, capsys):
    """sweep.rrd and sweep.npz: a failure writing the arrays keeps the previous pair, a success
    replaces both."""
    out = tmp_path / "out"
    assert cli.main(["sweep", "--n", "2", "--out", str(out), "--quiet"]) == 0
    before = snapshot(out)
    with monkeypatch.context() as patch:
        _fail_when_staged(patch, "sweep.npz")
        assert cli.main(["sweep", "--n", "3", "--out", str(out), "--quiet"]) == 2
    assert one_error_line(capsys.readouterr().err) == (
        f"bananagrid: error: {out / 'sweep.npz'}: cannot write the .npz arrays (No space left on device)")
    assert snapshot(out) == before and temporaries(out) == []
    assert cli.main(["sweep", "--n", "3", "--out", str(out), "--quiet"]) == 0
    after = snapshot(out)
    assert sorted(after) == sorted(before) and all(after[p] != before[p] for p in after)
    with np.load(out / "sweep.npz") as arrays:
        assert arrays["goodness"].shape == (3, 3)
