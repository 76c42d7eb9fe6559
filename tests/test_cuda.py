"""The GPU path: every model kind's kernels on a CUDA device against the CPU's on the same cells.

The CPU runs the lane kernels (their own exp, atan2 and sine) or the scalar kernels compiled by
clang; the GPU the scalar kernels compiled by NVRTC with CUDA's libm, so the two differ by a few
ulp per operation, amplified where a formula cancels. These tests need a CUDA device: CI has
none (they are skipped there) and they run on a machine with one
(``python -m pytest tests/test_cuda.py``). Densities, pdf at points, cell probabilities on
grids, polar lattices, tiles (Dask blocks), batches and the presence lattices are covered.

``BANANAGRID_TEST_GPU=cpu`` runs the same tests with the CPU in the GPU's place: a dry run of
the harness on a machine without a GPU (the agreement is then bit for bit or nearly).
"""

import math
import os
import warnings

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.engine.batch import pdf_batch, rasterise_batch
from bananagrid.engine.warp_runtime import warp
from bananagrid.models.presence import FLOAT32_RTOL, cell_probabilities, grid_probabilities

#: The device standing for the GPU ("cuda", or "cpu" for a dry run of the harness).
GPU = os.environ.get("BANANAGRID_TEST_GPU", "cuda")


def _has_cuda() -> bool:
    return any(device.is_cuda for device in warp().get_devices())


pytestmark = pytest.mark.skipif(GPU == "cuda" and not _has_cuda(), reason="needs a CUDA device (none here)")

FIG1 = dict(v0=280.0, t=10.0, sigma_a=5.0 / 3.0, sigma_omega=math.pi / 54.0)
FIG1_GRID = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=20.0)

#: Relative agreement of the GPU with the CPU where the density is at least 1e-10 (float64) or
#: 1e-6 (float32) of the peak. float64: a few ulp per step times the cancellation in
#: (r - mu) / sd (r / sd up to ~40 on these grids) and in the CAT's and Butterly's iterations
#: (stopped at 1e-14 relative). float32: the same with eps = 6e-8 (the lane kernels' float32
#: sweep bound is 64 eps32 kappa).
RTOL = {np.float64: 1e-10, np.float32: 1e-3}
FLOOR = {np.float64: 1e-10, np.float32: 1e-6}


def _models():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {
            "cat": (bg.CAT(**FIG1), FIG1_GRID),
            "cat-heading": (bg.CAT(**FIG1, sigma_heading=math.pi / 15), FIG1_GRID),
            "polar-rough": (bg.PolarBanana(**FIG1, variant="rough"), FIG1_GRID),
            "polar-improved": (bg.PolarBanana(**FIG1, variant="improved",
                                              pose=bg.Pose(origin=(120.0, -40.0), heading=0.3)), FIG1_GRID),
            "polar-heading-2": (bg.PolarBanana(**FIG1, sigma_heading=math.pi / 15, heading_order=2), FIG1_GRID),
            "polar-heading-4": (bg.PolarBanana(**FIG1, sigma_heading=math.pi / 15, heading_order=4), FIG1_GRID),
            "bearing-exact": (bg.BearingFix(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909],
                                            sigmas=[0.01, 0.02]),
                              bg.Grid.from_bounds(x=(0.0, 16000.0), y=(22000.0, 38000.0), step=64.0)),
            "bearing-linear": (bg.BearingFix(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909],
                                             sigmas=[0.01, 0.02], variant="linear"),
                               bg.Grid.from_bounds(x=(0.0, 16000.0), y=(22000.0, 38000.0), step=64.0)),
            "butterly": (bg.Butterly(mean=(1000.0, -500.0), cov=[[1e4, 1.25e4], [1.25e4, 6.25e4]],
                                     speeds=[0.3, 0.45, 0.6], weights=[0.2, 0.5, 0.3], t=3600.0),
                         bg.Grid.from_bounds(x=(-2000.0, 4000.0), y=(-3500.0, 2500.0), step=25.0)),
        }


