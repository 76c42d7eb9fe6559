"""Launch kernels generated from a family's device maths (as ``warp.fem`` builds its integration
kernels from a geometry's functions): a kernel module writes a density and a typed parameter
struct, and :func:`density_kernels` writes the grid, points and batch kernels around them.

A family declares its parameters once, with :class:`Params` (a ``wp.struct`` in float32 and in
float64, made from one list of fields), and its maths as a ``@wp.func density(x, y, p)``: the
density per m^2 at the world point (x, y) under the parameters ``p``. With ``lanes=True`` the
density takes vectors of world points (``kernels/lanes.py``, CPU only) and the kernels move a
vector of cells or points at a time (a density generic over both, as the bearing fix's, serves
the scalar and the lane kernels). Every generated kernel of a family calls the one density, so
that grids, points and batches agree bit for bit. The kernels join the density's module (one
module per family, one build; or the family's lane module, ``module``) and take its options.

Overloads on first use. Warp builds a module with every overload registered in it, so a module
that registered both scalar types and every kernel (the GPU path's scalar kernels beside the CPU
lanes, the batch kernels) built all of them for a run that launches one: the polar lane module
took 7.7 s of CPU to build, its float64 grid kernel alone 1.3 s (float32 16-lane kernels are the
costly part). Each kernel's overloads are therefore recorded here (:func:`overload_on_use`) and
registered only when the engine loads the kernel for a dtype (:func:`use_overload`, called by
``WarpContext.load``): a module is built with the overloads a run launches, and the kernel
cache keeps each combination. The code of each overload is the same whatever else its module
holds (Warp writes one C++ function per overload; the compiler contracts within a statement
only), so the values are the same bits.

Kernel arguments (``P`` the struct):

* grid ``(xs, ys, row0, columns, p: P, out[ny, nx])`` over ``(rows, blocks)``: ``columns``
  cells of a row per thread (a whole row on the CPU, where Warp's 2-D thread index costs an
  integer division per thread; one cell on a GPU); with ``row_sums`` (a CPU family's own row
  code) also ``sums[ny]`` after ``out``, each row's float64 sum;
* points ``(xs, ys, start, p: P, out[n])`` over a chunk of points from ``start``;
* batch grid ``(xs[H, nx], ys[H, ny], h0, ps: array of P, out[H, ny, nx])`` over
  ``(hypotheses, rows)``, and batch points ``(xs, ys, h0, ps, out[H, n])`` over hypotheses.

A family whose grid kernel works on blocks of rows (Butterly's tiles) passes its own ``grid``
with ``tile_rows``, ``scratch_width`` and ``quad_width`` (the engine's ``grid_block`` gives it
``(xs, ys, row0, row_end, rows, columns, step_x, step_y, p, scratch, quads, band, out)``); the
generator then writes the others. One with a faster way to fill a grid row passes ``row``.
"""

import inspect
import threading
from dataclasses import dataclass
from typing import Any

import warp as wp

from .lanes import lane_count, load_lanes, store_lanes

SCALARS = (wp.float32, wp.float64)


def SCALAR(scalar):
    """Field type: the kernels' scalar."""
    return scalar


def VEC4(scalar):
    """Field type: four scalars (a pose: origin x, origin y, cos heading, sin heading)."""
    return wp.types.vector(4, scalar)


def ARRAY(scalar):
    """Field type: a device array of scalars."""
    return wp.array(dtype=scalar)


def ARRAY_VEC4(scalar):
    """Field type: a device array of four-scalar vectors."""
    return wp.array(dtype=wp.types.vector(4, scalar))


def ARRAY2D(scalar):
    """Field type: a 2-D device array of scalars."""
    return wp.array2d(dtype=scalar)


#: Each kernel's overloads by scalar type, registered on first use (:func:`use_overload`): a list
#: of (kernel, argument types) shared by the kernels registered together.
_ON_USE: dict = {}
_ON_USE_LOCK = threading.Lock()


def overload_on_use(kernel, scalar, arg_types: dict, *together) -> None:
    """Record the overload of the generic ``kernel`` for ``scalar`` (argument name -> Warp type)
    and of the ``together`` pairs ``(kernel, arg_types)``: :func:`use_overload` registers them
    all when a launch in ``scalar`` first needs one of them (kernels launched side by side, a
    family's grid and points, so that their module is built once, not once for each)."""
    group = [(kernel, arg_types), *together]
    for member, _ in group:
        _ON_USE.setdefault(member, {})[scalar] = group


