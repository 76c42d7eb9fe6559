"""Content digests of recordings: damage to a file is an error, never a wrong number.

rerun's chunks carry no checksum: a byte flipped or a block zeroed inside an image's data reads
back without error (measured: a zeroed 60-byte block in a 100 x 100 layer changed its 99 %
region by 2 %, exit 0). So every row that bananagrid logs carries a digest of its own:

- :class:`DigestingRecording` (the stream :func:`bananagrid.recording.core.new_recording`
  makes) logs, after each row, a row under :data:`DIGESTS` at the same time (static with a
  static row) holding the row's entity and the BLAKE2b digest of its components (name,
  archetype and every value, as arrow arrays; :func:`row_digest`). Each entity's digests go to
  an entity of their own, ``DIGESTS`` + the entity's path: layers logged from several threads
  then never interleave their digests, so two runs of a scene cut the same chunks;
- at the end it logs one static :data:`MANIFEST`: how many rows it logged, a digest of all
  their digests, the recording and application ids and whether a blueprint store was sent, so
  that rows lost whole (a chunk dropped, a file cut short) and damaged store headers are caught
  too.

Reading (:func:`chunk_rows` and :class:`DigestCheck`, as
:func:`bananagrid.recording.readback.recording_rows` does) recomputes each row's digest from
what was read and checks that the rows and the digests match one for one, and the manifest.

Recordings without any digest (written by another program, or by a bananagrid before digests)
are read with one :class:`~bananagrid.validate.BananagridWarning` saying that damage to them
cannot be detected, when they are whole (rerun's footer is there); without their footer they
are refused: that is what a bananagrid recording cut short before its digests looks like, and
rerun writes the footer for every file it closes.
"""

from __future__ import annotations

import hashlib
import threading
import warnings
from collections import Counter
from collections.abc import Iterable, Iterator

import numpy as np
import pyarrow as pa
import rerun as rr

from ..validate import BananagridError, BananagridWarning

__all__ = [
    "DIGESTS", "MANIFEST", "DigestCheck", "DigestingRecording", "array_digest", "chunk_rows", "is_internal",
    "row_digest", "warn_undigested",
]

#: Root of the per-row digests (one entity below it per entity logged); :data:`MANIFEST` holds
#: the summary. Neither is in any view of the default blueprint (its views name their
#: contents), and readers skip both.
DIGESTS = "bananagrid/digests"
MANIFEST = "bananagrid/manifest"
#: Files already warned about as holding no digests: ``inspect`` reads a file three times, and
#: one warning says it all.
_WARNED: set[str] = set()
#: Bytes of each BLAKE2b digest: 128 bits, ample against chance (damage is not an adversary).
DIGEST_BYTES = 16


# --- digests of arrow values ------------------------------------------------------------------


def array_digest(hasher, array: pa.Array) -> None:
    """Feed the logical content of ``array`` into ``hasher``: lengths, validity, every value
    and its NumPy dtype, through lists, fixed-size lists and structs. Offsets, slicing and
    buffer padding do not count, so an array as logged and the same array as read back from
    a chunk give the same bytes."""
    kind = array.type
    hasher.update(f"<{len(array)},{array.null_count}".encode())
    if array.null_count:
        hasher.update(np.packbits(np.asarray(array.is_valid().to_numpy(zero_copy_only=False))).tobytes())
    if pa.types.is_list(kind) or pa.types.is_large_list(kind):
        lengths = array.value_lengths().fill_null(0).to_numpy(zero_copy_only=False).astype("<i8")
        hasher.update(b"list")
        hasher.update(lengths.tobytes())
        array_digest(hasher, array.flatten())
    elif pa.types.is_fixed_size_list(kind):
        hasher.update(f"fixed{kind.list_size}".encode())
        array_digest(hasher, array.flatten())
    elif pa.types.is_struct(kind):
        hasher.update(b"struct")
        for index, child in enumerate(array.flatten()):
            hasher.update(kind.field(index).name.encode() + b"\0")
            array_digest(hasher, child)
    elif pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_boolean(kind):
        values = np.ascontiguousarray(array.to_numpy(zero_copy_only=False))
        hasher.update(values.dtype.str.encode())
        hasher.update(values.view(np.uint8).ravel() if values.dtype != object else repr(values.tolist()).encode())
    else:  # strings, binaries, unions: small in bananagrid's recordings
        hasher.update(str(kind).encode())
        hasher.update(repr(array.to_pylist()).encode())
    hasher.update(b">")


def row_digest(entity: str, components: Iterable[tuple[str, str, pa.Array]]) -> str:
    """Hex digest of one row: its entity (``/a/b``) and its ``(component, archetype, values)``
    triples, in component order."""
    hasher = hashlib.blake2b(digest_size=DIGEST_BYTES)
    hasher.update(entity.encode() + b"\0")
    for name, archetype, values in sorted(components, key=lambda item: item[0]):
        hasher.update(f"{name}\0{archetype}\0".encode())
        array_digest(hasher, values)
    return hasher.hexdigest()


