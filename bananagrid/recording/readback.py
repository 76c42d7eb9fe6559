"""Read a bananagrid recording back: its rows, its images as arrays, its density layers as
rasters and its angular cell maps as probability tables (for ``inspect``, pictures and checks
without a viewer).

Everything goes through :class:`rerun.chunk.RrdReader`: each chunk of the (first) recording
store becomes an arrow record batch whose fields say, in their ``rerun:kind`` metadata,
whether a column is a timeline (``index``) or a component (``data``).

What ``bananagrid run`` writes and this module reads (see :mod:`bananagrid.recording.core` and
:mod:`bananagrid.recording.presence`):

- ``layers/NAME/density``: per elapsed time, the density (m^-2) as a float32 ``DepthImage``,
  rows north first, with a ``Transform3D`` from pixels to world metres (translation = the
  grid's north-west corner, scale = ``(dx, -dy)``);
- ``layers/NAME/info``: ``AnyValues`` of the raster (``mass``, ``normalised``, ``grid.*`` in
  float64, ``provenance.*``, ...);
- ``ENTITY/table`` and ``ENTITY/summary``: an array's cell probabilities p(C | S) as a float32
  ``DepthImage`` (columns azimuths, rows elevations) and its ``AnyValues`` (``cells``,
  ``region_probability``, ``provenance.lattice.*``, ...).
"""

from __future__ import annotations

import math
import os
import re
import tempfile
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun.chunk import RrdReader, StoreEntry

from ..domains.angular_lattice import AngularLattice
from ..domains.grid import Grid
from ..geo.frame import GeoFrame
from ..results import Raster
from ..validate import BananagridError, checked_in_child, regular_file
from .core import ELAPSED, elapsed_nanos, values_from_image
from .digest import DigestCheck, chunk_rows, is_internal, warn_undigested

__all__ = [
    "IMAGE_BUFFER", "IMAGE_FORMAT", "CheckedReader", "RecordedCellMap", "RecordedRaster", "check_in_child", "decode_image", "open_recording",
    "plain_cell", "read_cell_maps", "read_depth_image", "read_layers", "read_rasters", "recorded_frame",
    "recording_rows", "seconds",
]

IMAGE_BUFFER = "DepthImage:buffer"
IMAGE_FORMAT = "DepthImage:format"
_TRANSLATION = "Transform3D:translation"
_SCALE = "Transform3D:scale"
#: Relative slack between the float32 pixel transform and the float64 grid of a layer's info.
_TRANSFORM_RTOL = 1e-5


# --- reading rows -----------------------------------------------------------------------------


class CheckedReader(RrdReader):
    """An :class:`rerun.chunk.RrdReader` that knows whether its file has rerun's footer (what
    :func:`recording_rows` needs to tell a file cut short from another program's)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.checked = False  # set by open_recording once a child read it whole
        with warnings.catch_warnings(record=True) as caught:  # "RRD file has no footer": read by a full scan
            warnings.simplefilter("always")
            super().__init__(path)
            self.stores = self.recordings()
        self.footer = not any("no footer" in str(w.message) for w in caught)


def open_recording(path: str | os.PathLike) -> tuple[RrdReader, StoreEntry]:
    """The reader and the first recording store of ``path``; one-line errors naming it.

    Only a regular file is opened (a FIFO would block, a directory is no recording). The file
    is first read whole and checked against its digests in a child process
    (:func:`check_in_child`), since rerun's reader aborts the process on some damaged chunks."""
    path = regular_file(path, "a recording")
    check_in_child(path)
    reader, store = _open(path)
    reader.checked = True  # whole, in the child: recording_rows need not hash it again
    return reader, store


def _open(path: Path) -> tuple[CheckedReader, StoreEntry]:
    try:
        reader = CheckedReader(path)
        stores = reader.stores
    except (RuntimeError, ValueError, OSError) as exc:
        first_line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise BananagridError(f"{path}: not a readable .rrd file ({first_line})") from None
    if not stores:
        raise BananagridError(f"{path}: the file holds no recording (only blueprints)")
    return reader, stores[0]


#: Files checked whole by :func:`check_in_child` in this process, by path and version.
_CHECKED: set[tuple] = set()


