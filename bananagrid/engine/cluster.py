"""Dask clusters to run tiles and batches on: a local one, or an existing one by its address.

:func:`dask_client` is a context manager that yields a ``distributed.Client``: by default on a
``distributed.LocalCluster`` of worker processes on this machine (``workers``, one thread each,
``memory_limit`` each), its scheduler, workers and HTTP endpoint listening on the loopback
interface only, on free ports (the package starts no network service of its own; Dask's
processes talk over local TCP); with ``scheduler``, on the cluster someone already runs at that address (its dashboard
link, if it has one, is ``client.dashboard_link``). While the client is open, Dask computes
every tiled raster and sharded batch on it.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

import numpy as np

from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..validate import BananagridError, show
from .warp_runtime import default_threads

__all__ = ["dask_client", "check_memory_limit", "check_workers", "CONNECT_SECONDS"]

#: How long to wait for an existing scheduler to answer.
CONNECT_SECONDS = 20


def check_workers(workers) -> int:
    """``workers`` as an int >= 1 (None: one per core)."""
    if workers is None:
        return default_threads()
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise BananagridError(f"workers = {show(workers)}: expected an integer >= 1")
    return int(workers)


def check_memory_limit(memory_limit) -> int | None:
    """``memory_limit`` per worker (bytes, or a string such as ``"4GiB"``, ``"500MB"``) as bytes;
    None for Dask's default (the machine's memory shared among the workers)."""
    if memory_limit is None:
        return None
    dask_utils = require("dask.utils", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    try:
        value = int(dask_utils.parse_bytes(memory_limit)) if isinstance(memory_limit, str) else memory_limit
    except (ValueError, TypeError):
        value = None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 2**26:
        raise BananagridError(
            f"memory_limit = {show(memory_limit)}: expected bytes per worker, at least 64 MiB "
            "(a number, or a string such as '4GiB')"
        )
    return int(value)


@contextlib.contextmanager
def dask_client(*, workers=None, memory_limit=None, scheduler: str | None = None) -> Iterator:
    """A ``distributed.Client``: on a new local cluster, or on the scheduler at ``scheduler``.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the local cluster (default: one per core), one thread each.
    memory_limit : int or str, optional
        Memory per local worker (Dask pauses, then restarts, a worker above it).
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``); then ``workers`` and
        ``memory_limit`` must not be given (the cluster has its own).

    Raises
    ------
    BananagridError
        Bad arguments, a scheduler that does not answer, distributed missing.
    """
    distributed = require("distributed", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    if scheduler is not None:
        if workers is not None or memory_limit is not None:
            raise BananagridError("scheduler: an existing cluster has its own workers and memory limits; "
                                  "give workers and memory_limit only for a local cluster")
        if not isinstance(scheduler, str) or not scheduler.strip():
            raise BananagridError(f"scheduler = {show(scheduler)}: expected an address such as tcp://host:8786")
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_SECONDS)
        except (OSError, TimeoutError, ValueError) as exc:
            reason = (str(exc) or type(exc).__name__).splitlines()[0]
            raise BananagridError(f"scheduler = {scheduler}: cannot connect ({reason})") from None
        with client:
            yield client
        return
    n = check_workers(workers)
    limit = check_memory_limit(memory_limit)
    cluster = distributed.LocalCluster(
        n_workers=n, threads_per_worker=1, processes=True, memory_limit=limit if limit is not None else "auto",
        host="127.0.0.1", dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR,
    )
    with cluster, distributed.Client(cluster) as client:
        yield client
