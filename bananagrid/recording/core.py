"""Log rasters, scene text and a default blueprint into rerun recordings.

Every function takes the :class:`rerun.RecordingStream` explicitly; nothing here touches
rerun's global or thread-default recording.

Layout of one layer ``entity`` (all of it in world metres, x east, y north):

- ``entity``: a static ``Transform3D`` with scale ``(1, -1, 1)``. rerun's 2D views draw y
  downwards; this flip puts north at the top of the screen for everything below ``entity``.
- ``entity/density``: ``DepthImage`` (float32) of the density per square metre, stored with
  its rows north first (image row 0 is the top), and a ``Transform3D`` from pixels to world
  metres, so the centre of ``values[i, j]`` lands on ``(x[j], y[i])``.
- ``entity/log10_density``: the same in ``log10``, cells at or below ``10**floor`` set to the
  floor (:func:`log10_floor`: two decades below the lowest contour drawn).
- ``entity/contours/lines``: ``LineStrips2D`` of the probability-mass contours (the boundaries of
  the highest-density regions, :func:`bananagrid.contours.mass_regions`), one colour per level;
  ``entity/contours/labels``: ``Points2D``, one per level on its line, labelled
  ``"90 % · 0.960 km²"``.
- ``entity/density_contours/lines`` and ``/labels``: the same for fixed density levels, when
  given.
- ``entity/legend/colour_bar``, ``/ticks``, ``/scale``: a log10 colour bar east of the map's
  frame (:func:`focus_extent`) with a label per decade, and a scale bar below it.
- ``entity/info``: ``AnyValues`` with the flattened provenance, mass, peak, grid and regions
  (``regions.90.area`` ...).
- ``entity/mass``: ``Scalars`` with the captured mass, a time series over ``elapsed``.
"""

from __future__ import annotations

import datetime
import math
import os
import threading
import uuid
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader
from rerun.error_utils import catch_and_log_exceptions

from ..contours import (
    DEFAULT_LEVELS,
    DEFAULT_MASS_LEVELS,
    MassRegion,
    contour_lines,
    focus_extent,
    format_level,
    label_positions,
    mass_regions,
)
from ..atomic import OutputWriteError, atomic_write, check_target
from ..results import Raster
from ..validate import BananagridError, non_negative, positive
from .digest import DigestCheck, DigestingRecording, chunk_rows

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
    "strict",
    "union_extent",
    "values_from_image",
    "verify_recording",
    "write_recording",
]

#: Name of the duration timeline that carries the banana's elapsed time ``t``.
ELAPSED = "elapsed"

#: How many decades below the lowest contour level the log10 image is floored.
LOG10_FLOOR_DECADES = 2.0

#: Fixed-density contour colours (RGB), one per level in the order given, cycled. Light and
#: saturated so that they stand out on both viridis and turbo.
LEVEL_COLOURS = ((255, 255, 255), (255, 99, 71), (255, 200, 0), (0, 220, 255), (255, 0, 255))

#: Probability-mass contour colours, innermost (50 %) first. The inner regions lie in turbo's
#: red and yellow, the outer ones in its greens and blues: white and magenta show on the former,
#: dark grey and black on the latter.
MASS_COLOURS = ((255, 255, 255), (255, 0, 255), (70, 70, 70), (0, 0, 0))

#: Pixels along the log10 colour bar.
COLOUR_BAR_PIXELS = 256

#: Draw contours above the images in a 2D view.
CONTOUR_DRAW_ORDER = 30.0

_NAMESPACE = uuid.UUID("6f1c1a52-3c1e-4c55-9d0e-7e2b8f0a9b1d")


# --- recordings -------------------------------------------------------------------------------


def recording_id_for(content: str) -> str:
    """A recording id that depends on ``content`` only (a UUIDv5), e.g. the scene text."""
    return str(uuid.uuid5(_NAMESPACE, content))


#: rerun's batcher also cuts chunks on a 200 ms clock tick, so chunk boundaries (and with them
#: the file) depended on timing; with the tick a year long, chunks are cut only by size (rerun's
#: default 2 MiB) and at flushes, which depend on what is logged alone.
DETERMINISTIC_BATCHING = rr.ChunkBatcherConfig(
    flush_tick=datetime.timedelta(days=365), flush_num_bytes=rr.ChunkBatcherConfig.DEFAULT().flush_num_bytes,
)