def check_in_child(path: Path) -> None:
    """Read the recording at ``path`` whole and check it against its digests in a forked child
    process (:func:`bananagrid.validate.checked_in_child`), once per version of the file (path,
    inode, size, modification time) per process.

    rerun's reader decodes chunks on threads of its own, and a damaged chunk can make one panic
    and abort the whole process (measured: 1 in 150 random damages of a recording), which no
    ``except`` catches; a child that dies so says the file is damaged.

    Raises
    ------
    BananagridError
        One line naming the file: what the child found, or that rerun's reader crashed on it.
    """
    info = path.stat()
    key = (str(path.resolve()), info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)
    if key in _CHECKED:
        return
    checked_in_child(path, _read_whole)
    _CHECKED.add(key)


#: A line rerun's reader logs (on the process's stderr, from its own threads) where a chunk's
#: metadata is damaged but its rows still decode, e.g. "ERROR re_sorbet::migrations: ... could
#: not parse 'sorbet:version: 0.!.4'" (ANSI colours removed first).
RERUN_COMPLAINT = re.compile(r"\b(ERROR|WARN)\b\s+(\S+?):?\s+(.*)")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _read_whole(path: Path) -> None:
    """Read every row of ``path`` (in the child of :func:`check_in_child`), with what rerun's
    reader logs kept aside: a complaint of its (a damaged schema it read past) is the file's
    damage too, so that the file is refused rather than read with rerun's noise on stderr."""
    with tempfile.TemporaryFile() as log:
        saved = os.dup(2)
        os.dup2(log.fileno(), 2)
        try:
            reader, store = _open(path)
            for _ in recording_rows(reader, store):
                pass
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        log.seek(0)
        logged = _ANSI.sub("", log.read().decode(errors="replace"))
    for line in logged.splitlines():
        if match := RERUN_COMPLAINT.search(line):
            raise BananagridError(f"{path}: damaged (rerun's reader: {match.group(3).strip()[:200]})")


def recording_rows(reader: RrdReader, store: StoreEntry) -> Iterator[tuple[str, dict, dict]]:
    """Yield ``(entity_path, times, components)`` for every row of the recording store, then
    check the rows against the digests bananagrid logged beside them
    (:mod:`bananagrid.recording.digest`; those rows are not yielded). A reader from
    :func:`open_recording` was checked whole by a child already, and is not hashed again.

    ``times`` maps timeline name to ``(kind, value)`` (empty for static rows); ``components``
    maps component name to ``(archetype, arrow list value)`` for the non-null cells. Read every
    row: the check comes after the last.

    Raises
    ------
    BananagridError
        If a chunk cannot be decoded, or a row does not match its digest, or rows or digests
        are missing (a damaged file), naming the file. A whole recording without any digest
        (another program's) warns once instead (:class:`~bananagrid.validate.BananagridWarning`).
    """
    check = None if getattr(reader, "checked", False) else DigestCheck(str(reader.path))
    digests = 0
    try:
        for entity, times, cells in chunk_rows(reader, store, footer=getattr(reader, "footer", False)):
            internal = check.add(entity, times, cells) if check is not None else is_internal(entity)
            digests += internal
            if not internal:
                yield entity, times, cells
        if check is None:  # checked whole by a child: only its warning is left to give
            if not digests:
                warn_undigested(str(reader.path))
            return
        blueprint = bool(reader.blueprints())
    except (RuntimeError, ValueError, IndexError, TypeError, KeyError, OSError, pa.ArrowException) as exc:
        if isinstance(exc, BananagridError):
            raise
        first_line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise BananagridError(f"{reader.path}: a damaged .rrd file ({first_line})") from None
    check.finish(application_id=store.application_id, recording_id=store.recording_id, blueprint=blueprint,
                 footer=getattr(reader, "footer", False))


def seconds(kind: str, value: int) -> float | int:
    """A timeline value for people: seconds for durations and timestamps, else as is."""
    return value / 1e9 if kind in ("duration", "timestamp") else value


def decode_image(buffer: pa.Scalar, image_format: pa.Scalar) -> np.ndarray:
    """A logged image cell back to a ``(height, width)`` array of its channel type."""
    fmt = image_format.values[0].as_py()
    raw = buffer.values[0].values.to_numpy(zero_copy_only=False)
    dtype = rr.ChannelDatatype(fmt["channel_datatype"]).to_np_dtype()
    return np.frombuffer(raw.tobytes(), dtype=dtype).reshape(fmt["height"], fmt["width"])