def use_overload(kernel, scalar) -> None:
    """Register ``kernel``'s overload for ``scalar`` and those recorded with it, if waiting (once;
    thread safe); other kernels are left as they are (Warp infers a generic kernel's overload at
    launch)."""
    waiting = _ON_USE.get(kernel)
    if not waiting or scalar not in waiting:
        return
    with _ON_USE_LOCK:
        group = waiting.get(scalar)
        if group is None:
            return
        for member, arg_types in group:
            wp.overload(member, arg_types)
            _ON_USE[member].pop(scalar, None)


class Params:
    """A family's typed parameter struct, in float32 and in float64 (``of(scalar)``).

    ``fields`` map each name to a Warp type (``int``) or to a function of the scalar type
    (:func:`SCALAR`, :func:`VEC4`, :func:`ARRAY`, ...). ``module`` is the family's module.
    """

    def __init__(self, name: str, module: str, **fields):
        self.name = name
        self.fields = fields
        self.structs = {}
        for scalar in SCALARS:
            annotations = {k: (f(scalar) if inspect.isfunction(f) else f) for k, f in fields.items()}
            key = f"{name}{8 * wp.types.type_size_in_bytes(scalar)}"
            cls = type(key, (), {"__annotations__": annotations, "__module__": module, "__qualname__": key})
            self.structs[scalar] = wp.struct(cls)

    def of(self, scalar):
        """The struct of ``scalar`` (``wp.float32`` or ``wp.float64``)."""
        return self.structs[scalar]


@dataclass(frozen=True)
class DensityKernels:
    """The launch kernels of a family and how the engine lays them out.

    Attributes
    ----------
    name : str
        ``module.kernel`` of the grid kernel, for provenance.
    params : Params
    grid, points, batch_grid, batch_points : Warp kernels (the batch ones None without ``batch``)
    bands_per_thread : int
        Row bands per CPU thread: one where every row costs the same (fewest launches), many
        where the cost follows the density.
    tile_rows, scratch_width, quad_width : int
        Of a family's own block kernel (0 for the generated grid kernel): rows per thread on the
        CPU, and scalar and 4-vector scratch per band.
    row_sums : bool
        The grid kernel takes a last argument ``sums`` (float64, one per row of ``out``) and
        writes each row's float64 sum there, taken while the row is computed (so that the engine
        does not read the grid again to sum it).
    """

    name: str
    params: Params
    grid: Any
    points: Any
    batch_grid: Any = None
    batch_points: Any = None
    bands_per_thread: int = 16
    tile_rows: int = 0
    scratch_width: int = 0
    quad_width: int = 0
    row_sums: bool = False


@wp.func
def one_value(values: wp.array(dtype=Any)):
    """Values per step of a scalar kernel (as :func:`lanes.lane_count` of a lane kernel's): 1."""
    return 1


@wp.func
def load_value(values: wp.array(dtype=Any), start: int):
    """values[start] (as :func:`lanes.load_lanes` loads a vector)."""
    return values[start]


@wp.func
def store_value(out: wp.array(dtype=Any), start: int, value: Any, count: int):
    """out[start] = value (as :func:`lanes.store_lanes` stores a vector; ``count`` >= 1)."""
    out[start] = value