def new_recording(application_id: str = "bananagrid", *, recording_id: str) -> rr.RecordingStream:
    """A recording stream whose output depends only on what is logged to it.

    rerun adds wall-clock data by default; both sources are switched off here, so that two
    runs of the same content give recordings that ``rerun rrd compare`` finds equal:

    - ``send_properties=False`` drops the ``/__properties`` ``start_time`` (wall clock),
    - ``set_log_time_enabled(False)`` drops the ``log_time`` timeline (``log_tick`` too),
    - :data:`DETERMINISTIC_BATCHING` cuts chunks by size only, never by the clock.

    The recording id is the caller's (see :func:`recording_id_for`), never a random one.
    Every row logged carries a digest (:class:`bananagrid.recording.digest.DigestingRecording`),
    so that a reader can tell a damaged file from a whole one. The ``elapsed`` timeline starts
    at 0 on the calling thread, so no row is ever logged without a timeline (rerun would then
    decide on its own whether it is static).

    Parameters
    ----------
    application_id : str
        rerun application id; recordings with the same id share blueprints in the viewer.
    recording_id : str
        Non-empty id of this recording.
    """
    if not isinstance(recording_id, str) or not recording_id:
        raise BananagridError(f"recording_id = {recording_id!r}: expected a non-empty string")
    rec = DigestingRecording(application_id, recording_id=recording_id, send_properties=False,
                             batcher_config=DETERMINISTIC_BATCHING)
    rec.set_log_time_enabled(False)
    rec.set_log_tick_enabled(False)
    set_elapsed(rec, 0.0)
    return rec


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


def write_recording(
    path: str | os.PathLike,
    build: Callable[[rr.RecordingStream], None],
    *,
    recording_id: str,
    blueprint: rrb.BlueprintLike | None = None,
    application_id: str = "bananagrid",
    stage: Callable | None = None,
) -> Path:
    """Write a recording to ``path`` atomically.

    The recording goes to a temporary name beside ``path``, unique to the process
    (:func:`bananagrid.atomic.partial_path`); ``build(rec)`` logs into it, the stream is flushed
    and closed (which writes the footer), and only then is the file renamed to ``path``. If
    anything raises, the temporary file is removed and the error re-raised, so ``path`` is
    either the complete new recording or untouched.

    Parameters
    ----------
    path : path-like
        Final ``.rrd`` path; its directory must exist.
    build : callable
        ``build(rec)`` logs everything into the open recording.
    recording_id : str
        Passed to :func:`new_recording`.
    blueprint : rerun blueprint, optional
        Embedded as the default blueprint of the file (see :func:`default_blueprint`).
    application_id : str
        Passed to :func:`new_recording`.
    stage : callable, optional
        ``stage(path)``, a context manager giving the temporary path: default
        :func:`~bananagrid.atomic.atomic_write` (renamed when complete); a run passes its
        :meth:`~bananagrid.atomic.OutputSet.stage` to rename it with its other files.

    Returns
    -------
    Path
        The final path.

    Raises
    ------
    BananagridError
        ``path`` is not a regular file (a directory, a link), or the recording cannot be
        written or does not read back (:class:`RecordingWriteError`: the file system refused
        its bytes); nothing is left behind.
    """
    final = check_target(path, "recording")
    rec = new_recording(application_id, recording_id=recording_id)
    if not rec.is_enabled():
        raise BananagridError(f"{final}: rerun logging is disabled (is RERUN=off set?)")
    try:
        with (stage or atomic_write)(final) as partial:
            _open_file(rec, partial, blueprint, shown=final)
            try:
                build(rec)
            except BaseException:
                _close(rec, final, partial, failing=True)  # the build's error is the one to report
                raise
            rec.log_manifest(blueprint=blueprint is not None)
            _close(rec, final, partial)
            verify_recording(partial, recording_id, shown=final)
    except OSError as exc:  # the file system refused the temporary file or its rename: name the target
        raise RecordingWriteError(f"{final}: cannot write the recording ({exc.strerror or exc})") from None
    return final


