"""Parameter checks shared by every public constructor.

Every message names the argument, the value it got and what is allowed, so that a scene
error can be traced to its key (the scene layer prefixes the key path).
"""

from __future__ import annotations

import json
import math
import os
import select
import signal
import stat
import time
import warnings
from collections.abc import Callable
from numbers import Real
from pathlib import Path

import numpy as np

__all__ = ["finite", "positive", "non_negative", "positive_int", "pair", "point", "real_array", "show", "step_ratio",
           "BananagridError", "BananagridWarning", "regular_file", "checked_in_child"]


class BananagridError(ValueError):
    """A user-facing error: bad parameter, bad scene, bad file. The CLI prints it as one line."""


class BananagridWarning(UserWarning):
    """A likely mistake that still gives a result: a grid that misses the target, an angle that
    looks like degrees given in radians, a contour level the map never reaches. The CLI prints
    it as one line; ``warnings.simplefilter("error", BananagridWarning)`` makes it an error."""


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise BananagridError(f"{name} = {value!r}: expected a real number")
    return float(value)


def real_array(name: str, value, expected: str = "numbers") -> np.ndarray:
    """``value`` as a new float64 array, or raise unless every entry is a real number: NumPy
    alone would turn ``"1"`` and ``True`` into 1.0 (shape and finiteness are the caller's)."""
    try:
        array = np.array(value)
    except (TypeError, ValueError):  # ragged nesting
        array = None
    # kinds b: booleans, U/S: strings, O: anything else; and a bool among floats becomes a float
    if array is None or array.dtype.kind not in "iuf" or _holds_non_number(value):
        raise BananagridError(f"{name} = {value!r}: expected {expected}")
    return array.astype(float)


def _holds_non_number(value) -> bool:
    if isinstance(value, (bool, np.bool_, str, bytes)):
        return True
    return isinstance(value, (list, tuple)) and any(_holds_non_number(v) for v in value)


def finite(name: str, value) -> float:
    """Return ``value`` as float, or raise if it is not a finite real number."""
    v = _real(name, value)
    if not math.isfinite(v):
        raise BananagridError(f"{name} = {v!r}: must be finite")
    return v


def positive(name: str, value) -> float:
    """Return ``value`` as float, or raise unless it is finite and > 0."""
    v = finite(name, value)
    if v <= 0.0:
        raise BananagridError(f"{name} = {v!r}: must be > 0")
    return v


def non_negative(name: str, value) -> float:
    """Return ``value`` as float, or raise unless it is finite and >= 0."""
    v = finite(name, value)
    if v < 0.0:
        raise BananagridError(f"{name} = {v!r}: must be >= 0")
    return v


def positive_int(name: str, value) -> int:
    """Return ``value`` as int, or raise unless it is an integer >= 1."""
    if isinstance(value, bool) or not isinstance(value, (int,)) and not (
        isinstance(value, float) and value.is_integer()
    ):
        raise BananagridError(f"{name} = {value!r}: expected an integer")
    v = int(value)
    if v < 1:
        raise BananagridError(f"{name} = {v}: must be >= 1")
    return v


def pair(name: str, value, expected: str = "a pair (low, high)") -> tuple[float, float]:
    """Return ``value`` as a pair of finite floats, or raise naming ``name[0]`` / ``name[1]``
    (``expected`` says what the pair is, for the message when ``value`` is not a pair)."""
    try:
        first, second = value
    except (TypeError, ValueError):
        raise BananagridError(f"{name} = {value!r}: expected {expected}") from None
    return finite(f"{name}[0]", first), finite(f"{name}[1]", second)


def point(name: str, value) -> tuple[float, float]:
    """Return ``value`` as a pair of finite floats (x, y), or raise naming the bad one."""
    return pair(name, value, "a pair (x, y)")


def step_ratio(name: str, step: float, span: float, limit: int, unit: str = "") -> float:
    """``span / step``: the number of cells a step cuts a span into, or raise when it overflows
    (a subnormal step: 1 / 5e-324 is inf) or exceeds ``limit`` (before any count is rounded or
    any array allocated)."""
    ratio = span / step
    if not ratio <= limit:
        count = f"{ratio:.3g}" if math.isfinite(ratio) else "more than 1.8e308"
        raise BananagridError(
            f"{name} = {step!r}: cuts the span {span!r}{unit} into {count} cells, more than the {limit:,} a "
            "domain may have; use a larger step"
        )
    return ratio


