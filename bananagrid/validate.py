"""Parameter checks shared by every public constructor.

Every message names the argument, the value it got and what is allowed, so that a scene
error can be traced to its key (the scene layer prefixes the key path).
"""

from __future__ import annotations

import difflib
import json
import math
import os
import select
import signal
import stat
import time
import warnings
from collections.abc import Callable
from fractions import Fraction
from numbers import Real
from pathlib import Path

import numpy as np

__all__ = ["finite", "positive", "non_negative", "positive_int", "pair", "point", "real_array", "show", "step_ratio",
           "covariance", "polygon", "timed_track", "MAX_CONDITION",
           "BananagridError", "BananagridWarning", "regular_file", "checked_in_child", "radian_doubt", "DEGREES_MEANT",
           "unknown_key"]


class BananagridError(ValueError):
    """A user-facing error: bad parameter, bad scene, bad file. The CLI prints it as one line."""


class BananagridWarning(UserWarning):
    """A likely mistake that still gives a result: a grid that misses the target, an angle that
    looks like degrees given in radians, a contour level the map never reaches. The CLI prints
    it as one line; ``warnings.simplefilter("error", BananagridWarning)`` makes it an error."""


#: The question that ends every warning about an angle that looks like degrees given in radians
#: (a scene, which names the key and its ``_deg`` form, keeps its own and silences the model's).
DEGREES_MEANT = "were degrees meant?"


def radian_doubt(name: str, value, unit: str, t: float | None = None) -> str | None:
    """A warning's text when radians look like degrees, else None: an angle (``unit`` "rad")
    beyond a full turn, ``|value| > 2 pi``, or a rate ("rad/s") that turns more than a full
    turn in the elapsed time ``t``, ``|value| t > 2 pi``. Neither describes a plausible target;
    both are what a number meant in degrees gives. ``value`` may be a number or numbers."""
    values = np.abs(np.ravel(np.asarray(value, dtype=float)))
    values = values[np.isfinite(values)]
    if not values.size:
        return None
    largest = float(values.max())
    if unit == "rad" and largest > 2.0 * math.pi:
        return (f"{name} = {_plain(value)} rad is more than a full turn: {DEGREES_MEANT} "
                f"Pass math.radians({largest:g})")
    if unit == "rad/s" and t is not None and math.isfinite(t) and largest * t > 2.0 * math.pi:
        return (f"{name} = {_plain(value)} rad/s turns more than a full turn in t = {t:g} s "
                f"({math.degrees(largest * t):.3g} deg): {DEGREES_MEANT} Pass math.radians({largest:g})")
    return None


def _plain(value) -> str:
    array = np.asarray(value, dtype=float)
    return f"{float(array):g}" if array.ndim == 0 else "[" + ", ".join(f"{v:g}" for v in array.ravel()) + "]"


def unknown_key(where: str, key: str, allowed, note: str = "") -> str:
    """The message for a key outside ``allowed``: ``WHERE: unknown key NOTE; did you mean
    "NEAREST"? allowed: ...`` (the nearest allowed key by :func:`difflib.get_close_matches`, where
    one is close enough)."""
    allowed = [str(k) for k in allowed]
    nearest = difflib.get_close_matches(str(key), allowed, n=1)
    hint = f"; did you mean {show(nearest[0])}? allowed" if nearest else "; allowed"
    return f"{where}: unknown key{note}{hint}: {', '.join(allowed)}"


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


#: Largest condition number (ratio of the largest to the smallest eigenvalue) of a covariance:
#: beyond it the smallest axis is lost to the rounding of the largest in float64 (eps 2.2e-16
#: times 1e13 is 2e-3 of the smallest eigenvalue).
MAX_CONDITION = 1e13
#: Relative asymmetry of a covariance's off-diagonal pair that is taken as rounding (and made
#: exactly symmetric): a few ulps of the largest entry.
SYMMETRY_RTOL = 1e-12
#: Largest log of a normal's peak density (2 pi)^(-D/2) det^(-1/2): float64 reaches
#: exp(709.78); a factor of two below leaves room for the roundings of the normaliser.
MAX_LOG_PEAK = 709.0


def _eigenvalues_2x2(sxx: float, sxy: float, syy: float) -> tuple[float, float]:
    """Eigenvalues s1 <= s2 of [[sxx, sxy], [sxy, syy]]: s1 = det / s2, with det exact (in
    rationals, rounded once) and the entries scaled by a power of two, so that neither the
    cancellation of an elongated matrix nor the range of the units loses s1."""
    exponent = math.frexp(max(abs(sxx), abs(syy), abs(sxy)))[1]
    sxx, sxy, syy = (math.ldexp(v, -exponent) for v in (sxx, sxy, syy))
    s2 = 0.5 * (sxx + syy) + math.hypot(0.5 * (sxx - syy), sxy)
    s1 = float(Fraction(sxx) * Fraction(syy) - Fraction(sxy) ** 2) / s2
    return math.ldexp(s1, exponent), math.ldexp(s2, exponent)


