"""Loading kernels: a run builds only the overloads it launches, and the progress line says when
Warp compiles (the first run on a machine) rather than reading its kernel cache.

Warp builds a kernel module with every overload registered in it, so registering both scalar
types, the GPU path's scalar kernels and the batch kernels at import made every first run build
all of them. These tests run in a fresh interpreter (a test process shares Warp's registry, where
other tests may have launched anything) and read Warp's registry after each model kind's float64
rasterise on the CPU."""

import io
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bananagrid.cli import COMPILING, _Progress
from bananagrid.engine import warp_runtime
from bananagrid.engine.warp_runtime import WarpContext, compile_notice

ROOT = Path(__file__).resolve().parents[2]

#: Every kernel module, and a float64 CPU run of each kind of grid model, in a fresh interpreter:
#: the overloads registered at import, then after each run (module, kernel, scalar bits).
_PROBE = r"""
import importlib, json, math, pkgutil, warnings
import numpy as np
import warp as wp
import bananagrid as bg
import bananagrid.kernels as package

modules = [importlib.import_module(f"bananagrid.kernels.{m.name}") for m in pkgutil.iter_modules(package.__path__)]

def registered():
    out = []
    for m in modules:
        module = wp.get_module(m.__name__)
        for kernel in module.kernels.values():
            for overload in (kernel.overloads.values() if kernel.is_generic else ()):
                bits = sorted({8 * wp.types.type_size_in_bytes(a.type.dtype if hasattr(a.type, "dtype") else a.type)
                               for a in overload.adj.args if a.label in ("out", "prob", "table", "mean")})
                out.append([m.__name__.rsplit(".", 1)[-1], kernel.key, bits])
    return sorted(out)

result = {"import": registered()}
fig1 = dict(v0=280.0, t=10.0, sigma_a=5.0 / 3.0, sigma_omega=math.pi / 54.0)
models = {
    "cat": bg.CAT(**fig1),
    "polar": bg.PolarBanana(**fig1, variant="improved"),
    "bearing": bg.BearingFix(sensors=[(0.0, 0.0), (4000.0, 0.0)], bearings=[0.5, -0.5], sigmas=[0.02, 0.02]),
    "butterly": bg.Butterly(mean=(0.0, 0.0), cov=[[1e4, 0.0], [0.0, 1e4]], speeds=[5.0], weights=[1.0], t=100.0),
}
grid = bg.Grid.from_bounds(x=(-3000.0, 3000.0), y=(-200.0, 3400.0), step=200.0)
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    for name, model in models.items():
        bg.rasterise(model, grid, dtype=np.float64)
        result[name] = registered()
print(json.dumps(result))
"""


def test_a_float64_cpu_run_registers_only_the_float64_kernels_it_launches():
    """At import no kernel of any family has an overload (so no module would build anything
    unasked); after each kind's float64 rasterise on the CPU, the overloads registered are
    float64 ones of the kernels that run launches: the lane kernels' grid and points (and the
    CAT's scan table), never a float32 overload, a batch kernel or the GPU path's scalar grid
    kernels of a family that has lanes."""
    probe = subprocess.run([sys.executable, "-c", _PROBE], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert probe.returncode == 0, probe.stderr[-2000:]
    result = json.loads(probe.stdout.splitlines()[-1])
    assert result.pop("import") == []
    seen = set()
    for name, overloads in result.items():
        for module, kernel, bits in overloads:
            assert bits == [64], (name, module, kernel, bits)
            assert "batch" not in kernel, (name, kernel)
            assert module not in ("cat", "polar", "bearing") or kernel in ("cat_table", "polar_moments"), (name, kernel)
            seen.add((module, kernel))
    # each run's own kernels were registered (the CPU lanes, the CAT's table, Butterly's tiles)
    assert {("cat_lanes", "cat_grid_lanes"), ("cat", "cat_table"), ("polar_lanes", "polar_grid_lanes"),
            ("bearing_lanes", "bearing_grid_lanes"), ("butterly", "butterly_grid")} <= seen


class _SlowWarp:
    """Warp's load_module standing in for a compile (``seconds`` long) or a cache load."""

    def __init__(self, seconds):
        self.seconds = seconds

    def load_module(self, module, device):
        time.sleep(self.seconds)


def _load_with(seconds, notice):
    ctx = WarpContext(np.float64, "cpu", 1)
    ctx.wp = _SlowWarp(seconds)
    token = compile_notice.set(notice)
    try:
        from bananagrid.kernels import cat
        ctx.load(cat.cat_table)
    finally:
        compile_notice.reset(token)


def test_a_load_that_compiles_is_announced_and_a_cache_load_is_not():
    """A load longer than COMPILE_NOTICE_SECONDS (Warp compiling) calls the notice once; a load as
    short as a kernel-cache read (2 ms) does not, and without a notice nothing is called."""
    calls = []
    _load_with(warp_runtime.COMPILE_NOTICE_SECONDS + 0.4, lambda: calls.append("slow"))
    assert calls == ["slow"]
    _load_with(0.002, lambda: calls.append("fast"))
    time.sleep(warp_runtime.COMPILE_NOTICE_SECONDS + 0.2)  # the cancelled timer never fires
    assert calls == ["slow"]
    _load_with(0.002, None)


def test_the_progress_line_says_kernels_are_compiling_once_on_its_own_line():
    stream = io.StringIO()
    progress = _Progress("figure1", stream)
    progress(0, 2, "cat t=10 s")
    _load_with(warp_runtime.COMPILE_NOTICE_SECONDS + 0.4, progress.compiling)
    progress.compiling()  # a second module of the same item: said once
    progress(1, 2, "cat t=10 s")
    progress(1, 2, "rough t=10 s")
    progress(2, 2, "rough t=10 s")
    progress.compiling()  # no open line: nothing
    first, second = stream.getvalue().splitlines()
    assert first.startswith(f"[1/2] figure1: cat t=10 s ... {COMPILING} ... ") and first.endswith(" s")
    assert first.count(COMPILING) == 1
    assert COMPILING not in second and second.startswith("[2/2] figure1: rough t=10 s ... ")