def show(value) -> str:
    """A value as a scene file (TOML) would write it, for messages."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {show(v)}" for k, v in value.items()) + "}"
    return str(value)


def regular_file(path, what: str = "a file"):
    """``path`` as a :class:`pathlib.Path` if it names a regular file (symbolic links followed),
    else raise one line naming it and what it is: missing, a directory, a FIFO (opening one
    would wait for a writer), a device or a socket. ``what`` names what was expected
    (``"a recording"``)."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise BananagridError(f"{path}: no such file") from None
    except OSError as exc:
        raise BananagridError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if not stat.S_ISREG(mode):
        kind = ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
                else "a socket" if stat.S_ISSOCK(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
                else "not a regular file")
        raise BananagridError(f"{path}: {kind}, not {what}")
    return path


#: Seconds a child of :func:`checked_in_child` may take on an empty file, and the bytes per
#: second it must read beyond that (a tenth of what zlib inflates: slow disks, busy machines).
CHILD_SECONDS = 30.0
CHILD_BYTES_PER_SECOND = 5e6


def checked_in_child(path: Path, check: Callable[[Path], None]) -> None:
    """Run ``check(path)`` (a whole read of a file by a library that may not come back from a
    damaged one) in a forked child process and raise what it raised, as one line.

    Native readers can crash the process on a damaged file (rerun's reader panics and aborts
    on a damaged chunk) or never return (HDF5 loops on a zeroed B-tree node): no ``except``
    catches either. The child's death or its running past ``CHILD_SECONDS`` plus one second
    per ``CHILD_BYTES_PER_SECOND`` of the file is reported as a damaged file; the child is
    killed. Where there is no ``os.fork``, ``check`` runs here.

    Raises
    ------
    BananagridError
        ``check``'s own message, or one naming ``path`` and what became of the child.
    """
    if not hasattr(os, "fork"):
        check(path)
        return
    seconds = CHILD_SECONDS + os.stat(path).st_size / CHILD_BYTES_PER_SECOND
    read_end, write_end = os.pipe()
    with warnings.catch_warnings():
        # JAX (imported by a process that also timed peers, say) warns at every fork that its
        # threads may deadlock the child, and Python 3.12 does so for any threaded process: this
        # child only reads a file and leaves by os._exit, taking none of their locks.
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
        warnings.filterwarnings("ignore", message=r"This process .* is multi-threaded", category=DeprecationWarning)
        pid = os.fork()
    if pid == 0:  # the child: check, say what is wrong on the pipe, exit without any cleanup
        code, message = 0, ""
        try:
            os.close(read_end)
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 2)  # a panic's backtrace and HDF5's error stack are not for people
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the parent warns, reading it again
                check(path)
        except BananagridError as exc:
            code, message = 2, str(exc)
        except BaseException as exc:  # noqa: BLE001 - any failure is the file's: say which
            code, message = 3, f"{type(exc).__name__}: {exc}"
        finally:
            try:
                os.write(write_end, message.encode()[:4096])
            finally:
                os._exit(code)
    os.close(write_end)
    chunks, deadline, finished = [], time.monotonic() + seconds, False
    try:
        while (left := deadline - time.monotonic()) > 0:
            if select.select([read_end], [], [], left)[0]:
                chunk = os.read(read_end, 4096)
                if not chunk:
                    finished = True
                    break
                chunks.append(chunk)
    finally:
        os.close(read_end)
        if not finished:
            os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
    if not finished:
        raise BananagridError(f"{path}: damaged, or too slow to read (no result after {seconds:.0f} s)")
    first_line = (b"".join(chunks).decode(errors="replace").splitlines() or [""])[0]
    if os.WIFSIGNALED(status):
        name = signal.Signals(os.WTERMSIG(status)).name
        raise BananagridError(f"{path}: damaged (its reader crashed on it: {name})")
    code = os.WEXITSTATUS(status)
    if code == 2:
        raise BananagridError(first_line)
    if code != 0:
        raise BananagridError(f"{path}: damaged ({first_line or f'exit code {code}'})")
