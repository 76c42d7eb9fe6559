"""Rasterised results and the one place that launches kernels."""

from __future__ import annotations

import functools
import math
import os
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from .grid import Grid
from .validate import BananagridError

__all__ = [
    "Raster", "rasterise", "evaluate_points", "evaluate_polar_moments", "evaluate_polar_derivatives",
    "interpolate_table", "default_threads",
]


@dataclass(frozen=True)
class Raster:
    """A model's density sampled at the cell centres of a grid.

    Attributes
    ----------
    values : ndarray, shape (ny, nx)
        Density per square metre at each cell centre (``quantity == "density"``); rows south
        to north. After :meth:`normalise` the values are scaled so that they sum to one over the
        grid (times the cell area).
    grid : Grid
        The grid the values belong to.
    mass : float
        Probability mass captured by the grid before any normalisation: ``sum(values) * dx * dy``
        of the raw density (midpoint rule). A value well below one says the grid misses mass.
    normalised : bool
        Whether ``values`` were divided by ``mass``.
    provenance : dict
        Model name and parameters, kernel, dtype, device, threads, seconds, truncation.
    """

    values: np.ndarray
    grid: Grid
    mass: float
    normalised: bool = False
    quantity: str = "density"
    provenance: dict = field(default_factory=dict)

    @property
    def x(self) -> np.ndarray:
        return self.grid.x

    @property
    def y(self) -> np.ndarray:
        return self.grid.y

    @property
    def peak(self) -> float:
        return float(np.max(self.values))

    def normalise(self) -> "Raster":
        """Return a copy whose values integrate to one over the grid; ``mass`` keeps the raw mass."""
        if not self.mass > 0.0:
            raise BananagridError(
                f"cannot normalise a raster that captured no mass (mass = {self.mass!r}): "
                "the grid misses the model's support"
            )
        if self.normalised:
            return self
        return replace(self, values=self.values / self.mass, normalised=True)


# --------------------------------------------------------------------------------------------
# Launching kernels. This is the only module that calls wp.launch.
# --------------------------------------------------------------------------------------------

_DTYPES = {np.dtype(np.float32): "float32", np.dtype(np.float64): "float64"}

#: Turn-rate node spacing of the CAT scan table, in units of omega t (radians). Root pairs
#: closer than this are still found by the fold search; the spacing bounds how many extrema of
#: F one interval can hold.
CAT_NODE_SPACING = 0.1
CAT_MIN_NODES = 64
CAT_MAX_NODES = 8192


#: What Warp's native library prints on every machine without an NVIDIA driver. It is not news
#: to a CPU user and lands in the middle of the CLI's progress line, so it is filtered out.
_NO_DRIVER_NOTICE = b"Could not find or load the NVIDIA CUDA driver"


@functools.cache
def _warp():
    """Import and initialise Warp once, on first use (no import-time side effects)."""
    import warp as wp

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


def _scalar(dtype):
    try:
        name = _DTYPES[np.dtype(dtype)]
    except (TypeError, KeyError):
        raise BananagridError(f"dtype = {dtype!r}: must be float32 or float64") from None
    wp = _warp()
    return wp, np.dtype(dtype), getattr(wp, name)


def _check_device(wp, device: str) -> str:
    if not isinstance(device, str):
        raise BananagridError(f"device = {device!r}: expected 'cpu' or 'cuda'")
    try:
        wp.get_device(device)
    except Exception:
        available = ", ".join(str(d) for d in wp.get_devices())
        raise BananagridError(f"device = {device!r}: not available here (available: {available})") from None
    return device


