"""Dask clusters to run tiles and batches on: a local one, or an existing one by its address.

:func:`dask_client` is a context manager that yields a ``distributed.Client``: by default on a
``distributed.LocalCluster`` of worker processes on this machine (``workers``, one thread each,
``memory_limit`` each), its scheduler, workers and HTTP endpoint listening on the loopback
interface only, on free ports (the package starts no network service of its own; Dask's
processes talk over local TCP); with ``scheduler``, on the cluster someone already runs at that address (its dashboard
link, if it has one, is ``client.dashboard_link``). While the client is open, Dask computes
every tiled raster and sharded batch on it.

**Misuse fails fast, in one line.** An address is parsed here (scheme, host, port) and its
scheduler probed before ``distributed`` sees it: a plain TCP connection and Dask's handshake
(the first message a scheduler sends, a few dozen bytes), both within ``timeout`` seconds
(:data:`CONNECT_SECONDS` by default), reading at most :data:`HANDSHAKE_MAX_BYTES`. Without the
probe, ``distributed`` waits forever on a port that accepts and never answers, and allocates
whatever size the first eight bytes of a non-Dask answer spell (exabytes for ``HTTP/1.1``).
A worker's memory limit is checked against what a worker needs to compute one block
(:func:`worker_need`, measured) before any worker starts.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import math
import queue
import re
import socket
import struct
import threading
import time
from collections.abc import Iterator

import numpy as np

from ..geo.libraries import CLUSTER_EXTRA, CLUSTER_PURPOSE, require
from ..validate import BananagridError, show
from .memory import format_bytes
from .warp_runtime import default_threads

__all__ = ["dask_client", "check_memory_limit", "check_workers", "check_scheduler", "worker_need",
           "minimum_memory_limit", "CONNECT_SECONDS", "HANDSHAKE_MAX_BYTES", "WORKER_BASE_BYTES"]

#: Default seconds to wait for a scheduler given by address: to accept a connection and to send
#: Dask's handshake (``timeout`` of :func:`dask_client`, ``--connect-timeout`` of ``bananagrid run``).
CONNECT_SECONDS = 10.0

#: Largest first message accepted from a scheduler: its handshake is 58 bytes (distributed
#: 2026.8, Python 3.11); anything near this bound is not a handshake.
HANDSHAKE_MAX_BYTES = 2**16

#: Schemes a scheduler's address may have (none means ``tcp``): those that reach another process
#: over TCP. ``tcp`` is probed to Dask's handshake, ``tls`` to the TCP connection (its handshake is
#: encrypted; the TLS handshake that follows has ``distributed``'s own timeout).
SCHEMES = ("tcp", "tls")

#: Peak resident memory of a worker process that has computed a block: 495 MB measured (Python,
#: NumPy, distributed, Warp initialised and a kernel module loaded; ``ru_maxrss`` of a
#: LocalCluster worker after one block of each kernel family, blocks of 64 to 2048 cells a side,
#: float32 and float64 alike), rounded up.
WORKER_BASE_BYTES = 500 * 10**6

#: Bytes per block cell on top of the base: the kernel's output in the working dtype, the values
#: in the asked dtype and a copy of each (Zarr's encoding), per byte of the two dtypes.
_BLOCK_COPIES = 2

_HOSTNAME_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)$")


def check_workers(workers, name: str = "workers") -> int:
    """``workers`` as an int >= 1 (None: one per core)."""
    if workers is None:
        return default_threads()
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise BananagridError(f"{name} = {show(workers)}: expected an integer >= 1")
    return int(workers)


def worker_need(chunks, dtype="float64", computed_in="float64") -> int:
    """Bytes a worker process needs to compute one block of ``chunks = (rows, columns)`` cells
    with values in ``dtype`` computed in ``computed_in``: :data:`WORKER_BASE_BYTES` and two copies
    of the block in each dtype. No model's kernel scratch changed the measured peak (per-band
    rows of at most a few thousand numbers)."""
    cells = int(chunks[0]) * int(chunks[1])
    return WORKER_BASE_BYTES + cells * _BLOCK_COPIES * (np.dtype(dtype).itemsize + np.dtype(computed_in).itemsize)


def minimum_memory_limit(need: int) -> int:
    """The smallest ``memory_limit`` under which a worker using ``need`` bytes runs: Dask pauses a
    worker above the fraction ``distributed.worker.memory.pause`` of its limit (0.8 by default)
    and kills it above ``terminate`` (0.95), so a limit just above the need stalls the cluster."""
    dask = require("dask", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    require("distributed", CLUSTER_PURPOSE, CLUSTER_EXTRA)  # its import sets the defaults read here
    fractions = [dask.config.get(f"distributed.worker.memory.{k}", None) for k in ("pause", "terminate")]
    fractions = [float(f) for f in fractions if f not in (None, False) and 0.0 < float(f) <= 1.0]
    return math.ceil(need / min(fractions, default=1.0))


def check_memory_limit(memory_limit, *, need: int = WORKER_BASE_BYTES, name: str = "memory_limit",
                       what: str = "its first block") -> int | None:
    """``memory_limit`` per worker (bytes, or a string such as ``"4GiB"``, ``"500MB"``) as bytes;
    None for Dask's default (the machine's memory shared among the workers).

    Parameters
    ----------
    memory_limit : int or str or None
    need : int, default :data:`WORKER_BASE_BYTES`
        Bytes a worker needs (:func:`worker_need` of the blocks it will compute); a limit below
        :func:`minimum_memory_limit` of it is refused.
    name : str
        The argument or option, for the message.
    what : str
        What the need is for, for the message.

    Raises
    ------
    BananagridError
        Not a size, not positive, or below the minimum: one line with the figures.
    """
    if memory_limit is None:
        return None
    dask_utils = require("dask.utils", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    value = None
    if isinstance(memory_limit, str) and memory_limit.strip():
        try:
            value = int(dask_utils.parse_bytes(memory_limit))
        except (ValueError, TypeError, OverflowError):
            value = None
    elif isinstance(memory_limit, (int, np.integer)) and not isinstance(memory_limit, bool):
        value = int(memory_limit)
    if value is None or not 0 < value < 2**63:
        raise BananagridError(
            f"{name} = {show(memory_limit)}: expected a positive size of memory per worker "
            "(bytes, or a string such as '4GiB' or '500MB')"
        )
    minimum = minimum_memory_limit(need)
    if value < minimum:
        raise BananagridError(
            f"{name} = {show(memory_limit)} ({format_bytes(value)}): a worker needs about {format_bytes(need)} "
            f"to compute {what}, so at least {format_bytes(minimum)} per worker (Dask pauses a worker near its "
            "limit); give more memory or smaller --chunks"
        )
    return value


def _split_address(scheduler, name: str) -> tuple[str, str, int]:
    """``(scheme, host, port)`` of a scheduler's address, or a one-line error."""
    expected = "expected an address such as tcp://127.0.0.1:8786 (scheme tcp:// or tls://, a host, a port)"
    if not isinstance(scheduler, str) or not scheduler or any(c.isspace() for c in scheduler):
        raise BananagridError(f"{name} = {show(scheduler)}: {expected}")
    shown = scheduler  # as typed: a string without spaces
    scheme, sep, rest = scheduler.partition("://")
    if not sep:
        scheme, rest = "tcp", scheduler
    if scheme not in SCHEMES:
        raise BananagridError(f"{name} = {shown}: unknown scheme {scheme}://; {expected}")
    if rest.startswith("["):  # an IPv6 literal: [::1]:8786
        host, bracket, port = rest[1:].partition("]")
        port = port[1:] if bracket and port.startswith(":") else None
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise BananagridError(f"{name} = {shown}: {host!r} is not an IPv6 address; {expected}") from None
    else:
        host, colon, port = rest.rpartition(":")
        if not colon:
            host, port = rest, None
    if port is None or not port:
        raise BananagridError(f"{name} = {shown}: no port; {expected}")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise BananagridError(f"{name} = {shown}: port {port!r} is not an integer from 1 to 65535")
    if not rest.startswith("[") and not _is_host(host):
        raise BananagridError(f"{name} = {shown}: host {host!r} is not an IP address or a host name; "
                              f"{expected}")
    return scheme, host, int(port)


