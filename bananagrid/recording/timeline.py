"""A recording's timelines: ``elapsed`` (a duration, every recording) and ``utc`` (timestamps,
a geographic scene whose frame has a time): what time a row is logged at."""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np
import rerun as rr

from ..validate import BananagridError, non_negative

__all__ = ["ELAPSED", "UTC", "MAX_ELAPSED_S", "elapsed_nanos", "set_elapsed", "set_times", "utc_nanos"]


#: Name of the duration timeline that carries the banana's elapsed time ``t``.
ELAPSED = "elapsed"

#: Name of the timestamp timeline that carries a geographic scene's UTC time (the frame's time
#: plus the elapsed time).
UTC = "utc"

#: The UTC times a timestamp timeline holds: nanoseconds since 1970 in 64 bits.
UTC_FIRST = datetime(1677, 9, 21, 0, 12, 44, tzinfo=timezone.utc)
UTC_LAST = datetime(2262, 4, 11, 23, 47, 16, tzinfo=timezone.utc)

#: Longest elapsed time a recording can hold: its timeline counts nanoseconds in 64 bits.
MAX_ELAPSED_S = (2**63 - 1) / 1e9  # 9.2e9 s, 292 years


def elapsed_nanos(seconds: float) -> int:
    """Elapsed ``seconds`` as the integer nanoseconds stored on the ``elapsed`` timeline."""
    seconds = non_negative("elapsed", seconds)
    if seconds >= MAX_ELAPSED_S:
        raise BananagridError(f"elapsed = {seconds!r} s: a recording's timeline ends at {MAX_ELAPSED_S:.3g} s (292 years)")
    return round(seconds * 1e9)


def set_elapsed(rec: rr.RecordingStream, seconds: float) -> None:
    """Put what this thread logs next to ``rec`` at ``elapsed = seconds`` (duration timeline)."""
    rec.set_time(ELAPSED, duration=np.timedelta64(elapsed_nanos(seconds), "ns"))


def utc_nanos(when: datetime) -> int | None:
    """A UTC time as integer nanoseconds since 1970 (exact: no float rounding), or None outside
    what a timestamp timeline holds (:data:`UTC_FIRST` to :data:`UTC_LAST`)."""
    if not (UTC_FIRST <= when <= UTC_LAST):
        return None
    delta = when - datetime(1970, 1, 1, tzinfo=timezone.utc)
    return (delta.days * 86_400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1_000


def set_times(rec: rr.RecordingStream, seconds: float, frame=None) -> None:
    """:func:`set_elapsed`, and for a geographic ``frame`` with a time
    (:class:`bananagrid.geo.frame.GeoFrame`) the ``utc`` timeline at its time plus ``seconds``,
    so that the time panel can show either (a UTC time beyond 1677 to 2262 has no timestamp:
    the ``elapsed`` timeline alone carries it)."""
    set_elapsed(rec, seconds)
    when = None if frame is None or getattr(frame, "time", None) is None else frame.utc(seconds)
    nanos = None if when is None else utc_nanos(when)
    if nanos is not None:
        rec.set_time(UTC, timestamp=np.datetime64(nanos, "ns"))