def verify_recording(path: Path, recording_id: str, *, shown: Path | None = None) -> None:
    """Check that a just-written ``.rrd`` reads back whole: it has its footer (a file cut short
    has none), every chunk of every store decodes, and it holds the recording ``recording_id``.

    What it catches is a file that is short, damaged in its framing, or not the recording asked
    for, and (rerun's chunks carry no checksum) any row whose values do not match the digest
    logged beside it (:class:`bananagrid.recording.digest.DigestCheck`): what a reader will check.

    Raises
    ------
    BananagridError
        One line naming ``shown`` (default ``path``) and what is wrong.
    """
    name = shown if shown is not None else path
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # "RRD file has no footer": the file was cut short
            reader = RrdReader(path)
            stores = reader.recordings()
            for store in [*stores, *reader.blueprints()]:
                for _ in reader.stream(store=store):
                    pass
    except (RuntimeError, ValueError, OSError, Warning) as exc:
        first_line = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise BananagridError(f"{name}: the recording written does not read back ({first_line})") from None
    if [store.recording_id for store in stores] != [recording_id]:
        raise BananagridError(f"{name}: the recording written does not hold recording {recording_id!r} alone")
    check = DigestCheck(str(name))
    try:
        for row in chunk_rows(reader, stores[0], footer=True):
            check.add(*row)
        check.finish(application_id=stores[0].application_id, recording_id=recording_id,
                     blueprint=bool(reader.blueprints()), footer=True)
    except BananagridError as exc:
        found = str(exc).removeprefix(f"{name}: ")
        raise BananagridError(f"{name}: the recording written does not read back: {found}") from None


def _open_file(rec: rr.RecordingStream, path: Path, blueprint: rrb.BlueprintLike | None, *, shown: Path) -> None:
    """Start streaming ``rec`` to ``path`` (messages name ``shown``, the final path); rerun
    writes the blueprint as its own store."""
    try:
        rec.save(path, default_blueprint=blueprint)
    except RuntimeError as exc:
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise OutputWriteError(f"{shown}: cannot write the recording ({reason})") from None


#: Seconds a discarded recording's file is given to close (:func:`_let_go`).
LET_GO_SECONDS = 5.0
#: Bytes asked of the file system again when rerun's writer stopped, to learn why.
PROBE_BYTES = 1 << 20


class RecordingWriteError(OutputWriteError):
    """The file system refused the recording's bytes (a full disk, a file-size limit): the
    message names the file and the cause."""


def _close(rec: rr.RecordingStream, shown: Path, partial: Path, *, failing: bool = False) -> None:
    """Flush everything logged and close the file sink (this writes the RRD footer).

    rerun's file writer stops on a write error (a full disk, a file-size limit) and the flush
    then raises; that becomes one line naming ``shown`` and the cause (:func:`_write_failure`),
    unless ``failing`` (another error is already on its way: the file is discarded, and
    :func:`_let_go` closes it without waiting for ever)."""
    if failing:
        _let_go(rec)
        return
    try:
        rec.flush()
    except RuntimeError as exc:
        if not failing:
            rerun_says = (str(exc).splitlines() or ["the file writer stopped"])[0]
            raise RecordingWriteError(
                f"{shown}: cannot write the recording: {_write_failure(partial, rerun_says)}"
            ) from None
    finally:
        rec.disconnect()


def _let_go(rec: rr.RecordingStream) -> None:
    """Close the file of a recording being discarded, without waiting for ever.

    rerun 0.41's flush and disconnect can wait for ever when its file writer stops while they
    wait (a full disk or a file-size limit that an .npz written beside the recording hit first:
    seen in about one run in four under a 4 kB limit). The close runs on a daemon thread; if it
    has not ended within :data:`LET_GO_SECONDS` it is left behind, and rerun's exit handler,
    which would wait on the same writer again, is unregistered, so that the run can end with
    its one-line error."""
    try:
        rec.flush(timeout_sec=0.0)  # started, not waited for
    except RuntimeError:
        pass
    closer = threading.Thread(target=rec.disconnect, name="bananagrid-let-go", daemon=True)
    closer.start()
    closer.join(LET_GO_SECONDS)
    if closer.is_alive():
        rr.unregister_shutdown()


def _write_failure(partial: Path, rerun_says: str) -> str:
    """Why the file writer stopped: rerun's flush error does not say, so the same file is
    asked for another ``PROBE_BYTES`` (it is removed after); the operating system's answer
    (no space left on the device, file too large, quota) is the cause."""
    try:
        with open(partial, "ab") as fh:
            size = fh.tell()
            try:
                fh.write(bytes(PROBE_BYTES))
                fh.flush()
                os.fsync(fh.fileno())
            finally:
                fh.truncate(size)
    except OSError as exc:
        return f"{exc.strerror or exc} (rerun: {rerun_says})"
    return f"rerun: {rerun_says} (RUST_LOG=warn shows rerun's own messages)"