def is_internal(entity: str) -> bool:
    """Whether a row read at ``entity`` is a digest or the manifest, not data."""
    return entity == "/" + MANIFEST or entity == "/" + DIGESTS or entity.startswith("/" + DIGESTS + "/")


def _entity(path) -> str:
    """An entity path as the reader names it: ``/a/b``."""
    if isinstance(path, (list, tuple)):
        return "/" + "/".join(rr.escape_entity_path_part(str(part)) for part in path)
    return "/" + str(path).strip("/")


def _combined(pairs: Iterable[tuple[str, str]]) -> str:
    """One digest of a multiset of ``(entity, row digest)`` pairs (order does not count)."""
    hasher = hashlib.blake2b(digest_size=DIGEST_BYTES)
    for entity, digest in sorted(pairs):
        hasher.update(f"{entity}\0{digest}\n".encode())
    return hasher.hexdigest()


# --- writing ----------------------------------------------------------------------------------


class DigestingRecording(rr.RecordingStream):
    """A :class:`rerun.RecordingStream` that logs a digest after every row (see the module
    docstring) and, at :meth:`log_manifest`, their summary."""

    def __init__(self, application_id: str, *, recording_id: str, **kwargs) -> None:
        super().__init__(application_id, recording_id=recording_id, **kwargs)
        self._ids = (application_id, recording_id)
        self._lock = threading.Lock()
        self._pairs: list[tuple[str, str]] = []
        self._blueprint = False

    def log(self, entity_path, entity, *extra, static: bool = False, strict: bool | None = None) -> None:
        """As :meth:`rerun.RecordingStream.log`, then the row's digest at the same time."""
        batches = []
        for item in (entity, *extra):
            found = getattr(item, "as_component_batches", None)
            batches.extend(found() if found is not None else item)
        components, seen = [], set()
        for batch in batches:  # as rerun does: a component given twice counts once, None not at all
            descriptor, values = batch.component_descriptor(), batch.as_arrow_array()
            if values is None or descriptor in seen:
                continue
            seen.add(descriptor)
            archetype = (descriptor.archetype or "AnyValues").rsplit(".", 1)[-1]
            components.append((descriptor.component, archetype, values))
        super().log(entity_path, batches, static=static, strict=strict)
        name = _entity(entity_path)
        digest = row_digest(name, components)
        with self._lock:
            self._pairs.append((name, digest))
        super().log(DIGESTS + name, rr.AnyValues(entity=name, digest=digest), static=static, strict=True)

    def send_blueprint(self, blueprint, *args, **kwargs) -> None:
        """As :meth:`rerun.RecordingStream.send_blueprint`; the manifest says a blueprint was sent."""
        self._blueprint = True
        super().send_blueprint(blueprint, *args, **kwargs)

    def log_manifest(self, *, blueprint: bool = False) -> None:
        """Log the static manifest; call once, after everything else (``blueprint``: a default
        blueprint was embedded when the file was opened)."""
        with self._lock:
            pairs = list(self._pairs)
        application_id, recording_id = self._ids
        super().log(MANIFEST, rr.AnyValues(
            rows=float(len(pairs)), digest=_combined(pairs), recording_id=recording_id,
            application_id=application_id, blueprint="true" if (blueprint or self._blueprint) else "false",
        ), static=True, strict=True)


# --- reading ----------------------------------------------------------------------------------


def chunk_rows(reader, store, *, footer: bool) -> Iterator[tuple[str, dict, dict]]:
    """Yield ``(entity_path, times, components)`` for every row of ``store`` (all of them,
    digests included; :func:`bananagrid.recording.readback.recording_rows` checks and hides
    those). ``times`` maps timeline name to ``(kind, value)`` (empty for static rows);
    ``components`` maps component name to ``(archetype, arrow list value)`` for the non-null
    cells. Decoding errors propagate as rerun and arrow raise them.

    With rerun's ``footer`` the chunks are read where its index says they are: a scan of the
    file stops without a word at a damaged message header (measured: one flipped bit in a
    length and the scan yielded no chunk at all), the index does not."""
    chunks = reader.store(store=store).stream() if footer else reader.stream(store=store)
    for chunk in chunks:
        batch = chunk.to_record_batch()
        indexes, data = _columns(batch)
        rows = []
        for row in range(batch.num_rows):
            times = {name: (kind, int(column[row])) for name, (kind, column) in indexes.items()}
            cells = {
                name: (archetype, column[row])
                for name, (archetype, column) in data.items()
                if column[row].is_valid
            }
            rows.append((chunk.entity_path, times, cells))
        yield from rows


def _columns(batch: pa.RecordBatch) -> tuple[dict, dict]:
    """Split a chunk's columns into timelines ``{name: (kind, column)}`` and components
    ``{name: (archetype, column)}``; control columns (row ids) are dropped.

    Timeline columns come back as int64 numpy arrays (nanoseconds for durations and
    timestamps).
    """
    indexes, data = {}, {}
    for fld, column in zip(batch.schema, batch.columns):
        meta = {k.decode(): v.decode() for k, v in (fld.metadata or {}).items()}
        if meta.get("rerun:kind") == "index":
            times = column.cast(pa.int64()).to_numpy(zero_copy_only=False)
            indexes[meta.get("rerun:index_name", fld.name)] = (_time_kind(fld.type), times)
        elif meta.get("rerun:kind") == "data":
            archetype = meta.get("rerun:archetype", "AnyValues").rsplit(".", 1)[-1]
            data[meta.get("rerun:component", fld.name)] = (archetype, column)
    return indexes, data


