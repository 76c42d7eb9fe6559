"""``bananagrid bench``: kernel throughput against a NumPy baseline measured in the same run.

The banana kernels rasterise the Figure 1 frame of the polar-banana paper (x in [-3000, 3000] m,
y in [-200, 3400] m, 4 m: 1500 x 900 cells), the bearing-fix kernel a 2048 x 2048 grid about
the coastal fix of ``scenes/bearing_coastal.toml``, the Butterly kernel (``butterly-rN``) a 2048 x 2048 grid framed about
the ring +- 6 sigma_max of three speeds whose largest travelled range is N sigma_min (a
correlated start, :data:`BUTTERLY_START`), in float64 and float32, on one thread and on all
cores; each kernel's NumPy float64 twin (:mod:`bananagrid.bench.baselines`) runs on the same
cells. Every timed model is built through the model registry from its scene parameters (kind and
keys as a scene layer would give them). With the bearing kernel, the
containment probability of 10^6 geometries is timed too. Times are the best of ``--repeat``
runs after a warm-up (the first Warp compile is not timed). The exact CAT and the Butterly
baselines take about a minute or more on the full grid, so by default they run on every 10th
row and their time is scaled to the full grid (``--baseline-stride 1`` runs them all).
``--small`` times what a tracker pays on every update, per call: ``rasterise`` on 100 x 100
cells and ``pdf`` at 1,000 points, and framing 1,000 hypotheses against their batch launch.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import platform
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..atomic import atomic_write, check_target, check_writable
from ..domains.angular_lattice import AngularLattice
from ..domains.grid import Grid
from ..engine.batch import frame, rasterise_batch
from ..engine.grid_kernel import GridExtent
from ..engine.points import evaluate_points
from ..engine.rasterise import rasterise
from ..engine.warp_runtime import default_threads, device_name
from ..models.bearing import bearing_to, two_bearing_variances
from ..models.cat import cell_turn_edges, clear_heading_tables, scan_nodes
from ..models.containment import containment
from ..models.presence import GaussianMixture, cell_probabilities, grid_probabilities
from ..models.registry import MODEL_KINDS
from ..planning.allocation import allocate
from ..planning.periods import plan_periods
from ..protocol import DensityModel
from ..results import Raster
from ..validate import BananagridError
from ..engine.cluster import check_memory_limit
from . import baselines, cluster, peers
from .posterior import EVIDENCE, ROWS as POSTERIOR_ROWS, check_rows, posterior_rows

#: Figure 1 of the polar-banana paper.
FIG1 = dict(v0=280.0, t=10.0, sigma_a=5.0 / 3.0, sigma_omega=math.pi / 54.0)
FIG1_BOUNDS = dict(x=(-3000.0, 3000.0), y=(-200.0, 3400.0))

#: The coastal scene's fix: two stations 20 km apart, contact about 30 km out, 2048 x 2048 cells.
COASTAL = dict(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909], sigmas=[0.01, 0.02])
COASTAL_SIDE = 2048

#: Butterly rows: a start 100 m x 250 m (1 sigma) at rho = 0.5, three speeds travelling
#: 0.5, 0.75 and 1 times N sigma_min in an hour, weights 0.2, 0.5, 0.3.
BUTTERLY_START = dict(mean=(1000.0, -500.0), sx=100.0, sy=250.0, rho=0.5)
BUTTERLY_FRACTIONS, BUTTERLY_WEIGHTS, BUTTERLY_T = (0.5, 0.75, 1.0), (0.2, 0.5, 0.3), 3600.0
BUTTERLY_RATIOS = (1, 10, 100, 1000)
#: Side of the Butterly grid (cells).
BUTTERLY_SIDE = 2048
#: A Butterly baseline (on its rows) quicker than this many seconds is also timed best of
#: ``--repeat``, like the kernels; slower ones once (a few percent of noise against minutes).
BASELINE_REPEAT_BELOW = 5.0


def butterly_parameters(ratio: float) -> dict:
    """Scene parameters of the ``butterly-rN`` model: largest travelled range ``ratio`` sigma_min."""
    sx, sy, rho = BUTTERLY_START["sx"], BUTTERLY_START["sy"], BUTTERLY_START["rho"]
    cov = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
    s_min = math.sqrt(0.5 * (sx * sx + sy * sy) - math.hypot(0.5 * (sx * sx - sy * sy), rho * sx * sy))
    v = ratio * s_min / BUTTERLY_T
    return dict(mean=BUTTERLY_START["mean"], cov=cov, speeds=[f * v for f in BUTTERLY_FRACTIONS],
                weights=list(BUTTERLY_WEIGHTS), t=BUTTERLY_T)


#: Grid rows: the model kind (a registry name) and its scene parameters in SI units.
GRID_ROWS = {
    "cat": ("cat", FIG1),
    # Figure 8's widest heading error, sigma_0 = pi/15 (its cost against the plain CAT is reported)
    "cat-heading": ("cat", {**FIG1, "sigma_heading": math.pi / 15}),
    "polar-rough": ("polar", {**FIG1, "variant": "rough"}),
    "polar-improved": ("polar", {**FIG1, "variant": "improved"}),
    # Figure 8's widest heading error, sigma_0 = pi/15, at order 4 (no NumPy twin: the improved row's)
    "polar-heading": ("polar", {**FIG1, "variant": "improved", "sigma_heading": math.pi / 15, "heading_order": 4}),
    "bearing-exact": ("bearing_fix", COASTAL),
    **{f"butterly-r{n}": ("butterly", butterly_parameters(n)) for n in BUTTERLY_RATIOS},
}


def grid_model(name: str):
    """The model of grid row ``name``, built through the registry."""
    kind, params = GRID_ROWS[name]
    return MODEL_KINDS[kind].build(params)



class _PresenceJob:
    """``presence-plane``: the paper's 360 x 91 plane lattice (32,760 cells, h = 1.8 m) with an
    8-component mixture (fixed seed) at the guaranteed accuracy; baseline: SciPy ``dblquad``
    per cell (``baselines.presence_plane_cells``) on a spread sample of cells, scaled. float32
    runs at tolerance ``angular.FLOAT32_RTOL`` (the 1e-6 guarantee is float64's)."""

    dtypes = (np.float64, np.float32)

    def __init__(self):
        rng = np.random.default_rng(20261121)
        sd = rng.uniform(0.1, 0.6, (8, 2))
        rho = rng.uniform(-0.8, 0.8, 8)
        covs = [[[a * a, r * a * b], [r * a * b, b * b]] for (a, b), r in zip(sd, rho)]
        self.mixture = GaussianMixture(weights=np.full(8, 1 / 8), means=rng.uniform(-2.5, 2.5, (8, 2)), covs=covs)
        self.lattice = AngularLattice.integer_degrees("plane", h=1.8)
        self.cells = self.lattice.n_azimuth * self.lattice.n_elevation

    def work(self, dtype, threads, device="cpu"):
        cell_probabilities(self.mixture, self.lattice, dtype=dtype, threads=threads, device=device)

    def baseline(self, stride: int, repeat: int) -> float:
        n = max(8, self.cells // (100 * stride))
        rng = np.random.default_rng(1)
        cells = list(zip(rng.integers(0, self.lattice.n_azimuth, n), rng.integers(0, self.lattice.n_elevation, n)))
        start = time.perf_counter()
        baselines.presence_plane_cells(self.mixture, self.lattice, cells)
        return (time.perf_counter() - start) * self.cells / n


class _PresenceGridJob(_PresenceJob):
    """``presence-grid``: the same 8-component mixture on a 1024 x 1024 grid over a 6 m x 5 m
    room, each cell's exact probability (Genz's BVN in the kernel); baseline: SciPy
    ``multivariate_normal.cdf`` at each cell's corners per component, on a sample, scaled.
    float32 is the float64 arithmetic with float32 output (the orthant terms cancel), so it
    times the same work."""

    dtypes = (np.float64, np.float32)

    def __init__(self):
        super().__init__()
        self.grid = Grid.from_bounds(x=(-3.0, 3.0), y=(-2.5, 2.5), dx=6.0 / 1024, dy=5.0 / 1024)
        self.cells = self.grid.nx * self.grid.ny

    def work(self, dtype, threads, device="cpu"):
        grid_probabilities(self.mixture, self.grid, dtype=dtype, threads=threads, device=device)

    def baseline(self, stride: int, repeat: int) -> float:
        n = max(16, 2560 // stride)
        rng = np.random.default_rng(2)
        cells = list(zip(rng.integers(0, self.grid.ny, n), rng.integers(0, self.grid.nx, n)))
        start = time.perf_counter()
        baselines.presence_grid_cells(self.mixture, self.grid, cells)
        return (time.perf_counter() - start) * self.cells / n


class _PresenceFrustumJob:
    """``presence-frustum``: the 360 x 91 frustum lattice of the slab 1.3-1.8 m below the array
    with scenes/room_frustum.toml's 3-D mixture; baseline: SciPy ``tplquad`` per cell on a
    sample of 8 cells, scaled; float32 at ``angular.FLOAT32_RTOL``."""

    dtypes = (np.float64, np.float32)

    def __init__(self):
        sd = [(0.25, 0.25, 0.05), (0.7, 0.2, 0.08), (0.15, 0.3, 0.08)]
        rho = [0.0, 0.0, 0.3]
        covs = [[[a * a, r * a * b, 0.0], [r * a * b, b * b, 0.0], [0.0, 0.0, c * c]] for (a, b, c), r in zip(sd, rho)]
        self.mixture = GaussianMixture(
            weights=[0.5, 0.35, 0.15], means=[[-1.8, 1.5, -1.75], [1.2, -1.8, -1.75], [2.6, 1.9, -1.35]], covs=covs
        )
        self.lattice = AngularLattice.integer_degrees("frustum", h=1.55, dh=0.25)
        self.cells = self.lattice.n_azimuth * self.lattice.n_elevation

    def work(self, dtype, threads, device="cpu"):
        cell_probabilities(self.mixture, self.lattice, dtype=dtype, threads=threads, device=device)

    def baseline(self, stride: int, repeat: int) -> float:
        rng = np.random.default_rng(3)
        cells = list(zip(rng.integers(0, self.lattice.n_azimuth, 8), rng.integers(0, self.lattice.n_elevation, 8)))
        start = time.perf_counter()
        baselines.presence_frustum_cells(self.mixture, self.lattice, cells)
        return (time.perf_counter() - start) * self.cells / len(cells)


class _BatchJob:
    """``polar-batch``: 10,000 improved polar-banana hypotheses (fixed seed), each on its own
    64 x 64 grid framed about it (framing not timed), in one launch; baseline: the NumPy twin
    per hypothesis on every ``stride``-th hypothesis, scaled."""

    dtypes = (np.float64, np.float32)
    HYPOTHESES = 10_000

    def __init__(self):
        self.models = batch_hypotheses(self.HYPOTHESES)
        self.grids = frame(self.models)
        self.cells = self.HYPOTHESES * 64 * 64

    def work(self, dtype, threads, device="cpu"):
        rasterise_batch(self.models, self.grids, dtype=dtype, threads=threads, device=device)

    def baseline(self, stride: int, repeat: int) -> float:
        picks = range(0, self.HYPOTHESES, stride)
        start = time.perf_counter()
        for k in picks:
            m, g = self.models[k], self.grids[k]
            xx, yy = np.meshgrid(g.x, g.y)
            c, s = math.cos(m.pose.heading), math.sin(m.pose.heading)
            dx, dy = xx - m.pose.origin[0], yy - m.pose.origin[1]
            baselines.polar_density(dx * c - dy * s, dx * s + dy * c, m.v0, m.t, m.sigma_a, m.sigma_omega, m.variant)
        return (time.perf_counter() - start) * self.HYPOTHESES / len(picks)


class _CellJob:
    """Cell probabilities, ``rasterise(model, grid, quantity="probability")``, with the
    densities on the same grid timed alongside (``density_seconds``, ``cost_vs_density``)."""

    dtypes = (np.float64, np.float32)
    SAMPLE = 16

    def __init__(self, model, grid: Grid):
        self.model, self.grid = model, grid
        self.cells = grid.nx * grid.ny

    def work(self, dtype, threads, device="cpu"):
        rasterise(self.model, self.grid, quantity="probability", dtype=dtype, threads=threads, device=device)

    def density(self, dtype, threads, device="cpu"):
        rasterise(self.model, self.grid, dtype=dtype, threads=threads, device=device)

    def sample_cells(self, n: int) -> list[tuple[float, float, float, float]]:
        """``n`` cells drawn uniformly (fixed seed) as world boxes."""
        rng = np.random.default_rng(4)
        (x0, _, y0, _), g = self.grid.extent, self.grid
        return [(x0 + j * g.dx, x0 + (j + 1) * g.dx, y0 + i * g.dy, y0 + (i + 1) * g.dy)
                for i, j in zip(rng.integers(0, g.ny, n), rng.integers(0, g.nx, n))]


class _CatCellJob(_CellJob):
    """``cat-cells``: the Figure 1 CAT's cell probabilities on the ``cat`` row's grid (the
    Figure 1 frame at 4 m), exact in the acceleration; baseline: NumPy (``baselines.cat_cells``:
    the lines at the midpoints of the same turn-rate intervals, each clipped against a cell at
    once, the midpoint rule, a cheaper rule than the kernel's) on a sample of cells, scaled."""

    def __init__(self):
        super().__init__(grid_model("cat"), Grid.from_bounds(**FIG1_BOUNDS, step=4.0))

    def baseline(self, stride: int, repeat: int) -> float:
        edges = cell_turn_edges(self.model, min(self.grid.dx, self.grid.dy))
        cells = self.sample_cells(max(4, self.SAMPLE // stride))
        start = time.perf_counter()
        baselines.cat_cells(self.model, cells, edges)
        return (time.perf_counter() - start) * self.cells / len(cells)


class _ButterlyCellJob(_CellJob):
    """``butterly-cells``: the ``butterly-r10`` model's cell probabilities (the engine's
    Gauss-Legendre rule) on its bench frame at 256 x 256 cells; baseline: SciPy ``dblquad``
    of the NumPy twin (``baselines.density_cells``) on a sample of cells, scaled."""

    SIDE = 256

    def __init__(self):
        x0, x1, y0, y1 = _grid_for("butterly-r10", 4.0).extent
        side = (x1 - x0) / self.SIDE
        super().__init__(grid_model("butterly-r10"), Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=side, dy=side))

    def baseline(self, stride: int, repeat: int) -> float:
        cells = self.sample_cells(max(4, self.SAMPLE // stride))
        density = functools.partial(baselines.butterly_density, self.model)
        start = time.perf_counter()
        baselines.density_cells(density, cells)
        return (time.perf_counter() - start) * self.cells / len(cells)


class _AllocateJob:
    """``allocate``: optimal random-search effort (``bg.allocate``) on a 1000 x 1000 map of
    cell probabilities (the ``polar-improved`` density over the Figure 1 frame, times the cell
    area, normalised), effort a tenth of the frame's area; the sort and the closed form of the
    multiplier are NumPy on one core whatever the threads. Baseline: NumPy bisection of the
    multiplier (60 halvings of ln lambda, each a pass over every cell), what one writes without
    the sorted closed form."""

    dtypes = (np.float64,)
    SIDE = 1000

    def __init__(self):
        x0, x1, y0, y1 = _grid_for("polar-improved", 4.0).extent
        grid = Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / self.SIDE, dy=(y1 - y0) / self.SIDE)
        density = rasterise(grid_model("polar-improved"), grid).values.astype(np.float64)
        p = density / density.sum()
        self.map = Raster(values=p, grid=grid, mass=1.0, quantity="probability")
        self.cells = grid.nx * grid.ny
        self.effort = 0.1 * (x1 - x0) * (y1 - y0)

    def work(self, dtype, threads, device="cpu"):
        allocate(self.map, self.effort)

    def baseline(self, stride: int, repeat: int) -> float:
        p, area = self.map.values.ravel(), self.map.grid.cell_area
        keep = p > 0
        log_d = np.log(p[keep] / area)
        start = time.perf_counter()
        lo, hi = log_d.min() - self.effort / (area * keep.sum()), log_d.max()
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            spent = area * np.maximum(log_d - mid, 0.0).sum()
            lo, hi = (mid, hi) if spent > self.effort else (lo, mid)
        return time.perf_counter() - start


class _PeriodPlanJob:
    """``plan-periods``: a 3-period moving-target plan (``bg.plan_periods``, random search) for
    the submarine of ``scenes/submarine.toml`` (Butterly: start SD 2 km x 0.5 km, rho 0.5; 5, 10
    or 15 kn on any course) on that scene's own grid, +-230 km at 400 m cells (1150 x 1150), at
    2, 3 and 4 h, 5,000 km^2 of effort each (a 5 km sweep width over 1,000 km of track), to a
    tolerance of 1e-5 of POS per sweep. The maps are carried on the cells with mass only (some
    70,000 to 150,000 of the 1.3 million), first on 4 x 4 sub-cells of each, then from that plan
    on 12 x 12 where the other periods' weight varies. Baseline: the three periods' own
    single-period plans (each map's cell probabilities and ``allocate``), what planning the
    periods apart costs. Measured on one thread (Xeon, AVX-512): 788 s (the bench, loaded
    machine); 713 s of CPU in 14 first-look sweeps (24 s each), the refined maps' baseline and 2
    refined sweeps (126 s each), POS 0.92853. A row of minutes is timed once, with no warm-up
    run (the kernels' first compile is seconds of it): ``timed_once``."""

    dtypes = (np.float64,)
    timed_once = True
    TIMES = (7200.0, 10800.0, 14400.0)
    EFFORTS = (5e9, 5e9, 5e9)
    STEP = 400.0
    TOL = 1e-5

    def __init__(self):
        knot = 1852.0 / 3600.0
        sx, sy, rho = 2000.0, 500.0, 0.5
        self.model = MODEL_KINDS["butterly"].build(dict(
            mean=(0.0, 0.0), cov=[[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]],
            speeds=[5.0 * knot, 10.0 * knot, 15.0 * knot], weights=[0.2, 0.5, 0.3], t=self.TIMES[0]))
        self.grid = Grid.from_bounds(x=(-230000.0, 230000.0), y=(-230000.0, 230000.0), step=self.STEP)
        self.cells = self.grid.nx * self.grid.ny

    def work(self, dtype, threads, device="cpu"):
        self.plan = plan_periods(self.model, self.grid, self.TIMES, self.EFFORTS, tol=self.TOL, threads=threads)

    def baseline(self, stride: int, repeat: int) -> float:
        def own_plans():
            for t, z in zip(self.TIMES, self.EFFORTS):
                allocate(rasterise(replace(self.model, t=t), self.grid, quantity="probability"), z)
        return _best_of(repeat, own_plans)


#: Kernels timed on work other than one grid.
JOBS = {
    "presence-plane": _PresenceJob, "presence-frustum": _PresenceFrustumJob, "presence-grid": _PresenceGridJob,
    "polar-batch": _BatchJob, "cat-cells": _CatCellJob, "butterly-cells": _ButterlyCellJob,
    "allocate": _AllocateJob, "plan-periods": _PeriodPlanJob,
}

#: Every row of the bench, in order: a grid row's model factory, or None for a job or a posterior
#: row (:mod:`bananagrid.bench.posterior`).
KERNELS = {**{name: functools.partial(grid_model, name) for name in GRID_ROWS}, **dict.fromkeys(JOBS),
           **dict.fromkeys(POSTERIOR_ROWS)}

#: Geometries in the containment timing.
CONTAINMENT_GEOMETRIES = 1_000_000


def _grid_for(name: str, step: float) -> Grid:
    """The Figure 1 frame at ``step`` for the banana kernels; 2048^2 about the fix for bearings."""
    if name.startswith("bearing"):
        return Grid.from_bounds(x=(0.0, 16000.0), y=(22000.0, 38000.0), dx=16000.0 / COASTAL_SIDE, dy=16000.0 / COASTAL_SIDE)
    if name.startswith("butterly"):
        model = grid_model(name)
        half = float(model.ranges.max()) + 6.0 * math.sqrt(model.axes[1])
        (mx, my), side = model.mean, 2.0 * half / BUTTERLY_SIDE
        return Grid.from_bounds(x=(mx - half, mx + half), y=(my - half, my + half), dx=side, dy=side)
    return Grid.from_bounds(**FIG1_BOUNDS, step=step)

#: Side of the square float32 raster whose peak memory is reported.
MEMORY_SIDE = 8192


def _best_of(repeat: int, fn) -> float:
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _baseline_seconds(name: str, model: DensityModel, grid: Grid, stride: int, repeat: int) -> float:
    """NumPy float64 time for the whole grid (scaled from every ``stride``-th row for CAT and
    Butterly). The heading-convolved CAT and polar banana have no NumPy twin: their baselines
    are the plain CAT's and the improved polar banana's (the same formula without heading noise).
    Butterly's twin skips the same negligible cells as the kernel (``floors``)."""
    cat = name.startswith("cat")
    butterly = name.startswith("butterly")
    rows = grid.y[::stride] if cat or butterly else grid.y
    xx, yy = np.meshgrid(grid.x, rows)
    if cat:
        nodes = scan_nodes(model)
        fn = lambda: baselines.cat_density(xx, yy, model.v0, model.t, model.sigma_a, model.sigma_omega, nodes)
        seconds = _best_of(1 if stride > 1 else repeat, fn)
    elif name.startswith("bearing"):
        seconds = _best_of(repeat, lambda: baselines.bearing_density(xx, yy, model))
    elif butterly:
        model.peak_lower_bound()  # computed once per model, by the kernel: not NumPy's time
        fn = lambda: baselines.butterly_density(model, xx, yy, floors=True)
        seconds = _best_of(1, fn)
        if seconds < BASELINE_REPEAT_BELOW:  # best of ``repeat`` too where that is cheap
            seconds = min(seconds, _best_of(repeat - 1, fn))
    else:
        fn = lambda: baselines.polar_density(xx, yy, model.v0, model.t, model.sigma_a, model.sigma_omega, model.variant)
        seconds = _best_of(repeat, fn)
    return seconds * grid.ny / len(rows)


def _cold_rasterise(model: DensityModel, grid: Grid, dtype, threads: int, device: str = "cpu"):
    """rasterise with nothing remembered from an earlier call: a CAT with heading noise keeps
    its last tables, which would leave their cost out of the time."""
    clear_heading_tables()
    return rasterise(model, grid, dtype=dtype, threads=threads, device=device)


def run(kernels, step: float, threads: int, repeat: int, stride: int, log=print, device: str = "cpu") -> list[dict]:
    """Time every kernel in both dtypes on 1 and ``threads`` threads (on a GPU: one row per
    dtype, results copied back to the host included, and the first call, which builds or loads
    the kernel module, timed as ``first_call_seconds``); return the records."""
    records = []
    gpu = device != "cpu"
    for name in kernels:
        if name in JOBS:
            records += _run_job(name, threads, repeat, stride, log, device)
            continue
        if name in POSTERIOR_ROWS:  # timed by posterior_rows, after the kernel rows
            continue
        model = grid_model(name)
        grid = _grid_for(name, step)
        base = _baseline_seconds(name, model, grid, stride, repeat)
        estimate = model.work_estimate(grid.nx * grid.ny, GridExtent(grid))  # one core's seconds
        for dtype in (np.float64, np.float32):
            # warm-up: compile or load the module
            first = _best_of(1, lambda: rasterise(model, grid, dtype=dtype, threads=1, device=device))
            for n_threads in ([1] if gpu else sorted({1, threads})):
                seconds = _best_of(repeat, lambda: _cold_rasterise(model, grid, dtype, n_threads, device))
                record = {
                    "kernel": name, "dtype": np.dtype(dtype).name, "threads": n_threads, "device": device,
                    "cells": grid.nx * grid.ny, "seconds": seconds, "baseline_seconds": base,
                    "ratio": base / seconds, "mcells_per_s": grid.nx * grid.ny / seconds / 1e6,
                }
                if gpu:
                    record["first_call_seconds"] = first
                else:
                    record["estimate_seconds"] = estimate / n_threads
                records.append(record)
                log(_row(record))
    return records


def peer_table(names: list[str], step: float, repeat: int, log=print) -> list[dict]:
    """The polar rows ``names`` against the installed peers (:func:`bananagrid.bench.peers.compare`),
    both dtypes; logs the table and returns its records ([] when no peer is installed)."""
    found = peers.installed()
    if not found:
        log(f"peers: none installed ({peers.PEERS_EXTRA} adds Numba and JAX)")
        return []
    records = []
    for name in names:
        model, grid = grid_model(name), _grid_for(name, step)
        for dtype in (np.float64, np.float32):
            rows = peers.compare(model, grid, dtype, repeat)
            if not records:
                log(f"peers on one core (CPU {rows[0]['cpu']}), {', '.join(found)} against rasterise and the NumPy twin "
                    f"on the same grid, values checked equal first, rows alternated, best of {repeat} "
                    "(spread: worst / best - 1; ours x: our best over this row's best)")
                log(peers.PEER_HEADER)
            for record in rows:
                record["kernel"] = name
                log(peers.peer_row(record))
            records += rows
    return records


def _run_job(name: str, threads: int, repeat: int, stride: int, log, device: str = "cpu") -> list[dict]:
    job = JOBS[name]()
    once = getattr(job, "timed_once", False)  # a row of minutes: no warm-up run, one timed run
    base = job.baseline(stride, 1 if once else repeat)
    records = []
    gpu = device != "cpu"
    for dtype in job.dtypes:
        first = None if once else _best_of(1, lambda: job.work(dtype, 1, device))  # compile or load the module
        for n_threads in ([1] if gpu else sorted({1, threads})):
            seconds = _best_of(1 if once else repeat, lambda: job.work(dtype, n_threads, device))
            record = {
                "kernel": name, "dtype": np.dtype(dtype).name, "threads": n_threads, "device": device,
                "cells": job.cells, "seconds": seconds, "baseline_seconds": base, "ratio": base / seconds,
                "mcells_per_s": job.cells / seconds / 1e6,
            }
            if gpu:
                record["first_call_seconds"] = first
            if hasattr(job, "density"):  # cell probabilities: their cost against the densities
                record["density_seconds"] = _best_of(repeat, lambda: job.density(dtype, n_threads, device))
                record["cost_vs_density"] = seconds / record["density_seconds"]
            records.append(record)
            log(_row(record))
    return records


HEADER = f"{'kernel':<16} {'dtype':<8} {'threads':>7} {'cells':>10} {'seconds':>9} {'Mcells/s':>9} {'numpy s':>9} {'ratio':>7}"


def _row(r: dict) -> str:
    gpu = r.get("device", "cpu") != "cpu"
    line = (
        f"{r['kernel']:<16} {r['dtype']:<8} {'gpu' if gpu else r['threads']:>7} {r['cells']:>10} {r['seconds']:>9.4f} "
        f"{r['mcells_per_s']:>9.2f} {r['baseline_seconds']:>9.3f} {r['ratio']:>7.1f}"
    )
    if gpu:
        line += f"  (first call {r['first_call_seconds']:.1f} s)"
    return line


def containment_timing(n: int = CONTAINMENT_GEOMETRIES, seed: int = 0, repeat: int = 3) -> dict:
    """Seconds for the containment probability at R = 1 km of ``n`` two-bearing geometries at
    once: stations 5-40 km apart, contacts 10-60 km out, bearing SDs 0.005-0.05 rad; the fix
    and its principal variances (:func:`bananagrid.models.bearing.two_bearing_variances`), then containment by
    the exact and the series method. Best of ``repeat`` runs, like the kernel rows."""
    rng = np.random.default_rng(seed)
    s2 = np.column_stack((rng.uniform(5000.0, 40000.0, n), rng.uniform(-3000.0, 3000.0, n)))
    targets = np.column_stack((rng.uniform(-10000.0, 30000.0, n), rng.uniform(10000.0, 60000.0, n)))
    b1 = bearing_to(np.zeros(2), targets)
    b2 = bearing_to(s2, targets)
    sd1, sd2 = rng.uniform(0.005, 0.05, n), rng.uniform(0.005, 0.05, n)
    out = {"geometries": n}
    def run(method):
        _, v1, v2 = two_bearing_variances(np.zeros(2), s2, b1, b2, sd1, sd2)
        ok = np.isfinite(v1)
        containment(1000.0, v1[ok], v2[ok], method=method)
        return int(n - ok.sum())

    for method in ("exact", "series"):
        out[f"{method}_seconds"] = _best_of(repeat, lambda: run(method))
    out["without_fix"] = run("exact")
    return out


#: Small calls, what a tracker pays on every update: ``rasterise`` on a grid of SMALL_SIDE x
#: SMALL_SIDE cells over a row's frame, ``pdf`` at SMALL_POINTS of the model's own samples, and
#: framing and rasterising SMALL_HYPOTHESES polar hypotheses on grids of each SMALL_BATCH_SHAPES.
SMALL_SIDE, SMALL_POINTS, SMALL_HYPOTHESES = 100, 1000, 1000
SMALL_ROWS = ("polar-improved", "cat", "bearing-exact")
SMALL_BATCH_SHAPES = ((64, 64), (16, 16))
#: Each timing runs calls for about this many seconds of wall time, the best of ``repeat``.
SMALL_SECONDS = 0.05


def _per_call(repeat: int, fn) -> tuple[float, float, int]:
    """``(process CPU seconds, wall seconds, calls)`` per call of ``fn``: best of ``repeat`` runs
    of about SMALL_SECONDS each, after two warm-up calls (the first loads the kernel)."""
    fn()
    start = time.perf_counter()
    fn()
    calls = max(1, int(SMALL_SECONDS / max(time.perf_counter() - start, 1e-7)))
    cpu = wall = math.inf
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        for _ in range(calls):
            fn()
        cpu, wall = min(cpu, (time.process_time() - c0) / calls), min(wall, (time.perf_counter() - w0) / calls)
    return cpu, wall, calls


def batch_hypotheses(n: int, seed: int = 20261121) -> list:
    """``n`` polar hypotheses spread over 20 km (the ``polar-batch`` row's draw)."""
    rng = np.random.default_rng(seed)
    polar = MODEL_KINDS["polar"]
    return [polar.build(dict(v0=float(rng.uniform(150.0, 300.0)), t=10.0, sigma_a=float(rng.uniform(0.5, 2.0)),
                             sigma_omega=float(rng.uniform(0.02, 0.06)), origin=tuple(rng.uniform(-1e4, 1e4, 2)),
                             heading=float(rng.uniform(-math.pi, math.pi))))
            for _ in range(n)]


def small_calls(threads: int, repeat: int, log=print) -> dict:
    """Per-call times of small calls, float64: ``rasterise`` on SMALL_SIDE^2 cells and ``pdf`` at
    SMALL_POINTS points for each SMALL_ROWS model on one thread and on ``threads``; framing
    SMALL_HYPOTHESES hypotheses against rasterising them on the framed grids (``threads``).
    Process CPU time (every thread's) and wall time, microseconds."""
    rows = []
    log(f"small calls, float64, per call: process CPU time (all threads) and wall time, us, best of {repeat}")
    log(f"{'call':<28} {'model':<16} {'threads':>7} {'cpu us':>9} {'wall us':>9} {'calls':>6}")
    for name in SMALL_ROWS:
        model = grid_model(name)
        x0, x1, y0, y1 = _grid_for(name, 4.0).extent
        grid = Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / SMALL_SIDE, dy=(y1 - y0) / SMALL_SIDE)
        points = model.sample(SMALL_POINTS, np.random.default_rng(1))
        px, py = np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])
        for n in sorted({1, threads}):
            for call, fn in ((f"rasterise {SMALL_SIDE} x {SMALL_SIDE}", lambda: rasterise(model, grid, threads=n)),
                             (f"pdf {SMALL_POINTS:,} points", lambda: evaluate_points(model, px, py, threads=n))):
                cpu, wall, calls = _per_call(repeat, fn)
                rows.append({"call": call, "model": name, "threads": n, "cpu_us": cpu * 1e6, "wall_us": wall * 1e6,
                             "calls": calls})
                log(f"{call:<28} {name:<16} {n:>7} {cpu * 1e6:>9.1f} {wall * 1e6:>9.1f} {calls:>6}")
    hypotheses = batch_hypotheses(SMALL_HYPOTHESES)
    batches = []
    for shape in SMALL_BATCH_SHAPES:
        grids = frame(hypotheses, shape)
        f_cpu, f_wall, _ = _per_call(repeat, lambda: frame(hypotheses, shape))
        l_cpu, l_wall, _ = _per_call(repeat, lambda: rasterise_batch(hypotheses, grids, threads=threads))
        us = {"frame_cpu_us": f_cpu * 1e6, "frame_wall_us": f_wall * 1e6, "launch_cpu_us": l_cpu * 1e6,
              "launch_wall_us": l_wall * 1e6}
        # the ratios of the recorded figures themselves ((a 1e6) / (b 1e6) can differ from a / b by an ulp)
        batches.append({"hypotheses": SMALL_HYPOTHESES, "shape": list(shape), "threads": threads, **us,
                        "frame_over_launch_wall": us["frame_wall_us"] / us["launch_wall_us"],
                        "frame_over_launch_cpu": us["frame_cpu_us"] / us["launch_cpu_us"]})
        log(f"batch of {SMALL_HYPOTHESES:,} polar hypotheses on {shape[0]} x {shape[1]}, {threads} threads: frame "
            f"{f_wall * 1e3:.2f} ms, rasterise_batch on the framed grids {l_wall * 1e3:.2f} ms (wall; CPU "
            f"{f_cpu * 1e3:.2f} and {l_cpu * 1e3:.2f} ms): framing costs {f_wall / l_wall:.2f}x the launch "
            f"({f_cpu / l_cpu:.2f}x in CPU time)")
    return {"calls": rows, "batches": batches}


def memory_probe(side: int = MEMORY_SIDE) -> dict:
    """Peak resident memory (ru_maxrss) of a fresh process that imports bananagrid, initialises
    Warp and rasterises a side x side float32 polar map: everything a user's process holds."""
    code = (
        "import resource, bananagrid as bg, numpy as np;"
        f"m = bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5/3, sigma_omega={math.pi / 54!r});"
        "g = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), dx=6000/{s}, dy=3600/{s});"
        "r = bg.rasterise(m, g, dtype=np.float32);"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, r.values.nbytes)"
    ).replace("{s}", str(side))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    peak, nbytes = (int(v) for v in out.stdout.split()[-2:])
    return {"side": side, "peak_rss_mib": peak / 1024, "raster_mib": nbytes / 2**20}


def vector_width() -> str:
    """The widest SIMD registers the CPU offers (from /proc/cpuinfo's flags) and the lanes they
    hold: the lane kernels' 512-bit vectors run as one register with AVX-512, as two halves with
    AVX2."""
    try:
        with open("/proc/cpuinfo") as fh:
            flags = set(next(line.split(":", 1)[1].split() for line in fh if line.startswith(("flags", "Features"))))
    except (OSError, StopIteration):
        return "vector width unknown"
    for flag, bits, name in (("avx512f", 512, "AVX-512"), ("avx2", 256, "AVX2"), ("avx", 256, "AVX"),
                             ("asimd", 128, "NEON"), ("sse2", 128, "SSE2")):
        if flag in flags:
            return f"{bits}-bit vectors ({name}: {bits // 64} float64 / {bits // 32} float32 lanes)"
    return "no SIMD flags found"


def machine() -> str:
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            model = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return (f"{model}, {vector_width()}, {default_threads()} cores usable, Python {platform.python_version()}, "
            f"{platform.system()}")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="bananagrid bench",
        description="Time every kernel against its NumPy float64 baseline, measured in the same run.",
    )
    p.add_argument("--kernels", default=",".join(KERNELS), help=f"comma-separated subset of: {', '.join(KERNELS)} (default: all)")
    p.add_argument("--step", type=float, default=4.0, help="grid step in metres over the Figure 1 frame (default 4: 1500 x 900 cells)")
    p.add_argument("--threads", type=int, default=default_threads(), help="threads for the all-cores rows (default: every usable core)")
    p.add_argument("--repeat", type=int, default=3, help="timed runs per row; the best is reported (default 3)")
    p.add_argument("--baseline-stride", type=int, default=10, help="run the CAT and Butterly NumPy baselines on every N-th row and scale (default 10; 1 = all rows)")
    p.add_argument("--no-peers", action="store_true",
                   help="skip the peers table (the polar rows against Numba and JAX on one core, when the peers extra "
                        f"is installed: {peers.PEERS_EXTRA})")
    p.add_argument("--no-memory", action="store_true", help=f"skip the peak-memory probe ({MEMORY_SIDE} x {MEMORY_SIDE} float32)")
    p.add_argument("--json", metavar="FILE", help="also write the records as JSON to FILE")
    p.add_argument("--evidence", choices=EVIDENCE, default="earlier",
                   help="the posterior rows' two searches: at earlier times, carried to the map's time through the "
                        "model's paths (default), or at the map's own time")
    p.add_argument("--device", default="cpu",
                   help="Warp device of the kernel rows: cpu (default) or cuda. On cuda each row runs once per dtype "
                        "(results copied back to the host included), its first call (building or loading the kernel "
                        "module) is reported beside it, the baseline is still NumPy on the CPU, and the CPU-only "
                        "parts (peers, thread scaling, containment, memory probe) are skipped")
    p.add_argument("--small", action="store_true",
                   help=f"time small calls, what a tracker pays on every update: rasterise on {SMALL_SIDE} x "
                        f"{SMALL_SIDE} cells and pdf at {SMALL_POINTS:,} points ({', '.join(SMALL_ROWS)}; one thread "
                        f"and --threads), and framing {SMALL_HYPOTHESES:,} hypotheses against their batch launch. "
                        "Alone (without --kernels) it runs only these rows.")
    c = p.add_argument_group(
        "cluster rows (the cluster extra; minutes)",
        "--cluster measures tiles and hypothesis shards on a fresh local Dask cluster: a Butterly map on a "
        "SIDE x SIDE float32 grid into Zarr (seconds, blocks and cells computed and skipped, each worker's peak "
        "memory), the same map on a grid its support fills (a computed cell's cost into Zarr against the "
        "in-memory rasterise on one thread), and N polar hypotheses on 64 x 64 grids sharded over the workers against the single-process "
        "batch. Alone (without --kernels) it runs only these rows.",
    )
    c.add_argument("--cluster", action="store_true", help="run the cluster rows")
    c.add_argument("--cluster-side", type=int, default=cluster.CLUSTER_SIDE, metavar="SIDE",
                   help=f"side of the zarr row's grid, cells of 1 m (default {cluster.CLUSTER_SIDE})")
    c.add_argument("--dense-side", type=int, default=cluster.DENSE_SIDE, metavar="SIDE",
                   help=f"side of the zarr-dense row's grid, every block computed (default {cluster.DENSE_SIDE})")
    c.add_argument("--hypotheses", type=int, default=cluster.HYPOTHESES, metavar="N",
                   help=f"hypotheses of the sharded row (default {cluster.HYPOTHESES:,}; the single-process batch "
                   f"takes min(N, {cluster.IN_PROCESS_HYPOTHESES:,}))")
    c.add_argument("--workers", type=int, default=2, metavar="N", help="worker processes (default 2)")
    c.add_argument("--memory-limit", default="4GiB", metavar="SIZE", help="memory per worker (default 4GiB)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``bananagrid bench``; returns the exit code."""
    args = _parser().parse_args(argv)
    if (args.cluster or args.small) and not any(a == "--kernels" or a.startswith("--kernels=")
                                                for a in (argv or sys.argv[1:])):
        args.kernels = ""  # the cluster or small-call rows alone
    kernels = [k.strip() for k in args.kernels.split(",") if k.strip()]
    unknown = [k for k in kernels if k not in KERNELS]
    problems = []
    if unknown or not (kernels or args.cluster or args.small):
        problems.append(f"--kernels = {args.kernels!r}: choose from {', '.join(KERNELS)}")
    for name in ("threads", "repeat", "baseline_stride", "workers", "hypotheses"):
        if getattr(args, name) < 1:
            problems.append(f"--{name.replace('_', '-')} = {getattr(args, name)}: must be >= 1")
    for name in ("cluster_side", "dense_side"):
        if getattr(args, name) < 64:
            problems.append(f"--{name.replace('_', '-')} = {getattr(args, name)}: must be >= 64")
    if args.cluster:
        try:
            check_memory_limit(args.memory_limit)
        except BananagridError as exc:
            problems.append(f"--memory-limit: {exc}")
    if not (math.isfinite(args.step) and args.step > 0):
        problems.append(f"--step = {args.step}: must be > 0")
    gpu = args.device != "cpu"
    device = "cpu"
    if gpu and args.cluster:
        problems.append(f"--device = {args.device!r}: the cluster rows run on the CPU; drop --cluster or --device")
    if gpu and args.small:
        problems.append(f"--device = {args.device!r}: the small-call rows run on the CPU; drop --small or --device")
    if not problems:
        try:
            device = device_name(args.device)
        except BananagridError as exc:
            problems.append(f"--device: {exc}")
    if args.json and not problems:  # before minutes of timing, not after
        try:
            check_writable(Path(args.json).resolve().parent)
            check_target(args.json, "JSON records")  # a directory, a link or a pipe there is refused
        except BananagridError as exc:
            problems.append(f"--json {args.json}: {exc}")
    if not problems:
        try:
            check_rows([name for name in kernels if name in POSTERIOR_ROWS], args.step, args.evidence)
        except BananagridError as exc:
            problems.append(f"--evidence {args.evidence}: {exc}")
    if problems:
        print(f"bananagrid: error: {problems[0]}", file=sys.stderr)
        return 2
    print(f"machine: {machine()}")
    if gpu:
        print(f"device: {device} (kernel rows; baselines on the CPU above)")
    if kernels:
        print(f"grids: Figure 1 frame at {args.step:g} m (banana kernels), {COASTAL_SIDE} x {COASTAL_SIDE} "
              f"about the coastal fix (bearing), {BUTTERLY_SIDE} x {BUTTERLY_SIDE} about the ring +- 6 sigma "
              f"(butterly-rN: three speeds, largest range N sigma_min); baseline: NumPy {np.__version__} float64 "
              "(cat-heading, polar-heading: the plain CAT's and the improved polar's, as they have no NumPy twin)"
              + (f", CAT and Butterly on every {args.baseline_stride}th row, scaled" if args.baseline_stride > 1 else ""))
    records = []
    kernel_rows = [name for name in kernels if name not in POSTERIOR_ROWS]
    if kernel_rows:
        print(HEADER)
        records = run(kernel_rows, args.step, args.threads, args.repeat, args.baseline_stride, device=args.device)
    posterior_names = [name for name in kernels if name in POSTERIOR_ROWS]
    if posterior_names:
        if gpu:
            print(f"posterior rows: on the CPU (--device {args.device} applies to the kernel rows)")
        result_posterior = posterior_rows(posterior_names, args.step, args.threads, args.repeat, args.evidence)
    result = {"machine": machine(), "device": device, "step": args.step, "records": records}
    if posterior_names:
        result["posterior"] = result_posterior
    if args.small:
        result["small_calls"] = small_calls(args.threads, args.repeat)
    if args.cluster:
        result["cluster_zarr"] = cluster.zarr_row(side=args.cluster_side, workers=args.workers,
                                                  memory_limit=args.memory_limit)
        result["cluster_dense"] = cluster.dense_row(side=args.dense_side, workers=args.workers,
                                                    memory_limit=args.memory_limit)
        result["cluster_hypotheses"] = cluster.hypotheses_row(
            hypotheses=args.hypotheses, in_process=min(args.hypotheses, cluster.IN_PROCESS_HYPOTHESES),
            workers=args.workers, memory_limit=args.memory_limit)
    polar_rows = [name for name in kernels if name in GRID_ROWS and GRID_ROWS[name][0] == "polar"
                  and not GRID_ROWS[name][1].get("sigma_heading")]  # the peers compute (8) and (11) only
    if polar_rows and not args.no_peers and not gpu:
        result["peers"] = peer_table(polar_rows, args.step, args.repeat)
    for name in kernel_rows:
        one = {r["dtype"]: r for r in records if r["kernel"] == name and r["threads"] == 1}
        many = {r["dtype"]: r for r in records if r["kernel"] == name and r["threads"] == args.threads}
        if args.threads > 1 and not gpu:
            print(f"{name}: 1 -> {args.threads} threads speedup "
                  + ", ".join(f"{d} {one[d]['seconds'] / many[d]['seconds']:.2f}x" for d in one))
    estimated = [r for r in records if "estimate_seconds" in r and r["dtype"] == "float64" and r["threads"] == 1]
    if estimated:  # the work check before launches (bananagrid.engine.work) is meant to overestimate
        print("work estimate / measured (float64, 1 thread): "
              + ", ".join(f"{r['kernel']} {r['estimate_seconds'] / r['seconds']:.1f}x" for r in estimated))
    if "cat" in kernels and "cat-heading" in kernels:
        cost = {
            (r["dtype"], r["threads"]): r["seconds"] / next(
                c["seconds"] for c in records if c["kernel"] == "cat" and c["dtype"] == r["dtype"] and c["threads"] == r["threads"]
            )
            for r in records if r["kernel"] == "cat-heading"
        }
        result["heading_cost"] = [{"dtype": d, "threads": n, "ratio_to_cat": v} for (d, n), v in cost.items()]
        print("cat-heading (sigma_0 = pi/15) costs "
              + ", ".join(f"{v:.2f}x" for v in cost.values()) + " the plain CAT ("
              + ", ".join(f"{d} {n} thr" for d, n in cost) + ")")
    cells = [r for r in records if "cost_vs_density" in r]
    if cells:
        print("cell probabilities cost, against the densities on the same grid: "
              + ", ".join(f"{r['kernel']} {r['dtype']} {r['threads']} thr {r['cost_vs_density']:.1f}x" for r in cells))
    if "bearing-exact" in kernels and not gpu:
        timing = containment_timing(repeat=args.repeat)
        result["containment"] = timing
        print(f"containment: {timing['geometries']:,} two-bearing geometries (fix, variances, P(R = 1 km)) in "
              f"{timing['exact_seconds']:.2f} s (exact), {timing['series_seconds']:.2f} s (Robbins-Pitman series, "
              f"tol 1e-12); {timing['without_fix']:,} had no fix in front of both stations")
    if not args.no_memory and kernels and not gpu:
        mem = memory_probe()
        result["memory"] = mem
        print(f"memory: {mem['side']} x {mem['side']} float32 polar raster ({mem['raster_mib']:.0f} MiB of values): "
              f"peak RSS of the whole process {mem['peak_rss_mib']:.0f} MiB")
    if args.json:
        with atomic_write(args.json) as tmp, open(tmp, "w") as fh:
            json.dump(result, fh, indent=2)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