def _is_host(host: str) -> bool:
    """An IPv4 address or an RFC 1123 host name (checked before any name lookup)."""
    try:
        ipaddress.IPv4Address(host)
        return True
    except ValueError:
        pass
    labels = host[:-1].split(".") if host.endswith(".") else host.split(".")
    return 0 < len(host) <= 253 and not host.replace(".", "").isdigit() and all(
        _HOSTNAME_LABEL.match(label) for label in labels)


def _resolve(host: str, port: int, seconds: float) -> list:
    """``getaddrinfo`` within ``seconds`` (a name lookup has no timeout of its own: it runs on a
    daemon thread that may outlive the call)."""
    answers: queue.Queue = queue.Queue()

    def lookup():
        try:
            answers.put(socket.getaddrinfo(host, port, type=socket.SOCK_STREAM))
        except OSError as exc:
            answers.put(exc)

    threading.Thread(target=lookup, name="bananagrid-resolve", daemon=True).start()
    try:
        answer = answers.get(timeout=max(seconds, 0.0))
    except queue.Empty:
        raise TimeoutError from None
    if isinstance(answer, OSError):
        raise answer
    return answer


def _receive(sock: socket.socket, n: int, deadline: float) -> bytes:
    data = bytearray()
    while len(data) < n:
        sock.settimeout(max(deadline - time.monotonic(), 1e-3))
        part = sock.recv(n - len(data))
        if not part:
            raise ConnectionResetError("closed the connection")
        data += part
    return bytes(data)


