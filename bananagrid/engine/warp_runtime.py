"""Warp's runtime: initialisation, dtypes and devices, thread bands, and every launch.

This is the only module that calls ``wp.launch``. A Warp CPU launch runs on one core and
releases the GIL, so work is split into bands launched from a thread pool
(:func:`run_bands`); bands write disjoint outputs (``atomic_add`` on the CPU is not atomic
across concurrent launches).
"""

from __future__ import annotations

import contextvars
import functools
import os
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import warp as wp

from ..kernels.generate import use_overload
from ..validate import BananagridError

__all__ = ["WarpContext", "warp", "default_threads", "check_threads", "bands", "run_bands", "row_sums"]

_DTYPES = {np.dtype(np.float32): wp.float32, np.dtype(np.float64): wp.float64}
_FIXED = {np.dtype(np.float64): wp.float64, np.dtype(np.int32): wp.int32}

#: Called (on a timer thread, at most once a load) when loading a kernel module takes longer than
#: :data:`COMPILE_NOTICE_SECONDS`: Warp is compiling it, not reading its kernel cache (about
#: 2 ms). The CLI sets it to say so on its progress line; None (the default) says nothing.
compile_notice: contextvars.ContextVar = contextvars.ContextVar("compile_notice", default=None)
COMPILE_NOTICE_SECONDS = 0.3

#: What Warp's native library prints on every machine without an NVIDIA driver. It is not news
#: to a CPU user and lands in the middle of the CLI's progress line, so it is filtered out.
_NO_DRIVER_NOTICE = b"Could not find or load the NVIDIA CUDA driver"


@functools.cache
def warp():
    """Initialise Warp once, on first use (no import-time side effects), and return it."""
    # Warp logs its banner and every module load at INFO; users want our output, not that.
    wp.config.log_level = wp.LOG_WARNING
    # The native library writes to file descriptor 2 directly: capture it during init and
    # pass on everything but the no-driver notice.
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            for line in captured.read().splitlines(keepends=True):
                if _NO_DRIVER_NOTICE not in line:
                    sys.stderr.write(line.decode(errors="replace"))
    return wp


def device_name(device: str) -> str:
    """What ``device`` is, for reports: the CPU, or the GPU's name and compute capability
    (``"cuda:0 NVIDIA H100 80GB HBM3, sm_90"``). Raises BananagridError if it is not here."""
    wp_ = warp()
    try:
        if device.startswith("cuda") and not wp_.is_cuda_available():
            raise LookupError(device)  # asking Warp would print its driver errors first
        d = wp_.get_device(device)
    except Exception:
        available = ", ".join(str(x) for x in wp_.get_devices())
        raise BananagridError(f"device = {device!r}: not available here (available: {available})") from None
    if not d.is_cuda:
        return str(d)
    return f"{d} {d.name}, sm_{d.arch}"


