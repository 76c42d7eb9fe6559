"""A cluster given wrongly fails fast, in one line (bananagrid.engine.cluster, ``run --zarr``).

``--scheduler`` against things that are not a Dask scheduler: every server here listens on
127.0.0.1 only (a port the test binds and owns), and every malformed address is refused before
any name lookup or connection. ``--memory-limit`` against what a worker needs for one block:
refused before a worker starts. One test starts a real LocalCluster (at the minimum limit).
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.cli import main
from bananagrid.engine import cluster
from bananagrid.engine.cluster import (
    CONNECT_SECONDS, WORKER_BASE_BYTES, check_memory_limit, check_scheduler, minimum_memory_limit, worker_need,
)
from bananagrid.engine.memory import format_bytes
from bananagrid.scenes.examples import example_path

distributed = pytest.importorskip("distributed")
from distributed.protocol.core import dumps  # noqa: E402  (after the skip: the cluster extra)
from distributed.protocol.utils import pack_frames  # noqa: E402

xr = pytest.importorskip("xarray")

#: Timeout of the probes in these tests, s: short, so that each case costs about a second.
TIMEOUT = 1.0
#: Slack over the timeout for a probe's failure, s: thread start-up and scheduling on a loaded
#: 2-core CI machine (measured under 0.1 s on an idle one).
SLACK = 2.0

SWEEP = settings(max_examples=100, deadline=None, derandomize=True, database=None,
                 suppress_health_check=list(HealthCheck))


def _handshake() -> bytes:
    """The first message a Dask scheduler sends, framed as on the wire (distributed's own
    functions: a length, then the packed frames of the handshake mapping)."""
    body = pack_frames(dumps({"compression": None, "python": (3, 11, 7), "pickle-protocol": 5}))
    return struct.pack("<Q", len(body)) + body


class Server:
    """A TCP server on 127.0.0.1 that does ``behaviour`` with each connection, on a thread."""

    def __init__(self, behaviour):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.port = self.sock.getsockname()[1]
        self.behaviour = behaviour
        self.open: list[socket.socket] = []
        if behaviour is not None:  # None: listens, never accepts (the kernel completes connections)
            threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.open.append(conn)
            threading.Thread(target=self._handle, args=(conn,), daemon=True).start()

    def _handle(self, conn):
        try:
            self.behaviour(conn)
        except OSError:
            pass

    def close(self):
        for conn in self.open:
            conn.close()
        self.sock.close()


def _echo(conn):  # answers only what it is sent: silent to a client that waits for the server
    while data := conn.recv(4096):
        conn.sendall(data)


def _http(conn):  # a web server's banner: its first 8 bytes read as a length of about 3e18
    conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
    time.sleep(30)


def _plausible_garbage(conn):  # a length a handshake could have, then bytes that are not one
    conn.sendall(struct.pack("<Q", 58) + bytes(range(58)))
    time.sleep(30)


def _truncated(conn):  # a handshake cut short, then the connection closed
    conn.sendall(_handshake()[:20])
    conn.close()


def _hangs_up(conn):
    conn.close()


def _real_handshake(conn):
    conn.sendall(_handshake())
    time.sleep(30)


def _closed_port() -> int:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()  # bound, never listened: connections to it are refused
    return port


#: Servers that are not Dask schedulers, and what the one-line error must say.
NOT_SCHEDULERS = {
    "listens, never accepts": (None, f"no answer within {TIMEOUT:g} s"),
    "accepts, never answers (echo)": (_echo, f"no answer within {TIMEOUT:g} s"),
    "answers as a web server": (_http, "answered, but not as a Dask scheduler"),
    "answers a handshake's length of garbage": (_plausible_garbage, "answered, but not as a Dask scheduler"),
    "closes mid-handshake": (_truncated, "closed the connection without Dask's handshake"),
    "closes at once": (_hangs_up, "closed the connection without Dask's handshake"),
}


@pytest.mark.parametrize("case", list(NOT_SCHEDULERS))
def test_a_server_that_is_not_a_scheduler_fails_within_the_timeout(case):
    behaviour, reason = NOT_SCHEDULERS[case]
    server = Server(behaviour)
    address = f"tcp://127.0.0.1:{server.port}"
    try:
        start = time.monotonic()
        with pytest.raises(bg.BananagridError) as raised:
            check_scheduler(address, timeout=TIMEOUT)
        elapsed = time.monotonic() - start
    finally:
        server.close()
    message = str(raised.value)
    assert message.startswith(f"scheduler = {address}: {reason}") and "\n" not in message, message
    assert elapsed < TIMEOUT + SLACK, elapsed


def test_a_closed_port_is_refused_at_once():
    address = f"tcp://127.0.0.1:{_closed_port()}"
    start = time.monotonic()
    with pytest.raises(bg.BananagridError, match=rf"^scheduler = {address}: connection refused \(nothing listens"):
        check_scheduler(address, timeout=TIMEOUT)
    assert time.monotonic() - start < SLACK


def test_a_scheduler_that_answers_is_accepted_with_its_scheme():
    """A server sending Dask's handshake passes the probe; an address without a scheme is tcp."""
    server = Server(_real_handshake)
    try:
        assert check_scheduler(f"127.0.0.1:{server.port}", timeout=TIMEOUT) == f"tcp://127.0.0.1:{server.port}"
        assert check_scheduler(f"tcp://127.0.0.1:{server.port}", timeout=TIMEOUT) == f"tcp://127.0.0.1:{server.port}"
    finally:
        server.close()


