"""The recording API in one place: log rasters, scene text and a default blueprint into rerun
recordings.

Each role has its own module; this one gathers their public names, so that callers import them
from one place:

- :mod:`~bananagrid.recording.stream`: recording ids, the deterministic stream, the atomic
  write and the read-back check of a file (``new_recording``, ``write_recording``, ...).
- :mod:`~bananagrid.recording.timeline`: the ``elapsed`` duration timeline.
- :mod:`~bananagrid.recording.blueprint`: the default layout of maps, summary and scene.
- :mod:`~bananagrid.recording.scene_text`: the scene file as a text document.
- :mod:`~bananagrid.recording.raster`: one raster as a layer (its entities are listed there).
- :mod:`~bananagrid.recording.images`: grids as images placed in world metres, north up.
- :mod:`~bananagrid.recording.lines`: labelled contour lines.
- :mod:`~bananagrid.recording.legend`: the colour bar and the scale bar.
- :mod:`~bananagrid.recording.info`: provenance and numbers flattened for ``AnyValues``.
- :mod:`~bananagrid.recording.entities`: entity paths and strict logging.

Every function takes the :class:`rerun.RecordingStream` explicitly; nothing here touches
rerun's global or thread-default recording.
"""

from __future__ import annotations

from ..contours import DEFAULT_LEVELS, focus_extent
from .blueprint import HOVER_NOTE, default_blueprint, send_blueprint, union_extent
from .entities import entity_path, strict
from .images import (
    LOG10_FLOOR_DECADES,
    colormaps,
    image_from_values,
    log10_floor,
    log_cell_probabilities,
    log_north_up,
    log_signed_image,
    values_from_image,
)
from .info import flatten, raster_info
from .legend import COLOUR_BAR_PIXELS, format_length, nice_length
from .lines import CONTOUR_DRAW_ORDER, LEVEL_COLOURS, MASS_COLOURS
from .raster import log_raster
from .scene_text import log_scene_text
from .stream import (
    DETERMINISTIC_BATCHING,
    LET_GO_SECONDS,
    PROBE_BYTES,
    RecordingWriteError,
    new_recording,
    recording_id_for,
    verify_recording,
    write_recording,
)
from .timeline import ELAPSED, MAX_ELAPSED_S, UTC, elapsed_nanos, set_elapsed, set_times

__all__ = [
    "RecordingWriteError",
    "DEFAULT_LEVELS",
    "ELAPSED",
    "colormaps",
    "default_blueprint",
    "log_cell_probabilities",
    "elapsed_nanos",
    "entity_path",
    "flatten",
    "focus_extent",
    "image_from_values",
    "log_north_up",
    "log_raster",
    "log_scene_text",
    "new_recording",
    "recording_id_for",
    "send_blueprint",
    "set_elapsed",
    "set_times",
    "UTC",
    "strict",
    "union_extent",
    "values_from_image",
    "verify_recording",
    "write_recording",
]
