"""Outputs written whole or not at all: per-process temporary names, concurrent writers, a
terminating signal in the middle of a run, and an output directory refused before computing."""

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bananagrid import cli
from bananagrid.atomic import atomic_write, check_writable, partial_path
from bananagrid.recording.inspect import inspect_recording

ROOT = Path(__file__).resolve().parents[1]
RERUN = Path(sys.executable).parent / "rerun"


def test_temporary_names_are_unique_and_beside_the_target(tmp_path):
    a, b = partial_path(tmp_path / "x.rrd"), partial_path(tmp_path / "x.rrd")
    assert a != b and a.parent == b.parent == tmp_path
    assert a.name.startswith(".x.rrd.") and f".{os.getpid()}-" in a.name and a.name.endswith(".partial")


def test_a_failed_write_leaves_the_target_untouched(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_write(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("disk on fire")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]
    with atomic_write(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def run_cli(*args, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "bananagrid", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)


def test_two_runs_writing_the_same_output_both_succeed(tmp_path):
    """Each writes its own temporary file and renames it: the survivor is one whole recording."""
    runs = [run_cli("run", "scenes/figure1.toml", "--step", "40", "--out", str(tmp_path), "--quiet") for _ in range(2)]
    results = [run.communicate(timeout=300) for run in runs]
    assert [run.returncode for run in runs] == [0, 0], results
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure1.rrd"]  # no temporary file left
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(tmp_path / "figure1.rrd")], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    assert "/layers/cat/density" in inspect_recording(tmp_path / "figure1.rrd")["entities"]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_terminating_signal_leaves_no_partial_file(tmp_path, signum):
    """The signal arrives while the recording is being written: one line, exit 128 + signum,
    and nothing in the output directory."""
    run = run_cli("run", "scenes/sequence.toml", "--step", "8", "--out", str(tmp_path), "--quiet")
    deadline = time.monotonic() + 120
    while not any(p.name.endswith(".partial") for p in tmp_path.iterdir()):
        assert run.poll() is None, run.communicate()
        assert time.monotonic() < deadline, "no temporary file appeared"
        time.sleep(0.05)
    run.send_signal(signum)
    out, err = run.communicate(timeout=120)
    assert run.returncode == 128 + signum, err
    assert err.strip().splitlines() == [f"bananagrid: terminated by {signal.Signals(signum).name}"]
    assert list(tmp_path.iterdir()) == []


def test_an_unwritable_output_directory_is_refused_before_computing(monkeypatch, capsys):
    """/proc exists and is a directory, but nobody (root included) may create files in it."""
    def never(*args, **kwargs):
        raise AssertionError("computed before checking the output directory")

    monkeypatch.setattr(cli, "run_scene", never)
    assert cli.main(["run", str(ROOT / "scenes" / "figure1.toml"), "--out", "/proc"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bananagrid: error: /proc: cannot write there"), err


def test_check_writable_names_the_directory(tmp_path):
    check_writable(tmp_path)  # fine, and leaves nothing behind
    assert list(tmp_path.iterdir()) == []


def test_a_failing_later_scene_names_the_files_already_written(tmp_path, monkeypatch, capsys):
    real = cli.run_scene

    def second_fails(scene, *args, **kwargs):
        if scene.name == "folding":
            raise cli.BananagridError("folding.toml: the disk is on fire")
        return real(scene, *args, **kwargs)

    monkeypatch.setattr(cli, "run_scene", second_fails)
    scenes = [str(ROOT / "scenes" / f"{name}.toml") for name in ("figure1", "folding")]
    assert cli.main(["run", *scenes, "--step", "200", "--out", str(tmp_path), "--quiet"]) == 2
    # (200 m cells are coarse for Figure 1: each layer warns that the grid captured 0.986)
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("bananagrid: warning:")]
    assert err == [f"bananagrid: written before the error: {tmp_path / 'figure1.rrd'}",
                   "bananagrid: error: folding.toml: the disk is on fire"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure1.rrd"]


def _limit_file_size():
    """In the child: files may not grow past 200 kB (writes beyond fail as on a full disk, EFBIG),
    and SIGXFSZ is ignored so that the write fails instead of killing the process."""
    resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)


def test_a_write_that_fails_midway_ends_in_one_line_and_leaves_nothing(tmp_path):
    """rerun's file writer stops when a write fails (a full disk; here a 200 kB file-size limit,
    which needs no mount): the run ends with exit 2, our line last, and no file or temporary."""
    run = run_cli("run", "scenes/figure1.toml", "--step", "5", "--out", str(tmp_path), "--quiet",
                  preexec_fn=_limit_file_size)
    out, err = run.communicate(timeout=300)
    assert run.returncode == 2, err
    # one line: the cause asked of the file system again; rerun's own lines about it held back
    assert err.strip().splitlines() == [
        f"bananagrid: error: {tmp_path / 'figure1.rrd'}: cannot write the recording: File too large "
        "(rerun: File-writer thread shut down prematurely)"
    ], err
    assert list(tmp_path.iterdir()) == []


HOLD = """
import os, sys
from bananagrid.cli import native_log_held
from bananagrid.recording.core import RecordingWriteError
fail = sys.argv[1] == "fail"
try:
    with native_log_held():
        os.write(2, b"native line\\n")  # as rerun's logger writes: to the descriptor
        print("python line", file=sys.stderr)
        if fail:
            raise RecordingWriteError("x.rrd: cannot write the recording: No space left on device")
except RecordingWriteError as exc:
    print(exc, file=sys.stderr)
"""


@pytest.mark.parametrize("outcome", ["ok", "fail"])
def test_native_log_lines_are_held_and_shown_unless_the_write_failed(outcome):
    """rerun's native lines come after ours (held in a file meanwhile); after a failed write
    they are dropped, since our line names the cause."""
    run = subprocess.run([sys.executable, "-c", HOLD, outcome], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    lines = run.stderr.strip().splitlines()
    if outcome == "ok":
        assert lines == ["python line", "native line"]
    else:
        assert lines == ["python line", "x.rrd: cannot write the recording: No space left on device"]
