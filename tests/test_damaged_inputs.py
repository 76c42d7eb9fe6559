"""Damaged inputs are errors, never wrong numbers: every file kind that ``inspect`` and ``plot``
read (a recording .rrd, run's .npz arrays, its .nc maps, a scene .toml), damaged every way (cut
short, a bit flipped, a block zeroed, emptied, swapped for a directory, a FIFO, a file of
another kind, unreadable) ends either in exit code 2 with one line on stderr naming the file and
saying it is damaged or not what was asked for, or, where the damage hit bytes that do not
matter, in exactly the undamaged file's output. Never exit 0 with other numbers, never a
traceback, never a wait.

Recordings carry a digest per row and a manifest (:mod:`bananagrid.recording.digest`), .nc
maps a digest attribute (:func:`bananagrid.geo.dataset.netcdf_digest`), and .npz archives the
CRC-32 of each zip member; these tests damage the files and read them through ``cli.main``
in-process (rerun's reader runs in a forked child, so a crash in it cannot take the test
process down).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import stat
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bananagrid import BananagridError, BananagridWarning, cli, validate
from bananagrid.recording.core import set_elapsed, write_recording
from bananagrid.recording.digest import DIGESTS, MANIFEST, chunk_rows
from bananagrid.recording.readback import CheckedReader, read_rasters

from cases import small_scene

#: One slow target at one time on a 10 x 10 grid of 20 m cells, and a second layer: files of
#: every kind in a second.
TEXT = small_scene("hurt", '[layers.a]\nmodel = "cat"\n\n[layers.b]\nmodel = "polar"\n').replace(
    "step = 10.0", "step = 20.0")
SWEEP = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                 suppress_health_check=list(HealthCheck))
#: The messages' words for a damaged file or one of another kind.
SAYS_DAMAGED = re.compile(r"damaged|not a |not an |cut short|no such file|a FIFO|a directory|holds no recording")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """The scene and what ``run --npz --netcdf`` wrote from it."""
    out = tmp_path_factory.mktemp("whole")
    scene = out / "hurt.toml"
    scene.write_text(TEXT)
    assert cli.main(["run", str(scene), "--out", str(out), "--npz", "--netcdf", "--quiet"]) == 0
    return {suffix: out / f"hurt{suffix}" for suffix in (".toml", ".rrd", ".npz", ".nc")}


def command(path: Path, out_dir: Path) -> list[str]:
    """``inspect`` for a recording, ``plot`` (which reads all four kinds) for the others."""
    if path.suffix == ".rrd" and path.parent.name != "plot":
        return ["inspect", str(path)]
    return ["plot", str(path), "-o", str(out_dir / "map.png")]


def outcome(capfd, path: Path) -> tuple[int, str, str, bytes]:
    """Exit code, stdout and stderr (the file's folder written DIR) and the picture's bytes of
    the CLI run in-process on ``path``; a FIFO or a lock that made it wait fails the test."""
    out_dir = path.parent
    picture = out_dir / "map.png"
    picture.unlink(missing_ok=True)
    capfd.readouterr()
    previous = signal.signal(signal.SIGALRM, _waited)
    signal.alarm(60)  # inspect of this recording takes well under a second: 60 s is a hang
    try:
        code = cli.main(command(path, out_dir))
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    captured = capfd.readouterr()
    shown = lambda text: text.replace(str(out_dir), "DIR")  # noqa: E731
    return code, shown(captured.out), shown(captured.err), picture.read_bytes() if picture.exists() else b""


def _waited(signum, frame):
    raise AssertionError("the command waited: it must never block on its input")


def assert_error_or_same(result, whole, path: Path) -> None:
    """Exit 2 with one line naming ``path`` and saying what is wrong, or the whole file's result."""
    code, out, err, picture = result
    if code == 0:
        assert (out, err, picture) == whole[1:], "exit 0 with another output than the whole file's"
        return
    assert code == 2, (code, err)
    assert err.startswith(f"bananagrid: error: DIR/{path.name}: ") and err.count("\n") == 1, err
    assert SAYS_DAMAGED.search(err), err
    assert "Traceback" not in err


def damaged_copy(source: Path, tmp_path_factory, folder: str, damage) -> Path:
    """A copy of ``source`` under the same name in a new folder, with ``damage(bytes)`` applied."""
    target = tmp_path_factory.mktemp("damaged") / folder
    target.mkdir()
    path = target / source.name
    path.write_bytes(damage(bytearray(source.read_bytes())))
    return path


#: Ways to damage a file: cut at an offset, one bit flipped, a block zeroed. Offsets are
#: fractions of the file's size, so one strategy serves every file.
DAMAGE = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0.0, 1.0, exclude_max=True), st.just(0)),
    st.tuples(st.just("flip"), st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 7)),
    st.tuples(st.just("zero"), st.floats(0.0, 1.0, exclude_max=True), st.integers(1, 4096)),
)


