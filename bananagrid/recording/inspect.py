"""Read a recording back without a viewer: what it holds, and its images as arrays.

Everything goes through :class:`rerun.chunk.RrdReader`: each chunk of the (first) recording
store becomes an arrow record batch whose fields say, in their ``rerun:kind`` metadata,
whether a column is a timeline (``index``) or a component (``data``).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun.chunk import RrdReader, StoreEntry

from ..validate import BananagridError
from .core import ELAPSED, elapsed_nanos, values_from_image

__all__ = [
    "IMAGE_BUFFER", "IMAGE_FORMAT", "decode_image", "format_inspection", "inspect_recording", "open_recording",
    "plain_cell", "read_depth_image", "recording_rows",
]

IMAGE_BUFFER = "DepthImage:buffer"
IMAGE_FORMAT = "DepthImage:format"
_SCALARS = "Scalars:scalars"


# --- reading rows -----------------------------------------------------------------------------


def open_recording(path: str | os.PathLike) -> tuple[RrdReader, StoreEntry]:
    """The reader and the first recording store of ``path``; one-line errors naming it."""
    path = Path(path)
    if not path.exists():
        raise BananagridError(f"{path}: no such file")
    if not path.is_file():
        raise BananagridError(f"{path}: not a file")
    try:
        reader = RrdReader(path)
        stores = reader.recordings()
    except (RuntimeError, ValueError, OSError) as exc:
        first_line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise BananagridError(f"{path}: not a readable .rrd file ({first_line})") from None
    if not stores:
        raise BananagridError(f"{path}: the file holds no recording (only blueprints)")
    return reader, stores[0]


def recording_rows(reader: RrdReader, store: StoreEntry) -> Iterator[tuple[str, dict, dict]]:
    """Yield ``(entity_path, times, components)`` for every row of the recording store.

    ``times`` maps timeline name to ``(kind, value)`` (empty for static rows); ``components``
    maps component name to ``(archetype, arrow list value)`` for the non-null cells.
    """
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        indexes, data = _columns(batch)
        for row in range(batch.num_rows):
            times = {name: (kind, int(column[row])) for name, (kind, column) in indexes.items()}
            cells = {
                name: (archetype, column[row])
                for name, (archetype, column) in data.items()
                if column[row].is_valid
            }
            yield chunk.entity_path, times, cells


def _columns(batch: pa.RecordBatch) -> tuple[dict, dict]:
    """Split a chunk's columns into timelines ``{name: (kind, column)}`` and components
    ``{name: (archetype, column)}``; control columns (row ids) are dropped.

    Timeline columns come back as int64 numpy arrays (nanoseconds for durations and
    timestamps).
    """
    indexes, data = {}, {}
    for field, column in zip(batch.schema, batch.columns):
        meta = {k.decode(): v.decode() for k, v in (field.metadata or {}).items()}
        if meta.get("rerun:kind") == "index":
            times = column.cast(pa.int64()).to_numpy(zero_copy_only=False)
            indexes[meta.get("rerun:index_name", field.name)] = (_time_kind(field.type), times)
        elif meta.get("rerun:kind") == "data":
            archetype = meta.get("rerun:archetype", "AnyValues").rsplit(".", 1)[-1]
            data[meta.get("rerun:component", field.name)] = (archetype, column)
    return indexes, data


def _time_kind(datatype: pa.DataType) -> str:
    """``duration``, ``timestamp`` or ``sequence`` from a timeline column's arrow type."""
    if pa.types.is_duration(datatype):
        return "duration"
    if pa.types.is_timestamp(datatype):
        return "timestamp"
    return "sequence"


def _seconds(kind: str, value: int) -> float | int:
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


# --- inspection -------------------------------------------------------------------------------


def inspect_recording(path: str | os.PathLike) -> dict:
    """Summarise an ``.rrd`` file without a viewer.

    Returns
    -------
    dict
        ``path``, ``application_id``, ``recording_id``, ``blueprint`` (whether a blueprint
        store is embedded), ``timelines`` ``{name: {kind, count, min, max, values}}`` (seconds
        for durations) and ``entities`` ``{path: summary}``. An entity summary has
        ``archetypes`` and ``components`` (sorted names), ``static_rows``, ``temporal_rows``,
        and where present ``image_shapes`` (``(height, width)``) and ``value_range``
        (min, max over all its images), ``scalars`` and ``values`` (AnyValues): lists of
        ``{"times": {timeline: value}, "values": ...}`` in time order.

    Raises
    ------
    BananagridError
        If ``path`` is missing or not a readable recording.
    """
    reader, store = open_recording(path)
    timelines: dict[str, dict] = {}
    entities: dict[str, dict] = {}
    for entity, times, cells in recording_rows(reader, store):
        _add_times(timelines, times)
        _add_row(entities.setdefault(entity, _new_entity()), times, cells)
    return {
        "path": str(path),
        "application_id": store.application_id,
        "recording_id": store.recording_id,
        "blueprint": bool(reader.blueprints()),
        "timelines": {name: _timeline_summary(t) for name, t in sorted(timelines.items())},
        "entities": {name: _entity_summary(e) for name, e in sorted(entities.items())},
    }