def _compare(name, gpu, cpu, dtype, quiet=False) -> float:
    """Assert the agreement; print it unless ``quiet``; return the relative difference inside."""
    gpu, cpu = np.asarray(gpu, dtype=float), np.asarray(cpu, dtype=float)
    assert np.all(np.isfinite(gpu)), name
    peak = cpu.max()
    inside = cpu >= FLOOR[dtype] * peak
    rel = float(np.max(np.abs(gpu[inside] - cpu[inside]) / cpu[inside]))
    outside = float(np.max(np.abs(gpu[~inside] - cpu[~inside]), initial=0.0)) / peak
    if not quiet:
        print(f"cuda vs cpu {name} {np.dtype(dtype).name}: max relative {rel:.2e} inside, {outside:.2e} of the peak "
              "outside")
    assert rel <= RTOL[dtype], (name, rel)
    assert outside <= 1e-3 * FLOOR[dtype], (name, outside)  # a thousandth of the contour's level
    return rel


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("name", list(_models()))
def test_rasterise_and_pdf_on_the_gpu_match_the_cpu(name, dtype):
    model, grid = _models()[name]
    gpu = bg.rasterise(model, grid, dtype=dtype, device=GPU)
    cpu = bg.rasterise(model, grid, dtype=dtype, threads=2)
    assert gpu.provenance["device"] == GPU
    _compare(name, gpu.values, cpu.values, dtype)
    assert gpu.mass == pytest.approx(cpu.mass, rel=RTOL[dtype])
    rng = np.random.default_rng(5)
    (x0, x1, y0, y1) = grid.extent
    x, y = rng.uniform(x0, x1, 5000), rng.uniform(y0, y1, 5000)
    _compare(name + " pdf", model.pdf(x, y, dtype=dtype, device=GPU), model.pdf(x, y, dtype=dtype), dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_batches_on_the_gpu_match_the_cpu(dtype):
    rng = np.random.default_rng(11)
    models = [bg.PolarBanana(v0=float(rng.uniform(150.0, 300.0)), t=10.0, sigma_a=float(rng.uniform(0.5, 2.0)),
                             sigma_omega=float(rng.uniform(0.02, 0.06)), variant="rough" if k % 3 == 0 else "improved",
                             sigma_heading=0.05 if k % 4 == 0 else 0.0, heading_order=4 if k % 8 == 0 else 2,
                             pose=bg.Pose(origin=tuple(rng.uniform(-5e3, 5e3, 2)),
                                          heading=float(rng.uniform(-math.pi, math.pi))))
              for k in range(64)]
    gpu = rasterise_batch(models, dtype=dtype, device=GPU)
    cpu = rasterise_batch(models, dtype=dtype, threads=2)
    worst = max(_compare(f"batch {k}", gpu.values[k], cpu.values[k], dtype, quiet=True) for k in range(len(models)))
    print(f"cuda vs cpu rasterise_batch {np.dtype(dtype).name}: max relative {worst:.2e} over {len(models)} hypotheses")
    x, y = rng.uniform(-8e3, 8e3, 2000), rng.uniform(-8e3, 8e3, 2000)
    _compare("pdf_batch", pdf_batch(models, x, y, dtype=dtype, device=GPU), pdf_batch(models, x, y, dtype=dtype),
             dtype)


#: Cell probabilities: the CAT's exact rule (``kernels/cat_cells.py``) walks lines through the
#: grid and integrates between the turn rates where they pass a cell corner; a corner pass that
#: moves by an ulp moves a sub-piece's end, so GPU and CPU may differ by up to the rule's stated
#: error on either side (5e-5 of a cell + 1e-12, docs): 1e-4 relative. Every other model's
#: cells are fixed tensor Gauss-Legendre rules over its densities: the densities' agreement.
CELL_RTOL = {"cat": 1e-4}


def _cell_grid(name, grid):
    """A coarser grid over the same frame (cells of several density steps: a real integration)."""
    x0, x1, y0, y1 = grid.extent
    return bg.Grid.from_bounds(x=(x0, x1), y=(y0, y1), step=4.0 * grid.dx)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("name", list(_models()))
def test_cell_probabilities_on_the_gpu_match_the_cpu(name, dtype):
    model, grid = _models()[name]
    cells = _cell_grid(name, grid)
    gpu = bg.rasterise(model, cells, quantity="probability", dtype=dtype, device=GPU)
    cpu = bg.rasterise(model, cells, quantity="probability", dtype=dtype, threads=2)
    assert gpu.quantity == "probability" and gpu.provenance["device"] == GPU
    rtol = max(CELL_RTOL.get(name, 0.0), RTOL[dtype])
    peak = cpu.values.max()
    inside = cpu.values >= FLOOR[dtype] * peak
    rel = float(np.max(np.abs(gpu.values[inside] - cpu.values[inside]) / cpu.values[inside]))
    outside = float(np.max(np.abs(gpu.values[~inside] - cpu.values[~inside]), initial=0.0)) / peak
    print(f"cuda vs cpu cells {name} {np.dtype(dtype).name}: max relative {rel:.2e} inside, {outside:.2e} of the "
          f"peak outside, mass {gpu.mass!r} vs {cpu.mass!r}")
    assert rel <= rtol, (name, rel)
    assert outside <= max(rtol, 1e-3 * FLOOR[dtype]), (name, outside)
    assert gpu.mass == pytest.approx(cpu.mass, rel=rtol)


#: A polar lattice over each model's support: the Figure 1 models about their origin, the
#: bearing fix about its first station, Butterly about its start's mean.
LATTICES = {
    "bearing": dict(ranges=(20000.0, 40000.0), range_step=500.0, bearings=(0.0, 0.5), bearing_step=0.01),
    "butterly": dict(ranges=(0.0, 3000.0), range_step=100.0, bearings=(-math.pi, math.pi),
                     bearing_step=math.radians(5.0), pose=bg.Pose(origin=(1000.0, -500.0))),
    "motion": dict(ranges=(0.0, 4000.0), range_step=100.0, bearings=(-math.pi, math.pi),
                   bearing_step=math.radians(5.0)),
}


def _lattice(name, model):
    if name.startswith("bearing"):
        return bg.PolarLattice(**LATTICES["bearing"])
    if name == "butterly":
        return bg.PolarLattice(**LATTICES["butterly"])
    return bg.PolarLattice(**LATTICES["motion"], pose=model.pose)


@pytest.mark.parametrize("name", list(_models()))
def test_polar_lattices_on_the_gpu_match_the_cpu(name):
    model, _ = _models()[name]
    lattice = _lattice(name, model)
    gpu = bg.rasterise(model, lattice, device=GPU)
    cpu = bg.rasterise(model, lattice, threads=2)
    for what in ("density", "probability"):
        g, c = getattr(gpu, what), getattr(cpu, what)
        inside = c >= FLOOR[np.float64] * c.max()
        rel = float(np.max(np.abs(g[inside] - c[inside]) / c[inside]))
        print(f"cuda vs cpu polar lattice {name} {what}: max relative {rel:.2e} over {int(inside.sum())} cells, "
              f"sum {g.sum()!r} vs {c.sum()!r}")
        assert rel <= max(CELL_RTOL.get(name, 0.0), RTOL[np.float64]), (name, what, rel)
    assert gpu.mass == pytest.approx(cpu.mass, rel=max(CELL_RTOL.get(name, 0.0), RTOL[np.float64]))


@pytest.mark.parametrize("name", ["cat", "polar-improved", "polar-heading-4", "bearing-exact", "butterly"])
def test_tiles_on_the_gpu_match_the_in_memory_map(name):
    """Dask blocks on the GPU: each block is the grid kernel bound to the whole grid's extent,
    so it equals the in-memory map on the same device; the CPU agreement is the densities'."""
    pytest.importorskip("dask")
    model, grid = _models()[name]
    tiled = bg.rasterise(model, grid, chunks=64, dtype=np.float32, device=GPU)
    whole = bg.rasterise(model, grid, dtype=np.float32, device=GPU)
    values = np.asarray(tiled.values.compute(scheduler="synchronous"))
    same = bool(np.array_equal(values, whole.values))
    diff = float(np.max(np.abs(values - whole.values))) / float(whole.values.max())
    print(f"cuda tiles {name} float32: {'bit-identical to' if same else f'{diff:.2e} of the peak from'} the "
          "in-memory map on the same device")
    _compare(name + " tiles", values, bg.rasterise(model, grid, dtype=np.float32, threads=2).values, np.float32)
    assert diff <= 1e-6, (name, diff)  # float32: blocks run the same kernel code; a few ulp at most


def _mixtures():
    rng = np.random.default_rng(20261121)
    sd = rng.uniform(0.1, 0.6, (8, 2))
    rho = rng.uniform(-0.8, 0.8, 8)
    covs = [[[a * a, r * a * b], [r * a * b, b * b]] for (a, b), r in zip(sd, rho)]
    plane = bg.GaussianMixture(weights=np.full(8, 1 / 8), means=rng.uniform(-2.5, 2.5, (8, 2)), covs=covs)
    sd3 = [(0.25, 0.25, 0.05), (0.7, 0.2, 0.08), (0.15, 0.3, 0.08)]
    rho3 = [0.0, 0.0, 0.3]
    covs3 = [[[a * a, r * a * b, 0.0], [r * a * b, b * b, 0.0], [0.0, 0.0, c * c]] for (a, b, c), r in zip(sd3, rho3)]
    frustum = bg.GaussianMixture(weights=[0.5, 0.35, 0.15], means=[[-1.8, 1.5, -1.75], [1.2, -1.8, -1.75],
                                                                   [2.6, 1.9, -1.35]], covs=covs3)
    return plane, frustum


#: Presence cells: each component's adaptive Gauss-Kronrod integral stops once |K15 - G7| <=
#: rtol |K15|; an ulp of difference can stop a panel one split earlier or later on either
#: device, so the two agree to the stated accuracy (1e-6 relative for cells holding 1e-9 of the
#: mass in float64, docs), not to the ulp; float32 to its rtol, FLOAT32_RTOL, times 10.
PRESENCE_RTOL = {np.float64: 2e-6, np.float32: 10 * FLOAT32_RTOL}


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("geometry", ["plane", "frustum"])
def test_presence_lattices_on_the_gpu_match_the_cpu(geometry, dtype):
    plane, frustum = _mixtures()
    mixture = plane if geometry == "plane" else frustum
    lattice = (bg.AngularLattice.integer_degrees("plane", h=1.8) if geometry == "plane"
               else bg.AngularLattice.integer_degrees("frustum", h=1.55, dh=0.25))
    gpu = cell_probabilities(mixture, lattice, dtype=dtype, device=GPU).prob
    cpu = cell_probabilities(mixture, lattice, dtype=dtype, threads=2).prob
    inside = cpu >= 1e-9
    rel = float(np.max(np.abs(gpu[inside] - cpu[inside]) / cpu[inside]))
    print(f"cuda vs cpu presence {geometry} {np.dtype(dtype).name}: max relative {rel:.2e} over "
          f"{int(inside.sum())} cells holding >= 1e-9, sums {gpu.sum()!r} vs {cpu.sum()!r}")
    assert rel <= PRESENCE_RTOL[dtype], (geometry, rel)
    assert abs(gpu.sum() - cpu.sum()) <= 1e-6


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_presence_grids_on_the_gpu_match_the_cpu(dtype):
    """Exact cell probabilities of a mixture on a grid (bivariate normal CDFs in the kernel)."""
    plane, _ = _mixtures()
    grid = bg.Grid.from_bounds(x=(-3.0, 3.0), y=(-2.5, 2.5), dx=6.0 / 256, dy=5.0 / 256)
    gpu = grid_probabilities(plane, grid, dtype=dtype, device=GPU)
    cpu = grid_probabilities(plane, grid, dtype=dtype, threads=2)
    g, c = np.asarray(gpu.probability, dtype=float), np.asarray(cpu.probability, dtype=float)
    inside = c >= 1e-9
    rel = float(np.max(np.abs(g[inside] - c[inside]) / c[inside]))
    print(f"cuda vs cpu presence grid {np.dtype(dtype).name}: max relative {rel:.2e} over {int(inside.sum())} cells "
          f"holding >= 1e-9, sums {g.sum()!r} vs {c.sum()!r}")
    # float64: the same closed form (Genz's BVN) on both devices, a few ulp amplified by the
    # orthant differences of neighbouring corners (the docs' 1e-9 for cells holding 1e-9);
    # float32: float32 output of the float64 arithmetic, so its rounding, 6e-8, times a margin.
    assert rel <= {np.float64: 1e-9, np.float32: 1e-6}[dtype], rel
    d, e = np.asarray(gpu.density, dtype=float), np.asarray(cpu.density, dtype=float)
    _compare("presence grid density", d, e, dtype)


def test_bench_times_the_gpu_rows(tmp_path, capsys):
    """``bananagrid bench --device cuda``: one row per dtype, named as GPU rows, the first call
    (which builds or loads the module) beside it, and the device's name in the records."""
    import json

    from bananagrid.bench import runner as bench

    out = tmp_path / "bench.json"
    argv = ["--kernels", "cat,polar-improved,presence-grid", "--step", "100", "--repeat", "1", "--device", GPU,
            "--no-peers", "--no-memory", "--baseline-stride", "100", "--json", str(out)]
    assert bench.main(argv) == 0
    result = json.loads(out.read_text())
    assert result["device"].startswith(GPU)
    records = result["records"]
    assert {(r["kernel"], r["dtype"]) for r in records} == {
        (k, d) for k in ("cat", "polar-improved", "presence-grid") for d in ("float32", "float64")}
    if GPU != "cpu":
        assert len(records) == 6  # one row per kernel and dtype on a GPU
    for r in records:
        assert r["device"] == GPU and r["seconds"] > 0 and r["ratio"] > 0
        if GPU != "cpu":
            assert r["first_call_seconds"] > 0
    text = capsys.readouterr().out
    assert f"device: {result['device']}" in text or GPU == "cpu"
