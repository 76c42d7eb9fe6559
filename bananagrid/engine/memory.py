"""Memory before work: what a grid will take, what the machine has, and a refusal in one line.

An allocation the machine cannot give makes Warp abort the process (SIGABRT, no message) or
NumPy raise deep inside a kernel call. :func:`check_memory` refuses such work before any of it
starts, from an estimate of ``base + cells * bytes_per_cell`` against the memory the operating
system says is available (Linux ``MemAvailable``, which counts reclaimable caches), with the
estimate, the figure and the way out in the message.

The per-cell figures are measured peaks (resident set size of a whole process), rounded up:

* :data:`RASTERISE_BYTES_PER_CELL`: ``rasterise`` on a grid, float64: the float64 result, the
  kernel's output array in the launch dtype and the row bands' scratch;
* ``bananagrid run`` adds the recording's float32 images and contours
  (:data:`bananagrid.scenes.run.RUN_BYTES_PER_CELL`).
"""

from __future__ import annotations

from ..validate import BananagridError

__all__ = ["RASTERISE_BYTES_PER_CELL", "UNCHECKED_BYTES", "available_bytes", "check_memory", "format_bytes", "memory_limit"]

#: Peak bytes per grid cell of ``rasterise`` (float64 result + float64 kernel output + margin).
RASTERISE_BYTES_PER_CELL = 32

#: Estimates up to this many bytes are allowed without asking the system (reading
#: ``/proc/meminfo`` costs about 8 us, as much as the rest of a small call's checks): the process
#: asking already holds Python, NumPy and Warp, over 100 MB, so a system that cannot give it
#: 4 MiB more is swapping whatever we check. A ``limit`` given is always checked.
UNCHECKED_BYTES = 4 * 2**20


def available_bytes() -> int | None:
    """Memory available to a new allocation without swapping (Linux ``MemAvailable``), or None
    where the system does not say."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def format_bytes(n: float) -> str:
    """``1.3 GB``, ``130 MB``: decimal units, 3 significant digits."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.0f} B"


def check_memory(cells: int, bytes_per_cell: float, what: str, *, base: float = 0.0,
                 limit: float | None = None, option: str = "") -> float:
    """Refuse work whose estimated memory ``base + cells * bytes_per_cell`` exceeds ``limit``
    (default: :func:`available_bytes`; no check where that is unknown). Returns the estimate.

    Parameters
    ----------
    cells : int
        Grid cells (or lattice cells) the work holds at once.
    bytes_per_cell : float
        Measured peak bytes per cell of that work.
    what : str
        Names the work in the message (``"figure1: a grid of 1500 x 900 = 1,350,000 cells"``).
    base : float
        Bytes needed whatever the size (beyond the process as it is).
    limit : float, optional
        Bytes allowed; default what the system has available (not asked for an estimate of at
        most :data:`UNCHECKED_BYTES`).
    option : str
        How a user raises the limit, added to the message (e.g. ``"--max-memory GB"``).

    Raises
    ------
    BananagridError
        The estimate above the limit: one line with both figures and the ways out.
    """
    estimate = float(base) + float(cells) * float(bytes_per_cell)
    if limit is None and estimate <= UNCHECKED_BYTES:
        return estimate
    allowed = available_bytes() if limit is None else float(limit)
    if allowed is not None and estimate > allowed:
        source = "available" if limit is None else "allowed"
        more = f", or {option} to allow more" if option else ""
        raise BananagridError(
            f"{what} needs about {format_bytes(estimate)} ({bytes_per_cell:g} bytes per cell), more than the "
            f"{format_bytes(allowed)} {source}: use coarser cells or a smaller grid{more}"
        )
    return estimate


def memory_limit(value, key: str = "--max-memory") -> float:
    """A memory limit given in GB, as bytes (a positive finite number)."""
    try:
        gb = float(value)
    except (TypeError, ValueError):
        raise BananagridError(f"{key} = {value!r}: expected a number of GB") from None
    if not (gb > 0.0 and gb < float("inf")):
        raise BananagridError(f"{key} = {value!r}: expected a positive, finite number of GB")
    return gb * 1e9

