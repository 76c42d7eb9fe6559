"""The ``elapsed`` duration timeline of a recording: what time a row is logged at."""

from __future__ import annotations

import numpy as np
import rerun as rr

from ..validate import BananagridError, non_negative

__all__ = ["ELAPSED", "MAX_ELAPSED_S", "elapsed_nanos", "set_elapsed"]


#: Name of the duration timeline that carries the banana's elapsed time ``t``.
ELAPSED = "elapsed"

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