def density_kernels(density, params: Params, name: str, *, lanes: bool = False, batch: bool = False,
                    bands_per_thread: int = 16, suffix: str | None = None, grid=None, tile_rows: int = 0,
                    scratch_width: int = 0, quad_width: int = 0, module: str | None = None,
                    row=None, row_sums: bool = False) -> DensityKernels:
    """The grid and points kernels (and with ``batch`` the batch kernels) of ``density``, named
    ``NAME_grid``, ``NAME_points``, ... (``suffix`` appended: by default ``_lanes`` with ``lanes``), in its module
    (or the one named ``module``: a family's lane kernels in a module of their own, over the density
    that its scalar kernels call) and overloaded for both scalar types on first use
    (:func:`overload_on_use`); ``grid``: the family's own grid kernel instead (its overloads the
    family's to record); ``row``: a family's own code for a grid row, ``row(xs, y, out, row, j0, j1,
    p)``, that returns 1 where it filled ``out[row, j0:j1]`` and 0 to leave the row to the density;
    ``row_sums`` (with ``row``): the grid kernel takes ``sums`` (float64, a value per row of ``out``)
    after ``out`` and fills ``sums[row]`` with the row's float64 sum: ``row(xs, y, out, row, j0, j1,
    p, sums)`` sums what it fills (returning 1), and the kernel sums in order the rows it leaves to the
    density (on the CPU, where a block is a whole row: :class:`DensityKernels`' ``row_sums``).

    One body for each kernel: a scalar kernel takes one value a step, a lane kernel a vector of
    them (:func:`lanes.load_lanes`, :func:`lanes.store_lanes`)."""
    module = density.module if module is None else wp.get_module(module)
    suffix = ("_lanes" if lanes else "") if suffix is None else suffix
    step, load, store = (lane_count, load_lanes, store_lanes) if lanes else (one_value, load_value, store_value)

    def make(f, kind):
        return wp.kernel(f, name=f"{name}_{kind}{suffix}", module=module)

    def grid_kernel(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), row0: int, columns: int, p: Any,
                    out: wp.array2d(dtype=Any)):
        i, block = wp.tid()
        r = row0 + i
        j = block * columns
        j1 = wp.min((block + 1) * columns, xs.shape[0])
        y = ys[r]
        done = int(0)
        if wp.static(row is not None):
            done = row(xs, y, out, r, j, j1, p)
        if done == 0:
            while j < j1:
                x = load(xs, j)
                store(out[r], j, density(x, type(x)(y), p), j1 - j)
                j += step(xs)

    def summed_grid_kernel(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), row0: int, columns: int, p: Any,
                           out: wp.array2d(dtype=Any), sums: wp.array(dtype=wp.float64)):
        i, block = wp.tid()
        r = row0 + i
        j0 = block * columns
        j1 = wp.min((block + 1) * columns, xs.shape[0])
        y = ys[r]
        if row(xs, y, out, r, j0, j1, p, sums) == 0:
            j = j0
            while j < j1:
                x = load(xs, j)
                store(out[r], j, density(x, type(x)(y), p), j1 - j)
                j += step(xs)
            # four running sums side by side (one chain of adds waits on each add: 2 ms of a
            # 30 ms Figure 1 map with heading noise), then in a fixed order
            s0 = wp.float64(0.0)
            s1 = wp.float64(0.0)
            s2 = wp.float64(0.0)
            s3 = wp.float64(0.0)
            k = j0
            while k + 4 <= j1:
                s0 += wp.float64(out[r, k])
                s1 += wp.float64(out[r, k + 1])
                s2 += wp.float64(out[r, k + 2])
                s3 += wp.float64(out[r, k + 3])
                k += 4
            while k < j1:
                s0 += wp.float64(out[r, k])
                k += 1
            sums[r] = (s0 + s1) + (s2 + s3)

    def points_kernel(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), start: int, p: Any,
                      out: wp.array(dtype=Any)):
        # the thread of every step-th point (counted from the first of all, so that a vector is
        # computed once where it straddles two launches' chunks) fills it and the next ones; the
        # others return
        k = start + wp.tid()
        if k % step(xs) == 0:
            store(out, k, density(load(xs, k), load(ys, k), p), xs.shape[0] - k)

    def batch_grid_kernel(xs: wp.array2d(dtype=Any), ys: wp.array2d(dtype=Any), h0: int, ps: wp.array(dtype=Any),
                          out: wp.array3d(dtype=Any)):
        hh, i = wp.tid()
        h = h0 + hh
        p = ps[h]  # loaded once: the output's stores could alias it
        xs_h = xs[h]
        y = ys[h, i]
        j = int(0)
        while j < xs.shape[1]:
            x = load(xs_h, j)
            store(out[h, i], j, density(x, type(x)(y), p), xs.shape[1] - j)
            j += step(xs_h)

    def batch_points_kernel(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), h0: int, ps: wp.array(dtype=Any),
                            out: wp.array2d(dtype=Any)):
        h = h0 + wp.tid()
        p = ps[h]
        k = int(0)
        while k < xs.shape[0]:
            store(out[h], k, density(load(xs, k), load(ys, k), p), xs.shape[0] - k)
            k += step(xs)

    if row_sums and (row is None or grid is not None):
        raise ValueError("row_sums: the generated grid kernel with a family's row")
    own_grid = grid is not None
    grid = grid if own_grid else make(summed_grid_kernel if row_sums else grid_kernel, "grid")
    points = make(points_kernel, "points")
    batch_grid = make(batch_grid_kernel, "batch_grid") if batch else None
    batch_points = make(batch_points_kernel, "batch_points") if batch else None
    for scalar in SCALARS:
        vec, mat, struct = wp.array(dtype=scalar), wp.array2d(dtype=scalar), params.of(scalar)
        # the grid and points kernels together: a run that rasterises also evaluates points
        # (a tile's seams, a pdf), and adding one to a built module would build it again
        # (a family's own grid kernel: with the overloads it recorded)
        grid_types = {"xs": vec, "ys": vec, "p": struct, "out": mat}
        if row_sums:
            grid_types["sums"] = wp.array(dtype=wp.float64)
        grids = _ON_USE.get(grid, {}).get(scalar, []) if own_grid else [(grid, grid_types)]
        overload_on_use(points, scalar, {"xs": vec, "ys": vec, "p": struct, "out": vec}, *grids)
        if batch:
            many = wp.array(dtype=struct)
            overload_on_use(batch_grid, scalar, {"xs": mat, "ys": mat, "ps": many, "out": wp.array3d(dtype=scalar)})
            overload_on_use(batch_points, scalar, {"xs": vec, "ys": vec, "ps": many, "out": mat})
    short = module.name.rsplit(".", 1)[-1]
    return DensityKernels(f"{short}.{grid.key}", params, grid, points, batch_grid, batch_points, bands_per_thread,
                          tile_rows, scratch_width, quad_width, row_sums)


