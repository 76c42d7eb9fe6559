"""Map files written whole or not at all, with one-line errors.

:func:`writing` wraps :func:`bananagrid.atomic.atomic_write` for the writers of this package:
the target's directory is checked first, the file is written under a temporary name beside it
and renamed when complete, and a failure of the operating system or of the writing library
becomes one :class:`~bananagrid.validate.BananagridError` line, with nothing left behind.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..atomic import atomic_write
from ..validate import BananagridError

__all__ = ["writing"]


@contextmanager
def writing(path: str | os.PathLike, what: str, errors: tuple[type[BaseException], ...] = ()) -> Iterator[Path]:
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

    Raises
    ------
    BananagridError
        A missing directory, a target that is a directory, or a failure while writing; the
        temporary file is removed and ``path`` is untouched.
    """
    final = Path(path)
    if not final.parent.is_dir():
        raise BananagridError(f"{final}: cannot write the {what}: directory {final.parent} does not exist")
    if final.is_dir():
        raise BananagridError(f"{final}: cannot write the {what}: it is a directory")
    try:
        with atomic_write(final) as partial:
            yield partial
    except (OSError, *errors) as exc:
        reason = (getattr(exc, "strerror", None) or str(exc) or type(exc).__name__).splitlines()[0]
        raise BananagridError(f"{final}: cannot write the {what} ({reason})") from None