def _is_handshake(body: bytes) -> bool:
    """Whether ``body`` (the first message after its length) is Dask's handshake: frames that
    decode to a mapping with the keys a handshake has."""
    core = require("distributed.protocol.core", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    utils = require("distributed.protocol.utils", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    try:
        message = core.loads(utils.unpack_frames(body))
    except Exception:  # any decoding failure: not Dask's protocol  # noqa: BLE001
        return False
    return isinstance(message, dict) and "compression" in message and "python" in message


def check_scheduler(scheduler, *, timeout: float = CONNECT_SECONDS, name: str = "scheduler") -> str:
    """The address of a Dask scheduler that answers, or a one-line error within ``timeout``.

    The address is parsed (``[scheme://]host:port``, the scheme ``tcp`` when none is given, a host
    checked before any name lookup), then the scheduler is probed: a TCP connection and, for
    ``tcp``, Dask's handshake (the scheduler speaks first), all within ``timeout`` seconds.

    Parameters
    ----------
    scheduler : str
    timeout : float, default :data:`CONNECT_SECONDS`
        Seconds for the name lookup, the connection and the handshake together.
    name : str
        The argument or option, for the message.

    Returns
    -------
    str
        The address with its scheme (``tcp://127.0.0.1:8786``).

    Raises
    ------
    BananagridError
        A malformed address, nothing listening, no answer within ``timeout``, an answer that is not
        Dask's: one line naming ``name``, the address and what went wrong.
    """
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not 0.0 < timeout < math.inf:
        raise BananagridError(f"timeout = {show(timeout)}: expected a positive, finite number of seconds")
    scheme, host, port = _split_address(scheduler, name)
    deadline = time.monotonic() + timeout

    def fail(reason: str):
        return BananagridError(f"{name} = {scheduler}: {reason}")

    try:
        family, kind, proto, _, where = _resolve(host, port, timeout)[0]
        with socket.socket(family, kind, proto) as sock:
            sock.settimeout(max(deadline - time.monotonic(), 1e-3))
            sock.connect(where)
            if scheme == "tcp":
                (size,) = struct.unpack("<Q", _receive(sock, 8, deadline))
                if not 16 <= size <= HANDSHAKE_MAX_BYTES or not _is_handshake(_receive(sock, size, deadline)):
                    raise fail("answered, but not as a Dask scheduler (its first message is not Dask's handshake)")
    except BananagridError:
        raise
    except (TimeoutError, socket.timeout):
        raise fail(f"no answer within {timeout:g} s (is a Dask scheduler running there? "
                   "a slow one: a longer connect timeout)") from None
    except ConnectionRefusedError:
        raise fail("connection refused (nothing listens on that port)") from None
    except ConnectionResetError:
        raise fail("closed the connection without Dask's handshake (not a Dask scheduler)") from None
    except socket.gaierror as exc:
        raise fail(f"cannot resolve host {host!r} ({exc.strerror})") from None
    except OSError as exc:
        raise fail(f"cannot connect ({exc.strerror or type(exc).__name__})") from None
    return f"{scheme}://{host}:{port}" if not host.count(":") else f"{scheme}://[{host}]:{port}"


@contextlib.contextmanager
def dask_client(*, workers=None, memory_limit=None, scheduler: str | None = None,
                timeout: float = CONNECT_SECONDS) -> Iterator:
    """A ``distributed.Client``: on a new local cluster, or on the scheduler at ``scheduler``.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the local cluster (default: one per core), one thread each.
    memory_limit : int or str, optional
        Memory per local worker (Dask pauses, then restarts, a worker above it); at least
        :func:`minimum_memory_limit` of :data:`WORKER_BASE_BYTES` (a tiled raster checks its
        blocks against the workers' limits before it is planned).
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``; ``host:8786`` means tcp); then
        ``workers`` and ``memory_limit`` must not be given (the cluster has its own).
    timeout : float, default :data:`CONNECT_SECONDS`
        Seconds to wait for the scheduler at ``scheduler`` to answer (:func:`check_scheduler`).

    Raises
    ------
    BananagridError
        Bad arguments, a scheduler that does not answer as one, distributed missing.
    """
    distributed = require("distributed", CLUSTER_PURPOSE, CLUSTER_EXTRA)
    if scheduler is not None:
        if workers is not None or memory_limit is not None:
            raise BananagridError("scheduler: an existing cluster has its own workers and memory limits; "
                                  "give workers and memory_limit only for a local cluster")
        address = check_scheduler(scheduler, timeout=timeout)
        try:
            client = distributed.Client(address, timeout=timeout)
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
