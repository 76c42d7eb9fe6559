"""Zarr stores of maps too large for memory, written block by block, whole or not at all.

:func:`write_zarr` writes a scene's maps (panels ``(layer, t, raster)``; tiled rasters with lazy
Dask values, or rasters in memory) as the CF dataset of :func:`~bananagrid.geo.dataset.raster_dataset`
(coordinates, CRS, latitude and longitude, times, provenance) to a Zarr v3 store that
``xarray.open_zarr`` reads. The map variables are chunked as the tiles were computed
(``(1, rows, columns)``), a block that is all zeros (a skipped tile) is not written (Zarr's fill
value is 0, so it reads as zeros), and each layer's captured mass is computed in the same
pass as its blocks. The store is written under a hidden temporary name beside ``path`` and
renamed when complete; on any failure (a worker lost for good, a full disk, an interrupt) the
temporary store is removed and ``path`` is left as it was. An existing ``path`` is replaced only
if it is a store of ours (:func:`is_bananagrid_store`) or an empty directory: anything else
there is refused before any computing (:func:`check_store_target`), never emptied.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..atomic import OutputSet, OutputWriteError
from ..validate import BananagridError
from ..version import __version__
from .dataset import DENSITY_UNITS, layer_variables, raster_dataset
from .panels import check_panels
from .libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require

__all__ = ["write_zarr", "write_batch_zarr", "ZARR_FORMAT", "compute_with_progress", "is_bananagrid_store",
           "check_store_target", "STORE", "scale_stored"]

#: Zarr format of the stores (v3: its ``fill_value`` is separate from CF's ``_FillValue``, so a
#: block never written reads as 0 and no zero is read as missing).
ZARR_FORMAT = 3
#: What a store is called in messages (and in a run's :class:`~bananagrid.atomic.OutputSet`).
STORE = "Zarr store"
#: The root attribute every store of ours carries (:func:`~bananagrid.geo.dataset.raster_dataset`
#: and :func:`write_batch_zarr` set it).
OWN_ATTRIBUTE = "bananagrid_version"


def is_bananagrid_store(path: str | os.PathLike) -> bool:
    """Whether the directory ``path`` is a Zarr store this package wrote, and nothing else: a
    v3 group whose ``zarr.json`` carries the ``bananagrid_version`` attribute, beside which are
    only its arrays (directories each with its ``zarr.json`` and the chunk tree ``c``). A store
    someone added a file to, or any other directory, is not, so it is never replaced."""
    path = Path(path)
    try:
        meta = json.loads((path / "zarr.json").read_text(encoding="utf-8"))
        if not (isinstance(meta, dict) and meta.get("zarr_format") == ZARR_FORMAT and meta.get("node_type") == "group"
                and OWN_ATTRIBUTE in (meta.get("attributes") or {})):
            return False
        for entry in path.iterdir():
            if entry.name == "zarr.json":
                continue
            if entry.is_symlink() or not entry.is_dir() or not (entry / "zarr.json").is_file():
                return False
            if any(inner.name not in ("zarr.json", "c") or inner.is_symlink() for inner in entry.iterdir()):
                return False
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return True


def check_store_target(path: str | os.PathLike) -> Path:
    """Refuse now, before any computing, a ``path`` a store may not be written to: its directory
    missing or not writable, a file or a link there, or a directory that is neither empty nor a
    store of ours (:func:`is_bananagrid_store`). Needs zarr (the cluster extra)."""
    require("zarr", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    outputs = OutputSet()
    return outputs.add(path, STORE, ours=is_bananagrid_store)


def compute_with_progress(*collections, progress: bool = False):
    """``dask.compute(*collections)`` on the active scheduler (a ``distributed.Client`` if one is
    current), with a progress bar on stderr when ``progress``."""
    dask = require("dask", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    client = _current_client()
    if client is None:
        diagnostics = require("dask.diagnostics", CLUSTER_PURPOSE, CLUSTER_EXTRA)
        bar = diagnostics.ProgressBar(out=sys.stderr) if progress else contextlib.nullcontext()
        with bar:
            return dask.compute(*collections)
    futures = client.compute(list(collections))
    try:
        if progress:
            bar = require("distributed.diagnostics.progressbar", CLUSTER_PURPOSE, CLUSTER_EXTRA)
            with contextlib.redirect_stdout(sys.stderr):  # the summary table owns stdout
                bar.progress(futures, notebook=False)
                print(file=sys.stderr)
        return tuple(client.gather(futures))
    except BaseException:
        client.cancel(futures)
        _settle(client)
        raise


#: Seconds a failed computation waits for the tasks its workers are still running.
SETTLE_SECONDS = 30.0


def _settle(client, seconds: float = SETTLE_SECONDS) -> None:
    """Wait until no worker is executing a task (or ``seconds`` passed). When one task of a
    store fails, the tasks already running on other workers run on to their end, still writing
    blocks into the temporary store: it is removed only after them, or they would leave part of
    it behind."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            busy = client.run(lambda dask_worker: dask_worker.state.executing_count)
        except Exception:  # the cluster is gone: nothing runs any more
            return
        if not any(busy.values()):
            return
        time.sleep(0.05)