def covariance(name: str, value, dim: int = 2) -> np.ndarray:
    """``value`` as a new float64 ``(dim, dim)`` covariance matrix: finite, symmetric (to
    :data:`SYMMETRY_RTOL` of its largest entry; then made exactly so), positive variances and a
    condition number below :data:`MAX_CONDITION`, and a peak density within float64
    (:data:`MAX_LOG_PEAK`).

    Raises
    ------
    BananagridError
        ``NAME = value: rule`` naming the first rule broken (for a 2 x 2 matrix, its eigenvalues
        and correlation when it is not positive definite).
    """
    cov = real_array(name, value, f"a {dim}x{dim} array of numbers")
    if cov.shape != (dim, dim):
        layout = " [[sxx, sxy], [sxy, syy]]" if dim == 2 else ""
        raise BananagridError(f"{name} = {value!r}: expected a {dim}x{dim} array{layout}, got shape {cov.shape}")
    if not np.isfinite(cov).all():
        raise BananagridError(f"{name} = {cov.tolist()!r}: every entry must be finite (NaN or inf given)")
    scale = float(np.max(np.abs(cov)))
    bad = np.argwhere(np.abs(cov - cov.T) > SYMMETRY_RTOL * scale)
    if bad.size:
        i, j = (int(k) for k in bad[0])
        raise BananagridError(f"{name} = {cov.tolist()!r}: must be symmetric ({name}[{i}][{j}] == {name}[{j}][{i}])")
    cov = np.triu(cov) + np.triu(cov, 1).T  # exactly symmetric: the upper triangle mirrored
    if not np.all(np.diag(cov) > 0.0):
        raise BananagridError(f"{name} = {cov.tolist()!r}: must be positive definite (variances > 0)")
    if dim == 2:
        s1, s2 = _eigenvalues_2x2(cov[0, 0], cov[0, 1], cov[1, 1])
        if not s1 > MAX_CONDITION**-1 * s2:
            rho = cov[0, 1] / (math.sqrt(cov[0, 0]) * math.sqrt(cov[1, 1]))
            raise BananagridError(
                f"{name} = {cov.tolist()!r}: must be positive definite (eigenvalues {s1:.6g}, {s2:.6g}; "
                f"correlation {rho:.15g}; allowed: |rho| < 1 and a condition number below {MAX_CONDITION:g})"
            )
        return _finite_peak(name, cov, (s1, s2))
    # scaled by the diagonal, so that units of very different size on the axes do not count
    d = np.sqrt(np.diag(cov))
    eig = np.linalg.eigvalsh(cov / np.outer(d, d))
    if not eig[0] > eig[-1] / MAX_CONDITION:
        raise BananagridError(
            f"{name} = {cov.tolist()!r}: must be positive definite (correlation eigenvalues {eig.tolist()!r}; "
            f"condition number below {MAX_CONDITION:g})"
        )
    return _finite_peak(name, cov, np.linalg.eigvalsh(cov))


def _finite_peak(name: str, cov: np.ndarray, eigenvalues) -> np.ndarray:
    """``cov``, or an error where the normal's peak density (2 pi)^(-D/2) det^(-1/2) is beyond
    float64 (variances near 1e-308 and below: the densities would be inf)."""
    dim = cov.shape[0]
    log_peak = -0.5 * dim * math.log(2.0 * math.pi) - 0.5 * float(np.sum(np.log(np.asarray(eigenvalues, float))))
    if not log_peak < MAX_LOG_PEAK:
        raise BananagridError(
            f"{name} = {cov.tolist()!r}: so small that the normal's peak density (2 pi)^(-D/2) det^(-1/2) = "
            f"exp({log_peak:.6g}) is beyond float64 (up to exp({MAX_LOG_PEAK:g})); use smaller units"
        )
    return cov


