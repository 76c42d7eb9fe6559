"""Output files written whole or not at all.

Every file bananagrid writes goes first to a temporary name beside its target, unique to the
process and the call (two runs writing the same output never share one), and is renamed over
the target only when complete: a rename within one directory is atomic, so the target is
either the old file, the complete new one, or absent. On any failure, and on SIGINT, SIGTERM
or SIGHUP while :func:`signals_as_exceptions` is active, the temporary file is removed.
"""

from __future__ import annotations

import os
import secrets
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .validate import BananagridError

__all__ = ["partial_path", "atomic_write", "check_writable", "Terminated", "signals_as_exceptions"]

#: Signals that end a run cleanly (temporary files removed) rather than killing it mid-write.
TERMINATING_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


def partial_path(final: str | os.PathLike) -> Path:
    """The temporary name of ``final``: hidden, in the same directory (so the rename is atomic),
    and unique to this process and call."""
    final = Path(final)
    return final.with_name(f".{final.name}.{os.getpid()}-{secrets.token_hex(4)}.partial")


@contextmanager
def atomic_write(final: str | os.PathLike) -> Iterator[Path]:
    """``with atomic_write(path) as tmp:`` write ``tmp``; on success it becomes ``path``, on
    any exception (interrupts included) it is removed and ``path`` is untouched."""
    final = Path(final)
    partial = partial_path(final)
    try:
        yield partial
        os.replace(partial, final)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def check_writable(directory: str | os.PathLike) -> None:
    """Raise :class:`BananagridError` now, before any computing, if files cannot be created in
    ``directory`` (which must exist)."""
    directory = Path(directory)
    probe = partial_path(directory / "write-test")
    try:
        probe.touch(exist_ok=False)
    except OSError as exc:
        raise BananagridError(f"{directory}: cannot write there ({exc.strerror or exc})") from None
    probe.unlink(missing_ok=True)


class Terminated(BaseException):
    """A terminating signal received while :func:`signals_as_exceptions` was active (a
    BaseException, like KeyboardInterrupt, so that only cleanup code sees it on its way out)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum
        self.name = signal.Signals(signum).name


@contextmanager
def signals_as_exceptions() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated` in the main thread (the
    default action kills the process at once, leaving temporary files behind). Outside the main
    thread, where handlers cannot be installed, this does nothing."""

    def handler(signum, frame):
        raise Terminated(signum)

    previous = {}
    try:
        for signum in TERMINATING_SIGNALS:
            previous[signum] = signal.signal(signum, handler)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)
