"""Output files written whole or not at all.

Every file bananagrid writes goes first to a temporary name beside its target, unique to the
process and the call (two runs writing the same output never share one), and is renamed over
the target only when complete: a rename within one directory is atomic, so the target is
either the old file, the complete new one, or absent. On any failure, and on SIGINT, SIGTERM
or SIGHUP while :func:`signals_as_exceptions` is active, the temporary file is removed.

A run that writes several files (a scene's recording, arrays and map files) plans them first as
an :class:`OutputSet`: every target is checked before any computing (a directory, a link or
someone else's store where an output goes is refused, never emptied), each is written to its
temporary name, and only when all are complete are they renamed into place together; a
failure keeps the previous set whole.
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from .validate import BananagridError

__all__ = ["partial_path", "atomic_write", "check_writable", "check_target", "OutputSet", "OutputWriteError",
           "remove_path", "Terminated", "signals_as_exceptions"]

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


class OutputWriteError(BananagridError):
    """The file system refused an output's bytes (a full disk, a file-size limit, a quota): the
    message names the file and the operating system's cause. The command line then leaves out
    the native libraries' own log lines about the same failure."""


def remove_path(path: Path) -> None:
    """Remove the file, link or directory tree ``path`` if it is there (a temporary of ours)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


class OutputSet:
    """The files (and stores) one run writes, checked before any computing and replaced together.

    Each target is planned with :meth:`add`, which refuses at once what a run must not replace:
    a directory, a symbolic link or anything else that is not a regular file where a file goes;
    where a store (a directory) goes, a file, a link, or a directory that is not empty and not a
    store of ours (``ours(path)`` says). The run writes each target to a temporary name beside
    it (:meth:`stage`); only :meth:`commit`, once all are complete, puts them in place, old
    files first kept aside, so that if one rename fails the earlier ones are undone. Leaving the
    ``with`` block without a commit (any failure, an interrupt) removes every temporary and
    leaves the old files as they were.

    Examples
    --------
    >>> with OutputSet() as outputs:                                  # doctest: +SKIP
    ...     outputs.add(out / "a.rrd", "recording")
    ...     outputs.add(out / "a.npz", ".npz arrays")
    ...     write_recording(out / "a.rrd", build, stage=outputs.stage)
    ...     with outputs.stage(out / "a.npz") as tmp:
    ...         np.savez(tmp, ...)
    ...     outputs.commit()
    """

    def __init__(self):
        self._targets: dict[Path, tuple[str, Callable[[Path], bool] | None]] = {}
        self._partials: dict[Path, Path] = {}
        self._complete: set[Path] = set()

    def __enter__(self) -> "OutputSet":
        return self

    def __exit__(self, *exc) -> None:
        self.discard()

    @property
    def targets(self) -> list[Path]:
        """The planned targets, in the order added."""
        return list(self._targets)

    def add(self, path: str | os.PathLike, what: str, *, ours: Callable[[Path], bool] | None = None) -> Path:
        """Plan the target ``path`` (``what`` it is, for messages) and check it now.

        Parameters
        ----------
        path : path-like
            The final path; its directory must exist and take new files.
        what : str
            What the target is ("recording", "GeoTIFF"), for messages.
        ours : callable, optional
            For a store (a directory) target: ``ours(path)`` is true for a store this package
            wrote, which may be replaced whole. Without it the target is a regular file.

        Raises
        ------
        BananagridError
            One line naming ``path``: what is there and why it is not replaced.
        """
        final = Path(path)
        if final in self._targets:
            raise BananagridError(f"{final}: the run would write its {what} and its {self._targets[final][0]} "
                                  "to one path")
        check_target(final, what, ours=ours)
        if final.parent not in {p.parent for p in self._targets}:
            check_writable(final.parent)
        self._targets[final] = (what, ours)
        return final

    def reserve(self, final: str | os.PathLike) -> Path:
        """The temporary name of the planned target ``final`` (beside it; nothing created yet).
        The caller writes it; :meth:`commit` puts it in place, :meth:`discard` removes it."""
        final = Path(final)
        if final not in self._targets:
            raise ValueError(f"{final}: not a planned target of this output set")
        if final not in self._partials:
            self._partials[final] = partial_path(final)
        return self._partials[final]

    @contextmanager
    def stage(self, final: str | os.PathLike) -> Iterator[Path]:
        """``with outputs.stage(path) as tmp:`` write ``tmp``, the temporary name of the planned
        target ``path``; on success it waits for :meth:`commit`, on any exception it is removed.
        (The writers' ``stage=`` argument: :func:`atomic_write` renames at once, this does not.)"""
        final = Path(final)
        partial = self.reserve(final)
        try:
            yield partial
        except BaseException:
            remove_path(partial)
            self._complete.discard(final)
            raise
        self._complete.add(final)

    def commit(self) -> list[Path]:
        """Put every target in place, together: each is checked again, old files are kept
        aside until all the new ones are in place, and a failure undoes the renames done
        (the old files back, the new ones removed). Returns the targets.

        Raises
        ------
        BananagridError
            A target changed since it was planned (now a directory, say), or a rename failed;
            the old set is kept and the temporaries are removed.
        """
        missing = [str(t) for t in self._targets if t not in self._complete]
        if missing:
            raise RuntimeError(f"commit before every target was written: {', '.join(missing)}")
        raise_if_terminated()  # a signal whose exception was swallowed: nothing goes in place
        for final, (what, ours) in self._targets.items():
            check_target(final, what, ours=ours)
        done: list[tuple[Path, Path | None]] = []  # (target, its old version kept aside)
        try:
            for final in self._targets:
                aside = _set_aside(final)
                try:
                    os.replace(self._partials[final], final)
                except BaseException:
                    if aside is not None:
                        _put_back(aside, final)
                    raise
                done.append((final, aside))
        except BaseException as exc:
            failed = final
            for final, aside in reversed(done):
                if aside is not None:
                    if final.is_dir() and not final.is_symlink():  # a store: out of the way first
                        remove_path(final)
                    _put_back(aside, final)
                else:
                    remove_path(final)
            self.discard()
            if isinstance(exc, OSError):
                raise OutputWriteError(f"{failed}: cannot put the {self._targets[failed][0]} in place "
                                       f"({exc.strerror or exc}); the previous files are kept") from None
            raise
        for _, aside in done:
            if aside is not None:
                remove_path(aside)
        self._partials.clear()
        self._complete.clear()
        return list(self._targets)

    def discard(self) -> None:
        """Remove every temporary not yet committed (the old files are untouched)."""
        for partial in self._partials.values():
            remove_path(partial)
        self._partials.clear()
        self._complete.clear()


def check_target(path: str | os.PathLike, what: str, *, ours: Callable[[Path], bool] | None = None) -> Path:
    """Raise :class:`BananagridError` if a run may not write its ``what`` at ``path``: a
    regular file (or nothing) may be replaced; where a store goes (``ours`` given), an empty
    directory or a store ``ours`` recognises too. Everything else (a directory where a file
    goes, a symbolic link, a device, someone else's directory) is refused, naming it."""
    final = Path(path)
    if not final.parent.is_dir():
        raise BananagridError(f"{final}: cannot write the {what}: directory {final.parent} does not exist")
    if final.is_symlink():
        raise BananagridError(f"{final}: cannot write the {what}: it is a symbolic link (to {os.readlink(final)}); "
                              "remove it or write elsewhere")
    if not final.exists():
        return final
    if ours is None:
        if final.is_dir():
            raise BananagridError(f"{final}: cannot write the {what}: it is a directory; remove it or write elsewhere")
        if not final.is_file():
            raise BananagridError(f"{final}: cannot write the {what}: it is not a regular file")
        return final
    if not final.is_dir():
        there = "a file" if final.is_file() else "not a directory"
        raise BananagridError(f"{final}: cannot write the {what}: it is {there}, not a {what}; remove it or write elsewhere")
    if any(final.iterdir()) and not ours(final):
        raise BananagridError(f"{final}: cannot write the {what}: the directory is not empty and is not a {what} "
                              "written by bananagrid; remove it or write elsewhere")
    return final


def _set_aside(final: Path) -> Path | None:
    """Keep the old ``final`` under a temporary name until the new set is in place: a file as a
    second link (``final`` itself stays until the rename replaces it), a directory (a store,
    which a rename cannot replace) moved. None if there is no old ``final``."""
    if not final.exists():
        return None
    aside = final.with_name(partial_path(final).name.removesuffix(".partial") + ".old")
    if final.is_dir():
        os.replace(final, aside)
        return aside
    try:
        os.link(final, aside)
    except OSError:  # a file system without hard links
        os.replace(final, aside)
    return aside


def _put_back(aside: Path, final: Path) -> None:
    """Undo :func:`_set_aside`: the old file or store at ``final`` again. (Where ``final`` is
    still the old file, a second link of it, a rename would do nothing: the link is removed.)"""
    if final.exists() and not final.is_dir() and os.path.samefile(aside, final):
        aside.unlink()
    else:
        os.replace(aside, final)


class Terminated(BaseException):
    """A terminating signal received while :func:`signals_as_exceptions` was active (a
    BaseException, like KeyboardInterrupt, so that only cleanup code sees it on its way out)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum
        self.name = signal.Signals(signum).name


#: Terminating signals received by :func:`signals_as_exceptions`'s handler, the first first. A
#: handler's exception can be lost: raised while Python runs a weakref callback or a ``__del__``
#: (the import system's module locks have one), it is printed as "Exception ignored" and the
#: code goes on. So each is kept here too, and :func:`raise_if_terminated` raises it again at the
#: checkpoints that must not pass it (an output set's commit, the end of the block).
_received: list[int] = []


def raise_if_terminated() -> None:
    """Raise :class:`Terminated` if a terminating signal was received (and its exception lost)."""
    if _received:
        raise Terminated(_received[0])


@contextmanager
def signals_as_exceptions() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated` in the main thread (the
    default action kills the process at once, leaving temporary files behind); a signal whose
    exception is lost (see :data:`_received`) is raised again before any output set commits and
    when the block ends. Outside the main thread, where handlers cannot be installed, this does
    nothing."""

    def handler(signum, frame):
        _received.append(signum)
        raise Terminated(signum)

    previous = {}
    try:
        for signum in TERMINATING_SIGNALS:
            previous[signum] = signal.signal(signum, handler)
    except ValueError:  # not the main thread
        pass
    try:
        yield
        raise_if_terminated()
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)
        _received.clear()