def plain_cell(cell: pa.Scalar):
    """A component cell (a list) as a python value: its only item, or the list."""
    items = cell.as_py()
    return items[0] if len(items) == 1 else items


# --- images back as arrays --------------------------------------------------------------------


def read_depth_image(
    path: str | os.PathLike, entity_path: str, elapsed: float | None = None
) -> np.ndarray:
    """The ``DepthImage`` logged at ``entity_path`` as grid values (row 0 south).

    Undoes the north-first row order of :func:`bananagrid.recording.core.image_from_values`, so the
    result has the orientation and shape ``(ny, nx)`` of the raster's values, in float32.

    Parameters
    ----------
    path : path-like
        The ``.rrd`` file.
    entity_path : str
        E.g. ``"cat/density"`` (a leading ``/`` is optional).
    elapsed : float, optional
        Elapsed seconds of the row to read; by default the latest row.

    Raises
    ------
    BananagridError
        If the file is unreadable, or holds no image there (at that time).
    """
    entity = "/" + entity_path.strip("/")
    reader, store = open_recording(path)
    images = [
        (times.get(ELAPSED, (None, -1))[1], cells)
        for name, times, cells in recording_rows(reader, store)
        if name == entity and IMAGE_BUFFER in cells and IMAGE_FORMAT in cells
    ]
    if elapsed is not None:
        wanted = elapsed_nanos(elapsed)
        images = [(t, cells) for t, cells in images if t == wanted]
    if not images:
        at = "" if elapsed is None else f" at elapsed = {elapsed:g} s"
        raise BananagridError(f"{path}: no DepthImage at {entity}{at}")
    _, cells = max(images, key=lambda item: item[0])
    return values_from_image(decode_image(cells[IMAGE_BUFFER][1], cells[IMAGE_FORMAT][1]))


# --- density layers as rasters ----------------------------------------------------------------


@dataclass(frozen=True)
class RecordedRaster:
    """One density layer at one elapsed time, read back from a recording.

    Attributes
    ----------
    layer : str
        Layer name (``"cat"``).
    entity : str
        Its entity (``"layers/cat"``).
    t : float
        Elapsed time, s (0 for a layer logged without time).
    raster : Raster
        The density (m^-2), float64 of the recorded float32 image, rows south to north, on the
        layer's grid (float64 from its info, else rebuilt from the image's pixel-to-world
        transform and shape); ``mass`` (the raw captured mass, NaN if not recorded),
        ``normalised`` and ``quantity`` from the info; ``provenance`` the info's
        ``provenance.*`` values under their dotted keys without the prefix (``"sigma_a"``,
        ``"lattice.h"``), numbers as recorded (float).
    """

    layer: str
    entity: str
    t: float
    raster: Raster


def read_rasters(path: str | os.PathLike) -> list[RecordedRaster]:
    """Every density layer (``layers/NAME/density``) of a recording written by ``bananagrid
    run``, as rasters, ordered by time, then layer name.

    Parameters
    ----------
    path : path-like
        The ``.rrd`` file.

    Returns
    -------
    list of RecordedRaster
        One per layer and elapsed time.

    Raises
    ------
    BananagridError
        If the file is not a readable recording, holds no density layer (an array scene's
        recording holds cell maps instead: :func:`read_cell_maps`), a layer's image has
        neither a grid in its info nor a pixel-to-world transform, or they disagree, or an image
        holds NaN or inf (a damaged file).
    """
    found = read_layers(path)
    if not found:
        raise BananagridError(
            f"{path}: no density layers (layers/NAME/density); is it a recording of a scene with grid layers?"
        )
    return found


