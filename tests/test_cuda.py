"""The GPU path: every model kind's kernels on a CUDA device against the CPU's on the same cells.

The CPU runs the lane kernels (their own exp, atan2 and sine) or the scalar kernels compiled by
clang; the GPU the scalar kernels compiled by NVRTC with CUDA's libm, so the two differ by a few
ulp per operation, amplified where a formula cancels. These tests need a CUDA device: CI has
none (they are skipped there) and they run on a machine with one
(``python -m pytest tests/test_cuda.py``).
"""

import math
import warnings

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.engine.batch import pdf_batch, rasterise_batch
from bananagrid.engine.warp_runtime import warp


def _has_cuda() -> bool:
    return any(device.is_cuda for device in warp().get_devices())


pytestmark = pytest.mark.skipif(not _has_cuda(), reason="needs a CUDA device (none here)")

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
    gpu = bg.rasterise(model, grid, dtype=dtype, device="cuda")
    cpu = bg.rasterise(model, grid, dtype=dtype, threads=2)
    assert gpu.provenance["device"] == "cuda"
    _compare(name, gpu.values, cpu.values, dtype)
    assert gpu.mass == pytest.approx(cpu.mass, rel=RTOL[dtype])
    rng = np.random.default_rng(5)
    (x0, x1, y0, y1) = grid.extent
    x, y = rng.uniform(x0, x1, 5000), rng.uniform(y0, y1, 5000)
    _compare(name + " pdf", model.pdf(x, y, dtype=dtype, device="cuda"), model.pdf(x, y, dtype=dtype), dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_batches_on_the_gpu_match_the_cpu(dtype):
    rng = np.random.default_rng(11)
    models = [bg.PolarBanana(v0=float(rng.uniform(150.0, 300.0)), t=10.0, sigma_a=float(rng.uniform(0.5, 2.0)),
                             sigma_omega=float(rng.uniform(0.02, 0.06)), variant="rough" if k % 3 == 0 else "improved",
                             sigma_heading=0.05 if k % 4 == 0 else 0.0, heading_order=4 if k % 8 == 0 else 2,
                             pose=bg.Pose(origin=tuple(rng.uniform(-5e3, 5e3, 2)),
                                          heading=float(rng.uniform(-math.pi, math.pi))))
              for k in range(64)]
    gpu = rasterise_batch(models, dtype=dtype, device="cuda")
    cpu = rasterise_batch(models, dtype=dtype, threads=2)
    worst = max(_compare(f"batch {k}", gpu.values[k], cpu.values[k], dtype, quiet=True) for k in range(len(models)))
    print(f"cuda vs cpu rasterise_batch {np.dtype(dtype).name}: max relative {worst:.2e} over {len(models)} hypotheses")
    x, y = rng.uniform(-8e3, 8e3, 2000), rng.uniform(-8e3, 8e3, 2000)
    _compare("pdf_batch", pdf_batch(models, x, y, dtype=dtype, device="cuda"), pdf_batch(models, x, y, dtype=dtype),
             dtype)