# --- blueprint --------------------------------------------------------------------------------


def default_blueprint(
    layer_entities: Sequence[str],
    *,
    scene_entity: str = "scene",
    summary_entity: str | None = None,
    extra_images: Sequence[str] = (),
    text_entities: Sequence[str] = (),
    extra_views: Sequence[rrb.View] = (),
    several_times: bool = False,
    frames: Mapping[str, tuple[float, float, float, float]] | None = None,
    map_view: rrb.View | None = None,
) -> rrb.Blueprint:
    """The default layout: one map per layer (log10 first), beside the summary and the scene.

    The maps and the text panel fill rows of at most three panels, with no empty cell. Each
    layer's map is a tab group: the log10 density (shown first: the tails and the
    probability-mass contours are visible there), the linear density, then any extra images.
    The captured-mass plot is shown only when the scene has several times (one point says
    nothing that the summary does not), and the time cursor then starts at the last time
    (the time panel follows the data to its end).

    Parameters
    ----------
    layer_entities : sequence of str
        The ``entity`` paths given to :func:`log_raster`.
    scene_entity : str
        The entity given to :func:`log_scene_text`.
    summary_entity : str, optional
        A text document summarising the run (shown first, before the scene text).
    extra_images : sequence of str
        Further images under some layers (``"layers/NAME/IMAGE"``), each shown as one more
        tab of its layer (e.g. a bearing fix's difference to its linear map).
    text_entities : sequence of str
        Further text documents (e.g. a validation table), each a tab beside the scene text.
    extra_views : sequence of rerun views
        Further views (e.g. radial-curve plots), as tabs beside the summary and the scene.
    several_times : bool
        Whether the layers are logged at more than one elapsed time.
    frames : mapping of layer entity to (x0, x1, y0, y1), optional
        Where each map opens (m): its :func:`focus_extent` (over all times, see
        :func:`union_extent`) and the legend beside it. Anything beyond (the rest of the
        grid, distant bearing stations) is a zoom-out away.
    map_view : rerun view, optional
        A geographic scene's map (:func:`bananagrid.recording.geomap.map_view`), a panel
        after the layers' maps.
    """
    layers = [entity_path(e) for e in layer_entities]
    extras = [entity_path(e) for e in extra_images]
    texts = [] if summary_entity is None else [rrb.TextDocumentView(origin=f"/{entity_path(summary_entity)}", name="summary")]
    texts.append(rrb.TextDocumentView(origin=f"/{entity_path(scene_entity)}", name="scene"))
    texts += [rrb.TextDocumentView(origin=f"/{entity_path(e)}", name=entity_path(e)) for e in text_entities]
    texts += list(extra_views)
    side = rrb.Tabs(*texts) if len(texts) > 1 else texts[0]
    if several_times and layers:
        side = rrb.Vertical(
            side,
            rrb.TimeSeriesView(origin="/", contents=[f"/{e}/mass" for e in layers], name="captured mass"),
            row_shares=[2, 1],
        )
    # "following" puts the cursor at the last time; an explicit panel state, because rerun
    # drops the panel's state chunk with a warning when it is left empty.
    time_panel = rrb.TimePanel(state="expanded", timeline=ELAPSED, play_state="following") if several_times else None
    if not layers:
        return rrb.Blueprint(side, collapse_panels=False)
    frames = {entity_path(e): extent for e, extent in (frames or {}).items()}
    maps = [
        _layer_tabs(e, [x.rsplit("/", 1)[1] for x in extras if x.rsplit("/", 1)[0] == e],
                    _framed(frames[e]) if e in frames else None)
        for e in layers
    ]
    if map_view is not None:
        maps.append(map_view)
    top = _panels(maps, side)
    parts = [top] if time_panel is None else [top, time_panel]
    return rrb.Blueprint(*parts, collapse_panels=False)