def read_layers(path: str | os.PathLike) -> list[RecordedRaster]:
    """As :func:`read_rasters`, but an empty list for a recording without density layers.

    Raises
    ------
    BananagridError
        If the file is not a readable recording, or a layer's grid cannot be rebuilt.
    """
    reader, store = open_recording(path)
    images, transforms, infos = {}, {}, {}
    for name, times, cells in recording_rows(reader, store):
        parts = name.strip("/").split("/")
        if len(parts) != 3 or parts[0] != "layers":
            continue
        key = (parts[1], times[ELAPSED][1] if ELAPSED in times else None)  # None: static
        if parts[2] == "density":
            if IMAGE_BUFFER in cells and IMAGE_FORMAT in cells:
                images[key] = decode_image(cells[IMAGE_BUFFER][1], cells[IMAGE_FORMAT][1])
            if _TRANSLATION in cells and _SCALE in cells:
                transforms[key] = (plain_cell(cells[_TRANSLATION][1]), plain_cell(cells[_SCALE][1]))
        elif parts[2] == "info":
            infos[key] = {
                component.removeprefix("AnyValues:"): plain_cell(value) for component, (_, value) in cells.items()
            }
    out = []
    for (layer, nanos), image in sorted(images.items(), key=lambda item: (item[0][1] or 0, item[0][0])):
        entity = f"layers/{layer}"
        info = _latest(infos, layer, nanos, {})
        values = values_from_image(image).astype(np.float64)
        if not np.all(np.isfinite(values)):  # run logs finite densities only
            raise BananagridError(f"{path}: {entity}/density ({_when(nanos)}) holds NaN or inf: a damaged file")
        grid = _layer_grid(f"{path}: {entity}/density", values.shape, info, _latest(transforms, layer, nanos))
        provenance = {k.removeprefix("provenance."): v for k, v in info.items() if k.startswith("provenance.")}
        mass = info.get("mass")
        raster = Raster(
            values=values, grid=grid, mass=float(mass) if isinstance(mass, (int, float)) else math.nan,
            normalised=info.get("normalised") == "true", quantity=str(info.get("quantity", "density")),
            provenance=provenance, frame=recorded_frame(provenance),
        )
        out.append(RecordedRaster(layer, entity, 0.0 if nanos is None else nanos / 1e9, raster))
    return out


def recorded_frame(provenance: dict) -> GeoFrame | None:
    """The geographic frame a layer's flattened provenance names (``geo.lat``, ``geo.lon``,
    ``geo.time``, ``geo.crs``), or None: a scene in local metres, or pyproj missing (the geo
    extra), when positions stay in metres."""
    keys = ("geo.lat", "geo.lon", "geo.crs")
    if not all(k in provenance for k in keys):
        return None
    try:
        return GeoFrame.from_identity({
            "lat": provenance["geo.lat"], "lon": provenance["geo.lon"],
            "time": provenance.get("geo.time") or None, "crs": provenance["geo.crs"],
        })
    except BananagridError:
        return None


def _when(nanos: int | None) -> str:
    """An elapsed time for messages."""
    return "static" if nanos is None else f"t = {nanos / 1e9:g} s"


def _latest(by_key: dict, name: str, nanos: int | None, default=None):
    """The value logged for ``name`` at ``nanos``, else its static one, else ``default``."""
    return by_key.get((name, nanos), by_key.get((name, None), default))


def _layer_grid(where: str, shape: tuple[int, int], info: dict, transform) -> Grid:
    """The layer's grid: from its info's float64 ``grid.*`` values, checked against the image's
    shape and (to float32 precision) its pixel-to-world transform; else from the transform."""
    ny, nx = shape
    keys = ("grid.origin.0", "grid.origin.1", "grid.dx", "grid.dy", "grid.nx", "grid.ny")
    from_info = None
    if info and all(isinstance(info.get(k), (int, float)) for k in keys):
        if (int(info["grid.ny"]), int(info["grid.nx"])) != (ny, nx):
            raise BananagridError(
                f"{where}: the image is {ny} x {nx} (rows x cols) but the layer's info says "
                f"grid.ny x grid.nx = {info['grid.ny']:g} x {info['grid.nx']:g}"
            )
        from_info = Grid(origin=(info["grid.origin.0"], info["grid.origin.1"]), dx=info["grid.dx"],
                         dy=info["grid.dy"], nx=nx, ny=ny)
    if transform is None:
        if from_info is None:
            raise BananagridError(f"{where}: no pixel-to-world transform and no grid.* values in its info")
        return from_info
    (x0, y1, _), (sx, sy, _) = transform
    if not (sx > 0.0 and sy < 0.0):
        raise BananagridError(
            f"{where}: pixel-to-world scale ({sx:g}, {sy:g}): expected (dx, -dy) with dx, dy > 0 (rows north first)"
        )
    from_transform = Grid(origin=(float(x0), float(y1) + float(sy) * ny), dx=float(sx), dy=-float(sy), nx=nx, ny=ny)
    if from_info is None:
        return from_transform
    scale = max(abs(v) for v in (*from_info.extent, from_info.dx * nx, from_info.dy * ny))
    if not np.allclose(from_info.extent, from_transform.extent, rtol=0.0, atol=_TRANSFORM_RTOL * scale):
        raise BananagridError(
            f"{where}: its pixel-to-world transform spans {_extent(from_transform)} but its info's grid "
            f"{_extent(from_info)}"
        )
    return from_info