#: Malformed addresses (none resolves or connects anywhere), and what the error says.
MALFORMED = [
    ("127.0.0.1", "no port"),
    ("tcp://127.0.0.1", "no port"),
    ("tcp://127.0.0.1:", "no port"),
    ("tcp://", "no port"),
    ("tcp://127.0.0.1:0", "port '0' is not an integer from 1 to 65535"),
    ("tcp://127.0.0.1:65536", "port '65536' is not an integer from 1 to 65535"),
    ("tcp://127.0.0.1:99999", "port '99999' is not an integer from 1 to 65535"),
    ("tcp://127.0.0.1:-1", "port '-1' is not an integer from 1 to 65535"),
    ("tcp://127.0.0.1:http", "port 'http' is not an integer from 1 to 65535"),
    ("127.0.0.1:8786x", "port '8786x' is not an integer from 1 to 65535"),
    ("tcp://127.0.0.1:8786/status", "port '8786/status' is not an integer"),
    ("tcp://127.0.0.1:１２３", "port '１２３' is not an integer"),  # full-width digits: not ASCII
    ("udp://127.0.0.1:8786", "unknown scheme udp://"),
    ("http://127.0.0.1:8787", "unknown scheme http://"),
    ("inproc://127.0.0.1/1/2", "unknown scheme inproc://"),
    ("tcp://bad_host!:8786", "host 'bad_host!' is not an IP address or a host name"),
    ("tcp://-leading-hyphen:8786", "host '-leading-hyphen' is not an IP address or a host name"),
    ("tcp://two..dots:8786", "host 'two..dots' is not an IP address or a host name"),
    ("tcp://127.0.0:8786", "host '127.0.0' is not an IP address or a host name"),
    ("tcp://300.0.0.1:8786", "host '300.0.0.1' is not an IP address or a host name"),
    ("tcp://:8786", "host '' is not an IP address or a host name"),
    ("tcp://[::1:8786", "no port"),
    ("tcp://[127.0.0.1]:8786", "'127.0.0.1' is not an IPv6 address"),
    ("tcp://127.0.0.1 :8786", "expected an address such as tcp://127.0.0.1:8786"),
    ("", "expected an address such as tcp://127.0.0.1:8786"),
]


@pytest.mark.parametrize("address, reason", MALFORMED)
def test_a_malformed_address_is_refused_before_any_lookup(address, reason, monkeypatch):
    def no_network(*args, **kwargs):
        raise AssertionError("a malformed address reached the network")

    monkeypatch.setattr(socket, "getaddrinfo", no_network)
    monkeypatch.setattr(socket.socket, "connect", no_network)
    with pytest.raises(bg.BananagridError) as raised:
        check_scheduler(address, timeout=TIMEOUT)
    message = str(raised.value)
    assert message.startswith("scheduler = ") and reason in message and "\n" not in message, message