def _add_times(timelines: dict, times: dict) -> None:
    """Collect the values seen on each timeline."""
    for name, (kind, value) in times.items():
        timelines.setdefault(name, {"kind": kind, "values": set()})["values"].add(value)


def _timeline_summary(timeline: dict) -> dict:
    """Kind, count, range and sorted distinct values of one timeline (seconds where timed)."""
    kind = timeline["kind"]
    values = [_seconds(kind, v) for v in sorted(timeline["values"])]
    return {
        "kind": kind, "count": len(values), "min": values[0], "max": values[-1], "values": values
    }


def _new_entity() -> dict:
    """An empty per-entity accumulator."""
    return {"archetypes": set(), "components": set(), "static_rows": 0, "temporal_rows": 0,
            "image_shapes": set(), "ranges": [], "scalars": [], "values": []}


def _add_row(acc: dict, times: dict, cells: dict) -> None:
    """Fold one row into its entity's accumulator."""
    acc["static_rows" if not times else "temporal_rows"] += 1
    acc["components"].update(cells)
    acc["archetypes"].update(archetype for archetype, _ in cells.values())
    when = {name: _seconds(kind, value) for name, (kind, value) in times.items()}
    if IMAGE_BUFFER in cells and IMAGE_FORMAT in cells:
        image = decode_image(cells[IMAGE_BUFFER][1], cells[IMAGE_FORMAT][1])
        acc["image_shapes"].add(image.shape)
        acc["ranges"].append((float(np.min(image)), float(np.max(image))))
    if _SCALARS in cells:
        acc["scalars"].append({"times": when, "values": plain_cell(cells[_SCALARS][1])})
    untyped = {
        name: plain_cell(cell) for name, (archetype, cell) in cells.items() if archetype == "AnyValues"
    }
    if untyped:
        acc["values"].append({"times": when, "values": dict(sorted(untyped.items()))})


def _entity_summary(acc: dict) -> dict:
    """Plain-data summary of one entity; empty parts are left out."""
    summary = {
        "archetypes": sorted(acc["archetypes"]),
        "components": sorted(acc["components"]),
        "static_rows": acc["static_rows"],
        "temporal_rows": acc["temporal_rows"],
    }
    if acc["image_shapes"]:
        summary["image_shapes"] = sorted(acc["image_shapes"])
        lows, highs = zip(*acc["ranges"])
        summary["value_range"] = (min(lows), max(highs))
    for key in ("scalars", "values"):
        if acc[key]:
            summary[key] = sorted(acc[key], key=lambda sample: sorted(sample["times"].items()))
    return summary


# --- formatting -------------------------------------------------------------------------------


def format_inspection(info: dict) -> str:
    """Render :func:`inspect_recording`'s result as a plain-text report."""
    lines = [
        f"recording  {info['path']}",
        f"  application {info['application_id']}, id {info['recording_id']}, "
        f"blueprint {'embedded' if info['blueprint'] else 'none'}",
        "",
        "timelines",
    ]
    timelines = [_timeline_line(name, t) for name, t in info["timelines"].items()]
    lines += timelines or ["  (none: static only)"]
    lines += ["", "entities"]
    width = max((len(name) for name in info["entities"]), default=0)
    for name, entity in info["entities"].items():
        lines += _entity_lines(name.ljust(width), entity)
    return "\n".join(lines)


def _timeline_line(name: str, timeline: dict) -> str:
    """One line per timeline: kind, number of values and range."""
    unit = " s" if timeline["kind"] in ("duration", "timestamp") else ""
    return (
        f"  {name}  {timeline['kind']}  {timeline['count']} value(s)  "
        f"{timeline['min']:g}{unit} .. {timeline['max']:g}{unit}"
    )


def _entity_lines(name: str, entity: dict) -> list[str]:
    """The entity's headline, then indented details for images, scalars and values."""
    rows = f"{entity['temporal_rows']} temporal + {entity['static_rows']} static row(s)"
    lines = [f"  {name}  {', '.join(entity['archetypes'])}  ({rows})"]
    indent = " " * (len(name) + 4)
    if "image_shapes" in entity:
        shapes = ", ".join(f"{h}x{w}" for h, w in entity["image_shapes"])
        low, high = entity["value_range"]
        lines.append(f"{indent}image {shapes} (rows x cols), values {low:.6g} .. {high:.6g}")
    for sample in entity.get("scalars", []):
        lines.append(f"{indent}{_when(sample['times'])}: {sample['values']}")
    if "values" in entity:
        latest = entity["values"][-1]
        lines.append(f"{indent}values at {_when(latest['times'])}:")
        lines += [f"{indent}  {key} = {_number(value)}" for key, value in latest["values"].items()]
    return lines


def _number(value):
    """A recorded value as printed: whole floats as integers (recordings store every number
    as a float, so that a key keeps one type across times: ``grid.nx = 1500``)."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return int(value)
    return value


def _when(times: dict) -> str:
    """``elapsed=1.5`` style label for a row's times (``static`` for none)."""
    return ", ".join(f"{name}={value:g}" for name, value in sorted(times.items())) or "static"


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
