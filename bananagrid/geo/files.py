"""Map files written whole or not at all, with one-line errors.

:func:`writing` wraps :func:`bananagrid.atomic.atomic_write` for the writers of this package:
the target's directory is checked first, the file is written under a temporary name beside it
and renamed when complete, and a failure of the operating system or of the writing library
becomes one :class:`~bananagrid.validate.BananagridError` line, with nothing left behind.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path

from ..atomic import OutputWriteError, atomic_write, check_target

#: How a writer turns its target into the temporary path it writes: :func:`atomic_write`
#: (renamed when the block completes) or :meth:`bananagrid.atomic.OutputSet.stage` (renamed
#: with the rest of a run's files).
Stage = Callable[[Path], AbstractContextManager[Path]]

__all__ = ["writing"]


@contextmanager
def writing(path: str | os.PathLike, what: str, errors: tuple[type[BaseException], ...] = (),
            stage: Stage | None = None) -> Iterator[Path]:
    """``with writing(path, "NetCDF file") as tmp:`` write ``tmp``; it becomes ``path`` when
    the block completes.

    Parameters
    ----------
    path : path-like
        The file to write; its directory must exist.
    what : str
        What the file is, for messages.
    errors : tuple of exception types
        The writing library's own errors, turned into :class:`BananagridError` like ``OSError``.
    stage : callable, optional
        ``stage(path)``, a context manager giving the temporary path: default
        :func:`~bananagrid.atomic.atomic_write`; a run's :meth:`~bananagrid.atomic.OutputSet.stage`
        keeps the complete file for the run's commit.

    Raises
    ------
    BananagridError
        A missing directory, a target that is not a regular file (a directory, a link:
        :func:`~bananagrid.atomic.check_target`), or (:class:`~bananagrid.atomic.OutputWriteError`)
        a failure while writing; the temporary file is removed and ``path`` is untouched.
    """
    final = check_target(path, what)
    try:
        with (stage or atomic_write)(final) as partial:
            yield partial
    except (OSError, *errors) as exc:
        reason = (getattr(exc, "strerror", None) or str(exc) or type(exc).__name__).splitlines()[0]
        raise OutputWriteError(f"{final}: cannot write the {what} ({reason})") from None