def apply(damage):
    kind, where, amount = damage

    def hurt(data: bytearray) -> bytes:
        at = int(where * len(data))
        if kind == "truncate":
            return bytes(data[:at])
        if kind == "flip":
            data[at] ^= 1 << amount
            return bytes(data)
        data[at:at + amount] = bytes(len(data[at:at + amount]))
        return bytes(data)

    return hurt


@pytest.fixture(scope="module")
def whole(files, tmp_path_factory):
    """Each reading command's result on the undamaged files, run from a folder like the damaged ones'."""
    results = {}
    for key, suffix, folder in (("inspect", ".rrd", "inspect"), ("plot-rrd", ".rrd", "plot"),
                                (".npz", ".npz", "plot"), (".nc", ".nc", "plot"), (".toml", ".toml", "plot")):
        path = damaged_copy(files[suffix], tmp_path_factory, folder, bytes)
        results[key] = path
    return results


_REFERENCES: dict[str, tuple] = {}


def reference_outcome(capfd, whole, key: str) -> tuple:
    """The command's result on the whole file (computed once per module)."""
    if key not in _REFERENCES:
        _REFERENCES[key] = outcome(capfd, whole[key])
        assert _REFERENCES[key][0] == 0, _REFERENCES[key]
    return _REFERENCES[key]


@pytest.mark.parametrize("key, suffix, folder, examples", [
    ("inspect", ".rrd", "inspect", 120), ("plot-rrd", ".rrd", "plot", 15), (".npz", ".npz", "plot", 40),
    (".nc", ".nc", "plot", 40),
])
def test_damage_is_an_error_or_changes_nothing(files, whole, tmp_path_factory, capfd, monkeypatch, key, suffix,
                                              folder, examples):
    """Cut short, a bit flipped or a block of up to 4 KiB zeroed anywhere: exit 2 with one line,
    or (damage in bytes the reader does not use: rerun's footer index, zip and HDF5 slack) the
    very output of the whole file. A read that does not come back (HDF5 loops on some zeroed
    B-tree nodes) is given 2 s here (the whole file's check takes under 0.2 s in its child; a
    damaged file that is merely slow is then an error, which the assertion allows)."""
    reference = reference_outcome(capfd, whole, key)
    monkeypatch.setattr(validate, "CHILD_SECONDS", 2.0)

    @settings(SWEEP, max_examples=examples)
    @given(damage=DAMAGE)
    def check(damage):
        path = damaged_copy(files[suffix], tmp_path_factory, folder, apply(damage))
        assert_error_or_same(outcome(capfd, path), reference, path)

    check()


def _fifo(path: Path) -> None:
    os.mkfifo(path)


def _directory(path: Path) -> None:
    path.mkdir()


def _empty(path: Path) -> None:
    path.write_bytes(b"")


def _unreadable(path: Path, source: Path) -> None:
    shutil.copyfile(source, path)
    path.chmod(0)


#: Another kind's bytes under each suffix: what a renamed or mislabelled file gives.
OTHER_KIND = {".rrd": ".npz", ".npz": ".rrd", ".nc": ".npz", ".toml": ".nc"}


@pytest.mark.parametrize("suffix", [".rrd", ".npz", ".nc", ".toml"])
@pytest.mark.parametrize("what", ["fifo", "directory", "empty", "other kind", "unreadable", "missing"])
def test_special_files_are_one_line_errors(files, whole, tmp_path_factory, capfd, suffix, what):
    """A FIFO (it must not wait for a writer), a directory, an empty file, another kind's bytes
    under the suffix, a file without read permission (root reads it anyway: then its output is
    the whole file's), a missing file."""
    folder = "inspect" if suffix == ".rrd" else "plot"
    path = tmp_path_factory.mktemp("special") / folder / files[suffix].name
    path.parent.mkdir()
    if what == "fifo":
        _fifo(path)
    elif what == "directory":
        _directory(path)
    elif what == "empty":
        _empty(path)
    elif what == "other kind":
        shutil.copyfile(files[OTHER_KIND[suffix]], path)
    elif what == "unreadable":
        _unreadable(path, files[suffix])
    code, out, err, picture = outcome(capfd, path)
    if what == "unreadable" and code == 0:  # root reads anything
        assert os.geteuid() == 0
        reference = reference_outcome(capfd, whole, "inspect" if suffix == ".rrd" else suffix)
        assert (out, picture) == (reference[1], reference[3])
        return
    assert code == 2, (code, err)
    assert err.startswith(f"bananagrid: error: DIR/{path.name}: ") and err.count("\n") == 1, err
    if suffix != ".toml":  # a scene is text: its errors say what the parser found
        assert SAYS_DAMAGED.search(err), err


# --- the digests themselves -------------------------------------------------------------------