def _current_client():
    """The ``distributed.Client`` Dask would compute on now, or None (Dask's own threads or
    processes, as ``dask.config`` says: a ``dask.config.set(scheduler=...)`` overrides a client)."""
    base = require("dask.base", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    client = getattr(base.get_scheduler(), "__self__", None)
    try:
        distributed = require("distributed", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    except BananagridError:
        return None
    return client if isinstance(client, distributed.Client) else None


def write_zarr(path: str | os.PathLike, panels: Sequence, frame=None, *, title: str = "", source: str = "",
               progress: bool = False, stage=None, cells=None, posteriors=None, extra=(), finish=None) -> Path:
    """Write a scene's maps to the Zarr store ``path`` (a directory), whole or not at all.

    Parameters
    ----------
    path : path-like
        The store; its parent directory must exist. An existing store of ours there (or an empty
        directory) is replaced once the new one is complete; anything else there is refused.
    panels : sequence of (str, float, Raster or TiledRaster)
        As for :func:`~bananagrid.geo.dataset.raster_dataset`.
    frame : GeoFrame, optional
        Default: the rasters' own.
    title, source : str
        Global attributes.
    progress : bool
        A progress bar on stderr while the blocks are computed and written.
    stage : callable, optional
        A run's :meth:`bananagrid.atomic.OutputSet.stage` (the run planned ``path`` and commits
        it with its other files); default: the store is put in place when complete.
    cells : mapping of (str, float) to Raster, optional
        Cell probabilities by ``(layer, t)`` (rasters in memory), stored as ``LAYER_probability``
        as :func:`~bananagrid.geo.dataset.raster_dataset` puts them in the NetCDF.
    posteriors : mapping of (str, float) to Posterior, optional
        Posteriors by ``(layer, t)`` (``bg.posterior``'s, or a tiled posterior's lazy maps,
        :meth:`bananagrid.evidence.tiled.TiledPosterior.maps`), stored as
        :func:`~bananagrid.geo.dataset.raster_dataset` puts them in the NetCDF:
        ``LAYER_posterior``, ``LAYER_pod``, ``LAYER_pos`` and ``LAYER_search_pos``.
    extra : sequence of Dask collections, optional
        Computed in the same pass as the blocks (a posterior's sums, say: its blocks are then
        computed once) and handed to ``finish``.
    finish : callable, optional
        ``finish(group, values)``, called with the open ``zarr.Group`` of the temporary store and
        the computed ``extra`` once every block is written, before the store is put in place: it
        completes what needs the pass's results (:func:`scale_stored`, values and attributes);
        whatever it raises abandons the store. The metadata is consolidated again after it.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    BananagridError
        A missing directory, ``path`` a file, a link or a directory that is not a store of ours
        (:func:`check_store_target`), a missing library of the ``cluster`` extra, or
        (:class:`~bananagrid.atomic.OutputWriteError`) any failure while computing or writing
        (one line naming ``path``; nothing is left behind).
    """
    xr = require("xarray", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    final = check_store_target(path)
    dataset = raster_dataset(panels, frame, title=title, source=source, cells=cells, posteriors=posteriors)
    if not isinstance(dataset, xr.Dataset):  # pragma: no cover - raster_dataset always returns one
        raise BananagridError("write_zarr: expected the maps as an xarray.Dataset")
    encoding = {}
    for name, var in dataset.variables.items():
        keep = {k: v for k, v in var.encoding.items() if k in ("units", "calendar", "dtype")}
        if var.chunks is not None and name in dataset.data_vars and var.ndim == 3:
            # fill value 0: the blocks Zarr does not write (all zeros) read back as zeros
            keep.update(fill_value=np.zeros((), dtype=var.dtype)[()], chunks=tuple(c[0] for c in var.chunks),
                        compressors=_compressors())
        encoding[name] = keep
    _write_dataset(dataset, final, encoding, progress, _computed_pieces(dataset, check_panels(panels)), stage=stage,
                   extra=extra, finish=finish)
    return final


def scale_stored(group, name: str, divisors, *, progress: bool = False) -> None:
    """Divide each map ``k`` (the first axis) of the stored variable ``name`` of ``group`` by
    ``divisors[k]``, block by block in place (a block never written stays unwritten: 0 / d is 0)."""
    da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    array = group[name]
    divisors = np.asarray(divisors, dtype=np.float64).reshape((-1,) + (1,) * (array.ndim - 1))
    scaled = da.from_zarr(array) / divisors
    compute_with_progress(da.store(scaled, _SkipZeros(array), lock=False, compute=False), progress=progress)


def _computed_pieces(dataset, panels: list) -> dict:
    """``{variable: [(block, region), ...]}``: for each layer all of whose maps are tiled, the
    blocks that are not skipped and where each goes, so that a skipped block is not even a task
    (the layer's times in ``raster_dataset``'s order: by ``t``)."""
    names = layer_variables(dataset)
    series: dict[str, list] = {}
    for panel in panels:
        series.setdefault(panel.layer, []).append(panel)
    pieces = {}
    for layer, maps in series.items():
        if not all(hasattr(p.raster, "computed_blocks") for p in maps):
            continue
        maps.sort(key=lambda p: p.t)
        pieces[names[layer]] = [
            (p.raster.values.blocks[i, j], (k, slice(*rows), slice(*cols)))
            for k, p in enumerate(maps) for i, j, rows, cols in p.raster.computed_blocks()
        ]
    return pieces


def write_batch_zarr(path: str | os.PathLike, values, bounds: np.ndarray, mass, *, progress: bool = False) -> Path:
    """Write a sharded batch to the Zarr store ``path``, whole or not at all: ``density``
    (hypothesis, y, x), the density per m^2 at the cell centres of each hypothesis' own grid;
    ``bounds`` (hypothesis, edge), its grid's outer edges x0, x1, y0, y1 (m); ``mass``
    (hypothesis), its captured mass. Errors as for :func:`write_zarr`."""
    xr = require("xarray", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    final = check_store_target(path)
    h, ny, nx = values.shape
    dataset = xr.Dataset(
        {
            "density": (("hypothesis", "y", "x"), values, {
                "long_name": "probability density of the target's position at the cell centre of the hypothesis' grid",
                "units": DENSITY_UNITS}),
            "bounds": (("hypothesis", "edge"), bounds, {
                "long_name": "outer edges x0, x1, y0, y1 of the hypothesis' grid of ny x nx cells", "units": "m"}),
            "mass": (("hypothesis",), mass, {"long_name": "probability mass the grid captured", "units": "1"}),
        },
        attrs={"title": f"{h:,} hypotheses on grids of {ny} x {nx} cells", "source": f"bananagrid {__version__}",
               "bananagrid_version": __version__},
    )
    encoding = {"density": {"chunks": tuple(c[0] for c in values.chunks), "compressors": _compressors()}}
    _write_dataset(dataset, final, encoding, progress)
    return final


def _compressors() -> tuple:
    """Blosc LZ4 with byte shuffling: GB/s per core, so that writing never holds up the kernels
    (Zarr's default Zstandard took as long as computing a polar batch)."""
    codecs = require("zarr.codecs", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    return (codecs.BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"),)


def _write_dataset(dataset, final: Path, encoding: dict, progress: bool, pieces: dict | None = None,
                   stage=None, extra=(), finish=None) -> None:
    """Write ``dataset`` to a temporary store beside ``final``, computing its Dask variables in
    one pass, and put it in place when complete (``stage``: a run's, which commits it with its
    other files); on any failure remove it. ``pieces``: variables written only in the given
    blocks and regions (the rest is Zarr's fill value); ``extra``, ``finish``: as for
    :func:`write_zarr`."""
    with OutputSet() as own:
        if stage is None:
            own.add(final, STORE, ours=is_bananagrid_store)
            stage = own.stage
        try:
            with stage(final) as partial:
                _write_store(dataset, partial, encoding, progress, pieces or {}, extra, finish)
            own.commit()
        except Exception as exc:
            if isinstance(exc, BananagridError):
                raise
            reason = (str(exc) or type(exc).__name__).splitlines()[0]
            raise OutputWriteError(f"{final}: cannot write the {STORE} ({type(exc).__name__}: {reason})") from None


def _write_store(dataset, partial: Path, encoding: dict, progress: bool, pieces: dict, extra=(),
                 finish=None) -> None:
    """The store at ``partial``: its structure first, then the lazy variables (and ``extra``) in
    one pass, then ``finish``."""
    with warnings.catch_warnings():
        # consolidated metadata (one read opens the store) is zarr-python's extension of v3: it warns
        warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
        # the structure, the attributes and the variables in memory; the lazy ones (a map's blocks,
        # masses, latitudes) are stored below, so that a skipped block is never handed to Zarr
        dataset.to_zarr(partial, mode="w-", zarr_format=ZARR_FORMAT, consolidated=True, compute=False,
                        encoding=encoding)
    zarr = require("zarr", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    da = require("dask.array", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    group = zarr.open_group(partial, mode="r+", zarr_format=ZARR_FORMAT)
    sources, targets, regions = [], [], []
    for name, var in dataset.variables.items():
        if name in pieces:  # only the blocks computed, each into its region
            target = _SkipZeros(group[name])
            for block, region in pieces[name]:
                sources.append(block)
                targets.append(target)
                regions.append(region)
        elif var.chunks is not None:
            sources.append(var.data)
            targets.append(_SkipZeros(group[name]))
            regions.append(None)
    collections = [da.store(sources, targets, regions=regions, lock=False, compute=False)] if sources else []
    extra = list(extra)
    values = compute_with_progress(*collections, *extra, progress=progress) if collections or extra else ()
    if finish is not None:
        finish(group, list(values[len(collections):]))
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
            zarr.consolidate_metadata(partial, zarr_format=ZARR_FORMAT)  # what finish changed, in the one read


class _SkipZeros:
    """A Zarr array as a target of ``dask.array.store`` that leaves out the blocks of a skipped
    tile: :class:`~bananagrid.engine.tiles.TilePlan` gives them as one zero seen through the whole
    block (every stride 0), and Zarr's fill value 0 already reads as such a block. Handing Zarr
    16 MiB of zeros only for it to find them empty cost 26 ms a block."""

    def __init__(self, array):
        self.array = array

    def __setitem__(self, key, value) -> None:
        if value.size and not any(value.strides) and not value.flat[0]:
            return
        self.array[key] = value

