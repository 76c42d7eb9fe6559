"""A recording's stream and file: deterministic ids and batching, written atomically and read
back whole before it is named.

Every function takes the :class:`rerun.RecordingStream` explicitly; nothing here touches
rerun's global or thread-default recording."""

from __future__ import annotations

import datetime
import os
import threading
import uuid
import warnings
from collections.abc import Callable
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

from ..atomic import OutputWriteError, atomic_write, check_target
from ..validate import BananagridError
from .digest import DigestCheck, DigestingRecording, chunk_rows
from .timeline import set_elapsed

__all__ = ["RecordingWriteError", "new_recording", "recording_id_for", "verify_recording", "write_recording"]


_NAMESPACE = uuid.UUID("6f1c1a52-3c1e-4c55-9d0e-7e2b8f0a9b1d")


def recording_id_for(content: str) -> str:
    """A recording id that depends on ``content`` only (a UUIDv5), e.g. the scene text."""
    return str(uuid.uuid5(_NAMESPACE, content))


#: rerun's batcher also cuts chunks on a 200 ms clock tick, so chunk boundaries (and with them
#: the file) depended on timing; with the tick a year long, chunks are cut only by size (rerun's
#: default 2 MiB) and at flushes, which depend on what is logged alone.
DETERMINISTIC_BATCHING = rr.ChunkBatcherConfig(
    flush_tick=datetime.timedelta(days=365), flush_num_bytes=rr.ChunkBatcherConfig.DEFAULT().flush_num_bytes,
)


def new_recording(application_id: str = "bananagrid", *, recording_id: str) -> rr.RecordingStream:
    """A recording stream whose output depends only on what is logged to it.

    rerun adds wall-clock data by default; both sources are switched off here, so that two
    runs of the same content give recordings that ``rerun rrd compare`` finds equal:

    - ``send_properties=False`` drops the ``/__properties`` ``start_time`` (wall clock),
    - ``set_log_time_enabled(False)`` drops the ``log_time`` timeline (``log_tick`` too),
    - :data:`DETERMINISTIC_BATCHING` cuts chunks by size only, never by the clock.

    The recording id is the caller's (see :func:`recording_id_for`), never a random one.
    Every row logged carries a digest (:class:`bananagrid.recording.digest.DigestingRecording`),
    so that a reader can tell a damaged file from a whole one. The ``elapsed`` timeline starts
    at 0 on the calling thread, so no row is ever logged without a timeline (rerun would then
    decide on its own whether it is static).

    Parameters
    ----------
    application_id : str
        rerun application id; recordings with the same id share blueprints in the viewer.
    recording_id : str
        Non-empty id of this recording.
    """
    if not isinstance(recording_id, str) or not recording_id:
        raise BananagridError(f"recording_id = {recording_id!r}: expected a non-empty string")
    rec = DigestingRecording(application_id, recording_id=recording_id, send_properties=False,
                             batcher_config=DETERMINISTIC_BATCHING)
    rec.set_log_time_enabled(False)
    rec.set_log_tick_enabled(False)
    set_elapsed(rec, 0.0)
    return rec


def write_recording(
    path: str | os.PathLike,
    build: Callable[[rr.RecordingStream], None],
    *,
    recording_id: str,
    blueprint: rrb.BlueprintLike | None = None,
    application_id: str = "bananagrid",
    stage: Callable | None = None,
) -> Path:
    """Write a recording to ``path`` atomically.

    The recording goes to a temporary name beside ``path``, unique to the process
    (:func:`bananagrid.atomic.partial_path`); ``build(rec)`` logs into it, the stream is flushed
    and closed (which writes the footer), and only then is the file renamed to ``path``. If
    anything raises, the temporary file is removed and the error re-raised, so ``path`` is
    either the complete new recording or untouched.

    Parameters
    ----------
    path : path-like
        Final ``.rrd`` path; its directory must exist.
    build : callable
        ``build(rec)`` logs everything into the open recording.
    recording_id : str
        Passed to :func:`new_recording`.
    blueprint : rerun blueprint, optional
        Embedded as the default blueprint of the file (see :func:`default_blueprint`).
    application_id : str
        Passed to :func:`new_recording`.
    stage : callable, optional
        ``stage(path)``, a context manager giving the temporary path: default
        :func:`~bananagrid.atomic.atomic_write` (renamed when complete); a run passes its
        :meth:`~bananagrid.atomic.OutputSet.stage` to rename it with its other files.

    Returns
    -------
    Path
        The final path.

    Raises
    ------
    BananagridError
        ``path`` is not a regular file (a directory, a link), or the recording cannot be
        written or does not read back (:class:`RecordingWriteError`: the file system refused
        its bytes); nothing is left behind.
    """
    final = check_target(path, "recording")
    rec = new_recording(application_id, recording_id=recording_id)
    if not rec.is_enabled():
        raise BananagridError(f"{final}: rerun logging is disabled (is RERUN=off set?)")
    try:
        with (stage or atomic_write)(final) as partial:
            _open_file(rec, partial, blueprint, shown=final)
            try:
                build(rec)
            except BaseException:
                _close(rec, final, partial, failing=True)  # the build's error is the one to report
                raise
            rec.log_manifest(blueprint=blueprint is not None)
            _close(rec, final, partial)
            verify_recording(partial, recording_id, shown=final)
    except OSError as exc:  # the file system refused the temporary file or its rename: name the target
        raise RecordingWriteError(f"{final}: cannot write the recording ({exc.strerror or exc})") from None
    return final