def test_rows_are_checked_one_for_one_and_hidden(files):
    """Every row of a recording run wrote has its digest at the same time, one manifest closes
    it, and readers never see either (the entities a reader yields are the data's)."""
    reader = CheckedReader(files[".rrd"])
    rows = list(chunk_rows(reader, reader.stores[0], footer=reader.footer))
    data = [(e, tuple(sorted(t))) for e, t, _ in rows if not e.startswith("/bananagrid/")]
    digests = [(plain(c["entity"]), tuple(sorted(t))) for e, t, c in rows if e.startswith("/" + DIGESTS + "/")]
    assert sorted(data) == sorted(digests) and len(data) > 10
    # each entity's digests on an entity of their own, so threads never interleave them
    assert all(e == "/" + DIGESTS + plain(c["entity"]) for e, t, c in rows if e.startswith("/" + DIGESTS + "/"))
    assert [e for e, _, _ in rows].count("/" + MANIFEST) == 1
    found = read_rasters(files[".rrd"])
    assert {r.layer for r in found} == {"a", "b"}


def plain(cell):
    (_, value) = cell
    return value.as_py()[0]


def test_digests_stay_out_of_the_views(files):
    """The default blueprint names each view's contents: no view takes in the digests."""
    reader = CheckedReader(files[".rrd"])
    (blueprint,) = reader.blueprints()
    texts = []
    for _, _, cells in chunk_rows(reader, blueprint, footer=True):
        for _, cell in cells.values():
            texts += [str(v) for v in _leaves(cell.as_py())]
    assert any("/layers/a/log10_density" in t for t in texts)
    assert not any("bananagrid" in t and "/" in t and "digest" in t for t in texts)
    assert not any(t.strip() in ("/**", "+ /**") for t in texts)


def _leaves(value):
    if isinstance(value, dict):
        for v in value.values():
            yield from _leaves(v)
    elif isinstance(value, list):
        for v in value:
            yield from _leaves(v)
    else:
        yield value


def test_a_recording_without_digests_warns_once_when_whole_and_is_refused_when_cut(tmp_path, capfd):
    """Another program's recording (no digests) is read with one warning line; cut short (no
    footer), it is refused: a bananagrid recording cut before its digests looks the same."""
    path = tmp_path / "foreign.rrd"
    rec = rr.RecordingStream("elsewhere", recording_id="foreign")
    rec.save(path)
    rec.set_time("elapsed", duration=1.5)
    rec.log("layers/bare/density", rr.DepthImage(np.ones((3, 4), np.float32)),
            rr.Transform3D(translation=(0.0, 3.0, 0.0), scale=(1.0, -1.0, 1.0)))
    rec.flush()
    rec.disconnect()
    capfd.readouterr()
    assert cli.main(["inspect", str(path)]) == 0
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and "holds none of bananagrid's content digests" in err and str(path) in err
    again = tmp_path / "again.rrd"
    shutil.copyfile(path, again)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        (item,) = read_rasters(again)
        read_rasters(again)  # once per file and process
    assert item.raster.values.shape == (3, 4)
    assert [w.category for w in caught] == [BananagridWarning]
    cut = tmp_path / "cut.rrd"
    data = path.read_bytes()
    cut.write_bytes(data[:end_message(data)])  # every message whole; the end and the footer gone
    with pytest.raises(BananagridError, match=r"cut\.rrd: .*(cut short|damaged)"):
        read_rasters(cut)


def end_message(data: bytes) -> int:
    """Offset of the end message of an .rrd stream: after the 12-byte file header, messages are
    a little-endian u64 kind (0: end) and u64 length, then the payload; the footer follows the
    end."""
    at = 12
    while True:
        kind, length = struct.unpack_from("<QQ", data, at)
        if kind == 0:
            return at
        at += 16 + length


def test_a_row_changed_after_writing_is_named(tmp_path):
    """A recording whose image bytes were changed (a float's low byte, where rerun sees nothing
    wrong): the error names the entity whose digest does not match."""
    values = np.linspace(1.0, 2.0, 64 * 64, dtype=np.float32).reshape(64, 64)

    def build(rec):
        set_elapsed(rec, 2.0)
        rec.log("layers/x/density", rr.DepthImage(values), rr.Transform3D(translation=(0.0, 64.0, 0.0),
                                                                        scale=(1.0, -1.0, 1.0)))

    path = write_recording(tmp_path / "x.rrd", build, recording_id="x")
    data = bytearray(path.read_bytes())
    at = data.find(values[32].tobytes())
    if at < 0:  # the chunk is compressed: find a literal run of the image instead
        at = data.find(values[32, :8].tobytes())
    assert at > 0, "the image's bytes are stored as they are (LZ4 keeps incompressible runs literal)"
    data[at] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(BananagridError, match=r"x\.rrd: recording is damaged \(digest of /layers/x/density "
                                              r"\(elapsed = 2 s\) does not match\)"):
        read_rasters(path)


def test_unreadable_files_are_refused_by_the_check_too(files, tmp_path):
    """Without root a file with no read permission is an error naming it (root reads it)."""
    path = tmp_path / "locked.rrd"
    shutil.copyfile(files[".rrd"], path)
    path.chmod(0)
    try:
        if os.geteuid() == 0:
            assert read_rasters(path)
        else:
            with pytest.raises(BananagridError, match=r"locked\.rrd: "):
                read_rasters(path)
    finally:
        path.chmod(stat.S_IRUSR | stat.S_IWUSR)