def _extent(grid: Grid) -> str:
    x0, x1, y0, y1 = grid.extent
    return f"x {x0:g} .. {x1:g} m, y {y0:g} .. {y1:g} m"


# --- angular cell maps ------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordedCellMap:
    """One array's angular cell map at one elapsed time, read back from a recording.

    Attributes
    ----------
    entity : str
        Its entity (``"presence"``).
    t : float
        Elapsed time, s.
    prob : ndarray
        Cell probabilities p(C | S) (per cell, not densities), float64 of the recorded float32
        table, indexed ``[azimuth, elevation]`` (``[azimuth]`` for a line).
    lattice : AngularLattice or None
        The lattice, rebuilt from the summary's ``provenance.lattice.*`` values (None where
        they are missing or do not describe a lattice of ``prob``'s shape).
    summary : dict
        The ``ENTITY/summary`` values under their dotted keys (``cells``,
        ``region_probability``, ``total``, ``peak``, ``provenance.*``, ...).
    """

    entity: str
    t: float
    prob: np.ndarray
    lattice: AngularLattice | None
    summary: dict = field(default_factory=dict)


def read_cell_maps(path: str | os.PathLike) -> list[RecordedCellMap]:
    """Every angular cell map (``ENTITY/table`` beside ``ENTITY/summary``) of a recording, by
    time, then entity; empty for a recording without one.

    Raises
    ------
    BananagridError
        If the file is not a readable recording.
    """
    reader, store = open_recording(path)
    tables, summaries = {}, {}
    for name, times, cells in recording_rows(reader, store):
        entity, _, leaf = name.strip("/").rpartition("/")
        key = (entity, times[ELAPSED][1] if ELAPSED in times else None)
        if leaf == "table" and IMAGE_BUFFER in cells and IMAGE_FORMAT in cells:
            tables[key] = decode_image(cells[IMAGE_BUFFER][1], cells[IMAGE_FORMAT][1])
        elif leaf == "summary" and any(archetype == "AnyValues" for archetype, _ in cells.values()):
            summaries[key] = {
                component.removeprefix("AnyValues:"): plain_cell(value)
                for component, (archetype, value) in cells.items() if archetype == "AnyValues"
            }
    out = []
    for (entity, nanos), image in sorted(tables.items(), key=lambda item: (item[0][1] or 0, item[0][0])):
        summary = summaries.get((entity, nanos), summaries.get((entity, None)))
        if summary is None or "cells" not in summary:
            continue  # a table image that is not a cell map's
        lattice = _lattice(summary)
        if lattice is not None and lattice.geometry == "line":
            prob = image[0].astype(np.float64)
        else:
            prob = np.ascontiguousarray(image.T, dtype=np.float64)
        if not np.all(np.isfinite(prob)):
            raise BananagridError(f"{path}: {entity}/table ({_when(nanos)}) holds NaN or inf: a damaged file")
        if lattice is not None and lattice.shape != prob.shape:
            lattice = None
        out.append(RecordedCellMap(entity, 0.0 if nanos is None else nanos / 1e9, prob, lattice, summary))
    return out


def _lattice(summary: dict) -> AngularLattice | None:
    """The lattice that ``provenance.lattice.*`` describes, or None."""
    key = "provenance.lattice."
    values = {k.removeprefix(key): v for k, v in summary.items() if k.startswith(key)}

    def pair(name: str):
        first, last = values.get(f"{name}.0"), values.get(f"{name}.1")
        return None if first is None or last is None else (first, last)

    try:
        return AngularLattice(
            geometry=values["geometry"], h=values["h"], dh=values.get("dh", 0.0),
            azimuth_step=values["azimuth_step"], elevation_step=values.get("elevation_step"),
            azimuth_range=pair("azimuth_range"), elevation_range=pair("elevation_range"),
        )
    except (KeyError, TypeError, BananagridError):
        return None
