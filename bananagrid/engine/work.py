"""Work before it starts: an estimate of the computing a grid asks for, and a refusal in one line.

Valid parameters can ask for enormous work: a CAT whose turn rate spreads over thousands of
turns scans millions of turn-rate nodes at every cell, a Butterly with a wide continuous speed
law integrates the course at thousands of speeds. :func:`check_work` refuses such work before
any kernel is launched, from each model's own estimate
(:meth:`bananagrid.protocol.DensityModel.work_estimate`: seconds of one CPU core, from its scan
nodes, speed nodes or heading tables, calibrated on the reference machine and rounded up), with
the estimate, the limit and the way out in the message.

The estimates are for the CPU; a GPU run (``device="cuda"``) is not checked.
"""

from __future__ import annotations

import math

from ..validate import BananagridError

__all__ = ["DEFAULT_MAX_SECONDS", "check_work", "format_duration", "work_limit"]

#: Wall-clock seconds of estimated computing allowed by default (one hour).
DEFAULT_MAX_SECONDS = 3600.0


def format_duration(seconds: float) -> str:
    """``42 s``, ``12 min``, ``3.5 h``, ``41 days``, ``2.9e+09 years``: 2 significant digits."""
    # (unit, its seconds, used from): days and years from two of them, so "1.5 days" reads as "36 h"
    for unit, size, start in (("years", 31_557_600.0, 63_115_200.0), ("days", 86_400.0, 172_800.0),
                              ("h", 3600.0, 3600.0), ("min", 60.0, 60.0)):
        if seconds >= start:
            return f"{seconds / size:.2g} {unit}"
    return f"{seconds:.2g} s"


def check_work(core_seconds: float, threads: int, what: str, *, limit: float | None = None,
               option: str = "") -> float:
    """Refuse work whose estimated wall-clock time ``core_seconds / threads`` exceeds ``limit``
    (default :data:`DEFAULT_MAX_SECONDS`). Returns the estimated wall-clock seconds.

    Parameters
    ----------
    core_seconds : float
        Estimated seconds of one CPU core (the sum of the models' ``work_estimate``).
    threads : int
        CPU threads the work is spread over.
    what : str
        Names the work in the message.
    limit : float, optional
        Wall-clock seconds allowed (``math.inf``: no limit).
    option : str
        How a user raises the limit, added to the message (e.g. ``"--max-seconds S"``).

    Raises
    ------
    BananagridError
        The estimate above the limit: one line with both figures and the ways out.
    """
    allowed = DEFAULT_MAX_SECONDS if limit is None else float(limit)
    wall = float(core_seconds) / max(1, int(threads))
    if not wall <= allowed:  # a NaN estimate is refused too
        more = f", or {option} to allow more" if option else ""
        raise BananagridError(
            f"{what} would take about {format_duration(wall)} on {threads} CPU thread{'s' * (threads != 1)} "
            f"(estimate), more than the {format_duration(allowed)} allowed: use coarser cells, a smaller "
            f"grid or gentler parameters{more}"
        )
    return wall


def work_limit(value, key: str = "--max-seconds") -> float:
    """A work limit in seconds (a positive number; ``inf`` for none)."""
    if isinstance(value, bool):
        raise BananagridError(f"{key} = {value!r}: expected a number of seconds")
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        raise BananagridError(f"{key} = {value!r}: expected a number of seconds") from None
    if not seconds > 0.0 or math.isnan(seconds):
        raise BananagridError(f"{key} = {value!r}: expected a positive number of seconds (inf for no limit)")
    return seconds