@dataclass(frozen=True)
class CarriedKernels:
    """A family's carried points kernel (:func:`carried_points_kernel`), as a binding's ``kernels``."""

    name: str
    points: Any


def carried_points_kernel(carried, params: Params, evidence: Params, name: str) -> CarriedKernels:
    """The carried points kernel of a family (``bananagrid.protocol.CarryingModel``):
    ``NAME_carried_points(xs, ys, start, p, ev, lw, out)`` over a chunk of points from ``start``,
    each point's channels zeroed, then ``carried(x, y, p, ev, lw[k], out[k])`` (a ``@wp.func``
    that adds each path's density times its channel weights, ``kernels/evidence.py``). Overloads
    for both scalars are registered on first use; ``evidence`` is ``kernels.evidence.EVIDENCE``."""

    def points_kernel(xs: wp.array(dtype=Any), ys: wp.array(dtype=Any), start: int, p: Any, ev: Any,
                      lw: wp.array2d(dtype=Any), out: wp.array2d(dtype=Any)):
        k = start + wp.tid()
        x = xs[k]
        for c in range(out.shape[1]):
            out[k, c] = type(x)(0.0)
        carried(x, ys[k], p, ev, lw[k], out[k])

    kernel = wp.kernel(points_kernel, name=f"{name}_carried_points", module=carried.module)
    for scalar in SCALARS:
        vec, mat = wp.array(dtype=scalar), wp.array2d(dtype=scalar)
        overload_on_use(kernel, scalar, {"xs": vec, "ys": vec, "p": params.of(scalar), "ev": evidence.of(scalar),
                                         "lw": mat, "out": mat})
    return CarriedKernels(f"{carried.module.name.rsplit('.', 1)[-1]}.{kernel.key}", kernel)


def overload_each(kernel, **arg_types) -> None:
    """Record ``kernel``'s overloads for both scalar types, to register on first use
    (:func:`overload_on_use`): each argument's type a Warp type, or a function of the scalar type
    (:func:`SCALAR`, :func:`ARRAY`, ...) as :class:`Params` takes its fields."""
    for scalar in SCALARS:
        overload_on_use(kernel, scalar, {k: (f(scalar) if inspect.isfunction(f) else f) for k, f in arg_types.items()})