def _panels(maps: Sequence, side) -> rrb.Container:
    """Maps and the text panel in rows of at most three, the rows as even as possible, so
    that no cell is empty; one or two maps sit in one row with a narrower text panel."""
    if len(maps) <= 2:
        return rrb.Horizontal(*maps, side, column_shares=[3] * len(maps) + [2])
    cells = [*maps, side]
    rows = math.ceil(len(cells) / 3)
    sizes = [len(cells) // rows + (1 if k < len(cells) % rows else 0) for k in range(rows)]
    out, k = [], 0
    for size in sizes:
        out.append(rrb.Horizontal(*cells[k:k + size]))
        k += size
    return rrb.Vertical(*out)


def _framed(extent: tuple[float, float, float, float]) -> rrb.VisualBounds2D:
    """View bounds holding ``extent``, the colour bar east of it and the scale bar below it.

    The view's y axis points down (the layers are flipped north up), so world ``y`` maps to
    ``-y`` there.
    """
    x0, x1, y0, y1 = extent
    width, height = x1 - x0, y1 - y0
    return rrb.VisualBounds2D(
        x_range=(x0 - 0.03 * width, x1 + 0.16 * width), y_range=(-(y1 + 0.08 * height), -(y0 - 0.1 * height)),
    )


def _layer_tabs(entity: str, extra_images: Sequence[str] = (), bounds: rrb.VisualBounds2D | None = None) -> rrb.Tabs:
    """Log10 density and density views of one layer (and any extra images), each with its
    contours and whatever geometry the layer carries; the log10 view is the active tab."""
    return rrb.Tabs(
        *(_map_view(entity, image, bounds) for image in ("log10_density", "density", *extra_images)),
        name=entity,
    )


#: Shown in every map view's name: rerun's hover reports the view's own coordinates, whose y axis
#: points down (the maps are flipped north up), so a hovered line's "y" is minus the northing;
#: over an image it reports the pixel (column from the west edge, row from the north edge).
HOVER_NOTE = "hover y = −north"


def _map_view(entity: str, image: str, bounds: rrb.VisualBounds2D | None = None) -> rrb.Spatial2DView:
    """A 2D view of one image, the contours, the legend (log10 view) and the layer's geometry
    overlay (if any); rooted at ``/`` so the north-up flip applies."""
    contents = [f"/{entity}/{image}", f"/{entity}/contours/**", f"/{entity}/density_contours/**", f"/{entity}/geometry/**"]
    if image == "log10_density":
        contents.append(f"/{entity}/legend/**")
    label = entity.removeprefix("layers/")
    return rrb.Spatial2DView(
        origin="/", contents=contents, name=f"{label} · {image.replace('_', ' ')} · {HOVER_NOTE}", visual_bounds=bounds,
    )


def send_blueprint(rec: rr.RecordingStream, blueprint: rrb.BlueprintLike) -> None:
    """Send ``blueprint`` into ``rec``'s sinks as the active and default blueprint.

    With a file sink the blueprint is written into the ``.rrd`` as a separate blueprint store.
    :func:`write_recording` embeds its ``blueprint`` argument already.
    """
    rec.send_blueprint(blueprint, make_active=True, make_default=True)


# --- scene text -------------------------------------------------------------------------------


def log_scene_text(rec: rr.RecordingStream, text: str, entity: str = "scene") -> None:
    """Log the scene file as a static markdown ``TextDocument`` (a fenced TOML block).

    rerun renders ``text/plain`` and ``text/markdown`` only, so the TOML goes in a fence.
    """
    with strict():
        rec.log(
            entity_path(entity),
            rr.TextDocument(_fenced(text, "toml"), media_type=rr.MediaType.MARKDOWN),
            static=True,
        )


def _fenced(text: str, language: str) -> str:
    """``text`` in a markdown code fence longer than any backtick run inside it."""
    fence = "`" * max(3, _longest_run(text, "`") + 1)
    return f"{fence}{language}\n{text.rstrip()}\n{fence}\n"


def _longest_run(text: str, char: str) -> int:
    """Length of the longest run of ``char`` in ``text``."""
    best = run = 0
    for c in text:
        run = run + 1 if c == char else 0
        best = max(best, run)
    return best


# --- rasters ----------------------------------------------------------------------------------


def log_raster(
    rec: rr.RecordingStream,
    entity: str,
    raster: Raster,
    *,
    levels: Iterable[float] = (),
    mass_levels: Iterable[float] = DEFAULT_MASS_LEVELS,
    colormap: str = "viridis",
    log10_colormap: str = "turbo",
) -> list[MassRegion]:
    """Log one raster as a layer under ``entity`` at the current ``elapsed`` time.

    See the module docstring for the entities written. Call :func:`set_elapsed` first when a
    scene has several times.

    Parameters
    ----------
    rec : rerun.RecordingStream
        Where to log.
    entity : str
        Layer path, e.g. ``"cat"`` or ``"layers/cat"``.
    raster : Raster
        Density per square metre; values must be finite.
    levels : iterable of float
        Fixed contour levels, density per square metre, > 0 (none by default).
    mass_levels : iterable of float
        Probability-mass levels in (0, 1): the highest-density regions drawn as labelled
        contours (default 50, 90, 95 and 99 %).
    colormap, log10_colormap : str
        rerun colormap names for the density and the log10 density.

    Returns
    -------
    list of MassRegion
        The probability-mass regions drawn (see :func:`bananagrid.contours.mass_regions`).
    """
    entity = entity_path(entity)
    levels = tuple(positive(f"levels[{k}]", level) for k, level in enumerate(levels))
    _check_values(raster)
    regions = mass_regions(raster, mass_levels)
    floor = log10_floor(levels, regions, raster.peak)
    with strict():
        log_north_up(rec, entity)
        _log_density(rec, f"{entity}/density", raster, colormap)
        top = _log_log10_density(rec, f"{entity}/log10_density", raster, floor, log10_colormap)
        reached = [r for r in regions if r.reached]
        placed = _log_lines(
            rec, f"{entity}/contours", contour_lines(raster, [r.density for r in reached]),
            [format_level(r) for r in reached], MASS_COLOURS,
        )
        if levels:
            _log_lines(
                rec, f"{entity}/density_contours", contour_lines(raster, levels),
                [f"{level:g} m^-2" for level in levels], LEVEL_COLOURS, avoid=placed,
            )
        _log_legend(rec, f"{entity}/legend", focus_extent(raster, regions), floor, top, log10_colormap)
        info = raster_info(raster)
        info.update(flatten("regions", {f"{100 * r.probability:g}": r.describe() for r in regions}))
        rec.log(f"{entity}/info", rr.AnyValues(**info))
        rec.log(f"{entity}/mass", rr.Scalars(float(raster.mass)))
    return regions


def log_north_up(rec: rr.RecordingStream, entity: str) -> None:
    """Make ``entity``'s subtree (world metres, y north) show north up in a 2D view."""
    rec.log(entity_path(entity), rr.Transform3D(scale=(1.0, -1.0, 1.0)), static=True)


def image_from_values(values: np.ndarray) -> np.ndarray:
    """Grid values (row 0 south) as a float32 image (row 0 north, the image's top row)."""
    return np.ascontiguousarray(np.flipud(values), dtype=np.float32)


def values_from_image(image: np.ndarray) -> np.ndarray:
    """Inverse of :func:`image_from_values`: image rows back to grid rows (row 0 south)."""
    return np.ascontiguousarray(np.flipud(image))


def raster_info(raster: Raster) -> dict[str, float | str]:
    """Flat ``{key: number or string}`` of the raster's provenance, mass, peak and grid.

    Nested keys are joined with ``.`` (``grid.origin.0``); numbers become float so that a
    key keeps one arrow type across times; booleans become ``"true"``/``"false"``.
    """
    info = {
        "provenance": raster.provenance,
        "quantity": raster.quantity,
        "mass": raster.mass,
        "normalised": raster.normalised,
        "peak": raster.peak,
        "grid": raster.grid.describe(),
    }
    return dict(flatten("", info))


def flatten(prefix: str, value) -> Iterator[tuple[str, float | str]]:
    """Yield ``(dotted key, leaf)`` pairs of nested mappings and sequences."""
    if isinstance(value, Mapping):
        for key, item in value.items():
            yield from flatten(f"{prefix}.{key}" if prefix else str(key), item)
    elif isinstance(value, (list, tuple, np.ndarray)):
        for k, item in enumerate(value):
            yield from flatten(f"{prefix}.{k}", item)
    elif value is not None:
        yield prefix, _leaf(value)


def _leaf(value) -> float | str:
    """A plain number or string for AnyValues."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value)
    return str(value)


def _check_values(raster: Raster) -> None:
    """Raise unless the values match the grid and are finite (a colour range needs both)."""
    values = np.asarray(raster.values)
    if values.shape != raster.grid.shape:
        raise BananagridError(
            f"raster values have shape {values.shape}, the grid needs {raster.grid.shape}"
        )
    if not np.all(np.isfinite(values)):
        raise BananagridError("raster values contain NaN or inf; cannot record them")


def _log_density(rec: rr.RecordingStream, path: str, raster: Raster, colormap: str) -> None:
    """The density image with range ``(0, peak)`` and its pixel-to-world transform."""
    peak = raster.peak
    image = rr.DepthImage(
        image_from_values(raster.values),
        meter=1.0,
        colormap=colormap,
        depth_range=(0.0, peak if peak > 0.0 else 1.0),
    )
    rec.log(path, image, _pixel_to_world(raster))


def _log_log10_density(
    rec: rr.RecordingStream, path: str, raster: Raster, floor: float, colormap: str
) -> float:
    """``log10`` of the density, cells at or below ``10**floor`` shown at ``floor``, and the
    same transform as the density; returns the top of the colour range."""
    values = np.asarray(raster.values, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.where(values > 10.0**floor, np.log10(values), floor)
    top = float(logs.max())
    top = top if top > floor else floor + 1.0
    image = rr.DepthImage(image_from_values(logs), meter=1.0, colormap=colormap, depth_range=(floor, top))
    rec.log(path, image, _pixel_to_world(raster))
    return top


def log_cell_probabilities(rec: rr.RecordingStream, path: str, cells: Raster, *, colormap: str = "viridis") -> None:
    """The probability of each cell (a :class:`Raster` of ``quantity == "probability"``) as an
    image with range ``(0, largest cell)``, placed in world metres like the layer's density."""
    if cells.quantity != "probability":
        raise BananagridError(f"cells.quantity = {cells.quantity!r}: expected cell probabilities")
    _check_values(cells)
    with strict():
        _log_density(rec, entity_path(path), cells, colormap)


def log_signed_image(rec: rr.RecordingStream, path: str, values: np.ndarray, like: Raster) -> None:
    """A signed field on ``like``'s grid (a difference, a relative error) as an image with a
    diverging colormap symmetric about zero, placed in world metres like ``like``'s density."""
    bound = float(np.max(np.abs(values))) or 1.0
    with strict():
        rec.log(
            entity_path(path),
            rr.DepthImage(image_from_values(values), meter=1.0, colormap="cyantoyellow", depth_range=(-bound, bound)),
            _pixel_to_world(like),
        )


def colormaps() -> tuple[str, ...]:
    """The colormap names rerun knows, in lower case."""
    return tuple(c.name.lower() for c in rr.components.Colormap)


def log10_floor(levels: Sequence[float], regions: Sequence[MassRegion], peak: float) -> float:
    """Floor of the log10 image: ``LOG10_FLOOR_DECADES`` below the lowest contour drawn.

    The lowest contour is the outermost probability-mass region's boundary density or the
    lowest fixed level, whichever is lower; with neither, ``LOG10_FLOOR_DECADES`` below the
    peak's decade minus four. Zero cells (``log10 = -inf``) and anything below the floor are
    shown at the floor.
    """
    lowest = [r.density for r in regions if r.reached and r.density > 0.0] + list(levels)
    if lowest:
        return math.log10(min(lowest)) - LOG10_FLOOR_DECADES
    return (math.log10(peak) - 4.0 if peak > 0.0 else -12.0) - LOG10_FLOOR_DECADES


def _pixel_to_world(raster: Raster) -> rr.Transform3D:
    """Pixels of :func:`image_from_values` to world metres.

    Image pixel ``(u, v)`` covers ``[u, u+1] x [v, v+1]`` and row ``v = 0`` is the northern
    row, so ``x = x0 + dx u`` and ``y = y1 - dy v``; the centre of ``values[i, j]``, pixel
    ``(j + 1/2, ny - i - 1/2)``, lands on ``(x[j], y[i])``.
    """
    x0, _, _, y1 = raster.grid.extent
    return rr.Transform3D(translation=(x0, y1, 0.0), scale=(raster.grid.dx, -raster.grid.dy, 1.0))


def _log_lines(
    rec: rr.RecordingStream, path: str, lines: dict[float, list[np.ndarray]], labels: Sequence[str],
    colours: Sequence[tuple[int, int, int]], *, avoid: Sequence[tuple[float, float]] = (),
) -> list[tuple[float, float]]:
    """Contour lines under ``path/lines`` (one colour per level, unlabelled) and one label per
    level under ``path/labels``, placed on its line apart from the others and from ``avoid``
    (:func:`bananagrid.contours.label_positions`); returns the label positions. Empty lists
    clear both at this time. rerun writes a label in its point's colour on a dark box, so the
    label points are white whatever the line's colour."""
    strips, strip_colours = [], []
    for k, pieces in enumerate(lines.values()):
        strips += pieces
        strip_colours += [colours[k % len(colours)]] * len(pieces)
    rec.log(
        f"{path}/lines",
        rr.LineStrips2D(strips, colors=strip_colours, radii=rr.Radius.ui_points(1.5), draw_order=CONTOUR_DRAW_ORDER),
    )
    text = dict(zip(lines, labels))
    spots = label_positions(lines, avoid=avoid)
    rec.log(
        f"{path}/labels",
        rr.Points2D(
            [spots[level] for level in spots], labels=[text[level] for level in spots],
            colors=[(255, 255, 255)] * len(spots), radii=rr.Radius.ui_points(2.5),
            show_labels=True, draw_order=CONTOUR_DRAW_ORDER + 1,
        ),
    )
    return list(spots.values())


def union_extent(extents: Iterable[tuple[float, float, float, float]]) -> tuple[float, float, float, float]:
    """The smallest extent holding all of ``extents`` (at least one)."""
    x0, x1, y0, y1 = zip(*extents)
    return min(x0), max(x1), min(y0), max(y1)


def _log_legend(rec: rr.RecordingStream, path: str, extent: tuple, floor: float, top: float, colormap: str) -> None:
    """A scale bar below ``extent`` (the map's frame, see :func:`focus_extent`) and a log10
    colour bar east of it, in world metres.

    The colour bar is a one-pixel-wide image of ``COLOUR_BAR_PIXELS`` values from ``floor``
    (south end) to ``top`` (north end) in the log10 image's colormap and range, with a label
    at each whole decade; the scale bar is the roundest length (1, 2 or 5 x 10^k m) no longer
    than a quarter of the grid's width.
    """
    x0, x1, y0, y1 = extent
    width, height = x1 - x0, y1 - y0
    length = nice_length(width / 4.0)
    below = y0 - 0.05 * height
    rec.log(
        f"{path}/scale",
        rr.LineStrips2D(
            [[(x0, below), (x0 + length, below)]], colors=[(255, 255, 255)], radii=rr.Radius.ui_points(2.0),
            labels=[format_length(length)], show_labels=True,
        ),
    )
    bar_x0, bar_w = x1 + 0.03 * width, 0.025 * width
    ramp = np.linspace(top, floor, COLOUR_BAR_PIXELS, dtype=np.float32)[:, None]  # row 0 is the top
    rec.log(
        f"{path}/colour_bar",
        rr.DepthImage(ramp, meter=1.0, colormap=colormap, depth_range=(floor, top)),
        rr.Transform3D(translation=(bar_x0, y1, 0.0), scale=(bar_w, -height / COLOUR_BAR_PIXELS, 1.0)),
    )
    decades = np.arange(math.ceil(floor), math.floor(top) + 1)
    ticks = [(bar_x0 + bar_w, y0 + (d - floor) / (top - floor) * height) for d in decades]
    rec.log(
        f"{path}/ticks",
        rr.Points2D(
            ticks + [(bar_x0, y1 + 0.04 * height)],
            labels=[f"1e{int(d)}" for d in decades] + ["log10 m^-2"],
            colors=[(255, 255, 255)] * (len(ticks) + 1), radii=rr.Radius.ui_points(1.0), show_labels=True,
        ),
    )


def nice_length(limit: float) -> float:
    """The largest 1, 2 or 5 x 10^k not above ``limit`` (> 0)."""
    exponent = math.floor(math.log10(limit))
    for mantissa in (5.0, 2.0, 1.0):
        if mantissa * 10.0**exponent <= limit:
            return mantissa * 10.0**exponent
    return 10.0**exponent


def format_length(metres: float) -> str:
    """``500 m``, ``2 km``, ``0.5 m``."""
    if metres >= 1000.0:
        return f"{metres / 1000.0:g} km"
    return f"{metres:g} m"


# --- helpers ----------------------------------------------------------------------------------


def entity_path(entity: str) -> str:
    """``entity`` without leading or trailing slashes; raise if that leaves nothing."""
    if not isinstance(entity, str) or not entity.strip("/"):
        raise BananagridError(f"entity = {entity!r}: expected a non-empty entity path")
    return entity.strip("/")


def strict() -> catch_and_log_exceptions:
    """Make rerun raise on bad data inside this block instead of warning and dropping it.

    A recording that silently lacks a layer is worse than an error: :func:`write_recording`
    then removes the partial file. The setting is thread-local and restored on exit.
    """
    return catch_and_log_exceptions("bananagrid.recording", strict=True)