def verify_recording(path: Path, recording_id: str, *, shown: Path | None = None) -> None:
    """Check that a just-written ``.rrd`` reads back whole: it has its footer (a file cut short
    has none), every chunk of every store decodes, and it holds the recording ``recording_id``.

    What it catches is a file that is short, damaged in its framing, or not the recording asked
    for, and (rerun's chunks carry no checksum) any row whose values do not match the digest
    logged beside it (:class:`bananagrid.recording.digest.DigestCheck`): what a reader will check.

    Raises
    ------
    BananagridError
        One line naming ``shown`` (default ``path``) and what is wrong.
    """
    name = shown if shown is not None else path
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # "RRD file has no footer": the file was cut short
            reader = RrdReader(path)
            stores = reader.recordings()
            for store in [*stores, *reader.blueprints()]:
                for _ in reader.stream(store=store):
                    pass
    except (RuntimeError, ValueError, OSError, Warning) as exc:
        first_line = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise BananagridError(f"{name}: the recording written does not read back ({first_line})") from None
    if [store.recording_id for store in stores] != [recording_id]:
        raise BananagridError(f"{name}: the recording written does not hold recording {recording_id!r} alone")
    check = DigestCheck(str(name))
    try:
        for row in chunk_rows(reader, stores[0], footer=True):
            check.add(*row)
        check.finish(application_id=stores[0].application_id, recording_id=recording_id,
                     blueprint=bool(reader.blueprints()), footer=True)
    except BananagridError as exc:
        found = str(exc).removeprefix(f"{name}: ")
        raise BananagridError(f"{name}: the recording written does not read back: {found}") from None


def _open_file(rec: rr.RecordingStream, path: Path, blueprint: rrb.BlueprintLike | None, *, shown: Path) -> None:
    """Start streaming ``rec`` to ``path`` (messages name ``shown``, the final path); rerun
    writes the blueprint as its own store."""
    try:
        rec.save(path, default_blueprint=blueprint)
    except RuntimeError as exc:
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise OutputWriteError(f"{shown}: cannot write the recording ({reason})") from None


#: Seconds a discarded recording's file is given to close (:func:`_let_go`).
LET_GO_SECONDS = 5.0

#: Bytes asked of the file system again when rerun's writer stopped, to learn why.
PROBE_BYTES = 1 << 20


class RecordingWriteError(OutputWriteError):
    """The file system refused the recording's bytes (a full disk, a file-size limit): the
    message names the file and the cause."""


def _close(rec: rr.RecordingStream, shown: Path, partial: Path, *, failing: bool = False) -> None:
    """Flush everything logged and close the file sink (this writes the RRD footer).

    rerun's file writer stops on a write error (a full disk, a file-size limit) and the flush
    then raises; that becomes one line naming ``shown`` and the cause (:func:`_write_failure`),
    unless ``failing`` (another error is already on its way: the file is discarded, and
    :func:`_let_go` closes it without waiting for ever)."""
    if failing:
        _let_go(rec)
        return
    try:
        rec.flush()
    except RuntimeError as exc:
        if not failing:
            rerun_says = (str(exc).splitlines() or ["the file writer stopped"])[0]
            raise RecordingWriteError(
                f"{shown}: cannot write the recording: {_write_failure(partial, rerun_says)}"
            ) from None
    finally:
        rec.disconnect()


def _let_go(rec: rr.RecordingStream) -> None:
    """Close the file of a recording being discarded, without waiting for ever.

    rerun 0.41's flush and disconnect can wait for ever when its file writer stops while they
    wait (a full disk or a file-size limit that an .npz written beside the recording hit first:
    seen in about one run in four under a 4 kB limit). The close runs on a daemon thread; if it
    has not ended within :data:`LET_GO_SECONDS` it is left behind, and rerun's exit handler,
    which would wait on the same writer again, is unregistered, so that the run can end with
    its one-line error."""
    try:
        rec.flush(timeout_sec=0.0)  # started, not waited for
    except RuntimeError:
        pass
    closer = threading.Thread(target=rec.disconnect, name="bananagrid-let-go", daemon=True)
    closer.start()
    closer.join(LET_GO_SECONDS)
    if closer.is_alive():
        rr.unregister_shutdown()


def _write_failure(partial: Path, rerun_says: str) -> str:
    """Why the file writer stopped: rerun's flush error does not say, so the same file is
    asked for another ``PROBE_BYTES`` (it is removed after); the operating system's answer
    (no space left on the device, file too large, quota) is the cause."""
    try:
        with open(partial, "ab") as fh:
            size = fh.tell()
            try:
                fh.write(bytes(PROBE_BYTES))
                fh.flush()
                os.fsync(fh.fileno())
            finally:
                fh.truncate(size)
    except OSError as exc:
        return f"{exc.strerror or exc} (rerun: {rerun_says})"
    return f"rerun: {rerun_says} (RUST_LOG=warn shows rerun's own messages)"