def polygon(name: str, value) -> np.ndarray:
    """``value`` as a new float64 ``(n, 2)`` array of the vertices (x, y) of a simple polygon:
    at least 3, finite, a closing vertex equal to the first dropped, no two consecutive alike,
    an area above 0 and no edge crossing another.

    Raises
    ------
    BananagridError
        ``NAME = value: rule`` naming the first rule broken (``NAME[k]`` for one vertex).
    """
    vertices = real_array(name, value, "a list of [x, y] vertices")
    if vertices.ndim != 2 or vertices.shape[1] != 2:
        raise BananagridError(f"{name} = {value!r}: expected a list of [x, y] vertices, got shape {vertices.shape}")
    bad = np.argwhere(~np.isfinite(vertices))
    if bad.size:
        k = int(bad[0][0])
        raise BananagridError(f"{name}[{k}] = {vertices[k].tolist()!r}: must be finite")
    if len(vertices) > 1 and np.array_equal(vertices[0], vertices[-1]):
        vertices = vertices[:-1]  # a closed ring
    if len(vertices) < 3:
        raise BananagridError(f"{name}: {len(vertices)} distinct vertices given, a polygon needs at least 3")
    following = np.roll(vertices, -1, axis=0)
    same = np.flatnonzero(np.all(vertices == following, axis=1))
    if same.size:
        k = int(same[0])
        raise BananagridError(f"{name}[{(k + 1) % len(vertices)}] = {vertices[k].tolist()!r}: repeats the vertex before it")
    crossing = _crossing_edges(vertices)
    if crossing is not None:
        i, j = crossing
        raise BananagridError(f"{name}: edges {i}-{i + 1} and {j}-{(j + 1) % len(vertices)} cross; "
                              "the polygon must not cross itself")
    local = vertices - vertices[0]  # the shoelace about a vertex: no cancellation of a far offset
    x, y = local[:, 0], local[:, 1]
    area = 0.5 * abs(math.fsum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    span = float(np.max(np.ptp(vertices, axis=0)))
    # below the area a rounding of the coordinates (16 ulps of the largest) moves along the span
    if not area > span * 16.0 * np.finfo(float).eps * float(np.max(np.abs(vertices))):
        raise BananagridError(f"{name} = {vertices.tolist()!r}: encloses no area (its vertices lie on a line)")
    return vertices


def _orientation(a, b, c) -> np.ndarray:
    """Sign of the turn a -> b -> c (broadcast over rows): +1 left, -1 right, 0 collinear."""
    return np.sign((b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0]))


def _crossing_edges(vertices: np.ndarray) -> tuple[int, int] | None:
    """The first pair (i, j), i < j, of non-adjacent edges that touch or cross, or None."""
    n = len(vertices)
    a, b = vertices, np.roll(vertices, -1, axis=0)
    for i in range(n):
        j = np.arange(i + 2, n if i else n - 1)  # edges that share no vertex with edge i
        if not j.size:
            continue
        p, q = a[i], b[i]
        r, s = a[j], b[j]
        d1, d2 = _orientation(p, q, r), _orientation(p, q, s)
        d3, d4 = _orientation(r, s, p[None]), _orientation(r, s, q[None])
        proper = (d1 * d2 < 0) & (d3 * d4 < 0)
        # collinear touching: an end of one edge within the other's box on their common line
        def on(seg_a, seg_b, point):
            return ((np.minimum(seg_a[..., 0], seg_b[..., 0]) <= point[..., 0])
                    & (point[..., 0] <= np.maximum(seg_a[..., 0], seg_b[..., 0]))
                    & (np.minimum(seg_a[..., 1], seg_b[..., 1]) <= point[..., 1])
                    & (point[..., 1] <= np.maximum(seg_a[..., 1], seg_b[..., 1])))
        touch = (((d1 == 0) & on(p[None], q[None], r)) | ((d2 == 0) & on(p[None], q[None], s))
                 | ((d3 == 0) & on(r, s, p[None])) | ((d4 == 0) & on(r, s, q[None])))
        hit = np.flatnonzero(proper | touch)
        if hit.size:
            return i, int(j[hit[0]])
    return None


def timed_track(name: str, times, positions) -> tuple[np.ndarray, np.ndarray]:
    """``times`` (s) and ``positions`` (m) of a track as new float64 arrays ``(n,)`` and
    ``(n, 2)``: at least 2 points, finite, one position per time, times strictly increasing.

    Raises
    ------
    BananagridError
        ``NAME.times[k] = value: rule`` or ``NAME.positions[k] = ...`` naming the first bad one.
    """
    t = real_array(f"{name}.times", times, "a list of times (s)")
    p = real_array(f"{name}.positions", positions, "a list of [x, y] positions (m)")
    if t.ndim != 1:
        raise BananagridError(f"{name}.times = {times!r}: expected a list of times (s)")
    if p.ndim != 2 or p.shape[1] != 2:
        raise BananagridError(f"{name}.positions = {positions!r}: expected a list of [x, y] positions (m)")
    if len(t) != len(p):
        raise BananagridError(f"{name}: {len(t)} times and {len(p)} positions; give one position per time")
    if len(t) < 2:
        raise BananagridError(f"{name}: {len(t)} point given, a track needs at least 2")
    for label, array in (("times", t), ("positions", p)):
        bad = np.argwhere(~np.isfinite(array))
        if bad.size:
            k = int(bad[0][0])
            raise BananagridError(f"{name}.{label}[{k}] = {array[k].tolist()!r}: must be finite")
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        k = int(back[0]) + 1
        raise BananagridError(
            f"{name}.times[{k}] = {float(t[k])!r}: must be later than the time before it ({float(t[k - 1])!r}); times strictly increase"
        )
    return t, p


#: What each check allows, as the documentation states it (a declared parameter's default domain,
#: :func:`bananagrid.models.params.param`).
finite.domain = "finite"
positive.domain = "finite, > 0"
non_negative.domain = "finite, >= 0"
point.domain = "finite"
covariance.domain = "finite, symmetric, positive definite"


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