@pytest.mark.parametrize("value", [None, 8786, b"tcp://127.0.0.1:8786", ["tcp://127.0.0.1:8786"]])
def test_a_scheduler_that_is_not_a_string_is_refused(value):
    with pytest.raises(bg.BananagridError, match=r"^scheduler = .*: expected an address such as tcp://"):
        check_scheduler(value)


@pytest.mark.parametrize("timeout", [0, -1.0, math.inf, math.nan, True, "10"])
def test_the_timeout_is_checked(timeout):
    with pytest.raises(bg.BananagridError, match=r"^timeout = .*: expected a positive, finite number of seconds"):
        check_scheduler("tcp://127.0.0.1:8786", timeout=timeout)


def test_the_cli_names_the_option_and_exits_2_within_the_default_timeout(capsys, tmp_path, monkeypatch):
    """``--scheduler`` at a port that never answers: exit 2 and one line, within the default
    timeout (:data:`CONNECT_SECONDS`, shortened here to keep the test fast) and no store."""
    monkeypatch.setattr("bananagrid.cli.CONNECT_SECONDS", TIMEOUT)
    server = Server(None)
    address = f"tcp://127.0.0.1:{server.port}"
    try:
        start = time.monotonic()
        code = main(["run", "--example", "slow_contact", "--zarr", str(tmp_path / "s.zarr"), "--scheduler", address,
                     "--quiet"])
        elapsed = time.monotonic() - start
    finally:
        server.close()
    err = capsys.readouterr().err
    assert code == 2
    assert err == f"bananagrid: error: --scheduler = {address}: no answer within {TIMEOUT:g} s (is a Dask scheduler " \
                  "running there? a slow one: a longer connect timeout)\n"
    assert elapsed < TIMEOUT + SLACK + 5.0  # + loading the scene and planning its tiles (under 2 s measured)
    assert list(tmp_path.iterdir()) == []
    assert CONNECT_SECONDS == 10.0  # the documented default (docs, --help)