def _time_kind(datatype: pa.DataType) -> str:
    """``duration``, ``timestamp`` or ``sequence`` from a timeline column's arrow type."""
    if pa.types.is_duration(datatype):
        return "duration"
    if pa.types.is_timestamp(datatype):
        return "timestamp"
    return "sequence"


def _when(times: tuple) -> str:
    """A row's times for messages."""
    if not times:
        return "static"
    return ", ".join(f"{name} = {value / 1e9:g} s" if kind != "sequence" else f"{name} = {value}"
                     for name, kind, value in times)


def warn_undigested(where: str) -> None:
    """Warn (once per file and process) that the recording ``where`` holds no digests."""
    if where in _WARNED:
        return
    _WARNED.add(where)
    warnings.warn(
        f"{where}: holds none of bananagrid's content digests (written by another program or an older "
        "bananagrid): damage to it cannot be detected", BananagridWarning, stacklevel=3,
    )


class DigestCheck:
    """Checks the rows of one recording store against their digests and the manifest.

    Feed every row to :meth:`add` (it says which rows are the digests' own, to hide), then
    call :meth:`finish`.

    Parameters
    ----------
    where : str
        How messages name the file.
    """

    def __init__(self, where: str) -> None:
        self.where = where
        self._rows: Counter = Counter()  # (entity, times, digest) of the data rows
        self._digests: Counter = Counter()  # the same, as logged beside them
        self._manifests: list[dict] = []

    def add(self, entity: str, times: dict, cells: dict) -> bool:
        """Account for one row; True if it is a digest or the manifest (not data)."""
        key = tuple(sorted((name, kind, value) for name, (kind, value) in times.items()))
        if is_internal(entity):
            values = {}
            for name, (_, cell) in cells.items():
                items = cell.as_py() if isinstance(cell, pa.ListScalar) else None
                values[name] = items[0] if items and len(items) == 1 else items
            if entity == "/" + MANIFEST:
                self._manifests.append(values)
            elif isinstance(values.get("entity"), str) and isinstance(values.get("digest"), str):
                self._digests[(values["entity"], key, values["digest"])] += 1
            else:
                raise BananagridError(f"{self.where}: recording is damaged (a digest row without its entity or digest)")
            return True
        components = [(name, archetype, cell.values) for name, (archetype, cell) in cells.items()]
        self._rows[(entity, key, row_digest(entity, components))] += 1
        return False

    def finish(self, *, application_id: str, recording_id: str, blueprint: bool, footer: bool) -> None:
        """Raise :class:`~bananagrid.validate.BananagridError` (one line naming the file) unless
        every row matches its digest and the manifest matches everything; warn instead for a
        whole recording that holds no digest at all (another program's, an older bananagrid's).

        Parameters
        ----------
        application_id, recording_id : str
            The store's, as its header says.
        blueprint : bool
            Whether the file holds a blueprint store.
        footer : bool
            Whether the file has rerun's footer (a file cut short has none).
        """
        where = self.where
        if not self._manifests and not self._digests:
            if not footer:
                raise BananagridError(
                    f"{where}: recording is damaged (cut short: no footer, and none of bananagrid's digests)"
                )
            warn_undigested(where)
            return
        if not footer:  # bananagrid's writer checks the footer of every file it names
            raise BananagridError(f"{where}: recording is damaged (rerun's footer is missing or damaged)")
        if len(self._manifests) != 1:
            found = "no manifest (cut short?)" if not self._manifests else f"{len(self._manifests)} manifests"
            raise BananagridError(f"{where}: recording is damaged ({found})")
        extra, missing = self._rows - self._digests, self._digests - self._rows
        if extra or missing:
            entity, times, _ = min(extra or missing)
            wrong = {(e, t) for e, t, _ in extra} & {(e, t) for e, t, _ in missing}
            if (entity, times) in wrong:
                what = "does not match"
            elif extra:
                what = "is missing: a row without its digest"
            else:
                what = "is missing: a digest without its row"
            raise BananagridError(f"{where}: recording is damaged (digest of {entity} ({_when(times)}) {what})")
        manifest = self._manifests[0]
        pairs = [(entity, digest) for (entity, _, digest), count in self._digests.items() for _ in range(count)]
        expected = {
            "rows": float(len(pairs)), "digest": _combined(pairs), "recording_id": recording_id,
            "application_id": application_id, "blueprint": "true" if blueprint else "false",
        }
        for key, value in expected.items():
            if manifest.get(key) != value:
                raise BananagridError(
                    f"{where}: recording is damaged (its manifest's {key} does not match what the file holds)"
                )