def default_threads() -> int:
    """Worker threads for CPU launches: every core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def check_threads(threads) -> int:
    """``threads`` as an int >= 1 (None: :func:`default_threads`)."""
    if threads is None:
        return default_threads()
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise BananagridError(f"threads = {threads!r}: expected an integer >= 1")
    return int(threads)


def bands(n_rows: int, threads: int, per_thread: int = 1, align: int = 1) -> list[tuple[int, int]]:
    """Split rows into ``threads * per_thread`` contiguous bands (fewer if rows run out), each
    starting on a multiple of ``align`` rows (a kernel's tile side)."""
    units = -(-n_rows // align)
    n_bands = max(1, min(units, threads * per_thread))
    if n_bands == 1:  # one thread's one band: the same edges, without NumPy's 10 us
        return [(0, n_rows)] if n_rows > 0 else []
    edges = np.minimum(np.linspace(0, units, n_bands + 1).round().astype(int) * align, n_rows)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def row_sums(block: np.ndarray) -> np.ndarray:
    """float64 sums of each row of a 2-D array (float32 or float64): ``(rows,)``.

    A row's sum is NumPy's pairwise sum of that row alone, whatever rows surround it (the
    reduction runs along each contiguous row, casting in buffers that restart at every row), so
    sums taken band by band equal, bit for bit, those of the whole array at once
    (``tests/engine/test_thread_bits.py`` checks it over shapes, slices and both dtypes): results summed
    from them in a fixed order do not depend on how rows were split between threads."""
    return np.ascontiguousarray(block).sum(axis=1, dtype=np.float64)


@functools.cache
def _pool(pid: int, workers: int) -> ThreadPoolExecutor:
    """The helper threads of :func:`run_bands` for ``workers`` helpers in process ``pid``, made on
    first use and kept: starting threads for each call cost 100-300 us a call, more than a small
    grid's kernel (a forked child has none of its parent's threads, hence the pid)."""
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix=f"bananagrid-bands{workers}")


#: Recorded CPU launches kept for :meth:`WarpContext.launch_kept`: a tracker's few grids and
#: models, each one launch (most recently used last).
KEPT_LAUNCHES = 32
_kept: dict = {}
_kept_lock = threading.Lock()


def _input_key(value):
    """What identifies a kernel input in a kept launch: a number (Python, NumPy or Warp scalar)
    by its type and value, any other object (an array, a struct) by identity, which the kept
    launch's own reference to it keeps from being reused."""
    if isinstance(value, (int, float, np.number)):
        return type(value), value
    if wp.types.type_is_scalar(type(value)):  # a Warp scalar: a new object per call
        return type(value), value.value
    return id(value)


def run_bands(launch_band, bands: list[tuple[int, int]], threads: int) -> None:
    """Call ``launch_band(start, stop)`` for every band; on several threads, the calling one
    among them, each taking the next band when it finishes one (the cost of a band follows the
    density). The kernel's module must already be loaded (concurrent first launches would each
    build it).

    The helpers come from a pool kept for the process. The caller waits for the bands, not for
    its helpers: a helper still queued behind another call's work when the bands run out has
    nothing left to do, so calls from several threads (or from inside a band) never wait on one
    another's queue. The first error of any band is raised once every band has finished."""
    workers = min(threads, len(bands))
    if workers == 1:
        for band in bands:
            launch_band(*band)
        return
    pending = iter(bands)
    lock = threading.Condition()
    left = [len(bands)]
    errors = []

    def drain():
        while True:
            with lock:
                band = next(pending, None)
            if band is None:
                return
            try:
                launch_band(*band)
            except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread below
                errors.append(exc)
            finally:
                with lock:
                    left[0] -= 1
                    if not left[0]:
                        lock.notify_all()

    # the caller drains too: one thread fewer to wake, and no core idles while it waits
    pool = _pool(os.getpid(), workers - 1)
    for _ in range(workers - 1):
        pool.submit(drain)
    drain()
    with lock:
        lock.wait_for(lambda: not left[0])
    if errors:
        raise errors[0]


class WarpContext:
    """Warp arrays and launches in one dtype on one device (the engine's
    :class:`~bananagrid.protocol.KernelContext`).

    Parameters
    ----------
    dtype : float32 or float64
        The kernels' scalar type.
    device : str
        ``"cpu"``, or ``"cuda"`` where present.
    threads : int, optional
        CPU threads (default: every core).

    Raises
    ------
    BananagridError
        For a dtype other than float32 or float64, a device that is not available, or a thread
        count that is not an integer >= 1 (checked in that order).
    """

    def __init__(self, dtype=np.float64, device: str = "cpu", threads=None):
        try:
            self.dtype = np.dtype(dtype)
            self.scalar_type = _DTYPES[self.dtype]
        except (TypeError, KeyError):
            raise BananagridError(f"dtype = {dtype!r}: must be float32 or float64") from None
        self.wp = warp()
        if not isinstance(device, str):
            raise BananagridError(f"device = {device!r}: expected 'cpu' or 'cuda'")
        try:
            self.wp.get_device(device)
        except Exception:
            available = ", ".join(str(d) for d in self.wp.get_devices())
            raise BananagridError(f"device = {device!r}: not available here (available: {available})") from None
        self.device = device
        self.threads = check_threads(threads)

    @property
    def cpu(self) -> bool:
        return self.device == "cpu"

    @property
    def launch_threads(self) -> int:
        """Threads that launch concurrently: ``threads`` on the CPU, one launch on a GPU."""
        return self.threads if self.cpu else 1

    def _type(self, dtype):
        """The Warp type of ``dtype``: the scalar type for None, float64 or int32 for those NumPy
        dtypes, else ``dtype`` itself (a Warp type, e.g. :meth:`vector`)."""
        if dtype is None:
            return self.scalar_type
        if self.wp.types.type_is_vector(dtype):
            return dtype
        return _FIXED[np.dtype(dtype)]

    def scalar(self, value: float):
        """``value`` as the kernels' scalar type."""
        return self.scalar_type(value)

    def array(self, values, *, dtype=None):
        """A device array of ``values`` (the scalar type unless ``dtype``: float64 or int32)."""
        kind = self._type(dtype)
        if dtype is None:
            values = np.ascontiguousarray(values, dtype=self.dtype)
        return self.wp.array(values, dtype=kind, device=self.device)

    def struct(self, params, /, **values):
        """An instance of ``params``'s struct (a :class:`bananagrid.kernels.generate.Params`) in the
        scalar type, its fields set from ``values`` (numbers, sequences for vectors, device arrays)."""
        struct = params.of(self.scalar_type)
        instance = struct()
        for name, value in values.items():
            kind = struct.vars[name].type
            setattr(instance, name, kind(*value) if self.wp.types.type_is_vector(kind) else value)
        return instance

    def structs(self, params, count: int, /, **columns):
        """A device array of ``count`` instances of ``params``'s struct, field ``name`` of
        instance ``h`` from ``columns[name][h]`` (arrays of shape ``(count, ...)``)."""
        struct = params.of(self.scalar_type)
        records = np.zeros(count, dtype=struct.numpy_dtype())
        for name, column in columns.items():
            records[name] = column
        return self.wp.array(records, dtype=struct, device=self.device)

    def host_array(self, values):
        """A device array of ``values`` in the scalar type for the kernels to read: on the CPU it
        shares a contiguous host copy (none where ``values`` already is one), one copy fewer
        than :meth:`array` (Warp copies what it is given)."""
        if not self.cpu:
            return self.array(values)
        return self.shared(np.ascontiguousarray(values, dtype=self.dtype))

    def shared(self, values: np.ndarray, *, dtype=None):
        """A device array that shares the memory of ``values`` on the CPU (the same dtype: the
        scalar type, or ``dtype`` as :meth:`zeros` takes it)."""
        return self.wp.array(values, dtype=self._type(dtype), copy=False, device=self.device)

    def zeros(self, shape, *, dtype=None):
        return self.wp.zeros(shape, dtype=self._type(dtype), device=self.device)

    def empty(self, shape, *, dtype=None):
        return self.wp.empty(shape, dtype=self._type(dtype), device=self.device)

    def vector(self, length: int):
        """The Warp vector type of ``length`` lanes of the scalar type."""
        return self.wp.types.vector(length, self.scalar_type)

    def load(self, kernel) -> None:
        """Compile or load ``kernel``'s module before concurrent launches need it, with the
        kernel's overload for this dtype registered first: a module's kernels are overloaded on
        first use (:func:`bananagrid.kernels.generate.use_overload`), so a run builds only the
        overloads it launches. A load that compiles calls :data:`compile_notice`'s callable."""
        use_overload(kernel, self.scalar_type)
        notice = compile_notice.get()
        if notice is None:
            self.wp.load_module(kernel.module, device=self.device)
            return
        timer = threading.Timer(COMPILE_NOTICE_SECONDS, notice)
        timer.daemon = True
        timer.start()
        try:
            self.wp.load_module(kernel.module, device=self.device)
        finally:
            timer.cancel()

    def launch(self, kernel, *, dim, inputs, fresh=None) -> None:
        """``wp.launch`` on the context's device (``fresh``: ignored, as :meth:`launch_kept` takes it)."""
        self.wp.launch(kernel, dim=dim, inputs=inputs, device=self.device)

    def launch_kept(self, kernel, *, dim, inputs, fresh=(-1,)) -> None:
        """:meth:`launch`, for a launch repeated with the same inputs but those at the indices
        ``fresh`` (the output array, new points): on the CPU the launch is recorded once, kept
        (the last :data:`KEPT_LAUNCHES` of them, with their inputs) and replayed with only the
        fresh inputs packed again. Warp's launch infers a generic kernel's overload and packs
        every input each time: 30 us of a 100 x 100 polar map's 160.

        A kept launch is taken out of the cache while it runs, so threads never share one."""
        if not self.cpu:
            self.launch(kernel, dim=dim, inputs=inputs)
            return
        fresh = {i % len(inputs) for i in fresh}
        key = (kernel, dim, *(None if i in fresh else _input_key(v) for i, v in enumerate(inputs)))
        with _kept_lock:
            cmd = _kept.pop(key, None)
        if cmd is None:
            cmd = self.wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)
            if cmd is None:  # nothing to launch (an empty dimension)
                return
        else:
            for i in fresh:
                cmd.set_param_at_index(i, inputs[i])
        cmd.launch()
        with _kept_lock:
            _kept[key] = cmd
            while len(_kept) > KEPT_LAUNCHES:
                del _kept[next(iter(_kept))]

    def synchronize(self) -> None:
        self.wp.synchronize_device(self.device)

    def numpy(self, array) -> np.ndarray:
        """``array`` on the host (waits for the device)."""
        self.synchronize()
        return array.numpy()

    def bands(self, n: int, per_thread: int = 1, align: int = 1) -> list[tuple[int, int]]:
        """Bands of ``n`` rows for :meth:`run_bands`: ``per_thread`` per thread on the CPU, one on
        a GPU; each starts on a multiple of ``align``."""
        return bands(n, self.threads, per_thread, align) if self.cpu else [(0, n)]

    def run_bands(self, launch_band, band_list: list[tuple[int, int]]) -> None:
        run_bands(launch_band, band_list, self.launch_threads)