@pytest.mark.parametrize("argv, message", [
    (["--scheduler", "tcp://127.0.0.1:http"], "--scheduler = tcp://127.0.0.1:http: port 'http' is not an integer"),
    (["--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "0"], "--connect-timeout = 0.0: must be > 0"),
    (["--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "inf"], "--connect-timeout = inf: must be finite"),
    (["--connect-timeout", "3"], "--connect-timeout: only with --scheduler"),
    (["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--scheduler: an existing cluster has its own workers"),
    (["--workers", "0"], "--workers = 0: expected an integer >= 1"),
    (["--memory-limit", "lots"], '--memory-limit = "lots": expected a positive size of memory per worker'),
    (["--memory-limit", "0"], '--memory-limit = "0": expected a positive size'),
    (["--memory-limit=-1GiB"], '--memory-limit = "-1GiB": expected a positive size'),
    (["--memory-limit="], '--memory-limit = "": expected a positive size'),
    (["--memory-limit", "1e400"], '--memory-limit = "1e400": expected a positive size'),
    (["--memory-limit", "64MiB"], '--memory-limit = "64MiB" (67.1 MB): a worker needs about'),
])
def test_cluster_options_are_refused_before_a_worker_starts(argv, message, capsys, tmp_path, monkeypatch):
    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster started")

    monkeypatch.setattr(distributed, "LocalCluster", no_cluster)
    monkeypatch.setattr(distributed, "Client", no_cluster)
    code = main(["run", "--example", "slow_contact", "--zarr", str(tmp_path / "s.zarr"), "--quiet", *argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []


def test_a_memory_limit_below_a_block_names_the_figures(capsys, tmp_path, monkeypatch):
    """The need is that of the scene's largest block (figure1 at step 4: 900 x 1024 cells, float64)."""
    monkeypatch.setattr(distributed, "LocalCluster", lambda *a, **k: pytest.fail("a cluster started"))
    need = worker_need((900, 1024), "float64", "float64")
    code = main(["run", "--example", "figure1", "--zarr", str(tmp_path / "f.zarr"), "--quiet", "--memory-limit", "500MB"])
    err = capsys.readouterr().err
    assert code == 2
    assert err == (f'bananagrid: error: --memory-limit = "500MB" (500 MB): a worker needs about {format_bytes(need)} '
                   f"to compute a block of 900 x 1024 cells, so at least {format_bytes(minimum_memory_limit(need))} "
                   "per worker (Dask pauses a worker near its limit); give more memory or smaller --chunks\n")


@SWEEP
@given(st.integers(1, 8192), st.integers(1, 8192), st.sampled_from(["float32", "float64"]),
       st.sampled_from(["float32", "float64"]))
def test_the_minimum_is_the_need_over_the_pause_fraction(rows, cols, dtype, computed_in):
    """Every block shape and dtype: the minimum itself is accepted, a byte less is refused, and
    the minimum leaves the need below Dask's pause threshold (0.8 of the limit by default)."""
    need = worker_need((rows, cols), dtype, computed_in)
    assert need == WORKER_BASE_BYTES + rows * cols * 2 * (np.dtype(dtype).itemsize + np.dtype(computed_in).itemsize)
    minimum = minimum_memory_limit(need)
    assert need <= 0.8 * minimum < need + 1
    assert check_memory_limit(minimum, need=need) == minimum
    with pytest.raises(bg.BananagridError, match=r"^memory_limit = \d+ \(.*\): a worker needs about .* so at least"):
        check_memory_limit(minimum - 1, need=need)


@pytest.mark.parametrize("value", ["lots", "", " ", "0", "-5GiB", "nan", "inf", "1e400", "10 parsecs", 0, -1, True,
                                   1.5e9, None.__class__, [1]])
def test_memory_limits_that_are_not_sizes_are_refused(value):
    with pytest.raises(bg.BananagridError, match=r"^memory_limit = .*: expected a positive size of memory per worker"):
        check_memory_limit(value)


class _Client:
    """What ``rasterise(..., chunks=)`` asks of the current client: its workers' limits."""

    asynchronous = False

    def __init__(self, limits):
        self.limits = limits

    def scheduler_info(self):
        return {"workers": {f"tcp://127.0.0.1:{k + 1}": {"memory_limit": v} for k, v in enumerate(self.limits)}}


def test_a_tiled_raster_checks_the_open_clusters_workers(monkeypatch):
    """Under a client whose workers (local or at --scheduler) cannot hold a block: refused when
    planned, with the figures; workers without a limit (0) or enough of it pass."""
    model = bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)
    grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=20.0)
    need = worker_need((128, 128), "float64", "float64")
    monkeypatch.setattr(distributed, "default_client", lambda: _Client([4 * 2**30, 300 * 10**6]))
    with pytest.raises(bg.BananagridError) as raised:
        bg.rasterise(model, grid, chunks=128)
    assert str(raised.value) == (
        f"chunks = (128, 128): a worker needs about {format_bytes(need)} for a block of 128 x 128 cells, so a memory "
        f"limit of at least {format_bytes(minimum_memory_limit(need))}; this cluster's workers have 300 MB: give them "
        "more memory or use smaller chunks")
    for limits in ([0, 0], [minimum_memory_limit(need)] * 2):
        monkeypatch.setattr(distributed, "default_client", lambda limits=limits: _Client(limits))
        assert bg.rasterise(model, grid, chunks=128).values.shape == grid.shape


def test_a_local_cluster_at_the_minimum_limit_runs(tmp_path):
    """The measured need is enough: one worker at exactly the minimum for its blocks computes a
    scene (a worker paused near its limit would not finish; the test's own timeout bounds it)."""
    scene = bg.load_scene(example_path("figure1")).with_step(40.0)
    need = worker_need((64, 64), "float64", "float64")
    store = tmp_path / "f.zarr"
    assert main(["run", "--example", "figure1", "--step", "40", "--zarr", str(store), "--chunks", "64", "--workers", "1",
                 "--memory-limit", str(minimum_memory_limit(need)), "--quiet"]) == 0
    with xr.open_zarr(store) as ds:
        layer, t = scene.jobs()[0]
        assert ds[layer.name].sel(elapsed=t).values.shape == scene.grid.shape


def test_probe_reads_no_more_than_the_handshake_bound():
    """The largest first message the probe reads is small: a length beyond it is refused unread."""
    assert cluster.HANDSHAKE_MAX_BYTES <= 2**16
    assert len(_handshake()) - 8 <= cluster.HANDSHAKE_MAX_BYTES