def default_threads() -> int:
    """Worker threads for CPU launches: every core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class _Binding:
    """A model bound to its kernels: both take (xs, ys, offset, *params, out); a grid kernel
    with ``row_loop`` takes (xs, ys, row0, columns, *params, out) and loops over ``columns``
    cells of a row per thread."""

    grid_kernel: object
    points_kernel: object
    params: tuple
    kernel_name: str
    notes: dict
    row_loop: bool = False
    #: Bands per thread: one where every row costs the same (fewest launches), many where the
    #: cost follows the density (CAT rows through the banana refine roots, others only scan).
    bands_per_thread: int = 16
    #: Scratch values per band that the grid kernel takes after ``params`` (with the band's
    #: index): ``(scratch[n_bands, width], band)``; 0 for none.
    scratch_width: int = 0
    #: vec4 scratch per band, taken between the scratch and the band's index; 0 for none.
    quad_width: int = 0
    #: Rows per thread of a row-looping kernel that takes blocks of rows on the CPU: it then takes
    #: (xs, ys, row0, row_end, rows, columns, ...) (one cell per thread on a GPU); 0 for one row.
    tile_rows: int = 0


def _bind(model, wp, np_dtype, scalar, device, radii, threads, grid: bool = False) -> _Binding:
    """Bind ``model`` to its kernels, with their module loaded on ``device``. ``radii`` is the
    range (min, max) of distances from the model's origin that will be queried: a model whose
    kernel interpolates a table of its own (CAT with heading noise) builds it over that range.
    ``grid``: the binding is for the grid kernel (Butterly's may then skip negligible cells)."""
    binding = _bind_kernels(model, wp, np_dtype, scalar, device, radii, threads, grid)
    wp.load_module(binding.grid_kernel.module, device=device)
    return binding


def _bind_kernels(model, wp, np_dtype, scalar, device, radii, threads, grid=False) -> _Binding:
    from .bearing import BearingFix
    from .butterly import Butterly
    from .models import CAT, PolarBanana

    if isinstance(model, Butterly):
        from .kernels import butterly

        from .butterly import CELL_FLOOR

        params = wp.array(model.kernel_parameters(np_dtype, floors=grid), dtype=scalar, device=device)
        notes = {"speed_nodes": model.n_speed_nodes}
        if grid:
            notes["zero_below"] = CELL_FLOOR * model.peak_lower_bound()
        return _Binding(
            butterly.butterly_grid, butterly.butterly_points, (params, model.n_speed_nodes),
            "butterly.butterly_grid", notes, row_loop=True, scratch_width=butterly.SCRATCH,
            quad_width=butterly.QUAD_SCRATCH, tile_rows=butterly.TILE,
        )
    if isinstance(model, BearingFix):
        from .kernels import bearing

        params = wp.array(model.kernel_parameters().astype(np_dtype), dtype=scalar, device=device)
        variant = bearing.EXACT if model.variant == "exact" else bearing.LINEAR
        return _Binding(
            bearing.bearing_grid, bearing.bearing_points, (params, len(model.sensors), variant),
            "bearing.bearing_grid", {"variant": model.variant},
        )
    if not isinstance(model, (CAT, PolarBanana)):
        raise BananagridError(f"model = {type(model).__name__}: not a bananagrid model")
    pose = wp.array(model.pose.as_array().astype(np_dtype), dtype=scalar, device=device)
    if isinstance(model, CAT) and model.sigma_heading > 0.0:
        from .heading import heading_table

        table = heading_table(model, *radii, threads=threads)
        return _bind_table(table, wp, np_dtype, scalar, device, pose, {
            "k_sigma": model.k_sigma, "truncated_mass": model.truncated_mass, **table.notes(),
        })
    if isinstance(model, CAT):
        from .kernels import cat

        omegas = _cat_nodes(model).astype(np_dtype)
        table = wp.zeros((len(omegas), cat.TABLE_COLUMNS), dtype=scalar, device=device)
        wp.launch(
            cat.cat_table,
            dim=len(omegas),
            inputs=[wp.array(omegas, dtype=scalar, device=device), scalar(model.v0), scalar(model.t), table],
            device=device,
        )
        # Newton stops when its step is below a few ulps of the searched range.
        tol = 8.0 * np.finfo(np_dtype).eps * model.k_sigma * model.sigma_omega
        params = (
            table, scalar(model.v0), scalar(model.t), scalar(model.sigma_a),
            scalar(model.sigma_omega), pose, scalar(tol),
        )
        notes = {"scan_nodes": len(omegas), "k_sigma": model.k_sigma, "truncated_mass": model.truncated_mass}
        return _Binding(cat.cat_grid, cat.cat_points, params, "cat.cat_grid", notes)
    if isinstance(model, PolarBanana):
        from .kernels import polar

        params = (
            _polar_coefficients(model, wp, np_dtype, scalar, device), _polar_variant(model.variant),
            model.kernel_order, pose,
        )
        notes = {"variant": model.variant, "truncated_mass": model.truncated_mass}
        if model.sigma_heading > 0.0:
            notes["heading_order"] = model.heading_order
        return _Binding(
            polar.polar_grid, polar.polar_points, params, "polar.polar_grid", notes, row_loop=True, bands_per_thread=1
        )
    raise AssertionError("unreachable: every model kind is bound above")


def _bind_table(table, wp, np_dtype, scalar, device, pose, notes) -> _Binding:
    """Bind a density tabulated on a polar lattice (``heading.HeadingTable``) to the
    interpolating kernels."""
    from .heading import FLOOR
    from .kernels import tabulated

    values = table.values.astype(np_dtype)
    floor = FLOOR[np.dtype(np_dtype)]
    with np.errstate(divide="ignore"):
        logs = np.log(np.maximum(values, floor))  # entries at the floor are never used in log
    geometry = np.array([table.r0, table.dr, table.theta0, table.dtheta, floor], dtype=np_dtype)
    params = (
        wp.array(logs, dtype=scalar, device=device), wp.array(values, dtype=scalar, device=device),
        wp.array(geometry, dtype=scalar, device=device), int(table.mirror), pose,
    )
    return _Binding(
        tabulated.table_grid, tabulated.table_points, params, "tabulated.table_grid", notes,
        row_loop=True, bands_per_thread=1,
    )


def _polar_coefficients(model, wp, np_dtype, scalar, device):
    from .kernels import polar

    values = polar.coefficients(model.v0, model.t, model.sigma_a, model.sigma_omega, model.sigma_heading)
    return wp.array(np.array(values, dtype=np_dtype), dtype=scalar, device=device)


def _polar_variant(name: str) -> int:
    from .kernels import polar

    return polar.ROUGH if name == "rough" else polar.IMPROVED


def _cat_nodes(model) -> np.ndarray:
    """Turn-rate nodes of the CAT scan: uniform over +-k_sigma sigma_omega."""
    span = 2.0 * model.k_sigma * model.sigma_omega * model.t  # in omega t
    n = int(min(CAT_MAX_NODES, max(CAT_MIN_NODES, math.ceil(span / CAT_NODE_SPACING) + 1)))
    half = model.k_sigma * model.sigma_omega
    return np.linspace(-half, half, n)


def _bands(n_rows: int, threads: int, per_thread: int = 1) -> list[tuple[int, int]]:
    """Split rows into ``threads * per_thread`` contiguous bands (fewer if rows run out)."""
    n_bands = max(1, min(n_rows, threads * per_thread))
    edges = np.linspace(0, n_rows, n_bands + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def _check_threads(threads) -> int:
    if threads is None:
        return default_threads()
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise BananagridError(f"threads = {threads!r}: expected an integer >= 1")
    return int(threads)


def _run_bands(launch_band, bands: list[tuple[int, int]], threads: int) -> None:
    """Call ``launch_band(start, stop)`` for every band; on several threads, from a pool.
    The kernel's module must already be loaded (concurrent first launches would each build it)."""
    if threads == 1 or len(bands) == 1:
        for band in bands:
            launch_band(*band)
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for future in [pool.submit(launch_band, a, b) for a, b in bands]:
            future.result()


def rasterise(model, grid: Grid, *, dtype=np.float64, device: str = "cpu", threads=None) -> Raster:
    """Density of ``model`` at the cell centres of ``grid``, or on a polar lattice.

    With a :class:`~bananagrid.lattice.PolarLattice` the result is a
    :class:`~bananagrid.lattice.PolarRaster`: densities per (m, rad) at the cell centres and the
    probability integrated over each (range, bearing) cell (see
    :func:`bananagrid.lattice.rasterise_lattice`).

    Parameters
    ----------
    model : CAT, PolarBanana, BearingFix or Butterly
    grid : Grid or PolarLattice
    dtype : float32 or float64, default float64
        Kernel precision (and of ``values``).
    device : str, default "cpu"
        Warp device; "cuda" where present runs the same kernel source.
    threads : int, optional
        CPU worker threads (default: every core). Rows are split into bands, each a launch; a
        Warp CPU launch uses one core and releases the GIL, so bands run in parallel. Results do
        not depend on the number of threads.

    Returns
    -------
    Raster
        Raw (not normalised) densities per m^2, with the captured mass and provenance
        (a PolarRaster for a PolarLattice).
    """
    from .lattice import PolarLattice, rasterise_lattice  # lazily: lattice imports this module

    if isinstance(grid, PolarLattice):
        return rasterise_lattice(model, grid, dtype=dtype, device=device, threads=threads)
    if not isinstance(grid, Grid):
        raise BananagridError(f"grid = {grid!r}: expected a bananagrid.Grid")
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    threads = _check_threads(threads)
    start = time.perf_counter()
    binding = _bind(model, wp, np_dtype, scalar, device, _grid_radii(model, grid), threads, grid=True)
    xs = wp.array(grid.x.astype(np_dtype), dtype=scalar, device=device)
    ys = wp.array(grid.y.astype(np_dtype), dtype=scalar, device=device)
    if device == "cpu":
        values = np.empty(grid.shape, dtype=np_dtype)  # every cell is written by the kernel
        out = wp.array(values, dtype=scalar, copy=False, device=device)  # shares memory
    else:
        out = wp.zeros(grid.shape, dtype=scalar, device=device)

    # row-looping kernels take whole rows per thread on the CPU, one cell per thread on a GPU
    columns = (grid.nx if device == "cpu" else 1) if binding.row_loop else None

    bands = _bands(grid.ny, threads, binding.bands_per_thread) if device == "cpu" else [(0, grid.ny)]
    scratch, quads = None, None
    if binding.scratch_width:  # one work row per band: a band's rows run one after another
        scratch = wp.empty((len(bands), binding.scratch_width), dtype=scalar, device=device)
        band_of = {r0: k for k, (r0, _) in enumerate(bands)}
    if binding.quad_width:
        quads = wp.empty((len(bands), binding.quad_width), dtype=wp.types.vector(4, scalar), device=device)
    rows = (binding.tile_rows if device == "cpu" else 1) if binding.tile_rows else None

    def launch_band(r0, r1):
        if columns is None:
            dim, head = (r1 - r0, grid.nx), [xs, ys, r0]
        elif rows is None:
            dim, head = (r1 - r0, -(-grid.nx // columns)), [xs, ys, r0, columns]
        else:
            dim, head = (-(-(r1 - r0) // rows), -(-grid.nx // columns)), [xs, ys, r0, r1, rows, columns]
        extra = [] if scratch is None else [scratch] + ([] if quads is None else [quads]) + [band_of[r0]]
        wp.launch(binding.grid_kernel, dim=dim, inputs=[*head, *binding.params, *extra, out], device=device)

    _run_bands(launch_band, bands, threads)
    wp.synchronize_device(device)
    if device != "cpu":
        values = out.numpy()
    seconds = time.perf_counter() - start
    _check_finite(values, model)
    mass = float(np.sum(values, dtype=np.float64) * grid.cell_area)
    provenance = {
        **model.parameters(),
        "kernel": binding.kernel_name,
        "dtype": np_dtype.name,
        "device": device,
        "threads": threads if device == "cpu" else 1,
        "seconds": seconds,
        **binding.notes,
    }
    return Raster(values=values, grid=grid, mass=mass, normalised=False, provenance=provenance)


def _origin(model) -> tuple[float, float]:
    pose = getattr(model, "pose", None)
    return pose.origin if pose is not None else (0.0, 0.0)


def _grid_radii(model, grid: Grid) -> tuple[float, float]:
    """Least and greatest distance from the model's origin to the grid's cell centres."""
    ox, oy = _origin(model)
    x0, x1 = grid.x[0] - ox, grid.x[-1] - ox
    y0, y1 = grid.y[0] - oy, grid.y[-1] - oy
    near_x = 0.0 if x0 <= 0.0 <= x1 else min(abs(x0), abs(x1))
    near_y = 0.0 if y0 <= 0.0 <= y1 else min(abs(y0), abs(y1))
    far_x, far_y = max(abs(x0), abs(x1)), max(abs(y0), abs(y1))
    return math.hypot(near_x, near_y), math.hypot(far_x, far_y)


def _points_radii(model, x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    ox, oy = _origin(model)
    r = np.hypot(x - ox, y - oy)
    return float(r.min()), float(r.max())


def _check_finite(values: np.ndarray, model) -> None:
    if np.isfinite(values.sum()):  # one pass, no mask, in the common case
        return
    bad = ~np.isfinite(values)
    if bad.any():
        raise FloatingPointError(
            f"{type(model).__name__}: {int(bad.sum())} non-finite densities (first at index "
            f"{np.argwhere(bad)[0].tolist()}); please report this with the model parameters"
        )


#: Points per launch in evaluate_points: at most POINT_CHUNK (so the pool gets several chunks),
#: at least MIN_POINT_CHUNK (a launch costs a few microseconds).
POINT_CHUNK = 65536
MIN_POINT_CHUNK = 4096


def evaluate_points(model, x, y, *, dtype=np.float64, device: str = "cpu", threads=None, radii=None) -> np.ndarray:
    """Density of ``model`` at world points; ``x`` and ``y`` broadcast together.

    ``radii`` = (min, max) distance from the model's origin covering these points (default:
    computed from them). A caller evaluating many chunks of one region passes the region's
    range, so that a model that tabulates itself (CAT with heading noise) reuses one table.
    """
    try:
        bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    except ValueError:
        raise BananagridError(
            f"x and y: shapes {np.shape(x)} and {np.shape(y)} do not broadcast"
        ) from None
    if not (np.isfinite(bx).all() and np.isfinite(by).all()):
        raise BananagridError("x, y: points must be finite (NaN or inf given)")
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    threads = _check_threads(threads)
    if bx.size == 0:
        return np.zeros(bx.shape, dtype=np_dtype)
    if radii is None:
        radii = _points_radii(model, bx, by)
    binding = _bind(model, wp, np_dtype, scalar, device, radii, threads)
    return _launch_points(wp, binding, bx, by, np_dtype, scalar, device, threads)


def _launch_points(wp, binding: _Binding, bx, by, np_dtype, scalar, device, threads) -> np.ndarray:
    """Run a bound points kernel over (bx, by) in chunks from the thread pool (one launch on a
    GPU); the result has bx's shape. The kernel's module must be loaded."""
    n = bx.size
    xs = wp.array(np.ascontiguousarray(bx.ravel(), dtype=np_dtype), dtype=scalar, device=device)
    ys = wp.array(np.ascontiguousarray(by.ravel(), dtype=np_dtype), dtype=scalar, device=device)
    out = wp.zeros(n, dtype=scalar, device=device)

    def launch_chunk(a, b):
        wp.launch(binding.points_kernel, dim=b - a, inputs=[xs, ys, a, *binding.params, out], device=device)

    # at least one chunk per thread once there is enough work to share
    size = max(MIN_POINT_CHUNK, min(POINT_CHUNK, -(-n // threads)))
    chunks = [(a, min(n, a + size)) for a in range(0, n, size)] if device == "cpu" else [(0, n)]
    _run_bands(launch_chunk, chunks, threads)
    wp.synchronize_device(device)
    return out.numpy().reshape(bx.shape)


def _angles(name: str, values) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if not np.isfinite(values).all():
        raise BananagridError(f"{name}: angles must be finite")
    return values


def evaluate_polar_moments(model, phi, *, variant=None, order=0, dtype=np.float64, device: str = "cpu"):
    """Mean and SD of r given the angle for a PolarBanana: at ``order`` 0 given phi, its own
    variant's law or ``variant``'s ("improved": P_mu (8) and P_sigma (11)); at ``order`` 2 or 4
    given theta with the model's heading noise, (15)-(16)."""
    phi = _angles("phi", phi)
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    from .kernels import polar

    flat = wp.array(np.ascontiguousarray(phi.ravel(), dtype=np_dtype), dtype=scalar, device=device)
    mean = wp.zeros(phi.size, dtype=scalar, device=device)
    sd = wp.zeros(phi.size, dtype=scalar, device=device)
    if phi.size:
        coef = _polar_coefficients(model, wp, np_dtype, scalar, device)
        law = _polar_variant(model.variant if variant is None else variant)
        wp.launch(polar.polar_moments, dim=phi.size, inputs=[flat, coef, law, int(order), mean, sd], device=device)
        wp.synchronize_device(device)
    return mean.numpy().reshape(phi.shape), sd.numpy().reshape(phi.shape)


def evaluate_polar_derivatives(model, phi, *, dtype=np.float64, device: str = "cpu") -> np.ndarray:
    """P_mu with its derivatives 1-4 and P_sigma with its derivatives 1-2 at phi, for the
    model's variant: array of shape phi.shape + (8,)."""
    phi = _angles("phi", phi)
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    from .kernels import polar

    flat = wp.array(np.ascontiguousarray(phi.ravel(), dtype=np_dtype), dtype=scalar, device=device)
    out = wp.zeros((phi.size, 8), dtype=scalar, device=device)
    if phi.size:
        coef = _polar_coefficients(model, wp, np_dtype, scalar, device)
        law = _polar_variant(model.variant)
        wp.launch(polar.polar_derivatives, dim=phi.size, inputs=[flat, coef, law, out], device=device)
        wp.synchronize_device(device)
    return out.numpy().reshape(phi.shape + (8,))


def interpolate_table(table, x, y, *, dtype=np.float64, device: str = "cpu", threads=None) -> np.ndarray:
    """Interpolate a ``heading.HeadingTable`` at points (x, y) of its own local frame."""
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    threads = _check_threads(threads)
    bx, by = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    identity = wp.array(np.array([0.0, 0.0, 1.0, 0.0], dtype=np_dtype), dtype=scalar, device=device)
    binding = _bind_table(table, wp, np_dtype, scalar, device, identity, {})
    wp.load_module(binding.points_kernel.module, device=device)
    return _launch_points(wp, binding, bx, by, np_dtype, scalar, device, threads)


# --- many hypotheses at once ----------------------------------------------------------------


def _polar_batch_params(models, wp, np_dtype, scalar, device):
    """Per-hypothesis coefficient rows, variants, heading orders and poses of PolarBananas
    (``bananagrid.batch`` has checked that they are)."""
    from .kernels import polar

    coefs = np.array(
        [polar.coefficients(m.v0, m.t, m.sigma_a, m.sigma_omega, m.sigma_heading) for m in models], dtype=np_dtype
    )
    variants = np.array([_polar_variant(m.variant) for m in models], dtype=np.int32)
    orders = np.array([m.kernel_order for m in models], dtype=np.int32)
    poses = np.array([m.pose.as_array() for m in models], dtype=np_dtype)
    return (
        wp.array(coefs, dtype=scalar, device=device), wp.array(variants, dtype=wp.int32, device=device),
        wp.array(orders, dtype=wp.int32, device=device), wp.array(poses, dtype=scalar, device=device),
    )


def _launch_polar_batch(kernel, models, x, y, out_shape, rows, *, dtype, device, threads) -> np.ndarray:
    """Run a polar batch kernel (xs, ys, h0, *parameters, out) over bands of hypotheses; each
    launch covers hypotheses h0 .. h0 + b - a, times ``rows`` when that is not None."""
    wp, np_dtype, scalar = _scalar(dtype)
    device = _check_device(wp, device)
    threads = _check_threads(threads)
    params = _polar_batch_params(models, wp, np_dtype, scalar, device)
    wp.load_module(kernel.module, device=device)
    x_arr = wp.array(np.ascontiguousarray(x, dtype=np_dtype), dtype=scalar, device=device)
    y_arr = wp.array(np.ascontiguousarray(y, dtype=np_dtype), dtype=scalar, device=device)
    out = wp.zeros(out_shape, dtype=scalar, device=device)

    def launch_band(a, b):
        dim = b - a if rows is None else (b - a, rows)
        wp.launch(kernel, dim=dim, inputs=[x_arr, y_arr, a, *params, out], device=device)

    n = len(models)
    bands = _bands(n, threads, 4) if device == "cpu" else [(0, n)]
    _run_bands(launch_band, bands, threads)
    wp.synchronize_device(device)
    return out.numpy()


def launch_polar_batch(models, xs: np.ndarray, ys: np.ndarray, *, dtype=np.float64, device="cpu", threads=None) -> np.ndarray:
    """Densities of PolarBanana hypotheses h on their own grids: xs[h] (nx,) and ys[h] (ny,)
    cell centres; one kernel over (hypothesis, row), hypotheses banded over threads. Returns
    (H, ny, nx), bit-identical to rasterising each on its own (same device function)."""
    from .kernels import polar

    shape = (len(models), ys.shape[1], xs.shape[1])
    return _launch_polar_batch(polar.polar_batch_grid, models, xs, ys, shape, ys.shape[1],
                               dtype=dtype, device=device, threads=threads)


def launch_polar_batch_points(models, x: np.ndarray, y: np.ndarray, *, dtype=np.float64, device="cpu", threads=None) -> np.ndarray:
    """Densities of every world point (x[k], y[k]) under every PolarBanana hypothesis: (H, N)."""
    from .kernels import polar

    return _launch_polar_batch(polar.polar_batch_points, models, x, y, (len(models), x.size), None,
                               dtype=dtype, device=device, threads=threads)
